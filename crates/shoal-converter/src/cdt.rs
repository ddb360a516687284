//! The Control Data Terminal: the station's (or a relay USV's) side of the converter.
//!
//! Modem → DDS: frames from the vehicles' VDTs are unpacked, duplicates suppressed (the
//! modem may deliver a message twice: docs/acoustic.md#at-interface), states expanded from
//! keyframe or delta, and every datum republished with the **same types and topics as an
//! IP vehicle's**: the station needs no acoustic code. Each keyframe is acknowledged to
//! its VDT so it can code deltas against it. Alongside, a per-vehicle link-status event
//! carries the link metadata ([`crate::link_status`]). A PDU about a vehicle is accepted
//! only from that vehicle's modem (whose key opened the frame on a tagged link) or from a
//! relay configured to carry it ([`CdtConfig::relays`]); others are refused as
//! impersonation, counted, and raise an alarm naming the sender.
//!
//! DDS → modem: task assignments for the vehicles in the address book are given an 8-bit
//! task number and sent with the station's task id, issue sequence and expiry
//! ([`IdentifiedTask`], docs/acoustic.md#task-identity), so the vehicle's task ledger knows a
//! re-delivery as over IP; as control (acknowledged, retransmitted with backoff until their
//! TTL; aborts as emergency), and reported as `sent` on `shoal/task_status`, or `expired` if
//! the link gives up. A task whose PDU would not fit one frame is reported `failed`. Status
//! reports coming back name the task number; the CDT maps it to the station's task id.
//!
//! Link failover (docs/acoustic.md#link-failover): a vehicle whose VDT also has an IP path
//! shows up on the station's domain through its own participant while it is at the
//! surface. The CDT watches the state vectors and task status there: a vehicle heard over
//! IP within [`CdtConfig::ip_silence_s`] is on IP, and its tasks wait (the vehicle takes
//! them from the station's domain itself) instead of crossing the water; an acoustic state
//! newer than any IP state, or the IP silence, puts it back on acoustic. Then the CDT says
//! so (its link status at once, and a switch event) and sends every task of the vehicle
//! that has not ended: the ones that waited, and the ones the vehicle took over IP, whose
//! status can only come back with an acoustic task number (the vehicle's ledger refuses
//! to run any of them twice). Acoustic states older than the newest the station has from
//! either link are not republished, so the station never sees time run backwards.
//!
//! With a [`CdtConfig::tap`], a copy of every PDU handed to the link, every frame received
//! and every message's fate goes to a recorder ([`crate::tap`]); a full tap drops and
//! counts, the CDT never waits for it.

use std::collections::{HashMap, VecDeque};
use std::sync::Arc;

use shoal_acoustic::driver::ModemDriver;
use shoal_acoustic::link::{Class, LinkEvent, LinkSender, MessageId, Outgoing};
use shoal_acoustic::pdu::{
    self, Ack, AddressBook, DecodeError, DeltaDecoder, IdentifiedTask, Pdu, StateKeyframe,
};
use shoal_dds::{Priority, PubSub, Writer, WriterOptions};
use shoal_model::{
    EnvironmentObservation, Event, EventKind, LinkKind, Severity, StateVector, TaskAssignment,
    TaskKind, TaskState, TaskStatus, VehicleAnnouncement,
};
use tokio::time::{Instant, MissedTickBehavior};
use tokio_util::sync::CancellationToken;
use tracing::{debug, info, warn};

use crate::failover::switch_event;

use crate::common::{Counter, encode, key, next_opt, start_link, supersede_key, wall};
use crate::config::{CdtConfig, address_book};
use crate::dedup::Dedup;
use crate::error::ConverterError;
use crate::link_status::LinkStatus;
use crate::tap::{MessageFate, TapEvent, TapRecord};

/// Task numbers remembered per CDT for mapping status back (oldest forgotten).
const TASK_MEMORY: usize = 1024;

