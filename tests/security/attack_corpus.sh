#!/usr/bin/env bash
# The attack corpus on the standard path (issue 20, item 7): a secured `shoal station`
# (OMG DDS Security 1.1, credentials from `shoal keys`) and a legitimate secured vehicle
# (the Cyclone DDS C peer as auv-21) whose every state vector is counted, under more than
# 10,000 attacks; every one must be refused and no legitimate sample lost. Runs in its own
# loopback-only network namespace (domain 197, console 127.0.0.1:19797), ~3 min.
#
#   packets      attack_corpus.py captures auv-21's secured RTPS traffic on lo and injects
#                mutated copies into the station's locators: exact replays (live session
#                and a previous session), one bit flipped in every part (RTPS header,
#                submessage headers, SEC_PREFIX, SEC_BODY, SEC_POSTFIX, clear
#                submessages), truncated, extended, re-addressed (another GUID prefix),
#                and packets forged from scratch as auv-21 (clear DATA/HEARTBEAT/GAP, random
#                ciphertext, SPDP dispose)
#   credentials  participants that try to join and publish: self-signed identity with
#                auv-21's subject (forged-identity), an identity from another CA (wrong-ca), an
#                expired certificate and expired permissions (both signed by the real CAs;
#                the attacker's clock set back with faketime so its own stack loads them),
#                no security at all (unauthenticated), permissions signed by another
#                permissions CA, permissions of another subject, a revoked vehicle
#                (`shoal keys revoke`, applied live), a valid vehicle claiming auv-21 in its
#                own partition (impersonation), a valid vehicle assigning tasks
#
# A case is refused when nothing of it reached the station: no state for auv-21 beyond
# what auv-21 published (checked sample by sample in the history), no new vehicle, no
# rejected/malformed counter moved by a packet window, the attacker's writer matched no
# reader (or the refusal is counted as security:impersonation / security:revoked), no
# forged task received by auv-21. Prints cases and refusals by kind, legitimate samples
# sent and received, the station's health, then "N passed, M failed"; exits non-zero on
# any failure.
#
# Usage: tests/security/attack_corpus.sh [-v]
#   SHOAL_BIN              the shoal binary (default target/release/shoal)
#   SHOAL_ATTACK_SCALE     multiplies the packet cases (default 1: 12,600 cases)
# Needs root, scripts/install-test-deps.sh (the Cyclone C peer, faketime, openssl, curl).
set -uo pipefail

HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
REPO="$(cd "$HERE/../.." && pwd)"

# shellcheck source=../lib/own-netns.sh
source "$REPO/tests/lib/own-netns.sh"
[[ -n "${SHOAL_OWN_NETNS:-}" ]] || need_shoal_release
own_netns attack "$@"

VERBOSE=0
[[ "${1:-}" == "-v" ]] && VERBOSE=1
SHOAL="${SHOAL_BIN:-$REPO/target/release/shoal}"
CYCLONE="$REPO/tests/interop/build/cyclone_c_peer"
for b in "$SHOAL" "$CYCLONE"; do
    [[ -x "$b" ]] || { echo "missing $b: run scripts/install-test-deps.sh (and build shoal)" >&2; exit 2; }
done
for c in curl python3 openssl faketime; do
    command -v $c >/dev/null || { echo "missing $c: run scripts/install-test-deps.sh" >&2; exit 2; }
done

# Domain 197 and port 19797: no other test uses them (and the namespace is ours alone).
DOMAIN=197
PORT=19797
SCALE="${SHOAL_ATTACK_SCALE:-1}"
WORK="$(mktemp -d /tmp/shoal-attack.XXXXXX)"
STATION_PID=""
# shellcheck source=../lib/report.sh
source "$REPO/tests/lib/report.sh"
trap stop_everything EXIT
unset SHOAL_CONSOLE__AUTH__ENABLED SHOAL_CONSOLE__AUTH__INITIAL_ADMIN_PASSWORD \
    SHOAL_CONSOLE__AUTH__INITIAL_ADMIN_TOKEN SHOAL_CONSOLE__ALLOWED_HOSTS SHOAL_SECURITY__ENABLED

