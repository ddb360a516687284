//! The reporters: the Event Reporter (the station's own events and rule firings, kept,
//! stored and published; acknowledgements), the Tasks Reporter (vehicles' reports on
//! tasks, each task's transitions, missions moving on) and the Environment Reporter
//! (subscriptions by property, area and rate), and the live feed they all write to.

mod types;

use std::collections::{BTreeMap, BTreeSet, HashMap, VecDeque};
use std::sync::Mutex;

use shoal_history::Record;
use shoal_model::{
    EnvironmentObservation, Event, EventKind, Severity, TaskState, TaskStatus, Validate,
};
use tracing::{info, warn};

use crate::bus::EventOrigin;
use crate::core::{StationHandle, lock};
use crate::error::{Rejection, SubscriptionError};
pub use types::{Ack, EnvSubscription, EnvSubscriptionSpec, EventView, LiveUpdate};

/// Live updates buffered per API client; a slower client loses the oldest.
const LIVE_BUFFER: usize = 4096;
/// Least time between two data-rejected events for one vehicle and reason.
const REJECTION_ALERT_EVERY_MS: i64 = 60_000;
/// Most (vehicle, reason) pairs remembered for rate-limiting rejection alerts.
const MAX_REJECTION_ALERTS: usize = 4096;
/// Least time between two sweeps of the full rejection-alert memory.
const REJECTION_SWEEP_EVERY_MS: i64 = 1_000;

/// When a data-rejected event was last raised per (vehicle, reason), for at most
/// [`MAX_REJECTION_ALERTS`] pairs.
#[derive(Debug, Default)]
struct RejectionAlerts {
    last_ms: HashMap<(String, String), i64>,
    /// When the memory, full, was last swept of the pairs whose minute had passed. A
    /// sweep reads every pair: once per rejection, a flood of made-up ids made each
    /// rejection cost thousands of steps and slowed the fleet's ingest behind it.
    swept_ms: Option<i64>,
}

impl RejectionAlerts {
    /// Whether an alert for `key` is due at `now`; if it is, it is noted as raised. The
    /// ids are the senders' to choose: past the cap, pairs whose minute has passed go (a
    /// sweep at most every [`REJECTION_SWEEP_EVERY_MS`]), and if a flood of fresh ids
    /// still fills it, no alert is raised for new ones (each rejection is still counted
    /// and quarantined).
    fn due(&mut self, key: (String, String), now: i64) -> bool {
        let known = self.last_ms.contains_key(&key);
        if self.last_ms.len() >= MAX_REJECTION_ALERTS
            && !known
            && self
                .swept_ms
                .is_none_or(|t| now - t >= REJECTION_SWEEP_EVERY_MS)
        {
            self.last_ms
                .retain(|_, t| now - *t < REJECTION_ALERT_EVERY_MS);
            self.swept_ms = Some(now);
        }
        let due = self
            .last_ms
            .get(&key)
            .is_none_or(|t| now - t >= REJECTION_ALERT_EVERY_MS)
            && (known || self.last_ms.len() < MAX_REJECTION_ALERTS);
        if due {
            self.last_ms.insert(key, now);
        }
        due
    }
}

/// What the reporters keep.
#[derive(Debug)]
pub(crate) struct Reporters {
    /// Recent events, oldest first (`station.recent_events` of them).
    events: Mutex<VecDeque<Event>>,
    /// Operators' acknowledgements of events, by event id.
    acks: Mutex<HashMap<String, Ack>>,
    /// The Environment Reporter's subscriptions, by id.
    env_subs: Mutex<BTreeMap<String, EnvSubscription>>,
    /// Live updates for API clients (WebSocket); lagging receivers lose the oldest.
    live: tokio::sync::broadcast::Sender<LiveUpdate>,
    /// Last time each vehicle's state went to the live feed.
    live_state_ms: Mutex<HashMap<String, i64>>,
    /// Last time a data-rejected event was raised per (vehicle, reason), to rate-limit them.
    rejection_alerts: Mutex<RejectionAlerts>,
}

impl Default for Reporters {
    fn default() -> Self {
        Self {
            events: Mutex::default(),
            acks: Mutex::default(),
            env_subs: Mutex::default(),
            live: tokio::sync::broadcast::channel(LIVE_BUFFER).0,
            live_state_ms: Mutex::default(),
            rejection_alerts: Mutex::default(),
        }
    }
}

