//! A captured vehicle's acoustic key must not let it speak for another vehicle: the CDT
//! binds every PDU to the modem whose key opened the frame, or to the vehicles a
//! configured relay carries. Frames are sealed with real keys and opened by the CDT's
//! `TaggedDriver`; the modem underneath is scripted, since the question is what the CDT
//! does with an authentic frame, not how it crossed the water. Domain 111.

use std::time::Duration;

use futures::StreamExt;
use shoal_acoustic::pdu::{Pdu, StateKeyframe};
use shoal_acoustic::secure::TaggedDriver;
use shoal_converter::{AddressEntry, CdtConfig, RelayEntry, run_cdt};
use shoal_model::{Event, EventKind, Severity, StateVector};
use shoal_security::{AcousticKey, AcousticTagger, TagSize};
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;

use super::common::*;

const AUV_1: u8 = 2;
const AUV_2: u8 = 3;
const USV_1: u8 = 4;
/// The latitude every forged state carries, so the test can tell it from the real ones.
const FORGED_LAT: f64 = 10.0;

fn keyframe(vehicle: u8, seq: u8, latitude_deg: f64) -> Pdu {
    Pdu::StateKeyframe(StateKeyframe {
        vehicle,
        seq,
        seconds_of_day: u32::try_from(shoal_model::now_ms() / 1000 % 86_400).unwrap(),
        latitude_deg,
        longitude_deg: LON,
        depth_m: 20.0,
        altitude_m: None,
        speed_mps: 1.5,
        yaw_deg: 90.0,
        pitch_deg: 0.0,
        roll_deg: 0.0,
        battery_pct: 80.0,
    })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_vehicle_key_speaks_only_for_its_vehicle_and_a_relay_only_for_what_it_carries() {
    let keys: Vec<AcousticKey> = (0..3).map(|_| AcousticKey::generate().unwrap()).collect();
    let mut cdt_tagger = AcousticTagger::new(CDT, TagSize::Bits64, 1);
    for (addr, key) in [AUV_1, AUV_2, USV_1].into_iter().zip(&keys) {
        cdt_tagger.set_key(addr, key);
    }
    let (push, rx) = mpsc::channel(16);
    let driver = TaggedDriver::new(ScriptedModem::new(rx), cdt_tagger);
    let entry = |id: &str, address| AddressEntry {
        vehicle_id: id.into(),
        address,
    };
    let cfg = CdtConfig {
        address: CDT,
        vehicles: vec![
            entry("auv-1", AUV_1),
            entry("auv-2", AUV_2),
            entry("usv-1", USV_1),
        ],
        relays: vec![RelayEntry {
            relay: "usv-1".into(),
            carries: vec!["auv-2".into()],
        }],
        time_scale: SCALE,
        ..CdtConfig::default()
    };

    let station = participant(111);
    let mut states = station.subscribe::<StateVector>().unwrap();
    let mut events = station.subscribe::<Event>().unwrap();
    let shutdown = CancellationToken::new();
    let cdt = tokio::spawn(run_cdt(cfg, participant(111), driver, shutdown.clone()));

    let mut auv_1 = Sender::new(AUV_1, &keys[0]);
    let mut usv_1 = Sender::new(USV_1, &keys[2]);
    // Forged first: the CDT handles frames in order, so once a later real state has
    // arrived the forgery before it has been judged. Retried until the station's reader
    // has matched the CDT's writer.
    let real = within(30, "auv-1's own state", async {
        let mut seq = 0;
        loop {
            seq = (seq + 1) % 16;
            // (sent by auv-1's modem?, PDU)
            let script = [
                (true, keyframe(AUV_2, seq, FORGED_LAT)), // auv-1's key speaking for auv-2
                (true, keyframe(AUV_1, seq, LAT)),
                (false, keyframe(AUV_1, seq, FORGED_LAT)), // usv-1 does not carry auv-1
                (false, keyframe(AUV_2, seq, LAT + 0.001)),
                (false, keyframe(USV_1, seq, LAT + 0.002)),
            ];
            for (from_auv_1, p) in script {
                let sender = if from_auv_1 { &mut auv_1 } else { &mut usv_1 };
                push.send(sender.frame(&p)).await.unwrap();
            }
            let got = tokio::time::timeout(Duration::from_secs(2), async {
                let mut seen = Vec::new();
                while let Some(Ok((s, _))) = states.next().await {
                    let s = s.into_inner();
                    let last = s.vehicle_id == "usv-1";
                    seen.push(s);
                    if last {
                        return seen;
                    }
                }
                seen
            })
            .await;
            if let Ok(seen) = got
                && !seen.is_empty()
            {
                return seen;
            }
        }
    })
    .await;

    assert!(
        real.iter()
            .all(|s| (s.latitude_deg - FORGED_LAT).abs() > 1.0),
        "a forged state reached the station: {real:?}"
    );
    let ids: Vec<&str> = real.iter().map(|s| s.vehicle_id.as_str()).collect();
    assert!(ids.contains(&"auv-1"), "auv-1's own state missing: {ids:?}");
    assert!(
        ids.contains(&"auv-2"),
        "the relay's state for auv-2 missing: {ids:?}"
    );

    // Each offending sender raised one alarm, naming itself, however often it tried.
    let mut alarms = Vec::new();
    while let Ok(Some(Ok((e, _)))) =
        tokio::time::timeout(Duration::from_secs(2), events.next()).await
    {
        let e = e.into_inner();
        if e.kind == EventKind::DataRejected {
            alarms.push(e);
        }
    }
    let mut senders: Vec<&str> = alarms.iter().map(|e| e.vehicle_id.as_str()).collect();
    senders.sort_unstable();
    assert_eq!(senders, ["auv-1", "usv-1"], "{alarms:#?}");
    assert!(alarms.iter().all(|e| e.severity == Severity::Alarm));
    let auv_1_alarm = alarms.iter().find(|e| e.vehicle_id == "auv-1").unwrap();
    assert!(
        auv_1_alarm.text.contains("spoke for auv-2"),
        "{}",
        auv_1_alarm.text
    );

    shutdown.cancel();
    cdt.await.unwrap().unwrap();
}
