//! Shoal's recorder: every Shoal topic into MCAP files, and their replay onto DDS.
//!
//! - [`Recorder`] subscribes to the Shoal topics on a [`shoal_dds::PubSub`] and writes
//!   chunked, zstd-compressed MCAP files through a [`RecordWriter`], rotated by size and
//!   time, with every chunk on disk within a second (a recorder killed with SIGKILL
//!   loses at most the last second).
//! - [`McapMessages`] reads an MCAP file front to back, chunk by chunk, and says at which
//!   byte offset a damaged or truncated file stopped being readable.
//! - [`Replayer`] publishes recorded samples again on DDS at the recorded pace (or faster),
//!   each through the participant allowed to speak for it ([`Publishers`]).
//! - [`AcousticRecorder`] writes what a CDT's frame tap reports (frames sent and received,
//!   each message's fate on the acoustic link) into MCAP files of their own, as JSON with
//!   JSON Schemas ([`acoustic`]).
//!
//! The DDS topics' schemas are `omgidl` (the text of `idl/shoal.idl`), messages `cdr`:
//! the 4-byte encapsulation header and the XCDR1 body, exactly as they travel on DDS.

#![forbid(unsafe_code)]

pub mod acoustic;
mod config;
mod error;
mod reader;
mod recorder;
mod replay;
mod topic;
mod writer;

#[cfg(test)]
mod tests;

pub use acoustic::{AcousticRecorder, AcousticStats, AcousticWriter};
pub use config::{Compression, RecorderConfig};
pub use error::{ReadError, RecordError, ReplayError};
pub use reader::{McapMessages, ReaderStats, RecordedMessage, mcap_files};
pub use recorder::{Recorder, RecorderStats};
pub use replay::{
    Identity, Publishers, ReplayOptions, ReplayStats, Replayer, Speed, decode_message,
    publishing_vehicles,
};
pub use topic::{Sample, Topic};
pub use writer::{FLUSH_INTERVAL, RecordWriter, WriterStats};

/// The IDL every recorded schema carries (`omgidl` schema encoding).
pub const SHOAL_IDL: &str = include_str!("../../../idl/shoal.idl");
/// The MCAP schema encoding of the recorded schemas.
pub const SCHEMA_ENCODING: &str = "omgidl";
/// The MCAP message encoding of the recorded messages.
pub const MESSAGE_ENCODING: &str = "cdr";
/// The MCAP profile of the files (none of the well-known ones: plain DDS CDR).
pub const PROFILE: &str = "";
