//! An acoustic relay over the modem emulator: vehicles on their own private DDS domains,
//! each heard only through a VDT, an emulated sea and a CDT that republishes them on the
//! station's domain — the SWARMs sea-trial topology (vehicle →acoustic→ relay USV →DDS over
//! IP→ station) on one host, for any vehicle software that publishes on a DDS domain.
//!
//! [`run_emulated_relay`] starts, in this process:
//! - a modem emulator (`shoal-acoustic`) on 127.0.0.1 with one modem on the relay and one
//!   per vehicle; the vehicles' modems can follow their live state;
//! - per vehicle, a participant on its **own private DDS domain** (loopback only) handed to
//!   the caller's vehicle (the simulator, a proxy for real vehicle software, a test
//!   double), and a VDT bridging that domain to the vehicle's modem. The vehicle never
//!   joins the station's domain: everything the station hears of it crossed the emulated
//!   water;
//! - a CDT on the relay's modem with the given participant on the station's domain — the
//!   relay USV's DDS node — which republishes the vehicles' data there and forwards tasks.
//!
//! `shoal up`'s acoustic demo runs the simulator behind it (`crates/shoal/src/relay.rs`);
//! the closure given to [`run_emulated_relay`] starts whatever vehicle software should
//! speak on each private domain:
//!
//! ```no_run
//! # async fn f(station: std::sync::Arc<shoal_dds::PubSub>,
//! #            shutdown: tokio_util::sync::CancellationToken) {
//! use shoal_converter::emulated_relay::{EmulatedRelayConfig, RelayedVehicle, run_emulated_relay};
//! let auv = RelayedVehicle {
//!     id: "auv-7".into(),
//!     address: 2,
//!     domain_id: 100,
//!     latitude_deg: 63.467,
//!     longitude_deg: 10.372,
//! };
//! let cfg = EmulatedRelayConfig::new(1, 63.464, 10.380, vec![auv]);
//! let start_vehicle = |v: &RelayedVehicle, _private_dds, stop: tokio_util::sync::CancellationToken| {
//!     // A real caller runs the vehicle's DDS software on `_private_dds` until `stop`.
//!     let id = v.id.clone();
//!     async move {
//!         stop.cancelled().await;
//!         tracing::info!(vehicle = %id, "vehicle stopped");
//!         Ok(())
//!     }
//! };
//! if let Err(e) = run_emulated_relay(cfg, station, None, start_vehicle, shutdown).await {
//!     tracing::error!(error = %e, "emulated relay stopped");
//! }
//! # }
//! ```

use std::future::Future;
use std::sync::Arc;

use futures::StreamExt;
use shoal_acoustic::channel::ChannelModel;
use shoal_acoustic::emulator::{Emulator, EmulatorConfig, EmulatorHandle, ModemConfig};
use shoal_acoustic::relay::{HEADER_BYTES, RelayConfig};
use shoal_acoustic::secure::TaggedDriver;
use shoal_dds::{DdsConfig, PubSub};
use shoal_model::{StateVector, Warp};
use tokio::task::JoinSet;
use tokio_util::sync::CancellationToken;
use tracing::{debug, info, warn};

use crate::config::{
    AddressEntry, CdtConfig, LinkSettings, ModemKind, ModemPosition, ModemSettings, VdtConfig,
};
use crate::error::ConverterError;
use crate::modem::Modem;
use crate::tap::FrameTap;
use crate::{run_cdt, run_vdt};

/// The relay's link-status interval, seconds (simulated): a demo's operator watches the
/// frames arrive on the console's map, which learns of them only from the link status, so
/// it comes more often than a sea trial's 30 s. One small event per vehicle.
const LINK_STATUS_INTERVAL_S: f64 = 5.0;

/// Per-vehicle acoustic keys for the relay's link: every frame between a vehicle's VDT and
/// the CDT is tagged with that vehicle's key (`shoal keys` issues them).
#[derive(Debug)]
pub struct AcousticKeys {
    /// Tag size on the link.
    pub tag: shoal_security::TagSize,
    /// Key of each relayed vehicle, by vehicle id.
    pub keys: std::collections::HashMap<String, shoal_security::AcousticKey>,
}

impl AcousticKeys {
    fn key(&self, vehicle_id: &str) -> Result<&shoal_security::AcousticKey, ConverterError> {
        self.keys.get(vehicle_id).ok_or_else(|| {
            ConverterError::Config(format!(
                "no acoustic key for relayed vehicle {vehicle_id:?}"
            ))
        })
    }

