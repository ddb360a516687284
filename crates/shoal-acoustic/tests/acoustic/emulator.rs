//! Raw AT and NL sessions against the emulator.

use std::time::Duration;

use shoal_acoustic::at::{AtCommand, Notification};
use shoal_acoustic::nl::{NlCommand, NlEvent};

use crate::common::{AtClient, NlClient, emulator, modem};

#[tokio::test]
async fn an_acknowledged_instant_message_is_received_and_delivered() {
    let emu = emulator(vec![modem(1, 0.0), modem(2, 1000.0)], |_| {}).await;
    let mut a = AtClient::connect(emu.modems()[0].at).await;
    let mut b = AtClient::connect(emu.modems()[1].at).await;
    assert_eq!(a.command(b"+++AT?AL\n").await, "AT?AL:1");
    let send = AtCommand::SendIm {
        dst: 2,
        ack: true,
        data: b"hi\n+++\x00".to_vec(),
    };
    assert_eq!(a.command(&send.to_bytes()).await, "AT*SENDIM:OK");
    let f = b.frame(Duration::from_secs(5)).await.unwrap();
    let Some(Notification::RecvIm(r)) = Notification::parse(&f.body) else {
        panic!("{f:?}")
    };
    assert_eq!(
        (r.src, r.dst, r.ack, r.data.as_slice()),
        (1, 2, true, &b"hi\n+++\x00"[..])
    );
    assert!(r.rssi < 0 && r.integrity > 100, "{r:?}");
    assert_eq!(a.text().await, "AT:DELIVEREDIM,2");
    // 1 km at ~1490 m/s: AT?T reports the propagation time of the last reception (the ack).
    let t: u64 = a
        .command(b"+++AT?T\n")
        .await
        .trim_start_matches("AT?T:")
        .parse()
        .unwrap();
    assert!((660_000..680_000).contains(&t), "{t}");
    let s = emu.stats();
    assert!(
        s.iter().any(|l| (l.src, l.dst, l.delivered) == (1, 2, 1)),
        "{s:?}"
    );
}

#[tokio::test]
async fn bad_input_gets_modem_error_strings_and_the_connection_survives() {
    let emu = emulator(vec![modem(1, 0.0), modem(2, 500.0)], |_| {}).await;
    let mut a = AtClient::connect(emu.modems()[0].at).await;
    assert_eq!(
        a.command(b"\x00\xff garbage\n").await,
        "AT:ERROR WRONG FORMAT"
    );
    let mut long = b"+++AT*SENDIM,65,2,ack,".to_vec();
    long.extend([7u8; 65]);
    long.push(b'\n');
    assert_eq!(a.command(&long).await, "AT*SENDIM:ERROR OUT OF RANGE");
    assert_eq!(
        a.command(b"+++AT*SENDIM,1,9,ack,x\n").await,
        "AT*SENDIM:ERROR WRONG DESTINATION ADDRESS"
    );
    assert_eq!(
        a.command(b"+++AT*SENDIM,1,255,ack,x\n").await,
        "AT*SENDIM:ERROR WRONG DESTINATION ADDRESS"
    );
    assert_eq!(
        a.command(b"+++AT*SENDIM,x,2,ack,x\n").await,
        "AT*SENDIM:ERROR WRONG FORMAT"
    );
    assert_eq!(a.command(b"+++ATQQ\n").await, "ATQQ:ERROR UNKNOWN COMMAND");
    let mut burst = b"+++AT*SEND,1030,2,".to_vec();
    burst.extend([1u8; 1030]);
    burst.push(b'\n');
    assert_eq!(a.command(&burst).await, "AT*SEND:ERROR BUFFER FULL");
    assert_eq!(a.command(b"+++AT!RI5\n").await, "AT!RI:OK");
    assert_eq!(a.command(b"+++AT?RI\n").await, "AT?RI:5");
    assert_eq!(a.command(b"+++AT?S\n").await, "AT?S:IDLE,FREE 1024");
    let mut nl = NlClient::connect(emu.modems()[0].nl).await;
    nl.write(b"\xfe\xfe\nNL,send,3,99,abc\nNL,get,address\n")
        .await;
    assert_eq!(nl.event().await, NlEvent::Error("format".into()));
    assert_eq!(nl.event().await, NlEvent::NoRouting);
    assert_eq!(nl.event().await, NlEvent::Address(1));
}

