//! Errors of the station core.

use shoal_model::ValidationError;

/// The station could not start or stop cleanly.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum StationError {
    /// A configuration value is wrong; the message names the key.
    #[error("{0}")]
    Config(String),
    /// DDS endpoints could not be created.
    #[error(transparent)]
    Dds(#[from] shoal_dds::CreateError),
    /// The history store failed.
    #[error("history store: {0}")]
    History(#[source] shoal_history::HistoryError),
    /// The semantic model could not be built.
    #[error("semantic model: {0}")]
    Semantic(String),
    /// Shutdown did not complete.
    #[error("shutdown: {0}")]
    Shutdown(String),
}

/// A task or mission could not be registered or dispatched.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DispatchError {
    /// The task is malformed; the error names the field.
    #[error("invalid task: {0}")]
    Invalid(#[source] ValidationError),
    /// A field of the request breaks its rule.
    #[error("{field}: {rule}")]
    BadField {
        /// The field.
        field: &'static str,
        /// Its rule.
        rule: &'static str,
    },
    /// No vehicle with that id is registered.
    #[error("unknown vehicle {0:?}")]
    UnknownVehicle(String),
    /// The vehicle is not heard from.
    #[error("vehicle {0} is lost: no contact")]
    VehicleLost(String),
    /// The vehicle did not announce the capability the task needs.
    #[error("vehicle {vehicle} cannot do it: no {capability:?} capability")]
    Incapable {
        /// The vehicle.
        vehicle: String,
        /// The capability code it lacks.
        capability: &'static str,
    },
    /// The vehicle's battery is below the dispatch minimum.
    #[error(
        "vehicle {vehicle} has {battery_pct:.1} % battery, below the {min_pct:.0} % needed to start a task"
    )]
    LowBattery {
        /// The vehicle.
        vehicle: String,
        /// Its latest level.
        battery_pct: f64,
        /// The minimum (`station.min_dispatch_battery_pct`).
        min_pct: f64,
    },
    /// A task with this id exists already.
    #[error("task_id {0:?} is already in use")]
    DuplicateTask(String),
    /// A mission with this id exists already.
    #[error("mission_id {0:?} is already in use")]
    DuplicateMission(String),
    /// No mission with this id.
    #[error("unknown mission {0:?}")]
    UnknownMission(String),
    /// One task of a mission is refused.
    #[error("tasks[{index}]: {error}")]
    InMission {
        /// Index of the task in the request.
        index: usize,
        /// Why.
        error: Box<DispatchError>,
    },
    /// DDS refused the write.
    #[error("could not publish the task: {0}")]
    Dds(String),
}

/// A rule could not be created, switched or deleted.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RuleChangeError {
    /// The semantic store refused the change; the message says why.
    #[error(transparent)]
    Rule(#[from] shoal_semantic::RuleError),
    /// The change is in force but could not be saved for the next start.
    #[error("the rule change is in force but was not saved: {0}")]
    Save(#[from] crate::rules::RulesFileError),
}
