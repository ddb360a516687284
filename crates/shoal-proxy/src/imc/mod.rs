//! The IMC proxy: a vehicle running LSTS DUNE (or anything else speaking IMC), reached by
//! static unicast UDP.
//!
//! [`ImcAdapter::bind`] opens a UDP socket and runs a link task that:
//!
//! - sends the vehicle a `Heartbeat` every second and an `Announce` (this proxy as a CCU,
//!   with its `imc+udp://` service) every ten, so DUNE's UDP transport learns where to send;
//! - decodes every datagram ([`codec`]): `EstimatedState` (+ `FuelLevel`) become the state
//!   vector, `VehicleState` errors and `LogBookEntry` errors/warnings become events,
//!   `PlanControl` replies and `PlanControlState` become task updates. Bad packets (sync,
//!   CRC, unknown ids, malformed fields, out-of-range values) are counted
//!   ([`ImcAdapter::counters`]) and dropped;
//! - reports the link lost (a `comm_lost` alarm) when the vehicle is silent for
//!   [`ImcConfig::lost_after_ms`], and restored when it speaks again.
//!
//! Tasks become IMC plans: `goto` a one-`Goto` plan, `survey_area` a lawnmower of `Goto`s
//! chained by `ManeuverIsDone` transitions, `hold` a `StationKeeping`, `surface` a `Goto`
//! to the current position at depth 0, `return_home` a `Goto` to where the proxy first
//! heard the vehicle, each started with `PlanControl` (request, start, the plan inline).
//! `abort` sends `Abort`. The plan id is the task id, so `PlanControlState` tells which
//! task is running, its progress and its outcome. A vehicle runs one plan at a time: a new
//! plan supersedes the running one, which is reported `aborted`.
//!
//! Only unicast: the proxy never joins IMC's multicast discovery. DUNE must be told this
//! proxy's address (its `Transports.UDP` static destinations, or our `Announce`).

pub mod codec;
pub mod mapping;

use std::net::SocketAddr;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use serde::{Deserialize, Serialize};
use shoal_model::{
    EventKind, GeoPoint, LinkKind, Severity, StateVector, Task, TaskKind, TaskState, Validate,
    VehicleAnnouncement, VehicleKind, now_ms,
};
use tokio::net::UdpSocket;
use tokio::sync::mpsc;
use tokio::task::JoinHandle;
use tokio::time::{Instant, MissedTickBehavior};
use tracing::{debug, info, warn};

use crate::adapter::{
    Acceptance, Refusal, TaskOrder, VehicleAdapter, VehicleOutput, capability_of,
};
use crate::link::{Liveness, Outputs, bump};
use crate::sim::{distance, lawnmower};
use codec::{
    ANY_ENTITY, ANY_SYSTEM, Announce, DecodeError, Header, Message, Packet, PlanControl,
    PlanManeuver, PlanSpecification, PlanTransition, op_mode, plan_control, plan_state,
};

/// Largest UDP payload (IPv4).
const MAX_DATAGRAM: usize = 65_507;
/// `SystemType` of a CCU, as this proxy announces itself.
const SYSTEM_CCU: u8 = 0;
/// How often silence and unanswered requests are checked.
const WATCH_EVERY: Duration = Duration::from_millis(200);
/// Least progress change worth a report, percent.
const PROGRESS_STEP: f64 = 1.0;

/// How to reach an IMC vehicle; the `[proxy.imc]` section a CLI would read.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ImcConfig {
    /// Shoal vehicle id the proxy announces.
    pub vehicle_id: String,
    /// Human-readable name.
    pub name: String,
    /// Kind of vehicle.
    pub kind: VehicleKind,
    /// Vendor or integrator.
    pub vendor: String,
    /// Maximum speed, m/s (announced; used by the station's plausibility checks).
    pub max_speed_mps: f64,
    /// Local UDP address to receive on (port 0: any free port).
    pub bind: SocketAddr,
    /// The vehicle's IMC UDP address (DUNE's `Transports.UDP` port, 6002 by default).
    pub vehicle: SocketAddr,
    /// This proxy's IMC system id.
    pub imc_id: u16,
    /// The vehicle's IMC system id; `None` takes the first system that announces itself as
    /// a vehicle or sends a navigation state.
    pub vehicle_imc_id: Option<u16>,
    /// Heartbeat period, ms (DUNE expects a CCU's heartbeat about every second).
    pub heartbeat_interval_ms: u64,
    /// Silence after which the link is reported lost, ms.
    pub lost_after_ms: u64,
    /// How long to wait for the reply to a plan request or the end of an abort, ms.
    pub reply_timeout_ms: u64,
    /// Requests sent before giving up on a reply.
    pub attempts: u32,
    /// Speed for tasks that leave it to the vehicle (speed 0), m/s.
    pub default_speed_mps: f64,
    /// Radius of `StationKeeping` for `hold` tasks, m.
    pub hold_radius_m: f64,
}

