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

use super::helpers::{THROUGHPUT, date, dds, grouped, helper, machine, percentile, sample, seq_of};
use crate::config::ShoalConfig;

pub(super) const PING: &str = "shoal/bench/ping";
pub(super) const PONG: &str = "shoal/bench/pong";

/// Round trips ddsperf keeps per one-second window for its percentiles (`PINGPONG_RAWSIZE`
/// in ddsperf.c): later ones in the same second count only in its mean, min, max and count.
const DDSPERF_RAW_PER_WINDOW: usize = 20_000;

/// A run's p50 and p99 as ddsperf reports its own: each one-second window's p50 and p99,
/// then the median of those over the windows.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct PerSecond {
    pub(super) p50_us: f64,
    pub(super) p99_us: f64,
    /// One-second windows with at least one round trip.
    pub(super) windows: usize,
}

/// Shoal's round trips between two processes.
pub(super) struct RoundTrip {
    /// p50 over every round trip of the run, µs.
    pub(super) p50_us: f64,
    /// p99 over every round trip of the run, µs.
    pub(super) p99_us: f64,
    /// The same round trips computed as ddsperf computes its own ([`per_second`]): the
    /// figures compared with ddsperf's. `None` when no whole second had a round trip.
    pub(super) per_second: Option<PerSecond>,
    pub(super) count: usize,
    /// Pings whose pong did not come back within 2 s.
    pub(super) lost: usize,
}

/// Shoal's round trips reduced the way ddsperf reduces its own, so that the two compare
/// like with like. ddsperf's ping prints, once a second, the p50 and p99 of the round
/// trips whose pong came in that second (`print_stats` and `latencystat_print` in
/// ddsperf.c: the second's first 20,000, sorted, read by [`ddsperf_percentile`]); it
/// prints no line for a second without one and none for the partial last second, and the
/// bench takes the median of its lines. `timed` holds, in arrival order, when each pong
/// came (s since the measurement began) and the round trip (µs); `run_s` is how long the
/// measurement ran, so only its whole seconds count.
fn per_second(timed: &[(f64, f64)], run_s: f64) -> Option<PerSecond> {
    #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
    let whole = run_s.max(0.0).floor() as usize;
    let mut windows: Vec<Vec<f64>> = vec![Vec::new(); whole];
    for &(at_s, us) in timed {
        #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
        let w = at_s.max(0.0).floor() as usize;
        if let Some(window) = windows.get_mut(w)
            && window.len() < DDSPERF_RAW_PER_WINDOW
        {
            window.push(us);
        }
    }
    let (mut p50s, mut p99s) = (Vec::new(), Vec::new());
    for mut window in windows.into_iter().filter(|w| !w.is_empty()) {
        window.sort_by(f64::total_cmp);
        p50s.push(ddsperf_percentile(&window, 50));
        p99s.push(ddsperf_percentile(&window, 99));
    }
    let windows = p50s.len();
    (windows > 0).then(|| PerSecond {
        p50_us: median(p50s),
        p99_us: median(p99s),
        windows,
    })
}

/// A percentile of sorted values as ddsperf prints it: the value with ⌈n·(100 − p)/100⌉
/// values at or above it (`raw[n - (n + 1) / 2]` for its 50 %, `raw[n - (n + 99) / 100]`
/// for its 99 %); `p` from 0 to 99.
fn ddsperf_percentile(sorted: &[f64], p: usize) -> f64 {
    let n = sorted.len();
    if n == 0 {
        return f64::NAN;
    }
    let at_or_above = (n * (100 - p.min(99))).div_ceil(100);
    sorted[n - at_or_above]
}

/// The median of per-second figures, the same reduction for Shoal's and ddsperf's.
fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    percentile(&values, 50.0)
}

