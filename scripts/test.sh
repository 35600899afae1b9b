#!/usr/bin/env bash
# The project's test command (what CI runs): sets up the Python venv with the independent reference tools
# (Pinocchio, example-robot-data), then runs every Rust test with those references required.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
DYNFORGE_PYTHON=$(scripts/venv.sh)
export DYNFORGE_PYTHON
export DYNFORGE_REQUIRE_REFERENCE=1
cargo test --workspace --locked "$@"
