//! `shoal`: the command line of the Shoal middleware. Thin glue over the library crates.

#![forbid(unsafe_code)]

mod acoustic;
#[cfg(feature = "console")]
mod bench;
mod config;
mod daemons;
#[cfg(feature = "console")]
mod federation;
mod keys;
mod ledger;
#[cfg(feature = "console")]
mod query;
mod record;
mod relay;
mod scenario;

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use shoal_model::VehicleKind;

/// mimalloc: small allocations and frees (terms, query rows, samples) are the station's
/// commonest, and glibc's allocator made a fifth of a large query's time. Its `override`
/// feature makes it `malloc` too, so one allocator serves the whole process: Cyclone DDS (C)
/// allocates each received sample on its receive thread, and Shoal frees it on a tokio
/// thread.
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// Shoal: semantic publish/subscribe middleware for fleets of maritime robots.
#[derive(Debug, Parser)]
#[command(version, about, long_about = None)]
#[cfg_attr(not(feature = "console"), command(after_help = VEHICLE_BUILD))]
struct Cli {
    /// Configuration file (TOML); see config/shoal.toml for every key. Also SHOAL_CONFIG.
    #[arg(long, global = true, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Run with security off (as `[security] enabled = false`): no DDS Security, no acoustic
    /// tags. For lab work with unmodified third-party vehicles only; anyone on the domain
    /// can then command vehicles. A station refuses it on non-loopback interfaces unless
    /// security.allow_insecure_network is set.
    #[arg(long, global = true)]
    insecure: bool,
    #[command(subcommand)]
    command: Command,
}

/// What `--help` says in a build without the `console` feature.
#[cfg(not(feature = "console"))]
const VEHICLE_BUILD: &str = "This build is the vehicle side only (built without the `console` \
feature): the station and its web console, and `up`, `station`, `query` and `bench`, are left \
out.";

/// The commands a build without the `console` feature leaves out.
#[cfg(not(feature = "console"))]
const STATION_COMMANDS: [&str; 4] = ["up", "station", "query", "bench"];

