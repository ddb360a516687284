//! The simulator: a simulated AUV, USV, ROV or glider, and its [`SimAdapter`].
//!
//! [`SimVehicle`] is the vehicle itself, synchronous and without I/O so it is tested
//! step by step: kinematics, battery, task execution, events and environment sampling.
//! [`SimAdapter`] runs it in real time behind [`crate::run_proxy`].
//!
//! Behaviour, in brief:
//!
//! - **Motion.** Flat-earth kinematics; speed follows its target with a 2 s time
//!   constant, heading turns at the kind's turn rate, depth changes at most at the kind's
//!   vertical rate. Waypoints count as reached within [`ARRIVAL_RADIUS_M`] (the last one
//!   also needs its depth within half a metre). The vehicle slows down while turning
//!   hard, so a waypoint close abeam is reached instead of circled.
//! - **Battery.** A hotel load plus a propulsion term growing with the cube of speed (the
//!   power of a displacement hull), in percent per hour per [`Profile`].
//! - **Tasks.** Accepted tasks run one at a time, in issue order (`issued_ms`, then
//!   arrival); a `hold` of duration 0 lasts until the next task is accepted. `abort` is
//!   the exception: it aborts the running task and every queued one and makes an
//!   emergency surface (an emergency stop for surface craft).
//! - **Energy.** Before accepting, the vehicle estimates the battery the task needs (path
//!   length at the task speed, or the duration, plus the tasks ahead of it, plus 10 %)
//!   and refuses it if that would eat into the reserve. `surface` and `return_home` may
//!   use the reserve: that is what it is for. When the battery reaches the reserve, the
//!   running and queued tasks (but those two) fail and an underwater vehicle surfaces.
//! - **Events.** A low-battery warning once when the battery falls to the threshold
//!   (re-armed only after it rises a hysteresis above it), an alarm at the reserve, and
//!   detections at a configurable rate per second while surveying (seeded, so a seed
//!   repeats exactly).
//! - **Environment.** Temperature, salinity and current from [`water_at`], sampled at a
//!   configurable rate by the sensors that measure them (CTD; DVL or ADCP).

mod adapter;
mod rng;

use std::collections::VecDeque;

use serde::{Deserialize, Serialize};
use shoal_model::{
    EventKind, GeoPoint, LinkKind, Severity, StateVector, Task, TaskKind, TaskState, UNKNOWN,
    VehicleAnnouncement, VehicleKind,
};

pub use adapter::{SimAdapter, SimFault};
pub use shoal_model::geo::{EARTH_RADIUS_M, angle_diff, distance, distance_bearing, path_length};
pub use shoal_model::kinematics::Profile;
pub use shoal_model::ocean::{
    CURRENT_DIRECTION, CURRENT_SPEED, OceanField, Plume, SALINITY, TEMPERATURE, UNITS, Water,
    water_at,
};
pub use shoal_model::survey::{MAX_SURVEY_LINES, SurveyError, lawnmower};

use crate::adapter::{
    Acceptance, Refusal, TaskOrder, TaskUpdate, VehicleEvent, VehicleOutput, capability_of,
};
use rand::{RngExt as _, SeedableRng as _};
use rng::SplitMix64;

/// Distance at which a waypoint counts as reached, metres.
pub const ARRIVAL_RADIUS_M: f64 = 5.0;
/// Longest integration step, seconds; [`SimVehicle::step`] splits longer ones.
pub const MAX_STEP_S: f64 = 0.1;
/// Most simulated time one [`SimVehicle::step`] call advances, seconds.
pub const MAX_ADVANCE_S: f64 = 3600.0;
/// Least time between two progress reports of a task, seconds: a short task need not
/// report every tenth of its work.
const PROGRESS_EVERY_S: f64 = 5.0;
/// How close to its target depth the vehicle must be for the last waypoint to count.
const DEPTH_TOLERANCE_M: f64 = 0.5;
/// Sensors that can make a detection while surveying, in order of preference.
const DETECTION_SENSORS: [&str; 3] = ["sidescan_sonar", "multibeam", "camera"];

/// Where and how a simulated vehicle starts.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimSpec {
    /// Vehicle id.
    pub id: String,
    /// Kind of vehicle.
    pub kind: VehicleKind,
    /// Start latitude, degrees.
    pub latitude_deg: f64,
    /// Start longitude, degrees.
    pub longitude_deg: f64,
    /// State vectors per second.
    #[serde(default = "default_rate")]
    pub rate_hz: f64,
    /// Battery at start, percent.
    #[serde(default = "default_battery")]
    pub battery_pct: f64,
}

fn default_rate() -> f64 {
    1.0
}
fn default_battery() -> f64 {
    100.0
}

