//! What the station core's unit tests share: a core over a real SQLite history in a
//! temporary directory, publishing into an outbox that records what it was given.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use shoal_history::{History, HistoryConfig};
use shoal_model::{
    Event, GeoPoint, LinkKind, StateVector, Task, TaskAssignment, TaskState, TaskStatus, Validated,
    VehicleAnnouncement, VehicleKind, now_ms,
};

use crate::bus::{Outbox, PublishError};
use crate::clock::{Clock, ManualTime};
use crate::config::StationConfig;
use crate::core::StationHandle;

/// An outbox that keeps what the core published; it can be told to refuse.
#[derive(Debug, Default)]
pub(crate) struct RecordingOutbox {
    pub(crate) tasks: Mutex<Vec<TaskAssignment>>,
    pub(crate) events: Mutex<Vec<Event>>,
    /// Ids of the tasks retired (disposed), in order.
    pub(crate) retired: Mutex<Vec<String>>,
    pub(crate) refuse: AtomicBool,
}

impl RecordingOutbox {
    pub(crate) fn tasks(&self) -> Vec<TaskAssignment> {
        self.tasks.lock().unwrap().clone()
    }

    pub(crate) fn events(&self) -> Vec<Event> {
        self.events.lock().unwrap().clone()
    }

    pub(crate) fn retired(&self) -> Vec<String> {
        self.retired.lock().unwrap().clone()
    }
}

impl Outbox for RecordingOutbox {
    fn publish_task(&self, task: TaskAssignment) -> Result<(), PublishError> {
        if self.refuse.load(Ordering::Relaxed) {
            return Err(PublishError::new("TaskAssignment", "refused by the test"));
        }
        self.tasks.lock().unwrap().push(task);
        Ok(())
    }

    fn retire_task(&self, task: &TaskAssignment) -> Result<(), PublishError> {
        self.retired.lock().unwrap().push(task.task_id.clone());
        Ok(())
    }

    fn publish_event(&self, event: Event) -> Result<(), PublishError> {
        self.events.lock().unwrap().push(event);
        Ok(())
    }

    fn task_readers(&self) -> i32 {
        1
    }
}

/// A station core with its history and outbox.
pub(crate) struct Fixture {
    pub(crate) h: StationHandle,
    pub(crate) out: Arc<RecordingOutbox>,
    pub(crate) history: Option<History>,
    pub(crate) dir: tempfile::TempDir,
}

impl Fixture {
    /// A core on the default configuration (rules file and history in a temporary dir).
    pub(crate) fn new() -> Self {
        Self::with(|_| {})
    }

    /// A core whose configuration `change` adjusts first.
    pub(crate) fn with(change: impl FnOnce(&mut StationConfig)) -> Self {
        let dir = tempfile::tempdir().unwrap();
        Self::in_dir(dir, change)
    }

    /// A core over the history and rules file in `dir` (e.g. to restart one).
    pub(crate) fn in_dir(dir: tempfile::TempDir, change: impl FnOnce(&mut StationConfig)) -> Self {
        Self::in_dir_on(dir, change, Clock::system())
    }

    /// A core on the default configuration whose clock the test drives.
    pub(crate) fn manual_clock() -> (Self, ManualTime) {
        let (clock, time) = Clock::manual(now_ms());
        let dir = tempfile::tempdir().unwrap();
        (Self::in_dir_on(dir, |_| {}, clock), time)
    }

    fn in_dir_on(
        dir: tempfile::TempDir,
        change: impl FnOnce(&mut StationConfig),
        clock: Clock,
    ) -> Self {
        let mut config = StationConfig {
            rules_path: dir.path().join("rules.json"),
            summary_interval_s: 0.0,
            ..StationConfig::default()
        };
        change(&mut config);
        let history = History::open(&HistoryConfig {
            path: dir.path().join("history.db"),
            flush_interval_ms: 0,
            ..HistoryConfig::default()
        })
        .unwrap();
        let out = Arc::new(RecordingOutbox::default());
        let h = StationHandle::with_clock(config, &history, out.clone(), clock).unwrap();
        Self {
            h,
            out,
            history: Some(history),
            dir,
        }
    }

