//! A smooth, deterministic ocean for the simulator to sample: temperature, salinity and
//! current as functions of position and depth.
//!
//! Not an ocean model; just plausible structure so that maps and rules have something to
//! show: a large-scale surface temperature falling with latitude, mesoscale "eddies" a few
//! kilometres across (so a survey sees horizontal gradients), a thermocline and halocline
//! in the upper tens of metres, and a current that weakens with depth.

use std::f64::consts::TAU;

use shoal_model::{EnvironmentObservation, GeoPoint};

/// CF standard name of sea water temperature.
pub const TEMPERATURE: &str = "sea_water_temperature";
/// CF standard name of sea water (practical) salinity.
pub const SALINITY: &str = "sea_water_salinity";
/// CF standard name of the current's speed.
pub const CURRENT_SPEED: &str = "sea_water_speed";
/// CF standard name of the direction the current flows towards.
pub const CURRENT_DIRECTION: &str = "sea_water_to_direction";

/// UCUM units of the properties above, as the acoustic compact encoding expects them.
/// Practical salinity is dimensionless; `[ppth]` (‰) is numerically the same as PSU.
pub const UNITS: [(&str, &str); 4] = [
    (TEMPERATURE, "Cel"),
    (SALINITY, "[ppth]"),
    (CURRENT_SPEED, "m/s"),
    (CURRENT_DIRECTION, "deg"),
];

/// The water at one point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Water {
    /// Temperature, °C.
    pub temperature_c: f64,
    /// Practical salinity, PSU.
    pub salinity_psu: f64,
    /// Current speed, m/s.
    pub current_mps: f64,
    /// Direction the current flows towards, degrees clockwise from north, [0, 360).
    pub current_to_deg: f64,
}

/// The water at a position and depth (metres, clamped to [0, 11000]).
pub fn water_at(p: GeoPoint, depth_m: f64) -> Water {
    let z = if depth_m.is_finite() {
        depth_m.clamp(0.0, 11_000.0)
    } else {
        0.0
    };
    let lat = p.latitude_deg.clamp(-90.0, 90.0);
    // Kilometres east and north on a global grid, so the field is continuous everywhere
    // (not relative to where a vehicle started).
    let x = p.longitude_deg * 111.32 * lat.to_radians().cos();
    let y = lat * 110.57;
    let eddy = (TAU * x / 6.0).sin() * (TAU * y / 9.0).cos();
    let eddy2 = (TAU * x / 8.0).cos() * (TAU * y / 5.0).sin();

    let surface_t = 27.0 - 0.3 * lat.abs() + 0.6 * eddy;
    let deep_t = 3.0 + 0.2 * surface_t;
    let temperature_c = (deep_t + (surface_t - deep_t) * (-z / 30.0).exp()).clamp(-1.9, 35.0);

    let surface_s = 34.2 + 0.3 * eddy2;
    let salinity_psu = 35.0 + (surface_s - 35.0) * (-z / 40.0).exp();

    let current_mps = (0.25 + 0.15 * eddy2) * (-z / 60.0).exp() + 0.02;
    let current_to_deg = (45.0 + 60.0 * eddy).rem_euclid(360.0);
    Water {
        temperature_c,
        salinity_psu,
        current_mps,
        current_to_deg,
    }
}

impl Water {
    /// The four observations of this water, made by `vehicle_id` at a place and time.
    pub fn observations(
        &self,
        vehicle_id: &str,
        timestamp_ms: i64,
        at: GeoPoint,
        depth_m: f64,
    ) -> Vec<EnvironmentObservation> {
        let values = [
            self.temperature_c,
            self.salinity_psu,
            self.current_mps,
            self.current_to_deg,
        ];
        UNITS
            .iter()
            .zip(values)
            .map(|((property, unit), value)| EnvironmentObservation {
                vehicle_id: vehicle_id.to_string(),
                property: (*property).to_string(),
                timestamp_ms,
                value,
                unit: (*unit).to_string(),
                latitude_deg: at.latitude_deg,
                longitude_deg: at.longitude_deg,
                depth_m,
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shoal_model::Validate;

    fn p(lat: f64, lon: f64) -> GeoPoint {
        GeoPoint {
            latitude_deg: lat,
            longitude_deg: lon,
        }
    }

    #[test]
    fn values_are_oceanic_everywhere() {
        for lat in (-90..=90).step_by(5) {
            for lon in (-180..=180).step_by(15) {
                for depth in [0.0, 5.0, 50.0, 300.0, 4000.0, 11_000.0] {
                    let w = water_at(p(f64::from(lat), f64::from(lon)), depth);
                    assert!((-2.0..=35.0).contains(&w.temperature_c), "{w:?}");
                    assert!((33.0..=36.0).contains(&w.salinity_psu), "{w:?}");
                    assert!((0.0..=1.0).contains(&w.current_mps), "{w:?}");
                    assert!((0.0..360.0).contains(&w.current_to_deg), "{w:?}");
                }
            }
        }
    }

    #[test]
    fn temperature_falls_with_depth_and_salinity_rises_at_mid_latitudes() {
        let here = p(43.0, 5.9);
        let profile: Vec<Water> = (0..20)
            .map(|i| water_at(here, f64::from(i) * 10.0))
            .collect();
        for w in profile.windows(2) {
            assert!(w[1].temperature_c < w[0].temperature_c, "{w:?}");
            assert!(w[1].salinity_psu > w[0].salinity_psu, "{w:?}");
            assert!(w[1].current_mps < w[0].current_mps, "{w:?}");
        }
        // A thermocline: several degrees between the surface and 100 m.
        let drop = profile[0].temperature_c - profile[10].temperature_c;
        assert!((4.0..12.0).contains(&drop), "{drop}");
    }

    #[test]
    fn a_survey_sized_area_shows_horizontal_gradients_but_no_jumps() {
        let a = water_at(p(63.465, 10.37), 10.0);
        let b = water_at(p(63.465, 10.40), 10.0); // 1.5 km east
        assert!(
            (a.temperature_c - b.temperature_c).abs() > 0.05,
            "{a:?} {b:?}"
        );
        // 10 m apart: smooth.
        let c = water_at(p(63.465, 10.3702), 10.0);
        assert!(
            (a.temperature_c - c.temperature_c).abs() < 0.02,
            "{a:?} {c:?}"
        );
    }

    #[test]
    fn observations_carry_cf_names_and_ucum_units_and_validate() {
        let at = p(63.465, 10.37);
        let obs = water_at(at, 20.0).observations("auv-1", 1_700_000_000_000, at, 20.0);
        assert_eq!(obs.len(), 4);
        for o in &obs {
            assert_eq!(o.validate(), Ok(()), "{o:?}");
        }
        let names: Vec<_> = obs
            .iter()
            .map(|o| (o.property.as_str(), o.unit.as_str()))
            .collect();
        assert_eq!(names, UNITS);
        // Garbage depth does not make garbage values.
        let w = water_at(at, f64::NAN);
        assert!(w.temperature_c.is_finite() && w.salinity_psu.is_finite());
    }
}