impl Default for ImcConfig {
    fn default() -> Self {
        Self {
            vehicle_id: "imc-1".into(),
            name: "IMC vehicle".into(),
            kind: VehicleKind::Auv,
            vendor: "LSTS DUNE".into(),
            max_speed_mps: 2.5,
            bind: SocketAddr::from(([127, 0, 0, 1], 6001)),
            vehicle: SocketAddr::from(([127, 0, 0, 1], 6002)),
            imc_id: 0x4100,
            vehicle_imc_id: None,
            heartbeat_interval_ms: 1000,
            lost_after_ms: 5000,
            reply_timeout_ms: 2000,
            attempts: 3,
            default_speed_mps: 1.2,
            hold_radius_m: 10.0,
        }
    }
}

/// Why the IMC adapter cannot start or goes on no more.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ImcError {
    /// The configuration cannot work.
    #[error("invalid IMC configuration: {0}")]
    Config(String),
    /// The UDP socket could not be opened.
    #[error("cannot bind IMC UDP socket {addr}: {source}")]
    Bind {
        /// The address.
        addr: SocketAddr,
        /// The system's error.
        #[source]
        source: std::io::Error,
    },
    /// The link task ended (it only does when the socket fails for good).
    #[error("the IMC link stopped: {0}")]
    LinkStopped(String),
}

crate::link::link_counters! {
    /// What the link has seen so far; a snapshot from [`ImcAdapter::counters`].
    pub struct ImcCounters {
        /// Datagrams received.
        datagrams,
        /// Packets decoded and used.
        packets,
        /// Bytes skipped looking for a synchronisation number.
        garbage_bytes,
        /// Packets cut short.
        truncated,
        /// Packets whose CRC did not match.
        bad_crc,
        /// Well-formed packets with a message id the proxy does not use.
        unknown_message,
        /// Packets whose fields did not fit their message.
        malformed,
        /// Messages whose values were out of range (e.g. latitude beyond 90°).
        out_of_range,
        /// Packets from other IMC systems or addressed to others.
        foreign,
        /// Packets sent.
        sent,
        /// Packets that could not be sent.
        send_errors,
    }
}

/// What the adapter and the link task share: the latest telemetry and the link's health.
#[derive(Debug, Default)]
struct Shared {
    /// Last valid navigation, battery left at 0 (it comes from `FuelLevel`).
    nav: Option<StateVector>,
    battery_pct: Option<f64>,
    /// Where the vehicle was first heard: `return_home` goes there.
    home: Option<GeoPoint>,
    heard: bool,
    lost: bool,
    op_mode: Option<u8>,
    last_error: String,
    plan_engine: Option<u8>,
}

fn lock(shared: &Mutex<Shared>) -> std::sync::MutexGuard<'_, Shared> {
    // The data is plain values, always consistent between statements: a panic elsewhere
    // cannot leave it half-written, so a poisoned lock is still usable.
    shared.lock().unwrap_or_else(PoisonError::into_inner)
}

/// What the adapter asks of the link task.
#[derive(Debug)]
enum Command {
    /// Start a plan for a task.
    Plan {
        task_id: String,
        plan: Box<PlanSpecification>,
    },
    /// Stop everything.
    Abort { task_id: String },
}

/// An IMC vehicle behind a DDS Proxy.
#[derive(Debug)]
pub struct ImcAdapter {
    config: ImcConfig,
    shared: Arc<Mutex<Shared>>,
    counters: Arc<Counters>,
    commands: mpsc::Sender<Command>,
    outputs: mpsc::Receiver<VehicleOutput>,
    link: JoinHandle<Result<(), ImcError>>,
    local: SocketAddr,
}

impl Drop for ImcAdapter {
    fn drop(&mut self) {
        self.link.abort();
    }
}

impl ImcAdapter {
    /// Opens the UDP socket and starts talking to the vehicle.
    pub async fn bind(config: ImcConfig) -> Result<Self, ImcError> {
        check(&config)?;
        let socket = UdpSocket::bind(config.bind)
            .await
            .map_err(|source| ImcError::Bind {
                addr: config.bind,
                source,
            })?;
        let local = socket.local_addr().map_err(|source| ImcError::Bind {
            addr: config.bind,
            source,
        })?;
        info!(vehicle = %config.vehicle_id, %local, remote = %config.vehicle, "IMC link open");
        let shared = Arc::new(Mutex::new(Shared::default()));
        let counters = Arc::new(Counters::default());
        let (commands, command_rx) = mpsc::channel(crate::adapter::COMMAND_QUEUE);
        let (output_tx, outputs) = Outputs::channel(Arc::clone(&counters.outputs_dropped));
        let link = Link {
            config: config.clone(),
            socket,
            local,
            shared: Arc::clone(&shared),
            counters: Arc::clone(&counters),
            outputs: output_tx,
            vehicle_imc_id: config.vehicle_imc_id,
            liveness: Liveness::new(config.lost_after_ms),
            plan: None,
            abort: None,
            next_request: 1,
        };
        let link = tokio::spawn(link.run(command_rx));
        Ok(Self {
            config,
            shared,
            counters,
            commands,
            outputs,
            link,
            local,
        })
    }

