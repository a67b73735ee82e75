#!/usr/bin/env bash
# A real one-node Slurm cluster on this machine (loopback, no systemd), for
# testing the Slurm profile:  slurm_local.sh start|stop|status
#
#   start   install Debian's slurm-wlm + munge if missing (needs root and apt),
#           write munge/slurm config under $GS2E_SLURM_DIR, start munged,
#           slurmctld and slurmd, wait until `sinfo` shows the node idle.
#   stop    cancel the cluster's unfinished jobs, stop the daemons this script
#           started (by their pid files) and remove the /etc symlink.
#   status  print daemon states and `sinfo`; exit 0 only if all daemons run
#           and sinfo answers.
#
# Environment:
#   GS2E_SLURM_DIR        scratch dir for keys, sockets, state, logs
#                         (default /tmp/gs2e-slurm)
#   GS2E_SLURM_PARTITION  partition name (default gs2e; the profile's
#                         slurm_partition must match, or be left unset)
#   GS2E_SLURM_PORT       slurmctld port; slurmd uses PORT+1 (default 6817)
#   GS2E_SLURM_WAIT_S     seconds to wait for the node to become idle (default 60)
#
# Everything is idempotent: `start` on a running cluster only re-checks it,
# `stop` on a stopped one does nothing.  slurm.conf must also be reachable at
# /etc/slurm/slurm.conf (a symlink is written): the executor plugin's job step
# drops SLURM_* variables, so SLURM_CONF does not reach the jobs.
set -euo pipefail

DIR=${GS2E_SLURM_DIR:-/tmp/gs2e-slurm}
PARTITION=${GS2E_SLURM_PARTITION:-gs2e}
PORT=${GS2E_SLURM_PORT:-6817}
WAIT_S=${GS2E_SLURM_WAIT_S:-60}
CONF=$DIR/etc/slurm.conf
ETC_CONF=/etc/slurm/slurm.conf
MUNGE_SOCKET=$DIR/munge/munge.socket
export SLURM_CONF=$CONF

say() { echo "slurm_local: $*" >&2; }
die() { say "ERROR: $*"; exit 1; }

have_binaries() {
    command -v munged >/dev/null && command -v mungekey >/dev/null &&
    command -v slurmctld >/dev/null && command -v slurmd >/dev/null &&
    command -v sinfo >/dev/null && command -v sbatch >/dev/null
}

install_packages() {
    have_binaries && return 0
    [[ $(id -u) -eq 0 ]] || die "slurm-wlm/munge are not installed and installing them needs root (run as root, or: sudo apt-get install slurm-wlm munge)"
    command -v apt-get >/dev/null || die "slurm-wlm/munge are not installed and apt-get is not available on this machine"
    local t0=$SECONDS rc=0 policy=/usr/sbin/policy-rc.d
    say "installing slurm-wlm + munge with apt-get"
    # The packages' scripts must not start system-wide daemons (we start our
    # own with scratch paths): a temporary policy-rc.d denies service starts.
    local own_policy=0
    if [[ ! -e $policy ]]; then
        printf '#!/bin/sh\nexit 101\n' >"$policy" && chmod 755 "$policy" && own_policy=1
    fi
    export DEBIAN_FRONTEND=noninteractive
    { apt-get update -qq && apt-get install -y -qq --no-install-recommends slurm-wlm munge >/dev/null; } || rc=$?
    ((own_policy)) && rm -f "$policy"
    ((rc == 0)) || die "apt-get update/install of slurm-wlm munge failed (exit $rc)"
    have_binaries || die "slurm-wlm/munge installed but munged/slurmctld/slurmd/sinfo not on PATH"
    say "installed in $((SECONDS - t0)) s"
}

pid_alive() {  # pid_alive FILE NAME: the pid in FILE is a running process called NAME
    local pid
    [[ -s $1 ]] || return 1
    pid=$(<"$1")
    [[ $pid =~ ^[0-9]+$ ]] || return 1
    # a stale pid file may name a pid reused by an unrelated process
    [[ $(cat "/proc/$pid/comm" 2>/dev/null) == "$2" ]]
}

