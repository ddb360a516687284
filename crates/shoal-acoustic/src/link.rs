//! The acoustic link layer: what to send next over a slow, lossy, half-duplex link.
//!
//! One queue per [`Class`] (emergency > control > telemetry > bulk). Between queues the
//! next frame follows Goby's rule (docs/acoustic.md#link-layer): priority grows with the
//! time since the queue last sent, `P = value_base · (t − t_last) / ttl`, and the highest
//! queue not in blackout goes first — except that emergency traffic always goes before
//! everything else. Per queue: TTL (expired messages are reported and dropped), ack or not
//! (control and emergency are retransmitted with exponential backoff until acknowledged or
//! expired), newest-first (telemetry: the freshest state goes first and stale states age
//! out instead of queueing forever), maximum length (oldest dropped), and an optional
//! supersede key (a newer state of the same vehicle replaces the queued one).
//!
//! A frame to one destination is filled with as many queued PDUs as fit (several compact
//! messages share one 64-byte instant message: docs/acoustic.md#compact-messages). A
//! [`Mac`] option restricts when a node may start transmitting: free (one frame in flight
//! at a time) or TDMA slots (docs/acoustic.md#medium-access).
//!
//! [`LinkCore`] is pure logic driven by explicit instants (unit tests need no runtime);
//! [`start`] runs it against a [`ModemDriver`] on tokio.

use std::collections::VecDeque;
use std::future::Future;
use std::pin::Pin;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use serde::{Deserialize, Serialize};
use tokio::sync::{mpsc, watch};
use tokio::time::Instant;
use tracing::{debug, warn};

use crate::at::BROADCAST;
use crate::driver::{ModemDriver, OutFrame, Outcome, TransmitError};
use crate::pdu::MAX_FRAME;

/// Message classes, most urgent first.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Class {
    /// Alarms and aborts: always first, acknowledged.
    Emergency,
    /// Tasks and commands: acknowledged, retransmitted.
    Control,
    /// State vectors and observations: newest first, never retransmitted.
    Telemetry,
    /// Anything that can wait.
    Bulk,
}

impl Class {
    /// All classes, most urgent first.
    pub const ALL: [Self; 4] = [Self::Emergency, Self::Control, Self::Telemetry, Self::Bulk];

    fn index(self) -> usize {
        self as usize
    }
}

/// Behaviour of one class's queue (Goby's per-queue settings, docs/acoustic.md#link-layer).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QueueConfig {
    /// Goby's `value_base`: how fast priority grows.
    pub value_base: f64,
    /// Time to live; also the denominator of the priority growth.
    #[serde(with = "secs")]
    pub ttl: Duration,
    /// Whether frames carrying this class ask for an ack and are retransmitted.
    pub ack: bool,
    /// Send the newest message first.
    pub newest_first: bool,
    /// Longest queue; when full the oldest message is dropped.
    pub max_len: usize,
    /// After sending, the queue may not send again for this long.
    #[serde(with = "secs")]
    pub blackout: Duration,
}

mod secs {
    //! Durations as floating seconds in config files.
    use serde::{Deserialize, Deserializer, Serializer};
    use std::time::Duration;

    pub(super) fn serialize<S: Serializer>(d: &Duration, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_f64(d.as_secs_f64())
    }

    pub(super) fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Duration, D::Error> {
        let v = f64::deserialize(d)?;
        Duration::try_from_secs_f64(v).map_err(serde::de::Error::custom)
    }
}

/// When a node may start a transmission.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase", deny_unknown_fields)]
#[non_exhaustive]
pub enum Mac {
    /// Whenever the previous frame's outcome is known.
    Free,
    /// Fixed TDMA slots: `slots` slots of `slot` each, this node owns `own_slot`; a frame
    /// only starts in the first `slot − guard` of the own slot. Cycles are counted from the
    /// Unix epoch on the wall clock, so every node whose clock is synchronised (GPS at the
    /// surface, before diving) agrees on the slots without exchanging anything.
    Tdma {
        /// Slot length.
        #[serde(with = "secs")]
        slot: Duration,
        /// Slots per cycle.
        slots: u32,
        /// This node's slot, 0-based.
        own_slot: u32,
        /// Time kept free at the end of a slot (air time + propagation of one frame).
        #[serde(with = "secs")]
        guard: Duration,
    },
}

