//! Figures for `shoal bench acoustic` (issue 3, item 8); every function returns numbers and
//! prints nothing.
//!
//! - [`pdu_sizes`]: each compact message's size against the DCCL reference State Vector
//!   (158 bits → 20 bytes) and the SWARMs paper's 51-byte ASCII payload (ACOUSTIC.md §3).
//! - [`channel_use`]: a saturated telemetry link, two emulated modems `distance_m` apart;
//!   how busy the channel is and how full its frames are.
//! - [`emergency_latency`]: an alarm injected while telemetry saturates the channel; time
//!   from queueing to arrival, against one frame time plus propagation.
//! - [`control_delivery`]: control messages at a fixed packet error rate with no modem
//!   retries, so the link layer's ack and retransmission do all the work.
//!
//! Emergency latency has two bounds. The strict one is the issue's "one frame time plus
//! propagation" (a 64-byte frame + d/c). A modem cannot abort a frame already on air (it
//! answers BUSY), so an alarm that arrives as a full telemetry frame starts must wait for
//! that frame, then needs its own (short) air time: the second bound,
//! `bound_one_frame_wait_s`, adds the alarm frame's own air time. The link sends emergency
//! frames without telemetry filler, and the driver reports an unacknowledged frame sent only
//! when it is off air, so the link never commits a second telemetry frame ahead of an alarm.
//!
//! The measurements run the real emulator, AT drivers and link layer on 127.0.0.1 with
//! `time_scale` < 1, and report **simulated** seconds (wall time divided by the scale).

use std::time::Duration;

use serde::Serialize;
use shoal_acoustic::channel::sound_speed_mackenzie;
use shoal_acoustic::driver::{AtDriver, DriverConfig};
use shoal_acoustic::emulator::{Emulator, EmulatorConfig, EmulatorHandle, ModemConfig};
use shoal_acoustic::link::{self, Class, LinkConfig, LinkEvent, LinkSender, Outgoing};
use shoal_acoustic::pdu::{self, CompactEvent, CompactTask, MAX_FRAME, Pdu, TaskAction};
use tokio::sync::mpsc;
use tokio::time::Instant;

use crate::error::ConverterError;

/// The DCCL-equivalent size of the SWARMs State Vector, bytes (§3).
pub const DCCL_REFERENCE_BYTES: usize = 20;
/// The SWARMs paper's ASCII State Vector payload, bytes (§3).
pub const SWARMS_ASCII_BYTES: usize = 51;
/// A naive 32-bit binary layout of the State Vector, bytes (§3).
pub const NAIVE_BINARY_BYTES: usize = 42;

/// One row of the size table.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SizeRow {
    /// Message (and variant).
    pub message: &'static str,
    /// Significant bits, message id included.
    pub bits: usize,
    /// Bytes on the wire.
    pub bytes: usize,
    /// Bytes as a share of the SWARMs 51-byte ASCII payload.
    pub vs_swarms_ascii: f64,
    /// How many fit in one 64-byte instant message.
    pub per_frame: usize,
    /// How many fit once the frame carries the default 64-bit authentication tag.
    pub per_frame_tagged: usize,
}

/// The PDU size table and its reference points.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SizeReport {
    /// One row per message.
    pub rows: Vec<SizeRow>,
    /// DCCL reference, bytes.
    pub dccl_reference_bytes: usize,
    /// SWARMs ASCII payload, bytes.
    pub swarms_ascii_bytes: usize,
    /// Naive binary layout, bytes.
    pub naive_binary_bytes: usize,
    /// Bytes the default (64-bit) authentication tag and its counter add per frame when
    /// security is on (`shoal_acoustic::secure::TaggedDriver`).
    pub auth_tag_bytes: Option<usize>,
}

/// The size table (pure; no I/O).
pub fn pdu_sizes() -> SizeReport {
    #[allow(clippy::cast_precision_loss)]
    let rows = pdu::size_table()
        .into_iter()
        .map(|e| SizeRow {
            message: e.message,
            bits: e.bits,
            bytes: e.bytes,
            vs_swarms_ascii: e.bytes as f64 / SWARMS_ASCII_BYTES as f64,
            per_frame: MAX_FRAME.checked_div(e.bytes).unwrap_or(0),
            per_frame_tagged: (MAX_FRAME - shoal_security::acoustic::OVERHEAD_64)
                .checked_div(e.bytes)
                .unwrap_or(0),
        })
        .collect();
    SizeReport {
        rows,
        dccl_reference_bytes: DCCL_REFERENCE_BYTES,
        swarms_ascii_bytes: SWARMS_ASCII_BYTES,
        naive_binary_bytes: NAIVE_BINARY_BYTES,
        auth_tag_bytes: Some(shoal_security::acoustic::OVERHEAD_64),
    }
}

