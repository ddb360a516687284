//! Writing records to PostgreSQL: one statement per table per batch, and the same per-row
//! fallback as on SQLite.
//!
//! The upsert rules are SQLite's (see `crate::store`): the later record wins a key, and a
//! vehicle keeps the fields of its newest announcement with first/last seen widened. For
//! speed, each keyed table gets the whole batch in one `INSERT ... SELECT FROM unnest(...)`
//! of column arrays: one round trip and one statement per table and batch, prepared once
//! per connection. `ON CONFLICT DO UPDATE` refuses to touch a row twice in one statement,
//! so the arrays hold each key once, with the batch's last record for it: exactly the row
//! that a record-by-record upsert would have left. Vehicles are rare and their merge rule
//! compares with the stored row, so they go one statement per announcement, in order.

use std::collections::HashMap;
use std::collections::hash_map::Entry;
use std::hash::Hash;
use std::time::Duration;

use shoal_model::{EnvironmentObservation, Event, StateVector, TaskAssignment, TaskStatus};
use tokio::runtime::Runtime;
use tokio_postgres::types::ToSql;
use tokio_postgres::{Client, Statement, Transaction};
use tracing::{debug, error, warn};

use super::reader::placeholders;
use super::{Conn, Target, schema};
use crate::backend::FromRow;
use crate::error::pg_text;
use crate::query::Param;
use crate::store::{Outcome, StoreError, enum_name};
use crate::{HistoryError, Record};

/// Longest a batch may take before the connection is presumed dead: without it, a server
/// that stops answering (without closing the socket) would hang the writer, and `close`,
/// for good. The batch is then retried on a new connection; nothing was acknowledged.
const BATCH_TIMEOUT: Duration = Duration::from_secs(120);

const UPSERT_STATE: &str = "INSERT INTO state_vector (vehicle_id, timestamp_ms, latitude_deg, \
    longitude_deg, depth_m, altitude_m, speed_mps, yaw_deg, pitch_deg, roll_deg, battery_pct) \
    SELECT * FROM unnest($1::text[], $2::int8[], $3::float8[], $4::float8[], $5::float8[], \
    $6::float8[], $7::float8[], $8::float8[], $9::float8[], $10::float8[], $11::float8[]) \
    ON CONFLICT (vehicle_id, timestamp_ms) DO UPDATE SET \
    latitude_deg = excluded.latitude_deg, longitude_deg = excluded.longitude_deg, \
    depth_m = excluded.depth_m, altitude_m = excluded.altitude_m, \
    speed_mps = excluded.speed_mps, yaw_deg = excluded.yaw_deg, pitch_deg = excluded.pitch_deg, \
    roll_deg = excluded.roll_deg, battery_pct = excluded.battery_pct";

// SQLite's rule (see `crate::store::UPSERT_VEHICLE`): each field from the newer
// announcement, first/last seen widened. In the SET list, `vehicle.*` is the stored row as
// it was before this statement.
const UPSERT_VEHICLE: &str = "INSERT INTO vehicle (vehicle_id, name, kind, vendor, \
    capabilities, sensors, links, max_speed_mps, first_seen_ms, last_seen_ms) \
    VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $9) \
    ON CONFLICT (vehicle_id) DO UPDATE SET \
    name = CASE WHEN excluded.last_seen_ms >= vehicle.last_seen_ms \
        THEN excluded.name ELSE vehicle.name END, \
    kind = CASE WHEN excluded.last_seen_ms >= vehicle.last_seen_ms \
        THEN excluded.kind ELSE vehicle.kind END, \
    vendor = CASE WHEN excluded.last_seen_ms >= vehicle.last_seen_ms \
        THEN excluded.vendor ELSE vehicle.vendor END, \
    capabilities = CASE WHEN excluded.last_seen_ms >= vehicle.last_seen_ms \
        THEN excluded.capabilities ELSE vehicle.capabilities END, \
    sensors = CASE WHEN excluded.last_seen_ms >= vehicle.last_seen_ms \
        THEN excluded.sensors ELSE vehicle.sensors END, \
    links = CASE WHEN excluded.last_seen_ms >= vehicle.last_seen_ms \
        THEN excluded.links ELSE vehicle.links END, \
    max_speed_mps = CASE WHEN excluded.last_seen_ms >= vehicle.last_seen_ms \
        THEN excluded.max_speed_mps ELSE vehicle.max_speed_mps END, \
    first_seen_ms = least(vehicle.first_seen_ms, excluded.first_seen_ms), \
    last_seen_ms = greatest(vehicle.last_seen_ms, excluded.last_seen_ms)";

