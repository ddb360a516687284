//! Simulated time run faster than real time, shared by a station and its simulated
//! vehicles in one process (`shoal scenario run --speed N`).

use std::time::{Duration, Instant};

/// Largest speed-up: beyond it a 100 ms scheduler tick is minutes of simulated time.
pub const MAX_WARP: f64 = 1000.0;

/// A clock that runs `scale` times as fast as the monotonic clock from a common origin.
///
/// Copies share the origin, so every party holding one agrees on the time to the
/// millisecond: a station stamping a task and a vehicle stamping its state read the same
/// simulated clock, and no plausibility check sees the other's timestamps as skewed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Warp {
    origin_ms: i64,
    origin: Instant,
    scale: f64,
}

/// Why a speed-up was refused.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
#[error("time scale must be in (0, {MAX_WARP}], not {0}")]
pub struct WarpError(pub f64);

impl Warp {
    /// Starts simulated time at the system time now, running `scale` times as fast.
    pub fn start(scale: f64) -> Result<Self, WarpError> {
        Self::start_at(crate::now_ms(), scale)
    }

    /// Starts simulated time at `origin_ms` (ms since the Unix epoch).
    pub fn start_at(origin_ms: i64, scale: f64) -> Result<Self, WarpError> {
        if !(scale.is_finite() && scale > 0.0 && scale <= MAX_WARP) {
            return Err(WarpError(scale));
        }
        Ok(Self {
            origin_ms,
            origin: Instant::now(),
            scale,
        })
    }

    /// Simulated time now, ms since the Unix epoch (never goes back).
    pub fn now_ms(&self) -> i64 {
        #[allow(clippy::cast_possible_truncation)]
        let elapsed = (self.origin.elapsed().as_secs_f64() * 1000.0 * self.scale) as i64;
        self.origin_ms.saturating_add(elapsed)
    }

    /// Simulated seconds per real second.
    pub fn scale(&self) -> f64 {
        self.scale
    }

    /// Simulated time at the start, ms since the Unix epoch.
    pub fn origin_ms(&self) -> i64 {
        self.origin_ms
    }

    /// The real time a span of simulated time takes.
    pub fn real(&self, simulated: Duration) -> Duration {
        simulated.div_f64(self.scale)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn simulated_time_runs_scale_times_as_fast_from_the_origin() {
        let w = Warp::start_at(1_000_000, 100.0).unwrap();
        std::thread::sleep(Duration::from_millis(20));
        let t = w.now_ms() - 1_000_000;
        // 20 ms real is 2 s simulated, and sleeping never returns early.
        assert!(t >= 2_000, "{t}");
        assert_eq!(w.real(Duration::from_secs(60)), Duration::from_millis(600));
        let copy = w;
        assert!(copy.now_ms() >= w.now_ms() - 1);
    }

    #[test]
    fn a_scale_out_of_range_is_refused() {
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY, MAX_WARP * 2.0] {
            assert!(Warp::start(bad).is_err(), "{bad}");
        }
        assert!(Warp::start(MAX_WARP).is_ok());
    }
}
