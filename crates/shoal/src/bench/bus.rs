//! `shoal bench bus`: state-vector round trip (p50/p99) and the highest reliable rate
//! delivered without loss, between two processes, with Cyclone DDS's `ddsperf` measured in
//! the same run on the same host and the ratios printed. `pong` and `sink` are its helper
//! processes (hidden subcommands of the same binary), so each side is its own participant.

use std::process::Stdio;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use futures::StreamExt;
use shoal_dds::{Priority, WriterOptions};
use shoal_model::StateVector;
use tokio::io::AsyncBufReadExt;

use super::helpers::{THROUGHPUT, date, dds, helper, machine, percentile, sample, seq_of};
use crate::config::ShoalConfig;

pub(super) const PING: &str = "shoal/bench/ping";
pub(super) const PONG: &str = "shoal/bench/pong";

pub(super) struct RoundTrip {
    pub(super) p50_us: f64,
    pub(super) p99_us: f64,
    pub(super) count: usize,
    /// Pings whose pong did not come back within 2 s.
    pub(super) lost: usize,
}

async fn shoal_round_trip(cfg: &ShoalConfig, domain: u16, seconds: u64) -> Result<RoundTrip> {
    round_trip(cfg, domain, seconds, None).await
}

/// Round trips between this process and a `pong` helper, both secured with station
/// identities from the DDS Security keystore in `keystore` when given.
pub(super) async fn round_trip(
    cfg: &ShoalConfig,
    domain: u16,
    seconds: u64,
    keystore: Option<&std::path::Path>,
) -> Result<RoundTrip> {
    let dds =
        super::security::participant(cfg, domain, keystore, &shoal_security::dds::Grant::Station)?;
    let ping = dds.writer_on::<StateVector>(PING, WriterOptions::new(Priority::Telemetry))?;
    let mut pongs = dds.subscribe_on::<StateVector>(PONG)?;
    let mut args = vec!["pong".to_string(), "--domain".into(), domain.to_string()];
    if let Some(k) = keystore {
        args.extend(["--keystore".to_string(), k.display().to_string()]);
    }
    let _child = helper(cfg, &args)?;
    // Discovery first: ping until one comes back.
    let start = Instant::now();
    let mut seq = 0u64;
    loop {
        seq += 1;
        ping.write(sample("ping", seq, 0))
            .await
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        if let Ok(Some(Ok(_))) =
            tokio::time::timeout(Duration::from_millis(200), pongs.next()).await
        {
            break;
        }
        if start.elapsed() > Duration::from_secs(30) {
            bail!("the pong process did not answer within 30 s");
        }
    }
    while let Ok(Some(_)) = tokio::time::timeout(Duration::from_millis(300), pongs.next()).await {}
    let mut rtts = Vec::new();
    let mut sent = 0usize;
    let end = Instant::now() + Duration::from_secs(seconds);
    while Instant::now() < end {
        seq += 1;
        sent += 1;
        let t0 = Instant::now();
        ping.write(sample("ping", seq, 0))
            .await
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        loop {
            match tokio::time::timeout(Duration::from_secs(2), pongs.next()).await {
                Ok(Some(Ok((s, _)))) if seq_of(&s) == seq => {
                    rtts.push(t0.elapsed().as_secs_f64() * 1e6);
                    break;
                }
                Ok(Some(_)) => {}
                Ok(None) => bail!("pong stream ended"),
                Err(_) => break, // lost: counted by its absence
            }
        }
    }
    rtts.sort_by(f64::total_cmp);
    Ok(RoundTrip {
        p50_us: percentile(&rtts, 50.0),
        p99_us: percentile(&rtts, 99.0),
        count: rtts.len(),
        lost: sent - rtts.len(),
    })
}

pub(super) async fn pong(
    cfg: &ShoalConfig,
    domain: u16,
    keystore: Option<&std::path::Path>,
) -> Result<()> {
    let dds =
        super::security::participant(cfg, domain, keystore, &shoal_security::dds::Grant::Station)?;
    let w = dds.writer_on::<StateVector>(PONG, WriterOptions::new(Priority::Telemetry))?;
    let mut pings = dds.subscribe_on::<StateVector>(PING)?;
    let stop = crate::daemons::shutdown_signal(true);
    loop {
        tokio::select! {
            () = stop.cancelled() => return Ok(()),
            item = pings.next() => match item {
                Some(Ok((s, _))) => { let _ = w.write(s.into_inner()).await; }
                Some(Err(_)) => {}
                None => return Ok(()),
            }
        }
    }
}

