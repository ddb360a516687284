//! Recording 10,000 state vectors into a zstd MCAP file: CPU time per state vector (the
//! CDR encoding the recorder does, the MCAP writer, compression, the file) and, printed
//! after the run, bytes per state vector on disk.
//!
//! `CARGO_TARGET_DIR=... cargo bench -p shoal-recorder --bench record`

#![allow(clippy::panic)]

use std::hint::black_box;
use std::path::Path;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use shoal_model::StateVector;
use shoal_recorder::{RecordWriter, RecorderConfig, Sample, Topic};

const COUNT: u32 = 10_000;
const VEHICLES: u32 = 20;

/// 10,000 state vectors of 20 vehicles at 25 Hz each, each on its own circle with full
/// precision positions and attitude (as a navigation filter reports them), so that the
/// compression is measured on realistic entropy, not on repeated values.
fn states() -> Vec<(u64, StateVector)> {
    let t0_ms: i64 = 1_780_000_000_000;
    (0..COUNT)
        .map(|n| {
            let v = n % VEHICLES;
            let k = f64::from(n / VEHICLES);
            let t_ms = t0_ms + i64::from(n / VEHICLES) * 40;
            let phase = k * 0.002 + f64::from(v);
            let s = StateVector {
                vehicle_id: format!("auv-{v:02}"),
                timestamp_ms: t_ms,
                latitude_deg: 63.44 + 0.001 * phase.sin() + f64::from(v) * 0.01,
                longitude_deg: 10.39 + 0.002 * phase.cos(),
                depth_m: 20.0 + 5.0 * (phase * 0.3).sin(),
                altitude_m: 12.0 + 3.0 * (phase * 0.7).cos(),
                speed_mps: 1.5 + 0.1 * (phase * 3.0).sin(),
                yaw_deg: (phase.to_degrees() + 90.0).rem_euclid(360.0),
                pitch_deg: 2.0 * (phase * 5.0).sin(),
                roll_deg: 1.0 * (phase * 4.0).cos(),
                battery_pct: 90.0 - k * 0.0005,
            };
            // Received a few ms after it was sent, with the jitter of a network.
            let log_ns = u64::try_from(t_ms).unwrap_or(0) * 1_000_000
                + 3_000_000
                + u64::from(n.wrapping_mul(2_654_435_761) % 1_000_000);
            (log_ns, s)
        })
        .collect()
}

fn record(dir: &Path, states: &[(u64, StateVector)]) -> u64 {
    let config = RecorderConfig {
        directory: dir.to_path_buf(),
        ..RecorderConfig::default()
    };
    let mut w = RecordWriter::new(&config).unwrap_or_else(|e| panic!("{e}"));
    for (log_ns, s) in states {
        let publish_ns = u64::try_from(s.timestamp_ms).unwrap_or(0) * 1_000_000;
        let data = shoal_dds::to_cdr_le(s).unwrap_or_else(|e| panic!("{e}"));
        w.write(Topic::StateVector, *log_ns, publish_ns, &data)
            .unwrap_or_else(|e| panic!("{e}"));
    }
    w.close().unwrap_or_else(|e| panic!("{e}"));
    w.stats().bytes
}

fn bench(c: &mut Criterion) {
    let states = states();
    let mut group = c.benchmark_group("recorder");
    group.throughput(Throughput::Elements(u64::from(COUNT)));
    group.sample_size(20);
    group.bench_function("record_10k_state_vectors_zstd", |b| {
        b.iter(|| {
            let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
            black_box(record(dir.path(), &states))
        });
    });
    group.finish();

    let dir = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let bytes = record(dir.path(), &states);
    let raw: usize = states
        .iter()
        .map(|(_, s)| {
            Sample::StateVector(s.clone())
                .encode()
                .map_or(0, |d| d.len())
        })
        .sum();
    println!(
        "recorder: {COUNT} state vectors -> {bytes} bytes on disk ({:.1} bytes per state vector; CDR payloads {:.1} bytes each)",
        bytes as f64 / f64::from(COUNT),
        raw as f64 / f64::from(COUNT)
    );
}

criterion_group!(benches, bench);
criterion_main!(benches);
