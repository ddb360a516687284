//! Honest health, `/metrics` and the HTTP limits of `[console.limits]`, over a station
//! core that publishes to no bus (no DDS participant: no network namespace needed).
//! In-process requests (`tower::ServiceExt`) where the router is the subject; a real
//! server on `127.0.0.1:0` for what only sockets show (slow clients, WebSocket clients).
//!
//! Where new tests go: health and its thresholds, metrics, and any new limit here; API
//! behaviour in `api.rs`; the SPARQL protocol in `sparql_protocol.rs`.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::sync::Arc;
use std::time::{Duration, Instant};

use axum::Router;
use axum::body::Body;
use axum::http::{Request, StatusCode, header};
use http_body_util::BodyExt;
use serde_json::Value;
use shoal_console::{Auth, AuthConfig, ConsoleConfig, HealthConfig, LimitsConfig};
use shoal_history::{History, HistoryConfig};
use shoal_model::{
    Event, LinkKind, StateVector, TaskAssignment, VehicleAnnouncement, VehicleKind, now_ms,
};
use shoal_station::{Outbox, PublishError, StationConfig, StationHandle};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio_util::sync::CancellationToken;
use tower::ServiceExt;

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

struct Fixture {
    handle: StationHandle,
    history: Option<History>,
    dir: tempfile::TempDir,
}

fn station(history: HistoryConfig) -> Fixture {
    let dir = tempfile::tempdir().unwrap();
    let history = History::open(&HistoryConfig {
        path: dir.path().join("history.db"),
        ..history
    })
    .unwrap();
    let config = StationConfig {
        summary_interval_s: 0.0,
        rules_path: dir.path().join("rules.json"),
        ..StationConfig::default()
    };
    let handle = StationHandle::new(config, &history, Arc::new(NoBus)).unwrap();
    Fixture {
        handle,
        history: Some(history),
        dir,
    }
}

fn open_router(f: &Fixture, config: &ConsoleConfig) -> Router {
    shoal_console::console_router_with(f.handle.clone(), Arc::new(Auth::disabled()), config)
}

async fn call(
    router: &Router,
    method: &str,
    uri: &str,
    token: Option<&str>,
) -> (StatusCode, axum::http::HeaderMap, Vec<u8>) {
    let mut req = Request::builder().method(method).uri(uri);
    if let Some(t) = token {
        req = req.header(header::AUTHORIZATION, format!("Bearer {t}"));
    }
    let res = router
        .clone()
        .oneshot(req.body(Body::empty()).unwrap())
        .await
        .unwrap();
    let status = res.status();
    let headers = res.headers().clone();
    let body = res.into_body().collect().await.unwrap().to_bytes().to_vec();
    (status, headers, body)
}

async fn json(router: &Router, uri: &str) -> (StatusCode, Value) {
    let (status, _, body) = call(router, "GET", uri, None).await;
    let v = serde_json::from_slice(&body)
        .unwrap_or_else(|e| panic!("{uri}: not JSON ({e}): {}", String::from_utf8_lossy(&body)));
    (status, v)
}

fn announcement(id: &str) -> VehicleAnnouncement {
    VehicleAnnouncement {
        vehicle_id: id.into(),
        name: id.into(),
        kind: VehicleKind::Auv,
        vendor: "limits test".into(),
        capabilities: vec!["goto".into()],
        sensors: vec![],
        links: vec![LinkKind::Ip],
        max_speed_mps: 2.0,
        timestamp_ms: now_ms(),
    }
}

fn state(id: &str, t: i64) -> StateVector {
    StateVector {
        vehicle_id: id.into(),
        timestamp_ms: t,
        latitude_deg: 63.44,
        longitude_deg: 10.37,
        depth_m: 4.0,
        altitude_m: -1.0,
        speed_mps: 1.0,
        yaw_deg: 0.0,
        pitch_deg: 0.0,
        roll_deg: 0.0,
        battery_pct: 90.0,
    }
}