#[derive(Debug, Subcommand)]
enum Command {
    #[cfg(feature = "console")]
    /// Start everything on this host: a station, the simulated fleet of [fleet] and the
    /// HTTP API. Ctrl-C stops it all.
    Up {
        /// Start only the station, no simulated vehicles.
        #[arg(long)]
        no_fleet: bool,
        /// The scenario to run: its fleet is started and the station starts its missions
        /// on their timeline (docs/scenarios.md). A TOML file, the name of a shipped
        /// scenario (`shoal scenario list`), or `none` for the configured fleet and no
        /// missions. Default: the shipped `sea-trial`, unless the configuration lists its
        /// own [[fleet.vehicles]] (then none).
        #[arg(long, value_name = "FILE|NAME|none")]
        scenario: Option<String>,
        /// Security is on by default (the key store is created on first run, each vehicle
        /// gets its identity); kept so older scripts still run. See --insecure.
        #[arg(long, hide = true)]
        secure: bool,
        /// Also start N lightweight simulated vehicles in one process (`shoal swarm`), for
        /// scale tests; they report state at 1 Hz and take no tasks.
        #[arg(long, value_name = "N", default_value_t = 0)]
        sim_vehicles: usize,
    },
    /// Many lightweight simulated vehicles on one DDS participant (scale tests): each
    /// announces itself and reports its state while circling its start point; they take
    /// no tasks.
    Swarm {
        /// Number of vehicles.
        #[arg(long, default_value_t = 100)]
        count: usize,
        /// State vectors per second per vehicle.
        #[arg(long, default_value_t = 1.0)]
        rate: f64,
        /// Vehicle ids are PREFIX-1, PREFIX-2, ...
        #[arg(long, default_value = "sw")]
        prefix: String,
        /// Centre of the swarm, latitude degrees.
        #[arg(long, default_value_t = 63.44, allow_negative_numbers = true)]
        lat: f64,
        /// Centre of the swarm, longitude degrees.
        #[arg(long, default_value_t = 10.30, allow_negative_numbers = true)]
        lon: f64,
        /// Stop when standard input closes (used by `shoal up`).
        #[arg(long, hide = true)]
        exit_on_stdin_close: bool,
    },
    #[cfg(feature = "console")]
    /// Run the Command and Control Station: ingest, history, register, HTTP API.
    Station {
        /// Address of the HTTP API (overrides console.listen).
        #[arg(long, value_name = "ADDR")]
        listen: Option<std::net::SocketAddr>,
        /// History database (overrides history.path); ":memory:" keeps it in RAM.
        #[arg(long, value_name = "PATH")]
        db: Option<PathBuf>,
        /// Start the missions of this scenario (a TOML file or a shipped scenario's name)
        /// on its timeline as its vehicles are heard; its fleet is not started here.
        #[arg(long, value_name = "FILE|NAME", default_value = "none")]
        scenario: String,
        /// Stop when standard input closes (used by `shoal up` to stop its children).
        #[arg(long, hide = true)]
        exit_on_stdin_close: bool,
    },
    /// Join one vehicle to DDS: a simulated one (`--sim auv`), or a real vehicle's software
    /// through a proxy (`--proxy mavlink|imc|ros2`).
    Vehicle {
        /// Kind of simulated vehicle.
        #[arg(
            long,
            value_enum,
            required_unless_present = "proxy",
            conflicts_with = "proxy"
        )]
        sim: Option<SimKind>,
        /// Proxy for a real vehicle: MAVLink (ArduSub), IMC (LSTS DUNE) or ROS 2.
        #[arg(long, value_enum)]
        proxy: Option<ProxyKind>,
        /// MAVLink: the connection, `udpin:127.0.0.1:14550` (wait for the vehicle) or
        /// `udpout:HOST:PORT`. IMC: the vehicle's UDP address, `HOST:PORT`.
        #[arg(long)]
        address: Option<String>,
        /// IMC: the local UDP address to bind, `HOST:PORT`.
        #[arg(long)]
        bind: Option<String>,
        /// ROS 2: the vehicle's namespace (topics `rt/<namespace>/...`).
        #[arg(long)]
        namespace: Option<String>,
        /// ROS 2: the vehicle's middleware, DDS or rmw_zenoh (default: the proxy
        /// settings' `rmw`, else dds). rmw_zenoh's endpoints are the settings' `[zenoh]`.
        #[arg(long, value_enum)]
        rmw: Option<RmwKind>,
        /// The proxy's full settings as TOML (every key of its configuration; see the
        /// integrator guide); flags given here override it.
        #[arg(long, value_name = "FILE")]
        proxy_config: Option<PathBuf>,
        /// Vehicle id: letters, digits, '_', '-', '.', at most 32.
        #[arg(long)]
        id: String,
        /// Start latitude, degrees.
        #[arg(long, default_value_t = 63.465, allow_negative_numbers = true)]
        lat: f64,
        /// Start longitude, degrees.
        #[arg(long, default_value_t = 10.37, allow_negative_numbers = true)]
        lon: f64,
        /// State vectors per second.
        #[arg(long, default_value_t = 1.0)]
        rate: f64,
        /// Simulator: battery at start, %.
        #[arg(long, default_value_t = 100.0)]
        battery: f64,
        /// Simulator: sample the ocean of this scenario's `[environment]` (a scenario file
        /// or a shipped scenario's name), as `shoal up --scenario` does.
        #[arg(long, value_name = "FILE|NAME", conflicts_with = "proxy")]
        scenario: Option<String>,
        /// Stop when standard input closes (used by `shoal up`).
        #[arg(long, hide = true)]
        exit_on_stdin_close: bool,
    },
    /// (helper of `shoal up`) The acoustic demo: emulated modems, a simulated submerged AUV
    /// with its VDT on a private DDS domain, and a CDT relaying it to the station's domain.
    #[command(hide = true)]
    AcousticDemo {
        /// The scenario whose acoustic vehicles and relay to run (a file or a shipped
        /// name); without one, or when it has none, the demo's own AUV auv-ac1.
        #[arg(long, value_name = "FILE")]
        scenario: Option<String>,
        /// Stop when standard input closes.
        #[arg(long)]
        exit_on_stdin_close: bool,
    },
    #[cfg(feature = "console")]
    /// Benchmarks that print figures: `suite` runs every target in one table, beside the
    /// peer measured in the same run (Cyclone DDS, raw SQLite); the others measure one part each.
    Bench {
        #[command(subcommand)]
        which: bench::BenchCommand,
    },
    #[cfg(feature = "console")]
    /// Run a read-only SPARQL query against a running station's semantic model.
    Query {
        /// The SPARQL query; `-` reads it from standard input. The prefixes shoal:, geo:,
        /// sosa:, ... may be used without declaring them.
        sparql: String,
        /// Result format.
        #[arg(long, value_parser = ["csv", "json", "tsv", "xml"], default_value = "csv")]
        format: String,
        /// Station API: host:port or an http(s):// URL (default: console.listen, over
        /// HTTPS when [console.tls] is on).
        #[arg(long, value_name = "ADDR|URL")]
        station: Option<String>,
        /// PEM certificate(s) to trust when the API is HTTPS (default: the console's own
        /// [console.tls] cert).
        #[arg(long, value_name = "FILE")]
        ca: Option<PathBuf>,
        /// API token (viewer or better) sent as `Authorization: Bearer`; needed when the
        /// station requires logins (the default).
        #[arg(
            long,
            value_name = "TOKEN",
            env = "SHOAL_TOKEN",
            hide_env_values = true
        )]
        token: Option<String>,
    },
    /// The station's key store: CA, station and vehicle certificates, acoustic keys,
    /// revocations (see the operator guide, "Security").
    Keys(keys::KeysArgs),
    /// A vehicle's task ledger ([vehicle] state_dir): `show` what it holds, or
    /// `forget-lease` when the vehicle leaves a federation.
    Ledger(ledger::LedgerArgs),
    /// Compact acoustic PDUs: encode JSON to hex, decode hex to JSON, print sizes.
    Pdu {
        #[command(subcommand)]
        which: acoustic::PduCommand,
    },
    /// Emulated acoustic modems on 127.0.0.1 speaking EvoLogics AT and EviNS NL over TCP,
    /// in one simulated sea (delay, loss, half duplex, collisions).
    ModemEmu(acoustic::ModemEmuArgs),
    /// Record every Shoal topic (or those of --topics) into MCAP files, rotated by size and
    /// time; Ctrl-C closes the file properly (docs/recorder.md).
    Record(record::RecordArgs),
    /// Publish an MCAP recording (a file or a directory of them) on DDS again, at the
    /// recorded pace times --speed; with security on, each vehicle's samples under its own
    /// identity from the key store.
    Replay(record::ReplayArgs),
    /// Scenario files: a simulated fleet and missions on a timeline (docs/scenarios.md).
    /// `check` validates one; `shoal up --scenario FILE` runs one.
    Scenario(scenario::ScenarioArgs),
    /// Print the effective configuration (defaults, file and environment merged) as TOML.
    Config {
        /// Print the commented default configuration file instead.
        #[arg(long)]
        default: bool,
    },
}

