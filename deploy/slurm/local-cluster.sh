#!/usr/bin/env bash
# A real single-node Slurm cluster on this machine, for trying the batch scripts (and for the deploy tests, which run
# it in a private namespace): installs Debian's slurm-wlm and munge if absent, writes a one-node slurm.conf (this
# host, all its CPUs), starts munged, slurmctld and slurmd, and waits until the node is idle. Needs root.
#
#   local-cluster.sh up       idempotent: a cluster it started and still runs is left as it is
#   local-cluster.sh down     stops exactly the daemons `up` started (their pids are recorded), munged included
#   local-cluster.sh status   the node's state and which daemons are this script's
#
# It never takes over a Slurm it did not set up: `up` refuses (exit 3, nothing changed) when /etc/slurm/slurm.conf
# exists without the marker line this script writes first, or when a slurmctld or slurmd it did not start runs and
# would have to be restarted. A slurm.conf it replaces (its own, older) is first copied to $state/backup/. Its state
# (pid files, backups) is in /var/lib/dynforge-local-cluster.
set -euo pipefail
action=${1:-up}
conf_dir=/etc/slurm
conf=$conf_dir/slurm.conf
state=/var/lib/dynforge-local-cluster
marker="# dynforge-local-cluster: written by deploy/slurm/local-cluster.sh (pids of the daemons it started: $state)"
node=$(hostname -s)

say() { echo "local-cluster: $*" >&2; }
refuse() {
    say "$*"
    say "refusing: nothing was changed"
    exit 3
}

node_state() { sinfo -h -n "$node" -o %T 2>/dev/null | head -1; }

# The pid of daemon $1 if this script started it and it still runs, else nothing.
ours() {
    local pid
    pid=$(cat "$state/$1.pid" 2>/dev/null) || return 0
    [ "$(cat "/proc/$pid/comm" 2>/dev/null)" = "$1" ] && echo "$pid"
    return 0
}
# The pids of processes named $1 that this script did not start.
others() { pgrep -x "$1" | grep -vx "$(ours "$1")" || true; }

# Records the pid of daemon $1 from the pid file $2 it writes once it runs.
record() {
    local pid=""
    for _ in $(seq 1 100); do
        pid=$(cat "$2" 2>/dev/null || true)
        [ -n "$pid" ] && [ "$(cat "/proc/$pid/comm" 2>/dev/null)" = "$1" ] && break
        pid=""
        sleep 0.1
    done
    [ -n "$pid" ] || { say "$1 did not start (no live pid in $2; see its log)"; exit 1; }
    echo "$pid" >"$state/$1.pid"
    say "started $1 (pid $pid)"
}

# Stops daemon $1 if this script started it (SIGTERM, then SIGKILL after 15 s).
stop() {
    local pid
    pid=$(ours "$1")
    if [ -n "$pid" ]; then
        kill -TERM "$pid" 2>/dev/null || true
        for _ in $(seq 1 150); do
            [ -d "/proc/$pid" ] || break
            sleep 0.1
        done
        if [ -d "/proc/$pid" ]; then
            say "$1 (pid $pid) ignored SIGTERM for 15 s: SIGKILL"
            kill -KILL "$pid" 2>/dev/null || true
        fi
        say "stopped $1 (pid $pid)"
    fi
    rm -f "$state/$1.pid"
    local left
    left=$(others "$1" | tr '\n' ' ')
    [ -z "$left" ] || say "left running: $1 pid ${left% } (not started by this script)"
}

# Whether $conf was written by this script: its marker line first, or (an earlier version of it, without the
# marker) this script's cluster name.
written_here() {
    [ "$(head -1 "$conf")" = "$marker" ] || grep -qx 'ClusterName=dynforge-local' "$conf"
}

case "$action" in
status)
    echo "node $node: $(node_state || true)"
    for d in munged slurmctld slurmd; do
        pid=$(ours "$d")
        if [ -n "$pid" ]; then echo "$d: pid $pid (started by this script)"; fi
        for o in $(others "$d"); do echo "$d: pid $o (not started by this script)"; done
    done
    exit 0
    ;;
down)
    for d in slurmd slurmctld munged; do stop "$d"; done
    exit 0
    ;;
up) ;;
*)
    echo "usage: $0 up | down | status" >&2
    exit 2
    ;;
esac

