# Shared by the test scripts that print one PASS/FAIL line per step; bash only. Source it
# after setting VERBOSE (0/1), WORK (the run's scratch directory) and STATION_PID ("" until
# a station runs).
#
# result NAME OK DETAIL   counts and prints a step (OK: 0 passed, anything else failed)
# show_logs FILE...       the last 15 lines of each non-empty file, indented
# verbose_logs FILE...    the same, with -v only
# stop_everything         for `trap stop_everything EXIT`: stops background jobs, gives the
#                         station 10 s to stop cleanly, removes WORK

PASSED=0 FAILED=0 FAILURES=()
result() {
    if [[ "$2" == 0 ]]; then PASSED=$((PASSED + 1)); echo "PASS  $1  ($3)"
    else FAILED=$((FAILED + 1)); FAILURES+=("$1"); echo "FAIL  $1  ($3)"; fi
}
show_logs() {
    local f
    for f in "$@"; do
        [[ -s "$f" ]] || continue
        echo "    --- $(basename "$f")"; sed 's/^/    | /' "$f" | tail -n 15
    done
}
verbose_logs() { [[ $VERBOSE == 1 ]] && show_logs "$@"; }
stop_everything() {
    local p
    for p in $(jobs -p); do kill -TERM "$p" 2>/dev/null; done
    if [[ -n "$STATION_PID" ]]; then
        for _ in $(seq 50); do kill -0 "$STATION_PID" 2>/dev/null || break; sleep 0.2; done
        kill -KILL "$STATION_PID" 2>/dev/null
    fi
    wait 2>/dev/null
    rm -rf "$WORK"
}
