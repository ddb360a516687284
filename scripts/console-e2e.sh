#!/usr/bin/env bash
# The web console in a real browser: starts `shoal up` (station, simulated fleet, console
# with [console.auth] on) inside a private network namespace, then runs
# crates/shoal-console/web/tests/*.test.js with playwright-core driving Debian's Chromium
# in the same namespace (one test also starts a `shoal vehicle --sim` of its own on the
# same DDS domain, to watch it go stale and lost). It also runs a short `shoal scenario
# run` and opens its HTML report from the file, offline
# (web/tests/scenario-report.e2e.test.js). A second station, site "ship" (DDS domain 147,
# its own simulated AUV), is federated over Zenoh on 127.0.0.1 to the `shoal up` station,
# site "shore", whose console shows the ship's vehicle as another site's
# (web/tests/federation.e2e.test.js). Screenshots and the browser's request log go
# to target/console-e2e/.
#
# Usage: scripts/console-e2e.sh [<netns>]        (default: shoal-test)
#   SHOAL_BIN   the shoal binary (default: target/release/shoal; build it first with
#               cargo build --release -p shoal)
#   SHOAL_E2E_PORT  console port inside the namespace (default 18640); the AIS input is
#               on the next port, the federation's Zenoh endpoint on the one after, the
#               ship station's console on the one after that
#
# Needs root (network namespace; installs chromium with apt-get if /usr/bin/chromium is
# missing), node and npm (web/node_modules is installed with npm ci if missing).
# Exits non-zero on any failure and prints one summary line.
set -euo pipefail

repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
ns="${1:-shoal-test}"
bin="${SHOAL_BIN:-$repo/target/release/shoal}"
port="${SHOAL_E2E_PORT:-18640}"
web="$repo/crates/shoal-console/web"
out="$repo/target/console-e2e"
started=$(date +%s)

summary() { echo "console-e2e: $*"; }
die() { summary "FAILED: $*"; exit 1; }

[[ -x "$bin" ]] || die "no shoal binary at $bin (cargo build --release -p shoal, or set SHOAL_BIN)"
# The station runs from other directories and inside `ip netns exec`: make a relative path absolute.
bin="$(realpath "$bin")"
command -v node >/dev/null || die "node is not installed (Debian: apt-get install nodejs npm)"
if [[ ! -x /usr/bin/chromium ]]; then
    echo "console-e2e: installing Debian's chromium" >&2
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null 2>&1 || {
        apt-get update -qq >/dev/null && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null
    } || die "cannot install chromium (apt-get install chromium)"
fi
if [[ ! -d "$web/node_modules/playwright-core" ]]; then
    # Outside the namespace: npm needs the registry.
    (cd "$web" && npm ci --no-audit --no-fund --loglevel=error) || die "npm ci failed in $web"
fi

"$repo/scripts/netns-run.sh" --setup "$ns" || die "cannot set up network namespace $ns"
rm -rf "$out"
mkdir -p "$out"
work="$(mktemp -d /tmp/shoal-console-e2e.XXXXXX)"
up_pid=""
ship_pid=""
ship_vehicle_pid=""
# Stops one process of ours by its id: SIGINT (a clean stop), SIGKILL after 20 s.
stop() {
    local pid="$1"
    if [[ -n "$pid" ]] && kill -0 "$pid" 2>/dev/null; then
        kill -INT "$pid" 2>/dev/null || true
        for _ in $(seq 1 100); do kill -0 "$pid" 2>/dev/null || break; sleep 0.2; done
        kill -KILL "$pid" 2>/dev/null || true
    fi
}
cleanup() {
    stop "$up_pid"
    stop "$ship_vehicle_pid"
    stop "$ship_pid"
    rm -rf "$work"
}
trap cleanup EXIT

# The configuration file below decides the console's logins: a caller's environment
# (scripts/test.sh may turn logins off for other tests) must not override it.
unset SHOAL_CONSOLE__AUTH__ENABLED SHOAL_CONSOLE__AUTH__INITIAL_ADMIN_PASSWORD \
    SHOAL_CONSOLE__AUTH__INITIAL_ADMIN_TOKEN SHOAL_CONSOLE__ALLOWED_HOSTS

