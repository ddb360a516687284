//! A scenario's missions run by the station itself: each is planned and started through
//! the Mission Manager once its offset has passed and every vehicle it names has been
//! heard, so a scenario needs no console, no HTTP and no login.

use std::time::Duration;

use shoal_scenario::{Scenario, ScenarioMission};
use tokio_util::sync::CancellationToken;
use tracing::{info, warn};

use crate::core::StationHandle;
use crate::missions::{MissionSpec, MissionState, MissionTaskSpec};
use crate::register::Contact;

/// How often, in station time, a due mission looks again for the vehicles it waits for.
const POLL: Duration = Duration::from_millis(250);
/// Shortest real time between two looks on a fast (warped) clock.
const MIN_POLL: Duration = Duration::from_millis(5);

impl StationHandle {
    /// Runs `scenario`'s missions on their timeline, counted from now on the station's
    /// clock, until each has started, failed to plan, or outlived the scenario's duration
    /// waiting for its vehicles; returns then, or when `shutdown` is cancelled.
    ///
    /// The timeline is in station time: real seconds under `shoal up` (its vehicles run in
    /// their own processes at real time), simulated seconds when the station runs on a
    /// warped clock with its simulated vehicles (`shoal scenario run --speed N`).
    pub async fn run_scenario(&self, scenario: Scenario, shutdown: CancellationToken) {
        let start_ms = self.now();
        let offset_ms = |s: f64| start_ms.saturating_add((s * 1000.0) as i64);
        let end_ms = offset_ms(scenario.duration_s);
        // A suffix per run: missions of an earlier run of the same scenario may still be in
        // the register (ended tasks are kept a day), and their ids must not collide.
        let run = start_ms / 1000;
        let mut pending: Vec<ScenarioMission> = scenario.missions;
        pending.sort_by(|a, b| a.at_s.total_cmp(&b.at_s));
        info!(
            scenario = %scenario.name,
            missions = pending.len(),
            "scenario: missions start at their offsets once their vehicles are heard"
        );
        let mut waiting_said = Vec::new();
        let mut tick = tokio::time::interval(POLL.div_f64(self.clock_rate()).max(MIN_POLL));
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        while !pending.is_empty() {
            tokio::select! {
                () = shutdown.cancelled() => return,
                _ = tick.tick() => {}
            }
            let now = self.now();
            let mut i = 0;
            while i < pending.len() {
                let m = &pending[i];
                if now < offset_ms(m.at_s) {
                    // Sorted: the rest are later still.
                    break;
                }
                let unheard: Vec<&str> = m
                    .vehicles()
                    .into_iter()
                    .filter(|v| !self.heard(v))
                    .collect();
                if let Some(earlier) = self.earlier_run_still_active(&m.id) {
                    // A restarted station must not send a vehicle the same mission twice.
                    info!(mission = %m.id, %earlier, "scenario mission still under way from an earlier start; not started again");
                    pending.remove(i);
                } else if unheard.is_empty() {
                    self.start_scenario_mission(m, run);
                    pending.remove(i);
                } else if now >= end_ms {
                    warn!(
                        mission = %m.id,
                        vehicles = ?unheard,
                        "scenario mission not started: its vehicles were not heard within the scenario's duration"
                    );
                    pending.remove(i);
                } else {
                    if !waiting_said.contains(&m.id) {
                        info!(mission = %m.id, vehicles = ?unheard, "scenario mission due; waiting to hear its vehicles");
                        waiting_said.push(m.id.clone());
                    }
                    i += 1;
                }
            }
        }
        info!(scenario = %scenario.name, "scenario: every mission handled");
    }

