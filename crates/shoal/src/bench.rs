//! `shoal bench`: programs that print figures (never timed tests).
//!
//! - `bus`: state-vector round trip (p50/p99) and the highest reliable rate delivered
//!   without loss, between two processes, with Cyclone DDS's `ddsperf` measured in the
//!   same run on the same host and the ratios printed.
//! - `ingest`: station ingest rate from simulated vehicles in another process, and loss.
//! - `soak`: resident memory before, during and after many writes.
//! - `pipeline`: the station's Data Access Manager in one process (validation,
//!   plausibility, latest state, semantic model with 10 rules, history commit) against a
//!   raw batched SQLite insert of the same rows in the same run.
//!
//! Helper processes (`pong`, `sink`, `load`) are hidden subcommands of the same binary so
//! the two sides of each measurement are separate DDS participants, as in deployment.

use std::process::Stdio;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Subcommand;
use futures::StreamExt;
use shoal_dds::{DdsConfig, Priority, PubSub, WriterOptions};
use shoal_history::{History, HistoryConfig};
use shoal_model::{LinkKind, StateVector, VehicleAnnouncement, VehicleKind, now_ms};
use shoal_station::{Station, StationConfig};
use tokio::io::AsyncBufReadExt;
use tokio_util::sync::CancellationToken;

use crate::config::ShoalConfig;

const PING: &str = "shoal/bench/ping";
const PONG: &str = "shoal/bench/pong";
const THROUGHPUT: &str = "shoal/bench/throughput";

