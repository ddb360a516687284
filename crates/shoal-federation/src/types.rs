//! What crosses between sites, as this crate's own types: a vehicle's position for the
//! fleet picture and a task's transition. Alarms cross as `shoal_model::Event`s.
//!
//! These are smaller than the local topics on purpose: a shore operator needs where a
//! vehicle is, how fast it goes and how much battery it has, not its pitch and roll, and
//! every byte crosses a link paid by the byte.

use shoal_model::{
    MAX_ID_LEN, MAX_VEHICLE_ID_LEN, StateVector, TaskState, TaskStatus, Validate, ValidationError,
    VehicleKind, is_identifier,
};

/// Longest site name, in bytes.
pub const MAX_SITE_LEN: usize = 32;

/// True when `name` can name a site: 1..=32 of `[A-Za-z0-9_.-]`, so it is always exactly
/// one chunk of a Zenoh key expression (no `/`, `*`, `$`, `?` or `#`).
pub fn is_site_name(name: &str) -> bool {
    is_identifier(name, MAX_SITE_LEN) && name != "." && name != ".."
}

/// A vehicle's position as the federation carries it; built from the local state vector.
#[derive(Debug, Clone, PartialEq)]
pub struct VehiclePosition {
    /// Vehicle identifier (from the key expression on the wire).
    pub vehicle_id: String,
    /// The kind of platform.
    pub kind: VehicleKind,
    /// Time of the fix, ms since the Unix epoch.
    pub timestamp_ms: i64,
    /// WGS84 latitude, degrees, [-90, 90].
    pub latitude_deg: f64,
    /// WGS84 longitude, degrees, [-180, 180].
    pub longitude_deg: f64,
    /// Depth, metres, [0, 11000].
    pub depth_m: f64,
    /// Heading, degrees clockwise from true north, [0, 360).
    pub heading_deg: f64,
    /// Speed over ground, m/s, [0, 30].
    pub speed_mps: f64,
    /// Remaining battery, percent, [0, 100].
    pub battery_pct: f64,
}

impl VehiclePosition {
    /// The federated view of a local state vector.
    pub fn from_state(kind: VehicleKind, state: &StateVector) -> Self {
        Self {
            vehicle_id: state.vehicle_id.clone(),
            kind,
            timestamp_ms: state.timestamp_ms,
            latitude_deg: state.latitude_deg,
            longitude_deg: state.longitude_deg,
            depth_m: state.depth_m,
            heading_deg: state.yaw_deg,
            speed_mps: state.speed_mps,
            battery_pct: state.battery_pct,
        }
    }

    /// Checks every field against the ranges of `StateVector`, the one source of truth.
    pub fn validate(&self) -> Result<(), ValidationError> {
        // The state vector's own validation, with the fields a position does not carry
        // set to values that always pass.
        let state = StateVector {
            vehicle_id: self.vehicle_id.clone(),
            timestamp_ms: self.timestamp_ms,
            latitude_deg: self.latitude_deg,
            longitude_deg: self.longitude_deg,
            depth_m: self.depth_m,
            altitude_m: shoal_model::UNKNOWN,
            speed_mps: self.speed_mps,
            yaw_deg: self.heading_deg,
            pitch_deg: 0.0,
            roll_deg: 0.0,
            battery_pct: self.battery_pct,
        };
        Validate::validate(&state).map_err(|e| match e {
            // Named as this type names it, so a refusal counter says what was wrong.
            ValidationError::OutOfRange {
                field: "yaw_deg",
                value,
                min,
                max,
            } => ValidationError::OutOfRange {
                field: "heading_deg",
                value,
                min,
                max,
            },
            ValidationError::NotFinite { field: "yaw_deg" } => ValidationError::NotFinite {
                field: "heading_deg",
            },
            other => other,
        })
    }
}

/// A task changing state, as the federation carries it (reliably, with catch-up).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TaskTransition {
    /// Task identifier.
    pub task_id: String,
    /// Mission the task belongs to, or empty.
    pub mission_id: String,
    /// Vehicle doing the task.
    pub vehicle_id: String,
    /// The state entered.
    pub state: TaskState,
    /// When it was entered, ms since the Unix epoch.
    pub timestamp_ms: i64,
}

impl TaskTransition {
    /// The transition a vehicle's task status reports; the station knows the mission.
    pub fn from_status(status: &TaskStatus, mission_id: &str) -> Self {
        Self {
            task_id: status.task_id.clone(),
            mission_id: mission_id.to_string(),
            vehicle_id: status.vehicle_id.clone(),
            state: status.state,
            timestamp_ms: status.timestamp_ms,
        }
    }

    /// Checks the identifiers and the timestamp with the model's rules.
    pub fn validate(&self) -> Result<(), ValidationError> {
        // TaskStatus carries the same identifiers and timestamp; reuse its checks.
        Validate::validate(&TaskStatus {
            task_id: self.task_id.clone(),
            vehicle_id: self.vehicle_id.clone(),
            timestamp_ms: self.timestamp_ms,
            state: self.state,
            progress_pct: 0.0,
            message: String::new(),
        })?;
        if !self.mission_id.is_empty() && !is_identifier(&self.mission_id, MAX_ID_LEN) {
            return Err(ValidationError::BadText {
                field: "mission_id",
                rule: "must be 1..=64 of [A-Za-z0-9_.-] or empty",
            });
        }
        Ok(())
    }
}

/// Longest vehicle identifier a key expression may carry (the model's limit).
pub(crate) const MAX_VEHICLE_ID: usize = MAX_VEHICLE_ID_LEN;

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A plausible position off Toulon.
    pub(crate) fn position(id: &str) -> VehiclePosition {
        VehiclePosition {
            vehicle_id: id.into(),
            kind: VehicleKind::Auv,
            timestamp_ms: 1_700_000_000_000,
            latitude_deg: 43.1,
            longitude_deg: 5.9,
            depth_m: 12.4,
            heading_deg: 271.5,
            speed_mps: 1.5,
            battery_pct: 80.0,
        }
    }

    #[test]
    fn site_names_are_single_key_chunks() {
        for ok in ["ship-1", "shore", "a.b_c"] {
            assert!(is_site_name(ok), "{ok}");
        }
        for bad in ["", "a/b", "*", "$*", "a b", "..", &"x".repeat(33)] {
            assert!(!is_site_name(bad), "{bad:?}");
        }
    }

    #[test]
    fn a_position_out_of_range_names_its_field() {
        let mut p = position("auv-1");
        p.heading_deg = 360.0;
        assert_eq!(p.validate().unwrap_err().reason().field, "heading_deg");
        assert_eq!(position("auv-1").validate(), Ok(()));
    }

    #[test]
    fn a_transition_with_a_bad_mission_is_refused() {
        let t = TaskTransition {
            task_id: "t1".into(),
            mission_id: "m 1".into(),
            vehicle_id: "auv-1".into(),
            state: TaskState::Running,
            timestamp_ms: 1_700_000_000_000,
        };
        assert_eq!(t.validate().unwrap_err().reason().field, "mission_id");
    }
}