/// How a simulated vehicle behaves beyond its kind: battery policy, events, sampling.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SimSettings {
    /// Seed of the simulator's random numbers (detections); `None` derives one from the
    /// vehicle id, so each vehicle differs but every run repeats.
    pub seed: Option<u64>,
    /// Battery kept in reserve, percent: tasks that would need it are refused, and running
    /// tasks fail when the battery reaches it.
    pub reserve_pct: f64,
    /// Battery level that raises a low-battery warning, percent.
    pub low_battery_pct: f64,
    /// How far the battery must rise above `low_battery_pct` before the warning can fire
    /// again, percent.
    pub low_battery_hysteresis_pct: f64,
    /// Probability per second of a detection while surveying, [0, 1].
    pub detection_per_s: f64,
    /// Environment samples per second (each gives temperature, salinity and current); 0
    /// turns sampling off.
    pub environment_hz: f64,
    /// The ocean the vehicle samples.
    pub ocean: OceanField,
}

impl Default for SimSettings {
    fn default() -> Self {
        Self {
            seed: None,
            reserve_pct: 10.0,
            low_battery_pct: 20.0,
            low_battery_hysteresis_pct: 5.0,
            detection_per_s: 0.01,
            environment_hz: 0.1,
            ocean: OceanField::default(),
        }
    }
}

impl SimSettings {
    /// The settings with every value forced into its valid range (NaN becomes the default).
    fn sanitized(&self) -> Self {
        let d = Self::default();
        let pick = |v: f64, default: f64, lo: f64, hi: f64| {
            if v.is_finite() {
                v.clamp(lo, hi)
            } else {
                default
            }
        };
        Self {
            seed: self.seed,
            reserve_pct: pick(self.reserve_pct, d.reserve_pct, 0.0, 100.0),
            low_battery_pct: pick(self.low_battery_pct, d.low_battery_pct, 0.0, 100.0),
            low_battery_hysteresis_pct: pick(
                self.low_battery_hysteresis_pct,
                d.low_battery_hysteresis_pct,
                0.0,
                100.0,
            ),
            detection_per_s: pick(self.detection_per_s, 0.0, 0.0, 1.0),
            environment_hz: pick(self.environment_hz, 0.0, 0.0, 10.0),
            ocean: self.ocean.clone(),
        }
    }
}

/// An alarm that fires once when a level falls to a threshold, and re-arms only after the
/// level rises above the threshold plus a hysteresis (so noise around the threshold does
/// not repeat it).
#[derive(Debug, Clone)]
struct FallingAlarm {
    threshold: f64,
    rearm_above: f64,
    armed: bool,
}

impl FallingAlarm {
    fn new(threshold: f64, hysteresis: f64) -> Self {
        Self {
            threshold,
            rearm_above: threshold + hysteresis,
            armed: true,
        }
    }

    /// True exactly when the level reaches the threshold while armed.
    fn update(&mut self, level: f64) -> bool {
        if self.armed && level <= self.threshold {
            self.armed = false;
            return true;
        }
        if !self.armed && level > self.rearm_above {
            self.armed = true;
        }
        false
    }
}

/// How the vehicle executes one task.
#[derive(Debug, Clone, PartialEq)]
enum Plan {
    /// Follow waypoints (a goto is one, a survey many) at a depth and speed.
    Route {
        waypoints: Vec<GeoPoint>,
        next: usize,
        depth_m: f64,
        speed_mps: f64,
        /// Path length from waypoint `i` to the end, for progress.
        after: Vec<f64>,
        /// Path length when the task started.
        total_m: f64,
    },
    /// Hold position for a time, or until the next task (`None`).
    Hold {
        duration_s: Option<f64>,
        elapsed_s: f64,
    },
    /// Rise to the surface.
    Surface { from_m: f64 },
    /// Come to a stop (a surface craft's abort).
    Stop,
}

/// A task the vehicle accepted.
#[derive(Debug, Clone)]
struct Job {
    id: String,
    kind: TaskKind,
    issued_ms: i64,
    plan: Plan,
    /// Progress decile last reported as `running`.
    reported_decile: u32,
    /// Seconds since the last `running` report.
    since_report_s: f64,
}

impl Job {
    /// Tasks allowed to use the battery reserve, and which keep running at it.
    fn is_safety(&self) -> bool {
        matches!(
            self.kind,
            TaskKind::Surface | TaskKind::ReturnHome | TaskKind::Abort
        )
    }

    /// Fixes what depends on where the task starts.
    fn begin(&mut self, here: GeoPoint, depth_m: f64) {
        match &mut self.plan {
            Plan::Route {
                waypoints,
                after,
                total_m,
                ..
            } => {
                let mut suffix = vec![0.0; waypoints.len()];
                for i in (0..waypoints.len().saturating_sub(1)).rev() {
                    suffix[i] = suffix[i + 1] + distance(waypoints[i], waypoints[i + 1]);
                }
                *total_m = waypoints
                    .first()
                    .map_or(0.0, |w| distance(here, *w) + suffix[0]);
                *after = suffix;
            }
            Plan::Surface { from_m } => *from_m = depth_m,
            Plan::Hold { .. } | Plan::Stop => {}
        }
    }

