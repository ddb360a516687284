//! Reading the history back, on a read-only connection of its own.

use std::sync::{Arc, Mutex, MutexGuard, PoisonError};

use rusqlite::types::Type;
use rusqlite::{Connection, OptionalExtension, Row, params};
use serde::de::DeserializeOwned;
use shoal_model::{
    EnvironmentObservation, Event, StateVector, TaskAssignment, TaskStatus, VehicleAnnouncement,
};

use crate::{HistoryError, RejectedRecord, TaskHistory};

const STATE_COLUMNS: &str = "vehicle_id, timestamp_ms, latitude_deg, longitude_deg, depth_m, \
    altitude_m, speed_mps, yaw_deg, pitch_deg, roll_deg, battery_pct";

/// Queries on the history; cheap to clone and usable from any thread.
///
/// One read-only connection behind a mutex: queries are occasional (console, warm-up after a
/// restart) and short, so they take turns. In WAL mode they never block the writer, and
/// they see only committed data.
#[derive(Debug, Clone)]
pub struct HistoryReader {
    conn: Arc<Mutex<Connection>>,
}

/// A `usize` limit as SQLite's integer; anything beyond `i64::MAX` means "no limit" anyway.
fn sql_limit(limit: usize) -> i64 {
    i64::try_from(limit).unwrap_or(i64::MAX)
}

/// Decodes a text column holding a serde enum name or a JSON document.
fn json_column<T: DeserializeOwned>(
    row: &Row<'_>,
    idx: usize,
    is_name: bool,
) -> rusqlite::Result<T> {
    let text: String = row.get(idx)?;
    let decoded = if is_name {
        serde_json::from_value(serde_json::Value::String(text))
    } else {
        serde_json::from_str(&text)
    };
    decoded.map_err(|e| rusqlite::Error::FromSqlConversionFailure(idx, Type::Text, Box::new(e)))
}

fn state_row(r: &Row<'_>) -> rusqlite::Result<StateVector> {
    Ok(StateVector {
        vehicle_id: r.get(0)?,
        timestamp_ms: r.get(1)?,
        latitude_deg: r.get(2)?,
        longitude_deg: r.get(3)?,
        depth_m: r.get(4)?,
        altitude_m: r.get(5)?,
        speed_mps: r.get(6)?,
        yaw_deg: r.get(7)?,
        pitch_deg: r.get(8)?,
        roll_deg: r.get(9)?,
        battery_pct: r.get(10)?,
    })
}

fn vehicle_row(r: &Row<'_>) -> rusqlite::Result<VehicleAnnouncement> {
    Ok(VehicleAnnouncement {
        vehicle_id: r.get(0)?,
        name: r.get(1)?,
        kind: json_column(r, 2, true)?,
        vendor: r.get(3)?,
        capabilities: json_column(r, 4, false)?,
        sensors: json_column(r, 5, false)?,
        links: json_column(r, 6, false)?,
        max_speed_mps: r.get(7)?,
        timestamp_ms: r.get(8)?,
    })
}

fn task_row(r: &Row<'_>) -> rusqlite::Result<TaskAssignment> {
    Ok(TaskAssignment {
        task_id: r.get(0)?,
        mission_id: r.get(1)?,
        vehicle_id: r.get(2)?,
        issued_ms: r.get(3)?,
        kind: json_column(r, 4, true)?,
        area: json_column(r, 5, false)?,
        depth_m: r.get(6)?,
        altitude_m: r.get(7)?,
        speed_mps: r.get(8)?,
        line_spacing_m: r.get(9)?,
        duration_s: r.get(10)?,
        rate_hz: r.get(11)?,
    })
}

fn task_status_row(r: &Row<'_>) -> rusqlite::Result<TaskStatus> {
    Ok(TaskStatus {
        task_id: r.get(0)?,
        timestamp_ms: r.get(1)?,
        state: json_column(r, 2, true)?,
        progress_pct: r.get(3)?,
        message: r.get(4)?,
        vehicle_id: r.get(5)?,
    })
}

fn event_row(r: &Row<'_>) -> rusqlite::Result<Event> {
    Ok(Event {
        event_id: r.get(0)?,
        timestamp_ms: r.get(1)?,
        severity: json_column(r, 2, true)?,
        kind: json_column(r, 3, true)?,
        vehicle_id: r.get(4)?,
        task_id: r.get(5)?,
        text: r.get(6)?,
    })
}

fn observation_row(r: &Row<'_>) -> rusqlite::Result<EnvironmentObservation> {
    Ok(EnvironmentObservation {
        vehicle_id: r.get(0)?,
        property: r.get(1)?,
        timestamp_ms: r.get(2)?,
        value: r.get(3)?,
        unit: r.get(4)?,
        latitude_deg: r.get(5)?,
        longitude_deg: r.get(6)?,
        depth_m: r.get(7)?,
    })
}

impl HistoryReader {
    pub(crate) fn new(conn: Connection) -> Self {
        Self {
            conn: Arc::new(Mutex::new(conn)),
        }
    }

