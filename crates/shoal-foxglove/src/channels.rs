//! What the bridge advertises: one channel per Shoal topic (OMG IDL schema, CDR
//! messages) and `shoal/location_fix` (Foxglove's `foxglove.LocationFix`, protobuf).

use std::collections::HashMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

use foxglove::schemas::location_fix::PositionCovarianceType;
use foxglove::schemas::{Color, LocationFix, Timestamp};
use foxglove::{Channel, Context, RawChannel, Schema};
use shoal_dds::TopicType;
use shoal_model::StateVector;

use crate::BridgeError;
use crate::config::RateLimit;

/// The text of `idl/shoal.idl`: every Shoal channel's schema is this whole file, with the
/// channel's type named as the schema's root (`shoal::StateVector`).
pub const SHOAL_IDL: &str = include_str!("../../../idl/shoal.idl");

/// The Foxglove schema encoding of the Shoal channels.
pub const SCHEMA_ENCODING: &str = "omgidl";

/// The Foxglove message encoding of the Shoal channels: XCDR1 with its 4-byte
/// encapsulation header, the bytes DDS carries.
pub const MESSAGE_ENCODING: &str = "cdr";

/// The channel of the fleet's positions as `foxglove.LocationFix`, `frame_id` = vehicle.
pub const LOCATION_FIX_TOPIC: &str = "shoal/location_fix";

/// The schema of `T`'s channel: the IDL file with `T`'s type as its root.
pub fn schema_of<T: TopicType>() -> Schema {
    Schema::new(T::TYPE_NAME, SCHEMA_ENCODING, SHOAL_IDL.as_bytes())
}

/// The message bytes of a sample on its channel.
pub fn encode<T: TopicType>(sample: &T) -> Result<Vec<u8>, BridgeError> {
    shoal_dds::to_cdr_le(sample).map_err(|source| BridgeError::Encode {
        topic: T::TOPIC,
        source,
    })
}

/// Creates `T`'s channel (named as its DDS topic) in `ctx`.
pub(crate) fn topic_channel<T: TopicType>(
    ctx: &Arc<Context>,
) -> Result<Arc<RawChannel>, BridgeError> {
    ctx.channel_builder(T::TOPIC)
        .schema(schema_of::<T>())
        .message_encoding(MESSAGE_ENCODING)
        .add_metadata("dds_type", T::TYPE_NAME)
        .build_raw()
        .map_err(|e| BridgeError::Sdk(format!("channel {}: {e}", T::TOPIC)))
}

/// Creates the `foxglove.LocationFix` channel in `ctx`.
pub(crate) fn location_channel(ctx: &Arc<Context>) -> Channel<LocationFix> {
    ctx.channel_builder(LOCATION_FIX_TOPIC).build()
}

/// A state vector as Foxglove's `LocationFix`: WGS84 position, altitude = -depth (a
/// vehicle 10 m down is at -10 m), heading in radians, no covariance (Shoal reports
/// none), `frame_id` the vehicle, and a colour of its own so a Map panel tells the
/// vehicles apart on one channel.
pub fn location_fix(state: &StateVector) -> LocationFix {
    LocationFix {
        timestamp: Some(timestamp(state.timestamp_ms)),
        frame_id: state.vehicle_id.clone(),
        latitude: state.latitude_deg,
        longitude: state.longitude_deg,
        altitude: -state.depth_m,
        position_covariance: vec![0.0; 9],
        position_covariance_type: PositionCovarianceType::Unknown as i32,
        heading: Some(state.yaw_deg.to_radians()),
        velocity: None,
        color: Some(vehicle_color(&state.vehicle_id)),
        metadata: Vec::new(),
    }
}

