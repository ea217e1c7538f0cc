#!/usr/bin/env bash
# A one-node SLURM cluster on this machine (Debian 12), for testing the workflow's SLURM executor
# (snakemake-executor-plugin-slurm) end to end: jobs go through sbatch and the plugin polls their
# states with sacct, so accounting is real (slurmdbd backed by MariaDB), not accounting_storage/none.
#
#   bin/slurm-local.sh [start]   install what is missing, write the config, start what is down
#   bin/slurm-local.sh stop      stop slurmd, slurmctld, slurmdbd, MariaDB, munged (in that order)
#   bin/slurm-local.sh status    which daemons run, sinfo; exit 0 only if all are up and the node usable
#
# Needs root. Safe to run again: config files are rewritten only when their content changes, and
# only the daemons reading a changed file are restarted. Environment knobs: SLURM_LOCAL_CLUSTER
# (cluster name, default ocpipe), SLURM_LOCAL_ACCOUNT (default account, default ocpipe),
# SLURM_LOCAL_USERS (users given that account, default root plus $SUDO_USER), SLURM_LOCAL_WAIT
# (seconds to wait for each daemon, default 60).
set -euo pipefail

CLUSTER=${SLURM_LOCAL_CLUSTER:-ocpipe}
ACCOUNT=${SLURM_LOCAL_ACCOUNT:-ocpipe}
USERS=${SLURM_LOCAL_USERS:-root ${SUDO_USER:-}}
WAIT=${SLURM_LOCAL_WAIT:-60}
PARTITION=cpu
NODE=$(hostname -s)
PACKAGES=(slurmctld slurmd slurmdbd slurm-client mariadb-server munge)
DB_NAME=slurm_acct_db
SLURM_CONF=/etc/slurm/slurm.conf
DBD_CONF=/etc/slurm/slurmdbd.conf
# Our own MariaDB drop-in: Debian's default sends the server log to syslog, and there is no syslog
# daemon in a container, so without this a failing MariaDB would leave nothing to show.
MYSQL_CNF=/etc/mysql/mariadb.conf.d/60-slurm-local.cnf

# Daemons in start order. Each is found through its pid file (checked against the process name, so
# a stale file naming a reused pid is not mistaken for the daemon), never by a name-wide search.
DAEMONS=(munged mariadb slurmdbd slurmctld slurmd)
declare -A PIDFILE=(
    [munged]=/run/munge/munged.pid [mariadb]=/run/mysqld/mysqld.pid [slurmdbd]=/run/slurmdbd.pid
    [slurmctld]=/run/slurmctld.pid [slurmd]=/run/slurmd.pid)
declare -A COMM=(
    [munged]="munged" [mariadb]="mariadbd mysqld" [slurmdbd]="slurmdbd"
    [slurmctld]="slurmctld" [slurmd]="slurmd")
declare -A LOGFILE=(
    [munged]=/var/log/munge/munged.log [mariadb]=/var/log/mysql/error.log
    [slurmdbd]=/var/log/slurm/slurmdbd.log [slurmctld]=/var/log/slurm/slurmctld.log
    [slurmd]=/var/log/slurm/slurmd.log)
declare -A CHECK_DESC=(
    [munged]="munge -n | unmunge" [mariadb]="mysqladmin ping" [slurmdbd]="sacctmgr -n list cluster"
    [slurmctld]="scontrol ping" [slurmd]="sinfo shows node $NODE responding")
# Debian's service names, used only where systemd runs the show (see use_systemd).
declare -A UNIT=([munged]=munge [mariadb]=mariadb [slurmdbd]=slurmdbd [slurmctld]=slurmctld [slurmd]=slurmd)

say() { echo "slurm-local: $*"; }
warn() { echo "slurm-local: $*" >&2; }