/// How both ends of the round trip receive a sample.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub(crate) enum ReceivePath {
    /// A function on Cyclone's receive thread answers at once ([`shoal_dds::PubSub::listen`]):
    /// no thread woken, as in ddsperf's default (listener) mode.
    Listener,
    /// A tokio task is woken for each sample (a [`shoal_dds::Subscription`], the station's
    /// way): one thread woken per side, as in ddsperf's waitset mode.
    Stream,
}

impl ReceivePath {
    fn as_str(self) -> &'static str {
        match self {
            Self::Listener => "listener",
            Self::Stream => "stream",
        }
    }
}

/// Starts the `pong` helper on `domain`, answering the way `delivery` says.
fn pong_helper(
    cfg: &ShoalConfig,
    domain: u16,
    keystore: Option<&std::path::Path>,
    delivery: ReceivePath,
) -> Result<tokio::process::Child> {
    let mut args = vec![
        "pong".to_string(),
        "--domain".into(),
        domain.to_string(),
        "--delivery".into(),
        delivery.as_str().into(),
    ];
    if let Some(k) = keystore {
        args.extend(["--keystore".to_string(), k.display().to_string()]);
    }
    helper(cfg, &args)
}

/// The ping side's state when answers come on Cyclone's receive thread.
struct Pinging {
    /// The ping waiting for its pong.
    seq: u64,
    /// When it was sent.
    t0: Instant,
    /// Some pong came back (discovery is over).
    answered: bool,
    /// Round trips are being timed and each pong sends the next ping.
    measuring: bool,
    began: Instant,
    end: Instant,
    sent: usize,
    timed: Vec<(f64, f64)>,
}

impl Pinging {
    /// Sends the next ping; called with the state locked, so that its pong, which comes
    /// on another thread, finds `seq` and `t0` already set.
    fn send_next(&mut self, ping: &shoal_dds::Writer<StateVector>) -> Result<()> {
        self.seq += 1;
        self.t0 = Instant::now();
        ping.write_blocking(sample("ping", self.seq, 0))
            .map_err(|e| anyhow::anyhow!("{e}"))
    }
}

/// Round trips where both ends answer on Cyclone's receive thread, as ddsperf's default
/// mode does: the pong helper echoes in its listener, and this side's listener times each
/// pong and sends the next ping. A ping with no pong within 2 s is lost: counted, and the
/// next one goes.
async fn listener_round_trip(cfg: &ShoalConfig, domain: u16, seconds: u64) -> Result<RoundTrip> {
    use std::sync::{Arc, Mutex, PoisonError};
    let dds = dds(cfg, domain)?;
    let ping =
        Arc::new(dds.writer_on::<StateVector>(PING, WriterOptions::new(Priority::Telemetry))?);
    let now = Instant::now();
    let state = Arc::new(Mutex::new(Pinging {
        seq: 0,
        t0: now,
        answered: false,
        measuring: false,
        began: now,
        end: now,
        sent: 0,
        timed: Vec::new(),
    }));
    let (failed_tx, mut failed_rx) = tokio::sync::mpsc::unbounded_channel::<String>();
    let _listening = {
        let state = Arc::clone(&state);
        let ping = Arc::clone(&ping);
        dds.listen_on::<StateVector, _>(PONG, move |delivery| {
            let Ok((pong, _)) = delivery else { return };
            let mut st = state.lock().unwrap_or_else(PoisonError::into_inner);
            if seq_of(&pong) != st.seq {
                return;
            }
            let now = Instant::now();
            st.answered = true;
            if !st.measuring {
                return;
            }
            let rtt = now.duration_since(st.t0).as_secs_f64() * 1e6;
            let at = now.duration_since(st.began).as_secs_f64();
            st.timed.push((at, rtt));
            if now < st.end {
                st.sent += 1;
                if let Err(e) = st.send_next(&ping) {
                    let _ = failed_tx.send(format!("{e:#}"));
                }
            }
        })?
    };
    let _child = pong_helper(cfg, domain, None, ReceivePath::Listener)?;
    // Discovery first: ping until one comes back.
    let start = Instant::now();
    loop {
        state
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .send_next(&ping)?;
        tokio::time::sleep(Duration::from_millis(200)).await;
        if state
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .answered
        {
            break;
        }
        if start.elapsed() > Duration::from_secs(30) {
            bail!("the pong process did not answer within 30 s");
        }
    }
    tokio::time::sleep(Duration::from_millis(300)).await;
    {
        let mut st = state.lock().unwrap_or_else(PoisonError::into_inner);
        st.measuring = true;
        st.began = Instant::now();
        st.end = st.began + Duration::from_secs(seconds);
        st.sent = 1;
        st.send_next(&ping)?;
    }
    // The listener runs the measurement; this task only replaces lost pings and waits for
    // the last pong (or its loss) after the end.
    loop {
        tokio::time::sleep(Duration::from_millis(50)).await;
        if let Ok(e) = failed_rx.try_recv() {
            bail!("a ping could not be sent: {e}");
        }
        let mut st = state.lock().unwrap_or_else(PoisonError::into_inner);
        let now = Instant::now();
        let outstanding = st.timed.len() < st.sent;
        if !outstanding && now >= st.end {
            break;
        }
        if outstanding && now.duration_since(st.t0) > Duration::from_secs(2) {
            if now >= st.end {
                break;
            }
            st.sent += 1;
            st.send_next(&ping)?;
        }
    }
    let mut st = state.lock().unwrap_or_else(PoisonError::into_inner);
    st.measuring = false;
    let run_s = st.end.duration_since(st.began).as_secs_f64();
    Ok(round_trip_of(&st.timed, st.sent, run_s))
}

