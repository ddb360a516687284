//! `shoal scenario run`: a scenario headless in one process — a station and the
//! scenario's simulated vehicles on a private loopback DDS domain, all on one simulated
//! clock run `--speed` times as fast as real time — and its report directory.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Args;
use std::collections::HashMap;

use shoal_dds::PubSub;
use shoal_history::{Backend, History};
use shoal_model::{StateVector, TaskState, Warp};
use shoal_proxy::sim::SimFault;
use shoal_scenario::report::{
    self, FaultRecord, RunRecord, StationFigures, TaskRecord, VehicleRecord,
};
use shoal_scenario::{Fault, MAX_DURATION_S, Scenario};
use tokio_util::sync::CancellationToken;
use tracing::{info, warn};

use super::sea::AcousticNet;
use super::world::{Fleet, StationRun, missions_after};
use crate::config::ShoalConfig;

/// Fastest run: a vehicle reports at most 100 times a real second, so beyond this a 1 Hz
/// vehicle's reports thin out in simulated time.
pub const MAX_SPEED: f64 = 100.0;
/// The DDS domain of a run unless `--domain` says otherwise: not the default domain 0, so
/// a run never mixes with a station that `shoal up` runs on the same host.
pub const DEFAULT_DOMAIN: u16 = 200;
/// Most rows of one kind read back for the report.
const READ_LIMIT: usize = 1_000_000;

/// `shoal scenario run FILE`.
#[derive(Debug, Args)]
#[command(
    after_help = "Example: shoal scenario run sea-trial --speed 60 --duration 600 --out runs/trial-1\n\n\
The report directory holds report.html (open it in a browser; it needs no network), \
summary.json (the figures), history.sqlite (every state, task and event the station \
stored) and recording/ (every DDS sample, as MCAP; with [recorder] acoustic = true also the \
acoustic relay's frames and link events, in PREFIX-acoustic-*.mcap)."
)]
pub struct RunArgs {
    /// The scenario: a TOML file, or the name of a shipped one (`shoal scenario list`).
    #[arg(value_name = "FILE")]
    file: String,
    /// Simulated seconds per real second, at most 100 (default: the scenario's
    /// `time_scale`).
    #[arg(long)]
    speed: Option<f64>,
    /// Seed of the simulated vehicles' random draws (detections, environment noise); each
    /// vehicle draws from the seed and its id.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Simulated seconds to run (default: the scenario's `duration_s`).
    #[arg(long, value_name = "SECONDS")]
    duration: Option<f64>,
    /// Directory for the report, created; it must not hold anything yet (default:
    /// scenario-runs/<scenario>-<UTC time>).
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// DDS domain of the run (loopback only), so it does not mix with a running station.
    #[arg(long, default_value_t = DEFAULT_DOMAIN)]
    domain: u16,
}

impl RunArgs {
    /// A run of `file` for `duration_s` simulated seconds at `speed` into `out` on DDS
    /// domain `domain`, seed 1 (what `shoal bench scenario` runs).
    pub fn new(file: &str, speed: f64, duration_s: f64, out: &Path, domain: u16) -> Self {
        Self {
            file: file.to_owned(),
            speed: Some(speed),
            seed: 1,
            duration: Some(duration_s),
            out: Some(out.to_path_buf()),
            domain,
        }
    }
}

/// The run's settings, checked before anything starts.
struct Plan {
    scenario: Scenario,
    speed: f64,
    duration_s: f64,
    dir: PathBuf,
    cfg: ShoalConfig,
}

