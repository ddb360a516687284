//! The MAVLink proxy: ArduSub (a BlueROV2) or any ArduPilot vehicle speaking the
//! ardupilotmega dialect, over UDP.
//!
//! [`MavlinkAdapter::connect`] opens the UDP endpoint of [`MavlinkConfig::address`]
//! (`udpin:` waits for the vehicle and answers where it speaks from, as a GCS on port
//! 14550 does; `udpout:` sends to a fixed address) and runs a link task that:
//!
//! - sends a GCS HEARTBEAT every second (ArduSub's GCS failsafe needs it) and, whenever the
//!   vehicle (re)appears, REQUEST_DATA_STREAM for its telemetry;
//! - decodes MAVLink 1 and 2 frames ([`frame`]): HEARTBEAT (type, mode, armed),
//!   GLOBAL_POSITION_INT (1e-7°, depth from `relative_alt` in mm), ATTITUDE (rad), VFR_HUD
//!   (ground speed), SYS_STATUS / BATTERY_STATUS (%) make the state vector; STATUSTEXT,
//!   arming, mode changes and critical states become events. Bad frames (CRC, unknown id,
//!   garbage, unparsable payloads, out-of-range values) are counted
//!   ([`MavlinkAdapter::counters`]) and dropped;
//! - reports the link lost when the vehicle is silent for [`MavlinkConfig::lost_after_ms`]
//!   and restored, with its streams requested again, when it returns (from any port).
//!
//! Tasks, one at a time (a new one supersedes the running one, which is reported
//! `aborted`):
//!
//! - `goto_waypoint`: GUIDED mode (DO_SET_MODE, acknowledged by COMMAND_ACK), the speed
//!   (DO_CHANGE_SPEED) and SET_POSITION_TARGET_GLOBAL_INT; progress is the distance
//!   covered, done within [`MavlinkConfig::arrival_radius_m`] at the right depth.
//! - `survey_area`: a lawnmower uploaded as a mission (MISSION_COUNT, then a
//!   MISSION_ITEM_INT for each MISSION_REQUEST_INT, until MISSION_ACK) and AUTO mode;
//!   MISSION_CURRENT gives progress, MISSION_ITEM_REACHED of the last waypoint ends it.
//! - `hold`: POSHOLD for the duration; `surface` and `abort`: SURFACE mode, done at the
//!   surface. ArduSub has no return-to-launch, so `return_home` is refused.
//!
//! A task whose command is rejected fails with the vehicle's result; one whose mode the
//! pilot changes, or whose vehicle disarms, is aborted.

pub mod frame;
pub mod mapping;

use std::collections::VecDeque;
use std::net::SocketAddr;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use mavlink::dialects::ardupilotmega::{
    COMMAND_LONG_DATA, HEARTBEAT_DATA, MISSION_COUNT_DATA, MISSION_ITEM_INT_DATA, MavAutopilot,
    MavCmd, MavFrame, MavMessage, MavMissionResult, MavModeFlag, MavResult, MavState, MavType,
    PositionTargetTypemask, SET_POSITION_TARGET_GLOBAL_INT_DATA,
};
use mavlink::{MavHeader, MavlinkVersion};
use serde::{Deserialize, Serialize};
use shoal_model::{
    EventKind, GeoPoint, LinkKind, Severity, StateVector, Task, TaskKind, TaskState, UNKNOWN,
    Validate, VehicleAnnouncement, VehicleKind, now_ms,
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
use frame::Frame;
use mapping::sub_mode;

/// How often silence, timeouts and task goals are checked.
const WATCH_EVERY: Duration = Duration::from_millis(200);
/// Least progress change worth a report, percent.
const PROGRESS_STEP: f64 = 1.0;
/// Component id of a ground control station (MAV_COMP_ID_MISSIONPLANNER).
const GCS_COMPONENT: u8 = 190;
/// Component id of an autopilot (MAV_COMP_ID_AUTOPILOT1).
const AUTOPILOT_COMPONENT: u8 = 1;

/// How to reach a MAVLink vehicle; the `[proxy.mavlink]` section a CLI would read.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MavlinkConfig {
    /// Shoal vehicle id the proxy announces.
    pub vehicle_id: String,
    /// Human-readable name.
    pub name: String,
    /// Kind of vehicle (a BlueROV2 is an ROV).
    pub kind: VehicleKind,
    /// Vendor or integrator.
    pub vendor: String,
    /// Maximum speed, m/s (announced; used by the station's plausibility checks).
    pub max_speed_mps: f64,
    /// `udpin:IP:PORT` to listen where the vehicle sends (BlueOS and mavlink-router send
    /// to a GCS on 14550), or `udpout:IP:PORT` to send to the vehicle's address.
    pub address: String,
    /// This proxy's MAVLink system id (ArduSub's SYSID_MYGCS, 255 by default, must match
    /// for its GCS failsafe to count our heartbeats).
    pub system_id: u8,
    /// The vehicle's system id; `None` takes the first autopilot that sends a HEARTBEAT.
    pub vehicle_system_id: Option<u8>,
    /// GCS heartbeat period, ms.
    pub heartbeat_interval_ms: u64,
    /// Silence after which the link is reported lost, ms.
    pub lost_after_ms: u64,
    /// How long to wait for a COMMAND_ACK or a mission request, ms.
    pub command_timeout_ms: u64,
    /// Times a command is sent before giving up.
    pub attempts: u32,
    /// Telemetry rate asked of the vehicle (REQUEST_DATA_STREAM), Hz.
    pub stream_rate_hz: u16,
    /// Distance at which a goto counts as arrived, m.
    pub arrival_radius_m: f64,
    /// Depth error within which a target depth counts as reached, m.
    pub depth_tolerance_m: f64,
    /// Arm a disarmed vehicle for goto, survey and hold (otherwise they are refused).
    pub auto_arm: bool,
    /// Largest mission the vehicle accepts, items.
    pub max_mission_items: usize,
}

impl Default for MavlinkConfig {
    fn default() -> Self {
        Self {
            vehicle_id: "bluerov-1".into(),
            name: "BlueROV2".into(),
            kind: VehicleKind::Rov,
            vendor: "Blue Robotics (ArduSub)".into(),
            max_speed_mps: 1.5,
            address: "udpin:127.0.0.1:14550".into(),
            system_id: 255,
            vehicle_system_id: None,
            heartbeat_interval_ms: 1000,
            lost_after_ms: 3000,
            command_timeout_ms: 1500,
            attempts: 3,
            stream_rate_hz: 4,
            arrival_radius_m: 2.0,
            depth_tolerance_m: 0.5,
            auto_arm: false,
            max_mission_items: 700,
        }
    }
}