/// Highest offered rate (samples/s) delivered whole, stepping the rate up.
async fn shoal_throughput(cfg: &ShoalConfig, domain: u16) -> Result<(f64, Vec<(f64, u64, u64)>)> {
    let dds = dds(cfg, domain)?;
    let w = dds.writer_on::<StateVector>(THROUGHPUT, WriterOptions::new(Priority::Telemetry))?;
    let mut child = helper(cfg, &["sink".into(), "--domain".into(), domain.to_string()])?;
    let stdout = child.stdout.take().context("no helper stdout")?;
    let mut lines = tokio::io::BufReader::new(stdout).lines();
    let keys: Vec<String> = (0..100).map(|i| format!("v{i}")).collect();
    // Warm-up step 0 until the sink reports it is receiving.
    let t = Instant::now();
    let mut seq = 0u64;
    loop {
        seq += 1;
        w.write(sample(&keys[0], seq, 0))
            .await
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        if let Ok(Ok(Some(l))) =
            tokio::time::timeout(Duration::from_millis(200), lines.next_line()).await
            && l.starts_with("ready")
        {
            break;
        }
        if t.elapsed() > Duration::from_secs(30) {
            bail!("the sink process did not start receiving within 30 s");
        }
    }
    let mut results = Vec::new();
    let mut best = 0.0;
    for (step, rate) in [
        1_000.0, 2_000.0, 5_000.0, 10_000.0, 20_000.0, 40_000.0, 80_000.0, 120_000.0, 160_000.0,
        240_000.0,
    ]
    .into_iter()
    .enumerate()
    {
        let step = u32::try_from(step + 1).unwrap_or(u32::MAX);
        #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
        let n = (rate * 2.0) as u64;
        let t0 = Instant::now();
        for i in 0..n {
            // Pace in 1 ms slices so the offered rate is the stated one.
            #[allow(clippy::cast_precision_loss)]
            let due = Duration::from_secs_f64(i as f64 / rate);
            if let Some(wait) = due.checked_sub(t0.elapsed())
                && wait > Duration::from_millis(1)
            {
                tokio::time::sleep(wait).await;
            }
            seq += 1;
            #[allow(clippy::cast_possible_truncation)]
            let key = &keys[(i % 100) as usize];
            w.write(sample(key, seq, step))
                .await
                .map_err(|e| anyhow::anyhow!("{e}"))?;
        }
        let achieved = {
            #[allow(clippy::cast_precision_loss)]
            let a = n as f64 / t0.elapsed().as_secs_f64();
            a
        };
        // Marker samples of a closing step end this one at the sink; several, on their own
        // instance, so a marker is never the sample a keep-last history drops.
        tokio::time::sleep(Duration::from_millis(500)).await;
        let mut received = None;
        for _ in 0..50 {
            seq += 1;
            w.write(sample("marker", seq, step + 1000))
                .await
                .map_err(|e| anyhow::anyhow!("{e}"))?;
            if let Ok(Ok(Some(l))) =
                tokio::time::timeout(Duration::from_millis(200), lines.next_line()).await
                && let Some(rest) = l.strip_prefix(&format!("step {step} "))
            {
                received = rest.trim().parse::<u64>().ok();
                break;
            }
        }
        // No report in 10 s: the reader fell behind and lost samples the writer's
        // keep-last history had already replaced.
        let received = received.unwrap_or(0);
        results.push((achieved, n, received));
        if received == n && achieved >= rate * 0.9 {
            best = achieved;
        } else {
            break;
        }
    }
    Ok((best, results))
}

pub(super) async fn sink(cfg: &ShoalConfig, domain: u16) -> Result<()> {
    let dds = dds(cfg, domain)?;
    let mut sub = dds.subscribe_on::<StateVector>(THROUGHPUT)?;
    let stop = crate::daemons::shutdown_signal(true);
    let mut counts = std::collections::BTreeMap::<u32, u64>::new();
    let mut ready = false;
    let mut reported = std::collections::BTreeSet::new();
    loop {
        tokio::select! {
            () = stop.cancelled() => return Ok(()),
            item = sub.next() => match item {
                Some(Ok((s, _))) => {
                    #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
                    let step = s.depth_m as u32;
                    if step == 0 && !ready {
                        ready = true;
                        println!("ready");
                    }
                    if step >= 1000 {
                        let closed = step - 1000;
                        if reported.insert(closed) {
                            println!("step {closed} {}", counts.get(&closed).copied().unwrap_or(0));
                        }
                    } else {
                        *counts.entry(step).or_default() += 1;
                    }
                }
                Some(Err(_)) => {}
                None => return Ok(()),
            }
        }
    }
}

