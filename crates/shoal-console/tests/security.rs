//! The console locked down: logins on by default, Host allow-list (DNS rebinding), Origin
//! checks on changes and WebSocket handshakes, CSRF tokens on session cookies, login rate
//! limits and bounded hashing, TLS with a `Secure` cookie. Over a station core that
//! publishes to no bus (no DDS participant: no network namespace needed).

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::sync::Arc;
use std::time::Duration;

use axum::Router;
use axum::body::Body;
use axum::extract::ConnectInfo;
use axum::http::{HeaderMap, Request, StatusCode, header};
use http_body_util::BodyExt;
use serde_json::{Value, json};
use shoal_console::auth::CSRF_HEADER;
use shoal_console::{Auth, AuthConfig, ConsoleConfig, TlsConfig};
use shoal_history::{History, HistoryConfig};
use shoal_model::{Event, TaskAssignment};
use shoal_station::{Outbox, PublishError, StationConfig, StationHandle};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_util::sync::CancellationToken;
use tower::ServiceExt;

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
    dir: tempfile::TempDir,
    _history: History,
}

fn station() -> Fixture {
    let dir = tempfile::tempdir().unwrap();
    let history = History::open(&HistoryConfig {
        path: dir.path().join("history.db"),
        ..HistoryConfig::default()
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
        dir,
        _history: history,
    }
}

const PASSWORD: &str = "the admin's password";
const TOKEN: &str = "shoal_test_token_0123456789abcdef0123456789";
const OWN: &str = "http://127.0.0.1:8640";

fn auth_config(f: &Fixture) -> AuthConfig {
    AuthConfig {
        users_path: f.dir.path().join("users.json"),
        initial_admin_password: PASSWORD.into(),
        initial_admin_token: TOKEN.into(),
        ..AuthConfig::default()
    }
}

/// A router with logins on (the default), the admin's password and token known.
fn locked(f: &Fixture, config: &ConsoleConfig) -> Router {
    let (auth, boot) = Auth::load(&auth_config(f)).unwrap();
    assert!(boot.is_some());
    shoal_console::console_router_with(f.handle.clone(), Arc::new(auth), config)
}

struct Answer {
    status: StatusCode,
    headers: HeaderMap,
    body: Value,
}

async fn send(router: &Router, req: Request<Body>) -> Answer {
    let res = router.clone().oneshot(req).await.unwrap();
    let status = res.status();
    let headers = res.headers().clone();
    let bytes = res.into_body().collect().await.unwrap().to_bytes();
    let body = serde_json::from_slice(&bytes).unwrap_or(Value::Null);
    Answer {
        status,
        headers,
        body,
    }
}

/// A request with `headers`, and a JSON body when one is given.
fn request(
    method: &str,
    uri: &str,
    headers: &[(&str, &str)],
    body: Option<Value>,
) -> Request<Body> {
    let mut req = Request::builder().method(method).uri(uri);
    for (k, v) in headers {
        req = req.header(*k, *v);
    }
    match body {
        Some(b) => req
            .header(header::CONTENT_TYPE, "application/json")
            .body(Body::from(b.to_string()))
            .unwrap(),
        None => req.body(Body::empty()).unwrap(),
    }
}

fn from(addr: &str, mut req: Request<Body>) -> Request<Body> {
    let a: std::net::SocketAddr = addr.parse().unwrap();
    req.extensions_mut().insert(ConnectInfo(a));
    req
}

fn login_body(user: &str, password: &str) -> Option<Value> {
    Some(json!({"user": user, "password": password}))
}

/// Logs in as the page would; the cookie pair and the CSRF token.
async fn login(r: &Router) -> (String, String) {
    let a = send(
        r,
        request(
            "POST",
            "/api/auth/login",
            &[("origin", OWN)],
            login_body("admin", PASSWORD),
        ),
    )
    .await;
    assert_eq!(a.status, StatusCode::OK, "{}", a.body);
    let cookie = a.headers[header::SET_COOKIE].to_str().unwrap();
    assert!(!cookie.contains("Secure"), "plain HTTP: {cookie}");
    let pair = cookie.split(';').next().unwrap().to_owned();
    (pair, a.body["csrf_token"].as_str().unwrap().to_owned())
}

async fn stats(r: &Router) -> Value {
    let a = send(
        r,
        request(
            "GET",
            "/api/stats",
            &[("authorization", &format!("Bearer {TOKEN}"))],
            None,
        ),
    )
    .await;
    assert_eq!(a.status, StatusCode::OK);
    a.body["http"]["refused"].clone()
}

#[test]
fn logins_are_on_by_default() {
    assert!(ConsoleConfig::default().auth.enabled);
}

#[tokio::test]
async fn a_session_cookie_changes_things_only_with_the_pages_origin_and_csrf_token() {
    let f = station();
    let r = locked(&f, &ConsoleConfig::default());
    let (cookie, csrf) = login(&r).await;
    let rule =
        || Some(json!({"id": "r1", "condition": {"type": "threshold", "expr": "battery_pct < 5"}}));

    // The session answers with the same token the login gave.
    let a = send(
        &r,
        request("GET", "/api/auth/session", &[("cookie", &cookie)], None),
    )
    .await;
    assert_eq!(a.body["csrf_token"], csrf.as_str());
    assert_eq!(a.body["via"], "session");
    // Reads need neither.
    let a = send(
        &r,
        request("GET", "/api/rules", &[("cookie", &cookie)], None),
    )
    .await;
    assert_eq!(a.status, StatusCode::OK);

    // A change without the CSRF token: 403, explained.
    let a = send(
        &r,
        request(
            "POST",
            "/api/rules",
            &[("cookie", &cookie), ("origin", OWN)],
            rule(),
        ),
    )
    .await;
    assert_eq!(a.status, StatusCode::FORBIDDEN);
    assert!(
        a.body["error"].as_str().unwrap().contains("x-csrf-token"),
        "{}",
        a.body
    );
    // A wrong one.
    let wrong = "0".repeat(64);
    let a = send(
        &r,
        request(
            "POST",
            "/api/rules",
            &[("cookie", &cookie), ("origin", OWN), (CSRF_HEADER, &wrong)],
            rule(),
        ),
    )
    .await;
    assert_eq!(a.status, StatusCode::FORBIDDEN);
    // The right token but no Origin: not a browser, so not a session's business.
    let a = send(
        &r,
        request(
            "POST",
            "/api/rules",
            &[("cookie", &cookie), (CSRF_HEADER, &csrf)],
            rule(),
        ),
    )
    .await;
    assert_eq!(a.status, StatusCode::FORBIDDEN);
    assert!(
        a.body["error"].as_str().unwrap().contains("Origin"),
        "{}",
        a.body
    );
    // Another site's page, with everything else right.
    let a = send(
        &r,
        request(
            "POST",
            "/api/rules",
            &[
                ("cookie", &cookie),
                ("origin", "http://evil.example"),
                (CSRF_HEADER, &csrf),
            ],
            rule(),
        ),
    )
    .await;
    assert_eq!(a.status, StatusCode::FORBIDDEN);
    assert!(a.body["error"].as_str().unwrap().contains("another site"));
    let refused = stats(&r).await;
    assert_eq!(
        (refused["csrf"].as_u64(), refused["origin"].as_u64()),
        (Some(2), Some(2))
    );

    // The page's own request goes through.
    let a = send(
        &r,
        request(
            "POST",
            "/api/rules",
            &[("cookie", &cookie), ("origin", OWN), (CSRF_HEADER, &csrf)],
            rule(),
        ),
    )
    .await;
    assert_eq!(a.status, StatusCode::CREATED, "{}", a.body);
    // So does DELETE, with the same token.
    let a = send(
        &r,
        request(
            "DELETE",
            "/api/rules/r1",
            &[("cookie", &cookie), ("origin", OWN), (CSRF_HEADER, &csrf)],
            None,
        ),
    )
    .await;
    assert_eq!(a.status, StatusCode::NO_CONTENT);

    // The live feed: the session needs the page's Origin; another site's is refused.
    for (origin, status) in [
        (None, StatusCode::FORBIDDEN),
        (Some("http://evil.example"), StatusCode::FORBIDDEN),
    ] {
        let mut h = vec![("cookie", cookie.as_str())];
        h.extend(origin.map(|o| ("origin", o)));
        let a = send(&r, request("GET", "/api/ws", &h, None)).await;
        assert_eq!(a.status, status, "{origin:?}");
    }
}

#[tokio::test]
async fn tools_with_a_token_need_no_origin_but_another_sites_origin_is_refused_anyway() {
    let f = station();
    let r = locked(&f, &ConsoleConfig::default());
    let bearer = format!("Bearer {TOKEN}");
    let ack =
        |h: &[(&str, &str)]| request("POST", "/api/abort-all", h, Some(json!({"confirm": true})));
    let a = send(&r, ack(&[("authorization", &bearer)])).await;
    assert_eq!(a.status, StatusCode::OK, "{}", a.body);
    let a = send(&r, ack(&[("authorization", &bearer), ("origin", OWN)])).await;
    assert_eq!(a.status, StatusCode::OK);
    let a = send(&r, ack(&[("authorization", &bearer), ("origin", "null")])).await;
    assert_eq!(a.status, StatusCode::FORBIDDEN);
    // No credentials at all is still a 401, not a 403.
    let a = send(&r, ack(&[])).await;
    assert_eq!(a.status, StatusCode::UNAUTHORIZED);
    // A cross-site login attempt (login CSRF) is refused before any password check.
    let a = send(
        &r,
        request(
            "POST",
            "/api/auth/login",
            &[("origin", "http://evil.example")],
            login_body("admin", PASSWORD),
        ),
    )
    .await;
    assert_eq!(a.status, StatusCode::FORBIDDEN);
    assert!(!a.headers.contains_key(header::SET_COOKIE));
}

#[tokio::test]
async fn with_logins_off_another_sites_page_still_cannot_change_anything() {
    let f = station();
    let config = ConsoleConfig {
        auth: AuthConfig::off(),
        allowed_origins: vec!["https://ops.example.org".into()],
        ..ConsoleConfig::default()
    };
    let r =
        shoal_console::console_router_with(f.handle.clone(), Arc::new(Auth::disabled()), &config);
    let abort =
        |h: &[(&str, &str)]| request("POST", "/api/abort-all", h, Some(json!({"confirm": true})));
    let a = send(&r, abort(&[("origin", "http://evil.example")])).await;
    assert_eq!(a.status, StatusCode::FORBIDDEN);
    let ws = send(
        &r,
        request("GET", "/api/ws", &[("origin", "http://evil.example")], None),
    )
    .await;
    assert_eq!(ws.status, StatusCode::FORBIDDEN);
    // Reads from anywhere are not the Origin check's business (the browser keeps other
    // sites from reading the answers).
    let a = send(
        &r,
        request(
            "GET",
            "/api/fleet",
            &[("origin", "http://evil.example")],
            None,
        ),
    )
    .await;
    assert_eq!(a.status, StatusCode::OK);
    // Its own page, a configured origin and tools without Origin go through.
    for h in [
        vec![("origin", OWN)],
        vec![("origin", "https://ops.example.org")],
        vec![],
    ] {
        let a = send(&r, abort(&h)).await;
        assert_eq!(a.status, StatusCode::OK, "{h:?}: {}", a.body);
    }
    let a = send(&r, request("GET", "/api/stats", &[], None)).await;
    assert_eq!(a.body["http"]["refused"]["origin"], 2);
}

#[tokio::test]
async fn a_host_the_console_does_not_answer_to_gets_421_even_for_its_page() {
    let f = station();
    let config = ConsoleConfig {
        allowed_hosts: vec!["console.ship.local".into()],
        ..ConsoleConfig::default()
    };
    let r = locked(&f, &config);
    for host in [
        "rebind.evil.example:8640",
        "127.0.0.1:9999",
        "10.0.0.1:8640",
    ] {
        for path in ["/", "/api/health", "/api/auth/session"] {
            let a = send(&r, request("GET", path, &[("host", host)], None)).await;
            assert_eq!(a.status, StatusCode::MISDIRECTED_REQUEST, "{host} {path}");
            assert!(
                a.body["error"].as_str().unwrap().contains("allowed_hosts"),
                "{}",
                a.body
            );
        }
    }
    for host in [
        "127.0.0.1:8640",
        "localhost:8640",
        "[::1]:8640",
        "console.ship.local",
        "console.ship.local:8640",
    ] {
        let a = send(&r, request("GET", "/api/health", &[("host", host)], None)).await;
        assert_eq!(a.status, StatusCode::OK, "{host}");
    }
    assert_eq!(stats(&r).await["host"], 9);
}

#[tokio::test]
async fn failed_logins_are_limited_per_address_and_per_user_then_429_with_retry_after() {
    let f = station();
    let r = locked(&f, &ConsoleConfig::default());
    let attempt = |addr: &str, user: &str, pw: &str| {
        from(
            addr,
            request("POST", "/api/auth/login", &[], login_body(user, pw)),
        )
    };
    for i in 0..5 {
        let a = send(&r, attempt("127.0.0.5:40000", "admin", "wrong password")).await;
        assert_eq!(a.status, StatusCode::UNAUTHORIZED, "attempt {i}");
    }
    // The sixth within the minute, even with the right password: 429, Retry-After.
    let a = send(&r, attempt("127.0.0.5:40001", "admin", PASSWORD)).await;
    assert_eq!(a.status, StatusCode::TOO_MANY_REQUESTS, "{}", a.body);
    let wait: u64 = a.headers[header::RETRY_AFTER]
        .to_str()
        .unwrap()
        .parse()
        .unwrap();
    assert!((1..=60).contains(&wait), "{wait}");
    // The name is blocked from another address too, and the address for another name.
    let a = send(&r, attempt("127.0.0.6:40000", "admin", PASSWORD)).await;
    assert_eq!(a.status, StatusCode::TOO_MANY_REQUESTS);
    let a = send(&r, attempt("127.0.0.5:40002", "vera", "whatever pw")).await;
    assert_eq!(a.status, StatusCode::TOO_MANY_REQUESTS);
    // Another address and name are not affected.
    let a = send(&r, attempt("127.0.0.6:40000", "vera", "whatever pw")).await;
    assert_eq!(a.status, StatusCode::UNAUTHORIZED);
    let refused = stats(&r).await;
    assert_eq!(refused["login_throttled"], 3);
    assert_eq!(refused["login_failed"], 6);
    // A token still works: the limit is on guessing passwords, not on the console.
    let a = send(
        &r,
        request(
            "GET",
            "/api/fleet",
            &[("authorization", &format!("Bearer {TOKEN}"))],
            None,
        ),
    )
    .await;
    assert_eq!(a.status, StatusCode::OK);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_login_flood_waits_for_a_bounded_number_of_hashing_turns_then_gets_503() {
    let f = station();
    let config = ConsoleConfig {
        auth: AuthConfig {
            max_concurrent_hashes: 1,
            hash_queue_ms: 1,
            // Not the rate limit's turn here.
            max_failed_logins: 1000,
            ..auth_config(&f)
        },
        ..ConsoleConfig::default()
    };
    let r = locked(&f, &config);
    let mut flood = tokio::task::JoinSet::new();
    for i in 0..20 {
        let r = r.clone();
        flood.spawn(async move {
            let req = from(
                &format!("127.0.0.{}:1000", i + 1),
                request(
                    "POST",
                    "/api/auth/login",
                    &[],
                    login_body("admin", "wrong password"),
                ),
            );
            let a = send(&r, req).await;
            (a.status, a.headers.contains_key(header::RETRY_AFTER))
        });
    }
    let (mut wrong, mut busy) = (0, 0);
    while let Some(res) = flood.join_next().await {
        match res.unwrap() {
            (StatusCode::UNAUTHORIZED, _) => wrong += 1,
            (StatusCode::SERVICE_UNAVAILABLE, true) => busy += 1,
            other => panic!("unexpected answer {other:?}"),
        }
    }
    assert!(wrong >= 1, "no login was checked");
    assert!(
        busy >= 1,
        "20 logins at once with one hashing turn all got one"
    );
    assert_eq!(stats(&r).await["login_busy"], busy);
}

#[tokio::test]
async fn refusals_are_counted_in_metrics() {
    let f = station();
    let r = locked(&f, &ConsoleConfig::default());
    send(&r, request("GET", "/", &[("host", "evil.example")], None)).await;
    let a = r
        .clone()
        .oneshot(request(
            "GET",
            "/metrics",
            &[("authorization", &format!("Bearer {TOKEN}"))],
            None,
        ))
        .await
        .unwrap();
    let text =
        String::from_utf8(a.into_body().collect().await.unwrap().to_bytes().to_vec()).unwrap();
    assert!(
        text.lines()
            .any(|l| l == "shoal_http_refused_total{reason=\"host\"} 1"),
        "{text}"
    );
}

/// A self-signed certificate for localhost and 127.0.0.1 (ECDSA P-256, valid to 2125),
/// made once with `openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes
/// -days 36500 -subj /CN=localhost -addext subjectAltName=DNS:localhost,IP:127.0.0.1
/// -addext basicConstraints=critical,CA:FALSE -addext extendedKeyUsage=serverAuth`; the
/// client trusts it directly.
const CERT: &str = include_str!("tls/localhost.crt");
const KEY: &str = include_str!("tls/localhost.key");

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn over_tls_the_console_answers_https_and_the_cookie_is_secure() {
    use tokio_rustls::rustls;
    use tokio_rustls::rustls::pki_types::pem::PemObject as _;
    let f = station();
    std::fs::write(f.dir.path().join("c.pem"), CERT).unwrap();
    std::fs::write(f.dir.path().join("k.pem"), KEY).unwrap();
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let config = ConsoleConfig {
        auth: auth_config(&f),
        tls: TlsConfig {
            cert: f.dir.path().join("c.pem"),
            key: f.dir.path().join("k.pem"),
        },
        ..ConsoleConfig::default()
    };
    let stop = CancellationToken::new();
    let (station, s) = (f.handle.clone(), stop.clone());
    let server =
        tokio::spawn(async move { shoal_console::serve_with(listener, station, config, s).await });

    let mut roots = rustls::RootCertStore::empty();
    for c in rustls::pki_types::CertificateDer::pem_slice_iter(CERT.as_bytes()) {
        roots.add(c.unwrap()).unwrap();
    }
    let client = rustls::ClientConfig::builder_with_provider(Arc::new(
        rustls::crypto::ring::default_provider(),
    ))
    .with_safe_default_protocol_versions()
    .unwrap()
    .with_root_certificates(roots)
    .with_no_client_auth();
    let connector = tokio_rustls::TlsConnector::from(Arc::new(client));
    let exchange = |request: String| {
        let connector = connector.clone();
        async move {
            let mut tcp = None;
            for _ in 0..50 {
                if let Ok(t) = tokio::net::TcpStream::connect(addr).await {
                    tcp = Some(t);
                    break;
                }
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
            let name = rustls::pki_types::ServerName::try_from("localhost").unwrap();
            let mut tls = connector.connect(name, tcp.unwrap()).await.unwrap();
            tls.write_all(request.as_bytes()).await.unwrap();
            let mut out = Vec::new();
            let _ = tls.read_to_end(&mut out).await;
            String::from_utf8_lossy(&out).into_owned()
        }
    };
    let host = format!("localhost:{}", addr.port());
    let health = exchange(format!(
        "GET /api/health HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n"
    ))
    .await;
    assert!(health.starts_with("HTTP/1.1 200"), "{health}");
    let body = json!({"user": "admin", "password": PASSWORD}).to_string();
    let login = exchange(format!(
        "POST /api/auth/login HTTP/1.1\r\nHost: {host}\r\nOrigin: https://{host}\r\n\
         Content-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    ))
    .await;
    assert!(login.starts_with("HTTP/1.1 200"), "{login}");
    let cookie = login
        .lines()
        .find(|l| l.to_ascii_lowercase().starts_with("set-cookie:"))
        .unwrap();
    assert!(cookie.contains("; Secure"), "{cookie}");
    // The page's origin over TLS is https://...; http://... is another site.
    let ws_like = exchange(format!(
        "POST /api/auth/logout HTTP/1.1\r\nHost: {host}\r\nOrigin: http://{host}\r\n\
         Content-Length: 0\r\nConnection: close\r\n\r\n"
    ))
    .await;
    assert!(ws_like.starts_with("HTTP/1.1 403"), "{ws_like}");
    // Plain HTTP on the TLS port gets no answer.
    let mut plain = tokio::net::TcpStream::connect(addr).await.unwrap();
    plain
        .write_all(format!("GET /api/health HTTP/1.1\r\nHost: {host}\r\n\r\n").as_bytes())
        .await
        .unwrap();
    let mut out = Vec::new();
    let _ = tokio::time::timeout(Duration::from_secs(5), plain.read_to_end(&mut out)).await;
    assert!(!String::from_utf8_lossy(&out).contains("200 OK"));
    stop.cancel();
    server.await.unwrap().unwrap();
}

#[tokio::test]
async fn tls_with_a_missing_key_or_unreadable_files_refuses_to_start() {
    let f = station();
    for tls in [
        TlsConfig {
            cert: f.dir.path().join("c.pem"),
            key: "".into(),
        },
        TlsConfig {
            cert: f.dir.path().join("missing.pem"),
            key: f.dir.path().join("missing.key"),
        },
    ] {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let config = ConsoleConfig {
            auth: AuthConfig::off(),
            tls,
            ..ConsoleConfig::default()
        };
        let err =
            shoal_console::serve_with(listener, f.handle.clone(), config, CancellationToken::new())
                .await
                .unwrap_err();
        assert!(err.to_string().contains("[console.tls]"), "{err}");
    }
}

/// `/api/foxglove` is an API route like the others: no token, no upgrade; a page of
/// another site is refused even with a valid token; the Foxglove app's `?token=` is
/// accepted; and with the bridge off an authorised client is told so (404).
#[tokio::test]
async fn the_foxglove_route_needs_a_token_and_refuses_other_sites() {
    let f = station();
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let config = ConsoleConfig {
        auth: auth_config(&f),
        ..ConsoleConfig::default()
    };
    let stop = CancellationToken::new();
    let (station, s) = (f.handle.clone(), stop.clone());
    tokio::spawn(async move { shoal_console::serve_with(listener, station, config, s).await });
    // The status code of a WebSocket upgrade request for `path` with `extra` headers.
    let status = |path: String, extra: String| async move {
        let mut tcp = None;
        for _ in 0..50 {
            if let Ok(t) = tokio::net::TcpStream::connect(addr).await {
                tcp = Some(t);
                break;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        let mut tcp = tcp.unwrap();
        let request = format!(
            "GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: Upgrade\r\nUpgrade: websocket\r\n\
             Sec-WebSocket-Version: 13\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n\
             Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n{extra}\r\n"
        );
        tcp.write_all(request.as_bytes()).await.unwrap();
        let mut head = vec![0u8; 12];
        tcp.read_exact(&mut head).await.unwrap();
        String::from_utf8_lossy(&head[9..12])
            .parse::<u16>()
            .unwrap()
    };
    let path = "/api/foxglove".to_string();
    assert_eq!(status(path.clone(), String::new()).await, 401);
    assert_eq!(
        status(format!("{path}?token=not-a-token"), String::new()).await,
        401
    );
    let bearer = format!("Authorization: Bearer {TOKEN}\r\n");
    assert_eq!(
        status(
            path.clone(),
            format!("{bearer}Origin: https://evil.example\r\n")
        )
        .await,
        403
    );
    assert_eq!(
        status(format!("{path}?token={TOKEN}"), String::new()).await,
        404
    );
    assert_eq!(status(path, bearer).await, 404);
    stop.cancel();
}
