//! `shoal vehicle --proxy mavlink|imc|ros2` end to end: the binary joins a vehicle that
//! speaks its own protocol to an in-process station; the station sees the vehicle's
//! telemetry, and a goto dispatched by the station reaches the vehicle as its native
//! command, whose acknowledgement and progress come back as task status.
//!
//! The vehicles are independent implementations in `tests/peers/` (installed into `.venv`
//! by `scripts/install-proxy-peers.sh`): an ArduSub-like vehicle on PyPI pymavlink
//! (`ardusub_peer.py`), a DUNE-like AUV on LSTS's imcpy (`imc_auv_peer.py`) and a ROS 2
//! graph as DDS sees it on PyPI cyclonedds (`ros2_vehicle_peer.py`). Each peer prints a
//! JSON line for every native command it gets, which is how a test proves what arrived.
//!
//! DDS domains: MAVLink 55, IMC 50, ROS 2 51.

use std::process::Stdio;
use std::time::Duration;

use shoal_model::{GeoPoint, Task, TaskAssignment, TaskState, Validate, now_ms};
use shoal_proxy::ros2::mapping::EnuFrame;
use shoal_station::{StationHandle, TaskView};
use tokio::process::{Child, Command};

use crate::common::{eventually, start_station};

// The peers are started as the adapter tests of shoal-proxy start them (the venv's Python,
// skipped with a reason when it cannot run unless SHOAL_INTEROP_REQUIRED=1, one JSON line
// per thing the peer does): one helper for both test suites, not a copy.
#[path = "../../../shoal-proxy/tests/common/mod.rs"]
mod peers;
use peers::start_peer;

fn strings(args: &[&str]) -> Vec<String> {
    args.iter().map(ToString::to_string).collect()
}

/// `shoal vehicle --proxy <kind> --id <id> <args>` on DDS domain `domain`, publishing
/// state twice a second; [`stop_proxy`] ends it by closing its stdin.
fn start_proxy(kind: &str, id: &str, domain: u16, args: &[&str]) -> Child {
    // Each proxy its own task ledger: runs must not inherit what an earlier one executed.
    static RUN: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
    let n = RUN.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let ledgers = std::env::temp_dir().join(format!(
        "shoal-it-ledgers-{}-{n}-{}",
        std::process::id(),
        now_ms()
    ));
    Command::new(env!("CARGO_BIN_EXE_shoal"))
        .args(["vehicle", "--proxy", kind, "--id", id, "--rate", "2"])
        .args(args)
        .arg("--exit-on-stdin-close")
        .env("SHOAL_DDS__DOMAIN_ID", domain.to_string())
        .env("SHOAL_VEHICLE__STATE_DIR", &ledgers)
        // The station here is in-process and insecure (its Python peers have no DDS
        // Security), so the proxy is too.
        .env("SHOAL_SECURITY__ENABLED", "false")
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .stderr(Stdio::inherit())
        .kill_on_drop(true)
        .spawn()
        .unwrap()
}

/// Closes the proxy's stdin and checks that it stops cleanly.
async fn stop_proxy(mut proxy: Child) {
    drop(proxy.stdin.take());
    let status = tokio::time::timeout(Duration::from_secs(30), proxy.wait())
        .await
        .expect("the proxy stops when its stdin closes")
        .unwrap();
    assert!(status.success(), "{status:?}");
}

fn goto(
    task_id: &str,
    vehicle: &str,
    target: GeoPoint,
    depth_m: f64,
    speed: f64,
) -> TaskAssignment {
    TaskAssignment::new(
        task_id,
        "",
        vehicle,
        now_ms(),
        &Task::GotoWaypoint {
            target,
            depth_m: Some(depth_m),
            altitude_m: None,
            speed_mps: speed,
        },
    )
}

/// Dispatches a task through the station; any error fails the test. (`dispatch` once
/// re-read the task's state after publishing and called a task the vehicle had already
/// accepted unpublished; these tests caught it about one run in three.)
async fn dispatch(h: &StationHandle, task: TaskAssignment) {
    let id = task.task_id.clone();
    if let Err(e) = h.dispatch(task).await {
        panic!("dispatch {id}: {e}; {:?}", h.task(&id));
    }
}

/// Waits until the station holds a valid state vector from `vehicle` and returns it.
async fn telemetry(h: &StationHandle, vehicle: &str) -> shoal_model::StateVector {
    let v = eventually(60, &format!("{vehicle} registered with a state"), || {
        h.vehicle(vehicle).filter(|v| v.latest.is_some())
    })
    .await;
    let s = v.latest.unwrap();
    assert_eq!(s.validate(), Ok(()), "{s:?}");
    assert_eq!(s.vehicle_id, vehicle);
    s
}

/// Waits until the task is final at the station and returns it.
async fn finished(h: &StationHandle, task_id: &str, secs: u64) -> TaskView {
    eventually(secs, &format!("{task_id} final at the station"), || {
        h.task(task_id).filter(|t| t.state.is_final())
    })
    .await
}