    fn conn(&self) -> MutexGuard<'_, Connection> {
        // A panic in another query leaves the connection usable: statements are scoped.
        self.conn.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Runs `sql` with `params` and collects the rows decoded by `row`.
    fn collect<T, P: rusqlite::Params>(
        &self,
        sql: &str,
        params: P,
        row: fn(&Row<'_>) -> rusqlite::Result<T>,
    ) -> Result<Vec<T>, HistoryError> {
        let conn = self.conn();
        let mut stmt = conn.prepare_cached(sql)?;
        let rows = stmt.query_map(params, row)?;
        Ok(rows.collect::<Result<Vec<_>, _>>()?)
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
            params![vehicle_id, from_ms, to_ms, sql_limit(limit)],
            state_row,
        )
    }

    /// How many state vectors are stored, for one vehicle or for all.
    pub fn count_states(&self, vehicle_id: Option<&str>) -> Result<u64, HistoryError> {
        let conn = self.conn();
        let n: i64 = match vehicle_id {
            Some(v) => conn.query_row(
                "SELECT count(*) FROM state_vector WHERE vehicle_id = ?1",
                [v],
                |r| r.get(0),
            )?,
            None => conn.query_row("SELECT count(*) FROM state_vector", [], |r| r.get(0))?,
        };
        Ok(u64::try_from(n).unwrap_or(0))
    }

    /// The newest state vector of every vehicle, by vehicle id; used to warm up the
    /// station's registers after a restart.
    pub fn latest_states(&self) -> Result<Vec<StateVector>, HistoryError> {
        // A `GROUP BY vehicle_id` would scan the whole table. The recursive CTE instead hops
        // from one vehicle id to the next through the primary key, and takes each vehicle's
        // newest row with one more lookup: O(vehicles × log rows), whatever the history size.
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
        self.collect(&sql, [], state_row)
    }

    /// Every vehicle ever announced, with the fields of its newest announcement, by id.
    pub fn vehicles(&self) -> Result<Vec<VehicleAnnouncement>, HistoryError> {
        self.collect(
            "SELECT vehicle_id, name, kind, vendor, capabilities, sensors, links, \
             max_speed_mps, last_seen_ms FROM vehicle ORDER BY vehicle_id",
            [],
            vehicle_row,
        )
    }

    /// Events with `timestamp_ms >= since_ms`, oldest first, at most `limit`.
    pub fn events(&self, since_ms: i64, limit: usize) -> Result<Vec<Event>, HistoryError> {
        self.collect(
            "SELECT event_id, timestamp_ms, severity, kind, vehicle_id, task_id, text \
             FROM event WHERE timestamp_ms >= ?1 ORDER BY timestamp_ms, event_id LIMIT ?2",
            params![since_ms, sql_limit(limit)],
            event_row,
        )
    }

    /// A task's assignment and its status reports, oldest first (reports of the same
    /// millisecond in life-cycle order).
    pub fn task_history(&self, task_id: &str) -> Result<TaskHistory, HistoryError> {
        let assignment = {
            let conn = self.conn();
            conn.prepare_cached(
                "SELECT task_id, mission_id, vehicle_id, issued_ms, kind, area, depth_m, \
                 altitude_m, speed_mps, line_spacing_m, duration_s, rate_hz \
                 FROM task_assignment WHERE task_id = ?1",
            )?
            .query_row([task_id], task_row)
            .optional()?
        };
        let statuses = self.collect(
            "SELECT task_id, timestamp_ms, state, progress_pct, message, vehicle_id \
             FROM task_status WHERE task_id = ?1 ORDER BY timestamp_ms, \
             CASE state WHEN 'pending' THEN 0 WHEN 'sent' THEN 1 WHEN 'accepted' THEN 2 \
             WHEN 'running' THEN 3 ELSE 4 END, state",
            [task_id],
            task_status_row,
        )?;
        Ok(TaskHistory {
            assignment,
            statuses,
        })
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
            params![vehicle_id, property, from_ms, to_ms, sql_limit(limit)],
            observation_row,
        )
    }

    /// The newest `limit` quarantined records, newest first.
    pub fn rejected(&self, limit: usize) -> Result<Vec<RejectedRecord>, HistoryError> {
        self.collect(
            "SELECT id, received_ms, topic, reason, payload_json FROM rejected \
             ORDER BY id DESC LIMIT ?1",
            [sql_limit(limit)],
            |r| {
                Ok(RejectedRecord {
                    id: r.get(0)?,
                    received_ms: r.get(1)?,
                    topic: r.get(2)?,
                    reason: r.get(3)?,
                    payload_json: r.get(4)?,
                })
            },
        )
    }
}

#[cfg(test)]
impl HistoryReader {
    /// The raw connection, for tests that look at stored columns.
    pub(crate) fn conn_for_tests(&self) -> MutexGuard<'_, Connection> {
        self.conn()
    }
}
