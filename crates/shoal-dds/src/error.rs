//! Errors of the Publish/Subscribe Manager, split by operation.

use shoal_model::ValidationError;

/// Creating the participant, a topic, a reader or a writer failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CreateError {
    /// The DDS library refused.
    #[error("DDS could not create {what}: {detail}")]
    Dds {
        /// What was being created.
        what: String,
        /// The library's message.
        detail: String,
    },
    /// The configuration cannot work.
    #[error("invalid DDS configuration: {0}")]
    Config(String),
}

/// Writing a sample failed; the sample is handed back so the caller can retry or queue it.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum WriteError<T> {
    /// The sample failed its own validation and was not sent.
    #[error("not sent, invalid: {error}")]
    Invalid {
        /// Why.
        error: ValidationError,
        /// The sample, back to the caller.
        sample: T,
    },
    /// The DDS library could not send it (e.g. reliable history full for longer than allowed).
    #[error("DDS write failed: {detail}")]
    Dds {
        /// The library's message.
        detail: String,
        /// The sample, back to the caller.
        sample: T,
    },
}

impl<T> WriteError<T> {
    /// The sample that was not written.
    pub fn into_sample(self) -> T {
        match self {
            Self::Invalid { sample, .. } | Self::Dds { sample, .. } => sample,
        }
    }
}

/// A received sample could not be used.
#[derive(Debug, Clone, thiserror::Error)]
#[non_exhaustive]
pub enum ReadError {
    /// The bytes did not decode as the topic's type (a foreign writer with another type
    /// definition, or corrupt data).
    #[error("malformed sample on {topic}: {detail}")]
    Malformed {
        /// Topic name.
        topic: &'static str,
        /// Decoder message.
        detail: String,
    },
    /// The sample decoded but failed validation.
    #[error("invalid sample on {topic}: {error}")]
    Invalid {
        /// Topic name.
        topic: &'static str,
        /// Why.
        error: ValidationError,
        /// The sample as JSON (non-finite numbers become `null`), for the quarantine.
        payload: String,
    },
    /// Security is on and the sample came unsigned, on the plain topic.
    #[error("unsigned sample on {topic} refused (security is on)")]
    Unsigned {
        /// Topic name.
        topic: &'static str,
    },
    /// Security is on and the signed sample failed a check (signature, certificate,
    /// revocation, freshness, replay, publish policy).
    #[error("signed sample on {topic} refused: {reason}: {detail}")]
    Refused {
        /// Topic name.
        topic: &'static str,
        /// The stable reason code (`shoal_security::RejectionReason`), e.g. `bad_signature`.
        reason: &'static str,
        /// The details.
        detail: String,
    },
    /// Any other reader failure reported by DDS.
    #[error("DDS read failed on {topic}: {detail}")]
    Dds {
        /// Topic name.
        topic: &'static str,
        /// The library's message.
        detail: String,
    },
}
