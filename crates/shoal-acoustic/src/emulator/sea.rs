//! The simulated sea: node positions, transmissions, arrivals, losses and the modems'
//! state machines. Synchronous; the TCP servers in the parent module call into it under a
//! mutex and schedule the timers it asks for.

use std::collections::BTreeMap;
use std::time::Duration;

use rand::{RngExt as _, SeedableRng as _};
use rand_xoshiro::SplitMix64;
use shoal_model::geo;
use tokio::sync::mpsc;
use tokio::time::Instant;
use tracing::{debug, trace};

use super::{EmulatorConfig, LinkStats, Position};
use crate::at::{self, AtCommand, BROADCAST, ModemError, Notification, Received};
use crate::channel::ChannelModel;
use crate::nl::{NlCommand, NlEvent};

/// Bytes the EviNS network layer prefixes to each packet (docs/acoustic.md#nl-protocol);
/// counted in air time only.
const NL_HEADER: usize = 4;
/// NL payloads under this many bytes go as instant messages, larger ones as bursts
/// (docs/acoustic.md#nl-protocol).
const NL_IM_LIMIT: usize = 50;
/// Size of an acknowledgement on air, bytes (a short IM-like packet).
const ACK_BYTES: usize = 2;
/// Arrivals are kept this long (simulated seconds) after they end for collision checks.
const KEEP_ARRIVALS_S: f64 = 30.0;

/// Which host protocol a packet came from, so the receiver reports it on the same one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Proto {
    At,
    Nl,
}

/// How a new message is to be sent.
#[derive(Debug, Clone, Copy)]
struct How {
    ack: bool,
    burst: bool,
    proto: Proto,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    /// Payload; `ack` asks the receiver's modem to acknowledge automatically.
    Data { ack: bool },
    /// Acknowledgement of pending message `of`.
    Ack { of: u64 },
}

#[derive(Debug, Clone)]
struct Packet {
    id: u64,
    src: u8,
    dst: u8,
    kind: Kind,
    burst: bool,
    proto: Proto,
    data: Vec<u8>,
}

#[derive(Debug, Clone)]
struct Arrival {
    id: u64,
    rx: usize,
    start: Instant,
    end: Instant,
    lost: bool,
    air_us: u64,
    prop_us: u64,
    rssi: i32,
    integrity: u32,
    packet: Packet,
}

/// A message awaiting its acknowledgement.
#[derive(Debug, Clone)]
struct Pending {
    id: u64,
    dst: u8,
    data: Vec<u8>,
    burst: bool,
    proto: Proto,
    attempts_left: u8,
}

/// One virtual modem.
#[derive(Debug)]
pub(super) struct Node {
    pub(super) address: u8,
    pub(super) pos: Position,
    /// Failed or cut off (a scenario's modem failure or link outage): it neither puts
    /// anything on air nor hears anything.
    pub(super) silent: bool,
    /// Simulated seconds it has spent transmitting.
    pub(super) air_s: f64,
    remote: u8,
    retries: u8,
    source_level: u8,
    on_air_until: Instant,
    tx_log: Vec<(Instant, Instant)>,
    pending: Option<Pending>,
    last_rssi: i32,
    last_integrity: u32,
    last_prop_us: u64,
    protocol: String,
    routing: Vec<(u8, u8)>,
    at_clients: Vec<mpsc::Sender<Vec<u8>>>,
    nl_clients: Vec<mpsc::Sender<Vec<u8>>>,
}

/// Work the caller must schedule: call back into the sea at `at`.
#[derive(Debug, Clone, Copy)]
pub(super) enum Timer {
    /// An arrival ends: decide its fate.
    Resolve(u64),
    /// A pending message's ack did not come in time.
    Timeout { node: usize, id: u64 },
}

pub(super) type Timers = Vec<(Instant, Timer)>;