/// Runs a CDT over `driver` and the station-side DDS participant `dds` until `shutdown`.
///
/// Give the CDT its own participant (not the station's), so its samples carry a writer
/// GUID that the link-status events name. Build the driver with
/// [`Modem::start(&config.modem, config.time_scale)`](crate::Modem::start) or pass any
/// other [`ModemDriver`]. Returns `Ok(())` on shutdown.
pub async fn run_cdt<D: ModemDriver + 'static>(
    config: CdtConfig,
    dds: Arc<PubSub>,
    driver: D,
    shutdown: CancellationToken,
) -> Result<(), ConverterError> {
    config.check()?;
    let (link, mut events) = start_link(driver, &config.link, config.time_scale, &shutdown)?;
    let mut tasks = Some(dds.subscribe::<TaskAssignment>()?);
    // Vehicles with an IP path as well: what they say there, through their own participant.
    // Only with `ip_failover`: otherwise nothing a participant publishes about a vehicle
    // (a replay, a second tool) can hold its tasks back, and no CDT reads the whole fleet's
    // states for nothing.
    let failover = config.ip_failover;
    let mut ip_states = failover
        .then(|| dds.subscribe::<StateVector>())
        .transpose()?;
    let mut ip_status = failover
        .then(|| dds.subscribe::<TaskStatus>())
        .transpose()?;
    let mut ip_links = failover.then(|| dds.subscribe::<Event>()).transpose()?;
    let mut cdt = Cdt::new(config, &dds, link)?;
    let mut ip_tick = tokio::time::interval(wall(1.0, cdt.cfg.time_scale));
    ip_tick.set_missed_tick_behavior(MissedTickBehavior::Delay);
    info!(address = cdt.cfg.address, participant = %cdt.participant, "CDT running");
    loop {
        let step: Result<(), ConverterError> = tokio::select! {
            () = shutdown.cancelled() => break,
            Some(item) = next_opt(&mut tasks) => match item {
                Ok((t, _)) => cdt.on_task(t.into_inner()).await,
                Err(e) => {
                    warn!(error = %e, "bad task sample ignored");
                    Ok(())
                }
            },
            ev = events.recv() => match ev {
                Some(ev) => cdt.on_link_event(ev).await,
                None => Err(ConverterError::LinkStopped),
            },
            Some(item) = next_opt(&mut ip_states) => match item {
                Ok((s, meta)) if meta.participant != cdt.participant => {
                    cdt.on_ip_state(&s);
                    Ok(())
                }
                _ => Ok(()),
            },
            Some(item) = next_opt(&mut ip_status) => match item {
                Ok((s, meta)) => {
                    cdt.on_status_seen(&s, meta.participant != cdt.participant);
                    Ok(())
                }
                Err(_) => Ok(()),
            },
            Some(item) = next_opt(&mut ip_links) => match item {
                Ok((e, meta)) if meta.participant != cdt.participant => {
                    cdt.on_ip_event(&e);
                    Ok(())
                }
                _ => Ok(()),
            },
            _ = ip_tick.tick() => cdt.check_ip_silence().await,
        };
        // The link stops with the same shutdown signal: a send that races the stop is
        // part of stopping, not a failure.
        if let Err(e) = step {
            if shutdown.is_cancelled() {
                break;
            }
            return Err(e);
        }
    }
    cdt.refusals.report(Instant::now());
    info!("CDT stopped");
    Ok(())
}

/// What the CDT knows of one vehicle's link.
#[derive(Debug, Default)]
struct Peer {
    last_state_ms: Option<i64>,
    rssi: Option<i32>,
    integrity: Option<u32>,
    heard_ms: i64,
    /// Frames heard from it since the CDT started (the console animates their arrival).
    frames: u64,
    status_published: Option<Instant>,
    /// The vehicle is on its IP path (heard there within `ip_silence_s`).
    on_ip: bool,
    /// When it was last heard over IP.
    ip_heard: Option<Instant>,
    /// Vehicle time of its latest IP evidence: its newest state over IP, or the moment
    /// its VDT said it switched to IP. An acoustic state no newer than this was on the
    /// water before the switch, and says nothing about where the vehicle is now.
    ip_ms: i64,
}

struct Writers {
    state: Writer<StateVector>,
    announcement: Writer<VehicleAnnouncement>,
    status: Writer<TaskStatus>,
    event: Writer<Event>,
    alarm: Writer<Event>,
    environment: Writer<EnvironmentObservation>,
}

struct Cdt {
    cfg: CdtConfig,
    book: AddressBook,
    participant: String,
    link: LinkSender,
    w: Writers,
    decoder: DeltaDecoder,
    dedup: Dedup,
    peers: HashMap<u8, Peer>,
    /// (vehicle address, task number, station task id), newest last.
    tasks: VecDeque<(u8, u8, String)>,
    task_numbers: HashMap<u8, Counter>,
    /// Tasks already forwarded, with their issue time: transient-local DDS re-delivers
    /// history, while a station retrying an undelivered task re-issues it later.
    forwarded: VecDeque<(String, i64)>,
    /// Link message id → the task in the link's hands.
    in_flight: HashMap<MessageId, TaskAssignment>,
    /// Tasks for vehicles on IP, kept until the vehicle reports them ended or comes back
    /// to the acoustic link, oldest first.
    held: VecDeque<TaskAssignment>,
    /// Tasks reported ended on the station's domain, oldest first.
    ended: VecDeque<String>,
    event_no: u64,
    /// Relay address → the addresses it may speak for ([`CdtConfig::relays`]).
    relays: HashMap<u8, Vec<u8>>,
    impersonation: Impersonation,
    refusals: Refusals,
    /// Per vehicle address, when it was last told a keyframe is missing (at most 16).
    missing_reported: HashMap<u8, Instant>,
}

/// Frames and PDUs the CDT refused, by reason: each is logged at debug level, and a
/// warning sums them up at most every [`REFUSALS_REPORT_EVERY`] (and when the CDT stops),
/// so a sender of junk cannot flood the log.
#[derive(Debug, Default)]
struct Refusals {
    by_reason: std::collections::BTreeMap<&'static str, u64>,
    unreported: u64,
    reported_at: Option<Instant>,
}

/// How often refusals are summed up in the log while they go on.
const REFUSALS_REPORT_EVERY: std::time::Duration = std::time::Duration::from_secs(10);

impl Refusals {
    /// Counts one refusal; logs the summary if one is due.
    fn count(&mut self, reason: &'static str) {
        *self.by_reason.entry(reason).or_default() += 1;
        self.unreported += 1;
        let now = Instant::now();
        if self
            .reported_at
            .is_none_or(|t| now.duration_since(t) >= REFUSALS_REPORT_EVERY)
        {
            self.report(now);
        }
    }

