//! `shoal bench`: programs that print figures (never timed tests), one module each:
//!
//! - [`bus`]: state-vector round trip (p50/p99) and the highest reliable rate delivered
//!   without loss, between two processes, with Cyclone DDS's `ddsperf` measured in the
//!   same run on the same host and the ratios printed.
//! - [`ingest`]: station ingest rate from simulated vehicles in another process, and loss.
//! - [`soak`]: resident memory before, during and after many writes.
//! - [`pipeline`]: the station's Data Access Manager in one process (validation,
//!   plausibility, latest state, semantic model with 10 rules, history commit) against a
//!   raw batched SQLite insert of the same rows in the same run.
//! - [`acoustic`]: PDU sizes, channel use, emergency latency and control delivery on
//!   emulated modems.
//! - [`semantic`]: the standard SPARQL queries at fleet scale, fresh and through a
//!   simulated hour of traffic.
//! - [`scale`], [`latency`], [`late_joiner`]: a station with thousands of vehicles, the
//!   vehicle-to-console latency, late-joining participants.
//! - [`replay`]: an hour of a fleet's recording (MCAP) replayed at 100× to a subscriber
//!   in another process: wall time against the ideal, loss, lag behind the schedule.
//! - [`scenario`]: a scenario run headless at a speed-up, start to report, against its
//!   target.
//! - [`federation`]: three sites' stations over [`wan`], a user-space satellite WAN
//!   between network namespaces (delay, rate, loss, outage on TUN devices).
//! - [`suite`]: every target in one table, each beside its peer.
//! - [`helpers`]: what several of them share (participants, helper processes,
//!   percentiles, memory, the machine and date of a run).
//!
//! Helper processes (`pong`, `sink`, `load`, `replay-sink`, `endurance-fleet`,
//! `endurance-station`) are hidden subcommands of the same binary so the two sides of each
//! measurement are separate DDS participants, as in deployment.

mod acoustic;
mod bus;
mod endurance;
mod federation;
mod helpers;
mod ingest;
mod late_joiner;
mod latency;
mod pipeline;
mod replay;
mod scale;
mod scenario;
mod security;
mod semantic;
mod soak;
mod suite;
mod wan;

use anyhow::Result;
use clap::Subcommand;

use crate::config::ShoalConfig;