pub(super) struct PerfResult {
    pub(super) p50_us: f64,
    pub(super) p99_us: f64,
    pub(super) throughput: f64,
}

/// Runs a ddsperf process with `args`, and with `uri` as its CYCLONEDDS_URI if given.
fn ddsperf_process(args: Vec<String>, uri: Option<&str>) -> Result<tokio::process::Child> {
    let mut cmd = tokio::process::Command::new("ddsperf");
    cmd.args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .kill_on_drop(true);
    if let Some(uri) = uri {
        cmd.env("CYCLONEDDS_URI", uri);
    }
    cmd.spawn()
        .context("cannot run ddsperf (Debian package cyclonedds-tools)")
}

/// ddsperf's ping/pong round trip with 96-byte payloads (the size of a Shoal state
/// vector): median of its per-second p50 and p99 lines, µs.
///
/// ddsperf prints half the round trip (`(tnow - source_timestamp) / 2` in `ddsperf.c`'s
/// pong handling: a one-way estimate), so its figures are doubled here to compare round
/// trip with round trip. Its count of pongs per second agrees: at a printed 38 µs, about
/// 13,000 round trips a second, one every 75 µs.
async fn ddsperf_ping(domain: u16, seconds: u64, uri: Option<&str>) -> Result<(f64, f64)> {
    let d = domain.to_string();
    let _pong = ddsperf_process(
        vec![
            "-i".into(),
            d.clone(),
            "-D".into(),
            (seconds + 5).to_string(),
            "pong".into(),
        ],
        uri,
    )?;
    tokio::time::sleep(Duration::from_millis(500)).await;
    let ping = ddsperf_process(
        vec![
            "-i".into(),
            d,
            "-D".into(),
            seconds.to_string(),
            "ping".into(),
            "size".into(),
            "96".into(),
        ],
        uri,
    )?
    .wait_with_output()
    .await?;
    let out = String::from_utf8_lossy(&ping.stdout);
    let (mut p50s, mut p99s) = (Vec::new(), Vec::new());
    for line in out.lines().filter(|l| l.contains(" 50% ")) {
        let field = |name: &str| {
            line.split_whitespace()
                .skip_while(|w| *w != name)
                .nth(1)
                .and_then(|v| v.trim_end_matches("us").parse::<f64>().ok())
        };
        if let (Some(a), Some(b)) = (field("50%"), field("99%")) {
            p50s.push(a);
            p99s.push(b);
        }
    }
    if p50s.is_empty() {
        bail!("ddsperf ping printed no latency figures");
    }
    p50s.sort_by(f64::total_cmp);
    p99s.sort_by(f64::total_cmp);
    Ok((2.0 * percentile(&p50s, 50.0), 2.0 * percentile(&p99s, 50.0)))
}

/// Cyclone DDS's ddsperf, same host, same namespace, its default configuration: ping/pong
/// with 96-byte payloads, then pub/sub throughput.
async fn ddsperf(domain: u16, seconds: u64) -> Result<PerfResult> {
    let run = |args: Vec<String>| ddsperf_process(args, None);
    let (p50, p99) = ddsperf_ping(domain, seconds, None).await?;
    let d2 = (domain + 1).to_string();
    let sub = run(vec![
        "-i".into(),
        d2.clone(),
        "-D".into(),
        (seconds.min(5) + 3).to_string(),
        "sub".into(),
    ])?;
    tokio::time::sleep(Duration::from_millis(500)).await;
    let _ = run(vec![
        "-i".into(),
        d2,
        "-D".into(),
        seconds.min(5).to_string(),
        "pub".into(),
        "size".into(),
        "96".into(),
    ])?
    .wait()
    .await?;
    let out = sub.wait_with_output().await?;
    let text = String::from_utf8_lossy(&out.stdout);
    let mut rates: Vec<f64> = text
        .lines()
        .filter(|l| l.contains(" rate ") && l.contains("lost 0"))
        .filter_map(|l| {
            l.split_whitespace()
                .skip_while(|w| *w != "rate")
                .nth(1)
                .and_then(|v| v.parse::<f64>().ok())
        })
        .filter(|r| *r > 0.0)
        .map(|k| k * 1000.0)
        .collect();
    rates.sort_by(f64::total_cmp);
    Ok(PerfResult {
        p50_us: p50,
        p99_us: p99,
        throughput: percentile(&rates, 50.0),
    })
}

