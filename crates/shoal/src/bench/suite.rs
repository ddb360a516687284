//! `shoal bench suite`: every figure that has a target, in one run and one table, each
//! beside its target and, where there is one, the peer measured in the same run on the
//! same host (Cyclone DDS ddsperf, a raw batched SQLite insert); saved as Markdown. A
//! published figure that is not measured here (DCCL's State Vector size) is part of its
//! row's target, never in the peer column.

use std::time::Instant;

use anyhow::{Context, Result};

use super::bus::{BusFigures, bus_figures, peer_counts, shoal_counts};
use super::helpers::{date, grouped, machine, percentile};
use super::latency::{LatencyFigures, latency_figures};
use super::pipeline::pipeline_figures;
use super::scale::{ScaleFigures, scale_figures};
use super::{acoustic, semantic};
use crate::config::ShoalConfig;

/// One line of the suite's table.
struct SuiteRow {
    figure: String,
    shoal: String,
    /// A figure measured in this run, or `-`: never a published one.
    peer: String,
    ratio: String,
    target: String,
    met: Option<bool>,
}

/// Which way a figure is better, so that a rounded figure is never shown better than it is
/// (a ratio of 2.004 against "≤ 2×" reads 2.01×, not a passing 2.00×).
#[derive(Debug, Clone, Copy)]
enum Better {
    Lower,
    Higher,
}

/// `value` with `decimals` decimals, rounded towards worse; `-` when not a number.
fn shown(value: f64, decimals: i32, better: Better) -> String {
    if !value.is_finite() {
        return "-".into();
    }
    let scale = 10f64.powi(decimals);
    // Float noise first (99.9 × 100 is 9989.999…), so an exact figure is shown as itself.
    let scaled = (value * scale * 1e6).round() / 1e6;
    let v = match better {
        Better::Lower => scaled.ceil() / scale,
        Better::Higher => scaled.floor() / scale,
    };
    let places = usize::try_from(decimals).unwrap_or(0);
    format!("{v:.places$}")
}

/// A rate per second with thousands grouped, rounded down (rates are better higher).
fn rate_text(per_s: f64) -> String {
    if per_s.is_finite() && per_s >= 0.0 {
        #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
        let whole = per_s.floor() as u64;
        format!("{}/s", grouped(whole))
    } else {
        "-".into()
    }
}

/// µs or ms with no decimals, `-` when not measured.
fn whole(value: Option<f64>, unit: &str) -> String {
    value
        .filter(|v| v.is_finite())
        .map_or_else(|| "-".into(), |v| format!("{v:.0} {unit}"))
}

impl SuiteRow {
    fn new(figure: &str, shoal: String, target: &str, met: Option<bool>) -> Self {
        Self {
            figure: figure.to_string(),
            shoal,
            peer: "-".into(),
            ratio: "-".into(),
            target: target.to_string(),
            met,
        }
    }

    /// The peer measured in this run, and Shoal's figure over the peer's.
    fn with_peer(mut self, peer: String, ratio: f64, better: Better) -> Self {
        self.peer = peer;
        self.ratio = match shown(ratio, 2, better).as_str() {
            "-" => "-".into(),
            r => format!("{r}×"),
        };
        self
    }

    /// [`Self::with_peer`] when the peer could be measured.
    fn with_peer_if(self, peer: Option<(String, f64)>, better: Better) -> Self {
        match peer {
            Some((p, ratio)) => self.with_peer(p, ratio, better),
            None => self,
        }
    }
}

fn suite_table(rows: &[SuiteRow]) -> String {
    let mut t = String::from(
        "| figure | Shoal | peer, same run | ratio | target | met |\n| --- | --- | --- | --- | --- | --- |\n",
    );
    for r in rows {
        let met = match r.met {
            Some(true) => "yes",
            Some(false) => "**no**",
            None => "-",
        };
        t.push_str(&format!(
            "| {} | {} | {} | {} | {} | {met} |\n",
            r.figure, r.shoal, r.peer, r.ratio, r.target
        ));
    }
    t
}

/// Shoal's bus round trip p50 may be at most this many times ddsperf's.
const BUS_P50_MAX_RATIO: f64 = 1.3;
/// The station's ingest may be no slower than this share of a raw batched SQLite insert.
const INGEST_MIN_VS_RAW: f64 = 0.9;
/// State vectors a second the station's ingest must reach, whatever the raw insert does.
const INGEST_MIN_PER_S: f64 = 100_000.0;
/// Vehicle → console latency p99 target, ms.
const LATENCY_P99_MAX_MS: f64 = 5.0;
/// "Station ingest = offered": the share of the offered rate, %, that counts as all of it.
const SCALE_INGEST_MIN_PCT: f64 = 99.9;

