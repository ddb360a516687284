//! `shoal bench replay`: the target "an hour at 100 vehicles replays at 100×".
//!
//! A recording is written with the recorder's own [`RecordWriter`] (each vehicle's
//! announcement, then its state vector every second of recorded time, moving on a circle),
//! then replayed by a [`Replayer`] at the requested speed to a subscriber in another
//! process (the hidden `replay-sink` helper), which stamps every state vector as it
//! arrives. Each one's due instant follows from the replay's start and its log time, so
//! the lag of every delivery behind the schedule is measured, beside the replay's wall
//! time against the ideal, loss, and the CPU time of both processes.

use std::collections::HashSet;
use std::io::Write;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use anyhow::{Context, Result, bail};
use futures::StreamExt;
use shoal_dds::{Priority, WriterOptions};
use shoal_model::{LinkKind, StateVector, VehicleAnnouncement, VehicleKind};
use shoal_recorder::{
    Publishers, RecordWriter, RecorderConfig, ReplayOptions, Replayer, Sample, Speed,
};
use tokio::io::AsyncBufReadExt;
use tokio_util::sync::CancellationToken;

use super::helpers::{date, dds, helper, machine, percentile, tempfile_dir};
use crate::config::ShoalConfig;

/// What the run is asked to do.
pub(super) struct Plan {
    pub(super) vehicles: usize,
    pub(super) seconds: u64,
    pub(super) speed: f64,
    pub(super) domain: u16,
}

/// Share of the requested speed the replay must reach for the target to be met.
const SPEED_SHARE: f64 = 0.95;

/// How long deliveries may stall after the replay before the rest count as lost.
const DRAIN_QUIET: Duration = Duration::from_secs(5);

/// Microseconds since the Unix epoch of a wall-clock instant.
fn unix_us(t: SystemTime) -> i64 {
    t.duration_since(UNIX_EPOCH)
        .map_or(0, |d| i64::try_from(d.as_micros()).unwrap_or(i64::MAX))
}

// ---------------------------------------------------------------------------------------
// The recording.

/// Recorded time of vehicle `i`'s `k`-th state vector (ms): one a second, the vehicles
/// spread evenly over each second.
fn state_time_ms(t0_ms: i64, vehicles: usize, i: usize, k: u64) -> i64 {
    let offset = i64::try_from(i * 1000 / vehicles.max(1)).unwrap_or(0);
    t0_ms + i64::try_from(k).unwrap_or(i64::MAX / 2) * 1000 + offset
}

fn vehicle_id(i: usize) -> String {
    format!("auv-{i:03}")
}

fn announcement(i: usize, t0_ms: i64) -> VehicleAnnouncement {
    VehicleAnnouncement {
        vehicle_id: vehicle_id(i),
        name: format!("Replay AUV {i}"),
        kind: VehicleKind::Auv,
        vendor: "bench".into(),
        capabilities: vec!["goto".into(), "survey".into()],
        sensors: vec!["ctd".into()],
        links: vec![LinkKind::Ip],
        max_speed_mps: 2.0,
        timestamp_ms: t0_ms,
    }
}

/// Speed over ground of the recorded vehicles, m/s.
const SPEED_MPS: f64 = 1.5;
/// Radius of each vehicle's circle, m.
const RADIUS_M: f64 = 300.0;
/// Metres per degree of latitude.
const M_PER_DEG: f64 = 111_320.0;

