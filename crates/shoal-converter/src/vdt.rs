//! The Vehicle Data Terminal: the vehicle's side of the DDS-Acoustic Converter.
//!
//! Vehicle DDS → modem: the VDT subscribes the vehicle's local topics and sends, for the
//! vehicles it serves (docs/acoustic.md#converter):
//! - state vectors as telemetry, at most one per vehicle per `state_interval_s`, the
//!   freshest first (a newer state replaces a queued one), coded as a delta against the
//!   last keyframe the CDT acknowledged, or as a keyframe;
//! - announcements as control, on arrival and every `announce_interval_s`;
//! - task status as control, for tasks that came acoustically (the CDT maps them back to
//!   the station's task ids);
//! - events as emergency when alarm or critical, control otherwise;
//! - environment observations as bulk, rate-limited per property.
//!
//! Modem → vehicle DDS: task PDUs from the CDT become [`TaskAssignment`]s on the vehicle's
//! own `shoal/task_assignment` topic under the station's task id, issue sequence and expiry
//! ([`IdentifiedTask`]), so the vehicle's DDS Proxy treats them exactly as if they had come
//! over IP: its task ledger never runs a re-delivered task again, after a restart of the
//! VDT, the vehicle or the station, and reports how it ended instead. A task PDU of layout
//! 1 (no identity) is refused and reported failed: a re-delivery of it could not be told
//! from a new task. Keyframe acks from the CDT feed the delta encoder.
//!
//! Multi-hop relaying (docs/acoustic.md#multi-hop-relays) happens under the VDT, in the
//! modem's driver ([`crate::Modem::start_relayed`], [`VdtConfig::relay`]): a vehicle out
//! of the CDT's range reaches it through another vehicle whose VDT's modem forwards for
//! it; frames from the CDT come up here as the CDT's whichever way they came.
//!
//! Keyframe acks name the keyframe by its 4-bit sequence number only, so delta coding is
//! used when the VDT serves a single vehicle (the normal case: one VDT per vehicle); a VDT
//! serving several vehicles sends keyframes only, which is always correct.

use std::collections::{HashMap, VecDeque};
use std::sync::Arc;

use shoal_acoustic::driver::ModemDriver;
use shoal_acoustic::link::{Class, LinkEvent, LinkSender, Outgoing};
use shoal_acoustic::pdu::convert::seconds_of_day;
use shoal_acoustic::pdu::{
    self, AddressBook, CompactAnnouncement, CompactEnvironment, CompactEvent, CompactTaskStatus,
    ConvertError, DeltaEncoder, IdentifiedTask, Pdu, StateKeyframe,
};
use shoal_dds::{Priority, PubSub, ReadError, SampleMeta, Writer, WriterOptions};
use shoal_model::{
    EnvironmentObservation, Event, Severity, StateVector, TaskAssignment, TaskKind, TaskState,
    TaskStatus, VehicleAnnouncement,
};
use tokio::time::{Instant, MissedTickBehavior};
use tokio_util::sync::CancellationToken;
use tracing::{debug, info, warn};

use crate::common::{Counter, encode, key, next_opt, start_link, supersede_key, wall};
use crate::config::{VdtConfig, address_book};
use crate::dedup::Dedup;
use crate::error::ConverterError;

/// Acoustic task numbers remembered for mapping task status back (oldest forgotten).
const TASK_MEMORY: usize = 256;

/// One vehicle the VDT serves.
#[derive(Debug)]
struct Served {
    id: String,
    addr: u8,
    encoder: DeltaEncoder,
    /// The freshest state not yet handed to the link.
    pending_state: Option<StateVector>,
    announcement: Option<VehicleAnnouncement>,
    environment_sent: HashMap<String, Instant>,
}