write_config() {
    local node cpus mem_mb
    node=$(hostname -s)
    cpus=$(nproc)
    # Leave 10% of RAM to the OS and the Snakemake scheduler process.
    mem_mb=$(awk '/^MemTotal:/ {printf "%d", $2 / 1024 * 0.9}' /proc/meminfo)
    mkdir -p "$DIR"/{etc,munge,state,spool,log,run}
    cat >"$CONF" <<EOF
# Written by workflow/scripts/slurm_local.sh: one node on loopback, for tests.
ClusterName=gs2e
SlurmctldHost=${node}(127.0.0.1)
SlurmUser=root
SlurmdUser=root
SlurmctldPort=${PORT}
SlurmdPort=$((PORT + 1))
AuthType=auth/munge
AuthInfo=socket=${MUNGE_SOCKET}
StateSaveLocation=${DIR}/state
SlurmdSpoolDir=${DIR}/spool
SlurmctldPidFile=${DIR}/run/slurmctld.pid
SlurmdPidFile=${DIR}/run/slurmd.pid
SlurmctldLogFile=${DIR}/log/slurmctld.log
SlurmdLogFile=${DIR}/log/slurmd.log
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
MpiDefault=none
AccountingStorageType=accounting_storage/none
# Memory is enforced by polling (no cgroups here): a job step above its --mem
# is killed (OUT_OF_MEMORY), which is what triggers a retry with more memory.
JobAcctGatherType=jobacct_gather/linux
JobAcctGatherFrequency=task=1
JobAcctGatherParams=OverMemoryKill
JobCompType=jobcomp/none
# Reject jobs larger than the node instead of letting them pend forever.
EnforcePartLimits=ALL
# The node's real hardware may differ from what is declared below.
SlurmdParameters=config_overrides
ReturnToService=2
# Finished jobs stay visible to squeue (the profile's status command) for 1 h.
MinJobAge=3600
NodeName=${node} NodeAddr=127.0.0.1 CPUs=${cpus} RealMemory=${mem_mb} State=UNKNOWN
PartitionName=${PARTITION} Nodes=${node} Default=YES MaxTime=INFINITE State=UP
EOF
}

link_etc_conf() {
    mkdir -p /etc/slurm 2>/dev/null || die "cannot create /etc/slurm (need root)"
    if [[ -e $ETC_CONF || -L $ETC_CONF ]]; then
        if [[ -L $ETC_CONF && $(readlink "$ETC_CONF") == "$CONF" ]]; then return 0; fi
        if [[ ! -L $ETC_CONF ]]; then
            die "$ETC_CONF exists and is not our symlink; refusing to replace a real Slurm config"
        fi
        # a symlink left by another scratch dir: replace it unless that cluster runs
        local other_pid
        other_pid=$(sed -n 's/^SlurmctldPidFile=//p' "$ETC_CONF" 2>/dev/null || true)
        if [[ -n $other_pid ]] && pid_alive "$other_pid" slurmctld; then
            die "another local cluster ($(readlink "$ETC_CONF")) is running; stop it first (GS2E_SLURM_DIR=... $0 stop)"
        fi
    fi
    ln -sfn "$CONF" "$ETC_CONF" || die "cannot write the symlink $ETC_CONF -> $CONF"
}

start_munge() {
    pid_alive "$DIR/munge/munged.pid" munged && return 0
    [[ -s $DIR/munge/munge.key ]] || mungekey -c -k "$DIR/munge/munge.key" ||
        die "mungekey failed"
    chmod 600 "$DIR/munge/munge.key"
    # munged refuses a socket directory other users cannot traverse
    chmod 755 "$DIR/munge"
    rm -f "$MUNGE_SOCKET" "$MUNGE_SOCKET.lock"
    munged --force --key-file="$DIR/munge/munge.key" --socket="$MUNGE_SOCKET" \
        --pid-file="$DIR/munge/munged.pid" --log-file="$DIR/log/munged.log" \
        --seed-file="$DIR/munge/munged.seed" ||
        die "munged failed to start; see $DIR/log/munged.log"
}