/// Settings of the channel measurements.
#[derive(Debug, Clone, PartialEq)]
pub struct BenchOptions {
    /// Wall-clock seconds per simulated second (0.05 runs 20× faster than real time).
    pub time_scale: f64,
    /// Emulator seed.
    pub seed: u64,
    /// Distance between the two modems, metres.
    pub distance_m: f64,
    /// Simulated seconds the saturated channel is measured for.
    pub saturation_s: f64,
    /// Emergency messages injected (one measurement each).
    pub emergency_trials: u32,
    /// Control messages sent in the loss measurement.
    pub control_messages: u32,
    /// Packet error rate of the loss measurement.
    pub control_per: f64,
}

impl Default for BenchOptions {
    fn default() -> Self {
        Self {
            time_scale: 0.05,
            seed: 3,
            distance_m: 1000.0,
            saturation_s: 120.0,
            emergency_trials: 8,
            control_messages: 20,
            control_per: 0.3,
        }
    }
}

/// Channel use under saturation.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ChannelUse {
    /// Simulated seconds measured.
    pub seconds: f64,
    /// Frames received.
    pub frames: u64,
    /// PDU bytes received.
    pub payload_bytes: u64,
    /// Share of the time the channel carried a frame (air time incl. preamble / elapsed):
    /// what the MAC and the driver leave idle is the rest.
    pub busy_share: f64,
    /// PDU bytes / frame capacity: how full the link layer packs its frames.
    pub frame_fill: f64,
    /// The headline figure: `busy_share × frame_fill`, the share of air time carrying
    /// payload (goal ≥ 0.9). The modem's fixed preamble is physical-layer overhead and
    /// is reported separately in `payload_bit_share`.
    pub channel_use: f64,
    /// Strictest view: payload bit time / elapsed time (preamble counted as overhead).
    pub payload_bit_share: f64,
    /// Whether `channel_use` meets the 0.9 goal.
    pub goal_met: bool,
}

/// Emergency latency under saturating telemetry.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EmergencyLatency {
    /// Latency of each trial, simulated seconds (queueing → arrival at the receiver).
    pub latencies_s: Vec<f64>,
    /// Mean latency, s.
    pub mean_s: f64,
    /// Worst latency, s.
    pub max_s: f64,
    /// The goal: one 64-byte frame time plus propagation, s.
    pub bound_s: f64,
    /// Trials within the bound.
    pub within_bound: usize,
    /// One full frame's wait, plus the alarm frame's own air time, plus propagation, s.
    pub bound_one_frame_wait_s: f64,
    /// Trials within `bound_one_frame_wait_s`.
    pub within_one_frame_wait: usize,
}

/// Control delivery under loss.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ControlDelivery {
    /// Packet error rate applied to every packet (data and modem acks).
    pub per: f64,
    /// Messages sent.
    pub sent: u32,
    /// Acknowledged within the TTL.
    pub delivered: u32,
    /// The control TTL, simulated s.
    pub ttl_s: f64,
    /// Time until the last one was acknowledged, simulated s.
    pub all_delivered_after_s: f64,
    /// Packets the emulated channel lost during the run.
    pub packets_lost: u64,
}

/// All of `shoal bench acoustic`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AcousticBench {
    /// PDU sizes.
    pub sizes: SizeReport,
    /// Channel use under saturation.
    pub channel: ChannelUse,
    /// Emergency latency.
    pub emergency: EmergencyLatency,
    /// Control delivery at the configured PER.
    pub control: ControlDelivery,
}

/// Runs every measurement in turn.
pub async fn run(opts: &BenchOptions) -> Result<AcousticBench, ConverterError> {
    Ok(AcousticBench {
        sizes: pdu_sizes(),
        channel: channel_use(opts).await?,
        emergency: emergency_latency(opts).await?,
        control: control_delivery(opts).await?,
    })
}

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

fn check(opts: &BenchOptions) -> Result<(), ConverterError> {
    let ok = opts.time_scale.is_finite()
        && opts.time_scale > 0.0
        && opts.distance_m.is_finite()
        && opts.distance_m > 0.0
        && opts.saturation_s.is_finite()
        && opts.saturation_s > 0.0
        && (0.0..1.0).contains(&opts.control_per);
    if ok {
        Ok(())
    } else {
        Err(ConverterError::Config(format!(
            "bench options out of range: {opts:?}"
        )))
    }
}

