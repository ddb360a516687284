//! Shoal's vehicle side: DDS Proxies that join a vehicle to the swarm.
//!
//! A DDS Proxy translates between a vehicle's own software and Shoal's topics. This crate
//! holds the proxies Shoal ships; the first is the simulator:
//!
//! - [`sim::SimVehicle`] is a simulated AUV, USV, ROV or glider (kinematics, battery, task
//!   execution) with no I/O, so it is tested without a network.
//! - [`run_sim`] joins one simulated vehicle to DDS: it announces the vehicle, publishes
//!   its state at the requested rate, executes the tasks addressed to it and reports their
//!   status.

pub mod sim;

use std::sync::Arc;
use std::time::Duration;

use futures::StreamExt;
use shoal_dds::{CreateError, Priority, PubSub, WriterOptions};
use shoal_model::{StateVector, TaskAssignment, TaskStatus, VehicleAnnouncement, now_ms};
use tokio_util::sync::CancellationToken;
use tracing::{info, warn};

use crate::sim::{Report, SimSpec, SimVehicle};

/// Fastest simulation step; state is published at the vehicle's own rate.
const STEP: Duration = Duration::from_millis(100);

/// Runs one simulated vehicle on DDS until `shutdown` is cancelled.
pub async fn run_sim(
    spec: SimSpec,
    dds: Arc<PubSub>,
    shutdown: CancellationToken,
) -> Result<(), CreateError> {
    let mut vehicle = SimVehicle::new(&spec, now_ms());
    let id = spec.id.clone();
    let announce = dds.writer::<VehicleAnnouncement>(WriterOptions::new(Priority::Control))?;
    let mut state_opts = WriterOptions::new(Priority::Telemetry);
    // Promise three reporting periods, so a reader asking for a deadline learns of silence.
    state_opts.deadline = Some(Duration::from_secs_f64(3.0 / spec.rate_hz.max(0.01)));
    let state = dds.writer::<StateVector>(state_opts)?;
    let status = dds.writer::<TaskStatus>(WriterOptions::new(Priority::Control))?;
    let mut tasks = dds.subscribe::<TaskAssignment>()?;

    if let Err(e) = announce.write(vehicle.announcement.clone()).await {
        warn!(vehicle = %id, error = %e, "announcement not sent");
    }
    info!(vehicle = %id, kind = %spec.kind, "simulated vehicle joined");

    let mut step = tokio::time::interval(STEP);
    step.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut since_report = Duration::MAX;
    let mut seen_tasks = std::collections::HashSet::new();
    loop {
        tokio::select! {
            () = shutdown.cancelled() => break,
            item = tasks.next() => {
                match item {
                    None => break,
                    Some(Ok((task, _))) if task.vehicle_id == id => {
                        // Transient-local re-delivery after a reconnect must not restart a task.
                        if !seen_tasks.insert(task.task_id.clone()) {
                            continue;
                        }
                        let reports = match task.task() {
                            Ok(t) => {
                                info!(vehicle = %id, task = %task.task_id, kind = ?task.kind, "task received");
                                vehicle.start(&task.task_id, &t)
                            }
                            Err(e) => vec![Report {
                                task_id: task.task_id.clone(),
                                state: shoal_model::TaskState::Failed,
                                progress_pct: 0.0,
                                message: format!("invalid task: {e}"),
                            }],
                        };
                        send_reports(&status, &id, reports).await;
                    }
                    Some(Ok(_)) => {}
                    Some(Err(e)) => warn!(vehicle = %id, error = %e, "bad task sample ignored"),
                }
            }
            _ = step.tick() => {
                let reports = vehicle.step(STEP.as_secs_f64());
                send_reports(&status, &id, reports).await;
                since_report = since_report.saturating_add(STEP);
                let period = Duration::from_secs_f64(1.0 / vehicle.rate_hz.max(0.01));
                if since_report >= period || vehicle.state_requested {
                    since_report = Duration::ZERO;
                    vehicle.state_requested = false;
                    if let Err(e) = state.write(vehicle.state(now_ms())).await {
                        warn!(vehicle = %id, error = %e, "state vector not sent");
                    }
                }
            }
        }
    }
    info!(vehicle = %id, "simulated vehicle leaving");
    Ok(())
}

async fn send_reports(
    writer: &shoal_dds::Writer<TaskStatus>,
    vehicle_id: &str,
    reports: Vec<Report>,
) {
    for r in reports {
        let s = TaskStatus {
            task_id: r.task_id,
            vehicle_id: vehicle_id.to_string(),
            timestamp_ms: now_ms(),
            state: r.state,
            progress_pct: r.progress_pct.clamp(0.0, 100.0),
            message: r.message,
        };
        if let Err(e) = writer.write(s).await {
            warn!(vehicle = vehicle_id, error = %e, "task status not sent");
        }
    }
}
