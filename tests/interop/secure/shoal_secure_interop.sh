#!/usr/bin/env bash
# A Shoal station (OMG DDS Security 1.1 on, credentials from `shoal keys`) with foreign
# secured vehicles: Fast DDS 2.9.1 (tests/interop/build/fastdds_peer) as auv-7 and
# Debian's Cyclone DDS 0.10.2 from C (tests/interop/build/cyclone_c_peer) as auv-8, each
# loading the enclave `shoal keys export` wrote (<bundle>/dds/) with its stack's own
# builtin plugins. Everything runs in a private loopback-only network namespace.
#
#   keys     shoal keys init / issue / export; the station's subject hash sorts lowest,
#            so the station starts every PKI-DH handshake (Fast DDS 2.9 cannot)
#   state    each foreign vehicle's announcement + state reach the station: /api/fleet
#            lists it alive (also a Fast DDS auv-2, whose subject hash sorts below an
#            unground station subject's)
#   task     a mission started through the HTTP API reaches each foreign vehicle
#   outsider a peer without security: never in /api/fleet, receives no task
#   attack   auv-8's credentials claiming auv-7 in auv-8's partition: refused and counted
#            (ingest.rejected["security:impersonation"]), auv-7's entry untouched; a
#            TaskAssignment from a vehicle's credentials: refused by its own stack
#   wire     during state and task, no user DATA in clear on lo, and neither the vehicle
#            id nor a position value in any DATA payload of a user writer; control: the
#            same capture sees the outsider's id and position in clear
#
# Usage: tests/interop/secure/shoal_secure_interop.sh [-v]
#   SHOAL_BIN  the shoal binary (default target/release/shoal; built once with
#              `cargo build --release -p shoal` if missing and SHOAL_BIN is unset)
# Needs root (network namespace) and scripts/install-test-deps.sh done. About 1.5 min.
# Prints PASS/FAIL per step, then "N passed, M failed"; exits non-zero if anything failed.
set -uo pipefail

HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
REPO="$(cd "$HERE/../../.." && pwd)"

# shellcheck source=../../lib/own-netns.sh
source "$REPO/tests/lib/own-netns.sh"
[[ -n "${SHOAL_OWN_NETNS:-}" ]] || need_shoal_release
own_netns secint "$@"

VERBOSE=0
[[ "${1:-}" == "-v" ]] && VERBOSE=1
SHOAL="${SHOAL_BIN:-$REPO/target/release/shoal}"
FASTDDS="$REPO/tests/interop/build/fastdds_peer"
CYCLONE="$REPO/tests/interop/build/cyclone_c_peer"
for b in "$SHOAL" "$FASTDDS" "$CYCLONE"; do
    [[ -x "$b" ]] || { echo "missing $b: run scripts/install-test-deps.sh (and build shoal)" >&2; exit 2; }
done
for c in curl python3; do
    command -v $c >/dev/null || { echo "missing $c: run scripts/install-test-deps.sh" >&2; exit 2; }
done

# Domain 186: no other test uses it (and this namespace is ours alone anyway); secured
# swarms must stay within 0-230.
DOMAIN=186
PORT=18686
WORK="$(mktemp -d /tmp/shoal-secint.XXXXXX)"
STATION_PID=""
# shellcheck source=../../lib/report.sh
source "$REPO/tests/lib/report.sh"
trap stop_everything EXIT
# The config file decides the console's logins, not the caller's environment.
unset SHOAL_CONSOLE__AUTH__ENABLED SHOAL_CONSOLE__AUTH__INITIAL_ADMIN_PASSWORD \
    SHOAL_CONSOLE__AUTH__INITIAL_ADMIN_TOKEN SHOAL_CONSOLE__ALLOWED_HOSTS SHOAL_SECURITY__ENABLED


