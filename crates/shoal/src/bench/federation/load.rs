//! `bench wan-load`: one ship's load for `bench federation`, run in the ship's network
//! namespace: `shoal swarm`'s vehicles on one participant, a few vehicles that take the
//! tasks the benchmark dispatches through the ship's API and answer them, and an alarm at
//! a fixed period, stamped when published.

use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::Result;
use futures::StreamExt as _;
use shoal_dds::{Priority, WriterOptions};
use shoal_model::{
    Event, EventKind, LinkKind, Severity, StateVector, TaskAssignment, TaskState, TaskStatus,
    VehicleAnnouncement, VehicleKind, now_ms,
};
use tokio::io::AsyncWriteExt as _;
use tokio_util::sync::CancellationToken;

use super::TASK_VEHICLES;
use crate::bench::helpers::dds;
use crate::config::ShoalConfig;

/// `bench wan-load`'s flags: one ship's load, in its namespace.
#[derive(Debug, Clone, clap::Args)]
pub struct LoadArgs {
    #[arg(long)]
    pub(super) domain: u16,
    /// The ship's site: ids are made from it.
    #[arg(long)]
    pub(super) site: String,
    #[arg(long)]
    pub(super) vehicles: usize,
    #[arg(long)]
    pub(super) rate: f64,
    #[arg(long)]
    pub(super) alarm_every: f64,
    #[arg(long)]
    pub(super) task_every: f64,
    /// The ship station's HTTP API port on this namespace's loopback.
    #[arg(long)]
    pub(super) api: u16,
}

