//! Test support: every behaviour test runs on SQLite, and on PostgreSQL when
//! `SHOAL_TEST_POSTGRES_URL` names a server (see [`on_both_backends`]).
//!
//! Each PostgreSQL test gets a schema of its own with a unique name, which its store
//! creates at open and the fixture drops at the end (also when the test fails), so tests
//! run in parallel against one database without seeing each other. A test process that is
//! killed leaves its schemas behind; they are named `shoal_test_*`.

use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{SystemTime, UNIX_EPOCH};

use tokio_postgres::NoTls;

use crate::HistoryConfig;
use crate::error::pg_text;

/// The connection string of the PostgreSQL server to test against; unset: SQLite only.
pub(crate) const PG_URL_VAR: &str = "SHOAL_TEST_POSTGRES_URL";
/// `1`: the PostgreSQL variants fail, instead of being skipped, when the URL is unset.
pub(crate) const PG_REQUIRED_VAR: &str = "SHOAL_TEST_POSTGRES_REQUIRED";

/// Declares each `fn name(f: &Fixture) { ... }` as a module `name` with two tests,
/// `name::sqlite` and `name::postgres`, running the body against each backend.
macro_rules! on_both_backends {
    ($(fn $name:ident($f:ident: &Fixture) $body:block)*) => {$(
        mod $name {
            #[allow(unused_imports)]
            use super::*;
            use $crate::testing::Fixture;

            fn run($f: &Fixture) $body

            #[test]
            fn sqlite() {
                run(&Fixture::sqlite());
            }

            #[test]
            fn postgres() {
                if let Some(f) = Fixture::postgres() {
                    run(&f);
                }
            }
        }
    )*};
}
pub(crate) use on_both_backends;

/// Declares each `fn name(f: &Fixture) { ... }` as a test that runs on PostgreSQL only
/// (skipped, or failed if required, like the PostgreSQL half of [`on_both_backends`]).
macro_rules! on_postgres {
    ($(fn $name:ident($f:ident: &Fixture) $body:block)*) => {$(
        #[test]
        fn $name() {
            fn run($f: &$crate::testing::Fixture) $body
            if let Some(f) = $crate::testing::Fixture::postgres() {
                run(&f);
            }
        }
    )*};
}
pub(crate) use on_postgres;

/// The PostgreSQL server to test against, from the environment: `None` to skip the test.
///
/// # Panics
/// When `SHOAL_TEST_POSTGRES_REQUIRED=1` and no URL is set: a run that must cover
/// PostgreSQL fails rather than passing on SQLite alone.
pub(crate) fn postgres_url() -> Option<String> {
    match std::env::var(PG_URL_VAR) {
        Ok(url) if !url.trim().is_empty() => Some(url),
        _ => {
            let required = std::env::var(PG_REQUIRED_VAR).is_ok_and(|v| v.trim() == "1");
            assert!(
                !required,
                "{PG_REQUIRED_VAR}=1 but {PG_URL_VAR} is not set: no PostgreSQL server to \
                 test against (start one with scripts/postgres.sh start)"
            );
            eprintln!("{PG_URL_VAR} is not set: skipping the PostgreSQL variant");
            None
        }
    }
}

/// Where one test keeps its store, and how it reaches it behind the store's back.
#[derive(Debug)]
pub(crate) struct Fixture {
    backend: TestBackend,
    dir: tempfile::TempDir,
}

#[derive(Debug)]
enum TestBackend {
    Sqlite,
    Postgres { url: String, schema: String },
}

impl Fixture {
    /// A SQLite fixture in a temporary directory.
    pub(crate) fn sqlite() -> Self {
        Self {
            backend: TestBackend::Sqlite,
            dir: tempfile::tempdir().expect("temporary directory"),
        }
    }