/// Vehicle `i`'s `k`-th state vector: on a circle around its own point of a grid in the
/// Trondheimsfjord at 1.5 m/s, heading along the circle, depth and pitch rising and
/// falling, the battery draining.
fn state(i: usize, k: u64, vehicles: usize, t0_ms: i64) -> StateVector {
    #[allow(clippy::cast_precision_loss)]
    let (fi, t) = (i as f64, k as f64);
    let centre_lat = 63.40 + (fi / 10.0).floor() * 0.01;
    let centre_lon = 10.30 + (fi % 10.0) * 0.02;
    let omega = SPEED_MPS / RADIUS_M;
    let theta = fi * 0.7 + omega * t;
    let (north, east) = (RADIUS_M * theta.sin(), RADIUS_M * theta.cos());
    // Counter-clockwise: the velocity is (east, north) = (-sin θ, cos θ) · ω r.
    let mut yaw = (-theta.sin())
        .atan2(theta.cos())
        .to_degrees()
        .rem_euclid(360.0);
    if yaw >= 360.0 {
        yaw = 0.0;
    }
    let phase = std::f64::consts::TAU * t / 600.0 + fi;
    let depth = 20.0 + 15.0 * phase.sin();
    StateVector {
        vehicle_id: vehicle_id(i),
        timestamp_ms: state_time_ms(t0_ms, vehicles, i, k),
        latitude_deg: centre_lat + north / M_PER_DEG,
        longitude_deg: centre_lon + east / (M_PER_DEG * centre_lat.to_radians().cos()),
        depth_m: depth,
        altitude_m: 50.0 - depth,
        speed_mps: SPEED_MPS,
        yaw_deg: yaw,
        pitch_deg: -5.0 * phase.cos(),
        roll_deg: 2.0 * (phase * 3.0).sin(),
        battery_pct: (95.0 - t * 0.005).max(5.0),
    }
}

/// What writing the recording took.
struct Recording {
    messages: u64,
    bytes: u64,
    files: usize,
    write_s: f64,
    /// Log time of the first and the last message, ms.
    first_ms: i64,
    last_ms: i64,
}

/// Writes the announcements and `seconds` state vectors per vehicle into `dir`, in log
/// time order; each message's log time is its sample's timestamp.
fn write_recording(dir: &Path, vehicles: usize, seconds: u64, t0_ms: i64) -> Result<Recording> {
    let config = RecorderConfig {
        directory: dir.to_path_buf(),
        prefix: "replay-bench".into(),
        ..RecorderConfig::default()
    };
    let started = Instant::now();
    let mut w = RecordWriter::new(&config)?;
    let ns = |ms: i64| u64::try_from(ms).unwrap_or(0) * 1_000_000;
    let mut put = |sample: Sample, ms: i64| -> Result<()> {
        let payload = sample.encode().map_err(|e| anyhow::anyhow!("{e}"))?;
        w.write(sample.topic(), ns(ms), ns(ms), &payload)?;
        Ok(())
    };
    for i in 0..vehicles {
        put(Sample::VehicleAnnouncement(announcement(i, t0_ms)), t0_ms)?;
    }
    let mut last_ms = t0_ms;
    for k in 0..seconds {
        for i in 0..vehicles {
            let s = state(i, k, vehicles, t0_ms);
            last_ms = s.timestamp_ms;
            put(Sample::StateVector(s), last_ms)?;
        }
    }
    w.close()?;
    let write_s = started.elapsed().as_secs_f64();
    let bytes = w
        .files()
        .iter()
        .map(|f| std::fs::metadata(f).map(|m| m.len()))
        .sum::<std::io::Result<u64>>()?;
    Ok(Recording {
        messages: w.stats().messages,
        bytes,
        files: w.files().len(),
        write_s,
        first_ms: t0_ms,
        last_ms,
    })
}

// ---------------------------------------------------------------------------------------
// The schedule and the lag of deliveries behind it.

/// When each recorded message is due: the replay's first message (log time `t0_ms`) at
/// `start_us`, every other one its log-time distance later, divided by the speed.
#[derive(Debug, Clone, Copy)]
struct Schedule {
    start_us: i64,
    t0_ms: i64,
    speed: f64,
}

impl Schedule {
    /// Due instant of the message logged at `log_ms`, µs since the Unix epoch.
    fn due_us(&self, log_ms: i64) -> f64 {
        #[allow(clippy::cast_precision_loss)]
        let (start, offset) = (self.start_us as f64, (log_ms - self.t0_ms) as f64);
        start + offset * 1000.0 / self.speed
    }
}

/// A state vector as the subscriber received it.
#[derive(Debug, Clone, PartialEq)]
struct Arrival {
    vehicle: String,
    /// Its timestamp, which is its log time in the recording.
    timestamp_ms: i64,
    /// When the subscriber took it, µs since the Unix epoch.
    arrived_us: i64,
    /// The writer's source timestamp (when it was published), ms.
    source_ms: Option<i64>,
}

