//! The IMC wire format (LSTS Inter-Module Communication, IMC.xml 5.4), for the messages a
//! Shoal proxy exchanges with a DUNE vehicle.
//!
//! A packet is a 20-byte header, the message payload and a CRC-16 footer:
//!
//! | field | type | note |
//! | --- | --- | --- |
//! | sync | u16 | `0xFE54`; read as `0x54FE`, the sender used the other byte order |
//! | mgid | u16 | message id |
//! | size | u16 | payload bytes |
//! | timestamp | fp64 | seconds since the Unix epoch, sender's clock |
//! | src, src_ent | u16, u8 | sender system and entity |
//! | dst, dst_ent | u16, u8 | destination system and entity |
//! | payload | `size` bytes | the message's fields in IMC.xml order |
//! | crc16 | u16 | CRC-16/ARC (IBM, polynomial 0x8005 reflected) of header and payload |
//!
//! Every multi-byte value, the footer included, is in the sender's byte order, which the
//! sync number reveals; Shoal sends little-endian, like DUNE on x86 and ARM. Text and raw
//! fields are a u16 length and the bytes; an inline message is its u16 id (65535 for none)
//! and its payload; a message list is a u16 count and inline messages.
//!
//! Decoding never panics: anything malformed comes back as a [`DecodeError`] saying why,
//! so the adapter can count it and drop it.

use crc::{CRC_16_ARC, Crc};

/// Synchronisation number of IMC 5.4 packets, as read in the sender's byte order.
pub const SYNC: u16 = 0xFE54;
/// The synchronisation number as it reads when the sender used the other byte order.
pub const SYNC_SWAPPED: u16 = 0x54FE;
/// Header length, bytes.
pub const HEADER_LEN: usize = 20;
/// Footer (CRC) length, bytes.
pub const FOOTER_LEN: usize = 2;
/// Message id meaning "no inline message".
pub const NULL_ID: u16 = 0xFFFF;
/// System or entity address meaning "any" / "unknown" (DUNE's `0xFFFF` and `0xFF`).
pub const ANY_SYSTEM: u16 = 0xFFFF;
/// Entity address meaning "any".
pub const ANY_ENTITY: u8 = 0xFF;
/// Deepest nesting of inline messages decoded (a plan's maneuver inside a plan inside a
/// plan control is 3); deeper input is rejected rather than recursed into.
pub const MAX_DEPTH: usize = 6;

const CRC16: Crc<u16> = Crc::<u16>::new(&CRC_16_ARC);

/// CRC-16/ARC of a byte string, as IMC's footer holds it.
pub fn crc16(bytes: &[u8]) -> u16 {
    CRC16.checksum(bytes)
}

/// Byte order of a packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ByteOrder {
    /// Least significant byte first (x86, ARM): what Shoal sends.
    Little,
    /// Most significant byte first.
    Big,
}

/// Why bytes are not an IMC packet.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum DecodeError {
    /// Fewer bytes than a header, or than the header's size promises.
    #[error("truncated packet: {needed} bytes needed, {available} available")]
    Truncated {
        /// Bytes the packet needs.
        needed: usize,
        /// Bytes there are.
        available: usize,
    },
    /// The first two bytes are not an IMC 5.4 synchronisation number.
    #[error("no IMC synchronisation number (0x{0:04X})")]
    BadSync(u16),
    /// The footer does not match the header and payload.
    #[error("CRC mismatch: computed 0x{computed:04X}, packet says 0x{received:04X}")]
    BadCrc {
        /// CRC of what arrived.
        computed: u16,
        /// CRC in the footer.
        received: u16,
    },
    /// A message id this codec does not know (the packet is well formed).
    #[error("unknown IMC message id {0}")]
    UnknownMessage(u16),
    /// The payload does not fit its message's definition.
    #[error("malformed {message}: {detail}")]
    Malformed {
        /// Message being decoded.
        message: &'static str,
        /// What was wrong.
        detail: &'static str,
    },
}

/// Why a message cannot be encoded.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum EncodeError {
    /// A text field, list or payload is longer than IMC's 16-bit lengths allow.
    #[error("{0} is too long for IMC's 16-bit length")]
    TooLong(&'static str),
    /// Inline messages are nested deeper than [`MAX_DEPTH`].
    #[error("inline messages nested deeper than {MAX_DEPTH}")]
    TooDeep,
}

/// The packet header, less sync, id and size (which encoding derives).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Header {
    /// Seconds since the Unix epoch when sent, sender's clock.
    pub timestamp: f64,
    /// Sender system id.
    pub src: u16,
    /// Sender entity.
    pub src_ent: u8,
    /// Destination system id ([`ANY_SYSTEM`] for any).
    pub dst: u16,
    /// Destination entity ([`ANY_ENTITY`] for any).
    pub dst_ent: u8,
}

/// A decoded packet: header and message.
#[derive(Debug, Clone, PartialEq)]
pub struct Packet {
    /// Addressing and time.
    pub header: Header,
    /// The message.
    pub message: Message,
}

/// `Announce` (151): a system's name, type, position and services.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Announce {
    /// System name.
    pub sys_name: String,
    /// System type (`SystemType`: 0 CCU, 2 UUV, 3 USV, ...).
    pub sys_type: u8,
    /// System that controls this one, [`ANY_SYSTEM`] if none.
    pub owner: u16,
    /// WGS84 latitude, radians.
    pub lat: f64,
    /// WGS84 longitude, radians.
    pub lon: f64,
    /// Height above the WGS84 ellipsoid, metres.
    pub height: f32,
    /// Services, `;`-separated URIs (e.g. `imc+udp://127.0.0.1:6002/`).
    pub services: String,
}

/// `EstimatedState` (350): the navigation solution. The position is the reference
/// `lat`/`lon` displaced by `x` metres north and `y` metres east.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct EstimatedState {
    /// Reference latitude, radians.
    pub lat: f64,
    /// Reference longitude, radians.
    pub lon: f64,
    /// Reference height above the ellipsoid, metres.
    pub height: f32,
    /// Offset north of the reference, metres.
    pub x: f32,
    /// Offset east of the reference, metres.
    pub y: f32,
    /// Offset down, metres.
    pub z: f32,
    /// Roll, radians.
    pub phi: f32,
    /// Pitch, radians.
    pub theta: f32,
    /// Yaw (heading from north, clockwise), radians.
    pub psi: f32,
    /// Body-fixed surge velocity, m/s.
    pub u: f32,
    /// Body-fixed sway velocity, m/s.
    pub v: f32,
    /// Body-fixed heave velocity, m/s.
    pub w: f32,
    /// Ground velocity north, m/s.
    pub vx: f32,
    /// Ground velocity east, m/s.
    pub vy: f32,
    /// Ground velocity down, m/s.
    pub vz: f32,
    /// Roll rate, rad/s.
    pub p: f32,
    /// Pitch rate, rad/s.
    pub q: f32,
    /// Yaw rate, rad/s.
    pub r: f32,
    /// Depth, metres (below the surface, positive down).
    pub depth: f32,
    /// Altitude above the seabed, metres; negative when unknown.
    pub alt: f32,
}