# A fresh admin token for this run (logins are on by default; this is the harness's own
# credential, handed to the station as [console.auth] initial_admin_token).
token="shoal_test_$(od -An -tx1 -N24 /dev/urandom | tr -d ' \n')"

zenoh_port=$((port + 2))
ship_port=$((port + 3))

# DDS domain 145: the console's tests use 140-149, so they never meet other tests' DDS.
# [federation]: this station is site "shore" and connects to the ship's station started
# below. Of the commands given this file, only the station that `shoal up` starts joins
# the federation (`shoal scenario run` and `shoal record` do not read the section).
cat > "$work/shoal.toml" <<EOF
[dds]
domain_id = 145

[station]
rules_path = "$work/rules.json"
summary_interval_s = 0.0

[history]
path = "$work/history.db"

[vehicle]
state_dir = "$work/vehicles"

[console]
listen = "127.0.0.1:$port"

# AIS traffic for the map test, sent by the browser test over UDP.
[traffic]
inputs = ["udp://127.0.0.1:$((port + 1))"]

[console.auth]
enabled = true
users_path = "$work/console-users.json"
# The first admin token is set here rather than printed, so this script knows it; the
# station must then show it nowhere (checked below).
initial_admin_token = "$token"

[federation]
enabled = true
site = "shore"
listen = []
connect = ["tcp/127.0.0.1:$zenoh_port"]
remote_sites = ["ship"]
# Site identity (the default): the shore authenticates to the ship, which listens and
# checks it against its own dictionary (written below).
password_file = "$work/shore.password"
credentials_file = "$work/shore-sites.txt"
EOF
# Site identity for both sites: each one's password, and Zenoh's dictionary of the
# other's (<site>:<password> a line). Fresh random passwords, readable by root only.
shore_pw="$(head -c 18 /dev/urandom | base64 | tr -d '/+=')"
ship_pw="$(head -c 18 /dev/urandom | base64 | tr -d '/+=')"
(
    umask 077
    printf '%s\n' "$shore_pw" >"$work/shore.password"
    printf 'ship:%s\n' "$ship_pw" >"$work/shore-sites.txt"
    printf '%s\n' "$ship_pw" >"$work/ship.password"
    printf 'shore:%s\n' "$shore_pw" >"$work/ship-sites.txt"
)

# Site "ship": a station of its own (DDS domain 147, no DDS Security, no console logins:
# only the shore's federation talks to it, on loopback in the namespace) and one
# simulated AUV on its domain, in water off the shore's fleet. Started first, so the
# shore finds its Zenoh endpoint (a peer retries its connect endpoints anyway). Its
# default paths (rules, the vehicle's task ledger) land in a directory of its own.
mkdir -p "$work/ship"
ship_env=(SHOAL_DDS__DOMAIN_ID=147 SHOAL_CONSOLE__AUTH__ENABLED=false)
(cd "$work/ship" && exec ip netns exec "$ns" env "${ship_env[@]}" \
    SHOAL_FEDERATION__ENABLED=true SHOAL_FEDERATION__SITE=ship \
    SHOAL_FEDERATION__LISTEN="[\"tcp/127.0.0.1:$zenoh_port\"]" \
    SHOAL_FEDERATION__CONNECT='[]' SHOAL_FEDERATION__REMOTE_SITES='["shore"]' \
    SHOAL_FEDERATION__PASSWORD_FILE="$work/ship.password" \
    SHOAL_FEDERATION__CREDENTIALS_FILE="$work/ship-sites.txt" \
    SHOAL_FEDERATION__POSITIONS__MAX_RATE_HZ=1.0 \
    SHOAL_FEDERATION__ENVIRONMENT__MODE=aggregated SHOAL_FEDERATION__ENVIRONMENT__WINDOW_S=5 \
    "$bin" --insecure station --scenario none --listen "127.0.0.1:$ship_port" --db :memory: \
    >"$out/ship-station.log" 2>&1) &
ship_pid=$!
(cd "$work/ship" && exec ip netns exec "$ns" env "${ship_env[@]}" \
    "$bin" --insecure vehicle --sim auv --id ship-auv-1 --lat 63.455 --lon 10.35 \
    >"$out/ship-vehicle.log" 2>&1) &
