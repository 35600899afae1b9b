#!/usr/bin/env bash
# Builds the dynforge container image with podman or docker from the release binary:
#   deploy/container/build.sh [--tag dynforge:latest] [--binary PATH] [--engine podman|docker] [--offline-base]
#                             [--install]
# --binary takes a dynforge binary already built (default: cargo build --release). --engine chooses the engine
# (default: podman when installed, else docker). --offline-base makes the Debian base with debootstrap from the Debian
# mirror instead of pulling it from a container registry (for machines that reach Debian but no registry), without
# apt's downloaded archives and lists; it is cached as image dynforge-base:bookworm-min (localhost/... in podman).
# --install apt-installs what the build needs when missing (root): podman and runc unless --engine docker, and
# debootstrap with --offline-base. With podman, the OCI runtime is runc when
# present (DYNFORGE_OCI_RUNTIME overrides): crun cannot set rlimits in some VMs; and the build's rlimits are given
# (nofile: the host's hard limit; nproc 4096): podman's defaults exceed a low hard limit, which runc then refuses.
# Prints the tag.
# deploy/README.md says how to push the image to a registry for a cluster.
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
tag=dynforge:latest offline=0 binary="" install=0 engine_name=""
die() {
    echo "build.sh: $*" >&2
    exit "${2:-2}"
}
while [ $# -gt 0 ]; do
    case "$1" in
    --tag | --binary | --engine) [ $# -ge 2 ] || die "$1 needs a value" ;;
    esac
    case "$1" in
    --tag) tag=$2; shift 2 ;;
    --binary) binary=$2; shift 2 ;;
    --engine) engine_name=$2; shift 2 ;;
    --offline-base) offline=1; shift ;;
    --install) install=1; shift ;;
    *) die "unknown option $1 (see the header of $0)" ;;
    esac
done
case "$engine_name" in
"" | podman | docker) ;;
*) die "--engine must be podman or docker, not '$engine_name'" ;;
esac
if [ "$install" = 1 ]; then
    # What this build needs: podman and runc unless docker is named, debootstrap for an offline base.
    wanted=()
    [ "$engine_name" = docker ] || wanted+=(podman runc)
    [ "$offline" = 0 ] || wanted+=(debootstrap)
    if [ "$(id -u)" = 0 ]; then
        # Through the installer even when the commands are on PATH: it waits for another installer that may be
        # unpacking them right now, and returns at once when dpkg has them installed.
        [ ${#wanted[@]} = 0 ] || "$root/deploy/apt-install.sh" "${wanted[@]}"
    else
        for p in "${wanted[@]}"; do command -v "$p" >/dev/null || die "--install needs root to install $p" 77; done
    fi
fi
if [ -z "$engine_name" ]; then
    if command -v podman >/dev/null; then engine_name=podman; elif command -v docker >/dev/null; then engine_name=docker; fi
fi
if [ -z "$engine_name" ] || ! command -v "$engine_name" >/dev/null; then die "needs ${engine_name:-podman or docker}" 77; fi
engine=("$engine_name")
build_opts=()
if [ "$engine_name" = podman ]; then
    runtime=${DYNFORGE_OCI_RUNTIME:-$(command -v runc || true)}
    [ -z "$runtime" ] || engine+=(--runtime "$runtime")
    build_opts+=(--ulimit "nofile=$(ulimit -Hn):$(ulimit -Hn)" --ulimit nproc=4096:4096)
    # podman names an imported image localhost/NAME; docker keeps NAME (a "localhost/" prefix would be a registry).
    base=localhost/dynforge-base:bookworm-min
else
    base=dynforge-base:bookworm-min
fi
if [ -z "$binary" ]; then
    (cd "$root" && cargo build --release --locked --bin dynforge >&2)
    binary=${CARGO_TARGET_DIR:-$root/target}/release/dynforge
fi
[ -f "$binary" ] || die "--binary $binary: no such file"
context=$(mktemp -d)
rootfs=""
trap 'rm -rf "$context" ${rootfs:+"$rootfs"}' EXIT
cp "$binary" "$context/dynforge"
cp "$root/deploy/container/Containerfile" "$context/"
base_args=()
if [ "$offline" = 1 ]; then
    if "${engine[@]}" image inspect "$base" >/dev/null 2>&1; then
        echo "build.sh: using the cached base image $base" >&2
    else
        command -v debootstrap >/dev/null || die "--offline-base needs debootstrap (or --install)" 77
        rootfs=$(mktemp -d)
        debootstrap --variant=minbase bookworm "$rootfs" http://deb.debian.org/debian >&2
        # An image has no use for apt's downloaded packages and lists (~80 MB): apt-get update brings them back.
        rm -rf "$rootfs"/var/cache/apt/archives/*.deb "$rootfs"/var/cache/apt/*.bin "$rootfs"/var/lib/apt/lists/*
        mkdir -p "$rootfs"/var/lib/apt/lists/partial
        tar -C "$rootfs" -c . | "${engine[@]}" import - "$base" >&2
        rm -rf "$rootfs"
        echo "build.sh: made the base image $base with debootstrap" >&2
    fi
    base_args=(--build-arg "BASE=$base")
fi
"${engine[@]}" build "${build_opts[@]}" "${base_args[@]}" -t "$tag" -f "$context/Containerfile" "$context" >&2
echo "$tag"