const UPSERT_TASK: &str = "INSERT INTO task_assignment (task_id, mission_id, vehicle_id, \
    issued_ms, kind, area, depth_m, altitude_m, speed_mps, line_spacing_m, duration_s, rate_hz, \
    issue_seq, expires_ms, lease_term, lease_holder) \
    SELECT * FROM unnest($1::text[], $2::text[], $3::text[], $4::int8[], $5::text[], \
    $6::text[], $7::float8[], $8::float8[], $9::float8[], $10::float8[], $11::float8[], \
    $12::float8[], $13::int8[], $14::int8[], $15::int8[], $16::text[]) \
    ON CONFLICT (task_id) DO UPDATE SET mission_id = excluded.mission_id, \
    vehicle_id = excluded.vehicle_id, issued_ms = excluded.issued_ms, kind = excluded.kind, \
    area = excluded.area, depth_m = excluded.depth_m, altitude_m = excluded.altitude_m, \
    speed_mps = excluded.speed_mps, line_spacing_m = excluded.line_spacing_m, \
    duration_s = excluded.duration_s, rate_hz = excluded.rate_hz, \
    issue_seq = excluded.issue_seq, expires_ms = excluded.expires_ms, \
    lease_term = excluded.lease_term, lease_holder = excluded.lease_holder";

const UPSERT_TASK_STATUS: &str = "INSERT INTO task_status (task_id, timestamp_ms, state, \
    progress_pct, message, vehicle_id) \
    SELECT * FROM unnest($1::text[], $2::int8[], $3::text[], $4::float8[], $5::text[], \
    $6::text[]) \
    ON CONFLICT (task_id, timestamp_ms, state) DO UPDATE SET \
    progress_pct = excluded.progress_pct, message = excluded.message, \
    vehicle_id = excluded.vehicle_id";

const UPSERT_EVENT: &str = "INSERT INTO event (event_id, timestamp_ms, severity, kind, \
    vehicle_id, task_id, text) \
    SELECT * FROM unnest($1::text[], $2::int8[], $3::text[], $4::text[], $5::text[], \
    $6::text[], $7::text[]) \
    ON CONFLICT (event_id) DO UPDATE SET timestamp_ms = excluded.timestamp_ms, \
    severity = excluded.severity, kind = excluded.kind, vehicle_id = excluded.vehicle_id, \
    task_id = excluded.task_id, text = excluded.text";

const UPSERT_OBSERVATION: &str = "INSERT INTO observation (vehicle_id, property, \
    timestamp_ms, value, unit, latitude_deg, longitude_deg, depth_m) \
    SELECT * FROM unnest($1::text[], $2::text[], $3::int8[], $4::float8[], $5::text[], \
    $6::float8[], $7::float8[], $8::float8[]) \
    ON CONFLICT (vehicle_id, property, timestamp_ms) DO UPDATE SET value = excluded.value, \
    unit = excluded.unit, latitude_deg = excluded.latitude_deg, \
    longitude_deg = excluded.longitude_deg, depth_m = excluded.depth_m";

// Ordered by position so that ids follow submission order, as SQLite's rowids do.
const INSERT_REJECTED: &str = "INSERT INTO rejected (received_ms, topic, reason, payload_json) \
    SELECT r, t, w, p FROM unnest($1::int8[], $2::text[], $3::text[], $4::text[]) \
    WITH ORDINALITY AS u (r, t, w, p, n) ORDER BY n";

/// The writer's prepared statements, one per table.
#[derive(Debug)]
struct Statements {
    state: Statement,
    vehicle: Statement,
    task: Statement,
    task_status: Statement,
    event: Statement,
    observation: Statement,
    rejected: Statement,
}

impl Statements {
    async fn prepare(client: &Client) -> Result<Self, tokio_postgres::Error> {
        Ok(Self {
            state: client.prepare(UPSERT_STATE).await?,
            vehicle: client.prepare(UPSERT_VEHICLE).await?,
            task: client.prepare(UPSERT_TASK).await?,
            task_status: client.prepare(UPSERT_TASK_STATUS).await?,
            event: client.prepare(UPSERT_EVENT).await?,
            observation: client.prepare(UPSERT_OBSERVATION).await?,
            rejected: client.prepare(INSERT_REJECTED).await?,
        })
    }
}

