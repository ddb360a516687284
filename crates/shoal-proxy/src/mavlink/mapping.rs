//! MAVLink's units into Shoal's and back: 1e-7 degrees, millimetres of altitude relative
//! to the surface (negative below it), radians, centidegrees, percent; ArduSub's modes and
//! STATUSTEXT severities.

use mavlink::dialects::ardupilotmega::{MavSeverity, MavType};
use shoal_model::{EventKind, Severity, VehicleKind};

/// ArduSub flight modes (`custom_mode` of HEARTBEAT and DO_SET_MODE), as in `SubMode`.
pub mod sub_mode {
    /// Manual attitude stabilisation.
    pub const STABILIZE: u32 = 0;
    /// Rate control.
    pub const ACRO: u32 = 1;
    /// Depth hold.
    pub const ALT_HOLD: u32 = 2;
    /// Runs the uploaded mission.
    pub const AUTO: u32 = 3;
    /// Goes to position targets from the GCS.
    pub const GUIDED: u32 = 4;
    /// Circles a point.
    pub const CIRCLE: u32 = 7;
    /// Ascends to the surface.
    pub const SURFACE: u32 = 9;
    /// Holds position and depth.
    pub const POSHOLD: u32 = 16;
    /// Pilot in full control.
    pub const MANUAL: u32 = 19;
    /// Motor direction detection.
    pub const MOTOR_DETECT: u32 = 20;
    /// Holds altitude above the seabed.
    pub const SURFTRAK: u32 = 21;
}

/// The name of an ArduSub mode, for messages and events.
pub fn mode_name(mode: u32) -> String {
    match mode {
        sub_mode::STABILIZE => "STABILIZE".into(),
        sub_mode::ACRO => "ACRO".into(),
        sub_mode::ALT_HOLD => "ALT_HOLD".into(),
        sub_mode::AUTO => "AUTO".into(),
        sub_mode::GUIDED => "GUIDED".into(),
        sub_mode::CIRCLE => "CIRCLE".into(),
        sub_mode::SURFACE => "SURFACE".into(),
        sub_mode::POSHOLD => "POSHOLD".into(),
        sub_mode::MANUAL => "MANUAL".into(),
        sub_mode::MOTOR_DETECT => "MOTOR_DETECT".into(),
        sub_mode::SURFTRAK => "SURFTRAK".into(),
        other => format!("mode {other}"),
    }
}

/// Degrees from MAVLink's integer 1e-7 degrees.
pub fn deg_from_e7(v: i32) -> f64 {
    f64::from(v) * 1e-7
}

/// MAVLink's integer 1e-7 degrees from degrees (a model value, so within ±180°).
#[allow(clippy::cast_possible_truncation)]
pub fn e7_from_deg(v: f64) -> i32 {
    (v * 1e7)
        .round()
        .clamp(f64::from(i32::MIN), f64::from(i32::MAX)) as i32
}

/// Depth in metres from `relative_alt` in millimetres: ArduSub's altitude relative to the
/// surface is negative below it. Above the surface (a wave, a sensor offset) is depth 0.
pub fn depth_from_relative_alt_mm(relative_alt_mm: i32) -> f64 {
    (-f64::from(relative_alt_mm) / 1000.0).max(0.0)
}

/// MAVLink's `alt` (metres relative to home, up positive) for a depth.
#[allow(clippy::cast_possible_truncation)]
pub fn alt_for_depth(depth_m: f64) -> f32 {
    (-depth_m) as f32
}

/// Degrees from radians.
pub fn deg(rad: f32) -> f64 {
    f64::from(rad).to_degrees()
}

/// A heading in radians (ATTITUDE's yaw, in (-π, π]) as degrees in [0, 360).
pub fn yaw_deg(rad: f32) -> f64 {
    let d = deg(rad).rem_euclid(360.0);
    if d >= 360.0 { 0.0 } else { d }
}

/// A heading in centidegrees (GLOBAL_POSITION_INT's `hdg`), or `None` for UINT16_MAX.
pub fn hdg_deg(cdeg: u16) -> Option<f64> {
    (cdeg != u16::MAX).then(|| (f64::from(cdeg) / 100.0).rem_euclid(360.0))
}

/// Speed over ground in m/s from GLOBAL_POSITION_INT's north and east velocities in cm/s.
pub fn speed_from_cm_s(vx: i16, vy: i16) -> f64 {
    f64::from(vx).hypot(f64::from(vy)) / 100.0
}

/// What a battery's `battery_remaining` says: `Ok(None)` for -1 (unknown), `Err` for
/// values no battery has.
pub fn battery_pct(remaining: i8) -> Result<Option<f64>, i8> {
    match remaining {
        -1 => Ok(None),
        0..=100 => Ok(Some(f64::from(remaining))),
        other => Err(other),
    }
}

