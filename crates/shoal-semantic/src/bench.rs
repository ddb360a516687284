//! Benchmark of the standard queries at fleet scale, and the synthetic fleet it uses.
//!
//! [`run`] measures a fleet fresh and after a burst of state mirrors, and what a write
//! pays when a query snapshot is alive; [`run_hour`] drives a simulated hour of fleet
//! traffic through the normal write path and samples query latency and memory along the
//! way.
//! Both return figures and print nothing; `examples/semantic_bench.rs` prints them.
//! [`populate_fleet`] is deterministic so the cross-check and the benchmark see the same
//! kind of data.

use std::time::{Duration, Instant};

use shoal_model::{
    EnvironmentObservation, Event, EventKind, GeoPoint, LinkKind, Severity, StateVector, Task,
    TaskAssignment, TaskState, TaskStatus, VehicleAnnouncement, VehicleKind,
};

use crate::{QueryLimits, STANDARD_QUERIES, SemanticStore, StoreConfig, StoreError};

/// First timestamp of the synthetic fleet: 2023-11-14T22:13:20Z.
pub const T0_MS: i64 = 1_700_000_000_000;

/// A small deterministic generator (xorshift64*), so data needs no `rand` dependency.
#[derive(Debug, Clone)]
pub struct Lcg(u64);

impl Lcg {
    /// A generator from a seed.
    pub fn new(seed: u64) -> Self {
        Self(seed.max(1))
    }

