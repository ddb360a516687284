//! The store handle: opening, the writer thread's life, and shortcuts to the queue and queries.

use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use shoal_model::{EnvironmentObservation, Event, StateVector, VehicleAnnouncement};
use tokio::sync::watch;
use tracing::{error, info};

use crate::schema::{self, Location};
use crate::writer::{self, Shared};
use crate::{
    HistoryConfig, HistoryError, HistoryReader, HistoryStats, HistoryWriter, RejectedRecord,
    TaskHistory, WaitError,
};

/// The history store: a SQLite database, its writer thread and a query connection.
///
/// Dropping it closes it like [`History::close`], logging instead of returning errors.
#[derive(Debug)]
pub struct History {
    writer: HistoryWriter,
    reader: HistoryReader,
    thread: Option<JoinHandle<()>>,
}

impl History {
    /// Opens (creating if needed) the database and starts the writer thread.
    pub fn open(config: &HistoryConfig) -> Result<Self, HistoryError> {
        config.check()?;
        let location = Location::of(config);
        let conn = schema::open_writer(&location, config)?;
        // Opened after the writer created the schema, so a fresh database is never seen
        // without its tables.
        let reader = HistoryReader::new(schema::open_reader(&location)?);
        let shared = Arc::new(Shared::new(
            config.queue_capacity,
            config.batch_max,
            config.flush_interval(),
        ));
        let for_thread = Arc::clone(&shared);
        let thread = std::thread::Builder::new()
            .name("shoal-history".into())
            .spawn(move || writer::run(conn, &for_thread))
            .map_err(HistoryError::Spawn)?;
        info!(path = %config.path.display(), schema = schema::SCHEMA_VERSION, "history store open");
        Ok(Self {
            writer: HistoryWriter { shared },
            reader,
            thread: Some(thread),
        })
    }

    /// A handle to submit records, for any number of producer threads.
    pub fn writer(&self) -> HistoryWriter {
        self.writer.clone()
    }

    /// A handle for queries, for any thread; it stays usable after `close`.
    pub fn reader(&self) -> HistoryReader {
        self.reader.clone()
    }

    /// Stops accepting records, commits everything queued, and joins the writer thread.
    ///
    /// Fails with [`HistoryError::Unstored`] if the database kept failing and records had
    /// to be given up (they were never acknowledged).
    pub fn close(mut self) -> Result<HistoryStats, HistoryError> {
        self.shutdown()
    }

    fn shutdown(&mut self) -> Result<HistoryStats, HistoryError> {
        let Some(thread) = self.thread.take() else {
            return Ok(self.stats());
        };
        self.writer.shared.close();
        thread.join().map_err(|_| HistoryError::WriterPanicked)?;
        let stats = self.stats();
        info!(
            committed_rows = stats.committed_rows,
            failed_rows = stats.failed_rows,
            batches = stats.batches,
            "history store closed"
        );
        match stats.abandoned_rows {
            0 => Ok(stats),
            records => Err(HistoryError::Unstored { records }),
        }
    }

    /// See [`HistoryWriter::committed`].
    pub fn committed(&self) -> u64 {
        self.writer.committed()
    }

    /// See [`HistoryWriter::wait_committed`].
    pub fn wait_committed(&self, seq: u64, timeout: Duration) -> Result<(), WaitError> {
        self.writer.wait_committed(seq, timeout)
    }

    /// See [`HistoryWriter::subscribe_committed`].
    pub fn subscribe_committed(&self) -> watch::Receiver<u64> {
        self.writer.subscribe_committed()
    }

    /// See [`HistoryWriter::flush`].
    pub fn flush(&self, timeout: Duration) -> Result<(), WaitError> {
        self.writer.flush(timeout)
    }

    /// See [`HistoryWriter::stats`].
    pub fn stats(&self) -> HistoryStats {
        self.writer.stats()
    }

