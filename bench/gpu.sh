#!/usr/bin/env bash
# The transformer on a GPU beside the CPU, sized to fit 10 minutes on one GPU and 16 cores (the device machine some
# tasks are lent): generate with one worker per core, build the window cache, train `--preset fast` on the GPU for
# several epochs and on the CPU for one, and print R2 by epoch and windows/s of each, side by side.
# Usage: bench/gpu.sh [--dry-run] OUT
#   --dry-run   a few robots, one epoch, the CPU only: what the tests run (no GPU, no CUDA build needed)
#   DYNFORGE    the dynforge binary (default target/release/dynforge; build it with `--features cuda` for the GPU)
#   DYNFORGE_GPU_ROBOTS, DYNFORGE_GPU_EPOCHS, DYNFORGE_GPU_DEVICE   override 1024, 8 and cuda
# Writes OUT/data, OUT/cache timings, OUT/<device>/ (checkpoints) and OUT/gpu.md (the table).
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
dry=0
if [ "${1:-}" = "--dry-run" ]; then dry=1; shift; fi
out=${1:?usage: bench/gpu.sh [--dry-run] OUT}
bin=${DYNFORGE:-$root/target/release/dynforge}
workers=$(nproc)
if [ $dry = 1 ]; then
  robots=8 trajectories=2 epochs=1 gpu=cpu workers=2
  small=(--dim 16 --layers 1 --heads 2 --validation 0.5)
else
  robots=${DYNFORGE_GPU_ROBOTS:-1024} trajectories=16 epochs=${DYNFORGE_GPU_EPOCHS:-8} gpu=${DYNFORGE_GPU_DEVICE:-cuda}
  small=()
fi
mkdir -p "$out"
seconds() { local t0=$1; echo $(( $(date +%s) - t0 )); }

t0=$(date +%s)
"$bin" generate --out "$out/data" --robots "$robots" --trajectories "$trajectories" --workers "$workers" --seed 11 >&2
generate_s=$(seconds "$t0")
t0=$(date +%s)
"$bin" dataset prepare "$out/data" --model transformer >&2
prepare_s=$(seconds "$t0")

# One run per device: the GPU for `epochs`, the CPU for one (its windows/s is what the ratio needs).
train() {
  local device=$1 n=$2
  rm -rf "${out:?}/$device"
  "$bin" train "$out/data" --out "$out/$device" --model transformer --preset fast --epochs "$n" --lr 1e-3 \
    --device "$device" "${small[@]}" >&2
}
train "$gpu" "$epochs"
[ "$gpu" = cpu ] || train cpu 1

# metrics.csv: epoch,step,lr,train_loss,validation_loss,validation_r2,validation_rmse,windows_per_second,seconds,...
{
  echo "# GPU bench: $robots robots x $trajectories trajectories, transformer fast, $(nproc) cores"
  echo
  echo "generation ${generate_s} s with $workers workers; window cache ${prepare_s} s"
  echo
  echo "| device | epoch | validation R2 | windows/s | seconds |"
  echo "|---|---:|---:|---:|---:|"
  for device in $(printf '%s\n' "$gpu" cpu | sort -u); do
    tail -n +2 "$out/$device/metrics.csv" | awk -F, -v d="$device" '{ printf "| %s | %d | %.4f | %.0f | %.1f |\n", d, $1, $6, $8, $9 }'
  done
} | tee "$out/gpu.md"
