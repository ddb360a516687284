//! Shoal's DDS-Acoustic Converter: the bridge between DDS topics and an acoustic modem.
//!
//! A submerged vehicle reaches the station only through an acoustic modem. As in SWARMs,
//! a converter runs on each side of the water (docs/architecture.md#links):
//!
//! - [`vdt`]: the **Vehicle Data Terminal** on the vehicle. [`run_vdt`] subscribes the
//!   vehicle's local DDS topics, encodes them as compact PDUs and sends them through the
//!   acoustic link layer in the right class; task PDUs from the CDT become
//!   `TaskAssignment`s on the vehicle's DDS, so its DDS Proxy runs them unmodified.
//! - [`cdt`]: the **Control Data Terminal** at the station or on a relay USV. [`run_cdt`]
//!   republishes what arrives with the same types and topics as an IP vehicle's, and
//!   forwards tasks for its vehicles through the modem.
//! - [`link_status`]: how the station tells acoustic data from IP data without new IDL
//!   types (a per-vehicle link-status event plus the writer's participant).
//! - [`failover`]: which link a vehicle with an IP path and an acoustic link uses now
//!   ([`failover::Failover`], network-free); the VDT and CDT act on it
//!   (docs/acoustic.md#link-failover).
//! - [`config`]: [`VdtConfig`] and [`CdtConfig`] (serde, defaults, `deny_unknown_fields`).
//! - [`Modem`]: the configured modem driver (EvoLogics AT or EviNS NL).
//! - [`emulated_relay`]: the SWARMs sea-trial topology in one call: any vehicle software on
//!   its private DDS domain → VDT → emulated sea → CDT on a relay → station (`shoal up`'s
//!   acoustic demo puts the simulator behind it).
//! - [`tap`]: [`FrameTap`], a bounded, never-blocking copy of a CDT's frames and link
//!   events for a recorder ([`CdtConfig::tap`]).
//!
//! The codec, the modem drivers, the link layer and the emulator live in `shoal-acoustic`;
//! this crate is the glue between them and the Publish/Subscribe Manager (`shoal-dds`).

#![forbid(unsafe_code)]

pub mod cdt;
mod common;
pub mod config;
mod dedup;
pub mod emulated_relay;
mod error;
pub mod failover;
pub mod link_status;
mod modem;
pub mod tap;
pub mod vdt;

pub use cdt::run_cdt;
pub use config::{
    AcousticTopics, AddressEntry, CdtConfig, IpPathConfig, LinkSettings, ModemKind, ModemPosition,
    ModemSettings, RelayEntry, TtlConfig, VdtConfig,
};
pub use error::ConverterError;
pub use link_status::LinkStatus;
pub use modem::Modem;
pub use tap::{FrameTap, MessageFate, TapEvent, TapQueue, TapRecord};
pub use vdt::{run_vdt, run_vdt_secured};
