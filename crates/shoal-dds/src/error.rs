//! Errors of the Publish/Subscribe Manager, split by operation.

use shoal_model::ValidationError;

/// Creating the participant, a topic, a reader or a writer failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CreateError {
    /// The DDS library refused.
    #[error("DDS could not create {what}: {source}")]
    Dds {
        /// What was being created.
        what: String,
        /// Why.
        source: DdsError,
    },
    /// A topic's type cannot be declared to DDS.
    #[error("topic {topic}: {source}")]
    Type {
        /// The topic.
        topic: String,
        /// What is wrong with its type.
        source: TypeError,
    },
    /// The topic exists in this participant already, with another type.
    #[error("topic {topic} already carries {existing}, not {requested}")]
    TopicTypeMismatch {
        /// The topic.
        topic: String,
        /// The type it has.
        existing: String,
        /// The type asked for.
        requested: String,
    },
    /// The configuration cannot work.
    #[error("invalid DDS configuration: {0}")]
    Config(String),
    /// A DDS Security file (certificate, key, governance, permissions, revocation list) is
    /// missing or unusable: nothing is created half-secured.
    // Not a `#[source]`: the message already carries the file and its problem, and a
    // source would make every error chain print them twice.
    #[error("DDS Security: {0}")]
    Credentials(shoal_security::FileError),
}

impl From<shoal_security::FileError> for CreateError {
    fn from(e: shoal_security::FileError) -> Self {
        Self::Credentials(e)
    }
}

/// A call into the DDS library (Cyclone DDS) failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum DdsError {
    /// The library returned an error code (`DDS_RETCODE_*`).
    #[error("{message} (DDS return code {code})")]
    Code {
        /// The return code (negative).
        code: i32,
        /// The library's words for it.
        message: String,
    },
    /// A name or configuration text holds a NUL byte, which a C string cannot carry.
    #[error("{0:?} holds a NUL byte, which DDS cannot take")]
    Nul(String),
    /// The domain is open in this process already with another configuration: Cyclone
    /// has one configuration per domain and process.
    #[error("domain {0} is already open in this process with other interfaces or buffers")]
    DomainConflict(u16),
}

/// A topic type whose layout cannot be declared to DDS: a mistake in a
/// [`TopicType`](crate::TopicType), found when its topic is first created.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum TypeError {
    /// `serde-reflection` could not trace the type's `Deserialize` implementation.
    #[error("cannot trace the layout of {type_name}: {detail}")]
    Trace {
        /// The DDS type name.
        type_name: String,
        /// The tracer's message (its error holds `Rc`s, so it cannot travel in an error
        /// that must be `Send`).
        detail: String,
    },
    /// The type is not a struct.
    #[error("{0} is not a struct")]
    NotStruct(String),
    /// A declared key field is not a field of the type.
    #[error("{type_name} has no key field {key}")]
    NoKeyField {
        /// The DDS type name.
        type_name: String,
        /// The missing field.
        key: String,
    },
    /// The type uses something with no DDS equivalent here (a map, an option, a unit
    /// struct, an enum carrying data, a size beyond 32 bits...).
    #[error("{type_name} uses {what}, which has no DDS equivalent here")]
    Unsupported {
        /// The DDS type name.
        type_name: String,
        /// What it uses.
        what: String,
    },
    /// The library refused a step of building or registering the type.
    #[error("{type_name}: {step}: {source}")]
    Dds {
        /// The DDS type name.
        type_name: String,
        /// The step (`member x`, `key`, `register`...).
        step: String,
        /// Why.
        source: DdsError,
    },
}