    fn tagger(&self, local: u8) -> shoal_security::AcousticTagger {
        shoal_security::AcousticTagger::new(
            local,
            self.tag,
            shoal_security::acoustic::counter_start_from_clock(shoal_model::now_ms()),
        )
    }
}

/// Logs, at most every 10 s, how many received frames a tagged driver refused.
async fn report_refusals(
    who: &'static str,
    counts: Arc<std::sync::Mutex<shoal_security::RejectionCounts>>,
    stop: CancellationToken,
) -> Result<(), ConverterError> {
    let mut reported = 0;
    loop {
        tokio::select! {
            () = stop.cancelled() => return Ok(()),
            () = tokio::time::sleep(std::time::Duration::from_secs(10)) => {}
        }
        let Ok(c) = counts.lock().map(|c| c.clone()) else {
            return Ok(());
        };
        if c.total() > reported {
            reported = c.total();
            let by_reason: Vec<String> = c.iter().map(|(r, n)| format!("{r}={n}")).collect();
            warn!(converter = who, refused = reported, reasons = %by_reason.join(" "), "acoustic frames refused");
        }
    }
}

/// One vehicle behind the emulated relay.
#[derive(Debug, Clone, PartialEq)]
pub struct RelayedVehicle {
    /// Its vehicle id, as it publishes it.
    pub id: String,
    /// Its acoustic address, 1..=15, distinct from the relay's.
    pub address: u8,
    /// Its private DDS domain (vehicle side); must differ from the station's.
    pub domain_id: u16,
    /// Where its modem starts, degrees.
    pub latitude_deg: f64,
    /// Where its modem starts, degrees.
    pub longitude_deg: f64,
}

/// Configuration of an emulated relay.
#[derive(Debug, Clone, PartialEq)]
pub struct EmulatedRelayConfig {
    /// The vehicles behind it.
    pub vehicles: Vec<RelayedVehicle>,
    /// Acoustic address of the relay's modem (the CDT).
    pub relay_address: u8,
    /// Relay position, degrees.
    pub relay_latitude_deg: f64,
    /// Relay position, degrees.
    pub relay_longitude_deg: f64,
    /// Modem protocol the converters speak to the emulator.
    pub modem_kind: ModemKind,
    /// Wall-clock seconds per simulated second for the sea and the converters.
    pub time_scale: f64,
    /// Emulator PRNG seed.
    pub seed: u64,
    /// Fixed packet error rate instead of the channel model (`None`: physics).
    pub fixed_per: Option<f64>,
    /// The channel's physics (unused with `fixed_per`).
    pub channel: ChannelModel,
    /// VDT state interval, seconds.
    pub state_interval_s: f64,
    /// Link settings of both converters.
    pub link: LinkSettings,
    /// Move each vehicle's emulated modem to its live position.
    pub follow_vehicles: bool,
    /// A vehicle on the station's domain that carries the relay (a USV): the relay's modem
    /// moves to its live position. `None`: the relay stays where it is put.
    pub relay_vehicle: Option<String>,
    /// A scenario run's simulated clock for the converters' timestamps (`None`: the
    /// system clock); set with [`Self::warped`], which matches `time_scale` to it.
    pub clock: Option<Warp>,
    /// Relay settings of vehicles' modems, by vehicle id (docs/acoustic.md#multi-hop-relays):
    /// a vehicle out of the relay's range routes through another, which forwards. Others
    /// keep [`RelayConfig::default`] (no forwarding, no configured routes).
    pub relaying: std::collections::HashMap<String, RelayConfig>,
    /// The emulator's hard range, metres (`None`: the channel model decides).
    pub max_range_m: Option<f64>,
    /// Where the relay's CDT reports its frames and link events ([`CdtConfig::tap`]);
    /// `None`: nowhere.
    pub tap: Option<FrameTap>,
}

impl EmulatedRelayConfig {
    /// A relay at `relay_address` and the given position with `vehicles` behind it; the
    /// rest at its usual values: EvoLogics AT, real time, seed 1, channel physics, a state
    /// every 2 s, default link settings, modems following their vehicles.
    ///
    /// There is no `Default`: where the relay sits decides whether its vehicles are in
    /// acoustic range at all.
    pub fn new(
        relay_address: u8,
        relay_latitude_deg: f64,
        relay_longitude_deg: f64,
        vehicles: Vec<RelayedVehicle>,
    ) -> Self {
        Self {
            vehicles,
            relay_address,
            relay_latitude_deg,
            relay_longitude_deg,
            modem_kind: ModemKind::EvologicsAt,
            time_scale: 1.0,
            seed: 1,
            fixed_per: None,
            channel: ChannelModel::default(),
            state_interval_s: 2.0,
            link: LinkSettings::default(),
            follow_vehicles: true,
            relay_vehicle: None,
            clock: None,
            relaying: std::collections::HashMap::new(),
            max_range_m: None,
            tap: None,
        }
    }