/// The whole simulated sea.
#[derive(Debug)]
pub(super) struct Sea {
    model: ChannelModel,
    fixed_per: Option<f64>,
    max_range_m: Option<f64>,
    time_scale: f64,
    im_bit_rate: f64,
    burst_bit_rate: f64,
    preamble_s: f64,
    rng: SplitMix64,
    pub(super) nodes: Vec<Node>,
    arrivals: Vec<Arrival>,
    stats: BTreeMap<(u8, u8), LinkStats>,
    next_id: u64,
}

fn distance_m(a: &Position, b: &Position) -> f64 {
    // Equirectangular: exact enough over the few km an acoustic link spans.
    let (horizontal, _) = geo::distance_bearing(
        a.latitude_deg,
        a.longitude_deg,
        b.latitude_deg,
        b.longitude_deg,
    );
    horizontal.hypot(b.depth_m - a.depth_m)
}

fn micros(s: f64) -> u64 {
    // Non-negative and far below u64::MAX for any physical duration.
    #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
    let us = (s.max(0.0) * 1e6).round() as u64;
    us
}

impl Sea {
    pub(super) fn new(cfg: &EmulatorConfig, now: Instant) -> Self {
        let nodes = cfg
            .modems
            .iter()
            .map(|m| Node {
                address: m.address,
                pos: Position {
                    latitude_deg: m.latitude_deg,
                    longitude_deg: m.longitude_deg,
                    depth_m: m.depth_m,
                },
                silent: false,
                air_s: 0.0,
                remote: 0,
                retries: cfg.im_retries,
                source_level: 0,
                on_air_until: now,
                tx_log: Vec::new(),
                pending: None,
                last_rssi: 0,
                last_integrity: 0,
                last_prop_us: 0,
                protocol: "staticrack".into(),
                routing: Vec::new(),
                at_clients: Vec::new(),
                nl_clients: Vec::new(),
            })
            .collect();
        Self {
            model: cfg.channel,
            fixed_per: cfg.fixed_per,
            max_range_m: cfg.max_range_m,
            time_scale: cfg.time_scale,
            im_bit_rate: cfg.im_bit_rate,
            burst_bit_rate: cfg.burst_bit_rate,
            preamble_s: cfg.preamble_s,
            rng: SplitMix64::seed_from_u64(cfg.seed),
            nodes,
            arrivals: Vec::new(),
            stats: BTreeMap::new(),
            next_id: 1,
        }
    }

    /// The counters of the link from `src` to `dst`.
    fn link(&mut self, src: u8, dst: u8) -> &mut LinkStats {
        self.stats.entry((src, dst)).or_insert_with(|| LinkStats {
            src,
            dst,
            ..LinkStats::default()
        })
    }

    /// Simulated seconds → wall-clock duration.
    fn wall(&self, sim_s: f64) -> Duration {
        Duration::from_secs_f64((sim_s * self.time_scale).max(0.0))
    }

    pub(super) fn index_of(&self, addr: u8) -> Option<usize> {
        self.nodes.iter().position(|n| n.address == addr)
    }

    pub(super) fn add_client(&mut self, node: usize, nl: bool, tx: mpsc::Sender<Vec<u8>>) {
        if let Some(n) = self.nodes.get_mut(node) {
            if nl {
                n.nl_clients.push(tx);
            } else {
                n.at_clients.push(tx);
            }
        }
    }

    pub(super) fn stats(&self) -> Vec<LinkStats> {
        self.stats.values().cloned().collect()
    }

    fn send_to(clients: &mut Vec<mpsc::Sender<Vec<u8>>>, bytes: &[u8]) {
        // A client too slow to take its notifications loses them rather than stalling the sea.
        clients.retain(|c| match c.try_send(bytes.to_vec()) {
            Ok(()) | Err(mpsc::error::TrySendError::Full(_)) => true,
            Err(mpsc::error::TrySendError::Closed(_)) => false,
        });
    }

