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
    /// SQLite only: the writer's page cache, MiB. A batch's rows of many vehicles land on
    /// as many leaves of the state-vector table; a cache that holds them spares reading a
    /// page back from the file, and spilling it, within a batch (SQLite's own is 2 MiB).
    pub cache_mib: u32,
    /// SQLite only: how hard SQLite syncs to disk at each commit. (PostgreSQL commits with
    /// the server's own `synchronous_commit` setting.)
    pub synchronous: Synchronous,
    /// What is kept, and for how long: the writer's periodic maintenance pass.
    pub retention: RetentionConfig,
}

/// The writer's SQLite page cache by default, MiB: about the leaves a batch of 1,000
/// vehicles' rows touches (one 4 KiB page each, and their parents).
pub const DEFAULT_CACHE_MIB: u32 = 8;
/// The largest page cache `cache_mib` may ask for, MiB.
pub const MAX_CACHE_MIB: u32 = 4096;

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
            cache_mib: DEFAULT_CACHE_MIB,
            synchronous: Synchronous::Normal,
            retention: RetentionConfig::default(),
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
        if !(1..=MAX_CACHE_MIB).contains(&self.cache_mib) {
            return Err(HistoryError::Config(format!(
                "cache_mib must be 1 to {MAX_CACHE_MIB}, not {}",
                self.cache_mib
            )));
        }
        self.retention.check()?;
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

/// Retention of the history (`[history.retention]`): a maintenance pass on the writer
/// thread every `interval_s` thins old state vectors, drops what is older than the maximum
/// age, and enforces the row cap, in statements of at most `batch_rows` rows with the
/// queued records committed between two of them. See `crate::retention` for the policy.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RetentionConfig {
    /// False: nothing is ever deleted (the history grows without bound).
    pub enabled: bool,
    /// Seconds between two maintenance passes; the first runs one interval after open.
    pub interval_s: u64,
    /// Most rows one maintenance statement may delete; between two statements the writer
    /// commits what producers queued, so ingest waits at most one such statement.
    pub batch_rows: u64,
    /// State vectors younger than this many hours are kept as received (full rate).
    pub full_rate_hours: u64,
    /// Older state vectors are thinned to the first one per vehicle in each interval of
    /// this many seconds (aligned to the Unix epoch); 0 keeps them at full rate.
    pub downsample_interval_s: u64,
    /// Everything older than this many days is deleted (state vectors, observations,
    /// events, quarantine, ended tasks, vehicles with nothing newer); 0: no age limit.
    pub max_age_days: u64,
    /// Most rows kept in the history's tables together; over it the oldest data goes
    /// first, thinned before it is dropped (down to 90 % of the cap); 0: no cap. Checking it
    /// counts every row once per pass.
    pub max_rows: u64,
}

impl Default for RetentionConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            interval_s: 300,
            batch_rows: 5_000,
            full_rate_hours: 24,
            downsample_interval_s: 60,
            max_age_days: 30,
            max_rows: 0,
        }
    }
}

impl RetentionConfig {
    /// No deletion at all (the behaviour before retention existed).
    pub fn disabled() -> Self {
        Self {
            enabled: false,
            ..Self::default()
        }
    }

    /// Rejects settings that would make maintenance delete what it should keep, or never
    /// finish.
    pub fn check(&self) -> Result<(), HistoryError> {
        let bad = |m: String| Err(HistoryError::Config(format!("retention: {m}")));
        if !self.enabled {
            return Ok(());
        }
        if self.interval_s == 0 {
            return bad("interval_s must be at least 1".into());
        }
        if self.batch_rows == 0 {
            return bad("batch_rows must be at least 1".into());
        }
        // Bounds that keep every product in i64 milliseconds, with room to spare.
        const MAX_DAYS: u64 = 365 * 1000;
        if self.max_age_days > MAX_DAYS || self.full_rate_hours > MAX_DAYS * 24 {
            return bad(format!("ages are limited to {MAX_DAYS} days"));
        }
        if self.downsample_interval_s > MAX_DAYS * 86_400 {
            return bad(format!(
                "downsample_interval_s is limited to {MAX_DAYS} days"
            ));
        }
        if self.max_age_days > 0 && self.full_rate_hours > self.max_age_days * 24 {
            return bad(format!(
                "full_rate_hours ({}) is longer than max_age_days ({} = {} hours): state \
                 vectors would be deleted before they are ever downsampled",
                self.full_rate_hours,
                self.max_age_days,
                self.max_age_days * 24
            ));
        }
        Ok(())
    }

    /// True when a pass has something to do.
    pub(crate) fn is_active(&self) -> bool {
        self.enabled
            && (self.downsample_interval_s > 0 || self.max_age_days > 0 || self.max_rows > 0)
    }

    /// The pass interval as a duration.
    pub fn interval(&self) -> Duration {
        Duration::from_secs(self.interval_s)
    }
}

/// One hour in ms.
pub(crate) const HOUR_MS: i64 = 3_600_000;

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
    fn retention_has_defaults_and_refuses_nonsense_with_the_key_named() {
        let c: HistoryConfig =
            serde_json::from_str(r#"{"retention": {"max_rows": 1000}}"#).unwrap();
        let r = &c.retention;
        assert!(r.enabled && r.is_active());
        assert_eq!(
            (
                r.interval_s,
                r.batch_rows,
                r.full_rate_hours,
                r.downsample_interval_s,
                r.max_age_days
            ),
            (300, 5_000, 24, 60, 30)
        );
        assert_eq!(r.max_rows, 1000);
        assert!(serde_json::from_str::<HistoryConfig>(r#"{"retention": {"max_age": 3}}"#).is_err());
        let error = |f: fn(&mut RetentionConfig)| {
            let mut r = RetentionConfig::default();
            f(&mut r);
            match (HistoryConfig {
                retention: r,
                ..HistoryConfig::in_memory()
            })
            .check()
            {
                Err(HistoryError::Config(m)) => m,
                other => panic!("expected a config error, got {other:?}"),
            }
        };
        assert!(error(|r| r.interval_s = 0).contains("retention: interval_s"));
        assert!(error(|r| r.batch_rows = 0).contains("retention: batch_rows"));
        let m = error(|r| r.full_rate_hours = 24 * 31);
        assert!(
            m.contains("full_rate_hours") && m.contains("max_age_days"),
            "{m}"
        );
        assert!(error(|r| r.max_age_days = u64::MAX).contains("limited"));
        // Off, or with nothing to enforce, anything goes and no pass runs.
        let off = RetentionConfig {
            interval_s: 0,
            ..RetentionConfig::disabled()
        };
        assert!(off.check().is_ok() && !off.is_active());
        let nothing = RetentionConfig {
            downsample_interval_s: 0,
            max_age_days: 0,
            ..RetentionConfig::default()
        };
        assert!(nothing.check().is_ok() && !nothing.is_active());
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

    #[test]
    fn the_page_cache_is_bounded_both_ways() {
        for (mib, ok) in [
            (0, false),
            (1, true),
            (MAX_CACHE_MIB, true),
            (MAX_CACHE_MIB + 1, false),
        ] {
            let c = HistoryConfig {
                cache_mib: mib,
                ..HistoryConfig::in_memory()
            };
            assert_eq!(c.check().is_ok(), ok, "cache_mib = {mib}");
        }
    }
}
