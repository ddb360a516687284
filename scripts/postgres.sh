#!/usr/bin/env bash
# A private PostgreSQL server for Shoal's history store (tests, development, a single
# station), listening only on 127.0.0.1 and on a unix socket inside its own directory.
#
# Usage:
#   scripts/postgres.sh start [--netns NAME]   start it (installing Debian's postgresql
#                                              and creating the cluster if needed); prints
#                                              the connection string
#   scripts/postgres.sh stop                   stop it (wherever it runs)
#   scripts/postgres.sh status                 say whether it runs, and where
#   scripts/postgres.sh url                    print the connection string
#
# --netns NAME runs the server inside network namespace NAME (created, loopback only, if
# missing), for clients that run there: a namespace has a loopback of its own, so a server
# on the host's 127.0.0.1 is invisible from inside it. A server already running elsewhere
# is restarted there. The unix socket works from everywhere (it is a file).
#
# Environment: SHOAL_PG_DIR (default /tmp/shoal-pg) holds the cluster (data/), its socket
# (run/) and its log (postgres.log); SHOAL_PG_PORT (default 54329) is the TCP port.
# The cluster belongs to the `postgres` OS user; authentication is `trust`, for local and
# loopback connections only. Role `shoal` owns database `shoal`. Needs root (or running
# as `postgres`). Every command is idempotent and safe to repeat; a stale pid file is
# cleaned up.
set -euo pipefail

die() { echo "postgres.sh: $*" >&2; exit 2; }
note() { echo "postgres.sh: $*" >&2; }
usage() {
    awk 'NR > 1 && /^#/ { sub(/^# ?/, ""); print; next } NR > 1 { exit }' "$0" >&2
    exit 2
}

DIR="${SHOAL_PG_DIR:-/tmp/shoal-pg}"
PORT="${SHOAL_PG_PORT:-54329}"
[[ "$DIR" == /* ]] || die "SHOAL_PG_DIR must be an absolute path (got '$DIR')"
DIR="${DIR%/}"
[[ "$PORT" =~ ^[0-9]{1,5}$ ]] && (( PORT > 0 && PORT < 65536 )) || die "bad SHOAL_PG_PORT '$PORT'"
DATA="$DIR/data"
RUN="$DIR/run"
LOG="$DIR/postgres.log"
NETNS_FILE="$DIR/netns"
URL="host=127.0.0.1 port=$PORT user=shoal dbname=shoal"

# Runs a command as the cluster's owner.
as_pg() {
    if [[ "$(id -u)" == 0 ]]; then
        runuser -u postgres -- "$@"
    else
        [[ "$(id -un)" == postgres ]] || die "run as root or as the postgres user"
        "$@"
    fi
}

# The newest installed server's bin directory, or nothing.
find_bin() {
    local d
    d=$(ls -d /usr/lib/postgresql/*/bin 2>/dev/null | sort -V | tail -n 1 || true)
    if [[ -n "$d" && -x "$d/initdb" ]]; then echo "$d"; fi
}

install_server() {
    [[ "$(id -u)" == 0 ]] || die "PostgreSQL is not installed and installing it needs root"
    note "installing Debian's postgresql"
    # Only our private cluster should exist: no default cluster on port 5432.
    mkdir -p /etc/postgresql-common/createcluster.d
    echo "create_main_cluster = false" >/etc/postgresql-common/createcluster.d/shoal.conf
    local apt=(env DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends postgresql)
    if ! "${apt[@]}"; then
        note "install failed; updating the package lists and trying again"
        apt-get update
        "${apt[@]}"
    fi
}

# The pid of the running server of this cluster, or nothing. The pid file alone is not
# proof: after a crash or a reboot its pid may be dead, or reused by another program.
running_pid() {
    local pid comm state
    [[ -f "$DATA/postmaster.pid" ]] || return 0
    pid=$(head -n 1 "$DATA/postmaster.pid" 2>/dev/null || true)
    [[ "$pid" =~ ^[0-9]+$ ]] || return 0
    comm=$(cat "/proc/$pid/comm" 2>/dev/null || true)
    # A zombie keeps its name but serves nothing.
    state=$(awk '{print $3}' "/proc/$pid/stat" 2>/dev/null || true)
    if [[ ( "$comm" == postgres || "$comm" == postmaster ) && "$state" != Z ]]; then
        echo "$pid"
    fi
}