    fn notify_at(&mut self, node: usize, n: &Notification) {
        if let Some(nd) = self.nodes.get_mut(node) {
            Self::send_to(&mut nd.at_clients, &at::notification(&n.to_body()));
        }
    }

    fn notify_nl(&mut self, node: usize, e: &NlEvent) {
        if let Some(nd) = self.nodes.get_mut(node) {
            Self::send_to(&mut nd.nl_clients, &e.to_bytes());
        }
    }

    fn air_time_s(&self, bytes: usize, burst: bool) -> f64 {
        let rate = if burst {
            self.burst_bit_rate
        } else {
            self.im_bit_rate
        };
        #[allow(clippy::cast_precision_loss)]
        let bits = (bytes * 8) as f64;
        self.preamble_s + bits / rate.max(1.0)
    }

    /// Puts a packet on air from `src`: one arrival per audible node.
    fn transmit(&mut self, src: usize, packet: &Packet, now: Instant) -> Timers {
        let overhead = if packet.proto == Proto::Nl {
            NL_HEADER
        } else {
            0
        };
        let bytes = packet.data.len() + overhead;
        let air_s = self.air_time_s(bytes, packet.burst);
        let air = self.wall(air_s);
        let Some(sender) = self.nodes.get_mut(src) else {
            return Vec::new();
        };
        if sender.silent {
            // Nothing reaches the water; the addressee's link counts it as an outage.
            let from = sender.address;
            if packet.dst != BROADCAST && self.index_of(packet.dst).is_some() {
                let st = self.link(from, packet.dst);
                st.frames += 1;
                st.outage += 1;
            }
            return Vec::new();
        }
        sender.on_air_until = now + air;
        sender.air_s += air_s;
        sender.tx_log.push((now, now + air));
        let attenuation = 6.0 * f64::from(sender.source_level);
        let from = sender.pos;
        let rate = if packet.burst {
            self.burst_bit_rate
        } else {
            self.im_bit_rate
        };
        let mut timers = Vec::new();
        for rx in 0..self.nodes.len() {
            if rx == src {
                continue;
            }
            let Some(to) = self.nodes.get(rx).map(|n| n.pos) else {
                continue;
            };
            let d = distance_m(&from, &to);
            // Out of range: not heard at all, not even as interference.
            if self.max_range_m.is_some_and(|r| d > r) {
                continue;
            }
            let snr = self.model.snr(d, attenuation);
            // Far below the noise a packet neither arrives nor interferes.
            if snr < 0.0 && self.fixed_per.is_none() {
                continue;
            }
            let c = self.model.sound_speed((from.depth_m + to.depth_m) / 2.0);
            let delay_s = d / c;
            let per = self
                .fixed_per
                .unwrap_or_else(|| self.model.per(d, bytes * 8, rate, attenuation));
            let lost = self.rng.random::<f64>() < per;
            let start = now + self.wall(delay_s);
            let end = start + air;
            let id = self.next_id;
            self.next_id += 1;
            let rl = self.model.received_level(d, attenuation);
            #[allow(clippy::cast_possible_truncation)]
            let rssi = (rl - 190.0).round().clamp(-200.0, 0.0) as i32;
            #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
            let integrity = (snr * 8.0).round().clamp(0.0, 255.0) as u32;
            trace!(src, rx, d, per, lost, "arrival scheduled");
            self.arrivals.push(Arrival {
                id,
                rx,
                start,
                end,
                lost,
                air_us: micros(air_s),
                prop_us: micros(delay_s),
                rssi,
                integrity,
                packet: packet.clone(),
            });
            timers.push((end, Timer::Resolve(id)));
        }
        timers
    }

