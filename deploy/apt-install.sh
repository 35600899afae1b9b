#!/usr/bin/env bash
# Installs Debian packages for the deploy scripts, one installer at a time: the Slurm cluster and the container build
# may be set up at once (the tests do), and two apt-get runs side by side fail on dpkg's lock or on each other's
# downloaded archives. Needs root. Usage: apt-install.sh PACKAGE...
set -euo pipefail
export DEBIAN_FRONTEND=noninteractive
apt() { apt-get -o DPkg::Lock::Timeout=600 "$@" >&2; }
exec 9>/var/lock/dynforge-apt.lock
flock 9
# Another installer may have installed them while this one waited.
missing=()
for p in "$@"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
[ ${#missing[@]} = 0 ] && exit 0
apt install -y -qq --no-install-recommends "${missing[@]}" ||
    { apt update -qq && apt install -y -qq --no-install-recommends "${missing[@]}"; }