# The network namespace a process runs in ("" for the host's).
netns_of() {
    ip netns identify "$1" 2>/dev/null | awk '{print $1}' || true
}

clean_stale() {
    if [[ -f "$DATA/postmaster.pid" && -z "$(running_pid)" ]]; then
        note "removing a stale pid file"
        rm -f "$DATA/postmaster.pid" "$RUN/.s.PGSQL.$PORT.lock" "$RUN/.s.PGSQL.$PORT"
    fi
}

init_cluster() {
    local bin="$1"
    mkdir -p "$DIR" "$RUN"
    if [[ "$(id -u)" == 0 ]]; then
        chown postgres:postgres "$DIR" "$RUN"
    fi
    chmod 700 "$DIR"
    chmod 700 "$RUN"
    if [[ ! -f "$DATA/PG_VERSION" ]]; then
        note "creating the cluster in $DATA"
        # C collation: byte order, as the history's columns declare anyway.
        as_pg "$bin/initdb" -D "$DATA" --username=postgres --auth=trust \
            --encoding=UTF8 --no-locale >/dev/null
    fi
    cluster_bin >/dev/null
    # Rewritten at every start, so a changed port or directory takes effect.
    as_pg tee "$DATA/shoal.conf" >/dev/null <<EOF
# Written by scripts/postgres.sh; rewritten at every start.
listen_addresses = '127.0.0.1'
port = $PORT
unix_socket_directories = '$RUN'
log_destination = 'stderr'
logging_collector = off
EOF
    if ! grep -q "^include_if_exists = 'shoal.conf'" "$DATA/postgresql.conf"; then
        echo "include_if_exists = 'shoal.conf'" | as_pg tee -a "$DATA/postgresql.conf" >/dev/null
    fi
    as_pg tee "$DATA/pg_hba.conf" >/dev/null <<EOF
# Written by scripts/postgres.sh: trust, but only on this machine's socket and loopback.
# TYPE  DATABASE  USER  ADDRESS       METHOD
local   all       all                 trust
host    all       all   127.0.0.1/32  trust
# Streaming replication (a standby ashore, tests/history/replication.sh), loopback too.
local   replication  all                 trust
host    replication  all   127.0.0.1/32  trust
EOF
}

# The bin directory of the PostgreSQL version that made the cluster.
cluster_bin() {
    local major
    major=$(cat "$DATA/PG_VERSION")
    [[ -x "/usr/lib/postgresql/$major/bin/postgres" ]] \
        || die "$DATA was made by PostgreSQL $major, which is not installed (remove $DIR to start afresh)"
    echo "/usr/lib/postgresql/$major/bin"
}

# Runs a command with only stdin, stdout and stderr open. The server outlives this script
# and would otherwise keep every descriptor it inherits: our lock (so a second `start`
# would wait forever) and whatever pipes the caller holds (so the caller's `$(...)` or
# job control would wait for the server to exit).
without_inherited_fds() {
    (
        for fd in $(ls /proc/$BASHPID/fd); do
            if (( fd > 2 )); then eval "exec $fd>&-" 2>/dev/null || true; fi
        done
        exec "$@"
    )
}

psql_admin() {
    as_pg "$1/psql" -X -q -v ON_ERROR_STOP=1 -h "$RUN" -p "$PORT" -U postgres -d postgres -tA -c "$2"
}

ensure_role_and_db() {
    local bin="$1"
    if [[ -z "$(psql_admin "$bin" "SELECT 1 FROM pg_roles WHERE rolname = 'shoal'")" ]]; then
        psql_admin "$bin" "CREATE ROLE shoal LOGIN" >/dev/null
    fi
    if [[ -z "$(psql_admin "$bin" "SELECT 1 FROM pg_database WHERE datname = 'shoal'")" ]]; then
        psql_admin "$bin" "CREATE DATABASE shoal OWNER shoal" >/dev/null
    fi
}

