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
//! With an IP path (`[vdt.ip]`, docs/acoustic.md#link-failover) the VDT also owns a
//! participant on the station's DDS domain, opened only while the vehicle's radio can
//! work (at the surface), and a [`Failover`] decides which link carries the vehicle's data:
//! on IP every sample goes over DDS straight to the station's domain, as an IP vehicle's
//! would, the station's tasks come back the same way, and the acoustic link carries
//! nothing; on acoustic everything goes through the modem as above. Each sample is routed
//! once, at the moment it is handled, so no state vector crosses both links. The switch
//! to IP is announced to the station over IP (a `link.<vehicle>` status with link `ip`,
//! and a switch [`Event`]); the switch back is seen by the CDT, which says so.
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
use shoal_dds::{
    Credentials, DdsConfig, Priority, PubSub, ReadError, SampleMeta, Subscription, Writer,
    WriterOptions,
};
use shoal_model::{
    EnvironmentObservation, Event, LinkKind, LinkStatus, Severity, StateVector, TaskAssignment,
    TaskKind, TaskState, TaskStatus, VehicleAnnouncement,
};
use tokio::time::{Instant, MissedTickBehavior};
use tokio_util::sync::CancellationToken;
use tracing::{debug, info, warn};

use crate::common::{Counter, encode, key, next_opt, start_link, supersede_key, wall};
use crate::config::{VdtConfig, address_book};
use crate::dedup::Dedup;
use crate::error::ConverterError;
use crate::failover::{Failover, IpPathConfig, Switch, switch_event};

/// Acoustic task numbers remembered for mapping task status back (oldest forgotten).
const TASK_MEMORY: usize = 256;

/// How often the failover looks at the IP path's evidence, simulated seconds.
const FAILOVER_POLL_S: f64 = 0.5;

/// The VDT's side of the IP path: its own participant on the station's domain, with a
/// writer per class (as the CDT's) and the station's tasks. Dropping it (and the task
/// subscription the run loop holds) deletes the participant: nothing more crosses.
struct IpSide {
    /// GUID prefix of the participant, named in the link status.
    participant: String,
    state: Writer<StateVector>,
    announcement: Writer<VehicleAnnouncement>,
    status: Writer<TaskStatus>,
    event: Writer<Event>,
    alarm: Writer<Event>,
    environment: Writer<EnvironmentObservation>,
    /// Handed once to the run loop, which polls it.
    tasks: Option<Subscription<TaskAssignment>>,
    _dds: Arc<PubSub>,
}

impl IpSide {
    fn open(cfg: &IpPathConfig, credentials: Option<Credentials>) -> Result<Self, ConverterError> {
        let c = DdsConfig {
            domain_id: cfg.domain_id,
            interfaces: cfg.interfaces.clone(),
            ..DdsConfig::default()
        };
        let dds = Arc::new(match credentials {
            Some(credentials) => PubSub::with_credentials(&c, credentials)?,
            // `run_vdt_secured` or `insecure`, checked when the VDT starts.
            None => PubSub::new(&c)?,
        });
        let control = WriterOptions::new(Priority::Control);
        Ok(Self {
            participant: dds.participant_id(),
            state: dds.writer(WriterOptions::new(Priority::Telemetry))?,
            announcement: dds.writer(control)?,
            status: dds.writer(control)?,
            event: dds.writer(control)?,
            alarm: dds.writer(WriterOptions::new(Priority::Emergency))?,
            environment: dds.writer(WriterOptions::new(Priority::Bulk))?,
            tasks: Some(dds.subscribe::<TaskAssignment>()?),
            _dds: dds,
        })
    }
}

/// Logs a sample the IP path could not take (the participant is going away with it).
fn ip_write_failed<T>(what: &str, r: Result<(), shoal_dds::WriteError<T>>) {
    if let Err(e) = r {
        warn!(error = %e, "{what} not written over IP");
    }
}

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
    run(config, dds, driver, None, shutdown).await
}

/// Refuses an IP path that would join the station's domain without DDS Security unless
/// `insecure` says that is meant.
fn ip_path_secured(ip: &IpPathConfig, has_credentials: bool) -> Result<(), ConverterError> {
    if ip.enabled && !has_credentials && !ip.insecure {
        return Err(ConverterError::Config(
            "vdt.ip.enabled needs the vehicle's DDS Security credentials (run_vdt_secured), \
             or vdt.ip.insecure = true for a lab: an IP participant without them would take \
             tasks from anyone on the station's domain"
                .into(),
        ));
    }
    Ok(())
}

