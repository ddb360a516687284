//! The link-failover measurement of `shoal bench acoustic` (docs/acoustic.md#link-failover):
//! a simulated AUV that surfaces and dives again and again, with a VDT that has an IP path
//! (its own participant on the station's DDS domain, open only while the AUV is at the
//! surface) beside its emulated acoustic modem, and a CDT on the station's domain. Tasks are
//! dispatched on the station's domain around every switch; the figures say whether any was
//! lost or run twice, and whether any state vector was lost or duplicated at the station,
//! by the definition in the docs (restated on [`FailoverReport`]).
//!
//! Self-contained on purpose (public crates only, nothing from the rest of the binary): the
//! end-to-end test `converter::failover` runs this same code with fewer cycles and asserts
//! on its report.

use std::collections::{BTreeMap, HashMap};
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use anyhow::{Context, Result, bail};
use futures::StreamExt;
use serde::Serialize;
use shoal_acoustic::driver::{ModemDriver, OutFrame, Outcome, RxFrame, TransmitError, Withdrawal};
use shoal_acoustic::emulator::{Emulator, EmulatorConfig, ModemConfig};
use shoal_acoustic::pdu::{self, Pdu};
use shoal_converter::failover::switched_to;
use shoal_converter::{
    AddressEntry, CdtConfig, IpPathConfig, Modem, ModemKind, ModemSettings, VdtConfig, run_cdt,
    run_vdt,
};
use shoal_dds::{DdsConfig, Priority, PubSub, WriterOptions};
use shoal_model::geo::LocalFrame;
use shoal_model::{
    Event, GeoPoint, LinkKind, StateVector, Task, TaskAssignment, TaskState, TaskStatus,
    VehicleKind, Warp,
};
use shoal_proxy::ProxyOptions;
use shoal_proxy::ledger::{Progress, TaskLedger};
use shoal_proxy::sim::{SimSettings, SimSpec};
use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;

const VEHICLE: &str = "auv-1";
const CDT_ADDRESS: u8 = 1;
const AUV_ADDRESS: u8 = 2;
const LAT: f64 = 43.0;
const LON: f64 = 5.0;
/// The CDT's modem, east of the AUV's start, metres.
const RANGE_M: f64 = 800.0;
/// How deep each dive goes, and how far east or west, metres.
const DIVE_DEPTH_M: f64 = 4.0;
const DIVE_LEG_M: f64 = 30.0;
/// Longest a phase (a switch, the tasks ending) may take, simulated seconds.
const PHASE_S: f64 = 300.0;
/// Wall-clock seconds the IP path must be heard before data moves there.
const UP_AFTER_WALL_S: f64 = 3.0;

/// Settings of the measurement.
#[derive(Debug, Clone, PartialEq)]
pub struct FailoverOptions {
    /// Surfacings and dives: two link switches each.
    pub cycles: u32,
    /// Wall-clock seconds per simulated second (the vehicle, the sea and the converters).
    pub time_scale: f64,
    /// The vehicle's private DDS domain.
    pub vehicle_domain: u16,
    /// The station's DDS domain (the CDT, and the VDT's IP path).
    pub station_domain: u16,
    /// Emulator seed.
    pub seed: u64,
    /// The VDT's acoustic state interval, simulated s.
    pub state_interval_s: f64,
    /// The vehicle's state rate, per simulated second.
    pub rate_hz: f64,
}

impl Default for FailoverOptions {
    fn default() -> Self {
        Self {
            cycles: 10,
            // 4× real time: at 10× a build on the other core stalls the converters for
            // a few hundred milliseconds, seconds of simulated time, and the gaps that
            // makes in the station's track are the machine's, not the switches'.
            time_scale: 0.25,
            vehicle_domain: 192,
            station_domain: 193,
            seed: 3,
            state_interval_s: 2.0,
            rate_hz: 1.0,
        }
    }
}

