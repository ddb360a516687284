//! Shoal's Publish/Subscribe Manager: the only crate that talks to the DDS library.
//!
//! - [`PubSub`] owns the process's one DDS participant (Eclipse Cyclone DDS), confined to the
//!   interfaces in [`DdsConfig`] (loopback by default), and creates typed endpoints.
//! - [`Writer<T>`] publishes validated samples in a [`Priority`] class; a failed write hands
//!   the sample back ([`WriteError`]).
//! - [`Subscription<T>`] is an async stream of validated samples with [`SampleMeta`];
//!   malformed or invalid samples come out as [`ReadError`]s and the stream goes on.
//! - [`TopicType`] binds each model type of `shoal-model` to its topic name, IDL type
//!   name, key and [`QosProfile`].
//!
//! - With [`Credentials`] ([`PubSub::with_credentials`]) the participant runs OMG DDS
//!   Security 1.1 (Cyclone's built-in plugins): authenticated, access-controlled by signed
//!   permissions, encrypted as the governance says.
//!
//! DDS threads stay inside Cyclone; what comes out is `futures` streams, usable from tokio:
//! a reader's data-available listener wakes the stream's task, which takes the samples
//! itself, so a sample crosses one thread boundary between the socket and async code.

mod config;
mod cyclone;
mod error;
mod log_budget;
mod manager;
mod omg;
mod qos;
mod shape;
mod topics;

pub use config::DdsConfig;
pub use error::{CdrError, CreateError, DdsError, EndError, ReadError, TypeError, WriteError};
pub use log_budget::LogBudget;
pub use manager::{
    Delivery, Listening, ParticipantEvent, PubSub, SampleMeta, Subscription, Writer,
};
pub use omg::{Credentials, handshake_refusals};
pub use qos::{Priority, QosProfile, WriterOptions};
pub use topics::{ALL_TOPICS, ObservationKey, TopicType};

/// The Cyclone DDS XML configuration Shoal gives its domain for `config`: usable as
/// `CYCLONEDDS_URI` for other Cyclone-based processes (a vehicle's own DDS stack,
/// `ddsperf`) that should use the same interfaces and transport settings.
pub fn cyclone_config(config: &DdsConfig) -> String {
    cyclone::domain_xml(config)
}

/// Serialises a sample exactly as it goes on the wire: a 4-byte encapsulation header
/// (CDR little endian, RTPS 10.5) followed by XCDR1 plain CDR. For interop checks and tools.
pub fn to_cdr_le<T: serde::Serialize>(sample: &T) -> Result<Vec<u8>, CdrError> {
    let mut out = vec![0x00, 0x01, 0x00, 0x00];
    let body =
        cdr_encoding::to_vec::<T, byteorder::LittleEndian>(sample).map_err(CdrError::Encode)?;
    out.extend_from_slice(&body);
    Ok(out)
}

/// Decodes the bytes [`to_cdr_le`] makes (either byte order of plain CDR).
pub fn from_cdr<T: serde::de::DeserializeOwned>(bytes: &[u8]) -> Result<T, CdrError> {
    let (header, body) = bytes
        .split_at_checked(4)
        .ok_or(CdrError::TooShort(bytes.len()))?;
    let decoded = match [header[0], header[1]] {
        [0x00, 0x01] => cdr_encoding::from_bytes::<T, byteorder::LittleEndian>(body),
        [0x00, 0x00] => cdr_encoding::from_bytes::<T, byteorder::BigEndian>(body),
        other => return Err(CdrError::Encapsulation(other)),
    };
    decoded.map(|(v, _)| v).map_err(CdrError::Decode)
}
