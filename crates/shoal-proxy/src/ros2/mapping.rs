//! ROS 2 conventions into Shoal's: REP 103 frames (ENU world, body x forward, y left, z
//! up) and quaternions into a compass heading, nose-up pitch and starboard-down roll;
//! battery fractions into percent; geodetic targets into a local ENU goal frame.

use shoal_model::GeoPoint;

use super::msgs::Quaternion;
use crate::imc::mapping::displace;

/// WGS84 semi-major axis, metres.
///
/// Not a second Earth radius beside `shoal_model::geo::EARTH_RADIUS_M`: with the
/// eccentricity below it gives the ellipsoid's radii of curvature, so that goals in a
/// ROS 2 vehicle's ENU frame land where its own (ellipsoidal) navigation puts them, as
/// `imc::mapping::displace` does for DUNE.
const WGS84_A: f64 = 6_378_137.0;
/// WGS84 first eccentricity squared.
const WGS84_E2: f64 = 6.694_379_990_14e-3;

/// Roll, pitch and yaw in radians (ZYX, REP 103) of a quaternion; `None` if it is not a
/// finite, non-zero quaternion.
pub fn euler(q: &Quaternion) -> Option<(f64, f64, f64)> {
    let n = (q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w).sqrt();
    if !n.is_finite() || n < 1e-9 {
        return None;
    }
    let (x, y, z, w) = (q.x / n, q.y / n, q.z / n, q.w / n);
    let roll = (2.0 * (w * x + y * z)).atan2(1.0 - 2.0 * (x * x + y * y));
    let pitch = (2.0 * (w * y - z * x)).clamp(-1.0, 1.0).asin();
    let yaw = (2.0 * (w * z + x * y)).atan2(1.0 - 2.0 * (y * y + z * z));
    Some((roll, pitch, yaw))
}

/// Shoal's attitude in degrees (roll starboard-down positive, pitch nose-up positive,
/// heading clockwise from north in [0, 360)) from a REP 103 quaternion (ENU world, FLU
/// body).
///
/// In ENU, yaw is counter-clockwise from east, so the heading is 90° minus it; with the
/// body's y axis to port, a positive pitch puts the nose down, so Shoal's pitch is its
/// opposite; a positive roll puts the starboard side down, as in Shoal.
pub fn attitude_deg(q: &Quaternion) -> Option<(f64, f64, f64)> {
    let (roll, pitch, yaw) = euler(q)?;
    let heading = (90.0 - yaw.to_degrees()).rem_euclid(360.0);
    let heading = if heading >= 360.0 { 0.0 } else { heading };
    Some((roll.to_degrees(), -pitch.to_degrees(), heading))
}

/// A REP 103 quaternion for a compass heading in degrees, level.
pub fn heading_quaternion(heading_deg: f64) -> Quaternion {
    let yaw = (90.0 - heading_deg).to_radians();
    Quaternion {
        x: 0.0,
        y: 0.0,
        z: (yaw / 2.0).sin(),
        w: (yaw / 2.0).cos(),
    }
}

/// Percent from `BatteryState.percentage` (a fraction): `Ok(None)` for NaN (unknown),
/// `Err` outside [0, 1].
pub fn battery_pct(fraction: f32) -> Result<Option<f64>, f32> {
    if fraction.is_nan() {
        Ok(None)
    } else if (0.0..=1.0).contains(&fraction) {
        Ok(Some(f64::from(fraction) * 100.0))
    } else {
        Err(fraction)
    }
}

/// A local ENU frame with its origin at a geodetic datum, for goals.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EnuFrame {
    origin: GeoPoint,
}

impl EnuFrame {
    /// The frame whose origin is `origin`.
    pub fn new(origin: GeoPoint) -> Self {
        Self { origin }
    }

    /// The origin.
    pub fn origin(&self) -> GeoPoint {
        self.origin
    }

    /// (east, north) in metres of a point, with the WGS84 radii of curvature at the
    /// origin (millimetre-exact over a mission area).
    pub fn to_enu(&self, p: GeoPoint) -> (f64, f64) {
        let lat0 = self.origin.latitude_deg.to_radians();
        let s = lat0.sin();
        let w = 1.0 - WGS84_E2 * s * s;
        let prime_vertical = WGS84_A / w.sqrt();
        let meridional = WGS84_A * (1.0 - WGS84_E2) / (w * w.sqrt());
        let dlat = (p.latitude_deg - self.origin.latitude_deg).to_radians();
        let mut dlon = p.longitude_deg - self.origin.longitude_deg;
        // The short way round the antimeridian.
        if dlon > 180.0 {
            dlon -= 360.0;
        } else if dlon < -180.0 {
            dlon += 360.0;
        }
        (
            dlon.to_radians() * prime_vertical * lat0.cos(),
            dlat * meridional,
        )
    }

