//! Scenario files: a simulated fleet and missions on a timeline, written in TOML.
//!
//! [`parse`] reads a file's text into a [`Scenario`]: its [`ScenarioVehicle`]s (kind,
//! start position, battery, reporting rate) and its [`ScenarioMission`]s, each started
//! `at_s` seconds after the scenario starts, made of [`ScenarioTask`]s that are the data
//! model's own [`Task`]s. Every error is one [`ScenarioError`] line naming the key and
//! the line of the file it is on. [`SHIPPED`] holds the scenarios in the repository's
//! `scenarios/` folder, so a binary runs them with no file at hand.
//!
//! The format is described key by key in `docs/scenarios.md`. [`report`] turns what a
//! run stored into its summary and HTML page. This crate does no I/O.
#![forbid(unsafe_code)]

mod chart;
pub mod report;

pub use chart::on_land;

use std::collections::HashMap;
use std::ops::Range;

use serde::Deserialize;
use shoal_acoustic::channel::{ChannelModel, Modulation};
use shoal_model::ocean::{OceanField, Plume};
use shoal_model::{
    GeoPoint, MAX_NAME_LEN, MAX_VEHICLE_ID_LEN, StateVector, Task, TaskAssignment, VehicleKind,
    is_identifier,
};
use toml::Spanned;

/// The scenarios shipped in `scenarios/`, by name (the file name without `.toml`).
pub const SHIPPED: &[(&str, &str)] = &[
    (
        "sea-trial",
        include_str!("../../../scenarios/sea-trial.toml"),
    ),
    (
        "harbour-survey",
        include_str!("../../../scenarios/harbour-survey.toml"),
    ),
    (
        "acoustic-relay",
        include_str!("../../../scenarios/acoustic-relay.toml"),
    ),
];

/// The scenario `shoal up` runs when none is named.
pub const DEFAULT: &str = "sea-trial";

/// The text of a shipped scenario.
pub fn shipped(name: &str) -> Option<&'static str> {
    SHIPPED.iter().find(|(n, _)| *n == name).map(|(_, t)| *t)
}

/// Longest scenario, in seconds: a week.
pub const MAX_DURATION_S: f64 = 7.0 * 86_400.0;
/// Largest time scale (simulated seconds per wall-clock second).
pub const MAX_TIME_SCALE: f64 = 1000.0;
/// Longest mission id a scenario may give: the station appends a run suffix to it and
/// mission ids are at most 64 characters.
pub const MAX_MISSION_ID_LEN: usize = 40;

/// A scenario, checked: every vehicle a mission names is in the fleet, every value in range.
#[derive(Debug, Clone, PartialEq)]
pub struct Scenario {
    /// Its name, shown in logs.
    pub name: String,
    /// What it shows, for people.
    pub description: String,
    /// How long it runs, seconds; every mission starts within it.
    pub duration_s: f64,
    /// Simulated seconds per wall-clock second.
    pub time_scale: f64,
    /// The fleet, in file order.
    pub vehicles: Vec<ScenarioVehicle>,
    /// The missions, in file order (not necessarily time order).
    pub missions: Vec<ScenarioMission>,
    /// Faults injected on the timeline, in file order; only `shoal scenario run` injects
    /// them.
    pub faults: Vec<ScenarioFault>,
    /// The acoustic network, when vehicles are heard through one.
    pub acoustic: Option<AcousticNetwork>,
    /// The ocean the simulated vehicles sample (the default one without `[environment]`).
    pub environment: OceanField,
}

/// Most plumes one scenario's `[environment]` may place.
pub const MAX_PLUMES: usize = 32;

/// Highest acoustic address a vehicle or the relay may have (the compact PDUs carry 4 bits).
pub const MAX_ACOUSTIC_ADDRESS: u8 = 15;
/// Farthest a vehicle may start from the relay, m: the channel model loses everything by
/// about 8 km.
pub const MAX_ACOUSTIC_RANGE_M: f64 = 8_000.0;

/// The acoustic network of a scenario: one relay (the gateway's modem, on a USV or a
/// buoy) that hears every acoustic vehicle and republishes it to the station.
#[derive(Debug, Clone, PartialEq)]
pub struct AcousticNetwork {
    /// The relay modem's acoustic address.
    pub relay_address: u8,
    /// Where the relay is, degrees.
    pub relay_latitude_deg: f64,
    /// Where the relay is, degrees.
    pub relay_longitude_deg: f64,
    /// A fixed packet error rate for every frame instead of the channel's physics.
    pub fixed_per: Option<f64>,
    /// The IP vehicle that carries the relay (a USV), whose position the relay follows;
    /// `None`: the relay stays where it is put.
    pub relay_vehicle: Option<String>,
    /// The channel's physics (the emulator's defaults unless `[acoustic.channel]` changes
    /// them); unused when `fixed_per` is set.
    pub channel: ChannelModel,
}

impl Scenario {
    /// The vehicles heard through the acoustic network, in file order.
    pub fn acoustic_vehicles(&self) -> impl Iterator<Item = &ScenarioVehicle> {
        self.vehicles
            .iter()
            .filter(|v| v.acoustic_address.is_some())
    }
}

/// A fault on a scenario's timeline.
#[derive(Debug, Clone, PartialEq)]
pub struct ScenarioFault {
    /// When it happens, seconds after the scenario starts.
    pub at_s: f64,
    /// What happens.
    pub fault: Fault,
}

/// What a fault does.
#[derive(Debug, Clone, PartialEq)]
pub enum Fault {
    /// The vehicle's computer stops (its proxy with it); with `restart_after_s`, it starts
    /// again that much later where it was, with the same task ledger.
    VehicleFailure {
        /// The vehicle.
        vehicle: String,
        /// Seconds until it starts again; `None`: it stays down.
        restart_after_s: Option<f64>,
    },
    /// The vehicle's battery falls at once to `battery_pct` (a failed cell).
    BatteryDrop {
        /// The vehicle.
        vehicle: String,
        /// What is left, %.
        battery_pct: f64,
    },
    /// Someone else publishes a state vector for the vehicle, 50 km from where it is.
    RogueSample {
        /// The vehicle impersonated.
        vehicle: String,
    },
    /// The station stops and starts again over the same history `down_s` later.
    StationRestart {
        /// Seconds it is down.
        down_s: f64,
    },
    /// An acoustic vehicle's link to the relay is cut for `duration_s` (both ways).
    LinkOutage {
        /// The acoustic vehicle.
        vehicle: String,
        /// Seconds it lasts.
        duration_s: f64,
    },
    /// A modem fails: the relay's (`vehicle` `None`) or an acoustic vehicle's; with
    /// `repaired_after_s` it works again that much later.
    ModemFailure {
        /// The acoustic vehicle whose modem fails; `None`: the relay's.
        vehicle: Option<String>,
        /// Seconds until it works again; `None`: for good.
        repaired_after_s: Option<f64>,
    },
}

