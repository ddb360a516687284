//! Shoal's Foxglove live bridge: the station's topics over the Foxglove WebSocket protocol.
//!
//! [`Bridge::start`] subscribes to every Shoal topic on the station's DDS participant
//! and logs each sample to a Foxglove channel of the same name (schema: `idl/shoal.idl`
//! as `omgidl`, messages: CDR as DDS carries them), and each state vector also to
//! `shoal/location_fix` as `foxglove.LocationFix` for the Map panel. The Foxglove SDK's
//! own server runs on an ephemeral 127.0.0.1 port; clients reach it only through the
//! gateway ([`BridgeHandle::admit`], [`BridgeHandle::serve`]) that the console's
//! authenticated `/api/foxglove` route runs. See docs/foxglove.md.
#![forbid(unsafe_code)]

mod bridge;
pub mod channels;
mod config;
mod gateway;

pub use bridge::{Bridge, BridgeHandle, BridgeStats};
pub use config::{BridgeConfig, RateLimit, RateLimits};
pub use gateway::{ClientPlace, Frame, SessionEnd, Subprotocol, adapt, negotiate};

/// Why the bridge could not start or serve a client.
#[derive(Debug, thiserror::Error)]
pub enum BridgeError {
    /// A setting is out of range.
    #[error("bad Foxglove bridge setting: {0}")]
    Config(String),
    /// A DDS reader could not be created.
    #[error("the Foxglove bridge could not subscribe: {0}")]
    Subscribe(#[from] shoal_dds::CreateError),
    /// The Foxglove SDK refused (its server, a channel).
    #[error("Foxglove SDK: {0}")]
    Sdk(String),
    /// A sample could not be encoded for its channel.
    #[error("{topic}: not encodable as CDR: {source}")]
    Encode {
        /// Its topic.
        topic: &'static str,
        /// What the encoder said.
        #[source]
        source: shoal_dds::CdrError,
    },
    /// All places are taken.
    #[error("the Foxglove bridge has its {0} clients; try again later")]
    Busy(usize),
    /// The gateway could not reach the SDK's loopback server.
    #[error("the Foxglove bridge's server is unreachable: {0}")]
    Upstream(String),
}

#[doc(hidden)]
pub use bridge::BenchRig;