TOKEN="shoal_test_$(od -An -tx1 -N24 /dev/urandom | tr -d ' \n')"
api() {  # api <path> [curl args...]: the body on stdout; fails on HTTP errors
    local path="$1"; shift
    curl -sS --fail-with-body -m 10 -H "Authorization: Bearer $TOKEN" "$@" "http://127.0.0.1:$PORT$path"
}
# fleet_field <id> <python expression over v (the vehicle's entry)>: prints its value,
# or "absent" when the fleet has no such vehicle.
fleet_field() {
    api /api/fleet 2>/dev/null | python3 -c '
import json, sys
vid, expr = sys.argv[1], sys.argv[2]
try:
    doc = json.load(sys.stdin)
except ValueError:
    print("unreadable"); sys.exit()
items = doc.get("vehicles", doc) if isinstance(doc, dict) else doc
for v in items:
    if isinstance(v, dict) and (v.get("vehicle_id") == vid or v.get("id") == vid
                                or (v.get("announcement") or {}).get("vehicle_id") == vid):
        try:
            print(eval(expr))
        except Exception as e:
            print(f"?{e!r}")
        break
else:
    print("absent")' "$1" "$2"
}
contact() { fleet_field "$1" 'v.get("contact")'; }
wait_contact() {  # wait_contact <id> <want> <seconds>
    local i c=""
    for ((i = 0; i < $3 * 2; i++)); do
        c=$(contact "$1")
        [[ "$c" == "$2" ]] && { echo "$c"; return 0; }
        sleep 0.5
    done
    echo "$c"; return 1
}
impersonations() {
    api /api/stats 2>/dev/null | python3 -c '
import json, sys
d = json.load(sys.stdin)
i = d.get("ingest", d)
print(int((i.get("rejected") or {}).get("security:impersonation", 0)))' 2>/dev/null || echo "?"
}

echo "# Shoal station with foreign secured vehicles: Fast DDS 2.9.1 and Cyclone DDS 0.10.2 (C), DDS Security 1.1 (netns $(ip netns identify $$ 2>/dev/null || echo '?'), domain $DOMAIN)"

# ------------------------------------------------------------------ a. keys
KEYS="$WORK/keys"
ok=1 detail=""
if "$SHOAL" keys --dir "$KEYS" init >"$WORK/keys.out" 2>&1 &&
   "$SHOAL" keys --dir "$KEYS" issue auv-7 auv-8 auv-9 auv-2 >>"$WORK/keys.out" 2>&1 &&
   "$SHOAL" keys --dir "$KEYS" export auv-7 "$WORK/b7" >>"$WORK/keys.out" 2>&1 &&
   "$SHOAL" keys --dir "$KEYS" export auv-8 "$WORK/b8" >>"$WORK/keys.out" 2>&1 &&
   "$SHOAL" keys --dir "$KEYS" export auv-9 "$WORK/b9" >>"$WORK/keys.out" 2>&1 &&
   "$SHOAL" keys --dir "$KEYS" export auv-2 "$WORK/b2" >>"$WORK/keys.out" 2>&1; then
    missing=""
    for b in b7 b8 b9 b2; do
        for f in identity_ca.cert.pem cert.pem key.pem permissions_ca.cert.pem governance.p7s permissions.p7s; do
            [[ -s "$WORK/$b/dds/$f" ]] || missing+=" $b/dds/$f"
        done
    done
    if [[ -z "$missing" ]]; then ok=0; detail="enclaves in b7/dds, b8/dds, b9/dds, b2/dds"
    else detail="missing:$missing"; fi
else
    detail="shoal keys failed: $(tail -n 3 "$WORK/keys.out" | tr '\n' ' ')"
fi
result "keys    shoal keys init, issue auv-7 auv-8 auv-9 auv-2, export" $ok "$detail"
[[ $ok == 0 ]] || { show_logs "$WORK/keys.out"; echo "$PASSED passed, $FAILED failed"; exit 1; }

