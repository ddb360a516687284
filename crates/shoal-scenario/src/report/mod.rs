//! What a scenario run leaves behind: the figures of its [`Summary`] (written as JSON)
//! and a static HTML page with plots ([`render_html`]), both computed from a
//! [`RunRecord`] of what the station stored. No I/O here: the runner reads the history
//! store into a record and writes the files.

mod html;

use std::collections::BTreeMap;

use serde::Serialize;
use shoal_model::{
    EnvironmentObservation, Event, Severity, StateVector, TaskAssignment, TaskState, TaskStatus,
    geo,
};

pub use html::render_html;

/// Version of the summary's JSON layout; raised when a field changes meaning.
pub const SUMMARY_FORMAT: u32 = 1;

/// Everything a run's report is made from, in simulated time.
#[derive(Debug, Clone, Default)]
pub struct RunRecord {
    /// The scenario's name.
    pub scenario: String,
    /// What it shows.
    pub description: String,
    /// The seed the simulated vehicles drew from.
    pub seed: u64,
    /// Simulated seconds per real second.
    pub speed: f64,
    /// Simulated time at the start, ms since the Unix epoch.
    pub start_ms: i64,
    /// Simulated time at the end, ms since the Unix epoch.
    pub end_ms: i64,
    /// Real seconds the run took.
    pub wall_s: f64,
    /// The fleet: each vehicle's id, kind and stored state vectors, oldest first.
    pub vehicles: Vec<VehicleRecord>,
    /// Every task the station issued in the run, with its status reports.
    pub tasks: Vec<TaskRecord>,
    /// Events and alarms, oldest first.
    pub events: Vec<Event>,
    /// The station's own counters at the end (every station, across restarts).
    pub station: StationFigures,
    /// The faults injected, in the order they happened.
    pub faults: Vec<FaultRecord>,
    /// The ids of the station's rules (built-in and user), to tell their firings among
    /// the events.
    pub rule_ids: Vec<String>,
    /// The acoustic network's links (empty when the scenario has none).
    pub links: Vec<LinkFigures>,
    /// Per acoustic vehicle, how old each of its state vectors was when it reached the
    /// station's domain through the relay, simulated ms, in arrival order.
    pub acoustic_latency_ms: BTreeMap<String, Vec<i64>>,
    /// Per acoustic vehicle, the relay's link-status reports of it, oldest first.
    pub link_quality: BTreeMap<String, Vec<LinkSample>>,
    /// Simulated seconds each modem spent transmitting, by modem (a vehicle id or `relay`).
    pub airtime_s: BTreeMap<String, f64>,
    /// The environment observations the vehicles made, in any order.
    pub environment: Vec<EnvironmentObservation>,
}

/// What the fleet measured of one environment property.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EnvironmentFigures {
    /// Its unit (UCUM).
    pub unit: String,
    /// Observations made.
    pub observations: usize,
    /// The vehicles that made them, sorted.
    pub vehicles: Vec<String>,
    /// Lowest value (0.01).
    pub min: f64,
    /// Mean value (0.01).
    pub mean: f64,
    /// Highest value (0.01).
    pub max: f64,
    /// Where the lowest value was measured: latitude, longitude (1e-5 degrees), depth (0.1 m).
    pub min_at: [f64; 3],
    /// Where the highest value was measured.
    pub max_at: [f64; 3],
}

impl EnvironmentFigures {
    /// The figures of observations of one property; `None` for none.
    pub fn of(obs: &[&EnvironmentObservation]) -> Option<Self> {
        let first = obs.first()?;
        let place = |o: &EnvironmentObservation| {
            [
                round_dp(o.latitude_deg, 5),
                round_dp(o.longitude_deg, 5),
                round_dp(o.depth_m, 1),
            ]
        };
        let (mut lo, mut hi) = (*first, *first);
        let mut sum = 0.0;
        let mut vehicles: Vec<String> = Vec::new();
        for o in obs {
            if o.value < lo.value {
                lo = o;
            }
            if o.value > hi.value {
                hi = o;
            }
            sum += o.value;
            if !vehicles.contains(&o.vehicle_id) {
                vehicles.push(o.vehicle_id.clone());
            }
        }
        vehicles.sort();
        #[allow(clippy::cast_precision_loss)]
        let mean = sum / obs.len() as f64;
        Some(Self {
            unit: first.unit.clone(),
            observations: obs.len(),
            vehicles,
            min: round_dp(lo.value, 2),
            mean: round_dp(mean, 2),
            max: round_dp(hi.value, 2),
            min_at: place(lo),
            max_at: place(hi),
        })
    }
}

