#!/usr/bin/env bash
# The project's test command (what CI runs): sets up the Python venv with the independent reference tools
# (Pinocchio, example-robot-data), then runs every Rust test with those references required. The deploy engine tests
# (a real Slurm, podman, docker: they install packages and start daemons, and stop them) run only with
# DYNFORGE_ENGINE_TESTS=1, which .ci/run sets (deploy/README.md); without it they skip and the machine is left as is.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
DYNFORGE_PYTHON=$(scripts/venv.sh)
export DYNFORGE_PYTHON
export DYNFORGE_REQUIRE_REFERENCE=1
# `train --device cuda` compiles: the CUDA backend is type-checked (no GPU here to run it). Its build script would
# download an LLVM bundle (tracel-llvm-bundler) from outside the package registries; DOCS_RS=1 skips that download as
# docs.rs builds do, which a check does not need. A real CUDA build needs that network access once.
DOCS_RS=1 cargo check --locked -p dynforge --features cuda
cargo test --workspace --locked "$@"
