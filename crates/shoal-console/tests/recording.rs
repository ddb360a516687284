//! `POST /api/recordings/tracks`: an MCAP recording opened in the replay, through a real
//! server on `127.0.0.1:0` with logins on. The files are written in each test with the
//! recorder's own `RecordWriter`. Over a station core that publishes to no bus (no DDS
//! participant: no network namespace needed).

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::net::SocketAddr;
use std::sync::Arc;

use serde_json::{Value, json};
use shoal_console::{AuthConfig, ConsoleConfig, LimitsConfig};
use shoal_history::{History, HistoryConfig};
use shoal_model::{
    Event, LinkKind, StateVector, TaskAssignment, VehicleAnnouncement, VehicleKind, now_ms,
};
use shoal_recorder::{RecordWriter, RecorderConfig, Sample};
use shoal_station::{Outbox, PublishError, StationConfig, StationHandle};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio_util::sync::CancellationToken;

const PATH: &str = "/api/recordings/tracks";
const TOKEN: &str = "shoal_test_token_recording_0123456789abcdef01";

/// A bus that takes everything and has no readers.
#[derive(Debug)]
struct NoBus;

impl Outbox for NoBus {
    fn publish_task(&self, _: TaskAssignment) -> Result<(), PublishError> {
        Ok(())
    }
    fn retire_task(&self, _: &TaskAssignment) -> Result<(), PublishError> {
        Ok(())
    }
    fn publish_event(&self, _: Event) -> Result<(), PublishError> {
        Ok(())
    }
    fn task_readers(&self) -> i32 {
        0
    }
}

/// A station and its console served on a loopback socket, logins on.
struct Server {
    addr: SocketAddr,
    handle: StationHandle,
    shutdown: CancellationToken,
    dir: tempfile::TempDir,
    _history: History,
}

impl Drop for Server {
    fn drop(&mut self) {
        self.shutdown.cancel();
    }
}

async fn serve(limits: LimitsConfig) -> Server {
    let dir = tempfile::tempdir().unwrap();
    let history = History::open(&HistoryConfig {
        path: dir.path().join("history.db"),
        ..HistoryConfig::default()
    })
    .unwrap();
    let station = StationConfig {
        summary_interval_s: 0.0,
        rules_path: dir.path().join("rules.json"),
        ..StationConfig::default()
    };
    let handle = StationHandle::new(station, &history, Arc::new(NoBus)).unwrap();
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let config = ConsoleConfig {
        limits,
        auth: AuthConfig {
            users_path: dir.path().join("users.json"),
            initial_admin_password: "the admin's password".into(),
            initial_admin_token: TOKEN.into(),
            ..AuthConfig::default()
        },
        ..ConsoleConfig::default()
    };
    let shutdown = CancellationToken::new();
    let (h, stop) = (handle.clone(), shutdown.clone());
    tokio::spawn(async move { shoal_console::serve_with(listener, h, config, stop).await });
    let server = Server {
        addr,
        handle,
        shutdown,
        dir,
        _history: history,
    };
    // Served once the first answer comes.
    for _ in 0..200 {
        if TcpStream::connect(addr).await.is_ok() {
            break;
        }
        tokio::time::sleep(std::time::Duration::from_millis(10)).await;
    }
    server
}

/// How the body is sent.
#[derive(Clone, Copy)]
enum Framing {
    ContentLength,
    Chunked,
}

