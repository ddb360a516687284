//! `shoal bench soak`: resident memory before, during and after many writes (writer and
//! reader in this process).

use std::sync::Arc;
use std::time::Duration;

use anyhow::Result;
use futures::StreamExt;
use shoal_dds::{Priority, WriterOptions};
use shoal_model::StateVector;
use tokio_util::sync::CancellationToken;

use super::helpers::{THROUGHPUT, date, dds, machine, rss_mb, sample};
use crate::config::ShoalConfig;

pub(super) async fn soak(
    cfg: &ShoalConfig,
    domain: u16,
    writes: u64,
    instances: u32,
) -> Result<()> {
    let a = dds(cfg, domain)?;
    let b = dds(cfg, domain)?;
    let w = a.writer_on::<StateVector>(THROUGHPUT, WriterOptions::new(Priority::Telemetry))?;
    let mut sub = b.subscribe_on::<StateVector>(THROUGHPUT)?;
    let received = Arc::new(std::sync::atomic::AtomicU64::new(0));
    let r = Arc::clone(&received);
    let stop = CancellationToken::new();
    let s = stop.clone();
    let reader = tokio::spawn(async move {
        loop {
            tokio::select! {
                () = s.cancelled() => return,
                item = sub.next() => if let Some(Ok(_)) = item {
                    r.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                }
            }
        }
    });
    tokio::time::sleep(Duration::from_secs(2)).await;
    let keys: Vec<String> = (0..instances.max(1)).map(|i| format!("v{i}")).collect();
    println!("# shoal bench soak — {} — {}", machine(), date());
    println!("{:>10} {:>10} {:>9}", "writes", "received", "RSS MB");
    println!("{:>10} {:>10} {:>9.1}", 0, 0, rss_mb());
    let before = rss_mb();
    let report_every = (writes / 10).max(1);
    for i in 0..writes {
        #[allow(clippy::cast_possible_truncation)]
        let key = &keys[(i % keys.len() as u64) as usize];
        w.write(sample(key, i, 0))
            .await
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        if i % 200 == 199 {
            // About 20k writes/s: a heavy but sustainable telemetry load.
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        if (i + 1) % report_every == 0 {
            println!(
                "{:>10} {:>10} {:>9.1}",
                i + 1,
                received.load(std::sync::atomic::Ordering::Relaxed),
                rss_mb()
            );
        }
    }
    tokio::time::sleep(Duration::from_secs(5)).await;
    let after = rss_mb();
    println!(
        "after 5 s idle: received {} of {writes}, RSS {after:.1} MB (start {before:.1} MB, growth {:.1} MB)",
        received.load(std::sync::atomic::Ordering::Relaxed),
        after - before
    );
    stop.cancel();
    let _ = reader.await;
    Ok(())
}
