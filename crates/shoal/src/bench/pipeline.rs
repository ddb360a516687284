//! `shoal bench pipeline`: the station's Data Access Manager in one process (validation,
//! plausibility, latest state, semantic model with 10 rules, history commit) against a raw
//! batched SQLite insert of the same rows in the same run.

use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use shoal_history::{History, HistoryConfig};
use shoal_model::{LinkKind, StateVector, VehicleAnnouncement, VehicleKind, now_ms};
use shoal_station::{Station, StationConfig};
use tokio_util::sync::CancellationToken;

use super::helpers::{date, dds, machine, tempfile_dir};
use crate::config::ShoalConfig;

/// The rows of the pipeline benchmark: `vehicles` AUVs at 10 Hz over the last minutes,
/// moving and draining plausibly, so that every row is accepted.
fn pipeline_rows(vehicles: usize, rows: usize) -> Vec<StateVector> {
    let per_vehicle = rows.div_ceil(vehicles.max(1));
    let start = now_ms() - i64::try_from(per_vehicle).unwrap_or(0) * 100 - 60_000;
    let mut out = Vec::with_capacity(rows);
    for k in 0..per_vehicle {
        for v in 0..vehicles {
            if out.len() == rows {
                return out;
            }
            #[allow(clippy::cast_precision_loss)]
            let (kf, vf) = (k as f64, v as f64);
            out.push(StateVector {
                vehicle_id: format!("auv-{v:05}"),
                timestamp_ms: start + i64::try_from(k).unwrap_or(0) * 100,
                latitude_deg: 43.0 + vf * 1e-3,
                // 1.5 m/s eastwards: 0.15 m per step.
                longitude_deg: 5.0 + kf * 1.85e-6,
                depth_m: 20.0 + (kf * 0.01).sin() * 5.0,
                altitude_m: 12.0,
                speed_mps: 1.5,
                yaw_deg: 90.0,
                pitch_deg: 1.0,
                roll_deg: -1.0,
                battery_pct: 90.0 - kf * 0.001,
            });
        }
    }
    out
}

/// Eight user rules beside the built-in ones the station runs by default (low battery,
/// task overdue): thresholds on the native fast path,
/// an area, and a SPARQL rule on the coalesced RDF mirror.
fn pipeline_rules() -> Vec<shoal_station::RuleDoc> {
    use shoal_station::{ConditionDoc, RuleDoc};
    let threshold = |id: &str, expr: &str| RuleDoc {
        id: id.into(),
        description: format!("bench: {expr}"),
        severity: shoal_model::Severity::Warning,
        kind: shoal_model::EventKind::Rule,
        condition: ConditionDoc::Threshold { expr: expr.into() },
        enabled: true,
        built_in: false,
    };
    let corner = |lat: f64, lon: f64| shoal_model::GeoPoint {
        latitude_deg: lat,
        longitude_deg: lon,
    };
    vec![
        threshold("too-deep", "depth_m > 300"),
        threshold("too-fast", "speed_mps > 5"),
        threshold("steep-pitch", "pitch_deg > 45"),
        threshold("rolled", "roll_deg < -45"),
        threshold("near-bottom", "altitude_m < 2"),
        threshold("battery-low-15", "battery_pct < 15"),
        RuleDoc {
            condition: ConditionDoc::OutsideArea {
                polygon: vec![
                    corner(42.0, 4.0),
                    corner(45.0, 4.0),
                    corner(45.0, 7.0),
                    corner(42.0, 7.0),
                ],
            },
            ..threshold("geofence", "")
        },
        RuleDoc {
            condition: ConditionDoc::Sparql {
                query: "ASK { ?this shoal:batteryLevel ?b . FILTER(?b < 5) }".into(),
                watches: vec!["shoal:batteryLevel".into()],
            },
            ..threshold("battery-critical", "")
        },
    ]
}

/// What `bench pipeline` measures.
pub(super) struct PipelineFigures {
    pub(super) enabled: usize,
    pub(super) accepted: u64,
    pub(super) rejected: usize,
    pub(super) firings: u64,
    pub(super) committed: u64,
    pub(super) elapsed: Duration,
    pub(super) raw: Duration,
    pub(super) rate: f64,
    pub(super) raw_rate: f64,
}