fn plan(cfg: &ShoalConfig, args: &RunArgs) -> Result<Plan> {
    let source = super::resolve(&args.file)?.context("`none` is not a scenario to run")?;
    let mut scenario = super::load(&source)?;
    let speed = args.speed.unwrap_or(scenario.time_scale);
    if !(speed.is_finite() && speed > 0.0 && speed <= MAX_SPEED) {
        bail!("--speed must be in (0, {MAX_SPEED}] simulated seconds per real second, not {speed}");
    }
    let duration_s = args.duration.unwrap_or(scenario.duration_s);
    if !(duration_s.is_finite() && duration_s > 0.0 && duration_s <= MAX_DURATION_S) {
        bail!("--duration must be in (0, {MAX_DURATION_S}] seconds, not {duration_s}");
    }
    scenario.duration_s = duration_s;
    let dir = args
        .out
        .clone()
        .unwrap_or_else(|| default_dir(&scenario.name));
    let mut cfg = cfg.clone();
    cfg.dds.domain_id = args.domain;
    if !cfg.dds.is_loopback_only() {
        bail!(
            "a scenario run keeps its simulated fleet on this host: [dds] interfaces must be loopback addresses, not {:?}",
            cfg.dds.interfaces
        );
    }
    // Everything the run stores goes into its report directory.
    cfg.history.backend = Backend::Sqlite;
    cfg.history.path = dir.join("history.sqlite");
    cfg.recorder.enabled = true;
    cfg.recorder.directory = dir.join("recording");
    // Every simulated vehicle, on IP or acoustic, samples the scenario's ocean.
    cfg.fleet.sim.ocean = scenario.environment.clone();
    Ok(Plan {
        scenario,
        speed,
        duration_s,
        dir,
        cfg,
    })
}

fn default_dir(name: &str) -> PathBuf {
    let now = time::OffsetDateTime::now_utc();
    PathBuf::from("scenario-runs").join(format!(
        "{name}-{:04}{:02}{:02}T{:02}{:02}{:02}Z",
        now.year(),
        u8::from(now.month()),
        now.day(),
        now.hour(),
        now.minute(),
        now.second()
    ))
}

/// Creates the report directory; one that already holds files is refused, so a run never
/// mixes its history with another's.
fn create_dir(dir: &Path) -> Result<()> {
    if dir.exists() {
        let mut entries = std::fs::read_dir(dir)
            .with_context(|| format!("cannot read the report directory {}", dir.display()))?;
        if entries.next().is_some() {
            bail!(
                "the report directory {} is not empty: name another with --out",
                dir.display()
            );
        }
    }
    std::fs::create_dir_all(dir)
        .with_context(|| format!("cannot create the report directory {}", dir.display()))
}

/// A vehicle's seed: the run's seed and its id, so vehicles draw differently and a
/// vehicle draws the same in every run with the same seed.
pub(super) fn vehicle_seed(seed: u64, id: &str) -> u64 {
    // FNV-1a over the id, from the seed.
    id.bytes().fold(
        0xcbf2_9ce4_8422_2325 ^ seed.wrapping_mul(0x9e37_79b9_7f4a_7c15),
        |h, b| (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3),
    )
}

/// What happens next on the run's timeline.
#[derive(Debug, Clone)]
enum Action {
    /// A fault of the scenario.
    Fault(Fault),
    /// A failed vehicle's computer starts again.
    RestartVehicle(String),
    /// The station starts again after a restart fault; it went down this many simulated
    /// seconds into the run.
    StartStation(f64),
    /// A silenced modem works again: an acoustic vehicle's, or the relay's (`None`).
    ModemBack(Option<String>),
}