    /// The local UDP address the proxy receives on.
    pub fn local_addr(&self) -> SocketAddr {
        self.local
    }

    /// Packet and error counts so far.
    pub fn counters(&self) -> ImcCounters {
        self.counters.snapshot()
    }

    /// True while the vehicle is heard (it spoke within `lost_after_ms`).
    pub fn is_connected(&self) -> bool {
        let s = lock(&self.shared);
        s.heard && !s.lost
    }

    fn position(&self) -> Result<(GeoPoint, f64), Refusal> {
        let s = lock(&self.shared);
        let nav = s
            .nav
            .as_ref()
            .ok_or_else(|| Refusal::new("no navigation state from the vehicle yet"))?;
        Ok((
            GeoPoint {
                latitude_deg: nav.latitude_deg,
                longitude_deg: nav.longitude_deg,
            },
            nav.depth_m,
        ))
    }

    fn speed(&self, requested: f64) -> f64 {
        if requested > 0.0 {
            requested
        } else {
            self.config.default_speed_mps
        }
    }

    /// Seconds a `Goto` may take: three times the straight run plus a minute, so a
    /// current or a detour does not time it out, while a stuck vehicle does.
    fn goto_timeout(&self, target: GeoPoint, speed: f64) -> u16 {
        let from = lock(&self.shared).nav.as_ref().map(|n| GeoPoint {
            latitude_deg: n.latitude_deg,
            longitude_deg: n.longitude_deg,
        });
        match from {
            Some(from) => mapping::seconds_u16(3.0 * distance(from, target) / speed + 60.0),
            None => u16::MAX,
        }
    }

    /// The IMC plan for a moving task.
    fn plan_for(&self, order: &TaskOrder) -> Result<(PlanSpecification, String), Refusal> {
        let one = |m: Message| vec![m];
        let (maneuvers, note) = match &order.task {
            Task::GotoWaypoint {
                target,
                depth_m,
                altitude_m,
                speed_mps,
            } => {
                let speed = self.speed(*speed_mps);
                let g = mapping::goto(
                    *target,
                    mapping::z_of(*depth_m, *altitude_m),
                    speed,
                    self.goto_timeout(*target, speed),
                );
                (one(Message::Goto(g)), "Goto".to_string())
            }
            Task::SurveyArea {
                polygon,
                line_spacing_m,
                depth_m,
                altitude_m,
                speed_mps,
            } => {
                let points = lawnmower(polygon, *line_spacing_m)
                    .map_err(|e| Refusal::new(format!("no survey pattern: {e}")))?;
                if points.is_empty() {
                    return Err(Refusal::new("the survey polygon gives no survey lines"));
                }
                let speed = self.speed(*speed_mps);
                let z = mapping::z_of(*depth_m, *altitude_m);
                let mut prev: Option<GeoPoint> = None;
                let mut gotos = Vec::with_capacity(points.len());
                for p in &points {
                    // Each leg times out on its own length, the first from where the
                    // vehicle is now.
                    let timeout = match prev {
                        Some(a) => mapping::seconds_u16(3.0 * distance(a, *p) / speed + 60.0),
                        None => self.goto_timeout(*p, speed),
                    };
                    gotos.push(Message::Goto(mapping::goto(*p, z, speed, timeout)));
                    prev = Some(*p);
                }
                let n = gotos.len();
                (gotos, format!("lawnmower of {n} Goto maneuvers"))
            }
            Task::Hold { duration_s } => {
                let (here, depth) = self.position()?;
                let sk = mapping::station_keeping(
                    here,
                    depth,
                    self.config.hold_radius_m,
                    *duration_s,
                    self.config.default_speed_mps,
                );
                (one(Message::StationKeeping(sk)), "StationKeeping".into())
            }
            Task::Surface => {
                let (here, _) = self.position()?;
                let speed = self.config.default_speed_mps;
                let g = mapping::goto(
                    here,
                    mapping::z_of(Some(0.0), None),
                    speed,
                    self.goto_timeout(here, speed),
                );
                (one(Message::Goto(g)), "Goto to the surface".into())
            }
            Task::ReturnHome => {
                let home = lock(&self.shared).home.ok_or_else(|| {
                    Refusal::new("no home position: the vehicle was never located")
                })?;
                let speed = self.config.default_speed_mps;
                let g = mapping::goto(
                    home,
                    mapping::z_of(Some(0.0), None),
                    speed,
                    self.goto_timeout(home, speed),
                );
                (one(Message::Goto(g)), "Goto home at the surface".into())
            }
            Task::Abort | Task::RequestState | Task::SetReportingRate { .. } => {
                return Err(Refusal::new("not a plan task"));
            }
        };
        Ok((plan_of(&order.task_id, maneuvers), note))
    }
}

