//! Multi-hop relays over the emulator (docs/acoustic.md#multi-hop-relays): three modems
//! on a line, each in range of its neighbours only, tagged end to end.

use std::collections::BTreeSet;
use std::time::Duration;

use shoal_acoustic::driver::{AtDriver, DriverConfig, ModemDriver, OutFrame};
use shoal_acoustic::emulator::{Emulator, EmulatorConfig, EmulatorHandle};
use shoal_acoustic::link::{self, Class, LinkConfig, LinkEvent, LinkSender, Outgoing};
use shoal_acoustic::pdu::{self, CompactEvent, MAX_FRAME, Pdu};
use shoal_acoustic::relay::{Envelope, HEADER_BYTES, RelayConfig, RelayDriver, Route};
use shoal_acoustic::secure::TaggedDriver;
use shoal_security::{AcousticKey, AcousticTagger, TagSize};
use tokio::sync::mpsc;

const SCALE: f64 = 0.01;
const STATION: u8 = 1;
const NEAR: u8 = 2;
const FAR: u8 = 3;

fn key(of: u8) -> AcousticKey {
    AcousticKey::from_bytes([of; 32])
}

/// The station, the near AUV 1.5 km east and the far AUV 3 km east: the far AUV is out
/// of the station's range (2.25 km), the near one hears both.
async fn chain() -> EmulatorHandle {
    let mut cfg = EmulatorConfig::relay_chain(
        &[(STATION, "station"), (NEAR, "auv-near"), (FAR, "auv-far")],
        43.0,
        5.0,
        1500.0,
    );
    cfg.time_scale = SCALE;
    cfg.fixed_per = Some(0.0);
    Emulator::start(cfg, std::future::pending()).await.unwrap()
}

/// A tagged, relaying link on the modem at `address`; `peers` are the nodes it shares a
/// key with (a vehicle: the station only).
fn node(
    emu: &EmulatorHandle,
    address: u8,
    peers: &[u8],
    relay: RelayConfig,
    control_ttl_s: u64,
) -> (LinkSender, mpsc::Receiver<LinkEvent>, Refused) {
    let ep = emu.modems().iter().find(|m| m.address == address).unwrap();
    let modem = AtDriver::start(DriverConfig::new(ep.at).scaled(SCALE));
    let relayed = RelayDriver::start(modem, relay, SCALE).unwrap();
    let mut tagger = AcousticTagger::new(address, TagSize::Bits64, 100);
    for &p in peers {
        // A frame between the station and a vehicle uses that vehicle's key.
        tagger.set_key(p, &key(if address == STATION { p } else { address }));
    }
    let driver = TaggedDriver::new(relayed, tagger);
    let mut cfg = LinkConfig::default();
    cfg.control.ttl = Duration::from_secs(control_ttl_s);
    // Room for the tag and, on a relayed path, the envelope.
    cfg.max_frame = driver.frame_budget(MAX_FRAME - HEADER_BYTES);
    let refused = driver.refused();
    let (tx, rx) = link::start(driver, cfg.scaled(SCALE), std::future::pending());
    (tx, rx, refused)
}

type Refused = std::sync::Arc<std::sync::Mutex<shoal_security::RejectionCounts>>;

fn event(vehicle: u8, n: u8) -> Vec<u8> {
    pdu::encode(&Pdu::Event(CompactEvent {
        vehicle: Some(vehicle),
        event_no: n,
        severity: 1,
        kind: 0,
        task_no: None,
        seconds_of_day: 43_200,
    }))
    .unwrap()
}

async fn send(link: &LinkSender, dst: u8, pdu: Vec<u8>) {
    link.send(Outgoing {
        dst,
        class: Class::Control,
        pdu,
        supersede_key: None,
    })
    .await
    .unwrap();
}