    /// Uniform in [0, 1).
    pub fn next_f64(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let x = self.0.wrapping_mul(0x2545_F491_4F6C_DD1D);
        (x >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Uniform in `0..n`.
    pub fn below(&mut self, n: usize) -> usize {
        ((self.next_f64() * n as f64) as usize).min(n.saturating_sub(1))
    }
}

const KINDS: [VehicleKind; 5] = [
    VehicleKind::Auv,
    VehicleKind::Usv,
    VehicleKind::Asv,
    VehicleKind::Rov,
    VehicleKind::Glider,
];
const SENSORS: [&str; 8] = [
    "ctd",
    "sidescan_sonar",
    "sas",
    "multibeam",
    "camera",
    "gps",
    "dvl",
    "unknown_probe",
];
const CAPS: [&str; 5] = ["goto", "hold", "survey", "sidescan_survey", "custom_skill"];
const PROPERTIES: [(&str, &str, f64); 2] = [
    ("sea_water_temperature", "Cel", 14.0),
    ("sea_water_salinity", "[ppth]", 38.0),
];
const EVENT_KINDS: [(EventKind, Severity, &str); 4] = [
    (EventKind::Detection, Severity::Info, "contact on sonar"),
    (EventKind::Fault, Severity::Warning, "thruster current high"),
    (EventKind::LowBattery, Severity::Warning, "battery low"),
    (EventKind::Task, Severity::Info, "waypoint reached"),
];
/// Events per vehicle in the fixture: 1000 vehicles fill the default `max_events`.
const EVENTS_PER_VEHICLE: usize = 10;
const STATES: [TaskState; 6] = [
    TaskState::Pending,
    TaskState::Sent,
    TaskState::Accepted,
    TaskState::Running,
    TaskState::Done,
    TaskState::Failed,
];

/// A state vector for vehicle `i` of the synthetic fleet at time `t_ms`.
pub fn synthetic_state(rng: &mut Lcg, vehicle_id: &str, t_ms: i64) -> StateVector {
    StateVector {
        vehicle_id: vehicle_id.to_owned(),
        timestamp_ms: t_ms,
        latitude_deg: 42.9 + rng.next_f64() * 0.4,
        longitude_deg: 5.7 + rng.next_f64() * 0.4,
        depth_m: rng.next_f64() * 100.0,
        altitude_m: if rng.next_f64() < 0.2 {
            shoal_model::UNKNOWN
        } else {
            rng.next_f64() * 50.0
        },
        speed_mps: rng.next_f64() * 3.0,
        yaw_deg: rng.next_f64() * 359.0,
        pitch_deg: rng.next_f64() * 10.0 - 5.0,
        roll_deg: rng.next_f64() * 10.0 - 5.0,
        // Rounded to 0.1 % so that the cross-check compares exact decimal values.
        battery_pct: (rng.next_f64() * 1000.0).round() / 10.0,
    }
}

/// An observation by `vehicle_id` of the `k`-th fixture property at `t_ms`.
fn synthetic_observation(
    rng: &mut Lcg,
    vehicle_id: &str,
    k: usize,
    t_ms: i64,
) -> EnvironmentObservation {
    let (property, unit, base) = PROPERTIES[k % PROPERTIES.len()];
    EnvironmentObservation {
        vehicle_id: vehicle_id.to_owned(),
        property: property.to_owned(),
        timestamp_ms: t_ms,
        value: base + rng.next_f64(),
        unit: unit.to_owned(),
        latitude_deg: 42.9 + rng.next_f64() * 0.4,
        longitude_deg: 5.7 + rng.next_f64() * 0.4,
        depth_m: rng.next_f64() * 100.0,
    }
}

/// Registers `vehicles` vehicles with one state each, about two tasks per vehicle in
/// assorted states, two environment observations and ten events per vehicle; flushes so
/// the RDF model is complete. Deterministic for a seed.
pub fn populate_fleet(
    store: &mut SemanticStore,
    vehicles: usize,
    seed: u64,
) -> Result<(), StoreError> {
    let mut rng = Lcg::new(seed);
    for i in 0..vehicles {
        let id = format!("v{i:04}");
        let kind = KINDS[i % KINDS.len()];
        let mut sensors: Vec<String> = vec!["gps".into()];
        for s in SENSORS {
            if rng.next_f64() < 0.25 && !sensors.iter().any(|x| x == s) {
                sensors.push(s.into());
            }
        }
        let caps: Vec<String> = CAPS
            .iter()
            .filter(|_| rng.next_f64() < 0.3)
            .map(|c| (*c).to_owned())
            .collect();
        let links = if kind.is_underwater() {
            vec![LinkKind::Acoustic, LinkKind::Ip]
        } else {
            vec![LinkKind::Ip, LinkKind::Radio]
        };
        store.upsert_vehicle(&VehicleAnnouncement {
            vehicle_id: id.clone(),
            name: format!("Vehicle {i}"),
            kind,
            vendor: "Shoal sim".into(),
            capabilities: caps,
            sensors,
            links,
            max_speed_mps: 3.0,
            timestamp_ms: T0_MS,
        })?;
        store.update_state(&synthetic_state(&mut rng, &id, T0_MS + 1000))?;
        for k in 0..(1 + rng.below(3)) {
            let task_id = format!("t{i:04}-{k}");
            let task = if rng.next_f64() < 0.5 {
                Task::GotoWaypoint {
                    target: GeoPoint {
                        latitude_deg: 43.0 + rng.next_f64() * 0.1,
                        longitude_deg: 5.9,
                    },
                    depth_m: Some(10.0),
                    altitude_m: None,
                    speed_mps: 1.5,
                }
            } else {
                Task::SurveyArea {
                    polygon: vec![
                        GeoPoint {
                            latitude_deg: 43.0,
                            longitude_deg: 5.9,
                        },
                        GeoPoint {
                            latitude_deg: 43.0,
                            longitude_deg: 5.95,
                        },
                        GeoPoint {
                            latitude_deg: 43.05,
                            longitude_deg: 5.95,
                        },
                    ],
                    line_spacing_m: 20.0,
                    depth_m: None,
                    altitude_m: Some(5.0),
                    speed_mps: 1.0,
                }
            };
            store.upsert_task(&TaskAssignment::new(
                &task_id,
                format!("m{}", i % 7),
                &id,
                T0_MS,
                &task,
            ))?;
            let state = STATES[rng.below(STATES.len())];
            if state != TaskState::Pending {
                store.task_status(&TaskStatus {
                    task_id,
                    vehicle_id: id.clone(),
                    timestamp_ms: T0_MS + 2000,
                    state,
                    progress_pct: 50.0,
                    message: String::new(),
                })?;
            }
        }
    }
    for i in 0..vehicles {
        let id = format!("v{i:04}");
        for k in 0..PROPERTIES.len() {
            store.add_observation(&synthetic_observation(&mut rng, &id, k, T0_MS + 3000))?;
        }
        for k in 0..EVENTS_PER_VEHICLE {
            let (kind, severity, text) = EVENT_KINDS[rng.below(EVENT_KINDS.len())];
            store.add_event(&Event {
                event_id: format!("e{i:04}-{k}"),
                timestamp_ms: T0_MS + 4000 + k as i64,
                severity,
                kind,
                vehicle_id: id.clone(),
                task_id: if kind == EventKind::Task {
                    format!("t{i:04}-0")
                } else {
                    String::new()
                },
                text: text.to_owned(),
            })?;
        }
    }
    store.flush_dirty(T0_MS + 10_000)?;
    Ok(())
}

/// What to measure.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BenchOptions {
    /// Fleet size.
    pub vehicles: usize,
    /// State updates per vehicle between the fresh and the "after updates" measurements,
    /// each one flushed to RDF (the worst case: one mirror per update).
    pub updates_per_vehicle: usize,
    /// Runs of each query per measurement.
    pub samples: usize,
}

impl Default for BenchOptions {
    /// 1000 vehicles, 60 flushed updates each (60 000 state mirrors), 50 samples.
    fn default() -> Self {
        Self {
            vehicles: 1000,
            updates_per_vehicle: 60,
            samples: 50,
        }
    }
}

/// Latency of one standard query.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct QueryFigures {
    /// Query name (file stem under `ontology/queries/`).
    pub name: &'static str,
    /// Rows returned.
    pub rows: usize,
    /// Fastest run: close to the latency on an idle machine.
    pub min: Duration,
    /// Median latency.
    pub p50: Duration,
    /// 95th percentile latency.
    pub p95: Duration,
}

