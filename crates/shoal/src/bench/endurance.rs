//! `shoal bench endurance`: a deployment's lifetime compressed. A station (real DDS, real
//! SQLite history) gives simulated vehicles back-to-back tasks (goto, survey, hold); the
//! vehicles, which finish each task at once, each keep a real task ledger on disk. On a
//! schedule, vehicles restart (their ledger reopened, their task reader a late joiner),
//! the station restarts on the same history, and the station's system clock steps an hour
//! forward and back. Every report interval it prints the station process's RSS, the
//! history's size, the late-joiner burst (tasks a new reader is handed), the tasks-by-state
//! query's p50, and at the end a trend line of RSS against completed tasks.
//!
//! Counted by the vehicles themselves: tasks executed twice (must be zero). Counted at the
//! station: contact changes while the clock was stepped (must be zero).

use std::collections::{HashMap, VecDeque};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicI64, AtomicU64, Ordering};
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
use tokio::sync::Mutex;
use tokio_util::sync::CancellationToken;

use super::helpers::{date, dds, machine, percentile, rss_mb, tempfile_dir};
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
    rss_mb: f64,
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

/// The simulated fleet: one participant, a real ledger per vehicle.
struct Fleet {
    ids: Vec<String>,
    specs: HashMap<String, SimVehicle>,
    ledgers: HashMap<String, TaskLedger>,
    dir: PathBuf,
    /// Times each task was executed (handed to the vehicle), recent tasks only.
    executions: HashMap<String, u32>,
    order: VecDeque<String>,
    twice: u64,
    completed: Arc<AtomicU64>,
    status: Writer<TaskStatus>,
    state: Writer<StateVector>,
    announcement: Writer<VehicleAnnouncement>,
}

