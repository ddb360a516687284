//! Nominal kinematics and energy of each kind of vehicle: how fast it goes, dives and
//! turns, and how much battery a leg of a task takes.
//!
//! One model for everyone who estimates: the simulator flies and drains its battery by it,
//! and refuses a task it could not finish; the station previews a mission's duration and
//! energy per vehicle with the same numbers before an operator starts it. A real vehicle
//! differs from its kind's nominal profile, so the station's figures are estimates.
//!
//! Battery drain is a hotel load plus a propulsion term growing with the cube of speed (the
//! power of a displacement hull), in percent per hour. Estimates add
//! [`ENERGY_MARGIN`] for turns, acceleration and currents.

use crate::geo::path_length;
use crate::survey::{SurveyError, lawnmower};
use crate::{GeoPoint, Task, VehicleKind};

/// Energy estimates are raised by this factor for turns, acceleration and currents.
pub const ENERGY_MARGIN: f64 = 1.1;

/// Performance of one kind of vehicle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Profile {
    /// Cruise speed, m/s.
    pub cruise_mps: f64,
    /// Maximum speed, m/s.
    pub max_mps: f64,
    /// Vertical speed, m/s (0 for surface craft).
    pub vertical_mps: f64,
    /// Turn rate, degrees/s.
    pub turn_dps: f64,
    /// Battery percent per hour at rest.
    pub hotel_pct_h: f64,
    /// Extra battery percent per hour at maximum speed.
    pub propulsion_pct_h: f64,
    /// Water depth under the vehicle, for altitude, metres.
    pub seabed_m: f64,
}

/// Where a vehicle is when a leg ends, and what it took.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Leg {
    /// What the leg takes.
    pub cost: Cost,
    /// Where it ends.
    pub end: GeoPoint,
    /// Depth it ends at, metres.
    pub end_depth_m: f64,
}

/// What one leg of a task takes: time, and battery with [`ENERGY_MARGIN`].
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Cost {
    /// Duration, seconds.
    pub seconds: f64,
    /// Horizontal distance travelled, metres.
    pub distance_m: f64,
    /// Battery used, percent.
    pub battery_pct: f64,
}

impl Profile {
    /// The nominal profile of a kind of vehicle.
    pub fn of(kind: VehicleKind) -> Self {
        match kind {
            VehicleKind::Auv => Self {
                cruise_mps: 1.5,
                max_mps: 2.5,
                vertical_mps: 0.5,
                turn_dps: 10.0,
                hotel_pct_h: 2.0,
                propulsion_pct_h: 20.0,
                seabed_m: 80.0,
            },
            VehicleKind::Glider => Self {
                cruise_mps: 0.3,
                max_mps: 0.5,
                vertical_mps: 0.2,
                turn_dps: 3.0,
                hotel_pct_h: 0.2,
                propulsion_pct_h: 1.0,
                seabed_m: 80.0,
            },
            VehicleKind::Rov => Self {
                cruise_mps: 0.5,
                max_mps: 1.0,
                vertical_mps: 0.5,
                turn_dps: 30.0,
                hotel_pct_h: 5.0,
                propulsion_pct_h: 20.0,
                seabed_m: 80.0,
            },
            VehicleKind::Usv | VehicleKind::Asv => Self {
                cruise_mps: 2.0,
                max_mps: 4.0,
                vertical_mps: 0.0,
                turn_dps: 15.0,
                hotel_pct_h: 1.0,
                propulsion_pct_h: 25.0,
                seabed_m: 80.0,
            },
        }
    }

    /// Battery drain at a speed, percent per hour.
    pub fn drain_pct_h(&self, speed_mps: f64) -> f64 {
        self.hotel_pct_h
            + self.propulsion_pct_h * (speed_mps / self.max_mps).clamp(0.0, 1.0).powi(3)
    }

    /// The speed a task asking for `asked_mps` runs at: the cruise speed when it asks for
    /// none (0 or less), at most the maximum.
    pub fn speed_for(&self, asked_mps: f64) -> f64 {
        if asked_mps > self.max_mps {
            self.max_mps
        } else if asked_mps > 0.0 {
            asked_mps
        } else {
            self.cruise_mps
        }
    }