/// The memory picture at one point of the benchmark.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MemoryFigures {
    /// Quads in the store.
    pub quads: usize,
    /// Distinct terms the quads use.
    pub terms: usize,
    /// Resident set size of the process in KiB (Linux only; None elsewhere).
    pub rss_kib: Option<u64>,
}

/// Everything [`run`] measured.
#[derive(Debug, Clone, PartialEq)]
pub struct BenchReport {
    /// The options used.
    pub options: BenchOptions,
    /// Time to build the fleet.
    pub populate: Duration,
    /// Standard queries on the fresh fleet.
    pub fresh: Vec<QueryFigures>,
    /// Memory on the fresh fleet.
    pub fresh_memory: MemoryFigures,
    /// `update_state` calls per second (typed path, rules included, no RDF).
    pub update_state_per_s: f64,
    /// State mirrors written to RDF per second by `flush_dirty`.
    pub flushes_per_s: f64,
    /// Standard queries after the updates.
    pub after_updates: Vec<QueryFigures>,
    /// Memory after the updates.
    pub after_updates_memory: MemoryFigures,
    /// Time a write takes to copy the model because a query snapshot is alive (once per
    /// snapshot: the station's queries take one each).
    pub snapshot_copy: Duration,
}

/// Resident set size of this process in KiB, from `/proc/self/statm` (Linux).
pub fn rss_kib() -> Option<u64> {
    let statm = std::fs::read_to_string("/proc/self/statm").ok()?;
    let pages: u64 = statm.split_whitespace().nth(1)?.parse().ok()?;
    Some(pages * 4)
}

fn memory(store: &SemanticStore) -> Result<MemoryFigures, StoreError> {
    let s = store.stats()?;
    Ok(MemoryFigures {
        quads: s.quads,
        terms: s.terms,
        rss_kib: rss_kib(),
    })
}

/// Runs each standard query `samples` times and returns p50/p95.
pub fn measure_queries(store: &SemanticStore, samples: usize) -> Vec<QueryFigures> {
    let limits = QueryLimits::default();
    STANDARD_QUERIES
        .iter()
        .map(|(name, q)| {
            let mut times = Vec::with_capacity(samples);
            let mut rows = 0;
            for _ in 0..samples.max(1) {
                let start = Instant::now();
                rows = store.query(q, &limits).map(|r| r.len()).unwrap_or(0);
                times.push(start.elapsed());
            }
            figures(name, rows, &mut times)
        })
        .collect()
}

/// p50 and p95 of `times` (reordered), which must not be empty.
fn figures(name: &'static str, rows: usize, times: &mut [Duration]) -> QueryFigures {
    times.sort_unstable();
    let pick = |f: f64| {
        times
            .get(((times.len().saturating_sub(1)) as f64 * f).round() as usize)
            .copied()
            .unwrap_or_default()
    };
    QueryFigures {
        name,
        rows,
        min: pick(0.0),
        p50: pick(0.5),
        p95: pick(0.95),
    }
}

