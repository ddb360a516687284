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
use crate::driver::{ModemDriver, OutFrame, Outcome, TransmitError, Withdrawal};
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
    /// Fixed TDMA slots: `slots` slots of `slot` each, this node owns `own_slot`. Frames go
    /// back to back inside the own slot, each sized so that it is off air `guard` before the
    /// slot ends (the last one shrinks to the time left: docs/acoustic.md#medium-access).
    /// Cycles are counted from the Unix epoch on the wall clock, so every node whose clock
    /// is synchronised (GPS at the surface, before diving) agrees on the slots without
    /// exchanging anything.
    Tdma {
        /// Slot length.
        #[serde(with = "secs")]
        slot: Duration,
        /// Slots per cycle.
        slots: u32,
        /// This node's slot, 0-based.
        own_slot: u32,
        /// Time kept free at the end of a slot: the spread of propagation delays to the
        /// receivers plus the clocks' disagreement, so the next owner's first frame never
        /// overlaps this node's last one at any receiver.
        #[serde(with = "secs")]
        guard: Duration,
        /// The modem's fixed on-air overhead per frame (preamble), which sizes frames.
        #[serde(with = "secs", default = "default_preamble")]
        preamble: Duration,
        /// The modem's instant-message bit rate, bit/s, which sizes frames.
        #[serde(default = "default_bit_rate")]
        bit_rate: f64,
        /// Timing advance: this node's propagation delay to the receiver its slots are
        /// planned at (the station). It starts each slot that much early, so frames from
        /// nodes at different ranges arrive in their slots there and the guard need not
        /// cover the spread of ranges.
        #[serde(with = "secs", default)]
        advance: Duration,
    },
}

fn default_preamble() -> Duration {
    Duration::from_millis(100)
}

fn default_bit_rate() -> f64 {
    976.0
}

impl Mac {
    /// TDMA with the S2C's instant-message air time (0.1 s + bits at 976 bit/s,
    /// docs/acoustic.md#frame-sizes-and-bit-rates).
    pub fn tdma(slot: Duration, slots: u32, own_slot: u32, guard: Duration) -> Self {
        Self::Tdma {
            slot,
            slots,
            own_slot,
            guard,
            preamble: default_preamble(),
            bit_rate: default_bit_rate(),
            advance: Duration::ZERO,
        }
    }

    /// When TDMA cycle 0 of the cycle running at `now` began, counted from the Unix epoch
    /// (`since_unix` is the wall clock at `now`) in whole nanoseconds of `slot × slots`, as
    /// every node of the plan counts it (`None` without TDMA). Anyone reckoning the slots
    /// from outside a link (a benchmark, a test) must count with this, not in floating
    /// seconds: the cycle is a whole number of nanoseconds, and a fraction of a nanosecond
    /// per cycle over the ~10⁹ cycles since 1970 moves the phase by a sizeable part of it.
    pub fn tdma_epoch(&self, since_unix: Duration, now: Instant) -> Option<Instant> {
        match self {
            Self::Tdma { slot, slots, .. } => {
                Some(tdma_epoch(*slot * (*slots).max(1), since_unix, now))
            }
            Self::Free => None,
        }
    }

    /// Where this node stands in its TDMA plan when the wall clock reads `since_unix`,
    /// reckoned exactly as its running link reckons it (`None` without TDMA): with no frame
    /// of its own on air, how long its own slot stays open, and when it next opens.
    pub fn own_slot_at(&self, since_unix: Duration, now: Instant) -> Option<OwnSlot> {
        let epoch = self.tdma_epoch(since_unix, now)?;
        let core = LinkCore::new(
            LinkConfig {
                mac: *self,
                ..LinkConfig::default()
            },
            epoch,
        );
        let pos = core.tdma_at(now)?;
        Some(OwnSlot {
            left: Duration::from_secs_f64(pos.left_s.max(0.0)),
            next_open: pos.next_open,
        })
    }

    /// The same MAC with a timing advance (TDMA only; a free MAC is returned unchanged).
    #[must_use]
    pub fn with_advance(mut self, by: Duration) -> Self {
        if let Self::Tdma { advance, .. } = &mut self {
            *advance = by;
        }
        self
    }
}