#[tokio::test]
async fn a_new_instant_message_cancels_the_pending_one_and_atz_cancels_too() {
    // 3 km: the first message's ack cannot be back before the second command.
    let emu = emulator(vec![modem(1, 0.0), modem(2, 3000.0)], |c| {
        c.time_scale = 0.05;
    })
    .await;
    let mut a = AtClient::connect(emu.modems()[0].at).await;
    assert_eq!(
        a.command(
            &AtCommand::SendIm {
                dst: 2,
                ack: true,
                data: vec![1]
            }
            .to_bytes()
        )
        .await,
        "AT*SENDIM:OK"
    );
    // Still on air (~0.11 s simulated = 5 ms): busy.
    let r = a
        .command(
            &AtCommand::SendIm {
                dst: 2,
                ack: true,
                data: vec![2],
            }
            .to_bytes(),
        )
        .await;
    assert_eq!(r, "AT*SENDIM:BUSY DELIVERING INSTANT MESSAGE TO 2");
    tokio::time::sleep(Duration::from_millis(20)).await;
    // The reply comes first, then the notification about the message it displaced.
    assert_eq!(
        a.command(
            &AtCommand::SendIm {
                dst: 2,
                ack: true,
                data: vec![3]
            }
            .to_bytes()
        )
        .await,
        "AT*SENDIM:OK"
    );
    assert_eq!(a.text().await, "AT:CANCELEDIM,2");
    assert_eq!(a.command(b"+++ATZ4\n").await, "ATZ:OK");
    assert_eq!(a.text().await, "AT:CANCELEDIM,2");
}

#[tokio::test]
async fn beyond_range_the_message_fails_after_its_retries() {
    // 9 km: PER ≈ 1 with the default channel (total loss by 8 km:
    // docs/acoustic.md#packet-error-rate).
    let emu = emulator(vec![modem(1, 0.0), modem(2, 9000.0)], |_| {}).await;
    let mut a = AtClient::connect(emu.modems()[0].at).await;
    assert_eq!(
        a.command(
            &AtCommand::SendIm {
                dst: 2,
                ack: true,
                data: vec![1; 20]
            }
            .to_bytes()
        )
        .await,
        "AT*SENDIM:OK"
    );
    assert_eq!(a.text().await, "AT:FAILEDIM,2");
    // Moving the node close makes it reachable.
    emu.set_position(2, 43.0, 5.001, 20.0).unwrap();
    assert_eq!(
        a.command(
            &AtCommand::SendIm {
                dst: 2,
                ack: true,
                data: vec![1; 20]
            }
            .to_bytes()
        )
        .await,
        "AT*SENDIM:OK"
    );
    assert_eq!(a.text().await, "AT:DELIVEREDIM,2");
    assert!(emu.set_position(77, 0.0, 0.0, 0.0).is_err());
}

#[tokio::test]
async fn simultaneous_arrivals_collide_and_a_transmitting_modem_is_deaf() {
    let emu = emulator(
        vec![modem(1, 0.0), modem(2, 1000.0), modem(3, 2000.0)],
        |c| {
            c.fixed_per = Some(0.0);
            // Slow enough that "simultaneous" survives a loaded machine: the two packets
            // overlap if their commands land within 0.62 s simulated = 124 ms wall.
            c.time_scale = 0.2;
        },
    )
    .await;
    let mut a = AtClient::connect(emu.modems()[0].at).await;
    let mut c = AtClient::connect(emu.modems()[2].at).await;
    let im = |data: u8| {
        AtCommand::SendIm {
            dst: 2,
            ack: false,
            data: vec![data; 64],
        }
        .to_bytes()
    };
    // 1 and 3 are equidistant from 2: their 0.62 s packets overlap there.
    let (m1, m3) = (im(1), im(3));
    let (ra, rc) = tokio::join!(a.command(&m1), c.command(&m3));
    assert_eq!((ra.as_str(), rc.as_str()), ("AT*SENDIM:OK", "AT*SENDIM:OK"));
    tokio::time::sleep(Duration::from_millis(600)).await;
    let s = emu.stats();
    let col: u64 = s.iter().filter(|l| l.dst == 2).map(|l| l.collisions).sum();
    assert_eq!(col, 2, "{s:?}");

    // Half duplex: 2 transmits a long burst while 1's packet arrives. Move 2 to 10 m from
    // 1 first, so 1's packet reaches 2 within milliseconds and the overlap does not depend
    // on how fast this (possibly loaded) machine runs the two commands.
    let near = modem(2, 10.0);
    emu.set_position(2, near.latitude_deg, near.longitude_deg, near.depth_m)
        .unwrap();
    let mut b = AtClient::connect(emu.modems()[1].at).await;
    let burst = AtCommand::SendBurst {
        dst: 3,
        data: vec![0; 1000],
    }
    .to_bytes(); // ~0.68 s
    assert_eq!(b.command(&burst).await, "AT*SEND:OK");
    assert_eq!(a.command(&im(9)).await, "AT*SENDIM:OK");
    tokio::time::sleep(Duration::from_millis(600)).await;
    let deaf: u64 = emu
        .stats()
        .iter()
        .filter(|l| (l.src, l.dst) == (1, 2))
        .map(|l| l.half_duplex)
        .sum();
    assert_eq!(deaf, 1);
}

