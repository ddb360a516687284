//! Shoal's Mission Management Tool: the station's HTTP API and the web console over it.
//!
//! - [`router`] builds the axum router over a [`StationHandle`] without authentication;
//!   [`console_router`] takes an [`Auth`] store. Tests drive both without sockets.
//! - [`serve_with`] runs it on a listener until shutdown, with the `[console]` configuration
//!   ([`ConsoleConfig`], authentication included); [`serve`] uses the defaults.
//! - Every request must name this console in `Host` (`[console] allowed_hosts`, against
//!   DNS rebinding); WebSocket handshakes and state-changing requests from a browser must
//!   come from its own origin (or `allowed_origins`), and on a session cookie carry its
//!   CSRF token; logins are rate-limited ([`gate`], [`auth`]). Optional TLS: [`tls`].
//! - [`LimitsConfig`] (`[console.limits]`) bounds connections, slow clients, requests,
//!   bodies, live feed clients and SPARQL queries ([`limits`]); each limit hit is counted
//!   in `/api/stats`, `/api/health` and `/metrics`.
//! - `/api/health` answers 503 when the station is degraded by the thresholds of
//!   [`HealthConfig`] (`[console.health]`); `/metrics` serves the same figures and the
//!   ingest counters to Prometheus.
//! - [`ApiError`] is the one error type: client errors are explained in a JSON body,
//!   internal ones are logged and hidden.
//!
//! `GET /` is the web console (built from `web/` by `build.rs` and embedded), `GET
//! /status.html` a plain status page that needs no JavaScript. The JSON API is under
//! `/api/` and described in `openapi.json` (served at `/api/openapi.json`): fleet,
//! vehicles and their tracks, events and acknowledgement, tasks, missions (plan, start,
//! abort, abort all, CSV/GeoJSON export), the vehicles able to do a task (from the semantic
//! model), rules, environment subscriptions, SPARQL, the tracks of an MCAP recording for
//! the replay (`POST /api/recordings/tracks`), the acoustic network for the map
//! (`/api/acoustic`), the live WebSocket `/api/ws`, and logins
//! (`/api/auth/...`, see [`auth`]).

#![forbid(unsafe_code)]

use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4};
use std::sync::Arc;
use std::time::{Duration, Instant};

use axum::extract::{ConnectInfo, FromRef, Path, Query, Request, State};
use axum::http::{HeaderMap, Method, StatusCode, header};
use axum::middleware::Next;
use axum::response::{Html, IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Extension, Json, Router};
use serde::{Deserialize, Serialize};
use shoal_model::TaskAssignment;
use shoal_station::{
    DispatchError, EnvSubscriptionSpec, MissionSpec, RuleChangeError, RuleDoc, StationHandle,
};
use tokio::sync::Semaphore;
use tokio_util::sync::CancellationToken;
use tracing::{error, info, warn};

use crate::extract::ApiJson;

mod acoustic;
pub mod auth;
mod capable;
pub mod export;
mod extract;
mod federation;
mod foxglove;
mod gate;
mod health;
pub mod limits;
mod live;
mod metrics;
mod negotiate;
mod recording;
mod sparql;
pub mod tls;
mod traffic;
pub mod web;

pub use auth::{Auth, AuthConfig, AuthError, Identity, Role};
pub use gate::Refusals;
use gate::{Gate, Refused};
pub use health::HealthConfig;
use limits::Limits;
pub use limits::{LimitHits, LimitsConfig};
pub use tls::{TlsConfig, TlsError};

/// The `[console]` section of Shoal's configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ConsoleConfig {
    /// Address the console and its API listen on; loopback by default.
    pub listen: SocketAddr,
    /// Host names (`name` for any port, or `name:port`) the console answers to besides
    /// the listen address, `localhost`, `127.0.0.1` and `[::1]` on its port; others get
    /// 421 (DNS rebinding). `"*"` turns the check off.
    pub allowed_hosts: Vec<String>,
    /// Origins (`https://ops.example.org`) besides the console's own from which browsers
    /// may open the live feed or change anything; others get 403.
    pub allowed_origins: Vec<String>,
    /// Logins, roles and API tokens (`[console.auth]`); on by default.
    pub auth: AuthConfig,
    /// HTTPS (`[console.tls]`); off by default.
    pub tls: TlsConfig,
    /// Bounds on connections, requests, bodies, live feed clients and SPARQL queries
    /// (`[console.limits]`).
    pub limits: LimitsConfig,
    /// When `/api/health` answers 503 (`[console.health]`).
    pub health: HealthConfig,
}

impl Default for ConsoleConfig {
    fn default() -> Self {
        Self {
            listen: SocketAddr::V4(SocketAddrV4::new(Ipv4Addr::LOCALHOST, 8640)),
            allowed_hosts: Vec::new(),
            allowed_origins: Vec::new(),
            auth: AuthConfig::default(),
            tls: TlsConfig::default(),
            limits: LimitsConfig::default(),
            health: HealthConfig::default(),
        }
    }
}

