//! The station core's state, each part owned by the service named after it, and the
//! handle through which the bus, the API and tools reach them.

use std::sync::atomic::AtomicU64;
use std::sync::{Arc, Mutex, MutexGuard};

use shoal_history::{History, HistoryReader, HistoryWriter, Record, SubmitError};
use shoal_semantic::SemanticStore;
use tracing::{info, warn};

use crate::bus::Outbox;
use crate::clock::Clock;
use crate::config::StationConfig;
use crate::error::StationError;
use crate::ingest::IngestStats;
use crate::missions::TaskRegister;
use crate::register::Fleet;
use crate::reporters::Reporters;

/// How far back a restarted station reloads tasks from the history.
const TASK_MEMORY_MS: i64 = 24 * 3_600_000;

/// Everything the station keeps; one owner per kind of state.
pub(crate) struct Core {
    pub(crate) config: StationConfig,
    /// The Vehicle & Service Register: each vehicle's latest state, contact, availability.
    pub(crate) fleet: Mutex<Fleet>,
    /// The Mission & Task Register.
    pub(crate) tasks: Mutex<TaskRegister>,
    /// The Data Access Manager's counters.
    pub(crate) stats: Mutex<IngestStats>,
    /// State vectors from the bus waiting for their vehicle's announcement.
    pub(crate) early: Mutex<crate::ingest::EarlyStates>,
    /// The Event, Tasks and Environment Reporters, and the live feed.
    pub(crate) reporters: Reporters,
    /// The semantic model (ontology + a mirror of the live swarm); rules fire on insert.
    pub(crate) semantic: Mutex<SemanticStore>,
    pub(crate) history: HistoryWriter,
    pub(crate) reader: HistoryReader,
    pub(crate) outbox: Arc<dyn Outbox>,
    /// Held while a rule change is applied and saved, so saves happen in change order.
    pub(crate) rules_file: Mutex<()>,
    /// Numbers the station's own events, tasks and subscriptions.
    pub(crate) seq: AtomicU64,
    pub(crate) started_ms: i64,
    /// Station time: every timeout and timestamp the station makes (see [`Clock`]).
    pub(crate) clock: Clock,
    /// The system clock's distance from station time when last reported.
    pub(crate) reported_skew_ms: std::sync::atomic::AtomicI64,
    /// Log lines for rejected data: a flood's are cut to a budget (all still counted).
    pub(crate) rejection_log: Mutex<crate::ingest::LogBudget>,
    /// Log lines for registrations and contact changes: a large fleet coming alive or
    /// going quiet at once is summed up, not written vehicle by vehicle.
    pub(crate) fleet_log: Mutex<crate::ingest::LogBudget>,
    /// Rules disabled over their time budget, as last read from the model.
    pub(crate) rules_over_budget_seen: AtomicU64,
    /// The traffic picture (AIS), when one is attached.
    pub(crate) traffic: std::sync::OnceLock<crate::traffic::TrafficLink>,
    /// The federation with other sites, when one is attached.
    pub(crate) federation: std::sync::OnceLock<Arc<dyn crate::federation::FederationView>>,
}

/// Locks a mutex, recovering the data if a panicking thread poisoned it: the station's
/// in-memory views stay usable, and the history store is the record of truth anyway.
pub(crate) fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// A cheap, cloneable handle on the station core: what the bus feeds, the API reads and
/// operators command through.
#[derive(Clone)]
pub struct StationHandle {
    pub(crate) core: Arc<Core>,
}

impl std::fmt::Debug for StationHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StationHandle").finish_non_exhaustive()
    }
}

impl StationHandle {
    /// Builds the station core over `history`, publishing through `outbox`, and reloads
    /// what it knew before a restart: vehicles, their latest states, the last day's tasks.
    pub fn new(
        config: StationConfig,
        history: &History,
        outbox: Arc<dyn Outbox>,
    ) -> Result<Self, StationError> {
        Self::with_clock(config, history, outbox, Clock::system())
    }

