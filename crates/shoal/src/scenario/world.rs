//! The simulated world of a scenario run: its station (which a fault may restart) and its
//! simulated vehicles (which a fault may stop, restart, or drain), all on one [`Warp`].

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, Result};
use shoal_dds::{Priority, PubSub, Writer, WriterOptions};
use shoal_history::History;
use shoal_model::{StateVector, Warp};
use shoal_proxy::ProxyOptions;
use shoal_proxy::sim::{SimAdapter, SimFault, SimSettings, SimSpec};
use shoal_scenario::report::StationFigures;
use shoal_scenario::{Scenario, ScenarioMission};
use shoal_station::{Clock, Station, StationHandle, StationReport};
use tokio::sync::mpsc;
use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;
use tracing::warn;

use crate::config::ShoalConfig;

/// How far a rogue sample puts a vehicle from where it is, degrees of latitude (55 km).
const ROGUE_OFFSET_DEG: f64 = 0.5;

/// The run's station, stopped and started again by a `station_restart` fault.
pub struct StationRun {
    cfg: ShoalConfig,
    warp: Warp,
    up: Option<Running>,
    /// Counters of the stations that ran and stopped, added up.
    done: StationFigures,
    /// The rules of every station that ran, by id.
    rule_ids: std::collections::BTreeSet<String>,
}

struct Running {
    handle: StationHandle,
    stop: CancellationToken,
    task: JoinHandle<Result<StationReport, shoal_station::StationError>>,
    missions: JoinHandle<()>,
}

impl StationRun {
    /// A station not started yet.
    pub fn new(cfg: ShoalConfig, warp: Warp) -> Self {
        Self {
            cfg,
            warp,
            up: None,
            done: StationFigures::default(),
            rule_ids: std::collections::BTreeSet::new(),
        }
    }

    /// Starts a station (its own DDS participant, the run's history store) and has it run
    /// `missions` on their timeline from now; one already up is left as it is (restarts
    /// whose down times overlap end with the first start).
    pub fn start(&mut self, missions: Scenario) -> Result<()> {
        if self.up.is_some() {
            return Ok(());
        }
        let history =
            History::open(&self.cfg.history).context("cannot open the run's history store")?;
        let dds = Arc::new(PubSub::new(&self.cfg.dds).context("cannot join DDS")?);
        let station = Station::with_clock(
            self.cfg.station.clone(),
            dds,
            history,
            Clock::warped(self.warp),
        )
        .context("cannot start the station")?;
        let handle = station.handle();
        let stop = CancellationToken::new();
        let task = tokio::spawn(station.run(stop.clone()));
        let missions = tokio::spawn({
            let (handle, stop) = (handle.clone(), stop.clone());
            async move { handle.run_scenario(missions, stop).await }
        });
        self.up = Some(Running {
            handle,
            stop,
            task,
            missions,
        });
        Ok(())
    }

    /// The running station's handle, if it is up.
    pub fn handle(&self) -> Option<&StationHandle> {
        self.up.as_ref().map(|r| &r.handle)
    }

    /// Stops the station (its history closed) and adds its counters to the run's.
    pub async fn stop(&mut self) -> Result<()> {
        let Some(r) = self.up.take() else {
            return Ok(());
        };
        self.rule_ids
            .extend(r.handle.rules().into_iter().map(|rule| rule.id));
        r.stop.cancel();
        r.missions.abort();
        let report = r
            .task
            .await
            .context("the station task failed")?
            .context("the station failed")?;
        self.done.states_accepted += report.stats.states_accepted;
        self.done.rejected += report.stats.total_rejected();
        self.done.history_committed += report.history_committed;
        self.done.rule_firings += report.stats.rule_firings;
        Ok(())
    }

    /// The counters of every station of the run (call after [`Self::stop`]).
    pub fn figures(&self) -> StationFigures {
        self.done
    }

    /// The ids of every rule the run's stations had (call after [`Self::stop`]).
    pub fn rule_ids(&self) -> Vec<String> {
        self.rule_ids.iter().cloned().collect()
    }
}

/// The missions of `scenario` still to start `elapsed_s` into the run, with their offsets
/// counted from then: what a restarted station runs.
pub fn missions_after(scenario: &Scenario, elapsed_s: f64) -> Scenario {
    let missions: Vec<ScenarioMission> = scenario
        .missions
        .iter()
        .filter(|m| m.at_s >= elapsed_s)
        .map(|m| ScenarioMission {
            at_s: m.at_s - elapsed_s,
            ..m.clone()
        })
        .collect();
    Scenario {
        duration_s: (scenario.duration_s - elapsed_s).max(1.0),
        missions,
        faults: Vec::new(),
        ..scenario.clone()
    }
}

/// One simulated vehicle that is running.
struct Vehicle {
    stop: CancellationToken,
    task: JoinHandle<()>,
    faults: mpsc::UnboundedSender<SimFault>,
}