/// `FuelLevel` (279): remaining energy.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct FuelLevel {
    /// Remaining, percent [0, 100].
    pub value: f32,
    /// Confidence of the estimate, percent.
    pub confidence: f32,
    /// Estimated endurance per operation mode (`mode=hours;...`).
    pub opmodes: String,
}

/// `VehicleState` (500): the vehicle supervisor's state.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct VehicleState {
    /// Operation mode (`VS_*`: 0 service, 1 calibration, 2 error, 3 maneuver, 4 external,
    /// 5 boot).
    pub op_mode: u8,
    /// Number of entities in error.
    pub error_count: u8,
    /// Entities in error, comma-separated.
    pub error_ents: String,
    /// Id of the maneuver being executed.
    pub maneuver_type: u16,
    /// When the maneuver started, s since the epoch.
    pub maneuver_stime: f64,
    /// Maneuver's estimated time to completion, s (65535 unknown).
    pub maneuver_eta: u16,
    /// Enabled control loops (`CLoopsMask`).
    pub control_loops: u32,
    /// Flags (`VFLG_MANEUVER_DONE` = 1).
    pub flags: u8,
    /// Last error.
    pub last_error: String,
    /// When the last error happened, s since the epoch.
    pub last_error_time: f64,
}

/// `VehicleState.op_mode` values.
pub mod op_mode {
    /// Idle, ready for a plan.
    pub const SERVICE: u8 = 0;
    /// Calibrating.
    pub const CALIBRATION: u8 = 1;
    /// Some entity failed; plans cannot run.
    pub const ERROR: u8 = 2;
    /// Executing a maneuver.
    pub const MANEUVER: u8 = 3;
    /// Under external control.
    pub const EXTERNAL: u8 = 4;
    /// Booting.
    pub const BOOT: u8 = 5;
}

/// `PlanControl` (559): plan requests and their replies.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PlanControl {
    /// `PC_REQUEST` (0), `PC_SUCCESS` (1), `PC_FAILURE` (2), `PC_IN_PROGRESS` (3).
    pub kind: u8,
    /// `PC_START` (0), `PC_STOP` (1), `PC_LOAD` (2), `PC_GET` (3).
    pub op: u8,
    /// Matches a reply to its request.
    pub request_id: u16,
    /// Plan the request is about.
    pub plan_id: String,
    /// `FLG_CALIBRATE` (1), `FLG_IGNORE_ERRORS` (2).
    pub flags: u16,
    /// The plan (a `PlanSpecification`) or a single maneuver, inline.
    pub arg: Option<Box<Message>>,
    /// Free text (e.g. why a request failed).
    pub info: String,
}

/// `PlanControl` type and operation values.
pub mod plan_control {
    /// A request.
    pub const REQUEST: u8 = 0;
    /// Reply: done.
    pub const SUCCESS: u8 = 1;
    /// Reply: failed.
    pub const FAILURE: u8 = 2;
    /// Reply: under way.
    pub const IN_PROGRESS: u8 = 3;
    /// Start a plan.
    pub const START: u8 = 0;
    /// Stop a plan.
    pub const STOP: u8 = 1;
}

/// `PlanControlState` (560): the plan engine's state, periodic.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PlanControlState {
    /// `PCS_BLOCKED` (0), `PCS_READY` (1), `PCS_INITIALIZING` (2), `PCS_EXECUTING` (3).
    pub state: u8,
    /// Plan being (or last) executed.
    pub plan_id: String,
    /// Plan's estimated time to completion, s (-1 unknown).
    pub plan_eta: i32,
    /// Plan progress, percent (-1 unknown).
    pub plan_progress: f32,
    /// Current maneuver id.
    pub man_id: String,
    /// Current maneuver's message id.
    pub man_type: u16,
    /// Maneuver's estimated time to completion, s.
    pub man_eta: i32,
    /// `LPO_NONE` (0), `LPO_SUCCESS` (1), `LPO_FAILURE` (2).
    pub last_outcome: u8,
}

/// `PlanControlState` state and outcome values.
pub mod plan_state {
    /// Cannot execute plans.
    pub const BLOCKED: u8 = 0;
    /// Idle, ready for a plan.
    pub const READY: u8 = 1;
    /// Preparing a plan.
    pub const INITIALIZING: u8 = 2;
    /// Executing a plan.
    pub const EXECUTING: u8 = 3;
    /// No plan finished yet.
    pub const OUTCOME_NONE: u8 = 0;
    /// The last plan succeeded.
    pub const OUTCOME_SUCCESS: u8 = 1;
    /// The last plan failed.
    pub const OUTCOME_FAILURE: u8 = 2;
}

/// `Goto` (450): go to a point.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Goto {
    /// Give up after this many seconds.
    pub timeout: u16,
    /// Target latitude, radians.
    pub lat: f64,
    /// Target longitude, radians.
    pub lon: f64,
    /// Target z, metres, in `z_units`.
    pub z: f32,
    /// `Z_NONE` (0), `Z_DEPTH` (1), `Z_ALTITUDE` (2), `Z_HEIGHT` (3).
    pub z_units: u8,
    /// Speed, in `speed_units`.
    pub speed: f32,
    /// `SUNITS_METERS_PS` (0), `SUNITS_RPM` (1), `SUNITS_PERCENTAGE` (2).
    pub speed_units: u8,
    /// Roll, radians (-1 none).
    pub roll: f64,
    /// Pitch, radians (-1 none).
    pub pitch: f64,
    /// Yaw, radians (-1 none).
    pub yaw: f64,
    /// Custom settings (`key=value;...`).
    pub custom: String,
}