abort() { show_logs "$@"; echo "$PASSED passed, $((FAILED + 1)) failed"; exit 1; }

TOKEN="shoal_test_$(od -An -tx1 -N24 /dev/urandom | tr -d ' \n')"
API="http://127.0.0.1:$PORT"
api() {  # api <path> [curl args...]
    local path="$1"; shift
    curl -sS --fail-with-body -m 10 -H "Authorization: Bearer $TOKEN" "$@" "$API$path"
}
vehicle_field() {  # vehicle_field <id> <key>: from /api/fleet, "absent" if no such vehicle
    api /api/fleet 2>/dev/null | python3 -c '
import json, sys
vid, key = sys.argv[1], sys.argv[2]
d = json.load(sys.stdin)
for v in (d.get("vehicles", d) if isinstance(d, dict) else d):
    if vid in (v.get("vehicle_id"), v.get("id"), (v.get("announcement") or {}).get("vehicle_id")):
        print(v.get(key)); break
else:
    print("absent")' "$1" "$2" 2>/dev/null || echo "?"
}
rejected() {  # rejected <reason>: ingest.rejected[reason] from /api/stats
    api /api/stats 2>/dev/null | python3 -c '
import json, sys
d = json.load(sys.stdin); i = d.get("ingest", d)
print(int((i.get("rejected") or {}).get(sys.argv[1], 0)))' "$1" 2>/dev/null || echo "?"
}

echo "# attack corpus against a secured shoal station (netns $(ip netns identify $$ 2>/dev/null || echo '?'), domain $DOMAIN)"
T_START=$(date +%s)

# ------------------------------------------------------------------ keys
KEYS="$WORK/keys"
if ! ( set -e; "$SHOAL" keys --dir "$KEYS" init; "$SHOAL" keys --dir "$KEYS" issue auv-21 auv-22 auv-23
         for v in 21 22 23; do "$SHOAL" keys --dir "$KEYS" export auv-$v "$WORK/b$v"; done ) \
       >"$WORK/keys.out" 2>&1; then
    result "keys    shoal keys init, issue, export" 1 "$(tail -n 3 "$WORK/keys.out" | tr '\n' ' ')"
    abort "$WORK/keys.out"
fi
DDSK="$KEYS/dds"
IDCA="$DDSK/public/identity_ca.cert.pem" IDCA_KEY="$DDSK/private/identity_ca.key.pem"
PCA="$DDSK/public/permissions_ca.cert.pem" PCA_KEY="$DDSK/private/permissions_ca.key.pem"
E21="$WORK/b21/dds" E22="$WORK/b22/dds" E23="$WORK/b23/dds"