    /// The relay on a scenario run's simulated clock: the sea's physics, the converters'
    /// timers and their timestamps all run at `clock`'s speed.
    #[must_use]
    pub fn warped(mut self, clock: Warp) -> Self {
        self.time_scale = 1.0 / clock.scale();
        self.clock = Some(clock);
        self
    }

    /// Checks the relay against the station's DDS configuration.
    pub fn check(&self, station: &DdsConfig) -> Result<(), ConverterError> {
        let bad = |m: String| Err(ConverterError::Config(m));
        if self.vehicles.is_empty() {
            return bad("emulated relay: no vehicles".into());
        }
        for v in &self.vehicles {
            if v.domain_id == station.domain_id {
                return bad(format!(
                    "emulated relay: {} must use a private DDS domain, not the station's {}",
                    v.id, station.domain_id
                ));
            }
        }
        self.cdt_config(std::net::SocketAddr::from(([127, 0, 0, 1], 0)))
            .check()?;
        Ok(())
    }

    fn book(&self) -> Vec<AddressEntry> {
        self.vehicles
            .iter()
            .map(|v| AddressEntry {
                vehicle_id: v.id.clone(),
                address: v.address,
            })
            .collect()
    }

    fn modem(&self, at: std::net::SocketAddr, nl: std::net::SocketAddr) -> ModemSettings {
        ModemSettings {
            kind: self.modem_kind,
            address: match self.modem_kind {
                ModemKind::EvologicsAt => at,
                ModemKind::EvinsNl => nl,
            },
            nl_delivery_reports: true,
        }
    }

    fn cdt_config(&self, modem: std::net::SocketAddr) -> CdtConfig {
        CdtConfig {
            modem: ModemSettings {
                kind: self.modem_kind,
                address: modem,
                nl_delivery_reports: true,
            },
            address: self.relay_address,
            vehicles: self.book(),
            // The console draws the relay's modem from the link status: where it was put,
            // or on the vehicle carrying it.
            position: Some(ModemPosition {
                latitude_deg: self.relay_latitude_deg,
                longitude_deg: self.relay_longitude_deg,
            }),
            carrier: self.relay_vehicle.clone(),
            link_status_interval_s: LINK_STATUS_INTERVAL_S,
            link: self.link.clone(),
            time_scale: self.time_scale,
            clock: self.clock,
            tap: self.tap.clone(),
            ..CdtConfig::default()
        }
    }

    fn emulator_config(&self) -> EmulatorConfig {
        let mut modems = vec![ModemConfig {
            address: self.relay_address,
            name: "relay".into(),
            latitude_deg: self.relay_latitude_deg,
            longitude_deg: self.relay_longitude_deg,
            // A hull-mounted transducer.
            depth_m: 2.0,
            ..ModemConfig::default()
        }];
        modems.extend(self.vehicles.iter().map(|v| ModemConfig {
            address: v.address,
            name: v.id.clone(),
            latitude_deg: v.latitude_deg,
            longitude_deg: v.longitude_deg,
            depth_m: 1.0,
            ..ModemConfig::default()
        }));
        EmulatorConfig {
            seed: self.seed,
            time_scale: self.time_scale,
            fixed_per: self.fixed_per,
            channel: self.channel,
            max_range_m: self.max_range_m,
            modems,
            ..EmulatorConfig::default()
        }
    }
}

/// Runs the relay until `shutdown`. The CDT joins the station's domain through `cdt_dds`
/// (its own participant, as the relay USV's would be; with security on, one made with
/// [`PubSub::new_secure`] so the station admits what it relays); with `keys`, every
/// acoustic frame is authenticated ([`shoal_acoustic::secure`]).
///
/// For each vehicle, `start_vehicle` gets its description, a participant on its private
/// domain and a stop token, and returns the vehicle's software as a future; a vehicle that
/// ends or fails stops the relay like any other part.
///
/// Returns an error if the configuration is invalid, a DDS participant or the emulator
/// cannot start, or a part (converter or vehicle) stops on its own; everything it started
/// is stopped.
pub async fn run_emulated_relay<F, Fut>(
    cfg: EmulatedRelayConfig,
    cdt_dds: Arc<PubSub>,
    keys: Option<AcousticKeys>,
    start_vehicle: F,
    shutdown: CancellationToken,
) -> Result<(), ConverterError>
where
    F: FnMut(&RelayedVehicle, Arc<PubSub>, CancellationToken) -> Fut,
    Fut: Future<Output = Result<(), ConverterError>> + Send + 'static,
{
    run_emulated_relay_with(cfg, cdt_dds, keys, start_vehicle, |_| {}, shutdown).await
}