/// `StationKeeping` (461): hold a position within a radius.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct StationKeeping {
    /// Latitude, radians.
    pub lat: f64,
    /// Longitude, radians.
    pub lon: f64,
    /// Z, metres, in `z_units`.
    pub z: f32,
    /// Z units, as in [`Goto::z_units`].
    pub z_units: u8,
    /// Radius, metres.
    pub radius: f32,
    /// Seconds; 0 holds until stopped.
    pub duration: u16,
    /// Speed, in `speed_units`.
    pub speed: f32,
    /// Speed units, as in [`Goto::speed_units`].
    pub speed_units: u8,
    /// Custom settings.
    pub custom: String,
}

/// `Z_*` and `SUNITS_*` values.
pub mod units {
    /// Z is a depth.
    pub const Z_DEPTH: u8 = 1;
    /// Z is an altitude above the seabed.
    pub const Z_ALTITUDE: u8 = 2;
    /// Speed in metres per second.
    pub const SPEED_MPS: u8 = 0;
}

/// `PlanSpecification` (551): a plan, its maneuvers and transitions.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PlanSpecification {
    /// Plan id.
    pub plan_id: String,
    /// Description.
    pub description: String,
    /// Variables namespace.
    pub vnamespace: String,
    /// `PlanVariable`s (kept as messages).
    pub variables: Vec<Message>,
    /// First maneuver.
    pub start_man_id: String,
    /// The maneuvers.
    pub maneuvers: Vec<PlanManeuver>,
    /// Transitions between maneuvers.
    pub transitions: Vec<PlanTransition>,
    /// Actions at the start.
    pub start_actions: Vec<Message>,
    /// Actions at the end.
    pub end_actions: Vec<Message>,
}

/// `PlanManeuver` (552): one named maneuver of a plan.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PlanManeuver {
    /// Maneuver id within the plan.
    pub maneuver_id: String,
    /// The maneuver (`Goto`, `StationKeeping`, ...).
    pub data: Option<Box<Message>>,
    /// Actions at its start.
    pub start_actions: Vec<Message>,
    /// Actions at its end.
    pub end_actions: Vec<Message>,
}

/// `PlanTransition` (553): when to move from one maneuver to the next.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PlanTransition {
    /// From this maneuver.
    pub source_man: String,
    /// To this one.
    pub dest_man: String,
    /// Condition (DUNE uses `ManeuverIsDone`).
    pub conditions: String,
    /// Actions on the transition.
    pub actions: Vec<Message>,
}

/// `LogBookEntry` (103): a log line (DUNE sends errors and warnings this way).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct LogBookEntry {
    /// `LBET_INFO` (0), `WARNING` (1), `ERROR` (2), `CRITICAL` (3), `DEBUG` (4).
    pub kind: u8,
    /// When, s since the epoch.
    pub htime: f64,
    /// Context (entity).
    pub context: String,
    /// Text.
    pub text: String,
}

/// The IMC messages Shoal understands.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum Message {
    /// `Heartbeat` (150): "I am alive".
    Heartbeat,
    /// `Announce` (151).
    Announce(Announce),
    /// `LogBookEntry` (103).
    LogBookEntry(LogBookEntry),
    /// `FuelLevel` (279).
    FuelLevel(FuelLevel),
    /// `EstimatedState` (350).
    EstimatedState(EstimatedState),
    /// `Goto` (450).
    Goto(Goto),
    /// `StationKeeping` (461).
    StationKeeping(StationKeeping),
    /// `VehicleState` (500).
    VehicleState(VehicleState),
    /// `Abort` (550): stop everything.
    Abort,
    /// `PlanSpecification` (551).
    PlanSpecification(PlanSpecification),
    /// `PlanManeuver` (552).
    PlanManeuver(PlanManeuver),
    /// `PlanTransition` (553).
    PlanTransition(PlanTransition),
    /// `PlanControl` (559).
    PlanControl(PlanControl),
    /// `PlanControlState` (560).
    PlanControlState(PlanControlState),
}

/// Message ids, as in IMC.xml.
pub mod id {
    /// `LogBookEntry`.
    pub const LOG_BOOK_ENTRY: u16 = 103;
    /// `Heartbeat`.
    pub const HEARTBEAT: u16 = 150;
    /// `Announce`.
    pub const ANNOUNCE: u16 = 151;
    /// `FuelLevel`.
    pub const FUEL_LEVEL: u16 = 279;
    /// `EstimatedState`.
    pub const ESTIMATED_STATE: u16 = 350;
    /// `Goto`.
    pub const GOTO: u16 = 450;
    /// `StationKeeping`.
    pub const STATION_KEEPING: u16 = 461;
    /// `VehicleState`.
    pub const VEHICLE_STATE: u16 = 500;
    /// `Abort`.
    pub const ABORT: u16 = 550;
    /// `PlanSpecification`.
    pub const PLAN_SPECIFICATION: u16 = 551;
    /// `PlanManeuver`.
    pub const PLAN_MANEUVER: u16 = 552;
    /// `PlanTransition`.
    pub const PLAN_TRANSITION: u16 = 553;
    /// `PlanControl`.
    pub const PLAN_CONTROL: u16 = 559;
    /// `PlanControlState`.
    pub const PLAN_CONTROL_STATE: u16 = 560;
}

impl Message {
    /// The message's IMC id.
    pub fn id(&self) -> u16 {
        match self {
            Self::Heartbeat => id::HEARTBEAT,
            Self::Announce(_) => id::ANNOUNCE,
            Self::LogBookEntry(_) => id::LOG_BOOK_ENTRY,
            Self::FuelLevel(_) => id::FUEL_LEVEL,
            Self::EstimatedState(_) => id::ESTIMATED_STATE,
            Self::Goto(_) => id::GOTO,
            Self::StationKeeping(_) => id::STATION_KEEPING,
            Self::VehicleState(_) => id::VEHICLE_STATE,
            Self::Abort => id::ABORT,
            Self::PlanSpecification(_) => id::PLAN_SPECIFICATION,
            Self::PlanManeuver(_) => id::PLAN_MANEUVER,
            Self::PlanTransition(_) => id::PLAN_TRANSITION,
            Self::PlanControl(_) => id::PLAN_CONTROL,
            Self::PlanControlState(_) => id::PLAN_CONTROL_STATE,
        }
    }

    /// The message's IMC name.
    pub fn name(&self) -> &'static str {
        name_of(self.id()).unwrap_or("?")
    }
}