/// The figures of a run's timed round trips.
fn round_trip_of(timed: &[(f64, f64)], sent: usize, run_s: f64) -> RoundTrip {
    let per_second = per_second(timed, run_s);
    let mut rtts: Vec<f64> = timed.iter().map(|t| t.1).collect();
    rtts.sort_by(f64::total_cmp);
    RoundTrip {
        p50_us: percentile(&rtts, 50.0),
        p99_us: percentile(&rtts, 99.0),
        per_second,
        count: rtts.len(),
        lost: sent.saturating_sub(rtts.len()),
    }
}

/// Round trips between this process and a `pong` helper, each a tokio task woken per
/// sample, both secured with station identities from the DDS Security keystore in
/// `keystore` when given.
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
    let _child = pong_helper(cfg, domain, keystore, ReceivePath::Stream)?;
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
    // (when the pong came, s since `began`; round trip, µs), in arrival order.
    let mut timed = Vec::new();
    let mut sent = 0usize;
    let began = Instant::now();
    let end = began + Duration::from_secs(seconds);
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
                    timed.push((
                        began.elapsed().as_secs_f64(),
                        t0.elapsed().as_secs_f64() * 1e6,
                    ));
                    break;
                }
                Ok(Some(_)) => {}
                Ok(None) => bail!("pong stream ended"),
                Err(_) => break, // lost: counted by its absence
            }
        }
    }
    Ok(round_trip_of(&timed, sent, began.elapsed().as_secs_f64()))
}