# Exit naming the daemon and showing its log's tail: the log nearly always says why, and whoever runs
# this (often a CI job or another script) should not have to go looking for it.
fail() {
    local d=$1; shift
    warn "$d: $*"
    local log=${LOGFILE[$d]}
    if [ -s "$log" ]; then
        warn "last 20 lines of $log:"
        tail -n 20 "$log" | sed 's/^/    /' >&2
    else
        warn "(its log $log is empty or missing)"
    fi
    exit 1
}

# On a host booted with systemd the packages' units own the daemons, and starting them by hand
# as well would leave two managers fighting; in containers and sandboxed VMs (this project's test
# machines) there is no systemd, so the daemons are started directly.
use_systemd() { [ "$(ps -p 1 -o comm= 2>/dev/null)" = systemd ]; }

# Print the daemon's pid if it is running.
pid_of() {
    local d=$1 pid comm c
    [ -r "${PIDFILE[$d]}" ] || return 1
    pid=$(tr -dc 0-9 <"${PIDFILE[$d]}")
    [ -n "$pid" ] && [ -r "/proc/$pid/comm" ] || return 1
    comm=$(cat "/proc/$pid/comm" 2>/dev/null) || return 1
    for c in ${COMM[$d]}; do
        if [ "$comm" = "$c" ]; then echo "$pid"; return 0; fi
    done
    return 1
}
running() { pid_of "$1" >/dev/null; }

# Whether the daemon answers as a client would talk to it: a live process is not enough (slurmdbd,
# for one, runs for a while before it can reach its database). Each probe is time-limited because
# the SLURM clients retry for a long time when nobody answers.
answers() {
    case $1 in
        munged) munge -n 2>/dev/null | unmunge >/dev/null 2>&1 ;;
        mariadb) timeout 10 mysqladmin --silent ping >/dev/null 2>&1 ;;
        slurmdbd) timeout 10 sacctmgr -n list cluster >/dev/null 2>&1 ;;
        slurmctld) timeout 10 scontrol ping 2>/dev/null | grep -q 'is UP' ;;
        slurmd) slurmd_registered ;;
    esac
}

# slurmd answers its own RPCs and slurmctld has heard from it. A restarted slurmctld restores the
# node's last state (often "idle") before slurmd has said anything, so when this run launched
# slurmd, its registration must be newer than the launch. A trailing * in the state marks a node
# that slurmctld cannot reach.
slurmd_registered() {
    local s t
    timeout 10 scontrol show slurmd >/dev/null 2>&1 || return 1
    s=$(node_state) && [ -n "$s" ] && [[ $s != *'*' ]] && [[ $s != unknown* ]] || return 1
    [ -z "${LAUNCHED_AT[slurmd]:-}" ] && return 0
    t=$(timeout 10 scontrol show node "$NODE" 2>/dev/null | grep -oE 'SlurmdStartTime=[^ ]+' | cut -d= -f2)
    [ -n "$t" ] && [ "$(date -d "$t" +%s 2>/dev/null || echo 0)" -ge "${LAUNCHED_AT[slurmd]}" ]
}

node_state() { timeout 10 sinfo -h -N -n "$NODE" -o %T 2>/dev/null | head -n 1; }
# idle/mixed/allocated/completing: the node runs jobs. A start while a workflow is running finds
# the node busy, which is as good as idle for our purposes.
usable_state() { [[ $1 =~ ^(idle|mixed|allocated|completing)$ ]]; }

wait_until() { # wait_until COMMAND...: poll COMMAND twice a second for up to $WAIT seconds
    local end=$((SECONDS + WAIT))
    while ((SECONDS < end)); do
        if "$@"; then return 0; fi
        sleep 0.5
    done
    "$@"
}

# ---------------------------------------------------------------------------------------------
# Installation and configuration

