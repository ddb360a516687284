//! [`StoreConfig`]: the store's tuning, readable from the station's TOML configuration.
//!
//! Every field has a default, so a TOML section only lists what it changes; unknown keys
//! are refused (a misspelt key would otherwise silently keep its default). The operating
//! area is a list of `{ latitude_deg, longitude_deg }` tables:
//!
//! ```toml
//! [station.semantic]
//! min_state_interval_ms = 1000
//! operating_area = [
//!     { latitude_deg = 43.0, longitude_deg = 5.8 },
//!     { latitude_deg = 43.0, longitude_deg = 6.0 },
//!     { latitude_deg = 43.2, longitude_deg = 6.0 },
//! ]
//! ```
//!
//! Deserialising checks syntax only; [`StoreConfig::check`] checks values and
//! [`crate::SemanticStore::new`] calls it.

use serde::{Deserialize, Serialize};
use shoal_model::GeoPoint;

/// Tuning of the store; `Default` gives the values documented on each field.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StoreConfig {
    /// Least time between two RDF mirrors of one vehicle's state, ms; 0 mirrors every
    /// state (default 1000).
    pub min_state_interval_ms: i64,
    /// Events kept in the RDF model, oldest dropped first (default 10 000; history keeps all).
    pub max_events: usize,
    /// Expected state period of a vehicle not told otherwise, ms (default 1000).
    pub expected_state_period_ms: i64,
    /// Retired and ignored. It set the missed periods of the built-in lost-contact rule,
    /// which is gone (the station's Vehicle Register owns contact and raises its own
    /// CommLost alarm). Still accepted, and range-checked (finite, >= 1), so that older
    /// configuration files load; [`StoreConfig::retired_keys`] names it so the station
    /// can warn. Default: absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lost_contact_factor: Option<f64>,
    /// Built-in low-battery rule: threshold in percent (default 20).
    pub low_battery_pct: f64,
    /// Deadline of a task after it was issued, ms (default 1 h); hold tasks add their duration.
    pub task_deadline_ms: i64,
    /// Operating area for the built-in out-of-area rule, at least 3 corners; empty = no
    /// such rule (default).
    #[serde(with = "area")]
    pub operating_area: Vec<GeoPoint>,
    /// Longest a SPARQL rule may take to evaluate on one insert, ms (default 50): rules run
    /// while the model is locked, so a rule over budget is cancelled, disabled, and an
    /// event says so; ingest goes on.
    pub rule_budget_ms: u64,
    /// Built-in collision-risk rule: a surface vehicle's closest point of approach to an
    /// AIS target under this many metres raises an alarm (default 500).
    pub collision_cpa_m: f64,
    /// ... when that closest approach is at most this many seconds ahead (default 600).
    pub collision_tcpa_s: f64,
}

impl Default for StoreConfig {
    fn default() -> Self {
        Self {
            min_state_interval_ms: 1000,
            max_events: 10_000,
            expected_state_period_ms: 1000,
            lost_contact_factor: None,
            low_battery_pct: 20.0,
            task_deadline_ms: 3_600_000,
            operating_area: Vec::new(),
            rule_budget_ms: 50,
            collision_cpa_m: 500.0,
            collision_tcpa_s: 600.0,
        }
    }
}

/// Why a [`StoreConfig`] cannot be used; names the offending field.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ConfigError {
    /// A value outside its accepted range.
    #[error("{field} must be {expected}, got {value}")]
    OutOfRange {
        /// The field, as spelt in TOML.
        field: &'static str,
        /// What is accepted, e.g. `> 0`.
        expected: &'static str,
        /// The value found.
        value: String,
    },
    /// The operating area has corners but too few to enclose anything.
    #[error("operating_area needs at least 3 corners (or none to disable the rule), got {0}")]
    AreaTooSmall(usize),
    /// A corner of the operating area is not a valid WGS84 position.
    #[error("operating_area[{index}]: {field} = {value} is outside {range}")]
    BadCorner {
        /// Index of the corner in the list.
        index: usize,
        /// `latitude_deg` or `longitude_deg`.
        field: &'static str,
        /// The value found.
        value: f64,
        /// The accepted range.
        range: &'static str,
    },
}

