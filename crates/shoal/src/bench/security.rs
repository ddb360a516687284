//! `shoal bench security`: what OMG DDS Security costs, secure beside insecure in one run
//! on one host. The state-vector round trip between two processes (p50, p99 and lost
//! round trips), and the time until one participant has heard N participants of another
//! process (when secured, each authenticated, its permissions checked and keys exchanged
//! with every other), ingest, and the vehicle → console latency at 1000 vehicles × 1 Hz
//! (their states from one participant with a station identity, as no vehicle's permissions
//! let one participant speak for a thousand vehicles; the cost per sample is the same).
//! A throwaway keystore is made for the run.

use std::collections::HashSet;
use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use futures::StreamExt;
use shoal_dds::{Credentials, DdsConfig, Priority, PubSub, TopicType, WriterOptions};
use shoal_model::StateVector;
use shoal_security::dds::{DdsKeystore, Grant};

use super::bus::{RoundTrip, round_trip};
use super::helpers::{date, helper, machine, percentile, sample};
use super::ingest::ingest_figures;
use super::latency::{LatencyFigures, latency_figures};
use crate::config::ShoalConfig;

fn now_s() -> i64 {
    shoal_model::now_ms().div_euclid(1000)
}

/// A participant on `domain`, secured with `grant`'s enclave of the keystore in `keystore`
/// (issued on first use) when given.
pub(super) fn participant(
    cfg: &ShoalConfig,
    domain: u16,
    keystore: Option<&Path>,
    grant: &Grant,
) -> Result<Arc<PubSub>> {
    let c = DdsConfig {
        domain_id: domain,
        ..cfg.dds.clone()
    };
    let Some(dir) = keystore else {
        return Ok(Arc::new(PubSub::new(&c).context("cannot join DDS")?));
    };
    let ks = DdsKeystore::open(dir, crate::keys::keystore_options(&cfg.security))?;
    let enclave = ks.issue_if_missing(grant, now_s())?;
    let credentials = match grant.vehicle_id() {
        Some(id) => Credentials::vehicle(enclave, id),
        None => Credentials::station(enclave),
    };
    Ok(Arc::new(
        PubSub::with_credentials(&c, credentials).context("cannot join DDS securely")?,
    ))
}

/// How long until a participant has heard every one of `n` participants in a helper
/// process (each publishing its own state), or `None` within `limit`.
async fn discovery(
    cfg: &ShoalConfig,
    domain: u16,
    keystore: Option<&Path>,
    n: usize,
    limit: Duration,
) -> Result<(Option<Duration>, usize)> {
    let station = participant(cfg, domain, keystore, &Grant::Station)?;
    let mut states = station.subscribe::<StateVector>()?;
    let mut args = vec![
        "crowd".to_string(),
        "--domain".into(),
        domain.to_string(),
        "--count".into(),
        n.to_string(),
    ];
    if let Some(k) = keystore {
        args.extend(["--keystore".to_string(), k.display().to_string()]);
    }
    let start = Instant::now();
    let _crowd = helper(cfg, &args)?;
    let mut heard = HashSet::new();
    while heard.len() < n {
        let Some(left) = limit.checked_sub(start.elapsed()) else {
            return Ok((None, heard.len()));
        };
        match tokio::time::timeout(left, states.next()).await {
            Ok(Some(Ok((s, _)))) => {
                heard.insert(s.vehicle_id.clone());
            }
            Ok(Some(Err(_))) => {}
            Ok(None) | Err(_) => return Ok((None, heard.len())),
        }
    }
    Ok((Some(start.elapsed()), heard.len()))
}

/// The helper of [`discovery`]: `count` participants, vehicles `crowd-1`..., each writing
/// its state every 200 ms until stdin closes. Secured, each authenticates and exchanges
/// keys with every other participant on its own.
pub(super) async fn crowd(
    cfg: &ShoalConfig,
    domain: u16,
    count: usize,
    keystore: Option<&Path>,
) -> Result<()> {
    let mut writers = Vec::new();
    let mut keep = Vec::new();
    for i in 1..=count {
        let id = format!("crowd-{i}");
        // One identity for the whole crowd: Cyclone refuses endpoints of a second identity
        // in the same process (one vehicle, one process, as deployed).
        let p = participant(cfg, domain, keystore, &Grant::Station)?;
        writers.push((
            id,
            p.writer::<StateVector>(WriterOptions::new(Priority::Telemetry))?,
        ));
        keep.push(p);
    }
    let stop = crate::daemons::shutdown_signal(true);
    let mut seq = 0;
    loop {
        seq += 1;
        for (id, w) in &writers {
            let _ = w.write(sample(id, seq, 0)).await;
        }
        tokio::select! {
            () = stop.cancelled() => return Ok(()),
            () = tokio::time::sleep(Duration::from_millis(200)) => {}
        }
    }
}