/// A sample could not be turned into CDR bytes ([`to_cdr_le`](crate::to_cdr_le)) or back
/// ([`from_cdr`](crate::from_cdr)).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CdrError {
    /// The sample does not serialise as CDR (a type CDR cannot express, e.g. a map).
    #[error("cannot encode as CDR: {0}")]
    Encode(#[source] cdr_encoding::Error),
    /// Too few bytes for the 4-byte encapsulation header.
    #[error("{0} bytes cannot hold a CDR encapsulation header")]
    TooShort(usize),
    /// An encapsulation other than plain CDR (XCDR1) in either byte order.
    #[error("unsupported CDR encapsulation {0:02x?}")]
    Encapsulation([u8; 2]),
    /// The body does not decode as the type.
    #[error("cannot decode CDR: {0}")]
    Decode(#[source] cdr_encoding::Error),
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
    /// The sample could not be serialised (a type CDR cannot express).
    #[error("not sent, cannot encode: {source}")]
    Encode {
        /// Why.
        source: CdrError,
        /// The sample, back to the caller.
        sample: T,
    },
    /// A reliable writer's history stayed full of samples readers have not acknowledged
    /// for longer than the writer may block: worth retrying later.
    #[error("DDS write failed: reliable history full, readers are not acknowledging")]
    HistoryFull {
        /// The sample, back to the caller.
        sample: T,
    },
    /// The DDS library could not send it.
    #[error("DDS write failed: {source}")]
    Dds {
        /// The library's error.
        source: DdsError,
        /// The sample, back to the caller.
        sample: T,
    },
}

impl<T> WriteError<T> {
    /// The sample that was not written.
    pub fn into_sample(self) -> T {
        match self {
            Self::Invalid { sample, .. }
            | Self::Encode { sample, .. }
            | Self::HistoryFull { sample }
            | Self::Dds { sample, .. } => sample,
        }
    }
}

/// An instance could not be disposed or unregistered.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum EndError {
    /// The instance key could not be serialised.
    #[error("instance key cannot be encoded: {0}")]
    Encode(#[from] CdrError),
    /// The DDS library refused it.
    #[error("DDS could not end the instance: {0}")]
    Dds(#[from] DdsError),
}

/// Why a sample was not sent, before it is handed back in a [`WriteError`].
#[derive(Debug)]
pub(crate) enum SendError {
    /// See [`WriteError::Encode`].
    Encode(CdrError),
    /// See [`WriteError::HistoryFull`].
    HistoryFull,
    /// See [`WriteError::Dds`].
    Dds(DdsError),
}

impl SendError {
    /// The error for the caller, with the sample back.
    pub(crate) fn with<T>(self, sample: T) -> WriteError<T> {
        match self {
            Self::Encode(source) => WriteError::Encode { source, sample },
            Self::HistoryFull => WriteError::HistoryFull { sample },
            Self::Dds(source) => WriteError::Dds { source, sample },
        }
    }
}

impl From<CdrError> for SendError {
    fn from(e: CdrError) -> Self {
        Self::Encode(e)
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
    /// The sample came from a writer in one vehicle's partition (so, on a secured bus, from
    /// that authenticated vehicle) but speaks for another vehicle.
    #[error(
        "sample on {topic} refused: published as vehicle {publisher} but about vehicle {claimed}"
    )]
    Impersonation {
        /// Topic name.
        topic: &'static str,
        /// The vehicle whose partition the writer publishes in.
        publisher: String,
        /// The vehicle the sample names.
        claimed: String,
    },
    /// The sample came from a vehicle whose certificate was revoked while this participant
    /// runs.
    #[error("sample on {topic} refused: vehicle {vehicle} is revoked")]
    Revoked {
        /// Topic name.
        topic: &'static str,
        /// The revoked vehicle.
        vehicle: String,
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Errors travel between tasks and into `anyhow`: a field that is not `Send` (such as
    /// serde-reflection's error, which holds `Rc`s) would break every caller's build.
    #[test]
    fn errors_can_cross_threads() {
        fn check<E: std::error::Error + Send + Sync + 'static>() {}
        check::<CreateError>();
        check::<DdsError>();
        check::<TypeError>();
        check::<CdrError>();
        check::<ReadError>();
        check::<EndError>();
        check::<WriteError<shoal_model::StateVector>>();
    }
}
