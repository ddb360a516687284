//! `shoal bench scale`: a `shoal station` and N lightweight vehicles (`shoal swarm`), each
//! its own process, on loopback: vehicles alive, ingest rate, the resident memory of both
//! processes and the standard SPARQL queries over HTTP, every 10 s and at the end.

use std::time::{Duration, Instant};

use anyhow::{Result, bail};
use reqwest::Method;

use crate::query::{ApiClient, Target};

use super::helpers::{child, percentile, rss_mb_of, tempfile_dir};

/// One sample of a running station, read through its API.
struct StationSample {
    pub(super) alive: usize,
    pub(super) accepted: u64,
    pub(super) rejected: u64,
}

async fn station_sample(api: &ApiClient) -> Option<StationSample> {
    let (_, fleet) = api.request(Method::GET, "/api/fleet", None).await.ok()?;
    let (_, stats) = api.request(Method::GET, "/api/stats", None).await.ok()?;
    let fleet: serde_json::Value = serde_json::from_str(&fleet).ok()?;
    let stats: serde_json::Value = serde_json::from_str(&stats).ok()?;
    let alive = fleet
        .as_array()?
        .iter()
        .filter(|v| v["contact"] == "alive")
        .count();
    let rejected = stats["ingest"]["rejected"].as_object().map_or(0, |m| {
        m.values().filter_map(serde_json::Value::as_u64).sum()
    });
    Some(StationSample {
        alive,
        accepted: stats["ingest"]["states_accepted"].as_u64().unwrap_or(0),
        rejected,
    })
}

/// What `bench scale` measures.
pub(super) struct ScaleFigures {
    pub(super) all_alive_after_s: Option<f64>,
    /// State vectors accepted per second, the mean of the 10 s intervals once every vehicle
    /// was alive (the first one left out).
    pub(super) mean_rate: f64,
    /// State vectors offered per second: vehicles × rate.
    pub(super) offered_rate: f64,
    pub(super) peak_rss_mb: f64,
}

impl ScaleFigures {
    /// The mean ingest rate as a percentage of the offered rate (NaN when none was offered).
    pub(super) fn ingest_pct(&self) -> f64 {
        if self.offered_rate > 0.0 {
            100.0 * self.mean_rate / self.offered_rate
        } else {
            f64::NAN
        }
    }
}