/// Why the console cannot start.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ConsoleError {
    /// The users file of `[console.auth]` cannot be used.
    #[error("console authentication: {0}")]
    Auth(#[from] AuthError),
    /// The server failed.
    #[error("console server: {0}")]
    Io(#[from] std::io::Error),
    /// `[console.tls]` cannot be used.
    #[error(transparent)]
    Tls(#[from] TlsError),
}

/// The API's error: a status and a message for the client.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ApiError {
    /// The request is wrong; the message says how.
    #[error("{0}")]
    BadRequest(String),
    /// No such thing.
    #[error("{0}")]
    NotFound(String),
    /// The request conflicts with what exists (a duplicate id, deleting a built-in).
    #[error("{0}")]
    Conflict(String),
    /// No valid credentials: log in or send a token.
    #[error("{0}")]
    Unauthorized(String),
    /// The credentials are valid but their role may not do this, or the request came from
    /// another site's page.
    #[error("{0}")]
    Forbidden(String),
    /// The `Host` is not one this console answers to (421).
    #[error("{0}")]
    Misdirected(String),
    /// Too many failed logins lately; try again after `retry_after_s` (429).
    #[error("{message}")]
    TooManyRequests {
        /// What to tell the client.
        message: String,
        /// Seconds until an attempt may succeed.
        retry_after_s: u64,
    },
    /// The request was right but could not be answered in time.
    #[error("{0}")]
    Unavailable(String),
    /// A limit of `[console.limits]` is reached; the client should try again shortly
    /// (503 with `Retry-After`).
    #[error("{0}")]
    Busy(String),
    /// The request accepts no format the answer can be sent in; the message lists them.
    #[error("{0}")]
    NotAcceptable(String),
    /// The body is too large.
    #[error("{0}")]
    PayloadTooLarge(String),
    /// The body is not sent in a media type this operation reads.
    #[error("{0}")]
    UnsupportedMediaType(String),
    /// The body is well-formed JSON of the wrong shape (a missing or unknown member).
    #[error("{0}")]
    Unprocessable(String),
    /// The station failed; details are logged, not shown.
    #[error("internal error")]
    Internal(String),
}

#[derive(Serialize)]
struct ErrorBody<'a> {
    error: &'a str,
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let status = match &self {
            Self::BadRequest(_) => StatusCode::BAD_REQUEST,
            Self::NotFound(_) => StatusCode::NOT_FOUND,
            Self::Conflict(_) => StatusCode::CONFLICT,
            Self::Unauthorized(_) => StatusCode::UNAUTHORIZED,
            Self::Forbidden(_) => StatusCode::FORBIDDEN,
            Self::Misdirected(_) => StatusCode::MISDIRECTED_REQUEST,
            Self::TooManyRequests { .. } => StatusCode::TOO_MANY_REQUESTS,
            Self::Unavailable(_) | Self::Busy(_) => StatusCode::SERVICE_UNAVAILABLE,
            Self::NotAcceptable(_) => StatusCode::NOT_ACCEPTABLE,
            Self::PayloadTooLarge(_) => StatusCode::PAYLOAD_TOO_LARGE,
            Self::UnsupportedMediaType(_) => StatusCode::UNSUPPORTED_MEDIA_TYPE,
            Self::Unprocessable(_) => StatusCode::UNPROCESSABLE_ENTITY,
            Self::Internal(detail) => {
                error!(%detail, "API request failed");
                StatusCode::INTERNAL_SERVER_ERROR
            }
        };
        let msg = self.to_string();
        let mut res = (status, Json(ErrorBody { error: &msg })).into_response();
        if matches!(self, Self::Busy(_)) {
            // A second is long enough for a running query or request to finish.
            res.headers_mut()
                .insert(header::RETRY_AFTER, header::HeaderValue::from_static("1"));
        }
        if let Self::TooManyRequests { retry_after_s, .. } = self {
            res.headers_mut().insert(
                header::RETRY_AFTER,
                header::HeaderValue::from(retry_after_s),
            );
        }
        res
    }
}

/// What every handler can reach: the station, the authentication store, the limits and
/// what health needs.
#[derive(Debug, Clone)]
pub(crate) struct AppState {
    station: StationHandle,
    auth: Arc<Auth>,
    limits: Arc<Limits>,
    health: Arc<HealthConfig>,
    commits: Arc<health::CommitClock>,
    gate: Arc<Gate>,
    logins: Arc<Logins>,
    /// The Foxglove live bridge, when `[foxglove] enabled`.
    foxglove: Option<shoal_foxglove::BridgeHandle>,
}

/// What bounds logins: failures per address and name, and concurrent password hashes.
#[derive(Debug)]
struct Logins {
    throttle: auth::LoginThrottle,
    hashes: Arc<Semaphore>,
    hash_queue: Duration,
}

impl Logins {
    fn new(config: &AuthConfig) -> Self {
        Self {
            throttle: auth::LoginThrottle::new(
                config.max_failed_logins,
                Duration::from_secs(config.failed_login_window_s),
            ),
            hashes: Arc::new(Semaphore::new(config.max_concurrent_hashes.clamp(1, 64))),
            hash_queue: Duration::from_millis(config.hash_queue_ms),
        }
    }

    /// A turn to compute one password hash, waiting at most `hash_queue_ms`, or 503: a
    /// flood of logins waits here instead of filling the blocking thread pool.
    async fn hash_turn(&self, gate: &Gate) -> Result<tokio::sync::OwnedSemaphorePermit, ApiError> {
        match tokio::time::timeout(self.hash_queue, self.hashes.clone().acquire_owned()).await {
            Ok(Ok(p)) => Ok(p),
            _ => {
                gate.count(Refused::LoginBusy);
                Err(ApiError::Busy(
                    "too many logins at once; try again shortly".into(),
                ))
            }
        }
    }
}

impl FromRef<AppState> for Arc<Limits> {
    fn from_ref(app: &AppState) -> Self {
        app.limits.clone()
    }
}

impl FromRef<AppState> for StationHandle {
    fn from_ref(app: &AppState) -> Self {
        app.station.clone()
    }
}

impl FromRef<AppState> for Arc<Auth> {
    fn from_ref(app: &AppState) -> Self {
        app.auth.clone()
    }
}

/// Builds the console and API router over a running station, without authentication.
pub fn router(station: StationHandle) -> Router {
    console_router(station, Arc::new(Auth::disabled()))
}

/// Builds the console and API router; `auth` decides who may do what. The limits and
/// health thresholds are the defaults.
pub fn console_router(station: StationHandle, auth: Arc<Auth>) -> Router {
    console_router_with(station, auth, &ConsoleConfig::default())
}

/// Builds the console and API router with `config`'s limits, health thresholds, allowed
/// hosts and origins and login limits, as if served on `config.listen` (over TLS when
/// `config.tls` names files; `config.auth` is the caller's: `auth` is loaded already).
/// Without [`serve_with`]'s server loop, the connection limits do not apply.
pub fn console_router_with(
    station: StationHandle,
    auth: Arc<Auth>,
    config: &ConsoleConfig,
) -> Router {
    build(
        station,
        auth,
        config,
        config.listen,
        config.tls.enabled(),
        None,
    )
    .0
}

