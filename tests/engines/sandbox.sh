#!/usr/bin/env bash
# A private "host" for the Slurm engine tests: run as the first process of new mount, UTS, IPC, network and PID
# namespaces (tests/deploy.rs starts it with `unshare ... --kill-child`), it hides the host's Slurm and munge state
# behind empty tmpfs mounts (/etc/slurm, /etc/munge, /run, /var/spool, /var/log, /var/lib), names the host
# `dfnode` (127.0.0.1 on a loopback of its own), writes $1 once ready, and then only reaps orphans until it is
# killed. deploy/slurm/local-cluster.sh then sets up its cluster here as on a fresh machine, the host's own Slurm
# (running or not) is never touched, and every daemon of the sandbox dies with it (the PID namespace ends).
# Commands enter it with `nsenter --target PID --mount --uts --ipc --net --pid`.
set -euo pipefail
ready=${1:?usage: sandbox.sh READY_FILE}
[ "$$" = 1 ] || { echo "sandbox.sh: must be PID 1 of a new PID namespace (unshare --pid --fork)" >&2; exit 2; }
hostname dfnode
ip link set lo up
# A second loopback address: getaddrinfo(AI_ADDRCONFIG), which Slurm uses, finds no IPv4 address where 127.0.0.1
# is the only one.
ip addr add 127.0.0.2/8 dev lo
for d in /etc/slurm /etc/munge /run /var/spool /var/log /var/lib; do
    mkdir -p "$d"
    mount -t tmpfs -o mode=755 sandbox "$d"
done
printf '127.0.0.1 localhost dfnode\n::1 localhost\n' >/run/sandbox-hosts
mount --bind /run/sandbox-hosts /etc/hosts
mkdir -p /run/lock /var/lib/munge /var/log/munge /var/spool/slurmd /var/spool/slurmctld
chown munge:munge /etc/munge /var/lib/munge /var/log/munge
chmod 700 /etc/munge /var/lib/munge /var/log/munge
echo ready >"$ready"
# PID 1: orphans (job steps, daemons' children) are reparented here; `wait` reaps them.
trap 'exit 0' TERM INT
while :; do
    sleep 1 &
    wait $! || true
done
