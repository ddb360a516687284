//! Closest point of approach between two vessels on straight courses, and the pairs of
//! own vehicles and targets that come close.
//!
//! Positions are projected on a flat local tangent plane centred on the first vessel
//! (equirectangular: east = Δlon·cos(lat₀)·R, north = Δlat·R, R = 6 371 000 m). At the
//! ranges where CPA matters (a few nautical miles) the error is well under 1 % of the
//! distance; it grows with range and near the poles, and courses are assumed straight and
//! speeds constant (no rate of turn).

use serde::Serialize;

/// Mean Earth radius used by the tangent plane, metres.
pub const EARTH_RADIUS_M: f64 = 6_371_000.0;
/// Metres per second in one knot.
pub const MS_PER_KNOT: f64 = 1852.0 / 3600.0;

/// A vessel's kinematic state: where it is and how it moves.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct Motion {
    /// Latitude, degrees.
    pub lat: f64,
    /// Longitude, degrees.
    pub lon: f64,
    /// Course over ground, degrees true.
    pub cog_deg: f64,
    /// Speed over ground, knots.
    pub sog_kn: f64,
}

impl Motion {
    /// Where this vessel is `secs` seconds later on its course and speed (dead reckoning
    /// on the tangent plane; longitude wrapped, latitude clamped).
    pub fn advanced(self, secs: f64) -> Self {
        let (ve, vn) = velocity(self.cog_deg, self.sog_kn);
        let lat = self.lat + (vn * secs / EARTH_RADIUS_M).to_degrees();
        let coslat = self.lat.to_radians().cos().max(1e-6);
        let mut lon = self.lon + (ve * secs / (EARTH_RADIUS_M * coslat)).to_degrees();
        if lon > 180.0 {
            lon -= 360.0;
        } else if lon < -180.0 {
            lon += 360.0;
        }
        Self {
            lat: lat.clamp(-90.0, 90.0),
            lon,
            ..self
        }
    }
}

/// The result of a CPA computation.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Approach {
    /// Distance at the closest point of approach, metres.
    pub cpa_m: f64,
    /// Time until it, seconds; negative when it is in the past (diverging).
    pub tcpa_s: f64,
    /// Distance now, metres.
    pub range_m: f64,
}

/// East and north offset of `p` from `origin` on the tangent plane at `origin`, metres.
pub fn local_offset(origin_lat: f64, origin_lon: f64, lat: f64, lon: f64) -> (f64, f64) {
    // Longitude difference across the antimeridian takes the short way.
    let mut dlon = lon - origin_lon;
    if dlon > 180.0 {
        dlon -= 360.0;
    } else if dlon < -180.0 {
        dlon += 360.0;
    }
    let east = dlon.to_radians() * origin_lat.to_radians().cos() * EARTH_RADIUS_M;
    let north = (lat - origin_lat).to_radians() * EARTH_RADIUS_M;
    (east, north)
}

/// Velocity (east, north) in m/s from course and speed.
pub fn velocity(cog_deg: f64, sog_kn: f64) -> (f64, f64) {
    let v = sog_kn * MS_PER_KNOT;
    let c = cog_deg.to_radians();
    (v * c.sin(), v * c.cos())
}

/// Closest point of approach between `a` and `b` moving straight at constant speed.
///
/// When their relative velocity is (nearly) zero the distance never changes: TCPA is 0 and
/// CPA the present range.
pub fn cpa(a: &Motion, b: &Motion) -> Approach {
    let (rx, ry) = local_offset(a.lat, a.lon, b.lat, b.lon);
    let (ax, ay) = velocity(a.cog_deg, a.sog_kn);
    let (bx, by) = velocity(b.cog_deg, b.sog_kn);
    let (wx, wy) = (bx - ax, by - ay);
    let w2 = wx * wx + wy * wy;
    let range = rx.hypot(ry);
    // Below 1 mm/s relative speed the approach time is meaningless.
    if w2 < 1e-6 {
        return Approach {
            cpa_m: range,
            tcpa_s: 0.0,
            range_m: range,
        };
    }
    let t = -(rx * wx + ry * wy) / w2;
    let cpa = (rx + wx * t).hypot(ry + wy * t);
    Approach {
        cpa_m: cpa,
        tcpa_s: t,
        range_m: range,
    }
}