/// Vehicle software a proxy speaks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ProxyKind {
    /// MAVLink 2, ardupilotmega dialect (ArduSub / BlueROV2), over UDP.
    Mavlink,
    /// IMC (LSTS DUNE), static unicast UDP.
    Imc,
    /// ROS 2 topics over DDS or rmw_zenoh (NavSatFix, Odometry, BatteryState; PoseStamped
    /// goals).
    Ros2,
}

/// The ROS 2 middleware of a `--proxy ros2` vehicle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum RmwKind {
    /// DDS (rmw_cyclonedds, rmw_fastrtps): topics `rt/<ns>/<name>`.
    Dds,
    /// rmw_zenoh (ROS 2's Tier-1 middleware since Kilted), through a Zenoh session.
    Zenoh,
}

/// Kinds of simulated vehicle.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum SimKind {
    Auv,
    Usv,
    Asv,
    Rov,
    Glider,
}

impl From<SimKind> for VehicleKind {
    fn from(k: SimKind) -> Self {
        match k {
            SimKind::Auv => Self::Auv,
            SimKind::Usv => Self::Usv,
            SimKind::Asv => Self::Asv,
            SimKind::Rov => Self::Rov,
            SimKind::Glider => Self::Glider,
        }
    }
}

/// Puts the process's role (`station`, a vehicle id) in front of every log line, so the
/// interleaved output of `shoal up`'s processes stays readable.
struct Labeled<F> {
    label: String,
    inner: F,
}