/// A plan running `maneuvers` in order, each starting when the previous is done.
pub fn plan_of(plan_id: &str, maneuvers: Vec<Message>) -> PlanSpecification {
    let n = maneuvers.len();
    let name = |i: usize| (i + 1).to_string();
    PlanSpecification {
        plan_id: plan_id.to_string(),
        description: "Shoal task".into(),
        vnamespace: String::new(),
        variables: Vec::new(),
        start_man_id: name(0),
        maneuvers: maneuvers
            .into_iter()
            .enumerate()
            .map(|(i, m)| PlanManeuver {
                maneuver_id: name(i),
                data: Some(Box::new(m)),
                start_actions: Vec::new(),
                end_actions: Vec::new(),
            })
            .collect(),
        transitions: (1..n)
            .map(|i| PlanTransition {
                source_man: name(i - 1),
                dest_man: name(i),
                conditions: "ManeuverIsDone".into(),
                actions: Vec::new(),
            })
            .collect(),
        start_actions: Vec::new(),
        end_actions: Vec::new(),
    }
}

fn check(c: &ImcConfig) -> Result<(), ImcError> {
    let announcement = announcement_of(c);
    let mut a = announcement;
    a.timestamp_ms = now_ms();
    a.validate()
        .map_err(|e| ImcError::Config(format!("the vehicle cannot be announced: {e}")))?;
    if c.heartbeat_interval_ms == 0 || c.lost_after_ms == 0 || c.reply_timeout_ms == 0 {
        return Err(ImcError::Config(
            "heartbeat_interval_ms, lost_after_ms and reply_timeout_ms must be positive".into(),
        ));
    }
    if c.attempts == 0 {
        return Err(ImcError::Config("attempts must be at least 1".into()));
    }
    if !(c.default_speed_mps > 0.0 && c.default_speed_mps <= 30.0) {
        return Err(ImcError::Config(
            "default_speed_mps must be in (0, 30]".into(),
        ));
    }
    if !(c.hold_radius_m > 0.0 && c.hold_radius_m.is_finite()) {
        return Err(ImcError::Config("hold_radius_m must be positive".into()));
    }
    if c.vehicle_imc_id == Some(c.imc_id) {
        return Err(ImcError::Config(
            "imc_id and vehicle_imc_id must differ".into(),
        ));
    }
    Ok(())
}

fn announcement_of(c: &ImcConfig) -> VehicleAnnouncement {
    VehicleAnnouncement {
        vehicle_id: c.vehicle_id.clone(),
        name: c.name.clone(),
        kind: c.kind,
        vendor: c.vendor.clone(),
        capabilities: [
            TaskKind::GotoWaypoint,
            TaskKind::SurveyArea,
            TaskKind::Hold,
            TaskKind::Surface,
            TaskKind::ReturnHome,
            TaskKind::Abort,
        ]
        .into_iter()
        .map(|k| capability_of(k).to_string())
        .collect(),
        sensors: Vec::new(),
        links: vec![LinkKind::Ip],
        max_speed_mps: c.max_speed_mps,
        timestamp_ms: 0,
    }
}

impl VehicleAdapter for ImcAdapter {
    type Error = ImcError;

    fn announcement(&self) -> VehicleAnnouncement {
        announcement_of(&self.config)
    }

    fn state(&mut self) -> Option<StateVector> {
        let s = lock(&self.shared);
        if s.lost {
            // A stale fix repeated as if new would hide the silence from the station.
            return None;
        }
        let mut v = s.nav.clone()?;
        v.battery_pct = s.battery_pct?;
        Some(v)
    }

    async fn next_output(&mut self) -> Result<VehicleOutput, ImcError> {
        match self.outputs.recv().await {
            Some(out) => Ok(out),
            None => Err(ImcError::LinkStopped(
                "the link task ended; see the log for why".into(),
            )),
        }
    }