impl Fault {
    /// The fault's `kind` as the file writes it.
    pub fn kind(&self) -> &'static str {
        match self {
            Self::VehicleFailure { .. } => "vehicle_failure",
            Self::BatteryDrop { .. } => "battery_drop",
            Self::RogueSample { .. } => "rogue_sample",
            Self::StationRestart { .. } => "station_restart",
            Self::LinkOutage { .. } => "link_outage",
            Self::ModemFailure { .. } => "modem_failure",
        }
    }
}

/// A simulated vehicle of a scenario's fleet.
#[derive(Debug, Clone, PartialEq)]
pub struct ScenarioVehicle {
    /// Vehicle id.
    pub id: String,
    /// Platform kind.
    pub kind: VehicleKind,
    /// Start latitude, degrees.
    pub latitude_deg: f64,
    /// Start longitude, degrees.
    pub longitude_deg: f64,
    /// Battery at start, %.
    pub battery_pct: f64,
    /// State vectors per second.
    pub rate_hz: f64,
    /// Its acoustic address when it is heard through the acoustic network only
    /// (`link = "acoustic"`); `None` for a vehicle on IP.
    pub acoustic_address: Option<u8>,
}

/// A mission on the scenario's timeline.
#[derive(Debug, Clone, PartialEq)]
pub struct ScenarioMission {
    /// Mission id, unique in the scenario.
    pub id: String,
    /// Name shown to operators.
    pub name: String,
    /// When it starts, seconds after the scenario starts.
    pub at_s: f64,
    /// Its tasks, in order per vehicle.
    pub tasks: Vec<ScenarioTask>,
}

impl ScenarioMission {
    /// The vehicles it names, each once, in first-use order.
    pub fn vehicles(&self) -> Vec<&str> {
        let mut out: Vec<&str> = Vec::new();
        for t in &self.tasks {
            if !out.contains(&t.vehicle_id.as_str()) {
                out.push(&t.vehicle_id);
            }
        }
        out
    }
}

/// One task of a mission: the data model's task for one vehicle.
#[derive(Debug, Clone, PartialEq)]
pub struct ScenarioTask {
    /// The vehicle that runs it.
    pub vehicle_id: String,
    /// What it does.
    pub task: Task,
}

/// Why a scenario file was refused: always one line naming the line of the file and the key.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ScenarioError {
    /// Not TOML, an unknown key, a value of the wrong type or a missing key.
    #[error("line {line}: {key}: {message}")]
    Format {
        /// Line of the file, from 1.
        line: usize,
        /// Dotted path of the key (`missions[0].tasks[1].kind`), or `file` when TOML
        /// itself is broken.
        key: String,
        /// What is wrong.
        message: String,
    },
    /// A mission task names a vehicle that is not in `[[vehicles]]`.
    #[error("line {line}: {key}: unknown vehicle {vehicle:?} (not in [[vehicles]])")]
    UnknownVehicle {
        /// Line of the file, from 1.
        line: usize,
        /// Dotted path of the key.
        key: String,
        /// The id named.
        vehicle: String,
    },
    /// A number outside its bounds.
    #[error("line {line}: {key} = {value} is outside {bounds}")]
    OutOfRange {
        /// Line of the file, from 1.
        line: usize,
        /// Dotted path of the key.
        key: String,
        /// The value given.
        value: f64,
        /// The allowed range, as text (`[-90, 90]`).
        bounds: String,
    },
    /// An id given twice.
    #[error("line {line}: {key}: {id:?} is already used on line {first_line}")]
    Duplicate {
        /// Line of the file, from 1.
        line: usize,
        /// Dotted path of the key.
        key: String,
        /// The repeated id.
        id: String,
        /// Where it was first given.
        first_line: usize,
    },
    /// A value the format or the data model does not allow for another reason.
    #[error("line {line}: {key}: {reason}")]
    Invalid {
        /// Line of the file, from 1.
        line: usize,
        /// Dotted path of the key.
        key: String,
        /// Why.
        reason: String,
    },
}

impl ScenarioError {
    /// The line of the file the error is on, from 1.
    pub fn line(&self) -> usize {
        match self {
            Self::Format { line, .. }
            | Self::UnknownVehicle { line, .. }
            | Self::OutOfRange { line, .. }
            | Self::Duplicate { line, .. }
            | Self::Invalid { line, .. } => *line,
        }
    }
}