/// Runs a scenario headless and writes its report; Ctrl-C ends it early with a report of
/// what ran.
pub async fn run(cfg: &ShoalConfig, args: &RunArgs, stop: CancellationToken) -> Result<()> {
    let Plan {
        scenario,
        speed,
        duration_s,
        dir,
        cfg,
    } = plan(cfg, args)?;
    create_dir(&dir)?;
    eprintln!(
        "shoal: running scenario {:?} for {} simulated at {speed}x (about {:.0} s), seed {}, {} faults, into {}",
        scenario.name,
        format_s(duration_s),
        duration_s / speed,
        args.seed,
        scenario.faults.len(),
        dir.display()
    );
    info!(
        domain = cfg.dds.domain_id,
        "simulated fleet on loopback only, DDS security off (a closed simulation)"
    );
    // The recorder has a participant of its own, so a station restart does not cut it.
    let recorder_dds = Arc::new(PubSub::new(&cfg.dds).context("cannot join DDS")?);
    let recorder = shoal_recorder::Recorder::start(&recorder_dds, &cfg.recorder)
        .context("cannot start the run's recording")?;
    let warp = Warp::start(speed)?;
    let mut station = StationRun::new(cfg.clone(), warp);
    station.start(scenario.clone())?;
    let specs = super::fleet(&scenario);
    let rogue = scenario
        .faults
        .iter()
        .any(|f| matches!(f.fault, Fault::RogueSample { .. }));
    let mut fleet = Fleet::new(&cfg, warp, args.seed, dir.join("vehicles"), specs, rogue)?;
    fleet.start_all();
    let acoustic = AcousticNet::start(&cfg, &scenario, warp, args.seed, dir.join("vehicles"))?;

    let started = Instant::now();
    let start_ms = warp.origin_ms();
    let at = |s: f64| start_ms.saturating_add((s * 1000.0) as i64);
    let end_ms = at(duration_s);
    let mut timeline: Vec<(i64, Action)> = scenario
        .faults
        .iter()
        .map(|f| (at(f.at_s), Action::Fault(f.fault.clone())))
        .collect();
    let mut faults = Vec::new();
    let mut last_states: HashMap<String, StateVector> = HashMap::new();
    let mut progress = tokio::time::interval(Duration::from_secs(2));
    progress.tick().await;
    let stopped_early = loop {
        let now = warp.now_ms();
        timeline.sort_by_key(|(due, _)| *due);
        while timeline.first().is_some_and(|(due, _)| *due <= now) {
            let (_, action) = timeline.remove(0);
            #[allow(clippy::cast_precision_loss)]
            let at_s = (now - start_ms) as f64 / 1000.0;
            if let Some(h) = station.handle() {
                for v in h.fleet() {
                    if let Some(s) = v.latest {
                        last_states.insert(s.vehicle_id.clone(), s);
                    }
                }
            }
            let what = apply(
                action,
                &mut station,
                &mut fleet,
                acoustic.as_ref(),
                &scenario,
                &last_states,
                at_s,
                now,
                &mut timeline,
            )
            .await?;
            eprintln!("  {} fault: {what}", format_s(at_s));
            faults.push(FaultRecord {
                at_s: round_s(at_s),
                what,
            });
        }
        if now >= end_ms {
            break false;
        }
        // A fault may have put a restart on the timeline, before what was first.
        timeline.sort_by_key(|(due, _)| *due);
        let next = timeline
            .first()
            .map_or(end_ms, |(due, _)| (*due).min(end_ms));
        let wait = warp.real(Duration::from_millis(
            u64::try_from(next - now).unwrap_or(0),
        ));
        tokio::select! {
            () = stop.cancelled() => break true,
            () = tokio::time::sleep(wait) => {}
            _ = progress.tick() => eprintln!("{}", progress_line(station.handle(), warp.now_ms() - start_ms, duration_s)),
        }
    };
    if stopped_early {
        eprintln!("shoal: stopping early; the report covers what ran");
    }
    let end_ms = warp.now_ms().min(end_ms);
    // Vehicles first, then the station a moment later, so what they sent last is stored.
    fleet.stop_all().await;
    let mut acoustic_figures = RunRecord::default();
    if let Some(a) = acoustic {
        a.report(&mut acoustic_figures);
        a.stop().await;
    }
    tokio::time::sleep(Duration::from_millis(300)).await;
    station.stop().await?;
    match recorder.stop().await {
        Ok(s) => info!(
            files = s.files,
            messages = s.messages,
            bytes = s.bytes,
            "recording closed"
        ),
        Err(e) => {
            warn!(error = %e, "recording failed; its files are readable up to their last chunk");
        }
    }
    let wall_s = started.elapsed().as_secs_f64();
    let mut record = read_back(
        &cfg,
        &scenario,
        args.seed,
        speed,
        (start_ms, end_ms),
        wall_s,
        station.figures(),
    )?;
    record.faults = faults;
    record.links = acoustic_figures.links;
    record.acoustic_latency_ms = acoustic_figures.acoustic_latency_ms;
    record.link_quality = acoustic_figures.link_quality;
    record.airtime_s = acoustic_figures.airtime_s;
    record.rule_ids = station.rule_ids();
    let summary = report::summarise(&record);
    let json = serde_json::to_string_pretty(&summary).context("cannot write the summary")?;
    std::fs::write(dir.join("summary.json"), json + "\n")
        .with_context(|| format!("cannot write {}", dir.join("summary.json").display()))?;
    std::fs::write(
        dir.join("report.html"),
        report::render_html(&record, &summary),
    )
    .with_context(|| format!("cannot write {}", dir.join("report.html").display()))?;
    eprintln!("{}", closing_line(&summary, &dir));
    Ok(())
}