    async fn submit(&mut self, order: TaskOrder) -> Result<Acceptance, Refusal> {
        let command = if matches!(order.task, Task::Abort) {
            // Sent whatever the link looks like: an abort that might arrive beats none.
            Command::Abort {
                task_id: order.task_id,
            }
        } else {
            {
                let s = lock(&self.shared);
                if !s.heard || s.lost {
                    return Err(Refusal::new("no contact with the vehicle over IMC"));
                }
                if s.op_mode == Some(op_mode::ERROR) {
                    return Err(Refusal::new(format!(
                        "vehicle in ERROR mode: {}",
                        s.last_error
                    )));
                }
                if s.plan_engine == Some(plan_state::BLOCKED) {
                    return Err(Refusal::new("the vehicle's plan engine is blocked"));
                }
            }
            let (plan, note) = self.plan_for(&order)?;
            // The plan goes in one datagram: refuse what cannot.
            let size = codec::encode(&Packet {
                header: header(0, 0, 0),
                message: Message::PlanControl(PlanControl {
                    arg: Some(Box::new(Message::PlanSpecification(plan.clone()))),
                    ..PlanControl::default()
                }),
            })
            .map_err(|e| Refusal::new(format!("the plan cannot be encoded: {e}")))?
            .len();
            if size > MAX_DATAGRAM {
                return Err(Refusal::new(format!(
                    "the plan takes {size} bytes, more than one UDP datagram"
                )));
            }
            debug!(task = %order.task_id, %note, "IMC plan built");
            Command::Plan {
                task_id: order.task_id,
                plan: Box::new(plan),
            }
        };
        let note = match &command {
            Command::Abort { .. } => "Abort sent".to_string(),
            Command::Plan { plan, .. } => {
                format!("IMC plan of {} maneuvers sent", plan.maneuvers.len())
            }
        };
        self.commands
            .try_send(command)
            .map_err(|e| crate::adapter::queue_refusal("IMC", &e))?;
        Ok(Acceptance::with_message(note))
    }
}

fn header(src: u16, dst: u16, timestamp_ms: i64) -> Header {
    #[allow(clippy::cast_precision_loss)]
    let timestamp = timestamp_ms as f64 / 1000.0;
    Header {
        timestamp,
        src,
        src_ent: ANY_ENTITY,
        dst,
        dst_ent: ANY_ENTITY,
    }
}

/// A plan sent for a task, until its outcome.
#[derive(Debug)]
struct LivePlan {
    task_id: String,
    request_id: u16,
    packet: Vec<u8>,
    sent_at: Instant,
    attempts: u32,
    /// The vehicle replied `SUCCESS` or was seen executing it.
    confirmed: bool,
    last_progress: f64,
}

/// An abort sent, until the vehicle shows it stopped.
#[derive(Debug)]
struct LiveAbort {
    task_id: String,
    sent_at: Instant,
    attempts: u32,
}

/// The task that owns the socket.
struct Link {
    config: ImcConfig,
    socket: UdpSocket,
    local: SocketAddr,
    shared: Arc<Mutex<Shared>>,
    counters: Arc<Counters>,
    outputs: Outputs,
    vehicle_imc_id: Option<u16>,
    liveness: Liveness,
    plan: Option<LivePlan>,
    abort: Option<LiveAbort>,
    next_request: u16,
}

impl Link {
    async fn run(mut self, mut commands: mpsc::Receiver<Command>) -> Result<(), ImcError> {
        let mut buf = vec![0u8; MAX_DATAGRAM];
        let mut heartbeat =
            tokio::time::interval(Duration::from_millis(self.config.heartbeat_interval_ms));
        heartbeat.set_missed_tick_behavior(MissedTickBehavior::Delay);
        let mut watch = tokio::time::interval(WATCH_EVERY);
        watch.set_missed_tick_behavior(MissedTickBehavior::Delay);
        let mut beats: u64 = 0;
        loop {
            tokio::select! {
                received = self.socket.recv_from(&mut buf) => match received {
                    Ok((n, from)) => self.on_datagram(&buf[..n], from),
                    Err(e) => {
                        // UDP receive errors are transient (an ICMP error for an earlier
                        // send); pausing keeps a persistent one from spinning.
                        debug!(error = %e, "IMC receive error");
                        tokio::time::sleep(Duration::from_millis(100)).await;
                    }
                },
                command = commands.recv() => match command {
                    Some(c) => self.on_command(c).await,
                    // The adapter is gone: nothing left to do.
                    None => return Ok(()),
                },
                _ = heartbeat.tick() => {
                    self.send(Message::Heartbeat).await;
                    if beats.is_multiple_of(10) {
                        let announce = self.announce();
                        self.send(announce).await;
                    }
                    beats += 1;
                }
                _ = watch.tick() => self.on_watch().await,
            }
        }
    }

    fn announce(&self) -> Message {
        Message::Announce(Announce {
            sys_name: format!("shoal-{}", self.config.vehicle_id),
            sys_type: SYSTEM_CCU,
            owner: ANY_SYSTEM,
            lat: 0.0,
            lon: 0.0,
            height: 0.0,
            services: format!("imc+udp://{}/", self.local),
        })
    }

