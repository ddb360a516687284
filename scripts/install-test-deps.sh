#!/usr/bin/env bash
# Installs everything Shoal's DDS interop tests need on a Debian 12 machine:
#   - apt, through scripts/install-build-deps.sh: cmake + libclang-dev (Shoal's own
#     build: Cyclone DDS from source), iproute2 (network namespaces), cyclonedds-tools (ddsperf,
#     idlc), cyclonedds-dev (Debian's Cyclone DDS 0.10 C headers; libddsc0debian with the DDS
#     Security plugins), libfastrtps-dev + libfastcdr-dev (Fast DDS 2.9 / Fast CDR 1.0), gcc,
#     g++, make, openssl (test keystores), python3-venv, faketime (tests/security: an attacker
#     whose clock is set back loads expired credentials), curl (the console API in the
#     secure interop test)
#   - $REPO/.venv with PyPI cyclonedds and rticonnextdds-connector (DDS peers),
#     rdflib (independent SPARQL engine for the semantic cross-check and SPARQL protocol
#     client), schemathesis (OpenAPI conformance, scripts/api-conformance.sh), mcap (the
#     reference MCAP reader for recordings), pyais (an independent AIS encoder) and
#     eclipse-zenoh (the federation's independent client, tests/federation; the same
#     Zenoh 1.x protocol as the zenoh crate in Cargo.toml)
#   - tests/foxglove/node_modules: Foxglove's own client (npm), for the bridge's test
#   - the Fast DDS C++ peer and the Cyclone DDS C peer, built into tests/interop/build/
#     (gitignored; the C peer's type support is generated there by idlc)
#   - pymavlink and imcpy in the venv, the vehicle proxies' test peers
#     (scripts/install-proxy-peers.sh)
# Idempotent: every step is skipped when already done, so a re-run is fast.
# Run as root, non-interactively (CI=true, no stdin is fine).
#
# Environment overrides: PYTHON (interpreter for the venv, default python3),
# SHOAL_PIP_CYCLONEDDS / SHOAL_PIP_RTI / SHOAL_PIP_RDFLIB / SHOAL_PIP_SCHEMATHESIS /
# SHOAL_PIP_MCAP / SHOAL_PIP_PYAIS / SHOAL_PIP_ZENOH (pip requirement specs).
set -euo pipefail

REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$REPO/.venv"
PYTHON="${PYTHON:-python3}"
PIP_CYCLONEDDS="${SHOAL_PIP_CYCLONEDDS:-cyclonedds==11.0.1}"
PIP_RTI="${SHOAL_PIP_RTI:-rticonnextdds-connector==1.2.4}"
PIP_RDFLIB="${SHOAL_PIP_RDFLIB:-rdflib==7.6.0}"
PIP_SCHEMATHESIS="${SHOAL_PIP_SCHEMATHESIS:-schemathesis==4.32.5}"
PIP_MCAP="${SHOAL_PIP_MCAP:-mcap==1.6.0}"
PIP_PYAIS="${SHOAL_PIP_PYAIS:-pyais==3.3.1}"
PIP_ZENOH="${SHOAL_PIP_ZENOH:-eclipse-zenoh==1.10.2}"
export DEBIAN_FRONTEND=noninteractive

say() { echo "install-test-deps: $*"; }

if [[ $(id -u) != 0 ]]; then
    say "must run as root (apt-get, network namespaces)" >&2
    exit 1
fi

# ---------------------------------------------------------------- apt
# The build's own packages (cmake, libclang-dev) and the tests', in one apt run.
"$REPO/scripts/install-build-deps.sh" iproute2 cyclonedds-tools cyclonedds-dev libfastrtps-dev \
    libfastcdr-dev gcc g++ make openssl python3 python3-venv faketime curl

# ---------------------------------------------------------------- venv
venv_ok() {
    [[ -x "$VENV/bin/python" ]] &&
        "$VENV/bin/python" -c 'import cyclonedds.domain, rticonnextdds_connector, rdflib, schemathesis, mcap, pyais, zenoh' 2>/dev/null
}
if venv_ok; then
    say "venv $VENV ready (cyclonedds, rticonnextdds-connector, rdflib, schemathesis, mcap, pyais, zenoh importable)"
else
    if [[ ! -x "$VENV/bin/python" ]]; then
        say "creating venv $VENV with $(command -v "$PYTHON")"
        "$PYTHON" -m venv "$VENV"
    fi
    say "pip install $PIP_CYCLONEDDS $PIP_RTI $PIP_RDFLIB $PIP_SCHEMATHESIS $PIP_MCAP $PIP_PYAIS $PIP_ZENOH"
    "$VENV/bin/python" -m pip install -q --disable-pip-version-check "$PIP_CYCLONEDDS" "$PIP_RTI" \
        "$PIP_RDFLIB" "$PIP_SCHEMATHESIS" "$PIP_MCAP" "$PIP_PYAIS" "$PIP_ZENOH"
    venv_ok || { say "venv still cannot import cyclonedds / rticonnextdds_connector / rdflib / schemathesis / mcap / pyais / zenoh" >&2; exit 1; }
fi

# ---------------------------------------------------------------- Foxglove client
# Foxglove's own WebSocket protocol client (@foxglove/ws-protocol) and IDL/CDR decoders, for
# the Foxglove bridge's interop test; reinstalled only when the lock file changed.
fox="$REPO/tests/foxglove"
if [[ -f "$fox/node_modules/.package-lock.json" && "$fox/node_modules/.package-lock.json" -nt "$fox/package-lock.json" ]]; then
    say "Foxglove client packages up to date: tests/foxglove/node_modules"
else
    say "npm ci in tests/foxglove (the Foxglove bridge's client)"
    npm ci --prefix "$fox" --ignore-scripts --no-audit --no-fund
fi

# ---------------------------------------------------------------- Fast DDS peer
# make rebuilds only when fastdds_peer.cpp or the Makefile changed.
if make -q -C "$REPO/tests/interop/fastdds" BUILD="$REPO/tests/interop/build" >/dev/null 2>&1; then
    say "Fast DDS peer up to date: tests/interop/build/fastdds_peer"
else
    say "building Fast DDS peer -> tests/interop/build/fastdds_peer"
    make -C "$REPO/tests/interop/fastdds" BUILD="$REPO/tests/interop/build"
fi

# ---------------------------------------------------------------- Cyclone DDS C peer
# Debian's Cyclone DDS 0.10.2 from C; make regenerates the type support (idlc) and
# rebuilds only when cyclone_c_peer.c, idl/shoal.idl or the Makefile changed.
if make -q -C "$REPO/tests/interop/cyclone_c" BUILD="$REPO/tests/interop/build" >/dev/null 2>&1; then
    say "Cyclone DDS C peer up to date: tests/interop/build/cyclone_c_peer"
else
    say "building Cyclone DDS C peer -> tests/interop/build/cyclone_c_peer"
    make -C "$REPO/tests/interop/cyclone_c" BUILD="$REPO/tests/interop/build"
fi

# ---------------------------------------------------------------- vehicle proxy peers
# pymavlink (an ArduSub-like vehicle) and imcpy (an IMC AUV) for the proxy tests.
"$REPO/scripts/install-proxy-peers.sh"

say "done"