    /// Logs the totals by reason if anything was refused since the last report.
    fn report(&mut self, now: Instant) {
        if self.unreported == 0 {
            return;
        }
        let reasons: Vec<String> = self
            .by_reason
            .iter()
            .map(|(r, n)| format!("{r}={n}"))
            .collect();
        warn!(
            new = self.unreported,
            reasons = %reasons.join(" "),
            "acoustic frames or PDUs refused (totals by reason)"
        );
        self.unreported = 0;
        self.reported_at = Some(now);
    }
}

/// PDUs refused because they spoke for a vehicle other than their sender.
#[derive(Debug, Default)]
struct Impersonation {
    refused: u64,
    /// Per sending address, when its last alarm went out: one a minute at most, so a
    /// captured modem cannot flood the station's alarms either.
    alarmed: HashMap<u8, Instant>,
}

/// How often a vehicle is told at most that a keyframe its deltas name is missing here:
/// its answer (a keyframe, then an ack) takes a few frames on air.
const MISSING_KEYFRAME_EVERY: std::time::Duration = std::time::Duration::from_secs(10);

/// How often one sender's impersonation attempts raise an alarm.
const IMPERSONATION_ALARM_EVERY: std::time::Duration = std::time::Duration::from_secs(60);

/// The vehicle address a PDU speaks for; `None` for PDUs a CDT does not act on (keep in
/// step with `Cdt::on_pdu`: a PDU it acts on must be listed here, or it goes unchecked).
fn claimed_vehicle(p: &Pdu) -> Option<u8> {
    match p {
        Pdu::StateKeyframe(k) => Some(k.vehicle),
        Pdu::StateDelta(d) => Some(d.vehicle),
        Pdu::PredictedDelta(d) => Some(d.vehicle),
        Pdu::TaskStatus(s) => Some(s.vehicle),
        Pdu::Event(e) => e.vehicle,
        Pdu::Announcement(a) => Some(a.vehicle),
        Pdu::Environment(o) => Some(o.vehicle),
        _ => None,
    }
}

impl Cdt {
    fn new(cfg: CdtConfig, dds: &PubSub, link: LinkSender) -> Result<Self, ConverterError> {
        let book = address_book(&cfg.vehicles)?;
        let cfg_relays = cfg.relay_rules()?.into_iter().collect();
        let control = WriterOptions::new(Priority::Control);
        let w = Writers {
            state: dds.writer(WriterOptions::new(Priority::Telemetry))?,
            announcement: dds.writer(control)?,
            status: dds.writer(control)?,
            event: dds.writer(control)?,
            alarm: dds.writer(WriterOptions::new(Priority::Emergency))?,
            environment: dds.writer(WriterOptions::new(Priority::Bulk))?,
        };
        let ttl = cfg.link.ttl.control_s.max(cfg.link.ttl.emergency_s);
        Ok(Self {
            dedup: Dedup::new(wall(ttl, cfg.time_scale), 4096),
            participant: dds.participant_id(),
            cfg,
            book,
            link,
            w,
            decoder: DeltaDecoder::new(),
            peers: HashMap::new(),
            tasks: VecDeque::new(),
            task_numbers: HashMap::new(),
            forwarded: VecDeque::new(),
            in_flight: HashMap::new(),
            held: VecDeque::new(),
            ended: VecDeque::new(),
            event_no: 0,
            relays: cfg_relays,
            impersonation: Impersonation::default(),
            refusals: Refusals::default(),
            missing_reported: HashMap::new(),
        })
    }

    async fn publish_status(&self, task_id: &str, vehicle_id: &str, state: TaskState, msg: &str) {
        let s = TaskStatus {
            task_id: task_id.to_owned(),
            vehicle_id: vehicle_id.to_owned(),
            timestamp_ms: self.cfg.now_ms(),
            state,
            progress_pct: 0.0,
            message: msg.to_owned(),
        };
        if let Err(e) = self.w.status.write(s).await {
            warn!(task = task_id, error = %e, "task status not published");
        }
    }

    async fn on_task(&mut self, t: TaskAssignment) -> Result<(), ConverterError> {
        let Ok(addr) = self.book.addr(&t.vehicle_id) else {
            return Ok(()); // Not an acoustic vehicle of this CDT: IP carries it.
        };
        let again = |id: &str, issued: i64| id == t.task_id && issued >= t.issued_ms;
        if self.forwarded.iter().any(|(id, issued)| again(id, *issued))
            || self.held.iter().any(|h| again(&h.task_id, h.issued_ms))
        {
            return Ok(());
        }
        if stale(&self.cfg, &t, self.cfg.now_ms()) {
            // Transient-local history from before this CDT started, long past its time.
            debug!(task = %t.task_id, "stale task not forwarded");
            return Ok(());
        }
        if self.peers.get(&addr).is_some_and(|p| p.on_ip) {
            // The vehicle takes it from the station's domain itself; nothing redundant on
            // the water. Sent if the vehicle dives before reporting it ended.
            info!(task = %t.task_id, vehicle = %t.vehicle_id, "vehicle on IP: task not sent acoustically");
            self.hold(t);
            return Ok(());
        }
        self.send_task(addr, t).await
    }

    fn hold(&mut self, t: TaskAssignment) {
        self.held.retain(|h| h.task_id != t.task_id);
        self.held.push_back(t);
        while self.held.len() > TASK_MEMORY {
            self.held.pop_front();
        }
    }

