//! Many lightweight simulated vehicles on one DDS participant, for scale tests
//! (`shoal swarm`, `shoal up --sim-vehicles N`, `shoal bench scale`).
//!
//! Each vehicle announces itself and reports its state at the given rate while it circles
//! its start point (radius 100–300 m, 1–2 m/s, 5–50 m deep, a battery draining about 5 %
//! an hour). Reports are spread evenly over each period so the station sees a steady
//! stream, not a burst per second. They take no tasks: a task sent to one expires at the
//! station (use `shoal vehicle --sim` for vehicles that do).

use std::f64::consts::TAU;
use std::sync::Arc;
use std::time::Duration;

use shoal_dds::{CreateError, Priority, PubSub, WriterOptions};
use shoal_model::geo::LocalFrame;
use shoal_model::{GeoPoint, LinkKind, StateVector, VehicleAnnouncement, VehicleKind, now_ms};
use tokio_util::sync::CancellationToken;
use tracing::{info, warn};

/// Slices each reporting period is cut into; vehicle `i` reports in slice `i % SLICES`.
const SLICES: usize = 20;
/// Announcements are repeated this often (the station may have restarted).
const ANNOUNCE_EVERY: Duration = Duration::from_secs(60);

/// What to simulate.
#[derive(Debug, Clone, PartialEq)]
pub struct SwarmSpec {
    /// Number of vehicles.
    pub count: usize,
    /// Vehicle ids are `<prefix>-<n>`, n from 1.
    pub prefix: String,
    /// Centre of the swarm's grid, degrees.
    pub latitude_deg: f64,
    /// Centre of the swarm's grid, degrees.
    pub longitude_deg: f64,
    /// Distance between neighbouring vehicles' circles, metres.
    pub spacing_m: f64,
    /// State vectors per second per vehicle.
    pub rate_hz: f64,
}

impl Default for SwarmSpec {
    fn default() -> Self {
        Self {
            count: 100,
            prefix: "sw".into(),
            latitude_deg: 63.44,
            longitude_deg: 10.30,
            spacing_m: 700.0,
            rate_hz: 1.0,
        }
    }
}

impl SwarmSpec {
    /// Checks the values; the error names the flag.
    pub fn check(&self) -> Result<(), SwarmError> {
        if !(1..=100_000).contains(&self.count) {
            return Err(SwarmError::Spec(format!(
                "--count {} is outside 1..=100000",
                self.count
            )));
        }
        if !(self.rate_hz > 0.0 && self.rate_hz <= 10.0) {
            return Err(SwarmError::Spec(format!(
                "--rate {} is outside (0, 10] state vectors per second",
                self.rate_hz
            )));
        }
        if !(self.latitude_deg.abs() <= 85.0 && self.longitude_deg.abs() <= 180.0) {
            return Err(SwarmError::Spec(format!(
                "--lat {} --lon {}: the swarm's centre must be within ±85° latitude, ±180° longitude",
                self.latitude_deg, self.longitude_deg
            )));
        }
        if !shoal_model::is_identifier(&format!("{}-{}", self.prefix, self.count), 32) {
            return Err(SwarmError::Spec(format!(
                "--prefix {:?} does not make valid vehicle ids (letters, digits, '_', '-', '.'; at most 32 with the number)",
                self.prefix
            )));
        }
        Ok(())
    }
}

/// One lightweight vehicle: a point on a circle.
#[derive(Debug, Clone)]
struct Lite {
    id: String,
    /// East/north metres around the centre of its circle.
    centre: LocalFrame,
    radius_m: f64,
    speed_mps: f64,
    depth_m: f64,
    phase: f64,
    battery_pct: f64,
}

/// A deterministic value in [0, 1) per vehicle and purpose (no RNG state to keep).
fn unit(i: usize, salt: u64) -> f64 {
    let mut x = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ salt;
    x ^= x >> 33;
    x = x.wrapping_mul(0xff51_afd7_ed55_8ccd);
    x ^= x >> 33;
    #[allow(clippy::cast_precision_loss)]
    let v = (x >> 11) as f64 / (1u64 << 53) as f64;
    v
}