/// The bus round trip p50 target: at most twice ddsperf's, both reduced per second as
/// ddsperf does, and no round trip lost. A loss, or no round trip at all, fails it on its
/// own; otherwise it is unjudged (`None`) when ddsperf could not be measured.
fn bus_p50_met(shoal_us: Option<f64>, peer_us: Option<f64>, lost: usize) -> Option<bool> {
    let Some(shoal) = shoal_us.filter(|v| v.is_finite() && lost == 0) else {
        return Some(false);
    };
    peer_us.map(|p| shoal <= BUS_P50_MAX_RATIO * p)
}

/// Ingest against the raw batched SQLite insert of the same rows in the same run.
fn ingest_vs_raw_met(rate: f64, raw_rate: f64) -> bool {
    raw_rate > 0.0 && rate >= INGEST_MIN_VS_RAW * raw_rate
}

/// Ingest against its absolute target.
fn ingest_absolute_met(rate: f64) -> bool {
    rate >= INGEST_MIN_PER_S
}

/// The latency p99 target holds only if no update was dropped: a dropped update is one
/// whose latency was never measured, so a p99 over the others would flatter the feed.
fn latency_p99_met(p99_ms: f64, dropped: u64) -> bool {
    dropped == 0 && p99_ms <= LATENCY_P99_MAX_MS
}

/// "Station ingest = offered": at least 99.9 % of the offered rate.
fn scale_ingest_met(pct_of_offered: f64) -> bool {
    pct_of_offered >= SCALE_INGEST_MIN_PCT
}

/// The bus rows. Round trip p50 and p99 are Shoal's computed as ddsperf computes its own
/// (per one-second window, then the median over the windows: `bus::per_second`), so the
/// ratio compares like with like, as does the delivery: both answer in listeners, and the
/// row answered in tasks has ddsperf's waitset mode beside it. The whole-run figures
/// follow as information only.
fn bus_rows(bus: &BusFigures) -> Vec<SuiteRow> {
    let ps = bus.rt.per_second;
    let (p50, p99) = (ps.map(|p| p.p50_us), ps.map(|p| p.p99_us));
    let peer = bus.peer.as_ref();
    let ratio = |ours: Option<f64>, theirs: f64| ours.map_or(f64::NAN, |o| o / theirs);
    vec![
        SuiteRow::new(
            "bus round trip p50 (median of per-second p50s, as ddsperf computes it)",
            format!("{} ({})", whole(p50, "µs"), shoal_counts(&bus.rt)),
            "≤ 1.3× Cyclone, none lost",
            bus_p50_met(p50, peer.map(|p| p.rt.p50_us), bus.rt.lost),
        )
        .with_peer_if(
            peer.map(|p| {
                (
                    format!(
                        "Cyclone {} ({})",
                        whole(Some(p.rt.p50_us), "µs"),
                        peer_counts(&p.rt)
                    ),
                    ratio(p50, p.rt.p50_us),
                )
            }),
            Better::Lower,
        ),
        SuiteRow::new(
            "bus round trip p99 (median of per-second p99s, as ddsperf computes it)",
            whole(p99, "µs"),
            "-",
            None,
        )
        .with_peer_if(
            peer.map(|p| {
                (
                    format!("Cyclone {}", whole(Some(p.rt.p99_us), "µs")),
                    ratio(p99, p.rt.p99_us),
                )
            }),
            Better::Lower,
        ),
        SuiteRow::new(
            "bus round trip p50 (per second, as above), ddsperf with Shoal's Cyclone configuration",
            whole(p50, "µs"),
            "-",
            None,
        )
        .with_peer_if(
            bus.peer_shoal_transport.map(|p| {
                (
                    format!(
                        "Cyclone {} ({})",
                        whole(Some(p.p50_us), "µs"),
                        peer_counts(&p)
                    ),
                    ratio(p50, p.p50_us),
                )
            }),
            Better::Lower,
        ),
        SuiteRow::new(
            "bus round trip p50 (per second, as above), answered in tasks (the station's way), ddsperf in waitset mode",
            format!(
                "{} ({})",
                whole(bus.rt_stream.per_second.map(|p| p.p50_us), "µs"),
                shoal_counts(&bus.rt_stream)
            ),
            "-",
            None,
        )
        .with_peer_if(
            bus.peer_waitset.map(|p| {
                (
                    format!(
                        "Cyclone {} ({})",
                        whole(Some(p.p50_us), "µs"),
                        peer_counts(&p)
                    ),
                    ratio(bus.rt_stream.per_second.map(|p| p.p50_us), p.p50_us),
                )
            }),
            Better::Lower,
        ),
        SuiteRow::new(
            "bus round trip over the whole run (every round trip; information, ddsperf prints no such figure)",
            format!(
                "p50 {}, p99 {}",
                whole(Some(bus.rt.p50_us), "µs"),
                whole(Some(bus.rt.p99_us), "µs")
            ),
            "-",
            None,
        ),
        SuiteRow::new(
            "bus throughput, reliable, no loss",
            format!(
                "≥ {} k/s",
                shown(bus.throughput / 1000.0, 0, Better::Higher)
            ),
            "-",
            None,
        )
        .with_peer_if(
            peer.map(|p| {
                (
                    format!(
                        "Cyclone {} k/s",
                        shown(p.throughput / 1000.0, 0, Better::Higher)
                    ),
                    bus.throughput / p.throughput,
                )
            }),
            Better::Higher,
        ),
    ]
}