    /// Progress in percent, [0, 100].
    fn progress(&self, here: GeoPoint, depth_m: f64) -> f64 {
        let fraction = match &self.plan {
            Plan::Route {
                waypoints,
                next,
                after,
                total_m,
                ..
            } => match (waypoints.get(*next), after.get(*next)) {
                (Some(wp), Some(rest)) if *total_m > 0.0 => {
                    1.0 - (distance(here, *wp) + rest) / total_m
                }
                _ => 1.0,
            },
            Plan::Hold {
                duration_s: Some(d),
                elapsed_s,
            } if *d > 0.0 => elapsed_s / d,
            Plan::Surface { from_m } if *from_m > 0.0 => 1.0 - depth_m / from_m,
            Plan::Hold { .. } | Plan::Surface { .. } | Plan::Stop => 0.0,
        };
        (100.0 * fraction).clamp(0.0, 100.0)
    }

    /// What the vehicle is doing, for the operator.
    fn describe(&self) -> String {
        match &self.plan {
            Plan::Route {
                waypoints,
                depth_m,
                speed_mps,
                ..
            } => match (self.kind, waypoints.last()) {
                (TaskKind::SurveyArea, _) => format!(
                    "surveying {} lines at {depth_m:.1} m, {speed_mps:.1} m/s",
                    waypoints.len() / 2
                ),
                (TaskKind::ReturnHome, _) => format!("returning home at {speed_mps:.1} m/s"),
                (_, Some(wp)) => format!(
                    "going to {:.5}, {:.5} at {depth_m:.1} m, {speed_mps:.1} m/s",
                    wp.latitude_deg, wp.longitude_deg
                ),
                (_, None) => String::new(),
            },
            Plan::Hold {
                duration_s: Some(d),
                ..
            } => format!("holding for {d:.0} s"),
            Plan::Hold { .. } => "holding until the next task".into(),
            Plan::Surface { .. } if self.kind == TaskKind::Abort => "emergency surface".into(),
            Plan::Surface { .. } => "surfacing".into(),
            Plan::Stop => "emergency stop".into(),
        }
    }
}

/// One simulated vehicle: position, battery, tasks, and what it has to report.
#[derive(Debug, Clone)]
pub struct SimVehicle {
    /// Registration data it announces.
    pub announcement: VehicleAnnouncement,
    profile: Profile,
    settings: SimSettings,
    /// Simulation clock, ms since the Unix epoch (fractional, so 0.1 s steps do not drift).
    clock_ms: f64,
    lat: f64,
    lon: f64,
    depth: f64,
    speed: f64,
    yaw: f64,
    pitch: f64,
    battery: f64,
    home: GeoPoint,
    running: Option<Job>,
    queue: VecDeque<Job>,
    /// With no task, rise to the surface (after reaching the battery reserve).
    idle_surface: bool,
    outputs: VecDeque<VehicleOutput>,
    rng: SplitMix64,
    low_battery: FallingAlarm,
    at_reserve: bool,
    /// Seconds until the next environment sample.
    sample_in_s: f64,
}

impl SimVehicle {
    /// A vehicle at rest at its start position, with default [`SimSettings`].
    pub fn new(spec: &SimSpec, timestamp_ms: i64) -> Self {
        Self::with_settings(spec, &SimSettings::default(), timestamp_ms)
    }

