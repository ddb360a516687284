//! The IMC adapter against a simulated DUNE AUV written with LSTS's `imcpy`
//! (`tests/peers/imc_auv_peer.py`), over unicast UDP on 127.0.0.1.
//!
//! Telemetry becomes valid state vectors at the position imcpy's own `toWGS84` gives;
//! a goto reaches the vehicle as a `PlanControl` start with an inline `PlanSpecification`
//! of one `Goto` in radians; the reply, the progress and the outcome come back as task
//! updates; a plan the vehicle refuses fails with its reason; abort stops a running plan;
//! a vehicle that dies is reported lost and picked up again when it returns.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use std::time::Duration;

use common::{eventually, restart_peer, start_peer};
use shoal_model::{EventKind, GeoPoint, Severity, Task, TaskState, Validate, now_ms};
use shoal_proxy::imc::{ImcAdapter, ImcConfig};
use shoal_proxy::{TaskOrder, TaskUpdate, VehicleAdapter, VehicleOutput};

const SCRIPT: &str = "imc_auv_peer.py";

fn order(id: &str, task: Task) -> TaskOrder {
    TaskOrder {
        task_id: id.into(),
        mission_id: "m1".into(),
        issued_ms: now_ms(),
        task,
    }
}

fn goto(lat: f64, lon: f64, depth: f64, speed: f64) -> Task {
    Task::GotoWaypoint {
        target: GeoPoint {
            latitude_deg: lat,
            longitude_deg: lon,
        },
        depth_m: Some(depth),
        altitude_m: None,
        speed_mps: speed,
    }
}

async fn next_update(adapter: &mut ImcAdapter, task_id: &str) -> TaskUpdate {
    loop {
        let out = tokio::time::timeout(Duration::from_secs(20), adapter.next_output())
            .await
            .expect("a task update within 20 s")
            .unwrap();
        if let VehicleOutput::Task(u) = out
            && u.task_id == task_id
        {
            return u;
        }
    }
}

