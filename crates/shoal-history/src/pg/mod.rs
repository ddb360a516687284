//! The PostgreSQL backend: the same tables, upserts, quarantine and queries as the SQLite
//! backend, over `tokio-postgres` without TLS.
//!
//! `tokio-postgres` is asynchronous but this crate is not: callers need no runtime, and
//! may call it from inside theirs. So every PostgreSQL connection belongs to one thread of
//! the store's own (the writer thread, or the reader's query thread), which owns a private
//! current-thread runtime and blocks on it. No runtime is ever entered on a caller's thread,
//! which is what would panic ("cannot start a runtime from within a runtime") when the
//! caller is itself async; a caller only ever blocks on a channel, as it would on SQLite.

pub(crate) mod reader;
pub(crate) mod schema;
pub(crate) mod store;

use std::time::Duration;

use tokio::runtime::Runtime;
use tokio::task::JoinHandle;
use tokio_postgres::error::SqlState;
use tokio_postgres::{Client, NoTls};
use tracing::debug;

use crate::error::pg_text;
use crate::{HistoryConfig, HistoryError};

/// How long a connection attempt may take when `postgres_url` sets no `connect_timeout`:
/// the writer retries after it, and a close waits for a few attempts at most.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(5);

/// The `application_name` the store's connections show in `pg_stat_activity`, unless
/// `postgres_url` names one.
const APPLICATION_NAME: &str = "shoal-history";

/// Longest wait for a closing connection to say goodbye to the server.
const CLOSE_TIMEOUT: Duration = Duration::from_secs(1);

/// Where the PostgreSQL store lives: the parsed connection settings and the schema.
#[derive(Debug, Clone)]
pub(crate) struct Target {
    config: tokio_postgres::Config,
    schema: String,
}

impl Target {
    /// The target a checked configuration names.
    pub(crate) fn of(config: &HistoryConfig) -> Result<Self, HistoryError> {
        let mut pg = config.postgres_connect_config()?;
        if pg.get_connect_timeout().is_none() {
            pg.connect_timeout(CONNECT_TIMEOUT);
        }
        if pg.get_application_name().is_none() {
            pg.application_name(APPLICATION_NAME);
        }
        Ok(Self {
            config: pg,
            schema: config.postgres_schema.clone(),
        })
    }

    /// The schema holding the tables.
    pub(crate) fn schema(&self) -> &str {
        &self.schema
    }

    /// Where the store is, for logs: hosts, ports, database and schema, never the password.
    pub(crate) fn describe(&self) -> String {
        let hosts: Vec<String> = self
            .config
            .get_hosts()
            .iter()
            .map(|h| match h {
                tokio_postgres::config::Host::Tcp(name) => name.clone(),
                tokio_postgres::config::Host::Unix(path) => path.display().to_string(),
            })
            .collect();
        let ports: Vec<String> = self.config.get_ports().iter().map(u16::to_string).collect();
        format!(
            "host={} port={} dbname={} schema={}",
            hosts.join(","),
            ports.join(","),
            self.config
                .get_dbname()
                .or(self.config.get_user())
                .unwrap_or("?"),
            self.schema
        )
    }
}

/// The private runtime of one store thread: one thread, I/O and timers.
pub(crate) fn runtime() -> Result<Runtime, HistoryError> {
    tokio::runtime::Builder::new_current_thread()
        .enable_io()
        .enable_time()
        .build()
        .map_err(HistoryError::Runtime)
}

/// One open connection: the client, and the task that drives its socket.
#[derive(Debug)]
pub(crate) struct Conn {
    pub(crate) client: Client,
    driver: JoinHandle<()>,
}

impl Conn {
    /// Connects and points `search_path` at the store's schema, so that every statement
    /// names its tables unqualified, exactly as on SQLite. Must run inside the thread's
    /// runtime (`block_on`): the driver task is spawned on it.
    pub(crate) async fn open(target: &Target) -> Result<Self, tokio_postgres::Error> {
        let (client, connection) = target.config.connect(NoTls).await?;
        let driver = tokio::spawn(async move {
            if let Err(e) = connection.await {
                debug!(error = %pg_text(&e), "PostgreSQL connection ended");
            }
        });
        let conn = Self { client, driver };
        // The name was checked to need no quoting. The schema may not exist yet (the first
        // open creates it); `search_path` accepts that and finds it once it does.
        let set = conn
            .client
            .batch_execute(&format!("SET search_path TO \"{}\"", target.schema))
            .await;
        match set {
            Ok(()) => Ok(conn),
            Err(e) => {
                conn.close().await;
                Err(e)
            }
        }
    }

    /// Ends the session politely and waits a moment for it: requests already queued (such
    /// as the `ROLLBACK` of a dropped transaction) are sent first, then a goodbye, so the
    /// server logs no broken connection. Must run inside the thread's runtime, before the
    /// runtime is dropped (which would cut the connection mid-sentence).
    pub(crate) async fn close(self) {
        drop(self.client);
        if tokio::time::timeout(CLOSE_TIMEOUT, self.driver)
            .await
            .is_err()
        {
            debug!("PostgreSQL connection did not close in time");
        }
    }
}

/// True for SQLSTATEs that blame the data rather than the environment: class 22 (data
/// exception: a value the column type cannot hold, a NUL character in text...), class 23
/// (integrity constraint: `NOT NULL`, `CHECK`...), and 54000 (program limit exceeded, which
/// is what a key too large for its index raises: SQLite's `TOOBIG`). A batch refused for
/// one of these is retried row by row and the faulty rows quarantined; anything else
/// (connection lost, server shutting down, disk full, a table missing) keeps the batch.
pub(crate) fn is_data_state(state: &SqlState) -> bool {
    let code = state.code();
    code.starts_with("22") || code.starts_with("23") || *state == SqlState::PROGRAM_LIMIT_EXCEEDED
}

/// True when a failed read may succeed on a fresh connection: the connection broke
/// (closed, I/O error), or the server dropped it (class 08, connection exception; class
/// 57, operator intervention, e.g. `pg_terminate_backend` or a restart).
pub(crate) fn is_connection_error(e: &tokio_postgres::Error) -> bool {
    match e.code() {
        Some(state) => {
            let code = state.code();
            code.starts_with("08") || code.starts_with("57")
        }
        None => e.as_db_error().is_none(),
    }
}
