//! The station core: subscribes to every topic, validates, registers, stores, dispatches.

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use futures::StreamExt;
use serde::Serialize;
use shoal_dds::{
    ParticipantEvent, Priority, PubSub, ReadError, SampleMeta, TopicType, Writer, WriterOptions,
};
use shoal_history::{History, HistoryReader, HistoryWriter, Record, SubmitError};
use shoal_model::{
    EnvironmentObservation, Event, EventKind, Severity, StateVector, TaskAssignment, TaskKind,
    TaskStatus, Validate, VehicleAnnouncement, now_ms,
};
use shoal_semantic::{QueryLimits, QueryResult, QuerySnapshot, SemanticStore};
use tokio_util::sync::CancellationToken;
use tracing::{debug, info, warn};

use crate::config::StationConfig;
use crate::error::{DispatchError, RuleChangeError, StationError};
use crate::fleet::{Contact, Fleet, VehicleView};
use crate::missions::{MissionSpec, MissionView, Register, TaskView};
use crate::preprocess::{self, Verdict};
use crate::reporters::{Ack, EnvSubscription, EnvSubscriptionSpec, EventView, LiveUpdate};
use crate::rules::{RuleDoc, RulesFile};

/// Applies the rules file: creates its user rules and switches built-in ones as saved.
fn apply_rules_file(
    semantic: &mut SemanticStore,
    path: &std::path::Path,
) -> Result<(), StationError> {
    let file = RulesFile::load(path).map_err(|e| StationError::Config(e.to_string()))?;
    let bad = |id: &str, e: &dyn std::fmt::Display| {
        StationError::Config(format!("rules file {}: rule {id}: {e}", path.display()))
    };
    for doc in &file.rules {
        if !doc.built_in {
            let spec = doc.to_spec().map_err(|e| bad(&doc.id, &e))?;
            semantic.create_rule(spec).map_err(|e| bad(&doc.id, &e))?;
        }
        match semantic.set_rule_enabled(&doc.id, doc.enabled) {
            Ok(()) => {}
            // A built-in rule this version no longer has: nothing to switch.
            Err(e) if doc.built_in => {
                warn!(path = %path.display(), rule = %doc.id, error = %e, "saved built-in rule ignored");
            }
            Err(e) => return Err(bad(&doc.id, &e)),
        }
    }
    if !file.rules.is_empty() {
        info!(path = %path.display(), rules = file.rules.len(), "rules loaded");
    }
    Ok(())
}

/// How far back a restarted station reloads tasks from the history.
const TASK_MEMORY_MS: i64 = 24 * 3_600_000;

/// How often a share of the dirty state mirrors is written to the semantic model.
const FLUSH_STEP: Duration = Duration::from_millis(100);
/// Steps in a second: each writes this fraction of the mirrors waiting.
const FLUSH_STEPS_PER_S: usize = 10;

/// A datum as JSON for the quarantine table.
fn payload<T: Serialize>(value: &T) -> String {
    serde_json::to_string(value).unwrap_or_else(|e| format!("{{\"unencodable\":\"{e}\"}}"))
}

/// Counters of what the station received, by outcome; rejections by reason code.
#[derive(Debug, Clone, Default, Serialize, PartialEq, Eq)]
pub struct IngestStats {
    /// State vectors accepted and stored.
    pub states_accepted: u64,
    /// Vehicle announcements accepted.
    pub announcements: u64,
    /// Task status reports accepted.
    pub task_status: u64,
    /// Events from vehicles accepted.
    pub events: u64,
    /// Environment observations accepted.
    pub observations: u64,
    /// Rejected data, by reason code (e.g. `out_of_range:latitude_deg`, `unknown_vehicle`).
    pub rejected: BTreeMap<String, u64>,
    /// Samples that could not even be decoded, by topic.
    pub malformed: BTreeMap<String, u64>,
    /// Tasks the station dispatched.
    pub tasks_dispatched: u64,
    /// Events raised by rules as data arrived.
    pub rule_firings: u64,
}

impl IngestStats {
    /// Every rejected or malformed datum, all reasons together.
    pub fn total_rejected(&self) -> u64 {
        self.rejected.values().sum::<u64>() + self.malformed.values().sum::<u64>()
    }
}

struct Shared {
    config: StationConfig,
    fleet: Mutex<Fleet>,
    stats: Mutex<IngestStats>,
    events: Mutex<VecDeque<Event>>,
    /// The Mission & Task Register.
    register: Mutex<Register>,
    /// Operators' acknowledgements of events, by event id.
    acks: Mutex<HashMap<String, Ack>>,
    /// The Environment Reporter's subscriptions, by id.
    env_subs: Mutex<BTreeMap<String, EnvSubscription>>,
    /// Live updates for API clients (WebSocket); lagging receivers lose the oldest.
    live: tokio::sync::broadcast::Sender<LiveUpdate>,
    /// Last time each vehicle's state went to the live feed.
    live_state_ms: Mutex<HashMap<String, i64>>,
    /// The semantic model (ontology + live swarm), updated in the same step as the history
    /// (the Data Access Manager's job); rules fire as data arrives.
    semantic: Mutex<SemanticStore>,
    history: HistoryWriter,
    reader: HistoryReader,
    task_writer: Writer<TaskAssignment>,
    abort_writer: Writer<TaskAssignment>,
    event_writer: Writer<Event>,
    alarm_writer: Writer<Event>,
    /// Held while a rule change is applied and saved, so saves happen in change order.
    rules_file: Mutex<()>,
    /// Last time a data-rejected event was raised per (vehicle, reason), to rate-limit them.
    rejection_alerts: Mutex<HashMap<(String, String), i64>>,
    event_seq: AtomicU64,
    started_ms: i64,
    /// This station's DDS participant, to recognise its own events coming back.
    participant: String,
}

/// Locks a mutex, recovering the data if a panicking thread poisoned it: the station's
/// in-memory views stay usable, and the history store is the record of truth anyway.
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// A cheap, cloneable handle for the API and tools: read the fleet, dispatch tasks.
#[derive(Clone)]
pub struct StationHandle {
    shared: Arc<Shared>,
}

impl std::fmt::Debug for StationHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StationHandle").finish_non_exhaustive()
    }
}

/// The station core, ready to run.
pub struct Station {
    shared: Arc<Shared>,
    dds: Arc<PubSub>,
    history: History,
}

impl std::fmt::Debug for Station {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Station")
            .field("dds", &self.dds)
            .finish_non_exhaustive()
    }
}

/// What the station did, returned when it stops.
#[derive(Debug, Clone, Serialize)]
pub struct StationReport {
    /// Final counters.
    pub stats: IngestStats,
    /// Records committed to the history store over the run.
    pub history_committed: u64,
}

