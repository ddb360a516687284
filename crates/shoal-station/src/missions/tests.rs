//! Dispatch and missions without DDS: checks, every transition the station drives,
//! retries, expiry, abort, abort all, and resuming after a restart.

use std::sync::atomic::Ordering;

use shoal_model::{EventKind, Severity, Task, TaskKind, TaskState, now_ms};

use crate::error::DispatchError;
use crate::missions::MissionState;
use crate::testing::{Fixture, assignment, goto, spec, state};

fn task_state(f: &Fixture, id: &str) -> TaskState {
    f.h.task(id).unwrap().state
}

#[test]
fn a_dispatched_task_goes_out_and_is_sent() {
    let f = Fixture::new();
    f.alive("auv-1");
    f.h.dispatch_now(assignment("t-1", "auv-1")).unwrap();
    assert_eq!(f.out.tasks().len(), 1);
    assert_eq!(f.out.tasks()[0].task_id, "t-1");
    assert_eq!(task_state(&f, "t-1"), TaskState::Sent);
    assert_eq!(f.h.stats().tasks_dispatched, 1);
    f.flush();
    assert!(
        f.h.history()
            .task_history("t-1")
            .unwrap()
            .assignment
            .is_some()
    );
}

#[test]
fn a_task_for_an_unknown_vehicle_is_refused_and_nothing_goes_out() {
    let f = Fixture::new();
    let err = f.h.dispatch_now(assignment("t-1", "ghost")).unwrap_err();
    assert!(matches!(err, DispatchError::UnknownVehicle(v) if v == "ghost"));
    assert!(f.out.tasks().is_empty());
    assert!(f.h.task("t-1").is_none());
}

#[test]
fn a_task_the_vehicle_did_not_announce_it_can_do_is_refused() {
    let f = Fixture::new();
    f.alive("auv-1");
    let t = shoal_model::TaskAssignment::new("t-1", "", "auv-1", now_ms(), &Task::ReturnHome);
    let err = f.h.dispatch_now(t).unwrap_err();
    assert!(
        matches!(
            err,
            DispatchError::Incapable {
                capability: "return_home",
                ..
            }
        ),
        "{err:?}"
    );
}

#[test]
fn a_vehicle_low_on_battery_may_only_be_sent_up_or_home() {
    let f = Fixture::new();
    f.announce("auv-1");
    f.h.ingest_state(state("auv-1", now_ms(), 10.0)).unwrap();
    let err = f.h.dispatch_now(assignment("t-1", "auv-1")).unwrap_err();
    assert!(matches!(err, DispatchError::LowBattery { .. }), "{err:?}");
    assert!(f.h.check_dispatch("auv-1", TaskKind::Surface).is_ok());
    assert!(f.h.check_dispatch("auv-1", TaskKind::GotoWaypoint).is_err());
}

#[test]
fn a_lost_vehicle_gets_no_task_but_always_an_abort() {
    let f = Fixture::new();
    f.alive("auv-1");
    let lost = crate::config::ms(f.h.config().lost_after_s);
    f.h.tick(now_ms() + lost + 100);
    let err = f.h.dispatch_now(assignment("t-1", "auv-1")).unwrap_err();
    assert!(matches!(err, DispatchError::VehicleLost(_)));
    assert!(f.h.check_dispatch("auv-1", TaskKind::Abort).is_ok());
}

#[test]
fn a_task_id_is_used_once() {
    let f = Fixture::new();
    f.alive("auv-1");
    f.h.dispatch_now(assignment("t-1", "auv-1")).unwrap();
    let err = f.h.dispatch_now(assignment("t-1", "auv-1")).unwrap_err();
    assert!(matches!(err, DispatchError::DuplicateTask(_)));
    assert_eq!(f.out.tasks().len(), 1);
}

