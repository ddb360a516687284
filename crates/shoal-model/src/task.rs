//! Tasks: assignments from the station and status reports from vehicles.
//!
//! On the wire a [`TaskAssignment`] is one flat struct (a kind plus every parameter) because
//! flat structs are what every DDS vendor's IDL tooling handles alike; [`Task`] is the typed
//! view the rest of Shoal works with, and [`TaskAssignment::task`] checks the two agree.

use serde::{Deserialize, Serialize};

use crate::validate::{finite_in, identifier, optional_identifier, optional_in, text, timestamp};
use crate::{
    MAX_ID_LEN, MAX_TEXT_LEN, MAX_VEHICLE_ID_LEN, StateVector, UNKNOWN, Validate, ValidationError,
};

/// A WGS84 position on the surface, in degrees.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct GeoPoint {
    /// Latitude in degrees, [-90, 90].
    pub latitude_deg: f64,
    /// Longitude in degrees, [-180, 180].
    pub longitude_deg: f64,
}

impl Validate for GeoPoint {
    fn validate(&self) -> Result<(), ValidationError> {
        let (lat, lon) = (StateVector::LATITUDE, StateVector::LONGITUDE);
        finite_in("area.latitude_deg", self.latitude_deg, lat.0, lat.1)?;
        finite_in("area.longitude_deg", self.longitude_deg, lon.0, lon.1)
    }
}

/// The kind of a simple task; the IDL enum `shoal::TaskKind` in the same order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TaskKind {
    /// Go to one waypoint.
    GotoWaypoint,
    /// Lawnmower survey over a polygon.
    SurveyArea,
    /// Hold position / loiter.
    Hold,
    /// Come to the surface.
    Surface,
    /// Return to the launch point.
    ReturnHome,
    /// Emergency surface / abort everything.
    Abort,
    /// Send a state vector now.
    RequestState,
    /// Change the state reporting rate.
    SetReportingRate,
}

/// True when two non-adjacent edges of the closed polygon cross or touch (longitude and
/// latitude as planar coordinates, as the lawnmower planner uses them). O(n²) over at
/// most `MAX_AREA` corners.
fn self_intersecting(polygon: &[GeoPoint]) -> bool {
    fn orient(a: GeoPoint, b: GeoPoint, c: GeoPoint) -> f64 {
        (b.longitude_deg - a.longitude_deg) * (c.latitude_deg - a.latitude_deg)
            - (b.latitude_deg - a.latitude_deg) * (c.longitude_deg - a.longitude_deg)
    }
    fn on_segment(a: GeoPoint, b: GeoPoint, p: GeoPoint) -> bool {
        p.longitude_deg >= a.longitude_deg.min(b.longitude_deg)
            && p.longitude_deg <= a.longitude_deg.max(b.longitude_deg)
            && p.latitude_deg >= a.latitude_deg.min(b.latitude_deg)
            && p.latitude_deg <= a.latitude_deg.max(b.latitude_deg)
    }
    fn cross(a: GeoPoint, b: GeoPoint, c: GeoPoint, d: GeoPoint) -> bool {
        let (o1, o2, o3, o4) = (
            orient(a, b, c),
            orient(a, b, d),
            orient(c, d, a),
            orient(c, d, b),
        );
        if o1 * o2 < 0.0 && o3 * o4 < 0.0 {
            return true;
        }
        (o1 == 0.0 && on_segment(a, b, c))
            || (o2 == 0.0 && on_segment(a, b, d))
            || (o3 == 0.0 && on_segment(c, d, a))
            || (o4 == 0.0 && on_segment(c, d, b))
    }
    let n = polygon.len();
    if n < 4 {
        // A triangle cannot cross itself (a degenerate one is caught by the area check).
        return false;
    }
    for i in 0..n {
        let (a, b) = (polygon[i], polygon[(i + 1) % n]);
        for j in (i + 2)..n {
            // The first and last edges share a corner.
            if i == 0 && j == n - 1 {
                continue;
            }
            if cross(a, b, polygon[j], polygon[(j + 1) % n]) {
                return true;
            }
        }
    }
    false
}