    /// Sends a task over the acoustic link now (see [`Self::on_task`] for when).
    async fn send_task(&mut self, addr: u8, t: TaskAssignment) -> Result<(), ConverterError> {
        self.forwarded.push_back((t.task_id.clone(), t.issued_ms));
        while self.forwarded.len() > TASK_MEMORY {
            self.forwarded.pop_front();
        }
        let task_no = self.task_numbers.entry(addr).or_default().next();
        let compact = match IdentifiedTask::from_model(&t, &self.book, task_no) {
            Ok(c) => c,
            Err(e) => {
                warn!(task = %t.task_id, error = %e, "task cannot be sent acoustically");
                let msg = format!("cannot be sent over the acoustic link: {e}");
                self.publish_status(&t.task_id, &t.vehicle_id, TaskState::Failed, &msg)
                    .await;
                return Ok(());
            }
        };
        let Some(bytes) = encode(&Pdu::IdentifiedTask(compact)) else {
            return Ok(());
        };
        if bytes.len() > self.cfg.link.max_frame {
            // The link would drop it unsent; say why now instead of expiring it later.
            let msg = format!(
                "cannot be sent over the acoustic link: its {}-byte PDU exceeds the {}-byte frame",
                bytes.len(),
                self.cfg.link.max_frame
            );
            warn!(task = %t.task_id, bytes = bytes.len(), "task PDU larger than a frame");
            self.publish_status(&t.task_id, &t.vehicle_id, TaskState::Failed, &msg)
                .await;
            return Ok(());
        }
        let class = if t.kind == TaskKind::Abort {
            Class::Emergency
        } else {
            Class::Control
        };
        self.tasks.push_back((addr, task_no, t.task_id.clone()));
        while self.tasks.len() > TASK_MEMORY {
            self.tasks.pop_front();
        }
        let msg = Outgoing {
            dst: addr,
            class,
            pdu: bytes,
            supersede_key: None,
        };
        let id = self.send(msg).await?;
        info!(task = %t.task_id, vehicle = %t.vehicle_id, task_no, ?class, "task queued on the acoustic link");
        self.publish_status(
            &t.task_id,
            &t.vehicle_id,
            TaskState::Sent,
            "queued on the acoustic link",
        )
        .await;
        self.in_flight.insert(id, t);
        Ok(())
    }

    /// A state vector on the station's domain from another participant: the vehicle's own,
    /// over its IP path.
    fn on_ip_state(&mut self, s: &StateVector) {
        let Ok(addr) = self.book.addr(&s.vehicle_id) else {
            return;
        };
        let peer = self.peers.entry(addr).or_default();
        peer.ip_heard = Some(Instant::now());
        peer.ip_ms = peer.ip_ms.max(s.timestamp_ms);
        if peer.last_state_ms.is_none_or(|t| t < s.timestamp_ms) {
            peer.last_state_ms = Some(s.timestamp_ms);
        }
        if !peer.on_ip {
            peer.on_ip = true;
            info!(vehicle = %s.vehicle_id, "vehicle heard over IP: its tasks wait there");
        }
    }

    /// An event on the station's domain from another participant: a VDT's link status
    /// saying it switched to IP is the earliest evidence (before its first state there).
    fn on_ip_event(&mut self, e: &Event) {
        let Some(status) = LinkStatus::from_event(e) else {
            return;
        };
        // Transient-local history brings old statuses to a CDT that starts: only a fresh
        // one says where the vehicle is now.
        let age_ms = self.cfg.now_ms().saturating_sub(status.heard_ms);
        // Timestamps are simulated time on a scenario's clock, wall time otherwise.
        let silence = if self.cfg.clock.is_some() {
            std::time::Duration::from_secs_f64(self.cfg.ip_silence_s)
        } else {
            wall(self.cfg.ip_silence_s, self.cfg.time_scale)
        };
        let fresh = u128::try_from(age_ms).unwrap_or(0) < silence.as_millis();
        if status.link != LinkKind::Ip || !fresh {
            return;
        }
        let Ok(addr) = self.book.addr(&status.vehicle_id) else {
            return;
        };
        let peer = self.peers.entry(addr).or_default();
        peer.ip_heard = Some(Instant::now());
        peer.ip_ms = peer.ip_ms.max(status.heard_ms);
        if !peer.on_ip {
            peer.on_ip = true;
            info!(vehicle = %status.vehicle_id, "vehicle switched to IP: its tasks wait there");
        }
    }

    /// A task status on the station's domain (`over_ip`: not this CDT's own): an ended
    /// task is not sent again.
    fn on_status_seen(&mut self, s: &TaskStatus, over_ip: bool) {
        if over_ip && let Ok(addr) = self.book.addr(&s.vehicle_id) {
            self.peers.entry(addr).or_default().ip_heard = Some(Instant::now());
        }
        let ended = matches!(
            s.state,
            TaskState::Done | TaskState::Failed | TaskState::Aborted | TaskState::Expired
        );
        if ended && !self.ended.contains(&s.task_id) {
            self.held.retain(|h| h.task_id != s.task_id);
            self.ended.push_back(s.task_id.clone());
            while self.ended.len() > TASK_MEMORY {
                self.ended.pop_front();
            }
        }
    }

