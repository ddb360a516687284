//! `shoal bench late-joiner`: a station publishes a task, then a vehicle's participant
//! joins; does it get the task (transient-local durability)? Repeated with a new
//! participant each time, and timed.

use std::time::{Duration, Instant};

use anyhow::{Result, bail};
use futures::StreamExt;
use shoal_dds::{Priority, WriterOptions};
use shoal_model::now_ms;

use super::helpers::{date, dds, machine, percentile};
use crate::config::ShoalConfig;

pub(super) async fn late_joiner(cfg: &ShoalConfig, trials: usize, domain: u16) -> Result<()> {
    use shoal_model::{Task, TaskAssignment};
    let station = dds(cfg, domain)?;
    let w = station.writer::<TaskAssignment>(WriterOptions::new(Priority::Control))?;
    let mut delays = Vec::with_capacity(trials);
    let mut missed = Vec::new();
    println!("late joiner: {trials} trials, each a new participant joining after the task");
    for i in 0..trials {
        let id = format!("late-{i}");
        let task = TaskAssignment::new(&id, "m-late", "auv-late", now_ms(), &Task::Surface);
        w.write(task).await.map_err(|e| anyhow::anyhow!("{e}"))?;
        let t = Instant::now();
        let vehicle = dds(cfg, domain)?;
        let mut sub = vehicle.subscribe::<TaskAssignment>()?;
        let got = tokio::time::timeout(Duration::from_secs(15), async {
            while let Some(item) = sub.next().await {
                if matches!(&item, Ok((a, _)) if a.task_id == id) {
                    return true;
                }
            }
            false
        })
        .await
        .unwrap_or(false);
        if got {
            delays.push(t.elapsed().as_secs_f64() * 1e3);
        } else {
            missed.push(id);
        }
        if (i + 1) % 100 == 0 {
            println!("  {} trials, {} delivered", i + 1, delays.len());
        }
    }
    delays.sort_by(f64::total_cmp);
    println!("# shoal bench late-joiner — {} — {}", machine(), date());
    println!(
        "delivered {} of {trials}; join-to-task p50 {:.0} ms, p99 {:.0} ms, max {:.0} ms",
        delays.len(),
        percentile(&delays, 50.0),
        percentile(&delays, 99.0),
        delays.last().copied().unwrap_or(f64::NAN)
    );
    if !missed.is_empty() {
        bail!(
            "{} late joiners missed their task: {:?}",
            missed.len(),
            &missed[..missed.len().min(10)]
        );
    }
    Ok(())
}