/// The UDP endpoint of a [`MavlinkConfig::address`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Endpoint {
    /// Bind here and answer whoever the vehicle speaks from.
    In(SocketAddr),
    /// Send to here from any local port.
    Out(SocketAddr),
}

impl std::str::FromStr for Endpoint {
    type Err = MavlinkError;

    fn from_str(s: &str) -> Result<Self, MavlinkError> {
        let bad = |why: &str| MavlinkError::Config(format!("address {s:?}: {why}"));
        let (scheme, addr) = s
            .split_once(':')
            .ok_or_else(|| bad("expected udpin:IP:PORT or udpout:IP:PORT"))?;
        let addr: SocketAddr = addr
            .parse()
            .map_err(|_| bad("the address must be an IP and a port"))?;
        match scheme {
            "udpin" | "udp" => Ok(Self::In(addr)),
            "udpout" => Ok(Self::Out(addr)),
            _ => Err(bad("only udpin: and udpout: are supported")),
        }
    }
}

/// Why the MAVLink adapter cannot start or goes on no more.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum MavlinkError {
    /// The configuration cannot work.
    #[error("invalid MAVLink configuration: {0}")]
    Config(String),
    /// The UDP socket could not be opened.
    #[error("cannot open MAVLink UDP socket {addr}: {source}")]
    Bind {
        /// The address.
        addr: SocketAddr,
        /// The system's error.
        #[source]
        source: std::io::Error,
    },
    /// The link task ended.
    #[error("the MAVLink link stopped: {0}")]
    LinkStopped(String),
}

crate::link::link_counters! {
    /// What the link has seen so far; a snapshot from [`MavlinkAdapter::counters`].
    pub struct MavlinkCounters {
        /// Datagrams received.
        datagrams,
        /// Frames decoded and used.
        frames,
        /// Of those, MAVLink 1 frames.
        v1_frames,
        /// Bytes that were not MAVLink.
        garbage_bytes,
        /// Frames cut short.
        truncated,
        /// Frames whose CRC did not match.
        bad_crc,
        /// Frames with a message id outside the ardupilotmega dialect.
        unknown_message,
        /// Frames whose payload did not parse, or with unknown incompatibility flags.
        malformed,
        /// Messages whose values were out of range (e.g. latitude beyond 90°).
        out_of_range,
        /// Frames from other systems.
        foreign,
        /// Frames sent.
        sent,
        /// Frames that could not be sent.
        send_errors,
    }
}

/// The position part of the telemetry.
#[derive(Debug, Clone, Copy)]
struct Position {
    lat: f64,
    lon: f64,
    depth: f64,
    /// From the velocity in GLOBAL_POSITION_INT, when VFR_HUD is not heard.
    speed: f64,
    hdg: Option<f64>,
    at_ms: i64,
}

/// What HEARTBEAT says.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Heartbeat {
    mode: u32,
    armed: bool,
    status: MavState,
}

/// What the adapter and the link task share.
#[derive(Debug, Default)]
struct Shared {
    position: Option<Position>,
    /// Roll, pitch, yaw in degrees.
    attitude: Option<(f64, f64, f64)>,
    groundspeed: Option<f64>,
    battery_pct: Option<f64>,
    heartbeat: Option<Heartbeat>,
    heard: bool,
    lost: bool,
}

fn lock(shared: &Mutex<Shared>) -> std::sync::MutexGuard<'_, Shared> {
    // Plain values, consistent between statements: a poisoned lock is still usable.
    shared.lock().unwrap_or_else(PoisonError::into_inner)
}

impl Shared {
    fn state(&self, vehicle_id: &str) -> Option<StateVector> {
        if self.lost {
            return None;
        }
        let p = self.position?;
        let battery_pct = self.battery_pct?;
        let (roll, pitch, yaw) = self.attitude.unwrap_or((0.0, 0.0, p.hdg.unwrap_or(0.0)));
        Some(StateVector {
            vehicle_id: vehicle_id.to_string(),
            timestamp_ms: p.at_ms,
            latitude_deg: p.lat,
            longitude_deg: p.lon,
            depth_m: p.depth,
            altitude_m: UNKNOWN,
            speed_mps: self.groundspeed.unwrap_or(p.speed),
            yaw_deg: yaw,
            pitch_deg: pitch,
            roll_deg: roll,
            battery_pct,
        })
    }
}

/// One action of a task, in order.
#[derive(Debug, Clone)]
enum Step {
    /// COMMAND_LONG, answered by COMMAND_ACK; an `optional` one may be rejected.
    Command {
        command: MavCmd,
        params: [f32; 7],
        optional: bool,
    },
    /// SET_POSITION_TARGET_GLOBAL_INT (no acknowledgement in MAVLink).
    Target(SET_POSITION_TARGET_GLOBAL_INT_DATA),
    /// The mission upload protocol.
    Mission(Vec<MISSION_ITEM_INT_DATA>),
}

/// What ends a task.
#[derive(Debug, Clone)]
enum Goal {
    Goto {
        target: GeoPoint,
        depth: Option<f64>,
        start_distance: Option<f64>,
    },
    Mission {
        first_seq: u16,
        last_seq: u16,
    },
    Surface,
    Hold {
        duration: Option<Duration>,
    },
}

/// What a task waits for before its next step.
#[derive(Debug)]
struct Waiting {
    kind: WaitKind,
    /// The frame to send again on timeout.
    frame: Vec<u8>,
    sent_at: Instant,
    attempts: u32,
}

#[derive(Debug)]
enum WaitKind {
    Ack { command: MavCmd, optional: bool },
    Mission { items: Vec<MISSION_ITEM_INT_DATA> },
}

/// The task the vehicle is working on.
#[derive(Debug)]
struct Job {
    task_id: String,
    goal: Goal,
    /// The mode the task runs in: leaving it aborts the task.
    mode: u32,
    steps: VecDeque<Step>,
    waiting: Option<Waiting>,
    running_since: Option<Instant>,
    /// A HEARTBEAT showed `mode` since the task started running.
    mode_seen: bool,
    last_progress: f64,
    note: String,
}

/// What the adapter asks of the link task.
#[derive(Debug)]
struct Command {
    job: Job,
    abort: bool,
}

/// A MAVLink vehicle behind a DDS Proxy.
#[derive(Debug)]
pub struct MavlinkAdapter {
    config: MavlinkConfig,
    shared: Arc<Mutex<Shared>>,
    counters: Arc<Counters>,
    commands: mpsc::Sender<Command>,
    outputs: mpsc::Receiver<VehicleOutput>,
    link: JoinHandle<()>,
    local: SocketAddr,
}

