//! The service layer without pyais: TCP streams with over-long lines, reconnection
//! back-off, direct ingestion, configuration errors and cancellation.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::time::Duration;

use shoal_traffic::{TrafficConfig, TrafficError, TrafficPicture};
use tokio::io::AsyncWriteExt;
use tokio::net::TcpListener;
use tokio_util::sync::CancellationToken;

const T1: &str = "!AIVDM,1,1,,A,13KF5P@P1s1hntRRIjFQj1H1P000,0*2B";
const T18: &str = "!AIVDM,1,1,,B,B3KF5TP00VgVg8K=C62aWwP00000,0*40";

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tcp_over_long_line_is_skipped_to_its_end_and_reconnects_back_off() {
    let server = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let port = server.local_addr().unwrap().port();
    let config = TrafficConfig {
        inputs: vec![format!("tcp://127.0.0.1:{port}").parse().unwrap()],
        max_line_len: 100,
        reconnect_min_ms: 200,
        reconnect_max_ms: 400,
        ..TrafficConfig::default()
    };
    let cancel = CancellationToken::new();
    let handle = TrafficPicture::spawn(config, cancel.clone()).unwrap();

    let (mut conn, _) = server.accept().await.unwrap();
    // 64 KiB without a newline, in pieces, then the rest of that line and a good one.
    for _ in 0..64 {
        conn.write_all(&[b'x'; 1024]).await.unwrap();
    }
    conn.write_all(format!("tail of the long line\n{T1}\n").as_bytes())
        .await
        .unwrap();
    for _ in 0..100 {
        if handle.target(230_000_001).is_some() {
            break;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert!(handle.target(230_000_001).is_some(), "{:?}", handle.stats());
    assert_eq!(
        handle.stats().too_long,
        1,
        "one over-long line, counted once"
    );

    // The server hangs up; the next connection comes after the back-off, not at once.
    drop(conn);
    let hung_up = std::time::Instant::now();
    let (mut conn, _) = tokio::time::timeout(Duration::from_secs(5), server.accept())
        .await
        .expect("reconnects")
        .unwrap();
    assert!(
        hung_up.elapsed() >= Duration::from_millis(150),
        "{:?}",
        hung_up.elapsed()
    );
    conn.write_all(format!("{T18}\r\n").as_bytes())
        .await
        .unwrap();
    for _ in 0..100 {
        if handle.target(230_000_018).is_some() {
            break;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert!(handle.target(230_000_018).is_some());
    let s = handle.stats();
    assert_eq!((s.tcp_connects, s.accepted), (2, 2), "{s:?}");

    cancel.cancel();
    tokio::time::timeout(Duration::from_secs(5), handle.join())
        .await
        .expect("stops on cancel");
}

#[tokio::test]
async fn unreachable_server_is_retried_without_a_hot_loop() {
    // Bind and drop to get a port nobody listens on.
    let port = {
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        l.local_addr().unwrap().port()
    };
    let config = TrafficConfig {
        inputs: vec![format!("tcp://127.0.0.1:{port}").parse().unwrap()],
        reconnect_min_ms: 100,
        reconnect_max_ms: 200,
        ..TrafficConfig::default()
    };
    let cancel = CancellationToken::new();
    let handle = TrafficPicture::spawn(config, cancel.clone()).unwrap();
    tokio::time::sleep(Duration::from_millis(1000)).await;
    let failures = handle.stats().tcp_failures;
    // 100, 200, 200, … ms apart: about 5 in a second, never hundreds.
    assert!((2..=8).contains(&failures), "{failures} attempts in 1 s");
    cancel.cancel();
    handle.join().await;
}

#[tokio::test]
async fn ingest_line_and_config_errors() {
    let cancel = CancellationToken::new();
    let handle = TrafficPicture::spawn(TrafficConfig::default(), cancel.clone()).unwrap();
    assert!(handle.ingest_line(T1));
    assert!(!handle.ingest_line("garbage"));
    assert_eq!(handle.targets().len(), 1);
    assert_eq!(handle.stats().garbage, 1);
    assert!(handle.own_ship().is_none());

    let bad = TrafficConfig {
        max_targets: 0,
        ..TrafficConfig::default()
    };
    assert!(matches!(
        TrafficPicture::spawn(bad, cancel.clone()),
        Err(TrafficError::Config(_))
    ));
    // A UDP port already taken fails at spawn, not later.
    let taken = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let busy = TrafficConfig {
        inputs: vec![
            format!("udp://{}", taken.local_addr().unwrap())
                .parse()
                .unwrap(),
        ],
        ..TrafficConfig::default()
    };
    assert!(matches!(
        TrafficPicture::spawn(busy, cancel),
        Err(TrafficError::Bind { .. })
    ));
}

#[test]
fn spawn_outside_a_runtime_is_an_error() {
    let r = TrafficPicture::spawn(TrafficConfig::default(), CancellationToken::new());
    assert!(matches!(r, Err(TrafficError::NoRuntime)));
}