    /// Vehicles on IP not heard there for `ip_silence_s` are back on acoustic.
    async fn check_ip_silence(&mut self) -> Result<(), ConverterError> {
        let silence = wall(self.cfg.ip_silence_s, self.cfg.time_scale);
        let now = Instant::now();
        let silent: Vec<u8> = self
            .peers
            .iter()
            .filter(|(_, p)| {
                p.on_ip
                    && p.ip_heard
                        .is_none_or(|t| now.saturating_duration_since(t) >= silence)
            })
            .map(|(a, _)| *a)
            .collect();
        for addr in silent {
            let why = format!("not heard over IP for {:.0} s", self.cfg.ip_silence_s);
            self.back_on_acoustic(addr, &why).await?;
        }
        Ok(())
    }

    /// The vehicle at `addr` is back on the acoustic link: says so at once (link status
    /// and a switch event) and sends its tasks that have not ended.
    async fn back_on_acoustic(&mut self, addr: u8, why: &str) -> Result<(), ConverterError> {
        let Ok(vehicle_id) = self.book.vehicle_id(addr).map(str::to_owned) else {
            return Ok(());
        };
        if let Some(p) = self.peers.get_mut(&addr) {
            p.on_ip = false;
            p.status_published = None;
        }
        info!(vehicle = %vehicle_id, why, "link: acoustic");
        let now = self.cfg.now_ms();
        let ev = switch_event(
            &vehicle_id,
            LinkKind::Acoustic,
            now,
            format!("switched to the acoustic link: {why}"),
        );
        if let Err(e) = self.w.event.write(ev).await {
            warn!(error = %e, "switch event not published");
        }
        if self.peers.get(&addr).is_some_and(|p| p.heard_ms > 0) {
            self.maybe_publish_link_status(addr, &vehicle_id).await;
        }
        let (mine, rest): (VecDeque<_>, VecDeque<_>) = std::mem::take(&mut self.held)
            .into_iter()
            .partition(|t| t.vehicle_id == vehicle_id);
        self.held = rest;
        let now_ms = self.cfg.now_ms();
        for t in mine {
            if self.ended.contains(&t.task_id) || stale(&self.cfg, &t, now_ms) {
                continue;
            }
            info!(task = %t.task_id, vehicle = %vehicle_id, "vehicle back on acoustic: task sent over the water");
            self.send_task(addr, t).await?;
        }
        Ok(())
    }

    async fn on_link_event(&mut self, ev: LinkEvent) -> Result<(), ConverterError> {
        if self.cfg.tap.is_some() {
            let event = match &ev {
                LinkEvent::Received {
                    src,
                    dst,
                    frame,
                    rssi,
                    integrity,
                } => Some(TapEvent::Received {
                    src: *src,
                    dst: *dst,
                    bytes: frame.clone(),
                    rssi: *rssi,
                    integrity: *integrity,
                }),
                other => MessageFate::of(other)
                    .map(|(message_id, fate)| TapEvent::Fate { message_id, fate }),
            };
            if let Some(event) = event {
                self.tap(event);
            }
        }
        match ev {
            LinkEvent::Received {
                src,
                frame,
                rssi,
                integrity,
                ..
            } => self.on_frame(src, &frame, rssi, integrity).await?,
            LinkEvent::Delivered(id) => {
                if let Some(t) = self.in_flight.remove(&id) {
                    debug!(task = %t.task_id, "task delivered to the vehicle's modem");
                }
            }
            LinkEvent::Expired(id) | LinkEvent::Dropped(id) => {
                if let Some(t) = self.in_flight.remove(&id) {
                    let on_ip = self
                        .book
                        .addr(&t.vehicle_id)
                        .ok()
                        .and_then(|a| self.peers.get(&a))
                        .is_some_and(|p| p.on_ip);
                    if on_ip {
                        // Not lost: the vehicle takes it over IP, or gets it again when it
                        // dives before ending it.
                        debug!(task = %t.task_id, "acoustic copy given up while the vehicle is on IP");
                        if !self.ended.contains(&t.task_id) {
                            self.forwarded.retain(|(id, _)| *id != t.task_id);
                            self.hold(t);
                        }
                        return Ok(());
                    }
                    warn!(task = %t.task_id, vehicle = %t.vehicle_id, "task not delivered within its TTL");
                    self.publish_status(
                        &t.task_id,
                        &t.vehicle_id,
                        TaskState::Expired,
                        "not delivered over the acoustic link within its TTL",
                    )
                    .await;
                }
            }
            other => debug!(event = ?other, "link event"),
        }
        Ok(())
    }

    async fn on_frame(
        &mut self,
        src: u8,
        frame: &[u8],
        rssi: Option<i32>,
        integrity: Option<u32>,
    ) -> Result<(), ConverterError> {
        let Ok(vehicle_id) = self.book.vehicle_id(src).map(str::to_owned) else {
            debug!(src, "frame from a modem not in the address book ignored");
            return Ok(());
        };
        let pdus = match pdu::unpack_frame(frame) {
            Ok(p) => p,
            Err(e) => {
                debug!(src, error = %e, "undecodable frame dropped");
                self.refusals.count("undecodable_frame");
                return Ok(());
            }
        };
        let now = self.cfg.now_ms();
        let peer = self.peers.entry(src).or_default();
        peer.rssi = rssi;
        peer.integrity = integrity;
        peer.heard_ms = now;
        peer.frames = peer.frames.saturating_add(1);
        for mut p in pdus {
            // A frame without a vehicle speaks for its sender.
            if let Pdu::Event(e) = &mut p
                && e.vehicle.is_none()
            {
                e.vehicle = Some(src);
            }
            if let Some(claimed) = claimed_vehicle(&p)
                && !self.may_speak_for(src, claimed)
            {
                self.refuse_impersonation(src, &vehicle_id, claimed, p.name())
                    .await;
                continue;
            }
            self.on_pdu(src, p, now).await?;
        }
        self.maybe_publish_link_status(src, &vehicle_id).await;
        Ok(())
    }

