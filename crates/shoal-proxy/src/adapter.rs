//! What a DDS Proxy needs from a vehicle: the [`VehicleAdapter`] trait and the data that
//! crosses it.
//!
//! An adapter translates one vehicle's native interface (the simulator, a MAVLink socket,
//! an IMC/DUNE link, a ROS 2 graph) into Shoal's terms; [`crate::run_proxy`] does all the
//! DDS work once for every adapter. The split is:
//!
//! | the adapter | the proxy ([`crate::run_proxy`]) |
//! | --- | --- |
//! | identity and abilities ([`VehicleAdapter::announcement`]) | announcing, and re-announcing periodically |
//! | the latest fused navigation state ([`VehicleAdapter::state`]) | publishing it at the reporting rate; `request_state` and `set_reporting_rate` tasks |
//! | accepting or refusing a task, executing it ([`VehicleAdapter::submit`]) | filtering tasks by vehicle, dropping duplicates and stale replays, `accepted` / `failed: refused` statuses |
//! | progress, events and observations ([`VehicleAdapter::next_output`]) | vehicle ids, event ids, timestamps of statuses, priorities, publishing |

use std::future::Future;

use shoal_model::{
    EnvironmentObservation, EventKind, Severity, StateVector, Task, TaskKind, TaskState,
    VehicleAnnouncement,
};

/// A vehicle behind a DDS Proxy: implemented once per vehicle interface (simulator,
/// MAVLink, IMC, ROS 2).
///
/// The proxy owns the adapter and calls it from one task, so methods take `&mut self` and
/// need no locking. An adapter with its own I/O (a socket to the vehicle) either does that
/// I/O inside [`next_output`](Self::next_output) or runs its own event loop and hands
/// results over through channels; both fit, because the proxy only ever awaits
/// `next_output` and `submit`.
pub trait VehicleAdapter: Send {
    /// Why the adapter stopped working for good (a lost vehicle connection that cannot be
    /// re-established); [`std::convert::Infallible`] for adapters that cannot fail.
    type Error: std::error::Error + Send + Sync + 'static;

    /// Who the vehicle is and what it can do. Called on joining and for every
    /// re-announcement; the proxy stamps the time, so the adapter need not.
    fn announcement(&self) -> VehicleAnnouncement;

    /// The vehicle's latest navigation state, or `None` before its first fix.
    ///
    /// Called at the reporting rate and when a `request_state` task arrives, so it must be
    /// cheap: return the last fused state, never wait for the vehicle.
    fn state(&mut self) -> Option<StateVector>;

    /// Waits for the next thing the vehicle reports: task progress, an event or an
    /// environment observation.
    ///
    /// Must be cancel-safe: the proxy drops this future whenever a task, a timer or
    /// shutdown comes first, and calls it again later; nothing may be lost when it is
    /// dropped. An `Err` ends the proxy.
    fn next_output(&mut self) -> impl Future<Output = Result<VehicleOutput, Self::Error>> + Send;

    /// Offers the vehicle a task; it answers at once whether it takes it.
    ///
    /// `Ok` means the vehicle took the task (to run now or after the tasks it already has);
    /// the proxy then reports `accepted`, and everything after that (`running` with
    /// progress, `done`, `failed`, `aborted`) comes from the adapter through
    /// [`next_output`](Self::next_output) as [`TaskUpdate`]s. `Err` is a refusal; the proxy
    /// reports it as `failed` with the message `refused: <reason>`.
    ///
    /// `request_state` and `set_reporting_rate` never reach the adapter: the proxy serves
    /// them itself.
    fn submit(
        &mut self,
        order: TaskOrder,
    ) -> impl Future<Output = Result<Acceptance, Refusal>> + Send;
}

/// A task as offered to a vehicle: the typed task plus the identifiers it is reported under.
#[derive(Debug, Clone, PartialEq)]
pub struct TaskOrder {
    /// Task identifier; every [`TaskUpdate`] about the task carries it.
    pub task_id: String,
    /// Mission the task belongs to, or empty.
    pub mission_id: String,
    /// When the station issued it, ms since the Unix epoch: the order in which queued tasks run.
    pub issued_ms: i64,
    /// What to do.
    pub task: Task,
}

/// A vehicle took a task.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Acceptance {
    /// Note for the operator sent with `accepted` (e.g. "queued behind 2 tasks"), or empty.
    pub message: String,
}