# ------------------------------------------------------------------ attacker enclaves
# Each directory is what a participant loads (the SROS2 names); openssl CLI only.
ATT="$WORK/att"
mkdir -p "$ATT"
utc() { date -u -d "@$1" +%Y%m%d%H%M%SZ; }
xml_time() { date -u -d "@$1" +%Y-%m-%dT%H:%M:%S; }
enclave_from() {  # enclave_from <src enclave> <dest>: a copy to modify
    mkdir -p "$2" && cp "$1"/{cert.pem,key.pem,identity_ca.cert.pem,permissions_ca.cert.pem,governance.p7s,permissions.p7s,permissions.xml} "$2"/
}
sign_doc() {  # sign_doc <xml> <ca cert> <ca key> <out p7s>
    openssl smime -sign -text -in "$1" -signer "$2" -inkey "$3" -out "$4" -outform SMIME -nodetach
}
now=$(date +%s)
mk_enclaves() {
    set -e
    openssl ecparam -name prime256v1 -genkey -noout -out "$ATT/k.pem"
    openssl pkcs8 -topk8 -nocrypt -in "$ATT/k.pem" -out "$ATT/key.pem"
    # A request with auv-21's exact subject (DER order kept), under the attacker's key.
    openssl x509 -x509toreq -in "$E21/cert.pem" -signkey "$ATT/key.pem" -out "$ATT/req21.pem"
    # forged: self-signed, auv-21's subject; its own certificate is its identity CA.
    enclave_from "$E21" "$ATT/forged"
    openssl x509 -req -in "$ATT/req21.pem" -signkey "$ATT/key.pem" -days 30 -out "$ATT/forged/cert.pem"
    cp "$ATT/key.pem" "$ATT/forged/key.pem"
    cp "$ATT/forged/cert.pem" "$ATT/forged/identity_ca.cert.pem"
    # wrong-ca: auv-21's subject, issued by another identity CA.
    openssl ecparam -name prime256v1 -genkey -noout -out "$ATT/evilca.key.pem"
    openssl req -x509 -new -key "$ATT/evilca.key.pem" -subj "/CN=Shoal identity CA/O=Shoal" -days 30 \
        -out "$ATT/evilca.pem"
    enclave_from "$E21" "$ATT/wrong-ca"
    openssl x509 -req -in "$ATT/req21.pem" -CA "$ATT/evilca.pem" -CAkey "$ATT/evilca.key.pem" \
        -CAcreateserial -days 30 -out "$ATT/wrong-ca/cert.pem"
    cp "$ATT/key.pem" "$ATT/wrong-ca/key.pem"
    cp "$ATT/evilca.pem" "$ATT/wrong-ca/identity_ca.cert.pem"
    # expired-cert: auv-21's subject, signed by the real identity CA, valid from 590 s to
    # 60 s ago (keystore certificates are backdated 600 s, so the attacker, its clock set
    # back 300 s, finds its CA, permissions and certificate all valid).
    mkdir -p "$ATT/ca"
    : >"$ATT/ca/index.txt"
    echo 1000 >"$ATT/ca/serial"
    cat >"$ATT/ca.cnf" <<EOF
[ca]
default_ca = d
[d]
database = $ATT/ca/index.txt
new_certs_dir = $ATT/ca
serial = $ATT/ca/serial
default_md = sha256
policy = p
unique_subject = no
copy_extensions = none
[p]
commonName = supplied
organizationName = optional
EOF
    enclave_from "$E21" "$ATT/expired-cert"
    openssl ca -batch -config "$ATT/ca.cnf" -cert "$IDCA" -keyfile "$IDCA_KEY" -in "$ATT/req21.pem" \
        -out "$ATT/expired-cert/cert.pem" -notext -preserveDN \
        -startdate "$(utc $((now - 590)))" -enddate "$(utc $((now - 60)))"
    cp "$ATT/key.pem" "$ATT/expired-cert/key.pem"
    # expired-permissions: auv-21's real identity, its permissions re-dated to end 60 s
    # ago and signed by the real permissions CA.
    enclave_from "$E21" "$ATT/expired-perms"
    sed -e "s|<not_before>[^<]*</not_before>|<not_before>$(xml_time $((now - 590)))</not_before>|" \
        -e "s|<not_after>[^<]*</not_after>|<not_after>$(xml_time $((now - 60)))</not_after>|" \
        "$E21/permissions.xml" >"$ATT/expired-perms/permissions.xml"
    sign_doc "$ATT/expired-perms/permissions.xml" "$PCA" "$PCA_KEY" "$ATT/expired-perms/permissions.p7s"
    # wrong-perm-ca: auv-22's real identity; governance and permissions granting it
    # everything (the station's grant) signed by another permissions CA.
    openssl ecparam -name prime256v1 -genkey -noout -out "$ATT/evilpca.key.pem"
    openssl req -x509 -new -key "$ATT/evilpca.key.pem" -subj "/CN=Shoal permissions CA/O=Shoal" -days 30 \
        -out "$ATT/evilpca.pem"
    enclave_from "$E22" "$ATT/wrong-perm-ca"
    cp "$ATT/evilpca.pem" "$ATT/wrong-perm-ca/permissions_ca.cert.pem"
    sub22=$(grep -o '<subject_name>[^<]*</subject_name>' "$E22/permissions.xml")
    sed -e "s|<subject_name>[^<]*</subject_name>|$sub22|" -e "s|/shoal/station|/shoal/vehicle/auv-22|" \
        "$DDSK/enclaves/shoal/station/permissions.xml" >"$ATT/wrong-perm-ca/permissions.xml"
    sign_doc "$ATT/wrong-perm-ca/permissions.xml" "$ATT/evilpca.pem" "$ATT/evilpca.key.pem" \
        "$ATT/wrong-perm-ca/permissions.p7s"
    sign_doc "$DDSK/enclaves/governance.xml" "$ATT/evilpca.pem" "$ATT/evilpca.key.pem" \
        "$ATT/wrong-perm-ca/governance.p7s"
    # other-subject: auv-22's real identity with auv-21's real (signed) permissions.
    enclave_from "$E22" "$ATT/other-subject"
    cp "$E21/permissions.p7s" "$E21/permissions.xml" "$ATT/other-subject/"
}
if ! (mk_enclaves) >"$WORK/enclaves.out" 2>&1; then
    result "keys    attacker enclaves (openssl)" 1 "$(tail -n 3 "$WORK/enclaves.out" | tr '\n' ' ')"
    abort "$WORK/enclaves.out"
