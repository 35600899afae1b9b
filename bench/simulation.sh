#!/usr/bin/env bash
# Simulation speed and fidelity, side by side in one run: dynforge's native and rapier engines vs MuJoCo (PyPI
# `mujoco`, in the reference venv) stepping the same frictionless generated URDFs from the same state for SECONDS of
# torque-free swing, each engine at several step sizes; the engines are compared at equal accuracy (the cheapest
# configuration whose energy drift stays within DRIFT, per robot). Then the controller statistics over ROBOTS robots.
# Usage: bench/simulation.sh [SECONDS=10] [ROBOTS=100] [SWING_IDS=1,...,8] [DRIFT=1e-4].
# Results also go to bench/out/simulation.json.
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
ids=${3:-1,2,3,4,5,6,7,8}
drift=${4:-1e-4}
echo "machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)"
"$bin"/dynforge-bench-engines bench/out "$seconds" 1 "$ids" > bench/out/simulation.jsonl
"$py" bench/mujoco_engine.py "$seconds" $(echo "$ids" | tr ',' '\n' | sed 's|.*|&=bench/out/swing_&.urdf|') 2>/dev/null \
  >> bench/out/simulation.jsonl
"$py" - bench/out/simulation.jsonl "$drift" <<'PY'
import json, statistics, sys
rows = [json.loads(l) for l in open(sys.argv[1])]
bound = float(sys.argv[2])
engines = list(dict.fromkeys(r["engine"] for r in rows))
robots = list(dict.fromkeys(r["robot"] for r in rows))
print("every configuration: cost [us per simulated ms] / energy drift (max |E(t) - E(0)| / peak kinetic energy)")
configs = list(dict.fromkeys((r["engine"], r["h_ms"]) for r in rows))
print(f"{'engine':<14}{'h [ms]':>7}" + "".join(f"{'robot ' + str(k):>20}" for k in robots))
for e, h in configs:
    cells = {r["robot"]: r for r in rows if r["engine"] == e and r["h_ms"] == h}
    print(f"{e:<14}{h:>7}" + "".join(f"{cells[k]['us_per_ms']:>10.2f} {cells[k]['energy_drift']:>9.1e}" for k in robots))
print(f"\nequal accuracy: the cheapest configuration with drift <= {bound:g} (cost in us per simulated ms, step in ms)")
best = {}
for e in engines:
    for k in robots:
        ok = [r for r in rows if r["engine"] == e and r["robot"] == k and r["energy_drift"] <= bound]
        best[e, k] = min(ok, key=lambda r: r["us_per_ms"]) if ok else None
print(f"{'engine':<14}" + "".join(f"{'robot ' + str(k):>16}" for k in robots) + f"{'median ratio':>14}")
for e in engines:
    cells, ratios = "", []
    for k in robots:
        b, n = best[e, k], best["native_rk4", k]
        cells += f"{b['us_per_ms']:>9.2f} @{b['h_ms']:<5}" if b else f"{'none':>16}"
        if b and n:
            ratios.append(b["us_per_ms"] / n["us_per_ms"])
    print(f"{e:<14}" + cells + (f"{statistics.median(ratios):>13.2f}x" if ratios else f"{'-':>14}"))
print("median ratio = the engine's cost / native's cost at equal accuracy, over the robots where both reach it")
json.dump(rows, open("bench/out/simulation.json", "w"), indent=1)
PY
"$bin"/dynforge-bench-controller "$robots" 4
