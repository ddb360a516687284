#!/usr/bin/env bash
# Long fuzzing runs: every cargo-fuzz target for N executions (default 10
# million), one after another, on one core at low priority. Prints one line per target
# with the executions done, the time taken and the corpus size; a crash stops with the
# target's name and the input saved under fuzz/artifacts/<target>/ (turn it into a
# regression test with the bytes inline, as the codecs' tests do).
#
# Usage: scripts/fuzz-long.sh [runs] [target...]     (needs nightly and cargo-fuzz)
set -euo pipefail
repo="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
runs="${1:-10000000}"
shift || true
cd "$repo/fuzz"
targets=("$@")
if [[ ${#targets[@]} -eq 0 ]]; then
    mapfile -t targets < <(cargo +nightly fuzz list)
fi
for t in "${targets[@]}"; do
    cargo +nightly fuzz build --release "$t" >/dev/null 2>&1 || cargo +nightly fuzz build --release "$t"
    start=$(date +%s)
    log="$(mktemp)"
    if ! nice -n 19 cargo +nightly fuzz run --release "$t" -- -runs="$runs" -print_final_stats=1 >"$log" 2>&1; then
        tail -40 "$log"
        echo "fuzz-long: $t FAILED (input in fuzz/artifacts/$t/)"
        exit 1
    fi
    execs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$log" | grep -o '[0-9]*$' || echo "?")
    corpus=$(find "corpus/$t" -type f 2>/dev/null | wc -l)
    echo "fuzz-long: $t: $execs executions in $(( $(date +%s) - start )) s, corpus $corpus inputs, no crash"
    rm -f "$log"
done
