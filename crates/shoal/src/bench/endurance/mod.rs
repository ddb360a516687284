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
//! The station and the fleet each run in a process of their own (`bench
//! endurance-station`, `bench endurance-fleet`; see [`station`] and [`fleet`]): the
//! station's RSS is then what an operator's station process shows, its restart is a new
//! process on the same history, and the fleet's ledgers, which grow by design (each
//! remembers a task until an hour after its expiry), are not counted in it. This process
//! only directs the run and probes as a late joiner; it talks to both over their stdin and
//! stdout, one line each way per request (see [`lines`]).
//!
//! Counted by the vehicles themselves: tasks executed twice (must be zero). Counted at the
//! station: contact changes while the clock was stepped (must be zero).

mod fleet;
mod lines;
mod station;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use futures::StreamExt;
use shoal_model::TaskAssignment;

pub(super) use self::fleet::fleet;
use self::fleet::{FleetCommand, FleetProcess};
use self::station::StationProcess;
pub(super) use self::station::{StationArgs, station};
use super::helpers::{date, dds, machine, tempfile_dir};
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
    /// The station's RSS at the row, the mean of its readings over the last two seconds
    /// (one every 20 ms): single readings swing by tens of MB with the allocator's retained
    /// pages and the semantic model's copy while a query runs.
    station_rss_mb: f64,
    /// The highest reading in the interval.
    station_rss_max_mb: f64,
    fleet_rss_mb: f64,
    history_mb: f64,
    burst: usize,
    q3_p50_ms: f64,
    register_tasks: usize,
}

/// The station's RSS at a row: the mean of its last [`RssWindow::LEN`] readings (about the
/// last two seconds before the row), and the highest reading over the whole interval.
#[derive(Debug, Default)]
struct RssWindow {
    last: std::collections::VecDeque<f64>,
    max: f64,
}

impl RssWindow {
    /// Readings averaged: at one every 20 ms or so, about two seconds.
    const LEN: usize = 100;

    fn add(&mut self, mb: f64) {
        // A process between readings (a restart) reads as NaN: not a reading.
        if mb.is_finite() {
            if self.last.len() == Self::LEN {
                self.last.pop_front();
            }
            self.last.push_back(mb);
            self.max = self.max.max(mb);
        }
    }

    fn mean(&self) -> f64 {
        if self.last.is_empty() {
            return f64::NAN;
        }
        #[allow(clippy::cast_precision_loss)]
        let n = self.last.len() as f64;
        self.last.iter().sum::<f64>() / n
    }
}

