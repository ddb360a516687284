//! The Data Access Manager: the one entry for data heard from vehicles. Each datum goes,
//! in one step, through the Data Pre-Processor's plausibility checks ([`preprocess`]) to
//! the Vehicle Register's latest state, the semantic model (whose rules fire on insert)
//! and the history store. A refused datum is counted by reason, quarantined with its
//! payload and reported as an event.
//!
//! Data from the bus arrive [`Validated`] (the Publish/Subscribe Manager checks types and
//! ranges on receipt); data from elsewhere (an operator, a tool) are validated here.

mod early;
pub(crate) mod preprocess;
mod semantic;

pub(crate) use early::EarlyStates;

pub(crate) use shoal_dds::LogBudget;

/// Log lines a second for rejected data; beyond, rejections are only counted.
pub(crate) const REJECTION_LOG_LINES_PER_S: u32 = 20;

pub(crate) use semantic::FLUSH_STEP;

use std::collections::BTreeMap;
use std::sync::atomic::Ordering;

use serde::Serialize;
use shoal_dds::{ReadError, TopicType};
use shoal_history::Record;
use shoal_model::{
    EnvironmentObservation, Event, EventKind, Severity, StateVector, TaskStatus, Validated,
};
use tracing::{debug, warn};

use crate::core::{StationHandle, lock};
use crate::error::Rejection;
use preprocess::Verdict;

/// Counters of what the station received, by outcome; rejections by reason code.
#[derive(Debug, Clone, Default, Serialize, PartialEq, Eq)]
pub struct IngestStats {
    /// State vectors accepted and stored.
    pub states_accepted: u64,
    /// State vectors from the bus that arrived before their vehicle's announcement and
    /// waited for it (accepted when it came, refused as `unknown_vehicle` when not).
    pub states_held_for_announcement: u64,
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
    /// Ended tasks retired from the bus (disposed), so no vehicle receives them again.
    pub tasks_retired: u64,
    /// Ended tasks the bus would not retire (each also logged).
    pub tasks_not_retired: u64,
    /// Ended tasks forgotten by the register and the semantic model after their retention.
    pub tasks_forgotten: u64,
    /// Events raised by rules as data arrived.
    pub rule_firings: u64,
    /// User rules disabled because an evaluation ran over `station.semantic.rule_budget_ms`.
    pub rules_over_budget: u64,
    /// Rejections counted but not logged (beyond 20 log lines a second).
    pub rejections_not_logged: u64,
}

impl IngestStats {
    /// Every rejected or malformed datum, all reasons together.
    pub fn total_rejected(&self) -> u64 {
        self.rejected.values().sum::<u64>() + self.malformed.values().sum::<u64>()
    }
}

/// A datum as JSON for the quarantine table.
fn payload<T: Serialize>(value: &T) -> String {
    serde_json::to_string(value).unwrap_or_else(|e| format!("{{\"unencodable\":\"{e}\"}}"))
}

/// The vehicle id a refused datum names, if it is itself well-formed enough to trust.
fn trusted_id(id: &str) -> String {
    if shoal_model::is_identifier(id, shoal_model::MAX_VEHICLE_ID_LEN) {
        id.to_owned()
    } else {
        String::new()
    }
}

impl StationHandle {
    /// Takes one state vector from outside the bus (an operator's tool, a replay, a
    /// benchmark) through the Data Access Manager: validated first, then as
    /// [`Self::ingest_validated_state`].
    pub fn ingest_state(&self, s: StateVector) -> Result<(), Rejection> {
        match Validated::new(s) {
            Ok(s) => self.ingest_validated_state(s),
            Err((e, s)) => {
                let why = Rejection::Invalid(e);
                let id = trusted_id(&s.vehicle_id);
                self.reject(StateVector::TOPIC, &id, &why, payload(&s));
                Err(why)
            }
        }
    }

    /// A state vector from the bus. One naming a vehicle that has not announced itself
    /// yet waits up to `station.announcement_grace_s` for the announcement (see
    /// [`EarlyStates`]); everything else goes through [`Self::ingest_validated_state`].
    pub fn ingest_bus_state(&self, s: Validated<StateVector>) {
        let hold =
            self.core.config.require_announcement && self.core.config.announcement_grace_s > 0.0;
        // Rejections are counted, quarantined and reported inside.
        let _ = self.ingest_state_from(s, hold);
    }

