//! The WAN encoding, version 1: hand-packed little-endian fields, fixed point where a
//! float would waste bytes. `docs/federation.md` gives the byte layout a third party
//! decodes from; this file and that table must agree (the tests check the offsets).
//!
//! Every frame opens with a version byte and a kind byte; a decoder refuses any other
//! version, a frame cut short, bytes past the end and any code or value outside its
//! range, so that what it returns always passes the model's validation.
//!
//! Positions carry no site or vehicle name: both are in the key expression, and a
//! position crosses every few seconds for every vehicle. Alarms and task transitions
//! carry their site, the sender's epoch and a sequence number, which the receiver uses to
//! suppress duplicates and to ask for what it missed. Orders (a task the lease holder
//! sends to the vehicle's home site) carry the same envelope; they are rare, so their
//! numbers are plain `f64`s, exact, rather than fixed point. Environment summaries carry
//! the envelope too (numbered, never caught up); their statistics are `f64`s, since a
//! property's range and resolution are unknown to the federation, and the place of the
//! latest observation is coded as a position's.

use shoal_model::{
    Event, EventKind, GeoPoint, MAX_ID_LEN, MAX_NAME_LEN, MAX_TEXT_LEN, MAX_TIMESTAMP_MS,
    MAX_VEHICLE_ID_LEN, MIN_TIMESTAMP_MS, Severity, TaskAssignment, TaskKind, TaskState, Validate,
    ValidationError, VehicleKind,
};

use crate::environment::{EnvironmentAggregates, MAX_PROPERTIES_PER_FRAME, PropertyAggregate};
use crate::lease::{LeaseReason, LeaseRecord};
use crate::types::{MAX_SITE_LEN, TaskTransition, VehiclePosition, is_site_name};

/// The wire version this crate writes and reads.
pub const VERSION: u8 = 1;
/// Kind byte of a position frame.
pub const KIND_POSITION: u8 = 1;
/// Kind byte of an alarm frame.
pub const KIND_ALARM: u8 = 2;
/// Kind byte of a task-transition frame.
pub const KIND_TASK: u8 = 3;
/// Kind byte of a command-lease frame.
pub const KIND_LEASE: u8 = 4;
/// Kind byte of an order frame (a task relayed through the vehicle's home site).
pub const KIND_ORDER: u8 = 5;
/// Kind byte of an environment frame (a vehicle's summaries of one window).
pub const KIND_ENVIRONMENT: u8 = 6;
/// Kind byte of an identity frame (a site's certificate chain, [`crate::signed`]).
pub const KIND_IDENTITY: u8 = 7;
/// Kind byte of a catch-up end frame: the last reply of every catch-up answer.
pub const KIND_CATCHUP_END: u8 = 8;
/// Size of a position frame, bytes.
pub const POSITION_LEN: usize = 24;

/// Latitude and longitude step: 1e-7 degree (about 1.1 cm of latitude).
const DEG_SCALE: f64 = 1e7;
/// Depth step, metres: 11 000 m fits a u16 at 0.2 m.
const DEPTH_STEP_M: f64 = 0.2;
/// Heading step: a full turn in a u16.
const HEADING_STEP_DEG: f64 = 360.0 / 65_536.0;
/// Speed step, m/s.
const SPEED_STEP_MPS: f64 = 0.01;
/// Battery step, percent.
const BATTERY_STEP_PCT: f64 = 0.5;

