//! `GET /api/ws`: the live feed over a WebSocket, one JSON message per update
//! (`{"type": "event" | "task" | "mission" | "vehicle" | "observation" | "vessel" |
//! "vessel_gone", "data": ...}`; `lagged` when a slow client missed some).

use std::sync::Arc;

use axum::extract::State;
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::response::{IntoResponse, Response};
use shoal_station::StationHandle;
use tokio::sync::OwnedSemaphorePermit;
use tokio::sync::broadcast::error::RecvError;
use tracing::{debug, warn};

/// Opens the live feed for one more client, within `[console.limits] max_ws_clients`.
pub(crate) async fn ws(
    State(s): State<StationHandle>,
    State(limits): State<Arc<crate::limits::Limits>>,
    upgrade: WebSocketUpgrade,
) -> Response {
    let place = match limits.ws_client() {
        Ok(p) => p,
        Err(e) => return e.into_response(),
    };
    let rx = s.live();
    upgrade.on_upgrade(move |socket| forward(socket, rx, place))
}

/// Sends updates until the client leaves; `_place` is its place among the clients.
async fn forward(
    mut socket: WebSocket,
    mut rx: tokio::sync::broadcast::Receiver<shoal_station::LiveUpdate>,
    _place: OwnedSemaphorePermit,
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