    /// Stops this core (its history committed and closed) and starts another on the same
    /// files, as a restarted station would.
    pub(crate) fn restart(mut self) -> Self {
        self.h.flush_history(Duration::from_secs(10)).unwrap();
        drop(self.h);
        if let Some(history) = self.history.take() {
            history.close().unwrap();
        }
        Self::in_dir(self.dir, |_| {})
    }

    /// Everything submitted so far is committed (for history assertions).
    pub(crate) fn flush(&self) {
        self.h.flush_history(Duration::from_secs(10)).unwrap();
    }

    /// `id` announces itself, able to go to waypoints, survey and hold.
    pub(crate) fn announce(&self, id: &str) {
        self.h
            .ingest_announcement(valid(announcement(id)), "writer-1", "participant-1");
    }

    /// `id` announces itself through `participant`.
    pub(crate) fn announce_via(&self, id: &str, participant: &str) {
        self.h
            .ingest_announcement(valid(announcement(id)), "writer-1", participant);
    }

    /// `id` announces itself and reports one state now: registered and alive.
    pub(crate) fn alive(&self, id: &str) {
        self.announce(id);
        self.h.ingest_state(state(id, now_ms(), 80.0)).unwrap();
        self.h.tick(now_ms());
    }

    /// `vehicle` reports `state` for `task`.
    pub(crate) fn report(&self, task: &str, vehicle: &str, state: TaskState) {
        self.h
            .ingest_task_status(valid(status(task, vehicle, state)))
            .unwrap();
    }
}

/// Validates in a test: the value must be valid.
pub(crate) fn valid<T: shoal_model::Validate + std::fmt::Debug>(value: T) -> Validated<T> {
    Validated::new(value).unwrap()
}

pub(crate) fn announcement(id: &str) -> VehicleAnnouncement {
    VehicleAnnouncement {
        vehicle_id: id.into(),
        name: id.into(),
        kind: VehicleKind::Auv,
        vendor: "test".into(),
        capabilities: vec![
            "goto".into(),
            "survey".into(),
            "hold".into(),
            "surface".into(),
        ],
        sensors: vec![],
        links: vec![LinkKind::Ip],
        max_speed_mps: 2.0,
        timestamp_ms: now_ms(),
    }
}

pub(crate) fn state(id: &str, timestamp_ms: i64, battery_pct: f64) -> StateVector {
    StateVector {
        vehicle_id: id.into(),
        timestamp_ms,
        latitude_deg: 63.44,
        longitude_deg: 10.38,
        depth_m: 10.0,
        altitude_m: -1.0,
        speed_mps: 1.0,
        yaw_deg: 0.0,
        pitch_deg: 0.0,
        roll_deg: 0.0,
        battery_pct,
    }
}

pub(crate) fn status(task: &str, vehicle: &str, state: TaskState) -> TaskStatus {
    TaskStatus {
        task_id: task.into(),
        vehicle_id: vehicle.into(),
        timestamp_ms: now_ms(),
        state,
        progress_pct: if state == TaskState::Done { 100.0 } else { 0.0 },
        message: String::new(),
    }
}

pub(crate) fn goto() -> Task {
    Task::GotoWaypoint {
        target: GeoPoint {
            latitude_deg: 63.45,
            longitude_deg: 10.38,
        },
        depth_m: Some(5.0),
        altitude_m: None,
        speed_mps: 1.5,
    }
}

/// A mission `id` of `tasks`, each a vehicle and its task, ids left to the station.
pub(crate) fn spec(id: &str, tasks: &[(&str, Task)]) -> crate::missions::MissionSpec {
    crate::missions::MissionSpec {
        mission_id: id.into(),
        name: format!("mission {id}"),
        tasks: tasks
            .iter()
            .map(|(v, t)| crate::missions::MissionTaskSpec {
                task_id: None,
                vehicle_id: (*v).into(),
                task: t.clone(),
            })
            .collect(),
    }
}

pub(crate) fn assignment(task: &str, vehicle: &str) -> TaskAssignment {
    TaskAssignment::new(task, "", vehicle, now_ms(), &goto())
}
