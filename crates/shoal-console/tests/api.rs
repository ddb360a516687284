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
    start_with(domain_id, |c| c)
}

/// A station whose configuration `tune` adjusts (shorter contact timeouts, say).
fn start_with(domain_id: u16, tune: impl FnOnce(StationConfig) -> StationConfig) -> Fixture {
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
    let config = tune(StationConfig {
        summary_interval_s: 0.0,
        rules_path: dir.path().join("rules.json"),
        ..StationConfig::default()
    });
    let station = Station::new(config, dds, history).unwrap();
    let handle = station.handle();
    let shutdown = CancellationToken::new();
    let s = shutdown.clone();
    tokio::spawn(async move { station.run(s).await });
    let (auth, boot) = Auth::load(&AuthConfig {
        users_path: dir.path().join("users.json"),
        session_ttl_s: 600,
        ..AuthConfig::default()
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

/// Sends a request; `auth` is a full header value for Authorization or Cookie. With a
/// session cookie it sends what the console's page would: its Origin and, on a change,
/// the session's CSRF token.
async fn call(
    router: &Router,
    method: &str,
    uri: &str,
    auth: Option<(header::HeaderName, String)>,
    body: Option<Value>,
) -> (StatusCode, axum::http::HeaderMap, Vec<u8>) {
    let mut req = Request::builder().method(method).uri(uri);
    if let Some((name, value)) = auth {
        if name == header::COOKIE {
            let session = value.split_once('=').unwrap().1;
            req = req.header(header::ORIGIN, "http://127.0.0.1:8640").header(
                shoal_console::auth::CSRF_HEADER,
                shoal_console::auth::csrf_of(session),
            );
        }
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

/// [`call`], asserting the status; the body.
async fn expect(
    router: &Router,
    method: &str,
    uri: &str,
    auth: Option<(header::HeaderName, String)>,
    body: Option<Value>,
    status: StatusCode,
) -> Vec<u8> {
    let (got, _, bytes) = call(router, method, uri, auth, body).await;
    assert_eq!(
        got,
        status,
        "{method} {uri}: {}",
        String::from_utf8_lossy(&bytes)
    );
    bytes
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
    // The page learns its CSRF token from the login's answer.
    let session = pair.split_once('=').unwrap().1;
    assert_eq!(
        json_of(&body)["csrf_token"].as_str(),
        Some(shoal_console::auth::csrf_of(session).as_str())
    );
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
    let body = expect(r, "GET", "/api/fleet", None, None, StatusCode::UNAUTHORIZED).await;
    assert!(json_of(&body)["error"].as_str().unwrap().contains("log in"));
    expect(r, "GET", "/api/ws", None, None, StatusCode::UNAUTHORIZED).await;
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
    let body = expect(r, "GET", "/api/auth/session", None, None, StatusCode::OK).await;
    assert_eq!(json_of(&body)["enabled"], true);
    assert_eq!(json_of(&body)["user"], Value::Null);

    // Wrong password: 401, explained.
    let body = expect(
        r,
        "POST",
        "/api/auth/login",
        None,
        Some(json!({"user": "admin", "password": "nope"})),
        StatusCode::UNAUTHORIZED,
    )
    .await;
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

    // The last admin can be neither demoted nor deleted: a conflict with the station's
    // state (409), not a malformed request.
    for (method, uri, body) in [
        (
            "POST",
            "/api/auth/users",
            Some(json!({"name": "admin", "password": "long enough pw", "role": "operator"})),
        ),
        ("DELETE", "/api/auth/users/admin", None),
    ] {
        let body = expect(r, method, uri, token.clone(), body, StatusCode::CONFLICT).await;
        assert!(
            json_of(&body)["error"]
                .as_str()
                .unwrap()
                .contains("last admin"),
            "{method} {uri}"
        );
    }

    // A viewer reads and queries, but changes nothing.
    assert_eq!(
        call(r, "GET", "/api/fleet", viewer.clone(), None).await.0,
        StatusCode::OK
    );
    let mission = json!({"mission_id": "m-viewer", "tasks": [{"vehicle_id": "auv-9",
        "task": {"kind": "goto_waypoint", "target": {"latitude_deg": 63.46, "longitude_deg": 10.37},
                 "depth_m": 5.0, "speed_mps": 1.0}}]});
    let body = expect(
        r,
        "POST",
        "/api/missions?start=true",
        viewer.clone(),
        Some(mission.clone()),
        StatusCode::FORBIDDEN,
    )
    .await;
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
    expect(
        r,
        "POST",
        "/api/rules",
        operator.clone(),
        Some(json!({"id": "r1", "condition": {"type": "threshold", "expr": "battery_pct < 5"}})),
        StatusCode::FORBIDDEN,
    )
    .await;
    let (status, _, body) = call(r, "POST", "/api/missions", operator.clone(), Some(mission)).await;
    // Past the guard: the station itself refuses an unknown vehicle.
    assert_eq!(
        status,
        StatusCode::CONFLICT,
        "{}",
        String::from_utf8_lossy(&body)
    );
    // An admin manages rules.
    expect(
        r,
        "POST",
        "/api/rules",
        admin.clone(),
        Some(json!({"id": "r1", "condition": {"type": "threshold", "expr": "battery_pct < 5"}})),
        StatusCode::CREATED,
    )
    .await;

    // Logging out ends the session.
    expect(
        r,
        "POST",
        "/api/auth/logout",
        viewer.clone(),
        None,
        StatusCode::NO_CONTENT,
    )
    .await;
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
    expect(
        r,
        "POST",
        "/api/vehicles",
        token.clone(),
        Some(serde_json::to_value(announcement("auv-x")).unwrap()),
        StatusCode::CREATED,
    )
    .await;
    h.ingest_state(state("auv-x", now_ms(), 63.46)).unwrap();
    let spec = json!({"mission_id": "m-exp", "name": "export", "tasks": [{"vehicle_id": "auv-x",
        "task": {"kind": "goto_waypoint", "target": {"latitude_deg": 63.461, "longitude_deg": 10.37},
                 "depth_m": 5.0, "speed_mps": 1.0}}]});
    expect(
        r,
        "POST",
        "/api/missions?start=true",
        token.clone(),
        Some(spec),
        StatusCode::CREATED,
    )
    .await;
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

    let body = expect(
        r,
        "GET",
        "/api/missions/m-exp/export.geojson",
        token.clone(),
        None,
        StatusCode::OK,
    )
    .await;
    let g = json_of(&body);
    assert_eq!(g["mission"]["mission_id"], "m-exp");
    assert_eq!(g["features"][0]["geometry"]["type"], "LineString");
    assert_eq!(g["features"][1]["properties"]["feature"], "task");

    let body = expect(
        r,
        "GET",
        "/api/missions/nope/export.csv",
        token.clone(),
        None,
        StatusCode::NOT_FOUND,
    )
    .await;
    assert!(json_of(&body)["error"].as_str().unwrap().contains("nope"));
    // Unknown API paths answer JSON, the status page stays reachable without JavaScript.
    let body = expect(
        r,
        "GET",
        "/api/no-such-thing",
        token.clone(),
        None,
        StatusCode::NOT_FOUND,
    )
    .await;
    assert!(json_of(&body)["error"].is_string());
    let body = expect(r, "GET", "/status.html", None, None, StatusCode::OK).await;
    assert!(String::from_utf8_lossy(&body).contains("/api/fleet"));
    f.shutdown.cancel();
}

/// `POST /api/tasks` takes a task as a person writes it (`{vehicle_id, task}`, the id
/// filled in when left out) beside the wire form, and refuses a body that is neither,
/// naming the member at fault.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_single_task_is_ordered_in_the_missions_own_words() {
    let f = start(150);
    let r = &f.router;
    let token = bearer(&f.admin_token);
    expect(
        r,
        "POST",
        "/api/vehicles",
        token.clone(),
        Some(serde_json::to_value(announcement("auv-o")).unwrap()),
        StatusCode::CREATED,
    )
    .await;
    f.handle
        .ingest_state(state("auv-o", now_ms(), 63.46))
        .unwrap();
    let survey = json!({"vehicle_id": "auv-o", "task": {"kind": "survey_area",
        "polygon": [{"latitude_deg": 63.46, "longitude_deg": 10.37},
                    {"latitude_deg": 63.461, "longitude_deg": 10.37},
                    {"latitude_deg": 63.461, "longitude_deg": 10.372}],
        "line_spacing_m": 20.0, "altitude_m": 8.0, "speed_mps": 1.0}});
    let body = expect(
        r,
        "POST",
        "/api/tasks",
        token.clone(),
        Some(survey),
        StatusCode::ACCEPTED,
    )
    .await;
    let id = json_of(&body)["task_id"].as_str().unwrap().to_string();
    assert!(id.starts_with("task-"), "{id}");
    let body = expect(
        r,
        "GET",
        &format!("/api/tasks/{id}"),
        token.clone(),
        None,
        StatusCode::OK,
    )
    .await;
    let view = json_of(&body);
    assert_eq!(view["assignment"]["kind"], "survey_area", "{view}");
    assert_eq!(view["assignment"]["altitude_m"], 8.0, "{view}");
    assert_eq!(
        view["assignment"]["area"].as_array().map(Vec::len),
        Some(3),
        "{view}"
    );
    assert_eq!(view["assignment"]["mission_id"], "", "{view}");
    // With an id of the operator's choosing; a second order with it is refused.
    let goto = json!({"task_id": "t-mine", "vehicle_id": "auv-o", "task": {"kind": "goto_waypoint",
        "target": {"latitude_deg": 63.47, "longitude_deg": 10.37}, "depth_m": 5.0, "speed_mps": 1.0}});
    expect(
        r,
        "POST",
        "/api/tasks",
        token.clone(),
        Some(goto.clone()),
        StatusCode::ACCEPTED,
    )
    .await;
    expect(
        r,
        "POST",
        "/api/tasks",
        token.clone(),
        Some(goto),
        StatusCode::CONFLICT,
    )
    .await;
    // A typed task with a member of the wire form is neither: refused, the member named.
    let mixed = json!({"vehicle_id": "auv-o", "issue_seq": 3, "task": {"kind": "surface"}});
    let body = expect(
        r,
        "POST",
        "/api/tasks",
        token.clone(),
        Some(mixed),
        StatusCode::UNPROCESSABLE_ENTITY,
    )
    .await;
    assert!(
        String::from_utf8_lossy(&body).contains("issue_seq"),
        "{}",
        String::from_utf8_lossy(&body)
    );
    let bad = json!({"vehicle_id": "auv-o", "task": {"kind": "goto_waypoint", "speed_mps": 1.0}});
    let body = expect(
        r,
        "POST",
        "/api/tasks",
        token.clone(),
        Some(bad),
        StatusCode::UNPROCESSABLE_ENTITY,
    )
    .await;
    assert!(
        String::from_utf8_lossy(&body).contains("target"),
        "{}",
        String::from_utf8_lossy(&body)
    );
    f.shutdown.cancel();
}

/// The plan preview: figures per vehicle from its kind's kinematics, a warning when the
/// battery would not last, the same refusals as planning, and nothing registered; a viewer
/// may preview (it changes nothing) but not plan.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_mission_preview_estimates_each_vehicle_and_registers_nothing() {
    let f = start(148);
    let r = &f.router;
    let token = bearer(&f.admin_token);
    let h = &f.handle;
    expect(
        r,
        "POST",
        "/api/vehicles",
        token.clone(),
        Some(serde_json::to_value(announcement("auv-p")).unwrap()),
        StatusCode::CREATED,
    )
    .await;
    h.ingest_state(state("auv-p", now_ms(), 63.46)).unwrap();
    let goto = |lat: f64| {
        json!({"kind": "goto_waypoint", "target": {"latitude_deg": lat, "longitude_deg": 10.37},
               "depth_m": 5.0, "speed_mps": 1.5})
    };
    let spec = |lat: f64| {
        json!({"mission_id": "m-pre", "tasks": [
            {"vehicle_id": "auv-p", "task": goto(lat)},
            {"vehicle_id": "auv-p", "task": goto(63.46)}]})
    };
    let body = expect(
        r,
        "POST",
        "/api/mission-preview",
        token.clone(),
        Some(spec(63.47)),
        StatusCode::OK,
    )
    .await;
    let p = json_of(&body);
    let v = &p["vehicles"][0];
    assert_eq!(v["vehicle_id"], "auv-p");
    assert_eq!(v["tasks"], 2);
    // 0.01 degrees of latitude and back at 1.5 m/s.
    let distance = v["distance_m"].as_f64().unwrap();
    assert!((distance - 2.0 * 1113.0).abs() < 10.0, "{p}");
    let duration = v["duration_s"].as_f64().unwrap();
    assert!((duration - distance / 1.5).abs() < 1e-6, "{p}");
    assert_eq!(p["duration_s"].as_f64(), Some(duration));
    assert_eq!(v["battery_pct"], 90.0);
    assert_eq!(p["warnings"], false, "{p}");
    // 40 km at 1.5 m/s would take more battery than it has.
    let body = expect(
        r,
        "POST",
        "/api/mission-preview",
        token.clone(),
        Some(spec(63.82)),
        StatusCode::OK,
    )
    .await;
    let p = json_of(&body);
    assert_eq!(p["warnings"], true, "{p}");
    assert!(
        p["vehicles"][0]["warnings"][0]
            .as_str()
            .unwrap()
            .contains("would run out"),
        "{p}"
    );
    // Refused as planning refuses: an unknown vehicle, a bad body.
    let ghost =
        json!({"mission_id": "m-ghost", "tasks": [{"vehicle_id": "ghost", "task": goto(63.47)}]});
    expect(
        r,
        "POST",
        "/api/mission-preview",
        token.clone(),
        Some(ghost),
        StatusCode::CONFLICT,
    )
    .await;
    expect(
        r,
        "POST",
        "/api/mission-preview",
        token.clone(),
        Some(json!({"tasks": 3})),
        StatusCode::UNPROCESSABLE_ENTITY,
    )
    .await;
    // Nothing was registered.
    expect(
        r,
        "GET",
        "/api/missions/m-pre",
        token.clone(),
        None,
        StatusCode::NOT_FOUND,
    )
    .await;
    // A viewer may preview, not plan.
    let (status, _, _) = call(
        r,
        "POST",
        "/api/auth/users",
        token.clone(),
        Some(json!({"name": "vera", "password": "a long viewer password", "role": "viewer"})),
    )
    .await;
    assert!(status.is_success(), "{status}");
    let viewer = login(r, "vera", "a long viewer password").await;
    expect(
        r,
        "POST",
        "/api/mission-preview",
        viewer.clone(),
        Some(spec(63.47)),
        StatusCode::OK,
    )
    .await;
    expect(
        r,
        "POST",
        "/api/missions",
        viewer,
        Some(spec(63.47)),
        StatusCode::FORBIDDEN,
    )
    .await;
    f.shutdown.cancel();
}

/// A vehicle with these sensors and announced capabilities.
fn equipped(id: &str, kind: VehicleKind, sensors: &[&str], caps: &[&str]) -> VehicleAnnouncement {
    VehicleAnnouncement {
        kind,
        sensors: sensors.iter().map(|s| (*s).to_owned()).collect(),
        capabilities: caps.iter().map(|s| (*s).to_owned()).collect(),
        ..announcement(id)
    }
}

fn candidate<'a>(answer: &'a Value, id: &str) -> &'a Value {
    answer["vehicles"]
        .as_array()
        .unwrap()
        .iter()
        .find(|v| v["vehicle_id"] == id)
        .unwrap_or_else(|| panic!("{id} not listed: {answer}"))
}

fn strings(v: &Value) -> Vec<&str> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_str().unwrap())
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn capable_vehicles_come_from_the_semantic_model() {
    let f = start(143);
    let r = &f.router;
    let token = bearer(&f.admin_token);
    let h = &f.handle;
    let fleet = [
        // Side-scan sonar: sidescan_survey and seabed_imaging are inferred, not declared.
        equipped(
            "auv-s",
            VehicleKind::Auv,
            &["sidescan_sonar", "ctd"],
            &["goto", "survey"],
        ),
        // Declares sidescan_survey without the sensor: declared counts too.
        equipped(
            "auv-d",
            VehicleKind::Auv,
            &["ctd"],
            &["goto", "survey", "sidescan_survey"],
        ),
        equipped("auv-c", VehicleKind::Auv, &["ctd"], &["goto", "survey"]),
        // A synthetic aperture sonar is a side-scan sonar (sub-class in the ontology).
        equipped("auv-sas", VehicleKind::Auv, &["sas"], &["goto", "survey"]),
        equipped("rov-x", VehicleKind::Rov, &["camera"], &["goto"]),
        equipped(
            "auv-low",
            VehicleKind::Auv,
            &["sidescan_sonar"],
            &["goto", "survey"],
        ),
        // Its sonar gives it sidescan_survey, but a survey_area task also needs "survey",
        // which nothing but an announcement gives.
        equipped("usv-n", VehicleKind::Usv, &["sidescan_sonar"], &["goto"]),
    ];
    for a in fleet {
        let (status, _, body) = call(
            r,
            "POST",
            "/api/vehicles",
            token.clone(),
            Some(serde_json::to_value(&a).unwrap()),
        )
        .await;
        assert_eq!(
            status,
            StatusCode::CREATED,
            "{}",
            String::from_utf8_lossy(&body)
        );
        let mut s = state(&a.vehicle_id, now_ms(), 63.46);
        if a.vehicle_id == "auv-low" {
            s.battery_pct = 10.0;
        }
        h.ingest_state(s).unwrap();
    }

    let body = expect(
        r,
        "GET",
        "/api/fleet/capable?kind=survey_area&capability=sidescan_survey",
        token.clone(),
        None,
        StatusCode::OK,
    )
    .await;
    let a = json_of(&body);
    assert_eq!(a["kind"], "survey_area");
    let req: Vec<(&str, &str)> = a["requires"]
        .as_array()
        .unwrap()
        .iter()
        .map(|q| {
            (
                q["capability"].as_str().unwrap(),
                q["from"].as_str().unwrap(),
            )
        })
        .collect();
    assert_eq!(req, [("survey", "kind"), ("sidescan_survey", "request")]);

    let s = candidate(&a, "auv-s");
    assert_eq!(
        (s["capable"].as_bool(), s["dispatchable"].as_bool()),
        (Some(true), Some(true)),
        "{s}"
    );
    let sss = &s["capabilities"][1];
    assert_eq!(sss["capability"], "sidescan_survey");
    assert_eq!(sss["declared"], false);
    assert_eq!(strings(&sss["inferred_from"]), ["sidescan_sonar"]);
    assert_eq!(s["capabilities"][0]["declared"], true);
    let d = candidate(&a, "auv-d");
    assert_eq!(d["dispatchable"], true, "{d}");
    assert_eq!(d["capabilities"][1]["declared"], true);
    assert_eq!(
        strings(&candidate(&a, "auv-sas")["capabilities"][1]["inferred_from"]),
        ["sas"]
    );
    assert_eq!(candidate(&a, "auv-sas")["dispatchable"], true);

    let c = candidate(&a, "auv-c");
    assert_eq!(c["capable"], false);
    assert_eq!(strings(&c["missing"]), ["sidescan_survey"]);
    assert!(strings(&c["reasons"])[0].contains("sidescan_survey"), "{c}");
    let x = candidate(&a, "rov-x");
    assert_eq!(strings(&x["missing"]), ["survey", "sidescan_survey"]);
    // The station's own refusal ("no survey capability") is not repeated.
    assert_eq!(x["reasons"].as_array().unwrap().len(), 2, "{x}");

    let low = candidate(&a, "auv-low");
    assert_eq!(
        (low["capable"].as_bool(), low["dispatchable"].as_bool()),
        (Some(true), Some(false))
    );
    assert!(strings(&low["reasons"])[0].contains("battery"), "{low}");
    assert_eq!(low["battery_pct"], 10.0);
    let n = candidate(&a, "usv-n");
    assert_eq!(n["capable"], false, "{n}");
    assert_eq!(strings(&n["missing"]), ["survey"]);

    // Dispatchable first, then capable, then the rest; by id within each.
    let order: Vec<&str> = a["vehicles"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v["vehicle_id"].as_str().unwrap())
        .collect();
    assert_eq!(
        order,
        [
            "auv-d", "auv-s", "auv-sas", "auv-low", "auv-c", "rov-x", "usv-n"
        ]
    );

    // A capability alone: the sonar also enables seabed imaging. Without a task kind the
    // station's task checks do not apply, only contact.
    let body = expect(
        r,
        "GET",
        "/api/fleet/capable?capability=seabed_imaging",
        token.clone(),
        None,
        StatusCode::OK,
    )
    .await;
    let a = json_of(&body);
    assert_eq!(a["kind"], Value::Null);
    for (id, capable) in [
        ("auv-s", true),
        ("usv-n", true),
        ("auv-c", false),
        ("auv-d", false),
    ] {
        let v = candidate(&a, id);
        assert_eq!(v["capable"], capable, "{v}");
        assert_eq!(v["dispatchable"], capable, "{v}");
    }
    // A task kind that needs nothing of the ontology (abort): every vehicle, even incapable.
    let body = expect(
        r,
        "GET",
        "/api/fleet/capable?kind=abort",
        token.clone(),
        None,
        StatusCode::OK,
    )
    .await;
    let a = json_of(&body);
    assert_eq!(a["requires"], json!([]));
    assert!(
        a["vehicles"]
            .as_array()
            .unwrap()
            .iter()
            .all(|v| v["dispatchable"] == true),
        "{a}"
    );

    // Wrong questions are explained.
    for (uri, expect) in [
        ("/api/fleet/capable", "kind="),
        ("/api/fleet/capable?kind=fly", "unknown task kind"),
        (
            "/api/fleet/capable?capability=teleport",
            "neither in the ontology",
        ),
        (
            "/api/fleet/capable?capability=x%22%7D%20UNION",
            "not a code",
        ),
        ("/api/fleet/capable?kind=goto_waypoint&colour=red", "colour"),
        ("/api/fleet/capable?capability=a,b,c,d,e,f,g,h,i", "at most"),
    ] {
        let (status, _, body) = call(r, "GET", uri, token.clone(), None).await;
        assert_eq!(status, StatusCode::BAD_REQUEST, "{uri}");
        let msg = json_of(&body)["error"].as_str().unwrap().to_owned();
        assert!(msg.contains(expect), "{uri}: {msg}");
    }
    // A viewer may ask.
    expect(
        r,
        "GET",
        "/api/fleet/capable?kind=hold",
        None,
        None,
        StatusCode::UNAUTHORIZED,
    )
    .await;
    f.shutdown.cancel();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_rule_is_edited_in_place_and_checked_like_a_new_one() {
    let f = start(144);
    let r = &f.router;
    let token = bearer(&f.admin_token);
    let rule = |body: &[u8]| json_of(body);
    expect(
        r,
        "POST",
        "/api/rules",
        token.clone(),
        Some(
            json!({"id": "r-edit", "description": "deep", "severity": "info",
                    "condition": {"type": "threshold", "expr": "depth_m > 900"}}),
        ),
        StatusCode::CREATED,
    )
    .await;

    // A new condition and severity; the description stays.
    let body = expect(
        r,
        "PATCH",
        "/api/rules/r-edit",
        token.clone(),
        Some(
            json!({"severity": "alarm", "condition": {"type": "threshold", "expr": "depth_m > 3"}}),
        ),
        StatusCode::OK,
    )
    .await;
    let doc = rule(&body);
    assert_eq!(doc["condition"]["expr"], "depth_m > 3");
    assert_eq!(doc["severity"], "alarm");
    assert_eq!(doc["description"], "deep");
    assert_eq!(doc["enabled"], true);
    // Saved for the next start.
    let saved = std::fs::read_to_string(f._dir.path().join("rules.json")).unwrap();
    assert!(
        saved.contains("depth_m > 3") && !saved.contains("depth_m > 900"),
        "{saved}"
    );
    // And in force: a state 4 m deep fires it.
    f.handle.register_vehicle(announcement("auv-r")).unwrap();
    f.handle
        .ingest_state(state("auv-r", now_ms(), 63.46))
        .unwrap();
    let mut fired = false;
    for _ in 0..50 {
        let (_, _, body) = call(r, "GET", "/api/events", token.clone(), None).await;
        if String::from_utf8_lossy(&body).contains("r-edit") {
            fired = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert!(fired, "the edited rule did not fire");

    // A definition the parser refuses: 400 with its message, the rule unchanged.
    for bad in [
        json!({"condition": {"type": "threshold", "expr": "no_such_field > 3"}}),
        json!({"condition": {"type": "threshold", "expr": "depth_m >"}}),
        json!({"condition": {"type": "sparql", "query": "ASK { ?this shoal:batteryLevel ?b FILTER(?b < 15 }", "watches": ["shoal:batteryLevel"]}}),
        json!({"condition": {"type": "sparql", "query": "ASK { ?this shoal:batteryLevel ?b }", "watches": []}}),
        json!({"condition": {"type": "sparql", "query": "ASK { ?s ?p ?o }", "watches": ["shoal:batteryLevel"]}}),
        json!({"description": "x".repeat(600)}),
    ] {
        let (status, _, body) = call(
            r,
            "PATCH",
            "/api/rules/r-edit",
            token.clone(),
            Some(bad.clone()),
        )
        .await;
        assert_eq!(
            status,
            StatusCode::BAD_REQUEST,
            "{bad}: {}",
            String::from_utf8_lossy(&body)
        );
        assert!(!json_of(&body)["error"].as_str().unwrap().is_empty());
        let (_, _, body) = call(r, "GET", "/api/rules/r-edit", token.clone(), None).await;
        let now = rule(&body);
        assert_eq!(
            now["condition"]["expr"], "depth_m > 3",
            "{bad} changed the rule"
        );
        assert_eq!(now["severity"], "alarm");
        assert_eq!(now["enabled"], true);
    }
    let (_, _, body) = call(
        r,
        "PATCH",
        "/api/rules/r-edit",
        token.clone(),
        Some(json!({"condition": {"type": "sparql", "query": "ASK { ?this shoal:batteryLevel ?b FILTER(?b < 15 }", "watches": ["shoal:batteryLevel"]}})),
    )
    .await;
    assert!(
        json_of(&body)["error"]
            .as_str()
            .unwrap()
            .contains("does not parse"),
        "{}",
        String::from_utf8_lossy(&body)
    );

    // Switching alone still works; a later redefinition keeps it off.
    let body = expect(
        r,
        "PATCH",
        "/api/rules/r-edit",
        token.clone(),
        Some(json!({"enabled": false})),
        StatusCode::OK,
    )
    .await;
    assert_eq!(rule(&body)["enabled"], false);
    let redefined = json!({"description": "deeper", "condition": {"type": "sparql",
        "query": "ASK { ?this shoal:batteryLevel ?b FILTER(?b < 15) }",
        "watches": ["shoal:batteryLevel"]}});
    let body = expect(
        r,
        "PATCH",
        "/api/rules/r-edit",
        token.clone(),
        Some(redefined),
        StatusCode::OK,
    )
    .await;
    let doc = rule(&body);
    assert_eq!(
        (doc["enabled"].as_bool(), doc["condition"]["type"].as_str()),
        (Some(false), Some("sparql"))
    );
    assert_eq!(doc["description"], "deeper");
    // The whole document as GET gave it can be sent back.
    expect(
        r,
        "PATCH",
        "/api/rules/r-edit",
        token.clone(),
        Some(doc.clone()),
        StatusCode::OK,
    )
    .await;

    // What cannot be done is explained.
    for (uri, body, want, text) in [
        (
            "/api/rules/r-edit",
            json!({}),
            StatusCode::BAD_REQUEST,
            "nothing to change",
        ),
        (
            "/api/rules/r-edit",
            json!({"id": "other", "description": "y"}),
            StatusCode::BAD_REQUEST,
            "renamed",
        ),
        (
            "/api/rules/r-edit",
            json!({"built_in": true}),
            StatusCode::BAD_REQUEST,
            "built_in",
        ),
        (
            "/api/rules/r-edit",
            json!({"colour": "red"}),
            StatusCode::UNPROCESSABLE_ENTITY,
            "colour",
        ),
        (
            "/api/rules/r-edit",
            json!({"severity": "fatal"}),
            StatusCode::UNPROCESSABLE_ENTITY,
            "fatal",
        ),
        (
            "/api/rules/nope",
            json!({"enabled": true}),
            StatusCode::NOT_FOUND,
            "nope",
        ),
        (
            "/api/rules/builtin.low_battery",
            json!({"condition": {"type": "threshold", "expr": "battery_pct < 50"}}),
            StatusCode::CONFLICT,
            "built in",
        ),
    ] {
        let (status, _, res) = call(r, "PATCH", uri, token.clone(), Some(body.clone())).await;
        assert_eq!(
            status,
            want,
            "{uri} {body}: {}",
            String::from_utf8_lossy(&res)
        );
        let msg = json_of(&res)["error"].as_str().unwrap().to_owned();
        assert!(msg.contains(text), "{uri} {body}: {msg}");
    }
    // Built-in rules are still switched.
    let body = expect(
        r,
        "PATCH",
        "/api/rules/builtin.low_battery",
        token.clone(),
        Some(json!({"enabled": false})),
        StatusCode::OK,
    )
    .await;
    assert_eq!(rule(&body)["enabled"], false);
    f.shutdown.cancel();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn contact_changes_reach_the_live_feed() {
    let f = start_with(146, |c| StationConfig {
        stale_after_s: 1.0,
        // Two one-second ticks apart, so a loaded machine still sees it stale first.
        lost_after_s: 3.0,
        ..c
    });
    let mut live = f.handle.live();
    f.handle.register_vehicle(announcement("auv-q")).unwrap();
    f.handle
        .ingest_state(state("auv-q", now_ms(), 63.46))
        .unwrap();
    // Nothing more from it: the station must say so itself, stale then lost.
    let mut seen = Vec::new();
    let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
    while !seen.contains(&"lost".to_owned()) {
        let update = tokio::time::timeout_at(deadline, live.recv())
            .await
            .expect("no lost vehicle on the live feed within 10 s")
            .unwrap();
        let u = serde_json::to_value(&update).unwrap();
        if u["type"] == "vehicle" && u["data"]["announcement"]["vehicle_id"] == "auv-q" {
            let c = u["data"]["contact"].as_str().unwrap().to_owned();
            if seen.last() != Some(&c) {
                seen.push(c);
            }
        }
    }
    // Its first state is pushed before the next contact check, while it is still silent.
    if seen.first().is_some_and(|c| c == "silent") {
        seen.remove(0);
    }
    assert_eq!(seen, ["alive", "stale", "lost"]);
    // The editor is told why it is not offered.
    let body = expect(
        &f.router,
        "GET",
        "/api/fleet/capable?kind=goto_waypoint",
        bearer(&f.admin_token),
        None,
        StatusCode::OK,
    )
    .await;
    let a = json_of(&body);
    let q = candidate(&a, "auv-q");
    assert_eq!(
        (q["capable"].as_bool(), q["dispatchable"].as_bool()),
        (Some(true), Some(false))
    );
    assert!(strings(&q["reasons"])[0].contains("lost"), "{q}");
    assert_eq!(q["contact"], "lost");
    f.shutdown.cancel();
}

/// Every path, method, query parameter and error status of `openapi.json` against the
/// router itself: documented methods are served and undocumented ones get 405; no
/// credentials get a documented 401 where the document says credentials are needed;
/// each documented query parameter is accepted by name; and the errors this crate's own
/// extractors produce for a body (not JSON, not an object, not sent as JSON) and for an
/// unknown id are all documented. The document is kept by hand; this keeps it honest.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_openapi_document_matches_what_the_router_answers() {
    let f = start(140);
    let r = &f.router;
    let token = bearer(&f.admin_token);
    let doc: Value = serde_json::from_str(shoal_console::OPENAPI).unwrap();
    let public_by_default = doc["security"].as_array().is_some_and(Vec::is_empty);
    let mut checked = 0;
    let mut check = |what: &str, op: &Value, status: StatusCode, body: &[u8]| {
        checked += 1;
        assert!(
            op["responses"].get(status.as_str()).is_some(),
            "{what}: {status} is not documented ({})",
            String::from_utf8_lossy(body)
        );
        assert!(status != StatusCode::INTERNAL_SERVER_ERROR, "{what}: 500");
    };
    for (path, ops) in doc["paths"].as_object().unwrap() {
        if path == "/api/ws" {
            continue; // a WebSocket upgrade, tested in live.rs and the browser tests
        }
        // Ids that exist nowhere: the 404 paths.
        let uri = path
            .split('/')
            .map(|seg| {
                if seg.starts_with('{') {
                    "no-such-id"
                } else {
                    seg
                }
            })
            .collect::<Vec<_>>()
            .join("/");
        for method in ["GET", "POST", "PUT", "PATCH", "DELETE"] {
            let Some(op) = ops.get(method.to_ascii_lowercase()) else {
                let (status, headers, _) = call(r, method, &uri, token.clone(), None).await;
                assert_eq!(status, StatusCode::METHOD_NOT_ALLOWED, "{method} {uri}");
                assert!(
                    headers.contains_key(header::ALLOW),
                    "{method} {uri}: no Allow"
                );
                continue;
            };
            let what = format!("{method} {path}");
            let public = op.get("security").map_or(public_by_default, |s| {
                s.as_array().is_some_and(Vec::is_empty)
            });
            if !public {
                let (status, _, body) = call(r, method, &uri, None, None).await;
                assert_eq!(
                    status,
                    StatusCode::UNAUTHORIZED,
                    "{what} without credentials"
                );
                check(&what, op, status, &body);
            }
            let params = op["parameters"].as_array().cloned().unwrap_or_default();
            for p in params.iter().filter(|p| p["in"] == "query") {
                let name = p["name"].as_str().unwrap();
                let schema = &p["schema"];
                let sample = match schema["type"].as_str() {
                    Some("integer") => "1".to_owned(),
                    Some("boolean") => "false".to_owned(),
                    _ => schema["enum"][0].as_str().unwrap_or("x").to_owned(),
                };
                let (status, _, body) = call(
                    r,
                    method,
                    &format!("{uri}?{name}={sample}"),
                    token.clone(),
                    None,
                )
                .await;
                check(&format!("{what}?{name}"), op, status, &body);
                let text = String::from_utf8_lossy(&body);
                assert!(
                    !text.contains("unknown field"),
                    "{what}: the documented parameter {name} is refused: {text}"
                );
            }
            if op.get("requestBody").is_some() && path != "/api/sparql" {
                for (content_type, body) in [
                    (Some("application/json"), "{not json"),
                    (Some("application/json"), "[1, 2]"),
                    (Some("text/plain"), "{}"),
                    (None, ""),
                ] {
                    let mut req = Request::builder().method(method).uri(&uri);
                    if let Some((name, value)) = token.clone() {
                        req = req.header(name, value);
                    }
                    if let Some(ct) = content_type {
                        req = req.header(header::CONTENT_TYPE, ct);
                    }
                    let res = r
                        .clone()
                        .oneshot(req.body(Body::from(body)).unwrap())
                        .await
                        .unwrap();
                    let status = res.status();
                    let bytes = res.into_body().collect().await.unwrap().to_bytes();
                    check(
                        &format!("{what} with {content_type:?} {body:?}"),
                        op,
                        status,
                        &bytes,
                    );
                    assert!(status.is_client_error(), "{what} accepted {body:?}");
                    json_of(&bytes);
                }
            } else {
                let (status, _, body) = call(r, method, &uri, token.clone(), None).await;
                check(&what, op, status, &body);
            }
        }
    }
    assert!(checked > 100, "only {checked} answers checked");
    f.shutdown.cancel();
}

/// The acoustic network for the map: a CDT's link report for a registered vehicle shows
/// with its relay, which rides on a USV the station hears; the channel model's range rings
/// grow with the packet error rate.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_acoustic_network_shows_each_link_its_relay_and_the_range_rings() {
    let f = start(149);
    let r = &f.router;
    let token = bearer(&f.admin_token);
    let h = &f.handle;
    for id in ["auv-ac9", "usv-9"] {
        expect(
            r,
            "POST",
            "/api/vehicles",
            token.clone(),
            Some(serde_json::to_value(announcement(id)).unwrap()),
            StatusCode::CREATED,
        )
        .await;
    }
    let now = now_ms();
    h.ingest_state(state("auv-ac9", now, 63.467)).unwrap();
    h.ingest_state(state("usv-9", now, 63.464)).unwrap();
    let before = json_of(
        &expect(
            r,
            "GET",
            "/api/acoustic",
            token.clone(),
            None,
            StatusCode::OK,
        )
        .await,
    );
    assert_eq!(before["links"], json!([]), "no CDT has spoken yet");

    let status = shoal_model::LinkStatus {
        vehicle_id: "auv-ac9".into(),
        link: LinkKind::Acoustic,
        cdt_address: 1,
        vehicle_address: 2,
        rssi_db: Some(-72),
        integrity: Some(180),
        heard_ms: now,
        participant: "0a0b0c".into(),
        cdt_latitude_deg: Some(63.4),
        cdt_longitude_deg: Some(10.3),
        cdt_vehicle: Some("usv-9".into()),
        frames: Some(17),
        interval_s: Some(5.0),
    };
    h.ingest_event(shoal_model::Validated::new(status.to_event()).unwrap())
        .unwrap();

    let doc = json_of(
        &expect(
            r,
            "GET",
            "/api/acoustic",
            token.clone(),
            None,
            StatusCode::OK,
        )
        .await,
    );
    let links = doc["links"].as_array().unwrap();
    assert_eq!(links.len(), 1, "{doc}");
    let l = &links[0];
    assert_eq!(l["vehicle_id"], "auv-ac9");
    assert_eq!(l["link"], "acoustic");
    assert_eq!(
        (&l["cdt_address"], &l["vehicle_address"]),
        (&json!(1), &json!(2))
    );
    assert_eq!((&l["rssi_db"], &l["integrity"]), (&json!(-72), &json!(180)));
    assert_eq!(
        (&l["frames"], &l["cdt_vehicle"]),
        (&json!(17), &json!("usv-9"))
    );
    assert_eq!(l["heard_ms"], now);
    assert_eq!(l["position"]["latitude_deg"], 63.467);
    // The relay rides on usv-9: its modem is where usv-9 last reported, not where the CDT
    // was configured.
    assert_eq!(l["relay_position"]["from"], "carrier");
    assert_eq!(l["relay_position"]["latitude_deg"], 63.464);

    assert_eq!(
        (&doc["frame_bytes"], &doc["bit_rate_bps"]),
        (&json!(64), &json!(976.0))
    );
    let rings = doc["rings"].as_array().unwrap();
    let pers: Vec<f64> = rings.iter().map(|r| r["per"].as_f64().unwrap()).collect();
    assert_eq!(pers, [0.1, 0.5, 0.9]);
    let ranges: Vec<f64> = rings
        .iter()
        .map(|r| r["range_m"].as_f64().unwrap())
        .collect();
    assert!(
        ranges[0] > 100.0 && ranges[0] < ranges[1] && ranges[1] < ranges[2],
        "{ranges:?}"
    );

    // A viewer may read it.
    let who = json!({"name": "vic", "password": "viewer-password-1", "role": "viewer"});
    expect(
        r,
        "POST",
        "/api/auth/users",
        token.clone(),
        Some(who),
        StatusCode::CREATED,
    )
    .await;
    let viewer = login(r, "vic", "viewer-password-1").await;
    expect(r, "GET", "/api/acoustic", viewer, None, StatusCode::OK).await;
    f.shutdown.cancel();
}
