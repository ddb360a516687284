//! The PostgreSQL schema: the SQLite schema's tables, columns, keys and checks, in
//! PostgreSQL's types, and its versioning.
//!
//! Column for column the same as `crate::schema`: `INTEGER` is `BIGINT`, `REAL` is
//! `DOUBLE PRECISION`, `TEXT` is `TEXT`, and `rejected.id` is an identity column. Three
//! differences keep the two backends answering alike:
//!
//! - every `TEXT` column collates as `"C"` (byte order), which is SQLite's `BINARY` order, so
//!   `ORDER BY vehicle_id` lists vehicles in the same order whatever the server's locale;
//! - every `DOUBLE PRECISION` column refuses NaN: SQLite stores a NaN as NULL and its
//!   `NOT NULL` refuses the row, while PostgreSQL would store the NaN and let it poison
//!   averages and comparisons (`BETWEEN` checks already refuse it);
//! - the version lives in a one-row table `shoal_schema_version`, PostgreSQL having no
//!   `PRAGMA user_version`.
//!
//! Every statement is `IF NOT EXISTS`, so a schema created by hand (or half-created by an
//! interrupted first open) is completed rather than refused.

use tokio_postgres::Client;
use tracing::{debug, info};

use crate::HistoryError;

/// Schema scripts; `MIGRATIONS[i]` takes the schema from version `i` to `i + 1`, like
/// `crate::schema`'s (which has the same number of them).
pub(crate) const MIGRATIONS: &[&str] = &[
    // Version 1.
    r#"
    CREATE TABLE IF NOT EXISTS state_vector (
        vehicle_id    TEXT COLLATE "C" NOT NULL CHECK (length(vehicle_id) > 0),
        timestamp_ms  BIGINT           NOT NULL,
        latitude_deg  DOUBLE PRECISION NOT NULL CHECK (latitude_deg BETWEEN -90 AND 90),
        longitude_deg DOUBLE PRECISION NOT NULL CHECK (longitude_deg BETWEEN -180 AND 180),
        depth_m       DOUBLE PRECISION NOT NULL CHECK (depth_m <> 'NaN'),
        altitude_m    DOUBLE PRECISION NOT NULL CHECK (altitude_m <> 'NaN'),
        speed_mps     DOUBLE PRECISION NOT NULL CHECK (speed_mps <> 'NaN'),
        yaw_deg       DOUBLE PRECISION NOT NULL CHECK (yaw_deg <> 'NaN'),
        pitch_deg     DOUBLE PRECISION NOT NULL CHECK (pitch_deg <> 'NaN'),
        roll_deg      DOUBLE PRECISION NOT NULL CHECK (roll_deg <> 'NaN'),
        battery_pct   DOUBLE PRECISION NOT NULL CHECK (battery_pct <> 'NaN'),
        PRIMARY KEY (vehicle_id, timestamp_ms)
    );

    CREATE TABLE IF NOT EXISTS vehicle (
        vehicle_id    TEXT COLLATE "C" NOT NULL PRIMARY KEY CHECK (length(vehicle_id) > 0),
        name          TEXT COLLATE "C" NOT NULL,
        kind          TEXT COLLATE "C" NOT NULL,
        vendor        TEXT COLLATE "C" NOT NULL,
        capabilities  TEXT COLLATE "C" NOT NULL, -- JSON array of strings
        sensors       TEXT COLLATE "C" NOT NULL, -- JSON array of strings
        links         TEXT COLLATE "C" NOT NULL, -- JSON array of link kinds
        max_speed_mps DOUBLE PRECISION NOT NULL CHECK (max_speed_mps <> 'NaN'),
        first_seen_ms BIGINT           NOT NULL, -- earliest announcement
        last_seen_ms  BIGINT           NOT NULL  -- newest announcement; the other fields are from it
    );

    CREATE TABLE IF NOT EXISTS task_assignment (
        task_id        TEXT COLLATE "C" NOT NULL PRIMARY KEY CHECK (length(task_id) > 0),
        mission_id     TEXT COLLATE "C" NOT NULL,
        vehicle_id     TEXT COLLATE "C" NOT NULL,
        issued_ms      BIGINT           NOT NULL,
        kind           TEXT COLLATE "C" NOT NULL,
        area           TEXT COLLATE "C" NOT NULL, -- JSON array of {latitude_deg, longitude_deg}
        depth_m        DOUBLE PRECISION NOT NULL CHECK (depth_m <> 'NaN'),
        altitude_m     DOUBLE PRECISION NOT NULL CHECK (altitude_m <> 'NaN'),
        speed_mps      DOUBLE PRECISION NOT NULL CHECK (speed_mps <> 'NaN'),
        line_spacing_m DOUBLE PRECISION NOT NULL CHECK (line_spacing_m <> 'NaN'),
        duration_s     DOUBLE PRECISION NOT NULL CHECK (duration_s <> 'NaN'),
        rate_hz        DOUBLE PRECISION NOT NULL CHECK (rate_hz <> 'NaN')
    );
    CREATE INDEX IF NOT EXISTS task_assignment_by_vehicle
        ON task_assignment (vehicle_id, issued_ms);

    CREATE TABLE IF NOT EXISTS task_status (
        task_id      TEXT COLLATE "C" NOT NULL CHECK (length(task_id) > 0),
        timestamp_ms BIGINT           NOT NULL,
        state        TEXT COLLATE "C" NOT NULL,
        progress_pct DOUBLE PRECISION NOT NULL CHECK (progress_pct <> 'NaN'),
        message      TEXT COLLATE "C" NOT NULL,
        vehicle_id   TEXT COLLATE "C" NOT NULL,
        PRIMARY KEY (task_id, timestamp_ms, state)
    );

    CREATE TABLE IF NOT EXISTS event (
        event_id     TEXT COLLATE "C" NOT NULL PRIMARY KEY CHECK (length(event_id) > 0),
        timestamp_ms BIGINT           NOT NULL,
        severity     TEXT COLLATE "C" NOT NULL,
        kind         TEXT COLLATE "C" NOT NULL,
        vehicle_id   TEXT COLLATE "C" NOT NULL,
        task_id      TEXT COLLATE "C" NOT NULL,
        text         TEXT COLLATE "C" NOT NULL
    );
    CREATE INDEX IF NOT EXISTS event_by_time ON event (timestamp_ms);

    CREATE TABLE IF NOT EXISTS observation (
        vehicle_id    TEXT COLLATE "C" NOT NULL CHECK (length(vehicle_id) > 0),
        property      TEXT COLLATE "C" NOT NULL CHECK (length(property) > 0),
        timestamp_ms  BIGINT           NOT NULL,
        value         DOUBLE PRECISION NOT NULL CHECK (value <> 'NaN'),
        unit          TEXT COLLATE "C" NOT NULL,
        latitude_deg  DOUBLE PRECISION NOT NULL CHECK (latitude_deg <> 'NaN'),
        longitude_deg DOUBLE PRECISION NOT NULL CHECK (longitude_deg <> 'NaN'),
        depth_m       DOUBLE PRECISION NOT NULL CHECK (depth_m <> 'NaN'),
        PRIMARY KEY (vehicle_id, property, timestamp_ms)
    );

    -- Quarantine: data rejected by the station, or by this store, kept for inspection.
    CREATE TABLE IF NOT EXISTS rejected (
        id           BIGINT GENERATED ALWAYS AS IDENTITY PRIMARY KEY,
        received_ms  BIGINT           NOT NULL,
        topic        TEXT COLLATE "C" NOT NULL,
        reason       TEXT COLLATE "C" NOT NULL,
        payload_json TEXT COLLATE "C" NOT NULL
    );
    "#,
    // Version 2: tasks carry the station's issue sequence and an expiry (0 = none).
    r#"
    ALTER TABLE task_assignment
        ADD COLUMN IF NOT EXISTS issue_seq BIGINT NOT NULL DEFAULT 0 CHECK (issue_seq >= 0);
    ALTER TABLE task_assignment ADD COLUMN IF NOT EXISTS expires_ms BIGINT NOT NULL DEFAULT 0;
    "#,
    // Version 3: tasks carry the command lease they were sent under (0 and '' = none).
    r#"
    ALTER TABLE task_assignment
        ADD COLUMN IF NOT EXISTS lease_term BIGINT NOT NULL DEFAULT 0 CHECK (lease_term >= 0);
    ALTER TABLE task_assignment
        ADD COLUMN IF NOT EXISTS lease_holder TEXT COLLATE "C" NOT NULL DEFAULT '';
    "#,
];