/// A connection with the writer's statements prepared on it.
#[derive(Debug)]
struct Session {
    conn: Conn,
    statements: Statements,
}

impl Session {
    /// Connects, runs `setup` (e.g. the migration), and prepares the statements; a
    /// connection that fails half-way is closed properly.
    async fn open<E, F>(target: &Target, setup: F) -> Result<Self, E>
    where
        E: From<tokio_postgres::Error>,
        F: AsyncFnOnce(&mut Conn) -> Result<(), E>,
    {
        let mut conn = Conn::open(target).await?;
        let ready = match setup(&mut conn).await {
            Ok(()) => Statements::prepare(&conn.client).await.map_err(E::from),
            Err(e) => Err(e),
        };
        match ready {
            Ok(statements) => Ok(Self { conn, statements }),
            Err(e) => {
                conn.close().await;
                Err(e)
            }
        }
    }
}

/// The writer thread's PostgreSQL connection, with its runtime; reconnects after
/// environment failures.
#[derive(Debug)]
pub(crate) struct PgWriter {
    runtime: Runtime,
    target: Target,
    /// `None` after a failure: the next attempt starts on a fresh connection.
    session: Option<Session>,
}

impl PgWriter {
    /// Connects, creates or migrates the schema, and prepares the statements. Call on the
    /// writer thread: the runtime must never be entered from a caller's thread.
    pub(crate) fn open(target: Target) -> Result<Self, HistoryError> {
        let runtime = super::runtime()?;
        let session = runtime.block_on(Session::open(&target, async |conn: &mut Conn| {
            schema::migrate(&mut conn.client, target.schema()).await
        }))?;
        Ok(Self {
            runtime,
            target,
            session: Some(session),
        })
    }

    /// Commits a batch like `crate::store::write_batch`: `Err` is an environment failure,
    /// and nothing of the batch was committed.
    pub(crate) fn write_batch(&mut self, batch: &[Record]) -> Result<Outcome, StoreError> {
        self.run(async |s: &mut Session| write_batch(s, batch).await)
    }

    /// Runs one maintenance statement (SQLite-style placeholders) on its own, returning the
    /// rows it changed.
    pub(crate) fn execute(&mut self, sql: &str, params: &[Param]) -> Result<u64, StoreError> {
        let sql = placeholders(sql);
        let params: Vec<&(dyn ToSql + Sync)> = params.iter().map(Param::as_pg).collect();
        self.run(async |s: &mut Session| Ok(s.conn.client.execute(sql.as_str(), &params).await?))
    }

    /// Runs one maintenance query (SQLite-style placeholders) and decodes its rows.
    pub(crate) fn query<T: FromRow>(
        &mut self,
        sql: &str,
        params: &[Param],
    ) -> Result<Vec<T>, StoreError> {
        let sql = placeholders(sql);
        let params: Vec<&(dyn ToSql + Sync)> = params.iter().map(Param::as_pg).collect();
        self.run(async |s: &mut Session| {
            let rows = s.conn.client.query(sql.as_str(), &params).await?;
            Ok(rows
                .iter()
                .map(T::postgres)
                .collect::<Result<Vec<T>, _>>()?)
        })
    }

    /// Runs `job` on the session (connecting first if the last one broke), within
    /// [`BATCH_TIMEOUT`]; any failure ends the session.
    fn run<T>(
        &mut self,
        job: impl AsyncFnOnce(&mut Session) -> Result<T, StoreError>,
    ) -> Result<T, StoreError> {
        let Self {
            runtime,
            target,
            session,
        } = self;
        let result = runtime.block_on(async {
            let s = match session {
                Some(s) => s,
                None => {
                    debug!(target = %target.describe(), "connecting the history writer to PostgreSQL");
                    // No migration here: a table that went missing is an environment
                    // failure to wait out (and to see in the log), not something to paper
                    // over by recreating it empty.
                    let opened = Session::open(target, async |_: &mut Conn| {
                        Ok::<(), StoreError>(())
                    });
                    session.insert(opened.await?)
                }
            };
            match tokio::time::timeout(BATCH_TIMEOUT, job(s)).await {
                Ok(result) => result,
                Err(_) => Err(StoreError::Timeout(BATCH_TIMEOUT)),
            }
        });
        if result.is_err() {
            // Whatever broke (the connection, a dropped table behind a prepared statement,
            // a transaction left aborted), a new session starts clean. The next attempt
            // reconnects; failures are rare enough for that to cost nothing.
            if let Some(s) = session.take() {
                runtime.block_on(s.conn.close());
            }
        }
        result
    }
}

