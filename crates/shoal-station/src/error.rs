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

/// A task could not be dispatched.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DispatchError {
    /// The task is malformed.
    #[error("invalid task: {0}")]
    Invalid(#[source] ValidationError),
    /// No vehicle with that id is registered.
    #[error("unknown vehicle {0:?}")]
    UnknownVehicle(String),
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