/// What the measurement found. **Lost** and **duplicated** state vectors, as
/// docs/acoustic.md#link-failover defines them, counted from the first state the station
/// receives to the end of the run:
///
/// - a state the vehicle published is *lost on IP* when it lies between two states the
///   station received over IP in one stay on IP (every state crosses on IP), and the
///   station never received it;
/// - it is *lost* (either link) when the station received neither it nor any newer state
///   published within `window_s` after it (two acoustic state slots: the VDT sends the
///   freshest state once a slot, and a busy channel may let the next one supersede it, by
///   design);
/// - a state the station receives is *duplicated* when it received that state before,
///   or one published after it (it would see time run backwards).
///
/// The acoustic link sends state vectors unacknowledged and newest first, by design: a
/// frame the sea loses (a collision, half duplex, the channel) is replaced by the next
/// slot's state, not sent again. A state whose window holds a state frame the VDT sent and
/// the CDT never received is counted apart, as *missed on the water*: the channel's loss,
/// which the plain acoustic link has too, not the switch's.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FailoverReport {
    /// Link switches seen at the station: to IP (the VDT's switch events over IP) and to
    /// acoustic (the CDT's).
    pub switches: u32,
    /// Of which to IP.
    pub switches_to_ip: u32,
    /// Of which to acoustic.
    pub switches_to_acoustic: u32,
    /// Switch events repeating the previous one's link (a switch the vehicle did not make).
    pub switches_out_of_turn: u32,
    /// Tasks dispatched on the station's domain.
    pub tasks: u32,
    /// Reported done at the station.
    pub tasks_done: u32,
    /// Dispatched and never reported ended at the station, or not ended in the ledger.
    pub tasks_lost: u32,
    /// Run more than once by the vehicle.
    pub tasks_run_twice: u32,
    /// Copies handed to the vehicle beyond the first (IP and acoustic both, or again
    /// after a switch), each refused by its task ledger.
    pub copies_refused: u32,
    /// Tasks the CDT sent over the water (the others crossed on IP only).
    pub tasks_sent_acoustically: u32,
    /// States the vehicle published in the measured span.
    pub states_published: u32,
    /// States the station received over IP.
    pub states_over_ip: u32,
    /// States the station received over the acoustic link (through the CDT).
    pub states_over_acoustic: u32,
    /// Lost states (either rule).
    pub states_lost: u32,
    /// Of which lost during a stay on IP.
    pub states_lost_on_ip: u32,
    /// States not covered within the window because a state frame was lost on the water
    /// in it (not counted as lost: see above).
    pub states_missed_on_water: u32,
    /// Duplicated states.
    pub states_duplicated: u32,
    /// When the first lost states were published, simulated s from the start (at most 20).
    pub lost_at_s: Vec<f64>,
    /// Lost states published within 10 s of a switch (the rest are the acoustic link's own
    /// gaps, away from any switch).
    pub lost_near_switch: u32,
    /// The window of the "lost" rule, simulated s.
    pub window_s: f64,
    /// Frames from the vehicle to the CDT lost on the water (collisions, half duplex,
    /// channel), which cost the states they carried their slot.
    pub frames_lost_on_water: u64,
    /// Longest the station waited for a state at or after one the vehicle published,
    /// simulated s (vehicle time).
    pub worst_wait_s: f64,
    /// Simulated seconds measured.
    pub simulated_s: f64,
    /// Wall-clock seconds it took.
    pub wall_s: f64,
}

/// What the observers on both domains collected.
#[derive(Debug, Default)]
struct Seen {
    /// States the vehicle published (vehicle domain): timestamps.
    published: Vec<i64>,
    /// States at the station in arrival order: (timestamp, over IP).
    received: Vec<(i64, bool)>,
    /// Switch events at the station, in arrival order.
    switches: Vec<LinkKind>,
    /// When each switch happened (vehicle time), in arrival order.
    switch_ms: Vec<i64>,
    /// Task status at the station.
    station_status: Vec<TaskStatus>,
    /// Task status on the vehicle's domain.
    vehicle_status: Vec<TaskStatus>,
    /// Task assignments handed to the vehicle, by task id.
    copies: HashMap<String, u32>,
    /// Frames with a state PDU the VDT put on air: (vehicle time, bytes).
    state_frames_sent: Vec<(i64, Vec<u8>)>,
    /// Frames the CDT's modem received from the vehicle.
    frames_received: Vec<Vec<u8>>,
}