#[test]
fn a_task_the_bus_refuses_fails_and_says_why() {
    let f = Fixture::new();
    f.alive("auv-1");
    f.out.refuse.store(true, Ordering::Relaxed);
    let err = f.h.dispatch_now(assignment("t-1", "auv-1")).unwrap_err();
    assert!(matches!(err, DispatchError::Publish(_)), "{err:?}");
    let t = f.h.task("t-1").unwrap();
    assert_eq!(t.state, TaskState::Failed);
    assert!(
        t.message.contains("could not be published"),
        "{}",
        t.message
    );
}

#[test]
fn a_mission_is_checked_whole_before_anything_is_registered() {
    let f = Fixture::new();
    f.alive("auv-1");
    let bad_id = f.h.plan_mission(spec("bad id", &[("auv-1", goto())]));
    assert!(matches!(
        bad_id,
        Err(DispatchError::BadField {
            field: "mission_id",
            ..
        })
    ));
    let empty = f.h.plan_mission(spec("m-1", &[]));
    assert!(matches!(
        empty,
        Err(DispatchError::BadField { field: "tasks", .. })
    ));
    let second_refused =
        f.h.plan_mission(spec("m-1", &[("auv-1", goto()), ("ghost", goto())]));
    match second_refused {
        Err(DispatchError::InMission { index: 1, error }) => {
            assert!(matches!(*error, DispatchError::UnknownVehicle(_)));
        }
        other => panic!("{other:?}"),
    }
    assert!(f.h.missions().is_empty());
    assert!(f.h.tasks().is_empty());
    f.h.plan_mission(spec("m-1", &[("auv-1", goto())])).unwrap();
    let again = f.h.plan_mission(spec("m-1", &[("auv-1", goto())]));
    assert!(matches!(again, Err(DispatchError::DuplicateMission(_))));
}

#[test]
fn a_mission_runs_each_vehicles_tasks_in_order_and_ends_done() {
    let f = Fixture::new();
    f.alive("auv-1");
    f.alive("auv-2");
    let m =
        f.h.plan_mission(spec(
            "m-1",
            &[("auv-1", goto()), ("auv-2", goto()), ("auv-1", goto())],
        ))
        .unwrap();
    assert_eq!(m.state, MissionState::Planned);
    assert!(
        f.out.tasks().is_empty(),
        "nothing goes out before the start"
    );
    let m = f.h.start_mission("m-1").unwrap();
    assert_eq!(m.state, MissionState::Running);
    let sent: Vec<String> = f.out.tasks().into_iter().map(|t| t.task_id).collect();
    assert_eq!(sent, ["m-1-1", "m-1-2"]);
    assert_eq!(task_state(&f, "m-1-3"), TaskState::Pending);
    f.report("m-1-1", "auv-1", TaskState::Accepted);
    f.report("m-1-1", "auv-1", TaskState::Running);
    f.report("m-1-1", "auv-1", TaskState::Done);
    assert_eq!(f.out.tasks().last().unwrap().task_id, "m-1-3");
    f.report("m-1-2", "auv-2", TaskState::Done);
    f.report("m-1-3", "auv-1", TaskState::Done);
    let m = f.h.mission("m-1").unwrap();
    assert_eq!(m.state, MissionState::Done);
    assert!((m.progress_pct - 100.0).abs() < 1e-9);
}