/// The ingest rows: against the raw insert of the same run, and against the absolute
/// target, each with its own verdict.
fn ingest_rows(rate: f64, raw_rate: f64) -> Vec<SuiteRow> {
    vec![
        SuiteRow::new(
            "ingest vs raw SQLite, same run (validate + plausibility + latest + semantic + 10 rules + history)",
            rate_text(rate),
            "≥ 0.9× raw",
            Some(ingest_vs_raw_met(rate, raw_rate)),
        )
        .with_peer(
            format!(
                "raw SQLite {} (the faster of arrival and key order)",
                rate_text(raw_rate)
            ),
            rate / raw_rate,
            Better::Higher,
        ),
        SuiteRow::new(
            "ingest absolute (the same pipeline)",
            rate_text(rate),
            "≥ 100,000/s",
            Some(ingest_absolute_met(rate)),
        ),
    ]
}

/// The latency rows; the p99 row counts the live updates the feed had for the client,
/// those it received and those the feed dropped because it fell behind.
fn latency_rows(lat: &LatencyFigures) -> Vec<SuiteRow> {
    let p99 = percentile(&lat.samples, 99.0);
    vec![
        SuiteRow::new(
            "vehicle → console latency p50 (1000 × 1 Hz)",
            whole(Some(percentile(&lat.samples, 50.0)), "ms"),
            "-",
            None,
        ),
        SuiteRow::new(
            "vehicle → console latency p99 (1000 × 1 Hz; live updates sent to the client, received, dropped for falling behind)",
            format!(
                "{} ({} sent, {} received, {} dropped)",
                whole(Some(p99), "ms"),
                grouped(lat.sent()),
                grouped(lat.received),
                grouped(lat.dropped)
            ),
            "≤ 5 ms, no update dropped",
            Some(latency_p99_met(p99, lat.dropped)),
        ),
    ]
}

/// The State Vector PDU row: DCCL's size is published, not measured here, so it is the
/// target and the peer column stays empty.
fn pdu_row(bytes: usize, dccl_published: usize) -> SuiteRow {
    SuiteRow::new(
        "State Vector PDU (keyframe)",
        format!("{bytes} B"),
        &format!(
            "≤ {dccl_published} B (DCCL's published size at the same precision, not measured here)"
        ),
        Some(bytes <= dccl_published),
    )
}

/// The scale rows: the station's peak memory, and its ingest against what was offered.
fn scale_rows(sc: &ScaleFigures, vehicles: usize) -> Vec<SuiteRow> {
    let pct = sc.ingest_pct();
    vec![
        SuiteRow::new(
            &format!("station RSS, {vehicles} vehicles × 1 Hz (peak)"),
            format!("{:.0} MB", sc.peak_rss_mb),
            "≤ 2048 MB, all alive",
            Some(sc.peak_rss_mb <= 2048.0 && sc.all_alive_after_s.is_some()),
        ),
        SuiteRow::new(
            &format!("station ingest, {vehicles} vehicles × 1 Hz offered"),
            format!(
                "{} ({} % of {} offered)",
                rate_text(sc.mean_rate),
                shown(pct, 2, Better::Higher),
                rate_text(sc.offered_rate)
            ),
            "= offered (≥ 99.9 %)",
            Some(scale_ingest_met(pct)),
        ),
    ]
}

