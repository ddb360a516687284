//! The reporters without DDS: raised events, acknowledgements, the Environment
//! Reporter's subscriptions and the live feed.

use shoal_model::{EnvironmentObservation, EventKind, GeoPoint, Severity, TaskState, now_ms};

use crate::error::SubscriptionError;
use crate::reporters::{EnvSubscriptionSpec, LiveUpdate};
use crate::testing::{Fixture, assignment, valid};

fn observation(vehicle: &str, property: &str, lat: f64) -> EnvironmentObservation {
    EnvironmentObservation {
        vehicle_id: vehicle.into(),
        property: property.into(),
        timestamp_ms: now_ms(),
        value: 7.5,
        unit: "Cel".into(),
        latitude_deg: lat,
        longitude_deg: 10.38,
        depth_m: 10.0,
    }
}

#[test]
fn a_raised_event_is_kept_stored_and_published() {
    let f = Fixture::new();
    f.h.raise(
        Severity::Alarm,
        EventKind::Other,
        "auv-1",
        "",
        "hull breach",
    );
    let kept = f.h.recent_events();
    assert_eq!(kept.len(), 1);
    assert_eq!(kept[0].text, "hull breach");
    assert_eq!(f.out.events(), kept);
    f.flush();
    let stored = f.h.history().events(0, 10).unwrap();
    assert_eq!(stored.len(), 1);
    assert_eq!(stored[0].event_id, kept[0].event_id);
}

#[test]
fn overlong_text_is_cut_so_the_event_is_valid() {
    let f = Fixture::new();
    let long = "x".repeat(shoal_model::MAX_TEXT_LEN * 2);
    f.h.raise(Severity::Info, EventKind::Other, "", "", &long);
    assert_eq!(
        f.out.events()[0].text.len(),
        shoal_model::MAX_TEXT_LEN,
        "the event went out, cut to the limit"
    );
}

#[test]
fn recent_events_are_bounded() {
    let f = Fixture::with(|c| c.recent_events = 3);
    for n in 0..5 {
        f.h.raise(Severity::Info, EventKind::Other, "", "", &format!("e{n}"));
    }
    let texts: Vec<String> = f.h.recent_events().into_iter().map(|e| e.text).collect();
    assert_eq!(texts, ["e2", "e3", "e4"]);
}

#[test]
fn an_acknowledgement_keeps_the_first_operator_and_is_recorded() {
    let f = Fixture::new();
    f.h.raise(Severity::Alarm, EventKind::CommLost, "auv-1", "", "lost");
    let id = f.h.recent_events()[0].event_id.clone();
    let first = f.h.acknowledge(&id, "alice").unwrap();
    assert_eq!(first.acknowledged.as_ref().unwrap().by, "alice");
    let second = f.h.acknowledge(&id, "bob").unwrap();
    assert_eq!(second.acknowledged.unwrap().by, "alice");
    assert!(f.h.acknowledge("no-such-event", "alice").is_none());
    let views = f.h.event_views();
    assert_eq!(views[0].acknowledged.as_ref().unwrap().by, "alice");
    f.flush();
    let stored = f.h.history().events(0, 10).unwrap();
    let acks: Vec<_> = stored
        .iter()
        .filter(|e| e.text.starts_with("acknowledged"))
        .collect();
    assert_eq!(
        acks.len(),
        1,
        "one record per acknowledgement, not per click"
    );
    assert_eq!(acks[0].text, format!("acknowledged {id} by alice"));
}

#[test]
fn an_environment_subscription_filters_by_property_and_area_and_ends() {
    let f = Fixture::new();
    f.alive("auv-1");
    let sub =
        f.h.subscribe_environment(EnvSubscriptionSpec {
            property: Some("sea_water_temperature".into()),
            area: Some(vec![
                GeoPoint {
                    latitude_deg: 63.0,
                    longitude_deg: 10.0,
                },
                GeoPoint {
                    latitude_deg: 63.0,
                    longitude_deg: 11.0,
                },
                GeoPoint {
                    latitude_deg: 64.0,
                    longitude_deg: 10.5,
                },
            ]),
            max_rate_hz: 100.0,
        })
        .unwrap();
    let offer = |o| f.h.ingest_observation(valid(o)).unwrap();
    offer(observation("auv-1", "sea_water_temperature", 63.44));
    offer(observation("auv-1", "sea_water_salinity", 63.44));
    offer(observation("auv-1", "sea_water_temperature", 62.0));
    let got = f.h.environment_observations(&sub.id).unwrap();
    assert_eq!(got.len(), 1);
    assert_eq!(f.h.environment_subscriptions()[0].delivered, 1);
    assert!(f.h.unsubscribe_environment(&sub.id));
    assert!(!f.h.unsubscribe_environment(&sub.id));
    assert!(f.h.environment_observations(&sub.id).is_none());
}

