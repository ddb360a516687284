//! IMC's units and frames into Shoal's: radians to degrees, a reference position plus
//! north/east offsets to a geodetic position, and Shoal tasks into IMC maneuvers.

use shoal_model::{GeoPoint, StateVector, UNKNOWN};

use super::codec::{EstimatedState, Goto, StationKeeping, units};

/// WGS84 semi-major axis, metres.
const WGS84_A: f64 = 6_378_137.0;
/// WGS84 first eccentricity squared.
const WGS84_E2: f64 = 6.694_379_990_14e-3;

/// The geodetic position (degrees) of a point `north` and `east` metres from a reference
/// given in radians, as DUNE displaces `EstimatedState`'s reference by `x` and `y`.
///
/// Uses the WGS84 meridional and prime-vertical radii of curvature at the reference: for
/// the offsets DUNE produces (it moves the reference when they grow past a few hundred
/// metres) this is within millimetres of an exact ECEF computation.
pub fn displace(lat_rad: f64, lon_rad: f64, north_m: f64, east_m: f64) -> (f64, f64) {
    let s = lat_rad.sin();
    let w = 1.0 - WGS84_E2 * s * s;
    let prime_vertical = WGS84_A / w.sqrt();
    let meridional = WGS84_A * (1.0 - WGS84_E2) / (w * w.sqrt());
    let lat = lat_rad + north_m / meridional;
    let lon = lon_rad + east_m / (prime_vertical * lat_rad.cos());
    (lat.to_degrees(), wrap_lon_deg(lon.to_degrees()))
}

/// A longitude brought into [-180, 180].
fn wrap_lon_deg(lon: f64) -> f64 {
    if (-180.0..=180.0).contains(&lon) {
        lon
    } else {
        (lon + 180.0).rem_euclid(360.0) - 180.0
    }
}

/// A heading in radians as degrees in [0, 360).
pub fn heading_deg(rad: f64) -> f64 {
    let d = rad.to_degrees().rem_euclid(360.0);
    // rem_euclid can round up to exactly 360 for tiny negative inputs.
    if d >= 360.0 { 0.0 } else { d }
}

/// The navigation part of a state vector from an `EstimatedState` (vehicle id, time and
/// battery are the caller's). Not validated: the caller validates the whole vector.
pub fn state_from(es: &EstimatedState, vehicle_id: &str, timestamp_ms: i64) -> StateVector {
    let (lat, lon) = displace(es.lat, es.lon, f64::from(es.x), f64::from(es.y));
    let alt = f64::from(es.alt);
    StateVector {
        vehicle_id: vehicle_id.to_string(),
        timestamp_ms,
        latitude_deg: lat,
        longitude_deg: lon,
        // DUNE reports a few centimetres of negative depth at the surface (waves, sensor
        // offset); that is the surface, not bad data.
        depth_m: f64::from(es.depth).max(0.0),
        // DUNE sends -1 when no altimeter reading is valid.
        altitude_m: if alt < 0.0 { UNKNOWN } else { alt },
        speed_mps: f64::from(es.vx).hypot(f64::from(es.vy)),
        yaw_deg: heading_deg(f64::from(es.psi)),
        pitch_deg: f64::from(es.theta).to_degrees(),
        roll_deg: f64::from(es.phi).to_degrees(),
        battery_pct: 0.0,
    }
}

/// The z reference and units of a Shoal depth-or-altitude target.
pub fn z_of(depth_m: Option<f64>, altitude_m: Option<f64>) -> (f32, u8) {
    match (depth_m, altitude_m) {
        (_, Some(alt)) => (to_f32(alt), units::Z_ALTITUDE),
        (Some(depth), None) => (to_f32(depth), units::Z_DEPTH),
        (None, None) => (0.0, units::Z_DEPTH),
    }
}

/// An f64 that is already range-checked (a model value) as IMC's fp32.
#[allow(clippy::cast_possible_truncation)]
pub fn to_f32(v: f64) -> f32 {
    v as f32
}

/// A `Goto` maneuver to a point.
pub fn goto(target: GeoPoint, z: (f32, u8), speed_mps: f64, timeout_s: u16) -> Goto {
    Goto {
        timeout: timeout_s,
        lat: target.latitude_deg.to_radians(),
        lon: target.longitude_deg.to_radians(),
        z: z.0,
        z_units: z.1,
        speed: to_f32(speed_mps),
        speed_units: units::SPEED_MPS,
        // -1: no attitude constraint.
        roll: -1.0,
        pitch: -1.0,
        yaw: -1.0,
        custom: String::new(),
    }
}

/// A `StationKeeping` maneuver at a point.
pub fn station_keeping(
    at: GeoPoint,
    depth_m: f64,
    radius_m: f64,
    duration_s: f64,
    speed_mps: f64,
) -> StationKeeping {
    StationKeeping {
        lat: at.latitude_deg.to_radians(),
        lon: at.longitude_deg.to_radians(),
        z: to_f32(depth_m),
        z_units: units::Z_DEPTH,
        radius: to_f32(radius_m),
        duration: seconds_u16(duration_s),
        speed: to_f32(speed_mps),
        speed_units: units::SPEED_MPS,
        custom: String::new(),
    }
}