// The file as written. Every value a later check may refuse keeps its span, so that the
// error can name its line.

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFile {
    scenario: RawHeader,
    #[serde(default)]
    vehicles: Vec<RawVehicle>,
    #[serde(default)]
    missions: Vec<RawMission>,
    #[serde(default)]
    faults: Vec<RawFault>,
    acoustic: Option<RawAcoustic>,
    environment: Option<RawEnvironment>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawEnvironment {
    surface_temperature_c: Option<Spanned<f64>>,
    eddy_temperature_c: Option<Spanned<f64>>,
    thermocline_m: Option<Spanned<f64>>,
    surface_salinity_psu: Option<Spanned<f64>>,
    current_mps: Option<Spanned<f64>>,
    current_to_deg: Option<Spanned<f64>>,
    plumes: Option<Spanned<Vec<RawPlume>>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPlume {
    latitude_deg: Spanned<f64>,
    longitude_deg: Spanned<f64>,
    radius_m: Spanned<f64>,
    depth_m: Option<Spanned<f64>>,
    thickness_m: Option<Spanned<f64>>,
    temperature_c: Option<Spanned<f64>>,
    salinity_psu: Option<Spanned<f64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawAcoustic {
    relay_vehicle: Option<Spanned<String>>,
    relay_latitude_deg: Option<Spanned<f64>>,
    relay_longitude_deg: Option<Spanned<f64>>,
    relay_address: Option<Spanned<i64>>,
    per: Option<Spanned<f64>>,
    channel: Option<Spanned<RawChannel>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawChannel {
    source_level_db: Option<Spanned<f64>>,
    centre_khz: Option<Spanned<f64>>,
    bandwidth_khz: Option<Spanned<f64>>,
    spreading_k: Option<Spanned<f64>>,
    shipping: Option<Spanned<f64>>,
    wind_mps: Option<Spanned<f64>>,
    temperature_c: Option<Spanned<f64>>,
    salinity_ppt: Option<Spanned<f64>>,
    modulation: Option<Modulation>,
}

#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(rename_all = "snake_case")]
enum LinkName {
    Ip,
    Acoustic,
}

#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(rename_all = "snake_case")]
enum FaultName {
    VehicleFailure,
    BatteryDrop,
    RogueSample,
    StationRestart,
    LinkOutage,
    ModemFailure,
}

/// One fault as written: like a task, a flat table whose `kind` says which keys it takes.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFault {
    at_s: Spanned<f64>,
    kind: Spanned<FaultName>,
    vehicle: Option<Spanned<String>>,
    duration_s: Option<Spanned<f64>>,
    battery_pct: Option<Spanned<f64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawHeader {
    name: Spanned<String>,
    #[serde(default)]
    description: String,
    duration_s: Option<Spanned<f64>>,
    time_scale: Option<Spanned<f64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawVehicle {
    id: Spanned<String>,
    kind: VehicleKind,
    latitude_deg: Spanned<f64>,
    longitude_deg: Spanned<f64>,
    battery_pct: Option<Spanned<f64>>,
    rate_hz: Option<Spanned<f64>>,
    link: Option<Spanned<LinkName>>,
    acoustic_address: Option<Spanned<i64>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawMission {
    id: Option<Spanned<String>>,
    name: Spanned<String>,
    at_s: Spanned<f64>,
    tasks: Spanned<Vec<RawTask>>,
}

#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(rename_all = "snake_case")]
enum TaskName {
    Goto,
    Survey,
    Hold,
    Surface,
    ReturnHome,
}

/// One task as written: a flat table whose `kind` says which of the other keys it needs,
/// so that a key another kind uses is refused by name rather than ignored.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawTask {
    vehicle: Spanned<String>,
    kind: Spanned<TaskName>,
    latitude_deg: Option<Spanned<f64>>,
    longitude_deg: Option<Spanned<f64>>,
    polygon: Option<Spanned<Vec<[f64; 2]>>>,
    spacing_m: Option<Spanned<f64>>,
    depth_m: Option<Spanned<f64>>,
    altitude_m: Option<Spanned<f64>>,
    speed_mps: Option<Spanned<f64>>,
    duration_s: Option<Spanned<f64>>,
}

/// Byte offsets to 1-based line numbers.
struct Lines<'a>(&'a str);

impl Lines<'_> {
    fn of(&self, span: &Range<usize>) -> usize {
        let end = span.start.min(self.0.len());
        self.0.as_bytes()[..end]
            .iter()
            .filter(|&&b| b == b'\n')
            .count()
            + 1
    }
}

/// Reads and checks a scenario file's text.
pub fn parse(text: &str) -> Result<Scenario, ScenarioError> {
    let lines = Lines(text);
    let de = toml::Deserializer::parse(text).map_err(|e| format_error(&lines, "file", &e))?;
    let raw: RawFile = serde_path_to_error::deserialize(de).map_err(|e| {
        // Spanned values show in serde's path as a private field: not a key of the file.
        let path = e
            .path()
            .to_string()
            .replace(".$__serde_spanned_private_value", "");
        let key = if path == "." { "file".into() } else { path };
        format_error(&lines, &key, e.inner())
    })?;
    Checker { lines }.check(&raw)
}

fn format_error(lines: &Lines<'_>, key: &str, e: &toml::de::Error) -> ScenarioError {
    ScenarioError::Format {
        line: e.span().map_or(1, |s| lines.of(&s)),
        key: key.to_owned(),
        // toml's own message is one line; its Display adds the source excerpt.
        message: e.message().trim().to_owned(),
    }
}

struct Checker<'a> {
    lines: Lines<'a>,
}

impl Checker<'_> {
    fn line<T>(&self, s: &Spanned<T>) -> usize {
        self.lines.of(&s.span())
    }

    fn range(
        &self,
        key: &str,
        v: &Spanned<f64>,
        lo: f64,
        hi: f64,
        lo_open: bool,
    ) -> Result<f64, ScenarioError> {
        let x = *v.get_ref();
        let ok = x.is_finite() && x <= hi && if lo_open { x > lo } else { x >= lo };
        if ok {
            Ok(x)
        } else {
            Err(ScenarioError::OutOfRange {
                line: self.line(v),
                key: key.to_owned(),
                value: x,
                bounds: format!("{}{lo}, {hi}]", if lo_open { "(" } else { "[" }),
            })
        }
    }

    fn optional(
        &self,
        key: &str,
        v: Option<&Spanned<f64>>,
        default: f64,
        (lo, hi, lo_open): (f64, f64, bool),
    ) -> Result<f64, ScenarioError> {
        v.map_or(Ok(default), |v| self.range(key, v, lo, hi, lo_open))
    }

    fn check(&self, raw: &RawFile) -> Result<Scenario, ScenarioError> {
        let h = &raw.scenario;
        let name = h.name.get_ref().trim();
        if name.is_empty() || name.chars().count() > MAX_NAME_LEN {
            return Err(ScenarioError::Invalid {
                line: self.line(&h.name),
                key: "scenario.name".into(),
                reason: format!("1..={MAX_NAME_LEN} characters"),
            });
        }
        let duration_s = self.optional(
            "scenario.duration_s",
            h.duration_s.as_ref(),
            3600.0,
            (0.0, MAX_DURATION_S, true),
        )?;
        let time_scale = self.optional(
            "scenario.time_scale",
            h.time_scale.as_ref(),
            1.0,
            (0.0, MAX_TIME_SCALE, true),
        )?;

        let mut vehicles = Vec::with_capacity(raw.vehicles.len());
        let mut seen: HashMap<String, usize> = HashMap::new();
        for (i, v) in raw.vehicles.iter().enumerate() {
            let key = |k: &str| format!("vehicles[{i}].{k}");
            let id = v.id.get_ref();
            if !is_identifier(id, MAX_VEHICLE_ID_LEN) {
                return Err(ScenarioError::Invalid {
                    line: self.line(&v.id),
                    key: key("id"),
                    reason: format!(
                        "{id:?} is not a vehicle id (1..={MAX_VEHICLE_ID_LEN} of [A-Za-z0-9_.-])"
                    ),
                });
            }
            if let Some(first) = seen.insert(id.clone(), self.line(&v.id)) {
                return Err(ScenarioError::Duplicate {
                    line: self.line(&v.id),
                    key: key("id"),
                    id: id.clone(),
                    first_line: first,
                });
            }
            let (lat, lon) = (StateVector::LATITUDE, StateVector::LONGITUDE);
            vehicles.push(ScenarioVehicle {
                id: id.clone(),
                kind: v.kind,
                latitude_deg: self.range(
                    &key("latitude_deg"),
                    &v.latitude_deg,
                    lat.0,
                    lat.1,
                    false,
                )?,
                longitude_deg: self.range(
                    &key("longitude_deg"),
                    &v.longitude_deg,
                    lon.0,
                    lon.1,
                    false,
                )?,
                battery_pct: self.optional(
                    &key("battery_pct"),
                    v.battery_pct.as_ref(),
                    100.0,
                    (0.0, 100.0, false),
                )?,
                rate_hz: self.optional(
                    &key("rate_hz"),
                    v.rate_hz.as_ref(),
                    1.0,
                    (0.0, 100.0, true),
                )?,
                acoustic_address: None,
            });
            let v_new = &vehicles[vehicles.len() - 1];
            self.at_sea(
                &key("latitude_deg"),
                &v.latitude_deg,
                v_new.latitude_deg,
                v_new.longitude_deg,
                &format!("{id} starts"),
            )?;
        }
        let acoustic = self.acoustic(raw, &mut vehicles)?;

        let mut missions = Vec::with_capacity(raw.missions.len());
        let mut mission_ids: HashMap<String, usize> = HashMap::new();
        for (i, m) in raw.missions.iter().enumerate() {
            let key = |k: &str| format!("missions[{i}].{k}");
            let id = match &m.id {
                Some(id) => {
                    if !is_identifier(id.get_ref(), MAX_MISSION_ID_LEN) {
                        return Err(ScenarioError::Invalid {
                            line: self.line(id),
                            key: key("id"),
                            reason: format!(
                                "{:?} is not a mission id (1..={MAX_MISSION_ID_LEN} of [A-Za-z0-9_.-])",
                                id.get_ref()
                            ),
                        });
                    }
                    if let Some(first) = mission_ids.insert(id.get_ref().clone(), self.line(id)) {
                        return Err(ScenarioError::Duplicate {
                            line: self.line(id),
                            key: key("id"),
                            id: id.get_ref().clone(),
                            first_line: first,
                        });
                    }
                    id.get_ref().clone()
                }
                None => format!("mission-{}", i + 1),
            };
            let at_s = self.range(&key("at_s"), &m.at_s, 0.0, duration_s, false)?;
            if m.tasks.get_ref().is_empty() {
                return Err(ScenarioError::Invalid {
                    line: self.line(&m.tasks),
                    key: key("tasks"),
                    reason: "a mission needs at least one task".into(),
                });
            }
            let mut tasks = Vec::with_capacity(m.tasks.get_ref().len());
            for (j, t) in m.tasks.get_ref().iter().enumerate() {
                tasks.push(self.task(&format!("missions[{i}].tasks[{j}]"), t, &vehicles, &id)?);
            }
            // The station sends a vehicle's next task when the one before has ended, and a
            // hold until the next task never ends: the station would refuse the mission.
            for (j, t) in tasks.iter().enumerate() {
                let open_hold = matches!(t.task, Task::Hold { duration_s } if duration_s == 0.0);
                if open_hold && tasks[j + 1..].iter().any(|n| n.vehicle_id == t.vehicle_id) {
                    let raw_t = &m.tasks.get_ref()[j];
                    return Err(ScenarioError::Invalid {
                        line: self.line(&raw_t.kind),
                        key: format!("missions[{i}].tasks[{j}].duration_s"),
                        reason: "a hold of 0 s (until the next task) must be its vehicle's last \
                                 task in the mission: give it a duration"
                            .into(),
                    });
                }
            }
            missions.push(ScenarioMission {
                id,
                name: m.name.get_ref().clone(),
                at_s,
                tasks,
            });
        }
        // Default ids cannot collide with each other, but may with one given explicitly.
        let mut all: HashMap<&str, usize> = HashMap::new();
        for (i, m) in missions.iter().enumerate() {
            if let Some(first) = all.insert(&m.id, i) {
                let raw_m = &raw.missions[i];
                return Err(ScenarioError::Duplicate {
                    line: self.line(&raw_m.name),
                    key: format!("missions[{i}].id"),
                    id: m.id.clone(),
                    first_line: self.line(&raw.missions[first].name),
                });
            }
        }
        let faults = raw
            .faults
            .iter()
            .enumerate()
            .map(|(i, f)| {
                self.fault(
                    &format!("faults[{i}]"),
                    f,
                    &vehicles,
                    acoustic.as_ref(),
                    duration_s,
                )
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Scenario {
            name: name.to_owned(),
            description: h.description.clone(),
            duration_s,
            time_scale,
            vehicles,
            missions,
            faults,
            acoustic,
            environment: self.environment(raw.environment.as_ref())?,
        })
    }

    /// `[acoustic.channel]`: every parameter of the channel's physics in a range real
    /// modems and seas have; not with a fixed `per`, which replaces the physics.
    fn channel(&self, a: &RawAcoustic) -> Result<ChannelModel, ScenarioError> {
        let d = ChannelModel::default();
        let Some(c) = &a.channel else {
            return Ok(d);
        };
        if let Some(per) = &a.per {
            return Err(ScenarioError::Invalid {
                line: self.line(per),
                key: "acoustic.per".into(),
                reason: "a fixed per replaces the channel's physics: not with [acoustic.channel]"
                    .into(),
            });
        }
        let r = c.get_ref();
        let opt = |k: &str, v: &Option<Spanned<f64>>, default: f64, lo: f64, hi: f64| {
            self.optional(
                &format!("acoustic.channel.{k}"),
                v.as_ref(),
                default,
                (lo, hi, false),
            )
        };
        let centre_khz = opt("centre_khz", &r.centre_khz, d.centre_khz, 1.0, 200.0)?;
        let bandwidth_khz = opt(
            "bandwidth_khz",
            &r.bandwidth_khz,
            d.bandwidth_khz,
            0.1,
            100.0,
        )?;
        if bandwidth_khz > 2.0 * centre_khz
            && let Some(b) = &r.bandwidth_khz
        {
            return Err(ScenarioError::Invalid {
                line: self.line(b),
                key: "acoustic.channel.bandwidth_khz".into(),
                reason: format!("more than twice the centre frequency ({centre_khz} kHz)"),
            });
        }
        Ok(ChannelModel {
            source_level_db: opt(
                "source_level_db",
                &r.source_level_db,
                d.source_level_db,
                100.0,
                220.0,
            )?,
            centre_khz,
            bandwidth_khz,
            spreading_k: opt("spreading_k", &r.spreading_k, d.spreading_k, 1.0, 2.0)?,
            shipping: opt("shipping", &r.shipping, d.shipping, 0.0, 1.0)?,
            wind_mps: opt("wind_mps", &r.wind_mps, d.wind_mps, 0.0, 40.0)?,
            temperature_c: opt(
                "temperature_c",
                &r.temperature_c,
                d.temperature_c,
                -2.0,
                35.0,
            )?,
            salinity_ppt: opt("salinity_ppt", &r.salinity_ppt, d.salinity_ppt, 0.0, 42.0)?,
            modulation: r.modulation.unwrap_or(d.modulation),
        })
    }

    /// The `[environment]` section: every value in a range real water has, at most
    /// [`MAX_PLUMES`] plumes, each changing something.
    fn environment(&self, raw: Option<&RawEnvironment>) -> Result<OceanField, ScenarioError> {
        let d = OceanField::default();
        let Some(e) = raw else {
            return Ok(d);
        };
        let key = |k: &str| format!("environment.{k}");
        let opt = |k: &str, v: &Option<Spanned<f64>>, default: f64, bounds: (f64, f64, bool)| {
            self.optional(&key(k), v.as_ref(), default, bounds)
        };
        let raw_plumes = e
            .plumes
            .as_ref()
            .map_or(&[][..], |p| p.get_ref().as_slice());
        if let Some(all) = &e.plumes
            && raw_plumes.len() > MAX_PLUMES
        {
            return Err(ScenarioError::Invalid {
                line: self.line(all),
                key: key("plumes"),
                reason: format!("at most {MAX_PLUMES} plumes"),
            });
        }
        let (lat, lon) = (StateVector::LATITUDE, StateVector::LONGITUDE);
        let mut plumes = Vec::with_capacity(raw_plumes.len());
        for (i, p) in raw_plumes.iter().enumerate() {
            let key = |k: &str| format!("environment.plumes[{i}].{k}");
            let anomaly = |k: &str, v: &Option<Spanned<f64>>, lo: f64, hi: f64| {
                self.optional(&key(k), v.as_ref(), 0.0, (lo, hi, false))
            };
            let plume = Plume {
                latitude_deg: self.range(
                    &key("latitude_deg"),
                    &p.latitude_deg,
                    lat.0,
                    lat.1,
                    false,
                )?,
                longitude_deg: self.range(
                    &key("longitude_deg"),
                    &p.longitude_deg,
                    lon.0,
                    lon.1,
                    false,
                )?,
                radius_m: self.range(&key("radius_m"), &p.radius_m, 0.0, 50_000.0, true)?,
                depth_m: self.optional(
                    &key("depth_m"),
                    p.depth_m.as_ref(),
                    0.0,
                    (0.0, 1000.0, false),
                )?,
                thickness_m: self.optional(
                    &key("thickness_m"),
                    p.thickness_m.as_ref(),
                    10.0,
                    (0.0, 500.0, true),
                )?,
                temperature_c: anomaly("temperature_c", &p.temperature_c, -20.0, 20.0)?,
                salinity_psu: anomaly("salinity_psu", &p.salinity_psu, -35.0, 10.0)?,
            };
            if plume.temperature_c == 0.0 && plume.salinity_psu == 0.0 {
                return Err(ScenarioError::Invalid {
                    line: self.line(&p.radius_m),
                    key: key("temperature_c"),
                    reason: "a plume needs a temperature_c or salinity_psu anomaly; without, it changes nothing".into(),
                });
            }
            plumes.push(plume);
        }
        Ok(OceanField {
            surface_temperature_c: e
                .surface_temperature_c
                .as_ref()
                .map(|v| self.range(&key("surface_temperature_c"), v, -2.0, 35.0, false))
                .transpose()?,
            eddy_temperature_c: opt(
                "eddy_temperature_c",
                &e.eddy_temperature_c,
                d.eddy_temperature_c,
                (0.0, 5.0, false),
            )?,
            thermocline_m: opt(
                "thermocline_m",
                &e.thermocline_m,
                d.thermocline_m,
                (0.0, 500.0, true),
            )?,
            surface_salinity_psu: opt(
                "surface_salinity_psu",
                &e.surface_salinity_psu,
                d.surface_salinity_psu,
                (0.0, 42.0, false),
            )?,
            current_mps: opt(
                "current_mps",
                &e.current_mps,
                d.current_mps,
                (0.0, 3.0, false),
            )?,
            current_to_deg: opt(
                "current_to_deg",
                &e.current_to_deg,
                d.current_to_deg,
                (0.0, 360.0, false),
            )?,
            plumes,
        })
    }

    /// The `[acoustic]` section and each vehicle's `link` and `acoustic_address`: every
    /// address distinct (the relay's too) and every acoustic vehicle within range.
    fn acoustic(
        &self,
        raw: &RawFile,
        vehicles: &mut [ScenarioVehicle],
    ) -> Result<Option<AcousticNetwork>, ScenarioError> {
        let net = match &raw.acoustic {
            None => None,
            Some(a) => {
                let (lat, lon) = (StateVector::LATITUDE, StateVector::LONGITUDE);
                let carrier = self.relay_vehicle(a, raw, vehicles)?;
                let position = |key: &str,
                                v: Option<&Spanned<f64>>,
                                (lo, hi): (f64, f64),
                                start: Option<f64>|
                 -> Result<f64, ScenarioError> {
                    match (v, start) {
                        (Some(v), None) => self.range(key, v, lo, hi, false),
                        (None, Some(start)) => Ok(start),
                        (Some(v), Some(_)) => Err(ScenarioError::Invalid {
                            line: self.line(v),
                            key: key.to_owned(),
                            reason: "not with relay_vehicle: the relay is where its vehicle is"
                                .into(),
                        }),
                        (None, None) => Err(ScenarioError::Invalid {
                            line: self.line(&raw.scenario.name),
                            key: key.to_owned(),
                            reason: "the relay needs a position, or a relay_vehicle".into(),
                        }),
                    }
                };
                Some(AcousticNetwork {
                    relay_address: match &a.relay_address {
                        Some(r) => self.address("acoustic.relay_address", r)?,
                        None => 1,
                    },
                    relay_latitude_deg: position(
                        "acoustic.relay_latitude_deg",
                        a.relay_latitude_deg.as_ref(),
                        lat,
                        carrier.map(|v| v.latitude_deg),
                    )?,
                    relay_longitude_deg: position(
                        "acoustic.relay_longitude_deg",
                        a.relay_longitude_deg.as_ref(),
                        lon,
                        carrier.map(|v| v.longitude_deg),
                    )?,
                    relay_vehicle: carrier.map(|v| v.id.clone()),
                    fixed_per: a
                        .per
                        .as_ref()
                        .map(|p| self.range("acoustic.per", p, 0.0, 1.0, false))
                        .transpose()?,
                    channel: self.channel(a)?,
                })
            }
        };
        if let (Some(n), Some(a)) = (&net, &raw.acoustic)
            && let Some(la) = &a.relay_latitude_deg
        {
            self.at_sea(
                "acoustic.relay_latitude_deg",
                la,
                n.relay_latitude_deg,
                n.relay_longitude_deg,
                "the relay",
            )?;
        }
        // Addresses given first, then the lowest free one for each acoustic vehicle
        // without, in file order.
        let mut used: HashMap<u8, (usize, String)> = HashMap::new();
        if let (Some(n), Some(a)) = (&net, &raw.acoustic) {
            // The relay's own address is named where [acoustic] says most about it.
            let line = a
                .relay_address
                .as_ref()
                .map(|r| self.line(r))
                .or_else(|| a.relay_latitude_deg.as_ref().map(|r| self.line(r)))
                .or_else(|| a.relay_vehicle.as_ref().map(|r| self.line(r)))
                .unwrap_or(1);
            used.insert(n.relay_address, (line, "acoustic.relay_address".into()));
        }
        for (i, (v, rv)) in vehicles.iter_mut().zip(&raw.vehicles).enumerate() {
            let key = |k: &str| format!("vehicles[{i}].{k}");
            let acoustic = rv
                .link
                .as_ref()
                .is_some_and(|l| *l.get_ref() == LinkName::Acoustic);
            if !acoustic {
                if let Some(a) = &rv.acoustic_address {
                    return Err(ScenarioError::Invalid {
                        line: self.line(a),
                        key: key("acoustic_address"),
                        reason: "only a vehicle with link = \"acoustic\" has one".into(),
                    });
                }
                continue;
            }
            let Some(n) = &net else {
                let line = rv.link.as_ref().map_or(1, |l| self.line(l));
                return Err(ScenarioError::Invalid {
                    line,
                    key: key("link"),
                    reason:
                        "an acoustic vehicle needs an [acoustic] section (the relay that hears it)"
                            .into(),
                });
            };
            let d = shoal_model::geo::distance_m(
                n.relay_latitude_deg,
                n.relay_longitude_deg,
                v.latitude_deg,
                v.longitude_deg,
            );
            if d > MAX_ACOUSTIC_RANGE_M {
                return Err(ScenarioError::Invalid {
                    line: self.line(&rv.latitude_deg),
                    key: key("latitude_deg"),
                    reason: format!(
                        "{} starts {:.1} km from the relay ([acoustic]): out of acoustic range (about {} km)",
                        v.id,
                        d / 1000.0,
                        MAX_ACOUSTIC_RANGE_M / 1000.0
                    ),
                });
            }
            if let Some(a) = &rv.acoustic_address {
                let addr = self.address(&key("acoustic_address"), a)?;
                if let Some((first_line, _)) = used.get(&addr) {
                    return Err(ScenarioError::Duplicate {
                        line: self.line(a),
                        key: key("acoustic_address"),
                        id: addr.to_string(),
                        first_line: *first_line,
                    });
                }
                used.insert(addr, (self.line(a), key("acoustic_address")));
                v.acoustic_address = Some(addr);
            }
        }
        for (i, (v, rv)) in vehicles.iter_mut().zip(&raw.vehicles).enumerate() {
            let acoustic = rv
                .link
                .as_ref()
                .is_some_and(|l| *l.get_ref() == LinkName::Acoustic);
            if !acoustic || v.acoustic_address.is_some() {
                continue;
            }
            let Some(free) = (1..=MAX_ACOUSTIC_ADDRESS).find(|a| !used.contains_key(a)) else {
                return Err(ScenarioError::Invalid {
                    line: self.line(&rv.id),
                    key: format!("vehicles[{i}].link"),
                    reason: format!(
                        "no acoustic address left: the network has {MAX_ACOUSTIC_ADDRESS} (the relay's included)"
                    ),
                });
            };
            used.insert(free, (self.line(&rv.id), format!("vehicles[{i}]")));
            v.acoustic_address = Some(free);
        }
        Ok(net)
    }

    /// Refuses a position on land (on the shipped chart; elsewhere there is no land data).
    fn at_sea(
        &self,
        key: &str,
        at: &Spanned<f64>,
        latitude_deg: f64,
        longitude_deg: f64,
        what: &str,
    ) -> Result<(), ScenarioError> {
        if on_land(latitude_deg, longitude_deg) == Some(true) {
            return Err(ScenarioError::Invalid {
                line: self.line(at),
                key: key.to_owned(),
                reason: format!(
                    "{what} ({latitude_deg}, {longitude_deg}) is on land on the shipped chart"
                ),
            });
        }
        Ok(())
    }

    /// The vehicle `relay_vehicle` names: one of the fleet, on IP.
    fn relay_vehicle<'v>(
        &self,
        a: &RawAcoustic,
        raw: &RawFile,
        vehicles: &'v [ScenarioVehicle],
    ) -> Result<Option<&'v ScenarioVehicle>, ScenarioError> {
        let Some(name) = &a.relay_vehicle else {
            return Ok(None);
        };
        let key = "acoustic.relay_vehicle";
        let Some(i) = vehicles.iter().position(|v| &v.id == name.get_ref()) else {
            return Err(ScenarioError::UnknownVehicle {
                line: self.line(name),
                key: key.into(),
                vehicle: name.get_ref().clone(),
            });
        };
        let acoustic = raw.vehicles[i]
            .link
            .as_ref()
            .is_some_and(|l| *l.get_ref() == LinkName::Acoustic);
        if acoustic {
            return Err(ScenarioError::Invalid {
                line: self.line(name),
                key: key.into(),
                reason: format!(
                    "{} is heard acoustically itself: the relay rides on a vehicle on IP",
                    name.get_ref()
                ),
            });
        }
        Ok(vehicles.get(i))
    }

    fn address(&self, key: &str, v: &Spanned<i64>) -> Result<u8, ScenarioError> {
        let x = *v.get_ref();
        u8::try_from(x)
            .ok()
            .filter(|a| (1..=MAX_ACOUSTIC_ADDRESS).contains(a))
            .ok_or_else(|| ScenarioError::OutOfRange {
                line: self.line(v),
                key: key.to_owned(),
                #[allow(clippy::cast_precision_loss)]
                value: x as f64,
                bounds: format!("[1, {MAX_ACOUSTIC_ADDRESS}]"),
            })
    }

    fn fault(
        &self,
        at: &str,
        f: &RawFault,
        fleet: &[ScenarioVehicle],
        acoustic: Option<&AcousticNetwork>,
        duration_s: f64,
    ) -> Result<ScenarioFault, ScenarioError> {
        let key = |k: &str| format!("{at}.{k}");
        let kind = *f.kind.get_ref();
        let kind_line = self.line(&f.kind);
        let name = match kind {
            FaultName::VehicleFailure => "vehicle_failure",
            FaultName::BatteryDrop => "battery_drop",
            FaultName::RogueSample => "rogue_sample",
            FaultName::StationRestart => "station_restart",
            FaultName::LinkOutage => "link_outage",
            FaultName::ModemFailure => "modem_failure",
        };
        let used: &[&str] = match kind {
            FaultName::VehicleFailure => &["vehicle", "duration_s"],
            FaultName::BatteryDrop => &["vehicle", "battery_pct"],
            FaultName::RogueSample => &["vehicle"],
            FaultName::StationRestart => &["duration_s"],
            FaultName::LinkOutage | FaultName::ModemFailure => &["vehicle", "duration_s"],
        };
        let given: [(&str, Option<Range<usize>>); 3] = [
            ("vehicle", f.vehicle.as_ref().map(Spanned::span)),
            ("duration_s", f.duration_s.as_ref().map(Spanned::span)),
            ("battery_pct", f.battery_pct.as_ref().map(Spanned::span)),
        ];
        for (k, span) in &given {
            if let Some(span) = span
                && !used.contains(k)
            {
                return Err(ScenarioError::Invalid {
                    line: self.lines.of(span),
                    key: key(k),
                    reason: format!("not a key of a {name:?} fault"),
                });
            }
        }
        let missing = |k: &str| ScenarioError::Invalid {
            line: kind_line,
            key: key(k),
            reason: format!("a {name:?} fault needs it"),
        };
        let at_s = self.range(&key("at_s"), &f.at_s, 0.0, duration_s, false)?;
        let vehicle = || -> Result<String, ScenarioError> {
            let v = f.vehicle.as_ref().ok_or_else(|| missing("vehicle"))?;
            if fleet.iter().any(|x| &x.id == v.get_ref()) {
                Ok(v.get_ref().clone())
            } else {
                Err(ScenarioError::UnknownVehicle {
                    line: self.line(v),
                    key: key("vehicle"),
                    vehicle: v.get_ref().clone(),
                })
            }
        };
        let duration = |default: Option<f64>| -> Result<Option<f64>, ScenarioError> {
            match f.duration_s.as_ref() {
                Some(d) => self
                    .range(&key("duration_s"), d, 0.0, MAX_DURATION_S, true)
                    .map(Some),
                None => Ok(default),
            }
        };
        // The acoustic faults name an acoustic vehicle.
        let acoustic_vehicle = || -> Result<String, ScenarioError> {
            let id = vehicle()?;
            if fleet
                .iter()
                .any(|v| v.id == id && v.acoustic_address.is_some())
            {
                return Ok(id);
            }
            let line = f.vehicle.as_ref().map_or(kind_line, |v| self.line(v));
            Err(ScenarioError::Invalid {
                line,
                key: key("vehicle"),
                reason: format!(
                    "{id} is not heard through the acoustic network (link = \"acoustic\")"
                ),
            })
        };
        if matches!(kind, FaultName::LinkOutage | FaultName::ModemFailure) && acoustic.is_none() {
            return Err(ScenarioError::Invalid {
                line: kind_line,
                key: key("kind"),
                reason: format!("a {name:?} fault needs an [acoustic] section"),
            });
        }
        let fault = match kind {
            FaultName::VehicleFailure => Fault::VehicleFailure {
                vehicle: vehicle()?,
                restart_after_s: duration(None)?,
            },
            FaultName::LinkOutage => Fault::LinkOutage {
                vehicle: acoustic_vehicle()?,
                duration_s: duration(None)?.ok_or_else(|| missing("duration_s"))?,
            },
            FaultName::ModemFailure => Fault::ModemFailure {
                vehicle: match f.vehicle {
                    Some(_) => Some(acoustic_vehicle()?),
                    None => None,
                },
                repaired_after_s: duration(None)?,
            },
            FaultName::BatteryDrop => Fault::BatteryDrop {
                vehicle: vehicle()?,
                battery_pct: match f.battery_pct.as_ref() {
                    Some(b) => self.range(&key("battery_pct"), b, 0.0, 100.0, false)?,
                    None => return Err(missing("battery_pct")),
                },
            },
            FaultName::RogueSample => Fault::RogueSample {
                vehicle: vehicle()?,
            },
            FaultName::StationRestart => Fault::StationRestart {
                down_s: duration(Some(5.0))?.unwrap_or(5.0),
            },
        };
        Ok(ScenarioFault { at_s, fault })
    }

    fn task(
        &self,
        at: &str,
        t: &RawTask,
        fleet: &[ScenarioVehicle],
        mission_id: &str,
    ) -> Result<ScenarioTask, ScenarioError> {
        let key = |k: &str| format!("{at}.{k}");
        let vehicle_id = t.vehicle.get_ref();
        let Some(vehicle) = fleet.iter().find(|v| &v.id == vehicle_id) else {
            return Err(ScenarioError::UnknownVehicle {
                line: self.line(&t.vehicle),
                key: key("vehicle"),
                vehicle: vehicle_id.clone(),
            });
        };
        let kind = *t.kind.get_ref();
        // A key the kind does not use is refused: it is a mistake, not a default.
        let used: &[&str] = match kind {
            TaskName::Goto => &[
                "latitude_deg",
                "longitude_deg",
                "depth_m",
                "altitude_m",
                "speed_mps",
            ],
            TaskName::Survey => &["polygon", "spacing_m", "depth_m", "altitude_m", "speed_mps"],
            TaskName::Hold => &["duration_s"],
            TaskName::Surface | TaskName::ReturnHome => &[],
        };
        let given: [(&str, Option<Range<usize>>); 8] = [
            ("latitude_deg", t.latitude_deg.as_ref().map(Spanned::span)),
            ("longitude_deg", t.longitude_deg.as_ref().map(Spanned::span)),
            ("polygon", t.polygon.as_ref().map(Spanned::span)),
            ("spacing_m", t.spacing_m.as_ref().map(Spanned::span)),
            ("depth_m", t.depth_m.as_ref().map(Spanned::span)),
            ("altitude_m", t.altitude_m.as_ref().map(Spanned::span)),
            ("speed_mps", t.speed_mps.as_ref().map(Spanned::span)),
            ("duration_s", t.duration_s.as_ref().map(Spanned::span)),
        ];
        for (k, span) in &given {
            if let Some(span) = span
                && !used.contains(k)
            {
                return Err(ScenarioError::Invalid {
                    line: self.lines.of(span),
                    key: key(k),
                    reason: format!("not a key of a {:?} task", kind_name(kind)),
                });
            }
        }
        let kind_line = self.line(&t.kind);
        let missing = |k: &str| ScenarioError::Invalid {
            line: kind_line,
            key: key(k),
            reason: format!("a {:?} task needs it", kind_name(kind)),
        };
        let (lat, lon) = (StateVector::LATITUDE, StateVector::LONGITUDE);
        let speed = |this: &Self| match t.speed_mps.as_ref() {
            // A cruising speed every simulated kind reaches.
            None => Ok(1.5),
            Some(s) => this.range(&key("speed_mps"), s, 0.0, StateVector::SPEED.1, true),
        };
        let depth = |this: &Self| -> Result<(Option<f64>, Option<f64>), ScenarioError> {
            let d = t
                .depth_m
                .as_ref()
                .map(|d| {
                    this.range(
                        &key("depth_m"),
                        d,
                        StateVector::DEPTH.0,
                        StateVector::DEPTH.1,
                        false,
                    )
                })
                .transpose()?;
            let a = t
                .altitude_m
                .as_ref()
                .map(|a| {
                    this.range(
                        &key("altitude_m"),
                        a,
                        StateVector::ALTITUDE.0,
                        StateVector::ALTITUDE.1,
                        false,
                    )
                })
                .transpose()?;
            match (d, a) {
                (Some(_), Some(_)) => Err(ScenarioError::Invalid {
                    line: kind_line,
                    key: key("altitude_m"),
                    reason: "give depth_m or altitude_m, not both".into(),
                }),
                // A surface vehicle has one depth; anything else must say where to be.
                (None, None) if !vehicle.kind.is_underwater() => Ok((Some(0.0), None)),
                (None, None) => Err(ScenarioError::Invalid {
                    line: kind_line,
                    key: key("depth_m"),
                    reason: format!(
                        "{} is a {}: give depth_m or altitude_m",
                        vehicle.id, vehicle.kind
                    ),
                }),
                other => Ok(other),
            }
        };
        let task = match kind {
            TaskName::Goto => {
                let la = t
                    .latitude_deg
                    .as_ref()
                    .ok_or_else(|| missing("latitude_deg"))?;
                let lo = t
                    .longitude_deg
                    .as_ref()
                    .ok_or_else(|| missing("longitude_deg"))?;
                let (depth_m, altitude_m) = depth(self)?;
                let target = GeoPoint {
                    latitude_deg: self.range(&key("latitude_deg"), la, lat.0, lat.1, false)?,
                    longitude_deg: self.range(&key("longitude_deg"), lo, lon.0, lon.1, false)?,
                };
                self.at_sea(
                    &key("latitude_deg"),
                    la,
                    target.latitude_deg,
                    target.longitude_deg,
                    "the waypoint",
                )?;
                Task::GotoWaypoint {
                    target,
                    depth_m,
                    altitude_m,
                    speed_mps: speed(self)?,
                }
            }
            TaskName::Survey => {
                let Some(polygon) = &t.polygon else {
                    return Err(ScenarioError::Invalid {
                        line: kind_line,
                        key: key("polygon"),
                        reason: "a \"survey\" task needs it: [[lat, lon], ...], 3 or more corners"
                            .into(),
                    });
                };
                let spacing = t.spacing_m.as_ref().ok_or_else(|| missing("spacing_m"))?;
                let corners = polygon.get_ref();
                let pline = self.line(polygon);
                if corners.len() < 3 || corners.len() > TaskAssignment::MAX_AREA {
                    return Err(ScenarioError::Invalid {
                        line: pline,
                        key: key("polygon"),
                        reason: format!(
                            "{} corners; a polygon has 3..={}",
                            corners.len(),
                            TaskAssignment::MAX_AREA
                        ),
                    });
                }
                let mut points = Vec::with_capacity(corners.len());
                for (n, [la, lo]) in corners.iter().copied().enumerate() {
                    for (what, x, (a, b)) in [("latitude", la, lat), ("longitude", lo, lon)] {
                        if !(x.is_finite() && (a..=b).contains(&x)) {
                            return Err(ScenarioError::OutOfRange {
                                line: pline,
                                key: format!("{at}.polygon[{n}] {what}"),
                                value: x,
                                bounds: format!("[{a}, {b}]"),
                            });
                        }
                    }
                    points.push(GeoPoint {
                        latitude_deg: la,
                        longitude_deg: lo,
                    });
                }
                let (depth_m, altitude_m) = depth(self)?;
                Task::SurveyArea {
                    polygon: points,
                    line_spacing_m: self.range(&key("spacing_m"), spacing, 0.0, 10_000.0, true)?,
                    depth_m,
                    altitude_m,
                    speed_mps: speed(self)?,
                }
            }
            TaskName::Hold => Task::Hold {
                duration_s: self.optional(
                    &key("duration_s"),
                    t.duration_s.as_ref(),
                    0.0,
                    (0.0, 86_400.0, false),
                )?,
            },
            TaskName::Surface => Task::Surface,
            TaskName::ReturnHome => Task::ReturnHome,
        };
        // The data model's own checks (a self-intersecting polygon, for one), as the
        // station will make them when it plans the mission.
        let probe = TaskAssignment::new(
            "scenario-check",
            mission_id,
            vehicle_id,
            shoal_model::MIN_TIMESTAMP_MS,
            &task,
        );
        if let Err(e) = probe.task() {
            return Err(ScenarioError::Invalid {
                line: kind_line,
                key: key("kind"),
                reason: e.to_string(),
            });
        }
        Ok(ScenarioTask {
            vehicle_id: vehicle_id.clone(),
            task,
        })
    }
}

fn kind_name(k: TaskName) -> &'static str {
    match k {
        TaskName::Goto => "goto",
        TaskName::Survey => "survey",
        TaskName::Hold => "hold",
        TaskName::Surface => "surface",
        TaskName::ReturnHome => "return_home",
    }
}

#[cfg(test)]
mod tests;
