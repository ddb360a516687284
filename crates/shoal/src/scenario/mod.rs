//! `shoal scenario`: scenario files (the `shoal-scenario` crate) on the command line, how
//! `shoal up` and `shoal station` find the scenario their `--scenario` names, and
//! [`run`]: a scenario run headless, faster than real time, with its report.

#[cfg(feature = "console")]
pub mod run;
#[cfg(feature = "console")]
mod sea;
#[cfg(feature = "console")]
mod world;

use std::path::Path;
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand};
use shoal_scenario::{SHIPPED, Scenario};

/// `shoal scenario ...`.
#[derive(Debug, Args)]
pub struct ScenarioArgs {
    #[command(subcommand)]
    which: ScenarioCommand,
}

#[derive(Debug, Subcommand)]
enum ScenarioCommand {
    /// Check a scenario file and print a one-line summary of it. Exits 0 when it is
    /// valid, 2 with one line naming the key and the line number when it is not.
    ///
    /// The format (fleet, missions on a timeline, every key with its default and
    /// bounds) is in docs/scenarios.md.
    #[command(after_help = "Example: shoal scenario check scenarios/sea-trial.toml")]
    Check {
        /// The scenario: a TOML file, or the name of a shipped one (`shoal scenario list`).
        #[arg(value_name = "FILE")]
        file: String,
    },
    /// List the scenarios shipped in this binary (scenarios/ in the repository).
    List,
    /// Run a scenario headless, faster than real time: a station and the scenario's
    /// simulated vehicles in this process on a private loopback DDS domain, with a
    /// progress line every two seconds; then write its report directory.
    #[cfg(feature = "console")]
    Run(run::RunArgs),
}

impl ScenarioArgs {
    /// The `run` subcommand's arguments: it needs the configuration and a runtime,
    /// unlike `check` and `list`.
    #[cfg(feature = "console")]
    pub fn run_args(&self) -> Option<&run::RunArgs> {
        match &self.which {
            ScenarioCommand::Run(args) => Some(args),
            _ => None,
        }
    }
}

/// Where a scenario's text came from: a file, or one compiled into the binary.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Source {
    /// A shipped scenario, by name.
    Shipped(&'static str),
    /// A file, by the path given.
    File(String),
}

impl std::fmt::Display for Source {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Shipped(name) => write!(f, "{name} (shipped)"),
            Self::File(path) => f.write_str(path),
        }
    }
}

/// What `--scenario VALUE` names: `none`, an existing file, or a shipped scenario's name
/// (a file of that name wins, so a user's own file is never shadowed).
pub fn resolve(value: &str) -> Result<Option<Source>> {
    if value == "none" {
        return Ok(None);
    }
    if Path::new(value).exists() {
        return Ok(Some(Source::File(value.to_owned())));
    }
    if let Some((name, _)) = SHIPPED.iter().find(|(n, _)| *n == value) {
        return Ok(Some(Source::Shipped(name)));
    }
    let names: Vec<&str> = SHIPPED.iter().map(|(n, _)| *n).collect();
    bail!(
        "scenario {value:?}: no such file, and not a shipped scenario ({}), nor `none`",
        names.join(", ")
    )
}

/// Reads and checks a scenario; the error is one line naming the source, key and line.
pub fn load(source: &Source) -> Result<Scenario> {
    let text = match source {
        Source::Shipped(name) => shoal_scenario::shipped(name)
            .with_context(|| format!("no shipped scenario {name:?}"))?
            .to_owned(),
        Source::File(path) => {
            std::fs::read_to_string(path).with_context(|| format!("cannot read scenario {path}"))?
        }
    };
    shoal_scenario::parse(&text).with_context(|| format!("scenario {source}"))
}

/// The simulated vehicles of a scenario's fleet that are on IP (its acoustic vehicles are
/// heard through the acoustic network only: `shoal scenario run` runs that).
#[cfg(feature = "console")]
pub fn fleet(s: &Scenario) -> Vec<shoal_proxy::sim::SimSpec> {
    s.vehicles
        .iter()
        .filter(|v| v.acoustic_address.is_none())
        .map(sim_spec)
        .collect()
}

