//! The federated part of the fleet picture, as operators read it: vehicles, alarms and
//! task transitions from other Shoal sites (ship and shore). The Zenoh transport is the
//! binary's (`[federation]`); it hands the station a [`FederationView`] to read.

use std::collections::BTreeMap;
use std::sync::Arc;

use serde::Serialize;
use shoal_model::{Event, TaskState, VehicleKind};

use crate::core::StationHandle;

/// What the station reads of a running federation.
pub trait FederationView: Send + Sync {
    /// The remote picture at station time `now_ms`.
    fn snapshot(&self, now_ms: i64) -> FederationSnapshot;
}

/// The remote part of the fleet picture (`GET /api/federation`).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct FederationSnapshot {
    /// This site's name.
    pub site: String,
    /// The remote sites this one accepts, and whether each is online now.
    pub sites: Vec<SiteView>,
    /// Every vehicle of a remote site, with the age of its data.
    pub vehicles: Vec<RemoteVehicleView>,
    /// The latest alarms from remote sites (bounded), oldest first.
    pub alarms: Vec<RemoteAlarmView>,
    /// The latest task transitions from remote sites (bounded), oldest first.
    pub transitions: Vec<RemoteTransitionView>,
    /// Counters: what crossed each way, what was refused and why.
    pub counters: BTreeMap<String, u64>,
}

/// A remote site's link.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SiteView {
    /// Its name.
    pub site: String,
    /// Heard now (its Zenoh liveliness token is present).
    pub online: bool,
    /// Since when, ms since the Unix epoch.
    pub since_ms: i64,
}

/// A vehicle of another site.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RemoteVehicleView {
    /// The site it belongs to.
    pub site: String,
    /// Vehicle id (unique within its site).
    pub vehicle_id: String,
    /// Platform kind.
    pub kind: VehicleKind,
    /// When its position was taken, ms since the Unix epoch.
    pub timestamp_ms: i64,
    /// Latitude, degrees.
    pub latitude_deg: f64,
    /// Longitude, degrees.
    pub longitude_deg: f64,
    /// Depth, m.
    pub depth_m: f64,
    /// Heading, degrees.
    pub heading_deg: f64,
    /// Speed, m/s.
    pub speed_mps: f64,
    /// Battery, %.
    pub battery_pct: f64,
    /// How old the position is now, ms.
    pub age_ms: i64,
}

/// An alarm from another site.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RemoteAlarmView {
    /// The site that raised it.
    pub site: String,
    /// The alarm.
    pub alarm: Event,
}

/// A task transition at another site.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RemoteTransitionView {
    /// The site whose task it is.
    pub site: String,
    /// Task id.
    pub task_id: String,
    /// Mission id.
    pub mission_id: String,
    /// Vehicle id.
    pub vehicle_id: String,
    /// The state it reached.
    pub state: TaskState,
    /// When, ms since the Unix epoch.
    pub timestamp_ms: i64,
}

impl StationHandle {
    /// Hands the station a running federation to read; a second one is refused (given
    /// back).
    pub fn attach_federation(
        &self,
        view: Arc<dyn FederationView>,
    ) -> Result<(), Arc<dyn FederationView>> {
        self.core.federation.set(view)
    }

    /// The federated picture now, when a federation is attached.
    pub fn federation(&self) -> Option<FederationSnapshot> {
        let view = self.core.federation.get()?;
        Some(view.snapshot(self.now()))
    }
}