impl Lite {
    fn new(spec: &SwarmSpec, i: usize) -> Self {
        #[allow(
            clippy::cast_possible_truncation,
            clippy::cast_sign_loss,
            clippy::cast_precision_loss
        )]
        let side = (spec.count as f64).sqrt().ceil().max(1.0) as usize;
        #[allow(clippy::cast_precision_loss)]
        let (row, col) = ((i / side) as f64, (i % side) as f64);
        #[allow(clippy::cast_precision_loss)]
        let half = (side as f64 - 1.0) / 2.0;
        let north = (row - half) * spec.spacing_m;
        let east = (col - half) * spec.spacing_m;
        let swarm = LocalFrame::new(GeoPoint {
            latitude_deg: spec.latitude_deg,
            longitude_deg: spec.longitude_deg,
        });
        Self {
            id: format!("{}-{}", spec.prefix, i + 1),
            centre: LocalFrame::new(swarm.to_geo(east, north)),
            radius_m: 100.0 + 200.0 * unit(i, 1),
            speed_mps: 1.0 + unit(i, 2),
            depth_m: 5.0 + 45.0 * unit(i, 3),
            phase: TAU * unit(i, 4),
            battery_pct: 60.0 + 40.0 * unit(i, 5),
        }
    }

    fn announcement(&self) -> VehicleAnnouncement {
        VehicleAnnouncement {
            vehicle_id: self.id.clone(),
            name: format!("swarm vehicle {}", self.id),
            kind: VehicleKind::Auv,
            vendor: "shoal swarm".into(),
            capabilities: vec![],
            sensors: vec![],
            links: vec![LinkKind::Ip],
            max_speed_mps: 2.5,
            timestamp_ms: now_ms(),
        }
    }

    /// Moves `dt` seconds along the circle and returns the state at `t_ms`.
    fn step(&mut self, dt: f64, t_ms: i64) -> StateVector {
        self.phase = (self.phase + self.speed_mps * dt / self.radius_m) % TAU;
        self.battery_pct = (self.battery_pct - dt * 5.0 / 3600.0).max(0.0);
        let north = self.radius_m * self.phase.cos();
        let east = self.radius_m * self.phase.sin();
        let GeoPoint {
            latitude_deg: lat,
            longitude_deg: lon,
        } = self.centre.to_geo(east, north);
        // Counter-clockwise seen from above: the heading is the tangent.
        let yaw = (self.phase.to_degrees() + 90.0).rem_euclid(360.0);
        StateVector {
            vehicle_id: self.id.clone(),
            timestamp_ms: t_ms,
            latitude_deg: lat,
            longitude_deg: lon,
            depth_m: self.depth_m,
            altitude_m: -1.0,
            speed_mps: self.speed_mps,
            yaw_deg: yaw,
            pitch_deg: 0.0,
            roll_deg: 0.0,
            battery_pct: self.battery_pct,
        }
    }
}

/// Why a swarm cannot run.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SwarmError {
    /// The spec is out of range.
    #[error("{0}")]
    Spec(String),
    /// A DDS endpoint could not be created.
    #[error(transparent)]
    Dds(#[from] CreateError),
}