async fn next_event(
    adapter: &mut ImcAdapter,
    kind: EventKind,
    secs: u64,
) -> shoal_proxy::VehicleEvent {
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

fn peer_args(port: u16) -> Vec<String> {
    ["--port", &port.to_string(), "--speedup", "10"]
        .iter()
        .map(ToString::to_string)
        .collect()
}

#[tokio::test]
async fn an_imcpy_auv_is_driven_through_the_imc_adapter() {
    let Some(mut peer) = start_peer(SCRIPT, "imcpy", &peer_args(0)) else {
        return;
    };
    let port = peer.expect("listening", 20).await["port"].as_u64().unwrap();
    let port = u16::try_from(port).unwrap();
    let mut adapter = ImcAdapter::bind(ImcConfig {
        vehicle_id: "lauv-1".into(),
        bind: "127.0.0.1:0".parse().unwrap(),
        vehicle: format!("127.0.0.1:{port}").parse().unwrap(),
        lost_after_ms: 1500,
        ..ImcConfig::default()
    })
    .await
    .unwrap();

    // Telemetry: the position DUNE's own WGS84 code gives, depth, battery.
    let truth = peer.expect("truth", 10).await;
    let state = eventually(10, "a state vector", || adapter.state()).await;
    assert_eq!(state.validate(), Ok(()));
    assert_eq!(state.vehicle_id, "lauv-1");
    let (lat, lon) = (
        truth["lat_deg"].as_f64().unwrap(),
        truth["lon_deg"].as_f64().unwrap(),
    );
    assert!(
        (state.latitude_deg - lat).abs() < 1e-7,
        "{} vs {lat}",
        state.latitude_deg
    );
    assert!(
        (state.longitude_deg - lon).abs() < 1e-7,
        "{} vs {lon}",
        state.longitude_deg
    );
    assert!(state.latitude_deg > 41.185, "35 m north of the reference");
    assert!((state.depth_m - 2.0).abs() < 1e-6);
    assert_eq!(state.battery_pct, 87.5);
    let c = adapter.counters();
    assert!(
        c.bad_crc >= 1 && c.unknown_message >= 1,
        "the peer's noise was counted: {c:?}"
    );

    // A goto: the native command, the acknowledgement, progress and the outcome.
    let target = (41.1857, -8.7058);
    adapter
        .submit(order("goto-1", goto(target.0, target.1, 4.0, 1.5)))
        .await
        .unwrap();
    let plan = peer.expect("plan", 10).await;
    assert_eq!(plan["plan_id"], "goto-1");
    let m = &plan["maneuvers"][0];
    assert_eq!(m["type"], "Goto");
    assert!(
        (m["lat_deg"].as_f64().unwrap() - target.0).abs() < 1e-9,
        "{m}"
    );
    assert!(
        (m["lon_deg"].as_f64().unwrap() - target.1).abs() < 1e-9,
        "{m}"
    );
    assert_eq!(
        (m["z"].as_f64(), m["z_units"].as_u64()),
        (Some(4.0), Some(1))
    );
    assert_eq!(
        (m["speed"].as_f64(), m["speed_units"].as_u64()),
        (Some(1.5), Some(0))
    );
    let u = next_update(&mut adapter, "goto-1").await;
    assert_eq!(u.state, TaskState::Running, "{u:?}");
    let mut states = vec![u.state];
    loop {
        let u = next_update(&mut adapter, "goto-1").await;
        states.push(u.state);
        if u.state.is_final() {
            assert_eq!(u.state, TaskState::Done, "{u:?}");
            assert_eq!(u.progress_pct, 100.0);
            break;
        }
    }
    peer.expect("plan_done", 5).await;
    let arrived = eventually(5, "the vehicle at the target", || {
        adapter
            .state()
            .filter(|s| (s.latitude_deg - target.0).abs() < 1e-6)
    })
    .await;
    assert!((arrived.longitude_deg - target.1).abs() < 1e-6);
    assert!((arrived.depth_m - 4.0).abs() < 1e-3);

    // A plan the vehicle refuses fails with the vehicle's reason.
    adapter
        .submit(order("goto-far", goto(41.3, -8.7, 4.0, 1.0)))
        .await
        .unwrap();
    let u = next_update(&mut adapter, "goto-far").await;
    assert_eq!(u.state, TaskState::Failed);
    assert_eq!(
        u.message,
        "the vehicle refused the plan: target beyond 5 km"
    );

    // Abort stops a running plan.
    adapter
        .submit(order("goto-2", goto(41.1880, -8.7060, 3.0, 0.2)))
        .await
        .unwrap();
    assert_eq!(
        next_update(&mut adapter, "goto-2").await.state,
        TaskState::Running
    );
    adapter.submit(order("stop", Task::Abort)).await.unwrap();
    let abort = peer.expect("abort", 10).await;
    assert_eq!(abort["had_plan"], true);
    let u = next_update(&mut adapter, "goto-2").await;
    assert_eq!(
        (u.state, u.message.as_str()),
        (TaskState::Aborted, "aborted by task stop")
    );
    loop {
        let u = next_update(&mut adapter, "stop").await;
        if u.state.is_final() {
            assert_eq!(u.state, TaskState::Done, "{u:?}");
            break;
        }
    }

    // The vehicle dies: lost; it comes back on the same port: restored, telemetry again.
    peer.kill().await;
    let e = next_event(&mut adapter, EventKind::CommLost, 10).await;
    assert_eq!(e.severity, Severity::Alarm, "{e:?}");
    assert!(adapter.state().is_none());
    let mut peer = restart_peer(SCRIPT, "imcpy", &peer_args(port));
    peer.expect("listening", 20).await;
    let e = next_event(&mut adapter, EventKind::CommLost, 20).await;
    assert_eq!(e.severity, Severity::Info, "{e:?}");
    let s = eventually(10, "a state vector again", || adapter.state()).await;
    assert_eq!(s.validate(), Ok(()));
    peer.kill().await;
}
