//! The back end of Shoal's Mission Management Tool: the station's HTTP API.
//!
//! - [`router`] builds the axum router over a [`StationHandle`]; tests drive it without
//!   sockets.
//! - [`serve`] runs it on a listener until shutdown.
//! - [`ApiError`] is the one error type: client errors are explained in a JSON body,
//!   internal ones are logged and hidden.
//!
//! Endpoints (JSON): `GET /api/health`, `GET /api/fleet`, `GET /api/vehicles/{id}`,
//! `GET /api/vehicles/{id}/track?from_ms=&to_ms=&limit=`, `GET /api/stats`,
//! `GET /api/events`, `GET /api/tasks`, `POST /api/tasks`, `GET /api/rejected?limit=`;
//! rules: `GET|POST /api/rules`, `GET|PATCH|DELETE /api/rules/{id}` (PATCH takes
//! `{"enabled": bool}`);
//! `GET|POST /api/sparql` is a read-only SPARQL 1.1 Protocol endpoint over the semantic
//! model (results as SPARQL JSON or CSV); `GET /` is a plain status page listing the fleet.

use std::net::{Ipv4Addr, SocketAddr, SocketAddrV4};

use axum::extract::rejection::JsonRejection;
use axum::extract::{Path, Query, State};
use axum::http::StatusCode;
use axum::response::{Html, IntoResponse, Response};
use axum::routing::get;
use axum::{Json, Router};
use serde::{Deserialize, Serialize};
use shoal_model::TaskAssignment;
use shoal_station::{
    DispatchError, EnvSubscriptionSpec, MissionSpec, RuleChangeError, RuleDoc, StationHandle,
};
use tokio_util::sync::CancellationToken;
use tracing::{error, info};

mod live;

/// The `[console]` section of Shoal's configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ConsoleConfig {
    /// Address the HTTP API listens on; loopback by default.
    pub listen: SocketAddr,
}

impl Default for ConsoleConfig {
    fn default() -> Self {
        Self {
            listen: SocketAddr::V4(SocketAddrV4::new(Ipv4Addr::LOCALHOST, 8640)),
        }
    }
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
    /// The request was right but could not be answered in time.
    #[error("{0}")]
    Unavailable(String),
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
            Self::Unavailable(_) => StatusCode::SERVICE_UNAVAILABLE,
            Self::Internal(detail) => {
                error!(%detail, "API request failed");
                StatusCode::INTERNAL_SERVER_ERROR
            }
        };
        let msg = self.to_string();
        (status, Json(ErrorBody { error: &msg })).into_response()
    }
}

/// Builds the API router over a running station.
pub fn router(station: StationHandle) -> Router {
    // Every request body is small JSON; anything beyond this is refused before parsing.
    const MAX_BODY: usize = 1 << 20;
    Router::new()
        .route("/", get(index))
        .route("/api/health", get(health))
        .route("/api/fleet", get(fleet))
        .route("/api/vehicles/{id}", get(vehicle))
        .route("/api/vehicles/{id}/track", get(track))
        .route("/api/stats", get(stats))
        .route("/api/events", get(events))
        .route("/api/tasks", get(tasks).post(dispatch))
        .route("/api/tasks/{id}", get(task))
        .route("/api/vehicles", get(fleet).post(register_vehicle))
        .route("/api/missions", get(missions).post(plan_mission))
        .route("/api/missions/{id}", get(mission))
        .route(
            "/api/missions/{id}/start",
            axum::routing::post(start_mission),
        )
        .route(
            "/api/missions/{id}/abort",
            axum::routing::post(abort_mission),
        )
        .route("/api/abort-all", axum::routing::post(abort_all))
        .route("/api/events/{id}/ack", axum::routing::post(ack_event))
        .route(
            "/api/environment/subscriptions",
            get(env_subscriptions).post(env_subscribe),
        )
        .route(
            "/api/environment/subscriptions/{id}",
            get(env_observations).delete(env_unsubscribe),
        )
        .route("/api/ws", get(live::ws))
        .route("/api/openapi.json", get(openapi))
        .route("/api/rejected", get(rejected))
        .route("/api/rules", get(rules).post(create_rule))
        .route(
            "/api/rules/{id}",
            get(rule).patch(patch_rule).delete(delete_rule),
        )
        .route("/api/sparql", get(sparql_get).post(sparql_post))
        .layer(axum::extract::DefaultBodyLimit::max(MAX_BODY))
        .with_state(station)
}

/// Serves the API on `listener` until `shutdown` is cancelled.
pub async fn serve(
    listener: tokio::net::TcpListener,
    station: StationHandle,
    shutdown: CancellationToken,
) -> std::io::Result<()> {
    if let Ok(addr) = listener.local_addr() {
        info!(%addr, "HTTP API listening: http://{addr}/api/fleet");
    }
    axum::serve(listener, router(station))
        .with_graceful_shutdown(shutdown.cancelled_owned())
        .await
}