/// The router and the limits it shares with the server loop; `listen` is the address
/// actually bound (the configured port may be 0).
fn build(
    station: StationHandle,
    auth: Arc<Auth>,
    config: &ConsoleConfig,
    listen: SocketAddr,
    tls: bool,
    foxglove: Option<shoal_foxglove::BridgeHandle>,
) -> (Router, Arc<Limits>) {
    let limits = Arc::new(Limits::new(config.limits.clone()));
    let gate = Arc::new(Gate::new(
        listen,
        tls,
        &config.allowed_hosts,
        &config.allowed_origins,
    ));
    let state = AppState {
        commits: health::CommitClock::follow(&station),
        station,
        auth,
        limits: limits.clone(),
        health: Arc::new(config.health.clone()),
        gate: gate.clone(),
        logins: Arc::new(Logins::new(&config.auth)),
        foxglove,
    };
    let router = Router::new()
        .route("/status.html", get(status_page))
        .route("/api/health", get(health::health))
        .route("/metrics", get(metrics::metrics))
        .route("/api/fleet", get(fleet))
        .route("/api/fleet/capable", get(capable::capable))
        .route("/api/vehicles/{id}", get(vehicle))
        .route("/api/vehicles/{id}/track", get(track))
        // An MCAP recording's tracks for the replay: the one body allowed to be large.
        .route(
            "/api/recordings/tracks",
            post(recording::tracks).layer(axum::extract::DefaultBodyLimit::max(
                config.limits.max_recording_bytes,
            )),
        )
        .route("/api/stats", get(stats))
        .route("/api/events", get(events))
        .route("/api/tasks", get(tasks).post(dispatch))
        .route("/api/tasks/{id}", get(task))
        .route("/api/vehicles", get(fleet).post(register_vehicle))
        .route("/api/missions", get(missions).post(plan_mission))
        .route("/api/missions/{id}", get(mission))
        .route("/api/mission-preview", post(preview_mission))
        .route("/api/missions/{id}/start", post(start_mission))
        .route("/api/missions/{id}/abort", post(abort_mission))
        .route("/api/missions/{id}/export.csv", get(export_csv))
        .route("/api/missions/{id}/export.geojson", get(export_geojson))
        .route("/api/abort-all", post(abort_all))
        .route("/api/events/{id}/ack", post(ack_event))
        .route(
            "/api/environment/subscriptions",
            get(env_subscriptions).post(env_subscribe),
        )
        .route(
            "/api/environment/subscriptions/{id}",
            get(env_observations).delete(env_unsubscribe),
        )
        .route("/api/ws", get(live::ws))
        .route("/api/foxglove", get(foxglove::foxglove))
        .route("/api/openapi.json", get(openapi))
        .route("/api/rejected", get(rejected))
        .route("/api/traffic", get(traffic::traffic))
        .route("/api/acoustic", get(acoustic::acoustic))
        .route("/api/federation", get(federation::federation))
        .route(
            "/api/federation/leases/{vehicle}",
            post(federation::hand_over),
        )
        .route("/api/rules", get(rules).post(create_rule))
        .route(
            "/api/rules/{id}",
            get(rule).patch(patch_rule).delete(delete_rule),
        )
        .route("/api/sparql", get(sparql::get).post(sparql::post))
        .route("/api/auth/login", post(login))
        .route("/api/auth/logout", post(logout))
        .route("/api/auth/session", get(session))
        .route("/api/auth/users", get(users).post(set_user))
        .route("/api/auth/users/{name}", axum::routing::delete(delete_user))
        .route("/api/auth/tokens", get(tokens).post(create_token))
        .route("/api/auth/tokens/{id}", axum::routing::delete(delete_token))
        .fallback(web::serve)
        .layer(axum::middleware::from_fn_with_state(state.clone(), guard))
        // Before the guard: the Foxglove app sends its token as ?token=.
        .layer(axum::middleware::from_fn(foxglove::token_in_query))
        .layer(axum::middleware::from_fn(extract::json_errors))
        // Every other request body is small JSON; anything beyond this is refused before
        // parsing.
        .layer(axum::extract::DefaultBodyLimit::max(
            config.limits.max_body_bytes,
        ))
        // Before any handler, the console's files included: a page under another name
        // (DNS rebinding) gets nothing.
        .layer(axum::middleware::from_fn_with_state(gate, check_host))
        // Outermost: requests beyond the limit are refused before anything else is done.
        .layer(axum::middleware::from_fn_with_state(
            limits.clone(),
            limits::limit_requests,
        ))
        .with_state(state);
    (router, limits)
}

/// Serves the console on `listener` until `shutdown` is cancelled, without
/// authentication (logins off, the other `[console]` defaults): for tests and tools
/// that start a console of their own on loopback.
pub async fn serve(
    listener: tokio::net::TcpListener,
    station: StationHandle,
    shutdown: CancellationToken,
) -> std::io::Result<()> {
    let config = ConsoleConfig {
        auth: AuthConfig::off(),
        ..ConsoleConfig::default()
    };
    match serve_with(listener, station, config, shutdown).await {
        Ok(()) => Ok(()),
        Err(ConsoleError::Io(e)) => Err(e),
        Err(e) => Err(std::io::Error::other(e)),
    }
}

/// Serves the console on `listener` with `config` (authentication and TLS included) until
/// `shutdown` is cancelled. On the first start with authentication enabled it prints the
/// admin password and token it created on standard error, once, and never logs them.
pub async fn serve_with(
    listener: tokio::net::TcpListener,
    station: StationHandle,
    config: ConsoleConfig,
    shutdown: CancellationToken,
) -> Result<(), ConsoleError> {
    serve_with_bridge(listener, station, config, None, shutdown).await
}

/// [`serve_with`], also serving the Foxglove live bridge at `/api/foxglove` when one is
/// given (behind the same logins, Host and Origin checks).
pub async fn serve_with_bridge(
    listener: tokio::net::TcpListener,
    station: StationHandle,
    config: ConsoleConfig,
    foxglove: Option<shoal_foxglove::BridgeHandle>,
    shutdown: CancellationToken,
) -> Result<(), ConsoleError> {
    let tls = tls::acceptor(&config.tls)?;
    let auth_config = config.auth.clone();
    let (auth, boot) = tokio::task::spawn_blocking(move || Auth::load(&auth_config))
        .await
        .map_err(std::io::Error::other)??;
    let addr = listener.local_addr()?;
    if let Some(b) = boot {
        show_once(&b.notice(auth.path()));
        warn!(
            users_file = %auth.path().display(),
            "console authentication: created user \"{}\" (admin) and an admin API token; \
             credentials not set in [console.auth] were printed on the terminal, not here",
            b.user
        );
    }
    let scheme = if tls.is_some() { "https" } else { "http" };
    if auth.enabled() {
        info!(%addr, users = auth.users().len(), "console: {scheme}://{addr}/ (login required)");
    } else {
        if !addr.ip().is_loopback() {
            warn!(%addr, "the console listens beyond this host without authentication: set [console.auth] enabled = true");
        }
        info!(%addr, "console: {scheme}://{addr}/  API: {scheme}://{addr}/api/fleet (no login: [console.auth] enabled = false)");
    }
    if addr.ip().is_unspecified() && config.allowed_hosts.is_empty() {
        warn!(%addr, "the console listens on every interface but [console] allowed_hosts names no host: browsers must use an IP address");
    }
    let (router, limits) = build(
        station,
        Arc::new(auth),
        &config,
        addr,
        tls.is_some(),
        foxglove,
    );
    limits::serve_connections(listener, router, limits, tls, shutdown).await?;
    Ok(())
}