#[test]
fn an_environment_subscription_keeps_to_its_rate() {
    let f = Fixture::new();
    f.alive("auv-1");
    let sub =
        f.h.subscribe_environment(EnvSubscriptionSpec {
            property: None,
            area: None,
            max_rate_hz: 1.0,
        })
        .unwrap();
    for _ in 0..5 {
        f.h.ingest_observation(valid(observation("auv-1", "sea_water_temperature", 63.4)))
            .unwrap();
    }
    assert_eq!(f.h.environment_observations(&sub.id).unwrap().len(), 1);
    assert_eq!(
        f.h.stats().observations,
        5,
        "every observation is still stored"
    );
}

#[test]
fn a_bad_subscription_names_what_is_wrong() {
    let f = Fixture::new();
    let rate = f.h.subscribe_environment(EnvSubscriptionSpec {
        property: None,
        area: None,
        max_rate_hz: 0.0,
    });
    assert_eq!(rate.unwrap_err(), SubscriptionError::Rate);
    let area = f.h.subscribe_environment(EnvSubscriptionSpec {
        property: None,
        area: Some(vec![]),
        max_rate_hz: 1.0,
    });
    assert_eq!(area.unwrap_err(), SubscriptionError::AreaTooSmall);
    assert!(f.h.environment_subscriptions().is_empty());
}

#[test]
fn the_live_feed_carries_events_tasks_missions_and_vehicles() {
    let f = Fixture::new();
    let mut live = f.h.live();
    f.alive("auv-1");
    f.h.dispatch_now(assignment("t-1", "auv-1")).unwrap();
    f.report("t-1", "auv-1", TaskState::Done);
    let mut kinds = std::collections::BTreeSet::new();
    while let Ok(u) = live.try_recv() {
        kinds.insert(match u {
            LiveUpdate::Event(_) => "event",
            LiveUpdate::Task(_) => "task",
            LiveUpdate::Mission(_) => "mission",
            LiveUpdate::Vehicle(_) => "vehicle",
            LiveUpdate::Observation { .. } => "observation",
            LiveUpdate::Vessel(_) | LiveUpdate::VesselGone { .. } => "vessel",
        });
    }
    assert!(kinds.contains("event"), "{kinds:?}");
    assert!(kinds.contains("task"), "{kinds:?}");
    assert!(kinds.contains("vehicle"), "{kinds:?}");
}

#[test]
fn a_vehicles_state_reaches_the_live_feed_at_most_once_a_second() {
    let f = Fixture::new();
    f.announce("auv-1");
    let mut live = f.h.live();
    let t = now_ms() - 5000;
    for n in 0..5 {
        f.h.ingest_state(crate::testing::state("auv-1", t + n * 100, 80.0))
            .unwrap();
    }
    let mut vehicles = 0;
    while let Ok(u) = live.try_recv() {
        if matches!(u, LiveUpdate::Vehicle(_)) {
            vehicles += 1;
        }
    }
    assert_eq!(vehicles, 1);
}

/// Regression: with the rejection-alert memory full, every rejection of a fresh id swept
/// the whole memory; 100,000 made-up vehicles slowed the fleet's ingest by a fifth.
#[test]
fn a_full_rejection_alert_memory_is_swept_at_most_once_a_second() {
    use super::{MAX_REJECTION_ALERTS, REJECTION_ALERT_EVERY_MS, RejectionAlerts};
    let key = |n: usize| (format!("x-{n}"), "unknown_vehicle".to_string());
    let mut alerts = RejectionAlerts::default();
    for n in 0..MAX_REJECTION_ALERTS {
        assert!(alerts.due(key(n), 0));
    }
    // Full: fresh ids get no alert; one sweep, then none within the second.
    assert!(!alerts.due(key(MAX_REJECTION_ALERTS), 10));
    assert_eq!(alerts.swept_ms, Some(10));
    for n in 1..1000 {
        assert!(!alerts.due(key(MAX_REJECTION_ALERTS + n), 500));
    }
    assert_eq!(alerts.swept_ms, Some(10));
    // A known pair is still rate-limited by its own minute.
    assert!(!alerts.due(key(0), 500));
    // Once their minute has passed, the old pairs go at the next sweep.
    let later = REJECTION_ALERT_EVERY_MS + 1;
    assert!(alerts.due(key(9_999_999), later));
    assert_eq!(alerts.swept_ms, Some(later));
    assert_eq!(alerts.last_ms.len(), 1);
}