impl Drop for MavlinkAdapter {
    fn drop(&mut self) {
        self.link.abort();
    }
}

impl MavlinkAdapter {
    /// Opens the UDP endpoint and starts talking to the vehicle.
    pub async fn connect(config: MavlinkConfig) -> Result<Self, MavlinkError> {
        check(&config)?;
        let endpoint: Endpoint = config.address.parse()?;
        let (bind, remote) = match endpoint {
            Endpoint::In(addr) => (addr, None),
            Endpoint::Out(addr) => {
                let any: SocketAddr = if addr.is_ipv4() {
                    SocketAddr::from(([0, 0, 0, 0], 0))
                } else {
                    SocketAddr::from(([0u16; 8], 0))
                };
                (any, Some(addr))
            }
        };
        let socket = UdpSocket::bind(bind)
            .await
            .map_err(|source| MavlinkError::Bind { addr: bind, source })?;
        let local = socket
            .local_addr()
            .map_err(|source| MavlinkError::Bind { addr: bind, source })?;
        info!(vehicle = %config.vehicle_id, %local, address = %config.address, "MAVLink link open");
        let shared = Arc::new(Mutex::new(Shared::default()));
        let counters = Arc::new(Counters::default());
        let (commands, command_rx) = mpsc::channel(crate::adapter::COMMAND_QUEUE);
        let (output_tx, outputs) = Outputs::channel(Arc::clone(&counters.outputs_dropped));
        let link = Link {
            vehicle: config.vehicle_system_id.map(|s| (s, AUTOPILOT_COMPONENT)),
            config: config.clone(),
            socket,
            remote,
            fixed_remote: remote.is_some(),
            shared: Arc::clone(&shared),
            counters: Arc::clone(&counters),
            outputs: output_tx,
            sequence: 0,
            liveness: Liveness::new(config.lost_after_ms),
            job: None,
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

    /// The local UDP address the proxy uses.
    pub fn local_addr(&self) -> SocketAddr {
        self.local
    }

    /// Frame and error counts so far.
    pub fn counters(&self) -> MavlinkCounters {
        self.counters.snapshot()
    }

    /// True while the vehicle is heard (it spoke within `lost_after_ms`).
    pub fn is_connected(&self) -> bool {
        let s = lock(&self.shared);
        s.heard && !s.lost
    }

    /// The vehicle's ArduSub mode and whether it is armed, from its last HEARTBEAT.
    pub fn mode(&self) -> Option<(u32, bool)> {
        lock(&self.shared).heartbeat.map(|h| (h.mode, h.armed))
    }

    fn job_for(&self, order: &TaskOrder) -> Result<Job, Refusal> {
        let (position, heartbeat) = {
            let s = lock(&self.shared);
            (s.position, s.heartbeat)
        };
        let armed = heartbeat.is_some_and(|h| h.armed);
        let needs_arming = || -> Result<Option<Step>, Refusal> {
            match (armed, self.config.auto_arm) {
                (true, _) => Ok(None),
                (false, true) => Ok(Some(Step::Command {
                    command: MavCmd::MAV_CMD_COMPONENT_ARM_DISARM,
                    params: [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
                    optional: false,
                })),
                (false, false) => Err(Refusal::new("the vehicle is disarmed and auto_arm is off")),
            }
        };
        let here = || {
            position
                .map(|p| GeoPoint {
                    latitude_deg: p.lat,
                    longitude_deg: p.lon,
                })
                .ok_or_else(|| Refusal::new("no position from the vehicle yet"))
        };
        let set_mode = |mode: u32| Step::Command {
            command: MavCmd::MAV_CMD_DO_SET_MODE,
            params: [
                f32::from(MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED.bits()),
                mode as f32,
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
            ],
            optional: false,
        };
        let change_speed = |speed: f64| Step::Command {
            command: MavCmd::MAV_CMD_DO_CHANGE_SPEED,
            // Ground speed (type 1), no throttle change (-1).
            params: [1.0, mapping_f32(speed), -1.0, 0.0, 0.0, 0.0, 0.0],
            // Older ArduSub ignores speed changes in GUIDED: not worth failing the task.
            optional: true,
        };
        let mut steps = VecDeque::new();
        let (goal, mode, note) = match &order.task {
            Task::GotoWaypoint {
                target,
                depth_m,
                altitude_m,
                speed_mps,
            } => {
                here()?;
                steps.extend(needs_arming()?);
                steps.push_back(set_mode(sub_mode::GUIDED));
                if *speed_mps > 0.0 {
                    steps.push_back(change_speed(*speed_mps));
                }
                let (alt, frame) = z_frame(*depth_m, *altitude_m);
                steps.push_back(Step::Target(SET_POSITION_TARGET_GLOBAL_INT_DATA {
                    lat_int: mapping::e7_from_deg(target.latitude_deg),
                    lon_int: mapping::e7_from_deg(target.longitude_deg),
                    alt,
                    type_mask: position_only(),
                    coordinate_frame: frame,
                    ..SET_POSITION_TARGET_GLOBAL_INT_DATA::default()
                }));
                (
                    Goal::Goto {
                        target: *target,
                        depth: *depth_m,
                        start_distance: None,
                    },
                    sub_mode::GUIDED,
                    "GUIDED position target sent".to_string(),
                )
            }
            Task::SurveyArea {
                polygon,
                line_spacing_m,
                depth_m,
                altitude_m,
                speed_mps,
            } => {
                let home = here()?;
                let points = lawnmower(polygon, *line_spacing_m)
                    .map_err(|e| Refusal::new(format!("no survey pattern: {e}")))?;
                if points.is_empty() {
                    return Err(Refusal::new("the survey polygon gives no survey lines"));
                }
                let items = mission_items(
                    home,
                    &points,
                    *depth_m,
                    *altitude_m,
                    *speed_mps,
                    self.config.arrival_radius_m,
                );
                if items.len() > self.config.max_mission_items {
                    return Err(Refusal::new(format!(
                        "the survey needs {} mission items, more than the {} allowed",
                        items.len(),
                        self.config.max_mission_items
                    )));
                }
                let last_seq = u16::try_from(items.len() - 1)
                    .map_err(|_| Refusal::new("too many mission items"))?;
                let first_seq = last_seq + 1 - u16::try_from(points.len()).unwrap_or(0);
                steps.extend(needs_arming()?);
                steps.push_back(Step::Mission(items));
                steps.push_back(set_mode(sub_mode::AUTO));
                (
                    Goal::Mission {
                        first_seq,
                        last_seq,
                    },
                    sub_mode::AUTO,
                    format!("mission of {} waypoints running in AUTO", points.len()),
                )
            }
            Task::Hold { duration_s } => {
                here()?;
                steps.extend(needs_arming()?);
                steps.push_back(set_mode(sub_mode::POSHOLD));
                let duration = (*duration_s > 0.0).then(|| Duration::from_secs_f64(*duration_s));
                (
                    Goal::Hold { duration },
                    sub_mode::POSHOLD,
                    "holding in POSHOLD".into(),
                )
            }
            Task::Surface | Task::Abort => {
                steps.push_back(set_mode(sub_mode::SURFACE));
                (
                    Goal::Surface,
                    sub_mode::SURFACE,
                    "surfacing in SURFACE mode".into(),
                )
            }
            Task::ReturnHome => {
                return Err(Refusal::new("ArduSub has no return-to-launch mode"));
            }
            Task::RequestState | Task::SetReportingRate { .. } => {
                return Err(Refusal::new("served by the proxy, not the vehicle"));
            }
        };
        Ok(Job {
            task_id: order.task_id.clone(),
            goal,
            mode,
            steps,
            waiting: None,
            running_since: None,
            mode_seen: false,
            last_progress: 0.0,
            note,
        })
    }
}

#[allow(clippy::cast_possible_truncation)]
fn mapping_f32(v: f64) -> f32 {
    v as f32
}

/// SET_POSITION_TARGET's mask for "position only": velocity, acceleration, yaw and yaw
/// rate ignored.
fn position_only() -> PositionTargetTypemask {
    PositionTargetTypemask::POSITION_TARGET_TYPEMASK_VX_IGNORE
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_VY_IGNORE
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_VZ_IGNORE
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_AX_IGNORE
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_AY_IGNORE
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_AZ_IGNORE
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_YAW_IGNORE
        | PositionTargetTypemask::POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
}

/// MAVLink's altitude and frame for a depth (relative to the surface, negative below) or
/// an altitude above the seabed (terrain frame, from the vehicle's rangefinder).
fn z_frame(depth_m: Option<f64>, altitude_m: Option<f64>) -> (f32, MavFrame) {
    match (depth_m, altitude_m) {
        (_, Some(alt)) => (mapping_f32(alt), MavFrame::MAV_FRAME_GLOBAL_TERRAIN_ALT),
        (Some(depth), None) => (
            mapping::alt_for_depth(depth),
            MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT,
        ),
        (None, None) => (0.0, MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT),
    }
}

/// The mission of a survey: the home placeholder ArduPilot expects at seq 0, a speed
/// change if a speed is given, then one NAV_WAYPOINT per lawnmower point.
fn mission_items(
    home: GeoPoint,
    points: &[GeoPoint],
    depth_m: Option<f64>,
    altitude_m: Option<f64>,
    speed_mps: f64,
    radius_m: f64,
) -> Vec<MISSION_ITEM_INT_DATA> {
    let item = |command, frame, x, y, z, params: [f32; 4]| MISSION_ITEM_INT_DATA {
        param1: params[0],
        param2: params[1],
        param3: params[2],
        param4: params[3],
        x,
        y,
        z,
        command,
        frame,
        autocontinue: 1,
        ..MISSION_ITEM_INT_DATA::default()
    };
    let mut items = vec![item(
        MavCmd::MAV_CMD_NAV_WAYPOINT,
        MavFrame::MAV_FRAME_GLOBAL,
        mapping::e7_from_deg(home.latitude_deg),
        mapping::e7_from_deg(home.longitude_deg),
        0.0,
        [0.0; 4],
    )];
    if speed_mps > 0.0 {
        items.push(item(
            MavCmd::MAV_CMD_DO_CHANGE_SPEED,
            MavFrame::MAV_FRAME_MISSION,
            0,
            0,
            0.0,
            [1.0, mapping_f32(speed_mps), -1.0, 0.0],
        ));
    }
    let (z, frame) = z_frame(depth_m, altitude_m);
    for p in points {
        items.push(item(
            MavCmd::MAV_CMD_NAV_WAYPOINT,
            frame,
            mapping::e7_from_deg(p.latitude_deg),
            mapping::e7_from_deg(p.longitude_deg),
            z,
            // No hold time; the acceptance radius.
            [0.0, mapping_f32(radius_m), 0.0, 0.0],
        ));
    }
    for (seq, it) in items.iter_mut().enumerate() {
        it.seq = u16::try_from(seq).unwrap_or(u16::MAX);
    }
    items
}

fn check(c: &MavlinkConfig) -> Result<(), MavlinkError> {
    let mut a = announcement_of(c);
    a.timestamp_ms = now_ms();
    a.validate()
        .map_err(|e| MavlinkError::Config(format!("the vehicle cannot be announced: {e}")))?;
    c.address.parse::<Endpoint>()?;
    if c.heartbeat_interval_ms == 0 || c.lost_after_ms == 0 || c.command_timeout_ms == 0 {
        return Err(MavlinkError::Config(
            "heartbeat_interval_ms, lost_after_ms and command_timeout_ms must be positive".into(),
        ));
    }
    if c.attempts == 0 {
        return Err(MavlinkError::Config("attempts must be at least 1".into()));
    }
    let positive = |v: f64| v > 0.0 && v.is_finite();
    if !positive(c.arrival_radius_m) || !positive(c.depth_tolerance_m) {
        return Err(MavlinkError::Config(
            "arrival_radius_m and depth_tolerance_m must be positive".into(),
        ));
    }
    if c.max_mission_items < 2 || c.max_mission_items > usize::from(u16::MAX) {
        return Err(MavlinkError::Config(
            "max_mission_items must be in [2, 65535]".into(),
        ));
    }
    if c.vehicle_system_id == Some(c.system_id) {
        return Err(MavlinkError::Config(
            "system_id and vehicle_system_id must differ".into(),
        ));
    }
    Ok(())
}

fn announcement_of(c: &MavlinkConfig) -> VehicleAnnouncement {
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
            TaskKind::Abort,
        ]
        .into_iter()
        .map(|k| capability_of(k).to_string())
        .collect(),
        sensors: Vec::new(),
        links: vec![LinkKind::Tether],
        max_speed_mps: c.max_speed_mps,
        timestamp_ms: 0,
    }
}

impl VehicleAdapter for MavlinkAdapter {
    type Error = MavlinkError;