    /// An arrival ended: collision, half duplex, channel loss, or reception.
    pub(super) fn resolve(&mut self, id: u64, now: Instant) -> Timers {
        let keep = self.wall(KEEP_ARRIVALS_S);
        let Some(a) = self.arrivals.iter().find(|a| a.id == id).cloned() else {
            return Vec::new();
        };
        let collided = self
            .arrivals
            .iter()
            .any(|b| b.id != a.id && b.rx == a.rx && b.start < a.end && a.start < b.end);
        let Some(rx_node) = self.nodes.get(a.rx) else {
            return Vec::new();
        };
        let deaf = rx_node
            .tx_log
            .iter()
            .any(|&(s, e)| s < a.end && a.start < e);
        let rx_addr = rx_node.address;
        let rx_silent = rx_node.silent;
        // Forget what can no longer overlap anything.
        self.arrivals.retain(|b| b.end + keep > now);
        for n in &mut self.nodes {
            n.tx_log.retain(|&(_, e)| e + keep > now);
        }
        let p = &a.packet;
        let intended = p.dst == rx_addr || p.dst == BROADCAST;
        if !intended {
            return Vec::new();
        }
        let st = self.link(p.src, rx_addr);
        st.frames += 1;
        if rx_silent {
            st.outage += 1;
            debug!(
                src = p.src,
                dst = rx_addr,
                "packet lost: the receiver is silent"
            );
            return Vec::new();
        }
        if collided {
            st.collisions += 1;
        } else if deaf {
            st.half_duplex += 1;
        } else if a.lost {
            st.lost += 1;
        } else {
            st.delivered += 1;
        }
        if collided || deaf || a.lost {
            debug!(src = p.src, dst = rx_addr, collided, deaf, "packet lost");
            return Vec::new();
        }
        if let Some(n) = self.nodes.get_mut(a.rx) {
            n.last_rssi = a.rssi;
            n.last_integrity = a.integrity;
            n.last_prop_us = a.prop_us;
        }
        match p.kind {
            Kind::Ack { of } => {
                let Some(n) = self.nodes.get_mut(a.rx) else {
                    return Vec::new();
                };
                if n.pending.as_ref().is_some_and(|q| q.id == of)
                    && let Some(q) = n.pending.take()
                {
                    self.report_done(a.rx, &q, true);
                }
                Vec::new()
            }
            Kind::Data { ack } => {
                let r = Received {
                    src: p.src,
                    dst: p.dst,
                    ack,
                    duration_us: if p.burst {
                        u64::from(self.burst_rate_u32())
                    } else {
                        a.air_us
                    },
                    rssi: a.rssi,
                    integrity: a.integrity,
                    velocity_mps: 0.0,
                    propagation_us: if p.burst { a.prop_us } else { 0 },
                    data: p.data.clone(),
                };
                match p.proto {
                    Proto::At if p.burst => self.notify_at(a.rx, &Notification::Recv(r)),
                    Proto::At => self.notify_at(a.rx, &Notification::RecvIm(r)),
                    Proto::Nl => self.notify_nl(
                        a.rx,
                        &NlEvent::Recv {
                            src: p.src,
                            dst: p.dst,
                            data: p.data.clone(),
                        },
                    ),
                }
                if ack && p.dst != BROADCAST {
                    // The receiving modem acknowledges by itself, after the packet ends.
                    let reply = Packet {
                        id: 0,
                        src: rx_addr,
                        dst: p.src,
                        kind: Kind::Ack { of: p.id },
                        burst: false,
                        proto: p.proto,
                        data: vec![0; ACK_BYTES],
                    };
                    return self.transmit(a.rx, &reply, now);
                }
                Vec::new()
            }
        }
    }

    fn burst_rate_u32(&self) -> u32 {
        #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
        let r = self.burst_bit_rate.round().clamp(0.0, f64::from(u32::MAX)) as u32;
        r
    }

