//! The sending side's core, with no network: what to publish and when.
//!
//! - [`PositionLimiter`]: per vehicle, the latest position waits until the vehicle's
//!   period has passed since its last one was sent (coalescing, latest value wins).
//! - [`Journal`]: numbers one stream (alarms or task transitions) from 1 under this run's
//!   epoch and keeps the last frames, so a remote site can catch up after an outage.
//! - [`Outbound`]: both, for one site, applying the configured policy, the numbering of
//!   the orders this site sends (kept for nothing: orders are not caught up), and the
//!   environment [`Aggregator`] with the numbering of its frames (not caught up either).
//!
//! Times are in ms of any monotonic clock the caller keeps (the transport uses tokio's),
//! except the environment's, which are the wall clock: a window's bounds cross as
//! timestamps.

use std::collections::{HashMap, VecDeque};

use shoal_model::{EnvironmentObservation, Event, TaskAssignment, Validate as _, ValidationError};

use crate::config::{EnvironmentMode, FederationConfig};
use crate::environment::{self, Aggregator, Observed};
use crate::keys::{self, Stream};
use crate::types::{TaskTransition, VehiclePosition};
use crate::wire;

/// Releases each vehicle's latest position at most once per period.
#[derive(Debug)]
pub struct PositionLimiter {
    period_ms: i64,
    vehicles: HashMap<String, Slot>,
    coalesced: u64,
}

#[derive(Debug, Default)]
struct Slot {
    pending: Option<VehiclePosition>,
    /// When the vehicle may next send; `None` until its first position is due.
    next_ms: Option<i64>,
    /// Fix time of the newest position taken, to ignore older ones arriving late.
    newest_fix_ms: i64,
}

/// What became of an offered position.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Offer {
    /// Waiting for its vehicle's period.
    Queued,
    /// Replaced a position not yet sent.
    Coalesced,
    /// Older than one already taken: ignored.
    Stale,
}

impl PositionLimiter {
    /// A limiter releasing at most `max_rate_hz` positions per vehicle per second.
    pub fn new(max_rate_hz: f64) -> Self {
        // Rounded up, so the rate is never exceeded; validation keeps the rate in (0, 10].
        #[allow(clippy::cast_possible_truncation)]
        let period_ms = (1000.0 / max_rate_hz).ceil() as i64;
        Self {
            period_ms: period_ms.max(1),
            vehicles: HashMap::new(),
            coalesced: 0,
        }
    }

    /// The minimum time between two positions of one vehicle, ms.
    pub fn period_ms(&self) -> i64 {
        self.period_ms
    }

    /// Takes a (validated) position to send when its vehicle is due.
    pub fn offer(&mut self, p: VehiclePosition) -> Offer {
        let slot = self.vehicles.entry(p.vehicle_id.clone()).or_default();
        if p.timestamp_ms < slot.newest_fix_ms {
            return Offer::Stale;
        }
        slot.newest_fix_ms = p.timestamp_ms;
        if slot.pending.replace(p).is_some() {
            self.coalesced += 1;
            Offer::Coalesced
        } else {
            Offer::Queued
        }
    }

    /// The positions to send at `now_ms`, each marked sent.
    ///
    /// Each vehicle sends on its own phase of the period, from a hash of its id: a fleet
    /// whose states arrive together would otherwise leave together, every period, as one
    /// burst that fills a slow link's buffer for seconds (500 vehicles at 0.2 Hz: 20 kB,
    /// 2.5 s of a 64 kbit/s link) with alarms queued behind it.
    pub fn due(&mut self, now_ms: i64) -> Vec<VehiclePosition> {
        let period = self.period_ms;
        let mut out = Vec::new();
        for (id, slot) in &mut self.vehicles {
            if slot.pending.is_none() {
                continue;
            }
            let next = *slot
                .next_ms
                .get_or_insert_with(|| now_ms + phase(id, period));
            if now_ms >= next
                && let Some(p) = slot.pending.take()
            {
                // On the vehicle's grid while it keeps sending; a vehicle silent for longer
                // than a period starts again from now.
                let after = next + period;
                slot.next_ms = Some(if after > now_ms {
                    after
                } else {
                    now_ms + period
                });
                out.push(p);
            }
        }
        out
    }

    /// Positions replaced before they were sent, since the start.
    pub fn coalesced(&self) -> u64 {
        self.coalesced
    }
}