/// One of the station's own surface vehicles, for collision checks against AIS targets.
#[derive(Clone, Debug, PartialEq, Serialize, serde::Deserialize)]
pub struct OwnVehicle {
    /// The station's vehicle id.
    pub id: String,
    /// Its present position, course and speed.
    pub motion: Motion,
}

/// A target whose course brings it close to one of the own vehicles.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct VesselApproach {
    /// The own vehicle's id.
    pub vehicle_id: String,
    /// The target's MMSI.
    pub mmsi: u32,
    /// The target's name, if known.
    pub name: Option<String>,
    /// Distance at the closest point of approach, metres.
    pub cpa_m: f64,
    /// Time to it, seconds (negative once it is past).
    pub tcpa_s: f64,
    /// Distance now, metres.
    pub range_m: f64,
    /// The target's (extrapolated) position and motion used.
    pub target: Motion,
}

/// A target as the evaluator sees it: identity and present motion.
#[derive(Clone, Debug, PartialEq)]
pub struct TargetMotion {
    /// MMSI.
    pub mmsi: u32,
    /// Name, if known.
    pub name: Option<String>,
    /// Motion, extrapolated to now.
    pub motion: Motion,
}

/// Which approaches [`approaches`] reports: those whose CPA is under `within_m` and whose
/// closest point lies between `past_s` seconds ago and `ahead_s` seconds from now.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ApproachWindow {
    /// Largest CPA reported, metres.
    pub within_m: f64,
    /// How far in the past the closest point may be, seconds (≥ 0).
    pub past_s: f64,
    /// How far ahead the closest point may be, seconds.
    pub ahead_s: f64,
}

/// Every (vehicle, target) pair inside `window`. It keeps no state and raises nothing:
/// the caller decides what is an alarm (Shoal's station hands these to its rules engine,
/// whose collision-risk rule owns the thresholds and raises each alarm once).
pub fn approaches(
    vehicles: &[OwnVehicle],
    targets: &[TargetMotion],
    window: ApproachWindow,
) -> Vec<VesselApproach> {
    let mut out = Vec::new();
    for v in vehicles.iter().filter(|v| motion_ok(&v.motion)) {
        for t in targets.iter().filter(|t| motion_ok(&t.motion)) {
            let a = cpa(&v.motion, &t.motion);
            if a.cpa_m < window.within_m && a.tcpa_s >= -window.past_s && a.tcpa_s <= window.ahead_s
            {
                out.push(VesselApproach {
                    vehicle_id: v.id.clone(),
                    mmsi: t.mmsi,
                    name: t.name.clone(),
                    cpa_m: a.cpa_m,
                    tcpa_s: a.tcpa_s,
                    range_m: a.range_m,
                    target: t.motion,
                });
            }
        }
    }
    out
}