/// A node's place in its TDMA plan at one instant ([`Mac::own_slot_at`]), at its own
/// transmitter (timing advance applied).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OwnSlot {
    /// How long the own slot stays open from that instant (zero outside it).
    pub left: Duration,
    /// When the own slot next opens after the current one.
    pub next_open: Instant,
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
        if let Mac::Tdma {
            slot,
            guard,
            preamble,
            bit_rate,
            advance,
            ..
        } = &mut self.mac
        {
            *slot = s(*slot);
            *guard = s(*guard);
            *preamble = s(*preamble);
            *advance = s(*advance);
            // Bits go out `1 / factor` times as fast when time runs faster.
            *bit_rate /= factor.max(1e-9);
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
    /// The core's `busy_until` and `last_sent` before this frame was planned, restored if
    /// the frame is withdrawn (it never went on air).
    busy_before: Instant,
    last_sent_before: [Instant; 4],
}

impl FramePlan {
    /// Whether the frame carries an emergency PDU.
    pub fn has_emergency(&self) -> bool {
        self.entries.iter().any(|e| e.msg.class == Class::Emergency)
    }
}

/// Where an instant falls in the TDMA cycle.
#[derive(Debug, Clone, Copy)]
struct SlotPosition {
    /// Seconds of the own slot left at `start` (0 outside it).
    left_s: f64,
    /// When the own slot next opens after the current one.
    next_open: Instant,
}

