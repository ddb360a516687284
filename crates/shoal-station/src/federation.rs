//! The federated part of the fleet picture, as operators read it: vehicles, alarms and
//! task transitions from other Shoal sites (ship and shore). The Zenoh transport is the
//! binary's (`[federation]`); it hands the station a [`FederationView`] to read.

use std::collections::BTreeMap;
use std::sync::Arc;

use serde::Serialize;
use shoal_model::{EnvironmentObservation, Event, TaskAssignment, TaskState, VehicleKind};

use crate::core::StationHandle;

/// What the station reads of a running federation, and asks of its command lease.
pub trait FederationView: Send + Sync {
    /// The remote picture at station time `now_ms`.
    fn snapshot(&self, now_ms: i64) -> FederationSnapshot;

    /// Whether this station may command `vehicle` (one of its own) now: the command lease
    /// it holds ([`LeaseGrant::NONE`] when the lease is not in force), or why not.
    fn may_command(&self, vehicle: &str) -> Result<LeaseGrant, LeaseDenial>;

    /// Hands the lease of a vehicle this station holds to the site `to`.
    fn hand_over(&self, vehicle: &str, to: &str) -> Result<LeaseView, HandoverRefused>;

    /// The site whose vehicle `vehicle` is, when it is another site's.
    fn home_of(&self, vehicle: &str) -> Option<String>;

    /// Sends `task`, for another site's vehicle whose lease this station holds (and that
    /// the task carries), to that site, whose station gives it to the vehicle.
    fn relay(&self, task: &TaskAssignment) -> Result<(), RelayRefused>;

    /// Takes an environment observation this station accepted (the federation aggregates
    /// it for the other sites, when `[federation.environment]` says so).
    fn observe(&self, observation: &EnvironmentObservation);
}

/// Why a task for another site's vehicle was not sent to that site.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum RelayRefused {
    /// The federation refused to send it; the text says why.
    #[error("the task for {vehicle} cannot be sent to site {site}: {why}")]
    Refused {
        /// The vehicle.
        vehicle: String,
        /// Its site.
        site: String,
        /// Why.
        why: String,
    },
}

/// The command lease a station sends a vehicle's tasks under; every task carries it, and
/// the vehicle refuses one under a lease older than one it has obeyed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LeaseGrant {
    /// The lease's term; 0 when no lease is in force.
    pub term: u64,
    /// The site that holds it (this one); empty when no lease is in force.
    pub holder: String,
}

impl LeaseGrant {
    /// No lease: a station that is not federated, or whose lease is off.
    pub const NONE: Self = Self {
        term: 0,
        holder: String::new(),
    };
}

/// Why this station may not command a vehicle: the command lease
/// (`[federation.lease]`).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum LeaseDenial {
    /// Another site holds the vehicle's lease.
    #[error(
        "{vehicle} is commanded by site {holder} (command lease term {term}); ask {holder} to hand it over"
    )]
    HeldElsewhere {
        /// The vehicle.
        vehicle: String,
        /// The site that holds it.
        holder: String,
        /// The lease's term.
        term: u64,
    },
    /// The task was sent under a lease that is no longer in force (a task another site
    /// sent here, or one registered before the lease changed hands).
    #[error(
        "the task for {vehicle} was sent under site {sent_holder}'s command lease term {sent_term}, no longer in force (site {holder} holds term {term})"
    )]
    Superseded {
        /// The vehicle.
        vehicle: String,
        /// The site whose lease the task carries.
        sent_holder: String,
        /// That lease's term.
        sent_term: u64,
        /// The site that holds the lease now (this one).
        holder: String,
        /// Its term.
        term: u64,
    },
    /// The station has just started and is still learning the other sites' leases.
    #[error(
        "the command lease of {vehicle} is not settled yet: this site started {waited_ms} ms ago and waits up to {settle_ms} ms (lease.settle_ms) for the other sites' leases"
    )]
    NotSettled {
        /// The vehicle.
        vehicle: String,
        /// Time since the federation started, ms.
        waited_ms: u64,
        /// `lease.settle_ms`.
        settle_ms: u64,
    },
    /// No lease could be had (none held anywhere and this site does not claim, or the
    /// table is full); the text says which.
    #[error("no command lease for {vehicle}: {why}")]
    Unavailable {
        /// The vehicle.
        vehicle: String,
        /// Why.
        why: String,
    },
}

