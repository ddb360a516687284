//! Multi-hop relays (docs/acoustic.md#multi-hop-relays): a vehicle's modem forwards frames
//! for a node out of the other end's range (AUV → AUV → USV → station).
//!
//! - [`Envelope`]: the relay header (version 1, message id [`ENVELOPE_ID`]): origin, final
//!   destination, hops taken, hops left, an ack flag and the origin's message number, in
//!   front of the origin's frame, which travels **untouched**.
//! - [`RelayCore`]: the decisions, without I/O: the route to a destination (configured,
//!   or learned from what the modem hears), duplicate suppression in a bounded cache, TTL
//!   per hop, and refusal of malformed envelopes, forged routes and loops, each counted in
//!   [`RelayStats`].
//! - [`RelayDriver`]: a [`ModemDriver`] that wraps the modem's driver with a core: frames
//!   for a destination reached through a relay leave enveloped; envelopes for this node
//!   come up as if the origin had sent them directly; others are forwarded, acknowledged
//!   and retried hop by hop.
//!
//! Security has two layers. End to end: the relay layer sits **under**
//! [`crate::secure::TaggedDriver`], so the origin seals its frame for the final
//! destination (the tag covers origin, final destination, counter and frame), relays
//! forward the sealed bytes without a key for them, and the final receiver checks the tag
//! and its replay window against the origin: a relay can drop or delay a frame, never
//! forge or alter what it carries, nor its origin or destination. Hop by hop, when the
//! driver has link keys ([`RelayDriver::start_keyed`], [`RelayCore::with_hop_keys`]):
//! every envelope on air is sealed by the node sending it for the node it is sent to
//! (counter + truncated HMAC in [`AcousticTagger::for_relay_hops`]'s own domain), and an
//! envelope whose hop seal fails (forged, altered header, replayed, or from a node without
//! a link key) is refused and counted (`unauthenticated`) before anything is learned or
//! forwarded. Then only keyed neighbours can put a route, a hop count or a TTL on the
//! channel, and plain frames, whose tags only the final receiver above can check, teach no
//! route.

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use serde::{Deserialize, Serialize};
use tokio::sync::mpsc;
use tokio::task::JoinSet;
use tokio::time::Instant;
use tracing::{debug, warn};

use shoal_security::AcousticTagger;

use crate::at::BROADCAST;
use crate::driver::{
    ModemDriver, OutFrame, Outcome, RxFrame, TransmitError, Withdrawal, transmit_wrapped,
};
use crate::pdu::{BitReader, BitWriter, DecodeError, EncodeError, MAX_FRAME};

/// First byte of an enveloped frame. Outside the compact PDUs' ids (1..=11), so a build
/// without relays refuses an envelope as an unknown message instead of misreading it; a
/// test keeps the PDU codec from ever taking it.
pub const ENVELOPE_ID: u8 = 127;
/// The envelope layout this build writes and reads.
pub const ENVELOPE_VERSION: u8 = 1;
/// Bytes the envelope adds in front of the origin's frame (47 bits, padded).
pub const HEADER_BYTES: usize = 6;
/// Largest origin frame an envelope carries: what is left of an instant message.
pub const MAX_INNER: usize = MAX_FRAME - HEADER_BYTES;
/// Most hops a frame may make: the 3-bit hop fields.
pub const MAX_TTL: u8 = 7;
/// Highest address an envelope can name: 4-bit fields, as the compact PDUs' vehicles.
pub const MAX_RELAY_ADDRESS: u8 = 15;
/// Learned routes kept at most (the oldest goes first).
pub const MAX_ROUTES: usize = 64;

/// The relay header in front of a forwarded frame (docs/acoustic.md#multi-hop-relays).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Envelope {
    /// The node that sealed the inner frame, 1..=15.
    pub origin: u8,
    /// The node it is for, 1..=15.
    pub dst: u8,
    /// Relays it has passed, 0..=7.
    pub hops: u8,
    /// Hops it may still make after the current one, 0..=7.
    pub ttl: u8,
    /// Whether each hop is acknowledged and retried (the origin's link asked for it).
    pub ack: bool,
    /// The origin's number for this frame: with the origin, what duplicate suppression
    /// remembers.
    pub msg_id: u16,
    /// The origin's frame, sealed by the origin when security is on; 1..=58 bytes.
    pub inner: Vec<u8>,
}

impl Envelope {
    /// Whether `frame` is enveloped (its first byte is [`ENVELOPE_ID`]).
    pub fn is_envelope(frame: &[u8]) -> bool {
        frame.first() == Some(&ENVELOPE_ID)
    }

    /// The wire form: header MSB first, zero-padded to a byte, then the inner frame.
    pub fn encode(&self) -> Result<Vec<u8>, EncodeError> {
        let addr_ok = |a: u8| (1..=MAX_RELAY_ADDRESS).contains(&a);
        if !addr_ok(self.origin) || !addr_ok(self.dst) {
            return Err(EncodeError::Inconsistent {
                field: "origin/dst",
                rule: "relay addresses are 1..=15",
            });
        }
        if self.hops > MAX_TTL || self.ttl > MAX_TTL || self.hops + self.ttl > MAX_TTL {
            return Err(EncodeError::Inconsistent {
                field: "hops/ttl",
                rule: "hops + ttl is at most 7",
            });
        }
        if self.inner.is_empty() || self.inner.len() > MAX_INNER {
            return Err(EncodeError::FrameTooLong {
                bytes: self.inner.len() + HEADER_BYTES,
                max: MAX_FRAME,
            });
        }
        let mut w = BitWriter::new();
        w.write(u64::from(ENVELOPE_ID), 8);
        w.write(u64::from(ENVELOPE_VERSION), 2);
        w.write(u64::from(self.origin), 4);
        w.write(u64::from(self.dst), 4);
        w.write(u64::from(self.hops), 3);
        w.write(u64::from(self.ttl), 3);
        w.write(u64::from(self.ack), 1);
        w.write(u64::from(self.msg_id), 16);
        w.write(self.inner.len() as u64 - 1, 6);
        let mut out = w.finish();
        out.extend_from_slice(&self.inner);
        Ok(out)
    }

    /// Reads an enveloped frame; never panics. Trailing zero bytes are a modem's padding
    /// (id 0 is reserved, as between PDUs); anything else after the inner frame is refused.
    pub fn decode(frame: &[u8]) -> Result<Self, DecodeError> {
        let mut r = BitReader::new(frame);
        let id = r.read(8)?;
        if id != u64::from(ENVELOPE_ID) {
            return Err(DecodeError::UnknownMessage {
                id: u8::try_from(id).unwrap_or(0),
            });
        }
        let version = r.read(2)?;
        if version != u64::from(ENVELOPE_VERSION) {
            return Err(DecodeError::InvalidCode {
                field: "relay version",
                code: version,
            });
        }
        // Every field below fits its type: at most 16 bits each.
        let mut small = |bits: u32| -> Result<u8, DecodeError> {
            Ok(u8::try_from(r.read(bits)?).unwrap_or(u8::MAX))
        };
        let origin = small(4)?;
        let dst = small(4)?;
        let hops = small(3)?;
        let ttl = small(3)?;
        let ack = small(1)? == 1;
        let msg_id = u16::try_from(r.read(16)?).unwrap_or(u16::MAX);
        let len = usize::try_from(r.read(6)?).unwrap_or(0) + 1;
        let used = r.align()?;
        if origin == 0 || dst == 0 {
            return Err(DecodeError::Inconsistent {
                rule: "relay address 0",
            });
        }
        if hops + ttl > MAX_TTL {
            return Err(DecodeError::Inconsistent {
                rule: "hops + ttl above 7",
            });
        }
        // The length field reaches 64; what fits a frame behind the header is less, and an
        // envelope the encoder could not have made is refused (found by fuzzing).
        if len > MAX_INNER {
            return Err(DecodeError::Inconsistent {
                rule: "relayed frame longer than a frame holds",
            });
        }
        let rest = frame.get(used..).unwrap_or_default();
        let Some(inner) = rest.get(..len) else {
            return Err(DecodeError::Truncated {
                needed_bits: (used + len) * 8,
                available_bits: frame.len() * 8,
            });
        };
        let tail = rest.get(len..).unwrap_or_default();
        if tail.iter().any(|&b| b != 0) {
            return Err(DecodeError::TrailingBytes(tail.len()));
        }
        Ok(Self {
            origin,
            dst,
            hops,
            ttl,
            ack,
            msg_id,
            inner: inner.to_vec(),
        })
    }
}