/// [`run_vdt`] with the vehicle's DDS Security credentials, which the IP path's
/// participant (`[vdt.ip]`) joins the station's secured domain with.
pub async fn run_vdt_secured<D: ModemDriver + 'static>(
    config: VdtConfig,
    dds: Arc<PubSub>,
    driver: D,
    ip_credentials: Credentials,
    shutdown: CancellationToken,
) -> Result<(), ConverterError> {
    run(config, dds, driver, Some(ip_credentials), shutdown).await
}

async fn run<D: ModemDriver + 'static>(
    config: VdtConfig,
    dds: Arc<PubSub>,
    driver: D,
    ip_credentials: Option<Credentials>,
    shutdown: CancellationToken,
) -> Result<(), ConverterError> {
    config.check()?;
    ip_path_secured(&config.ip, ip_credentials.is_some())?;
    let (link, mut events) = start_link(driver, &config.link, config.time_scale, &shutdown)?;
    let mut vdt = Vdt::new(config, &dds, link)?;
    vdt.ip_credentials = ip_credentials;
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
    let ip_enabled = vdt.cfg.ip.enabled;
    let mut failover_tick = tokio::time::interval(wall(FAILOVER_POLL_S, scale));
    failover_tick.set_missed_tick_behavior(MissedTickBehavior::Delay);
    // The station's tasks over IP, while the IP side is open (taken from it after each
    // step, dropped with it).
    let mut ip_tasks: Option<Subscription<TaskAssignment>> = None;
    let mut ip_opened = vdt.take_ip_opened();
    // The first tick of an interval fires at once; announcements are sent on arrival.
    announce_tick.tick().await;
    info!(
        vehicles = ?vdt.served.iter().map(|s| &s.id).collect::<Vec<_>>(),
        cdt = vdt.cfg.cdt_address,
        delta = vdt.delta_coding,
        ip = ip_enabled,
        "VDT running"
    );
    loop {
        let step: Result<(), ConverterError> = tokio::select! {
            () = shutdown.cancelled() => break,
            Some(item) = next_opt(&mut states) => match sample(item) {
                Some(s) => vdt.on_state(s.into_inner()).await,
                None => Ok(()),
            },
            Some(item) = next_opt(&mut ip_tasks) => match sample(item) {
                Some(t) => vdt.on_ip_task(t.into_inner()).await,
                None => Ok(()),
            },
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
            _ = failover_tick.tick(), if ip_enabled => vdt.on_failover_tick().await,
            Some(opened) = ip_opened.recv() => {
                vdt.on_ip_opened(opened);
                Ok(())
            }
        };
        if vdt.ip_changed {
            vdt.ip_changed = false;
            let new = vdt.ip.as_mut().and_then(|ip| ip.tasks.take());
            if let Some(old) = std::mem::replace(&mut ip_tasks, new) {
                // Deleting DDS entities may wait for acknowledgements: not on this loop.
                tokio::task::spawn_blocking(move || drop(old));
            }
        }
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
    /// Which link the data uses (acoustic only without `[vdt.ip]`).
    failover: Failover,
    /// The IP path's participant, while the radio can work.
    ip: Option<IpSide>,
    /// `ip` was opened or closed: the run loop takes (or drops) its task subscription.
    ip_changed: bool,
    /// The radio works at the vehicle's latest depth.
    radio_up: bool,
    /// An IP side is being opened (off the loop: creating a participant takes a while).
    opening: bool,
    /// Where an opened IP side comes back, and the run loop's end of it.
    ip_opened_tx: tokio::sync::mpsc::Sender<Result<IpSide, ConverterError>>,
    /// The vehicle's DDS Security credentials for the IP participant (`None`: insecure,
    /// allowed only with `ip.insecure`).
    ip_credentials: Option<Credentials>,
    ip_opened_rx: Option<tokio::sync::mpsc::Receiver<Result<IpSide, ConverterError>>>,
    /// Tasks handed to the vehicle, (task id, issue sequence), newest last, by either
    /// link: the station's transient-local history brings them again each time the IP
    /// side opens, and the CDT sends acoustically those a vehicle took over IP and had not
    /// ended when it dived. Only spares the vehicle's bus; its ledger is what keeps a task
    /// from running twice.
    handed: VecDeque<(String, u64)>,
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
        let cfg_timing = cfg.ip.timing(cfg.time_scale);
        let (ip_opened_tx, ip_opened_rx) = tokio::sync::mpsc::channel(1);
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
            failover: Failover::new(cfg_timing, Instant::now()),
            ip: None,
            ip_changed: false,
            radio_up: false,
            opening: false,
            ip_opened_tx,
            ip_credentials: None,
            ip_opened_rx: Some(ip_opened_rx),
            handed: VecDeque::new(),
        })
    }

    /// True while the data goes over IP.
    fn on_ip(&self) -> bool {
        self.failover.link() == LinkKind::Ip && self.ip.is_some()
    }

    /// The radio as the vehicle's depth allows it: opens the IP side at the surface,
    /// closes it below `radio_max_depth_m` (and falls back to acoustic at once: the path is
    /// gone for certain).
    async fn radio(&mut self, depth_m: f64) -> Result<(), ConverterError> {
        let ip = &self.cfg.ip;
        if !ip.enabled {
            return Ok(());
        }
        let up = ip.radio_max_depth_m.is_none_or(|d| depth_m <= d);
        self.radio_up = up;
        if up && self.ip.is_none() {
            self.open_ip();
        } else if !up && let Some(side) = self.ip.take() {
            self.ip_changed = true;
            info!(depth_m, "radio under water: IP participant closed");
            // Deleting writers waits for their acknowledgements: not on this loop.
            tokio::task::spawn_blocking(move || drop(side));
            self.failover.ip_down(Instant::now());
            self.poll_failover().await?;
        }
        Ok(())
    }

    /// The receiver of opened IP sides, for the run loop (once).
    fn take_ip_opened(&mut self) -> tokio::sync::mpsc::Receiver<Result<IpSide, ConverterError>> {
        self.ip_opened_rx
            .take()
            .unwrap_or_else(|| tokio::sync::mpsc::channel(1).1)
    }

    /// Opens the IP side off the loop (a participant takes a while to create); it comes
    /// back to [`Self::on_ip_opened`].
    fn open_ip(&mut self) {
        if self.opening {
            return;
        }
        self.opening = true;
        let cfg = self.cfg.ip.clone();
        let credentials = self.ip_credentials.clone();
        let tx = self.ip_opened_tx.clone();
        tokio::task::spawn_blocking(move || {
            // The loop may have stopped meanwhile; the side is dropped then.
            let _ = tx.blocking_send(IpSide::open(&cfg, credentials));
        });
    }

    fn on_ip_opened(&mut self, opened: Result<IpSide, ConverterError>) {
        self.opening = false;
        match opened {
            // The vehicle dived while it opened: the radio is gone again.
            Ok(side) if !self.radio_up || self.ip.is_some() => {
                tokio::task::spawn_blocking(move || drop(side));
            }
            Ok(side) => {
                info!(participant = %side.participant, domain = self.cfg.ip.domain_id, "IP participant opened");
                self.ip = Some(side);
                self.ip_changed = true;
            }
            Err(e) => warn!(error = %e, "IP participant could not be opened; staying acoustic"),
        }
    }

    /// Feeds the failover what the IP path shows now, and acts on its decision.
    async fn on_failover_tick(&mut self) -> Result<(), ConverterError> {
        if self.cfg.ip.radio_max_depth_m.is_none() && self.ip.is_none() {
            self.radio_up = true;
            self.open_ip();
        }
        // A station reader matched to our state writer: discovery crossed the path both
        // ways, and the match ends when the station's lease runs out.
        let readers = self.ip.as_ref().map_or(0, |ip| ip.state.matched_readers());
        let readers = usize::try_from(readers).unwrap_or(0);
        if readers > 0 {
            if readers != self.failover.readers() {
                debug!(
                    readers,
                    "IP path: station readers matched to the state writer"
                );
            }
            self.failover.heard_ip(Instant::now(), readers);
        }
        self.poll_failover().await
    }

    async fn poll_failover(&mut self) -> Result<(), ConverterError> {
        let Some(sw) = self.failover.poll(Instant::now()) else {
            return Ok(());
        };
        if sw.to == LinkKind::Ip {
            self.switched_to_ip(sw).await;
            Ok(())
        } else {
            self.switched_to_acoustic(sw).await
        }
    }

    /// Now on IP: tells the station (link status and a switch event, over IP), announces
    /// the vehicles there, and sends the state that waited for the acoustic slot.
    async fn switched_to_ip(&mut self, sw: Switch) {
        let Some(ip) = &self.ip else {
            return;
        };
        let now = self.cfg.now_ms();
        let after = sw.after.as_secs_f64() / self.cfg.time_scale;
        for v in &mut self.served {
            info!(vehicle = %v.id, after_s = after, "link: IP (the station is heard over IP)");
            let status = LinkStatus {
                vehicle_id: v.id.clone(),
                link: LinkKind::Ip,
                cdt_address: self.cfg.cdt_address,
                vehicle_address: v.addr,
                rssi_db: None,
                integrity: None,
                heard_ms: now,
                participant: ip.participant.clone(),
                cdt_latitude_deg: None,
                cdt_longitude_deg: None,
                cdt_vehicle: None,
                frames: None,
                interval_s: None,
            };
            ip_write_failed("link status", ip.event.write(status.to_event()).await);
            let text = format!(
                "switched to the IP link after {after:.1} s on the acoustic link: the station is heard over IP"
            );
            let ev = switch_event(&v.id, LinkKind::Ip, now, text);
            ip_write_failed("switch event", ip.event.write(ev).await);
            if let Some(mut a) = v.announcement.clone() {
                a.timestamp_ms = now;
                ip_write_failed("announcement", ip.announcement.write(a).await);
            }
            // Not yet given to the acoustic link: it goes the new way, never both.
            if let Some(s) = v.pending_state.take() {
                ip_write_failed("state vector", ip.state.write(s).await);
            }
        }
    }

    /// Back on acoustic: announce at once, so the station learns the vehicle through the
    /// CDT again; the CDT tells the station of the switch when the first frame arrives.
    async fn switched_to_acoustic(&mut self, sw: Switch) -> Result<(), ConverterError> {
        let after = sw.after.as_secs_f64() / self.cfg.time_scale;
        for v in &self.served {
            info!(vehicle = %v.id, after_s = after, "link: acoustic (IP path lost)");
        }
        self.reannounce().await
    }

    /// Notes that `t` is handed to the vehicle now; false if it was already.
    fn hand_over(&mut self, t: &TaskAssignment) -> bool {
        let key = (t.task_id.clone(), t.issue_seq);
        if self.handed.contains(&key) {
            return false;
        }
        self.handed.push_back(key);
        while self.handed.len() > TASK_MEMORY {
            self.handed.pop_front();
        }
        true
    }

    /// A task from the station over IP: handed to the vehicle as an acoustic one would be.
    /// The vehicle's ledger refuses a copy that also came acoustically.
    async fn on_ip_task(&mut self, t: TaskAssignment) -> Result<(), ConverterError> {
        if !self.served.iter().any(|v| v.id == t.vehicle_id) {
            return Ok(());
        }
        if !self.hand_over(&t) {
            debug!(task = %t.task_id, "task over IP already handed to the vehicle");
            return Ok(());
        }
        info!(vehicle = %t.vehicle_id, task = %t.task_id, seq = t.issue_seq, "task over IP handed to the vehicle");
        let writer = if t.kind == TaskKind::Abort {
            &self.abort_writer
        } else {
            &self.task_writer
        };
        let id = t.task_id.clone();
        if let Err(e) = writer.write(t).await {
            warn!(task = %id, error = %e, "task not published on the vehicle's DDS");
        }
        Ok(())
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

    async fn on_state(&mut self, s: StateVector) -> Result<(), ConverterError> {
        if self.served_mut(&s.vehicle_id).is_none() {
            return Ok(());
        }
        // The radio first: a state reported below the surface does not go over IP.
        self.radio(s.depth_m).await?;
        if self.on_ip()
            && let Some(ip) = &self.ip
        {
            ip_write_failed("state vector", ip.state.write(s).await);
            return Ok(());
        }
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
        Ok(())
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
        if self.on_ip()
            && let Some(ip) = &self.ip
        {
            ip_write_failed("announcement", ip.announcement.write(a).await);
            return Ok(());
        }
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
        if self.on_ip() {
            // The vehicle's own announcements cross over IP; nothing redundant on the water.
            return Ok(());
        }
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
        if self.on_ip()
            && let Some(ip) = &self.ip
        {
            ip_write_failed("task status", ip.status.write(s.clone()).await);
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
        if self.on_ip()
            && let Some(ip) = &self.ip
        {
            let w = if e.severity >= Severity::Alarm {
                &ip.alarm
            } else {
                &ip.event
            };
            ip_write_failed("event", w.write(e.clone()).await);
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
        if self.served_mut(&o.vehicle_id).is_some()
            && self.on_ip()
            && let Some(ip) = &self.ip
        {
            // No rate limit over IP: the acoustic one exists for the channel's sake.
            ip_write_failed("observation", ip.environment.write(o.clone()).await);
            return Ok(());
        }
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
        if !self.hand_over(&assignment) {
            // Taken over IP before the vehicle dived: the CDT sent it so that its status
            // can come back with this task number, which is now known.
            debug!(vehicle = %vehicle_id, task = %task_id, "acoustic task already handed over IP");
            return Ok(());
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_ip_path_without_credentials_is_refused_unless_insecure_is_meant() {
        let mut ip = IpPathConfig::default();
        assert!(ip_path_secured(&ip, false).is_ok(), "off needs nothing");
        ip.enabled = true;
        let e = ip_path_secured(&ip, false).unwrap_err().to_string();
        assert!(
            e.contains("vdt.ip.insecure") && e.contains("credentials"),
            "{e}"
        );
        assert!(ip_path_secured(&ip, true).is_ok());
        ip.insecure = true;
        assert!(ip_path_secured(&ip, false).is_ok());
    }
}
