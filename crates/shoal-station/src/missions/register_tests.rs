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