/// The `pong` helper: echoes every ping back, in a listener or a task as `delivery` says.
pub(super) async fn pong(
    cfg: &ShoalConfig,
    domain: u16,
    keystore: Option<&std::path::Path>,
    delivery: ReceivePath,
) -> Result<()> {
    let dds =
        super::security::participant(cfg, domain, keystore, &shoal_security::dds::Grant::Station)?;
    let w = dds.writer_on::<StateVector>(PONG, WriterOptions::new(Priority::Telemetry))?;
    let stop = crate::daemons::shutdown_signal(true);
    if delivery == ReceivePath::Listener {
        let _listening = dds.listen_on::<StateVector, _>(PING, move |ping| {
            if let Ok((s, _)) = ping {
                let _ = w.write_blocking(s.into_inner());
            }
        })?;
        stop.cancelled().await;
        return Ok(());
    }
    let mut pings = dds.subscribe_on::<StateVector>(PING)?;
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

/// What ddsperf measured in its default configuration.
pub(super) struct PerfResult {
    pub(super) rt: PeerRoundTrip,
    pub(super) throughput: f64,
}

/// ddsperf's round trip, read from its ping's output.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct PeerRoundTrip {
    /// Median over its per-second lines of their p50, doubled to a round trip, µs.
    pub(super) p50_us: f64,
    /// Median over its per-second lines of their p99, doubled to a round trip, µs.
    pub(super) p99_us: f64,
    /// Its per-second lines.
    pub(super) windows: usize,
    /// Round trips those lines cover (the sum of their `cnt`).
    pub(super) received: u64,
    /// Pings it gave up on after 1 s: the running total in its last "ping timed out" line.
    /// It prints that line at most once a second, so this can miss the last second's.
    pub(super) timed_out: u64,
}

/// Reads ddsperf ping's output: per-second lines
/// `[pid] t  host:pid size 96 mean 40.1us min … 50% 38.2us 90% … 99% 61.0us max … cnt 13021`
/// and `[pid] ping timed out (total 3 times) ... sending new ping`. Its figures are half a
/// round trip (`(tnow - source_timestamp) / 2` in `process_pong`: a one-way estimate), so
/// they are doubled to compare round trip with round trip. `None` without a latency line.
fn parse_ddsperf_ping(out: &str) -> Option<PeerRoundTrip> {
    let field = |line: &str, name: &str| {
        line.split_whitespace()
            .skip_while(|w| *w != name)
            .nth(1)
            .and_then(|v| v.trim_end_matches("us").parse::<f64>().ok())
    };
    let (mut p50s, mut p99s, mut received, mut timed_out) = (Vec::new(), Vec::new(), 0u64, 0u64);
    for line in out.lines() {
        if line.contains(" 50% ") {
            if let (Some(a), Some(b)) = (field(line, "50%"), field(line, "99%")) {
                p50s.push(a);
                p99s.push(b);
                #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
                let cnt = field(line, "cnt").unwrap_or(0.0) as u64;
                received += cnt;
            }
        } else if line.contains("ping timed out")
            && let Some(total) = line
                .split("(total ")
                .nth(1)
                .and_then(|rest| rest.split_whitespace().next())
                .and_then(|n| n.parse::<u64>().ok())
        {
            timed_out = timed_out.max(total);
        }
    }
    let windows = p50s.len();
    (windows > 0).then(|| PeerRoundTrip {
        p50_us: 2.0 * median(p50s),
        p99_us: 2.0 * median(p99s),
        windows,
        received,
        timed_out,
    })
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
/// vector): median of its per-second p50 and p99 lines, doubled ([`parse_ddsperf_ping`]).
/// Its count of pongs per second agrees with the doubling: at a printed 38 µs, about
/// 13,000 round trips a second, one every 75 µs.
/// `mode` is ddsperf's triggering mode for both ends, `listener` (its default) or
/// `waitset`.
async fn ddsperf_ping(
    domain: u16,
    seconds: u64,
    uri: Option<&str>,
    mode: &str,
) -> Result<PeerRoundTrip> {
    let d = domain.to_string();
    let _pong = ddsperf_process(
        vec![
            "-i".into(),
            d.clone(),
            "-D".into(),
            (seconds + 5).to_string(),
            "pong".into(),
            mode.into(),
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
            mode.into(),
        ],
        uri,
    )?
    .wait_with_output()
    .await?;
    parse_ddsperf_ping(&String::from_utf8_lossy(&ping.stdout))
        .context("ddsperf ping printed no latency figures")
}

/// Cyclone DDS's ddsperf, same host, same namespace, its default configuration: ping/pong
/// with 96-byte payloads, then pub/sub throughput.
async fn ddsperf(domain: u16, seconds: u64) -> Result<PerfResult> {
    let run = |args: Vec<String>| ddsperf_process(args, None);
    let rt = ddsperf_ping(domain, seconds, None, "listener").await?;
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
        rt,
        throughput: percentile(&rates, 50.0),
    })
}

