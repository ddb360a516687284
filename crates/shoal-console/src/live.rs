//! `GET /api/ws`: the live feed over a WebSocket, one JSON message per update
//! (`{"type": "event" | "task" | "mission" | "vehicle" | "observation", "data": ...}`).

use axum::extract::State;
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::response::Response;
use shoal_station::StationHandle;
use tokio::sync::broadcast::error::RecvError;
use tracing::{debug, warn};

pub(crate) async fn ws(State(s): State<StationHandle>, upgrade: WebSocketUpgrade) -> Response {
    let rx = s.live();
    upgrade.on_upgrade(move |socket| forward(socket, rx))
}

async fn forward(
    mut socket: WebSocket,
    mut rx: tokio::sync::broadcast::Receiver<shoal_station::LiveUpdate>,
) {
    loop {
        tokio::select! {
            update = rx.recv() => match update {
                Ok(u) => {
                    let text = match serde_json::to_string(&u) {
                        Ok(t) => t,
                        Err(e) => {
                            warn!(error = %e, "live update not encodable");
                            continue;
                        }
                    };
                    if socket.send(Message::Text(text.into())).await.is_err() {
                        break;
                    }
                }
                // A slow client misses updates rather than slowing the station; tell it.
                Err(RecvError::Lagged(n)) => {
                    let note = format!("{{\"type\":\"lagged\",\"data\":{{\"missed\":{n}}}}}");
                    if socket.send(Message::Text(note.into())).await.is_err() {
                        break;
                    }
                }
                Err(RecvError::Closed) => break,
            },
            incoming = socket.recv() => match incoming {
                // Clients only listen; pings are answered by axum, anything else ignored.
                Some(Ok(Message::Close(_)) | Err(_)) | None => break,
                Some(Ok(_)) => {}
            },
        }
    }
    debug!("live client gone");
}