fn round_s(s: f64) -> f64 {
    (s * 10.0).round() / 10.0
}

/// Carries out one action of the timeline; returns what to tell about it (one line).
#[allow(clippy::too_many_arguments)]
async fn apply(
    action: Action,
    station: &mut StationRun,
    fleet: &mut Fleet,
    acoustic: Option<&AcousticNet>,
    scenario: &Scenario,
    last: &HashMap<String, StateVector>,
    at_s: f64,
    now_ms: i64,
    timeline: &mut Vec<(i64, Action)>,
) -> Result<String> {
    let later = |s: f64| now_ms.saturating_add((s * 1000.0) as i64);
    Ok(match action {
        Action::Fault(Fault::VehicleFailure {
            vehicle,
            restart_after_s,
        }) => {
            fleet.stop(&vehicle);
            if let Some(a) = acoustic {
                a.fail(&vehicle);
            }
            match restart_after_s {
                Some(r) => {
                    timeline.push((later(r), Action::RestartVehicle(vehicle.clone())));
                    format!("{vehicle} fails; it starts again in {r} s")
                }
                None => format!("{vehicle} fails for good"),
            }
        }
        Action::RestartVehicle(vehicle) => {
            fleet.start(&vehicle, last.get(&vehicle));
            if let Some(a) = acoustic {
                a.restart(&vehicle, last.get(&vehicle));
            }
            format!("{vehicle} starts again where it was")
        }
        Action::Fault(Fault::BatteryDrop {
            vehicle,
            battery_pct,
        }) => {
            let fault = SimFault::BatteryDrop(battery_pct);
            if fleet.inject(&vehicle, fault) || acoustic.is_some_and(|a| a.inject(&vehicle, fault))
            {
                format!("{vehicle}'s battery drops to {battery_pct} %")
            } else {
                format!("{vehicle}'s battery drop not injected: the vehicle is down")
            }
        }
        Action::Fault(Fault::RogueSample { vehicle }) => match last.get(&vehicle) {
            Some(s) => {
                fleet.rogue_sample(s).await?;
                format!("another participant publishes {vehicle} 55 km from where it is")
            }
            None => format!("no rogue sample for {vehicle}: the station has no position of it yet"),
        },
        Action::Fault(Fault::StationRestart { down_s }) => {
            station.stop().await?;
            timeline.push((later(down_s), Action::StartStation(at_s)));
            format!("the station stops; it starts again in {down_s} s")
        }
        Action::Fault(Fault::LinkOutage {
            vehicle,
            duration_s,
        }) => {
            if acoustic.is_some_and(|a| a.set_silent(Some(&vehicle), true)) {
                timeline.push((later(duration_s), Action::ModemBack(Some(vehicle.clone()))));
                format!("{vehicle}'s acoustic link is cut for {duration_s} s")
            } else {
                format!("{vehicle}'s link outage not injected: the acoustic network is not up")
            }
        }
        Action::Fault(Fault::ModemFailure {
            vehicle,
            repaired_after_s,
        }) => {
            let whose = vehicle
                .as_deref()
                .map_or_else(|| "the relay's".to_owned(), |v| format!("{v}'s"));
            if !acoustic.is_some_and(|a| a.set_silent(vehicle.as_deref(), true)) {
                format!("{whose} modem failure not injected: the acoustic network is not up")
            } else if let Some(r) = repaired_after_s {
                timeline.push((later(r), Action::ModemBack(vehicle)));
                format!("{whose} modem fails; it works again in {r} s")
            } else {
                format!("{whose} modem fails for good")
            }
        }
        Action::ModemBack(vehicle) => {
            let whose = vehicle
                .as_deref()
                .map_or_else(|| "the relay's".to_owned(), |v| format!("{v}'s"));
            if acoustic.is_some_and(|a| a.set_silent(vehicle.as_deref(), false)) {
                format!("{whose} modem works again")
            } else {
                format!("{whose} modem not brought back: the acoustic network is not up")
            }
        }
        Action::StartStation(went_down_s) => {
            // Missions due while it was down start now; those it ran are in the register.
            station.start(missions_after(scenario, went_down_s))?;
            "the station starts again over the same history".to_owned()
        }
    })
}

