//! Errors of the transport, split by operation.

use crate::config::ConfigError;

/// Why a federation could not start.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum StartError {
    /// The configuration cannot work.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// The lease state file (`lease.state_file`) cannot be read.
    #[error(transparent)]
    LeaseFile(#[from] crate::lease_keeper::LeaseFileError),
    /// Zenoh refused a step (the session, a declaration).
    #[error("zenoh: cannot {what}: {source}")]
    Zenoh {
        /// The step that failed.
        what: &'static str,
        /// Zenoh's error.
        #[source]
        source: zenoh::Error,
    },
}

/// Why a federation did not stop cleanly (it is stopped anyway).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ShutdownError {
    /// Closing the Zenoh session failed.
    #[error("zenoh: cannot close the session: {0}")]
    Close(#[source] zenoh::Error),
}