    /// A vehicle at rest at its start position.
    pub fn with_settings(spec: &SimSpec, settings: &SimSettings, timestamp_ms: i64) -> Self {
        let profile = Profile::of(spec.kind);
        let settings = settings.sanitized();
        let (capabilities, sensors, links): (&[&str], &[&str], Vec<LinkKind>) = match spec.kind {
            VehicleKind::Auv | VehicleKind::Glider => (
                &["goto", "survey", "hold", "surface", "return_home", "abort"],
                &["ctd", "sidescan_sonar", "dvl"],
                vec![LinkKind::Ip, LinkKind::Acoustic],
            ),
            VehicleKind::Rov => (
                &["goto", "hold", "surface", "return_home", "abort"],
                &["camera", "ctd"],
                vec![LinkKind::Tether, LinkKind::Ip],
            ),
            VehicleKind::Usv | VehicleKind::Asv => (
                &["goto", "survey", "hold", "return_home", "abort"],
                &["gps", "ctd", "multibeam", "adcp"],
                vec![LinkKind::Ip, LinkKind::Radio, LinkKind::Acoustic],
            ),
        };
        let announcement = VehicleAnnouncement {
            vehicle_id: spec.id.clone(),
            name: format!(
                "Simulated {} {}",
                spec.kind.as_str().to_uppercase(),
                spec.id
            ),
            kind: spec.kind,
            vendor: "Shoal simulator".into(),
            capabilities: capabilities.iter().map(|s| (*s).to_string()).collect(),
            sensors: sensors.iter().map(|s| (*s).to_string()).collect(),
            links,
            max_speed_mps: profile.max_mps,
            timestamp_ms,
        };
        let battery = if spec.battery_pct.is_finite() {
            spec.battery_pct.clamp(0.0, 100.0)
        } else {
            0.0
        };
        let seed = settings.seed.unwrap_or_else(|| rng::seed_from(&spec.id));
        #[allow(clippy::cast_precision_loss)]
        let clock_ms = timestamp_ms as f64;
        Self {
            announcement,
            profile,
            rng: SplitMix64::seed_from_u64(seed),
            low_battery: FallingAlarm::new(
                settings.low_battery_pct,
                settings.low_battery_hysteresis_pct,
            ),
            // The first sample comes one period after the start, like every later one.
            sample_in_s: if settings.environment_hz > 0.0 {
                1.0 / settings.environment_hz
            } else {
                f64::INFINITY
            },
            settings,
            clock_ms,
            lat: spec.latitude_deg,
            lon: spec.longitude_deg,
            depth: 0.0,
            speed: 0.0,
            yaw: 0.0,
            pitch: 0.0,
            battery,
            home: GeoPoint {
                latitude_deg: spec.latitude_deg,
                longitude_deg: spec.longitude_deg,
            },
            running: None,
            queue: VecDeque::new(),
            idle_surface: false,
            outputs: VecDeque::new(),
            at_reserve: false,
        }
    }

    /// The current state vector, stamped `timestamp_ms`.
    pub fn state(&self, timestamp_ms: i64) -> StateVector {
        StateVector {
            vehicle_id: self.announcement.vehicle_id.clone(),
            timestamp_ms,
            latitude_deg: self.lat,
            longitude_deg: self.lon,
            depth_m: self.depth,
            altitude_m: if self.is_underwater() {
                (self.profile.seabed_m - self.depth).max(0.0)
            } else {
                UNKNOWN
            },
            speed_mps: self.speed,
            yaw_deg: self.yaw.rem_euclid(360.0) % 360.0,
            pitch_deg: self.pitch,
            roll_deg: 0.0,
            battery_pct: self.battery,
        }
    }

    /// The simulation clock, ms since the Unix epoch.
    pub fn clock_ms(&self) -> i64 {
        // Finite and within a few hours of a valid timestamp by construction.
        #[allow(clippy::cast_possible_truncation)]
        let ms = self.clock_ms.round() as i64;
        ms
    }

    /// Where the vehicle is.
    pub fn position(&self) -> GeoPoint {
        GeoPoint {
            latitude_deg: self.lat,
            longitude_deg: self.lon,
        }
    }

    /// Depth, metres.
    pub fn depth_m(&self) -> f64 {
        self.depth
    }

    /// Remaining battery, percent.
    pub fn battery_pct(&self) -> f64 {
        self.battery
    }

    /// A failed cell: the battery falls at once to `to_pct` (never rises); the warning and
    /// the reserve policy react at the next step as to any drain.
    pub fn drop_battery(&mut self, to_pct: f64) {
        if to_pct.is_finite() {
            self.battery = self.battery.min(to_pct.clamp(0.0, 100.0));
        }
    }

    /// The task being executed, if any.
    pub fn current_task(&self) -> Option<&str> {
        self.running.as_ref().map(|j| j.id.as_str())
    }

    /// The accepted tasks waiting to run, in the order they will run.
    pub fn queued_tasks(&self) -> impl Iterator<Item = &str> {
        self.queue.iter().map(|j| j.id.as_str())
    }

    /// Takes the oldest output the vehicle has not handed over yet.
    pub fn pop_output(&mut self) -> Option<VehicleOutput> {
        self.outputs.pop_front()
    }

    /// Takes every output the vehicle has not handed over yet, oldest first.
    pub fn drain_outputs(&mut self) -> Vec<VehicleOutput> {
        self.outputs.drain(..).collect()
    }

    fn is_underwater(&self) -> bool {
        self.announcement.kind.is_underwater()
    }

    fn has_sensor(&self, code: &str) -> bool {
        self.announcement.sensors.iter().any(|s| s == code)
    }

