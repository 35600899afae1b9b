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
# No service starts at installation (munge's, slurmctld's init scripts...): the deploy scripts start the daemons they
# need themselves, and stop exactly those. A policy-rc.d of the host's own is left as it is.
if [ ! -e /usr/sbin/policy-rc.d ]; then
    printf '#!/bin/sh\n# dynforge deploy/apt-install.sh: no service starts while it installs\nexit 101\n' \
        >/usr/sbin/policy-rc.d
    chmod 755 /usr/sbin/policy-rc.d
    trap 'rm -f /usr/sbin/policy-rc.d' EXIT
fi
apt install -y -qq --no-install-recommends "${missing[@]}" ||
    { apt update -qq && apt install -y -qq --no-install-recommends "${missing[@]}"; }
