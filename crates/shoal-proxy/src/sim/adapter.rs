//! The simulator as a [`VehicleAdapter`]: a [`SimVehicle`] advanced in real time.

use std::convert::Infallible;
use std::time::Duration;

use shoal_model::{StateVector, VehicleAnnouncement, Warp, now_ms};
use tokio::time::{Instant, Interval, MissedTickBehavior};

use super::{SimSettings, SimSpec, SimVehicle};
use crate::adapter::{Acceptance, Refusal, TaskOrder, VehicleAdapter, VehicleOutput};

/// How often the simulation advances when nothing asks for it sooner.
pub const TICK: Duration = Duration::from_millis(100);

/// A fault injected into a running simulated vehicle (`shoal scenario run`'s timeline).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SimFault {
    /// The battery falls at once to this percentage.
    BatteryDrop(f64),
}

/// Shortest real time between two advances of a warped vehicle: finer steps only cost CPU.
const MIN_WARPED_TICK: Duration = Duration::from_millis(10);

/// A simulated vehicle behind a DDS Proxy, advancing with the Tokio clock.
///
/// Simulated time follows the Tokio clock (so tests with paused time run a long mission
/// in an instant), or a scenario run's [`Warp`], and the state vector is brought up to
/// date whenever it is read, so states are fresh at any reporting rate.
#[derive(Debug)]
pub struct SimAdapter {
    vehicle: SimVehicle,
    /// Created on first use: an interval needs a running Tokio runtime.
    ticker: Option<Interval>,
    last: Option<Instant>,
    warp: Option<Warp>,
    faults: Option<tokio::sync::mpsc::UnboundedReceiver<SimFault>>,
}

impl SimAdapter {
    /// A simulated vehicle at its start position, its clock at the current time.
    pub fn new(spec: &SimSpec, settings: &SimSettings) -> Self {
        Self::from_vehicle(SimVehicle::with_settings(spec, settings, now_ms()))
    }

    /// Runs an already built vehicle (e.g. one moved along before joining).
    pub fn from_vehicle(vehicle: SimVehicle) -> Self {
        Self {
            vehicle,
            ticker: None,
            last: None,
            warp: None,
            faults: None,
        }
    }

    /// Takes faults from `faults` while it runs (a closed channel injects no more).
    #[must_use]
    pub fn with_faults(mut self, faults: tokio::sync::mpsc::UnboundedReceiver<SimFault>) -> Self {
        self.faults = Some(faults);
        self
    }

    fn inject(&mut self, fault: SimFault) {
        self.catch_up();
        match fault {
            SimFault::BatteryDrop(pct) => self.vehicle.drop_battery(pct),
        }
    }

    /// A simulated vehicle at its start position living on `warp`'s simulated clock,
    /// which a station in the same process shares (`shoal scenario run`).
    pub fn warped(spec: &SimSpec, settings: &SimSettings, warp: Warp) -> Self {
        Self {
            warp: Some(warp),
            ..Self::from_vehicle(SimVehicle::with_settings(spec, settings, warp.now_ms()))
        }
    }

    /// The simulated vehicle.
    pub fn vehicle(&self) -> &SimVehicle {
        &self.vehicle
    }

    /// Advances the simulation to the current instant.
    fn catch_up(&mut self) {
        if let Some(warp) = self.warp {
            // Anchored to the warp, not summed from ticks, so the vehicle's clock never
            // drifts from the station's.
            #[allow(clippy::cast_precision_loss)]
            let behind_ms = (warp.now_ms() - self.vehicle.clock_ms()) as f64;
            self.vehicle.step(behind_ms / 1000.0);
            return;
        }
        let now = Instant::now();
        if let Some(last) = self.last {
            self.vehicle.step(now.duration_since(last).as_secs_f64());
        }
        self.last = Some(now);
    }
}

impl VehicleAdapter for SimAdapter {
    type Error = Infallible;

    fn announcement(&self) -> VehicleAnnouncement {
        self.vehicle.announcement.clone()
    }

    fn state(&mut self) -> Option<StateVector> {
        self.catch_up();
        Some(self.vehicle.state(self.vehicle.clock_ms()))
    }