/// Writes first-start credentials straight to standard error: the terminal of whoever
/// started the station, and never the tracing log, which may be shipped or kept.
fn show_once(text: &str) {
    use std::io::Write as _;
    let mut err = std::io::stderr().lock();
    let _ = err.write_all(text.as_bytes());
    let _ = err.flush();
}

/// Refuses a request whose `Host` this console does not answer to (421): a DNS-rebinding
/// page reaches it under the attacker's own name.
async fn check_host(State(gate): State<Arc<Gate>>, req: Request, next: Next) -> Response {
    let host = req
        .headers()
        .get(header::HOST)
        .map(|h| h.to_str().unwrap_or("\u{fffd}"));
    // HTTP/1.0 tools may send no Host; browsers always do.
    if let Some(host) = host
        && !gate.host_ok(host)
    {
        gate.count(Refused::Host);
        return ApiError::Misdirected(format!(
            "this console does not answer to Host {host:?}: open it by an address it listens \
             on, or add the name to [console] allowed_hosts"
        ))
        .into_response();
    }
    next.run(req).await
}

/// True for methods that change something (every method but reads).
fn changes(method: &Method) -> bool {
    !matches!(*method, Method::GET | Method::HEAD | Method::OPTIONS)
}

/// Checks origin, credentials, role and CSRF token before any handler runs (see
/// [`auth::required_role`]):
///
/// 1. a WebSocket handshake or a change (POST, PUT, PATCH, DELETE) naming another site's
///    `Origin` is refused (403), logins on or off: a page elsewhere cannot make the
///    browser act on this console, even one with no login on loopback;
/// 2. without valid credentials, 401; with a role too low, 403;
/// 3. on a session cookie, which the browser attaches by itself, a handshake or a change
///    must also carry `Origin` (every browser sends it on those; its absence means a
///    tool, which should send a bearer token) and a change its session's `X-CSRF-Token`.
async fn guard(State(app): State<AppState>, mut req: Request, next: Next) -> Response {
    let path = req.uri().path().to_owned();
    let watched = changes(req.method()) || path == "/api/ws";
    let origin = req.headers().get(header::ORIGIN).cloned();
    if watched && let Some(origin) = &origin {
        let host = req
            .headers()
            .get(header::HOST)
            .and_then(|h| h.to_str().ok());
        let ok = origin.to_str().is_ok_and(|o| app.gate.origin_ok(o, host));
        if !ok {
            app.gate.count(Refused::Origin);
            return ApiError::Forbidden(format!(
                "{} {path} from a page of another site (Origin {origin:?}) is refused: only \
                 pages served by this console may do it ([console] allowed_origins)",
                req.method()
            ))
            .into_response();
        }
    }
    let Some(need) = auth::required_role(req.method(), &path) else {
        return next.run(req).await;
    };
    if !app.auth.enabled() {
        return next.run(req).await;
    }
    let who = match app.auth.authenticate(req.headers()) {
        Err(why) => return ApiError::Unauthorized(why.into()).into_response(),
        Ok(who) => who,
    };
    if who.role < need {
        return ApiError::Forbidden(format!(
            "{} {path} needs the {need} role; {} is {}",
            req.method(),
            who.name,
            who.role
        ))
        .into_response();
    }
    if who.via == "session" && watched {
        if origin.is_none() {
            app.gate.count(Refused::Origin);
            return ApiError::Forbidden(format!(
                "{} {path} with a session cookie needs the Origin header a browser sends; \
                 tools send Authorization: Bearer <token> instead",
                req.method()
            ))
            .into_response();
        }
        if changes(req.method()) && !app.auth.csrf_ok(req.headers()) {
            app.gate.count(Refused::Csrf);
            return ApiError::Forbidden(format!(
                "{} {path}: missing or wrong {} header (the csrf_token of /api/auth/session)",
                req.method(),
                auth::CSRF_HEADER
            ))
            .into_response();
        }
    }
    req.extensions_mut().insert(who);
    next.run(req).await
}

async fn status_page() -> Html<&'static str> {
    Html(include_str!("status.html"))
}

async fn fleet(State(s): State<StationHandle>) -> impl IntoResponse {
    Json(s.fleet())
}