// Codes of the model's enums, in the order of `idl/shoal.idl` (their declaration order).
const VEHICLE_KINDS: [VehicleKind; 5] = [
    VehicleKind::Auv,
    VehicleKind::Usv,
    VehicleKind::Asv,
    VehicleKind::Rov,
    VehicleKind::Glider,
];
const SEVERITIES: [Severity; 4] = [
    Severity::Info,
    Severity::Warning,
    Severity::Alarm,
    Severity::Critical,
];
const EVENT_KINDS: [EventKind; 9] = [
    EventKind::LowBattery,
    EventKind::OutOfArea,
    EventKind::CommLost,
    EventKind::Fault,
    EventKind::Detection,
    EventKind::Task,
    EventKind::Rule,
    EventKind::DataRejected,
    EventKind::Other,
];
const TASK_KINDS: [TaskKind; 8] = TaskKind::ALL;
const TASK_STATES: [TaskState; 8] = [
    TaskState::Pending,
    TaskState::Sent,
    TaskState::Accepted,
    TaskState::Running,
    TaskState::Done,
    TaskState::Failed,
    TaskState::Aborted,
    TaskState::Expired,
];

/// Why bytes were refused as a frame.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum DecodeError {
    /// The frame ended before a field.
    #[error("frame too short: {field} needs bytes past the end")]
    Truncated {
        /// The field that did not fit.
        field: &'static str,
    },
    /// A version this decoder does not read.
    #[error("wire version {0} is not supported (this decoder reads version {VERSION})")]
    Version(u8),
    /// A frame of another kind than the key expression announces.
    #[error("frame kind {found} where kind {expected} was expected")]
    Kind {
        /// The kind the key expression calls for.
        expected: u8,
        /// The kind byte received.
        found: u8,
    },
    /// An enum code outside its table.
    #[error("{field} code {value} is unknown")]
    Code {
        /// The field.
        field: &'static str,
        /// The code received.
        value: u8,
    },
    /// A fixed-point value outside its encoded range.
    #[error("{field} = {value} is outside its encoded range")]
    Range {
        /// The field.
        field: &'static str,
        /// The raw value received.
        value: i64,
    },
    /// A text field that is not UTF-8.
    #[error("{field} is not UTF-8")]
    Utf8 {
        /// The field.
        field: &'static str,
    },
    /// Bytes after the last field.
    #[error("{0} bytes after the end of the frame")]
    Trailing(usize),
    /// Decoded, but the value breaks the model's rules (e.g. a bad identifier).
    #[error(transparent)]
    Invalid(#[from] ValidationError),
}

impl DecodeError {
    /// A stable short code for counters, e.g. `truncated`, `code:severity`,
    /// `invalid:bad_text:event_id`.
    pub fn reason(&self) -> String {
        match self {
            Self::Truncated { .. } => "truncated".into(),
            Self::Version(_) => "version".into(),
            Self::Kind { .. } => "kind".into(),
            Self::Code { field, .. } => format!("code:{field}"),
            Self::Range { field, .. } => format!("range:{field}"),
            Self::Utf8 { field } => format!("utf8:{field}"),
            Self::Trailing(_) => "trailing".into(),
            Self::Invalid(e) => format!("invalid:{}", e.reason()),
        }
    }
}

/// The envelope of a sequenced frame: who sent it and where it sits in the sender's
/// stream.
#[derive(Debug, Clone, PartialEq)]
pub struct Sequenced<T> {
    /// The sending site.
    pub site: String,
    /// The sender's epoch: when its federation started, ms since the Unix epoch. A
    /// restarted sender numbers from 1 again under a later epoch.
    pub epoch: u64,
    /// Position in the sender's stream, from 1, without gaps.
    pub seq: u64,
    /// The alarm, transition or order.
    pub item: T,
}

// ------------------------------------------------------------------ encoding

/// Encodes a position (validated first) into its 24-byte frame.
pub fn encode_position(p: &VehiclePosition) -> Result<Vec<u8>, ValidationError> {
    p.validate()?;
    let mut out = Vec::with_capacity(POSITION_LEN);
    out.extend([VERSION, KIND_POSITION, code_of(&VEHICLE_KINDS, p.kind)]);
    put_u48(&mut out, p.timestamp_ms);
    // Validated ranges keep every rounded value inside its integer type.
    out.extend(fixed_i32(p.latitude_deg * DEG_SCALE).to_le_bytes());
    out.extend(fixed_i32(p.longitude_deg * DEG_SCALE).to_le_bytes());
    out.extend(fixed_u16(p.depth_m / DEPTH_STEP_M).to_le_bytes());
    // 359.999..° rounds to a full turn, which is north again.
    let heading = (p.heading_deg / HEADING_STEP_DEG).round() as u32 % 65_536;
    out.extend((heading as u16).to_le_bytes());
    out.extend(fixed_u16(p.speed_mps / SPEED_STEP_MPS).to_le_bytes());
    out.push((p.battery_pct / BATTERY_STEP_PCT).round() as u8);
    Ok(out)
}