async fn index() -> Html<&'static str> {
    Html(include_str!("status.html"))
}

#[derive(Serialize)]
struct Health {
    status: &'static str,
    vehicles: usize,
    history_committed: u64,
}

async fn health(State(s): State<StationHandle>) -> Json<Health> {
    Json(Health {
        status: "ok",
        vehicles: s.fleet().len(),
        history_committed: s.history_committed(),
    })
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
}

async fn stats(State(s): State<StationHandle>) -> Json<Stats> {
    Json(Stats {
        ingest: s.stats(),
        history_committed: s.history_committed(),
    })
}

async fn events(State(s): State<StationHandle>) -> impl IntoResponse {
    Json(s.event_views())
}

async fn tasks(State(s): State<StationHandle>) -> impl IntoResponse {
    Json(s.tasks())
}

async fn dispatch(
    State(s): State<StationHandle>,
    body: Result<Json<TaskAssignment>, JsonRejection>,
) -> Result<impl IntoResponse, ApiError> {
    let Json(task) = body.map_err(|e| ApiError::BadRequest(e.body_text()))?;
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

/// The SPARQL 1.1 Protocol's query parameters (query operation).
#[derive(Debug, Deserialize)]
struct SparqlParams {
    query: Option<String>,
    /// Shortcut for the `Accept` header: `json` or `csv`.
    format: Option<String>,
    #[serde(rename = "default-graph-uri")]
    default_graph_uri: Option<String>,
    #[serde(rename = "named-graph-uri")]
    named_graph_uri: Option<String>,
}

fn result_format(
    params_format: Option<&str>,
    headers: &axum::http::HeaderMap,
) -> Result<shoal_semantic::ResultFormat, ApiError> {
    use shoal_semantic::ResultFormat;
    if let Some(f) = params_format {
        return match f {
            "json" => Ok(ResultFormat::Json),
            "csv" => Ok(ResultFormat::Csv),
            "tsv" => Ok(ResultFormat::Tsv),
            "xml" => Ok(ResultFormat::Xml),
            other => Err(ApiError::BadRequest(format!(
                "unknown format {other:?}: use json, csv, tsv or xml"
            ))),
        };
    }
    let accept = headers
        .get(axum::http::header::ACCEPT)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("");
    Ok(if accept.contains("text/csv") {
        ResultFormat::Csv
    } else if accept.contains("text/tab-separated-values") {
        ResultFormat::Tsv
    } else if accept.contains("application/sparql-results+xml") {
        ResultFormat::Xml
    } else {
        ResultFormat::Json
    })
}

async fn run_sparql(
    s: StationHandle,
    query: String,
    format: shoal_semantic::ResultFormat,
) -> Result<Response, ApiError> {
    use shoal_semantic::QueryError;
    let snapshot = s.semantic_snapshot();
    let out = tokio::task::spawn_blocking(move || {
        let result = snapshot.query(&query, &shoal_semantic::QueryLimits::default())?;
        result.write(format, Vec::new())
    })
    .await
    .map_err(|e| ApiError::Internal(e.to_string()))?;
    match out {
        Ok(bytes) => Ok((
            [(axum::http::header::CONTENT_TYPE, format.media_type())],
            bytes,
        )
            .into_response()),
        Err(e @ QueryError::Timeout(_)) => Err(ApiError::Unavailable(e.to_string())),
        Err(e @ (QueryError::Evaluation(_) | QueryError::Serialize(_))) => {
            Err(ApiError::Internal(e.to_string()))
        }
        Err(e) => Err(ApiError::BadRequest(e.to_string())),
    }
}

fn check_dataset(p: &SparqlParams) -> Result<(), ApiError> {
    if p.default_graph_uri.is_some() || p.named_graph_uri.is_some() {
        return Err(ApiError::BadRequest(
            "default-graph-uri and named-graph-uri are not supported: queries run over the whole model".into(),
        ));
    }
    Ok(())
}

async fn sparql_get(
    State(s): State<StationHandle>,
    headers: axum::http::HeaderMap,
    q: Result<Query<SparqlParams>, axum::extract::rejection::QueryRejection>,
) -> Result<Response, ApiError> {
    let Query(p) = q.map_err(|e| ApiError::BadRequest(e.body_text()))?;
    check_dataset(&p)?;
    let format = result_format(p.format.as_deref(), &headers)?;
    let query = p
        .query
        .ok_or_else(|| ApiError::BadRequest("missing the `query` parameter".into()))?;
    run_sparql(s, query, format).await
}

/// POST: `application/sparql-query` (the query is the body) or
/// `application/x-www-form-urlencoded` (`query=...`), as in the SPARQL 1.1 Protocol.
async fn sparql_post(
    State(s): State<StationHandle>,
    headers: axum::http::HeaderMap,
    q: Result<Query<SparqlParams>, axum::extract::rejection::QueryRejection>,
    body: String,
) -> Result<Response, ApiError> {
    let Query(url) = q.map_err(|e| ApiError::BadRequest(e.body_text()))?;
    let content_type = headers
        .get(axum::http::header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("")
        .to_ascii_lowercase();
    let (query, form_format) = if content_type.starts_with("application/sparql-query") {
        (body, None)
    } else if content_type.starts_with("application/x-www-form-urlencoded") {
        let p: SparqlParams =
            serde_urlencoded::from_str(&body).map_err(|e| ApiError::BadRequest(e.to_string()))?;
        check_dataset(&p)?;
        (
            p.query
                .ok_or_else(|| ApiError::BadRequest("missing the `query` field".into()))?,
            p.format,
        )
    } else {
        return Err(ApiError::BadRequest(
            "send the query as application/sparql-query or application/x-www-form-urlencoded"
                .into(),
        ));
    };
    check_dataset(&url)?;
    let format = result_format(form_format.as_deref().or(url.format.as_deref()), &headers)?;
    run_sparql(s, query, format).await
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
    body: Result<Json<RuleDoc>, JsonRejection>,
) -> Result<impl IntoResponse, ApiError> {
    let Json(doc) = body.map_err(|e| ApiError::BadRequest(e.body_text()))?;
    let created = s.create_rule(&doc)?;
    Ok((StatusCode::CREATED, Json(created)))
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RulePatch {
    enabled: bool,
}

async fn patch_rule(
    State(s): State<StationHandle>,
    Path(id): Path<String>,
    body: Result<Json<RulePatch>, JsonRejection>,
) -> Result<impl IntoResponse, ApiError> {
    let Json(patch) = body.map_err(|e| ApiError::BadRequest(e.body_text()))?;
    Ok(Json(s.set_rule_enabled(&id, patch.enabled)?))
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
            DispatchError::VehicleLost(_)
            | DispatchError::Incapable { .. }
            | DispatchError::LowBattery { .. } => Self::Conflict(e.to_string()),
            DispatchError::Dds(_) => Self::Internal(e.to_string()),
            DispatchError::InMission { ref error, .. }
                if matches!(
                    **error,
                    DispatchError::UnknownVehicle(_)
                        | DispatchError::VehicleLost(_)
                        | DispatchError::Incapable { .. }
                        | DispatchError::LowBattery { .. }
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
    body: Result<Json<shoal_model::VehicleAnnouncement>, JsonRejection>,
) -> Result<impl IntoResponse, ApiError> {
    let Json(a) = body.map_err(|e| ApiError::BadRequest(e.body_text()))?;
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
    body: Result<Json<MissionSpec>, JsonRejection>,
) -> Result<impl IntoResponse, ApiError> {
    let Query(q) = q.map_err(|e| ApiError::BadRequest(e.body_text()))?;
    let Json(spec) = body.map_err(|e| ApiError::BadRequest(e.body_text()))?;
    let mut view = s.plan_mission(spec)?;
    if q.start {
        view = s.start_mission(&view.mission_id)?;
    }
    Ok((StatusCode::CREATED, Json(view)))
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
    body: Result<Json<Confirm>, JsonRejection>,
) -> Result<impl IntoResponse, ApiError> {
    let Json(c) = body.map_err(|e| ApiError::BadRequest(e.body_text()))?;
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
    /// Operator name (until the console has logins).
    #[serde(default)]
    by: Option<String>,
}

async fn ack_event(
    State(s): State<StationHandle>,
    Path(id): Path<String>,
    body: Option<Json<AckBody>>,
) -> Result<impl IntoResponse, ApiError> {
    let by = body
        .and_then(|Json(b)| b.by)
        .filter(|b| !b.trim().is_empty())
        .unwrap_or_else(|| "operator".into());
    s.acknowledge(&id, &by)
        .map(Json)
        .ok_or_else(|| ApiError::NotFound(format!("no recent event {id:?}")))
}

async fn env_subscriptions(State(s): State<StationHandle>) -> impl IntoResponse {
    Json(s.environment_subscriptions())
}

async fn env_subscribe(
    State(s): State<StationHandle>,
    body: Result<Json<EnvSubscriptionSpec>, JsonRejection>,
) -> Result<impl IntoResponse, ApiError> {
    let Json(spec) = body.map_err(|e| ApiError::BadRequest(e.body_text()))?;
    let sub = s
        .subscribe_environment(spec)
        .map_err(ApiError::BadRequest)?;
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

/// The OpenAPI 3.1 description of this API.
pub const OPENAPI: &str = include_str!("openapi.json");

async fn openapi() -> impl IntoResponse {
    (
        [(axum::http::header::CONTENT_TYPE, "application/json")],
        OPENAPI,
    )
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
            .filter(|p| p.starts_with("/api/"))
            .collect();
        served.sort_unstable();
        served.dedup();
        assert_eq!(served, documented);
    }
}