/// Link layer configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LinkConfig {
    /// Emergency queue.
    pub emergency: QueueConfig,
    /// Control queue.
    pub control: QueueConfig,
    /// Telemetry queue.
    pub telemetry: QueueConfig,
    /// Bulk queue.
    pub bulk: QueueConfig,
    /// Largest frame, bytes (64 = one instant message).
    pub max_frame: usize,
    /// First retransmission delay; doubles per attempt.
    #[serde(with = "secs")]
    pub backoff_initial: Duration,
    /// Longest retransmission delay.
    #[serde(with = "secs")]
    pub backoff_max: Duration,
    /// Medium access.
    pub mac: Mac,
}

impl Default for LinkConfig {
    fn default() -> Self {
        let q = |value_base, ttl_s, ack, newest_first, max_len| QueueConfig {
            value_base,
            ttl: Duration::from_secs(ttl_s),
            ack,
            newest_first,
            max_len,
            blackout: Duration::ZERO,
        };
        Self {
            emergency: q(1000.0, 600, true, false, 16),
            control: q(100.0, 900, true, false, 64),
            // Stale telemetry is useless: a minute, newest first, a short queue.
            telemetry: q(10.0, 60, false, true, 8),
            // Goby's default TTL (docs/acoustic.md#link-layer).
            bulk: q(1.0, 1800, false, false, 256),
            max_frame: MAX_FRAME,
            backoff_initial: Duration::from_secs(2),
            backoff_max: Duration::from_secs(60),
            mac: Mac::Free,
        }
    }
}

impl LinkConfig {
    /// The queue settings of `class`.
    pub fn queue(&self, class: Class) -> &QueueConfig {
        match class {
            Class::Emergency => &self.emergency,
            Class::Control => &self.control,
            Class::Telemetry => &self.telemetry,
            Class::Bulk => &self.bulk,
        }
    }

    /// Multiplies every duration (for emulators running faster than real time).
    pub fn scaled(mut self, factor: f64) -> Self {
        let s = |d: Duration| Duration::from_secs_f64(d.as_secs_f64() * factor);
        for q in [
            &mut self.emergency,
            &mut self.control,
            &mut self.telemetry,
            &mut self.bulk,
        ] {
            q.ttl = s(q.ttl);
            q.blackout = s(q.blackout);
        }
        self.backoff_initial = s(self.backoff_initial);
        self.backoff_max = s(self.backoff_max);
        if let Mac::Tdma { slot, guard, .. } = &mut self.mac {
            *slot = s(*slot);
            *guard = s(*guard);
        }
        self
    }
}

/// Identifies a queued message in [`LinkEvent`]s.
pub type MessageId = u64;

/// A message for the link: one encoded PDU for one destination.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Outgoing {
    /// Destination modem address (255 = broadcast; never acknowledged).
    pub dst: u8,
    /// Queue.
    pub class: Class,
    /// One encoded PDU (see [`crate::pdu::encode`]).
    pub pdu: Vec<u8>,
    /// A newer message with the same key and class replaces a queued one.
    pub supersede_key: Option<u64>,
}

/// What happened to messages, and what arrived.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum LinkEvent {
    /// A frame arrived; unpack it with [`crate::pdu::unpack_frame`].
    Received {
        /// Sender address.
        src: u8,
        /// Destination address.
        dst: u8,
        /// The frame.
        frame: Vec<u8>,
        /// RSSI, dB, if the modem reports it.
        rssi: Option<i32>,
        /// Integrity, if the modem reports it.
        integrity: Option<u32>,
    },
    /// The destination acknowledged the message.
    Delivered(MessageId),
    /// Sent without acknowledgement.
    Sent(MessageId),
    /// Its TTL ran out before it was delivered.
    Expired(MessageId),
    /// Dropped: queue full, superseded, rejected by the modem, or larger than a frame.
    Dropped(MessageId),
}