impl<S, N, F> tracing_subscriber::fmt::FormatEvent<S, N> for Labeled<F>
where
    S: tracing::Subscriber + for<'a> tracing_subscriber::registry::LookupSpan<'a>,
    N: for<'a> tracing_subscriber::fmt::FormatFields<'a> + 'static,
    F: tracing_subscriber::fmt::FormatEvent<S, N>,
{
    fn format_event(
        &self,
        ctx: &tracing_subscriber::fmt::FmtContext<'_, S, N>,
        mut writer: tracing_subscriber::fmt::format::Writer<'_>,
        event: &tracing::Event<'_>,
    ) -> std::fmt::Result {
        write!(writer, "{:<8} ", self.label)?;
        self.inner.format_event(ctx, writer, event)
    }
}

fn init_logging(label: &str, default_filter: &str) {
    use std::io::IsTerminal;
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default_filter));
    // Zenoh logs its whole configuration at debug when a session opens, the federation's
    // password ([federation] password) with it: that one module never logs below info,
    // whatever RUST_LOG says.
    let filter = match "zenoh::api::session=info".parse() {
        Ok(directive) => filter.add_directive(directive),
        Err(_) => filter,
    };
    let ansi = std::io::stderr().is_terminal();
    let format = tracing_subscriber::fmt::format()
        .with_target(false)
        .with_ansi(ansi);
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_ansi(ansi)
        .with_writer(std::io::stderr)
        .event_format(Labeled {
            label: label.to_string(),
            inner: format,
        })
        .init();
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => {
            #[cfg(not(feature = "console"))]
            if let Some(name) = left_out_command(&e) {
                eprintln!(
                    "shoal: error: `shoal {name}` is not in this build: it is the vehicle side \
                     only, built without the `console` feature (see docs/integrator-guide.md, \
                     \"Building the vehicle side\")"
                );
                return ExitCode::from(2);
            }
            e.exit()
        }
    };
    let label = match &cli.command {
        #[cfg(feature = "console")]
        Command::Up { .. } => "up".to_string(),
        #[cfg(feature = "console")]
        Command::Station { .. } => "station".to_string(),
        Command::Vehicle { id, .. } => id.clone(),
        Command::Swarm { .. } => "swarm".to_string(),
        Command::AcousticDemo { .. } => "acoustic".to_string(),
        #[cfg(feature = "console")]
        Command::Bench { .. } => "bench".to_string(),
        Command::Config { .. } => "config".to_string(),
        Command::Keys(_) => "keys".to_string(),
        Command::Ledger(_) => "ledger".to_string(),
        Command::Pdu { .. } => "pdu".to_string(),
        #[cfg(feature = "console")]
        Command::Query { .. } => "query".to_string(),
        Command::ModemEmu(_) => "modem-emu".to_string(),
        Command::Record(_) => "record".to_string(),
        Command::Replay(_) => "replay".to_string(),
        Command::Scenario(_) => "scenario".to_string(),
    };
    // A scenario run prints its own progress; its station's and vehicles' INFO lines
    // would bury it (RUST_LOG=info shows them).
    let default_filter = if matches!(cli.command, Command::Scenario(_)) {
        "warn,cyclonedds=warn"
    } else {
        "info,cyclonedds=warn"
    };
    init_logging(&label, default_filter);
    // Before the configuration is loaded: checking a file needs none, and an invalid
    // scenario has its own exit code.
    if let Command::Scenario(args) = &cli.command {
        #[cfg(feature = "console")]
        let offline = args.run_args().is_none();
        #[cfg(not(feature = "console"))]
        let offline = true;
        if offline {
            return scenario::run(args);
        }
    }
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // One clear line: the context chain, outermost first.
            eprintln!("shoal: error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// The station command a parse error is about, if this build leaves it out.
#[cfg(not(feature = "console"))]
fn left_out_command(e: &clap::Error) -> Option<String> {
    use clap::error::{ContextKind, ContextValue, ErrorKind};
    if e.kind() != ErrorKind::InvalidSubcommand {
        return None;
    }
    match e.get(ContextKind::InvalidSubcommand) {
        Some(ContextValue::String(name)) if STATION_COMMANDS.contains(&name.as_str()) => {
            Some(name.clone())
        }
        _ => None,
    }
}

fn run(cli: Cli) -> anyhow::Result<()> {
    let flags = match &cli.command {
        #[cfg(feature = "console")]
        Command::Station { listen, db, .. } => config::Flags {
            listen: *listen,
            db: db.clone(),
        },
        _ => config::Flags::default(),
    };
    let mut cfg = config::load(cli.config.as_deref(), &flags)?;
    if cli.insecure {
        cfg.security.enabled = false;
    }
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    match cli.command {
        #[cfg(feature = "console")]
        Command::Up {
            no_fleet,
            secure: _,
            sim_vehicles,
            scenario,
        } => rt.block_on(daemons::up(
            cli.config.as_deref(),
            &cfg,
            daemons::UpOptions {
                no_fleet,
                sim_vehicles,
                scenario,
            },
        )),
        Command::Swarm {
            count,
            rate,
            prefix,
            lat,
            lon,
            exit_on_stdin_close,
        } => {
            let spec = shoal_proxy::swarm::SwarmSpec {
                count,
                prefix,
                latitude_deg: lat,
                longitude_deg: lon,
                rate_hz: rate,
                ..shoal_proxy::swarm::SwarmSpec::default()
            };
            rt.block_on(daemons::swarm(&cfg, spec, exit_on_stdin_close))
        }
        Command::Keys(args) => keys::run(args, &cfg.security),
        Command::Ledger(args) => ledger::run(args, &cfg.vehicle),
        // --listen and --db are in `cfg` already: flags are its last layer.
        #[cfg(feature = "console")]
        Command::Station {
            exit_on_stdin_close,
            scenario,
            ..
        } => rt.block_on(daemons::station(cfg, &scenario, exit_on_stdin_close)),
        Command::Vehicle {
            sim,
            proxy: Some(kind),
            address,
            bind,
            namespace,
            rmw,
            proxy_config,
            id,
            rate,
            exit_on_stdin_close,
            ..
        } if sim.is_none() => {
            let flags = daemons::ProxyFlags {
                id,
                address,
                bind,
                namespace,
                rmw,
                config_file: proxy_config,
                rate_hz: rate,
            };
            rt.block_on(daemons::proxy(&cfg, kind, flags, exit_on_stdin_close))
        }
        Command::Vehicle {
            sim,
            id,
            lat,
            lon,
            rate,
            battery,
            scenario,
            exit_on_stdin_close,
            ..
        } => {
            let mut cfg = cfg;
            if let Some(source) = scenario
                .as_deref()
                .map(scenario::resolve)
                .transpose()?
                .flatten()
            {
                cfg.fleet.sim.ocean = scenario::load(&source)?.environment;
            }
            let spec = shoal_proxy::sim::SimSpec {
                id,
                kind: sim.unwrap_or(SimKind::Auv).into(),
                latitude_deg: lat,
                longitude_deg: lon,
                rate_hz: rate,
                battery_pct: battery,
            };
            rt.block_on(daemons::vehicle(&cfg, spec, exit_on_stdin_close))
        }
        #[cfg(feature = "console")]
        Command::Bench { which } => rt.block_on(bench::run(which, &cfg)),
        Command::AcousticDemo {
            scenario,
            exit_on_stdin_close,
        } => rt.block_on(daemons::acoustic_demo(
            &cfg,
            scenario.as_deref(),
            exit_on_stdin_close,
        )),
        Command::Pdu { which } => acoustic::pdu(which),
        #[cfg(feature = "console")]
        Command::Query {
            sparql,
            format,
            station,
            ca,
            token,
        } => {
            let tls = &cfg.console.tls;
            let target = query::Target::new(
                station.as_deref(),
                ca.as_deref(),
                cfg.console.listen,
                tls.enabled().then_some(tls.cert.as_path()),
            )?;
            let client = query::ApiClient::new(&target, token.as_deref())?;
            rt.block_on(query::run(&sparql, &format, &client))
        }
        Command::ModemEmu(args) => rt.block_on(acoustic::modem_emu(args)),
        Command::Record(args) => rt.block_on(record::record(&cfg, args)),
        Command::Replay(args) => rt.block_on(record::replay(&cfg, cli.config.as_deref(), args)),
        #[cfg(feature = "console")]
        Command::Scenario(args) => match args.run_args() {
            Some(run) => rt.block_on(async {
                let stop = daemons::shutdown_signal(false);
                scenario::run::run(&cfg, run, stop).await
            }),
            // `check` and `list` are run by `main` before the configuration is loaded.
            None => Ok(()),
        },
        #[cfg(not(feature = "console"))]
        Command::Scenario(_) => Ok(()),
        Command::Config { default } => {
            if default {
                print!("{}", config::DEFAULT_CONFIG);
            } else {
                print!("{}", toml::to_string(&cfg)?);
            }
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::panic)]
    use super::*;

    /// A vehicle build names the station commands it lacks instead of "unrecognized
    /// subcommand", and says so in --help.
    #[cfg(not(feature = "console"))]
    #[test]
    fn a_vehicle_build_says_which_commands_it_leaves_out() {
        use clap::CommandFactory;
        for name in STATION_COMMANDS {
            let e = Cli::try_parse_from(["shoal", "--config", "x.toml", name]).unwrap_err();
            assert_eq!(left_out_command(&e).as_deref(), Some(name));
        }
        let e = Cli::try_parse_from(["shoal", "statoin"]).unwrap_err();
        assert_eq!(left_out_command(&e), None);
        let help = Cli::command().render_long_help().to_string();
        assert!(help.contains("vehicle side only"), "{help}");
        assert!(!help.contains("\n  station "), "{help}");
        assert!(Cli::try_parse_from(["shoal", "vehicle", "--sim", "auv", "--id", "a"]).is_ok());
    }

    #[cfg(feature = "console")]
    #[test]
    fn station_flags_become_the_last_configuration_layer() {
        let cli = Cli::try_parse_from(["shoal", "station", "--db", ":memory:"]).unwrap();
        let Command::Station { db, .. } = cli.command else {
            panic!("not the station command");
        };
        assert_eq!(db, Some(PathBuf::from(":memory:")));
    }

    /// A simulated vehicle may take its ocean from a scenario; a proxy for a real one has
    /// the real sea and refuses the flag.
    #[test]
    fn only_a_simulated_vehicle_takes_a_scenarios_ocean() {
        let ok = [
            "shoal",
            "vehicle",
            "--sim",
            "usv",
            "--id",
            "a",
            "--scenario",
            "harbour-survey",
        ];
        let Command::Vehicle { scenario, .. } = Cli::try_parse_from(ok).unwrap().command else {
            panic!("not the vehicle command");
        };
        assert_eq!(scenario.as_deref(), Some("harbour-survey"));
        let proxy = [
            "shoal",
            "vehicle",
            "--proxy",
            "mavlink",
            "--id",
            "a",
            "--scenario",
            "x",
        ];
        assert!(Cli::try_parse_from(proxy).is_err());
    }
}