/// A modem driver that notes what crosses it (the VDT's state frames sent, the CDT's
/// frames received), so a gap at the station can be told from a frame the sea lost.
struct Tap<D> {
    inner: D,
    seen: Shared,
    warp: Warp,
}

fn carries_state(data: &[u8]) -> bool {
    pdu::unpack_frame(data).is_ok_and(|pdus| {
        pdus.iter().any(|p| {
            matches!(
                p,
                Pdu::StateKeyframe(_) | Pdu::StateDelta(_) | Pdu::PredictedDelta(_)
            )
        })
    })
}

impl<D: ModemDriver> Tap<D> {
    fn note(&self, frame: &OutFrame) {
        if frame.dst == CDT_ADDRESS && carries_state(&frame.data) {
            lock(&self.seen)
                .state_frames_sent
                .push((self.warp.now_ms(), frame.data.clone()));
        }
    }
}

impl<D: ModemDriver> ModemDriver for Tap<D> {
    async fn transmit(&self, frame: OutFrame) -> Result<Outcome, TransmitError> {
        self.note(&frame);
        self.inner.transmit(frame).await
    }

    async fn transmit_withdrawable(
        &self,
        frame: OutFrame,
        withdrawal: Withdrawal,
    ) -> Result<Outcome, TransmitError> {
        self.note(&frame);
        self.inner.transmit_withdrawable(frame, withdrawal).await
    }

    async fn receive(&self) -> Option<RxFrame> {
        let rx = self.inner.receive().await?;
        if rx.src == AUV_ADDRESS {
            lock(&self.seen).frames_received.push(rx.data.clone());
        }
        Some(rx)
    }

    fn local_address(&self) -> Option<u8> {
        self.inner.local_address()
    }

    fn is_connected(&self) -> bool {
        self.inner.is_connected()
    }
}

type Shared = Arc<Mutex<Seen>>;

fn lock(s: &Shared) -> std::sync::MutexGuard<'_, Seen> {
    s.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

fn participant(domain: u16) -> Result<Arc<PubSub>> {
    Ok(Arc::new(
        PubSub::new(&DdsConfig {
            domain_id: domain,
            ..DdsConfig::default()
        })
        .with_context(|| format!("DDS participant on domain {domain}"))?,
    ))
}

/// Runs `collect` on every valid sample of `T` on `dds` until `stop`.
fn observe<T, F>(dds: &PubSub, stop: &CancellationToken, mut collect: F) -> Result<JoinHandle<()>>
where
    T: shoal_dds::TopicType + Send + 'static,
    F: FnMut(T, shoal_dds::SampleMeta) + Send + 'static,
{
    let mut sub = dds.subscribe::<T>()?;
    let stop = stop.clone();
    Ok(tokio::spawn(async move {
        loop {
            tokio::select! {
                () = stop.cancelled() => return,
                item = sub.next() => match item {
                    Some(Ok((v, meta))) => collect(v.into_inner(), meta),
                    Some(Err(_)) => {}
                    None => return,
                },
            }
        }
    }))
}