/// Why a frame cannot leave through a relay ([`RelayCore::outbound`],
/// [`RelayCore::seal_hop`]).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum RelaySendError {
    /// The frame does not fit an envelope.
    #[error("cannot relay: {0}")]
    Envelope(#[from] EncodeError),
    /// No link key for the next hop (or its counter is used up).
    #[error("cannot seal for relay {relay}: {source}")]
    Seal {
        /// The next hop.
        relay: u8,
        /// Why.
        source: shoal_security::acoustic::SealError,
    },
    /// The envelope and its hop seal exceed an instant message.
    #[error("a relayed frame of {bytes} bytes with its hop seal exceeds a {max}-byte frame")]
    TooLong {
        /// Bytes with the seal.
        bytes: usize,
        /// The frame limit.
        max: usize,
    },
}

/// A configured route: to reach `dst`, hand frames to `via`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Route {
    /// Final destination, 1..=15.
    pub dst: u8,
    /// Next hop, 1..=15, a neighbour in range.
    pub via: u8,
}

/// A relay allowed to carry frames of some origins to this node.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrustedRelay {
    /// The relay's address.
    pub relay: u8,
    /// Origins it may carry.
    pub carries: Vec<u8>,
}

/// Relay settings of one node; durations in simulated seconds (see
/// [`RelayDriver::start`]'s `time_scale`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RelayConfig {
    /// Forward frames for other nodes (this node is a relay). Without it, frames for
    /// others are refused and counted (`not_forwarding`).
    pub forward: bool,
    /// Hops a frame this node originates may make, 1..=7.
    pub ttl: u8,
    /// Configured routes; they take precedence over learned ones.
    pub routes: Vec<Route>,
    /// When not empty, an envelope that has already passed a relay is accepted only from
    /// a relay listed here as carrying its origin; others are forged routes. Empty: routes
    /// are learned from any sender (the end-to-end tag still guards the content).
    pub trusted: Vec<TrustedRelay>,
    /// How long a learned route stays usable without being heard again, seconds.
    pub route_lifetime_s: f64,
    /// Frames remembered for duplicate suppression (bounded; the oldest goes first).
    pub dedup_capacity: usize,
    /// How long a frame is remembered, seconds.
    pub dedup_window_s: f64,
    /// Frames being forwarded at most; more are dropped and counted (`queue_full`).
    pub forward_queue: usize,
    /// Transmissions of a forwarded frame at most (first one included).
    pub forward_attempts: u32,
    /// Wait before the first re-send of a forwarded frame, seconds; doubles per attempt.
    pub backoff_initial_s: f64,
    /// Longest wait between re-sends, seconds.
    pub backoff_max_s: f64,
}

impl Default for RelayConfig {
    fn default() -> Self {
        Self {
            forward: false,
            // AUV → AUV → USV → station is three hops; one spare.
            ttl: 4,
            routes: Vec::new(),
            trusted: Vec::new(),
            route_lifetime_s: 600.0,
            dedup_capacity: 1024,
            // The control TTL (docs/acoustic.md#link-layer): a copy can arrive that late.
            dedup_window_s: 900.0,
            forward_queue: 16,
            forward_attempts: 8,
            backoff_initial_s: 2.0,
            backoff_max_s: 30.0,
        }
    }
}

/// Why a [`RelayConfig`] is unusable.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum RelayConfigError {
    /// A key holds a value outside its range; the message names the key.
    #[error("relay.{key}: {problem}")]
    Invalid {
        /// The key.
        key: &'static str,
        /// What is wrong.
        problem: String,
    },
}

impl RelayConfig {
    /// Checks every key; the error names it.
    pub fn check(&self) -> Result<(), RelayConfigError> {
        let bad = |key, problem: String| Err(RelayConfigError::Invalid { key, problem });
        let addr_ok = |a: u8| (1..=MAX_RELAY_ADDRESS).contains(&a);
        if !(1..=MAX_TTL).contains(&self.ttl) {
            return bad("ttl", format!("must be 1..={MAX_TTL}, not {}", self.ttl));
        }
        let mut dsts = std::collections::HashSet::new();
        for r in &self.routes {
            if !addr_ok(r.dst) || !addr_ok(r.via) || r.dst == r.via {
                return bad(
                    "routes",
                    format!("{r:?}: dst and via must be distinct addresses 1..=15"),
                );
            }
            if !dsts.insert(r.dst) {
                return bad("routes", format!("two routes to {}", r.dst));
            }
        }
        for t in &self.trusted {
            if !addr_ok(t.relay) || !t.carries.iter().copied().all(addr_ok) {
                return bad("trusted", format!("{t:?}: addresses are 1..=15"));
            }
        }
        for (key, v) in [
            ("route_lifetime_s", self.route_lifetime_s),
            ("dedup_window_s", self.dedup_window_s),
            ("backoff_initial_s", self.backoff_initial_s),
            ("backoff_max_s", self.backoff_max_s),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return bad(
                    key,
                    format!("must be a positive number of seconds, not {v}"),
                );
            }
        }
        for (key, v, max) in [
            ("dedup_capacity", self.dedup_capacity, 65_536),
            ("forward_queue", self.forward_queue, 256),
        ] {
            if !(1..=max).contains(&v) {
                return bad(key, format!("must be 1..={max}, not {v}"));
            }
        }
        if !(1..=32).contains(&self.forward_attempts) {
            return bad(
                "forward_attempts",
                format!("must be 1..=32, not {}", self.forward_attempts),
            );
        }
        Ok(())
    }

    /// The wall-clock timing at `time_scale` wall seconds per simulated second.
    fn timing(&self, time_scale: f64) -> Timing {
        let s = |v: f64| Duration::from_secs_f64((v * time_scale).max(0.0));
        Timing {
            route_lifetime: s(self.route_lifetime_s),
            dedup_window: s(self.dedup_window_s),
            backoff_initial: s(self.backoff_initial_s),
            backoff_max: s(self.backoff_max_s),
        }
    }
}

#[derive(Debug, Clone, Copy)]
struct Timing {
    route_lifetime: Duration,
    dedup_window: Duration,
    backoff_initial: Duration,
    backoff_max: Duration,
}

/// What the relay layer did, by outcome; every refusal is counted here.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct RelayStats {
    /// Frames this node sent enveloped through a relay.
    pub originated: u64,
    /// Envelopes for this node passed up.
    pub delivered: u64,
    /// Frames forwarded for others and acknowledged by the next hop (or sent, when the
    /// origin asked for no acknowledgement).
    pub forwarded: u64,
    /// Copies of a frame already handled (a retransmission whose ack was lost).
    pub duplicates: u64,
    /// Frames that came back to a node they had passed, or would be sent back where
    /// they came from.
    pub loops: u64,
    /// Frames for others with no hop left.
    pub ttl_expired: u64,
    /// Envelopes whose route contradicts itself or the trusted relays.
    pub forged_route: u64,
    /// Envelopes that do not decode (truncated, unknown version, junk after them).
    pub malformed: u64,
    /// Envelopes whose hop seal failed, with link keys configured: a bad tag (a forged or
    /// altered header or content), a replayed counter, too short to carry a seal, or sent
    /// by a node this one holds no link key for.
    pub unauthenticated: u64,
    /// Frames for others while this node does not forward.
    pub not_forwarding: u64,
    /// Frames for others dropped because the forwarding queue was full.
    pub queue_full: u64,
    /// Frames for others the next hop never acknowledged within the attempts.
    pub undeliverable: u64,
}

/// Why an incoming envelope was not delivered or forwarded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum Refusal {
    /// Does not decode.
    Malformed,
    /// Its hop seal failed (link keys configured).
    Unauthenticated,
    /// Seen before.
    Duplicate,
    /// Came back, or would go back.
    Loop,
    /// No hop left.
    TtlExpired,
    /// The route contradicts itself or the trusted relays.
    ForgedRoute,
    /// For another node, and this one does not forward.
    NotForwarding,
}

/// What to do with a received frame.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum Inbound {
    /// Pass up, as from `src` (the origin, for an envelope).
    Deliver(RxFrame),
    /// Send on to the next hop.
    Forward(OutFrame),
    /// Dropped, and counted.
    Refused(Refusal),
}

