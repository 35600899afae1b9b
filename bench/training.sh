#!/usr/bin/env bash
# Training throughput (windows/s) of dynforge's transformer: our burn trainer vs the same model in PyTorch
# (bench/torch_train.py), on the same CPU, same batch, same random-data setup, 2 threads each.
# Creates the PyTorch venv .venv-bench at the repository root if needed (~5.4 GB: the PyPI wheel brings CUDA libs).
# Results also go to bench/out/training.json.
# Usage: bench/training.sh
#   DYNFORGE_BENCH_STEPS  timed steps per preset (default 20; 3 warm-up steps are run first and not timed)
#   DYNFORGE_BENCH_INPUTS input features per time step F (default 90)
#   DYNFORGE_BENCH_BATCH  windows per step (default 64)
#   DYNFORGE_BENCH_MICRO  micro-batches per step on the burn side (default: the trainer's default, 4), each on a
#                         thread of its own; PyTorch uses 2 intra-op threads
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
steps=${DYNFORGE_BENCH_STEPS:-20}
inputs=${DYNFORGE_BENCH_INPUTS:-90}
batch=${DYNFORGE_BENCH_BATCH:-64}
micro=${DYNFORGE_BENCH_MICRO:+--micro-batches $DYNFORGE_BENCH_MICRO}

venv=$root/.venv-bench
req=bench/requirements-torch.txt
stamp=$venv/.requirements.sha256
want=$(sha256sum "$req" | cut -d' ' -f1)
if [ ! -x "$venv/bin/python" ] || [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  echo "venv: installing PyTorch into $venv (large download)" >&2
  python3 -m venv "$venv" >&2
  "$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r "$req" >&2
  echo "$want" > "$stamp"
fi
py=$venv/bin/python

# Last line of stdout that looks like a JSON object (tolerates stray output before it).
json_line() { grep '^{' | tail -n 1; }

echo "machine: $(nproc) cores, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | xargs)" >&2
echo "settings: inputs $inputs, batch $batch, $steps timed steps after 3 warm-up steps" >&2
# The whole workspace, not `-p dynforge-bench`: a package selection unifies other features and rebuilds burn.
cargo build --release -q --workspace
bin=${CARGO_TARGET_DIR:-$root/target}/release/dynforge-bench-train
results=()
for p in paper fast; do
  echo "== preset $p: burn" >&2
  # shellcheck disable=SC2086 # $micro is empty or two words
  burn=$("$bin" --preset "$p" --inputs "$inputs" --steps "$steps" --batch "$batch" $micro | json_line)
  echo "$burn" >&2
  echo "== preset $p: torch" >&2
  torch=$("$py" bench/torch_train.py --preset "$p" --inputs "$inputs" --steps "$steps" --batch "$batch" | json_line)
  echo "$torch" >&2
  results+=("$burn" "$torch")
done

mkdir -p bench/out
"$py" - "${results[@]}" <<'EOF'
import json, sys
rows = [json.loads(s) for s in sys.argv[1:]]
with open("bench/out/training.json", "w") as f:
    json.dump(rows, f, indent=1)
by = {}
for r in rows:
    by.setdefault(r["preset"], {})[r["framework"]] = r["windows_per_second"]
print("| preset | burn windows/s | torch windows/s | ratio burn/torch |")
print("| --- | ---: | ---: | ---: |")
for preset, v in by.items():
    b, t = v.get("burn"), v.get("torch")
    ratio = f"{b / t:.2f}x" if b and t else "n/a"
    fmt = lambda w: f"{w:.1f}" if w is not None else "n/a"
    print(f"| {preset} | {fmt(b)} | {fmt(t)} | {ratio} |")
EOF