/// Builds a fleet, measures the standard queries fresh and after many flushed state
/// updates, then the copy a write makes while a snapshot is alive.
pub fn run(options: BenchOptions) -> Result<BenchReport, StoreError> {
    let mut store = SemanticStore::new(StoreConfig::default())?;
    let start = Instant::now();
    populate_fleet(&mut store, options.vehicles, 7)?;
    let populate = start.elapsed();
    let fresh = measure_queries(&store, options.samples);
    let fresh_memory = memory(&store)?;

    let mut rng = Lcg::new(11);
    let ids: Vec<String> = (0..options.vehicles).map(|i| format!("v{i:04}")).collect();
    let (mut update_time, mut flush_time, mut flushes) = (Duration::ZERO, Duration::ZERO, 0u64);
    let mut updates = 0u64;
    for round in 0..options.updates_per_vehicle {
        let t = T0_MS + 20_000 + (round as i64) * 1000;
        let states: Vec<StateVector> = ids
            .iter()
            .map(|id| synthetic_state(&mut rng, id, t))
            .collect();
        let s0 = Instant::now();
        for s in &states {
            store.update_state(s)?;
            updates += 1;
        }
        update_time += s0.elapsed();
        let s1 = Instant::now();
        let before = store.stats()?.state_flushes;
        store.flush_dirty(t)?;
        flushes += store.stats()?.state_flushes - before;
        flush_time += s1.elapsed();
    }
    let after_updates = measure_queries(&store, options.samples);
    let after_updates_memory = memory(&store)?;
    let snapshot = store.snapshot();
    let t = T0_MS + 20_000 + (options.updates_per_vehicle as i64) * 1000;
    if let Some(id) = ids.first() {
        store.update_state(&synthetic_state(&mut rng, id, t))?;
    }
    let before = store.stats()?.snapshot_copy_time;
    store.flush_dirty(t)?;
    let snapshot_copy = store.stats()?.snapshot_copy_time - before;
    drop(snapshot);
    let per_s = |n: u64, d: Duration| {
        if d.is_zero() {
            0.0
        } else {
            n as f64 / d.as_secs_f64()
        }
    };
    Ok(BenchReport {
        options,
        populate,
        fresh,
        fresh_memory,
        update_state_per_s: per_s(updates, update_time),
        flushes_per_s: per_s(flushes, flush_time),
        after_updates,
        after_updates_memory,
        snapshot_copy,
    })
}

/// What [`run_hour`] simulates and how often it samples.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HourOptions {
    /// Fleet size.
    pub vehicles: usize,
    /// Simulated seconds; every vehicle reports one state per second.
    pub seconds: u64,
    /// Simulated seconds between two samples of the series.
    pub sample_every_s: u64,
    /// Standard queries run each simulated second, in turn, between the writes; the
    /// series reports their latency over each interval, with whatever the writes left
    /// in the caches.
    pub queries_per_s: usize,
    /// Runs of each query for the measurements before and after the traffic.
    pub samples: usize,
}

impl Default for HourOptions {
    /// 1000 vehicles for 3600 s (3.6 million state mirrors), a sample every 600 s, each
    /// standard query once a simulated second, 30 runs before and after.
    fn default() -> Self {
        Self {
            vehicles: 1000,
            seconds: 3600,
            sample_every_s: 600,
            queries_per_s: STANDARD_QUERIES.len(),
            samples: 30,
        }
    }
}

/// One point of the [`run_hour`] series.
#[derive(Debug, Clone, PartialEq)]
pub struct HourSample {
    /// Simulated seconds since the traffic started.
    pub sim_s: u64,
    /// State mirrors written to RDF so far.
    pub state_mirrors: u64,
    /// Memory at the sample.
    pub memory: MemoryFigures,
    /// The standard queries run during the interval that ends here, one at a time
    /// between the writes (the caches hold whatever the writes left in them).
    pub queries: Vec<QueryFigures>,
    /// The standard queries run `samples` times each at the sample, back to back, as
    /// [`measure_queries`] does before and after the traffic.
    pub back_to_back: Vec<QueryFigures>,
    /// Wall time spent writing (updates, mirrors, rules, events) since the previous sample.
    pub write_time: Duration,
}

/// Everything [`run_hour`] measured.
#[derive(Debug, Clone, PartialEq)]
pub struct HourReport {
    /// The options used.
    pub options: HourOptions,
    /// Standard queries on the fresh fleet, before any traffic.
    pub fresh: Vec<QueryFigures>,
    /// Memory on the fresh fleet.
    pub fresh_memory: MemoryFigures,
    /// The series, one sample every `sample_every_s` (the last one is the end of the run).
    pub series: Vec<HourSample>,
    /// Events the rules raised during the run, all added to the model as the station does.
    pub events_raised: u64,
}