async fn vehicle(
    State(s): State<StationHandle>,
    Path(id): Path<String>,
) -> Result<impl IntoResponse, ApiError> {
    s.vehicle(&id)
        .map(Json)
        .ok_or_else(|| ApiError::NotFound(format!("no vehicle {id:?}")))
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct TrackQuery {
    from_ms: Option<i64>,
    to_ms: Option<i64>,
    limit: Option<usize>,
}

/// Most rows one history query returns.
const MAX_ROWS: usize = 10_000;

async fn track(
    State(s): State<StationHandle>,
    Path(id): Path<String>,
    q: Result<Query<TrackQuery>, axum::extract::rejection::QueryRejection>,
) -> Result<impl IntoResponse, ApiError> {
    let Query(q) = q.map_err(|e| ApiError::BadRequest(e.body_text()))?;
    if s.vehicle(&id).is_none() {
        return Err(ApiError::NotFound(format!("no vehicle {id:?}")));
    }
    let to = q.to_ms.unwrap_or(i64::MAX);
    let from = q.from_ms.unwrap_or(0);
    if from > to {
        return Err(ApiError::BadRequest("from_ms is after to_ms".into()));
    }
    let limit = q.limit.unwrap_or(1000).min(MAX_ROWS);
    let reader = s.history().clone();
    let rows = tokio::task::spawn_blocking(move || reader.track(&id, from, to, limit))
        .await
        .map_err(|e| ApiError::Internal(e.to_string()))?
        .map_err(|e| ApiError::Internal(e.to_string()))?;
    Ok(Json(rows))
}

#[derive(Serialize)]
struct Stats {
    ingest: shoal_station::IngestStats,
    history_committed: u64,
    /// How often each HTTP limit was hit, and what is in use now.
    http: HttpStats,
}

#[derive(Serialize)]
struct HttpStats {
    #[serde(flatten)]
    hits: LimitHits,
    in_use: limits::InUse,
    /// Requests the gate refused, by reason (Host, Origin, CSRF, login limits).
    refused: Refusals,
}

async fn stats(State(app): State<AppState>) -> Json<Stats> {
    Json(Stats {
        ingest: app.station.stats(),
        history_committed: app.station.history_committed(),
        http: HttpStats {
            hits: app.limits.hits(),
            in_use: app.limits.in_use(),
            refused: app.gate.refusals(),
        },
    })
}

async fn events(State(s): State<StationHandle>) -> impl IntoResponse {
    Json(s.event_views())
}

async fn tasks(State(s): State<StationHandle>) -> impl IntoResponse {
    Json(s.tasks())
}

/// `POST /api/tasks` as a person writes it: the vehicle and a typed task (as a mission's
/// step names them); the station fills in the rest: an id if none is given, no mission,
/// issued now, and its own sequence and expiry as for every task.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct TaskOrder {
    #[serde(default)]
    task_id: Option<String>,
    vehicle_id: String,
    task: shoal_model::Task,
}

/// Ids of tasks ordered without one: the station's clock and a counter, so two orders in
/// the same millisecond differ.
fn order_task_id(now_ms: i64) -> String {
    static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    format!("task-{now_ms}-{n}")
}

/// The body of `POST /api/tasks`: a [`TaskOrder`] (it has a `task` member) or the wire
/// form a DDS writer sends, each read with the errors naming the member at fault.
fn dispatch_body(
    s: &StationHandle,
    body: &serde_json::Map<String, serde_json::Value>,
) -> Result<TaskAssignment, ApiError> {
    let bytes = serde_json::to_vec(body).map_err(|e| ApiError::Internal(e.to_string()))?;
    if !body.contains_key("task") {
        return extract::parse::<TaskAssignment>(&bytes);
    }
    let order: TaskOrder = extract::parse(&bytes)?;
    let now = s.now();
    let id = order.task_id.unwrap_or_else(|| order_task_id(now));
    Ok(TaskAssignment::new(
        id,
        "",
        order.vehicle_id,
        now,
        &order.task,
    ))
}

async fn dispatch(
    State(s): State<StationHandle>,
    ApiJson(body): ApiJson<serde_json::Map<String, serde_json::Value>>,
) -> Result<impl IntoResponse, ApiError> {
    let task = dispatch_body(&s, &body)?;
    let id = task.task_id.clone();
    s.dispatch(task).await?;
    Ok((
        StatusCode::ACCEPTED,
        Json(serde_json::json!({ "task_id": id, "state": "sent" })),
    ))
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct LimitQuery {
    limit: Option<usize>,
}

async fn rejected(
    State(s): State<StationHandle>,
    q: Result<Query<LimitQuery>, axum::extract::rejection::QueryRejection>,
) -> Result<impl IntoResponse, ApiError> {
    let Query(q) = q.map_err(|e| ApiError::BadRequest(e.body_text()))?;
    let limit = q.limit.unwrap_or(100).min(MAX_ROWS);
    let reader = s.history().clone();
    let rows = tokio::task::spawn_blocking(move || reader.rejected(limit))
        .await
        .map_err(|e| ApiError::Internal(e.to_string()))?
        .map_err(|e| ApiError::Internal(e.to_string()))?;
    Ok(Json(rows))
}

impl From<RuleChangeError> for ApiError {
    fn from(e: RuleChangeError) -> Self {
        use shoal_semantic::RuleError;
        match e {
            RuleChangeError::Rule(RuleError::NotFound(id)) => {
                Self::NotFound(format!("no rule {id:?}"))
            }
            RuleChangeError::Rule(e @ (RuleError::Exists(_) | RuleError::BuiltIn(_))) => {
                Self::Conflict(e.to_string())
            }
            RuleChangeError::Rule(e) => Self::BadRequest(e.to_string()),
            e @ RuleChangeError::Save(_) => Self::Internal(e.to_string()),
            e => Self::Internal(e.to_string()),
        }
    }
}

async fn rules(State(s): State<StationHandle>) -> impl IntoResponse {
    Json(s.rules())
}

async fn rule(
    State(s): State<StationHandle>,
    Path(id): Path<String>,
) -> Result<impl IntoResponse, ApiError> {
    s.rule(&id)
        .map(Json)
        .ok_or_else(|| ApiError::NotFound(format!("no rule {id:?}")))
}

async fn create_rule(
    State(s): State<StationHandle>,
    ApiJson(doc): ApiJson<RuleDoc>,
) -> Result<impl IntoResponse, ApiError> {
    let created = s.create_rule(&doc)?;
    Ok((StatusCode::CREATED, Json(created)))
}

/// A change to a rule: `enabled` alone switches it (built-in rules too); any other member
/// replaces that part of a user rule's definition, checked exactly as on creation. `id` and
/// `built_in` may be sent back as `GET` gave them, but not changed.
/// A member left out leaves that part as it is; `null` is refused like any other value of
/// the wrong type, as the OpenAPI document says.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RulePatch {
    #[serde(default, deserialize_with = "present")]
    id: Option<String>,
    #[serde(default, deserialize_with = "present")]
    description: Option<String>,
    #[serde(default, deserialize_with = "present")]
    severity: Option<shoal_model::Severity>,
    #[serde(default, deserialize_with = "present")]
    kind: Option<shoal_model::EventKind>,
    #[serde(default, deserialize_with = "present")]
    condition: Option<shoal_station::ConditionDoc>,
    #[serde(default, deserialize_with = "present")]
    enabled: Option<bool>,
    #[serde(default, deserialize_with = "present")]
    built_in: Option<bool>,
}

/// A member that was sent: its value, which must not be `null`.
fn present<'de, D, T>(d: D) -> Result<Option<T>, D::Error>
where
    D: serde::Deserializer<'de>,
    T: Deserialize<'de>,
{
    T::deserialize(d).map(Some)
}

