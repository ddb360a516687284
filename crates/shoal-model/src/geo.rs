//! Geometry on a spherical Earth, shared by the station's checks, the simulator, the
//! vehicle proxies and the acoustic channel model: one Earth radius for all of them.
//!
//! - [`distance_m`]: great-circle distance (haversine), good at any range.
//! - [`distance_bearing`], [`distance`], [`path_length`]: equirectangular distance and
//!   bearing between nearby points (a mission area, an acoustic link's few kilometres),
//!   within well under 0.1 % of the great circle there, far below a vehicle's navigation
//!   error, and cheap enough to run every simulation step.
//! - [`LocalFrame`]: a local east/north tangent plane in metres around an origin.
//! - [`angle_diff`]: the short way between two headings.
//! - [`inside`]: whether a point lies in a polygon (operating areas, land on a chart).
//!
//! The vehicle proxies' WGS84 radii of curvature (IMC, ROS 2) are an ellipsoid model kept
//! on purpose to match what those vehicles' own software computes, not a second sphere.

use crate::GeoPoint;

/// Mean Earth radius, metres (6371 km, the IUGG mean radius rounded to the kilometre): the
/// spherical model is within 0.5 % of WGS84, far below what plausibility checks,
/// proximity tests and the simulator need.
///
/// The simulator, the acoustic channel model and the test fixtures' metres per degree
/// (111 194.93) were all made with this value, so seeded simulations repeat exactly.
pub const EARTH_RADIUS_M: f64 = 6_371_000.0;

/// Great-circle distance in metres between two WGS84 positions in degrees (haversine).
pub fn distance_m(lat1: f64, lon1: f64, lat2: f64, lon2: f64) -> f64 {
    let (p1, p2) = (lat1.to_radians(), lat2.to_radians());
    let dp = p2 - p1;
    let dl = (lon2 - lon1).to_radians();
    let a = (dp / 2.0).sin().powi(2) + p1.cos() * p2.cos() * (dl / 2.0).sin().powi(2);
    2.0 * EARTH_RADIUS_M * a.sqrt().min(1.0).asin()
}

/// True when `(lat, lon)` lies inside `polygon` (even-odd ray casting in the lon/lat
/// plane; the ring closes itself). Over several rings (land with lakes), a point is inside
/// when an odd number of them contain it.
///
/// Adequate for areas of a few tens of kilometres away from the poles; an area crossing
/// the antimeridian must be split.
pub fn inside(polygon: &[GeoPoint], lat: f64, lon: f64) -> bool {
    let mut inside = false;
    let n = polygon.len();
    for i in 0..n {
        let (a, b) = (polygon[i], polygon[(i + n - 1) % n]);
        if (a.latitude_deg > lat) != (b.latitude_deg > lat) {
            let x = (b.longitude_deg - a.longitude_deg) * (lat - a.latitude_deg)
                / (b.latitude_deg - a.latitude_deg)
                + a.longitude_deg;
            if lon < x {
                inside = !inside;
            }
        }
    }
    inside
}

/// Signed smallest difference `a - b` between two headings, degrees in (-180, 180].
pub fn angle_diff(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(360.0);
    if d > 180.0 { d - 360.0 } else { d }
}

/// Equirectangular distance (m) and initial bearing (degrees clockwise from north, in
/// [0, 360)) between two nearby points.
pub fn distance_bearing(lat1: f64, lon1: f64, lat2: f64, lon2: f64) -> (f64, f64) {
    let mean_lat = ((lat1 + lat2) / 2.0).to_radians();
    let north = (lat2 - lat1).to_radians() * EARTH_RADIUS_M;
    let east = (lon2 - lon1).to_radians() * EARTH_RADIUS_M * mean_lat.cos();
    (
        north.hypot(east),
        east.atan2(north).to_degrees().rem_euclid(360.0),
    )
}

/// Equirectangular distance in metres between two nearby points.
pub fn distance(a: GeoPoint, b: GeoPoint) -> f64 {
    distance_bearing(
        a.latitude_deg,
        a.longitude_deg,
        b.latitude_deg,
        b.longitude_deg,
    )
    .0
}

/// Length in metres of the path from `from` through every waypoint in order.
pub fn path_length(from: GeoPoint, waypoints: &[GeoPoint]) -> f64 {
    let mut last = from;
    let mut total = 0.0;
    for wp in waypoints {
        total += distance(last, *wp);
        last = *wp;
    }
    total
}