/// One HTTP/1.1 request on its own connection; the status and the JSON body. The body is
/// written while the answer is read, so that a refusal before the body is read is seen.
async fn send(
    addr: SocketAddr,
    method: &str,
    path: &str,
    headers: &[(&str, &str)],
    body: Vec<u8>,
    framing: Framing,
) -> (u16, Value) {
    let tcp = TcpStream::connect(addr).await.unwrap();
    let (mut rd, mut wr) = tcp.into_split();
    let mut head = format!("{method} {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n");
    for (k, v) in headers {
        head.push_str(&format!("{k}: {v}\r\n"));
    }
    match framing {
        Framing::ContentLength => head.push_str(&format!("Content-Length: {}\r\n", body.len())),
        Framing::Chunked => head.push_str("Transfer-Encoding: chunked\r\n"),
    }
    head.push_str("\r\n");
    let writer = tokio::spawn(async move {
        wr.write_all(head.as_bytes()).await?;
        match framing {
            Framing::ContentLength => wr.write_all(&body).await?,
            Framing::Chunked => {
                for chunk in body.chunks(1024) {
                    wr.write_all(format!("{:x}\r\n", chunk.len()).as_bytes())
                        .await?;
                    wr.write_all(chunk).await?;
                    wr.write_all(b"\r\n").await?;
                }
                wr.write_all(b"0\r\n\r\n").await?;
            }
        }
        wr.flush().await?;
        // Keeps the write half open until the answer was read (dropping it would close).
        Ok::<_, std::io::Error>(wr)
    });
    let mut all = Vec::new();
    // The server may reset the connection after answering early: what came is kept.
    let _ = rd.read_to_end(&mut all).await;
    let _ = writer.await;
    let text = String::from_utf8_lossy(&all).into_owned();
    let (head, body) = text
        .split_once("\r\n\r\n")
        .unwrap_or_else(|| panic!("no answer: {text:?}"));
    let status: u16 = head
        .split(' ')
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("status line: {head}"));
    let chunked = head
        .to_ascii_lowercase()
        .contains("transfer-encoding: chunked");
    let body = if chunked {
        dechunk(body)
    } else {
        body.to_owned()
    };
    let json = serde_json::from_str(&body)
        .unwrap_or_else(|e| panic!("{method} {path} answered {status}, not JSON ({e}): {body}"));
    (status, json)
}

fn dechunk(mut s: &str) -> String {
    let mut out = String::new();
    while let Some((size, rest)) = s.split_once("\r\n") {
        let n = usize::from_str_radix(size.trim(), 16).unwrap();
        if n == 0 {
            break;
        }
        out.push_str(&rest[..n]);
        s = &rest[n + 2..];
    }
    out
}

fn bearer(token: &str) -> String {
    format!("Bearer {token}")
}

/// POSTs `file` as a recording with `token`.
async fn open(addr: SocketAddr, token: &str, file: &[u8]) -> (u16, Value) {
    send(
        addr,
        "POST",
        PATH,
        &[
            ("Authorization", &bearer(token)),
            ("Content-Type", "application/octet-stream"),
        ],
        file.to_vec(),
        Framing::ContentLength,
    )
    .await
}

/// A viewer's API token, made by the admin through the API.
async fn viewer_token(addr: SocketAddr) -> String {
    let (status, body) = send(
        addr,
        "POST",
        "/api/auth/tokens",
        &[
            ("Authorization", &bearer(TOKEN)),
            ("Content-Type", "application/json"),
        ],
        json!({"name": "replay-viewer", "role": "viewer"})
            .to_string()
            .into_bytes(),
        Framing::ContentLength,
    )
    .await;
    assert_eq!(status, 201, "{body}");
    body["token"].as_str().unwrap().to_owned()
}

fn state(id: &str, t: i64, lat: f64) -> StateVector {
    StateVector {
        vehicle_id: id.into(),
        timestamp_ms: t,
        latitude_deg: lat,
        longitude_deg: 10.37,
        depth_m: 4.0,
        altitude_m: -1.0,
        speed_mps: 1.0,
        yaw_deg: 90.0,
        pitch_deg: 0.0,
        roll_deg: 0.0,
        battery_pct: 80.0,
    }
}

