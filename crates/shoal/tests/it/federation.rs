//! Two stations federated over Zenoh through the binary: a ship's station (DDS domain 116)
//! with a vehicle, and a shore station (domain 117) that sees that vehicle, with its site,
//! through `GET /api/federation` without it joining its own fleet; both with site identity
//! (Zenoh user-password authentication and access control, the default).
//!
//! Site identity refusing (domains 119 shore, 125 ship, 126 impostor): a station claiming
//! site `ship` with the wrong password, and the genuine ship's credentials used to publish
//! under another site's keys, never reach the shore's picture while the ship's vehicle does.

use std::path::Path;
use std::time::{Duration, Instant};

use crate::common::{free_port, http_get};
use crate::recorder::Proc;

/// Writes a site's password file and its Zenoh dictionary (`<site>:<password>` a line)
/// in `dir`; the environment pointing a station at them.
fn identity(
    dir: &Path,
    site: &str,
    password: &str,
    dictionary: &[(&str, &str)],
) -> Vec<(String, String)> {
    let password_file = dir.join(format!("{site}-{password}.password"));
    let credentials_file = dir.join(format!("{site}-{password}.sites"));
    std::fs::write(&password_file, format!("{password}\n")).unwrap();
    let entries: String = dictionary
        .iter()
        .map(|(site, password)| format!("{site}:{password}\n"))
        .collect();
    std::fs::write(&credentials_file, entries).unwrap();
    vec![
        (
            "SHOAL_FEDERATION__PASSWORD_FILE".into(),
            password_file.display().to_string(),
        ),
        (
            "SHOAL_FEDERATION__CREDENTIALS_FILE".into(),
            credentials_file.display().to_string(),
        ),
    ]
}

/// A station process with no scenario, its API on `api`, its history in `db`, and `env`
/// in its environment.
fn station(
    dir: &Path,
    name: &'static str,
    domain: u16,
    api: u16,
    db: &str,
    env: &[(&str, &str)],
) -> Proc {
    let listen = format!("127.0.0.1:{api}");
    Proc::start_with(
        name,
        dir,
        domain,
        &[
            "--insecure",
            "station",
            "--scenario",
            "none",
            "--listen",
            &listen,
            "--db",
            db,
        ],
        env,
    )
}

/// [`station`] with the federation on; `env` configures the federation.
fn federated_station(
    dir: &Path,
    name: &'static str,
    domain: u16,
    api: u16,
    db: &str,
    env: &[(&str, &str)],
) -> Proc {
    let mut all = vec![("SHOAL_FEDERATION__ENABLED", "true")];
    all.extend_from_slice(env);
    station(dir, name, domain, api, db, &all)
}

fn refs(env: &[(String, String)]) -> Vec<(&str, &str)> {
    env.iter().map(|(k, v)| (k.as_str(), v.as_str())).collect()
}

fn json(port: u16, path: &str) -> serde_json::Value {
    http_get(port, path)
        .ok()
        .and_then(|b| serde_json::from_str(&b).ok())
        .unwrap_or(serde_json::Value::Null)
}

