#!/bin/bash
# SLURM array job: capture a Blender scene as a NeRF dataset in shards, one array task per shard.
#
#   JOB=$(sbatch --parsable farm/slurm/capture_array.sh SCENE.blend DATASET [capture.py options])
#   sbatch --dependency=afterok:$JOB --array=1 farm/slurm/capture_array.sh --merge DATASET
#
# The array's size is the number of shards (change --array below or on the sbatch command line);
# 0-based arrays (--array=0-7) work too: shard K = task id - first id + 1, N = last - first + 1.
# DATASET must be on storage every node shares. A shard that fails can be resubmitted alone
# (sbatch --array=3 ...): it resumes, keeping the frames it had finished. The merge fails, listing
# the frames still missing, until every shard is done.
# Environment: BLENDER (default: blender), NERF_BRIDGE_DIR (default: the submit directory, i.e. run
# sbatch from the repository root), NERF_DRY_RUN=1 prints the command instead of running it.
#
#SBATCH --job-name=nerf-capture
#SBATCH --array=1-8
#SBATCH --cpus-per-task=8
#SBATCH --time=04:00:00
#SBATCH --output=nerf-capture-%A_%a.log
set -euo pipefail

BLENDER=${BLENDER:-blender}
REPO=${NERF_BRIDGE_DIR:-${SLURM_SUBMIT_DIR:-$(pwd)}}
SCRIPT="$REPO/scripts/capture.py"

run() {
    if [ "${NERF_DRY_RUN:-0}" = "1" ]; then
        printf '%q ' "$@"; echo
    else
        exec "$@"
    fi
}

if [ "${1:-}" = "--merge" ]; then
    [ $# -eq 2 ] || { echo "usage: capture_array.sh --merge DATASET" >&2; exit 2; }
    run "$BLENDER" -b --factory-startup --python "$SCRIPT" -- --out "$2" --merge
    exit 0
fi

[ $# -ge 2 ] || { echo "usage: capture_array.sh SCENE.blend DATASET [capture.py options]" >&2; exit 2; }
BLEND=$1; OUT=$2; shift 2
: "${SLURM_ARRAY_TASK_ID:?not an array task: submit with sbatch --array=1-N}"
FIRST=${SLURM_ARRAY_TASK_MIN:?}
LAST=${SLURM_ARRAY_TASK_MAX:?}
K=$((SLURM_ARRAY_TASK_ID - FIRST + 1))
N=$((LAST - FIRST + 1))
if [ -n "${SLURM_ARRAY_TASK_COUNT:-}" ] && [ "$SLURM_ARRAY_TASK_COUNT" -ne "$N" ]; then
    echo "capture_array.sh: the array must be a contiguous range (--array=1-N); got $SLURM_ARRAY_TASK_COUNT tasks" \
         "between $FIRST and $LAST" >&2
    exit 2
fi
run "$BLENDER" -b "$BLEND" --python "$SCRIPT" -- --out "$OUT" --quiet "$@" --shard "$K/$N"