# Who starts each handshake: the participant whose adjusted GUID is lower, i.e. whose
# SHA-256(DER subject) is lower (DDS Security 1.1 9.3.3; Cyclone and Fast DDS compare
# the same way). The station's subject is ground to start with 16 zero bits. auv-2's
# subject hash (2866..) sorts below what the station's would be without the nonce
# (CN=/shoal/station, O=Shoal: 7003..), so without the rule a Fast DDS auv-2 would have
# to initiate, and fail.
hashes=$(python3 - "$KEYS/dds/enclaves/shoal/station/cert.pem" "$WORK/b7/dds/cert.pem" "$WORK/b8/dds/cert.pem" "$WORK/b2/dds/cert.pem" <<'EOF'
import base64, hashlib, sys

def tlv(b, i):  # (tag, start of value, end of value) of the DER element at i
    tag, n = b[i], b[i + 1]
    i += 2
    if n & 0x80:
        k = n & 0x7F
        n = int.from_bytes(b[i:i + k], "big")
        i += k
    return tag, i, i + n

def subject_der(pem_path):
    pem = open(pem_path).read()
    der = base64.b64decode("".join(l for l in pem.splitlines() if l and not l.startswith("-----")))
    _, cs, _ = tlv(der, 0)          # Certificate
    _, ts, te = tlv(der, cs)        # tbsCertificate
    i, fields = ts, []
    while i < te:
        tag, vs, ve = tlv(der, i)
        fields.append((tag, i, ve))
        i = ve
    if fields[0][0] == 0xA0:        # [0] version
        fields = fields[1:]
    _, s, e = fields[4]             # serial, signature, issuer, validity, subject
    return der[s:e]

for p in sys.argv[1:]:
    print(hashlib.sha256(subject_der(p)).hexdigest()[:8])
EOF
)
read -r h_station h7 h8 h2 <<<"$(echo $hashes)"
if [[ "$h_station" == 0000* && "$h_station" < "$h7" && "$h_station" < "$h8" && "$h_station" < "$h2" ]]; then
    result "keys    station subject hash sorts lowest: the station initiates every handshake" 0 \
        "sha256(subject) station $h_station.., auv-7 $h7.., auv-8 $h8.., auv-2 $h2.."
else
    result "keys    station subject hash sorts lowest: the station initiates every handshake" 1 \
        "sha256(subject) station ${h_station:-?}.., auv-7 ${h7:-?}.., auv-8 ${h8:-?}.., auv-2 ${h2:-?}.."
fi

# ------------------------------------------------------------------ b. station
cat >"$WORK/shoal.toml" <<EOF
[dds]
domain_id = $DOMAIN

[security]
store = "$KEYS"

[station]
rules_path = "$WORK/rules.json"
summary_interval_s = 0.0

[history]
path = "$WORK/history.db"

[vehicle]
state_dir = "$WORK/vehicles"

[console]
listen = "127.0.0.1:$PORT"

[console.auth]
enabled = true
users_path = "$WORK/console-users.json"
initial_admin_token = "$TOKEN"
EOF
"$SHOAL" --config "$WORK/shoal.toml" station >"$WORK/station.log" 2>&1 &
STATION_PID=$!
ok=1 detail="the console did not answer within 60 s"
for _ in $(seq 300); do
    kill -0 "$STATION_PID" 2>/dev/null || { detail="shoal station exited"; break; }
    if api /api/fleet >/dev/null 2>&1; then ok=0; detail="console on 127.0.0.1:$PORT, security on"; break; fi
    sleep 0.2
done
if [[ $ok == 0 ]] && grep -q "SECURITY IS OFF" "$WORK/station.log"; then ok=1; detail="the station runs insecure"; fi
result "station shoal station (DDS Security on, domain $DOMAIN)" $ok "$detail"
[[ $ok == 0 ]] || { show_logs "$WORK/station.log"; echo "$PASSED passed, $FAILED failed"; exit 1; }

# ------------------------------------------------------------------ wire capture (c, d)
python3 "$HERE/rtps_plaintext.py" --text auv-7 --text auv-8 --f64 5.9 --f64 43.0 \
    --ready-file "$WORK/sniff.ready" >"$WORK/sniff.out" 2>"$WORK/sniff.err" &
SNIFF=$!
for _ in $(seq 50); do [[ -e "$WORK/sniff.ready" ]] && break; sleep 0.1; done

# ------------------------------------------------------------------ c. state
# Each vehicle keeps publishing (2 Hz) through the task step, so it stays in contact.
"$FASTDDS" --domain $DOMAIN publish-state --vehicle-id auv-7 --count 240 --rate 2 --linger 1 \
    --security "$WORK/b7/dds" --partition shoal.vehicle.auv-7 >"$WORK/pub7.out" 2>"$WORK/pub7.err" &