impl Drop for PgWriter {
    fn drop(&mut self) {
        // Runs on the writer thread, outside any runtime: blocking here is allowed.
        if let Some(s) = self.session.take() {
            self.runtime.block_on(s.conn.close());
        }
    }
}

async fn write_batch(s: &mut Session, batch: &[Record]) -> Result<Outcome, StoreError> {
    match write_all(s, batch).await {
        Ok(()) => Ok(Outcome {
            stored: batch.len() as u64,
            ..Outcome::default()
        }),
        Err(e) if e.is_data_error() => {
            debug!(error = %e, rows = batch.len(), "history batch refused; retrying row by row");
            write_one_by_one(s, batch).await
        }
        Err(e) => Err(e),
    }
}

/// The fast path: every record in one transaction; any error rolls all of it back.
async fn write_all(s: &mut Session, batch: &[Record]) -> Result<(), StoreError> {
    let columns = Columns::of(batch)?;
    let tx = s.conn.client.transaction().await?;
    if let Err(e) = columns.write(&tx, &s.statements).await {
        rollback(tx).await;
        return Err(e);
    }
    tx.commit().await?;
    Ok(())
}

/// The slow path: still one transaction, but each record under its own savepoint, so that
/// a faulty one is rolled back alone and replaced by a quarantine row. (On PostgreSQL an
/// error aborts the whole transaction, so even the quarantine insert gets a savepoint.)
async fn write_one_by_one(s: &mut Session, batch: &[Record]) -> Result<Outcome, StoreError> {
    let mut outcome = Outcome::default();
    let mut tx = s.conn.client.transaction().await?;
    for record in batch {
        let sp = tx.transaction().await?;
        let written = match Columns::of(std::slice::from_ref(record)) {
            Ok(columns) => columns.write(&sp, &s.statements).await,
            Err(e) => Err(e),
        };
        match written {
            Ok(()) => {
                sp.commit().await?;
                outcome.stored += 1;
            }
            Err(e) if e.is_data_error() => {
                sp.rollback().await?;
                outcome.failed += 1;
                if !quarantine(&mut tx, &s.statements, record, &e).await? {
                    outcome.lost += 1;
                }
            }
            Err(e) => {
                rollback(sp).await;
                rollback(tx).await;
                return Err(e);
            }
        }
    }
    tx.commit().await?;
    Ok(outcome)
}

/// Rolls back after a failure; a rollback that fails too (the connection is gone) changes
/// nothing: the server rolls back whatever a lost connection left open.
async fn rollback(tx: Transaction<'_>) {
    if let Err(e) = tx.rollback().await {
        debug!(error = %pg_text(&e), "rollback failed");
    }
}

/// Stores a record that failed on its own in `rejected`, with PostgreSQL's reason. Returns
/// false when even that failed because of the record (it is then only in the log); `Err`
/// for environment failures.
async fn quarantine(
    tx: &mut Transaction<'_>,
    statements: &Statements,
    record: &Record,
    why: &StoreError,
) -> Result<bool, StoreError> {
    let table = record.table();
    let reason = format!("history: {why}");
    let payload = match record.payload_json() {
        Ok(p) => p,
        Err(e) => format!("{{\"unencodable\": {:?}}}", e.to_string()),
    };
    warn!(table, reason = %why, "record refused by the history store; quarantined");
    let sp = tx.transaction().await?;
    let inserted = sp
        .execute(
            &statements.rejected,
            &[
                &vec![shoal_model::now_ms()],
                &vec![table],
                &vec![reason.as_str()],
                &vec![payload.as_str()],
            ],
        )
        .await;
    match inserted {
        Ok(_) => {
            sp.commit().await?;
            Ok(true)
        }
        Err(e) => {
            let e = StoreError::from(e);
            if e.is_data_error() {
                sp.rollback().await?;
                error!(table, reason = %why, quarantine_error = %e, payload, "record refused and could not be quarantined");
                Ok(false)
            } else {
                Err(e)
            }
        }
    }
}