/// Over an acoustic link the report of a finished task can be the first thing through
/// after an outage: it proves the vehicle is heard, so its next task goes out.
#[test]
fn a_lost_vehicles_report_of_a_done_task_brings_it_back_and_its_next_task_goes_out() {
    let (f, time) = Fixture::manual_clock();
    f.announce("auv-1");
    f.h.ingest_state(state("auv-1", f.h.now(), 80.0)).unwrap();
    f.h.tick(f.h.now());
    f.h.plan_mission(spec("m-1", &[("auv-1", goto()), ("auv-1", goto())]))
        .unwrap();
    f.h.start_mission("m-1").unwrap();
    let report = |state: TaskState| {
        let mut s = crate::testing::status("m-1-1", "auv-1", state);
        s.timestamp_ms = f.h.now();
        f.h.ingest_task_status(crate::testing::valid(s)).unwrap();
    };
    report(TaskState::Accepted);
    report(TaskState::Running);
    // An outage longer than lost_after_s: nothing from the vehicle.
    time.advance(crate::config::ms(f.h.config().lost_after_s) + 1_000);
    f.h.tick(f.h.now());
    assert_eq!(
        f.h.vehicle("auv-1").unwrap().contact,
        crate::register::Contact::Lost
    );
    report(TaskState::Done);
    assert_eq!(
        f.h.vehicle("auv-1").unwrap().contact,
        crate::register::Contact::Alive
    );
    assert_eq!(task_state(&f, "m-1-2"), TaskState::Sent);
    assert!(
        f.h.recent_events()
            .iter()
            .any(|e| e.text == "contact with auv-1 regained")
    );
    // A relay's word about a task is not the vehicle's: it brings nothing back.
    time.advance(crate::config::ms(f.h.config().lost_after_s) + 1_000);
    f.h.tick(f.h.now());
    let mut sent = crate::testing::status("m-1-2", "auv-1", TaskState::Sent);
    sent.timestamp_ms = f.h.now();
    let _ = f.h.ingest_task_status(crate::testing::valid(sent));
    assert_eq!(
        f.h.vehicle("auv-1").unwrap().contact,
        crate::register::Contact::Lost
    );
}

#[test]
fn a_failed_task_skips_the_rest_of_its_vehicle_and_fails_the_mission() {
    let f = Fixture::new();
    f.alive("auv-1");
    f.h.plan_mission(spec("m-1", &[("auv-1", goto()), ("auv-1", goto())]))
        .unwrap();
    f.h.start_mission("m-1").unwrap();
    f.report("m-1-1", "auv-1", TaskState::Failed);
    assert_eq!(task_state(&f, "m-1-2"), TaskState::Aborted);
    assert_eq!(f.out.tasks().len(), 1, "the skipped task never went out");
    assert_eq!(f.h.mission("m-1").unwrap().state, MissionState::Failed);
    assert!(f.h.recent_events().iter().any(|e| e.kind == EventKind::Task
        && e.task_id == "m-1-1"
        && e.severity == Severity::Warning));
}

#[test]
fn a_report_never_moves_a_task_backwards_or_out_of_a_final_state() {
    let f = Fixture::new();
    f.alive("auv-1");
    f.h.dispatch_now(assignment("t-1", "auv-1")).unwrap();
    f.report("t-1", "auv-1", TaskState::Running);
    f.report("t-1", "auv-1", TaskState::Accepted);
    assert_eq!(task_state(&f, "t-1"), TaskState::Running);
    f.report("t-1", "auv-1", TaskState::Done);
    f.report("t-1", "auv-1", TaskState::Failed);
    assert_eq!(task_state(&f, "t-1"), TaskState::Done);
}