    async fn send(&self, message: Message) {
        let name = message.name();
        let packet = Packet {
            header: header(
                self.config.imc_id,
                self.vehicle_imc_id.unwrap_or(ANY_SYSTEM),
                now_ms(),
            ),
            message,
        };
        match codec::encode(&packet) {
            Ok(bytes) => self.send_bytes(&bytes, name).await,
            Err(e) => {
                bump(&self.counters.send_errors);
                warn!(message = name, error = %e, "IMC message not encodable");
            }
        }
    }

    async fn send_bytes(&self, bytes: &[u8], name: &str) {
        match self.socket.send_to(bytes, self.config.vehicle).await {
            Ok(_) => bump(&self.counters.sent),
            Err(e) => {
                bump(&self.counters.send_errors);
                debug!(message = name, error = %e, "IMC send failed");
            }
        }
    }

    fn on_datagram(&mut self, mut bytes: &[u8], from: SocketAddr) {
        bump(&self.counters.datagrams);
        while !bytes.is_empty() {
            match codec::decode(bytes) {
                Ok((packet, _, used)) => {
                    bytes = &bytes[used..];
                    self.on_packet(packet, from);
                }
                Err(e) => {
                    let skip = match &e {
                        DecodeError::BadSync(_) => {
                            let skip = codec::resync(bytes);
                            self.counters
                                .garbage_bytes
                                .fetch_add(skip as u64, Ordering::Relaxed);
                            skip
                        }
                        DecodeError::Truncated { .. } => {
                            bump(&self.counters.truncated);
                            bytes.len()
                        }
                        DecodeError::BadCrc { .. } => {
                            bump(&self.counters.bad_crc);
                            codec::resync(bytes)
                        }
                        DecodeError::UnknownMessage(_) => {
                            bump(&self.counters.unknown_message);
                            codec::resync(bytes)
                        }
                        _ => {
                            bump(&self.counters.malformed);
                            codec::resync(bytes)
                        }
                    };
                    debug!(%from, error = %e, "IMC packet dropped");
                    bytes = &bytes[skip..];
                }
            }
        }
    }

    /// Whether a packet comes from the vehicle (adopting it if none is known yet).
    fn accept_source(&mut self, p: &Packet) -> bool {
        let h = &p.header;
        if h.src == self.config.imc_id {
            return false;
        }
        if h.dst != ANY_SYSTEM && h.dst != self.config.imc_id {
            return false;
        }
        match self.vehicle_imc_id {
            Some(id) => h.src == id,
            None => {
                let vehicle_like = match &p.message {
                    Message::Announce(a) => a.sys_type != SYSTEM_CCU,
                    Message::EstimatedState(_) => true,
                    _ => false,
                };
                if vehicle_like {
                    info!(
                        imc_id = format!("0x{:04X}", h.src),
                        "IMC vehicle identified"
                    );
                    self.vehicle_imc_id = Some(h.src);
                }
                vehicle_like
            }
        }
    }

    fn on_packet(&mut self, p: Packet, from: SocketAddr) {
        if !self.accept_source(&p) {
            bump(&self.counters.foreign);
            debug!(%from, src = p.header.src, message = p.message.name(), "IMC packet from another system ignored");
            return;
        }
        bump(&self.counters.packets);
        self.heard();
        match p.message {
            Message::EstimatedState(es) => self.on_estimated_state(&es),
            Message::FuelLevel(f) => {
                let v = f64::from(f.value);
                if (0.0..=100.0).contains(&v) {
                    lock(&self.shared).battery_pct = Some(v);
                } else {
                    bump(&self.counters.out_of_range);
                }
            }
            Message::VehicleState(vs) => self.on_vehicle_state(&vs),
            Message::PlanControl(pc) => self.on_plan_control(&pc),
            Message::PlanControlState(pcs) => self.on_plan_state(&pcs),
            Message::LogBookEntry(l) => self.on_log(&l),
            Message::Announce(a) => debug!(name = %a.sys_name, "IMC vehicle announced"),
            _ => {}
        }
    }

    fn heard(&mut self) {
        let heard = self.liveness.heard();
        {
            let mut s = lock(&self.shared);
            s.heard = true;
            s.lost = false;
        }
        if let Some(silent) = heard.back_after {
            let silent = silent.as_secs_f64();
            info!(vehicle = %self.config.vehicle_id, "IMC link restored");
            self.outputs.event(
                Severity::Info,
                EventKind::CommLost,
                "",
                format!("IMC link restored after {silent:.1} s of silence"),
            );
        }
    }

