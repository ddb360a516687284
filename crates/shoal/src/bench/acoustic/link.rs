//! The channel measurements of `shoal bench acoustic` on emulated modems on 127.0.0.1 with
//! the real AT drivers and link layer, in simulated seconds: two modems with a free MAC
//! ([`channel_use`], [`emergency_latency`], [`control_delivery`]), and a station with four
//! vehicles in TDMA slots ([`fleet_channel_use`], [`fleet_emergency`]).

use std::time::Duration;

use anyhow::{Context, Result, anyhow, bail};
use shoal_acoustic::channel::sound_speed_mackenzie;
use shoal_acoustic::driver::{AtDriver, DriverConfig};
use shoal_acoustic::emulator::{Emulator, EmulatorConfig, EmulatorHandle, ModemConfig};
use shoal_acoustic::link::{self, Class, LinkConfig, LinkEvent, LinkSender, Mac, Outgoing};
use shoal_acoustic::pdu::{self, CompactEvent, CompactTask, MAX_FRAME, Pdu, TaskAction};
use tokio::sync::mpsc;
use tokio::time::Instant;

use super::{
    BenchOptions, ChannelUse, ControlDelivery, EmergencyLatency, FLEET_GOAL, FleetChannelUse,
    FleetEmergency, FleetTrial,
};

/// Two modems, a sending link on modem 1 and a receiving link on modem 2.
struct Rig {
    emu: EmulatorHandle,
    tx: LinkSender,
    rx: mpsc::Receiver<LinkEvent>,
    tx_events: mpsc::Receiver<LinkEvent>,
    scale: f64,
    shutdown: tokio_util::sync::CancellationToken,
}

impl Drop for Rig {
    fn drop(&mut self) {
        self.shutdown.cancel();
        self.emu.shutdown();
    }
}

fn check(opts: &BenchOptions) -> Result<()> {
    let ok = opts.time_scale.is_finite()
        && opts.time_scale > 0.0
        && opts.distance_m.is_finite()
        && opts.distance_m > 0.0
        && opts.saturation_s.is_finite()
        && opts.saturation_s > 0.0
        && (0.0..1.0).contains(&opts.control_per);
    if !ok {
        bail!("bench options out of range: {opts:?}");
    }
    Ok(())
}

impl Rig {
    async fn start(
        opts: &BenchOptions,
        tweak: impl FnOnce(&mut EmulatorConfig),
        link_cfg: LinkConfig,
    ) -> Result<Self> {
        check(opts)?;
        let origin = shoal_model::geo::LocalFrame::new(shoal_model::GeoPoint {
            latitude_deg: 43.0,
            longitude_deg: 5.0,
        });
        let m = |address: u8, east_m: f64| {
            let at = origin.to_geo(east_m, 0.0);
            ModemConfig {
                address,
                name: format!("bench-{address}"),
                latitude_deg: at.latitude_deg,
                longitude_deg: at.longitude_deg,
                depth_m: 20.0,
                ..ModemConfig::default()
            }
        };
        let mut cfg = EmulatorConfig {
            time_scale: opts.time_scale,
            seed: opts.seed,
            fixed_per: Some(0.0),
            modems: vec![m(1, 0.0), m(2, opts.distance_m)],
            ..EmulatorConfig::default()
        };
        tweak(&mut cfg);
        let emu = Emulator::start(cfg, std::future::pending()).await?;
        let driver = |i: usize| -> Result<AtDriver> {
            let ep = emu.modems().get(i).context("emulator modem missing")?;
            let mut d = DriverConfig::new(ep.at).scaled(opts.time_scale);
            // Poll a busy modem every 20 ms (simulated) instead of 0.5 s: the driver holds
            // the next frame until the modem should be free, but should it still answer
            // `BUSY` (timer slip), the default would idle the channel for half a second.
            // The hand-over lead is the driver's default (20 ms, scaled).
            d.busy_retry =
                Duration::from_secs_f64(0.02 * opts.time_scale).max(Duration::from_millis(1));
            Ok(AtDriver::start(d))
        };
        let shutdown = tokio_util::sync::CancellationToken::new();
        let (tx, tx_events) = link::start(
            driver(0)?,
            link_cfg.scaled(opts.time_scale),
            shutdown.clone().cancelled_owned(),
        );
        let (_peer, rx) = link::start(
            driver(1)?,
            LinkConfig::default().scaled(opts.time_scale),
            shutdown.clone().cancelled_owned(),
        );
        Ok(Self {
            emu,
            tx,
            rx,
            tx_events,
            scale: opts.time_scale,
            shutdown,
        })
    }