    /// [`Self::new`] on a given clock (tests drive time and step the system clock).
    pub fn with_clock(
        config: StationConfig,
        history: &History,
        outbox: Arc<dyn Outbox>,
        clock: Clock,
    ) -> Result<Self, StationError> {
        config.check()?;
        let start = clock.clone();
        let now_ms = move || start.now_ms();
        for key in config.semantic.retired_keys() {
            warn!(
                key = %format_args!("station.semantic.{key}"),
                "this setting has no effect any more: contact and availability are the register's"
            );
        }
        let mut fleet = Fleet::default();
        let reader = history.reader();
        // A restarted station knows its vehicles at once; DDS re-delivers announcements
        // (transient-local) too, and re-registration is idempotent.
        for a in reader.vehicles().map_err(StationError::History)? {
            fleet.register(a);
        }
        let mut semantic =
            SemanticStore::new(config.semantic.clone()).map_err(StationError::Semantic)?;
        crate::rules::apply_rules_file(&mut semantic, &config.rules_path)?;
        for e in fleet.vehicles.values() {
            let id = &e.announcement.vehicle_id;
            if let Err(err) = semantic.upsert_vehicle(&e.announcement) {
                warn!(vehicle = %id, error = %err, "not in the semantic model");
            }
            if let Err(err) = semantic.set_availability(id, e.availability) {
                warn!(vehicle = %id, error = %err, "availability not in the semantic model");
            }
        }
        for s in reader.latest_states().map_err(StationError::History)? {
            if let Err(err) = semantic.update_state(&s) {
                warn!(vehicle = %s.vehicle_id, error = %err, "state not in the semantic model");
            }
            if let Some(e) = fleet.vehicles.get_mut(&s.vehicle_id) {
                e.latest = Some(s);
            }
        }
        fleet.recount_unheard();
        // The Mission & Task Register resumes where it was: tasks of the last day with the
        // state their recorded transitions reached.
        let mut tasks = TaskRegister::default();
        let reloaded = reader
            .tasks_since(now_ms() - TASK_MEMORY_MS, 100_000)
            .map_err(StationError::History)?;
        if !reloaded.is_empty() {
            info!(tasks = reloaded.len(), "tasks reloaded from the history");
        }
        tasks.restore(reloaded, now_ms());
        // Only what retention keeps goes on to the semantic model.
        tasks.prune(
            now_ms() - crate::config::ms(config.task_retention_s),
            config.max_ended_tasks,
        );
        for t in tasks.tasks() {
            if let Err(err) = semantic.upsert_task(&t.assignment) {
                warn!(task = %t.assignment.task_id, error = %err, "task not in the semantic model");
            }
        }
        // Sequences continue past every one ever issued, so none is repeated; and past the
        // start time in microseconds, so that even a station whose history was wiped never
        // issues a sequence a vehicle's task ledger already holds for a reused task id.
        let floor = u64::try_from(now_ms()).unwrap_or(0).saturating_mul(1000);
        let stored = reader.max_issue_seq().map_err(StationError::History)?;
        tasks.continue_sequence_after(stored.max(floor));
        let core = Core {
            fleet: Mutex::new(fleet),
            tasks: Mutex::new(tasks),
            stats: Mutex::new(IngestStats::default()),
            early: Mutex::default(),
            reporters: Reporters::default(),
            semantic: Mutex::new(semantic),
            history: history.writer(),
            reader,
            outbox,
            rules_file: Mutex::new(()),
            seq: AtomicU64::new(0),
            started_ms: now_ms(),
            clock,
            reported_skew_ms: std::sync::atomic::AtomicI64::new(0),
            rules_over_budget_seen: AtomicU64::new(0),
            traffic: std::sync::OnceLock::new(),
            federation: std::sync::OnceLock::new(),
            rejection_log: Mutex::new(crate::ingest::LogBudget::new(
                crate::ingest::REJECTION_LOG_LINES_PER_S,
            )),
            fleet_log: Mutex::new(crate::ingest::LogBudget::new(
                crate::register::FLEET_LOG_LINES_PER_S,
            )),
            config,
        };
        let handle = Self {
            core: Arc::new(core),
        };
        // Restored tasks make vehicles busy before any of them is heard again.
        handle.refresh_availability_all(now_ms());
        Ok(handle)
    }

    /// Station time now, ms since the Unix epoch: monotonic, immune to system clock steps.
    pub fn now(&self) -> i64 {
        self.core.clock.now_ms()
    }

    /// What the history's retention has done (rows thinned and deleted, database size).
    pub fn history_maintenance(&self) -> shoal_history::MaintenanceStats {
        self.core.history.maintenance_stats()
    }

    /// Tasks and missions the Mission & Task Register holds now (bounded by retention).
    pub fn register_sizes(&self) -> (usize, usize) {
        lock(&self.core.tasks).sizes()
    }

    /// Station seconds per real second: 1, or a scenario run's speed-up.
    pub fn clock_rate(&self) -> f64 {
        self.core.clock.rate()
    }

    /// How far the system clock is from station time (after a step, for health reports).
    pub fn clock_skew_ms(&self) -> i64 {
        self.core.clock.skew_ms()
    }

    /// Hands a record to the history writer; waits for room rather than lose it.
    pub(crate) fn store(&self, record: Record) {
        match self.core.history.submit(record) {
            Ok(_) => {}
            // Back-pressure instead of loss: wait for the writer thread to make room.
            Err(SubmitError::Full(record)) => {
                let w = self.core.history.clone();
                let r = blocking(move || w.submit_blocking(*record));
                if let Err(e) = r {
                    warn!(error = %e, "history store closed; record not stored");
                }
            }
            Err(e) => warn!(error = %e, "history store closed; record not stored"),
        }
    }

    /// The next number of the station's own sequence.
    pub(crate) fn next_seq(&self) -> u64 {
        self.core
            .seq
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed)
    }

    /// The station's configuration.
    pub fn config(&self) -> &StationConfig {
        &self.core.config
    }
}

/// Runs `f`, which may wait (on the bus, on the history writer) without stalling a tokio worker: other tasks move
/// to another worker meanwhile. Outside a multi-threaded runtime (a test, a
/// single-threaded tool) it just runs `f`.
pub(crate) fn blocking<R>(f: impl FnOnce() -> R) -> R {
    match tokio::runtime::Handle::try_current() {
        Ok(h) if h.runtime_flavor() == tokio::runtime::RuntimeFlavor::MultiThread => {
            tokio::task::block_in_place(f)
        }
        _ => f(),
    }
}
