//! A budget of log lines per second for messages a remote sender can cause at will (a
//! refused handshake per attempt, a rejected sample per datum of a flood): the log stays
//! readable and its disk bounded, the counters keep the whole story.

use std::time::{Duration, Instant};

/// At most `per_second` lines a second; the line written after a gap says how many were
/// left out.
#[derive(Debug)]
pub struct LogBudget {
    per_second: u32,
    window_start: Option<Instant>,
    used: u32,
    left_out: u64,
    left_out_total: u64,
}

impl LogBudget {
    /// A budget of `per_second` lines a second.
    pub const fn new(per_second: u32) -> Self {
        Self {
            per_second,
            window_start: None,
            used: 0,
            left_out: 0,
            left_out_total: 0,
        }
    }

    /// `Some(n)`: write this line, noting the `n` left out since the last one written;
    /// `None`: leave it out (counted).
    pub fn take(&mut self, now: Instant) -> Option<u64> {
        let fresh = self
            .window_start
            .is_none_or(|s| now.saturating_duration_since(s) >= Duration::from_secs(1));
        if fresh {
            self.window_start = Some(now);
            self.used = 0;
        }
        if self.used < self.per_second {
            self.used += 1;
            Some(std::mem::take(&mut self.left_out))
        } else {
            self.left_out += 1;
            self.left_out_total += 1;
            None
        }
    }

    /// Lines left out since the start.
    pub fn left_out_total(&self) -> u64 {
        self.left_out_total
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_flood_is_cut_to_the_budget_and_the_next_line_counts_what_was_left_out() {
        let mut b = LogBudget::new(3);
        let t0 = Instant::now();
        let written: Vec<_> = (0..10).map(|_| b.take(t0)).collect();
        assert_eq!(written.iter().filter(|w| w.is_some()).count(), 3);
        assert_eq!(b.left_out_total(), 7);
        // A second later the budget is back, and the first line says 7 were left out.
        assert_eq!(b.take(t0 + Duration::from_secs(1)), Some(7));
        assert_eq!(b.take(t0 + Duration::from_secs(1)), Some(0));
        assert_eq!(b.left_out_total(), 7);
    }
}