    fn on_estimated_state(&mut self, es: &codec::EstimatedState) {
        let mut v = mapping::state_from(es, &self.config.vehicle_id, now_ms());
        // Validate with a placeholder battery: the battery is checked on its own message.
        v.battery_pct = 50.0;
        if let Err(e) = v.validate() {
            bump(&self.counters.out_of_range);
            debug!(error = %e, "IMC EstimatedState out of range dropped");
            return;
        }
        v.battery_pct = 0.0;
        let mut s = lock(&self.shared);
        if s.home.is_none() {
            s.home = Some(GeoPoint {
                latitude_deg: v.latitude_deg,
                longitude_deg: v.longitude_deg,
            });
        }
        s.nav = Some(v);
    }

    fn on_vehicle_state(&mut self, vs: &codec::VehicleState) {
        let previous = {
            let mut s = lock(&self.shared);
            s.last_error.clone_from(&vs.last_error);
            s.op_mode.replace(vs.op_mode)
        };
        if previous == Some(vs.op_mode) {
            return;
        }
        if vs.op_mode == op_mode::ERROR {
            let what = if vs.last_error.is_empty() {
                vs.error_ents.clone()
            } else {
                vs.last_error.clone()
            };
            self.outputs.event(
                Severity::Alarm,
                EventKind::Fault,
                "",
                format!("vehicle in ERROR mode: {what}"),
            );
        } else if previous == Some(op_mode::ERROR) {
            self.outputs.event(
                Severity::Info,
                EventKind::Fault,
                "",
                "vehicle left ERROR mode".into(),
            );
        }
    }

    fn on_plan_control(&mut self, pc: &PlanControl) {
        if pc.kind == plan_control::REQUEST {
            return;
        }
        let Some(plan) = self.plan.as_mut() else {
            return;
        };
        if pc.request_id != plan.request_id || pc.op != plan_control::START {
            return;
        }
        match pc.kind {
            plan_control::SUCCESS if !plan.confirmed => {
                plan.confirmed = true;
                let task = plan.task_id.clone();
                self.outputs.task(
                    &task,
                    TaskState::Running,
                    0.0,
                    "plan started by the vehicle",
                );
            }
            plan_control::FAILURE => {
                if let Some(plan) = self.plan.take() {
                    let why = if pc.info.is_empty() {
                        "no reason given".to_string()
                    } else {
                        pc.info.clone()
                    };
                    self.outputs.task(
                        &plan.task_id,
                        TaskState::Failed,
                        0.0,
                        &format!("the vehicle refused the plan: {why}"),
                    );
                }
            }
            _ => {}
        }
    }

    fn on_plan_state(&mut self, pcs: &codec::PlanControlState) {
        lock(&self.shared).plan_engine = Some(pcs.state);
        let running = matches!(pcs.state, plan_state::EXECUTING | plan_state::INITIALIZING);
        if !running && let Some(abort) = self.abort.take() {
            self.outputs.task(
                &abort.task_id,
                TaskState::Done,
                100.0,
                "the vehicle stopped",
            );
        }
        let Some(plan) = self.plan.as_mut() else {
            return;
        };
        let ours = pcs.plan_id == plan.task_id;
        if running && ours {
            let progress = f64::from(pcs.plan_progress);
            let first = !plan.confirmed;
            plan.confirmed = true;
            let moved = progress.is_finite()
                && progress >= 0.0
                && (progress - plan.last_progress).abs() >= PROGRESS_STEP;
            if first || moved {
                if moved {
                    plan.last_progress = progress;
                }
                let p = plan.last_progress;
                let task = plan.task_id.clone();
                self.outputs.task(&task, TaskState::Running, p, "executing");
            }
        } else if running && plan.confirmed {
            // Someone else (an operator console) started another plan over ours.
            if let Some(plan) = self.plan.take() {
                self.outputs.task(
                    &plan.task_id,
                    TaskState::Aborted,
                    plan.last_progress,
                    &format!("the vehicle is executing plan {:?} instead", pcs.plan_id),
                );
            }
        } else if !running
            && ours
            && plan.confirmed
            && let Some(plan) = self.plan.take()
        {
            let last_error = lock(&self.shared).last_error.clone();
            let (state, progress, message) = match pcs.last_outcome {
                plan_state::OUTCOME_SUCCESS => (TaskState::Done, 100.0, "plan completed".into()),
                plan_state::OUTCOME_FAILURE if !last_error.is_empty() => (
                    TaskState::Failed,
                    plan.last_progress,
                    format!("plan failed: {last_error}"),
                ),
                plan_state::OUTCOME_FAILURE => {
                    (TaskState::Failed, plan.last_progress, "plan failed".into())
                }
                _ => (
                    TaskState::Aborted,
                    plan.last_progress,
                    "plan stopped".into(),
                ),
            };
            self.outputs.task(&plan.task_id, state, progress, &message);
        }
    }

