//! The MAVLink adapter against an ArduSub-like vehicle written with PyPI `pymavlink`
//! (`tests/peers/ardusub_peer.py`), MAVLink 2 over UDP on 127.0.0.1.
//!
//! Telemetry becomes valid state vectors; a goto reaches the vehicle as DO_SET_MODE
//! GUIDED, DO_CHANGE_SPEED and SET_POSITION_TARGET_GLOBAL_INT, a survey as a mission
//! upload and AUTO; the acknowledgements and progress come back as task updates; the
//! vehicle's noise is counted; a vehicle that dies is reported lost, and picked up again,
//! with its streams requested anew, when it restarts on another port.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use std::time::Duration;

use common::{Peer, eventually, restart_peer, start_peer};
use shoal_model::{EventKind, GeoPoint, Severity, Task, TaskState, Validate, now_ms};
use shoal_proxy::mavlink::{MavlinkAdapter, MavlinkConfig};
use shoal_proxy::{TaskOrder, VehicleAdapter, VehicleEvent, VehicleOutput};

const SCRIPT: &str = "ardusub_peer.py";
const LAT: f64 = 47.397_742;
const LON: f64 = 8.545_594;

fn order(id: &str, task: Task) -> TaskOrder {
    TaskOrder {
        task_id: id.into(),
        mission_id: "m1".into(),
        issued_ms: now_ms(),
        task,
    }
}

/// Reads outputs until `task_id` ends; returns its states and the events seen meanwhile.
async fn run_to_end(
    adapter: &mut MavlinkAdapter,
    task_id: &str,
) -> (Vec<(TaskState, f64, String)>, Vec<VehicleEvent>) {
    let mut states = Vec::new();
    let mut events = Vec::new();
    loop {
        let out = tokio::time::timeout(Duration::from_secs(30), adapter.next_output())
            .await
            .unwrap_or_else(|_| panic!("{task_id} did not end within 30 s: {states:?}"))
            .unwrap();
        match out {
            VehicleOutput::Task(u) if u.task_id == task_id => {
                states.push((u.state, u.progress_pct, u.message.clone()));
                if u.state.is_final() {
                    return (states, events);
                }
            }
            VehicleOutput::Event(e) => events.push(e),
            _ => {}
        }
    }
}

async fn next_event(adapter: &mut MavlinkAdapter, kind: EventKind, secs: u64) -> VehicleEvent {
    loop {
        let out = tokio::time::timeout(Duration::from_secs(secs), adapter.next_output())
            .await
            .expect("an event")
            .unwrap();
        if let VehicleOutput::Event(e) = out
            && e.kind == kind
        {
            return e;
        }
    }
}

fn args(port: u16) -> Vec<String> {
    vec![
        "--port".into(),
        port.to_string(),
        "--speedup".into(),
        "10".into(),
    ]
}

async fn check_telemetry(adapter: &mut MavlinkAdapter) {
    let s = eventually(15, "a state vector", || adapter.state()).await;
    assert_eq!(s.validate(), Ok(()));
    assert_eq!(s.vehicle_id, "bluerov-7");
    assert!(
        (s.latitude_deg - LAT).abs() < 2e-7 && (s.longitude_deg - LON).abs() < 2e-7,
        "{s:?}"
    );
    assert!(
        (s.depth_m - 3.0).abs() < 1e-3,
        "relative_alt -3000 mm: {s:?}"
    );
    assert_eq!(s.battery_pct, 76.0);
    assert!((s.pitch_deg + 2.864_79).abs() < 1e-3, "-0.05 rad: {s:?}");
    assert!((s.roll_deg - 1.145_92).abs() < 1e-3, "0.02 rad: {s:?}");
    assert!(s.yaw_deg < 360.0);
}

