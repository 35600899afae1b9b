#!/usr/bin/env bash
# Fingerprints of what dynforge writes, to show that a refactor changed no output: run it with the binary before and
# after the change (same OUT) and diff the two listings. It covers a generation (shards), a robot's family on designed
# excitations (CSV, MCAP, JSON, report, shards), the window and physics caches and a trained model (one epoch), and,
# given a checkout of github shamilmamedov/dynamic_calibration, a real UR10e's calibrated URDF, MJCF and JSON. Files
# that hold times or process ids (ledgers, locks, metrics, training state) are left out. About 10 s with a release
# binary.
#
# Usage: bench/golden.sh BIN OUT [UR10E_CHECKOUT] > listing.txt
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
bin=$(cd "$(dirname "$1")" && pwd)/$(basename "$1")
out=${2:?usage: bench/golden.sh BIN OUT [UR10E_CHECKOUT]}
ur10e=${3:-}
rm -rf "$out" && mkdir -p "$out" && out=$(cd "$out" && pwd)
py=$("$root/scripts/venv.sh")
urdf=$("$py" "$root/tests/reference/simulate_arm.py" --path ur5)
quiet() { "$@" > "$out/log.txt" 2>&1 || { cat "$out/log.txt" >&2; exit 1; }; }
quiet "$bin" generate --robots 6 --trajectories 2 --seed 5 --workers 2 --out "$out/gen"
quiet "$bin" excite --urdf "$urdf" --out "$out/exc" --count 2 --evaluations 200 --duration 6
quiet "$bin" generate --urdf "$urdf" --excitation "$out/exc" --robots 3 --seed 2 --workers 2 --out "$out/fam"
quiet "$bin" dataset prepare "$out/gen" --model transformer
quiet "$bin" train "$out/gen" --out "$out/run" --epochs 1 --validation 0.34 --generated 512
if [ -n "$ur10e" ]; then
  mkdir -p "$out/ur10e"
  sed -n 635,3510p "$ur10e/dataset_ur10e/identification_data/ur-20_02_10-30sec_12harm.csv" > "$out/ur10e/a.csv"
  sed -n 320,2310p "$ur10e/dataset_ur10e/identification_data/ur-20_02_05-20sec_8harm.csv" > "$out/ur10e/b.csv"
  {
    echo 'bad_rows = "skip"'
    echo 'time = { column = 1, unit = "s" }'
    gains=(10.0000 10.6956 8.4566 9.0029 9.4800 10.1232)
    joints=(shoulder_pan_joint shoulder_lift_joint elbow_joint wrist_1_joint wrist_2_joint wrist_3_joint)
    for k in 0 1 2 3 4 5; do
      printf '[joints.%s]\nposition = %d\nvelocity = %d\ncurrent = %d\ngain = %s\n' \
        "${joints[$k]}" $((k + 2)) $((k + 8)) $((k + 14)) "${gains[$k]}"
    done
  } > "$out/ur10e/columns.toml"
  "$bin" identify "$out/ur10e/a.csv" "$out/ur10e/b.csv" --urdf "$ur10e/URe/urdf/ur10e.urdf" \
    --columns "$out/ur10e/columns.toml" --out "$out/ur10e/cal.urdf" --mjcf "$out/ur10e/cal.xml" --json \
    > "$out/ur10e/cal.json" 2> "$out/log.txt"
  rm "$out/ur10e/a.csv" "$out/ur10e/b.csv"
fi
rm "$out/log.txt"
cd "$out"
find . -type f ! -path './*/logs/*' ! -name ledger.tsv ! -name lock ! -name 'metrics*' ! -name state.json \
  ! -name checkpoint.json ! -name last.bpk ! -name optimizer.bin | sort |
  while read -r f; do echo "$(sha256sum "$f" | cut -c1-16) $f"; done