#[derive(Debug, Clone)]
struct Entry {
    id: MessageId,
    msg: Outgoing,
    enqueued: Instant,
    expires: Instant,
    not_before: Instant,
    attempts: u32,
}

/// A frame chosen by [`LinkCore::next_frame`], to hand to the driver.
#[derive(Debug, Clone)]
pub struct FramePlan {
    /// The frame.
    pub frame: OutFrame,
    /// Messages in it.
    pub ids: Vec<MessageId>,
    entries: Vec<Entry>,
}

/// The link layer's queues and decisions, without I/O.
#[derive(Debug)]
pub struct LinkCore {
    cfg: LinkConfig,
    queues: [VecDeque<Entry>; 4],
    last_sent: [Instant; 4],
    epoch: Instant,
    next_id: MessageId,
}

impl LinkCore {
    /// Empty queues; `epoch` is when TDMA slot 0 of cycle 0 starts (and the reference for
    /// priority growth).
    pub fn new(cfg: LinkConfig, epoch: Instant) -> Self {
        Self {
            cfg,
            queues: Default::default(),
            last_sent: [epoch; 4],
            epoch,
            next_id: 1,
        }
    }

    /// Messages waiting (not in flight).
    pub fn queued(&self) -> usize {
        self.queues.iter().map(VecDeque::len).sum()
    }

    /// Queues a message with a fresh id.
    pub fn push(&mut self, msg: Outgoing, now: Instant) -> (MessageId, Vec<LinkEvent>) {
        let id = self.next_id;
        self.next_id += 1;
        (id, self.push_with_id(id, msg, now))
    }

    /// Queues a message under `id`; returns events for messages it displaced.
    pub fn push_with_id(&mut self, id: MessageId, msg: Outgoing, now: Instant) -> Vec<LinkEvent> {
        let mut events = Vec::new();
        if msg.pdu.len() > self.cfg.max_frame {
            warn!(id, len = msg.pdu.len(), "PDU larger than a frame dropped");
            return vec![LinkEvent::Dropped(id)];
        }
        let qc = *self.cfg.queue(msg.class);
        let Some(q) = self.queues.get_mut(msg.class.index()) else {
            return vec![LinkEvent::Dropped(id)];
        };
        if let Some(key) = msg.supersede_key {
            q.retain(|e| {
                let same = e.msg.supersede_key == Some(key) && e.msg.dst == msg.dst;
                if same {
                    events.push(LinkEvent::Dropped(e.id));
                }
                !same
            });
        }
        while q.len() >= qc.max_len.max(1) {
            if let Some(old) = q.pop_front() {
                events.push(LinkEvent::Dropped(old.id));
            }
        }
        q.push_back(Entry {
            id,
            msg,
            enqueued: now,
            expires: now + qc.ttl,
            not_before: now,
            attempts: 0,
        });
        events
    }

    /// Drops expired messages.
    pub fn expire(&mut self, now: Instant) -> Vec<LinkEvent> {
        let mut events = Vec::new();
        for q in &mut self.queues {
            q.retain(|e| {
                let alive = e.expires > now;
                if !alive {
                    debug!(id = e.id, "message expired");
                    events.push(LinkEvent::Expired(e.id));
                }
                alive
            });
        }
        events
    }

    /// Goby priority of a class now (emergency: infinite while it has traffic).
    pub fn priority(&self, class: Class, now: Instant) -> f64 {
        if class == Class::Emergency {
            return f64::INFINITY;
        }
        let qc = self.cfg.queue(class);
        let since = now.saturating_duration_since(
            self.last_sent
                .get(class.index())
                .copied()
                .unwrap_or(self.epoch),
        );
        qc.value_base * since.as_secs_f64() / qc.ttl.as_secs_f64().max(1e-9)
    }