    fn announcement(&self) -> VehicleAnnouncement {
        announcement_of(&self.config)
    }

    fn state(&mut self) -> Option<StateVector> {
        lock(&self.shared).state(&self.config.vehicle_id)
    }

    async fn next_output(&mut self) -> Result<VehicleOutput, MavlinkError> {
        match self.outputs.recv().await {
            Some(out) => Ok(out),
            None => Err(MavlinkError::LinkStopped(
                "the link task ended; see the log for why".into(),
            )),
        }
    }

    async fn submit(&mut self, order: TaskOrder) -> Result<Acceptance, Refusal> {
        let abort = matches!(order.task, Task::Abort);
        if !abort {
            let s = lock(&self.shared);
            if !s.heard || s.lost {
                return Err(Refusal::new("no contact with the vehicle over MAVLink"));
            }
        }
        let job = self.job_for(&order)?;
        let note = format!("{} step(s) to send", job.steps.len());
        self.commands
            .try_send(Command { job, abort })
            .map_err(|e| crate::adapter::queue_refusal("MAVLink", &e))?;
        Ok(Acceptance::with_message(note))
    }
}

/// The task that owns the socket.
struct Link {
    config: MavlinkConfig,
    socket: UdpSocket,
    /// Where the vehicle is: fixed for `udpout:`, learned for `udpin:`.
    remote: Option<SocketAddr>,
    fixed_remote: bool,
    shared: Arc<Mutex<Shared>>,
    counters: Arc<Counters>,
    outputs: Outputs,
    /// The vehicle's system and component ids, once known.
    vehicle: Option<(u8, u8)>,
    sequence: u8,
    liveness: Liveness,
    job: Option<Job>,
}

impl Link {
    async fn run(mut self, mut commands: mpsc::Receiver<Command>) {
        let mut buf = vec![0u8; 65_536];
        let mut heartbeat =
            tokio::time::interval(Duration::from_millis(self.config.heartbeat_interval_ms));
        heartbeat.set_missed_tick_behavior(MissedTickBehavior::Delay);
        let mut watch = tokio::time::interval(WATCH_EVERY);
        watch.set_missed_tick_behavior(MissedTickBehavior::Delay);
        loop {
            tokio::select! {
                received = self.socket.recv_from(&mut buf) => match received {
                    Ok((n, from)) => self.on_datagram(&buf[..n], from).await,
                    Err(e) => {
                        // Transient (an ICMP error for an earlier send); the pause keeps a
                        // persistent one from spinning.
                        debug!(error = %e, "MAVLink receive error");
                        tokio::time::sleep(Duration::from_millis(100)).await;
                    }
                },
                command = commands.recv() => match command {
                    Some(c) => self.on_command(c).await,
                    None => return,
                },
                _ = heartbeat.tick() => {
                    let hb = MavMessage::HEARTBEAT(HEARTBEAT_DATA {
                        custom_mode: 0,
                        mavtype: MavType::MAV_TYPE_GCS,
                        autopilot: MavAutopilot::MAV_AUTOPILOT_INVALID,
                        base_mode: MavModeFlag::empty(),
                        system_status: MavState::MAV_STATE_ACTIVE,
                        mavlink_version: 3,
                    });
                    self.send(&hb).await;
                }
                _ = watch.tick() => self.on_watch().await,
            }
        }
    }

