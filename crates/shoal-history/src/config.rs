//! Configuration of the history store.

use std::path::PathBuf;
use std::time::Duration;

use serde::{Deserialize, Serialize};

use crate::HistoryError;

/// Settings of the history store; every field has a default, unknown fields are errors.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HistoryConfig {
    /// Which database holds the history: embedded SQLite (`path`) or a PostgreSQL server
    /// (`postgres_url`, `postgres_schema`).
    pub backend: Backend,
    /// SQLite only: the database file; its parent directory is created. `:memory:` keeps
    /// everything in RAM (for tests: nothing survives `close`).
    pub path: PathBuf,
    /// PostgreSQL only: a libpq-style connection string (`host=... port=... user=...
    /// dbname=...`, or a `postgresql://` URL). No TLS; a password, if the server wants one,
    /// goes in the string (`.pgpass` and `PG*` variables are not read).
    pub postgres_url: String,
    /// PostgreSQL only: the schema holding the tables; created at open if missing. Lower-case
    /// letters, digits and `_`, so that it never needs quoting.
    pub postgres_schema: String,
    /// Most records committed in one transaction.
    pub batch_max: usize,
    /// Longest a record waits in the queue for its batch to fill up before the batch is
    /// committed anyway, in ms; 0 commits whatever is queued at once.
    pub flush_interval_ms: u64,
    /// Most records queued for the writer; beyond it `submit` hands records back.
    pub queue_capacity: usize,
    /// SQLite only: how hard SQLite syncs to disk at each commit. (PostgreSQL commits with
    /// the server's own `synchronous_commit` setting.)
    pub synchronous: Synchronous,
}