fn out_of_range(
    field: &'static str,
    expected: &'static str,
    value: &dyn std::fmt::Display,
) -> ConfigError {
    ConfigError::OutOfRange {
        field,
        expected,
        value: value.to_string(),
    }
}

impl StoreConfig {
    /// The retired keys this configuration sets (they have no effect), as spelt in TOML,
    /// so that the caller can warn about them.
    pub fn retired_keys(&self) -> Vec<&'static str> {
        let mut keys = Vec::new();
        if self.lost_contact_factor.is_some() {
            keys.push("lost_contact_factor");
        }
        keys
    }

    /// Checks every value; the first problem found is returned.
    pub fn check(&self) -> Result<(), ConfigError> {
        // 0 would disable every rule at its first evaluation.
        if !(1..=60_000).contains(&self.rule_budget_ms) {
            return Err(out_of_range(
                "rule_budget_ms",
                "within [1, 60000]",
                &self.rule_budget_ms,
            ));
        }
        if self.min_state_interval_ms < 0 {
            return Err(out_of_range(
                "min_state_interval_ms",
                ">= 0",
                &self.min_state_interval_ms,
            ));
        }
        if self.expected_state_period_ms <= 0 {
            return Err(out_of_range(
                "expected_state_period_ms",
                "> 0",
                &self.expected_state_period_ms,
            ));
        }
        if self.task_deadline_ms <= 0 {
            return Err(out_of_range(
                "task_deadline_ms",
                "> 0",
                &self.task_deadline_ms,
            ));
        }
        // Ignored, but still checked: a value the old rule refused is a mistake in the
        // file, better named than carried silently.
        if let Some(factor) = self.lost_contact_factor
            && !(factor.is_finite() && factor >= 1.0)
        {
            return Err(out_of_range(
                "lost_contact_factor",
                "finite and >= 1",
                &factor,
            ));
        }
        if !(0.0..=100.0).contains(&self.low_battery_pct) {
            return Err(out_of_range(
                "low_battery_pct",
                "within [0, 100]",
                &self.low_battery_pct,
            ));
        }
        if !(self.collision_cpa_m.is_finite() && self.collision_cpa_m > 0.0) {
            return Err(out_of_range(
                "collision_cpa_m",
                "finite and > 0",
                &self.collision_cpa_m,
            ));
        }
        if !(self.collision_tcpa_s.is_finite() && self.collision_tcpa_s > 0.0) {
            return Err(out_of_range(
                "collision_tcpa_s",
                "finite and > 0",
                &self.collision_tcpa_s,
            ));
        }
        let n = self.operating_area.len();
        if n > 0 && n < 3 {
            return Err(ConfigError::AreaTooSmall(n));
        }
        for (index, p) in self.operating_area.iter().enumerate() {
            for (field, value, limit, range) in [
                ("latitude_deg", p.latitude_deg, 90.0, "[-90, 90]"),
                ("longitude_deg", p.longitude_deg, 180.0, "[-180, 180]"),
            ] {
                // NaN fails `contains`, so it is reported like any other bad value.
                if !(-limit..=limit).contains(&value) {
                    return Err(ConfigError::BadCorner {
                        index,
                        field,
                        value,
                        range,
                    });
                }
            }
        }
        Ok(())
    }
}

/// Corners as `{ latitude_deg, longitude_deg }` tables that refuse unknown keys, which
/// `shoal_model::GeoPoint`'s own serde form does not.
mod area {
    use serde::{Deserialize, Deserializer, Serialize, Serializer};
    use shoal_model::GeoPoint;