if [ "$(id -u)" != 0 ]; then
    say "needs root (installs packages and starts daemons)"
    exit 77
fi
if [ -e "$conf" ] && ! written_here; then
    refuse "$conf was not written by this script (its first line is not '$marker'): this host has a Slurm" \
        "configuration of its own. Submit to that cluster directly (deploy/slurm/submit.sh), or move the file away."
fi
if ! command -v slurmctld >/dev/null || ! command -v munged >/dev/null; then
    say "installing slurm-wlm and munge"
    "$(dirname "$0")/../apt-install.sh" slurm-wlm munge
fi
mkdir -p "$state/backup"

# One node: this host with all its CPUs. Process tracking by /proc and no task plugin, so no cgroup or systemd is
# needed (a container or a VM without them runs it too); no accounting database.
mkdir -p "$conf_dir" /var/spool/slurmctld /var/spool/slurmd /var/log/slurm
new=$(mktemp "$conf_dir/.slurm.conf.XXXXXX")
trap 'rm -f "$new"' EXIT
cat >"$new" <<CONF
$marker
ClusterName=dynforge-local
SlurmctldHost=$node
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/none
JobCompType=jobcomp/none
MpiDefault=none
ReturnToService=2
StateSaveLocation=/var/spool/slurmctld
SlurmdSpoolDir=/var/spool/slurmd
SlurmctldLogFile=/var/log/slurm/slurmctld.log
SlurmdLogFile=/var/log/slurm/slurmd.log
SlurmctldPidFile=/run/slurmctld.pid
SlurmdPidFile=/run/slurmd.pid
NodeName=$node CPUs=$(nproc) State=UNKNOWN
PartitionName=local Nodes=$node Default=YES MaxTime=INFINITE State=UP
CONF
chmod 644 "$new"
settings() { grep -v '^#' "$1" 2>/dev/null; }
if [ -e "$conf" ] && cmp -s "$new" "$conf"; then
    changed=no
elif [ -e "$conf" ] && [ "$(settings "$new")" = "$(settings "$conf")" ]; then
    changed=comments
else
    changed=settings
fi
# Daemons running with another configuration are restarted, and only this script's own.
if [ "$changed" = settings ]; then
    for d in slurmctld slurmd; do
        o=$(others "$d" | tr '\n' ' ')
        [ -z "$o" ] || refuse "$d (pid ${o% }) runs and was not started by this script: it would have to be" \
            "restarted with the new $conf. Stop it yourself first."
    done
fi
if [ "$changed" != no ]; then
    if [ -e "$conf" ]; then
        backup=$state/backup/slurm.conf.$(date +%Y%m%dT%H%M%S).$$
        cp -p "$conf" "$backup"
        say "replacing $conf (the previous one is in $backup)"
    fi
    mv "$new" "$conf"
fi
if [ "$changed" = settings ]; then
    stop slurmd
    stop slurmctld
fi

# munge: the key (created only when there is none), then the daemon as its own user (or the one already running).
if [ ! -s /etc/munge/munge.key ]; then
    mungekey --create >&2
    chown munge:munge /etc/munge/munge.key
    chmod 400 /etc/munge/munge.key
fi
mkdir -p /run/munge && chown munge:munge /run/munge
if [ -z "$(ours munged)" ] && [ -z "$(others munged)" ]; then
    rm -f /run/munge/munged.pid
    runuser -u munge -- /usr/sbin/munged --pid-file=/run/munge/munged.pid
    record munged /run/munge/munged.pid
fi
if [ -z "$(ours slurmctld)" ] && [ -z "$(others slurmctld)" ]; then
    rm -f /run/slurmctld.pid
    slurmctld
    record slurmctld /run/slurmctld.pid
fi
if [ -z "$(ours slurmd)" ] && [ -z "$(others slurmd)" ]; then
    rm -f /run/slurmd.pid
    slurmd
    record slurmd /run/slurmd.pid
fi

for _ in $(seq 1 60); do
    case "$(node_state)" in
    idle* | mix* | alloc*)
        say "node $node is up ($(node_state))"
        exit 0
        ;;
    down* | drain*)
        scontrol update nodename="$node" state=resume >/dev/null 2>&1 || true
        ;;
    esac
    sleep 1
done
say "the node did not come up; see /var/log/slurm/slurmctld.log and slurmd.log"
exit 1