    /// The id of this scenario mission as an earlier start of the station ran it
    /// (`<id>-<run>`), if that one is still planned or running (the register keeps
    /// missions across restarts).
    fn earlier_run_still_active(&self, id: &str) -> Option<String> {
        self.missions()
            .into_iter()
            .find(|v| {
                let run = v
                    .mission_id
                    .strip_prefix(id)
                    .and_then(|r| r.strip_prefix('-'));
                run.is_some_and(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()))
                    && matches!(v.state, MissionState::Planned | MissionState::Running)
            })
            .map(|v| v.mission_id)
    }

    /// Registered, with a state vector, and not lost: what planning a task needs.
    fn heard(&self, vehicle: &str) -> bool {
        self.vehicle(vehicle)
            .is_some_and(|v| v.latest.is_some() && v.contact != Contact::Lost)
    }

    fn start_scenario_mission(&self, m: &ScenarioMission, run: i64) {
        let spec = MissionSpec {
            mission_id: format!("{}-{run}", m.id),
            name: m.name.clone(),
            tasks: m
                .tasks
                .iter()
                .map(|t| MissionTaskSpec {
                    task_id: None,
                    vehicle_id: t.vehicle_id.clone(),
                    task: t.task.clone(),
                })
                .collect(),
        };
        let id = spec.mission_id.clone();
        match self
            .plan_mission(spec)
            .and_then(|_| self.start_mission(&id))
        {
            Ok(view) => {
                info!(
                    mission = %id,
                    name = ?m.name,
                    at_s = m.at_s,
                    tasks = view.tasks.len(),
                    vehicles = ?m.vehicles(),
                    "scenario mission started"
                );
            }
            Err(e) => {
                warn!(mission = %id, reason = %e, "scenario mission not started; the scenario goes on");
            }
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::testing::Fixture;

    const SCENARIO: &str = r#"
[scenario]
name = "t"
duration_s = 60

[[vehicles]]
id = "auv-1"
kind = "auv"
latitude_deg = 63.465
longitude_deg = 10.36

[[vehicles]]
id = "auv-2"
kind = "auv"
latitude_deg = 63.465
longitude_deg = 10.36

[[missions]]
id = "early"
name = "early"
at_s = 1

[[missions.tasks]]
vehicle = "auv-1"
kind = "goto"
latitude_deg = 63.467
longitude_deg = 10.37
depth_m = 2

[[missions]]
id = "late"
name = "late"
at_s = 5

[[missions.tasks]]
vehicle = "auv-2"
kind = "hold"
"#;

    fn started(f: &Fixture, prefix: &str) -> bool {
        f.h.missions()
            .iter()
            .any(|m| m.mission_id.starts_with(prefix) && m.state != MissionState::Planned)
    }

    /// Missions start at their offsets, not before, and wait for their vehicles.
    // Real time, not paused: starting a mission blocks in place, which needs the
    // multi-threaded runtime, and tokio pauses time only on the current-thread one.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn missions_start_at_their_offset_once_their_vehicles_are_heard() {
        let f = Fixture::new();
        f.alive("auv-1");
        let scenario = shoal_scenario::parse(SCENARIO).unwrap();
        let stop = CancellationToken::new();
        let h = f.h.clone();
        let s = stop.clone();
        let run = tokio::spawn(async move { h.run_scenario(scenario, s).await });
        assert!(!started(&f, "early-"), "started before its offset");
        tokio::time::sleep(Duration::from_millis(1600)).await;
        assert!(started(&f, "early-"));
        assert_eq!(f.out.tasks().len(), 1);
        // auv-2 is heard only after its mission is due: it starts then.
        tokio::time::sleep(Duration::from_millis(4000)).await;
        assert!(!started(&f, "late-"));
        f.alive("auv-2");
        tokio::time::sleep(Duration::from_millis(600)).await;
        assert!(started(&f, "late-"));
        tokio::time::timeout(Duration::from_secs(2), run)
            .await
            .unwrap()
            .unwrap();
        stop.cancel();
    }

    /// A mission the station refuses to plan is skipped with a warning; the next runs.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_mission_that_cannot_be_planned_does_not_stop_the_scenario() {
        let f = Fixture::new();
        // auv-1's battery is too low for a goto: planning refuses it.
        f.announce("auv-1");
        f.h.ingest_state(crate::testing::state("auv-1", shoal_model::now_ms(), 1.0))
            .unwrap();
        f.alive("auv-2");
        let scenario = shoal_scenario::parse(&SCENARIO.replace("at_s = 5", "at_s = 2")).unwrap();
        tokio::time::timeout(
            Duration::from_secs(5),
            f.h.run_scenario(scenario, CancellationToken::new()),
        )
        .await
        .unwrap();
        assert!(!started(&f, "early-"));
        assert!(
            f.h.missions()
                .iter()
                .all(|m| !m.mission_id.starts_with("early-"))
        );
        assert!(started(&f, "late-"));
    }

    /// A station started again while a scenario's missions are under way (the register
    /// restores them) does not send them a second time.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_second_start_does_not_send_a_mission_still_under_way_again() {
        let f = Fixture::new();
        f.alive("auv-1");
        f.alive("auv-2");
        let text = SCENARIO.replace("at_s = 5", "at_s = 1");
        for _ in 0..2 {
            let scenario = shoal_scenario::parse(&text).unwrap();
            tokio::time::timeout(
                Duration::from_secs(5),
                f.h.run_scenario(scenario, CancellationToken::new()),
            )
            .await
            .unwrap();
            // The run suffix is in seconds: the second start gets another one.
            tokio::time::sleep(Duration::from_millis(1100)).await;
        }
        let ids: Vec<String> = f.h.missions().into_iter().map(|m| m.mission_id).collect();
        assert_eq!(ids.len(), 2, "{ids:?}");
        assert_eq!(f.out.tasks().len(), 2, "each vehicle got its task once");
    }
}
