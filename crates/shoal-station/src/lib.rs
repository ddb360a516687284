//! Shoal's middleware core at the Command and Control Station.
//!
//! - [`Station`] subscribes to every Shoal topic through the Publish/Subscribe Manager,
//!   validates each datum (the Data Pre-Processor's type and range checks; samples that
//!   fail are counted by reason, quarantined in the history store and reported as
//!   events), keeps the Vehicle Register's live view ([`VehicleView`]), writes every
//!   accepted datum to the history store, and watches contact (stale, lost).
//! - [`StationHandle`] is what the API uses: fleet, counters ([`IngestStats`]), history
//!   queries, events, and task dispatch.
//! - [`StationConfig`] is the `[station]` configuration section.

mod config;
mod error;
mod fleet;
mod missions;
mod preprocess;
mod reporters;
mod rules;
mod station;

pub use config::StationConfig;
pub use error::{DispatchError, RuleChangeError, StationError};
pub use fleet::{Availability, Contact, VehicleView};
pub use missions::{MissionSpec, MissionState, MissionTaskSpec, MissionView, TaskView};
pub use preprocess::{Implausible, PlausibilityConfig};
pub use reporters::{Ack, EnvSubscription, EnvSubscriptionSpec, EventView, LiveUpdate};
pub use rules::{ConditionDoc, RuleDoc, RulesFileError};
pub use station::{IngestStats, Station, StationHandle, StationReport};
