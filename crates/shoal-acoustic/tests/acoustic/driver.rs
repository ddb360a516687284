//! Drivers against the emulator and against scripted fake modems.

use std::time::Duration;

use shoal_acoustic::at::{self, CommandParser};
use shoal_acoustic::driver::{
    AtDriver, DriverConfig, ModemDriver, NlDriver, OutFrame, Outcome, TransmitError,
};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

use crate::common::{emulator, modem};

fn frame(dst: u8, data: &[u8], ack: bool) -> OutFrame {
    OutFrame {
        dst,
        data: data.to_vec(),
        ack,
        burst: false,
    }
}

#[tokio::test]
async fn at_driver_sends_receives_and_reports() {
    let emu = emulator(vec![modem(1, 0.0), modem(2, 1500.0)], |_| {}).await;
    let a = AtDriver::start(DriverConfig::new(emu.modems()[0].at).scaled(0.01));
    let b = AtDriver::start(DriverConfig::new(emu.modems()[1].at).scaled(0.01));
    assert_eq!(
        a.transmit(frame(2, b"state", true)).await.unwrap(),
        Outcome::Delivered
    );
    let rx = tokio::time::timeout(Duration::from_secs(5), b.receive())
        .await
        .unwrap()
        .unwrap();
    assert_eq!((rx.src, rx.data.as_slice()), (1, &b"state"[..]));
    assert!(rx.rssi.is_some() && rx.integrity.is_some());
    assert_eq!(a.local_address(), Some(1));
    // Back-to-back unacknowledged messages: the second meets BUSY and is retried.
    assert_eq!(
        a.transmit(frame(2, b"one", false)).await.unwrap(),
        Outcome::Sent
    );
    assert_eq!(
        a.transmit(frame(2, b"two", false)).await.unwrap(),
        Outcome::Sent
    );
    // An unknown address is rejected with the modem's error string, frame handed back.
    match a.transmit(frame(99, b"x", true)).await {
        Err(TransmitError::Rejected { frame, reason }) => {
            assert_eq!(
                (frame.dst, reason.as_str()),
                (99, "ERROR WRONG DESTINATION ADDRESS")
            );
        }
        other => panic!("{other:?}"),
    }
}

#[tokio::test]
async fn nl_driver_sends_and_receives() {
    let emu = emulator(vec![modem(1, 0.0), modem(2, 1500.0)], |_| {}).await;
    let a = NlDriver::start(DriverConfig::new(emu.modems()[0].nl).scaled(0.01), true);
    let b = NlDriver::start(DriverConfig::new(emu.modems()[1].nl).scaled(0.01), true);
    assert_eq!(
        a.transmit(frame(2, b"hello", true)).await.unwrap(),
        Outcome::Delivered
    );
    let rx = tokio::time::timeout(Duration::from_secs(5), b.receive())
        .await
        .unwrap()
        .unwrap();
    assert_eq!((rx.src, rx.data.as_slice()), (1, &b"hello"[..]));
    assert!(matches!(
        a.transmit(frame(42, b"x", true)).await,
        Err(TransmitError::Rejected { .. })
    ));
}

/// Reads one complete AT command from a fake modem's client.
async fn read_command(s: &mut TcpStream, p: &mut CommandParser) -> at::AtCommand {
    loop {
        if let Some(c) = p.next() {
            return c.unwrap();
        }
        let mut buf = [0u8; 512];
        let n = s.read(&mut buf).await.unwrap();
        assert!(n > 0, "driver closed the connection");
        p.push(&buf[..n]);
    }
}

#[tokio::test]
async fn at_driver_survives_busy_and_a_dropped_connection_without_losing_the_frame() {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let modem = tokio::spawn(async move {
        // First connection: answer the address query, say BUSY once, then die mid-send.
        let (mut s, _) = listener.accept().await.unwrap();
        let mut p = CommandParser::new();
        assert_eq!(
            read_command(&mut s, &mut p).await,
            at::AtCommand::GetLocalAddress
        );
        s.write_all(&at::reply("AT?AL", b"1")).await.unwrap();
        let c = read_command(&mut s, &mut p).await;
        assert!(matches!(c, at::AtCommand::SendIm { dst: 2, .. }));
        s.write_all(&at::reply("AT*SENDIM", b"BUSY BACKOFF STATE"))
            .await
            .unwrap();
        let c = read_command(&mut s, &mut p).await;
        assert!(
            matches!(c, at::AtCommand::SendIm { dst: 2, .. }),
            "resent after BUSY"
        );
        drop(s);
        // Second connection: the same frame comes again; deliver it.
        let (mut s, _) = listener.accept().await.unwrap();
        let mut p = CommandParser::new();
        assert_eq!(
            read_command(&mut s, &mut p).await,
            at::AtCommand::GetLocalAddress
        );
        s.write_all(&at::reply("AT?AL", b"1")).await.unwrap();
        let c = read_command(&mut s, &mut p).await;
        let at::AtCommand::SendIm { data, .. } = c else {
            panic!("{c:?}")
        };
        s.write_all(b"\x00garbage").await.unwrap();
        s.write_all(&at::reply("AT*SENDIM", b"OK")).await.unwrap();
        s.write_all(&at::notification(b"DELIVEREDIM,2"))
            .await
            .unwrap();
        data
    });
    let cfg = DriverConfig {
        reconnect_delay: Duration::from_millis(20),
        busy_retry: Duration::from_millis(20),
        ..DriverConfig::new(addr)
    };
    let d = AtDriver::start(cfg);
    let out = tokio::time::timeout(
        Duration::from_secs(5),
        d.transmit(frame(2, b"keep me", true)),
    )
    .await
    .unwrap();
    assert_eq!(out.unwrap(), Outcome::Delivered);
    assert_eq!(modem.await.unwrap(), b"keep me");
}

