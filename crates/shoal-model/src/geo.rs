//! Geodesy the checks and the station share.

/// Mean Earth radius (IUGG), metres: the spherical model is within 0.5 % of WGS84, far
/// below what plausibility checks and proximity tests need.
pub const EARTH_RADIUS_M: f64 = 6_371_008.8;

/// Great-circle distance in metres between two WGS84 positions in degrees (haversine).
pub fn distance_m(lat1: f64, lon1: f64, lat2: f64, lon2: f64) -> f64 {
    let (p1, p2) = (lat1.to_radians(), lat2.to_radians());
    let dp = p2 - p1;
    let dl = (lon2 - lon1).to_radians();
    let a = (dp / 2.0).sin().powi(2) + p1.cos() * p2.cos() * (dl / 2.0).sin().powi(2);
    2.0 * EARTH_RADIUS_M * a.sqrt().min(1.0).asin()
}

#[cfg(test)]
mod tests {
    use super::*;

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
}