/// A Foxglove timestamp of ms since the Unix epoch (clamped to what it can hold).
pub fn timestamp(ms: i64) -> Timestamp {
    let ms = ms.max(0);
    let sec = u32::try_from(ms / 1000).unwrap_or(u32::MAX);
    let nsec = u32::try_from((ms % 1000) * 1_000_000).unwrap_or(0);
    Timestamp::new_checked(sec, nsec).unwrap_or(Timestamp::MAX)
}

/// Nanoseconds since the epoch of ms since the epoch, for the messages' log time.
pub(crate) fn nanos(ms: i64) -> u64 {
    u64::try_from(ms.max(0))
        .unwrap_or(0)
        .saturating_mul(1_000_000)
}

/// A stable, saturated colour per vehicle id (FNV-1a of the id picks the hue).
pub fn vehicle_color(vehicle_id: &str) -> Color {
    let hash = vehicle_id.bytes().fold(0xcbf2_9ce4_8422_2325_u64, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    });
    let hue = (hash % 360) as f64;
    let (r, g, b) = hsv(hue, 0.8, 0.95);
    Color { r, g, b, a: 1.0 }
}

fn hsv(h: f64, s: f64, v: f64) -> (f64, f64, f64) {
    let c = v * s;
    let x = c * (1.0 - ((h / 60.0) % 2.0 - 1.0).abs());
    let m = v - c;
    let (r, g, b) = match h {
        h if h < 60.0 => (c, x, 0.0),
        h if h < 120.0 => (x, c, 0.0),
        h if h < 180.0 => (0.0, c, x),
        h if h < 240.0 => (0.0, x, c),
        h if h < 300.0 => (x, 0.0, c),
        _ => (c, 0.0, x),
    };
    (r + m, g + m, b + m)
}

/// Most instances a limiter remembers; past this it forgets them all (a flood of
/// distinct keys cannot grow it without bound).
const MAX_REMEMBERED: usize = 100_000;

/// Decides which samples of one channel go out under its [`RateLimit`].
#[derive(Debug)]
pub struct Limiter {
    min_gap: Option<Duration>,
    per_s: u32,
    last: HashMap<String, Instant>,
    window: Instant,
    in_window: u32,
    /// Samples skipped so far.
    pub skipped: u64,
}

impl Limiter {
    /// A limiter for `limit`, starting at `now`.
    pub fn new(limit: RateLimit, now: Instant) -> Self {
        let min_gap = (limit.per_instance_hz > 0.0)
            .then(|| Duration::from_secs_f64(1.0 / limit.per_instance_hz));
        Self {
            min_gap,
            per_s: limit.per_channel_per_s,
            last: HashMap::new(),
            window: now,
            in_window: 0,
            skipped: 0,
        }
    }