impl Arrival {
    /// Parses the subscriber's `sv VEHICLE TIMESTAMP_MS ARRIVED_US SOURCE_MS|-` line.
    fn parse(line: &str) -> Option<Self> {
        let mut f = line.strip_prefix("sv ")?.split(' ');
        let vehicle = f.next()?.to_string();
        let timestamp_ms = f.next()?.parse().ok()?;
        let arrived_us = f.next()?.parse().ok()?;
        let source_ms = match f.next()? {
            "-" => None,
            s => Some(s.parse().ok()?),
        };
        Some(Self {
            vehicle,
            timestamp_ms,
            arrived_us,
            source_ms,
        })
    }

    fn line(&self) -> String {
        let source = self.source_ms.map_or_else(|| "-".into(), |s| s.to_string());
        format!(
            "sv {} {} {} {source}",
            self.vehicle, self.timestamp_ms, self.arrived_us
        )
    }
}

/// Deliveries measured against the schedule.
#[derive(Debug, Default)]
struct Lags {
    /// Distinct state vectors (vehicle, timestamp) delivered.
    distinct: u64,
    /// Deliveries of a state vector already delivered.
    duplicates: u64,
    /// Arrival minus due, ms, sorted (first delivery of each).
    arrival_ms: Vec<f64>,
    /// Source timestamp minus due, ms, sorted: how late the replay published (1 ms
    /// resolution).
    publish_ms: Vec<f64>,
    /// The last arrival, µs since the Unix epoch.
    last_arrived_us: Option<i64>,
}

fn lags(arrivals: &[Arrival], schedule: &Schedule) -> Lags {
    let mut seen = HashSet::with_capacity(arrivals.len());
    let mut out = Lags::default();
    for a in arrivals {
        if !seen.insert((a.vehicle.as_str(), a.timestamp_ms)) {
            out.duplicates += 1;
            continue;
        }
        out.distinct += 1;
        let due = schedule.due_us(a.timestamp_ms);
        #[allow(clippy::cast_precision_loss)]
        out.arrival_ms.push((a.arrived_us as f64 - due) / 1000.0);
        if let Some(s) = a.source_ms {
            #[allow(clippy::cast_precision_loss)]
            out.publish_ms.push((s as f64 * 1000.0 - due) / 1000.0);
        }
        out.last_arrived_us = out.last_arrived_us.max(Some(a.arrived_us));
    }
    out.arrival_ms.sort_by(f64::total_cmp);
    out.publish_ms.sort_by(f64::total_cmp);
    out
}

// ---------------------------------------------------------------------------------------
// CPU time.

/// Clock ticks per second of `/proc/*/stat` (`getconf CLK_TCK`).
fn clock_ticks() -> Option<f64> {
    let out = std::process::Command::new("getconf")
        .arg("CLK_TCK")
        .output()
        .ok()?;
    String::from_utf8(out.stdout).ok()?.trim().parse().ok()
}

/// User plus system CPU time of a process (`self` or a pid) so far, s.
fn cpu_s(pid: &str, ticks: Option<f64>) -> Option<f64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // Fields after the command name (which may hold spaces) start with the state, field 3;
    // utime and stime are fields 14 and 15.
    let rest = stat.rsplit_once(')')?.1;
    let f: Vec<&str> = rest.split_whitespace().collect();
    let utime: f64 = f.get(11)?.parse().ok()?;
    let stime: f64 = f.get(12)?.parse().ok()?;
    Some((utime + stime) / ticks?)
}

// ---------------------------------------------------------------------------------------
// The subscriber process.

