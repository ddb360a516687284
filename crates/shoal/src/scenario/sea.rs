//! The acoustic network of a scenario run: the scenario's acoustic vehicles, each on a
//! private DDS domain of its own, heard by the station only through an emulated sea, their
//! VDTs and the relay's CDT (`shoal_converter::emulated_relay`), all on the run's
//! simulated clock. Link outages and modem failures silence modems in the emulated sea,
//! a vehicle failure stops the vehicle's computer behind its modem; the sea's per-link
//! counters and time on air, and what an observer on the station's domain sees (relayed
//! states' age, link-status reports), go into the report.

use std::collections::{BTreeMap, HashMap};
use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use anyhow::{Context, Result};
use futures::StreamExt;
use shoal_acoustic::emulator::EmulatorHandle;
use shoal_converter::ConverterError;
use shoal_converter::emulated_relay::{
    EmulatedRelayConfig, RelayedVehicle, run_emulated_relay_with,
};
use shoal_dds::PubSub;
use shoal_model::{Event, LinkStatus, StateVector, Warp};
use shoal_proxy::ProxyOptions;
use shoal_proxy::sim::{SimAdapter, SimFault, SimSettings, SimSpec};
use shoal_recorder::AcousticRecorder;
use shoal_scenario::Scenario;
use shoal_scenario::report::{LinkFigures, LinkSample, RunRecord};
use tokio::sync::mpsc;
use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;
use tracing::warn;

use crate::config::ShoalConfig;

/// The highest DDS domain id; acoustic vehicles' private domains count down from it.
const TOP_DOMAIN: u16 = 232;
/// Most latencies and link-status reports kept per vehicle (a week at one a second).
const MAX_SAMPLES: usize = 604_800;

/// What the observer on the station's domain saw of the acoustic vehicles.
#[derive(Default)]
struct Watched {
    latency_ms: BTreeMap<String, Vec<i64>>,
    quality: BTreeMap<String, Vec<LinkSample>>,
}

/// A running acoustic network.
pub struct AcousticNet {
    /// The emulated sea, once the relay has started it.
    sea: Arc<Mutex<Option<Arc<EmulatorHandle>>>>,
    /// The relay's acoustic address.
    relay: u8,
    /// Each acoustic vehicle's acoustic address, by vehicle id.
    addresses: HashMap<String, u8>,
    controls: Controls,
    watched: Arc<Mutex<Watched>>,
    stop: CancellationToken,
    task: JoinHandle<()>,
    observer: JoinHandle<()>,
    /// The relay's frames and link events into the run's recording (`[recorder] acoustic`).
    recorder: Option<AcousticRecorder>,
}