    /// Reports the end of a pending message to the host that sent it.
    fn report_done(&mut self, node: usize, q: &Pending, delivered: bool) {
        let src = self.nodes.get(node).map_or(0, |n| n.address);
        match (q.proto, q.burst, delivered) {
            (Proto::At, false, true) => self.notify_at(node, &Notification::DeliveredIm(q.dst)),
            (Proto::At, false, false) => self.notify_at(node, &Notification::FailedIm(q.dst)),
            (Proto::At, true, true) => self.notify_at(
                node,
                &Notification::Delivered {
                    count: q.data.len(),
                    dst: q.dst,
                },
            ),
            (Proto::At, true, false) => self.notify_at(
                node,
                &Notification::Failed {
                    count: q.data.len(),
                    dst: q.dst,
                },
            ),
            (Proto::Nl, _, true) => self.notify_nl(node, &NlEvent::Delivered { src, dst: q.dst }),
            (Proto::Nl, _, false) => self.notify_nl(node, &NlEvent::Failed { src, dst: q.dst }),
        }
    }

    /// How long to wait for an ack: round trip, both air times and a margin.
    fn ack_wait(&self, node: usize, q: &Pending) -> Duration {
        let d = match (
            self.nodes.get(node),
            self.index_of(q.dst).and_then(|i| self.nodes.get(i)),
        ) {
            (Some(a), Some(b)) => distance_m(&a.pos, &b.pos),
            _ => 0.0,
        };
        let c = self.model.sound_speed(0.0);
        let overhead = if q.proto == Proto::Nl { NL_HEADER } else { 0 };
        let s = 2.0 * d / c
            + self.air_time_s(q.data.len() + overhead, q.burst)
            + self.air_time_s(ACK_BYTES, false)
            + 0.5;
        self.wall(s)
    }

    /// Sends (or re-sends) the pending message of `node`.
    fn send_pending(&mut self, node: usize, now: Instant) -> Timers {
        let Some(n) = self.nodes.get(node) else {
            return Vec::new();
        };
        let Some(q) = n.pending.clone() else {
            return Vec::new();
        };
        let packet = Packet {
            id: q.id,
            src: n.address,
            dst: q.dst,
            kind: Kind::Data { ack: true },
            burst: q.burst,
            proto: q.proto,
            data: q.data.clone(),
        };
        let mut timers = self.transmit(node, &packet, now);
        timers.push((
            now + self.ack_wait(node, &q),
            Timer::Timeout { node, id: q.id },
        ));
        timers
    }

    /// No ack in time: retry while attempts remain, then report failure.
    pub(super) fn timeout(&mut self, node: usize, id: u64, now: Instant) -> Timers {
        let Some(n) = self.nodes.get_mut(node) else {
            return Vec::new();
        };
        let Some(q) = n.pending.as_mut().filter(|q| q.id == id) else {
            return Vec::new();
        };
        if q.attempts_left > 0 {
            q.attempts_left -= 1;
            return self.send_pending(node, now);
        }
        if let Some(q) = n.pending.take() {
            self.report_done(node, &q, false);
        }
        Vec::new()
    }

    /// Checks a destination for a send from `node`: Ok, or the error to reply.
    fn check_destination(
        &self,
        node: usize,
        dst: u8,
        broadcast_ok: bool,
    ) -> Result<(), ModemError> {
        let own = self.nodes.get(node).map(|n| n.address);
        if dst == BROADCAST {
            return if broadcast_ok {
                Ok(())
            } else {
                Err(ModemError::WrongDestinationAddress)
            };
        }
        if Some(dst) == own || self.index_of(dst).is_none() {
            return Err(ModemError::WrongDestinationAddress);
        }
        Ok(())
    }

