//! The link layer over a driver over the emulator.

use std::collections::HashSet;
use std::time::Duration;

use shoal_acoustic::driver::{AtDriver, DriverConfig};
use shoal_acoustic::link::{self, Class, LinkConfig, LinkEvent, Outgoing};
use shoal_acoustic::pdu;

use crate::common::{emulator, modem};

const SCALE: f64 = 0.01;

fn task_pdu(task_no: u8) -> Vec<u8> {
    let p = pdu::Pdu::Task(pdu::CompactTask {
        vehicle: 2,
        task_no,
        action: pdu::TaskAction::Abort,
    });
    pdu::encode(&p).unwrap()
}

#[tokio::test]
async fn control_messages_are_all_delivered_at_30_percent_per_within_ttl() {
    let emu = emulator(vec![modem(1, 0.0), modem(2, 1000.0)], |c| {
        c.fixed_per = Some(0.3);
        // No modem-level retries: the link layer's retransmission must do the work.
        c.im_retries = 0;
    })
    .await;
    let drv = AtDriver::start(DriverConfig::new(emu.modems()[0].at).scaled(SCALE));
    let _peer = AtDriver::start(DriverConfig::new(emu.modems()[1].at).scaled(SCALE));
    let cfg = LinkConfig {
        max_frame: 16,
        ..LinkConfig::default()
    }
    .scaled(SCALE);
    let ttl = cfg.control.ttl;
    let (tx, mut events) = link::start(drv, cfg, std::future::pending());
    let mut ids = HashSet::new();
    for n in 0..20 {
        ids.insert(
            tx.send(Outgoing {
                dst: 2,
                class: Class::Control,
                pdu: task_pdu(n),
                supersede_key: None,
            })
            .await
            .unwrap(),
        );
    }
    let deadline = tokio::time::Instant::now() + ttl;
    while !ids.is_empty() {
        let ev = tokio::time::timeout_at(deadline, events.recv())
            .await
            .expect("TTL passed")
            .unwrap();
        match ev {
            LinkEvent::Delivered(id) => assert!(ids.remove(&id)),
            LinkEvent::Expired(id) | LinkEvent::Dropped(id) => panic!("control message {id} lost"),
            _ => {}
        }
    }
    let s = emu.stats();
    let lost: u64 = s.iter().map(|l| l.lost).sum();
    assert!(lost > 0, "30 % PER should have lost something: {s:?}");
}

#[tokio::test]
async fn an_emergency_overtakes_queued_telemetry() {
    let emu = emulator(vec![modem(1, 0.0), modem(2, 1000.0)], |c| {
        c.fixed_per = Some(0.0);
    })
    .await;
    let drv = AtDriver::start(DriverConfig::new(emu.modems()[0].at).scaled(SCALE));
    let peer = link::start(
        AtDriver::start(DriverConfig::new(emu.modems()[1].at).scaled(SCALE)),
        LinkConfig::default(),
        std::future::pending(),
    );
    let (_peer_tx, mut peer_events) = peer;
    // One telemetry PDU per frame, so the queue takes many frames to drain.
    let cfg = LinkConfig {
        max_frame: 40,
        ..LinkConfig::default()
    }
    .scaled(SCALE);
    let (tx, _events) = link::start(drv, cfg, std::future::pending());
    for i in 0..6u8 {
        tx.send(Outgoing {
            dst: 2,
            class: Class::Telemetry,
            pdu: vec![0x10 + i; 30],
            supersede_key: None,
        })
        .await
        .unwrap();
    }
    let alarm = pdu::encode(&pdu::Pdu::Event(pdu::CompactEvent {
        vehicle: Some(1),
        event_no: 1,
        severity: 3,
        kind: 0,
        task_no: None,
        seconds_of_day: 0,
    }))
    .unwrap();
    tx.send(Outgoing {
        dst: 2,
        class: Class::Emergency,
        pdu: alarm.clone(),
        supersede_key: None,
    })
    .await
    .unwrap();
    // The receiver sees the alarm in one of the first two frames (one may already be on
    // air); it may share its frame with telemetry.
    let mut order: Vec<Vec<u8>> = Vec::new();
    while order.iter().map(Vec::len).sum::<usize>() < 6 * 30 + alarm.len() {
        let Ok(Some(ev)) = tokio::time::timeout(Duration::from_secs(5), peer_events.recv()).await
        else {
            panic!(
                "only {} frames arrived: {order:?}; stats {:?}",
                order.len(),
                emu.stats()
            );
        };
        if let LinkEvent::Received { frame, .. } = ev {
            order.push(frame);
        }
    }
    let pos = order
        .iter()
        .position(|f| f.starts_with(&alarm))
        .expect("alarm never arrived");
    assert!(pos <= 1, "alarm arrived as frame {pos}");
    assert!(matches!(
        pdu::decode_prefix(&order[pos]),
        Ok((pdu::Pdu::Event(_), 7))
    ));
}
