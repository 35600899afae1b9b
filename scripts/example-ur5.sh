#!/usr/bin/env bash
# A real arm calibrated end to end, on logs anyone can make: example-robot-data's UR5 simulated by MuJoCo with known
# joint friction, logged as a driver writes it (a 1 kHz ROS 2 bag: 1 % effort noise, 2^17-count encoders, velocity
# from encoder differences), and a "nominal" URDF whose every link mass, centre of mass and inertia is 20-30 % off and
# which states no friction, as a user's URDF is. `dynforge identify` calibrates the nominal URDF to the bag and
# scores it on a second motion it never saw.
#
# Usage: scripts/example-ur5.sh [OUT]   (default OUT: dynforge-ur5/; needs Python 3 with venv, like the tests)
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
out=$(mkdir -p "${1:-dynforge-ur5}" && cd "${1:-dynforge-ur5}" && pwd)
py=$("$root/scripts/venv.sh")
harness=$root/tests/reference/simulate_arm.py
urdf=$("$py" "$harness" --path ur5)
# The friction MuJoCo simulates (Coulomb N m, viscous N m s/rad): what identify should find.
friction='{"shoulder_pan_joint": [5.0, 4.0], "shoulder_lift_joint": [6.0, 5.0], "elbow_joint": [4.0, 3.0],
  "wrist_1_joint": [1.5, 1.0], "wrist_2_joint": [1.2, 0.8], "wrist_3_joint": [1.0, 0.5]}'
echo "simulating the UR5 in MuJoCo into $out ..." >&2
echo "{\"urdf\": \"$urdf\", \"seed\": 3, \"low\": 0.2, \"high\": 0.3, \"out\": \"$out/nominal.urdf\"}" |
  "$py" "$harness" --perturb >/dev/null
echo "{\"urdf\": \"$urdf\", \"friction\": $friction, \"seed\": 1, \"duration\": 30, \"rate\": 1000,
  \"effort\": \"held\", \"noise\": 0.01, \"counts\": 131072, \"velocity\": \"encoder\", \"out\": \"$out/ur5.mcap\"}" |
  "$py" "$harness" >/dev/null
echo "{\"urdf\": \"$urdf\", \"friction\": $friction, \"seed\": 2, \"duration\": 20, \"rate\": 1000,
  \"effort\": \"held\", \"out\": \"$out/held-out.mcap\"}" | "$py" "$harness" >/dev/null
cd "$root"
cargo run --release --quiet -- identify "$out/ur5.mcap" --urdf "$out/nominal.urdf" --effort held \
  --holdout "$out/held-out.mcap" --out "$out/ur5.calibrated.urdf"
echo "true friction (MuJoCo's): $friction" | tr -s ' \n' ' '
echo