/// Which benchmark to run.
#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// Round trip and throughput of the bus, side by side with Cyclone DDS's ddsperf.
    Bus {
        /// Seconds of round trips for each implementation.
        #[arg(long, default_value_t = 10)]
        seconds: u64,
        /// DDS domain for the measurement (ddsperf uses the next two).
        #[arg(long, default_value_t = 80)]
        domain: u16,
        /// Skip the ddsperf comparison.
        #[arg(long)]
        no_peer: bool,
    },
    /// Station ingest: simulated vehicles in another process publish state vectors.
    Ingest {
        /// Number of vehicles.
        #[arg(long, default_value_t = 100)]
        vehicles: usize,
        /// State vectors per second per vehicle.
        #[arg(long, default_value_t = 250.0)]
        rate: f64,
        /// Seconds of load.
        #[arg(long, default_value_t = 10.0)]
        seconds: f64,
        /// DDS domain for the measurement.
        #[arg(long, default_value_t = 83)]
        domain: u16,
    },
    /// The Data Access Manager without the bus: validate + plausibility + latest state +
    /// semantic model with 10 rules + history commit, against a raw batched SQLite insert
    /// of the same rows in the same run.
    Pipeline {
        /// Number of vehicles.
        #[arg(long, default_value_t = 1000)]
        vehicles: usize,
        /// State vectors in all.
        #[arg(long, default_value_t = 500_000)]
        rows: usize,
        /// DDS domain of the station's (idle) participant.
        #[arg(long, default_value_t = 85)]
        domain: u16,
    },
    /// Resident memory before, during and after N writes (writer and reader in this process).
    Soak {
        /// Number of state vectors to write.
        #[arg(long, default_value_t = 300_000)]
        writes: u64,
        /// Instances (vehicle ids) the writes cycle through.
        #[arg(long, default_value_t = 100)]
        instances: u32,
        /// DDS domain for the measurement.
        #[arg(long, default_value_t = 84)]
        domain: u16,
    },
    /// The acoustic link against its goals: PDU sizes vs DCCL (20 B) and SWARMs (51 B),
    /// channel use under saturation, emergency latency under load, control delivery at
    /// 30 % packet loss. Emulated modems on 127.0.0.1; figures in simulated time.
    Acoustic {
        /// Wall-clock seconds per simulated second (smaller is faster).
        #[arg(long, default_value_t = 0.05)]
        time_scale: f64,
    },
    /// Scale: a `shoal station` and N lightweight vehicles (`shoal swarm`), each its own
    /// process, on loopback: vehicles alive, ingest rate and the resident memory of both
    /// processes, every 10 s and at the end.
    Scale {
        /// Number of vehicles.
        #[arg(long, default_value_t = 10_000)]
        vehicles: usize,
        /// State vectors per second per vehicle.
        #[arg(long, default_value_t = 1.0)]
        rate: f64,
        /// Seconds to run once every vehicle is alive (or after 120 s of trying).
        #[arg(long, default_value_t = 60)]
        seconds: u64,
        /// DDS domain for the measurement.
        #[arg(long, default_value_t = 24)]
        domain: u16,
    },
    /// Every figure of the targets in one run and one table, each beside the peer
    /// measured in the same run (Cyclone DDS ddsperf, a raw batched SQLite insert, DCCL's
    /// published size) and its target; saved as Markdown under `--out`.
    Suite {
        /// Seconds of round trips (and of latency measurement) per figure.
        #[arg(long, default_value_t = 10)]
        seconds: u64,
        /// Vehicles of the scale figure.
        #[arg(long, default_value_t = 10_000)]
        scale_vehicles: usize,
        /// Directory the Markdown report is written to.
        #[arg(long, default_value = "bench/runs")]
        out: std::path::PathBuf,
        /// First DDS domain (the suite uses the next eight).
        #[arg(long, default_value_t = 30)]
        domain: u16,
        /// Simulated seconds of fleet traffic through the semantic store before the
        /// queries are measured again (0 skips it; an hour takes about 2 minutes).
        #[arg(long, default_value_t = 3600)]
        semantic_hour_s: u64,
    },
    /// End-to-end latency, vehicle -> station -> console: N lightweight vehicles in another
    /// process (`shoal swarm`, each state stamped when sent) and a WebSocket client on the
    /// console's live feed, as the web console reads it; p50/p99 of arrival minus stamp.
    Latency {
        /// Number of vehicles.
        #[arg(long, default_value_t = 1000)]
        vehicles: usize,
        /// State vectors per second per vehicle.
        #[arg(long, default_value_t = 1.0)]
        rate: f64,
        /// Seconds of measurement after a 5 s warm-up.
        #[arg(long, default_value_t = 30)]
        seconds: u64,
        /// DDS domain for the measurement.
        #[arg(long, default_value_t = 25)]
        domain: u16,
    },
    /// Late joiners: a station publishes a task, then a vehicle's participant joins; does it
    /// get the task (transient-local durability)? Repeated N times, each with a new
    /// participant, and timed.
    LateJoiner {
        /// Trials.
        #[arg(long, default_value_t = 1000)]
        trials: usize,
        /// DDS domain for the measurement.
        #[arg(long, default_value_t = 26)]
        domain: u16,
    },
    /// (helper) Echo pings back as pongs.
    #[command(hide = true)]
    Pong {
        #[arg(long)]
        domain: u16,
    },
    /// (helper) Count throughput samples per step and print the counts.
    #[command(hide = true)]
    Sink {
        #[arg(long)]
        domain: u16,
    },
    /// (helper) Announce vehicles and publish their state vectors at a rate.
    #[command(hide = true)]
    Load {
        #[arg(long)]
        domain: u16,
        #[arg(long)]
        vehicles: usize,
        #[arg(long)]
        rate: f64,
        #[arg(long)]
        seconds: f64,
    },
}