/// The name of a known message id.
pub fn name_of(mgid: u16) -> Option<&'static str> {
    Some(match mgid {
        id::HEARTBEAT => "Heartbeat",
        id::ANNOUNCE => "Announce",
        id::LOG_BOOK_ENTRY => "LogBookEntry",
        id::FUEL_LEVEL => "FuelLevel",
        id::ESTIMATED_STATE => "EstimatedState",
        id::GOTO => "Goto",
        id::STATION_KEEPING => "StationKeeping",
        id::VEHICLE_STATE => "VehicleState",
        id::ABORT => "Abort",
        id::PLAN_SPECIFICATION => "PlanSpecification",
        id::PLAN_MANEUVER => "PlanManeuver",
        id::PLAN_TRANSITION => "PlanTransition",
        id::PLAN_CONTROL => "PlanControl",
        id::PLAN_CONTROL_STATE => "PlanControlState",
        _ => return None,
    })
}

// ------------------------------------------------------------------ fields

/// A type of IMC field, written and read the same way in every message: so each
/// message's fields are listed once, in IMC.xml order, for both directions
/// ([`imc_fields!`]), and encoding and decoding cannot drift apart.
trait Field: Sized {
    /// Appends the field; `what` (`Message.field`) names it in a [`EncodeError::TooLong`].
    fn put(&self, w: &mut Writer, what: &'static str, depth: usize) -> Result<(), EncodeError>;
    /// Reads the field.
    fn get(r: &mut Reader<'_>, depth: usize) -> Result<Self, DecodeError>;
}

/// Numbers: their bytes in the packet's byte order.
macro_rules! number_fields {
    ($($t:ty),*) => {$(
        impl Field for $t {
            fn put(&self, w: &mut Writer, _: &'static str, _: usize) -> Result<(), EncodeError> {
                w.bytes(self.to_le_bytes(), self.to_be_bytes());
                Ok(())
            }
            fn get(r: &mut Reader<'_>, _: usize) -> Result<Self, DecodeError> {
                let b = r.take()?;
                Ok(match r.order {
                    ByteOrder::Little => <$t>::from_le_bytes(b),
                    ByteOrder::Big => <$t>::from_be_bytes(b),
                })
            }
        }
    )*};
}
number_fields!(u8, u16, u32, i32, f32, f64);

impl Field for String {
    fn put(&self, w: &mut Writer, what: &'static str, _: usize) -> Result<(), EncodeError> {
        w.text(self, what)
    }
    fn get(r: &mut Reader<'_>, _: usize) -> Result<Self, DecodeError> {
        r.text()
    }
}

/// An inline message, or none.
impl Field for Option<Box<Message>> {
    fn put(&self, w: &mut Writer, _: &'static str, depth: usize) -> Result<(), EncodeError> {
        w.inline(self.as_deref(), depth)
    }
    fn get(r: &mut Reader<'_>, depth: usize) -> Result<Self, DecodeError> {
        r.inline(depth)
    }
}

/// A message list.
impl Field for Vec<Message> {
    fn put(&self, w: &mut Writer, what: &'static str, depth: usize) -> Result<(), EncodeError> {
        w.list(self.iter(), depth, what)
    }
    fn get(r: &mut Reader<'_>, depth: usize) -> Result<Self, DecodeError> {
        r.list(depth)
    }
}

/// A message list whose entries must all be one message (a plan's maneuvers, its
/// transitions).
macro_rules! typed_list_fields {
    ($($t:ident: $variant:ident, $mgid:expr, $detail:literal;)*) => {$(
        impl Field for Vec<$t> {
            fn put(&self, w: &mut Writer, what: &'static str, depth: usize) -> Result<(), EncodeError> {
                w.typed_list(self, $mgid, depth, what, |w, m, d| m.put_fields(w, d))
            }
            fn get(r: &mut Reader<'_>, depth: usize) -> Result<Self, DecodeError> {
                r.typed_list(
                    depth,
                    |m| match m {
                        Message::$variant(x) => Some(x),
                        _ => None,
                    },
                    $detail,
                )
            }
        }
    )*};
}
typed_list_fields! {
    PlanManeuver: PlanManeuver, id::PLAN_MANEUVER, "maneuvers must be PlanManeuver";
    PlanTransition: PlanTransition, id::PLAN_TRANSITION, "transitions must be PlanTransition";
}

/// A message's payload: its fields in order.
trait Fields: Sized {
    fn put_fields(&self, w: &mut Writer, depth: usize) -> Result<(), EncodeError>;
    fn get_fields(r: &mut Reader<'_>, depth: usize) -> Result<Self, DecodeError>;
}

/// Lists each message's fields once, in IMC.xml (wire) order, for both directions.
macro_rules! imc_fields {
    ($($t:ident { $($f:ident),* $(,)? })*) => {$(
        impl Fields for $t {
            fn put_fields(&self, w: &mut Writer, depth: usize) -> Result<(), EncodeError> {
                $( Field::put(&self.$f, w, concat!(stringify!($t), ".", stringify!($f)), depth)?; )*
                Ok(())
            }
            fn get_fields(r: &mut Reader<'_>, depth: usize) -> Result<Self, DecodeError> {
                // Struct fields are evaluated in the order written: the wire order.
                Ok(Self { $( $f: Field::get(r, depth)?, )* })
            }
        }
    )*};
}
imc_fields! {
    Header { timestamp, src, src_ent, dst, dst_ent }
    Announce { sys_name, sys_type, owner, lat, lon, height, services }
    LogBookEntry { kind, htime, context, text }
    FuelLevel { value, confidence, opmodes }
    EstimatedState {
        lat, lon, height, x, y, z, phi, theta, psi, u, v, w, vx, vy, vz, p, q, r, depth, alt,
    }
    Goto { timeout, lat, lon, z, z_units, speed, speed_units, roll, pitch, yaw, custom }
    StationKeeping { lat, lon, z, z_units, radius, duration, speed, speed_units, custom }
    VehicleState {
        op_mode, error_count, error_ents, maneuver_type, maneuver_stime, maneuver_eta,
        control_loops, flags, last_error, last_error_time,
    }
    PlanSpecification {
        plan_id, description, vnamespace, variables, start_man_id, maneuvers, transitions,
        start_actions, end_actions,
    }
    PlanManeuver { maneuver_id, data, start_actions, end_actions }
    PlanTransition { source_man, dest_man, conditions, actions }
    PlanControl { kind, op, request_id, plan_id, flags, arg, info }
    PlanControlState {
        state, plan_id, plan_eta, plan_progress, man_id, man_type, man_eta, last_outcome,
    }
}

// ------------------------------------------------------------------ encoding

/// Appends values in one byte order.
struct Writer {
    out: Vec<u8>,
    order: ByteOrder,
}

impl Writer {
    fn bytes<const N: usize>(&mut self, le: [u8; N], be: [u8; N]) {
        match self.order {
            ByteOrder::Little => self.out.extend_from_slice(&le),
            ByteOrder::Big => self.out.extend_from_slice(&be),
        }
    }
    fn u16(&mut self, v: u16) {
        self.bytes(v.to_le_bytes(), v.to_be_bytes());
    }
    fn len16(&mut self, len: usize, what: &'static str) -> Result<(), EncodeError> {
        let n = u16::try_from(len).map_err(|_| EncodeError::TooLong(what))?;
        self.u16(n);
        Ok(())
    }
    fn text(&mut self, s: &str, what: &'static str) -> Result<(), EncodeError> {
        self.len16(s.len(), what)?;
        self.out.extend_from_slice(s.as_bytes());
        Ok(())
    }
    fn inline(&mut self, m: Option<&Message>, depth: usize) -> Result<(), EncodeError> {
        match m {
            None => {
                self.u16(NULL_ID);
                Ok(())
            }
            Some(m) => {
                self.u16(m.id());
                self.payload(m, depth + 1)
            }
        }
    }
    fn list<'a>(
        &mut self,
        items: impl ExactSizeIterator<Item = &'a Message>,
        depth: usize,
        what: &'static str,
    ) -> Result<(), EncodeError> {
        self.len16(items.len(), what)?;
        for m in items {
            self.u16(m.id());
            self.payload(m, depth + 1)?;
        }
        Ok(())
    }
    fn typed_list<T>(
        &mut self,
        items: &[T],
        mgid: u16,
        depth: usize,
        what: &'static str,
        mut each: impl FnMut(&mut Self, &T, usize) -> Result<(), EncodeError>,
    ) -> Result<(), EncodeError> {
        self.len16(items.len(), what)?;
        for item in items {
            self.u16(mgid);
            if depth + 1 > MAX_DEPTH {
                return Err(EncodeError::TooDeep);
            }
            each(self, item, depth + 1)?;
        }
        Ok(())
    }

    fn payload(&mut self, m: &Message, depth: usize) -> Result<(), EncodeError> {
        if depth > MAX_DEPTH {
            return Err(EncodeError::TooDeep);
        }
        match m {
            Message::Heartbeat | Message::Abort => Ok(()),
            Message::Announce(a) => a.put_fields(self, depth),
            Message::LogBookEntry(l) => l.put_fields(self, depth),
            Message::FuelLevel(f) => f.put_fields(self, depth),
            Message::EstimatedState(e) => e.put_fields(self, depth),
            Message::Goto(g) => g.put_fields(self, depth),
            Message::StationKeeping(s) => s.put_fields(self, depth),
            Message::VehicleState(v) => v.put_fields(self, depth),
            Message::PlanSpecification(p) => p.put_fields(self, depth),
            Message::PlanManeuver(p) => p.put_fields(self, depth),
            Message::PlanTransition(t) => t.put_fields(self, depth),
            Message::PlanControl(p) => p.put_fields(self, depth),
            Message::PlanControlState(s) => s.put_fields(self, depth),
        }
    }
}

/// Encodes a packet little-endian, as Shoal sends it.
pub fn encode(packet: &Packet) -> Result<Vec<u8>, EncodeError> {
    encode_with(packet, ByteOrder::Little)
}

/// Encodes a packet in the given byte order.
pub fn encode_with(packet: &Packet, order: ByteOrder) -> Result<Vec<u8>, EncodeError> {
    let mut body = Writer {
        out: Vec::with_capacity(128),
        order,
    };
    body.payload(&packet.message, 0)?;
    let size = u16::try_from(body.out.len()).map_err(|_| EncodeError::TooLong("payload"))?;
    let mut w = Writer {
        out: Vec::with_capacity(HEADER_LEN + body.out.len() + FOOTER_LEN),
        order,
    };
    w.u16(SYNC);
    w.u16(packet.message.id());
    w.u16(size);
    packet.header.put_fields(&mut w, 0)?;
    w.out.extend_from_slice(&body.out);
    let crc = crc16(&w.out);
    w.u16(crc);
    Ok(w.out)
}

// ------------------------------------------------------------------ decoding

/// Reads values in one byte order, failing (never panicking) past the end.
struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
    order: ByteOrder,
    message: &'static str,
}

impl<'a> Reader<'a> {
    fn malformed(&self, detail: &'static str) -> DecodeError {
        DecodeError::Malformed {
            message: self.message,
            detail,
        }
    }
    fn take<const N: usize>(&mut self) -> Result<[u8; N], DecodeError> {
        let end = self.pos.checked_add(N).filter(|e| *e <= self.buf.len());
        let Some(end) = end else {
            return Err(self.malformed("payload shorter than its fields"));
        };
        let mut a = [0u8; N];
        a.copy_from_slice(&self.buf[self.pos..end]);
        self.pos = end;
        Ok(a)
    }
    fn u16(&mut self) -> Result<u16, DecodeError> {
        u16::get(self, 0)
    }
    fn text(&mut self) -> Result<String, DecodeError> {
        let n = usize::from(self.u16()?);
        let end = self.pos.checked_add(n).filter(|e| *e <= self.buf.len());
        let Some(end) = end else {
            return Err(self.malformed("text longer than the payload"));
        };
        // IMC text is ASCII; bytes that are not even UTF-8 are corruption.
        let s = std::str::from_utf8(&self.buf[self.pos..end])
            .map_err(|_| self.malformed("text is not UTF-8"))?
            .to_string();
        self.pos = end;
        Ok(s)
    }
    fn inline(&mut self, depth: usize) -> Result<Option<Box<Message>>, DecodeError> {
        let mgid = self.u16()?;
        if mgid == NULL_ID {
            return Ok(None);
        }
        Ok(Some(Box::new(self.message(mgid, depth + 1)?)))
    }
    fn list(&mut self, depth: usize) -> Result<Vec<Message>, DecodeError> {
        let n = usize::from(self.u16()?);
        // Each entry takes at least its 2-byte id: a count beyond that is a lie, and must
        // not size an allocation.
        if n > (self.buf.len() - self.pos) / 2 {
            return Err(self.malformed("message list longer than the payload"));
        }
        let mut out = Vec::with_capacity(n);
        for _ in 0..n {
            let mgid = self.u16()?;
            if mgid == NULL_ID {
                return Err(self.malformed("empty entry in a message list"));
            }
            out.push(self.message(mgid, depth + 1)?);
        }
        Ok(out)
    }
    fn typed_list<T>(
        &mut self,
        depth: usize,
        pick: impl Fn(Message) -> Option<T>,
        detail: &'static str,
    ) -> Result<Vec<T>, DecodeError> {
        let parent = self.message;
        let list = self.list(depth)?;
        self.message = parent;
        list.into_iter()
            .map(|m| pick(m).ok_or(self.malformed(detail)))
            .collect()
    }

