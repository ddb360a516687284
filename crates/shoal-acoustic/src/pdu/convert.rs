//! Conversions between `shoal-model` types and compact PDUs.
//!
//! What the compact forms lose, on purpose (docs/acoustic.md#compact-messages):
//! - vehicle ids become 4-bit acoustic addresses through an [`AddressBook`] the caller
//!   supplies; event ids become 8-bit numbers the caller maps; a task keeps its station
//!   task id, issue sequence, expiry and command lease ([`IdentifiedTask`]) but not its
//!   mission id or issue time;
//! - timestamps keep only the second of the UTC day; the receiver restores the date as the
//!   one nearest its own clock ([`time_from_seconds_of_day`]), and sub-second parts are lost;
//! - each number is quantised to its field's resolution (1e-5° ≈ 1.1 m, depth 0.1 m, speed
//!   0.05 m/s, yaw/pitch/roll 0.5°, battery 1 %); depth is limited to 0..=6000 m, speed to
//!   0..=10 m/s, and an altitude above 1000 m is sent as unknown;
//! - free text (task status message, event text, announcement name and vendor), mission
//!   ids and capabilities or sensors outside [`CAPABILITIES`]/[`SENSORS`] are dropped.

use std::collections::HashMap;

use shoal_model::{
    EnvironmentObservation, Event, EventKind, GeoPoint, LinkKind, Severity, StateVector, Task,
    TaskAssignment, TaskState, TaskStatus, UNKNOWN, Validate, ValidationError, VehicleAnnouncement,
    VehicleKind,
};

use super::{
    CompactAnnouncement, CompactEnvironment, CompactEvent, CompactTask, CompactTaskStatus,
    ENVIRONMENT_PROPERTIES, EncodeError, IdentifiedTask, MAX_ISSUE_SEQ, MAX_LEASE_HOLDER_LEN,
    MAX_LEASE_TERM, Motion, Point, StateKeyframe, TaskAction, TaskLease,
};

/// Capabilities an announcement can carry, by bit position.
pub const CAPABILITIES: [&str; 8] = [
    "goto",
    "survey",
    "hold",
    "surface",
    "return_home",
    "abort",
    "request_state",
    "set_reporting_rate",
];
/// Sensors an announcement can carry, by bit position.
pub const SENSORS: [&str; 8] = [
    "gps",
    "ctd",
    "dvl",
    "usbl",
    "sidescan_sonar",
    "multibeam",
    "camera",
    "adcp",
];

/// Highest acoustic address a compact PDU can name (4-bit field).
pub const MAX_ADDRESS: u8 = 15;

/// Why a model value could not be converted.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ConvertError {
    /// The vehicle id has no acoustic address in the table.
    #[error("vehicle {0:?} has no acoustic address")]
    UnknownVehicle(String),
    /// The acoustic address has no vehicle id in the table.
    #[error("acoustic address {0} is not in the address book")]
    UnknownAddress(u8),
    /// The model value does not fit the compact encoding.
    #[error(transparent)]
    Encode(#[from] EncodeError),
    /// The model value (or the rebuilt one) is invalid.
    #[error(transparent)]
    Invalid(#[from] ValidationError),
    /// A value the compact form has no code for.
    #[error("{field}: {value:?} has no compact code")]
    Unsupported {
        /// Field name.
        field: &'static str,
        /// The value.
        value: String,
    },
}

/// Two-way table between Shoal vehicle ids and 4-bit acoustic addresses (0..=15).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct AddressBook {
    by_id: HashMap<String, u8>,
    by_addr: HashMap<u8, String>,
}

impl AddressBook {
    /// An empty table.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds or replaces a mapping; addresses above [`MAX_ADDRESS`] are refused.
    pub fn insert(&mut self, vehicle_id: impl Into<String>, addr: u8) -> Result<(), ConvertError> {
        if addr > MAX_ADDRESS {
            return Err(ConvertError::UnknownAddress(addr));
        }
        let id = vehicle_id.into();
        if let Some(old) = self.by_id.insert(id.clone(), addr) {
            self.by_addr.remove(&old);
        }
        if let Some(old_id) = self.by_addr.insert(addr, id) {
            self.by_id.retain(|k, v| !(k == &old_id && *v == addr));
        }
        Ok(())
    }

