//! Shoal's history store: the station's relational database, embedded SQLite or a
//! PostgreSQL server.
//!
//! Everything the station accepts (and everything it rejects) is written here for later
//! inspection, replay and warm-up after a restart. This is the data path with the strongest
//! guarantee: **no acknowledged data is lost**, where "acknowledged" means "committed".
//!
//! - [`History`] owns the store: [`History::open`] creates the database (SQLite in WAL mode,
//!   or a PostgreSQL schema; versioned either way) and starts one dedicated writer thread;
//!   [`History::close`] (or dropping it) drains the queue, commits and joins the thread.
//! - [`HistoryWriter`] (from [`History::writer`]) submits [`Record`]s into a bounded queue
//!   without blocking and returns a sequence number; a full queue hands the record back in
//!   [`SubmitError::Full`]. [`HistoryWriter::committed`], [`HistoryWriter::wait_committed`],
//!   [`HistoryWriter::subscribe_committed`] (a `tokio::sync::watch`, for async callers) and
//!   [`HistoryWriter::flush`] tell when records are durably committed.
//! - The writer commits batches of up to `batch_max` records in one transaction. A batch the
//!   database refuses because of one bad record is retried row by row, and the bad rows go
//!   to the `rejected` quarantine table with the database's reason; a batch that fails for
//!   environment reasons (disk full, I/O) is kept and retried, never dropped.
//! - [`HistoryReader`] (from [`History::reader`]) answers queries on a separate
//!   connection: tracks, latest states, vehicles, events, task histories, observations and
//!   quarantined records.
//! - Retention ([`RetentionConfig`], `[history.retention]`) keeps the database bounded: the
//!   writer thread runs a maintenance pass every interval that thins old state vectors,
//!   drops data past a maximum age and enforces a row cap, in bounded statements with ingest
//!   committed between them; [`History::maintenance_stats`] reports what it did.
//! - [`HistoryConfig`] holds the settings, among them the [`Backend`]; [`raw_insert_baseline`]
//!   is the plain-SQLite reference the ingest benchmark compares against.
//!
//! Both backends have the same tables, keys, upsert rules, quarantine and queries, and run
//! the same tests. With PostgreSQL (`backend = "postgres"`, see `docs/postgres.md`) a batch
//! goes to each table in one `INSERT ... SELECT FROM unnest(...)`; SQLSTATE classes 22 and
//! 23 blame the data (quarantine), anything else the environment (keep, reconnect, retry).
//!
//! The crate is synchronous and its callers need no async runtime: PostgreSQL connections
//! are driven by private single-threaded runtimes on the store's own threads, so the store
//! may also be used from inside a caller's runtime.

#![forbid(unsafe_code)]

mod backend;
mod baseline;
mod config;
mod error;
mod history;
mod pg;
mod query;
mod record;
mod retention;
mod schema;
mod store;
#[cfg(test)]
mod testing;
mod writer;

pub use baseline::{RawOrder, raw_insert_baseline};
pub use config::{
    Backend, DEFAULT_POSTGRES_SCHEMA, DEFAULT_POSTGRES_URL, HistoryConfig, RetentionConfig,
    Synchronous,
};
pub use error::{HistoryError, SubmitError, WaitError};
pub use history::History;
pub use query::HistoryReader;
pub use record::{Record, RejectedRecord, TaskHistory};
pub use retention::MaintenanceStats;
pub use writer::{HistoryStats, HistoryWriter};

/// The schema version this build reads and writes (SQLite's `PRAGMA user_version`,
/// PostgreSQL's `shoal_schema_version` table).
pub const SCHEMA_VERSION: i64 = schema::SCHEMA_VERSION;