install_packages() {
    local p missing=()
    for p in "${PACKAGES[@]}"; do
        dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q 'ok installed' || missing+=("$p")
    done
    [ ${#missing[@]} -eq 0 ] && return 0
    say "installing ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -q
    apt-get install -y -q --no-install-recommends "${missing[@]}"
}

CHANGED=()    # config files rewritten by this run
STARTED=()    # daemons this run started
STOP_FAILED=0 # set when a daemon had to be killed
declare -A LAUNCHED_AT=() # daemon -> epoch seconds when this run launched it
declare -A BG_PID=()      # daemon -> pid of a launch that does not daemonize (mariadbd)

# write_file PATH MODE OWNER: write stdin to PATH only if the content differs, so that an unchanged
# setup neither touches the file nor restarts anything.
write_file() {
    local path=$1 mode=$2 owner=$3 tmp
    tmp=$(mktemp)
    cat >"$tmp"
    if [ -f "$path" ] && cmp -s "$tmp" "$path"; then
        rm -f "$tmp"
    else
        mkdir -p "$(dirname "$path")"
        install -m "$mode" -o "${owner%:*}" -g "${owner#*:}" "$tmp" "$path"
        rm -f "$tmp"
        CHANGED+=("$path")
        say "wrote $path"
    fi
    # Mode and owner are enforced even when the content is right: slurmdbd refuses to start with a
    # world-readable slurmdbd.conf (it holds the database password).
    chmod "$mode" "$path"
    chown "$owner" "$path"
}
changed() { local f; for f in "${CHANGED[@]}"; do [ "$f" = "$1" ] && return 0; done; return 1; }

prepare_system() {
    # The packages normally create these accounts; make sure, as everything below relies on them.
    id slurm >/dev/null 2>&1 || adduser --system --group --no-create-home --home /nonexistent slurm
    id munge >/dev/null 2>&1 || adduser --system --group --no-create-home --home /nonexistent munge
    install -d -o munge -g munge -m 0755 /run/munge
    install -d -o munge -g munge -m 0700 /var/log/munge /var/lib/munge
    # munged refuses a key anyone but munge can read; the package makes one, but not always (an
    # interrupted install, a key copied in by hand).
    if [ ! -s /etc/munge/munge.key ]; then
        say "creating /etc/munge/munge.key"
        mungekey --create --keyfile /etc/munge/munge.key
    fi
    chown munge:munge /etc/munge/munge.key
    chmod 0400 /etc/munge/munge.key
    install -d -o mysql -g mysql -m 0755 /run/mysqld
    install -d -o mysql -g adm -m 2750 /var/log/mysql
    install -d -o slurm -g slurm -m 0755 /var/log/slurm /var/spool/slurmctld
    install -d -o root -g root -m 0755 /var/spool/slurmd
    # Each daemon's log exists before launch, owned by the user the daemon runs as: launch()
    # appends the daemon's early output (before it has read its config) to the same file as root,
    # and a root-owned log would lock out slurmctld and slurmdbd (which run as slurm) and make
    # munged refuse to start ("Logfile is insecure").
    own_log munged munge:munge
    own_log mariadb mysql:adm
    own_log slurmdbd slurm:slurm
    own_log slurmctld slurm:slurm
    own_log slurmd root:root
}
own_log() {
    local log=${LOGFILE[$1]}
    [ -e "$log" ] || : >"$log"
    chown "$2" "$log"
    chmod 0640 "$log"
}

write_configs() {
    local cpus mem_mb pass
    cpus=$(nproc)
    # Leave ~1 GB for the OS and the daemons; a RealMemory above what slurmd finds drains the node.
    mem_mb=$(($(awk '/^MemTotal:/ {print int($2 / 1024)}' /proc/meminfo) - 1024))
    # Keep the database password across runs (otherwise slurmdbd.conf would change every time).
    pass=""
    [ ! -f "$DBD_CONF" ] || pass=$(sed -n 's/^StoragePass=//p' "$DBD_CONF" | head -n 1)
    [ -n "$pass" ] || pass=$(od -An -N16 -tx1 /dev/urandom | tr -d ' \n')

    write_file "$SLURM_CONF" 0644 root:root <<EOF
# Written by bin/slurm-local.sh (ocpipe): a one-node test cluster. Edits here are overwritten.
ClusterName=$CLUSTER
# The address is given so that nothing depends on how (or whether) the host name resolves.
SlurmctldHost=$NODE(127.0.0.1)
SlurmUser=slurm
AuthType=auth/munge
# linuxproc and task/none need no cgroup hierarchy, which containers and sandboxed VMs rarely give.
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
# cons_tres with cores and memory as resources: --cpus-per-task and --mem are allocated (the
# scheduler never overcommits them) and recorded in accounting, as on the real clusters the
# workflow targets. Without cgroups a running job is not confined to them, which a test doesn't need.
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
SchedulerType=sched/backfill
# A node that was DOWN (e.g. this machine restarted under it) comes back by itself once slurmd
# registers with a valid configuration.
ReturnToService=2
# sacct (which the executor plugin polls) reads job records from slurmdbd.
AccountingStorageType=accounting_storage/slurmdbd
AccountingStorageHost=localhost
# keep --comment (the plugin puts the rule and its wildcards there) in accounting, so sacct shows each job's rule
AccountingStoreFlags=job_comment
JobAcctGatherType=jobacct_gather/linux
JobCompType=jobcomp/none
# No mail on this machine; without this slurmctld logs an error per job that asks for mail.
MailProg=/bin/true
StateSaveLocation=/var/spool/slurmctld
SlurmdSpoolDir=/var/spool/slurmd
SlurmctldPidFile=${PIDFILE[slurmctld]}
SlurmdPidFile=${PIDFILE[slurmd]}
SlurmctldLogFile=${LOGFILE[slurmctld]}
SlurmdLogFile=${LOGFILE[slurmd]}
SlurmctldDebug=info
SlurmdDebug=info
NodeName=$NODE NodeAddr=127.0.0.1 CPUs=$cpus RealMemory=$mem_mb State=UNKNOWN
PartitionName=$PARTITION Nodes=$NODE Default=YES MaxTime=INFINITE State=UP
EOF

    write_file "$DBD_CONF" 0600 slurm:slurm <<EOF
# Written by bin/slurm-local.sh (ocpipe). Edits here are overwritten (the password is kept).
AuthType=auth/munge
DbdHost=localhost
SlurmUser=slurm
DebugLevel=info
LogFile=${LOGFILE[slurmdbd]}
PidFile=${PIDFILE[slurmdbd]}
StorageType=accounting_storage/mysql
StorageHost=localhost
StorageUser=slurm
StoragePass=$pass
StorageLoc=$DB_NAME
EOF

    write_file "$MYSQL_CNF" 0644 root:root <<EOF
# Written by bin/slurm-local.sh (ocpipe) for slurmdbd.
[mysqld]
# A file log, as containers have no syslog to receive the default one.
log_error = ${LOGFILE[mariadb]}
# SLURM's documented minimum for slurmdbd (its schema upgrades hold long locks).
innodb_lock_wait_timeout = 900
# Small: this is a test cluster sharing the machine with the real work. slurmdbd logs "Database
# settings not recommended values: innodb_buffer_pool_size" for it; harmless at this scale.
innodb_buffer_pool_size = 128M
EOF
}

# The database and its user; statements that are no-ops when both exist, so always run.
setup_database() {
    local pass
    pass=$(sed -n 's/^StoragePass=//p' "$DBD_CONF" | head -n 1)
    mysql -u root <<EOF || fail mariadb "could not create database $DB_NAME and user slurm"
CREATE DATABASE IF NOT EXISTS $DB_NAME;
CREATE USER IF NOT EXISTS 'slurm'@'localhost' IDENTIFIED BY '$pass';
ALTER USER 'slurm'@'localhost' IDENTIFIED BY '$pass';
GRANT ALL ON $DB_NAME.* TO 'slurm'@'localhost';
EOF
}

# The cluster, a default account, and the users' associations. slurmctld would add the cluster
# itself, but the executor plugin looks up the user's account with sacctmgr and sshare, which need
# an association to report.
setup_accounts() {
    local u
    if ! sacctmgr -n -P list cluster format=cluster | grep -qx "$CLUSTER"; then
        sacctmgr -i add cluster "$CLUSTER" >/dev/null
        say "registered cluster $CLUSTER"
    fi
    if ! sacctmgr -n -P list account "$ACCOUNT" format=account | grep -qx "$ACCOUNT"; then
        sacctmgr -i add account "$ACCOUNT" cluster="$CLUSTER" \
            description="ocpipe test account" organization=ocpipe >/dev/null
        say "added account $ACCOUNT"
    fi
    for u in $USERS; do
        if ! sacctmgr -n -P list assoc cluster="$CLUSTER" user="$u" account="$ACCOUNT" format=user |
            grep -qx "$u"; then
            sacctmgr -i add user "$u" account="$ACCOUNT" cluster="$CLUSTER" defaultaccount="$ACCOUNT" >/dev/null
            say "added user $u to account $ACCOUNT"
        fi
    done
}

# ---------------------------------------------------------------------------------------------
# Starting and stopping

launch() {
    local d=$1
    if use_systemd; then
        systemctl start "${UNIT[$d]}" || fail "$d" "systemctl start ${UNIT[$d]} failed"
        return 0
    fi
    # The SLURM daemons and munged daemonize and return non-zero when they cannot start (bad
    # config, missing key), so their exit status is checked. Output goes to the log so that
    # nothing holds the caller's terminal or pipe open.
    case $d in
        munged)
            runuser -u munge -- /usr/sbin/munged </dev/null >>"${LOGFILE[munged]}" 2>&1 ||
                fail munged "munged exited with status $?" ;;
        mariadb)
            if [ ! -d /var/lib/mysql/mysql ]; then
                say "initialising the MariaDB data directory"
                mariadb-install-db --user=mysql --skip-test-db >/dev/null ||
                    fail mariadb "mariadb-install-db failed"
            fi
            # mariadbd does not daemonize; setsid detaches it from this script's session so it
            # outlives the caller's terminal (mysqld_safe would only add a restart loop and a
            # syslog-only log). -w keeps $! alive exactly as long as mariadbd, whether or not
            # setsid had to fork.
            setsid -w /usr/sbin/mariadbd --user=mysql </dev/null >>"${LOGFILE[mariadb]}" 2>&1 &
            BG_PID[mariadb]=$!
            ;;
        slurmdbd | slurmctld | slurmd)
            "/usr/sbin/$d" </dev/null >>"${LOGFILE[$d]}" 2>&1 || fail "$d" "$d exited with status $?" ;;
    esac
}