/// One link-status report: how well the relay heard a vehicle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct LinkSample {
    /// When, ms since the Unix epoch (simulated).
    pub at_ms: i64,
    /// Received signal strength, dB.
    pub rssi_db: Option<i32>,
    /// The modem's signal integrity figure (0..=255).
    pub integrity: Option<u32>,
}

/// How old an acoustic vehicle's state vectors were on arrival.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct LatencyFigures {
    /// State vectors measured.
    pub samples: usize,
    /// Median, simulated seconds (0.01 s).
    pub p50_s: f64,
    /// 95th percentile, simulated seconds.
    pub p95_s: f64,
    /// Largest, simulated seconds.
    pub max_s: f64,
}

impl LatencyFigures {
    /// The figures of `ms` (any order); `None` when empty.
    pub fn of(ms: &[i64]) -> Option<Self> {
        let mut v: Vec<i64> = ms.to_vec();
        v.sort_unstable();
        let last = *v.last()?;
        #[allow(clippy::cast_precision_loss)]
        let s = |x: i64| round_dp(x as f64 / 1000.0, 2);
        // Nearest rank: the smallest value with at least q of the samples at or below it.
        let rank = |q: f64| {
            #[allow(
                clippy::cast_precision_loss,
                clippy::cast_possible_truncation,
                clippy::cast_sign_loss
            )]
            let k = ((q * v.len() as f64).ceil() as usize).clamp(1, v.len());
            v[k - 1]
        };
        Some(Self {
            samples: v.len(),
            p50_s: s(rank(0.5)),
            p95_s: s(rank(0.95)),
            max_s: s(last),
        })
    }
}

/// What one directed acoustic link carried in a run, as the emulated sea counted it.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct LinkFigures {
    /// The sending modem: a vehicle id, or `relay`.
    pub from: String,
    /// The receiving modem.
    pub to: String,
    /// Frames addressed over it.
    pub frames: u64,
    /// Received intact.
    pub delivered: u64,
    /// Lost to the channel (range, noise).
    pub lost: u64,
    /// Lost to a collision with another arrival.
    pub collisions: u64,
    /// Lost because the receiver was transmitting.
    pub half_duplex: u64,
    /// Lost because a modem was failed or cut off (a fault).
    pub outage: u64,
}

impl LinkFigures {
    /// Delivered frames, % of those sent (0.1); `None` when none were sent.
    pub fn delivery_pct(&self) -> Option<f64> {
        #[allow(clippy::cast_precision_loss)]
        (self.frames > 0).then(|| round_dp(self.delivered as f64 * 100.0 / self.frames as f64, 1))
    }
}

/// A fault injected during a run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FaultRecord {
    /// Simulated seconds from the start (0.1 s).
    pub at_s: f64,
    /// What happened, for people.
    pub what: String,
}

/// One vehicle of a run.
#[derive(Debug, Clone)]
pub struct VehicleRecord {
    /// Vehicle id.
    pub id: String,
    /// Platform kind, as the scenario names it.
    pub kind: String,
    /// State vectors the station accepted, oldest first.
    pub track: Vec<StateVector>,
}

/// One task of a run.
#[derive(Debug, Clone)]
pub struct TaskRecord {
    /// The assignment the station sent.
    pub assignment: TaskAssignment,
    /// Its status reports, oldest first.
    pub statuses: Vec<TaskStatus>,
}

impl TaskRecord {
    /// The state its last report gave (`Pending` with none).
    pub fn last_state(&self) -> TaskState {
        self.statuses.last().map_or(TaskState::Pending, |s| s.state)
    }

