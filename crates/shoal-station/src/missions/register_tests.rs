//! The Mission & Task Register's state machine, without DDS.
use super::*;
use shoal_model::GeoPoint;
use shoal_model::Task;

const T: i64 = 1_800_000_000_000;

fn goto(id: &str, vehicle: &str) -> TaskAssignment {
    TaskAssignment::new(
        id,
        "m1",
        vehicle,
        T,
        &Task::GotoWaypoint {
            target: GeoPoint {
                latitude_deg: 63.0,
                longitude_deg: 10.0,
            },
            depth_m: Some(5.0),
            altitude_m: None,
            speed_mps: 1.5,
        },
    )
}

fn report(id: &str, vehicle: &str, state: TaskState) -> TaskStatus {
    TaskStatus {
        task_id: id.into(),
        vehicle_id: vehicle.into(),
        timestamp_ms: T,
        state,
        progress_pct: 50.0,
        message: String::new(),
    }
}

fn mission() -> TaskRegister {
    let mut r = TaskRegister::default();
    for (id, v) in [("a1", "a"), ("b1", "b"), ("a2", "a"), ("b2", "b")] {
        r.add_task(goto(id, v), T);
    }
    r.add_mission(
        "m1",
        "two each",
        vec!["a1".into(), "b1".into(), "a2".into(), "b2".into()],
        T,
    );
    r
}

#[test]
fn states_only_move_forward() {
    assert!(may_move(TaskState::Pending, TaskState::Sent));
    assert!(may_move(TaskState::Sent, TaskState::Running));
    assert!(may_move(TaskState::Running, TaskState::Running));
    assert!(!may_move(TaskState::Running, TaskState::Accepted));
    assert!(!may_move(TaskState::Done, TaskState::Failed));
    assert!(!may_move(TaskState::Sent, TaskState::Pending));
}

#[test]
fn a_mission_runs_each_vehicles_tasks_in_order_and_ends_done() {
    let mut r = mission();
    assert_eq!(r.start("m1", T).unwrap(), vec!["a1", "b1"]);
    for id in ["a1", "b1"] {
        r.sent(id, LinkKind::Ip, T);
    }
    assert_eq!(
        r.on_status(&report("a1", "a", TaskState::Running), T),
        Some(true)
    );
    assert!(r.advance("a1", T).is_empty());
    assert_eq!(
        r.on_status(&report("a1", "a", TaskState::Done), T),
        Some(true)
    );
    assert_eq!(r.advance("a1", T), vec!["a2"]);
    r.sent("a2", LinkKind::Ip, T);
    // A late "running" after "done" changes nothing.
    assert_eq!(
        r.on_status(&report("a1", "a", TaskState::Running), T),
        Some(false)
    );
    assert_eq!(r.task("a1").unwrap().state, TaskState::Done);
    for id in ["b1", "a2", "b2"] {
        let v = &id[..1];
        r.sent(id, LinkKind::Ip, T);
        r.on_status(&report(id, v, TaskState::Done), T);
        r.advance(id, T);
    }
    let m = r.mission("m1").unwrap();
    assert_eq!(m.state, MissionState::Done);
    assert!((m.progress_pct - 100.0).abs() < 1e-9);
    assert!(m.ended_ms.is_some());
}

#[test]
fn a_failed_task_skips_the_rest_of_its_vehicle_and_fails_the_mission() {
    let mut r = mission();
    r.start("m1", T);
    r.sent("a1", LinkKind::Ip, T);
    r.on_status(&report("a1", "a", TaskState::Failed), T);
    // b1 is still pending (never sent here): it is next; nothing more for vehicle a.
    assert_eq!(r.advance("a1", T), vec!["b1"]);
    assert_eq!(r.task("a2").unwrap().state, TaskState::Aborted);
    assert!(r.task("a2").unwrap().message.contains("skipped"));
    for id in ["b1", "b2"] {
        r.sent(id, LinkKind::Ip, T);
        r.on_status(&report(id, "b", TaskState::Done), T);
        r.advance(id, T);
    }
    assert_eq!(r.mission("m1").unwrap().state, MissionState::Failed);
}

#[test]
fn reports_for_unknown_tasks_or_from_another_vehicle_are_refused() {
    let mut r = mission();
    assert_eq!(r.on_status(&report("zz", "a", TaskState::Done), T), None);
    assert_eq!(r.on_status(&report("a1", "b", TaskState::Done), T), None);
}

