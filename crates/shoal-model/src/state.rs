//! The SWARMs State Vector.

use serde::{Deserialize, Serialize};

use crate::validate::{finite_in, identifier, optional_in, timestamp};
use crate::{MAX_VEHICLE_ID_LEN, Validate, ValidationError};

/// A vehicle's navigation and battery report (SWARMs "State Vector"); DDS key `vehicle_id`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StateVector {
    /// Vehicle identifier: 1..=32 of `[A-Za-z0-9_.-]`.
    pub vehicle_id: String,
    /// Time of the fix, ms since the Unix epoch (UTC), 2000..2100.
    pub timestamp_ms: i64,
    /// WGS84 latitude in degrees, [-90, 90].
    pub latitude_deg: f64,
    /// WGS84 longitude in degrees, [-180, 180].
    pub longitude_deg: f64,
    /// Depth below the surface in metres, [0, 11000] (0 at the surface).
    pub depth_m: f64,
    /// Altitude above the seabed in metres, [0, 10000], or -1 when not measured.
    pub altitude_m: f64,
    /// Speed over ground in m/s, [0, 30].
    pub speed_mps: f64,
    /// Heading (yaw) in degrees clockwise from true north, [0, 360).
    pub yaw_deg: f64,
    /// Pitch in degrees, nose up positive, [-90, 90].
    pub pitch_deg: f64,
    /// Roll in degrees, starboard down positive, [-180, 180].
    pub roll_deg: f64,
    /// Remaining battery charge in percent, [0, 100].
    pub battery_pct: f64,
}

impl StateVector {
    /// Valid latitude range, degrees.
    pub const LATITUDE: (f64, f64) = (-90.0, 90.0);
    /// Valid longitude range, degrees.
    pub const LONGITUDE: (f64, f64) = (-180.0, 180.0);
    /// Valid depth range, metres.
    pub const DEPTH: (f64, f64) = (0.0, 11_000.0);
    /// Valid altitude range, metres (or [`crate::UNKNOWN`]).
    pub const ALTITUDE: (f64, f64) = (0.0, 10_000.0);
    /// Valid speed range, m/s.
    pub const SPEED: (f64, f64) = (0.0, 30.0);
    /// Valid yaw range, degrees (360 itself is normalised to 0 by senders).
    pub const YAW: (f64, f64) = (0.0, 360.0);
    /// Valid pitch range, degrees.
    pub const PITCH: (f64, f64) = (-90.0, 90.0);
    /// Valid roll range, degrees.
    pub const ROLL: (f64, f64) = (-180.0, 180.0);
    /// Valid battery range, percent.
    pub const BATTERY: (f64, f64) = (0.0, 100.0);
}

impl Validate for StateVector {
    fn validate(&self) -> Result<(), ValidationError> {
        identifier("vehicle_id", &self.vehicle_id, MAX_VEHICLE_ID_LEN)?;
        timestamp("timestamp_ms", self.timestamp_ms)?;
        finite_in(
            "latitude_deg",
            self.latitude_deg,
            Self::LATITUDE.0,
            Self::LATITUDE.1,
        )?;
        finite_in(
            "longitude_deg",
            self.longitude_deg,
            Self::LONGITUDE.0,
            Self::LONGITUDE.1,
        )?;
        finite_in("depth_m", self.depth_m, Self::DEPTH.0, Self::DEPTH.1)?;
        optional_in(
            "altitude_m",
            self.altitude_m,
            Self::ALTITUDE.0,
            Self::ALTITUDE.1,
        )?;
        finite_in("speed_mps", self.speed_mps, Self::SPEED.0, Self::SPEED.1)?;
        finite_in("yaw_deg", self.yaw_deg, Self::YAW.0, Self::YAW.1)?;
        if self.yaw_deg >= 360.0 {
            return Err(ValidationError::OutOfRange {
                field: "yaw_deg",
                value: self.yaw_deg,
                min: 0.0,
                max: 360.0,
            });
        }
        finite_in("pitch_deg", self.pitch_deg, Self::PITCH.0, Self::PITCH.1)?;
        finite_in("roll_deg", self.roll_deg, Self::ROLL.0, Self::ROLL.1)?;
        finite_in(
            "battery_pct",
            self.battery_pct,
            Self::BATTERY.0,
            Self::BATTERY.1,
        )?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    pub(crate) fn sample() -> StateVector {
        StateVector {
            vehicle_id: "auv-1".into(),
            timestamp_ms: 1_700_000_000_000,
            latitude_deg: 43.1,
            longitude_deg: 5.9,
            depth_m: 12.5,
            altitude_m: crate::UNKNOWN,
            speed_mps: 1.5,
            yaw_deg: 359.9,
            pitch_deg: -3.0,
            roll_deg: 1.0,
            battery_pct: 80.0,
        }
    }

    #[test]
    fn a_plausible_state_vector_is_valid() {
        assert_eq!(sample().validate(), Ok(()));
    }

    #[test]
    fn nan_is_rejected_with_the_field_named() {
        let mut s = sample();
        s.depth_m = f64::NAN;
        let e = s.validate().unwrap_err();
        assert_eq!(e.reason().to_string(), "not_finite:depth_m");
    }

    #[test]
    fn yaw_of_exactly_360_is_rejected() {
        let mut s = sample();
        s.yaw_deg = 360.0;
        assert_eq!(s.validate().unwrap_err().reason().field, "yaw_deg");
    }

    #[test]
    fn bad_vehicle_ids_are_rejected() {
        for id in ["", "a b", "x'; DROP TABLE", &"x".repeat(33)] {
            let mut s = sample();
            s.vehicle_id = id.to_string();
            assert!(s.validate().is_err(), "{id:?} should be rejected");
        }
    }

    proptest! {
        #[test]
        fn latitude_outside_range_is_always_rejected(lat in prop_oneof![-1e9..-90.000_001f64, 90.000_001..1e9f64]) {
            let mut s = sample();
            s.latitude_deg = lat;
            prop_assert_eq!(s.validate().unwrap_err().reason().to_string(), "out_of_range:latitude_deg");
        }

        #[test]
        fn any_in_range_vector_is_valid(
            lat in -90.0..=90.0f64, lon in -180.0..=180.0f64, depth in 0.0..=11_000.0f64,
            yaw in 0.0..360.0f64, battery in 0.0..=100.0f64,
        ) {
            let s = StateVector { latitude_deg: lat, longitude_deg: lon, depth_m: depth, yaw_deg: yaw, battery_pct: battery, ..sample() };
            prop_assert_eq!(s.validate(), Ok(()));
        }
    }
}