    async fn on_pdu(&mut self, src: u8, p: Pdu, now: i64) -> Result<(), ConverterError> {
        if let Pdu::StateKeyframe(k) = &p {
            // Ack every copy: if an earlier ack was lost the VDT still waits for one.
            self.ack_keyframe(src, k).await?;
        }
        let Some(bytes) = encode(&p) else {
            return Ok(());
        };
        if !self.dedup.first(src, &bytes, Instant::now()) {
            debug!(src, pdu = p.name(), "duplicate PDU suppressed");
            return Ok(());
        }
        let book = &self.book;
        match p {
            Pdu::StateKeyframe(_) | Pdu::StateDelta(_) | Pdu::PredictedDelta(_) => {
                match self.decoder.decode(&p) {
                    Ok(Some(k)) => self.on_state(&k, now).await,
                    Ok(None) => {}
                    Err(DecodeError::UnknownKeyframe { vehicle, seq }) => {
                        debug!(vehicle, seq, "delta against an unknown keyframe dropped");
                        self.refusals.count("unknown_keyframe");
                        // Ask for a keyframe rather than wait for the VDT's refresh.
                        self.report_missing_keyframe(vehicle, seq).await?;
                    }
                    Err(e) => {
                        debug!(error = %e, "state PDU unusable");
                        self.refusals.count("unusable_state");
                    }
                }
            }
            Pdu::TaskStatus(s) => {
                let task_id = self
                    .tasks
                    .iter()
                    .rev()
                    .find(|(a, n, _)| *a == s.vehicle && *n == s.task_no)
                    .map(|(_, _, id)| id.clone());
                let Some(task_id) = task_id else {
                    debug!(
                        vehicle = s.vehicle,
                        task_no = s.task_no,
                        "status of an unknown task number"
                    );
                    return Ok(());
                };
                match s.to_model(book, &task_id, now) {
                    Ok(m) => {
                        debug!(task = %task_id, state = ?m.state, "task status from the water");
                        if let Err(e) = self.w.status.write(m).await {
                            warn!(error = %e, "task status not published");
                        }
                    }
                    Err(e) => {
                        debug!(task = %task_id, error = %e, "task status PDU unusable");
                        self.refusals.count("unusable_status");
                    }
                }
            }
            Pdu::Event(e) => {
                self.event_no += 1;
                let vehicle = e
                    .vehicle
                    .and_then(|a| book.vehicle_id(a).ok())
                    .unwrap_or("unknown");
                // Unique across restarts of the CDT and across vehicles.
                let event_id = format!("{vehicle}-ac-{now}-{}", self.event_no);
                let task_id = e
                    .task_no
                    .and_then(|n| {
                        self.tasks
                            .iter()
                            .rev()
                            .find(|(a, t, _)| Some(*a) == e.vehicle && *t == n)
                    })
                    .map(|(_, _, id)| id.as_str())
                    .unwrap_or_default();
                match e.to_model(book, &event_id, task_id, now) {
                    Ok(m) => {
                        let w = if m.severity >= Severity::Alarm {
                            &self.w.alarm
                        } else {
                            &self.w.event
                        };
                        if let Err(err) = w.write(m).await {
                            warn!(error = %err, "event not published");
                        }
                    }
                    Err(err) => {
                        debug!(error = %err, "event PDU unusable");
                        self.refusals.count("unusable_event");
                    }
                }
            }
            Pdu::Announcement(a) => match a.to_model(book, now) {
                Ok(m) => {
                    if let Err(e) = self.w.announcement.write(m).await {
                        warn!(error = %e, "announcement not published");
                    }
                }
                Err(e) => {
                    debug!(error = %e, "announcement PDU unusable");
                    self.refusals.count("unusable_announcement");
                }
            },
            Pdu::Environment(o) => match o.to_model(book, now) {
                Ok(m) => {
                    if let Err(e) = self.w.environment.write(m).await {
                        warn!(error = %e, "observation not published");
                    }
                }
                Err(e) => {
                    debug!(error = %e, "environment PDU unusable");
                    self.refusals.count("unusable_environment");
                }
            },
            other => debug!(pdu = other.name(), "PDU not meant for a CDT ignored"),
        }
        Ok(())
    }

    /// Whether the modem at `src` (authenticated by its key on a tagged link) may send
    /// PDUs about the vehicle at `claimed`: its own, or those it relays by configuration.
    fn may_speak_for(&self, src: u8, claimed: u8) -> bool {
        claimed == src || self.relays.get(&src).is_some_and(|c| c.contains(&claimed))
    }