pub(super) async fn suite(
    cfg: &ShoalConfig,
    seconds: u64,
    scale_vehicles: usize,
    out: &std::path::Path,
    domain: u16,
    semantic_hour_s: u64,
) -> Result<()> {
    let started = Instant::now();
    // Figures on a shared machine mean little without its load: note it before and after.
    let load = || {
        std::fs::read_to_string("/proc/loadavg")
            .ok()
            .and_then(|l| l.split_whitespace().next().map(str::to_string))
            .unwrap_or_else(|| "?".into())
    };
    let load_before = load();
    let mut rows = Vec::new();

    eprintln!("suite 1/6: bus (Shoal vs Cyclone DDS ddsperf)");
    let bus = bus_figures(cfg, domain, seconds, false).await?;
    rows.extend(bus_rows(&bus));

    eprintln!("suite 2/6: ingest pipeline (Shoal vs raw batched SQLite insert)");
    let pf = pipeline_figures(cfg, domain + 4, 1000, super::pipeline::DEFAULT_ROWS).await?;
    rows.extend(ingest_rows(pf.rate, pf.raw_rate));

    eprintln!("suite 3/6: end-to-end latency, 1000 vehicles x 1 Hz");
    let lat = latency_figures(cfg, 1000, 1.0, seconds.max(10), domain + 5).await?;
    rows.extend(latency_rows(&lat));

    eprintln!("suite 4/6: SPARQL, 1000 vehicles");
    let sem = tokio::task::spawn_blocking(|| {
        semantic::run(semantic::BenchOptions {
            vehicles: 1000,
            updates_per_vehicle: 10,
            samples: 30,
        })
    })
    .await?
    .context("semantic benchmark")?;
    for q in &sem.fresh {
        let ms = q.p50.as_secs_f64() * 1e3;
        rows.push(SuiteRow::new(
            &format!("SPARQL p50 {} (1000 vehicles, fresh)", q.name),
            format!("{} ms", shown(ms, 2, Better::Lower)),
            "≤ 2 ms",
            Some(ms <= 2.0),
        ));
    }
    if semantic_hour_s > 0 {
        eprintln!(
            "suite 4/6: SPARQL after {semantic_hour_s} simulated seconds of 1000 vehicles' traffic"
        );
        let hour = tokio::task::spawn_blocking(move || {
            semantic::hour::run_hour(
                semantic::hour::HourOptions {
                    seconds: semantic_hour_s,
                    sample_every_s: semantic_hour_s.div_ceil(6),
                    ..semantic::hour::HourOptions::default()
                },
                shoal_semantic::StoreConfig::default(),
            )
        })
        .await?
        .context("semantic hour benchmark")?;
        if let Some(last) = hour.series.last() {
            for (after, between) in last.back_to_back.iter().zip(&last.queries) {
                let ms = after.p50.as_secs_f64() * 1e3;
                rows.push(SuiteRow::new(
                    &format!(
                        "SPARQL p50 {} after {semantic_hour_s} s of updates (between writes: {:.2} ms)",
                        after.name,
                        between.p50.as_secs_f64() * 1e3
                    ),
                    format!("{} ms", shown(ms, 2, Better::Lower)),
                    "≤ 2 ms",
                    Some(ms <= 2.0),
                ));
            }
            // The first sample, not the fresh store, is the baseline: the first writes
            // while query snapshots are alive copy the index once (copy on write), and the
            // allocator keeps that high-water mark; growth after it is what would leak.
            let first = hour.series.first().unwrap_or(last);
            #[allow(clippy::cast_precision_loss)]
            let (fresh_kib, first_kib, end_kib) = (
                hour.fresh_memory.rss_kib.unwrap_or(0) as f64,
                first.memory.rss_kib.unwrap_or(0) as f64,
                last.memory.rss_kib.unwrap_or(0) as f64,
            );
            if first_kib > 0.0 {
                rows.push(SuiteRow::new(
                    &format!(
                        "semantic bench process RSS, after {} s vs after {semantic_hour_s} s of updates (fresh: {:.0} MB)",
                        first.sim_s,
                        fresh_kib / 1024.0
                    ),
                    format!(
                        "{:+.1} % ({:.0} → {:.0} MB)",
                        100.0 * (end_kib / first_kib - 1.0),
                        first_kib / 1024.0,
                        end_kib / 1024.0
                    ),
                    "flat (< 10 %)",
                    Some(end_kib < 1.1 * first_kib),
                ));
            }
        }
    }

    eprintln!("suite 5/6: acoustic (PDU sizes, channel use)");
    let ac = acoustic::run(&acoustic::BenchOptions::default())
        .await
        .context("acoustic benchmark")?;
    let key = ac
        .sizes
        .rows
        .iter()
        .find(|r| r.message.starts_with("state_keyframe"))
        .map_or(0, |r| r.bytes);
    rows.push(pdu_row(key, ac.sizes.dccl_reference_bytes));
    rows.push(SuiteRow::new(
        "acoustic channel use under saturation",
        shown(ac.channel.channel_use, 2, Better::Higher),
        "≥ 0.90",
        Some(ac.channel.goal_met),
    ));
    rows.push(SuiteRow::new(
        "acoustic frame tag + counter (security on)",
        format!("{} B of 64", ac.sizes.auth_tag_bytes.unwrap_or(0)),
        "-",
        None,
    ));

    eprintln!("suite 6/6: scale, {scale_vehicles} vehicles x 1 Hz");
    let sc = scale_figures(scale_vehicles, 1.0, 30, domain + 6).await?;
    rows.extend(scale_rows(&sc, scale_vehicles));

    let table = suite_table(&rows);
    let header = format!(
        "# shoal bench suite — {} — {}\n\nRelease build, loopback only, {:.0} s in all, load average {load_before} before and {} after. Peers measured in the same run on the same host; a published figure not measured here appears only in its row's target.\n\n",
        date(),
        machine(),
        started.elapsed().as_secs_f64(),
        load()
    );
    println!("{header}{table}");
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let host = machine()
        .split_whitespace()
        .next()
        .unwrap_or("host")
        .to_string();
    let path = unused_path(out, &format!("{}-{host}-suite", date()), "md");
    std::fs::write(&path, format!("{header}{table}"))
        .with_context(|| format!("cannot write {}", path.display()))?;
    eprintln!("suite: written to {}", path.display());
    Ok(())
}