fn ms(d: Option<Duration>) -> String {
    d.map_or_else(
        || "not all".into(),
        |d| format!("{:.0} ms", d.as_secs_f64() * 1e3),
    )
}

/// Runs the comparison and prints the table.
pub(super) async fn security(
    cfg: &ShoalConfig,
    domain: u16,
    seconds: u64,
    participants: usize,
) -> Result<()> {
    let tmp = std::env::temp_dir().join(format!("shoal-bench-security-{}", std::process::id()));
    let dir = tmp.join("dds");
    // The governance configured in [security.governance], so what is measured is what
    // would be deployed (e.g. telemetry only signed); the round trip's own topics get
    // the protection state vectors have.
    let mut options = crate::keys::keystore_options(&cfg.security);
    let state = options.governance.protection_of(StateVector::TOPIC);
    for topic in [super::bus::PING, super::bus::PONG] {
        options.governance.topics.insert(topic.to_string(), state);
    }
    DdsKeystore::create(&dir, options, now_s())?;
    let result = compare(cfg, domain, seconds, participants, &tmp).await;
    let _ = std::fs::remove_dir_all(&tmp);
    result
}

async fn compare(
    cfg: &ShoalConfig,
    domain: u16,
    seconds: u64,
    participants: usize,
    store: &Path,
) -> Result<()> {
    let dir = &crate::keys::dds_dir(store);
    let secure_cfg = ShoalConfig {
        security: crate::config::SecurityConfig {
            enabled: true,
            store: store.to_path_buf(),
            ..cfg.security.clone()
        },
        ..cfg.clone()
    };
    eprintln!("security: {seconds} s of round trips, insecure...");
    let plain: RoundTrip = round_trip(cfg, domain, seconds, None).await?;
    eprintln!(
        "security: {seconds} s of round trips, secured ({})...",
        cfg.security.governance
    );
    let secure: RoundTrip = round_trip(cfg, domain + 1, seconds, Some(dir)).await?;
    // Participants with identities from another CA keep trying to authenticate on the
    // same domain: the secured round trip must go on, unstarved.
    let rogue_store = store.join("rogue");
    let rogue = crate::keys::dds_dir(&rogue_store);
    DdsKeystore::create(
        &rogue,
        crate::keys::keystore_options(&cfg.security),
        now_s(),
    )?;
    let rogues = 50;
    eprintln!(
        "security: {seconds} s of secured round trips while {rogues} participants from another CA try to join..."
    );
    let crowd = helper(
        cfg,
        &[
            "crowd".to_string(),
            "--domain".into(),
            (domain + 1).to_string(),
            "--count".into(),
            rogues.to_string(),
            "--keystore".into(),
            rogue.display().to_string(),
        ],
    )?;
    tokio::time::sleep(Duration::from_secs(2)).await;
    let besieged: RoundTrip = round_trip(cfg, domain + 1, seconds, Some(dir)).await?;
    drop(crowd);
    let limit = Duration::from_secs(60);
    eprintln!("security: {participants} participants discovered, insecure...");
    let (plain_disc, plain_heard) = discovery(cfg, domain + 2, None, participants, limit).await?;
    eprintln!("security: {participants} participants discovered, secured...");
    let (secure_disc, secure_heard) =
        discovery(cfg, domain + 3, Some(dir), participants, limit).await?;
    let (vehicles, rate, load_s) = (100, 250.0, 5.0);
    eprintln!("security: ingest, {vehicles} vehicles × {rate} Hz for {load_s} s, insecure...");
    let plain_ingest = ingest_figures(cfg, domain + 4, vehicles, rate, load_s).await?;
    eprintln!("security: ingest, secured...");
    let secure_ingest = ingest_figures(&secure_cfg, domain + 5, vehicles, rate, load_s).await?;
    let (fleet, fleet_rate, latency_s) = (1000, 1.0, seconds.max(10));
    eprintln!(
        "security: vehicle -> console latency, {fleet} vehicles × {fleet_rate} Hz for {latency_s} s, insecure..."
    );
    let plain_latency = latency_figures(cfg, fleet, fleet_rate, latency_s, domain + 6).await?;
    eprintln!("security: vehicle -> console latency, secured...");
    let secure_latency =
        latency_figures(&secure_cfg, fleet, fleet_rate, latency_s, domain + 7).await?;

    println!("# shoal bench security — {} — {}", machine(), date());
    println!("# governance: {}", cfg.security.governance);
    println!(
        "{:<44} {:>14} {:>14} {:>8}  target",
        "figure", "insecure", "secure", "ratio"
    );
    let ratio = |s: f64, p: f64| format!("{:.2}×", s / p);
    println!(
        "{:<44} {:>14} {:>14} {:>8}  secure ≤ 1.5× insecure",
        "bus round trip p50",
        format!("{:.0} µs", plain.p50_us),
        format!("{:.0} µs", secure.p50_us),
        ratio(secure.p50_us, plain.p50_us)
    );
    println!(
        "{:<44} {:>14} {:>14} {:>8}",
        "bus round trip p99",
        format!("{:.0} µs", plain.p99_us),
        format!("{:.0} µs", secure.p99_us),
        ratio(secure.p99_us, plain.p99_us)
    );
    println!(
        "{:<44} {:>14} {:>14}",
        "round trips (lost)",
        format!("{} ({})", plain.count, plain.lost),
        format!("{} ({})", secure.count, secure.lost)
    );
    println!(
        "{:<44} {:>14} {:>14} {:>8}  no loss",
        format!("  p50 with {rogues} other-CA participants joining"),
        "-",
        format!("{:.0} µs", besieged.p50_us),
        ratio(besieged.p50_us, secure.p50_us)
    );
    println!(
        "{:<44} {:>14} {:>14}",
        format!("  round trips (lost) with {rogues} joining"),
        "-",
        format!("{} ({})", besieged.count, besieged.lost)
    );
    println!(
        "{:<44} {:>14} {:>14} {:>8}  secure ≤ 10 s",
        format!("{participants} participants heard by one"),
        ms(plain_disc),
        ms(secure_disc),
        match (plain_disc, secure_disc) {
            (Some(p), Some(s)) => ratio(s.as_secs_f64(), p.as_secs_f64()),
            _ => "-".into(),
        }
    );
    println!(
        "{:<44} {:>14} {:>14} {:>8}  secure ≥ 0.5× insecure",
        format!("ingest ({vehicles} vehicles × {rate} Hz offered)"),
        format!("{:.0} /s", plain_ingest.rate),
        format!("{:.0} /s", secure_ingest.rate),
        ratio(secure_ingest.rate, plain_ingest.rate)
    );
    println!(
        "{:<44} {:>14} {:>14}",
        "  sent / accepted",
        format!("{} / {}", plain_ingest.sent, plain_ingest.accepted),
        format!("{} / {}", secure_ingest.sent, secure_ingest.accepted)
    );
    let p99 = |f: &LatencyFigures| percentile(&f.samples, 99.0);
    println!(
        "{:<44} {:>14} {:>14} {:>8}  secure ≤ 5 ms, none dropped",
        format!("vehicle → console p99 ({fleet} × {fleet_rate} Hz)"),
        format!("{:.0} ms", p99(&plain_latency)),
        format!("{:.0} ms", p99(&secure_latency)),
        ratio(p99(&secure_latency), p99(&plain_latency))
    );
    println!(
        "{:<44} {:>14} {:>14}",
        "  p50",
        format!("{:.0} ms", percentile(&plain_latency.samples, 50.0)),
        format!("{:.0} ms", percentile(&secure_latency.samples, 50.0))
    );
    println!(
        "{:<44} {:>14} {:>14}",
        "  updates timed / sent / dropped",
        format!(
            "{} / {} / {}",
            plain_latency.samples.len(),
            plain_latency.sent(),
            plain_latency.dropped
        ),
        format!(
            "{} / {} / {}",
            secure_latency.samples.len(),
            secure_latency.sent(),
            secure_latency.dropped
        )
    );
    if secure_disc.is_none() || plain_disc.is_none() {
        println!(
            "(heard within {} s: {plain_heard} insecure, {secure_heard} secured of {participants})",
            limit.as_secs()
        );
    }
    Ok(())
}