    /// The address of a vehicle.
    pub fn addr(&self, vehicle_id: &str) -> Result<u8, ConvertError> {
        self.by_id
            .get(vehicle_id)
            .copied()
            .ok_or_else(|| ConvertError::UnknownVehicle(vehicle_id.to_owned()))
    }

    /// The vehicle at an address.
    pub fn vehicle_id(&self, addr: u8) -> Result<&str, ConvertError> {
        self.by_addr
            .get(&addr)
            .map(String::as_str)
            .ok_or(ConvertError::UnknownAddress(addr))
    }
}

impl<S: Into<String>> FromIterator<(S, u8)> for AddressBook {
    /// Builds a table from `(vehicle_id, address)` pairs; invalid addresses are skipped.
    fn from_iter<I: IntoIterator<Item = (S, u8)>>(iter: I) -> Self {
        let mut b = Self::new();
        for (id, a) in iter {
            let _ = b.insert(id, a);
        }
        b
    }
}

const DAY_MS: i64 = 86_400_000;

/// Second of the UTC day of a Unix time in ms.
pub fn seconds_of_day(ms: i64) -> u32 {
    u32::try_from(ms.rem_euclid(DAY_MS) / 1000).unwrap_or(0)
}

/// The Unix time (ms) with second-of-day `sod` nearest to `reference_ms` (the receiver's
/// clock): within ±12 h, which is far more than any acoustic delay.
pub fn time_from_seconds_of_day(sod: u32, reference_ms: i64) -> i64 {
    let day = reference_ms.div_euclid(DAY_MS) * DAY_MS;
    let candidate = day + i64::from(sod) * 1000;
    let diff = candidate - reference_ms;
    if diff > DAY_MS / 2 {
        candidate - DAY_MS
    } else if diff < -DAY_MS / 2 {
        candidate + DAY_MS
    } else {
        candidate
    }
}

fn opt(v: f64) -> Option<f64> {
    if v == UNKNOWN { None } else { Some(v) }
}

impl StateKeyframe {
    /// Compact form of a State Vector, with keyframe sequence number `seq`.
    pub fn from_model(sv: &StateVector, book: &AddressBook, seq: u8) -> Result<Self, ConvertError> {
        sv.validate()?;
        Ok(Self {
            vehicle: book.addr(&sv.vehicle_id)?,
            seq: seq % 16,
            seconds_of_day: seconds_of_day(sv.timestamp_ms),
            latitude_deg: sv.latitude_deg,
            longitude_deg: sv.longitude_deg,
            depth_m: sv.depth_m,
            // An altimeter beyond the field's 1000 m is as good as no reading.
            altitude_m: opt(sv.altitude_m).filter(|a| *a <= 1000.0),
            speed_mps: sv.speed_mps,
            yaw_deg: sv.yaw_deg,
            pitch_deg: sv.pitch_deg,
            roll_deg: sv.roll_deg,
            battery_pct: sv.battery_pct,
        })
    }

    /// The State Vector this keyframe describes; the date comes from `reference_ms`.
    pub fn to_model(
        &self,
        book: &AddressBook,
        reference_ms: i64,
    ) -> Result<StateVector, ConvertError> {
        let sv = StateVector {
            vehicle_id: book.vehicle_id(self.vehicle)?.to_owned(),
            timestamp_ms: time_from_seconds_of_day(self.seconds_of_day, reference_ms),
            latitude_deg: self.latitude_deg,
            longitude_deg: self.longitude_deg,
            depth_m: self.depth_m,
            altitude_m: self.altitude_m.unwrap_or(UNKNOWN),
            speed_mps: self.speed_mps,
            yaw_deg: self.yaw_deg.rem_euclid(360.0),
            pitch_deg: self.pitch_deg,
            roll_deg: self.roll_deg,
            battery_pct: self.battery_pct,
        };
        sv.validate()?;
        Ok(sv)
    }
}

fn point(p: GeoPoint) -> Point {
    Point {
        latitude_deg: p.latitude_deg,
        longitude_deg: p.longitude_deg,
    }
}

fn geo(p: Point) -> GeoPoint {
    GeoPoint {
        latitude_deg: p.latitude_deg,
        longitude_deg: p.longitude_deg,
    }
}