/// One stream's sequence numbers and its last frames, for catch-up.
#[derive(Debug)]
pub struct Journal {
    epoch: u64,
    last_seq: u64,
    frames: VecDeque<(u64, Vec<u8>)>,
    capacity: usize,
}

impl Journal {
    /// An empty stream of this run (`epoch`) keeping at most `capacity` frames.
    pub fn new(epoch: u64, capacity: usize) -> Self {
        Self {
            epoch,
            last_seq: 0,
            frames: VecDeque::with_capacity(capacity.min(1024)),
            capacity,
        }
    }

    /// Encodes the next item with the next sequence number, keeps the frame and returns
    /// it; a failed encoding uses no number.
    pub fn append<E>(
        &mut self,
        encode: impl FnOnce(u64, u64) -> Result<Vec<u8>, E>,
    ) -> Result<Vec<u8>, E> {
        let seq = self.last_seq + 1;
        let frame = encode(self.epoch, seq)?;
        self.last_seq = seq;
        if self.capacity > 0 {
            if self.frames.len() == self.capacity {
                self.frames.pop_front();
            }
            self.frames.push_back((seq, frame.clone()));
        }
        Ok(frame)
    }

    /// The kept frames a remote site that has everything up to `after` of `epoch` is
    /// missing, oldest first, at most `limit`. A remote that knows another epoch (or
    /// none) gets every kept frame.
    pub fn since(&self, epoch: Option<u64>, after: u64, limit: usize) -> Vec<Vec<u8>> {
        let after = if epoch == Some(self.epoch) { after } else { 0 };
        self.frames
            .iter()
            .filter(|(seq, _)| *seq > after)
            .take(limit)
            .map(|(_, f)| f.clone())
            .collect()
    }

    /// The last sequence number used.
    pub fn last_seq(&self) -> u64 {
        self.last_seq
    }

    /// The oldest number kept (`last_seq + 1` when none is).
    pub fn oldest(&self) -> u64 {
        self.frames
            .front()
            .map_or(self.last_seq + 1, |(seq, _)| *seq)
    }
}

/// A message ready to publish: its key expression and frame.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Publication {
    /// Where to publish.
    pub key: String,
    /// The encoded frame.
    pub frame: Vec<u8>,
}

/// The sending side's counters.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct OutboundCounters {
    /// Positions released by the limiter.
    pub positions_sent: u64,
    /// Positions replaced by a newer one before they were sent.
    pub positions_coalesced: u64,
    /// Alarms numbered and published.
    pub alarms_sent: u64,
    /// Alarms below `alarms.min_severity`, not sent.
    pub alarms_below_severity: u64,
    /// Task transitions numbered and published.
    pub transitions_sent: u64,
    /// Frames sent in answer to catch-up queries.
    pub catchup_served: u64,
    /// Catch-up answers cut short to arrive within their asker's wait (it asks for the
    /// rest).
    pub catchup_cut: u64,
    /// Catch-up queries dropped unanswered because too many were waiting (the asker asks
    /// again).
    pub catchup_dropped: u64,
    /// Orders numbered and queued for publishing.
    pub orders_sent: u64,
    /// Frames the publishing queue had no room for (remote sites catch up on them).
    pub queue_full: u64,
    /// Environment observations folded into a summary (`environment.mode = "aggregated"`).
    pub environment_observations: u64,
    /// Environment observations of a property not in `environment.properties`, not sent.
    pub environment_not_listed: u64,
    /// Environment observations dropped: a new (vehicle, property) while 10 000 summaries
    /// were held, or a unit other than the one of the property's summary in its window.
    pub environment_dropped: u64,
    /// Environment summaries (one per vehicle, property and window) published.
    pub environment_aggregates_sent: u64,
    /// Environment frames published (one per vehicle and window, more past 32 properties).
    pub environment_frames_sent: u64,
}

/// One site's sending side.
#[derive(Debug)]
pub struct Outbound {
    site: String,
    config: FederationConfig,
    positions: PositionLimiter,
    alarms: Journal,
    tasks: Journal,
    orders: Journal,
    /// `None` unless `environment.mode = "aggregated"`.
    environment: Option<Aggregator>,
    /// Numbers only: a lost summary is replaced by the next window's.
    environment_frames: Journal,
    counters: OutboundCounters,
}

/// Why a local datum was not taken.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum PushError {
    /// The datum breaks the model's rules; nothing was sent.
    #[error("not sent: {0}")]
    Invalid(#[from] ValidationError),
}