/// Encodes an alarm (validated first) with its envelope.
pub fn encode_alarm(
    site: &str,
    epoch: u64,
    seq: u64,
    e: &Event,
) -> Result<Vec<u8>, ValidationError> {
    e.validate()?;
    let mut out = envelope(KIND_ALARM, site, epoch, seq, e.timestamp_ms)?;
    out.push(code_of(&SEVERITIES, e.severity));
    out.push(code_of(&EVENT_KINDS, e.kind));
    put_str8(&mut out, &e.event_id);
    put_str8(&mut out, &e.vehicle_id);
    put_str8(&mut out, &e.task_id);
    // Validation caps the text at 512 bytes, well inside a u16.
    out.extend((e.text.len() as u16).to_le_bytes());
    out.extend(e.text.as_bytes());
    Ok(out)
}

/// Encodes a task transition (validated first) with its envelope.
pub fn encode_task(
    site: &str,
    epoch: u64,
    seq: u64,
    t: &TaskTransition,
) -> Result<Vec<u8>, ValidationError> {
    t.validate()?;
    let mut out = envelope(KIND_TASK, site, epoch, seq, t.timestamp_ms)?;
    out.push(code_of(&TASK_STATES, t.state));
    put_str8(&mut out, &t.task_id);
    put_str8(&mut out, &t.mission_id);
    put_str8(&mut out, &t.vehicle_id);
    Ok(out)
}

/// Encodes a command-lease record (checked first); the vehicle is in the key expression.
pub fn encode_lease(r: &LeaseRecord) -> Result<Vec<u8>, ValidationError> {
    r.check().map_err(|field| ValidationError::BadText {
        field,
        rule: "must be an identifier (term: at least 1, a time in 2000..2100)",
    })?;
    let mut out = Vec::with_capacity(24 + r.holder.len() + r.home.len() + r.standby.len());
    out.extend([VERSION, KIND_LEASE, r.reason.code()]);
    out.extend(r.term.to_le_bytes());
    put_u48(&mut out, r.granted_ms);
    put_str8(&mut out, &r.holder);
    put_str8(&mut out, &r.home);
    put_str8(&mut out, &r.standby);
    Ok(out)
}

/// Encodes an order: a task `site` sends, under the command lease it holds, to the
/// vehicle's home site (validated first). The vehicle is in the key expression and the
/// lease holder is the envelope's site, so neither is repeated; `issue_seq` and
/// `expires_ms` are not carried (the home station stamps its own).
pub fn encode_order(
    site: &str,
    epoch: u64,
    seq: u64,
    task: &TaskAssignment,
) -> Result<Vec<u8>, ValidationError> {
    task.validate()?;
    if task.lease_term == 0 {
        return Err(ValidationError::Inconsistent {
            field: "lease_term",
            rule: "an order goes under a command lease (term at least 1)",
        });
    }
    // The holder is not carried: the receiver takes it from the envelope, which its key
    // authenticates. A task under another site's lease would come out changed.
    if task.lease_holder != site {
        return Err(ValidationError::Inconsistent {
            field: "lease_holder",
            rule: "an order goes under the sending site's own lease",
        });
    }
    let mut out = envelope(KIND_ORDER, site, epoch, seq, task.issued_ms)?;
    out.push(code_of(&TASK_KINDS, task.kind));
    out.extend(task.lease_term.to_le_bytes());
    for v in [
        task.depth_m,
        task.altitude_m,
        task.speed_mps,
        task.line_spacing_m,
        task.duration_s,
        task.rate_hz,
    ] {
        out.extend(v.to_le_bytes());
    }
    put_str8(&mut out, &task.task_id);
    put_str8(&mut out, &task.mission_id);
    // Validation caps the area at 256 points.
    out.extend((task.area.len() as u16).to_le_bytes());
    // f64, not the positions' 1e-7 degree: the vehicle gets the very polygon the holder's
    // station validated and recorded (rounding could make a valid survey polygon touch
    // itself), for at most 4 kB in a message that is rare.
    for p in &task.area {
        out.extend(p.latitude_deg.to_le_bytes());
        out.extend(p.longitude_deg.to_le_bytes());
    }
    Ok(out)
}

