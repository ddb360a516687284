//! `shoal bench latency`: end to end, vehicle -> station -> console. N lightweight vehicles
//! in another process (`shoal swarm`, each state stamped when sent) and a WebSocket client
//! on the console's live feed, as the web console reads it; p50/p99 of arrival minus stamp,
//! and how many updates the feed dropped for the client because it fell behind.

use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use futures::StreamExt;
use shoal_model::now_ms;
use tokio_util::sync::CancellationToken;

use super::helpers::{
    bench_station, date, dds, grouped, helper, machine, percentile, tempfile_dir,
};
use crate::config::ShoalConfig;

/// What `bench latency` measures. Counts are of the measured window (after the warm-up).
///
/// The feed is a broadcast channel per station: every update it carries after the client
/// joined either reaches the client or is counted in the `lagged` note the console sends
/// when the client fell behind (`missed`: tokio's `RecvError::Lagged`, in shoal-console's
/// live.rs). So `received + dropped` is what the feed had for the client, and a dropped
/// update is one whose latency was never measured.
#[derive(Debug, Default)]
pub(super) struct LatencyFigures {
    /// Arrival minus stamp of each vehicle update, ms (sorted once the run is over).
    pub(super) samples: Vec<f64>,
    /// Live updates of any kind (vehicle states, events…) that reached the client.
    pub(super) received: u64,
    /// Live updates the feed dropped for the client (the sum of its `lagged` notes' `missed`;
    /// the note does not say of which kind).
    pub(super) dropped: u64,
    /// The same during the warm-up, not counted in `dropped`.
    pub(super) dropped_in_warm_up: u64,
}

impl LatencyFigures {
    /// Live updates the feed had for the client in the measured window.
    pub(super) fn sent(&self) -> u64 {
        self.received + self.dropped
    }

    /// Counts one message of the live feed, `v`, that arrived at `arrived_ms`; `measuring`
    /// once the warm-up is over. A `lagged` note counts in the part of the run in which it
    /// arrives.
    fn count(&mut self, v: &serde_json::Value, arrived_ms: i64, measuring: bool) {
        match v["type"].as_str() {
            None => {}
            Some("lagged") => {
                let missed = v["data"]["missed"].as_u64().unwrap_or(0);
                if measuring {
                    self.dropped += missed;
                } else {
                    self.dropped_in_warm_up += missed;
                }
            }
            Some(_) if !measuring => {}
            Some("vehicle") => {
                self.received += 1;
                if let Some(stamp) = v["data"]["latest"]["timestamp_ms"].as_i64() {
                    #[allow(clippy::cast_precision_loss)]
                    self.samples.push((arrived_ms - stamp) as f64);
                }
            }
            Some(_) => self.received += 1,
        }
    }
}

pub(super) async fn latency(
    cfg: &ShoalConfig,
    vehicles: usize,
    rate: f64,
    seconds: u64,
    domain: u16,
) -> Result<()> {
    let figures = latency_figures(cfg, vehicles, rate, seconds, domain).await?;
    let samples = &figures.samples;
    println!("# shoal bench latency — {} — {}", machine(), date());
    println!(
        "vehicle -> station -> console live feed, {vehicles} vehicles x {rate} Hz, {} vehicle updates timed in {seconds} s",
        grouped(samples.len() as u64)
    );
    println!(
        "live updates to this client in those {seconds} s: {} sent, {} received, {} dropped because the client fell behind ({} more dropped in the warm-up)",
        grouped(figures.sent()),
        grouped(figures.received),
        grouped(figures.dropped),
        grouped(figures.dropped_in_warm_up)
    );
    println!(
        "latency p50 {:.0} ms, p99 {:.0} ms, max {:.0} ms (stamps have 1 ms resolution)",
        percentile(samples, 50.0),
        percentile(samples, 99.0),
        samples.last().copied().unwrap_or(f64::NAN)
    );
    Ok(())
}

/// The helper process of [`latency_figures`]: `shoal swarm`'s vehicles on one
/// participant, secured with a station identity when `cfg` says so, until stdin closes.
pub(super) async fn swarm(cfg: &ShoalConfig, domain: u16, count: usize, rate: f64) -> Result<()> {
    let spec = shoal_proxy::swarm::SwarmSpec {
        count,
        rate_hz: rate,
        ..shoal_proxy::swarm::SwarmSpec::default()
    };
    spec.check()?;
    let shutdown = crate::daemons::shutdown_signal(true);
    shoal_proxy::swarm::run_swarm(spec, dds(cfg, domain)?, shutdown)
        .await
        .context("swarm failed")
}