/// Rows of one keyed table, each key once with the last row given for it, in order of
/// first appearance.
#[derive(Debug)]
struct Latest<K, V> {
    index: HashMap<K, usize>,
    rows: Vec<V>,
}

impl<K, V> Default for Latest<K, V> {
    fn default() -> Self {
        Self {
            index: HashMap::new(),
            rows: Vec::new(),
        }
    }
}

impl<K: Hash + Eq, V> Latest<K, V> {
    fn put(&mut self, key: K, row: V) {
        match self.index.entry(key) {
            Entry::Occupied(e) => self.rows[*e.get()] = row,
            Entry::Vacant(e) => {
                e.insert(self.rows.len());
                self.rows.push(row);
            }
        }
    }

    /// One column of the rows, as the array parameter of an `unnest`.
    fn column<'a, T>(&'a self, f: impl Fn(&'a V) -> T) -> Vec<T> {
        self.rows.iter().map(f).collect()
    }
}

/// A task assignment with its encoded columns.
#[derive(Debug)]
struct TaskRow<'a> {
    task: &'a TaskAssignment,
    kind: String,
    area: String,
}

/// A vehicle announcement with its encoded columns.
#[derive(Debug)]
struct VehicleRow<'a> {
    vehicle: &'a shoal_model::VehicleAnnouncement,
    kind: String,
    capabilities: String,
    sensors: String,
    links: String,
}

/// An event with its enum columns as names.
#[derive(Debug)]
struct EventRow<'a> {
    event: &'a Event,
    severity: String,
    kind: String,
}

