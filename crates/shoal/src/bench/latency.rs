//! `shoal bench latency`: end to end, vehicle -> station -> console. N lightweight vehicles
//! in another process (`shoal swarm`, each state stamped when sent) and a WebSocket client
//! on the console's live feed, as the web console reads it; p50/p99 of arrival minus stamp.

use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use futures::StreamExt;
use shoal_model::now_ms;
use tokio_util::sync::CancellationToken;

use super::helpers::{bench_station, child, date, machine, percentile, tempfile_dir};
use crate::config::ShoalConfig;

/// What `bench latency` measures, in ms.
pub(super) struct LatencyFigures {
    pub(super) samples: Vec<f64>,
    pub(super) lagged: u64,
}

pub(super) async fn latency(
    cfg: &ShoalConfig,
    vehicles: usize,
    rate: f64,
    seconds: u64,
    domain: u16,
) -> Result<()> {
    let LatencyFigures { samples, lagged } =
        latency_figures(cfg, vehicles, rate, seconds, domain).await?;
    println!("# shoal bench latency — {} — {}", machine(), date());
    println!(
        "vehicle -> station -> console live feed, {vehicles} vehicles x {rate} Hz, {} updates in {seconds} s (missed by a slow client: {lagged})",
        samples.len()
    );
    println!(
        "latency p50 {:.0} ms, p99 {:.0} ms, max {:.0} ms (stamps have 1 ms resolution)",
        percentile(&samples, 50.0),
        percentile(&samples, 99.0),
        samples.last().copied().unwrap_or(f64::NAN)
    );
    Ok(())
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
    let count = vehicles.to_string();
    let rate_arg = rate.to_string();
    let mut swarm = child(&["swarm", "--count", &count, "--rate", &rate_arg], domain)?;
    eprintln!(
        "latency: {vehicles} vehicles x {rate} Hz -> station -> /api/ws; 5 s warm-up, then {seconds} s"
    );
    let mut samples: Vec<f64> = Vec::new();
    let (mut lagged, mut started) = (0u64, None::<Instant>);
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
        match v["type"].as_str() {
            Some("vehicle") => {
                let started = *started.get_or_insert_with(Instant::now);
                if started.elapsed() < Duration::from_secs(5) {
                    continue;
                }
                if let Some(stamp) = v["data"]["latest"]["timestamp_ms"].as_i64() {
                    #[allow(clippy::cast_precision_loss)]
                    samples.push((arrived - stamp) as f64);
                }
            }
            Some("lagged") => lagged += v["data"]["missed"].as_u64().unwrap_or(0),
            _ => {}
        }
    }
    drop(swarm.stdin.take());
    let _ = tokio::time::timeout(Duration::from_secs(15), swarm.wait()).await;
    stop.cancel();
    let _ = task.await;
    let _ = console.await;
    let _ = std::fs::remove_dir_all(&dir);
    samples.sort_by(f64::total_cmp);
    Ok(LatencyFigures { samples, lagged })
}
