#!/usr/bin/env bash
# Run a command inside a private, loopback-only network namespace so that DDS
# discovery (multicast) never leaves this machine.
#
# Usage:
#   scripts/netns-run.sh [<name>] -- <command...>   run <command> in namespace <name>
#   scripts/netns-run.sh --delete [<name>]          delete namespace <name>
#   scripts/netns-run.sh --setup [<name>]           only create/configure it
#   scripts/netns-run.sh --check [<name>]           set up, then prove multicast
#                                                   loops back on lo (UDP to 239.255.0.1)
# <name> defaults to "shoal-test" (or $SHOAL_NETNS).
#
# The namespace has only `lo` (up, multicast on) and a route 224.0.0.0/4 via lo,
# so RTPS SPDP multicast (239.255.0.1) and unicast both stay on loopback.
# Environment and exit code of <command> are preserved. Needs root (or
# CAP_SYS_ADMIN + CAP_NET_ADMIN). Safe to call repeatedly and concurrently:
# creation is serialized with flock and every step is idempotent.
set -euo pipefail

die() { echo "netns-run: $*" >&2; exit 2; }
usage() {
    awk 'NR > 1 && /^#/ { sub(/^# ?/, ""); print; next } NR > 1 { exit }' "$0" >&2
    exit 2
}

mode=run
name="${SHOAL_NETNS:-shoal-test}"
case "${1:-}" in
    --delete) mode=delete; shift ;;
    --setup) mode=setup; shift ;;
    --check) mode=check; shift ;;
    -h|--help|"") usage ;;
esac
if [[ $# -gt 0 && "$1" != "--" ]]; then
    name="$1"; shift
fi
[[ "$name" =~ ^[A-Za-z0-9_.-]{1,64}$ ]] || die "bad namespace name '$name'"

command -v ip >/dev/null || die "'ip' not found (apt-get install iproute2)"

lockfile="/run/lock/shoal-netns-${name}.lock"
mkdir -p /run/lock 2>/dev/null || true

ns_exists() { ip netns list 2>/dev/null | awk '{print $1}' | grep -qx -- "$name"; }

setup() {
    exec 9>"$lockfile"
    flock 9
    if ! ns_exists; then
        ip netns add "$name" 2>/dev/null || ns_exists || die "cannot create netns '$name'"
    fi
    ip -n "$name" link set lo up
    ip -n "$name" link set lo multicast on
    # `replace` is idempotent (add fails if the route is already there).
    ip -n "$name" route replace 224.0.0.0/4 dev lo
    # DDS discovery binds fixed ports, 7400 + 250 x domain and the next one; from domain
    # 102 up they fall in the kernel's ephemeral range, where any other socket of the
    # tests (an HTTP client, a Cyclone unicast socket) could already hold one, and then
    # creating that domain fails. Reserved ports are never handed out as ephemeral.
    local ports="" d
    for ((d = 0; d <= 232; d++)); do
        ports+="${ports:+,}$((7400 + 250 * d))-$((7401 + 250 * d))"
    done
    ip netns exec "$name" sh -c "echo '$ports' > /proc/sys/net/ipv4/ip_local_reserved_ports"
    # Safety net: there must be no interface other than lo.
    local others
    others=$(ip -n "$name" -o link show | awk -F': ' '{print $2}' | sed 's/@.*//' | grep -vx lo || true)
    [[ -z "$others" ]] || die "namespace '$name' has non-loopback interfaces: $others"
    flock -u 9
    exec 9>&-
}

case "$mode" in
    delete)
        exec 9>"$lockfile"; flock 9
        if ns_exists; then
            ip netns delete "$name"
            echo "netns-run: deleted namespace $name" >&2
        fi
        exit 0
        ;;
    setup)
        setup
        exit 0
        ;;
    check)
        setup
        # Join 239.255.0.1 (the RTPS SPDP group) on lo, send one datagram to
        # it and expect to read it back: what DDS discovery needs.
        ip netns exec "$name" python3 - <<'PY'
import socket, struct, sys
grp, port = "239.255.0.1", 7399
r = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
r.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
r.bind(("", port))
r.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP,
             struct.pack("4s4s", socket.inet_aton(grp), socket.inet_aton("127.0.0.1")))
r.settimeout(2)
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton("127.0.0.1"))
s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)
s.sendto(b"shoal-netns-check", (grp, port))
try:
    data, src = r.recvfrom(64)
except socket.timeout:
    sys.exit("netns-run: multicast check FAILED: nothing looped back on lo")
print(f"netns-run: multicast OK ({grp}:{port} from {src[0]})")
PY
        exit $?
        ;;
    run)
        [[ "${1:-}" == "--" ]] && shift
        [[ $# -gt 0 ]] || usage
        setup
        # `ip netns exec` keeps the environment; exec keeps the exit code and
        # lets signals reach the command directly.
        exec ip netns exec "$name" "$@"
        ;;
esac