    /// Whether the MAC allows starting a frame now; otherwise when it next will.
    pub fn mac_ready(&self, now: Instant) -> Result<(), Instant> {
        match self.cfg.mac {
            Mac::Free => Ok(()),
            Mac::Tdma {
                slot,
                slots,
                own_slot,
                guard,
            } => {
                let slot_s = slot.as_secs_f64().max(1e-6);
                let cycle = slot_s * f64::from(slots.max(1));
                let t = now.saturating_duration_since(self.epoch).as_secs_f64();
                let in_cycle = t.rem_euclid(cycle);
                let own_start = slot_s * f64::from(own_slot % slots.max(1));
                let usable = (slot_s - guard.as_secs_f64()).max(0.0);
                if in_cycle >= own_start && in_cycle < own_start + usable {
                    return Ok(());
                }
                let wait = (own_start - in_cycle).rem_euclid(cycle);
                Err(now + Duration::from_secs_f64(wait))
            }
        }
    }

    fn eligible(&self, class: Class, now: Instant) -> bool {
        let qc = self.cfg.queue(class);
        let last = self
            .last_sent
            .get(class.index())
            .copied()
            .unwrap_or(self.epoch);
        let blackout_over =
            last == self.epoch || now.saturating_duration_since(last) >= qc.blackout;
        blackout_over
            && self
                .queues
                .get(class.index())
                .is_some_and(|q| q.iter().any(|e| e.not_before <= now))
    }

    /// Chooses the next frame and takes its messages out of the queues.
    pub fn next_frame(&mut self, now: Instant) -> Option<FramePlan> {
        let mut order: Vec<Class> = Class::ALL
            .into_iter()
            .filter(|&c| self.eligible(c, now))
            .collect();
        if order.is_empty() {
            return None;
        }
        // Highest priority first; ties go to the more urgent class.
        order.sort_by(|a, b| {
            self.priority(*b, now)
                .total_cmp(&self.priority(*a, now))
                .then(a.cmp(b))
        });
        let first = *order.first()?;
        let pick_in =
            |q: &VecDeque<Entry>, newest: bool, pred: &dyn Fn(&Entry) -> bool| -> Vec<usize> {
                let mut idx: Vec<usize> = (0..q.len())
                    .filter(|&i| q.get(i).is_some_and(|e| e.not_before <= now && pred(e)))
                    .collect();
                if newest {
                    idx.sort_by_key(|&i| std::cmp::Reverse(q.get(i).map(|e| e.enqueued)));
                }
                idx
            };
        let head_q = self.queues.get(first.index())?;
        let head_idx = *pick_in(head_q, self.cfg.queue(first).newest_first, &|_| true).first()?;
        let dst = head_q.get(head_idx)?.msg.dst;
        // Fill the frame: classes in priority order, each in its own order, same destination.
        // An emergency frame takes no telemetry or bulk filler: every byte lengthens its air
        // time, and its latency is what the emergency class exists for.
        let mut chosen: Vec<(Class, usize)> = vec![(first, head_idx)];
        let mut size = head_q.get(head_idx)?.msg.pdu.len();
        let fillers: Vec<Class> = if first == Class::Emergency {
            order
                .iter()
                .copied()
                .filter(|c| *c <= Class::Control)
                .collect()
        } else {
            order.clone()
        };
        for &c in &fillers {
            let Some(q) = self.queues.get(c.index()) else {
                continue;
            };
            for i in pick_in(q, self.cfg.queue(c).newest_first, &|e| e.msg.dst == dst) {
                if chosen.contains(&(c, i)) {
                    continue;
                }
                let Some(e) = q.get(i) else { continue };
                if size + e.msg.pdu.len() <= self.cfg.max_frame {
                    size += e.msg.pdu.len();
                    chosen.push((c, i));
                }
            }
        }
        // Remove from the back so earlier indices stay valid.
        chosen.sort_by(|a, b| b.cmp(a));
        let mut entries = Vec::with_capacity(chosen.len());
        for (c, i) in chosen {
            if let Some(e) = self.queues.get_mut(c.index()).and_then(|q| q.remove(i)) {
                if let Some(t) = self.last_sent.get_mut(c.index()) {
                    *t = now;
                }
                entries.push(e);
            }
        }
        // Restore priority order inside the frame (most urgent PDUs first).
        entries.sort_by_key(|e| (e.msg.class, e.enqueued));
        let ack = dst != BROADCAST && entries.iter().any(|e| self.cfg.queue(e.msg.class).ack);
        let data: Vec<u8> = entries
            .iter()
            .flat_map(|e| e.msg.pdu.iter().copied())
            .collect();
        Some(FramePlan {
            frame: OutFrame {
                dst,
                data,
                ack,
                burst: false,
            },
            ids: entries.iter().map(|e| e.id).collect(),
            entries,
        })
    }