#[test]
fn aborting_a_mission_ends_pending_tasks_and_names_busy_vehicles() {
    let mut r = mission();
    r.start("m1", T);
    r.sent("a1", LinkKind::Ip, T);
    r.sent("b1", LinkKind::Acoustic, T);
    r.on_status(&report("b1", "b", TaskState::Done), T);
    r.advance("b1", T);
    r.sent("b2", LinkKind::Acoustic, T);
    let mut busy = r.abort_mission("m1", T).unwrap();
    busy.sort();
    assert_eq!(busy, vec!["a", "b"]);
    assert_eq!(r.task("a2").unwrap().state, TaskState::Aborted);
    assert_eq!(r.mission("m1").unwrap().state, MissionState::Aborted);
    r.on_status(&report("a1", "a", TaskState::Aborted), T);
    r.on_status(&report("b2", "b", TaskState::Aborted), T);
    r.advance("a1", T);
    r.advance("b2", T);
    let m = r.mission("m1").unwrap();
    assert_eq!(m.state, MissionState::Aborted);
    assert!(m.ended_ms.is_some());
}

#[test]
fn an_undelivered_acoustic_task_is_retried_a_bounded_number_of_times() {
    let mut r = mission();
    r.start("m1", T);
    r.sent("a1", LinkKind::Acoustic, T);
    r.sent("b1", LinkKind::Ip, T);
    assert!(
        r.retry("b1", 2, T + 1).is_none(),
        "IP tasks are not retried"
    );
    for n in 1..=2 {
        let again = r.retry("a1", 2, T + n).unwrap();
        assert_eq!(again.issued_ms, T + n);
        assert_eq!(r.task("a1").unwrap().state, TaskState::Pending);
        r.sent("a1", LinkKind::Acoustic, T + n);
    }
    assert!(r.retry("a1", 2, T + 3).is_none());
    assert_eq!(r.task("a1").unwrap().retries, 2);
}

#[test]
fn a_restarted_register_resumes_missions_from_the_transitions_it_recorded() {
    let mut r = mission();
    r.start("m1", T);
    r.sent("a1", LinkKind::Ip, T);
    r.sent("b1", LinkKind::Acoustic, T);
    r.on_status(&report("a1", "a", TaskState::Done), T);
    r.advance("a1", T);
    r.sent("a2", LinkKind::Ip, T);
    // What the history holds: assignments, the vehicles' reports, the station's own.
    let mut statuses: Vec<TaskStatus> = r.take_transitions();
    statuses.push(report("a1", "a", TaskState::Done));
    let history: Vec<shoal_history::TaskHistory> = ["a1", "b1", "a2", "b2"]
        .iter()
        .map(|id| shoal_history::TaskHistory {
            assignment: Some(r.task(id).unwrap().assignment.clone()),
            statuses: statuses
                .iter()
                .filter(|s| s.task_id == *id)
                .cloned()
                .collect(),
        })
        .collect();
    let mut back = TaskRegister::default();
    back.restore(history, T + 10);
    assert_eq!(back.task("a1").unwrap().state, TaskState::Done);
    assert_eq!(back.task("a2").unwrap().state, TaskState::Sent);
    assert_eq!(back.task("b1").unwrap().link, Some(LinkKind::Acoustic));
    assert_eq!(back.mission("m1").unwrap().state, MissionState::Running);
    // Nothing new is due: both vehicles have a task under way.
    assert!(back.due_tasks().is_empty());
    back.on_status(&report("b1", "b", TaskState::Done), T + 20);
    assert_eq!(back.advance("b1", T + 20), vec!["b2"]);
}

#[test]
fn sent_tasks_expire_by_their_links_timeout() {
    let mut r = mission();
    r.start("m1", T);
    r.sent("a1", LinkKind::Ip, T);
    r.sent("b1", LinkKind::Acoustic, T);
    assert_eq!(r.overdue(T + 61_000, 60_000, 600_000), vec!["a1"]);
    assert!(r.overdue(T + 30_000, 60_000, 600_000).is_empty());
    let mut both = r.overdue(T + 601_000, 60_000, 600_000);
    both.sort();
    assert_eq!(both, vec!["a1", "b1"]);
}