# Start the daemon unless it runs, then wait until it answers.
ensure_up() {
    local d=$1
    if ! running "$d"; then
        say "starting $d"
        # A pid file left by a killed daemon would pass for the new one's (see up_or_dead).
        rm -f "${PIDFILE[$d]}"
        LAUNCHED_AT[$d]=$(($(date +%s) - 1)) # the registration time has 1 s resolution
        launch "$d"
        STARTED+=("$d")
    fi
    # Note the early death of a daemon too, rather than wait out the whole timeout for it.
    wait_until up_or_dead "$d" || fail "$d" "did not answer within $WAIT s (check: ${CHECK_DESC[$d]})"
    running "$d" || answers "$d" || fail "$d" "exited during start-up"
}
up_or_dead() {
    answers "$1" && return 0
    # The pid file appears a moment after launch; only a process gone after that counts as dead.
    [ -e "${PIDFILE[$1]}" ] && ! running "$1" && return 0
    # mariadbd is launched in the background and can die before it writes its pid file.
    [ -n "${BG_PID[$1]:-}" ] && ! kill -0 "${BG_PID[$1]}" 2>/dev/null && return 0
    return 1
}

stop_daemon() {
    local d=$1 pid
    pid=$(pid_of "$d") || return 0
    say "stopping $d (pid $pid)"
    if use_systemd; then
        systemctl stop "${UNIT[$d]}" || true
    elif [ "$d" = mariadb ]; then
        # A clean shutdown flushes InnoDB; SIGTERM does too, and serves if the socket does not answer.
        timeout 30 mysqladmin shutdown 2>/dev/null || kill -TERM "$pid" 2>/dev/null || true
    else
        kill -TERM "$pid" 2>/dev/null || true
    fi
    if ! wait_until not_alive "$pid"; then
        warn "$d (pid $pid) still running after $WAIT s; sending SIGKILL"
        kill -KILL "$pid" 2>/dev/null || true
        STOP_FAILED=1
    fi
}
not_alive() { ! kill -0 "$1" 2>/dev/null; }

