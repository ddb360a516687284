#!/usr/bin/env bash
# Runs every Shoal test on a fresh Debian 12 machine (as root), from the repository root:
#   1. installs what the tests need (apt packages, the Python venv with the foreign DDS
#      peers, the Fast DDS C++ peer, cargo-fuzz) and starts a private PostgreSQL inside
#      the namespace (the history tests run against SQLite and PostgreSQL),
#   2. checks formatting and clippy (also of the vehicle-side build without the console,
#      and `cargo check` of it for aarch64), builds every test binary OUTSIDE the namespace,
#   3. runs the foreign-peer matrix, a secure Shoal station with foreign secured vehicles
#      (Fast DDS and Cyclone DDS with their standard DDS Security plugins), and every Rust
#      test INSIDE private network namespaces (loopback only, multicast routed to lo), so
#      no DDS discovery traffic can leave the machine,
#   4. drives the web console in Debian's Chromium (Playwright) against `shoal up`, then
#      checks the HTTP API against its OpenAPI document with schemathesis, inside the
#      namespace,
#   5. runs each cargo-fuzz target for a short smoke run.
# Environment: SHOAL_SKIP_FUZZ=1 skips step 5; SHOAL_NETNS names the namespace;
# SHOAL_TEST_DISK_GB is the free disk the build needs (checked first, default 6).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
NS="${SHOAL_NETNS:-shoal-test}"
# Each step says when it starts; the end lists how long each took (the test command has a
# time budget, and this says where it goes).
step_name=""
step_start=$SECONDS
timings=()
step() {
    if [[ -n "$step_name" ]]; then
        timings+=("$(printf '%6d s  %s' $((SECONDS - step_start)) "$step_name")")
    fi
    step_name="$*"
    step_start=$SECONDS
    printf '\n==> %s  (at %d s)\n' "$*" "$SECONDS"
}

# A one-off run gains nothing from incremental compilation, which doubles the workspace
# crates' share of target/; set CARGO_INCREMENTAL=1 to keep it between runs.
export CARGO_INCREMENTAL="${CARGO_INCREMENTAL:-0}"
# Nor does it need debug info: a failing test's panic still names its file and line (that
# is not debug info). Measured on a clean clone: target/ peaked at 4.4 GB this way, 6.25 GB
# with the profiles' line tables; with the small-disk removals below the whole clone
# peaked at 4.9 GB (8.8 GB before: target/ and fuzz/target side by side).
export CARGO_PROFILE_DEV_DEBUG="${CARGO_PROFILE_DEV_DEBUG:-false}"
export CARGO_PROFILE_RELEASE_DEBUG="${CARGO_PROFILE_RELEASE_DEBUG:-false}"

# Stop at once, not at the first linker error twenty minutes in, when the disk is too
# small for the build (the debug binaries, clippy, the fuzz targets).
need_gb="${SHOAL_TEST_DISK_GB:-6}"
target_dir="${CARGO_TARGET_DIR:-$PWD/target}"
mkdir -p "$target_dir"
free_gb=$(( $(df --output=avail -k "$target_dir" | tail -1) / 1024 / 1024 ))
have_gb=$(( free_gb + $(du -sk "$target_dir" | cut -f1) / 1024 / 1024 ))
if (( have_gb < need_gb )); then
    echo "error: the test command needs about ${need_gb} GB for $target_dir;" \
         "${free_gb} GB are free (set SHOAL_TEST_DISK_GB to change the check)" >&2
    exit 1
fi
# Below this much free disk at the start (SHOAL_TEST_ROOMY_GB, default 20), each build is
# removed once nothing needs it.
roomy_gb="${SHOAL_TEST_ROOMY_GB:-20}"
tight=$(( free_gb < roomy_gb ))

step "installing test dependencies"
scripts/install-test-deps.sh

step "PostgreSQL inside network namespace $NS (the history store's second backend)"
scripts/netns-run.sh --setup "$NS"
pg_url="$(scripts/postgres.sh start --netns "$NS")"
echo "PostgreSQL: $pg_url"