/// The Shoal kind of a MAVLink vehicle type, if it is a maritime one.
pub fn kind_of(t: MavType) -> Option<VehicleKind> {
    match t {
        MavType::MAV_TYPE_SUBMARINE => Some(VehicleKind::Rov),
        MavType::MAV_TYPE_SURFACE_BOAT => Some(VehicleKind::Usv),
        _ => None,
    }
}

/// The event severity and kind of a STATUSTEXT severity, or `None` for debug chatter.
pub fn statustext_event(s: MavSeverity) -> Option<(Severity, EventKind)> {
    Some(match s {
        MavSeverity::MAV_SEVERITY_EMERGENCY
        | MavSeverity::MAV_SEVERITY_ALERT
        | MavSeverity::MAV_SEVERITY_CRITICAL => (Severity::Critical, EventKind::Fault),
        MavSeverity::MAV_SEVERITY_ERROR => (Severity::Alarm, EventKind::Fault),
        MavSeverity::MAV_SEVERITY_WARNING => (Severity::Warning, EventKind::Other),
        MavSeverity::MAV_SEVERITY_NOTICE | MavSeverity::MAV_SEVERITY_INFO => {
            (Severity::Info, EventKind::Other)
        }
        MavSeverity::MAV_SEVERITY_DEBUG => return None,
    })
}

/// STATUSTEXT's text: up to the first NUL, invalid UTF-8 replaced.
pub fn statustext(text: &[u8]) -> String {
    let end = text.iter().position(|b| *b == 0).unwrap_or(text.len());
    String::from_utf8_lossy(&text[..end]).trim().to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn degrees_e7_round_trip() {
        assert_eq!(deg_from_e7(473_977_420), 47.397_742);
        assert_eq!(e7_from_deg(-122.084_095_1), -1_220_840_951);
        assert_eq!(e7_from_deg(deg_from_e7(123_456_789)), 123_456_789);
        assert_eq!(deg_from_e7(-1_800_000_000), -180.0);
    }

    #[test]
    fn millimetres_below_the_surface_are_depth_in_metres() {
        assert_eq!(depth_from_relative_alt_mm(-12_345), 12.345);
        assert_eq!(depth_from_relative_alt_mm(0), 0.0);
        assert_eq!(depth_from_relative_alt_mm(250), 0.0, "above the surface");
        assert_eq!(alt_for_depth(7.5), -7.5);
    }

    #[test]
    fn attitude_radians_become_degrees_and_yaw_0_360() {
        assert!((deg(0.5) - 28.647_889).abs() < 1e-5);
        assert!((yaw_deg(-std::f32::consts::FRAC_PI_2) - 270.0).abs() < 1e-4);
        assert!((yaw_deg(std::f32::consts::PI) - 180.0).abs() < 1e-4);
        assert_eq!(yaw_deg(-0.0), 0.0);
        assert!(yaw_deg(-1e-9) < 360.0);
        assert_eq!(hdg_deg(27_000), Some(270.0));
        assert_eq!(hdg_deg(u16::MAX), None);
    }

    #[test]
    fn speed_and_battery() {
        assert_eq!(speed_from_cm_s(30, 40), 0.5);
        assert_eq!(battery_pct(-1), Ok(None));
        assert_eq!(battery_pct(73), Ok(Some(73.0)));
        assert_eq!(battery_pct(101), Err(101));
        assert_eq!(battery_pct(-5), Err(-5));
    }

    #[test]
    fn statustext_severities_and_text() {
        assert_eq!(
            statustext_event(MavSeverity::MAV_SEVERITY_CRITICAL),
            Some((Severity::Critical, EventKind::Fault))
        );
        assert_eq!(
            statustext_event(MavSeverity::MAV_SEVERITY_WARNING),
            Some((Severity::Warning, EventKind::Other))
        );
        assert_eq!(statustext_event(MavSeverity::MAV_SEVERITY_DEBUG), None);
        assert_eq!(statustext(b"Leak Detected\0\0\0garbage"), "Leak Detected");
        assert_eq!(statustext(&[b'a', 0xFF, b'b']), "a\u{FFFD}b");
    }

    #[test]
    fn vehicle_types_and_modes() {
        assert_eq!(kind_of(MavType::MAV_TYPE_SUBMARINE), Some(VehicleKind::Rov));
        assert_eq!(kind_of(MavType::MAV_TYPE_QUADROTOR), None);
        assert_eq!(mode_name(sub_mode::GUIDED), "GUIDED");
        assert_eq!(mode_name(42), "mode 42");
    }
}