/// `dir/stem.ext`, or `dir/stem-2.ext`, `-3`… if that exists: a second run on the same day
/// must not overwrite the first one's record.
fn unused_path(dir: &std::path::Path, stem: &str, ext: &str) -> std::path::PathBuf {
    let mut path = dir.join(format!("{stem}.{ext}"));
    let mut n = 2;
    while path.exists() {
        path = dir.join(format!("{stem}-{n}.{ext}"));
        n += 1;
    }
    path
}

#[cfg(test)]
mod tests {
    use super::super::bus::{PeerRoundTrip, PerSecond, PerfResult, RoundTrip};
    use super::*;

    fn bus(lost: usize, peer: bool) -> BusFigures {
        let peer_rt = PeerRoundTrip {
            p50_us: 76.0,
            p99_us: 120.0,
            windows: 10,
            received: 130_000,
            timed_out: 0,
        };
        BusFigures {
            rt: RoundTrip {
                p50_us: 148.0,
                p99_us: 410.0,
                per_second: Some(PerSecond {
                    p50_us: 150.0,
                    p99_us: 300.0,
                    windows: 10,
                }),
                count: 92_024,
                lost,
            },
            rt_stream: RoundTrip {
                p50_us: 170.0,
                p99_us: 450.0,
                per_second: Some(PerSecond {
                    p50_us: 172.0,
                    p99_us: 330.0,
                    windows: 10,
                }),
                count: 80_000,
                lost: 0,
            },
            throughput: 80_000.0,
            steps: Vec::new(),
            peer: peer.then_some(PerfResult {
                rt: peer_rt,
                throughput: 400_000.0,
            }),
            peer_shoal_transport: peer.then_some(PeerRoundTrip {
                p50_us: 90.0,
                ..peer_rt
            }),
            peer_waitset: peer.then_some(PeerRoundTrip {
                p50_us: 100.0,
                ..peer_rt
            }),
        }
    }