fi
verbose_logs "$WORK/enclaves.out"

# ------------------------------------------------------------------ station
cat >"$WORK/shoal.toml" <<EOF
[dds]
domain_id = $DOMAIN

[security]
store = "$KEYS"
crl_check_s = 1

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
    if api /api/fleet >/dev/null 2>&1; then ok=0; detail="console on 127.0.0.1:$PORT"; break; fi
    sleep 0.2
done
if [[ $ok == 0 ]] && grep -q "SECURITY IS OFF" "$WORK/station.log"; then ok=1; detail="the station runs insecure"; fi
result "station shoal station, DDS Security on, domain $DOMAIN" $ok "$detail"
[[ $ok == 0 ]] || abort "$WORK/station.log"

# A StateVector for auv-21 as XCDR1 bytes (for the forged clear DATA), if the venv is there.
STATE_CDR=""
if [[ -x "$REPO/.venv/bin/python" ]]; then
    STATE_CDR=$("$REPO/.venv/bin/python" "$REPO/tests/interop/peers/cyclone_peer.py" encode-sample StateVector \
        '{"vehicle_id": "auv-21", "timestamp_ms": '"$(($(date +%s) * 1000))"', "latitude_deg": 12.345, "longitude_deg": 5.9, "depth_m": 1.0, "altitude_m": -1.0, "speed_mps": 0.5, "yaw_deg": 0.0, "pitch_deg": 0.0, "roll_deg": 0.0, "battery_pct": 50.0}' \
        --header 2>/dev/null | tail -n 1 || true)
fi

# ------------------------------------------------------------------ capture + first session
python3 "$HERE/attack_corpus.py" packets --vehicle-cert "$E21/cert.pem" --station-cert "$DDSK/enclaves/shoal/station/cert.pem" \
    --api "$API" --token "$TOKEN" --work "$WORK" --scale "$SCALE" --state-cdr "$STATE_CDR" \
    >"$WORK/packets.out" 2>"$WORK/packets.err" &
PKT=$!
for _ in $(seq 100); do [[ -e "$WORK/sniff.ready" ]] && break; sleep 0.1; done
[[ -e "$WORK/sniff.ready" ]] || { result "packets capture on lo" 1 "no sniffer"; abort "$WORK/packets.err"; }

