//! The Data Access Manager without DDS: acceptance, every rejection reason, quarantine.

use std::time::Duration;

use shoal_dds::{ReadError, TopicType};
use shoal_model::{
    Availability, EventKind, LinkKind, Severity, StateVector, TaskState, Validated, now_ms,
};

use crate::error::Rejection;
use crate::testing::{Fixture, state, status, valid};

fn rejected_reasons(f: &Fixture) -> Vec<(String, String)> {
    f.flush();
    f.h.history()
        .rejected(100)
        .unwrap()
        .into_iter()
        .map(|r| (r.topic, r.reason))
        .collect()
}

fn data_rejected_events(f: &Fixture) -> usize {
    f.h.recent_events()
        .iter()
        .filter(|e| e.kind == EventKind::DataRejected)
        .count()
}

#[test]
fn an_accepted_state_becomes_the_latest_and_is_stored() {
    let f = Fixture::new();
    f.announce("auv-1");
    let t = now_ms();
    f.h.ingest_state(state("auv-1", t, 80.0)).unwrap();
    let v = f.h.vehicle("auv-1").unwrap();
    assert_eq!(v.latest.unwrap().timestamp_ms, t);
    assert_eq!(v.states_accepted, 1);
    assert_eq!(f.h.stats().states_accepted, 1);
    f.flush();
    assert_eq!(f.h.history().count_states(Some("auv-1")).unwrap(), 1);
}

#[test]
fn an_out_of_range_state_is_rejected_by_reason_and_quarantined_with_its_payload() {
    let f = Fixture::new();
    f.announce("auv-1");
    let mut s = state("auv-1", now_ms(), 80.0);
    s.latitude_deg = 95.0;
    let err = f.h.ingest_state(s).unwrap_err();
    assert!(matches!(err, Rejection::Invalid(_)), "{err:?}");
    assert_eq!(err.reason(), "out_of_range:latitude_deg");
    assert_eq!(f.h.stats().rejected["out_of_range:latitude_deg"], 1);
    assert_eq!(f.h.vehicle("auv-1").unwrap().states_rejected, 1);
    f.flush();
    let q = f.h.history().rejected(10).unwrap();
    assert_eq!(q.len(), 1);
    assert!(
        q[0].payload_json.contains("\"latitude_deg\":95.0"),
        "{}",
        q[0].payload_json
    );
    assert_eq!(f.h.history().count_states(None).unwrap(), 0);
}

#[test]
fn a_state_from_a_vehicle_that_never_announced_itself_is_rejected() {
    let f = Fixture::new();
    let err =
        f.h.ingest_state(state("ghost", now_ms(), 80.0))
            .unwrap_err();
    assert_eq!(err, Rejection::UnknownVehicle("ghost".into()));
    assert_eq!(f.h.stats().rejected["unknown_vehicle"], 1);
    assert!(f.h.vehicle("ghost").is_none());
    assert_eq!(
        rejected_reasons(&f),
        vec![(
            StateVector::TOPIC.to_string(),
            "unknown_vehicle".to_string()
        )]
    );
}

#[test]
fn a_bus_state_that_beats_its_announcement_waits_for_it_and_is_accepted() {
    let (f, time) = Fixture::manual_clock();
    let t = f.h.now();
    f.h.ingest_bus_state(valid(state("auv-1", t, 80.0)));
    f.h.ingest_bus_state(valid(state("auv-1", t + 100, 79.9)));
    assert_eq!(f.h.stats().states_accepted, 0);
    time.advance(1_000);
    f.h.tick(f.h.now());
    f.announce("auv-1");
    let stats = f.h.stats();
    assert_eq!(stats.states_accepted, 2);
    assert_eq!(stats.states_held_for_announcement, 2);
    assert!(stats.rejected.is_empty(), "{:?}", stats.rejected);
    assert_eq!(
        f.h.vehicle("auv-1").unwrap().latest.unwrap().timestamp_ms,
        t + 100
    );
    // Once known, a vehicle's samples are not held.
    f.h.ingest_bus_state(valid(state("auv-1", t + 200, 79.8)));
    assert_eq!(f.h.stats().states_accepted, 3);
    assert_eq!(f.h.stats().states_held_for_announcement, 2);
}

