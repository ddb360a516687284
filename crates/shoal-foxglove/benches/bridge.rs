//! The bridge's per-message cost: encoding a state vector (CDR and LocationFix) and
//! fanning it out to five subscribed clients through the gateway; then the issue's
//! target as a latency run: 1000 vehicles at 1 Hz to 5 clients, p99 of the time from
//! logging a state vector to a client having read it.
//!
//! `cargo bench -p shoal-foxglove --bench bridge` (no DDS: the samples are logged as
//! the bridge's pumps log what DDS hands them). Clients connect over in-memory duplex
//! pipes (64 KiB, like a socket buffer) and read as fast as they can.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::hint::black_box;
use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use criterion::{Criterion, Throughput, criterion_group};
use futures::{SinkExt, StreamExt};
use shoal_foxglove::{BenchRig, BridgeConfig, Frame, RateLimits, Subprotocol, channels};
use shoal_model::StateVector;
use tokio::sync::Mutex;
use tokio_tungstenite::WebSocketStream;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::protocol::Role;

const CLIENTS: usize = 5;
const VEHICLES: usize = 1000;

fn state(i: usize, now_ms: i64) -> StateVector {
    StateVector {
        vehicle_id: format!("auv-{i:04}"),
        timestamp_ms: now_ms,
        latitude_deg: 43.0 + (i as f64) * 1e-3,
        longitude_deg: 5.9,
        depth_m: 10.0,
        altitude_m: -1.0,
        speed_mps: 1.2,
        yaw_deg: 90.0,
        pitch_deg: 0.0,
        roll_deg: 0.0,
        battery_pct: 80.0,
    }
}

fn now_ms() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| i64::try_from(d.as_millis()).unwrap_or(i64::MAX))
}

fn now_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX))
}

/// A client through the gateway over an in-memory pipe.
async fn gateway_client(rig: &BenchRig) -> WebSocketStream<tokio::io::DuplexStream> {
    let (near, far) = tokio::io::duplex(64 << 10);
    let server_side = WebSocketStream::from_raw_socket(near, Role::Server, None).await;
    let server_side = shoal_foxglove::adapt(server_side, to_tungstenite, from_tungstenite);
    let handle = rig.handle.clone();
    let place = handle.admit().unwrap();
    tokio::spawn(async move { handle.serve(place, server_side, Subprotocol::SdkV1).await });
    WebSocketStream::from_raw_socket(far, Role::Client, None).await
}

fn to_tungstenite(frame: Frame) -> Message {
    match frame {
        Frame::Text(t) => Message::text(t),
        Frame::Binary(b) => Message::Binary(b),
        Frame::Close => Message::Close(None),
    }
}

fn from_tungstenite(message: Message) -> Option<Frame> {
    match message {
        Message::Text(t) => Some(Frame::Text(t.as_str().to_owned())),
        Message::Binary(b) => Some(Frame::Binary(b)),
        Message::Close(_) => Some(Frame::Close),
        _ => None,
    }
}

/// Latencies (ns) every client measured, shared with the reading tasks.
type Samples = Arc<Mutex<Vec<u64>>>;

/// Connects one client through the gateway over an in-memory pipe, subscribes to the
/// two state-vector channels and reads until the pipe closes, recording each message's
/// latency (now − its log time).
async fn client(rig: &BenchRig, samples: Samples, through_gateway: bool) {
    let mut ws = if through_gateway {
        gateway_client(rig).await
    } else {
        // Straight to the SDK's server: what `log` costs without the gateway's tasks.
        use tokio_tungstenite::tungstenite::client::IntoClientRequest;
        let mut request = format!("ws://{}/", rig.handle.internal_addr())
            .into_client_request()
            .unwrap();
        request
            .headers_mut()
            .insert("sec-websocket-protocol", "foxglove.sdk.v1".parse().unwrap());
        let (ws, _) = tokio_tungstenite::connect_async(request).await.unwrap();
        let (near, far) = tokio::io::duplex(64 << 10);
        // Bridge the TCP client into a duplex so both kinds read the same way.
        let mut raw = WebSocketStream::from_raw_socket(near, Role::Server, None).await;
        tokio::spawn(async move {
            let (mut tx, mut rx) = ws.split();
            loop {
                tokio::select! {
                    m = rx.next() => match m {
                        Some(Ok(m)) => if raw.send(m).await.is_err() { break },
                        _ => break,
                    },
                    m = raw.next() => match m {
                        Some(Ok(m)) => if tx.send(m).await.is_err() { break },
                        _ => break,
                    },
                }
            }
        });
        WebSocketStream::from_raw_socket(far, Role::Client, None).await
    };
    let mut wanted = vec!["shoal/state_vector", "shoal/location_fix"];
    let mut next_sub = 0;
    while !wanted.is_empty() {
        let Some(Ok(Message::Text(t))) = ws.next().await else {
            continue;
        };
        let v: serde_json::Value = serde_json::from_str(t.as_str()).unwrap();
        if v["op"] != "advertise" {
            continue;
        }
        for c in v["channels"].as_array().unwrap() {
            let topic = c["topic"].as_str().unwrap();
            if let Some(i) = wanted.iter().position(|w| *w == topic) {
                wanted.remove(i);
                let msg = serde_json::json!({"op": "subscribe",
                    "subscriptions": [{"id": next_sub, "channelId": c["id"]}]});
                next_sub += 1;
                ws.send(Message::text(msg.to_string())).await.unwrap();
            }
        }
    }
    tokio::spawn(async move {
        let mut local = Vec::new();
        while let Some(Ok(msg)) = ws.next().await {
            if let Message::Binary(b) = msg
                && b.first() == Some(&1)
                && b.len() >= 13
            {
                let mut t = [0u8; 8];
                t.copy_from_slice(&b[5..13]);
                local.push(now_ns().saturating_sub(u64::from_le_bytes(t)));
                if local.len() >= 1024 {
                    samples.lock().await.append(&mut local);
                }
            }
        }
        samples.lock().await.append(&mut local);
    });
}

