//! Retention: the maintenance pass that keeps the history bounded over a deployment.
//!
//! Every `retention.interval_s` the writer thread runs one pass, as of the wall clock
//! (`now`), in this order:
//!
//! 1. **Age.** Everything older than `now - max_age_days` is deleted: state vectors,
//!    observations, events, quarantined records (`rejected`, by `received_ms`), vehicles
//!    last announced before it that have no state vector left, and *ended* tasks whose
//!    assignment and every status are older. A task is ended when it has a final status
//!    (`done`, `failed`, `aborted`, `expired`), or when it expired before the cutoff
//!    without ever being accepted. The data of a task that is not ended is never deleted,
//!    whatever its age or the size cap.
//! 2. **Downsampling.** State vectors older than `now - full_rate_hours` are thinned to the
//!    first one per vehicle in each `downsample_interval_s` interval. Intervals are aligned
//!    to the Unix epoch and only whole intervals are thinned, so a thinned interval never
//!    changes again and a later pass keeps exactly the row an earlier one kept.
//! 3. **Size cap.** With `max_rows` set, the rows of the history's tables are counted; over
//!    the cap the oldest data goes first until 90 % of the cap is left (so that the cap
//!    does not fire on every pass): first the downsampling cutoff moves towards `now`,
//!    one hour at a time (resolution goes before coverage), then everything older than the
//!    oldest remaining hour is dropped, hour by hour, as in step 1. The last hour is never
//!    dropped for the cap, and neither are tasks that are not ended, so the cap may stay
//!    exceeded when it is smaller than that.
//!
//! Every statement is bounded: a delete touches at most `batch_rows` rows (downsampling:
//! at most `batch_rows` rows, or one interval's rows if more), selected by key range (a
//! vehicle's time range, an index range of event times, of quarantine ids), never a
//! `DELETE` over a whole table. Each runs in a transaction of its own, and between two of
//! them the writer commits whatever producers queued, so ingest waits at most for one
//! statement however big the backlog. A pass stops early when the store is closing; it
//! resumes at the next one.
//!
//! A vehicle's thinned time range is remembered between passes, so a pass only looks at
//! what became old since the last one; once a day (and after a restart) the whole range
//! is checked again, which also thins state vectors that arrived late.

use std::collections::HashMap;
use std::time::{Duration, Instant};

use serde::Serialize;
use tracing::{debug, info, warn};

use crate::backend::{FromRow, WriteStore};
use crate::config::HOUR_MS;
use crate::query::Param;
use crate::store::StoreError;
use crate::{RetentionConfig, schema};

/// One day in ms.
const DAY_MS: i64 = 24 * HOUR_MS;

/// Free SQLite pages released per `incremental_vacuum` statement.
const VACUUM_PAGES: i64 = 1024;

/// Final task states, as stored (their serde names; checked against the model in a test).
const FINAL_STATES: &str = "('done', 'failed', 'aborted', 'expired')";

/// What maintenance has done since the store was opened, for stats and health pages.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
#[non_exhaustive]
pub struct MaintenanceStats {
    /// False when retention is off (`retention.enabled = false`, or nothing to enforce).
    pub enabled: bool,
    /// Passes completed.
    pub passes: u64,
    /// Passes that stopped on a database error (retried at the next interval).
    pub failed_passes: u64,
    /// State vectors deleted by downsampling.
    pub rows_downsampled: u64,
    /// Rows deleted for their age or for the size cap (all tables).
    pub rows_deleted: u64,
    /// Passes in which the size cap (`max_rows`) had to act.
    pub cap_passes: u64,
    /// Bounded maintenance statements run (queries included).
    pub statements: u64,
    /// When the last pass ended, ms since the Unix epoch; 0 before the first.
    pub last_pass_ms: i64,
    /// How long the last pass took, in ms (ingest batches committed meanwhile included).
    pub last_duration_ms: u64,
    /// Why the last pass failed, if it did.
    pub last_error: Option<String>,
    /// Size of the database on disk, in bytes, as of the last pass (or the open): SQLite's
    /// file without its WAL, or the PostgreSQL schema's tables with their indexes.
    pub database_bytes: u64,
    /// Rows in the history's tables at the end of the last pass; counted only when
    /// `max_rows` is set.
    pub rows: Option<u64>,
}

/// What one pass did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(crate) struct PassReport {
    pub(crate) downsampled: u64,
    pub(crate) deleted: u64,
    pub(crate) statements: u64,
    pub(crate) cap_acted: bool,
    pub(crate) rows: Option<u64>,
}

/// Why a pass ended before its work was done.
#[derive(Debug, thiserror::Error)]
pub(crate) enum PassError {
    /// The database refused or failed; the pass is retried at the next interval.
    #[error(transparent)]
    Store(#[from] StoreError),
    /// The store is closing (or the writer gave up): the rest waits for the next pass.
    #[error("maintenance stopped: the store is closing")]
    Stopped,
}

/// Called between two maintenance statements: commits what producers queued meanwhile;
/// false stops the pass.
pub(crate) type Between<'a> = dyn FnMut(&mut WriteStore) -> bool + 'a;

/// The retention policy's state on the writer thread: when the next pass is due, and how
/// far each vehicle's state vectors are already thinned.
#[derive(Debug)]
pub(crate) struct Maintainer {
    config: RetentionConfig,
    next_due: Instant,
    /// Per vehicle: state vectors before this time (ms) are already thinned.
    thinned_until: HashMap<String, i64>,
    /// When `thinned_until` was last forgotten, to check the whole range again.
    rescan_due: Instant,
}

impl Maintainer {
    /// A maintainer whose first pass is due one interval from now.
    pub(crate) fn new(config: RetentionConfig) -> Self {
        let now = Instant::now();
        Self {
            next_due: now + config.interval(),
            rescan_due: now + Duration::from_secs(86_400),
            config,
            thinned_until: HashMap::new(),
        }
    }