impl Rig {
    async fn start(
        opts: &BenchOptions,
        tweak: impl FnOnce(&mut EmulatorConfig),
        link_cfg: LinkConfig,
    ) -> Result<Self, ConverterError> {
        check(opts)?;
        let m = |address: u8, east_m: f64| ModemConfig {
            address,
            name: format!("bench-{address}"),
            latitude_deg: 43.0,
            longitude_deg: 5.0 + east_m / (111_194.93 * 43f64.to_radians().cos()),
            depth_m: 20.0,
            ..ModemConfig::default()
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
        let driver = |i: usize| -> Result<AtDriver, ConverterError> {
            let ep = emu
                .modems()
                .get(i)
                .ok_or_else(|| ConverterError::Config("emulator modem missing".into()))?;
            let mut d = DriverConfig::new(ep.at).scaled(opts.time_scale);
            // Poll a busy modem every 20 ms (simulated) instead of 0.5 s: under saturation
            // the default leaves the channel idle for up to half a second per frame.
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

    async fn send(&self, class: Class, pdu: Vec<u8>) -> Result<u64, ConverterError> {
        self.tx
            .send(Outgoing {
                dst: 2,
                class,
                pdu,
                supersede_key: None,
            })
            .await
            .map_err(|_| ConverterError::LinkStopped)
    }
}

/// A 10-byte delta State Vector, the typical telemetry PDU.
fn telemetry_pdu() -> Result<Vec<u8>, ConverterError> {
    pdu::samples()
        .into_iter()
        .find(|(n, _)| *n == "state_delta")
        .and_then(|(_, p)| pdu::encode(&p).ok())
        .ok_or_else(|| ConverterError::Config("no delta sample PDU".into()))
}

/// A saturating telemetry load: a long queue that never runs dry during the run.
fn saturating_link(opts: &BenchOptions) -> LinkConfig {
    let mut cfg = LinkConfig::default();
    cfg.telemetry.max_len = 100_000;
    cfg.telemetry.ttl = Duration::from_secs_f64(opts.saturation_s * 10.0 + 600.0);
    cfg
}

async fn fill(rig: &Rig, opts: &BenchOptions, bytes: &[u8]) -> Result<(), ConverterError> {
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
pub async fn channel_use(opts: &BenchOptions) -> Result<ChannelUse, ConverterError> {
    let mut rig = Rig::start(opts, |_| {}, saturating_link(opts)).await?;
    let pdu = telemetry_pdu()?;
    fill(&rig, opts, &pdu).await?;
    // Measure from the end of the first frame to the end of the last one in the window, so
    // the start-up (connect, first frame's flight) is not counted.
    let mut first: Option<Instant> = None;
    let mut last = None;
    let (mut frames, mut bytes, mut air) = (0u64, 0u64, 0f64);
    let deadline = Instant::now() + rig.wall(opts.saturation_s + 30.0);
    while let Ok(Some(ev)) = tokio::time::timeout_at(deadline, rig.rx.recv()).await {
        if let LinkEvent::Received { frame, .. } = ev {
            let now = Instant::now();
            match first {
                None => first = Some(now),
                Some(t0) => {
                    frames += 1;
                    bytes += frame.len() as u64;
                    air += air_time_s(frame.len());
                    last = Some(now);
                    if rig.sim(now - t0) >= opts.saturation_s {
                        break;
                    }
                }
            }
        }
    }
    let seconds = match (first, last) {
        (Some(a), Some(b)) => rig.sim(b - a),
        _ => 0.0,
    };
    let d = EmulatorConfig::default();
    #[allow(clippy::cast_precision_loss)]
    let (frame_fill, payload_bit_s) = (
        if frames == 0 {
            0.0
        } else {
            bytes as f64 / (frames as f64 * MAX_FRAME as f64)
        },
        bytes as f64 * 8.0 / d.im_bit_rate,
    );
    let ratio = |x: f64| if seconds > 0.0 { x / seconds } else { 0.0 };
    let busy_share = ratio(air).min(1.0);
    let channel_use = busy_share * frame_fill;
    Ok(ChannelUse {
        seconds,
        frames,
        payload_bytes: bytes,
        busy_share,
        frame_fill,
        channel_use,
        payload_bit_share: ratio(payload_bit_s).min(1.0),
        goal_met: channel_use >= 0.9,
    })
}

/// Size of the alarm PDU the latency trials send.
fn telemetry_alarm_len() -> Result<usize, ConverterError> {
    pdu::encode(&Pdu::Event(CompactEvent {
        vehicle: Some(1),
        event_no: 0,
        severity: 3,
        kind: 3,
        task_no: None,
        seconds_of_day: 0,
    }))
    .map(|b| b.len())
    .map_err(|e| ConverterError::Config(e.to_string()))
}

/// Latency of emergency messages while telemetry saturates the channel.
pub async fn emergency_latency(opts: &BenchOptions) -> Result<EmergencyLatency, ConverterError> {
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
        .map_err(|e| ConverterError::Config(e.to_string()))?;
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
                Ok(None) => return Err(ConverterError::LinkStopped),
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
pub async fn control_delivery(opts: &BenchOptions) -> Result<ControlDelivery, ConverterError> {
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
        let bytes = pdu::encode(&task).map_err(|e| ConverterError::Config(e.to_string()))?;
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