/// Encodes a vehicle's summaries of one window (validated first) with its envelope; the
/// envelope's timestamp is the window's end, and the vehicle is in the key expression.
pub fn encode_environment(
    site: &str,
    epoch: u64,
    seq: u64,
    a: &EnvironmentAggregates,
) -> Result<Vec<u8>, ValidationError> {
    a.validate()?;
    let mut out = envelope(KIND_ENVIRONMENT, site, epoch, seq, a.window_end_ms)?;
    put_u48(&mut out, a.window_start_ms);
    // Validation caps the count at 32.
    out.push(a.properties.len() as u8);
    for p in &a.properties {
        put_str8(&mut out, &p.property);
        // Validation caps the unit at 16 bytes.
        put_str8(&mut out, &p.unit);
        out.extend(p.count.to_le_bytes());
        for v in [p.min, p.max, p.mean, p.last_value] {
            out.extend(v.to_le_bytes());
        }
        put_u48(&mut out, p.last_ms);
        // As a position's: the place of the latest observation locates the summary; it is
        // not a measurement of its own, and 0.2 m of depth is finer than a window of a
        // moving vehicle resolves (2 bytes where an f32 would take 4).
        out.extend(fixed_i32(p.latitude_deg * DEG_SCALE).to_le_bytes());
        out.extend(fixed_i32(p.longitude_deg * DEG_SCALE).to_le_bytes());
        out.extend(fixed_u16(p.depth_m / DEPTH_STEP_M).to_le_bytes());
    }
    Ok(out)
}

fn envelope(
    kind: u8,
    site: &str,
    epoch: u64,
    seq: u64,
    timestamp_ms: i64,
) -> Result<Vec<u8>, ValidationError> {
    check_site(site)?;
    let mut out = Vec::with_capacity(64);
    out.extend([VERSION, kind]);
    put_str8(&mut out, site);
    out.extend(epoch.to_le_bytes());
    out.extend(seq.to_le_bytes());
    put_u48(&mut out, timestamp_ms);
    Ok(out)
}

/// A site's name as the wire carries it: one key chunk.
fn check_site(site: &str) -> Result<(), ValidationError> {
    if is_site_name(site) {
        Ok(())
    } else {
        Err(ValidationError::BadText {
            field: "site",
            rule: "must be 1..=32 of [A-Za-z0-9_.-]",
        })
    }
}

fn code_of<T: PartialEq + Copy>(table: &[T], value: T) -> u8 {
    // Every table lists every variant, and none has more than 255.
    table.iter().position(|v| *v == value).unwrap_or(0) as u8
}

#[allow(clippy::cast_possible_truncation)]
fn fixed_i32(v: f64) -> i32 {
    v.round() as i32
}

#[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
fn fixed_u16(v: f64) -> u16 {
    v.round() as u16
}

fn put_u48(out: &mut Vec<u8>, v: i64) {
    // Validated timestamps lie in 2000..2100: positive and far below 2^48 ms (year 10889).
    out.extend(&v.to_le_bytes()[..6]);
}

fn put_str8(out: &mut Vec<u8>, s: &str) {
    // Every str8 field is an identifier of at most 64 bytes, validated before.
    out.push(s.len() as u8);
    out.extend(s.as_bytes());
}