    /// Offers the vehicle a task: accepted (to run now or after the queued ones) or refused
    /// with the reason. Progress follows in the outputs.
    pub fn submit(&mut self, order: &TaskOrder) -> Result<Acceptance, Refusal> {
        let kind = order.task.kind();
        let code = capability_of(kind);
        if matches!(kind, TaskKind::RequestState | TaskKind::SetReportingRate) {
            return Err(Refusal::new(format!(
                "{code} is served by the DDS proxy, not the vehicle"
            )));
        }
        if !self.announcement.capabilities.iter().any(|c| c == code) {
            return Err(Refusal::new(format!(
                "a simulated {} has no {code} capability",
                self.announcement.kind
            )));
        }
        if kind == TaskKind::Abort {
            return Ok(self.abort(&order.task_id));
        }
        if self.battery <= 0.0 {
            return Err(Refusal::new("battery empty"));
        }
        let mut notes = Vec::new();
        let job = Job {
            id: order.task_id.clone(),
            kind,
            issued_ms: order.issued_ms,
            plan: self.plan(&order.task, &mut notes)?,
            reported_decile: 0,
            since_report_s: 0.0,
        };
        let safety = job.is_safety();
        let reserve = self.settings.reserve_pct;
        if self.at_reserve && !safety {
            return Err(Refusal::new(format!(
                "battery at its {reserve:.0} % reserve: only surface, return_home and abort are taken"
            )));
        }
        let (ahead_pct, from, from_depth) = self.energy_ahead();
        let (need, _, _) = self.energy(&job.plan, from, from_depth);
        let floor = if safety { 0.0 } else { reserve };
        let available = self.battery - ahead_pct - floor;
        if need > available {
            let ahead = self.queue.len() + usize::from(self.running.is_some());
            let after = if ahead > 0 {
                format!(" after the {ahead} task(s) ahead of it")
            } else {
                String::new()
            };
            return Err(Refusal::new(format!(
                "needs about {need:.1} % of battery, but only {:.1} % is left{after} above the {floor:.0} % reserve",
                available.max(0.0)
            )));
        }
        let at = self
            .queue
            .iter()
            .position(|j| j.issued_ms > job.issued_ms)
            .unwrap_or(self.queue.len());
        self.queue.insert(at, job);
        self.start_next();
        let waiting = self.queue.iter().position(|j| j.id == order.task_id);
        if let Some(i) = waiting {
            let ahead = i + usize::from(self.running.is_some());
            notes.insert(0, format!("queued behind {ahead} task(s)"));
        }
        Ok(Acceptance::with_message(notes.join("; ")))
    }

    /// How the vehicle would execute a task, or why it cannot.
    fn plan(&self, task: &Task, notes: &mut Vec<String>) -> Result<Plan, Refusal> {
        let p = self.profile;
        let depth_for = |depth: Option<f64>, altitude: Option<f64>| -> Result<f64, Refusal> {
            // The surface for surface craft, whatever the task says.
            let d = p.depth_for(depth, altitude);
            if d > p.seabed_m - 1.0 {
                return Err(Refusal::new(format!(
                    "target depth {d:.1} m is at or below the seabed at {:.1} m",
                    p.seabed_m
                )));
            }
            Ok(d)
        };
        let mut speed_for = |s: f64| {
            if s > p.max_mps {
                notes.push(format!("speed limited to {:.1} m/s", p.max_mps));
            }
            p.speed_for(s)
        };
        let route = |waypoints: Vec<GeoPoint>, depth_m: f64, speed_mps: f64| Plan::Route {
            waypoints,
            next: 0,
            depth_m,
            speed_mps,
            after: Vec::new(),
            total_m: 0.0,
        };
        Ok(match task {
            Task::GotoWaypoint {
                target,
                depth_m,
                altitude_m,
                speed_mps,
            } => route(
                vec![*target],
                depth_for(*depth_m, *altitude_m)?,
                speed_for(*speed_mps),
            ),
            Task::SurveyArea {
                polygon,
                line_spacing_m,
                depth_m,
                altitude_m,
                speed_mps,
            } => {
                let waypoints =
                    lawnmower(polygon, *line_spacing_m).map_err(|e| Refusal::new(e.to_string()))?;
                route(
                    waypoints,
                    depth_for(*depth_m, *altitude_m)?,
                    speed_for(*speed_mps),
                )
            }
            Task::Hold { duration_s } => Plan::Hold {
                duration_s: (*duration_s > 0.0).then_some(*duration_s),
                elapsed_s: 0.0,
            },
            Task::Surface => Plan::Surface { from_m: 0.0 },
            Task::ReturnHome => route(vec![self.home], 0.0, p.cruise_mps),
            Task::Abort | Task::RequestState | Task::SetReportingRate { .. } => Plan::Stop,
        })
    }