    /// See [`HistoryReader::track`].
    pub fn track(
        &self,
        vehicle_id: &str,
        from_ms: i64,
        to_ms: i64,
        limit: usize,
    ) -> Result<Vec<StateVector>, HistoryError> {
        self.reader.track(vehicle_id, from_ms, to_ms, limit)
    }

    /// See [`HistoryReader::count_states`].
    pub fn count_states(&self, vehicle_id: Option<&str>) -> Result<u64, HistoryError> {
        self.reader.count_states(vehicle_id)
    }

    /// See [`HistoryReader::latest_states`].
    pub fn latest_states(&self) -> Result<Vec<StateVector>, HistoryError> {
        self.reader.latest_states()
    }

    /// See [`HistoryReader::vehicles`].
    pub fn vehicles(&self) -> Result<Vec<VehicleAnnouncement>, HistoryError> {
        self.reader.vehicles()
    }

    /// See [`HistoryReader::events`].
    pub fn events(&self, since_ms: i64, limit: usize) -> Result<Vec<Event>, HistoryError> {
        self.reader.events(since_ms, limit)
    }

    /// See [`HistoryReader::task_history`].
    pub fn task_history(&self, task_id: &str) -> Result<TaskHistory, HistoryError> {
        self.reader.task_history(task_id)
    }

    /// See [`HistoryReader::observations`].
    pub fn observations(
        &self,
        vehicle_id: &str,
        property: &str,
        from_ms: i64,
        to_ms: i64,
        limit: usize,
    ) -> Result<Vec<EnvironmentObservation>, HistoryError> {
        self.reader
            .observations(vehicle_id, property, from_ms, to_ms, limit)
    }

    /// See [`HistoryReader::rejected`].
    pub fn rejected(&self, limit: usize) -> Result<Vec<RejectedRecord>, HistoryError> {
        self.reader.rejected(limit)
    }
}

