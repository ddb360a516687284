//! `shoal bench pipeline`: the station's Data Access Manager in one process (validation,
//! plausibility, latest state, semantic model with 10 rules, history commit) against a raw
//! batched SQLite insert of the same rows in the same run.

use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use shoal_history::{History, HistoryConfig, RawOrder};
use shoal_model::{LinkKind, StateVector, VehicleAnnouncement, VehicleKind, now_ms};
use shoal_station::{Station, StationConfig};
use tokio_util::sync::CancellationToken;

use super::helpers::{date, dds, machine, tempfile_dir};
use crate::config::ShoalConfig;

/// State vectors of a pipeline run, `bench pipeline`'s and the suite's: enough that the
/// pipeline's fill (the writer waits for its first batch while the ingesting thread makes
/// it) is a small part of the run, as it is of a station's hours.
pub(super) const DEFAULT_ROWS: usize = 500_000;

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

/// One pass of the rows through a station.
struct StationRun {
    enabled: usize,
    accepted: u64,
    rejected: usize,
    firings: u64,
    committed: u64,
    /// Until the last `ingest_state` returned.
    ingest: Duration,
    /// Until the last row was committed to the history.
    total: Duration,
    /// Time the history's writer thread spent writing during the pass.
    write_busy: Duration,
}

/// Feeds `data` through a fresh station whose history is `history`, from the calling
/// runtime's blocking pool, and waits until every row is committed.
async fn station_pass(
    cfg: &ShoalConfig,
    domain: u16,
    vehicles: usize,
    data: Vec<StateVector>,
    history: &HistoryConfig,
    dir: &std::path::Path,
) -> Result<StationRun> {
    let history = History::open(history)?;
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
    let busy_before = h.history_stats().write_busy;
    eprintln!("pipeline: {enabled} rules enabled; ingesting...");
    let handle = h.clone();
    let (ingest, total, rejected) =
        tokio::task::spawn_blocking(move || -> Result<(Duration, Duration, usize)> {
            let t = Instant::now();
            let mut rejected = 0;
            for s in data {
                if handle.ingest_state(s).is_err() {
                    rejected += 1;
                }
            }
            let ingest = t.elapsed();
            handle.flush_history(Duration::from_secs(300))?;
            Ok((ingest, t.elapsed(), rejected))
        })
        .await??;
    let stats = h.stats();
    let committed = h.history_committed() - base;
    let write_busy = h.history_stats().write_busy.saturating_sub(busy_before);
    // The handle holds the station's DDS writers: drop it while the participant lives.
    drop(h);
    stop.cancel();
    task.await??;
    Ok(StationRun {
        enabled,
        accepted: stats.states_accepted,
        rejected,
        firings: stats.rule_firings,
        committed,
        ingest,
        total,
        write_busy,
    })
}

/// What `bench pipeline` measures.
pub(super) struct PipelineFigures {
    pub(super) enabled: usize,
    pub(super) accepted: u64,
    pub(super) rejected: usize,
    pub(super) firings: u64,
    pub(super) committed: u64,
    /// From the first row offered to the last committed, history included.
    pub(super) elapsed: Duration,
    /// Of `elapsed`, until the last row was handed to the history's queue.
    pub(super) ingest: Duration,
    /// The history writer's busy time during `elapsed`.
    pub(super) write_busy: Duration,
    /// The same rows with the history excluded: queued for it, but its writer does not
    /// write until the pass is over, so the in-memory stages run alone.
    pub(super) excluded: Duration,
    /// The raw baseline, each transaction's rows in arrival order.
    pub(super) raw: Duration,
    /// The raw baseline, each transaction's rows in key order as the writer puts them.
    pub(super) raw_key: Duration,
    pub(super) rate: f64,
    pub(super) excluded_rate: f64,
    /// The faster raw baseline's rate: what the pipeline is judged against.
    pub(super) raw_rate: f64,
}