start_daemon() {  # start_daemon NAME
    local name=$1
    pid_alive "$DIR/run/$name.pid" "$name" && return 0
    "$name" -f "$CONF" || die "$name failed to start; see $DIR/log/$name.log"
}

node_state() {
    sinfo -h -N -o '%T' 2>/dev/null | head -n1
}

wait_idle() {
    local t0=$SECONDS state=""
    while ((SECONDS - t0 < WAIT_S)); do
        state=$(node_state || true)
        case $state in
            idle | mixed | allocated) return 0 ;;
        esac
        sleep 0.5
    done
    die "node not idle after ${WAIT_S} s (state: '${state:-unknown}'); see $DIR/log/slurmctld.log and $DIR/log/slurmd.log"
}

cmd_start() {
    local t0=$SECONDS
    install_packages
    if pid_alive "$DIR/run/slurmctld.pid" slurmctld && pid_alive "$DIR/run/slurmd.pid" slurmd &&
        pid_alive "$DIR/munge/munged.pid" munged; then
        wait_idle
        say "already running (config $CONF)"
        return 0
    fi
    write_config
    link_etc_conf
    # A fresh controller state: the node must register anew (no node state
    # or jobs remembered from an earlier run).
    pid_alive "$DIR/run/slurmctld.pid" slurmctld || rm -rf "${DIR:?}"/state/* "${DIR:?}"/spool/*
    start_munge
    start_daemon slurmctld
    start_daemon slurmd
    wait_idle
    say "node $(hostname -s) idle in partition '$PARTITION' (started in $((SECONDS - t0)) s; config $CONF)"
}

stop_pidfile() {  # stop_pidfile NAME FILE
    local name=$1 file=$2 pid i
    if ! pid_alive "$file" "$name"; then rm -f "$file"; return 0; fi
    pid=$(cat "$file")
    kill "$pid" 2>/dev/null || true
    for ((i = 0; i < 100; i++)); do
        kill -0 "$pid" 2>/dev/null || { rm -f "$file"; say "stopped $name ($pid)"; return 0; }
        sleep 0.1
    done
    say "$name ($pid) ignored SIGTERM for 10 s; sending SIGKILL"
    kill -9 "$pid" 2>/dev/null || true
    rm -f "$file"
}

cmd_stop() {
    # Cancel jobs still queued or running on this private cluster first, so
    # that slurmstepd ends their processes before the daemons go.
    if pid_alive "$DIR/run/slurmctld.pid" slurmctld; then
        local jobs
        jobs=$(squeue -h -o '%i' -t pending,running,suspended 2>/dev/null || true)
        if [[ -n $jobs ]]; then
            say "cancelling jobs: $(echo $jobs)"
            # shellcheck disable=SC2086
            scancel $jobs 2>/dev/null || true
            local i
            for ((i = 0; i < 50; i++)); do
                [[ -z $(squeue -h -o '%i' -t pending,running,suspended,completing 2>/dev/null) ]] && break
                sleep 0.2
            done
        fi
    fi
    stop_pidfile slurmd "$DIR/run/slurmd.pid"
    stop_pidfile slurmctld "$DIR/run/slurmctld.pid"
    stop_pidfile munged "$DIR/munge/munged.pid"
    # Remove our /etc symlink so no stale config points into the scratch dir.
    if [[ -L $ETC_CONF && $(readlink "$ETC_CONF") == "$CONF" ]]; then rm -f "$ETC_CONF"; fi
}

cmd_status() {
    local ok=0 name file
    for name in munged slurmctld slurmd; do
        file=$DIR/run/$name.pid
        [[ $name == munged ]] && file=$DIR/munge/munged.pid
        if pid_alive "$file" "$name"; then echo "$name: running ($(cat "$file"))"; else echo "$name: stopped"; ok=1; fi
    done
    if ((ok == 0)); then sinfo || ok=1; fi
    return $ok
}

case ${1:-} in
    start) cmd_start ;;
    stop) cmd_stop ;;
    status) cmd_status ;;
    *) echo "usage: $0 start|stop|status" >&2; exit 2 ;;
esac
