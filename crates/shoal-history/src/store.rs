//! Writing records to SQLite: one SQL statement per record, and batches with per-row
//! fallback. (PostgreSQL's counterpart is `crate::pg::store`, with the same rules.)
//!
//! Duplicate keys are upserts (`INSERT OR REPLACE`) rather than errors or `INSERT OR IGNORE`:
//! a duplicate is almost always the same sample delivered twice (a DDS reliable
//! retransmission, a transient-local replay to a late joiner, a proxy resending after a
//! reconnect, or a replayed log), and storing it again must be harmless so that a producer can
//! always resend what it is unsure about. When the two do differ (a vehicle re-sends a corrected
//! fix for the same instant), the later one wins, which is DDS's own rule for a keyed
//! instance. An error on duplicates would instead push good data into quarantine. `REPLACE`
//! only resolves key conflicts: `NOT NULL` (no column has a default) and `CHECK` failures
//! still abort the statement.

use rusqlite::{Connection, ErrorCode, params};
use serde::Serialize;
use tracing::{debug, error, warn};

use crate::Record;

const INSERT_STATE: &str = "INSERT OR REPLACE INTO state_vector (vehicle_id, timestamp_ms, \
    latitude_deg, longitude_deg, depth_m, altitude_m, speed_mps, yaw_deg, pitch_deg, roll_deg, \
    battery_pct) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11)";

// One row per vehicle. An announcement older than the stored one (a late replay) must not
// roll the fields back, so each field takes the newer of the two; first/last seen widen.
// In an UPDATE every right-hand side sees the row as it was before, so `last_seen_ms` on
// the right is the stored announcement's time.
const UPSERT_VEHICLE: &str = "INSERT INTO vehicle (vehicle_id, name, kind, vendor, \
    capabilities, sensors, links, max_speed_mps, first_seen_ms, last_seen_ms) \
    VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?9) \
    ON CONFLICT (vehicle_id) DO UPDATE SET \
    name = iif(excluded.last_seen_ms >= last_seen_ms, excluded.name, name), \
    kind = iif(excluded.last_seen_ms >= last_seen_ms, excluded.kind, kind), \
    vendor = iif(excluded.last_seen_ms >= last_seen_ms, excluded.vendor, vendor), \
    capabilities = iif(excluded.last_seen_ms >= last_seen_ms, excluded.capabilities, capabilities), \
    sensors = iif(excluded.last_seen_ms >= last_seen_ms, excluded.sensors, sensors), \
    links = iif(excluded.last_seen_ms >= last_seen_ms, excluded.links, links), \
    max_speed_mps = iif(excluded.last_seen_ms >= last_seen_ms, excluded.max_speed_mps, max_speed_mps), \
    first_seen_ms = min(first_seen_ms, excluded.first_seen_ms), \
    last_seen_ms = max(last_seen_ms, excluded.last_seen_ms)";

const INSERT_TASK: &str = "INSERT OR REPLACE INTO task_assignment (task_id, mission_id, \
    vehicle_id, issued_ms, kind, area, depth_m, altitude_m, speed_mps, line_spacing_m, \
    duration_s, rate_hz, issue_seq, expires_ms, lease_term, lease_holder) \
    VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, ?14, ?15, ?16)";

const INSERT_TASK_STATUS: &str = "INSERT OR REPLACE INTO task_status (task_id, timestamp_ms, \
    state, progress_pct, message, vehicle_id) VALUES (?1, ?2, ?3, ?4, ?5, ?6)";

const INSERT_EVENT: &str = "INSERT OR REPLACE INTO event (event_id, timestamp_ms, severity, \
    kind, vehicle_id, task_id, text) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7)";

const INSERT_OBSERVATION: &str = "INSERT OR REPLACE INTO observation (vehicle_id, property, \
    timestamp_ms, value, unit, latitude_deg, longitude_deg, depth_m) \
    VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8)";

const INSERT_REJECTED: &str =
    "INSERT INTO rejected (received_ms, topic, reason, payload_json) VALUES (?1, ?2, ?3, ?4)";

