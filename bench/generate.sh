#!/usr/bin/env bash
# Coordinator benchmark, side by side in one run: the same dataset generated with 1 and with 2 workers (scaling
# ratio against linear), the coordinator's own CPU share, and the iceoryx2 dispatch round trip (from the ipc
# crate's latency test). Usage: bench/generate.sh [ROBOTS=24] [TRAJECTORIES=4]
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
robots=${1:-24}
trajectories=${2:-4}
# The whole workspace, not `-p ...`: a package selection unifies other features and rebuilds burn.
cargo build --release -q --workspace
bin=${CARGO_TARGET_DIR:-$root/target}/release
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
echo "machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)"
declare -A wall
for w in 1 2; do
  start=$(date +%s.%N)
  line=$("$bin"/dynforge generate --out "$out/w$w" --robots "$robots" --trajectories "$trajectories" --workers "$w" --seed 9 2>/dev/null)
  end=$(date +%s.%N)
  wall[$w]=$(echo "$end - $start" | awk '{print $1 - $3}')
  echo "workers $w: ${wall[$w]} s wall | $line"
done
python3 -c "
t1, t2 = ${wall[1]}, ${wall[2]}
jobs = $robots * $trajectories
print(f'throughput: {jobs / t1:.1f} jobs/s with 1 worker, {jobs / t2:.1f} jobs/s with 2; scaling {t1 / t2:.2f}x = {t1 / t2 / 2:.2f} of linear (target >= 0.9)')
"
cmp <(cd "$out/w1/shards" && sha256sum *) <(cd "$out/w2/shards" && sha256sum *) && echo "1-worker and 2-worker datasets are byte-identical"
echo "dispatch round trip (iceoryx2 request -> progress + final report, zero-work jobs):"
cargo test --release -q -p dynforge-ipc --test transport latency_and_idle_cpu -- --nocapture 2>&1 | grep -E "round trip|CPU" || true