/// What `bench bus` measures.
pub(super) struct BusFigures {
    /// Both ends answering in a listener: the figure compared with ddsperf's default.
    pub(super) rt: RoundTrip,
    /// Both ends answering in a task woken per sample, the station's way.
    pub(super) rt_stream: RoundTrip,
    pub(super) throughput: f64,
    pub(super) steps: Vec<(f64, u64, u64)>,
    pub(super) peer: Option<PerfResult>,
    /// ddsperf's round trip with the Cyclone configuration Shoal uses.
    pub(super) peer_shoal_transport: Option<PeerRoundTrip>,
    /// ddsperf's round trip in waitset mode (a thread woken per sample, as a task is).
    pub(super) peer_waitset: Option<PeerRoundTrip>,
}

pub(super) async fn bus_figures(
    cfg: &ShoalConfig,
    domain: u16,
    seconds: u64,
    no_peer: bool,
) -> Result<BusFigures> {
    eprintln!(
        "bus: {seconds} s of Shoal round trips answered in listeners (Cyclone DDS, two processes, state vectors)..."
    );
    let rt = listener_round_trip(cfg, domain, seconds).await?;
    eprintln!("bus: {seconds} s of Shoal round trips answered in tasks...");
    let rt_stream = round_trip(cfg, domain + 8, seconds, None).await?;
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
        match ddsperf_ping(domain + 1, seconds, Some(&uri), "listener").await {
            Ok(p) => Some(p),
            Err(e) => {
                eprintln!("bus: ddsperf (Shoal's configuration) not measured: {e:#}");
                None
            }
        }
    };
    let peer_waitset = if no_peer {
        None
    } else {
        eprintln!("bus: ddsperf again in waitset mode, {seconds} s...");
        match ddsperf_ping(domain + 1, seconds, None, "waitset").await {
            Ok(p) => Some(p),
            Err(e) => {
                eprintln!("bus: ddsperf (waitset) not measured: {e:#}");
                None
            }
        }
    };
    Ok(BusFigures {
        rt,
        rt_stream,
        throughput: thr,
        steps,
        peer,
        peer_shoal_transport,
        peer_waitset,
    })
}

/// Shoal's round trip counts, as the reports print them: `92,024 measured, 0 lost`.
pub(super) fn shoal_counts(rt: &RoundTrip) -> String {
    format!(
        "{} measured, {} lost",
        grouped(rt.count as u64),
        grouped(rt.lost as u64)
    )
}

/// ddsperf's round trip counts, as the reports print them: `92,024 measured, 0 timed out`
/// (`≥` before a non-zero count of timeouts: ddsperf may not have printed the last ones).
pub(super) fn peer_counts(p: &PeerRoundTrip) -> String {
    let at_least = if p.timed_out > 0 { "≥ " } else { "" };
    format!(
        "{} measured, {at_least}{} timed out",
        grouped(p.received),
        grouped(p.timed_out)
    )
}

