//! The HTTP server's resource limits (`[console.limits]`) and the counters of each limit
//! hit, shown in `/api/stats` (`http`), `/api/health` and `/metrics`.
//!
//! - connections: at most `max_connections` open at once (WebSocket clients included);
//!   past that, new connections wait in the kernel's backlog ([`serve_connections`]);
//! - slow clients: a request's headers must arrive within `header_read_timeout_s`, or
//!   the connection is closed (hyper's header read timeout; a slowloris client sending a
//!   byte a second is cut off);
//! - requests: at most `max_concurrent_requests` handled at once, each waiting at most
//!   `request_queue_ms` for a turn, and answered within `request_timeout_s`; otherwise
//!   503 with `Retry-After` ([`limit_requests`]). `/api/health` and `/metrics` skip the
//!   queue so monitoring still sees a saturated station;
//! - bodies: at most `max_body_bytes` (413), except a recording opened in the replay
//!   (`POST /api/recordings/tracks`): at most `max_recording_bytes`, and at most
//!   [`MAX_CONCURRENT_RECORDINGS`] read at once, each waiting at most
//!   [`RECORDING_QUEUE`] for a turn (503 with `Retry-After`);
//! - WebSocket clients of `/api/ws`: at most `max_ws_clients`;
//! - SPARQL queries: at most `max_concurrent_sparql` running and `max_queued_sparql`
//!   waiting up to `sparql_queue_ms`; the rest get 503 with `Retry-After` at once.

use std::pin::{Pin, pin};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::task::{Context, Poll};
use std::time::Duration;

use axum::Router;
use axum::extract::{ConnectInfo, Request, State};
use axum::http::StatusCode;
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use serde::{Deserialize, Serialize};
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::TcpListener;
use tokio::sync::{OwnedSemaphorePermit, Semaphore};
use tokio_rustls::TlsAcceptor;
use tokio_util::sync::CancellationToken;
use tower::ServiceExt as _;
use tracing::{debug, warn};

use crate::ApiError;

/// The `[console.limits]` section: bounds on what HTTP clients can make the station hold.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LimitsConfig {
    /// Open connections at most, WebSocket clients included. Default 256.
    pub max_connections: usize,
    /// Seconds a client has to send a request's headers before it is disconnected
    /// (slow clients). Default 10.
    pub header_read_timeout_s: f64,
    /// Requests handled at once at most. Default 64.
    pub max_concurrent_requests: usize,
    /// How long a request waits for a turn before 503, ms. Default 250.
    pub request_queue_ms: u64,
    /// Seconds a request may take to be answered before 503. Default 30.
    pub request_timeout_s: f64,
    /// Largest request body, bytes. Default 1 MiB.
    pub max_body_bytes: usize,
    /// Largest MCAP recording the replay may open (`POST /api/recordings/tracks`), bytes.
    /// Default 64 MiB.
    pub max_recording_bytes: usize,
    /// Live feed (`/api/ws`) clients at most. Default 32.
    pub max_ws_clients: usize,
    /// SPARQL queries running at once at most. Default 2 (one a core of a small station).
    pub max_concurrent_sparql: usize,
    /// SPARQL queries waiting for a turn at most. Default 16.
    pub max_queued_sparql: usize,
    /// How long a SPARQL query waits for a turn before 503, ms. Default 2,000.
    pub sparql_queue_ms: u64,
}

impl Default for LimitsConfig {
    fn default() -> Self {
        Self {
            max_connections: 256,
            header_read_timeout_s: 10.0,
            max_concurrent_requests: 64,
            request_queue_ms: 250,
            request_timeout_s: 30.0,
            max_body_bytes: 1 << 20,
            max_recording_bytes: 64 << 20,
            max_ws_clients: 32,
            max_concurrent_sparql: 2,
            max_queued_sparql: 16,
            sparql_queue_ms: 2_000,
        }
    }
}

/// A duration from seconds in the configuration; negative or not a number is zero.
fn secs(s: f64) -> Duration {
    Duration::try_from_secs_f64(s.max(0.0)).unwrap_or(Duration::MAX)
}

