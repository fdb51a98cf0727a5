#!/usr/bin/env bash
# A one-node SLURM cluster on this machine, for the cluster test (tests/workflow/test_slurm_cluster.py)
# and for trying the SLURM profile without a cluster (docs/jobs/cluster.md). Needs root.
#
#   scripts/slurm_one_node.sh install       apt-get install slurm-wlm and munge, if missing
#   scripts/slurm_one_node.sh start DIR     write DIR/slurm.conf, start munged, slurmctld and slurmd
#                                           (their ids in DIR/run/*.pid), wait until the node is idle
#   scripts/slurm_one_node.sh stop DIR      cancel the cluster's jobs, stop its daemons by their ids
#
# Everything lives under DIR: configuration, munge key and socket, state, spool, logs (DIR/log).
# The one file outside it is the link /etc/slurm/slurm.conf -> DIR/slurm.conf (removed by stop),
# where SLURM's commands look when SLURM_CONF is not set: the SLURM executor plugin's job step
# drops SLURM_CONF before its `srun`, so the configuration must be at the default path. A machine
# with a SLURM configuration of its own is left alone (start refuses).
# The node is this machine's host name with the CPUs and memory `slurmd -C` reads from it;
# select/cons_tres with cores and memory as consumables, proctrack/linuxproc, task/none, no
# accounting storage (so `sacct` cannot answer), MinJobAge 300 s (squeue shows a finished job
# for 5 minutes). Ports are free ones chosen at start (override: SLURM_ONE_NODE_PORTS="6817 6818").
set -euo pipefail

DEFAULT_CONF=/etc/slurm/slurm.conf
MARK="One-node cluster written by scripts/slurm_one_node.sh"

die() { echo "slurm_one_node: $*" >&2; exit 1; }