    fn sim(&self, wall: Duration) -> f64 {
        wall.as_secs_f64() / self.scale
    }

    fn wall(&self, sim_s: f64) -> Duration {
        Duration::from_secs_f64(sim_s * self.scale)
    }

    async fn send(&self, class: Class, pdu: Vec<u8>) -> Result<u64> {
        self.tx
            .send(Outgoing {
                dst: 2,
                class,
                pdu,
                supersede_key: None,
            })
            .await
            .map_err(|_| anyhow!("acoustic link stopped"))
    }
}

/// A 10-byte delta State Vector, the typical telemetry PDU.
fn telemetry_pdu() -> Result<Vec<u8>> {
    pdu::samples()
        .into_iter()
        .find(|(n, _)| *n == "state_delta")
        .and_then(|(_, p)| pdu::encode(&p).ok())
        .context("no delta sample PDU")
}

/// A saturating telemetry load: a long queue that never runs dry during the run.
fn saturating_link(opts: &BenchOptions) -> LinkConfig {
    let mut cfg = LinkConfig::default();
    cfg.telemetry.max_len = 100_000;
    cfg.telemetry.ttl = Duration::from_secs_f64(opts.saturation_s * 10.0 + 600.0);
    cfg
}

async fn fill(rig: &Rig, opts: &BenchOptions, bytes: &[u8]) -> Result<()> {
    // ~10 PDUs/s leave at 976 bit/s; queue twice what the run can drain.
    #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
    let n = (opts.saturation_s * 20.0).ceil() as usize + 100;
    for _ in 0..n {
        rig.send(Class::Telemetry, bytes.to_vec()).await?;
    }
    Ok(())
}

/// Air time of a frame of `bytes` at the emulator's defaults, simulated seconds.
fn air_time_s(bytes: usize) -> f64 {
    let d = EmulatorConfig::default();
    #[allow(clippy::cast_precision_loss)]
    let bits = (bytes * 8) as f64;
    d.preamble_s + bits / d.im_bit_rate
}

/// Channel use while a telemetry queue saturates the link.
pub(super) async fn channel_use(opts: &BenchOptions) -> Result<ChannelUse> {
    let mut rig = Rig::start(opts, |_| {}, saturating_link(opts)).await?;
    let pdu = telemetry_pdu()?;
    fill(&rig, opts, &pdu).await?;
    let t = tally(&mut rig.rx, rig.scale, opts.saturation_s).await;
    Ok(channel_figures(&t, 0.9))
}

/// Size of the alarm PDU the latency trials send.
fn telemetry_alarm_len() -> Result<usize> {
    pdu::encode(&Pdu::Event(CompactEvent {
        vehicle: Some(1),
        event_no: 0,
        severity: 3,
        kind: 3,
        task_no: None,
        seconds_of_day: 0,
    }))
    .map(|b| b.len())
    .context("alarm PDU")
}

