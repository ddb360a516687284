//! The database schema, its versioning, and how connections are opened.
//!
//! The schema version lives in `PRAGMA user_version`; [`MIGRATIONS`] holds one script per
//! version and [`migrate`] applies the missing ones in one transaction, so a store written by
//! an older Shoal is upgraded in place and one written by a newer Shoal is refused.
//!
//! Tables are `STRICT` so a value of the wrong type is an error rather than silently stored
//! as text, and every column is `NOT NULL`: SQLite stores a NaN as NULL, so a NaN that slipped
//! past validation fails its row (which is then quarantined) instead of being stored as a
//! hole. The few `CHECK`s are sanity bounds, not a second validator: validation belongs to
//! the pre-processor, the store only refuses what would make its queries lie.

use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use rusqlite::{Connection, OpenFlags};
use tracing::{debug, info, warn};

use crate::{HistoryConfig, HistoryError};

/// `PRAGMA auto_vacuum` value of incremental auto-vacuum.
pub(crate) const AUTO_VACUUM_INCREMENTAL: i64 = 2;

/// Size the WAL file is truncated back to after a checkpoint: a maintenance pass that
/// deletes a lot writes a lot of WAL, which should not stay on disk afterwards.
const JOURNAL_SIZE_LIMIT: i64 = 64 * 1024 * 1024;

/// How long a connection waits for a lock held by another connection before failing.
const BUSY_TIMEOUT: Duration = Duration::from_secs(5);

/// Schema scripts; `MIGRATIONS[i]` takes the database from version `i` to `i + 1`.
///
/// Duplicate keys are upserts (`INSERT OR REPLACE`, see `store.rs`), so every keyed table
/// declares the key as its primary key. Time-series tables are `WITHOUT ROWID`: rows are
/// stored in key order, which is exactly the order the track and window queries read them in,
/// and no second b-tree is kept for a rowid.
const MIGRATIONS: &[&str] = &[
    // Version 1.
    "
    CREATE TABLE state_vector (
        vehicle_id    TEXT    NOT NULL CHECK (length(vehicle_id) > 0),
        timestamp_ms  INTEGER NOT NULL,
        latitude_deg  REAL    NOT NULL CHECK (latitude_deg BETWEEN -90 AND 90),
        longitude_deg REAL    NOT NULL CHECK (longitude_deg BETWEEN -180 AND 180),
        depth_m       REAL    NOT NULL,
        altitude_m    REAL    NOT NULL,
        speed_mps     REAL    NOT NULL,
        yaw_deg       REAL    NOT NULL,
        pitch_deg     REAL    NOT NULL,
        roll_deg      REAL    NOT NULL,
        battery_pct   REAL    NOT NULL,
        PRIMARY KEY (vehicle_id, timestamp_ms)
    ) WITHOUT ROWID, STRICT;

    CREATE TABLE vehicle (
        vehicle_id    TEXT    NOT NULL PRIMARY KEY CHECK (length(vehicle_id) > 0),
        name          TEXT    NOT NULL,
        kind          TEXT    NOT NULL,
        vendor        TEXT    NOT NULL,
        capabilities  TEXT    NOT NULL, -- JSON array of strings
        sensors       TEXT    NOT NULL, -- JSON array of strings
        links         TEXT    NOT NULL, -- JSON array of link kinds
        max_speed_mps REAL    NOT NULL,
        first_seen_ms INTEGER NOT NULL, -- earliest announcement
        last_seen_ms  INTEGER NOT NULL  -- newest announcement; the other fields are from it
    ) STRICT;

    CREATE TABLE task_assignment (
        task_id        TEXT    NOT NULL PRIMARY KEY CHECK (length(task_id) > 0),
        mission_id     TEXT    NOT NULL,
        vehicle_id     TEXT    NOT NULL,
        issued_ms      INTEGER NOT NULL,
        kind           TEXT    NOT NULL,
        area           TEXT    NOT NULL, -- JSON array of {latitude_deg, longitude_deg}
        depth_m        REAL    NOT NULL,
        altitude_m     REAL    NOT NULL,
        speed_mps      REAL    NOT NULL,
        line_spacing_m REAL    NOT NULL,
        duration_s     REAL    NOT NULL,
        rate_hz        REAL    NOT NULL
    ) STRICT;
    CREATE INDEX task_assignment_by_vehicle ON task_assignment (vehicle_id, issued_ms);

    CREATE TABLE task_status (
        task_id      TEXT    NOT NULL CHECK (length(task_id) > 0),
        timestamp_ms INTEGER NOT NULL,
        state        TEXT    NOT NULL,
        progress_pct REAL    NOT NULL,
        message      TEXT    NOT NULL,
        vehicle_id   TEXT    NOT NULL,
        PRIMARY KEY (task_id, timestamp_ms, state)
    ) WITHOUT ROWID, STRICT;

    CREATE TABLE event (
        event_id     TEXT    NOT NULL PRIMARY KEY CHECK (length(event_id) > 0),
        timestamp_ms INTEGER NOT NULL,
        severity     TEXT    NOT NULL,
        kind         TEXT    NOT NULL,
        vehicle_id   TEXT    NOT NULL,
        task_id      TEXT    NOT NULL,
        text         TEXT    NOT NULL
    ) STRICT;
    CREATE INDEX event_by_time ON event (timestamp_ms);

    CREATE TABLE observation (
        vehicle_id    TEXT    NOT NULL CHECK (length(vehicle_id) > 0),
        property      TEXT    NOT NULL CHECK (length(property) > 0),
        timestamp_ms  INTEGER NOT NULL,
        value         REAL    NOT NULL,
        unit          TEXT    NOT NULL,
        latitude_deg  REAL    NOT NULL,
        longitude_deg REAL    NOT NULL,
        depth_m       REAL    NOT NULL,
        PRIMARY KEY (vehicle_id, property, timestamp_ms)
    ) WITHOUT ROWID, STRICT;

    -- Quarantine: data rejected by the station, or by this store, kept for inspection.
    CREATE TABLE rejected (
        id           INTEGER PRIMARY KEY,
        received_ms  INTEGER NOT NULL,
        topic        TEXT    NOT NULL,
        reason       TEXT    NOT NULL,
        payload_json TEXT    NOT NULL
    ) STRICT;
    ",
    // Version 2: tasks carry the station's issue sequence and an expiry (0 = none).
    "
    ALTER TABLE task_assignment
        ADD COLUMN issue_seq INTEGER NOT NULL DEFAULT 0 CHECK (issue_seq >= 0);
    ALTER TABLE task_assignment ADD COLUMN expires_ms INTEGER NOT NULL DEFAULT 0;
    ",
    // Version 3: tasks carry the command lease they were sent under (0 and '' = none).
    "
    ALTER TABLE task_assignment
        ADD COLUMN lease_term INTEGER NOT NULL DEFAULT 0 CHECK (lease_term >= 0);
    ALTER TABLE task_assignment ADD COLUMN lease_holder TEXT NOT NULL DEFAULT '';
    ",
];