    /// Seconds to change depth by `dz` metres (none for surface craft).
    pub fn vertical_s(&self, dz: f64) -> f64 {
        if self.vertical_mps > 0.0 {
            dz.abs() / self.vertical_mps
        } else {
            0.0
        }
    }

    /// A route through `waypoints` from `from` at `speed_mps`, changing depth from
    /// `from_depth_m` to `depth_m` on the way: the vehicle dives while it travels, so the
    /// slower of the two sets the time.
    pub fn route(
        &self,
        from: GeoPoint,
        waypoints: &[GeoPoint],
        from_depth_m: f64,
        depth_m: f64,
        speed_mps: f64,
    ) -> Cost {
        let distance_m = path_length(from, waypoints);
        let seconds =
            (distance_m / speed_mps.max(0.01)).max(self.vertical_s(depth_m - from_depth_m));
        Cost {
            seconds,
            distance_m,
            battery_pct: self.drain_pct_h(speed_mps) * seconds / 3600.0 * ENERGY_MARGIN,
        }
    }

    /// Holding position (at rest) for `seconds`.
    pub fn hold(&self, seconds: f64) -> Cost {
        let seconds = seconds.max(0.0);
        Cost {
            seconds,
            distance_m: 0.0,
            battery_pct: self.hotel_pct_h * seconds / 3600.0 * ENERGY_MARGIN,
        }
    }

    /// Rising to the surface from `from_depth_m`.
    pub fn surface(&self, from_depth_m: f64) -> Cost {
        self.hold(self.vertical_s(from_depth_m))
    }

    /// The depth a moving task keeps: its depth, or the seabed less its altitude, or the
    /// surface; always the surface for surface craft.
    pub fn depth_for(&self, depth_m: Option<f64>, altitude_m: Option<f64>) -> f64 {
        if self.vertical_mps <= 0.0 {
            return 0.0;
        }
        depth_m
            .or_else(|| altitude_m.map(|a| (self.seabed_m - a).max(0.0)))
            .unwrap_or(0.0)
    }

