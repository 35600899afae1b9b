#!/usr/bin/env bash
# The bounded-disk path against keeping every shard, side by side on one dataset: (a) generate the whole run, then
# train's physics cache; (b) the same run as P partitions one after another, each cached and pruned
# (`dataset prepare --prune`) before the next, then merged by their caches. Reports wall time, the peak disk of each
# (largest `du` seen between steps), the disk per job left, and checks that both give the same cache bytes.
# Usage: bench/bounded-disk.sh [ROBOTS=64] [PARTITIONS=4] [TRAJECTORIES=16]
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
robots=${1:-64}
partitions=${2:-4}
trajectories=${3:-16}
# The whole workspace, not `-p ...`: a package selection unifies other features and rebuilds burn.
cargo build --release -q --workspace
bin=${CARGO_TARGET_DIR:-$root/target}/release/dynforge
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
echo "machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)"
gen=(--robots "$robots" --trajectories "$trajectories" --seed 21 --workers "$(nproc)")
peak=0
measure() { local kb; kb=$(du -sk "$1" | cut -f1); [ "$kb" -gt "$peak" ] && peak=$kb; return 0; }

start=$(date +%s.%N)
"$bin" generate --out "$out/whole" "${gen[@]}" >/dev/null 2>&1
measure "$out/whole"
"$bin" dataset prepare "$out/whole" >/dev/null 2>&1
measure "$out/whole"
whole_wall=$(echo "$(date +%s.%N) $start" | awk '{print $1 - $2}')
whole_peak=$peak
whole_jobs=$(grep -c . "$out/whole/ledger.tsv")

peak=0
start=$(date +%s.%N)
parts=()
for ((i = 0; i < partitions; i++)); do
  p=$out/parts/part-$i
  "$bin" generate --out "$p" --partition "$i/$partitions" "${gen[@]}" >/dev/null 2>&1
  measure "$out/parts"
  "$bin" dataset prepare "$p" --prune >/dev/null 2>&1
  measure "$out/parts"
  parts+=("$p")
done
"$bin" merge --out "$out/parts/merged" "${parts[@]}" >/dev/null
measure "$out/parts"
parts_wall=$(echo "$(date +%s.%N) $start" | awk '{print $1 - $2}')
parts_peak=$peak
merged_kb=$(du -sk "$out/parts/merged" | cut -f1)
part_cache_kb=$(du -sck "${parts[@]/%//cache}" | tail -1 | cut -f1)

python3 -c "
jobs, ww, pw, wp, pp = $whole_jobs, $whole_wall, $parts_wall, $whole_peak, $parts_peak
print(f'{jobs} jobs ($robots robots x $trajectories trajectories), {$partitions} partitions')
print(f'keep every shard: {ww:7.1f} s wall, peak disk {wp / 1024:8.1f} MB ({wp / jobs:6.1f} KB per job)')
print(f'bounded disk:     {pw:7.1f} s wall, peak disk {pp / 1024:8.1f} MB ({pp / jobs:6.1f} KB per job)')
print(f'ratio bounded / whole: time {pw / ww:.2f}, peak disk {pp / wp:.2f}')
print(f'left after the merge: merged {$merged_kb / jobs:.1f} KB per job, partition caches {$part_cache_kb / jobs:.1f} KB per job')
"
cmp <(cat "$out"/whole/cache/physics-*.bin | sha256sum) <(cat "$out"/parts/merged/cache/physics-*.bin | sha256sum) \
  && [ "$(ls "$out/whole/cache")" = "$(ls "$out/parts/merged/cache")" ] \
  && echo "the merged cache is the whole run's, byte for byte and by name"