/// The run's simulated vehicles, on one DDS participant.
pub struct Fleet {
    dds: Arc<PubSub>,
    warp: Warp,
    settings: SimSettings,
    seed: u64,
    ledgers: PathBuf,
    specs: HashMap<String, SimSpec>,
    running: HashMap<String, Vehicle>,
    /// Vehicles told to stop, not yet gone: awaited at the end, not when they fail, so a
    /// slow DDS goodbye does not hold up the timeline.
    stopping: Vec<JoinHandle<()>>,
    rogue: Option<Writer<StateVector>>,
}

impl Fleet {
    /// A fleet of `specs`, none started; `rogue` creates the other participant's writer
    /// that `rogue_sample` faults publish through.
    pub fn new(
        cfg: &ShoalConfig,
        warp: Warp,
        seed: u64,
        ledgers: PathBuf,
        specs: Vec<SimSpec>,
        rogue: bool,
    ) -> Result<Self> {
        let dds = Arc::new(PubSub::new(&cfg.dds).context("cannot join DDS")?);
        let rogue = if rogue {
            let other = PubSub::new(&cfg.dds).context("cannot join DDS")?;
            Some(
                other
                    .writer::<StateVector>(WriterOptions::new(Priority::Telemetry))
                    .context("cannot create the rogue writer")?,
            )
        } else {
            None
        };
        Ok(Self {
            dds,
            warp,
            settings: cfg.fleet.sim.clone(),
            seed,
            ledgers,
            specs: specs.into_iter().map(|s| (s.id.clone(), s)).collect(),
            running: HashMap::new(),
            stopping: Vec::new(),
            rogue,
        })
    }

    /// Starts `id` (from its spec, or from `from`: where it was when it failed).
    pub fn start(&mut self, id: &str, from: Option<&StateVector>) {
        let Some(mut spec) = self.specs.get(id).cloned() else {
            return;
        };
        if let Some(s) = from {
            spec.latitude_deg = s.latitude_deg;
            spec.longitude_deg = s.longitude_deg;
            spec.battery_pct = s.battery_pct;
        }
        let settings = SimSettings {
            seed: Some(super::run::vehicle_seed(self.seed, id)),
            ..self.settings.clone()
        };
        let options = ProxyOptions {
            state_rate_hz: spec.rate_hz,
            clock: Some(self.warp),
            // A real ledger, as on a vehicle: a task runs once even across a restart.
            ledger_dir: Some(self.ledgers.clone()),
            ..ProxyOptions::default()
        };
        let (tx, rx) = mpsc::unbounded_channel();
        let adapter = SimAdapter::warped(&spec, &settings, self.warp).with_faults(rx);
        let stop = CancellationToken::new();
        let run =
            shoal_proxy::run_sim_adapter(adapter, options, Arc::clone(&self.dds), stop.clone());
        let vid = id.to_owned();
        let task = tokio::spawn(async move {
            if let Err(e) = run.await {
                warn!(vehicle = %vid, error = %e, "simulated vehicle stopped");
            }
        });
        self.running.insert(
            id.to_owned(),
            Vehicle {
                stop,
                task,
                faults: tx,
            },
        );
    }

    /// Starts every vehicle from its spec.
    pub fn start_all(&mut self) {
        let mut ids: Vec<String> = self.specs.keys().cloned().collect();
        ids.sort();
        for id in ids {
            self.start(&id, None);
        }
    }

    /// Stops `id` as a failed computer would: no goodbye beyond what its proxy does.
    pub fn stop(&mut self, id: &str) {
        if let Some(v) = self.running.remove(id) {
            v.stop.cancel();
            self.stopping.push(v.task);
        }
    }

    /// Stops every vehicle and waits (a few seconds at most each) until they are gone.
    pub async fn stop_all(&mut self) {
        let ids: Vec<String> = self.running.keys().cloned().collect();
        for id in ids {
            self.stop(&id);
        }
        for task in self.stopping.drain(..) {
            let _ = tokio::time::timeout(Duration::from_secs(5), task).await;
        }
    }

    /// Injects a fault into a running vehicle; false if it is not running.
    pub fn inject(&self, id: &str, fault: SimFault) -> bool {
        self.running
            .get(id)
            .is_some_and(|v| v.faults.send(fault).is_ok())
    }

    /// Publishes, from another participant, a state vector for `last.vehicle_id` far from
    /// `last`: what the station's plausibility checks must refuse.
    pub async fn rogue_sample(&self, last: &StateVector) -> Result<()> {
        let Some(w) = &self.rogue else {
            return Ok(());
        };
        let mut s = last.clone();
        s.timestamp_ms = self.warp.now_ms();
        s.latitude_deg = if s.latitude_deg > 0.0 {
            s.latitude_deg - ROGUE_OFFSET_DEG
        } else {
            s.latitude_deg + ROGUE_OFFSET_DEG
        };
        w.write(s)
            .await
            .map_err(|e| anyhow::anyhow!("rogue sample not written: {e}"))
    }
}