/// [`run_emulated_relay`], handing `on_sea` the running emulator once it is up: a
/// scenario run reads its per-link counters and fails modems through it. The caller
/// should drop its clone when the relay stops.
pub async fn run_emulated_relay_with<F, Fut>(
    cfg: EmulatedRelayConfig,
    cdt_dds: Arc<PubSub>,
    keys: Option<AcousticKeys>,
    mut start_vehicle: F,
    on_sea: impl FnOnce(&Arc<EmulatorHandle>),
    shutdown: CancellationToken,
) -> Result<(), ConverterError>
where
    F: FnMut(&RelayedVehicle, Arc<PubSub>, CancellationToken) -> Fut,
    Fut: Future<Output = Result<(), ConverterError>> + Send + 'static,
{
    cfg.check(cdt_dds.config())?;
    // A child token: a failing part stops the others without cancelling the caller.
    let stop = shutdown.child_token();
    // The sea stops last, once every converter has: a converter that saw its modem vanish
    // first would log a reconnection attempt on every orderly stop. The guard stops it on
    // every way out of here.
    let sea_stop = CancellationToken::new();
    let _sea_guard = sea_stop.clone().drop_guard();
    let emu =
        Arc::new(Emulator::start(cfg.emulator_config(), sea_stop.clone().cancelled_owned()).await?);
    on_sea(&emu);
    let endpoint = |addr: u8| emu.modems().iter().find(|m| m.address == addr).cloned();
    let mut tasks: JoinSet<Result<(), ConverterError>> = JoinSet::new();

    let relay = endpoint(cfg.relay_address)
        .ok_or_else(|| ConverterError::Config("relay modem missing".into()))?;
    if let Some(carrier) = &cfg.relay_vehicle {
        // The relay rides on a vehicle of the station's domain: follow it there.
        let states = cdt_dds.subscribe::<StateVector>()?;
        tasks.spawn(follow(
            emu.clone(),
            cfg.relay_address,
            states,
            Some(carrier.clone()),
            stop.clone(),
        ));
    }
    let mut cdt_cfg = cfg.cdt_config(cfg.modem(relay.at, relay.nl).address);
    let driver = Modem::start_relayed(&cdt_cfg.modem, cdt_cfg.relay_config()?, cfg.time_scale)?;
    if !cfg.relaying.is_empty() {
        // Tasks for a vehicle behind a relay leave enveloped.
        cdt_cfg.link.max_frame = cdt_cfg.link.max_frame.saturating_sub(HEADER_BYTES);
    }
    if let Some(keys) = &keys {
        let mut tagger = keys.tagger(cfg.relay_address);
        for v in &cfg.vehicles {
            tagger.set_key(v.address, keys.key(&v.id)?);
        }
        let driver = TaggedDriver::new(driver, tagger);
        // The tag takes its bytes from every frame the link fills.
        cdt_cfg.link.max_frame = driver.frame_budget(cdt_cfg.link.max_frame);
        tasks.spawn(report_refusals("cdt", driver.refused(), stop.clone()));
        tasks.spawn(run_cdt(cdt_cfg, cdt_dds, driver, stop.clone()));
    } else {
        tasks.spawn(run_cdt(cdt_cfg, cdt_dds, driver, stop.clone()));
    }

    for v in &cfg.vehicles {
        let ep = endpoint(v.address)
            .ok_or_else(|| ConverterError::Config(format!("modem of {} missing", v.id)))?;
        // The vehicle's own network: loopback only, its own domain, never the station's.
        let private = DdsConfig {
            domain_id: v.domain_id,
            ..DdsConfig::default()
        };
        let vehicle_dds = Arc::new(PubSub::new(&private)?);
        let vdt_dds = Arc::new(PubSub::new(&private)?);
        let mut vdt_cfg = VdtConfig {
            modem: cfg.modem(ep.at, ep.nl),
            cdt_address: cfg.relay_address,
            vehicles: vec![AddressEntry {
                vehicle_id: v.id.clone(),
                address: v.address,
            }],
            state_interval_s: cfg.state_interval_s,
            link: cfg.link.clone(),
            time_scale: cfg.time_scale,
            clock: cfg.clock,
            relay: cfg.relaying.get(&v.id).cloned().unwrap_or_default(),
            ..VdtConfig::default()
        };
        if !vdt_cfg.relay.routes.is_empty() {
            // What it sends to the relay's CDT goes through another vehicle, enveloped.
            vdt_cfg.link.max_frame = vdt_cfg.link.max_frame.saturating_sub(HEADER_BYTES);
        }
        if cfg.follow_vehicles {
            let states = vdt_dds.subscribe::<StateVector>()?;
            tasks.spawn(follow(emu.clone(), v.address, states, None, stop.clone()));
        }
        tasks.spawn(start_vehicle(v, vehicle_dds, stop.clone()));
        let driver = Modem::start_relayed(&vdt_cfg.modem, vdt_cfg.relay.clone(), cfg.time_scale)?;
        if let Some(keys) = &keys {
            let mut tagger = keys.tagger(v.address);
            tagger.set_key(cfg.relay_address, keys.key(&v.id)?);
            let driver = TaggedDriver::new(driver, tagger);
            vdt_cfg.link.max_frame = driver.frame_budget(vdt_cfg.link.max_frame);
            tasks.spawn(report_refusals("vdt", driver.refused(), stop.clone()));
            tasks.spawn(run_vdt(vdt_cfg, vdt_dds, driver, stop.clone()));
        } else {
            tasks.spawn(run_vdt(vdt_cfg, vdt_dds, driver, stop.clone()));
        }
        info!(vehicle = %v.id, address = v.address, domain = v.domain_id, "relayed vehicle started");
    }

    let mut result = Ok(());
    while let Some(done) = tasks.join_next().await {
        let r = done.map_err(|e| ConverterError::Config(format!("relay task panicked: {e}")));
        if let Err(e) = r.and_then(|r| r) {
            if result.is_ok() && !shutdown.is_cancelled() {
                warn!(error = %e, "emulated relay part failed; stopping the relay");
                result = Err(e);
            }
            stop.cancel();
        } else if !stop.is_cancelled() {
            // A part ended without being asked to: stop the rest too.
            stop.cancel();
        }
    }
    stop.cancel();
    sea_stop.cancel();
    if let Ok(emu) = Arc::try_unwrap(emu) {
        emu.stopped().await;
    }
    result
}

