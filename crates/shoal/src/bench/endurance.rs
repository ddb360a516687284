//! `shoal bench endurance`: a deployment's lifetime compressed. A station (real DDS, real
//! SQLite history) gives simulated vehicles back-to-back tasks (goto, survey, hold); the
//! vehicles, which finish each task at once, each keep a real task ledger on disk. On a
//! schedule, vehicles restart (their ledger reopened, their task reader a late joiner),
//! the station restarts on the same history, and the station's system clock steps an hour
//! forward and back. Every report interval it prints the station process's RSS, the fleet
//! process's RSS, the history's size, the late-joiner burst (tasks a new reader is handed),
//! the tasks-by-state query's p50, and at the end a trend line of the station's RSS against
//! completed tasks.
//!
//! The fleet runs in its own process (`bench endurance-fleet`, see [`fleet`]): its ledgers
//! grow by design (each remembers a task until an hour after its expiry), and in one
//! process that growth would hide whether the station's own state stays bounded. The two
//! talk over the child's stdin and stdout, one line each way per request (see
//! [`FleetCommand`]).
//!
//! Counted by the vehicles themselves: tasks executed twice (must be zero). Counted at the
//! station: contact changes while the clock was stepped (must be zero).

use std::collections::{HashMap, VecDeque};
use std::fmt::Write as _;
use std::io::{BufRead as _, Write as _};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicI64, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use futures::StreamExt;
use shoal_dds::{Priority, PubSub, Writer, WriterOptions};
use shoal_history::{History, HistoryConfig};
use shoal_model::{
    EventKind, GeoPoint, StateVector, Task, TaskAssignment, TaskState, TaskStatus,
    VehicleAnnouncement, VehicleKind, now_ms,
};
use shoal_proxy::ledger::{Admission, TaskLedger};
use shoal_proxy::sim::{SimSpec, SimVehicle};
use shoal_semantic::QueryLimits;
use shoal_station::{Clock, Station, StationConfig, StationHandle};
use tokio::io::{AsyncBufReadExt as _, AsyncWriteExt as _};
use tokio_util::sync::CancellationToken;

use super::helpers::{date, dds, helper, machine, percentile, rss_mb, rss_mb_of, tempfile_dir};
use crate::config::ShoalConfig;

/// What one run does.
#[derive(Debug, Clone)]
pub(super) struct Plan {
    pub(super) vehicles: usize,
    pub(super) tasks: u64,
    pub(super) report_every: u64,
    pub(super) domain: u16,
    pub(super) out: Option<PathBuf>,
}

/// One row of the report.
#[derive(Debug, Clone)]
struct Row {
    completed: u64,
    elapsed_s: f64,
    station_rss_mb: f64,
    fleet_rss_mb: f64,
    history_mb: f64,
    burst: usize,
    q3_p50_ms: f64,
    register_tasks: usize,
}

/// The station side, restartable on the same history.
struct StationRun {
    handle: StationHandle,
    stop: CancellationToken,
    join:
        tokio::task::JoinHandle<Result<shoal_station::StationReport, shoal_station::StationError>>,
}

fn start_station(
    cfg: &ShoalConfig,
    dir: &Path,
    dds: &Arc<PubSub>,
    offset: &Arc<AtomicI64>,
) -> Result<StationRun> {
    let history = History::open(&HistoryConfig {
        path: dir.join("history.db"),
        ..cfg.history.clone()
    })?;
    let station = Station::with_clock(
        StationConfig {
            summary_interval_s: 0.0,
            rules_path: dir.join("rules.json"),
            // Retention at its shortest, so a compressed run shows it at work.
            task_retention_s: 60.0,
            ..cfg.station.clone()
        },
        Arc::clone(dds),
        history,
        Clock::system_offset(Arc::clone(offset)),
    )?;
    let handle = station.handle();
    let stop = CancellationToken::new();
    let join = tokio::spawn(station.run(stop.clone()));
    Ok(StationRun { handle, stop, join })
}