/// A local east/north tangent plane in metres around an origin (equirectangular: for the
/// few kilometres around the origin a mission area spans).
#[derive(Debug, Clone, Copy)]
pub struct LocalFrame {
    lat0: f64,
    lon0: f64,
    cos_lat0: f64,
}

impl LocalFrame {
    /// The frame whose origin is `origin`.
    pub fn new(origin: GeoPoint) -> Self {
        Self {
            lat0: origin.latitude_deg,
            lon0: origin.longitude_deg,
            // Kept off zero so a frame at a pole still maps (if badly) instead of dividing
            // by zero.
            cos_lat0: origin.latitude_deg.to_radians().cos().max(1e-6),
        }
    }

    /// (east, north) of a point, metres.
    pub fn to_xy(self, p: GeoPoint) -> (f64, f64) {
        (
            (p.longitude_deg - self.lon0).to_radians() * EARTH_RADIUS_M * self.cos_lat0,
            (p.latitude_deg - self.lat0).to_radians() * EARTH_RADIUS_M,
        )
    }

    /// The point at (east, north) metres.
    pub fn to_geo(self, x: f64, y: f64) -> GeoPoint {
        GeoPoint {
            latitude_deg: self.lat0 + (y / EARTH_RADIUS_M).to_degrees(),
            longitude_deg: self.lon0 + (x / (EARTH_RADIUS_M * self.cos_lat0)).to_degrees(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(lat: f64, lon: f64) -> GeoPoint {
        GeoPoint {
            latitude_deg: lat,
            longitude_deg: lon,
        }
    }

    #[test]
    fn a_point_is_inside_a_ring_by_the_even_odd_rule() {
        let square = [p(0.0, 0.0), p(0.0, 1.0), p(1.0, 1.0), p(1.0, 0.0)];
        assert!(inside(&square, 0.5, 0.5));
        assert!(!inside(&square, 1.5, 0.5));
        assert!(!inside(&square, 0.5, -0.1));
        assert!(!inside(&[], 0.5, 0.5));
    }

    #[test]
    fn one_degree_of_latitude_is_about_111_km() {
        let d = distance_m(43.0, 5.0, 44.0, 5.0);
        assert!((d - 111_195.0).abs() < 50.0, "{d}");
    }

    #[test]
    fn across_the_antimeridian_is_short() {
        let d = distance_m(0.0, 179.9995, 0.0, -179.9995);
        assert!((d - 111.2).abs() < 1.0, "{d}");
    }

    #[test]
    fn same_point_is_zero() {
        assert!(distance_m(59.9, 10.7, 59.9, 10.7).abs() < 1e-9);
    }

    #[test]
    fn path_length_adds_the_legs() {
        let a = p(0.0, 0.0);
        let b = p(0.001, 0.0);
        let total = path_length(a, &[b, a]);
        assert!((total - 2.0 * distance(a, b)).abs() < 1e-9);
        assert!((distance(a, b) - 111.19).abs() < 0.1);
    }

    #[test]
    fn angle_diff_takes_the_short_way_round() {
        assert_eq!(angle_diff(10.0, 350.0), 20.0);
        assert_eq!(angle_diff(350.0, 10.0), -20.0);
        assert_eq!(angle_diff(180.0, 0.0), 180.0);
    }

    #[test]
    fn nearby_distances_agree_with_the_great_circle() {
        let (a, b) = (p(63.44, 10.39), p(63.46, 10.43));
        let (flat, bearing) = distance_bearing(
            a.latitude_deg,
            a.longitude_deg,
            b.latitude_deg,
            b.longitude_deg,
        );
        let great = distance_m(
            a.latitude_deg,
            a.longitude_deg,
            b.latitude_deg,
            b.longitude_deg,
        );
        assert!((flat - great).abs() < 1e-3 * great, "{flat} vs {great}");
        // North-east: 0.04° of longitude at 63° N is about 2.0 km east, 0.02° of latitude
        // 2.2 km north, so a little under 45°.
        assert!((40.0..45.0).contains(&bearing), "{bearing}");
    }

    #[test]
    fn a_local_frame_round_trips() {
        let frame = LocalFrame::new(p(43.0, 5.9));
        let q = p(43.003, 5.905);
        let (x, y) = frame.to_xy(q);
        let back = frame.to_geo(x, y);
        assert!((back.latitude_deg - q.latitude_deg).abs() < 1e-12);
        assert!((back.longitude_deg - q.longitude_deg).abs() < 1e-12);
        assert!((x.hypot(y) - distance(p(43.0, 5.9), q)).abs() < 1.0);
    }
}
