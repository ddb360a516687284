//! A client that stops reading is dropped, and another keeps receiving; the bridge never
//! buffers for a stalled client beyond its queue. Real DDS on a private domain.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

mod common;

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use futures::StreamExt;
use shoal_dds::{Priority, WriterOptions};
use shoal_foxglove::{Bridge, BridgeConfig, RateLimits};
use shoal_model::{Event, EventKind, Severity};
use tokio::net::TcpSocket;
use tokio_util::sync::CancellationToken;

const DOMAIN: u16 = 176;

fn event(i: u64) -> Event {
    Event {
        event_id: format!("e-{i}"),
        timestamp_ms: 1_767_225_600_000 + i64::try_from(i).unwrap(),
        severity: Severity::Info,
        kind: EventKind::Other,
        vehicle_id: "auv-1".into(),
        task_id: String::new(),
        // Large messages fill the stalled client's socket sooner.
        text: "x".repeat(500),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_that_stops_reading_is_dropped_while_another_keeps_receiving() {
    let station = Arc::new(common::pubsub(DOMAIN));
    let vehicle = common::pubsub(DOMAIN);
    let cancel = CancellationToken::new();
    let config = BridgeConfig {
        enabled: true,
        max_clients: 2,
        client_queue: 64,
        send_timeout_ms: 1000,
        rates: RateLimits::unlimited(),
        ..BridgeConfig::default()
    };
    let bridge = Bridge::start(Arc::clone(&station), config, cancel.clone())
        .await
        .unwrap();
    let addr = common::front(bridge.clone()).await;
    let writer = vehicle
        .writer::<Event>(WriterOptions::new(Priority::Control))
        .unwrap();
    common::wait_matched(&writer).await;

    // The stalled client: a small receive buffer, subscribes, then never reads again.
    let socket = TcpSocket::new_v4().unwrap();
    socket.set_recv_buffer_size(4096).unwrap();
    let stream = socket.connect(addr).await.unwrap();
    let mut stalled = common::connect_over(stream, addr, "foxglove.sdk.v1").await;
    let channel = common::channel_id(&mut stalled, "shoal/event").await;
    common::subscribe(&mut stalled, 1, channel).await;

    // The reading client.
    let stream = tokio::net::TcpStream::connect(addr).await.unwrap();
    let mut reader = common::connect_over(stream, addr, "foxglove.websocket.v1").await;
    let channel = common::channel_id(&mut reader, "shoal/event").await;
    common::subscribe(&mut reader, 1, channel).await;
    let received = Arc::new(AtomicU64::new(0));
    let counter = Arc::clone(&received);
    let reading = tokio::spawn(async move {
        loop {
            match reader.next().await {
                Some(Ok(msg)) => {
                    if common::is_message_data(&msg) {
                        counter.fetch_add(1, Ordering::Relaxed);
                    }
                }
                end => {
                    println!("reader ended: {end:?}");
                    break;
                }
            }
        }
    });
    assert_eq!(bridge.clients(), 2);

    // Publish until the stalled client is dropped (60 s at most).
    let mut i = 0;
    let deadline = tokio::time::Instant::now() + Duration::from_secs(60);
    while bridge.stats().slow_clients_dropped.load(Ordering::Relaxed) == 0 {
        assert!(
            tokio::time::Instant::now() < deadline,
            "the stalled client was not dropped after {i} events"
        );
        for _ in 0..50 {
            writer.write(event(i)).await.unwrap();
            i += 1;
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    let published_at_drop = i;
    println!(
        "dropped after {i} events; the reader had {}; bridge logged {}",
        received.load(Ordering::Relaxed),
        bridge.stats().logged.load(Ordering::Relaxed)
    );
    // Its place is free again; the reader still has its own.
    for _ in 0..100 {
        if bridge.clients() == 1 {
            break;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert_eq!(bridge.clients(), 1);
    assert_eq!(
        bridge.stats().slow_clients_dropped.load(Ordering::Relaxed),
        1
    );

    // The reader keeps receiving what is published after the drop.
    let before = received.load(Ordering::Relaxed);
    for _ in 0..200 {
        writer.write(event(i)).await.unwrap();
        i += 1;
    }
    let deadline = tokio::time::Instant::now() + Duration::from_secs(20);
    while received.load(Ordering::Relaxed) < before + 200 {
        assert!(
            tokio::time::Instant::now() < deadline,
            "the reader got {} of 200 events after the drop",
            received.load(Ordering::Relaxed) - before
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert!(
        !reading.is_finished(),
        "the reader's connection must stay open"
    );

    // The stalled client, reading again, finds its connection closed after what was
    // already in its socket: far fewer events than were published.
    let mut got = 0u64;
    let drained = tokio::time::timeout(Duration::from_secs(20), async {
        while let Some(Ok(msg)) = stalled.next().await {
            if common::is_message_data(&msg) {
                got += 1;
            }
        }
    })
    .await;
    assert!(
        drained.is_ok(),
        "the stalled client's connection was not closed"
    );
    assert!(
        got < published_at_drop,
        "the stalled client got {got} of {published_at_drop}: it was not cut off"
    );
    cancel.cancel();
}
