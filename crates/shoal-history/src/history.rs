//! The store handle: opening, the writer thread's life, and shortcuts to the queue and queries.

use std::sync::{Arc, mpsc};
use std::thread::JoinHandle;
use std::time::Duration;

use shoal_model::{EnvironmentObservation, Event, StateVector, VehicleAnnouncement};
use tokio::sync::watch;
use tracing::{error, info};

use crate::backend::WriteStore;
use crate::pg::Target;
use crate::pg::reader::PgReader;
use crate::pg::store::PgWriter;
use crate::retention::{Maintainer, MaintenanceStats};
use crate::schema::{self, Location};
use crate::writer::{self, Shared};
use crate::{
    Backend, HistoryConfig, HistoryError, HistoryReader, HistoryStats, HistoryWriter,
    RejectedRecord, TaskHistory, WaitError,
};

/// The history store: a SQLite or PostgreSQL database, its writer thread and a query
/// connection.
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
    ///
    /// With the PostgreSQL backend this connects twice (writer and reader) and creates or
    /// migrates the schema; it fails if the server cannot be reached now. Later outages are
    /// survived: the writer keeps its batch and reconnects, the reader reconnects.
    pub fn open(config: &HistoryConfig) -> Result<Self, HistoryError> {
        config.check()?;
        let shared = Arc::new(Shared::new(
            config.queue_capacity,
            config.batch_max,
            config.flush_interval(),
        ));
        let (thread, reader) = match config.backend {
            Backend::Sqlite => {
                let location = Location::of(config);
                let conn = schema::open_writer(&location, config)?;
                // Opened after the writer created the schema, so a fresh database is never
                // seen without its tables.
                let reader = HistoryReader::sqlite(schema::open_reader(&location)?);
                let thread = spawn_writer(&shared, config, move || Ok(WriteStore::Sqlite(conn)))?;
                info!(path = %config.path.display(), schema = schema::SCHEMA_VERSION, "history store open (SQLite)");
                (thread, reader)
            }
            Backend::Postgres => {
                let target = Target::of(config)?;
                let described = target.describe();
                let for_writer = target.clone();
                // Connected on the writer thread itself: the connection's runtime must
                // never be entered (or dropped) on the caller's thread, which may be async.
                let thread = spawn_writer(&shared, config, move || {
                    PgWriter::open(for_writer).map(|w| WriteStore::Postgres(Box::new(w)))
                })?;
                // Started after the writer created the schema, like SQLite's reader.
                let reader = match PgReader::open(target) {
                    Ok(r) => HistoryReader::postgres(r),
                    Err(e) => {
                        shared.close();
                        if thread.join().is_err() {
                            error!("the history writer thread panicked");
                        }
                        return Err(e);
                    }
                };
                info!(target = %described, schema = schema::SCHEMA_VERSION, "history store open (PostgreSQL)");
                (thread, reader)
            }
        };
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

    /// See [`HistoryWriter::maintenance_stats`].
    pub fn maintenance_stats(&self) -> MaintenanceStats {
        self.writer.maintenance_stats()
    }

    /// See [`HistoryWriter::maintain`].
    pub fn maintain(&self, timeout: Duration) -> Result<MaintenanceStats, WaitError> {
        self.writer.maintain(timeout)
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

/// Starts the writer thread, which first opens its store with `open` (on the thread, so
/// that whatever the store needs stays there), and waits until that succeeded or failed.
fn spawn_writer(
    shared: &Arc<Shared>,
    config: &HistoryConfig,
    open: impl FnOnce() -> Result<WriteStore, HistoryError> + Send + 'static,
) -> Result<JoinHandle<()>, HistoryError> {
    let (ready_tx, ready_rx) = mpsc::sync_channel(1);
    let shared = Arc::clone(shared);
    let maintainer = config
        .retention
        .is_active()
        .then(|| Maintainer::new(config.retention.clone()));
    let thread = std::thread::Builder::new()
        .name("shoal-history".into())
        .spawn(move || match open() {
            Ok(store) => {
                // `spawn_writer` waits for this message; it cannot be gone.
                let _ = ready_tx.send(Ok(()));
                writer::run(store, &shared, maintainer);
            }
            Err(e) => {
                let _ = ready_tx.send(Err(e));
            }
        })
        .map_err(HistoryError::Spawn)?;
    match ready_rx.recv() {
        Ok(Ok(())) => Ok(thread),
        Ok(Err(e)) => {
            let _ = thread.join();
            Err(e)
        }
        Err(_) => {
            let _ = thread.join();
            Err(HistoryError::WriterPanicked)
        }
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
    use proptest::prelude::*;
    use proptest::test_runner::TestRunner;
    use shoal_model::{
        EventKind, GeoPoint, LinkKind, Severity, Task, TaskAssignment, TaskState, TaskStatus,
        VehicleKind,
    };

    use super::*;
    use crate::testing::{on_both_backends, on_postgres};
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

    fn event(id: &str, ts: i64) -> Event {
        Event {
            event_id: id.into(),
            timestamp_ms: ts,
            severity: Severity::Info,
            kind: EventKind::Other,
            vehicle_id: String::new(),
            task_id: String::new(),
            text: String::new(),
        }
    }

    fn observation(vehicle: &str, ts: i64) -> EnvironmentObservation {
        EnvironmentObservation {
            vehicle_id: vehicle.into(),
            property: "p".into(),
            timestamp_ms: ts,
            value: 1.0,
            unit: String::new(),
            latitude_deg: 0.0,
            longitude_deg: 0.0,
            depth_m: 0.0,
        }
    }

    on_both_backends! {
        fn every_record_type_round_trips(f: &Fixture) {
            let h = History::open(&f.config()).unwrap();
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
            let mut task = TaskAssignment::new("t-1", "m-1", "auv-1", T, &survey);
            task.issue_seq = 41;
            task.expires_ms = T + 60_000;
            task.lease_term = 3;
            task.lease_holder = "shore".into();
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
            let reloaded = h.reader().tasks_since(task.issued_ms, 10).unwrap();
            assert_eq!(reloaded.len(), 1);
            assert_eq!(reloaded[0].assignment.as_ref(), Some(&task));
            assert_eq!(reloaded[0].statuses, vec![status.clone()]);
            assert!(h.reader().tasks_since(task.issued_ms + 1, 10).unwrap().is_empty());
            assert_eq!(h.reader().max_issue_seq().unwrap(), 41);
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

        fn enums_are_stored_as_their_serde_names(f: &Fixture) {
            let h = History::open(&f.quick()).unwrap();
            h.writer().submit(announcement("usv-1", T)).unwrap();
            h.flush(LONG).unwrap();
            let r = h.reader();
            assert_eq!(r.texts_for_tests("SELECT kind FROM vehicle").unwrap(), ["usv"]);
            assert_eq!(
                r.texts_for_tests("SELECT links FROM vehicle").unwrap(),
                [r#"["ip","acoustic"]"#]
            );
        }

        fn a_hundred_thousand_state_vectors_are_all_committed(f: &Fixture) {
            let h = History::open(&f.config()).unwrap();
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
                stats.batches >= 5,
                "at most 20000 rows per batch: {stats:?}"
            );
        }

        fn a_duplicate_vehicle_and_time_is_an_idempotent_upsert(f: &Fixture) {
            let h = History::open(&f.quick()).unwrap();
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

        fn the_last_of_several_duplicates_in_one_batch_wins(f: &Fixture) {
            // PostgreSQL writes a batch's rows of a table with one statement, which must
            // not touch a row twice: the duplicates of one batch must still end like a
            // record-by-record upsert, for every keyed table.
            let h = History::open(&f.lingering(100)).unwrap();
            let w = h.writer();
            for battery in [10.0, 20.0, 30.0] {
                w.submit(StateVector { battery_pct: battery, ..state("auv-1", T) }).unwrap();
                w.submit(state("auv-2", T)).unwrap();
            }
            for value in [1.0, 2.0] {
                w.submit(EnvironmentObservation { value, ..observation("auv-1", T) }).unwrap();
            }
            for text in ["first", "second"] {
                w.submit(Event { text: text.into(), ..event("e-1", T) }).unwrap();
            }
            let status = |message: &str| TaskStatus {
                task_id: "t-1".into(),
                vehicle_id: "auv-1".into(),
                timestamp_ms: T,
                state: TaskState::Running,
                progress_pct: 50.0,
                message: message.into(),
            };
            w.submit(status("old")).unwrap();
            w.submit(status("new")).unwrap();
            let task = |mission: &str| {
                TaskAssignment::new("t-1", mission, "auv-1", T, &Task::Hold { duration_s: 10.0 })
            };
            w.submit(task("m-1")).unwrap();
            w.submit(task("m-2")).unwrap();
            w.submit(announcement("usv-1", T + 5)).unwrap();
            w.submit(VehicleAnnouncement { name: "older".into(), ..announcement("usv-1", T) })
                .unwrap();
            h.flush(LONG).unwrap();
            let stats = h.stats();
            assert_eq!((stats.batches, stats.failed_rows), (1, 0), "{stats:?}");
            assert_eq!(stats.committed_rows, 16);
            assert!(stats.write_busy > Duration::ZERO, "{stats:?}");
            let states = h.track("auv-1", T, T, 10).unwrap();
            assert_eq!(states.iter().map(|s| s.battery_pct).collect::<Vec<_>>(), [30.0]);
            assert_eq!(h.count_states(None).unwrap(), 2);
            let obs = h.observations("auv-1", "p", T, T, 10).unwrap();
            assert_eq!(obs.iter().map(|o| o.value).collect::<Vec<_>>(), [2.0]);
            let events = h.events(T, 10).unwrap();
            assert_eq!(events.iter().map(|e| e.text.as_str()).collect::<Vec<_>>(), ["second"]);
            let th = h.task_history("t-1").unwrap();
            assert_eq!(th.statuses, vec![status("new")]);
            assert_eq!(th.assignment, Some(task("m-2")));
            let vehicles = h.vehicles().unwrap();
            assert_eq!(vehicles, vec![announcement("usv-1", T + 5)]);
            assert_eq!(
                h.reader().ints_for_tests("SELECT first_seen_ms FROM vehicle").unwrap(),
                [T]
            );
        }

        fn an_older_announcement_does_not_roll_a_vehicle_back(f: &Fixture) {
            let h = History::open(&f.quick()).unwrap();
            let w = h.writer();
            let newer = VehicleAnnouncement {
                name: "new name".into(),
                ..announcement("usv-1", T + 10)
            };
            w.submit(newer.clone()).unwrap();
            h.flush(LONG).unwrap();
            // In a batch of its own: the merge with the stored row is what is tested.
            w.submit(announcement("usv-1", T)).unwrap();
            h.flush(LONG).unwrap();
            assert_eq!(h.vehicles().unwrap(), vec![newer]);
            let first_seen = h
                .reader()
                .ints_for_tests("SELECT first_seen_ms FROM vehicle")
                .unwrap();
            assert_eq!(first_seen, [T]);
            // A newer one takes over every field, and widens last seen.
            let newest = VehicleAnnouncement {
                vendor: "refitted".into(),
                ..announcement("usv-1", T + 20)
            };
            w.submit(newest.clone()).unwrap();
            h.flush(LONG).unwrap();
            assert_eq!(h.vehicles().unwrap(), vec![newest]);
        }

        fn a_full_queue_hands_the_record_back(f: &Fixture) {
            let h = History::open(&f.lingering(2)).unwrap();
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

        fn submit_blocking_waits_for_space(f: &Fixture) {
            let h = History::open(&f.lingering(1)).unwrap();
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

        fn close_drains_the_queue(f: &Fixture) {
            let config = f.lingering(10_000);
            let h = History::open(&config).unwrap();
            let w = h.writer();
            for i in 0..2500 {
                w.submit(state("auv-1", T + i)).unwrap();
            }
            // Full batches (1000) go at once; the last 500 linger until `close`.
            assert!(
                h.committed() <= 2000,
                "the writer lingers over a partial batch, yet {} are committed",
                h.committed()
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

        fn a_refused_record_is_quarantined_and_its_batch_kept(f: &Fixture) {
            let h = History::open(&f.lingering(100)).unwrap();
            let w = h.writer();
            let nan = StateVector {
                latitude_deg: f64::NAN,
                ..state("auv-1", T + 1)
            };
            let far = StateVector {
                longitude_deg: 1000.0,
                ..state("auv-1", T + 3)
            };
            let nan_battery = StateVector {
                battery_pct: f64::NAN,
                ..state("auv-1", T + 4)
            };
            w.submit(state("auv-1", T)).unwrap();
            w.submit(nan).unwrap();
            w.submit(state("auv-1", T + 2)).unwrap();
            w.submit(far.clone()).unwrap();
            w.submit(nan_battery).unwrap();
            w.submit(state("auv-1", T + 5)).unwrap();
            h.flush(LONG).unwrap();
            assert_eq!(h.committed(), 6, "quarantined records are acknowledged too");
            let kept: Vec<i64> = h
                .track("auv-1", T, T + 10, 10)
                .unwrap()
                .iter()
                .map(|s| s.timestamp_ms)
                .collect();
            assert_eq!(kept, vec![T, T + 2, T + 5]);
            let rejected = h.rejected(10).unwrap();
            assert_eq!(rejected.len(), 3);
            assert!(rejected.iter().all(|r| r.topic == "state_vector"));
            // Newest first: the NaN battery, the CHECK failure, then the NaN latitude. SQLite
            // stores a NaN as NULL, which NOT NULL refuses; PostgreSQL's CHECKs refuse NaN.
            let reasons: Vec<&str> = rejected.iter().map(|r| r.reason.as_str()).collect();
            if f.is_postgres() {
                for (reason, column) in reasons.iter().zip(["battery_pct", "longitude_deg", "latitude_deg"]) {
                    assert!(reason.contains(&format!("state_vector_{column}_check")), "{reason}");
                    assert!(reason.contains("SQLSTATE 23514"), "{reason}");
                }
            } else {
                assert!(reasons[0].contains("NOT NULL"), "{}", reasons[0]);
                assert!(reasons[1].contains("CHECK"), "{}", reasons[1]);
                assert!(reasons[2].contains("NOT NULL"), "{}", reasons[2]);
            }
            let payload: StateVector = serde_json::from_str(&rejected[1].payload_json).unwrap();
            assert_eq!(payload, far);
            assert!(rejected[0].id > rejected[1].id && rejected[1].id > rejected[2].id);
            let stats = h.stats();
            assert_eq!(
                (stats.committed_rows, stats.failed_rows, stats.batches),
                (3, 3, 1)
            );
        }

        fn a_database_failure_is_retried_not_dropped(f: &Fixture) {
            let h = History::open(&f.config()).unwrap();
            // A missing table is an environment failure, not the record's fault.
            let ddl = f.drop_table("event");
            let seq = h.writer().submit(event("e-1", T)).unwrap();
            let waited = h.wait_committed(seq, Duration::from_millis(300));
            assert!(
                matches!(waited, Err(WaitError::Timeout { committed: 0, .. })),
                "{waited:?}"
            );
            f.exec(&ddl);
            h.wait_committed(seq, LONG).unwrap();
            assert_eq!(h.events(0, 10).unwrap(), vec![event("e-1", T)]);
            let stats = h.close().unwrap();
            assert!(stats.retries >= 1);
            assert_eq!((stats.failed_rows, stats.abandoned_rows), (0, 0));
        }

        fn close_gives_up_on_records_the_database_keeps_refusing_without_acknowledging_them(
            f: &Fixture
        ) {
            let h = History::open(&f.config()).unwrap();
            f.drop_table("observation");
            let w = h.writer();
            let seq = w.submit(observation("auv-1", T)).unwrap();
            assert!(matches!(
                h.close(),
                Err(HistoryError::Unstored { records: 1 })
            ));
            assert!(matches!(
                w.wait_committed(seq, LONG),
                Err(WaitError::Stopped { committed: 0, .. })
            ));
        }

        fn a_reopened_store_sees_the_data_and_warms_up(f: &Fixture) {
            let config = f.config();
            let h = History::open(&config).unwrap();
            let w = h.writer();
            for v in ["auv-1", "auv-2", "usv-1"] {
                for i in 0..50 {
                    w.submit(state(v, T + i * 1000)).unwrap();
                }
            }
            w.submit(announcement("usv-1", T)).unwrap();
            w.submit(event("e-1", T)).unwrap();
            w.submit(Record::rejected("state", "bad", "{}")).unwrap();
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
            assert_eq!(h.events(T, 10).unwrap(), vec![event("e-1", T)]);
            // Sequence numbers are per run: a new store starts counting from 1 again.
            assert_eq!(h.writer().submit(state("auv-1", T - 1)).unwrap(), 1);
            // Quarantine ids go on from where they were.
            h.writer().submit(Record::rejected("state", "worse", "{}")).unwrap();
            h.flush(LONG).unwrap();
            let rejected = h.rejected(10).unwrap();
            let reasons: Vec<&str> = rejected.iter().map(|r| r.reason.as_str()).collect();
            assert_eq!(reasons, ["worse", "bad"]);
            assert!(rejected[0].id > rejected[1].id);
            assert_eq!(h.count_states(None).unwrap(), 151);
        }

        fn latest_states_of_an_empty_store_is_empty(f: &Fixture) {
            let h = History::open(&f.quick()).unwrap();
            assert_eq!(h.latest_states().unwrap(), vec![]);
            assert_eq!(h.count_states(None).unwrap(), 0);
            assert_eq!(h.vehicles().unwrap(), vec![]);
            assert_eq!(h.rejected(10).unwrap(), vec![]);
            assert_eq!(h.task_history("t-1").unwrap().assignment, None);
        }

        fn vehicle_ids_sort_by_bytes_on_every_backend(f: &Fixture) {
            // Byte order, whatever a server's locale would say about case and punctuation.
            let h = History::open(&f.quick()).unwrap();
            let ids = ["auv-10", "AUV-2", "auv_1", "auv-1", "auv.1", "Zeta", "a"];
            for id in ids {
                h.writer().submit(state(id, T)).unwrap();
            }
            h.flush(LONG).unwrap();
            let mut expected = ids.to_vec();
            expected.sort_unstable();
            let got: Vec<String> =
                h.latest_states().unwrap().into_iter().map(|s| s.vehicle_id).collect();
            assert_eq!(got, expected);
        }

        fn a_newer_schema_is_refused(f: &Fixture) {
            let config = f.config();
            History::open(&config).unwrap().close().unwrap();
            // The same version opens again.
            History::open(&config).unwrap().close().unwrap();
            f.set_schema_version(crate::SCHEMA_VERSION + 1);
            assert!(matches!(
                History::open(&config),
                Err(HistoryError::SchemaTooNew { found, .. }) if found == crate::SCHEMA_VERSION + 1
            ));
        }

        fn the_track_window_is_inclusive_ordered_and_limited(f: &Fixture) {
            let h = History::open(&f.quick()).unwrap();
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
            assert_eq!(
                ts(h.track("auv-1", T, T + 9, usize::MAX).unwrap()).len(),
                10
            );
            assert!(h.track("auv-3", T, T + 9, 100).unwrap().is_empty());
        }

        fn the_watch_channel_follows_commits(f: &Fixture) {
            let h = History::open(&f.quick()).unwrap();
            let mut rx = h.subscribe_committed();
            assert_eq!(*rx.borrow_and_update(), 0);
            let seq = h.writer().submit(state("auv-1", T)).unwrap();
            h.flush(LONG).unwrap();
            assert!(rx.has_changed().unwrap());
            assert_eq!(*rx.borrow_and_update(), seq);
        }

        fn task_statuses_of_one_millisecond_come_in_life_cycle_order(f: &Fixture) {
            let h = History::open(&f.quick()).unwrap();
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

        fn the_store_works_from_inside_an_async_runtime(f: &Fixture) {
            // The station opens, queries and drops its store from async code; nothing here
            // may try to start (or drop) a runtime within that one.
            let runtime = tokio::runtime::Builder::new_current_thread().build().unwrap();
            let config = f.quick();
            runtime.block_on(async move {
                let h = History::open(&config).unwrap();
                let reader = h.reader();
                let mut acks = h.subscribe_committed();
                let seq = h.writer().submit(state("auv-1", T)).unwrap();
                h.flush(LONG).unwrap();
                assert!(*acks.borrow_and_update() >= seq);
                assert_eq!(reader.count_states(None).unwrap(), 1);
                assert_eq!(reader.latest_states().unwrap(), vec![state("auv-1", T)]);
                drop(h);
                // The reader outlives the store.
                assert_eq!(reader.track("auv-1", T, T, 1).unwrap().len(), 1);
                drop(reader);
            });
        }

        fn any_valid_state_vector_round_trips_bit_for_bit(f: &Fixture) {
            let h = History::open(&f.quick()).unwrap();
            let strategy = (
                (-90.0..=90.0f64, -180.0..=180.0f64, 0.0..=11_000.0f64),
                (prop_oneof![Just(-1.0), 0.0..=10_000.0f64], 0.0..=30.0f64, 0.0..360.0f64),
                (-90.0..=90.0f64, -180.0..=180.0f64, 0.0..=100.0f64),
                shoal_model::MIN_TIMESTAMP_MS..=shoal_model::MAX_TIMESTAMP_MS,
                "[A-Za-z0-9_.-]{1,32}",
            );
            let mut runner = TestRunner::new(ProptestConfig::with_cases(24));
            runner
                .run(
                    &strategy,
                    |((lat, lon, depth), (alt, speed, yaw), (pitch, roll, battery), ts, id)| {
                        let s = StateVector {
                            vehicle_id: id, timestamp_ms: ts, latitude_deg: lat,
                            longitude_deg: lon, depth_m: depth, altitude_m: alt,
                            speed_mps: speed, yaw_deg: yaw, pitch_deg: pitch, roll_deg: roll,
                            battery_pct: battery,
                        };
                        // One store for every case: a key seen before is simply overwritten.
                        h.writer().submit(s.clone()).unwrap();
                        h.flush(LONG).unwrap();
                        prop_assert_eq!(h.track(&s.vehicle_id, ts, ts, 1).unwrap(), vec![s]);
                        Ok(())
                    },
                )
                .unwrap();
        }
    }

    #[test]
    fn the_raw_baseline_writes_the_same_table() {
        let f = crate::testing::Fixture::sqlite();
        let config = HistoryConfig {
            batch_max: 300,
            ..f.config()
        };
        let rows: Vec<StateVector> = (0..1000)
            .map(|i| state(&format!("auv-{}", i % 7), T + i))
            .collect();
        crate::raw_insert_baseline(&config, &rows, crate::RawOrder::Arrival).unwrap();
        let h = History::open(&config).unwrap();
        assert_eq!(h.count_states(None).unwrap(), 1000);
        drop(h);
        // Run again: each run starts from a fresh database.
        crate::raw_insert_baseline(&config, &rows[..10], crate::RawOrder::Key).unwrap();
        let h = History::open(&config).unwrap();
        assert_eq!(h.count_states(None).unwrap(), 10);
        assert_eq!(h.count_states(Some("auv-3")).unwrap(), 1);
    }

    /// Ingest rate through the writer, per backend: 200,000 state vectors of 20 vehicles,
    /// default batching, from submit to the last acknowledgement. A measurement, not a
    /// check: `cargo test --release -p shoal-history -- --ignored --nocapture ingest_rate`
    /// (with `SHOAL_TEST_POSTGRES_URL` set for the PostgreSQL figure).
    #[test]
    #[ignore = "benchmark; run in release with --ignored --nocapture"]
    fn ingest_rate_of_200k_state_vectors() {
        const ROWS: i64 = 200_000;
        const VEHICLES: i64 = 20;
        let rows: Vec<StateVector> = (0..ROWS)
            .map(|i| StateVector {
                latitude_deg: 43.0 + (i % 1000) as f64 * 1e-5,
                ..state(&format!("auv-{}", i % VEHICLES), T + i / VEHICLES * 100)
            })
            .collect();
        let mut fixtures = vec![crate::testing::Fixture::sqlite()];
        fixtures.extend(crate::testing::Fixture::postgres());
        for f in fixtures {
            let h = History::open(&f.config()).unwrap();
            let w = h.writer();
            let start = std::time::Instant::now();
            for row in &rows {
                w.submit_blocking(row.clone()).unwrap();
            }
            h.flush(Duration::from_secs(600)).unwrap();
            let elapsed = start.elapsed();
            let stats = h.close().unwrap();
            assert_eq!((stats.committed_rows, stats.failed_rows), (ROWS as u64, 0));
            println!(
                "{}: {ROWS} state vectors committed in {:.2} s = {:.0} rows/s ({} batches)",
                if f.is_postgres() {
                    "PostgreSQL"
                } else {
                    "SQLite"
                },
                elapsed.as_secs_f64(),
                ROWS as f64 / elapsed.as_secs_f64(),
                stats.batches
            );
        }
    }

    #[test]
    fn an_unreachable_postgres_server_fails_open_with_the_reason() {
        // Nothing listens on port 1; no server is needed for this one.
        let config = HistoryConfig::postgres(
            "host=127.0.0.1 port=1 user=shoal dbname=shoal connect_timeout=5",
            "public",
        );
        let started = std::time::Instant::now();
        match History::open(&config) {
            Err(HistoryError::Postgres(e)) => {
                let text = HistoryError::Postgres(e).to_string();
                assert!(
                    text.contains("PostgreSQL") && text.contains("connect"),
                    "{text}"
                );
            }
            other => panic!("expected a PostgreSQL error, got {other:?}"),
        }
        assert!(started.elapsed() < Duration::from_secs(30));
    }

    #[test]
    fn a_bad_postgres_configuration_fails_open_before_connecting() {
        let config = HistoryConfig::postgres("host=127.0.0.1 port=54329", "Bad-Schema");
        assert!(matches!(
            History::open(&config),
            Err(HistoryError::Config(_))
        ));
    }

    on_postgres! {
        fn postgres_refuses_nul_characters_into_quarantine(f: &Fixture) {
            // SQLite keeps a NUL inside TEXT; PostgreSQL refuses it (SQLSTATE 22021, a data
            // exception), so the record goes to quarantine, JSON-escaped.
            let h = History::open(&f.lingering(100)).unwrap();
            let w = h.writer();
            let nul = state("auv\u{0}1", T);
            w.submit(state("auv-1", T)).unwrap();
            w.submit(nul.clone()).unwrap();
            w.submit(observation("auv-1", T)).unwrap();
            // A quarantine record whose payload holds a NUL cannot be quarantined again by
            // the store either (the payload is the point of it): counted, logged, lost.
            w.submit(Record::rejected("state", "bad", "raw \u{0} bytes")).unwrap();
            h.flush(LONG).unwrap();
            assert_eq!(h.committed(), 4);
            assert_eq!(h.count_states(None).unwrap(), 1);
            assert_eq!(h.observations("auv-1", "p", T, T, 10).unwrap().len(), 1);
            let rejected = h.rejected(10).unwrap();
            assert_eq!(rejected.len(), 1, "{rejected:?}");
            assert_eq!(rejected[0].topic, "state_vector");
            assert!(rejected[0].reason.contains("SQLSTATE 22021"), "{}", rejected[0].reason);
            let payload: StateVector = serde_json::from_str(&rejected[0].payload_json).unwrap();
            assert_eq!(payload, nul);
            let stats = h.close().unwrap();
            assert_eq!((stats.committed_rows, stats.failed_rows), (2, 2));
        }

        fn the_writer_and_reader_reconnect_after_the_server_drops_them(f: &Fixture) {
            let (url, schema) = f.postgres_target().unwrap();
            // A name of its own, so that only this test's sessions are ended.
            let app = format!("{schema}_app");
            let h = History::open(&HistoryConfig {
                postgres_url: format!("{url} application_name={app}"),
                ..f.config()
            })
            .unwrap();
            h.writer().submit(state("auv-1", T)).unwrap();
            h.flush(LONG).unwrap();
            assert_eq!(h.count_states(None).unwrap(), 1);
            crate::testing::pg_exec(
                url,
                None,
                &format!(
                    "SELECT pg_terminate_backend(pid) FROM pg_stat_activity \
                     WHERE application_name = '{app}'"
                ),
            )
            .unwrap();
            let seq = h.writer().submit(state("auv-1", T + 1)).unwrap();
            h.wait_committed(seq, LONG).unwrap();
            assert_eq!(h.count_states(None).unwrap(), 2);
            let stats = h.close().unwrap();
            assert!(stats.retries >= 1, "the first attempt met the dead connection: {stats:?}");
            assert_eq!((stats.committed_rows, stats.abandoned_rows), (2, 0));
        }

        fn two_stores_in_two_schemas_do_not_see_each_other(f: &Fixture) {
            let (url, schema) = f.postgres_target().unwrap();
            let other = crate::testing::Fixture::postgres().unwrap();
            let a = History::open(&f.config()).unwrap();
            let b = History::open(&other.config()).unwrap();
            a.writer().submit(state("auv-1", T)).unwrap();
            a.flush(LONG).unwrap();
            assert_eq!((a.count_states(None).unwrap(), b.count_states(None).unwrap()), (1, 0));
            drop((a, b));
            // The schema was created by the store, with the version stamped.
            crate::testing::pg_exec(
                url,
                Some(schema),
                &format!(
                    "DO $$ BEGIN IF (SELECT version FROM shoal_schema_version) <> {} \
                     THEN RAISE 'bad version'; END IF; END $$",
                    crate::SCHEMA_VERSION
                ),
            )
            .unwrap();
        }
    }
}