// ------------------------------------------------------------------ decoding

/// Decodes a position frame; the vehicle id comes from the key expression.
pub fn decode_position(vehicle_id: &str, bytes: &[u8]) -> Result<VehiclePosition, DecodeError> {
    let mut r = Reader::open(bytes, KIND_POSITION)?;
    let kind = r.code("vehicle_kind", &VEHICLE_KINDS)?;
    let timestamp_ms = r.timestamp()?;
    let lat = r.i32("latitude")?;
    let lon = r.i32("longitude")?;
    let depth = r.u16("depth")?;
    let heading = r.u16("heading")?;
    let speed = r.u16("speed")?;
    let battery = r.u8("battery")?;
    r.end()?;
    range("latitude", i64::from(lat), 900_000_000)?;
    range("longitude", i64::from(lon), 1_800_000_000)?;
    range("depth", i64::from(depth), 55_000)?;
    range("speed", i64::from(speed), 3_000)?;
    range("battery", i64::from(battery), 200)?;
    let p = VehiclePosition {
        vehicle_id: vehicle_id.to_string(),
        kind,
        timestamp_ms,
        latitude_deg: f64::from(lat) / DEG_SCALE,
        longitude_deg: f64::from(lon) / DEG_SCALE,
        depth_m: f64::from(depth) * DEPTH_STEP_M,
        heading_deg: f64::from(heading) * HEADING_STEP_DEG,
        speed_mps: f64::from(speed) * SPEED_STEP_MPS,
        battery_pct: f64::from(battery) * BATTERY_STEP_PCT,
    };
    p.validate()?;
    Ok(p)
}

/// Decodes an alarm frame.
pub fn decode_alarm(bytes: &[u8]) -> Result<Sequenced<Event>, DecodeError> {
    let mut r = Reader::open(bytes, KIND_ALARM)?;
    let (site, epoch, seq, timestamp_ms) = r.envelope()?;
    let severity = r.code("severity", &SEVERITIES)?;
    let kind = r.code("event_kind", &EVENT_KINDS)?;
    let event_id = r.str8("event_id", MAX_ID_LEN)?;
    let vehicle_id = r.str8("vehicle_id", MAX_VEHICLE_ID_LEN)?;
    let task_id = r.str8("task_id", MAX_ID_LEN)?;
    let text_len = r.u16("text")?;
    range("text", i64::from(text_len), MAX_TEXT_LEN as i64)?;
    let text = r.text("text", usize::from(text_len))?;
    r.end()?;
    let event = Event {
        event_id,
        timestamp_ms,
        severity,
        kind,
        vehicle_id,
        task_id,
        text,
    };
    event.validate()?;
    Ok(Sequenced {
        site,
        epoch,
        seq,
        item: event,
    })
}

/// The last reply of a catch-up answer: how far the sender's stream goes. Without it an
/// asker cannot tell an answer cut short (by its deadline, or by the link) from one that
/// brought everything, nor a stream with nothing new from a query no queryable heard.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CatchupEnd {
    /// The answering site.
    pub site: String,
    /// The sender's epoch.
    pub epoch: u64,
    /// The oldest number the sender still keeps (`highest + 1` when it keeps none): what
    /// lies below it is lost for good.
    pub oldest: u64,
    /// The highest number the sender has given in that epoch (0: none yet).
    pub highest: u64,
}

/// Encodes a catch-up end frame (27 bytes plus the site's name).
pub fn encode_catchup_end(end: &CatchupEnd) -> Result<Vec<u8>, ValidationError> {
    check_site(&end.site)?;
    let mut out = Vec::with_capacity(27 + end.site.len());
    out.extend([VERSION, KIND_CATCHUP_END]);
    put_str8(&mut out, &end.site);
    out.extend(end.epoch.to_le_bytes());
    out.extend(end.oldest.to_le_bytes());
    out.extend(end.highest.to_le_bytes());
    Ok(out)
}

