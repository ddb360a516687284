//! The gateway between an authenticated client connection (the console's
//! `/api/foxglove` upgrade) and the SDK's loopback server: it negotiates the
//! subprotocol, enforces the client limit, and drops a client that reads too slowly
//! instead of buffering for it.
//!
//! The SDK's server cannot check the upgrade request (no token, no Origin), and for a
//! slow client it only drops the oldest of its queued messages, keeping the client
//! connected (its data queue is bounded, but nothing ever gives up on the client); so
//! clients never reach it directly.

use std::sync::atomic::Ordering;
use std::time::Duration;

use bytes::Bytes;
use futures::{Sink, SinkExt, Stream, StreamExt};
use tokio::sync::{OwnedSemaphorePermit, mpsc};
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::http::HeaderValue;
use tokio_tungstenite::tungstenite::protocol::WebSocketConfig;
use tracing::{debug, info, warn};

use crate::BridgeError;
use crate::bridge::BridgeHandle;

/// A WebSocket subprotocol a Foxglove client may offer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Subprotocol {
    /// `foxglove.sdk.v1.1`: advertisements refer to a per-connection schema table.
    SdkV1_1,
    /// `foxglove.sdk.v1`: advertisements carry their schemas inline.
    SdkV1,
    /// `foxglove.websocket.v1`: the protocol's older name (the `@foxglove/ws-protocol`
    /// client and older apps); the same messages as `foxglove.sdk.v1`.
    WebsocketV1,
}

impl Subprotocol {
    /// The name as it goes in `Sec-WebSocket-Protocol`.
    pub const fn as_str(self) -> &'static str {
        match self {
            Self::SdkV1_1 => "foxglove.sdk.v1.1",
            Self::SdkV1 => "foxglove.sdk.v1",
            Self::WebsocketV1 => "foxglove.websocket.v1",
        }
    }

    /// What the gateway asks of the SDK's server for a client that chose `self`.
    const fn upstream(self) -> &'static str {
        match self {
            Self::SdkV1_1 => "foxglove.sdk.v1.1",
            Self::SdkV1 | Self::WebsocketV1 => "foxglove.sdk.v1",
        }
    }

    fn from_name(name: &str) -> Option<Self> {
        [Self::SdkV1_1, Self::SdkV1, Self::WebsocketV1]
            .into_iter()
            .find(|p| p.as_str() == name)
    }

    fn rank(self) -> u8 {
        match self {
            Self::SdkV1_1 => 3,
            Self::SdkV1 => 2,
            Self::WebsocketV1 => 1,
        }
    }
}

/// The newest subprotocol among those a client offered (the values of its
/// `Sec-WebSocket-Protocol` headers, comma-separated), or `None` when it offered none
/// the bridge speaks: the upgrade is then refused.
pub fn negotiate<'a>(offered: impl IntoIterator<Item = &'a str>) -> Option<Subprotocol> {
    offered
        .into_iter()
        .flat_map(|h| h.split(','))
        .filter_map(|name| Subprotocol::from_name(name.trim()))
        .max_by_key(|p| p.rank())
}

/// One WebSocket message between a client and the bridge; pings and pongs stay with
/// each side's WebSocket library.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Frame {
    /// A JSON control message.
    Text(String),
    /// A binary message (message data, time).
    Binary(Bytes),
    /// The peer closes.
    Close,
}

/// Makes a WebSocket of any library (`M` its message type) a connection the gateway
/// can serve: `to` turns a [`Frame`] into its message, `from` a message into a frame
/// (`None` for what the gateway does not forward: pings, pongs).
pub fn adapt<S, M, E>(
    socket: S,
    to: fn(Frame) -> M,
    from: fn(M) -> Option<Frame>,
) -> impl Stream<Item = Result<Frame, E>> + Sink<Frame, Error = E> + Send + Unpin
where
    S: Stream<Item = Result<M, E>> + Sink<M, Error = E> + Send + Unpin,
    M: Send,
    E: Send,
{
    socket
        .with(move |f: Frame| futures::future::ready(Ok::<M, E>(to(f))))
        .filter_map(move |m| {
            futures::future::ready(match m {
                Ok(m) => from(m).map(Ok),
                Err(e) => Some(Err(e)),
            })
        })
}

/// A client's place among the bridge's `max_clients`; freed when dropped.
#[derive(Debug)]
pub struct ClientPlace(#[allow(dead_code)] OwnedSemaphorePermit);

/// Why a client's session ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SessionEnd {
    /// The client closed or went away.
    ClientLeft,
    /// The client read too slowly and was dropped.
    TooSlow,
    /// The SDK's server closed (the bridge is stopping).
    ServerClosed,
    /// The bridge stopped.
    Stopped,
}

impl BridgeHandle {
    /// A place for one more client, or [`BridgeError::Busy`] when `max_clients` are
    /// connected. Take it before upgrading, so a refused client gets a plain 503.
    pub fn admit(&self) -> Result<ClientPlace, BridgeError> {
        match self.shared.places.clone().try_acquire_owned() {
            Ok(p) => Ok(ClientPlace(p)),
            Err(_) => {
                self.shared
                    .stats
                    .clients_refused
                    .fetch_add(1, Ordering::Relaxed);
                Err(BridgeError::Busy(self.shared.config.max_clients))
            }
        }
    }

