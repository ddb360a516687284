//! The console's handlers over a real station, without sockets (`tower::ServiceExt`).
//! The station opens a DDS participant: run inside a network namespace
//! (`scripts/netns-run.sh shoal-web -- cargo test -p shoal-console`). DDS domains 140–149.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::sync::Arc;
use std::time::Duration;

use axum::Router;
use axum::body::Body;
use axum::http::{Request, StatusCode, header};
use http_body_util::BodyExt;
use serde_json::{Value, json};
use shoal_console::{Auth, AuthConfig};
use shoal_dds::{DdsConfig, PubSub};
use shoal_history::{History, HistoryConfig};
use shoal_model::{LinkKind, StateVector, VehicleAnnouncement, VehicleKind, now_ms};
use shoal_station::{Station, StationConfig, StationHandle};
use tokio_util::sync::CancellationToken;
use tower::ServiceExt;

struct Fixture {
    handle: StationHandle,
    router: Router,
    admin_password: String,
    admin_token: String,
    shutdown: CancellationToken,
    _dir: tempfile::TempDir,
}

fn start(domain_id: u16) -> Fixture {
    let dir = tempfile::tempdir().unwrap();
    let history = History::open(&HistoryConfig {
        path: dir.path().join("history.db"),
        ..HistoryConfig::default()
    })
    .unwrap();
    let dds = Arc::new(
        PubSub::new(&DdsConfig {
            domain_id,
            ..DdsConfig::default()
        })
        .unwrap(),
    );
    let config = StationConfig {
        summary_interval_s: 0.0,
        rules_path: dir.path().join("rules.json"),
        ..StationConfig::default()
    };
    let station = Station::new(config, dds, history).unwrap();
    let handle = station.handle();
    let shutdown = CancellationToken::new();
    let s = shutdown.clone();
    tokio::spawn(async move { station.run(s).await });
    let (auth, boot) = Auth::load(&AuthConfig {
        enabled: true,
        users_path: dir.path().join("users.json"),
        session_ttl_s: 600,
    })
    .unwrap();
    let boot = boot.expect("a first start creates the admin");
    Fixture {
        router: shoal_console::console_router(handle.clone(), Arc::new(auth)),
        handle,
        admin_password: boot.password,
        admin_token: boot.token,
        shutdown,
        _dir: dir,
    }
}

/// Sends a request; `auth` is a full header value for Authorization or Cookie.
async fn call(
    router: &Router,
    method: &str,
    uri: &str,
    auth: Option<(header::HeaderName, String)>,
    body: Option<Value>,
) -> (StatusCode, axum::http::HeaderMap, Vec<u8>) {
    let mut req = Request::builder().method(method).uri(uri);
    if let Some((name, value)) = auth {
        req = req.header(name, value);
    }
    let body = match body {
        Some(v) => {
            req = req.header(header::CONTENT_TYPE, "application/json");
            Body::from(v.to_string())
        }
        None => Body::empty(),
    };
    let res = router
        .clone()
        .oneshot(req.body(body).unwrap())
        .await
        .unwrap();
    let status = res.status();
    let headers = res.headers().clone();
    let bytes = res.into_body().collect().await.unwrap().to_bytes().to_vec();
    (status, headers, bytes)
}

fn json_of(bytes: &[u8]) -> Value {
    serde_json::from_slice(bytes).unwrap_or_else(|e| {
        panic!("not JSON ({e}): {}", String::from_utf8_lossy(bytes));
    })
}

fn bearer(token: &str) -> Option<(header::HeaderName, String)> {
    Some((header::AUTHORIZATION, format!("Bearer {token}")))
}

async fn login(
    router: &Router,
    user: &str,
    password: &str,
) -> Option<(header::HeaderName, String)> {
    let (status, headers, body) = call(
        router,
        "POST",
        "/api/auth/login",
        None,
        Some(json!({"user": user, "password": password})),
    )
    .await;
    assert_eq!(status, StatusCode::OK, "{}", String::from_utf8_lossy(&body));
    let cookie = headers
        .get(header::SET_COOKIE)
        .unwrap()
        .to_str()
        .unwrap()
        .to_owned();
    assert!(cookie.contains("HttpOnly") && cookie.contains("SameSite=Strict"));
    let pair = cookie.split(';').next().unwrap().to_owned();
    Some((header::COOKIE, pair))
}