/// Latency of emergency messages while telemetry saturates the channel.
pub(super) async fn emergency_latency(opts: &BenchOptions) -> Result<EmergencyLatency> {
    let mut rig = Rig::start(opts, |_| {}, saturating_link(opts)).await?;
    let pdu = telemetry_pdu()?;
    fill(&rig, opts, &pdu).await?;
    let mut latencies = Vec::new();
    for trial in 0..opts.emergency_trials {
        // Land at different points of the frame cycle.
        let pause = 3.0 + f64::from(trial) * 0.37;
        tokio::time::sleep(rig.wall(pause)).await;
        let event_no = u8::try_from(trial % 256).unwrap_or(0);
        let alarm = pdu::encode(&Pdu::Event(CompactEvent {
            vehicle: Some(1),
            event_no,
            severity: 3,
            kind: 3,
            task_no: None,
            seconds_of_day: 0,
        }))
        .context("alarm PDU")?;
        let t0 = Instant::now();
        rig.send(Class::Emergency, alarm.clone()).await?;
        let deadline = t0 + rig.wall(60.0);
        loop {
            match tokio::time::timeout_at(deadline, rig.rx.recv()).await {
                Ok(Some(LinkEvent::Received { frame, .. })) if frame.starts_with(&alarm) => {
                    latencies.push(rig.sim(t0.elapsed()));
                    break;
                }
                Ok(Some(_)) => {}
                Ok(None) => bail!("acoustic link stopped"),
                Err(_) => {
                    latencies.push(f64::INFINITY);
                    break;
                }
            }
        }
    }
    let c = sound_speed_mackenzie(10.0, 35.0, 20.0);
    let bound_s = air_time_s(MAX_FRAME) + opts.distance_m / c;
    let alarm_len = telemetry_alarm_len()?;
    let bound_one_frame_wait_s = bound_s + air_time_s(alarm_len);
    // The goal's literal bound, from queueing, one sender saturating a free channel.
    for (trial, latency_s) in latencies.iter().enumerate() {
        tracing::info!(
            trial,
            latency_s,
            bound_s = bound_one_frame_wait_s,
            within = *latency_s <= bound_one_frame_wait_s,
            "free-access emergency trial"
        );
    }
    let finite: Vec<f64> = latencies
        .iter()
        .copied()
        .filter(|l| l.is_finite())
        .collect();
    #[allow(clippy::cast_precision_loss)]
    let mean_s = if finite.len() == latencies.len() && !finite.is_empty() {
        finite.iter().sum::<f64>() / finite.len() as f64
    } else {
        f64::INFINITY
    };
    Ok(EmergencyLatency {
        within_bound: latencies.iter().filter(|l| **l <= bound_s).count(),
        within_one_frame_wait: latencies
            .iter()
            .filter(|l| **l <= bound_one_frame_wait_s)
            .count(),
        bound_one_frame_wait_s,
        max_s: latencies.iter().copied().fold(0.0, f64::max),
        mean_s,
        bound_s,
        latencies_s: latencies,
    })
}

/// Delivery of control messages at `control_per` with no modem-level retries.
pub(super) async fn control_delivery(opts: &BenchOptions) -> Result<ControlDelivery> {
    // One message per frame, so every message faces the loss on its own.
    let cfg = LinkConfig {
        max_frame: 16,
        ..LinkConfig::default()
    };
    let ttl = cfg.control.ttl;
    let per = opts.control_per;
    let mut rig = Rig::start(
        opts,
        |c| {
            c.fixed_per = Some(per);
            c.im_retries = 0;
        },
        cfg,
    )
    .await?;
    let mut pending = std::collections::HashSet::new();
    for n in 0..opts.control_messages {
        let task = Pdu::Task(CompactTask {
            vehicle: 2,
            task_no: u8::try_from(n % 256).unwrap_or(0),
            action: TaskAction::Hold { duration_s: 60 },
        });
        let bytes = pdu::encode(&task).context("task PDU")?;
        pending.insert(rig.send(Class::Control, bytes).await?);
    }
    let t0 = Instant::now();
    let deadline = t0 + rig.wall(ttl.as_secs_f64());
    let sent = opts.control_messages;
    let mut delivered = 0;
    let mut after = 0.0;
    while !pending.is_empty() {
        match tokio::time::timeout_at(deadline, rig.tx_events.recv()).await {
            Ok(Some(LinkEvent::Delivered(id))) => {
                if pending.remove(&id) {
                    delivered += 1;
                    after = rig.sim(t0.elapsed());
                }
            }
            Ok(Some(LinkEvent::Expired(id) | LinkEvent::Dropped(id))) => {
                pending.remove(&id);
            }
            Ok(Some(_)) => {}
            Ok(None) | Err(_) => break,
        }
    }
    let packets_lost = rig.emu.stats().iter().map(|l| l.lost + l.collisions).sum();
    Ok(ControlDelivery {
        per,
        sent,
        delivered,
        ttl_s: ttl.as_secs_f64(),
        all_delivered_after_s: after,
        packets_lost,
    })
}

/// Vehicles sharing the channel in the fleet measurements.
pub(super) const FLEET: u32 = 4;

/// The station's modem address in the fleet measurements; vehicles are 2..=5.
const STATION: u8 = 1;

