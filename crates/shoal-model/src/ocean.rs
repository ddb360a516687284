//! A smooth, deterministic ocean for simulated vehicles to sample: temperature, salinity
//! and current as functions of position and depth, shaped by an [`OceanField`] a scenario
//! file may set.
//!
//! Not an ocean model; just plausible structure so that maps and rules have something to
//! show: a large-scale surface temperature falling with latitude (or a fixed one), mesoscale
//! "eddies" a few kilometres across (so a survey sees horizontal gradients), a thermocline
//! and halocline in the upper tens of metres, a current that weakens with depth, and local
//! [`Plume`]s (a river's fresh water, a warm outfall) that a survey can find.

use std::f64::consts::TAU;

use serde::{Deserialize, Serialize};

use crate::{EnvironmentObservation, GeoPoint};

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

/// A local anomaly: warmer or colder, fresher or saltier water around a point, fading
/// with distance (a Gaussian of `radius_m`) and with depth away from `depth_m` (a Gaussian
/// of `thickness_m`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Plume {
    /// Centre, degrees.
    pub latitude_deg: f64,
    /// Centre, degrees.
    pub longitude_deg: f64,
    /// Horizontal scale, m: the anomaly is down to 37 % this far from the centre.
    pub radius_m: f64,
    /// Depth of its core, m (0: at the surface, as fresh river water floats).
    #[serde(default)]
    pub depth_m: f64,
    /// Vertical scale, m.
    #[serde(default = "default_thickness")]
    pub thickness_m: f64,
    /// Temperature anomaly at the core, °C (negative: colder).
    #[serde(default)]
    pub temperature_c: f64,
    /// Salinity anomaly at the core, PSU (negative: fresher).
    #[serde(default)]
    pub salinity_psu: f64,
}

fn default_thickness() -> f64 {
    10.0
}

/// The shape of the simulated ocean. The default is the one every simulated vehicle
/// samples unless told otherwise.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OceanField {
    /// Surface temperature away from eddies and plumes, °C; `None`: falling with latitude
    /// from 27 °C at the equator (0.3 °C a degree).
    pub surface_temperature_c: Option<f64>,
    /// How much the eddies warm or cool the surface, °C.
    pub eddy_temperature_c: f64,
    /// Depth scale of the thermocline, m: the water is two thirds of the way from the
    /// surface temperature to the deep one this deep.
    pub thermocline_m: f64,
    /// Surface salinity away from eddies and plumes, PSU (deep water is 35).
    pub surface_salinity_psu: f64,
    /// Surface current away from eddies, m/s.
    pub current_mps: f64,
    /// Direction the current flows towards away from eddies, degrees from north.
    pub current_to_deg: f64,
    /// Local anomalies.
    pub plumes: Vec<Plume>,
}

impl Default for OceanField {
    fn default() -> Self {
        Self {
            surface_temperature_c: None,
            eddy_temperature_c: 0.6,
            thermocline_m: 30.0,
            surface_salinity_psu: 34.2,
            current_mps: 0.25,
            current_to_deg: 45.0,
            plumes: Vec::new(),
        }
    }
}

/// The water at a position and depth (metres, clamped to [0, 11000]) in the default ocean.
pub fn water_at(p: GeoPoint, depth_m: f64) -> Water {
    OceanField::default().water_at(p, depth_m)
}

impl OceanField {
    /// The water at a position and depth (metres, clamped to [0, 11000]).
    pub fn water_at(&self, p: GeoPoint, depth_m: f64) -> Water {
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

        let base_t = self.surface_temperature_c.unwrap_or(27.0 - 0.3 * lat.abs());
        let surface_t = base_t + self.eddy_temperature_c * eddy;
        let deep_t = 3.0 + 0.2 * surface_t;
        let thermocline = self.thermocline_m.max(1.0);
        let mut temperature_c = deep_t + (surface_t - deep_t) * (-z / thermocline).exp();

        let surface_s = self.surface_salinity_psu + 0.3 * eddy2;
        let mut salinity_psu = 35.0 + (surface_s - 35.0) * (-z / (thermocline * 4.0 / 3.0)).exp();

        for plume in &self.plumes {
            let g = plume.weight(p, z);
            temperature_c += plume.temperature_c * g;
            salinity_psu += plume.salinity_psu * g;
        }

        let surface_current = self.current_mps + 0.6 * self.current_mps * eddy2;
        let current_mps = surface_current.max(0.0) * (-z / 60.0).exp() + 0.02;
        let current_to_deg = (self.current_to_deg + 60.0 * eddy).rem_euclid(360.0);
        Water {
            temperature_c: temperature_c.clamp(-1.9, 35.0),
            salinity_psu: salinity_psu.clamp(0.0, 42.0),
            current_mps,
            current_to_deg,
        }
    }
}