/// A learned way to a destination.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct LearnedRoute {
    /// The destination.
    pub dst: u8,
    /// The next hop (`dst` itself for a neighbour heard directly).
    pub via: u8,
    /// Hops to `dst` through `via`.
    pub hops: u8,
}

#[derive(Debug, Clone, Copy)]
struct Learned {
    via: u8,
    hops: u8,
    heard: Instant,
}

#[derive(Debug, Clone, Copy)]
struct Seen {
    at: Instant,
    /// Where this node sent it, if it did.
    forwarded_to: Option<u8>,
}

/// Relay decisions without I/O, driven by explicit instants.
#[derive(Debug)]
pub struct RelayCore {
    cfg: RelayConfig,
    timing: Timing,
    learned: BTreeMap<u8, Learned>,
    seen: HashMap<(u8, u16), Seen>,
    seen_order: VecDeque<((u8, u16), Instant)>,
    next_msg_id: u16,
    stats: RelayStats,
    /// Link keys: seals envelopes for the next hop, opens those from the previous one.
    hop: Option<AcousticTagger>,
}

impl RelayCore {
    /// A core for `cfg` (checked) at `time_scale` wall seconds per simulated second;
    /// `first_msg_id` numbers the first frame it originates (take it from the clock, so a
    /// restarted node does not repeat numbers relays still remember).
    pub fn new(
        cfg: RelayConfig,
        time_scale: f64,
        first_msg_id: u16,
    ) -> Result<Self, RelayConfigError> {
        cfg.check()?;
        if !(time_scale.is_finite() && time_scale > 0.0) {
            return Err(RelayConfigError::Invalid {
                key: "time_scale",
                problem: format!("must be > 0, not {time_scale}"),
            });
        }
        Ok(Self {
            timing: cfg.timing(time_scale),
            cfg,
            learned: BTreeMap::new(),
            seen: HashMap::new(),
            seen_order: VecDeque::new(),
            next_msg_id: first_msg_id,
            stats: RelayStats::default(),
            hop: None,
        })
    }

    /// Seals every envelope this node puts on air for the node it goes to, and refuses
    /// envelopes whose seal does not open, with `tagger`'s link keys (one per neighbour,
    /// looked up by its address; make it with [`AcousticTagger::for_relay_hops`]).
    #[must_use]
    pub fn with_hop_keys(mut self, tagger: AcousticTagger) -> Self {
        self.hop = Some(tagger);
        self
    }

    /// Bytes relaying adds to a frame: the envelope header, and the hop seal when link keys
    /// are configured. A frame sent through a relay carries at most
    /// `MAX_FRAME - overhead()` bytes of the origin's (sealed) frame.
    pub fn overhead(&self) -> usize {
        HEADER_BYTES + self.hop.as_ref().map_or(0, AcousticTagger::overhead)
    }

    /// The envelope `frame` ready for the air: sealed for its next hop `frame.dst` when
    /// link keys are configured (a fresh counter each time, so a retransmission is not a
    /// replay), unchanged otherwise.
    pub fn seal_hop(&mut self, frame: &OutFrame) -> Result<OutFrame, RelaySendError> {
        let Some(t) = self.hop.as_mut() else {
            return Ok(frame.clone());
        };
        let data = t
            .seal(frame.dst, &frame.data)
            .map_err(|source| RelaySendError::Seal {
                relay: frame.dst,
                source,
            })?;
        if data.len() > MAX_FRAME {
            return Err(RelaySendError::TooLong {
                bytes: data.len(),
                max: MAX_FRAME,
            });
        }
        Ok(OutFrame {
            data,
            ..frame.clone()
        })
    }

    /// The counters so far.
    pub fn stats(&self) -> &RelayStats {
        &self.stats
    }

    /// Learned routes still usable at `now`, by destination.
    pub fn learned_routes(&self, now: Instant) -> Vec<LearnedRoute> {
        self.learned
            .iter()
            .filter(|(_, l)| now.saturating_duration_since(l.heard) <= self.timing.route_lifetime)
            .map(|(&dst, l)| LearnedRoute {
                dst,
                via: l.via,
                hops: l.hops,
            })
            .collect()
    }

    /// The next hop towards `dst`: a configured route, else a neighbour heard directly,
    /// else a learned route, else `dst` itself (try directly).
    pub fn next_hop(&self, dst: u8, now: Instant) -> u8 {
        if let Some(r) = self.cfg.routes.iter().find(|r| r.dst == dst) {
            return r.via;
        }
        match self.learned.get(&dst) {
            Some(l) if now.saturating_duration_since(l.heard) <= self.timing.route_lifetime => {
                l.via
            }
            _ => dst,
        }
    }

    /// Remembers that `dst` is reachable through `via` in `hops` hops. A neighbour heard
    /// directly wins over a relayed way; among relayed ways the shorter, or the one heard
    /// again, wins while it lives.
    fn learn(&mut self, dst: u8, via: u8, hops: u8, now: Instant) {
        let live = self.timing.route_lifetime;
        let replace = match self.learned.get(&dst) {
            None => true,
            Some(old) if now.saturating_duration_since(old.heard) > live => true,
            // A neighbour heard directly is the best way there.
            Some(_) if via == dst => true,
            // Never trade a live direct way for a relayed one.
            Some(old) if old.via == dst => false,
            Some(old) => old.via == via || hops <= old.hops,
        };
        if !replace {
            return;
        }
        if !self.learned.contains_key(&dst) && self.learned.len() >= MAX_ROUTES {
            // Make room: the route heard longest ago goes.
            if let Some(oldest) = self
                .learned
                .iter()
                .min_by_key(|(_, l)| l.heard)
                .map(|(d, _)| *d)
            {
                self.learned.remove(&oldest);
            }
        }
        self.learned.insert(
            dst,
            Learned {
                via,
                hops,
                heard: now,
            },
        );
    }

    /// Whether `(origin, msg_id)` was seen within the window; forgets what is older, and
    /// the oldest beyond the capacity.
    fn seen_before(&mut self, key: (u8, u16), now: Instant) -> Option<Seen> {
        while let Some(&(k, t)) = self.seen_order.front() {
            let old = now.saturating_duration_since(t) > self.timing.dedup_window;
            if !old && self.seen_order.len() < self.cfg.dedup_capacity {
                break;
            }
            if self.seen.get(&k).is_some_and(|s| s.at == t) {
                self.seen.remove(&k);
            }
            self.seen_order.pop_front();
        }
        self.seen.get(&key).copied()
    }

    fn remember(&mut self, key: (u8, u16), forwarded_to: Option<u8>, now: Instant) {
        self.seen.insert(
            key,
            Seen {
                at: now,
                forwarded_to,
            },
        );
        self.seen_order.push_back((key, now));
    }

    /// How a frame for `frame.dst` leaves this node (`local`, once the modem told its
    /// address): unchanged when the next hop is the destination, else enveloped for the
    /// next hop. `Err` names why it cannot be sent through a relay.
    pub fn outbound(
        &mut self,
        frame: &OutFrame,
        local: Option<u8>,
        now: Instant,
    ) -> Result<OutFrame, RelaySendError> {
        let Some(local) = local else {
            return Ok(frame.clone());
        };
        if frame.dst == BROADCAST {
            return Ok(frame.clone());
        }
        let via = self.next_hop(frame.dst, now);
        if via == frame.dst {
            return Ok(frame.clone());
        }
        let msg_id = self.next_msg_id;
        self.next_msg_id = self.next_msg_id.wrapping_add(1);
        let env = Envelope {
            origin: local,
            dst: frame.dst,
            hops: 0,
            ttl: self.cfg.ttl - 1,
            ack: frame.ack,
            msg_id,
            inner: frame.data.clone(),
        };
        let data = env.encode()?;
        let sealed = self.seal_hop(&OutFrame {
            dst: via,
            data,
            ack: frame.ack,
            burst: false,
        })?;
        // A copy that comes back is a loop, not a new frame.
        self.remember((local, msg_id), Some(via), now);
        self.stats.originated += 1;
        Ok(sealed)
    }