/// Runs one benchmark.
pub async fn run(which: BenchCommand, cfg: &ShoalConfig) -> Result<()> {
    match which {
        BenchCommand::Bus {
            seconds,
            domain,
            no_peer,
        } => bus(cfg, domain, seconds, no_peer).await,
        BenchCommand::Ingest {
            vehicles,
            rate,
            seconds,
            domain,
        } => ingest(cfg, domain, vehicles, rate, seconds).await,
        BenchCommand::Pipeline {
            vehicles,
            rows,
            domain,
        } => pipeline(cfg, domain, vehicles, rows).await,
        BenchCommand::Soak {
            writes,
            instances,
            domain,
        } => soak(cfg, domain, writes, instances).await,
        BenchCommand::Acoustic { time_scale } => acoustic(time_scale).await,
        BenchCommand::Latency {
            vehicles,
            rate,
            seconds,
            domain,
        } => latency(cfg, vehicles, rate, seconds, domain).await,
        BenchCommand::LateJoiner { trials, domain } => late_joiner(cfg, trials, domain).await,
        BenchCommand::Suite {
            seconds,
            scale_vehicles,
            out,
            domain,
            semantic_hour_s,
        } => suite(cfg, seconds, scale_vehicles, &out, domain, semantic_hour_s).await,
        BenchCommand::Scale {
            vehicles,
            rate,
            seconds,
            domain,
        } => scale(vehicles, rate, seconds, domain).await,
        BenchCommand::Pong { domain } => pong(cfg, domain).await,
        BenchCommand::Sink { domain } => sink(cfg, domain).await,
        BenchCommand::Load {
            domain,
            vehicles,
            rate,
            seconds,
        } => load(cfg, domain, vehicles, rate, seconds).await,
    }
}

fn dds(cfg: &ShoalConfig, domain: u16) -> Result<Arc<PubSub>> {
    let c = DdsConfig {
        domain_id: domain,
        ..cfg.dds.clone()
    };
    Ok(Arc::new(PubSub::new(&c).context("cannot join DDS")?))
}

/// A state vector whose timestamp carries a sequence number (and stays valid).
fn sample(vehicle: &str, seq: u64, step: u32) -> StateVector {
    StateVector {
        vehicle_id: vehicle.to_string(),
        timestamp_ms: 1_700_000_000_000 + i64::try_from(seq).unwrap_or(0),
        latitude_deg: 63.44,
        longitude_deg: 10.4,
        depth_m: f64::from(step),
        altitude_m: 12.0,
        speed_mps: 1.5,
        yaw_deg: 90.0,
        pitch_deg: 1.0,
        roll_deg: -1.0,
        battery_pct: 77.0,
    }
}

fn seq_of(s: &StateVector) -> u64 {
    u64::try_from(s.timestamp_ms - 1_700_000_000_000).unwrap_or(0)
}

/// Starts `shoal bench <args>` as a helper process that stops when our stdin pipe closes.
fn helper(args: &[String]) -> Result<tokio::process::Child> {
    let exe = std::env::current_exe()?;
    tokio::process::Command::new(exe)
        .arg("bench")
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .kill_on_drop(true)
        .spawn()
        .context("cannot start the helper process")
}

/// Percentile of sorted values (nearest rank).
fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    #[allow(
        clippy::cast_possible_truncation,
        clippy::cast_sign_loss,
        clippy::cast_precision_loss
    )]
    let i = ((p / 100.0) * (sorted.len() - 1) as f64).round() as usize;
    sorted[i.min(sorted.len() - 1)]
}

struct RoundTrip {
    p50_us: f64,
    p99_us: f64,
    count: usize,
}

async fn shoal_round_trip(cfg: &ShoalConfig, domain: u16, seconds: u64) -> Result<RoundTrip> {
    let dds = dds(cfg, domain)?;
    let ping = dds.writer_on::<StateVector>(PING, WriterOptions::new(Priority::Telemetry))?;
    let mut pongs = dds.subscribe_on::<StateVector>(PONG)?;
    let _child = helper(&["pong".into(), "--domain".into(), domain.to_string()])?;
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
    let end = Instant::now() + Duration::from_secs(seconds);
    while Instant::now() < end {
        seq += 1;
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
    })
}