#[test]
fn a_bus_state_whose_vehicle_never_announces_is_refused_after_the_grace() {
    let (f, time) = Fixture::manual_clock();
    f.h.ingest_bus_state(valid(state("ghost", f.h.now(), 80.0)));
    time.advance(4_000);
    f.h.tick(f.h.now());
    assert!(f.h.stats().rejected.is_empty());
    time.advance(1_000);
    f.h.tick(f.h.now());
    assert_eq!(f.h.stats().rejected["unknown_vehicle"], 1);
    assert_eq!(
        rejected_reasons(&f),
        vec![(
            StateVector::TOPIC.to_string(),
            "unknown_vehicle".to_string()
        )]
    );
    // A late announcement finds nothing left to take.
    f.announce("ghost");
    assert_eq!(f.h.stats().states_accepted, 0);
}

#[test]
fn with_no_grace_a_bus_state_of_an_unknown_vehicle_is_refused_at_once() {
    let f = Fixture::with(|c| c.announcement_grace_s = 0.0);
    f.h.ingest_bus_state(valid(state("ghost", now_ms(), 80.0)));
    assert_eq!(f.h.stats().rejected["unknown_vehicle"], 1);
    assert_eq!(f.h.stats().states_held_for_announcement, 0);
}

#[test]
fn without_required_announcements_an_unknown_vehicle_is_heard() {
    let f = Fixture::with(|c| c.require_announcement = false);
    f.h.ingest_state(state("free", now_ms(), 80.0)).unwrap();
    assert_eq!(f.h.stats().states_accepted, 1);
}

#[test]
fn a_position_jump_beyond_the_vehicles_speed_is_implausible() {
    let f = Fixture::new();
    f.announce("auv-1");
    let t = now_ms() - 10_000;
    f.h.ingest_state(state("auv-1", t, 80.0)).unwrap();
    let mut jump = state("auv-1", t + 1000, 80.0);
    jump.latitude_deg += 0.01; // about 1.1 km in a second from a 2 m/s vehicle
    let err = f.h.ingest_state(jump).unwrap_err();
    assert_eq!(err.reason(), "implausible:position_jump");
    assert!(matches!(err, Rejection::Implausible(_)));
    // The latest state is still the plausible one.
    assert_eq!(
        f.h.vehicle("auv-1").unwrap().latest.unwrap().timestamp_ms,
        t
    );
}

#[test]
fn a_battery_rising_while_diving_is_implausible() {
    let f = Fixture::new();
    f.announce("auv-1");
    let t = now_ms() - 10_000;
    f.h.ingest_state(state("auv-1", t, 50.0)).unwrap();
    let err =
        f.h.ingest_state(state("auv-1", t + 1000, 70.0))
            .unwrap_err();
    assert_eq!(err.reason(), "implausible:battery_rising");
}

#[test]
fn timestamps_far_from_the_station_clock_are_implausible() {
    let f = Fixture::new();
    f.announce("auv-1");
    let future = f.h.ingest_state(state("auv-1", now_ms() + 3_600_000, 80.0));
    assert_eq!(future.unwrap_err().reason(), "implausible:timestamp_future");
    let past =
        f.h.ingest_state(state("auv-1", now_ms() - 86_400_000, 80.0));
    assert_eq!(past.unwrap_err().reason(), "implausible:timestamp_past");
}

#[test]
fn a_late_state_is_stored_but_does_not_become_the_latest() {
    let f = Fixture::new();
    f.announce("auv-1");
    let t = now_ms() - 10_000;
    f.h.ingest_state(state("auv-1", t, 80.0)).unwrap();
    f.h.ingest_state(state("auv-1", t - 2000, 80.0)).unwrap();
    assert_eq!(
        f.h.vehicle("auv-1").unwrap().latest.unwrap().timestamp_ms,
        t
    );
    f.flush();
    assert_eq!(f.h.history().count_states(Some("auv-1")).unwrap(), 2);
}

