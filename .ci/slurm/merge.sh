#!/usr/bin/env bash
# Merges the shards of .ci/slurm/sweep-array.sh into $SWEEP_OUT/merged: sweep.json, sweep.csv
# and the plots, byte for byte those of the unsharded sweep. Slurm runs it after the array
# (`sbatch --dependency=afterany:<array job id> .ci/slurm/merge.sh`, see submit.sh); the GitHub
# merge job and tests/scheduler.rs run it with plain bash.
#
# It merges every $SWEEP_OUT/shard-*/sweep-shard-*-of-*.json it finds: each file records its
# shard count and its sweep, so `evitrack merge` names a missing, repeated, unfinished or foreign
# shard (exit 2) and no shard count has to be kept in step with the array here.
#
# Environment: SWEEP_OUT and EVITRACK as in sweep-array.sh.
# Arguments go to `evitrack merge` (e.g. --check: the expectations are checked here, on the
# whole sweep, not in the shards).
#
#SBATCH --job-name=evitrack-merge
#SBATCH --cpus-per-task=1
#SBATCH --time=00:05:00
#SBATCH --output=slurm-%j-merge.out
set -euo pipefail

out=${SWEEP_OUT:-out/sweep-sharded}
if [[ -z ${EVITRACK:-} ]]; then
    EVITRACK=$(command -v evitrack || echo target/release/evitrack)
fi

shopt -s nullglob
files=("$out"/shard-*/sweep-shard-*-of-*.json)
if ((${#files[@]} == 0)); then
    echo "merge.sh: no shard has results: nothing matches $out/shard-*/sweep-shard-*-of-*.json" >&2
    exit 2
fi
exec "$EVITRACK" merge "${files[@]}" --out "$out/merged" "$@"
