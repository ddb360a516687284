//! Configuration of the station core.

use crate::error::ConfigError;
use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::ingest::preprocess::PlausibilityConfig;

/// The `[station]` section of Shoal's configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StationConfig {
    /// Seconds without a state vector after which a vehicle is shown as stale.
    pub stale_after_s: f64,
    /// Seconds without a state vector after which a vehicle is lost (a CommLost alarm).
    pub lost_after_s: f64,
    /// Seconds between fleet summaries in the log (a line per vehicle up to 20, counts beyond; 0 = never).
    pub summary_interval_s: f64,
    /// Accept state vectors only from vehicles that announced themselves first.
    pub require_announcement: bool,
    /// Seconds a state vector from the bus may wait for its vehicle's announcement (DDS
    /// often delivers a starting vehicle's first state vector before it); unannounced
    /// after that, it is refused as `unknown_vehicle`. 0 refuses at once.
    pub announcement_grace_s: f64,
    /// Most recent events kept in memory for the API (older ones are in the history).
    pub recent_events: usize,
    /// The Data Pre-Processor's plausibility checks against each vehicle's history.
    pub plausibility: PlausibilityConfig,
    /// The semantic model: mirroring rate, built-in rule thresholds, the operating area.
    pub semantic: shoal_semantic::StoreConfig,
    /// Seconds a task sent over IP may wait for its vehicle's acknowledgement before it
    /// expires.
    pub task_ack_timeout_s: f64,
    /// The same for a task sent over the acoustic link (store-and-forward, retransmissions).
    pub acoustic_task_ack_timeout_s: f64,
    /// Times a task is sent again when the acoustic link could not deliver it within its
    /// TTL, before it expires.
    pub acoustic_task_retries: u32,
    /// Least battery, %, a vehicle needs to be given a task (surface, return home, abort and
    /// state requests are always allowed).
    pub min_dispatch_battery_pct: f64,
    /// Where user rules (and the enabled state of built-in ones) are kept across restarts.
    pub rules_path: PathBuf,
    /// Seconds an ended task (and an ended mission, with its tasks) stays in the Mission &
    /// Task Register and the semantic model; older ones live on in the history only.
    pub task_retention_s: f64,
    /// Most ended tasks kept in the register and the semantic model, whatever their age;
    /// beyond, the oldest go first (an ended mission with all its tasks).
    pub max_ended_tasks: usize,
    /// Most vehicles known by their announcement only (no state vector yet); a new
    /// vehicle's announcement beyond is refused and counted (a flood of made-up ids).
    pub max_unheard_vehicles: usize,
}

impl Default for StationConfig {
    fn default() -> Self {
        Self {
            stale_after_s: 5.0,
            lost_after_s: 30.0,
            summary_interval_s: 10.0,
            require_announcement: true,
            announcement_grace_s: 5.0,
            recent_events: 500,
            plausibility: PlausibilityConfig::default(),
            semantic: shoal_semantic::StoreConfig::default(),
            task_ack_timeout_s: 60.0,
            acoustic_task_ack_timeout_s: 900.0,
            acoustic_task_retries: 2,
            min_dispatch_battery_pct: 20.0,
            rules_path: PathBuf::from("shoal-data/rules.json"),
            task_retention_s: 24.0 * 3600.0,
            max_ended_tasks: 2000,
            max_unheard_vehicles: 10_000,
        }
    }
}

impl StationConfig {
    /// Checks the values make sense together; the error names the key.
    pub fn check(&self) -> Result<(), ConfigError> {
        if !(self.stale_after_s.is_finite() && self.stale_after_s > 0.0) {
            return Err(ConfigError::new(
                "stale_after_s",
                "station.stale_after_s must be a positive number of seconds",
            ));
        }
        if !(self.lost_after_s.is_finite() && self.lost_after_s >= self.stale_after_s) {
            return Err(ConfigError::new(
                "lost_after_s",
                "station.lost_after_s must be at least station.stale_after_s",
            ));
        }
        if !(self.summary_interval_s.is_finite() && self.summary_interval_s >= 0.0) {
            return Err(ConfigError::new(
                "summary_interval_s",
                "station.summary_interval_s must be 0 or a positive number",
            ));
        }
        if !(0.0..=60.0).contains(&self.announcement_grace_s) {
            return Err(ConfigError::new(
                "announcement_grace_s",
                "station.announcement_grace_s must be within [0, 60] seconds",
            ));
        }
        if !(self.task_ack_timeout_s.is_finite() && self.task_ack_timeout_s > 0.0) {
            return Err(ConfigError::new(
                "task_ack_timeout_s",
                "station.task_ack_timeout_s must be a positive number of seconds",
            ));
        }
        if !(self.acoustic_task_ack_timeout_s.is_finite() && self.acoustic_task_ack_timeout_s > 0.0)
        {
            return Err(ConfigError::new(
                "acoustic_task_ack_timeout_s",
                "station.acoustic_task_ack_timeout_s must be a positive number of seconds",
            ));
        }
        if !(self.task_retention_s.is_finite() && self.task_retention_s >= 60.0) {
            return Err(ConfigError::new(
                "task_retention_s",
                "station.task_retention_s must be at least 60 seconds",
            ));
        }
        if !(0.0..=100.0).contains(&self.min_dispatch_battery_pct) {
            return Err(ConfigError::new(
                "min_dispatch_battery_pct",
                "station.min_dispatch_battery_pct must be within [0, 100]",
            ));
        }
        self.semantic
            .check()
            .map_err(|e| ConfigError::new("semantic", format!("station.semantic: {e}")))?;
        self.plausibility.check()
    }
}

/// Seconds from the configuration as whole milliseconds (checked values are finite and
/// far below the range where the cast saturates).
#[allow(clippy::cast_possible_truncation)]
pub(crate) fn ms(seconds: f64) -> i64 {
    (seconds * 1000.0) as i64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_announcement_grace_is_checked_and_its_error_names_the_key() {
        assert!(StationConfig::default().check().is_ok());
        for bad in [-1.0, 61.0, f64::NAN, f64::INFINITY] {
            let c = StationConfig {
                announcement_grace_s: bad,
                ..StationConfig::default()
            };
            let e = c.check().unwrap_err();
            assert_eq!(e.key, "announcement_grace_s", "{bad}");
            assert!(e.to_string().contains("[0, 60]"), "{e}");
        }
        let off = StationConfig {
            announcement_grace_s: 0.0,
            ..StationConfig::default()
        };
        assert!(off.check().is_ok(), "0 refuses at once");
    }
}
