//! Shoal's configuration: defaults → file (`--config` / `SHOAL_CONFIG`) → environment
//! (`SHOAL_<SECTION>__<KEY>`) → command-line flags.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use serde::{Deserialize, Serialize};
use shoal_console::ConsoleConfig;
use shoal_dds::DdsConfig;
use shoal_history::HistoryConfig;
use shoal_model::VehicleKind;
use shoal_proxy::sim::{SimSettings, SimSpec};
use shoal_station::StationConfig;

/// The commented default configuration, kept in the repository; a test parses it so it
/// cannot drift from the code.
pub const DEFAULT_CONFIG: &str = include_str!("../../../config/shoal.toml");

/// Every section of Shoal's configuration.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ShoalConfig {
    /// DDS participant.
    pub dds: DdsConfig,
    /// Station core.
    pub station: StationConfig,
    /// History store.
    pub history: HistoryConfig,
    /// HTTP API.
    pub console: ConsoleConfig,
    /// Message authentication and access control on IP links.
    pub security: SecurityConfig,
    /// The simulated fleet `shoal up` starts.
    pub fleet: FleetConfig,
}

/// The `[security]` section.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SecurityConfig {
    /// Sign every sample on Shoal's topics and drop what does not verify.
    pub enabled: bool,
    /// The station's key store (`shoal keys init`).
    pub store: PathBuf,
    /// A vehicle's bundle (`shoal keys export`).
    pub bundle: PathBuf,
    /// Publish access policy file; empty for the built-in policy.
    pub policy: PathBuf,
    /// Oldest signed sample accepted, seconds.
    pub max_age_s: u32,
    /// How far ahead of this host's clock a signed sample may be, seconds.
    pub max_future_s: u32,
    /// Seconds between re-reads of the revocation list at the station.
    pub crl_check_s: u32,
}

impl Default for SecurityConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            store: PathBuf::from("shoal-data/keys"),
            bundle: PathBuf::new(),
            policy: PathBuf::new(),
            max_age_s: 30,
            max_future_s: 5,
            crl_check_s: 5,
        }
    }
}

impl SecurityConfig {
    /// Checks the values; the error names the key.
    pub fn check(&self) -> Result<(), String> {
        if !(1..=3600).contains(&self.max_age_s) {
            return Err(format!(
                "security.max_age_s = {} is outside [1, 3600]",
                self.max_age_s
            ));
        }
        if self.max_future_s > 600 {
            return Err(format!(
                "security.max_future_s = {} is above 600",
                self.max_future_s
            ));
        }
        if !(1..=3600).contains(&self.crl_check_s) {
            return Err(format!(
                "security.crl_check_s = {} is outside [1, 3600]",
                self.crl_check_s
            ));
        }
        Ok(())
    }
}

/// The `[fleet]` section: simulated vehicles for `shoal up`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FleetConfig {
    /// Also start the acoustic demo: a submerged AUV (auv-ac1) heard only through an
    /// emulated acoustic link, relayed by a CDT on the surface, as in the SWARMs sea trial.
    pub acoustic_demo: bool,
    /// How every simulated vehicle behaves: battery reserve, low-battery warning,
    /// detections, environment sampling.
    pub sim: SimSettings,
    /// One entry per vehicle on IP.
    pub vehicles: Vec<SimSpec>,
}

impl FleetConfig {
    /// Checks the simulator settings; the error names the key.
    pub fn check(&self) -> Result<(), String> {
        let s = &self.sim;
        for (key, v, lo, hi) in [
            ("reserve_pct", s.reserve_pct, 0.0, 100.0),
            ("low_battery_pct", s.low_battery_pct, 0.0, 100.0),
            (
                "low_battery_hysteresis_pct",
                s.low_battery_hysteresis_pct,
                0.0,
                100.0,
            ),
            ("detection_per_s", s.detection_per_s, 0.0, 1.0),
            ("environment_hz", s.environment_hz, 0.0, 10.0),
        ] {
            if !(v.is_finite() && (lo..=hi).contains(&v)) {
                return Err(format!("fleet.sim.{key} = {v} is outside [{lo}, {hi}]"));
            }
        }
        Ok(())
    }
}