/// A vehicle moving and draining its battery smoothly, so rules fire at a realistic rate.
#[derive(Debug, Clone, Copy)]
struct Motion {
    lat: f64,
    lon: f64,
    depth: f64,
    heading: f64,
    speed: f64,
    battery: f64,
    drain: f64,
}

impl Motion {
    fn from(s: &StateVector, rng: &mut Lcg) -> Self {
        Self {
            lat: s.latitude_deg,
            lon: s.longitude_deg,
            depth: s.depth_m,
            heading: s.yaw_deg,
            speed: s.speed_mps.max(0.5),
            battery: s.battery_pct,
            // 3 to 10 hours from full to empty.
            drain: 100.0 / (3600.0 * (3.0 + 7.0 * rng.next_f64())),
        }
    }

    fn step(&mut self, rng: &mut Lcg, vehicle_id: &str, t_ms: i64) -> StateVector {
        self.heading = (self.heading + (rng.next_f64() - 0.5) * 10.0).rem_euclid(360.0);
        let (s, c) = self.heading.to_radians().sin_cos();
        // Metres to degrees, near 43 N; bounce off the edges of the fixture's area.
        self.lat += c * self.speed / 111_000.0;
        self.lon += s * self.speed / 81_000.0;
        if !(42.9..=43.3).contains(&self.lat) || !(5.7..=6.1).contains(&self.lon) {
            self.heading = (self.heading + 180.0).rem_euclid(360.0);
            self.lat = self.lat.clamp(42.9, 43.3);
            self.lon = self.lon.clamp(5.7, 6.1);
        }
        self.depth = (self.depth + (rng.next_f64() - 0.5) * 0.5).clamp(0.0, 100.0);
        self.battery -= self.drain;
        if self.battery < 3.0 {
            // Recovered and swapped.
            self.battery = 100.0;
        }
        StateVector {
            vehicle_id: vehicle_id.to_owned(),
            timestamp_ms: t_ms,
            latitude_deg: self.lat,
            longitude_deg: self.lon,
            depth_m: self.depth,
            altitude_m: 10.0 + (rng.next_f64() - 0.5),
            speed_mps: self.speed,
            yaw_deg: self.heading.min(359.9),
            pitch_deg: (rng.next_f64() - 0.5) * 2.0,
            roll_deg: (rng.next_f64() - 0.5) * 2.0,
            battery_pct: (self.battery * 10.0).round() / 10.0,
        }
    }
}

