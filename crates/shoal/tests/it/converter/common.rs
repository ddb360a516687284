//! Shared helpers: the emulator, DDS participants, converter configs, waiting, and the
//! acoustic demo's relay topology.

use std::future::Future;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use futures::{Stream, StreamExt};
use shoal_acoustic::driver::{ModemDriver, OutFrame, Outcome, RxFrame, TransmitError};
use shoal_acoustic::emulator::{Emulator, EmulatorConfig, EmulatorHandle, ModemConfig};
use shoal_acoustic::pdu::{self, Pdu};
use shoal_converter::emulated_relay::{EmulatedRelayConfig, RelayedVehicle, run_emulated_relay};
use shoal_converter::{
    AddressEntry, CdtConfig, ConverterError, ModemKind, ModemSettings, VdtConfig,
};
use shoal_dds::{DdsConfig, PubSub, ReadError, SampleMeta};
use shoal_model::{GeoPoint, Task, TaskAssignment, Validated, VehicleKind, now_ms};
use shoal_proxy::sim::SimSpec;
use shoal_security::{AcousticKey, AcousticTagger, TagSize};

/// Wall-clock seconds per simulated second in these tests.
pub const SCALE: f64 = 0.1;
/// The CDT's acoustic address.
pub const CDT: u8 = 1;
/// The AUV's acoustic address.
pub const AUV: u8 = 2;
/// Where the AUV starts.
pub const LAT: f64 = 43.0;
/// Where the AUV starts.
pub const LON: f64 = 5.0;

/// A modem `east_m` metres east of the AUV's start, 10 m deep.
pub fn modem(address: u8, east_m: f64, at_port: u16, nl_port: u16) -> ModemConfig {
    let at = shoal_model::geo::LocalFrame::new(GeoPoint {
        latitude_deg: LAT,
        longitude_deg: LON,
    })
    .to_geo(east_m, 0.0);
    ModemConfig {
        address,
        name: format!("m{address}"),
        at_port,
        nl_port,
        latitude_deg: at.latitude_deg,
        longitude_deg: at.longitude_deg,
        depth_m: 10.0,
    }
}

/// An emulator with the CDT's modem and the AUV's 800 m apart, ten times faster than real
/// time; `ports` fixes the (at, nl) ports of both modems (0 = any).
pub async fn emulator(ports: [(u16, u16); 2]) -> EmulatorHandle {
    let cfg = EmulatorConfig {
        time_scale: SCALE,
        seed: 7,
        fixed_per: Some(0.0),
        modems: vec![
            modem(CDT, 800.0, ports[0].0, ports[0].1),
            modem(AUV, 0.0, ports[1].0, ports[1].1),
        ],
        ..EmulatorConfig::default()
    };
    Emulator::start(cfg, std::future::pending()).await.unwrap()
}

/// A free TCP port on 127.0.0.1 (bound and released).
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// A loopback participant on `domain`.
pub fn participant(domain: u16) -> Arc<PubSub> {
    Arc::new(
        PubSub::new(&DdsConfig {
            domain_id: domain,
            ..DdsConfig::default()
        })
        .unwrap(),
    )
}

/// The simulated AUV.
pub fn auv() -> SimSpec {
    SimSpec {
        id: "auv-1".into(),
        kind: VehicleKind::Auv,
        latitude_deg: LAT,
        longitude_deg: LON,
        rate_hz: 2.0,
        battery_pct: 90.0,
    }
}

fn book() -> Vec<AddressEntry> {
    vec![AddressEntry {
        vehicle_id: "auv-1".into(),
        address: AUV,
    }]
}

/// A VDT config for the AUV's modem at `addr` speaking `kind`.
pub fn vdt_config(kind: ModemKind, addr: SocketAddr) -> VdtConfig {
    VdtConfig {
        modem: ModemSettings {
            kind,
            address: addr,
            nl_delivery_reports: true,
        },
        cdt_address: CDT,
        vehicles: book(),
        state_interval_s: 2.0,
        time_scale: SCALE,
        ..VdtConfig::default()
    }
}