impl Default for FleetConfig {
    fn default() -> Self {
        // Off Trondheim, where the SWARMs project ran its Norwegian sea trials.
        let v = |id: &str, kind, lat, lon| SimSpec {
            id: id.into(),
            kind,
            latitude_deg: lat,
            longitude_deg: lon,
            rate_hz: 1.0,
            battery_pct: 100.0,
        };
        Self {
            acoustic_demo: true,
            sim: SimSettings::default(),
            vehicles: vec![
                v("auv-1", VehicleKind::Auv, 63.4650, 10.3700),
                v("auv-2", VehicleKind::Auv, 63.4660, 10.3750),
                v("usv-1", VehicleKind::Usv, 63.4640, 10.3800),
                v("rov-1", VehicleKind::Rov, 63.4630, 10.3650),
            ],
        }
    }
}

/// Loads the configuration: `path` (or `SHOAL_CONFIG`) if given, then environment overrides.
pub fn load(path: Option<&Path>) -> Result<ShoalConfig> {
    let env_path = std::env::var_os("SHOAL_CONFIG").map(PathBuf::from);
    let path = path.map(Path::to_path_buf).or(env_path);
    let mut table = match &path {
        Some(p) => {
            let text = std::fs::read_to_string(p)
                .with_context(|| format!("cannot read config file {}", p.display()))?;
            parse_table(&text).with_context(|| format!("config file {}", p.display()))?
        }
        None => toml::Table::new(),
    };
    apply_env(&mut table, std::env::vars())?;
    from_table(table)
}

fn parse_table(text: &str) -> Result<toml::Table> {
    text.parse::<toml::Table>().map_err(|e| {
        // toml's message spans several lines with a source excerpt; keep one line.
        let line = e
            .span()
            .map(|s| text[..s.start.min(text.len())].matches('\n').count() + 1)
            .map_or_else(String::new, |l| format!("line {l}: "));
        anyhow::anyhow!("{line}{}", e.message())
    })
}

/// Applies `SHOAL_<SECTION>__<KEY>=value` overrides; values are TOML when they parse as
/// TOML (numbers, booleans, arrays), strings otherwise.
fn apply_env(table: &mut toml::Table, vars: impl Iterator<Item = (String, String)>) -> Result<()> {
    for (name, raw) in vars {
        let Some(rest) = name.strip_prefix("SHOAL_") else {
            continue;
        };
        let Some((section, key)) = rest.split_once("__") else {
            continue;
        };
        let (section, key) = (section.to_ascii_lowercase(), key.to_ascii_lowercase());
        if section.is_empty() || key.is_empty() {
            bail!("environment variable {name}: expected SHOAL_<SECTION>__<KEY>");
        }
        let value = format!("v = {raw}")
            .parse::<toml::Table>()
            .ok()
            .and_then(|mut t| t.remove("v"))
            .unwrap_or(toml::Value::String(raw));
        let entry = table
            .entry(section.clone())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        let Some(sec) = entry.as_table_mut() else {
            bail!("environment variable {name}: [{section}] is not a section");
        };
        sec.insert(key, value);
    }
    Ok(())
}

