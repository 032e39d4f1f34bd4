#!/usr/bin/env bash
# A single-node SLURM cluster on this machine, from Debian's packages (slurmctld, slurmd,
# slurm-client, munge), to run the workflow through profiles/slurm for real:
#   scripts/slurm_local.sh start    # munged, slurmctld, slurmd; waits until the node is idle
#   scripts/slurm_local.sh status   # sinfo's view, or "not running"
#   scripts/slurm_local.sh stop     # stops the daemons, removes the state directory
# Everything lives in IPM_SLURM_STATE (default /tmp/ipm-slurm): slurm.conf, the munge key and
# socket, the daemons' spool, state, logs and job-completion log (jobcomp.log, one line per
# finished job). The only thing outside it is /etc/slurm/slurm.conf, a link to its slurm.conf,
# where SLURM's commands look by default (srun inside a job does not see SLURM_CONF: the
# plugin's job step drops SLURM_* variables). No accounting database: job states come from
# slurmctld (squeue keeps finished jobs for MinJobAge seconds), so Snakemake runs with
# --slurm-status-command squeue (profiles/slurm sets it). No cgroups: processes tracked by their
# parents (proctrack/linuxproc), each job pinned to its CPUs (task/affinity).
set -euo pipefail
export PATH="$PATH:/usr/sbin:/sbin"

STATE=${IPM_SLURM_STATE:-/tmp/ipm-slurm}
ETC_CONF=/etc/slurm/slurm.conf
PARTITION=main
CLUSTER=ipmlocal

die() { echo "slurm_local.sh: $*" >&2; exit 1; }

usage() { die "usage: scripts/slurm_local.sh start|stop|status"; }

case "$STATE" in
  /?*) ;;
  *) die "IPM_SLURM_STATE must be an absolute path, not '$STATE'" ;;
esac

pid_alive() { [ -f "$1" ] && kill -0 "$(cat "$1")" 2>/dev/null; }

check_can_run() {
  [ "$(id -u)" -eq 0 ] || die "needs root (the daemons run as root here); run it as root"
  local missing=""
  for cmd in munged mungekey slurmctld slurmd sinfo sbatch squeue scontrol; do
    command -v "$cmd" >/dev/null 2>&1 || missing="$missing $cmd"
  done
  [ -z "$missing" ] || die "missing:$missing (apt-get install slurmctld slurmd slurm-client munge, or scripts/setup.sh)"
}

running() { pid_alive "$STATE/slurmctld.pid" && pid_alive "$STATE/slurmd.pid"; }

write_conf() {
  local host cpus mem_kb real_mb
  host=$(hostname -s)
  cpus=$(nproc)
  mem_kb=$(awk '/^MemTotal:/ {print $2}' /proc/meminfo)
  # slurmd drains a node that reports less memory than configured: leave 5% and 256 MB aside
  real_mb=$(( mem_kb / 1024 * 95 / 100 - 256 ))
  [ "$real_mb" -gt 512 ] || die "too little memory for a node (${mem_kb} kB in /proc/meminfo)"
  cat >"$STATE/slurm.conf" <<EOF
# Written by scripts/slurm_local.sh: one node, this machine ($cpus CPUs, $real_mb MB).
ClusterName=$CLUSTER
SlurmctldHost=$host(127.0.0.1)
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$STATE/munge/munge.socket.2
StateSaveLocation=$STATE/ctld
SlurmdSpoolDir=$STATE/spool
SlurmctldPidFile=$STATE/slurmctld.pid
SlurmdPidFile=$STATE/slurmd.pid
SlurmctldLogFile=$STATE/log/slurmctld.log
SlurmdLogFile=$STATE/log/slurmd.log
SlurmctldPort=${IPM_SLURM_PORT:-6817}
SlurmdPort=$(( ${IPM_SLURM_PORT:-6817} + 1 ))
ProctrackType=proctrack/linuxproc
TaskPlugin=task/affinity
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/filetxt
JobCompLoc=$STATE/jobcomp.log
MpiDefault=none
SwitchType=switch/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU_Memory
# a job without --mem gets its CPUs' share of memory, not the whole node
DefMemPerCPU=$(( real_mb / cpus ))
# a job asking more than the partition has is refused at submission, not left pending forever
EnforcePartLimits=ALL
# finished jobs stay visible to squeue for 10 minutes (the plugin's squeue status needs >= 120 s)
MinJobAge=600
ReturnToService=2
SlurmdTimeout=60
InactiveLimit=0
KillWait=10
NodeName=$host NodeAddr=127.0.0.1 CPUs=$cpus RealMemory=$real_mb State=UNKNOWN
PartitionName=$PARTITION Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF
}

