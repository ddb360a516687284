//! The ROS 2 adapter against a ROS 2 vehicle simulated in Rust on a second DDS participant,
//! with the same topic names and message types. Opens DDS participants, so run it inside
//! a loopback-only network namespace (`scripts/netns-run.sh`), as CI does.
//!
//! Checks the adapter's own logic end to end over DDS: state vectors from fix, odometry
//! and battery; goals in the ENU frame one leg at a time for a survey; progress and
//! arrival; abort superseding a task; silence reported lost. (`ros2_peer.rs` checks the
//! wire against Cyclone DDS, the middleware of ROS 2.)

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use std::sync::{Arc, Mutex};
use std::time::Duration;

use common::{eventually, order};
use futures::StreamExt;
use shoal_dds::{DdsConfig, Priority, PubSub, WriterOptions};
use shoal_model::{EventKind, GeoPoint, Severity, Task, TaskState, Validate, now_ms};
use shoal_proxy::ros2::mapping::{EnuFrame, heading_quaternion};
use shoal_proxy::ros2::msgs::{
    BatteryState, Header, NavSatFix, NavSatStatus, Odometry, PoseStamped, Time,
};
use shoal_proxy::ros2::{Datum, Ros2Adapter, Ros2Config};
use shoal_proxy::{Refusal, VehicleAdapter, VehicleEvent, VehicleOutput};
use tokio_util::sync::CancellationToken;

const DOMAIN: u16 = 172;
const DATUM: GeoPoint = GeoPoint {
    latitude_deg: 43.1,
    longitude_deg: 5.9,
};

/// A vehicle on its own participant: publishes fix, odometry and battery at 20 Hz and
/// drives to each goal at 20 m/s; records the goals.
fn spawn_vehicle(stop: CancellationToken) -> Arc<Mutex<Vec<PoseStamped>>> {
    let goals = Arc::new(Mutex::new(Vec::new()));
    let seen = Arc::clone(&goals);
    tokio::spawn(async move {
        let dds = PubSub::new(&DdsConfig {
            domain_id: DOMAIN,
            ..DdsConfig::default()
        })
        .unwrap();
        let opts = WriterOptions::new(Priority::Telemetry);
        let fix_w = dds.writer_on::<NavSatFix>("rt/sub1/fix", opts).unwrap();
        let odom_w = dds.writer_on::<Odometry>("rt/sub1/odom", opts).unwrap();
        let bat_w = dds
            .writer_on::<BatteryState>("rt/sub1/battery", opts)
            .unwrap();
        let mut goal_r = dds
            .subscribe_on::<PoseStamped>("rt/sub1/goal_pose")
            .unwrap();
        let frame = EnuFrame::new(DATUM);
        let (mut x, mut y, mut z) = (0.0f64, 0.0f64, -1.0f64);
        let mut target: Option<(f64, f64, f64)> = None;
        let mut tick = tokio::time::interval(Duration::from_millis(50));
        loop {
            tokio::select! {
                () = stop.cancelled() => return,
                Some(Ok((g, _))) = goal_r.next() => {
                    target = Some((g.pose.position.x, g.pose.position.y, g.pose.position.z));
                    seen.lock().unwrap().push(g.into_inner());
                }
                _ = tick.tick() => {
                    if let Some((tx, ty, tz)) = target {
                        let (dx, dy) = (tx - x, ty - y);
                        let d = dx.hypot(dy);
                        let step = 1.0;
                        if d <= step { (x, y) = (tx, ty) } else { x += dx / d * step; y += dy / d * step; }
                        z += (tz - z).clamp(-step, step);
                    }
                    let p = frame.to_geo(x, y);
                    let header = Header { stamp: Time::from_ms(now_ms()), frame_id: "odom".into() };
                    let r = fix_w.write(NavSatFix {
                        header: header.clone(),
                        status: NavSatStatus { status: 0, service: 1 },
                        latitude: p.latitude_deg,
                        longitude: p.longitude_deg,
                        ..NavSatFix::default()
                    }).await;
                    assert!(r.is_ok(), "{r:?}");
                    let mut o = Odometry { header: header.clone(), child_frame_id: "base_link".into(), ..Odometry::default() };
                    o.pose.pose.position.z = z;
                    o.pose.pose.orientation = heading_quaternion(200.0);
                    o.twist.twist.linear.x = 0.5;
                    let _ = odom_w.write(o).await;
                    let _ = bat_w.write(BatteryState { header, percentage: 0.375, present: true, ..BatteryState::default() }).await;
                }
            }
        }
    });
    goals
}

async fn submit_when_matched(adapter: &mut Ros2Adapter, id: &str, task: Task) {
    let deadline = tokio::time::Instant::now() + Duration::from_secs(30);
    loop {
        match adapter.submit(order(id, task.clone())).await {
            Ok(_) => return,
            Err(Refusal { reason }) if reason.starts_with("nothing subscribes") => {
                assert!(tokio::time::Instant::now() < deadline, "{reason}");
                tokio::time::sleep(Duration::from_millis(200)).await;
            }
            Err(r) => panic!("refused: {r}"),
        }
    }
}