/// How often each limit was hit since the console started.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct LimitHits {
    /// Connections that had to wait because `max_connections` were open.
    pub connections_waited: u64,
    /// Connections closed because their headers came too slowly.
    pub slow_headers_cut: u64,
    /// Requests refused (503) because `max_concurrent_requests` were being handled.
    pub requests_refused: u64,
    /// Requests that took longer than `request_timeout_s` (503).
    pub requests_timed_out: u64,
    /// Requests whose body was over `max_body_bytes` (or a recording over
    /// `max_recording_bytes`) (413).
    pub bodies_too_large: u64,
    /// Live feed clients refused (503) because `max_ws_clients` were connected.
    pub ws_refused: u64,
    /// SPARQL queries refused (503) because the queue was full or the wait too long.
    pub sparql_refused: u64,
    /// Recordings refused (503) because others were being read for too long.
    pub recordings_refused: u64,
}

impl LimitHits {
    /// Each count with the name `/metrics` labels it with.
    pub fn labelled(&self) -> [(&'static str, u64); 8] {
        [
            ("connections", self.connections_waited),
            ("slow_headers", self.slow_headers_cut),
            ("requests", self.requests_refused),
            ("request_timeout", self.requests_timed_out),
            ("body_size", self.bodies_too_large),
            ("ws_clients", self.ws_refused),
            ("sparql", self.sparql_refused),
            ("recordings", self.recordings_refused),
        ]
    }
}

/// What is in use now, against its limit.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct InUse {
    /// Open connections.
    pub connections: usize,
    /// Live feed clients.
    pub ws_clients: usize,
    /// SPARQL queries running.
    pub sparql_running: usize,
    /// SPARQL queries waiting for a turn.
    pub sparql_queued: usize,
}

#[derive(Debug, Default)]
struct Counters {
    connections_waited: AtomicU64,
    slow_headers_cut: AtomicU64,
    requests_refused: AtomicU64,
    requests_timed_out: AtomicU64,
    bodies_too_large: AtomicU64,
    ws_refused: AtomicU64,
    sparql_refused: AtomicU64,
    recordings_refused: AtomicU64,
}

fn bump(c: &AtomicU64) {
    c.fetch_add(1, Ordering::Relaxed);
}

/// The limits in force and their counters; one per console, shared by the server loop
/// and the router.
#[derive(Debug)]
pub(crate) struct Limits {
    pub(crate) config: LimitsConfig,
    connections: Arc<Semaphore>,
    requests: Arc<Semaphore>,
    ws: Arc<Semaphore>,
    sparql: Arc<Semaphore>,
    sparql_waiting: AtomicUsize,
    recordings: Arc<Semaphore>,
    hits: Counters,
}

/// Recordings read at once at most (`POST /api/recordings/tracks`): each holds its body
/// (up to `max_recording_bytes`) and what is read from it, so a few concurrent uploads
/// must not add up to gigabytes.
pub const MAX_CONCURRENT_RECORDINGS: usize = 2;

/// How long a recording waits for a turn before 503.
pub const RECORDING_QUEUE: Duration = Duration::from_secs(2);

/// Semaphores refuse more permits than this; a larger configured limit means "as many as
/// that", which no station reaches.
fn permits(n: usize) -> usize {
    n.min(Semaphore::MAX_PERMITS)
}

impl Limits {
    pub(crate) fn new(config: LimitsConfig) -> Self {
        Self {
            connections: Arc::new(Semaphore::new(permits(config.max_connections))),
            requests: Arc::new(Semaphore::new(permits(config.max_concurrent_requests))),
            ws: Arc::new(Semaphore::new(permits(config.max_ws_clients))),
            sparql: Arc::new(Semaphore::new(permits(config.max_concurrent_sparql))),
            sparql_waiting: AtomicUsize::new(0),
            recordings: Arc::new(Semaphore::new(MAX_CONCURRENT_RECORDINGS)),
            hits: Counters::default(),
            config,
        }
    }