/// Reads what the station stored during the run back from its history store.
fn read_back(
    cfg: &ShoalConfig,
    scenario: &Scenario,
    seed: u64,
    speed: f64,
    (start_ms, end_ms): (i64, i64),
    wall_s: f64,
    station: StationFigures,
) -> Result<RunRecord> {
    let history = History::open(&cfg.history).context("cannot read the run's history store")?;
    let reader = history.reader();
    let mut vehicles = Vec::new();
    let mut environment = Vec::new();
    for v in &scenario.vehicles {
        for (property, _) in shoal_proxy::sim::UNITS {
            environment.extend(
                reader
                    .observations(&v.id, property, start_ms, end_ms, READ_LIMIT)
                    .with_context(|| format!("cannot read the observations of {}", v.id))?,
            );
        }
        let track = reader
            .track(&v.id, start_ms, end_ms, READ_LIMIT)
            .with_context(|| format!("cannot read the track of {}", v.id))?;
        vehicles.push(VehicleRecord {
            id: v.id.clone(),
            kind: v.kind.as_str().to_owned(),
            track,
        });
    }
    let tasks = reader
        .tasks_since(start_ms, READ_LIMIT)
        .context("cannot read the run's tasks")?
        .into_iter()
        .filter_map(|t| {
            Some(TaskRecord {
                assignment: t.assignment?,
                statuses: t.statuses,
            })
        })
        .collect();
    let events = reader
        .events(start_ms, READ_LIMIT)
        .context("cannot read the run's events")?;
    let _ = history.close();
    Ok(RunRecord {
        scenario: scenario.name.clone(),
        description: scenario.description.clone(),
        seed,
        speed,
        start_ms,
        end_ms,
        wall_s,
        vehicles,
        tasks,
        events,
        station,
        faults: Vec::new(),
        rule_ids: Vec::new(),
        environment,
        ..RunRecord::default()
    })
}

fn format_s(s: f64) -> String {
    #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
    let s = s.max(0.0).round() as u64;
    format!("{}:{:02}:{:02}", s / 3600, s / 60 % 60, s % 60)
}

/// One line of progress: simulated time, vehicles heard, tasks by state, alarms.
fn progress_line(
    handle: Option<&shoal_station::StationHandle>,
    elapsed_ms: i64,
    duration_s: f64,
) -> String {
    #[allow(clippy::cast_precision_loss)]
    let elapsed_s = elapsed_ms as f64 / 1000.0;
    let Some(handle) = handle else {
        return format!(
            "  {} / {} simulated ({:>3.0} %)  the station is down",
            format_s(elapsed_s),
            format_s(duration_s),
            (elapsed_s / duration_s * 100.0).min(100.0),
        );
    };
    let fleet = handle.fleet();
    let heard = fleet.iter().filter(|v| v.latest.is_some()).count();
    let tasks = handle.tasks();
    let count = |f: fn(TaskState) -> bool| tasks.iter().filter(|t| f(t.state)).count();
    let alarms = handle
        .recent_events()
        .iter()
        .filter(|e| e.severity >= shoal_model::Severity::Alarm)
        .count();
    format!(
        "  {} / {} simulated ({:>3.0} %)  vehicles heard {heard}/{}  tasks: {} done, {} under way, {} failed  alarms {alarms}",
        format_s(elapsed_s),
        format_s(duration_s),
        (elapsed_s / duration_s * 100.0).min(100.0),
        fleet.len(),
        count(|s| s == TaskState::Done),
        count(|s| !s.is_final()),
        count(|s| s.is_final() && s != TaskState::Done),
    )
}

