//! Closest point of approach between two vessels on straight courses, and the evaluator
//! that turns it into collision warnings with hysteresis.
//!
//! Positions are projected on a flat local tangent plane centred on the first vessel
//! (equirectangular: east = Δlon·cos(lat₀)·R, north = Δlat·R, R = 6 371 000 m). At the
//! ranges where CPA matters (a few nautical miles) the error is well under 1 % of the
//! distance; it grows with range and near the poles, and courses are assumed straight and
//! speeds constant (no rate of turn).

use std::collections::HashSet;

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

/// A target predicted to pass too close to one of the own vehicles.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CollisionWarning {
    /// The own vehicle's id.
    pub vehicle_id: String,
    /// The target's MMSI.
    pub mmsi: u32,
    /// The target's name, if known.
    pub name: Option<String>,
    /// Distance at the closest point of approach, metres.
    pub cpa_m: f64,
    /// Time to it, seconds.
    pub tcpa_s: f64,
    /// Distance now, metres.
    pub range_m: f64,
    /// The target's (extrapolated) position and motion used.
    pub target: Motion,
}

/// Warnings raised and pairs cleared by one evaluation.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct CollisionUpdate {
    /// Pairs that newly meet the alarm condition.
    pub raised: Vec<CollisionWarning>,
    /// Pairs raised earlier that no longer do, as (vehicle id, MMSI).
    pub cleared: Vec<(String, u32)>,
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

/// Raises each (vehicle, target) pair once when its CPA is under the threshold within the
/// horizon, and again only after it has cleared.
#[derive(Debug)]
pub struct CollisionMonitor {
    alarm_m: f64,
    horizon_s: f64,
    clear_factor: f64,
    active: HashSet<(String, u32)>,
}

impl CollisionMonitor {
    /// A monitor with these thresholds (`clear_factor` ≥ 1 widens both to clear).
    pub fn new(alarm_m: f64, horizon_s: f64, clear_factor: f64) -> Self {
        Self {
            alarm_m,
            horizon_s,
            clear_factor: clear_factor.max(1.0),
            active: HashSet::new(),
        }
    }

    /// Pairs currently raised.
    #[cfg(test)]
    pub fn active(&self) -> usize {
        self.active.len()
    }

    /// Evaluates every pair; pairs whose vehicle or target is gone clear too.
    pub fn evaluate(
        &mut self,
        vehicles: &[OwnVehicle],
        targets: &[TargetMotion],
    ) -> CollisionUpdate {
        let mut update = CollisionUpdate::default();
        let mut seen: HashSet<(String, u32)> = HashSet::new();
        for v in vehicles {
            if !motion_ok(&v.motion) {
                continue;
            }
            for t in targets {
                let key = (v.id.clone(), t.mmsi);
                let a = cpa(&v.motion, &t.motion);
                let alarm =
                    a.tcpa_s >= 0.0 && a.tcpa_s <= self.horizon_s && a.cpa_m <= self.alarm_m;
                let holds = a.tcpa_s >= 0.0
                    && a.tcpa_s <= self.horizon_s * self.clear_factor
                    && a.cpa_m <= self.alarm_m * self.clear_factor;
                let was = self.active.contains(&key);
                if alarm && !was {
                    update.raised.push(CollisionWarning {
                        vehicle_id: v.id.clone(),
                        mmsi: t.mmsi,
                        name: t.name.clone(),
                        cpa_m: a.cpa_m,
                        tcpa_s: a.tcpa_s,
                        range_m: a.range_m,
                        target: t.motion,
                    });
                    self.active.insert(key.clone());
                    seen.insert(key);
                } else if was && holds {
                    seen.insert(key);
                }
            }
        }
        let gone: Vec<(String, u32)> = self
            .active
            .iter()
            .filter(|k| !seen.contains(*k))
            .cloned()
            .collect();
        for k in gone {
            self.active.remove(&k);
            update.cleared.push(k);
        }
        update.cleared.sort();
        update
    }
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

    #[test]
    fn diverging_has_negative_tcpa_and_no_alarm() {
        // Back to back, 500 m apart, both going away.
        let a = at(0.0, 0.0, 180.0, 8.0);
        let b = at(0.0, 500.0, 0.0, 8.0);
        let r = cpa(&a, &b);
        assert!(r.tcpa_s < 0.0, "{r:?}");
        let mut m = CollisionMonitor::new(1000.0, 600.0, 1.2);
        let targets = [TargetMotion {
            mmsi: 1,
            name: None,
            motion: b,
        }];
        let vehicles = [OwnVehicle {
            id: "usv1".into(),
            motion: a,
        }];
        assert!(m.evaluate(&vehicles, &targets).raised.is_empty());
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
    fn monitor_raises_once_and_clears_with_hysteresis() {
        let mut m = CollisionMonitor::new(500.0, 600.0, 1.2);
        let vehicles = [OwnVehicle {
            id: "usv1".into(),
            motion: at(0.0, 0.0, 0.0, 5.0),
        }];
        let target = |east: f64| TargetMotion {
            mmsi: 230_000_001,
            name: Some("TEST".into()),
            motion: at(east, 2000.0, 180.0, 10.0),
        };
        // 400 m lateral offset: CPA 400 < 500, raised once.
        let u = m.evaluate(&vehicles, &[target(400.0)]);
        assert_eq!(u.raised.len(), 1);
        assert_eq!(u.raised[0].vehicle_id, "usv1");
        assert!(close(u.raised[0].cpa_m, 400.0, 0.5));
        assert!(m.evaluate(&vehicles, &[target(400.0)]).raised.is_empty());
        // 550 m: above the alarm but within the clear margin (600): still held.
        let u = m.evaluate(&vehicles, &[target(550.0)]);
        assert!(u.raised.is_empty() && u.cleared.is_empty());
        // 700 m: cleared.
        let u = m.evaluate(&vehicles, &[target(700.0)]);
        assert_eq!(u.cleared, vec![("usv1".to_string(), 230_000_001)]);
        // Back under: raised again.
        assert_eq!(m.evaluate(&vehicles, &[target(100.0)]).raised.len(), 1);
        // Target gone: cleared.
        assert_eq!(m.evaluate(&vehicles, &[]).cleared.len(), 1);
        assert_eq!(m.active(), 0);
    }

    #[test]
    fn beyond_horizon_is_not_raised() {
        let mut m = CollisionMonitor::new(500.0, 60.0, 1.2);
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
        assert!(m.evaluate(&vehicles, &t).raised.is_empty());
    }
}
