//! `shoal vehicle --proxy mavlink`: the binary joins an ArduSub-like vehicle (PyPI
//! pymavlink, `tests/peers/ardusub_peer.py`) to a station, and a station task reaches the
//! vehicle as MAVLink commands. Domain 55.

use std::process::Stdio;
use std::time::Duration;

use shoal_model::{GeoPoint, Task, TaskAssignment, TaskState, now_ms};
use tokio::io::AsyncBufReadExt;

use crate::common::{eventually, start_station};

fn python() -> Option<std::path::PathBuf> {
    let py = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../.venv/bin/python");
    let ok = std::process::Command::new(&py)
        .args(["-c", "import pymavlink"])
        .output()
        .is_ok_and(|o| o.status.success());
    if ok {
        return Some(py);
    }
    assert!(
        std::env::var("SHOAL_INTEROP_REQUIRED").as_deref() != Ok("1"),
        "pymavlink is required but missing in .venv (scripts/install-proxy-peers.sh)"
    );
    eprintln!("SKIPPED: no .venv with pymavlink");
    None
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_mavlink_proxy_command_joins_an_ardusub_vehicle_to_the_station() {
    let Some(py) = python() else { return };
    let station = start_station(55);
    let h = station.handle.clone();
    let port = std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let mut proxy = tokio::process::Command::new(env!("CARGO_BIN_EXE_shoal"))
        .args([
            "vehicle",
            "--proxy",
            "mavlink",
            "--id",
            "bluerov-1",
            "--address",
            &format!("udpin:127.0.0.1:{port}"),
            "--rate",
            "2",
            "--exit-on-stdin-close",
        ])
        .env("SHOAL_DDS__DOMAIN_ID", "55")
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .stderr(Stdio::inherit())
        .kill_on_drop(true)
        .spawn()
        .unwrap();
    let peer_script =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/peers/ardusub_peer.py");
    let mut peer = tokio::process::Command::new(py)
        .arg(peer_script)
        .args([
            "--port",
            &port.to_string(),
            "--lat",
            "63.44",
            "--lon",
            "10.4",
        ])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .kill_on_drop(true)
        .spawn()
        .unwrap();
    let mut lines = tokio::io::BufReader::new(peer.stdout.take().unwrap()).lines();

    let v = eventually(40, "bluerov-1 registered with a state", || {
        h.vehicle("bluerov-1").filter(|v| v.latest.is_some())
    })
    .await;
    let s = v.latest.unwrap();
    assert!((s.latitude_deg - 63.44).abs() < 1e-3, "{s:?}");
    assert!(
        s.depth_m > 0.0,
        "depth from relative_alt below the surface: {s:?}"
    );

    let task = TaskAssignment::new(
        "cli-goto-1",
        "",
        "bluerov-1",
        now_ms(),
        &Task::GotoWaypoint {
            target: GeoPoint {
                latitude_deg: 63.4402,
                longitude_deg: 10.4,
            },
            depth_m: Some(3.0),
            altitude_m: None,
            speed_mps: 1.0,
        },
    );
    h.dispatch(task).await.unwrap();
    // The vehicle receives the goto as a MAVLink position target...
    let target = tokio::time::timeout(Duration::from_secs(30), async {
        while let Ok(Some(l)) = lines.next_line().await {
            if l.contains("position_target") {
                return l;
            }
        }
        String::new()
    })
    .await
    .expect("the peer got no position target");
    assert!(target.contains("position_target"), "{target}");
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
    drop(proxy.stdin.take());
    let status = tokio::time::timeout(Duration::from_secs(15), proxy.wait())
        .await
        .expect("the proxy stops when its stdin closes")
        .unwrap();
    assert!(status.success(), "{status:?}");
    drop(peer.stdin.take());
    let _ = peer.wait().await;
    station.shutdown.cancel();
    station.task.await.unwrap();
}