    /// The counters now.
    pub(crate) fn hits(&self) -> LimitHits {
        let h = &self.hits;
        let get = |c: &AtomicU64| c.load(Ordering::Relaxed);
        LimitHits {
            connections_waited: get(&h.connections_waited),
            slow_headers_cut: get(&h.slow_headers_cut),
            requests_refused: get(&h.requests_refused),
            requests_timed_out: get(&h.requests_timed_out),
            bodies_too_large: get(&h.bodies_too_large),
            ws_refused: get(&h.ws_refused),
            sparql_refused: get(&h.sparql_refused),
            recordings_refused: get(&h.recordings_refused),
        }
    }

    /// What is in use now.
    pub(crate) fn in_use(&self) -> InUse {
        let used = |s: &Semaphore, max: usize| permits(max).saturating_sub(s.available_permits());
        let c = &self.config;
        InUse {
            connections: used(&self.connections, c.max_connections),
            ws_clients: used(&self.ws, c.max_ws_clients),
            sparql_running: used(&self.sparql, c.max_concurrent_sparql),
            sparql_queued: self.sparql_waiting.load(Ordering::Relaxed),
        }
    }

    /// A place for one more live feed client, or 503.
    pub(crate) fn ws_client(&self) -> Result<OwnedSemaphorePermit, ApiError> {
        self.ws.clone().try_acquire_owned().map_err(|_| {
            bump(&self.hits.ws_refused);
            ApiError::Busy(format!(
                "the live feed has its {} clients; try again later",
                self.config.max_ws_clients
            ))
        })
    }

    /// A turn to run one SPARQL query: waits in a bounded queue for a bounded time, or 503.
    pub(crate) async fn sparql_turn(&self) -> Result<OwnedSemaphorePermit, ApiError> {
        if let Ok(p) = self.sparql.clone().try_acquire_owned() {
            return Ok(p);
        }
        let refuse = |why: String| {
            bump(&self.hits.sparql_refused);
            ApiError::Busy(why)
        };
        let waiting = self.sparql_waiting.fetch_add(1, Ordering::Relaxed);
        // Decrements on every way out, a cancelled request included.
        let _queued = Dequeue(&self.sparql_waiting);
        if waiting >= self.config.max_queued_sparql {
            return Err(refuse(format!(
                "{} SPARQL queries are waiting already; try again later",
                self.config.max_queued_sparql
            )));
        }
        let wait = Duration::from_millis(self.config.sparql_queue_ms);
        match tokio::time::timeout(wait, self.sparql.clone().acquire_owned()).await {
            Ok(Ok(p)) => Ok(p),
            _ => Err(refuse(format!(
                "no SPARQL query finished within {} ms; try again later",
                self.config.sparql_queue_ms
            ))),
        }
    }

    /// A turn to read one recording, waiting at most [`RECORDING_QUEUE`], or 503.
    pub(crate) async fn recording_turn(&self) -> Result<OwnedSemaphorePermit, ApiError> {
        match tokio::time::timeout(RECORDING_QUEUE, self.recordings.clone().acquire_owned()).await {
            Ok(Ok(p)) => Ok(p),
            _ => {
                bump(&self.hits.recordings_refused);
                Err(ApiError::Busy(format!(
                    "{MAX_CONCURRENT_RECORDINGS} recordings are being read already; try again shortly"
                )))
            }
        }
    }
}

struct Dequeue<'a>(&'a AtomicUsize);

impl Drop for Dequeue<'_> {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::Relaxed);
    }
}

