#!/usr/bin/env bash
# Submits a sharded sweep to Slurm: an array of SHARDS tasks, then the merge once all of them
# succeeded (afterok). Run from the repository root, with evitrack built or on PATH:
#
#   cargo build --release
#   SHARDS=4 SWEEP_FILE=scenarios/paper.toml .ci/slurm/submit.sh --seeds 10
#
# sbatch passes the environment on (--export=ALL), so both jobs see SHARDS, SWEEP_FILE,
# SWEEP_OUT and EVITRACK. Arguments go to every `evitrack sweep` task.
set -euo pipefail
cd "$(dirname "$0")/../.."
export SHARDS=${SHARDS:-3}
array=$(sbatch --parsable --array="0-$((SHARDS - 1))" .ci/slurm/sweep-array.sh "$@")
array=${array%%;*} # --parsable prints `id` or `id;cluster`
merge=$(sbatch --parsable --dependency="afterok:$array" .ci/slurm/merge.sh)
echo "submitted the sweep array $array ($SHARDS tasks) and the merge $merge (after it)"