impl Outbound {
    /// The sending side of a (validated) configuration, numbering under `epoch`.
    pub fn new(config: &FederationConfig, epoch: u64) -> Self {
        let keep = |reliable: bool, n: usize| if reliable { n } else { 0 };
        Self {
            site: config.site.clone(),
            positions: PositionLimiter::new(config.positions.max_rate_hz),
            alarms: Journal::new(epoch, keep(config.alarms.reliable, config.alarms.catchup)),
            tasks: Journal::new(epoch, keep(config.tasks.reliable, config.tasks.catchup)),
            // Numbers only: an order that did not arrive is not delivered late.
            orders: Journal::new(epoch, 0),
            environment: (config.environment.mode == EnvironmentMode::Aggregated).then(|| {
                // Validation keeps the window in 5..=3600 s.
                let window_ms = i64::try_from(config.environment.window_s)
                    .unwrap_or(i64::MAX / 1000)
                    .saturating_mul(1000);
                Aggregator::new(
                    window_ms,
                    &config.environment.properties,
                    environment::MAX_AGGREGATES,
                )
            }),
            environment_frames: Journal::new(epoch, 0),
            config: config.clone(),
            counters: OutboundCounters::default(),
        }
    }

    /// Takes a local position; it goes out when its vehicle is due. Returns whether it
    /// is queued (`false` when positions do not cross).
    pub fn position(&mut self, p: VehiclePosition) -> Result<Offer, PushError> {
        p.validate()?;
        if !self.config.positions.crosses {
            return Ok(Offer::Stale);
        }
        Ok(self.positions.offer(p))
    }

    /// The positions due at `now_ms`, encoded.
    pub fn due_positions(&mut self, now_ms: i64) -> Vec<Publication> {
        let due = self.positions.due(now_ms);
        self.counters.positions_coalesced = self.positions.coalesced();
        let mut out = Vec::with_capacity(due.len());
        for p in due {
            // Validated when offered, so encoding cannot fail; skip rather than panic.
            if let Ok(frame) = wire::encode_position(&p) {
                self.counters.positions_sent += 1;
                out.push(Publication {
                    key: keys::position(&self.site, &p.vehicle_id),
                    frame,
                });
            }
        }
        out
    }

    /// Numbers a local alarm and returns it to publish; `None` when alarms do not cross
    /// or it is below the configured severity.
    pub fn alarm(&mut self, e: &Event) -> Result<Option<Publication>, PushError> {
        e.validate()?;
        let policy = &self.config.alarms;
        if !policy.crosses {
            return Ok(None);
        }
        if e.severity < policy.min_severity {
            self.counters.alarms_below_severity += 1;
            return Ok(None);
        }
        let site = &self.site;
        let frame = self
            .alarms
            .append(|epoch, seq| wire::encode_alarm(site, epoch, seq, e))?;
        self.counters.alarms_sent += 1;
        Ok(Some(Publication {
            key: keys::alarms(site),
            frame,
        }))
    }

    /// Numbers a local task transition and returns it to publish; `None` when tasks do
    /// not cross.
    pub fn task(&mut self, t: &TaskTransition) -> Result<Option<Publication>, PushError> {
        t.validate()?;
        if !self.config.tasks.crosses {
            return Ok(None);
        }
        let site = &self.site;
        let frame = self
            .tasks
            .append(|epoch, seq| wire::encode_task(site, epoch, seq, t))?;
        self.counters.transitions_sent += 1;
        Ok(Some(Publication {
            key: keys::task(site, &t.task_id),
            frame,
        }))
    }

    /// Numbers an order (a task under this site's lease for another site's vehicle; the
    /// caller checked the lease) and returns it to publish.
    pub fn order(&mut self, task: &TaskAssignment, home: &str) -> Result<Publication, PushError> {
        let site = &self.site;
        let frame = self
            .orders
            .append(|epoch, seq| wire::encode_order(site, epoch, seq, task))?;
        self.counters.orders_sent += 1;
        Ok(Publication {
            key: keys::order(site, home, &task.vehicle_id),
            frame,
        })
    }