impl StationRun {
    async fn stop(self) -> Result<()> {
        self.stop.cancel();
        self.join.await??;
        Ok(())
    }
}

/// The simulated fleet: one participant, a real ledger per vehicle; it lives in the
/// `endurance-fleet` process.
struct Fleet {
    ids: Vec<String>,
    specs: HashMap<String, SimVehicle>,
    ledgers: HashMap<String, TaskLedger>,
    dir: PathBuf,
    /// Times each task was executed (handed to the vehicle), recent tasks only.
    executions: HashMap<String, u32>,
    order: VecDeque<String>,
    twice: u64,
    completed: u64,
    status: Writer<TaskStatus>,
    state: Writer<StateVector>,
    announcement: Writer<VehicleAnnouncement>,
}

impl Fleet {
    fn new(dds: &PubSub, n: usize, dir: &Path) -> Result<Self> {
        let mut ids = Vec::new();
        let mut specs = HashMap::new();
        let mut ledgers = HashMap::new();
        let dir = dir.join("vehicles");
        for i in 0..n {
            let id = vehicle_id(i);
            let spec = SimSpec {
                id: id.clone(),
                kind: VehicleKind::Auv,
                latitude_deg: 63.4 + f64::from(u32::try_from(i % 100).unwrap_or(0)) * 1e-3,
                longitude_deg: 10.4,
                rate_hz: 1.0,
                battery_pct: 100.0,
            };
            specs.insert(id.clone(), SimVehicle::new(&spec, now_ms()));
            let ledger = TaskLedger::open(&dir, &id, Some(900_000))
                .with_context(|| format!("cannot open the ledger of {id} in {}", dir.display()))?;
            ledgers.insert(id.clone(), ledger);
            ids.push(id);
        }
        Ok(Self {
            ids,
            specs,
            ledgers,
            dir,
            executions: HashMap::new(),
            order: VecDeque::new(),
            twice: 0,
            completed: 0,
            status: dds.writer(WriterOptions::new(Priority::Control))?,
            state: dds.writer(WriterOptions::new(Priority::Telemetry))?,
            announcement: dds.writer(WriterOptions::new(Priority::Control))?,
        })
    }

    async fn announce(&self) -> Result<()> {
        for id in &self.ids {
            let mut a = self.specs[id].announcement.clone();
            a.timestamp_ms = now_ms();
            self.announcement
                .write(a)
                .await
                .map_err(|e| anyhow::anyhow!("{e}"))?;
        }
        Ok(())
    }

    async fn report_states(&self) {
        let now = now_ms();
        for id in &self.ids {
            // A full history or a slow reader is the measurement's business, not an error.
            let _ = self.state.write(self.specs[id].state(now)).await;
        }
    }

    async fn status(&self, task: &TaskAssignment, state: TaskState, message: &str) {
        let s = TaskStatus {
            task_id: task.task_id.clone(),
            vehicle_id: task.vehicle_id.clone(),
            timestamp_ms: now_ms(),
            state,
            progress_pct: if state == TaskState::Done { 100.0 } else { 0.0 },
            message: message.to_owned(),
        };
        let _ = self.status.write(s).await;
    }

    /// A vehicle restarts: what it remembers is only what its ledger file says.
    fn restart(&mut self, id: &str) -> Result<()> {
        self.ledgers.remove(id);
        let ledger = TaskLedger::open(&self.dir, id, Some(900_000))
            .with_context(|| format!("cannot reopen the ledger of {id}"))?;
        self.ledgers.insert(id.to_owned(), ledger);
        Ok(())
    }

    fn progress(&self) -> FleetProgress {
        FleetProgress {
            completed: self.completed,
            twice: self.twice,
        }
    }

