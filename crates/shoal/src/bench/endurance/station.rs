//! The station of `bench endurance`, in a process of its own (`bench endurance-station`),
//! so its resident memory is what an operator's station process would show, and a station
//! restart is a new process on the same history, as in deployment. It dispatches the
//! benchmark's tasks itself (to every vehicle whose task has ended) and answers the
//! benchmark's requests, one line each (see [`WORDS`]).

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicI64, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use shoal_history::{History, HistoryConfig};
use shoal_model::{EventKind, GeoPoint, Task, TaskAssignment, now_ms};
use shoal_semantic::QueryLimits;
use shoal_station::{Clock, Station, StationConfig, StationHandle};
use tokio_util::sync::CancellationToken;

use super::lines::{LineChild, READY, field, stdin_lines, tell_parent};
use super::{Plan, vehicle_id};
use crate::bench::helpers::{dds, percentile};
use crate::config::ShoalConfig;

/// Every word the station process answers with:
/// - `ready` once its station runs;
/// - `alive` → `alive`, once every vehicle is in contact (60 s at most); dispatching
///   starts then;
/// - `count` → `count <comm-lost alarms raised> <next task number>`;
/// - `row` → `row <q3 p50 in µs> <tasks in the register>`;
/// - `dispatch on|off` → `dispatch`: dispatching resumes or pauses (the late-joiner probe
///   counts what it is handed while dispatching is paused, so only tasks already under way);
/// - `clock <offset ms>` → `clock`: the station's system clock steps to that offset;
/// - `stop` → `stop <next task number>`, then the process ends.
const WORDS: &[&str] = &[READY, "alive", "count", "row", "dispatch", "clock", "stop"];

/// What one station process was started with.
#[derive(Debug, Clone, Copy)]
pub(in crate::bench) struct StationArgs {
    pub(in crate::bench) domain: u16,
    pub(in crate::bench) vehicles: usize,
    /// Tasks to dispatch in all, over every station process of the run.
    pub(in crate::bench) tasks: u64,
    /// Number of the first task this process dispatches.
    pub(in crate::bench) first_task: u64,
    /// The system clock's offset at start, ms.
    pub(in crate::bench) clock_offset_ms: i64,
}

/// The station process, as the benchmark drives it.
pub(super) struct StationProcess(LineChild);

impl StationProcess {
    /// Starts a station on the history in `dir`, dispatching from task `first_task` on.
    pub(super) async fn start(
        cfg: &ShoalConfig,
        plan: &Plan,
        dir: &Path,
        first_task: u64,
    ) -> Result<Self> {
        let args = [
            "endurance-station".to_string(),
            "--domain".into(),
            plan.domain.to_string(),
            "--vehicles".into(),
            plan.vehicles.to_string(),
            "--tasks".into(),
            plan.tasks.to_string(),
            "--first-task".into(),
            first_task.to_string(),
            "--dir".into(),
            dir.display().to_string(),
        ];
        let (child, _) = LineChild::start(cfg, "station process", WORDS, &args).await?;
        Ok(Self(child))
    }

    pub(super) fn pid(&self) -> &str {
        &self.0.pid
    }

    pub(super) fn rss_mb(&self) -> f64 {
        self.0.rss_mb()
    }

    /// Waits until every vehicle is in contact; dispatching starts then.
    pub(super) async fn alive(&mut self) -> Result<()> {
        self.0.ask("alive").await.map(drop)
    }

    /// CommLost alarms raised so far, and the next task's number.
    pub(super) async fn count(&mut self) -> Result<(usize, u64)> {
        let f = self.0.ask("count").await?;
        Ok((
            field(&f, 0, "comm-lost count")?,
            field(&f, 1, "next task number")?,
        ))
    }

    /// The tasks-by-state query's p50 (ms) and the register's size.
    pub(super) async fn row(&mut self) -> Result<(f64, usize)> {
        let f = self.0.ask("row").await?;
        let us: f64 = field(&f, 0, "q3 p50")?;
        Ok((us / 1e3, field(&f, 1, "register size")?))
    }

    /// Pauses or resumes dispatching.
    pub(super) async fn dispatching(&mut self, on: bool) -> Result<()> {
        let request = if on { "dispatch on" } else { "dispatch off" };
        self.0.ask(request).await.map(drop)
    }