impl Station {
    /// Creates the station's DDS writers and loads the vehicles it knew before a restart.
    pub fn new(
        config: StationConfig,
        dds: Arc<PubSub>,
        history: History,
    ) -> Result<Self, StationError> {
        config.check().map_err(StationError::Config)?;
        let control = WriterOptions::new(Priority::Control);
        let emergency = WriterOptions::new(Priority::Emergency);
        let mut fleet = Fleet::default();
        let reader = history.reader();
        // A restarted station knows its vehicles at once; DDS re-delivers announcements
        // (transient-local) too, and re-registration is idempotent.
        for a in reader.vehicles().map_err(StationError::History)? {
            fleet.register(a);
        }
        let mut semantic = SemanticStore::new(config.semantic.clone())
            .map_err(|e| StationError::Semantic(e.to_string()))?;
        // Contact loss is the station's own alarm (it also covers acoustic vehicles heard
        // through a CDT); the semantic rule would raise it a second time.
        semantic
            .set_rule_enabled(shoal_semantic::builtin::LOST_CONTACT, false)
            .map_err(|e| StationError::Semantic(e.to_string()))?;
        apply_rules_file(&mut semantic, &config.rules_path)?;
        for e in fleet.vehicles.values() {
            if let Err(err) = semantic.upsert_vehicle(&e.announcement) {
                warn!(vehicle = %e.announcement.vehicle_id, error = %err, "not in the semantic model");
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
        // The Mission & Task Register resumes where it was: tasks of the last day with the
        // state their recorded transitions reached.
        let mut register = Register::default();
        let since = now_ms() - TASK_MEMORY_MS;
        let reloaded = reader
            .tasks_since(since, 100_000)
            .map_err(StationError::History)?;
        if !reloaded.is_empty() {
            info!(tasks = reloaded.len(), "tasks reloaded from the history");
        }
        for t in reloaded.iter().filter_map(|t| t.assignment.as_ref()) {
            if let Err(err) = semantic.upsert_task(t) {
                warn!(task = %t.task_id, error = %err, "task not in the semantic model");
            }
        }
        register.restore(reloaded, now_ms());
        let shared = Arc::new(Shared {
            fleet: Mutex::new(fleet),
            stats: Mutex::new(IngestStats::default()),
            events: Mutex::new(VecDeque::new()),
            register: Mutex::new(register),
            acks: Mutex::new(HashMap::new()),
            env_subs: Mutex::new(BTreeMap::new()),
            live: tokio::sync::broadcast::channel(4096).0,
            live_state_ms: Mutex::new(HashMap::new()),
            semantic: Mutex::new(semantic),
            history: history.writer(),
            reader,
            task_writer: dds.writer(control)?,
            abort_writer: dds.writer(emergency)?,
            event_writer: dds.writer(control)?,
            alarm_writer: dds.writer(emergency)?,
            rules_file: Mutex::new(()),
            rejection_alerts: Mutex::new(HashMap::new()),
            event_seq: AtomicU64::new(0),
            started_ms: now_ms(),
            participant: dds.participant_id(),
            config,
        });
        Ok(Self {
            shared,
            dds,
            history,
        })
    }

    /// A handle for the API; valid while the station runs.
    pub fn handle(&self) -> StationHandle {
        StationHandle {
            shared: Arc::clone(&self.shared),
        }
    }

    /// Runs until `shutdown` is cancelled, then drains and closes the history store.
    pub async fn run(self, shutdown: CancellationToken) -> Result<StationReport, StationError> {
        let states = self.dds.subscribe::<StateVector>()?;
        let announcements = self.dds.subscribe::<VehicleAnnouncement>()?;
        let statuses = self.dds.subscribe::<TaskStatus>()?;
        let events = self.dds.subscribe::<Event>()?;
        let observations = self.dds.subscribe::<EnvironmentObservation>()?;
        let h = self.handle();
        let mut tasks = tokio::task::JoinSet::new();
        tasks.spawn(consume(
            states,
            h.clone(),
            shutdown.clone(),
            StationHandle::on_state,
        ));
        tasks.spawn(consume(
            announcements,
            h.clone(),
            shutdown.clone(),
            StationHandle::on_announcement,
        ));
        tasks.spawn(consume(
            statuses,
            h.clone(),
            shutdown.clone(),
            StationHandle::on_task_status,
        ));
        tasks.spawn(consume(
            events,
            h.clone(),
            shutdown.clone(),
            StationHandle::on_event,
        ));
        tasks.spawn(consume(
            observations,
            h.clone(),
            shutdown.clone(),
            StationHandle::on_observation,
        ));
        info!(participant = %self.dds.participant_id(), "station running");
        let due = lock(&self.shared.register).due_tasks();
        if !due.is_empty() {
            info!(
                tasks = due.len(),
                "sending the tasks restored missions are waiting for"
            );
            tokio::task::block_in_place(|| {
                for id in due {
                    h.send_registered(&id);
                }
            });
        }

        let cfg = &self.shared.config;
        let mut tick = tokio::time::interval(Duration::from_secs(1));
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
        let summary_every = Duration::from_secs_f64(cfg.summary_interval_s.max(0.0));
        let mut last_summary = tokio::time::Instant::now();
        let mut flush = tokio::time::interval(FLUSH_STEP);
        flush.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
        loop {
            tokio::select! {
                () = shutdown.cancelled() => break,
                _ = flush.tick() => h.semantic_flush_step(),
                _ = tick.tick() => {
                    for ev in self.dds.participant_events() {
                        log_participant_event(&ev);
                        if let ParticipantEvent::Lost { participant, reason } = &ev {
                            h.participant_left(participant, reason);
                        }
                    }
                    h.refresh_contact().await;
                    h.expire_tasks();
                    h.semantic_tick();
                    if !summary_every.is_zero() && last_summary.elapsed() >= summary_every {
                        last_summary = tokio::time::Instant::now();
                        h.log_summary();
                    }
                }
            }
        }
        info!("station stopping: draining subscriptions and history");
        while tasks.join_next().await.is_some() {}
        let stats = h.stats();
        drop(h);
        let history = self.history;
        let closed = tokio::task::spawn_blocking(move || history.close())
            .await
            .map_err(|e| StationError::Shutdown(e.to_string()))?
            .map_err(StationError::History)?;
        info!(committed = closed.committed_rows, "history closed");
        Ok(StationReport {
            stats,
            history_committed: closed.committed_rows,
        })
    }
}

async fn consume<T, F>(
    mut sub: shoal_dds::Subscription<T>,
    h: StationHandle,
    shutdown: CancellationToken,
    on_sample: F,
) where
    T: TopicType,
    F: Fn(&StationHandle, T, &SampleMeta),
{
    loop {
        let item = tokio::select! {
            () = shutdown.cancelled() => return,
            item = sub.next() => item,
        };
        match item {
            None => return,
            Some(Ok((sample, meta))) => on_sample(&h, sample, &meta),
            Some(Err(e)) => h.on_read_error::<T>(&e),
        }
    }
}

fn log_participant_event(ev: &ParticipantEvent) {
    match ev {
        ParticipantEvent::Discovered { participant, name } => {
            info!(%participant, name = name.as_deref().unwrap_or("-"), "DDS participant discovered");
        }
        ParticipantEvent::Lost {
            participant,
            reason,
        } => {
            info!(%participant, %reason, "DDS participant lost");
        }
        ParticipantEvent::IncompatibleWriter { writer, detail } => {
            warn!(%writer, %detail, "a remote writer's QoS cannot serve the station; it will not be heard");
        }
        ParticipantEvent::IncompatibleReader { reader, detail } => {
            warn!(%reader, %detail, "a remote reader's QoS cannot be served by the station");
        }
        _ => {}
    }
}

impl StationHandle {
    fn store(&self, record: Record) {
        match self.shared.history.submit(record) {
            Ok(_) => {}
            // Back-pressure instead of loss: wait for the writer thread to make room.
            Err(SubmitError::Full(record)) => {
                let w = self.shared.history.clone();
                let r = tokio::task::block_in_place(move || w.submit_blocking(*record));
                if let Err(e) = r {
                    warn!(error = %e, "history store closed; record not stored");
                }
            }
            Err(e) => warn!(error = %e, "history store closed; record not stored"),
        }
    }

    fn reject(
        &self,
        topic: &str,
        vehicle_id: &str,
        reason: &str,
        detail: &str,
        payload_json: String,
    ) {
        *lock(&self.shared.stats)
            .rejected
            .entry(reason.to_string())
            .or_default() += 1;
        if let Some(e) = lock(&self.shared.fleet).vehicles.get_mut(vehicle_id) {
            e.states_rejected += 1;
        }
        warn!(topic, vehicle = vehicle_id, reason, detail, "data rejected");
        self.store(Record::rejected(topic, reason, payload_json));
        self.alert_rejection(topic, vehicle_id, reason, detail);
    }

    /// A sample refused by the P/S Manager's security (unsigned, forged, replayed, revoked,
    /// not allowed): counted as `security:<reason>` and reported, never stored, because
    /// nothing in it can be trusted, not even the vehicle it names.
    fn refuse(&self, topic: &str, reason: &str, detail: &str) {
        let reason = format!("security:{reason}");
        *lock(&self.shared.stats)
            .rejected
            .entry(reason.clone())
            .or_default() += 1;
        debug!(topic, reason, detail, "sample refused by security");
        self.alert_rejection(topic, "", &reason, detail);
    }

    /// One event per vehicle and reason per minute: enough for the operator, no flood.
    fn alert_rejection(&self, topic: &str, vehicle_id: &str, reason: &str, detail: &str) {
        let now = now_ms();
        let key = (vehicle_id.to_string(), reason.to_string());
        let raise = {
            let mut alerts = lock(&self.shared.rejection_alerts);
            let due = alerts.get(&key).is_none_or(|t| now - t >= 60_000);
            if due {
                alerts.insert(key, now);
            }
            due
        };
        if raise {
            self.raise(
                Severity::Warning,
                EventKind::DataRejected,
                vehicle_id,
                "",
                &format!("{topic} rejected: {reason}: {detail}"),
            );
        }
    }

    fn on_read_error<T: TopicType>(&self, e: &ReadError) {
        match e {
            ReadError::Invalid { error, payload, .. } => {
                // The vehicle id is only trusted if it is itself well-formed.
                let vehicle = serde_json::from_str::<serde_json::Value>(payload)
                    .ok()
                    .and_then(|v| {
                        v.get("vehicle_id")
                            .and_then(|v| v.as_str())
                            .map(str::to_string)
                    })
                    .filter(|id| shoal_model::is_identifier(id, shoal_model::MAX_VEHICLE_ID_LEN))
                    .unwrap_or_default();
                self.reject(
                    T::TOPIC,
                    &vehicle,
                    &error.reason().to_string(),
                    &error.to_string(),
                    payload.clone(),
                );
            }
            ReadError::Malformed { detail, .. } => {
                *lock(&self.shared.stats)
                    .malformed
                    .entry(T::TOPIC.to_string())
                    .or_default() += 1;
                self.store(Record::rejected(
                    T::TOPIC,
                    format!("malformed: {detail}"),
                    "null",
                ));
            }
            ReadError::Unsigned { .. } => {
                self.refuse(
                    T::TOPIC,
                    "unsigned",
                    "no signature: the sender has security off",
                );
            }
            ReadError::Refused { reason, detail, .. } => self.refuse(T::TOPIC, reason, detail),
            other => warn!(topic = T::TOPIC, error = %other, "read failed"),
        }
    }

    fn on_state(&self, s: StateVector, _meta: &SampleMeta) {
        // Rejections are counted, quarantined and reported inside.
        let _ = self.ingest_state(s);
    }

    /// Takes one state vector through the Data Access Manager in one step: validation and
    /// plausibility (the Data Pre-Processor), the vehicle's latest state, the semantic
    /// model and its rules, the history store. A rejected state vector is counted by
    /// reason, quarantined with its payload and reported as an event; the reason code is
    /// returned.
    pub fn ingest_state(&self, s: StateVector) -> Result<(), String> {
        if let Err(e) = s.validate() {
            let reason = e.reason().to_string();
            let id = if shoal_model::is_identifier(&s.vehicle_id, shoal_model::MAX_VEHICLE_ID_LEN) {
                s.vehicle_id.clone()
            } else {
                String::new()
            };
            self.reject(
                StateVector::TOPIC,
                &id,
                &reason,
                &e.to_string(),
                payload(&s),
            );
            return Err(reason);
        }
        let now = now_ms();
        let mut fleet = lock(&self.shared.fleet);
        let (verdict, newer) = match fleet.vehicles.get_mut(&s.vehicle_id) {
            Some(e) => {
                let verdict = preprocess::judge(
                    &self.shared.config.plausibility,
                    e.latest.as_ref(),
                    &mut e.suspects,
                    &s,
                    e.announcement.max_speed_mps,
                    now,
                );
                // Even a rejected sample proves the vehicle is heard: a bad clock must not
                // also look like a lost vehicle.
                e.last_contact_ms = Some(now);
                let newer = e
                    .latest
                    .as_ref()
                    .is_none_or(|l| l.timestamp_ms < s.timestamp_ms);
                if !matches!(verdict, Verdict::Reject(_)) {
                    // A late sample (acoustic store-and-forward) goes to the history only.
                    if newer {
                        e.battery_rising = e
                            .latest
                            .as_ref()
                            .is_some_and(|l| s.battery_pct > l.battery_pct && l.battery_pct >= 0.0);
                        e.latest = Some(s.clone());
                    }
                    e.states_accepted += 1;
                }
                (verdict, newer)
            }
            None if self.shared.config.require_announcement => {
                drop(fleet);
                let id = s.vehicle_id.clone();
                let reason = "unknown_vehicle";
                let detail = format!("{id} never announced itself");
                self.reject(StateVector::TOPIC, &id, reason, &detail, payload(&s));
                return Err(reason.into());
            }
            None => (Verdict::Accept, true),
        };
        drop(fleet);
        match verdict {
            Verdict::Accept => {}
            Verdict::Reject(why) => {
                let id = s.vehicle_id.clone();
                self.reject(
                    StateVector::TOPIC,
                    &id,
                    why.reason(),
                    &why.to_string(),
                    payload(&s),
                );
                return Err(why.reason().into());
            }
            Verdict::Reanchor(why) => {
                let text = format!(
                    "{} re-anchored after consistent data that looked implausible ({why})",
                    s.vehicle_id
                );
                warn!(vehicle = %s.vehicle_id, %why, "vehicle re-anchored");
                self.raise(
                    Severity::Warning,
                    EventKind::Other,
                    &s.vehicle_id,
                    "",
                    &text,
                );
            }
        }
        lock(&self.shared.stats).states_accepted += 1;
        if newer {
            // Typed and cheap: the RDF mirror is written coalesced, once a second per vehicle.
            let fired = lock(&self.shared.semantic).update_state(&s);
            self.emit_fired(fired);
        }
        if newer {
            self.push_state(&s.vehicle_id);
        }
        self.store(Record::State(s));
        Ok(())
    }

    /// Sends a vehicle's view to live clients, at most once a second per vehicle.
    fn push_state(&self, vehicle_id: &str) {
        if self.shared.live.receiver_count() == 0 {
            return;
        }
        let now = now_ms();
        {
            let mut last = lock(&self.shared.live_state_ms);
            if last.get(vehicle_id).is_some_and(|t| now - t < 1000) {
                return;
            }
            last.insert(vehicle_id.to_owned(), now);
        }
        if let Some(v) = self.vehicle(vehicle_id) {
            let _ = self.shared.live.send(LiveUpdate::Vehicle(Box::new(v)));
        }
    }

    /// The timestamp checks for data other than state vectors; true when accepted.
    fn timely(
        &self,
        topic: &str,
        vehicle_id: &str,
        timestamp_ms: i64,
        json: impl FnOnce() -> String,
    ) -> bool {
        match preprocess::check_time(&self.shared.config.plausibility, timestamp_ms, now_ms()) {
            None => true,
            Some(why) => {
                self.reject(topic, vehicle_id, why.reason(), &why.to_string(), json());
                false
            }
        }
    }

    fn on_announcement(&self, a: VehicleAnnouncement, meta: &SampleMeta) {
        let id = a.vehicle_id.clone();
        self.register(a, &meta.writer);
        if let Some(e) = lock(&self.shared.fleet).vehicles.get_mut(&id) {
            e.participant = Some(meta.participant.clone());
        }
    }

    /// DDS discovery says a participant left: the vehicles heard through it are lost now.
    fn participant_left(&self, participant: &str, reason: &str) {
        let gone = lock(&self.shared.fleet).participant_left(participant, now_ms());
        for id in gone {
            info!(vehicle = %id, %participant, reason, "the vehicle's DDS participant left");
        }
    }

    /// Registers (or re-registers) a vehicle as if it had announced itself, e.g. from the
    /// operator's tool; the announcement is validated first.
    pub fn register_vehicle(
        &self,
        a: VehicleAnnouncement,
    ) -> Result<(), shoal_model::ValidationError> {
        a.validate()?;
        self.register(a, "operator");
        Ok(())
    }

    fn register(&self, a: VehicleAnnouncement, source: &str) {
        let new = lock(&self.shared.fleet).register(a.clone());
        lock(&self.shared.stats).announcements += 1;
        let fired = lock(&self.shared.semantic).upsert_vehicle(&a);
        self.emit_fired(fired);
        if new {
            info!(vehicle = %a.vehicle_id, kind = %a.kind, vendor = %a.vendor, source, "vehicle registered");
        } else {
            debug!(vehicle = %a.vehicle_id, "vehicle re-announced");
        }
        self.store(Record::Vehicle(a));
    }

    fn on_task_status(&self, s: TaskStatus, _meta: &SampleMeta) {
        if !self.timely(TaskStatus::TOPIC, &s.vehicle_id, s.timestamp_ms, || {
            payload(&s)
        }) {
            return;
        }
        let now = now_ms();
        // A relay that gave up on delivering a task acoustically: send it again while
        // retries last, instead of expiring it.
        if s.state == shoal_model::TaskState::Expired {
            let again = lock(&self.shared.register).retry(
                &s.task_id,
                self.shared.config.acoustic_task_retries,
                now,
            );
            if let Some(a) = again {
                warn!(task = %s.task_id, vehicle = %s.vehicle_id, reason = %s.message, "task not delivered acoustically; sending it again");
                self.store(Record::Task(a));
                let id = s.task_id.clone();
                self.store(Record::TaskStatus(s));
                self.send_registered(&id);
                return;
            }
        }
        let changed = lock(&self.shared.register).on_status(&s, now);
        let Some(changed) = changed else {
            // Not a task this station gave that vehicle: nothing to track, nothing to store.
            warn!(task = %s.task_id, vehicle = %s.vehicle_id, state = ?s.state, "status for a task this station never gave that vehicle; ignored");
            *lock(&self.shared.stats)
                .rejected
                .entry("unknown_task".into())
                .or_default() += 1;
            return;
        };
        lock(&self.shared.stats).task_status += 1;
        let fired = lock(&self.shared.semantic).task_status(&s);
        self.emit_fired(fired);
        info!(task = %s.task_id, vehicle = %s.vehicle_id, state = ?s.state, progress = s.progress_pct, "task status");
        if changed {
            self.task_changed(&s.task_id, s.state, &s.message);
        }
        self.store(Record::TaskStatus(s));
    }

    /// Reports a task's new state (Tasks Reporter) and moves its mission on.
    fn task_changed(&self, task_id: &str, state: shoal_model::TaskState, message: &str) {
        use shoal_model::TaskState;
        self.push_task(task_id);
        let vehicle = lock(&self.shared.register)
            .task(task_id)
            .map(|t| t.assignment.vehicle_id.clone())
            .unwrap_or_default();
        let severity = match state {
            TaskState::Failed | TaskState::Expired => Severity::Warning,
            _ => Severity::Info,
        };
        if state.is_final() || state == TaskState::Accepted {
            let state_name = format!("{state:?}").to_lowercase();
            let text = if message.is_empty() {
                format!("task {task_id} {state_name}")
            } else {
                format!("task {task_id} {state_name}: {message}")
            };
            self.raise(severity, EventKind::Task, &vehicle, task_id, &text);
        }
        let next = lock(&self.shared.register).advance(task_id, now_ms());
        self.record_transitions();
        for id in next {
            self.send_registered(&id);
        }
        self.push_mission_of(task_id);
    }

    /// Writes the state changes the station made itself to the history and the model, so
    /// the history holds every transition (and a restarted station can resume).
    /// Live consoles are told of each task that changed and of its mission once.
    fn record_transitions(&self) {
        let records = lock(&self.shared.register).take_transitions();
        let mut task_ids = std::collections::BTreeSet::new();
        for s in records {
            let fired = lock(&self.shared.semantic).task_status(&s);
            self.emit_fired(fired);
            self.push_task(&s.task_id);
            task_ids.insert(s.task_id.clone());
            self.store(Record::TaskStatus(s));
        }
        let mut pushed = std::collections::BTreeSet::new();
        for task_id in task_ids {
            if let Some(m) = self.task(&task_id).map(|t| t.assignment.mission_id)
                && pushed.insert(m.clone())
                && let Some(view) = self.mission(&m)
            {
                let _ = self.shared.live.send(LiveUpdate::Mission(Box::new(view)));
            }
        }
    }

    fn push_task(&self, task_id: &str) {
        if let Some(t) = self.task(task_id) {
            let _ = self.shared.live.send(LiveUpdate::Task(Box::new(t)));
        }
    }

    fn push_mission_of(&self, task_id: &str) {
        let mission = self
            .task(task_id)
            .map(|t| t.assignment.mission_id)
            .and_then(|m| self.mission(&m));
        if let Some(m) = mission {
            let _ = self.shared.live.send(LiveUpdate::Mission(Box::new(m)));
        }
    }

    /// A live feed of events, tasks, missions, vehicle states (≤ 1 Hz each) and subscribed
    /// observations; a receiver that falls behind loses the oldest updates.
    pub fn live(&self) -> tokio::sync::broadcast::Receiver<LiveUpdate> {
        self.shared.live.subscribe()
    }

    /// Recent events with their acknowledgements, oldest first.
    pub fn event_views(&self) -> Vec<EventView> {
        let acks = lock(&self.shared.acks);
        lock(&self.shared.events)
            .iter()
            .map(|e| EventView {
                acknowledged: acks.get(&e.event_id).cloned(),
                event: e.clone(),
            })
            .collect()
    }

    /// An operator acknowledges an event; acknowledging twice keeps the first. The
    /// acknowledgement is itself stored in the history as an event.
    pub fn acknowledge(&self, event_id: &str, by: &str) -> Option<EventView> {
        let event = lock(&self.shared.events)
            .iter()
            .find(|e| e.event_id == event_id)
            .cloned()?;
        let by: String = by.chars().take(shoal_model::MAX_NAME_LEN).collect();
        let (ack, new) = {
            let mut acks = lock(&self.shared.acks);
            match acks.get(event_id) {
                Some(a) => (a.clone(), false),
                None => {
                    let a = Ack {
                        by: by.clone(),
                        at_ms: now_ms(),
                    };
                    acks.insert(event_id.to_owned(), a.clone());
                    (a, true)
                }
            }
        };
        if new {
            info!(event = event_id, by = %by, "event acknowledged");
            let seq = self.shared.event_seq.fetch_add(1, Ordering::Relaxed);
            let record = Event {
                event_id: format!("station-{}-{seq}", self.shared.started_ms),
                timestamp_ms: ack.at_ms,
                severity: Severity::Info,
                kind: EventKind::Other,
                vehicle_id: event.vehicle_id.clone(),
                task_id: event.task_id.clone(),
                text: format!("acknowledged {event_id} by {by}"),
            };
            self.store(Record::Event(record));
        }
        let view = EventView {
            event,
            acknowledged: Some(ack),
        };
        let _ = self.shared.live.send(LiveUpdate::Event(view.clone()));
        Some(view)
    }

    /// Subscribes to environment observations (Environment Reporter).
    pub fn subscribe_environment(
        &self,
        spec: EnvSubscriptionSpec,
    ) -> Result<EnvSubscription, String> {
        spec.check()?;
        let seq = self.shared.event_seq.fetch_add(1, Ordering::Relaxed);
        let sub = EnvSubscription {
            id: format!("env-{seq}"),
            spec,
            delivered: 0,
            recent: VecDeque::new(),
            last_ms: HashMap::new(),
        };
        lock(&self.shared.env_subs).insert(sub.id.clone(), sub.clone());
        Ok(sub)
    }

    /// Every environment subscription.
    pub fn environment_subscriptions(&self) -> Vec<EnvSubscription> {
        lock(&self.shared.env_subs).values().cloned().collect()
    }

    /// The observations a subscription matched, oldest first (the latest 1000).
    pub fn environment_observations(&self, id: &str) -> Option<Vec<EnvironmentObservation>> {
        lock(&self.shared.env_subs)
            .get(id)
            .map(|s| s.recent.iter().cloned().collect())
    }

    /// Ends a subscription; false if there was none.
    pub fn unsubscribe_environment(&self, id: &str) -> bool {
        lock(&self.shared.env_subs).remove(id).is_some()
    }

    fn on_event(&self, e: Event, meta: &SampleMeta) {
        // The station hears its own events (its alarms, rule firings) too, on the same
        // topic; they are already recorded.
        if meta.participant == self.shared.participant {
            return;
        }
        if !self.timely(Event::TOPIC, &e.vehicle_id, e.timestamp_ms, || payload(&e)) {
            return;
        }
        // A CDT's link table entry: link metadata for the vehicle, not an operator event.
        if let Some(status) = shoal_model::LinkStatus::from_event(&e) {
            let mut fleet = lock(&self.shared.fleet);
            if let Some(v) = fleet.vehicles.get_mut(&status.vehicle_id) {
                if v.link != status.link {
                    info!(vehicle = %status.vehicle_id, link = ?status.link, "vehicle heard on a new link");
                }
                v.link = status.link;
                v.link_status = Some(status);
            }
            drop(fleet);
            self.store(Record::Event(e));
            return;
        }
        lock(&self.shared.stats).events += 1;
        if e.kind == EventKind::Fault
            && let Some(v) = lock(&self.shared.fleet).vehicles.get_mut(&e.vehicle_id)
        {
            v.last_fault_ms = Some(now_ms());
        }
        let fired = lock(&self.shared.semantic).add_event(&e);
        self.emit_fired(fired);
        self.remember_event(e.clone());
        self.store(Record::Event(e));
    }

    fn on_observation(&self, o: EnvironmentObservation, _meta: &SampleMeta) {
        if !self.timely(
            EnvironmentObservation::TOPIC,
            &o.vehicle_id,
            o.timestamp_ms,
            || payload(&o),
        ) {
            return;
        }
        lock(&self.shared.stats).observations += 1;
        let now = now_ms();
        let matched: Vec<String> = lock(&self.shared.env_subs)
            .values_mut()
            .filter_map(|sub| sub.offer(&o, now).then(|| sub.id.clone()))
            .collect();
        for subscription in matched {
            let _ = self.shared.live.send(LiveUpdate::Observation {
                subscription,
                observation: o.clone(),
            });
        }
        let fired = lock(&self.shared.semantic).add_observation(&o);
        self.emit_fired(fired);
        self.store(Record::Observation(o));
    }

    fn remember_event(&self, e: Event) {
        let _ = self.shared.live.send(LiveUpdate::Event(EventView {
            event: e.clone(),
            acknowledged: None,
        }));
        let mut events = lock(&self.shared.events);
        events.push_back(e);
        while events.len() > self.shared.config.recent_events {
            events.pop_front();
        }
    }

    /// Raises a station event: kept, stored, and published on DDS (alarms on the emergency class).
    pub fn raise(
        &self,
        severity: Severity,
        kind: EventKind,
        vehicle_id: &str,
        task_id: &str,
        text: &str,
    ) {
        let seq = self.shared.event_seq.fetch_add(1, Ordering::Relaxed);
        let e = Event {
            event_id: format!("station-{}-{seq}", self.shared.started_ms),
            timestamp_ms: now_ms(),
            severity,
            kind,
            vehicle_id: vehicle_id.to_string(),
            task_id: task_id.to_string(),
            text: text.chars().take(shoal_model::MAX_TEXT_LEN).collect(),
        };
        self.emit(e);
    }

    /// Records, stores and publishes an event the station produced (its own or a rule's).
    fn emit(&self, e: Event) {
        if let Err(err) = e.validate() {
            warn!(error = %err, "station event not raised: invalid");
            return;
        }
        info!(kind = ?e.kind, severity = ?e.severity, vehicle = %e.vehicle_id, text = %e.text, "event");
        // Rule firings enter the model too, so rules and queries can see them.
        if !e.event_id.starts_with("station-")
            && let Err(err) = lock(&self.shared.semantic).add_event(&e)
        {
            warn!(error = %err, "event not in the semantic model");
        }
        let severity = e.severity;
        self.remember_event(e.clone());
        self.store(Record::Event(e.clone()));
        let writer = if severity >= Severity::Alarm {
            &self.shared.alarm_writer
        } else {
            &self.shared.event_writer
        };
        if let Err(err) = writer.write_blocking(e) {
            warn!(error = %err, "event not published on DDS");
        }
    }

    /// Emits the events rules fired; a failed model update is logged, never fatal.
    fn emit_fired(&self, fired: Result<Vec<Event>, shoal_semantic::StoreError>) {
        match fired {
            Ok(events) => {
                for e in events {
                    lock(&self.shared.stats).rule_firings += 1;
                    self.emit(e);
                }
            }
            Err(e) => warn!(error = %e, "semantic model update failed"),
        }
    }

    /// Every [`FLUSH_STEP`]: mirrors a share of the dirty states into RDF (coalesced: a
    /// vehicle at most once per `semantic.min_state_interval_ms`), so that the mirrors of a
    /// second are written in [`FLUSH_STEPS_PER_S`] small parts spread over it. Written all
    /// at once, a thousand mirrors took 10 to 15 ms of one core each second, and the state
    /// vectors arriving meanwhile waited behind them (the 5 to 10 ms tail of vehicle ->
    /// console latency). Each part is written a few vehicles per hold of the model's lock,
    /// which ingest takes for every state vector.
    fn semantic_flush_step(&self) {
        const MIRRORS_PER_LOCK: usize = 32;
        let now = now_ms();
        let mut left = lock(&self.shared.semantic)
            .dirty_len()
            .div_ceil(FLUSH_STEPS_PER_S);
        while left > 0 {
            let part = left.min(MIRRORS_PER_LOCK);
            let fired = lock(&self.shared.semantic).flush_dirty_at_most(now, part);
            left -= part;
            self.emit_fired(fired);
        }
    }

    /// Once a second: the time-based rules.
    fn semantic_tick(&self) {
        let fired = lock(&self.shared.semantic).tick(now_ms());
        self.emit_fired(fired);
    }

    /// A read-only view of the semantic model for SPARQL queries, taken without holding
    /// the model's lock while the query runs.
    pub fn semantic_snapshot(&self) -> QuerySnapshot {
        lock(&self.shared.semantic).snapshot()
    }

    /// Runs a read-only SPARQL query over the semantic model, within `limits`.
    pub fn sparql(
        &self,
        query: &str,
        limits: &QueryLimits,
    ) -> Result<QueryResult, shoal_semantic::QueryError> {
        self.semantic_snapshot().query(query, limits)
    }

    async fn refresh_contact(&self) {
        let cfg = &self.shared.config;
        #[allow(clippy::cast_possible_truncation)]
        let (stale, lost) = (
            (cfg.stale_after_s * 1000.0) as i64,
            (cfg.lost_after_s * 1000.0) as i64,
        );
        let changed = lock(&self.shared.fleet).refresh_contact(now_ms(), stale, lost);
        for (id, from, to) in changed {
            match to {
                Contact::Lost => {
                    let left = lock(&self.shared.fleet).vehicles.get(&id).is_some_and(|e| {
                        e.left_ms
                            .is_some_and(|l| e.last_contact_ms.is_some_and(|t| l >= t))
                    });
                    let text = if left {
                        format!("lost contact with {id}: its DDS participant left")
                    } else {
                        format!("no state vector from {id} for {:.0} s", cfg.lost_after_s)
                    };
                    self.raise(Severity::Alarm, EventKind::CommLost, &id, "", &text);
                }
                Contact::Alive if from == Contact::Lost => {
                    self.raise(
                        Severity::Info,
                        EventKind::Other,
                        &id,
                        "",
                        &format!("contact with {id} regained"),
                    );
                }
                _ => {}
            }
            info!(vehicle = %id, from = ?from, to = ?to, "contact changed");
            // Stale and lost happen exactly when the vehicle sends nothing, so no state
            // carries the change to live clients: push the vehicle's view now.
            if let Some(v) = self.vehicle(&id) {
                let _ = self.shared.live.send(LiveUpdate::Vehicle(Box::new(v)));
            }
        }
    }

    /// Logs the fleet: a line per vehicle for a small fleet, counts by contact for a large
    /// one (ten thousand lines every few seconds help nobody). The lines are formatted
    /// after the fleet's lock is released, since ingest takes it for every state vector.
    fn log_summary(&self) {
        const VEHICLE_LINES_UP_TO: usize = 20;
        let now = now_ms();
        let (mut lines, mut counts) = (Vec::new(), None);
        let fleet = lock(&self.shared.fleet);
        let total = fleet.vehicles.len();
        if total <= VEHICLE_LINES_UP_TO {
            for (id, e) in &fleet.vehicles {
                lines.push((
                    id.clone(),
                    e.announcement.kind.as_str(),
                    e.contact,
                    e.latest.clone(),
                    e.last_contact_ms,
                    e.states_accepted,
                ));
            }
        } else {
            let count = |c| fleet.vehicles.values().filter(|e| e.contact == c).count();
            counts = Some(
                [
                    Contact::Alive,
                    Contact::Stale,
                    Contact::Lost,
                    Contact::Silent,
                ]
                .map(count),
            );
        }
        drop(fleet);
        if total == 0 {
            info!("no vehicles yet");
        }
        if let Some([alive, stale, lost, silent]) = counts {
            info!(vehicles = total, alive, stale, lost, silent, "fleet");
        }
        lines.sort_by(|a, b| a.0.cmp(&b.0));
        for (id, kind, contact, latest, last_contact_ms, n) in lines {
            #[allow(clippy::cast_precision_loss)]
            let ago = last_contact_ms.map_or_else(
                || "never".to_string(),
                |t| format!("{:.1}s ago", (now - t) as f64 / 1000.0),
            );
            match latest {
                Some(s) => info!(
                    "{id:<10} {kind:<6} {contact:<6} lat {lat:>9.5} lon {lon:>10.5} depth {depth:>6.1} m speed {speed:>4.1} m/s heading {yaw:>5.1} battery {batt:>5.1}% last {ago} states {n}",
                    contact = format!("{contact:?}").to_lowercase(),
                    lat = s.latitude_deg,
                    lon = s.longitude_deg,
                    depth = s.depth_m,
                    speed = s.speed_mps,
                    yaw = s.yaw_deg,
                    batt = s.battery_pct,
                ),
                None => info!("{id:<10} {kind:<6} announced, no state yet"),
            }
        }
        let stats = self.stats();
        info!(
            accepted = stats.states_accepted,
            rejected = stats.total_rejected(),
            history_committed = self.shared.history.committed(),
            "ingest"
        );
    }

    /// Every known vehicle, sorted by id.
    pub fn fleet(&self) -> Vec<VehicleView> {
        let busy = self.busy_vehicles();
        lock(&self.shared.fleet).view(|id| busy.contains(id), now_ms())
    }

    /// One vehicle.
    pub fn vehicle(&self, id: &str) -> Option<VehicleView> {
        let busy = !lock(&self.shared.register).active_tasks_of(id).is_empty();
        lock(&self.shared.fleet)
            .vehicles
            .get(id)
            .map(|e| e.view(busy, now_ms()))
    }

    fn busy_vehicles(&self) -> std::collections::HashSet<String> {
        lock(&self.shared.register)
            .busy_vehicles()
            .into_iter()
            .map(str::to_owned)
            .collect()
    }

    /// Current counters.
    pub fn stats(&self) -> IngestStats {
        lock(&self.shared.stats).clone()
    }

    /// Records committed to the history store so far (acknowledged data).
    pub fn history_committed(&self) -> u64 {
        self.shared.history.committed()
    }

    /// Waits until everything submitted to the history store so far is committed.
    pub fn flush_history(&self, timeout: Duration) -> Result<(), shoal_history::WaitError> {
        self.shared.history.flush(timeout)
    }

    /// Read access to the history store.
    pub fn history(&self) -> &HistoryReader {
        &self.shared.reader
    }

    /// Recent events, oldest first.
    pub fn recent_events(&self) -> Vec<Event> {
        lock(&self.shared.events).iter().cloned().collect()
    }

    /// Tasks issued since the station started, by id.
    pub fn tasks(&self) -> Vec<TaskView> {
        lock(&self.shared.register).tasks()
    }

    /// One task.
    pub fn task(&self, task_id: &str) -> Option<TaskView> {
        lock(&self.shared.register).task(task_id).cloned()
    }

    /// Every mission, by id.
    pub fn missions(&self) -> Vec<MissionView> {
        lock(&self.shared.register).missions()
    }

    /// One mission.
    pub fn mission(&self, mission_id: &str) -> Option<MissionView> {
        lock(&self.shared.register).mission(mission_id)
    }

    /// Remote readers matched by the station's (control-class) task writer now.
    pub fn task_readers(&self) -> i32 {
        self.shared.task_writer.matched_readers()
    }

    /// Every rule, built-in ones included, ordered by identifier.
    pub fn rules(&self) -> Vec<RuleDoc> {
        lock(&self.shared.semantic)
            .rules()
            .iter()
            .map(RuleDoc::from_info)
            .collect()
    }

    /// One rule.
    pub fn rule(&self, id: &str) -> Option<RuleDoc> {
        self.rules().into_iter().find(|r| r.id == id)
    }

    /// Creates a user rule (checked and, for SPARQL, parsed now); it is saved for restarts.
    pub fn create_rule(&self, doc: &RuleDoc) -> Result<RuleDoc, RuleChangeError> {
        self.change_rules(&doc.id, |sem| {
            sem.create_rule(doc.to_spec()?)?;
            if !doc.enabled {
                sem.set_rule_enabled(&doc.id, false)?;
            }
            Ok(())
        })
    }

    /// Enables or disables a rule, built-in ones included.
    pub fn set_rule_enabled(&self, id: &str, enabled: bool) -> Result<RuleDoc, RuleChangeError> {
        self.change_rules(id, |sem| sem.set_rule_enabled(id, enabled))
    }

    /// Replaces a user rule's definition (description, severity, kind, condition, enabled)
    /// with `doc`, checked exactly as [`Self::create_rule`] checks a new one. On a refused
    /// definition the rule stays as it was; built-in rules can only be enabled or disabled.
    pub fn replace_rule(&self, doc: &RuleDoc) -> Result<RuleDoc, RuleChangeError> {
        self.change_rules(&doc.id, |sem| {
            let old = sem
                .rules()
                .into_iter()
                .find(|r| r.spec.id == doc.id)
                .ok_or_else(|| shoal_semantic::RuleError::NotFound(doc.id.clone()))?;
            if old.built_in {
                return Err(shoal_semantic::RuleError::BuiltIn(doc.id.clone()));
            }
            // A threshold expression is parsed here, before anything changes.
            let spec = doc.to_spec()?;
            // The store has no in-place update: the semantic lock is held throughout, so
            // no datum is ever checked against a half-replaced rule.
            sem.delete_rule(&doc.id)?;
            if let Err(e) = sem.create_rule(spec) {
                // The old definition was accepted before, so it is accepted again.
                if let Err(back) = sem.create_rule(old.spec) {
                    warn!(rule = %doc.id, error = %back, "rule lost while restoring it");
                } else if !old.enabled
                    && let Err(back) = sem.set_rule_enabled(&doc.id, false)
                {
                    warn!(rule = %doc.id, error = %back, "restored rule left enabled");
                }
                return Err(e);
            }
            if !doc.enabled {
                sem.set_rule_enabled(&doc.id, false)?;
            }
            Ok(())
        })
    }

    /// Deletes a user rule (built-in rules can only be disabled).
    pub fn delete_rule(&self, id: &str) -> Result<(), RuleChangeError> {
        let _file = lock(&self.shared.rules_file);
        let docs = {
            let mut sem = lock(&self.shared.semantic);
            sem.delete_rule(id)?;
            sem.rules().iter().map(RuleDoc::from_info).collect()
        };
        info!(rule = id, "rule deleted");
        self.save_rules(docs)
    }

    fn change_rules(
        &self,
        id: &str,
        change: impl FnOnce(&mut SemanticStore) -> Result<(), shoal_semantic::RuleError>,
    ) -> Result<RuleDoc, RuleChangeError> {
        let _file = lock(&self.shared.rules_file);
        let docs: Vec<RuleDoc> = {
            let mut sem = lock(&self.shared.semantic);
            change(&mut sem)?;
            sem.rules().iter().map(RuleDoc::from_info).collect()
        };
        let doc = docs
            .iter()
            .find(|d| d.id == id)
            .cloned()
            .ok_or_else(|| shoal_semantic::RuleError::NotFound(id.to_owned()))?;
        info!(rule = id, enabled = doc.enabled, condition = ?doc.condition, "rule changed");
        self.save_rules(docs)?;
        Ok(doc)
    }

    fn save_rules(&self, rules: Vec<RuleDoc>) -> Result<(), RuleChangeError> {
        RulesFile { rules }
            .save(&self.shared.config.rules_path)
            .map_err(|e| {
                warn!(error = %e, "rules not saved");
                RuleChangeError::Save(e)
            })
    }

    /// Checks a task can go to its vehicle now: well-formed, the vehicle registered and
    /// in contact, able to do it (its announced capabilities, the register's part of the
    /// information model) and with battery enough for anything but going home or up.
    fn check_task(&self, task: &TaskAssignment) -> Result<(), DispatchError> {
        task.validate().map_err(DispatchError::Invalid)?;
        task.task().map_err(DispatchError::Invalid)?;
        self.check_dispatch(&task.vehicle_id, task.kind)
    }

    /// Whether a task of `kind` would go to `vehicle_id` now, as far as the vehicle is
    /// concerned (registered, in contact, announcing the capability, battery enough): the
    /// same check dispatching makes, so that a console can say beforehand what the station
    /// would refuse.
    pub fn check_dispatch(&self, vehicle_id: &str, kind: TaskKind) -> Result<(), DispatchError> {
        use shoal_model::TaskKind as K;
        let fleet = lock(&self.shared.fleet);
        let Some(v) = fleet.vehicles.get(vehicle_id) else {
            return Err(DispatchError::UnknownVehicle(vehicle_id.to_owned()));
        };
        if kind == K::Abort {
            // An emergency order always goes out, whatever the vehicle says it can do.
            return Ok(());
        }
        if v.contact == Contact::Lost {
            return Err(DispatchError::VehicleLost(vehicle_id.to_owned()));
        }
        let capability = kind.capability();
        if !v.announcement.capabilities.iter().any(|c| c == capability) {
            return Err(DispatchError::Incapable {
                vehicle: vehicle_id.to_owned(),
                capability,
            });
        }
        let needs_energy = !matches!(
            kind,
            K::Surface | K::ReturnHome | K::RequestState | K::SetReportingRate
        );
        let min = self.shared.config.min_dispatch_battery_pct;
        if let Some(s) = &v.latest
            && needs_energy
            && s.battery_pct != shoal_model::UNKNOWN
            && s.battery_pct < min
        {
            return Err(DispatchError::LowBattery {
                vehicle: vehicle_id.to_owned(),
                battery_pct: s.battery_pct,
                min_pct: min,
            });
        }
        Ok(())
    }

    /// Validates a single task, registers it and sends it at once. Aborts go out on the
    /// emergency priority class.
    pub async fn dispatch(&self, task: TaskAssignment) -> Result<(), DispatchError> {
        self.check_task(&task)?;
        {
            let mut reg = lock(&self.shared.register);
            if reg.contains_task(&task.task_id) {
                return Err(DispatchError::DuplicateTask(task.task_id));
            }
            reg.add_task(task.clone(), now_ms());
        }
        self.register_task(&task);
        let id = task.task_id;
        // The outcome of the write itself: reading the register afterwards would race the
        // vehicle, whose acceptance may already have moved the task past `sent`.
        if tokio::task::block_in_place(|| self.send_registered(&id)) {
            Ok(())
        } else {
            Err(DispatchError::Dds("the task could not be published".into()))
        }
    }

    /// Enters a task in the semantic model and the history.
    fn register_task(&self, task: &TaskAssignment) {
        let fired = lock(&self.shared.semantic).upsert_task(task);
        self.emit_fired(fired);
        self.store(Record::Task(task.clone()));
    }

    /// Publishes a registered pending task on the link its vehicle is reachable on now.
    ///
    /// Both links start at the same DDS topic: a vehicle on IP takes it directly, and the
    /// CDT that hears a submerged vehicle forwards it acoustically (retransmitting until
    /// its TTL). The station records which link it expects to carry the task, which sets
    /// how long it waits for an acknowledgement before the task expires.
    /// Sends a registered task; true when it was published.
    fn send_registered(&self, task_id: &str) -> bool {
        let Some(task) = lock(&self.shared.register)
            .task(task_id)
            .map(|t| t.assignment.clone())
        else {
            return false;
        };
        // Checked again when a mission's next task comes due: things change.
        if let Err(e) = self.check_task(&task) {
            let now = now_ms();
            warn!(task = task_id, error = %e, "task not sent");
            lock(&self.shared.register).finish(
                task_id,
                shoal_model::TaskState::Failed,
                &format!("not sent: {e}"),
                now,
            );
            self.task_changed(
                task_id,
                shoal_model::TaskState::Failed,
                &format!("not sent: {e}"),
            );
            return false;
        }
        let link = lock(&self.shared.fleet)
            .vehicles
            .get(&task.vehicle_id)
            .map_or(shoal_model::LinkKind::Ip, |v| v.link);
        let writer = if task.kind == TaskKind::Abort {
            &self.shared.abort_writer
        } else {
            &self.shared.task_writer
        };
        let kind = task.kind;
        let vehicle = task.vehicle_id.clone();
        match writer.write_blocking(task) {
            Ok(()) => {
                info!(task = task_id, vehicle = %vehicle, ?kind, ?link, "task dispatched");
                lock(&self.shared.stats).tasks_dispatched += 1;
                lock(&self.shared.register).sent(task_id, link, now_ms());
                self.record_transitions();
                self.push_task(task_id);
                true
            }
            Err(e) => {
                warn!(task = task_id, error = %e, "task not published");
                lock(&self.shared.register).finish(
                    task_id,
                    shoal_model::TaskState::Failed,
                    &format!("could not be published: {e}"),
                    now_ms(),
                );
                self.record_transitions();
                false
            }
        }
    }

    /// Registers a mission after checking every task (ids unique, vehicles able); it
    /// starts with [`Self::start_mission`].
    pub fn plan_mission(&self, spec: MissionSpec) -> Result<MissionView, DispatchError> {
        if !shoal_model::is_identifier(&spec.mission_id, shoal_model::MAX_ID_LEN) {
            return Err(DispatchError::BadField {
                field: "mission_id",
                rule: "1..=64 of [A-Za-z0-9_.-]",
            });
        }
        if spec.tasks.is_empty() {
            return Err(DispatchError::BadField {
                field: "tasks",
                rule: "a mission needs at least one task",
            });
        }
        if lock(&self.shared.register).contains_mission(&spec.mission_id) {
            return Err(DispatchError::DuplicateMission(spec.mission_id));
        }
        let now = now_ms();
        let mut assignments = Vec::with_capacity(spec.tasks.len());
        for (n, t) in spec.tasks.iter().enumerate() {
            let id = t
                .task_id
                .clone()
                .unwrap_or_else(|| format!("{}-{}", spec.mission_id, n + 1));
            // One millisecond apart, so that the history keeps the mission's order.
            let issued = now + i64::try_from(n).unwrap_or(0);
            let a = TaskAssignment::new(id, &spec.mission_id, &t.vehicle_id, issued, &t.task);
            self.check_task(&a).map_err(|e| DispatchError::InMission {
                index: n,
                error: Box::new(e),
            })?;
            if assignments
                .iter()
                .any(|b: &TaskAssignment| b.task_id == a.task_id)
                || lock(&self.shared.register).contains_task(&a.task_id)
            {
                return Err(DispatchError::InMission {
                    index: n,
                    error: Box::new(DispatchError::DuplicateTask(a.task_id)),
                });
            }
            assignments.push(a);
        }
        {
            let mut reg = lock(&self.shared.register);
            let ids = assignments.iter().map(|a| a.task_id.clone()).collect();
            for a in &assignments {
                reg.add_task(a.clone(), now);
            }
            reg.add_mission(&spec.mission_id, &spec.name, ids, now);
        }
        for a in &assignments {
            self.register_task(a);
        }
        info!(mission = %spec.mission_id, tasks = assignments.len(), "mission planned");
        let view = self
            .mission(&spec.mission_id)
            .ok_or(DispatchError::UnknownMission(spec.mission_id))?;
        let _ = self
            .shared
            .live
            .send(LiveUpdate::Mission(Box::new(view.clone())));
        Ok(view)
    }

    /// Starts a planned mission: each vehicle's first task goes out.
    pub fn start_mission(&self, mission_id: &str) -> Result<MissionView, DispatchError> {
        let first = lock(&self.shared.register)
            .start(mission_id, now_ms())
            .ok_or_else(|| DispatchError::UnknownMission(mission_id.to_owned()))?;
        info!(mission = mission_id, "mission started");
        tokio::task::block_in_place(|| {
            for id in first {
                self.send_registered(&id);
            }
        });
        self.mission(mission_id)
            .ok_or_else(|| DispatchError::UnknownMission(mission_id.to_owned()))
    }

    /// Aborts a mission: pending tasks end, vehicles with a task under way get an abort
    /// (emergency surface) on the emergency class.
    pub fn abort_mission(&self, mission_id: &str) -> Result<MissionView, DispatchError> {
        let busy = lock(&self.shared.register)
            .abort_mission(mission_id, now_ms())
            .ok_or_else(|| DispatchError::UnknownMission(mission_id.to_owned()))?;
        self.record_transitions();
        warn!(mission = mission_id, vehicles = ?busy, "mission aborted");
        self.raise(
            Severity::Warning,
            EventKind::Task,
            "",
            "",
            &format!("mission {mission_id} aborted by the operator"),
        );
        tokio::task::block_in_place(|| {
            for v in busy {
                self.send_abort(&v, mission_id);
            }
        });
        self.mission(mission_id)
            .ok_or_else(|| DispatchError::UnknownMission(mission_id.to_owned()))
    }

    /// Aborts every open mission and sends an abort to every vehicle in contact.
    pub fn abort_all(&self) -> Vec<String> {
        let missions = lock(&self.shared.register).open_missions();
        for m in &missions {
            let _ = lock(&self.shared.register).abort_mission(m, now_ms());
        }
        self.record_transitions();
        let vehicles: Vec<String> = lock(&self.shared.fleet)
            .vehicles
            .iter()
            .filter(|(_, v)| v.contact != Contact::Lost)
            .map(|(id, _)| id.clone())
            .collect();
        self.raise(
            Severity::Alarm,
            EventKind::Task,
            "",
            "",
            &format!(
                "ABORT ALL by the operator: {} vehicles, {} missions",
                vehicles.len(),
                missions.len()
            ),
        );
        tokio::task::block_in_place(|| {
            for v in &vehicles {
                self.send_abort(v, "all");
            }
        });
        vehicles
    }

    fn send_abort(&self, vehicle_id: &str, scope: &str) {
        let seq = self.shared.event_seq.fetch_add(1, Ordering::Relaxed);
        let id: String = format!("abort-{scope}-{vehicle_id}-{seq}")
            .chars()
            .take(shoal_model::MAX_ID_LEN)
            .collect();
        let a = TaskAssignment::new(&id, "", vehicle_id, now_ms(), &shoal_model::Task::Abort);
        lock(&self.shared.register).add_task(a.clone(), now_ms());
        self.register_task(&a);
        self.send_registered(&id);
    }

    /// Expires sent tasks their vehicle never acknowledged in time.
    fn expire_tasks(&self) {
        let cfg = &self.shared.config;
        #[allow(clippy::cast_possible_truncation)]
        let (ip, acoustic) = (
            (cfg.task_ack_timeout_s * 1000.0) as i64,
            (cfg.acoustic_task_ack_timeout_s * 1000.0) as i64,
        );
        let now = now_ms();
        let overdue = lock(&self.shared.register).overdue(now, ip, acoustic);
        for id in overdue {
            let msg = "not acknowledged by the vehicle in time";
            lock(&self.shared.register).finish(&id, shoal_model::TaskState::Expired, msg, now);
            self.task_changed(&id, shoal_model::TaskState::Expired, msg);
        }
    }
}