/// Seconds as IMC's u16, saturating (a model duration is at most a day, above 65535 s).
#[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
pub fn seconds_u16(s: f64) -> u16 {
    if s.is_nan() {
        0
    } else {
        s.round().clamp(0.0, f64::from(u16::MAX)) as u16
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shoal_model::Validate;

    #[test]
    fn offsets_north_and_east_move_the_reference() {
        let (lat0, lon0) = (41.18_f64.to_radians(), (-8.70_f64).to_radians());
        let (lat, lon) = displace(lat0, lon0, 0.0, 0.0);
        assert!((lat - 41.18).abs() < 1e-12 && (lon + 8.70).abs() < 1e-12);
        // 1000 m north at 41° N is 0.009 004° of latitude (meridional radius 6 363 km).
        let (lat, lon) = displace(lat0, lon0, 1000.0, 0.0);
        assert!((lat - 41.18 - 0.009_004).abs() < 2e-5, "{lat}");
        assert!((lon + 8.70).abs() < 1e-12);
        // 1000 m east is more longitude than latitude, by 1/cos(lat).
        let (lat, lon) = displace(lat0, lon0, 0.0, 1000.0);
        assert!((lat - 41.18).abs() < 1e-12);
        let dlon = lon + 8.70;
        assert!((dlon - 0.011_93).abs() < 5e-5, "{dlon}");
        // Negative offsets go south and west.
        let (lat, lon) = displace(lat0, lon0, -500.0, -500.0);
        assert!(lat < 41.18 && lon < -8.70);
    }

    #[test]
    fn headings_are_brought_into_0_360() {
        assert!((heading_deg(std::f64::consts::FRAC_PI_2) - 90.0).abs() < 1e-9);
        assert!((heading_deg(-std::f64::consts::FRAC_PI_2) - 270.0).abs() < 1e-9);
        assert_eq!(heading_deg(0.0), 0.0);
        assert_eq!(heading_deg(-1e-18), 0.0);
        assert!((heading_deg(7.0 * std::f64::consts::PI) - 180.0).abs() < 1e-9);
    }

    #[test]
    fn an_estimated_state_becomes_a_valid_state_vector_in_degrees() {
        let es = EstimatedState {
            lat: 41.18_f64.to_radians(),
            lon: (-8.70_f64).to_radians(),
            x: 100.0,
            y: -50.0,
            depth: 12.5,
            alt: -1.0,
            phi: 0.1,
            theta: -0.05,
            psi: -0.5,
            vx: 1.2,
            vy: 0.5,
            ..EstimatedState::default()
        };
        let mut s = state_from(&es, "auv-1", 1_700_000_000_000);
        s.battery_pct = 80.0;
        assert_eq!(s.validate(), Ok(()));
        assert!(s.latitude_deg > 41.18 && s.longitude_deg < -8.70);
        assert_eq!(s.depth_m, 12.5);
        assert_eq!(s.altitude_m, UNKNOWN);
        assert!((s.speed_mps - 1.3).abs() < 1e-6);
        assert!(
            (s.yaw_deg - (360.0 - 28.647_889_756)).abs() < 1e-4,
            "{}",
            s.yaw_deg
        );
        assert!((s.roll_deg - 5.729_578).abs() < 1e-4);
        assert!((s.pitch_deg + 2.864_789).abs() < 1e-4);
    }

    #[test]
    fn a_slightly_negative_depth_is_the_surface() {
        let es = EstimatedState {
            depth: -0.05,
            alt: 20.0,
            ..EstimatedState::default()
        };
        let s = state_from(&es, "auv-1", 1_700_000_000_000);
        assert_eq!(s.depth_m, 0.0);
        assert_eq!(s.altitude_m, 20.0);
    }

    #[test]
    fn goto_targets_are_in_radians_with_units() {
        let g = goto(
            GeoPoint {
                latitude_deg: 41.0,
                longitude_deg: -8.0,
            },
            z_of(Some(10.0), None),
            1.5,
            600,
        );
        assert!((g.lat - 0.715_584_993).abs() < 1e-9);
        assert!((g.lon + 0.139_626_340).abs() < 1e-9);
        assert_eq!((g.z, g.z_units), (10.0, units::Z_DEPTH));
        assert_eq!(z_of(None, Some(3.0)), (3.0, units::Z_ALTITUDE));
        assert_eq!((g.speed, g.speed_units), (1.5, units::SPEED_MPS));
    }

    #[test]
    fn durations_saturate_into_u16() {
        assert_eq!(seconds_u16(86_400.0), u16::MAX);
        assert_eq!(seconds_u16(-3.0), 0);
        assert_eq!(seconds_u16(f64::NAN), 0);
        assert_eq!(seconds_u16(59.6), 60);
    }
}