print_status() {
    local d pid
    for d in "${DAEMONS[@]}"; do
        if pid=$(pid_of "$d"); then
            printf '  %-10s running (pid %s)\n' "$d" "$pid"
        else
            printf '  %-10s not running\n' "$d"
        fi
    done
    if running slurmctld; then timeout 10 sinfo || true; fi
}

cmd_start() {
    local t0=$SECONDS state d
    [ "$(id -u)" -eq 0 ] || { warn "must run as root"; exit 1; }
    STARTED=()
    install_packages
    prepare_system
    write_configs
    # A changed file takes effect only on restart (slurm.conf's node lines are not re-read by
    # "scontrol reconfigure" in this version), so stop the daemons that read it; ensure_up below
    # brings them back with the new content.
    if changed "$MYSQL_CNF"; then stop_daemon mariadb; fi
    if changed "$DBD_CONF"; then stop_daemon slurmdbd; fi
    if changed "$SLURM_CONF"; then stop_daemon slurmd; stop_daemon slurmctld; fi

    ensure_up munged
    ensure_up mariadb
    setup_database
    ensure_up slurmdbd
    setup_accounts
    ensure_up slurmctld
    ensure_up slurmd

    # A node left DRAINED or DOWN by an earlier run (e.g. with another memory size) does not
    # come back by itself; resume it once, now that slurmd has registered with this config.
    state=$(node_state)
    if [[ $state =~ ^(down|drain|fail) ]]; then
        say "node $NODE is $state ($(sinfo -h -n "$NODE" -o %E)); resuming it"
        scontrol update nodename="$NODE" state=resume || true
    fi
    wait_until node_usable ||
        fail slurmd "node $NODE is '$(node_state)', not idle, after $WAIT s ($(sinfo -h -n "$NODE" -o %E))"
    wait_until sacct_answers || fail slurmdbd "sacct does not answer"

    timeout 10 sinfo
    if [ ${#STARTED[@]} -gt 0 ]; then d=${STARTED[*]}; else d="none (all were up)"; fi
    say "cluster $CLUSTER up: node $NODE $(node_state), partition $PARTITION, account $ACCOUNT;" \
        "started: $d; took $((SECONDS - t0)) s"
}
node_usable() { usable_state "$(node_state)"; }
sacct_answers() { timeout 10 sacct -n -X >/dev/null 2>&1; }

cmd_stop() {
    local i
    [ "$(id -u)" -eq 0 ] || { warn "must run as root"; exit 1; }
    STOP_FAILED=0
    for ((i = ${#DAEMONS[@]} - 1; i >= 0; i--)); do stop_daemon "${DAEMONS[i]}"; done
    [ "$STOP_FAILED" -eq 0 ] || { warn "some daemons had to be killed"; exit 1; }
    say "all stopped"
}

cmd_status() {
    local d ok=0 state
    print_status
    for d in "${DAEMONS[@]}"; do running "$d" || ok=1; done
    if [ $ok -eq 0 ]; then
        state=$(node_state)
        if ! usable_state "$state"; then
            warn "node $NODE is '${state:-not listed}'"
            ok=1
        fi
    fi
    return $ok
}

case ${1:-start} in
    start) cmd_start ;;
    stop) cmd_stop ;;
    status) cmd_status ;;
    *) echo "usage: $0 [start|stop|status]" >&2; exit 2 ;;
esac
