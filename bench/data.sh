#!/usr/bin/env bash
# Trainer data pipeline throughput: windows/s built from shards (cold) and read from the cache, next to the model's
# consumption on this machine. Generates an 8-robot dataset into bench/out/data8 first if it is not there.
# Usage: bench/data.sh [LEN:STRIDE:SSR=64:64:16]
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
cd "$root"
# The whole workspace, not `-p ...`: a package selection unifies other features and rebuilds burn.
cargo build --release -q --workspace
bin=${CARGO_TARGET_DIR:-$root/target}/release
mkdir -p bench/out
[ -f bench/out/data8/ledger.tsv ] || "$bin/dynforge" generate --out bench/out/data8 --robots 8 --seed 0 >/dev/null
"$bin/dynforge-bench-data" bench/out/data8 "${1:-64:64:16}"
