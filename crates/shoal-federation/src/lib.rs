//! Ship ↔ shore federation over Zenoh: what crosses between Shoal sites, how often, in
//! what encoding, and how a site catches up after its link was down.
//!
//! - [`FederationConfig`]: the `[federation]` section: this site, its remote sites, the
//!   endpoints, and per kind of data whether it crosses, how often and with what QoS.
//! - [`Federation`]: the running transport. The station pushes its local data
//!   ([`Federation::push_position`], [`Federation::push_alarm`],
//!   [`Federation::push_transition`], [`Federation::push_observation`]) and reads the
//!   remote part of the fleet picture
//!   ([`Federation::picture`], [`Federation::counters`], [`Federation::changed`]).
//! - The cores, tested without a network: [`outbound`] (rate limiting per vehicle,
//!   sequence numbers, catch-up journals) and [`inbound`] (validation, duplicate
//!   suppression, gaps, the [`FederatedPicture`]).
//! - [`environment`]: environment observations summarised per vehicle, property and
//!   window before they cross (`[federation.environment] mode = "aggregated"`).
//! - [`lease`]: the command lease, which site commands each vehicle (tested without a
//!   network like the other cores).
//! - [`orders`]: a task the lease holder sends to the vehicle's home site
//!   ([`Federation::relay_order`]), which delivers it to its station
//!   ([`Federation::take_orders`]) once it has checked the lease.
//! - [`signed`]: end-to-end signatures on lease records and orders (with TLS), checked
//!   against the signing site's own certificate whatever hops they crossed.
//! - [`wire`]: the compact WAN encoding; [`keys`]: the key expressions. Both are
//!   documented byte for byte in `docs/federation.md` for third-party clients.
//!
//! The `transport` feature (default) brings the Zenoh transport; without it the crate is
//! the cores and the codec alone (the fuzz targets build it so).

#![forbid(unsafe_code)]

pub mod config;
pub mod environment;
#[cfg(feature = "transport")]
mod error;
#[cfg(feature = "transport")]
mod federation;
pub mod inbound;
pub mod keys;
pub mod lease;
#[cfg(feature = "transport")]
mod lease_keeper;
pub mod orders;
pub mod outbound;
#[cfg(feature = "transport")]
mod pacing;
pub mod picture;
pub mod signed;
#[cfg(feature = "transport")]
mod site_keys;
mod tls;
pub mod types;
pub mod wire;
#[cfg(feature = "transport")]
mod zenoh_config;

pub use config::{
    ConfigError, EnvironmentMode, EnvironmentPolicy, FederationConfig, Identity, LeasePolicy,
    Secret, TlsConfig, TlsIdentity, UserPassword,
};
pub use environment::{EnvironmentAggregates, PropertyAggregate};
#[cfg(feature = "transport")]
pub use error::{ShutdownError, StartError};
#[cfg(feature = "transport")]
pub use federation::{Counters, Federation};
pub use inbound::{InboundCounters, Refusal};
pub use lease::{HandoverError, LeaseCounters, LeaseReason, LeaseRecord, LeaseTable};
#[cfg(feature = "transport")]
pub use lease_keeper::{CommandDenied, LeaseFileError};
pub use orders::{OrderError, OrderRefusal, RelayedOrder};
pub use outbound::{OutboundCounters, PushError};
pub use picture::{
    FederatedPicture, RemoteAlarm, RemoteEnvironment, RemoteTransition, RemoteVehicle, SiteStatus,
};
pub use types::{TaskTransition, VehiclePosition};