fn closing_line(s: &report::Summary, dir: &Path) -> String {
    let moved = s.vehicles.values().filter(|v| v.distance_m > 0.0).count();
    format!(
        "shoal: scenario {:?} ran {} simulated in {:.1} s: {} of {} vehicles moved, tasks {}; report: {}",
        s.scenario,
        format_s(s.simulated_s),
        s.wall_s,
        moved,
        s.vehicles.len(),
        s.tasks
            .iter()
            .map(|(k, n)| format!("{k} {n}"))
            .collect::<Vec<_>>()
            .join(", "),
        dir.join("report.html").display()
    )
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn args(extra: &[&str]) -> RunArgs {
        use clap::Parser;
        #[derive(Parser)]
        struct Cli {
            #[command(flatten)]
            run: RunArgs,
        }
        let mut argv = vec!["run"];
        argv.extend_from_slice(extra);
        Cli::try_parse_from(argv).unwrap().run
    }

    #[test]
    fn a_run_is_planned_into_its_directory_on_a_private_loopback_domain() {
        let p = plan(
            &ShoalConfig::default(),
            &args(&["sea-trial", "--out", "/tmp/x", "--speed", "30"]),
        )
        .unwrap();
        assert_eq!(p.speed, 30.0);
        assert_eq!(p.cfg.dds.domain_id, DEFAULT_DOMAIN);
        assert_eq!(p.cfg.history.path, Path::new("/tmp/x/history.sqlite"));
        assert!(p.cfg.recorder.enabled);
        assert_eq!(p.duration_s, p.scenario.duration_s);
    }

    #[test]
    fn bad_speeds_durations_and_interfaces_are_refused_before_anything_starts() {
        let cfg = ShoalConfig::default();
        for (flags, says) in [
            (vec!["sea-trial", "--speed", "0"], "--speed"),
            (vec!["sea-trial", "--speed", "1000"], "--speed"),
            (vec!["sea-trial", "--duration=-5"], "--duration"),
            (vec!["none"], "not a scenario"),
        ] {
            let e = plan(&cfg, &args(&flags)).err().unwrap().to_string();
            assert!(e.contains(says), "{flags:?}: {e}");
        }
        let mut open = ShoalConfig::default();
        open.dds.interfaces = vec!["192.0.2.1".parse().unwrap()];
        let e = plan(&open, &args(&["sea-trial"]))
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("loopback"), "{e}");
    }

    #[test]
    fn a_directory_with_files_is_not_reused() {
        let d = tempfile::tempdir().unwrap();
        create_dir(d.path()).unwrap();
        create_dir(&d.path().join("new/deeper")).unwrap();
        std::fs::write(d.path().join("summary.json"), "{}").unwrap();
        let e = create_dir(d.path()).unwrap_err().to_string();
        assert!(e.contains("not empty"), "{e}");
    }

    #[test]
    fn vehicles_draw_from_the_seed_and_their_id() {
        assert_eq!(vehicle_seed(1, "auv-1"), vehicle_seed(1, "auv-1"));
        assert_ne!(vehicle_seed(1, "auv-1"), vehicle_seed(1, "auv-2"));
        assert_ne!(vehicle_seed(1, "auv-1"), vehicle_seed(2, "auv-1"));
    }
}
