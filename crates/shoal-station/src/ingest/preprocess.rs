//! The Data Pre-Processor's plausibility checks: a datum can be well-formed and in range
//! yet impossible given what the station already knows about its vehicle.
//!
//! Type, format and range checks happen when a sample is decoded (`shoal_model::Validate`);
//! this module compares a state vector with the vehicle's last accepted one (which after a
//! restart is the latest in the history store) and with the station's clock.
//!
//! A relative check can be wrong when the *previous* sample was the odd one, or when the
//! vehicle really changed abruptly: an AUV that surfaces after hours of dead reckoning
//! gets a GPS fix hundreds of metres from its estimate, a battery gauge recalibrates
//! upwards. Rejecting everything after such a step would lose good data for ever, so a
//! run of [`PlausibilityConfig::reanchor_after`] rejected samples that are plausible
//! *among themselves* re-anchors the vehicle: the last of them is accepted and the
//! operator is told.

use crate::error::ConfigError;
use serde::{Deserialize, Serialize};
use shoal_model::{StateVector, UNKNOWN, geo};

/// The `[station.plausibility]` configuration section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PlausibilityConfig {
    /// Run the plausibility checks at all (type and range checks always run).
    pub enabled: bool,
    /// Largest accepted lead of a sample's timestamp over the station clock, s (clock skew).
    pub max_future_s: f64,
    /// Oldest accepted sample, s before the station clock. Acoustic store-and-forward
    /// delivers minutes late; older data is a replay or a vehicle clock that was never set.
    pub max_age_s: f64,
    /// Factor on the vehicle's announced maximum speed a position change may reach.
    pub speed_margin: f64,
    /// Position change always accepted, m: fix noise and acoustic positioning error.
    pub position_tolerance_m: f64,
    /// Battery rise always accepted, percentage points: gauge noise.
    pub battery_tolerance_pct: f64,
    /// After this much silence a higher battery is accepted (swapped or charged), s.
    pub battery_reset_gap_s: f64,
    /// Rejected samples in a row, plausible among themselves, that re-anchor a vehicle.
    pub reanchor_after: u32,
}

impl Default for PlausibilityConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            max_future_s: 10.0,
            max_age_s: 3600.0,
            speed_margin: 1.5,
            position_tolerance_m: 50.0,
            battery_tolerance_pct: 2.0,
            battery_reset_gap_s: 600.0,
            reanchor_after: 3,
        }
    }
}

impl PlausibilityConfig {
    /// Checks the values; the error names the key.
    pub fn check(&self) -> Result<(), ConfigError> {
        let positive = [
            ("max_future_s", self.max_future_s),
            ("max_age_s", self.max_age_s),
            ("speed_margin", self.speed_margin),
            ("battery_reset_gap_s", self.battery_reset_gap_s),
        ];
        for (key, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(ConfigError::new(
                    format!("plausibility.{key}"),
                    format!("station.plausibility.{key} must be a positive number"),
                ));
            }
        }
        for (key, v) in [
            ("position_tolerance_m", self.position_tolerance_m),
            ("battery_tolerance_pct", self.battery_tolerance_pct),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(ConfigError::new(
                    format!("plausibility.{key}"),
                    format!("station.plausibility.{key} must be 0 or a positive number"),
                ));
            }
        }
        if self.reanchor_after == 0 {
            return Err(ConfigError::new(
                "plausibility.reanchor_after",
                "station.plausibility.reanchor_after must be at least 1",
            ));
        }
        Ok(())
    }
}

/// Why a state vector is implausible.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Implausible {
    /// Timestamp ahead of the station clock by more than `max_future_s`.
    TimestampFuture {
        /// Lead over the station clock, ms.
        ahead_ms: i64,
    },
    /// Timestamp older than `max_age_s`.
    TimestampPast {
        /// Age at arrival, ms.
        age_ms: i64,
    },
    /// Moved farther than the vehicle can since its last accepted state.
    PositionJump {
        /// Distance from the last accepted position, m.
        distance_m: f64,
        /// Largest distance the vehicle could have covered, m.
        allowed_m: f64,
    },
    /// Battery higher than in the last accepted state, without a reason to charge.
    BatteryRising {
        /// Last accepted level, %.
        from_pct: f64,
        /// This sample's level, %.
        to_pct: f64,
    },
}