    #[derive(Serialize, Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Corner {
        latitude_deg: f64,
        longitude_deg: f64,
    }

    pub(super) fn serialize<S: Serializer>(area: &[GeoPoint], s: S) -> Result<S::Ok, S::Error> {
        s.collect_seq(area.iter().map(|p| Corner {
            latitude_deg: p.latitude_deg,
            longitude_deg: p.longitude_deg,
        }))
    }

    pub(super) fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<GeoPoint>, D::Error> {
        Ok(Vec::<Corner>::deserialize(d)?
            .into_iter()
            .map(|c| GeoPoint {
                latitude_deg: c.latitude_deg,
                longitude_deg: c.longitude_deg,
            })
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn corner(latitude_deg: f64, longitude_deg: f64) -> GeoPoint {
        GeoPoint {
            latitude_deg,
            longitude_deg,
        }
    }

    #[test]
    fn the_default_is_valid() {
        assert_eq!(StoreConfig::default().check(), Ok(()));
    }

    #[test]
    fn a_toml_section_round_trips_and_missing_keys_take_their_default() {
        let text = r#"
            min_state_interval_ms = 500
            low_battery_pct = 15.0
            operating_area = [
                { latitude_deg = 43.0, longitude_deg = 5.8 },
                { latitude_deg = 43.0, longitude_deg = 6.0 },
                { latitude_deg = 43.2, longitude_deg = 6.0 },
            ]
        "#;
        let c: StoreConfig = toml::from_str(text).unwrap();
        assert_eq!(c.min_state_interval_ms, 500);
        assert_eq!(c.low_battery_pct, 15.0);
        assert_eq!(c.max_events, StoreConfig::default().max_events);
        assert_eq!(c.operating_area[2], corner(43.2, 6.0));
        assert_eq!(c.check(), Ok(()));
        let back: StoreConfig = toml::from_str(&toml::to_string(&c).unwrap()).unwrap();
        assert_eq!(back, c);
        let empty: StoreConfig = toml::from_str("").unwrap();
        assert_eq!(empty, StoreConfig::default());
    }

    #[test]
    fn unknown_keys_are_refused_at_every_level() {
        let e = toml::from_str::<StoreConfig>("max_event = 5").unwrap_err();
        assert!(e.to_string().contains("max_event"), "{e}");
        let e = toml::from_str::<StoreConfig>(
            "operating_area = [{ latitude_deg = 1.0, longitude_deg = 2.0, lat = 3.0 }]",
        )
        .unwrap_err();
        assert!(e.to_string().contains("lat"), "{e}");
    }

    #[test]
    fn bad_values_are_named() {
        let with = |f: fn(&mut StoreConfig)| {
            let mut c = StoreConfig::default();
            f(&mut c);
            c.check().unwrap_err().to_string()
        };
        assert_eq!(
            with(|c| c.expected_state_period_ms = 0),
            "expected_state_period_ms must be > 0, got 0"
        );
        assert!(with(|c| c.min_state_interval_ms = -1).starts_with("min_state_interval_ms"));
        assert!(with(|c| c.task_deadline_ms = -5).starts_with("task_deadline_ms"));
        assert!(with(|c| c.lost_contact_factor = Some(0.5)).starts_with("lost_contact_factor"));
        assert!(with(|c| c.low_battery_pct = f64::NAN).starts_with("low_battery_pct"));
        assert_eq!(
            with(|c| c.operating_area = vec![corner(43.0, 5.8); 2]),
            "operating_area needs at least 3 corners (or none to disable the rule), got 2"
        );
        assert_eq!(
            with(|c| c.operating_area =
                vec![corner(43.0, 5.8), corner(91.0, 6.0), corner(43.2, 6.0)]),
            "operating_area[1]: latitude_deg = 91 is outside [-90, 90]"
        );
        assert!(
            with(|c| c.operating_area =
                vec![corner(0.0, 0.0), corner(0.0, 1.0), corner(1.0, f64::NAN)])
            .starts_with("operating_area[2]: longitude_deg = NaN")
        );
    }

    #[test]
    fn the_retired_lost_contact_factor_still_loads_and_is_named() {
        let c: StoreConfig = toml::from_str("lost_contact_factor = 5.0").unwrap();
        assert_eq!(c.lost_contact_factor, Some(5.0));
        assert_eq!(c.check(), Ok(()));
        assert_eq!(c.retired_keys(), ["lost_contact_factor"]);
        assert!(StoreConfig::default().retired_keys().is_empty());
        // Absent, it is not written back either.
        let text = toml::to_string(&StoreConfig::default()).unwrap();
        assert!(!text.contains("lost_contact_factor"), "{text}");
        assert!(toml::from_str::<StoreConfig>("lost_contact_factor = \"five\"").is_err());
    }
}