    /// Starts a new message from `node`; a pending one is cancelled (the modem does not
    /// queue: docs/acoustic.md#at-interface).
    fn start_send(
        &mut self,
        node: usize,
        dst: u8,
        data: Vec<u8>,
        how: How,
        now: Instant,
    ) -> Timers {
        let How { ack, burst, proto } = how;
        let id = self.next_id;
        self.next_id += 1;
        if let Some(old) = self.nodes.get_mut(node).and_then(|n| n.pending.take()) {
            match old.proto {
                Proto::At if !old.burst => self.notify_at(node, &Notification::CanceledIm(old.dst)),
                _ => self.report_done(node, &old, false),
            }
        }
        let Some(n) = self.nodes.get_mut(node) else {
            return Vec::new();
        };
        if ack && dst != BROADCAST {
            n.pending = Some(Pending {
                id,
                dst,
                data,
                burst,
                proto,
                attempts_left: n.retries,
            });
            self.send_pending(node, now)
        } else {
            let packet = Packet {
                id,
                src: n.address,
                dst,
                kind: Kind::Data { ack: false },
                burst,
                proto,
                data,
            };
            self.transmit(node, &packet, now)
        }
    }

    /// Executes one AT command for `node`; returns the reply body and timers.
    pub(super) fn at_command(
        &mut self,
        node: usize,
        cmd: AtCommand,
        now: Instant,
    ) -> (String, Timers) {
        let ok = || "OK".to_owned();
        let Some(n) = self.nodes.get(node) else {
            return (ModemError::WrongFormat.as_str().into(), Vec::new());
        };
        let on_air = n.on_air_until > now;
        match cmd {
            AtCommand::SendIm { dst, ack, data } => {
                if let Err(e) = self.check_destination(node, dst, !ack) {
                    return (e.as_str().into(), Vec::new());
                }
                if on_air {
                    let to = n.pending.as_ref().map_or(dst, |p| p.dst);
                    return (
                        format!("BUSY DELIVERING INSTANT MESSAGE TO {to}"),
                        Vec::new(),
                    );
                }
                (
                    ok(),
                    self.start_send(
                        node,
                        dst,
                        data,
                        How {
                            ack,
                            burst: false,
                            proto: Proto::At,
                        },
                        now,
                    ),
                )
            }
            AtCommand::SendBurst { dst, data } => {
                if let Err(e) = self.check_destination(node, dst, false) {
                    return (e.as_str().into(), Vec::new());
                }
                if on_air || n.pending.is_some() {
                    return ("BUSY BACKOFF STATE".into(), Vec::new());
                }
                (
                    ok(),
                    self.start_send(
                        node,
                        dst,
                        data,
                        How {
                            ack: true,
                            burst: true,
                            proto: Proto::At,
                        },
                        now,
                    ),
                )
            }
            AtCommand::SetLocalAddress(a) => {
                if a == 0 || a == BROADCAST || self.index_of(a).is_some_and(|i| i != node) {
                    return (ModemError::OutOfRange.as_str().into(), Vec::new());
                }
                if let Some(n) = self.nodes.get_mut(node) {
                    n.address = a;
                }
                (ok(), Vec::new())
            }
            AtCommand::GetLocalAddress => (n.address.to_string(), Vec::new()),
            AtCommand::SetRemoteAddress(a) => {
                if let Some(n) = self.nodes.get_mut(node) {
                    n.remote = a;
                }
                (ok(), Vec::new())
            }
            AtCommand::GetRemoteAddress => (n.remote.to_string(), Vec::new()),
            AtCommand::GetStatus => {
                let state = if n.pending.is_some() {
                    "DELIVERING"
                } else if on_air {
                    "TRANSMITTING"
                } else {
                    "IDLE"
                };
                (format!("{state},FREE {}", at::MAX_BURST), Vec::new())
            }
            AtCommand::SetImRetry(r) => {
                if let Some(n) = self.nodes.get_mut(node) {
                    n.retries = r;
                }
                (ok(), Vec::new())
            }
            AtCommand::GetImRetry => (n.retries.to_string(), Vec::new()),
            AtCommand::SetSourceLevel(l) => {
                if let Some(n) = self.nodes.get_mut(node) {
                    n.source_level = l;
                }
                (ok(), Vec::new())
            }
            AtCommand::GetSourceLevel => (n.source_level.to_string(), Vec::new()),
            AtCommand::GetRssi => (n.last_rssi.to_string(), Vec::new()),
            AtCommand::GetIntegrity => (n.last_integrity.to_string(), Vec::new()),
            AtCommand::GetPropagationTime => (n.last_prop_us.to_string(), Vec::new()),
            AtCommand::Reset(_) => {
                if let Some(old) = self.nodes.get_mut(node).and_then(|n| n.pending.take()) {
                    match old.proto {
                        Proto::At if !old.burst => {
                            self.notify_at(node, &Notification::CanceledIm(old.dst));
                        }
                        _ => self.report_done(node, &old, false),
                    }
                }
                (ok(), Vec::new())
            }
            // `AtCommand` is non-exhaustive for users, not for this crate; keep a fallback
            // so a future command cannot panic the emulator.
            #[allow(unreachable_patterns)]
            _ => (ModemError::UnknownCommand.as_str().into(), Vec::new()),
        }
    }

