#!/usr/bin/env bash
# Merges the shards of .ci/slurm/sweep-array.sh into $SWEEP_OUT/merged: sweep.json, sweep.csv
# and the plots, byte for byte those of the unsharded sweep. Slurm runs it after the array
# (`sbatch --dependency=afterok:<array job id> .ci/slurm/merge.sh`, see submit.sh); the GitHub
# merge job and tests/scheduler.rs run it with plain bash.
#
# Environment: SHARDS, SWEEP_OUT and EVITRACK as in sweep-array.sh (SHARDS defaults to 3).
# Arguments go to `evitrack merge` (e.g. --check).
#
#SBATCH --job-name=evitrack-merge
#SBATCH --cpus-per-task=1
#SBATCH --time=00:05:00
#SBATCH --output=slurm-%j-merge.out
set -euo pipefail

shards=${SHARDS:-3}
out=${SWEEP_OUT:-out/sweep-sharded}
if [[ -z ${EVITRACK:-} ]]; then
    EVITRACK=$(command -v evitrack || echo target/release/evitrack)
fi

files=()
missing=()
for ((i = 0; i < shards; i++)); do
    file="$out/shard-$i/sweep-shard-$((i + 1))-of-$shards.json"
    if [[ -f $file ]]; then files+=("$file"); else missing+=("$file"); fi
done
if ((${#missing[@]} > 0)); then
    echo "merge.sh: ${#missing[@]} of $shards shards have no results: ${missing[*]}" >&2
    exit 2
fi
exec "$EVITRACK" merge "${files[@]}" --out "$out/merged" "$@"
