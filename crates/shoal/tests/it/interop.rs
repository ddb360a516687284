//! Foreign DDS implementations against the station, in both directions.
//!
//! Peers (installed by `scripts/install-test-deps.sh`, run with the names and types of
//! `idl/shoal.idl`):
//! - Cyclone DDS: `tests/interop/peers/cyclone_peer.py` (PyPI `cyclonedds`)
//! - RTI Connext: `tests/interop/peers/rti_peer.py` (PyPI `rticonnextdds-connector`)
//! - Fast DDS 2.9: `tests/interop/build/fastdds_peer` (Debian `libfastrtps-dev`)
//!
//! For each: a foreign publisher's state vectors reach the station; a foreign subscriber
//! receives a task the station publishes; a late-joining foreign subscriber still gets
//! the transient-local task. A peer that is not installed is skipped with its reason,
//! unless `SHOAL_INTEROP_REQUIRED=1` (the README's test command sets it), when it fails.

use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::Duration;

use shoal_dds::{Priority, WriterOptions};
use shoal_model::{
    GeoPoint, LinkKind, Task, TaskAssignment, VehicleAnnouncement, VehicleKind, now_ms,
};
use tokio::io::AsyncBufReadExt;

use crate::common::{TestStation, dds, eventually, start_station};

#[derive(Debug, Clone, Copy)]
enum Vendor {
    Cyclone,
    Rti,
    FastDds,
}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

impl Vendor {
    /// The command that runs this vendor's peer, or why it cannot run here.
    fn command(self) -> Result<tokio::process::Command, String> {
        let root = repo();
        let python = root.join(".venv/bin/python");
        let (program, script) = match self {
            Self::Cyclone => (
                python,
                Some(root.join("tests/interop/peers/cyclone_peer.py")),
            ),
            Self::Rti => (python, Some(root.join("tests/interop/peers/rti_peer.py"))),
            Self::FastDds => (root.join("tests/interop/build/fastdds_peer"), None),
        };
        if !program.exists() {
            return Err(format!(
                "{} not found: run scripts/install-test-deps.sh",
                program.display()
            ));
        }
        let mut cmd = tokio::process::Command::new(program);
        if let Some(s) = script {
            cmd.arg(s);
        }
        cmd.kill_on_drop(true)
            .stdin(Stdio::null())
            .stderr(Stdio::inherit());
        Ok(cmd)
    }

    fn name(self) -> &'static str {
        match self {
            Self::Cyclone => "cyclonedds",
            Self::Rti => "rti-connext",
            Self::FastDds => "fastdds",
        }
    }
}

fn peer(vendor: Vendor) -> Option<tokio::process::Command> {
    match vendor.command() {
        Ok(c) => Some(c),
        Err(reason) => {
            assert!(
                std::env::var("SHOAL_INTEROP_REQUIRED").as_deref() != Ok("1"),
                "interop peer {} is required but missing: {reason}",
                vendor.name()
            );
            eprintln!("SKIPPED interop with {}: {reason}", vendor.name());
            None
        }
    }
}

/// Registers `vehicle_id` at the station through a Shoal writer, as its proxy would.
async fn register(
    station: &TestStation,
    domain: u16,
    vehicle_id: &str,
) -> std::sync::Arc<shoal_dds::PubSub> {
    let p = dds(domain);
    let w = p
        .writer::<VehicleAnnouncement>(WriterOptions::new(Priority::Control))
        .unwrap();
    w.write(VehicleAnnouncement {
        vehicle_id: vehicle_id.into(),
        name: "interop target".into(),
        kind: VehicleKind::Auv,
        vendor: "interop".into(),
        capabilities: vec!["goto".into()],
        sensors: vec![],
        links: vec![LinkKind::Ip],
        max_speed_mps: 2.0,
        timestamp_ms: now_ms(),
    })
    .await
    .unwrap();
    let h = station.handle.clone();
    eventually(20, "the announcement", || h.vehicle(vehicle_id)).await;
    p
}

fn goto(task_id: &str, vehicle_id: &str) -> TaskAssignment {
    TaskAssignment::new(
        task_id,
        "interop-mission",
        vehicle_id,
        now_ms(),
        &Task::GotoWaypoint {
            target: GeoPoint {
                latitude_deg: 63.4412,
                longitude_deg: 10.4021,
            },
            depth_m: Some(12.5),
            altitude_m: None,
            speed_mps: 1.25,
        },
    )
}