    /// When the next pass is due.
    pub(crate) fn next_due(&self) -> Instant {
        self.next_due
    }

    /// Runs a whole pass as of `now_ms` (wall clock), calling `between` after every
    /// statement; schedules the next one an interval from its end, whatever the outcome.
    pub(crate) fn run_pass(
        &mut self,
        store: &mut WriteStore,
        now_ms: i64,
        between: &mut Between<'_>,
    ) -> Result<PassReport, PassError> {
        if Instant::now() >= self.rescan_due {
            self.thinned_until.clear();
            self.rescan_due = Instant::now() + Duration::from_secs(86_400);
        }
        let mut pass = Pass {
            store,
            between,
            batch: i64::try_from(self.config.batch_rows).unwrap_or(i64::MAX),
            report: PassReport::default(),
        };
        let result = self.pass(&mut pass, now_ms);
        self.next_due = Instant::now() + self.config.interval();
        result.map(|()| pass.report)
    }

    fn pass(&mut self, pass: &mut Pass<'_, '_>, now: i64) -> Result<(), PassError> {
        let c = self.config.clone();
        let interval = ms(c.downsample_interval_s, 1000);
        let full_rate_cutoff = now.saturating_sub(ms(c.full_rate_hours, HOUR_MS));
        if c.max_age_days > 0 {
            let deleted = pass.drop_older_than(now.saturating_sub(ms(c.max_age_days, DAY_MS)))?;
            pass.report.deleted += deleted;
        }
        if interval > 0 {
            let thinned = self.downsample_before(pass, align(full_rate_cutoff, interval))?;
            pass.report.downsampled += thinned;
        }
        if c.max_rows == 0 {
            return Ok(());
        }
        let max_rows = c.max_rows;
        let mut rows = pass.count_rows()?;
        if rows > max_rows {
            pass.report.cap_acted = true;
            let target = max_rows - max_rows / 10;
            info!(
                rows,
                max_rows, "history over its row cap; thinning, then dropping the oldest data"
            );
            // Resolution goes first: thin the full-rate window from its old end.
            if interval > 0 {
                let end = align(now, interval);
                let mut cutoff = align(full_rate_cutoff, interval);
                while rows > target && cutoff < end {
                    cutoff = align(cutoff + HOUR_MS, interval)
                        .max(cutoff + interval)
                        .min(end);
                    let thinned = self.downsample_before(pass, cutoff)?;
                    pass.report.downsampled += thinned;
                    rows = rows.saturating_sub(thinned);
                }
            }
            // Then coverage: the oldest hour left, as long as there is one before the last.
            while rows > target {
                let Some(oldest) = pass.oldest()? else { break };
                let cutoff = oldest.saturating_add(HOUR_MS);
                if cutoff > now - HOUR_MS {
                    break;
                }
                let deleted = pass.drop_older_than(cutoff)?;
                pass.report.deleted += deleted;
                rows = rows.saturating_sub(deleted);
            }
            if rows > max_rows {
                warn!(
                    rows,
                    max_rows,
                    "history still over its row cap: what is left is the last hour or tasks that are not ended"
                );
            }
        }
        pass.report.rows = Some(rows);
        Ok(())
    }

    /// Thins every vehicle's state vectors before `cutoff` (aligned) to one per interval;
    /// returns the rows deleted.
    fn downsample_before(
        &mut self,
        pass: &mut Pass<'_, '_>,
        cutoff: i64,
    ) -> Result<u64, PassError> {
        let interval = ms(self.config.downsample_interval_s, 1000);
        let vehicles = pass.vehicles()?;
        // Forget vehicles that have no state vector left, so the map stays bounded.
        self.thinned_until
            .retain(|v, _| vehicles.binary_search(v).is_ok());
        let mut deleted = 0;
        for v in vehicles {
            let mut from = match self.thinned_until.get(&v) {
                Some(&until) => until,
                None => {
                    let first: Option<Option<i64>> = pass.query(
                        "SELECT min(timestamp_ms) FROM state_vector WHERE vehicle_id = ?1",
                        &[v.as_str().into()],
                    )?;
                    match first.flatten() {
                        Some(first) => align(first, interval),
                        None => continue,
                    }
                }
            };
            while from < cutoff {
                // The range holding about `batch` rows, cut at an interval boundary.
                let bound: Option<i64> = pass.query(
                    "SELECT timestamp_ms FROM state_vector WHERE vehicle_id = ?1 \
                     AND timestamp_ms >= ?2 AND timestamp_ms < ?3 \
                     ORDER BY timestamp_ms LIMIT 1 OFFSET ?4",
                    &[
                        v.as_str().into(),
                        from.into(),
                        cutoff.into(),
                        pass.batch.into(),
                    ],
                )?;
                let to = match bound {
                    None => cutoff,
                    Some(b) => align(b, interval).max(from + interval).min(cutoff),
                };
                deleted += pass.exec(
                    "DELETE FROM state_vector WHERE vehicle_id = ?1 \
                     AND timestamp_ms >= ?2 AND timestamp_ms < ?3 \
                     AND timestamp_ms NOT IN (SELECT min(timestamp_ms) FROM state_vector \
                         WHERE vehicle_id = ?1 AND timestamp_ms >= ?2 AND timestamp_ms < ?3 \
                         GROUP BY timestamp_ms / ?4)",
                    &[v.as_str().into(), from.into(), to.into(), interval.into()],
                )?;
                from = to;
                // Recorded as it goes, so that a pass cut short resumes where it stopped.
                self.thinned_until.insert(v.clone(), from);
            }
        }
        Ok(deleted)
    }
}

/// `n` units of `unit` ms, saturating (the configuration bounds keep it far from that).
fn ms(n: u64, unit: i64) -> i64 {
    i64::try_from(n).unwrap_or(i64::MAX).saturating_mul(unit)
}

/// `t` rounded down to a multiple of `interval` (> 0).
fn align(t: i64, interval: i64) -> i64 {
    t - t.rem_euclid(interval)
}

/// One pass in progress: the store, the ingest hook, and what was done so far.
struct Pass<'s, 'b> {
    store: &'s mut WriteStore,
    between: &'s mut Between<'b>,
    batch: i64,
    report: PassReport,
}

impl Pass<'_, '_> {
    /// Runs a statement, then lets queued records in.
    fn exec(&mut self, sql: &str, params: &[Param]) -> Result<u64, PassError> {
        let n = self.store.execute(sql, params)?;
        self.after_statement()?;
        Ok(n)
    }