    /// Drops a PDU about another vehicle, counts it, and raises a data-rejected alarm
    /// naming the sender (at most once a minute per sender).
    async fn refuse_impersonation(&mut self, src: u8, sender: &str, claimed: u8, pdu: &str) {
        let claimed_id = self
            .book
            .vehicle_id(claimed)
            .unwrap_or("unknown")
            .to_owned();
        self.refusals.count("impersonation");
        let imp = &mut self.impersonation;
        imp.refused += 1;
        debug!(
            sender,
            src,
            claimed = %claimed_id,
            claimed_address = claimed,
            pdu,
            refused = imp.refused,
            "acoustic PDU about another vehicle refused (impersonation)"
        );
        let now = Instant::now();
        if imp
            .alarmed
            .get(&src)
            .is_some_and(|t| now.duration_since(*t) < IMPERSONATION_ALARM_EVERY)
        {
            return;
        }
        imp.alarmed.insert(src, now);
        self.event_no += 1;
        let ts = self.cfg.now_ms();
        let alarm = Event {
            event_id: format!("{sender}-ac-imp-{ts}-{}", self.event_no),
            timestamp_ms: ts,
            severity: Severity::Alarm,
            kind: EventKind::DataRejected,
            vehicle_id: sender.to_owned(),
            task_id: String::new(),
            text: format!(
                "acoustic {pdu} from {sender}'s modem (address {src}) spoke for {claimed_id} \
                 (address {claimed}) and was refused; {} refused so far. Its acoustic key \
                 may be compromised.",
                imp.refused
            ),
        };
        if let Err(e) = self.w.alarm.write(alarm).await {
            warn!(error = %e, "impersonation alarm not published");
        }
    }

    /// Tells the VDT of `vehicle` that keyframe `seq`, which its deltas name, is not held
    /// here (this CDT restarted, or never got it): an [`Ack`] of the delta message id,
    /// which makes the VDT send a keyframe next (docs/acoustic.md#converter). At most one
    /// every [`MISSING_KEYFRAME_EVERY`] per vehicle; a queued one is replaced.
    async fn report_missing_keyframe(
        &mut self,
        vehicle: u8,
        seq: u8,
    ) -> Result<(), ConverterError> {
        let now = Instant::now();
        if self
            .missing_reported
            .get(&vehicle)
            .is_some_and(|t| now.duration_since(*t) < MISSING_KEYFRAME_EVERY)
        {
            return Ok(());
        }
        self.missing_reported.insert(vehicle, now);
        self.send_ack(vehicle, pdu::id::STATE_DELTA, seq, key::KEYFRAME_MISSING)
            .await
    }

    async fn ack_keyframe(&self, src: u8, k: &StateKeyframe) -> Result<(), ConverterError> {
        self.send_ack(src, pdu::id::STATE_KEYFRAME, k.seq, key::KEYFRAME_ACK)
            .await
    }

    /// Sends an [`Ack`] of (`msg_id`, `ref_no`) to `dst`. Telemetry class: a lost ack
    /// costs one more keyframe, not a retransmission; a newer one of the same `kind`
    /// replaces a queued older one.
    async fn send_ack(
        &self,
        dst: u8,
        msg_id: u8,
        ref_no: u8,
        kind: u8,
    ) -> Result<(), ConverterError> {
        let ack = Pdu::Ack(Ack {
            from: self.cfg.address,
            msg_id,
            ref_no,
        });
        let Some(bytes) = encode(&ack) else {
            return Ok(());
        };
        let msg = Outgoing {
            dst,
            class: Class::Telemetry,
            pdu: bytes,
            supersede_key: Some(supersede_key(kind, dst, 0)),
        };
        self.send(msg).await.map(|_| ())
    }

    /// Hands `msg` to the link layer, and a copy to the tap if there is one.
    async fn send(&self, msg: Outgoing) -> Result<MessageId, ConverterError> {
        let copy = self
            .cfg
            .tap
            .as_ref()
            .map(|_| (msg.dst, msg.class, msg.pdu.clone()));
        let id = self
            .link
            .send(msg)
            .await
            .map_err(|_| ConverterError::LinkStopped)?;
        if let Some((dst, class, bytes)) = copy {
            self.tap(TapEvent::Sent {
                dst,
                class,
                message_id: id,
                bytes,
            });
        }
        Ok(id)
    }

    /// Reports `event` to the tap, if there is one.
    fn tap(&self, event: TapEvent) {
        if let Some(tap) = &self.cfg.tap {
            tap.report(TapRecord::now(self.cfg.address, self.cfg.now_ms(), event));
        }
    }

    async fn on_state(&mut self, k: &StateKeyframe, now: i64) {
        let sv = match k.to_model(&self.book, now) {
            Ok(s) => s,
            Err(e) => {
                debug!(error = %e, "state PDU unusable");
                self.refusals.count("unusable_state");
                return;
            }
        };
        let peer = self.peers.entry(k.vehicle).or_default();
        // Newest-first telemetry may deliver an older state after a newer one (and one
        // queued before a switch to IP may follow the IP states); the station would see
        // time run backwards, so only newer states are republished.
        if peer.last_state_ms.is_some_and(|t| t >= sv.timestamp_ms) {
            debug!(vehicle = %sv.vehicle_id, "older state not republished");
            return;
        }
        if peer.on_ip && sv.timestamp_ms > peer.ip_ms {
            // The VDT routes each state once: one over the water newer than anything it
            // sent over IP (or than its switch to IP) means it left IP.
            if let Err(e) = self
                .back_on_acoustic(k.vehicle, "a newer state came over the acoustic link")
                .await
            {
                warn!(error = %e, "tasks not sent after the switch");
            }
        }
        let peer = self.peers.entry(k.vehicle).or_default();
        peer.last_state_ms = Some(sv.timestamp_ms);
        if let Err(e) = self.w.state.write(sv).await {
            warn!(error = %e, "state vector not published");
        }
    }

