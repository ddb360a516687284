//! The services end to end: a station and three simulated vehicles, one of them heard
//! only over the emulated acoustic link through a CDT, each run a two-task mission.
//! Domains 69 (station) and 131 (the acoustic AUV's private domain).

use std::time::Duration;

use axum::http::StatusCode;
use shoal_dds::DdsConfig;
use shoal_model::{EventKind, LinkKind, TaskState, VehicleKind, now_ms};
use shoal_proxy::sim::SimSpec;
use shoal_station::MissionState;
use tokio_util::sync::CancellationToken;

use crate::common::{dds, eventually, start_station};
use crate::converter::common::{demo_relay, run_relayed_sim};
use crate::station::call;

fn goto(vehicle: &str, lat: f64, lon: f64) -> serde_json::Value {
    serde_json::json!({
        "vehicle_id": vehicle,
        "task": {
            "kind": "goto_waypoint",
            "target": { "latitude_deg": lat, "longitude_deg": lon },
            "depth_m": 3.0,
            "speed_mps": 2.0
        }
    })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn three_vehicles_one_acoustic_run_their_missions_to_done() {
    let station = start_station(69);
    let h = station.handle.clone();
    let router = shoal_console::router(h.clone());
    let stop = CancellationToken::new();

    // Two vehicles on IP.
    let mut runs = Vec::new();
    for (id, kind, lat, lon) in [
        ("auv-s1", VehicleKind::Auv, 63.44, 10.36),
        ("usv-s2", VehicleKind::Usv, 63.45, 10.37),
    ] {
        let spec = SimSpec {
            id: id.into(),
            kind,
            latitude_deg: lat,
            longitude_deg: lon,
            rate_hz: 2.0,
            battery_pct: 95.0,
        };
        runs.push(tokio::spawn(shoal_proxy::run_sim(
            spec,
            dds(69),
            stop.clone(),
        )));
    }
    // One AUV behind the acoustic relay, on its own private domain.
    let (demo, ac) = demo_relay(131, 0.1);
    let station_dds = DdsConfig {
        domain_id: 69,
        ..DdsConfig::default()
    };
    let relay = {
        let stop = stop.clone();
        let ac = ac.clone();
        tokio::spawn(async move { run_relayed_sim(demo, ac, station_dds, stop).await })
    };

    for id in ["auv-s1", "usv-s2", ac.id.as_str()] {
        eventually(90, &format!("{id} registered with a state"), || {
            h.vehicle(id).filter(|v| v.latest.is_some())
        })
        .await;
    }
    let link = eventually(60, "the acoustic AUV's link", || {
        h.vehicle(&ac.id).filter(|v| v.link == LinkKind::Acoustic)
    })
    .await;
    assert_eq!(link.link, LinkKind::Acoustic);

    // A user rule that fires as soon as a vehicle dives below 1 m.
    let rule = r#"{"id":"dived","severity":"warning",
        "condition":{"type":"threshold","expr":"depth_m > 1"}}"#;
    let (status, body) = call(&router, "POST", "/api/rules", rule).await;
    assert_eq!(status, StatusCode::CREATED, "{body}");

    // Bad missions are explained and nothing is registered.
    let (status, body) = call(
        &router,
        "POST",
        "/api/missions",
        &serde_json::json!({"mission_id": "bad", "tasks": [goto("nobody", 63.0, 10.0)]})
            .to_string(),
    )
    .await;
    assert_eq!(status, StatusCode::CONFLICT, "{body}");
    assert!(
        body["error"].as_str().unwrap().contains("tasks[0]"),
        "{body}"
    );
    let bow_tie = serde_json::json!({"mission_id": "bad2", "tasks": [{
        "vehicle_id": "auv-s1",
        "task": {"kind": "survey_area", "line_spacing_m": 20.0, "depth_m": 5.0, "speed_mps": 1.5,
                 "polygon": [{"latitude_deg": 63.44, "longitude_deg": 10.36},
                             {"latitude_deg": 63.441, "longitude_deg": 10.361},
                             {"latitude_deg": 63.44, "longitude_deg": 10.361},
                             {"latitude_deg": 63.441, "longitude_deg": 10.36}]}}]});
    let (status, body) = call(&router, "POST", "/api/missions", &bow_tie.to_string()).await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{body}");
    assert!(body["error"].as_str().unwrap().contains("area"), "{body}");
    assert!(h.missions().is_empty());

    // One mission per vehicle: two short gotos each (about 15 m apart).
    let d = 0.000_135; // ≈ 15 m of latitude
    for (m, id, lat, lon) in [
        ("m-s1", "auv-s1", 63.44, 10.36),
        ("m-s2", "usv-s2", 63.45, 10.37),
        ("m-ac", ac.id.as_str(), ac.latitude_deg, ac.longitude_deg),
    ] {
        let spec = serde_json::json!({
            "mission_id": m,
            "name": format!("two gotos for {id}"),
            "tasks": [goto(id, lat + d, lon), goto(id, lat + 2.0 * d, lon)],
        });
        let (status, body) = call(
            &router,
            "POST",
            "/api/missions?start=true",
            &spec.to_string(),
        )
        .await;
        assert_eq!(status, StatusCode::CREATED, "{body}");
        assert_eq!(body["state"], "running");
    }
    // A duplicate mission id is refused as a conflict with the mission that has it.
    let dup = serde_json::json!({"mission_id": "m-s1", "tasks": [goto("auv-s1", 63.44, 10.36)]});
    let (status, body) = call(&router, "POST", "/api/missions", &dup.to_string()).await;
    assert_eq!(status, StatusCode::CONFLICT, "{body}");
    assert!(body.to_string().contains("already in use"), "{body}");

    for m in ["m-s1", "m-s2", "m-ac"] {
        let view = eventually(240, &format!("mission {m} done"), || {
            h.mission(m).filter(|v| {
                assert_ne!(v.state, MissionState::Failed, "{v:?}");
                v.state == MissionState::Done
            })
        })
        .await;
        assert!(view.tasks.iter().all(|t| t.state == TaskState::Done));
        assert!((view.progress_pct - 100.0).abs() < 1e-9);
    }
    let ac_tasks: Vec<_> = h
        .tasks()
        .into_iter()
        .filter(|t| t.assignment.mission_id == "m-ac")
        .collect();
    assert!(
        ac_tasks.iter().all(|t| t.link == Some(LinkKind::Acoustic)),
        "{ac_tasks:?}"
    );

    // The history holds every vehicle's track.
    for id in ["auv-s1", "usv-s2", ac.id.as_str()] {
        let track = h.history().track(id, 0, now_ms(), 10_000).unwrap();
        assert!(track.len() >= 3, "{id}: {} states", track.len());
    }

    // The rule fired, and an operator acknowledges its event through the API.
    let fired = eventually(10, "the rule's event", || {
        h.event_views()
            .into_iter()
            .find(|e| e.event.kind == EventKind::Rule && e.event.event_id.starts_with("dived"))
    })
    .await;
    let uri = format!("/api/events/{}/ack", fired.event.event_id);
    let (status, body) = call(&router, "POST", &uri, r#"{"by":"alice"}"#).await;
    assert_eq!(status, StatusCode::OK, "{body}");
    assert_eq!(body["acknowledged"]["by"], "alice");
    let (_, events) = call(&router, "GET", "/api/events", "").await;
    let listed = events
        .as_array()
        .unwrap()
        .iter()
        .find(|e| e["event_id"] == fired.event.event_id.as_str())
        .unwrap();
    assert_eq!(listed["acknowledged"]["by"], "alice");
    let (status, _) = call(&router, "POST", "/api/events/nope/ack", "{}").await;
    assert_eq!(status, StatusCode::NOT_FOUND);
    // Task events were reported too.
    assert!(
        h.recent_events()
            .iter()
            .any(|e| e.kind == EventKind::Task && e.text.contains("done"))
    );

    stop.cancel();
    for r in runs {
        r.await.unwrap().unwrap();
    }
    tokio::time::timeout(Duration::from_secs(20), relay)
        .await
        .unwrap()
        .unwrap()
        .unwrap();
    station.shutdown.cancel();
    station.task.await.unwrap();
}
