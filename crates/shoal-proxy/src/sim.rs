//! A simulated vehicle: kinematics, battery and task execution, no I/O.
//!
//! Flat-earth kinematics around the current position (good to well under 0.1 % over the
//! few kilometres of a mission area), first-order depth and speed response, and a battery
//! that drains with a hotel load plus a term growing with the cube of speed (propulsion
//! power of a displacement hull).

use serde::{Deserialize, Serialize};
use shoal_model::{
    GeoPoint, LinkKind, StateVector, Task, TaskState, UNKNOWN, VehicleAnnouncement, VehicleKind,
};

const EARTH_RADIUS_M: f64 = 6_371_000.0;
/// Distance at which a waypoint counts as reached, metres.
pub const ARRIVAL_RADIUS_M: f64 = 5.0;

/// Performance of one kind of simulated vehicle.
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

impl Profile {
    /// The profile of a kind of vehicle.
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
}

/// What the simulated vehicle is doing.
#[derive(Debug, Clone, PartialEq)]
enum Activity {
    Idle,
    /// Following waypoints (a goto is one, a survey many) at a depth and speed.
    Route {
        waypoints: Vec<GeoPoint>,
        next: usize,
        depth_m: f64,
        speed_mps: f64,
    },
    Hold {
        remaining_s: Option<f64>,
    },
    Surfacing,
}

/// A task report the simulator wants sent.
#[derive(Debug, Clone, PartialEq)]
pub struct Report {
    /// Task reported on.
    pub task_id: String,
    /// New state.
    pub state: TaskState,
    /// Progress, percent.
    pub progress_pct: f64,
    /// Text for the operator.
    pub message: String,
}

/// One simulated vehicle's state.
#[derive(Debug, Clone)]
pub struct SimVehicle {
    /// Registration data it announces.
    pub announcement: VehicleAnnouncement,
    profile: Profile,
    lat: f64,
    lon: f64,
    depth: f64,
    speed: f64,
    yaw: f64,
    battery: f64,
    home: GeoPoint,
    activity: Activity,
    task: Option<String>,
    /// Reporting rate asked by the station (set_reporting_rate), Hz.
    pub rate_hz: f64,
    /// A state vector was requested (request_state) and not yet sent.
    pub state_requested: bool,
}

/// Where and how a simulated vehicle starts.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimSpec {
    /// Vehicle id.
    pub id: String,
    /// Kind of vehicle.
    pub kind: VehicleKind,
    /// Start latitude, degrees.
    pub latitude_deg: f64,
    /// Start longitude, degrees.
    pub longitude_deg: f64,
    /// State vectors per second.
    #[serde(default = "default_rate")]
    pub rate_hz: f64,
    /// Battery at start, percent.
    #[serde(default = "default_battery")]
    pub battery_pct: f64,
}

fn default_rate() -> f64 {
    1.0
}
fn default_battery() -> f64 {
    100.0
}

impl SimVehicle {
    /// A vehicle at rest at its start position.
    pub fn new(spec: &SimSpec, timestamp_ms: i64) -> Self {
        let profile = Profile::of(spec.kind);
        let (capabilities, sensors, links): (&[&str], &[&str], Vec<LinkKind>) = match spec.kind {
            VehicleKind::Auv | VehicleKind::Glider => (
                &["goto", "survey", "hold", "surface", "return_home"],
                &["ctd", "sidescan_sonar", "dvl"],
                vec![LinkKind::Ip, LinkKind::Acoustic],
            ),
            VehicleKind::Rov => (
                &["goto", "hold", "surface"],
                &["camera", "ctd"],
                vec![LinkKind::Tether, LinkKind::Ip],
            ),
            VehicleKind::Usv | VehicleKind::Asv => (
                &["goto", "survey", "hold", "return_home"],
                &["gps", "weather_station", "multibeam_sonar"],
                vec![LinkKind::Ip, LinkKind::Radio, LinkKind::Acoustic],
            ),
        };
        let announcement = VehicleAnnouncement {
            vehicle_id: spec.id.clone(),
            name: format!(
                "Simulated {} {}",
                spec.kind.as_str().to_uppercase(),
                spec.id
            ),
            kind: spec.kind,
            vendor: "Shoal simulator".into(),
            capabilities: capabilities.iter().map(|s| (*s).to_string()).collect(),
            sensors: sensors.iter().map(|s| (*s).to_string()).collect(),
            links,
            max_speed_mps: profile.max_mps,
            timestamp_ms,
        };
        Self {
            announcement,
            profile,
            lat: spec.latitude_deg,
            lon: spec.longitude_deg,
            depth: 0.0,
            speed: 0.0,
            yaw: 0.0,
            battery: spec.battery_pct.clamp(0.0, 100.0),
            home: GeoPoint {
                latitude_deg: spec.latitude_deg,
                longitude_deg: spec.longitude_deg,
            },
            activity: Activity::Idle,
            task: None,
            rate_hz: spec.rate_hz,
            state_requested: false,
        }
    }