    /// Battery (percent) a plan needs from a start point and depth, and where it ends.
    fn energy(&self, plan: &Plan, from: GeoPoint, from_depth: f64) -> (f64, GeoPoint, f64) {
        let p = self.profile;
        match plan {
            Plan::Route {
                waypoints,
                next,
                depth_m,
                speed_mps,
                ..
            } => {
                let rest = waypoints.get(*next..).unwrap_or_default();
                let cost = p.route(from, rest, from_depth, *depth_m, *speed_mps);
                let end = rest.last().copied().unwrap_or(from);
                (cost.battery_pct, end, *depth_m)
            }
            Plan::Hold {
                duration_s,
                elapsed_s,
            } => {
                let left = duration_s.map_or(0.0, |d| d - elapsed_s);
                (p.hold(left).battery_pct, from, from_depth)
            }
            Plan::Surface { .. } => (p.surface(from_depth).battery_pct, from, 0.0),
            Plan::Stop => (0.0, from, from_depth),
        }
    }

    /// Battery the running and queued tasks still need, and where the last one ends.
    fn energy_ahead(&self) -> (f64, GeoPoint, f64) {
        let mut at = (self.position(), self.depth);
        let mut total = 0.0;
        for job in self.running.iter().chain(self.queue.iter()) {
            let (pct, end, depth) = self.energy(&job.plan, at.0, at.1);
            total += pct;
            at = (end, depth);
        }
        (total, at.0, at.1)
    }

    /// Emergency: aborts everything and surfaces (stops, at the surface).
    fn abort(&mut self, task_id: &str) -> Acceptance {
        let what = if self.is_underwater() {
            "emergency surface"
        } else {
            "emergency stop"
        };
        let reason = format!("aborted by {task_id} ({what})");
        let mut aborted = 0;
        if let Some(job) = self.running.take() {
            let progress = job.progress(self.position(), self.depth);
            self.push_update(&job.id, TaskState::Aborted, progress, &reason);
            aborted += 1;
        }
        for job in std::mem::take(&mut self.queue) {
            self.push_update(&job.id, TaskState::Aborted, 0.0, &reason);
            aborted += 1;
        }
        let plan = if self.is_underwater() {
            Plan::Surface { from_m: 0.0 }
        } else {
            Plan::Stop
        };
        let mut job = Job {
            id: task_id.to_string(),
            kind: TaskKind::Abort,
            issued_ms: 0,
            plan,
            reported_decile: 0,
            since_report_s: 0.0,
        };
        job.begin(self.position(), self.depth);
        self.push_update(task_id, TaskState::Running, 0.0, &job.describe());
        self.running = Some(job);
        Acceptance::with_message(format!("{what}; {aborted} task(s) aborted"))
    }

    /// Starts the next queued task if nothing runs, ending an open-ended hold first.
    fn start_next(&mut self) {
        if let Some(job) = &self.running {
            let open_hold = matches!(
                job.plan,
                Plan::Hold {
                    duration_s: None,
                    ..
                }
            );
            match self.queue.front() {
                Some(next) if open_hold => {
                    let msg = format!("held until {} started", next.id);
                    self.finish(TaskState::Done, &msg);
                }
                _ => return,
            }
        }
        let Some(mut job) = self.queue.pop_front() else {
            return;
        };
        job.begin(self.position(), self.depth);
        self.push_update(&job.id, TaskState::Running, 0.0, &job.describe());
        self.running = Some(job);
    }

    /// Ends the running task with a final state.
    fn finish(&mut self, state: TaskState, message: &str) {
        if let Some(job) = self.running.take() {
            let progress = if state == TaskState::Done {
                100.0
            } else {
                job.progress(self.position(), self.depth)
            };
            self.push_update(&job.id, state, progress, message);
        }
    }

    fn push_update(&mut self, task_id: &str, state: TaskState, progress: f64, message: &str) {
        let progress = (progress * 10.0).round() / 10.0;
        self.outputs.push_back(VehicleOutput::Task(TaskUpdate::new(
            task_id, state, progress, message,
        )));
    }

    fn push_event(&mut self, severity: Severity, kind: EventKind, task_id: &str, text: String) {
        self.outputs.push_back(VehicleOutput::Event(VehicleEvent {
            timestamp_ms: self.clock_ms(),
            severity,
            kind,
            task_id: task_id.to_string(),
            text,
        }));
    }

    /// Advances the simulation by `dt` seconds (at most [`MAX_ADVANCE_S`], in steps of at
    /// most [`MAX_STEP_S`]); what happened is queued as outputs.
    pub fn step(&mut self, dt: f64) {
        if !dt.is_finite() || dt <= 0.0 {
            return;
        }
        let mut left = dt.min(MAX_ADVANCE_S);
        while left > 1e-9 {
            let h = left.min(MAX_STEP_S);
            self.step_once(h);
            left -= h;
        }
    }

    fn step_once(&mut self, dt: f64) {
        self.clock_ms += dt * 1000.0;
        let (target_speed, target_depth, heading) = self.guide(dt);
        self.move_by(dt, target_speed, target_depth, heading);
        self.report_progress(dt);
        self.check_battery();
        self.maybe_detect(dt);
        self.maybe_sample(dt);
        self.start_next();
    }

