//! Why a message was refused, and counters of refusals by reason for metrics and tests.

use std::collections::BTreeMap;
use std::fmt;

use crate::cert::{CertError, CertId};
use crate::envelope::DecodeError;
use crate::policy::{Denied, DenyReason};
use crate::replay::ReplayError;
use crate::util;

/// Why an envelope or acoustic frame was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum Rejection {
    /// The bytes are not an envelope.
    #[error("malformed envelope: {0}")]
    Malformed(#[from] DecodeError),
    /// A compact envelope names a certificate this verifier has not seen.
    #[error("unknown certificate {0} (send the full certificate first)")]
    UnknownCertificate(CertId),
    /// The embedded certificate does not parse or is not a Shoal leaf certificate.
    #[error("bad certificate: {0}")]
    BadCertificate(CertError),
    /// The certificate was not issued by the trusted station CA.
    #[error("certificate not issued by the station CA")]
    UntrustedCertificate,
    /// The sender's certificate has expired.
    #[error("certificate {serial} expired on {}", util::rfc3339(*.not_after_ms))]
    CertificateExpired {
        /// Its serial number.
        serial: String,
        /// End of its validity.
        not_after_ms: i64,
    },
    /// The sender's certificate is not valid yet.
    #[error("certificate {serial} is not valid before {}", util::rfc3339(*.not_before_ms))]
    CertificateNotYetValid {
        /// Its serial number.
        serial: String,
        /// Start of its validity.
        not_before_ms: i64,
    },
    /// The station CA itself has expired: nothing can be trusted until it is renewed.
    #[error("the station CA expired on {}", util::rfc3339(*.not_after_ms))]
    CaExpired {
        /// End of the CA's validity.
        not_after_ms: i64,
    },
    /// The sender's certificate is on the revocation list.
    #[error("certificate {serial} is revoked")]
    Revoked {
        /// Its serial number.
        serial: String,
    },
    /// The signature does not match the content and certificate.
    #[error("bad signature")]
    BadSignature,
    /// The timestamp is older than the freshness window.
    #[error("stale: sent {age_ms} ms ago")]
    Stale {
        /// How old, by the receiver's clock.
        age_ms: i64,
    },
    /// The timestamp is further ahead of the receiver's clock than the allowed skew.
    #[error("from the future: {ahead_ms} ms ahead")]
    FromFuture {
        /// How far ahead.
        ahead_ms: i64,
    },
    /// The counter was seen before or is older than the replay window.
    #[error("replayed: {0}")]
    Replayed(ReplayError),
    /// The access policy does not let this sender publish this.
    #[error("denied: {0}")]
    Denied(#[from] Denied),
    /// The signed payload does not decode as the topic's type (or has no instance key).
    #[error("payload does not decode: {0}")]
    MalformedPayload(String),
    /// An acoustic frame from (or broadcast to) an address without a key.
    #[error("no acoustic key for address {address}")]
    NoKey {
        /// The address whose key is missing.
        address: u8,
    },
    /// The acoustic frame's tag does not verify.
    #[error("bad acoustic tag")]
    BadTag,
    /// The acoustic frame is too short to hold a counter and tag.
    #[error("acoustic frame of {len} bytes is shorter than the {min}-byte trailer")]
    FrameTooShort {
        /// Frame length.
        len: usize,
        /// The trailer length.
        min: usize,
    },
}

/// A rejection's kind without its details: a stable short code for counting and logs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[non_exhaustive]
pub enum RejectionReason {
    /// [`Rejection::Malformed`].
    Malformed,
    /// [`Rejection::UnknownCertificate`].
    UnknownCertificate,
    /// [`Rejection::BadCertificate`].
    BadCertificate,
    /// [`Rejection::UntrustedCertificate`].
    UntrustedCertificate,
    /// [`Rejection::CertificateExpired`].
    CertificateExpired,
    /// [`Rejection::CertificateNotYetValid`].
    CertificateNotYetValid,
    /// [`Rejection::CaExpired`].
    CaExpired,
    /// [`Rejection::Revoked`].
    Revoked,
    /// [`Rejection::BadSignature`].
    BadSignature,
    /// [`Rejection::Stale`].
    Stale,
    /// [`Rejection::FromFuture`].
    FromFuture,
    /// [`Rejection::Replayed`].
    Replayed,
    /// [`Rejection::Denied`] because the topic is not allowed to this sender.
    TopicNotAllowed,
    /// [`Rejection::Denied`] because the instance belongs to someone else (impersonation).
    WrongInstance,
    /// [`Rejection::MalformedPayload`].
    MalformedPayload,
    /// [`Rejection::NoKey`].
    NoKey,
    /// [`Rejection::BadTag`].
    BadTag,
    /// [`Rejection::FrameTooShort`].
    FrameTooShort,
}

impl RejectionReason {
    /// Every reason, in declaration order.
    pub const ALL: [Self; 18] = [
        Self::Malformed,
        Self::UnknownCertificate,
        Self::BadCertificate,
        Self::UntrustedCertificate,
        Self::CertificateExpired,
        Self::CertificateNotYetValid,
        Self::CaExpired,
        Self::Revoked,
        Self::BadSignature,
        Self::Stale,
        Self::FromFuture,
        Self::Replayed,
        Self::TopicNotAllowed,
        Self::WrongInstance,
        Self::MalformedPayload,
        Self::NoKey,
        Self::BadTag,
        Self::FrameTooShort,
    ];

    /// The stable code, e.g. `bad_signature`.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Malformed => "malformed",
            Self::UnknownCertificate => "unknown_certificate",
            Self::BadCertificate => "bad_certificate",
            Self::UntrustedCertificate => "untrusted_certificate",
            Self::CertificateExpired => "certificate_expired",
            Self::CertificateNotYetValid => "certificate_not_yet_valid",
            Self::CaExpired => "ca_expired",
            Self::Revoked => "revoked",
            Self::BadSignature => "bad_signature",
            Self::Stale => "stale",
            Self::FromFuture => "from_future",
            Self::Replayed => "replayed",
            Self::TopicNotAllowed => "topic_not_allowed",
            Self::WrongInstance => "wrong_instance",
            Self::MalformedPayload => "malformed_payload",
            Self::NoKey => "no_key",
            Self::BadTag => "bad_tag",
            Self::FrameTooShort => "frame_too_short",
        }
    }
}

