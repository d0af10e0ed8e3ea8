#!/usr/bin/env bash
# Submits a sharded sweep to Slurm: an array of SHARDS tasks, then the merge once all of them
# ended. Run from the repository root, with evitrack built or on PATH:
#
#   cargo build --release
#   SHARDS=4 SWEEP_FILE=scenarios/paper.toml .ci/slurm/submit.sh --seeds 10 --check
#
# sbatch passes the environment on (--export=ALL), so both jobs see SHARDS, SWEEP_FILE,
# SWEEP_OUT and EVITRACK. `--check` goes to the merge (a shard holds only some runs, and a shard
# that exits 1 on a regression would leave an `afterok` merge waiting forever); every other
# argument goes to each `evitrack sweep` task. The merge runs `afterany`: when a task failed, it
# names the missing or unfinished shard and exits 2 instead of never starting.
set -euo pipefail
cd "$(dirname "$0")/../.."
export SHARDS=${SHARDS:-3}
sweep_args=()
merge_args=()
for arg in "$@"; do
    if [[ $arg == --check ]]; then merge_args+=("$arg"); else sweep_args+=("$arg"); fi
done
array=$(sbatch --parsable --array="0-$((SHARDS - 1))" .ci/slurm/sweep-array.sh "${sweep_args[@]}")
array=${array%%;*} # --parsable prints `id` or `id;cluster`
merge=$(sbatch --parsable --dependency="afterany:$array" .ci/slurm/merge.sh "${merge_args[@]}")
echo "submitted the sweep array $array ($SHARDS tasks) and the merge $merge (after it)"
