//! Shoal's middleware core at the Command and Control Station, as the architecture's
//! services:
//!
//! - [`ingest`](crate::IngestStats) — the Data Access Manager: the one entry for data
//!   heard from vehicles (plausibility, latest state, semantic model, history), typed
//!   [`Rejection`]s counted, quarantined and reported.
//! - `register` — the Vehicle & Service Register: registration, contact, availability
//!   ([`VehicleView`]); the one owner of a vehicle's live state.
//! - `missions` — the Mission & Task Register and dispatch ([`MissionView`], [`TaskView`]).
//! - `reporters` — the Event, Tasks and Environment Reporters and the live feed
//!   ([`LiveUpdate`]).
//! - `rules` — Rules & Policies as the API and the rules file see them ([`RuleDoc`]).
//! - `scenario` — a scenario file's missions started on their timeline through the
//!   Mission Manager ([`StationHandle::run_scenario`]).
//! - `traffic` — AIS vessels in the semantic model and surface vehicles' encounters with
//!   them; the collision-risk rule turns a close one into an alarm.
//!
//! [`StationHandle`] is the core: the bus feeds it, the API reads and commands through
//! it, and it publishes through an [`Outbox`], so it runs in plain unit tests. [`Station`]
//! wires it to the Publish/Subscribe Manager and runs it.

#![forbid(unsafe_code)]

mod bus;
mod clock;
mod config;
mod core;
mod error;
mod federation;
mod health;
mod ingest;
mod missions;
mod register;
mod reporters;
mod rules;
mod scenario;
mod station;
#[cfg(test)]
mod testing;
mod traffic;

pub use bus::{DdsOutbox, EventOrigin, Outbox, PublishError};
pub use clock::{Clock, ManualTime};
pub use config::StationConfig;
pub use core::StationHandle;
pub use error::{
    ConfigError, DispatchError, Rejection, RuleChangeError, StationError, SubscriptionError,
};
pub use federation::{
    FederationSnapshot, FederationView, HandoverRefused, LeaseDenial, LeaseGrant, LeaseView,
    RelayRefused, RemoteAlarmView, RemoteEnvironmentView, RemoteTransitionView, RemoteVehicleView,
    SiteView,
};
pub use health::{
    DdsHealth, HealthThresholds, HealthVerdict, HistoryHealth, SemanticHealth, StationHealth,
};
pub use ingest::IngestStats;
pub use ingest::preprocess::{Implausible, PlausibilityConfig};
pub use missions::{
    MissionPreview, MissionSpec, MissionState, MissionTaskSpec, MissionView, TaskView,
    VehiclePreview,
};
pub use register::{Contact, VehicleView};
pub use reporters::{Ack, EnvSubscription, EnvSubscriptionSpec, EventView, LiveUpdate};
pub use rules::{ConditionDoc, RuleDoc, RulesFileError};
pub use shoal_model::Availability;
pub use station::{Station, StationReport};
