//! The three-hop relay measurement of `shoal bench acoustic`
//! (docs/acoustic.md#multi-hop-relays): AUV → AUV → USV → station on four emulated modems
//! in a line, each in range of its neighbours only, every packet (data and modem acks)
//! lost at a fixed rate per hop, no modem-level retries, frames tagged end to end and every
//! envelope sealed hop by hop with the neighbours' link keys. Control
//! messages go up from the far AUV, then down from the station over the route it learned;
//! each is timed from queueing at the origin to arrival at the destination's link.

use std::collections::HashMap;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use serde::Serialize;
use shoal_acoustic::driver::{AtDriver, DriverConfig};
use shoal_acoustic::emulator::{Emulator, EmulatorConfig, EmulatorHandle};
use shoal_acoustic::link::{self, Class, LinkConfig, LinkEvent, LinkSender, Outgoing};
use shoal_acoustic::pdu::{self, CompactEvent, Pdu};
use shoal_acoustic::relay::{RelayConfig, RelayDriver, RelayStats, RelayStatsHandle, Route};
use shoal_acoustic::secure::TaggedDriver;
use shoal_security::{AcousticKey, AcousticTagger, RejectionCounts, TagSize};
use tokio::sync::mpsc;
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;

use super::BenchOptions;

const STATION: u8 = 1;
const USV: u8 = 2;
const NEAR: u8 = 3;
const FAR: u8 = 4;
/// Neighbours 1.5 km apart, range 2.25 km: only the chain reaches end to end.
const SPACING_M: f64 = 1500.0;
/// The loss per hop.
const PER: f64 = 0.1;
/// Neighbours sharing a link key for the hop seals: each pair along the chain.
const LINKS: [(u8, u8); 3] = [(FAR, NEAR), (NEAR, USV), (USV, STATION)];

/// Messages each way, and the simulated seconds between two.
const MESSAGES: u8 = 30;
const INTERVAL_S: f64 = 8.0;

/// One direction of the measurement.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RelayDirection {
    /// Messages queued at the origin.
    pub sent: u32,
    /// Arrived at the destination within the control TTL.
    pub delivered_within_ttl: u32,
    /// Latency of each delivered message, simulated s (queueing → arrival).
    pub latencies_s: Vec<f64>,
    /// Median latency, s.
    pub median_s: f64,
    /// 90th percentile, s.
    pub p90_s: f64,
    /// Worst, s.
    pub max_s: f64,
}

/// The three-hop figures.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RelayReport {
    /// Packet error rate on every hop (data and acks).
    pub per_hop_per: f64,
    /// Hops between the far AUV and the station, as the station learned them.
    pub hops: u8,
    /// The control TTL, simulated s.
    pub ttl_s: f64,
    /// Far AUV → station.
    pub up: RelayDirection,
    /// Station → far AUV, over the learned route.
    pub down: RelayDirection,
    /// The near AUV's relay counters.
    pub near: RelayStats,
    /// The USV's relay counters.
    pub usv: RelayStats,
    /// Frames that went directly between the far AUV and the station (must be 0).
    pub direct_frames: u64,
    /// Packets the channel lost (PER draws and collisions).
    pub packets_lost: u64,
    /// Frames refused by their end-to-end tag at the station and the far AUV.
    pub tag_refusals: u64,
    /// Envelopes refused by their hop seal at any of the four nodes.
    pub hop_refusals: u64,
    /// Whether every message arrived within the TTL both ways (the goal).
    pub goal_met: bool,
}

type Refused = std::sync::Arc<std::sync::Mutex<RejectionCounts>>;

struct Node {
    link: LinkSender,
    rx: mpsc::Receiver<LinkEvent>,
    relay: RelayStatsHandle,
    refused: Refused,
}

struct Chain {
    emu: EmulatorHandle,
    stop: CancellationToken,
}

impl Drop for Chain {
    fn drop(&mut self) {
        self.stop.cancel();
        self.emu.shutdown();
    }
}

impl Chain {
    /// A tagged, relaying link on `address`; `key_of` is the vehicle whose key each of
    /// `peers` shares with it.
    fn node(&self, address: u8, peers: &[u8], relay: RelayConfig, scale: f64) -> Result<Node> {
        let ep = self
            .emu
            .modems()
            .iter()
            .find(|m| m.address == address)
            .context("emulator modem missing")?;
        let modem = AtDriver::start(DriverConfig::new(ep.at).scaled(scale));
        // Link keys with its neighbours in the chain, for the hop seals.
        let mut hop = AcousticTagger::for_relay_hops(address, TagSize::Bits64, 1);
        for (a, b) in LINKS {
            let link_key = AcousticKey::from_bytes([0x80 | (a << 4) | b; 32]);
            if a == address {
                hop.set_key(b, &link_key);
            } else if b == address {
                hop.set_key(a, &link_key);
            }
        }
        let relayed = RelayDriver::start_keyed(modem, relay, scale, hop)?;
        let stats = relayed.stats_handle();
        let mut tagger = AcousticTagger::new(address, TagSize::Bits64, 1);
        for &p in peers {
            // Station ↔ vehicle frames use the vehicle's key; relays hold none of others'.
            let vehicle = if address == STATION { p } else { address };
            tagger.set_key(p, &AcousticKey::from_bytes([vehicle; 32]));
        }
        let driver = TaggedDriver::new(relayed, tagger);
        let refused = driver.refused();
        let event_bytes = event(0, 0)?.len();
        let cfg = LinkConfig {
            // One message per frame, so each faces the loss on every hop on its own.
            max_frame: event_bytes,
            ..LinkConfig::default()
        };
        let (link, rx) = link::start(
            driver,
            cfg.scaled(scale),
            self.stop.clone().cancelled_owned(),
        );
        Ok(Node {
            link,
            rx,
            relay: stats,
            refused,
        })
    }
}