async fn pong(cfg: &ShoalConfig, domain: u16) -> Result<()> {
    let dds = dds(cfg, domain)?;
    let w = dds.writer_on::<StateVector>(PONG, WriterOptions::new(Priority::Telemetry))?;
    let mut pings = dds.subscribe_on::<StateVector>(PING)?;
    let stop = crate::daemons::shutdown_signal(true);
    loop {
        tokio::select! {
            () = stop.cancelled() => return Ok(()),
            item = pings.next() => match item {
                Some(Ok((s, _))) => { let _ = w.write(s).await; }
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
    let mut child = helper(&["sink".into(), "--domain".into(), domain.to_string()])?;
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

async fn sink(cfg: &ShoalConfig, domain: u16) -> Result<()> {
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

struct PerfResult {
    p50_us: f64,
    p99_us: f64,
    throughput: f64,
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
struct BusFigures {
    rt: RoundTrip,
    throughput: f64,
    steps: Vec<(f64, u64, u64)>,
    peer: Option<PerfResult>,
    /// ddsperf's round trip (p50, p99) with the Cyclone configuration Shoal uses.
    peer_shoal_transport: Option<(f64, f64)>,
}

async fn bus_figures(
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

async fn bus(cfg: &ShoalConfig, domain: u16, seconds: u64, no_peer: bool) -> Result<()> {
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

async fn acoustic(time_scale: f64) -> Result<()> {
    if !(time_scale > 0.0 && time_scale <= 1.0) {
        bail!("--time-scale must be in (0, 1]");
    }
    let opts = shoal_converter::bench::BenchOptions {
        time_scale,
        ..Default::default()
    };
    eprintln!("acoustic: running emulated modems at {time_scale}x wall time...");
    let r = shoal_converter::bench::run(&opts)
        .await
        .context("acoustic benchmark failed")?;
    println!("# shoal bench acoustic — {} — {}", machine(), date());
    println!(
        "PDU sizes (DCCL reference {} B, SWARMs ASCII {} B, naive binary {} B; auth tag + counter {}):",
        r.sizes.dccl_reference_bytes,
        r.sizes.swarms_ascii_bytes,
        r.sizes.naive_binary_bytes,
        r.sizes
            .auth_tag_bytes
            .map_or_else(|| "none yet".to_string(), |b| format!("{b} B"))
    );
    println!(
        "  {:<34} {:>5} {:>6} {:>10} {:>10} {:>10}",
        "message", "bits", "bytes", "vs 51 B", "per frame", "tagged"
    );
    for row in &r.sizes.rows {
        println!(
            "  {:<34} {:>5} {:>6} {:>9.0}% {:>10} {:>10}",
            row.message,
            row.bits,
            row.bytes,
            row.vs_swarms_ascii * 100.0,
            row.per_frame,
            row.per_frame_tagged
        );
    }
    let c = &r.channel;
    println!(
        "channel use under saturation: {:.2} (goal >= 0.90: {}) — {} frames in {:.0} s, on air {:.2}, frames {:.1}% full",
        c.channel_use,
        if c.goal_met { "met" } else { "NOT met" },
        c.frames,
        c.seconds,
        c.busy_share,
        c.frame_fill * 100.0
    );
    let e = &r.emergency;
    println!(
        "emergency latency under saturating telemetry: mean {:.2} s, max {:.2} s",
        e.mean_s, e.max_s
    );
    println!(
        "  within one 64-byte frame time + propagation ({:.2} s): {}/{}",
        e.bound_s,
        e.within_bound,
        e.latencies_s.len()
    );
    println!(
        "  within one frame's wait + its own air time + propagation ({:.2} s): {}/{}",
        e.bound_one_frame_wait_s,
        e.within_one_frame_wait,
        e.latencies_s.len()
    );
    let d = &r.control;
    println!(
        "control delivery at {:.0}% packet error rate: {}/{} within the {:.0} s TTL (last after {:.1} s, {} packets lost)",
        d.per * 100.0,
        d.delivered,
        d.sent,
        d.ttl_s,
        d.all_delivered_after_s,
        d.packets_lost
    );
    Ok(())
}

fn machine() -> String {
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap_or_default();
    let cpus = std::thread::available_parallelism().map_or(0, std::num::NonZero::get);
    format!("{} ({cpus} cores)", host.trim())
}

fn date() -> String {
    utc_date(now_ms())
}

/// The UTC calendar date of a time in ms since the Unix epoch, e.g. `2026-11-21`.
pub(crate) fn utc_date(ms: i64) -> String {
    match time::OffsetDateTime::from_unix_timestamp(ms.div_euclid(1000)) {
        Ok(t) => format!("{:04}-{:02}-{:02}", t.year(), u8::from(t.month()), t.day()),
        Err(_) => "(date out of range)".to_string(),
    }
}

fn rss_mb() -> f64 {
    rss_mb_of("self")
}

/// Resident memory of a process (`self` or a pid), MB.
fn rss_mb_of(pid: &str) -> f64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.split_whitespace().next())
        .and_then(|kb| kb.parse::<f64>().ok())
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

async fn soak(cfg: &ShoalConfig, domain: u16, writes: u64, instances: u32) -> Result<()> {
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

async fn load(
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

/// A station for a measurement: the configured one, with its history in `db` and no
/// periodic summary in the output.
fn bench_station(cfg: &ShoalConfig, domain: u16, db: &std::path::Path) -> Result<Station> {
    let history = History::open(&HistoryConfig {
        path: db.to_path_buf(),
        ..cfg.history.clone()
    })?;
    Ok(Station::new(
        StationConfig {
            summary_interval_s: 0.0,
            ..cfg.station.clone()
        },
        dds(cfg, domain)?,
        history,
    )?)
}

async fn ingest(
    cfg: &ShoalConfig,
    domain: u16,
    vehicles: usize,
    rate: f64,
    seconds: f64,
) -> Result<()> {
    let dir = tempfile_dir()?;
    let station = bench_station(cfg, domain, &dir.join("ingest.db"))?;
    let h = station.handle();
    let stop = CancellationToken::new();
    let task = tokio::spawn(station.run(stop.clone()));
    eprintln!("ingest: {vehicles} vehicles × {rate} Hz for {seconds} s from another process...");
    let mut child = helper(&[
        "load".into(),
        "--domain".into(),
        domain.to_string(),
        "--vehicles".into(),
        vehicles.to_string(),
        "--rate".into(),
        rate.to_string(),
        "--seconds".into(),
        seconds.to_string(),
    ])?;
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
        "sent {n}, accepted {}, rejected {}, lost {}",
        stats.states_accepted,
        stats.total_rejected(),
        n.saturating_sub(stats.states_accepted)
    );
    println!(
        "ingest rate (validated, registered, queued for history) {ingest_rate:.0} state vectors/s"
    );
    println!(
        "history committed {} records (state vectors + announcements)",
        report.history_committed
    );
    let _ = std::fs::remove_dir_all(&dir);
    Ok(())
}

/// The rows of the pipeline benchmark: `vehicles` AUVs at 10 Hz over the last minutes,
/// moving and draining plausibly, so that every row is accepted.
fn pipeline_rows(vehicles: usize, rows: usize) -> Vec<StateVector> {
    let per_vehicle = rows.div_ceil(vehicles.max(1));
    let start = now_ms() - i64::try_from(per_vehicle).unwrap_or(0) * 100 - 60_000;
    let mut out = Vec::with_capacity(rows);
    for k in 0..per_vehicle {
        for v in 0..vehicles {
            if out.len() == rows {
                return out;
            }
            #[allow(clippy::cast_precision_loss)]
            let (kf, vf) = (k as f64, v as f64);
            out.push(StateVector {
                vehicle_id: format!("auv-{v:05}"),
                timestamp_ms: start + i64::try_from(k).unwrap_or(0) * 100,
                latitude_deg: 43.0 + vf * 1e-3,
                // 1.5 m/s eastwards: 0.15 m per step.
                longitude_deg: 5.0 + kf * 1.85e-6,
                depth_m: 20.0 + (kf * 0.01).sin() * 5.0,
                altitude_m: 12.0,
                speed_mps: 1.5,
                yaw_deg: 90.0,
                pitch_deg: 1.0,
                roll_deg: -1.0,
                battery_pct: 90.0 - kf * 0.001,
            });
        }
    }
    out
}

/// Eight user rules beside the built-in ones the station runs by default (low battery,
/// task overdue): thresholds on the native fast path,
/// an area, and a SPARQL rule on the coalesced RDF mirror.
fn pipeline_rules() -> Vec<shoal_station::RuleDoc> {
    use shoal_station::{ConditionDoc, RuleDoc};
    let threshold = |id: &str, expr: &str| RuleDoc {
        id: id.into(),
        description: format!("bench: {expr}"),
        severity: shoal_model::Severity::Warning,
        kind: shoal_model::EventKind::Rule,
        condition: ConditionDoc::Threshold { expr: expr.into() },
        enabled: true,
        built_in: false,
    };
    let corner = |lat: f64, lon: f64| shoal_model::GeoPoint {
        latitude_deg: lat,
        longitude_deg: lon,
    };
    vec![
        threshold("too-deep", "depth_m > 300"),
        threshold("too-fast", "speed_mps > 5"),
        threshold("steep-pitch", "pitch_deg > 45"),
        threshold("rolled", "roll_deg < -45"),
        threshold("near-bottom", "altitude_m < 2"),
        threshold("battery-low-15", "battery_pct < 15"),
        RuleDoc {
            condition: ConditionDoc::OutsideArea {
                polygon: vec![
                    corner(42.0, 4.0),
                    corner(45.0, 4.0),
                    corner(45.0, 7.0),
                    corner(42.0, 7.0),
                ],
            },
            ..threshold("geofence", "")
        },
        RuleDoc {
            condition: ConditionDoc::Sparql {
                query: "ASK { ?this shoal:batteryLevel ?b . FILTER(?b < 5) }".into(),
                watches: vec!["shoal:batteryLevel".into()],
            },
            ..threshold("battery-critical", "")
        },
    ]
}

/// What `bench pipeline` measures.
struct PipelineFigures {
    enabled: usize,
    accepted: u64,
    rejected: usize,
    firings: u64,
    committed: u64,
    elapsed: Duration,
    raw: Duration,
    rate: f64,
    raw_rate: f64,
}

async fn pipeline_figures(
    cfg: &ShoalConfig,
    domain: u16,
    vehicles: usize,
    rows: usize,
) -> Result<PipelineFigures> {
    let dir = tempfile_dir()?;
    eprintln!("pipeline: generating {rows} state vectors for {vehicles} vehicles...");
    let data = pipeline_rows(vehicles, rows);
    let history = History::open(&HistoryConfig {
        path: dir.join("pipeline.db"),
        ..cfg.history.clone()
    })?;
    let station = Station::new(
        StationConfig {
            summary_interval_s: 0.0,
            rules_path: dir.join("rules.json"),
            ..cfg.station.clone()
        },
        dds(cfg, domain)?,
        history,
    )?;
    let h = station.handle();
    for rule in pipeline_rules() {
        h.create_rule(&rule).context("bench rule")?;
    }
    let enabled = h.rules().iter().filter(|r| r.enabled).count();
    let stop = CancellationToken::new();
    let task = tokio::spawn(station.run(stop.clone()));
    for v in 0..vehicles {
        h.register_vehicle(VehicleAnnouncement {
            vehicle_id: format!("auv-{v:05}"),
            name: format!("bench {v}"),
            kind: VehicleKind::Auv,
            vendor: "shoal-bench".into(),
            capabilities: vec!["survey".into()],
            sensors: vec!["ctd".into()],
            links: vec![LinkKind::Ip],
            max_speed_mps: 2.0,
            timestamp_ms: now_ms(),
        })?;
    }
    h.flush_history(Duration::from_secs(30))?;
    let base = h.history_committed();
    eprintln!("pipeline: {enabled} rules enabled; ingesting...");
    let handle = h.clone();
    let (elapsed, rejected) = tokio::task::spawn_blocking(move || -> Result<(Duration, usize)> {
        let t = Instant::now();
        let mut rejected = 0;
        for s in data {
            if handle.ingest_state(s).is_err() {
                rejected += 1;
            }
        }
        handle.flush_history(Duration::from_secs(120))?;
        Ok((t.elapsed(), rejected))
    })
    .await??;
    let stats = h.stats();
    let committed = h.history_committed() - base;
    // The handle holds the station's DDS writers: drop it while the participant lives.
    drop(h);
    stop.cancel();
    task.await??;
    eprintln!("pipeline: raw batched SQLite insert of the same rows...");
    let raw_rows = pipeline_rows(vehicles, rows);
    let raw =
        shoal_history::raw_insert_baseline(&dir.join("raw.db"), &raw_rows, cfg.history.batch_max)?;
    #[allow(clippy::cast_precision_loss)]
    let (rate, raw_rate) = (
        rows as f64 / elapsed.as_secs_f64(),
        rows as f64 / raw.as_secs_f64(),
    );
    let _ = std::fs::remove_dir_all(&dir);
    Ok(PipelineFigures {
        enabled,
        accepted: stats.states_accepted,
        rejected,
        firings: stats.rule_firings,
        committed,
        elapsed,
        raw,
        rate,
        raw_rate,
    })
}

async fn pipeline(cfg: &ShoalConfig, domain: u16, vehicles: usize, rows: usize) -> Result<()> {
    let PipelineFigures {
        enabled,
        accepted,
        rejected,
        firings,
        committed,
        elapsed,
        raw,
        rate,
        raw_rate,
    } = pipeline_figures(cfg, domain, vehicles, rows).await?;
    println!("# shoal bench pipeline — {} — {}", machine(), date());
    println!(
        "{vehicles} vehicles, {rows} state vectors, {enabled} rules enabled, history batch {}",
        cfg.history.batch_max
    );
    println!(
        "accepted {accepted}, rejected {rejected}, rule firings {firings}, history committed {committed}"
    );
    println!("{:<58} {:>12} {:>12}", "", "state vec/s", "time");
    println!(
        "{:<58} {:>12.0} {:>10.3} s",
        "Shoal: validate+plausibility+latest+semantic+rules+history",
        rate,
        elapsed.as_secs_f64()
    );
    println!(
        "{:<58} {:>12.0} {:>10.3} s",
        "raw batched SQLite insert (same rows, schema, pragmas)",
        raw_rate,
        raw.as_secs_f64()
    );
    println!(
        "ratio Shoal / raw: {:.2} (goal >= 0.80); goal >= 100000/s: {}",
        rate / raw_rate,
        if rate >= 100_000.0 { "met" } else { "NOT met" }
    );
    Ok(())
}

fn tempfile_dir() -> Result<std::path::PathBuf> {
    let dir = std::env::temp_dir().join(format!("shoal-bench-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    Ok(dir)
}

/// One sample of a running station, read through its API.
struct StationSample {
    alive: usize,
    accepted: u64,
    rejected: u64,
}

async fn station_sample(api: std::net::SocketAddr) -> Option<StationSample> {
    let (_, fleet) = crate::query::request(api, "GET", "/api/fleet", None)
        .await
        .ok()?;
    let (_, stats) = crate::query::request(api, "GET", "/api/stats", None)
        .await
        .ok()?;
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

/// Starts `shoal <args>` with a domain, stopping when our stdin pipe closes.
fn child(args: &[&str], domain: u16) -> Result<tokio::process::Child> {
    let exe = std::env::current_exe()?;
    tokio::process::Command::new(exe)
        .args(args)
        .arg("--exit-on-stdin-close")
        .env("SHOAL_DDS__DOMAIN_ID", domain.to_string())
        .env("RUST_LOG", "warn,cyclonedds=error")
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .stderr(Stdio::inherit())
        .kill_on_drop(true)
        .spawn()
        .with_context(|| format!("cannot start shoal {}", args.join(" ")))
}

/// What `bench scale` measures.
struct ScaleFigures {
    all_alive_after_s: Option<f64>,
    mean_rate: f64,
    peak_rss_mb: f64,
}

/// Runs each standard SPARQL query once against the station's endpoint, as an operator's
/// console would, and returns the round-trip times in ms (HTTP included).
async fn standard_query_times(api: std::net::SocketAddr) -> Result<Vec<f64>> {
    let mut times = Vec::with_capacity(shoal_semantic::STANDARD_QUERIES.len());
    for (name, q) in shoal_semantic::STANDARD_QUERIES {
        let t = Instant::now();
        let (status, body) = crate::query::post(api, "json", q).await?;
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
    t_s: f64,
    /// State vectors accepted per second over the last interval.
    per_s: f64,
    rss_mb: f64,
    /// The standard queries' HTTP round trips, ms.
    queries_ms: Vec<f64>,
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

async fn scale(vehicles: usize, rate: f64, seconds: u64, domain: u16) -> Result<()> {
    scale_figures(vehicles, rate, seconds, domain)
        .await
        .map(|_| ())
}

async fn scale_figures(
    vehicles: usize,
    rate: f64,
    seconds: u64,
    domain: u16,
) -> Result<ScaleFigures> {
    let dir = tempfile_dir()?;
    let port = std::net::TcpListener::bind("127.0.0.1:0")?
        .local_addr()?
        .port();
    let api = std::net::SocketAddr::from(([127, 0, 0, 1], port));
    let db = dir.join("scale.db");
    let listen = api.to_string();
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
    loop {
        tokio::time::sleep(Duration::from_secs(10)).await;
        let Some(s) = station_sample(api).await else {
            bail!("the station stopped answering");
        };
        let now = Instant::now();
        #[allow(clippy::cast_precision_loss)]
        let per_s = (s.accepted - last.1) as f64 / now.duration_since(last.0).as_secs_f64();
        last = (now, s.accepted);
        let (st, sw) = (rss_mb_of(&station_pid), rss_mb_of(&swarm_pid));
        let q = standard_query_times(api).await?;
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
    match all_alive_at {
        Some(t) => {
            println!(
                "all {vehicles} alive after {:.0} s; steady ingest {mean:.0} state vectors/s (offered {:.0}/s); station RSS idle {idle_rss:.1} MB, all alive {:.1} MB, peak {peak:.1} MB",
                t.as_secs_f64(),
                rate * {
                    #[allow(clippy::cast_precision_loss)]
                    let v = vehicles as f64;
                    v
                },
                first_rss.unwrap_or(f64::NAN)
            );
        }
        None => println!("not every vehicle was alive within 120 s"),
    }
    Ok(ScaleFigures {
        all_alive_after_s: all_alive_at.map(|t| t.as_secs_f64()),
        mean_rate: mean,
        peak_rss_mb: peak,
    })
}

/// What `bench latency` measures, in ms.
struct LatencyFigures {
    samples: Vec<f64>,
    lagged: u64,
}

async fn latency(
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

async fn latency_figures(
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
        shoal_console::ConsoleConfig::default(),
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

async fn late_joiner(cfg: &ShoalConfig, trials: usize, domain: u16) -> Result<()> {
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

async fn suite(
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
        shoal_semantic::bench::run(shoal_semantic::bench::BenchOptions {
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
            shoal_semantic::bench::run_hour(
                shoal_semantic::bench::HourOptions {
                    seconds: semantic_hour_s,
                    sample_every_s: semantic_hour_s.div_ceil(6),
                    ..shoal_semantic::bench::HourOptions::default()
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
    let ac = shoal_converter::bench::run(&shoal_converter::bench::BenchOptions::default())
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
