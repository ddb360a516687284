# Shared by the test scripts that start DDS processes of their own. Source it after setting
# REPO (the repository root); bash only.
#
# own_netns NAME "$@"   re-runs the calling script inside a network namespace of its own,
#                       shoal-NAME-<pid>, deleted when it ends, so discovery multicast never
#                       leaves this host; returns at once when already inside it.
# need_shoal_release    builds target/release/shoal once when SHOAL_BIN is unset and the
#                       binary is missing (call it before own_netns: the build needs no
#                       namespace).

own_netns() {
    local name=$1
    shift
    [[ "${SHOAL_OWN_NETNS:-}" == "$name" ]] && return 0
    OWN_NS="shoal-$name-$$"
    trap '"$REPO/scripts/netns-run.sh" --delete "$OWN_NS" 2>/dev/null' EXIT
    SHOAL_OWN_NETNS=$name "$REPO/scripts/netns-run.sh" "$OWN_NS" -- bash "$0" "$@"
    exit $?
}

need_shoal_release() {
    if [[ -z "${SHOAL_BIN:-}" && ! -x "$REPO/target/release/shoal" ]]; then
        echo "# building target/release/shoal (cargo build --release -p shoal)"
        (cd "$REPO" && cargo build --release -p shoal) || exit 2
    fi
}
