#!/usr/bin/env bash
# Simulation speed and fidelity, side by side in one run: dynforge's native and rapier engines vs MuJoCo (PyPI
# `mujoco`, in the reference venv) stepping the same frictionless generated URDF from the same state at 1 ms for
# SECONDS of torque-free swing. Then the controller statistics over ROBOTS generated robots.
# Usage: bench/simulation.sh [SECONDS=10] [ROBOTS=100]. Results also go to bench/out/simulation.json.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
seconds=${1:-10}
robots=${2:-100}
py=$(scripts/venv.sh)
# The whole workspace, not `-p ...`: a package selection unifies other features and rebuilds burn.
cargo build --release -q --workspace
bin=${CARGO_TARGET_DIR:-$root/target}/release
mkdir -p bench/out
urdf=bench/out/swing.urdf
echo "machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)"
{ "$bin"/dynforge-bench-engines "$urdf" "$seconds"; "$py" bench/mujoco_engine.py "$urdf" "$seconds" 2>/dev/null; } > bench/out/simulation.jsonl
"$py" - bench/out/simulation.jsonl <<'PY'
import json, sys
rows = [json.loads(l) for l in open(sys.argv[1])]
by = {r["engine"]: r for r in rows}
native = by["native_rk4"]["steps_per_s"]
print(f"{'engine':<20} {'steps/s':>10} {'us/step':>9} {'energy drift':>13} {'native speedup':>15}")
for r in rows:
    print(f"{r['engine']:<20} {r['steps_per_s']:>10} {r['us_per_step']:>9.3f} {r['energy_drift']:>13.2e} {native / r['steps_per_s']:>14.2f}x")
print("energy drift = max |E(t) - E(0)| / peak kinetic energy over the run (>= 1 means the run went unstable)")
json.dump(rows, open("bench/out/simulation.json", "w"), indent=1)
PY
"$bin"/dynforge-bench-controller "$robots" 4
