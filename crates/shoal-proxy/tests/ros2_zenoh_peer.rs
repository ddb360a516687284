//! The ROS 2 adapter over rmw_zenoh against a ROS 2 robot on rmw_zenoh played by an
//! independent client (`tests/ros2_zenoh/robot_peer.py`, PyPI eclipse-zenoh, written from
//! rmw_zenoh's design document). Zenoh on loopback endpoints only, multicast scouting off:
//! no network namespace needed (no DDS participant is opened).
//!
//! - peer to peer (the proxy listens, the robot connects): the robot's NavSatFix,
//!   Odometry and BatteryState become a state vector at its position; each side sees the
//!   other's liveliness tokens with the right type hashes and QoS; a goto reaches the
//!   robot as a PoseStamped with a valid attachment and completes; fixes with a wrong
//!   type hash, truncated CDR or a bad attachment are counted and dropped; a robot that
//!   dies is reported lost;
//! - through a Zenoh router (rmw_zenoh's usual topology, the router here a Zenoh session
//!   in router mode): the proxy as a client, the robot as a peer; telemetry and a goal.
//!
//! Skipped, with the reason printed, where the venv cannot import zenoh, unless
//! `SHOAL_INTEROP_REQUIRED=1`.

#![cfg(feature = "rmw-zenoh")]
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use std::time::Duration;

use common::{Peer, eventually, order, run_to_end, start_peer};
use shoal_model::{EventKind, GeoPoint, Severity, Task, TaskState, Validate};
use shoal_proxy::ros2::mapping::EnuFrame;
use shoal_proxy::ros2::type_hash::type_hash;
use shoal_proxy::ros2::{Datum, Rmw, Ros2Adapter, Ros2Config, ZenohMode, ZenohSettings};
use shoal_proxy::{Refusal, VehicleAdapter, VehicleOutput};

const DATUM: (f64, f64) = (59.9, 10.7);
/// The robot peer, from `tests/peers/` (where `common` looks).
const PEER: &str = "../ros2_zenoh/robot_peer.py";

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn config(domain_id: u32, zenoh: ZenohSettings) -> Ros2Config {
    Ros2Config {
        vehicle_id: "auv-zenoh".into(),
        namespace: "auv1".into(),
        datum: Some(Datum {
            latitude_deg: DATUM.0,
            longitude_deg: DATUM.1,
        }),
        lost_after_ms: 1500,
        rmw: Rmw::Zenoh,
        zenoh: ZenohSettings { domain_id, ..zenoh },
        ..Ros2Config::default()
    }
}

fn peer_args(domain_id: u32, connect: &str, extra: &[&str]) -> Vec<String> {
    let mut args: Vec<String> = ["--connect", connect, "--domain", &domain_id.to_string()]
        .iter()
        .map(ToString::to_string)
        .collect();
    args.extend(extra.iter().map(ToString::to_string));
    args
}

/// Submits until the robot's goal subscription is known from its token, then returns the
/// acceptance note.
async fn submit_when_matched(adapter: &mut Ros2Adapter, id: &str, task: Task) -> String {
    let deadline = tokio::time::Instant::now() + Duration::from_secs(20);
    loop {
        match adapter.submit(order(id, task.clone())).await {
            Ok(a) => return a.message,
            Err(Refusal { reason })
                if reason.starts_with("nothing subscribes")
                    || reason.starts_with("no data from") =>
            {
                assert!(tokio::time::Instant::now() < deadline, "{reason}");
                tokio::time::sleep(Duration::from_millis(100)).await;
            }
            Err(r) => panic!("refused: {r}"),
        }
    }
}

/// The robot's token lines until one of each wanted kind and topic (`None`: a node) came,
/// in the order asked.
async fn tokens(peer: &mut Peer, want: &[(&str, Option<&str>)]) -> Vec<serde_json::Value> {
    let matches = |t: &serde_json::Value, (kind, topic): &(&str, Option<&str>)| {
        t["kind"] == *kind && topic.is_none_or(|n| t["topic"] == n)
    };
    let mut seen: Vec<serde_json::Value> = Vec::new();
    while !want.iter().all(|w| seen.iter().any(|t| matches(t, w))) {
        seen.push(peer.expect("token", 20).await);
    }
    want.iter()
        .filter_map(|w| seen.iter().find(|t| matches(t, w)).cloned())
        .collect()
}

