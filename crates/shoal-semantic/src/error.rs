//! Errors, split by operation as the failures differ.

use shoal_model::ValidationError;

/// Why the store rejected a datum or failed to update the model.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum StoreError {
    /// The datum failed validation; nothing was changed.
    #[error("invalid {what}: {source}")]
    Invalid {
        /// Which kind of datum (`state vector`, `task assignment`, ...).
        what: &'static str,
        /// The first violated rule.
        #[source]
        source: ValidationError,
    },
    /// A task status refers to a task the store does not know.
    #[error("unknown task {task_id}")]
    UnknownTask {
        /// The task identifier received.
        task_id: String,
    },
    /// A task status comes from another vehicle than the one the task is assigned to.
    #[error("task {task_id} is assigned to {assigned}, not {reporter}")]
    WrongVehicle {
        /// The task.
        task_id: String,
        /// Vehicle the task is assigned to.
        assigned: String,
        /// Vehicle that reported.
        reporter: String,
    },
    /// The configuration is unusable; nothing was built.
    #[error("semantic store configuration: {0}")]
    Config(#[from] crate::config::ConfigError),
    /// A compiled-in ontology file failed to parse (a build defect, caught by the tests).
    #[error("ontology file {file} does not parse: {message}")]
    Ontology {
        /// File name under `ontology/`.
        file: String,
        /// The parser's message.
        message: String,
    },
    /// A built-in rule cannot be set up from the configuration (e.g. a bad operating area).
    #[error("rule {rule_id}: {message}")]
    BuiltinRule {
        /// The rule.
        rule_id: String,
        /// What is wrong.
        message: String,
    },
    /// Writing an export failed.
    #[error("export: {0}")]
    Export(#[from] std::io::Error),
}

impl StoreError {
    pub(crate) fn invalid(what: &'static str) -> impl FnOnce(ValidationError) -> Self {
        move |source| Self::Invalid { what, source }
    }
}

/// Why a query was refused or failed; every variant is the client's or the limits' doing
/// except [`QueryError::Evaluation`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum QueryError {
    /// The query text is longer than [`crate::QueryLimits::max_len`].
    #[error("query is {len} bytes long, the limit is {max}")]
    TooLong {
        /// Length of the query in bytes.
        len: usize,
        /// The limit.
        max: usize,
    },
    /// The text is not a SPARQL 1.1 query; carries the parser's message.
    #[error("SPARQL syntax error: {0}")]
    Syntax(String),
    /// The text is a SPARQL UPDATE: data changes only through the services.
    #[error("SPARQL UPDATE is not allowed: the model is read-only here")]
    UpdateNotAllowed,
    /// The query ran longer than [`crate::QueryLimits::timeout`].
    #[error("query timed out after {0:?}")]
    Timeout(std::time::Duration),
    /// Evaluation failed for another reason.
    #[error("query evaluation failed: {0}")]
    Evaluation(String),
    /// Serialising the results failed.
    #[error("cannot serialise results: {0}")]
    Serialize(String),
}

/// Why a rule could not be created or changed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum RuleError {
    /// The rule identifier is empty, too long or has characters outside `[A-Za-z0-9_.-]`.
    #[error("bad rule id {0:?}: 1..=32 of [A-Za-z0-9_.-]")]
    BadId(String),
    /// A rule with this identifier exists already.
    #[error("rule {0} exists already")]
    Exists(String),
    /// No rule has this identifier.
    #[error("no rule {0}")]
    NotFound(String),
    /// Built-in rules may be disabled but not deleted or replaced.
    #[error("rule {0} is built in: disable it instead")]
    BuiltIn(String),
    /// The rule's condition does not parse; carries the parser's message.
    #[error("rule does not parse: {0}")]
    Parse(String),
    /// The condition parses but cannot be used as a rule (e.g. a CONSTRUCT query).
    #[error("invalid rule: {0}")]
    Invalid(String),
}