/// Decodes a catch-up end frame.
pub fn decode_catchup_end(bytes: &[u8]) -> Result<CatchupEnd, DecodeError> {
    let mut r = Reader::open(bytes, KIND_CATCHUP_END)?;
    let site = r.site()?;
    let epoch = r.u64("epoch")?;
    let oldest = r.u64("oldest")?;
    let highest = r.u64("highest")?;
    r.end()?;
    Ok(CatchupEnd {
        site,
        epoch,
        oldest,
        highest,
    })
}

/// Whether a frame is a catch-up end frame (by its kind byte; decode it to check it).
pub fn is_catchup_end(bytes: &[u8]) -> bool {
    bytes.get(1) == Some(&KIND_CATCHUP_END)
}

/// Decodes a task-transition frame.
pub fn decode_task(bytes: &[u8]) -> Result<Sequenced<TaskTransition>, DecodeError> {
    let mut r = Reader::open(bytes, KIND_TASK)?;
    let (site, epoch, seq, timestamp_ms) = r.envelope()?;
    let state = r.code("state", &TASK_STATES)?;
    let task_id = r.str8("task_id", MAX_ID_LEN)?;
    let mission_id = r.str8("mission_id", MAX_ID_LEN)?;
    let vehicle_id = r.str8("vehicle_id", MAX_VEHICLE_ID_LEN)?;
    r.end()?;
    let t = TaskTransition {
        task_id,
        mission_id,
        vehicle_id,
        state,
        timestamp_ms,
    };
    t.validate()?;
    Ok(Sequenced {
        site,
        epoch,
        seq,
        item: t,
    })
}

/// Decodes a command-lease frame; the vehicle id comes from the key expression.
pub fn decode_lease(vehicle_id: &str, bytes: &[u8]) -> Result<LeaseRecord, DecodeError> {
    let mut r = Reader::open(bytes, KIND_LEASE)?;
    let code = r.u8("reason")?;
    let reason = LeaseReason::from_code(code).ok_or(DecodeError::Code {
        field: "reason",
        value: code,
    })?;
    let term = r.u64("term")?;
    let granted_ms = r.timestamp()?;
    let holder = r.str8("holder", MAX_SITE_LEN)?;
    let home = r.str8("home", MAX_SITE_LEN)?;
    let standby = r.str8("standby", MAX_SITE_LEN)?;
    r.end()?;
    if term == 0 {
        return Err(DecodeError::Range {
            field: "term",
            value: 0,
        });
    }
    let record = LeaseRecord {
        vehicle_id: vehicle_id.to_string(),
        term,
        holder,
        home,
        standby,
        reason,
        granted_ms,
    };
    record.check().map_err(|field| ValidationError::BadText {
        field,
        rule: "must be 1..=32 of [A-Za-z0-9_.-]",
    })?;
    Ok(record)
}

/// Decodes an order frame; the vehicle id comes from the key expression and the lease
/// holder is the envelope's site. `issue_seq` and `expires_ms` come back as 0.
pub fn decode_order(
    vehicle_id_from_key: &str,
    bytes: &[u8],
) -> Result<Sequenced<TaskAssignment>, DecodeError> {
    let mut r = Reader::open(bytes, KIND_ORDER)?;
    let (site, epoch, seq, issued_ms) = r.envelope()?;
    let kind = r.code("task_kind", &TASK_KINDS)?;
    let lease_term = r.u64("lease_term")?;
    let depth_m = r.f64("depth_m")?;
    let altitude_m = r.f64("altitude_m")?;
    let speed_mps = r.f64("speed_mps")?;
    let line_spacing_m = r.f64("line_spacing_m")?;
    let duration_s = r.f64("duration_s")?;
    let rate_hz = r.f64("rate_hz")?;
    let task_id = r.str8("task_id", MAX_ID_LEN)?;
    let mission_id = r.str8("mission_id", MAX_ID_LEN)?;
    let count = r.u16("area")?;
    // Checked before reading the points, so a count cannot make the decoder reserve more.
    range("area", i64::from(count), TaskAssignment::MAX_AREA as i64)?;
    let mut area = Vec::with_capacity(usize::from(count));
    for _ in 0..count {
        area.push(GeoPoint {
            latitude_deg: r.f64("area.latitude_deg")?,
            longitude_deg: r.f64("area.longitude_deg")?,
        });
    }
    r.end()?;
    if lease_term == 0 {
        return Err(DecodeError::Range {
            field: "lease_term",
            value: 0,
        });
    }
    let task = TaskAssignment {
        task_id,
        mission_id,
        vehicle_id: vehicle_id_from_key.to_string(),
        issued_ms,
        kind,
        area,
        depth_m,
        altitude_m,
        speed_mps,
        line_spacing_m,
        duration_s,
        rate_hz,
        issue_seq: 0,
        expires_ms: 0,
        lease_term,
        lease_holder: site.clone(),
    };
    task.validate()?;
    Ok(Sequenced {
        site,
        epoch,
        seq,
        item: task,
    })
}

