//! Duplicate suppression for received PDUs.
//!
//! The modem may deliver a message twice: when a `FAILEDIM` means "no ack came back" the
//! message may still have arrived (docs/acoustic.md#at-interface), and the link layer
//! retransmits it. A PDU's encoding is canonical and every message that may legitimately
//! repeat carries a number or a time of day, so a byte-identical PDU from the same sender
//! within the window is a duplicate.

use std::collections::{HashMap, VecDeque};

use tokio::time::{Duration, Instant};

/// Remembers `(sender, PDU bytes)` for `window`, at most `capacity` entries.
#[derive(Debug)]
pub(crate) struct Dedup {
    window: Duration,
    capacity: usize,
    seen: HashMap<(u8, Vec<u8>), Instant>,
    order: VecDeque<((u8, Vec<u8>), Instant)>,
}

impl Dedup {
    pub(crate) fn new(window: Duration, capacity: usize) -> Self {
        Self {
            window,
            capacity: capacity.max(1),
            seen: HashMap::new(),
            order: VecDeque::new(),
        }
    }

    /// True the first time `(src, bytes)` is seen within the window.
    pub(crate) fn first(&mut self, src: u8, bytes: &[u8], now: Instant) -> bool {
        while let Some((key, t)) = self.order.front() {
            let old = now.saturating_duration_since(*t) > self.window;
            if !old && self.order.len() < self.capacity {
                break;
            }
            // Only forget the key if this queue entry is its latest sighting.
            if self.seen.get(key) == Some(t) {
                self.seen.remove(key);
            }
            self.order.pop_front();
        }
        let key = (src, bytes.to_vec());
        if self.seen.contains_key(&key) {
            return false;
        }
        self.seen.insert(key.clone(), now);
        self.order.push_back((key, now));
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_repeat_within_the_window_is_a_duplicate_and_after_it_is_not() {
        let t0 = Instant::now();
        let mut d = Dedup::new(Duration::from_secs(10), 100);
        assert!(d.first(2, &[1, 2, 3], t0));
        assert!(!d.first(2, &[1, 2, 3], t0 + Duration::from_secs(5)));
        assert!(d.first(3, &[1, 2, 3], t0 + Duration::from_secs(5)));
        assert!(d.first(2, &[1, 2, 3], t0 + Duration::from_secs(11)));
    }

    #[test]
    fn memory_is_bounded_by_capacity() {
        let t0 = Instant::now();
        let mut d = Dedup::new(Duration::from_secs(1000), 4);
        for i in 0..10u8 {
            assert!(d.first(1, &[i], t0));
        }
        assert!(d.seen.len() <= 4 && d.order.len() <= 4);
    }
}
