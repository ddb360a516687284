//! The channel measurements of `shoal bench acoustic`, each on two emulated modems on
//! 127.0.0.1 with the real AT drivers and link layer, in simulated seconds.

use std::time::Duration;

use anyhow::{Context, Result, anyhow, bail};
use shoal_acoustic::channel::sound_speed_mackenzie;
use shoal_acoustic::driver::{AtDriver, DriverConfig};
use shoal_acoustic::emulator::{Emulator, EmulatorConfig, EmulatorHandle, ModemConfig};
use shoal_acoustic::link::{self, Class, LinkConfig, LinkEvent, LinkSender, Outgoing};
use shoal_acoustic::pdu::{self, CompactEvent, CompactTask, MAX_FRAME, Pdu, TaskAction};
use tokio::sync::mpsc;
use tokio::time::Instant;

use super::{BenchOptions, ChannelUse, ControlDelivery, EmergencyLatency};

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