fn from_table(table: toml::Table) -> Result<ShoalConfig> {
    let config: ShoalConfig =
        serde_path_to_error::deserialize(toml::Value::Table(table)).map_err(|e| {
            // toml appends the key on a second line; the path is already in front.
            let inner = e.inner().to_string();
            let first = inner.lines().next().unwrap_or_default().to_string();
            anyhow::anyhow!("invalid configuration at `{}`: {first}", e.path())
        })?;
    config
        .station
        .check()
        .map_err(|e| anyhow::anyhow!("invalid configuration: {e}"))?;
    config
        .history
        .check()
        .map_err(|e| anyhow::anyhow!("invalid configuration in [history]: {e}"))?;
    config
        .security
        .check()
        .map_err(|e| anyhow::anyhow!("invalid configuration: {e}"))?;
    config
        .fleet
        .check()
        .map_err(|e| anyhow::anyhow!("invalid configuration: {e}"))?;
    Ok(config)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn the_shipped_default_config_parses_and_equals_the_built_in_defaults() {
        let parsed = from_table(parse_table(DEFAULT_CONFIG).unwrap()).unwrap();
        assert_eq!(parsed, ShoalConfig::default());
    }

    #[test]
    fn an_older_file_with_the_retired_same_host_loopback_key_still_loads() {
        let parsed =
            from_table(parse_table("[dds]\nsame_host_loopback = true\n").unwrap()).unwrap();
        assert_eq!(parsed.dds.same_host_loopback, Some(true));
        assert!(from_table(parse_table("[dds]\nsame_host_loopback = 3\n").unwrap()).is_err());
    }

    #[test]
    fn an_older_file_with_the_retired_lost_contact_factor_still_loads() {
        let text = "[station.semantic]\nlost_contact_factor = 5.0\n";
        let parsed = from_table(parse_table(text).unwrap()).unwrap();
        assert_eq!(
            parsed.station.semantic.retired_keys(),
            ["lost_contact_factor"]
        );
        let bad = "[station.semantic]\nlost_contact_factor = 0.5\n";
        assert!(from_table(parse_table(bad).unwrap()).is_err());
    }

    #[test]
    fn environment_overrides_the_file() {
        let mut t = parse_table("[dds]\ndomain_id = 3\n").unwrap();
        let vars = [
            ("SHOAL_DDS__DOMAIN_ID".to_string(), "7".to_string()),
            (
                "SHOAL_CONSOLE__LISTEN".to_string(),
                "127.0.0.1:9999".to_string(),
            ),
            ("UNRELATED".to_string(), "x".to_string()),
        ];
        apply_env(&mut t, vars.into_iter()).unwrap();
        let c = from_table(t).unwrap();
        assert_eq!(c.dds.domain_id, 7);
        assert_eq!(c.console.listen.port(), 9999);
    }

    #[test]
    fn a_bad_value_gives_one_line_naming_the_key() {
        let e = from_table(parse_table("[dds]\ndomain_id = \"seven\"\n").unwrap())
            .unwrap_err()
            .to_string();
        assert!(e.contains("dds.domain_id"), "{e}");
        assert!(!e.contains('\n'), "{e}");
    }

    #[test]
    fn an_unknown_key_is_named() {
        let e = from_table(parse_table("[station]\nstale_after = 3\n").unwrap())
            .unwrap_err()
            .to_string();
        assert!(e.contains("stale_after"), "{e}");
    }

    #[test]
    fn a_syntax_error_names_the_line() {
        let e = parse_table("[dds]\ndomain_id = = 3\n")
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("line 2"), "{e}");
    }

    #[test]
    fn inconsistent_values_are_explained() {
        let e =
            from_table(parse_table("[station]\nstale_after_s = 10\nlost_after_s = 5\n").unwrap())
                .unwrap_err()
                .to_string();
        assert!(e.contains("station.lost_after_s"), "{e}");
        let e = from_table(
            parse_table(
                "[station.semantic]\noperating_area = [{ latitude_deg = 1.0, longitude_deg = 2.0 }]\n",
            )
            .unwrap(),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("station.semantic: operating_area"), "{e}");
        let e = from_table(parse_table("[security]\nmax_age_s = 0\n").unwrap())
            .unwrap_err()
            .to_string();
        assert!(e.contains("security.max_age_s"), "{e}");
    }

    #[test]
    fn an_operating_area_in_the_file_reaches_the_semantic_model() {
        let c = from_table(
            parse_table(
                "[station.semantic]\noperating_area = [\n { latitude_deg = 63.4, longitude_deg = 10.2 },\n { latitude_deg = 63.4, longitude_deg = 10.5 },\n { latitude_deg = 63.5, longitude_deg = 10.5 },\n]\n",
            )
            .unwrap(),
        )
        .unwrap();
        assert_eq!(c.station.semantic.operating_area.len(), 3);
    }
}