    /// Target speed, depth and heading from the running task (or idling); completes tasks
    /// whose goal is reached.
    fn guide(&mut self, dt: f64) -> (f64, f64, Option<f64>) {
        let here = self.position();
        let depth = self.depth;
        let (yaw, speed) = (self.yaw, self.speed);
        if self.battery <= 0.0 {
            // A flat battery stops the thrusters; a positively buoyant hull floats up.
            return (0.0, 0.0, None);
        }
        let Some(job) = &mut self.running else {
            let target = if self.idle_surface { 0.0 } else { depth };
            return (0.0, target, None);
        };
        let mut done: Option<String> = None;
        let target = match &mut job.plan {
            Plan::Route {
                waypoints,
                next,
                depth_m,
                speed_mps,
                ..
            } => {
                let depth_ok = (depth - *depth_m).abs() <= DEPTH_TOLERANCE_M;
                while let Some(wp) = waypoints.get(*next) {
                    let last = *next + 1 == waypoints.len();
                    if distance(here, *wp) > ARRIVAL_RADIUS_M || (last && !depth_ok) {
                        break;
                    }
                    *next += 1;
                }
                match waypoints.get(*next) {
                    None => {
                        done = Some(match job.kind {
                            TaskKind::SurveyArea => "survey complete".to_string(),
                            TaskKind::ReturnHome => "home".to_string(),
                            _ => "arrived".to_string(),
                        });
                        (0.0, depth, None)
                    }
                    // At the last waypoint, still changing depth: hover until there.
                    Some(wp) if distance(here, *wp) <= ARRIVAL_RADIUS_M => (0.0, *depth_m, None),
                    Some(wp) => {
                        let (_, bearing) = distance_bearing(
                            here.latitude_deg,
                            here.longitude_deg,
                            wp.latitude_deg,
                            wp.longitude_deg,
                        );
                        // Slowing down in a hard turn shrinks the turn circle, so a waypoint
                        // close abeam is reached instead of circled for ever.
                        let error = angle_diff(bearing, yaw).abs();
                        let factor = error.to_radians().cos().max(0.1);
                        (*speed_mps * factor, *depth_m, Some(bearing))
                    }
                }
            }
            Plan::Hold {
                duration_s,
                elapsed_s,
            } => {
                *elapsed_s += dt;
                if let Some(d) = duration_s
                    && *elapsed_s >= *d - 1e-9
                {
                    done = Some(format!("held for {d:.0} s"));
                }
                (0.0, depth, None)
            }
            Plan::Surface { .. } => {
                if depth <= 0.01 {
                    done = Some("at the surface".into());
                }
                (0.0, 0.0, None)
            }
            Plan::Stop => {
                if speed < 0.05 {
                    done = Some("stopped".into());
                }
                (0.0, depth, None)
            }
        };
        if let Some(msg) = done {
            self.finish(TaskState::Done, &msg);
        }
        target
    }

    /// Kinematics and battery over one step.
    fn move_by(&mut self, dt: f64, target_speed: f64, target_depth: f64, heading: Option<f64>) {
        let p = self.profile;
        if let Some(h) = heading {
            let turn = angle_diff(h, self.yaw).clamp(-p.turn_dps * dt, p.turn_dps * dt);
            self.yaw = (self.yaw + turn).rem_euclid(360.0);
        }
        // First-order speed response, time constant 2 s.
        self.speed += (target_speed - self.speed) * (dt / 2.0).min(1.0);
        self.speed = self.speed.clamp(0.0, p.max_mps);
        let target_depth = if self.is_underwater() {
            target_depth.clamp(0.0, p.seabed_m)
        } else {
            0.0
        };
        let dz = (target_depth - self.depth).clamp(-p.vertical_mps * dt, p.vertical_mps * dt);
        self.depth = (self.depth + dz).max(0.0);
        if self.depth < 1e-6 {
            self.depth = 0.0;
        }
        // Flying vehicles pitch into a dive (nose down is negative); an ROV and a surface
        // craft stay level.
        self.pitch = match self.announcement.kind {
            VehicleKind::Auv | VehicleKind::Glider if dz != 0.0 => {
                (-(dz / dt).atan2(self.speed.max(0.3)).to_degrees()).clamp(-30.0, 30.0)
            }
            _ => 0.0,
        };
        let d = self.speed * dt;
        let yaw = self.yaw.to_radians();
        self.lat += (d * yaw.cos() / EARTH_RADIUS_M).to_degrees();
        self.lon +=
            (d * yaw.sin() / (EARTH_RADIUS_M * self.lat.to_radians().cos().max(1e-6))).to_degrees();
        self.lat = self.lat.clamp(-89.9, 89.9);
        if self.lon > 180.0 {
            self.lon -= 360.0;
        } else if self.lon < -180.0 {
            self.lon += 360.0;
        }
        self.battery = (self.battery - p.drain_pct_h(self.speed) * dt / 3600.0).max(0.0);
    }

