//! Station and simulated vehicles over real DDS in one process; the HTTP API without sockets.

use std::time::Duration;

use axum::body::Body;
use axum::http::{Request, StatusCode};
use http_body_util::BodyExt;
use shoal_dds::{Priority, WriterOptions};
use shoal_history::{History, HistoryConfig};
use shoal_model::{GeoPoint, StateVector, Task, TaskAssignment, TaskState, VehicleKind, now_ms};
use shoal_proxy::sim::SimSpec;
use tokio_util::sync::CancellationToken;
use tower::ServiceExt;

use crate::common::{dds, eventually, start_station};

pub(crate) async fn call(
    router: &axum::Router,
    method: &str,
    uri: &str,
    body: &str,
) -> (StatusCode, serde_json::Value) {
    let req = Request::builder()
        .method(method)
        .uri(uri)
        .header("content-type", "application/json")
        .body(Body::from(body.to_string()))
        .unwrap();
    let resp = router.clone().oneshot(req).await.unwrap();
    let status = resp.status();
    let bytes = resp.into_body().collect().await.unwrap().to_bytes();
    let json = serde_json::from_slice(&bytes).unwrap_or(serde_json::Value::Null);
    (status, json)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_simulated_vehicle_joins_reports_and_executes_a_task() {
    let station = start_station(60);
    let vehicle_stop = CancellationToken::new();
    let spec = SimSpec {
        id: "auv-9".into(),
        kind: VehicleKind::Auv,
        latitude_deg: 63.0,
        longitude_deg: 10.0,
        rate_hz: 5.0,
        battery_pct: 90.0,
    };
    let v = tokio::spawn(shoal_proxy::run_sim(spec, dds(60), vehicle_stop.clone()));
    let h = station.handle.clone();
    eventually(20, "auv-9 to report state", || {
        h.vehicle("auv-9").filter(|v| v.states_accepted >= 3)
    })
    .await;

    // A goto 15 m north: accepted, running, done.
    let target = GeoPoint {
        latitude_deg: 63.000_135,
        longitude_deg: 10.0,
    };
    let task = TaskAssignment::new(
        "task-goto-1",
        "m-1",
        "auv-9",
        now_ms(),
        &Task::GotoWaypoint {
            target,
            depth_m: Some(5.0),
            altitude_m: None,
            speed_mps: 2.0,
        },
    );
    h.dispatch(task).await.unwrap();
    eventually(60, "the goto to be done", || {
        h.tasks().into_iter().find(|t| {
            t.assignment.task_id == "task-goto-1"
                && t.status
                    .as_ref()
                    .is_some_and(|s| s.state == TaskState::Done)
        })
    })
    .await;

    // The API sees the same fleet.
    let router = shoal_console::router(h.clone());
    let (status, fleet) = call(&router, "GET", "/api/fleet", "").await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(fleet[0]["announcement"]["vehicle_id"], "auv-9");
    let (status, track) = call(&router, "GET", "/api/vehicles/auv-9/track?limit=5", "").await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(track.as_array().map(Vec::len), Some(5));

    vehicle_stop.cancel();
    v.await.unwrap().unwrap();
    station.shutdown.cancel();
    let report = station.task.await.unwrap();
    // Every accepted state vector was acknowledged by the history store and is there after
    // a restart: nothing acknowledged is lost.
    let reopened = History::open(&HistoryConfig {
        path: station.db.clone(),
        ..HistoryConfig::default()
    })
    .unwrap();
    assert_eq!(
        reopened.count_states(Some("auv-9")).unwrap(),
        report.stats.states_accepted
    );
    assert!(reopened.task_history("task-goto-1").unwrap().statuses.len() >= 3);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn state_from_an_unknown_vehicle_is_rejected_counted_and_quarantined() {
    let station = start_station(61);
    let rogue = dds(61);
    let w = rogue
        .writer::<StateVector>(WriterOptions::new(Priority::Telemetry))
        .unwrap();
    let s = StateVector {
        vehicle_id: "ghost-1".into(),
        timestamp_ms: now_ms(),
        latitude_deg: 1.0,
        longitude_deg: 2.0,
        depth_m: 3.0,
        altitude_m: -1.0,
        speed_mps: 0.5,
        yaw_deg: 10.0,
        pitch_deg: 0.0,
        roll_deg: 0.0,
        battery_pct: 50.0,
    };
    let h = station.handle.clone();
    // Keep publishing until discovery has matched and the station has seen one.
    let mut n = 0;
    loop {
        let mut sample = s.clone();
        sample.timestamp_ms += n;
        w.write(sample).await.unwrap();
        n += 1;
        if h.stats().rejected.contains_key("unknown_vehicle") {
            break;
        }
        assert!(n < 200, "the station never saw the rogue state vector");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    assert_eq!(h.stats().states_accepted, 0);
    assert!(h.fleet().is_empty());
    let quarantined = eventually(10, "the quarantine row", || {
        h.history().rejected(10).ok().filter(|r| !r.is_empty())
    })
    .await;
    assert_eq!(quarantined[0].reason, "unknown_vehicle");
    assert!(quarantined[0].payload_json.contains("ghost-1"));
    assert_eq!(h.history().count_states(None).unwrap(), 0);
    station.shutdown.cancel();
    station.task.await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_api_explains_bad_requests_and_survives_them() {
    let station = start_station(62);
    let router = shoal_console::router(station.handle.clone());
    let (status, body) = call(&router, "POST", "/api/tasks", "{not json").await;
    assert_eq!(status, StatusCode::BAD_REQUEST);
    assert!(body["error"].as_str().unwrap().len() > 5);

    // JSON of the wrong shape: 422, as the OpenAPI document says.
    let (status, body) = call(&router, "POST", "/api/tasks", r#"{"task_id": 5}"#).await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body}");

    let task = TaskAssignment::new("t-x", "", "nobody", now_ms(), &Task::Surface);
    let (status, body) = call(
        &router,
        "POST",
        "/api/tasks",
        &serde_json::to_string(&task).unwrap(),
    )
    .await;
    assert_eq!(status, StatusCode::NOT_FOUND);
    assert!(body["error"].as_str().unwrap().contains("nobody"));

    let mut bad = TaskAssignment::new(
        "t-y",
        "",
        "auv-1",
        now_ms(),
        &Task::Hold { duration_s: 10.0 },
    );
    bad.duration_s = -5.0;
    let (status, body) = call(
        &router,
        "POST",
        "/api/tasks",
        &serde_json::to_string(&bad).unwrap(),
    )
    .await;
    assert_eq!(status, StatusCode::BAD_REQUEST);
    assert!(
        body["error"].as_str().unwrap().contains("duration_s"),
        "{body}"
    );

    let (status, _) = call(&router, "GET", "/api/vehicles/nobody", "").await;
    assert_eq!(status, StatusCode::NOT_FOUND);
    let (status, _) = call(&router, "GET", "/api/rejected?limit=abc", "").await;
    assert_eq!(status, StatusCode::BAD_REQUEST);

    // The services' other inputs: each bad body is explained, nothing is registered.
    let mut ann = crate::common::auv_announcement("auv-bad-reg");
    ann.max_speed_mps = -1.0;
    let (status, body) = call(
        &router,
        "POST",
        "/api/vehicles",
        &serde_json::to_string(&ann).unwrap(),
    )
    .await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{body}");
    assert!(
        body["error"].as_str().unwrap().contains("max_speed_mps"),
        "{body}"
    );
    assert!(station.handle.vehicle("auv-bad-reg").is_none());
    let (status, body) = call(&router, "POST", "/api/vehicles", "[1, 2]").await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
    // Values the station refuses are 400; JSON of the wrong shape is 422.
    for (bad_sub, expected) in [
        (r#"{"max_rate_hz": 0}"#, StatusCode::BAD_REQUEST),
        (
            r#"{"area": [{"latitude_deg": 1, "longitude_deg": 2}]}"#,
            StatusCode::BAD_REQUEST,
        ),
        (r#"{"property": 5}"#, StatusCode::UNPROCESSABLE_ENTITY),
        (r#"{"colour": "red"}"#, StatusCode::UNPROCESSABLE_ENTITY),
    ] {
        let (status, body) = call(&router, "POST", "/api/environment/subscriptions", bad_sub).await;
        assert_eq!(status, expected, "{bad_sub}: {body}");
    }
    assert!(station.handle.environment_subscriptions().is_empty());
    let (status, body) = call(&router, "POST", "/api/abort-all", r#"{"confirm": false}"#).await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{body}");
    assert!(
        body["error"].as_str().unwrap().contains("confirm"),
        "{body}"
    );
    let (status, _) = call(&router, "POST", "/api/missions", r#"{"mission_id": "m"}"#).await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY);
    let empty = r#"{"mission_id": "m", "tasks": []}"#;
    let (status, body) = call(&router, "POST", "/api/missions", empty).await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{body}");
    assert!(body["error"].as_str().unwrap().contains("tasks"), "{body}");
    let (status, _) = call(&router, "POST", "/api/missions/nope/start", "").await;
    assert_eq!(status, StatusCode::NOT_FOUND);
    let (status, _) = call(
        &router,
        "PATCH",
        "/api/rules/builtin.low_battery",
        r#"{"enabled": "yes"}"#,
    )
    .await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY);
    assert!(station.handle.missions().is_empty());

    let (status, health) = call(&router, "GET", "/api/health", "").await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(health["status"], "ok");
    station.shutdown.cancel();
    station.task.await.unwrap();
}

/// A registered vehicle sends NaN and out-of-range values: each is rejected with its
/// reason, counted, quarantined with its payload, and never stored as valid; the good
/// state vector sent after them is stored.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn nan_and_out_of_range_state_is_rejected_and_good_data_is_kept() {
    use shoal_model::{LinkKind, VehicleAnnouncement};
    let station = start_station(64);
    let vehicle = dds(64);
    let ann = vehicle
        .writer::<VehicleAnnouncement>(WriterOptions::new(Priority::Control))
        .unwrap();
    ann.write(VehicleAnnouncement {
        vehicle_id: "auv-bad".into(),
        name: "faulty".into(),
        kind: VehicleKind::Auv,
        vendor: "test".into(),
        capabilities: vec![],
        sensors: vec![],
        links: vec![LinkKind::Ip],
        max_speed_mps: 2.0,
        timestamp_ms: now_ms(),
    })
    .await
    .unwrap();
    let h = station.handle.clone();
    eventually(20, "the registration", || h.vehicle("auv-bad")).await;
    let w = vehicle
        .writer::<StateVector>(WriterOptions::new(Priority::Telemetry))
        .unwrap();
    let good = StateVector {
        vehicle_id: "auv-bad".into(),
        timestamp_ms: now_ms(),
        latitude_deg: 63.0,
        longitude_deg: 10.0,
        depth_m: 5.0,
        altitude_m: -1.0,
        speed_mps: 1.0,
        yaw_deg: 0.0,
        pitch_deg: 0.0,
        roll_deg: 0.0,
        battery_pct: 50.0,
    };
    let mut nan = good.clone();
    nan.battery_pct = f64::NAN;
    nan.timestamp_ms -= 2;
    let mut far = good.clone();
    far.latitude_deg = 123.0;
    far.timestamp_ms -= 1;
    // Discovery may still be settling: repeat the pair until both are seen.
    let mut sent_good = false;
    for _ in 0..100 {
        w.write_unchecked(nan.clone()).await.unwrap();
        w.write_unchecked(far.clone()).await.unwrap();
        tokio::time::sleep(Duration::from_millis(100)).await;
        let s = h.stats();
        if s.rejected.contains_key("not_finite:battery_pct")
            && s.rejected.contains_key("out_of_range:latitude_deg")
        {
            w.write(good.clone()).await.unwrap();
            sent_good = true;
            break;
        }
    }
    assert!(
        sent_good,
        "the station never saw the bad samples: {:?}",
        h.stats()
    );
    eventually(20, "the good sample", || {
        (h.stats().states_accepted == 1).then_some(())
    })
    .await;
    let quarantine = eventually(10, "quarantine rows", || {
        h.history().rejected(1000).ok().filter(|r| r.len() >= 2)
    })
    .await;
    assert!(
        quarantine
            .iter()
            .any(|r| r.reason == "not_finite:battery_pct" && r.payload_json.contains("auv-bad"))
    );
    assert!(
        quarantine
            .iter()
            .any(|r| r.reason == "out_of_range:latitude_deg" && r.payload_json.contains("123"))
    );
    let rejected_count = h.vehicle("auv-bad").unwrap().states_rejected;
    assert!(rejected_count >= 2);
    // Only the good one is in the history, and it is the latest state.
    eventually(10, "the good one committed", || {
        (h.history().count_states(Some("auv-bad")).unwrap() == 1).then_some(())
    })
    .await;
    assert_eq!(
        h.vehicle("auv-bad").unwrap().latest.unwrap().latitude_deg,
        63.0
    );
    station.shutdown.cancel();
    station.task.await.unwrap();
}

/// The semantic model follows the data: a low battery fires the built-in rule as the state
/// arrives, and SPARQL over the HTTP API (SPARQL 1.1 Protocol) sees the vehicle, its class
/// from the ontology, and its battery; bad queries are explained, updates refused.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rules_fire_on_insert_and_sparql_sees_the_swarm() {
    use shoal_model::{EventKind, LinkKind, VehicleAnnouncement};
    let station = start_station(65);
    let vehicle = dds(65);
    let ann = vehicle
        .writer::<VehicleAnnouncement>(WriterOptions::new(Priority::Control))
        .unwrap();
    ann.write(VehicleAnnouncement {
        vehicle_id: "glider-7".into(),
        name: "low glider".into(),
        kind: VehicleKind::Glider,
        vendor: "test".into(),
        capabilities: vec!["survey".into()],
        sensors: vec!["ctd".into()],
        links: vec![LinkKind::Acoustic],
        max_speed_mps: 0.5,
        timestamp_ms: now_ms(),
    })
    .await
    .unwrap();
    let h = station.handle.clone();
    eventually(20, "the registration", || h.vehicle("glider-7")).await;
    let w = vehicle
        .writer::<StateVector>(WriterOptions::new(Priority::Telemetry))
        .unwrap();
    let state = StateVector {
        vehicle_id: "glider-7".into(),
        timestamp_ms: now_ms(),
        latitude_deg: 63.45,
        longitude_deg: 10.39,
        depth_m: 30.0,
        altitude_m: 40.0,
        speed_mps: 0.3,
        yaw_deg: 180.0,
        pitch_deg: -20.0,
        roll_deg: 0.0,
        battery_pct: 15.0,
    };
    // A volatile sample written before discovery completes can be lost: repeat until seen.
    for i in 0..100 {
        let mut s = state.clone();
        s.timestamp_ms += i;
        w.write(s).await.unwrap();
        if h.vehicle("glider-7").is_some_and(|v| v.states_accepted > 0) {
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    eventually(20, "a LowBattery event", || {
        h.recent_events()
            .into_iter()
            .find(|e| e.kind == EventKind::LowBattery && e.vehicle_id == "glider-7")
    })
    .await;
    assert!(h.stats().rule_firings >= 1);

    let router = shoal_console::router(h.clone());
    let q = "SELECT ?v ?b WHERE { ?v a shoal:UnderwaterVehicle ; shoal:batteryLevel ?b . FILTER(?b < 20) }";
    let uri = format!("/api/sparql?query={}", urlencode(q));
    // The RDF mirror is written at most once a second per vehicle.
    let rows = eventually(10, "the glider in SPARQL results", || {
        let (status, body) = futures::executor::block_on(call(&router, "GET", &uri, ""));
        (status == StatusCode::OK && body.to_string().contains("glider-7")).then_some(body)
    })
    .await;
    assert_eq!(rows["head"]["vars"], serde_json::json!(["v", "b"]));

    let req = Request::builder()
        .method("POST")
        .uri("/api/sparql?format=csv")
        .header("content-type", "application/sparql-query")
        .body(Body::from(q))
        .unwrap();
    let resp = router.clone().oneshot(req).await.unwrap();
    assert_eq!(resp.status(), StatusCode::OK);
    let csv = String::from_utf8(
        resp.into_body()
            .collect()
            .await
            .unwrap()
            .to_bytes()
            .to_vec(),
    )
    .unwrap();
    assert!(csv.starts_with("v,b") && csv.contains("glider-7"), "{csv}");

    let (status, body) = call(&router, "GET", "/api/sparql?query=SELEKT%20nonsense", "").await;
    assert_eq!(status, StatusCode::BAD_REQUEST);
    assert!(body["error"].as_str().unwrap().contains("syntax"), "{body}");
    let update = urlencode("INSERT DATA { <urn:a> <urn:b> <urn:c> }");
    let (status, body) = call(&router, "GET", &format!("/api/sparql?query={update}"), "").await;
    assert_eq!(status, StatusCode::BAD_REQUEST);
    assert!(body["error"].as_str().unwrap().contains("UPDATE"), "{body}");
    station.shutdown.cancel();
    station.task.await.unwrap();
}

pub(crate) fn urlencode(s: &str) -> String {
    s.bytes()
        .map(|b| match b {
            b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'-' | b'_' | b'.' | b'~' => {
                (b as char).to_string()
            }
            _ => format!("%{b:02X}"),
        })
        .collect()
}

/// Malformed SPARQL protocol requests get a 400 that says what is wrong; the endpoint
/// keeps answering good requests afterwards.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_sparql_endpoint_explains_malformed_requests() {
    let station = start_station(66);
    let router = shoal_console::router(station.handle.clone());
    let (status, body) = call(&router, "GET", "/api/sparql", "").await;
    assert_eq!(status, StatusCode::BAD_REQUEST);
    assert!(body["error"].as_str().unwrap().contains("query"), "{body}");
    let (status, body) = call(
        &router,
        "GET",
        "/api/sparql?query=ASK%7B%7D&format=yaml",
        "",
    )
    .await;
    assert_eq!(status, StatusCode::BAD_REQUEST);
    assert!(body["error"].as_str().unwrap().contains("yaml"), "{body}");
    // `call` sends application/json, which the SPARQL protocol does not accept.
    let (status, body) = call(&router, "POST", "/api/sparql", "ASK {}").await;
    assert_eq!(status, StatusCode::UNSUPPORTED_MEDIA_TYPE);
    assert!(
        body["error"]
            .as_str()
            .unwrap()
            .contains("application/sparql-query"),
        "{body}"
    );
    let (status, body) = call(
        &router,
        "GET",
        "/api/sparql?query=ASK%7B%7D&default-graph-uri=urn%3Ax",
        "",
    )
    .await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{body}");
    let (status, body) = call(&router, "GET", "/api/sparql?query=ASK%7B%7D", "").await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(body["boolean"], true);
    station.shutdown.cancel();
    station.task.await.unwrap();
}

/// The Data Pre-Processor against history: a position jump beyond the vehicle's maximum
/// speed, a battery that rises while diving, and timestamps far ahead or behind are each
/// rejected with their reason, counted, quarantined and reported; good data around them
/// is stored, and a consistent run after a real relocation re-anchors the vehicle.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn implausible_state_is_rejected_by_reason_and_good_data_is_kept() {
    let station = start_station(67);
    let h = station.handle.clone();
    h.register_vehicle(crate::common::auv_announcement("auv-p"))
        .unwrap();
    let t0 = now_ms() - 60_000;
    let at = |dt_s: i64, lat: f64, battery: f64| StateVector {
        vehicle_id: "auv-p".into(),
        timestamp_ms: t0 + dt_s * 1000,
        latitude_deg: lat,
        longitude_deg: 10.0,
        depth_m: 30.0,
        altitude_m: -1.0,
        speed_mps: 1.5,
        yaw_deg: 0.0,
        pitch_deg: 0.0,
        roll_deg: 0.0,
        battery_pct: battery,
    };
    assert!(h.ingest_state(at(0, 63.0, 80.0)).is_ok());
    assert!(h.ingest_state(at(1, 63.000_01, 80.0)).is_ok());
    // 1.1 km in one second from a 2 m/s vehicle.
    assert_eq!(
        h.ingest_state(at(2, 63.01, 80.0)).map_err(|r| r.reason()),
        Err("implausible:position_jump".into())
    );
    // Battery up 15 points while diving.
    assert_eq!(
        h.ingest_state(at(3, 63.000_02, 95.0))
            .map_err(|r| r.reason()),
        Err("implausible:battery_rising".into())
    );
    let mut future = at(4, 63.000_03, 80.0);
    future.timestamp_ms = now_ms() + 3_600_000;
    assert_eq!(
        h.ingest_state(future).map_err(|r| r.reason()),
        Err("implausible:timestamp_future".into())
    );
    let mut past = at(4, 63.000_03, 80.0);
    past.timestamp_ms = now_ms() - 86_400_000;
    assert_eq!(
        h.ingest_state(past).map_err(|r| r.reason()),
        Err("implausible:timestamp_past".into())
    );
    assert!(h.ingest_state(at(5, 63.000_03, 79.9)).is_ok());
    // A late sample (older than the latest) is stored but does not become the latest.
    assert!(h.ingest_state(at(2, 63.000_015, 80.0)).is_ok());
    assert_eq!(
        h.vehicle("auv-p").unwrap().latest.unwrap().timestamp_ms,
        t0 + 5000
    );
    // Surfacing with a GPS fix 2 km away: three consistent fixes re-anchor the vehicle.
    for (i, expect_ok) in [(6, false), (7, false), (8, true)] {
        let r = h.ingest_state(at(i, 63.02 + 1e-6 * i as f64, 79.9));
        assert_eq!(r.is_ok(), expect_ok, "fix {i}: {r:?}");
    }

    let stats = h.stats();
    for (reason, n) in [
        ("implausible:position_jump", 3),
        ("implausible:battery_rising", 1),
        ("implausible:timestamp_future", 1),
        ("implausible:timestamp_past", 1),
    ] {
        assert_eq!(stats.rejected.get(reason), Some(&n), "{reason}: {stats:?}");
    }
    assert_eq!(stats.states_accepted, 5);
    let v = h.vehicle("auv-p").unwrap();
    assert_eq!((v.states_accepted, v.states_rejected), (5, 6));
    // Quarantined with payload, never stored as valid.
    let rejected = eventually(10, "the quarantine to hold 6 rows", || {
        h.history().rejected(100).ok().filter(|r| r.len() >= 6)
    })
    .await;
    assert!(rejected.iter().all(|r| r.topic == "shoal/state_vector"));
    assert!(
        rejected
            .iter()
            .any(|r| r.reason == "implausible:position_jump" && r.payload_json.contains("63.01"))
    );
    eventually(10, "5 states in the history", || {
        (h.history().count_states(Some("auv-p")).ok()? == 5).then_some(())
    })
    .await;
    // Reported to the operator as events, one per reason, and the re-anchoring too.
    let events = h.recent_events();
    for reason in [
        "position_jump",
        "battery_rising",
        "timestamp_future",
        "timestamp_past",
    ] {
        assert!(
            events
                .iter()
                .any(|e| e.kind == shoal_model::EventKind::DataRejected && e.text.contains(reason)),
            "no event for {reason}: {events:?}"
        );
    }
    assert!(events.iter().any(|e| e.text.contains("re-anchored")));
    station.shutdown.cancel();
    station.task.await.unwrap();
}

/// Rules & Policies through the API: a threshold rule is created, fires on insert, is
/// disabled (and stops firing), survives a restart of the station, and is deleted; bad
/// rules and forbidden changes are explained with the right status.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn rules_are_managed_through_the_api_and_survive_a_restart() {
    use shoal_model::EventKind;
    let station = start_station(68);
    let h = station.handle.clone();
    h.register_vehicle(crate::common::auv_announcement("auv-r"))
        .unwrap();
    let t0 = now_ms() - 30_000;
    let at = |i: i64, depth: f64| StateVector {
        vehicle_id: "auv-r".into(),
        timestamp_ms: t0 + i * 1000,
        latitude_deg: 63.0,
        longitude_deg: 10.0,
        depth_m: depth,
        altitude_m: -1.0,
        speed_mps: 0.5,
        yaw_deg: 0.0,
        pitch_deg: 0.0,
        roll_deg: 0.0,
        battery_pct: 80.0,
    };
    let router = shoal_console::router(h.clone());
    let rule = r#"{"id":"deep","description":"deeper than 100 m","severity":"alarm",
        "condition":{"type":"threshold","expr":"depth_m > 100"}}"#;
    let (status, created) = call(&router, "POST", "/api/rules", rule).await;
    assert_eq!(status, StatusCode::CREATED, "{created}");
    assert_eq!(created["enabled"], true);
    assert_eq!(created["condition"]["expr"], "depth_m > 100");

    // Bad rules are explained; the station keeps running.
    let (status, body) = call(&router, "POST", "/api/rules", rule).await;
    assert_eq!(status, StatusCode::CONFLICT, "{body}");
    let bad_expr = r#"{"id":"x1","condition":{"type":"threshold","expr":"depth_m ~ 3"}}"#;
    let (status, body) = call(&router, "POST", "/api/rules", bad_expr).await;
    assert_eq!(status, StatusCode::BAD_REQUEST);
    assert!(body["error"].as_str().unwrap().contains("parse"), "{body}");
    let bad_sparql = r#"{"id":"x2","condition":{"type":"sparql","query":"ASK { ?this shoal:x","watches":["shoal:batteryLevel"]}}"#;
    let (status, body) = call(&router, "POST", "/api/rules", bad_sparql).await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{body}");
    let unknown_field =
        r#"{"id":"x3","colour":"red","condition":{"type":"threshold","expr":"depth_m > 3"}}"#;
    let (status, body) = call(&router, "POST", "/api/rules", unknown_field).await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY);
    assert!(body["error"].as_str().unwrap().contains("colour"), "{body}");

    // Evaluated on insert.
    h.ingest_state(at(0, 50.0)).unwrap();
    h.ingest_state(at(1, 150.0)).unwrap();
    let fired = |h: &shoal_station::StationHandle| {
        h.recent_events()
            .into_iter()
            .filter(|e| e.kind == EventKind::Rule && e.vehicle_id == "auv-r")
            .count()
    };
    assert_eq!(fired(&h), 1, "{:?}", h.recent_events());

    // A member sent as null is a value of the wrong type, not "leave it" (schemathesis).
    let (status, body) = call(
        &router,
        "PATCH",
        "/api/rules/deep",
        r#"{"enabled":false,"condition":null}"#,
    )
    .await;
    assert_eq!(status, StatusCode::UNPROCESSABLE_ENTITY, "{body}");
    assert!(h.rule("deep").unwrap().enabled);

    // Disabled: no more firings.
    let (status, patched) = call(&router, "PATCH", "/api/rules/deep", r#"{"enabled":false}"#).await;
    assert_eq!(status, StatusCode::OK, "{patched}");
    assert_eq!(patched["enabled"], false);
    h.ingest_state(at(2, 50.0)).unwrap();
    h.ingest_state(at(3, 150.0)).unwrap();
    assert_eq!(fired(&h), 1);
    let (status, body) = call(&router, "PATCH", "/api/rules/nope", r#"{"enabled":false}"#).await;
    assert_eq!(status, StatusCode::NOT_FOUND, "{body}");

    // Listed with the built-in rules; built-in ones cannot be deleted.
    let (status, list) = call(&router, "GET", "/api/rules", "").await;
    assert_eq!(status, StatusCode::OK);
    let ids: Vec<&str> = list
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|r| r["id"].as_str())
        .collect();
    assert!(
        ids.contains(&"deep") && ids.contains(&"builtin.low_battery"),
        "{ids:?}"
    );
    let (status, _) = call(&router, "DELETE", "/api/rules/builtin.low_battery", "").await;
    assert_eq!(status, StatusCode::CONFLICT);

    // A restarted station has the rule, still disabled.
    station.shutdown.cancel();
    station.task.await.unwrap();
    let station = crate::common::start_station_in(68, station.dir);
    let router = shoal_console::router(station.handle.clone());
    let (status, rule) = call(&router, "GET", "/api/rules/deep", "").await;
    assert_eq!(status, StatusCode::OK);
    assert_eq!(rule["enabled"], false);
    assert_eq!(rule["severity"], "alarm");
    let (status, _) = call(&router, "DELETE", "/api/rules/deep", "").await;
    assert_eq!(status, StatusCode::NO_CONTENT);
    let (status, _) = call(&router, "GET", "/api/rules/deep", "").await;
    assert_eq!(status, StatusCode::NOT_FOUND);
    station.shutdown.cancel();
    station.task.await.unwrap();
}

/// Vehicle & Service Register: a vehicle whose DDS participant leaves is lost at once
/// (from DDS discovery, long before `lost_after_s`), and is registered again, idempotently,
/// when it comes back.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_vehicle_whose_participant_leaves_is_lost_at_once_and_rejoins() {
    let station = start_station(58);
    let h = station.handle.clone();
    let spec = SimSpec {
        id: "auv-gone".into(),
        kind: VehicleKind::Auv,
        latitude_deg: 63.0,
        longitude_deg: 10.0,
        rate_hz: 5.0,
        battery_pct: 90.0,
    };
    for round in 0..2 {
        let stop = CancellationToken::new();
        let participant = dds(58);
        let v = tokio::spawn(shoal_proxy::run_sim(
            spec.clone(),
            participant,
            stop.clone(),
        ));
        eventually(20, "the vehicle alive", || {
            h.vehicle("auv-gone")
                .filter(|v| v.contact == shoal_station::Contact::Alive)
        })
        .await;
        assert_eq!(
            h.fleet().len(),
            1,
            "round {round}: re-registration is idempotent"
        );
        stop.cancel();
        v.await.unwrap().unwrap();
        // Lost well before the 30 s `lost_after_s`.
        let lost = eventually(15, "the vehicle lost", || {
            h.vehicle("auv-gone")
                .filter(|v| v.contact == shoal_station::Contact::Lost)
        })
        .await;
        assert_eq!(lost.availability, shoal_station::Availability::Lost);
    }
    station.shutdown.cancel();
    station.task.await.unwrap();
}

/// The live feed: a WebSocket client on `/api/ws` gets vehicle states and events as they
/// happen, as typed JSON messages.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_websocket_streams_vehicles_and_events() {
    use futures::StreamExt;
    let station = start_station(57);
    let h = station.handle.clone();
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let stop = CancellationToken::new();
    let server = tokio::spawn(shoal_console::serve(listener, h.clone(), stop.clone()));
    let (mut ws, _) = tokio_tungstenite::connect_async(format!("ws://{addr}/api/ws"))
        .await
        .unwrap();
    h.register_vehicle(crate::common::auv_announcement("auv-ws"))
        .unwrap();
    let mut s = StateVector {
        vehicle_id: "auv-ws".into(),
        timestamp_ms: now_ms(),
        latitude_deg: 63.0,
        longitude_deg: 10.0,
        depth_m: 3.0,
        altitude_m: -1.0,
        speed_mps: 1.0,
        yaw_deg: 0.0,
        pitch_deg: 0.0,
        roll_deg: 0.0,
        battery_pct: 10.0,
    };
    h.ingest_state(s.clone()).unwrap();
    let mut seen_vehicle = false;
    let mut seen_event = false;
    let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
    while !(seen_vehicle && seen_event) {
        let msg = tokio::time::timeout_at(deadline, ws.next())
            .await
            .expect("live updates within 10 s")
            .unwrap()
            .unwrap();
        let text = msg.into_text().unwrap();
        let v: serde_json::Value = serde_json::from_str(&text).unwrap();
        match v["type"].as_str().unwrap() {
            "vehicle" => {
                assert_eq!(v["data"]["announcement"]["vehicle_id"], "auv-ws");
                seen_vehicle = true;
            }
            // 10 % battery: the built-in low-battery rule fires on insert.
            "event" if v["data"]["kind"] == "low_battery" => seen_event = true,
            _ => {}
        }
        s.timestamp_ms += 1;
    }
    stop.cancel();
    server.await.unwrap().unwrap();
    station.shutdown.cancel();
    station.task.await.unwrap();
}

/// The Mission & Task Register survives a station restart: a mission under way when the
/// station stops is reloaded from the history's recorded transitions and runs to done.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_mission_resumes_after_the_station_restarts() {
    let station = start_station(56);
    let stop = CancellationToken::new();
    let spec = SimSpec {
        id: "auv-rs".into(),
        kind: VehicleKind::Auv,
        latitude_deg: 63.0,
        longitude_deg: 10.0,
        rate_hz: 5.0,
        battery_pct: 90.0,
    };
    let v = tokio::spawn(shoal_proxy::run_sim(spec, dds(56), stop.clone()));
    let h = station.handle.clone();
    eventually(20, "auv-rs to report state", || {
        h.vehicle("auv-rs").filter(|v| v.latest.is_some())
    })
    .await;
    let goto = |lat: f64| shoal_station::MissionTaskSpec {
        task_id: None,
        vehicle_id: "auv-rs".into(),
        task: Task::GotoWaypoint {
            target: GeoPoint {
                latitude_deg: lat,
                longitude_deg: 10.0,
            },
            depth_m: Some(2.0),
            altitude_m: None,
            speed_mps: 2.0,
        },
    };
    h.plan_mission(shoal_station::MissionSpec {
        mission_id: "m-rs".into(),
        name: "restart".into(),
        tasks: vec![goto(63.000_2), goto(63.000_4)],
    })
    .unwrap();
    tokio::task::block_in_place(|| h.start_mission("m-rs")).unwrap();
    eventually(30, "the first task running", || {
        h.task("m-rs-1")
            .filter(|t| matches!(t.state, TaskState::Running | TaskState::Done))
    })
    .await;
    station.shutdown.cancel();
    station.task.await.unwrap();

    let station = crate::common::start_station_in(56, station.dir);
    let h = station.handle.clone();
    let m = h.mission("m-rs").expect("the mission is reloaded");
    assert_eq!(m.state, shoal_station::MissionState::Running, "{m:?}");
    let done = eventually(60, "the mission done after the restart", || {
        h.mission("m-rs")
            .filter(|m| m.state == shoal_station::MissionState::Done)
    })
    .await;
    assert!(done.tasks.iter().all(|t| t.state == TaskState::Done));
    // Every transition is in the history: sent by the station, then the vehicle's reports.
    // The writer commits in batches, and the last report may still be on its way to it
    // when the register already shows the mission done: wait for it.
    let states: Vec<TaskState> = eventually(20, "m-rs-2 done in the history", || {
        let th = h.history().task_history("m-rs-2").ok()?;
        let states: Vec<TaskState> = th.statuses.iter().map(|s| s.state).collect();
        (states.last() == Some(&TaskState::Done)).then_some(states)
    })
    .await;
    assert_eq!(states.first(), Some(&TaskState::Sent), "{states:?}");
    stop.cancel();
    v.await.unwrap().unwrap();
    station.shutdown.cancel();
    station.task.await.unwrap();
}

/// Consoles learn of missions the operator plans and aborts as they happen, not at their
/// next reconnect: both go out on the live feed. Domain 53.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn planned_and_aborted_missions_go_out_on_the_live_feed() {
    let station = start_station(53);
    let stop = CancellationToken::new();
    let spec = SimSpec {
        id: "auv-lv".into(),
        kind: VehicleKind::Auv,
        latitude_deg: 63.0,
        longitude_deg: 10.0,
        rate_hz: 5.0,
        battery_pct: 90.0,
    };
    let v = tokio::spawn(shoal_proxy::run_sim(spec, dds(53), stop.clone()));
    let h = station.handle.clone();
    eventually(20, "auv-lv to report state", || {
        h.vehicle("auv-lv").filter(|v| v.latest.is_some())
    })
    .await;
    let mut live = h.live();
    let hold = shoal_station::MissionTaskSpec {
        task_id: None,
        vehicle_id: "auv-lv".into(),
        task: Task::Hold { duration_s: 600.0 },
    };
    h.plan_mission(shoal_station::MissionSpec {
        mission_id: "m-lv".into(),
        name: "live".into(),
        tasks: vec![hold.clone(), hold],
    })
    .unwrap();
    let mission_state = |live: &mut tokio::sync::broadcast::Receiver<_>| {
        let mut last = None;
        while let Ok(u) = live.try_recv() {
            if let shoal_station::LiveUpdate::Mission(m) = u
                && m.mission_id == "m-lv"
            {
                last = Some(m.state);
            }
        }
        last
    };
    assert_eq!(
        mission_state(&mut live),
        Some(shoal_station::MissionState::Planned)
    );
    tokio::task::block_in_place(|| h.abort_mission("m-lv")).unwrap();
    assert_eq!(
        mission_state(&mut live),
        Some(shoal_station::MissionState::Aborted)
    );
    stop.cancel();
    let _ = v.await;
    station.shutdown.cancel();
    station.task.await.unwrap();
}