impl StationHandle {
    fn reporters(&self) -> &Reporters {
        &self.core.reporters
    }

    // --- The live feed ---------------------------------------------------------------

    /// A live feed of events, tasks, missions, vehicle states (≤ 1 Hz each) and subscribed
    /// observations; a receiver that falls behind loses the oldest updates.
    pub fn live(&self) -> tokio::sync::broadcast::Receiver<LiveUpdate> {
        self.reporters().live.subscribe()
    }

    /// Sends an update to live clients, if any listen.
    pub(crate) fn publish_live(&self, update: LiveUpdate) {
        let _ = self.reporters().live.send(update);
    }

    /// Whether any live client is connected: updates built only for them can be skipped.
    pub(crate) fn has_live_clients(&self) -> bool {
        self.reporters().live.receiver_count() > 0
    }

    /// Sends a vehicle's view to live clients, at most once a second per vehicle.
    pub(crate) fn push_state(&self, vehicle_id: &str) {
        if !self.has_live_clients() {
            return;
        }
        let now = self.now();
        {
            let mut last = lock(&self.reporters().live_state_ms);
            if last.get(vehicle_id).is_some_and(|t| now - t < 1000) {
                return;
            }
            last.insert(vehicle_id.to_owned(), now);
        }
        if let Some(v) = self.vehicle(vehicle_id) {
            self.publish_live(LiveUpdate::Vehicle(Box::new(v)));
        }
    }

    // --- Event Reporter --------------------------------------------------------------

    /// Raises a station event: kept, stored, and published on the bus (alarms on the
    /// emergency class).
    pub fn raise(
        &self,
        severity: Severity,
        kind: EventKind,
        vehicle_id: &str,
        task_id: &str,
        text: &str,
    ) {
        let e = Event {
            event_id: format!("station-{}-{}", self.core.started_ms, self.next_seq()),
            timestamp_ms: self.now(),
            severity,
            kind,
            vehicle_id: vehicle_id.to_string(),
            task_id: task_id.to_string(),
            text: text.chars().take(shoal_model::MAX_TEXT_LEN).collect(),
        };
        self.emit(e, EventOrigin::Station);
    }

    /// Records, stores and publishes an event the station produced (its own or a rule's).
    fn emit(&self, e: Event, origin: EventOrigin) {
        if let Err(err) = e.validate() {
            warn!(error = %err, "station event not raised: invalid");
            return;
        }
        info!(kind = ?e.kind, severity = ?e.severity, vehicle = %e.vehicle_id, text = %e.text, "event");
        // Rule firings enter the model too, so rules and queries can see them.
        if origin == EventOrigin::Rule
            && let Err(err) = lock(&self.core.semantic).add_event(&e)
        {
            warn!(error = %err, "event not in the semantic model");
        }
        self.remember_event(e.clone());
        self.store(Record::Event(e.clone()));
        if let Err(err) = self.core.outbox.publish_event(e) {
            warn!(error = %err, "event not published on the bus");
        }
    }

    /// Emits the events rules fired; a failed model update is logged, never fatal.
    pub(crate) fn emit_fired(&self, fired: Result<Vec<Event>, shoal_semantic::StoreError>) {
        match fired {
            Ok(events) => {
                for e in events {
                    lock(&self.core.stats).rule_firings += 1;
                    self.emit(e, EventOrigin::Rule);
                }
            }
            Err(e) => warn!(error = %e, "semantic model update failed"),
        }
    }

    /// Keeps an event among the recent ones and tells live clients.
    pub(crate) fn remember_event(&self, e: Event) {
        self.publish_live(LiveUpdate::Event(EventView {
            event: e.clone(),
            acknowledged: None,
        }));
        let mut events = lock(&self.reporters().events);
        events.push_back(e);
        while events.len() > self.core.config.recent_events {
            events.pop_front();
        }
    }

