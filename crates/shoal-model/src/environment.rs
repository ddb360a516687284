//! Environment observations (temperature, salinity, currents, ...).

use serde::{Deserialize, Serialize};

use crate::validate::{finite_in, identifier, text, timestamp};
use crate::{MAX_NAME_LEN, MAX_VEHICLE_ID_LEN, StateVector, Validate, ValidationError};

/// One measured environment property; DDS key (`vehicle_id`, `property`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EnvironmentObservation {
    /// Vehicle that measured it.
    pub vehicle_id: String,
    /// Observed property, e.g. `sea_water_temperature` (CF standard names are preferred).
    pub property: String,
    /// Time of the measurement, ms since the Unix epoch.
    pub timestamp_ms: i64,
    /// The measured value, finite, in `unit`.
    pub value: f64,
    /// Unit of `value` (UCUM code, e.g. `Cel`, `[ppth]`, `m/s`), at most 16 bytes.
    pub unit: String,
    /// Where: WGS84 latitude in degrees, [-90, 90].
    pub latitude_deg: f64,
    /// Where: WGS84 longitude in degrees, [-180, 180].
    pub longitude_deg: f64,
    /// Where: depth in metres, [0, 11000].
    pub depth_m: f64,
}

impl Validate for EnvironmentObservation {
    fn validate(&self) -> Result<(), ValidationError> {
        identifier("vehicle_id", &self.vehicle_id, MAX_VEHICLE_ID_LEN)?;
        identifier("property", &self.property, MAX_NAME_LEN)?;
        timestamp("timestamp_ms", self.timestamp_ms)?;
        finite_in("value", self.value, f64::MIN, f64::MAX)?;
        text("unit", &self.unit, 16)?;
        let (lat, lon, depth) = (
            StateVector::LATITUDE,
            StateVector::LONGITUDE,
            StateVector::DEPTH,
        );
        finite_in("latitude_deg", self.latitude_deg, lat.0, lat.1)?;
        finite_in("longitude_deg", self.longitude_deg, lon.0, lon.1)?;
        finite_in("depth_m", self.depth_m, depth.0, depth.1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn infinite_value_is_rejected() {
        let o = EnvironmentObservation {
            vehicle_id: "auv-1".into(),
            property: "sea_water_temperature".into(),
            timestamp_ms: 1_700_000_000_000,
            value: f64::INFINITY,
            unit: "Cel".into(),
            latitude_deg: 0.0,
            longitude_deg: 0.0,
            depth_m: 5.0,
        };
        assert_eq!(
            o.validate().unwrap_err().reason().to_string(),
            "not_finite:value"
        );
    }
}