    /// When it started running (or was accepted), ms.
    pub fn started_ms(&self) -> Option<i64> {
        let first = |wanted: TaskState| {
            self.statuses
                .iter()
                .find(|s| s.state == wanted)
                .map(|s| s.timestamp_ms)
        };
        first(TaskState::Running).or_else(|| first(TaskState::Accepted))
    }

    /// When it reached its final state, ms.
    pub fn ended_ms(&self) -> Option<i64> {
        self.statuses
            .iter()
            .find(|s| s.state.is_final())
            .map(|s| s.timestamp_ms)
    }
}

/// The station's counters a report shows.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct StationFigures {
    /// State vectors accepted.
    pub states_accepted: u64,
    /// Samples refused, every reason together.
    pub rejected: u64,
    /// Records the history store committed.
    pub history_committed: u64,
    /// Events rules raised as data arrived.
    pub rule_firings: u64,
}

/// The figures of a run, written as `summary.json`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Summary {
    /// [`SUMMARY_FORMAT`].
    pub format: u32,
    /// The scenario's name.
    pub scenario: String,
    /// The seed.
    pub seed: u64,
    /// Simulated seconds per real second.
    pub speed: f64,
    /// Simulated seconds covered.
    pub simulated_s: f64,
    /// Real seconds the run took.
    pub wall_s: f64,
    /// Per vehicle, by id.
    pub vehicles: BTreeMap<String, VehicleFigures>,
    /// Tasks by their last state (`done`, `failed`, ...), and `total`.
    pub tasks: BTreeMap<String, usize>,
    /// Each task's outcome, by [`task_key`].
    pub task_outcomes: BTreeMap<String, TaskOutcome>,
    /// Events by severity (`info`, `warning`, `alarm`, `critical`).
    pub events: BTreeMap<String, usize>,
    /// The rules that fired, by rule id.
    pub rule_firings: BTreeMap<String, RuleFiring>,
    /// The station's counters.
    pub station: StationFigures,
    /// The faults injected.
    pub faults: Vec<FaultRecord>,
    /// The acoustic network's links, keyed `from>to`, each with its `delivery_pct`.
    pub acoustic_links: BTreeMap<String, AcousticLink>,
    /// Per acoustic vehicle, how old its state vectors were on reaching the station.
    pub acoustic_latency: BTreeMap<String, LatencyFigures>,
    /// Simulated seconds each modem spent transmitting (0.1 s).
    pub acoustic_airtime_s: BTreeMap<String, f64>,
    /// The share of the run the one acoustic channel carried a transmission, % (0.1;
    /// overlapping transmissions count twice); `None` without an acoustic network.
    pub acoustic_channel_use_pct: Option<f64>,
    /// What the fleet measured of the environment, by property (CF standard name).
    pub environment: BTreeMap<String, EnvironmentFigures>,
}

/// One acoustic link in the summary.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AcousticLink {
    /// Its counters.
    #[serde(flatten)]
    pub figures: LinkFigures,
    /// Delivered, % of frames sent.
    pub delivery_pct: Option<f64>,
}

/// What one vehicle did.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct VehicleFigures {
    /// Platform kind.
    pub kind: String,
    /// State vectors stored.
    pub states: usize,
    /// Distance along its reported track, m (rounded to 1 m).
    pub distance_m: f64,
    /// Deepest reported depth, m (rounded to 0.1 m).
    pub max_depth_m: f64,
    /// Battery at the first and last stored state and the lowest, % (rounded to 0.1).
    pub battery_start_pct: f64,
    /// Battery at the last stored state, %.
    pub battery_end_pct: f64,
    /// Lowest battery, %.
    pub battery_min_pct: f64,
    /// Simulated seconds from the start to the first state with speed over 0.2 m/s.
    pub first_motion_s: Option<f64>,
}

/// How often one rule fired, and about what.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RuleFiring {
    /// Events it raised.
    pub count: usize,
    /// Simulated seconds from the start to its first firing (0.1 s).
    pub first_s: f64,
    /// The vehicles its events named, sorted.
    pub vehicles: Vec<String>,
}

