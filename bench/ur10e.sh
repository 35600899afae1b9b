#!/usr/bin/env bash
# A real arm: `dynforge identify` on a UR10e's public logs (github shamilmamedov/dynamic_calibration, dataset_ur10e/),
# read as their CSV tables come, with the repository's drive gains, no conversion step. The data carry no licence:
# they are read from your checkout and never copied into this repository; the trimmed copies go to OUT.
#
# Identifies the four unloaded excitation logs that the repository's main.m names (trimmed to its index ranges), holds
# out the point-to-point motion (rows 700-4200), and prints identify's tables, its held-out torque NRMSE beside the URDF
# as given and least squares, its link masses beside UR's published ones, whether the 50 s log's identification and
# the other three's agree within their spreads, and one independent held-out measure (bench/ur10e_least_squares.py:
# Pinocchio, its own filtering) of identify's calibration, least squares, the repository's published parameters and
# the URDF as given.
#
# Usage: bench/ur10e.sh CHECKOUT [OUT=bench/out/ur10e] [identify flags...]
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
repo=$(cd "${1:?usage: bench/ur10e.sh CHECKOUT_OF_dynamic_calibration [OUT] [identify flags]}" && pwd)
out=${2:-$root/bench/out/ur10e}
shift $(( $# >= 2 ? 2 : 1 ))
mkdir -p "$out"
cd "$root"
cargo build --release -q --workspace
bin=${CARGO_TARGET_DIR:-$root/target}/release

# Rows as main.m takes them (1-based, inclusive): the motion, without the rest before and after.
trim() { sed -n "$2,$3p" "$repo/dataset_ur10e/$1" > "$out/$(basename "$1")"; }
trim identification_data/ur-20_02_10-30sec_12harm.csv 635 3510
trim identification_data/ur-20_02_12-40sec_12harm.csv 500 4460
trim identification_data/ur-20_02_05-20sec_8harm.csv 320 2310
trim identification_data/ur-20_02_12-50sec_12harm.csv 355 5090
trim validation_data/ur-20_01_17-ptp_10_points.csv 700 4200

# Columns (utils/data_processing/parseURData.m): t, q1..6, qd1..6, motor current i1..6 [A], target currents, target
# torques. Gains: UR10E_parameters.txt's drvGains [N m / A]. Some rows are torn (fewer columns): skipped and counted.
gains=(10.0000 10.6956 8.4566 9.0029 9.4800 10.1232)
joints=(shoulder_pan_joint shoulder_lift_joint elbow_joint wrist_1_joint wrist_2_joint wrist_3_joint)
{
  echo 'bad_rows = "skip"'
  echo 'time = { column = 1, unit = "s" }'
  for k in 0 1 2 3 4 5; do
    printf '[joints.%s]\nposition = %d\nvelocity = %d\ncurrent = %d\ngain = %s\n' \
      "${joints[$k]}" $((k + 2)) $((k + 8)) $((k + 14)) "${gains[$k]}"
  done
} > "$out/ur10e.columns.toml"

logs=("$out"/ur-20_02_10-30sec_12harm.csv "$out"/ur-20_02_12-40sec_12harm.csv "$out"/ur-20_02_05-20sec_8harm.csv
  "$out"/ur-20_02_12-50sec_12harm.csv)
"$bin/dynforge" info "${logs[0]}" --columns "$out/ur10e.columns.toml"
"$bin/dynforge" identify "${logs[@]}" --urdf "$repo/URe/urdf/ur10e.urdf" --columns "$out/ur10e.columns.toml" \
  --holdout "$out/ur-20_01_17-ptp_10_points.csv" --out "$out/ur10e.calibrated.urdf" --mjcf "$out/ur10e.calibrated.xml" \
  "$@" | tee "$out/identify.txt"
echo
echo "UR's published masses [kg]: shoulder 7.369, upper arm 13.051, forearm 3.989, wrist 1 2.1, wrist 2 1.98, wrist 3 0.615"
py=$(scripts/venv.sh)

# The 50 s log against the other three: do two identifications of one arm agree within their printed spreads (friction
# and offsets: their spreads over runs)? The three's identification measures friction's run-to-run share between them
# (each identified alone: `--run-to-run measured`, the default), and the 50 s log takes that share: out of sample.
one() { "$bin/dynforge" identify "$@" --urdf "$repo/URe/urdf/ur10e.urdf" --columns "$out/ur10e.columns.toml" --json; }
one "${logs[@]:0:3}" --out "$out/three.urdf" > "$out/three.json"
share=$("$py" -c 'import json, sys; print(json.load(open(sys.argv[1]))["run_to_run"])' "$out/three.json")
echo "friction's run-to-run share measured between the three logs: $share"
one "${logs[3]}" --out "$out/50s.urdf" --run-to-run "$share" > "$out/50s.json"
"$py" - "$out/50s.json" "$out/three.json" <<'EOF'
import json, math, sys
def estimates(path):
    r = json.load(open(path))
    out = {}
    for link in r["links"]:
        out[link["name"] + ".mass"] = link["mass"]
        out.update({f"{link['name']}.com_{k}": e for k, e in zip("xyz", link["com"])})
        out.update({f"{link['name']}.{k}": e for k, e in zip(["ixx", "ixy", "ixz", "iyy", "iyz", "izz"], link["inertia"])})
    for joint in r["joints"]:
        out.update({f"{joint['name']}.{k}": joint[k] for k in ["coulomb", "viscous", "armature", "offset"]})
    return out
a, b = estimates(sys.argv[1]), estimates(sys.argv[2])
apart = []
for name, x in a.items():
    y = b[name]
    d = math.log(x["value"] / y["value"]) if x["scale"] == "log" else x["value"] - y["value"]
    # Friction and offsets over runs (the logs are runs of other days), the rest as the run's own.
    z = d / math.hypot(x.get("over_runs", x["std"]), y.get("over_runs", y["std"]))
    if abs(z) > 2:
        apart.append(f"{name} ({z:+.1f})")
print(f"50 s log against the other three: {len(a) - len(apart)} of {len(a)} parameters within two standard deviations "
      f"(of their difference); apart: {', '.join(apart) or 'none'}")
EOF

# The same logs as ROS 2 bags, MCAP (mcap_ros2's writer) and Humble's sqlite3 (rosbags): the same URDF and JSON.
columns='"shoulder_pan_joint": [2, 8, 14], "shoulder_lift_joint": [3, 9, 15], "elbow_joint": [4, 10, 16],
  "wrist_1_joint": [5, 11, 17], "wrist_2_joint": [6, 12, 18], "wrist_3_joint": [7, 13, 19]'
gain_map=$(for k in 0 1 2 3 4 5; do printf '"%s": %s,' "${joints[$k]}" "${gains[$k]}"; done)
run() { "$bin/dynforge" identify "$@" --urdf "$repo/URe/urdf/ur10e.urdf" --json; }
for log in "${logs[@]}"; do
  name=$(basename "$log" .csv)
  echo "{\"mcap\": \"$out/$name.mcap\", \"db3\": \"$out/${name}_db3\", \"table\": {\"path\": \"$log\", \"time\": 1,
    \"joints\": {$columns}, \"gains\": {${gain_map%,}}}}" | "$py" tests/reference/convert_log.py > /dev/null
done
run "${logs[@]}" --columns "$out/ur10e.columns.toml" --out "$out/csv.urdf" > "$out/csv.json"
run "${logs[@]/%.csv/.mcap}" --out "$out/mcap.urdf" > "$out/mcap.json"
run "${logs[@]/%.csv/_db3}" --out "$out/db3.urdf" > "$out/db3.json"
"$py" - "$out" <<'EOF'
import json, sys
out = sys.argv[1]
def result(form):
    r = json.load(open(f"{out}/{form}.json"))
    # What names the files is the one thing a form changes.
    r.pop("logs"), r.pop("urdf")
    r["notes"] = [n.split(": ", 1)[1] for n in r["notes"]]
    return r, open(f"{out}/{form}.urdf", "rb").read()
csv = result("csv")
for form in ["mcap", "db3"]:
    same = result(form) == csv
    print(f"{form} bag against the CSV tables: URDF and JSON {'byte-identical' if same else 'DIFFERENT'}")
EOF

# One independent measure for every model: identify's calibration (its URDF and JSON, four logs), least squares, the
# repository's published parameters and the URDF as given, each scored by the Pinocchio script's own filtering.
echo
echo "independent held-out measure (bench/ur10e_least_squares.py: Pinocchio, its own filtering):"
"$py" bench/ur10e_least_squares.py "$repo" --calibrated "$out/csv.urdf" "$out/csv.json"
