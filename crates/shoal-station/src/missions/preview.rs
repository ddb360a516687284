//! A mission's plan preview: before an operator starts a mission, how long each vehicle's
//! part takes, how far it goes and how much battery it uses, with a warning when its
//! battery would not suffice.
//!
//! The figures come from the nominal kinematics of the vehicle's kind
//! ([`shoal_model::kinematics::Profile`], the simulator's own model), chained task after
//! task from where the vehicle last reported itself. The mission is checked exactly as
//! planning it would check it, but nothing is registered or sent.

use serde::Serialize;
use shoal_model::kinematics::{Cost, Profile};
use shoal_model::{GeoPoint, UNKNOWN, VehicleKind};

use crate::core::StationHandle;
use crate::error::DispatchError;
use crate::missions::MissionSpec;

/// One vehicle's part of a previewed mission.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct VehiclePreview {
    /// The vehicle.
    pub vehicle_id: String,
    /// Its kind, whose nominal profile the estimate uses.
    pub kind: VehicleKind,
    /// Its tasks in the mission.
    pub tasks: usize,
    /// Horizontal distance it travels, metres.
    pub distance_m: f64,
    /// Time its tasks take, seconds (a `hold` until the next task counts as none).
    pub duration_s: f64,
    /// Battery its tasks use, percent, with a margin for turns and currents.
    pub energy_pct: f64,
    /// Its battery now, percent, when it has reported one.
    pub battery_pct: Option<f64>,
    /// Its battery when its part ends, percent (below 0: it runs out first).
    pub battery_after_pct: Option<f64>,
    /// The battery the station wants left: its minimum for giving a vehicle a task.
    pub reserve_pct: f64,
    /// Whether the estimate starts from a reported position (otherwise from its first
    /// waypoint, and the way there is not counted).
    pub from_position: bool,
    /// What the operator should know before starting: the battery would run out, or end
    /// below the reserve; no position or battery reported yet.
    pub warnings: Vec<String>,
}

/// A mission's plan preview.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MissionPreview {
    /// The mission id asked for.
    pub mission_id: String,
    /// The longest vehicle's duration, seconds: vehicles work in parallel.
    pub duration_s: f64,
    /// Each vehicle's part, in the order the vehicles first appear in the mission.
    pub vehicles: Vec<VehiclePreview>,
    /// Whether any vehicle has a warning.
    pub warnings: bool,
}

/// Where a vehicle starts its part from, as far as the station knows.
struct Start {
    kind: VehicleKind,
    at: Option<GeoPoint>,
    depth_m: f64,
    battery_pct: Option<f64>,
}

impl StationHandle {
    /// The plan preview of a mission: checked as [`Self::plan_mission`] checks it, then
    /// estimated per vehicle; nothing is registered.
    pub fn preview_mission(&self, spec: &MissionSpec) -> Result<MissionPreview, DispatchError> {
        let (_, assignments) = self.mission_assignments(spec)?;
        let assignments: Vec<shoal_model::TaskAssignment> =
            assignments.into_iter().map(|(a, _)| a).collect();
        let reserve_pct = self.core.config.min_dispatch_battery_pct;
        let mut vehicles: Vec<VehiclePreview> = Vec::new();
        let mut ids: Vec<&str> = Vec::new();
        for a in &assignments {
            if !ids.contains(&a.vehicle_id.as_str()) {
                ids.push(&a.vehicle_id);
            }
        }
        for id in ids {
            let start = self.start_of(id)?;
            let tasks: Vec<_> = assignments.iter().filter(|a| a.vehicle_id == id).collect();
            let mut total = Cost::default();
            let profile = Profile::of(start.kind);
            // Without a reported position, the first waypoint stands in for it.
            let first_target = tasks
                .iter()
                .find_map(|a| a.task().ok().and_then(|t| first_point(&t)));
            let home = start.at.or(first_target).unwrap_or(GeoPoint {
                latitude_deg: 0.0,
                longitude_deg: 0.0,
            });
            let (mut at, mut depth) = (home, start.depth_m);
            for (n, a) in tasks.iter().enumerate() {
                // Checked by `mission_assignments`: a task that does not parse is not here.
                let task = a.task().map_err(DispatchError::Invalid)?;
                let leg =
                    profile
                        .task(&task, at, depth, home)
                        .map_err(|e| DispatchError::InMission {
                            index: n,
                            error: Box::new(DispatchError::BadField {
                                field: "polygon",
                                rule: survey_rule(&e),
                            }),
                        })?;
                total.seconds += leg.cost.seconds;
                total.distance_m += leg.cost.distance_m;
                total.battery_pct += leg.cost.battery_pct;
                (at, depth) = (leg.end, leg.end_depth_m);
            }
            vehicles.push(vehicle_preview(id, &start, tasks.len(), total, reserve_pct));
        }
        let duration_s = vehicles.iter().map(|v| v.duration_s).fold(0.0, f64::max);
        let warnings = vehicles.iter().any(|v| !v.warnings.is_empty());
        Ok(MissionPreview {
            mission_id: spec.mission_id.clone(),
            duration_s,
            vehicles,
            warnings,
        })
    }