    /// A PostgreSQL fixture with a fresh schema name, or `None` to skip (see
    /// [`postgres_url`]).
    pub(crate) fn postgres() -> Option<Self> {
        static NEXT: AtomicU64 = AtomicU64::new(0);
        let url = postgres_url()?;
        // Unique across parallel tests (counter), test processes (pid) and runs (clock).
        let nanos = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| d.subsec_nanos());
        let schema = format!(
            "shoal_test_{}_{}_{nanos}",
            std::process::id(),
            NEXT.fetch_add(1, Ordering::Relaxed)
        );
        Some(Self {
            backend: TestBackend::Postgres { url, schema },
            dir: tempfile::tempdir().expect("temporary directory"),
        })
    }

    /// True for the PostgreSQL variant.
    pub(crate) fn is_postgres(&self) -> bool {
        matches!(self.backend, TestBackend::Postgres { .. })
    }

    /// A store that survives `close`: a file, or the fixture's schema.
    pub(crate) fn config(&self) -> HistoryConfig {
        match &self.backend {
            TestBackend::Sqlite => HistoryConfig {
                path: self.sqlite_path(),
                ..HistoryConfig::default()
            },
            TestBackend::Postgres { url, schema } => HistoryConfig::postgres(url, schema),
        }
    }

    /// A store for one open: in memory on SQLite (cheapest), the schema on PostgreSQL.
    pub(crate) fn quick(&self) -> HistoryConfig {
        match &self.backend {
            TestBackend::Sqlite => HistoryConfig::in_memory(),
            TestBackend::Postgres { .. } => self.config(),
        }
    }

    /// [`Self::config`] with a writer that lingers for minutes, so that records stay queued
    /// (and end up in one batch) until a flush or close: tests control batching without
    /// timing.
    pub(crate) fn lingering(&self, queue_capacity: usize) -> HistoryConfig {
        HistoryConfig {
            flush_interval_ms: 600_000,
            batch_max: 1000,
            queue_capacity,
            ..self.config()
        }
    }

    /// The PostgreSQL connection string and schema, on PostgreSQL.
    pub(crate) fn postgres_target(&self) -> Option<(&str, &str)> {
        match &self.backend {
            TestBackend::Sqlite => None,
            TestBackend::Postgres { url, schema } => Some((url, schema)),
        }
    }

    fn sqlite_path(&self) -> PathBuf {
        self.dir.path().join("data").join("history.db")
    }

    /// Runs SQL on a connection of its own to the [`Self::config`] store.
    pub(crate) fn exec(&self, sql: &str) {
        match &self.backend {
            TestBackend::Sqlite => rusqlite::Connection::open(self.sqlite_path())
                .and_then(|c| c.execute_batch(sql))
                .unwrap_or_else(|e| panic!("{sql}: {e}")),
            TestBackend::Postgres { url, schema } => {
                pg_exec(url, Some(schema), sql).unwrap_or_else(|e| panic!("{sql}: {e}"));
            }
        }
    }

    /// Drops a table of the [`Self::config`] store and returns the SQL that recreates it.
    pub(crate) fn drop_table(&self, table: &str) -> String {
        let ddl = match &self.backend {
            TestBackend::Sqlite => rusqlite::Connection::open(self.sqlite_path())
                .and_then(|c| {
                    c.query_row(
                        "SELECT sql FROM sqlite_schema WHERE name = ?1",
                        [table],
                        |r| r.get(0),
                    )
                })
                .unwrap_or_else(|e| panic!("DDL of {table}: {e}")),
            // Every statement of the schema is IF NOT EXISTS: rerunning it recreates only
            // what is missing.
            TestBackend::Postgres { .. } => crate::pg::schema::MIGRATIONS.join("\n"),
        };
        self.exec(&format!("DROP TABLE {table}"));
        ddl
    }

    /// Stamps the [`Self::config`] store with another schema version.
    pub(crate) fn set_schema_version(&self, version: i64) {
        match &self.backend {
            TestBackend::Sqlite => self.exec(&format!("PRAGMA user_version = {version}")),
            TestBackend::Postgres { .. } => {
                self.exec(&format!(
                    "UPDATE shoal_schema_version SET version = {version}"
                ));
            }
        }
    }
}

impl Drop for Fixture {
    fn drop(&mut self) {
        if let TestBackend::Postgres { url, schema } = &self.backend {
            // Best effort: a schema left behind only costs space.
            if let Err(e) = pg_exec(
                url,
                None,
                &format!("DROP SCHEMA IF EXISTS {schema} CASCADE"),
            ) {
                eprintln!("could not drop test schema {schema}: {e}");
            }
        }
    }
}

/// Runs SQL on a new connection (in `schema`, if given), with a runtime of its own (tests
/// run on plain threads).
pub(crate) fn pg_exec(url: &str, schema: Option<&str>, sql: &str) -> Result<(), String> {
    let runtime = crate::pg::runtime().map_err(|e| e.to_string())?;
    runtime.block_on(async {
        let (client, connection) = tokio_postgres::connect(url, NoTls)
            .await
            .map_err(|e| pg_text(&e))?;
        let driver = tokio::spawn(connection);
        if let Some(schema) = schema {
            client
                .batch_execute(&format!("SET search_path TO {schema}"))
                .await
                .map_err(|e| pg_text(&e))?;
        }
        let result = client.batch_execute(sql).await.map_err(|e| pg_text(&e));
        drop(client);
        let _ = driver.await;
        result
    })
}