    fn refuse(&mut self, r: Refusal) -> Inbound {
        let s = &mut self.stats;
        match r {
            Refusal::Malformed => s.malformed += 1,
            Refusal::Unauthenticated => s.unauthenticated += 1,
            Refusal::Duplicate => s.duplicates += 1,
            Refusal::Loop => s.loops += 1,
            Refusal::TtlExpired => s.ttl_expired += 1,
            Refusal::ForgedRoute => s.forged_route += 1,
            Refusal::NotForwarding => s.not_forwarding += 1,
        }
        Inbound::Refused(r)
    }

    fn trusted(&self, relay: u8, origin: u8) -> bool {
        self.cfg.trusted.is_empty()
            || self
                .cfg
                .trusted
                .iter()
                .any(|t| t.relay == relay && t.carries.contains(&origin))
    }

    /// Decides what becomes of a received frame at this node (`local`, or the frame's
    /// own unicast destination while the modem has not told it). A forwarded envelope
    /// comes back without its hop seal: seal each transmission with [`Self::seal_hop`].
    pub fn inbound(&mut self, f: RxFrame, local: Option<u8>, now: Instant) -> Inbound {
        if !Envelope::is_envelope(&f.data) {
            // The sender is in range: the simplest route there is. With link keys, only
            // what a seal proves teaches a route: a plain frame's tag is for the final
            // receiver above to check, after this.
            if self.hop.is_none() && (1..=MAX_RELAY_ADDRESS).contains(&f.src) {
                self.learn(f.src, f.src, 1, now);
            }
            return Inbound::Deliver(f);
        }
        let me = match local {
            Some(a) => a,
            None if f.dst != BROADCAST => f.dst,
            // Relays are unicast: an envelope to everyone is not one a relay sent.
            None => return self.refuse(Refusal::ForgedRoute),
        };
        if f.dst == BROADCAST {
            return self.refuse(Refusal::ForgedRoute);
        }
        let mut f = f;
        if let Some(t) = self.hop.as_mut() {
            match t.open(f.src, f.dst, &f.data) {
                Ok(content) => f.data = content.to_vec(),
                Err(rejection) => {
                    debug!(src = f.src, reason = %rejection.reason(), "relay hop seal refused");
                    return self.refuse(Refusal::Unauthenticated);
                }
            }
        }
        let env = match Envelope::decode(&f.data) {
            Ok(e) => e,
            Err(e) => {
                debug!(src = f.src, error = %e, "relay envelope refused");
                return self.refuse(Refusal::Malformed);
            }
        };
        if env.origin == env.dst {
            return self.refuse(Refusal::ForgedRoute);
        }
        if env.origin == me {
            // Our own frame came back.
            return self.refuse(Refusal::Loop);
        }
        // The first hop comes from the origin itself, later ones from relays; a relay
        // must be trusted to carry that origin when a list is configured.
        let first_hop = env.hops == 0;
        if first_hop != (f.src == env.origin) || (!first_hop && !self.trusted(f.src, env.origin)) {
            return self.refuse(Refusal::ForgedRoute);
        }
        let key = (env.origin, env.msg_id);
        if let Some(seen) = self.seen_before(key, now) {
            return if seen.forwarded_to == Some(f.src) {
                self.refuse(Refusal::Loop)
            } else {
                self.refuse(Refusal::Duplicate)
            };
        }
        if (1..=MAX_RELAY_ADDRESS).contains(&f.src) {
            self.learn(f.src, f.src, 1, now);
        }
        if env.origin != f.src {
            self.learn(env.origin, f.src, env.hops + 1, now);
        }
        if env.dst == me {
            self.remember(key, None, now);
            self.stats.delivered += 1;
            return Inbound::Deliver(RxFrame {
                src: env.origin,
                dst: me,
                data: env.inner,
                rssi: f.rssi,
                integrity: f.integrity,
            });
        }
        if !self.cfg.forward {
            return self.refuse(Refusal::NotForwarding);
        }
        if env.ttl == 0 {
            self.remember(key, None, now);
            return self.refuse(Refusal::TtlExpired);
        }
        let via = self.next_hop(env.dst, now);
        if via == f.src || via == me {
            return self.refuse(Refusal::Loop);
        }
        let onward = Envelope {
            hops: env.hops + 1,
            ttl: env.ttl - 1,
            ..env
        };
        let Ok(data) = onward.encode() else {
            return self.refuse(Refusal::Malformed);
        };
        self.remember(key, Some(via), now);
        Inbound::Forward(OutFrame {
            dst: via,
            data,
            ack: onward.ack,
            burst: false,
        })
    }

    fn backoff(&self, attempt: u32) -> Duration {
        let f = 2f64.powi(i32::try_from(attempt.min(30)).unwrap_or(30));
        Duration::from_secs_f64(
            (self.timing.backoff_initial.as_secs_f64() * f)
                .min(self.timing.backoff_max.as_secs_f64()),
        )
    }
}

type Shared = Arc<Mutex<RelayCore>>;

fn lock(core: &Shared) -> MutexGuard<'_, RelayCore> {
    // A panic while holding the lock would be a bug; the counters stay usable.
    core.lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// A modem driver that relays: see the [module docs](self).
#[derive(Debug)]
pub struct RelayDriver<D> {
    inner: Arc<D>,
    core: Shared,
    up: tokio::sync::Mutex<mpsc::Receiver<RxFrame>>,
    pump: tokio::task::JoinHandle<()>,
}

impl<D> Drop for RelayDriver<D> {
    fn drop(&mut self) {
        // Stops receiving and every forward in progress.
        self.pump.abort();
    }
}

impl<D: ModemDriver + 'static> RelayDriver<D> {
    /// Wraps `inner` with relay settings `cfg` (durations in simulated seconds, at
    /// `time_scale` wall seconds per simulated one). Must be called inside a tokio runtime.
    pub fn start(inner: D, cfg: RelayConfig, time_scale: f64) -> Result<Self, RelayConfigError> {
        Self::start_with(inner, cfg, time_scale, None)
    }

    /// [`Self::start`] with link keys for the hop-by-hop seal (`hop`, made with
    /// [`AcousticTagger::for_relay_hops`], a key for every neighbour envelopes may come
    /// from or go to): envelopes leave sealed for their next hop, and envelopes whose seal
    /// fails are refused and counted (`unauthenticated`). The origin's link must then fill
    /// frames to `MAX_FRAME` less [`Self::overhead`] (and the end-to-end tag).
    pub fn start_keyed(
        inner: D,
        cfg: RelayConfig,
        time_scale: f64,
        hop: AcousticTagger,
    ) -> Result<Self, RelayConfigError> {
        Self::start_with(inner, cfg, time_scale, Some(hop))
    }

    fn start_with(
        inner: D,
        cfg: RelayConfig,
        time_scale: f64,
        hop: Option<AcousticTagger>,
    ) -> Result<Self, RelayConfigError> {
        let first_msg_id = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| (d.as_millis() / 100) as u16)
            .unwrap_or(0);
        let queue = cfg.forward_queue;
        let attempts = cfg.forward_attempts;
        let mut core = RelayCore::new(cfg, time_scale, first_msg_id)?;
        if let Some(t) = hop {
            core = core.with_hop_keys(t);
        }
        let core: Shared = Arc::new(Mutex::new(core));
        let inner = Arc::new(inner);
        let (tx, rx) = mpsc::channel(256);
        let pump = tokio::spawn(pump(inner.clone(), core.clone(), tx, queue, attempts));
        Ok(Self {
            inner,
            core,
            up: tokio::sync::Mutex::new(rx),
            pump,
        })
    }

    /// The counters so far.
    pub fn stats(&self) -> RelayStats {
        lock(&self.core).stats().clone()
    }

    /// Bytes relaying adds to a frame sent through a relay ([`RelayCore::overhead`]).
    pub fn overhead(&self) -> usize {
        lock(&self.core).overhead()
    }

    /// A handle on the counters that stays readable after the driver moved into a link.
    pub fn stats_handle(&self) -> RelayStatsHandle {
        RelayStatsHandle(self.core.clone())
    }
}

/// Reads a [`RelayDriver`]'s counters and routes from elsewhere.
#[derive(Debug, Clone)]
pub struct RelayStatsHandle(Shared);

impl RelayStatsHandle {
    /// The counters so far.
    pub fn stats(&self) -> RelayStats {
        lock(&self.0).stats().clone()
    }

    /// Learned routes usable now.
    pub fn learned_routes(&self) -> Vec<LearnedRoute> {
        lock(&self.0).learned_routes(Instant::now())
    }
}

