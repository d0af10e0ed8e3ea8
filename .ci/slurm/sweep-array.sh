#!/usr/bin/env bash
# One shard of a sweep: array task i of n runs `evitrack sweep FILE --shard (i+1)/n` into its own
# folder, $SWEEP_OUT/shard-i. Slurm runs it as an array job; the GitHub matrix job
# (.ci/github/sweep-matrix.yml) and tests/scheduler.rs run it with plain bash.
#
#   sbatch .ci/slurm/sweep-array.sh                 # 3 tasks on scenarios/paper.toml
#   sbatch --array=0-9 .ci/slurm/sweep-array.sh --seeds 10
#   .ci/slurm/submit.sh                              # the array plus the dependent merge job
#
# Environment (all optional):
#   SHARD       this task's index, 0 … n−1 (default: $SLURM_ARRAY_TASK_ID)
#   SHARDS      the task count n (default: $SLURM_ARRAY_TASK_COUNT, else 3)
#   SWEEP_FILE  the scenario file (default: scenarios/paper.toml)
#   SWEEP_OUT   the output folder shared by all tasks (default: out/sweep-sharded)
#   EVITRACK    the binary (default: evitrack on PATH, else target/release/evitrack)
#   JOBS        variants at once (default: $SLURM_CPUS_PER_TASK, else evitrack's default)
# Arguments after the script name go to `evitrack sweep` (e.g. --seeds 10); `--check` is
# refused here: it belongs on the merge (merge.sh --check), which sees every run.
# The scheduler counts from 0, `--shard` from 1: task i runs shard i+1.
#
#SBATCH --job-name=evitrack-sweep
#SBATCH --array=0-2
#SBATCH --cpus-per-task=2
#SBATCH --time=00:30:00
#SBATCH --output=slurm-%A_%a.out
set -euo pipefail

shard=${SHARD:-${SLURM_ARRAY_TASK_ID:?set SHARD or run as a Slurm array task}}
shards=${SHARDS:-${SLURM_ARRAY_TASK_COUNT:-3}}
file=${SWEEP_FILE:-scenarios/paper.toml}
out=${SWEEP_OUT:-out/sweep-sharded}
if [[ -z ${EVITRACK:-} ]]; then
    EVITRACK=$(command -v evitrack || echo target/release/evitrack)
fi
if ! [[ $shard =~ ^[0-9]+$ && $shards =~ ^[0-9]+$ ]] || ((shard >= shards)); then
    echo "sweep-array.sh: task $shard of $shards: need 0 <= SHARD < SHARDS" >&2
    exit 2
fi
for arg in "$@"; do
    if [[ $arg == --check ]]; then
        echo "sweep-array.sh: --check belongs on the merge (merge.sh --check, or submit.sh" \
            "--check, which passes it there): a shard holds only some of the runs" >&2
        exit 2
    fi
done
jobs=()
if [[ -n ${JOBS:-${SLURM_CPUS_PER_TASK:-}} ]]; then
    jobs=(--jobs "${JOBS:-$SLURM_CPUS_PER_TASK}")
fi

# Each task writes only its own folder: no two tasks share a file, on one machine or many.
exec "$EVITRACK" sweep "$file" --shard "$((shard + 1))/$shards" --out "$out/shard-$shard" \
    "${jobs[@]}" "$@"
