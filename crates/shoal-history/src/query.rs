//! Reading the history back, on a connection of its own: SQLite's read-only connection, or
//! PostgreSQL's query thread.
//!
//! Each query is written once, in SQL both databases accept, with SQLite's `?N`
//! placeholders; rows are decoded by one function per type through [`Fields`], which both
//! backends' rows implement.

use std::sync::{Arc, Mutex, PoisonError};

use rusqlite::Connection;
use rusqlite::types::ToSqlOutput;
use serde::de::DeserializeOwned;
use shoal_model::{
    EnvironmentObservation, Event, StateVector, TaskAssignment, TaskStatus, VehicleAnnouncement,
};

use crate::pg::reader::PgReader;
use crate::{HistoryError, RejectedRecord, TaskHistory};

const STATE_COLUMNS: &str = "vehicle_id, timestamp_ms, latitude_deg, longitude_deg, depth_m, \
    altitude_m, speed_mps, yaw_deg, pitch_deg, roll_deg, battery_pct";

/// Queries on the history; cheap to clone and usable from any thread.
///
/// One read connection, taking turns: queries are occasional (console, warm-up after a
/// restart) and short. On SQLite it is a read-only connection behind a mutex, which in WAL
/// mode never blocks the writer; on PostgreSQL it is a connection owned by a query thread.
/// Either way queries see only committed data.
#[derive(Debug, Clone)]
pub struct HistoryReader {
    conn: Arc<ReadConn>,
}

/// The reader's connection, by backend.
#[derive(Debug)]
enum ReadConn {
    Sqlite(Mutex<Connection>),
    Postgres(PgReader),
}

/// A query parameter; owned, so that it can travel to PostgreSQL's query thread.
#[derive(Debug, Clone)]
pub(crate) enum Param {
    /// A text value.
    Text(String),
    /// An integer value (`INTEGER` / `BIGINT`).
    Int(i64),
}

impl Param {
    /// The value as a PostgreSQL parameter.
    pub(crate) fn as_pg(&self) -> &(dyn tokio_postgres::types::ToSql + Sync) {
        match self {
            Self::Text(s) => s,
            Self::Int(i) => i,
        }
    }
}

impl From<&str> for Param {
    fn from(s: &str) -> Self {
        Self::Text(s.to_owned())
    }
}

impl From<i64> for Param {
    fn from(i: i64) -> Self {
        Self::Int(i)
    }
}

impl rusqlite::ToSql for Param {
    fn to_sql(&self) -> rusqlite::Result<ToSqlOutput<'_>> {
        match self {
            Self::Text(s) => s.to_sql(),
            Self::Int(i) => i.to_sql(),
        }
    }
}

/// The columns of a result row, whichever backend it came from.
pub(crate) trait Fields {
    /// A text column.
    fn text(&self, idx: usize) -> Result<String, HistoryError>;
    /// An integer column.
    fn int(&self, idx: usize) -> Result<i64, HistoryError>;
    /// A floating-point column.
    fn real(&self, idx: usize) -> Result<f64, HistoryError>;
}

impl Fields for rusqlite::Row<'_> {
    fn text(&self, idx: usize) -> Result<String, HistoryError> {
        Ok(self.get(idx)?)
    }
    fn int(&self, idx: usize) -> Result<i64, HistoryError> {
        Ok(self.get(idx)?)
    }
    fn real(&self, idx: usize) -> Result<f64, HistoryError> {
        Ok(self.get(idx)?)
    }
}

impl Fields for tokio_postgres::Row {
    fn text(&self, idx: usize) -> Result<String, HistoryError> {
        Ok(self.try_get(idx)?)
    }
    fn int(&self, idx: usize) -> Result<i64, HistoryError> {
        Ok(self.try_get(idx)?)
    }
    fn real(&self, idx: usize) -> Result<f64, HistoryError> {
        Ok(self.try_get(idx)?)
    }
}

/// Decodes one row into a value.
type Decode<T> = fn(&dyn Fields) -> Result<T, HistoryError>;

/// A `usize` limit as SQL's integer; anything beyond `i64::MAX` means "no limit" anyway.
fn sql_limit(limit: usize) -> Param {
    Param::Int(i64::try_from(limit).unwrap_or(i64::MAX))
}

/// Decodes a text column holding a serde enum name or a JSON document.
fn json_column<T: DeserializeOwned>(
    row: &dyn Fields,
    idx: usize,
    is_name: bool,
) -> Result<T, HistoryError> {
    let text = row.text(idx)?;
    let decoded = if is_name {
        serde_json::from_value(serde_json::Value::String(text))
    } else {
        serde_json::from_str(&text)
    };
    decoded.map_err(|source| HistoryError::Decode {
        column: idx,
        source,
    })
}