/// A batch sorted into tables, with everything encoded that can fail to encode (so that an
/// encoding failure blames the batch before anything is sent).
#[derive(Debug, Default)]
struct Columns<'a> {
    states: Latest<(&'a str, i64), &'a StateVector>,
    vehicles: Vec<VehicleRow<'a>>,
    tasks: Latest<&'a str, TaskRow<'a>>,
    statuses: Latest<(&'a str, i64, String), (&'a TaskStatus, String)>,
    events: Latest<&'a str, EventRow<'a>>,
    observations: Latest<(&'a str, &'a str, i64), &'a EnvironmentObservation>,
    rejected: Vec<(i64, &'a str, &'a str, &'a str)>,
}

impl<'a> Columns<'a> {
    fn of(batch: &'a [Record]) -> Result<Self, StoreError> {
        let mut c = Self::default();
        for record in batch {
            match record {
                Record::State(s) => c.states.put((&s.vehicle_id, s.timestamp_ms), s),
                Record::Vehicle(v) => c.vehicles.push(VehicleRow {
                    vehicle: v,
                    kind: enum_name(&v.kind)?,
                    capabilities: serde_json::to_string(&v.capabilities)?,
                    sensors: serde_json::to_string(&v.sensors)?,
                    links: serde_json::to_string(&v.links)?,
                }),
                Record::Task(t) => c.tasks.put(
                    &t.task_id,
                    TaskRow {
                        task: t,
                        kind: enum_name(&t.kind)?,
                        area: serde_json::to_string(&t.area)?,
                    },
                ),
                Record::TaskStatus(s) => {
                    let state = enum_name(&s.state)?;
                    c.statuses
                        .put((&s.task_id, s.timestamp_ms, state.clone()), (s, state));
                }
                Record::Event(e) => c.events.put(
                    &e.event_id,
                    EventRow {
                        event: e,
                        severity: enum_name(&e.severity)?,
                        kind: enum_name(&e.kind)?,
                    },
                ),
                Record::Observation(o) => c
                    .observations
                    .put((&o.vehicle_id, &o.property, o.timestamp_ms), o),
                Record::Rejected {
                    received_ms,
                    topic,
                    reason,
                    payload_json,
                } => c.rejected.push((*received_ms, topic, reason, payload_json)),
            }
        }
        Ok(c)
    }

    /// Sends every table's rows; tables are independent, so their order does not matter.
    async fn write(&self, tx: &Transaction<'_>, st: &Statements) -> Result<(), StoreError> {
        if !self.states.rows.is_empty() {
            let s = &self.states;
            exec(
                tx,
                &st.state,
                &[
                    &s.column(|r| r.vehicle_id.as_str()),
                    &s.column(|r| r.timestamp_ms),
                    &s.column(|r| r.latitude_deg),
                    &s.column(|r| r.longitude_deg),
                    &s.column(|r| r.depth_m),
                    &s.column(|r| r.altitude_m),
                    &s.column(|r| r.speed_mps),
                    &s.column(|r| r.yaw_deg),
                    &s.column(|r| r.pitch_deg),
                    &s.column(|r| r.roll_deg),
                    &s.column(|r| r.battery_pct),
                ],
            )
            .await?;
        }
        for v in &self.vehicles {
            let a = v.vehicle;
            exec(
                tx,
                &st.vehicle,
                &[
                    &a.vehicle_id,
                    &a.name,
                    &v.kind,
                    &a.vendor,
                    &v.capabilities,
                    &v.sensors,
                    &v.links,
                    &a.max_speed_mps,
                    &a.timestamp_ms,
                ],
            )
            .await?;
        }
        if !self.tasks.rows.is_empty() {
            let t = &self.tasks;
            exec(
                tx,
                &st.task,
                &[
                    &t.column(|r| r.task.task_id.as_str()),
                    &t.column(|r| r.task.mission_id.as_str()),
                    &t.column(|r| r.task.vehicle_id.as_str()),
                    &t.column(|r| r.task.issued_ms),
                    &t.column(|r| r.kind.as_str()),
                    &t.column(|r| r.area.as_str()),
                    &t.column(|r| r.task.depth_m),
                    &t.column(|r| r.task.altitude_m),
                    &t.column(|r| r.task.speed_mps),
                    &t.column(|r| r.task.line_spacing_m),
                    &t.column(|r| r.task.duration_s),
                    &t.column(|r| r.task.rate_hz),
                    &t.column(|r| crate::store::seq_column(r.task.issue_seq)),
                    &t.column(|r| r.task.expires_ms),
                    &t.column(|r| crate::store::seq_column(r.task.lease_term)),
                    &t.column(|r| r.task.lease_holder.as_str()),
                ],
            )
            .await?;
        }
        if !self.statuses.rows.is_empty() {
            let s = &self.statuses;
            exec(
                tx,
                &st.task_status,
                &[
                    &s.column(|r| r.0.task_id.as_str()),
                    &s.column(|r| r.0.timestamp_ms),
                    &s.column(|r| r.1.as_str()),
                    &s.column(|r| r.0.progress_pct),
                    &s.column(|r| r.0.message.as_str()),
                    &s.column(|r| r.0.vehicle_id.as_str()),
                ],
            )
            .await?;
        }
        if !self.events.rows.is_empty() {
            let e = &self.events;
            exec(
                tx,
                &st.event,
                &[
                    &e.column(|r| r.event.event_id.as_str()),
                    &e.column(|r| r.event.timestamp_ms),
                    &e.column(|r| r.severity.as_str()),
                    &e.column(|r| r.kind.as_str()),
                    &e.column(|r| r.event.vehicle_id.as_str()),
                    &e.column(|r| r.event.task_id.as_str()),
                    &e.column(|r| r.event.text.as_str()),
                ],
            )
            .await?;
        }
        if !self.observations.rows.is_empty() {
            let o = &self.observations;
            exec(
                tx,
                &st.observation,
                &[
                    &o.column(|r| r.vehicle_id.as_str()),
                    &o.column(|r| r.property.as_str()),
                    &o.column(|r| r.timestamp_ms),
                    &o.column(|r| r.value),
                    &o.column(|r| r.unit.as_str()),
                    &o.column(|r| r.latitude_deg),
                    &o.column(|r| r.longitude_deg),
                    &o.column(|r| r.depth_m),
                ],
            )
            .await?;
        }
        if !self.rejected.is_empty() {
            let r = &self.rejected;
            exec(
                tx,
                &st.rejected,
                &[
                    &r.iter().map(|x| x.0).collect::<Vec<_>>(),
                    &r.iter().map(|x| x.1).collect::<Vec<_>>(),
                    &r.iter().map(|x| x.2).collect::<Vec<_>>(),
                    &r.iter().map(|x| x.3).collect::<Vec<_>>(),
                ],
            )
            .await?;
        }
        Ok(())
    }
}

async fn exec(
    tx: &Transaction<'_>,
    statement: &Statement,
    params: &[&(dyn ToSql + Sync)],
) -> Result<(), StoreError> {
    tx.execute(statement, params).await?;
    Ok(())
}