/// What the console's timeline draws: when each task went out, started and ended, in
/// station time, each set once; a skipped task only ends.
#[test]
fn a_missions_tasks_carry_when_they_were_dispatched_started_and_ended() {
    let (f, time) = Fixture::manual_clock();
    f.announce("auv-1");
    f.h.ingest_state(state("auv-1", f.h.now(), 80.0)).unwrap();
    f.h.tick(f.h.now());
    f.h.plan_mission(spec(
        "m-1",
        &[("auv-1", goto()), ("auv-1", goto()), ("auv-1", goto())],
    ))
    .unwrap();
    let times = |id: &str| {
        let t = f.h.task(id).unwrap();
        (t.dispatched_ms, t.started_ms, t.ended_ms)
    };
    assert_eq!(times("m-1-1"), (None, None, None));
    time.advance(1_000);
    let sent_at = f.h.now();
    f.h.start_mission("m-1").unwrap();
    assert_eq!(times("m-1-1"), (Some(sent_at), None, None));
    let report = |id: &str, state: TaskState| {
        let mut s = crate::testing::status(id, "auv-1", state);
        s.timestamp_ms = f.h.now();
        f.h.ingest_task_status(crate::testing::valid(s)).unwrap();
    };
    time.advance(1_000);
    let started_at = f.h.now();
    report("m-1-1", TaskState::Running);
    time.advance(1_000);
    report("m-1-1", TaskState::Running);
    assert_eq!(times("m-1-1"), (Some(sent_at), Some(started_at), None));
    time.advance(1_000);
    let ended_at = f.h.now();
    report("m-1-1", TaskState::Done);
    assert_eq!(
        times("m-1-1"),
        (Some(sent_at), Some(started_at), Some(ended_at))
    );
    // The next task went out when the first was done.
    assert_eq!(times("m-1-2"), (Some(ended_at), None, None));
    time.advance(1_000);
    report("m-1-2", TaskState::Failed);
    let failed_at = f.h.now();
    assert_eq!(times("m-1-2"), (Some(ended_at), None, Some(failed_at)));
    assert_eq!(times("m-1-3"), (None, None, Some(failed_at)), "skipped");
    // The mission's view carries them too, and a late report moves nothing.
    time.advance(1_000);
    report("m-1-1", TaskState::Running);
    let m = f.h.mission("m-1").unwrap();
    let t = &m.tasks[0];
    assert_eq!(
        (t.dispatched_ms, t.started_ms, t.ended_ms),
        (Some(sent_at), Some(started_at), Some(ended_at))
    );
}

#[test]
fn aborting_a_mission_ends_pending_tasks_and_stops_busy_vehicles() {
    let f = Fixture::new();
    f.alive("auv-1");
    f.h.plan_mission(spec("m-1", &[("auv-1", goto()), ("auv-1", goto())]))
        .unwrap();
    f.h.start_mission("m-1").unwrap();
    f.report("m-1-1", "auv-1", TaskState::Running);
    let m = f.h.abort_mission("m-1").unwrap();
    assert_eq!(m.state, MissionState::Aborted);
    assert_eq!(task_state(&f, "m-1-2"), TaskState::Aborted);
    let abort = f
        .out
        .tasks()
        .into_iter()
        .find(|t| t.kind == TaskKind::Abort);
    assert_eq!(abort.unwrap().vehicle_id, "auv-1");
    assert!(matches!(
        f.h.abort_mission("m-unknown"),
        Err(DispatchError::UnknownMission(_))
    ));
}

#[test]
fn abort_all_stops_every_vehicle_in_contact_and_raises_an_alarm() {
    let f = Fixture::new();
    f.alive("auv-1");
    f.alive("auv-2");
    f.announce("auv-silent");
    f.h.plan_mission(spec("m-1", &[("auv-1", goto())])).unwrap();
    f.h.start_mission("m-1").unwrap();
    let stopped = f.h.abort_all();
    assert_eq!(
        stopped.len(),
        3,
        "silent is not lost: it gets the abort too"
    );
    let aborts = f
        .out
        .tasks()
        .into_iter()
        .filter(|t| t.kind == TaskKind::Abort)
        .count();
    assert_eq!(aborts, 3);
    assert_eq!(f.h.mission("m-1").unwrap().state, MissionState::Aborted);
    assert!(
        f.out
            .events()
            .iter()
            .any(|e| e.severity == Severity::Alarm && e.text.starts_with("ABORT ALL"))
    );
}

#[test]
fn a_sent_task_never_acknowledged_expires_and_fails_its_mission() {
    let f = Fixture::new();
    f.alive("auv-1");
    f.h.plan_mission(spec("m-1", &[("auv-1", goto())])).unwrap();
    f.h.start_mission("m-1").unwrap();
    let timeout = crate::config::ms(f.h.config().task_ack_timeout_s);
    f.h.expire_tasks(now_ms() + timeout / 2);
    assert_eq!(task_state(&f, "m-1-1"), TaskState::Sent);
    f.h.expire_tasks(now_ms() + timeout + 1000);
    assert_eq!(task_state(&f, "m-1-1"), TaskState::Expired);
    assert_eq!(f.h.mission("m-1").unwrap().state, MissionState::Failed);
}