    /// Runs a query for its first row, then lets queued records in.
    fn query<T: FromRow>(&mut self, sql: &str, params: &[Param]) -> Result<Option<T>, PassError> {
        let row = self.store.query_opt(sql, params)?;
        self.after_statement()?;
        Ok(row)
    }

    /// Runs a query for all its rows, then lets queued records in.
    fn query_all<T: FromRow>(&mut self, sql: &str, params: &[Param]) -> Result<Vec<T>, PassError> {
        let rows = self.store.query(sql, params)?;
        self.after_statement()?;
        Ok(rows)
    }

    fn after_statement(&mut self) -> Result<(), PassError> {
        self.report.statements += 1;
        if (self.between)(self.store) {
            Ok(())
        } else {
            Err(PassError::Stopped)
        }
    }

    /// Every vehicle with state vectors, in key order, one index seek each.
    fn vehicles(&mut self) -> Result<Vec<String>, PassError> {
        let mut out: Vec<String> = Vec::new();
        loop {
            let after = out.last().map_or("", String::as_str).into();
            let next: Option<String> = self.query(
                "SELECT vehicle_id FROM state_vector WHERE vehicle_id > ?1 \
                 ORDER BY vehicle_id LIMIT 1",
                &[after],
            )?;
            match next {
                Some(v) => out.push(v),
                None => return Ok(out),
            }
        }
    }

    /// Every (vehicle, property) with observations, in key order, one index seek each.
    fn observed(&mut self) -> Result<Vec<(String, String)>, PassError> {
        let mut out: Vec<(String, String)> = Vec::new();
        loop {
            let (v, p) = out
                .last()
                .map_or(("", ""), |(v, p)| (v.as_str(), p.as_str()));
            let next: Option<(String, String)> = self.query(
                "SELECT vehicle_id, property FROM observation \
                 WHERE (vehicle_id, property) > (?1, ?2) \
                 ORDER BY vehicle_id, property LIMIT 1",
                &[v.into(), p.into()],
            )?;
            match next {
                Some(pair) => out.push(pair),
                None => return Ok(out),
            }
        }
    }

    /// Rows in the tables retention prunes (all but `vehicle`): one scan of each.
    fn count_rows(&mut self) -> Result<u64, PassError> {
        let n: Option<i64> = self.query(
            "SELECT (SELECT count(*) FROM state_vector) + (SELECT count(*) FROM observation) \
             + (SELECT count(*) FROM event) + (SELECT count(*) FROM rejected) \
             + (SELECT count(*) FROM task_status) + (SELECT count(*) FROM task_assignment)",
            &[],
        )?;
        Ok(n.map_or(0, |n| u64::try_from(n).unwrap_or(0)))
    }

    /// The oldest time in the tables that can always be dropped (state vectors,
    /// observations, events, quarantine), by index seeks.
    fn oldest(&mut self) -> Result<Option<i64>, PassError> {
        let mut oldest: Option<i64> = None;
        let mut see = |t: Option<i64>| {
            if let Some(t) = t {
                oldest = Some(oldest.map_or(t, |o| o.min(t)));
            }
        };
        for v in self.vehicles()? {
            let t: Option<Option<i64>> = self.query(
                "SELECT min(timestamp_ms) FROM state_vector WHERE vehicle_id = ?1",
                &[v.as_str().into()],
            )?;
            see(t.flatten());
        }
        for (v, p) in self.observed()? {
            let t: Option<Option<i64>> = self.query(
                "SELECT min(timestamp_ms) FROM observation WHERE vehicle_id = ?1 AND property = ?2",
                &[v.as_str().into(), p.as_str().into()],
            )?;
            see(t.flatten());
        }
        let t: Option<Option<i64>> = self.query("SELECT min(timestamp_ms) FROM event", &[])?;
        see(t.flatten());
        // Ids follow arrival, so the first is (about) the oldest; exact enough to make
        // progress, as every row older than a dropped cutoff is gone.
        let t: Option<i64> =
            self.query("SELECT received_ms FROM rejected ORDER BY id LIMIT 1", &[])?;
        see(t);
        Ok(oldest)
    }