    /// Where the station last knew a vehicle to be, and its battery.
    fn start_of(&self, id: &str) -> Result<Start, DispatchError> {
        let Some(v) = self.vehicle(id) else {
            // Another site's vehicle: where the federation last saw it.
            let remote = self
                .federation()
                .and_then(|f| f.vehicles.into_iter().find(|v| v.vehicle_id == id))
                .ok_or_else(|| DispatchError::UnknownVehicle(id.to_owned()))?;
            return Ok(Start {
                kind: remote.kind,
                at: Some(GeoPoint {
                    latitude_deg: remote.latitude_deg,
                    longitude_deg: remote.longitude_deg,
                }),
                depth_m: remote.depth_m.max(0.0),
                battery_pct: Some(remote.battery_pct).filter(|b| *b != UNKNOWN),
            });
        };
        let latest = v.latest.as_ref();
        Ok(Start {
            kind: v.announcement.kind,
            at: latest.map(|s| GeoPoint {
                latitude_deg: s.latitude_deg,
                longitude_deg: s.longitude_deg,
            }),
            depth_m: latest.map_or(0.0, |s| s.depth_m.max(0.0)),
            battery_pct: latest.map(|s| s.battery_pct).filter(|b| *b != UNKNOWN),
        })
    }
}

/// The first place a task goes to, if it goes anywhere.
fn first_point(task: &shoal_model::Task) -> Option<GeoPoint> {
    match task {
        shoal_model::Task::GotoWaypoint { target, .. } => Some(*target),
        shoal_model::Task::SurveyArea { polygon, .. } => polygon.first().copied(),
        _ => None,
    }
}

/// The rule a survey polygon broke, for the error (the model checks most of them before).
fn survey_rule(e: &shoal_model::survey::SurveyError) -> &'static str {
    use shoal_model::survey::SurveyError;
    match e {
        SurveyError::TooManyLines { .. } => "the survey needs more lines than a vehicle flies",
        SurveyError::Antimeridian => "survey polygons across the antimeridian are not supported",
        _ => "a polygon of 3..=256 finite corners and a line spacing of at least 1 m",
    }
}

/// One vehicle's figures and warnings.
fn vehicle_preview(
    id: &str,
    start: &Start,
    tasks: usize,
    total: Cost,
    reserve_pct: f64,
) -> VehiclePreview {
    let mut warnings = Vec::new();
    let after = start.battery_pct.map(|b| b - total.battery_pct);
    match (start.battery_pct, after) {
        (Some(now), Some(after)) if after < 0.0 => {
            let share = (now / total.battery_pct).clamp(0.0, 1.0);
            warnings.push(format!(
                "its battery would run out: it needs about {:.0} % and has {now:.0} %, \
                 enough for about {} of {}",
                total.battery_pct,
                duration_text(total.seconds * share),
                duration_text(total.seconds),
            ));
        }
        (Some(_), Some(after)) if after < reserve_pct => warnings.push(format!(
            "its battery would end at about {after:.0} %, below the {reserve_pct:.0} % the \
             station keeps in reserve"
        )),
        _ => {}
    }
    if start.battery_pct.is_none() {
        warnings.push("no battery level reported yet: energy not checked".into());
    }
    if start.at.is_none() {
        warnings
            .push("no position reported yet: the way to its first waypoint is not counted".into());
    }
    VehiclePreview {
        vehicle_id: id.to_owned(),
        kind: start.kind,
        tasks,
        distance_m: total.distance_m,
        duration_s: total.seconds,
        energy_pct: total.battery_pct,
        battery_pct: start.battery_pct,
        battery_after_pct: after,
        reserve_pct,
        from_position: start.at.is_some(),
        warnings,
    }
}

