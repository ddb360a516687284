//! The command lease end to end, at the vehicle: a ship's station and a shore station both
//! reach one vehicle (DDS domain 213, as when both are in radio range of it) and federate
//! through a Zenoh router that the test closes to cut the link and opens again to heal it.
//!
//! The ship holds the lease and commands; cut off, it still believes it does, while the
//! shore (its standby) takes the lease over, announces it to the vehicle and commands too.
//! The vehicle obeys the newer lease and refuses the ship's task, saying who it obeys;
//! once the link heals the ship
//! learns the shore's lease and refuses to command at all.
//!
//! Then a shore with no path of its own to the ship's vehicle commands it through the
//! ship's station, under the lease it was handed.

use std::path::Path;
use std::time::Duration;

use crate::common::{free_port, http_get, http_post};
use crate::federation::{auv, federated_station, json};
use crate::recorder::Proc;

const DOMAIN: u16 = 213;

/// A bare Zenoh router on loopback: the link between the two sites.
fn router(rt: &tokio::runtime::Runtime, port: u16) -> zenoh::Session {
    let mut c = zenoh::Config::default();
    for (k, v) in [
        ("mode", r#""router""#.to_owned()),
        ("listen/endpoints", format!(r#"["tcp/127.0.0.1:{port}"]"#)),
        ("connect/endpoints", "[]".into()),
        ("scouting/multicast/enabled", "false".into()),
        ("scouting/gossip/enabled", "false".into()),
    ] {
        c.insert_json5(k, &v).unwrap();
    }
    rt.block_on(async { zenoh::open(c).await }).unwrap()
}

/// Who holds `vehicle`'s lease as the station on `api` sees it: (holder, term, held here).
fn lease(api: u16, vehicle: &str) -> Option<(String, u64, bool)> {
    json(api, "/api/federation")["leases"]
        .as_array()?
        .iter()
        .find(|l| l["vehicle_id"] == vehicle)
        .map(|l| {
            (
                l["holder"].as_str().unwrap_or_default().to_owned(),
                l["term"].as_u64().unwrap_or_default(),
                l["held_here"].as_bool().unwrap_or_default(),
            )
        })
}

fn held(holder: &str, term: u64, here: bool) -> Option<(String, u64, bool)> {
    Some((holder.to_owned(), term, here))
}

/// Orders `vehicle` to hold for ten minutes as task `task_id`: the HTTP status and body.
fn hold(api: u16, task_id: &str, vehicle: &str) -> (u16, String) {
    let body = format!(
        r#"{{"task_id": "{task_id}", "vehicle_id": "{vehicle}", "task": {{"kind": "hold", "duration_s": 600}}}}"#
    );
    http_post(api, "/api/tasks", &body).unwrap()
}

fn state(api: u16, task_id: &str) -> serde_json::Value {
    json(api, &format!("/api/tasks/{task_id}"))["state"].clone()
}

/// A station of site `name` on DDS `domain`, its API on `api`, a client of the test's
/// router at `connect`, with `extra` settings. Site identity is tested in `federation`:
/// here the router is the test's own, on loopback.
fn site_station(
    dir: &Path,
    name: &'static str,
    domain: u16,
    api: u16,
    connect: &str,
    extra: &[(&str, &str)],
) -> Proc {
    let mut env = vec![
        ("SHOAL_FEDERATION__SITE", name),
        ("SHOAL_FEDERATION__MODE", "client"),
        ("SHOAL_FEDERATION__LISTEN", "[]"),
        ("SHOAL_FEDERATION__CONNECT", connect),
        ("SHOAL_FEDERATION__INSECURE_OPEN", "true"),
        ("SHOAL_FEDERATION__LEASE__SETTLE_MS", "2000"),
    ];
    env.extend_from_slice(extra);
    federated_station(dir, name, domain, api, &format!("{name}.db"), &env)
}

#[test]
fn a_vehicle_obeys_only_the_newest_lease_across_a_partition_and_its_heal() {
    let dir = tempfile::tempdir().unwrap();
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (ship_api, shore_api, zenoh) = (free_port(), free_port(), free_port());
    let link = router(&rt, zenoh);
    let connect = format!(r#"["tcp/127.0.0.1:{zenoh}"]"#);
    let fast = [
        ("SHOAL_FEDERATION__LINK_LEASE_MS", "2000"),
        ("SHOAL_FEDERATION__LEASE__FAILOVER_TIMEOUT_MS", "1000"),
    ];
    let ship_env = [
        ("SHOAL_FEDERATION__REMOTE_SITES", r#"["shore"]"#),
        ("SHOAL_FEDERATION__LEASE__STANDBY", "shore"),
    ];
    let shore_env = [
        ("SHOAL_FEDERATION__REMOTE_SITES", r#"["ship"]"#),
        ("SHOAL_FEDERATION__LEASE__HOME", "false"),
    ];
    let mut ship = site_station(
        dir.path(),
        "ship",
        DOMAIN,
        ship_api,
        &connect,
        &[&fast[..], &ship_env[..]].concat(),
    );
    let mut shore = site_station(
        dir.path(),
        "shore",
        DOMAIN,
        shore_api,
        &connect,
        &[&fast[..], &shore_env[..]].concat(),
    );
    let _vehicle = auv(dir.path(), "auv-l1", DOMAIN);
    ship.wait_for(60, "the ship's API", || {
        http_get(ship_api, "/api/fleet").is_ok()
    });
    ship.wait_for(60, "the ship to claim auv-l1", || {
        lease(ship_api, "auv-l1") == held("ship", 1, true)
    });
    shore.wait_for(60, "the shore to learn the ship's lease", || {
        lease(shore_api, "auv-l1") == held("ship", 1, false)
    });
    let (code, body) = hold(ship_api, "s-1", "auv-l1");
    assert_eq!(code, 202, "{body}");
    ship.wait_for(30, "the ship's first task running", || {
        state(ship_api, "s-1") == "running"
    });
    let (code, body) = hold(shore_api, "h-0", "auv-l1");
    assert_eq!(code, 409, "the shore does not hold the lease: {body}");

    // The link is cut. The shore, the ship's standby, takes the lease over; the ship,
    // alone, still believes it holds it.
    rt.block_on(async { link.close().await }).unwrap();
    drop(link);
    shore.wait_for(30, "the shore to take auv-l1's lease over", || {
        lease(shore_api, "auv-l1") == held("shore", 2, true)
    });
    assert_eq!(lease(ship_api, "auv-l1"), held("ship", 1, true));
    // Taking the lease, the shore announces it to the vehicle (a state request under it).
    shore.wait_for(30, "the shore's lease announced to auv-l1", || {
        state(shore_api, "lease-auv-l1-2") == "done"
    });

    // Both stations now command the vehicle; it obeys the newer lease only, from the
    // announcement on.
    let (code, body) = hold(ship_api, "s-2", "auv-l1");
    assert_eq!(code, 202, "the ship cannot know yet: {body}");
    ship.wait_for(30, "the vehicle to refuse the ship's task", || {
        state(ship_api, "s-2") == "failed"
    });
    let refused = json(ship_api, "/api/tasks/s-2");
    let message = refused["message"].as_str().unwrap_or_default();
    assert!(
        message.contains("issued under command lease term 1 of site ship")
            && message.contains("obeys site shore (command lease term 2)"),
        "{refused}"
    );
    let (code, body) = hold(shore_api, "h-1", "auv-l1");
    assert_eq!(code, 202, "{body}");
    // Accepted: the vehicle queues it behind the ship's first task.
    shore.wait_for(30, "the vehicle to accept the shore's task", || {
        state(shore_api, "h-1") == "accepted"
    });
    let sent = json(shore_api, "/api/tasks/h-1");
    assert_eq!(
        (
            &sent["assignment"]["lease_term"],
            &sent["assignment"]["lease_holder"]
        ),
        (&serde_json::json!(2), &serde_json::json!("shore")),
        "{sent}"
    );
    std::thread::sleep(Duration::from_secs(2));
    assert_eq!(
        state(shore_api, "h-1"),
        "accepted",
        "the shore's task stands"
    );

    // The link heals: the ship learns the shore's lease and no longer commands.
    let _link = router(&rt, zenoh);
    ship.wait_for(60, "the ship to learn the shore's lease", || {
        lease(ship_api, "auv-l1") == held("shore", 2, false)
    });
    let (code, body) = hold(ship_api, "s-3", "auv-l1");
    assert_eq!(code, 409, "{body}");
    assert!(body.contains("commanded by site shore"), "{body}");
}

/// A shore with no path of its own to the ship's vehicle (DDS domains 214 ship, 215 shore)
/// commands it through the ship's station while it holds the lease, and follows the task
/// through the ship's transitions; without the lease it cannot.
#[test]
fn the_shore_commands_the_ships_vehicle_through_the_ship_while_it_holds_the_lease() {
    let dir = tempfile::tempdir().unwrap();
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (ship_api, shore_api, zenoh) = (free_port(), free_port(), free_port());
    let _link = router(&rt, zenoh);
    let connect = format!(r#"["tcp/127.0.0.1:{zenoh}"]"#);
    let remote = |site| [("SHOAL_FEDERATION__REMOTE_SITES", site)];
    let mut ship = site_station(
        dir.path(),
        "ship",
        214,
        ship_api,
        &connect,
        &remote(r#"["shore"]"#),
    );
    let mut shore = site_station(
        dir.path(),
        "shore",
        215,
        shore_api,
        &connect,
        &remote(r#"["ship"]"#),
    );
    let _vehicle = auv(dir.path(), "auv-r1", 214);
    ship.wait_for(60, "the ship to claim auv-r1", || {
        lease(ship_api, "auv-r1") == held("ship", 1, true)
    });
    shore.wait_for(60, "the shore to learn the ship's lease", || {
        lease(shore_api, "auv-r1") == held("ship", 1, false)
    });
    let (code, body) = hold(shore_api, "r-0", "auv-r1");
    assert_eq!(code, 409, "{body}");
    assert!(body.contains("commanded by site ship"), "{body}");

    let to_shore = r#"{"to": "shore"}"#;
    let (code, body) = http_post(ship_api, "/api/federation/leases/auv-r1", to_shore).unwrap();
    assert_eq!(code, 200, "{body}");
    shore.wait_for(30, "the shore to hold auv-r1's lease", || {
        lease(shore_api, "auv-r1") == held("shore", 2, true)
    });
    // The shore announces its lease to the vehicle through the ship.
    shore.wait_for(
        30,
        "the shore's lease announced to auv-r1 through the ship",
        || state(shore_api, "lease-auv-r1-2") == "done",
    );
    // A mission of the shore's on the ship's vehicle: each task through the ship, the
    // next when the one before is done there (before the long hold below, which the
    // vehicle would finish first).
    let short = r#"{"vehicle_id": "auv-r1", "task": {"kind": "hold", "duration_s": 1}}"#;
    let mission = format!(r#"{{"mission_id": "rm", "tasks": [{short}, {short}]}}"#);
    let (code, body) = http_post(shore_api, "/api/missions?start=true", &mission).unwrap();
    assert_eq!(code, 201, "{body}");
    shore.wait_for(
        60,
        "the shore's mission through the ship to be done",
        || json(shore_api, "/api/missions/rm")["state"] == "done",
    );
    for task in ["rm-1", "rm-2"] {
        let there = json(ship_api, &format!("/api/tasks/{task}"));
        assert_eq!(there["state"], "done", "{there}");
        assert_eq!(there["assignment"]["lease_holder"], "shore", "{there}");
        assert_eq!(
            json(shore_api, &format!("/api/tasks/{task}"))["via_site"],
            "ship"
        );
    }

    let (code, body) = hold(shore_api, "r-1", "auv-r1");
    assert_eq!(code, 202, "{body}");
    ship.wait_for(
        30,
        "the ship to give the shore's task to its vehicle",
        || state(ship_api, "r-1") == "running",
    );
    let there = json(ship_api, "/api/tasks/r-1");
    assert_eq!(
        (
            &there["assignment"]["lease_term"],
            &there["assignment"]["lease_holder"]
        ),
        (&serde_json::json!(2), &serde_json::json!("shore")),
        "{there}"
    );
    shore.wait_for(30, "the shore to see its task running", || {
        state(shore_api, "r-1") == "running"
    });
    let here = json(shore_api, "/api/tasks/r-1");
    assert_eq!(here["via_site"], "ship", "{here}");
    // The ship no longer commands its own vehicle.
    let (code, body) = hold(ship_api, "s-1", "auv-r1");
    assert_eq!(code, 409, "{body}");

    // Handed back, the shore commands it no more.
    let to_ship = r#"{"to": "ship"}"#;
    let (code, body) = http_post(shore_api, "/api/federation/leases/auv-r1", to_ship).unwrap();
    assert_eq!(code, 200, "{body}");
    let (code, body) = hold(shore_api, "r-2", "auv-r1");
    assert_eq!(code, 409, "{body}");
    assert!(
        state(shore_api, "r-2").is_null(),
        "a refused task is not registered"
    );
}
