//! Lawnmower survey patterns: the route a vehicle flies to cover a survey polygon.
//!
//! One pattern for everyone who needs it: the simulator flies it, the proxies plan surveys
//! the same way, and the station estimates a survey's length and energy from it before a
//! mission starts.

use crate::GeoPoint;
use crate::geo::LocalFrame;

/// Most survey lines one survey may have; a bigger survey is refused, not truncated.
pub const MAX_SURVEY_LINES: usize = 1000;

/// Why no lawnmower pattern can be made for a polygon.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum SurveyError {
    /// Fewer than three corners.
    #[error("a survey polygon needs at least 3 corners, not {0}")]
    TooFewCorners(usize),
    /// A corner is not a finite position.
    #[error("a survey polygon corner is not a finite position")]
    NotFinite,
    /// Line spacing below 1 m or not a number.
    #[error("line spacing {0} m is not at least 1 m")]
    BadSpacing(f64),
    /// The polygon spans more than 180° of longitude.
    #[error("survey polygons across the antimeridian are not supported")]
    Antimeridian,
    /// More lines than [`MAX_SURVEY_LINES`].
    #[error("the survey needs {lines} lines, more than the {max} allowed")]
    TooManyLines {
        /// Lines the polygon would need.
        lines: usize,
        /// Most allowed.
        max: usize,
    },
}

/// Lawnmower waypoints covering a polygon: east-west lines at most `spacing_m` apart,
/// alternating direction, starting in the south-west.
///
/// Lines are spread evenly between the southern and northern extremes, half a spacing in
/// from each, so a sensor whose swath is the line spacing sees every point of the polygon.
/// Each line spans the polygon's whole east-west extent within its swath band, so slanted
/// and concave edges are covered too (at the price of some overlap outside the polygon).
pub fn lawnmower(polygon: &[GeoPoint], spacing_m: f64) -> Result<Vec<GeoPoint>, SurveyError> {
    if polygon.len() < 3 {
        return Err(SurveyError::TooFewCorners(polygon.len()));
    }
    if polygon
        .iter()
        .any(|p| !p.latitude_deg.is_finite() || !p.longitude_deg.is_finite())
    {
        return Err(SurveyError::NotFinite);
    }
    if spacing_m.is_nan() || spacing_m < 1.0 {
        return Err(SurveyError::BadSpacing(spacing_m));
    }
    let (mut west, mut east) = (f64::MAX, f64::MIN);
    for p in polygon {
        west = west.min(p.longitude_deg);
        east = east.max(p.longitude_deg);
    }
    if east - west > 180.0 {
        return Err(SurveyError::Antimeridian);
    }
    #[allow(clippy::cast_precision_loss)]
    let n_corners = polygon.len() as f64;
    let centroid = GeoPoint {
        latitude_deg: polygon.iter().map(|p| p.latitude_deg).sum::<f64>() / n_corners,
        longitude_deg: polygon.iter().map(|p| p.longitude_deg).sum::<f64>() / n_corners,
    };
    let frame = LocalFrame::new(centroid);
    let corners: Vec<(f64, f64)> = polygon.iter().map(|p| frame.to_xy(*p)).collect();
    let (mut south, mut north) = (f64::MAX, f64::MIN);
    for (_, y) in &corners {
        south = south.min(*y);
        north = north.max(*y);
    }
    let height = north - south;
    let lines_f = (height / spacing_m).ceil().max(1.0);
    #[allow(clippy::cast_precision_loss)]
    if lines_f > MAX_SURVEY_LINES as f64 {
        #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
        let lines = lines_f.min(usize::MAX as f64) as usize;
        return Err(SurveyError::TooManyLines {
            lines,
            max: MAX_SURVEY_LINES,
        });
    }
    #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
    let lines = lines_f as usize;
    let half_band = height / (2.0 * lines_f);
    let mut out = Vec::with_capacity(2 * lines);
    for k in 0..lines {
        #[allow(clippy::cast_precision_loss)]
        let y = south + height * (k as f64 + 0.5) / lines_f;
        let Some((x_min, x_max)) = band_extent(&corners, y - half_band, y + half_band) else {
            continue;
        };
        let (a, b) = if k % 2 == 0 {
            (x_min, x_max)
        } else {
            (x_max, x_min)
        };
        out.push(frame.to_geo(a, y));
        out.push(frame.to_geo(b, y));
    }
    Ok(out)
}