fn duration_u32(s: f64) -> u32 {
    // Validated to [0, 86400] by the model.
    #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
    let d = s.round().clamp(0.0, 86_400.0) as u32;
    d
}

impl CompactTask {
    /// Compact form of a task assignment as task number `task_no` (mission id dropped).
    pub fn from_model(
        a: &TaskAssignment,
        book: &AddressBook,
        task_no: u8,
    ) -> Result<Self, ConvertError> {
        let action = match a.task()? {
            Task::GotoWaypoint {
                target,
                depth_m,
                altitude_m,
                speed_mps,
            } => TaskAction::Goto {
                target: point(target),
                motion: Motion {
                    depth_m,
                    altitude_m,
                    speed_mps,
                },
            },
            Task::SurveyArea {
                polygon,
                line_spacing_m,
                depth_m,
                altitude_m,
                speed_mps,
            } => TaskAction::Survey {
                polygon: polygon.into_iter().map(point).collect(),
                line_spacing_m,
                motion: Motion {
                    depth_m,
                    altitude_m,
                    speed_mps,
                },
            },
            Task::Hold { duration_s } => TaskAction::Hold {
                duration_s: duration_u32(duration_s),
            },
            Task::Surface => TaskAction::Surface,
            Task::ReturnHome => TaskAction::ReturnHome,
            Task::Abort => TaskAction::Abort,
            Task::RequestState => TaskAction::RequestState,
            Task::SetReportingRate { rate_hz } => TaskAction::SetRate { rate_hz },
        };
        Ok(Self {
            vehicle: book.addr(&a.vehicle_id)?,
            task_no,
            action,
        })
    }

    /// The task assignment, with the caller's `task_id` and issue time `issued_ms`.
    pub fn to_model(
        &self,
        book: &AddressBook,
        task_id: &str,
        issued_ms: i64,
    ) -> Result<TaskAssignment, ConvertError> {
        let task = match &self.action {
            TaskAction::Goto { target, motion } => Task::GotoWaypoint {
                target: geo(*target),
                depth_m: motion.depth_m,
                altitude_m: motion.altitude_m,
                speed_mps: motion.speed_mps,
            },
            TaskAction::Survey {
                polygon,
                line_spacing_m,
                motion,
            } => Task::SurveyArea {
                polygon: polygon.iter().copied().map(geo).collect(),
                line_spacing_m: *line_spacing_m,
                depth_m: motion.depth_m,
                altitude_m: motion.altitude_m,
                speed_mps: motion.speed_mps,
            },
            TaskAction::Hold { duration_s } => Task::Hold {
                duration_s: f64::from(*duration_s),
            },
            TaskAction::Surface => Task::Surface,
            TaskAction::ReturnHome => Task::ReturnHome,
            TaskAction::Abort => Task::Abort,
            TaskAction::RequestState => Task::RequestState,
            TaskAction::SetRate { rate_hz } => Task::SetReportingRate { rate_hz: *rate_hz },
        };
        let a = TaskAssignment::new(
            task_id,
            "",
            book.vehicle_id(self.vehicle)?,
            issued_ms,
            &task,
        );
        a.validate()?;
        Ok(a)
    }
}