/// Polls `check` every 20 ms until it holds or `within` passes.
async fn eventually<F, Fut>(within: Duration, mut check: F) -> bool
where
    F: FnMut() -> Fut,
    Fut: Future<Output = bool>,
{
    let deadline = Instant::now() + within;
    while Instant::now() < deadline {
        if check().await {
            return true;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    false
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn health_is_ok_then_503_with_the_reason_once_the_history_writer_stops() {
    let mut f = station(HistoryConfig::default());
    let r = open_router(&f, &ConsoleConfig::default());
    let (status, h) = json(&r, "/api/health").await;
    assert_eq!(status, StatusCode::OK, "{h}");
    assert_eq!(h["status"], "ok");
    assert_eq!(h["dds"]["participant_up"], true);
    assert_eq!(h["history"]["writer_running"], true);
    assert_eq!(h["semantic"]["lock_taken"], true);
    assert!(h["limits"]["hit"]["sparql_refused"].is_u64(), "{h}");

    // The station's run loop closes the history when it stops: so does this test.
    let history = f.history.take().unwrap();
    tokio::task::spawn_blocking(move || history.close().unwrap())
        .await
        .unwrap();
    let (status, h) = json(&r, "/api/health").await;
    assert_eq!(status, StatusCode::SERVICE_UNAVAILABLE, "{h}");
    assert_eq!(h["status"], "degraded");
    let reasons = h["degraded"].to_string();
    assert!(reasons.contains("history writer stopped"), "{reasons}");
    assert!(reasons.contains("DDS participant"), "{reasons}");
    assert_eq!(h["dds"]["participant_up"], false);
}

/// A writer that lingers a minute before committing a partial batch: records stay
/// pending, as they do behind a locked database.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn health_is_503_while_records_wait_too_long_for_a_commit_and_ok_once_committed() {
    let f = station(HistoryConfig {
        flush_interval_ms: 60_000,
        batch_max: 100_000,
        ..HistoryConfig::default()
    });
    let config = ConsoleConfig {
        health: HealthConfig {
            max_commit_stall_s: 0.3,
            ..HealthConfig::default()
        },
        ..ConsoleConfig::default()
    };
    let r = open_router(&f, &config);
    f.handle.register_vehicle(announcement("auv-1")).unwrap();
    f.handle
        .ingest_state(state("auv-1", f.handle.now()))
        .unwrap();
    let degraded = eventually(Duration::from_secs(5), || async {
        json(&r, "/api/health").await.0 == StatusCode::SERVICE_UNAVAILABLE
    })
    .await;
    let (_, h) = json(&r, "/api/health").await;
    assert!(degraded, "{h}");
    assert!(h["history"]["lag"].as_u64().unwrap() > 0, "{h}");
    assert!(
        h["degraded"].to_string().contains("no history commit"),
        "{h}"
    );

    let s = f.handle.clone();
    tokio::task::spawn_blocking(move || s.flush_history(Duration::from_secs(10)).unwrap())
        .await
        .unwrap();
    let ok = eventually(Duration::from_secs(5), || async {
        json(&r, "/api/health").await.0 == StatusCode::OK
    })
    .await;
    let (_, h) = json(&r, "/api/health").await;
    assert!(ok, "{h}");
    assert_eq!(h["history"]["lag"], 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn health_is_public_and_metrics_need_a_viewer_and_parse_as_prometheus_text() {
    let f = station(HistoryConfig::default());
    let (auth, boot) = Auth::load(&AuthConfig {
        users_path: f.dir.path().join("users.json"),
        session_ttl_s: 600,
        ..AuthConfig::default()
    })
    .unwrap();
    let (_, viewer) = auth
        .create_token("prometheus", shoal_console::Role::Viewer)
        .unwrap();
    assert!(boot.is_some());
    let r = shoal_console::console_router(f.handle.clone(), Arc::new(auth));
    f.handle.register_vehicle(announcement("auv-1")).unwrap();
    f.handle
        .ingest_state(state("auv-1", f.handle.now()))
        .unwrap();
    let mut bad = state("auv-1", f.handle.now());
    bad.latitude_deg = 95.0;
    assert!(f.handle.ingest_state(bad).is_err());

    let (status, _, body) = call(&r, "GET", "/api/health", None).await;
    assert_eq!(status, StatusCode::OK, "{}", String::from_utf8_lossy(&body));
    let text = String::from_utf8(body).unwrap();
    assert!(!text.contains("auv-1"), "health names no vehicle: {text}");

    let (status, _, _) = call(&r, "GET", "/metrics", None).await;
    assert_eq!(status, StatusCode::UNAUTHORIZED);
    let (status, headers, body) = call(&r, "GET", "/metrics", Some(&viewer)).await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(
        headers[header::CONTENT_TYPE],
        "text/plain; version=0.0.4; charset=utf-8"
    );
    let text = String::from_utf8(body).unwrap();
    let scrape = prometheus_parse::Scrape::parse(text.lines().map(|l| Ok(l.to_owned()))).unwrap();
    let value = |name: &str, label: Option<(&str, &str)>| -> f64 {
        let s = scrape
            .samples
            .iter()
            .find(|s| s.metric == name && label.is_none_or(|(k, v)| s.labels.get(k) == Some(v)))
            .unwrap_or_else(|| panic!("no {name} {label:?} in\n{text}"));
        match s.value {
            prometheus_parse::Value::Counter(v)
            | prometheus_parse::Value::Gauge(v)
            | prometheus_parse::Value::Untyped(v) => v,
            ref other => panic!("{name}: {other:?}"),
        }
    };
    assert_eq!(value("shoal_health_degraded", None), 0.0);
    assert_eq!(value("shoal_vehicles", None), 1.0);
    assert_eq!(
        value("shoal_ingest_accepted_total", Some(("kind", "state"))),
        1.0
    );
    let rejected: f64 = scrape
        .samples
        .iter()
        .filter(|s| s.metric == "shoal_ingest_rejected_total")
        .map(|s| match s.value {
            prometheus_parse::Value::Counter(v) => v,
            _ => 0.0,
        })
        .sum();
    assert_eq!(rejected, 1.0, "{text}");
    assert_eq!(value("shoal_dds_participant_up", None), 1.0);
    assert_eq!(
        value("shoal_http_limit_hits_total", Some(("limit", "sparql"))),
        0.0
    );
    for name in [
        "shoal_history_lag_records",
        "shoal_semantic_lock_wait_seconds",
        "shoal_clock_skew_seconds",
        "shoal_tasks_dispatched_total",
        "shoal_rule_firings_total",
        "shoal_rules_disabled",
        "shoal_history_seconds_since_commit",
    ] {
        value(name, None);
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_thousand_concurrent_sparql_requests_are_bounded_and_counted_while_health_answers() {
    let f = station(HistoryConfig::default());
    let config = ConsoleConfig::default();
    let r = open_router(&f, &config);
    let query = "/api/sparql?query=SELECT%20*%20WHERE%20%7B%20%3Fs%20%3Fp%20%3Fo%20%7D";
    let mut flood = tokio::task::JoinSet::new();
    for _ in 0..1000 {
        let r = r.clone();
        flood.spawn(async move {
            let (status, headers, _) = call(&r, "GET", query, None).await;
            (status, headers.contains_key(header::RETRY_AFTER))
        });
    }
    // While the flood runs, health answers promptly and never sees more queries running
    // than allowed.
    let mut most_running = 0;
    let mut slowest_health = Duration::ZERO;
    while !flood.is_empty() {
        let t = Instant::now();
        let (status, h) = json(&r, "/api/health").await;
        slowest_health = slowest_health.max(t.elapsed());
        assert_eq!(status, StatusCode::OK, "{h}");
        most_running = most_running.max(h["limits"]["in_use"]["sparql_running"].as_u64().unwrap());
        tokio::time::sleep(Duration::from_millis(10)).await;
        while flood.try_join_next().is_some() {}
    }
    assert!(
        most_running <= config.limits.max_concurrent_sparql as u64,
        "{most_running} queries ran at once"
    );
    assert!(
        slowest_health < Duration::from_secs(2),
        "health took {slowest_health:?}"
    );

    let mut flood = tokio::task::JoinSet::new();
    for _ in 0..1000 {
        let r = r.clone();
        flood.spawn(async move {
            let (status, headers, _) = call(&r, "GET", query, None).await;
            (status, headers.contains_key(header::RETRY_AFTER))
        });
    }
    let (mut ok, mut busy) = (0, 0);
    while let Some(res) = flood.join_next().await {
        match res.unwrap() {
            (StatusCode::OK, _) => ok += 1,
            (StatusCode::SERVICE_UNAVAILABLE, true) => busy += 1,
            other => panic!("unexpected answer {other:?}"),
        }
    }
    assert!(ok > 0, "no query was answered");
    let (_, stats) = json(&r, "/api/stats").await;
    let counted = stats["http"]["sparql_refused"].as_u64().unwrap()
        + stats["http"]["requests_refused"].as_u64().unwrap();
    assert!(
        busy > 0,
        "1000 queries at once were all answered: nothing bounded them"
    );
    // Both floods' refusals are counted; the second's alone are at most that.
    assert!(
        counted >= busy,
        "{busy} refused, {counted} counted: {stats}"
    );
    assert_eq!(stats["http"]["in_use"]["sparql_queued"], 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_request_over_its_time_and_a_body_over_its_size_are_refused_and_counted() {
    let f = station(HistoryConfig::default());
    let slow = ConsoleConfig {
        limits: LimitsConfig {
            request_timeout_s: 0.000_001,
            max_body_bytes: 1024,
            ..LimitsConfig::default()
        },
        ..ConsoleConfig::default()
    };
    let r = open_router(&f, &slow);
    // A query that takes a while (a cross product of the model): a timeout only cuts a
    // request that is still running when it fires, and `ASK {}` may be done before that.
    let q = "/api/sparql?query=SELECT%20(COUNT(*)%20AS%20%3Fn)%20WHERE%20%7B%20%3Fa%20%3Fb%20%3Fc%20.%20%3Fd%20%3Fe%20%3Ff%20%7D";
    let (status, headers, _) = call(&r, "GET", q, None).await;
    assert_eq!(status, StatusCode::SERVICE_UNAVAILABLE);
    assert_eq!(headers[header::RETRY_AFTER], "1");

    let r = open_router(
        &f,
        &ConsoleConfig {
            limits: LimitsConfig {
                max_body_bytes: 1024,
                ..LimitsConfig::default()
            },
            ..ConsoleConfig::default()
        },
    );
    let big = Request::post("/api/sparql")
        .header(header::CONTENT_TYPE, "application/sparql-query")
        .body(Body::from(format!("ASK {{}} #{}", "x".repeat(4096))))
        .unwrap();
    let res = r.clone().oneshot(big).await.unwrap();
    assert_eq!(res.status(), StatusCode::PAYLOAD_TOO_LARGE);
    let (_, stats) = json(&r, "/api/stats").await;
    assert_eq!(stats["http"]["bodies_too_large"], 1, "{stats}");
    // Existing members stay.
    assert!(stats["ingest"].is_object() && stats["history_committed"].is_u64());
}

/// A console served on a loopback socket with `limits`; its address and shutdown.
async fn serve(f: &Fixture, limits: LimitsConfig) -> (std::net::SocketAddr, CancellationToken) {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let shutdown = CancellationToken::new();
    // Logins off: these tests are about the server loop, not who may use it.
    let config = ConsoleConfig {
        limits,
        auth: AuthConfig::off(),
        ..ConsoleConfig::default()
    };
    let (station, stop) = (f.handle.clone(), shutdown.clone());
    tokio::spawn(async move { shoal_console::serve_with(listener, station, config, stop).await });
    (addr, shutdown)
}

/// Sends `request` and reads the status line of the answer.
async fn status_line(tcp: &mut TcpStream, request: &str) -> String {
    tcp.write_all(request.as_bytes()).await.unwrap();
    let mut got = Vec::new();
    let mut byte = [0u8; 1];
    while !got.ends_with(b"\r\n") {
        match tcp.read(&mut byte).await.unwrap() {
            0 => break,
            _ => got.push(byte[0]),
        }
    }
    String::from_utf8_lossy(&got).trim().to_owned()
}

async fn get_json(addr: std::net::SocketAddr, path: &str) -> Value {
    let mut tcp = TcpStream::connect(addr).await.unwrap();
    let req = format!("GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n");
    tcp.write_all(req.as_bytes()).await.unwrap();
    let mut all = Vec::new();
    tcp.read_to_end(&mut all).await.unwrap();
    let text = String::from_utf8(all).unwrap();
    let (_, body) = text.split_once("\r\n\r\n").unwrap();
    serde_json::from_str(body).unwrap_or_else(|e| panic!("{path}: {e}: {text}"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_sending_its_headers_a_byte_at_a_time_is_cut_off() {
    let f = station(HistoryConfig::default());
    let (addr, shutdown) = serve(
        &f,
        LimitsConfig {
            header_read_timeout_s: 0.5,
            ..LimitsConfig::default()
        },
    )
    .await;
    let mut tcp = TcpStream::connect(addr).await.unwrap();
    let request = b"GET /api/health HTTP/1.1\r\nHost: shoal\r\nX-Slow: aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa\r\n\r\n";
    let start = Instant::now();
    let mut cut_after = None;
    for b in request {
        // A write can still succeed after the server closed; the read below tells.
        if tcp.write_all(&[*b]).await.is_err() {
            cut_after = Some(start.elapsed());
            break;
        }
        let mut buf = [0u8; 64];
        match tokio::time::timeout(Duration::from_millis(100), tcp.read(&mut buf)).await {
            Ok(Ok(0) | Err(_)) => {
                cut_after = Some(start.elapsed());
                break;
            }
            Ok(Ok(n)) => panic!("answered: {}", String::from_utf8_lossy(&buf[..n])),
            Err(_) => {} // nothing yet: the next byte
        }
    }
    let cut_after = cut_after.expect("the slow client was never cut off");
    assert!(
        cut_after < Duration::from_secs(3),
        "cut off only after {cut_after:?}"
    );
    let stats = get_json(addr, "/api/stats").await;
    assert_eq!(stats["http"]["slow_headers_cut"], 1, "{stats}");
    // A client that connects and says nothing is cut off too.
    let mut idle = TcpStream::connect(addr).await.unwrap();
    let mut buf = [0u8; 16];
    let n = tokio::time::timeout(Duration::from_secs(3), idle.read(&mut buf))
        .await
        .expect("an idle connection was left open")
        .unwrap_or(0);
    assert_eq!(n, 0);
    shutdown.cancel();
}

fn ws_request(addr: std::net::SocketAddr) -> String {
    format!(
        "GET /api/ws HTTP/1.1\r\nHost: {addr}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\
         Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n"
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn live_feed_clients_beyond_the_limit_are_refused_and_counted() {
    let f = station(HistoryConfig::default());
    let (addr, shutdown) = serve(
        &f,
        LimitsConfig {
            max_ws_clients: 2,
            ..LimitsConfig::default()
        },
    )
    .await;
    let mut clients = Vec::new();
    for _ in 0..2 {
        let mut tcp = TcpStream::connect(addr).await.unwrap();
        let line = status_line(&mut tcp, &ws_request(addr)).await;
        assert!(line.starts_with("HTTP/1.1 101"), "{line}");
        clients.push(tcp);
    }
    let mut third = TcpStream::connect(addr).await.unwrap();
    let line = status_line(&mut third, &ws_request(addr)).await;
    assert!(line.starts_with("HTTP/1.1 503"), "{line}");
    let stats = get_json(addr, "/api/stats").await;
    assert_eq!(stats["http"]["ws_refused"], 1, "{stats}");
    assert_eq!(stats["http"]["in_use"]["ws_clients"], 2, "{stats}");

    // A client that leaves makes room.
    drop(clients.pop());
    let deadline = Instant::now() + Duration::from_secs(5);
    let room = loop {
        let mut tcp = TcpStream::connect(addr).await.unwrap();
        if status_line(&mut tcp, &ws_request(addr))
            .await
            .starts_with("HTTP/1.1 101")
        {
            clients.push(tcp);
            break true;
        }
        if Instant::now() > deadline {
            break false;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    assert!(room, "no room after a client left");
    shutdown.cancel();
}
