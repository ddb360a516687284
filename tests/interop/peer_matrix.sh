#!/usr/bin/env bash
# Interop matrix between Shoal's foreign DDS peers (Cyclone DDS, RTI Connext,
# Fast DDS), all inside a private loopback-only network namespace.
#
#   state  (VehicleAnnouncement + StateVector):  cyclone->rti, rti->fastdds, fastdds->cyclone
#   task   (TaskAssignment):                     rti->cyclone, fastdds->rti, cyclone->fastdds
#   late-joining task subscriber (transient-local; the subscriber starts only
#   after the publisher has written): cyclone->rti, rti->fastdds, fastdds->cyclone
#   codec: Fast DDS hand-written serializer == Cyclone's XCDR1 bytes; key hashes agree
#   rti xml: shoal_rti.xml agrees with idl/shoal.idl
#   wire: every user DATA on the wire (all vendors) has encapsulation CDR_LE/CDR_BE
#
# Usage: tests/interop/peer_matrix.sh [-v]        (-v: show each peer's stderr)
# Needs root (network namespaces) and scripts/install-test-deps.sh done.
# Prints "N passed, M failed" and exits non-zero if anything failed.
set -uo pipefail

HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
REPO="$(cd "$HERE/../.." && pwd)"

# shellcheck source=../lib/own-netns.sh
source "$REPO/tests/lib/own-netns.sh"
own_netns matrix "$@"

VERBOSE=0
[[ "${1:-}" == "-v" ]] && VERBOSE=1

PY="$REPO/.venv/bin/python"
PEERS="$HERE/peers"
FASTDDS="$HERE/build/fastdds_peer"
WORK="$(mktemp -d /tmp/shoal-matrix.XXXXXX)"
trap 'jobs -p | xargs -r kill 2>/dev/null; rm -rf "$WORK"' EXIT

[[ -x "$PY" ]] || { echo "missing $PY: run scripts/install-test-deps.sh" >&2; exit 2; }
[[ -x "$FASTDDS" ]] || { echo "missing $FASTDDS: run scripts/install-test-deps.sh" >&2; exit 2; }

peer() {  # peer <name> args...  (always called with &: exec makes $! the peer's timeout)
    local name="$1"; shift
    case "$name" in
        cyclone) exec timeout -s TERM 60 "$PY" "$PEERS/cyclone_peer.py" "$@" ;;
        rti)     exec timeout -s TERM 60 "$PY" "$PEERS/rti_peer.py" "$@" ;;
        fastdds) exec timeout -s TERM 60 "$FASTDDS" "$@" ;;
        *) echo "unknown peer $name" >&2; return 2 ;;
    esac
}
vendor() { case "$1" in cyclone) echo cyclonedds ;; rti) echo rti-connext ;; fastdds) echo fastdds ;; esac; }

PASSED=0
FAILED=0
FAILURES=()
DOMAIN=20

result() {  # result <name> <ok 0/1> <detail>
    if [[ "$2" == 0 ]]; then
        PASSED=$((PASSED + 1)); echo "PASS  $1  ($3)"
    else
        FAILED=$((FAILED + 1)); FAILURES+=("$1"); echo "FAIL  $1  ($3)"
    fi
}

show_logs() {
    local f
    for f in "$@"; do
        [[ -s "$f" ]] || continue
        echo "    --- $(basename "$f")"; sed 's/^/    | /' "$f" | tail -n 20
    done
}

wait_for_line() {  # wait_for_line <file> <regex> <seconds>
    local end=$((SECONDS + $3))
    while (( SECONDS < end )); do
        grep -qE "$2" "$1" 2>/dev/null && return 0
        sleep 0.1
    done
    return 1
}

# state <publisher> <subscriber>
test_state() {
    local pub="$1" sub="$2" d=$((DOMAIN++)) id="auv-$1-$2" n=5 t="$WORK/state-$1-$2"
    peer "$sub" --domain "$d" subscribe-state --vehicle-id "$id" --expect "$n" \
        --expect-announcements 1 --timeout 40 >"$t.sub.out" 2>"$t.sub.err" &
    local sp=$!
    peer "$pub" --domain "$d" publish-state --vehicle-id "$id" --count "$n" --rate 20 --linger 2 \
        >"$t.pub.out" 2>"$t.pub.err" &
    local pp=$!
    wait "$sp"; local src=$?
    wait "$pp"; local prc=$?
    local detail ok=1
    if [[ $src != 0 ]]; then detail="subscriber exit $src"
    elif [[ $prc != 0 ]]; then detail="publisher exit $prc"
    elif ! grep -qx "published $n" "$t.pub.out"; then detail="publisher did not print 'published $n'"
    elif detail=$("$PY" "$HERE/matrix_check.py" state "$t.sub.out" --vehicle-id "$id" --count "$n" \
                  --vendor "$(vendor "$pub")" 2>&1); then ok=0
    fi
    result "state   $pub -> $sub" $ok "$detail"
    if [[ $ok != 0 || $VERBOSE == 1 ]]; then show_logs "$t.pub.err" "$t.sub.out" "$t.sub.err"; fi
}