    async fn next_output(&mut self) -> Result<VehicleOutput, Infallible> {
        loop {
            if let Some(out) = self.vehicle.pop_output() {
                return Ok(out);
            }
            let period = self
                .warp
                .map_or(TICK, |w| TICK.div_f64(w.scale()).max(MIN_WARPED_TICK));
            let ticker = self.ticker.get_or_insert_with(|| {
                let mut t = tokio::time::interval(period);
                t.set_missed_tick_behavior(MissedTickBehavior::Delay);
                t
            });
            // Cancel-safe: a dropped tick loses nothing, the next catch-up covers the time.
            let fault = match self.faults.as_mut() {
                Some(rx) => tokio::select! {
                    _ = ticker.tick() => None,
                    f = rx.recv() => {
                        if f.is_none() {
                            self.faults = None;
                        }
                        f
                    }
                },
                None => {
                    ticker.tick().await;
                    None
                }
            };
            match fault {
                Some(f) => self.inject(f),
                None => self.catch_up(),
            }
        }
    }

    async fn submit(&mut self, order: TaskOrder) -> Result<Acceptance, Refusal> {
        // Decide on the vehicle as it is now, not as it was at the last tick.
        self.catch_up();
        self.vehicle.submit(&order)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shoal_model::{GeoPoint, Task, TaskState, VehicleKind};

    use crate::adapter::TaskUpdate;

    fn spec() -> SimSpec {
        SimSpec {
            id: "auv-1".into(),
            kind: VehicleKind::Auv,
            latitude_deg: 43.0,
            longitude_deg: 5.9,
            rate_hz: 1.0,
            battery_pct: 100.0,
        }
    }

    #[tokio::test(start_paused = true)]
    async fn simulated_time_follows_the_tokio_clock() {
        let mut a = SimAdapter::new(&spec(), &SimSettings::default());
        let t0 = a.state().unwrap().timestamp_ms;
        tokio::time::sleep(Duration::from_secs(30)).await;
        let t1 = a.state().unwrap().timestamp_ms;
        assert_eq!(t1 - t0, 30_000);
    }

    #[tokio::test]
    async fn a_warped_vehicle_lives_on_the_warp_clock() {
        let warp = Warp::start(200.0).unwrap();
        let mut a = SimAdapter::warped(&spec(), &SimSettings::default(), warp);
        let t0 = a.state().unwrap().timestamp_ms;
        tokio::time::sleep(Duration::from_millis(50)).await;
        let (t1, now) = (a.state().unwrap().timestamp_ms, warp.now_ms());
        // 50 ms real is at least 10 s simulated; the state is stamped on the warp's clock.
        assert!(t1 - t0 >= 10_000, "{}", t1 - t0);
        assert!((now - t1).abs() <= 50, "{now} {t1}");
    }

    #[tokio::test(start_paused = true)]
    async fn a_goto_runs_to_done_through_next_output() {
        let mut a = SimAdapter::new(
            &spec(),
            &SimSettings {
                environment_hz: 0.0,
                ..SimSettings::default()
            },
        );
        let order = TaskOrder {
            task_id: "t1".into(),
            mission_id: String::new(),
            issued_ms: now_ms(),
            task: Task::GotoWaypoint {
                target: GeoPoint {
                    latitude_deg: 43.001,
                    longitude_deg: 5.9,
                },
                depth_m: Some(5.0),
                altitude_m: None,
                speed_mps: 2.0,
            },
        };
        assert!(a.submit(order).await.is_ok());
        let started = Instant::now();
        let mut states = Vec::new();
        loop {
            if let VehicleOutput::Task(TaskUpdate { state, .. }) = a.next_output().await.unwrap() {
                states.push(state);
                if state.is_final() {
                    break;
                }
            }
        }
        assert_eq!(states.first(), Some(&TaskState::Running));
        assert_eq!(states.last(), Some(&TaskState::Done));
        // 111 m at 2 m/s, less the arrival radius, plus the speed's 2 s time constant.
        let took = started.elapsed().as_secs_f64();
        assert!((53.0..60.0).contains(&took), "{took} s");
    }
}