impl fmt::Display for RejectionReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl Rejection {
    /// The reason code of this rejection.
    pub fn reason(&self) -> RejectionReason {
        match self {
            Self::Malformed(_) => RejectionReason::Malformed,
            Self::UnknownCertificate(_) => RejectionReason::UnknownCertificate,
            Self::BadCertificate(_) => RejectionReason::BadCertificate,
            Self::UntrustedCertificate => RejectionReason::UntrustedCertificate,
            Self::CertificateExpired { .. } => RejectionReason::CertificateExpired,
            Self::CertificateNotYetValid { .. } => RejectionReason::CertificateNotYetValid,
            Self::CaExpired { .. } => RejectionReason::CaExpired,
            Self::Revoked { .. } => RejectionReason::Revoked,
            Self::BadSignature => RejectionReason::BadSignature,
            Self::Stale { .. } => RejectionReason::Stale,
            Self::FromFuture { .. } => RejectionReason::FromFuture,
            Self::Replayed(_) => RejectionReason::Replayed,
            Self::Denied(d) => match d.reason {
                DenyReason::TopicNotAllowed => RejectionReason::TopicNotAllowed,
                DenyReason::WrongInstance => RejectionReason::WrongInstance,
            },
            Self::MalformedPayload(_) => RejectionReason::MalformedPayload,
            Self::NoKey { .. } => RejectionReason::NoKey,
            Self::BadTag => RejectionReason::BadTag,
            Self::FrameTooShort { .. } => RejectionReason::FrameTooShort,
        }
    }
}

/// How many messages were refused, by reason.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct RejectionCounts {
    counts: BTreeMap<RejectionReason, u64>,
}

impl RejectionCounts {
    /// No rejections yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// Counts one rejection.
    pub fn record(&mut self, rejection: &Rejection) {
        self.add(rejection.reason(), 1);
    }

    /// Adds `n` rejections for `reason`.
    pub fn add(&mut self, reason: RejectionReason, n: u64) {
        *self.counts.entry(reason).or_default() += n;
    }

    /// How many were refused for `reason`.
    pub fn get(&self, reason: RejectionReason) -> u64 {
        self.counts.get(&reason).copied().unwrap_or(0)
    }

    /// How many were refused in all.
    pub fn total(&self) -> u64 {
        self.counts.values().sum()
    }

    /// Reasons with at least one rejection, with their counts, in reason order.
    pub fn iter(&self) -> impl Iterator<Item = (RejectionReason, u64)> + '_ {
        self.counts.iter().map(|(r, n)| (*r, *n))
    }

    /// Adds another set of counts to this one.
    pub fn merge(&mut self, other: &Self) {
        for (r, n) in other.iter() {
            self.add(r, n);
        }
    }
}

impl fmt::Display for RejectionCounts {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (reason, n) in self.iter() {
            writeln!(f, "{:<26} {n:>8}", reason.as_str())?;
        }
        write!(f, "{:<26} {:>8}", "total", self.total())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_add_up_by_reason() {
        let mut c = RejectionCounts::new();
        c.record(&Rejection::BadTag);
        c.record(&Rejection::BadTag);
        c.record(&Rejection::BadSignature);
        assert_eq!(c.get(RejectionReason::BadTag), 2);
        assert_eq!(c.get(RejectionReason::Stale), 0);
        assert_eq!(c.total(), 3);
        let mut d = RejectionCounts::new();
        d.merge(&c);
        d.merge(&c);
        assert_eq!(d.total(), 6);
        let text = d.to_string();
        assert!(text.contains("bad_tag"), "{text}");
        assert!(text.ends_with("6"), "{text}");
    }

    #[test]
    fn reason_codes_are_distinct() {
        let codes: std::collections::BTreeSet<_> =
            RejectionReason::ALL.iter().map(|r| r.as_str()).collect();
        assert_eq!(codes.len(), RejectionReason::ALL.len());
    }
}