async fn rig_with_clients(samples: &Samples, through_gateway: bool) -> BenchRig {
    let config = BridgeConfig {
        enabled: true,
        rates: RateLimits::unlimited(),
        ..BridgeConfig::default()
    };
    let rig = BenchRig::start(config).await.unwrap();
    for _ in 0..CLIENTS {
        client(&rig, Arc::clone(samples), through_gateway).await;
    }
    // Subscriptions are asynchronous: wait until the channels have sinks.
    tokio::time::sleep(Duration::from_millis(300)).await;
    rig
}

fn encoding(c: &mut Criterion) {
    let s = state(7, 1_767_225_600_000);
    let mut g = c.benchmark_group("encode");
    g.throughput(Throughput::Elements(1));
    g.bench_function("state_vector_cdr", |b| {
        b.iter(|| channels::encode(black_box(&s)).unwrap());
    });
    g.bench_function("state_vector_to_location_fix", |b| {
        b.iter(|| channels::location_fix(black_box(&s)));
    });
    g.finish();
}

fn fanout(c: &mut Criterion) {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    let samples: Samples = Arc::default();
    let rig = rt.block_on(rig_with_clients(&samples, false));
    let mut g = c.benchmark_group("fanout");
    g.throughput(Throughput::Elements(1));
    let mut i = 0usize;
    g.bench_function("log_state_vector_to_5_clients", |b| {
        b.iter(|| {
            rig.log(&state(i % VEHICLES, now_ms()));
            i += 1;
        });
    });
    g.finish();
    rig.handle.stop();
    drop(rt);
}

/// The target as a run of its own: 1000 vehicles at 1 Hz (one state vector a
/// millisecond, round robin) to 5 clients for `seconds`; prints latency percentiles.
fn latency(seconds: u64) {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    let samples: Samples = Arc::default();
    let rig = rt.block_on(rig_with_clients(&samples, true));
    let sent = rt.block_on(async {
        let mut tick = tokio::time::interval(Duration::from_millis(1));
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Burst);
        let end = Instant::now() + Duration::from_secs(seconds);
        let mut i = 0usize;
        while Instant::now() < end {
            tick.tick().await;
            rig.log(&state(i % VEHICLES, now_ms()));
            i += 1;
        }
        tokio::time::sleep(Duration::from_millis(500)).await;
        i
    });
    let dropped = rig
        .handle
        .stats()
        .slow_clients_dropped
        .load(std::sync::atomic::Ordering::Relaxed);
    rig.handle.stop();
    rt.block_on(async { tokio::time::sleep(Duration::from_millis(200)).await });
    let mut all = rt.block_on(async { samples.lock().await.clone() });
    drop(rt);
    all.sort_unstable();
    let pct = |p: f64| {
        let i = ((all.len() as f64 - 1.0) * p).round() as usize;
        all.get(i).copied().unwrap_or(0) as f64 / 1e6
    };
    // The log time has ms resolution (the sample's own timestamp), so each figure may
    // read up to 1 ms high.
    println!(
        "latency: {VEHICLES} vehicles at 1 Hz to {CLIENTS} clients, {seconds} s: {sent} state \
         vectors, {} messages received of {} expected; p50 {:.2} ms, p99 {:.2} ms, max {:.2} ms \
         (target p99 <= 50 ms); slow clients dropped: {dropped}",
        all.len(),
        sent * 2 * CLIENTS,
        pct(0.5),
        pct(0.99),
        pct(1.0),
    );
}

criterion_group!(benches, encoding, fanout);

fn main() {
    benches();
    Criterion::default().configure_from_args().final_summary();
    let quick = std::env::args().any(|a| a == "--test" || a == "--quick");
    latency(if quick { 1 } else { 10 });
}