#[tokio::test]
async fn a_pymavlink_ardusub_is_driven_through_the_mavlink_adapter() {
    let mut adapter = MavlinkAdapter::connect(MavlinkConfig {
        vehicle_id: "bluerov-7".into(),
        address: "udpin:127.0.0.1:0".into(),
        lost_after_ms: 1500,
        ..MavlinkConfig::default()
    })
    .await
    .unwrap();
    let port = adapter.local_addr().port();
    let Some(mut peer) = start_peer(SCRIPT, "pymavlink", &args(port)) else {
        return;
    };
    assert_eq!(peer.expect("started", 20).await["mavlink"], "2.0");
    check_telemetry(&mut adapter).await;
    let gcs = peer.expect("gcs_heartbeat", 10).await;
    assert_eq!(
        (gcs["type"].as_u64(), gcs["mavlink2"].as_bool()),
        (Some(6), Some(true))
    );
    assert_eq!(peer.expect("request_data_stream", 10).await["rate"], 4);
    let c = adapter.counters();
    assert!(
        c.bad_crc >= 1 && c.unknown_message >= 1,
        "the peer's noise was counted: {c:?}"
    );
    assert_eq!(c.v1_frames, 0, "the peer speaks MAVLink 2");

    // A goto: GUIDED, the speed, the position target; progress; arrival.
    let target = (LAT + 0.0003, LON + 0.0001);
    let task = Task::GotoWaypoint {
        target: GeoPoint {
            latitude_deg: target.0,
            longitude_deg: target.1,
        },
        depth_m: Some(5.0),
        altitude_m: None,
        speed_mps: 1.0,
    };
    adapter.submit(order("goto-1", task)).await.unwrap();
    let mode = peer.expect("set_mode", 10).await;
    assert_eq!(
        (mode["mode"].as_u64(), mode["param1"].as_f64()),
        (Some(4), Some(1.0))
    );
    assert_eq!(peer.expect("change_speed", 10).await["speed"], 1.0);
    let t = peer.expect("position_target", 10).await;
    assert_eq!(t["lat_int"].as_i64(), Some((target.0 * 1e7).round() as i64));
    assert_eq!(t["lon_int"].as_i64(), Some((target.1 * 1e7).round() as i64));
    assert_eq!(t["alt"].as_f64(), Some(-5.0), "5 m below the surface");
    assert_eq!(
        t["frame"].as_u64(),
        Some(3),
        "MAV_FRAME_GLOBAL_RELATIVE_ALT"
    );
    assert_eq!(t["type_mask"].as_u64(), Some(0x0DF8), "position only");
    assert_eq!(
        t["mode"].as_u64(),
        Some(4),
        "the target came after GUIDED was set"
    );
    assert_eq!(t["target"], serde_json::json!([1, 1]));
    let (states, events) = run_to_end(&mut adapter, "goto-1").await;
    assert_eq!(states[0].0, TaskState::Running, "{states:?}");
    assert!(
        states
            .iter()
            .any(|(s, p, _)| *s == TaskState::Running && *p > 0.0),
        "progress: {states:?}"
    );
    assert_eq!(
        states.last().map(|s| (s.0, s.2.as_str())),
        Some((TaskState::Done, "arrived"))
    );
    assert!(
        events.iter().any(|e| e.text == "mode MANUAL -> GUIDED"),
        "the mode change is an event: {events:?}"
    );
    let s = adapter.state().unwrap();
    assert!(
        (s.depth_m - 5.0).abs() <= 0.5 && s.validate().is_ok(),
        "{s:?}"
    );

    // A survey: a mission upload, AUTO, mission progress, completion.
    let p = |dlat: f64, dlon: f64| GeoPoint {
        latitude_deg: target.0 + dlat,
        longitude_deg: target.1 + dlon,
    };
    let survey = Task::SurveyArea {
        polygon: vec![
            p(0.0, 0.0),
            p(0.0, 0.0003),
            p(0.0002, 0.0003),
            p(0.0002, 0.0),
        ],
        line_spacing_m: 12.0,
        depth_m: Some(4.0),
        altitude_m: None,
        speed_mps: 1.5,
    };
    adapter.submit(order("survey-1", survey)).await.unwrap();
    let mission = peer.expect("mission", 10).await;
    let items = mission["items"].as_array().unwrap();
    // 22 m north-south at 12 m: 2 lines of 2 points, after home and the speed change.
    assert_eq!(items.len(), 6, "{mission}");
    assert_eq!(items[1]["command"], 178, "DO_CHANGE_SPEED");
    assert_eq!(items[1]["param2"], 1.5);
    for it in &items[2..] {
        assert_eq!(
            (
                it["command"].as_u64(),
                it["frame"].as_u64(),
                it["z"].as_f64()
            ),
            (Some(16), Some(3), Some(-4.0))
        );
    }
    assert_eq!(
        peer.expect("set_mode", 10).await["mode"],
        3,
        "AUTO after the upload"
    );
    let (states, _) = run_to_end(&mut adapter, "survey-1").await;
    assert_eq!(states[0].0, TaskState::Running);
    assert!(
        states
            .iter()
            .any(|(s, p, _)| *s == TaskState::Running && *p > 0.0 && *p < 100.0),
        "{states:?}"
    );
    assert_eq!(
        states.last().map(|s| (s.0, s.2.as_str())),
        Some((TaskState::Done, "mission complete"))
    );

    // Surface.
    adapter.submit(order("up", Task::Surface)).await.unwrap();
    assert_eq!(peer.expect("set_mode", 10).await["mode"], 9);
    let (states, _) = run_to_end(&mut adapter, "up").await;
    assert_eq!(
        states.last().map(|s| (s.0, s.2.as_str())),
        Some((TaskState::Done, "at the surface"))
    );

    restart(adapter, peer, port).await;
}

/// The vehicle dies: the link is reported lost; it restarts (from another port): the link
/// is restored, its streams are asked for again and telemetry flows.
async fn restart(mut adapter: MavlinkAdapter, peer: Peer, port: u16) {
    peer.kill().await;
    let e = next_event(&mut adapter, EventKind::CommLost, 10).await;
    assert_eq!(e.severity, Severity::Alarm, "{e:?}");
    assert!(adapter.state().is_none(), "no stale state while lost");
    assert!(!adapter.is_connected());
    let mut peer = restart_peer(SCRIPT, "pymavlink", &args(port));
    peer.expect("started", 20).await;
    let e = next_event(&mut adapter, EventKind::CommLost, 20).await;
    assert_eq!(e.severity, Severity::Info, "{e:?}");
    assert!(e.text.starts_with("MAVLink link restored"), "{e:?}");
    peer.expect("request_data_stream", 10).await;
    peer.expect("gcs_heartbeat", 10).await;
    check_telemetry(&mut adapter).await;
    peer.kill().await;
}
