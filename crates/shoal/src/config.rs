//! Shoal's configuration: defaults → file (`--config` / `SHOAL_CONFIG`) → environment
//! (`SHOAL_<SECTION>__<KEY>`) → command-line flags.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use figment::error::{Kind, OneOf};
use figment::value::{Dict, Map, Value};
use figment::{Figment, Metadata, Profile, Provider};
use serde::{Deserialize, Serialize};
#[cfg(feature = "console")]
use shoal_console::ConsoleConfig;
use shoal_dds::DdsConfig;
#[cfg(feature = "console")]
use shoal_federation::FederationConfig;
#[cfg(feature = "console")]
use shoal_foxglove::BridgeConfig;
#[cfg(feature = "console")]
use shoal_history::HistoryConfig;
use shoal_model::VehicleKind;
use shoal_proxy::sim::{SimSettings, SimSpec};
use shoal_recorder::RecorderConfig;
#[cfg(feature = "console")]
use shoal_station::StationConfig;
#[cfg(feature = "console")]
use shoal_traffic::TrafficConfig;

/// A section of the station side in a build without it (no `console` feature): kept as
/// read, unchecked, so one configuration file serves the station and its vehicles.
#[cfg(not(feature = "console"))]
pub type StationSide = toml::Table;
#[cfg(not(feature = "console"))]
type StationConfig = StationSide;
#[cfg(not(feature = "console"))]
type HistoryConfig = StationSide;
#[cfg(not(feature = "console"))]
type ConsoleConfig = StationSide;
#[cfg(not(feature = "console"))]
type TrafficConfig = StationSide;
#[cfg(not(feature = "console"))]
type BridgeConfig = StationSide;
#[cfg(not(feature = "console"))]
type FederationConfig = StationSide;

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
    /// What a vehicle (`shoal vehicle`, or one of `shoal up`'s fleet) keeps across restarts.
    pub vehicle: VehicleConfig,
    /// The station's AIS and NMEA 0183 inputs (vessel traffic on the map, collision risk).
    pub traffic: TrafficConfig,
    /// The Foxglove live bridge.
    pub foxglove: BridgeConfig,
    /// The station's own MCAP recorder (`shoal record` is the same, as a process).
    pub recorder: RecorderConfig,
    /// Ship ↔ shore federation with other stations over Zenoh.
    pub federation: FederationConfig,
}

/// The `[vehicle]` section.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VehicleConfig {
    /// Directory of each vehicle's task ledger (`<id>.tasks.json`): which tasks it started
    /// and how they ended, so no restart makes it run a task twice.
    pub state_dir: PathBuf,
    /// Seconds after which a task that carries no expiry of its own is refused as too old.
    pub max_task_age_s: u32,
}

impl Default for VehicleConfig {
    fn default() -> Self {
        Self {
            state_dir: PathBuf::from("shoal-data/vehicles"),
            max_task_age_s: 900,
        }
    }
}

impl VehicleConfig {
    /// Checks the values; the error names the key.
    pub fn check(&self) -> Result<(), String> {
        if self.state_dir.as_os_str().is_empty() {
            return Err("vehicle.state_dir must name a directory".into());
        }
        if !(1..=86_400).contains(&self.max_task_age_s) {
            return Err(format!(
                "vehicle.max_task_age_s = {} is outside [1, 86400]",
                self.max_task_age_s
            ));
        }
        Ok(())
    }
}

/// The `[security]` section.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SecurityConfig {
    /// OMG DDS Security on IP links (authenticated, access-controlled, encrypted) and
    /// HMAC tags on acoustic frames. On by default; `--insecure` turns it off.
    pub enabled: bool,
    /// The station's key store (`shoal keys init`; `shoal up` and `shoal station` create
    /// it on first run).
    pub store: PathBuf,
    /// A vehicle's bundle (`shoal keys export`); empty: a vehicle on the station's host
    /// takes its credentials from `store`.
    pub bundle: PathBuf,
    /// Seconds between re-reads of the revocation list at the station.
    pub crl_check_s: u32,
    /// Let `shoal station` run with security off on interfaces other than loopback (lab
    /// work with unmodified third-party vehicles). Off: it refuses to.
    pub allow_insecure_network: bool,
    /// Which topics the governance document encrypts, signs or leaves open (applied when
    /// the key store is created, or by `shoal keys governance`).
    pub governance: shoal_security::dds::GovernanceOptions,
}

impl Default for SecurityConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            store: PathBuf::from("shoal-data/keys"),
            bundle: PathBuf::new(),
            crl_check_s: 5,
            allow_insecure_network: false,
            governance: shoal_security::dds::GovernanceOptions::default(),
        }
    }
}