step "formatting and lints"
cargo fmt --all --check
cargo clippy --workspace --all-targets --locked -- -D warnings

step "the vehicle side: no console feature (no Node), clippy-clean, and checked for aarch64"
cargo clippy -p shoal --no-default-features --all-targets --locked -- -D warnings
scripts/check-vehicle-aarch64.sh

step "building tests (outside the namespace)"
cargo test --workspace --locked --no-run

step "RTI XML types agree with idl/shoal.idl"
.venv/bin/python tests/interop/check_rti_xml.py

step "foreign DDS peers against each other (Cyclone, RTI, Fast DDS)"
tests/interop/peer_matrix.sh

# The scripts below drive the `shoal` binary the test build made (target/debug/shoal): the
# same code as a release build, which on two cores took 18 more minutes of the budget.
shoal_bin="${CARGO_TARGET_DIR:-$PWD/target}/debug/shoal"

step "a secure Shoal station with foreign secured vehicles (Fast DDS, Cyclone DDS C; DDS Security 1.1)"
SHOAL_BIN="$shoal_bin" tests/interop/secure/shoal_secure_interop.sh

step "the attack corpus against a secure Shoal station (> 10,000 packet and credential attacks, all refused)"
SHOAL_BIN="$shoal_bin" tests/security/attack_corpus.sh

step "Rust tests inside network namespace $NS (interop peers required)"
results="$(mktemp)"
trap 'rm -f "$results"; scripts/postgres.sh stop >/dev/null 2>&1 || true' EXIT
SHOAL_INTEROP_REQUIRED=1 SHOAL_TEST_POSTGRES_URL="$pg_url" SHOAL_TEST_POSTGRES_REQUIRED=1 \
    scripts/netns-run.sh "$NS" -- cargo test --workspace --locked 2>&1 | tee "$results"
passed=$(grep -Eo 'test result: ok\. [0-9]+ passed' "$results" | awk '{s += $4} END {print s + 0}')

step "web console in a real browser (Playwright + Chromium against shoal up, inside $NS)"
SHOAL_BIN="$shoal_bin" scripts/console-e2e.sh "$NS"

step "the HTTP API against its OpenAPI document (schemathesis, all checks, inside $NS)"
SHOAL_BIN="$shoal_bin" scripts/api-conformance.sh "$NS"

step "shared history: a ship's PostgreSQL streamed to a standby ashore, across an outage (inside $NS)"
SHOAL_BIN="$shoal_bin" tests/history/replication.sh "$NS"

if [[ "${SHOAL_SKIP_FUZZ:-0}" != 1 ]]; then
    # On a small disk the debug build goes once it is done with: the fuzz targets build
    # apart (fuzz/target), under the nightly toolchain. A larger disk keeps it for the next
    # run.
    if (( tight )); then
        echo "disk: removing the debug build (under ${roomy_gb} GB were free at the start)"
        rm -rf "${CARGO_TARGET_DIR:-$PWD/target}/debug"
    fi
    step "fuzz smoke run (every cargo-fuzz target, 10 s each; scripts/fuzz-long.sh runs them for longer)"
    # cargo-fuzz needs the nightly toolchain (fuzzing only: the product builds on stable).
    if ! cargo +nightly --version >/dev/null 2>&1; then
        rustup toolchain install nightly --profile minimal
    fi
    if ! cargo +nightly fuzz --version >/dev/null 2>&1; then
        cargo +nightly install cargo-fuzz --locked
    fi
    for target in $(cd fuzz && cargo +nightly fuzz list); do
        (cd fuzz && cargo +nightly fuzz run "$target" -- -max_total_time=10 -print_final_stats=0)
    done
fi

step "all tests passed"
printf '%s\n' "${timings[@]}"
echo "time: ${SECONDS} s in all"
echo "summary: ${passed} passed, 0 failed"