impl TaskKind {
    /// Every kind, in the IDL's declaration order (the order of their wire codes).
    pub const ALL: [Self; 8] = [
        Self::GotoWaypoint,
        Self::SurveyArea,
        Self::Hold,
        Self::Surface,
        Self::ReturnHome,
        Self::Abort,
        Self::RequestState,
        Self::SetReportingRate,
    ];

    /// The capability code a vehicle announces to say it can do this kind of task.
    pub fn capability(self) -> &'static str {
        match self {
            Self::GotoWaypoint => "goto",
            Self::SurveyArea => "survey",
            Self::Hold => "hold",
            Self::Surface => "surface",
            Self::ReturnHome => "return_home",
            Self::Abort => "abort",
            Self::RequestState => "request_state",
            Self::SetReportingRate => "set_reporting_rate",
        }
    }
}

/// A simple task for one vehicle; DDS key `task_id`, reliable and transient-local.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TaskAssignment {
    /// Task identifier: 1..=64 of `[A-Za-z0-9_.-]`.
    pub task_id: String,
    /// Mission the task belongs to, or empty.
    pub mission_id: String,
    /// Vehicle that must execute the task.
    pub vehicle_id: String,
    /// When the station issued the task, ms since the Unix epoch.
    pub issued_ms: i64,
    /// What to do; which parameters below apply depends on it.
    pub kind: TaskKind,
    /// `goto_waypoint`: exactly one point; `survey_area`: polygon of 3..=256 corners.
    pub area: Vec<GeoPoint>,
    /// Target depth in metres [0, 11000], or -1 to keep altitude instead.
    pub depth_m: f64,
    /// Target altitude above seabed in metres [0, 10000], or -1 to keep depth instead.
    pub altitude_m: f64,
    /// Speed in m/s, [0, 30]; 0 lets the vehicle choose.
    pub speed_mps: f64,
    /// `survey_area`: distance between survey lines in metres, [1, 10000].
    pub line_spacing_m: f64,
    /// `hold`: how long in seconds, [0, 86400]; 0 means until the next task.
    pub duration_s: f64,
    /// `set_reporting_rate`: state vectors per second, (0, 100].
    pub rate_hz: f64,
    /// The station's issue sequence: strictly increasing across the station's restarts, so
    /// a vehicle can order tasks exactly; 0 when a tool, not a station, issued the task.
    pub issue_seq: u64,
    /// The last instant the vehicle may start the task, ms since the Unix epoch; a task
    /// that arrives later is refused as expired (one already started is not stopped).
    /// 0 when the issuer set none: the vehicle then applies its own maximum task age.
    pub expires_ms: i64,
    /// The term of the command lease the issuing station held for the vehicle; 0 when the
    /// station commands without a lease (not federated, or the lease is off). A vehicle
    /// refuses a task whose lease is older than one it has already obeyed. Absent from a
    /// JSON body is 0 (a station stamps its own lease on every task it sends anyway).
    #[serde(default)]
    pub lease_term: u64,
    /// The site that held that lease (1..=32 of `[A-Za-z0-9_.-]`); empty when
    /// `lease_term` is 0.
    #[serde(default)]
    pub lease_holder: String,
}

/// Whether the command lease `(term, holder)` is newer than `(other_term, other_holder)`:
/// a higher term, or the same term held by a site whose name sorts first. Every site and
/// every vehicle orders leases so, which is how they agree after a partition in which two
/// sites took the same term.
pub fn lease_supersedes(term: u64, holder: &str, other_term: u64, other_holder: &str) -> bool {
    term > other_term || (term == other_term && holder < other_holder)
}

