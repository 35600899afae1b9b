#!/usr/bin/env bash
# A real single-node Slurm cluster on this machine, for the deploy tests and for trying the batch scripts:
# installs Debian's slurm-wlm and munge if absent, writes a one-node slurm.conf (this host, all its CPUs), starts
# munged, slurmctld and slurmd, and waits until the node is idle. Idempotent: a running cluster is left as it is.
# Needs root (package installation, daemons). Usage: local-cluster.sh up | down | status
set -euo pipefail
action=${1:-up}
conf_dir=/etc/slurm
node=$(hostname -s)

say() { echo "local-cluster: $*" >&2; }

node_state() { sinfo -h -n "$node" -o %T 2>/dev/null | head -1; }

case "$action" in
status)
    node_state
    exit 0
    ;;
down)
    pkill -x slurmd || true
    pkill -x slurmctld || true
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
if ! command -v slurmctld >/dev/null || ! command -v munged >/dev/null; then
    say "installing slurm-wlm and munge"
    "$(dirname "$0")/../apt-install.sh" slurm-wlm munge
fi

# munge: the key, then the daemon as its own user.
if [ ! -s /etc/munge/munge.key ]; then
    mungekey --create --force >&2
    chown munge:munge /etc/munge/munge.key
    chmod 400 /etc/munge/munge.key
fi
mkdir -p /run/munge && chown munge:munge /run/munge
if ! pgrep -x munged >/dev/null; then
    runuser -u munge -- /usr/sbin/munged
fi

# One node: this host with all its CPUs. Process tracking by /proc and no task plugin, so no cgroup or systemd is
# needed (a container or a VM without them runs it too); no accounting database.
mkdir -p "$conf_dir" /var/spool/slurmctld /var/spool/slurmd /var/log/slurm
cat >"$conf_dir/slurm.conf.new" <<CONF
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
if ! cmp -s "$conf_dir/slurm.conf.new" "$conf_dir/slurm.conf" 2>/dev/null; then
    mv "$conf_dir/slurm.conf.new" "$conf_dir/slurm.conf"
    pkill -x slurmd || true
    pkill -x slurmctld || true
    sleep 1
else
    rm "$conf_dir/slurm.conf.new"
fi
pgrep -x slurmctld >/dev/null || slurmctld
pgrep -x slurmd >/dev/null || slurmd

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
