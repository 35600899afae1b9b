#!/usr/bin/env bash
# RNEA / ABA / CRBA / regressor microseconds per call: dynforge vs Pinocchio (called from Python) on the same URDFs, side by side
# in one run. Creates the reference venv if needed. Results also go to bench/out/dynamics.json.
# Usage: bench/dynamics.sh [CALLS]   (default 200000 for dynforge, a quarter of that for Pinocchio)
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
calls=${1:-200000}
py=$(scripts/venv.sh)
# The whole workspace, not `-p ...`: a package selection unifies other features and rebuilds burn.
cargo build --release -q --workspace
bin=${CARGO_TARGET_DIR:-$root/target}/release
out=bench/out
mkdir -p "$out"
"$bin"/dynforge robot --seed 1 --id 7 --out "$out/df6_s1_r7.urdf" 2>/dev/null
ur5=$("$py" robot/tests/reference/pinocchio_dynamics.py --ur5)
echo "machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)"
printf '%-12s %-6s %12s %12s %8s\n' robot algo dynforge_us pinocchio_us speedup
json="["
for urdf in "$out/df6_s1_r7.urdf" "$ur5"; do
  name=$(basename "$urdf" .urdf)
  ours=$("$bin"/dynforge-bench-dynamics "$urdf" "$calls")
  theirs=$("$py" bench/pinocchio_dynamics.py "$urdf" $((calls / 4)))
  for algo in rnea aba crba regressor; do
    "$py" -c "import json,sys; a=json.loads(sys.argv[1])['${algo}_us']; b=json.loads(sys.argv[2])['${algo}_us']; \
print('%-12s %-6s %12.3f %12.3f %7.2fx' % ('$name', '$algo', a, b, b / a))" "$ours" "$theirs"
  done
  json="$json{\"robot\": \"$name\", \"dynforge\": $ours, \"pinocchio_python\": $theirs},"
done
echo "${json%,}]" > "$out/dynamics.json"
echo "speedup = Pinocchio-from-Python time / dynforge time (higher is better for dynforge); target: ABA >= 1.0x"