    /// Holds `s`, whose vehicle the register did not know a moment ago; `Err(s)` when it
    /// knows it now. Checked under the hold's lock: an announcement registers the vehicle
    /// before it takes that lock to release what waits, so no sample is left behind.
    fn hold_early(&self, s: Validated<StateVector>) -> Result<(), Validated<StateVector>> {
        let mut early = lock(&self.core.early);
        if lock(&self.core.fleet).vehicles.contains_key(&s.vehicle_id) {
            return Err(s);
        }
        let refused = early.hold(s, self.now());
        drop(early);
        lock(&self.core.stats).states_held_for_announcement += 1;
        if let Some(refused) = refused {
            // Rejections are counted, quarantined and reported inside.
            let _ = self.ingest_validated_state(refused);
        }
        Ok(())
    }

    /// The state vectors that waited for `vehicle_id`'s announcement, now that it came.
    pub(crate) fn release_early_states(&self, vehicle_id: &str) {
        let held = lock(&self.core.early).release(vehicle_id);
        for s in held {
            let _ = self.ingest_validated_state(s);
        }
    }

    /// Ends the wait of state vectors held longer than the grace: each goes through the
    /// Data Access Manager again, which refuses it unless its vehicle is known by now.
    pub(crate) fn expire_early_states(&self, now: i64) {
        let grace = crate::config::ms(self.core.config.announcement_grace_s);
        let expired = lock(&self.core.early).expire(now, grace);
        for s in expired {
            let _ = self.ingest_validated_state(s);
        }
    }

    /// Takes one validated state vector through the Data Access Manager in one step:
    /// plausibility (the Data Pre-Processor), the vehicle's latest state, the semantic
    /// model and its rules, the history store. A refused state vector is counted by
    /// reason, quarantined with its payload and reported as an event.
    pub fn ingest_validated_state(&self, s: Validated<StateVector>) -> Result<(), Rejection> {
        self.ingest_state_from(s, false)
    }