/// Waits until `done` holds, polling; fails after `sim_s` simulated seconds.
async fn until(
    seen: &Shared,
    time_scale: f64,
    sim_s: f64,
    what: &str,
    done: impl Fn(&Seen) -> bool,
) -> Result<()> {
    let deadline = tokio::time::Instant::now() + Duration::from_secs_f64(sim_s * time_scale);
    while !done(&lock(seen)) {
        if tokio::time::Instant::now() > deadline {
            bail!("no {what} within {sim_s:.0} simulated seconds");
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    Ok(())
}

/// The station's side of the measurement: dispatches tasks on its domain.
struct Dispatcher {
    writer: shoal_dds::Writer<TaskAssignment>,
    warp: Warp,
    seq: u64,
    ids: Vec<String>,
}

impl Dispatcher {
    async fn send(&mut self, id: String, task: &Task) -> Result<()> {
        let now = self.warp.now_ms();
        let mut t = TaskAssignment::new(&id, "m-failover", VEHICLE, now, task);
        // As a station stamps a send: a rising issue sequence and a start-by time.
        self.seq += 1;
        t.issue_seq = self.seq;
        t.expires_ms = now + 600_000;
        self.writer
            .write(t)
            .await
            .map_err(|e| anyhow::anyhow!("task {id} not written: {e}"))?;
        self.ids.push(id);
        Ok(())
    }
}

/// Runs the measurement.
pub async fn run(opts: &FailoverOptions) -> Result<FailoverReport> {
    let started = std::time::Instant::now();
    let scale = opts.time_scale;
    let warp = Warp::start_at(shoal_model::now_ms(), 1.0 / scale)
        .map_err(|e| anyhow::anyhow!("time scale: {e}"))?;
    let ledger_dir = ledger_dir()?;
    let stop = CancellationToken::new();
    let result = measure(opts, warp, &ledger_dir, &stop).await;
    stop.cancel();
    // Best effort: a temporary directory of a few kilobytes.
    let _ = std::fs::remove_dir_all(&ledger_dir);
    let mut report = result?;
    report.wall_s = started.elapsed().as_secs_f64();
    Ok(report)
}

fn ledger_dir() -> Result<PathBuf> {
    let dir = std::env::temp_dir().join(format!(
        "shoal-failover-{}-{}",
        std::process::id(),
        shoal_model::now_ms()
    ));
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    Ok(dir)
}

#[allow(clippy::too_many_lines)]
async fn measure(
    opts: &FailoverOptions,
    warp: Warp,
    ledger_dir: &std::path::Path,
    stop: &CancellationToken,
) -> Result<FailoverReport> {
    let scale = opts.time_scale;
    let here = GeoPoint {
        latitude_deg: LAT,
        longitude_deg: LON,
    };
    let cdt_at = LocalFrame::new(here).to_geo(RANGE_M, 0.0);
    let modem = |address: u8, p: GeoPoint| ModemConfig {
        address,
        name: format!("m{address}"),
        latitude_deg: p.latitude_deg,
        longitude_deg: p.longitude_deg,
        depth_m: 10.0,
        ..ModemConfig::default()
    };
    let emu = Emulator::start(
        EmulatorConfig {
            time_scale: scale,
            seed: opts.seed,
            fixed_per: Some(0.0),
            modems: vec![modem(CDT_ADDRESS, cdt_at), modem(AUV_ADDRESS, here)],
            ..EmulatorConfig::default()
        },
        stop.clone().cancelled_owned(),
    )
    .await
    .context("modem emulator")?;
    let endpoint = |a: u8| emu.modems().iter().find(|m| m.address == a).map(|m| m.at);
    let (Some(cdt_modem), Some(auv_modem)) = (endpoint(CDT_ADDRESS), endpoint(AUV_ADDRESS)) else {
        bail!("emulated modems missing");
    };
    let book = vec![AddressEntry {
        vehicle_id: VEHICLE.into(),
        address: AUV_ADDRESS,
    }];
    let at = |address| ModemSettings {
        kind: ModemKind::EvologicsAt,
        address,
        nl_delivery_reports: true,
    };

    // Observers first, so they see everything from the start.
    let seen: Shared = Arc::default();
    let vehicle_obs = participant(opts.vehicle_domain)?;
    let station = participant(opts.station_domain)?;
    let cdt_dds = participant(opts.station_domain)?;
    let cdt_participant = cdt_dds.participant_id();
    let mut observers = Vec::new();
    let s = seen.clone();
    observers.push(observe::<StateVector, _>(
        &vehicle_obs,
        stop,
        move |v, _| {
            if v.vehicle_id == VEHICLE {
                lock(&s).published.push(v.timestamp_ms);
            }
        },
    )?);
    let s = seen.clone();
    observers.push(observe::<TaskStatus, _>(
        &vehicle_obs,
        stop,
        move |v, _| {
            lock(&s).vehicle_status.push(v);
        },
    )?);
    let s = seen.clone();
    observers.push(observe::<TaskAssignment, _>(
        &vehicle_obs,
        stop,
        move |v, _| {
            *lock(&s).copies.entry(v.task_id).or_default() += 1;
        },
    )?);
    let s = seen.clone();
    let cdt_id = cdt_participant.clone();
    observers.push(observe::<StateVector, _>(
        &station,
        stop,
        move |v, meta| {
            if v.vehicle_id == VEHICLE {
                lock(&s)
                    .received
                    .push((v.timestamp_ms, meta.participant != cdt_id));
            }
        },
    )?);
    let s = seen.clone();
    observers.push(observe::<TaskStatus, _>(&station, stop, move |v, _| {
        lock(&s).station_status.push(v);
    })?);
    let s = seen.clone();
    observers.push(observe::<Event, _>(&station, stop, move |v, _| {
        if let Some(to) = switched_to(&v) {
            let mut s = lock(&s);
            s.switches.push(to);
            s.switch_ms.push(v.timestamp_ms);
        }
    })?);

    // The vehicle, its VDT (acoustic modem + IP path) and the station's CDT.
    let spec = SimSpec {
        id: VEHICLE.into(),
        kind: VehicleKind::Auv,
        latitude_deg: LAT,
        longitude_deg: LON,
        rate_hz: opts.rate_hz,
        battery_pct: 95.0,
    };
    let options = ProxyOptions {
        ledger_dir: Some(ledger_dir.to_path_buf()),
        clock: Some(warp),
        ..ProxyOptions::default()
    };
    let mut parts: Vec<JoinHandle<Result<()>>> = Vec::new();
    let sim = shoal_proxy::run_sim_on(
        spec,
        SimSettings::default(),
        options,
        participant(opts.vehicle_domain)?,
        stop.clone(),
    );
    parts.push(tokio::spawn(async move { Ok(sim.await?) }));
    let vdt = VdtConfig {
        modem: at(auv_modem),
        cdt_address: CDT_ADDRESS,
        vehicles: book.clone(),
        state_interval_s: opts.state_interval_s,
        ip: IpPathConfig {
            enabled: true,
            domain_id: opts.station_domain,
            // Discovery runs on the wall clock, which the warp does not shorten: the
            // station's readers learn the IP side's writers in wall-clock time, so the wait
            // before data moves to IP keeps its wall-clock length (3 s, as at time scale 1).
            // Warped to 0.75 s, a loaded machine moved states to IP before the station's
            // reader had learnt the writer, and lost them.
            up_after_s: IpPathConfig::default()
                .up_after_s
                .max(UP_AFTER_WALL_S / scale),
            // The measurement's domains are insecure, as every bench's but `security`.
            insecure: true,
            ..IpPathConfig::default()
        },
        time_scale: scale,
        clock: Some(warp),
        ..VdtConfig::default()
    };
    let driver = Tap {
        inner: Modem::start(&vdt.modem, scale),
        seen: seen.clone(),
        warp,
    };
    let vdt = run_vdt(vdt, participant(opts.vehicle_domain)?, driver, stop.clone());
    parts.push(tokio::spawn(async move { Ok(vdt.await?) }));
    let cdt = CdtConfig {
        modem: at(cdt_modem),
        address: CDT_ADDRESS,
        vehicles: book,
        link_status_interval_s: 5.0,
        ip_failover: true,
        time_scale: scale,
        clock: Some(warp),
        ..CdtConfig::default()
    };
    let driver = Tap {
        inner: Modem::start(&cdt.modem, scale),
        seen: seen.clone(),
        warp,
    };
    let cdt = run_cdt(cdt, cdt_dds, driver, stop.clone());
    parts.push(tokio::spawn(async move { Ok(cdt.await?) }));

    let mut station_tasks = Dispatcher {
        writer: station.writer(WriterOptions::new(Priority::Control))?,
        warp,
        // Above anything a ledger left by an earlier run could hold.
        seq: u64::try_from(shoal_model::now_ms()).unwrap_or(0) * 1000,
        ids: Vec::new(),
    };
    let frame = LocalFrame::new(here);
    for i in 0..opts.cycles {
        let n = usize::try_from(i).unwrap_or(usize::MAX);
        // The latest switch, and the (n+1)th of its kind: a false switch shows in the counts
        // without letting the dispatch run ahead of the vehicle.
        until(&seen, scale, PHASE_S, "switch to IP", |s| {
            s.switches.last() == Some(&LinkKind::Ip)
                && s.switches.iter().filter(|l| **l == LinkKind::Ip).count() > n
        })
        .await?;
        // At the surface, on IP: dive (east and west in turn), and ask for a state.
        let east = if i % 2 == 0 { DIVE_LEG_M } else { 0.0 };
        let dive = Task::GotoWaypoint {
            target: frame.to_geo(east, 0.0),
            depth_m: Some(DIVE_DEPTH_M),
            altitude_m: None,
            speed_mps: 1.5,
        };
        station_tasks.send(format!("dive-{i}"), &dive).await?;
        station_tasks
            .send(format!("state-{i}-ip"), &Task::RequestState)
            .await?;
        until(&seen, scale, PHASE_S, "switch to acoustic", |s| {
            s.switches.last() == Some(&LinkKind::Acoustic)
                && s.switches
                    .iter()
                    .filter(|l| **l == LinkKind::Acoustic)
                    .count()
                    > n
        })
        .await?;
        // Just dived: a task in the switch's wake, and the way back up.
        station_tasks
            .send(format!("state-{i}-ac"), &Task::RequestState)
            .await?;
        station_tasks
            .send(format!("surface-{i}"), &Task::Surface)
            .await?;
    }
    // Every task ended at the station, then the last states settle.
    let ids = station_tasks.ids.clone();
    until(&seen, scale, PHASE_S, "end of every task", |s| {
        ids.iter().all(|id| {
            s.station_status
                .iter()
                .any(|st| st.task_id == *id && st.state == TaskState::Done)
        })
    })
    .await
    .ok();
    let end_ms = warp.now_ms();
    let window_ms = (2.0 * opts.state_interval_s * 1000.0).round();
    #[allow(clippy::cast_possible_truncation)]
    let window = window_ms as i64;
    tokio::time::sleep(Duration::from_secs_f64((3.0 * window_ms / 1000.0) * scale)).await;
    stop.cancel();
    for p in parts {
        match p.await {
            Ok(Ok(())) => {}
            Ok(Err(e)) => return Err(e.context("a part of the measurement failed")),
            Err(e) => bail!("a part of the measurement panicked: {e}"),
        }
    }
    for o in observers {
        o.await.ok();
    }
    let frames_lost_on_water = emu
        .stats()
        .iter()
        .filter(|l| l.src == AUV_ADDRESS && l.dst == CDT_ADDRESS)
        .map(|l| l.lost + l.collisions + l.half_duplex + l.outage)
        .sum();
    drop(emu);

    let ledger = TaskLedger::open(ledger_dir, VEHICLE, None)
        .map_err(|e| anyhow::anyhow!("reading the vehicle's task ledger: {e}"))?;
    let seen = lock(&seen);
    let mut report = analyse(&seen, &ids, &ledger, end_ms, window);
    report.frames_lost_on_water = frames_lost_on_water;
    Ok(report)
}

/// The figures from what was seen (see [`FailoverReport`] for the definitions).
#[allow(clippy::cast_precision_loss)]
fn analyse(
    seen: &Seen,
    ids: &[String],
    ledger: &TaskLedger,
    end_ms: i64,
    window_ms: i64,
) -> FailoverReport {
    let count = |n: usize| u32::try_from(n).unwrap_or(u32::MAX);
    // Tasks.
    let done = |id: &str| {
        seen.station_status
            .iter()
            .any(|s| s.task_id == id && s.state == TaskState::Done)
    };
    let ended_in_ledger = |id: &str| matches!(ledger.progress(id), Some(Progress::Ended(_)));
    let runs = |id: &str| {
        seen.vehicle_status
            .iter()
            .filter(|s| {
                s.task_id == id
                    && (s.state == TaskState::Accepted
                        || (s.state == TaskState::Done && s.message == "state vector sent"))
            })
            .count()
    };
    let tasks_done = count(ids.iter().filter(|id| done(id)).count());
    let tasks_lost = count(
        ids.iter()
            .filter(|id| !done(id) || !ended_in_ledger(id))
            .count(),
    );
    let tasks_run_twice = count(ids.iter().filter(|id| runs(id) > 1).count());
    let copies_refused = ids
        .iter()
        .map(|id| seen.copies.get(id).copied().unwrap_or(0).saturating_sub(1))
        .sum();
    let tasks_sent_acoustically = count(
        ids.iter()
            .filter(|id| {
                seen.station_status
                    .iter()
                    .any(|s| s.task_id == **id && s.message == "queued on the acoustic link")
            })
            .count(),
    );

    // States, from the first the station received.
    let start = seen.received.iter().map(|r| r.0).min().unwrap_or(i64::MAX);
    let mut published: BTreeMap<i64, u32> = BTreeMap::new();
    for t in seen
        .published
        .iter()
        .filter(|t| **t >= start && **t <= end_ms)
    {
        *published.entry(*t).or_default() += 1;
    }
    let mut arrivals: BTreeMap<i64, u32> = BTreeMap::new();
    let mut newest = i64::MIN;
    let mut reordered = 0u32;
    for (t, _) in &seen.received {
        let n = arrivals.entry(*t).or_default();
        *n += 1;
        if *t < newest {
            reordered += 1;
        }
        newest = newest.max(*t);
    }
    // More copies of a timestamp than the vehicle published of it.
    let copies: u32 = arrivals
        .iter()
        .map(|(t, n)| n.saturating_sub(published.get(t).copied().unwrap_or(1)))
        .sum();
    // Stays on IP: runs of states received over IP, in vehicle time.
    let mut by_time: Vec<(i64, bool)> = seen.received.clone();
    by_time.sort_unstable();
    let mut ip_spans: Vec<(i64, i64)> = Vec::new();
    let mut open: Option<(i64, i64)> = None;
    for (t, ip) in &by_time {
        match (ip, open.as_mut()) {
            (true, Some(span)) => span.1 = *t,
            (true, None) => open = Some((*t, *t)),
            (false, _) => ip_spans.extend(open.take()),
        }
    }
    ip_spans.extend(open);
    // State frames the VDT sent that never reached the CDT: lost on the water.
    let mut received_frames: HashMap<&[u8], u32> = HashMap::new();
    for f in &seen.frames_received {
        *received_frames.entry(f.as_slice()).or_default() += 1;
    }
    let mut lost_frames: Vec<i64> = Vec::new();
    for (t, f) in &seen.state_frames_sent {
        match received_frames.get_mut(f.as_slice()) {
            Some(n) if *n > 0 => *n -= 1,
            _ => lost_frames.push(*t),
        }
    }
    let mut lost_on_ip = 0u32;
    let mut lost = 0u32;
    let mut missed_on_water = 0u32;
    let mut lost_at = Vec::new();
    let mut lost_near_switch = 0u32;
    let mut worst_wait = 0i64;
    // The link's start is no switch: a state published before the station first heard
    // the vehicle at all (announcement, keyframe, the first frames' way) is not judged.
    let first_heard = arrivals.keys().next().copied().unwrap_or(i64::MAX);
    for t in published.keys().filter(|t| **t >= first_heard) {
        let on_ip = ip_spans.iter().any(|(a, b)| a <= t && t <= b);
        let missing_on_ip = on_ip && !arrivals.contains_key(t);
        let next = arrivals.range(*t..).next().map(|(r, _)| *r);
        let covered = next.is_some_and(|r| r - t <= window_ms);
        if let Some(r) = next {
            worst_wait = worst_wait.max(r - t);
        }
        if missing_on_ip {
            lost_on_ip += 1;
        }
        let water = lost_frames.iter().any(|f| *t <= *f && *f <= t + window_ms);
        if !missing_on_ip && !covered && water {
            missed_on_water += 1;
        } else if missing_on_ip || !covered {
            lost += 1;
            if seen.switch_ms.iter().any(|w| (w - t).abs() <= 10_000) {
                lost_near_switch += 1;
            }
            if lost_at.len() < 20 {
                lost_at.push((t - start) as f64 / 1000.0);
            }
        }
    }
    let switches_to_ip = count(seen.switches.iter().filter(|l| **l == LinkKind::Ip).count());
    let switches_to_acoustic = count(seen.switches.len()) - switches_to_ip;
    let switches_out_of_turn = count(seen.switches.windows(2).filter(|w| w[0] == w[1]).count());
    FailoverReport {
        switches_out_of_turn,
        switches: count(seen.switches.len()),
        switches_to_ip,
        switches_to_acoustic,
        tasks: count(ids.len()),
        tasks_done,
        tasks_lost,
        tasks_run_twice,
        copies_refused,
        tasks_sent_acoustically,
        states_published: published.values().sum(),
        states_over_ip: count(seen.received.iter().filter(|r| r.1).count()),
        states_over_acoustic: count(seen.received.iter().filter(|r| !r.1).count()),
        states_lost: lost,
        states_lost_on_ip: lost_on_ip,
        states_missed_on_water: missed_on_water,
        lost_at_s: lost_at,
        lost_near_switch,
        states_duplicated: copies + reordered,
        window_s: window_ms as f64 / 1000.0,
        frames_lost_on_water: 0,
        worst_wait_s: worst_wait as f64 / 1000.0,
        simulated_s: (end_ms - start) as f64 / 1000.0,
        wall_s: 0.0,
    }
}

/// Prints the figures (`shoal bench acoustic`).
pub fn print(r: &FailoverReport) {
    // The target is about the switches: the acoustic link's own gaps away from them are
    // reported beside it.
    let met = r.switches_out_of_turn == 0
        && r.tasks_lost == 0
        && r.tasks_run_twice == 0
        && r.states_lost_on_ip == 0
        && r.lost_near_switch == 0
        && r.states_duplicated == 0;
    println!(
        "link failover, a surfacing/diving AUV: {} switches ({} to IP, {} to acoustic, {} out of turn) in {:.0} simulated s ({:.0} s wall) — zero lost or duplicated: {}",
        r.switches,
        r.switches_to_ip,
        r.switches_to_acoustic,
        r.switches_out_of_turn,
        r.simulated_s,
        r.wall_s,
        if met { "met" } else { "NOT met" }
    );
    println!(
        "  tasks: {} dispatched, {} done, {} lost, {} run twice; {} sent acoustically, {} extra copies refused by the ledger",
        r.tasks,
        r.tasks_done,
        r.tasks_lost,
        r.tasks_run_twice,
        r.tasks_sent_acoustically,
        r.copies_refused
    );
    println!(
        "  state vectors: {} published, received {} over IP and {} acoustically; {} lost ({} on IP, {} within 10 s of a switch), {} duplicated (window {:.0} s, worst wait {:.1} s)",
        r.states_published,
        r.states_over_ip,
        r.states_over_acoustic,
        r.states_lost,
        r.states_lost_on_ip,
        r.lost_near_switch,
        r.states_duplicated,
        r.window_s,
        r.worst_wait_s
    );
    println!(
        "  the sea's share (not the switches'): {} frames from the vehicle lost on the water, {} states missed their window with them",
        r.frames_lost_on_water, r.states_missed_on_water
    );
}