#[test]
fn a_shore_station_sees_the_ships_vehicle_over_the_federation() {
    let dir = tempfile::tempdir().unwrap();
    let (ship_api, shore_api, zenoh) = (free_port(), free_port(), free_port());
    let zenoh_ep = format!("[\"tcp/127.0.0.1:{zenoh}\"]");
    let station = |name: &'static str, domain: u16, api: u16, env: &[(&str, &str)]| {
        federated_station(dir.path(), name, domain, api, &format!("{name}.db"), env)
    };
    // The ship listens: it checks the shore's password against its dictionary. The shore
    // connects, with its password from the environment rather than a file.
    let ship_id = identity(dir.path(), "ship", "pw-ship-1", &[("shore", "pw-shore-1")]);
    let mut ship_env = refs(&ship_id);
    ship_env.extend_from_slice(&[
        ("SHOAL_FEDERATION__SITE", "ship"),
        ("SHOAL_FEDERATION__LISTEN", &zenoh_ep),
        ("SHOAL_FEDERATION__REMOTE_SITES", "[\"shore\"]"),
        ("SHOAL_FEDERATION__POSITIONS__MAX_RATE_HZ", "2.0"),
    ]);
    let mut ship = station("ship", 116, ship_api, &ship_env);
    let shore_id = identity(dir.path(), "shore", "unused", &[("ship", "pw-ship-1")]);
    let mut shore = station(
        "shore",
        117,
        shore_api,
        &[
            ("SHOAL_FEDERATION__SITE", "shore"),
            ("SHOAL_FEDERATION__LISTEN", "[]"),
            ("SHOAL_FEDERATION__CONNECT", &zenoh_ep),
            ("SHOAL_FEDERATION__REMOTE_SITES", "[\"ship\"]"),
            ("SHOAL_FEDERATION__PASSWORD", "pw-shore-1"),
            (&shore_id[1].0, &shore_id[1].1),
        ],
    );
    let vehicle = Proc::start_with(
        "auv-f1",
        dir.path(),
        116,
        &[
            "--insecure",
            "vehicle",
            "--sim",
            "auv",
            "--id",
            "auv-f1",
            "--lat",
            "63.44",
            "--lon",
            "10.36",
        ],
        &[],
    );
    let remote = || {
        json(shore_api, "/api/federation")["vehicles"]
            .as_array()
            .and_then(|vs| vs.iter().find(|v| v["vehicle_id"] == "auv-f1").cloned())
    };
    ship.wait_for(60, "the ship's API", || {
        http_get(ship_api, "/api/fleet").is_ok()
    });
    shore.wait_for(60, "auv-f1 at the shore through the federation", || {
        remote().is_some()
    });
    let v = remote().unwrap();
    assert_eq!(v["site"], "ship", "{v}");
    assert_eq!(v["kind"], "auv");
    assert!(
        (v["latitude_deg"].as_f64().unwrap() - 63.44).abs() < 0.01,
        "{v}"
    );
    assert!(v["age_ms"].as_i64().unwrap() < 30_000, "{v}");
    let doc = json(shore_api, "/api/federation");
    assert_eq!(doc["enabled"], true);
    assert_eq!(doc["site"], "shore");
    assert!(
        doc["counters"]["received_positions"].as_u64().unwrap() >= 1,
        "{doc}"
    );
    // The ship's vehicle is the shore's federated picture, not the shore's own fleet.
    let fleet = json(shore_api, "/api/fleet");
    assert!(
        fleet.as_array().is_some_and(|vs| vs.is_empty()),
        "{fleet}\n{}",
        shore.log()
    );
    // The ship sends; it has no remote vehicles of its own.
    let ship_doc = json(ship_api, "/api/federation");
    assert!(
        ship_doc["counters"]["sent_positions"].as_u64().unwrap() >= 1,
        "{ship_doc}\n{}",
        ship.log()
    );
    assert!(ship_doc["vehicles"].as_array().unwrap().is_empty());
    // Neither password shows in either log.
    for log in [ship.log(), shore.log()] {
        assert!(
            !log.contains("pw-ship-1") && !log.contains("pw-shore-1"),
            "{log}"
        );
    }
    drop(vehicle);
}

/// A position frame of `vehicle`, as a site publishes it.
fn position_frame(vehicle: &str) -> Vec<u8> {
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap();
    shoal_federation::wire::encode_position(&shoal_federation::VehiclePosition {
        vehicle_id: vehicle.into(),
        kind: shoal_model::VehicleKind::Auv,
        timestamp_ms: i64::try_from(now.as_millis()).unwrap(),
        latitude_deg: 63.5,
        longitude_deg: 10.4,
        depth_m: 5.0,
        heading_deg: 90.0,
        speed_mps: 1.0,
        battery_pct: 80.0,
    })
    .unwrap()
}