PUB7=$!
"$CYCLONE" --domain $DOMAIN publish-state --vehicle-id auv-8 --count 240 --rate 2 --linger 1 \
    --security "$WORK/b8/dds" --partition shoal.vehicle.auv-8 >"$WORK/pub8.out" 2>"$WORK/pub8.err" &
PUB8=$!
"$FASTDDS" --domain $DOMAIN publish-state --vehicle-id auv-2 --count 240 --rate 2 --linger 1 \
    --security "$WORK/b2/dds" --partition shoal.vehicle.auv-2 >"$WORK/pub2.out" 2>"$WORK/pub2.err" &
PUB2=$!
for v in 7 8 2; do
    vendor=$([[ $v == 8 ]] && echo "Cyclone C" || echo "Fast DDS")
    if c=$(wait_contact auv-$v alive 45); then
        result "state   $vendor(auv-$v) -> station: /api/fleet lists auv-$v alive" 0 \
            "contact $c, vendor $(fleet_field auv-$v '(v.get("announcement") or {}).get("vendor")'), lat $(fleet_field auv-$v '(v.get("latest") or {}).get("latitude_deg")')"
        verbose_logs "$WORK/pub$v.err"
    else
        result "state   $vendor(auv-$v) -> station: /api/fleet lists auv-$v alive" 1 "contact: $c"
        show_logs "$WORK/pub$v.err" "$WORK/station.log"
    fi
done

# ------------------------------------------------------------------ d. task
mission='{"mission_id": "secint", "name": "secure interop", "tasks": [
  {"task_id": "secint-goto-7", "vehicle_id": "auv-7",
   "task": {"kind": "goto_waypoint", "target": {"latitude_deg": 43.001, "longitude_deg": 5.901}, "depth_m": 10.0, "speed_mps": 1.0}},
  {"task_id": "secint-goto-8", "vehicle_id": "auv-8",
   "task": {"kind": "goto_waypoint", "target": {"latitude_deg": 43.002, "longitude_deg": 5.902}, "depth_m": 10.0, "speed_mps": 1.0}}]}'
if api '/api/missions?start=true' -X POST -H 'content-type: application/json' -d "$mission" \
        >"$WORK/mission.out" 2>&1; then
    verbose_logs "$WORK/mission.out"
else
    echo "    mission not started: $(head -c 400 "$WORK/mission.out")"
fi
# The assignments are TRANSIENT_LOCAL: a reader started now still gets them.
"$FASTDDS" --domain $DOMAIN subscribe-task --vehicle-id auv-7 --expect 1 --timeout 40 \
    --security "$WORK/b7/dds" >"$WORK/task7.out" 2>"$WORK/task7.err" &
T7=$!
"$CYCLONE" --domain $DOMAIN subscribe-task --vehicle-id auv-8 --expect 1 --timeout 40 \
    --security "$WORK/b8/dds" >"$WORK/task8.out" 2>"$WORK/task8.err" &
T8=$!
wait $T7; rc7=$?
wait $T8; rc8=$?
check_task() {  # check_task <file> <vehicle> <task-id> <lat> <lon>
    python3 - "$@" <<'EOF'
import json, sys
path, vid, tid, lat, lon = sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4]), float(sys.argv[5])
for line in open(path):
    if not line.startswith("{"):
        continue
    t = json.loads(line)
    if t.get("task_id") != tid:
        continue
    p = t["area"][0]
    assert t["vehicle_id"] == vid, f"vehicle_id {t['vehicle_id']!r}"
    assert t["kind"] == "GOTO_WAYPOINT", f"kind {t['kind']!r}"
    assert abs(p["latitude_deg"] - lat) < 1e-9 and abs(p["longitude_deg"] - lon) < 1e-9, f"area {t['area']!r}"
    assert t["mission_id"] == "secint", f"mission_id {t['mission_id']!r}"
    print(f"task {tid} GOTO_WAYPOINT ({lat}, {lon}) of mission secint, issue_seq {t['issue_seq']}")
    sys.exit(0)