/// The rule that raised an event, when its id is a rule firing's
/// (`<rule id>-<timestamp>-<sequence>`, the rule among `rule_ids`).
pub fn rule_of<'a>(event_id: &str, rule_ids: &'a [String]) -> Option<&'a str> {
    let mut parts = event_id.rsplitn(3, '-');
    let (seq, ts, rule) = (parts.next()?, parts.next()?, parts.next()?);
    let digits = |s: &str| !s.is_empty() && s.bytes().all(|b| b.is_ascii_digit());
    if !(digits(seq) && digits(ts)) {
        return None;
    }
    rule_ids.iter().find(|r| *r == rule).map(String::as_str)
}

/// How one task ended.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TaskOutcome {
    /// The task's id in this run.
    pub task_id: String,
    /// The vehicle.
    pub vehicle: String,
    /// Its mission.
    pub mission: String,
    /// Task kind.
    pub kind: String,
    /// Last state reported.
    pub state: String,
    /// Simulated seconds from its start to its end, when both were reported (0.1 s).
    pub duration_s: Option<f64>,
}

/// `v` rounded to `decimals` places (multiplying, not dividing by a step, keeps the
/// result the nearest double to the decimal: 20.4, not 20.400000000000002).
fn round_dp(v: f64, decimals: i32) -> f64 {
    let f = 10f64.powi(decimals);
    (v * f).round() / f
}

/// A task's key in the summary: its scenario mission's id (without the station's run
/// suffix) and its place in the mission, e.g. `survey-box/1`, so two runs compare.
pub fn task_key(a: &TaskAssignment) -> String {
    let base = a
        .mission_id
        .rsplit_once('-')
        .filter(|(_, run)| !run.is_empty() && run.bytes().all(|b| b.is_ascii_digit()))
        .map_or(a.mission_id.as_str(), |(m, _)| m);
    let place = a
        .task_id
        .strip_prefix(a.mission_id.as_str())
        .and_then(|r| r.strip_prefix('-'))
        .unwrap_or(a.task_id.as_str());
    format!("{base}/{place}")
}

/// A task state's name as operators read it.
pub fn state_name(s: TaskState) -> &'static str {
    match s {
        TaskState::Pending => "pending",
        TaskState::Sent => "sent",
        TaskState::Accepted => "accepted",
        TaskState::Running => "running",
        TaskState::Done => "done",
        TaskState::Failed => "failed",
        TaskState::Aborted => "aborted",
        TaskState::Expired => "expired",
    }
}

fn severity_name(s: Severity) -> &'static str {
    match s {
        Severity::Info => "info",
        Severity::Warning => "warning",
        Severity::Alarm => "alarm",
        Severity::Critical => "critical",
    }
}

/// Distance along a track, m.
fn track_length(track: &[StateVector]) -> f64 {
    track
        .windows(2)
        .map(|w| {
            geo::distance_m(
                w[0].latitude_deg,
                w[0].longitude_deg,
                w[1].latitude_deg,
                w[1].longitude_deg,
            )
        })
        .sum()
}

