//! Error types, split by operation: opening and querying, submitting, waiting.

use std::path::PathBuf;

use crate::Record;

/// Why the store could not be opened, closed or queried.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum HistoryError {
    /// A configuration value makes no sense.
    #[error("invalid history configuration: {0}")]
    Config(String),
    /// The database's directory could not be created.
    #[error("cannot create the directory {path}: {source}")]
    CreateDir {
        /// The directory.
        path: PathBuf,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
    /// SQLite reported an error (opening, schema, query, or decoding a stored row).
    #[error("history database error: {0}")]
    Sqlite(#[from] rusqlite::Error),
    /// PostgreSQL (or the connection to it) reported an error.
    #[error("history database error (PostgreSQL): {}", pg_text(.0))]
    Postgres(#[from] tokio_postgres::Error),
    /// A stored JSON or enum-name column holds text this build cannot decode.
    #[error("cannot decode stored column {column}: {source}")]
    Decode {
        /// Zero-based column index in the query.
        column: usize,
        /// The decoding error.
        #[source]
        source: serde_json::Error,
    },
    /// The private runtime that drives the PostgreSQL connections could not be built.
    #[error("cannot start the PostgreSQL client runtime: {0}")]
    Runtime(#[source] std::io::Error),
    /// The thread that runs PostgreSQL queries for the reader is gone (a bug).
    #[error("the history query thread stopped")]
    ReaderStopped,
    /// The database was written by a newer Shoal with a schema this build does not know.
    #[error("the history database has schema version {found}; this build knows up to {supported}")]
    SchemaTooNew {
        /// `PRAGMA user_version` found in the file (SQLite) or the version in
        /// `shoal_schema_version` (PostgreSQL).
        found: i64,
        /// The newest version this build can use.
        supported: i64,
    },
    /// The writer thread could not be started.
    #[error("cannot start the history writer thread: {0}")]
    Spawn(#[source] std::io::Error),
    /// The writer thread panicked (a bug); records still queued were not stored.
    #[error("the history writer thread panicked")]
    WriterPanicked,
    /// The store closed with records it could not write (the database kept failing);
    /// they were never acknowledged.
    #[error("the history store closed with {records} records it could not store")]
    Unstored {
        /// How many records were given up.
        records: u64,
    },
}

/// A PostgreSQL error with what the server said: `tokio_postgres::Error`'s own `Display` is
/// only the kind ("db error"), which would leave logs and quarantine reasons without the
/// actual message, constraint and SQLSTATE.
pub(crate) fn pg_text(e: &tokio_postgres::Error) -> String {
    if let Some(db) = e.as_db_error() {
        return format!("{db} (SQLSTATE {})", db.code().code());
    }
    let mut text = e.to_string();
    let mut source = std::error::Error::source(e);
    while let Some(s) = source {
        text.push_str(": ");
        text.push_str(&s.to_string());
        source = s.source();
    }
    text
}

/// Why a record was not queued; the record is handed back so the caller can retry,
/// buffer or quarantine it instead of losing it. (Boxed so that `Result<u64, SubmitError>`
/// stays small on the common, successful path.)
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SubmitError {
    /// The queue holds `queue_capacity` records; try again later or use `submit_blocking`.
    #[error("the history queue is full; the record was handed back")]
    Full(Box<Record>),
    /// The store is closing or closed.
    #[error("the history store is closed; the record was handed back")]
    Closed(Box<Record>),
}

impl SubmitError {
    /// The record that was not queued.
    pub fn into_record(self) -> Record {
        match self {
            Self::Full(r) | Self::Closed(r) => *r,
        }
    }
}

/// Why waiting for a commit acknowledgement ended without it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum WaitError {
    /// The timeout elapsed first; the record may still be committed later.
    #[error(
        "timed out waiting for record {target} to be committed (committed so far: {committed})"
    )]
    Timeout {
        /// Sequence number waited for.
        target: u64,
        /// Highest committed sequence number when the wait ended.
        committed: u64,
    },
    /// The writer stopped (store closed with records it could not store); they never will be.
    #[error(
        "the history writer stopped before record {target} was committed (committed: {committed})"
    )]
    Stopped {
        /// Sequence number waited for.
        target: u64,
        /// Highest committed sequence number.
        committed: u64,
    },
}
