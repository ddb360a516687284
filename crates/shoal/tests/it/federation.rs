//! Two stations federated over Zenoh through the binary: a ship's station (DDS domain 116)
//! with a vehicle, and a shore station (domain 117) that sees that vehicle, with its site,
//! through `GET /api/federation` without it joining its own fleet; both with site identity
//! (Zenoh user-password authentication and access control, the default).
//!
//! Site identity refusing (domains 119 shore, 125 ship, 126 impostor): a station claiming
//! site `ship` with the wrong password, and the genuine ship's credentials used to publish
//! under another site's keys, never reach the shore's picture while the ship's vehicle does.
//!
//! Mutual TLS (domains 127 ship, 128 shore, 129 rogue; 130 a false shore, 132 the ship
//! facing it):
//! each site's certificate from its own station CA (`shoal keys site-cert`), the CAs
//! exchanged; the ship's vehicle reaches the shore, a station claiming `ship` with a
//! certificate from another CA is refused, the genuine ship's certificate publishing under
//! another site's keys is dropped; a connecting ship refuses a listener whose certificate
//! its trusted CAs did not issue, and drops what the genuine shore's certificate publishes
//! under another site's keys.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use crate::common::{free_port, http_get, http_post};
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
pub(crate) fn station(
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
pub(crate) fn federated_station(
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

/// A bare Zenoh peer (no scouting) listening on and connecting to the given endpoints (JSON
/// arrays), with `extra` settings: a site's genuine credentials, sending what no site would.
fn raw_zenoh(
    rt: &tokio::runtime::Runtime,
    listen: &str,
    connect: &str,
    extra: &[(&str, String)],
) -> zenoh::Session {
    let mut z = zenoh::Config::default();
    for (k, v) in [
        ("mode", r#""peer""#),
        ("listen/endpoints", listen),
        ("connect/endpoints", connect),
        ("scouting/multicast/enabled", "false"),
        ("scouting/gossip/enabled", "false"),
    ] {
        z.insert_json5(k, v).unwrap();
    }
    for (k, v) in extra {
        z.insert_json5(k, v).unwrap();
    }
    rt.block_on(async { zenoh::open(z).await }).unwrap()
}

/// Zenoh's mutual-TLS settings for a raw session that `role`s ("listen" or "connect") with
/// `site`'s certificate, trusting `ca`.
fn mtls(role: &str, ca: &Path, site: &SiteTls) -> Vec<(&'static str, String)> {
    let quoted = |p: &Path| format!("{:?}", p.display().to_string());
    let (cert, key) = match role {
        "listen" => (
            "transport/link/tls/listen_certificate",
            "transport/link/tls/listen_private_key",
        ),
        _ => (
            "transport/link/tls/connect_certificate",
            "transport/link/tls/connect_private_key",
        ),
    };
    vec![
        ("transport/link/tls/root_ca_certificate", quoted(ca)),
        (cert, quoted(&site.cert)),
        (key, quoted(&site.key)),
        ("transport/link/tls/enable_mtls", "true".into()),
    ]
}

fn refs(env: &[(String, String)]) -> Vec<(&str, &str)> {
    env.iter().map(|(k, v)| (k.as_str(), v.as_str())).collect()
}

pub(crate) fn json(port: u16, path: &str) -> serde_json::Value {
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
        ("SHOAL_FEDERATION__ENVIRONMENT__MODE", "aggregated"),
        ("SHOAL_FEDERATION__ENVIRONMENT__WINDOW_S", "5"),
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

    // The ship's environment data, one summary per property and 5 s window (its AUV's CTD
    // samples every 10 s).
    let summaries = || {
        json(shore_api, "/api/federation")["environment"]
            .as_array()
            .map(|es| {
                es.iter()
                    .filter(|e| e["site"] == "ship" && e["vehicle_id"] == "auv-f1")
                    .cloned()
                    .collect::<Vec<_>>()
            })
            .unwrap_or_default()
    };
    shore.wait_for(60, "auv-f1's environment summaries at the shore", || {
        !summaries().is_empty()
    });
    for e in summaries() {
        let (min, mean, max) = (e["min"].as_f64(), e["mean"].as_f64(), e["max"].as_f64());
        assert!(e["count"].as_u64() >= Some(1), "{e}");
        assert!(min <= mean && mean <= max, "{e}");
    }

    // The command lease: the ship, auv-f1's home, claims it; the shore learns who holds it.
    let lease = |api: u16| {
        json(api, "/api/federation")["leases"]
            .as_array()
            .and_then(|ls| ls.iter().find(|l| l["vehicle_id"] == "auv-f1").cloned())
            .map(|l| {
                (
                    l["holder"].clone(),
                    l["term"].clone(),
                    l["held_here"].clone(),
                )
            })
    };
    let held = |holder: &str, term: u64, here: bool| {
        Some((
            serde_json::json!(holder),
            serde_json::json!(term),
            serde_json::json!(here),
        ))
    };
    shore.wait_for(60, "the ship's lease of auv-f1 at the shore", || {
        lease(shore_api) == held("ship", 1, false)
    });
    assert_eq!(lease(ship_api), held("ship", 1, true));
    let hold = r#"{"vehicle_id": "auv-f1", "task": {"kind": "hold", "duration_s": 30}}"#;
    let (code, body) = http_post(ship_api, "/api/tasks", hold).unwrap();
    assert_eq!(code, 202, "the holder commands: {body}");
    // The shore cannot hand over what it does not hold; the ship hands it to the shore.
    let to = |site: &str| format!(r#"{{"to": "{site}"}}"#);
    let (code, body) = http_post(shore_api, "/api/federation/leases/auv-f1", &to("shore")).unwrap();
    assert_eq!(code, 409, "{body}");
    let (code, body) =
        http_post(ship_api, "/api/federation/leases/auv-f1", &to("nowhere")).unwrap();
    assert_eq!(code, 400, "{body}");
    let (code, body) = http_post(ship_api, "/api/federation/leases/auv-f1", &to("shore")).unwrap();
    assert_eq!(code, 200, "{body}");
    assert!(body.contains(r#""term":2"#), "{body}");
    // The ship no longer commands auv-f1, aborts included.
    let (code, body) = http_post(ship_api, "/api/tasks", hold).unwrap();
    assert_eq!(code, 409, "{body}");
    assert!(body.contains("commanded by site shore"), "{body}");
    shore.wait_for(30, "the shore to hold auv-f1's lease", || {
        lease(shore_api) == held("shore", 2, true)
    });
    // The shore hands it back, and the ship commands again.
    let (code, body) = http_post(shore_api, "/api/federation/leases/auv-f1", &to("ship")).unwrap();
    assert_eq!(code, 200, "{body}");
    ship.wait_for(30, "the ship to hold auv-f1's lease again", || {
        lease(ship_api) == held("ship", 3, true)
    });
    let (code, body) = http_post(ship_api, "/api/tasks", hold).unwrap();
    assert_eq!(code, 202, "{body}");

    // Neither password shows in either log; both say their links are not encrypted.
    for log in [ship.log(), shore.log()] {
        assert!(
            !log.contains("pw-ship-1") && !log.contains("pw-shore-1"),
            "{log}"
        );
        assert!(log.contains("FEDERATION NOT ENCRYPTED"), "{log}");
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
    let raw = raw_zenoh(
        &rt,
        "[]",
        &connect,
        &[(
            "transport/auth/usrpwd",
            r#"{ user: "ship", password: "pw-ship-2" }"#.into(),
        )],
    );
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

/// A site's TLS files: its certificate and key, and its CA's certificate (what the
/// other sites trust).
struct SiteTls {
    cert: PathBuf,
    key: PathBuf,
    ca: PathBuf,
}

/// A new station key store in `dir/<store>` (`shoal keys init`) and `site`'s certificate
/// from it (`shoal keys site-cert`), valid for 127.0.0.1.
fn site_tls(dir: &Path, store: &str, site: &str) -> SiteTls {
    let keys = dir.join(store);
    let out = dir.join(format!("{store}-federation"));
    let run = |args: &[&str]| {
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_shoal"))
            .arg("keys")
            .arg("--dir")
            .arg(&keys)
            .args(args)
            .current_dir(dir)
            .output()
            .unwrap();
        assert!(o.status.success(), "shoal keys {args:?}: {o:?}");
        String::from_utf8_lossy(&o.stdout).into_owned()
    };
    run(&["init", "--station", store]);
    let out_arg = out.display().to_string();
    let said = run(&["site-cert", site, "--name", "127.0.0.1", "--out", &out_arg]);
    assert!(said.contains(&format!("{site}-ca.crt")), "{said}");
    SiteTls {
        cert: out.join(format!("{site}.crt")),
        key: out.join(format!("{site}.key")),
        ca: out.join(format!("{site}-ca.crt")),
    }
}

/// The environment turning on `[federation.tls]` with `tls`, trusting the CAs in
/// `trusted` (one PEM bundle written next to them).
fn tls_env(dir: &Path, name: &str, tls: &SiteTls, trusted: &[&Path]) -> Vec<(String, String)> {
    let bundle = dir.join(format!("{name}-trusted-cas.pem"));
    let pem: String = trusted
        .iter()
        .map(|p| std::fs::read_to_string(p).unwrap())
        .collect();
    std::fs::write(&bundle, pem).unwrap();
    let path = |p: &Path| p.display().to_string();
    vec![
        ("SHOAL_FEDERATION__TLS__ENABLED".into(), "true".into()),
        ("SHOAL_FEDERATION__TLS__CERTIFICATE".into(), path(&tls.cert)),
        ("SHOAL_FEDERATION__TLS__PRIVATE_KEY".into(), path(&tls.key)),
        ("SHOAL_FEDERATION__TLS__TRUSTED_CAS".into(), path(&bundle)),
    ]
}

/// `site/vehicle` of every remote vehicle in a station's federated picture.
fn remote_vehicles(api: u16) -> Vec<String> {
    json(api, "/api/federation")["vehicles"]
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
}

/// A simulated AUV on `domain`.
pub(crate) fn auv(dir: &Path, id: &'static str, domain: u16) -> Proc {
    Proc::start_with(
        id,
        dir,
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
}

#[test]
fn two_stations_federate_over_mutual_tls_and_refuse_a_foreign_ca_and_a_forged_site() {
    let dir = tempfile::tempdir().unwrap();
    let (ship_api, shore_api, rogue_api, zenoh) =
        (free_port(), free_port(), free_port(), free_port());
    let endpoint = format!("[\"tls/127.0.0.1:{zenoh}\"]");
    // Each site's certificate from its own station's CA; the CAs exchanged. The rogue's
    // CA is nobody's: it trusts the shore's, but the shore does not trust it.
    let shore_tls = site_tls(dir.path(), "shore-keys", "shore");
    let ship_tls = site_tls(dir.path(), "ship-keys", "ship");
    let rogue_tls = site_tls(dir.path(), "rogue-keys", "ship");
    let station = |name: &'static str, domain: u16, api: u16, env: &[(String, String)]| {
        federated_station(dir.path(), name, domain, api, ":memory:", &refs(env))
    };
    let with = |mut env: Vec<(String, String)>, more: &[(&str, &str)]| {
        env.extend(
            more.iter()
                .map(|(k, v)| ((*k).to_string(), (*v).to_string())),
        );
        env
    };

    // The shore listens and accepts ship and ship2 (a site that is not running: the
    // forgery below claims it). The refused handshakes show in its log at Zenoh's
    // TLS link target.
    let shore_env = with(
        tls_env(dir.path(), "shore", &shore_tls, &[&ship_tls.ca]),
        &[
            ("SHOAL_FEDERATION__SITE", "shore"),
            ("SHOAL_FEDERATION__LISTEN", &endpoint),
            ("SHOAL_FEDERATION__REMOTE_SITES", "[\"ship\", \"ship2\"]"),
            (
                "RUST_LOG",
                "info,zenoh_link_tls=debug,zenoh::net::runtime::orchestrator=debug",
            ),
        ],
    );
    let mut shore = station("shore", 128, shore_api, &shore_env);
    shore.wait_for(60, "the shore's API", || {
        http_get(shore_api, "/api/fleet").is_ok()
    });
    let ship_like = |tls: &SiteTls, name: &str| {
        with(
            tls_env(dir.path(), name, tls, &[&shore_tls.ca]),
            &[
                ("SHOAL_FEDERATION__SITE", "ship"),
                ("SHOAL_FEDERATION__LISTEN", "[]"),
                ("SHOAL_FEDERATION__CONNECT", &endpoint),
                ("SHOAL_FEDERATION__REMOTE_SITES", "[\"shore\"]"),
                ("SHOAL_FEDERATION__POSITIONS__MAX_RATE_HZ", "2.0"),
            ],
        )
    };
    let mut rogue = station("rogue", 129, rogue_api, &ship_like(&rogue_tls, "rogue"));
    let mut ship = station("ship", 127, ship_api, &ship_like(&ship_tls, "ship"));
    let _genuine = auv(dir.path(), "auv-t1", 127);
    let _rogue_auv = auv(dir.path(), "auv-rogue", 129);

    shore.wait_for(60, "the ship's auv-t1 at the shore over TLS", || {
        remote_vehicles(shore_api).contains(&"ship/auv-t1".to_string())
    });
    rogue.wait_for(30, "the rogue's vehicle at its own station", || {
        http_get(rogue_api, "/api/fleet").is_ok_and(|b| b.contains("auv-rogue"))
    });
    // The shore is online at the ship: the link is up both ways.
    ship.wait_for(30, "the shore online at the ship", || {
        json(ship_api, "/api/federation")["sites"]
            .as_array()
            .is_some_and(|s| {
                s.iter()
                    .any(|s| s["site"] == "shore" && s["online"] == true)
            })
    });
    // The ship's claim of auv-t1 reaches the shore signed end to end, checked against the
    // ship's certificate, which the shore asked the ship for.
    shore.wait_for(60, "the ship's signed lease of auv-t1 at the shore", || {
        let doc = json(shore_api, "/api/federation");
        let claimed = doc["leases"].as_array().is_some_and(|ls| {
            ls.iter()
                .any(|l| l["vehicle_id"] == "auv-t1" && l["holder"] == "ship")
        });
        claimed && doc["counters"]["remote_identities"].as_u64() >= Some(1)
    });
    let doc = json(shore_api, "/api/federation");
    let signature_refusals: Vec<_> = doc["counters"]
        .as_object()
        .unwrap()
        .keys()
        .filter(|k| k.starts_with("refused_signature"))
        .collect();
    assert!(signature_refusals.is_empty(), "{doc}");
    for (p, who) in [(&ship, "ship"), (&shore, "shore")] {
        let log = p.log();
        assert!(log.contains("tls"), "{who} does not say TLS is on:\n{log}");
        assert!(!log.contains("NOT ENCRYPTED"), "{who}:\n{log}");
    }

    // The genuine ship's certificate in a raw Zenoh session: what it publishes under its
    // own site arrives, what it publishes under ship2 (a site the shore accepts) is
    // dropped by the shore's access control (by the certificate's common name).
    let rt = tokio::runtime::Runtime::new().unwrap();
    let raw = raw_zenoh(
        &rt,
        "[]",
        &endpoint,
        &mtls("connect", &shore_tls.ca, &ship_tls),
    );
    let publish = || {
        rt.block_on(async {
            raw.put(
                "shoal/ship/vehicles/raw-t1/position",
                position_frame("raw-t1"),
            )
            .await
            .unwrap();
            raw.put(
                "shoal/ship2/vehicles/forged-t1/position",
                position_frame("forged-t1"),
            )
            .await
            .unwrap();
        });
        true
    };
    shore.wait_for(
        30,
        "raw-t1 from the raw session with ship's certificate",
        || publish() && remote_vehicles(shore_api).contains(&"ship/raw-t1".to_string()),
    );
    // A bounded wait, publishing the forgery all along, in which neither the rogue's
    // vehicle nor anything of ship2 ever shows.
    let until = Instant::now() + Duration::from_secs(10);
    while Instant::now() < until {
        publish();
        let ids = remote_vehicles(shore_api);
        assert!(
            ids.iter()
                .all(|id| id != "ship/auv-rogue" && !id.starts_with("ship2/")),
            "{ids:?}\n{}",
            shore.log()
        );
        std::thread::sleep(Duration::from_millis(250));
    }
    rt.block_on(async { raw.close().await }).unwrap();
    let doc = json(shore_api, "/api/federation");
    for reason in ["refused_unknown_site", "refused_site_mismatch"] {
        assert_eq!(doc["counters"][reason].as_u64().unwrap_or(0), 0, "{doc}");
    }
    // The rogue's handshake was refused by the shore's rustls (its CA is not trusted),
    // and the rogue never saw the shore.
    let log = shore.log();
    assert!(
        log.contains("UnknownIssuer") || log.contains("unknown issuer"),
        "the rogue's refused handshake is not in the shore's log:\n{log}"
    );
    let rogue_doc = json(rogue_api, "/api/federation");
    assert!(
        rogue_doc["sites"]
            .as_array()
            .is_some_and(|s| s.iter().all(|s| s["online"] != true)),
        "{rogue_doc}"
    );
}

#[test]
fn a_connecting_ship_refuses_a_false_shore_and_polices_the_genuine_one() {
    let dir = tempfile::tempdir().unwrap();
    let (ship_api, false_api, false_port, genuine_port) =
        (free_port(), free_port(), free_port(), free_port());
    let false_ep = format!("tls/127.0.0.1:{false_port}");
    let genuine_ep = format!("tls/127.0.0.1:{genuine_port}");
    let shore_tls = site_tls(dir.path(), "shore-keys", "shore");
    let false_tls = site_tls(dir.path(), "false-keys", "shore");
    let ship_tls = site_tls(dir.path(), "ship-keys", "ship");
    // A false shore that trusts the ship (so only the ship's check can refuse the link),
    // with a certificate for site `shore` from a CA the ship does not trust.
    let false_listen = format!("[\"{false_ep}\"]");
    let mut false_env = tls_env(dir.path(), "false", &false_tls, &[&ship_tls.ca]);
    false_env.extend(
        [
            ("SHOAL_FEDERATION__SITE", "shore"),
            ("SHOAL_FEDERATION__LISTEN", false_listen.as_str()),
            ("SHOAL_FEDERATION__REMOTE_SITES", "[\"ship\"]"),
        ]
        .map(|(k, v)| (k.to_string(), v.to_string())),
    );
    let mut false_shore = federated_station(
        dir.path(),
        "false-shore",
        130,
        false_api,
        ":memory:",
        &refs(&false_env),
    );
    false_shore.wait_for(60, "the false shore's API", || {
        http_get(false_api, "/api/fleet").is_ok()
    });
    // The genuine shore's certificate in a raw Zenoh listener that publishes under its
    // own site and under ship9's (a site the ship accepts): the ship, which connects,
    // polices what it receives by the listener's common name too.
    let rt = tokio::runtime::Runtime::new().unwrap();
    let raw = raw_zenoh(
        &rt,
        &format!("[\"{genuine_ep}\"]"),
        "[]",
        &mtls("listen", &ship_tls.ca, &shore_tls),
    );

    let connect = format!("[\"{false_ep}\", \"{genuine_ep}\"]");
    let mut ship_env = tls_env(dir.path(), "ship", &ship_tls, &[&shore_tls.ca]);
    ship_env.extend(
        [
            ("SHOAL_FEDERATION__SITE", "ship"),
            ("SHOAL_FEDERATION__LISTEN", "[]"),
            ("SHOAL_FEDERATION__CONNECT", connect.as_str()),
            ("SHOAL_FEDERATION__REMOTE_SITES", "[\"shore\", \"ship9\"]"),
            // A connecting site logs each refused attempt here (docs/federation.md).
            ("RUST_LOG", "info,zenoh::net::runtime::orchestrator=debug"),
        ]
        .map(|(k, v)| (k.to_string(), v.to_string())),
    );
    let mut ship = federated_station(
        dir.path(),
        "ship",
        132,
        ship_api,
        ":memory:",
        &refs(&ship_env),
    );
    let publish = || {
        rt.block_on(async {
            raw.put(
                "shoal/shore/vehicles/raw-s1/position",
                position_frame("raw-s1"),
            )
            .await
            .unwrap();
            raw.put(
                "shoal/ship9/vehicles/forged-s1/position",
                position_frame("forged-s1"),
            )
            .await
            .unwrap();
        });
        true
    };
    ship.wait_for(
        60,
        "raw-s1 from the genuine shore's certificate at the ship",
        || publish() && remote_vehicles(ship_api).contains(&"shore/raw-s1".to_string()),
    );
    let ship_log = dir.path().join("ship.log");
    ship.wait_for(
        30,
        "the ship's refusal of the false shore in its log",
        || {
            let log = std::fs::read_to_string(&ship_log).unwrap_or_default();
            log.contains("UnknownIssuer")
        },
    );
    // A bounded wait in which nothing of ship9 reaches the ship, and the false shore
    // never has the ship online.
    let until = Instant::now() + Duration::from_secs(5);
    while Instant::now() < until {
        publish();
        let ids = remote_vehicles(ship_api);
        assert!(
            ids.iter().all(|id| !id.starts_with("ship9/")),
            "{ids:?}\n{}",
            ship.log()
        );
        let doc = json(false_api, "/api/federation");
        assert!(
            doc["sites"]
                .as_array()
                .is_some_and(|s| s.iter().all(|s| s["online"] != true)),
            "{doc}"
        );
        std::thread::sleep(Duration::from_millis(250));
    }
    rt.block_on(async { raw.close().await }).unwrap();
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