    /// Reports `running` each time a task passes another tenth of its work (at most every
    /// [`PROGRESS_EVERY_S`]).
    fn report_progress(&mut self, dt: f64) {
        let here = self.position();
        let depth = self.depth;
        let Some(job) = &mut self.running else {
            return;
        };
        job.since_report_s += dt;
        let progress = job.progress(here, depth);
        // Truncation is the point: the decile the progress is in.
        #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
        let decile = (progress / 10.0).floor() as u32;
        if decile > job.reported_decile
            && progress < 100.0
            && job.since_report_s >= PROGRESS_EVERY_S
        {
            job.reported_decile = decile;
            job.since_report_s = 0.0;
            let id = job.id.clone();
            self.push_update(&id, TaskState::Running, progress, "");
        }
    }

    fn check_battery(&mut self) {
        let task = self.current_task().unwrap_or_default().to_string();
        if self.low_battery.update(self.battery) {
            let text = format!(
                "battery at {:.1} %, below the {:.0} % threshold",
                self.battery, self.settings.low_battery_pct
            );
            self.push_event(Severity::Warning, EventKind::LowBattery, &task, text);
        }
        let reserve = self.settings.reserve_pct;
        if !self.at_reserve && self.battery <= reserve {
            self.at_reserve = true;
            let msg = format!("battery at its {reserve:.0} % reserve");
            if self.running.as_ref().is_some_and(|j| !j.is_safety()) {
                self.finish(TaskState::Failed, &msg);
            }
            let (keep, fail): (VecDeque<Job>, VecDeque<Job>) = std::mem::take(&mut self.queue)
                .into_iter()
                .partition(Job::is_safety);
            self.queue = keep;
            let mut failed = usize::from(self.running.is_none() && !task.is_empty());
            for job in fail {
                self.push_update(&job.id, TaskState::Failed, 0.0, &msg);
                failed += 1;
            }
            self.idle_surface = self.is_underwater();
            let then = if self.is_underwater() {
                "surfacing"
            } else {
                "stopping"
            };
            self.push_event(
                Severity::Alarm,
                EventKind::LowBattery,
                &task,
                format!("{msg}: {failed} task(s) failed, {then}"),
            );
        } else if self.at_reserve
            && self.battery > reserve + self.settings.low_battery_hysteresis_pct
        {
            self.at_reserve = false;
            self.idle_surface = false;
        }
        if self.battery <= 0.0 && self.running.is_some() {
            self.finish(TaskState::Failed, "battery empty");
        }
    }

    /// Random detections while on the survey lines (not on the transit to the first one).
    fn maybe_detect(&mut self, dt: f64) {
        let surveying = self.running.as_ref().is_some_and(|j| {
            j.kind == TaskKind::SurveyArea && matches!(j.plan, Plan::Route { next, .. } if next > 0)
        });
        let p = self.settings.detection_per_s;
        if !surveying || p <= 0.0 {
            return;
        }
        let Some(sensor) = DETECTION_SENSORS.iter().find(|s| self.has_sensor(s)) else {
            return;
        };
        // Per-second probability p over a step of dt seconds.
        let p_step = 1.0 - (1.0 - p).powf(dt);
        if self.rng.random::<f64>() >= p_step {
            return;
        }
        let text = format!(
            "{sensor} contact at {:.5}, {:.5}, depth {:.1} m",
            self.lat, self.lon, self.depth
        );
        let task = self.current_task().unwrap_or_default().to_string();
        self.push_event(Severity::Info, EventKind::Detection, &task, text);
    }

    /// Environment samples at the configured rate, for the properties the sensors measure.
    fn maybe_sample(&mut self, dt: f64) {
        self.sample_in_s -= dt;
        if self.sample_in_s > 1e-9 {
            return;
        }
        let period = 1.0 / self.settings.environment_hz;
        self.sample_in_s = (self.sample_in_s + period).max(period / 2.0);
        let ctd = self.has_sensor("ctd");
        let current = self.has_sensor("dvl") || self.has_sensor("adcp");
        let here = self.position();
        let obs = self.settings.ocean.water_at(here, self.depth).observations(
            &self.announcement.vehicle_id,
            self.clock_ms(),
            here,
            self.depth,
        );
        for o in obs {
            let measured = match o.property.as_str() {
                TEMPERATURE | SALINITY => ctd,
                CURRENT_SPEED | CURRENT_DIRECTION => current,
                _ => false,
            };
            if measured {
                self.outputs.push_back(VehicleOutput::Observation(o));
            }
        }
    }
}

#[cfg(test)]
mod tests;