    fn backoff(&self, attempts: u32) -> Duration {
        let f = 2f64.powi(
            i32::try_from(attempts.saturating_sub(1))
                .unwrap_or(30)
                .min(30),
        );
        Duration::from_secs_f64(
            (self.cfg.backoff_initial.as_secs_f64() * f).min(self.cfg.backoff_max.as_secs_f64()),
        )
    }

    /// Applies a frame's outcome: done, or back in the queue with backoff.
    pub fn on_outcome(
        &mut self,
        plan: FramePlan,
        outcome: &Result<Outcome, TransmitError>,
        now: Instant,
    ) -> Vec<LinkEvent> {
        let mut events = Vec::new();
        for mut e in plan.entries {
            let qc = *self.cfg.queue(e.msg.class);
            let needs_ack = qc.ack && e.msg.dst != BROADCAST;
            match outcome {
                Ok(Outcome::Delivered) => events.push(LinkEvent::Delivered(e.id)),
                Ok(Outcome::Sent) if !needs_ack => events.push(LinkEvent::Sent(e.id)),
                // The modem refused the frame: retrying the same bytes will not help.
                Err(TransmitError::Rejected { reason, .. }) => {
                    warn!(id = e.id, %reason, "frame rejected by modem");
                    events.push(LinkEvent::Dropped(e.id));
                }
                // Unacknowledged traffic is never retransmitted (it may well have arrived).
                Ok(_) if !needs_ack => events.push(LinkEvent::Sent(e.id)),
                _ => {
                    e.attempts += 1;
                    e.not_before = now + self.backoff(e.attempts);
                    if e.not_before >= e.expires {
                        events.push(LinkEvent::Expired(e.id));
                    } else if let Some(q) = self.queues.get_mut(e.msg.class.index()) {
                        debug!(id = e.id, attempts = e.attempts, "retransmission scheduled");
                        q.push_front(e);
                    }
                }
            }
        }
        events
    }

    /// The next instant at which something may change without new input.
    pub fn next_wakeup(&self, now: Instant) -> Option<Instant> {
        self.queues
            .iter()
            .flatten()
            .flat_map(|e| {
                [
                    Some(e.expires),
                    (e.not_before > now).then_some(e.not_before),
                ]
            })
            .flatten()
            .min()
    }
}

/// Sends messages into a running link.
#[derive(Debug, Clone)]
pub struct LinkSender {
    tx: mpsc::Sender<(MessageId, Outgoing)>,
    ids: Arc<AtomicU64>,
}

/// The link has stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("acoustic link stopped")]
pub struct LinkClosed;

impl LinkSender {
    /// Queues a message; its fate is reported as a [`LinkEvent`] with the returned id.
    pub async fn send(&self, msg: Outgoing) -> Result<MessageId, LinkClosed> {
        let id = self.ids.fetch_add(1, Ordering::Relaxed);
        self.tx.send((id, msg)).await.map_err(|_| LinkClosed)?;
        Ok(id)
    }
}