impl Plume {
    /// How much of the anomaly reaches a point, [0, 1].
    fn weight(&self, p: GeoPoint, depth_m: f64) -> f64 {
        let d = crate::geo::distance_m(
            self.latitude_deg,
            self.longitude_deg,
            p.latitude_deg,
            p.longitude_deg,
        );
        let r = self.radius_m.max(1.0);
        let dz = (depth_m - self.depth_m) / self.thickness_m.max(0.1);
        (-(d / r).powi(2) - dz * dz).exp()
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
    use crate::Validate;

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

    #[test]
    fn the_default_field_is_the_simulators_ocean_of_before() {
        // Values of the formula before it took an OceanField, at a few points.
        let here = p(63.465, 10.37);
        let w = water_at(here, 10.0);
        let f = OceanField::default().water_at(here, 10.0);
        assert_eq!(w, f);
        let lat: f64 = 63.465;
        let x = 10.37 * 111.32 * lat.to_radians().cos();
        let y = lat * 110.57;
        let eddy = (TAU * x / 6.0).sin() * (TAU * y / 9.0).cos();
        let surface_t = 27.0 - 0.3 * lat + 0.6 * eddy;
        let deep_t = 3.0 + 0.2 * surface_t;
        let t = deep_t + (surface_t - deep_t) * (-10.0_f64 / 30.0).exp();
        assert!((w.temperature_c - t).abs() < 1e-12, "{w:?} {t}");
    }

    #[test]
    fn a_plume_shows_at_its_core_and_fades_away_from_it() {
        let centre = p(63.44, 10.40);
        let field = OceanField {
            surface_temperature_c: Some(8.0),
            plumes: vec![Plume {
                latitude_deg: centre.latitude_deg,
                longitude_deg: centre.longitude_deg,
                radius_m: 300.0,
                depth_m: 0.0,
                thickness_m: 5.0,
                temperature_c: 4.0,
                salinity_psu: -10.0,
            }],
            ..OceanField::default()
        };
        let plain = OceanField {
            plumes: Vec::new(),
            ..field
        };
        let core = field.water_at(centre, 0.0);
        let without = plain.water_at(centre, 0.0);
        assert!((core.temperature_c - without.temperature_c - 4.0).abs() < 1e-9);
        assert!((core.salinity_psu - without.salinity_psu + 10.0).abs() < 1e-9);
        // 300 m away: exp(-1) of it; 2 km away or 20 m down: nothing to speak of.
        let east = p(
            63.44,
            10.40 + 300.0 / (111_320.0 * 63.44_f64.to_radians().cos()),
        );
        let d = field.water_at(east, 0.0).temperature_c - plain.water_at(east, 0.0).temperature_c;
        assert!((d - 4.0 * (-1.0_f64).exp()).abs() < 0.05, "{d}");
        let far = p(63.458, 10.40);
        assert!(
            (field.water_at(far, 0.0).temperature_c - plain.water_at(far, 0.0).temperature_c).abs()
                < 1e-6
        );
        let deep =
            field.water_at(centre, 20.0).temperature_c - plain.water_at(centre, 20.0).temperature_c;
        assert!(deep.abs() < 1e-6, "{deep}");
        // A fixed surface temperature replaces the latitude's.
        assert!((plain.water_at(far, 0.0).temperature_c - 8.0).abs() <= 0.6 + 1e-9);
    }
}
