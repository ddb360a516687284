//! What the bridge's integration tests share: test participants, a stand-in for the
//! console's `/api/foxglove` route (a WebSocket upgrade in front of the bridge's gateway,
//! with the same subprotocol negotiation), and raw Foxglove clients.
#![allow(
    dead_code,
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    // tungstenite's handshake callback type returns its whole response as the error.
    clippy::result_large_err
)]

use std::net::SocketAddr;
use std::time::Duration;

use futures::{SinkExt, StreamExt};
use shoal_dds::{DdsConfig, PubSub, Writer};
use shoal_foxglove::{BridgeHandle, Frame, negotiate};
use shoal_model::StateVector;
use tokio::net::{TcpListener, TcpStream};
use tokio_tungstenite::tungstenite::handshake::server::{Request, Response};
use tokio_tungstenite::tungstenite::http::HeaderValue;
use tokio_tungstenite::tungstenite::{self, Message};
use tokio_tungstenite::{MaybeTlsStream, WebSocketStream};

/// A participant on `domain_id` (loopback; the tests run in a private namespace).
pub fn pubsub(domain_id: u16) -> PubSub {
    PubSub::new(&DdsConfig {
        domain_id,
        ..DdsConfig::default()
    })
    .expect("a DDS participant")
}

/// A valid state vector.
pub fn state(vehicle_id: &str, timestamp_ms: i64, lat: f64, lon: f64, depth: f64) -> StateVector {
    StateVector {
        vehicle_id: vehicle_id.into(),
        timestamp_ms,
        latitude_deg: lat,
        longitude_deg: lon,
        depth_m: depth,
        altitude_m: -1.0,
        speed_mps: 1.0,
        yaw_deg: 45.0,
        pitch_deg: 0.0,
        roll_deg: 0.0,
        battery_pct: 77.0,
    }
}

/// Waits until `writer` has matched the bridge's reader (10 s at most).
pub async fn wait_matched<T: shoal_dds::TopicType>(writer: &Writer<T>) {
    for _ in 0..200 {
        if writer.matched_readers() > 0 {
            return;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    panic!("no reader matched within 10 s");
}

/// Serves the bridge's gateway on a loopback port, as the console's route does: the
/// upgrade echoes the negotiated subprotocol (refused without one), a place is taken
/// before upgrading, and the upgraded socket is handed to `BridgeHandle::serve`.
pub async fn front(handle: BridgeHandle) -> SocketAddr {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    tokio::spawn(async move {
        while let Ok((stream, _)) = listener.accept().await {
            let handle = handle.clone();
            tokio::spawn(async move {
                let Ok(place) = handle.admit() else {
                    return; // refused: the connection just closes
                };
                let mut chosen = None;
                let callback = |req: &Request, mut res: Response| {
                    let offered = req
                        .headers()
                        .get_all("sec-websocket-protocol")
                        .iter()
                        .filter_map(|v| v.to_str().ok())
                        .collect::<Vec<_>>();
                    match negotiate(offered) {
                        Some(p) => {
                            res.headers_mut().insert(
                                "sec-websocket-protocol",
                                HeaderValue::from_static(p.as_str()),
                            );
                            chosen = Some(p);
                            Ok(res)
                        }
                        None => {
                            let mut refusal = tungstenite::http::Response::new(Some(
                                "no Foxglove subprotocol offered".into(),
                            ));
                            *refusal.status_mut() = tungstenite::http::StatusCode::BAD_REQUEST;
                            Err(refusal)
                        }
                    }
                };
                let Ok(ws) = tokio_tungstenite::accept_hdr_async(stream, callback).await else {
                    return;
                };
                let Some(subprotocol) = chosen else { return };
                let client = shoal_foxglove::adapt(ws, to_tungstenite, from_tungstenite);
                let end = handle.serve(place, client, subprotocol).await;
                println!("front: session ended: {end:?}");
            });
        }
    });
    addr
}

/// A raw Foxglove client connection.
pub type Client = WebSocketStream<MaybeTlsStream<TcpStream>>;

/// Connects to `addr` offering `subprotocol`, over `stream` (so a test can shrink the
/// socket's buffers first).
pub async fn connect_over(stream: TcpStream, addr: SocketAddr, subprotocol: &str) -> Client {
    use tokio_tungstenite::tungstenite::client::IntoClientRequest;
    let mut request = format!("ws://{addr}/api/foxglove")
        .into_client_request()
        .unwrap();
    request.headers_mut().insert(
        "sec-websocket-protocol",
        HeaderValue::from_str(subprotocol).unwrap(),
    );
    let (ws, response) = tokio_tungstenite::client_async(request, MaybeTlsStream::Plain(stream))
        .await
        .unwrap();
    assert_eq!(
        response.headers().get("sec-websocket-protocol").unwrap(),
        subprotocol
    );
    ws
}

/// Reads until the server has advertised `topic`, and returns the channel id.
pub async fn channel_id(ws: &mut Client, topic: &str) -> u64 {
    let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
    loop {
        let msg = tokio::time::timeout_at(deadline, ws.next())
            .await
            .expect("no advertisement within 10 s")
            .expect("connection open")
            .unwrap();
        if let Message::Text(t) = msg {
            let v: serde_json::Value = serde_json::from_str(t.as_str()).unwrap();
            if v["op"] == "advertise" {
                for c in v["channels"].as_array().unwrap() {
                    if c["topic"] == topic {
                        return c["id"].as_u64().unwrap();
                    }
                }
            }
        }
    }
}

/// Subscribes (subscription id `sub`) to channel `channel`.
pub async fn subscribe(ws: &mut Client, sub: u32, channel: u64) {
    let msg = serde_json::json!({
        "op": "subscribe",
        "subscriptions": [{"id": sub, "channelId": channel}],
    });
    ws.send(Message::text(msg.to_string())).await.unwrap();
}

/// Whether a frame is message data (binary opcode 1).
pub fn is_message_data(msg: &Message) -> bool {
    matches!(msg, Message::Binary(b) if b.first() == Some(&1))
}

/// A gateway frame as a tungstenite message.
pub fn to_tungstenite(frame: Frame) -> Message {
    match frame {
        Frame::Text(t) => Message::text(t),
        Frame::Binary(b) => Message::Binary(b),
        Frame::Close => Message::Close(None),
    }
}

/// A tungstenite message as a gateway frame (`None` for pings and pongs).
pub fn from_tungstenite(message: Message) -> Option<Frame> {
    match message {
        Message::Text(t) => Some(Frame::Text(t.as_str().to_owned())),
        Message::Binary(b) => Some(Frame::Binary(b)),
        Message::Close(_) => Some(Frame::Close),
        _ => None,
    }
}