    /// Deletes everything older than `cutoff` that may be deleted; returns the row count.
    fn drop_older_than(&mut self, cutoff: i64) -> Result<u64, PassError> {
        let mut deleted = 0;
        for v in self.vehicles()? {
            deleted += self.drop_range(
                "SELECT timestamp_ms FROM state_vector WHERE vehicle_id = ?1 \
                 AND timestamp_ms < ?2 ORDER BY timestamp_ms LIMIT 1 OFFSET ?3",
                "DELETE FROM state_vector WHERE vehicle_id = ?1 AND timestamp_ms < ?2",
                &[v.as_str().into()],
                cutoff,
            )?;
        }
        for (v, p) in self.observed()? {
            deleted += self.drop_range(
                "SELECT timestamp_ms FROM observation WHERE vehicle_id = ?1 AND property = ?2 \
                 AND timestamp_ms < ?3 ORDER BY timestamp_ms LIMIT 1 OFFSET ?4",
                "DELETE FROM observation WHERE vehicle_id = ?1 AND property = ?2 \
                 AND timestamp_ms < ?3",
                &[v.as_str().into(), p.as_str().into()],
                cutoff,
            )?;
        }
        deleted += self.drop_batches(
            "DELETE FROM event WHERE event_id IN (SELECT event_id FROM event \
             WHERE timestamp_ms < ?1 ORDER BY timestamp_ms LIMIT ?2)",
            cutoff,
        )?;
        deleted += self.drop_batches(
            "DELETE FROM rejected WHERE id IN (SELECT id FROM rejected \
             WHERE received_ms < ?1 ORDER BY id LIMIT ?2)",
            cutoff,
        )?;
        deleted += self.drop_tasks(cutoff)?;
        // After the state vectors: a vehicle that still has some keeps its announcement.
        deleted += self.drop_batches(
            "DELETE FROM vehicle WHERE vehicle_id IN (SELECT v.vehicle_id FROM vehicle v \
             WHERE v.last_seen_ms < ?1 AND NOT EXISTS \
             (SELECT 1 FROM state_vector s WHERE s.vehicle_id = v.vehicle_id) \
             ORDER BY v.vehicle_id LIMIT ?2)",
            cutoff,
        )?;
        Ok(deleted)
    }

    /// Deletes one key prefix's rows older than `cutoff`, `batch` rows per statement:
    /// `bound` finds the time of the row after the next `batch` ones (parameters: `key`,
    /// the cutoff, the batch), `delete` removes the rows before a time (`key`, the time).
    fn drop_range(
        &mut self,
        bound: &str,
        delete: &str,
        key: &[Param],
        cutoff: i64,
    ) -> Result<u64, PassError> {
        let mut deleted = 0;
        loop {
            let mut params = key.to_vec();
            params.extend([cutoff.into(), self.batch.into()]);
            let next: Option<i64> = self.query(bound, &params)?;
            let mut params = key.to_vec();
            params.push(next.unwrap_or(cutoff).into());
            deleted += self.exec(delete, &params)?;
            if next.is_none() {
                return Ok(deleted);
            }
        }
    }

    /// Runs `delete` (parameters: the cutoff, the batch) until it deletes less than a batch.
    fn drop_batches(&mut self, delete: &str, cutoff: i64) -> Result<u64, PassError> {
        let mut deleted = 0;
        loop {
            let n = self.exec(delete, &[cutoff.into(), self.batch.into()])?;
            deleted += n;
            if n < u64::try_from(self.batch).unwrap_or(u64::MAX) {
                return Ok(deleted);
            }
        }
    }

    /// Deletes ended tasks whose assignment and statuses are all older than `cutoff`.
    fn drop_tasks(&mut self, cutoff: i64) -> Result<u64, PassError> {
        let ended = format!(
            "SELECT a.task_id FROM task_assignment a WHERE a.issued_ms < ?1 \
             AND NOT EXISTS (SELECT 1 FROM task_status s \
                 WHERE s.task_id = a.task_id AND s.timestamp_ms >= ?1) \
             AND (EXISTS (SELECT 1 FROM task_status s \
                     WHERE s.task_id = a.task_id AND s.state IN {FINAL_STATES}) \
                 OR (a.expires_ms > 0 AND a.expires_ms < ?1 AND NOT EXISTS \
                     (SELECT 1 FROM task_status s WHERE s.task_id = a.task_id \
                      AND s.state IN ('accepted', 'running')))) \
             ORDER BY a.task_id LIMIT ?2"
        );
        // Statuses whose assignment was never stored, or is already deleted (a pass cut
        // short between the two): the final status is deleted last, so they stay ended.
        let orphans = format!(
            "SELECT DISTINCT s.task_id FROM task_status s WHERE s.state IN {FINAL_STATES} \
             AND s.timestamp_ms < ?1 \
             AND NOT EXISTS (SELECT 1 FROM task_assignment a WHERE a.task_id = s.task_id) \
             AND NOT EXISTS (SELECT 1 FROM task_status n \
                 WHERE n.task_id = s.task_id AND n.timestamp_ms >= ?1) \
             ORDER BY s.task_id LIMIT ?2"
        );
        let mut deleted = 0;
        for select in [ended, orphans] {
            loop {
                let ids: Vec<String> =
                    self.query_all(&select, &[cutoff.into(), self.batch.into()])?;
                for id in &ids {
                    deleted += self.drop_task(id)?;
                }
                if ids.len() < usize::try_from(self.batch).unwrap_or(usize::MAX) {
                    break;
                }
            }
        }
        Ok(deleted)
    }