    /// The current state vector.
    pub fn state(&self, timestamp_ms: i64) -> StateVector {
        let underwater = self.announcement.kind.is_underwater();
        StateVector {
            vehicle_id: self.announcement.vehicle_id.clone(),
            timestamp_ms,
            latitude_deg: self.lat,
            longitude_deg: self.lon,
            depth_m: self.depth,
            altitude_m: if underwater {
                (self.profile.seabed_m - self.depth).max(0.0)
            } else {
                UNKNOWN
            },
            speed_mps: self.speed,
            yaw_deg: self.yaw.rem_euclid(360.0),
            pitch_deg: 0.0,
            roll_deg: 0.0,
            battery_pct: self.battery,
        }
    }

    /// Starts a task; returns the reports to send (accepted, or failed with a reason).
    pub fn start(&mut self, task_id: &str, task: &Task) -> Vec<Report> {
        let mut out = Vec::new();
        if let Some(prev) = self.task.take() {
            out.push(report(
                &prev,
                TaskState::Aborted,
                0.0,
                "superseded by a new task",
            ));
        }
        let underwater = self.announcement.kind.is_underwater();
        let depth_for = |depth: Option<f64>, altitude: Option<f64>| -> f64 {
            if !underwater {
                return 0.0;
            }
            depth
                .or_else(|| altitude.map(|a| (self.profile.seabed_m - a).max(0.0)))
                .unwrap_or(0.0)
        };
        let cruise = |s: f64| {
            if s > 0.0 {
                s.min(self.profile.max_mps)
            } else {
                self.profile.cruise_mps
            }
        };
        let activity = match task {
            Task::GotoWaypoint {
                target,
                depth_m,
                altitude_m,
                speed_mps,
            } => Activity::Route {
                waypoints: vec![*target],
                next: 0,
                depth_m: depth_for(*depth_m, *altitude_m),
                speed_mps: cruise(*speed_mps),
            },
            Task::SurveyArea {
                polygon,
                line_spacing_m,
                depth_m,
                altitude_m,
                speed_mps,
            } => Activity::Route {
                waypoints: lawnmower(polygon, *line_spacing_m),
                next: 0,
                depth_m: depth_for(*depth_m, *altitude_m),
                speed_mps: cruise(*speed_mps),
            },
            Task::Hold { duration_s } => Activity::Hold {
                remaining_s: (*duration_s > 0.0).then_some(*duration_s),
            },
            Task::Surface | Task::Abort => Activity::Surfacing,
            Task::ReturnHome => Activity::Route {
                waypoints: vec![self.home],
                next: 0,
                depth_m: 0.0,
                speed_mps: self.profile.cruise_mps,
            },
            Task::RequestState => {
                self.state_requested = true;
                out.push(report(task_id, TaskState::Done, 100.0, "state vector sent"));
                return out;
            }
            Task::SetReportingRate { rate_hz } => {
                self.rate_hz = *rate_hz;
                out.push(report(
                    task_id,
                    TaskState::Done,
                    100.0,
                    &format!("reporting at {rate_hz} Hz"),
                ));
                return out;
            }
        };
        if let Activity::Route { waypoints, .. } = &activity
            && waypoints.is_empty()
        {
            out.push(report(
                task_id,
                TaskState::Failed,
                0.0,
                "survey polygon yields no survey lines",
            ));
            return out;
        }
        self.activity = activity;
        self.task = Some(task_id.to_string());
        out.push(report(task_id, TaskState::Accepted, 0.0, ""));
        out.push(report(task_id, TaskState::Running, 0.0, ""));
        out
    }

