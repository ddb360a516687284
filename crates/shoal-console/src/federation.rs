//! `GET /api/federation`: the part of the fleet picture that other Shoal sites send over
//! the federation (`[federation]`): their vehicles with the age of their data, their
//! alarms and task transitions, and what crossed or was refused.

use axum::Json;
use axum::extract::State;
use serde::Serialize;
use shoal_station::{FederationSnapshot, StationHandle};

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