/// (helper) Subscribes to state vectors and announcements, prints `ready`, then
/// `count STATES ANNOUNCED` every 250 ms; when stdin closes, every state vector's arrival
/// (`sv ...` lines) and `end`.
pub(super) async fn sink(cfg: &ShoalConfig, domain: u16) -> Result<()> {
    let dds = dds(cfg, domain)?;
    let mut states = dds.subscribe::<StateVector>()?;
    let mut announcements = dds.subscribe::<VehicleAnnouncement>()?;
    let stop = crate::daemons::shutdown_signal(true);
    println!("ready");
    let mut got: Vec<Arrival> = Vec::new();
    let mut announced = HashSet::new();
    let mut tick = tokio::time::interval(Duration::from_millis(250));
    loop {
        tokio::select! {
            () = stop.cancelled() => break,
            item = states.next() => match item {
                Some(Ok((s, meta))) => got.push(Arrival {
                    arrived_us: unix_us(SystemTime::now()),
                    vehicle: s.vehicle_id.clone(),
                    timestamp_ms: s.timestamp_ms,
                    source_ms: meta.source_timestamp_ms,
                }),
                Some(Err(_)) => {}
                None => break,
            },
            item = announcements.next() => match item {
                Some(Ok((a, _))) => {
                    announced.insert(a.vehicle_id.clone());
                }
                Some(Err(_)) => {}
                None => break,
            },
            _ = tick.tick() => println!("count {} {}", got.len(), announced.len()),
        }
    }
    let mut out = std::io::BufWriter::new(std::io::stdout().lock());
    writeln!(out, "count {} {}", got.len(), announced.len())?;
    for a in &got {
        writeln!(out, "{}", a.line())?;
    }
    writeln!(out, "end")?;
    out.flush()?;
    Ok(())
}

/// What the subscriber reported.
#[derive(Default)]
struct SinkReport {
    arrivals: Vec<Arrival>,
    announced: u64,
}

/// Reads the subscriber's output: `ready` through the `ready` sender, the running counts
/// into `states` and `announced`, and at the end every arrival.
async fn read_sink(
    stdout: tokio::process::ChildStdout,
    ready: tokio::sync::oneshot::Sender<()>,
    states: Arc<AtomicU64>,
    announced: Arc<AtomicU64>,
) -> Result<SinkReport> {
    let mut lines = tokio::io::BufReader::new(stdout).lines();
    let mut ready = Some(ready);
    let mut report = SinkReport::default();
    while let Some(line) = lines.next_line().await? {
        if line == "ready" {
            if let Some(r) = ready.take() {
                let _ = r.send(());
            }
        } else if let Some(rest) = line.strip_prefix("count ") {
            let mut n = rest.split(' ').map(|x| x.parse::<u64>().unwrap_or(0));
            states.store(n.next().unwrap_or(0), Ordering::Relaxed);
            let a = n.next().unwrap_or(0);
            announced.store(a, Ordering::Relaxed);
            report.announced = a;
        } else if line == "end" {
            return Ok(report);
        } else if let Some(a) = Arrival::parse(&line) {
            report.arrivals.push(a);
        }
    }
    bail!("the subscriber process ended without its report")
}

// ---------------------------------------------------------------------------------------
// The benchmark.

pub(super) async fn replay(cfg: &ShoalConfig, plan: Plan) -> Result<()> {
    let Plan {
        vehicles,
        seconds,
        speed,
        domain,
    } = plan;
    if vehicles == 0 || seconds == 0 {
        bail!("--vehicles and --seconds must be at least 1");
    }
    let Some(pace) = Speed::factor(speed) else {
        bail!("--speed must be 1 to 100 (the replayer's range), not {speed}");
    };
    // As `shoal replay`: an insecure replay stays on loopback unless allowed.
    if !cfg.dds.is_loopback_only() && !cfg.security.allow_insecure_network {
        bail!(
            "refusing an insecure replay on non-loopback interfaces ({:?}); run it in a network namespace with dds.interfaces on loopback",
            cfg.dds.interfaces
        );
    }
    let work = tempfile_dir()?;
    let dir = work.join("replay-recording");
    let result = run(cfg, &dir, vehicles, seconds, speed, pace, domain).await;
    let _ = std::fs::remove_dir_all(&work);
    result
}