impl IdentifiedTask {
    /// Compact form of a task assignment, with its station identity and command lease, as
    /// task number `task_no`. Refused: an issue sequence above [`MAX_ISSUE_SEQ`], a lease
    /// term above [`MAX_LEASE_TERM`] (a lease holder longer than [`MAX_LEASE_HOLDER_LEN`]
    /// too), and an expiry 12 h or more after the issue time (a second of the day could not
    /// name it unambiguously).
    pub fn from_model(
        a: &TaskAssignment,
        book: &AddressBook,
        task_no: u8,
    ) -> Result<Self, ConvertError> {
        let c = CompactTask::from_model(a, book, task_no)?;
        if a.issue_seq > MAX_ISSUE_SEQ {
            return Err(ConvertError::Unsupported {
                field: "issue_seq",
                value: a.issue_seq.to_string(),
            });
        }
        // Validated above (by `CompactTask::from_model`): a holder iff the term is above 0.
        let lease = if a.lease_term == 0 {
            None
        } else if a.lease_term > MAX_LEASE_TERM {
            // Never wrapped or clamped: a smaller term would order as an older lease.
            return Err(ConvertError::Unsupported {
                field: "lease_term",
                value: a.lease_term.to_string(),
            });
        } else if a.lease_holder.len() > MAX_LEASE_HOLDER_LEN {
            return Err(ConvertError::Unsupported {
                field: "lease_holder",
                value: a.lease_holder.clone(),
            });
        } else {
            Some(TaskLease {
                term: a.lease_term,
                holder: a.lease_holder.clone(),
            })
        };
        let expires_s_of_day = if a.expires_ms == 0 {
            None
        } else if a.expires_ms.saturating_sub(a.issued_ms) >= DAY_MS / 2 {
            return Err(ConvertError::Unsupported {
                field: "expires_ms",
                value: format!(
                    "{} ms after issue (at most 12 h)",
                    a.expires_ms - a.issued_ms
                ),
            });
        } else {
            Some(seconds_of_day(a.expires_ms))
        };
        Ok(Self {
            vehicle: c.vehicle,
            task_no,
            task_id: a.task_id.clone(),
            issue_seq: a.issue_seq,
            expires_s_of_day,
            lease,
            action: c.action,
        })
    }

    /// The task assignment as the station issued it (same task id, issue sequence, lease and
    /// expiry, the expiry to the second), received at `received_ms`: that is its issue
    /// time on the vehicle side, or the expiry if that is earlier (a late re-delivery must
    /// still reach the vehicle's ledger, to be answered, not fail validation). The mission
    /// id is not carried.
    pub fn to_model(
        &self,
        book: &AddressBook,
        received_ms: i64,
    ) -> Result<TaskAssignment, ConvertError> {
        let plain = CompactTask {
            vehicle: self.vehicle,
            task_no: self.task_no,
            action: self.action.clone(),
        };
        let expires_ms = self
            .expires_s_of_day
            .map_or(0, |sod| time_from_seconds_of_day(sod, received_ms));
        let issued_ms = if expires_ms == 0 {
            received_ms
        } else {
            received_ms.min(expires_ms)
        };
        let mut a = plain.to_model(book, &self.task_id, issued_ms)?;
        a.issue_seq = self.issue_seq;
        a.expires_ms = expires_ms;
        if let Some(lease) = &self.lease {
            a.lease_term = lease.term;
            a.lease_holder.clone_from(&lease.holder);
        }
        a.validate()?;
        Ok(a)
    }
}

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
const VEHICLE_KINDS: [VehicleKind; 5] = [
    VehicleKind::Auv,
    VehicleKind::Usv,
    VehicleKind::Asv,
    VehicleKind::Rov,
    VehicleKind::Glider,
];
const LINK_KINDS: [LinkKind; 5] = [
    LinkKind::Ip,
    LinkKind::Acoustic,
    LinkKind::Radio,
    LinkKind::Satellite,
    LinkKind::Tether,
];

fn index_of<T: PartialEq>(table: &[T], v: &T) -> u8 {
    u8::try_from(table.iter().position(|x| x == v).unwrap_or(0)).unwrap_or(0)
}

fn from_index<T: Copy>(table: &[T], i: u8, field: &'static str) -> Result<T, ConvertError> {
    table
        .get(usize::from(i))
        .copied()
        .ok_or(ConvertError::Unsupported {
            field,
            value: i.to_string(),
        })
}

impl CompactTaskStatus {
    /// Compact form of a task status for task number `task_no` (message text dropped).
    pub fn from_model(
        s: &TaskStatus,
        book: &AddressBook,
        task_no: u8,
    ) -> Result<Self, ConvertError> {
        s.validate()?;
        Ok(Self {
            vehicle: book.addr(&s.vehicle_id)?,
            task_no,
            state: index_of(&TASK_STATES, &s.state),
            progress_pct: s.progress_pct,
            seconds_of_day: seconds_of_day(s.timestamp_ms),
        })
    }