/// What `bench bus` measures.
pub(super) struct BusFigures {
    pub(super) rt: RoundTrip,
    pub(super) throughput: f64,
    pub(super) steps: Vec<(f64, u64, u64)>,
    pub(super) peer: Option<PerfResult>,
    /// ddsperf's round trip (p50, p99) with the Cyclone configuration Shoal uses.
    pub(super) peer_shoal_transport: Option<(f64, f64)>,
}

pub(super) async fn bus_figures(
    cfg: &ShoalConfig,
    domain: u16,
    seconds: u64,
    no_peer: bool,
) -> Result<BusFigures> {
    eprintln!(
        "bus: {seconds} s of Shoal round trips (Cyclone DDS, two processes, state vectors)..."
    );
    let rt = shoal_round_trip(cfg, domain, seconds).await?;
    eprintln!("bus: Shoal throughput, stepping the offered rate up until samples are lost...");
    let (thr, steps) = shoal_throughput(cfg, domain + 3).await?;
    let peer = if no_peer {
        None
    } else {
        eprintln!("bus: Cyclone DDS ddsperf, same host, {seconds} s...");
        match ddsperf(domain + 1, seconds).await {
            Ok(p) => Some(p),
            Err(e) => {
                eprintln!("bus: ddsperf not measured: {e:#}");
                None
            }
        }
    };
    let peer_shoal_transport = if no_peer {
        None
    } else {
        eprintln!("bus: ddsperf again with Shoal's Cyclone configuration, {seconds} s...");
        let uri = shoal_dds::cyclone_config(&cfg.dds);
        match ddsperf_ping(domain + 1, seconds, Some(&uri)).await {
            Ok(p) => Some(p),
            Err(e) => {
                eprintln!("bus: ddsperf (Shoal's configuration) not measured: {e:#}");
                None
            }
        }
    };
    Ok(BusFigures {
        rt,
        throughput: thr,
        steps,
        peer,
        peer_shoal_transport,
    })
}

pub(super) async fn bus(cfg: &ShoalConfig, domain: u16, seconds: u64, no_peer: bool) -> Result<()> {
    let BusFigures {
        rt,
        throughput: thr,
        steps,
        peer,
        peer_shoal_transport,
    } = bus_figures(cfg, domain, seconds, no_peer).await?;
    println!("# shoal bench bus — {} — {}", machine(), date());
    println!(
        "{:<38} {:>12} {:>14} {:>9}",
        "figure", "Shoal", "Cyclone DDS", "ratio"
    );
    let row = |name: &str, ours: f64, theirs: Option<f64>, unit: &str| {
        let t = theirs.map_or_else(|| "-".to_string(), |v| format!("{v:.1} {unit}"));
        let r = theirs.map_or_else(|| "-".to_string(), |v| format!("{:.2}×", ours / v));
        println!(
            "{name:<38} {:>12} {t:>14} {r:>9}",
            format!("{ours:.1} {unit}")
        );
    };
    row(
        "round trip p50",
        rt.p50_us,
        peer.as_ref().map(|p| p.p50_us),
        "µs",
    );
    row(
        "round trip p99",
        rt.p99_us,
        peer.as_ref().map(|p| p.p99_us),
        "µs",
    );
    row(
        "round trip p50, ddsperf as Shoal's config",
        rt.p50_us,
        peer_shoal_transport.map(|p| p.0),
        "µs",
    );
    row(
        "reliable throughput, no loss",
        thr / 1000.0,
        peer.as_ref().map(|p| p.throughput / 1000.0),
        "k/s",
    );
    println!("round trips measured: {}", rt.count);
    for (achieved, sent, received) in steps {
        println!(
            "  offered {:>8.0}/s  sent {sent:>7}  received {received:>7}",
            achieved
        );
    }
    println!("(ratio = Shoal / Cyclone: below 1 is better for latency, above 1 for throughput;");
    println!(" ddsperf runs with its default configuration, and once more for the round trip with");
    println!(" the Cyclone configuration Shoal uses (interfaces, multicast for discovery only);");
    println!(
        " Cyclone throughput is ddsperf pub/sub with its own 96-byte type, keep-last, reliable)"
    );
    Ok(())
}
