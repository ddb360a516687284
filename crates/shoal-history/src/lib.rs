//! Shoal's history store: the station's relational database, embedded SQLite.
//!
//! Everything the station accepts (and everything it rejects) is written here for later
//! inspection, replay and warm-up after a restart. This is the data path with the strongest
//! guarantee: **no acknowledged data is lost**, where "acknowledged" means "committed".
//!
//! - [`History`] owns the store: [`History::open`] creates the database (WAL mode, versioned
//!   schema) and starts one dedicated writer thread; [`History::close`] (or dropping it)
//!   drains the queue, commits and joins the thread.
//! - [`HistoryWriter`] (from [`History::writer`]) submits [`Record`]s into a bounded queue
//!   without blocking and returns a sequence number; a full queue hands the record back in
//!   [`SubmitError::Full`]. [`HistoryWriter::committed`], [`HistoryWriter::wait_committed`],
//!   [`HistoryWriter::subscribe_committed`] (a `tokio::sync::watch`, for async callers) and
//!   [`HistoryWriter::flush`] tell when records are durably committed.
//! - The writer commits batches of up to `batch_max` records in one transaction. A batch the
//!   database refuses because of one bad record is retried row by row, and the bad rows go
//!   to the `rejected` quarantine table with SQLite's reason; a batch that fails for
//!   environment reasons (disk full, I/O) is kept and retried, never dropped.
//! - [`HistoryReader`] (from [`History::reader`]) answers queries on a separate read-only
//!   connection: tracks, latest states, vehicles, events, task histories, observations and
//!   quarantined records.
//! - [`HistoryConfig`] holds the settings; [`raw_insert_baseline`] is the plain-SQLite
//!   reference the ingest benchmark compares against.
//!
//! The crate is synchronous and needs no async runtime; only `tokio::sync::watch` is used.

mod baseline;
mod config;
mod error;
mod history;
mod query;
mod record;
mod schema;
mod store;
mod writer;

pub use baseline::raw_insert_baseline;
pub use config::{HistoryConfig, Synchronous};
pub use error::{HistoryError, SubmitError, WaitError};
pub use history::History;
pub use query::HistoryReader;
pub use record::{Record, RejectedRecord, TaskHistory};
pub use writer::{HistoryStats, HistoryWriter};

/// The schema version (`PRAGMA user_version`) this build reads and writes.
pub const SCHEMA_VERSION: i64 = schema::SCHEMA_VERSION;
