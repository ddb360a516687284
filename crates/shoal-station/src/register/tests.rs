//! The Vehicle & Service Register without DDS: join, re-join, contact, participants,
//! availability and its mirror in the semantic model.

use shoal_model::{Availability, EventKind, Severity, TaskState, now_ms};
use shoal_semantic::{QueryLimits, QueryResult};

use crate::register::Contact;
use crate::testing::{Fixture, announcement, assignment, state};

/// The availability the semantic model holds for `id`, asked with SPARQL.
fn mirrored(f: &Fixture, id: &str, a: &str) -> bool {
    let q = format!("ASK {{ ?v shoal:vehicleId \"{id}\" ; shoal:availability shoal:{a} }}");
    match f.h.sparql(&q, &QueryLimits::default()).unwrap() {
        QueryResult::Boolean(b) => b,
        other => panic!("ASK answered {other:?}"),
    }
}

#[test]
fn a_vehicle_joins_silent_and_idle_and_the_model_mirrors_it() {
    let f = Fixture::new();
    f.announce("auv-1");
    let v = f.h.vehicle("auv-1").unwrap();
    assert_eq!(v.contact, Contact::Silent);
    assert_eq!(v.availability, Availability::Idle);
    assert_eq!(f.h.stats().announcements, 1);
    assert!(mirrored(&f, "auv-1", "Idle"));
}

#[test]
fn re_joining_is_idempotent_and_keeps_counters_and_state() {
    let f = Fixture::new();
    f.alive("auv-1");
    let before = f.h.vehicle("auv-1").unwrap();
    let mut again = announcement("auv-1");
    again.name = "renamed".into();
    f.h.register_vehicle(again).unwrap();
    let after = f.h.vehicle("auv-1").unwrap();
    assert_eq!(f.h.fleet().len(), 1);
    assert_eq!(after.announcement.name, "renamed");
    assert_eq!(after.states_accepted, before.states_accepted);
    assert_eq!(after.latest, before.latest);
    assert_eq!(after.contact, Contact::Alive);
}

#[test]
fn an_invalid_registration_is_refused() {
    let f = Fixture::new();
    let mut a = announcement("auv-1");
    a.vehicle_id = "bad id with spaces".into();
    assert!(f.h.register_vehicle(a).is_err());
    assert!(f.h.fleet().is_empty());
}

#[test]
fn contact_goes_stale_then_lost_with_an_alarm_on_the_bus() {
    let f = Fixture::new();
    f.alive("auv-1");
    assert_eq!(f.h.vehicle("auv-1").unwrap().contact, Contact::Alive);
    let cfg = f.h.config().clone();
    let (stale, lost) = (
        crate::config::ms(cfg.stale_after_s),
        crate::config::ms(cfg.lost_after_s),
    );
    f.h.tick(now_ms() + stale + 100);
    assert_eq!(f.h.vehicle("auv-1").unwrap().contact, Contact::Stale);
    f.h.tick(now_ms() + lost + 100);
    let v = f.h.vehicle("auv-1").unwrap();
    assert_eq!(v.contact, Contact::Lost);
    assert_eq!(v.availability, Availability::Lost);
    assert!(mirrored(&f, "auv-1", "Lost"));
    let alarms: Vec<_> = f
        .out
        .events()
        .into_iter()
        .filter(|e| e.kind == EventKind::CommLost)
        .collect();
    assert_eq!(
        alarms.len(),
        1,
        "one CommLost alarm, from the register only"
    );
    assert_eq!(alarms[0].severity, Severity::Alarm);
    assert_eq!(alarms[0].vehicle_id, "auv-1");
}

#[test]
fn contact_regained_is_reported_and_the_vehicle_is_idle_again() {
    let f = Fixture::new();
    f.alive("auv-1");
    let lost = crate::config::ms(f.h.config().lost_after_s);
    f.h.tick(now_ms() + lost + 100);
    assert_eq!(f.h.vehicle("auv-1").unwrap().contact, Contact::Lost);
    f.h.ingest_state(state("auv-1", now_ms(), 80.0)).unwrap();
    f.h.tick(now_ms());
    let v = f.h.vehicle("auv-1").unwrap();
    assert_eq!(v.contact, Contact::Alive);
    assert_eq!(v.availability, Availability::Idle);
    assert!(mirrored(&f, "auv-1", "Idle"));
    assert!(
        f.h.recent_events()
            .iter()
            .any(|e| e.text == "contact with auv-1 regained")
    );
}