/// Builds the fleet and drives `seconds` of traffic through the store's normal write
/// path: every vehicle reports a state each second (mirrored
/// at the configured rate), one observation every 10 s, a few task reports a second,
/// `tick` each second, and every event the rules raise is added to the model as the
/// station does. Samples memory and the standard queries every `sample_every_s`.
pub fn run_hour(options: HourOptions, config: StoreConfig) -> Result<HourReport, StoreError> {
    let mut store = SemanticStore::new(config)?;
    populate_fleet(&mut store, options.vehicles, 7)?;
    let fresh = measure_queries(&store, options.samples);
    let fresh_memory = memory(&store)?;

    let mut rng = Lcg::new(13);
    let ids: Vec<String> = (0..options.vehicles).map(|i| format!("v{i:04}")).collect();
    let mut motion: Vec<Motion> = Vec::with_capacity(ids.len());
    for id in &ids {
        let s = store
            .latest_state(id)
            .unwrap_or_else(|| synthetic_state(&mut rng, id, T0_MS));
        motion.push(Motion::from(&s, &mut rng));
    }
    let tasks: Vec<(String, String)> = (0..options.vehicles)
        .flat_map(|i| (0..3).map(move |k| (format!("t{i:04}-{k}"), format!("v{i:04}"))))
        .filter(|(t, _)| store.task_state(t).is_some())
        .collect();
    let start_ms = T0_MS + 20_000;
    let limits = QueryLimits::default();
    let mut latencies: Vec<Vec<Duration>> = vec![Vec::new(); STANDARD_QUERIES.len()];
    let mut rows = vec![0; STANDARD_QUERIES.len()];
    let mut next_query = 0;
    let mut series = Vec::new();
    let mut events_raised = 0u64;
    let mut write_time = Duration::ZERO;
    let mut fired: Vec<Event> = Vec::new();
    for sec in 1..=options.seconds {
        let t = start_ms + (sec as i64) * 1000;
        let w = Instant::now();
        for (i, id) in ids.iter().enumerate() {
            let s = motion[i].step(&mut rng, id, t - 1000 + (i as i64 % 1000));
            fired.extend(store.update_state(&s)?);
            if (sec as usize + i).is_multiple_of(10) {
                let k = (sec as usize / 10 + i) % PROPERTIES.len();
                fired.extend(store.add_observation(&synthetic_observation(&mut rng, id, k, t))?);
            }
        }
        for _ in 0..tasks.len().min(3) {
            let (task_id, vehicle_id) = &tasks[rng.below(tasks.len())];
            let state = match store.task_state(task_id) {
                Some(s) if s.is_final() => continue,
                Some(TaskState::Running) if rng.next_f64() < 0.1 => TaskState::Done,
                Some(TaskState::Pending | TaskState::Sent | TaskState::Accepted) => {
                    TaskState::Running
                }
                Some(s) => s,
                None => continue,
            };
            fired.extend(store.task_status(&TaskStatus {
                task_id: task_id.clone(),
                vehicle_id: vehicle_id.clone(),
                timestamp_ms: t,
                state,
                progress_pct: (rng.next_f64() * 100.0).round(),
                message: String::new(),
            })?);
        }
        fired.extend(store.flush_dirty(t)?);
        fired.extend(store.tick(t)?);
        // Rule firings enter the model, which may fire more rules: drain to a fixed point.
        while let Some(e) = fired.pop() {
            events_raised += 1;
            fired.extend(store.add_event(&e)?);
        }
        write_time += w.elapsed();
        for _ in 0..options.queries_per_s {
            let k = next_query % STANDARD_QUERIES.len();
            next_query += 1;
            let q = Instant::now();
            rows[k] = store
                .query(STANDARD_QUERIES[k].1, &limits)
                .map_or(0, |r| r.len());
            latencies[k].push(q.elapsed());
        }
        if sec % options.sample_every_s.max(1) == 0 || sec == options.seconds {
            let st = store.stats()?;
            let queries = STANDARD_QUERIES
                .iter()
                .zip(&mut latencies)
                .zip(&rows)
                .map(|(((name, _), times), rows)| {
                    let f = figures(name, *rows, times);
                    times.clear();
                    f
                })
                .collect();
            series.push(HourSample {
                sim_s: sec,
                state_mirrors: st.state_flushes,
                memory: memory(&store)?,
                queries,
                back_to_back: measure_queries(&store, options.samples),
                write_time: std::mem::take(&mut write_time),
            });
        }
    }
    Ok(HourReport {
        options,
        fresh,
        fresh_memory,
        series,
        events_raised,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_tiny_benchmark_runs_and_reports_every_query() {
        let r = run(BenchOptions {
            vehicles: 20,
            updates_per_vehicle: 3,
            samples: 3,
        })
        .unwrap();
        assert_eq!(r.fresh.len(), 5);
        assert_eq!(r.after_updates.len(), 5);
        // Updates replace values: the model keeps its size.
        assert_eq!(r.after_updates_memory.quads, r.fresh_memory.quads);
        assert!(r.snapshot_copy > Duration::ZERO);
    }

    #[test]
    fn a_short_simulated_run_keeps_the_model_bounded_and_samples_it() {
        let options = HourOptions {
            vehicles: 20,
            seconds: 40,
            sample_every_s: 20,
            queries_per_s: 1,
            samples: 2,
        };
        let r = run_hour(options, StoreConfig::default()).unwrap();
        assert_eq!(
            r.series.iter().map(|s| s.sim_s).collect::<Vec<_>>(),
            [20, 40]
        );
        let last = &r.series[1];
        // One mirror per vehicle per simulated second, after the fixture's own.
        assert_eq!(last.state_mirrors, 20 + 20 * 40);
        // Traffic replaces values; it adds no entities, so the model stays the same size
        // (a few more events at most).
        assert!(
            last.memory.quads <= r.fresh_memory.quads + 200,
            "{} vs {}",
            last.memory.quads,
            r.fresh_memory.quads
        );
        // Replaced values and timestamps are freed: the terms stay as few as the quads.
        assert!(
            last.memory.terms <= r.fresh_memory.terms + 200,
            "{} vs {}",
            last.memory.terms,
            r.fresh_memory.terms
        );
        assert_eq!(last.back_to_back.len(), 5);
    }
}