    fn latency(dropped: u64) -> LatencyFigures {
        LatencyFigures {
            // Sorted, as `latency_figures` returns them: p50 2 ms, p99 3 ms.
            samples: (0..1000).map(|i| f64::from(i / 250)).collect(),
            received: 29_000,
            dropped,
            dropped_in_warm_up: 0,
        }
    }

    fn scale(mean_rate: f64) -> ScaleFigures {
        ScaleFigures {
            all_alive_after_s: Some(20.0),
            mean_rate,
            offered_rate: 10_000.0,
            peak_rss_mb: 900.0,
        }
    }

    /// Every row the builders make, from the given figures.
    fn all_rows(bus: &BusFigures, lat: &LatencyFigures, sc: &ScaleFigures) -> Vec<SuiteRow> {
        let mut rows = bus_rows(bus);
        rows.extend(ingest_rows(130_000.0, 150_000.0));
        rows.extend(latency_rows(lat));
        rows.push(pdu_row(20, acoustic::DCCL_REFERENCE_BYTES));
        rows.extend(scale_rows(sc, 10_000));
        rows
    }

    /// The table's data lines, split into their six cells.
    fn cells(table: &str) -> Vec<Vec<String>> {
        table
            .lines()
            .skip(2)
            .map(|l| {
                l.trim_matches('|')
                    .split(" | ")
                    .map(|c| c.trim().to_string())
                    .collect()
            })
            .collect()
    }

    /// The row whose figure starts with `start`.
    fn row_starting(rows: &[Vec<String>], start: &str, table: &str) -> Vec<String> {
        rows.iter()
            .find(|r| r[0].starts_with(start))
            .cloned()
            .unwrap_or_else(|| panic!("no row {start} in {table}"))
    }

    #[test]
    fn the_peer_column_holds_only_figures_measured_in_the_run() {
        let table = suite_table(&all_rows(&bus(0, true), &latency(0), &scale(9_995.0)));
        let rows = cells(&table);
        assert!(rows.iter().all(|r| r.len() == 6), "{table}");
        for r in &rows {
            assert!(
                !r[2].contains("published") && !r[2].contains("DCCL"),
                "peer column: {r:?}"
            );
        }
        let pdu = rows
            .iter()
            .find(|r| r[0].starts_with("State Vector PDU"))
            .unwrap_or_else(|| panic!("no PDU row in {table}"));
        assert_eq!((pdu[2].as_str(), pdu[3].as_str()), ("-", "-"));
        assert!(
            pdu[4].starts_with("≤ 20 B (DCCL's published size"),
            "{pdu:?}"
        );
        assert_eq!(pdu[5], "yes");
    }

    #[test]
    fn the_table_shows_counts_percentages_and_one_verdict_per_ingest_target() {
        let table = suite_table(&all_rows(&bus(0, true), &latency(0), &scale(9_995.0)));
        let rows = cells(&table);
        let row = |start: &str| row_starting(&rows, start, &table);
        let p50 = row("bus round trip p50 (median of per-second");
        assert_eq!(p50[1], "150 µs (92,024 measured, 0 lost)");
        assert_eq!(p50[2], "Cyclone 76 µs (130,000 measured, 0 timed out)");
        // 150 / 76 = 1.9736…: shown rounded up, as a latency ratio never reads better,
        // and over the 1.3× target.
        assert_eq!((p50[3].as_str(), p50[5].as_str()), ("1.98×", "**no**"));
        let whole = row("bus round trip over the whole run");
        assert_eq!(
            (whole[1].as_str(), whole[2].as_str()),
            ("p50 148 µs, p99 410 µs", "-")
        );
        let vs_raw = row("ingest vs raw SQLite");
        assert_eq!(
            vs_raw[2],
            "raw SQLite 150,000/s (the faster of arrival and key order)"
        );
        assert_eq!(
            (vs_raw[3].as_str(), vs_raw[4].as_str()),
            ("0.86×", "≥ 0.9× raw")
        );
        assert_eq!(vs_raw[5], "**no**");
        let absolute = row("ingest absolute");
        assert_eq!(
            (absolute[1].as_str(), absolute[2].as_str()),
            ("130,000/s", "-")
        );
        assert_eq!(
            (absolute[4].as_str(), absolute[5].as_str()),
            ("≥ 100,000/s", "yes")
        );
        let p99 = row("vehicle → console latency p99");
        assert_eq!(p99[1], "3 ms (29,000 sent, 29,000 received, 0 dropped)");
        assert_eq!(p99[5], "yes");
        let ingest = row("station ingest");
        assert_eq!(ingest[1], "9,995/s (99.95 % of 10,000/s offered)");
        assert_eq!(ingest[5], "yes");
    }

