//! The ROS 2 adapter against a ROS 2 vehicle as DDS sees it, written with PyPI `cyclonedds`
//! (`tests/peers/ros2_vehicle_peer.py`): ROS 2 topic and type names, plain CDR in `.msg`
//! order, ROS 2's default QoS. Opens a DDS participant, so run it inside a loopback-only
//! network namespace (`scripts/netns-run.sh`), as CI does.
//!
//! NavSatFix, Odometry and BatteryState become valid state vectors; a `/rosout` warning
//! becomes an event; a goto reaches the vehicle as a PoseStamped in the ENU goal frame
//! and its progress and arrival come back as task updates; surfacing; a vehicle that goes
//! silent is reported lost. A vehicle whose process dies is reported lost and picked up
//! again when a new one starts (domain 52; the drive test uses 171).

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use std::sync::Arc;
use std::time::Duration;

use common::{Peer, eventually, order, restart_peer, run_to_end, start_peer};
use shoal_dds::{DdsConfig, PubSub};
use shoal_model::{EventKind, GeoPoint, Severity, Task, TaskState, Validate};
use shoal_proxy::ros2::mapping::EnuFrame;
use shoal_proxy::ros2::{Datum, Ros2Adapter, Ros2Config};
use shoal_proxy::{Refusal, VehicleAdapter, VehicleEvent, VehicleOutput};

const DOMAIN: u16 = 171;
const DATUM: (f64, f64) = (59.9, 10.7);