/// The typed view of a [`TaskAssignment`]'s kind and parameters.
/// As JSON, tagged by `kind` (`{"kind": "goto_waypoint", "target": {...}, "speed_mps": 1.5}`);
/// an absent `depth_m` or `altitude_m` is `None`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Task {
    /// Go to a waypoint at a depth (or altitude) and speed.
    GotoWaypoint {
        /// Where to go.
        target: GeoPoint,
        /// Depth in metres, or `None` to hold altitude.
        #[serde(default)]
        depth_m: Option<f64>,
        /// Altitude in metres, or `None` to hold depth.
        #[serde(default)]
        altitude_m: Option<f64>,
        /// Speed in m/s.
        speed_mps: f64,
    },
    /// Lawnmower survey over a polygon.
    SurveyArea {
        /// Polygon corners, 3..=256.
        polygon: Vec<GeoPoint>,
        /// Distance between lines in metres.
        line_spacing_m: f64,
        /// Depth in metres, or `None` to hold altitude.
        #[serde(default)]
        depth_m: Option<f64>,
        /// Altitude in metres, or `None` to hold depth.
        #[serde(default)]
        altitude_m: Option<f64>,
        /// Speed in m/s.
        speed_mps: f64,
    },
    /// Hold position for a duration (0 = until the next task).
    Hold {
        /// Seconds.
        duration_s: f64,
    },
    /// Come to the surface.
    Surface,
    /// Return to the launch point.
    ReturnHome,
    /// Emergency surface.
    Abort,
    /// Report a state vector now.
    RequestState,
    /// Report state at this rate.
    SetReportingRate {
        /// State vectors per second.
        rate_hz: f64,
    },
}

fn some_unless_unknown(v: f64) -> Option<f64> {
    if v == UNKNOWN { None } else { Some(v) }
}

/// Longest command lease holder (a site name) a task carries.
pub const MAX_LEASE_HOLDER_LEN: usize = 32;

impl TaskAssignment {
    /// Most polygon corners a survey may have.
    pub const MAX_AREA: usize = 256;

    /// Builds the wire form of a typed task.
    pub fn new(
        task_id: impl Into<String>,
        mission_id: impl Into<String>,
        vehicle_id: impl Into<String>,
        issued_ms: i64,
        task: &Task,
    ) -> Self {
        let mut a = Self {
            task_id: task_id.into(),
            mission_id: mission_id.into(),
            vehicle_id: vehicle_id.into(),
            issued_ms,
            kind: task.kind(),
            area: Vec::new(),
            depth_m: UNKNOWN,
            altitude_m: UNKNOWN,
            speed_mps: 0.0,
            line_spacing_m: 0.0,
            duration_s: 0.0,
            rate_hz: 0.0,
            issue_seq: 0,
            expires_ms: 0,
            lease_term: 0,
            lease_holder: String::new(),
        };
        match task {
            Task::GotoWaypoint {
                target,
                depth_m,
                altitude_m,
                speed_mps,
            } => {
                a.area = vec![*target];
                a.depth_m = depth_m.unwrap_or(UNKNOWN);
                a.altitude_m = altitude_m.unwrap_or(UNKNOWN);
                a.speed_mps = *speed_mps;
            }
            Task::SurveyArea {
                polygon,
                line_spacing_m,
                depth_m,
                altitude_m,
                speed_mps,
            } => {
                a.area.clone_from(polygon);
                a.line_spacing_m = *line_spacing_m;
                a.depth_m = depth_m.unwrap_or(UNKNOWN);
                a.altitude_m = altitude_m.unwrap_or(UNKNOWN);
                a.speed_mps = *speed_mps;
            }
            Task::Hold { duration_s } => a.duration_s = *duration_s,
            Task::SetReportingRate { rate_hz } => a.rate_hz = *rate_hz,
            Task::Surface | Task::ReturnHome | Task::Abort | Task::RequestState => {}
        }
        a
    }

    /// Whether the task may still start at `now_ms`: before its expiry, or, when it has
    /// none, no older than `max_age_ms` (if given).
    pub fn may_start(&self, now_ms: i64, max_age_ms: Option<i64>) -> bool {
        if self.expires_ms != 0 {
            return now_ms <= self.expires_ms;
        }
        max_age_ms.is_none_or(|max| now_ms.saturating_sub(self.issued_ms) <= max)
    }