/// Receives from the modem: passes frames for this node up, forwards the others.
async fn pump<D: ModemDriver + 'static>(
    inner: Arc<D>,
    core: Shared,
    up: mpsc::Sender<RxFrame>,
    queue: usize,
    attempts: u32,
) {
    let mut forwards = JoinSet::new();
    loop {
        tokio::select! {
            f = inner.receive() => {
                let Some(f) = f else { break };
                let decision = lock(&core).inbound(f, inner.local_address(), Instant::now());
                match decision {
                    Inbound::Deliver(f) => {
                        if up.send(f).await.is_err() {
                            break;
                        }
                    }
                    Inbound::Forward(out) => {
                        if forwards.len() >= queue {
                            lock(&core).stats.queue_full += 1;
                            warn!(dst = out.dst, "relay queue full; frame for another node dropped");
                        } else {
                            forwards.spawn(forward(inner.clone(), core.clone(), out, attempts));
                        }
                    }
                    Inbound::Refused(r) => debug!(reason = ?r, "frame not relayed"),
                }
            }
            Some(_) = forwards.join_next(), if !forwards.is_empty() => {}
        }
    }
}

/// Sends a frame on to its next hop, retrying with backoff until acknowledged.
async fn forward<D: ModemDriver>(inner: Arc<D>, core: Shared, out: OutFrame, attempts: u32) {
    for attempt in 0..attempts {
        // Sealed again for every attempt: a fresh counter, so the next hop takes a
        // retransmission for the duplicate it is, not for a replay.
        let sealed = lock(&core).seal_hop(&out);
        let sealed = match sealed {
            Ok(f) => f,
            Err(reason) => {
                warn!(dst = out.dst, %reason, "relayed frame not sealed");
                break;
            }
        };
        match inner.transmit(sealed).await {
            Ok(Outcome::Delivered) => {
                lock(&core).stats.forwarded += 1;
                return;
            }
            Ok(Outcome::Sent) if !out.ack => {
                lock(&core).stats.forwarded += 1;
                return;
            }
            Err(TransmitError::Rejected { reason, .. }) => {
                warn!(dst = out.dst, %reason, "modem refused a relayed frame");
                break;
            }
            Err(_) => return,
            Ok(_) => {
                let wait = lock(&core).backoff(attempt);
                tokio::time::sleep(wait).await;
            }
        }
    }
    lock(&core).stats.undeliverable += 1;
}

impl<D: ModemDriver + 'static> RelayDriver<D> {
    /// Envelopes `frame` and hands it to the inner driver, withdrawably when `withdrawal`
    /// is given.
    async fn send(
        &self,
        frame: OutFrame,
        withdrawal: Option<Withdrawal>,
    ) -> Result<Outcome, TransmitError> {
        let planned = lock(&self.core).outbound(&frame, self.inner.local_address(), Instant::now());
        let out = match planned {
            Ok(out) => out,
            Err(e) => {
                return Err(TransmitError::Rejected {
                    frame,
                    reason: e.to_string(),
                });
            }
        };
        // On failure (or withdrawal) hand back the caller's frame, not the envelope: a retry
        // is planned (and numbered) again.
        transmit_wrapped(&*self.inner, out, withdrawal, frame).await
    }
}

