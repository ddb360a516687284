//! `shoal bench ingest`: station ingest rate from simulated vehicles in another process
//! (the hidden `load` helper), and loss.

use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use shoal_dds::{Priority, WriterOptions};
use shoal_model::{LinkKind, StateVector, VehicleAnnouncement, VehicleKind, now_ms};
use tokio::io::AsyncBufReadExt;
use tokio_util::sync::CancellationToken;

use super::helpers::{bench_station, date, dds, helper, machine, sample, tempfile_dir};
use crate::config::ShoalConfig;

pub(super) async fn load(
    cfg: &ShoalConfig,
    domain: u16,
    vehicles: usize,
    rate: f64,
    seconds: f64,
) -> Result<()> {
    let dds = dds(cfg, domain)?;
    let ann = dds.writer::<VehicleAnnouncement>(WriterOptions::new(Priority::Control))?;
    let w = dds.writer::<StateVector>(WriterOptions::new(Priority::Telemetry))?;
    let ids: Vec<String> = (0..vehicles).map(|i| format!("sim-{i}")).collect();
    for id in &ids {
        ann.write(VehicleAnnouncement {
            vehicle_id: id.clone(),
            name: id.clone(),
            kind: VehicleKind::Auv,
            vendor: "bench".into(),
            capabilities: vec![],
            sensors: vec![],
            links: vec![LinkKind::Ip],
            max_speed_mps: 2.0,
            timestamp_ms: now_ms(),
        })
        .await
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    }
    let t = Instant::now();
    while w.matched_readers() == 0 {
        if t.elapsed() > Duration::from_secs(30) {
            bail!("no station matched within 30 s");
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    // Let the station take the announcements and match both ways before the load.
    tokio::time::sleep(Duration::from_secs(2)).await;
    #[allow(
        clippy::cast_possible_truncation,
        clippy::cast_sign_loss,
        clippy::cast_precision_loss
    )]
    let total = (rate * seconds * vehicles as f64) as u64;
    let per_s = rate * {
        #[allow(clippy::cast_precision_loss)]
        let v = vehicles as f64;
        v
    };
    let t0 = Instant::now();
    let base = now_ms();
    for i in 0..total {
        #[allow(clippy::cast_precision_loss)]
        let due = Duration::from_secs_f64(i as f64 / per_s);
        if let Some(wait) = due.checked_sub(t0.elapsed())
            && wait > Duration::from_millis(1)
        {
            tokio::time::sleep(wait).await;
        }
        #[allow(clippy::cast_possible_truncation)]
        let v = (i % vehicles as u64) as usize;
        let mut s = sample(&ids[v], 0, 0);
        // Distinct timestamps per vehicle: the history's key is (vehicle, time).
        s.timestamp_ms = base + i64::try_from(i / vehicles as u64).unwrap_or(0);
        s.depth_m = 10.0;
        w.write(s).await.map_err(|e| anyhow::anyhow!("{e}"))?;
    }
    println!("sent {total} in {:.3} s", t0.elapsed().as_secs_f64());
    let stop = crate::daemons::shutdown_signal(true);
    stop.cancelled().await;
    Ok(())
}

/// What one ingest run measured.
pub(super) struct IngestFigures {
    pub(super) sent: u64,
    pub(super) accepted: u64,
    pub(super) rejected: u64,
    /// Validated, registered and queued for history, per second.
    pub(super) rate: f64,
    pub(super) committed: u64,
}

pub(super) async fn ingest(
    cfg: &ShoalConfig,
    domain: u16,
    vehicles: usize,
    rate: f64,
    seconds: f64,
) -> Result<()> {
    let f = ingest_figures(cfg, domain, vehicles, rate, seconds).await?;
    println!("# shoal bench ingest — {} — {}", machine(), date());
    println!(
        "vehicles {vehicles}, offered {:.0} state vectors/s for {seconds} s",
        rate * {
            #[allow(clippy::cast_precision_loss)]
            let v = vehicles as f64;
            v
        }
    );
    println!(
        "sent {}, accepted {}, rejected {}, lost {}",
        f.sent,
        f.accepted,
        f.rejected,
        f.sent.saturating_sub(f.accepted)
    );
    println!(
        "ingest rate (validated, registered, queued for history) {:.0} state vectors/s",
        f.rate
    );
    println!(
        "history committed {} records (state vectors + announcements)",
        f.committed
    );
    Ok(())
}

/// Runs the load and measures it (with DDS Security when `cfg.security` says so, the
/// load process included).
pub(super) async fn ingest_figures(
    cfg: &ShoalConfig,
    domain: u16,
    vehicles: usize,
    rate: f64,
    seconds: f64,
) -> Result<IngestFigures> {
    let dir = tempfile_dir()?;
    let station = bench_station(cfg, domain, &dir.join("ingest.db"))?;
    let h = station.handle();
    let stop = CancellationToken::new();
    let task = tokio::spawn(station.run(stop.clone()));
    eprintln!("ingest: {vehicles} vehicles × {rate} Hz for {seconds} s from another process...");
    let mut child = helper(
        cfg,
        &[
            "load".into(),
            "--domain".into(),
            domain.to_string(),
            "--vehicles".into(),
            vehicles.to_string(),
            "--rate".into(),
            rate.to_string(),
            "--seconds".into(),
            seconds.to_string(),
        ],
    )?;
    let stdout = child.stdout.take().context("no helper stdout")?;
    let mut lines = tokio::io::BufReader::new(stdout).lines();
    // Time the window from the first accepted state vector to the last.
    let mut first: Option<(Instant, u64)> = None;
    let mut sent = None;
    let mut last_change = (Instant::now(), 0u64);
    loop {
        tokio::select! {
            line = lines.next_line(), if sent.is_none() => {
                match line {
                    Ok(Some(l)) => if let Some(rest) = l.strip_prefix("sent ") {
                        sent = rest.split_whitespace().next().and_then(|n| n.parse::<u64>().ok());
                    },
                    _ => bail!("the load process ended without reporting"),
                }
            }
            () = tokio::time::sleep(Duration::from_millis(20)) => {}
        }
        let accepted = h.stats().states_accepted;
        if accepted > 0 && first.is_none() {
            first = Some((Instant::now(), accepted));
        }
        if accepted != last_change.1 {
            last_change = (Instant::now(), accepted);
        }
        if let Some(n) = sent
            && (accepted >= n || last_change.0.elapsed() > Duration::from_secs(5))
        {
            break;
        }
    }
    let stats = h.stats();
    let n = sent.unwrap_or(0);
    let (t_first, a_first) = first.unwrap_or((Instant::now(), 0));
    let window = last_change
        .0
        .duration_since(t_first)
        .as_secs_f64()
        .max(1e-9);
    #[allow(clippy::cast_precision_loss)]
    let ingest_rate = (stats.states_accepted.saturating_sub(a_first)) as f64 / window;
    let t = Instant::now();
    while h.history_committed() < stats.states_accepted + vehicles as u64
        && t.elapsed() < Duration::from_secs(30)
    {
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    drop(child);
    drop(h);
    stop.cancel();
    let report = task.await??;
    let _ = std::fs::remove_dir_all(&dir);
    Ok(IngestFigures {
        sent: n,
        accepted: stats.states_accepted,
        rejected: stats.total_rejected(),
        rate: ingest_rate,
        committed: report.history_committed,
    })
}