async fn patch_rule(
    State(s): State<StationHandle>,
    Path(id): Path<String>,
    ApiJson(patch): ApiJson<RulePatch>,
) -> Result<impl IntoResponse, ApiError> {
    let current = s
        .rule(&id)
        .ok_or_else(|| ApiError::NotFound(format!("no rule {id:?}")))?;
    if patch.id.as_ref().is_some_and(|p| *p != id) {
        return Err(ApiError::BadRequest(format!(
            "id: a rule cannot be renamed ({id:?} in the path); create a new one instead"
        )));
    }
    if patch.built_in.is_some_and(|b| b != current.built_in) {
        return Err(ApiError::BadRequest(
            "built_in: whether a rule is built in cannot be changed".into(),
        ));
    }
    let redefines = patch.description.is_some()
        || patch.severity.is_some()
        || patch.kind.is_some()
        || patch.condition.is_some();
    if !redefines {
        let enabled = patch.enabled.ok_or_else(|| {
            ApiError::BadRequest(
                "nothing to change: send enabled, description, severity, kind or condition".into(),
            )
        })?;
        return Ok(Json(s.set_rule_enabled(&id, enabled)?));
    }
    if current.built_in {
        return Err(ApiError::Conflict(format!(
            "rule {id:?} is built in: it can be enabled or disabled, not redefined"
        )));
    }
    let doc = RuleDoc {
        description: patch.description.unwrap_or(current.description),
        severity: patch.severity.unwrap_or(current.severity),
        kind: patch.kind.unwrap_or(current.kind),
        condition: patch.condition.unwrap_or(current.condition),
        enabled: patch.enabled.unwrap_or(current.enabled),
        ..current
    };
    Ok(Json(s.replace_rule(&doc)?))
}

async fn delete_rule(
    State(s): State<StationHandle>,
    Path(id): Path<String>,
) -> Result<StatusCode, ApiError> {
    s.delete_rule(&id)?;
    Ok(StatusCode::NO_CONTENT)
}

impl From<DispatchError> for ApiError {
    fn from(e: DispatchError) -> Self {
        match e {
            DispatchError::UnknownVehicle(_) | DispatchError::UnknownMission(_) => {
                Self::NotFound(e.to_string())
            }
            // An id already in use conflicts with what exists; the body itself is fine.
            DispatchError::VehicleLost(_)
            | DispatchError::Incapable { .. }
            | DispatchError::LowBattery { .. }
            | DispatchError::DuplicateTask(_)
            | DispatchError::Lease(_)
            | DispatchError::Relay(_)
            | DispatchError::DuplicateMission(_) => Self::Conflict(e.to_string()),
            DispatchError::Publish(_) => Self::Internal(e.to_string()),
            DispatchError::InMission { ref error, .. }
                if matches!(
                    **error,
                    DispatchError::UnknownVehicle(_)
                        | DispatchError::VehicleLost(_)
                        | DispatchError::Incapable { .. }
                        | DispatchError::LowBattery { .. }
                        | DispatchError::DuplicateTask(_)
                        | DispatchError::Lease(_)
                ) =>
            {
                Self::Conflict(e.to_string())
            }
            _ => Self::BadRequest(e.to_string()),
        }
    }
}

async fn task(
    State(s): State<StationHandle>,
    Path(id): Path<String>,
) -> Result<impl IntoResponse, ApiError> {
    s.task(&id)
        .map(Json)
        .ok_or_else(|| ApiError::NotFound(format!("no task {id:?}")))
}

async fn register_vehicle(
    State(s): State<StationHandle>,
    ApiJson(a): ApiJson<shoal_model::VehicleAnnouncement>,
) -> Result<impl IntoResponse, ApiError> {
    let id = a.vehicle_id.clone();
    s.register_vehicle(a)
        .map_err(|e| ApiError::BadRequest(format!("invalid vehicle: {e}")))?;
    s.vehicle(&id)
        .map(|v| (StatusCode::CREATED, Json(v)))
        .ok_or_else(|| ApiError::Internal("registered vehicle not found".into()))
}

async fn missions(State(s): State<StationHandle>) -> impl IntoResponse {
    Json(s.missions())
}