/// Ranges of the four vehicles from the station, metres, as multiples of `distance_m`:
/// unequal, so the slots must absorb a spread of propagation delays.
const RANGE_FACTORS: [f64; FLEET as usize] = [0.6, 0.85, 1.0, 1.25];

/// The saturating load each vehicle sends.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Load {
    /// The VDT's State Vector PDUs over the simulated AUV's track (keyframes and the
    /// smaller of the two delta layouts, as `DeltaEncoder::predictive` sends them).
    VdtStates,
    /// 10-byte layout-1 deltas only, the two-modem measurement's load.
    Deltas10,
}

impl Load {
    fn name(self) -> &'static str {
        match self {
            Self::VdtStates => "VDT state PDUs (keyframes + predicted deltas)",
            Self::Deltas10 => "10-byte layout-1 deltas",
        }
    }
}

/// The TDMA plan the fleet shares, simulated seconds.
#[derive(Debug, Clone, Copy)]
pub(super) struct Plan {
    /// Slot length.
    pub slot_s: f64,
    /// Guard at the end of each slot.
    pub guard_s: f64,
    /// Full frames per slot.
    pub frames_per_slot: u32,
}

impl Plan {
    /// Slots of `frames_per_slot` full instant messages plus a guard. Each vehicle starts
    /// its slot early by its own propagation delay to the station (timing advance), so the
    /// slots line up where the frames are received and the guard covers only what advance
    /// cannot: the clocks' disagreement and, in the emulator, timer slip, which is about a
    /// few milliseconds of wall time, i.e. `3 ms / time_scale` simulated.
    fn new(frames_per_slot: u32, time_scale: f64) -> Self {
        let guard_s = 0.02 + 0.003 / time_scale;
        // Room for the slot's first frame to start a timer tick late.
        let slack_s = 0.001 / time_scale;
        Self {
            slot_s: f64::from(frames_per_slot) * air_time_s(MAX_FRAME) + slack_s + guard_s,
            guard_s,
            frames_per_slot,
        }
    }

    fn cycle_s(&self) -> f64 {
        self.slot_s * f64::from(FLEET)
    }

    /// Vehicle `k`'s link configuration (simulated time), with its timing advance.
    fn link(&self, k: u32, advance_s: f64, base: &LinkConfig) -> LinkConfig {
        LinkConfig {
            mac: Mac::tdma(
                Duration::from_secs_f64(self.slot_s),
                FLEET,
                k,
                Duration::from_secs_f64(self.guard_s),
            )
            .with_advance(Duration::from_secs_f64(advance_s)),
            ..base.clone()
        }
    }
}

/// A station and four vehicles on one channel, each vehicle in its own TDMA slot.
struct Fleet {
    emu: EmulatorHandle,
    vehicles: Vec<LinkSender>,
    station: mpsc::Receiver<LinkEvent>,
    /// One-way propagation delay of each vehicle to the station, simulated s.
    delay_s: Vec<f64>,
    /// Each vehicle's medium access as its link runs it (wall time).
    macs: Vec<Mac>,
    plan: Plan,
    scale: f64,
    shutdown: tokio_util::sync::CancellationToken,
}

impl Drop for Fleet {
    fn drop(&mut self) {
        self.shutdown.cancel();
        self.emu.shutdown();
    }
}