fn motion_ok(m: &Motion) -> bool {
    m.lat.is_finite()
        && m.lon.is_finite()
        && m.cog_deg.is_finite()
        && m.sog_kn.is_finite()
        && (-90.0..=90.0).contains(&m.lat)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A point `east`, `north` metres from (0, 0) on the tangent plane.
    fn at(east: f64, north: f64, cog_deg: f64, sog_kn: f64) -> Motion {
        Motion {
            lat: (north / EARTH_RADIUS_M).to_degrees(),
            lon: (east / EARTH_RADIUS_M).to_degrees(),
            cog_deg,
            sog_kn,
        }
    }

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol
    }

    #[test]
    fn head_on_meets_at_half_time() {
        // 10 kn each towards the other, 1852 m apart: closing at 20 kn = 10.288 m/s.
        let a = at(0.0, 0.0, 0.0, 10.0);
        let b = at(0.0, 1852.0, 180.0, 10.0);
        let r = cpa(&a, &b);
        assert!(close(r.cpa_m, 0.0, 0.01), "{r:?}");
        assert!(
            close(r.tcpa_s, 1852.0 / (20.0 * MS_PER_KNOT), 0.01),
            "{r:?}"
        );
        assert!(close(r.tcpa_s, 180.0, 0.01));
        assert!(close(r.range_m, 1852.0, 0.01));
    }

    #[test]
    fn head_on_with_lateral_offset() {
        // Same, offset 100 m east: CPA is the offset.
        let a = at(0.0, 0.0, 0.0, 10.0);
        let b = at(100.0, 1852.0, 180.0, 10.0);
        let r = cpa(&a, &b);
        assert!(close(r.cpa_m, 100.0, 0.01), "{r:?}");
        assert!(close(r.tcpa_s, 180.0, 0.01), "{r:?}");
    }

    #[test]
    fn crossing_at_right_angles() {
        // A heads north at 10 kn from the origin; B heads west at 10 kn from 1000 m east,
        // 1000 m north: both reach (0, 1000) together -> CPA 0 at 1000 / 5.144 s.
        let a = at(0.0, 0.0, 0.0, 10.0);
        let b = at(1000.0, 1000.0, 270.0, 10.0);
        let r = cpa(&a, &b);
        assert!(close(r.cpa_m, 0.0, 0.05), "{r:?}");
        assert!(
            close(r.tcpa_s, 1000.0 / (10.0 * MS_PER_KNOT), 0.05),
            "{r:?}"
        );
        // B 400 m further east: relative position (1400, 1000), relative velocity
        // (-v, -v): t = 2400 / (2v), miss distance |(1400 - 1200, 1000 - 1200)| = 282.84 m.
        let b = at(1400.0, 1000.0, 270.0, 10.0);
        let r = cpa(&a, &b);
        let v = 10.0 * MS_PER_KNOT;
        assert!(close(r.tcpa_s, 2400.0 / (2.0 * v), 0.05), "{r:?}");
        assert!(close(r.cpa_m, 200.0 * 2f64.sqrt(), 0.05), "{r:?}");
    }

    const WINDOW: ApproachWindow = ApproachWindow {
        within_m: 1000.0,
        past_s: 0.0,
        ahead_s: 600.0,
    };

    #[test]
    fn diverging_has_negative_tcpa_and_is_not_approaching() {
        // Back to back, 500 m apart, both going away.
        let a = at(0.0, 0.0, 180.0, 8.0);
        let b = at(0.0, 500.0, 0.0, 8.0);
        let r = cpa(&a, &b);
        assert!(r.tcpa_s < 0.0, "{r:?}");
        let targets = [TargetMotion {
            mmsi: 1,
            name: None,
            motion: b,
        }];
        let vehicles = [OwnVehicle {
            id: "usv1".into(),
            motion: a,
        }];
        assert!(approaches(&vehicles, &targets, WINDOW).is_empty());
        // Within a window reaching into the past (they were closest 61 s ago) it is
        // reported, with its negative TCPA.
        let past = ApproachWindow {
            past_s: 120.0,
            ..WINDOW
        };
        let found = approaches(&vehicles, &targets, past);
        assert_eq!(found.len(), 1);
        assert!(found[0].tcpa_s < 0.0);
    }

    #[test]
    fn parallel_same_speed_keeps_its_distance() {
        let a = at(0.0, 0.0, 45.0, 12.0);
        let b = at(300.0, 0.0, 45.0, 12.0);
        let r = cpa(&a, &b);
        assert!(close(r.cpa_m, 300.0, 0.01), "{r:?}");
        assert_eq!(r.tcpa_s, 0.0);
    }

    #[test]
    fn dead_reckoning_moves_along_the_course() {
        let m = Motion {
            lat: 63.0,
            lon: 10.0,
            cog_deg: 0.0,
            sog_kn: 10.0,
        };
        // 10 kn for an hour is 10 nautical miles, 10 minutes of latitude (to 0.1 %).
        let north = m.advanced(3600.0);
        assert!(close(north.lat, 63.0 + 10.0 / 60.0, 2e-4), "{north:?}");
        assert!(close(north.lon, 10.0, 1e-9));
        let east = Motion { cog_deg: 90.0, ..m }.advanced(3600.0);
        assert!(close(east.lat, 63.0, 1e-9));
        assert!(
            close(
                east.lon,
                10.0 + 10.0 / 60.0 / 63f64.to_radians().cos(),
                1e-3
            ),
            "{east:?}"
        );
        // Across the antimeridian the longitude wraps.
        let w = Motion {
            lat: 0.0,
            lon: 179.99,
            cog_deg: 90.0,
            sog_kn: 10.0,
        }
        .advanced(3600.0);
        assert!(w.lon < -179.0, "{w:?}");
    }

    #[test]
    fn tangent_plane_matches_known_distances() {
        // One minute of latitude is one nautical mile on this sphere to 0.1 %.
        let (e, n) = local_offset(60.0, 10.0, 60.0 + 1.0 / 60.0, 10.0);
        assert!(close(e, 0.0, 1e-6) && close(n, 1853.2, 1.0), "{e} {n}");
        // One minute of longitude at 60° N is half that.
        let (e, _) = local_offset(60.0, 10.0, 60.0, 10.0 + 1.0 / 60.0);
        assert!(close(e, 926.6, 1.0), "{e}");
        // Across the antimeridian the short way.
        let (e, _) = local_offset(0.0, 179.99, 0.0, -179.99);
        assert!(close(e, 0.02f64.to_radians() * EARTH_RADIUS_M, 0.01), "{e}");
    }

    #[test]
    fn approaches_inside_the_window_are_reported_each_time() {
        let vehicles = [OwnVehicle {
            id: "usv1".into(),
            motion: at(0.0, 0.0, 0.0, 5.0),
        }];
        let target = |east: f64| TargetMotion {
            mmsi: 230_000_001,
            name: Some("TEST".into()),
            motion: at(east, 2000.0, 180.0, 10.0),
        };
        // 400 m lateral offset: CPA 400 < 1000, reported, and again (no state kept).
        for _ in 0..2 {
            let u = approaches(&vehicles, &[target(400.0)], WINDOW);
            assert_eq!(u.len(), 1);
            assert_eq!((u[0].vehicle_id.as_str(), u[0].mmsi), ("usv1", 230_000_001));
            assert!(close(u[0].cpa_m, 400.0, 0.5));
        }
        assert!(approaches(&vehicles, &[target(1100.0)], WINDOW).is_empty());
        // A vehicle with no valid motion is skipped.
        let bad = [OwnVehicle {
            id: "x".into(),
            motion: at(f64::NAN, 0.0, 0.0, 5.0),
        }];
        assert!(approaches(&bad, &[target(0.0)], WINDOW).is_empty());
    }

    #[test]
    fn beyond_the_horizon_is_not_reported() {
        let vehicles = [OwnVehicle {
            id: "v".into(),
            motion: at(0.0, 0.0, 0.0, 0.0),
        }];
        // Head-on at 10 kn from 5 km: TCPA ~972 s > 60 s.
        let t = [TargetMotion {
            mmsi: 2,
            name: None,
            motion: at(0.0, 5000.0, 180.0, 10.0),
        }];
        let short = ApproachWindow {
            ahead_s: 60.0,
            ..WINDOW
        };
        assert!(approaches(&vehicles, &t, short).is_empty());
        assert_eq!(
            approaches(&vehicles, &t, WINDOW).len(),
            0,
            "CPA 0 but TCPA 972 > 600"
        );
        let long = ApproachWindow {
            ahead_s: 1000.0,
            ..WINDOW
        };
        assert_eq!(approaches(&vehicles, &t, long).len(), 1);
    }
}