/// Runs a VDT over `driver` and the vehicle's DDS participant `dds` until `shutdown`.
///
/// Build the driver from the configuration with
/// [`Modem::start(&config.modem, config.time_scale)`](crate::Modem::start), or pass any
/// other [`ModemDriver`]. Returns `Ok(())` on shutdown.
pub async fn run_vdt<D: ModemDriver + 'static>(
    config: VdtConfig,
    dds: Arc<PubSub>,
    driver: D,
    shutdown: CancellationToken,
) -> Result<(), ConverterError> {
    config.check()?;
    let (link, mut events) = start_link(driver, &config.link, config.time_scale, &shutdown)?;
    let mut vdt = Vdt::new(config, &dds, link)?;
    let t = &vdt.cfg.topics;
    let mut states = t
        .state
        .then(|| dds.subscribe::<StateVector>())
        .transpose()?;
    let mut announcements = t
        .announcement
        .then(|| dds.subscribe::<VehicleAnnouncement>())
        .transpose()?;
    let mut statuses = t
        .task_status
        .then(|| dds.subscribe::<TaskStatus>())
        .transpose()?;
    let mut vehicle_events = t.events.then(|| dds.subscribe::<Event>()).transpose()?;
    let mut observations = t
        .environment
        .then(|| dds.subscribe::<EnvironmentObservation>())
        .transpose()?;
    let scale = vdt.cfg.time_scale;
    let mut state_tick = tokio::time::interval(wall(vdt.cfg.state_interval_s, scale));
    state_tick.set_missed_tick_behavior(MissedTickBehavior::Delay);
    let mut announce_tick = tokio::time::interval(wall(vdt.cfg.announce_interval_s, scale));
    announce_tick.set_missed_tick_behavior(MissedTickBehavior::Delay);
    // The first tick of an interval fires at once; announcements are sent on arrival.
    announce_tick.tick().await;
    info!(
        vehicles = ?vdt.served.iter().map(|s| &s.id).collect::<Vec<_>>(),
        cdt = vdt.cfg.cdt_address,
        delta = vdt.delta_coding,
        "VDT running"
    );
    loop {
        let step: Result<(), ConverterError> = tokio::select! {
            () = shutdown.cancelled() => break,
            Some(item) = next_opt(&mut states) => {
                if let Some(s) = sample(item) {
                    vdt.on_state(s.into_inner());
                }
                Ok(())
            }
            Some(item) = next_opt(&mut announcements) => match sample(item) {
                Some(a) => vdt.on_announcement(a.into_inner()).await,
                None => Ok(()),
            },
            Some(item) = next_opt(&mut statuses) => match sample(item) {
                Some(s) => vdt.on_task_status(&s).await,
                None => Ok(()),
            },
            Some(item) = next_opt(&mut vehicle_events) => match sample(item) {
                Some(e) => vdt.on_event(&e).await,
                None => Ok(()),
            },
            Some(item) = next_opt(&mut observations) => match sample(item) {
                Some(o) => vdt.on_observation(&o).await,
                None => Ok(()),
            },
            ev = events.recv() => match ev {
                Some(ev) => vdt.on_link_event(ev).await,
                None => Err(ConverterError::LinkStopped),
            },
            _ = state_tick.tick() => vdt.flush_states().await,
            _ = announce_tick.tick() => vdt.reannounce().await,
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
    info!("VDT stopped");
    Ok(())
}

/// A usable sample, or `None` after logging why not.
fn sample<T>(item: Result<(T, SampleMeta), ReadError>) -> Option<T> {
    match item {
        Ok((v, _)) => Some(v),
        Err(e) => {
            warn!(error = %e, "bad sample on the vehicle's DDS ignored");
            None
        }
    }
}

struct Vdt {
    cfg: VdtConfig,
    book: AddressBook,
    served: Vec<Served>,
    delta_coding: bool,
    link: LinkSender,
    /// task id on the vehicle's DDS → (vehicle address, acoustic task number), newest last.
    tasks: VecDeque<(String, u8, u8)>,
    event_no: Counter,
    dedup: Dedup,
    task_writer: Writer<TaskAssignment>,
    abort_writer: Writer<TaskAssignment>,
}

impl Vdt {
    fn new(cfg: VdtConfig, dds: &PubSub, link: LinkSender) -> Result<Self, ConverterError> {
        let book = address_book(&cfg.vehicles)?;
        let served: Vec<Served> = cfg
            .vehicles
            .iter()
            .map(|v| Served {
                id: v.vehicle_id.clone(),
                addr: v.address,
                // Predicted deltas (layout 2) when smaller than layout 1: the CDT of this
                // build reads both (docs/acoustic.md#predicted-deltas).
                encoder: DeltaEncoder::predictive(),
                pending_state: None,
                announcement: None,
                environment_sent: HashMap::new(),
            })
            .collect();
        let ttl = cfg.link.ttl.control_s.max(cfg.link.ttl.emergency_s);
        Ok(Self {
            dedup: Dedup::new(wall(ttl, cfg.time_scale), 4096),
            delta_coding: served.len() == 1,
            task_writer: dds.writer(WriterOptions::new(Priority::Control))?,
            abort_writer: dds.writer(WriterOptions::new(Priority::Emergency))?,
            cfg,
            book,
            served,
            link,
            tasks: VecDeque::new(),
            event_no: Counter::default(),
        })
    }

    fn served_mut(&mut self, vehicle_id: &str) -> Option<&mut Served> {
        self.served.iter_mut().find(|s| s.id == vehicle_id)
    }

    async fn send(
        &self,
        class: Class,
        pdu: &Pdu,
        supersede: Option<u64>,
    ) -> Result<(), ConverterError> {
        let Some(bytes) = encode(pdu) else {
            return Ok(());
        };
        let msg = Outgoing {
            dst: self.cfg.cdt_address,
            class,
            pdu: bytes,
            supersede_key: supersede,
        };
        match self.link.send(msg).await {
            Ok(id) => {
                debug!(id, pdu = pdu.name(), ?class, "queued for the CDT");
                Ok(())
            }
            Err(_) => Err(ConverterError::LinkStopped),
        }
    }

    fn on_state(&mut self, s: StateVector) {
        if let Some(v) = self.served_mut(&s.vehicle_id) {
            // Newest first: only the freshest state waits for the next slot.
            let newer = v
                .pending_state
                .as_ref()
                .is_none_or(|p| p.timestamp_ms <= s.timestamp_ms);
            if newer {
                v.pending_state = Some(s);
            }
        }
    }

    async fn flush_states(&mut self) -> Result<(), ConverterError> {
        let mut out = Vec::new();
        for v in &mut self.served {
            let Some(s) = v.pending_state.take() else {
                continue;
            };
            let key = match StateKeyframe::from_model(&s, &self.book, 0) {
                Ok(k) => k,
                Err(e) => {
                    warn!(vehicle = %v.id, error = %e, "state vector not encodable; skipped");
                    continue;
                }
            };
            match v.encoder.encode(&key) {
                Ok(p) => out.push((v.addr, p)),
                Err(e) => warn!(vehicle = %v.id, error = %e, "state vector not encodable"),
            }
        }
        for (addr, p) in out {
            self.send(
                Class::Telemetry,
                &p,
                Some(supersede_key(key::STATE, addr, 0)),
            )
            .await?;
        }
        Ok(())
    }

    async fn on_announcement(&mut self, a: VehicleAnnouncement) -> Result<(), ConverterError> {
        let Some(v) = self.served_mut(&a.vehicle_id) else {
            return Ok(());
        };
        v.announcement = Some(a.clone());
        let addr = v.addr;
        self.send_announcement(addr, &a).await
    }

    async fn send_announcement(
        &self,
        addr: u8,
        a: &VehicleAnnouncement,
    ) -> Result<(), ConverterError> {
        // Re-stamp so each repetition is a distinct PDU (not a duplicate at the CDT).
        let mut a = a.clone();
        a.timestamp_ms = self.cfg.now_ms();
        match CompactAnnouncement::from_model(&a, &self.book) {
            Ok(c) => {
                let key = supersede_key(key::ANNOUNCEMENT, addr, 0);
                self.send(Class::Control, &Pdu::Announcement(c), Some(key))
                    .await
            }
            Err(e) => {
                warn!(vehicle = %a.vehicle_id, error = %e, "announcement not encodable");
                Ok(())
            }
        }
    }

    async fn reannounce(&mut self) -> Result<(), ConverterError> {
        let list: Vec<(u8, VehicleAnnouncement)> = self
            .served
            .iter()
            .filter_map(|v| v.announcement.clone().map(|a| (v.addr, a)))
            .collect();
        for (addr, a) in list {
            self.send_announcement(addr, &a).await?;
        }
        Ok(())
    }

    fn task_no_of(&self, task_id: &str) -> Option<(u8, u8)> {
        self.tasks
            .iter()
            .rev()
            .find(|(id, _, _)| id == task_id)
            .map(|(_, a, n)| (*a, *n))
    }

    async fn on_task_status(&mut self, s: &TaskStatus) -> Result<(), ConverterError> {
        if self.served_mut(&s.vehicle_id).is_none() {
            return Ok(());
        }
        let Some((addr, task_no)) = self.task_no_of(&s.task_id) else {
            // A task given locally (not over the acoustic link): the station never saw it.
            debug!(task = %s.task_id, "status of a non-acoustic task not forwarded");
            return Ok(());
        };
        match CompactTaskStatus::from_model(s, &self.book, task_no) {
            Ok(c) => {
                let key = supersede_key(key::TASK_STATUS, addr, u32::from(task_no));
                self.send(Class::Control, &Pdu::TaskStatus(c), Some(key))
                    .await
            }
            Err(e) => {
                warn!(task = %s.task_id, error = %e, "task status not encodable");
                Ok(())
            }
        }
    }

    async fn on_event(&mut self, e: &Event) -> Result<(), ConverterError> {
        if self.served_mut(&e.vehicle_id).is_none() {
            return Ok(());
        }
        let task_no = self.task_no_of(&e.task_id).map(|(_, n)| n);
        let no = self.event_no.next();
        match CompactEvent::from_model(e, &self.book, no, task_no) {
            Ok(c) => {
                let class = if e.severity >= Severity::Alarm {
                    Class::Emergency
                } else {
                    Class::Control
                };
                self.send(class, &Pdu::Event(c), None).await
            }
            Err(err) => {
                warn!(event = %e.event_id, error = %err, "event not encodable");
                Ok(())
            }
        }
    }

    async fn on_observation(&mut self, o: &EnvironmentObservation) -> Result<(), ConverterError> {
        let interval = wall(self.cfg.environment_interval_s, self.cfg.time_scale);
        let now = Instant::now();
        let Some(v) = self.served_mut(&o.vehicle_id) else {
            return Ok(());
        };
        if v.environment_sent
            .get(&o.property)
            .is_some_and(|t| now.saturating_duration_since(*t) < interval)
        {
            return Ok(());
        }
        let addr = v.addr;
        v.environment_sent.insert(o.property.clone(), now);
        match CompactEnvironment::from_model(o, &self.book) {
            Ok(c) => {
                let key = supersede_key(key::ENVIRONMENT, addr, u32::from(c.property));
                self.send(Class::Bulk, &Pdu::Environment(c), Some(key))
                    .await
            }
            Err(ConvertError::Unsupported { value, .. }) => {
                debug!(property = %value, "observation has no compact code; not sent");
                Ok(())
            }
            Err(e) => {
                warn!(property = %o.property, error = %e, "observation not encodable");
                Ok(())
            }
        }
    }

    async fn on_link_event(&mut self, ev: LinkEvent) -> Result<(), ConverterError> {
        match ev {
            LinkEvent::Received {
                src, dst, frame, ..
            } => {
                if src != self.cfg.cdt_address {
                    debug!(src, dst, "frame from another node ignored");
                    return Ok(());
                }
                match pdu::unpack_frame(&frame) {
                    Ok(pdus) => {
                        for p in pdus {
                            self.on_pdu(src, p).await?;
                        }
                    }
                    Err(e) => warn!(src, error = %e, "undecodable frame dropped"),
                }
            }
            LinkEvent::Expired(id) => warn!(id, "message expired before delivery"),
            LinkEvent::Dropped(id) => debug!(id, "message dropped or superseded"),
            LinkEvent::Delivered(id) | LinkEvent::Sent(id) => debug!(id, "message sent"),
            other => debug!(event = ?other, "link event"),
        }
        Ok(())
    }

    async fn on_pdu(&mut self, src: u8, p: Pdu) -> Result<(), ConverterError> {
        match p {
            Pdu::Ack(a) if a.msg_id == pdu::id::STATE_KEYFRAME => {
                if self.delta_coding {
                    for v in &mut self.served {
                        if v.encoder.acknowledge(a.ref_no) {
                            debug!(vehicle = %v.id, seq = a.ref_no, "keyframe acknowledged");
                        }
                    }
                }
            }
            // The CDT does not hold the keyframe our deltas name (it restarted): send one.
            Pdu::Ack(a) if a.msg_id == pdu::id::STATE_DELTA => {
                if self.delta_coding {
                    for v in &mut self.served {
                        if v.encoder.reference_unknown(a.ref_no) {
                            info!(vehicle = %v.id, seq = a.ref_no, "the CDT lacks our keyframe; sending a new one");
                        }
                    }
                }
            }
            Pdu::IdentifiedTask(t) => {
                let Some(bytes) = encode(&Pdu::IdentifiedTask(t.clone())) else {
                    return Ok(());
                };
                // Only spares the vehicle's bus: the vehicle's ledger is what keeps a task
                // from running twice, also after this VDT restarts.
                if !self.dedup.first(src, &bytes, Instant::now()) {
                    debug!(task = %t.task_id, task_no = t.task_no, "duplicate task PDU suppressed");
                    return Ok(());
                }
                self.on_task(t).await?;
            }
            Pdu::Task(t) => {
                // Layout 1 names the task by an 8-bit number only: running it could run a
                // re-delivered task twice. Refuse it, and say so to the station.
                warn!(
                    vehicle = t.vehicle,
                    task_no = t.task_no,
                    "task PDU without the station's task identity (layout 1) refused: update the CDT"
                );
                if self.served.iter().any(|v| v.addr == t.vehicle) {
                    self.send_failed(t.vehicle, t.task_no).await?;
                }
            }
            other => debug!(pdu = other.name(), "PDU not meant for a VDT ignored"),
        }
        Ok(())
    }

    /// Tells the CDT that task number `task_no` of `addr` failed on arrival.
    async fn send_failed(&self, addr: u8, task_no: u8) -> Result<(), ConverterError> {
        let failed = Pdu::TaskStatus(CompactTaskStatus {
            vehicle: addr,
            task_no,
            state: task_state_code(TaskState::Failed),
            progress_pct: 0.0,
            seconds_of_day: seconds_of_day(self.cfg.now_ms()),
        });
        self.send(Class::Control, &failed, None).await
    }

    async fn on_task(&mut self, t: IdentifiedTask) -> Result<(), ConverterError> {
        let Some(v) = self.served.iter().find(|v| v.addr == t.vehicle) else {
            debug!(
                vehicle = t.vehicle,
                "task for a vehicle this VDT does not serve"
            );
            return Ok(());
        };
        let now = self.cfg.now_ms();
        // The station's own task id, issue sequence and expiry, as over IP: the vehicle's
        // ledger knows a re-delivery whoever delivers it. The 8-bit task number only
        // routes status back; the CDT maps it to the same task id.
        let task_id = t.task_id.clone();
        let (vehicle_id, addr) = (v.id.clone(), v.addr);
        let assignment = match t.to_model(&self.book, now) {
            Ok(a) => a,
            Err(e) => {
                warn!(vehicle = %vehicle_id, task = %task_id, task_no = t.task_no, error = %e, "task PDU unusable");
                return self.send_failed(addr, t.task_no).await;
            }
        };
        self.tasks.push_back((task_id.clone(), addr, t.task_no));
        while self.tasks.len() > TASK_MEMORY {
            self.tasks.pop_front();
        }
        let writer = if assignment.kind == TaskKind::Abort {
            &self.abort_writer
        } else {
            &self.task_writer
        };
        info!(vehicle = %vehicle_id, task = %task_id, seq = assignment.issue_seq, kind = ?assignment.kind, "acoustic task handed to the vehicle");
        if let Err(e) = writer.write(assignment).await {
            warn!(task = %task_id, error = %e, "task not published on the vehicle's DDS");
        }
        Ok(())
    }
}

/// The compact code of a task state (its position in the IDL enum).
fn task_state_code(s: TaskState) -> u8 {
    match s {
        TaskState::Pending => 0,
        TaskState::Sent => 1,
        TaskState::Accepted => 2,
        TaskState::Running => 3,
        TaskState::Done => 4,
        TaskState::Failed => 5,
        TaskState::Aborted => 6,
        TaskState::Expired => 7,
    }
}