# auv-23: a valid vehicle, heard before it is revoked.
"$CYCLONE" --domain $DOMAIN publish-state --vehicle-id auv-23 --count 10 --rate 5 --linger 1 \
    --security "$E23" --partition shoal.vehicle.auv-23 >"$WORK/pub23.out" 2>"$WORK/pub23.err" &
P23=$!
# auv-21's first session: replayed later as "old" traffic.
"$CYCLONE" --domain $DOMAIN publish-state --vehicle-id auv-21 --count 20 --rate 10 --linger 1 \
    --security "$E21" --partition shoal.vehicle.auv-21 >"$WORK/run1.out" 2>"$WORK/run1.err"
rc1=$?
n1=$(grep -o '^published [0-9]*' "$WORK/run1.out" | awk '{print $2}')
touch "$WORK/run1.done"
if [[ $rc1 != 0 || -z "$n1" ]]; then
    result "legit   auv-21 first session" 1 "exit $rc1"; abort "$WORK/run1.err" "$WORK/station.log"
fi
# auv-21's second session publishes through every attack: 4 Hz.
N2=${SHOAL_ATTACK_LEGIT_COUNT:-560}
"$CYCLONE" --domain $DOMAIN publish-state --vehicle-id auv-21 --count "$N2" --rate 4 --linger 3 \
    --security "$E21" --partition shoal.vehicle.auv-21 >"$WORK/run2.out" 2>"$WORK/run2.err" &
RUN2=$!
wait $P23; rc23=$?
acc23=$(vehicle_field auv-23 states_accepted)
result "legit   auv-23 (to be revoked) heard while valid" "$([[ $rc23 == 0 && "$acc23" == 10 ]] && echo 0 || echo 1)" \
    "exit $rc23, station accepted $acc23 of 10"

# ------------------------------------------------------------------ credential attacks
# attack <kind> <n> <enclave dir|-> [faketime offset|-] [command args...]: one attacking
# participant; its report goes to $WORK/cred/<kind>.<n>.out
mkdir -p "$WORK/cred"
attack() {
    local kind=$1 n=$2 enc=$3 ft=$4
    shift 4
    local sec=() pre=()
    [[ "$enc" != - ]] && sec=(--security "$enc")
    [[ "$ft" != - ]] && pre=(env FAKETIME_DONT_FAKE_MONOTONIC=1 faketime -f "$ft")
    timeout -s TERM 60 "${pre[@]}" "$CYCLONE" --domain $DOMAIN "$@" "${sec[@]}" \
        >"$WORK/cred/$kind.$n.out" 2>"$WORK/cred/$kind.$n.err"
    echo "exit $?" >>"$WORK/cred/$kind.$n.out"
}
state_attack() {  # state_attack <kind> <n> <enclave> <faketime> <claimed id> <partition>
    attack "$1" "$2" "$3" "$4" publish-state --attack --vehicle-id "$5" --partition "$6" \
        --count 5 --rate 10 --linger 1 --settle 0.3 --match-timeout 6
}
JOIN_KINDS=(forged-identity wrong-ca expired-cert expired-perms unauthenticated wrong-perm-ca other-subject)
join_round() {  # one participant of each kind that must not authenticate or match
    local n=$1
    state_attack forged-identity "$n" "$ATT/forged" - auv-21 shoal.vehicle.auv-21 &
    state_attack wrong-ca "$n" "$ATT/wrong-ca" - auv-21 shoal.vehicle.auv-21 &
    state_attack expired-cert "$n" "$ATT/expired-cert" -300 auv-21 shoal.vehicle.auv-21 &
    state_attack expired-perms "$n" "$ATT/expired-perms" -300 auv-21 shoal.vehicle.auv-21 &
    state_attack unauthenticated "$n" - - auv-21 shoal.vehicle.auv-21 &
    state_attack wrong-perm-ca "$n" "$ATT/wrong-perm-ca" - auv-21 shoal.vehicle.auv-21 &
    state_attack other-subject "$n" "$ATT/other-subject" - auv-21 shoal.vehicle.auv-21 &
    wait
}