/// The id of the fleet's `i`-th vehicle; both processes derive the fleet from its size.
/// The id of the fleet's `i`-th vehicle; every process derives the fleet from its size.
fn vehicle_id(i: usize) -> String {
    format!("end-{i}")
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
    let mut station = StationProcess::start(cfg, &plan, &dir, 0).await?;
    let mut fleet = FleetProcess::start(cfg, &plan, &dir).await?;

    println!(
        "endurance: {} vehicles (fleet process, pid {}), station process pid {}, {} tasks, a \
         row every {}; vehicle restarts every row, a station restart at 1/2, a clock step of \
         +1 h at 3/10 and back at 2/5",
        plan.vehicles,
        fleet.pid(),
        station.pid(),
        plan.tasks,
        plan.report_every
    );
    station.alive().await?;
    let started = Instant::now();
    let mut rows: Vec<Row> = Vec::new();
    let mut next_row = plan.report_every;
    let (mut stepped, mut stepped_back, mut restarted) = (false, false, false);
    let lost_before_step = station.count().await?.0;
    let mut contact_changes_in_step = 0usize;
    let mut last_progress = (0u64, Instant::now());
    let mut done = 0;
    let mut rss = RssWindow::default();
    while done < plan.tasks {
        tokio::time::sleep(Duration::from_millis(20)).await;
        rss.add(station.rss_mb());
        done = fleet.ask(FleetCommand::Count).await?.completed;
        if done > last_progress.0 {
            last_progress = (done, Instant::now());
        } else if last_progress.1.elapsed() > Duration::from_secs(120) {
            bail!("no task completed for two minutes (at {done})");
        }
        let fraction = |num: u64, den: u64| plan.tasks * num / den;
        if !stepped && done >= fraction(3, 10) {
            stepped = true;
            station.clock(3_600_000).await?;
            println!("  {done}: the station's system clock steps +1 h");
        }
        if stepped && !stepped_back && done >= fraction(2, 5) {
            stepped_back = true;
            contact_changes_in_step = station.count().await?.0 - lost_before_step;
            station.clock(0).await?;
            println!(
                "  {done}: the clock steps back; contact changes meanwhile: {contact_changes_in_step}"
            );
        }
        if !restarted && done >= fraction(1, 2) {
            restarted = true;
            println!("  {done}: the station restarts on its history (a new process)");
            let next_task = station.stop().await?;
            station = StationProcess::start(cfg, &plan, &dir, next_task).await?;
            station.alive().await?;
            // The readings are the new process's alone.
            rss = RssWindow::default();
        }
        if done >= next_row || done >= plan.tasks {
            next_row += plan.report_every;
            // A tenth of the fleet restarts; their task reader joins late. No task is
            // dispatched meanwhile, so the probe is handed only tasks already under way.
            station.dispatching(false).await?;
            fleet.ask(FleetCommand::Restart).await?;
            let burst = late_joiner_burst(cfg, plan.domain).await?;
            station.dispatching(true).await?;
            let (q3_p50_ms, register_tasks) = station.row().await?;
            rss.add(station.rss_mb());
            let row = Row {
                completed: done,
                elapsed_s: started.elapsed().as_secs_f64(),
                station_rss_mb: rss.mean(),
                station_rss_max_mb: rss.max,
                fleet_rss_mb: fleet.rss_mb(),
                history_mb: file_mb(&dir.join("history.db")),
                burst,
                q3_p50_ms,
                register_tasks,
            };
            println!(
                "  {:>7} tasks  {:>6.0} s  station RSS {:>6.1} MB (max {:>6.1})  fleet RSS {:>6.1} MB  history {:>6.1} MB  late-joiner burst {:>4}  q3 p50 {:>6.2} ms  register {:>6}",
                row.completed,
                row.elapsed_s,
                row.station_rss_mb,
                row.station_rss_max_mb,
                row.fleet_rss_mb,
                row.history_mb,
                row.burst,
                row.q3_p50_ms,
                row.register_tasks
            );
            rows.push(row);
            rss = RssWindow::default();
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

fn render(plan: &Plan, rows: &[Row], twice: u64, contact_changes: usize) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# shoal bench endurance — {} — {}\n", machine(), date());
    let _ = writeln!(
        s,
        "{} vehicles, {} tasks (goto, survey, hold, back to back), vehicle restarts at every \
         row, one station restart, a +1 h clock step and back. The fleet runs in its own \
         process (its own DDS participant and ledgers), the station in its own (restarted as a new \
         process on the same history): station RSS is the station's process alone, the mean \
         of its readings (one every 20 ms) over the two seconds before the row, the highest \
         reading of the row's interval beside it, fleet \
         RSS the fleet's at the row, whose ledgers grow by design (each remembers a task \
         until an hour after its expiry). q3 is measured while the station dispatches and \
         ingests at full pace.\n",
        plan.vehicles, plan.tasks
    );
    let _ = writeln!(
        s,
        "| completed tasks | elapsed s | station RSS MB (2 s mean) | station RSS MB (interval max) | fleet RSS MB | history MB | late-joiner burst | q3 p50 ms | tasks in register |"
    );
    let _ = writeln!(s, "|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for r in rows {
        let _ = writeln!(
            s,
            "| {} | {:.0} | {:.1} | {:.1} | {:.1} | {:.1} | {} | {:.2} | {} |",
            r.completed,
            r.elapsed_s,
            r.station_rss_mb,
            r.station_rss_max_mb,
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
        .filter(|(_, mb)| mb.is_finite())
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
            "- station RSS (2 s mean) at {} tasks {:.1} MB, at {} tasks {:.1} MB: {:+.1} % (target within 10 %)",
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