async fn next_event(adapter: &mut Ros2Adapter, kind: EventKind, secs: u64) -> VehicleEvent {
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

/// Starts the Cyclone DDS vehicle on `domain`, in the configuration's namespace, and an
/// adapter for it on a participant of its own; also returns the peer's arguments (to start
/// it again). `None` when the peer cannot run here.
fn start(domain: u16, config: Ros2Config) -> Option<(Peer, Ros2Adapter, Vec<String>)> {
    let args: Vec<String> = [
        "--domain",
        &domain.to_string(),
        "--namespace",
        &config.namespace,
    ]
    .iter()
    .map(ToString::to_string)
    .collect();
    let peer = start_peer("ros2_vehicle_peer.py", "cyclonedds", &args)?;
    let dds = Arc::new(
        PubSub::new(&DdsConfig {
            domain_id: domain,
            ..DdsConfig::default()
        })
        .unwrap(),
    );
    let adapter = Ros2Adapter::new(dds, config).unwrap();
    Some((peer, adapter, args))
}

/// Submits until the goal writer has matched the vehicle's subscriber (discovery takes a
/// moment), then returns the acceptance note.
async fn submit_when_matched(adapter: &mut Ros2Adapter, id: &str, task: Task) -> String {
    let deadline = tokio::time::Instant::now() + Duration::from_secs(30);
    loop {
        match adapter.submit(order(id, task.clone())).await {
            Ok(a) => return a.message,
            Err(Refusal { reason }) if reason.starts_with("nothing subscribes") => {
                assert!(tokio::time::Instant::now() < deadline, "{reason}");
                tokio::time::sleep(Duration::from_millis(200)).await;
            }
            Err(r) => panic!("refused: {r}"),
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_cyclonedds_ros2_vehicle_is_driven_through_the_ros2_adapter() {
    let config = Ros2Config {
        vehicle_id: "auv-ros".into(),
        namespace: "bluerov".into(),
        datum: Some(Datum {
            latitude_deg: DATUM.0,
            longitude_deg: DATUM.1,
        }),
        ..Ros2Config::default()
    };
    let Some((mut peer, mut adapter, _)) = start(DOMAIN, config) else {
        return;
    };
    peer.expect("ready", 20).await;
    let frame = EnuFrame::new(GeoPoint {
        latitude_deg: DATUM.0,
        longitude_deg: DATUM.1,
    });

    // Telemetry: the fix, depth from odometry z, REP 103 attitude, battery fraction.
    let s = eventually(30, "a state vector", || adapter.state()).await;
    assert_eq!(s.validate(), Ok(()));
    assert_eq!(s.vehicle_id, "auv-ros");
    let start = frame.to_geo(10.0, -20.0);
    assert!((s.latitude_deg - start.latitude_deg).abs() < 1e-8, "{s:?}");
    assert!(
        (s.longitude_deg - start.longitude_deg).abs() < 1e-8,
        "{s:?}"
    );
    assert!((s.depth_m - 2.5).abs() < 1e-9, "odometry z -2.5: {s:?}");
    assert!((s.battery_pct - 64.0).abs() < 1e-4, "fraction 0.64: {s:?}");
    assert!(
        (s.yaw_deg - 90.0).abs() < 1e-6,
        "ENU yaw 0 faces east: {s:?}"
    );
    assert!(
        (s.pitch_deg + 0.1f64.to_degrees()).abs() < 1e-6,
        "nose down 0.1 rad: {s:?}"
    );

    let warn = next_event(&mut adapter, EventKind::Other, 20).await;
    assert_eq!(warn.severity, Severity::Warning);
    assert_eq!(warn.text, "bluerov.controller: thruster 3 current high");

    // A goto: a PoseStamped in the ENU goal frame, progress, arrival.
    let target = frame.to_geo(40.0, 30.0);
    let task = Task::GotoWaypoint {
        target,
        depth_m: Some(4.0),
        altitude_m: None,
        speed_mps: 1.0,
    };
    let note = submit_when_matched(&mut adapter, "goto-1", task).await;
    assert_eq!(note, "1 goal(s) for 1 subscriber(s)");
    let goal = peer.expect("goal", 10).await;
    assert_eq!(goal["frame_id"], "map");
    let x = goal["x"].as_f64().unwrap();
    let y = goal["y"].as_f64().unwrap();
    assert!((x - 40.0).abs() < 1e-6 && (y - 30.0).abs() < 1e-6, "{goal}");
    assert_eq!(goal["z"].as_f64(), Some(-4.0), "z up: 4 m deep is -4");
    let yaw = 2.0
        * goal["qz"]
            .as_f64()
            .unwrap()
            .atan2(goal["qw"].as_f64().unwrap());
    assert!(
        (yaw - 50f64.atan2(30.0)).abs() < 0.01,
        "facing the target: {yaw}"
    );
    assert!(goal["sec"].as_i64().unwrap() > 1_600_000_000);
    let states = run_to_end(&mut adapter, "goto-1").await;
    assert_eq!(states[0].0, TaskState::Running, "{states:?}");
    assert!(
        states
            .iter()
            .any(|(s, p, _)| *s == TaskState::Running && *p > 0.0 && *p < 100.0),
        "{states:?}"
    );
    assert_eq!(
        states.last().map(|s| (s.0, s.2.as_str())),
        Some((TaskState::Done, "arrived"))
    );
    let s = adapter.state().unwrap();
    assert!((s.depth_m - 4.0).abs() <= 0.5, "{s:?}");

    // Surfacing: a goal where the vehicle is, at z 0.
    submit_when_matched(&mut adapter, "up", Task::Surface).await;
    let goal = peer.expect("goal", 10).await;
    assert_eq!(goal["z"].as_f64(), Some(0.0));
    assert!((goal["x"].as_f64().unwrap() - 40.0).abs() < 2.0, "{goal}");
    let states = run_to_end(&mut adapter, "up").await;
    assert_eq!(
        states.last().map(|s| (s.0, s.2.as_str())),
        Some((TaskState::Done, "at the surface"))
    );
    let c = adapter.counters();
    assert_eq!((c.malformed, c.invalid, c.goals_sent), (0, 0, 2), "{c:?}");

    // Silence: lost.
    peer.kill().await;
    let e = next_event(&mut adapter, EventKind::CommLost, 20).await;
    assert_eq!(e.severity, Severity::Alarm);
    assert!(adapter.state().is_none());
}

/// Everything the adapter has already queued, without waiting.
async fn drain(adapter: &mut Ros2Adapter) -> Vec<VehicleOutput> {
    let mut out = Vec::new();
    while let Ok(Ok(o)) = tokio::time::timeout(Duration::ZERO, adapter.next_output()).await {
        out.push(o);
    }
    out
}

fn is_comm_lost(o: &VehicleOutput, severity: Severity) -> bool {
    matches!(o, VehicleOutput::Event(e) if e.kind == EventKind::CommLost && e.severity == severity)
}

// ROS 2 has no connection to lose: the adapter can only tell a vehicle is gone from the
// silence of its topics (`lost_after_ms`), and that it is back from samples of a new
// participant on the same topics.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_ros2_vehicle_that_dies_is_reported_lost_and_picked_up_when_it_returns() {
    let config = Ros2Config {
        vehicle_id: "auv7".into(),
        namespace: "auv7".into(),
        lost_after_ms: 3000,
        ..Ros2Config::default()
    };
    let Some((mut peer, mut adapter, args)) = start(52, config) else {
        return;
    };
    peer.expect("ready", 30).await;
    let s = eventually(60, "a state vector", || adapter.state()).await;
    assert_eq!(s.validate(), Ok(()));
    assert!(adapter.is_connected());

    // The vehicle dies: after lost_after_ms of silence, lost, and no stale state.
    peer.kill().await;
    eventually(60, "the vehicle reported lost", || {
        (!adapter.is_connected()).then_some(())
    })
    .await;
    assert!(adapter.state().is_none());
    let before = drain(&mut adapter).await;
    assert!(
        before.iter().any(|o| is_comm_lost(o, Severity::Alarm)),
        "a comm_lost alarm: {before:?}"
    );

    // A new vehicle process on the same topics: heard again, state again.
    let mut peer = restart_peer("ros2_vehicle_peer.py", "cyclonedds", &args);
    peer.expect("ready", 30).await;
    let e = next_event(&mut adapter, EventKind::CommLost, 60).await;
    assert_eq!(e.severity, Severity::Info, "{e:?}");
    assert!(e.text.starts_with("ROS 2 topics heard again"), "{e:?}");
    let s = eventually(30, "a state vector again", || adapter.state()).await;
    assert_eq!(s.validate(), Ok(()));
    assert!(adapter.is_connected());
    peer.kill().await;
}