impl Fleet {
    async fn start(opts: &BenchOptions, base: &LinkConfig) -> Result<Self> {
        check(opts)?;
        let scale = opts.fleet_time_scale;
        if !(scale.is_finite() && scale > 0.0 && scale <= 1.0) || opts.frames_per_slot == 0 {
            bail!("fleet bench options out of range: {opts:?}");
        }
        let origin = shoal_model::geo::LocalFrame::new(shoal_model::GeoPoint {
            latitude_deg: 43.0,
            longitude_deg: 5.0,
        });
        let modem = |address: u8, east_m: f64, north_m: f64| {
            let at = origin.to_geo(east_m, north_m);
            ModemConfig {
                address,
                name: format!("fleet-{address}"),
                latitude_deg: at.latitude_deg,
                longitude_deg: at.longitude_deg,
                depth_m: 20.0,
                ..ModemConfig::default()
            }
        };
        let mut modems = vec![modem(STATION, 0.0, 0.0)];
        let mut ranges = Vec::new();
        for (k, f) in (0u8..).zip(RANGE_FACTORS) {
            // Spread round the station so the vehicles are far from each other too.
            let bearing = f64::from(k) * std::f64::consts::FRAC_PI_2 + 0.3;
            let r = f * opts.distance_m;
            modems.push(modem(2 + k, r * bearing.sin(), r * bearing.cos()));
            ranges.push(r);
        }
        let cfg = EmulatorConfig {
            time_scale: scale,
            seed: opts.seed,
            fixed_per: Some(0.0),
            // A modem retries an unacknowledged message whenever it likes, slot or not:
            // under TDMA the link layer retransmits, in its own slot (AT!RI0 on an S2C).
            im_retries: 0,
            modems,
            ..EmulatorConfig::default()
        };
        let c = cfg.channel.sound_speed(20.0);
        let emu = Emulator::start(cfg, std::future::pending()).await?;
        let driver = |i: usize| -> Result<AtDriver> {
            let ep = emu.modems().get(i).context("emulator modem missing")?;
            let mut d = DriverConfig::new(ep.at).scaled(scale);
            d.busy_retry = Duration::from_secs_f64(0.02 * scale).max(Duration::from_millis(1));
            Ok(AtDriver::start(d))
        };
        let plan = Plan::new(opts.frames_per_slot, scale);
        let shutdown = tokio_util::sync::CancellationToken::new();
        let (_station_tx, station) = link::start(
            driver(0)?,
            LinkConfig::default().scaled(scale),
            shutdown.clone().cancelled_owned(),
        );
        let delay_s: Vec<f64> = ranges.iter().map(|r| r / c).collect();
        let mut vehicles = Vec::new();
        let mut macs = Vec::new();
        for (k, d) in (0u32..).zip(&delay_s) {
            let cfg = plan.link(k, *d, base).scaled(scale);
            macs.push(cfg.mac);
            let (tx, _events) = link::start(
                driver(usize::try_from(k + 1)?)?,
                cfg,
                shutdown.clone().cancelled_owned(),
            );
            vehicles.push(tx);
        }
        Ok(Self {
            emu,
            vehicles,
            station,
            delay_s,
            macs,
            plan,
            scale,
            shutdown,
        })
    }

    fn sim(&self, wall: Duration) -> f64 {
        wall.as_secs_f64() / self.scale
    }

    fn wall(&self, sim_s: f64) -> Duration {
        Duration::from_secs_f64(sim_s * self.scale)
    }

    async fn send(&self, vehicle: usize, class: Class, pdu: Vec<u8>) -> Result<u64> {
        self.vehicles
            .get(vehicle)
            .context("no such vehicle")?
            .send(Outgoing {
                dst: STATION,
                class,
                pdu,
                supersede_key: None,
            })
            .await
            .map_err(|_| anyhow!("acoustic link stopped"))
    }

    /// Queues `n` PDUs of `load` on every vehicle.
    async fn fill(&self, load: Load, n: usize) -> Result<()> {
        let pdus = match load {
            Load::VdtStates => vdt_state_pdus(n * self.vehicles.len())?,
            Load::Deltas10 => vec![telemetry_pdu()?; n * self.vehicles.len()],
        };
        for (i, p) in pdus.into_iter().enumerate() {
            self.send(i % self.vehicles.len(), Class::Telemetry, p)
                .await?;
        }
        Ok(())
    }

    /// Where the slot of vehicle `k` stands now for a frame of `bytes`, reckoned by the
    /// vehicle's own link arithmetic ([`slot_state`]).
    fn slot_state(&self, k: usize, bytes: usize) -> Result<SlotState> {
        let since_unix = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap_or_default();
        let mac = self.macs.get(k).context("no such vehicle")?;
        slot_state(mac, since_unix, Instant::now(), bytes, self.scale).context("not TDMA")
    }
}

/// Where a node stands in its TDMA slots for a frame of `bytes`, simulated seconds.
#[derive(Debug, Clone, Copy, PartialEq)]
struct SlotState {
    /// For how much longer a frame of `bytes` may still start in the own slot open now
    /// (zero outside it, or when too little of it is left).
    room_s: f64,
    /// Until the own slot next opens after the current one.
    next_open_s: f64,
}