    fn encode(&mut self, message: &MavMessage) -> Option<Vec<u8>> {
        let header = MavHeader {
            system_id: u32::from(self.config.system_id),
            component_id: GCS_COMPONENT,
            sequence: self.sequence,
        };
        self.sequence = self.sequence.wrapping_add(1);
        match frame::encode(header, message) {
            Ok(bytes) => Some(bytes),
            Err(e) => {
                bump(&self.counters.send_errors);
                warn!(error = %e, "MAVLink message not encodable");
                None
            }
        }
    }

    async fn send_bytes(&self, bytes: &[u8]) {
        let Some(remote) = self.remote else {
            // udpin before the vehicle spoke: nowhere to send yet.
            return;
        };
        match self.socket.send_to(bytes, remote).await {
            Ok(_) => bump(&self.counters.sent),
            Err(e) => {
                bump(&self.counters.send_errors);
                debug!(error = %e, "MAVLink send failed");
            }
        }
    }

    async fn send(&mut self, message: &MavMessage) -> Option<Vec<u8>> {
        let bytes = self.encode(message)?;
        self.send_bytes(&bytes).await;
        Some(bytes)
    }

    fn target(&self) -> (u8, u8) {
        self.vehicle.unwrap_or((1, AUTOPILOT_COMPONENT))
    }

    async fn on_datagram(&mut self, mut bytes: &[u8], from: SocketAddr) {
        bump(&self.counters.datagrams);
        while !bytes.is_empty() {
            let (f, used) = frame::next(bytes);
            bytes = &bytes[used.max(1).min(bytes.len())..];
            match f {
                Frame::Message {
                    header,
                    message,
                    version,
                } => {
                    if version == MavlinkVersion::V1 {
                        bump(&self.counters.v1_frames);
                    }
                    self.on_message(header, *message, from).await;
                }
                Frame::Garbage(n) => {
                    self.counters
                        .garbage_bytes
                        .fetch_add(n as u64, Ordering::Relaxed);
                }
                Frame::Truncated => bump(&self.counters.truncated),
                Frame::BadCrc(id) => {
                    bump(&self.counters.bad_crc);
                    debug!(%from, id, "MAVLink frame with a bad CRC dropped");
                }
                Frame::UnknownMessage(id) => {
                    bump(&self.counters.unknown_message);
                    debug!(%from, id, "MAVLink frame with an unknown id dropped");
                }
                Frame::Malformed(id) => {
                    bump(&self.counters.malformed);
                    debug!(%from, id, "malformed MAVLink frame dropped");
                }
            }
        }
    }

    /// Whether a frame comes from the vehicle, adopting the first autopilot heard.
    fn accept_source(&mut self, header: &MavHeader, message: &MavMessage) -> bool {
        let sys = u8::try_from(header.system_id).ok();
        match self.vehicle {
            Some((id, _)) => sys == Some(id),
            None => {
                let MavMessage::HEARTBEAT(hb) = message else {
                    return false;
                };
                let Some(sys) = sys else {
                    return false;
                };
                if hb.autopilot == MavAutopilot::MAV_AUTOPILOT_INVALID
                    || hb.mavtype == MavType::MAV_TYPE_GCS
                    || sys == self.config.system_id
                {
                    return false;
                }
                info!(system = sys, component = header.component_id, kind = ?hb.mavtype, "MAVLink vehicle identified");
                self.vehicle = Some((sys, header.component_id));
                if let Some(kind) = mapping::kind_of(hb.mavtype)
                    && kind != self.config.kind
                {
                    warn!(configured = %self.config.kind, reported = %kind, "the vehicle reports another kind than configured");
                }
                true
            }
        }
    }

