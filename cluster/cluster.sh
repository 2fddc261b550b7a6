#!/usr/bin/env bash
# A single-node SLURM cluster on this machine, for the test suite and for trying the SLURM launcher:
#   bash cluster/cluster.sh up      install (Debian's slurm-wlm, slurmdbd, munge, mariadb-server) and start
#   bash cluster/cluster.sh down    stop the daemons
#   bash cluster/cluster.sh status  sinfo and the daemons' pids
#   bash cluster/cluster.sh is-up   exit 0 when every daemon runs and the node answers (installs nothing)
# Run as root (apt-get, daemons). Everything lives under $LOSSVO_CLUSTER (default /var/tmp/lossvo-cluster):
# configs, spool, state, logs, the database files. One node, this machine's cores and memory, one partition
# ("debug"), accounting through slurmdbd into MariaDB so that sacct (which submitit polls) knows every job.
# The same MariaDB holds a database for Optuna studies shared by several workers:
#   hydra.sweeper.storage.url=mysql+pymysql://lossvo:lossvo@localhost/lossvo_optuna
set -euo pipefail

HERE=${LOSSVO_CLUSTER:-/var/tmp/lossvo-cluster}
CLUSTER=lossvo
NODE=$(hostname -s)
CPUS=$(env -u OMP_NUM_THREADS -u OMP_THREAD_LIMIT nproc)  # the machine's cores, not a test worker's thread share
MEMORY=$(( $(awk '/MemTotal/ {print $2}' /proc/meminfo) / 1024 - 1024 ))  # MB, a GB left for the system
export SLURM_CONF=$HERE/etc/slurm.conf

log() { echo "cluster: $*" >&2; }
fail() { echo "cluster: error: $*" >&2; exit 2; }

install_packages() {
  command -v slurmctld >/dev/null && command -v slurmdbd >/dev/null && command -v munged >/dev/null \
    && command -v mariadbd >/dev/null && return
  command -v apt-get >/dev/null || fail "no apt-get: install slurm-wlm, slurmdbd, munge and mariadb-server yourself"
  log "installing slurm-wlm slurmdbd munge mariadb-server (Debian)"
  mkdir -p "$HERE/log"
  local packages=(slurm-wlm slurmdbd munge mariadb-server) policy=/usr/sbin/policy-rc.d made="" installed=""
  if [ ! -e $policy ]; then  # the packages' own services stay stopped: this script starts its daemons
    printf '#!/bin/sh\nexit 101\n' > $policy && chmod +x $policy && made=$policy
  fi
  { DEBIAN_FRONTEND=noninteractive apt-get install -y -q "${packages[@]}" \
      || { apt-get update -q && DEBIAN_FRONTEND=noninteractive apt-get install -y -q "${packages[@]}"; }
  } >"$HERE/log/apt-get.log" 2>&1 || installed=no
  rm -f $made
  [ -z "$installed" ] || fail "apt-get could not install ${packages[*]} (see $HERE/log/apt-get.log)"
}

write_configs() {
  mkdir -p "$HERE"/{etc,log,spool/slurmd,state,run,db,munge}
  cat > "$HERE/etc/slurm.conf" <<CONF
ClusterName=$CLUSTER
SlurmctldHost=$NODE
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
MpiDefault=none
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
ReturnToService=2
SlurmctldPidFile=$HERE/run/slurmctld.pid
SlurmdPidFile=$HERE/run/slurmd.pid
SlurmdSpoolDir=$HERE/spool/slurmd
StateSaveLocation=$HERE/state
SlurmctldLogFile=$HERE/log/slurmctld.log
SlurmdLogFile=$HERE/log/slurmd.log
SlurmctldParameters=enable_configless
JobCompType=jobcomp/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/slurmdbd
AccountingStorageHost=localhost
AccountingStorageEnforce=associations
MinJobAge=300
KillWait=10
InactiveLimit=0
DefMemPerCPU=1024
NodeName=$NODE CPUs=$CPUS RealMemory=$MEMORY State=UNKNOWN
PartitionName=debug Nodes=$NODE Default=YES MaxTime=INFINITE State=UP
CONF
  cat > "$HERE/etc/slurmdbd.conf" <<CONF
AuthType=auth/munge
DbdHost=localhost
SlurmUser=root
PidFile=$HERE/run/slurmdbd.pid
LogFile=$HERE/log/slurmdbd.log
StorageType=accounting_storage/mysql
StorageHost=localhost
StoragePort=3306
StorageUser=slurm
StoragePass=lossvo
StorageLoc=slurm_acct_db
CONF
  chmod 600 "$HERE/etc/slurmdbd.conf"
  mkdir -p /etc/slurm
  cp "$HERE/etc/slurmdbd.conf" /etc/slurm/slurmdbd.conf
  ln -sfn "$HERE/etc/slurm.conf" /etc/slurm/slurm.conf  # where sbatch, sacct and submitit look by default
}

start_munge() {
  pgrep -x munged >/dev/null && return
  [ -s /etc/munge/munge.key ] || dd if=/dev/urandom of=/etc/munge/munge.key bs=1024 count=1 status=none
  chown munge:munge /etc/munge/munge.key && chmod 400 /etc/munge/munge.key
  mkdir -p /run/munge /var/log/munge /var/lib/munge && chown munge:munge /run/munge /var/log/munge /var/lib/munge
  runuser -u munge -- /usr/sbin/munged || fail "munged did not start (see /var/log/munge/munged.log)"
}