    /// Advances the simulation by `dt` seconds; returns task reports to send.
    pub fn step(&mut self, dt: f64) -> Vec<Report> {
        let mut out = Vec::new();
        let p = self.profile;
        let (target_speed, target_depth) = match &mut self.activity {
            Activity::Idle | Activity::Hold { .. } => (0.0, self.depth),
            Activity::Surfacing => (0.0, 0.0),
            Activity::Route {
                waypoints,
                next,
                depth_m,
                speed_mps,
            } => {
                let wp = waypoints[*next];
                let (dist, bearing) =
                    distance_bearing(self.lat, self.lon, wp.latitude_deg, wp.longitude_deg);
                if dist <= ARRIVAL_RADIUS_M {
                    *next += 1;
                    #[allow(clippy::cast_precision_loss)]
                    let progress = 100.0 * *next as f64 / waypoints.len() as f64;
                    if *next >= waypoints.len() {
                        if let Some(t) = self.task.take() {
                            out.push(report(&t, TaskState::Done, 100.0, "arrived"));
                        }
                        self.activity = Activity::Hold { remaining_s: None };
                        (0.0, self.depth)
                    } else {
                        if let Some(t) = &self.task {
                            out.push(report(t, TaskState::Running, progress, ""));
                        }
                        (*speed_mps, *depth_m)
                    }
                } else {
                    let turn =
                        angle_diff(bearing, self.yaw).clamp(-p.turn_dps * dt, p.turn_dps * dt);
                    self.yaw = (self.yaw + turn).rem_euclid(360.0);
                    // Slow down on the final approach so the vehicle does not overshoot.
                    (speed_mps.min(dist / dt.max(1e-3) * 0.5), *depth_m)
                }
            }
        };
        if let Activity::Hold {
            remaining_s: Some(r),
        } = &mut self.activity
        {
            *r -= dt;
            if *r <= 0.0 {
                if let Some(t) = self.task.take() {
                    out.push(report(&t, TaskState::Done, 100.0, "hold complete"));
                }
                self.activity = Activity::Idle;
            }
        }
        // First-order response of speed (time constant 2 s) and bounded vertical speed.
        self.speed += (target_speed - self.speed) * (dt / 2.0).min(1.0);
        self.speed = self.speed.clamp(0.0, p.max_mps);
        let dz = (target_depth - self.depth).clamp(-p.vertical_mps * dt, p.vertical_mps * dt);
        self.depth = (self.depth + dz).max(0.0);
        if self.activity == Activity::Surfacing && self.depth <= 0.01 {
            self.depth = 0.0;
            if let Some(t) = self.task.take() {
                out.push(report(&t, TaskState::Done, 100.0, "at the surface"));
            }
            self.activity = Activity::Idle;
        }
        let d = self.speed * dt;
        let yaw = self.yaw.to_radians();
        self.lat += (d * yaw.cos() / EARTH_RADIUS_M).to_degrees();
        self.lon +=
            (d * yaw.sin() / (EARTH_RADIUS_M * self.lat.to_radians().cos().max(1e-6))).to_degrees();
        self.lat = self.lat.clamp(-89.9, 89.9);
        if self.lon > 180.0 {
            self.lon -= 360.0;
        } else if self.lon < -180.0 {
            self.lon += 360.0;
        }
        let load = (self.speed / p.max_mps).powi(3);
        self.battery =
            (self.battery - (p.hotel_pct_h + p.propulsion_pct_h * load) * dt / 3600.0).max(0.0);
        out
    }

    /// The task being executed, if any.
    pub fn current_task(&self) -> Option<&str> {
        self.task.as_deref()
    }
}

fn report(task_id: &str, state: TaskState, progress_pct: f64, message: &str) -> Report {
    Report {
        task_id: task_id.to_string(),
        state,
        progress_pct,
        message: message.to_string(),
    }
}

/// Signed smallest difference `a - b` between two headings, degrees in (-180, 180].
fn angle_diff(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(360.0);
    if d > 180.0 { d - 360.0 } else { d }
}

/// Equirectangular distance (m) and initial bearing (degrees) between two nearby points.
pub fn distance_bearing(lat1: f64, lon1: f64, lat2: f64, lon2: f64) -> (f64, f64) {
    let mean_lat = ((lat1 + lat2) / 2.0).to_radians();
    let north = (lat2 - lat1).to_radians() * EARTH_RADIUS_M;
    let east = (lon2 - lon1).to_radians() * EARTH_RADIUS_M * mean_lat.cos();
    (
        north.hypot(east),
        east.atan2(north).to_degrees().rem_euclid(360.0),
    )
}