    async fn on_message(&mut self, header: MavHeader, message: MavMessage, from: SocketAddr) {
        if !self.accept_source(&header, &message) {
            bump(&self.counters.foreign);
            return;
        }
        bump(&self.counters.frames);
        if !self.fixed_remote && self.remote != Some(from) {
            info!(%from, "MAVLink vehicle address");
            self.remote = Some(from);
        }
        self.heard().await;
        match message {
            MavMessage::HEARTBEAT(hb) => self.on_heartbeat(&hb),
            MavMessage::GLOBAL_POSITION_INT(p) => {
                let lat = mapping::deg_from_e7(p.lat);
                let lon = mapping::deg_from_e7(p.lon);
                if p.lat == 0 && p.lon == 0 {
                    // ArduPilot's "no position estimate yet".
                    return;
                }
                let pos = Position {
                    lat,
                    lon,
                    depth: mapping::depth_from_relative_alt_mm(p.relative_alt),
                    speed: mapping::speed_from_cm_s(p.vx, p.vy),
                    hdg: mapping::hdg_deg(p.hdg),
                    at_ms: now_ms(),
                };
                let ok = (-90.0..=90.0).contains(&lat)
                    && (-180.0..=180.0).contains(&lon)
                    && pos.depth <= StateVector::DEPTH.1
                    && pos.speed <= StateVector::SPEED.1;
                if !ok {
                    bump(&self.counters.out_of_range);
                    return;
                }
                lock(&self.shared).position = Some(pos);
                self.check_goal().await;
            }
            MavMessage::ATTITUDE(a) => {
                let (roll, pitch) = (mapping::deg(a.roll), mapping::deg(a.pitch));
                let ok = a.yaw.is_finite()
                    && (-180.0..=180.0).contains(&roll)
                    && (-90.0..=90.0).contains(&pitch);
                if ok {
                    lock(&self.shared).attitude = Some((roll, pitch, mapping::yaw_deg(a.yaw)));
                } else {
                    bump(&self.counters.out_of_range);
                }
            }
            MavMessage::VFR_HUD(v) => {
                let speed = f64::from(v.groundspeed);
                if (0.0..=StateVector::SPEED.1).contains(&speed) {
                    lock(&self.shared).groundspeed = Some(speed);
                } else {
                    bump(&self.counters.out_of_range);
                }
            }
            MavMessage::SYS_STATUS(s) => self.on_battery(s.battery_remaining),
            MavMessage::BATTERY_STATUS(b) if b.id == 0 => self.on_battery(b.battery_remaining),
            MavMessage::STATUSTEXT(t) => {
                if let Some((severity, kind)) = mapping::statustext_event(t.severity) {
                    let text = mapping::statustext(&t.text[..]);
                    if !text.is_empty() {
                        let task = self
                            .job
                            .as_ref()
                            .map(|j| j.task_id.clone())
                            .unwrap_or_default();
                        let task = if severity >= Severity::Alarm {
                            task
                        } else {
                            String::new()
                        };
                        self.outputs.event(severity, kind, &task, text);
                    }
                }
            }
            MavMessage::COMMAND_ACK(ack) => self.on_ack(ack.command, ack.result).await,
            MavMessage::MISSION_REQUEST_INT(r) if r.target_system == self.config.system_id => {
                self.on_mission_request(r.seq).await;
            }
            // Deprecated, but older firmware still asks this way.
            #[allow(deprecated)]
            MavMessage::MISSION_REQUEST(r) if r.target_system == self.config.system_id => {
                self.on_mission_request(r.seq).await;
            }
            MavMessage::MISSION_ACK(a) if a.target_system == self.config.system_id => {
                self.on_mission_ack(a.mavtype).await;
            }
            MavMessage::MISSION_CURRENT(c) => self.on_mission_current(c.seq),
            MavMessage::MISSION_ITEM_REACHED(r) => self.on_item_reached(r.seq),
            _ => {}
        }
    }

    fn on_battery(&self, remaining: i8) {
        match mapping::battery_pct(remaining) {
            Ok(Some(pct)) => lock(&self.shared).battery_pct = Some(pct),
            Ok(None) => {}
            Err(_) => bump(&self.counters.out_of_range),
        }
    }

    async fn heard(&mut self) {
        let heard = self.liveness.heard();
        {
            let mut s = lock(&self.shared);
            s.heard = true;
            s.lost = false;
        }
        if heard.first || heard.back_after.is_some() {
            self.request_streams().await;
        }
        if let Some(silent) = heard.back_after {
            let silent = silent.as_secs_f64();
            info!(vehicle = %self.config.vehicle_id, "MAVLink link restored");
            self.outputs.event(
                Severity::Info,
                EventKind::CommLost,
                "",
                format!("MAVLink link restored after {silent:.1} s of silence"),
            );
            // Whatever was waiting for an answer is asked again now, not at its timeout.
            if let Some(w) = self.job.as_mut().and_then(|j| j.waiting.as_mut()) {
                w.sent_at = Instant::now();
                let frame = w.frame.clone();
                self.send_bytes(&frame).await;
            }
        }
    }

    /// Asks for every telemetry stream at the configured rate.
    ///
    /// REQUEST_DATA_STREAM is deprecated in favour of one SET_MESSAGE_INTERVAL per message,
    /// but ArduPilot still honours it, as QGroundControl and MAVProxy still send it, and one
    /// message restores all of a restarted vehicle's streams.
    #[allow(deprecated)]
    async fn request_streams(&mut self) {
        use mavlink::dialects::ardupilotmega::{MavDataStream, REQUEST_DATA_STREAM_DATA};
        let (sys, comp) = self.target();
        let msg = MavMessage::REQUEST_DATA_STREAM(REQUEST_DATA_STREAM_DATA {
            req_message_rate: self.config.stream_rate_hz,
            target_system: sys,
            target_component: comp,
            req_stream_id: MavDataStream::MAV_DATA_STREAM_ALL,
            start_stop: 1,
        });
        self.send(&msg).await;
    }

    fn on_heartbeat(&mut self, hb: &HEARTBEAT_DATA) {
        let now = Heartbeat {
            mode: hb.custom_mode,
            armed: hb
                .base_mode
                .contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED),
            status: hb.system_status,
        };
        let before = lock(&self.shared).heartbeat.replace(now);
        let Some(before) = before else {
            self.outputs.event(
                Severity::Info,
                EventKind::Other,
                "",
                format!(
                    "MAVLink vehicle connected: {}, {}",
                    mapping::mode_name(now.mode),
                    if now.armed { "armed" } else { "disarmed" }
                ),
            );
            self.check_mode(now);
            return;
        };
        if before.armed != now.armed {
            let text = if now.armed {
                "vehicle armed"
            } else {
                "vehicle disarmed"
            };
            self.outputs
                .event(Severity::Info, EventKind::Other, "", text.into());
        }
        if before.mode != now.mode {
            self.outputs.event(
                Severity::Info,
                EventKind::Other,
                "",
                format!(
                    "mode {} -> {}",
                    mapping::mode_name(before.mode),
                    mapping::mode_name(now.mode)
                ),
            );
        }
        if before.status != now.status {
            match now.status {
                MavState::MAV_STATE_CRITICAL => self.outputs.event(
                    Severity::Alarm,
                    EventKind::Fault,
                    "",
                    "the vehicle reports a CRITICAL state (failsafe)".into(),
                ),
                MavState::MAV_STATE_EMERGENCY => self.outputs.event(
                    Severity::Critical,
                    EventKind::Fault,
                    "",
                    "the vehicle reports an EMERGENCY".into(),
                ),
                _ => {}
            }
        }
        self.check_mode(now);
    }