/// Why a record or a batch could not be written.
#[derive(Debug, thiserror::Error)]
pub(crate) enum StoreError {
    /// SQLite refused.
    #[error("{0}")]
    Sqlite(#[from] rusqlite::Error),
    /// PostgreSQL refused, or the connection to it failed.
    #[error("{}", crate::error::pg_text(.0))]
    Postgres(#[from] tokio_postgres::Error),
    /// PostgreSQL did not answer in time; the connection is presumed dead.
    #[error("no answer from PostgreSQL within {0:?}")]
    Timeout(std::time::Duration),
    /// A JSON column could not be encoded.
    #[error("cannot encode a JSON column: {0}")]
    Encode(#[from] serde_json::Error),
}

impl StoreError {
    /// True when the record itself is at fault, so that retrying it can never succeed and
    /// it belongs in quarantine; false for the environment (disk full, I/O error, locked,
    /// missing table...), where the batch is kept and retried because it may well succeed
    /// later.
    pub(crate) fn is_data_error(&self) -> bool {
        match self {
            Self::Encode(_) => true,
            // Classified by SQLSTATE; errors without one (I/O, closed connection) are the
            // environment's.
            Self::Postgres(e) => e.code().is_some_and(crate::pg::is_data_state),
            Self::Timeout(_) => false,
            Self::Sqlite(e) => match e.sqlite_error_code() {
                Some(code) => matches!(
                    code,
                    ErrorCode::ConstraintViolation
                        | ErrorCode::TypeMismatch
                        | ErrorCode::TooBig
                        | ErrorCode::ParameterOutOfRange
                ),
                None => matches!(
                    e,
                    rusqlite::Error::ToSqlConversionFailure(_)
                        | rusqlite::Error::IntegralValueOutOfRange(..)
                ),
            },
        }
    }
}

/// What became of a committed batch.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Outcome {
    /// Rows stored in their own table.
    pub(crate) stored: u64,
    /// Rows that failed on their own and went to `rejected` (or were lost, see `lost`).
    pub(crate) failed: u64,
    /// Of `failed`, rows that could not even be quarantined.
    pub(crate) lost: u64,
}

/// The serde name of a unit enum variant (`snake_case` / `lowercase` as the model declares),
/// so the database holds the same words as the JSON API and the IDL.
/// An issue sequence as the databases store it (a signed 64-bit integer); a sequence
/// past `i64::MAX` (never reached by a station counting from 1) saturates.
pub(crate) fn seq_column(seq: u64) -> i64 {
    i64::try_from(seq).unwrap_or(i64::MAX)
}

pub(crate) fn enum_name<T: Serialize>(value: &T) -> Result<String, serde_json::Error> {
    Ok(match serde_json::to_value(value)? {
        serde_json::Value::String(s) => s,
        other => other.to_string(),
    })
}

/// Writes one record with a cached prepared statement.
pub(crate) fn insert(conn: &Connection, record: &Record) -> Result<(), StoreError> {
    match record {
        Record::State(s) => insert_state(conn, s)?,
        Record::Vehicle(v) => {
            conn.prepare_cached(UPSERT_VEHICLE)?.execute(params![
                v.vehicle_id,
                v.name,
                enum_name(&v.kind)?,
                v.vendor,
                serde_json::to_string(&v.capabilities)?,
                serde_json::to_string(&v.sensors)?,
                serde_json::to_string(&v.links)?,
                v.max_speed_mps,
                v.timestamp_ms,
            ])?;
        }
        Record::Task(t) => {
            conn.prepare_cached(INSERT_TASK)?.execute(params![
                t.task_id,
                t.mission_id,
                t.vehicle_id,
                t.issued_ms,
                enum_name(&t.kind)?,
                serde_json::to_string(&t.area)?,
                t.depth_m,
                t.altitude_m,
                t.speed_mps,
                t.line_spacing_m,
                t.duration_s,
                t.rate_hz,
                seq_column(t.issue_seq),
                t.expires_ms,
                seq_column(t.lease_term),
                t.lease_holder,
            ])?;
        }
        Record::TaskStatus(s) => {
            conn.prepare_cached(INSERT_TASK_STATUS)?.execute(params![
                s.task_id,
                s.timestamp_ms,
                enum_name(&s.state)?,
                s.progress_pct,
                s.message,
                s.vehicle_id,
            ])?;
        }
        Record::Event(e) => {
            conn.prepare_cached(INSERT_EVENT)?.execute(params![
                e.event_id,
                e.timestamp_ms,
                enum_name(&e.severity)?,
                enum_name(&e.kind)?,
                e.vehicle_id,
                e.task_id,
                e.text,
            ])?;
        }
        Record::Observation(o) => {
            conn.prepare_cached(INSERT_OBSERVATION)?.execute(params![
                o.vehicle_id,
                o.property,
                o.timestamp_ms,
                o.value,
                o.unit,
                o.latitude_deg,
                o.longitude_deg,
                o.depth_m,
            ])?;
        }
        Record::Rejected {
            received_ms,
            topic,
            reason,
            payload_json,
        } => {
            insert_rejected(conn, *received_ms, topic, reason, payload_json)?;
        }
    }
    Ok(())
}

/// Writes one state vector; shared with the raw baseline so both run the same statement.
pub(crate) fn insert_state(
    conn: &Connection,
    s: &shoal_model::StateVector,
) -> rusqlite::Result<()> {
    conn.prepare_cached(INSERT_STATE)?.execute(params![
        s.vehicle_id,
        s.timestamp_ms,
        s.latitude_deg,
        s.longitude_deg,
        s.depth_m,
        s.altitude_m,
        s.speed_mps,
        s.yaw_deg,
        s.pitch_deg,
        s.roll_deg,
        s.battery_pct,
    ])?;
    Ok(())
}

fn insert_rejected(
    conn: &Connection,
    received_ms: i64,
    topic: &str,
    reason: &str,
    payload_json: &str,
) -> rusqlite::Result<()> {
    conn.prepare_cached(INSERT_REJECTED)?.execute(params![
        received_ms,
        topic,
        reason,
        payload_json
    ])?;
    Ok(())
}

/// Commits a batch in one transaction; if a record is at fault, commits the batch again row
/// by row with the faulty rows quarantined. An `Err` is an environment failure: nothing of
/// the batch was committed and the caller must retry it.
pub(crate) fn write_batch(conn: &mut Connection, batch: &[Record]) -> Result<Outcome, StoreError> {
    match write_all(conn, batch) {
        Ok(()) => Ok(Outcome {
            stored: batch.len() as u64,
            ..Outcome::default()
        }),
        Err(e) if e.is_data_error() => {
            debug!(error = %e, rows = batch.len(), "history batch refused; retrying row by row");
            write_one_by_one(conn, batch)
        }
        Err(e) => Err(e),
    }
}

/// The fast path: every record in one transaction; any error rolls all of it back.
///
/// State vectors go in key order (vehicle, then time): a batch of a thousand vehicles'
/// reports in arrival order jumps between a thousand leaves of the table's B-tree, one per
/// row, where key order walks them once, each vehicle's rows landing together. The sort
/// is stable, so of two reports with the same key the later still replaces the earlier,
/// and a transaction's rows become visible together whatever their order.
fn write_all(conn: &mut Connection, batch: &[Record]) -> Result<(), StoreError> {
    let tx = conn.transaction()?;
    let mut states = Vec::with_capacity(batch.len());
    for record in batch {
        match record {
            Record::State(s) => states.push(s),
            other => insert(&tx, other)?,
        }
    }
    states.sort_by(|a, b| state_key(a).cmp(&state_key(b)));
    for s in states {
        insert_state(&tx, s)?;
    }
    tx.commit()?;
    Ok(())
}

/// A state vector's primary key in the table's order.
pub(crate) fn state_key(s: &shoal_model::StateVector) -> (&str, i64) {
    (&s.vehicle_id, s.timestamp_ms)
}

/// The slow path: still one transaction, but each record under its own savepoint so a
/// faulty one is rolled back alone and replaced by a quarantine row.
fn write_one_by_one(conn: &mut Connection, batch: &[Record]) -> Result<Outcome, StoreError> {
    let mut outcome = Outcome::default();
    let mut tx = conn.transaction()?;
    for record in batch {
        let sp = tx.savepoint()?;
        match insert(&sp, record) {
            Ok(()) => {
                sp.commit()?;
                outcome.stored += 1;
            }
            Err(e) if e.is_data_error() => {
                sp.finish()?; // rolls back this record only
                outcome.failed += 1;
                if !quarantine(&tx, record, &e)? {
                    outcome.lost += 1;
                }
            }
            Err(e) => return Err(e),
        }
    }
    tx.commit()?;
    Ok(outcome)
}

/// Stores a record that failed on its own in `rejected`, with SQLite's reason. Returns
/// false when even that failed because of the record (it is then only in the log);
/// `Err` for environment failures.
fn quarantine(conn: &Connection, record: &Record, why: &StoreError) -> Result<bool, StoreError> {
    let table = record.table();
    let reason = format!("history: {why}");
    let payload = match record.payload_json() {
        Ok(p) => p,
        Err(e) => format!("{{\"unencodable\": {:?}}}", e.to_string()),
    };
    warn!(table, reason = %why, "record refused by the history store; quarantined");
    match insert_rejected(conn, shoal_model::now_ms(), table, &reason, &payload) {
        Ok(()) => Ok(true),
        Err(e) => {
            let e = StoreError::from(e);
            if e.is_data_error() {
                error!(table, reason = %why, quarantine_error = %e, payload, "record refused and could not be quarantined");
                Ok(false)
            } else {
                Err(e)
            }
        }
    }
}