/// Decodes an environment frame; the vehicle id comes from the key expression.
pub fn decode_environment(
    vehicle_id: &str,
    bytes: &[u8],
) -> Result<Sequenced<EnvironmentAggregates>, DecodeError> {
    let mut r = Reader::open(bytes, KIND_ENVIRONMENT)?;
    let (site, epoch, seq, window_end_ms) = r.envelope()?;
    let window_start_ms = r.time("window_start_ms")?;
    let count = r.u8("properties")?;
    // Checked before reading them, so a count cannot make the decoder reserve more.
    if count == 0 || usize::from(count) > MAX_PROPERTIES_PER_FRAME {
        return Err(DecodeError::Range {
            field: "properties",
            value: i64::from(count),
        });
    }
    let mut properties = Vec::with_capacity(usize::from(count));
    for _ in 0..count {
        let property = r.str8("property", MAX_NAME_LEN)?;
        let unit = r.str8("unit", crate::environment::MAX_UNIT_LEN)?;
        let count = r.u32("count")?;
        let min = r.f64("min")?;
        let max = r.f64("max")?;
        let mean = r.f64("mean")?;
        let last_value = r.f64("last_value")?;
        let last_ms = r.time("last_ms")?;
        let lat = r.i32("latitude")?;
        let lon = r.i32("longitude")?;
        let depth = r.u16("depth")?;
        range("latitude", i64::from(lat), 900_000_000)?;
        range("longitude", i64::from(lon), 1_800_000_000)?;
        range("depth", i64::from(depth), 55_000)?;
        properties.push(PropertyAggregate {
            property,
            unit,
            count,
            min,
            max,
            mean,
            last_value,
            last_ms,
            latitude_deg: f64::from(lat) / DEG_SCALE,
            longitude_deg: f64::from(lon) / DEG_SCALE,
            depth_m: f64::from(depth) * DEPTH_STEP_M,
        });
    }
    r.end()?;
    let aggregates = EnvironmentAggregates {
        vehicle_id: vehicle_id.to_string(),
        window_start_ms,
        window_end_ms,
        properties,
    };
    aggregates.validate()?;
    Ok(Sequenced {
        site,
        epoch,
        seq,
        item: aggregates,
    })
}

fn range(field: &'static str, value: i64, max_abs: i64) -> Result<(), DecodeError> {
    if value.abs() > max_abs {
        return Err(DecodeError::Range { field, value });
    }
    Ok(())
}

/// A cursor over a frame that never reads past its end.
struct Reader<'a> {
    rest: &'a [u8],
}

impl<'a> Reader<'a> {
    /// Checks the version and kind bytes.
    fn open(bytes: &'a [u8], kind: u8) -> Result<Self, DecodeError> {
        let mut r = Self { rest: bytes };
        let version = r.u8("version")?;
        if version != VERSION {
            return Err(DecodeError::Version(version));
        }
        let found = r.u8("kind")?;
        if found != kind {
            return Err(DecodeError::Kind {
                expected: kind,
                found,
            });
        }
        Ok(r)
    }

