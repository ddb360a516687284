#!/usr/bin/env bash
# Installs what building Shoal needs beyond Rust, on Debian 12: cmake and libclang, with
# which the `cyclors` crate builds Eclipse Cyclone DDS from its bundled source and
# generates its Rust bindings, and OpenSSL's headers (libssl-dev, found with pkg-config)
# for Cyclone's DDS Security plugins and Shoal's key store. Node.js >= 20 and npm (for the console) are checked, not
# installed. Further Debian packages given as arguments are installed in the same apt run
# (scripts/install-test-deps.sh passes the tests' own). Idempotent; apt needs root.
set -euo pipefail
say() { echo "install-build-deps: $*"; }

APT_PKGS=(cmake libclang-dev libssl-dev pkg-config "$@")
missing=()
for p in "${APT_PKGS[@]}"; do
    if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
        missing+=("$p")
    fi
done
if ((${#missing[@]})); then
    if [[ $(id -u) != 0 ]]; then
        say "missing ${missing[*]}: run 'sudo apt-get install ${missing[*]}' (or this script as root)" >&2
        exit 1
    fi
    say "apt-get install ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -q
    apt-get install -y -q --no-install-recommends "${missing[@]}" </dev/null
else
    say "apt packages present: ${APT_PKGS[*]}"
fi
if ! command -v npm >/dev/null 2>&1; then
    say "npm not found: the console's build needs Node.js >= 20 and npm" >&2
    exit 1
fi