    /// [`Self::ingest_validated_state`]; with `hold_unknown`, a sample of a vehicle the
    /// register does not know yet is held for its announcement instead of refused.
    fn ingest_state_from(
        &self,
        s: Validated<StateVector>,
        hold_unknown: bool,
    ) -> Result<(), Rejection> {
        let now = self.now();
        let Some((verdict, newer)) = self.judge_state(&s, now) else {
            if hold_unknown {
                return match self.hold_early(s) {
                    Ok(()) => Ok(()),
                    // Announced in the meantime: in as any other sample.
                    Err(s) => self.ingest_state_from(s, false),
                };
            }
            let s = s.into_inner();
            let why = Rejection::UnknownVehicle(s.vehicle_id.clone());
            self.reject(StateVector::TOPIC, &s.vehicle_id, &why, payload(&s));
            return Err(why);
        };
        let s = s.into_inner();
        match verdict {
            Verdict::Accept => {}
            Verdict::Reject(why) => {
                let why = Rejection::Implausible(why);
                self.reject(StateVector::TOPIC, &s.vehicle_id, &why, payload(&s));
                return Err(why);
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
        lock(&self.core.stats).states_accepted += 1;
        if newer {
            // Typed and cheap: the RDF mirror is written coalesced, once a second per vehicle.
            let fired = lock(&self.core.semantic).update_state(&s);
            self.emit_fired(fired);
            self.refresh_heard_availability(&s.vehicle_id, now);
            self.push_state(&s.vehicle_id);
        }
        self.store(Record::State(s));
        Ok(())
    }

    /// The plausibility verdict on `s` and whether it is newer than the latest state;
    /// an accepted newer state becomes the vehicle's latest. `None` for a vehicle that
    /// must announce itself first.
    fn judge_state(&self, s: &StateVector, now: i64) -> Option<(Verdict, bool)> {
        let mut fleet = lock(&self.core.fleet);
        let Some(e) = fleet.vehicles.get_mut(&s.vehicle_id) else {
            return (!self.core.config.require_announcement).then_some((Verdict::Accept, true));
        };
        let verdict = preprocess::judge(
            &self.core.config.plausibility,
            e.latest.as_ref(),
            &mut e.suspects,
            s,
            e.announcement.max_speed_mps,
            now,
        );
        // Even a rejected sample proves the vehicle is heard: a bad clock must not also
        // look like a lost vehicle.
        e.last_contact_ms = Some(now);
        let newer = e
            .latest
            .as_ref()
            .is_none_or(|l| l.timestamp_ms < s.timestamp_ms);
        let mut first_state = false;
        if !matches!(verdict, Verdict::Reject(_)) {
            // A late sample (acoustic store-and-forward) goes to the history only.
            if newer {
                e.battery_rising = e
                    .latest
                    .as_ref()
                    .is_some_and(|l| s.battery_pct > l.battery_pct && l.battery_pct >= 0.0);
                first_state = e.latest.is_none();
                e.latest = Some(s.clone());
            }
            e.states_accepted += 1;
        }
        if first_state {
            fleet.unheard = fleet.unheard.saturating_sub(1);
        }
        Some((verdict, newer))
    }

    /// The timestamp checks for data other than state vectors; true when accepted.
    fn timely(
        &self,
        topic: &str,
        vehicle_id: &str,
        timestamp_ms: i64,
        json: &dyn Fn() -> String,
    ) -> Result<(), Rejection> {
        match preprocess::check_time(&self.core.config.plausibility, timestamp_ms, self.now()) {
            None => Ok(()),
            Some(why) => {
                let why = Rejection::Implausible(why);
                self.reject(topic, vehicle_id, &why, json());
                Err(why)
            }
        }
    }

    /// A vehicle's report on a task: checked against the station's clock, then the
    /// Mission & Task Register's (see [`Self::task_reported`]).
    pub fn ingest_task_status(&self, s: Validated<TaskStatus>) -> Result<(), Rejection> {
        let s = s.into_inner();
        self.timely(TaskStatus::TOPIC, &s.vehicle_id, s.timestamp_ms, &|| {
            payload(&s)
        })?;
        self.task_reported(s)
    }

    /// An event from a vehicle (or a CDT's link report): kept, entered in the semantic
    /// model, stored. The station's own events never come through here.
    pub fn ingest_event(&self, e: Validated<Event>) -> Result<(), Rejection> {
        let e = e.into_inner();
        self.timely(Event::TOPIC, &e.vehicle_id, e.timestamp_ms, &|| payload(&e))?;
        // A CDT's link table entry: link metadata for the vehicle, not an operator event.
        if let Some(status) = shoal_model::LinkStatus::from_event(&e) {
            self.link_reported(status);
            self.store(Record::Event(e));
            return Ok(());
        }
        lock(&self.core.stats).events += 1;
        if e.kind == EventKind::Fault {
            self.fault_reported(&e.vehicle_id);
        }
        let fired = lock(&self.core.semantic).add_event(&e);
        self.emit_fired(fired);
        self.remember_event(e.clone());
        self.store(Record::Event(e));
        Ok(())
    }

    /// An environment observation: offered to the Environment Reporter's subscriptions,
    /// entered in the semantic model, stored.
    pub fn ingest_observation(
        &self,
        o: Validated<EnvironmentObservation>,
    ) -> Result<(), Rejection> {
        let o = o.into_inner();
        self.timely(
            EnvironmentObservation::TOPIC,
            &o.vehicle_id,
            o.timestamp_ms,
            &|| payload(&o),
        )?;
        lock(&self.core.stats).observations += 1;
        self.offer_observation(&o);
        // Aggregated for the other sites, when the federation sends environment data.
        if let Some(view) = self.core.federation.get() {
            view.observe(&o);
        }
        let fired = lock(&self.core.semantic).add_observation(&o);
        self.emit_fired(fired);
        self.store(Record::Observation(o));
        Ok(())
    }

    /// Counts a refusal by reason, quarantines the payload and reports it (rate-limited).
    pub(crate) fn reject(
        &self,
        topic: &str,
        vehicle_id: &str,
        why: &Rejection,
        payload_json: String,
    ) {
        let reason = why.reason();
        *lock(&self.core.stats)
            .rejected
            .entry(reason.clone())
            .or_default() += 1;
        if let Some(e) = lock(&self.core.fleet).vehicles.get_mut(vehicle_id) {
            e.states_rejected += 1;
        }
        let detail = why.to_string();
        let logged = lock(&self.core.rejection_log).take(std::time::Instant::now());
        match logged {
            Some(0) => warn!(topic, vehicle = vehicle_id, reason, detail, "data rejected"),
            Some(left_out) => warn!(
                topic,
                vehicle = vehicle_id,
                reason,
                detail,
                left_out,
                "data rejected (and {left_out} more not logged; every one is counted in /api/stats)"
            ),
            None => debug!(topic, vehicle = vehicle_id, reason, detail, "data rejected"),
        }
        self.store(Record::rejected(topic, &reason, payload_json));
        self.alert_rejection(topic, vehicle_id, &reason, &detail);
    }

    /// Counts a refusal that is not worth quarantining (nothing to keep).
    pub(crate) fn count_rejection(&self, reason: &str) {
        *lock(&self.core.stats)
            .rejected
            .entry(reason.to_owned())
            .or_default() += 1;
    }

    /// A sample refused by the P/S Manager's security (about another vehicle than its
    /// authenticated publisher, or from a revoked vehicle): counted as `security:<reason>` and reported, never stored, because
    /// nothing in it can be trusted, not even the vehicle it names.
    fn refuse(&self, topic: &str, reason: &str, detail: &str) {
        let reason = format!("security:{reason}");
        self.count_rejection(&reason);
        debug!(topic, reason, detail, "sample refused by security");
        self.alert_rejection(topic, "", &reason, detail);
    }

    /// A sample the bus could not hand over: counted by reason, quarantined when there is
    /// a payload to keep, reported.
    pub fn on_read_error<T: TopicType>(&self, e: &ReadError) {
        match e {
            ReadError::Invalid { error, payload, .. } => {
                // The vehicle id is only trusted if it is itself well-formed.
                let vehicle = serde_json::from_str::<serde_json::Value>(payload)
                    .ok()
                    .and_then(|v| v.get("vehicle_id").and_then(|v| v.as_str()).map(trusted_id))
                    .unwrap_or_default();
                let why = Rejection::Invalid(error.clone());
                self.reject(T::TOPIC, &vehicle, &why, payload.clone());
            }
            ReadError::Malformed { detail, .. } => {
                *lock(&self.core.stats)
                    .malformed
                    .entry(T::TOPIC.to_string())
                    .or_default() += 1;
                self.store(Record::rejected(
                    T::TOPIC,
                    format!("malformed: {detail}"),
                    "null",
                ));
            }
            ReadError::Impersonation { .. } => {
                self.refuse(T::TOPIC, "impersonation", &e.to_string());
            }
            ReadError::Revoked { .. } => self.refuse(T::TOPIC, "revoked", &e.to_string()),
            other => warn!(topic = T::TOPIC, error = %other, "read failed"),
        }
    }

    /// Current counters.
    pub fn stats(&self) -> IngestStats {
        let mut stats = lock(&self.core.stats).clone();
        stats.rejections_not_logged = lock(&self.core.rejection_log).left_out_total();
        // Never wait for the model here: /api/stats must answer while a rule holds it, so
        // a busy model reports the figure last read.
        let over = &self.core.rules_over_budget_seen;
        if let Ok(model) = self.core.semantic.try_lock() {
            over.store(model.rules_over_budget(), Ordering::Relaxed);
        }
        stats.rules_over_budget = over.load(Ordering::Relaxed);
        // Participants DDS Security refused before any sample of theirs reached a reader
        // (counted by the P/S Manager for the whole process).
        for (reason, n) in shoal_dds::handshake_refusals() {
            stats
                .rejected
                .insert(format!("security:handshake_refused:{reason}"), n);
        }
        stats
    }

    /// Records committed to the history store so far (acknowledged data).
    pub fn history_committed(&self) -> u64 {
        self.core.history.committed()
    }

    /// The history writer's counters: rows, batches, retries, its busy time.
    pub fn history_stats(&self) -> shoal_history::HistoryStats {
        self.core.history.stats()
    }

    /// Waits until everything submitted to the history store so far is committed.
    pub fn flush_history(
        &self,
        timeout: std::time::Duration,
    ) -> Result<(), shoal_history::WaitError> {
        self.core.history.flush(timeout)
    }

    /// Read access to the history store.
    pub fn history(&self) -> &shoal_history::HistoryReader {
        &self.core.reader
    }
}

#[cfg(test)]
mod tests;