/// The schema version this build writes.
pub(crate) const SCHEMA_VERSION: i64 = MIGRATIONS.len() as i64;

/// Brings the schema to [`SCHEMA_VERSION`], refusing databases from a newer build.
pub(crate) fn migrate(conn: &mut Connection) -> Result<(), HistoryError> {
    let found: i64 = conn.pragma_query_value(None, "user_version", |r| r.get(0))?;
    if found > SCHEMA_VERSION {
        return Err(HistoryError::SchemaTooNew {
            found,
            supported: SCHEMA_VERSION,
        });
    }
    if found == SCHEMA_VERSION {
        return Ok(());
    }
    // All missing steps in one transaction: a crash half-way leaves the old version intact.
    let tx = conn.transaction()?;
    for (from, script) in MIGRATIONS
        .iter()
        .enumerate()
        .skip(usize::try_from(found).unwrap_or(0))
    {
        debug!(from, "migrating the history schema");
        tx.execute_batch(script)?;
    }
    tx.pragma_update(None, "user_version", SCHEMA_VERSION)?;
    tx.commit()?;
    Ok(())
}

/// Where a [`HistoryConfig`] points: a file, or a named in-memory database.
#[derive(Debug, Clone)]
pub(crate) enum Location {
    /// A database file.
    File(std::path::PathBuf),
    /// A `memdb` URI. A plain `:memory:` database is private to one connection, but the
    /// writer thread and the readers need the same one, so in-memory stores use SQLite's
    /// `memdb` VFS under a process-unique name, which connections of one process share.
    Memory(String),
}

impl Location {
    /// The location a configuration selects; in-memory ones get a fresh name each time.
    pub(crate) fn of(config: &HistoryConfig) -> Self {
        static NEXT: AtomicU64 = AtomicU64::new(0);
        if config.is_in_memory() {
            let n = NEXT.fetch_add(1, Ordering::Relaxed);
            Self::Memory(format!(
                "file:/shoal-history-{}-{n}?vfs=memdb",
                std::process::id()
            ))
        } else {
            Self::File(config.path.clone())
        }
    }

    fn open(&self, flags: OpenFlags) -> rusqlite::Result<Connection> {
        match self {
            Self::File(p) => Connection::open_with_flags(p, flags),
            Self::Memory(uri) => Connection::open_with_flags(uri, flags),
        }
    }
}