fn announcement(id: &str, kind: VehicleKind) -> VehicleAnnouncement {
    VehicleAnnouncement {
        vehicle_id: id.into(),
        name: id.into(),
        kind,
        vendor: "recording test".into(),
        capabilities: vec!["goto".into()],
        sensors: vec![],
        links: vec![LinkKind::Ip],
        max_speed_mps: 2.0,
        timestamp_ms: now_ms(),
    }
}

/// Writes MCAP files with the recorder's writer.
struct Recording {
    dir: tempfile::TempDir,
    writer: RecordWriter,
}

impl Recording {
    fn new() -> Self {
        let dir = tempfile::tempdir().unwrap();
        let writer = RecordWriter::new(&RecorderConfig {
            directory: dir.path().to_path_buf(),
            ..RecorderConfig::default()
        })
        .unwrap();
        Self { dir, writer }
    }

    fn write(&mut self, sample: &Sample, at_ms: i64) {
        let ns = u64::try_from(at_ms).unwrap() * 1_000_000;
        self.writer
            .write(sample.topic(), ns, ns, &sample.encode().unwrap())
            .unwrap();
    }

    /// The chunk written out; the file's length so far.
    fn flush(&mut self) -> u64 {
        self.writer.flush().unwrap();
        self.writer.stats().bytes
    }

    /// The file, closed (summary and footer written).
    fn finish(mut self) -> Vec<u8> {
        self.writer.close().unwrap();
        assert_eq!(self.writer.files().len(), 1, "{:?}", self.dir.path());
        std::fs::read(&self.writer.files()[0]).unwrap()
    }
}