/// Bounds concurrent requests and their time, and counts bodies refused as too large.
pub(crate) async fn limit_requests(
    State(limits): State<Arc<Limits>>,
    req: Request,
    next: Next,
) -> Response {
    let path = req.uri().path();
    let queued = !matches!(path, "/api/health" | "/metrics");
    let _turn = if queued {
        let wait = Duration::from_millis(limits.config.request_queue_ms);
        match tokio::time::timeout(wait, limits.requests.clone().acquire_owned()).await {
            Ok(Ok(p)) => Some(p),
            _ => {
                bump(&limits.hits.requests_refused);
                return ApiError::Busy(format!(
                    "the station is answering {} requests already; try again later",
                    limits.config.max_concurrent_requests
                ))
                .into_response();
            }
        }
    } else {
        None
    };
    let timeout = secs(limits.config.request_timeout_s);
    let Ok(res) = tokio::time::timeout(timeout, next.run(req)).await else {
        bump(&limits.hits.requests_timed_out);
        return ApiError::Busy(format!(
            "the request took longer than {} s",
            limits.config.request_timeout_s
        ))
        .into_response();
    };
    if res.status() == StatusCode::PAYLOAD_TOO_LARGE {
        bump(&limits.hits.bodies_too_large);
    }
    res
}

/// A connection's socket (plain or TLS) holding its place among the `max_connections`;
/// the place is given back when the socket is dropped, after a WebSocket upgrade too.
struct Counted<I> {
    io: I,
    _place: OwnedSemaphorePermit,
}

impl<I: AsyncRead + Unpin> AsyncRead for Counted<I> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.io).poll_read(cx, buf)
    }
}

impl<I: AsyncWrite + Unpin> AsyncWrite for Counted<I> {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        Pin::new(&mut self.io).poll_write(cx, buf)
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[std::io::IoSlice<'_>],
    ) -> Poll<std::io::Result<usize>> {
        Pin::new(&mut self.io).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.io.is_write_vectored()
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.io).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.io).poll_shutdown(cx)
    }
}

/// How long open connections get to finish their requests once shutdown is asked.
const SHUTDOWN_GRACE: Duration = Duration::from_secs(5);

/// Serves `router` on `listener` until `shutdown`, within `limits`: HTTP/1.1 (over TLS
/// when `tls` is given) with WebSocket upgrades, a place among `max_connections` per
/// connection and hyper's header read timeout for slow clients. Each request carries the
/// client's address as [`ConnectInfo`] (the login rate limits count by it).
pub(crate) async fn serve_connections(
    listener: TcpListener,
    router: Router,
    limits: Arc<Limits>,
    tls: Option<TlsAcceptor>,
    shutdown: CancellationToken,
) -> std::io::Result<()> {
    let mut http = hyper::server::conn::http1::Builder::new();
    http.timer(hyper_util::rt::TokioTimer::new())
        .header_read_timeout(secs(limits.config.header_read_timeout_s));
    // Every connection task holds a sender; when all are gone, the receiver says so.
    let (open_tx, mut all_closed) = tokio::sync::mpsc::channel::<()>(1);
    loop {
        let place = match limits.connections.clone().try_acquire_owned() {
            Ok(p) => p,
            Err(_) => {
                bump(&limits.hits.connections_waited);
                debug!("console connections at their limit; new ones wait");
                tokio::select! {
                    p = limits.connections.clone().acquire_owned() => match p {
                        Ok(p) => p,
                        Err(_) => break,
                    },
                    () = shutdown.cancelled() => break,
                }
            }
        };
        let (tcp, peer) = tokio::select! {
            accepted = listener.accept() => match accepted {
                Ok(a) => a,
                Err(e) => {
                    // Out of file descriptors, say: pause instead of spinning.
                    warn!(error = %e, "console cannot accept a connection");
                    tokio::time::sleep(Duration::from_millis(50)).await;
                    continue;
                }
            },
            () = shutdown.cancelled() => break,
        };
        // Live updates are small writes: with Nagle's algorithm on, each one after an
        // unacknowledged one waited for the client's delayed ACK (40 ms on Linux), which
        // was the whole tail of the vehicle → console latency.
        if let Err(e) = tcp.set_nodelay(true) {
            warn!(error = %e, "cannot set TCP_NODELAY on a console connection");
        }
        let service = router
            .clone()
            .map_request(move |mut req: Request<hyper::body::Incoming>| {
                req.extensions_mut().insert(ConnectInfo(peer));
                req
            });
        let service = hyper_util::service::TowerToHyperService::new(service);
        let (http, tls, limits, shutdown, open) = (
            http.clone(),
            tls.clone(),
            limits.clone(),
            shutdown.clone(),
            open_tx.clone(),
        );
        tokio::spawn(async move {
            match tls {
                None => {
                    let io = Counted {
                        io: tcp,
                        _place: place,
                    };
                    serve_one(&http, io, service, &limits, &shutdown).await;
                }
                Some(acceptor) => {
                    // The handshake is bounded like the headers: a client that opens a
                    // connection and sends nothing must not hold its place.
                    let wait = secs(limits.config.header_read_timeout_s);
                    match tokio::time::timeout(wait, acceptor.accept(tcp)).await {
                        Ok(Ok(stream)) => {
                            let io = Counted {
                                io: stream,
                                _place: place,
                            };
                            serve_one(&http, io, service, &limits, &shutdown).await;
                        }
                        Ok(Err(e)) => debug!(error = %e, %peer, "TLS handshake failed"),
                        Err(_) => {
                            bump(&limits.hits.slow_headers_cut);
                            debug!(%peer, "TLS handshake too slow; connection closed");
                        }
                    }
                }
            }
            drop(open);
        });
    }
    drop(open_tx);
    if tokio::time::timeout(SHUTDOWN_GRACE, all_closed.recv())
        .await
        .is_err()
    {
        warn!("console connections still open after the shutdown grace; closing");
    }
    Ok(())
}