#[tokio::test]
async fn at_driver_reports_failed_and_canceled() {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    tokio::spawn(async move {
        let (mut s, _) = listener.accept().await.unwrap();
        let mut p = CommandParser::new();
        let _ = read_command(&mut s, &mut p).await;
        s.write_all(&at::reply("AT?AL", b"1")).await.unwrap();
        for note in [&b"FAILEDIM,2"[..], b"CANCELEDIM,2"] {
            let _ = read_command(&mut s, &mut p).await;
            s.write_all(&at::reply("AT*SENDIM", b"OK")).await.unwrap();
            s.write_all(&at::notification(note)).await.unwrap();
        }
        // Keep the connection open until the test ends.
        let mut buf = [0u8; 64];
        let _ = s.read(&mut buf).await;
    });
    let d = AtDriver::start(DriverConfig::new(addr));
    assert_eq!(
        d.transmit(frame(2, b"a", true)).await.unwrap(),
        Outcome::Failed
    );
    assert_eq!(
        d.transmit(frame(2, b"b", true)).await.unwrap(),
        Outcome::Canceled
    );
}

/// Tagged frames over the emulator: the CDT's tagged driver seals what it sends (the
/// vehicle opens it with the shared key) and opens what it receives; frames without a tag,
/// tampered, replayed, sealed with another key or from an address without a key are
/// refused and counted, and the genuine frames around them still arrive.
#[tokio::test]
async fn tagged_drivers_authenticate_frames_and_refuse_forgeries_and_replays() {
    use shoal_acoustic::secure::TaggedDriver;
    use shoal_security::{AcousticKey, AcousticTagger, RejectionReason, TagSize};

    let emu = emulator(
        vec![modem(1, 0.0), modem(2, 1500.0), modem(3, 800.0)],
        |_| {},
    )
    .await;
    let key = AcousticKey::from_bytes([7; 32]);
    let mut cdt_tagger = AcousticTagger::new(2, TagSize::Bits64, 1000);
    cdt_tagger.set_key(1, &key);
    let cdt = TaggedDriver::new(
        AtDriver::start(DriverConfig::new(emu.modems()[1].at).scaled(0.01)),
        cdt_tagger,
    );
    assert_eq!(cdt.overhead(), 12);
    assert_eq!(cdt.frame_budget(64), 52);
    let refused = cdt.refused();
    // The vehicle's side by hand: a plain driver and its own tagger.
    let vehicle = AtDriver::start(DriverConfig::new(emu.modems()[0].at).scaled(0.01));
    let mut own = AcousticTagger::new(1, TagSize::Bits64, 5000);
    own.set_key(2, &key);

    // CDT -> vehicle: sealed on the way out, authentic at the vehicle.
    cdt.transmit(frame(1, b"task", true)).await.unwrap();
    let rx = tokio::time::timeout(Duration::from_secs(5), vehicle.receive())
        .await
        .unwrap()
        .unwrap();
    assert_eq!(rx.data.len(), 4 + 12);
    assert_eq!(own.open(2, 1, &rx.data).unwrap(), b"task");

    let genuine = own.seal(2, b"state").unwrap();
    let mut flipped = own.seal(2, b"state").unwrap();
    flipped[0] ^= 0x01;
    let mut stranger = AcousticTagger::new(1, TagSize::Bits64, 9000);
    stranger.set_key(2, &AcousticKey::from_bytes([8; 32]));
    let wrong_key = stranger.seal(2, b"abort").unwrap();
    for data in [
        genuine.clone(),
        b"junk".to_vec(),
        flipped,
        genuine,
        wrong_key,
        own.seal(2, b"next").unwrap(),
    ] {
        vehicle.transmit(frame(2, &data, true)).await.unwrap();
    }
    // A modem whose address has no key.
    let intruder = AtDriver::start(DriverConfig::new(emu.modems()[2].at).scaled(0.01));
    intruder
        .transmit(frame(2, &own.seal(2, b"x").unwrap(), true))
        .await
        .unwrap();

    let mut got = Vec::new();
    for _ in 0..2 {
        let rx = tokio::time::timeout(Duration::from_secs(5), cdt.receive())
            .await
            .unwrap()
            .unwrap();
        assert_eq!(rx.src, 1);
        got.push(rx.data);
    }
    assert_eq!(got, [b"state".to_vec(), b"next".to_vec()]);
    // The intruder's frame arrives last; wait until every refusal has been counted. A
    // sending modem whose ack comes late retransmits (at 100x on a loaded machine acks
    // are often late), and the receiver hears the frame twice: a repeat is refused for the
    // same reason again, or as replayed. So each reason is counted at least as often as
    // its frames were sent, and a genuine frame heard twice counts as replayed.
    let expected = [
        (RejectionReason::FrameTooShort, 1),
        (RejectionReason::BadTag, 2),
        (RejectionReason::Replayed, 1),
        (RejectionReason::NoKey, 1),
    ];
    let deadline = tokio::time::Instant::now() + Duration::from_secs(5);
    let counts = loop {
        let c = refused.lock().unwrap().clone();
        let all = expected.iter().all(|(r, n)| c.get(*r) >= *n);
        if all || tokio::time::Instant::now() > deadline {
            break c;
        }
        tokio::select! {
            _ = cdt.receive() => panic!("a refused frame was delivered"),
            () = tokio::time::sleep(Duration::from_millis(50)) => {}
        }
    };
    for (reason, n) in expected {
        assert!(counts.get(reason) >= n, "{reason:?}: {counts}");
    }
    // Only repeats add to the count: at most one per frame sent (8 refused or genuine).
    assert!(counts.total() <= 5 + 8, "{counts}");
}
