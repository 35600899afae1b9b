#!/usr/bin/env bash
# The paper's transformer by dataset size. One run of ROBOTS x 16 trajectories (the paper's 8,192) is generated in 8
# partitions, each cached and pruned before the next (bounded disk: one partition's shards at a time); nested subsets
# of 1/8, 1/4, 1/2 and all of its robots are merged from them (`merge` of the partitions j/8 with j % m == 0); on
# each the transformer (`--preset fast`, lr 1e-3, at most 12 epochs, stopped after 3 without a better validation
# loss) trains under the robot split, and `evaluate` scores its best epoch per window and per robot. The table (and
# CPU hours) goes to OUT/scale.md; each size's report.md has its per-label tables.
# Rerunning the same command resumes all of it: generation, merges, training and evaluation.
# Usage: bench/scale.sh [--dry-run] OUT
#   --dry-run   32 robots x 2 trajectories, a tiny network, one epoch: what the tests run
#   DYNFORGE    the dynforge binary (default target/release/dynforge)
#   DYNFORGE_SCALE_SIZES   the sizes to train, as robot counts (default: all four, 1/8 to all of ROBOTS)
#   DYNFORGE_SCALE_TRAJECTORIES   trajectories per robot (default 16, the paper's). A job's trajectory does not depend
#                                 on this count, so 4 gives the first 4 of each robot's 16: the same robots, fewer jobs
#   DYNFORGE_SCALE_HOP   time steps between window starts (`train --hop`; default 64, back to back). The partitions
#                        are cached for it and pruned, so another hop needs another OUT
#   DYNFORGE_SCALE_DROPOUT, DYNFORGE_SCALE_EPOCHS   the training's dropout and most epochs (default: the preset's
#                        0.1, and 12)
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
dry=0
if [ "${1:-}" = "--dry-run" ]; then dry=1; shift; fi
out=${1:?usage: bench/scale.sh [--dry-run] OUT}
bin=${DYNFORGE:-$root/target/release/dynforge}
if [ $dry = 1 ]; then
  robots=32 trajectories=2 epochs=1 patience=3
  net=(--dim 16 --layers 1 --heads 2 --patch 4 --validation 0.5)
else
  robots=8192 trajectories=${DYNFORGE_SCALE_TRAJECTORIES:-16} epochs=${DYNFORGE_SCALE_EPOCHS:-12} patience=3
  net=(--preset fast)
  if [ -n "${DYNFORGE_SCALE_DROPOUT:-}" ]; then net+=(--dropout "$DYNFORGE_SCALE_DROPOUT"); fi
fi
hop=${DYNFORGE_SCALE_HOP:-}
window=(); hop_flag=()
if [ -n "$hop" ]; then window=(--window "64:64:16:$hop"); hop_flag=(--hop "$hop"); fi
sizes=${DYNFORGE_SCALE_SIZES:-"$((robots / 8)) $((robots / 4)) $((robots / 2)) $robots"}
mkdir -p "$out"
log() { echo "[$(date -u +%T)] $*" >&2; }

# Which partitions j/8 a size needs: those with j % m == 0, m = robots / size.
step_of() {
  local size=$1
  if [ $((robots % size)) != 0 ] || [ $((8 % (robots / size))) != 0 ]; then
    echo "bench/scale.sh: size $size is not ROBOTS / 1, 2, 4 or 8 (ROBOTS = $robots)" >&2
    exit 2
  fi
  echo $((robots / size))
}
needed=()
for j in 0 4 2 6 1 5 3 7; do
  for size in $sizes; do
    if [ $((j % $(step_of "$size"))) = 0 ]; then needed+=("$j"); break; fi
  done
done

# Generation, nested sizes first; each partition cached and pruned before the next.
for j in "${needed[@]}"; do
  [ -f "$out/p$j.prepared" ] && continue
  log "partition $j/8: generate, cache, prune"
  "$bin" generate --out "$out/p$j" --robots "$robots" --trajectories "$trajectories" --seed 11 --partition "$j/8" \
    --workers "$(nproc)" >&2
  "$bin" dataset prepare "$out/p$j" --model transformer "${window[@]}" --prune >&2
  touch "$out/p$j.prepared"
done

# Per size: its data (a partition, or partitions merged), the training (resumed if it was interrupted), the report.
for size in $sizes; do
  m=$(step_of "$size")
  data=$out/p0
  if [ "$m" != 8 ]; then
    data=$out/n$size
    if [ ! -f "$data/manifest.toml" ]; then
      rm -rf "$data"
      parts=()
      for j in 0 1 2 3 4 5 6 7; do [ $((j % m)) = 0 ] && parts+=("$out/p$j"); done
      log "$size robots: merging ${#parts[@]} partitions"
      "$bin" merge --out "$data" "${parts[@]}" >&2
    fi
  fi
  run=$out/t$size
  if [ ! -f "$run.trained" ]; then
    resume=()
    [ -f "$run/train/state.json" ] && resume=(--resume)
    log "$size robots: training ${resume[*]}"
    "$bin" train "$data" --out "$run" --model transformer "${net[@]}" "${hop_flag[@]}" --lr 1e-3 \
      --epochs "$epochs" --patience "$patience" "${resume[@]}" 2>&1 | tee -a "$run.log" >&2
    touch "$run.trained"
  fi
  if [ ! -f "$run/report.md" ]; then
    log "$size robots: evaluating"
    "$bin" evaluate "$run" --torque-recordings 0 --identify-robots 0 --spread-robots 0 >&2
  fi
done

# train's log: "... N training / M validation windows"; report.md: "**Overall** (N samples): R2 = x, ..." per window,
# then "**Overall per robot** (N samples) ..."; metrics.csv: epoch,step,lr,train_loss,validation_loss,validation_r2,
# validation_rmse,windows_per_second,seconds,cpu_seconds (per epoch).
{
  echo "# The transformer by robots: ${robots} x ${trajectories} generated (seed 11), \`fast\`, robot split"
  echo
  echo "| robots | training windows | validation robots | epochs run | best epoch | per window R2 | per robot R2 |" \
    "CPU hours | wall hours |"
  echo "|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
  for size in $sizes; do
    run=$out/t$size
    overall() { grep -m1 "^\*\*Overall$1\*\*" "$run/report.md"; }
    r2() { overall "$1" | sed 's/.*R2 = \([-0-9.]*\).*/\1/'; }
    held=$(overall ' per robot' | sed 's/.*(\([0-9]*\) samples).*/\1/')
    windows=$(grep -m1 -o '[0-9]* training / [0-9]* validation windows' "$run.log" | cut -d' ' -f1)
    best=$(sed -n '1s/.*(epoch \([0-9]*\)).*/\1/p' "$run/report.md")
    tail -n +2 "$run/metrics.csv" | awk -F, -v s="$size" -v t="$windows" -v v="$held" -v b="$best" \
      -v w="$(r2 '')" -v r="$(r2 ' per robot')" '
      { n++; cpu += $10; wall += $9 }
      END {
        printf "| %d | %d | %d | %d | %d | %s | %s | %.3g | %.3g |\n", s, t, v, n, b + 1, w, r, cpu / 3600, wall / 3600
      }'
  done
  echo
  echo "Per kind (mean R2 per window; per robot):"
  echo
  for size in $sizes; do
    echo "- $size robots: $(grep -m1 '^Mean R2 per group' "$out/t$size/report.md" | sed 's/Mean R2 per group: //');" \
      "$(grep '^Mean R2 per group' "$out/t$size/report.md" | sed -n '2s/Mean R2 per group: //p')"
  done
} | tee "$out/scale.md"