impl SecurityConfig {
    /// Checks the values; the error names the key.
    pub fn check(&self) -> Result<(), String> {
        // A topic expression that names no Shoal topic (a typo) would leave the topic it
        // meant under the default protection without a word.
        for expression in self.governance.topics.keys() {
            let pattern = glob::Pattern::new(expression).map_err(|e| {
                format!("security.governance.topics: {expression:?} is not a topic expression: {e}")
            })?;
            if !shoal_dds::ALL_TOPICS
                .iter()
                .any(|(topic, _)| pattern.matches(topic))
            {
                let known: Vec<&str> = shoal_dds::ALL_TOPICS.iter().map(|(t, _)| *t).collect();
                return Err(format!(
                    "security.governance.topics: {expression:?} matches no topic (topics: {})",
                    known.join(", ")
                ));
            }
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

/// The values given on the command line, the last layer (`shoal station --listen/--db`).
#[derive(Debug, Clone, Default)]
pub struct Flags {
    /// `--listen`: `console.listen`.
    #[cfg(feature = "console")]
    pub listen: Option<std::net::SocketAddr>,
    /// `--db`: `history.path`.
    #[cfg(feature = "console")]
    pub db: Option<PathBuf>,
}

impl Flags {
    /// Each flag given: its name, the key it sets and the value.
    fn given(&self) -> Result<Vec<(&'static str, &'static str, Value)>> {
        #[allow(unused_mut)] // Without the station, no flag sets a configuration key.
        let mut given = Vec::new();
        #[cfg(feature = "console")]
        {
            if let Some(l) = self.listen {
                given.push(("--listen", "console.listen", Value::from(l.to_string())));
            }
            if let Some(db) = &self.db {
                given.push(("--db", "history.path", Value::serialize(db)?));
            }
        }
        Ok(given)
    }
}

/// Loads the configuration: defaults, then the file `path` (or `SHOAL_CONFIG`), then the
/// `SHOAL_<SECTION>__<KEY>` environment variables, then `flags`.
pub fn load(path: Option<&Path>, flags: &Flags) -> Result<ShoalConfig> {
    let env_path = std::env::var_os("SHOAL_CONFIG").map(PathBuf::from);
    let path = path.map(Path::to_path_buf).or(env_path);
    let mut env = Vec::new();
    for (name, value) in std::env::vars_os() {
        // Only Shoal's own variables need be text; other programs' may be anything.
        let Some(name) = name.to_str().filter(|n| n.starts_with(ENV_PREFIX)) else {
            continue;
        };
        let Some(value) = value.to_str() else {
            bail!("environment variable {name}: the value is not UTF-8");
        };
        env.push((name.to_string(), value.to_string()));
    }
    load_from(path.as_deref(), env, flags)
}

/// [`load`] with the environment given: what the tests call.
fn load_from(
    path: Option<&Path>,
    env: impl IntoIterator<Item = (String, String)>,
    flags: &Flags,
) -> Result<ShoalConfig> {
    // Defaults are the serde defaults of the types (every struct is `#[serde(default)]`),
    // so a layer needs to hold only what it changes.
    let mut figment = Figment::new();
    if let Some(p) = path {
        let text = std::fs::read_to_string(p)
            .with_context(|| format!("cannot read config file {}", p.display()))?;
        let table = parse_table(&text).with_context(|| format!("config file {}", p.display()))?;
        figment = figment.merge(Layer::file(p, &table)?);
    }
    figment = figment.merge(Layer::env(env)?);
    figment = figment.merge(Layer::flags(flags.given()?)?);
    let config: ShoalConfig = figment
        .extract()
        .map_err(|e| anyhow::anyhow!("{}", describe(&figment, &e)))?;
    check(&config)?;
    Ok(config)
}

/// The environment variables Shoal reads its configuration from start with this.
const ENV_PREFIX: &str = "SHOAL_";
/// Separates the section, nested sections and the key in a variable's name.
const ENV_SEPARATOR: &str = "__";

/// One layer of the configuration: the keys it sets and where they came from.
struct Layer {
    metadata: Metadata,
    dict: Dict,
}

impl Layer {
    /// A configuration file, already parsed (so that a syntax error names its line).
    fn file(path: &Path, table: &toml::Table) -> Result<Self> {
        let shown = format!("config file {}", path.display());
        let metadata = Metadata::from("config file", path).interpolater(move |_, _| shown.clone());
        Ok(Self {
            metadata,
            dict: as_dict(Value::serialize(table)?),
        })
    }

    /// `SHOAL_<SECTION>__<KEY>=value` variables, sections nested with `__`
    /// (`SHOAL_CONSOLE__AUTH__ENABLED`); a value is TOML where it parses as TOML (numbers,
    /// booleans, arrays, inline tables, quoted strings), a string otherwise. Variables
    /// without `__` (`SHOAL_CONFIG`, the test scripts' own) are not configuration.
    fn env(vars: impl IntoIterator<Item = (String, String)>) -> Result<Self> {
        let mut vars: Vec<(String, Vec<String>, String)> = vars
            .into_iter()
            .filter_map(|(name, raw)| {
                let rest = name.strip_prefix(ENV_PREFIX)?;
                let keys = rest.contains(ENV_SEPARATOR).then(|| {
                    rest.split(ENV_SEPARATOR)
                        .map(str::to_ascii_lowercase)
                        .collect()
                })?;
                Some((name, keys, raw))
            })
            .collect();
        // The environment's order is arbitrary; a conflict must be reported the same way
        // every time.
        vars.sort();
        let mut dict = Dict::new();
        for (name, keys, raw) in &vars {
            if keys.iter().any(String::is_empty) {
                bail!("environment variable {name}: expected SHOAL_<SECTION>__<KEY>");
            }
            let value = format!("v = {raw}")
                .parse::<toml::Table>()
                .ok()
                .and_then(|mut t| t.remove("v"))
                .unwrap_or_else(|| toml::Value::String(raw.clone()));
            insert(&mut dict, keys, Value::serialize(value)?)
                .map_err(|e| anyhow::anyhow!("environment variable {name}: {e}"))?;
        }
        // An error names the variable that set the key: one naming the key or a section
        // above it (`SHOAL_CONSOLE__AUTH={ enabled = 3 }`), or the first under it (an
        // unknown section is reported at the section).
        let names: Vec<(Vec<String>, String)> = vars
            .into_iter()
            .map(|(name, keys, _)| (keys, name))
            .collect();
        let metadata =
            Metadata::named("environment variable").interpolater(move |_, path: &[&str]| {
                let set = names
                    .iter()
                    .find(|(keys, _)| keys.iter().zip(path).all(|(k, p)| k == p));
                match set {
                    Some((_, name)) => format!("environment variable {name}"),
                    None => "the environment".to_string(),
                }
            });
        Ok(Self { metadata, dict })
    }

    /// Command-line flags: (flag, key, value).
    fn flags(given: Vec<(&'static str, &'static str, Value)>) -> Result<Self> {
        let mut dict = Dict::new();
        let mut names = Vec::new();
        for (flag, key, value) in given {
            let keys: Vec<String> = key.split('.').map(str::to_string).collect();
            insert(&mut dict, &keys, value).map_err(|e| anyhow::anyhow!("{flag}: {e}"))?;
            names.push((keys, flag));
        }
        let metadata =
            Metadata::named("command-line flag").interpolater(move |_, path: &[&str]| {
                names
                    .iter()
                    .find(|(keys, _)| keys.iter().zip(path).all(|(k, p)| k == p))
                    .map_or_else(|| "a flag".to_string(), |(_, flag)| format!("flag {flag}"))
            });
        Ok(Self { metadata, dict })
    }
}

impl Provider for Layer {
    fn metadata(&self) -> Metadata {
        self.metadata.clone()
    }

    fn data(&self) -> Result<Map<Profile, Dict>, figment::Error> {
        Ok(Profile::Default.collect(self.dict.clone()))
    }
}

fn as_dict(value: Value) -> Dict {
    value.into_dict().unwrap_or_default()
}

/// Puts `value` at `keys` (a section path and a key) in `dict`, making the sections.
fn insert(dict: &mut Dict, keys: &[String], value: Value) -> Result<(), String> {
    let Some((last, sections)) = keys.split_last() else {
        return Err("no key".to_string());
    };
    let mut at = dict;
    for (i, section) in sections.iter().enumerate() {
        let entry = at
            .entry(section.clone())
            .or_insert_with(|| Value::from(Dict::new()));
        at = match entry {
            Value::Dict(_, d) => d,
            _ => return Err(format!("`{}` is not a section", keys[..=i].join("."))),
        };
    }
    if matches!(at.get(last), Some(Value::Dict(..))) {
        return Err(format!("`{}` is a section, not a key", keys.join(".")));
    }
    at.insert(last.clone(), value);
    Ok(())
}

/// One line for a configuration error: the key, the layer that set it (file, variable or
/// flag), and what is wrong.
fn describe(figment: &Figment, error: &figment::Error) -> String {
    // figment chains one error per failing value; the first is enough to act on.
    let mut path = error.path.clone();
    let mut metadata = error.metadata.clone();
    if let Kind::UnknownField(field, _) = &error.kind {
        // The layer that set the unknown key is the one to name; the error carries the
        // section's, which may have come from another layer.
        if path.last() != Some(field) {
            path.push(field.clone());
        }
        if let Some(m) = figment.find_metadata(&path.join(".")) {
            metadata = Some(m.clone());
        }
    }
    let from = metadata
        .map(|m| format!(" ({})", m.interpolate(&Profile::Default, &path)))
        .unwrap_or_default();
    // figment's own wording quotes the list of keys twice; a custom message may run over
    // several lines: keep one.
    let kind = match &error.kind {
        Kind::UnknownField(field, expected) => {
            format!("unknown key `{field}`, expected {}", OneOf(expected))
        }
        Kind::UnknownVariant(value, expected) => {
            format!("unknown value `{value}`, expected {}", OneOf(expected))
        }
        other => other.to_string(),
    };
    let what = kind.lines().next().unwrap_or_default();
    if path.is_empty() {
        format!("invalid configuration{from}: {what}")
    } else {
        format!(
            "invalid configuration at `{}`{from}: {what}",
            path.join(".")
        )
    }
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

/// The checks across keys that serde cannot make; each error names the key.
fn check(config: &ShoalConfig) -> Result<()> {
    #[cfg(feature = "console")]
    {
        config
            .station
            .check()
            .map_err(|e| anyhow::anyhow!("invalid configuration: {e}"))?;
        config
            .history
            .check()
            .map_err(|e| anyhow::anyhow!("invalid configuration in [history]: {e}"))?;
        config
            .traffic
            .validate()
            .map_err(|e| anyhow::anyhow!("invalid configuration in [traffic]: {e}"))?;
        config
            .foxglove
            .validate()
            .map_err(|e| anyhow::anyhow!("invalid configuration in [foxglove]: {e}"))?;
        if config.federation.enabled {
            config
                .federation
                .validate()
                .map_err(|e| anyhow::anyhow!("invalid configuration in [federation]: {e}"))?;
        }
    }
    config
        .security
        .check()
        .map_err(|e| anyhow::anyhow!("invalid configuration: {e}"))?;
    config
        .recorder
        .check()
        .map_err(|e| anyhow::anyhow!("invalid configuration in [recorder]: {e}"))?;
    config
        .fleet
        .check()
        .map_err(|e| anyhow::anyhow!("invalid configuration: {e}"))?;
    config
        .vehicle
        .check()
        .map_err(|e| anyhow::anyhow!("invalid configuration: {e}"))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::panic)]
    use super::*;

    /// Loads `text` as the configuration file, with `env` as the environment.
    fn load_text(text: &str, env: &[(&str, &str)], flags: &Flags) -> Result<ShoalConfig> {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("shoal.toml");
        std::fs::write(&path, text).unwrap();
        let env = env
            .iter()
            .map(|(k, v)| ((*k).to_string(), (*v).to_string()));
        load_from(Some(&path), env, flags)
    }

    fn file(text: &str) -> Result<ShoalConfig> {
        load_text(text, &[], &Flags::default())
    }

    fn env(vars: &[(&str, &str)]) -> Result<ShoalConfig> {
        let vars = vars
            .iter()
            .map(|(k, v)| ((*k).to_string(), (*v).to_string()));
        load_from(None, vars, &Flags::default())
    }

    #[test]
    fn the_shipped_default_config_parses_and_equals_the_built_in_defaults() {
        #[allow(unused_mut)] // Changed only in a vehicle build.
        let mut parsed = file(DEFAULT_CONFIG).unwrap();
        #[cfg(not(feature = "console"))]
        {
            // The station's sections are kept unchecked, so they are what the file says.
            parsed.station.clear();
            parsed.history.clear();
            parsed.console.clear();
            parsed.traffic.clear();
            parsed.foxglove.clear();
            parsed.federation.clear();
        }
        assert_eq!(parsed, ShoalConfig::default());
        assert_eq!(env(&[]).unwrap(), ShoalConfig::default());
    }

    #[test]
    fn an_older_file_with_the_retired_same_host_loopback_key_still_loads() {
        let parsed = file("[dds]\nsame_host_loopback = true\n").unwrap();
        assert_eq!(parsed.dds.same_host_loopback, Some(true));
        assert!(file("[dds]\nsame_host_loopback = 3\n").is_err());
    }

    #[cfg(feature = "console")]
    #[test]
    fn an_older_file_with_the_retired_lost_contact_factor_still_loads() {
        let parsed = file("[station.semantic]\nlost_contact_factor = 5.0\n").unwrap();
        assert_eq!(
            parsed.station.semantic.retired_keys(),
            ["lost_contact_factor"]
        );
        assert!(file("[station.semantic]\nlost_contact_factor = 0.5\n").is_err());
    }

    /// One key of every section and nested section, set from the environment. A section
    /// added to config/shoal.toml without a row here fails the test.
    #[test]
    fn every_section_can_be_set_from_the_environment() {
        type Check = fn(&ShoalConfig) -> bool;
        let mut rows: Vec<(&str, &str, &str, Check)> = vec![
            ("dds", "SHOAL_DDS__DOMAIN_ID", "7", |c| c.dds.domain_id == 7),
            ("recorder", "SHOAL_RECORDER__ENABLED", "true", |c| {
                c.recorder.enabled && c.recorder.prefix == "shoal"
            }),
            ("recorder", "SHOAL_RECORDER__ACOUSTIC", "true", |c| {
                c.recorder.acoustic && c.recorder.directory == Path::new("recordings")
            }),
            (
                "security",
                "SHOAL_SECURITY__BUNDLE",
                "/etc/shoal/bundle",
                |c| c.security.bundle == Path::new("/etc/shoal/bundle"),
            ),
            (
                "security.governance",
                "SHOAL_SECURITY__GOVERNANCE__DEFAULT",
                "sign",
                |c| c.security.governance.default == shoal_security::dds::Protection::Sign,
            ),
            ("fleet", "SHOAL_FLEET__ACOUSTIC_DEMO", "false", |c| {
                !c.fleet.acoustic_demo
            }),
            ("fleet.sim", "SHOAL_FLEET__SIM__RESERVE_PCT", "15.5", |c| {
                c.fleet.sim.reserve_pct == 15.5
            }),
            (
                "vehicle",
                "SHOAL_VEHICLE__STATE_DIR",
                "/var/lib/shoal/vehicles",
                |c| c.vehicle.state_dir == Path::new("/var/lib/shoal/vehicles"),
            ),
            (
                "fleet.vehicles",
                "SHOAL_FLEET__VEHICLES",
                r#"[{ id = "usv-9", kind = "usv", latitude_deg = 63.4, longitude_deg = 10.3 }]"#,
                |c| c.fleet.vehicles.len() == 1 && c.fleet.vehicles[0].id == "usv-9",
            ),
        ];
        #[cfg(feature = "console")]
        rows.extend::<[(&str, &str, &str, Check); 30]>([
            ("foxglove", "SHOAL_FOXGLOVE__ENABLED", "true", |c| {
                c.foxglove.enabled && c.foxglove.max_clients == 8
            }),
            ("federation", "SHOAL_FEDERATION__SITE", "ship-1", |c| {
                c.federation.site == "ship-1" && !c.federation.enabled
            }),
            // Site identity: the password comes from the environment rather than a file.
            (
                "federation",
                "SHOAL_FEDERATION__PASSWORD",
                "pw from env",
                |c| c.federation.password.expose() == "pw from env" && !c.federation.insecure_open,
            ),
            (
                "federation.tls",
                "SHOAL_FEDERATION__TLS__CERTIFICATE",
                "/etc/shoal/federation/ship-1.crt",
                |c| {
                    c.federation.tls.certificate == Path::new("/etc/shoal/federation/ship-1.crt")
                        && !c.federation.tls.enabled
                },
            ),
            (
                "federation.positions",
                "SHOAL_FEDERATION__POSITIONS__MAX_RATE_HZ",
                "0.5",
                |c| c.federation.positions.max_rate_hz == 0.5,
            ),
            (
                "federation.positions.qos",
                "SHOAL_FEDERATION__POSITIONS__QOS",
                // A QoS is set whole: one key alone is refused, naming the missing ones.
                "{ priority = \"data\", congestion = \"drop\", express = true }",
                |c| c.federation.positions.qos.express,
            ),
            (
                "federation.alarms.qos",
                "SHOAL_FEDERATION__ALARMS__QOS",
                // A QoS is set whole: one key alone is refused, naming the missing ones.
                "{ priority = \"real_time\", congestion = \"block\", express = false }",
                |c| !c.federation.alarms.qos.express,
            ),
            (
                "federation.tasks.qos",
                "SHOAL_FEDERATION__TASKS__QOS",
                // A QoS is set whole: one key alone is refused, naming the missing ones.
                "{ priority = \"interactive_high\", congestion = \"block\", express = true }",
                |c| c.federation.tasks.qos.express,
            ),
            (
                "federation.alarms",
                "SHOAL_FEDERATION__ALARMS__CATCHUP",
                "77",
                |c| c.federation.alarms.catchup == 77,
            ),
            (
                "federation.alarms.own_link",
                "SHOAL_FEDERATION__ALARMS__OWN_LINK",
                "false",
                |c| !c.federation.alarms.own_link,
            ),
            (
                "federation.tasks",
                "SHOAL_FEDERATION__TASKS__CATCHUP",
                "78",
                |c| c.federation.tasks.catchup == 78,
            ),
            (
                "federation.environment",
                "SHOAL_FEDERATION__ENVIRONMENT__MODE",
                "aggregated",
                |c| {
                    c.federation.environment.mode
                        == shoal_federation::config::EnvironmentMode::Aggregated
                },
            ),
            (
                "federation.environment.qos",
                "SHOAL_FEDERATION__ENVIRONMENT__QOS",
                "{ priority = \"background\", congestion = \"drop\", express = true }",
                |c| c.federation.environment.qos.express,
            ),
            (
                "federation",
                "SHOAL_FEDERATION__LINK_RATE_KBPS",
                "64",
                |c| c.federation.link_rate_kbps == 64,
            ),
            (
                "federation.limits",
                "SHOAL_FEDERATION__LIMITS__REMOTE_VEHICLES",
                "99",
                |c| c.federation.limits.remote_vehicles == 99,
            ),
            (
                "federation.lease",
                "SHOAL_FEDERATION__LEASE__FAILOVER_TIMEOUT_MS",
                "4500",
                |c| c.federation.lease.failover_timeout_ms == 4500,
            ),
            ("station", "SHOAL_STATION__LOST_AFTER_S", "45", |c| {
                c.station.lost_after_s == 45.0
            }),
            (
                "traffic",
                "SHOAL_TRAFFIC__INPUTS",
                "[\"udp://127.0.0.1:10110\"]",
                |c| c.traffic.inputs.len() == 1 && c.traffic.max_targets == 2000,
            ),
            (
                "station.plausibility",
                "SHOAL_STATION__PLAUSIBILITY__ENABLED",
                "false",
                |c| !c.station.plausibility.enabled,
            ),
            (
                "station.semantic",
                "SHOAL_STATION__SEMANTIC__OPERATING_AREA",
                "[{ latitude_deg = 63.4, longitude_deg = 10.2 }, \
                  { latitude_deg = 63.4, longitude_deg = 10.5 }, \
                  { latitude_deg = 63.5, longitude_deg = 10.5 }]",
                |c| c.station.semantic.operating_area.len() == 3,
            ),
            ("history", "SHOAL_HISTORY__PATH", ":memory:", |c| {
                c.history.path == Path::new(":memory:")
            }),
            (
                "history.retention",
                "SHOAL_HISTORY__RETENTION__MAX_ROWS",
                "1000",
                |c| c.history.retention.max_rows == 1000,
            ),
            ("console", "SHOAL_CONSOLE__LISTEN", "127.0.0.1:9999", |c| {
                c.console.listen.port() == 9999
            }),
            (
                "console.health",
                "SHOAL_CONSOLE__HEALTH__MAX_HISTORY_LAG",
                "123",
                |c| c.console.health.max_history_lag == 123,
            ),
            (
                "console.limits",
                "SHOAL_CONSOLE__LIMITS__MAX_WS_CLIENTS",
                "7",
                |c| c.console.limits.max_ws_clients == 7,
            ),
            (
                "console",
                "SHOAL_CONSOLE__ALLOWED_HOSTS",
                "[\"bridge.ship.local\"]",
                |c| c.console.allowed_hosts == ["bridge.ship.local"],
            ),
            // Logins are on by default: the variable that turns them off, as tests use it.
            (
                "console.auth",
                "SHOAL_CONSOLE__AUTH__ENABLED",
                "false",
                |c| !c.console.auth.enabled,
            ),
            // How harnesses give the first admin a known password.
            (
                "console.auth",
                "SHOAL_CONSOLE__AUTH__INITIAL_ADMIN_PASSWORD",
                "harness password",
                |c| c.console.auth.initial_admin_password == "harness password",
            ),
            (
                "console.tls",
                "SHOAL_CONSOLE__TLS__CERT",
                "/etc/shoal/console.pem",
                |c| c.console.tls.cert == Path::new("/etc/shoal/console.pem"),
            ),
            (
                "console.auth.users_path",
                "SHOAL_CONSOLE__AUTH__USERS_PATH",
                "/var/lib/shoal/users.json",
                |c| c.console.auth.users_path == Path::new("/var/lib/shoal/users.json"),
            ),
        ]);
        #[cfg(not(feature = "console"))]
        rows.push((
            "console.auth",
            "SHOAL_CONSOLE__AUTH__ENABLED",
            "false",
            |c| c.console["auth"]["enabled"].as_bool() == Some(false),
        ));
        for (_, var, value, landed) in &rows {
            let c = env(&[(var, value)]).unwrap_or_else(|e| panic!("{var}={value}: {e}"));
            assert!(landed(&c), "{var}={value} did not land");
        }
        // All at once, too: sections set by different variables merge.
        let all: Vec<(&str, &str)> = rows.iter().map(|(_, k, v, _)| (*k, *v)).collect();
        let c = env(&all).unwrap();
        for (_, var, _, landed) in &rows {
            assert!(landed(&c), "{var} lost when set with the others");
        }
        let mut sections = Vec::new();
        collect_sections(&parse_table(DEFAULT_CONFIG).unwrap(), "", &mut sections);
        #[cfg(not(feature = "console"))]
        sections.retain(|s| {
            ![
                "station",
                "history",
                "console",
                "traffic",
                "foxglove",
                "federation",
            ]
            .iter()
            .any(|p| s.starts_with(p))
        });
        for section in sections {
            assert!(
                rows.iter().any(|(s, ..)| *s == section),
                "no environment test for [{section}]"
            );
        }
    }

    /// The limits this wave added refuse values that would break the station or vehicle,
    /// each error naming its key.
    #[test]
    fn bad_values_of_the_lifetime_limits_are_refused_naming_the_key() {
        for (var, value, key) in [
            ("SHOAL_STATION__TASK_RETENTION_S", "10", "task_retention_s"),
            (
                "SHOAL_VEHICLE__MAX_TASK_AGE_S",
                "0",
                "vehicle.max_task_age_s",
            ),
            ("SHOAL_VEHICLE__STATE_DIR", "\"\"", "vehicle.state_dir"),
            (
                "SHOAL_STATION__SEMANTIC__RULE_BUDGET_MS",
                "0",
                "rule_budget_ms",
            ),
        ] {
            #[cfg(not(feature = "console"))]
            if var.starts_with("SHOAL_STATION") {
                continue;
            }
            let err = env(&[(var, value)]).expect_err(var).to_string();
            assert!(err.contains(key), "{var}={value}: {err}");
        }
    }

    /// A protection the governance does not know, or a topic given a non-protection, is
    /// refused naming the key, before any key store is made from it.
    #[test]
    fn bad_governance_protections_are_refused_naming_the_key() {
        let err = env(&[("SHOAL_SECURITY__GOVERNANCE__DEFAULT", "plaintext")])
            .expect_err("unknown protection")
            .to_string();
        assert!(err.contains("security.governance"), "{err}");
        let err = file("[security.governance]\ntopics = { \"shoal/event\" = 3 }\n")
            .expect_err("a number for a protection")
            .to_string();
        assert!(err.contains("security.governance"), "{err}");
        // A topic expression must match a Shoal topic; a pattern may match several.
        let err = file("[security.governance]\ntopics = { \"shoal/state\" = \"sign\" }\n")
            .expect_err("no such topic")
            .to_string();
        assert!(
            err.contains("\"shoal/state\" matches no topic") && err.contains("shoal/state_vector"),
            "{err}"
        );
        let ok = file(
            "[security.governance]\ntopics = { \"shoal/task_*\" = \"sign\", \"shoal/event\" = \"none\" }\n",
        );
        assert!(ok.is_ok(), "{ok:?}");
    }

    /// Every table and array of tables in `table`, as dotted paths.
    fn collect_sections(table: &toml::Table, prefix: &str, out: &mut Vec<String>) {
        for (key, value) in table {
            let path = format!("{prefix}{key}");
            match value {
                toml::Value::Table(t) => {
                    out.push(path.clone());
                    collect_sections(t, &format!("{path}."), out);
                }
                toml::Value::Array(a) if a.iter().all(toml::Value::is_table) && !a.is_empty() => {
                    out.push(path);
                }
                _ => {}
            }
        }
    }

    #[test]
    fn an_environment_value_that_is_not_toml_is_a_string() {
        let c = env(&[("SHOAL_SECURITY__STORE", "keys dir/[1]")]).unwrap();
        assert_eq!(c.security.store, Path::new("keys dir/[1]"));
        let c = env(&[("SHOAL_SECURITY__STORE", "\"quoted\"")]).unwrap();
        assert_eq!(c.security.store, Path::new("quoted"));
    }

    #[test]
    fn variables_without_the_separator_are_not_configuration() {
        let c = env(&[
            ("SHOAL_CONFIG", "/nowhere.toml"),
            ("SHOAL_INTEROP_REQUIRED", "1"),
            ("UNRELATED__KEY", "x"),
        ])
        .unwrap();
        assert_eq!(c, ShoalConfig::default());
    }

    #[test]
    fn a_malformed_variable_name_is_named() {
        let e = env(&[("SHOAL_DDS____DOMAIN_ID", "3")])
            .unwrap_err()
            .to_string();
        assert!(e.contains("SHOAL_DDS____DOMAIN_ID"), "{e}");
        let e = env(&[
            ("SHOAL_DDS__DOMAIN_ID", "3"),
            ("SHOAL_DDS__DOMAIN_ID__X", "4"),
        ])
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("SHOAL_DDS__DOMAIN_ID__X") && e.contains("not a section"),
            "{e}"
        );
    }

    #[cfg(feature = "console")]
    #[test]
    fn precedence_is_file_then_environment_then_flags() {
        let text = "[dds]\ndomain_id = 3\n[console]\nlisten = \"127.0.0.1:1001\"\n\
                    [history]\npath = \"from-file.db\"\n[security]\ncrl_check_s = 40\n";
        let vars = [
            ("SHOAL_CONSOLE__LISTEN", "127.0.0.1:1002"),
            ("SHOAL_HISTORY__PATH", "from-env.db"),
            ("SHOAL_SECURITY__CRL_CHECK_S", "50"),
        ];
        let flags = Flags {
            listen: Some("127.0.0.1:1003".parse().unwrap()),
            db: None,
        };
        let c = load_text(text, &vars, &flags).unwrap();
        assert_eq!(c.dds.domain_id, 3, "the file over the defaults");
        assert_eq!(c.security.crl_check_s, 50, "the environment over the file");
        assert_eq!(
            c.history.path,
            Path::new("from-env.db"),
            "no flag: the environment"
        );
        assert_eq!(c.console.listen.port(), 1003, "the flag over both");
        let flags = Flags {
            listen: None,
            db: Some(PathBuf::from("from-flag.db")),
        };
        let c = load_text(text, &vars, &flags).unwrap();
        assert_eq!(c.history.path, Path::new("from-flag.db"));
        assert_eq!(c.console.listen.port(), 1002);
        // Untouched keys of a section the environment sets keep the file's values.
        let c = load_text(
            "[console.auth]\nsession_ttl_s = 60\n",
            &[("SHOAL_CONSOLE__AUTH__ENABLED", "false")],
            &Flags::default(),
        )
        .unwrap();
        assert!(!c.console.auth.enabled);
        assert_eq!(c.console.auth.session_ttl_s, 60);
    }

    #[test]
    fn the_environment_overrides_the_file() {
        let c = load_text(
            "[dds]\ndomain_id = 3\n[fleet.sim]\nreserve_pct = 12.0\n",
            &[("SHOAL_DDS__DOMAIN_ID", "7")],
            &Flags::default(),
        )
        .unwrap();
        assert_eq!(c.dds.domain_id, 7);
        assert_eq!(c.fleet.sim.reserve_pct, 12.0);
    }

    #[test]
    fn a_bad_value_gives_one_line_naming_the_key_and_the_file() {
        let e = file("[dds]\ndomain_id = \"seven\"\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("dds.domain_id") && e.contains("shoal.toml"),
            "{e}"
        );
        assert!(!e.contains('\n'), "{e}");
    }

    #[test]
    fn a_bad_value_from_the_environment_names_the_variable() {
        let e = load_text(
            "[fleet.sim]\nreserve_pct = 12.0\n",
            &[("SHOAL_FLEET__SIM__RESERVE_PCT", "lots")],
            &Flags::default(),
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("fleet.sim.reserve_pct") && e.contains("SHOAL_FLEET__SIM__RESERVE_PCT"),
            "{e}"
        );
        assert!(!e.contains("shoal.toml") && !e.contains('\n'), "{e}");
    }

    #[test]
    fn an_unknown_key_is_named_with_where_it_came_from() {
        let e = file("[security]\nstale_after = 3\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("security.stale_after") && e.contains("shoal.toml"),
            "{e}"
        );
        // The section comes from the file, the unknown key from the environment.
        let e = load_text(
            "[fleet.sim]\nreserve_pct = 12.0\n",
            &[("SHOAL_FLEET__SIM__RESERVE", "3")],
            &Flags::default(),
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("fleet.sim.reserve") && e.contains("SHOAL_FLEET__SIM__RESERVE"),
            "{e}"
        );
        let e = env(&[("SHOAL_FLEET__SIMS__RESERVE_PCT", "3")])
            .unwrap_err()
            .to_string();
        assert!(e.contains("SHOAL_FLEET__SIMS__RESERVE_PCT"), "{e}");
        // A whole section as an inline table: the variable that set it is named.
        let e = env(&[("SHOAL_FLEET__SIM", "{ reserve_pct = \"x\" }")])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("fleet.sim.reserve_pct") && e.contains("variable SHOAL_FLEET__SIM)"),
            "{e}"
        );
    }