/// Runs the swarm until `shutdown` is cancelled.
pub async fn run_swarm(
    spec: SwarmSpec,
    dds: Arc<PubSub>,
    shutdown: CancellationToken,
) -> Result<(), SwarmError> {
    spec.check()?;
    let announce = dds.writer::<VehicleAnnouncement>(WriterOptions::new(Priority::Control))?;
    let states = dds.writer::<StateVector>(WriterOptions::new(Priority::Telemetry))?;
    let mut vehicles: Vec<Lite> = (0..spec.count).map(|i| Lite::new(&spec, i)).collect();
    let period = Duration::from_secs_f64(1.0 / spec.rate_hz);
    #[allow(clippy::cast_possible_truncation)]
    let mut ticker = tokio::time::interval(period / SLICES as u32);
    // Catch up after a slow slice, so the offered rate holds on average.
    ticker.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Burst);
    // States from a vehicle the station has not heard announced are refused: once a
    // reader matched both writers (or after 30 s), announce everyone, give the station a
    // second to take the announcements (another reader), then report.
    let waiting = tokio::time::Instant::now();
    while (announce.matched_readers() == 0 || states.matched_readers() == 0)
        && waiting.elapsed() < Duration::from_secs(30)
    {
        tokio::select! {
            () = shutdown.cancelled() => return Ok(()),
            () = tokio::time::sleep(Duration::from_millis(100)) => {}
        }
    }
    for v in &vehicles {
        if let Err(e) = announce.write(v.announcement()).await {
            warn!(vehicle = %v.id, error = %e, "announcement not sent");
        }
    }
    tokio::time::sleep(Duration::from_secs(1)).await;
    let mut last_announce = Some(tokio::time::Instant::now());
    info!(
        vehicles = spec.count,
        rate_hz = spec.rate_hz,
        "swarm started"
    );
    let mut slice = 0usize;
    let (mut sent, mut failed) = (0u64, 0u64);
    loop {
        tokio::select! {
            () = shutdown.cancelled() => break,
            _ = ticker.tick() => {}
        }
        if last_announce.is_none_or(|t| t.elapsed() >= ANNOUNCE_EVERY) {
            for v in &vehicles {
                if let Err(e) = announce.write(v.announcement()).await {
                    warn!(vehicle = %v.id, error = %e, "announcement not sent");
                }
            }
            last_announce = Some(tokio::time::Instant::now());
        }
        for v in vehicles.iter_mut().skip(slice).step_by(SLICES) {
            // Stamped as it is written, as a vehicle stamps its own sample: a stamp shared
            // by the slice would count the slice's earlier writes as transport latency.
            match states.write(v.step(period.as_secs_f64(), now_ms())).await {
                Ok(()) => sent += 1,
                Err(_) => failed += 1,
            }
        }
        slice = (slice + 1) % SLICES;
    }
    info!(sent, failed, "swarm stopped");
    Ok(())
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use shoal_model::Validate;

    #[test]
    fn swarm_vehicles_report_valid_states_on_their_circles() {
        let spec = SwarmSpec {
            count: 10_000,
            ..SwarmSpec::default()
        };
        let mut ids = std::collections::HashSet::new();
        for i in [0, 1, 99, 5_000, 9_999] {
            let mut v = Lite::new(&spec, i);
            v.announcement().validate().unwrap();
            assert!(ids.insert(v.id.clone()));
            let a = v.step(1.0, 1_780_000_000_000);
            a.validate().unwrap();
            let b = v.step(1.0, 1_780_000_001_000);
            // Moving at its speed along the circle (chord ≈ arc for 1 s).
            let d = shoal_model::geo::distance_m(
                a.latitude_deg,
                a.longitude_deg,
                b.latitude_deg,
                b.longitude_deg,
            );
            assert!((d - v.speed_mps).abs() < 0.05, "{d} vs {}", v.speed_mps);
            assert!(b.battery_pct < a.battery_pct);
        }
        assert_eq!(Lite::new(&spec, 9_999).id, "sw-10000");
    }

    #[test]
    fn a_bad_swarm_spec_names_the_flag() {
        let bad = |f: fn(&mut SwarmSpec)| {
            let mut s = SwarmSpec::default();
            f(&mut s);
            s.check().unwrap_err().to_string()
        };
        assert!(bad(|s| s.count = 0).starts_with("--count 0"));
        assert!(bad(|s| s.rate_hz = f64::NAN).starts_with("--rate NaN"));
        assert!(bad(|s| s.latitude_deg = 91.0).starts_with("--lat 91"));
        assert!(bad(|s| s.prefix = "a b".into()).starts_with("--prefix"));
        assert!(bad(|s| s.prefix = "x".repeat(40)).starts_with("--prefix"));
        SwarmSpec::default().check().unwrap();
    }
}