/// The simulator's description of a scenario vehicle.
pub(crate) fn sim_spec(v: &shoal_scenario::ScenarioVehicle) -> shoal_proxy::sim::SimSpec {
    shoal_proxy::sim::SimSpec {
        id: v.id.clone(),
        kind: v.kind,
        latitude_deg: v.latitude_deg,
        longitude_deg: v.longitude_deg,
        rate_hz: v.rate_hz,
        battery_pct: v.battery_pct,
    }
}

/// One line about a valid scenario.
pub fn summary(s: &Scenario) -> String {
    let tasks: usize = s.missions.iter().map(|m| m.tasks.len()).sum();
    let times = s.missions.iter().map(|m| m.at_s);
    let first = times.clone().fold(f64::INFINITY, f64::min);
    let last = times.fold(0.0, f64::max);
    let timeline = if s.missions.is_empty() {
        String::new()
    } else {
        format!(" starting {first} s to {last} s in")
    };
    let acoustic = s.acoustic_vehicles().count();
    let acoustic = if acoustic > 0 {
        format!(" ({acoustic} acoustic)")
    } else {
        String::new()
    };
    let plumes = s.environment.plumes.len();
    let ocean = if s.environment == shoal_model::ocean::OceanField::default() {
        String::new()
    } else {
        let s = if plumes == 1 { "" } else { "s" };
        format!(", its own ocean ({plumes} plume{s})")
    };
    format!(
        "scenario {:?}: {} vehicles{acoustic}, {} missions ({tasks} tasks){timeline}, {} s at time scale {}{ocean}",
        s.name,
        s.vehicles.len(),
        s.missions.len(),
        s.duration_s,
        s.time_scale
    )
}

/// `shoal scenario ...`; its own exit code (2: the scenario is not valid).
pub fn run(args: &ScenarioArgs) -> ExitCode {
    match &args.which {
        #[cfg(feature = "console")]
        // main runs it with the configuration and a runtime; never reached from there.
        ScenarioCommand::Run(_) => {
            eprintln!("shoal: error: `scenario run` needs the configuration loaded first");
            ExitCode::FAILURE
        }
        ScenarioCommand::List => {
            for (name, text) in SHIPPED {
                match shoal_scenario::parse(text) {
                    Ok(s) => println!("{name}: {}", s.description),
                    Err(e) => println!("{name}: INVALID: {e}"),
                }
            }
            ExitCode::SUCCESS
        }
        ScenarioCommand::Check { file } => {
            let checked = resolve(file).and_then(|source| match source {
                Some(source) => load(&source).map(|s| (source, s)),
                None => bail!("`none` is not a scenario to check"),
            });
            match checked {
                Ok((source, s)) => {
                    println!("{source}: {}", summary(&s));
                    ExitCode::SUCCESS
                }
                Err(e) => {
                    eprintln!("shoal: error: {e:#}");
                    ExitCode::from(2)
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn none_a_file_and_a_shipped_name_are_told_apart() {
        assert_eq!(resolve("none").unwrap(), None);
        assert_eq!(
            resolve("sea-trial").unwrap(),
            Some(Source::Shipped("sea-trial"))
        );
        let dir = tempfile::tempdir().unwrap();
        let f = dir.path().join("sea-trial");
        std::fs::write(&f, "").unwrap();
        let p = f.to_str().unwrap();
        assert_eq!(resolve(p).unwrap(), Some(Source::File(p.to_owned())));
        let e = resolve("no-such-scenario").unwrap_err().to_string();
        assert!(e.contains("sea-trial") && e.contains("no such file"), "{e}");
    }

    #[test]
    fn the_summary_of_the_default_scenario_is_one_line() {
        let s = load(&Source::Shipped("sea-trial")).unwrap();
        let line = summary(&s);
        assert!(
            line.contains("5 vehicles (1 acoustic)") && line.contains("5 missions"),
            "{line}"
        );
        assert!(!line.contains('\n'));
    }
}