/// Opens the writer's connection: WAL, the configured sync level and page cache, the
/// schema migrated.
pub(crate) fn open_writer(
    location: &Location,
    config: &HistoryConfig,
) -> Result<Connection, HistoryError> {
    if let Location::File(path) = location {
        create_parent_dir(path)?;
    }
    let flags = OpenFlags::SQLITE_OPEN_READ_WRITE
        | OpenFlags::SQLITE_OPEN_CREATE
        | OpenFlags::SQLITE_OPEN_URI
        | OpenFlags::SQLITE_OPEN_NO_MUTEX;
    let mut conn = location.open(flags)?;
    conn.busy_timeout(BUSY_TIMEOUT)?;
    // Incremental auto-vacuum lets retention give freed pages back to the file system in
    // small steps (`PRAGMA incremental_vacuum`). SQLite honours it only before the first
    // table is created; on an older database the setting is a no-op (its free pages are
    // still reused) until an offline VACUUM, which the operator guide describes: a VACUUM
    // here would rewrite the whole file while the station waits.
    conn.pragma_update(None, "auto_vacuum", AUTO_VACUUM_INCREMENTAL)?;
    // WAL: a commit appends to the log instead of rewriting pages, readers never block the
    // writer, and a committed transaction survives a process crash (it is replayed from the
    // log on the next open). That is what makes "committed" mean "acknowledged".
    let mode: String = conn.query_row("PRAGMA journal_mode = WAL", [], |r| r.get(0))?;
    match location {
        Location::File(path) if !mode.eq_ignore_ascii_case("wal") => {
            warn!(path = %path.display(), mode, "history database is not in WAL mode");
        }
        _ => debug!(mode, "history journal mode"),
    }
    conn.pragma_update(None, "synchronous", config.synchronous.pragma())?;
    conn.pragma_update(None, "journal_size_limit", JOURNAL_SIZE_LIMIT)?;
    // Negative: KiB rather than pages.
    conn.pragma_update(None, "cache_size", -(i64::from(config.cache_mib) * 1024))?;
    migrate(&mut conn)?;
    let auto_vacuum: i64 = conn.pragma_query_value(None, "auto_vacuum", |r| r.get(0))?;
    if auto_vacuum != AUTO_VACUUM_INCREMENTAL && config.retention.is_active() {
        info!(
            auto_vacuum,
            "history database predates incremental auto-vacuum: space freed by retention is \
             reused but not given back to the file system (see the operator guide)"
        );
    }
    Ok(conn)
}

/// Opens a read-only connection for queries; call after [`open_writer`] created the schema.
pub(crate) fn open_reader(location: &Location) -> Result<Connection, HistoryError> {
    let flags = OpenFlags::SQLITE_OPEN_READ_ONLY
        | OpenFlags::SQLITE_OPEN_URI
        | OpenFlags::SQLITE_OPEN_NO_MUTEX;
    let conn = location.open(flags)?;
    conn.busy_timeout(BUSY_TIMEOUT)?;
    Ok(conn)
}

fn create_parent_dir(path: &Path) -> Result<(), HistoryError> {
    match path.parent() {
        Some(dir) if !dir.as_os_str().is_empty() => {
            std::fs::create_dir_all(dir).map_err(|source| HistoryError::CreateDir {
                path: dir.to_path_buf(),
                source,
            })
        }
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn the_writer_gets_the_configured_page_cache() {
        let config = HistoryConfig {
            cache_mib: 48,
            ..HistoryConfig::in_memory()
        };
        let conn = open_writer(&Location::of(&config), &config).unwrap();
        let kib: i64 = conn
            .pragma_query_value(None, "cache_size", |r| r.get(0))
            .unwrap();
        assert_eq!(kib, -48 * 1024);
    }

    #[test]
    fn a_version_1_store_is_upgraded_in_place_and_keeps_its_tasks() {
        let mut conn = Connection::open_in_memory().unwrap();
        conn.execute_batch(MIGRATIONS[0]).unwrap();
        conn.pragma_update(None, "user_version", 1).unwrap();
        conn.execute(
            "INSERT INTO task_assignment VALUES ('t-1', '', 'auv-1', 5, 'surface', '[]', \
             -1, -1, 0, 0, 0, 0)",
            [],
        )
        .unwrap();
        migrate(&mut conn).unwrap();
        let version: i64 = conn
            .pragma_query_value(None, "user_version", |r| r.get(0))
            .unwrap();
        assert_eq!(version, SCHEMA_VERSION);
        let (seq, expires): (i64, i64) = conn
            .query_row(
                "SELECT issue_seq, expires_ms FROM task_assignment WHERE task_id = 't-1'",
                [],
                |r| Ok((r.get(0)?, r.get(1)?)),
            )
            .unwrap();
        assert_eq!((seq, expires), (0, 0));
        let (term, holder): (i64, String) = conn
            .query_row(
                "SELECT lease_term, lease_holder FROM task_assignment WHERE task_id = 't-1'",
                [],
                |r| Ok((r.get(0)?, r.get(1)?)),
            )
            .unwrap();
        assert_eq!((term, holder.as_str()), (0, ""), "no lease before leases");
        // The new column keeps its sanity bound.
        let negative = conn.execute(
            "UPDATE task_assignment SET issue_seq = -1 WHERE task_id = 't-1'",
            [],
        );
        assert!(negative.is_err());
    }
}