# The packet corpus starts once auv-21's second session is authenticated and flowing;
# the join attempts run at the same time (three rounds).
for _ in $(seq 900); do [[ -e "$WORK/attacking" ]] && break; kill -0 $PKT 2>/dev/null || break; sleep 0.1; done
[[ -e "$WORK/attacking" ]] || { result "packets capture of auv-21's sessions" 1 "injector gave up"; abort "$WORK/packets.err"; }
T_ATTACK=$(date +%s)
( for r in 1 2 3; do join_round $r; done ) &
JOINS=$!
wait $PKT; rcp=$?
wait $JOINS
T_JOINS=$(date +%s)

# ------------------------------------------------------------------ revoked, impersonation, task
shoal_revoke_out=$("$SHOAL" keys --dir "$KEYS" revoke auv-23 --reason key-compromise 2>&1)
rev_ok=$?
for _ in $(seq 50); do grep -q "revocation list reloaded" "$WORK/station.log" && break; sleep 0.2; done
imp0=$(rejected security:impersonation)
rev0=$(rejected security:revoked)
acc23_before=$(vehicle_field auv-23 states_accepted)
"$CYCLONE" --domain $DOMAIN subscribe-task --vehicle-id auv-21 --expect 100 --timeout 25 \
    --security "$E21" >"$WORK/tasks21.out" 2>"$WORK/tasks21.err" &
TSUB=$!
sleep 2
for n in 1 2 3; do
    state_attack revoked "$n" "$E23" - auv-23 shoal.vehicle.auv-23 &
    state_attack impersonation "$n" "$E22" - auv-21 shoal.vehicle.auv-22 &
done
attack task 1 "$E22" - publish-task --attack --vehicle-id auv-21 --task-id evil-1 --linger 4 --wait-match 5 &
attack task 2 "$E22" - publish-task --attack --vehicle-id auv-21 --task-id evil-2 --linger 4 --wait-match 5 &
attack task 3 "$ATT/wrong-perm-ca" - publish-task --attack --vehicle-id auv-21 --task-id evil-3 --linger 4 --wait-match 5 &
for j in $(jobs -p); do [[ $j == "$RUN2" || $j == "$TSUB" || $j == "$STATION_PID" ]] || wait "$j"; done
sleep 2
imp1=$(rejected security:impersonation)
rev1=$(rejected security:revoked)
# The expired-certificate attackers ran earlier; the station counts their refused handshakes.
hs_expired=$(rejected security:handshake_refused:expired)
acc23_after=$(vehicle_field auv-23 states_accepted)
wait $TSUB

# ------------------------------------------------------------------ the legitimate vehicle
wait $RUN2; rc2=$?
n2=$(grep -o '^published [0-9]*' "$WORK/run2.out" | awk '{print $2}')
sleep 2
T_END=$(date +%s)

# ------------------------------------------------------------------ verdicts
api /api/fleet >"$WORK/fleet.json" 2>/dev/null
api /api/stats >"$WORK/stats.json" 2>/dev/null
api "/api/vehicles/auv-21/track?limit=10000" >"$WORK/track21.json" 2>/dev/null
health=$(curl -s -o /dev/null -w '%{http_code}' -m 10 -H "Authorization: Bearer $TOKEN" "$API/api/health")
echo "$shoal_revoke_out" >"$WORK/revoke.out"

python3 - "$WORK" "${n1:-0}" "${n2:-0}" "$rc2" "$health" "$rev_ok" "$imp0" "$imp1" "$rev0" "$rev1" \
    "$acc23_before" "$acc23_after" "$rcp" "${hs_expired:-0}" <<'EOF'
import glob, json, os, re, sys
(work, n1, n2, rc2, health, rev_ok, imp0, imp1, rev0, rev1, a23b, a23a, rcp, hs_expired) = sys.argv[1:]
n1, n2 = int(n1), int(n2)
fails = []
def out(line): print(line, flush=True)

