//! Two stations federated over Zenoh through the binary: a ship's station (DDS domain 116)
//! with a vehicle, and a shore station (domain 117) that sees that vehicle, with its site,
//! through `GET /api/federation` without it joining its own fleet.

use crate::common::{free_port, http_get};
use crate::recorder::Proc;

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
        let listen = format!("127.0.0.1:{api}");
        let db = format!("{name}.db");
        let mut all = vec![("SHOAL_FEDERATION__ENABLED", "true")];
        all.extend_from_slice(env);
        Proc::start_with(
            name,
            dir.path(),
            domain,
            &[
                "--insecure",
                "station",
                "--scenario",
                "none",
                "--listen",
                &listen,
                "--db",
                &db,
            ],
            &all,
        )
    };
    let mut ship = station(
        "ship",
        116,
        ship_api,
        &[
            ("SHOAL_FEDERATION__SITE", "ship"),
            ("SHOAL_FEDERATION__LISTEN", &zenoh_ep),
            ("SHOAL_FEDERATION__REMOTE_SITES", "[\"shore\"]"),
            ("SHOAL_FEDERATION__POSITIONS__MAX_RATE_HZ", "2.0"),
        ],
    );
    let mut shore = station(
        "shore",
        117,
        shore_api,
        &[
            ("SHOAL_FEDERATION__SITE", "shore"),
            ("SHOAL_FEDERATION__LISTEN", "[]"),
            ("SHOAL_FEDERATION__CONNECT", &zenoh_ep),
            ("SHOAL_FEDERATION__REMOTE_SITES", "[\"ship\"]"),
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
    drop(vehicle);
}

#[test]
fn a_station_without_federation_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let api = free_port();
    let listen = format!("127.0.0.1:{api}");
    let mut station = Proc::start_with(
        "alone",
        dir.path(),
        118,
        &[
            "--insecure",
            "station",
            "--scenario",
            "none",
            "--listen",
            &listen,
            "--db",
            ":memory:",
        ],
        &[],
    );
    station.wait_for(60, "the station's API", || {
        http_get(api, "/api/fleet").is_ok()
    });
    let doc = json(api, "/api/federation");
    assert_eq!(doc["enabled"], false, "{doc}");
    assert!(doc["vehicles"].as_array().unwrap().is_empty());
}