/// The instant at which the TDMA cycle running at `now` began, with cycles counted from the
/// Unix epoch (`since_unix` is the wall clock at `now`): nodes started at different times
/// but with synchronised clocks get the same cycle boundaries.
pub fn tdma_epoch(cycle: Duration, since_unix: Duration, now: Instant) -> Instant {
    let cycle_ns = cycle.as_nanos().max(1);
    let into_cycle = since_unix.as_nanos() % cycle_ns;
    let into_cycle = Duration::from_nanos(u64::try_from(into_cycle).unwrap_or(0));
    now.checked_sub(into_cycle).unwrap_or(now)
}

/// Runs a link over `driver` until `shutdown` completes; returns the sender and the
/// event stream (received frames and message fates).
pub fn start<D: ModemDriver + 'static>(
    driver: D,
    cfg: LinkConfig,
    shutdown: impl Future<Output = ()> + Send + 'static,
) -> (LinkSender, mpsc::Receiver<LinkEvent>) {
    let (tx, rx) = mpsc::channel(256);
    let (ev_tx, ev_rx) = mpsc::channel(1024);
    let (stop_tx, stop_rx) = watch::channel(false);
    tokio::spawn(async move {
        shutdown.await;
        let _ = stop_tx.send(true);
    });
    tokio::spawn(run(driver, cfg, rx, ev_tx, stop_rx));
    (
        LinkSender {
            tx,
            ids: Arc::new(AtomicU64::new(1)),
        },
        ev_rx,
    )
}

type TxFuture<'a> = Pin<Box<dyn Future<Output = Result<Outcome, TransmitError>> + Send + 'a>>;

