//! `shoal bench semantic hour`: a simulated hour of fleet traffic through the store's
//! normal write path, with query latency and memory sampled along the way.

use std::collections::HashMap;
use std::time::{Duration, Instant};

use anyhow::Result;
use shoal_model::{Availability, Event, StateVector, TaskState, TaskStatus};
use shoal_semantic::synthetic::{
    Lcg, PROPERTIES, T0_MS, is_under_way, populate_fleet, synthetic_observation, synthetic_state,
};
use shoal_semantic::{QueryLimits, STANDARD_QUERIES, SemanticStore, StoreConfig, StoreError};

use super::{
    MemoryFigures, QueryFigures, figures, measure_queries, memory, ms, print_memory, print_queries,
};

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
    // Tasks under way per vehicle: availability follows them, as the station's register
    // would decide it.
    let mut under_way: HashMap<String, u32> = HashMap::new();
    for (task_id, vehicle_id) in &tasks {
        if store.task_state(task_id).is_some_and(is_under_way) {
            *under_way.entry(vehicle_id.clone()).or_default() += 1;
        }
    }
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
            let was = store.task_state(task_id).is_some_and(is_under_way);
            fired.extend(store.task_status(&TaskStatus {
                task_id: task_id.clone(),
                vehicle_id: vehicle_id.clone(),
                timestamp_ms: t,
                state,
                progress_pct: (rng.next_f64() * 100.0).round(),
                message: String::new(),
            })?);
            let now = store.task_state(task_id).is_some_and(is_under_way);
            if was != now {
                let n = under_way.entry(vehicle_id.clone()).or_default();
                *n = if now { *n + 1 } else { n.saturating_sub(1) };
                let a = if *n > 0 {
                    Availability::Busy
                } else {
                    Availability::Idle
                };
                store.set_availability(vehicle_id, a)?;
            }
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

/// Runs [`run_hour`] with `options` and prints its series.
pub(super) fn hour(options: HourOptions) -> Result<()> {
    println!("{options:?}");
    let r = run_hour(options, StoreConfig::default())?;
    print_queries("fresh", &r.fresh);
    print_memory("fresh", &r.fresh_memory);
    let names: Vec<&str> = r.fresh.iter().map(|q| q.name).collect();
    println!(
        "\n{:>6} {:>9} {:>7} {:>8} {:>9} {:>8}  p50 ms: {}",
        "sim_s",
        "mirrors",
        "quads",
        "terms",
        "rss_KiB",
        "write_s",
        names
            .iter()
            .map(|n| n.split('_').next().unwrap_or(n))
            .collect::<Vec<_>>()
            .join("    ")
    );
    for s in &r.series {
        println!(
            "{:>6} {:>9} {:>7} {:>8} {:>9} {:>8.1}  {}",
            s.sim_s,
            s.state_mirrors,
            s.memory.quads,
            s.memory.terms,
            s.memory.rss_kib.map_or("?".into(), |r| r.to_string()),
            s.write_time.as_secs_f64(),
            s.queries
                .iter()
                .map(|q| format!("{:>5.2}", ms(q.p50)))
                .collect::<Vec<_>>()
                .join(" ")
        );
    }
    println!(
        "\nback to back at each sample ({} runs each), p50 ms:",
        r.options.samples
    );
    for s in &r.series {
        println!(
            "{:>6}  {}",
            s.sim_s,
            s.back_to_back
                .iter()
                .map(|q| format!("{:>6.2}", ms(q.p50)))
                .collect::<Vec<_>>()
                .join(" ")
        );
    }
    if let Some(last) = r.series.last() {
        print_queries("\nduring the last interval, between writes", &last.queries);
        print_queries("at the end, back to back", &last.back_to_back);
    }
    println!("events raised and added: {}", r.events_raised);
    if let Some(last) = r.series.last() {
        print_memory("at the end", &last.memory);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

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