    /// Takes a local environment observation the station took at `now_ms` (wall clock)
    /// into its vehicle's window; with `environment.mode = "off"`, does nothing (and does
    /// not look at it).
    pub fn observation(
        &mut self,
        o: &EnvironmentObservation,
        now_ms: i64,
    ) -> Result<(), PushError> {
        let Some(aggregator) = self.environment.as_mut() else {
            return Ok(());
        };
        o.validate()?;
        let c = &mut self.counters;
        match aggregator.observe(o, now_ms) {
            Observed::Taken => c.environment_observations += 1,
            Observed::NotListed => c.environment_not_listed += 1,
            Observed::Dropped | Observed::UnitMismatch => c.environment_dropped += 1,
        }
        Ok(())
    }

    /// The environment frames of the windows over at `now_ms` (wall clock), numbered and
    /// encoded; none with `environment.mode = "off"`.
    pub fn due_environment(&mut self, now_ms: i64) -> Vec<Publication> {
        let Some(aggregator) = self.environment.as_mut() else {
            return Vec::new();
        };
        let due = aggregator.due(now_ms);
        let site = &self.site;
        let mut out = Vec::with_capacity(due.len());
        for a in due {
            // Built from validated observations, so encoding cannot fail; skip rather than
            // panic.
            if let Ok(frame) = self
                .environment_frames
                .append(|epoch, seq| wire::encode_environment(site, epoch, seq, &a))
            {
                self.counters.environment_frames_sent += 1;
                self.counters.environment_aggregates_sent += a.properties.len() as u64;
                out.push(Publication {
                    key: keys::environment(site, &a.vehicle_id),
                    frame,
                });
            }
        }
        out
    }

    /// Answers a catch-up query: the kept frames after `after` of `epoch`.
    pub fn catchup(
        &self,
        stream: Stream,
        epoch: Option<u64>,
        after: u64,
        limit: usize,
    ) -> Vec<Vec<u8>> {
        self.journal(stream).since(epoch, after, limit)
    }

    fn journal(&self, stream: Stream) -> &Journal {
        match stream {
            Stream::Alarms => &self.alarms,
            Stream::Tasks => &self.tasks,
        }
    }

    /// Counts a catch-up answer: the frames it sent, and whether it was cut short so that
    /// it would arrive within its asker's wait (the asker asks for the rest).
    pub fn catchup_answered(&mut self, sent: usize, cut: bool) {
        self.counters.catchup_served += sent as u64;
        self.counters.catchup_cut += u64::from(cut);
    }

    /// The end frame of a catch-up answer on `stream`: how far it goes now (`None` only if
    /// the site's name were not one, which the configuration's validation rules out).
    pub fn catchup_end(&self, stream: Stream) -> Option<Vec<u8>> {
        let journal = self.journal(stream);
        let end = wire::CatchupEnd {
            site: self.site.clone(),
            epoch: journal.epoch,
            oldest: journal.oldest(),
            highest: journal.last_seq(),
        };
        wire::encode_catchup_end(&end).ok()
    }

    /// Counts a catch-up query dropped unanswered: too many were waiting.
    pub fn catchup_dropped(&mut self) {
        self.counters.catchup_dropped += 1;
    }

    /// Counts a frame the publishing queue had no room for.
    pub fn queue_full(&mut self) {
        self.counters.queue_full += 1;
    }

    /// The counters so far.
    pub fn counters(&self) -> &OutboundCounters {
        &self.counters
    }
}

/// How many frames a catch-up answer carries: the `limit=` a remote site asked for (what it
/// can take in one answer over its link), between 1 and `own`; `own` when it asked for none
/// or for something that is not a count.
pub fn catchup_limit(asked: Option<&str>, own: usize) -> usize {
    asked
        .and_then(|v| v.parse::<usize>().ok())
        .map_or(own, |n| n.clamp(1, own))
}