    async fn on_task(&mut self, a: &TaskAssignment) -> Result<()> {
        let Some(ledger) = self.ledgers.get_mut(&a.vehicle_id) else {
            return Ok(());
        };
        let admission = ledger
            .admit(a, now_ms())
            .with_context(|| format!("ledger of {}", a.vehicle_id))?;
        match admission {
            Admission::Start => {
                let n = self.executions.entry(a.task_id.clone()).or_insert(0);
                *n += 1;
                if *n > 1 {
                    self.twice += 1;
                } else {
                    self.order.push_back(a.task_id.clone());
                    while self.order.len() > 20_000 {
                        if let Some(old) = self.order.pop_front() {
                            self.executions.remove(&old);
                        }
                    }
                }
                // Time compressed: accepted, running and done at once.
                ledger
                    .end(&a.task_id, TaskState::Done, now_ms())
                    .with_context(|| format!("ledger of {}", a.vehicle_id))?;
                self.status(a, TaskState::Accepted, "").await;
                self.status(a, TaskState::Running, "").await;
                self.status(a, TaskState::Done, "").await;
                self.completed += 1;
            }
            Admission::Ended(state) => {
                self.status(a, state, "already ended before; not run again")
                    .await;
            }
            Admission::Expired => self.status(a, TaskState::Expired, "expired").await,
            // Tasks here end as they start: nothing is ever left under way to resume.
            Admission::Resume | Admission::Duplicate => {}
        }
        Ok(())
    }
}

/// The id of the fleet's `i`-th vehicle; both processes derive the fleet from its size.
fn vehicle_id(i: usize) -> String {
    format!("end-{i}")
}

/// What the benchmark asks the fleet process, one line on its stdin; each is answered with
/// one line on its stdout, `<word> <completed> <twice>` (see [`FleetProgress`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum FleetCommand {
    /// Only the progress.
    Count,
    /// A tenth of the vehicles restart (ledgers reopened) and the task reader is replaced
    /// (a late joiner), before the answer.
    Restart,
    /// Answer, then end.
    Stop,
}

impl FleetCommand {
    fn word(self) -> &'static str {
        match self {
            Self::Count => "count",
            Self::Restart => "restart",
            Self::Stop => "stop",
        }
    }

    fn parse(line: &str) -> Option<Self> {
        [Self::Count, Self::Restart, Self::Stop]
            .into_iter()
            .find(|c| c.word() == line.trim())
    }
}

/// The word of the fleet process's first line, once its vehicles are announced.
const READY: &str = "ready";

/// What the fleet process reports: tasks it ran to the end, and tasks it was handed to run
/// a second time (counted by the vehicles, from what their ledgers admitted).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
struct FleetProgress {
    completed: u64,
    twice: u64,
}

fn reply_line(word: &str, p: FleetProgress) -> String {
    format!("{word} {} {}", p.completed, p.twice)
}

/// `<word> <completed> <twice>` with a word of the protocol, or `None` for any other line.
fn parse_reply(line: &str) -> Option<(&str, FleetProgress)> {
    let mut parts = line.split_whitespace();
    let word = parts
        .next()
        .filter(|w| *w == READY || FleetCommand::parse(w).is_some())?;
    let completed = parts.next()?.parse().ok()?;
    let twice = parts.next()?.parse().ok()?;
    if parts.next().is_some() {
        return None;
    }
    Some((word, FleetProgress { completed, twice }))
}

/// Waits for the fleet process to come up (announce its vehicles).
const READY_WITHIN: Duration = Duration::from_secs(60);
/// Waits for any answer; a fleet that is alive answers within milliseconds, so this only
/// turns a stuck process into an error instead of a hang.
const ANSWER_WITHIN: Duration = Duration::from_secs(30);

/// The fleet process, as the benchmark drives it.
struct FleetProcess {
    child: tokio::process::Child,
    pid: String,
    stdin: tokio::process::ChildStdin,
    lines: tokio::io::Lines<tokio::io::BufReader<tokio::process::ChildStdout>>,
}