async fn outputs_until_end(
    adapter: &mut Ros2Adapter,
    task_id: &str,
) -> (Vec<(String, TaskState, f64, String)>, Vec<VehicleEvent>) {
    let mut updates = Vec::new();
    let mut events = Vec::new();
    loop {
        let out = tokio::time::timeout(Duration::from_secs(30), adapter.next_output())
            .await
            .unwrap_or_else(|_| panic!("{task_id} did not end: {updates:?}"))
            .unwrap();
        match out {
            VehicleOutput::Task(u) => {
                let end = u.task_id == task_id && u.state.is_final();
                updates.push((u.task_id, u.state, u.progress_pct, u.message));
                if end {
                    return (updates, events);
                }
            }
            VehicleOutput::Event(e) => events.push(e),
            VehicleOutput::Observation(_) => {}
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_ros2_adapter_drives_a_simulated_ros2_vehicle_over_dds() {
    let stop = CancellationToken::new();
    let goals = spawn_vehicle(stop.clone());
    let dds = Arc::new(
        PubSub::new(&DdsConfig {
            domain_id: DOMAIN,
            ..DdsConfig::default()
        })
        .unwrap(),
    );
    let mut adapter = Ros2Adapter::new(
        dds,
        Ros2Config {
            vehicle_id: "sub-1".into(),
            namespace: "sub1".into(),
            datum: Some(Datum {
                latitude_deg: DATUM.latitude_deg,
                longitude_deg: DATUM.longitude_deg,
            }),
            lost_after_ms: 1000,
            ..Ros2Config::default()
        },
    )
    .unwrap();

    let s = eventually(30, "a state vector", || adapter.state()).await;
    assert_eq!(s.validate(), Ok(()));
    assert!((s.latitude_deg - DATUM.latitude_deg).abs() < 1e-9);
    assert_eq!((s.depth_m, s.speed_mps, s.battery_pct), (1.0, 0.5, 37.5));
    assert!((s.yaw_deg - 200.0).abs() < 1e-6, "{s:?}");

    // A survey: one goal per lawnmower point, each published when the last is reached.
    let frame = EnuFrame::new(DATUM);
    let corner = |e: f64, n: f64| frame.to_geo(e, n);
    let survey = Task::SurveyArea {
        polygon: vec![
            corner(10.0, 10.0),
            corner(40.0, 10.0),
            corner(40.0, 29.0),
            corner(10.0, 29.0),
        ],
        line_spacing_m: 10.0,
        depth_m: Some(3.0),
        altitude_m: None,
        speed_mps: 1.0,
    };
    submit_when_matched(&mut adapter, "survey", survey).await;
    let (updates, _) = outputs_until_end(&mut adapter, "survey").await;
    let last = updates.last().unwrap();
    assert_eq!(
        (last.1, last.3.as_str()),
        (TaskState::Done, "arrived"),
        "{updates:?}"
    );
    assert!(
        updates.iter().any(|u| u.3 == "goal 4 of 4 published"),
        "{updates:?}"
    );
    let progress: Vec<f64> = updates.iter().map(|u| u.2).collect();
    assert!(
        progress.windows(2).all(|w| w[1] >= w[0]),
        "progress never goes back: {progress:?}"
    );
    let g = goals.lock().unwrap().clone();
    assert_eq!(g.len(), 4);
    // 19 m north-south at 10 m: two lines, a quarter in from each edge, west to east then
    // back.
    let xy: Vec<(f64, f64)> = g
        .iter()
        .map(|p| (p.pose.position.x, p.pose.position.y))
        .collect();
    for ((x, y), (ex, ey)) in
        xy.iter()
            .zip([(10.0, 14.75), (40.0, 14.75), (40.0, 24.25), (10.0, 24.25)])
    {
        assert!((x - ex).abs() < 0.2 && (y - ey).abs() < 0.2, "{xy:?}");
    }
    assert!(
        g.iter()
            .all(|p| p.pose.position.z == -3.0 && p.header.frame_id == "map")
    );

    // A long goto, superseded by an abort: aborted, then the abort surfaces.
    submit_when_matched(
        &mut adapter,
        "far",
        Task::GotoWaypoint {
            target: corner(500.0, 500.0),
            depth_m: Some(2.0),
            altitude_m: None,
            speed_mps: 1.0,
        },
    )
    .await;
    tokio::time::sleep(Duration::from_millis(500)).await;
    submit_when_matched(&mut adapter, "stop", Task::Abort).await;
    let (updates, _) = outputs_until_end(&mut adapter, "stop").await;
    let far = updates.iter().rfind(|u| u.0 == "far").unwrap();
    assert_eq!(
        (far.1, far.3.as_str()),
        (TaskState::Aborted, "aborted by task stop")
    );
    assert_eq!(updates.last().map(|u| u.3.as_str()), Some("at the surface"));
    assert_eq!(goals.lock().unwrap().last().unwrap().pose.position.z, 0.0);

    // Hold for a second: done after it.
    submit_when_matched(&mut adapter, "hold", Task::Hold { duration_s: 1.0 }).await;
    let (updates, _) = outputs_until_end(&mut adapter, "hold").await;
    assert_eq!(
        updates.last().map(|u| (u.1, u.3.as_str())),
        Some((TaskState::Done, "held for the duration"))
    );

    // Silence.
    stop.cancel();
    let (_, events) = loop {
        let out = tokio::time::timeout(Duration::from_secs(10), adapter.next_output())
            .await
            .unwrap()
            .unwrap();
        if let VehicleOutput::Event(e) = out
            && e.kind == EventKind::CommLost
        {
            break ((), vec![e]);
        }
    };
    assert_eq!(events[0].severity, Severity::Alarm);
    assert!(adapter.state().is_none());
    assert_eq!(adapter.counters().malformed, 0);
}