    /// Steps the station's system clock to `offset_ms` from true time.
    pub(super) async fn clock(&mut self, offset_ms: i64) -> Result<()> {
        self.0.ask(&format!("clock {offset_ms}")).await.map(drop)
    }

    /// Stops the station; the next task's number, for the station that takes over.
    pub(super) async fn stop(self) -> Result<u64> {
        field(&self.0.stop("stop").await?, 0, "next task number")
    }
}

/// `shoal bench endurance-station`: the station of `bench endurance` with its history under
/// `dir`, driven by requests on stdin; it ends when told to stop or when stdin closes.
pub(in crate::bench) async fn station(
    cfg: &ShoalConfig,
    args: StationArgs,
    dir: &Path,
) -> Result<()> {
    let mut requests = stdin_lines()?;
    let offset = Arc::new(AtomicI64::new(args.clock_offset_ms));
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
        dds(cfg, args.domain)?,
        history,
        Clock::system_offset(Arc::clone(&offset)),
    )?;
    let h = station.handle();
    let stop = CancellationToken::new();
    let mut run = tokio::spawn(station.run(stop.clone()));
    let ids: Vec<String> = (0..args.vehicles).map(vehicle_id).collect();
    let mut dispatch = Dispatch {
        next: args.first_task,
        // Whatever is still under way in the history stays with its vehicle.
        current: h
            .tasks()
            .into_iter()
            .filter(|t| !t.state.is_final())
            .map(|t| (t.assignment.vehicle_id, t.assignment.task_id))
            .collect(),
        limit: args.tasks + args.vehicles as u64,
        on: false,
    };
    tell_parent(READY)?;
    let mut tick = tokio::time::interval(Duration::from_millis(5));
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            line = requests.recv() => {
                // No more requests: the benchmark process has ended.
                let Some(line) = line else { break };
                let mut words = line.split_whitespace();
                match (words.next(), words.next()) {
                    (Some("alive"), None) => {
                        wait_alive(&h, args.vehicles).await?;
                        dispatch.on = true;
                        tell_parent("alive")?;
                    }
                    (Some("count"), None) => {
                        tell_parent(&format!("count {} {}", comm_lost(&h), dispatch.next))?;
                    }
                    (Some("row"), None) => {
                        let q = h.clone();
                        let ms = tokio::task::spawn_blocking(move || q3_p50_ms(&q)).await?;
                        tell_parent(&format!(
                            "row {:.0} {}",
                            ms * 1e3,
                            h.register_sizes().0
                        ))?;
                    }
                    (Some("dispatch"), Some(on @ ("on" | "off"))) => {
                        dispatch.on = on == "on";
                        tell_parent("dispatch")?;
                    }
                    (Some("clock"), Some(ms)) => {
                        let ms: i64 = ms.parse().with_context(|| format!("bad clock offset {ms:?}"))?;
                        offset.store(ms, Ordering::SeqCst);
                        tell_parent("clock")?;
                    }
                    (Some("stop"), None) => {
                        stop.cancel();
                        run.await.context("the station task panicked")??;
                        return tell_parent(&format!("stop {}", dispatch.next));
                    }
                    _ => bail!("unknown request from the benchmark: {line:?}"),
                }
            }
            _ = tick.tick(), if dispatch.on => dispatch.round(&h, &ids),
            ended = &mut run => {
                ended.context("the station task panicked")??;
                bail!("the station ended by itself");
            }
        }
    }
    stop.cancel();
    run.await.context("the station task panicked")??;
    Ok(())
}

/// The benchmark's dispatcher: a vehicle whose task has ended gets the next one.
struct Dispatch {
    next: u64,
    /// Each vehicle's latest task.
    current: HashMap<String, String>,
    /// Tasks dispatched in all (the run's tasks, plus one in flight per vehicle at the end).
    limit: u64,
    on: bool,
}

impl Dispatch {
    fn round(&mut self, h: &StationHandle, ids: &[String]) {
        for id in ids {
            let idle = self
                .current
                .get(id)
                .is_none_or(|t| h.task(t).is_none_or(|v| v.state.is_final()));
            if idle && self.next < self.limit {
                let a = task_for(self.next, id);
                self.next += 1;
                if h.dispatch_now(a.clone()).is_ok() {
                    self.current.insert(id.clone(), a.task_id);
                }
            }
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
