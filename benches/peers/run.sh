#!/usr/bin/env bash
# evitrack against its peers (pybelief, hmmlearn, scikit-learn) on the inputs of its own
# benches, timed alternately in one window; see benches/peers/README.md.
# Usage: benches/peers/run.sh [OUT_DIR]   (ROUNDS=5 by default)
set -euo pipefail
cd "$(dirname "$0")/../.."
out=${1:-target/peers/$(date -u +%Y%m%dT%H%M%SZ)}
rounds=${ROUNDS:-5}
venv=target/peers-venv

if [ ! -x "$venv/bin/python" ]; then
    python3 -m venv "$venv"
fi
"$venv/bin/pip" install -q pybelief==0.1.0 hmmlearn==0.3.3 scikit-learn==1.9.1 \
    numpy==2.4.6 scipy==1.17.1
py="$venv/bin/python"
# One thread for every peer's numerical library.
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1

bin=$(cargo bench --bench peers --no-run --message-format=json 2>/dev/null |
    "$py" -c 'import json, sys
for line in sys.stdin:
    m = json.loads(line)
    if m.get("reason") == "compiler-artifact" and m["target"]["name"] == "peers" and m.get("executable"):
        print(m["executable"])')
mkdir -p "$out"
"$bin" export "$out"
: >"$out/times.jsonl"
{ echo "start: $(date -u +%FT%TZ), load: $(cut -d' ' -f1-3 /proc/loadavg), cores: $(getconf _NPROCESSORS_ONLN)"; } >"$out/load.txt"

# task, repetitions per call for evitrack, for the peer.
tasks=("dempster_fixed 50 2" "dempster_seed5 50 2" "em 20 2" "em_log 20 2" "gp_1start 2 2" "gp_2starts 2 2")
for round in $(seq 1 "$rounds"); do
    for spec in "${tasks[@]}"; do
        read -r task ours theirs <<<"$spec"
        ours_cmd=("$bin" time "$task" "$ours")
        peer_cmd=("$py" benches/peers/peers.py time "$task" "$out" "$theirs")
        if [ "$round" -eq 1 ]; then
            ours_cmd+=("$out/result-$task-evitrack.json")
            peer_cmd+=("$out/result-$task-peer.json")
        fi
        # Alternate which side goes first, so neither always meets the same load.
        if [ $((round % 2)) -eq 1 ]; then
            "${ours_cmd[@]}" >>"$out/times.jsonl"
            "${peer_cmd[@]}" >>"$out/times.jsonl"
        else
            "${peer_cmd[@]}" >>"$out/times.jsonl"
            "${ours_cmd[@]}" >>"$out/times.jsonl"
        fi
    done
    echo "round $round of $rounds done" >&2
done
echo "end: $(date -u +%FT%TZ), load: $(cut -d' ' -f1-3 /proc/loadavg)" >>"$out/load.txt"
"$py" benches/peers/peers.py table "$out" | tee "$out/table.md"
cat "$out/load.txt"
