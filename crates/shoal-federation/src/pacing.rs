//! Pacing of bulk answers on a slow link, with no network: a token bucket.
//!
//! A site answering catch-up and lease queries sends a burst: a part of 100 frames is
//! about 10 kB, more than a second of a 64 kbit/s satellite link. Sent at once, a burst
//! fills the link and the modem's buffer ahead of it (TCP grows its window until that
//! buffer overflows), and live alarms, transitions and positions then wait seconds behind
//! it whatever their priority: Zenoh's priorities order only what has not left yet. Worse,
//! an answer that takes longer than the asker's timeout is thrown away on arrival and
//! asked for again, so a busy link spends itself on answers nobody reads. With
//! `link_rate_kbps` set, the answers leave at most at [`crate::config::LinkShaping`]'s
//! bulk rate, a quarter of the link, and the askers ask for parts that cross within a
//! quarter of their timeout at that rate.

use std::collections::HashMap;
use std::time::Duration;

use tokio::time::Instant;

/// A token bucket of bytes: `rate` per second, at most `burst` saved up.
#[derive(Debug, Clone)]
pub(crate) struct Pacer {
    bytes_per_s: f64,
    burst: f64,
    tokens: f64,
    last: Instant,
}

impl Pacer {
    /// A bucket for `bytes_per_s`, holding a quarter of a second's worth; full at `now`.
    pub(crate) fn new(bytes_per_s: u32, now: Instant) -> Self {
        let rate = f64::from(bytes_per_s.max(1));
        let burst = (rate / 4.0).max(256.0);
        Self {
            bytes_per_s: rate,
            burst,
            tokens: burst,
            last: now,
        }
    }

    /// Takes `bytes` at `now`; how long to wait before sending them (zero when the bucket
    /// held enough). The bytes are counted at once, so whoever asks next waits for them
    /// too: the bucket is shared by every answering task of the site.
    pub(crate) fn reserve(&mut self, bytes: usize, now: Instant) -> Duration {
        self.refill(now);
        #[allow(clippy::cast_precision_loss)]
        let need = bytes as f64;
        self.tokens -= need;
        self.wait()
    }

    /// Takes `bytes` at `now` only if they may leave by `deadline`; how long to wait, or
    /// `None` (and nothing taken) when they would leave too late. An answer is cut there
    /// rather than sent to an asker who will have stopped listening.
    pub(crate) fn reserve_by(
        &mut self,
        bytes: usize,
        now: Instant,
        deadline: Instant,
    ) -> Option<Duration> {
        self.refill(now);
        #[allow(clippy::cast_precision_loss)]
        let after = self.tokens - bytes as f64;
        let wait = self.wait_for(after);
        if now + wait > deadline {
            return None;
        }
        self.tokens = after;
        Some(wait)
    }

    fn refill(&mut self, now: Instant) {
        let elapsed = now.saturating_duration_since(self.last).as_secs_f64();
        self.last = self.last.max(now);
        self.tokens = (self.tokens + elapsed * self.bytes_per_s).min(self.burst);
    }

    fn wait(&self) -> Duration {
        self.wait_for(self.tokens)
    }

    /// How long until a bucket holding `tokens` is back at zero.
    fn wait_for(&self, tokens: f64) -> Duration {
        if tokens >= 0.0 {
            Duration::ZERO
        } else {
            Duration::from_secs_f64(-tokens / self.bytes_per_s)
        }
    }
}

/// How long this site waits for each remote site's answers: the configured wait at first;
/// doubled (up to `max`) each time an answer came incomplete; twice what the last whole
/// answer took (within the configured wait and `max`) once one came whole. A site two
/// slow hops away (ship to ship through the shore), or behind a busy link, needs longer
/// than one next door, and an answer thrown away for arriving late costs the link as
/// much as one that is read. Going back to the configured wait at once after a whole
/// answer would have the next one run out of time again.
#[derive(Debug, Clone)]
pub(crate) struct Waits {
    base: Duration,
    max: Duration,
    /// Only sites waited for longer than `base`; at most the configured remote sites.
    longer: HashMap<String, Duration>,
}