pub(super) async fn latency_figures(
    cfg: &ShoalConfig,
    vehicles: usize,
    rate: f64,
    seconds: u64,
    domain: u16,
) -> Result<LatencyFigures> {
    use tokio_tungstenite::tungstenite::Message;
    let dir = tempfile_dir()?;
    let station = bench_station(cfg, domain, &dir.join("latency.db"))?;
    let stop = CancellationToken::new();
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await?;
    let api = listener.local_addr()?;
    let console = tokio::spawn(shoal_console::serve_with(
        listener,
        station.handle(),
        shoal_console::ConsoleConfig {
            auth: shoal_console::AuthConfig::off(),
            ..shoal_console::ConsoleConfig::default()
        },
        stop.clone(),
    ));
    let task = tokio::spawn(station.run(stop.clone()));
    let (mut ws, _) = tokio_tungstenite::connect_async(format!("ws://{api}/api/ws"))
        .await
        .context("cannot open the console's live feed")?;
    // Secured as the station is (`bench security`), insecure otherwise.
    let mut swarm = helper(
        cfg,
        &[
            "swarm".into(),
            "--domain".into(),
            domain.to_string(),
            "--count".into(),
            vehicles.to_string(),
            "--rate".into(),
            rate.to_string(),
        ],
    )?;
    // Nothing is read from the helper's standard output; it must never block on it.
    if let Some(mut out) = swarm.stdout.take() {
        tokio::spawn(async move { tokio::io::copy(&mut out, &mut tokio::io::sink()).await });
    }
    eprintln!(
        "latency: {vehicles} vehicles x {rate} Hz -> station -> /api/ws{}; 5 s warm-up, then {seconds} s",
        if cfg.security.enabled {
            ", DDS Security on"
        } else {
            ""
        }
    );
    let mut figures = LatencyFigures::default();
    let mut started = None::<Instant>;
    let warm_up = Duration::from_secs(5);
    let total = Duration::from_secs(seconds + 5);
    let begin = Instant::now();
    loop {
        // The clock starts with the first vehicle update.
        if started.is_some_and(|t| t.elapsed() >= total) || begin.elapsed() > total * 3 {
            break;
        }
        let msg = match tokio::time::timeout(Duration::from_secs(1), ws.next()).await {
            Ok(Some(Ok(Message::Text(t)))) => t,
            Ok(Some(Ok(_))) | Err(_) => continue,
            Ok(Some(Err(e))) => bail!("live feed failed: {e}"),
            Ok(None) => bail!("live feed closed"),
        };
        let arrived = now_ms();
        let Ok(v) = serde_json::from_str::<serde_json::Value>(msg.as_str()) else {
            continue;
        };
        if v["type"] == "vehicle" {
            started.get_or_insert_with(Instant::now);
        }
        let measuring = started.is_some_and(|t| t.elapsed() >= warm_up);
        figures.count(&v, arrived, measuring);
    }
    drop(swarm.stdin.take());
    let _ = tokio::time::timeout(Duration::from_secs(15), swarm.wait()).await;
    stop.cancel();
    let _ = task.await;
    let _ = console.await;
    let _ = std::fs::remove_dir_all(&dir);
    figures.samples.sort_by(f64::total_cmp);
    Ok(figures)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn drops_count_apart_from_the_warm_up_and_sent_is_received_plus_dropped() {
        let mut f = LatencyFigures::default();
        let vehicle =
            serde_json::json!({"type": "vehicle", "data": {"latest": {"timestamp_ms": 1_000}}});
        let event = serde_json::json!({"type": "event", "data": {}});
        let lagged = |n: u64| serde_json::json!({"type": "lagged", "data": {"missed": n}});
        // Warm-up: nothing counts but the drops, apart.
        f.count(&vehicle, 1_003, false);
        f.count(&event, 1_003, false);
        f.count(&lagged(7), 1_003, false);
        assert_eq!((f.received, f.dropped, f.dropped_in_warm_up), (0, 0, 7));
        assert!(f.samples.is_empty());
        // Measured: every update received counts, vehicles are timed, drops add up.
        f.count(&vehicle, 1_004, true);
        f.count(&event, 1_004, true);
        f.count(&lagged(3), 1_004, true);
        f.count(&lagged(2), 1_004, true);
        f.count(&serde_json::json!({"no": "type"}), 1_004, true);
        assert_eq!((f.received, f.dropped, f.dropped_in_warm_up), (2, 5, 7));
        assert_eq!(f.samples, vec![4.0]);
        assert_eq!(f.sent(), 7);
    }
}