/// A CDT config for the CDT's modem at `addr` speaking `kind`.
pub fn cdt_config(kind: ModemKind, addr: SocketAddr) -> CdtConfig {
    CdtConfig {
        modem: ModemSettings {
            kind,
            address: addr,
            nl_delivery_reports: true,
        },
        address: CDT,
        vehicles: book(),
        link_status_interval_s: 5.0,
        time_scale: SCALE,
        ..CdtConfig::default()
    }
}

/// A go-to task for the AUV, issued now.
pub fn goto_task(task_id: &str) -> TaskAssignment {
    TaskAssignment::new(
        task_id,
        "m-1",
        "auv-1",
        now_ms(),
        &Task::GotoWaypoint {
            target: GeoPoint {
                latitude_deg: LAT + 0.002,
                longitude_deg: LON + 0.002,
            },
            depth_m: Some(10.0),
            altitude_m: None,
            speed_mps: 1.5,
        },
    )
}

/// The first valid sample that satisfies `pred`, within `secs` seconds.
pub async fn wait_for<T, S>(
    stream: &mut S,
    secs: u64,
    what: &str,
    mut pred: impl FnMut(&T, &SampleMeta) -> bool,
) -> (T, SampleMeta)
where
    S: Stream<Item = Result<(Validated<T>, SampleMeta), ReadError>> + Unpin,
{
    let fut = async {
        while let Some(item) = stream.next().await {
            if let Ok((v, meta)) = item
                && pred(&v, &meta)
            {
                return (v.into_inner(), meta);
            }
        }
        panic!("stream ended while waiting for {what}");
    };
    within(secs, what, fut).await
}

/// Runs `fut`, failing the test after `secs` seconds.
pub async fn within<F: Future>(secs: u64, what: &str, fut: F) -> F::Output {
    tokio::time::timeout(Duration::from_secs(secs), fut)
        .await
        .unwrap_or_else(|_| panic!("timed out after {secs} s waiting for {what}"))
}

/// A simulated AUV behind a VDT on `vehicle_domain`, a CDT relaying it onto
/// `station_domain`, and the station's participant there, once the AUV's announcement has
/// crossed the acoustic link.
pub struct AcousticAuv {
    /// The station side's participant.
    pub station: Arc<PubSub>,
    /// Task status as the station hears it.
    pub status: shoal_dds::Subscription<shoal_model::TaskStatus>,
    /// The CDT, which ends when `shutdown` is cancelled.
    pub cdt: tokio::task::JoinHandle<Result<(), ConverterError>>,
}

impl AcousticAuv {
    /// Starts it all over EvoLogics AT modems at `auv_at` and `cdt_at`, at `time_scale`.
    pub async fn start(
        (vehicle_domain, station_domain): (u16, u16),
        (cdt_at, auv_at): (SocketAddr, SocketAddr),
        time_scale: f64,
        shutdown: &tokio_util::sync::CancellationToken,
    ) -> Self {
        use shoal_model::{TaskStatus, VehicleAnnouncement};
        let station = participant(station_domain);
        let mut announcements = station.subscribe::<VehicleAnnouncement>().unwrap();
        let status = station.subscribe::<TaskStatus>().unwrap();
        tokio::spawn(shoal_proxy::run_sim(
            auv(),
            participant(vehicle_domain),
            shutdown.clone(),
        ));
        let vdt = VdtConfig {
            time_scale,
            ..vdt_config(ModemKind::EvologicsAt, auv_at)
        };
        let driver = shoal_converter::Modem::start(&vdt.modem, time_scale);
        tokio::spawn(shoal_converter::run_vdt(
            vdt,
            participant(vehicle_domain),
            driver,
            shutdown.clone(),
        ));
        let cdt = CdtConfig {
            time_scale,
            ..cdt_config(ModemKind::EvologicsAt, cdt_at)
        };
        let driver = shoal_converter::Modem::start(&cdt.modem, time_scale);
        let cdt = tokio::spawn(shoal_converter::run_cdt(
            cdt,
            participant(station_domain),
            driver,
            shutdown.clone(),
        ));
        wait_for(
            &mut announcements,
            60,
            "announcement",
            |a: &VehicleAnnouncement, _| a.vehicle_id == "auv-1",
        )
        .await;
        Self {
            station,
            status,
            cdt,
        }
    }
}