#[test]
fn a_vehicle_whose_participant_left_is_lost_at_once() {
    let f = Fixture::new();
    f.announce_via("auv-1", "p-1");
    f.h.ingest_state(state("auv-1", now_ms(), 80.0)).unwrap();
    f.h.tick(now_ms());
    f.h.participant_left("p-1", "disposed");
    f.h.tick(now_ms() + 1);
    assert_eq!(f.h.vehicle("auv-1").unwrap().contact, Contact::Lost);
    let alarm =
        f.h.recent_events()
            .into_iter()
            .find(|e| e.kind == EventKind::CommLost)
            .unwrap();
    assert!(alarm.text.contains("participant left"), "{}", alarm.text);
}

#[test]
fn a_vehicle_that_moved_to_another_participant_survives_the_old_one_leaving() {
    let f = Fixture::new();
    f.announce_via("auv-1", "p-old");
    f.h.ingest_state(state("auv-1", now_ms(), 80.0)).unwrap();
    // Restarted: the same vehicle now speaks through a new participant.
    f.announce_via("auv-1", "p-new");
    f.h.participant_left("p-old", "lease expired");
    f.h.tick(now_ms());
    assert_eq!(f.h.vehicle("auv-1").unwrap().contact, Contact::Alive);
    // Other vehicles of other participants are untouched by a leaving one.
    f.announce_via("usv-1", "p-usv");
    f.h.participant_left("p-unknown", "gone");
    assert_eq!(f.h.vehicle("usv-1").unwrap().contact, Contact::Silent);
}

#[test]
fn a_vehicle_is_busy_while_a_task_is_under_way_and_the_model_follows() {
    let f = Fixture::new();
    f.alive("auv-1");
    f.h.dispatch_now(assignment("t-1", "auv-1")).unwrap();
    assert_eq!(
        f.h.vehicle("auv-1").unwrap().availability,
        Availability::Busy
    );
    assert!(mirrored(&f, "auv-1", "Busy"));
    f.report("t-1", "auv-1", TaskState::Accepted);
    f.report("t-1", "auv-1", TaskState::Done);
    assert_eq!(
        f.h.vehicle("auv-1").unwrap().availability,
        Availability::Idle
    );
    assert!(mirrored(&f, "auv-1", "Idle"));
}

#[test]
fn state_vectors_keep_a_busy_vehicle_busy() {
    let f = Fixture::new();
    f.alive("auv-1");
    f.h.dispatch_now(assignment("t-1", "auv-1")).unwrap();
    let t = now_ms();
    for n in 1..=3 {
        f.h.ingest_state(state("auv-1", t + n * 100, 80.0)).unwrap();
        assert_eq!(
            f.h.vehicle("auv-1").unwrap().availability,
            Availability::Busy
        );
    }
    // A fault outranks the task; when it ages out the vehicle is busy again, not idle.
    f.h.fault_reported("auv-1");
    assert_eq!(
        f.h.vehicle("auv-1").unwrap().availability,
        Availability::Fault
    );
    f.h.refresh_availability_all(now_ms() + 11 * 60_000);
    assert_eq!(
        f.h.vehicle("auv-1").unwrap().availability,
        Availability::Busy
    );
}

#[test]
fn a_fault_ages_out_after_ten_minutes() {
    let f = Fixture::new();
    f.alive("auv-1");
    f.h.fault_reported("auv-1");
    assert_eq!(
        f.h.vehicle("auv-1").unwrap().availability,
        Availability::Fault
    );
    assert!(mirrored(&f, "auv-1", "Faulty"));
    // Keep it in contact while the fault ages.
    f.h.ingest_state(state("auv-1", now_ms(), 80.0)).unwrap();
    f.h.refresh_availability_all(now_ms() + 11 * 60_000);
    assert_eq!(
        f.h.vehicle("auv-1").unwrap().availability,
        Availability::Idle
    );
}

#[test]
fn a_vehicle_at_rest_at_the_surface_with_battery_rising_is_charging() {
    let f = Fixture::new();
    f.announce("usv-1");
    let t = now_ms() - 5000;
    let at_rest = |t, battery| {
        let mut s = state("usv-1", t, battery);
        s.depth_m = 0.0;
        s.speed_mps = 0.0;
        s
    };
    f.h.ingest_state(at_rest(t, 50.0)).unwrap();
    f.h.ingest_state(at_rest(t + 1000, 50.2)).unwrap();
    assert_eq!(
        f.h.vehicle("usv-1").unwrap().availability,
        Availability::Charging
    );
    assert!(mirrored(&f, "usv-1", "Charging"));
}

