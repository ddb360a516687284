//! What the writer stores: one [`Record`] per datum, and the rows read back.

use shoal_model::{
    EnvironmentObservation, Event, StateVector, TaskAssignment, TaskStatus, VehicleAnnouncement,
};

/// One datum to store; each variant goes to its own table.
#[derive(Debug, Clone, PartialEq)]
pub enum Record {
    /// A state vector, table `state_vector` (upsert on vehicle and time).
    State(StateVector),
    /// A vehicle announcement, table `vehicle` (one row per vehicle, newest fields win).
    Vehicle(VehicleAnnouncement),
    /// A task assignment, table `task_assignment` (upsert on task id).
    Task(TaskAssignment),
    /// A task status report, table `task_status` (upsert on task, time and state).
    TaskStatus(TaskStatus),
    /// An event, table `event` (upsert on event id).
    Event(Event),
    /// An environment observation, table `observation` (upsert on vehicle, property, time).
    Observation(EnvironmentObservation),
    /// Data the station rejected, kept for inspection in table `rejected`.
    Rejected {
        /// When the station received it, ms since the Unix epoch.
        received_ms: i64,
        /// Topic (or source) it came from.
        topic: String,
        /// Why it was rejected (e.g. a validation reason code).
        reason: String,
        /// The datum as JSON, as far as it could be decoded.
        payload_json: String,
    },
}

impl Record {
    /// A [`Record::Rejected`] received now.
    pub fn rejected(
        topic: impl Into<String>,
        reason: impl Into<String>,
        payload_json: impl Into<String>,
    ) -> Self {
        Self::Rejected {
            received_ms: shoal_model::now_ms(),
            topic: topic.into(),
            reason: reason.into(),
            payload_json: payload_json.into(),
        }
    }

    /// The table this record goes to; also the `topic` of its quarantine row.
    pub fn table(&self) -> &'static str {
        match self {
            Self::State(_) => "state_vector",
            Self::Vehicle(_) => "vehicle",
            Self::Task(_) => "task_assignment",
            Self::TaskStatus(_) => "task_status",
            Self::Event(_) => "event",
            Self::Observation(_) => "observation",
            Self::Rejected { .. } => "rejected",
        }
    }

    /// The datum as JSON, for the quarantine table.
    pub(crate) fn payload_json(&self) -> Result<String, serde_json::Error> {
        match self {
            Self::State(v) => serde_json::to_string(v),
            Self::Vehicle(v) => serde_json::to_string(v),
            Self::Task(v) => serde_json::to_string(v),
            Self::TaskStatus(v) => serde_json::to_string(v),
            Self::Event(v) => serde_json::to_string(v),
            Self::Observation(v) => serde_json::to_string(v),
            Self::Rejected { payload_json, .. } => Ok(payload_json.clone()),
        }
    }
}

impl From<StateVector> for Record {
    fn from(v: StateVector) -> Self {
        Self::State(v)
    }
}

impl From<VehicleAnnouncement> for Record {
    fn from(v: VehicleAnnouncement) -> Self {
        Self::Vehicle(v)
    }
}

impl From<TaskAssignment> for Record {
    fn from(v: TaskAssignment) -> Self {
        Self::Task(v)
    }
}

impl From<TaskStatus> for Record {
    fn from(v: TaskStatus) -> Self {
        Self::TaskStatus(v)
    }
}

impl From<Event> for Record {
    fn from(v: Event) -> Self {
        Self::Event(v)
    }
}

impl From<EnvironmentObservation> for Record {
    fn from(v: EnvironmentObservation) -> Self {
        Self::Observation(v)
    }
}

/// A row of the `rejected` (quarantine) table.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct RejectedRecord {
    /// Row id, increasing in insertion order.
    pub id: i64,
    /// When the datum was received (or quarantined by the store), ms since the Unix epoch.
    pub received_ms: i64,
    /// Topic it came from, or the table it failed to go into.
    pub topic: String,
    /// Why it was rejected; for rows the store itself quarantined, the SQLite error.
    pub reason: String,
    /// The datum as JSON.
    pub payload_json: String,
}

/// Everything stored about one task.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct TaskHistory {
    /// The assignment, if it was stored.
    pub assignment: Option<TaskAssignment>,
    /// Status reports, oldest first.
    pub statuses: Vec<TaskStatus>,
}
