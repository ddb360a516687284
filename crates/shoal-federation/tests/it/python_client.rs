//! An independent client: PyPI `eclipse-zenoh` (the same 1.x protocol) running
//! `tests/federation/shore_client.py`, which decodes the federation's payloads from
//! `docs/federation.md` alone, against a Rust site.
//!
//! Skipped, with the reason printed, when `<repo>/.venv/bin/python` is missing or cannot
//! import `zenoh` (scripts/install-test-deps.sh installs it), unless
//! `SHOAL_INTEROP_REQUIRED=1`, when the test fails instead.

use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::Duration;

use serde_json::Value;
use shoal_federation::{EnvironmentMode, Federation};
use shoal_model::{EnvironmentObservation, TaskState, now_ms};
use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::process::Command;

use crate::common::*;

/// The venv's Python if it can import zenoh; else why not.
fn python() -> Result<PathBuf, String> {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let python = repo.join(".venv/bin/python");
    if !python.exists() {
        return Err(format!(
            "{} not found: run scripts/install-test-deps.sh",
            python.display()
        ));
    }
    let ok = std::process::Command::new(&python)
        .args(["-c", "import zenoh"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .map_err(|e| format!("cannot run {}: {e}", python.display()))?;
    if !ok.success() {
        return Err(
            "PyPI eclipse-zenoh is not installed in .venv: run scripts/install-test-deps.sh".into(),
        );
    }
    Ok(python)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_python_zenoh_client_decodes_the_federation_from_the_doc() {
    let python = match python() {
        Ok(p) => p,
        Err(reason) => {
            assert!(
                std::env::var("SHOAL_INTEROP_REQUIRED").as_deref() != Ok("1"),
                "the Python zenoh client is required (SHOAL_INTEROP_REQUIRED=1): {reason}"
            );
            eprintln!("SKIPPED: the Python zenoh client cannot run: {reason}");
            return;
        }
    };
    let port = free_port();
    let mut config = site("ship", Some(port), &[], &["shore"]);
    config.positions.max_rate_hz = 5.0;
    config.environment.mode = EnvironmentMode::Aggregated;
    config.environment.window_s = 5;
    let ship = Federation::start(config).await.unwrap();

    // Published before the client exists: it gets them from the catch-up queryable.
    let sent_alarm = alarm("a1");
    let sent_task = transition("t-7", TaskState::Running);
    ship.push_alarm(&sent_alarm).unwrap();
    ship.push_transition(&sent_task).unwrap();

    let script =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/federation/shore_client.py");
    let mut child = Command::new(python)
        .arg(script)
        .args([
            "--connect",
            &endpoint(port),
            "--site",
            "ship",
            "--environment",
            "1",
            "--timeout",
            "25",
        ])
        .env("PYTHONUNBUFFERED", "1")
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .kill_on_drop(true)
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();

    // Positions go on being pushed until the client has one: its subscription reaches
    // the site at a moment only it knows.
    let mut items: Vec<Value> = Vec::new();
    let mut lat = 43.0;
    let read = async {
        loop {
            tokio::select! {
                line = lines.next_line() => match line.unwrap() {
                    Some(l) => items.push(serde_json::from_str(&l).unwrap()),
                    None => break,
                },
                () = tokio::time::sleep(Duration::from_millis(200)) => {
                    lat += 1e-3;
                    ship.push_position(position("auv-1", lat)).unwrap();
                    ship.push_observation(&EnvironmentObservation {
                        vehicle_id: "auv-1".into(),
                        property: "sea_water_temperature".into(),
                        timestamp_ms: now_ms(),
                        value: 7.0 + (lat - 43.0) * 100.0,
                        unit: "Cel".into(),
                        latitude_deg: lat,
                        longitude_deg: 10.0,
                        depth_m: 12.0,
                    })
                    .unwrap();
                }
            }
        }
    };
    tokio::time::timeout(PATIENCE, read)
        .await
        .expect("the client to finish");
    let status = child.wait().await.unwrap();
    assert!(status.success(), "client failed: {items:?}");

    let of =
        |event: &str| -> Vec<&Value> { items.iter().filter(|i| i["event"] == event).collect() };
    assert!(of("refused").is_empty(), "{items:?}");
    let alarms = of("alarm");
    assert_eq!(alarms.len(), 1);
    let a = alarms[0];
    assert_eq!(a["site"], "ship");
    assert_eq!(a["epoch"], ship.epoch());
    assert_eq!(a["seq"], 1);
    assert_eq!(a["timestamp_ms"], sent_alarm.timestamp_ms);
    assert_eq!(a["severity"], "critical");
    assert_eq!(a["event_kind"], "fault");
    assert_eq!(a["event_id"], "a1");
    assert_eq!(a["vehicle_id"], "auv-1");
    assert_eq!(a["task_id"], "");
    assert_eq!(a["text"], sent_alarm.text);

    let tasks = of("task");
    assert_eq!(tasks.len(), 1);
    let t = tasks[0];
    assert_eq!(
        (&t["task_id"], &t["mission_id"], &t["vehicle_id"]),
        (&"t-7".into(), &"m-1".into(), &"auv-1".into())
    );
    assert_eq!(t["state"], "running");
    assert_eq!(t["timestamp_ms"], sent_task.timestamp_ms);

    // Each catch-up answer ended with its end frame: one of one kept on each stream.
    let mut ends: Vec<(String, u64, u64, u64)> = of("catchup_end")
        .iter()
        .map(|e| {
            assert_eq!(e["site"], "ship");
            let n = |k: &str| e[k].as_u64().unwrap();
            (
                e["stream"].as_str().unwrap().to_owned(),
                n("epoch"),
                n("oldest"),
                n("highest"),
            )
        })
        .collect();
    ends.sort();
    assert_eq!(
        ends,
        vec![
            ("alarms".into(), ship.epoch(), 1, 1),
            ("tasks".into(), ship.epoch(), 1, 1)
        ]
    );

    let positions = of("position");
    let p = positions[0];
    assert_eq!(
        (&p["site"], &p["vehicle"], &p["kind"]),
        (&"ship".into(), &"auv-1".into(), &"auv".into())
    );
    let expected = position("auv-1", 43.0);
    let near = |field: &str, value: f64, step: f64| {
        let got = p[field].as_f64().unwrap();
        assert!(
            (got - value).abs() <= step / 2.0 + 1e-9,
            "{field}: {got} vs {value}"
        );
    };
    assert!(p["latitude_deg"].as_f64().unwrap() > 43.0);
    near("longitude_deg", expected.longitude_deg, 1e-7);
    near("depth_m", expected.depth_m, 0.2);
    near("heading_deg", expected.heading_deg, 360.0 / 65536.0);
    near("speed_mps", expected.speed_mps, 0.01);
    near("battery_pct", expected.battery_pct, 0.5);

    // A window's summary, decoded from the doc's kind-6 table.
    let env = of("environment");
    let e = env[0];
    assert_eq!(
        (&e["site"], &e["vehicle"]),
        (&"ship".into(), &"auv-1".into())
    );
    let s = &e["properties"][0];
    assert_eq!(
        (&s["property"], &s["unit"]),
        (&"sea_water_temperature".into(), &"Cel".into())
    );
    let f = |k: &str| s[k].as_f64().unwrap();
    assert!(s["count"].as_u64().unwrap() >= 1, "{e}");
    assert!(f("min") <= f("mean") && f("mean") <= f("max"), "{e}");
    assert!(f("min") >= 7.0 && (f("depth_m") - 12.0).abs() <= 0.1, "{e}");

    ship.shutdown().await.unwrap();
}