/// `bench wan-load`: one ship's load in its namespace (see the module doc). Prints
/// `alarm <id> <stamp>` and `task <id>` lines; `stop` on stdin stops raising alarms and
/// tasks, the end of stdin stops it.
pub(in crate::bench) async fn wan_load(cfg: &ShoalConfig, a: LoadArgs) -> Result<()> {
    let p = dds(cfg, a.domain)?;
    let shutdown = CancellationToken::new();
    let spec = shoal_proxy::swarm::SwarmSpec {
        count: a.vehicles - TASK_VEHICLES,
        prefix: format!("{}-v", a.site),
        rate_hz: a.rate,
        ..shoal_proxy::swarm::SwarmSpec::default()
    };
    spec.check()?;
    let swarm = tokio::spawn(shoal_proxy::swarm::run_swarm(
        spec,
        Arc::clone(&p),
        shutdown.clone(),
    ));
    let workers: Vec<String> = (1..=TASK_VEHICLES)
        .map(|k| format!("{}-t{k}", a.site))
        .collect();
    let announce = p.writer::<VehicleAnnouncement>(WriterOptions::new(Priority::Control))?;
    let states = p.writer::<StateVector>(WriterOptions::new(Priority::Telemetry))?;
    let status = Arc::new(p.writer::<TaskStatus>(WriterOptions::new(Priority::Control))?);
    let events = p.writer::<Event>(WriterOptions::new(Priority::Control))?;
    let mut assignments = p.subscribe::<TaskAssignment>()?;
    // Lines from the benchmark, read on a plain thread (see daemons::shutdown_signal).
    let (line_tx, mut line_rx) = tokio::sync::mpsc::unbounded_channel::<String>();
    std::thread::Builder::new()
        .name("stdin-lines".into())
        .spawn(move || {
            for line in std::io::stdin().lines() {
                let Ok(line) = line else { break };
                if line_tx.send(line).is_err() {
                    break;
                }
            }
        })?;
    let announcement = |id: &str| VehicleAnnouncement {
        vehicle_id: id.to_owned(),
        name: format!("wan bench worker {id}"),
        kind: VehicleKind::Auv,
        vendor: "shoal bench".into(),
        capabilities: vec!["hold".into()],
        sensors: vec![],
        links: vec![LinkKind::Ip],
        max_speed_mps: 2.0,
        timestamp_ms: now_ms(),
    };
    // Announced once the station's readers matched (as the swarm does).
    let waiting = Instant::now();
    while (announce.matched_readers() == 0 || states.matched_readers() == 0)
        && waiting.elapsed() < Duration::from_secs(30)
    {
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    for w in &workers {
        let _ = announce.write(announcement(w)).await;
    }
    tokio::time::sleep(Duration::from_secs(1)).await;
    let http = reqwest::Client::builder()
        .timeout(Duration::from_secs(10))
        .build()?;
    let mut state_tick = tokio::time::interval(Duration::from_secs(1));
    let mut alarm_tick = tokio::time::interval(Duration::from_secs_f64(a.alarm_every));
    let mut task_tick = tokio::time::interval(Duration::from_secs_f64(a.task_every));
    for t in [&mut state_tick, &mut alarm_tick, &mut task_tick] {
        t.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    }
    let (mut raising, mut n_alarm, mut n_task) = (true, 0u64, 0u64);
    let mut answered = std::collections::HashSet::new();
    let mut out = tokio::io::stdout();
    loop {
        tokio::select! {
            line = line_rx.recv() => match line.as_deref() {
                Some("stop") => raising = false,
                Some(_) => {}
                None => break,
            },
            _ = state_tick.tick() => {
                let t = now_ms();
                for (i, w) in workers.iter().enumerate() {
                    #[allow(clippy::cast_precision_loss)]
                    let s = StateVector {
                        vehicle_id: w.clone(),
                        timestamp_ms: t,
                        latitude_deg: 63.44 + 0.001 * i as f64,
                        longitude_deg: 10.30,
                        depth_m: 5.0,
                        altitude_m: -1.0,
                        speed_mps: 0.0,
                        yaw_deg: 0.0,
                        pitch_deg: 0.0,
                        roll_deg: 0.0,
                        battery_pct: 90.0,
                    };
                    let _ = states.write(s).await;
                }
            }
            _ = alarm_tick.tick(), if raising => {
                n_alarm += 1;
                let id = format!("{}-a{n_alarm}", a.site);
                let stamp = now_ms();
                let e = Event {
                    event_id: id.clone(),
                    timestamp_ms: stamp,
                    severity: Severity::Warning,
                    kind: EventKind::Other,
                    vehicle_id: String::new(),
                    task_id: String::new(),
                    text: format!("wan bench alarm {n_alarm}"),
                };
                if events.write(e).await.is_ok() {
                    out.write_all(format!("alarm {id} {stamp}\n").as_bytes()).await?;
                    out.flush().await?;
                }
            }
            _ = task_tick.tick(), if raising => {
                n_task += 1;
                let id = format!("{}-k{n_task}", a.site);
                #[allow(clippy::cast_possible_truncation)]
                let vehicle = &workers[(n_task as usize) % workers.len()];
                let body = serde_json::json!({
                    "task_id": id,
                    "vehicle_id": vehicle,
                    "task": {"kind": "hold", "duration_s": 1.0},
                });
                let reply = http
                    .post(format!("http://127.0.0.1:{}/api/tasks", a.api))
                    .header("content-type", "application/json")
                    .body(body.to_string())
                    .send()
                    .await;
                let line = match reply {
                    Ok(r) if r.status().is_success() => format!("task {id}\n"),
                    Ok(r) => format!("task refused {id}: {} {}\n", r.status(), r.text().await.unwrap_or_default()),
                    Err(e) => format!("task not sent {id}: {e}\n"),
                };
                out.write_all(line.as_bytes()).await?;
                out.flush().await?;
            }
            item = assignments.next() => {
                let Some(Ok((task, _))) = item else { continue };
                let task = task.into_inner();
                if !workers.contains(&task.vehicle_id) || !answered.insert(task.task_id.clone()) {
                    continue;
                }
                let status = Arc::clone(&status);
                tokio::spawn(async move {
                    for (state, progress, after) in [
                        (TaskState::Accepted, 0.0, 0),
                        (TaskState::Running, 0.0, 200),
                        (TaskState::Done, 100.0, 1000),
                    ] {
                        tokio::time::sleep(Duration::from_millis(after)).await;
                        let _ = status
                            .write(TaskStatus {
                                task_id: task.task_id.clone(),
                                vehicle_id: task.vehicle_id.clone(),
                                timestamp_ms: now_ms(),
                                state,
                                progress_pct: progress,
                                message: String::new(),
                            })
                            .await;
                    }
                });
            }
        }
    }
    shutdown.cancel();
    let _ = swarm.await;
    Ok(())
}
