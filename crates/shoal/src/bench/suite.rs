//! `shoal bench suite`: every figure that has a target, in one run and one table, each
//! beside the peer measured in the same run (Cyclone DDS ddsperf, a raw batched SQLite
//! insert, DCCL's published size) and its target; saved as Markdown.

use std::time::Instant;

use anyhow::{Context, Result};

use super::bus::bus_figures;
use super::helpers::{date, machine, percentile};
use super::latency::latency_figures;
use super::pipeline::pipeline_figures;
use super::scale::scale_figures;
use super::{acoustic, semantic};
use crate::config::ShoalConfig;

/// One line of the suite's table.
struct SuiteRow {
    figure: String,
    shoal: String,
    peer: String,
    ratio: String,
    target: String,
    met: Option<bool>,
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

    fn with_peer(mut self, peer: String, ratio: f64) -> Self {
        self.peer = peer;
        self.ratio = format!("{ratio:.2}×");
        self
    }

    /// [`Self::with_peer`] when the peer could be measured.
    fn with_peer_if(self, peer: Option<(String, f64)>) -> Self {
        match peer {
            Some((p, ratio)) => self.with_peer(p, ratio),
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
    let peer = bus.peer.as_ref();
    rows.push(
        SuiteRow::new(
            "bus round trip p50",
            format!("{:.0} µs", bus.rt.p50_us),
            "≤ 2× Cyclone",
            peer.map(|p| bus.rt.p50_us <= 2.0 * p.p50_us),
        )
        .with_peer_if(peer.map(|p| {
            (
                format!("Cyclone {:.0} µs", p.p50_us),
                bus.rt.p50_us / p.p50_us,
            )
        })),
    );
    rows.push(
        SuiteRow::new(
            "bus round trip p99",
            format!("{:.0} µs", bus.rt.p99_us),
            "-",
            None,
        )
        .with_peer_if(peer.map(|p| {
            (
                format!("Cyclone {:.0} µs", p.p99_us),
                bus.rt.p99_us / p.p99_us,
            )
        })),
    );
    rows.push(
        SuiteRow::new(
            "bus round trip p50, ddsperf with Shoal's Cyclone configuration",
            format!("{:.0} µs", bus.rt.p50_us),
            "-",
            None,
        )
        .with_peer_if(
            bus.peer_shoal_transport
                .map(|p| (format!("Cyclone {:.0} µs", p.0), bus.rt.p50_us / p.0)),
        ),
    );
    rows.push(
        SuiteRow::new(
            "bus throughput, reliable, no loss",
            format!("≥ {:.0} k/s", bus.throughput / 1000.0),
            "-",
            None,
        )
        .with_peer_if(peer.map(|p| {
            (
                format!("Cyclone {:.0} k/s", p.throughput / 1000.0),
                bus.throughput / p.throughput,
            )
        })),
    );

    eprintln!("suite 2/6: ingest pipeline (Shoal vs raw batched SQLite insert)");
    let pf = pipeline_figures(cfg, domain + 4, 1000, 300_000).await?;
    rows.push(
        SuiteRow::new(
            "ingest (validate + plausibility + latest + semantic + 10 rules + history)",
            format!("{:.0}/s", pf.rate),
            "≥ 100,000/s and ≥ 0.8× raw",
            Some(pf.rate >= 100_000.0 && pf.rate >= 0.8 * pf.raw_rate),
        )
        .with_peer(
            format!("raw SQLite {:.0}/s", pf.raw_rate),
            pf.rate / pf.raw_rate,
        ),
    );

    eprintln!("suite 3/6: end-to-end latency, 1000 vehicles x 1 Hz");
    let lat = latency_figures(cfg, 1000, 1.0, seconds.max(10), domain + 5).await?;
    let p99 = percentile(&lat.samples, 99.0);
    rows.push(SuiteRow::new(
        "vehicle → console latency p50 (1000 × 1 Hz)",
        format!("{:.0} ms", percentile(&lat.samples, 50.0)),
        "-",
        None,
    ));
    rows.push(SuiteRow::new(
        "vehicle → console latency p99 (1000 × 1 Hz)",
        format!("{p99:.0} ms"),
        "≤ 5 ms",
        Some(p99 <= 5.0),
    ));

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
            format!("{ms:.2} ms"),
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
                    format!("{ms:.2} ms"),
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
    #[allow(clippy::cast_precision_loss)]
    rows.push(
        SuiteRow::new(
            "State Vector PDU",
            format!("{key} B"),
            "≤ DCCL",
            Some(key <= ac.sizes.dccl_reference_bytes),
        )
        .with_peer(
            format!("DCCL {} B (published)", ac.sizes.dccl_reference_bytes),
            key as f64 / ac.sizes.dccl_reference_bytes as f64,
        ),
    );
    rows.push(SuiteRow::new(
        "acoustic channel use under saturation",
        format!("{:.2}", ac.channel.channel_use),
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
    rows.push(SuiteRow::new(
        &format!("station RSS, {scale_vehicles} vehicles × 1 Hz (peak)"),
        format!("{:.0} MB", sc.peak_rss_mb),
        "≤ 2048 MB, all alive",
        Some(sc.peak_rss_mb <= 2048.0 && sc.all_alive_after_s.is_some()),
    ));
    #[allow(clippy::cast_precision_loss)]
    rows.push(SuiteRow::new(
        &format!("station ingest, {scale_vehicles} vehicles × 1 Hz offered"),
        format!("{:.0}/s", sc.mean_rate),
        "= offered",
        Some(sc.mean_rate >= 0.95 * scale_vehicles as f64),
    ));

    let table = suite_table(&rows);
    let header = format!(
        "# shoal bench suite — {} — {}\n\nRelease build, loopback only, {:.0} s in all, load average {load_before} before and {} after. Peers measured in the same run on the same host.\n\n",
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
    use super::*;

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