#[test]
fn a_task_the_acoustic_link_gave_up_on_is_sent_again_a_bounded_number_of_times() {
    let f = Fixture::with(|c| c.acoustic_task_retries = 2);
    f.alive("auv-ac1");
    f.h.link_reported(shoal_model::LinkStatus {
        vehicle_id: "auv-ac1".into(),
        link: shoal_model::LinkKind::Acoustic,
        cdt_address: 1,
        vehicle_address: 2,
        rssi_db: None,
        integrity: None,
        heard_ms: now_ms(),
        participant: "cdt".into(),
        cdt_latitude_deg: None,
        cdt_longitude_deg: None,
        cdt_vehicle: None,
        frames: None,
        interval_s: None,
    });
    f.h.dispatch_now(assignment("t-1", "auv-ac1")).unwrap();
    assert_eq!(
        f.h.task("t-1").unwrap().link,
        Some(shoal_model::LinkKind::Acoustic)
    );
    for n in 1..=2 {
        f.report("t-1", "auv-ac1", TaskState::Expired);
        assert_eq!(f.out.tasks().len(), 1 + n, "retry {n} went out");
        assert_eq!(f.h.task("t-1").unwrap().retries, u32::try_from(n).unwrap());
    }
    f.report("t-1", "auv-ac1", TaskState::Expired);
    assert_eq!(f.out.tasks().len(), 3);
    assert_eq!(task_state(&f, "t-1"), TaskState::Expired);
}

#[test]
fn a_task_over_ip_that_a_relay_reports_expired_is_not_sent_again() {
    let f = Fixture::with(|c| c.acoustic_task_retries = 2);
    f.alive("auv-1");
    f.h.dispatch_now(assignment("t-1", "auv-1")).unwrap();
    f.report("t-1", "auv-1", TaskState::Expired);
    assert_eq!(f.out.tasks().len(), 1);
    assert_eq!(task_state(&f, "t-1"), TaskState::Expired);
}

#[test]
fn an_accepted_task_is_reported_as_an_event() {
    let f = Fixture::new();
    f.alive("auv-1");
    f.h.dispatch_now(assignment("t-1", "auv-1")).unwrap();
    f.report("t-1", "auv-1", TaskState::Accepted);
    let ev = f.h.recent_events();
    assert!(ev.iter().any(|e| e.text == "task t-1 accepted"), "{ev:?}");
    assert_eq!(f.h.stats().task_status, 1);
}

#[test]
fn a_status_from_another_vehicle_than_the_tasks_is_refused() {
    let f = Fixture::new();
    f.alive("auv-1");
    f.alive("auv-2");
    f.h.dispatch_now(assignment("t-1", "auv-1")).unwrap();
    let err =
        f.h.ingest_task_status(crate::testing::valid(crate::testing::status(
            "t-1",
            "auv-2",
            TaskState::Done,
        )))
        .unwrap_err();
    assert_eq!(err.reason(), "unknown_task");
    assert_eq!(task_state(&f, "t-1"), TaskState::Sent);
}

#[test]
fn a_restarted_station_resumes_its_missions_where_they_were() {
    let f = Fixture::new();
    f.alive("auv-1");
    f.h.plan_mission(spec("m-1", &[("auv-1", goto()), ("auv-1", goto())]))
        .unwrap();
    f.h.start_mission("m-1").unwrap();
    f.report("m-1-1", "auv-1", TaskState::Done);
    assert_eq!(task_state(&f, "m-1-2"), TaskState::Sent);
    let f = f.restart();
    assert_eq!(task_state(&f, "m-1-1"), TaskState::Done);
    assert_eq!(task_state(&f, "m-1-2"), TaskState::Sent);
    assert_eq!(f.h.mission("m-1").unwrap().state, MissionState::Running);
    // The vehicle is busy with the restored task before it is heard again.
    assert_eq!(
        f.h.vehicle("auv-1").unwrap().availability,
        shoal_model::Availability::Busy
    );
}