impl Implausible {
    /// Reason code, as counted and quarantined (`implausible:<what>`).
    pub fn reason(&self) -> &'static str {
        match self {
            Self::TimestampFuture { .. } => "implausible:timestamp_future",
            Self::TimestampPast { .. } => "implausible:timestamp_past",
            Self::PositionJump { .. } => "implausible:position_jump",
            Self::BatteryRising { .. } => "implausible:battery_rising",
        }
    }

    /// True for checks against the previous sample, which a consistent run can override.
    fn is_relative(&self) -> bool {
        matches!(self, Self::PositionJump { .. } | Self::BatteryRising { .. })
    }
}

impl std::fmt::Display for Implausible {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        #[allow(clippy::cast_precision_loss)]
        match *self {
            Self::TimestampFuture { ahead_ms } => write!(
                f,
                "timestamp {:.1} s ahead of the station clock",
                ahead_ms as f64 / 1000.0
            ),
            Self::TimestampPast { age_ms } => {
                write!(f, "timestamp {:.0} s old", age_ms as f64 / 1000.0)
            }
            Self::PositionJump {
                distance_m,
                allowed_m,
            } => write!(
                f,
                "moved {distance_m:.0} m since the last accepted state; at most {allowed_m:.0} m possible"
            ),
            Self::BatteryRising { from_pct, to_pct } => {
                write!(
                    f,
                    "battery rose from {from_pct:.1} % to {to_pct:.1} % while not charging"
                )
            }
        }
    }
}

/// A vehicle's run of rejected-but-self-consistent samples.
#[derive(Debug, Clone, Default)]
pub(crate) struct Suspects {
    last: Option<StateVector>,
    count: u32,
}

/// What the pre-processor decided about one state vector.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Verdict {
    /// Plausible.
    Accept,
    /// Implausible against the previous state, but the latest of a consistent run: the
    /// vehicle is re-anchored on it.
    Reanchor(Implausible),
    /// Rejected.
    Reject(Implausible),
}

/// True when a vehicle sitting still at the surface may be on a charger.
fn may_be_charging(s: &StateVector) -> bool {
    s.depth_m <= 1.0 && s.speed_mps <= 0.2
}

/// The checks of `s` against the previous sample `prev` (older) of the same vehicle.
fn relative(
    cfg: &PlausibilityConfig,
    prev: &StateVector,
    s: &StateVector,
    max_speed_mps: f64,
) -> Option<Implausible> {
    let dt_ms = s.timestamp_ms - prev.timestamp_ms;
    if dt_ms <= 0 {
        // Late or duplicate delivery: an older sample says nothing about a newer one.
        return None;
    }
    #[allow(clippy::cast_precision_loss)]
    let dt_s = dt_ms as f64 / 1000.0;
    let distance_m = geo::distance_m(
        prev.latitude_deg,
        prev.longitude_deg,
        s.latitude_deg,
        s.longitude_deg,
    );
    let allowed_m = max_speed_mps * cfg.speed_margin * dt_s + cfg.position_tolerance_m;
    if distance_m > allowed_m {
        return Some(Implausible::PositionJump {
            distance_m,
            allowed_m,
        });
    }
    let known = prev.battery_pct != UNKNOWN && s.battery_pct != UNKNOWN;
    if known
        && s.battery_pct > prev.battery_pct + cfg.battery_tolerance_pct
        && dt_s < cfg.battery_reset_gap_s
        && !(may_be_charging(prev) && may_be_charging(s))
    {
        return Some(Implausible::BatteryRising {
            from_pct: prev.battery_pct,
            to_pct: s.battery_pct,
        });
    }
    None
}

/// The clock checks alone, for data other than state vectors.
pub(crate) fn check_time(
    cfg: &PlausibilityConfig,
    timestamp_ms: i64,
    now_ms: i64,
) -> Option<Implausible> {
    if !cfg.enabled {
        return None;
    }
    #[allow(clippy::cast_possible_truncation)]
    let (future_ms, age_ms) = (
        (cfg.max_future_s * 1000.0) as i64,
        (cfg.max_age_s * 1000.0) as i64,
    );
    if timestamp_ms - now_ms > future_ms {
        Some(Implausible::TimestampFuture {
            ahead_ms: timestamp_ms - now_ms,
        })
    } else if now_ms - timestamp_ms > age_ms {
        Some(Implausible::TimestampPast {
            age_ms: now_ms - timestamp_ms,
        })
    } else {
        None
    }
}