/// The link layer's queues and decisions, without I/O.
#[derive(Debug)]
pub struct LinkCore {
    cfg: LinkConfig,
    queues: [VecDeque<Entry>; 4],
    last_sent: [Instant; 4],
    epoch: Instant,
    next_id: MessageId,
    /// When this node's last frame leaves the air (TDMA sizes the next one from then).
    busy_until: Instant,
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
            busy_until: epoch,
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
        self.frame_budget(now).map(|_| ())
    }

    /// How long a frame of `bytes` stays on air, if the MAC knows the modem's rate.
    pub fn air_time(&self, bytes: usize) -> Option<Duration> {
        match self.cfg.mac {
            Mac::Free => None,
            Mac::Tdma {
                preamble, bit_rate, ..
            } => {
                #[allow(clippy::cast_precision_loss)]
                let bits = (bytes * 8) as f64;
                Some(preamble + Duration::from_secs_f64(bits / bit_rate.max(1e-9)))
            }
        }
    }

    /// The largest frame, in bytes, that may start now: under TDMA, one that is off air
    /// `guard` before the own slot ends, counted from when this node's previous frame
    /// leaves the air (the driver hands a frame over slightly before that). `Err` holds
    /// when the own slot next opens.
    pub fn frame_budget(&self, now: Instant) -> Result<usize, Instant> {
        let (
            Mac::Tdma {
                guard,
                preamble,
                bit_rate,
                ..
            },
            Some(pos),
        ) = (self.cfg.mac, self.tdma_at(now))
        else {
            return Ok(self.cfg.max_frame);
        };
        let left = pos.left_s - guard.as_secs_f64() - preamble.as_secs_f64();
        #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
        let bytes = (left * bit_rate / 8.0).floor().max(0.0) as usize;
        if bytes == 0 {
            return Err(pos.next_open);
        }
        Ok(bytes.min(self.cfg.max_frame))
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
    ///
    /// The most urgent eligible message that fits the MAC's budget heads the frame
    /// (emergency first: it goes in the next frame this node owns); the rest of the frame
    /// is filled with messages to the same destination. An emergency frame takes only
    /// emergency and control messages, so it stays short.
    pub fn next_frame(&mut self, now: Instant) -> Option<FramePlan> {
        let budget = self.frame_budget(now).ok()?;
        let busy_before = self.busy_until;
        let last_sent_before = self.last_sent;
        let mut order: Vec<Class> = Class::ALL
            .into_iter()
            .filter(|&c| self.eligible(c, now))
            .collect();
        // Highest priority first; ties go to the more urgent class.
        order.sort_by(|a, b| {
            self.priority(*b, now)
                .total_cmp(&self.priority(*a, now))
                .then(a.cmp(b))
        });
        // Every eligible message in sending order: class by priority, each in its own order.
        let mut candidates: Vec<(Class, usize)> = Vec::new();
        for &c in &order {
            let Some(q) = self.queues.get(c.index()) else {
                continue;
            };
            let mut idx: Vec<usize> = (0..q.len())
                .filter(|&i| q.get(i).is_some_and(|e| e.not_before <= now))
                .collect();
            if self.cfg.queue(c).newest_first {
                idx.sort_by_key(|&i| std::cmp::Reverse(q.get(i).map(|e| e.enqueued)));
            }
            candidates.extend(idx.into_iter().map(|i| (c, i)));
        }
        let len = |&(c, i): &(Class, usize)| {
            self.queues
                .get(c.index())
                .and_then(|q| q.get(i))
                .map_or(usize::MAX, |e| e.msg.pdu.len())
        };
        let dst_of = |&(c, i): &(Class, usize)| {
            self.queues
                .get(c.index())
                .and_then(|q| q.get(i))
                .map(|e| e.msg.dst)
        };
        // The head is the first message that fits the time left in the slot: one that does
        // not fit cannot go before the next slot anyway, so a smaller one may use the rest.
        let head = *candidates.iter().find(|c| len(c) <= budget)?;
        let dst = dst_of(&head)?;
        let emergency = head.0 == Class::Emergency;
        let fillers: Vec<(Class, usize)> = candidates
            .iter()
            .copied()
            .filter(|c| *c != head && dst_of(c) == Some(dst))
            .filter(|c| !emergency || c.0 <= Class::Control)
            .collect();
        // Class by class, so a less urgent PDU never takes the place of a more urgent one;
        // within a class, the combination that fills the most.
        let mut chosen = vec![head];
        let mut room = budget.saturating_sub(len(&head));
        for &class in &order {
            let mine: Vec<(Class, usize)> =
                fillers.iter().copied().filter(|c| c.0 == class).collect();
            let sizes: Vec<usize> = mine.iter().map(len).collect();
            for k in pack(&sizes, room) {
                if let (Some(c), Some(size)) = (mine.get(k), sizes.get(k)) {
                    chosen.push(*c);
                    room -= size;
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
        if let Some(air) = self.air_time(data.len()) {
            self.busy_until = now.max(self.busy_until) + air;
        }
        Some(FramePlan {
            frame: OutFrame {
                dst,
                data,
                ack,
                burst: false,
            },
            ids: entries.iter().map(|e| e.id).collect(),
            entries,
            busy_before,
            last_sent_before,
        })
    }

    /// When the own TDMA slot next opens after the current one (`None` without TDMA):
    /// where a node whose queued messages fit no budget left in this slot waits.
    pub fn next_slot(&self, now: Instant) -> Option<Instant> {
        self.tdma_at(now).map(|p| p.next_open)
    }

    /// Where `t` (or the end of the frame on air, if later) falls in the TDMA cycle.
    fn tdma_at(&self, t: Instant) -> Option<SlotPosition> {
        let Mac::Tdma {
            slot,
            slots,
            own_slot,
            advance,
            ..
        } = self.cfg.mac
        else {
            return None;
        };
        let start = t.max(self.busy_until);
        let slot_s = slot.as_secs_f64().max(1e-6);
        let cycle = slot_s * f64::from(slots.max(1));
        // Slots are planned where frames arrive: a frame started now gets there `advance`
        // later.
        let in_cycle = ((start + advance)
            .saturating_duration_since(self.epoch)
            .as_secs_f64())
        .rem_euclid(cycle);
        let own_start = slot_s * f64::from(own_slot % slots.max(1));
        let wait = (own_start - in_cycle).rem_euclid(cycle);
        // At (or inside) the own slot, the next opening is a whole cycle on.
        let wait = if wait <= 0.0 { cycle } else { wait };
        let inside = in_cycle >= own_start && in_cycle < own_start + slot_s;
        Some(SlotPosition {
            left_s: if inside {
                own_start + slot_s - in_cycle
            } else {
                0.0
            },
            next_open: start + Duration::from_secs_f64(wait),
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

    /// Whether an emergency waits behind `in_flight`, a frame without one that the driver
    /// holds until the modem is free: the link then withdraws it, so the alarm goes in the
    /// next frame instead of after it (docs/acoustic.md#channel-use-and-emergency-latency).
    pub fn emergency_waits_behind(&self, in_flight: &FramePlan, now: Instant) -> bool {
        !in_flight.has_emergency() && self.eligible(Class::Emergency, now)
    }

    /// Puts the messages of a withdrawn frame (never on air) back where they were, as if it
    /// had not been planned: same attempts, same place, slot time and priority restored.
    /// One superseded meanwhile by a newer state is dropped, as `push` would have.
    fn requeue(&mut self, plan: FramePlan) -> Vec<LinkEvent> {
        let mut events = Vec::new();
        self.busy_until = plan.busy_before;
        self.last_sent = plan.last_sent_before;
        // In queue order (by age, then by id: ids grow as messages are queued), pushed to
        // the front in reverse, so each class's queue is as it was before the frame.
        let mut entries = plan.entries;
        entries.sort_by_key(|e| (e.enqueued, e.id));
        for e in entries.into_iter().rev() {
            let Some(q) = self.queues.get_mut(e.msg.class.index()) else {
                events.push(LinkEvent::Dropped(e.id));
                continue;
            };
            let superseded = e.msg.supersede_key.is_some_and(|key| {
                q.iter()
                    .any(|n| n.msg.supersede_key == Some(key) && n.msg.dst == e.msg.dst)
            });
            if superseded {
                events.push(LinkEvent::Dropped(e.id));
            } else {
                q.push_front(e);
            }
        }
        events
    }

    /// Applies a frame's outcome: done, back in the queue with backoff, or (withdrawn)
    /// back in the queue as it was.
    pub fn on_outcome(
        &mut self,
        plan: FramePlan,
        outcome: &Result<Outcome, TransmitError>,
        now: Instant,
    ) -> Vec<LinkEvent> {
        if let Err(TransmitError::Withdrawn { .. }) = outcome {
            return self.requeue(plan);
        }
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

/// Candidates [`pack`] weighs at most: enough for any 64-byte frame of PDUs of 1 byte or
/// more, and a bound on its work (candidates × capacity steps).
const PACK_CANDIDATES: usize = 64;

/// Which of `sizes` (in sending order) fill `capacity` bytes best: the most bytes, and
/// among equally full choices the one that leans on the earliest candidates. Returns their
/// indices in order.
///
/// First-fit in sending order leaves the last bytes of a frame empty whenever no single
/// remaining PDU fits them (e.g. 6 bytes of 10-byte deltas); choosing the subset fills them
/// when some combination does. It is a subset sum over at most 64 × 64 states.
fn pack(sizes: &[usize], capacity: usize) -> Vec<usize> {
    let sizes = &sizes[..sizes.len().min(PACK_CANDIDATES)];
    let n = sizes.len();
    // reach[k][s]: whether the candidates from k on can make exactly s bytes.
    let mut reach = vec![vec![false; capacity + 1]; n + 1];
    reach[n][0] = true;
    for k in (0..n).rev() {
        for s in 0..=capacity {
            let take = s
                .checked_sub(sizes[k])
                .is_some_and(|rest| reach[k + 1][rest]);
            reach[k][s] = reach[k + 1][s] || take;
        }
    }
    let Some(mut want) = (0..=capacity).rev().find(|&s| reach[0][s]) else {
        return Vec::new();
    };
    // Walk forward taking each candidate whenever the rest can still make up the total:
    // earlier candidates win over later ones of the same size.
    let mut out = Vec::new();
    for (k, &size) in sizes.iter().enumerate() {
        if let Some(rest) = want.checked_sub(size)
            && reach[k + 1][rest]
        {
            out.push(k);
            want = rest;
        }
    }
    out
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

/// The frame handed to the driver, until its outcome is known.
struct InFlight<'a> {
    plan: FramePlan,
    fut: TxFuture<'a>,
    /// Takes the frame back while the modem has not taken it (for an emergency).
    withdrawal: Withdrawal,
}

async fn poll_opt(f: &mut Option<InFlight<'_>>) -> Result<Outcome, TransmitError> {
    match f {
        Some(f) => f.fut.as_mut().await,
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
    let since_unix = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap_or_default();
    let epoch = cfg.mac.tdma_epoch(since_unix, now).unwrap_or(now);
    let mut core = LinkCore::new(cfg, epoch);
    let mut in_flight: Option<InFlight<'_>> = None;
    let mut cmds_open = true;
    loop {
        let now = Instant::now();
        emit(&events, core.expire(now)).await;
        let mut mac_wait = None;
        if in_flight.is_none() {
            match core.mac_ready(now) {
                Ok(()) => {
                    let plan = core.next_frame(now);
                    if plan.is_none() && core.queued() > 0 {
                        // Nothing fits what is left of the own slot: wait for the next.
                        mac_wait = core.next_slot(now);
                    }
                    if let Some(plan) = plan {
                        debug!(
                            dst = plan.frame.dst,
                            bytes = plan.frame.data.len(),
                            n = plan.ids.len(),
                            "frame out"
                        );
                        let withdrawal = Withdrawal::new();
                        let fut: TxFuture<'_> = Box::pin(
                            driver.transmit_withdrawable(plan.frame.clone(), withdrawal.clone()),
                        );
                        in_flight = Some(InFlight {
                            plan,
                            fut,
                            withdrawal,
                        });
                    }
                }
                Err(next) if core.queued() > 0 => mac_wait = Some(next),
                Err(_) => {}
            }
        } else if let Some(f) = &in_flight
            && !f.withdrawal.is_requested()
            && core.emergency_waits_behind(&f.plan, now)
        {
            // The driver takes the next frame a little before the modem is free; if the
            // modem has not taken it yet, take it back so the alarm goes first. Its
            // messages come back to the queues (or it was already on air and completes).
            debug!(ids = ?f.plan.ids, "withdrawing a frame for an emergency");
            f.withdrawal.request();
        }
        let wake = match (core.next_wakeup(now), mac_wait) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        };
        tokio::select! {
            r = poll_opt(&mut in_flight) => {
                if let Some(f) = in_flight.take() {
                    if matches!(r, Err(TransmitError::Withdrawn { .. })) {
                        debug!(ids = ?f.plan.ids, "frame withdrawn; its messages are queued again");
                    }
                    let evs = core.on_outcome(f.plan, &r, Instant::now());
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

    /// Slots are whole nanoseconds counted from 1970: at today's clock, reckoning them in
    /// floating seconds lands far from where the links are (a benchmark did, and counted
    /// 0.73 s of the wait for a slot as time after it opened).
    #[test]
    fn own_slot_at_reckons_as_a_running_link_at_todays_clock() {
        // A slot that is no whole number of nanoseconds in floating seconds (the fleet
        // benchmark's at 0.25x wall time), four per cycle, own slot 2, with an advance.
        let mac = Mac::tdma(
            Duration::from_secs_f64(0.321_295_081_967_213_1),
            4,
            2,
            Duration::from_millis(8),
        )
        .with_advance(Duration::from_millis(100));
        let cycle = Duration::from_nanos(4 * 321_295_082);
        // 2026-11-27T00:00:00Z.
        let day = Duration::from_secs(1_795_737_600);
        let t0 = Instant::now();
        let core = LinkCore::new(
            LinkConfig {
                mac,
                ..LinkConfig::default()
            },
            mac.tdma_epoch(day, t0).unwrap(),
        );
        let mut float_off = 0.0f64;
        for step in 0..300u32 {
            let dt = Duration::from_millis(11) * step;
            let own = mac.own_slot_at(day + dt, t0 + dt).unwrap();
            let in_slot = own.left > Duration::ZERO;
            assert_eq!(in_slot, core.tdma_at(t0 + dt).unwrap().left_s > 0.0);
            if let Err(next) = core.mac_ready(t0 + dt) {
                let d = next.max(own.next_open) - next.min(own.next_open);
                assert!(d < Duration::from_micros(1), "step {step}: {d:?}");
            }
            // What floating seconds of the configured slot make of the same instant.
            let float_phase = (day + dt)
                .as_secs_f64()
                .rem_euclid(4.0 * 0.321_295_081_967_213_1);
            let int_phase = ((day + dt).as_nanos() % cycle.as_nanos()) as f64 * 1e-9;
            float_off = float_off.max((float_phase - int_phase).abs());
        }
        assert!(
            float_off > 0.1,
            "floating seconds would be {float_off} s off"
        );
    }

    #[test]
    fn tdma_only_starts_frames_in_the_own_slot() {
        let t0 = Instant::now();
        let mac = Mac::tdma(Duration::from_secs(10), 3, 1, Duration::from_secs(2));
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

    /// A TDMA link owning slot `own` of four `slot_ms` slots with a 0.1 s guard.
    fn tdma_core(slot_ms: u64, own: u32, t0: Instant) -> LinkCore {
        let mac = Mac::tdma(
            Duration::from_millis(slot_ms),
            4,
            own,
            Duration::from_millis(100),
        );
        LinkCore::new(
            LinkConfig {
                mac,
                ..saturating()
            },
            t0,
        )
    }

    /// Telemetry that never runs out or expires during a test.
    fn saturating() -> LinkConfig {
        let mut cfg = LinkConfig::default();
        cfg.telemetry.max_len = 10_000;
        cfg
    }

    #[test]
    fn pack_fills_the_bytes_first_fit_leaves_empty() {
        // First fit takes 20 + 20 + 20 and leaves 4 bytes no 8-byte PDU fits.
        let sizes = [20, 20, 20, 8, 8, 8];
        let got = pack(&sizes, 64);
        let total: usize = got.iter().map(|&k| sizes[k]).sum();
        assert_eq!(total, 64);
        assert_eq!(got, vec![0, 1, 3, 4, 5]);
        // Among equally full choices, the earliest candidates win.
        assert_eq!(pack(&[5, 5, 5], 10), vec![0, 1]);
        assert!(pack(&[65], 64).is_empty());
        assert!(pack(&[], 64).is_empty());
    }

    #[test]
    fn a_frame_of_mixed_pdus_is_filled_to_the_last_byte() {
        let t0 = Instant::now();
        let mut core = LinkCore::new(saturating(), t0);
        for (i, len) in [20, 20, 20, 8, 8, 8].into_iter().enumerate() {
            core.push(msg(Class::Telemetry, u8::try_from(i).unwrap(), len), t0);
        }
        let plan = core.next_frame(t0).unwrap();
        assert_eq!(plan.frame.data.len(), 64);
        assert_eq!(core.queued(), 1);
    }

    #[test]
    fn tdma_frames_shrink_to_the_time_left_in_the_own_slot() {
        let t0 = Instant::now();
        // Slot 1 of four 1.5 s slots: [1.5 s, 3 s), frames off air by 2.9 s.
        let mut core = tdma_core(1500, 1, t0);
        for i in 0..200 {
            core.push(msg(Class::Telemetry, i, 4), t0);
        }
        let open = t0 + Duration::from_millis(1500);
        assert!(core.next_frame(t0 + Duration::from_millis(200)).is_none());
        let mut sizes = Vec::new();
        let mut end = open;
        while let Some(plan) = core.next_frame(open) {
            end += core.air_time(plan.frame.data.len()).unwrap();
            sizes.push(plan.frame.data.len());
        }
        // Two full frames (0.62 s each), then one sized to the 51 ms left before the guard.
        assert_eq!(sizes, vec![64, 64, 4]);
        assert!(end <= t0 + Duration::from_millis(2900), "{:?}", end - t0);
        // The next frame waits for the next cycle's slot.
        let next = open + Duration::from_secs(6);
        let near = |t: Instant| t.max(next) - t.min(next) < Duration::from_micros(1);
        assert!(core.mac_ready(open).is_err_and(near));
        assert!(core.next_slot(open).is_some_and(near));
    }

    #[test]
    fn an_emergency_goes_alone_in_the_next_frame_the_node_owns() {
        let t0 = Instant::now();
        let mut core = tdma_core(2000, 2, t0);
        for i in 0..50 {
            core.push(msg(Class::Telemetry, i, 6), t0);
        }
        // Queued in another node's slot: nothing may start until slot 2 opens at 4 s.
        let (e, _) = core.push(
            msg(Class::Emergency, 0xee, 5),
            t0 + Duration::from_millis(500),
        );
        let before = t0 + Duration::from_secs(1);
        assert_eq!(core.mac_ready(before), Err(t0 + Duration::from_secs(4)));
        assert!(core.next_frame(before).is_none());
        let open = t0 + Duration::from_secs(4);
        let first = core.next_frame(open).unwrap();
        assert_eq!(first.ids, vec![e]);
        assert_eq!(first.frame.data.len(), 5, "no telemetry filler");
        assert!(first.frame.ack);
        // The rest of the slot carries telemetry.
        let second = core.next_frame(open).unwrap();
        assert_eq!(second.frame.data.len(), 60);
    }

    #[test]
    fn an_emergency_queued_inside_the_own_slot_waits_only_for_the_frame_on_air() {
        let t0 = Instant::now();
        let mut core = tdma_core(3000, 0, t0);
        for i in 0..50 {
            core.push(msg(Class::Telemetry, i, 8), t0);
        }
        let on_air = core.next_frame(t0).unwrap();
        let air = core.air_time(on_air.frame.data.len()).unwrap();
        // The driver hands the frame back a little before it ends; an alarm queued then
        // goes next, and starts when the telemetry frame is off air.
        let handover = t0 + air - Duration::from_millis(20);
        let (e, _) = core.push(msg(Class::Emergency, 0xee, 5), handover);
        let next = core.next_frame(handover).unwrap();
        assert_eq!(next.ids, vec![e]);
        assert!(air <= core.air_time(MAX_FRAME).unwrap());
    }

    /// A frame the driver hands back unsent (withdrawn for an alarm) puts its messages back
    /// as they were: nothing lost, nothing repeated, no attempt counted, the slot time it
    /// had reserved free again for the alarm.
    #[test]
    fn a_withdrawn_frame_gives_its_messages_back_and_its_slot_time_to_the_alarm() {
        let t0 = Instant::now();
        let mut core = tdma_core(3000, 0, t0);
        let mut ids = Vec::new();
        for i in 0..12 {
            ids.push(core.push(msg(Class::Telemetry, i, 10), t0).0);
        }
        let on_air = core.next_frame(t0).unwrap();
        let held = core.next_frame(t0).unwrap();
        let busy = core.busy_until;
        let (e, _) = core.push(msg(Class::Emergency, 0xee, 5), t0);
        assert!(core.emergency_waits_behind(&held, t0));
        let frame = held.frame.clone();
        let held_ids = held.ids.clone();
        let ev = core.on_outcome(held, &Err(TransmitError::Withdrawn { frame }), t0);
        assert!(ev.is_empty(), "{ev:?}");
        assert!(core.busy_until < busy);
        assert_eq!(core.busy_until, t0 + core.air_time(60).unwrap());
        let alarm = core.next_frame(t0).unwrap();
        assert_eq!(alarm.ids, vec![e]);
        assert!(alarm.has_emergency());
        // The withdrawn messages go next, in the same frame as before.
        let again = core.next_frame(t0).unwrap();
        assert_eq!(again.ids, held_ids);
        let mut sent: Vec<MessageId> = on_air.ids;
        sent.extend(&again.ids);
        sent.sort_unstable();
        assert_eq!(sent, ids);
        assert_eq!(core.queued(), 0);
    }

    #[test]
    fn a_pdu_too_long_for_the_rest_of_the_slot_lets_a_shorter_one_go() {
        let t0 = Instant::now();
        let mut core = tdma_core(1500, 0, t0);
        for i in 0..3 {
            core.push(msg(Class::Telemetry, i, 64), t0);
        }
        let (small, _) = core.push(msg(Class::Bulk, 1, 4), t0);
        let a = core.next_frame(t0).unwrap();
        let b = core.next_frame(t0).unwrap();
        assert_eq!((a.frame.data.len(), b.frame.data.len()), (64, 64));
        // 51 ms are left: the 4-byte bulk PDU fits, telemetry does not.
        let c = core.next_frame(t0).unwrap();
        assert_eq!(c.ids, vec![small]);
        assert!(core.next_frame(t0).is_none());
        assert_eq!(core.queued(), 1);
    }

    proptest::proptest! {
        /// Packing never overfills a frame or the slot, and loses or repeats no message.
        #[test]
        fn frames_respect_the_budget_and_keep_every_message(
            lens in proptest::collection::vec(1usize..=64, 1..80),
            slot_ms in 200u64..5000,
            offset_ms in 0u64..20_000,
        ) {
            let t0 = Instant::now();
            let mut core = tdma_core(slot_ms, 1, t0);
            let mut ids = std::collections::BTreeSet::new();
            for (i, len) in lens.iter().enumerate() {
                let class = Class::ALL[i % 4];
                let (id, displaced) = core.push(msg(class, 0, *len), t0);
                ids.insert(id);
                // A full queue drops its oldest message.
                for e in displaced {
                    if let LinkEvent::Dropped(old) = e {
                        ids.remove(&old);
                    }
                }
            }
            let now = t0 + Duration::from_millis(offset_ms);
            let mut sent = std::collections::BTreeSet::new();
            for _ in 0..lens.len() {
                let Ok(budget) = core.frame_budget(now) else { break };
                let Some(plan) = core.next_frame(now) else { break };
                proptest::prop_assert!(plan.frame.data.len() <= budget.min(MAX_FRAME));
                for id in plan.ids {
                    proptest::prop_assert!(sent.insert(id), "sent twice");
                }
            }
            proptest::prop_assert_eq!(sent.len() + core.queued(), ids.len());
            proptest::prop_assert!(sent.is_subset(&ids));
        }
    }
}
