//! Benchmark of the standard queries at fleet scale, and the synthetic fleet it uses.
//!
//! [`run`] returns figures and prints nothing; `examples/semantic_bench.rs` prints them.
//! [`populate_fleet`] is deterministic so the cross-check and the benchmark see the same
//! kind of data.

use std::time::{Duration, Instant};

use shoal_model::{
    GeoPoint, LinkKind, StateVector, Task, TaskAssignment, TaskState, TaskStatus,
    VehicleAnnouncement, VehicleKind,
};

use crate::{
    CompactionReport, QueryLimits, STANDARD_QUERIES, SemanticStore, StoreConfig, StoreError,
};

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

/// Registers `vehicles` vehicles with one state each, and about two tasks per vehicle in
/// assorted states; flushes so the RDF model is complete. Deterministic for a seed.
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
    /// Median latency.
    pub p50: Duration,
    /// 95th percentile latency.
    pub p95: Duration,
}

/// The memory picture at one point of the benchmark.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MemoryFigures {
    /// Live quads in the store.
    pub quads: usize,
    /// Removed quads the store still holds.
    pub garbage_quads: u64,
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
    /// Standard queries after the updates, compaction disabled.
    pub after_updates: Vec<QueryFigures>,
    /// Memory after the updates, before compaction.
    pub after_updates_memory: MemoryFigures,
    /// The compaction.
    pub compaction: CompactionReport,
    /// Standard queries after compaction.
    pub after_compaction: Vec<QueryFigures>,
    /// Memory after compaction.
    pub after_compaction_memory: MemoryFigures,
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
        garbage_quads: s.garbage_quads,
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
            times.sort();
            let pick = |f: f64| times[((times.len() - 1) as f64 * f).round() as usize];
            QueryFigures {
                name,
                rows,
                p50: pick(0.5),
                p95: pick(0.95),
            }
        })
        .collect()
}

/// Builds a fleet, measures the standard queries fresh, after many flushed state updates
/// without compaction, and after compaction.
pub fn run(options: BenchOptions) -> Result<BenchReport, StoreError> {
    let config = StoreConfig {
        compact_after_removed_quads: u64::MAX,
        ..StoreConfig::default()
    };
    let mut store = SemanticStore::new(config)?;
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
    let compaction = store.compact()?;
    let after_compaction = measure_queries(&store, options.samples);
    let after_compaction_memory = memory(&store)?;
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
        compaction,
        after_compaction,
        after_compaction_memory,
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
        assert_eq!(r.after_compaction.len(), 5);
        assert_eq!(r.after_compaction_memory.garbage_quads, 0);
        assert!(r.after_updates_memory.garbage_quads > 0);
        // Compaction keeps every live quad.
        assert_eq!(
            r.after_compaction_memory.quads,
            r.after_updates_memory.quads
        );
        for (a, b) in r.after_updates.iter().zip(&r.after_compaction) {
            assert_eq!(a.rows, b.rows, "{}", a.name);
        }
    }
}