#[allow(clippy::too_many_lines)]
async fn run(
    cfg: &ShoalConfig,
    dir: &Path,
    vehicles: usize,
    seconds: u64,
    speed: f64,
    pace: Speed,
    domain: u16,
) -> Result<()> {
    // The recording ends now: an hour of the fleet just gone, to the second.
    let span_ms = i64::try_from(seconds).unwrap_or(i64::MAX / 2000) * 1000;
    let t0_ms = (shoal_model::now_ms() - span_ms).div_euclid(1000) * 1000;
    eprintln!(
        "replay: writing {vehicles} vehicles × {seconds} s of recorded time into {}...",
        dir.display()
    );
    let d = dir.to_path_buf();
    let rec = tokio::task::spawn_blocking(move || write_recording(&d, vehicles, seconds, t0_ms))
        .await??;
    let expected_states = vehicles as u64 * seconds;

    eprintln!("replay: starting the subscriber process...");
    let mut child = helper(
        cfg,
        &["replay-sink".into(), "--domain".into(), domain.to_string()],
    )?;
    let sink_pid = child.id().map(|p| p.to_string());
    let stdout = child.stdout.take().context("no subscriber stdout")?;
    let (ready_tx, ready_rx) = tokio::sync::oneshot::channel();
    let (got_states, got_announced) = (Arc::new(AtomicU64::new(0)), Arc::new(AtomicU64::new(0)));
    let reader = tokio::spawn(read_sink(
        stdout,
        ready_tx,
        Arc::clone(&got_states),
        Arc::clone(&got_announced),
    ));
    tokio::time::timeout(Duration::from_secs(30), ready_rx)
        .await
        .context("the subscriber was not ready within 30 s")?
        .context("the subscriber process ended")?;

    let pubsub = dds(cfg, domain)?;
    // Writers of both topics on the replay's participant, matched before the start: the
    // subscriber's readers are then known, so the replayer's own writers match as they are
    // created and its clock does not pause for discovery (which would shift the schedule).
    let probe_states = pubsub.writer::<StateVector>(WriterOptions::new(Priority::Telemetry))?;
    let probe_ann = pubsub.writer::<VehicleAnnouncement>(WriterOptions::new(Priority::Control))?;
    let t = Instant::now();
    while probe_states.matched_readers() < 1 || probe_ann.matched_readers() < 1 {
        if t.elapsed() > Duration::from_secs(30) {
            bail!("the subscriber's readers were not matched within 30 s");
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let publishers = Publishers::insecure(Arc::clone(&pubsub))?;
    let start_at = SystemTime::now() + Duration::from_millis(500);
    let schedule = Schedule {
        start_us: unix_us(start_at),
        t0_ms: rec.first_ms,
        speed,
    };
    let mut replayer = Replayer::new(
        publishers,
        ReplayOptions {
            speed: pace,
            start_at: Some(start_at),
            ..ReplayOptions::default()
        },
    );
    let recorded_s = (rec.last_ms - rec.first_ms) as f64 / 1000.0;
    let ideal_s = recorded_s / speed;
    eprintln!(
        "replay: {} messages, {recorded_s:.2} s recorded, at {speed}× (ideal {ideal_s:.2} s)...",
        rec.messages
    );
    replayer.on_progress(Duration::from_secs(10), |s| {
        eprintln!("replay: {} read, {} published", s.read, s.published);
    });
    let ticks = clock_ticks();
    let cpu_before = cpu_s("self", ticks);
    let cancel = CancellationToken::new();
    let damaged = replayer.replay_path(dir, &cancel).await?;
    let published_at = SystemTime::now();
    let cpu_after = cpu_s("self", ticks);
    if let Some(e) = damaged.first() {
        bail!("the recording could not be replayed to its end: {e}");
    }
    let stats = replayer.stats();

    // Deliveries still in flight: until everything arrived, or nothing more for a while.
    let want = (expected_states, vehicles as u64);
    let mut last = (0, 0);
    let mut changed = Instant::now();
    loop {
        let now = (
            got_states.load(Ordering::Relaxed),
            got_announced.load(Ordering::Relaxed),
        );
        if now.0 >= want.0 && now.1 >= want.1 {
            break;
        }
        if now != last {
            (last, changed) = (now, Instant::now());
        } else if changed.elapsed() > DRAIN_QUIET {
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let sink_cpu = sink_pid.as_deref().and_then(|p| cpu_s(p, ticks));
    drop(child.stdin.take());
    let report = tokio::time::timeout(Duration::from_secs(60), reader)
        .await
        .context("the subscriber's report did not come within 60 s")???;
    let _ = tokio::time::timeout(Duration::from_secs(10), child.wait()).await;
    drop((probe_states, probe_ann, replayer));

    let lag = lags(&report.arrivals, &schedule);
    let start_us = schedule.start_us;
    #[allow(clippy::cast_precision_loss)]
    let wall_published_s = (unix_us(published_at) - start_us) as f64 / 1e6;
    #[allow(clippy::cast_precision_loss)]
    let wall_delivered_s = lag
        .last_arrived_us
        .map_or(f64::NAN, |l| (l - start_us) as f64 / 1e6);
    // The stricter of the two ends the replay.
    let wall_s = wall_published_s.max(wall_delivered_s);
    let achieved = recorded_s / wall_s;
    let delivered = lag.distinct + report.announced.min(vehicles as u64);
    let lost = rec.messages.saturating_sub(delivered);
    let met = achieved >= SPEED_SHARE * speed
        && lost == 0
        && stats.published == rec.messages
        && stats.write_failed == 0;
    let replay_cpu = cpu_before.zip(cpu_after).map(|(b, a)| a - b);

    println!("# shoal bench replay — {} — {}", machine(), date());
    println!(
        "# {vehicles} vehicles × {seconds} s (announcement + 1 state vector/s each), replayed at {speed}× to a subscriber in another process"
    );
    let row = |figure: &str, measured: String, target: &str| {
        println!("{figure:<46} {measured:>28}  {target}");
    };
    row("figure", "measured".into(), "target");
    row(
        "recording written (RecordWriter, zstd)",
        format!(
            "{} msgs, {:.1} MB, {} file(s)",
            rec.messages,
            mb(rec.bytes),
            rec.files
        ),
        "",
    );
    row("  write time", format!("{:.2} s", rec.write_s), "");
    row("recorded duration", format!("{recorded_s:.2} s"), "");
    row("speed asked", format!("{speed}×"), "");
    row(
        "replay wall time (first due → last delivered)",
        format!("{wall_s:.3} s"),
        &format!("ideal {ideal_s:.3} s"),
    );
    row(
        "  first due → last published",
        format!("{wall_published_s:.3} s"),
        "",
    );
    row(
        "achieved speed-up",
        format!("{achieved:.2}×"),
        &format!("≥ {:.0}× ({SPEED_SHARE} × {speed})", SPEED_SHARE * speed),
    );
    row(
        "published / delivered / lost",
        format!("{} / {delivered} / {lost}", stats.published),
        &format!("no loss (recorded {})", rec.messages),
    );
    row(
        "  state vectors delivered (duplicates)",
        format!("{} of {expected_states} ({})", lag.distinct, lag.duplicates),
        "",
    );
    row(
        "  announcements delivered",
        format!("{} of {vehicles}", report.announced),
        "",
    );
    if stats.write_failed + stats.invalid + stats.undecodable > 0 {
        row(
            "  write failed / invalid / undecodable",
            format!(
                "{} / {} / {}",
                stats.write_failed, stats.invalid, stats.undecodable
            ),
            "",
        );
    }
    row(
        "lag behind schedule p50 / p99 / max",
        format!(
            "{:.1} / {:.1} / {:.1} ms",
            percentile(&lag.arrival_ms, 50.0),
            percentile(&lag.arrival_ms, 99.0),
            lag.arrival_ms.last().copied().unwrap_or(f64::NAN)
        ),
        "",
    );
    row(
        "  published late (source stamp) p50 / p99 / max",
        format!(
            "{:.0} / {:.0} / {:.0} ms",
            percentile(&lag.publish_ms, 50.0),
            percentile(&lag.publish_ms, 99.0),
            lag.publish_ms.last().copied().unwrap_or(f64::NAN)
        ),
        "",
    );
    row(
        "replayer process CPU (user + system)",
        cpu_line(replay_cpu, wall_published_s),
        "",
    );
    row(
        "subscriber process CPU (whole run)",
        sink_cpu.map_or_else(|| "-".into(), |c| format!("{c:.2} s")),
        "",
    );
    println!(
        "verdict: {} — {seconds} s of {vehicles} vehicles replayed at {achieved:.2}× (target ≥ {:.0}× of {speed}×, no loss)",
        if met { "met" } else { "NOT met" },
        SPEED_SHARE * speed
    );
    Ok(())
}

fn mb(bytes: u64) -> f64 {
    #[allow(clippy::cast_precision_loss)]
    let b = bytes as f64;
    b / 1e6
}

fn cpu_line(cpu: Option<f64>, wall_s: f64) -> String {
    cpu.map_or_else(
        || "-".into(),
        |c| format!("{c:.2} s ({:.0} % of a core)", 100.0 * c / wall_s),
    )
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::float_cmp)]
    use shoal_model::Validate;

    use super::*;

    #[test]
    fn the_schedule_divides_recorded_time_by_the_speed() {
        let s = Schedule {
            start_us: 1_000_000,
            t0_ms: 5_000,
            speed: 100.0,
        };
        assert_eq!(s.due_us(5_000), 1_000_000.0);
        // An hour of recorded time is due 36 s after the start at 100×.
        assert_eq!(s.due_us(5_000 + 3_600_000), 1_000_000.0 + 36e6);
        assert_eq!(s.due_us(5_010), 1_000_100.0);
    }

    #[test]
    fn lags_count_each_state_once_and_measure_it_against_its_due_instant() {
        let s = Schedule {
            start_us: 0,
            t0_ms: 0,
            speed: 10.0,
        };
        let a = |v: &str, ts: i64, at: i64, src: Option<i64>| Arrival {
            vehicle: v.into(),
            timestamp_ms: ts,
            arrived_us: at,
            source_ms: src,
        };
        let arrivals = [
            // Due at 100 ms, arrives at 102 ms, published at 101 ms.
            a("a", 1000, 102_000, Some(101)),
            a("b", 1000, 100_500, None),
            a("a", 1000, 150_000, Some(140)),
            a("a", 2000, 230_000, Some(210)),
        ];
        let l = lags(&arrivals, &s);
        assert_eq!((l.distinct, l.duplicates), (3, 1));
        assert_eq!(l.arrival_ms, [0.5, 2.0, 30.0]);
        assert_eq!(l.publish_ms, [1.0, 10.0]);
        assert_eq!(l.last_arrived_us, Some(230_000));
    }

    #[test]
    fn arrival_lines_round_trip() {
        for a in [
            Arrival {
                vehicle: "auv-007".into(),
                timestamp_ms: 1_750_000_000_123,
                arrived_us: 1_760_000_000_000_456,
                source_ms: Some(1_760_000_000_000),
            },
            Arrival {
                vehicle: "x".into(),
                timestamp_ms: 1,
                arrived_us: 2,
                source_ms: None,
            },
        ] {
            assert_eq!(Arrival::parse(&a.line()), Some(a));
        }
        assert_eq!(Arrival::parse("count 1 2"), None);
    }

    #[test]
    fn recorded_vehicles_are_valid_and_move_at_their_speed() {
        let t0 = 1_750_000_000_000;
        for i in [0, 7, 99] {
            announcement(i, t0).validate().unwrap();
            let mut prev: Option<StateVector> = None;
            for k in 0..3600 {
                let s = state(i, k, 100, t0);
                s.validate().unwrap();
                assert_eq!(s.timestamp_ms, t0 + k as i64 * 1000 + i as i64 * 10);
                if let Some(p) = prev {
                    let north = (s.latitude_deg - p.latitude_deg) * M_PER_DEG;
                    let east = (s.longitude_deg - p.longitude_deg)
                        * M_PER_DEG
                        * s.latitude_deg.to_radians().cos();
                    let d = north.hypot(east);
                    assert!((d - SPEED_MPS).abs() < 0.01, "moved {d} m in a second");
                    // Heading points along the move (within the turn of one second).
                    let heading = east.atan2(north).to_degrees().rem_euclid(360.0);
                    let diff = (heading - p.yaw_deg + 540.0).rem_euclid(360.0) - 180.0;
                    assert!(diff.abs() < 1.0, "heading {heading} vs yaw {}", p.yaw_deg);
                }
                prev = Some(s);
            }
        }
    }
}