fn state_row(r: &dyn Fields) -> Result<StateVector, HistoryError> {
    Ok(StateVector {
        vehicle_id: r.text(0)?,
        timestamp_ms: r.int(1)?,
        latitude_deg: r.real(2)?,
        longitude_deg: r.real(3)?,
        depth_m: r.real(4)?,
        altitude_m: r.real(5)?,
        speed_mps: r.real(6)?,
        yaw_deg: r.real(7)?,
        pitch_deg: r.real(8)?,
        roll_deg: r.real(9)?,
        battery_pct: r.real(10)?,
    })
}

fn vehicle_row(r: &dyn Fields) -> Result<VehicleAnnouncement, HistoryError> {
    Ok(VehicleAnnouncement {
        vehicle_id: r.text(0)?,
        name: r.text(1)?,
        kind: json_column(r, 2, true)?,
        vendor: r.text(3)?,
        capabilities: json_column(r, 4, false)?,
        sensors: json_column(r, 5, false)?,
        links: json_column(r, 6, false)?,
        max_speed_mps: r.real(7)?,
        timestamp_ms: r.int(8)?,
    })
}

fn task_row(r: &dyn Fields) -> Result<TaskAssignment, HistoryError> {
    Ok(TaskAssignment {
        task_id: r.text(0)?,
        mission_id: r.text(1)?,
        vehicle_id: r.text(2)?,
        issued_ms: r.int(3)?,
        kind: json_column(r, 4, true)?,
        area: json_column(r, 5, false)?,
        depth_m: r.real(6)?,
        altitude_m: r.real(7)?,
        speed_mps: r.real(8)?,
        line_spacing_m: r.real(9)?,
        duration_s: r.real(10)?,
        rate_hz: r.real(11)?,
        // The schema refuses negative sequences.
        issue_seq: u64::try_from(r.int(12)?).unwrap_or(0),
        expires_ms: r.int(13)?,
        lease_term: u64::try_from(r.int(14)?).unwrap_or(0),
        lease_holder: r.text(15)?,
    })
}

fn task_status_row(r: &dyn Fields) -> Result<TaskStatus, HistoryError> {
    Ok(TaskStatus {
        task_id: r.text(0)?,
        timestamp_ms: r.int(1)?,
        state: json_column(r, 2, true)?,
        progress_pct: r.real(3)?,
        message: r.text(4)?,
        vehicle_id: r.text(5)?,
    })
}

fn event_row(r: &dyn Fields) -> Result<Event, HistoryError> {
    Ok(Event {
        event_id: r.text(0)?,
        timestamp_ms: r.int(1)?,
        severity: json_column(r, 2, true)?,
        kind: json_column(r, 3, true)?,
        vehicle_id: r.text(4)?,
        task_id: r.text(5)?,
        text: r.text(6)?,
    })
}

fn observation_row(r: &dyn Fields) -> Result<EnvironmentObservation, HistoryError> {
    Ok(EnvironmentObservation {
        vehicle_id: r.text(0)?,
        property: r.text(1)?,
        timestamp_ms: r.int(2)?,
        value: r.real(3)?,
        unit: r.text(4)?,
        latitude_deg: r.real(5)?,
        longitude_deg: r.real(6)?,
        depth_m: r.real(7)?,
    })
}

fn rejected_row(r: &dyn Fields) -> Result<RejectedRecord, HistoryError> {
    Ok(RejectedRecord {
        id: r.int(0)?,
        received_ms: r.int(1)?,
        topic: r.text(2)?,
        reason: r.text(3)?,
        payload_json: r.text(4)?,
    })
}

fn count_row(r: &dyn Fields) -> Result<i64, HistoryError> {
    r.int(0)
}

impl HistoryReader {
    pub(crate) fn sqlite(conn: Connection) -> Self {
        Self {
            conn: Arc::new(ReadConn::Sqlite(Mutex::new(conn))),
        }
    }

    pub(crate) fn postgres(reader: PgReader) -> Self {
        Self {
            conn: Arc::new(ReadConn::Postgres(reader)),
        }
    }