fn event(vehicle: u8, n: u8) -> Result<Vec<u8>> {
    pdu::encode(&Pdu::Event(CompactEvent {
        vehicle: Some(vehicle),
        event_no: n,
        severity: 1,
        kind: 0,
        task_no: None,
        seconds_of_day: 43_200,
    }))
    .context("event PDU")
}

/// Sends `MESSAGES` events from `from` (as `vehicle`) to `dst`, one every `INTERVAL_S`,
/// and times their arrival at `to`.
async fn one_way(
    from: &LinkSender,
    to: &mut mpsc::Receiver<LinkEvent>,
    dst: u8,
    origin: u8,
    ttl: Duration,
    scale: f64,
) -> Result<RelayDirection> {
    let wall = move |s: f64| Duration::from_secs_f64(s * scale);
    let sender = from.clone();
    let sending = tokio::spawn(async move {
        let mut sent = Vec::new();
        for n in 0..MESSAGES {
            let pdu = event(origin, n)?;
            sent.push(Instant::now());
            sender
                .send(Outgoing {
                    dst,
                    class: Class::Control,
                    pdu,
                    supersede_key: None,
                })
                .await
                .context("acoustic link stopped")?;
            tokio::time::sleep(wall(INTERVAL_S)).await;
        }
        anyhow::Ok(sent)
    });
    let start = Instant::now();
    let deadline = start + wall(f64::from(MESSAGES) * INTERVAL_S) + ttl;
    let mut arrived: HashMap<u8, Instant> = HashMap::new();
    while arrived.len() < usize::from(MESSAGES) {
        let Ok(Some(ev)) = tokio::time::timeout_at(deadline, to.recv()).await else {
            break;
        };
        if let LinkEvent::Received { src, frame, .. } = ev
            && src == origin
            && let Ok(pdus) = pdu::unpack_frame(&frame)
        {
            for p in pdus {
                if let Pdu::Event(e) = p {
                    arrived.entry(e.event_no).or_insert_with(Instant::now);
                }
            }
        }
    }
    let sent = sending.await.context("sender task")??;
    let mut latencies: Vec<f64> = sent
        .iter()
        .zip(0u8..)
        .filter_map(|(t, n)| arrived.get(&n).map(|a| a.duration_since(*t)))
        .filter(|d| *d <= ttl)
        .map(|d| d.as_secs_f64() / scale)
        .collect();
    latencies.sort_by(f64::total_cmp);
    let pick = |q: f64| -> f64 {
        #[allow(
            clippy::cast_possible_truncation,
            clippy::cast_sign_loss,
            clippy::cast_precision_loss
        )]
        let i = ((latencies.len() as f64 - 1.0) * q).round().max(0.0) as usize;
        latencies.get(i).copied().unwrap_or(f64::NAN)
    };
    Ok(RelayDirection {
        sent: u32::from(MESSAGES),
        delivered_within_ttl: u32::try_from(latencies.len()).unwrap_or(u32::MAX),
        median_s: pick(0.5),
        p90_s: pick(0.9),
        max_s: latencies.last().copied().unwrap_or(f64::NAN),
        latencies_s: latencies,
    })
}

