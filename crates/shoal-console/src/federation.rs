//! `GET /api/federation`: the part of the fleet picture that other Shoal sites send over
//! the federation (`[federation]`): their vehicles with the age of their data, their
//! alarms and task transitions, the command leases, and what crossed or was refused.
//! `POST /api/federation/leases/{vehicle}` hands a lease this site holds to another site.

use axum::Json;
use axum::extract::{Path, State};
use serde::{Deserialize, Serialize};
use shoal_station::{FederationSnapshot, HandoverRefused, LeaseView, StationHandle};

use crate::ApiError;
use crate::extract::ApiJson;

/// What `GET /api/federation` answers.
#[derive(Debug, Serialize)]
pub(crate) struct FederationDoc {
    /// False when this station is not federated (everything else is then empty).
    enabled: bool,
    #[serde(flatten)]
    picture: FederationSnapshot,
}

pub(crate) async fn federation(State(s): State<StationHandle>) -> Json<FederationDoc> {
    Json(match s.federation() {
        Some(picture) => FederationDoc {
            enabled: true,
            picture,
        },
        None => FederationDoc {
            enabled: false,
            picture: FederationSnapshot::default(),
        },
    })
}

/// The body of `POST /api/federation/leases/{vehicle}`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct Handover {
    /// The site to hand the lease to.
    to: String,
}

pub(crate) async fn hand_over(
    State(s): State<StationHandle>,
    Path(vehicle): Path<String>,
    ApiJson(body): ApiJson<Handover>,
) -> Result<Json<LeaseView>, ApiError> {
    s.hand_over_lease(&vehicle, &body.to)
        .map(Json)
        .map_err(|e| match e {
            HandoverRefused::UnknownLease(_) => ApiError::NotFound(e.to_string()),
            HandoverRefused::UnknownSite(_) => ApiError::BadRequest(e.to_string()),
            _ => ApiError::Conflict(e.to_string()),
        })
}