impl FleetProcess {
    async fn start(cfg: &ShoalConfig, plan: &Plan, dir: &Path) -> Result<Self> {
        let args = [
            "endurance-fleet".to_string(),
            "--domain".into(),
            plan.domain.to_string(),
            "--vehicles".into(),
            plan.vehicles.to_string(),
            "--dir".into(),
            dir.display().to_string(),
        ];
        let mut child = helper(cfg, &args).context("cannot start the fleet process")?;
        let pid = child
            .id()
            .context("the fleet process ended as it started")?
            .to_string();
        let stdin = child.stdin.take().context("no fleet process stdin")?;
        let stdout = child.stdout.take().context("no fleet process stdout")?;
        let mut fleet = Self {
            child,
            pid,
            stdin,
            lines: tokio::io::BufReader::new(stdout).lines(),
        };
        fleet.answer(READY, READY_WITHIN).await?;
        Ok(fleet)
    }

    async fn ask(&mut self, command: FleetCommand) -> Result<FleetProgress> {
        let line = format!("{}\n", command.word());
        if let Err(e) = self.stdin.write_all(line.as_bytes()).await {
            let ended = self.exit_status().await;
            bail!(
                "cannot tell the fleet process to {} ({e}): it {ended}",
                command.word()
            );
        }
        self.answer(command.word(), ANSWER_WITHIN).await
    }

    /// The next answer, which must carry `word`; lines that are not answers at all (a
    /// library printing to stdout) are skipped.
    async fn answer(&mut self, word: &str, within: Duration) -> Result<FleetProgress> {
        let deadline = tokio::time::Instant::now() + within;
        loop {
            let line = match tokio::time::timeout_at(deadline, self.lines.next_line()).await {
                Err(_) => bail!(
                    "the fleet process (pid {}) did not answer `{word}` within {} s",
                    self.pid,
                    within.as_secs()
                ),
                Ok(Ok(Some(line))) => line,
                Ok(Ok(None)) => {
                    let ended = self.exit_status().await;
                    bail!("the fleet process {ended} before answering `{word}`");
                }
                Ok(Err(e)) => {
                    return Err(e).context("cannot read the fleet process's answer");
                }
            };
            match parse_reply(&line) {
                Some((w, progress)) if w == word => return Ok(progress),
                Some((w, _)) => {
                    bail!("the fleet process answered `{w}` where `{word}` was due: out of step")
                }
                None => {}
            }
        }
    }

    /// How the process ended, for an error message ("ended with exit status: 1").
    async fn exit_status(&mut self) -> String {
        match tokio::time::timeout(Duration::from_secs(5), self.child.wait()).await {
            Ok(Ok(status)) => format!("ended with {status} (its error, if any, is above)"),
            Ok(Err(e)) => format!("cannot be waited for ({e})"),
            Err(_) => "closed its output but did not end".to_string(),
        }
    }

    fn rss_mb(&self) -> f64 {
        rss_mb_of(&self.pid)
    }

    /// Tells the fleet to stop, and its last progress.
    async fn stop(mut self) -> Result<FleetProgress> {
        let last = self.ask(FleetCommand::Stop).await?;
        drop(self.stdin);
        match tokio::time::timeout(Duration::from_secs(10), self.child.wait()).await {
            Ok(Ok(status)) if status.success() => Ok(last),
            Ok(Ok(status)) => bail!("the fleet process ended with {status}"),
            Ok(Err(e)) => Err(e).context("cannot wait for the fleet process"),
            // Dropping the child kills it.
            Err(_) => bail!("the fleet process did not end within 10 s of being told to stop"),
        }
    }
}

/// Lines from stdin until it closes. A plain thread, not `tokio::io::stdin`: that read
/// runs on the runtime's blocking pool, which the runtime waits for when it shuts down, so
/// the process could not end while the parent still held the pipe open.
fn stdin_lines() -> Result<tokio::sync::mpsc::UnboundedReceiver<String>> {
    let (tx, rx) = tokio::sync::mpsc::unbounded_channel();
    std::thread::Builder::new()
        .name("fleet-commands".into())
        .spawn(move || {
            for line in std::io::stdin().lock().lines() {
                let Ok(line) = line else { break };
                if tx.send(line).is_err() {
                    break;
                }
            }
        })
        .context("cannot start the command reader")?;
    Ok(rx)
}

