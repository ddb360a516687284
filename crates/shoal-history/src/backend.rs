//! What the writer thread writes to: SQLite or PostgreSQL, behind one interface.

use crate::Record;
use crate::pg::store::PgWriter;
use crate::store::{self, Outcome, StoreError};

/// The writer thread's database connection, whichever backend the configuration chose.
#[derive(Debug)]
pub(crate) enum WriteStore {
    /// SQLite: the writer's connection (WAL, migrated).
    Sqlite(rusqlite::Connection),
    /// PostgreSQL: the writer's connection and private runtime (migrated); boxed, being
    /// five times the size of the SQLite variant.
    Postgres(Box<PgWriter>),
}

impl WriteStore {
    /// Commits a batch in one transaction, with the per-row fallback for faulty rows. An
    /// `Err` is an environment failure: nothing of the batch was committed and the caller
    /// must retry it.
    pub(crate) fn write_batch(&mut self, batch: &[Record]) -> Result<Outcome, StoreError> {
        match self {
            Self::Sqlite(conn) => store::write_batch(conn, batch),
            Self::Postgres(pg) => pg.write_batch(batch),
        }
    }
}
