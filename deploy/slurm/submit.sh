#!/usr/bin/env bash
# Submits a dataset generation to Slurm: a job array of N partitions (generate.sbatch), then a job that runs once
# they all succeed and merges them (merge.sbatch). Prints the two job ids. deploy/README.md is the operator's guide.
#
#   deploy/slurm/submit.sh --root /shared/run1 --partitions 16 --cpus 8 -- --robots 8192 --seed 1
#
# Everything after `--` goes to `dynforge generate` (robots, trajectories, seed, --config ...). Options:
#   --root DIR          the run's directory on the shared filesystem (part-i/, merged/, model/ and the job logs)
#   --partitions N      the job array's size: task i generates partition i/N
#   --cpus N            CPUs (= worker processes) per array task (default 2)
#   --merge-cpus N      CPUs of the merge job, which trains (default: --cpus)
#   --train "ARGS"      train on the merged directory afterwards (`dynforge train merged --out model ARGS`)
#   --prune             cache each finished partition for training and delete its shards (`dataset prepare --prune`):
#                       ~25 KB of disk per job instead of ~1 MB
#   --prune-args "ARGS" one cache to build before the shards go (e.g. "--model transformer --window 64:64:16");
#                       repeat it for several caches (implies --prune)
#   --sbatch "OPTS"     extra sbatch options for both jobs (account, partition, time); SBATCH_* variables work too
#   --dynforge PATH     the dynforge binary (default: dynforge on the nodes' PATH); a path is made absolute, and it
#                       must be reachable from the nodes
# Resubmitting the same command resumes: finished partitions are skipped, a complete merge is kept, training resumes.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
die() {
    echo "submit.sh: $*" >&2
    exit 2
}
root="" partitions="" cpus=2 merge_cpus="" train="" sbatch_opts="" dynforge=${DYNFORGE:-dynforge} prune=""
prune_args=""
while [ $# -gt 0 ]; do
    case "$1" in
    --root | --partitions | --cpus | --merge-cpus | --train | --prune-args | --sbatch | --dynforge)
        [ $# -ge 2 ] || die "$1 needs a value"
        ;;
    esac
    case "$1" in
    --root) root=$2; shift 2 ;;
    --partitions) partitions=$2; shift 2 ;;
    --cpus) cpus=$2; shift 2 ;;
    --merge-cpus) merge_cpus=$2; shift 2 ;;
    --train) train=$2; shift 2 ;;
    --prune) prune=yes; shift ;;
    # One line per cache: generate.sbatch runs `dataset prepare` once per line, --prune on the last.
    --prune-args) prune=yes prune_args+="${2//$'\n'/ }"$'\n'; shift 2 ;;
    --sbatch) sbatch_opts=$2; shift 2 ;;
    --dynforge) dynforge=$2; shift 2 ;;
    --) shift; break ;;
    *) die "unknown option $1 (see the header of $0)" ;;
    esac
done
count() {
    if ! [[ $2 =~ ^[0-9]+$ ]] || [ "$2" -lt 1 ]; then die "$1 must be a whole number >= 1, not '$2'"; fi
}
[ -n "$root" ] || die "--root DIR is required"
[ -n "$partitions" ] || die "--partitions N is required"
count --partitions "$partitions"
count --cpus "$cpus"
merge_cpus=${merge_cpus:-$cpus}
count --merge-cpus "$merge_cpus"
# The jobs run with --chdir at the root: a relative path to the binary would be looked up there.
case "$dynforge" in
*/*)
    if ! [ -f "$dynforge" ] || ! [ -x "$dynforge" ]; then die "--dynforge $dynforge: no executable file there"; fi
    dynforge="$(cd "$(dirname "$dynforge")" && pwd)/$(basename "$dynforge")"
    ;;
esac
mkdir -p "$root"
root=$(cd "$root" && pwd)
export DYNFORGE_ROOT=$root DYNFORGE=$dynforge DYNFORGE_GENERATE_ARGS="$*" DYNFORGE_TRAIN_ARGS=$train \
    DYNFORGE_PRUNE=$prune DYNFORGE_PRUNE_ARGS=$prune_args
# shellcheck disable=SC2086 # a list of options
array=$(sbatch --parsable --export=ALL --chdir="$root" --array="0-$((partitions - 1))" \
    --cpus-per-task="$cpus" $sbatch_opts "$here/generate.sbatch")
# --kill-on-invalid-dep: if a task fails or is cancelled, the merge is cancelled too instead of pending forever
# (DependencyNeverSatisfied); resubmitting submits a new one.
# shellcheck disable=SC2086
merge=$(sbatch --parsable --export=ALL --chdir="$root" --dependency="afterok:${array%%;*}" --kill-on-invalid-dep=yes \
    --cpus-per-task="$merge_cpus" $sbatch_opts "$here/merge.sbatch")
echo "generate: job array $array ($partitions partitions into $root/part-*)"
echo "merge:    job $merge (after all of them: $root/merged, $merge_cpus CPUs)"