    /// Aborts the running task if the pilot (or a failsafe) took the vehicle out of the
    /// task's mode, or disarmed it mid-move.
    fn check_mode(&mut self, hb: Heartbeat) {
        let Some(job) = self.job.as_mut() else {
            return;
        };
        if job.running_since.is_none() {
            return;
        }
        if hb.mode == job.mode {
            job.mode_seen = true;
            let moving = matches!(job.goal, Goal::Goto { .. } | Goal::Mission { .. });
            if moving
                && !hb.armed
                && let Some(job) = self.job.take()
            {
                self.outputs.task(
                    &job.task_id,
                    TaskState::Aborted,
                    job.last_progress,
                    "the vehicle disarmed",
                );
            }
            return;
        }
        // Until the task's mode has shown in a HEARTBEAT, an older HEARTBEAT is no news.
        if !job.mode_seen {
            return;
        }
        if let Some(job) = self.job.take() {
            self.outputs.task(
                &job.task_id,
                TaskState::Aborted,
                job.last_progress,
                &format!(
                    "the vehicle left {} for {}",
                    mapping::mode_name(job.mode),
                    mapping::mode_name(hb.mode)
                ),
            );
        }
    }

    async fn on_command(&mut self, command: Command) {
        let Command { job, abort } = command;
        if let Some(old) = self.job.take() {
            let held_until_next =
                matches!(old.goal, Goal::Hold { duration: None }) && old.running_since.is_some();
            self.outputs.replaced(
                &old.task_id,
                old.last_progress,
                held_until_next,
                &job.task_id,
                abort,
            );
        }
        info!(task = %job.task_id, steps = job.steps.len(), "MAVLink task started");
        self.job = Some(job);
        self.advance().await;
    }

    /// Sends the running task's next steps until one needs an answer, or reports it
    /// running when none is left.
    async fn advance(&mut self) {
        loop {
            let Some(job) = self.job.as_mut() else {
                return;
            };
            if job.waiting.is_some() || job.running_since.is_some() {
                return;
            }
            let Some(step) = job.steps.pop_front() else {
                job.running_since = Some(Instant::now());
                let (task, note) = (job.task_id.clone(), job.note.clone());
                self.outputs.task(&task, TaskState::Running, 0.0, &note);
                let hb = lock(&self.shared).heartbeat;
                if let Some(hb) = hb {
                    self.check_mode(hb);
                }
                self.check_goal().await;
                return;
            };
            let (sys, comp) = self.target();
            match step {
                Step::Command {
                    command,
                    params,
                    optional,
                } => {
                    let msg = MavMessage::COMMAND_LONG(COMMAND_LONG_DATA {
                        param1: params[0],
                        param2: params[1],
                        param3: params[2],
                        param4: params[3],
                        param5: params[4],
                        param6: params[5],
                        param7: params[6],
                        command,
                        target_system: sys,
                        target_component: comp,
                        confirmation: 0,
                    });
                    let Some(frame) = self.send(&msg).await else {
                        self.fail("the command cannot be encoded");
                        return;
                    };
                    if let Some(job) = self.job.as_mut() {
                        job.waiting = Some(Waiting {
                            kind: WaitKind::Ack { command, optional },
                            frame,
                            sent_at: Instant::now(),
                            attempts: 1,
                        });
                    }
                }
                Step::Target(mut target) => {
                    target.target_system = sys;
                    target.target_component = comp;
                    if self
                        .send(&MavMessage::SET_POSITION_TARGET_GLOBAL_INT(target))
                        .await
                        .is_none()
                    {
                        self.fail("the position target cannot be encoded");
                        return;
                    }
                }
                Step::Mission(mut items) => {
                    for it in &mut items {
                        it.target_system = sys;
                        it.target_component = comp;
                    }
                    let count = u16::try_from(items.len()).unwrap_or(u16::MAX);
                    let msg = MavMessage::MISSION_COUNT(MISSION_COUNT_DATA {
                        count,
                        target_system: sys,
                        target_component: comp,
                    });
                    let Some(frame) = self.send(&msg).await else {
                        self.fail("the mission cannot be encoded");
                        return;
                    };
                    if let Some(job) = self.job.as_mut() {
                        job.waiting = Some(Waiting {
                            kind: WaitKind::Mission { items },
                            frame,
                            sent_at: Instant::now(),
                            attempts: 1,
                        });
                    }
                }
            }
        }
    }

    fn fail(&mut self, why: &str) {
        if let Some(job) = self.job.take() {
            warn!(task = %job.task_id, why, "MAVLink task failed");
            self.outputs
                .task(&job.task_id, TaskState::Failed, job.last_progress, why);
        }
    }

    async fn on_ack(&mut self, command: MavCmd, result: MavResult) {
        let Some(job) = self.job.as_mut() else {
            return;
        };
        let Some(Waiting {
            kind:
                WaitKind::Ack {
                    command: expected,
                    optional,
                },
            ..
        }) = &job.waiting
        else {
            return;
        };
        if *expected != command {
            return;
        }
        let optional = *optional;
        match result {
            MavResult::MAV_RESULT_ACCEPTED => {
                job.waiting = None;
                self.advance().await;
            }
            MavResult::MAV_RESULT_IN_PROGRESS => {
                if let Some(w) = job.waiting.as_mut() {
                    w.sent_at = Instant::now();
                }
            }
            other if optional => {
                debug!(?command, ?other, "optional MAVLink command not accepted");
                job.waiting = None;
                self.advance().await;
            }
            other => {
                let why = format!(
                    "the vehicle rejected {}: {}",
                    cmd_name(command),
                    result_name(other)
                );
                self.fail(&why);
            }
        }
    }