    /// The task status, with the caller's `task_id`; the date comes from `reference_ms`.
    pub fn to_model(
        &self,
        book: &AddressBook,
        task_id: &str,
        reference_ms: i64,
    ) -> Result<TaskStatus, ConvertError> {
        let s = TaskStatus {
            task_id: task_id.to_owned(),
            vehicle_id: book.vehicle_id(self.vehicle)?.to_owned(),
            timestamp_ms: time_from_seconds_of_day(self.seconds_of_day, reference_ms),
            state: from_index(&TASK_STATES, self.state, "state")?,
            progress_pct: self.progress_pct,
            message: String::new(),
        };
        s.validate()?;
        Ok(s)
    }
}

impl CompactEvent {
    /// Compact form of an event numbered `event_no`, about task number `task_no` if any
    /// (text dropped).
    pub fn from_model(
        e: &Event,
        book: &AddressBook,
        event_no: u8,
        task_no: Option<u8>,
    ) -> Result<Self, ConvertError> {
        e.validate()?;
        let vehicle = if e.vehicle_id.is_empty() {
            None
        } else {
            Some(book.addr(&e.vehicle_id)?)
        };
        Ok(Self {
            vehicle,
            event_no,
            severity: index_of(&SEVERITIES, &e.severity),
            kind: index_of(&EVENT_KINDS, &e.kind),
            task_no,
            seconds_of_day: seconds_of_day(e.timestamp_ms),
        })
    }

    /// The event, with the caller's ids; the date comes from `reference_ms`.
    pub fn to_model(
        &self,
        book: &AddressBook,
        event_id: &str,
        task_id: &str,
        reference_ms: i64,
    ) -> Result<Event, ConvertError> {
        let e = Event {
            event_id: event_id.to_owned(),
            timestamp_ms: time_from_seconds_of_day(self.seconds_of_day, reference_ms),
            severity: from_index(&SEVERITIES, self.severity, "severity")?,
            kind: from_index(&EVENT_KINDS, self.kind, "kind")?,
            vehicle_id: match self.vehicle {
                Some(a) => book.vehicle_id(a)?.to_owned(),
                None => String::new(),
            },
            task_id: task_id.to_owned(),
            text: String::new(),
        };
        e.validate()?;
        Ok(e)
    }
}

fn bitset(items: &[String], table: &[&str; 8]) -> u8 {
    items
        .iter()
        .filter_map(|s| table.iter().position(|t| t == s))
        .fold(0u8, |acc, i| acc | (1 << i))
}

fn from_bitset(bits: u8, table: &[&str; 8]) -> Vec<String> {
    table
        .iter()
        .enumerate()
        .filter(|(i, _)| bits & (1 << i) != 0)
        .map(|(_, s)| (*s).to_owned())
        .collect()
}

impl CompactAnnouncement {
    /// Compact form of an announcement (name, vendor and unknown capabilities dropped).
    pub fn from_model(a: &VehicleAnnouncement, book: &AddressBook) -> Result<Self, ConvertError> {
        a.validate()?;
        let links = a
            .links
            .iter()
            .fold(0u8, |acc, l| acc | (1 << index_of(&LINK_KINDS, l)));
        Ok(Self {
            vehicle: book.addr(&a.vehicle_id)?,
            kind: index_of(&VEHICLE_KINDS, &a.kind),
            links,
            capabilities: bitset(&a.capabilities, &CAPABILITIES),
            sensors: bitset(&a.sensors, &SENSORS),
            max_speed_mps: a.max_speed_mps,
            seconds_of_day: seconds_of_day(a.timestamp_ms),
        })
    }

    /// The announcement; the name is the vehicle id and the vendor is empty.
    pub fn to_model(
        &self,
        book: &AddressBook,
        reference_ms: i64,
    ) -> Result<VehicleAnnouncement, ConvertError> {
        let id = book.vehicle_id(self.vehicle)?.to_owned();
        let a = VehicleAnnouncement {
            name: id.clone(),
            vehicle_id: id,
            kind: from_index(&VEHICLE_KINDS, self.kind, "kind")?,
            vendor: String::new(),
            capabilities: from_bitset(self.capabilities, &CAPABILITIES),
            sensors: from_bitset(self.sensors, &SENSORS),
            links: LINK_KINDS
                .iter()
                .enumerate()
                .filter(|(i, _)| self.links & (1 << i) != 0)
                .map(|(_, l)| *l)
                .collect(),
            max_speed_mps: self.max_speed_mps,
            timestamp_ms: time_from_seconds_of_day(self.seconds_of_day, reference_ms),
        };
        a.validate()?;
        Ok(a)
    }
}