    /// The geodetic point at (east, north) metres.
    pub fn to_geo(&self, east: f64, north: f64) -> GeoPoint {
        let (lat, lon) = displace(
            self.origin.latitude_deg.to_radians(),
            self.origin.longitude_deg.to_radians(),
            north,
            east,
        );
        GeoPoint {
            latitude_deg: lat,
            longitude_deg: lon,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn q_from_euler(roll: f64, pitch: f64, yaw: f64) -> Quaternion {
        let (cr, sr) = ((roll / 2.0).cos(), (roll / 2.0).sin());
        let (cp, sp) = ((pitch / 2.0).cos(), (pitch / 2.0).sin());
        let (cy, sy) = ((yaw / 2.0).cos(), (yaw / 2.0).sin());
        Quaternion {
            w: cr * cp * cy + sr * sp * sy,
            x: sr * cp * cy - cr * sp * sy,
            y: cr * sp * cy + sr * cp * sy,
            z: cr * cp * sy - sr * sp * cy,
        }
    }

    #[test]
    fn enu_yaw_becomes_a_compass_heading() {
        // Facing east in ENU (yaw 0) is heading 90; facing north (yaw 90°) is heading 0.
        let (_, _, h) = attitude_deg(&Quaternion::default()).unwrap();
        assert!((h - 90.0).abs() < 1e-9);
        let (_, _, h) = attitude_deg(&q_from_euler(0.0, 0.0, std::f64::consts::FRAC_PI_2)).unwrap();
        assert!(h.abs() < 1e-9 || (h - 360.0).abs() < 1e-9, "{h}");
        let (_, _, h) = attitude_deg(&q_from_euler(0.0, 0.0, std::f64::consts::PI)).unwrap();
        assert!((h - 270.0).abs() < 1e-9, "west");
        let (_, _, h) = attitude_deg(&heading_quaternion(135.0)).unwrap();
        assert!((h - 135.0).abs() < 1e-9, "{h}");
    }

    #[test]
    fn nose_down_ros_pitch_is_negative_shoal_pitch() {
        let (roll, pitch, _) = attitude_deg(&q_from_euler(0.1, 0.2, 0.3)).unwrap();
        assert!((roll - 0.1f64.to_degrees()).abs() < 1e-9);
        assert!((pitch + 0.2f64.to_degrees()).abs() < 1e-9);
    }

    #[test]
    fn degenerate_quaternions_are_rejected() {
        let zero = Quaternion {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 0.0,
        };
        assert_eq!(euler(&zero), None);
        assert_eq!(
            euler(&Quaternion {
                w: f64::NAN,
                ..zero
            }),
            None
        );
        // Unnormalised ones are normalised.
        let (_, _, h) = attitude_deg(&Quaternion { w: 3.0, ..zero }).unwrap();
        assert!((h - 90.0).abs() < 1e-9);
    }

    #[test]
    fn battery_fraction_is_percent() {
        assert_eq!(battery_pct(0.42), Ok(Some(f64::from(0.42f32) * 100.0)));
        assert_eq!(battery_pct(1.0), Ok(Some(100.0)));
        assert_eq!(battery_pct(f32::NAN), Ok(None));
        assert_eq!(
            battery_pct(42.0),
            Err(42.0),
            "a percentage sent as such is an error"
        );
    }

    #[test]
    fn enu_round_trips_and_points_the_right_way() {
        let f = EnuFrame::new(GeoPoint {
            latitude_deg: 59.9,
            longitude_deg: 10.7,
        });
        let (e, n) = f.to_enu(GeoPoint {
            latitude_deg: 59.901,
            longitude_deg: 10.702,
        });
        assert!((n - 111.6).abs() < 0.5, "{n}");
        assert!((e - 112.0).abs() < 0.5, "{e}");
        let back = f.to_geo(e, n);
        assert!((back.latitude_deg - 59.901).abs() < 1e-9);
        assert!((back.longitude_deg - 10.702).abs() < 1e-9);
        let (e, _) = f.to_enu(GeoPoint {
            latitude_deg: 59.9,
            longitude_deg: 10.69,
        });
        assert!(e < 0.0, "west is negative east");
    }
}