/// Which benchmark to run.
#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// Round trip and throughput of the bus, side by side with Cyclone DDS's ddsperf.
    Bus {
        /// Seconds of round trips for each implementation.
        #[arg(long, default_value_t = 10)]
        seconds: u64,
        /// First DDS domain of the measurement: Shoal uses it and the third and eighth after it, ddsperf the next two.
        #[arg(long, default_value_t = 80)]
        domain: u16,
        /// Skip the ddsperf comparison.
        #[arg(long)]
        no_peer: bool,
    },
    /// Station ingest: simulated vehicles in another process publish state vectors.
    Ingest {
        /// Number of vehicles.
        #[arg(long, default_value_t = 100)]
        vehicles: usize,
        /// State vectors per second per vehicle.
        #[arg(long, default_value_t = 250.0)]
        rate: f64,
        /// Seconds of load.
        #[arg(long, default_value_t = 10.0)]
        seconds: f64,
        /// DDS domain for the measurement.
        #[arg(long, default_value_t = 83)]
        domain: u16,
    },
    /// The Data Access Manager without the bus: validate + plausibility + latest state +
    /// semantic model with 10 rules + history commit, against a raw batched SQLite insert
    /// of the same rows in the same run.
    Pipeline {
        /// Number of vehicles.
        #[arg(long, default_value_t = 1000)]
        vehicles: usize,
        /// State vectors in all.
        #[arg(long, default_value_t = pipeline::DEFAULT_ROWS)]
        rows: usize,
        /// DDS domain of the station's (idle) participant.
        #[arg(long, default_value_t = 85)]
        domain: u16,
    },
    /// Resident memory before, during and after N writes (writer and reader in this process).
    Soak {
        /// Number of state vectors to write.
        #[arg(long, default_value_t = 300_000)]
        writes: u64,
        /// Instances (vehicle ids) the writes cycle through.
        #[arg(long, default_value_t = 100)]
        instances: u32,
        /// DDS domain for the measurement.
        #[arg(long, default_value_t = 84)]
        domain: u16,
    },
    /// The acoustic link against its goals: PDU sizes vs DCCL (20 B) and SWARMs (51 B),
    /// channel use under saturation, emergency latency under load, control delivery at
    /// 30 % packet loss. Emulated modems on 127.0.0.1; figures in simulated time.
    Acoustic {
        /// Wall-clock seconds per simulated second (smaller is faster).
        #[arg(long, default_value_t = 0.05)]
        time_scale: f64,
        /// Wall-clock seconds per simulated second of the four-vehicle TDMA measurements.
        #[arg(long, default_value_t = 0.25)]
        fleet_time_scale: f64,
    },
    /// The semantic store's five standard SPARQL queries at fleet scale, in this process
    /// (no DDS): `burst` on a fresh fleet and after a burst of state mirrors, `hour`
    /// through a simulated hour of fleet traffic, with memory.
    Semantic {
        #[command(subcommand)]
        which: semantic::SemanticCommand,
    },
    /// Scale: a `shoal station` and N lightweight vehicles (`shoal swarm`), each its own
    /// process, on loopback: vehicles alive, ingest rate and the resident memory of both
    /// processes, every 10 s and at the end.
    Scale {
        /// Number of vehicles.
        #[arg(long, default_value_t = 10_000)]
        vehicles: usize,
        /// State vectors per second per vehicle.
        #[arg(long, default_value_t = 1.0)]
        rate: f64,
        /// Seconds to run once every vehicle is alive (or after 120 s of trying).
        #[arg(long, default_value_t = 60)]
        seconds: u64,
        /// DDS domain for the measurement.
        #[arg(long, default_value_t = 24)]
        domain: u16,
    },
    /// Every figure that has a target, in one run and one table, each beside its target
    /// and, where there is one, the peer measured in the same run (Cyclone DDS ddsperf, a
    /// raw batched SQLite insert); saved as Markdown under `--out`.
    Suite {
        /// Seconds of round trips (and of latency measurement) per figure.
        #[arg(long, default_value_t = 10)]
        seconds: u64,
        /// Vehicles of the scale figure.
        #[arg(long, default_value_t = 10_000)]
        scale_vehicles: usize,
        /// Directory the Markdown report is written to.
        #[arg(long, default_value = "bench/runs")]
        out: std::path::PathBuf,
        /// First DDS domain (the suite uses the next eight).
        #[arg(long, default_value_t = 30)]
        domain: u16,
        /// Simulated seconds of fleet traffic through the semantic store before the
        /// queries are measured again (0 skips it; an hour takes about 2 minutes).
        #[arg(long, default_value_t = 3600)]
        semantic_hour_s: u64,
    },
    /// End-to-end latency, vehicle -> station -> console: N lightweight vehicles in another
    /// process (`shoal swarm`, each state stamped when sent) and a WebSocket client on the
    /// console's live feed, as the web console reads it; p50/p99 of arrival minus stamp.
    Latency {
        /// Number of vehicles.
        #[arg(long, default_value_t = 1000)]
        vehicles: usize,
        /// State vectors per second per vehicle.
        #[arg(long, default_value_t = 1.0)]
        rate: f64,
        /// Seconds of measurement after a 5 s warm-up.
        #[arg(long, default_value_t = 30)]
        seconds: u64,
        /// DDS domain for the measurement.
        #[arg(long, default_value_t = 25)]
        domain: u16,
    },
    /// Late joiners: a station publishes a task, then a vehicle's participant joins; does it
    /// get the task (transient-local durability)? Repeated N times, each with a new
    /// participant, and timed.
    LateJoiner {
        /// Trials.
        #[arg(long, default_value_t = 1000)]
        trials: usize,
        /// DDS domain for the measurement.
        #[arg(long, default_value_t = 26)]
        domain: u16,
    },
    /// A deployment's lifetime compressed: back-to-back tasks for a simulated fleet (in a
    /// process of its own) with vehicle restarts, a station restart and a clock step; the
    /// station's and the fleet's memory, history size, the late-joiner burst and the
    /// tasks-by-state query over time, and tasks run twice.
    Endurance {
        /// Number of vehicles.
        #[arg(long, default_value_t = 200)]
        vehicles: usize,
        /// Tasks to complete.
        #[arg(long, default_value_t = 100_000)]
        tasks: u64,
        /// Completed tasks between two rows of the report.
        #[arg(long, default_value_t = 10_000)]
        report_every: u64,
        /// DDS domain for the measurement.
        #[arg(long, default_value_t = 40)]
        domain: u16,
        /// Also write the report (Markdown) here, e.g. under bench/runs/.
        #[arg(long)]
        out: Option<std::path::PathBuf>,
    },
    /// What OMG DDS Security costs, secure beside insecure in one run: the bus round trip
    /// (two processes) and the time until one participant hears N others.
    Security {
        /// Seconds of round trips for each.
        #[arg(long, default_value_t = 10)]
        seconds: u64,
        /// Participants to discover.
        #[arg(long, default_value_t = 100)]
        participants: usize,
        /// First of the eight DDS domains the measurement uses.
        #[arg(long, default_value_t = 74)]
        domain: u16,
    },
    /// Replay: an hour at 100 vehicles (by default) written into an MCAP recording, then
    /// replayed at 100× to a subscriber in another process; wall time against the ideal,
    /// loss, and the lag of each state vector behind its due instant.
    Replay {
        /// Number of vehicles (each one announcement and a state vector per second).
        #[arg(long, default_value_t = 100)]
        vehicles: usize,
        /// Seconds of recorded time.
        #[arg(long, default_value_t = 3600)]
        seconds: u64,
        /// Times the recorded pace, 1 to 100.
        #[arg(long, default_value_t = 100.0)]
        speed: f64,
        /// DDS domain for the measurement.
        #[arg(long, default_value_t = 86)]
        domain: u16,
    },
    /// A scenario run headless (`shoal scenario run`), timed from start to report written:
    /// by default one simulated hour of `harbour-survey` at 60x (target: 2 minutes).
    Scenario {
        /// The scenario: a file or a shipped name.
        #[arg(long, default_value = "harbour-survey")]
        name: String,
        /// Simulated seconds per real second.
        #[arg(long, default_value_t = 60.0)]
        speed: f64,
        /// Simulated seconds to run.
        #[arg(long, default_value_t = 3600.0)]
        seconds: f64,
        /// DDS domain for the run.
        #[arg(long, default_value_t = 87)]
        domain: u16,
    },
    /// The federation over an emulated satellite WAN (network namespaces, TUN devices):
    /// a ship, the shore and a second ship; backlog, uplink per added site, alarm latency
    /// and exactly-once across an outage. Needs root.
    Federation(federation::Plan),
    /// (helper) One ship's load for `bench federation`, in its namespace.
    #[command(hide = true)]
    WanLoad(federation::LoadArgs),
    /// (helper) Echo pings back as pongs.
    #[command(hide = true)]
    Pong {
        #[arg(long)]
        domain: u16,
        /// Secure the participant with a station identity from this DDS keystore.
        #[arg(long)]
        keystore: Option<std::path::PathBuf>,
        /// Answer in a listener on Cyclone's receive thread, or in a task.
        #[arg(long, value_enum, default_value_t = bus::ReceivePath::Stream)]
        delivery: bus::ReceivePath,
    },
    /// (helper) Participants that each publish their own state.
    #[command(hide = true)]
    Crowd {
        #[arg(long)]
        domain: u16,
        #[arg(long)]
        count: usize,
        /// Secure each with its own vehicle identity from this DDS keystore.
        #[arg(long)]
        keystore: Option<std::path::PathBuf>,
    },
    /// (helper) Count throughput samples per step and print the counts.
    #[command(hide = true)]
    Sink {
        #[arg(long)]
        domain: u16,
    },
    /// (helper) Count replayed state vectors and stamp their arrival.
    #[command(hide = true)]
    ReplaySink {
        #[arg(long)]
        domain: u16,
    },
    /// (helper) The endurance benchmark's fleet, with its task ledgers under `dir`, driven
    /// line by line over stdin and stdout by `bench endurance`.
    #[command(hide = true)]
    EnduranceFleet {
        #[arg(long)]
        domain: u16,
        #[arg(long)]
        vehicles: usize,
        #[arg(long)]
        dir: std::path::PathBuf,
    },
    /// (helper) The station of `bench endurance` in its own process, driven on stdin.
    #[command(hide = true)]
    EnduranceStation {
        #[arg(long)]
        domain: u16,
        #[arg(long)]
        vehicles: usize,
        #[arg(long)]
        tasks: u64,
        #[arg(long)]
        first_task: u64,
        #[arg(long, default_value_t = 0)]
        clock_offset_ms: i64,
        #[arg(long)]
        dir: std::path::PathBuf,
    },
    /// (helper) `shoal swarm`'s vehicles on one participant, secured with a station
    /// identity when the process that starts it is (`bench security`'s latency): no
    /// vehicle's permissions allow one participant to speak for a thousand vehicles.
    #[command(hide = true)]
    Swarm {
        #[arg(long)]
        domain: u16,
        #[arg(long)]
        count: usize,
        #[arg(long)]
        rate: f64,
    },
    /// (helper) Announce vehicles and publish their state vectors at a rate.
    #[command(hide = true)]
    Load {
        #[arg(long)]
        domain: u16,
        #[arg(long)]
        vehicles: usize,
        #[arg(long)]
        rate: f64,
        #[arg(long)]
        seconds: f64,
    },
}
/// Runs one benchmark.
pub async fn run(which: BenchCommand, cfg: &ShoalConfig) -> Result<()> {
    // Measurements run insecure (their peers, ddsperf and the foreign DDS stacks, are)
    // unless `bench security` says otherwise; helper processes get their setting from the
    // process that starts them.
    let helper_process = matches!(
        which,
        BenchCommand::Pong { .. }
            | BenchCommand::Sink { .. }
            | BenchCommand::Load { .. }
            | BenchCommand::Crowd { .. }
            | BenchCommand::ReplaySink { .. }
            | BenchCommand::EnduranceFleet { .. }
            | BenchCommand::EnduranceStation { .. }
            | BenchCommand::Swarm { .. }
    );
    let mut owned = cfg.clone();
    if !helper_process {
        owned.security.enabled = false;
    }
    let cfg = &owned;
    match which {
        BenchCommand::Bus {
            seconds,
            domain,
            no_peer,
        } => bus::bus(cfg, domain, seconds, no_peer).await,
        BenchCommand::Ingest {
            vehicles,
            rate,
            seconds,
            domain,
        } => ingest::ingest(cfg, domain, vehicles, rate, seconds).await,
        BenchCommand::Pipeline {
            vehicles,
            rows,
            domain,
        } => pipeline::pipeline(cfg, domain, vehicles, rows).await,
        BenchCommand::Soak {
            writes,
            instances,
            domain,
        } => soak::soak(cfg, domain, writes, instances).await,
        BenchCommand::Acoustic {
            time_scale,
            fleet_time_scale,
        } => acoustic::acoustic(time_scale, fleet_time_scale).await,
        BenchCommand::Scenario {
            name,
            speed,
            seconds,
            domain,
        } => scenario::scenario(cfg, &name, speed, seconds, domain).await,
        BenchCommand::Semantic { which } => {
            tokio::task::spawn_blocking(move || semantic::semantic(which)).await?
        }
        BenchCommand::Latency {
            vehicles,
            rate,
            seconds,
            domain,
        } => latency::latency(cfg, vehicles, rate, seconds, domain).await,
        BenchCommand::LateJoiner { trials, domain } => {
            late_joiner::late_joiner(cfg, trials, domain).await
        }
        BenchCommand::Suite {
            seconds,
            scale_vehicles,
            out,
            domain,
            semantic_hour_s,
        } => suite::suite(cfg, seconds, scale_vehicles, &out, domain, semantic_hour_s).await,
        BenchCommand::Scale {
            vehicles,
            rate,
            seconds,
            domain,
        } => scale::scale(vehicles, rate, seconds, domain).await,
        BenchCommand::Endurance {
            vehicles,
            tasks,
            report_every,
            domain,
            out,
        } => {
            let plan = endurance::Plan {
                vehicles,
                tasks,
                report_every,
                domain,
                out,
            };
            endurance::endurance(cfg, plan).await
        }
        BenchCommand::Security {
            seconds,
            participants,
            domain,
        } => security::security(cfg, domain, seconds, participants).await,
        BenchCommand::Replay {
            vehicles,
            seconds,
            speed,
            domain,
        } => {
            let plan = replay::Plan {
                vehicles,
                seconds,
                speed,
                domain,
            };
            replay::replay(cfg, plan).await
        }
        BenchCommand::Federation(plan) => federation::federation(plan).await,
        BenchCommand::WanLoad(args) => federation::wan_load(cfg, args).await,
        BenchCommand::Pong {
            domain,
            keystore,
            delivery,
        } => bus::pong(cfg, domain, keystore.as_deref(), delivery).await,
        BenchCommand::Crowd {
            domain,
            count,
            keystore,
        } => security::crowd(cfg, domain, count, keystore.as_deref()).await,
        BenchCommand::Sink { domain } => bus::sink(cfg, domain).await,
        BenchCommand::ReplaySink { domain } => replay::sink(cfg, domain).await,
        BenchCommand::EnduranceFleet {
            domain,
            vehicles,
            dir,
        } => endurance::fleet(cfg, domain, vehicles, &dir).await,
        BenchCommand::EnduranceStation {
            domain,
            vehicles,
            tasks,
            first_task,
            clock_offset_ms,
            dir,
        } => {
            let args = endurance::StationArgs {
                domain,
                vehicles,
                tasks,
                first_task,
                clock_offset_ms,
            };
            endurance::station(cfg, args, &dir).await
        }
        BenchCommand::Load {
            domain,
            vehicles,
            rate,
            seconds,
        } => ingest::load(cfg, domain, vehicles, rate, seconds).await,
        BenchCommand::Swarm {
            domain,
            count,
            rate,
        } => latency::swarm(cfg, domain, count, rate).await,
    }
}