    async fn maybe_publish_link_status(&mut self, src: u8, vehicle_id: &str) {
        let interval = wall(self.cfg.link_status_interval_s, self.cfg.time_scale);
        let now = Instant::now();
        let Some(peer) = self.peers.get_mut(&src) else {
            return;
        };
        if peer.on_ip {
            // A straggler frame; the vehicle's own link status (over IP) stands.
            return;
        }
        if peer
            .status_published
            .is_some_and(|t| now.saturating_duration_since(t) < interval)
        {
            return;
        }
        peer.status_published = Some(now);
        let status = LinkStatus {
            vehicle_id: vehicle_id.to_owned(),
            link: LinkKind::Acoustic,
            cdt_address: self.cfg.address,
            vehicle_address: src,
            rssi_db: peer.rssi,
            integrity: peer.integrity,
            heard_ms: peer.heard_ms,
            participant: self.participant.clone(),
            cdt_latitude_deg: self.cfg.position.map(|p| p.latitude_deg),
            cdt_longitude_deg: self.cfg.position.map(|p| p.longitude_deg),
            cdt_vehicle: self.cfg.carrier.clone(),
            frames: Some(peer.frames),
            interval_s: Some(self.cfg.link_status_interval_s),
        };
        if let Err(e) = self.w.event.write(status.to_event()).await {
            warn!(error = %e, "link status not published");
        }
    }
}

/// A task the station no longer wants delivered at `now`: past the start window it gave
/// it (`expires_ms`), or, without one, issued longer ago than the control TTL. A mission's
/// later task is issued with the mission and sent when its turn comes, so only its window
/// says whether it is still wanted.
fn stale(cfg: &CdtConfig, t: &TaskAssignment, now: i64) -> bool {
    if t.expires_ms > 0 {
        return now > t.expires_ms;
    }
    // The TTL is simulated time on a scenario's clock, wall time otherwise.
    let ttl = if cfg.clock.is_some() {
        std::time::Duration::from_secs_f64(cfg.link.ttl.control_s.max(0.0))
    } else {
        wall(cfg.link.ttl.control_s, cfg.time_scale)
    };
    u128::try_from(now.saturating_sub(t.issued_ms)).unwrap_or(0) > ttl.as_millis()
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn a_task_is_stale_past_its_start_window_or_without_one_past_the_control_ttl() {
        let cfg = CdtConfig::default();
        let ttl_ms = (cfg.link.ttl.control_s * 1000.0) as i64;
        let issued = 1_800_000_000_000;
        let mut t = TaskAssignment::new("m-2", "m", "auv-1", issued, &shoal_model::Task::Surface);
        // A mission's second task, issued with the mission long ago, sent now within the
        // window the station gave it: still wanted.
        t.expires_ms = issued + 10 * ttl_ms;
        assert!(!stale(&cfg, &t, issued + 5 * ttl_ms));
        assert!(stale(&cfg, &t, issued + 10 * ttl_ms + 1));
        // No window: the control TTL from its issue.
        t.expires_ms = 0;
        assert!(!stale(&cfg, &t, issued + ttl_ms));
        assert!(stale(&cfg, &t, issued + ttl_ms + 1));
        // At a tenth of real time without a scenario clock the TTL is wall time (a tenth),
        // on a scenario's clock it is simulated time.
        let fast = CdtConfig {
            time_scale: 0.1,
            ..CdtConfig::default()
        };
        assert!(stale(&fast, &t, issued + ttl_ms / 10 + 1));
        let warped = CdtConfig {
            time_scale: 0.1,
            clock: Some(shoal_model::Warp::start_at(issued, 10.0).unwrap()),
            ..CdtConfig::default()
        };
        assert!(!stale(&warped, &t, issued + ttl_ms / 10 + 1));
        assert!(stale(&warped, &t, issued + ttl_ms + 1));
    }

    #[test]
    fn refusals_are_summed_up_in_the_log_not_written_one_by_one() {
        let mut r = Refusals::default();
        // The first refusal is reported at once, later ones within 10 s wait for the next
        // summary; the totals keep every one.
        r.count("impersonation");
        assert_eq!(r.unreported, 0);
        r.count("impersonation");
        r.count("undecodable_frame");
        assert_eq!(r.unreported, 2);
        assert_eq!(r.by_reason["impersonation"], 2);
        r.report(Instant::now());
        assert_eq!(r.unreported, 0);
        assert_eq!(r.by_reason.values().sum::<u64>(), 3);
    }

    /// A PDU kind added later that speaks for a vehicle must be bound to its sender too:
    /// every sample PDU but the station's own (tasks, acks) names its vehicle.
    #[test]
    fn every_pdu_a_vehicle_sends_names_the_vehicle_it_speaks_for() {
        for (name, p) in pdu::samples() {
            let from_station = matches!(p, Pdu::Task(_) | Pdu::IdentifiedTask(_) | Pdu::Ack(_));
            let anonymous_event = matches!(&p, Pdu::Event(e) if e.vehicle.is_none());
            assert_eq!(
                claimed_vehicle(&p).is_some(),
                !from_station && !anonymous_event,
                "{name}"
            );
        }
    }
}