fn tell_parent(word: &str, p: FleetProgress) -> Result<()> {
    let mut out = std::io::stdout().lock();
    writeln!(out, "{}", reply_line(word, p))
        .and_then(|()| out.flush())
        .context("cannot answer the benchmark process (has it ended?)")
}

/// `shoal bench endurance-fleet`: the fleet of `bench endurance` in a process of its own,
/// its ledgers under `dir`, driven by [`FleetCommand`]s on stdin; it ends when stdin closes.
pub(super) async fn fleet(
    cfg: &ShoalConfig,
    domain: u16,
    vehicles: usize,
    dir: &Path,
) -> Result<()> {
    let mut commands = stdin_lines()?;
    let p = dds(cfg, domain)?;
    let mut fleet = Fleet::new(&p, vehicles, dir)?;
    fleet.announce().await?;
    let mut sub = p.subscribe::<TaskAssignment>()?;
    tell_parent(READY, fleet.progress())?;
    // State at 1 Hz, tasks as they come, and the parent's commands, in one loop: a command
    // is answered between two tasks, so its counts are exact at that instant.
    let mut tick = tokio::time::interval(Duration::from_secs(1));
    loop {
        tokio::select! {
            line = commands.recv() => {
                // No more commands: the benchmark process has ended.
                let Some(line) = line else { return Ok(()) };
                let command = FleetCommand::parse(&line)
                    .with_context(|| format!("unknown command from the benchmark: {line:?}"))?;
                if command == FleetCommand::Restart {
                    for id in fleet.ids.clone().iter().step_by(10) {
                        fleet.restart(id)?;
                    }
                    sub = p.subscribe::<TaskAssignment>()?;
                }
                tell_parent(command.word(), fleet.progress())?;
                if command == FleetCommand::Stop {
                    return Ok(());
                }
            }
            _ = tick.tick() => fleet.report_states().await,
            item = sub.next() => match item {
                Some(Ok((a, _))) => fleet.on_task(&a).await?,
                Some(Err(_)) => {}
                None => bail!("the task reader ended"),
            },
        }
    }
}

fn task_for(n: u64, vehicle: &str) -> TaskAssignment {
    let p = |lat: f64, lon: f64| GeoPoint {
        latitude_deg: lat,
        longitude_deg: lon,
    };
    let task = match n % 3 {
        0 => Task::GotoWaypoint {
            target: p(63.401, 10.401),
            depth_m: Some(5.0),
            altitude_m: None,
            speed_mps: 1.5,
        },
        1 => Task::SurveyArea {
            polygon: vec![p(63.40, 10.40), p(63.40, 10.401), p(63.401, 10.401)],
            line_spacing_m: 20.0,
            depth_m: Some(5.0),
            altitude_m: None,
            speed_mps: 1.5,
        },
        _ => Task::Hold { duration_s: 1.0 },
    };
    TaskAssignment::new(format!("e{n}"), "", vehicle, now_ms(), &task)
}

fn file_mb(path: &Path) -> f64 {
    let size = |p: PathBuf| std::fs::metadata(p).map_or(0, |m| m.len());
    let base = path.to_path_buf();
    let mut wal = base.clone().into_os_string();
    wal.push("-wal");
    #[allow(clippy::cast_precision_loss)]
    let mb = (size(base) + size(PathBuf::from(wal))) as f64 / 1e6;
    mb
}

fn q3_p50_ms(h: &StationHandle) -> f64 {
    let q = shoal_semantic::STANDARD_QUERIES
        .iter()
        .find(|(n, _)| *n == "q3_tasks_by_state")
        .map_or("", |(_, q)| q);
    let mut ms = Vec::new();
    for _ in 0..15 {
        let t = Instant::now();
        if h.sparql(q, &QueryLimits::default()).is_err() {
            return f64::NAN;
        }
        ms.push(t.elapsed().as_secs_f64() * 1e3);
    }
    ms.sort_by(f64::total_cmp);
    percentile(&ms, 50.0)
}