/// The times the console's timeline draws: each is set by the first transition into its
/// stage and never moved by a repeated or late report.
#[test]
fn a_tasks_dispatch_start_and_end_times_are_set_once_each() {
    let mut r = mission();
    r.start("m1", T);
    let a1 = |r: &TaskRegister| {
        let t = r.task("a1").unwrap();
        (t.dispatched_ms, t.started_ms, t.ended_ms)
    };
    assert_eq!(a1(&r), (None, None, None), "pending: nothing yet");
    r.sent("a1", LinkKind::Ip, T + 1);
    assert_eq!(a1(&r), (Some(T + 1), None, None));
    r.on_status(&report("a1", "a", TaskState::Accepted), T + 2);
    assert_eq!(a1(&r), (Some(T + 1), Some(T + 2), None));
    // Running after accepted, and running again: the start stays the acceptance.
    r.on_status(&report("a1", "a", TaskState::Running), T + 3);
    r.on_status(&report("a1", "a", TaskState::Running), T + 4);
    assert_eq!(a1(&r), (Some(T + 1), Some(T + 2), None));
    // A duplicated send does not move the dispatch time either.
    r.sent("a1", LinkKind::Ip, T + 5);
    assert_eq!(a1(&r), (Some(T + 1), Some(T + 2), None));
    r.on_status(&report("a1", "a", TaskState::Done), T + 6);
    assert_eq!(a1(&r), (Some(T + 1), Some(T + 2), Some(T + 6)));
    // Late or repeated reports after the end move nothing.
    for s in [TaskState::Running, TaskState::Done, TaskState::Failed] {
        r.on_status(&report("a1", "a", s), T + 7);
    }
    r.finish("a1", TaskState::Expired, "late", T + 8);
    assert_eq!(a1(&r), (Some(T + 1), Some(T + 2), Some(T + 6)));
    // A task first reported running starts then.
    r.sent("b1", LinkKind::Ip, T + 1);
    r.on_status(&report("b1", "b", TaskState::Running), T + 9);
    r.on_status(&report("b1", "b", TaskState::Running), T + 10);
    assert_eq!(r.task("b1").unwrap().started_ms, Some(T + 9));
}

#[test]
fn tasks_ended_by_the_station_get_an_end_time_and_no_start() {
    let mut r = mission();
    r.start("m1", T);
    r.sent("a1", LinkKind::Ip, T + 1);
    r.on_status(&report("a1", "a", TaskState::Failed), T + 2);
    r.advance("a1", T + 2);
    // a2 was skipped without ever going out.
    let a2 = r.task("a2").unwrap();
    assert_eq!(a2.state, TaskState::Aborted);
    assert_eq!(
        (a2.dispatched_ms, a2.started_ms, a2.ended_ms),
        (None, None, Some(T + 2))
    );
    let a1 = r.task("a1").unwrap();
    assert_eq!(
        (a1.dispatched_ms, a1.started_ms, a1.ended_ms),
        (Some(T + 1), None, Some(T + 2))
    );
    // Expired by the station, never acknowledged.
    r.sent("b1", LinkKind::Ip, T + 3);
    r.finish("b1", TaskState::Expired, "not acknowledged", T + 4);
    r.finish("b1", TaskState::Aborted, "again", T + 5);
    let b1 = r.task("b1").unwrap();
    assert_eq!(
        (b1.dispatched_ms, b1.started_ms, b1.ended_ms),
        (Some(T + 3), None, Some(T + 4))
    );
    // Aborted by the operator while pending.
    r.abort_mission("m1", T + 6);
    let b2 = r.task("b2").unwrap();
    assert_eq!(
        (b2.dispatched_ms, b2.started_ms, b2.ended_ms),
        (None, None, Some(T + 6))
    );
}

#[test]
fn a_retried_task_keeps_its_first_dispatch_time() {
    let mut r = mission();
    r.start("m1", T);
    r.sent("a1", LinkKind::Acoustic, T + 1);
    r.retry("a1", 2, T + 100).unwrap();
    assert_eq!(r.task("a1").unwrap().dispatched_ms, Some(T + 1));
    r.sent("a1", LinkKind::Acoustic, T + 100);
    assert_eq!(r.task("a1").unwrap().dispatched_ms, Some(T + 1));
}

/// The vehicle's acceptance can be applied before the station marks its write sent: the
/// task was dispatched all the same, and not after it started.
#[test]
fn an_acceptance_applied_before_the_send_is_noted_still_gives_a_dispatch_time() {
    let mut r = mission();
    r.start("m1", T);
    r.on_status(&report("a1", "a", TaskState::Accepted), T + 2);
    r.sent("a1", LinkKind::Ip, T + 3);
    let t = r.task("a1").unwrap();
    assert_eq!(t.state, TaskState::Accepted);
    assert_eq!((t.dispatched_ms, t.started_ms), (Some(T + 2), Some(T + 2)));
}

#[test]
fn a_restored_register_takes_the_times_from_the_history() {
    let mut r = mission();
    r.start("m1", T);
    r.sent("a1", LinkKind::Ip, T + 1);
    let mut statuses = r.take_transitions();
    for (s, at) in [
        (TaskState::Accepted, T + 2),
        (TaskState::Running, T + 3),
        (TaskState::Done, T + 4),
    ] {
        let mut s = report("a1", "a", s);
        s.timestamp_ms = at;
        statuses.push(s);
    }
    let history = vec![shoal_history::TaskHistory {
        assignment: Some(r.task("a1").unwrap().assignment.clone()),
        statuses,
    }];
    let mut back = TaskRegister::default();
    back.restore(history, T + 10);
    let t = back.task("a1").unwrap();
    assert_eq!(
        (t.dispatched_ms, t.started_ms, t.ended_ms),
        (Some(T + 1), Some(T + 2), Some(T + 4))
    );
}