#[test]
fn a_restarted_station_publishes_a_task_under_way_again_unchanged_and_not_an_ended_one() {
    let f = Fixture::new();
    f.alive("auv-1");
    f.h.plan_mission(spec("m-1", &[("auv-1", goto())])).unwrap();
    f.h.dispatch_now(assignment("t-done", "auv-1")).unwrap();
    f.report("t-done", "auv-1", TaskState::Done);
    f.h.start_mission("m-1").unwrap();
    let first = f
        .out
        .tasks()
        .into_iter()
        .find(|t| t.task_id == "m-1-1")
        .unwrap();
    let f = f.restart();
    f.h.resume_missions();
    // The same assignment, sequence and expiry included: a vehicle that restarted resumes
    // it, one that has it already (its task ledger says so) ignores it. Not a new send.
    assert_eq!(f.out.tasks(), vec![first]);
    assert_eq!(f.h.stats().tasks_dispatched, 0);
    assert_eq!(task_state(&f, "m-1-1"), TaskState::Sent);
    // Once it ends, it is retired from the bus like any other.
    f.report("m-1-1", "auv-1", TaskState::Done);
    assert_eq!(f.out.retired(), vec!["m-1-1".to_string()]);
}

#[test]
fn each_send_carries_the_next_issue_sequence_and_a_start_by_expiry_also_after_a_restart() {
    let f = Fixture::new();
    f.alive("auv-1");
    let before = now_ms();
    f.h.dispatch_now(assignment("t-1", "auv-1")).unwrap();
    f.h.dispatch_now(assignment("t-2", "auv-1")).unwrap();
    let sent = f.out.tasks();
    assert_eq!(sent[1].issue_seq, sent[0].issue_seq + 1);
    // Seeded from the start time (µs), so a wiped history cannot make it repeat.
    assert!(sent[0].issue_seq > u64::try_from(before).unwrap() * 1000 - 60_000_000);
    // Three quarters of the 60 s acknowledgement timeout on IP. Station time is the
    // start's system time advanced by a monotonic clock, so it may sit a millisecond or
    // so behind the system clock `before` was read from.
    let window = sent[0].expires_ms - before;
    assert!(
        (44_900..46_000).contains(&window),
        "start window {window} ms"
    );
    f.flush();
    let stored =
        f.h.history()
            .task_history("t-2")
            .unwrap()
            .assignment
            .unwrap();
    assert_eq!(
        (stored.issue_seq, stored.expires_ms),
        (sent[1].issue_seq, sent[1].expires_ms)
    );
    let f = f.restart();
    f.alive("auv-1");
    f.h.dispatch_now(assignment("t-3", "auv-1")).unwrap();
    let t3 = f
        .out
        .tasks()
        .into_iter()
        .find(|t| t.task_id == "t-3")
        .unwrap();
    assert!(
        t3.issue_seq > sent[1].issue_seq,
        "a restarted station repeated a sequence"
    );
}

#[test]
fn an_ended_task_is_retired_from_the_bus_once_and_an_unsent_one_never() {
    let f = Fixture::new();
    f.alive("auv-1");
    f.h.dispatch_now(assignment("t-1", "auv-1")).unwrap();
    f.report("t-1", "auv-1", TaskState::Running);
    assert!(f.out.retired().is_empty(), "a running task was retired");
    f.report("t-1", "auv-1", TaskState::Done);
    f.report("t-1", "auv-1", TaskState::Done);
    assert_eq!(f.out.retired(), vec!["t-1".to_string()]);
    assert_eq!(f.h.stats().tasks_retired, 1);
    // A mission task skipped after its predecessor failed never went out: nothing to retire.
    f.h.plan_mission(spec("m-1", &[("auv-1", goto()), ("auv-1", goto())]))
        .unwrap();
    f.h.start_mission("m-1").unwrap();
    f.report("m-1-1", "auv-1", TaskState::Failed);
    assert_eq!(task_state(&f, "m-1-2"), TaskState::Aborted);
    assert_eq!(
        f.out.retired(),
        vec!["t-1".to_string(), "m-1-1".to_string()]
    );
}