    /// Whether a sample of instance `key` at `now` may go out (and counts it if so).
    pub fn allow(&mut self, key: &str, now: Instant) -> bool {
        if self.per_s > 0 {
            if now.duration_since(self.window) >= Duration::from_secs(1) {
                self.window = now;
                self.in_window = 0;
            }
            if self.in_window >= self.per_s {
                self.skipped += 1;
                return false;
            }
        }
        if let Some(gap) = self.min_gap {
            if let Some(last) = self.last.get(key)
                && now.duration_since(*last) < gap
            {
                self.skipped += 1;
                return false;
            }
            if self.last.len() >= MAX_REMEMBERED && !self.last.contains_key(key) {
                self.last.clear();
            }
            self.last.insert(key.to_owned(), now);
        }
        self.in_window += 1;
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shoal_model::{
        EnvironmentObservation, Event, TaskAssignment, TaskStatus, VehicleAnnouncement,
    };

    fn state() -> StateVector {
        StateVector {
            vehicle_id: "auv-7".into(),
            timestamp_ms: 1_767_225_600_250,
            latitude_deg: 43.1,
            longitude_deg: 5.9,
            depth_m: 12.5,
            altitude_m: -1.0,
            speed_mps: 1.5,
            yaw_deg: 90.0,
            pitch_deg: 0.0,
            roll_deg: 0.0,
            battery_pct: 80.0,
        }
    }

    #[test]
    fn every_schema_is_the_idl_rooted_at_the_topics_type() {
        fn check<T: TopicType>() {
            let s = schema_of::<T>();
            assert_eq!(s.name, T::TYPE_NAME);
            assert_eq!(s.encoding, "omgidl");
            assert_eq!(&*s.data, SHOAL_IDL.as_bytes());
            // The root type is declared in the text under its unqualified name.
            let short = T::TYPE_NAME.trim_start_matches("shoal::");
            assert!(SHOAL_IDL.contains(&format!("struct {short} {{")), "{short}");
        }
        check::<StateVector>();
        check::<VehicleAnnouncement>();
        check::<TaskAssignment>();
        check::<TaskStatus>();
        check::<Event>();
        check::<EnvironmentObservation>();
        assert!(SHOAL_IDL.contains("module shoal {"));
    }

    #[test]
    fn messages_are_cdr_le_with_the_encapsulation_header_and_decode_back() {
        let s = state();
        let bytes = encode(&s).unwrap_or_else(|e| unreachable!("{e}"));
        assert_eq!(bytes[..4], [0x00, 0x01, 0x00, 0x00]);
        // string length (incl. NUL) then the text, little endian.
        assert_eq!(bytes[4..8], 6u32.to_le_bytes());
        assert_eq!(&bytes[8..13], b"auv-7");
        // int64 timestamp aligned to 8 within the body (body offset 16 = byte 20).
        assert_eq!(bytes[20..28], 1_767_225_600_250_i64.to_le_bytes());
        let back: StateVector = shoal_dds::from_cdr(&bytes).unwrap_or_else(|e| unreachable!("{e}"));
        assert_eq!(back, s);
    }

    #[test]
    fn a_state_vector_maps_to_a_location_fix() {
        let fix = location_fix(&state());
        assert_eq!(fix.frame_id, "auv-7");
        assert_eq!(fix.latitude, 43.1);
        assert_eq!(fix.longitude, 5.9);
        assert_eq!(fix.altitude, -12.5);
        assert_eq!(
            fix.position_covariance_type,
            PositionCovarianceType::Unknown as i32
        );
        assert_eq!(fix.position_covariance.len(), 9);
        assert!((fix.heading.unwrap_or_default() - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        let ts = fix.timestamp.unwrap_or(Timestamp::MIN);
        assert_eq!((ts.sec(), ts.nsec()), (1_767_225_600, 250_000_000));
        // The same vehicle always gets the same colour, another one (almost always) not.
        assert_eq!(fix.color, Some(vehicle_color("auv-7")));
        assert_ne!(vehicle_color("auv-7"), vehicle_color("auv-8"));
    }

    #[test]
    fn a_vehicle_at_the_surface_is_at_altitude_zero() {
        let mut s = state();
        s.depth_m = 0.0;
        assert_eq!(location_fix(&s).altitude, 0.0);
    }

    #[test]
    fn the_limiter_keeps_each_instance_to_its_rate_and_the_channel_to_its_total() {
        let t0 = Instant::now();
        let mut l = Limiter::new(RateLimit::new(2.0, 3), t0);
        assert!(l.allow("a", t0));
        assert!(!l.allow("a", t0 + Duration::from_millis(100)));
        assert!(l.allow("b", t0 + Duration::from_millis(100)));
        assert!(l.allow("a", t0 + Duration::from_millis(600)));
        // Three went out in this second: the fourth instance waits for the next one.
        assert!(!l.allow("c", t0 + Duration::from_millis(700)));
        assert!(l.allow("c", t0 + Duration::from_millis(1001)));
        assert_eq!(l.skipped, 2);
        let mut open = Limiter::new(RateLimit::UNLIMITED, t0);
        assert!((0..10_000).all(|_| open.allow("a", t0)));
        assert!(open.last.is_empty());
    }
}