    /// Executes one NL command for `node`; returns the reply and timers.
    pub(super) fn nl_command(
        &mut self,
        node: usize,
        cmd: NlCommand,
        now: Instant,
    ) -> (NlEvent, Timers) {
        let Some(n) = self.nodes.get(node) else {
            return (NlEvent::Error("format".into()), Vec::new());
        };
        match cmd {
            NlCommand::Send { dst, data, .. } => {
                if self.check_destination(node, dst, true).is_err() {
                    return (NlEvent::NoRouting, Vec::new());
                }
                if n.pending.is_some() || n.on_air_until > now {
                    return (NlEvent::SendBusy, Vec::new());
                }
                if data.len() > at::MAX_BURST {
                    return (NlEvent::SendError, Vec::new());
                }
                let ack = n.protocol.ends_with("ack") && dst != BROADCAST;
                let burst = data.len() >= NL_IM_LIMIT;
                (
                    NlEvent::SendOk,
                    self.start_send(
                        node,
                        dst,
                        data,
                        How {
                            ack,
                            burst,
                            proto: Proto::Nl,
                        },
                        now,
                    ),
                )
            }
            NlCommand::SetAddress(a) => {
                if a == BROADCAST || self.index_of(a).is_some_and(|i| i != node) {
                    return (NlEvent::Error("format".into()), Vec::new());
                }
                if let Some(n) = self.nodes.get_mut(node) {
                    n.address = a;
                }
                (NlEvent::Address(a), Vec::new())
            }
            NlCommand::SetProtocol(p) => {
                if let Some(n) = self.nodes.get_mut(node) {
                    n.protocol.clone_from(&p);
                }
                (NlEvent::Protocol(p), Vec::new())
            }
            NlCommand::SetRouting(r) => {
                if let Some(n) = self.nodes.get_mut(node) {
                    n.routing.clone_from(&r);
                }
                (NlEvent::Routing(r), Vec::new())
            }
            NlCommand::GetAddress => (NlEvent::Address(n.address), Vec::new()),
            NlCommand::GetProtocol => (NlEvent::Protocol(n.protocol.clone()), Vec::new()),
            NlCommand::GetRouting => (NlEvent::Routing(n.routing.clone()), Vec::new()),
            #[allow(unreachable_patterns)]
            _ => (NlEvent::Error("format".into()), Vec::new()),
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod tests {
    use super::*;

    #[test]
    fn one_km_east_at_the_equator_is_one_km() {
        let a = Position {
            latitude_deg: 0.0,
            longitude_deg: 0.0,
            depth_m: 0.0,
        };
        let b = Position {
            latitude_deg: 0.0,
            longitude_deg: 1000.0 / 111_194.93,
            depth_m: 0.0,
        };
        assert!((distance_m(&a, &b) - 1000.0).abs() < 1.0);
    }
}