def load(p, default=None):
    try:
        return json.load(open(os.path.join(work, p)))
    except Exception:
        return default

pk = load("packets.json", {}) or {}
fleet = load("fleet.json", {}) or {}
track = load("track21.json", []) or []
vehicles = fleet.get("vehicles", fleet) if isinstance(fleet, dict) else fleet
vid = lambda v: v.get("vehicle_id") or v.get("id") or (v.get("announcement") or {}).get("vehicle_id")
by_id = {vid(v): v for v in vehicles}
points = track.get("points", track.get("track", track.get("states", []))) if isinstance(track, dict) else track

# -- legitimate samples: auv-21's two sessions, sample by sample
sent = n1 + n2
acc21 = (by_id.get("auv-21") or {}).get("states_accepted")
rej21 = (by_id.get("auv-21") or {}).get("states_rejected")
lats = sorted(round(((p.get("latitude_deg") if isinstance(p, dict) else None) or 0) - 43.0, 7) for p in points)
stamps = [p.get("timestamp_ms") for p in points if isinstance(p, dict)]
want = sorted([round(i * 1e-5, 7) for i in range(n1)] + [round(i * 1e-5, 7) for i in range(n2)])
legit_ok = (rc2 == "0" and n2 > 0 and acc21 == sent and rej21 == 0 and len(points) == sent
            and lats == want and len(set(stamps)) == len(stamps))
extra = len(points) - sent
foreign = [p for p in points if round((p.get("latitude_deg") or 0) - 43.0, 7) not in set(want)]

# -- packet kinds
cases, refused = {}, {}
for kind, n in (pk.get("cases") or {}).items():
    d = (pk.get("windows") or {}).get(kind, {}).get("delta", {"error": "no window"})
    cases[kind] = n
    refused[kind] = n if (not d and legit_ok) else 0
    if d:
        fails.append(f"packets {kind}: the station changed during its window: {d}")
if pk.get("error") or rcp != "0":
    fails.append(f"packet injector: {pk.get('error') or 'exit ' + rcp}")

# -- credential kinds
station_ids = set(by_id)
for f in sorted(glob.glob(os.path.join(work, "cred", "*.out"))):
    kind, n = os.path.basename(f)[:-4].rsplit(".", 1)
    # A refused attacker's output may echo the garbage it was fed: never fail on it.
    text = open(f, errors="replace").read()
    err = open(f[:-4] + ".err", errors="replace").read() if os.path.exists(f[:-4] + ".err") else ""
    cases[kind] = cases.get(kind, 0) + 1
    m = re.search(r"attack matched (\d+) readers on shoal/state_vector", text)
    local = "refused locally" in text or ("error:" in err and "attack writer" not in text)
    if kind in ("revoked", "impersonation"):
        ok = m is not None  # it did join and publish: the station's own check must refuse
        why = "reached the station" if ok else f"did not run: {text.strip()[-200:]} {err.strip()[-200:]}"
    elif kind == "task":
        ok = True
        why = ""
    else:
        ok = local or (m is not None and m.group(1) == "0")
        why = "" if ok else f"matched readers: {m.group(1) if m else '?'} / {text.strip()[-300:]}"
    if ok:
        refused[kind] = refused.get(kind, 0) + 1
        if local:
            refused.setdefault(kind + " (by its own stack)", 0)
            refused[kind + " (by its own stack)"] += 1
    else:
        fails.append(f"{kind} #{n}: {why}")

# revoked: counted, and auv-23 got nothing more
if not (hs_expired.isdigit() and int(hs_expired) > 0):
    fails.append(f"expired-cert: no security:handshake_refused:expired counted ({hs_expired})")
if not (imp0.isdigit() and imp1.isdigit() and int(imp1) > int(imp0)):
    fails.append(f"impersonation: security:impersonation {imp0} -> {imp1}")
    refused["impersonation"] = 0