async fn mission(
    State(s): State<StationHandle>,
    Path(id): Path<String>,
) -> Result<impl IntoResponse, ApiError> {
    s.mission(&id)
        .map(Json)
        .ok_or_else(|| ApiError::NotFound(format!("no mission {id:?}")))
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PlanQuery {
    /// Start the mission at once.
    #[serde(default)]
    start: bool,
}

async fn plan_mission(
    State(s): State<StationHandle>,
    q: Result<Query<PlanQuery>, axum::extract::rejection::QueryRejection>,
    ApiJson(spec): ApiJson<MissionSpec>,
) -> Result<impl IntoResponse, ApiError> {
    let Query(q) = q.map_err(|e| ApiError::BadRequest(e.body_text()))?;
    let mut view = s.plan_mission(spec)?;
    if q.start {
        view = s.start_mission(&view.mission_id)?;
    }
    Ok((StatusCode::CREATED, Json(view)))
}

/// The plan preview of a mission: per vehicle, its duration, distance and energy, and
/// warnings (battery); nothing is registered.
async fn preview_mission(
    State(s): State<StationHandle>,
    ApiJson(spec): ApiJson<MissionSpec>,
) -> Result<Json<shoal_station::MissionPreview>, ApiError> {
    Ok(Json(s.preview_mission(&spec)?))
}

async fn start_mission(
    State(s): State<StationHandle>,
    Path(id): Path<String>,
) -> Result<impl IntoResponse, ApiError> {
    Ok(Json(s.start_mission(&id)?))
}

async fn abort_mission(
    State(s): State<StationHandle>,
    Path(id): Path<String>,
) -> Result<impl IntoResponse, ApiError> {
    Ok(Json(s.abort_mission(&id)?))
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Confirm {
    confirm: bool,
}

async fn abort_all(
    State(s): State<StationHandle>,
    ApiJson(c): ApiJson<Confirm>,
) -> Result<impl IntoResponse, ApiError> {
    if !c.confirm {
        return Err(ApiError::BadRequest(
            "confirm: send {\"confirm\": true} to abort every vehicle".into(),
        ));
    }
    let vehicles = s.abort_all();
    Ok(Json(serde_json::json!({ "aborted_vehicles": vehicles })))
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct AckBody {
    /// Operator name; with authentication on, the logged-in user is recorded instead.
    #[serde(default)]
    by: Option<String>,
}

async fn ack_event(
    State(s): State<StationHandle>,
    who: Option<Extension<Identity>>,
    Path(id): Path<String>,
    headers: HeaderMap,
    body: Result<axum::body::Bytes, axum::extract::rejection::BytesRejection>,
) -> Result<impl IntoResponse, ApiError> {
    // The body is optional: none at all, or a JSON object.
    let body = body.map_err(|e| extract::bytes_rejection(&e))?;
    let body: Option<AckBody> = if body.is_empty() {
        None
    } else if extract::is_json(&headers) {
        Some(extract::parse(&body)?)
    } else {
        return Err(ApiError::UnsupportedMediaType(
            "send the body as application/json, or no body".into(),
        ));
    };
    let by = match who {
        Some(Extension(who)) => who.name,
        None => body
            .and_then(|b| b.by)
            .filter(|b| !b.trim().is_empty())
            .unwrap_or_else(|| "operator".into()),
    };
    s.acknowledge(&id, &by)
        .map(Json)
        .ok_or_else(|| ApiError::NotFound(format!("no recent event {id:?}")))
}

async fn env_subscriptions(State(s): State<StationHandle>) -> impl IntoResponse {
    Json(s.environment_subscriptions())
}

async fn env_subscribe(
    State(s): State<StationHandle>,
    ApiJson(spec): ApiJson<EnvSubscriptionSpec>,
) -> Result<impl IntoResponse, ApiError> {
    let sub = s
        .subscribe_environment(spec)
        .map_err(|e| ApiError::BadRequest(e.to_string()))?;
    Ok((StatusCode::CREATED, Json(sub)))
}

async fn env_observations(
    State(s): State<StationHandle>,
    Path(id): Path<String>,
) -> Result<impl IntoResponse, ApiError> {
    s.environment_observations(&id)
        .map(Json)
        .ok_or_else(|| ApiError::NotFound(format!("no subscription {id:?}")))
}

async fn env_unsubscribe(
    State(s): State<StationHandle>,
    Path(id): Path<String>,
) -> Result<StatusCode, ApiError> {
    if s.unsubscribe_environment(&id) {
        Ok(StatusCode::NO_CONTENT)
    } else {
        Err(ApiError::NotFound(format!("no subscription {id:?}")))
    }
}

/// A mission's log from the history: its vehicles' tracks over its time window.
async fn mission_log(s: &StationHandle, id: &str) -> Result<export::MissionLog, ApiError> {
    let mission = s
        .mission(id)
        .ok_or_else(|| ApiError::NotFound(format!("no mission {id:?}")))?;
    let (from_ms, to_ms) = export::MissionLog::window(&mission, shoal_model::now_ms());
    let vehicles = export::MissionLog::vehicles(&mission);
    let reader = s.history().clone();
    let (tracks, truncated) = tokio::task::spawn_blocking(move || {
        let mut truncated = false;
        let mut tracks = Vec::with_capacity(vehicles.len());
        for v in vehicles {
            let rows = reader
                .track(&v, from_ms, to_ms, MAX_EXPORT_ROWS)
                .map_err(|e| e.to_string())?;
            truncated |= rows.len() == MAX_EXPORT_ROWS;
            tracks.push((v, rows));
        }
        Ok::<_, String>((tracks, truncated))
    })
    .await
    .map_err(|e| ApiError::Internal(e.to_string()))?
    .map_err(ApiError::Internal)?;
    Ok(export::MissionLog {
        mission,
        from_ms,
        to_ms,
        tracks,
        truncated,
    })
}

/// Most state vectors per vehicle in one export (about 28 h at 1 Hz).
const MAX_EXPORT_ROWS: usize = 100_000;

fn attachment(id: &str, ext: &str) -> String {
    // Mission ids are `[A-Za-z0-9_.-]`, safe in a quoted file name.
    format!("attachment; filename=\"{id}.{ext}\"")
}

async fn export_csv(
    State(s): State<StationHandle>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let log = mission_log(&s, &id).await?;
    Ok((
        [
            (header::CONTENT_TYPE, "text/csv; charset=utf-8".to_owned()),
            (header::CONTENT_DISPOSITION, attachment(&id, "csv")),
        ],
        export::to_csv(&log),
    )
        .into_response())
}

async fn export_geojson(
    State(s): State<StationHandle>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let log = mission_log(&s, &id).await?;
    Ok((
        [
            (header::CONTENT_TYPE, "application/geo+json".to_owned()),
            (header::CONTENT_DISPOSITION, attachment(&id, "geojson")),
        ],
        export::to_geojson(&log).to_string(),
    )
        .into_response())
}

impl From<AuthError> for ApiError {
    fn from(e: AuthError) -> Self {
        match e {
            AuthError::BadCredentials => Self::Unauthorized(e.to_string()),
            AuthError::Invalid(_) | AuthError::Disabled => Self::BadRequest(e.to_string()),
            AuthError::NotFound(_) => Self::NotFound(e.to_string()),
            AuthError::LastAdmin(_) => Self::Conflict(e.to_string()),
            e => Self::Internal(e.to_string()),
        }
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct LoginBody {
    user: String,
    password: String,
}

#[derive(Serialize)]
struct SessionView {
    /// Whether the station requires logins.
    enabled: bool,
    /// Who is logged in (absent when nobody is).
    user: Option<String>,
    /// What they may do; `admin` when authentication is off.
    role: Option<Role>,
    /// `session`, `token` or `open`.
    via: Option<&'static str>,
    /// For a session: the value every change must carry in `X-CSRF-Token`.
    #[serde(skip_serializing_if = "Option::is_none")]
    csrf_token: Option<String>,
}

impl SessionView {
    fn of(auth: &Auth, who: Option<Identity>, csrf_token: Option<String>) -> Self {
        let session = who.as_ref().is_some_and(|w| w.via == "session");
        Self {
            enabled: auth.enabled(),
            user: who
                .as_ref()
                .filter(|_| auth.enabled())
                .map(|w| w.name.clone()),
            role: who.as_ref().map(|w| w.role),
            via: who.map(|w| w.via),
            csrf_token: csrf_token.filter(|_| session),
        }
    }
}

/// 429 when `addr` or `user` failed too often lately.
fn throttled(app: &AppState, addr: Option<std::net::IpAddr>, user: &str) -> Result<(), ApiError> {
    app.logins
        .throttle
        .check(addr, user, Instant::now())
        .map_err(|wait| {
            app.gate.count(Refused::LoginThrottled);
            ApiError::TooManyRequests {
                message: format!(
                    "too many failed logins from this address or for this user; try again in {} s",
                    wait.as_secs_f64().ceil()
                ),
                retry_after_s: wait.as_secs_f64().ceil() as u64,
            }
        })
}

async fn login(
    State(app): State<AppState>,
    peer: Option<Extension<ConnectInfo<SocketAddr>>>,
    ApiJson(b): ApiJson<LoginBody>,
) -> Result<Response, ApiError> {
    let addr = peer.map(|Extension(ConnectInfo(a))| a.ip());
    throttled(&app, addr, &b.user)?;
    let turn = app.logins.hash_turn(&app.gate).await?;
    // Failures recorded while this one waited for its turn count too.
    throttled(&app, addr, &b.user)?;
    let a = app.auth.clone();
    let user = b.user.clone();
    // Argon2 takes tens of milliseconds on purpose: not on the async threads, and no
    // more at once than there are hashing turns.
    let result = tokio::task::spawn_blocking(move || {
        let _turn = turn;
        a.login(&b.user, &b.password)
    })
    .await
    .map_err(|e| ApiError::Internal(e.to_string()))?;
    let (session, who) = match result {
        Ok(ok) => ok,
        Err(e) => {
            if matches!(e, AuthError::BadCredentials) {
                app.logins.throttle.failed(addr, &user, Instant::now());
                app.gate.count(Refused::LoginFailed);
                warn!(client = ?addr, "console login refused: wrong user name or password");
            }
            return Err(e.into());
        }
    };
    app.logins.throttle.succeeded(&user);
    info!(user = %who.name, role = %who.role, "console login");
    let cookie =
        auth::session_set_cookie(Some(&session), app.auth.ttl_s(), app.gate.scheme == "https");
    let csrf = auth::csrf_of(&session);
    Ok((
        [(header::SET_COOKIE, cookie)],
        Json(SessionView::of(&app.auth, Some(who), Some(csrf))),
    )
        .into_response())
}

async fn logout(State(app): State<AppState>, headers: HeaderMap) -> Response {
    app.auth.logout(&headers);
    let cookie = auth::session_set_cookie(None, 0, app.gate.scheme == "https");
    (StatusCode::NO_CONTENT, [(header::SET_COOKIE, cookie)]).into_response()
}

async fn session(State(auth): State<Arc<Auth>>, headers: HeaderMap) -> Json<SessionView> {
    Json(SessionView::of(
        &auth,
        auth.authenticate(&headers).ok(),
        auth.csrf_token(&headers),
    ))
}

async fn users(State(auth): State<Arc<Auth>>) -> Json<Vec<auth::UserInfo>> {
    Json(auth.users())
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct UserBody {
    name: String,
    password: String,
    role: Role,
}

async fn set_user(
    State(app): State<AppState>,
    ApiJson(b): ApiJson<UserBody>,
) -> Result<impl IntoResponse, ApiError> {
    let a = app.auth.clone();
    let (name, role) = (b.name.clone(), b.role);
    let turn = app.logins.hash_turn(&app.gate).await?;
    tokio::task::spawn_blocking(move || {
        let _turn = turn;
        a.set_user(&b.name, &b.password, b.role)
    })
    .await
    .map_err(|e| ApiError::Internal(e.to_string()))??;
    info!(user = %name, %role, "console user saved");
    Ok((StatusCode::CREATED, Json(auth::UserInfo { name, role })))
}

async fn delete_user(
    State(auth): State<Arc<Auth>>,
    Path(name): Path<String>,
) -> Result<StatusCode, ApiError> {
    auth.delete_user(&name)?;
    Ok(StatusCode::NO_CONTENT)
}

async fn tokens(State(auth): State<Arc<Auth>>) -> Json<Vec<auth::TokenInfo>> {
    Json(auth.tokens())
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct TokenBody {
    name: String,
    role: Role,
}

async fn create_token(
    State(auth): State<Arc<Auth>>,
    ApiJson(b): ApiJson<TokenBody>,
) -> Result<impl IntoResponse, ApiError> {
    let (info, token) = auth.create_token(&b.name, b.role)?;
    Ok((
        StatusCode::CREATED,
        Json(serde_json::json!({ "token": token, "info": info })),
    ))
}

async fn delete_token(
    State(auth): State<Arc<Auth>>,
    Path(id): Path<String>,
) -> Result<StatusCode, ApiError> {
    auth.delete_token(&id)?;
    Ok(StatusCode::NO_CONTENT)
}

/// The OpenAPI 3.1 description of this API.
pub const OPENAPI: &str = include_str!("openapi.json");

async fn openapi() -> impl IntoResponse {
    ([(header::CONTENT_TYPE, "application/json")], OPENAPI)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every route the router serves is in the OpenAPI document, and nothing else: the
    /// document is written by hand, so this keeps it honest.
    #[test]
    fn the_openapi_document_lists_exactly_the_served_paths() {
        let doc: serde_json::Value = serde_json::from_str(OPENAPI).unwrap();
        assert_eq!(doc["openapi"], "3.1.0");
        let mut documented: Vec<&str> = doc["paths"]
            .as_object()
            .unwrap()
            .keys()
            .map(String::as_str)
            .collect();
        documented.sort_unstable();
        let source = include_str!("lib.rs");
        let mut served: Vec<&str> = source
            .lines()
            .filter_map(|l| l.trim().strip_prefix(".route(\""))
            .chain(
                // Routes split over lines by rustfmt: the path is on the next line.
                source
                    .lines()
                    .map(str::trim)
                    .filter(|l| l.starts_with("\"/api/") && l.ends_with("\","))
                    .map(|l| &l[1..]),
            )
            .filter_map(|l| l.split('"').next())
            .filter(|p| p.starts_with("/api/") || *p == "/metrics")
            .collect();
        served.sort_unstable();
        served.dedup();
        assert_eq!(served, documented);
    }
}