#[test]
fn an_expired_task_is_retired_so_a_late_vehicle_never_gets_it() {
    let f = Fixture::new();
    f.alive("auv-1");
    f.h.dispatch_now(assignment("t-1", "auv-1")).unwrap();
    f.h.expire_tasks(now_ms() + 61_000);
    assert_eq!(task_state(&f, "t-1"), TaskState::Expired);
    assert_eq!(f.out.retired(), vec!["t-1".to_string()]);
}

#[test]
fn ended_tasks_and_missions_past_their_retention_are_forgotten_and_live_ones_kept() {
    let f = Fixture::new();
    f.alive("auv-1");
    f.alive("auv-2");
    f.h.dispatch_now(assignment("t-old", "auv-1")).unwrap();
    f.report("t-old", "auv-1", TaskState::Done);
    f.h.dispatch_now(assignment("t-live", "auv-2")).unwrap();
    f.report("t-live", "auv-2", TaskState::Running);
    f.h.plan_mission(spec("m-done", &[("auv-1", goto())]))
        .unwrap();
    f.h.start_mission("m-done").unwrap();
    f.report("m-done-1", "auv-1", TaskState::Done);
    f.h.plan_mission(spec("m-run", &[("auv-2", goto()), ("auv-2", goto())]))
        .unwrap();
    f.h.start_mission("m-run").unwrap();
    f.report("m-run-1", "auv-2", TaskState::Done);
    let in_model = |id: &str| {
        let q = format!("ASK {{ ?t shoal:taskId \"{id}\" }}");
        matches!(
            f.h.sparql(&q, &shoal_semantic::QueryLimits::default())
                .unwrap(),
            shoal_semantic::QueryResult::Boolean(true)
        )
    };
    assert!(in_model("t-old"));
    // A day and a minute later.
    f.h.prune_tasks(now_ms() + 24 * 3_600_000 + 61_000);
    for gone in ["t-old", "m-done-1"] {
        assert!(f.h.task(gone).is_none(), "{gone} kept");
        assert!(!in_model(gone), "{gone} still in the model");
    }
    assert!(f.h.mission("m-done").is_none());
    // Live, or part of a live mission: kept.
    for kept in ["t-live", "m-run-1", "m-run-2"] {
        assert!(f.h.task(kept).is_some(), "{kept} forgotten");
        assert!(in_model(kept), "{kept} not in the model");
    }
    assert_eq!(f.h.stats().tasks_forgotten, 2);
    // The history still has them.
    f.flush();
    assert!(
        f.h.history()
            .task_history("t-old")
            .unwrap()
            .assignment
            .is_some()
    );
}

#[test]
fn a_surface_vehicle_sent_somewhere_without_depth_or_altitude_goes_at_the_surface() {
    use crate::testing::{announcement, state as state_at, valid};
    let f = Fixture::new();
    let mut usv = announcement("usv-1");
    usv.kind = shoal_model::VehicleKind::Usv;
    f.h.ingest_announcement(valid(usv), "writer-1", "participant-1");
    f.h.ingest_state(state_at("usv-1", now_ms(), 80.0)).unwrap();
    f.h.tick(now_ms());
    f.alive("auv-1");
    let goto = |depth_m| Task::GotoWaypoint {
        target: shoal_model::GeoPoint {
            latitude_deg: 43.001,
            longitude_deg: 5.9,
        },
        depth_m,
        altitude_m: None,
        speed_mps: 1.0,
    };
    let a = shoal_model::TaskAssignment::new("t-usv", "", "usv-1", now_ms(), &goto(None));
    f.h.dispatch_now(a).unwrap();
    assert_eq!(f.out.tasks()[0].depth_m, 0.0);
    // In a mission too.
    f.h.plan_mission(spec("m-usv", &[("usv-1", goto(None))]))
        .unwrap();
    assert_eq!(f.h.task("m-usv-1").unwrap().assignment.depth_m, 0.0);
    // An underwater vehicle still has to be told.
    let a = shoal_model::TaskAssignment::new("t-auv", "", "auv-1", now_ms(), &goto(None));
    assert!(matches!(
        f.h.dispatch_now(a),
        Err(DispatchError::Invalid(_))
    ));
}

