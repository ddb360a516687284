//! Shoal's traffic picture: AIS and NMEA 0183 inputs, surface targets and collision warnings (CPA/TCPA).
//!
//! - [`Picture`] is the core, without I/O: lines in ([`Picture::ingest_line`]), targets,
//!   own ship and counters as state, the pairs of own vehicles and targets that come close ([`Picture::approaches`]) out. Time is passed in.
//! - [`TrafficPicture::spawn`] runs the configured UDP and TCP inputs on tokio around one
//!   shared `Picture` and returns a [`TrafficHandle`].
//! - [`cpa()`] is the pure closest-point-of-approach computation.
//!
//! See docs/traffic.md for the configuration, the sentences read and the counters.

#![forbid(unsafe_code)]

mod config;
mod cpa;
mod decode;
mod framing;
mod picture;
mod service;

pub use config::{ConfigError, Input, TrafficConfig};
pub use cpa::{
    Approach, ApproachWindow, MS_PER_KNOT, Motion, OwnVehicle, TargetMotion, VesselApproach,
    approaches, cpa,
};
pub use decode::{Class, Dimensions};
pub use picture::{OwnShipView, Picture, TargetView, TrafficStats};
pub use service::{TrafficError, TrafficHandle, TrafficPicture};