ship_vehicle_pid=$!

# --scenario none: the tests dispatch their own tasks and expect idle vehicles; the
# default scenario (scenarios/sea-trial.toml) would keep them busy.
ip netns exec "$ns" "$bin" --config "$work/shoal.toml" up --scenario none >"$out/shoal-up.log" 2>&1 &
up_pid=$!

# Wait for the console to answer, then check the token is in no log line.
ready=""
for _ in $(seq 1 300); do
    kill -0 "$up_pid" 2>/dev/null || die "shoal up exited early; see $out/shoal-up.log"
    if ip netns exec "$ns" curl -sf "http://127.0.0.1:$port/api/health" >/dev/null 2>&1; then
        ready=1
        break
    fi
    sleep 0.2
done
[[ -n "$ready" ]] || die "the console did not answer within 60 s; see $out/shoal-up.log"
# The ship's side must still run, or the federation test would only time out.
kill -0 "$ship_pid" 2>/dev/null || die "the ship's station exited early; see $out/ship-station.log"
kill -0 "$ship_vehicle_pid" 2>/dev/null || die "the ship's vehicle exited early; see $out/ship-vehicle.log"
if grep -aqF "$token" "$out/shoal-up.log"; then
    die "the admin token appears in $out/shoal-up.log: credentials must never be logged"
fi
for log in "$out/shoal-up.log" "$out/ship-station.log"; do
    if grep -aqF -e "$shore_pw" -e "$ship_pw" "$log"; then
        die "a federation password appears in $log: credentials must never be logged"
    fi
done
# Logins are on: the token must be required and must work.
code="$(ip netns exec "$ns" curl -s -o /dev/null -w '%{http_code}' "http://127.0.0.1:$port/api/fleet")"
[[ "$code" == 401 ]] || die "GET /api/fleet without credentials answered $code, not 401"
ip netns exec "$ns" curl -sf -H "Authorization: Bearer $token" "http://127.0.0.1:$port/api/fleet" >/dev/null \
    || die "the configured admin token does not work"

# A headless scenario run (DDS domain 146), ten simulated minutes at 100x, whose report
# the browser opens from its file.
ip netns exec "$ns" "$bin" --config "$work/shoal.toml" scenario run sea-trial --speed 100 \
    --duration 600 --domain 146 --out "$work/run" >"$out/scenario-run.log" 2>&1 \
    || die "shoal scenario run failed; see $out/scenario-run.log"

set +e
ip netns exec "$ns" env \
    SHOAL_REPORT="$work/run/report.html" \
    SHOAL_URL="http://127.0.0.1:$port" \
    SHOAL_SHIP_URL="http://127.0.0.1:$ship_port" \
    SHOAL_AIS_PORT="$((port + 1))" \
    SHOAL_ADMIN_TOKEN="$token" \
    SHOAL_E2E_OUT="$out" \
    SHOAL_BIN="$bin" \
    SHOAL_E2E_CONFIG="$work/shoal.toml" \
    node --test --test-reporter=spec --test-reporter-destination=stdout \
    "$web/tests/console.e2e.test.js" "$web/tests/scenario-report.e2e.test.js" \
    "$web/tests/federation.e2e.test.js" 2>&1 | tee "$out/results.txt"
status=${PIPESTATUS[0]}
set -e

pass=$(grep -aoE '^ℹ pass [0-9]+' "$out/results.txt" | awk '{print $3}' | tail -n1)
fail=$(grep -aoE '^ℹ fail [0-9]+' "$out/results.txt" | awk '{print $3}' | tail -n1)
elapsed=$(( $(date +%s) - started ))
shots=$(find "$out" -name '*.png' | wc -l)
if [[ $status -ne 0 || -z "$pass" || "${fail:-1}" != "0" ]]; then
    summary "FAILED: ${pass:-0} passed, ${fail:-?} failed in ${elapsed} s; $shots screenshots and logs in $out"
    exit 1
fi
summary "${pass} passed, 0 failed in ${elapsed} s; $shots screenshots in $out"
