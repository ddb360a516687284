//! `shoal bench semantic`: the semantic store's five standard SPARQL queries at fleet
//! scale, in this process (no DDS), on the synthetic fleet of [`shoal_semantic::synthetic`].
//!
//! - `burst` ([`run`]): a fleet fresh and after a burst of state mirrors, and what a write
//!   pays when a query snapshot is alive.
//! - `hour` ([`hour::run_hour`]): a simulated hour of fleet traffic through the normal write
//!   path, sampling query latency and memory along the way.
//!
//! `shoal bench suite` takes its SPARQL figures from both.

use std::time::{Duration, Instant};

use anyhow::Result;
use clap::Subcommand;
use shoal_model::StateVector;
use shoal_semantic::synthetic::{Lcg, T0_MS, populate_fleet, synthetic_state};
use shoal_semantic::{QueryLimits, STANDARD_QUERIES, SemanticStore, StoreConfig, StoreError};

pub(super) mod hour;

use hour::HourOptions;

/// Which semantic measurement to run.
#[derive(Debug, Clone, Copy, Subcommand)]
pub enum SemanticCommand {
    /// A fresh fleet, the same after a burst of state mirrors, and the copy a write makes
    /// while a query snapshot is alive.
    Burst {
        /// Fleet size.
        #[arg(long, default_value_t = BenchOptions::default().vehicles)]
        vehicles: usize,
        /// State updates per vehicle between the two measurements, each mirrored to RDF.
        #[arg(long, default_value_t = BenchOptions::default().updates_per_vehicle)]
        updates_per_vehicle: usize,
        /// Runs of each query per measurement.
        #[arg(long, default_value_t = BenchOptions::default().samples)]
        samples: usize,
    },
    /// A simulated hour of traffic through the normal write path, the standard queries
    /// running in turn between the writes; prints their p50 and the memory every
    /// `--sample-every-s` simulated seconds.
    Hour {
        /// Fleet size.
        #[arg(long, default_value_t = HourOptions::default().vehicles)]
        vehicles: usize,
        /// Simulated seconds; every vehicle reports one state per second.
        #[arg(long, default_value_t = HourOptions::default().seconds)]
        seconds: u64,
        /// Simulated seconds between two samples of the series.
        #[arg(long, default_value_t = HourOptions::default().sample_every_s)]
        sample_every_s: u64,
    },
}

/// Runs one semantic measurement and prints it (CPU-bound: call it off the async runtime).
pub(super) fn semantic(which: SemanticCommand) -> Result<()> {
    match which {
        SemanticCommand::Burst {
            vehicles,
            updates_per_vehicle,
            samples,
        } => burst(BenchOptions {
            vehicles,
            updates_per_vehicle,
            samples,
        }),
        SemanticCommand::Hour {
            vehicles,
            seconds,
            sample_every_s,
        } => hour::hour(HourOptions {
            vehicles,
            seconds,
            sample_every_s,
            ..HourOptions::default()
        }),
    }
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

pub(super) fn memory(store: &SemanticStore) -> Result<MemoryFigures, StoreError> {
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
pub(super) fn figures(name: &'static str, rows: usize, times: &mut [Duration]) -> QueryFigures {
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

/// `d` in milliseconds.
pub(super) fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1e3
}

/// Prints `title`, then one line per query: rows, min, p50 and p95.
pub(super) fn print_queries(title: &str, figures: &[QueryFigures]) {
    println!("{title}");
    for f in figures {
        println!(
            "  {:<30} rows {:>5}  min {:>8.3} ms  p50 {:>8.3} ms  p95 {:>8.3} ms",
            f.name,
            f.rows,
            f.min.as_secs_f64() * 1e3,
            ms(f.p50),
            ms(f.p95)
        );
    }
}

/// Prints one line of `m` under `title`.
pub(super) fn print_memory(title: &str, m: &MemoryFigures) {
    println!(
        "{title}: quads {} terms {} rss {} KiB",
        m.quads,
        m.terms,
        m.rss_kib.map_or("?".into(), |r| r.to_string())
    );
}

/// Runs [`run`] with `options` and prints its figures.
fn burst(options: BenchOptions) -> Result<()> {
    let r = run(options)?;
    println!("{options:?}; populate {:?}", r.populate);
    print_queries("fresh", &r.fresh);
    print_memory("fresh", &r.fresh_memory);
    println!(
        "update_state {:.0}/s, state mirrors {:.0}/s",
        r.update_state_per_s, r.flushes_per_s
    );
    print_queries("after updates", &r.after_updates);
    print_memory("after updates", &r.after_updates_memory);
    println!(
        "a write while a query snapshot is alive copies the model once: {:.1} ms",
        ms(r.snapshot_copy)
    );
    Ok(())
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
}