/// The task's states as the station recorded them (history), oldest first, once the
/// history holds the final one.
async fn recorded_states(h: &StationHandle, task_id: &str) -> Vec<(TaskState, f64)> {
    // The history writer commits in batches, and the final status reaches it a moment
    // after the task register (a CI run read the register's `done` and then a history
    // that ended at 98 % running): wait for what was submitted, until it is final.
    eventually(
        30,
        &format!("{task_id}'s final status in the history"),
        || {
            tokio::task::block_in_place(|| h.flush_history(Duration::from_secs(30))).unwrap();
            let states: Vec<(TaskState, f64)> = h
                .history()
                .task_history(task_id)
                .unwrap()
                .statuses
                .iter()
                .map(|s| (s.state, s.progress_pct))
                .collect();
            states
                .last()
                .is_some_and(|(s, _)| s.is_final())
                .then_some(states)
        },
    )
    .await
}

/// Checks the station saw the vehicle take the task, run it and finish it, in that order.
fn assert_accepted_running_done(states: &[(TaskState, f64)]) {
    let at = |want: TaskState| states.iter().position(|(s, _)| *s == want);
    let (accepted, running) = (at(TaskState::Accepted), at(TaskState::Running));
    assert!(
        accepted.is_some() && running.is_some() && accepted < running,
        "accepted, then running: {states:?}"
    );
    assert_eq!(
        states.last().map(|s| s.0),
        Some(TaskState::Done),
        "{states:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_mavlink_proxy_command_joins_an_ardusub_vehicle_to_the_station() {
    let station = start_station(55);
    let h = station.handle.clone();
    let port = std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let address = format!("udpin:127.0.0.1:{port}");
    let proxy = start_proxy("mavlink", "bluerov-1", 55, &["--address", &address]);
    let args = strings(&[
        "--port",
        &port.to_string(),
        "--lat",
        "63.44",
        "--lon",
        "10.4",
    ]);
    let Some(mut peer) = start_peer("ardusub_peer.py", "pymavlink", &args) else {
        return;
    };

    let s = telemetry(&h, "bluerov-1").await;
    assert!((s.latitude_deg - 63.44).abs() < 1e-3, "{s:?}");
    assert!(
        s.depth_m > 0.0,
        "depth from relative_alt below the surface: {s:?}"
    );

    let target = GeoPoint {
        latitude_deg: 63.4402,
        longitude_deg: 10.4,
    };
    dispatch(&h, goto("cli-goto-1", "bluerov-1", target, 3.0, 1.0)).await;
    // The vehicle receives the goto as a MAVLink position target...
    let t = peer.expect("position_target", 60).await;
    let lat = t["lat_int"].as_f64().unwrap() / 1e7;
    assert!((lat - target.latitude_deg).abs() < 1e-6, "{t}");
    // ...and its progress comes back as task status.
    eventually(60, "the goto accepted by the vehicle", || {
        h.task("cli-goto-1").filter(|t| {
            matches!(
                t.state,
                TaskState::Accepted | TaskState::Running | TaskState::Done
            )
        })
    })
    .await;
    stop_proxy(proxy).await;
    peer.kill().await;
    station.shutdown.cancel();
    station.task.await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_imc_proxy_command_joins_a_dune_auv_to_the_station() {
    let args = strings(&["--port", "0", "--speedup", "10", "--lifetime", "600"]);
    // The peer picks its port and says which; the proxy is told where the vehicle is.
    let Some(mut peer) = start_peer("imc_auv_peer.py", "imcpy", &args) else {
        return;
    };
    let station = start_station(50);
    let h = station.handle.clone();
    let port = peer.expect("listening", 60).await["port"].as_u64().unwrap();
    let vehicle = format!("127.0.0.1:{port}");
    let proxy = start_proxy(
        "imc",
        "lauv-1",
        50,
        &["--address", &vehicle, "--bind", "127.0.0.1:0"],
    );

    // Telemetry: where imcpy's own toWGS84 puts the vehicle, its depth and its fuel.
    let truth = peer.expect("truth", 60).await;
    let s = telemetry(&h, "lauv-1").await;
    let lat = truth["lat_deg"].as_f64().unwrap();
    let lon = truth["lon_deg"].as_f64().unwrap();
    assert!((s.latitude_deg - lat).abs() < 1e-6, "{s:?} vs {truth}");
    assert!((s.longitude_deg - lon).abs() < 1e-6, "{s:?} vs {truth}");
    assert!((s.depth_m - 2.0).abs() < 1e-3, "{s:?}");
    assert!((s.battery_pct - 87.5).abs() < 1e-3, "{s:?}");

    // A goto from the station reaches the vehicle as a PlanControl start whose inline plan
    // is one Goto, in radians on the wire (the peer prints degrees), depth in z units 1.
    let target = GeoPoint {
        latitude_deg: 41.1857,
        longitude_deg: -8.7058,
    };
    dispatch(&h, goto("imc-goto-1", "lauv-1", target, 4.0, 1.5)).await;
    let plan = peer.expect("plan", 60).await;
    assert_eq!(plan["plan_id"], "imc-goto-1", "{plan}");
    let m = &plan["maneuvers"][0];
    assert_eq!(m["type"], "Goto", "{plan}");
    assert!((m["lat_deg"].as_f64().unwrap() - target.latitude_deg).abs() < 1e-9);
    assert!((m["lon_deg"].as_f64().unwrap() - target.longitude_deg).abs() < 1e-9);
    assert_eq!(
        (m["z"].as_f64(), m["z_units"].as_u64()),
        (Some(4.0), Some(1))
    );
    assert_eq!(m["speed"].as_f64(), Some(1.5));

    // The vehicle's reply and PlanControlState come back as task status.
    let t = finished(&h, "imc-goto-1", 120).await;
    assert_eq!(t.state, TaskState::Done, "{t:?}");
    peer.expect("plan_done", 30).await;
    assert_accepted_running_done(&recorded_states(&h, "imc-goto-1").await);

    stop_proxy(proxy).await;
    peer.kill().await;
    station.shutdown.cancel();
    station.task.await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_ros2_proxy_command_joins_a_ros2_vehicle_to_the_station() {
    const DOMAIN: u16 = 51;
    let args = strings(&[
        "--domain",
        &DOMAIN.to_string(),
        "--namespace",
        "bluerov",
        "--lifetime",
        "600",
    ]);
    let Some(mut peer) = start_peer("ros2_vehicle_peer.py", "cyclonedds", &args) else {
        return;
    };
    let station = start_station(DOMAIN);
    let h = station.handle.clone();
    let datum = GeoPoint {
        latitude_deg: 59.9,
        longitude_deg: 10.7,
    };
    let frame = EnuFrame::new(datum);
    // The goal frame's origin must be the peer's: the proxy's full settings, as a file.
    let settings = station.dir.path().join("ros2-proxy.toml");
    std::fs::write(
        &settings,
        format!(
            "datum = {{ latitude_deg = {}, longitude_deg = {} }}\n",
            datum.latitude_deg, datum.longitude_deg
        ),
    )
    .unwrap();
    peer.expect("ready", 60).await;
    let proxy = start_proxy(
        "ros2",
        "auv-ros",
        DOMAIN,
        &[
            "--namespace",
            "bluerov",
            "--proxy-config",
            settings.to_str().unwrap(),
        ],
    );

    // Telemetry: the fix (10 m east, 20 m south of the datum), depth from odometry z,
    // battery from the BatteryState fraction.
    let s = telemetry(&h, "auv-ros").await;
    let start = frame.to_geo(10.0, -20.0);
    assert!((s.latitude_deg - start.latitude_deg).abs() < 1e-7, "{s:?}");
    assert!(
        (s.longitude_deg - start.longitude_deg).abs() < 1e-7,
        "{s:?}"
    );
    assert!((s.depth_m - 2.5).abs() < 1e-6, "{s:?}");
    assert!((s.battery_pct - 64.0).abs() < 1e-3, "{s:?}");

    // A goto from the station reaches the vehicle as a PoseStamped goal in the ENU frame.
    // ROS 2 topics have no acknowledgement, so the proxy refuses a goal nobody subscribes
    // to yet; discovery of the goal reader can trail the telemetry by a moment, so a goto
    // refused for that alone is dispatched again under a new id.
    let target = frame.to_geo(40.0, 30.0);
    let deadline = tokio::time::Instant::now() + Duration::from_secs(60);
    let mut attempt = 0;
    let task_id = loop {
        attempt += 1;
        let id = format!("ros2-goto-{attempt}");
        dispatch(&h, goto(&id, "auv-ros", target, 4.0, 1.0)).await;
        let t = eventually(60, &format!("{id} taken or refused"), || {
            h.task(&id).filter(|t| {
                matches!(
                    t.state,
                    TaskState::Accepted | TaskState::Running | TaskState::Done | TaskState::Failed
                )
            })
        })
        .await;
        if t.state != TaskState::Failed {
            break id;
        }
        assert!(
            t.message.contains("nothing subscribes") && tokio::time::Instant::now() < deadline,
            "{t:?}"
        );
    };
    let goal = peer.expect("goal", 60).await;
    assert_eq!(goal["frame_id"], "map", "{goal}");
    let (x, y) = (goal["x"].as_f64().unwrap(), goal["y"].as_f64().unwrap());
    assert!((x - 40.0).abs() < 1e-6 && (y - 30.0).abs() < 1e-6, "{goal}");
    assert_eq!(
        goal["z"].as_f64(),
        Some(-4.0),
        "z up: 4 m deep is -4: {goal}"
    );

    // Progress (from the fix and odometry) and arrival come back as task status.
    let t = finished(&h, &task_id, 120).await;
    assert_eq!(
        (t.state, t.message.as_str()),
        (TaskState::Done, "arrived"),
        "{t:?}"
    );
    let states = recorded_states(&h, &task_id).await;
    assert_accepted_running_done(&states);
    assert!(
        states
            .iter()
            .any(|(s, p)| *s == TaskState::Running && *p > 0.0 && *p < 100.0),
        "progress under way: {states:?}"
    );

    stop_proxy(proxy).await;
    peer.kill().await;
    station.shutdown.cancel();
    station.task.await.unwrap();
}
