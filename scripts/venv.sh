#!/usr/bin/env bash
# Creates (or reuses) the Python venv holding the independent reference tools the tests and benchmarks compare
# against (Pinocchio, example-robot-data, ...). Prints the venv's python path on stdout.
# DYNFORGE_VENV overrides the location (default: .venv in the repository).
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
venv=${DYNFORGE_VENV:-$root/.venv}
req=$root/scripts/requirements.txt
stamp=$venv/.requirements.sha256
want=$(sha256sum "$req" | cut -d' ' -f1)
if [ ! -x "$venv/bin/python" ] || [ "$(cat "$stamp" 2>/dev/null)" != "$want" ]; then
  echo "venv: installing reference tools into $venv" >&2
  python3 -m venv "$venv" >&2
  "$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r "$req" >&2
  echo "$want" > "$stamp"
fi
echo "$venv/bin/python"