/// Lawnmower waypoints covering a polygon's bounding box, lines east-west, `spacing_m` apart.
pub fn lawnmower(polygon: &[GeoPoint], spacing_m: f64) -> Vec<GeoPoint> {
    if polygon.len() < 3 || spacing_m.is_nan() || spacing_m < 1.0 {
        return Vec::new();
    }
    let (mut s, mut n, mut w, mut e) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for p in polygon {
        s = s.min(p.latitude_deg);
        n = n.max(p.latitude_deg);
        w = w.min(p.longitude_deg);
        e = e.max(p.longitude_deg);
    }
    let step = (spacing_m / EARTH_RADIUS_M).to_degrees();
    let mut out = Vec::new();
    let mut lat = s;
    let mut eastward = true;
    // Bounded so a degenerate polygon can never make an unbounded route.
    while lat <= n + 1e-12 && out.len() < 2000 {
        let (a, b) = if eastward { (w, e) } else { (e, w) };
        out.push(GeoPoint {
            latitude_deg: lat,
            longitude_deg: a,
        });
        out.push(GeoPoint {
            latitude_deg: lat,
            longitude_deg: b,
        });
        eastward = !eastward;
        lat += step;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use shoal_model::Validate;

    fn auv() -> SimVehicle {
        let spec = SimSpec {
            id: "auv-1".into(),
            kind: VehicleKind::Auv,
            latitude_deg: 43.0,
            longitude_deg: 5.9,
            rate_hz: 1.0,
            battery_pct: 100.0,
        };
        SimVehicle::new(&spec, 1_700_000_000_000)
    }

    fn run(v: &mut SimVehicle, seconds: usize) -> Vec<Report> {
        (0..seconds * 10).flat_map(|_| v.step(0.1)).collect()
    }

    #[test]
    fn announcement_and_states_are_valid() {
        let mut v = auv();
        assert_eq!(v.announcement.validate(), Ok(()));
        let target = GeoPoint {
            latitude_deg: 43.001,
            longitude_deg: 5.901,
        };
        v.start(
            "t",
            &Task::GotoWaypoint {
                target,
                depth_m: Some(20.0),
                altitude_m: None,
                speed_mps: 1.5,
            },
        );
        for _ in 0..2000 {
            v.step(0.1);
            assert_eq!(v.state(1_700_000_000_000).validate(), Ok(()));
        }
    }

    #[test]
    fn goto_arrives_and_reports_done() {
        let mut v = auv();
        let target = GeoPoint {
            latitude_deg: 43.002,
            longitude_deg: 5.9,
        };
        let started = v.start(
            "t1",
            &Task::GotoWaypoint {
                target,
                depth_m: Some(10.0),
                altitude_m: None,
                speed_mps: 2.0,
            },
        );
        assert_eq!(
            started.iter().map(|r| r.state).collect::<Vec<_>>(),
            [TaskState::Accepted, TaskState::Running]
        );
        let reports = run(&mut v, 600);
        assert!(
            reports
                .iter()
                .any(|r| r.task_id == "t1" && r.state == TaskState::Done),
            "{reports:?}"
        );
        let (d, _) = distance_bearing(v.lat, v.lon, target.latitude_deg, target.longitude_deg);
        assert!(d <= ARRIVAL_RADIUS_M + 1.0, "{d} m from target");
        assert!((v.depth - 10.0).abs() < 1.0);
    }

    #[test]
    fn battery_drains_faster_at_speed() {
        let mut resting = auv();
        run(&mut resting, 600);
        let mut moving = auv();
        let target = GeoPoint {
            latitude_deg: 44.0,
            longitude_deg: 5.9,
        };
        moving.start(
            "t",
            &Task::GotoWaypoint {
                target,
                depth_m: Some(5.0),
                altitude_m: None,
                speed_mps: 2.5,
            },
        );
        run(&mut moving, 600);
        assert!(moving.battery < resting.battery && resting.battery < 100.0);
    }

    #[test]
    fn a_new_task_aborts_the_previous_one() {
        let mut v = auv();
        v.start("a", &Task::Hold { duration_s: 0.0 });
        let r = v.start("b", &Task::Surface);
        assert_eq!(r[0].task_id, "a");
        assert_eq!(r[0].state, TaskState::Aborted);
    }

    #[test]
    fn lawnmower_covers_the_box_in_alternating_lines() {
        let poly = [
            GeoPoint {
                latitude_deg: 43.0,
                longitude_deg: 5.9,
            },
            GeoPoint {
                latitude_deg: 43.0,
                longitude_deg: 5.91,
            },
            GeoPoint {
                latitude_deg: 43.001,
                longitude_deg: 5.91,
            },
        ];
        let wps = lawnmower(&poly, 20.0);
        // 0.001° of latitude is about 111 m: lines at 0, 20, ..., 100 m → 6 lines.
        assert_eq!(wps.len(), 12);
        assert!(
            wps[0].longitude_deg < wps[1].longitude_deg
                && wps[2].longitude_deg > wps[3].longitude_deg
        );
        assert!(lawnmower(&poly, 0.0).is_empty());
    }

    #[test]
    fn surface_craft_stay_at_the_surface() {
        let spec = SimSpec {
            id: "usv-1".into(),
            kind: VehicleKind::Usv,
            latitude_deg: 0.0,
            longitude_deg: 0.0,
            rate_hz: 1.0,
            battery_pct: 50.0,
        };
        let mut v = SimVehicle::new(&spec, 1_700_000_000_000);
        let target = GeoPoint {
            latitude_deg: 0.001,
            longitude_deg: 0.0,
        };
        v.start(
            "t",
            &Task::GotoWaypoint {
                target,
                depth_m: Some(30.0),
                altitude_m: None,
                speed_mps: 1.0,
            },
        );
        run(&mut v, 30);
        assert_eq!(v.depth, 0.0);
        assert_eq!(v.state(1_700_000_000_000).altitude_m, UNKNOWN);
    }
}
