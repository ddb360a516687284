//! The raw-SQLite baseline the ingest benchmark compares the store against.

use std::path::Path;
use std::time::{Duration, Instant};

use shoal_model::StateVector;

use crate::schema::{self, Location};
use crate::{HistoryConfig, HistoryError, store};

/// The order the raw baseline inserts each transaction's rows in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RawOrder {
    /// As they came: what a plain application does.
    Arrival,
    /// Sorted by key (vehicle, then time), as the history's writer does with each batch;
    /// the sort is timed with the inserts.
    Key,
}

/// Inserts `rows` into a fresh SQLite database at `history.path` with plain prepared
/// `INSERT`s, `history.batch_max` rows per transaction in `order`, in the calling thread:
/// no queue, no writer thread, no acknowledgements.
///
/// It uses the same pragmas as the store with this configuration (WAL, and the
/// configuration's own `synchronous`: the baseline is never made less durable than the
/// store it is compared with), the same schema and statement, so the difference to the
/// store's ingest rate is the cost of Shoal's own machinery. An existing database at the
/// path is deleted first. Returns the time from the first insert to the last commit.
pub fn raw_insert_baseline(
    history: &HistoryConfig,
    rows: &[StateVector],
    order: RawOrder,
) -> Result<Duration, HistoryError> {
    let config = HistoryConfig {
        backend: crate::Backend::Sqlite,
        ..history.clone()
    };
    config.check()?;
    let path: &Path = &config.path;
    let batch = config.batch_max;
    for suffix in ["", "-wal", "-shm"] {
        let mut file = path.as_os_str().to_owned();
        file.push(suffix);
        match std::fs::remove_file(&file) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(source) => {
                return Err(HistoryError::CreateDir {
                    path: file.into(),
                    source,
                });
            }
        }
    }
    let mut conn = schema::open_writer(&Location::of(&config), &config)?;
    let start = Instant::now();
    for chunk in rows.chunks(batch.max(1)) {
        let tx = conn.transaction()?;
        let mut chunk: Vec<&StateVector> = chunk.iter().collect();
        if order == RawOrder::Key {
            chunk.sort_by(|a, b| store::state_key(a).cmp(&store::state_key(b)));
        }
        for row in chunk {
            store::insert_state(&tx, row)?;
        }
        tx.commit()?;
    }
    Ok(start.elapsed())
}