impl Waits {
    /// Waits of `base`, growing to `max` at most.
    pub(crate) fn new(base: Duration, max: Duration) -> Self {
        Self {
            base,
            max: max.max(base),
            longer: HashMap::new(),
        }
    }

    /// How long to wait for `site`'s next answer.
    pub(crate) fn of(&self, site: &str) -> Duration {
        self.longer.get(site).copied().unwrap_or(self.base)
    }

    /// Notes how `site`'s last answer came: `whole` (after `took`), or incomplete.
    pub(crate) fn answered(&mut self, site: &str, whole: bool, took: Duration) {
        let next = if whole {
            (took * 2).clamp(self.base, self.max)
        } else {
            (self.of(site) * 2).min(self.max)
        };
        if next > self.base {
            self.longer.insert(site.to_string(), next);
        } else {
            self.longer.remove(site);
        }
    }
}

/// Bytes a reply costs on the link beyond its payload and key: Zenoh's reply header and
/// framing, and a share of TCP/IP's (measured sizes are in docs/federation.md).
pub(crate) const REPLY_OVERHEAD: usize = 24;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_burst_goes_at_once_and_the_rest_at_the_rate() {
        let t0 = Instant::now();
        let mut p = Pacer::new(2000, t0);
        // A quarter of a second's worth (500 B) is saved up.
        assert_eq!(p.reserve(500, t0), Duration::ZERO);
        // The next 1000 B wait half a second, and the 1000 after them a second.
        assert_eq!(p.reserve(1000, t0), Duration::from_millis(500));
        assert_eq!(p.reserve(1000, t0), Duration::from_millis(1000));
        // Two seconds later the debt is paid and the bucket refilled to its burst only.
        let later = t0 + Duration::from_secs(3);
        assert_eq!(p.reserve(500, later), Duration::ZERO);
        assert!(p.reserve(1, later) > Duration::ZERO);
    }

    #[test]
    fn an_answer_is_cut_where_it_would_leave_after_its_deadline() {
        let t0 = Instant::now();
        let mut p = Pacer::new(2000, t0);
        let deadline = t0 + Duration::from_secs(1);
        // 500 B of burst, then 2,000 B/s: 2,500 B may leave within the second.
        let mut sent = 0;
        while let Some(wait) = p.reserve_by(100, t0, deadline) {
            assert!(wait <= Duration::from_secs(1));
            sent += 100;
        }
        assert_eq!(sent, 2500);
        // What was refused was not taken: a second later the debt is paid and the burst
        // saved up again.
        let later = t0 + Duration::from_secs(2);
        assert_eq!(p.reserve_by(500, later, later), Some(Duration::ZERO));
        // Another answering task sharing the bucket waits behind what was taken.
        assert_eq!(p.reserve(1000, later), Duration::from_millis(500));
        assert_eq!(
            p.reserve_by(1, later, later + Duration::from_millis(400)),
            None
        );
    }

    #[test]
    fn a_site_whose_answers_come_incomplete_is_given_longer_up_to_a_bound() {
        let s = Duration::from_secs;
        let mut w = Waits::new(s(10), s(40));
        assert_eq!(w.of("ship-1"), s(10));
        w.answered("ship-1", false, s(10));
        assert_eq!((w.of("ship-1"), w.of("shore")), (s(20), s(10)));
        for _ in 0..5 {
            w.answered("ship-1", false, s(40));
        }
        assert_eq!(w.of("ship-1"), s(40));
        // A whole answer that took 12 s: the next is waited for twice that.
        w.answered("ship-1", true, s(12));
        assert_eq!(w.of("ship-1"), s(24));
        // A quick one: the configured wait again, and nothing kept.
        w.answered("ship-1", true, s(1));
        assert_eq!(w.of("ship-1"), s(10));
        assert!(w.longer.is_empty());
    }

    #[test]
    fn a_part_of_answers_leaves_at_the_rate_on_average() {
        let t0 = Instant::now();
        let mut p = Pacer::new(2000, t0);
        let mut now = t0;
        for _ in 0..100 {
            now += p.reserve(100, now);
        }
        // 10,000 B at 2,000 B/s, less the 500 B burst.
        let took = now - t0;
        assert!(
            took >= Duration::from_millis(4700) && took <= Duration::from_millis(4800),
            "{took:?}"
        );
    }
}
