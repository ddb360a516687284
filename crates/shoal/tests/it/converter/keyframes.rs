//! A CDT that lacks the keyframe a delta names (it restarted) asks the vehicle's VDT for a
//! keyframe instead of dropping deltas until the VDT's periodic refresh. The modem is
//! scripted, as in `impersonation`: what matters is what the CDT sends back. Domain 112.

use std::time::Duration;

use shoal_acoustic::pdu::{self, Ack, Pdu, PredictedDelta, StateKeyframe};
use shoal_converter::{AddressEntry, CdtConfig, run_cdt};
use tokio::sync::mpsc;
use tokio_util::sync::CancellationToken;

use super::common::*;

fn predicted_delta(seq: u8) -> Pdu {
    Pdu::PredictedDelta(PredictedDelta {
        vehicle: AUV,
        keyframe_seq: seq,
        dt_s: 4,
        lat_steps: 1,
        lon_steps: -1,
        depth_steps: 0,
        altitude_steps: None,
        speed_steps: 0,
        yaw_steps: 0,
        pitch_steps: 0,
        roll_steps: 0,
        battery_steps: 0,
    })
}

/// The acknowledgements the CDT sent to the AUV, decoded.
fn acks_to_auv(modem_sent: &[shoal_acoustic::driver::OutFrame]) -> Vec<Ack> {
    modem_sent
        .iter()
        .filter(|f| f.dst == AUV)
        .flat_map(|f| pdu::unpack_frame(&f.data).unwrap())
        .filter_map(|p| match p {
            Pdu::Ack(a) => Some(a),
            _ => None,
        })
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_cdt_lacking_the_keyframe_a_delta_names_asks_for_one_once() {
    let (push, rx) = mpsc::channel(16);
    let modem = ScriptedModem::new(rx);
    let sent = modem.sent.clone();
    let cfg = CdtConfig {
        address: CDT,
        vehicles: vec![AddressEntry {
            vehicle_id: "auv-1".into(),
            address: AUV,
        }],
        time_scale: SCALE,
        ..CdtConfig::default()
    };
    let shutdown = CancellationToken::new();
    let cdt = tokio::spawn(run_cdt(cfg, participant(112), modem, shutdown.clone()));
    let frame = |p: &Pdu| shoal_acoustic::driver::RxFrame {
        src: AUV,
        dst: CDT,
        data: pdu::pack_frame(std::slice::from_ref(p)).unwrap(),
        rssi: None,
        integrity: None,
    };

    // Two deltas against keyframe 5, which this (fresh) CDT never saw: one report.
    push.send(frame(&predicted_delta(5))).await.unwrap();
    push.send(frame(&predicted_delta(5))).await.unwrap();
    let reports = within(10, "the report of the missing keyframe", async {
        loop {
            let acks = acks_to_auv(&sent.lock().unwrap());
            if !acks.is_empty() {
                return acks;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await;
    assert_eq!(
        reports,
        [Ack {
            from: CDT,
            msg_id: pdu::id::STATE_DELTA,
            ref_no: 5
        }]
    );

    // A keyframe is still acknowledged as ever; nothing else is sent.
    let key = StateKeyframe {
        vehicle: AUV,
        seq: 6,
        seconds_of_day: u32::try_from(shoal_model::now_ms() / 1000 % 86_400).unwrap(),
        latitude_deg: LAT,
        longitude_deg: LON,
        depth_m: 10.0,
        altitude_m: None,
        speed_mps: 1.0,
        yaw_deg: 90.0,
        pitch_deg: 0.0,
        roll_deg: 0.0,
        battery_pct: 80.0,
    };
    push.send(frame(&Pdu::StateKeyframe(key))).await.unwrap();
    push.send(frame(&predicted_delta(6))).await.unwrap();
    let acks = within(10, "the keyframe's ack", async {
        loop {
            let acks = acks_to_auv(&sent.lock().unwrap());
            if acks.len() >= 2 {
                return acks;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    let acks_later = acks_to_auv(&sent.lock().unwrap());
    assert_eq!(acks, acks_later, "nothing more was sent");
    assert_eq!(
        acks[1],
        Ack {
            from: CDT,
            msg_id: pdu::id::STATE_KEYFRAME,
            ref_no: 6
        }
    );
    shutdown.cancel();
    cdt.await.unwrap().unwrap();
}