/// Runs the rows through a station with its history (as deployed), then with the history
/// excluded, then the raw SQLite baseline with the history's own settings, in arrival
/// order and in key order.
pub(super) async fn pipeline_figures(
    cfg: &ShoalConfig,
    domain: u16,
    vehicles: usize,
    rows: usize,
) -> Result<PipelineFigures> {
    let dir = tempfile_dir()?;
    eprintln!("pipeline: generating {rows} state vectors for {vehicles} vehicles...");
    let included = HistoryConfig {
        path: dir.join("pipeline.db"),
        ..cfg.history.clone()
    };
    let run = station_pass(
        cfg,
        domain,
        vehicles,
        pipeline_rows(vehicles, rows),
        &included,
        &dir,
    )
    .await?;
    eprintln!("pipeline: again with the history excluded (rows queued, written afterwards)...");
    // Room for every row in one batch, and no flush before it is full or an hour has
    // passed: the writer sleeps until the pass asks for the flush.
    let room = rows + vehicles + 1024;
    let excluded_history = HistoryConfig {
        path: dir.join("excluded.db"),
        batch_max: room,
        queue_capacity: room,
        flush_interval_ms: 3_600_000,
        ..cfg.history.clone()
    };
    let _ = std::fs::remove_file(dir.join("rules.json"));
    let excluded = station_pass(
        cfg,
        domain,
        vehicles,
        pipeline_rows(vehicles, rows),
        &excluded_history,
        &dir,
    )
    .await?;
    eprintln!("pipeline: raw batched SQLite insert of the same rows, in arrival order...");
    let raw_rows = pipeline_rows(vehicles, rows);
    let raw_config = HistoryConfig {
        path: dir.join("raw.db"),
        ..cfg.history.clone()
    };
    let raw = shoal_history::raw_insert_baseline(&raw_config, &raw_rows, RawOrder::Arrival)?;
    eprintln!("pipeline: again, each transaction's rows in key order...");
    let raw_key = shoal_history::raw_insert_baseline(&raw_config, &raw_rows, RawOrder::Key)?;
    #[allow(clippy::cast_precision_loss)]
    let per_s = |d: Duration| rows as f64 / d.as_secs_f64();
    let _ = std::fs::remove_dir_all(&dir);
    Ok(PipelineFigures {
        enabled: run.enabled,
        accepted: run.accepted,
        rejected: run.rejected,
        firings: run.firings,
        committed: run.committed,
        elapsed: run.total,
        ingest: run.ingest,
        write_busy: run.write_busy,
        excluded: excluded.ingest,
        raw,
        raw_key,
        rate: per_s(run.total),
        excluded_rate: per_s(excluded.ingest),
        raw_rate: per_s(raw.min(raw_key)),
    })
}

pub(super) async fn pipeline(
    cfg: &ShoalConfig,
    domain: u16,
    vehicles: usize,
    rows: usize,
) -> Result<()> {
    let f = pipeline_figures(cfg, domain, vehicles, rows).await?;
    println!("# shoal bench pipeline — {} — {}", machine(), date());
    println!(
        "{vehicles} vehicles, {rows} state vectors, {} rules enabled, history batch {}, synchronous {:?}",
        f.enabled, cfg.history.batch_max, cfg.history.synchronous
    );
    println!(
        "accepted {}, rejected {}, rule firings {}, history committed {}",
        f.accepted, f.rejected, f.firings, f.committed
    );
    println!("{:<62} {:>12} {:>12}", "", "state vec/s", "time");
    let line = |what: &str, rate: f64, d: Duration| {
        println!("{what:<62} {rate:>12.0} {:>10.3} s", d.as_secs_f64());
    };
    line(
        "Shoal, history included: validate+plausibility+latest+",
        f.rate,
        f.elapsed,
    );
    println!("  semantic+rules+history, until the last row is committed");
    line(
        "Shoal, history excluded (rows queued, written afterwards)",
        f.excluded_rate,
        f.excluded,
    );
    #[allow(clippy::cast_precision_loss)]
    let per_s = |d: Duration| rows as f64 / d.as_secs_f64();
    line(
        "raw batched SQLite insert (same rows, schema, pragmas)",
        per_s(f.raw),
        f.raw,
    );
    line(
        "  the same, each transaction's rows in key order",
        per_s(f.raw_key),
        f.raw_key,
    );
    println!("where the time goes, per state vector:");
    for (what, d) in [
        ("in-memory stages alone (history excluded)", f.excluded),
        (
            "ingesting thread to the last row queued (waits for queue room)",
            f.ingest,
        ),
        (
            "the history writer's busy time, history included",
            f.write_busy,
        ),
        ("raw SQLite insert, arrival order", f.raw),
        ("raw SQLite insert, key order", f.raw_key),
    ] {
        #[allow(clippy::cast_precision_loss)]
        let us = d.as_secs_f64() * 1e6 / rows.max(1) as f64;
        println!("  {what:<58} {us:>7.2} µs");
    }
    // The two threads run at once, so the pipeline goes at the pace of the slower one.
    let bound = if f.write_busy > f.excluded {
        "the history writer (SQLite)"
    } else {
        "the in-memory stages"
    };
    println!("the slower of the two threads, which sets the pace: {bound}");
    println!(
        "ratio Shoal / the faster raw insert: {:.2} (goal >= 0.90); goal >= 100000/s: {}",
        f.rate / f.raw_rate,
        if f.rate >= 100_000.0 {
            "met"
        } else {
            "NOT met"
        }
    );
    Ok(())
}