install_packages() {
    local missing=()
    for p in slurm-wlm munge; do
        dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
    done
    [ ${#missing[@]} -eq 0 ] && return 0
    [ "$(id -u)" -eq 0 ] || die "installing ${missing[*]} needs root"
    command -v apt-get >/dev/null || die "no apt-get to install ${missing[*]}"
    echo "slurm_one_node: installing ${missing[*]}"
    # The package index may be stale or absent on a fresh machine: update once if needed.
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null 2>&1 || {
        apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null
    }
}

free_ports() {  # two free TCP ports
    if [ -n "${SLURM_ONE_NODE_PORTS:-}" ]; then echo "$SLURM_ONE_NODE_PORTS"; return; fi
    python3 - <<'EOF'
import socket
socks = [socket.socket() for _ in range(2)]
for s in socks:
    s.bind(("", 0))
print(*(s.getsockname()[1] for s in socks))
EOF
}

write_config() {  # DIR
    local dir=$1 host node ctld_port slurmd_port
    # "NodeName=vm CPUs=2 Boards=1 SocketsPerBoard=1 CoresPerSocket=2 ThreadsPerCore=1 RealMemory=24105"
    node=$(slurmd -C | head -n 1)
    [[ $node == NodeName=* ]] || die "slurmd -C did not describe this node: $node"
    host=${node#NodeName=}; host=${host%% *}
    read -r ctld_port slurmd_port < <(free_ports)
    cat > "$dir/slurm.conf" <<EOF
# $MARK
ClusterName=capsmech
SlurmctldHost=$host
SlurmctldPort=$ctld_port
SlurmdPort=$slurmd_port
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$dir/munge/munge.socket
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool/%n
SlurmctldPidFile=$dir/run/slurmctld.daemon.pid
SlurmdPidFile=$dir/run/slurmd.daemon.pid
SlurmctldLogFile=$dir/log/slurmctld.log
SlurmdLogFile=$dir/log/slurmd.log
SlurmctldDebug=info
SlurmdDebug=info
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
MpiDefault=none
ReturnToService=2
MinJobAge=300
SchedulerParameters=batch_sched_delay=1,sched_min_interval=100000
KillWait=5
$node State=UNKNOWN
PartitionName=main Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF
}

daemon_alive() {  # PIDFILE NAME: the process of the pid file runs the named program
    local pid
    [ -s "$1" ] || return 1
    pid=$(cat "$1")
    [ -r "/proc/$pid/cmdline" ] && tr '\0' ' ' < "/proc/$pid/cmdline" | grep -q "$2"
}

start() {  # DIR
    local dir
    [ "$(id -u)" -eq 0 ] || die "the daemons need root"
    for c in munged slurmctld slurmd sinfo; do
        command -v $c >/dev/null || die "$c missing: run \`$0 install\`"
    done
    mkdir -p "$1"
    dir=$(cd "$1" && pwd)
    [ ! -e "$dir/run/slurmctld.pid" ] || ! daemon_alive "$dir/run/slurmctld.pid" slurmctld \
        || die "a cluster already runs from $dir (stop it first)"
    # The default configuration path: free, or a link left by an earlier start of this script.
    if [ -e "$DEFAULT_CONF" ] || [ -L "$DEFAULT_CONF" ]; then
        if [ -L "$DEFAULT_CONF" ] && { [ ! -e "$DEFAULT_CONF" ] || grep -q "$MARK" "$DEFAULT_CONF"; }; then
            daemon_alive "$(dirname "$(readlink "$DEFAULT_CONF")")/run/slurmctld.pid" slurmctld \
                && die "a one-node cluster already runs from $(dirname "$(readlink "$DEFAULT_CONF")")"
            rm -f "$DEFAULT_CONF"
        else
            die "this machine has a SLURM configuration of its own ($DEFAULT_CONF): not starting another cluster"
        fi
    fi
    mkdir -p "$dir"/{munge,state,spool,log,run} "$(dirname "$DEFAULT_CONF")"
    chmod 700 "$dir/munge"
    head -c 1024 /dev/urandom > "$dir/munge/munge.key"
    chmod 400 "$dir/munge/munge.key"
    write_config "$dir"
    ln -s "$dir/slurm.conf" "$DEFAULT_CONF"
    export SLURM_CONF=$dir/slurm.conf

    setsid munged --foreground --force --socket="$dir/munge/munge.socket" \
        --key-file="$dir/munge/munge.key" --pid-file="$dir/munge/munged.pid" \
        --log-file="$dir/log/munged.log" --seed-file="$dir/munge/munged.seed" \
        </dev/null >>"$dir/log/munged.out" 2>&1 &
    echo $! > "$dir/run/munged.pid"
    for _ in $(seq 50); do [ -S "$dir/munge/munge.socket" ] && break; sleep 0.1; done
    [ -S "$dir/munge/munge.socket" ] || { cat "$dir/log/munged".* >&2; die "munged did not start"; }

    setsid slurmctld -D -i -f "$SLURM_CONF" </dev/null >>"$dir/log/slurmctld.out" 2>&1 &
    echo $! > "$dir/run/slurmctld.pid"
    setsid slurmd -D -f "$SLURM_CONF" </dev/null >>"$dir/log/slurmd.out" 2>&1 &
    echo $! > "$dir/run/slurmd.pid"

    local state=""
    for _ in $(seq 120); do
        state=$(sinfo -h -N -o %T 2>/dev/null | head -n 1 || true)
        [ "$state" = idle ] && break
        sleep 0.5
    done
    if [ "$state" != idle ]; then
        tail -n 20 "$dir"/log/*.log "$dir"/log/*.out >&2 || true
        die "the node is not idle after 60 s (state: '${state:-no answer}'); logs above"
    fi
    echo "slurm_one_node: cluster up in $dir: $(sinfo -h -N -o '%N %c CPUs %m MB %T')"
}

stop() {  # DIR
    local dir pid name
    dir=$(cd "$1" && pwd)
    export SLURM_CONF=$dir/slurm.conf
    if daemon_alive "$dir/run/slurmctld.pid" slurmctld; then
        scancel --full --quiet $(squeue -h -o %i 2>/dev/null) 2>/dev/null || true
        for _ in $(seq 20); do
            [ -z "$(squeue -h -t R,CG,PD -o %i 2>/dev/null)" ] && break
            sleep 0.5
        done
    fi
    # Job step daemons of this cluster that outlived their job: slurmstepd processes that
    # carry this cluster's SLURM_CONF in their environment.
    for env in /proc/[0-9]*/environ; do
        pid=${env#/proc/}; pid=${pid%/environ}
        [ "$(cat "/proc/$pid/comm" 2>/dev/null)" = slurmstepd ] || continue
        tr '\0' '\n' < "$env" 2>/dev/null | grep -qx "SLURM_CONF=$SLURM_CONF" && kill -KILL "$pid" 2>/dev/null || true
    done
    for name in slurmd slurmctld munged; do
        daemon_alive "$dir/run/$name.pid" $name || continue
        pid=$(cat "$dir/run/$name.pid")
        kill -TERM "$pid" 2>/dev/null || true
        for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
        kill -0 "$pid" 2>/dev/null && kill -KILL "$pid" 2>/dev/null || true
        rm -f "$dir/run/$name.pid"
    done
    if [ "$(readlink "$DEFAULT_CONF" 2>/dev/null)" = "$dir/slurm.conf" ]; then rm -f "$DEFAULT_CONF"; fi
    echo "slurm_one_node: stopped the cluster of $dir"
}

case "${1:-}" in
    install) install_packages ;;
    start) [ $# -eq 2 ] || die "usage: $0 start DIR"; start "$2" ;;
    stop) [ $# -eq 2 ] || die "usage: $0 stop DIR"; stop "$2" ;;
    *) die "usage: $0 install | start DIR | stop DIR" ;;
esac