print(f"no task {tid} among: " + ", ".join(json.loads(l).get("task_id", "?") for l in open(path) if l.startswith("{")))
sys.exit(1)
EOF
}
for v in 7 8; do
    vendor=$([[ $v == 7 ]] && echo "Fast DDS" || echo "Cyclone C")
    rc=$([[ $v == 7 ]] && echo $rc7 || echo $rc8)
    ok=1
    if [[ $rc != 0 ]]; then detail="subscriber exit $rc"
    elif detail=$(check_task "$WORK/task$v.out" auv-$v secint-goto-$v 43.00$((v - 6)) 5.90$((v - 6)) 2>&1); then ok=0
    fi
    result "task    station -> $vendor(auv-$v): the mission's goto arrives" $ok "$detail"
    if [[ $ok != 0 ]]; then show_logs "$WORK/mission.out" "$WORK/task$v.out" "$WORK/task$v.err"
    else verbose_logs "$WORK/task$v.err"; fi
done

# ------------------------------------------------------------------ g. wire (of c, d)
kill -TERM $SNIFF 2>/dev/null; wait $SNIFF
SEEN=$(cat "$WORK/sniff.out")
wire=$(python3 - "$SEEN" <<'EOF'
import json, sys
try:
    d = json.loads(sys.argv[1])
except ValueError:
    print("no capture"); sys.exit(1)
user = {k: v for k, v in d["user_hits"].items() if v}
pos_builtin = {k: v for k, v in d["builtin_hits"].items() if v and k in ("5.9", "43.0")}
ok = d["rtps"] > 0 and d["secured"] > 0 and d["user_data"] == 0 and not user and not pos_builtin
ids = {k: v for k, v in d["builtin_hits"].items() if k.startswith("auv") and v}
print(f"{d['rtps']} RTPS datagrams, {d['secured']} protected submessages (SEC_BODY), "
      f"{d['user_data']} user DATA in clear, markers in user DATA: {user or 'none'}, "
      f"position in builtin DATA: {pos_builtin or 'none'}; vehicle ids seen only in builtin "
      f"DATA (SPDP identity token / handshake certificate and permissions, clear by design): {ids or 'none'}")
sys.exit(0 if ok else 1)
EOF
)
result "wire    state and tasks: no user DATA in clear, no vehicle id / position in any user payload" $? "$wire"

# The foreign vehicles stop publishing: what follows must not be mistaken for them.
kill -TERM $PUB7 $PUB8 $PUB2 2>/dev/null; wait $PUB7 $PUB8 $PUB2 2>/dev/null
verbose_logs "$WORK/pub7.err" "$WORK/pub8.err" "$WORK/pub2.err"

# ------------------------------------------------------------------ e. outsiders
python3 "$HERE/rtps_plaintext.py" --text auv-9 --f64 5.9 --ready-file "$WORK/sniff9.ready" \
    >"$WORK/sniff9.out" 2>"$WORK/sniff9.err" &
SNIFF=$!
for _ in $(seq 50); do [[ -e "$WORK/sniff9.ready" ]] && break; sleep 0.1; done
# The station's readers never match an unauthenticated writer; a plain Cyclone reader
# does (so auv-9 really publishes, and the capture has something in clear to see).
timeout -s TERM 40 "$CYCLONE" --domain $DOMAIN subscribe-state --vehicle-id auv-9 --expect 10 \
    --expect-announcements 1 --timeout 25 --read-partition 'shoal.vehicle.*' \
    >"$WORK/plainstate.out" 2>"$WORK/plainstate.err" &
PS=$!
timeout -s TERM 40 "$CYCLONE" --domain $DOMAIN subscribe-task --vehicle-id auv-7 --expect 1 --timeout 20 \
    >"$WORK/plaintask.out" 2>"$WORK/plaintask.err" &
PT=$!
sleep 1
timeout -s TERM 40 "$FASTDDS" --domain $DOMAIN publish-state --vehicle-id auv-9 --count 20 --rate 4 \
    --linger 2 --partition shoal.vehicle.auv-9 >"$WORK/pub9.out" 2>"$WORK/pub9.err" &