#[test]
fn a_restarted_station_knows_its_vehicles_and_their_latest_state() {
    let f = Fixture::new();
    f.alive("auv-1");
    let latest = f.h.vehicle("auv-1").unwrap().latest;
    let f = f.restart();
    let v = f.h.vehicle("auv-1").unwrap();
    assert_eq!(v.latest, latest);
    assert_eq!(v.announcement.vehicle_id, "auv-1");
    assert!(mirrored(&f, "auv-1", "Idle"));
}

#[test]
fn a_system_clock_step_of_an_hour_either_way_changes_no_contact_and_expires_no_task() {
    let (f, time) = Fixture::manual_clock();
    let heard = |id: &str| {
        // The vehicles' clocks are right; only the station's system clock steps.
        f.h.ingest_state(state(id, f.h.now(), 80.0)).unwrap();
    };
    f.announce("auv-1");
    f.announce("auv-2");
    heard("auv-1");
    heard("auv-2");
    f.h.tick(f.h.now());
    f.h.dispatch_now(assignment("t-1", "auv-1")).unwrap();
    for step in [3_600_000, -3_600_000, -3_600_000] {
        time.step_system_clock(step);
        for _ in 0..3 {
            time.advance(1_000);
            heard("auv-1");
            heard("auv-2");
            f.h.tick(f.h.now());
        }
        for id in ["auv-1", "auv-2"] {
            assert_eq!(
                f.h.vehicle(id).unwrap().contact,
                Contact::Alive,
                "{id} after {step}"
            );
        }
        assert_eq!(f.h.task("t-1").unwrap().state, TaskState::Sent);
    }
    assert_eq!(f.h.clock_skew_ms(), -3_600_000);
    assert_eq!(
        f.h.stats().total_rejected(),
        0,
        "good data refused after the step"
    );
    // Real silence still counts: 31 s without a state and auv-2 is lost.
    for _ in 0..31 {
        time.advance(1_000);
        heard("auv-1");
        f.h.tick(f.h.now());
    }
    assert_eq!(f.h.vehicle("auv-2").unwrap().contact, Contact::Lost);
    assert_eq!(f.h.vehicle("auv-1").unwrap().contact, Contact::Alive);
}

#[test]
fn a_flood_of_announcements_with_made_up_ids_is_capped_and_real_vehicles_go_on() {
    let f = Fixture::with(|c| c.max_unheard_vehicles = 20);
    f.alive("auv-1");
    for i in 0..500 {
        f.announce(&format!("ghost-{i}"));
    }
    let stats = f.h.stats();
    assert_eq!(stats.rejected.get("too_many_unheard_vehicles"), Some(&480));
    assert!(f.h.vehicle("ghost-19").is_some());
    assert!(f.h.vehicle("ghost-20").is_none());
    // The real vehicle is still ingested, and re-announcing a known one is not refused.
    f.h.ingest_state(state("auv-1", now_ms(), 79.0)).unwrap();
    f.announce("auv-1");
    f.announce("ghost-3");
    assert_eq!(
        f.h.stats().rejected.get("too_many_unheard_vehicles"),
        Some(&480)
    );
    // A ghost that starts reporting frees a place.
    f.h.ingest_state(state("ghost-3", now_ms(), 50.0)).unwrap();
    f.announce("usv-7");
    assert!(f.h.vehicle("usv-7").is_some());
}

#[test]
fn a_large_fleet_coming_alive_is_summed_up_in_the_log_not_written_vehicle_by_vehicle() {
    let f = Fixture::new();
    let start = std::time::Instant::now();
    for i in 0..200 {
        f.alive(&format!("sw-{i}"));
    }
    // 200 registrations and 200 contact changes: at most ten INFO lines in each second
    // (window) the loop took get through, the rest are counted.
    let windows = start.elapsed().as_secs() + 1;
    let left_out = f.h.fleet_lines_not_logged();
    assert!(
        left_out >= 400 - windows * 10,
        "{left_out} left out in {windows} s"
    );
    assert!(f.h.fleet().iter().all(|v| v.contact == Contact::Alive));
}