    /// Runs `sql` with `params` and collects the rows decoded by `decode`.
    fn collect<T: Send + 'static>(
        &self,
        sql: &str,
        params: Vec<Param>,
        decode: Decode<T>,
    ) -> Result<Vec<T>, HistoryError> {
        match &*self.conn {
            ReadConn::Sqlite(conn) => {
                // A panic in another query leaves the connection usable: statements are
                // scoped.
                let conn = conn.lock().unwrap_or_else(PoisonError::into_inner);
                let mut stmt = conn.prepare_cached(sql)?;
                let mut rows = stmt.query(rusqlite::params_from_iter(params.iter()))?;
                let mut out = Vec::new();
                while let Some(row) = rows.next()? {
                    out.push(decode(row)?);
                }
                Ok(out)
            }
            ReadConn::Postgres(reader) => {
                let sql = sql.to_owned();
                reader.call(move |session| {
                    session
                        .query(&sql, &params)?
                        .iter()
                        .map(|row| decode(row))
                        .collect()
                })
            }
        }
    }

    /// A vehicle's state vectors with `from_ms <= timestamp_ms <= to_ms`, oldest first, at
    /// most `limit` of them (the oldest ones).
    pub fn track(
        &self,
        vehicle_id: &str,
        from_ms: i64,
        to_ms: i64,
        limit: usize,
    ) -> Result<Vec<StateVector>, HistoryError> {
        let sql = format!(
            "SELECT {STATE_COLUMNS} FROM state_vector \
             WHERE vehicle_id = ?1 AND timestamp_ms BETWEEN ?2 AND ?3 \
             ORDER BY timestamp_ms LIMIT ?4"
        );
        self.collect(
            &sql,
            vec![
                vehicle_id.into(),
                from_ms.into(),
                to_ms.into(),
                sql_limit(limit),
            ],
            state_row,
        )
    }

    /// The highest issue sequence any stored task carries (0 when none does): where a
    /// restarted station's sequence continues, so it never repeats one.
    pub fn max_issue_seq(&self) -> Result<u64, HistoryError> {
        let max = self.collect(
            "SELECT coalesce(max(issue_seq), 0) FROM task_assignment",
            vec![],
            count_row,
        )?;
        Ok(max.first().map_or(0, |n| u64::try_from(*n).unwrap_or(0)))
    }

    /// How many state vectors are stored, for one vehicle or for all.
    pub fn count_states(&self, vehicle_id: Option<&str>) -> Result<u64, HistoryError> {
        let counts = match vehicle_id {
            Some(v) => self.collect(
                "SELECT count(*) FROM state_vector WHERE vehicle_id = ?1",
                vec![v.into()],
                count_row,
            )?,
            None => self.collect("SELECT count(*) FROM state_vector", vec![], count_row)?,
        };
        let n = counts.first().copied().unwrap_or(0);
        Ok(u64::try_from(n).unwrap_or(0))
    }

    /// The newest state vector of every vehicle, by vehicle id; used to warm up the
    /// station's registers after a restart.
    pub fn latest_states(&self) -> Result<Vec<StateVector>, HistoryError> {
        // A `GROUP BY vehicle_id` would scan the whole table. The recursive CTE instead hops
        // from one vehicle id to the next through the primary key, and takes each vehicle's
        // newest row with one more lookup: O(vehicles × log rows), whatever the history size.
        // (Both databases plan it that way: it is PostgreSQL's "loose index scan" idiom.)
        let sql = format!(
            "WITH RECURSIVE v(id) AS ( \
                 SELECT min(vehicle_id) FROM state_vector \
                 UNION ALL \
                 SELECT (SELECT min(vehicle_id) FROM state_vector WHERE vehicle_id > v.id) \
                 FROM v WHERE v.id IS NOT NULL) \
             SELECT {STATE_COLUMNS} FROM v JOIN state_vector s ON s.vehicle_id = v.id \
             AND s.timestamp_ms = ( \
                 SELECT max(timestamp_ms) FROM state_vector WHERE vehicle_id = v.id) \
             ORDER BY s.vehicle_id"
        );
        self.collect(&sql, vec![], state_row)
    }

    /// Every vehicle ever announced, with the fields of its newest announcement, by id.
    pub fn vehicles(&self) -> Result<Vec<VehicleAnnouncement>, HistoryError> {
        self.collect(
            "SELECT vehicle_id, name, kind, vendor, capabilities, sensors, links, \
             max_speed_mps, last_seen_ms FROM vehicle ORDER BY vehicle_id",
            vec![],
            vehicle_row,
        )
    }

    /// Events with `timestamp_ms >= since_ms`, oldest first, at most `limit`.
    pub fn events(&self, since_ms: i64, limit: usize) -> Result<Vec<Event>, HistoryError> {
        self.collect(
            "SELECT event_id, timestamp_ms, severity, kind, vehicle_id, task_id, text \
             FROM event WHERE timestamp_ms >= ?1 ORDER BY timestamp_ms, event_id LIMIT ?2",
            vec![since_ms.into(), sql_limit(limit)],
            event_row,
        )
    }

    /// A task's assignment and its status reports, oldest first (reports of the same
    /// millisecond in life-cycle order).
    pub fn task_history(&self, task_id: &str) -> Result<TaskHistory, HistoryError> {
        let assignment = self
            .collect(
                "SELECT task_id, mission_id, vehicle_id, issued_ms, kind, area, depth_m, \
                 altitude_m, speed_mps, line_spacing_m, duration_s, rate_hz, issue_seq, \
                 expires_ms, lease_term, lease_holder FROM task_assignment WHERE task_id = ?1",
                vec![task_id.into()],
                task_row,
            )?
            .into_iter()
            .next();
        let statuses = self.collect(
            "SELECT task_id, timestamp_ms, state, progress_pct, message, vehicle_id \
             FROM task_status WHERE task_id = ?1 ORDER BY timestamp_ms, \
             CASE state WHEN 'pending' THEN 0 WHEN 'sent' THEN 1 WHEN 'accepted' THEN 2 \
             WHEN 'running' THEN 3 ELSE 4 END, state",
            vec![task_id.into()],
            task_status_row,
        )?;
        Ok(TaskHistory {
            assignment,
            statuses,
        })
    }

    /// Tasks issued at or after `since_ms` (at most `limit`, the oldest first), each with
    /// its status reports in life-cycle order: what a restarted station reloads.
    pub fn tasks_since(
        &self,
        since_ms: i64,
        limit: usize,
    ) -> Result<Vec<TaskHistory>, HistoryError> {
        let assignments = self.collect(
            "SELECT task_id, mission_id, vehicle_id, issued_ms, kind, area, depth_m, \
             altitude_m, speed_mps, line_spacing_m, duration_s, rate_hz, issue_seq, expires_ms, \
             lease_term, lease_holder FROM task_assignment WHERE issued_ms >= ?1 ORDER BY issued_ms, task_id LIMIT ?2",
            vec![since_ms.into(), sql_limit(limit)],
            task_row,
        )?;
        let statuses = self.collect(
            "SELECT s.task_id, s.timestamp_ms, s.state, s.progress_pct, s.message, s.vehicle_id \
             FROM task_status s JOIN task_assignment a ON a.task_id = s.task_id \
             WHERE a.issued_ms >= ?1 ORDER BY s.task_id, s.timestamp_ms, \
             CASE s.state WHEN 'pending' THEN 0 WHEN 'sent' THEN 1 WHEN 'accepted' THEN 2 \
             WHEN 'running' THEN 3 ELSE 4 END, s.state",
            vec![since_ms.into()],
            task_status_row,
        )?;
        let mut by_task: std::collections::HashMap<String, Vec<TaskStatus>> =
            std::collections::HashMap::new();
        for s in statuses {
            by_task.entry(s.task_id.clone()).or_default().push(s);
        }
        Ok(assignments
            .into_iter()
            .map(|a| TaskHistory {
                statuses: by_task.remove(&a.task_id).unwrap_or_default(),
                assignment: Some(a),
            })
            .collect())
    }

    /// A vehicle's observations of one property with `from_ms <= timestamp_ms <= to_ms`,
    /// oldest first, at most `limit`.
    pub fn observations(
        &self,
        vehicle_id: &str,
        property: &str,
        from_ms: i64,
        to_ms: i64,
        limit: usize,
    ) -> Result<Vec<EnvironmentObservation>, HistoryError> {
        self.collect(
            "SELECT vehicle_id, property, timestamp_ms, value, unit, latitude_deg, \
             longitude_deg, depth_m FROM observation \
             WHERE vehicle_id = ?1 AND property = ?2 AND timestamp_ms BETWEEN ?3 AND ?4 \
             ORDER BY timestamp_ms LIMIT ?5",
            vec![
                vehicle_id.into(),
                property.into(),
                from_ms.into(),
                to_ms.into(),
                sql_limit(limit),
            ],
            observation_row,
        )
    }

    /// The newest `limit` quarantined records, newest first.
    pub fn rejected(&self, limit: usize) -> Result<Vec<RejectedRecord>, HistoryError> {
        self.collect(
            "SELECT id, received_ms, topic, reason, payload_json FROM rejected \
             ORDER BY id DESC LIMIT ?1",
            vec![sql_limit(limit)],
            rejected_row,
        )
    }
}

#[cfg(test)]
impl HistoryReader {
    /// The first column of every row of `sql` as text, for tests that look at stored
    /// columns on either backend.
    pub(crate) fn texts_for_tests(&self, sql: &str) -> Result<Vec<String>, HistoryError> {
        self.collect(sql, vec![], |r| r.text(0))
    }

    /// The first column of every row of `sql` as an integer.
    pub(crate) fn ints_for_tests(&self, sql: &str) -> Result<Vec<i64>, HistoryError> {
        self.collect(sql, vec![], |r| r.int(0))
    }
}