/// The figures of a run.
pub fn summarise(r: &RunRecord) -> Summary {
    #[allow(clippy::cast_precision_loss)]
    let seconds = |ms: i64| (ms - r.start_ms) as f64 / 1000.0;
    let vehicles = r
        .vehicles
        .iter()
        .map(|v| {
            let battery = v.track.iter().map(|s| s.battery_pct);
            let figures = VehicleFigures {
                kind: v.kind.clone(),
                states: v.track.len(),
                distance_m: round_dp(track_length(&v.track), 0),
                max_depth_m: round_dp(v.track.iter().map(|s| s.depth_m).fold(0.0, f64::max), 1),
                battery_start_pct: round_dp(v.track.first().map_or(0.0, |s| s.battery_pct), 1),
                battery_end_pct: round_dp(v.track.last().map_or(0.0, |s| s.battery_pct), 1),
                battery_min_pct: round_dp(
                    if v.track.is_empty() {
                        0.0
                    } else {
                        battery.fold(f64::INFINITY, f64::min)
                    },
                    1,
                ),
                first_motion_s: v
                    .track
                    .iter()
                    .find(|s| s.speed_mps > 0.2)
                    .map(|s| round_dp(seconds(s.timestamp_ms), 1)),
            };
            (v.id.clone(), figures)
        })
        .collect();
    let mut tasks: BTreeMap<String, usize> = BTreeMap::new();
    let mut task_outcomes = BTreeMap::new();
    for t in &r.tasks {
        let state = state_name(t.last_state());
        *tasks.entry(state.to_owned()).or_default() += 1;
        #[allow(clippy::cast_precision_loss)]
        let duration_s = match (t.started_ms(), t.ended_ms()) {
            (Some(a), Some(b)) if b >= a => Some(round_dp((b - a) as f64 / 1000.0, 1)),
            _ => None,
        };
        task_outcomes.insert(
            task_key(&t.assignment),
            TaskOutcome {
                task_id: t.assignment.task_id.clone(),
                vehicle: t.assignment.vehicle_id.clone(),
                mission: t.assignment.mission_id.clone(),
                kind: t.assignment.kind.capability().to_owned(),
                state: state.to_owned(),
                duration_s,
            },
        );
    }
    tasks.insert("total".to_owned(), r.tasks.len());
    let mut events: BTreeMap<String, usize> = BTreeMap::new();
    for e in &r.events {
        *events
            .entry(severity_name(e.severity).to_owned())
            .or_default() += 1;
    }
    let mut rule_firings: BTreeMap<String, RuleFiring> = BTreeMap::new();
    for e in &r.events {
        let Some(rule) = rule_of(&e.event_id, &r.rule_ids) else {
            continue;
        };
        let f = rule_firings
            .entry(rule.to_owned())
            .or_insert_with(|| RuleFiring {
                count: 0,
                first_s: round_dp(seconds(e.timestamp_ms), 1),
                vehicles: Vec::new(),
            });
        f.count += 1;
        if !e.vehicle_id.is_empty() && !f.vehicles.contains(&e.vehicle_id) {
            f.vehicles.push(e.vehicle_id.clone());
            f.vehicles.sort();
        }
    }
    Summary {
        format: SUMMARY_FORMAT,
        scenario: r.scenario.clone(),
        seed: r.seed,
        speed: r.speed,
        simulated_s: round_dp(seconds(r.end_ms), 1),
        wall_s: round_dp(r.wall_s, 1),
        vehicles,
        tasks,
        task_outcomes,
        events,
        rule_firings,
        station: r.station,
        faults: r.faults.clone(),
        acoustic_links: r
            .links
            .iter()
            .map(|l| {
                (
                    format!("{}>{}", l.from, l.to),
                    AcousticLink {
                        figures: l.clone(),
                        delivery_pct: l.delivery_pct(),
                    },
                )
            })
            .collect(),
        acoustic_latency: r
            .acoustic_latency_ms
            .iter()
            .filter_map(|(v, ms)| Some((v.clone(), LatencyFigures::of(ms)?)))
            .collect(),
        acoustic_airtime_s: r
            .airtime_s
            .iter()
            .map(|(m, s)| (m.clone(), round_dp(*s, 1)))
            .collect(),
        acoustic_channel_use_pct: channel_use_pct(r),
        environment: environment_figures(r),
    }
}

/// Per property, what the fleet measured.
fn environment_figures(r: &RunRecord) -> BTreeMap<String, EnvironmentFigures> {
    let mut by: BTreeMap<&str, Vec<&EnvironmentObservation>> = BTreeMap::new();
    for o in &r.environment {
        by.entry(o.property.as_str()).or_default().push(o);
    }
    by.into_iter()
        .filter_map(|(p, obs)| Some((p.to_owned(), EnvironmentFigures::of(&obs)?)))
        .collect()
}

/// The share of the run the acoustic channel was busy, %.
fn channel_use_pct(r: &RunRecord) -> Option<f64> {
    if r.airtime_s.is_empty() {
        return None;
    }
    #[allow(clippy::cast_precision_loss)]
    let span_s = (r.end_ms - r.start_ms) as f64 / 1000.0;
    let air: f64 = r.airtime_s.values().sum();
    (span_s > 0.0).then(|| round_dp(air / span_s * 100.0, 1))
}

#[cfg(test)]
mod tests;