/// A duration for people: `45 s`, `12 min`, `3 h 20 min`.
fn duration_text(seconds: f64) -> String {
    let s = seconds.max(0.0).round() as u64;
    match s {
        0..60 => format!("{s} s"),
        60..3600 => format!("{} min", s / 60),
        _ => format!("{} h {} min", s / 3600, s % 3600 / 60),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::{Fixture, goto, spec, state};
    use shoal_model::{Task, now_ms};

    #[test]
    fn a_preview_chains_each_vehicles_tasks_and_registers_nothing() {
        let f = Fixture::new();
        f.alive("auv-1");
        f.alive("auv-2");
        let hold = Task::Hold { duration_s: 600.0 };
        let m = spec(
            "m-1",
            &[("auv-1", goto()), ("auv-2", hold.clone()), ("auv-1", hold)],
        );
        let p = f.h.preview_mission(&m).unwrap();
        assert_eq!(p.vehicles.len(), 2);
        let (a, b) = (&p.vehicles[0], &p.vehicles[1]);
        assert_eq!((a.vehicle_id.as_str(), a.tasks), ("auv-1", 2));
        // 0.01 degrees of latitude at 1.5 m/s (the dive to 5 m is quicker), then 600 s.
        assert!((a.distance_m - 1112.0).abs() < 5.0, "{a:?}");
        assert!(
            (a.duration_s - (a.distance_m / 1.5 + 600.0)).abs() < 1e-6,
            "{a:?}"
        );
        assert_eq!(b.duration_s, 600.0);
        assert_eq!(p.duration_s, a.duration_s);
        assert_eq!(a.battery_pct, Some(80.0));
        let after = a.battery_after_pct.unwrap();
        assert!((after - (80.0 - a.energy_pct)).abs() < 1e-9 && after < 80.0);
        assert!(!p.warnings, "{p:?}");
        // Nothing registered, nothing sent: the same mission plans afterwards.
        assert!(f.h.mission("m-1").is_none());
        assert!(f.out.tasks().is_empty());
        f.h.plan_mission(m).unwrap();
    }

    #[test]
    fn a_vehicle_whose_battery_would_not_suffice_is_warned_about() {
        let f = Fixture::new();
        f.announce("auv-1");
        f.h.ingest_state(state("auv-1", now_ms(), 25.0)).unwrap();
        let far = Task::GotoWaypoint {
            target: GeoPoint {
                latitude_deg: 63.6,
                longitude_deg: 10.38,
            },
            depth_m: Some(5.0),
            altitude_m: None,
            speed_mps: 2.5,
        };
        let p =
            f.h.preview_mission(&spec("m-far", &[("auv-1", far)]))
                .unwrap();
        assert!(p.warnings);
        let v = &p.vehicles[0];
        assert!(v.battery_after_pct.unwrap() < 0.0, "{v:?}");
        assert!(v.warnings[0].contains("would run out"), "{v:?}");
    }

    #[test]
    fn a_preview_refuses_what_planning_refuses() {
        let f = Fixture::new();
        f.alive("auv-1");
        let err =
            f.h.preview_mission(&spec("m-1", &[("ghost", goto())]))
                .unwrap_err();
        assert!(
            matches!(&err, DispatchError::InMission { error, .. } if matches!(**error, DispatchError::UnknownVehicle(_))),
            "{err:?}"
        );
        let err =
            f.h.preview_mission(&spec("bad id!", &[("auv-1", goto())]))
                .unwrap_err();
        assert!(
            matches!(
                err,
                DispatchError::BadField {
                    field: "mission_id",
                    ..
                }
            ),
            "{err:?}"
        );
        f.h.plan_mission(spec("m-2", &[("auv-1", goto())])).unwrap();
        let err =
            f.h.preview_mission(&spec("m-2", &[("auv-1", goto())]))
                .unwrap_err();
        assert!(matches!(err, DispatchError::DuplicateMission(_)), "{err:?}");
    }

    fn start(battery: Option<f64>, at: bool) -> Start {
        Start {
            kind: VehicleKind::Auv,
            at: at.then_some(GeoPoint {
                latitude_deg: 63.44,
                longitude_deg: 10.4,
            }),
            depth_m: 0.0,
            battery_pct: battery,
        }
    }

    fn cost(battery_pct: f64) -> Cost {
        Cost {
            seconds: 3600.0,
            distance_m: 5000.0,
            battery_pct,
        }
    }

    #[test]
    fn enough_battery_gives_no_warning() {
        let v = vehicle_preview("auv-1", &start(Some(80.0), true), 2, cost(10.0), 20.0);
        assert!(v.warnings.is_empty(), "{v:?}");
        assert_eq!(v.battery_after_pct, Some(70.0));
        assert!(v.from_position);
    }

    #[test]
    fn ending_below_the_reserve_or_running_out_is_a_warning() {
        let v = vehicle_preview("auv-1", &start(Some(30.0), true), 1, cost(15.0), 20.0);
        assert_eq!(v.warnings.len(), 1, "{v:?}");
        assert!(v.warnings[0].contains("end at about 15 %"), "{v:?}");
        let v = vehicle_preview("auv-1", &start(Some(30.0), true), 1, cost(60.0), 20.0);
        assert!(v.warnings[0].contains("would run out"), "{v:?}");
        assert!(v.warnings[0].contains("about 30 min of 1 h 0 min"), "{v:?}");
    }

    #[test]
    fn what_is_not_known_is_said() {
        let v = vehicle_preview("auv-1", &start(None, false), 1, cost(5.0), 20.0);
        assert_eq!(v.battery_after_pct, None);
        assert_eq!(v.warnings.len(), 2, "{v:?}");
        assert!(!v.from_position);
    }

    #[test]
    fn durations_read_as_people_say_them() {
        assert_eq!(duration_text(42.4), "42 s");
        assert_eq!(duration_text(720.0), "12 min");
        assert_eq!(duration_text(12_000.0), "3 h 20 min");
        assert_eq!(duration_text(-1.0), "0 s");
    }
}