/// Waits for the peer's first JSON line on stdout and checks it is the task.
async fn expect_task(child: &mut tokio::process::Child, task: &TaskAssignment) {
    let stdout = child.stdout.take().unwrap();
    let mut lines = tokio::io::BufReader::new(stdout).lines();
    let line = tokio::time::timeout(Duration::from_secs(60), lines.next_line())
        .await
        .expect("the foreign subscriber printed nothing in 60 s")
        .unwrap()
        .expect("the foreign subscriber exited without printing the task");
    let got: serde_json::Value =
        serde_json::from_str(&line).unwrap_or_else(|e| panic!("{e}: {line}"));
    assert_eq!(got["task_id"], task.task_id.as_str(), "{line}");
    assert_eq!(got["mission_id"], "interop-mission");
    assert_eq!(got["vehicle_id"], task.vehicle_id.as_str());
    assert_eq!(got["kind"], "GOTO_WAYPOINT");
    assert_eq!(got["issued_ms"], task.issued_ms);
    assert_eq!(got["area"][0]["latitude_deg"], 63.4412);
    assert_eq!(got["area"][0]["longitude_deg"], 10.4021);
    assert_eq!(got["depth_m"], 12.5);
    assert_eq!(got["altitude_m"], -1.0);
    assert_eq!(got["speed_mps"], 1.25);
    let status = tokio::time::timeout(Duration::from_secs(20), child.wait())
        .await
        .unwrap()
        .unwrap();
    assert!(status.success());
}

async fn foreign_state_reaches_station(vendor: Vendor, domain: u16) {
    let Some(mut cmd) = peer(vendor) else { return };
    let station = start_station(domain);
    let id = format!("{}-1", vendor.name().replace('-', ""));
    let mut child = cmd
        .args([
            "publish-state",
            "--vehicle-id",
            &id,
            "--count",
            "20",
            "--rate",
            "20",
            "--domain",
        ])
        .arg(domain.to_string())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let h = station.handle.clone();
    let v = eventually(90, "20 foreign state vectors", || {
        h.vehicle(&id).filter(|v| v.states_accepted >= 20)
    })
    .await;
    assert_eq!(v.states_accepted, 20);
    assert_eq!(v.announcement.vendor, vendor.name(), "vendor field");
    assert_eq!(h.stats().total_rejected(), 0, "{:?}", h.stats());
    let latest = v.latest.unwrap();
    assert!(
        (latest.latitude_deg - 43.0).abs() < 0.01 && latest.depth_m == 10.0,
        "{latest:?}"
    );
    let _ = tokio::time::timeout(Duration::from_secs(30), child.wait()).await;
    station.shutdown.cancel();
    station.task.await.unwrap();
}

async fn foreign_subscriber_gets_task(vendor: Vendor, domain: u16, late: bool) {
    let Some(mut cmd) = peer(vendor) else { return };
    let station = start_station(domain);
    let id = "target-1";
    let _proxy = register(&station, domain, id).await;
    let task = goto(
        &format!(
            "task-{}-{}",
            vendor.name(),
            if late { "late" } else { "live" }
        ),
        id,
    );
    cmd.args([
        "subscribe-task",
        "--vehicle-id",
        id,
        "--expect",
        "1",
        "--timeout",
        "60",
        "--domain",
    ])
    .arg(domain.to_string())
    .stdout(Stdio::piped());
    let mut child = if late {
        // Published before the subscriber exists: only transient-local durability delivers it.
        station.handle.dispatch(task.clone()).await.unwrap();
        tokio::time::sleep(Duration::from_millis(500)).await;
        cmd.spawn().unwrap()
    } else {
        let child = cmd.spawn().unwrap();
        let h = station.handle.clone();
        eventually(60, "the foreign reader to match the task writer", || {
            (h.task_readers() > 0).then_some(())
        })
        .await;
        station.handle.dispatch(task.clone()).await.unwrap();
        child
    };
    expect_task(&mut child, &task).await;
    station.shutdown.cancel();
    station.task.await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cyclone_publisher_reaches_station() {
    foreign_state_reaches_station(Vendor::Cyclone, 70).await;
}
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cyclone_subscriber_receives_task() {
    foreign_subscriber_gets_task(Vendor::Cyclone, 71, false).await;
}
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cyclone_late_joiner_receives_task() {
    foreign_subscriber_gets_task(Vendor::Cyclone, 72, true).await;
}
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rti_publisher_reaches_station() {
    foreign_state_reaches_station(Vendor::Rti, 73).await;
}
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rti_subscriber_receives_task() {
    foreign_subscriber_gets_task(Vendor::Rti, 74, false).await;
}
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rti_late_joiner_receives_task() {
    foreign_subscriber_gets_task(Vendor::Rti, 75, true).await;
}
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn fastdds_publisher_reaches_station() {
    foreign_state_reaches_station(Vendor::FastDds, 76).await;
}
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn fastdds_subscriber_receives_task() {
    foreign_subscriber_gets_task(Vendor::FastDds, 77, false).await;
}
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn fastdds_late_joiner_receives_task() {
    foreign_subscriber_gets_task(Vendor::FastDds, 78, true).await;
}