    /// Serves one upgraded, authenticated client connection until it ends: connects to
    /// the SDK's server with the subprotocol the client chose (see [`negotiate`]) and
    /// pipes frames both ways. Messages toward the client wait in a queue of
    /// `client_queue`; a client that leaves it full, or takes one message, for longer
    /// than `send_timeout_ms` is dropped.
    pub async fn serve<S, E>(
        &self,
        place: ClientPlace,
        client: S,
        subprotocol: Subprotocol,
    ) -> Result<SessionEnd, BridgeError>
    where
        S: Stream<Item = Result<Frame, E>> + Sink<Frame, Error = E> + Send + Unpin,
        E: std::fmt::Display,
    {
        let shared = &self.shared;
        let config = &shared.config;
        let mut request = format!("ws://{}/", shared.internal)
            .into_client_request()
            .map_err(|e| BridgeError::Upstream(e.to_string()))?;
        request.headers_mut().insert(
            "sec-websocket-protocol",
            HeaderValue::from_static(subprotocol.upstream()),
        );
        let ws_config = WebSocketConfig::default()
            .max_message_size(Some(config.max_client_message_bytes.max(64 << 20)));
        let (upstream, _) =
            tokio_tungstenite::connect_async_with_config(request, Some(ws_config), true)
                .await
                .map_err(|e| BridgeError::Upstream(e.to_string()))?;
        shared.stats.clients_served.fetch_add(1, Ordering::Relaxed);
        let (mut up_tx, mut up_rx) = upstream.split();
        let (mut cl_tx, mut cl_rx) = client.split();
        let (queue_tx, mut queue_rx) = mpsc::channel::<Frame>(config.client_queue);
        let send_timeout = Duration::from_millis(config.send_timeout_ms);
        let max_in = config.max_client_message_bytes;

        // Upstream to the queue.
        let from_server = async {
            while let Some(msg) = up_rx.next().await {
                let frame = match msg {
                    Ok(Message::Text(t)) => Frame::Text(t.as_str().to_owned()),
                    Ok(Message::Binary(b)) => Frame::Binary(b),
                    Ok(Message::Close(_)) | Err(_) => return SessionEnd::ServerClosed,
                    Ok(_) => continue,
                };
                // A full queue may be a burst the client is still taking: wait for room,
                // but no longer than one send may take. Meanwhile the SDK's own bounded
                // queue holds what comes (dropping its oldest), so nothing grows.
                match tokio::time::timeout(send_timeout, queue_tx.send(frame)).await {
                    Ok(Ok(())) => {}
                    Ok(Err(_)) => return SessionEnd::ClientLeft,
                    Err(_) => return SessionEnd::TooSlow,
                }
            }
            SessionEnd::ServerClosed
        };
        // The queue to the client, each message within the send timeout.
        let to_client = async {
            while let Some(frame) = queue_rx.recv().await {
                match tokio::time::timeout(send_timeout, cl_tx.send(frame)).await {
                    Ok(Ok(())) => {}
                    Ok(Err(e)) => {
                        debug!(error = %e, "Foxglove client connection failed");
                        return SessionEnd::ClientLeft;
                    }
                    Err(_) => return SessionEnd::TooSlow,
                }
            }
            SessionEnd::ServerClosed
        };
        // The client's requests (subscribe, unsubscribe) to the server.
        let from_client = async {
            while let Some(frame) = cl_rx.next().await {
                let msg = match frame {
                    Ok(Frame::Text(t)) if t.len() <= max_in => Message::text(t),
                    Ok(Frame::Binary(b)) if b.len() <= max_in => Message::Binary(b),
                    Ok(Frame::Close) | Err(_) => return SessionEnd::ClientLeft,
                    Ok(_) => {
                        warn!(max_in, "Foxglove client sent an oversized message: dropped");
                        return SessionEnd::ClientLeft;
                    }
                };
                if up_tx.send(msg).await.is_err() {
                    return SessionEnd::ServerClosed;
                }
            }
            SessionEnd::ClientLeft
        };
        let end = tokio::select! {
            end = from_server => end,
            end = to_client => end,
            end = from_client => end,
            () = shared.cancel.cancelled() => SessionEnd::Stopped,
        };
        if end == SessionEnd::TooSlow {
            shared
                .stats
                .slow_clients_dropped
                .fetch_add(1, Ordering::Relaxed);
            info!(
                queue = config.client_queue,
                send_timeout_ms = config.send_timeout_ms,
                "Foxglove client dropped: it reads too slowly"
            );
        } else {
            debug!(?end, "Foxglove client session ended");
        }
        drop(place);
        Ok(end)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_newest_offered_subprotocol_wins_and_unknown_ones_are_refused() {
        assert_eq!(
            negotiate(["foxglove.websocket.v1"]),
            Some(Subprotocol::WebsocketV1)
        );
        assert_eq!(
            negotiate(["foxglove.websocket.v1, foxglove.sdk.v1"]),
            Some(Subprotocol::SdkV1)
        );
        assert_eq!(
            negotiate(["foxglove.sdk.v1", "foxglove.sdk.v1.1"]),
            Some(Subprotocol::SdkV1_1)
        );
        assert_eq!(negotiate(["foxglove.sdk.v1.10", "chat"]), None);
        assert_eq!(negotiate([]), None);
        assert_eq!(Subprotocol::WebsocketV1.upstream(), "foxglove.sdk.v1");
    }
}