/// [`SlotState`] of a node whose link runs `mac` (wall time, `scale` wall seconds per
/// simulated one) when the wall clock reads `since_unix` at `now`.
///
/// This asks the link's own reckoning ([`Mac::own_slot_at`]). An earlier version reckoned
/// the phase itself, `since_unix / scale` modulo the cycle in floating simulated seconds,
/// while the links count whole nanoseconds: the scaled slot is rounded to a nanosecond
/// (321 295 082 ns for 321 295 081.967), and that third of a nanosecond per cycle, over
/// the 1.4 × 10⁹ cycles since 1970, put the benchmark's idea of the slots 0.73 s
/// (simulated) ahead of the vehicles' on 2026-11-27: the "unexplained 0.74 s" after the
/// slot opened was that much of the wait for the slot, wrongly counted after it.
fn slot_state(
    mac: &Mac,
    since_unix: Duration,
    now: Instant,
    bytes: usize,
    scale: f64,
) -> Option<SlotState> {
    let Mac::Tdma {
        guard,
        preamble,
        bit_rate,
        ..
    } = *mac
    else {
        return None;
    };
    let own = mac.own_slot_at(since_unix, now)?;
    #[allow(clippy::cast_precision_loss)]
    let air_s = preamble.as_secs_f64() + (bytes * 8) as f64 / bit_rate.max(1e-9);
    let room_s = (own.left.as_secs_f64() - guard.as_secs_f64() - air_s).max(0.0);
    Some(SlotState {
        room_s: room_s / scale,
        next_open_s: own.next_open.saturating_duration_since(now).as_secs_f64() / scale,
    })
}

/// `n` State Vector PDUs as the VDT codes them: the simulated AUV's track through a
/// predictive encoder, 7 of 10 keyframes acknowledged (as `coding`).
fn vdt_state_pdus(n: usize) -> Result<Vec<Vec<u8>>> {
    let track = super::coding::track(n)?;
    let mut enc = pdu::DeltaEncoder::predictive();
    let (mut out, mut keyframes, mut pending) = (Vec::with_capacity(n), 0usize, None);
    for state in &track {
        let p = enc.encode(state)?;
        if let Some(seq) = pending.take() {
            enc.acknowledge(seq);
        }
        if let Pdu::StateKeyframe(k) = &p {
            keyframes += 1;
            if !matches!(keyframes % 10, 3 | 6 | 9) {
                pending = Some(k.seq);
            }
        }
        out.push(pdu::encode(&p)?);
    }
    Ok(out)
}

/// What arrived at a receiver over a measurement window.
struct Tally {
    seconds: f64,
    frames: u64,
    bytes: u64,
    air_s: f64,
    per_src: std::collections::BTreeMap<u8, u64>,
}

/// Counts frames arriving on `rx` for `window_s` simulated seconds, from the end of the
/// first one (so start-up is not counted) to the end of the last one.
async fn tally(rx: &mut mpsc::Receiver<LinkEvent>, scale: f64, window_s: f64) -> Tally {
    let sim = |d: Duration| d.as_secs_f64() / scale;
    let mut first: Option<Instant> = None;
    let mut last = None;
    let mut t = Tally {
        seconds: 0.0,
        frames: 0,
        bytes: 0,
        air_s: 0.0,
        per_src: std::collections::BTreeMap::new(),
    };
    let deadline = Instant::now() + Duration::from_secs_f64((window_s + 30.0) * scale);
    while let Ok(Some(ev)) = tokio::time::timeout_at(deadline, rx.recv()).await {
        if let LinkEvent::Received { frame, src, .. } = ev {
            let now = Instant::now();
            match first {
                None => first = Some(now),
                Some(t0) => {
                    t.frames += 1;
                    t.bytes += frame.len() as u64;
                    t.air_s += air_time_s(frame.len());
                    *t.per_src.entry(src).or_default() += 1;
                    last = Some(now);
                    if sim(now - t0) >= window_s {
                        break;
                    }
                }
            }
        }
    }
    if let (Some(a), Some(b)) = (first, last) {
        t.seconds = sim(b - a);
    }
    t
}