    /// Decodes one message payload of id `mgid` at the current position.
    fn message(&mut self, mgid: u16, depth: usize) -> Result<Message, DecodeError> {
        if depth > MAX_DEPTH {
            return Err(self.malformed("inline messages nested too deep"));
        }
        let parent = self.message;
        self.message = name_of(mgid).ok_or(DecodeError::UnknownMessage(mgid))?;
        let m = self.fields(mgid, depth)?;
        self.message = parent;
        Ok(m)
    }

    fn fields(&mut self, mgid: u16, depth: usize) -> Result<Message, DecodeError> {
        let d = depth;
        Ok(match mgid {
            id::HEARTBEAT => Message::Heartbeat,
            id::ABORT => Message::Abort,
            id::ANNOUNCE => Message::Announce(Fields::get_fields(self, d)?),
            id::LOG_BOOK_ENTRY => Message::LogBookEntry(Fields::get_fields(self, d)?),
            id::FUEL_LEVEL => Message::FuelLevel(Fields::get_fields(self, d)?),
            id::ESTIMATED_STATE => Message::EstimatedState(Fields::get_fields(self, d)?),
            id::GOTO => Message::Goto(Fields::get_fields(self, d)?),
            id::STATION_KEEPING => Message::StationKeeping(Fields::get_fields(self, d)?),
            id::VEHICLE_STATE => Message::VehicleState(Fields::get_fields(self, d)?),
            id::PLAN_SPECIFICATION => Message::PlanSpecification(Fields::get_fields(self, d)?),
            id::PLAN_MANEUVER => Message::PlanManeuver(Fields::get_fields(self, d)?),
            id::PLAN_TRANSITION => Message::PlanTransition(Fields::get_fields(self, d)?),
            id::PLAN_CONTROL => Message::PlanControl(Fields::get_fields(self, d)?),
            id::PLAN_CONTROL_STATE => Message::PlanControlState(Fields::get_fields(self, d)?),
            other => return Err(DecodeError::UnknownMessage(other)),
        })
    }
}

/// The byte order a synchronisation number reveals, if it is IMC 5.4's.
fn order_of(first_two: [u8; 2]) -> Option<ByteOrder> {
    match u16::from_le_bytes(first_two) {
        SYNC => Some(ByteOrder::Little),
        SYNC_SWAPPED => Some(ByteOrder::Big),
        _ => None,
    }
}

/// Decodes the packet at the start of `bytes`; returns it with the byte order it was
/// sent in and the number of bytes it took.
///
/// The checks run cheapest first: sync, length, CRC, then the message id and fields. A
/// packet whose id is unknown is reported as [`DecodeError::UnknownMessage`] only after its
/// CRC checked out, so the error means "a real IMC message Shoal does not use".
pub fn decode(bytes: &[u8]) -> Result<(Packet, ByteOrder, usize), DecodeError> {
    let truncated = |needed: usize| DecodeError::Truncated {
        needed,
        available: bytes.len(),
    };
    // Sync first, so that short garbage counts as garbage rather than as a cut packet.
    let [b0, b1, ..] = bytes else {
        return Err(truncated(HEADER_LEN + FOOTER_LEN));
    };
    let Some(order) = order_of([*b0, *b1]) else {
        return Err(DecodeError::BadSync(u16::from_be_bytes([*b0, *b1])));
    };
    if bytes.len() < HEADER_LEN + FOOTER_LEN {
        return Err(truncated(HEADER_LEN + FOOTER_LEN));
    }
    let mut h = Reader {
        buf: &bytes[..HEADER_LEN],
        pos: 2,
        order,
        message: "header",
    };
    let mgid = h.u16()?;
    let size = usize::from(h.u16()?);
    let header = Header::get_fields(&mut h, 0)?;
    let total = HEADER_LEN + size + FOOTER_LEN;
    if bytes.len() < total {
        return Err(truncated(total));
    }
    let body_end = HEADER_LEN + size;
    let mut footer = Reader {
        buf: &bytes[body_end..total],
        pos: 0,
        order,
        message: "footer",
    };
    let received = footer.u16()?;
    let computed = crc16(&bytes[..body_end]);
    if computed != received {
        return Err(DecodeError::BadCrc { computed, received });
    }
    let mut r = Reader {
        buf: &bytes[HEADER_LEN..body_end],
        pos: 0,
        order,
        message: "payload",
    };
    let message = r.message(mgid, 0)?;
    if r.pos != r.buf.len() {
        return Err(DecodeError::Malformed {
            message: name_of(mgid).unwrap_or("?"),
            detail: "payload longer than its fields",
        });
    }
    Ok((Packet { header, message }, order, total))
}

/// Where the next packet may start in `bytes` after a failure at offset 0: the next
/// synchronisation number in either byte order, or the end.
pub fn resync(bytes: &[u8]) -> usize {
    bytes
        .windows(2)
        .skip(1)
        .position(|w| order_of([w[0], w[1]]).is_some())
        .map_or(bytes.len(), |p| p + 1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn header() -> Header {
        Header {
            timestamp: 1.5,
            src: 0x1234,
            src_ent: 1,
            dst: 0x5678,
            dst_ent: 2,
        }
    }

    #[test]
    fn a_heartbeat_is_byte_for_byte_what_imcpy_sends() {
        // imcpy 1.1.2: Heartbeat with src 0x1234/1, dst 0x5678/2, timestamp 1.5.
        let expected = "54fe96000000000000000000f83f341201785602ab92";
        let p = Packet {
            header: header(),
            message: Message::Heartbeat,
        };
        let bytes = encode(&p).unwrap();
        assert_eq!(hex::encode(&bytes), expected);
        let (back, order, used) = decode(&bytes).unwrap();
        assert_eq!((back, order, used), (p, ByteOrder::Little, 22));
    }

    #[test]
    fn a_big_endian_packet_is_recognised_by_its_swapped_sync() {
        let p = Packet {
            header: header(),
            message: Message::FuelLevel(FuelLevel {
                value: 77.5,
                confidence: 90.0,
                opmodes: "Survey=3.5".into(),
            }),
        };
        let be = encode_with(&p, ByteOrder::Big).unwrap();
        assert_eq!(&be[..2], &[0xFE, 0x54]);
        let le = encode(&p).unwrap();
        assert_eq!(&le[..2], &[0x54, 0xFE]);
        assert_ne!(be, le);
        let (back, order, _) = decode(&be).unwrap();
        assert_eq!(order, ByteOrder::Big);
        assert_eq!(back, p);
    }

    #[test]
    fn the_crc_is_crc16_arc() {
        // The standard check value of CRC-16/ARC.
        assert_eq!(crc16(b"123456789"), 0xBB3D);
    }

    #[test]
    fn a_flipped_bit_is_a_crc_error() {
        let mut bytes = encode(&Packet {
            header: header(),
            message: Message::Abort,
        })
        .unwrap();
        bytes[10] ^= 0x01;
        assert!(matches!(decode(&bytes), Err(DecodeError::BadCrc { .. })));
    }

    #[test]
    fn an_unknown_id_with_a_good_crc_is_reported_as_unknown() {
        let mut bytes = encode(&Packet {
            header: header(),
            message: Message::Heartbeat,
        })
        .unwrap();
        // EntityState (1): a real message this codec does not use.
        bytes[2] = 1;
        bytes[3] = 0;
        let n = bytes.len();
        let crc = crc16(&bytes[..n - 2]).to_le_bytes();
        bytes[n - 2..].copy_from_slice(&crc);
        assert_eq!(decode(&bytes), Err(DecodeError::UnknownMessage(1)));
    }

    #[test]
    fn lengths_that_lie_are_errors_not_panics() {
        let p = Packet {
            header: header(),
            message: Message::PlanControlState(PlanControlState {
                plan_id: "p".into(),
                ..PlanControlState::default()
            }),
        };
        let good = encode(&p).unwrap();
        for cut in 0..good.len() {
            assert!(decode(&good[..cut]).is_err(), "cut at {cut}");
        }
        // A text length pointing past the payload, with the CRC fixed up.
        let mut bad = good;
        bad[HEADER_LEN + 1] = 0xFF;
        let n = bad.len();
        let crc = crc16(&bad[..n - 2]).to_le_bytes();
        bad[n - 2..].copy_from_slice(&crc);
        assert!(matches!(decode(&bad), Err(DecodeError::Malformed { .. })));
    }

    #[test]
    fn resync_finds_the_next_packet_after_garbage() {
        let mut bytes = vec![0x00, 0x54, 0x13, 0x37];
        let pkt = encode(&Packet {
            header: header(),
            message: Message::Heartbeat,
        })
        .unwrap();
        bytes.extend_from_slice(&pkt);
        assert!(decode(&bytes).is_err());
        let skip = resync(&bytes);
        assert_eq!(skip, 4);
        assert!(decode(&bytes[skip..]).is_ok());
        assert_eq!(resync(&[1, 2, 3]), 3);
    }

    #[test]
    fn deep_nesting_is_refused_both_ways() {
        let mut m = Message::Abort;
        for _ in 0..=MAX_DEPTH {
            m = Message::PlanControl(PlanControl {
                arg: Some(Box::new(m)),
                ..PlanControl::default()
            });
        }
        let p = Packet {
            header: header(),
            message: m,
        };
        assert_eq!(encode(&p), Err(EncodeError::TooDeep));
    }

    fn text() -> impl Strategy<Value = String> {
        "[ -~]{0,24}"
    }

    // Floats are compared bit for bit by PartialEq only when not NaN, so NaN is left out;
    // infinities and subnormals stay in.
    fn f32s() -> impl Strategy<Value = f32> {
        any::<f32>().prop_filter("not NaN", |v| !v.is_nan())
    }
    fn f64s() -> impl Strategy<Value = f64> {
        any::<f64>().prop_filter("not NaN", |v| !v.is_nan())
    }

    fn goto() -> impl Strategy<Value = Goto> {
        (
            any::<u16>(),
            f64s(),
            f64s(),
            f32s(),
            any::<u8>(),
            f32s(),
            any::<u8>(),
            (f64s(), f64s(), f64s()),
            text(),
        )
            .prop_map(
                |(
                    timeout,
                    lat,
                    lon,
                    z,
                    z_units,
                    speed,
                    speed_units,
                    (roll, pitch, yaw),
                    custom,
                )| {
                    Goto {
                        timeout,
                        lat,
                        lon,
                        z,
                        z_units,
                        speed,
                        speed_units,
                        roll,
                        pitch,
                        yaw,
                        custom,
                    }
                },
            )
    }

    fn leaf() -> impl Strategy<Value = Message> {
        prop_oneof![
            Just(Message::Heartbeat),
            Just(Message::Abort),
            goto().prop_map(Message::Goto),
            (
                text(),
                any::<u8>(),
                any::<u16>(),
                f64s(),
                f64s(),
                f32s(),
                text()
            )
                .prop_map(|(sys_name, sys_type, owner, lat, lon, height, services)| {
                    Message::Announce(Announce {
                        sys_name,
                        sys_type,
                        owner,
                        lat,
                        lon,
                        height,
                        services,
                    })
                }),
            (f64s(), f64s(), prop::collection::vec(f32s(), 18)).prop_map(|(lat, lon, f)| {
                Message::EstimatedState(EstimatedState {
                    lat,
                    lon,
                    height: f[0],
                    x: f[1],
                    y: f[2],
                    z: f[3],
                    phi: f[4],
                    theta: f[5],
                    psi: f[6],
                    u: f[7],
                    v: f[8],
                    w: f[9],
                    vx: f[10],
                    vy: f[11],
                    vz: f[12],
                    p: f[13],
                    q: f[14],
                    r: f[15],
                    depth: f[16],
                    alt: f[17],
                })
            }),
            (f32s(), f32s(), text()).prop_map(|(value, confidence, opmodes)| {
                Message::FuelLevel(FuelLevel {
                    value,
                    confidence,
                    opmodes,
                })
            }),
            (
                (any::<u8>(), any::<u8>(), text(), any::<u16>(), f64s()),
                (any::<u16>(), any::<u32>(), any::<u8>(), text(), f64s())
            )
                .prop_map(|((a, b, c, d, e), (f, g, h, i, j))| {
                    Message::VehicleState(VehicleState {
                        op_mode: a,
                        error_count: b,
                        error_ents: c,
                        maneuver_type: d,
                        maneuver_stime: e,
                        maneuver_eta: f,
                        control_loops: g,
                        flags: h,
                        last_error: i,
                        last_error_time: j,
                    })
                }),
            (
                any::<u8>(),
                text(),
                any::<i32>(),
                f32s(),
                text(),
                any::<u16>(),
                any::<i32>(),
                any::<u8>()
            )
                .prop_map(
                    |(
                        state,
                        plan_id,
                        plan_eta,
                        plan_progress,
                        man_id,
                        man_type,
                        man_eta,
                        last_outcome,
                    )| {
                        Message::PlanControlState(PlanControlState {
                            state,
                            plan_id,
                            plan_eta,
                            plan_progress,
                            man_id,
                            man_type,
                            man_eta,
                            last_outcome,
                        })
                    }
                ),
            (
                f64s(),
                f64s(),
                f32s(),
                any::<u8>(),
                f32s(),
                any::<u16>(),
                f32s(),
                any::<u8>(),
                text()
            )
                .prop_map(
                    |(lat, lon, z, z_units, radius, duration, speed, speed_units, custom)| {
                        Message::StationKeeping(StationKeeping {
                            lat,
                            lon,
                            z,
                            z_units,
                            radius,
                            duration,
                            speed,
                            speed_units,
                            custom,
                        })
                    }
                ),
            (any::<u8>(), f64s(), text(), text()).prop_map(|(kind, htime, context, text)| {
                Message::LogBookEntry(LogBookEntry {
                    kind,
                    htime,
                    context,
                    text,
                })
            }),
        ]
    }

    fn plan_maneuver() -> impl Strategy<Value = PlanManeuver> {
        (
            text(),
            prop::option::of(leaf()),
            prop::collection::vec(leaf(), 0..3),
        )
            .prop_map(|(maneuver_id, data, start_actions)| PlanManeuver {
                maneuver_id,
                data: data.map(Box::new),
                start_actions,
                end_actions: Vec::new(),
            })
    }

    fn plan_spec() -> impl Strategy<Value = PlanSpecification> {
        (
            text(),
            text(),
            prop::collection::vec(plan_maneuver(), 0..5),
            prop::collection::vec((text(), text(), text()), 0..5),
            prop::collection::vec(leaf(), 0..2),
        )
            .prop_map(
                |(plan_id, start_man_id, maneuvers, transitions, end_actions)| PlanSpecification {
                    plan_id,
                    description: "lawnmower".into(),
                    vnamespace: String::new(),
                    variables: Vec::new(),
                    start_man_id,
                    maneuvers,
                    transitions: transitions
                        .into_iter()
                        .map(|(source_man, dest_man, conditions)| PlanTransition {
                            source_man,
                            dest_man,
                            conditions,
                            actions: Vec::new(),
                        })
                        .collect(),
                    start_actions: Vec::new(),
                    end_actions,
                },
            )
    }

    fn message() -> impl Strategy<Value = Message> {
        prop_oneof![
            leaf(),
            plan_maneuver().prop_map(Message::PlanManeuver),
            plan_spec().prop_map(Message::PlanSpecification),
            (
                any::<u8>(),
                any::<u8>(),
                any::<u16>(),
                text(),
                any::<u16>(),
                prop::option::of(prop_oneof![
                    leaf(),
                    plan_spec().prop_map(Message::PlanSpecification)
                ]),
                text()
            )
                .prop_map(|(kind, op, request_id, plan_id, flags, arg, info)| {
                    Message::PlanControl(PlanControl {
                        kind,
                        op,
                        request_id,
                        plan_id,
                        flags,
                        arg: arg.map(Box::new),
                        info,
                    })
                }),
        ]
    }

    proptest! {
        #[test]
        fn every_message_round_trips_in_both_byte_orders(
            m in message(),
            big in any::<bool>(),
            (timestamp, src, src_ent, dst, dst_ent) in (f64s(), any::<u16>(), any::<u8>(), any::<u16>(), any::<u8>()),
        ) {
            let order = if big { ByteOrder::Big } else { ByteOrder::Little };
            let p = Packet { header: Header { timestamp, src, src_ent, dst, dst_ent }, message: m };
            let bytes = encode_with(&p, order).unwrap();
            let (back, got_order, used) = decode(&bytes).unwrap();
            prop_assert_eq!(used, bytes.len());
            prop_assert_eq!(got_order, order);
            prop_assert_eq!(back, p);
        }

        #[test]
        fn arbitrary_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..256)) {
            let _ = decode(&bytes);
            let skip = resync(&bytes);
            prop_assert!(skip <= bytes.len());
        }

        #[test]
        fn a_valid_header_with_a_random_payload_never_panics(
            mgid in prop::sample::select(vec![103u16, 150, 151, 279, 350, 450, 461, 500, 550, 551, 552, 553, 559, 560]),
            payload in prop::collection::vec(any::<u8>(), 0..200),
        ) {
            // A correct header and CRC around garbage: only the field decoders stand guard.
            let mut bytes = Vec::new();
            bytes.extend_from_slice(&SYNC.to_le_bytes());
            bytes.extend_from_slice(&mgid.to_le_bytes());
            bytes.extend_from_slice(&u16::try_from(payload.len()).unwrap().to_le_bytes());
            bytes.extend_from_slice(&[0u8; 14]);
            bytes.extend_from_slice(&payload);
            let crc = crc16(&bytes);
            bytes.extend_from_slice(&crc.to_le_bytes());
            match decode(&bytes) {
                Ok((p, _, used)) => {
                    prop_assert_eq!(used, bytes.len());
                    // What decodes re-encodes to the same bytes (floats carry their bits).
                    prop_assert_eq!(encode(&p).unwrap(), bytes);
                }
                Err(e) => prop_assert!(matches!(e, DecodeError::Malformed { .. } | DecodeError::UnknownMessage(_)), "{e}"),
            }
        }
    }
}