impl Default for HistoryConfig {
    fn default() -> Self {
        Self {
            backend: Backend::Sqlite,
            path: PathBuf::from("shoal-data/history.db"),
            postgres_url: DEFAULT_POSTGRES_URL.into(),
            postgres_schema: DEFAULT_POSTGRES_SCHEMA.into(),
            batch_max: 20_000,
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

    /// A configuration for a PostgreSQL store at `url`, in `schema`, otherwise the defaults.
    pub fn postgres(url: impl Into<String>, schema: impl Into<String>) -> Self {
        Self {
            backend: Backend::Postgres,
            postgres_url: url.into(),
            postgres_schema: schema.into(),
            ..Self::default()
        }
    }

    /// True when the SQLite backend is selected and `path` asks for an in-memory database.
    pub fn is_in_memory(&self) -> bool {
        self.backend == Backend::Sqlite && self.path.as_os_str() == MEMORY_PATH
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
        match self.backend {
            Backend::Sqlite if self.path.as_os_str().is_empty() => {
                Err(HistoryError::Config("path must not be empty".into()))
            }
            Backend::Sqlite => Ok(()),
            Backend::Postgres => {
                self.postgres_connect_config()?;
                check_schema_name(&self.postgres_schema)
            }
        }
    }

    /// `postgres_url` parsed, or a configuration error saying what is wrong with it.
    pub(crate) fn postgres_connect_config(&self) -> Result<tokio_postgres::Config, HistoryError> {
        if self.postgres_url.trim().is_empty() {
            return Err(HistoryError::Config(
                "postgres_url must not be empty with backend = \"postgres\"".into(),
            ));
        }
        let config: tokio_postgres::Config = self.postgres_url.parse().map_err(|e| {
            HistoryError::Config(format!(
                "postgres_url is not a valid connection string: {}",
                crate::error::pg_text(&e)
            ))
        })?;
        // The store connects without TLS; refusing here beats a connect error at every open.
        if config.get_ssl_mode() == tokio_postgres::config::SslMode::Require {
            return Err(HistoryError::Config(
                "postgres_url asks for sslmode=require, but the history store connects without \
                 TLS (use a loopback or otherwise trusted network)"
                    .into(),
            ));
        }
        Ok(config)
    }
}

/// The default `postgres_url`: the private server `scripts/postgres.sh start` runs.
pub const DEFAULT_POSTGRES_URL: &str = "host=127.0.0.1 port=54329 user=shoal dbname=shoal";

/// The default `postgres_schema`.
pub const DEFAULT_POSTGRES_SCHEMA: &str = "public";

/// Longest schema name PostgreSQL keeps (`NAMEDATALEN - 1` bytes); longer ones are truncated
/// silently by the server, which would make two configured names meet in one schema.
const MAX_SCHEMA_NAME: usize = 63;

/// Accepts only names that are the same quoted and unquoted, so the name can be spliced into
/// SQL (`SET search_path`, `CREATE SCHEMA`) without any escaping question.
fn check_schema_name(name: &str) -> Result<(), HistoryError> {
    let bad = |why: &str| {
        Err(HistoryError::Config(format!(
            "postgres_schema {name:?} {why}"
        )))
    };
    let mut chars = name.chars();
    match chars.next() {
        None => return bad("must not be empty"),
        Some(c) if !(c.is_ascii_lowercase() || c == '_') => {
            return bad("must start with a lower-case letter or '_'");
        }
        Some(_) => {}
    }
    if !chars.all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_') {
        return bad("may only hold lower-case ASCII letters, digits and '_'");
    }
    if name.len() > MAX_SCHEMA_NAME {
        return bad("is longer than 63 characters");
    }
    if name.starts_with("pg_") {
        return bad("must not start with 'pg_' (reserved by PostgreSQL)");
    }
    Ok(())
}

/// Where the history is stored.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Backend {
    /// An embedded SQLite database file (`path`): nothing to run, the default.
    #[default]
    Sqlite,
    /// A PostgreSQL server (`postgres_url`, `postgres_schema`).
    Postgres,
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
            (20_000, 20, 200_000)
        );
        assert_eq!(c.synchronous, Synchronous::Normal);
        assert_eq!(c.backend, Backend::Sqlite);
        assert_eq!(c.postgres_url, DEFAULT_POSTGRES_URL);
        assert_eq!(c.postgres_schema, "public");
    }

    #[test]
    fn the_backend_is_chosen_by_name() {
        let c: HistoryConfig = serde_json::from_str(
            r#"{"backend": "postgres", "postgres_url": "host=127.0.0.1 port=5432 user=u dbname=d", "postgres_schema": "fleet_a"}"#,
        )
        .unwrap();
        assert_eq!(c.backend, Backend::Postgres);
        assert_eq!(c.postgres_schema, "fleet_a");
        c.check().unwrap();
        assert!(!c.is_in_memory());
        assert!(serde_json::from_str::<HistoryConfig>(r#"{"backend": "mysql"}"#).is_err());
        assert!(serde_json::from_str::<HistoryConfig>(r#"{"backend": "Postgres"}"#).is_err());
    }

    #[test]
    fn postgres_settings_are_checked_only_for_postgres() {
        let url_error = |url: &str| {
            let c = HistoryConfig::postgres(url, "public");
            match c.check() {
                Err(HistoryError::Config(m)) => m,
                other => panic!("{url:?}: expected a config error, got {other:?}"),
            }
        };
        assert!(
            url_error("").contains("must not be empty"),
            "{}",
            url_error("")
        );
        let m = url_error("host=127.0.0.1 port=notaport");
        assert!(m.contains("postgres_url") && m.contains("port"), "{m}");
        let m = url_error("host=127.0.0.1 bogus_key=1");
        assert!(m.contains("bogus_key"), "{m}");
        let m = url_error("host=127.0.0.1 sslmode=require");
        assert!(m.contains("TLS"), "{m}");
        assert!(
            HistoryConfig::postgres("postgresql://shoal@127.0.0.1:54329/shoal", "public")
                .check()
                .is_ok()
        );
        // A SQLite store does not care about a broken PostgreSQL setting, and vice versa.
        let c = HistoryConfig {
            postgres_url: "port=notaport".into(),
            postgres_schema: "Bad Name".into(),
            ..HistoryConfig::in_memory()
        };
        assert!(c.check().is_ok());
        let c = HistoryConfig {
            path: PathBuf::new(),
            ..HistoryConfig::postgres(DEFAULT_POSTGRES_URL, "public")
        };
        assert!(c.check().is_ok());
    }

    #[test]
    fn schema_names_must_need_no_quoting() {
        for good in ["public", "shoal", "_x", "fleet_2", &"a".repeat(63)] {
            assert!(check_schema_name(good).is_ok(), "{good}");
        }
        for bad in [
            "",
            "Fleet",
            "2fleet",
            "a-b",
            "a b",
            "a\"b",
            "sch\u{e9}ma",
            "pg_shoal",
            &"a".repeat(64),
        ] {
            assert!(check_schema_name(bad).is_err(), "{bad:?}");
        }
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