P9=$!
seen9=""
for _ in $(seq 40); do
    c=$(contact auv-9); [[ "$c" != absent ]] && seen9="$c"
    kill -0 $P9 2>/dev/null || break
    sleep 0.5
done
wait $P9; rc9=$?
wait $PS; rcs=$?
wait $PT; rct=$?
kill -TERM $SNIFF 2>/dev/null; wait $SNIFF
c=$(contact auv-9)
plain=$(grep -c '^{' "$WORK/plainstate.out")
if [[ -z "$seen9" && "$c" == absent && $rc9 == 0 && $plain -gt 0 ]]; then
    result "outsider Fast DDS without security as auv-9: never in /api/fleet" 0 \
        "$(grep -o 'published [0-9]*' "$WORK/pub9.out"), a plain reader got $plain (exit $rcs); /api/fleet: auv-9 absent throughout"
else
    result "outsider Fast DDS without security as auv-9: never in /api/fleet" 1 \
        "auv-9 contact ${seen9:-$c}; publisher exit $rc9; plain reader got $plain"
    show_logs "$WORK/pub9.err" "$WORK/plainstate.err"
fi
got=$(grep -c '^{' "$WORK/plaintask.out")
if [[ $rct == 1 && $got == 0 ]]; then
    result "outsider Cyclone C without security subscribing to auv-7's tasks: receives nothing" 0 \
        "exit 1 after 20 s, 0 tasks"
else
    result "outsider Cyclone C without security subscribing to auv-7's tasks: receives nothing" 1 \
        "exit $rct, $got tasks"
    show_logs "$WORK/plaintask.out" "$WORK/plaintask.err"
