#!/usr/bin/env bash
# Shared history, one topology (docs/postgres.md, "Shared history: a ship's history
# streamed ashore"): a ship's station keeps its history in a PostgreSQL server on the ship;
# a PostgreSQL server ashore is its hot standby, fed by streaming replication through a
# replication slot. The test runs both servers, a station and a simulated vehicle inside
# network namespace NETNS, and checks that
#   - what the ship's station commits reaches the shore, readable there with plain SQL;
#   - the shore cannot write into the ship's history (a standby is read-only);
#   - after an outage of the shore (the standby stopped while the ship keeps writing), the
#     slot has kept what the shore missed, and the shore catches up to the same rows;
# and prints the WAL the ship produced per second and per state vector, the bandwidth the
# link must carry.
#
# Usage: SHOAL_BIN=target/release/shoal tests/history/replication.sh NETNS
# Needs root (the servers run as the `postgres` OS user, as scripts/postgres.sh runs them).
set -euo pipefail

ns="${1:?usage: SHOAL_BIN=... $0 NETNS}"
bin="${SHOAL_BIN:?SHOAL_BIN must name the shoal binary}"
repo="$(cd "$(dirname "$0")/../.." && pwd)"
say() { echo "replication: $*"; }
fail() { echo "replication: FAILED: $*" >&2; exit 1; }

work="$(mktemp -d /tmp/shoal-replication.XXXXXX)"
chmod 755 "$work"
ship_pg="$work/ship-pg"
shore_pg="$work/shore-pg"
ship_port=54341
shore_port=54342
api_port=18631
domain=149
station_pid=""
vehicle_pid=""
pgbin="$(ls -d /usr/lib/postgresql/*/bin 2>/dev/null | sort -V | tail -n 1)"

stop_pid() {
    if [[ -n "$1" ]] && kill -0 "$1" 2>/dev/null; then
        kill "$1" 2>/dev/null || true
        wait "$1" 2>/dev/null || true
    fi
}
shore_ctl() {
    runuser -u postgres -- "$pgbin/pg_ctl" -D "$shore_pg/data" "$@"
}
cleanup() {
    stop_pid "$vehicle_pid"
    stop_pid "$station_pid"
    shore_ctl -m fast -w -t 60 stop >/dev/null 2>&1 || true
    SHOAL_PG_DIR="$ship_pg" SHOAL_PG_PORT="$ship_port" "$repo/scripts/postgres.sh" stop \
        >/dev/null 2>&1 || true
    rm -rf "$work"
}
trap cleanup EXIT

# psql against the ship (primary) or the shore (standby), as the station's role; one value.
sql() {
    local port="$1" query="$2"
    ip netns exec "$ns" runuser -u postgres -- "$pgbin/psql" -X -q -tA \
        -h 127.0.0.1 -p "$port" -U shoal -d shoal -c "$query"
}
state_vectors() { sql "$1" "SELECT count(*) FROM state_vector WHERE vehicle_id = 'auv-h1'"; }
# Polls until `$2` (a shell test on $n, the value of `$1`) holds; fails after `$3` s.
wait_until() {
    local what="$1" cond="$2" secs="$3" n
    for ((i = 0; i < secs * 2; i++)); do
        n="$(eval "$what" 2>/dev/null || echo 0)"
        if eval "$cond"; then echo "$n"; return 0; fi
        sleep 0.5
    done
    fail "after ${secs} s: $what = ${n:-?}, wanted $cond"
}

say "the ship's server (primary) on 127.0.0.1:$ship_port in $ns"
ship_url="$(SHOAL_PG_DIR="$ship_pg" SHOAL_PG_PORT="$ship_port" \
    "$repo/scripts/postgres.sh" start --netns "$ns")"

say "the shore's server: a base backup of the ship's, following it through slot 'shore'"
mkdir -p "$shore_pg/run"
chown postgres:postgres "$shore_pg" "$shore_pg/run"
chmod 700 "$shore_pg" "$shore_pg/run"
# -R: standby.signal and primary_conninfo; -C -S: a slot on the ship, so the ship keeps
# the WAL the shore has not received while the link is down.
ip netns exec "$ns" runuser -u postgres -- "$pgbin/pg_basebackup" -h 127.0.0.1 \
    -p "$ship_port" -U postgres -D "$shore_pg/data" -R -C -S shore -X stream >/dev/null