/// Runs the three-hop measurement at `opts.time_scale` with `opts.seed`.
pub(super) async fn three_hop(opts: &BenchOptions) -> Result<RelayReport> {
    let scale = opts.time_scale;
    if !(scale.is_finite() && scale > 0.0) {
        bail!("time_scale out of range: {scale}");
    }
    let mut cfg = EmulatorConfig::relay_chain(
        &[
            (STATION, "station"),
            (USV, "usv"),
            (NEAR, "auv-near"),
            (FAR, "auv-far"),
        ],
        43.0,
        5.0,
        SPACING_M,
    );
    cfg.time_scale = scale;
    cfg.seed = opts.seed;
    cfg.fixed_per = Some(PER);
    // No modem-level retries: the relays' and the link's retransmissions do the work.
    cfg.im_retries = 0;
    let emu = Emulator::start(cfg, std::future::pending()).await?;
    let chain = Chain {
        emu,
        stop: CancellationToken::new(),
    };
    let relay = |routes: Vec<Route>, forward: bool| RelayConfig {
        forward,
        routes,
        ..RelayConfig::default()
    };
    let to_station = |via| vec![Route { dst: STATION, via }];
    let mut station = chain.node(STATION, &[FAR], relay(Vec::new(), false), scale)?;
    // The USV hears the station directly; the AUVs know by configuration which way the
    // station is, and everyone learns the way down from what comes up.
    let usv = chain.node(USV, &[], relay(Vec::new(), true), scale)?;
    let near = chain.node(NEAR, &[], relay(to_station(USV), true), scale)?;
    let mut far = chain.node(FAR, &[STATION], relay(to_station(NEAR), false), scale)?;
    let ttl = LinkConfig::default().control.ttl;
    let ttl_wall = Duration::from_secs_f64(ttl.as_secs_f64() * scale);

    let up = one_way(&far.link, &mut station.rx, STATION, FAR, ttl_wall, scale).await?;
    let hops = station
        .relay
        .learned_routes()
        .iter()
        .find(|r| r.dst == FAR)
        .map_or(0, |r| r.hops);
    let down = one_way(&station.link, &mut far.rx, FAR, STATION, ttl_wall, scale).await?;

    let stats = chain.emu.stats();
    let direct_frames = stats
        .iter()
        .filter(|l| (l.src, l.dst) == (FAR, STATION) || (l.src, l.dst) == (STATION, FAR))
        .map(|l| l.frames)
        .sum();
    let packets_lost = stats
        .iter()
        .map(|l| l.lost + l.collisions + l.half_duplex)
        .sum();
    let refusals = |r: &Refused| r.lock().map_or(0, |c| c.total());
    let tag_refusals = refusals(&station.refused) + refusals(&far.refused);
    let hop_refusals = [&station, &usv, &near, &far]
        .iter()
        .map(|n| n.relay.stats().unauthenticated)
        .sum();
    let goal_met = up.delivered_within_ttl == up.sent && down.delivered_within_ttl == down.sent;
    Ok(RelayReport {
        per_hop_per: PER,
        hops,
        ttl_s: ttl.as_secs_f64(),
        up,
        down,
        near: near.relay.stats(),
        usv: usv.relay.stats(),
        direct_frames,
        packets_lost,
        tag_refusals,
        hop_refusals,
        goal_met,
    })
}

/// The relay lines of the report.
pub(super) fn print(r: &RelayReport) {
    println!(
        "three-hop relay (AUV -> AUV -> USV -> station, {} hops learned, {:.0}% PER per hop, no modem retries, tags end to end, hop seals):",
        r.hops,
        r.per_hop_per * 100.0
    );
    for (name, d) in [
        ("up (far AUV -> station)", &r.up),
        ("down (station -> far AUV)", &r.down),
    ] {
        println!(
            "  {name:<26} {}/{} within the {:.0} s TTL; latency median {:.1} s, p90 {:.1} s, max {:.1} s",
            d.delivered_within_ttl, d.sent, r.ttl_s, d.median_s, d.p90_s, d.max_s
        );
    }
    for (name, s) in [("near AUV", &r.near), ("USV", &r.usv)] {
        println!(
            "  {name:<9} forwarded {}, duplicates {}, loops {}, ttl expired {}, forged routes {}, malformed {}, unauthenticated {}, undeliverable {}",
            s.forwarded,
            s.duplicates,
            s.loops,
            s.ttl_expired,
            s.forged_route,
            s.malformed,
            s.unauthenticated,
            s.undeliverable
        );
    }
    println!(
        "  direct frames between the ends {}, packets lost {}, tag refusals {}, hop seal refusals {}; 100 % within TTL: {}",
        r.direct_frames,
        r.packets_lost,
        r.tag_refusals,
        r.hop_refusals,
        if r.goal_met { "met" } else { "NOT met" }
    );
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    /// The target: every control message over three hops at 10 % PER per hop
    /// within the TTL, both ways, and nothing directly between the ends.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn three_hops_at_10_percent_per_deliver_every_control_message_within_the_ttl() {
        let r = three_hop(&BenchOptions::default()).await.unwrap();
        eprintln!("{}", serde_json::to_string_pretty(&r).unwrap());
        assert_eq!(r.hops, 3, "{r:?}");
        assert!(r.goal_met, "{r:?}");
        assert_eq!(r.direct_frames, 0);
        assert_eq!(r.tag_refusals, 0);
        // Every hop sealed, none refused: retransmissions are sealed afresh.
        assert_eq!(r.hop_refusals, 0, "{r:?}");
        assert!(r.packets_lost > 0, "10 % PER should lose packets");
        assert!(r.near.forwarded >= u64::from(MESSAGES) * 2, "{:?}", r.near);
    }
}