impl AcousticNet {
    /// Starts the network of `scenario` (none when it has no acoustic vehicles): the
    /// emulated sea, a CDT on the run's domain, and per vehicle a VDT and the simulated
    /// vehicle on its private domain, with a task ledger in `ledgers`.
    pub fn start(
        cfg: &ShoalConfig,
        scenario: &Scenario,
        warp: Warp,
        seed: u64,
        ledgers: PathBuf,
    ) -> Result<Option<Self>> {
        let Some(net) = &scenario.acoustic else {
            return Ok(None);
        };
        let station_domain = cfg.dds.domain_id;
        let mut domains = (0..=TOP_DOMAIN).rev().filter(|d| *d != station_domain);
        let mut specs: HashMap<String, SimSpec> = HashMap::new();
        let mut vehicles = Vec::new();
        for v in scenario.acoustic_vehicles() {
            let (Some(address), Some(domain_id)) = (v.acoustic_address, domains.next()) else {
                continue;
            };
            vehicles.push(RelayedVehicle {
                id: v.id.clone(),
                address,
                domain_id,
                latitude_deg: v.latitude_deg,
                longitude_deg: v.longitude_deg,
            });
            specs.insert(v.id.clone(), super::sim_spec(v));
        }
        if vehicles.is_empty() {
            return Ok(None);
        }
        let addresses = vehicles.iter().map(|v| (v.id.clone(), v.address)).collect();
        let mut relay = EmulatedRelayConfig::new(
            net.relay_address,
            net.relay_latitude_deg,
            net.relay_longitude_deg,
            vehicles,
        )
        .warped(warp);
        relay.seed = seed;
        relay.fixed_per = net.fixed_per;
        relay.channel = net.channel;
        relay.relay_vehicle.clone_from(&net.relay_vehicle);
        let (recorder, tap) = crate::record::start_acoustic(&cfg.recorder)?.unzip();
        relay.tap = tap;
        let cdt_dds = Arc::new(PubSub::new(&cfg.dds).context("cannot join DDS for the relay")?);

        let controls: Controls = Arc::default();
        let settings = cfg.fleet.sim.clone();
        let start_vehicle = {
            let controls = Arc::clone(&controls);
            move |v: &RelayedVehicle, dds: Arc<PubSub>, stop: CancellationToken| {
                let spec = specs.get(&v.id).cloned();
                let settings = SimSettings {
                    seed: Some(super::run::vehicle_seed(seed, &v.id)),
                    ..settings.clone()
                };
                let (power, power_rx) = mpsc::unbounded_channel();
                if let Ok(mut c) = controls.lock() {
                    c.insert(
                        v.id.clone(),
                        Control {
                            power,
                            faults: None,
                        },
                    );
                }
                let vehicle = Computer {
                    id: v.id.clone(),
                    settings,
                    warp,
                    ledgers: ledgers.clone(),
                    controls: Arc::clone(&controls),
                };
                async move {
                    let spec = spec.ok_or_else(|| {
                        ConverterError::Config("relayed vehicle missing from the scenario".into())
                    })?;
                    vehicle.run(spec, dds, power_rx, stop).await
                }
            }
        };
        let sea: Arc<Mutex<Option<Arc<EmulatorHandle>>>> = Arc::default();
        let stop = CancellationToken::new();
        let watched: Arc<Mutex<Watched>> = Arc::default();
        let observer = tokio::spawn(observe(
            Arc::new(PubSub::new(&cfg.dds).context("cannot join DDS for the acoustic figures")?),
            warp,
            addresses_of(&addresses),
            Arc::clone(&watched),
            stop.clone(),
        ));
        let task = tokio::spawn({
            let (sea, stop) = (Arc::clone(&sea), stop.clone());
            async move {
                let keep = |emu: &Arc<EmulatorHandle>| {
                    if let Ok(mut s) = sea.lock() {
                        *s = Some(Arc::clone(emu));
                    }
                };
                if let Err(e) =
                    run_emulated_relay_with(relay, cdt_dds, None, start_vehicle, keep, stop).await
                {
                    warn!(error = %e, "the acoustic network stopped");
                }
            }
        });
        Ok(Some(Self {
            sea,
            relay: net.relay_address,
            addresses,
            controls,
            watched,
            stop,
            task,
            observer,
            recorder,
        }))
    }

    fn sea(&self) -> Option<Arc<EmulatorHandle>> {
        self.sea.lock().ok().and_then(|s| s.clone())
    }

    /// Silences (or brings back) the modem of `vehicle`, or the relay's with `None`;
    /// false when there is no such modem or the sea is not up.
    pub fn set_silent(&self, vehicle: Option<&str>, silent: bool) -> bool {
        let address = match vehicle {
            None => Some(self.relay),
            Some(id) => self.addresses.get(id).copied(),
        };
        match (address, self.sea()) {
            (Some(a), Some(sea)) => sea.set_silent(a, silent).is_ok(),
            _ => false,
        }
    }

    /// Injects a fault into an acoustic vehicle's simulator; false if it is not one or
    /// it is down.
    pub fn inject(&self, vehicle: &str, fault: SimFault) -> bool {
        self.controls
            .lock()
            .ok()
            .and_then(|c| {
                c.get(vehicle)
                    .and_then(|c| c.faults.as_ref())
                    .map(|tx| tx.send(fault).is_ok())
            })
            .unwrap_or(false)
    }

