#!/usr/bin/env bash
# Builds the dynforge container image with podman (or docker) from the release binary:
#   deploy/container/build.sh [--tag dynforge:latest] [--binary PATH] [--offline-base] [--install]
# --binary takes a dynforge binary already built (default: cargo build --release). --offline-base makes the Debian
# base with debootstrap from the Debian mirror instead of pulling it from a container registry (for machines that
# reach Debian but no registry); it is cached as image dynforge-base:bookworm. --install apt-installs podman, runc and
# debootstrap when missing (root). With podman, the OCI runtime is runc when present (DYNFORGE_OCI_RUNTIME overrides):
# crun cannot set rlimits in some VMs. Prints the tag.
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
tag=dynforge:latest offline=0 binary="" install=0
while [ $# -gt 0 ]; do
    case "$1" in
    --tag) tag=$2; shift 2 ;;
    --binary) binary=$2; shift 2 ;;
    --offline-base) offline=1; shift ;;
    --install) install=1; shift ;;
    *) echo "build.sh: unknown option $1" >&2; exit 2 ;;
    esac
done
if [ "$install" = 1 ] && ! { command -v podman && command -v runc && command -v debootstrap; } >/dev/null; then
    [ "$(id -u)" = 0 ] || { echo "build.sh: --install needs root" >&2; exit 77; }
    "$root/deploy/apt-install.sh" podman runc debootstrap
fi
engine=$(command -v podman || command -v docker || true)
if [ -z "$engine" ]; then
    echo "build.sh: needs podman or docker" >&2
    exit 77
fi
if [ "$(basename "$engine")" = podman ]; then
    runtime=${DYNFORGE_OCI_RUNTIME:-$(command -v runc || true)}
    [ -z "$runtime" ] || engine="$engine --runtime $runtime"
fi
if [ -z "$binary" ]; then
    (cd "$root" && cargo build --release --locked --bin dynforge >&2)
    binary=${CARGO_TARGET_DIR:-$root/target}/release/dynforge
fi
context=$(mktemp -d)
trap 'rm -rf "$context"' EXIT
cp "$binary" "$context/dynforge"
cp "$root/deploy/container/Containerfile" "$context/"
base_args=()
if [ "$offline" = 1 ]; then
    if ! $engine image exists dynforge-base:bookworm 2>/dev/null; then
        command -v debootstrap >/dev/null || { echo "build.sh: --offline-base needs debootstrap" >&2; exit 77; }
        rootfs=$(mktemp -d)
        debootstrap --variant=minbase bookworm "$rootfs" http://deb.debian.org/debian >&2
        tar -C "$rootfs" -c . | $engine import - dynforge-base:bookworm >&2
        rm -rf "$rootfs"
    fi
    base_args=(--build-arg BASE=localhost/dynforge-base:bookworm)
fi
$engine build "${base_args[@]}" -t "$tag" -f "$context/Containerfile" "$context" >&2
echo "$tag"
