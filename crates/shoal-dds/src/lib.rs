//! Shoal's Publish/Subscribe Manager: the only crate that talks to the DDS library.
//!
//! - [`PubSub`] owns the process's one DDS participant (RustDDS), confined to the
//!   interfaces in [`DdsConfig`] (loopback by default), and creates typed endpoints.
//! - [`Writer<T>`] publishes validated samples in a [`Priority`] class; a failed write hands
//!   the sample back ([`WriteError`]).
//! - [`Subscription<T>`] is an async stream of validated samples with [`SampleMeta`];
//!   malformed or invalid samples come out as [`ReadError`]s and the stream goes on.
//! - [`TopicType`] binds each model type of `shoal-model` to its topic name, IDL type
//!   name, key and [`QosProfile`].
//!
//! DDS threads stay inside RustDDS; what comes out is `futures` streams, usable from tokio.

mod config;
mod error;
mod manager;
mod qos;
mod topics;

pub use config::DdsConfig;
pub use error::{CreateError, ReadError, WriteError};
pub use manager::{ParticipantEvent, PubSub, SampleMeta, Subscription, Writer};
pub use qos::{Priority, QosProfile, WriterOptions};
pub use topics::{ALL_TOPICS, ObservationKey, TopicType};

/// Serialises a sample exactly as it goes on the wire: a 4-byte encapsulation header
/// (CDR little endian, RTPS 10.5) followed by XCDR1 plain CDR. For interop checks and tools.
pub fn to_cdr_le<T: TopicType>(sample: &T) -> Result<Vec<u8>, String> {
    let mut out = vec![0x00, 0x01, 0x00, 0x00];
    let body = rustdds::cdr_encoding::to_vec::<T, byteorder::LittleEndian>(sample)
        .map_err(|e| e.to_string())?;
    out.extend_from_slice(&body);
    Ok(out)
}