    /// Stops an acoustic vehicle's computer (its proxy with it) as a failure would; its
    /// modem and VDT stay; false if it is not one.
    pub fn fail(&self, vehicle: &str) -> bool {
        self.power(vehicle, Power::Fail)
    }

    /// Starts a failed acoustic vehicle's computer again, where `from` says (else where
    /// it started), with the same task ledger; false if it is not one.
    pub fn restart(&self, vehicle: &str, from: Option<&StateVector>) -> bool {
        self.power(vehicle, Power::Restart(from.cloned()))
    }

    fn power(&self, vehicle: &str, p: Power) -> bool {
        self.controls
            .lock()
            .ok()
            .and_then(|c| c.get(vehicle).map(|c| c.power.send(p).is_ok()))
            .unwrap_or(false)
    }

    /// The counters of every link that carried a frame, named by vehicle (`relay` for the
    /// relay's modem).
    fn links(&self) -> Vec<LinkFigures> {
        let Some(sea) = self.sea() else {
            return Vec::new();
        };
        let name = |a: u8| self.name(a);
        sea.stats()
            .into_iter()
            .map(|l| LinkFigures {
                from: name(l.src),
                to: name(l.dst),
                frames: l.frames,
                delivered: l.delivered,
                lost: l.lost,
                collisions: l.collisions,
                half_duplex: l.half_duplex,
                outage: l.outage,
            })
            .collect()
    }

    /// Simulated seconds each modem spent transmitting, by vehicle id (`relay`).
    pub fn airtime(&self) -> BTreeMap<String, f64> {
        let Some(sea) = self.sea() else {
            return BTreeMap::new();
        };
        sea.airtime()
            .into_iter()
            .map(|(a, s)| (self.name(a), s))
            .collect()
    }

    fn name(&self, address: u8) -> String {
        if address == self.relay {
            return "relay".to_owned();
        }
        self.addresses
            .iter()
            .find(|(_, x)| **x == address)
            .map_or_else(|| format!("modem {address}"), |(id, _)| id.clone())
    }

    /// Writes what the network measured into `record`.
    pub fn report(&self, record: &mut RunRecord) {
        record.links = self.links();
        record.airtime_s = self.airtime();
        if let Ok(w) = self.watched.lock() {
            record.acoustic_latency_ms.clone_from(&w.latency_ms);
            record.link_quality.clone_from(&w.quality);
        }
    }

    /// Stops the network and waits for it (a few seconds at most).
    pub async fn stop(self) {
        self.stop.cancel();
        drop(self.sea.lock().ok().and_then(|mut s| s.take()));
        let wait = std::time::Duration::from_secs(10);
        let _ = tokio::time::timeout(wait, self.task).await;
        let _ = tokio::time::timeout(wait, self.observer).await;
        if let Some(recorder) = self.recorder {
            crate::record::stop_acoustic(recorder).await;
        }
    }
}

/// Each acoustic vehicle's controls, by id.
type Controls = Arc<Mutex<HashMap<String, Control>>>;

/// How the run reaches one acoustic vehicle's computer.
struct Control {
    power: mpsc::UnboundedSender<Power>,
    /// Its simulator's fault channel while it runs.
    faults: Option<mpsc::UnboundedSender<SimFault>>,
}

/// What a `vehicle_failure` fault does to an acoustic vehicle's computer.
enum Power {
    Fail,
    Restart(Option<StateVector>),
}

/// An acoustic vehicle's computer: its simulator behind its DDS Proxy, on its private
/// domain. The relay sees one part that runs until the run stops; inside, a failure stops
/// the proxy and a restart starts it again on the same participant and ledger.
struct Computer {
    id: String,
    settings: SimSettings,
    warp: Warp,
    ledgers: PathBuf,
    controls: Controls,
}