fn rows(vehicle: &Value) -> &Vec<Value> {
    vehicle["rows"].as_array().unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_recording_opens_as_each_vehicles_track_for_a_viewer() {
    let s = serve(LimitsConfig::default()).await;
    let t0 = now_ms() - 60_000;
    let mut rec = Recording::new();
    rec.write(
        &Sample::VehicleAnnouncement(announcement("glider-1", VehicleKind::Glider)),
        t0,
    );
    for i in 0..20 {
        let t = t0 + i * 1000;
        rec.write(&Sample::StateVector(state("glider-1", t, 63.44)), t);
        rec.write(
            &Sample::StateVector(state("auv-9", t + 500, 63.45 + i as f64 * 1e-4)),
            t + 500,
        );
    }
    // Out of range: decodes, but is not valid; skipped as replay would.
    rec.write(&Sample::StateVector(state("auv-9", t0, 95.0)), t0);
    let file = rec.finish();

    // A viewer may open it: it changes nothing.
    let viewer = viewer_token(s.addr).await;
    let (status, body) = send(
        s.addr,
        "POST",
        PATH,
        &[
            ("Authorization", &bearer(&viewer)),
            ("Content-Type", "application/x-mcap"),
        ],
        file.clone(),
        Framing::ContentLength,
    )
    .await;
    assert_eq!(status, 200, "{body}");
    assert_eq!(body["error"], Value::Null);
    assert_eq!(body["messages"], 42, "{body}");
    assert_eq!(body["state_vectors"], 40);
    assert_eq!(body["skipped"], 1);
    assert_eq!(body["thinned"], false);
    assert_eq!(body["omitted"], 0);
    assert_eq!(body["from_ms"], t0);
    assert_eq!(body["to_ms"], t0 + 19_500);
    let vehicles = body["vehicles"].as_array().unwrap();
    let ids: Vec<&str> = vehicles
        .iter()
        .map(|v| v["vehicle_id"].as_str().unwrap())
        .collect();
    assert_eq!(ids, ["auv-9", "glider-1"]);
    // No announcement recorded and unknown to the station: no kind.
    assert_eq!(vehicles[0]["kind"], Value::Null);
    assert_eq!(vehicles[1]["kind"], "glider");
    assert_eq!(vehicles[0]["state_vectors"], 20);
    // The rows are the track endpoint's state vectors, by time.
    let auv = rows(&vehicles[0]);
    assert_eq!(auv.len(), 20);
    assert_eq!(
        serde_json::from_value::<StateVector>(auv[3].clone()).unwrap(),
        state("auv-9", t0 + 3500, 63.45 + 3.0 * 1e-4)
    );
    assert!(
        auv.windows(2)
            .all(|w| w[0]["timestamp_ms"].as_i64() < w[1]["timestamp_ms"].as_i64())
    );

    // Once the station knows the vehicle, its kind comes from the fleet.
    s.handle
        .register_vehicle(announcement("auv-9", VehicleKind::Auv))
        .unwrap();
    let (status, body) = open(s.addr, TOKEN, &file).await;
    assert_eq!(status, 200, "{body}");
    assert_eq!(body["vehicles"][0]["kind"], "auv");
    // Sent in chunks (no Content-Length), it reads the same.
    let (status, chunked) = send(
        s.addr,
        "POST",
        PATH,
        &[("Authorization", &bearer(TOKEN))],
        file,
        Framing::Chunked,
    )
    .await;
    assert_eq!(status, 200, "{chunked}");
    assert_eq!(chunked, body);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_truncated_recording_gives_what_was_readable_and_where_reading_stopped() {
    let s = serve(LimitsConfig::default()).await;
    let t0 = now_ms() - 60_000;
    let mut rec = Recording::new();
    for i in 0..10 {
        rec.write(&Sample::StateVector(state("usv-1", t0 + i, 63.44)), t0 + i);
    }
    let first_chunk_end = rec.flush();
    for i in 10..20 {
        rec.write(&Sample::StateVector(state("usv-1", t0 + i, 63.44)), t0 + i);
    }
    let second_chunk_end = rec.flush();
    let file = rec.finish();
    assert!(second_chunk_end > first_chunk_end + 20);
    // A recorder killed while writing its second chunk.
    let cut = usize::try_from((first_chunk_end + second_chunk_end) / 2).unwrap();
    let (status, body) = open(s.addr, TOKEN, &file[..cut]).await;
    assert_eq!(status, 200, "{body}");
    let error = body["error"].as_str().unwrap();
    assert!(
        error.contains("truncated")
            && error.contains(&format!("byte offset {first_chunk_end}"))
            && error.contains(&format!("byte {cut}")),
        "{error}"
    );
    assert_eq!(body["messages"], 10);
    let track = rows(&body["vehicles"][0]);
    assert_eq!(track.len(), 10);
    assert_eq!(track[9]["timestamp_ms"], t0 + 9);

    // Cut inside the first chunk: nothing readable, 400 with the reason.
    let (status, body) = open(s.addr, TOKEN, &file[..40]).await;
    assert_eq!(status, 400, "{body}");
    let error = body["error"].as_str().unwrap();
    assert!(
        error.contains("truncated") && error.contains("offset"),
        "{error}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn garbage_an_empty_body_and_another_media_type_are_refused() {
    let s = serve(LimitsConfig::default()).await;
    let (status, body) = open(s.addr, TOKEN, b"GIF89a, not a recording at all").await;
    assert_eq!(status, 400, "{body}");
    let error = body["error"].as_str().unwrap();
    assert!(
        error.contains("no Shoal message") && error.contains("byte offset 0"),
        "{error}"
    );

    let (status, body) = open(s.addr, TOKEN, b"").await;
    assert_eq!(status, 400, "{body}");
    assert!(body["error"].as_str().unwrap().contains("empty"), "{body}");

    let (status, body) = send(
        s.addr,
        "POST",
        PATH,
        &[
            ("Authorization", &bearer(TOKEN)),
            ("Content-Type", "application/json"),
        ],
        b"{}".to_vec(),
        Framing::ContentLength,
    )
    .await;
    assert_eq!(status, 415, "{body}");
    assert!(
        body["error"]
            .as_str()
            .unwrap()
            .contains("application/octet-stream"),
        "{body}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_recording_over_max_recording_bytes_is_413_and_counted() {
    assert_eq!(LimitsConfig::default().max_recording_bytes, 64 << 20);
    let s = serve(LimitsConfig {
        max_recording_bytes: 4096,
        ..LimitsConfig::default()
    })
    .await;
    let t0 = now_ms() - 60_000;
    let mut rec = Recording::new();
    for i in 0..400 {
        rec.write(
            &Sample::StateVector(state("auv-1", t0 + i * 1000, 63.44 + i as f64 * 1e-5)),
            t0 + i * 1000,
        );
    }
    let file = rec.finish();
    assert!(file.len() > 4096, "{}", file.len());
    // Refused from its Content-Length, before the body is read...
    let (status, body) = open(s.addr, TOKEN, &file).await;
    assert_eq!(status, 413, "{body}");
    let error = body["error"].as_str().unwrap();
    assert!(
        error.contains("max_recording_bytes") && error.contains("4096"),
        "{error}"
    );
    // ...and, sent without one, once it has grown past the limit.
    let (status, body) = send(
        s.addr,
        "POST",
        PATH,
        &[("Authorization", &bearer(TOKEN))],
        file,
        Framing::Chunked,
    )
    .await;
    assert_eq!(status, 413, "{body}");
    assert!(
        body["error"]
            .as_str()
            .unwrap()
            .contains("max_recording_bytes"),
        "{body}"
    );
    let (_, stats) = send(
        s.addr,
        "GET",
        "/api/stats",
        &[("Authorization", &bearer(TOKEN))],
        Vec::new(),
        Framing::ContentLength,
    )
    .await;
    assert_eq!(stats["http"]["bodies_too_large"], 2, "{stats}");
    assert_eq!(stats["http"]["recordings_refused"], 0, "{stats}");
    // The other bodies keep their own, smaller limit.
    assert_eq!(LimitsConfig::default().max_body_bytes, 1 << 20);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_long_track_is_thinned_evenly_and_says_so() {
    let s = serve(LimitsConfig::default()).await;
    let t0 = now_ms() - 3_600_000;
    let mut rec = Recording::new();
    let n = 12_345;
    for i in 0..n {
        let t = t0 + i * 100;
        rec.write(&Sample::StateVector(state("auv-1", t, 63.44)), t);
    }
    let file = rec.finish();
    let (status, body) = open(s.addr, TOKEN, &file).await;
    assert_eq!(status, 200, "{body}");
    assert_eq!(body["thinned"], true);
    let v = &body["vehicles"][0];
    assert_eq!(v["state_vectors"], n);
    let track = rows(v);
    assert_eq!(track.len(), 10_000);
    assert_eq!(track[0]["timestamp_ms"], t0);
    assert_eq!(track[9_999]["timestamp_ms"], t0 + (n - 1) * 100);
    assert_eq!(body["to_ms"], t0 + (n - 1) * 100);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn without_valid_credentials_a_recording_is_not_read() {
    let s = serve(LimitsConfig::default()).await;
    let mut rec = Recording::new();
    let t = now_ms();
    rec.write(&Sample::StateVector(state("auv-1", t, 63.44)), t);
    let file = rec.finish();
    let (status, body) = send(
        s.addr,
        "POST",
        PATH,
        &[("Content-Type", "application/octet-stream")],
        file.clone(),
        Framing::ContentLength,
    )
    .await;
    assert_eq!(status, 401, "{body}");
    assert!(body["error"].is_string());
    let (status, _) = open(s.addr, "shoal_not_a_token", &file).await;
    assert_eq!(status, 401);
    // From another site's page, even with a token: 403 (a change-like method).
    let (status, _) = send(
        s.addr,
        "POST",
        PATH,
        &[
            ("Authorization", &bearer(TOKEN)),
            ("Origin", "https://elsewhere.example"),
        ],
        file,
        Framing::ContentLength,
    )
    .await;
    assert_eq!(status, 403);
    assert!(s.dir.path().join("users.json").exists());
}