/// The shared definition of channel use (see [`ChannelUse`]).
fn channel_figures(t: &Tally, goal: f64) -> ChannelUse {
    let d = EmulatorConfig::default();
    #[allow(clippy::cast_precision_loss)]
    let (frame_fill, payload_bit_s) = (
        if t.frames == 0 {
            0.0
        } else {
            t.bytes as f64 / (t.frames as f64 * MAX_FRAME as f64)
        },
        t.bytes as f64 * 8.0 / d.im_bit_rate,
    );
    let ratio = |x: f64| if t.seconds > 0.0 { x / t.seconds } else { 0.0 };
    let busy_share = ratio(t.air_s).min(1.0);
    let channel_use = busy_share * frame_fill;
    ChannelUse {
        seconds: t.seconds,
        frames: t.frames,
        payload_bytes: t.bytes,
        busy_share,
        frame_fill,
        channel_use,
        payload_bit_share: ratio(payload_bit_s).min(1.0),
        goal_met: channel_use >= goal,
    }
}

/// Channel use at the station while four vehicles saturate their TDMA slots with `load`.
pub(super) async fn fleet_channel_use(opts: &BenchOptions, load: Load) -> Result<FleetChannelUse> {
    let mut fleet = Fleet::start(opts, &saturating_link(opts)).await?;
    // Each vehicle gets a quarter of ~100 B/s; queue twice what the run can drain.
    #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
    let n = (opts.saturation_s * 10.0).ceil() as usize + 200;
    fleet.fill(load, n).await?;
    let scale = fleet.scale;
    let t = tally(&mut fleet.station, scale, opts.saturation_s).await;
    let stats = fleet.emu.stats();
    let to_station = stats.iter().filter(|l| l.dst == STATION);
    let (collisions, half_duplex) =
        to_station.fold((0, 0), |(c, h), l| (c + l.collisions, h + l.half_duplex));
    Ok(FleetChannelUse {
        vehicles: FLEET,
        load: load.name(),
        time_scale: scale,
        slot_s: fleet.plan.slot_s,
        guard_s: fleet.plan.guard_s,
        frames_per_slot: fleet.plan.frames_per_slot,
        ranges_m: RANGE_FACTORS.iter().map(|f| f * opts.distance_m).collect(),
        frames_per_vehicle: t.per_src.values().copied().collect(),
        collisions,
        half_duplex,
        channel: channel_figures(&t, FLEET_GOAL),
    })
}