/// Why a lease was not handed over.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum HandoverRefused {
    /// The station is not federated, or the lease is not in force.
    #[error("the command lease is not in force here ([federation] and [federation.lease] enabled)")]
    NotInForce,
    /// No lease is known for the vehicle.
    #[error("no command lease is known for {0}")]
    UnknownLease(String),
    /// Another site holds it.
    #[error(
        "{vehicle} is commanded by site {holder} (term {term}); only {holder} can hand it over"
    )]
    NotHolder {
        /// The vehicle.
        vehicle: String,
        /// Who holds it.
        holder: String,
        /// The term.
        term: u64,
    },
    /// The receiving site is not one of this federation's.
    #[error("{0} is not a site of this federation")]
    UnknownSite(String),
}

/// A vehicle's command lease, as this site knows it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct LeaseView {
    /// The vehicle.
    pub vehicle_id: String,
    /// The site that commands it.
    pub holder: String,
    /// Its home site (where it is registered).
    pub home: String,
    /// The site that takes over when the holder is lost; empty for none.
    pub standby: String,
    /// Increases with every change.
    pub term: u64,
    /// What made the last change: `claim`, `handover` or `failover`.
    pub reason: &'static str,
    /// When, ms since the Unix epoch (the granting site's clock).
    pub granted_ms: i64,
    /// Whether this site holds it.
    pub held_here: bool,
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
    /// The latest environment aggregate of each remote vehicle and property (bounded).
    pub environment: Vec<RemoteEnvironmentView>,
    /// Whether the command lease is in force (`[federation.lease] enabled`).
    pub lease_enabled: bool,
    /// Every command lease this site knows, by vehicle.
    pub leases: Vec<LeaseView>,
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

/// Another site's environment data: one property of one vehicle over one window.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RemoteEnvironmentView {
    /// The site whose vehicle measured it.
    pub site: String,
    /// The vehicle.
    pub vehicle_id: String,
    /// The property (e.g. `sea_water_temperature`).
    pub property: String,
    /// Its unit.
    pub unit: String,
    /// The window, ms since the Unix epoch: from …
    pub window_start_ms: i64,
    /// … to.
    pub window_end_ms: i64,
    /// Observations in the window.
    pub count: u64,
    /// Least value.
    pub min: f64,
    /// Greatest value.
    pub max: f64,
    /// Mean value.
    pub mean: f64,
    /// The window's last value …
    pub last_value: f64,
    /// … when it was measured, ms since the Unix epoch, …
    pub last_ms: i64,
    /// … and where: latitude, degrees, …
    pub latitude_deg: f64,
    /// … longitude, degrees, …
    pub longitude_deg: f64,
    /// … depth, metres.
    pub depth_m: f64,
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

    /// Hands the command lease of `vehicle`, which this station holds, to site `to`.
    pub fn hand_over_lease(&self, vehicle: &str, to: &str) -> Result<LeaseView, HandoverRefused> {
        let view = self
            .core
            .federation
            .get()
            .ok_or(HandoverRefused::NotInForce)?;
        let lease = view.hand_over(vehicle, to)?;
        // Logged at the station too: an operator's decision about who commands a vehicle.
        tracing::info!(vehicle, to, term = lease.term, "command lease handed over");
        Ok(lease)
    }

    /// The site whose vehicle `vehicle` is, when the federation knows it as another site's.
    pub(crate) fn home_of(&self, vehicle: &str) -> Option<String> {
        self.core.federation.get()?.home_of(vehicle)
    }

    /// Sends a task to its vehicle's site (see [`FederationView::relay`]).
    pub(crate) fn relay(&self, task: &TaskAssignment, site: &str) -> Result<(), RelayRefused> {
        match self.core.federation.get() {
            Some(view) => view.relay(task),
            None => Err(RelayRefused::Refused {
                vehicle: task.vehicle_id.clone(),
                site: site.to_owned(),
                why: "this station is not federated".into(),
            }),
        }
    }

    /// Whether this station may command `vehicle` under the command lease (always when it
    /// is not federated).
    pub(crate) fn may_command(&self, vehicle: &str) -> Result<LeaseGrant, LeaseDenial> {
        match self.core.federation.get() {
            Some(view) => view.may_command(vehicle),
            None => Ok(LeaseGrant::NONE),
        }
    }
}

#[cfg(test)]
mod tests;
