#!/usr/bin/env bash
# Starts a throwaway single-node Slurm cluster (munged + slurmctld + slurmd) on this machine, so
# farm-submission code can be tested against a real scheduler. Needs root and Debian; no systemd
# (CI containers have none), so the daemons are started directly. Safe to run again: running
# daemons are kept. Stop it with slurm-down.sh, which kills the pids recorded in $PIDS.
set -euo pipefail

RUN=/run/slurm                 # pid files live here, so a reboot clears them
PIDS=$RUN/ci-daemons.pids      # "name pid" lines read by slurm-down.sh
CONF=/etc/slurm/slurm.conf     # Debian's compiled-in path: sbatch/sinfo find it without SLURM_CONF
HOST=$(hostname -s)            # slurmd finds its NodeName from this, so they must match
TIMEOUT=${SLURM_UP_TIMEOUT:-60}
PKGS="slurmctld slurmd munge"

# shellcheck disable=SC2086
if ! dpkg -s $PKGS >/dev/null 2>&1; then
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq || true   # a clean image may have no package lists yet
  apt-get install -y -qq --no-install-recommends $PKGS >/dev/null
fi

# munged only accepts a key owned by its own user and unreadable by others.
[ -s /etc/munge/munge.key ] || mungekey --create --keyfile=/etc/munge/munge.key
chown munge:munge /etc/munge/munge.key && chmod 0400 /etc/munge/munge.key
install -d -o munge -g munge -m 0755 /run/munge    # normally made by systemd's RuntimeDirectory
install -d -m 0755 "$RUN" /var/lib/slurm/slurmctld /var/lib/slurm/slurmd /var/log/slurm

# Whole-MiB memory, half of what exists: slurmd drains a node that has less than RealMemory.
MEM=$(( $(awk '/^MemTotal:/ {print $2}' /proc/meminfo) / 2048 ))
# SlurmUser=root avoids chown-ing state dirs to the slurm user; fine for a throwaway CI node.
# NodeAddr/SlurmctldHost address 127.0.0.1 so it works even where the hostname does not resolve.
# linuxproc/task none: no cgroup setup needed (containers often lack a writable cgroup tree).
# MailProg: Debian's default (/usr/bin/mail) is usually absent and slurmctld logs an error.
# batch_sched_delay=0: start batch jobs at once instead of up to 3 s later (4-task array plus
# dependent merge: 7.3 s -> 2.1 s).
NEW_CONF="ClusterName=ci
SlurmctldHost=$HOST(127.0.0.1)
SlurmUser=root
AuthType=auth/munge
StateSaveLocation=/var/lib/slurm/slurmctld
SlurmdSpoolDir=/var/lib/slurm/slurmd
SlurmctldPidFile=$RUN/slurmctld.pid
SlurmdPidFile=$RUN/slurmd.pid
SlurmctldLogFile=/var/log/slurm/slurmctld.log
SlurmdLogFile=/var/log/slurm/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
AccountingStorageType=accounting_storage/none
JobAcctGatherType=jobacct_gather/none
JobCompType=jobcomp/none
MpiDefault=none
MailProg=/bin/true
SchedulerParameters=batch_sched_delay=0
ReturnToService=2
NodeName=$HOST NodeAddr=127.0.0.1 CPUs=$(nproc) RealMemory=$MEM State=UNKNOWN
PartitionName=ci Nodes=ALL Default=YES MaxTime=INFINITE State=UP"

# A changed config (other nproc, hostname) needs a restart; an unchanged one keeps daemons up.
if [ "$(cat "$CONF" 2>/dev/null)" != "$NEW_CONF" ]; then
  [ -f "$PIDS" ] && "$(dirname "$0")/slurm-down.sh"
  printf '%s\n' "$NEW_CONF" > "$CONF"
fi

# True when pid file $2 names a live process called $1 (a stale file or reused pid is not, nor
# a zombie: PID 1 in some containers never reaps the daemons' exited fork parents).
alive() {
  local p; p=$(cat "$2" 2>/dev/null) && [ "$(cat "/proc/$p/comm" 2>/dev/null)" = "$1" ] &&
    ! grep -q '^State:.Z' "/proc/$p/status" 2>/dev/null
}
# Each daemon forks and writes its pid file a moment later; wait for it.
start() { # name pidfile command...
  local n=$1 f=$2; shift 2
  alive "$n" "$f" && return 0
  "$@"
  for _ in $(seq 50); do alive "$n" "$f" && return 0; sleep 0.1; done
  echo "slurm-up: $n did not start; see /var/log/slurm or /var/log/munge" >&2; exit 1
}
start munged /run/munge/munged.pid runuser -u munge -- /usr/sbin/munged
start slurmctld "$RUN/slurmctld.pid" /usr/sbin/slurmctld
start slurmd "$RUN/slurmd.pid" /usr/sbin/slurmd
printf 'munged %s\nslurmctld %s\nslurmd %s\n' "$(cat /run/munge/munged.pid)" \
  "$(cat "$RUN/slurmctld.pid")" "$(cat "$RUN/slurmd.pid")" > "$PIDS"

# slurmd registers asynchronously; jobs submitted before that would just sit pending.
# Busy states count as up, so a second run while jobs execute still succeeds.
for _ in $(seq "$TIMEOUT"); do
  state=$(sinfo -h -N -n "$HOST" -o %T 2>/dev/null || true)
  case $state in idle|mixed|allocated|completing) echo "slurm-up: node $HOST $state"; exit 0;; esac
  sleep 1
done
echo "slurm-up: node $HOST not idle after ${TIMEOUT}s (state: '${state:-none}')" >&2
sinfo -R >&2 || true
tail -n 20 /var/log/slurm/slurmctld.log /var/log/slurm/slurmd.log >&2 || true
exit 1