impl CompactEnvironment {
    /// Compact form of an observation whose property and unit are in
    /// [`ENVIRONMENT_PROPERTIES`].
    pub fn from_model(
        o: &EnvironmentObservation,
        book: &AddressBook,
    ) -> Result<Self, ConvertError> {
        o.validate()?;
        let code = ENVIRONMENT_PROPERTIES
            .iter()
            .position(|p| p.name == o.property && p.unit == o.unit)
            .ok_or_else(|| ConvertError::Unsupported {
                field: "property",
                value: format!("{} [{}]", o.property, o.unit),
            })?;
        Ok(Self {
            vehicle: book.addr(&o.vehicle_id)?,
            property: u8::try_from(code).unwrap_or(u8::MAX),
            seconds_of_day: seconds_of_day(o.timestamp_ms),
            value: o.value,
            latitude_deg: o.latitude_deg,
            longitude_deg: o.longitude_deg,
            depth_m: o.depth_m,
        })
    }

    /// The observation; the date comes from `reference_ms`.
    pub fn to_model(
        &self,
        book: &AddressBook,
        reference_ms: i64,
    ) -> Result<EnvironmentObservation, ConvertError> {
        let p = ENVIRONMENT_PROPERTIES
            .get(usize::from(self.property))
            .ok_or(ConvertError::Unsupported {
                field: "property",
                value: self.property.to_string(),
            })?;
        let o = EnvironmentObservation {
            vehicle_id: book.vehicle_id(self.vehicle)?.to_owned(),
            property: p.name.to_owned(),
            timestamp_ms: time_from_seconds_of_day(self.seconds_of_day, reference_ms),
            value: self.value,
            unit: p.unit.to_owned(),
            latitude_deg: self.latitude_deg,
            longitude_deg: self.longitude_deg,
            depth_m: self.depth_m,
        };
        o.validate()?;
        Ok(o)
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod tests {
    use super::*;

    const T: i64 = 1_700_000_000_000;

    fn book() -> AddressBook {
        [("station", 0u8), ("auv-1", 3)].into_iter().collect()
    }

    #[test]
    fn the_date_is_restored_from_the_receivers_clock_across_midnight() {
        let day = 1_700_006_400_000; // a UTC midnight
        assert_eq!(day % DAY_MS, 0);
        let sent = day - 2_000; // 23:59:58
        let received = day + 3_000; // 00:00:03 the next day
        assert_eq!(
            time_from_seconds_of_day(seconds_of_day(sent), received),
            sent
        );
    }

    #[test]
    fn state_vector_round_trips_within_resolution() {
        let sv = StateVector {
            vehicle_id: "auv-1".into(),
            timestamp_ms: T,
            latitude_deg: 43.123_456,
            longitude_deg: 5.987_654,
            depth_m: 12.34,
            altitude_m: UNKNOWN,
            speed_mps: 1.53,
            yaw_deg: 359.9,
            pitch_deg: -3.2,
            roll_deg: 1.1,
            battery_pct: 80.4,
        };
        let k = StateKeyframe::from_model(&sv, &book(), 2).unwrap();
        let bytes = super::super::encode(&super::super::Pdu::StateKeyframe(k)).unwrap();
        assert!(bytes.len() <= 20);
        let super::super::Pdu::StateKeyframe(back) = super::super::decode(&bytes).unwrap() else {
            panic!("wrong message");
        };
        let out = back.to_model(&book(), T + 5_000).unwrap();
        assert_eq!(out.timestamp_ms, T); // T is a whole second
        assert!((out.latitude_deg - sv.latitude_deg).abs() <= 0.5e-5 + 1e-12);
        assert!((out.depth_m - sv.depth_m).abs() <= 0.05 + 1e-9);
        assert_eq!(out.altitude_m, UNKNOWN);
        assert_eq!(out.yaw_deg, 0.0); // 359.9 rounds to 360 and wraps
    }

    #[test]
    fn unknown_vehicle_is_an_error_not_a_panic() {
        let mut sv = StateVector {
            vehicle_id: "nobody".into(),
            timestamp_ms: T,
            latitude_deg: 0.0,
            longitude_deg: 0.0,
            depth_m: 0.0,
            altitude_m: UNKNOWN,
            speed_mps: 0.0,
            yaw_deg: 0.0,
            pitch_deg: 0.0,
            roll_deg: 0.0,
            battery_pct: 50.0,
        };
        assert!(matches!(
            StateKeyframe::from_model(&sv, &book(), 0),
            Err(ConvertError::UnknownVehicle(_))
        ));
        sv.vehicle_id = "auv-1".into();
        assert!(StateKeyframe::from_model(&sv, &book(), 0).is_ok());
    }

    #[test]
    fn every_task_kind_round_trips_through_the_compact_form() {
        let p = |a, b| GeoPoint {
            latitude_deg: a,
            longitude_deg: b,
        };
        let tasks = [
            Task::GotoWaypoint {
                target: p(43.1, 5.9),
                depth_m: Some(10.0),
                altitude_m: None,
                speed_mps: 1.5,
            },
            Task::SurveyArea {
                polygon: vec![p(43.0, 5.0), p(43.0, 5.01), p(43.01, 5.01)],
                line_spacing_m: 20.0,
                depth_m: None,
                altitude_m: Some(5.0),
                speed_mps: 1.0,
            },
            Task::Hold { duration_s: 60.0 },
            Task::Surface,
            Task::ReturnHome,
            Task::Abort,
            Task::RequestState,
            Task::SetReportingRate { rate_hz: 0.05 },
        ];
        for t in tasks {
            let a = TaskAssignment::new("t-7", "m1", "auv-1", T, &t);
            let c = CompactTask::from_model(&a, &book(), 7).unwrap();
            let pdu = super::super::Pdu::Task(c);
            let back = super::super::decode(&super::super::encode(&pdu).unwrap()).unwrap();
            let super::super::Pdu::Task(c) = back else {
                panic!("wrong message")
            };
            let out = c.to_model(&book(), "t-7", T).unwrap();
            assert_eq!(out.task().unwrap(), t);
        }
    }

    #[test]
    fn an_identified_task_reaches_the_vehicle_under_the_station_identity() {
        let mut a = TaskAssignment::new("m-7-2", "m-7", "auv-1", T, &Task::Surface);
        a.issue_seq = 1_780_000_000_000_123;
        a.expires_ms = T + 675_250;
        let c = IdentifiedTask::from_model(&a, &book(), 9).unwrap();
        let bytes = super::super::encode(&super::super::Pdu::IdentifiedTask(c)).unwrap();
        let super::super::Pdu::IdentifiedTask(c) = super::super::decode(&bytes).unwrap() else {
            panic!("wrong message")
        };
        let out = c.to_model(&book(), T + 40_000).unwrap();
        assert_eq!(
            (out.task_id.as_str(), out.issue_seq, out.expires_ms),
            ("m-7-2", a.issue_seq, T + 675_000),
            "same id and sequence; the expiry to the second, rounded down"
        );
        assert_eq!(out.issued_ms, T + 40_000);
        // Re-delivered after its expiry: still a valid assignment (issued at its expiry),
        // so the vehicle's ledger answers it instead of the VDT failing it.
        let late = c.to_model(&book(), T + 900_000).unwrap();
        assert_eq!(
            (late.issued_ms, late.expires_ms),
            (T + 675_000, T + 675_000)
        );
        // No expiry travels as none.
        a.expires_ms = 0;
        let c = IdentifiedTask::from_model(&a, &book(), 9).unwrap();
        assert_eq!(c.to_model(&book(), T).unwrap().expires_ms, 0);
        // An expiry a second of the day cannot name is refused at the sender.
        a.expires_ms = T + 12 * 3_600_000;
        assert!(matches!(
            IdentifiedTask::from_model(&a, &book(), 9),
            Err(ConvertError::Unsupported {
                field: "expires_ms",
                ..
            })
        ));
    }

    #[test]
    fn a_task_keeps_its_command_lease_across_the_water() {
        let through = |a: &TaskAssignment| {
            let c = IdentifiedTask::from_model(a, &book(), 9).unwrap();
            let bytes = super::super::encode(&super::super::Pdu::IdentifiedTask(c)).unwrap();
            let super::super::Pdu::IdentifiedTask(c) = super::super::decode(&bytes).unwrap() else {
                panic!("wrong message")
            };
            (bytes[0], c.to_model(&book(), T).unwrap())
        };
        let mut a = TaskAssignment::new("m-7-2", "m-7", "auv-1", T, &Task::Surface);
        a.issue_seq = 1_780_000_000_000_123;
        // No lease: layout 2, and none on arrival.
        let (layout, out) = through(&a);
        assert_eq!(layout, super::super::id::IDENTIFIED_TASK);
        assert_eq!((out.lease_term, out.lease_holder.as_str()), (0, ""));
        // A lease, up to the largest term: layout 3, the very lease on arrival.
        for term in [1, 42, MAX_LEASE_TERM] {
            a.lease_term = term;
            a.lease_holder = "ship_2.north-sea".into();
            let (layout, out) = through(&a);
            assert_eq!(layout, super::super::id::LEASED_TASK);
            assert_eq!(
                (out.lease_term, out.lease_holder.as_str(), out.issue_seq),
                (term, "ship_2.north-sea", a.issue_seq)
            );
        }
        // A term the layout cannot carry is refused at the sender, never wrapped.
        a.lease_term = MAX_LEASE_TERM + 1;
        assert!(matches!(
            IdentifiedTask::from_model(&a, &book(), 9),
            Err(ConvertError::Unsupported {
                field: "lease_term",
                ..
            })
        ));
        // A holder without a term (or the reverse) is an invalid assignment, not a lease.
        a.lease_term = 0;
        assert!(matches!(
            IdentifiedTask::from_model(&a, &book(), 9),
            Err(ConvertError::Invalid(_))
        ));
    }

    #[test]
    fn status_event_announcement_and_environment_round_trip() {
        let s = TaskStatus {
            task_id: "t-7".into(),
            vehicle_id: "auv-1".into(),
            timestamp_ms: T,
            state: TaskState::Running,
            progress_pct: 42.0,
            message: "dropped".into(),
        };
        let c = CompactTaskStatus::from_model(&s, &book(), 7).unwrap();
        let out = c.to_model(&book(), "t-7", T).unwrap();
        assert_eq!(
            (out.state, out.progress_pct, out.timestamp_ms),
            (s.state, s.progress_pct, s.timestamp_ms)
        );

        let e = Event {
            event_id: "e1".into(),
            timestamp_ms: T,
            severity: Severity::Critical,
            kind: EventKind::LowBattery,
            vehicle_id: "auv-1".into(),
            task_id: String::new(),
            text: "battery 9%".into(),
        };
        let c = CompactEvent::from_model(&e, &book(), 1, None).unwrap();
        let out = c.to_model(&book(), "e1", "", T).unwrap();
        assert_eq!(
            (out.severity, out.kind, out.vehicle_id.as_str()),
            (Severity::Critical, EventKind::LowBattery, "auv-1")
        );

        let a = VehicleAnnouncement {
            vehicle_id: "auv-1".into(),
            name: "A".into(),
            kind: VehicleKind::Auv,
            vendor: "V".into(),
            capabilities: vec!["goto".into(), "survey".into(), "dance".into()],
            sensors: vec!["ctd".into()],
            links: vec![LinkKind::Acoustic],
            max_speed_mps: 2.5,
            timestamp_ms: T,
        };
        let c = CompactAnnouncement::from_model(&a, &book()).unwrap();
        let out = c.to_model(&book(), T).unwrap();
        assert_eq!(
            out.capabilities,
            vec!["goto".to_owned(), "survey".to_owned()]
        );
        assert_eq!(
            (out.kind, out.links.clone(), out.max_speed_mps),
            (VehicleKind::Auv, vec![LinkKind::Acoustic], 2.5)
        );

        let o = EnvironmentObservation {
            vehicle_id: "auv-1".into(),
            property: "sea_water_temperature".into(),
            timestamp_ms: T,
            value: 13.2512,
            unit: "Cel".into(),
            latitude_deg: 43.1,
            longitude_deg: 5.9,
            depth_m: 20.0,
        };
        let c = CompactEnvironment::from_model(&o, &book()).unwrap();
        let out = c.to_model(&book(), T).unwrap();
        assert!((out.value - o.value).abs() <= 0.0005 + 1e-9);
    }
}