/// A modem whose acknowledgement comes late retransmits, so the receiver may hear a frame
/// twice and the sender may still be busy just after `Delivered`: real modems do both
/// (docs/acoustic.md#at-interface). At 100x, a loaded test machine makes acks late, so
/// the test accepts those repeats and asserts what must hold: each payload arrives intact,
/// delivery is reported, and a send after delivery is accepted.
#[tokio::test]
async fn nl_send_is_received_and_reported_delivered() {
    let emu = emulator(vec![modem(1, 0.0), modem(2, 800.0)], |_| {}).await;
    let mut a = NlClient::connect(emu.modems()[0].nl).await;
    let mut b = NlClient::connect(emu.modems()[1].nl).await;
    a.write(&NlCommand::SetProtocol("staticrack".into()).to_bytes())
        .await;
    assert_eq!(a.event().await, NlEvent::Protocol("staticrack".into()));
    let first = b"x,y\nz".to_vec();
    let send = |data: Vec<u8>| {
        NlCommand::Send {
            kind: None,
            dst: 2,
            data,
        }
        .to_bytes()
    };
    a.write(&send(first.clone())).await;
    assert_eq!(a.event().await, NlEvent::SendOk);
    let recv = |data: &[u8]| NlEvent::Recv {
        src: 1,
        dst: 2,
        data: data.to_vec(),
    };
    assert_eq!(b.event().await, recv(&first));
    assert_eq!(a.event().await, NlEvent::Delivered { src: 1, dst: 2 });
    // A second send while the first is pending would be busy; after delivery it is
    // accepted once any retransmission of the first has left the modem.
    let second = vec![0; 80];
    let deadline = tokio::time::Instant::now() + Duration::from_secs(5);
    'send: loop {
        a.write(&send(second.clone())).await;
        loop {
            match a.event().await {
                NlEvent::SendOk => break 'send,
                NlEvent::SendBusy if tokio::time::Instant::now() < deadline => break,
                // The retransmission's own delivery report.
                NlEvent::Delivered { src: 1, dst: 2 } => {}
                other => panic!("second send answered {other:?}"),
            }
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    loop {
        let e = b.event().await;
        if e == recv(&second) {
            break;
        }
        assert_eq!(
            e,
            recv(&first),
            "only a repeat of the first frame may come first"
        );
    }
}

#[tokio::test]
async fn a_silent_modem_neither_hears_nor_is_heard_until_it_is_back() {
    let emu = emulator(vec![modem(1, 0.0), modem(2, 1000.0)], |_| {}).await;
    let mut a = AtClient::connect(emu.modems()[0].at).await;
    let mut b = AtClient::connect(emu.modems()[1].at).await;
    let send = |dst: u8| {
        AtCommand::SendIm {
            dst,
            ack: true,
            data: vec![7; 8],
        }
        .to_bytes()
    };
    emu.set_silent(2, true).unwrap();
    assert_eq!(a.command(&send(2)).await, "AT*SENDIM:OK");
    assert_eq!(a.text().await, "AT:FAILEDIM,2");
    // Nor does anything it sends reach the water.
    assert_eq!(b.command(&send(1)).await, "AT*SENDIM:OK");
    assert_eq!(b.text().await, "AT:FAILEDIM,1");
    let outage = |s: &[shoal_acoustic::emulator::LinkStats], src, dst| {
        s.iter()
            .find(|l| (l.src, l.dst) == (src, dst))
            .map_or(0, |l| l.outage)
    };
    let s = emu.stats();
    assert!(outage(&s, 1, 2) >= 1 && outage(&s, 2, 1) >= 1, "{s:?}");
    assert!(s.iter().all(|l| l.delivered == 0), "{s:?}");

    // The silent modem put nothing on the water; the other tried (with its retries).
    let air: std::collections::HashMap<u8, f64> = emu.airtime().into_iter().collect();
    assert!(air[&2] == 0.0 && air[&1] > 0.3, "{air:?}");

    emu.set_silent(2, false).unwrap();
    assert_eq!(a.command(&send(2)).await, "AT*SENDIM:OK");
    assert_eq!(a.text().await, "AT:DELIVEREDIM,2");
    // An 8-byte IM at 976 bit/s takes about 0.17 s on air; its acknowledgement is modem 2's.
    let after: std::collections::HashMap<u8, f64> = emu.airtime().into_iter().collect();
    assert!(
        (0.1..0.3).contains(&(after[&1] - air[&1])),
        "{air:?} then {after:?}"
    );
    assert!(after[&2] > 0.0, "{after:?}");
    assert!(emu.set_silent(77, true).is_err());
}
