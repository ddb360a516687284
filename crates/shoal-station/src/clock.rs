//! The station's time: its system clock read once at start, then advanced by a monotonic
//! clock. Every timeout (contact, acknowledgement, expiry, rate limits) and every timestamp
//! the station writes comes from it, so a step of the system clock while the station runs
//! (NTP, a GPS time fix, an operator) neither marks the fleet lost nor expires tasks nor
//! makes good data look stale. The difference from the system clock is watched and
//! reported ([`Clock::skew_ms`]); a restart adopts the system clock again.

use std::sync::Arc;
use std::sync::atomic::{AtomicI64, Ordering};
use std::time::Instant;

/// Where the system (wall) time comes from: the real clock, or a test's.
type WallSource = Arc<dyn Fn() -> i64 + Send + Sync>;

/// The station's clock (cheap to clone; clones share their origin).
#[derive(Clone)]
pub struct Clock {
    origin_wall_ms: i64,
    elapsed: Elapsed,
    wall: WallSource,
}

#[derive(Clone)]
enum Elapsed {
    /// Real monotonic time since the origin.
    Real(Instant),
    /// A test's monotonic time, in ms since the origin.
    Manual(Arc<AtomicI64>),
    /// Simulated time run faster than real time (a scenario run).
    Warped(shoal_model::Warp),
}

impl std::fmt::Debug for Clock {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Clock")
            .field("origin_wall_ms", &self.origin_wall_ms)
            .field("now_ms", &self.now_ms())
            .finish_non_exhaustive()
    }
}

impl Default for Clock {
    fn default() -> Self {
        Self::system()
    }
}

impl Clock {
    /// The real clock, starting at the system time now.
    pub fn system() -> Self {
        Self {
            origin_wall_ms: shoal_model::now_ms(),
            elapsed: Elapsed::Real(Instant::now()),
            wall: Arc::new(shoal_model::now_ms),
        }
    }

    /// The real clock, with `offset` ms added to the system time it reads: a benchmark
    /// steps the system clock of a running process by changing the offset.
    pub fn system_offset(offset: Arc<AtomicI64>) -> Self {
        let wall = move || shoal_model::now_ms().saturating_add(offset.load(Ordering::SeqCst));
        Self {
            origin_wall_ms: wall(),
            elapsed: Elapsed::Real(Instant::now()),
            wall: Arc::new(wall),
        }
    }

    /// Simulated time shared with the simulated vehicles of a scenario run: the station's
    /// timeouts, rate limits and timestamps all run `warp.scale()` times as fast. Its
    /// "system clock" is the warp itself, so no skew is reported.
    pub fn warped(warp: shoal_model::Warp) -> Self {
        Self {
            origin_wall_ms: warp.origin_ms(),
            elapsed: Elapsed::Warped(warp),
            wall: Arc::new(move || warp.now_ms()),
        }
    }

    /// A clock for tests: starts at `start_ms`; [`ManualTime`] advances its monotonic
    /// time and steps its system time independently.
    pub fn manual(start_ms: i64) -> (Self, ManualTime) {
        let elapsed = Arc::new(AtomicI64::new(0));
        let wall = Arc::new(AtomicI64::new(start_ms));
        let wall_source = {
            let wall = Arc::clone(&wall);
            Arc::new(move || wall.load(Ordering::SeqCst))
        };
        (
            Self {
                origin_wall_ms: start_ms,
                elapsed: Elapsed::Manual(Arc::clone(&elapsed)),
                wall: wall_source,
            },
            ManualTime { elapsed, wall },
        )
    }

    /// Station time now, ms since the Unix epoch (never goes back).
    pub fn now_ms(&self) -> i64 {
        let elapsed = match &self.elapsed {
            Elapsed::Real(origin) => {
                i64::try_from(origin.elapsed().as_millis()).unwrap_or(i64::MAX)
            }
            Elapsed::Manual(ms) => ms.load(Ordering::SeqCst),
            Elapsed::Warped(warp) => return warp.now_ms(),
        };
        self.origin_wall_ms.saturating_add(elapsed)
    }

    /// Station seconds per real second: 1, or a scenario run's speed-up.
    pub fn rate(&self) -> f64 {
        match &self.elapsed {
            Elapsed::Warped(warp) => warp.scale(),
            Elapsed::Real(_) | Elapsed::Manual(_) => 1.0,
        }
    }

    /// How far the system clock is from station time now (positive: the system clock is
    /// ahead), e.g. after a step.
    pub fn skew_ms(&self) -> i64 {
        (self.wall)().saturating_sub(self.now_ms())
    }
}

/// A test's handle on a [`Clock::manual`] clock.
#[derive(Debug, Clone)]
pub struct ManualTime {
    elapsed: Arc<AtomicI64>,
    wall: Arc<AtomicI64>,
}

impl ManualTime {
    /// Time passes: monotonic and system time both advance by `ms`.
    pub fn advance(&self, ms: i64) {
        self.elapsed.fetch_add(ms, Ordering::SeqCst);
        self.wall.fetch_add(ms, Ordering::SeqCst);
    }

    /// The system clock alone jumps by `ms` (either way), as an NTP or GPS step does.
    pub fn step_system_clock(&self, ms: i64) {
        self.wall.fetch_add(ms, Ordering::SeqCst);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_warped_clock_is_the_warp_and_reports_no_skew() {
        let warp = shoal_model::Warp::start_at(2_000_000, 50.0).unwrap();
        let clock = Clock::warped(warp);
        std::thread::sleep(std::time::Duration::from_millis(10));
        let (c, w) = (clock.now_ms(), warp.now_ms());
        assert!(c >= 2_000_500, "{c}");
        assert!((w - c).abs() < 50, "{w} {c}");
        assert!(clock.skew_ms().abs() < 50);
    }

    #[test]
    fn station_time_follows_monotonic_time_not_system_clock_steps() {
        let (clock, time) = Clock::manual(1_000_000);
        time.advance(1_500);
        assert_eq!(clock.now_ms(), 1_001_500);
        time.step_system_clock(-3_600_000);
        assert_eq!(clock.now_ms(), 1_001_500);
        assert_eq!(clock.skew_ms(), -3_600_000);
        time.advance(10);
        assert_eq!(clock.now_ms(), 1_001_510);
    }

    #[test]
    fn the_system_clock_starts_at_the_system_time_and_never_goes_back() {
        let clock = Clock::system();
        let a = clock.now_ms();
        assert!((a - shoal_model::now_ms()).abs() < 1_000);
        assert!(clock.now_ms() >= a);
        assert!(clock.skew_ms().abs() < 1_000);
    }
}
