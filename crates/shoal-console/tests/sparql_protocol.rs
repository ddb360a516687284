//! The SPARQL 1.1 Protocol as an independent client sees it: `tests/sparql_client.py`
//! (rdflib) asks a served console for every result format, with Accept headers as
//! clients write them, and parses each answer by its Content-Type alone.
//!
//! Runs with the workspace's `.venv` Python (or `SHOAL_PYTHON`); skipped, saying why, when
//! that Python lacks rdflib, unless `SHOAL_INTEROP_REQUIRED=1` (the test command sets it).
//! The station opens a DDS participant: run inside a network namespace
//! (`scripts/netns-run.sh shoal-web -- cargo test -p shoal-console`). DDS domain 147.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::PathBuf;
use std::sync::Arc;

use shoal_dds::{DdsConfig, PubSub};
use shoal_history::{History, HistoryConfig};
use shoal_model::{LinkKind, StateVector, VehicleAnnouncement, VehicleKind, now_ms};
use shoal_station::{Station, StationConfig};
use tokio_util::sync::CancellationToken;

fn python() -> Option<PathBuf> {
    let py = std::env::var_os("SHOAL_PYTHON").map_or_else(
        || PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../.venv/bin/python"),
        PathBuf::from,
    );
    let ok = std::process::Command::new(&py)
        .args(["-c", "import rdflib"])
        .output()
        .is_ok_and(|o| o.status.success());
    if ok {
        return Some(py);
    }
    let why = format!(
        "{} cannot import rdflib (scripts/install-test-deps.sh installs it)",
        py.display()
    );
    assert!(
        std::env::var("SHOAL_INTEROP_REQUIRED").as_deref() != Ok("1"),
        "SHOAL_INTEROP_REQUIRED=1 but {why}"
    );
    eprintln!("SKIPPED sparql_protocol: {why}");
    None
}

fn announcement(id: &str) -> VehicleAnnouncement {
    VehicleAnnouncement {
        vehicle_id: id.into(),
        name: id.into(),
        kind: VehicleKind::Auv,
        vendor: "sparql test".into(),
        capabilities: vec!["goto".into(), "survey".into()],
        sensors: vec![],
        links: vec![LinkKind::Ip],
        max_speed_mps: 2.0,
        timestamp_ms: now_ms(),
    }
}

fn state(id: &str, battery_pct: f64) -> StateVector {
    StateVector {
        vehicle_id: id.into(),
        timestamp_ms: now_ms(),
        latitude_deg: 63.44,
        longitude_deg: 10.37,
        depth_m: 4.0,
        altitude_m: -1.0,
        speed_mps: 1.0,
        yaw_deg: 0.0,
        pitch_deg: 0.0,
        roll_deg: 0.0,
        battery_pct,
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_rdflib_client_gets_every_format_labelled_as_what_it_is() {
    let Some(py) = python() else { return };
    let dir = tempfile::tempdir().unwrap();
    let history = History::open(&HistoryConfig {
        path: dir.path().join("history.db"),
        ..HistoryConfig::default()
    })
    .unwrap();
    let dds = Arc::new(
        PubSub::new(&DdsConfig {
            domain_id: 147,
            ..DdsConfig::default()
        })
        .unwrap(),
    );
    let station = Station::new(
        StationConfig {
            summary_interval_s: 0.0,
            rules_path: dir.path().join("rules.json"),
            ..StationConfig::default()
        },
        dds,
        history,
    )
    .unwrap();
    let handle = station.handle();
    let shutdown = CancellationToken::new();
    let s = shutdown.clone();
    tokio::spawn(async move { station.run(s).await });
    for (id, battery) in [("auv-s1", 81.5), ("auv-s2", 47.0)] {
        handle.register_vehicle(announcement(id)).unwrap();
        handle.ingest_state(state(id, battery)).unwrap();
    }
    // The RDF mirror of a state is written coalesced, a moment after ingest: the client
    // compares every answer with its first, so the model must hold both batteries first.
    let both = "ASK { ?a shoal:batteryLevel ?x . ?b shoal:batteryLevel ?y . FILTER(?x = 81.5 && ?y = 47.0) }";
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
    loop {
        let limits = shoal_semantic::QueryLimits::default();
        if matches!(
            handle.sparql(both, &limits),
            Ok(shoal_semantic::QueryResult::Boolean(true))
        ) {
            break;
        }
        assert!(
            std::time::Instant::now() < deadline,
            "the model never mirrored both states: {:?}",
            handle.sparql(both, &limits)
        );
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
    }

    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let url = format!("http://{}", listener.local_addr().unwrap());
    let server = tokio::spawn(shoal_console::serve(
        listener,
        handle.clone(),
        shutdown.clone(),
    ));

    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/sparql_client.py");
    let out = tokio::process::Command::new(&py)
        .arg(&script)
        .args([url.as_str(), "auv-s1"])
        .output()
        .await
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    println!("{stdout}");
    shutdown.cancel();
    server.await.unwrap().unwrap();
    assert!(
        out.status.success(),
        "the rdflib client found failures:\n{stdout}\n{stderr}"
    );
    assert!(stdout.contains(" 0 failed"), "{stdout}");
}