runuser -u postgres -- tee "$shore_pg/data/shoal.conf" >/dev/null <<EOF
listen_addresses = '127.0.0.1'
port = $shore_port
unix_socket_directories = '$shore_pg/run'
hot_standby = on
EOF
start_shore() {
    ip netns exec "$ns" runuser -u postgres -- "$pgbin/pg_ctl" -D "$shore_pg/data" \
        -l "$shore_pg/postgres.log" -w -t 60 start </dev/null >/dev/null 2>&1 \
        || { tail -n 20 "$shore_pg/postgres.log" >&2; fail "the shore's server did not start"; }
}
start_shore

say "a ship's station writing its history to the ship's server, and a simulated AUV"
mkdir -p "$work/ship"
(cd "$work/ship" && exec ip netns exec "$ns" env SHOAL_DDS__DOMAIN_ID="$domain" \
    SHOAL_CONSOLE__AUTH__ENABLED=false SHOAL_HISTORY__BACKEND=postgres \
    SHOAL_HISTORY__POSTGRES_URL="$ship_url" \
    "$bin" --insecure station --scenario none --listen "127.0.0.1:$api_port" \
    >"$work/station.log" 2>&1) &
station_pid=$!
(cd "$work/ship" && exec ip netns exec "$ns" env SHOAL_DDS__DOMAIN_ID="$domain" \
    "$bin" --insecure vehicle --sim auv --id auv-h1 --lat 63.44 --lon 10.36 --rate 10 \
    >"$work/vehicle.log" 2>&1) &
vehicle_pid=$!

start_rows="$(wait_until "state_vectors $ship_port" '(( n >= 5 ))' 90)" \
    || { tail -n 30 "$work/station.log" >&2; exit 1; }
# The link's load is measured from here, the station and its vehicle running.
t0=$SECONDS
start_lsn="$(sql "$ship_port" "SELECT pg_current_wal_lsn()")"
start_rows="$(state_vectors "$ship_port")"
say "the ship has $start_rows state vectors of auv-h1; waiting for the shore"
wait_until "state_vectors $shore_port" '(( n >= 5 ))' 30 >/dev/null
# Read-only ashore: the ship's history cannot be altered from there.
if sql "$shore_port" "DELETE FROM state_vector" >/dev/null 2>"$work/delete.err"; then
    fail "the shore deleted from the ship's history"
fi
grep -q "read-only" "$work/delete.err" || fail "unexpected refusal: $(cat "$work/delete.err")"
say "the shore reads the ship's history and cannot write to it"

say "outage: the shore's server stopped for 10 s while the ship goes on writing"
before="$(state_vectors "$shore_port")"
shore_ctl -m fast -w -t 60 stop >/dev/null
sleep 10
retained="$(sql "$ship_port" "SELECT pg_wal_lsn_diff(pg_current_wal_lsn(), restart_lsn) FROM pg_replication_slots WHERE slot_name = 'shore'")"
say "the ship's slot keeps ${retained} bytes of WAL for the shore"
start_shore
during="$(state_vectors "$ship_port")"
(( during > before )) || fail "the ship wrote nothing during the outage ($before, $during)"
wait_until "state_vectors $shore_port" "(( n >= $during ))" 60 >/dev/null
say "the shore caught up: $during state vectors (it had $before before the outage)"

# The same rows on both sides, once the station has stopped writing.
stop_pid "$vehicle_pid"; vehicle_pid=""
stop_pid "$station_pid"; station_pid=""
end_lsn="$(sql "$ship_port" "SELECT pg_current_wal_lsn()")"
total="$(state_vectors "$ship_port")"
wait_until "state_vectors $shore_port" "(( n == $total ))" 60 >/dev/null
for table in vehicle task_assignment event observation; do
    a="$(sql "$ship_port" "SELECT count(*) FROM $table")"
    b="$(sql "$shore_port" "SELECT count(*) FROM $table")"
    [[ "$a" == "$b" ]] || fail "$table: $a rows on the ship, $b ashore"
done
elapsed=$(( SECONDS - t0 ))
wal="$(sql "$ship_port" "SELECT pg_wal_lsn_diff('$end_lsn', '$start_lsn')")"
rows=$(( total - start_rows ))
rate=$(( ${wal%.*} / (elapsed > 0 ? elapsed : 1) ))
per_sv=$(( ${wal%.*} / (rows > 0 ? rows : 1) ))
say "WAL shipped ashore: ${wal%.*} bytes in ${elapsed} s, $rows state vectors of one simulated AUV at 10 Hz (~${rate} B/s, ~${per_sv} B of WAL per state vector, everything included)"
say "passed"