#[test]
fn an_impostor_and_a_forged_site_never_reach_the_shore() {
    let dir = tempfile::tempdir().unwrap();
    let (shore_api, ship_api, impostor_api, zenoh) =
        (free_port(), free_port(), free_port(), free_port());
    let zenoh_ep = format!("tcp/127.0.0.1:{zenoh}");
    let connect = format!("[\"{zenoh_ep}\"]");
    let station = |name: &'static str, domain: u16, api: u16, env: &[(&str, &str)]| {
        federated_station(dir.path(), name, domain, api, ":memory:", env)
    };
    // The shore listens and accepts two sites; the refused handshakes show in its log at
    // debug under Zenoh's target (docs/federation.md, "Site identity").
    let shore_id = identity(
        dir.path(),
        "shore",
        "pw-shore-2",
        &[("ship", "pw-ship-2"), ("shore2", "pw-shore2-2")],
    );
    let mut shore_env = refs(&shore_id);
    shore_env.extend_from_slice(&[
        ("SHOAL_FEDERATION__SITE", "shore"),
        ("SHOAL_FEDERATION__LISTEN", &connect),
        ("SHOAL_FEDERATION__REMOTE_SITES", "[\"ship\", \"shore2\"]"),
        (
            "RUST_LOG",
            "info,zenoh_transport::unicast::establishment::accept=debug",
        ),
    ]);
    let mut shore = station("shore", 119, shore_api, &shore_env);
    shore.wait_for(60, "the shore's API", || {
        http_get(shore_api, "/api/fleet").is_ok()
    });
    let ship_id = identity(dir.path(), "ship", "pw-ship-2", &[("shore", "pw-shore-2")]);
    let impostor_id = identity(dir.path(), "ship", "wrong-pw", &[("shore", "pw-shore-2")]);
    let ship_like = |id: &[(String, String)]| {
        let mut env = refs(id);
        env.extend_from_slice(&[
            ("SHOAL_FEDERATION__SITE", "ship"),
            ("SHOAL_FEDERATION__LISTEN", "[]"),
            ("SHOAL_FEDERATION__CONNECT", connect.as_str()),
            ("SHOAL_FEDERATION__REMOTE_SITES", "[\"shore\"]"),
            ("SHOAL_FEDERATION__POSITIONS__MAX_RATE_HZ", "2.0"),
        ]);
        env.into_iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect::<Vec<_>>()
    };
    let mut impostor = station(
        "impostor",
        126,
        impostor_api,
        &refs(&ship_like(&impostor_id)),
    );
    let _ship = station("ship", 125, ship_api, &refs(&ship_like(&ship_id)));
    let vehicle = |id: &'static str, domain: u16| {
        Proc::start_with(
            id,
            dir.path(),
            domain,
            &[
                "--insecure",
                "vehicle",
                "--sim",
                "auv",
                "--id",
                id,
                "--lat",
                "63.44",
                "--lon",
                "10.36",
            ],
            &[],
        )
    };
    let _genuine = vehicle("auv-g1", 125);
    let _forged = vehicle("auv-imp", 126);
    let remote_ids = || -> Vec<String> {
        json(shore_api, "/api/federation")["vehicles"]
            .as_array()
            .map(|vs| {
                vs.iter()
                    .map(|v| {
                        format!(
                            "{}/{}",
                            v["site"].as_str().unwrap_or(""),
                            v["vehicle_id"].as_str().unwrap_or("")
                        )
                    })
                    .collect()
            })
            .unwrap_or_default()
    };
    shore.wait_for(60, "the genuine ship's auv-g1 at the shore", || {
        remote_ids().contains(&"ship/auv-g1".to_string())
    });
    impostor.wait_for(30, "the impostor's vehicle at its own station", || {
        http_get(impostor_api, "/api/fleet").is_ok_and(|b| b.contains("auv-imp"))
    });

    // The genuine ship's credentials in a raw Zenoh session: what it publishes under its
    // own site arrives (so the session is authenticated and routed), what it publishes
    // under site shore2 (accepted by the shore, with its own password) is dropped by the
    // shore's access control before the federation sees it.
    let rt = tokio::runtime::Runtime::new().unwrap();
    let mut z = zenoh::Config::default();
    for (k, v) in [
        ("mode", r#""peer""#.to_string()),
        ("listen/endpoints", "[]".into()),
        ("connect/endpoints", connect.clone()),
        ("scouting/multicast/enabled", "false".into()),
        ("scouting/gossip/enabled", "false".into()),
        (
            "transport/auth/usrpwd",
            r#"{ user: "ship", password: "pw-ship-2" }"#.into(),
        ),
    ] {
        z.insert_json5(k, &v).unwrap();
    }
    let raw = rt.block_on(async { zenoh::open(z).await }).unwrap();
    let publish = || {
        rt.block_on(async {
            raw.put(
                "shoal/ship/vehicles/raw-1/position",
                position_frame("raw-1"),
            )
            .await
            .unwrap();
            raw.put(
                "shoal/shore2/vehicles/forged-1/position",
                position_frame("forged-1"),
            )
            .await
            .unwrap();
        });
        true
    };
    shore.wait_for(30, "raw-1 from the raw session as site ship", || {
        publish() && remote_ids().contains(&"ship/raw-1".to_string())
    });

    // A bounded wait, publishing the forgery all along, in which neither the impostor's
    // vehicle nor the forged site's ever shows.
    let until = Instant::now() + Duration::from_secs(10);
    while Instant::now() < until {
        publish();
        let ids = remote_ids();
        assert!(
            ids.iter()
                .all(|id| id != "ship/auv-imp" && !id.starts_with("shore2/")),
            "{ids:?}\n{}",
            shore.log()
        );
        std::thread::sleep(Duration::from_millis(250));
    }
    rt.block_on(async { raw.close().await }).unwrap();
    let doc = json(shore_api, "/api/federation");
    // Zenoh dropped the forgery itself: the federation never saw it to refuse it.
    for reason in [
        "refused_unknown_site",
        "refused_site_mismatch",
        "refused_bad_key",
    ] {
        assert_eq!(doc["counters"][reason].as_u64().unwrap_or(0), 0, "{doc}");
    }
    let log = shore.log();
    assert!(
        log.contains("Invalid password"),
        "the impostor's refused handshake is not in the shore's log:\n{log}"
    );
    assert!(
        !log.contains("pw-shore-2") && !log.contains("wrong-pw"),
        "{log}"
    );
}

#[test]
fn a_station_without_federation_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let api = free_port();
    let mut alone = station(dir.path(), "alone", 118, api, ":memory:", &[]);
    alone.wait_for(60, "the station's API", || {
        http_get(api, "/api/fleet").is_ok()
    });
    let doc = json(api, "/api/federation");
    assert_eq!(doc["enabled"], false, "{doc}");
    assert!(doc["vehicles"].as_array().unwrap().is_empty());
}
