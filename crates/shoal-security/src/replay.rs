//! A sliding anti-replay window over a sender's message counters (RFC 4303 §3.4.3).
//!
//! The receiver remembers the highest counter it accepted and, for the `size` counters just
//! below it, which ones it has seen. A counter above the highest moves the window; one inside
//! is accepted once; one below the window is refused, since it can no longer be told apart
//! from a replay. Out-of-order delivery within the window is therefore tolerated, which the
//! acoustic link (retransmissions) and DDS (one writer per topic) both need.

/// Why a counter was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ReplayError {
    /// This counter was accepted before.
    #[error("counter {0} was already received")]
    Duplicate(u64),
    /// The counter lies below the window; it may or may not have been seen.
    #[error("counter {counter} is older than the window (highest {highest}, window {size})")]
    TooOld {
        /// The refused counter.
        counter: u64,
        /// The highest counter accepted so far.
        highest: u64,
        /// The window size.
        size: u64,
    },
}

/// A sliding window of `size` counters (a multiple of 64, at least 64).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ReplayWindow {
    /// Highest counter accepted so far; `None` before the first.
    highest: Option<u64>,
    /// Bit `c % size` is set when counter `c` (within the window) was seen.
    bits: Vec<u64>,
}

impl ReplayWindow {
    /// Default window size: IPsec's customary 64.
    pub const DEFAULT_SIZE: u32 = 64;
    /// Largest window size accepted; larger requests are clamped.
    pub const MAX_SIZE: u32 = 65_536;

    /// A window remembering `size` counters, rounded up to a multiple of 64 in 64..=65 536.
    pub fn new(size: u32) -> Self {
        let words = size.clamp(64, Self::MAX_SIZE).div_ceil(64) as usize;
        Self {
            highest: None,
            bits: vec![0; words],
        }
    }

    /// How many counters the window spans.
    pub fn size(&self) -> u64 {
        self.bits.len() as u64 * 64
    }

    /// The highest counter accepted so far.
    pub fn highest(&self) -> Option<u64> {
        self.highest
    }

    fn slot(&self, counter: u64) -> (usize, u64) {
        let bit = counter % self.size();
        ((bit / 64) as usize, 1u64 << (bit % 64))
    }

    /// Whether `counter` would be accepted, without recording it.
    ///
    /// Receivers call this before the (costlier) authenticity check and [`Self::accept`] only
    /// after it passes, so forged messages cannot move the window.
    pub fn check(&self, counter: u64) -> Result<(), ReplayError> {
        let Some(highest) = self.highest else {
            return Ok(());
        };
        if counter > highest {
            return Ok(());
        }
        if highest - counter >= self.size() {
            return Err(ReplayError::TooOld {
                counter,
                highest,
                size: self.size(),
            });
        }
        let (word, mask) = self.slot(counter);
        if self.bits[word] & mask != 0 {
            Err(ReplayError::Duplicate(counter))
        } else {
            Ok(())
        }
    }

    /// Records `counter` if it is acceptable, moving the window when it is the new highest.
    pub fn accept(&mut self, counter: u64) -> Result<(), ReplayError> {
        self.check(counter)?;
        match self.highest {
            Some(highest) if counter <= highest => {}
            Some(highest) => {
                let advance = counter - highest;
                if advance >= self.size() {
                    self.bits.fill(0);
                } else {
                    // Forget the counters that slide out: their slots now stand for the new
                    // counters highest+1 ..= counter.
                    for c in highest + 1..=counter {
                        let (word, mask) = self.slot(c);
                        self.bits[word] &= !mask;
                    }
                }
                self.highest = Some(counter);
            }
            None => self.highest = Some(counter),
        }
        let (word, mask) = self.slot(counter);
        self.bits[word] |= mask;
        Ok(())
    }
}

impl Default for ReplayWindow {
    fn default() -> Self {
        Self::new(Self::DEFAULT_SIZE)
    }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeSet;

    use proptest::prelude::*;

    use super::*;

    #[test]
    fn duplicates_and_old_counters_are_refused() {
        let mut w = ReplayWindow::new(64);
        w.accept(10).unwrap();
        assert_eq!(w.accept(10), Err(ReplayError::Duplicate(10)));
        w.accept(5).unwrap();
        assert_eq!(w.accept(5), Err(ReplayError::Duplicate(5)));
        w.accept(100).unwrap();
        assert!(matches!(w.accept(36), Err(ReplayError::TooOld { .. })));
        w.accept(37).unwrap();
        assert_eq!(w.accept(37), Err(ReplayError::Duplicate(37)));
        // A big jump forgets everything below the new window.
        w.accept(1_000_000).unwrap();
        assert!(matches!(w.accept(100), Err(ReplayError::TooOld { .. })));
        w.accept(999_999).unwrap();
        assert_eq!(w.highest(), Some(1_000_000));
    }

    #[test]
    fn the_first_counter_may_be_anything_and_u64_max_works() {
        let mut w = ReplayWindow::new(64);
        w.accept(u64::MAX).unwrap();
        assert_eq!(w.accept(u64::MAX), Err(ReplayError::Duplicate(u64::MAX)));
        w.accept(u64::MAX - 63).unwrap();
        assert!(w.accept(u64::MAX - 64).is_err());
        let mut w = ReplayWindow::new(64);
        w.accept(0).unwrap();
        assert_eq!(w.accept(0), Err(ReplayError::Duplicate(0)));
    }

    #[test]
    fn sizes_round_up_to_whole_words() {
        assert_eq!(ReplayWindow::new(0).size(), 64);
        assert_eq!(ReplayWindow::new(65).size(), 128);
        assert_eq!(ReplayWindow::new(u32::MAX).size(), 65_536);
    }

    proptest! {
        /// The window agrees with a model that remembers every counter: accepted iff never
        /// seen and within `size` of the highest seen.
        #[test]
        fn matches_a_model_that_remembers_everything(
            size in prop_oneof![Just(64u32), Just(128u32)],
            counters in prop::collection::vec(0u64..400, 1..300),
        ) {
            let mut w = ReplayWindow::new(size);
            let mut seen = BTreeSet::new();
            let mut highest: Option<u64> = None;
            for c in counters {
                let fresh = !seen.contains(&c)
                    && highest.is_none_or(|h| c > h || h - c < u64::from(size));
                prop_assert_eq!(w.accept(c).is_ok(), fresh, "counter {}", c);
                if fresh {
                    seen.insert(c);
                    highest = Some(highest.map_or(c, |h| h.max(c)));
                }
            }
        }
    }
}