#[test]
fn rejections_are_reported_once_a_minute_per_vehicle_and_reason() {
    let f = Fixture::new();
    f.announce("auv-1");
    for _ in 0..5 {
        let mut s = state("auv-1", now_ms(), 80.0);
        s.depth_m = -50.0;
        assert!(f.h.ingest_state(s).is_err());
    }
    assert_eq!(f.h.stats().total_rejected(), 5);
    assert_eq!(data_rejected_events(&f), 1);
    // Another reason is reported on its own.
    let mut s = state("auv-1", now_ms(), 80.0);
    s.longitude_deg = 200.0;
    assert!(f.h.ingest_state(s).is_err());
    assert_eq!(data_rejected_events(&f), 2);
    let alert = f.out.events();
    assert!(
        alert
            .iter()
            .any(|e| e.kind == EventKind::DataRejected && e.vehicle_id == "auv-1")
    );
}

#[test]
fn malformed_samples_are_counted_by_topic_and_quarantined_without_payload() {
    let f = Fixture::new();
    let e = ReadError::Malformed {
        topic: StateVector::TOPIC,
        detail: "short buffer".into(),
    };
    f.h.on_read_error::<StateVector>(&e);
    f.h.on_read_error::<StateVector>(&e);
    assert_eq!(f.h.stats().malformed[StateVector::TOPIC], 2);
    assert_eq!(f.h.stats().total_rejected(), 2);
    let reasons = rejected_reasons(&f);
    assert_eq!(reasons.len(), 2);
    assert!(reasons[0].1.starts_with("malformed: short buffer"));
}

#[test]
fn an_invalid_sample_from_the_bus_names_its_vehicle_only_when_the_id_is_well_formed() {
    let f = Fixture::new();
    f.announce("auv-1");
    let mut bad = state("auv-1", now_ms(), 80.0);
    bad.speed_mps = 500.0;
    let Err((error, bad)) = Validated::new(bad) else {
        panic!("500 m/s passed validation");
    };
    let payload = serde_json::to_string(&bad).unwrap();
    f.h.on_read_error::<StateVector>(&ReadError::Invalid {
        topic: StateVector::TOPIC,
        error: error.clone(),
        payload,
    });
    assert_eq!(f.h.vehicle("auv-1").unwrap().states_rejected, 1);
    // A forged id full of markup is not trusted as a vehicle id.
    f.h.on_read_error::<StateVector>(&ReadError::Invalid {
        topic: StateVector::TOPIC,
        error,
        payload: r#"{"vehicle_id":"<script>"}"#.into(),
    });
    let events = f.h.recent_events();
    let last = events.last().unwrap();
    assert_eq!(last.kind, EventKind::DataRejected);
    assert!(!last.vehicle_id.contains('<'));
    assert_eq!(f.h.stats().total_rejected(), 2);
}

#[test]
fn samples_refused_by_security_are_counted_and_reported_but_never_stored() {
    let f = Fixture::new();
    f.h.on_read_error::<StateVector>(&ReadError::Impersonation {
        topic: StateVector::TOPIC,
        publisher: "auv-2".into(),
        claimed: "auv-1".into(),
    });
    f.h.on_read_error::<StateVector>(&ReadError::Revoked {
        topic: StateVector::TOPIC,
        vehicle: "auv-3".into(),
    });
    let stats = f.h.stats();
    assert_eq!(stats.rejected["security:impersonation"], 1);
    assert_eq!(stats.rejected["security:revoked"], 1);
    assert!(rejected_reasons(&f).is_empty());
    assert_eq!(data_rejected_events(&f), 2);
}

#[test]
fn a_status_for_a_task_the_station_never_gave_is_refused_and_counted() {
    let f = Fixture::new();
    f.alive("auv-1");
    let err =
        f.h.ingest_task_status(valid(status("t-x", "auv-1", TaskState::Done)))
            .unwrap_err();
    assert_eq!(err.reason(), "unknown_task");
    assert_eq!(f.h.stats().rejected["unknown_task"], 1);
    assert_eq!(f.h.stats().task_status, 0);
}

#[test]
fn a_task_status_from_far_in_the_future_is_implausible() {
    let f = Fixture::new();
    f.alive("auv-1");
    let mut s = status("t-1", "auv-1", TaskState::Running);
    s.timestamp_ms = now_ms() + 3_600_000;
    let err = f.h.ingest_task_status(valid(s)).unwrap_err();
    assert_eq!(err.reason(), "implausible:timestamp_future");
}

