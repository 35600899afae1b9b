#!/usr/bin/env bash
# Submits a dataset generation to Slurm: a job array of N partitions (generate.sbatch), then a job that runs once
# they all succeed and merges them (merge.sbatch). Prints the two job ids.
#
#   deploy/slurm/submit.sh --root /shared/run1 --partitions 16 --cpus 8 -- --robots 8192 --seed 1
#
# Everything after `--` goes to `dynforge generate` (robots, trajectories, seed, --config ...). --train "ARGS" trains
# on the merged directory afterwards. --prune caches each finished partition for training and deletes its shards
# (`dataset prepare --prune`; --prune-args "ARGS" passes e.g. --window), so the run needs ~25 KB of disk per job. Extra sbatch options (account, partition, time) come from SBATCH_* variables or
# --sbatch "OPTS". The dynforge binary is found on PATH or given with --dynforge (it must be reachable from the nodes).
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root="" partitions="" cpus=2 train="" sbatch_opts="" dynforge=${DYNFORGE:-dynforge} prune="" prune_args=""
while [ $# -gt 0 ]; do
    case "$1" in
    --root) root=$2; shift 2 ;;
    --partitions) partitions=$2; shift 2 ;;
    --cpus) cpus=$2; shift 2 ;;
    --train) train=$2; shift 2 ;;
    --prune) prune=yes; shift ;;
    --prune-args) prune=yes prune_args=$2; shift 2 ;;
    --sbatch) sbatch_opts=$2; shift 2 ;;
    --dynforge) dynforge=$2; shift 2 ;;
    --) shift; break ;;
    *) echo "submit.sh: unknown option $1 (see the header of $0)" >&2; exit 2 ;;
    esac
done
if [ -z "$root" ] || [ -z "$partitions" ] || ! [ "$partitions" -ge 1 ] 2>/dev/null; then
    echo "submit.sh: --root DIR and --partitions N (>= 1) are required" >&2
    exit 2
fi
mkdir -p "$root"
root=$(cd "$root" && pwd)
export DYNFORGE_ROOT=$root DYNFORGE=$dynforge DYNFORGE_GENERATE_ARGS="$*" DYNFORGE_TRAIN_ARGS=$train \
    DYNFORGE_PRUNE=$prune DYNFORGE_PRUNE_ARGS=$prune_args
# shellcheck disable=SC2086 # a list of options
array=$(sbatch --parsable --export=ALL --chdir="$root" --array="0-$((partitions - 1))" \
    --cpus-per-task="$cpus" $sbatch_opts "$here/generate.sbatch")
# shellcheck disable=SC2086
merge=$(sbatch --parsable --export=ALL --chdir="$root" --dependency="afterok:${array%%;*}" \
    $sbatch_opts "$here/merge.sbatch")
echo "generate: job array $array ($partitions partitions into $root/part-*)"
echo "merge:    job $merge (after all of them: $root/merged)"