async fn poll_opt(f: &mut Option<(FramePlan, TxFuture<'_>)>) -> Result<Outcome, TransmitError> {
    match f {
        Some((_, fut)) => fut.await,
        None => std::future::pending().await,
    }
}

async fn sleep_opt(at: Option<Instant>) {
    match at {
        Some(t) => tokio::time::sleep_until(t).await,
        None => std::future::pending().await,
    }
}

async fn emit(events: &mpsc::Sender<LinkEvent>, list: Vec<LinkEvent>) {
    for e in list {
        // Nobody listening is not an error: the link keeps running.
        let _ = events.send(e).await;
    }
}

async fn run<D: ModemDriver>(
    driver: D,
    cfg: LinkConfig,
    mut cmds: mpsc::Receiver<(MessageId, Outgoing)>,
    events: mpsc::Sender<LinkEvent>,
    mut stop: watch::Receiver<bool>,
) {
    let now = Instant::now();
    let epoch = match &cfg.mac {
        Mac::Tdma { slot, slots, .. } => {
            let since_unix = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .unwrap_or_default();
            tdma_epoch(*slot * (*slots).max(1), since_unix, now)
        }
        Mac::Free => now,
    };
    let mut core = LinkCore::new(cfg, epoch);
    let mut in_flight: Option<(FramePlan, TxFuture<'_>)> = None;
    let mut cmds_open = true;
    loop {
        let now = Instant::now();
        emit(&events, core.expire(now)).await;
        let mut mac_wait = None;
        if in_flight.is_none() {
            match core.mac_ready(now) {
                Ok(()) => {
                    if let Some(plan) = core.next_frame(now) {
                        debug!(
                            dst = plan.frame.dst,
                            bytes = plan.frame.data.len(),
                            n = plan.ids.len(),
                            "frame out"
                        );
                        let fut: TxFuture<'_> = Box::pin(driver.transmit(plan.frame.clone()));
                        in_flight = Some((plan, fut));
                    }
                }
                Err(next) if core.queued() > 0 => mac_wait = Some(next),
                Err(_) => {}
            }
        }
        let wake = match (core.next_wakeup(now), mac_wait) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        };
        tokio::select! {
            r = poll_opt(&mut in_flight) => {
                if let Some((plan, _)) = in_flight.take() {
                    let evs = core.on_outcome(plan, &r, Instant::now());
                    emit(&events, evs).await;
                }
            }
            f = driver.receive() => match f {
                Some(f) => {
                    let ev = LinkEvent::Received { src: f.src, dst: f.dst, frame: f.data, rssi: f.rssi, integrity: f.integrity };
                    let _ = events.send(ev).await;
                }
                None => {
                    warn!("modem driver stopped; link stops");
                    return;
                }
            },
            m = cmds.recv(), if cmds_open => match m {
                Some((id, msg)) => {
                    let evs = core.push_with_id(id, msg, Instant::now());
                    emit(&events, evs).await;
                }
                None => cmds_open = false,
            },
            () = sleep_opt(wake) => {}
            () = crate::emulator::stopped(&mut stop) => return,
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod tests {
    use super::*;

    fn msg(class: Class, byte: u8, len: usize) -> Outgoing {
        Outgoing {
            dst: 2,
            class,
            pdu: vec![byte; len],
            supersede_key: None,
        }
    }

    #[test]
    fn emergency_overtakes_queued_telemetry() {
        let t0 = Instant::now();
        let mut core = LinkCore::new(
            LinkConfig {
                max_frame: 10,
                ..LinkConfig::default()
            },
            t0,
        );
        for i in 0..5 {
            core.push(msg(Class::Telemetry, i, 10), t0);
        }
        let (e, _) = core.push(msg(Class::Emergency, 0xee, 10), t0 + Duration::from_secs(1));
        let plan = core.next_frame(t0 + Duration::from_secs(2)).unwrap();
        assert_eq!(plan.ids, vec![e]);
        assert!(plan.frame.ack);
    }

    #[test]
    fn several_pdus_share_a_frame_most_urgent_first() {
        let t0 = Instant::now();
        let mut core = LinkCore::new(LinkConfig::default(), t0);
        let (a, _) = core.push(msg(Class::Telemetry, 1, 20), t0);
        let (b, _) = core.push(msg(Class::Control, 2, 13), t0);
        let (c, _) = core.push(msg(Class::Bulk, 3, 40), t0); // does not fit with the others
        let plan = core.next_frame(t0 + Duration::from_secs(1)).unwrap();
        assert_eq!(plan.ids, vec![b, a]);
        assert_eq!(plan.frame.data.len(), 33);
        assert_eq!(core.queued(), 1);
        let _ = c;
    }

    #[test]
    fn telemetry_is_newest_first_and_stale_telemetry_expires() {
        let t0 = Instant::now();
        let cfg = LinkConfig {
            max_frame: 10,
            ..LinkConfig::default()
        };
        let mut core = LinkCore::new(cfg, t0);
        let (old, _) = core.push(msg(Class::Telemetry, 1, 10), t0);
        let (new, _) = core.push(msg(Class::Telemetry, 2, 10), t0 + Duration::from_secs(10));
        let plan = core.next_frame(t0 + Duration::from_secs(11)).unwrap();
        assert_eq!(plan.ids, vec![new]);
        assert_eq!(
            core.expire(t0 + Duration::from_secs(61)),
            vec![LinkEvent::Expired(old)]
        );
    }

    #[test]
    fn a_full_telemetry_queue_drops_its_oldest() {
        let t0 = Instant::now();
        let mut core = LinkCore::new(LinkConfig::default(), t0);
        let (first, _) = core.push(msg(Class::Telemetry, 0, 5), t0);
        let mut dropped = Vec::new();
        for i in 1..=8 {
            dropped.extend(core.push(msg(Class::Telemetry, i, 5), t0).1);
        }
        assert_eq!(dropped, vec![LinkEvent::Dropped(first)]);
    }

    #[test]
    fn supersede_key_replaces_the_queued_state() {
        let t0 = Instant::now();
        let mut core = LinkCore::new(LinkConfig::default(), t0);
        let m = |b| Outgoing {
            supersede_key: Some(7),
            ..msg(Class::Telemetry, b, 10)
        };
        let (a, _) = core.push(m(1), t0);
        let (_, ev) = core.push(m(2), t0);
        assert_eq!(ev, vec![LinkEvent::Dropped(a)]);
        assert_eq!(core.queued(), 1);
    }

    #[test]
    fn failed_control_is_retransmitted_with_backoff_until_ttl() {
        let t0 = Instant::now();
        let mut core = LinkCore::new(LinkConfig::default(), t0);
        let (id, _) = core.push(msg(Class::Control, 1, 10), t0);
        let mut now = t0;
        let mut gaps = Vec::new();
        let mut expired = false;
        for _ in 0..20 {
            let Some(plan) = core.next_frame(now) else {
                let next = core.next_wakeup(now).unwrap();
                gaps.push(next.duration_since(now).as_secs());
                now = next;
                continue;
            };
            let ev = core.on_outcome(plan, &Ok(Outcome::Failed), now);
            if ev.contains(&LinkEvent::Expired(id)) {
                expired = true;
                break;
            }
        }
        assert_eq!(&gaps[..4], &[2, 4, 8, 16]);
        assert!(expired || now < t0 + Duration::from_secs(900));
    }

    #[test]
    fn failed_telemetry_is_not_retransmitted() {
        let t0 = Instant::now();
        let mut core = LinkCore::new(LinkConfig::default(), t0);
        let (id, _) = core.push(msg(Class::Telemetry, 1, 10), t0);
        let plan = core.next_frame(t0).unwrap();
        assert!(!plan.frame.ack);
        assert_eq!(
            core.on_outcome(plan, &Ok(Outcome::Sent), t0),
            vec![LinkEvent::Sent(id)]
        );
        assert_eq!(core.queued(), 0);
    }

    #[test]
    fn goby_priority_grows_with_waiting_time() {
        let t0 = Instant::now();
        let core = LinkCore::new(LinkConfig::default(), t0);
        let p = |c, s| core.priority(c, t0 + Duration::from_secs(s));
        // Telemetry (10/60 s) that waited 60 s outranks control (100/900 s) that waited 60 s.
        assert!(p(Class::Telemetry, 60) > p(Class::Control, 60));
        assert!(p(Class::Control, 60) > p(Class::Control, 30));
        assert!(p(Class::Emergency, 0).is_infinite());
    }

    #[test]
    fn tdma_cycles_agree_between_nodes_started_at_different_times() {
        let cycle = Duration::from_secs(30);
        let t0 = Instant::now();
        let unix0 = Duration::from_secs(1_763_700_000) + Duration::from_millis(12_345);
        let a = tdma_epoch(cycle, unix0, t0);
        // Node B starts 7.3 s later on the same (synchronised) clock.
        let late = Duration::from_millis(7_300);
        let b = tdma_epoch(cycle, unix0 + late, t0 + late);
        assert_eq!(a, b);
        // And a node starting in the next cycle lands on a boundary one cycle on.
        let next = Duration::from_secs(31);
        let c = tdma_epoch(cycle, unix0 + next, t0 + next);
        assert_eq!(c.duration_since(a), cycle);
    }

    #[test]
    fn tdma_only_starts_frames_in_the_own_slot() {
        let t0 = Instant::now();
        let mac = Mac::Tdma {
            slot: Duration::from_secs(10),
            slots: 3,
            own_slot: 1,
            guard: Duration::from_secs(2),
        };
        let core = LinkCore::new(
            LinkConfig {
                mac,
                ..LinkConfig::default()
            },
            t0,
        );
        let at = |s: u64| t0 + Duration::from_secs(s);
        assert_eq!(core.mac_ready(at(5)), Err(at(10)));
        assert_eq!(core.mac_ready(at(12)), Ok(()));
        assert_eq!(core.mac_ready(at(19)), Err(at(40)));
        assert_eq!(core.mac_ready(at(35)), Err(at(40)));
    }
}