    /// Deletes one ended task: its assignment, then its other statuses, its final ones last.
    fn drop_task(&mut self, id: &str) -> Result<u64, PassError> {
        let mut deleted = self.exec(
            "DELETE FROM task_assignment WHERE task_id = ?1",
            &[id.into()],
        )?;
        for which in [format!("AND state NOT IN {FINAL_STATES}"), String::new()] {
            loop {
                let next: Option<i64> = self.query(
                    &format!(
                        "SELECT timestamp_ms FROM task_status WHERE task_id = ?1 {which} \
                         ORDER BY timestamp_ms LIMIT 1 OFFSET ?2"
                    ),
                    &[id.into(), self.batch.into()],
                )?;
                let Some(next) = next else {
                    deleted += self.exec(
                        &format!("DELETE FROM task_status WHERE task_id = ?1 {which}"),
                        &[id.into()],
                    )?;
                    break;
                };
                let n = self.exec(
                    &format!(
                        "DELETE FROM task_status WHERE task_id = ?1 {which} AND timestamp_ms < ?2"
                    ),
                    &[id.into(), next.into()],
                )?;
                // Up to eight statuses share a millisecond (one per state): with a batch
                // smaller than that, take the whole millisecond rather than none of it.
                let n = if n == 0 {
                    self.exec(
                        &format!(
                            "DELETE FROM task_status WHERE task_id = ?1 {which} \
                             AND timestamp_ms <= ?2"
                        ),
                        &[id.into(), next.into()],
                    )?
                } else {
                    n
                };
                deleted += n;
            }
        }
        Ok(deleted)
    }
}

/// After a pass on SQLite: gives free pages back to the file system, in bounded steps,
/// when the database was created with `auto_vacuum = INCREMENTAL`, keeping a tenth of the
/// file free for the ingest to come. (A database created before retention existed has no
/// auto-vacuum: its free pages are reused by new rows, and the file stops growing, but it
/// only shrinks after an offline `VACUUM`; see the operator guide.)
pub(crate) fn release_free_pages(
    store: &mut WriteStore,
    between: &mut Between<'_>,
) -> Result<u64, PassError> {
    if !matches!(store, WriteStore::Sqlite(_)) {
        return Ok(0);
    }
    let mode: Option<i64> = store.query_opt("SELECT auto_vacuum FROM pragma_auto_vacuum()", &[])?;
    if mode != Some(schema::AUTO_VACUUM_INCREMENTAL) {
        return Ok(0);
    }
    let mut released = 0;
    loop {
        let pages: Option<(i64, i64)> = store
            .query_opt::<PageCounts>(
                "SELECT f.freelist_count, p.page_count \
                 FROM pragma_freelist_count() f, pragma_page_count() p",
                &[],
            )?
            .map(|c| (c.free, c.total));
        let Some((free, total)) = pages else {
            return Ok(released);
        };
        let excess = free - total / 10;
        if excess <= 0 {
            return Ok(released);
        }
        let n = excess.min(VACUUM_PAGES);
        if let WriteStore::Sqlite(conn) = store {
            conn.execute_batch(&format!("PRAGMA incremental_vacuum({n})"))
                .map_err(StoreError::from)?;
        }
        released += u64::try_from(n).unwrap_or(0);
        if !between(store) {
            return Err(PassError::Stopped);
        }
    }
}

/// SQLite's free and total page counts.
struct PageCounts {
    free: i64,
    total: i64,
}

impl FromRow for PageCounts {
    fn sqlite(row: &rusqlite::Row<'_>) -> rusqlite::Result<Self> {
        Ok(Self {
            free: row.get(0)?,
            total: row.get(1)?,
        })
    }
    fn postgres(row: &tokio_postgres::Row) -> Result<Self, tokio_postgres::Error> {
        Ok(Self {
            free: row.try_get(0)?,
            total: row.try_get(1)?,
        })
    }
}

/// Logs what a pass did.
pub(crate) fn log_pass(report: &PassReport, took: Duration) {
    if report.deleted + report.downsampled > 0 {
        info!(
            downsampled = report.downsampled,
            deleted = report.deleted,
            statements = report.statements,
            ms = took.as_millis() as u64,
            "history maintenance pass"
        );
    } else {
        debug!(
            statements = report.statements,
            "history maintenance pass: nothing to do"
        );
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod tests {
    use shoal_model::{
        EnvironmentObservation, Event, EventKind, Severity, StateVector, Task, TaskAssignment,
        TaskState, TaskStatus,
    };

    use super::*;
    use crate::testing::{Fixture, on_both_backends};
    use crate::{HistoryConfig, Record};

    /// "Now" of the unit tests: a whole hour, so that cutoffs fall on interval boundaries.
    const NOW: i64 = 1_700_002_800_000;
    const MIN: i64 = 60_000;

    fn store(f: &Fixture) -> WriteStore {
        let config = f.config();
        if f.is_postgres() {
            let target = crate::pg::Target::of(&config).unwrap();
            WriteStore::Postgres(Box::new(crate::pg::store::PgWriter::open(target).unwrap()))
        } else {
            let location = schema::Location::of(&config);
            WriteStore::Sqlite(schema::open_writer(&location, &config).unwrap())
        }
    }

    fn write(store: &mut WriteStore, records: impl IntoIterator<Item = Record>) {
        let records: Vec<Record> = records.into_iter().collect();
        for chunk in records.chunks(5000) {
            let outcome = store.write_batch(chunk).unwrap();
            assert_eq!(outcome.failed, 0);
        }
    }

    fn count(store: &mut WriteStore, sql: &str) -> i64 {
        store.query_opt::<i64>(sql, &[]).unwrap().unwrap()
    }

    fn times(store: &mut WriteStore, vehicle: &str) -> Vec<i64> {
        store
            .query(
                "SELECT timestamp_ms FROM state_vector WHERE vehicle_id = ?1 ORDER BY timestamp_ms",
                &[vehicle.into()],
            )
            .unwrap()
    }

    fn state(vehicle: &str, ts: i64) -> Record {
        Record::State(StateVector {
            vehicle_id: vehicle.into(),
            timestamp_ms: ts,
            latitude_deg: 43.1,
            longitude_deg: 5.9,
            depth_m: 1.0,
            altitude_m: -1.0,
            speed_mps: 1.0,
            yaw_deg: 0.0,
            pitch_deg: 0.0,
            roll_deg: 0.0,
            battery_pct: 80.0,
        })
    }

    fn event(id: &str, ts: i64) -> Record {
        Record::Event(Event {
            event_id: id.into(),
            timestamp_ms: ts,
            severity: Severity::Info,
            kind: EventKind::Other,
            vehicle_id: String::new(),
            task_id: String::new(),
            text: String::new(),
        })
    }

    fn observation(ts: i64) -> Record {
        Record::Observation(EnvironmentObservation {
            vehicle_id: "auv-1".into(),
            property: "temperature".into(),
            timestamp_ms: ts,
            value: 14.0,
            unit: "Cel".into(),
            latitude_deg: 0.0,
            longitude_deg: 0.0,
            depth_m: 0.0,
        })
    }

    fn task(id: &str, issued: i64, expires: i64) -> Record {
        let mut t = TaskAssignment::new(id, "m-1", "auv-1", issued, &Task::Surface);
        t.expires_ms = expires;
        Record::Task(t)
    }

    fn status(id: &str, ts: i64, state: TaskState) -> Record {
        Record::TaskStatus(TaskStatus {
            task_id: id.into(),
            vehicle_id: "auv-1".into(),
            timestamp_ms: ts,
            state,
            progress_pct: 0.0,
            message: String::new(),
        })
    }

    fn retention(f: impl FnOnce(&mut RetentionConfig)) -> RetentionConfig {
        let mut c = RetentionConfig {
            full_rate_hours: 1,
            downsample_interval_s: 60,
            max_age_days: 0,
            max_rows: 0,
            ..RetentionConfig::default()
        };
        f(&mut c);
        c.check().unwrap();
        c
    }

    /// A pass with a hook that only counts its calls.
    fn pass(m: &mut Maintainer, store: &mut WriteStore, now: i64) -> (PassReport, u64) {
        let mut calls = 0;
        let report = m
            .run_pass(store, now, &mut |_: &mut WriteStore| {
                calls += 1;
                true
            })
            .unwrap();
        (report, calls)
    }

    on_both_backends! {
        fn recent_state_vectors_are_kept_and_older_ones_thinned_per_vehicle(f: &Fixture) {
            let mut s = store(f);
            // Every 10 s for 3 hours, two vehicles, one of them offset by 5 s.
            let start = NOW - 180 * MIN;
            write(&mut s, (start..NOW).step_by(10_000).flat_map(|t| {
                [state("auv-1", t), state("auv-2", t + 5_000)]
            }));
            let mut m = Maintainer::new(retention(|_| {}));
            let (report, _) = pass(&mut m, &mut s, NOW);
            let cutoff = NOW - 60 * MIN;
            for (v, offset) in [("auv-1", 0), ("auv-2", 5_000)] {
                let got = times(&mut s, v);
                let (old, recent): (Vec<i64>, Vec<i64>) = got.iter().partition(|&&t| t < cutoff);
                // The first state vector of each old minute, and nothing else.
                let expected: Vec<i64> = (start..cutoff).step_by(60_000).map(|t| t + offset).collect();
                assert_eq!(old, expected, "{v}");
                // The last hour at full rate.
                let full: Vec<i64> = (cutoff..NOW).step_by(10_000).map(|t| t + offset).collect();
                assert_eq!(recent, full, "{v}");
            }
            assert_eq!(report.downsampled, 2 * 120 * 5);
            assert_eq!(report.deleted, 0);
            // A second pass, later, keeps the thinned minutes exactly as they are.
            let before = times(&mut s, "auv-1");
            let (again, _) = pass(&mut m, &mut s, NOW + 59_000);
            assert_eq!(again.downsampled, 0);
            assert_eq!(times(&mut s, "auv-1"), before);
            // And so does a fresh maintainer (after a restart) that checks the whole range.
            let (fresh, _) = pass(&mut Maintainer::new(retention(|_| {})), &mut s, NOW);
            assert_eq!(fresh.downsampled, 0);
        }

        fn data_past_the_maximum_age_is_dropped_but_tasks_not_ended_are_kept(f: &Fixture) {
            let mut s = store(f);
            let old = NOW - 3 * DAY_MS;
            let recent = NOW - HOUR_MS;
            write(&mut s, [
                state("auv-1", old), state("auv-1", recent), state("gone-1", old),
                observation(old), observation(recent),
                event("e-old", old), event("e-new", recent),
                Record::Rejected { received_ms: old, topic: "t".into(), reason: "r".into(), payload_json: "{}".into() },
                Record::Rejected { received_ms: recent, topic: "t".into(), reason: "r".into(), payload_json: "{}".into() },
                // Ended long ago: dropped with its statuses.
                task("t-done", old, 0), status("t-done", old, TaskState::Running), status("t-done", old + 1, TaskState::Done),
                // Final status only (assignment never stored): dropped.
                status("t-orphan", old, TaskState::Failed),
                // Expired without being accepted: ended, dropped.
                task("t-expired", old, old + 1), status("t-expired", old, TaskState::Sent),
                // Not ended, however old: kept.
                task("t-running", old, 0), status("t-running", old, TaskState::Running),
                task("t-pending", old, 0),
                task("t-late", old, old + 1), status("t-late", old, TaskState::Accepted),
                status("t-orphan-running", old, TaskState::Running),
                // Ended, but its last status is recent: kept.
                task("t-recent", old, 0), status("t-recent", recent, TaskState::Done),
            ]);
            // Announced long ago: kept while it has state vectors, dropped with them.
            write(&mut s, [Record::Vehicle(vehicle("auv-1", old)), Record::Vehicle(vehicle("gone-1", old))]);
            let mut m = Maintainer::new(retention(|c| c.max_age_days = 1));
            let (report, _) = pass(&mut m, &mut s, NOW);
            assert_eq!(times(&mut s, "auv-1"), vec![recent]);
            assert!(times(&mut s, "gone-1").is_empty());
            assert_eq!(count(&mut s, "SELECT count(*) FROM observation"), 1);
            let events: Vec<String> = s.query("SELECT event_id FROM event", &[]).unwrap();
            assert_eq!(events, ["e-new"]);
            let rejected: Vec<i64> = s.query("SELECT received_ms FROM rejected", &[]).unwrap();
            assert_eq!(rejected, [recent]);
            let vehicles: Vec<String> = s.query("SELECT vehicle_id FROM vehicle", &[]).unwrap();
            assert_eq!(vehicles, ["auv-1"]);
            let tasks: Vec<String> = s
                .query("SELECT task_id FROM task_assignment ORDER BY task_id", &[])
                .unwrap();
            assert_eq!(tasks, ["t-late", "t-pending", "t-recent", "t-running"]);
            let statuses: Vec<String> = s
                .query("SELECT task_id FROM task_status ORDER BY task_id", &[])
                .unwrap();
            assert_eq!(statuses, ["t-late", "t-orphan-running", "t-recent", "t-running"]);
            // state ×2, observation, event, rejected, vehicle, 3 assignments, 5 statuses.
            assert_eq!(report.deleted, 2 + 1 + 1 + 1 + 1 + 2 + 4);
        }

        fn a_big_backlog_is_deleted_in_bounded_statements_over_several_passes(f: &Fixture) {
            let mut s = store(f);
            let old = NOW - 3 * DAY_MS;
            write(&mut s, (0..3000).map(|i| state("auv-1", old + i * 1000)));
            write(&mut s, (0..1000).map(|i| event(&format!("e-{i}"), old + i)));
            let config = retention(|c| {
                c.max_age_days = 1;
                c.batch_rows = 100;
            });
            // The first pass is cut short after 10 statements (as when the store closes).
            let mut m = Maintainer::new(config);
            let mut calls = 0;
            let cut = m.run_pass(&mut s, NOW, &mut |_: &mut WriteStore| {
                calls += 1;
                calls < 10
            });
            assert!(matches!(cut, Err(PassError::Stopped)), "{cut:?}");
            let left = count(&mut s, "SELECT count(*) FROM state_vector");
            assert!(left < 3000 && left > 0, "{left}");
            // The next pass finishes, never deleting more than a batch per statement, and
            // handing over to ingest between any two.
            let (report, calls) = pass(&mut m, &mut s, NOW);
            assert_eq!(report.statements, calls);
            assert_eq!(report.deleted, left as u64 + 1000);
            assert!(report.statements >= (left as u64 + 1000) / 100, "{report:?}");
            assert_eq!(count(&mut s, "SELECT count(*) FROM state_vector"), 0);
            assert_eq!(count(&mut s, "SELECT count(*) FROM event"), 0);
        }

        fn a_long_backlog_is_thinned_in_bounded_statements(f: &Fixture) {
            let mut s = store(f);
            // Three hours at 1 Hz; batches of 200 rows, intervals of 60.
            write(&mut s, (0..3 * 3600).map(|i| state("auv-1", NOW - 3 * HOUR_MS + i * 1000)));
            let mut m = Maintainer::new(retention(|c| c.batch_rows = 200));
            let (report, _) = pass(&mut m, &mut s, NOW);
            assert_eq!(report.downsampled, 120 * 59);
            // Every delete covered at most 200 rows (whole minutes), so many of them ran.
            assert!(report.statements >= 2 * 7200 / 200, "{report:?}");
            assert_eq!(times(&mut s, "auv-1").len(), 120 + 3600);
        }

        fn the_size_cap_thins_the_oldest_data_first_then_drops_it(f: &Fixture) {
            let mut s = store(f);
            let start = NOW - 3 * HOUR_MS;
            write(&mut s, (0..3 * 360).map(|i| state("auv-1", start + i * 10_000)));
            write(&mut s, [task("t-running", start, 0), status("t-running", start, TaskState::Running)]);
            // 1080 rows at 10 s; the oldest hour is thinned anyway (to 60), which leaves
            // 782 rows: the cap thins one more hour, no more.
            let cap = |max_rows| retention(|c| {
                c.full_rate_hours = 2;
                c.max_rows = max_rows;
            });
            let mut m = Maintainer::new(cap(600));
            let (report, _) = pass(&mut m, &mut s, NOW);
            assert!(report.cap_acted);
            assert_eq!(report.deleted, 0, "nothing needed dropping");
            assert_eq!(report.downsampled, 2 * 300);
            let got = times(&mut s, "auv-1");
            assert_eq!(got.first(), Some(&start), "the oldest data was thinned, not dropped");
            assert_eq!(got.len(), 60 + 60 + 360);
            // The newest hour stays at full rate.
            assert_eq!(got[120..], (NOW - HOUR_MS..NOW).step_by(10_000).collect::<Vec<_>>()[..]);
            assert_eq!(report.rows, Some(482));

            // A cap thinning cannot meet: the oldest hours go, the last hour stays.
            let mut m = Maintainer::new(cap(80));
            let (report, _) = pass(&mut m, &mut s, NOW);
            assert!(report.cap_acted);
            assert_eq!((report.downsampled, report.deleted), (300, 120));
            let got = times(&mut s, "auv-1");
            assert_eq!(got, (NOW - HOUR_MS..NOW).step_by(60_000).collect::<Vec<_>>());
            assert_eq!(report.rows, Some(62));
            // The task that is not ended survives the cap.
            assert_eq!(count(&mut s, "SELECT count(*) FROM task_status"), 1);
            assert_eq!(count(&mut s, "SELECT count(*) FROM task_assignment"), 1);
        }

        fn maintain_runs_a_pass_on_the_writer_and_reports_it(f: &Fixture) {
            let now = shoal_model::now_ms();
            let h = crate::History::open(&HistoryConfig {
                retention: RetentionConfig {
                    interval_s: 3600,
                    batch_rows: 50,
                    max_age_days: 1,
                    ..RetentionConfig::default()
                },
                ..f.config()
            })
            .unwrap();
            let w = h.writer();
            for i in 0..500 {
                w.submit(state("auv-1", now - 3 * DAY_MS + i)).unwrap();
                w.submit(state("auv-2", now - 10 * MIN + i * 1000)).unwrap();
            }
            h.flush(Duration::from_secs(60)).unwrap();
            assert_eq!(h.maintenance_stats().passes, 0, "the first pass waits an interval");
            // Records submitted while the pass runs are committed meanwhile.
            let feeder = {
                let w = h.writer();
                std::thread::spawn(move || {
                    (0..200).map(|i| w.submit_blocking(state("auv-3", now + i)).unwrap()).max()
                })
            };
            let stats = h.maintain(Duration::from_secs(60)).unwrap();
            let last = feeder.join().unwrap().unwrap();
            h.wait_committed(last, Duration::from_secs(60)).unwrap();
            assert!(stats.enabled);
            assert_eq!(stats.last_error, None);
            assert_eq!(stats.passes, 1);
            assert_eq!(stats.rows_deleted, 500);
            assert_eq!(stats.rows_downsampled, 0);
            assert!(stats.statements >= 10, "{stats:?}");
            assert!(stats.last_pass_ms >= now && stats.database_bytes > 0, "{stats:?}");
            assert_eq!(stats.last_error, None);
            assert_eq!(h.count_states(Some("auv-1")).unwrap(), 0);
            assert_eq!(h.count_states(Some("auv-2")).unwrap(), 500);
            assert_eq!(h.count_states(Some("auv-3")).unwrap(), 200);
            assert_eq!(h.maintenance_stats(), stats);
        }

        fn with_retention_off_nothing_is_deleted(f: &Fixture) {
            let h = crate::History::open(&HistoryConfig {
                retention: RetentionConfig::disabled(),
                ..f.config()
            })
            .unwrap();
            h.writer().submit(state("auv-1", 1_000_000_000_000)).unwrap();
            h.flush(Duration::from_secs(60)).unwrap();
            let stats = h.maintain(Duration::from_secs(60)).unwrap();
            assert!(!stats.enabled);
            assert_eq!(stats.passes, 0);
            assert_eq!(h.count_states(None).unwrap(), 1);
        }
    }

    fn vehicle(id: &str, ts: i64) -> shoal_model::VehicleAnnouncement {
        shoal_model::VehicleAnnouncement {
            vehicle_id: id.into(),
            name: id.into(),
            kind: shoal_model::VehicleKind::Auv,
            vendor: String::new(),
            capabilities: vec![],
            sensors: vec![],
            links: vec![],
            max_speed_mps: 1.0,
            timestamp_ms: ts,
        }
    }

    #[test]
    fn final_states_are_the_models_final_states_by_their_stored_names() {
        let states = [
            TaskState::Pending,
            TaskState::Sent,
            TaskState::Accepted,
            TaskState::Running,
            TaskState::Done,
            TaskState::Failed,
            TaskState::Aborted,
            TaskState::Expired,
        ];
        let names: Vec<String> = states
            .iter()
            .filter(|s| s.is_final())
            .map(|s| format!("'{}'", crate::store::enum_name(s).unwrap()))
            .collect();
        assert_eq!(format!("({})", names.join(", ")), FINAL_STATES);
        for (state, name) in [
            (TaskState::Accepted, "accepted"),
            (TaskState::Running, "running"),
        ] {
            assert_eq!(crate::store::enum_name(&state).unwrap(), name);
        }
    }

    #[test]
    fn a_new_sqlite_database_gives_freed_pages_back_in_steps() {
        let f = Fixture::sqlite();
        let mut s = store(&f);
        let mode: Option<i64> = s
            .query_opt("SELECT auto_vacuum FROM pragma_auto_vacuum()", &[])
            .unwrap();
        assert_eq!(mode, Some(schema::AUTO_VACUUM_INCREMENTAL));
        write(
            &mut s,
            (0..50_000).map(|i| state("auv-1", NOW - 3 * DAY_MS + i)),
        );
        let before = s.database_bytes().unwrap();
        let mut m = Maintainer::new(retention(|c| c.max_age_days = 1));
        pass(&mut m, &mut s, NOW);
        let mut steps = 0;
        let released = release_free_pages(&mut s, &mut |_: &mut WriteStore| {
            steps += 1;
            true
        })
        .unwrap();
        assert!(released > 0 && steps >= 1);
        let after = s.database_bytes().unwrap();
        assert!(after < before / 2, "{before} -> {after}");
    }

    #[test]
    fn alignment_is_to_the_epoch() {
        assert_eq!(align(125_000, 60_000), 120_000);
        assert_eq!(align(120_000, 60_000), 120_000);
        assert_eq!(align(-1, 60_000), -60_000);
    }
}