/// Emergency latency with four vehicles saturating the channel: each trial queues an alarm
/// on one vehicle (in turn) at a different point of the TDMA cycle.
pub(super) async fn fleet_emergency(opts: &BenchOptions) -> Result<FleetEmergency> {
    let mut fleet = Fleet::start(opts, &saturating_link(opts)).await?;
    #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
    let n = (opts.saturation_s * 10.0).ceil() as usize + 200;
    fleet.fill(Load::VdtStates, n).await?;
    let alarm_len = telemetry_alarm_len()?;
    let short_frame_s = air_time_s(MAX_FRAME);
    let own_air_s = air_time_s(alarm_len);
    let cycle = fleet.plan.cycle_s();
    let mut trials = Vec::new();
    // Let the slots settle into saturation first.
    tokio::time::sleep(fleet.wall(cycle)).await;
    for trial in 0..opts.emergency_trials {
        // Golden-ratio steps spread the trials over the cycle.
        let phase = (f64::from(trial) * 0.618_034).fract() * cycle;
        tokio::time::sleep(fleet.wall(2.0 + phase)).await;
        let k = usize::try_from(trial % FLEET)?;
        let alarm = pdu::encode(&Pdu::Event(CompactEvent {
            vehicle: Some(u8::try_from(k + 2)?),
            event_no: u8::try_from(trial % 256).unwrap_or(0),
            severity: 3,
            kind: 3,
            task_no: None,
            seconds_of_day: 0,
        }))
        .context("alarm PDU")?;
        let slot = fleet.slot_state(k, alarm.len())?;
        let t0 = Instant::now();
        fleet.send(k, Class::Emergency, alarm.clone()).await?;
        let deadline = t0 + fleet.wall(60.0);
        let latency_s = loop {
            match tokio::time::timeout_at(deadline, fleet.station.recv()).await {
                Ok(Some(LinkEvent::Received { frame, .. })) if frame.starts_with(&alarm) => {
                    break fleet.sim(t0.elapsed());
                }
                Ok(Some(_)) => {}
                Ok(None) => bail!("acoustic link stopped"),
                Err(_) => break f64::INFINITY,
            }
        };
        let propagation_s = fleet.delay_s.get(k).copied().unwrap_or(0.0);
        let bound_s = short_frame_s + own_air_s + propagation_s;
        // The judged latency runs from the opening of the next slot in which the alarm can
        // go (docs/acoustic.md#channel-use-and-emergency-latency), or from queueing when it
        // was queued in its own slot with room for it. An alarm queued in its slot's tail,
        // when the frame on air left it no room, goes first in the next slot, and that slot
        // is the reference; arriving after the next opening tells which happened (this slot's
        // frames arrive before it: the rest of the cycle is longer than any propagation).
        // With at least a short frame's room left it had to go in this slot: if it did not,
        // it is judged from queueing, and fails.
        let (where_queued, slot_wait_s) = if slot.room_s <= 0.0 {
            ("outside its slot", slot.next_open_s)
        } else if latency_s < slot.next_open_s {
            ("in its slot", 0.0)
        } else if slot.room_s < short_frame_s {
            (
                "in its slot's tail, behind the last frame",
                slot.next_open_s,
            )
        } else {
            ("in its slot, yet sent in the next: missed", 0.0)
        };
        tracing::info!(
            trial,
            vehicle = k + 2,
            where_queued,
            latency_s,
            slot_wait_s,
            from_reference_s = latency_s - slot_wait_s,
            bound_s,
            cycle_s = cycle,
            "fleet emergency trial"
        );
        trials.push(FleetTrial {
            vehicle: u8::try_from(k + 2)?,
            latency_s,
            slot_wait_s,
            bound_s,
            within_bound: latency_s <= bound_s,
            after_slot_s: latency_s - slot_wait_s,
            within_bound_after_slot: latency_s - slot_wait_s <= bound_s,
        });
    }
    Ok(FleetEmergency {
        short_frame_s,
        own_air_s,
        cycle_s: cycle,
        within_bound: trials.iter().filter(|t| t.within_bound).count(),
        within_bound_after_slot: trials.iter().filter(|t| t.within_bound_after_slot).count(),
        trials,
    })
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used)]
mod tests {
    use super::*;

    /// The "unexplained 0.74 s" of the four-vehicle emergency trials: the benchmark
    /// reckoned the vehicles' slots in floating seconds since 1970 while their links count
    /// whole nanoseconds, and on 2026-11-27 the two were 0.73 s (simulated) apart, so part
    /// of the wait for the slot was counted after it opened. The benchmark's reckoning must
    /// be the link's, at today's clock, for every phase of the cycle.
    #[test]
    fn the_bench_reckons_a_vehicles_slot_as_its_link_does() {
        let scale = 0.25;
        let plan = Plan::new(2, scale);
        let alarm = 5;
        // 2026-11-27T00:00:00Z.
        let day = Duration::from_secs(1_795_737_600);
        for k in 0..FLEET {
            let cfg = plan.link(k, 0.4 + 0.1 * f64::from(k), &LinkConfig::default());
            let cfg = cfg.scaled(scale);
            let t0 = Instant::now();
            // The running link's own view: its epoch from the clock at start, then where it
            // may start a frame of the alarm's size.
            let epoch = cfg.mac.tdma_epoch(day, t0).unwrap();
            let core = link::LinkCore::new(cfg.clone(), epoch);
            for step in 0..400u32 {
                let dt = Duration::from_millis(7) * step;
                let st = slot_state(&cfg.mac, day + dt, t0 + dt, alarm, scale).unwrap();
                let budget = core.frame_budget(t0 + dt);
                match budget {
                    Ok(bytes) if bytes > alarm => {
                        assert!(st.room_s > 0.0, "vehicle {k} step {step}: {st:?}");
                    }
                    Ok(_) => {}
                    Err(next) => {
                        assert!(st.room_s <= 0.0, "vehicle {k} step {step}: {st:?}");
                        let link_wait_s = (next - (t0 + dt)).as_secs_f64() / scale;
                        assert!(
                            (link_wait_s - st.next_open_s).abs() < 1e-6,
                            "vehicle {k} step {step}: link {link_wait_s} bench {st:?}"
                        );
                    }
                }
            }
        }
    }
}
