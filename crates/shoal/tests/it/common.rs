//! Helpers shared by the end-to-end tests.

use std::sync::Arc;
use std::time::Duration;

use shoal_dds::{DdsConfig, PubSub};
use shoal_history::{History, HistoryConfig};
use shoal_station::{Station, StationConfig, StationHandle, StationReport};
use tokio_util::sync::CancellationToken;

/// A station running in this process on its own DDS domain, with a temporary history.
pub struct TestStation {
    pub handle: StationHandle,
    pub shutdown: CancellationToken,
    pub task: tokio::task::JoinHandle<StationReport>,
    pub db: std::path::PathBuf,
    pub dir: tempfile::TempDir,
}

pub fn dds(domain_id: u16) -> Arc<PubSub> {
    Arc::new(
        PubSub::new(&DdsConfig {
            domain_id,
            ..DdsConfig::default()
        })
        .unwrap(),
    )
}

pub fn start_station(domain_id: u16) -> TestStation {
    start_station_in(domain_id, tempfile::tempdir().unwrap())
}

/// Like [`start_station`], with the history and rules files in `dir` (to restart on them).
pub fn start_station_in(domain_id: u16, dir: tempfile::TempDir) -> TestStation {
    let db = dir.path().join("history.db");
    let history = History::open(&HistoryConfig {
        path: db.clone(),
        ..HistoryConfig::default()
    })
    .unwrap();
    let config = StationConfig {
        summary_interval_s: 0.0,
        rules_path: dir.path().join("rules.json"),
        ..StationConfig::default()
    };
    let station = Station::new(config, dds(domain_id), history).unwrap();
    let handle = station.handle();
    let shutdown = CancellationToken::new();
    let s = shutdown.clone();
    let task = tokio::spawn(async move { station.run(s).await.unwrap() });
    TestStation {
        handle,
        shutdown,
        task,
        db,
        dir,
    }
}

/// Polls `check` every 100 ms until it returns Some, for at most `secs` seconds.
pub async fn eventually<T>(secs: u64, what: &str, mut check: impl FnMut() -> Option<T>) -> T {
    let deadline = tokio::time::Instant::now() + Duration::from_secs(secs);
    loop {
        if let Some(v) = check() {
            return v;
        }
        assert!(
            tokio::time::Instant::now() < deadline,
            "timed out after {secs} s waiting for {what}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// An AUV's announcement (max 2 m/s, goto-capable, on IP), announced now.
pub fn auv_announcement(id: &str) -> shoal_model::VehicleAnnouncement {
    shoal_model::VehicleAnnouncement {
        vehicle_id: id.into(),
        name: format!("test {id}"),
        kind: shoal_model::VehicleKind::Auv,
        vendor: "test".into(),
        capabilities: vec!["goto".into()],
        sensors: vec![],
        links: vec![shoal_model::LinkKind::Ip],
        max_speed_mps: 2.0,
        timestamp_ms: shoal_model::now_ms(),
    }
}

/// A minimal HTTP/1.0 GET over a plain socket, to keep an HTTP client out of the test deps.
pub fn http_get(port: u16, path: &str) -> std::io::Result<String> {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(("127.0.0.1", port))?;
    s.set_read_timeout(Some(Duration::from_secs(5)))?;
    write!(s, "GET {path} HTTP/1.0\r\nHost: localhost\r\n\r\n")?;
    let mut out = String::new();
    s.read_to_string(&mut out)?;
    Ok(out
        .split_once("\r\n\r\n")
        .map(|(_, b)| b.to_string())
        .unwrap_or_default())
}

/// A minimal HTTP/1.0 POST of a JSON body; returns the status line's code and the body.
pub fn http_post(port: u16, path: &str, json: &str) -> std::io::Result<(u16, String)> {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(("127.0.0.1", port))?;
    s.set_read_timeout(Some(Duration::from_secs(10)))?;
    write!(
        s,
        "POST {path} HTTP/1.0\r\nHost: localhost\r\ncontent-type: application/json\r\ncontent-length: {}\r\n\r\n{json}",
        json.len()
    )?;
    let mut out = String::new();
    s.read_to_string(&mut out)?;
    let code = out
        .split(' ')
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or(0);
    Ok((
        code,
        out.split_once("\r\n\r\n")
            .map(|(_, b)| b.to_string())
            .unwrap_or_default(),
    ))
}

/// A free TCP port on 127.0.0.1 (bound and released), for a child process to listen on.
///
/// Taken below the kernel's ephemeral range (32768 and up), so no outgoing connection of
/// another test can take it between this check and the child's bind; a counter keeps two
/// tests of this binary from drawing the same one.
pub fn free_port() -> u16 {
    use std::sync::atomic::{AtomicU16, Ordering};
    static NEXT: AtomicU16 = AtomicU16::new(0);
    let seed = (std::process::id() % 600) as u16 * 20;
    loop {
        let port = 20_000 + (seed + NEXT.fetch_add(1, Ordering::Relaxed) % 12_000) % 12_000;
        if std::net::TcpListener::bind(("127.0.0.1", port)).is_ok() {
            return port;
        }
    }
}