    fn take<const N: usize>(&mut self, field: &'static str) -> Result<[u8; N], DecodeError> {
        let (head, rest) = self
            .rest
            .split_first_chunk::<N>()
            .ok_or(DecodeError::Truncated { field })?;
        self.rest = rest;
        Ok(*head)
    }

    fn u8(&mut self, field: &'static str) -> Result<u8, DecodeError> {
        Ok(self.take::<1>(field)?[0])
    }

    fn u16(&mut self, field: &'static str) -> Result<u16, DecodeError> {
        Ok(u16::from_le_bytes(self.take(field)?))
    }

    fn i32(&mut self, field: &'static str) -> Result<i32, DecodeError> {
        Ok(i32::from_le_bytes(self.take(field)?))
    }

    fn u32(&mut self, field: &'static str) -> Result<u32, DecodeError> {
        Ok(u32::from_le_bytes(self.take(field)?))
    }

    fn u64(&mut self, field: &'static str) -> Result<u64, DecodeError> {
        Ok(u64::from_le_bytes(self.take(field)?))
    }

    /// Any bit pattern; NaN and infinities are left to the model's validation.
    fn f64(&mut self, field: &'static str) -> Result<f64, DecodeError> {
        Ok(f64::from_le_bytes(self.take(field)?))
    }

    /// A u48 of ms since the Unix epoch, inside the model's accepted years.
    fn timestamp(&mut self) -> Result<i64, DecodeError> {
        self.time("timestamp_ms")
    }

    /// A u48 of ms since the Unix epoch named `field`, inside the model's accepted years.
    fn time(&mut self, field: &'static str) -> Result<i64, DecodeError> {
        let b: [u8; 6] = self.take(field)?;
        let mut full = [0u8; 8];
        full[..6].copy_from_slice(&b);
        let ms = i64::from_le_bytes(full);
        if !(MIN_TIMESTAMP_MS..=MAX_TIMESTAMP_MS).contains(&ms) {
            return Err(DecodeError::Range { field, value: ms });
        }
        Ok(ms)
    }

    fn code<T: Copy>(&mut self, field: &'static str, table: &[T]) -> Result<T, DecodeError> {
        let value = self.u8(field)?;
        table
            .get(usize::from(value))
            .copied()
            .ok_or(DecodeError::Code { field, value })
    }

    fn text(&mut self, field: &'static str, len: usize) -> Result<String, DecodeError> {
        if self.rest.len() < len {
            return Err(DecodeError::Truncated { field });
        }
        let (head, rest) = self.rest.split_at(len);
        self.rest = rest;
        String::from_utf8(head.to_vec()).map_err(|_| DecodeError::Utf8 { field })
    }

    fn str8(&mut self, field: &'static str, max: usize) -> Result<String, DecodeError> {
        let len = self.u8(field)?;
        range(field, i64::from(len), max as i64)?;
        self.text(field, usize::from(len))
    }

    /// A site's name.
    fn site(&mut self) -> Result<String, DecodeError> {
        let site = self.str8("site", MAX_SITE_LEN)?;
        check_site(&site)?;
        Ok(site)
    }

    /// Site, epoch, sequence number and timestamp of a sequenced frame.
    fn envelope(&mut self) -> Result<(String, u64, u64, i64), DecodeError> {
        let site = self.site()?;
        let epoch = self.u64("epoch")?;
        let seq = self.u64("seq")?;
        if seq == 0 {
            return Err(DecodeError::Range {
                field: "seq",
                value: 0,
            });
        }
        let ts = self.timestamp()?;
        Ok((site, epoch, seq, ts))
    }

    fn end(&self) -> Result<(), DecodeError> {
        match self.rest.len() {
            0 => Ok(()),
            n => Err(DecodeError::Trailing(n)),
        }
    }
}

#[cfg(test)]
pub(crate) mod tests;