fi
# Control for the wire check: the same capture sees an unprotected peer's samples.
ctl=$(python3 -c '
import json, sys
d = json.loads(sys.argv[1])
print(d["user_data"], d["user_hits"].get("auv-9", 0), d["user_hits"].get("5.9", 0))' "$(cat "$WORK/sniff9.out")" 2>/dev/null)
read -r ud h9 hp <<<"${ctl:-0 0 0}"
if (( ud > 0 && h9 > 0 && hp > 0 )); then
    result "wire    control: the same capture sees the outsider's id and position in clear" 0 \
        "$ud user DATA in clear, auv-9 in $h9, 5.9 in $hp"
else
    result "wire    control: the same capture sees the outsider's id and position in clear" 1 "$(cat "$WORK/sniff9.out")"
fi

# ------------------------------------------------------------------ f. attacks
before_vendor=$(fleet_field auv-7 '(v.get("announcement") or {}).get("vendor")')
before_name=$(fleet_field auv-7 '(v.get("announcement") or {}).get("name")')
before_ts=$(fleet_field auv-7 '(v.get("latest") or {}).get("timestamp_ms")')
before_acc=$(fleet_field auv-7 'v.get("states_accepted")')
imp0=$(impersonations)
"$CYCLONE" --domain $DOMAIN publish-state --attack --vehicle-id auv-7 --count 5 --rate 5 --linger 3 \
    --match-timeout 20 --partition shoal.vehicle.auv-8 --security "$WORK/b8/dds" \
    >"$WORK/attack-state.out" 2>"$WORK/attack-state.err"
imp1=$imp0
for _ in $(seq 20); do
    imp1=$(impersonations)
    [[ "$imp1" =~ ^[0-9]+$ && "$imp0" =~ ^[0-9]+$ ]] && (( imp1 > imp0 )) && break
    sleep 0.5
done
after_vendor=$(fleet_field auv-7 '(v.get("announcement") or {}).get("vendor")')
after_name=$(fleet_field auv-7 '(v.get("announcement") or {}).get("name")')
after_ts=$(fleet_field auv-7 '(v.get("latest") or {}).get("timestamp_ms")')
after_acc=$(fleet_field auv-7 'v.get("states_accepted")')
what=$(grep '^attack writer\|^attack write \|^published' "$WORK/attack-state.out" | tr '\n' ';' | sed 's/;$//')
if [[ "$imp1" =~ ^[0-9]+$ ]] && (( imp1 > 0 )) && [[ "$imp0" =~ ^[0-9]+$ ]] && (( imp1 > imp0 )) &&
   [[ "$before_name" != absent && "$after_vendor" == "$before_vendor" && "$after_name" == "$before_name" &&
      "$after_ts" == "$before_ts" && "$after_acc" == "$before_acc" ]]; then
    result "attack  Cyclone C with auv-8's credentials claims auv-7 in shoal.vehicle.auv-8: refused and counted" 0 \
        "security:impersonation $imp0 -> $imp1; auv-7 still '$after_name', $after_acc states accepted, latest timestamp_ms $after_ts unchanged; peer: $what"
else
    result "attack  Cyclone C with auv-8's credentials claims auv-7 in shoal.vehicle.auv-8: refused and counted" 1 \
        "security:impersonation $imp0 -> $imp1; auv-7 '$before_name'/$before_acc/$before_ts -> '$after_name'/$after_acc/$after_ts; peer: $what"
    show_logs "$WORK/attack-state.out" "$WORK/attack-state.err" "$WORK/station.log"
fi
verbose_logs "$WORK/attack-state.out"

# A TaskAssignment from vehicle credentials (Cyclone with auv-8's, Fast DDS with auv-7's):
# auv-7's secured task reader must get no task "evil" (it still gets the station's).
"$FASTDDS" --domain $DOMAIN subscribe-task --vehicle-id auv-7 --expect 3 --timeout 15 \
    --security "$WORK/b7/dds" >"$WORK/evil-sub.out" 2>"$WORK/evil-sub.err" &
ES=$!
sleep 1
"$CYCLONE" --domain $DOMAIN publish-task --attack --vehicle-id auv-7 --task-id evil --linger 6 \
    --wait-match 5 --security "$WORK/b8/dds" >"$WORK/evil-cyc.out" 2>"$WORK/evil-cyc.err" &
EC=$!
"$FASTDDS" --domain $DOMAIN publish-task --attack --vehicle-id auv-7 --task-id evil --linger 6 \
    --wait-match 5 --security "$WORK/b7/dds" >"$WORK/evil-fd.out" 2>"$WORK/evil-fd.err" &
EF=$!
wait $EC $EF
wait $ES
evil=$(grep -c '"task_id":"evil"' "$WORK/evil-sub.out")
real=$(grep -c '"task_id":"secint-goto-7"' "$WORK/evil-sub.out")
wc=$(grep '^attack writer' "$WORK/evil-cyc.out" | head -n 1)
wf=$(grep '^attack writer' "$WORK/evil-fd.out" | head -n 1)
if [[ $evil == 0 && $real -ge 1 ]]; then
    result "attack  TaskAssignment from vehicle credentials: auv-7 receives none" 0 \
        "Cyclone C(auv-8): ${wc:-?}; Fast DDS(auv-7): ${wf:-?}; auv-7's reader got the station's task and $evil forged"
else
    result "attack  TaskAssignment from vehicle credentials: auv-7 receives none" 1 \
        "forged tasks received: $evil, station's: $real; Cyclone C: ${wc:-?}; Fast DDS: ${wf:-?}"
    show_logs "$WORK/evil-sub.out" "$WORK/evil-sub.err" "$WORK/evil-cyc.out" "$WORK/evil-fd.out"
fi
verbose_logs "$WORK/evil-cyc.out" "$WORK/evil-fd.out"

# ------------------------------------------------------------------ the station's view
if kill -0 "$STATION_PID" 2>/dev/null; then
    result "station still running, no handshake failure logged" \
        "$(grep -qi 'handshake.*fail' "$WORK/station.log" && echo 1 || echo 0)" \
        "$(grep -ci 'sample about another vehicle refused' "$WORK/station.log") impersonation warnings in its log"
else
    result "station still running" 1 "exited"; show_logs "$WORK/station.log"
fi
verbose_logs "$WORK/station.log"

echo
(( FAILED > 0 )) && printf 'failed: %s\n' "${FAILURES[@]}"
echo "$PASSED passed, $FAILED failed"
(( FAILED == 0 ))