pub(super) async fn pipeline_figures(
    cfg: &ShoalConfig,
    domain: u16,
    vehicles: usize,
    rows: usize,
) -> Result<PipelineFigures> {
    let dir = tempfile_dir()?;
    eprintln!("pipeline: generating {rows} state vectors for {vehicles} vehicles...");
    let data = pipeline_rows(vehicles, rows);
    let history = History::open(&HistoryConfig {
        path: dir.join("pipeline.db"),
        ..cfg.history.clone()
    })?;
    let station = Station::new(
        StationConfig {
            summary_interval_s: 0.0,
            rules_path: dir.join("rules.json"),
            ..cfg.station.clone()
        },
        dds(cfg, domain)?,
        history,
    )?;
    let h = station.handle();
    for rule in pipeline_rules() {
        h.create_rule(&rule).context("bench rule")?;
    }
    let enabled = h.rules().iter().filter(|r| r.enabled).count();
    let stop = CancellationToken::new();
    let task = tokio::spawn(station.run(stop.clone()));
    for v in 0..vehicles {
        h.register_vehicle(VehicleAnnouncement {
            vehicle_id: format!("auv-{v:05}"),
            name: format!("bench {v}"),
            kind: VehicleKind::Auv,
            vendor: "shoal-bench".into(),
            capabilities: vec!["survey".into()],
            sensors: vec!["ctd".into()],
            links: vec![LinkKind::Ip],
            max_speed_mps: 2.0,
            timestamp_ms: now_ms(),
        })?;
    }
    h.flush_history(Duration::from_secs(30))?;
    let base = h.history_committed();
    eprintln!("pipeline: {enabled} rules enabled; ingesting...");
    let handle = h.clone();
    let (elapsed, rejected) = tokio::task::spawn_blocking(move || -> Result<(Duration, usize)> {
        let t = Instant::now();
        let mut rejected = 0;
        for s in data {
            if handle.ingest_state(s).is_err() {
                rejected += 1;
            }
        }
        handle.flush_history(Duration::from_secs(120))?;
        Ok((t.elapsed(), rejected))
    })
    .await??;
    let stats = h.stats();
    let committed = h.history_committed() - base;
    // The handle holds the station's DDS writers: drop it while the participant lives.
    drop(h);
    stop.cancel();
    task.await??;
    eprintln!("pipeline: raw batched SQLite insert of the same rows...");
    let raw_rows = pipeline_rows(vehicles, rows);
    let raw =
        shoal_history::raw_insert_baseline(&dir.join("raw.db"), &raw_rows, cfg.history.batch_max)?;
    #[allow(clippy::cast_precision_loss)]
    let (rate, raw_rate) = (
        rows as f64 / elapsed.as_secs_f64(),
        rows as f64 / raw.as_secs_f64(),
    );
    let _ = std::fs::remove_dir_all(&dir);
    Ok(PipelineFigures {
        enabled,
        accepted: stats.states_accepted,
        rejected,
        firings: stats.rule_firings,
        committed,
        elapsed,
        raw,
        rate,
        raw_rate,
    })
}

pub(super) async fn pipeline(
    cfg: &ShoalConfig,
    domain: u16,
    vehicles: usize,
    rows: usize,
) -> Result<()> {
    let PipelineFigures {
        enabled,
        accepted,
        rejected,
        firings,
        committed,
        elapsed,
        raw,
        rate,
        raw_rate,
    } = pipeline_figures(cfg, domain, vehicles, rows).await?;
    println!("# shoal bench pipeline — {} — {}", machine(), date());
    println!(
        "{vehicles} vehicles, {rows} state vectors, {enabled} rules enabled, history batch {}",
        cfg.history.batch_max
    );
    println!(
        "accepted {accepted}, rejected {rejected}, rule firings {firings}, history committed {committed}"
    );
    println!("{:<58} {:>12} {:>12}", "", "state vec/s", "time");
    println!(
        "{:<58} {:>12.0} {:>10.3} s",
        "Shoal: validate+plausibility+latest+semantic+rules+history",
        rate,
        elapsed.as_secs_f64()
    );
    println!(
        "{:<58} {:>12.0} {:>10.3} s",
        "raw batched SQLite insert (same rows, schema, pragmas)",
        raw_rate,
        raw.as_secs_f64()
    );
    println!(
        "ratio Shoal / raw: {:.2} (goal >= 0.80); goal >= 100000/s: {}",
        rate / raw_rate,
        if rate >= 100_000.0 { "met" } else { "NOT met" }
    );
    Ok(())
}