    /// The typed task, after validating every field that its kind uses.
    pub fn task(&self) -> Result<Task, ValidationError> {
        self.validate()?;
        Ok(match self.kind {
            TaskKind::GotoWaypoint => Task::GotoWaypoint {
                target: self.area[0],
                depth_m: some_unless_unknown(self.depth_m),
                altitude_m: some_unless_unknown(self.altitude_m),
                speed_mps: self.speed_mps,
            },
            TaskKind::SurveyArea => Task::SurveyArea {
                polygon: self.area.clone(),
                line_spacing_m: self.line_spacing_m,
                depth_m: some_unless_unknown(self.depth_m),
                altitude_m: some_unless_unknown(self.altitude_m),
                speed_mps: self.speed_mps,
            },
            TaskKind::Hold => Task::Hold {
                duration_s: self.duration_s,
            },
            TaskKind::Surface => Task::Surface,
            TaskKind::ReturnHome => Task::ReturnHome,
            TaskKind::Abort => Task::Abort,
            TaskKind::RequestState => Task::RequestState,
            TaskKind::SetReportingRate => Task::SetReportingRate {
                rate_hz: self.rate_hz,
            },
        })
    }
}

impl Task {
    /// The wire kind of this task.
    pub fn kind(&self) -> TaskKind {
        match self {
            Self::GotoWaypoint { .. } => TaskKind::GotoWaypoint,
            Self::SurveyArea { .. } => TaskKind::SurveyArea,
            Self::Hold { .. } => TaskKind::Hold,
            Self::Surface => TaskKind::Surface,
            Self::ReturnHome => TaskKind::ReturnHome,
            Self::Abort => TaskKind::Abort,
            Self::RequestState => TaskKind::RequestState,
            Self::SetReportingRate { .. } => TaskKind::SetReportingRate,
        }
    }
}

impl Validate for TaskAssignment {
    fn validate(&self) -> Result<(), ValidationError> {
        identifier("task_id", &self.task_id, MAX_ID_LEN)?;
        optional_identifier("mission_id", &self.mission_id, MAX_ID_LEN)?;
        identifier("vehicle_id", &self.vehicle_id, MAX_VEHICLE_ID_LEN)?;
        timestamp("issued_ms", self.issued_ms)?;
        if self.area.len() > Self::MAX_AREA {
            return Err(ValidationError::Inconsistent {
                field: "area",
                rule: "at most 256 points",
            });
        }
        for p in &self.area {
            p.validate()?;
        }
        optional_in(
            "depth_m",
            self.depth_m,
            StateVector::DEPTH.0,
            StateVector::DEPTH.1,
        )?;
        optional_in(
            "altitude_m",
            self.altitude_m,
            StateVector::ALTITUDE.0,
            StateVector::ALTITUDE.1,
        )?;
        finite_in(
            "speed_mps",
            self.speed_mps,
            StateVector::SPEED.0,
            StateVector::SPEED.1,
        )?;
        finite_in("line_spacing_m", self.line_spacing_m, 0.0, 10_000.0)?;
        finite_in("duration_s", self.duration_s, 0.0, 86_400.0)?;
        finite_in("rate_hz", self.rate_hz, 0.0, 100.0)?;
        if self.expires_ms != 0 {
            timestamp("expires_ms", self.expires_ms)?;
            if self.expires_ms < self.issued_ms {
                return Err(ValidationError::Inconsistent {
                    field: "expires_ms",
                    rule: "a task cannot expire before it is issued (0 means no expiry)",
                });
            }
        }
        optional_identifier("lease_holder", &self.lease_holder, MAX_LEASE_HOLDER_LEN)?;
        if (self.lease_term == 0) != self.lease_holder.is_empty() {
            return Err(ValidationError::Inconsistent {
                field: "lease_holder",
                rule: "a lease holder goes with a lease term above 0, and no holder with term 0",
            });
        }
        let moves = matches!(self.kind, TaskKind::GotoWaypoint | TaskKind::SurveyArea);
        if moves && (self.depth_m == UNKNOWN) == (self.altitude_m == UNKNOWN) {
            return Err(ValidationError::Inconsistent {
                field: "depth_m",
                rule: "exactly one of depth_m and altitude_m must be set (the other -1)",
            });
        }
        match self.kind {
            TaskKind::GotoWaypoint if self.area.len() != 1 => Err(ValidationError::Inconsistent {
                field: "area",
                rule: "goto_waypoint needs exactly one point",
            }),
            TaskKind::SurveyArea if self.area.len() < 3 => Err(ValidationError::Inconsistent {
                field: "area",
                rule: "survey_area needs a polygon of at least 3 points",
            }),
            TaskKind::SurveyArea if self_intersecting(&self.area) => {
                Err(ValidationError::Inconsistent {
                    field: "area",
                    rule: "the survey polygon's edges must not cross each other",
                })
            }
            TaskKind::SurveyArea if self.line_spacing_m < 1.0 => Err(ValidationError::OutOfRange {
                field: "line_spacing_m",
                value: self.line_spacing_m,
                min: 1.0,
                max: 10_000.0,
            }),
            TaskKind::SetReportingRate if self.rate_hz <= 0.0 => Err(ValidationError::OutOfRange {
                field: "rate_hz",
                value: self.rate_hz,
                min: f64::MIN_POSITIVE,
                max: 100.0,
            }),
            _ => Ok(()),
        }
    }
}