impl Computer {
    async fn run(
        self,
        mut spec: SimSpec,
        dds: Arc<PubSub>,
        mut power: mpsc::UnboundedReceiver<Power>,
        stop: CancellationToken,
    ) -> Result<(), ConverterError> {
        loop {
            let life = stop.child_token();
            let (tx, rx) = mpsc::unbounded_channel();
            self.set_faults(Some(tx));
            let options = ProxyOptions {
                state_rate_hz: spec.rate_hz,
                clock: Some(self.warp),
                ledger_dir: Some(self.ledgers.clone()),
                ..ProxyOptions::default()
            };
            let adapter = SimAdapter::warped(&spec, &self.settings, self.warp).with_faults(rx);
            let run =
                shoal_proxy::run_sim_adapter(adapter, options, Arc::clone(&dds), life.clone());
            tokio::pin!(run);
            // Up until it fails or the run stops.
            loop {
                tokio::select! {
                    r = &mut run => {
                        r.map_err(ConverterError::from)?;
                        // Stopped without a failure: the run is ending.
                        return Ok(());
                    }
                    p = power.recv() => match p {
                        Some(Power::Fail) => {
                            life.cancel();
                            (&mut run).await.map_err(ConverterError::from)?;
                            break;
                        }
                        Some(Power::Restart(_)) => {}
                        None => return Ok(()),
                    },
                }
            }
            self.set_faults(None);
            // Down until it is restarted or the run stops.
            loop {
                tokio::select! {
                    () = stop.cancelled() => return Ok(()),
                    p = power.recv() => match p {
                        Some(Power::Restart(from)) => {
                            if let Some(s) = from {
                                spec.latitude_deg = s.latitude_deg;
                                spec.longitude_deg = s.longitude_deg;
                                spec.battery_pct = s.battery_pct;
                            }
                            break;
                        }
                        Some(Power::Fail) => {}
                        None => return Ok(()),
                    },
                }
            }
        }
    }

    fn set_faults(&self, tx: Option<mpsc::UnboundedSender<SimFault>>) {
        if let Ok(mut c) = self.controls.lock()
            && let Some(c) = c.get_mut(&self.id)
        {
            c.faults = tx;
        }
    }
}

fn addresses_of(addresses: &HashMap<String, u8>) -> Vec<String> {
    addresses.keys().cloned().collect()
}

/// Watches the station's domain as the station would hear it: each relayed state vector's
/// age on arrival (simulated time), and the relay's link-status reports.
async fn observe(
    dds: Arc<PubSub>,
    warp: Warp,
    vehicles: Vec<String>,
    watched: Arc<Mutex<Watched>>,
    stop: CancellationToken,
) {
    let (Ok(mut states), Ok(mut events)) =
        (dds.subscribe::<StateVector>(), dds.subscribe::<Event>())
    else {
        warn!("no acoustic latency or link quality figures: cannot subscribe");
        return;
    };
    let ours = |id: &str| vehicles.iter().any(|v| v == id);
    loop {
        tokio::select! {
            () = stop.cancelled() => return,
            item = states.next() => match item {
                Some(Ok((s, _))) if ours(&s.vehicle_id) => {
                    let age = warp.now_ms() - s.timestamp_ms;
                    if let Ok(mut w) = watched.lock() {
                        let v = w.latency_ms.entry(s.vehicle_id.clone()).or_default();
                        if v.len() < MAX_SAMPLES && age >= 0 {
                            v.push(age);
                        }
                    }
                }
                Some(_) => {}
                None => return,
            },
            item = events.next() => match item {
                Some(Ok((e, _))) => {
                    if let Some(l) = LinkStatus::from_event(&e).filter(|l| ours(&l.vehicle_id))
                        && let Ok(mut w) = watched.lock()
                    {
                        let v = w.quality.entry(l.vehicle_id).or_default();
                        if v.len() < MAX_SAMPLES {
                            v.push(LinkSample {
                                at_ms: e.timestamp_ms,
                                rssi_db: l.rssi_db,
                                integrity: l.integrity,
                            });
                        }
                    }
                }
                Some(Err(_)) => {}
                None => return,
            },
        }
    }
}
