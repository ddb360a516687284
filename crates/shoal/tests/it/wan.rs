//! The WAN bench's short run: `shoal bench federation` with three stations (ship-1, the
//! shore, ship-2) in network namespaces of their own, joined by the bench's user-space
//! satellite link (600 ms RTT, 64 kbit/s, 2 % loss), 50 vehicles per ship, 80 s with ship-1's
//! link cut for 15 s. Only the hard invariants are asserted, never a timing target: every
//! alarm and task transition ship-1 numbered is at the shore exactly once after the outage,
//! alarms arrive, the uplink per site count is measured, and ship-1 and the shore (its
//! lease standby) agree on every command lease once the link is back.
//!
//! The bench makes its namespaces (`shoal-wan-<pid>-*`) inside the test's own
//! (`scripts/netns-run.sh`) and deletes them; it needs root and /dev/net/tun, and the test
//! is skipped, saying why, without them.

use std::process::Command;

/// Why this machine cannot run the bench, if it cannot.
fn cannot_run() -> Option<String> {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    let root = status
        .lines()
        .find_map(|l| l.strip_prefix("Uid:"))
        .and_then(|v| v.split_whitespace().nth(1))
        == Some("0");
    if !root {
        return Some("not root (network namespaces and TUN devices need it)".into());
    }
    if !std::path::Path::new("/dev/net/tun").exists() {
        return Some("no /dev/net/tun".into());
    }
    None
}

#[test]
fn the_federation_over_an_emulated_satellite_link_loses_and_repeats_nothing_across_an_outage() {
    if let Some(why) = cannot_run() {
        eprintln!("SKIPPED the WAN bench's short run: {why}");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let summary = dir.path().join("summary.json");
    let out = Command::new(env!("CARGO_BIN_EXE_shoal"))
        .args([
            "bench",
            "federation",
            "--seconds",
            "80",
            "--outage",
            "15",
            "--vehicles",
            "50",
            "--rtt-ms",
            "600",
            "--rate-kbps",
            "64",
            "--loss-pct",
            "2",
            "--lease-timeout",
            "1",
            "--summary",
        ])
        .arg(&summary)
        .env("RUST_LOG", "warn")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stdout}\n{stderr}");
    let s: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&summary).unwrap()).unwrap();
    let n = |v: &serde_json::Value| v.as_u64().unwrap();
    // Alarms arrive, each exactly once, the outage's caught up.
    assert!(n(&s["alarms_raised"]) >= 30, "{s}\n{stdout}");
    assert_eq!(s["raised_alarms_missing"], 0, "{s}\n{stdout}");
    assert_eq!(n(&s["alarms"]["duplicated"]), 0, "{s}\n{stdout}");
    assert_eq!(n(&s["alarms"]["lost"]), 0, "{s}\n{stdout}");
    assert_eq!(
        s["alarms"]["sent"], s["alarms"]["distinct"],
        "{s}\n{stdout}"
    );
    // Task transitions too (seven tasks or more, four transitions each).
    assert!(n(&s["transitions"]["sent"]) >= 20, "{s}\n{stdout}");
    assert_eq!(n(&s["transitions"]["duplicated"]), 0, "{s}\n{stdout}");
    assert_eq!(n(&s["transitions"]["lost"]), 0, "{s}\n{stdout}");
    assert_eq!(
        s["transitions"]["sent"], s["transitions"]["distinct"],
        "{s}\n{stdout}"
    );
    assert_eq!(s["settled"], true, "{s}\n{stdout}");
    // The uplink per site count is measured (its 10 % target is the long run's).
    assert!(s["uplink_2_sites_bps"].as_f64().unwrap() > 0.0, "{s}");
    assert!(s["uplink_3_sites_bps"].as_f64().unwrap() > 0.0, "{s}");
    assert_eq!(n(&s["ship_vehicles_at_shore"]), 50, "{s}\n{stdout}");
    assert!(stdout.contains("| target | measured | met |"), "{stdout}");
    // The command lease: every ship-1 vehicle had one before the cut, and once the link is
    // back the shore (its standby, which may have taken them over in the outage) and
    // ship-1 agree on every one; a taken-over lease is no longer held by ship-1.
    let lease = &s["lease"];
    assert_eq!(
        n(&lease["leased_before"]),
        50,
        "{s}
{stdout}"
    );
    assert_eq!(
        n(&lease["disagreeing_at_end"]),
        0,
        "{s}
{stdout}"
    );
    assert_eq!(
        n(&lease["held_by_shore_at_end"]) + n(&lease["held_by_ship_at_end"]),
        50,
        "{s}
{stdout}"
    );
    // The bench deleted its namespaces.
    let list = Command::new("ip").args(["netns", "list"]).output().unwrap();
    let pid_ns = String::from_utf8_lossy(&list.stdout)
        .lines()
        .filter(|l| l.starts_with("shoal-wan-"))
        .map(str::to_owned)
        .collect::<Vec<_>>();
    // Another test binary's run may be under way; none may be left by a process gone.
    for ns in pid_ns {
        let pid = ns.split('-').nth(2).unwrap_or("");
        assert!(
            std::path::Path::new(&format!("/proc/{pid}")).exists(),
            "namespace {ns} left behind"
        );
    }
}
