//! `GET /api/traffic`: the vessels the station knows from AIS, its own ship (the ship's
//! navigation sentences) and the inputs' counters, for the map and for tools.

use axum::Json;
use axum::extract::State;
use serde::Serialize;
use shoal_station::StationHandle;
use shoal_traffic::{OwnShipView, TargetView, TrafficStats};

/// What `GET /api/traffic` answers.
#[derive(Debug, Serialize)]
pub(crate) struct TrafficDoc {
    /// False when no `[traffic]` input is configured (the lists are then empty).
    enabled: bool,
    /// Vessels, most recently heard first.
    targets: Vec<TargetView>,
    /// The ship the station is on, when its navigation is fed in.
    own_ship: Option<OwnShipView>,
    /// What the inputs read, accepted and dropped (and why).
    stats: Option<TrafficStats>,
}

pub(crate) async fn traffic(State(s): State<StationHandle>) -> Json<TrafficDoc> {
    let Some(t) = s.traffic() else {
        return Json(TrafficDoc {
            enabled: false,
            targets: Vec::new(),
            own_ship: None,
            stats: None,
        });
    };
    let mut targets = t.targets();
    targets.sort_by(|a, b| a.age_s.total_cmp(&b.age_s));
    Json(TrafficDoc {
        enabled: true,
        targets,
        own_ship: t.own_ship(),
        stats: Some(t.stats()),
    })
}