    #[test]
    fn a_syntax_error_names_the_line() {
        let e = format!("{:#}", file("[dds]\ndomain_id = = 3\n").unwrap_err());
        assert!(e.contains("shoal.toml: line 2"), "{e}");
    }

    #[test]
    fn inconsistent_values_are_explained() {
        #[cfg(feature = "console")]
        {
            let e = file("[station]\nstale_after_s = 10\nlost_after_s = 5\n")
                .unwrap_err()
                .to_string();
            assert!(e.contains("station.lost_after_s"), "{e}");
            let e = file(
                "[station.semantic]\noperating_area = [{ latitude_deg = 1.0, longitude_deg = 2.0 }]\n",
            )
            .unwrap_err()
            .to_string();
            assert!(e.contains("station.semantic: operating_area"), "{e}");
        }
        let e = env(&[("SHOAL_SECURITY__CRL_CHECK_S", "0")])
            .unwrap_err()
            .to_string();
        assert!(e.contains("security.crl_check_s"), "{e}");
    }

    #[cfg(feature = "console")]
    #[test]
    fn an_operating_area_in_the_file_reaches_the_semantic_model() {
        let c = file(
            "[station.semantic]\noperating_area = [\n { latitude_deg = 63.4, longitude_deg = 10.2 },\n { latitude_deg = 63.4, longitude_deg = 10.5 },\n { latitude_deg = 63.5, longitude_deg = 10.5 },\n]\n",
        )
        .unwrap();
        assert_eq!(c.station.semantic.operating_area.len(), 3);
    }

    #[cfg(not(feature = "console"))]
    #[test]
    fn a_vehicle_build_keeps_the_station_sections_unchecked() {
        let c = file("[station]\nlost_after_s = 45.0\n[history]\nanything = 1\n").unwrap();
        assert_eq!(c.station["lost_after_s"].as_float(), Some(45.0));
    }
}