impl<D: ModemDriver + 'static> ModemDriver for RelayDriver<D> {
    async fn transmit(&self, frame: OutFrame) -> Result<Outcome, TransmitError> {
        self.send(frame, None).await
    }

    async fn transmit_withdrawable(
        &self,
        frame: OutFrame,
        withdrawal: Withdrawal,
    ) -> Result<Outcome, TransmitError> {
        self.send(frame, Some(withdrawal)).await
    }

    async fn receive(&self) -> Option<RxFrame> {
        self.up.lock().await.recv().await
    }

    fn local_address(&self) -> Option<u8> {
        self.inner.local_address()
    }

    fn is_connected(&self) -> bool {
        self.inner.is_connected()
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    const STATION: u8 = 1;
    const NEAR: u8 = 2;
    const FAR: u8 = 3;

    fn env(origin: u8, dst: u8, hops: u8, ttl: u8, msg_id: u16) -> Envelope {
        Envelope {
            origin,
            dst,
            hops,
            ttl,
            ack: true,
            msg_id,
            inner: vec![9, 8, 7, 6],
        }
    }

    fn rx(src: u8, dst: u8, data: Vec<u8>) -> RxFrame {
        RxFrame {
            src,
            dst,
            data,
            rssi: None,
            integrity: None,
        }
    }

    fn core(cfg: RelayConfig) -> RelayCore {
        RelayCore::new(cfg, 1.0, 100).unwrap()
    }

    fn relay() -> RelayCore {
        core(RelayConfig {
            forward: true,
            ..RelayConfig::default()
        })
    }

    fn out(dst: u8) -> OutFrame {
        OutFrame {
            dst,
            data: vec![4, 1, 2],
            ack: true,
            burst: false,
        }
    }

    #[test]
    fn the_envelope_is_not_a_compact_pdu_and_its_header_is_six_bytes() {
        // A PDU id taking 127 would make envelopes ambiguous.
        assert_eq!(
            crate::pdu::decode_prefix(&[ENVELOPE_ID, 0, 0, 0]),
            Err(DecodeError::UnknownMessage { id: ENVELOPE_ID })
        );
        let e = env(FAR, STATION, 2, 5, 0xBEEF);
        let bytes = e.encode().unwrap();
        assert_eq!(bytes.len(), HEADER_BYTES + e.inner.len());
        assert_eq!(Envelope::decode(&bytes).unwrap(), e);
    }

    #[test]
    fn unknown_versions_junk_and_impossible_hop_counts_are_refused() {
        let mut bytes = env(FAR, STATION, 0, 3, 1).encode().unwrap();
        let good = bytes.clone();
        // Version bits are the top two of the second byte.
        bytes[1] = (bytes[1] & 0x3F) | 0x80;
        assert!(matches!(
            Envelope::decode(&bytes),
            Err(DecodeError::InvalidCode {
                field: "relay version",
                code: 2
            })
        ));
        let mut tail = good.clone();
        tail.push(5);
        assert_eq!(Envelope::decode(&tail), Err(DecodeError::TrailingBytes(1)));
        let mut padded = good;
        padded.extend([0, 0]);
        assert!(
            Envelope::decode(&padded).is_ok(),
            "a modem's zero padding is fine"
        );
        assert!(env(FAR, STATION, 4, 4, 1).encode().is_err());
        assert!(env(0, STATION, 0, 1, 1).encode().is_err());
        let long = Envelope {
            inner: vec![1; MAX_INNER + 1],
            ..env(FAR, STATION, 0, 1, 1)
        };
        assert!(matches!(
            long.encode(),
            Err(EncodeError::FrameTooLong { .. })
        ));
        // Nor does one decode: a length field of 63 (64 bytes) with the bytes behind it,
        // the case fuzzing found (decoded, then refused by the encoder).
        let mut wire = vec![0x7f, 0x7e, 0x07, 0x3f, 0x00, 0xfe];
        wire.extend([0xfe; 64]);
        assert!(matches!(
            Envelope::decode(&wire),
            Err(DecodeError::Inconsistent { .. })
        ));
    }

    proptest! {
        #[test]
        fn envelopes_round_trip(
            origin in 1u8..=15, dst in 1u8..=15, hops in 0u8..=7, ttl in 0u8..=7,
            ack: bool, msg_id: u16, inner in proptest::collection::vec(any::<u8>(), 1..=MAX_INNER),
        ) {
            prop_assume!(hops + ttl <= MAX_TTL);
            let e = Envelope { origin, dst, hops, ttl, ack, msg_id, inner };
            let bytes = e.encode().unwrap();
            prop_assert!(bytes.len() <= MAX_FRAME);
            prop_assert_eq!(Envelope::decode(&bytes).unwrap(), e);
        }

        /// Every prefix of an envelope is refused: a truncated frame is never delivered
        /// short.
        #[test]
        fn every_truncation_is_refused(
            inner in proptest::collection::vec(1u8..=255, 1..=MAX_INNER), cut in 0usize..64,
        ) {
            let bytes = Envelope { inner, ..env(FAR, STATION, 0, 3, 7) }.encode().unwrap();
            let cut = cut % bytes.len();
            prop_assert!(Envelope::decode(&bytes[..cut]).is_err());
        }

        /// Arbitrary bytes after the envelope id never panic the core and are counted
        /// when refused.
        #[test]
        fn junk_envelopes_are_counted_never_delivered_wrong(
            junk in proptest::collection::vec(any::<u8>(), 0..70),
        ) {
            let mut c = relay();
            let mut data = vec![ENVELOPE_ID];
            data.extend(junk);
            match c.inbound(rx(FAR, NEAR, data.clone()), Some(NEAR), Instant::now()) {
                Inbound::Refused(_) => {
                    let s = c.stats();
                    let refused = s.malformed + s.forged_route + s.loops + s.duplicates
                        + s.ttl_expired + s.not_forwarding;
                    prop_assert_eq!(refused, 1);
                }
                Inbound::Deliver(f) => {
                    // Only a well-formed envelope for this node comes up, as its origin's.
                    let e = Envelope::decode(&data).unwrap();
                    prop_assert_eq!(f.src, e.origin);
                    prop_assert_eq!(f.data, e.inner);
                }
                Inbound::Forward(f) => {
                    let e = Envelope::decode(&f.data).unwrap();
                    prop_assert!(e.hops >= 1 && e.dst != NEAR);
                }
            }
        }
    }

    #[test]
    fn a_copy_of_a_frame_already_handled_is_suppressed_and_the_cache_is_bounded() {
        let mut c = core(RelayConfig {
            dedup_capacity: 4,
            ..RelayConfig::default()
        });
        let now = Instant::now();
        let first = env(FAR, NEAR, 0, 3, 10).encode().unwrap();
        assert!(matches!(
            c.inbound(rx(FAR, NEAR, first.clone()), Some(NEAR), now),
            Inbound::Deliver(_)
        ));
        // The hop's ack was lost and the origin's modem sent it again.
        assert_eq!(
            c.inbound(rx(FAR, NEAR, first.clone()), Some(NEAR), now),
            Inbound::Refused(Refusal::Duplicate)
        );
        assert_eq!(c.stats().duplicates, 1);
        assert_eq!(c.stats().delivered, 1);
        for id in 11..20 {
            let e = env(FAR, NEAR, 0, 3, id).encode().unwrap();
            c.inbound(rx(FAR, NEAR, e), Some(NEAR), now);
        }
        assert!(
            c.seen.len() <= 4 && c.seen_order.len() <= 5,
            "{}",
            c.seen.len()
        );
        // Forgotten beyond the capacity: a very late copy comes up again, and the link's
        // own duplicate suppression above catches it.
        assert!(matches!(
            c.inbound(rx(FAR, NEAR, first), Some(NEAR), now),
            Inbound::Deliver(_)
        ));
    }

    #[test]
    fn each_hop_spends_one_ttl_and_a_frame_without_one_is_dropped_and_counted() {
        let mut c = relay();
        let now = Instant::now();
        let Inbound::Forward(f) = c.inbound(
            rx(FAR, NEAR, env(FAR, STATION, 0, 2, 1).encode().unwrap()),
            Some(NEAR),
            now,
        ) else {
            panic!("not forwarded");
        };
        assert_eq!(f.dst, STATION);
        let e = Envelope::decode(&f.data).unwrap();
        assert_eq!((e.hops, e.ttl, e.origin, e.dst), (1, 1, FAR, STATION));
        assert_eq!(
            e.inner,
            vec![9, 8, 7, 6],
            "the origin's frame travels untouched"
        );
        assert_eq!(
            c.inbound(
                rx(FAR, NEAR, env(FAR, STATION, 0, 0, 2).encode().unwrap()),
                Some(NEAR),
                now
            ),
            Inbound::Refused(Refusal::TtlExpired)
        );
        assert_eq!(c.stats().ttl_expired, 1);
    }

    #[test]
    fn routes_are_learned_from_what_the_modem_hears_and_configured_ones_win() {
        let mut c = core(RelayConfig {
            route_lifetime_s: 60.0,
            ..RelayConfig::default()
        });
        let t0 = Instant::now();
        assert_eq!(c.next_hop(FAR, t0), FAR, "unknown: try directly");
        // NEAR relays FAR's frame to us (STATION): FAR is behind NEAR, two hops away.
        let e = env(FAR, STATION, 1, 2, 5).encode().unwrap();
        assert!(matches!(
            c.inbound(rx(NEAR, STATION, e), Some(STATION), t0),
            Inbound::Deliver(f) if f.src == FAR
        ));
        assert_eq!(c.next_hop(FAR, t0), NEAR);
        assert_eq!(c.next_hop(NEAR, t0), NEAR);
        let out = c.outbound(&out(FAR), Some(STATION), t0).unwrap();
        assert_eq!(out.dst, NEAR);
        let sent = Envelope::decode(&out.data).unwrap();
        assert_eq!(
            (sent.origin, sent.dst, sent.hops, sent.ttl),
            (STATION, FAR, 0, 3)
        );
        // Heard directly later: the direct way wins, and no relayed way replaces it.
        c.inbound(rx(FAR, STATION, vec![4, 0]), Some(STATION), t0);
        assert_eq!(c.next_hop(FAR, t0), FAR);
        c.inbound(
            rx(NEAR, STATION, env(FAR, STATION, 1, 2, 6).encode().unwrap()),
            Some(STATION),
            t0,
        );
        assert_eq!(c.next_hop(FAR, t0), FAR);
        // Not heard for a route lifetime: forgotten.
        assert_eq!(c.next_hop(FAR, t0 + Duration::from_secs(61)), FAR);
        assert!(c.learned_routes(t0 + Duration::from_secs(61)).is_empty());
        let mut fixed = core(RelayConfig {
            routes: vec![Route {
                dst: STATION,
                via: NEAR,
            }],
            ..RelayConfig::default()
        });
        fixed.inbound(rx(STATION, FAR, vec![4, 0]), Some(FAR), t0);
        assert_eq!(fixed.next_hop(STATION, t0), NEAR, "configured routes win");
    }

    #[test]
    fn a_frame_looping_between_two_relays_is_stopped_and_counted() {
        // Misconfigured: each relay thinks the station is behind the other.
        let cfg = |via| RelayConfig {
            forward: true,
            routes: vec![Route { dst: STATION, via }],
            ..RelayConfig::default()
        };
        let (a, b) = (4, 5);
        let mut ra = core(cfg(b));
        let mut rb = core(cfg(a));
        let now = Instant::now();
        let from_far = env(FAR, STATION, 0, 6, 1).encode().unwrap();
        let Inbound::Forward(f) = ra.inbound(rx(FAR, a, from_far), Some(a), now) else {
            panic!("a forwards");
        };
        assert_eq!(f.dst, b);
        // b would send it straight back to a.
        assert_eq!(
            rb.inbound(rx(a, b, f.data.clone()), Some(b), now),
            Inbound::Refused(Refusal::Loop)
        );
        assert_eq!(rb.stats().loops, 1);
        // Had it come back to a anyway, a knows it sent it to b.
        let back = Envelope {
            hops: 2,
            ttl: 4,
            ..Envelope::decode(&f.data).unwrap()
        };
        assert_eq!(
            ra.inbound(rx(b, a, back.encode().unwrap()), Some(a), now),
            Inbound::Refused(Refusal::Loop)
        );
        // And an origin that hears its own frame again drops it.
        let mine = env(FAR, STATION, 2, 1, 1).encode().unwrap();
        let mut far = core(RelayConfig::default());
        assert_eq!(
            far.inbound(rx(a, FAR, mine), Some(FAR), now),
            Inbound::Refused(Refusal::Loop)
        );
    }

    #[test]
    fn forged_routes_are_refused_and_counted() {
        let now = Instant::now();
        let mut c = core(RelayConfig {
            forward: true,
            trusted: vec![TrustedRelay {
                relay: NEAR,
                carries: vec![FAR],
            }],
            ..RelayConfig::default()
        });
        let check = |c: &mut RelayCore, src: u8, dst: u8, e: Envelope| {
            c.inbound(rx(src, dst, e.encode().unwrap()), Some(STATION), now)
        };
        let forged = Inbound::Refused(Refusal::ForgedRoute);
        // A first hop that does not come from its origin.
        assert_eq!(
            check(&mut c, NEAR, STATION, env(FAR, STATION, 0, 3, 1)),
            forged
        );
        // An origin claiming relays behind it.
        assert_eq!(
            check(&mut c, FAR, STATION, env(FAR, STATION, 2, 1, 2)),
            forged
        );
        // A relay nobody trusted to carry that origin.
        assert_eq!(
            check(&mut c, 9, STATION, env(FAR, STATION, 1, 1, 3)),
            forged
        );
        assert_eq!(
            check(&mut c, NEAR, STATION, env(8, STATION, 1, 1, 4)),
            forged
        );
        // To itself, or to everyone.
        assert_eq!(check(&mut c, FAR, STATION, env(FAR, FAR, 0, 1, 5)), forged);
        assert_eq!(
            check(&mut c, NEAR, BROADCAST, env(FAR, STATION, 1, 1, 6)),
            forged
        );
        assert_eq!(c.stats().forged_route, 6);
        assert!(
            c.learned_routes(now).is_empty(),
            "no route learned from a forgery"
        );
        // The trusted relay carrying the origin it is trusted with gets through.
        assert!(matches!(
            check(&mut c, NEAR, STATION, env(FAR, STATION, 1, 1, 7)),
            Inbound::Deliver(f) if f.src == FAR
        ));
    }

    #[test]
    fn a_node_that_does_not_forward_refuses_frames_for_others() {
        let mut c = core(RelayConfig::default());
        let e = env(FAR, STATION, 0, 3, 1).encode().unwrap();
        assert_eq!(
            c.inbound(rx(FAR, NEAR, e), Some(NEAR), Instant::now()),
            Inbound::Refused(Refusal::NotForwarding)
        );
        assert_eq!(c.stats().not_forwarding, 1);
    }

    #[test]
    fn frames_leave_unchanged_unless_a_relay_is_on_the_way() {
        let mut c = core(RelayConfig {
            routes: vec![Route {
                dst: STATION,
                via: NEAR,
            }],
            ..RelayConfig::default()
        });
        let now = Instant::now();
        assert_eq!(c.outbound(&out(NEAR), Some(FAR), now).unwrap(), out(NEAR));
        assert_eq!(
            c.outbound(&out(BROADCAST), Some(FAR), now).unwrap(),
            out(BROADCAST)
        );
        let via = c.outbound(&out(STATION), Some(FAR), now).unwrap();
        assert_eq!(via.dst, NEAR);
        assert_eq!(
            Envelope::decode(&via.data).unwrap().inner,
            out(STATION).data
        );
        let big = OutFrame {
            data: vec![1; MAX_INNER + 1],
            ..out(STATION)
        };
        assert!(c.outbound(&big, Some(FAR), now).is_err());
        assert_eq!(c.stats().originated, 1);
    }

    #[test]
    fn bad_settings_name_their_key() {
        let bad = |c: RelayConfig| c.check().unwrap_err().to_string();
        assert!(
            bad(RelayConfig {
                ttl: 0,
                ..RelayConfig::default()
            })
            .contains("relay.ttl")
        );
        assert!(
            bad(RelayConfig {
                routes: vec![Route { dst: 2, via: 2 }],
                ..RelayConfig::default()
            })
            .contains("relay.routes")
        );
        assert!(
            bad(RelayConfig {
                dedup_capacity: 0,
                ..RelayConfig::default()
            })
            .contains("relay.dedup_capacity")
        );
        RelayConfig::default().check().unwrap();
    }

    // ---- Hop-by-hop seals (link keys) -------------------------------------------------

    use shoal_security::{AcousticKey, TagSize};

    /// The far end of a three-hop chain: FAR2 → FAR → NEAR → STATION.
    const FAR2: u8 = 4;
    /// A node with a modem but no link key of anyone in the chain.
    const OUTSIDER: u8 = 9;

    /// Link keys of the chain's neighbours, one per pair.
    struct LinkKeys(Vec<((u8, u8), AcousticKey)>);

    impl LinkKeys {
        fn chain() -> Self {
            let pairs = [(FAR2, FAR), (FAR, NEAR), (NEAR, STATION)];
            Self(
                pairs
                    .into_iter()
                    .map(|p| (p, AcousticKey::generate().unwrap()))
                    .collect(),
            )
        }

        /// The hop tagger of `node`: a key for each of its neighbours.
        fn tagger(&self, node: u8) -> AcousticTagger {
            let mut t = AcousticTagger::for_relay_hops(node, TagSize::Bits64, 1);
            for ((a, b), key) in &self.0 {
                if *a == node {
                    t.set_key(*b, key);
                } else if *b == node {
                    t.set_key(*a, key);
                }
            }
            t
        }
    }

    /// The chain's four relay cores with link keys: the far vehicles know the way up.
    fn keyed_chain(keys: &LinkKeys) -> BTreeMap<u8, RelayCore> {
        let cfg = |forward, via: Option<u8>| RelayConfig {
            forward,
            routes: via
                .map(|via| vec![Route { dst: STATION, via }])
                .unwrap_or_default(),
            ..RelayConfig::default()
        };
        [
            (FAR2, cfg(false, Some(FAR))),
            (FAR, cfg(true, Some(NEAR))),
            (NEAR, cfg(true, None)),
            (STATION, cfg(false, None)),
        ]
        .into_iter()
        .map(|(node, c)| (node, core(c).with_hop_keys(keys.tagger(node))))
        .collect()
    }

    /// Carries `frame` from `from` hop by hop until someone delivers or refuses it.
    fn carry(
        nodes: &mut BTreeMap<u8, RelayCore>,
        from: u8,
        frame: &OutFrame,
        now: Instant,
    ) -> (Inbound, Vec<OutFrame>) {
        let mut on_air = nodes
            .get_mut(&from)
            .unwrap()
            .outbound(frame, Some(from), now)
            .unwrap();
        let (mut src, mut hops) = (from, vec![on_air.clone()]);
        loop {
            let at = on_air.dst;
            let node = nodes.get_mut(&at).unwrap();
            match node.inbound(rx(src, at, on_air.data.clone()), Some(at), now) {
                Inbound::Forward(next) => {
                    on_air = node.seal_hop(&next).unwrap();
                    hops.push(on_air.clone());
                    src = at;
                }
                other => return (other, hops),
            }
        }
    }

    #[test]
    fn a_keyed_three_hop_chain_delivers_both_ways_with_every_hop_sealed() {
        let keys = LinkKeys::chain();
        let mut nodes = keyed_chain(&keys);
        let now = Instant::now();
        let overhead = nodes[&FAR2].overhead();
        assert_eq!(overhead, HEADER_BYTES + TagSize::Bits64.overhead());
        // The largest frame the origin may hand down still fits every hop.
        let up = OutFrame {
            dst: STATION,
            data: vec![0x5a; MAX_FRAME - overhead],
            ack: true,
            burst: false,
        };
        let (got, hops) = carry(&mut nodes, FAR2, &up, now);
        assert_eq!(hops.len(), 3, "three hops");
        assert!(hops.iter().all(|h| h.data.len() == MAX_FRAME), "{hops:?}");
        let Inbound::Deliver(f) = got else {
            panic!("not delivered: {got:?}");
        };
        assert_eq!((f.src, f.dst, &f.data), (FAR2, STATION, &up.data));
        // The way down is learned from what came up, through the same keyed hops.
        let down = OutFrame {
            dst: FAR2,
            ..out(FAR2)
        };
        let (got, hops) = carry(&mut nodes, STATION, &down, now);
        assert_eq!(hops.len(), 3, "three hops down");
        assert!(matches!(got, Inbound::Deliver(f) if f.src == STATION && f.data == down.data));
        for n in nodes.values() {
            assert_eq!(n.stats().unauthenticated, 0);
        }
    }

    #[test]
    fn a_tampered_ttl_hop_count_origin_route_or_content_is_refused_and_counted() {
        let keys = LinkKeys::chain();
        let mut nodes = keyed_chain(&keys);
        let now = Instant::now();
        // FAR forwards FAR2's frame to NEAR; an attacker (or a relay without NEAR's trust)
        // rewrites the header in flight and leaves the seal.
        let far2 = nodes.get_mut(&FAR2).unwrap();
        let first = far2.outbound(&out(STATION), Some(FAR2), now).unwrap();
        let far = nodes.get_mut(&FAR).unwrap();
        let Inbound::Forward(next) = far.inbound(rx(FAR2, FAR, first.data), Some(FAR), now) else {
            panic!("FAR forwards");
        };
        let sealed = far.seal_hop(&next).unwrap();
        let seal_at = sealed.data.len() - TagSize::Bits64.overhead();
        let (env_bytes, seal) = sealed.data.split_at(seal_at);
        let genuine = Envelope::decode(env_bytes).unwrap();
        let tampered: Vec<(&str, Envelope)> = vec![
            (
                "more TTL",
                Envelope {
                    ttl: genuine.ttl + 1,
                    ..genuine.clone()
                },
            ),
            (
                "fewer hops",
                Envelope {
                    hops: 0,
                    ..genuine.clone()
                },
            ),
            (
                "hops and TTL shifted",
                Envelope {
                    hops: 0,
                    ttl: genuine.ttl + 1,
                    ..genuine.clone()
                },
            ),
            (
                "another origin",
                Envelope {
                    origin: 7,
                    ..genuine.clone()
                },
            ),
            (
                "another destination",
                Envelope {
                    dst: 7,
                    ..genuine.clone()
                },
            ),
            (
                "another number",
                Envelope {
                    msg_id: genuine.msg_id ^ 1,
                    ..genuine.clone()
                },
            ),
            (
                "another content",
                Envelope {
                    inner: vec![1, 2, 3],
                    ..genuine
                },
            ),
        ];
        let near = nodes.get_mut(&NEAR).unwrap();
        for (what, e) in &tampered {
            let mut data = e.encode().unwrap();
            data.extend_from_slice(seal);
            assert_eq!(
                near.inbound(rx(FAR, NEAR, data), Some(NEAR), now),
                Inbound::Refused(Refusal::Unauthenticated),
                "{what}"
            );
        }
        assert_eq!(near.stats().unauthenticated, tampered.len() as u64);
        assert!(
            near.learned_routes(now).is_empty(),
            "no route from a refused frame"
        );
        // The genuine frame, still unseen by NEAR's replay window, goes on.
        assert!(matches!(
            near.inbound(rx(FAR, NEAR, sealed.data.clone()), Some(NEAR), now),
            Inbound::Forward(f) if f.dst == STATION
        ));
    }

    #[test]
    fn envelopes_from_nodes_without_a_link_key_or_without_a_seal_are_refused() {
        let keys = LinkKeys::chain();
        let mut nodes = keyed_chain(&keys);
        let now = Instant::now();
        let near = nodes.get_mut(&NEAR).unwrap();
        // An outsider with a modem and a key of its own claims to relay FAR2's frame: a
        // forged route that would draw the station's traffic for FAR2 to it.
        let mut outsider = AcousticTagger::for_relay_hops(OUTSIDER, TagSize::Bits64, 1);
        outsider.set_key(NEAR, &AcousticKey::generate().unwrap());
        let forged = env(FAR2, STATION, 2, 1, 77).encode().unwrap();
        let sealed = outsider.seal(NEAR, &forged).unwrap();
        assert_eq!(
            near.inbound(rx(OUTSIDER, NEAR, sealed), Some(NEAR), now),
            Inbound::Refused(Refusal::Unauthenticated)
        );
        // A neighbour's address on an unsealed (version 1, keyless) envelope.
        assert_eq!(
            near.inbound(rx(FAR, NEAR, forged.clone()), Some(NEAR), now),
            Inbound::Refused(Refusal::Unauthenticated)
        );
        // Spoofing a keyed neighbour with a wrong key.
        let mut spoof = AcousticTagger::for_relay_hops(FAR, TagSize::Bits64, 1);
        spoof.set_key(NEAR, &AcousticKey::generate().unwrap());
        let sealed = spoof.seal(NEAR, &forged).unwrap();
        assert_eq!(
            near.inbound(rx(FAR, NEAR, sealed), Some(NEAR), now),
            Inbound::Refused(Refusal::Unauthenticated)
        );
        assert_eq!(near.stats().unauthenticated, 3);
        assert!(near.learned_routes(now).is_empty());
        // Plain frames, whose tags only the receiver above can check, teach no route.
        assert!(matches!(
            near.inbound(rx(OUTSIDER, NEAR, vec![4, 0]), Some(NEAR), now),
            Inbound::Deliver(_)
        ));
        assert!(near.learned_routes(now).is_empty());
        // And an origin with no link key for its next hop does not send unsealed.
        let lost = OutFrame { dst: 12, ..out(12) };
        let mut lonely = core(RelayConfig {
            routes: vec![Route {
                dst: 12,
                via: OUTSIDER,
            }],
            ..RelayConfig::default()
        })
        .with_hop_keys(keys.tagger(FAR2));
        assert!(matches!(
            lonely.outbound(&lost, Some(FAR2), now),
            Err(RelaySendError::Seal {
                relay: OUTSIDER,
                ..
            })
        ));
        assert_eq!(lonely.stats().originated, 0);
    }

    #[test]
    fn a_replayed_hop_frame_is_refused_and_a_resealed_retransmission_is_a_duplicate() {
        let keys = LinkKeys::chain();
        let mut nodes = keyed_chain(&keys);
        let now = Instant::now();
        let first = nodes
            .get_mut(&FAR2)
            .unwrap()
            .outbound(&out(STATION), Some(FAR2), now)
            .unwrap();
        let far = nodes.get_mut(&FAR).unwrap();
        let Inbound::Forward(next) = far.inbound(rx(FAR2, FAR, first.data.clone()), Some(FAR), now)
        else {
            panic!("FAR forwards");
        };
        // The same bytes again: a replay.
        assert_eq!(
            far.inbound(rx(FAR2, FAR, first.data), Some(FAR), now),
            Inbound::Refused(Refusal::Unauthenticated)
        );
        // FAR's retransmission to NEAR (its ack was lost) is sealed afresh each time.
        let a = far.seal_hop(&next).unwrap();
        let b = far.seal_hop(&next).unwrap();
        assert_ne!(a.data, b.data);
        let near = nodes.get_mut(&NEAR).unwrap();
        assert!(matches!(
            near.inbound(rx(FAR, NEAR, a.data), Some(NEAR), now),
            Inbound::Forward(_)
        ));
        assert_eq!(
            near.inbound(rx(FAR, NEAR, b.data), Some(NEAR), now),
            Inbound::Refused(Refusal::Duplicate)
        );
        assert_eq!(
            (near.stats().duplicates, near.stats().unauthenticated),
            (1, 0)
        );
    }

    proptest! {
        /// Any one bit flipped in a sealed envelope after its first byte (which would make
        /// it a plain frame, for the end-to-end tag above to refuse) is refused and counted.
        #[test]
        fn any_flipped_bit_of_a_sealed_envelope_is_refused(
            inner in proptest::collection::vec(any::<u8>(), 1..=MAX_FRAME - HEADER_BYTES - 12),
            hops in 0u8..=3, ttl in 0u8..=3, msg_id: u16, pick: prop::sample::Index,
        ) {
            let keys = LinkKeys::chain();
            let mut far = keys.tagger(FAR);
            let mut near = core(RelayConfig { forward: true, ..RelayConfig::default() })
                .with_hop_keys(keys.tagger(NEAR));
            let e = Envelope { origin: FAR2, dst: STATION, hops: hops.max(1), ttl, ack: true, msg_id, inner };
            let mut data = far.seal(NEAR, &e.encode().unwrap()).unwrap();
            let bit = 8 + pick.index(data.len() * 8 - 8);
            data[bit / 8] ^= 1 << (bit % 8);
            prop_assert_eq!(
                near.inbound(rx(FAR, NEAR, data), Some(NEAR), Instant::now()),
                Inbound::Refused(Refusal::Unauthenticated)
            );
            prop_assert_eq!(near.stats().unauthenticated, 1);
        }

        /// Junk that looks like an envelope never comes up or goes on at a keyed node.
        #[test]
        fn junk_at_a_keyed_node_is_counted_never_delivered(
            junk in proptest::collection::vec(any::<u8>(), 0..70), src in 1u8..=15,
        ) {
            let keys = LinkKeys::chain();
            let mut near = core(RelayConfig { forward: true, ..RelayConfig::default() })
                .with_hop_keys(keys.tagger(NEAR));
            let mut data = vec![ENVELOPE_ID];
            data.extend(junk);
            let got = near.inbound(rx(src, NEAR, data), Some(NEAR), Instant::now());
            prop_assert_eq!(got, Inbound::Refused(Refusal::Unauthenticated));
        }
    }
}