    /// What a task takes from `from` at `from_depth_m`, for a vehicle whose home (launch
    /// point) is `home`; a `hold` of duration 0 (until the next task) counts as nothing.
    pub fn task(
        &self,
        task: &Task,
        from: GeoPoint,
        from_depth_m: f64,
        home: GeoPoint,
    ) -> Result<Leg, SurveyError> {
        let stay = |cost: Cost, end_depth_m: f64| Leg {
            cost,
            end: from,
            end_depth_m,
        };
        let go = |waypoints: &[GeoPoint], depth_m: f64, speed_mps: f64| Leg {
            cost: self.route(
                from,
                waypoints,
                from_depth_m,
                depth_m,
                self.speed_for(speed_mps),
            ),
            end: waypoints.last().copied().unwrap_or(from),
            end_depth_m: depth_m,
        };
        Ok(match task {
            Task::GotoWaypoint {
                target,
                depth_m,
                altitude_m,
                speed_mps,
            } => go(
                &[*target],
                self.depth_for(*depth_m, *altitude_m),
                *speed_mps,
            ),
            Task::SurveyArea {
                polygon,
                line_spacing_m,
                depth_m,
                altitude_m,
                speed_mps,
            } => go(
                &lawnmower(polygon, *line_spacing_m)?,
                self.depth_for(*depth_m, *altitude_m),
                *speed_mps,
            ),
            Task::Hold { duration_s } => stay(self.hold(*duration_s), from_depth_m),
            Task::Surface | Task::Abort => stay(self.surface(from_depth_m), 0.0),
            Task::ReturnHome => go(&[home], 0.0, 0.0),
            Task::RequestState | Task::SetReportingRate { .. } => {
                stay(Cost::default(), from_depth_m)
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn drain_grows_with_the_cube_of_speed_up_to_the_maximum() {
        let p = Profile::of(VehicleKind::Auv);
        assert_eq!(p.drain_pct_h(0.0), p.hotel_pct_h);
        assert!((p.drain_pct_h(p.max_mps) - 22.0).abs() < 1e-9);
        assert_eq!(p.drain_pct_h(2.0 * p.max_mps), p.drain_pct_h(p.max_mps));
        let half = p.drain_pct_h(p.max_mps / 2.0) - p.hotel_pct_h;
        assert!((half - p.propulsion_pct_h / 8.0).abs() < 1e-9);
    }

    #[test]
    fn speed_defaults_to_cruise_and_is_capped() {
        let p = Profile::of(VehicleKind::Usv);
        assert_eq!(p.speed_for(0.0), p.cruise_mps);
        assert_eq!(p.speed_for(-1.0), p.cruise_mps);
        assert_eq!(p.speed_for(1.0), 1.0);
        assert_eq!(p.speed_for(99.0), p.max_mps);
    }

    #[test]
    fn a_route_takes_the_slower_of_travel_and_dive() {
        let p = Profile::of(VehicleKind::Auv);
        let from = GeoPoint {
            latitude_deg: 63.44,
            longitude_deg: 10.4,
        };
        let to = GeoPoint {
            latitude_deg: 63.45,
            longitude_deg: 10.4,
        };
        let c = p.route(from, &[to], 0.0, 10.0, 1.5);
        assert!((c.distance_m - 1112.0).abs() < 5.0, "{c:?}");
        assert!((c.seconds - c.distance_m / 1.5).abs() < 1e-6);
        let expected = p.drain_pct_h(1.5) * c.seconds / 3600.0 * ENERGY_MARGIN;
        assert!((c.battery_pct - expected).abs() < 1e-9);
        // A deep dive to a close point: the dive sets the time.
        let dive = p.route(from, &[from], 0.0, 50.0, 1.5);
        assert_eq!(dive.seconds, 100.0);
        // Surface craft never dive.
        assert_eq!(Profile::of(VehicleKind::Usv).surface(30.0).seconds, 0.0);
        assert_eq!(p.surface(30.0).seconds, 60.0);
        assert_eq!(p.hold(-5.0), Cost::default());
    }

    #[test]
    fn tasks_chain_from_where_the_last_one_ended() {
        let p = Profile::of(VehicleKind::Auv);
        let home = GeoPoint {
            latitude_deg: 63.44,
            longitude_deg: 10.4,
        };
        let target = GeoPoint {
            latitude_deg: 63.45,
            longitude_deg: 10.4,
        };
        let goto = Task::GotoWaypoint {
            target,
            depth_m: Some(20.0),
            altitude_m: None,
            speed_mps: 0.0,
        };
        let out = p.task(&goto, home, 0.0, home).unwrap();
        assert_eq!((out.end, out.end_depth_m), (target, 20.0));
        assert!((out.cost.seconds - out.cost.distance_m / p.cruise_mps).abs() < 1e-6);
        let back = p.task(&Task::ReturnHome, out.end, 20.0, home).unwrap();
        assert_eq!((back.end, back.end_depth_m), (home, 0.0));
        assert!((back.cost.distance_m - out.cost.distance_m).abs() < 1e-6);
        let up = p.task(&Task::Surface, target, 20.0, home).unwrap();
        assert_eq!((up.cost.seconds, up.end_depth_m), (40.0, 0.0));
        // Altitude: the nominal seabed less the altitude; surface craft stay at the surface.
        assert_eq!(p.depth_for(None, Some(10.0)), 70.0);
        assert_eq!(
            Profile::of(VehicleKind::Usv).depth_for(Some(10.0), None),
            0.0
        );
        // A survey flies its lawnmower; a bad polygon is the survey's error.
        let survey = |polygon: Vec<GeoPoint>| Task::SurveyArea {
            polygon,
            line_spacing_m: 50.0,
            depth_m: Some(5.0),
            altitude_m: None,
            speed_mps: 1.5,
        };
        let square = vec![
            home,
            GeoPoint {
                latitude_deg: 63.44,
                longitude_deg: 10.41,
            },
            GeoPoint {
                latitude_deg: 63.445,
                longitude_deg: 10.41,
            },
            GeoPoint {
                latitude_deg: 63.445,
                longitude_deg: 10.4,
            },
        ];
        let flown = p.task(&survey(square), home, 0.0, home).unwrap();
        assert!(flown.cost.distance_m > 5000.0, "{flown:?}");
        assert!(matches!(
            p.task(&survey(vec![home]), home, 0.0, home),
            Err(SurveyError::TooFewCorners(1))
        ));
    }
}