    async fn on_mission_request(&mut self, seq: u16) {
        let Some(job) = self.job.as_mut() else {
            return;
        };
        let Some(Waiting {
            kind: WaitKind::Mission { items },
            ..
        }) = &job.waiting
        else {
            return;
        };
        let Some(item) = items.get(usize::from(seq)).cloned() else {
            self.fail(&format!(
                "the vehicle asked for mission item {seq}, which does not exist"
            ));
            return;
        };
        let Some(frame) = self.send(&MavMessage::MISSION_ITEM_INT(item)).await else {
            self.fail("a mission item cannot be encoded");
            return;
        };
        if let Some(w) = self.job.as_mut().and_then(|j| j.waiting.as_mut()) {
            w.frame = frame;
            w.sent_at = Instant::now();
            w.attempts = 1;
        }
    }

    async fn on_mission_ack(&mut self, result: MavMissionResult) {
        let Some(job) = self.job.as_mut() else {
            return;
        };
        if !matches!(
            job.waiting,
            Some(Waiting {
                kind: WaitKind::Mission { .. },
                ..
            })
        ) {
            return;
        }
        if result == MavMissionResult::MAV_MISSION_ACCEPTED {
            job.waiting = None;
            self.advance().await;
        } else {
            self.fail(&format!("the vehicle rejected the mission: {result:?}"));
        }
    }

    fn mission_progress(&mut self, seq: u16, reached: bool) {
        let Some(job) = self.job.as_mut() else {
            return;
        };
        if job.running_since.is_none() {
            return;
        }
        let Goal::Mission {
            first_seq,
            last_seq,
        } = job.goal
        else {
            return;
        };
        if reached && seq >= last_seq {
            if let Some(job) = self.job.take() {
                self.outputs
                    .task(&job.task_id, TaskState::Done, 100.0, "mission complete");
            }
            return;
        }
        let done_items = if reached { seq + 1 } else { seq }.saturating_sub(first_seq);
        let total = last_seq + 1 - first_seq;
        let progress = 100.0 * f64::from(done_items) / f64::from(total.max(1));
        if (progress - job.last_progress).abs() >= PROGRESS_STEP {
            job.last_progress = progress;
            let task = job.task_id.clone();
            self.outputs.task(
                &task,
                TaskState::Running,
                progress,
                &format!("mission item {seq}"),
            );
        }
    }

    fn on_mission_current(&mut self, seq: u16) {
        self.mission_progress(seq, false);
    }

    fn on_item_reached(&mut self, seq: u16) {
        self.mission_progress(seq, true);
    }

    /// Ends or advances the running task from the latest telemetry.
    async fn check_goal(&mut self) {
        let position = lock(&self.shared).position;
        let Some(job) = self.job.as_mut() else {
            return;
        };
        let Some(since) = job.running_since else {
            return;
        };
        let (done, progress) = match &mut job.goal {
            Goal::Goto {
                target,
                depth,
                start_distance,
            } => {
                let Some(p) = position else {
                    return;
                };
                let here = GeoPoint {
                    latitude_deg: p.lat,
                    longitude_deg: p.lon,
                };
                let d = distance(here, *target);
                let start = *start_distance.get_or_insert(d);
                let depth_ok =
                    depth.is_none_or(|z| (p.depth - z).abs() <= self.config.depth_tolerance_m);
                let done = d <= self.config.arrival_radius_m && depth_ok;
                let progress = if start > self.config.arrival_radius_m {
                    100.0
                        * (1.0
                            - (d - self.config.arrival_radius_m).max(0.0)
                                / (start - self.config.arrival_radius_m))
                } else {
                    job.last_progress
                };
                (done, progress)
            }
            Goal::Surface => {
                let Some(p) = position else {
                    return;
                };
                (p.depth <= self.config.depth_tolerance_m, job.last_progress)
            }
            Goal::Hold { duration } => match duration {
                Some(d) => {
                    let frac = since.elapsed().as_secs_f64() / d.as_secs_f64().max(1e-3);
                    (since.elapsed() >= *d, 100.0 * frac.min(1.0))
                }
                None => (false, 0.0),
            },
            Goal::Mission { .. } => return,
        };
        if done {
            if let Some(job) = self.job.take() {
                let message = match job.goal {
                    Goal::Goto { .. } => "arrived",
                    Goal::Surface => "at the surface",
                    _ => "held for the duration",
                };
                self.outputs
                    .task(&job.task_id, TaskState::Done, 100.0, message);
            }
        } else if (progress - job.last_progress).abs() >= PROGRESS_STEP {
            job.last_progress = progress.clamp(0.0, 100.0);
            let (task, p) = (job.task_id.clone(), job.last_progress);
            self.outputs.task(&task, TaskState::Running, p, "under way");
        }
    }

    async fn on_watch(&mut self) {
        if self.liveness.check() {
            let lost_after = self.liveness.lost_after();
            lock(&self.shared).lost = true;
            warn!(vehicle = %self.config.vehicle_id, "MAVLink link lost");
            let task = self
                .job
                .as_ref()
                .map(|j| j.task_id.clone())
                .unwrap_or_default();
            self.outputs.event(
                Severity::Alarm,
                EventKind::CommLost,
                &task,
                format!(
                    "no MAVLink from the vehicle for {:.1} s: link lost",
                    lost_after.as_secs_f64()
                ),
            );
        }
        self.check_goal().await;
        let timeout = Duration::from_millis(self.config.command_timeout_ms);
        let attempts = self.config.attempts;
        let lost = self.liveness.is_lost();
        let Some(job) = self.job.as_mut() else {
            return;
        };
        let Some(w) = job.waiting.as_mut() else {
            return;
        };
        // While the link is down, waiting is not the vehicle's fault: the request goes
        // out again when it returns.
        if lost || w.sent_at.elapsed() <= timeout {
            return;
        }
        if w.attempts < attempts {
            w.attempts += 1;
            w.sent_at = Instant::now();
            let frame = w.frame.clone();
            self.send_bytes(&frame).await;
            return;
        }
        let what = match &w.kind {
            WaitKind::Ack { command, .. } => format!("COMMAND_ACK for {}", cmd_name(*command)),
            WaitKind::Mission { .. } => "the mission upload".into(),
        };
        self.fail(&format!(
            "no answer from the vehicle to {what} ({attempts} attempts)"
        ));
    }
}

/// A command's name without the `MAV_CMD_` prefix.
fn cmd_name(c: MavCmd) -> String {
    let s = format!("{c:?}");
    s.strip_prefix("MAV_CMD_").unwrap_or(&s).to_string()
}

/// A result's name without the `MAV_RESULT_` prefix.
fn result_name(r: MavResult) -> String {
    let s = format!("{r:?}");
    s.strip_prefix("MAV_RESULT_").unwrap_or(&s).to_string()
}

#[cfg(test)]
mod tests;
