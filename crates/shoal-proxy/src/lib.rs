//! Shoal's vehicle side: DDS Proxies that join a vehicle to the swarm.
//!
//! A DDS Proxy translates between a vehicle's own software and Shoal's topics. It is
//! split in two, so that each new kind of vehicle only writes the part that differs:
//!
//! - [`VehicleAdapter`] is what a proxy needs from one vehicle interface: its
//!   announcement, its latest state, its reports (task progress, events, environment
//!   observations) and the decision to accept or refuse a task. The simulator
//!   ([`sim::SimAdapter`]) is the first adapter; MAVLink, IMC and ROS 2 adapters implement
//!   the same trait.
//! - [`run_proxy`] does all the DDS work once, for every adapter: it announces the vehicle
//!   (and again periodically), publishes state at the reporting rate, takes the tasks
//!   addressed to this vehicle (dropping duplicates and stale replays), reports their
//!   status and publishes events and observations.
//!
//! [`run_sim`] is [`run_proxy`] with a simulated vehicle, as `shoal vehicle --sim` runs it.
//! [`sim::SimVehicle`] is the simulation itself, with no I/O, so it is tested step by step.

#![forbid(unsafe_code)]

pub mod adapter;
pub mod imc;
pub mod ledger;
mod link;
pub mod mavlink;
mod proxy;
pub mod ros2;
pub mod sim;
pub mod swarm;

use std::sync::Arc;

use shoal_dds::{CreateError, PubSub};
use shoal_model::{TaskAssignment, Validate, now_ms};
use tokio_util::sync::CancellationToken;
use tracing::{info, warn};

pub use adapter::{
    Acceptance, Refusal, TaskOrder, TaskUpdate, VehicleAdapter, VehicleEvent, VehicleOutput,
};
pub use proxy::{PROXY_CAPABILITIES, ProxyError, ProxyOptions};

use crate::ledger::TaskLedger;
use crate::proxy::DdsOutbox;
use crate::sim::{SimAdapter, SimSettings, SimSpec};

/// Runs a DDS Proxy for one vehicle until `shutdown` is cancelled.
///
/// - Announces the vehicle on joining and every `options.announce_interval` (an unchanged
///   announcement is idempotent for the station), with the time of sending and with
///   [`PROXY_CAPABILITIES`] added, since the proxy serves those tasks itself.
/// - Publishes the adapter's state every `1 / state_rate_hz` seconds; a `request_state`
///   task publishes one at once, a `set_reporting_rate` task changes the rate.
/// - Takes the task assignments whose `vehicle_id` is this vehicle's; ignores the others,
///   any task id it has already seen (transient-local replays) and tasks older than
///   `options.max_task_age`. Accepted tasks are reported `accepted`; refused ones `failed`
///   with the message `refused: <reason>`; later states come from the adapter.
/// - Publishes the adapter's events (with unique ids; alarms on the emergency priority)
///   and environment observations.
pub async fn run_proxy<A: VehicleAdapter>(
    adapter: A,
    dds: Arc<PubSub>,
    options: ProxyOptions,
    shutdown: CancellationToken,
) -> Result<(), ProxyError<A::Error>> {
    let mut announcement = adapter.announcement();
    announcement.timestamp_ms = now_ms();
    announcement.validate().map_err(ProxyError::Announcement)?;
    let id = announcement.vehicle_id;
    let max_age_ms = options
        .max_task_age
        .map(|d| i64::try_from(d.as_millis()).unwrap_or(i64::MAX));
    let ledger = match &options.ledger_dir {
        Some(dir) => TaskLedger::open(dir, &id, max_age_ms)?,
        None => {
            warn!(vehicle = %id, "task ledger in memory only: a restart forgets which tasks ran");
            TaskLedger::in_memory(&id, max_age_ms)
        }
    };
    let mut outbox = DdsOutbox::new(&dds, &id, &options)?;
    let tasks = dds.subscribe::<TaskAssignment>()?;
    info!(vehicle = %id, kind = %announcement.kind, vendor = %announcement.vendor, remembered_tasks = ledger.len(), "vehicle joined");
    let result = proxy::serve(adapter, &mut outbox, tasks, options, ledger, shutdown).await;
    info!(vehicle = %id, "vehicle leaving");
    result.map_err(ProxyError::Adapter)
}

/// Runs one simulated vehicle (default [`SimSettings`]) on DDS until `shutdown` is cancelled.
pub async fn run_sim(
    spec: SimSpec,
    dds: Arc<PubSub>,
    shutdown: CancellationToken,
) -> Result<(), CreateError> {
    run_sim_with(spec, SimSettings::default(), dds, shutdown).await
}

/// Runs one simulated vehicle with the given settings on DDS until `shutdown` is cancelled.
pub async fn run_sim_with(
    spec: SimSpec,
    settings: SimSettings,
    dds: Arc<PubSub>,
    shutdown: CancellationToken,
) -> Result<(), CreateError> {
    let options = ProxyOptions::default();
    run_sim_on(spec, settings, options, dds, shutdown).await
}

/// Runs one simulated vehicle with the given settings and proxy options (its task ledger,
/// for one) on DDS until `shutdown` is cancelled; the spec's rate is the reporting rate.
pub async fn run_sim_on(
    spec: SimSpec,
    settings: SimSettings,
    options: ProxyOptions,
    dds: Arc<PubSub>,
    shutdown: CancellationToken,
) -> Result<(), CreateError> {
    let options = ProxyOptions {
        state_rate_hz: spec.rate_hz,
        ..options
    };
    let adapter = match options.clock {
        Some(warp) => SimAdapter::warped(&spec, &settings, warp),
        None => SimAdapter::new(&spec, &settings),
    };
    run_sim_adapter(adapter, options, dds, shutdown).await
}

/// Runs an already built simulated vehicle (on a warped clock, taking faults, restarted
/// where it was) on DDS until `shutdown` is cancelled; `options.state_rate_hz` is its
/// reporting rate.
pub async fn run_sim_adapter(
    adapter: SimAdapter,
    options: ProxyOptions,
    dds: Arc<PubSub>,
    shutdown: CancellationToken,
) -> Result<(), CreateError> {
    let id = adapter.vehicle().announcement.vehicle_id.clone();
    match run_proxy(adapter, dds, options, shutdown).await {
        Ok(()) => Ok(()),
        Err(ProxyError::Dds(e)) => Err(e),
        Err(ProxyError::Announcement(e)) => Err(CreateError::Config(format!(
            "simulated vehicle {id:?} cannot be announced: {e}"
        ))),
        Err(ProxyError::Ledger(e)) => Err(CreateError::Config(format!(
            "simulated vehicle {id:?}: {e}"
        ))),
        Err(ProxyError::Adapter(never)) => match never {},
    }
}
