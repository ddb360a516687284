#!/usr/bin/env bash
# Installs what the vehicle-proxy test peers (tests/peers/) need into the project venv
# $REPO/.venv, which scripts/install-test-deps.sh creates:
#   - pymavlink (the ArduSub-like MAVLink peer, tests/peers/ardusub_peer.py)
#   - imcpy     (the DUNE-like IMC peer, tests/peers/imc_auv_peer.py)
# The ROS 2 peer uses cyclonedds, which install-test-deps.sh already installs.
# Both are binary wheels for CPython 3.11 x86_64 (manylinux), so no compiler is needed.
# Idempotent: nothing is installed when both already import.
#
# Environment overrides: SHOAL_PIP_PYMAVLINK / SHOAL_PIP_IMCPY (pip requirement specs).
set -euo pipefail

REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$REPO/.venv"
PIP_PYMAVLINK="${SHOAL_PIP_PYMAVLINK:-pymavlink==2.4.50}"
PIP_IMCPY="${SHOAL_PIP_IMCPY:-imcpy==1.1.2}"

say() { echo "install-proxy-peers: $*"; }

if [[ ! -x "$VENV/bin/python" ]]; then
    say "$VENV/bin/python not found: run scripts/install-test-deps.sh first" >&2
    exit 1
fi

peers_ok() {
    "$VENV/bin/python" -c 'import pymavlink.mavutil, pymavlink.dialects.v20.ardupilotmega, imcpy' 2>/dev/null
}
if peers_ok; then
    say "venv $VENV ready (pymavlink, imcpy importable)"
else
    say "pip install $PIP_PYMAVLINK $PIP_IMCPY"
    "$VENV/bin/python" -m pip install -q --disable-pip-version-check "$PIP_PYMAVLINK" "$PIP_IMCPY"
    peers_ok || { say "venv still cannot import pymavlink / imcpy" >&2; exit 1; }
fi
say "done"