/// A vehicle's offset into the period, ms: FNV-1a of its id, so the same on every run.
pub(crate) fn phase(id: &str, period_ms: i64) -> i64 {
    let h = id.bytes().fold(0xcbf2_9ce4_8422_2325_u64, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    });
    let period = u64::try_from(period_ms.max(1)).unwrap_or(1);
    i64::try_from(h % period).unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use shoal_model::{Severity, TaskState};

    use super::*;
    use crate::types::tests::position;
    use crate::wire::tests::{alarm, transition};

    fn at(id: &str, fix_ms: i64, lat: f64) -> VehiclePosition {
        let mut p = position(id);
        p.timestamp_ms += fix_ms;
        p.latitude_deg = lat;
        p
    }

    #[test]
    fn a_vehicle_sends_at_most_once_per_period_and_the_latest_value_wins() {
        let mut l = PositionLimiter::new(0.2); // every 5 s
        let p = phase("a", 5000);
        assert_eq!(l.offer(at("a", 0, 1.0)), Offer::Queued);
        if p > 0 {
            assert!(l.due(0).is_empty(), "sent before its phase");
        }
        assert_eq!(l.due(p).len(), 1);
        // Four fixes within the period: only the last crosses, when the period is over.
        for (i, lat) in [2.0, 3.0, 4.0, 5.0].into_iter().enumerate() {
            l.offer(at("a", p + 1000 * (i as i64 + 1), lat));
            assert!(l.due(p + 1000 * (i as i64 + 1)).is_empty());
        }
        assert!(l.due(p + 4999).is_empty());
        let sent = l.due(p + 5000);
        assert_eq!(sent.len(), 1);
        assert_eq!(sent[0].latitude_deg, 5.0);
        assert_eq!(l.coalesced(), 3);
        // Nothing new: nothing sent, however late.
        assert!(l.due(60_000).is_empty());
        // After a silence longer than the period, the next fix waits a period at most.
        l.offer(at("a", 60_000, 6.0));
        assert_eq!(l.due(60_000).len(), 1);
        l.offer(at("a", 61_000, 7.0));
        assert!(l.due(64_999).is_empty());
        assert_eq!(l.due(65_000).len(), 1);
    }

    #[test]
    fn a_catch_up_answer_carries_what_was_asked_for_within_our_own_limit() {
        assert_eq!(catchup_limit(Some("100"), 1000), 100);
        assert_eq!(catchup_limit(None, 1000), 1000);
        // Whatever a remote site sends, the answer stays within 1..=own.
        for (asked, want) in [
            ("0", 1),
            ("1000000", 1000),
            ("18446744073709551616", 1000),
            ("-5", 1000),
            ("ten", 1000),
            ("", 1000),
            (" 10", 1000),
        ] {
            assert_eq!(catchup_limit(Some(asked), 1000), want, "{asked:?}");
        }
    }

    #[test]
    fn a_fleet_whose_states_arrive_together_is_sent_spread_over_the_period() {
        let mut l = PositionLimiter::new(0.2);
        let ids: Vec<String> = (0..500).map(|i| format!("auv-{i}")).collect();
        let mut per_tick = Vec::new();
        // States at 1 Hz, all in the same instant; the sender ticks every 100 ms.
        for t in (0..30_000).step_by(100) {
            if t % 1000 == 0 {
                for id in &ids {
                    l.offer(at(id, t, 1.0));
                }
            }
            per_tick.push(l.due(t).len());
        }
        // Every vehicle still sends once per period once it has started (from 5 s on)...
        let steady: usize = per_tick[100..150].iter().sum();
        assert_eq!(steady, 500);
        // ...but no tick carries more than a few times its share (500 / 50 ticks).
        let worst = per_tick.iter().max().copied().unwrap_or(0);
        assert!(worst <= 40, "{worst} positions in one tick");
    }

    #[test]
    fn vehicles_are_limited_independently() {
        let mut l = PositionLimiter::new(1.0);
        let pa = phase("a", 1000);
        l.offer(at("a", 0, 1.0));
        l.offer(at("b", 0, 1.0));
        // Each on its own phase within the first period.
        assert_eq!(l.due(0).len() + l.due(999).len(), 2);
        l.offer(at("a", 1000, 2.0));
        assert!(l.due(pa + 999).is_empty());
        assert_eq!(l.due(pa + 1000).len(), 1);
    }

    #[test]
    fn an_older_fix_arriving_late_is_ignored() {
        let mut l = PositionLimiter::new(1.0);
        l.offer(at("a", 100, 1.0));
        assert_eq!(l.offer(at("a", 50, 2.0)), Offer::Stale);
        let sent = [l.due(0), l.due(999)].concat();
        assert_eq!(sent[0].latitude_deg, 1.0);
    }

    #[test]
    fn the_journal_numbers_from_one_and_keeps_only_its_capacity() {
        let mut j = Journal::new(7, 3);
        for _ in 0..5 {
            j.append(|e, s| Ok::<_, ()>(vec![e as u8, s as u8]))
                .unwrap();
        }
        assert_eq!(j.last_seq(), 5);
        assert_eq!(
            j.since(Some(7), 0, 10),
            vec![vec![7, 3], vec![7, 4], vec![7, 5]]
        );
        assert_eq!(j.since(Some(7), 4, 10), vec![vec![7, 5]]);
        assert_eq!(j.since(Some(7), 3, 1), vec![vec![7, 4]]);
        // Another epoch, or none: everything kept.
        assert_eq!(j.since(Some(6), 4, 10).len(), 3);
        assert_eq!(j.since(None, 4, 10).len(), 3);
        // A failed encoding uses no number.
        assert!(j.append(|_, _| Err::<Vec<u8>, _>(())).is_err());
        assert_eq!(
            j.append(|_, s| Ok::<_, ()>(vec![s as u8])).unwrap(),
            vec![6]
        );
    }

    #[test]
    fn alarms_below_the_severity_do_not_cross_and_use_no_number() {
        let mut o = Outbound::new(&FederationConfig::default(), 1);
        let mut e = alarm("e1");
        e.severity = Severity::Info;
        assert_eq!(o.alarm(&e), Ok(None));
        e.severity = Severity::Warning;
        let p = o.alarm(&e).unwrap().unwrap();
        assert_eq!(p.key, "shoal/local/alarms");
        assert_eq!(wire::decode_alarm(&p.frame).unwrap().seq, 1);
        assert_eq!(o.counters().alarms_below_severity, 1);
    }

    #[test]
    fn an_invalid_datum_is_refused_and_uses_no_number() {
        let mut o = Outbound::new(&FederationConfig::default(), 1);
        let mut t = transition("t-1", TaskState::Running);
        t.task_id = "bad id".into();
        assert!(o.task(&t).is_err());
        let ok = o
            .task(&transition("t-1", TaskState::Running))
            .unwrap()
            .unwrap();
        assert_eq!(ok.key, "shoal/local/tasks/t-1");
        assert_eq!(wire::decode_task(&ok.frame).unwrap().seq, 1);
        let mut p = position("auv-1");
        p.latitude_deg = 91.0;
        assert!(o.position(p).is_err());
    }

    #[test]
    fn environment_off_takes_nothing_and_aggregated_sends_each_window_once() {
        use crate::environment::tests::{T0, obs};
        let mut off = Outbound::new(&FederationConfig::default(), 1);
        // Off: not even looked at.
        let mut bad = obs("auv-1", "t", f64::NAN, T0);
        assert_eq!(off.observation(&bad, T0), Ok(()));
        assert!(off.due_environment(T0 + 3_600_000).is_empty());
        assert_eq!(off.counters(), &OutboundCounters::default());

        let mut c = FederationConfig::default();
        c.environment.mode = EnvironmentMode::Aggregated;
        c.environment.properties = vec!["t".into()];
        let mut on = Outbound::new(&c, 9);
        assert!(on.observation(&bad, T0).is_err());
        bad.value = 1.0;
        on.observation(&bad, T0).unwrap();
        on.observation(&obs("auv-1", "t", 3.0, T0), T0).unwrap();
        on.observation(&obs("auv-1", "s", 3.0, T0), T0).unwrap();
        let sent = on.due_environment(T0 + 60_000);
        assert_eq!(sent.len(), 1);
        assert_eq!(sent[0].key, "shoal/local/environment/auv-1");
        let frame = wire::decode_environment("auv-1", &sent[0].frame).unwrap();
        assert_eq!((frame.epoch, frame.seq), (9, 1));
        assert_eq!(frame.item.properties[0].mean, 2.0);
        assert!(on.due_environment(T0 + 120_000).is_empty());
        let counters = on.counters();
        assert_eq!(counters.environment_observations, 2);
        assert_eq!(counters.environment_not_listed, 1);
        assert_eq!(counters.environment_aggregates_sent, 1);
        assert_eq!(counters.environment_frames_sent, 1);
    }

    #[test]
    fn an_unreliable_stream_keeps_nothing_for_catch_up() {
        let mut c = FederationConfig::default();
        c.alarms.reliable = false;
        let mut o = Outbound::new(&c, 1);
        o.alarm(&alarm("e1")).unwrap();
        assert!(o.catchup(Stream::Alarms, None, 0, 10).is_empty());
        o.task(&transition("t", TaskState::Done)).unwrap();
        assert_eq!(o.catchup(Stream::Tasks, None, 0, 10).len(), 1);
    }
}
