//! `GET /api/health`: the station's health for anyone who can reach the console (no login;
//! it shows figures and reasons, no vehicle, user or path), 200 when ok, 503 with the same
//! body when degraded ([`shoal_station::StationHealth::verdict`] with `[console.health]`).

use std::sync::{Arc, Mutex, Weak};

use axum::Json;
use axum::extract::State;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use serde::Serialize;
use shoal_station::{
    DdsHealth, HealthThresholds, HealthVerdict, HistoryHealth, StationHandle, StationHealth,
};

use crate::limits::{InUse, LimitHits};
use crate::{ApiError, AppState};

/// When the history last committed, in station time (ms): a task follows the writer's
/// committed number and notes each change. Until the first commit, the time the console
/// started counts, so a writer stalled from the start is noticed too.
#[derive(Debug)]
pub(crate) struct CommitClock {
    last_ms: Mutex<i64>,
}

impl CommitClock {
    /// Starts following `station`'s commits (when a tokio runtime is there to run the task;
    /// without one, the start time stays the last commit).
    pub(crate) fn follow(station: &StationHandle) -> Arc<Self> {
        let clock = Arc::new(Self {
            last_ms: Mutex::new(station.now()),
        });
        if let Ok(rt) = tokio::runtime::Handle::try_current() {
            let mut committed = station.subscribe_history_committed();
            let weak: Weak<Self> = Arc::downgrade(&clock);
            let station = station.clone();
            // Ends when the console is gone (the clock dropped) or the writer is.
            rt.spawn(async move {
                while committed.changed().await.is_ok() {
                    let Some(clock) = weak.upgrade() else { break };
                    *lock(&clock.last_ms) = station.now();
                }
            });
        }
        clock
    }

    /// Station time of the last commit seen.
    pub(crate) fn last_ms(&self) -> i64 {
        *lock(&self.last_ms)
    }
}

/// A poisoned lock still holds a good number: a panic cannot tear an `i64` store.
fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// The health measured now, the commit clock applied; off the async threads, since the
/// semantic lock probe may wait up to its threshold.
pub(crate) async fn measure(app: &AppState) -> Result<(StationHealth, HealthVerdict), ApiError> {
    let s = app.station.clone();
    let give_up = std::time::Duration::from_millis(app.health.max_semantic_lock_wait_ms);
    let mut h = tokio::task::spawn_blocking(move || s.health(give_up))
        .await
        .map_err(|e| ApiError::Internal(e.to_string()))?;
    let since = app.station.now().saturating_sub(app.commits.last_ms());
    h.history.since_last_commit_ms = Some(u64::try_from(since).unwrap_or(0));
    let verdict = h.verdict(&app.health);
    Ok((h, verdict))
}

#[derive(Serialize)]
struct Semantic {
    lock_wait_ms: u64,
    lock_taken: bool,
    /// How many rules are disabled (which ones: `/api/rules`, with a login).
    disabled_rules: Option<usize>,
}

#[derive(Serialize)]
struct Limits {
    hit: LimitHits,
    in_use: InUse,
}

#[derive(Serialize)]
struct Health {
    /// `ok` or `degraded`.
    status: &'static str,
    /// Why degraded; empty when ok.
    degraded: Vec<String>,
    warnings: Vec<String>,
    vehicles: usize,
    history_committed: u64,
    dds: DdsHealth,
    history: HistoryHealth,
    semantic: Semantic,
    clock_skew_ms: i64,
    limits: Limits,
}

pub(crate) async fn health(State(app): State<AppState>) -> Result<Response, ApiError> {
    let (h, verdict) = measure(&app).await?;
    let ok = verdict.is_ok();
    let body = Health {
        status: if ok { "ok" } else { "degraded" },
        degraded: verdict.degraded,
        warnings: verdict.warnings,
        vehicles: app.station.fleet().len(),
        history_committed: app.station.history_committed(),
        dds: h.dds,
        history: h.history,
        semantic: Semantic {
            lock_wait_ms: h.semantic.lock_wait_ms,
            lock_taken: h.semantic.lock_taken,
            disabled_rules: h.semantic.disabled_rules.map(|r| r.len()),
        },
        clock_skew_ms: h.clock_skew_ms,
        limits: Limits {
            hit: app.limits.hits(),
            in_use: app.limits.in_use(),
        },
    };
    let status = if ok {
        StatusCode::OK
    } else {
        StatusCode::SERVICE_UNAVAILABLE
    };
    Ok((status, Json(body)).into_response())
}

/// `[console.health]`: the thresholds, as the station defines them.
pub type HealthConfig = HealthThresholds;