if not (rev0.isdigit() and rev1.isdigit() and int(rev1) > int(rev0) and a23b == a23a and rev_ok == "0"):
    fails.append(f"revoked: security:revoked {rev0} -> {rev1}, auv-23 states {a23b} -> {a23a}, revoke exit {rev_ok}")
    refused["revoked"] = 0
# task: auv-21's reader got no forged task
tasks = [l for l in open(os.path.join(work, "tasks21.out"), errors="replace") if l.startswith("{")] if os.path.exists(os.path.join(work, "tasks21.out")) else []
evil = [l for l in tasks if '"evil' in l]
if evil:
    fails.append(f"task: auv-21 received {len(evil)} forged tasks")
    refused["task"] = 0
# nobody else became a vehicle
unexpected = sorted(station_ids - {"auv-21", "auv-22", "auv-23"} - {None})
if "auv-22" in station_ids:
    unexpected.append("auv-22 (never announced itself legitimately)")
if unexpected:
    fails.append(f"unexpected vehicles at the station: {unexpected}")
if not legit_ok:
    fails.append(f"legitimate samples: sent {sent}, station accepted {acc21} (rejected {rej21}), "
                 f"history {len(points)} ({extra:+d}), foreign {foreign[:3]}")
    for k in cases:
        if not k.startswith(("revoked", "impersonation", "task")):
            refused[k] = 0
if health != "200":
    fails.append(f"/api/health {health}")

total = sum(cases.values())
tot_ref = sum(v for k, v in refused.items() if "(" not in k)
out("")
out(f"{'kind':<22}{'cases':>8}{'refused':>9}")
for k in sorted(cases, key=lambda k: (k not in (pk.get('cases') or {}), k)):
    extra_note = f"  ({refused[k + ' (by its own stack)']} by the attacker's own stack)" if refused.get(k + " (by its own stack)") else ""
    out(f"{k:<22}{cases[k]:>8}{refused.get(k, 0):>9}{extra_note}")
out(f"{'total':<22}{total:>8}{tot_ref:>9}")
out(f"security counters: security:impersonation {imp0} -> {imp1}, security:revoked {rev0} -> {rev1}, security:handshake_refused:expired {hs_expired}")
out(f"legitimate auv-21 samples: sent {sent} ({n1} + {n2}), accepted by the station {acc21}, "
    f"rejected {rej21}, in its history {len(points)}")
out(f"packet corpus: captured {pk.get('captured')} datagrams of auv-21's (old, live) sessions; "
    f"sent to {pk.get('destinations')} (the station's locators {pk.get('station_locators')} and the SPDP group)")
out(f"station /api/health: {health}")
json.dump({"cases": cases, "refused": refused, "sent": sent, "accepted": acc21, "history": len(points),
           "fails": fails}, open(os.path.join(work, "verdict.json"), "w"))
if total < 10000:
    fails.append(f"only {total} cases (< 10,000)")
for f in fails:
    out(f"  problem: {f}")
sys.exit(1 if fails else 0)
EOF
ok=$?
cases_total=$(python3 -c 'import json,sys; d=json.load(open(sys.argv[1])); print(sum(d["cases"].values()))' "$WORK/verdict.json" 2>/dev/null || echo "?")
result "corpus  $cases_total cases, all refused, no legitimate sample lost, station healthy" $ok \
    "$(( T_END - T_START )) s in all; packets from $((T_ATTACK - T_START)) s, joins until $((T_JOINS - T_START)) s"
if [[ $ok != 0 || $VERBOSE == 1 ]]; then
    show_logs "$WORK/packets.err" "$WORK/run2.err" "$WORK/tasks21.err"
    for f in "$WORK"/cred/*.1.out; do show_logs "$f" "${f%.out}.err"; done
    grep -i "warn\|error" "$WORK/station.log" | tail -n 20 | sed 's/^/    | /'
fi
echo
(( FAILED > 0 )) && printf 'failed: %s\n' "${FAILURES[@]}"
echo "$PASSED passed, $FAILED failed"
(( FAILED == 0 ))