/// Judges `s` at station time `now_ms`, given the vehicle's last accepted state and its
/// maximum speed; updates the vehicle's run of suspects.
pub(crate) fn judge(
    cfg: &PlausibilityConfig,
    last: Option<&StateVector>,
    suspects: &mut Suspects,
    s: &StateVector,
    max_speed_mps: f64,
    now_ms: i64,
) -> Verdict {
    if !cfg.enabled {
        return Verdict::Accept;
    }
    if let Some(why) = check_time(cfg, s.timestamp_ms, now_ms) {
        return Verdict::Reject(why);
    }
    let Some(finding) = last.and_then(|p| relative(cfg, p, s, max_speed_mps)) else {
        *suspects = Suspects::default();
        return Verdict::Accept;
    };
    debug_assert!(finding.is_relative());
    let continues = suspects.last.as_ref().is_some_and(|p| {
        p.timestamp_ms < s.timestamp_ms && relative(cfg, p, s, max_speed_mps).is_none()
    });
    suspects.count = if continues { suspects.count + 1 } else { 1 };
    suspects.last = Some(s.clone());
    if suspects.count >= cfg.reanchor_after {
        *suspects = Suspects::default();
        Verdict::Reanchor(finding)
    } else {
        Verdict::Reject(finding)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const T0: i64 = 1_800_000_000_000;

    fn state(t_s: i64, lat: f64, lon: f64, battery: f64) -> StateVector {
        StateVector {
            vehicle_id: "auv1".into(),
            timestamp_ms: T0 + t_s * 1000,
            latitude_deg: lat,
            longitude_deg: lon,
            depth_m: 20.0,
            altitude_m: UNKNOWN,
            speed_mps: 1.5,
            yaw_deg: 90.0,
            pitch_deg: 0.0,
            roll_deg: 0.0,
            battery_pct: battery,
        }
    }

    fn judge_at(last: Option<&StateVector>, suspects: &mut Suspects, s: &StateVector) -> Verdict {
        judge(
            &PlausibilityConfig::default(),
            last,
            suspects,
            s,
            2.0,
            s.timestamp_ms + 100,
        )
    }

    #[test]
    fn normal_motion_is_accepted() {
        let a = state(0, 43.0, 5.0, 80.0);
        // 0.0001° of longitude at 43° N ≈ 8 m in 1 s: within 2 m/s × 1.5 + 50 m.
        let b = state(1, 43.0, 5.0001, 79.9);
        assert_eq!(
            judge_at(Some(&a), &mut Suspects::default(), &b),
            Verdict::Accept
        );
    }

    #[test]
    fn a_jump_beyond_max_speed_is_rejected_with_its_distance() {
        let a = state(0, 43.0, 5.0, 80.0);
        let b = state(10, 43.01, 5.0, 80.0); // 1.1 km in 10 s
        match judge_at(Some(&a), &mut Suspects::default(), &b) {
            Verdict::Reject(Implausible::PositionJump {
                distance_m,
                allowed_m,
            }) => {
                assert!((distance_m - 1112.0).abs() < 5.0, "{distance_m}");
                assert!((allowed_m - 80.0).abs() < 1e-9, "{allowed_m}");
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn a_long_gap_allows_a_long_way() {
        let a = state(0, 43.0, 5.0, 80.0);
        let b = state(1000, 43.01, 5.0, 79.0); // 1.1 km in 1000 s at ≤ 3 m/s
        assert_eq!(
            judge_at(Some(&a), &mut Suspects::default(), &b),
            Verdict::Accept
        );
    }

    #[test]
    fn battery_rising_is_rejected_unless_charging_or_after_a_long_gap() {
        let a = state(0, 43.0, 5.0, 50.0);
        let b = state(5, 43.0, 5.0, 60.0);
        assert_eq!(
            judge_at(Some(&a), &mut Suspects::default(), &b),
            Verdict::Reject(Implausible::BatteryRising {
                from_pct: 50.0,
                to_pct: 60.0
            })
        );
        // Within gauge noise.
        let c = state(5, 43.0, 5.0, 51.5);
        assert_eq!(
            judge_at(Some(&a), &mut Suspects::default(), &c),
            Verdict::Accept
        );
        // Still at the surface: on a charger.
        let (mut a2, mut b2) = (a.clone(), b);
        for s in [&mut a2, &mut b2] {
            s.depth_m = 0.0;
            s.speed_mps = 0.0;
        }
        assert_eq!(
            judge_at(Some(&a2), &mut Suspects::default(), &b2),
            Verdict::Accept
        );
        // Silent for 20 minutes: the battery may have been swapped.
        let d = state(1200, 43.0, 5.0, 95.0);
        assert_eq!(
            judge_at(Some(&a), &mut Suspects::default(), &d),
            Verdict::Accept
        );
        // Unknown levels are never compared.
        let e = state(5, 43.0, 5.0, UNKNOWN);
        assert_eq!(
            judge_at(Some(&a), &mut Suspects::default(), &e),
            Verdict::Accept
        );
    }

    #[test]
    fn timestamps_far_ahead_or_behind_the_station_clock_are_rejected() {
        let cfg = PlausibilityConfig::default();
        let s = state(0, 43.0, 5.0, 50.0);
        let mut sus = Suspects::default();
        assert_eq!(
            judge(&cfg, None, &mut sus, &s, 2.0, s.timestamp_ms - 60_000),
            Verdict::Reject(Implausible::TimestampFuture { ahead_ms: 60_000 })
        );
        assert_eq!(
            judge(&cfg, None, &mut sus, &s, 2.0, s.timestamp_ms + 7_200_000),
            Verdict::Reject(Implausible::TimestampPast { age_ms: 7_200_000 })
        );
        // A few seconds of skew and acoustic delays of minutes are normal.
        assert_eq!(
            judge(&cfg, None, &mut sus, &s, 2.0, s.timestamp_ms - 5_000),
            Verdict::Accept
        );
        assert_eq!(
            judge(&cfg, None, &mut sus, &s, 2.0, s.timestamp_ms + 600_000),
            Verdict::Accept
        );
    }

    #[test]
    fn a_consistent_run_after_a_jump_reanchors_the_vehicle() {
        let a = state(0, 43.0, 5.0, 80.0);
        let mut sus = Suspects::default();
        // A surfacing AUV's GPS fix 1 km from its dead-reckoned track, then steady fixes.
        let fixes: Vec<_> = (1..=3)
            .map(|i| state(i, 43.009, 5.0 + 0.00001 * f64::from(i as i32), 80.0))
            .collect();
        assert!(matches!(
            judge_at(Some(&a), &mut sus, &fixes[0]),
            Verdict::Reject(Implausible::PositionJump { .. })
        ));
        assert!(matches!(
            judge_at(Some(&a), &mut sus, &fixes[1]),
            Verdict::Reject(Implausible::PositionJump { .. })
        ));
        assert!(matches!(
            judge_at(Some(&a), &mut sus, &fixes[2]),
            Verdict::Reanchor(Implausible::PositionJump { .. })
        ));
    }

    #[test]
    fn scattered_outliers_never_reanchor() {
        let a = state(0, 43.0, 5.0, 80.0);
        let mut sus = Suspects::default();
        for i in 1..=10 {
            // Alternating wild fixes, inconsistent with each other.
            let lat = if i % 2 == 0 { 43.02 } else { 42.98 };
            let v = judge_at(Some(&a), &mut sus, &state(i, lat, 5.0, 80.0));
            assert!(matches!(v, Verdict::Reject(_)), "{i}: {v:?}");
        }
    }

    #[test]
    fn late_samples_are_not_compared_with_newer_ones() {
        let newer = state(10, 43.0, 5.0, 50.0);
        let older = state(0, 43.05, 5.0, 70.0);
        assert_eq!(
            judge_at(Some(&newer), &mut Suspects::default(), &older),
            Verdict::Accept
        );
    }

    #[test]
    fn disabled_accepts_everything() {
        let cfg = PlausibilityConfig {
            enabled: false,
            ..PlausibilityConfig::default()
        };
        let s = state(0, 43.0, 5.0, 50.0);
        assert_eq!(
            judge(&cfg, None, &mut Suspects::default(), &s, 2.0, 0),
            Verdict::Accept
        );
    }

    #[test]
    fn config_errors_name_the_key() {
        let bad = PlausibilityConfig {
            speed_margin: 0.0,
            ..PlausibilityConfig::default()
        };
        assert!(
            bad.check()
                .unwrap_err()
                .to_string()
                .contains("speed_margin")
        );
        let bad = PlausibilityConfig {
            reanchor_after: 0,
            ..PlausibilityConfig::default()
        };
        assert!(
            bad.check()
                .unwrap_err()
                .to_string()
                .contains("reanchor_after")
        );
        assert!(PlausibilityConfig::default().check().is_ok());
    }
}
