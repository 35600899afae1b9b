#!/usr/bin/env bash
# Excitation design against a fair baseline: `dynforge excite` with its defaults on example-robot-data's UR5 and Panda
# (fingers welded), timed, then scored independently by bench/excitation.py (Pinocchio's regressor at 1 kHz) beside
# 20 random multi-sines and 20 random sets of as many multi-sines, built the usual way and scaled joint by joint into
# the same limits, the acceleration limit included. Prints per arm excite's own lines and the independent table (best
# and median multi-sine, each designed trajectory alone and the set). A UR5 design at --acceleration 30 shows what the
# default limit (5 rad/s^2) costs.
#
# Usage: bench/excitation.sh [OUT=bench/out/excitation]
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
out=${1:-$root/bench/out/excitation}
mkdir -p "$out"
cd "$root"
py=${DYNFORGE_PYTHON:-$(scripts/venv.sh)}
cargo build --release -q --bin dynforge
bin=${CARGO_TARGET_DIR:-$root/target}/release/dynforge

design() { # NAME URDF ACCELERATION [excite flags...]: excite, timed, then the independent score
  local name=$1 urdf=$2 acceleration=$3
  shift 3
  local fix=()
  for a in "$@"; do [[ $a == --* ]] || fix+=(--fix "$a"); done
  echo "## $name: dynforge excite --acceleration $acceleration $*"
  /usr/bin/time -f "design time: %e s wall, %U s CPU" "$bin" excite --urdf "$urdf" --out "$out/$name" \
    --acceleration "$acceleration" "$@" | grep -v '^wrote'
  "$py" bench/excitation.py --urdf "$urdf" --design "$out/$name" --acceleration "$acceleration" --json "$out/$name.json" \
    "${fix[@]}"
  echo
}

ur5=$("$py" tests/reference/simulate_arm.py --path ur5 </dev/null)
panda=$("$py" tests/reference/simulate_arm.py --path panda </dev/null)
design ur5 "$ur5" 5
design panda "$panda" 5 --fix panda_finger_joint1
design ur5-acceleration-30 "$ur5" 30