/// Runs each standard SPARQL query once against the station's endpoint, as an operator's
/// console would, and returns the round-trip times in ms (HTTP included).
async fn standard_query_times(api: &ApiClient) -> Result<Vec<f64>> {
    let mut times = Vec::with_capacity(shoal_semantic::STANDARD_QUERIES.len());
    for (name, q) in shoal_semantic::STANDARD_QUERIES {
        let t = Instant::now();
        let (status, body) = api.sparql("json", q).await?;
        if status != 200 {
            bail!("{name} answered {status}: {body}");
        }
        times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    Ok(times)
}

/// One 10-second sample of `bench scale` once every vehicle is alive.
struct ScaleRow {
    /// Seconds since the swarm started.
    pub(super) t_s: f64,
    /// State vectors accepted per second over the last interval.
    pub(super) per_s: f64,
    pub(super) rss_mb: f64,
    /// The standard queries' HTTP round trips, ms.
    pub(super) queries_ms: Vec<f64>,
}

/// Whether memory and queries stay flat over a scale run: the first and last tenth
/// (session 5's measure), every tenth's mean RSS (single readings swing by 10 to 20 MB
/// as the allocator keeps and returns pages), and a least-squares line through all RSS
/// readings, which a steady swing does not tilt but a leak does.
fn print_flatness(rows: &[ScaleRow]) {
    let tenth = (rows.len() / 10).max(1);
    let medians = |part: &[ScaleRow]| {
        column_medians(
            &part
                .iter()
                .map(|r| r.queries_ms.clone())
                .collect::<Vec<_>>(),
        )
    };
    let (first, last) = (
        medians(&rows[..tenth]),
        medians(&rows[rows.len() - tenth..]),
    );
    let show = |v: &[f64]| {
        v.iter()
            .map(|t| format!("{t:.2}"))
            .collect::<Vec<_>>()
            .join(" / ")
    };
    println!(
        "SPARQL median ms (q1 / q2 / q3 / q4 / q5), first tenth of the run: {}; last tenth: {}",
        show(&first),
        show(&last)
    );
    #[allow(clippy::cast_precision_loss)]
    let mean_rss =
        |part: &[ScaleRow]| part.iter().map(|r| r.rss_mb).sum::<f64>() / part.len() as f64;
    let (a, b) = (
        mean_rss(&rows[..tenth]),
        mean_rss(&rows[rows.len() - tenth..]),
    );
    println!(
        "station RSS first tenth {a:.1} MB, last tenth {b:.1} MB ({:+.1} %)",
        (b / a - 1.0) * 100.0
    );
    if rows.len() >= 10 {
        let tenths: Vec<String> = (0..10)
            .map(|i| {
                let part = &rows[i * rows.len() / 10..(i + 1) * rows.len() / 10];
                format!("{:.1}", mean_rss(part))
            })
            .collect();
        println!("station RSS by tenth of the run, MB: {}", tenths.join(", "));
    }
    let points: Vec<(f64, f64)> = rows.iter().map(|r| (r.t_s, r.rss_mb)).collect();
    // Over a few minutes the allocator's swing is all a line would show.
    let long_enough = points.len() >= 30;
    if let Some((at_zero, per_s)) = least_squares(&points).filter(|_| long_enough) {
        let (t0, t1) = (points[0].0, points[points.len() - 1].0);
        let (y0, y1) = (at_zero + per_s * t0, at_zero + per_s * t1);
        println!(
            "station RSS trend (least squares over {} readings): {:+.1} MB/h, {y0:.1} MB at the start to {y1:.1} MB at the end of the line ({:+.1} %)",
            points.len(),
            per_s * 3600.0,
            (y1 / y0 - 1.0) * 100.0
        );
    }
}

/// The least-squares line through `points`: its value at x = 0 and its slope; `None` for
/// fewer than two distinct x.
fn least_squares(points: &[(f64, f64)]) -> Option<(f64, f64)> {
    #[allow(clippy::cast_precision_loss)]
    let n = points.len() as f64;
    let mx = points.iter().map(|p| p.0).sum::<f64>() / n;
    let my = points.iter().map(|p| p.1).sum::<f64>() / n;
    let sxx: f64 = points.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = points.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    if points.len() < 2 || sxx <= 0.0 {
        return None;
    }
    let slope = sxy / sxx;
    Some((my - slope * mx, slope))
}

/// The median of each column of `rows`.
fn column_medians(rows: &[Vec<f64>]) -> Vec<f64> {
    let width = rows.first().map_or(0, Vec::len);
    (0..width)
        .map(|c| {
            let mut col: Vec<f64> = rows.iter().map(|r| r[c]).collect();
            col.sort_by(f64::total_cmp);
            percentile(&col, 50.0)
        })
        .collect()
}

pub(super) async fn scale(vehicles: usize, rate: f64, seconds: u64, domain: u16) -> Result<()> {
    scale_figures(vehicles, rate, seconds, domain)
        .await
        .map(|_| ())
}

pub(super) async fn scale_figures(
    vehicles: usize,
    rate: f64,
    seconds: u64,
    domain: u16,
) -> Result<ScaleFigures> {
    let dir = tempfile_dir()?;
    let port = std::net::TcpListener::bind("127.0.0.1:0")?
        .local_addr()?
        .port();
    let addr = std::net::SocketAddr::from(([127, 0, 0, 1], port));
    let api = &ApiClient::new(&Target::plain(addr), None)?;
    let db = dir.join("scale.db");
    let listen = addr.to_string();
    let db_arg = db.display().to_string();
    let mut station = child(&["station", "--listen", &listen, "--db", &db_arg], domain)?;
    let t = Instant::now();
    while station_sample(api).await.is_none() {
        if t.elapsed() > Duration::from_secs(30) {
            bail!("the station did not open its API within 30 s");
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    let station_pid = station.id().map(|p| p.to_string()).unwrap_or_default();
    let idle_rss = rss_mb_of(&station_pid);
    let count = vehicles.to_string();
    let rate_arg = rate.to_string();
    let mut swarm = child(&["swarm", "--count", &count, "--rate", &rate_arg], domain)?;
    let swarm_pid = swarm.id().map(|p| p.to_string()).unwrap_or_default();
    println!(
        "scale: {vehicles} vehicles x {rate} Hz, station and swarm in separate processes, domain {domain}"
    );
    println!(
        "{:>6} {:>7} {:>12} {:>10} {:>12} {:>10}  SPARQL ms (q1..q5, HTTP round trip)",
        "t (s)", "alive", "accepted/s", "rejected", "station MB", "swarm MB"
    );
    let start = Instant::now();
    let mut all_alive_at = None;
    let mut last = (Instant::now(), 0u64);
    let mut first_rss = None;
    let mut rows = Vec::new();
    // A poll can time out while a loaded station is busy: one is retried at the next
    // sample and counted; three in a row, or a station process that ended, end the run.
    let (mut failed_polls, mut failed_in_a_row) = (0u32, 0u32);
    loop {
        tokio::time::sleep(Duration::from_secs(10)).await;
        let polled = match station_sample(api).await {
            Some(s) => match standard_query_times(api).await {
                Ok(q) => Some((s, q)),
                Err(e) => {
                    eprintln!("scale: a SPARQL poll failed: {e:#}");
                    None
                }
            },
            None => None,
        };
        let Some((s, q)) = polled else {
            failed_polls += 1;
            failed_in_a_row += 1;
            if let Ok(Some(status)) = station.try_wait() {
                bail!("the station process ended ({status})");
            }
            if failed_in_a_row >= 3 {
                bail!("the station stopped answering (3 polls in a row failed)");
            }
            eprintln!("scale: the station's API did not answer a poll; trying again in 10 s");
            continue;
        };
        failed_in_a_row = 0;
        let now = Instant::now();
        #[allow(clippy::cast_precision_loss)]
        let per_s = (s.accepted - last.1) as f64 / now.duration_since(last.0).as_secs_f64();
        last = (now, s.accepted);
        let (st, sw) = (rss_mb_of(&station_pid), rss_mb_of(&swarm_pid));
        println!(
            "{:>6.0} {:>7} {:>12.0} {:>10} {:>12.1} {:>10.1}  {}",
            start.elapsed().as_secs_f64(),
            s.alive,
            per_s,
            s.rejected,
            st,
            sw,
            q.iter()
                .map(|t| format!("{t:>6.2}"))
                .collect::<Vec<_>>()
                .join(" ")
        );
        if all_alive_at.is_none() && s.alive >= vehicles {
            all_alive_at = Some(start.elapsed());
            first_rss = Some(st);
        }
        if all_alive_at.is_some() {
            rows.push(ScaleRow {
                t_s: start.elapsed().as_secs_f64(),
                per_s,
                rss_mb: st,
                queries_ms: q,
            });
        }
        let deadline =
            all_alive_at.unwrap_or(Duration::from_secs(120)) + Duration::from_secs(seconds);
        if start.elapsed() >= deadline {
            break;
        }
    }
    drop(swarm.stdin.take());
    drop(station.stdin.take());
    let _ = tokio::time::timeout(Duration::from_secs(15), swarm.wait()).await;
    let _ = tokio::time::timeout(Duration::from_secs(15), station.wait()).await;
    let _ = std::fs::remove_dir_all(&dir);
    let steady: Vec<f64> = rows.iter().skip(1).map(|r| r.per_s).collect();
    #[allow(clippy::cast_precision_loss)]
    let mean = steady.iter().sum::<f64>() / steady.len().max(1) as f64;
    let peak = rows.iter().map(|r| r.rss_mb).fold(0.0, f64::max);
    if rows.len() >= 2 {
        print_flatness(&rows);
    }
    if failed_polls > 0 {
        println!("polls of the station's API that failed and were retried: {failed_polls}");
    }
    let figures = ScaleFigures {
        all_alive_after_s: all_alive_at.map(|t| t.as_secs_f64()),
        mean_rate: mean,
        offered_rate: rate * {
            #[allow(clippy::cast_precision_loss)]
            let v = vehicles as f64;
            v
        },
        peak_rss_mb: peak,
    };
    match all_alive_at {
        Some(t) => {
            println!(
                "all {vehicles} alive after {:.0} s; steady ingest {mean:.0} state vectors/s, {:.2} % of the {:.0}/s offered; station RSS idle {idle_rss:.1} MB, all alive {:.1} MB, peak {peak:.1} MB",
                t.as_secs_f64(),
                figures.ingest_pct(),
                figures.offered_rate,
                first_rss.unwrap_or(f64::NAN)
            );
        }
        None => println!("not every vehicle was alive within 120 s"),
    }
    Ok(figures)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ingest_is_a_percentage_of_what_was_offered() {
        let mut f = ScaleFigures {
            all_alive_after_s: Some(20.0),
            mean_rate: 9_995.0,
            offered_rate: 10_000.0,
            peak_rss_mb: 900.0,
        };
        assert!((f.ingest_pct() - 99.95).abs() < 1e-9);
        f.offered_rate = 0.0;
        assert!(f.ingest_pct().is_nan());
    }

    #[test]
    fn least_squares_finds_a_line_and_ignores_a_steady_swing() {
        let line: Vec<(f64, f64)> = (0..10)
            .map(|i| (f64::from(i), 3.0 + 2.0 * f64::from(i)))
            .collect();
        let (a, b) = least_squares(&line).unwrap_or((f64::NAN, f64::NAN));
        assert!((a - 3.0).abs() < 1e-9 && (b - 2.0).abs() < 1e-9, "{a} {b}");
        // A swing of ±15 MB around 80 MB every 10 minutes tilts the hour's line by under
        // 5 MB/h (the phase at the ends), where 10 % growth would be 8 MB/h.
        let swing: Vec<(f64, f64)> = (0..360)
            .map(|i| {
                let t = f64::from(i) * 10.0;
                (t, 80.0 + 15.0 * (t / 600.0 * std::f64::consts::TAU).sin())
            })
            .collect();
        let (_, slope) = least_squares(&swing).unwrap_or((f64::NAN, f64::NAN));
        assert!(slope.abs() * 3600.0 < 5.0, "{slope}");
        assert!(least_squares(&[(1.0, 2.0)]).is_none());
        assert!(least_squares(&[(1.0, 2.0), (1.0, 3.0)]).is_none());
    }
}