start_munge() {
  mkdir -p "$STATE/munge"
  chmod 700 "$STATE/munge"
  [ -f "$STATE/munge/munge.key" ] || mungekey --create --keyfile="$STATE/munge/munge.key" 2>/dev/null \
    || dd if=/dev/urandom of="$STATE/munge/munge.key" bs=1024 count=1 status=none
  chmod 600 "$STATE/munge/munge.key"
  pid_alive "$STATE/munge/munged.pid" && return 0
  munged --force --socket="$STATE/munge/munge.socket.2" --key-file="$STATE/munge/munge.key" \
    --pid-file="$STATE/munge/munged.pid" --log-file="$STATE/log/munged.log" \
    --seed-file="$STATE/munge/munged.seed" \
    || die "munged did not start (see $STATE/log/munged.log)"
}

start() {
  check_can_run
  if running && [ "$(readlink "$ETC_CONF" 2>/dev/null)" = "$STATE/slurm.conf" ]; then
    wait_idle
    return 0
  fi
  if [ -e "$ETC_CONF" ] && [ "$(readlink "$ETC_CONF" 2>/dev/null)" != "$STATE/slurm.conf" ]; then
    die "$ETC_CONF exists and is not this script's: another SLURM setup owns this machine"
  fi
  mkdir -p "$STATE"/{ctld,spool,log}
  chmod 755 "$STATE"
  write_conf
  mkdir -p "$(dirname "$ETC_CONF")"
  ln -sfn "$STATE/slurm.conf" "$ETC_CONF"
  start_munge
  pid_alive "$STATE/slurmctld.pid" || slurmctld -i -f "$STATE/slurm.conf" \
    || die "slurmctld did not start (see $STATE/log/slurmctld.log)"
  pid_alive "$STATE/slurmd.pid" || slurmd -f "$STATE/slurm.conf" \
    || die "slurmd did not start (see $STATE/log/slurmd.log)"
  wait_idle
}

wait_idle() {
  local state=""
  for _ in $(seq 60); do
    state=$(sinfo -h -N -o %T 2>/dev/null | head -1) || true
    case "$state" in
      idle|mixed|allocated) echo "slurm_local.sh: node $(hostname -s) $state, partition $PARTITION ($STATE)"; return 0 ;;
      drain*|down*) scontrol update nodename="$(hostname -s)" state=resume >/dev/null 2>&1 || true ;;
    esac
    sleep 1
  done
  die "the node did not become idle within 60 s (state '${state:-none}'; see $STATE/log)"
}

stop_pids() {  # TERM to each daemon of the given pid files at once, KILL to any left after 10 s
  local pids="" alive="" f pid
  for f in "$@"; do pid_alive "$f" && pids="$pids $(cat "$f")"; done
  [ -n "$pids" ] || return 0
  kill $pids 2>/dev/null || true
  for _ in $(seq 50); do
    alive=""
    for pid in $pids; do kill -0 "$pid" 2>/dev/null && alive="$alive $pid"; done
    [ -n "$alive" ] || return 0
    sleep 0.2
  done
  kill -9 $alive 2>/dev/null || true
}

stop() {
  [ "$(id -u)" -eq 0 ] || die "needs root (the daemons run as root here); run it as root"
  if running; then  # cancel what is left and let slurmd end its job steps
    scancel --quiet --partition="$PARTITION" 2>/dev/null || true
    for _ in $(seq 30); do
      [ -z "$(squeue -h -t running,completing -o %i 2>/dev/null)" ] && break
      sleep 1
    done
  fi
  stop_pids "$STATE/slurmd.pid" "$STATE/slurmctld.pid" "$STATE/munge/munged.pid"
  [ "$(readlink "$ETC_CONF" 2>/dev/null)" = "$STATE/slurm.conf" ] && rm -f "$ETC_CONF"
  # the state directory only where this script made it (its slurm.conf says so)
  if [ -d "$STATE" ]; then
    grep -qs "^# Written by scripts/slurm_local.sh" "$STATE/slurm.conf" \
      || die "$STATE was not made by this script; left as it is"
    rm -rf "$STATE"
  fi
  echo "slurm_local.sh: stopped"
}

status() {
  if running; then
    sinfo -N -o "%N %P %T %c %m"
  else
    echo "slurm_local.sh: not running"
    return 3
  fi
}

case "${1:-}" in
  start) start ;;
  stop) stop ;;
  status) status ;;
  *) usage ;;
esac