/// Event numbers received from `src` until `want` have come, or `wait` passes.
async fn events_from(
    rx: &mut mpsc::Receiver<LinkEvent>,
    src: u8,
    want: usize,
    wait: Duration,
) -> BTreeSet<u8> {
    let mut got = BTreeSet::new();
    let deadline = tokio::time::Instant::now() + wait;
    while got.len() < want {
        let Ok(Some(ev)) = tokio::time::timeout_at(deadline, rx.recv()).await else {
            break;
        };
        if let LinkEvent::Received { src: s, frame, .. } = ev
            && s == src
        {
            for p in pdu::unpack_frame(&frame).unwrap() {
                if let Pdu::Event(e) = p {
                    got.insert(e.event_no);
                }
            }
        }
    }
    got
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_chain_delivers_both_ways_and_a_relay_cannot_forge_for_the_far_vehicle() {
    let emu = chain().await;
    let (station, mut station_rx, station_refused) =
        node(&emu, STATION, &[NEAR, FAR], RelayConfig::default(), 900);
    let near_relay = RelayConfig {
        forward: true,
        ..RelayConfig::default()
    };
    let ep = emu.modems().iter().find(|m| m.address == NEAR).unwrap();
    let near = RelayDriver::start(
        AtDriver::start(DriverConfig::new(ep.at).scaled(SCALE)),
        near_relay,
        SCALE,
    )
    .unwrap();
    let near_stats = near.stats_handle();
    // The near AUV's own traffic is not the point: it only relays here.
    let _near_link = link::start(
        near,
        LinkConfig::default().scaled(SCALE),
        std::future::pending(),
    );
    // The far AUV knows by configuration that the station is behind the near one.
    let far_relay = RelayConfig {
        routes: vec![Route {
            dst: STATION,
            via: NEAR,
        }],
        ..RelayConfig::default()
    };
    let (far, mut far_rx, _) = node(&emu, FAR, &[STATION], far_relay, 900);

    for n in 0..6 {
        send(&far, STATION, event(FAR, n)).await;
    }
    let up = events_from(&mut station_rx, FAR, 6, Duration::from_secs(30)).await;
    assert_eq!(
        up,
        (0..6).collect(),
        "every control message crossed both hops"
    );

    // The station learned the way back from what it heard: via the near AUV.
    send(&station, FAR, event(STATION, 42)).await;
    let down = events_from(&mut far_rx, STATION, 1, Duration::from_secs(30)).await;
    assert_eq!(down, BTreeSet::from([42]));
    let s = near_stats.stats();
    // The far AUV's link packs its messages into frames: at least one frame each way.
    assert!(s.forwarded >= 2 && s.undeliverable == 0, "{s:?}");
    assert!(
        near_stats
            .learned_routes()
            .iter()
            .any(|r| r.dst == FAR && r.via == FAR)
    );
    let direct = emu
        .stats()
        .into_iter()
        .filter(|l| (l.src, l.dst) == (FAR, STATION) || (l.src, l.dst) == (STATION, FAR))
        .map(|l| l.frames)
        .sum::<u64>();
    assert_eq!(direct, 0, "nothing went directly between the ends");

    // The relay tries to speak for the far AUV: it has no key for it, so its envelope
    // (sealed with its own key) fails the far AUV's tag at the station.
    let mut own = AcousticTagger::new(NEAR, TagSize::Bits64, 10_000);
    own.set_key(STATION, &key(NEAR));
    let forged = Envelope {
        origin: FAR,
        dst: STATION,
        hops: 1,
        ttl: 1,
        ack: false,
        msg_id: 7,
        inner: own.seal(STATION, &event(FAR, 99)).unwrap(),
    };
    let raw = AtDriver::start(DriverConfig::new(ep.at).scaled(SCALE));
    raw.transmit(OutFrame {
        dst: STATION,
        data: forged.encode().unwrap(),
        ack: false,
        burst: false,
    })
    .await
    .unwrap();
    let after = events_from(&mut station_rx, FAR, 1, Duration::from_millis(500)).await;
    assert!(after.is_empty(), "a forged frame came up: {after:?}");
    assert_eq!(
        station_refused.lock().unwrap().total(),
        1,
        "refused by its tag"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn without_a_relay_the_far_vehicle_does_not_reach_the_station() {
    let emu = chain().await;
    let (_station, mut station_rx, _) = node(&emu, STATION, &[FAR], RelayConfig::default(), 900);
    // The near AUV is there but does not forward; the far one has no route.
    let ep = emu.modems().iter().find(|m| m.address == NEAR).unwrap();
    let near = RelayDriver::start(
        AtDriver::start(DriverConfig::new(ep.at).scaled(SCALE)),
        RelayConfig::default(),
        SCALE,
    )
    .unwrap();
    let _near_link = link::start(
        near,
        LinkConfig::default().scaled(SCALE),
        std::future::pending(),
    );
    let (far, mut far_events, _) = node(&emu, FAR, &[STATION], RelayConfig::default(), 30);
    send(&far, STATION, event(FAR, 1)).await;
    // Sent directly, out of range: never acknowledged, expired after its TTL.
    let expired = tokio::time::timeout(Duration::from_secs(10), async {
        while let Some(ev) = far_events.recv().await {
            if matches!(ev, LinkEvent::Expired(_)) {
                return true;
            }
        }
        false
    })
    .await
    .unwrap();
    assert!(expired);
    let got = events_from(&mut station_rx, FAR, 1, Duration::from_millis(200)).await;
    assert!(got.is_empty());
    let heard = emu
        .stats()
        .into_iter()
        .filter(|l| l.dst == STATION)
        .map(|l| l.delivered)
        .sum::<u64>();
    assert_eq!(heard, 0, "the station heard nothing at all");
}