# task <publisher> <subscriber> [late]
test_task() {
    local pub="$1" sub="$2" late="${3:-}" d=$((DOMAIN++)) id="auv-$1-$2" task="task-$1-$2${3:+-late}"
    local t="$WORK/task-$1-$2${3:+-late}" sp pp src prc
    if [[ -z "$late" ]]; then
        peer "$sub" --domain "$d" subscribe-task --vehicle-id "$id" --expect 1 --timeout 40 \
            >"$t.sub.out" 2>"$t.sub.err" &
        sp=$!
        sleep 1
        peer "$pub" --domain "$d" publish-task --vehicle-id "$id" --task-id "$task" --linger 4 \
            --wait-match 20 >"$t.pub.out" 2>"$t.pub.err" &
        pp=$!
    else
        # Publisher first, subscriber only after the sample has been written.
        peer "$pub" --domain "$d" publish-task --vehicle-id "$id" --task-id "$task" --linger 15 \
            >"$t.pub.out" 2>"$t.pub.err" &
        pp=$!
        if ! wait_for_line "$t.pub.err" "published task" 20; then
            kill "$pp" 2>/dev/null; wait "$pp"
            result "task    $pub -> $sub (late join)" 1 "publisher never published"
            show_logs "$t.pub.err"; return
        fi
        sleep 2
        peer "$sub" --domain "$d" subscribe-task --vehicle-id "$id" --expect 1 --timeout 12 \
            >"$t.sub.out" 2>"$t.sub.err" &
        sp=$!
    fi
    wait "$sp"; src=$?
    kill -TERM "$pp" 2>/dev/null  # no need to linger once delivered
    wait "$pp"; prc=$?
    local detail ok=1
    if [[ $src != 0 ]]; then detail="subscriber exit $src"
    elif [[ $prc != 0 ]]; then detail="publisher exit $prc"
    elif detail=$("$PY" "$HERE/matrix_check.py" task "$t.sub.out" --vehicle-id "$id" \
                  --task-id "$task" 2>&1); then ok=0
    fi
    result "task    $pub -> $sub${late:+ (late join)}" $ok "$detail"
    if [[ $ok != 0 || $VERBOSE == 1 ]]; then show_logs "$t.pub.err" "$t.sub.out" "$t.sub.err"; fi
}

test_codec() {
    local ty out json hex chex ok detail
    for ty in StateVector VehicleAnnouncement TaskAssignment; do
        ok=1
        if out=$("$FASTDDS" encode-demo "$ty" 2>&1); then
            json=$(sed -n 1p <<<"$out"); hex=$(sed -n 2p <<<"$out")
            chex=$("$PY" "$PEERS/cyclone_peer.py" encode-sample "$ty" "$json" 2>&1)
            if [[ -n "$hex" && "$hex" == "$chex" ]]; then ok=0; detail="$(( ${#hex} / 2 )) bytes identical"
            else detail="fastdds $hex != cyclone $chex"; fi
        else detail="encode-demo failed: $out"; fi
        result "codec   $ty fastdds == cyclonedds XCDR1" $ok "$detail"
    done
    local k fk ck
    for k in "StateVector vehicle_id auv-1" "TaskAssignment task_id task-7"; do
        set -- $k
        ok=1
        fk=$("$FASTDDS" key-hash "$1" "$3" 2>&1)
        json=$("$FASTDDS" encode-demo "$1" | sed -n 1p)
        ck=$("$PY" "$PEERS/cyclone_peer.py" key-hash "$1" "$json" 2>&1)
        [[ -n "$fk" && "$fk" == "$ck" ]] && ok=0
        result "keyhash $1($3) fastdds == cyclonedds" $ok "$fk vs $ck"
    done
}

echo "# Shoal peer interop matrix (netns $(ip netns identify $$ 2>/dev/null || echo '?'))"

if out=$("$PY" "$HERE/check_rti_xml.py" 2>&1); then result "rti-xml shoal_rti.xml == idl/shoal.idl" 0 "$(tail -n1 <<<"$out")"
else result "rti-xml shoal_rti.xml == idl/shoal.idl" 1 "see below"; sed 's/^/    | /' <<<"$out"; fi

test_codec

# Watch the wire for the rest of the run: every user sample must be XCDR1.
"$PY" "$HERE/rtps_sniff.py" --expect-vendors cyclonedds,rti,fastdds --ready-file "$WORK/sniff.ready" \
    >"$WORK/sniff.out" 2>"$WORK/sniff.err" &
SNIFF=$!
for _ in $(seq 100); do [[ -e "$WORK/sniff.ready" ]] && break; sleep 0.1; done

test_state cyclone rti
test_state rti fastdds
test_state fastdds cyclone

test_task rti cyclone
test_task fastdds rti
test_task cyclone fastdds

test_task cyclone rti late
test_task rti fastdds late
test_task fastdds cyclone late

kill -TERM "$SNIFF" 2>/dev/null
if wait "$SNIFF"; then
    result "wire    every user DATA is plain CDR (XCDR1)" 0 "$(cat "$WORK/sniff.out")"
else
    result "wire    every user DATA is plain CDR (XCDR1)" 1 "$(cat "$WORK/sniff.out" "$WORK/sniff.err")"
fi

echo
if (( FAILED > 0 )); then
    printf 'failed: %s\n' "${FAILURES[@]}"
fi
echo "$PASSED passed, $FAILED failed"
(( FAILED == 0 ))
