//! What the writer thread writes to: SQLite or PostgreSQL, behind one interface.

use crate::Record;
use crate::pg::store::PgWriter;
use crate::query::Param;
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

/// A row of a maintenance query, decoded the same way from either backend.
pub(crate) trait FromRow: Sized + Send + 'static {
    /// Decodes a SQLite row.
    fn sqlite(row: &rusqlite::Row<'_>) -> rusqlite::Result<Self>;
    /// Decodes a PostgreSQL row.
    fn postgres(row: &tokio_postgres::Row) -> Result<Self, tokio_postgres::Error>;
}

impl FromRow for i64 {
    fn sqlite(row: &rusqlite::Row<'_>) -> rusqlite::Result<Self> {
        row.get(0)
    }
    fn postgres(row: &tokio_postgres::Row) -> Result<Self, tokio_postgres::Error> {
        row.try_get(0)
    }
}

impl FromRow for Option<i64> {
    fn sqlite(row: &rusqlite::Row<'_>) -> rusqlite::Result<Self> {
        row.get(0)
    }
    fn postgres(row: &tokio_postgres::Row) -> Result<Self, tokio_postgres::Error> {
        row.try_get(0)
    }
}

impl FromRow for String {
    fn sqlite(row: &rusqlite::Row<'_>) -> rusqlite::Result<Self> {
        row.get(0)
    }
    fn postgres(row: &tokio_postgres::Row) -> Result<Self, tokio_postgres::Error> {
        row.try_get(0)
    }
}

impl FromRow for (String, String) {
    fn sqlite(row: &rusqlite::Row<'_>) -> rusqlite::Result<Self> {
        Ok((row.get(0)?, row.get(1)?))
    }
    fn postgres(row: &tokio_postgres::Row) -> Result<Self, tokio_postgres::Error> {
        Ok((row.try_get(0)?, row.try_get(1)?))
    }
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

    /// Runs one statement in a transaction of its own and returns the rows it changed. The
    /// SQL is written once for both databases, with SQLite's `?N` placeholders.
    pub(crate) fn execute(&mut self, sql: &str, params: &[Param]) -> Result<u64, StoreError> {
        match self {
            Self::Sqlite(conn) => {
                let n = conn
                    .prepare_cached(sql)?
                    .execute(rusqlite::params_from_iter(params))?;
                Ok(n as u64)
            }
            Self::Postgres(pg) => pg.execute(sql, params),
        }
    }

    /// Runs one query and decodes every row, like [`Self::execute`].
    pub(crate) fn query<T: FromRow>(
        &mut self,
        sql: &str,
        params: &[Param],
    ) -> Result<Vec<T>, StoreError> {
        match self {
            Self::Sqlite(conn) => {
                let mut statement = conn.prepare_cached(sql)?;
                let rows = statement.query_map(rusqlite::params_from_iter(params), T::sqlite)?;
                Ok(rows.collect::<rusqlite::Result<Vec<T>>>()?)
            }
            Self::Postgres(pg) => pg.query(sql, params),
        }
    }

    /// The first row of [`Self::query`], if any.
    pub(crate) fn query_opt<T: FromRow>(
        &mut self,
        sql: &str,
        params: &[Param],
    ) -> Result<Option<T>, StoreError> {
        Ok(self.query(sql, params)?.into_iter().next())
    }

    /// Bytes the history takes on disk: SQLite's file (pages, free ones included, without
    /// the WAL), or PostgreSQL's tables, indexes and TOAST in the store's schema.
    pub(crate) fn database_bytes(&mut self) -> Result<u64, StoreError> {
        let sql = match self {
            Self::Sqlite(_) => {
                "SELECT page_count * page_size FROM pragma_page_count(), pragma_page_size()"
            }
            Self::Postgres(_) => {
                "SELECT CAST(coalesce(sum(pg_total_relation_size(c.oid)), 0) AS BIGINT) \
                 FROM pg_class c WHERE c.relnamespace = current_schema()::regnamespace \
                 AND c.relkind = 'r'"
            }
        };
        let bytes: Option<i64> = self.query_opt(sql, &[])?;
        Ok(bytes.map_or(0, |b| u64::try_from(b).unwrap_or(0)))
    }
}