stop_server() {
    local bin="$1" pid
    pid=$(running_pid)
    if [[ -z "$pid" ]]; then
        clean_stale
        rm -f "$NETNS_FILE"
        return 0
    fi
    # Signals cross network namespaces: this works wherever the server runs.
    as_pg "$bin/pg_ctl" -D "$DATA" -m fast -w -t 60 stop >/dev/null
    rm -f "$NETNS_FILE"
}

cmd_start() {
    local netns=""
    while [[ $# -gt 0 ]]; do
        case "$1" in
            --netns) [[ $# -ge 2 ]] || die "--netns needs a name"; netns="$2"; shift 2 ;;
            --netns=*) netns="${1#--netns=}"; shift ;;
            *) die "unknown argument '$1'" ;;
        esac
    done
    if [[ -n "$netns" ]]; then
        [[ "$netns" =~ ^[A-Za-z0-9_.-]{1,64}$ ]] || die "bad namespace name '$netns'"
        command -v ip >/dev/null || die "'ip' not found (apt-get install iproute2)"
        if ! ip netns list 2>/dev/null | awk '{print $1}' | grep -qx -- "$netns"; then
            note "creating network namespace $netns (loopback only)"
            ip netns add "$netns" 2>/dev/null || true
        fi
        ip -n "$netns" link set lo up
    fi

    local bin
    bin=$(find_bin)
    if [[ -z "$bin" ]]; then
        install_server
        bin=$(find_bin)
        [[ -n "$bin" ]] || die "no /usr/lib/postgresql/*/bin/initdb after installing postgresql"
    fi
    id postgres >/dev/null 2>&1 || die "there is no 'postgres' OS user (the postgresql package creates it)"

    mkdir -p "$(dirname "$DIR")"
    exec 9>"$DIR.lock"
    flock 9

    local pid
    pid=$(running_pid)
    if [[ -n "$pid" ]]; then
        local where
        where=$(netns_of "$pid")
        if [[ "$where" == "$netns" ]]; then
            ensure_role_and_db "$bin"
            echo "$URL"
            return 0
        fi
        note "the server runs in namespace '${where:-host}', not '${netns:-host}': restarting it"
        stop_server "$bin"
    fi
    clean_stale
    init_cluster "$bin"
    bin=$(cluster_bin)

    local launch=()
    if [[ -n "$netns" ]]; then launch=(ip netns exec "$netns"); fi
    if [[ "$(id -u)" == 0 ]]; then launch+=(runuser -u postgres --); fi
    if ! without_inherited_fds "${launch[@]}" "$bin/pg_ctl" -D "$DATA" -l "$LOG" -w -t 60 start >/dev/null; then
        tail -n 20 "$LOG" >&2 || true
        die "the server did not start (log: $LOG)"
    fi
    if [[ -n "$netns" ]]; then echo "$netns" >"$NETNS_FILE"; else rm -f "$NETNS_FILE"; fi
    ensure_role_and_db "$bin"
    echo "$URL"
}

cmd_stop() {
    local bin
    bin=$(find_bin)
    if [[ -z "$bin" ]]; then
        note "PostgreSQL is not installed; nothing to stop"
        return 0
    fi
    [[ -f "$DATA/PG_VERSION" ]] || { note "no cluster in $DIR; nothing to stop"; return 0; }
    exec 9>"$DIR.lock"
    flock 9
    bin=$(cluster_bin)
    stop_server "$bin"
    note "stopped"
}

cmd_status() {
    local pid
    pid=$(running_pid)
    if [[ -z "$pid" ]]; then
        echo "not running"
        return 3
    fi
    local where
    where=$(netns_of "$pid")
    echo "running (pid $pid, network namespace: ${where:-host}): $URL"
}

case "${1:-}" in
    start) shift; cmd_start "$@" ;;
    stop) shift; [[ $# -eq 0 ]] || die "stop takes no arguments"; cmd_stop ;;
    status) shift; cmd_status ;;
    url) echo "$URL" ;;
    -h|--help|"") usage ;;
    *) die "unknown command '$1' (start, stop, status, url)" ;;
esac