fn announcement(id: &str) -> VehicleAnnouncement {
    VehicleAnnouncement {
        vehicle_id: id.into(),
        name: id.into(),
        kind: VehicleKind::Auv,
        vendor: "console test".into(),
        capabilities: vec!["goto".into(), "survey".into()],
        sensors: vec![],
        links: vec![LinkKind::Ip],
        max_speed_mps: 2.0,
        timestamp_ms: now_ms(),
    }
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
        yaw_deg: 0.0,
        pitch_deg: 0.0,
        roll_deg: 0.0,
        battery_pct: 90.0,
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn roles_decide_who_may_read_dispatch_and_manage() {
    let f = start(141);
    let r = &f.router;

    // Nothing without credentials, but the page, health and the API description.
    let (status, _, body) = call(r, "GET", "/api/fleet", None, None).await;
    assert_eq!(status, StatusCode::UNAUTHORIZED);
    assert!(json_of(&body)["error"].as_str().unwrap().contains("log in"));
    let (status, _, _) = call(r, "GET", "/api/ws", None, None).await;
    assert_eq!(status, StatusCode::UNAUTHORIZED);
    let (status, headers, _) = call(r, "GET", "/", None, None).await;
    assert_eq!(status, StatusCode::OK);
    assert!(
        headers[header::CONTENT_SECURITY_POLICY]
            .to_str()
            .unwrap()
            .contains("default-src 'self'")
    );
    assert_eq!(
        call(r, "GET", "/api/health", None, None).await.0,
        StatusCode::OK
    );
    let (status, _, body) = call(r, "GET", "/api/auth/session", None, None).await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(json_of(&body)["enabled"], true);
    assert_eq!(json_of(&body)["user"], Value::Null);

    // Wrong password: 401, explained.
    let (status, _, body) = call(
        r,
        "POST",
        "/api/auth/login",
        None,
        Some(json!({"user": "admin", "password": "nope"})),
    )
    .await;
    assert_eq!(status, StatusCode::UNAUTHORIZED);
    assert!(json_of(&body)["error"].as_str().unwrap().contains("wrong"));

    // The admin's token makes users; the admin's login works.
    let admin = login(r, "admin", &f.admin_password).await;
    let token = bearer(&f.admin_token);
    for (name, role) in [("vera", "viewer"), ("otto", "operator")] {
        let (status, _, body) = call(
            r,
            "POST",
            "/api/auth/users",
            token.clone(),
            Some(json!({"name": name, "password": "long enough pw", "role": role})),
        )
        .await;
        assert_eq!(
            status,
            StatusCode::CREATED,
            "{}",
            String::from_utf8_lossy(&body)
        );
    }
    let viewer = login(r, "vera", "long enough pw").await;
    let operator = login(r, "otto", "long enough pw").await;

    // A viewer reads and queries, but changes nothing.
    assert_eq!(
        call(r, "GET", "/api/fleet", viewer.clone(), None).await.0,
        StatusCode::OK
    );
    let mission = json!({"mission_id": "m-viewer", "tasks": [{"vehicle_id": "auv-9",
        "task": {"kind": "goto_waypoint", "target": {"latitude_deg": 63.46, "longitude_deg": 10.37},
                 "depth_m": 5.0, "speed_mps": 1.0}}]});
    let (status, _, body) = call(
        r,
        "POST",
        "/api/missions?start=true",
        viewer.clone(),
        Some(mission.clone()),
    )
    .await;
    assert_eq!(status, StatusCode::FORBIDDEN);
    assert!(
        json_of(&body)["error"]
            .as_str()
            .unwrap()
            .contains("operator role")
    );
    for (method, uri, body) in [
        ("POST", "/api/abort-all", json!({"confirm": true})),
        ("POST", "/api/missions/m1/abort", json!({})),
        ("POST", "/api/tasks", json!({})),
        ("POST", "/api/rules", json!({})),
        (
            "PATCH",
            "/api/rules/builtin.low_battery",
            json!({"enabled": false}),
        ),
        ("DELETE", "/api/rules/x", json!({})),
        ("POST", "/api/vehicles", json!({})),
        ("GET", "/api/auth/users", json!({})),
    ] {
        let (status, _, _) = call(r, method, uri, viewer.clone(), Some(body)).await;
        assert_eq!(status, StatusCode::FORBIDDEN, "{method} {uri} as a viewer");
    }
    // An operator dispatches but does not manage rules or vehicles.
    let (status, _, _) = call(
        r,
        "POST",
        "/api/rules",
        operator.clone(),
        Some(json!({"id": "r1", "condition": {"type": "threshold", "expr": "battery_pct < 5"}})),
    )
    .await;
    assert_eq!(status, StatusCode::FORBIDDEN);
    let (status, _, body) = call(r, "POST", "/api/missions", operator.clone(), Some(mission)).await;
    // Past the guard: the station itself refuses an unknown vehicle.
    assert_eq!(
        status,
        StatusCode::CONFLICT,
        "{}",
        String::from_utf8_lossy(&body)
    );
    // An admin manages rules.
    let (status, _, body) = call(
        r,
        "POST",
        "/api/rules",
        admin.clone(),
        Some(json!({"id": "r1", "condition": {"type": "threshold", "expr": "battery_pct < 5"}})),
    )
    .await;
    assert_eq!(
        status,
        StatusCode::CREATED,
        "{}",
        String::from_utf8_lossy(&body)
    );

    // Logging out ends the session.
    let (status, _, _) = call(r, "POST", "/api/auth/logout", viewer.clone(), None).await;
    assert_eq!(status, StatusCode::NO_CONTENT);
    assert_eq!(
        call(r, "GET", "/api/fleet", viewer, None).await.0,
        StatusCode::UNAUTHORIZED
    );
    // The live feed refuses pages from other sites even with a valid session.
    let req = Request::builder()
        .uri("/api/ws")
        .header(header::COOKIE, admin.unwrap().1)
        .header(header::HOST, "127.0.0.1:8640")
        .header(header::ORIGIN, "http://evil.example")
        .body(Body::empty())
        .unwrap();
    let res = r.clone().oneshot(req).await.unwrap();
    assert_eq!(res.status(), StatusCode::FORBIDDEN);
    f.shutdown.cancel();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_missions_log_exports_as_csv_and_geojson() {
    let f = start(142);
    let r = &f.router;
    let token = bearer(&f.admin_token);
    let h = &f.handle;
    let (status, _, body) = call(
        r,
        "POST",
        "/api/vehicles",
        token.clone(),
        Some(serde_json::to_value(announcement("auv-x")).unwrap()),
    )
    .await;
    assert_eq!(
        status,
        StatusCode::CREATED,
        "{}",
        String::from_utf8_lossy(&body)
    );
    h.ingest_state(state("auv-x", now_ms(), 63.46)).unwrap();
    let spec = json!({"mission_id": "m-exp", "name": "export", "tasks": [{"vehicle_id": "auv-x",
        "task": {"kind": "goto_waypoint", "target": {"latitude_deg": 63.461, "longitude_deg": 10.37},
                 "depth_m": 5.0, "speed_mps": 1.0}}]});
    let (status, _, body) = call(
        r,
        "POST",
        "/api/missions?start=true",
        token.clone(),
        Some(spec),
    )
    .await;
    assert_eq!(
        status,
        StatusCode::CREATED,
        "{}",
        String::from_utf8_lossy(&body)
    );
    // States stamped after the start (and not after now) are in the running mission's window.
    tokio::time::sleep(Duration::from_millis(400)).await;
    let t0 = now_ms() - 300;
    for i in 0..3 {
        h.ingest_state(state("auv-x", t0 + i * 100, 63.46 + 0.00001 * i as f64))
            .unwrap();
    }
    h.flush_history(Duration::from_secs(10)).unwrap();

    let (status, headers, body) = call(
        r,
        "GET",
        "/api/missions/m-exp/export.csv",
        token.clone(),
        None,
    )
    .await;
    assert_eq!(status, StatusCode::OK);
    assert!(
        headers[header::CONTENT_TYPE]
            .to_str()
            .unwrap()
            .starts_with("text/csv")
    );
    assert!(
        headers[header::CONTENT_DISPOSITION]
            .to_str()
            .unwrap()
            .contains("m-exp.csv")
    );
    let csv = String::from_utf8(body).unwrap();
    let rows: Vec<&str> = csv.lines().skip(1).collect();
    assert!(rows.len() >= 3, "{csv}");
    assert!(rows.iter().all(|l| l.starts_with("m-exp,auv-x,")));

    let (status, _, body) = call(
        r,
        "GET",
        "/api/missions/m-exp/export.geojson",
        token.clone(),
        None,
    )
    .await;
    assert_eq!(status, StatusCode::OK);
    let g = json_of(&body);
    assert_eq!(g["mission"]["mission_id"], "m-exp");
    assert_eq!(g["features"][0]["geometry"]["type"], "LineString");
    assert_eq!(g["features"][1]["properties"]["feature"], "task");

    let (status, _, body) = call(
        r,
        "GET",
        "/api/missions/nope/export.csv",
        token.clone(),
        None,
    )
    .await;
    assert_eq!(status, StatusCode::NOT_FOUND);
    assert!(json_of(&body)["error"].as_str().unwrap().contains("nope"));
    // Unknown API paths answer JSON, the status page stays reachable without JavaScript.
    let (status, _, body) = call(r, "GET", "/api/no-such-thing", token.clone(), None).await;
    assert_eq!(status, StatusCode::NOT_FOUND);
    assert!(json_of(&body)["error"].is_string());
    let (status, _, body) = call(r, "GET", "/status.html", None, None).await;
    assert_eq!(status, StatusCode::OK);
    assert!(String::from_utf8_lossy(&body).contains("/api/fleet"));
    f.shutdown.cancel();
}