    fn on_log(&self, l: &codec::LogBookEntry) {
        let severity = match l.kind {
            1 => Severity::Warning,
            2 => Severity::Alarm,
            3 => Severity::Critical,
            _ => return,
        };
        let kind = if severity >= Severity::Alarm {
            EventKind::Fault
        } else {
            EventKind::Other
        };
        let text = if l.context.is_empty() {
            l.text.clone()
        } else {
            format!("{}: {}", l.context, l.text)
        };
        self.outputs.event(severity, kind, "", text);
    }

    async fn on_command(&mut self, command: Command) {
        match command {
            Command::Plan { task_id, plan } => {
                if let Some(old) = self.plan.take() {
                    self.outputs
                        .replaced(&old.task_id, old.last_progress, false, &task_id, false);
                }
                let request_id = self.next_request;
                self.next_request = self.next_request.wrapping_add(1);
                let message = Message::PlanControl(PlanControl {
                    kind: plan_control::REQUEST,
                    op: plan_control::START,
                    request_id,
                    plan_id: plan.plan_id.clone(),
                    flags: 0,
                    arg: Some(Box::new(Message::PlanSpecification(*plan))),
                    info: "Shoal".into(),
                });
                let packet = Packet {
                    header: header(
                        self.config.imc_id,
                        self.vehicle_imc_id.unwrap_or(ANY_SYSTEM),
                        now_ms(),
                    ),
                    message,
                };
                match codec::encode(&packet) {
                    Ok(bytes) => {
                        self.send_bytes(&bytes, "PlanControl").await;
                        info!(task = %task_id, request_id, "IMC plan start requested");
                        self.plan = Some(LivePlan {
                            task_id,
                            request_id,
                            packet: bytes,
                            sent_at: Instant::now(),
                            attempts: 1,
                            confirmed: false,
                            last_progress: 0.0,
                        });
                    }
                    Err(e) => self.outputs.task(
                        &task_id,
                        TaskState::Failed,
                        0.0,
                        &format!("the plan cannot be encoded: {e}"),
                    ),
                }
            }
            Command::Abort { task_id } => {
                self.send(Message::Abort).await;
                info!(task = %task_id, "IMC abort sent");
                if let Some(plan) = self.plan.take() {
                    self.outputs
                        .replaced(&plan.task_id, plan.last_progress, false, &task_id, true);
                }
                if let Some(old) = self.abort.take() {
                    self.outputs.task(
                        &old.task_id,
                        TaskState::Done,
                        100.0,
                        &format!("superseded by abort {task_id}"),
                    );
                }
                self.outputs
                    .task(&task_id, TaskState::Running, 0.0, "Abort sent");
                self.abort = Some(LiveAbort {
                    task_id,
                    sent_at: Instant::now(),
                    attempts: 1,
                });
            }
        }
    }

    async fn on_watch(&mut self) {
        if self.liveness.check() {
            let lost_after = self.liveness.lost_after();
            lock(&self.shared).lost = true;
            warn!(vehicle = %self.config.vehicle_id, "IMC link lost");
            self.outputs.event(
                Severity::Alarm,
                EventKind::CommLost,
                "",
                format!(
                    "no IMC message from the vehicle for {:.1} s: link lost",
                    lost_after.as_secs_f64()
                ),
            );
        }
        let timeout = Duration::from_millis(self.config.reply_timeout_ms);
        let attempts = self.config.attempts;
        let mut resend = None;
        if let Some(plan) = self.plan.as_mut()
            && !plan.confirmed
            && plan.sent_at.elapsed() > timeout
        {
            if plan.attempts < attempts {
                plan.attempts += 1;
                plan.sent_at = Instant::now();
                resend = Some(plan.packet.clone());
            } else if let Some(plan) = self.plan.take() {
                self.outputs.task(
                    &plan.task_id,
                    TaskState::Failed,
                    0.0,
                    &format!("no reply from the vehicle to the plan start ({attempts} attempts)"),
                );
            }
        }
        if let Some(bytes) = resend {
            self.send_bytes(&bytes, "PlanControl").await;
        }
        let mut resend_abort = false;
        if let Some(abort) = self.abort.as_mut()
            && abort.sent_at.elapsed() > timeout
        {
            if abort.attempts < attempts {
                abort.attempts += 1;
                abort.sent_at = Instant::now();
                resend_abort = true;
            } else if let Some(abort) = self.abort.take() {
                self.outputs.task(
                    &abort.task_id,
                    TaskState::Failed,
                    0.0,
                    &format!("the vehicle did not show it stopped ({attempts} aborts sent)"),
                );
            }
        }
        if resend_abort {
            self.send(Message::Abort).await;
        }
    }
}

#[cfg(test)]
mod tests;