impl Fleet {
    fn new(dds: &PubSub, n: usize, dir: &Path, completed: Arc<AtomicU64>) -> Result<Self> {
        let mut ids = Vec::new();
        let mut specs = HashMap::new();
        let mut ledgers = HashMap::new();
        let dir = dir.join("vehicles");
        for i in 0..n {
            let id = format!("end-{i}");
            let spec = SimSpec {
                id: id.clone(),
                kind: VehicleKind::Auv,
                latitude_deg: 63.4 + f64::from(u32::try_from(i % 100).unwrap_or(0)) * 1e-3,
                longitude_deg: 10.4,
                rate_hz: 1.0,
                battery_pct: 100.0,
            };
            specs.insert(id.clone(), SimVehicle::new(&spec, now_ms()));
            ledgers.insert(id.clone(), TaskLedger::open(&dir, &id, Some(900_000))?);
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
            completed,
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
        let ledger = TaskLedger::open(&self.dir, id, Some(900_000))?;
        self.ledgers.insert(id.to_owned(), ledger);
        Ok(())
    }

    async fn on_task(&mut self, a: &TaskAssignment) -> Result<()> {
        let Some(ledger) = self.ledgers.get_mut(&a.vehicle_id) else {
            return Ok(());
        };
        match ledger.admit(a, now_ms())? {
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
                ledger.end(&a.task_id, TaskState::Done, now_ms())?;
                self.status(a, TaskState::Accepted, "").await;
                self.status(a, TaskState::Running, "").await;
                self.status(a, TaskState::Done, "").await;
                self.completed.fetch_add(1, Ordering::Relaxed);
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
    let fleet_dds = dds(cfg, plan.domain)?;
    let mut station = start_station(cfg, &dir, &station_dds, &offset)?;
    let completed = Arc::new(AtomicU64::new(0));
    let fleet = Arc::new(Mutex::new(Fleet::new(
        &fleet_dds,
        plan.vehicles,
        &dir,
        Arc::clone(&completed),
    )?));
    fleet.lock().await.announce().await?;
    let stop = CancellationToken::new();

    // The vehicles: state at 1 Hz, tasks as they come; the task reader is replaced (a late
    // joiner) whenever vehicles restart.
    let restart_reader = Arc::new(tokio::sync::Notify::new());
    let fleet_task = {
        let (fleet, stop, restart) = (
            Arc::clone(&fleet),
            stop.clone(),
            Arc::clone(&restart_reader),
        );
        let p = Arc::clone(&fleet_dds);
        tokio::spawn(async move {
            let mut sub = p.subscribe::<TaskAssignment>()?;
            let mut tick = tokio::time::interval(Duration::from_secs(1));
            loop {
                tokio::select! {
                    () = stop.cancelled() => return anyhow::Ok(()),
                    () = restart.notified() => sub = p.subscribe::<TaskAssignment>()?,
                    _ = tick.tick() => fleet.lock().await.report_states().await,
                    item = sub.next() => match item {
                        Some(Ok((a, _))) => fleet.lock().await.on_task(&a).await?,
                        Some(Err(_)) => {}
                        None => return anyhow::Ok(()),
                    },
                }
            }
        })
    };

    println!(
        "endurance: {} vehicles, {} tasks, a row every {}; vehicle restarts every row, a \
         station restart at 1/2, a clock step of +1 h at 3/10 and back at 2/5",
        plan.vehicles, plan.tasks, plan.report_every
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
    let ids = fleet.lock().await.ids.clone();
    let mut last_progress = (0u64, Instant::now());
    while completed.load(Ordering::Relaxed) < plan.tasks {
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
        let done = completed.load(Ordering::Relaxed);
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
            {
                let mut f = fleet.lock().await;
                for id in ids.iter().step_by(10) {
                    f.restart(id)?;
                }
            }
            restart_reader.notify_one();
            let burst = late_joiner_burst(cfg, plan.domain).await?;
            let h = station.handle.clone();
            let row = Row {
                completed: done,
                elapsed_s: started.elapsed().as_secs_f64(),
                rss_mb: rss_mb(),
                history_mb: file_mb(&dir.join("history.db")),
                burst,
                q3_p50_ms: tokio::task::spawn_blocking(move || q3_p50_ms(&h)).await?,
                register_tasks: station.handle.register_sizes().0,
            };
            println!(
                "  {:>7} tasks  {:>6.0} s  RSS {:>6.1} MB  history {:>6.1} MB  late-joiner burst {:>4}  q3 p50 {:>6.2} ms  register {:>6}",
                row.completed,
                row.elapsed_s,
                row.rss_mb,
                row.history_mb,
                row.burst,
                row.q3_p50_ms,
                row.register_tasks
            );
            rows.push(row);
        }
    }
    let twice = fleet.lock().await.twice;
    stop.cancel();
    fleet_task.await??;
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
         row, one station restart, a +1 h clock step and back.\n",
        plan.vehicles, plan.tasks
    );
    let _ = writeln!(
        s,
        "| completed tasks | elapsed s | process RSS MB (station + fleet) | history MB | late-joiner burst | q3 p50 ms | tasks in register |"
    );
    let _ = writeln!(s, "|---:|---:|---:|---:|---:|---:|---:|");
    for r in rows {
        let _ = writeln!(
            s,
            "| {} | {:.0} | {:.1} | {:.1} | {} | {:.2} | {} |",
            r.completed,
            r.elapsed_s,
            r.rss_mb,
            r.history_mb,
            r.burst,
            r.q3_p50_ms,
            r.register_tasks
        );
    }
    #[allow(clippy::cast_precision_loss)]
    let points: Vec<(f64, f64)> = rows
        .iter()
        .map(|r| (r.completed as f64, r.rss_mb))
        .collect();
    let trend = slope(&points) * 10_000.0;
    let first = rows
        .iter()
        .find(|r| r.completed >= plan.tasks / 10)
        .or(rows.first());
    let last = rows.last();
    let _ = writeln!(
        s,
        "\n- RSS trend: {trend:+.2} MB per 10,000 tasks (least squares over the rows)"
    );
    if let (Some(a), Some(b)) = (first, last) {
        let _ = writeln!(
            s,
            "- RSS at {} tasks {:.1} MB, at {} tasks {:.1} MB: {:+.1} % (target within 10 %)",
            a.completed,
            a.rss_mb,
            b.completed,
            b.rss_mb,
            (b.rss_mb / a.rss_mb - 1.0) * 100.0
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