fn vehicle_event(id: &str, kind: EventKind) -> shoal_model::Event {
    shoal_model::Event {
        event_id: format!("{id}-ev-1"),
        timestamp_ms: now_ms(),
        severity: Severity::Warning,
        kind,
        vehicle_id: id.into(),
        task_id: String::new(),
        text: "thruster 2 overcurrent".into(),
    }
}

#[test]
fn a_vehicles_event_is_kept_stored_and_not_published_again() {
    let f = Fixture::new();
    f.alive("auv-1");
    let published = f.out.events().len();
    f.h.ingest_event(valid(vehicle_event("auv-1", EventKind::Detection)))
        .unwrap();
    assert_eq!(f.h.stats().events, 1);
    assert!(
        f.h.recent_events()
            .iter()
            .any(|e| e.event_id == "auv-1-ev-1")
    );
    // The vehicle published it; the station does not echo it on the bus.
    assert_eq!(f.out.events().len(), published);
    f.flush();
    let stored = f.h.history().events(0, 100).unwrap();
    assert!(stored.iter().any(|e| e.event_id == "auv-1-ev-1"));
}

#[test]
fn a_fault_event_makes_the_vehicle_unavailable() {
    let f = Fixture::new();
    f.alive("auv-1");
    assert_eq!(
        f.h.vehicle("auv-1").unwrap().availability,
        Availability::Idle
    );
    f.h.ingest_event(valid(vehicle_event("auv-1", EventKind::Fault)))
        .unwrap();
    assert_eq!(
        f.h.vehicle("auv-1").unwrap().availability,
        Availability::Fault
    );
}

#[test]
fn a_relays_link_report_sets_the_vehicles_link_and_is_not_an_operator_event() {
    let f = Fixture::new();
    f.alive("auv-ac1");
    let status = shoal_model::LinkStatus {
        vehicle_id: "auv-ac1".into(),
        link: LinkKind::Acoustic,
        cdt_address: 1,
        vehicle_address: 2,
        rssi_db: Some(-80),
        integrity: None,
        heard_ms: now_ms(),
        participant: "0102".into(),
        cdt_latitude_deg: None,
        cdt_longitude_deg: None,
        cdt_vehicle: None,
        frames: None,
        interval_s: None,
    };
    f.h.ingest_event(valid(status.to_event())).unwrap();
    let v = f.h.vehicle("auv-ac1").unwrap();
    assert_eq!(v.link, LinkKind::Acoustic);
    assert!(v.link_status.is_some());
    assert_eq!(f.h.stats().events, 0);
}

#[test]
fn an_observation_is_counted_and_stored() {
    let f = Fixture::new();
    f.alive("auv-1");
    let o = shoal_model::EnvironmentObservation {
        vehicle_id: "auv-1".into(),
        timestamp_ms: now_ms(),
        latitude_deg: 63.44,
        longitude_deg: 10.38,
        depth_m: 10.0,
        property: "sea_water_temperature".into(),
        value: 7.5,
        unit: "Cel".into(),
    };
    f.h.ingest_observation(valid(o)).unwrap();
    assert_eq!(f.h.stats().observations, 1);
    f.h.flush_history(Duration::from_secs(5)).unwrap();
    let stored =
        f.h.history()
            .observations("auv-1", "sea_water_temperature", 0, i64::MAX, 10)
            .unwrap();
    assert_eq!(stored.len(), 1);
}

#[test]
fn a_rule_firing_on_insert_is_published_and_counted() {
    let f = Fixture::new();
    f.announce("auv-1");
    // The built-in low-battery rule: below 20 %.
    f.h.ingest_state(state("auv-1", now_ms(), 12.0)).unwrap();
    assert_eq!(f.h.stats().rule_firings, 1);
    let fired = f.out.events();
    assert!(
        fired
            .iter()
            .any(|e| e.kind == EventKind::LowBattery && e.vehicle_id == "auv-1"),
        "{fired:?}"
    );
}