#[test]
fn beyond_max_ended_tasks_the_oldest_ended_go_first_and_live_ones_stay() {
    let f = Fixture::with(|c| c.max_ended_tasks = 3);
    f.alive("auv-1");
    f.alive("auv-2");
    for i in 0..6 {
        let id = format!("t-{i}");
        f.h.dispatch_now(assignment(&id, "auv-1")).unwrap();
        f.report(&id, "auv-1", TaskState::Done);
        std::thread::sleep(std::time::Duration::from_millis(2));
    }
    f.h.dispatch_now(assignment("t-live", "auv-2")).unwrap();
    f.h.prune_tasks(now_ms() + 2_000);
    for gone in ["t-0", "t-1", "t-2"] {
        assert!(f.h.task(gone).is_none(), "{gone} kept");
    }
    for kept in ["t-3", "t-4", "t-5", "t-live"] {
        assert!(f.h.task(kept).is_some(), "{kept} forgotten");
    }
    assert_eq!(f.h.stats().tasks_forgotten, 3);
}

#[test]
fn an_underwater_vehicle_sent_neither_depth_nor_altitude_is_told_what_to_give() {
    let f = Fixture::new();
    f.alive("auv-1");
    let Task::GotoWaypoint { target, .. } = goto() else {
        unreachable!("goto() is a goto")
    };
    let neither = Task::GotoWaypoint {
        target,
        depth_m: None,
        altitude_m: None,
        speed_mps: 1.0,
    };
    let err =
        f.h.plan_mission(spec("m-auv", &[("auv-1", neither)]))
            .unwrap_err();
    let text = err.to_string();
    assert!(
        text.starts_with("tasks[0]: invalid task: depth_m: "),
        "{text}"
    );
    assert!(
        text.contains("give depth_m (0 for the surface) or altitude_m"),
        "{text}"
    );
    assert!(f.h.mission("m-auv").is_none());
}

#[test]
fn a_hold_until_the_next_task_must_be_its_vehicles_last_task_in_a_mission() {
    let f = Fixture::new();
    f.alive("auv-1");
    f.alive("auv-2");
    let open = Task::Hold { duration_s: 0.0 };
    // Another task of the same vehicle after it would never be sent.
    let err =
        f.h.plan_mission(spec(
            "m-stuck",
            &[("auv-1", open.clone()), ("auv-1", goto())],
        ))
        .unwrap_err();
    assert!(
        matches!(
            &err,
            DispatchError::InMission { index: 0, error }
                if matches!(**error, DispatchError::BadField { field: "duration_s", .. })
        ),
        "{err:?}"
    );
    assert!(f.h.mission("m-stuck").is_none());
    assert!(
        f.h.preview_mission(&spec(
            "m-stuck",
            &[("auv-1", open.clone()), ("auv-1", goto())]
        ))
        .is_err()
    );
    // Last for its vehicle (another vehicle's task may follow), or with a duration: planned.
    f.h.plan_mission(spec(
        "m-last",
        &[("auv-1", goto()), ("auv-1", open), ("auv-2", goto())],
    ))
    .unwrap();
    f.h.plan_mission(spec(
        "m-timed",
        &[
            ("auv-2", Task::Hold { duration_s: 30.0 }),
            ("auv-2", goto()),
        ],
    ))
    .unwrap();
}