/// How many tasks a reader joining now is handed by the station within a second.
async fn late_joiner_burst(cfg: &ShoalConfig, domain: u16) -> Result<usize> {
    let p = dds(cfg, domain)?;
    let mut sub = p.subscribe::<TaskAssignment>()?;
    let mut n = 0;
    let end = tokio::time::Instant::now() + Duration::from_millis(1500);
    while let Ok(Some(_)) = tokio::time::timeout_at(end, sub.next()).await {
        n += 1;
    }
    Ok(n)
}

/// Least-squares slope of y against x (per unit of x).
fn slope(points: &[(f64, f64)]) -> f64 {
    #[allow(clippy::cast_precision_loss)]
    let n = points.len() as f64;
    let (sx, sy) = points
        .iter()
        .fold((0.0, 0.0), |(a, b), (x, y)| (a + x, b + y));
    let (mx, my) = (sx / n, sy / n);
    let (num, den) = points.iter().fold((0.0, 0.0), |(a, b), (x, y)| {
        (a + (x - mx) * (y - my), b + (x - mx) * (x - mx))
    });
    if den == 0.0 { 0.0 } else { num / den }
}

pub(super) async fn endurance(cfg: &ShoalConfig, plan: Plan) -> Result<()> {
    if plan.vehicles == 0 || plan.tasks == 0 || plan.report_every == 0 {
        bail!("--vehicles, --tasks and --report-every must be positive");
    }
    let dir = tempfile_dir()?.join("endurance");
    std::fs::create_dir_all(&dir)?;
    let offset = Arc::new(AtomicI64::new(0));
    let station_dds = dds(cfg, plan.domain)?;
    let mut station = start_station(cfg, &dir, &station_dds, &offset)?;
    let mut fleet = FleetProcess::start(cfg, &plan, &dir).await?;

    println!(
        "endurance: {} vehicles (in their own process, pid {}), {} tasks, a row every {}; \
         vehicle restarts every row, a station restart at 1/2, a clock step of +1 h at 3/10 \
         and back at 2/5",
        plan.vehicles, fleet.pid, plan.tasks, plan.report_every
    );
    wait_alive(&station.handle, plan.vehicles).await?;
    let started = Instant::now();
    let mut rows: Vec<Row> = Vec::new();
    let mut next_task: u64 = 0;
    let mut current: HashMap<String, String> = HashMap::new();
    let mut next_row = plan.report_every;
    let (mut stepped, mut stepped_back, mut restarted) = (false, false, false);
    let lost_before_step = comm_lost(&station.handle);
    let mut contact_changes_in_step = 0usize;
    let ids: Vec<String> = (0..plan.vehicles).map(vehicle_id).collect();
    let mut last_progress = (0u64, Instant::now());
    let mut done = 0;
    while done < plan.tasks {
        let h = station.handle.clone();
        for id in &ids {
            let idle = current
                .get(id)
                .is_none_or(|t| h.task(t).is_none_or(|v| v.state.is_final()));
            if idle && next_task < plan.tasks + plan.vehicles as u64 {
                let a = task_for(next_task, id);
                next_task += 1;
                if h.dispatch_now(a.clone()).is_ok() {
                    current.insert(id.clone(), a.task_id);
                }
            }
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
        done = fleet.ask(FleetCommand::Count).await?.completed;
        if done > last_progress.0 {
            last_progress = (done, Instant::now());
        } else if last_progress.1.elapsed() > Duration::from_secs(120) {
            bail!("no task completed for two minutes (at {done})");
        }
        let fraction = |num: u64, den: u64| plan.tasks * num / den;
        if !stepped && done >= fraction(3, 10) {
            stepped = true;
            offset.store(3_600_000, Ordering::SeqCst);
            println!("  {done}: the station's system clock steps +1 h");
        }
        if stepped && !stepped_back && done >= fraction(2, 5) {
            stepped_back = true;
            contact_changes_in_step = comm_lost(&station.handle) - lost_before_step;
            offset.store(0, Ordering::SeqCst);
            println!(
                "  {done}: the clock steps back; contact changes meanwhile: {contact_changes_in_step}"
            );
        }
        if !restarted && done >= fraction(1, 2) {
            restarted = true;
            println!("  {done}: the station restarts on its history");
            station.stop().await?;
            station = start_station(cfg, &dir, &station_dds, &offset)?;
            wait_alive(&station.handle, plan.vehicles).await?;
        }
        if done >= next_row || done >= plan.tasks {
            next_row += plan.report_every;
            // A tenth of the fleet restarts; their task reader joins late.
            fleet.ask(FleetCommand::Restart).await?;
            let burst = late_joiner_burst(cfg, plan.domain).await?;
            let h = station.handle.clone();
            let row = Row {
                completed: done,
                elapsed_s: started.elapsed().as_secs_f64(),
                station_rss_mb: rss_mb(),
                fleet_rss_mb: fleet.rss_mb(),
                history_mb: file_mb(&dir.join("history.db")),
                burst,
                q3_p50_ms: tokio::task::spawn_blocking(move || q3_p50_ms(&h)).await?,
                register_tasks: station.handle.register_sizes().0,
            };
            println!(
                "  {:>7} tasks  {:>6.0} s  station RSS {:>6.1} MB  fleet RSS {:>6.1} MB  history {:>6.1} MB  late-joiner burst {:>4}  q3 p50 {:>6.2} ms  register {:>6}",
                row.completed,
                row.elapsed_s,
                row.station_rss_mb,
                row.fleet_rss_mb,
                row.history_mb,
                row.burst,
                row.q3_p50_ms,
                row.register_tasks
            );
            rows.push(row);
        }
    }
    let twice = fleet.stop().await?.twice;
    station.stop().await?;
    let report = render(&plan, &rows, twice, contact_changes_in_step);
    print!("{report}");
    if let Some(out) = &plan.out {
        std::fs::write(out, &report).with_context(|| format!("cannot write {}", out.display()))?;
        println!("written to {}", out.display());
    }
    let _ = std::fs::remove_dir_all(&dir);
    if twice > 0 {
        bail!("{twice} tasks were executed twice");
    }
    if contact_changes_in_step > 0 {
        bail!("the clock step changed contact {contact_changes_in_step} times");
    }
    Ok(())
}

/// CommLost alarms the station has raised so far (recent events).
fn comm_lost(h: &StationHandle) -> usize {
    h.recent_events()
        .iter()
        .filter(|e| e.kind == EventKind::CommLost)
        .count()
}

async fn wait_alive(h: &StationHandle, n: usize) -> Result<()> {
    let t = Instant::now();
    while h
        .fleet()
        .iter()
        .filter(|v| v.contact == shoal_station::Contact::Alive)
        .count()
        < n
    {
        if t.elapsed() > Duration::from_secs(60) {
            bail!("the fleet did not come alive at the station within 60 s");
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    Ok(())
}

fn render(plan: &Plan, rows: &[Row], twice: u64, contact_changes: usize) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# shoal bench endurance — {} — {}\n", machine(), date());
    let _ = writeln!(
        s,
        "{} vehicles, {} tasks (goto, survey, hold, back to back), vehicle restarts at every \
         row, one station restart, a +1 h clock step and back. The fleet runs in its own \
         process (its own DDS participant and ledgers): station RSS is the station's process \
         alone (with the late-joiner probe's participant), fleet RSS the fleet's, whose \
         ledgers grow by design (each remembers a task until an hour after its expiry).\n",
        plan.vehicles, plan.tasks
    );
    let _ = writeln!(
        s,
        "| completed tasks | elapsed s | station RSS MB | fleet RSS MB | history MB | late-joiner burst | q3 p50 ms | tasks in register |"
    );
    let _ = writeln!(s, "|---:|---:|---:|---:|---:|---:|---:|---:|");
    for r in rows {
        let _ = writeln!(
            s,
            "| {} | {:.0} | {:.1} | {:.1} | {:.1} | {} | {:.2} | {} |",
            r.completed,
            r.elapsed_s,
            r.station_rss_mb,
            r.fleet_rss_mb,
            r.history_mb,
            r.burst,
            r.q3_p50_ms,
            r.register_tasks
        );
    }
    #[allow(clippy::cast_precision_loss)]
    let points: Vec<(f64, f64)> = rows
        .iter()
        .map(|r| (r.completed as f64, r.station_rss_mb))
        .collect();
    let trend = slope(&points) * 10_000.0;
    let first = rows
        .iter()
        .find(|r| r.completed >= plan.tasks / 10)
        .or(rows.first());
    let last = rows.last();
    let _ = writeln!(
        s,
        "\n- station RSS trend: {trend:+.2} MB per 10,000 tasks (least squares over the rows)"
    );
    if let (Some(a), Some(b)) = (first, last) {
        let _ = writeln!(
            s,
            "- station RSS at {} tasks {:.1} MB, at {} tasks {:.1} MB: {:+.1} % (target within 10 %)",
            a.completed,
            a.station_rss_mb,
            b.completed,
            b.station_rss_mb,
            (b.station_rss_mb / a.station_rss_mb - 1.0) * 100.0
        );
        let _ = writeln!(
            s,
            "- fleet process RSS at {} tasks {:.1} MB, at {} tasks {:.1} MB: {:+.1} % (not judged: \
             its ledgers grow by design)",
            a.completed,
            a.fleet_rss_mb,
            b.completed,
            b.fleet_rss_mb,
            (b.fleet_rss_mb / a.fleet_rss_mb - 1.0) * 100.0
        );
    }
    let burst_max = rows.iter().map(|r| r.burst).max().unwrap_or(0);
    let _ = writeln!(
        s,
        "- late-joiner burst at most {burst_max} tasks with {} vehicles (target: bounded by the active tasks, not the past)",
        plan.vehicles
    );
    let q3_max = rows.iter().map(|r| r.q3_p50_ms).fold(0.0, f64::max);
    let _ = writeln!(
        s,
        "- q3 p50 at most {q3_max:.2} ms (target ≤ 2 ms throughout)"
    );
    let _ = writeln!(
        s,
        "- tasks executed twice, counted by the vehicles: {twice} (target 0)"
    );
    let _ = writeln!(
        s,
        "- contact changes caused by the clock step: {contact_changes} (target 0)"
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fleet_commands_are_one_word_each_and_read_back() {
        for c in [
            FleetCommand::Count,
            FleetCommand::Restart,
            FleetCommand::Stop,
        ] {
            assert_eq!(FleetCommand::parse(c.word()), Some(c));
        }
        assert_eq!(
            FleetCommand::parse("restart\r"),
            Some(FleetCommand::Restart)
        );
        assert_eq!(FleetCommand::parse(""), None);
        assert_eq!(FleetCommand::parse("restart all"), None);
        assert_eq!(FleetCommand::parse("COUNT"), None);
    }

    #[test]
    fn fleet_replies_read_back_and_anything_else_is_not_a_reply() {
        let p = FleetProgress {
            completed: 100_002,
            twice: 3,
        };
        let line = reply_line("restart", p);
        assert_eq!(line, "restart 100002 3");
        assert_eq!(parse_reply(&line), Some(("restart", p)));
        assert_eq!(
            parse_reply("ready 0 0"),
            Some((READY, FleetProgress::default()))
        );
        for junk in [
            "",
            "count",
            "count 12",
            "count 12 x",
            "count -1 0",
            "count 1 2 3",
            "progress 1 2",
            "1970-01-01 some library's banner",
        ] {
            assert_eq!(parse_reply(junk), None, "{junk:?}");
        }
    }
}