impl Acceptance {
    /// An acceptance with a note for the operator.
    pub fn with_message(message: impl Into<String>) -> Self {
        Self {
            message: message.into(),
        }
    }
}

/// Why a vehicle will not take a task (e.g. "needs 34 % of battery, 22 % left above the
/// 10 % reserve").
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{reason}")]
pub struct Refusal {
    /// The reason, for the operator.
    pub reason: String,
}

impl Refusal {
    /// A refusal with its reason.
    pub fn new(reason: impl Into<String>) -> Self {
        Self {
            reason: reason.into(),
        }
    }
}

/// Something a vehicle reports through [`VehicleAdapter::next_output`].
#[derive(Debug, Clone, PartialEq)]
pub enum VehicleOutput {
    /// A task changed state or made progress.
    Task(TaskUpdate),
    /// An alarm, detection or other event.
    Event(VehicleEvent),
    /// One measured environment property; the proxy sets its `vehicle_id`.
    Observation(EnvironmentObservation),
}

/// A task's new state, as the vehicle reports it; the proxy adds vehicle id and time.
#[derive(Debug, Clone, PartialEq)]
pub struct TaskUpdate {
    /// Task reported on.
    pub task_id: String,
    /// New state (`running`, `done`, `failed`, `aborted`).
    pub state: TaskState,
    /// Progress in percent, [0, 100].
    pub progress_pct: f64,
    /// Text for the operator, e.g. why it failed.
    pub message: String,
}

impl TaskUpdate {
    /// An update from its parts.
    pub fn new(task_id: &str, state: TaskState, progress_pct: f64, message: &str) -> Self {
        Self {
            task_id: task_id.to_string(),
            state,
            progress_pct,
            message: message.to_string(),
        }
    }
}

/// An event as the vehicle reports it; the proxy gives it a unique id and the vehicle id.
#[derive(Debug, Clone, PartialEq)]
pub struct VehicleEvent {
    /// When it happened, ms since the Unix epoch.
    pub timestamp_ms: i64,
    /// How urgent; `alarm` and `critical` go out on the emergency priority class.
    pub severity: Severity,
    /// What about.
    pub kind: EventKind,
    /// Task concerned, or empty.
    pub task_id: String,
    /// Text for the operator.
    pub text: String,
}

/// The capability code a vehicle announces for a kind of task, as listed in
/// `VehicleAnnouncement::capabilities` and the acoustic announcement table.
pub fn capability_of(kind: TaskKind) -> &'static str {
    kind.capability()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_task_kind_has_a_distinct_capability_code() {
        let kinds = TaskKind::ALL;
        let codes: std::collections::HashSet<_> = kinds.iter().map(|k| capability_of(*k)).collect();
        assert_eq!(codes.len(), kinds.len());
    }

    #[test]
    fn a_refusal_displays_its_reason() {
        assert_eq!(Refusal::new("no battery").to_string(), "no battery");
    }
}

/// Commands an adapter queues for its link task; a vehicle that stops reading its link
/// cannot make the proxy hold more than this.
pub(crate) const COMMAND_QUEUE: usize = 16;

/// The refusal for a command the link's queue would not take.
pub(crate) fn queue_refusal<T>(
    link: &str,
    e: &tokio::sync::mpsc::error::TrySendError<T>,
) -> Refusal {
    match e {
        tokio::sync::mpsc::error::TrySendError::Full(_) => Refusal::new(format!(
            "the {link} link is not keeping up: {COMMAND_QUEUE} commands already queued"
        )),
        tokio::sync::mpsc::error::TrySendError::Closed(_) => {
            Refusal::new(format!("the {link} link has stopped"))
        }
    }
}

#[cfg(test)]
mod queue_tests {
    use super::*;

    #[test]
    fn a_full_command_queue_refuses_with_a_reason_and_a_closed_one_says_stopped() {
        let (tx, rx) = tokio::sync::mpsc::channel::<u8>(COMMAND_QUEUE);
        for _ in 0..COMMAND_QUEUE {
            tx.try_send(0).unwrap();
        }
        let full = tx.try_send(0).unwrap_err();
        assert!(
            queue_refusal("MAVLink", &full)
                .to_string()
                .contains("not keeping up: 16 commands already queued")
        );
        drop(rx);
        let closed = tx.try_send(0).unwrap_err();
        assert!(
            queue_refusal("IMC", &closed)
                .to_string()
                .contains("the IMC link has stopped")
        );
    }
}