    #[test]
    fn a_dropped_update_a_lost_round_trip_or_a_short_ingest_fails_its_row() {
        let table = suite_table(&all_rows(&bus(1, true), &latency(12), &scale(9_989.0)));
        let rows = cells(&table);
        let row = |start: &str| row_starting(&rows, start, &table);
        let p50 = row("bus round trip p50 (median of per-second");
        assert_eq!(p50[1], "150 µs (92,024 measured, 1 lost)");
        assert_eq!(p50[5], "**no**");
        let p99 = row("vehicle → console latency p99");
        assert_eq!(p99[1], "3 ms (29,012 sent, 29,000 received, 12 dropped)");
        assert_eq!(p99[5], "**no**");
        let ingest = row("station ingest");
        assert_eq!(ingest[1], "9,989/s (99.89 % of 10,000/s offered)");
        assert_eq!(ingest[5], "**no**");
    }

    #[test]
    fn without_ddsperf_the_bus_rows_are_unjudged_and_have_no_peer() {
        let rows = bus_rows(&bus(0, false));
        assert!(rows.iter().all(|r| r.peer == "-" && r.ratio == "-"));
        assert_eq!(rows[0].met, None);
    }

    #[test]
    fn row_verdicts() {
        // 98 / 76 = 1.289 and 100 / 76 = 1.316, against at most 1.3×.
        assert_eq!(bus_p50_met(Some(98.0), Some(76.0), 0), Some(true));
        assert_eq!(bus_p50_met(Some(100.0), Some(76.0), 0), Some(false));
        assert_eq!(bus_p50_met(Some(98.0), Some(76.0), 1), Some(false));
        assert_eq!(bus_p50_met(Some(150.0), None, 0), None);
        assert_eq!(bus_p50_met(Some(150.0), None, 3), Some(false));
        assert_eq!(bus_p50_met(None, Some(76.0), 0), Some(false));
        assert!(ingest_vs_raw_met(90_000.0, 100_000.0));
        assert!(!ingest_vs_raw_met(89_999.0, 100_000.0));
        assert!(!ingest_vs_raw_met(90_000.0, 0.0));
        assert!(ingest_absolute_met(100_000.0));
        assert!(!ingest_absolute_met(99_999.9));
        assert!(latency_p99_met(5.0, 0));
        assert!(!latency_p99_met(6.0, 0));
        assert!(!latency_p99_met(1.0, 1));
        assert!(!latency_p99_met(f64::NAN, 0));
        assert!(scale_ingest_met(99.9));
        assert!(scale_ingest_met(100.0));
        assert!(!scale_ingest_met(99.89));
        assert!(!scale_ingest_met(95.0));
        assert!(!scale_ingest_met(f64::NAN));
    }

    #[test]
    fn rounded_figures_never_read_better_than_they_are() {
        assert_eq!(shown(2.004, 2, Better::Lower), "2.01");
        assert_eq!(shown(2.0, 2, Better::Lower), "2.00");
        assert_eq!(shown(0.8996, 2, Better::Higher), "0.89");
        assert_eq!(shown(99.9, 2, Better::Higher), "99.90");
        assert_eq!(shown(0.29, 2, Better::Higher), "0.29");
        assert_eq!(shown(f64::NAN, 2, Better::Higher), "-");
        assert_eq!(rate_text(99_999.6), "99,999/s");
        assert_eq!(rate_text(f64::NAN), "-");
    }

    #[test]
    fn a_second_suite_run_on_a_day_gets_its_own_file() {
        let dir = std::env::temp_dir().join(format!("shoal-unused-path-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap_or_default();
        let first = unused_path(&dir, "day-suite", "md");
        assert_eq!(first, dir.join("day-suite.md"));
        std::fs::write(&first, "one").unwrap_or_default();
        assert_eq!(
            unused_path(&dir, "day-suite", "md"),
            dir.join("day-suite-2.md")
        );
        std::fs::write(dir.join("day-suite-2.md"), "two").unwrap_or_default();
        assert_eq!(
            unused_path(&dir, "day-suite", "md"),
            dir.join("day-suite-3.md")
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