/// The life cycle of a task; the IDL enum `shoal::TaskState` in the same order.
///
/// `pending → sent → accepted → running → done | failed | aborted | expired`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TaskState {
    /// Registered at the station, not yet sent.
    Pending,
    /// Handed to a link.
    Sent,
    /// The vehicle accepted it.
    Accepted,
    /// The vehicle is executing it.
    Running,
    /// Finished successfully.
    Done,
    /// The vehicle could not do it.
    Failed,
    /// Cancelled by an operator or superseded by an abort.
    Aborted,
    /// Not confirmed before its deadline.
    Expired,
}

impl TaskState {
    /// True for the states a task never leaves.
    pub fn is_final(self) -> bool {
        matches!(
            self,
            Self::Done | Self::Failed | Self::Aborted | Self::Expired
        )
    }
}

/// A report on one task; DDS key `task_id`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TaskStatus {
    /// Task reported on.
    pub task_id: String,
    /// Vehicle reporting.
    pub vehicle_id: String,
    /// Time of the report, ms since the Unix epoch.
    pub timestamp_ms: i64,
    /// New state.
    pub state: TaskState,
    /// Progress in percent, [0, 100].
    pub progress_pct: f64,
    /// Free text, at most 512 bytes (e.g. why it failed).
    pub message: String,
}