pub(super) async fn bus(cfg: &ShoalConfig, domain: u16, seconds: u64, no_peer: bool) -> Result<()> {
    let BusFigures {
        rt,
        rt_stream,
        throughput: thr,
        steps,
        peer,
        peer_shoal_transport,
        peer_waitset,
    } = bus_figures(cfg, domain, seconds, no_peer).await?;
    println!("# shoal bench bus — {} — {}", machine(), date());
    println!(
        "{:<52} {:>12} {:>14} {:>9}",
        "figure", "Shoal", "Cyclone DDS", "ratio"
    );
    let row = |name: &str, ours: Option<f64>, theirs: Option<f64>, unit: &str| {
        let show = |v: Option<f64>| v.map_or_else(|| "-".to_string(), |v| format!("{v:.1} {unit}"));
        let r = match (ours, theirs) {
            (Some(o), Some(t)) => format!("{:.2}×", o / t),
            _ => "-".to_string(),
        };
        println!("{name:<52} {:>12} {:>14} {r:>9}", show(ours), show(theirs));
    };
    let ps = rt.per_second;
    row(
        "round trip p50, median of per-second p50s",
        ps.map(|p| p.p50_us),
        peer.as_ref().map(|p| p.rt.p50_us),
        "µs",
    );
    row(
        "round trip p99, median of per-second p99s",
        ps.map(|p| p.p99_us),
        peer.as_ref().map(|p| p.rt.p99_us),
        "µs",
    );
    row(
        "round trip p50 per second, ddsperf as Shoal's config",
        ps.map(|p| p.p50_us),
        peer_shoal_transport.map(|p| p.p50_us),
        "µs",
    );
    let st = rt_stream.per_second;
    row(
        "round trip p50 per second, answered in tasks | waitset",
        st.map(|p| p.p50_us),
        peer_waitset.map(|p| p.p50_us),
        "µs",
    );
    row(
        "round trip p99 per second, answered in tasks | waitset",
        st.map(|p| p.p99_us),
        peer_waitset.map(|p| p.p99_us),
        "µs",
    );
    row(
        "reliable throughput, no loss",
        Some(thr / 1000.0),
        peer.as_ref().map(|p| p.throughput / 1000.0),
        "k/s",
    );
    row("round trip p50, whole run", Some(rt.p50_us), None, "µs");
    row("round trip p99, whole run", Some(rt.p99_us), None, "µs");
    println!(
        "round trips: Shoal {} (no pong within 2 s) in {} one-second windows",
        shoal_counts(&rt),
        ps.map_or(0, |p| p.windows)
    );
    println!(
        "             Shoal in tasks {} in {} one-second windows",
        shoal_counts(&rt_stream),
        st.map_or(0, |p| p.windows)
    );
    let peer_line = |name: &str, p: Option<&PeerRoundTrip>| match p {
        Some(p) => println!(
            "             {name} {} (no pong within 1 s) in {} per-second lines",
            peer_counts(p),
            p.windows
        ),
        None => println!("             {name} not measured"),
    };
    peer_line("ddsperf", peer.as_ref().map(|p| &p.rt));
    peer_line("ddsperf as Shoal's config", peer_shoal_transport.as_ref());
    peer_line("ddsperf waitset", peer_waitset.as_ref());
    for (achieved, sent, received) in steps {
        println!(
            "  offered {:>8.0}/s  sent {sent:>7}  received {received:>7}",
            achieved
        );
    }
    println!("(ratio = Shoal / Cyclone: below 1 is better for latency, above 1 for throughput;");
    println!(" round trip p50 and p99 are computed as ddsperf computes its own: each one-second");
    println!(" window's p50 and p99, then the median over the windows; the whole-run figures are");
    println!(" over every round trip and have no ddsperf counterpart;");
    println!(" Shoal answers in a listener on Cyclone's receive thread at both ends, as ddsperf's");
    println!(" default listener mode does; the task rows have a tokio task woken per sample at");
    println!(
        " each end, the station's way, beside ddsperf's waitset mode, a thread woken per sample;"
    );
    println!(" ddsperf runs with its default configuration, and once more for the round trip with");
    println!(" the Cyclone configuration Shoal uses (interfaces, multicast for discovery only);");
    println!(
        " Cyclone throughput is ddsperf pub/sub with its own 96-byte type, keep-last, reliable)"
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_are_read_as_ddsperf_reads_them() {
        // ddsperf.c's `latencystat_print`: raw[n - (n+1)/2], raw[n - (n+9)/10],
        // raw[n - (n+99)/100] of the sorted second.
        for n in 1..=250usize {
            #[allow(clippy::cast_precision_loss)]
            let sorted: Vec<f64> = (0..n).map(|i| i as f64).collect();
            assert_eq!(ddsperf_percentile(&sorted, 50), sorted[n - n.div_ceil(2)]);
            assert_eq!(ddsperf_percentile(&sorted, 90), sorted[n - n.div_ceil(10)]);
            assert_eq!(ddsperf_percentile(&sorted, 99), sorted[n - n.div_ceil(100)]);
        }
        assert!(ddsperf_percentile(&[], 50).is_nan());
    }

    #[test]
    fn per_second_figures_are_the_median_of_each_whole_seconds_percentiles() {
        let mut timed = Vec::new();
        // Second 0: 100 round trips of 1..=100 µs; second 1: 200 of 101..=300 µs;
        // second 2: none (no line, as ddsperf prints none); second 3 is cut short by the
        // end of the run (ddsperf prints no partial last second).
        for i in 1..=100 {
            timed.push((0.5, f64::from(i)));
        }
        for i in 101..=300 {
            timed.push((1.5, f64::from(i)));
        }
        timed.push((3.2, 1e6));
        let ps = per_second(&timed, 3.4);
        assert_eq!(
            ps,
            Some(PerSecond {
                // Seconds' p50s 51 and 201, p99s 100 and 299; `median` takes the upper of two.
                p50_us: 201.0,
                p99_us: 299.0,
                windows: 2,
            })
        );
        assert_eq!(per_second(&timed, 0.9), None);
        assert_eq!(per_second(&[], 5.0), None);
    }

    #[test]
    fn a_second_counts_only_its_first_20000_round_trips_as_ddsperf_does() {
        let mut timed = vec![(0.1, 10.0); DDSPERF_RAW_PER_WINDOW];
        timed.extend(vec![(0.9, 1e4); 5_000]);
        let ps = per_second(&timed, 1.0).unwrap_or(PerSecond {
            p50_us: f64::NAN,
            p99_us: f64::NAN,
            windows: 0,
        });
        assert_eq!((ps.p50_us, ps.p99_us, ps.windows), (10.0, 10.0, 1));
    }

    #[test]
    fn ddsperf_ping_output_gives_doubled_medians_counts_and_timeouts() {
        let out = "\
[4242] 1.000  host:4243 size 96 mean 40.100us min 30.000us 50% 38.000us 90% 45.000us 99% 60.000us max 200.000us cnt 12000
[4242] ping timed out (total 1 times) ... sending new ping
[4242] 2.000  host:4243 size 96 mean 41.100us min 30.000us 50% 40.000us 90% 45.000us 99% 70.000us max 900.000us cnt 13000
[4242] 3.000  host:4243 size 96 mean 39.100us min 30.000us 50% 36.000us 90% 45.000us 99% 50.000us max 100.000us cnt 11000
[4242] ping timed out (total 3 times) ... sending new ping
";
        assert_eq!(
            parse_ddsperf_ping(out),
            Some(PeerRoundTrip {
                p50_us: 76.0,
                p99_us: 120.0,
                windows: 3,
                received: 36_000,
                timed_out: 3,
            })
        );
        assert_eq!(
            parse_ddsperf_ping("[4242] ping timed out (total 1 times)"),
            None
        );
    }

    #[test]
    fn counts_read_as_measured_and_lost() {
        let rt = RoundTrip {
            p50_us: 150.0,
            p99_us: 400.0,
            per_second: None,
            count: 92_024,
            lost: 0,
        };
        assert_eq!(shoal_counts(&rt), "92,024 measured, 0 lost");
        let mut p = PeerRoundTrip {
            p50_us: 76.0,
            p99_us: 120.0,
            windows: 10,
            received: 130_000,
            timed_out: 0,
        };
        assert_eq!(peer_counts(&p), "130,000 measured, 0 timed out");
        p.timed_out = 2;
        assert_eq!(peer_counts(&p), "130,000 measured, ≥ 2 timed out");
    }
}
