//! The PostgreSQL side of `HistoryReader`: one thread that owns the reader's connection and
//! runs the queries sent to it.
//!
//! A query is a closure sent over a channel; the thread runs it against its session (which
//! blocks on the thread's private runtime) and the closure sends the decoded result back.
//! The calling thread only waits on a channel, so the reader works the same from plain
//! threads and from inside a caller's tokio runtime (where entering a second runtime would
//! panic). Queries take turns, as they do on SQLite's single read connection.

use std::collections::HashMap;
use std::sync::mpsc;

use tokio::runtime::Runtime;
use tokio_postgres::types::ToSql;
use tokio_postgres::{Row, Statement};
use tracing::debug;

use super::{Conn, Target, is_connection_error};
use crate::HistoryError;
use crate::error::pg_text;
use crate::query::Param;

/// A query for the reader thread.
type Job = Box<dyn FnOnce(&mut ReadSession) + Send>;

/// A handle to the reader thread; the thread ends when the last handle is dropped.
#[derive(Debug, Clone)]
pub(crate) struct PgReader {
    jobs: mpsc::Sender<Job>,
}

impl PgReader {
    /// Starts the reader thread and waits until it is connected, so that a store that
    /// cannot be read fails at open rather than at its first query.
    pub(crate) fn open(target: Target) -> Result<Self, HistoryError> {
        let (jobs, queue) = mpsc::channel::<Job>();
        let (ready_tx, ready_rx) = mpsc::sync_channel(1);
        std::thread::Builder::new()
            .name("shoal-history-query".into())
            .spawn(move || match ReadSession::open(target) {
                Ok(mut session) => {
                    // The receiver waits in `open` until this is sent; it cannot be gone.
                    let _ = ready_tx.send(Ok(()));
                    while let Ok(job) = queue.recv() {
                        job(&mut session);
                    }
                    session.close();
                }
                Err(e) => {
                    let _ = ready_tx.send(Err(e));
                }
            })
            .map_err(HistoryError::Spawn)?;
        ready_rx.recv().map_err(|_| HistoryError::ReaderStopped)??;
        Ok(Self { jobs })
    }

    /// Runs `job` on the reader thread and returns its result.
    pub(crate) fn call<T: Send + 'static>(
        &self,
        job: impl FnOnce(&mut ReadSession) -> Result<T, HistoryError> + Send + 'static,
    ) -> Result<T, HistoryError> {
        let (reply, result) = mpsc::sync_channel(1);
        self.jobs
            .send(Box::new(move |session| {
                // Only fails if the caller is gone, and then nobody wants the answer.
                let _ = reply.send(job(session));
            }))
            .map_err(|_| HistoryError::ReaderStopped)?;
        result.recv().map_err(|_| HistoryError::ReaderStopped)?
    }
}

/// The reader thread's connection, runtime and prepared statements.
#[derive(Debug)]
pub(crate) struct ReadSession {
    runtime: Runtime,
    target: Target,
    /// `None` after the connection was found broken; the next query reconnects.
    conn: Option<Conn>,
    /// Prepared statements by their SQLite-style text.
    statements: HashMap<String, Statement>,
}

impl ReadSession {
    fn open(target: Target) -> Result<Self, HistoryError> {
        let runtime = super::runtime()?;
        let conn = runtime.block_on(Conn::open(&target))?;
        Ok(Self {
            runtime,
            target,
            conn: Some(conn),
            statements: HashMap::new(),
        })
    }

    fn close(mut self) {
        if let Some(conn) = self.conn.take() {
            self.runtime.block_on(conn.close());
        }
    }

    /// Runs one query written for SQLite (`?1`-style placeholders, which become `$1`).
    ///
    /// A query that fails because the connection broke (a server restart, an
    /// administrator ending the session) is tried once more on a fresh connection: queries
    /// only read, so running one twice is harmless, and the caller should not see an error
    /// for an outage that is already over.
    pub(crate) fn query(&mut self, sql: &str, params: &[Param]) -> Result<Vec<Row>, HistoryError> {
        let Self {
            runtime,
            target,
            conn,
            statements,
        } = self;
        let params: Vec<&(dyn ToSql + Sync)> = params.iter().map(Param::as_pg).collect();
        runtime.block_on(async {
            let mut retried = false;
            loop {
                let c: &Conn = match conn.take() {
                    Some(c) if !c.client.is_closed() => conn.insert(c),
                    stale => {
                        if let Some(old) = stale {
                            old.close().await;
                        }
                        statements.clear();
                        conn.insert(Conn::open(target).await?)
                    }
                };
                match run(c, statements, sql, &params).await {
                    Ok(rows) => return Ok(rows),
                    Err(e) => {
                        // A statement that failed may be the reason (e.g. its table was
                        // dropped); prepare it afresh next time.
                        statements.remove(sql);
                        if retried || !is_connection_error(&e) {
                            return Err(e.into());
                        }
                        debug!(error = %pg_text(&e), "history query lost its connection; reconnecting");
                        retried = true;
                        if let Some(old) = conn.take() {
                            old.close().await;
                        }
                    }
                }
            }
        })
    }
}

async fn run(
    c: &Conn,
    statements: &mut HashMap<String, Statement>,
    sql: &str,
    params: &[&(dyn ToSql + Sync)],
) -> Result<Vec<Row>, tokio_postgres::Error> {
    let statement = match statements.get(sql) {
        Some(s) => s.clone(),
        None => {
            let s = c.client.prepare(&placeholders(sql)).await?;
            statements.insert(sql.to_owned(), s.clone());
            s
        }
    };
    c.client.query(&statement, params).await
}

/// SQLite's `?N` placeholders as PostgreSQL's `$N`. The queries are the crate's own and
/// hold no `?` anywhere else (no string literal contains one).
pub(crate) fn placeholders(sql: &str) -> String {
    sql.replace('?', "$")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn placeholders_are_renumbered_for_postgres() {
        assert_eq!(
            placeholders("SELECT a FROM t WHERE b = ?1 AND c BETWEEN ?2 AND ?3 LIMIT ?10"),
            "SELECT a FROM t WHERE b = $1 AND c BETWEEN $2 AND $3 LIMIT $10"
        );
    }
}