/// The schema version this build writes; the same number as SQLite's.
pub(crate) const SCHEMA_VERSION: i64 = MIGRATIONS.len() as i64;

// Both backends must evolve in step: one version number describes the data either way.
const _: () = assert!(SCHEMA_VERSION == crate::schema::SCHEMA_VERSION);

/// The table holding the schema version (one row).
const VERSION_TABLE: &str =
    "CREATE TABLE IF NOT EXISTS shoal_schema_version (version BIGINT NOT NULL)";

/// Key of the advisory lock that serialises migrations of one database: `CREATE TABLE IF NOT
/// EXISTS` is not safe against a concurrent creator of the same table (one of them fails
/// on the catalog's unique index), and two stations may well start together.
const MIGRATION_LOCK: i64 = 0x5348_4f41_4c48_4953; // "SHOALHIS"

/// Creates the schema (the namespace) if missing and brings its tables to
/// [`SCHEMA_VERSION`], refusing a schema from a newer build; all in one transaction.
pub(crate) async fn migrate(client: &mut Client, schema: &str) -> Result<(), HistoryError> {
    let tx = client.transaction().await?;
    tx.execute("SELECT pg_advisory_xact_lock($1)", &[&MIGRATION_LOCK])
        .await?;
    // Looked up rather than `CREATE SCHEMA IF NOT EXISTS`, which needs the CREATE privilege
    // on the database even when the schema exists: an operator may well have created the
    // schema for a role that has no such right.
    let exists = tx
        .query_opt("SELECT 1 FROM pg_namespace WHERE nspname = $1", &[&schema])
        .await?
        .is_some();
    if !exists {
        info!(schema, "creating the PostgreSQL schema for the history");
        // The name was checked to need no quoting (see `HistoryConfig::check`).
        tx.batch_execute(&format!("CREATE SCHEMA \"{schema}\""))
            .await?;
    }
    tx.batch_execute(VERSION_TABLE).await?;
    let found: Option<i64> = tx
        .query_one("SELECT max(version) FROM shoal_schema_version", &[])
        .await?
        .try_get(0)?;
    let found = found.unwrap_or(0);
    if found > SCHEMA_VERSION {
        return Err(HistoryError::SchemaTooNew {
            found,
            supported: SCHEMA_VERSION,
        });
    }
    if found == SCHEMA_VERSION {
        tx.commit().await?;
        return Ok(());
    }
    for (from, script) in MIGRATIONS
        .iter()
        .enumerate()
        .skip(usize::try_from(found).unwrap_or(0))
    {
        debug!(from, schema, "migrating the PostgreSQL history schema");
        tx.batch_execute(script).await?;
    }
    tx.batch_execute("DELETE FROM shoal_schema_version").await?;
    tx.execute(
        "INSERT INTO shoal_schema_version (version) VALUES ($1)",
        &[&SCHEMA_VERSION],
    )
    .await?;
    tx.commit().await?;
    Ok(())
}