/// Keeps a vehicle's emulated modem at the vehicle's reported position: every state on
/// `states`, or only `vehicle`'s on a domain that carries others too.
async fn follow(
    emu: Arc<EmulatorHandle>,
    address: u8,
    mut states: shoal_dds::Subscription<StateVector>,
    vehicle: Option<String>,
    stop: CancellationToken,
) -> Result<(), ConverterError> {
    loop {
        tokio::select! {
            () = stop.cancelled() => return Ok(()),
            item = states.next() => match item {
                Some(Ok((s, _))) if vehicle.as_ref().is_some_and(|v| *v != s.vehicle_id) => {}
                Some(Ok((s, _))) => {
                    // The transducer is never above the surface.
                    let depth = s.depth_m.max(0.5);
                    if let Err(e) = emu.set_position(address, s.latitude_deg, s.longitude_deg, depth) {
                        debug!(error = %e, "modem position not updated");
                    }
                }
                Some(Err(e)) => debug!(error = %e, "bad state sample"),
                None => return Ok(()),
            },
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn the_cdt_is_told_where_the_relays_modem_is_and_what_carries_it() {
        let auv = RelayedVehicle {
            id: "auv-7".into(),
            address: 2,
            domain_id: 100,
            latitude_deg: 63.467,
            longitude_deg: 10.372,
        };
        let mut cfg = EmulatedRelayConfig::new(1, 63.464, 10.38, vec![auv]);
        let cdt = cfg.cdt_config(std::net::SocketAddr::from(([127, 0, 0, 1], 0)));
        assert_eq!(
            cdt.position,
            Some(ModemPosition {
                latitude_deg: 63.464,
                longitude_deg: 10.38
            })
        );
        assert_eq!(cdt.carrier, None);
        cfg.relay_vehicle = Some("usv-1".into());
        let cdt = cfg.cdt_config(std::net::SocketAddr::from(([127, 0, 0, 1], 0)));
        assert_eq!(cdt.carrier.as_deref(), Some("usv-1"));
        cdt.check().unwrap();
    }

    #[test]
    fn the_channel_reaches_the_emulated_sea() {
        let mut cfg = EmulatedRelayConfig::new(1, 63.464, 10.38, Vec::new());
        assert_eq!(cfg.emulator_config().channel, ChannelModel::default());
        cfg.channel.wind_mps = 20.0;
        assert_eq!(cfg.emulator_config().channel.wind_mps, 20.0);
    }
}