    /// One event per vehicle and reason per minute: enough for the operator, no flood.
    pub(crate) fn alert_rejection(
        &self,
        topic: &str,
        vehicle_id: &str,
        reason: &str,
        detail: &str,
    ) {
        let now = self.now();
        let key = (vehicle_id.to_string(), reason.to_string());
        let raise = lock(&self.reporters().rejection_alerts).due(key, now);
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

    /// Recent events with their acknowledgements, oldest first.
    pub fn event_views(&self) -> Vec<EventView> {
        let acks = lock(&self.reporters().acks);
        lock(&self.reporters().events)
            .iter()
            .map(|e| EventView {
                acknowledged: acks.get(&e.event_id).cloned(),
                event: e.clone(),
            })
            .collect()
    }

    /// Recent events, oldest first.
    pub fn recent_events(&self) -> Vec<Event> {
        lock(&self.reporters().events).iter().cloned().collect()
    }

    /// An operator acknowledges an event; acknowledging twice keeps the first. The
    /// acknowledgement is itself stored in the history as an event.
    pub fn acknowledge(&self, event_id: &str, by: &str) -> Option<EventView> {
        let event = lock(&self.reporters().events)
            .iter()
            .find(|e| e.event_id == event_id)
            .cloned()?;
        let by: String = by.chars().take(shoal_model::MAX_NAME_LEN).collect();
        let (ack, new) = {
            let mut acks = lock(&self.reporters().acks);
            match acks.get(event_id) {
                Some(a) => (a.clone(), false),
                None => {
                    let a = Ack {
                        by: by.clone(),
                        at_ms: self.now(),
                    };
                    acks.insert(event_id.to_owned(), a.clone());
                    (a, true)
                }
            }
        };
        if new {
            info!(event = event_id, by = %by, "event acknowledged");
            let record = Event {
                event_id: format!("station-{}-{}", self.core.started_ms, self.next_seq()),
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
        self.publish_live(LiveUpdate::Event(view.clone()));
        Some(view)
    }

    // --- Tasks Reporter --------------------------------------------------------------

    /// A vehicle's report on a task moves the task's state machine and its mission on.
    pub(crate) fn task_reported(&self, s: TaskStatus) -> Result<(), Rejection> {
        let now = self.now();
        // A relay that gave up on delivering a task acoustically: send it again while
        // retries last, instead of expiring it.
        if s.state == TaskState::Expired {
            let again = lock(&self.core.tasks).retry(
                &s.task_id,
                self.core.config.acoustic_task_retries,
                now,
            );
            if let Some(a) = again {
                warn!(task = %s.task_id, vehicle = %s.vehicle_id, reason = %s.message, "task not delivered acoustically; sending it again");
                self.store(Record::Task(a));
                let id = s.task_id.clone();
                self.store(Record::TaskStatus(s));
                self.send_all(vec![id]);
                return Ok(());
            }
        }
        self.apply_task_status(s, true)
    }

    /// A task this station sent through `site` (another site's vehicle) moved there: that
    /// site's task transition, applied as the vehicle's report. False when it is not such
    /// a task (then nothing changes).
    pub fn remote_task_moved(&self, site: &str, t: &TaskStatus) -> bool {
        let ours = lock(&self.core.tasks).task(&t.task_id).is_some_and(|v| {
            v.via_site.as_deref() == Some(site) && v.assignment.vehicle_id == t.vehicle_id
        });
        if !ours {
            return false;
        }
        let mut s = t.clone();
        if s.message.is_empty() {
            s.message = format!("reported by site {site}");
        }
        self.apply_task_status(s, false).is_ok()
    }

    /// Moves a task's state machine and its mission on with a report; `heard` when the
    /// vehicle itself reported (which proves contact).
    fn apply_task_status(&self, s: TaskStatus, heard: bool) -> Result<(), Rejection> {
        let now = self.now();
        let Some(changed) = lock(&self.core.tasks).on_status(&s, now) else {
            // Not a task this station gave that vehicle: nothing to track, nothing to store.
            warn!(task = %s.task_id, vehicle = %s.vehicle_id, state = ?s.state, "status for a task this station never gave that vehicle; ignored");
            let why = Rejection::UnknownTask {
                task_id: s.task_id,
                vehicle_id: s.vehicle_id,
            };
            self.count_rejection(&why.reason());
            return Err(why);
        };
        lock(&self.core.stats).task_status += 1;
        // The vehicle's own word on its task proves it is heard (a relay's word, sent or
        // expired, does not).
        if heard
            && matches!(
                s.state,
                TaskState::Accepted | TaskState::Running | TaskState::Done
            )
        {
            self.heard_from(&s.vehicle_id, now);
        }
        let fired = lock(&self.core.semantic).task_status(&s);
        self.emit_fired(fired);
        info!(task = %s.task_id, vehicle = %s.vehicle_id, state = ?s.state, progress = s.progress_pct, "task status");
        if changed {
            self.task_changed(&s.task_id, s.state, &s.message);
        }
        self.store(Record::TaskStatus(s));
        Ok(())
    }

    /// Reports a task's new state and moves its mission on.
    pub(crate) fn task_changed(&self, task_id: &str, state: TaskState, message: &str) {
        self.push_task(task_id);
        let vehicle = lock(&self.core.tasks)
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
        let next = lock(&self.core.tasks).advance(task_id, self.now());
        self.record_transitions();
        self.refresh_availability(&vehicle, self.now());
        self.send_all(next);
        self.push_mission_of(task_id);
    }

    /// Writes the state changes the station made itself to the history and the model, so
    /// the history holds every transition (and a restarted station can resume).
    /// Live consoles are told of each task that changed and of its mission once; the
    /// vehicles concerned have their availability decided again.
    pub(crate) fn record_transitions(&self) {
        self.retire_ended_tasks();
        let records = lock(&self.core.tasks).take_transitions();
        let mut task_ids = BTreeSet::new();
        let mut vehicles = BTreeSet::new();
        for s in records {
            let fired = lock(&self.core.semantic).task_status(&s);
            self.emit_fired(fired);
            self.push_task(&s.task_id);
            task_ids.insert(s.task_id.clone());
            vehicles.insert(s.vehicle_id.clone());
            self.store(Record::TaskStatus(s));
        }
        let now = self.now();
        for v in vehicles {
            self.refresh_availability(&v, now);
        }
        let mut pushed = BTreeSet::new();
        for task_id in task_ids {
            if let Some(m) = self.task(&task_id).map(|t| t.assignment.mission_id)
                && pushed.insert(m.clone())
                && let Some(view) = self.mission(&m)
            {
                self.publish_live(LiveUpdate::Mission(Box::new(view)));
            }
        }
    }

    pub(crate) fn push_task(&self, task_id: &str) {
        if let Some(t) = self.task(task_id) {
            self.publish_live(LiveUpdate::Task(Box::new(t)));
        }
    }

    fn push_mission_of(&self, task_id: &str) {
        let mission = self
            .task(task_id)
            .map(|t| t.assignment.mission_id)
            .and_then(|m| self.mission(&m));
        if let Some(m) = mission {
            self.publish_live(LiveUpdate::Mission(Box::new(m)));
        }
    }

    // --- Environment Reporter --------------------------------------------------------

    /// Subscribes to environment observations.
    pub fn subscribe_environment(
        &self,
        spec: EnvSubscriptionSpec,
    ) -> Result<EnvSubscription, SubscriptionError> {
        spec.check()?;
        let sub = EnvSubscription::new(format!("env-{}", self.next_seq()), spec);
        lock(&self.reporters().env_subs).insert(sub.id.clone(), sub.clone());
        Ok(sub)
    }

    /// Every environment subscription.
    pub fn environment_subscriptions(&self) -> Vec<EnvSubscription> {
        lock(&self.reporters().env_subs).values().cloned().collect()
    }

    /// The observations a subscription matched, oldest first (the latest 1000).
    pub fn environment_observations(&self, id: &str) -> Option<Vec<EnvironmentObservation>> {
        lock(&self.reporters().env_subs)
            .get(id)
            .map(|s| s.recent.iter().cloned().collect())
    }

    /// Ends a subscription; false if there was none.
    pub fn unsubscribe_environment(&self, id: &str) -> bool {
        lock(&self.reporters().env_subs).remove(id).is_some()
    }

    /// Offers an observation to every subscription; live clients hear of each match.
    pub(crate) fn offer_observation(&self, o: &EnvironmentObservation) {
        let now = self.now();
        let matched: Vec<String> = lock(&self.reporters().env_subs)
            .values_mut()
            .filter_map(|sub| sub.offer(o, now).then(|| sub.id.clone()))
            .collect();
        for subscription in matched {
            self.publish_live(LiveUpdate::Observation {
                subscription,
                observation: o.clone(),
            });
        }
    }
}

#[cfg(test)]
mod tests;