/// East-west extent of the part of a polygon between two northings, if any.
///
/// The extent of a polygon clipped to a horizontal band is reached at an end of an edge
/// clipped to the band, because x varies linearly along each edge.
fn band_extent(corners: &[(f64, f64)], lo: f64, hi: f64) -> Option<(f64, f64)> {
    let mut extent: Option<(f64, f64)> = None;
    let mut include = |x: f64| {
        extent = Some(match extent {
            Some((a, b)) => (a.min(x), b.max(x)),
            None => (x, x),
        });
    };
    for (i, &(ax, ay)) in corners.iter().enumerate() {
        let (bx, by) = corners[(i + 1) % corners.len()];
        let (y0, y1) = (ay.min(by), ay.max(by));
        if y1 < lo || y0 > hi {
            continue;
        }
        if (by - ay).abs() < f64::EPSILON {
            include(ax);
            include(bx);
            continue;
        }
        for y in [y0.max(lo), y1.min(hi)] {
            let t = (y - ay) / (by - ay);
            include(ax + t * (bx - ax));
        }
    }
    extent
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geo::distance;

    fn p(lat: f64, lon: f64) -> GeoPoint {
        GeoPoint {
            latitude_deg: lat,
            longitude_deg: lon,
        }
    }

    fn inside(poly: &[(f64, f64)], x: f64, y: f64) -> bool {
        let mut c = false;
        for i in 0..poly.len() {
            let (ax, ay) = poly[i];
            let (bx, by) = poly[(i + 1) % poly.len()];
            if (ay > y) != (by > y) && x < ax + (y - ay) / (by - ay) * (bx - ax) {
                c = !c;
            }
        }
        c
    }

    fn segment_distance((px, py): (f64, f64), (ax, ay): (f64, f64), (bx, by): (f64, f64)) -> f64 {
        let (dx, dy) = (bx - ax, by - ay);
        let len2 = dx * dx + dy * dy;
        let t = if len2 == 0.0 {
            0.0
        } else {
            (((px - ax) * dx + (py - ay) * dy) / len2).clamp(0.0, 1.0)
        };
        (px - ax - t * dx).hypot(py - ay - t * dy)
    }

    /// Every point of a grid inside the polygon is within half a line spacing of a line.
    fn assert_covers(poly: &[GeoPoint], spacing: f64) {
        let wps = lawnmower(poly, spacing).unwrap();
        let frame = LocalFrame::new(poly[0]);
        let corners: Vec<_> = poly.iter().map(|c| frame.to_xy(*c)).collect();
        let route: Vec<_> = wps.iter().map(|w| frame.to_xy(*w)).collect();
        let (xs, ys): (Vec<f64>, Vec<f64>) = corners.iter().copied().unzip();
        let fold = |v: &[f64], f: fn(f64, f64) -> f64, init| v.iter().copied().fold(init, f);
        let (x0, x1) = (fold(&xs, f64::min, f64::MAX), fold(&xs, f64::max, f64::MIN));
        let (y0, y1) = (fold(&ys, f64::min, f64::MAX), fold(&ys, f64::max, f64::MIN));
        let mut checked = 0;
        for i in 0..=60 {
            for j in 0..=60 {
                let x = x0 + (x1 - x0) * f64::from(i) / 60.0;
                let y = y0 + (y1 - y0) * f64::from(j) / 60.0;
                if !inside(&corners, x, y) {
                    continue;
                }
                checked += 1;
                // Only the survey lines (even-odd pairs), not the turns, count as coverage.
                let d = route
                    .chunks(2)
                    .map(|l| segment_distance((x, y), l[0], l[1]))
                    .fold(f64::MAX, f64::min);
                assert!(
                    d <= spacing / 2.0 + 0.5,
                    "({x:.1}, {y:.1}) is {d:.1} m from any line"
                );
            }
        }
        assert!(checked > 100, "too few grid points inside: {checked}");
    }

    #[test]
    fn lawnmower_covers_a_triangle_with_alternating_lines() {
        let poly = [p(43.0, 5.9), p(43.0, 5.91), p(43.001, 5.91)];
        let wps = lawnmower(&poly, 20.0).unwrap();
        // 0.001° of latitude is 111 m: six lines at most 20 m apart.
        assert_eq!(wps.len(), 12);
        assert!(
            wps[0].longitude_deg < wps[1].longitude_deg
                && wps[2].longitude_deg > wps[3].longitude_deg
        );
        assert!(
            wps.windows(2)
                .all(|w| w[0].latitude_deg <= w[1].latitude_deg)
        );
        assert_covers(&poly, 20.0);
    }

    #[test]
    fn lawnmower_covers_concave_and_slanted_polygons() {
        let l_shape = [
            p(63.0, 10.0),
            p(63.0, 10.004),
            p(63.001, 10.004),
            p(63.001, 10.002),
            p(63.002, 10.002),
            p(63.002, 10.0),
        ];
        assert_covers(&l_shape, 25.0);
        let rhombus = [
            p(0.0, 0.0),
            p(0.001, 0.002),
            p(0.002, 0.0),
            p(0.001, -0.002),
        ];
        assert_covers(&rhombus, 15.0);
    }

    #[test]
    fn lawnmower_refuses_what_it_cannot_fly() {
        let poly = [p(43.0, 5.9), p(43.0, 5.91), p(43.001, 5.91)];
        assert_eq!(lawnmower(&poly, 0.5), Err(SurveyError::BadSpacing(0.5)));
        assert_eq!(
            lawnmower(&poly[..2], 10.0),
            Err(SurveyError::TooFewCorners(2))
        );
        let huge = [p(0.0, 0.0), p(0.0, 1.0), p(1.0, 1.0)];
        assert!(matches!(
            lawnmower(&huge, 1.0),
            Err(SurveyError::TooManyLines { lines, .. }) if lines > 100_000
        ));
        let wide = [p(0.0, -170.0), p(0.0, 170.0), p(0.001, 170.0)];
        assert_eq!(lawnmower(&wide, 10.0), Err(SurveyError::Antimeridian));
        let nan = [p(0.0, 0.0), p(f64::NAN, 0.0), p(0.001, 0.001)];
        assert_eq!(lawnmower(&nan, 10.0), Err(SurveyError::NotFinite));
    }

    #[test]
    fn a_flat_polygon_gives_one_line() {
        let flat = [p(10.0, 10.0), p(10.0, 10.001), p(10.0, 10.002)];
        let wps = lawnmower(&flat, 10.0).unwrap();
        assert_eq!(wps.len(), 2);
        assert!((distance(wps[0], wps[1]) - 219.0).abs() < 2.0, "{wps:?}");
    }
}
