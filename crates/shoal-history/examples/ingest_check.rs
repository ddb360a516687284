//! Quick ingest check: state vectors through the store's writer versus plain batched SQLite
//! inserts into the same schema, on a temporary file.
//!
//! `cargo run --release -p shoal-history --example ingest_check -- [rows] [vehicles]`

use std::time::{Duration, Instant};

use shoal_history::{History, HistoryConfig, RawOrder, raw_insert_baseline};
use shoal_model::StateVector;

fn rows(n: usize, vehicles: usize) -> Vec<StateVector> {
    (0..n)
        .map(|i| StateVector {
            vehicle_id: format!("auv-{}", i % vehicles),
            timestamp_ms: 1_700_000_000_000 + (i / vehicles) as i64 * 100,
            latitude_deg: 43.0 + (i % 1000) as f64 * 1e-5,
            longitude_deg: 5.9,
            depth_m: 12.5,
            altitude_m: -1.0,
            speed_mps: 1.5,
            yaw_deg: 90.0,
            pitch_deg: 0.0,
            roll_deg: 0.0,
            battery_pct: 80.0,
        })
        .collect()
}

fn rate(n: usize, d: Duration) -> f64 {
    n as f64 / d.as_secs_f64()
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let n: usize = args
        .next()
        .map(|a| a.parse())
        .transpose()?
        .unwrap_or(200_000);
    let vehicles: usize = args
        .next()
        .map(|a| a.parse())
        .transpose()?
        .unwrap_or(20)
        .max(1);
    let data = rows(n, vehicles);
    let dir = tempfile::tempdir()?;

    // Same batch size and durability as the store below.
    let raw = raw_insert_baseline(
        &HistoryConfig {
            path: dir.path().join("raw.db"),
            ..HistoryConfig::default()
        },
        &data,
        RawOrder::Key,
    )?;

    let config = HistoryConfig {
        path: dir.path().join("shoal.db"),
        ..HistoryConfig::default()
    };
    let history = History::open(&config)?;
    let writer = history.writer();
    let start = Instant::now();
    for row in data {
        writer.submit_blocking(row)?;
    }
    let submitted = start.elapsed();
    history.flush(Duration::from_secs(600))?;
    let committed = start.elapsed();
    let stats = history.close()?;

    println!(
        "rows: {n}, vehicles: {vehicles}, batch_max: {}",
        config.batch_max
    );
    println!(
        "raw SQLite (1 thread, batches of 2000): {:>10.0} rows/s",
        rate(n, raw)
    );
    println!(
        "shoal writer, submitted:                {:>10.0} rows/s",
        rate(n, submitted)
    );
    println!(
        "shoal writer, committed (acknowledged): {:>10.0} rows/s",
        rate(n, committed)
    );
    println!(
        "time shoal/raw: {:.2} (1.00 = as fast as raw SQLite); batches: {}, failed rows: {}",
        committed.as_secs_f64() / raw.as_secs_f64(),
        stats.batches,
        stats.failed_rows
    );
    Ok(())
}
