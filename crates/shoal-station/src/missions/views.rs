//! What the Mission & Task Register shows and takes: tasks and missions as the API lists
//! them, and missions as operators write them.

use serde::{Deserialize, Serialize};
use shoal_model::{LinkKind, Task, TaskAssignment, TaskState, TaskStatus};

/// A task as the register tracks it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TaskView {
    /// What was asked.
    pub assignment: TaskAssignment,
    /// Where it is in its state machine.
    pub state: TaskState,
    /// Progress reported by the vehicle, %.
    pub progress_pct: f64,
    /// The latest message (why it failed, which link carried it ...).
    pub message: String,
    /// When the state last changed or progress was reported, ms since the Unix epoch.
    pub updated_ms: i64,
    /// When the station first handed it to a link (`sent`), ms since the Unix epoch.
    pub dispatched_ms: Option<i64>,
    /// When the vehicle first reported it accepted or running, ms since the Unix epoch.
    pub started_ms: Option<i64>,
    /// When it reached a final state (done, failed, aborted, expired), ms since the Unix epoch.
    pub ended_ms: Option<i64>,
    /// The link the station chose when it dispatched the task.
    pub link: Option<LinkKind>,
    /// The latest report from the vehicle, if any.
    pub status: Option<TaskStatus>,
    /// Times the station sent it again after the acoustic link gave up on it.
    pub retries: u32,
    /// The site it was sent through, for another site's vehicle commanded under this
    /// station's lease (its state then comes from that site's task transitions).
    pub via_site: Option<String>,
}

/// Where a mission is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MissionState {
    /// Registered, not started.
    Planned,
    /// Started; some task is not final yet.
    Running,
    /// Every task done.
    Done,
    /// Every task final, some not done.
    Failed,
    /// Aborted by an operator.
    Aborted,
}

/// One task of a mission as an operator writes it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MissionTaskSpec {
    /// Task id; `<mission_id>-<n>` when absent.
    #[serde(default)]
    pub task_id: Option<String>,
    /// Vehicle that executes it.
    pub vehicle_id: String,
    /// What to do.
    pub task: Task,
}

/// A mission as an operator writes it: tasks per vehicle, run in the order listed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MissionSpec {
    /// Mission id: 1..=64 of `[A-Za-z0-9_.-]`.
    pub mission_id: String,
    /// Name shown to operators.
    #[serde(default)]
    pub name: String,
    /// The tasks, in order per vehicle.
    pub tasks: Vec<MissionTaskSpec>,
}

/// A mission as the register tracks it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MissionView {
    /// Mission id.
    pub mission_id: String,
    /// Name shown to operators.
    pub name: String,
    /// Where it is.
    pub state: MissionState,
    /// When it was registered, started and ended, ms since the Unix epoch.
    pub created_ms: i64,
    /// When it was started.
    pub started_ms: Option<i64>,
    /// When its last task reached a final state.
    pub ended_ms: Option<i64>,
    /// Done tasks plus the running tasks' progress, over all tasks, %.
    pub progress_pct: f64,
    /// Its tasks, in order.
    pub tasks: Vec<TaskView>,
}
