#!/usr/bin/env bash
# Checks that the vehicle side of Shoal (the `shoal` binary without its `console` feature:
# `shoal vehicle`, the proxies, the acoustic vehicle side, `shoal keys`) compiles for
# 64-bit ARM Linux vehicle computers (aarch64-unknown-linux-gnu), without Node.js.
#
# Installs what it needs when missing: the rustup target, and Debian's cross compilers
# (gcc- and g++-aarch64-linux-gnu, with the aarch64 C library headers), which Cyclone DDS
# (built from source by the `cyclors` crate with cmake, whose project also asks for a C++
# compiler; its bindings generated with libclang: see scripts/install-build-deps.sh) and
# mimalloc are compiled with. apt needs root.
#
# Runs `cargo check`; with `--build` it builds the release binary instead, to copy to a
# vehicle (~/.cache/shoal/vehicle-aarch64/aarch64-unknown-linux-gnu/release/shoal).
#
# Environment: CARGO_TARGET_DIR (default ~/.cache/shoal/vehicle-aarch64: its own directory,
# outside the checkout, so the check neither waits on nor churns the host build in target/,
# and a fresh clone reuses the cross-built Cyclone DDS).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
say() { echo "check-vehicle-aarch64: $*"; }

TARGET=aarch64-unknown-linux-gnu
CROSS_GCC=aarch64-linux-gnu-gcc
mode=check
case "${1:-}" in
    "") ;;
    --build) mode=build ;;
    *)
        echo "usage: $0 [--build]" >&2
        exit 2
        ;;
esac

if ! rustup target list --installed | grep -qx "$TARGET"; then
    say "rustup target add $TARGET"
    rustup target add "$TARGET"
fi

# cmake and libclang as for a native build (scripts/install-build-deps.sh, which also
# insists on npm: not needed here), and the cross compiler with the target's C library.
APT_PKGS=(cmake libclang-dev gcc-aarch64-linux-gnu g++-aarch64-linux-gnu libc6-dev-arm64-cross libssl-dev:arm64)
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
    # OpenSSL for the target (DDS Security): Debian's arm64 package beside the host's.
    if ! dpkg --print-foreign-architectures | grep -qx arm64; then
        dpkg --add-architecture arm64
    fi
    apt-get update -q
    apt-get install -y -q --no-install-recommends "${missing[@]}" </dev/null
fi

# cc-rs and the cmake crate would pick these compilers for this target by themselves; said
# here so that a machine with several cross toolchains uses Debian's. The linker (for
# --build) and bindgen's view of the target's C headers must be told.
export CARGO_TARGET_AARCH64_UNKNOWN_LINUX_GNU_LINKER="$CROSS_GCC"
export CC_aarch64_unknown_linux_gnu="$CROSS_GCC"
export CXX_aarch64_unknown_linux_gnu=aarch64-linux-gnu-g++
export AR_aarch64_unknown_linux_gnu=aarch64-linux-gnu-ar
export BINDGEN_EXTRA_CLANG_ARGS_aarch64_unknown_linux_gnu="--sysroot=/usr/aarch64-linux-gnu"
# The target's OpenSSL (libssl-dev:arm64): openssl-sys and Cyclone DDS's security plugins.
export AARCH64_UNKNOWN_LINUX_GNU_OPENSSL_LIB_DIR=/usr/lib/aarch64-linux-gnu
export AARCH64_UNKNOWN_LINUX_GNU_OPENSSL_INCLUDE_DIR=/usr/include
export CFLAGS_aarch64_unknown_linux_gnu="-I/usr/include/aarch64-linux-gnu"
# A build cache outside the checkout (like cargo's registry), so that a fresh clone on the
# same machine does not build Cyclone DDS for aarch64 from C again: ~6 min cold, seconds warm.
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-${XDG_CACHE_HOME:-$HOME/.cache}/shoal/vehicle-aarch64}"

start=$SECONDS
if [[ $mode == check ]]; then
    say "cargo check -p shoal --no-default-features --target $TARGET (in $CARGO_TARGET_DIR)"
    cargo check -p shoal --no-default-features --target "$TARGET" --locked
else
    say "cargo build --release -p shoal --no-default-features --target $TARGET (in $CARGO_TARGET_DIR)"
    cargo build --release -p shoal --no-default-features --target "$TARGET" --locked
    file "$CARGO_TARGET_DIR/$TARGET/release/shoal" 2>/dev/null || true
fi
say "done in $((SECONDS - start)) s"