/// The state vector at the robot's start (east 10 m, north -20 m of the datum, 2.5 m deep,
/// battery 0.64).
async fn sees_the_robot(adapter: &mut Ros2Adapter) {
    let frame = EnuFrame::new(GeoPoint {
        latitude_deg: DATUM.0,
        longitude_deg: DATUM.1,
    });
    let deadline = tokio::time::Instant::now() + Duration::from_secs(30);
    let s = loop {
        if let Some(s) = adapter.state() {
            break s;
        }
        assert!(
            tokio::time::Instant::now() < deadline,
            "no state vector within 30 s: {:?}",
            adapter.counters()
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    assert_eq!(s.validate(), Ok(()));
    assert_eq!(s.vehicle_id, "auv-zenoh");
    let start = frame.to_geo(10.0, -20.0);
    assert!((s.latitude_deg - start.latitude_deg).abs() < 1e-7, "{s:?}");
    assert!(
        (s.longitude_deg - start.longitude_deg).abs() < 1e-7,
        "{s:?}"
    );
    assert!((s.depth_m - 2.5).abs() < 1e-9, "{s:?}");
    assert!((s.battery_pct - 64.0).abs() < 1e-4, "{s:?}");
    assert!(
        (s.yaw_deg - 90.0).abs() < 1e-6,
        "ENU yaw 0 faces east: {s:?}"
    );
}

/// A goto in the ENU goal frame: the robot's goal line, checked.
async fn goto(adapter: &mut Ros2Adapter, peer: &mut Peer, id: &str) -> serde_json::Value {
    let frame = EnuFrame::new(GeoPoint {
        latitude_deg: DATUM.0,
        longitude_deg: DATUM.1,
    });
    let task = Task::GotoWaypoint {
        target: frame.to_geo(40.0, 30.0),
        depth_m: Some(4.0),
        altitude_m: None,
        speed_mps: 1.0,
    };
    let note = submit_when_matched(adapter, id, task).await;
    assert_eq!(note, "1 goal(s) for 1 subscriber(s)");
    let goal = peer.expect("goal", 10).await;
    assert_eq!(goal["attachment_ok"], true, "{goal}");
    assert_eq!(goal["frame_id"], "map");
    let (x, y) = (goal["x"].as_f64().unwrap(), goal["y"].as_f64().unwrap());
    assert!((x - 40.0).abs() < 1e-6 && (y - 30.0).abs() < 1e-6, "{goal}");
    assert_eq!(goal["z"].as_f64(), Some(-4.0), "z up: 4 m deep is -4");
    goal
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_rmw_zenoh_robot_joins_peer_to_peer_and_takes_a_goal() {
    let port = free_port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let domain = 23;
    let mut adapter = Ros2Adapter::zenoh(config(
        domain,
        ZenohSettings {
            connect: vec![],
            listen: vec![endpoint.clone()],
            ..ZenohSettings::default()
        },
    ))
    .await
    .unwrap();
    let Some(mut peer) = start_peer(PEER, "zenoh", &peer_args(domain, &endpoint, &["--garbage"]))
    else {
        return;
    };
    peer.expect("ready", 20).await;

    // The robot's graph shows the proxy's node and entities, with rosidl's type hashes.
    let seen = tokens(
        &mut peer,
        &[
            ("NN", None),
            ("MS", Some("/auv1/fix")),
            ("MS", Some("/auv1/odom")),
            ("MS", Some("/auv1/battery")),
            ("MS", Some("/rosout")),
            ("MP", Some("/auv1/goal_pose")),
        ],
    )
    .await;
    let node = &seen[0];
    assert_eq!(
        (&node["node"], &node["namespace"]),
        (&"shoal_proxy".into(), &"/auv1".into())
    );
    for t in &seen[1..] {
        assert_eq!(t["hash_ok"], true, "{t}");
        assert_eq!(t["qos"], "::,10:,:,:,,", "{t}");
    }
    let t = &seen[5];
    assert_eq!(t["type"], "geometry_msgs::msg::dds_::PoseStamped_");
    assert_eq!(t["hash_ok"], true, "{t}");
    assert!(
        t["key"]
            .as_str()
            .unwrap()
            .contains(&type_hash("geometry_msgs/msg/PoseStamped").unwrap())
    );
    sees_the_robot(&mut adapter).await;

    // Bad input is counted and dropped: one fix with another type hash, one truncated,
    // one without an attachment, one with a 5-byte attachment.
    peer.expect("garbage_sent", 10).await;
    let c = eventually(10, "the garbage counted", || {
        let c = adapter.counters();
        (c.wrong_type >= 1 && c.malformed >= 1 && c.bad_attachment >= 2).then_some(c)
    })
    .await;
    assert_eq!(
        (c.wrong_type, c.malformed, c.bad_attachment),
        (1, 1, 2),
        "{c:?}"
    );
    assert_eq!(c.invalid, 0, "{c:?}");

    // A goto: the goal with its attachment, progress, arrival; a second goal's sequence
    // number follows the first's.
    let goal = goto(&mut adapter, &mut peer, "goto-1").await;
    assert_eq!(goal["seq"], 1, "{goal}");
    let states = run_to_end(&mut adapter, "goto-1").await;
    assert_eq!(states[0].0, TaskState::Running, "{states:?}");
    assert_eq!(
        states.last().map(|s| (s.0, s.2.as_str())),
        Some((TaskState::Done, "arrived"))
    );
    submit_when_matched(&mut adapter, "up", Task::Surface).await;
    let goal = peer.expect("goal", 10).await;
    assert_eq!(
        (goal["seq"].as_i64(), goal["z"].as_f64()),
        (Some(2), Some(0.0)),
        "{goal}"
    );
    assert_eq!(goal["attachment_ok"], true, "{goal}");
    let c = adapter.counters();
    assert_eq!((c.goals_sent, c.goal_errors, c.flooded), (2, 0, 0), "{c:?}");
    assert!(c.samples > 10, "{c:?}");

    // The robot dies: lost after lost_after_ms of silence, and no state vector.
    peer.kill().await;
    loop {
        let out = tokio::time::timeout(Duration::from_secs(10), adapter.next_output())
            .await
            .expect("comm_lost within 10 s")
            .unwrap();
        if let VehicleOutput::Event(e) = out
            && e.kind == EventKind::CommLost
            && e.severity == Severity::Alarm
        {
            break;
        }
    }
    assert!(adapter.state().is_none());
    assert!(!adapter.is_connected());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_rmw_zenoh_robot_joins_through_a_router() {
    let port = free_port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    // The router, as `rmw_zenohd` runs it, but on loopback and without scouting.
    let mut router = zenoh::Config::default();
    for (k, v) in [
        ("mode", "\"router\"".to_string()),
        ("listen/endpoints", format!("[\"{endpoint}\"]")),
        ("connect/endpoints", "[]".into()),
        ("scouting/multicast/enabled", "false".into()),
    ] {
        router.insert_json5(k, &v).unwrap();
    }
    let router = zenoh::open(router).await.unwrap();
    let domain = 24;
    let Some(mut peer) = start_peer(PEER, "zenoh", &peer_args(domain, &endpoint, &[])) else {
        return;
    };
    let mut adapter = Ros2Adapter::zenoh(config(
        domain,
        ZenohSettings {
            mode: ZenohMode::Client,
            connect: vec![endpoint],
            listen: vec![],
            ..ZenohSettings::default()
        },
    ))
    .await
    .unwrap();
    peer.expect("ready", 20).await;
    sees_the_robot(&mut adapter).await;
    let goal = goto(&mut adapter, &mut peer, "goto-r").await;
    assert_eq!(goal["seq"], 1, "{goal}");
    let states = run_to_end(&mut adapter, "goto-r").await;
    assert_eq!(
        states.last().map(|s| s.0),
        Some(TaskState::Done),
        "{states:?}"
    );
    assert_eq!(adapter.counters().bad_attachment, 0);
    peer.kill().await;
    drop(adapter);
    router.close().await.unwrap();
}