impl Validate for TaskStatus {
    fn validate(&self) -> Result<(), ValidationError> {
        identifier("task_id", &self.task_id, MAX_ID_LEN)?;
        identifier("vehicle_id", &self.vehicle_id, MAX_VEHICLE_ID_LEN)?;
        timestamp("timestamp_ms", self.timestamp_ms)?;
        finite_in("progress_pct", self.progress_pct, 0.0, 100.0)?;
        text("message", &self.message, MAX_TEXT_LEN)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bow_tie_survey_polygon_is_refused_naming_the_area() {
        let p = |lat: f64, lon: f64| GeoPoint {
            latitude_deg: lat,
            longitude_deg: lon,
        };
        let survey = |polygon: Vec<GeoPoint>| {
            TaskAssignment::new(
                "t",
                "m",
                "v",
                1_800_000_000_000,
                &Task::SurveyArea {
                    polygon,
                    line_spacing_m: 20.0,
                    depth_m: Some(10.0),
                    altitude_m: None,
                    speed_mps: 1.5,
                },
            )
        };
        let bow_tie = survey(vec![p(0.0, 0.0), p(0.01, 0.01), p(0.0, 0.01), p(0.01, 0.0)]);
        let err = bow_tie.task().unwrap_err();
        assert_eq!(err.reason().to_string(), "inconsistent:area");
        let square = survey(vec![p(0.0, 0.0), p(0.0, 0.01), p(0.01, 0.01), p(0.01, 0.0)]);
        assert!(square.task().is_ok());
        let concave = survey(vec![
            p(0.0, 0.0),
            p(0.0, 0.02),
            p(0.01, 0.01),
            p(0.02, 0.02),
            p(0.02, 0.0),
        ]);
        assert!(concave.task().is_ok());
    }

    const T: i64 = 1_700_000_000_000;

    #[test]
    fn a_lease_holder_goes_with_a_term_and_is_an_identifier() {
        let ok = |term: u64, holder: &str| {
            let mut a = TaskAssignment::new("t", "", "v", T, &Task::Surface);
            a.lease_term = term;
            a.lease_holder = holder.into();
            a.validate().map_err(|e| e.reason().to_string())
        };
        assert_eq!(ok(0, ""), Ok(()));
        assert_eq!(ok(3, "shore"), Ok(()));
        assert_eq!(ok(3, ""), Err("inconsistent:lease_holder".into()));
        assert_eq!(ok(0, "shore"), Err("inconsistent:lease_holder".into()));
        assert!(ok(3, "sh ore").is_err());
        assert!(ok(3, &"s".repeat(MAX_LEASE_HOLDER_LEN + 1)).is_err());
    }

    #[test]
    fn leases_order_by_term_then_by_the_holder_name_that_sorts_first() {
        assert!(lease_supersedes(2, "ship", 1, "alpha"));
        assert!(lease_supersedes(2, "alpha", 2, "bravo"));
        assert!(!lease_supersedes(2, "bravo", 2, "alpha"));
        assert!(
            !lease_supersedes(2, "ship", 2, "ship"),
            "not newer than itself"
        );
        assert!(
            lease_supersedes(1, "ship", 0, ""),
            "any lease is newer than none"
        );
    }

    #[test]
    fn a_task_starts_only_before_its_expiry_or_within_the_age_limit_without_one() {
        let mut a = TaskAssignment::new("t", "", "v", T, &Task::Surface);
        // No expiry: the vehicle's own age limit decides, and without one any age goes.
        assert!(a.may_start(T + 59_000, Some(60_000)));
        assert!(!a.may_start(T + 61_000, Some(60_000)));
        assert!(a.may_start(T + 86_400_000, None));
        // An expiry overrides the age limit both ways.
        a.expires_ms = T + 10_000;
        assert!(a.validate().is_ok());
        assert!(a.may_start(T + 10_000, Some(1)));
        assert!(!a.may_start(T + 10_001, None));
        a.expires_ms = T - 1;
        assert_eq!(
            a.validate().unwrap_err().reason().to_string(),
            "inconsistent:expires_ms"
        );
        a.expires_ms = -5;
        assert!(a.validate().is_err());
    }

    fn p(lat: f64, lon: f64) -> GeoPoint {
        GeoPoint {
            latitude_deg: lat,
            longitude_deg: lon,
        }
    }

    #[test]
    fn typed_tasks_round_trip_through_the_wire_form() {
        let tasks = [
            Task::GotoWaypoint {
                target: p(1.0, 2.0),
                depth_m: Some(10.0),
                altitude_m: None,
                speed_mps: 1.5,
            },
            Task::SurveyArea {
                polygon: vec![p(0.0, 0.0), p(0.0, 0.01), p(0.01, 0.01)],
                line_spacing_m: 20.0,
                depth_m: None,
                altitude_m: Some(5.0),
                speed_mps: 1.0,
            },
            Task::Hold { duration_s: 60.0 },
            Task::Surface,
            Task::ReturnHome,
            Task::Abort,
            Task::RequestState,
            Task::SetReportingRate { rate_hz: 2.0 },
        ];
        for t in tasks {
            let a = TaskAssignment::new("t1", "m1", "auv-1", T, &t);
            assert_eq!(a.task(), Ok(t));
        }
    }

    #[test]
    fn goto_with_two_points_is_inconsistent() {
        let mut a = TaskAssignment::new(
            "t1",
            "",
            "auv-1",
            T,
            &Task::GotoWaypoint {
                target: p(1.0, 2.0),
                depth_m: Some(1.0),
                altitude_m: None,
                speed_mps: 1.0,
            },
        );
        a.area.push(p(1.0, 2.0));
        assert_eq!(
            a.task().unwrap_err().reason().to_string(),
            "inconsistent:area"
        );
    }

    #[test]
    fn goto_with_both_depth_and_altitude_is_inconsistent() {
        let a = TaskAssignment::new(
            "t1",
            "",
            "auv-1",
            T,
            &Task::GotoWaypoint {
                target: p(1.0, 2.0),
                depth_m: Some(1.0),
                altitude_m: Some(2.0),
                speed_mps: 1.0,
            },
        );
        assert!(a.validate().is_err());
    }

    #[test]
    fn final_states_are_final() {
        assert!(TaskState::Done.is_final() && !TaskState::Running.is_final());
    }
}
