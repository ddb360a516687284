//! The recorder's and replay's errors.

use std::path::PathBuf;

use shoal_dds::{CdrError, CreateError};

/// Recording failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RecordError {
    /// The configuration cannot work.
    #[error("invalid recorder configuration: {0}")]
    Config(String),
    /// A file or directory could not be created or written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file or directory.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The MCAP writer failed.
    #[error("{}: MCAP: {source}", path.display())]
    Mcap {
        /// The file being written.
        path: PathBuf,
        /// Why.
        source: mcap::McapError,
    },
    /// A sample could not be serialised.
    #[error("cannot encode a sample: {0}")]
    Encode(#[from] CdrError),
    /// An acoustic record could not be serialised as JSON.
    #[error("cannot encode an acoustic record as JSON: {0}")]
    Json(#[from] serde_json::Error),
    /// A subscription could not be created.
    #[error("cannot subscribe: {0}")]
    Subscribe(#[from] CreateError),
    /// The file writer thread could not be started or stopped abnormally.
    #[error("the recorder's writer thread: {0}")]
    Thread(String),
}

/// Reading an MCAP file stopped before its end. Every error names the byte offset up to
/// which the file was read and used: what lies before it was delivered.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ReadError {
    /// The file ends inside a record (a recorder killed while writing, a partial copy).
    #[error(
        "truncated: the file ends at byte {file_len} inside the record that starts at byte offset {offset}; reading stopped there"
    )]
    Truncated {
        /// Where the incomplete record starts: everything before was read.
        offset: u64,
        /// How many bytes the file has.
        file_len: u64,
    },
    /// The bytes at `offset` are not a valid MCAP record (or chunk).
    #[error("corrupt: reading stopped at byte offset {offset}: {detail}")]
    Corrupt {
        /// Where the bad record starts: everything before was read.
        offset: u64,
        /// What is wrong, in the MCAP library's words.
        detail: String,
    },
    /// The operating system failed to read.
    #[error("I/O error: reading stopped at byte offset {offset}: {source}")]
    Io {
        /// How far the file was read.
        offset: u64,
        /// Why.
        source: std::io::Error,
    },
}

impl ReadError {
    /// The byte offset where reading stopped.
    pub fn offset(&self) -> u64 {
        match self {
            Self::Truncated { offset, .. }
            | Self::Corrupt { offset, .. }
            | Self::Io { offset, .. } => *offset,
        }
    }
}

/// Replaying failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ReplayError {
    /// A file or directory could not be opened or listed.
    #[error("{}: {source}", path.display())]
    Open {
        /// The file or directory.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// A directory holds no `.mcap` file.
    #[error("{}: no .mcap files in it", .0.display())]
    NoFiles(PathBuf),
    /// A file could not be read to its end (what was before the offset was replayed).
    #[error("{}: {source}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// Where and why reading stopped.
        source: ReadError,
    },
    /// A participant or writer could not be created.
    #[error("cannot publish {what}: {source}")]
    Dds {
        /// For whom or on which topic.
        what: String,
        /// Why (boxed: DDS errors are large and replay's results are passed around).
        source: Box<CreateError>,
    },
    /// The domain is secure and the caller gave one participant for everything.
    #[error(
        "this participant has DDS Security credentials: one identity cannot publish every vehicle's data; replay each identity's samples through its own participant (Publishers::secure)"
    )]
    SecureShared,
    /// A secure replay runs a process per vehicle; a recording naming more is refused.
    #[error(
        "the recording names more than {max} vehicles: a secure replay runs one process per vehicle"
    )]
    TooManyVehicles {
        /// The limit.
        max: usize,
    },
}
