//! Why an acoustic frame was refused, and counters of refusals by reason for logs and tests.

use std::collections::BTreeMap;
use std::fmt;

use crate::replay::ReplayError;

/// Why an acoustic frame was refused by [`AcousticTagger::open`](crate::AcousticTagger::open).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum Rejection {
    /// The counter was seen before or is older than the replay window.
    #[error("replayed: {0}")]
    Replayed(ReplayError),
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
    /// [`Rejection::Replayed`].
    Replayed,
    /// [`Rejection::NoKey`].
    NoKey,
    /// [`Rejection::BadTag`].
    BadTag,
    /// [`Rejection::FrameTooShort`].
    FrameTooShort,
}

impl RejectionReason {
    /// Every reason, in declaration order.
    pub const ALL: [Self; 4] = [
        Self::Replayed,
        Self::NoKey,
        Self::BadTag,
        Self::FrameTooShort,
    ];

    /// The stable code, e.g. `bad_tag`.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Replayed => "replayed",
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
            Self::Replayed(_) => RejectionReason::Replayed,
            Self::NoKey { .. } => RejectionReason::NoKey,
            Self::BadTag => RejectionReason::BadTag,
            Self::FrameTooShort { .. } => RejectionReason::FrameTooShort,
        }
    }
}

/// How many frames were refused, by reason.
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
        c.record(&Rejection::NoKey { address: 3 });
        assert_eq!(c.get(RejectionReason::BadTag), 2);
        assert_eq!(c.get(RejectionReason::Replayed), 0);
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
