//! Shoal's common data model: the typed topics exchanged between the station and vehicles.
//!
//! Each type here is one DDS topic type of `idl/shoal.idl`, field for field and in the same
//! order, so that its serde serialisation in CDR (as the Publish/Subscribe Manager writes
//! it) is what any other vendor's DDS produces from the IDL:
//!
//! - [`StateVector`]: the SWARMs State Vector, a vehicle's navigation and battery report.
//! - [`VehicleAnnouncement`]: who a vehicle is and what it can do (registration).
//! - [`TaskAssignment`]: a simple task from the station to one vehicle; [`Task`] is its
//!   typed view.
//! - [`TaskStatus`]: a vehicle's report on a task.
//! - [`Event`]: alarms, detections and task events.
//! - [`EnvironmentObservation`]: one measured environment property.
//! - [`LinkStatus`]: which link (IP, acoustic via a CDT) a vehicle is heard on, carried
//!   as a link-status [`Event`].
//!
//! Every type implements [`Validate`]; units and valid ranges are documented on each field
//! and exported as constants so codecs and checks share one source of truth. The crate has
//! no I/O and no async. [`Warp`] is the simulated clock a scenario run shares between
//! its station and its simulated vehicles.

#![forbid(unsafe_code)]

pub mod datetime;
mod environment;
mod event;
pub mod geo;
pub mod kinematics;
mod link;
pub mod ocean;
mod state;
pub mod survey;
mod task;
mod validate;
mod vehicle;
mod warp;

pub use environment::EnvironmentObservation;
pub use event::{Event, EventKind, Severity};
pub use link::{EVENT_ID_PREFIX as LINK_EVENT_PREFIX, LinkStatus};
pub use state::StateVector;
pub use task::{
    GeoPoint, MAX_LEASE_HOLDER_LEN, Task, TaskAssignment, TaskKind, TaskState, TaskStatus,
    lease_supersedes,
};
pub use validate::{Reason, Validate, Validated, ValidationError, is_identifier};
pub use vehicle::{Availability, LinkKind, VehicleAnnouncement, VehicleKind};
pub use warp::{MAX_WARP, Warp, WarpError};

/// Sentinel for an optional measurement that is not available (e.g. altitude at the surface).
pub const UNKNOWN: f64 = -1.0;
/// Earliest accepted timestamp: 2000-01-01T00:00:00Z in ms.
pub const MIN_TIMESTAMP_MS: i64 = 946_684_800_000;
/// Latest accepted timestamp: 2100-01-01T00:00:00Z in ms.
pub const MAX_TIMESTAMP_MS: i64 = 4_102_444_800_000;
/// Longest vehicle identifier, in bytes.
pub const MAX_VEHICLE_ID_LEN: usize = 32;
/// Longest task, mission or event identifier, in bytes.
pub const MAX_ID_LEN: usize = 64;
/// Longest name, vendor, capability or sensor string, in bytes.
pub const MAX_NAME_LEN: usize = 64;
/// Longest free-text message, in bytes.
pub const MAX_TEXT_LEN: usize = 512;

/// Milliseconds since the Unix epoch for a `SystemTime`; saturates instead of failing.
pub fn unix_ms(t: std::time::SystemTime) -> i64 {
    match t.duration_since(std::time::UNIX_EPOCH) {
        Ok(d) => i64::try_from(d.as_millis()).unwrap_or(i64::MAX),
        Err(e) => -i64::try_from(e.duration().as_millis()).unwrap_or(i64::MAX),
    }
}

/// The current time in milliseconds since the Unix epoch.
pub fn now_ms() -> i64 {
    unix_ms(std::time::SystemTime::now())
}