/// Serves one connection until it ends or, after `shutdown`, until its requests are done.
async fn serve_one<I, S>(
    http: &hyper::server::conn::http1::Builder,
    io: I,
    service: S,
    limits: &Limits,
    shutdown: &CancellationToken,
) where
    I: AsyncRead + AsyncWrite + Unpin + Send + 'static,
    S: hyper::service::Service<
            hyper::Request<hyper::body::Incoming>,
            Response = hyper::Response<axum::body::Body>,
        > + Send,
    S::Future: Send + 'static,
    S::Error: Into<Box<dyn std::error::Error + Send + Sync>>,
{
    let conn = http
        .serve_connection(hyper_util::rt::TokioIo::new(io), service)
        .with_upgrades();
    let mut conn = pin!(conn);
    let done = tokio::select! {
        done = conn.as_mut() => done,
        () = shutdown.cancelled() => {
            conn.as_mut().graceful_shutdown();
            conn.await
        }
    };
    if let Err(e) = done {
        if e.is_timeout() {
            bump(&limits.hits.slow_headers_cut);
            debug!("console connection closed: its headers came too slowly");
        } else {
            debug!(error = %e, "console connection ended with an error");
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[tokio::test(start_paused = true)]
    async fn sparql_queue_is_bounded_and_refusals_counted() {
        let limits = Arc::new(Limits::new(LimitsConfig {
            max_concurrent_sparql: 1,
            max_queued_sparql: 1,
            sparql_queue_ms: 100,
            ..LimitsConfig::default()
        }));
        let running = limits.sparql_turn().await.unwrap();
        let l = limits.clone();
        let queued = tokio::spawn(async move { l.sparql_turn().await.map(drop) });
        tokio::task::yield_now().await;
        assert_eq!(limits.in_use().sparql_queued, 1);
        // The queue is full: refused at once.
        assert!(matches!(limits.sparql_turn().await, Err(ApiError::Busy(_))));
        // The queued one waits its 100 ms, then is refused too.
        assert!(matches!(queued.await.unwrap(), Err(ApiError::Busy(_))));
        assert_eq!(limits.hits().sparql_refused, 2);
        assert_eq!(limits.in_use().sparql_queued, 0);
        drop(running);
        assert!(limits.sparql_turn().await.is_ok());
    }

    #[test]
    fn ws_clients_beyond_the_limit_are_refused() {
        let limits = Limits::new(LimitsConfig {
            max_ws_clients: 1,
            ..LimitsConfig::default()
        });
        let first = limits.ws_client().unwrap();
        assert!(limits.ws_client().is_err());
        assert_eq!(limits.hits().ws_refused, 1);
        assert_eq!(limits.in_use().ws_clients, 1);
        drop(first);
        assert!(limits.ws_client().is_ok());
    }
}
