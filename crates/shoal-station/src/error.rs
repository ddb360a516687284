//! Errors of the station core.

use shoal_model::ValidationError;

/// A configuration value is wrong; the message names the key and its rule.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{message}")]
pub struct ConfigError {
    /// The key under `[station]`, e.g. `plausibility.max_age_s`.
    pub key: String,
    message: String,
}

impl ConfigError {
    /// An error about `key`; `message` says what the key must be.
    pub fn new(key: impl Into<String>, message: impl Into<String>) -> Self {
        Self {
            key: key.into(),
            message: message.into(),
        }
    }
}

/// The station could not start or stop cleanly.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum StationError {
    /// A configuration value is wrong; the message names the key.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The rules file could not be applied; the message names the file and the rule.
    #[error(transparent)]
    RulesFile(#[from] crate::rules::RulesFileError),
    /// DDS endpoints could not be created.
    #[error(transparent)]
    Dds(#[from] shoal_dds::CreateError),
    /// The history store failed.
    #[error("history store: {0}")]
    History(#[source] shoal_history::HistoryError),
    /// The semantic model could not be built.
    #[error("semantic model: {0}")]
    Semantic(#[source] shoal_semantic::StoreError),
    /// Shutdown did not complete.
    #[error("shutdown: {0}")]
    Shutdown(#[source] tokio::task::JoinError),
}

/// Why the Data Access Manager refused a datum; counted and reported under [`Self::reason`].
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum Rejection {
    /// A type or range check failed (only for data that did not come through the bus,
    /// which validates on receipt).
    #[error("invalid: {0}")]
    Invalid(#[source] ValidationError),
    /// Plausible neither against the vehicle's history nor the station's clock.
    #[error("implausible: {0}")]
    Implausible(crate::ingest::preprocess::Implausible),
    /// The vehicle never announced itself (`station.require_announcement`).
    #[error("{0} never announced itself")]
    UnknownVehicle(String),
    /// A task status for a task this station never gave that vehicle.
    #[error("task {task_id} was never given to {vehicle_id}")]
    UnknownTask {
        /// The task it names.
        task_id: String,
        /// The vehicle that reported it.
        vehicle_id: String,
    },
    /// A new vehicle announced itself while too many known vehicles have sent nothing
    /// but an announcement (`station.max_unheard_vehicles`).
    #[error("{max} vehicles have announced themselves and sent no state yet; a new one is refused")]
    TooManyUnheard {
        /// The limit.
        max: usize,
    },
}

impl Rejection {
    /// The stable reason code the counters and the quarantine use, e.g.
    /// `out_of_range:latitude_deg`, `implausible:position_jump`, `unknown_vehicle`.
    pub fn reason(&self) -> String {
        match self {
            Self::Invalid(e) => e.reason().to_string(),
            Self::Implausible(why) => why.reason().to_owned(),
            Self::UnknownVehicle(_) => "unknown_vehicle".to_owned(),
            Self::UnknownTask { .. } => "unknown_task".to_owned(),
            Self::TooManyUnheard { .. } => "too_many_unheard_vehicles".to_owned(),
        }
    }
}

/// An environment subscription request breaks a rule; the message names the field.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum SubscriptionError {
    /// `max_rate_hz` is out of range.
    #[error("max_rate_hz must be within (0, 100]")]
    Rate,
    /// The area has fewer than three corners.
    #[error("area: a polygon needs at least 3 points")]
    AreaTooSmall,
    /// A corner of the area is out of range.
    #[error("area: {0}")]
    AreaPoint(#[source] ValidationError),
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
    /// Another site commands the vehicle, or the command lease is not settled yet.
    #[error(transparent)]
    Lease(#[from] crate::federation::LeaseDenial),
    /// A task for another site's vehicle could not be sent to that site.
    #[error(transparent)]
    Relay(#[from] crate::federation::RelayRefused),
    /// A mission with this id exists already.
    #[error("mission_id {0:?} is already in use")]
    DuplicateMission(String),
    /// No mission with this id.
    #[error("unknown mission {0:?}")]
    UnknownMission(String),
    /// No task with this id.
    #[error("unknown task {0:?}")]
    UnknownTask(String),
    /// One task of a mission is refused.
    #[error("tasks[{index}]: {error}")]
    InMission {
        /// Index of the task in the request.
        index: usize,
        /// Why.
        error: Box<DispatchError>,
    },
    /// The bus refused the write.
    #[error("could not publish the task: {0}")]
    Publish(#[source] crate::bus::PublishError),
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