start_database() {
  if ! pgrep -x mariadbd >/dev/null; then
    if [ ! -d "$HERE/db/mysql" ]; then
      chown mysql:mysql "$HERE/db"
      mariadb-install-db --user=mysql --datadir="$HERE/db" >"$HERE/log/mariadb-install.log" 2>&1 \
        || fail "mariadb-install-db failed (see $HERE/log/mariadb-install.log)"
    fi
    mkdir -p /run/mysqld && chown mysql:mysql /run/mysqld
    (setsid mariadbd --user=mysql --datadir="$HERE/db" --socket=/run/mysqld/mysqld.sock --port=3306 \
      --bind-address=127.0.0.1 </dev/null >"$HERE/log/mariadb.log" 2>&1 &)
    for _ in $(seq 60); do mariadb -uroot -e "select 1" >/dev/null 2>&1 && break; sleep 0.5; done
    mariadb -uroot -e "select 1" >/dev/null 2>&1 || fail "MariaDB did not start (see $HERE/log/mariadb.log)"
  fi
  mariadb -uroot -e "CREATE USER IF NOT EXISTS 'slurm'@'localhost' IDENTIFIED BY 'lossvo';
    GRANT ALL ON slurm_acct_db.* TO 'slurm'@'localhost';
    CREATE USER IF NOT EXISTS 'lossvo'@'localhost' IDENTIFIED BY 'lossvo';
    CREATE DATABASE IF NOT EXISTS lossvo_optuna; GRANT ALL ON lossvo_optuna.* TO 'lossvo'@'localhost';
    FLUSH PRIVILEGES;"  # the accounting database; an Optuna storage (mysql+pymysql://lossvo:lossvo@localhost/lossvo_optuna)
}

keep_nothing_inherited() {  # stdin and every descriptor past stderr closed, so the daemons hold no pipe
  local fd script                # or lock of whoever called `up` (a caller waiting for EOF would wait forever)
  script=$(readlink -f "$0")
  for fd in /proc/$$/fd/*; do
    fd=${fd##*/}
    [ "$fd" -gt 2 ] && [ "$(readlink -f "/proc/$$/fd/$fd" 2>/dev/null)" != "$script" ] && eval "exec $fd>&-"
  done
  exec </dev/null
}

running() {  # running NAME...: whether a process of any of these names runs
  local name; for name; do pgrep -x "$name" >/dev/null && return 0; done; return 1
}

wait_for() {  # wait_for WHAT COMMAND...: up to 30 s
  local what=$1; shift
  for _ in $(seq 60); do "$@" >/dev/null 2>&1 && return; sleep 0.5; done
  fail "$what did not come up (logs: $HERE/log)"
}

start_slurm() {
  pgrep -x slurmdbd >/dev/null || /usr/sbin/slurmdbd -f "$HERE/etc/slurmdbd.conf" 2>/dev/null || /usr/sbin/slurmdbd
  wait_for slurmdbd sacctmgr -i show cluster
  sacctmgr -i show cluster -n format=cluster | grep -qw $CLUSTER || sacctmgr -i add cluster $CLUSTER >/dev/null
  sacctmgr -i show account -n format=account | grep -qw lossvo || sacctmgr -i add account lossvo Cluster=$CLUSTER >/dev/null
  sacctmgr -i show user -n format=user | grep -qw root || sacctmgr -i add user root Account=lossvo >/dev/null
  if pgrep -x slurmctld >/dev/null; then scontrol reconfigure >/dev/null  # a running cluster reads the config again
  else /usr/sbin/slurmctld -f "$SLURM_CONF"; fi
  wait_for slurmctld scontrol ping
  pgrep -x slurmd >/dev/null || /usr/sbin/slurmd -f "$SLURM_CONF"
  wait_for "the node" bash -c "sinfo -h -o %t | grep -qE '^(idle|mix|alloc)'"
}

case "${1:-}" in
  up)  # one `up` at a time (parallel test workers call it); the lock is flock's own, not the daemons'
    [ "$(id -u)" = 0 ] || fail "run as root (it installs packages and starts daemons)"
    mkdir -p "$(dirname "$HERE")"
    exec flock --close "$HERE.lock" bash "$0" locked-up;;
  locked-up)
    keep_nothing_inherited
    install_packages; write_configs; start_munge; start_database; start_slurm
    log "up: $(sinfo -h -o '%P %D %c %m %t') (SLURM_CONF=$SLURM_CONF)";;
  down)
    for d in slurmd slurmctld slurmdbd; do pkill -x $d || true; done
    for _ in $(seq 60); do running slurmd slurmctld slurmdbd || break; sleep 0.5; done
    mariadb-admin -uroot shutdown 2>/dev/null || pkill -x mariadbd || true
    pkill -x munged || true
    for _ in $(seq 60); do running mariadbd munged || break; sleep 0.5; done
    log "down";;
  is-up)
    running_all() { local name; for name; do pgrep -x "$name" >/dev/null || return 1; done; }
    running_all munged mariadbd slurmdbd slurmctld slurmd && [ -f "$SLURM_CONF" ] \
      && sinfo -h -o %t 2>/dev/null | grep -qE '^(idle|mix|alloc)';;
  status)
    sinfo; for d in munged mariadbd slurmdbd slurmctld slurmd; do echo "$d: $(pgrep -x $d || echo not running)"; done;;
  *) echo "usage: bash cluster/cluster.sh up|down|status|is-up" >&2; exit 2;;
esac