/// The relay of `shoal up`'s acoustic demo (`crates/shoal/src/relay.rs`): one AUV,
/// `auv-ac1`, off Trondheim about 520 m from the relay, on `private_domain`, the sea and
/// the converters at `time_scale`; and the simulated vehicle to put behind it.
pub fn demo_relay(private_domain: u16, time_scale: f64) -> (EmulatedRelayConfig, SimSpec) {
    let sim = SimSpec {
        id: "auv-ac1".into(),
        kind: VehicleKind::Auv,
        latitude_deg: 63.4670,
        longitude_deg: 10.3720,
        rate_hz: 1.0,
        battery_pct: 100.0,
    };
    let auv = RelayedVehicle {
        id: sim.id.clone(),
        address: 2,
        domain_id: private_domain,
        latitude_deg: sim.latitude_deg,
        longitude_deg: sim.longitude_deg,
    };
    let mut relay = EmulatedRelayConfig::new(1, 63.4640, 10.3800, vec![auv]);
    relay.time_scale = time_scale;
    (relay, sim)
}

/// Runs `relay` until `stop` with the simulated `sim` behind it (every relayed vehicle is
/// that simulator) and the CDT on `station`'s domain with its own participant, as the
/// demo does.
pub async fn run_relayed_sim(
    relay: EmulatedRelayConfig,
    sim: SimSpec,
    station: DdsConfig,
    stop: tokio_util::sync::CancellationToken,
) -> Result<(), ConverterError> {
    relay.check(&station)?;
    let cdt_dds = Arc::new(PubSub::new(&station)?);
    let start_sim = move |_: &RelayedVehicle, dds, stop| {
        let spec = sim.clone();
        async move {
            shoal_proxy::run_sim(spec, dds, stop)
                .await
                .map_err(ConverterError::from)
        }
    };
    run_emulated_relay(relay, cdt_dds, None, start_sim, stop).await
}

/// A modem whose received frames the test pushes; what the CDT sends is accepted.
pub struct ScriptedModem {
    rx: tokio::sync::Mutex<tokio::sync::mpsc::Receiver<RxFrame>>,
    /// Every frame the CDT transmitted, in order.
    pub sent: Arc<std::sync::Mutex<Vec<OutFrame>>>,
}

impl ScriptedModem {
    /// A modem that receives what is pushed into `rx`.
    pub fn new(rx: tokio::sync::mpsc::Receiver<RxFrame>) -> Self {
        Self {
            rx: tokio::sync::Mutex::new(rx),
            sent: Arc::default(),
        }
    }
}

impl ModemDriver for ScriptedModem {
    async fn transmit(&self, frame: OutFrame) -> Result<Outcome, TransmitError> {
        self.sent.lock().unwrap().push(frame);
        Ok(Outcome::Sent)
    }

    async fn receive(&self) -> Option<RxFrame> {
        self.rx.lock().await.recv().await
    }

    fn local_address(&self) -> Option<u8> {
        Some(CDT)
    }

    fn is_connected(&self) -> bool {
        true
    }
}

/// One vehicle's modem: seals frames to the CDT with the key it shares with the station.
pub struct Sender {
    address: u8,
    tagger: AcousticTagger,
}

impl Sender {
    pub fn new(address: u8, key: &AcousticKey) -> Self {
        let mut tagger = AcousticTagger::new(address, TagSize::Bits64, 1);
        tagger.set_key(CDT, key);
        Self { address, tagger }
    }

    pub fn frame(&mut self, p: &Pdu) -> RxFrame {
        let data = self
            .tagger
            .seal(CDT, &pdu::pack_frame(std::slice::from_ref(p)).unwrap())
            .unwrap();
        RxFrame {
            src: self.address,
            dst: CDT,
            data,
            rssi: None,
            integrity: None,
        }
    }
}