impl Drop for History {
    fn drop(&mut self) {
        if let Err(e) = self.shutdown() {
            error!(error = %e, "history store closed with an error");
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod tests {
    use std::path::Path;

    use proptest::prelude::*;
    use shoal_model::{
        EventKind, GeoPoint, LinkKind, Severity, Task, TaskAssignment, TaskState, TaskStatus,
        VehicleKind,
    };

    use super::*;
    use crate::{Record, SubmitError};

    const T: i64 = 1_700_000_000_000;
    const LONG: Duration = Duration::from_secs(120);

    fn state(vehicle: &str, ts: i64) -> StateVector {
        StateVector {
            vehicle_id: vehicle.into(),
            timestamp_ms: ts,
            latitude_deg: 43.1,
            longitude_deg: 5.9,
            depth_m: 12.5,
            altitude_m: shoal_model::UNKNOWN,
            speed_mps: 1.5,
            yaw_deg: 359.9,
            pitch_deg: -3.0,
            roll_deg: 1.0,
            battery_pct: 80.0,
        }
    }

    fn announcement(vehicle: &str, ts: i64) -> VehicleAnnouncement {
        VehicleAnnouncement {
            vehicle_id: vehicle.into(),
            name: "Surface relay \"one\"".into(),
            kind: VehicleKind::Usv,
            vendor: "Shoal sim".into(),
            capabilities: vec!["goto".into(), "hold".into()],
            sensors: vec!["gps".into()],
            links: vec![LinkKind::Ip, LinkKind::Acoustic],
            max_speed_mps: 3.0,
            timestamp_ms: ts,
        }
    }

    fn file_config(dir: &Path) -> HistoryConfig {
        HistoryConfig {
            path: dir.join("data").join("history.db"),
            ..HistoryConfig::default()
        }
    }

    /// A config whose writer lingers for minutes, so records stay queued (and end up in one
    /// batch) until a flush or close: tests control batching without timing.
    fn lingering(dir: &Path, queue_capacity: usize) -> HistoryConfig {
        HistoryConfig {
            flush_interval_ms: 600_000,
            batch_max: 1000,
            queue_capacity,
            ..file_config(dir)
        }
    }

    #[test]
    fn every_record_type_round_trips() {
        let dir = tempfile::tempdir().unwrap();
        let h = History::open(&file_config(dir.path())).unwrap();
        let w = h.writer();
        let s = state("auv-1", T);
        let v = announcement("usv-1", T);
        let survey = Task::SurveyArea {
            polygon: vec![
                GeoPoint {
                    latitude_deg: 43.0,
                    longitude_deg: 5.0,
                },
                GeoPoint {
                    latitude_deg: 43.0,
                    longitude_deg: 5.01,
                },
                GeoPoint {
                    latitude_deg: 43.01,
                    longitude_deg: 5.01,
                },
            ],
            line_spacing_m: 20.0,
            depth_m: None,
            altitude_m: Some(5.0),
            speed_mps: 1.0,
        };
        let task = TaskAssignment::new("t-1", "m-1", "auv-1", T, &survey);
        let status = TaskStatus {
            task_id: "t-1".into(),
            vehicle_id: "auv-1".into(),
            timestamp_ms: T + 5,
            state: TaskState::Running,
            progress_pct: 12.5,
            message: "on line 3".into(),
        };
        let event = Event {
            event_id: "e-1".into(),
            timestamp_ms: T + 7,
            severity: Severity::Warning,
            kind: EventKind::LowBattery,
            vehicle_id: "auv-1".into(),
            task_id: String::new(),
            text: "battery 15 %".into(),
        };
        let obs = EnvironmentObservation {
            vehicle_id: "auv-1".into(),
            property: "sea_water_temperature".into(),
            timestamp_ms: T + 9,
            value: 14.25,
            unit: "Cel".into(),
            latitude_deg: 43.1,
            longitude_deg: 5.9,
            depth_m: 12.0,
        };
        w.submit(s.clone()).unwrap();
        w.submit(v.clone()).unwrap();
        w.submit(task.clone()).unwrap();
        w.submit(status.clone()).unwrap();
        w.submit(event.clone()).unwrap();
        w.submit(obs.clone()).unwrap();
        let last = w
            .submit(Record::rejected("state", "out_of_range:latitude_deg", "{}"))
            .unwrap();
        assert_eq!(last, 7);
        h.flush(LONG).unwrap();
        assert_eq!(h.committed(), 7);

        assert_eq!(h.track("auv-1", T, T, 10).unwrap(), vec![s]);
        assert_eq!(h.vehicles().unwrap(), vec![v]);
        let th = h.task_history("t-1").unwrap();
        assert_eq!(th.assignment.as_ref(), Some(&task));
        assert_eq!(th.assignment.unwrap().task(), Ok(survey));
        assert_eq!(th.statuses, vec![status]);
        assert_eq!(h.events(T, 10).unwrap(), vec![event]);
        let got = h
            .observations("auv-1", "sea_water_temperature", T, T + 100, 10)
            .unwrap();
        assert_eq!(got, vec![obs]);
        let rejected = h.rejected(10).unwrap();
        assert_eq!(rejected.len(), 1);
        assert_eq!(
            (rejected[0].topic.as_str(), rejected[0].reason.as_str()),
            ("state", "out_of_range:latitude_deg")
        );
        let stats = h.close().unwrap();
        assert_eq!(
            (stats.submitted, stats.committed_rows, stats.failed_rows),
            (7, 7, 0)
        );
    }

    #[test]
    fn enums_are_stored_as_their_serde_names() {
        let h = History::open(&HistoryConfig::in_memory()).unwrap();
        h.writer().submit(announcement("usv-1", T)).unwrap();
        h.flush(LONG).unwrap();
        let conn = h.reader.conn_for_tests();
        let (kind, links): (String, String) = conn
            .query_row("SELECT kind, links FROM vehicle", [], |r| {
                Ok((r.get(0)?, r.get(1)?))
            })
            .unwrap();
        assert_eq!(
            (kind.as_str(), links.as_str()),
            ("usv", r#"["ip","acoustic"]"#)
        );
    }

    #[test]
    fn a_hundred_thousand_state_vectors_are_all_committed() {
        let dir = tempfile::tempdir().unwrap();
        let h = History::open(&file_config(dir.path())).unwrap();
        let w = h.writer();
        for i in 0..100_000_i64 {
            w.submit_blocking(state(&format!("auv-{}", i % 10), T + i / 10))
                .unwrap();
        }
        h.flush(LONG).unwrap();
        assert_eq!(h.committed(), 100_000);
        assert_eq!(h.count_states(None).unwrap(), 100_000);
        assert_eq!(h.count_states(Some("auv-3")).unwrap(), 10_000);
        let stats = h.close().unwrap();
        assert_eq!(
            (stats.submitted, stats.committed_rows, stats.failed_rows),
            (100_000, 100_000, 0)
        );
        assert!(
            stats.batches >= 50,
            "at most 2000 rows per batch: {stats:?}"
        );
    }

    #[test]
    fn a_duplicate_vehicle_and_time_is_an_idempotent_upsert() {
        let h = History::open(&HistoryConfig::in_memory()).unwrap();
        let w = h.writer();
        w.submit(state("auv-1", T)).unwrap();
        w.submit(state("auv-1", T)).unwrap();
        h.flush(LONG).unwrap();
        assert_eq!(h.count_states(None).unwrap(), 1);
        // A corrected fix for the same instant replaces the stored one (last writer wins).
        let corrected = StateVector {
            battery_pct: 79.0,
            ..state("auv-1", T)
        };
        w.submit(corrected.clone()).unwrap();
        h.flush(LONG).unwrap();
        assert_eq!(h.track("auv-1", T, T, 10).unwrap(), vec![corrected]);
        assert_eq!(h.stats().failed_rows, 0);
    }

    #[test]
    fn an_older_announcement_does_not_roll_a_vehicle_back() {
        let h = History::open(&HistoryConfig::in_memory()).unwrap();
        let w = h.writer();
        let newer = VehicleAnnouncement {
            name: "new name".into(),
            ..announcement("usv-1", T + 10)
        };
        w.submit(newer.clone()).unwrap();
        w.submit(announcement("usv-1", T)).unwrap();
        h.flush(LONG).unwrap();
        assert_eq!(h.vehicles().unwrap(), vec![newer]);
        let first_seen: i64 = h
            .reader
            .conn_for_tests()
            .query_row("SELECT first_seen_ms FROM vehicle", [], |r| r.get(0))
            .unwrap();
        assert_eq!(first_seen, T);
    }

    #[test]
    fn a_full_queue_hands_the_record_back() {
        let dir = tempfile::tempdir().unwrap();
        let h = History::open(&lingering(dir.path(), 2)).unwrap();
        let w = h.writer();
        assert_eq!(w.submit(state("auv-1", T)).unwrap(), 1);
        assert_eq!(w.submit(state("auv-1", T + 1)).unwrap(), 2);
        match w.submit(state("auv-1", T + 2)) {
            Err(SubmitError::Full(r)) => assert_eq!(*r, Record::State(state("auv-1", T + 2))),
            other => panic!("expected Full, got {other:?}"),
        }
        assert_eq!(h.stats().queue_len, 2);
        assert_eq!(h.stats().submitted, 2);
    }

    #[test]
    fn submit_blocking_waits_for_space() {
        let dir = tempfile::tempdir().unwrap();
        let h = History::open(&lingering(dir.path(), 1)).unwrap();
        let w = h.writer();
        w.submit(state("auv-1", T)).unwrap();
        let w2 = h.writer();
        let blocked = std::thread::spawn(move || w2.submit_blocking(state("auv-1", T + 1)));
        // The flush makes the writer take record 1, which frees the slot record 2 waits for.
        h.flush(LONG).unwrap();
        assert_eq!(blocked.join().unwrap().unwrap(), 2);
        h.flush(LONG).unwrap();
        assert_eq!(h.count_states(None).unwrap(), 2);
    }

    #[test]
    fn close_drains_the_queue() {
        let dir = tempfile::tempdir().unwrap();
        let config = lingering(dir.path(), 10_000);
        let h = History::open(&config).unwrap();
        let w = h.writer();
        for i in 0..2500 {
            w.submit(state("auv-1", T + i)).unwrap();
        }
        assert_eq!(
            h.committed(),
            0,
            "the writer lingers, nothing is committed yet"
        );
        let stats = h.close().unwrap();
        assert_eq!((stats.committed_rows, stats.queue_len), (2500, 0));
        assert_eq!(w.committed(), 2500);
        assert!(matches!(
            w.submit(state("auv-1", T)),
            Err(SubmitError::Closed(_))
        ));
        let h = History::open(&config).unwrap();
        assert_eq!(h.count_states(None).unwrap(), 2500);
    }

    #[test]
    fn a_refused_record_is_quarantined_and_its_batch_kept() {
        let dir = tempfile::tempdir().unwrap();
        let h = History::open(&lingering(dir.path(), 100)).unwrap();
        let w = h.writer();
        let nan = StateVector {
            latitude_deg: f64::NAN,
            ..state("auv-1", T + 1)
        };
        let far = StateVector {
            longitude_deg: 1000.0,
            ..state("auv-1", T + 3)
        };
        w.submit(state("auv-1", T)).unwrap();
        w.submit(nan).unwrap();
        w.submit(state("auv-1", T + 2)).unwrap();
        w.submit(far.clone()).unwrap();
        h.flush(LONG).unwrap();
        assert_eq!(h.committed(), 4, "quarantined records are acknowledged too");
        let kept: Vec<i64> = h
            .track("auv-1", T, T + 10, 10)
            .unwrap()
            .iter()
            .map(|s| s.timestamp_ms)
            .collect();
        assert_eq!(kept, vec![T, T + 2]);
        let rejected = h.rejected(10).unwrap();
        assert_eq!(rejected.len(), 2);
        assert!(rejected.iter().all(|r| r.topic == "state_vector"));
        // Newest first: the CHECK failure, then the NaN (stored by SQLite as NULL).
        assert!(
            rejected[0].reason.contains("CHECK"),
            "{}",
            rejected[0].reason
        );
        assert!(
            rejected[1].reason.contains("NOT NULL"),
            "{}",
            rejected[1].reason
        );
        let payload: StateVector = serde_json::from_str(&rejected[0].payload_json).unwrap();
        assert_eq!(payload, far);
        let stats = h.stats();
        assert_eq!(
            (stats.committed_rows, stats.failed_rows, stats.batches),
            (2, 2, 1)
        );
    }

    #[test]
    fn a_database_failure_is_retried_not_dropped() {
        let dir = tempfile::tempdir().unwrap();
        let config = file_config(dir.path());
        let h = History::open(&config).unwrap();
        let other = rusqlite::Connection::open(&config.path).unwrap();
        let ddl: String = other
            .query_row(
                "SELECT sql FROM sqlite_schema WHERE name = 'event'",
                [],
                |r| r.get(0),
            )
            .unwrap();
        // A missing table is an environment failure, not the record's fault.
        other.execute_batch("DROP TABLE event").unwrap();
        let event = Event {
            event_id: "e-1".into(),
            timestamp_ms: T,
            severity: Severity::Info,
            kind: EventKind::Other,
            vehicle_id: String::new(),
            task_id: String::new(),
            text: String::new(),
        };
        let seq = h.writer().submit(event.clone()).unwrap();
        let waited = h.wait_committed(seq, Duration::from_millis(300));
        assert!(
            matches!(waited, Err(WaitError::Timeout { committed: 0, .. })),
            "{waited:?}"
        );
        other.execute_batch(&ddl).unwrap();
        h.wait_committed(seq, LONG).unwrap();
        assert_eq!(h.events(0, 10).unwrap(), vec![event]);
        let stats = h.close().unwrap();
        assert!(stats.retries >= 1);
        assert_eq!((stats.failed_rows, stats.abandoned_rows), (0, 0));
    }

    #[test]
    fn close_gives_up_on_records_the_database_keeps_refusing_without_acknowledging_them() {
        let dir = tempfile::tempdir().unwrap();
        let config = file_config(dir.path());
        let h = History::open(&config).unwrap();
        let other = rusqlite::Connection::open(&config.path).unwrap();
        other.execute_batch("DROP TABLE observation").unwrap();
        let obs = EnvironmentObservation {
            vehicle_id: "auv-1".into(),
            property: "p".into(),
            timestamp_ms: T,
            value: 1.0,
            unit: String::new(),
            latitude_deg: 0.0,
            longitude_deg: 0.0,
            depth_m: 0.0,
        };
        let w = h.writer();
        let seq = w.submit(obs).unwrap();
        assert!(matches!(
            h.close(),
            Err(HistoryError::Unstored { records: 1 })
        ));
        assert!(matches!(
            w.wait_committed(seq, LONG),
            Err(WaitError::Stopped { committed: 0, .. })
        ));
    }

    #[test]
    fn a_reopened_store_sees_the_data_and_warms_up() {
        let dir = tempfile::tempdir().unwrap();
        let config = file_config(dir.path());
        let h = History::open(&config).unwrap();
        let w = h.writer();
        for v in ["auv-1", "auv-2", "usv-1"] {
            for i in 0..50 {
                w.submit(state(v, T + i * 1000)).unwrap();
            }
        }
        w.submit(announcement("usv-1", T)).unwrap();
        h.close().unwrap();

        let h = History::open(&config).unwrap();
        let latest = h.latest_states().unwrap();
        let got: Vec<(&str, i64)> = latest
            .iter()
            .map(|s| (s.vehicle_id.as_str(), s.timestamp_ms))
            .collect();
        let newest = T + 49_000;
        assert_eq!(
            got,
            vec![("auv-1", newest), ("auv-2", newest), ("usv-1", newest)]
        );
        assert_eq!(h.vehicles().unwrap(), vec![announcement("usv-1", T)]);
        assert_eq!(h.count_states(None).unwrap(), 150);
        // Sequence numbers are per run: a new store starts counting from 1 again.
        assert_eq!(h.writer().submit(state("auv-1", T - 1)).unwrap(), 1);
    }

    #[test]
    fn latest_states_of_an_empty_store_is_empty() {
        let h = History::open(&HistoryConfig::in_memory()).unwrap();
        assert_eq!(h.latest_states().unwrap(), vec![]);
        assert_eq!(h.count_states(None).unwrap(), 0);
    }

    #[test]
    fn a_newer_schema_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let config = file_config(dir.path());
        History::open(&config).unwrap().close().unwrap();
        let other = rusqlite::Connection::open(&config.path).unwrap();
        other
            .pragma_update(None, "user_version", crate::SCHEMA_VERSION + 1)
            .unwrap();
        drop(other);
        assert!(matches!(
            History::open(&config),
            Err(HistoryError::SchemaTooNew { .. })
        ));
    }

    #[test]
    fn the_track_window_is_inclusive_ordered_and_limited() {
        let h = History::open(&HistoryConfig::in_memory()).unwrap();
        let w = h.writer();
        // Submitted out of order, and with another vehicle interleaved.
        for i in [5, 0, 9, 2, 7, 1, 3, 8, 4, 6] {
            w.submit(state("auv-1", T + i)).unwrap();
            w.submit(state("auv-2", T + i)).unwrap();
        }
        h.flush(LONG).unwrap();
        let ts = |v: Vec<StateVector>| v.iter().map(|s| s.timestamp_ms - T).collect::<Vec<_>>();
        assert_eq!(
            ts(h.track("auv-1", T + 2, T + 5, 100).unwrap()),
            vec![2, 3, 4, 5]
        );
        assert_eq!(ts(h.track("auv-1", T + 2, T + 5, 2).unwrap()), vec![2, 3]);
        assert_eq!(ts(h.track("auv-1", T + 9, T + 9, 100).unwrap()), vec![9]);
        assert_eq!(ts(h.track("auv-1", T - 100, T, 100).unwrap()), vec![0]);
        assert_eq!(
            ts(h.track("auv-1", T + 10, T + 100, 100).unwrap()),
            Vec::<i64>::new()
        );
        assert_eq!(
            ts(h.track("auv-1", T + 5, T + 2, 100).unwrap()),
            Vec::<i64>::new()
        );
        assert_eq!(
            ts(h.track("auv-1", T, T + 9, 0).unwrap()),
            Vec::<i64>::new()
        );
        assert!(h.track("auv-3", T, T + 9, 100).unwrap().is_empty());
    }

    #[test]
    fn the_watch_channel_follows_commits() {
        let h = History::open(&HistoryConfig::in_memory()).unwrap();
        let mut rx = h.subscribe_committed();
        assert_eq!(*rx.borrow_and_update(), 0);
        let seq = h.writer().submit(state("auv-1", T)).unwrap();
        h.flush(LONG).unwrap();
        assert!(rx.has_changed().unwrap());
        assert_eq!(*rx.borrow_and_update(), seq);
    }

    #[test]
    fn task_statuses_of_one_millisecond_come_in_life_cycle_order() {
        let h = History::open(&HistoryConfig::in_memory()).unwrap();
        let w = h.writer();
        let status = |state| TaskStatus {
            task_id: "t-1".into(),
            vehicle_id: "auv-1".into(),
            timestamp_ms: T,
            state,
            progress_pct: 0.0,
            message: String::new(),
        };
        for s in [TaskState::Done, TaskState::Running, TaskState::Accepted] {
            w.submit(status(s)).unwrap();
        }
        h.flush(LONG).unwrap();
        let got: Vec<TaskState> = h
            .task_history("t-1")
            .unwrap()
            .statuses
            .iter()
            .map(|s| s.state)
            .collect();
        assert_eq!(
            got,
            vec![TaskState::Accepted, TaskState::Running, TaskState::Done]
        );
        assert_eq!(h.task_history("t-1").unwrap().assignment, None);
    }

    #[test]
    fn the_raw_baseline_writes_the_same_table() {
        let dir = tempfile::tempdir().unwrap();
        let config = file_config(dir.path());
        let rows: Vec<StateVector> = (0..1000).map(|i| state("auv-1", T + i)).collect();
        crate::raw_insert_baseline(&config.path, &rows, 300).unwrap();
        // Run twice: the second run starts from a fresh database again.
        crate::raw_insert_baseline(&config.path, &rows[..10], 300).unwrap();
        let h = History::open(&config).unwrap();
        assert_eq!(h.count_states(None).unwrap(), 10);
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(24))]

        #[test]
        fn any_valid_state_vector_round_trips_bit_for_bit(
            lat in -90.0..=90.0f64, lon in -180.0..=180.0f64, depth in 0.0..=11_000.0f64,
            alt in prop_oneof![Just(-1.0), 0.0..=10_000.0f64], speed in 0.0..=30.0f64,
            yaw in 0.0..360.0f64, pitch in -90.0..=90.0f64, roll in -180.0..=180.0f64,
            battery in 0.0..=100.0f64, ts in shoal_model::MIN_TIMESTAMP_MS..=shoal_model::MAX_TIMESTAMP_MS,
            id in "[A-Za-z0-9_.-]{1,32}",
        ) {
            let s = StateVector {
                vehicle_id: id, timestamp_ms: ts, latitude_deg: lat, longitude_deg: lon,
                depth_m: depth, altitude_m: alt, speed_mps: speed, yaw_deg: yaw,
                pitch_deg: pitch, roll_deg: roll, battery_pct: battery,
            };
            let h = History::open(&HistoryConfig::in_memory()).unwrap();
            h.writer().submit(s.clone()).unwrap();
            h.flush(LONG).unwrap();
            prop_assert_eq!(h.track(&s.vehicle_id, ts, ts, 1).unwrap(), vec![s]);
        }
    }
}
