//! Configuration of the history store.

use std::path::PathBuf;
use std::time::Duration;

use serde::{Deserialize, Serialize};

use crate::HistoryError;

/// Settings of the history store; every field has a default, unknown fields are errors.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HistoryConfig {
    /// Database file; its parent directory is created. `:memory:` keeps everything in RAM
    /// (for tests: nothing survives `close`).
    pub path: PathBuf,
    /// Most records committed in one transaction.
    pub batch_max: usize,
    /// Longest a record waits in the queue for its batch to fill up before the batch is
    /// committed anyway, in ms; 0 commits whatever is queued at once.
    pub flush_interval_ms: u64,
    /// Most records queued for the writer; beyond it `submit` hands records back.
    pub queue_capacity: usize,
    /// How hard SQLite syncs to disk at each commit.
    pub synchronous: Synchronous,
}

impl Default for HistoryConfig {
    fn default() -> Self {
        Self {
            path: PathBuf::from("shoal-data/history.db"),
            batch_max: 2000,
            flush_interval_ms: 20,
            queue_capacity: 200_000,
            synchronous: Synchronous::Normal,
        }
    }
}

impl HistoryConfig {
    /// A configuration for an in-memory store, otherwise the defaults (for tests).
    pub fn in_memory() -> Self {
        Self {
            path: PathBuf::from(MEMORY_PATH),
            ..Self::default()
        }
    }

    /// True when `path` asks for an in-memory database.
    pub fn is_in_memory(&self) -> bool {
        self.path.as_os_str() == MEMORY_PATH
    }

    /// The flush interval as a duration.
    pub fn flush_interval(&self) -> Duration {
        Duration::from_millis(self.flush_interval_ms)
    }

    /// Rejects settings the writer cannot work with.
    pub fn check(&self) -> Result<(), HistoryError> {
        if self.batch_max == 0 {
            return Err(HistoryError::Config("batch_max must be at least 1".into()));
        }
        if self.queue_capacity == 0 {
            return Err(HistoryError::Config(
                "queue_capacity must be at least 1".into(),
            ));
        }
        if self.path.as_os_str().is_empty() {
            return Err(HistoryError::Config("path must not be empty".into()));
        }
        Ok(())
    }
}

/// The `path` that selects an in-memory database, as in SQLite.
pub(crate) const MEMORY_PATH: &str = ":memory:";

/// SQLite's `PRAGMA synchronous` level, in WAL mode.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Synchronous {
    /// No fsync per commit, only at checkpoints: a committed transaction survives a crash
    /// of the process (it is in the WAL file) but the last ones may be lost if the whole
    /// machine loses power. The usual choice for WAL.
    #[default]
    Normal,
    /// fsync the WAL at every commit: committed data also survives a power cut, at the
    /// cost of one fsync per batch.
    Full,
}

impl Synchronous {
    /// The pragma value.
    pub(crate) fn pragma(self) -> &'static str {
        match self {
            Self::Normal => "NORMAL",
            Self::Full => "FULL",
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used)]
mod tests {
    use super::*;

    #[test]
    fn an_empty_document_gives_the_defaults() {
        let c: HistoryConfig = serde_json::from_str("{}").unwrap();
        assert_eq!(c, HistoryConfig::default());
        assert_eq!(c.path, PathBuf::from("shoal-data/history.db"));
        assert_eq!(
            (c.batch_max, c.flush_interval_ms, c.queue_capacity),
            (2000, 20, 200_000)
        );
        assert_eq!(c.synchronous, Synchronous::Normal);
    }

    #[test]
    fn unknown_fields_and_bad_levels_are_rejected() {
        assert!(serde_json::from_str::<HistoryConfig>(r#"{"batch": 5}"#).is_err());
        assert!(serde_json::from_str::<HistoryConfig>(r#"{"synchronous": "off"}"#).is_err());
        let c: HistoryConfig = serde_json::from_str(r#"{"synchronous": "full"}"#).unwrap();
        assert_eq!(c.synchronous, Synchronous::Full);
    }

    #[test]
    fn zero_sizes_are_refused() {
        let c = HistoryConfig {
            batch_max: 0,
            ..HistoryConfig::in_memory()
        };
        assert!(c.check().is_err());
        let c = HistoryConfig {
            queue_capacity: 0,
            ..HistoryConfig::in_memory()
        };
        assert!(c.check().is_err());
        assert!(HistoryConfig::in_memory().check().is_ok());
    }
}
