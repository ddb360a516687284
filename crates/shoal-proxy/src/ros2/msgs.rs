//! ROS 2 message types as they travel on DDS, field for field in `.msg` order, with the
//! DDS type names ROS 2 gives them (`<package>::msg::dds_::<Name>_`).
//!
//! ROS 2 (rmw_cyclonedds, rmw_fastrtps) sends messages as plain CDR (XCDR1) with the
//! types' fields in declaration order, nested messages inline, fixed arrays without a
//! length and sequences and strings with one; that is exactly how Shoal's DDS layer
//! serialises a serde struct, so these are plain structs. Each implements
//! [`shoal_dds::TopicType`] with its ROS type name and ROS 2's default QoS (reliable,
//! volatile; see [`super`] for the history depth).

use serde::de::{self, SeqAccess, Visitor};
use serde::ser::SerializeTuple;
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use shoal_dds::{Priority, QosProfile, TopicType};
use shoal_model::{Validate, ValidationError};

/// `builtin_interfaces/Time`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Time {
    /// Seconds since the epoch.
    pub sec: i32,
    /// Nanoseconds, [0, 1e9).
    pub nanosec: u32,
}

impl Time {
    /// A time from ms since the Unix epoch (saturating beyond 2038).
    pub fn from_ms(ms: i64) -> Self {
        let sec = i32::try_from(ms.div_euclid(1000)).unwrap_or(i32::MAX);
        let nanosec = u32::try_from(ms.rem_euclid(1000) * 1_000_000).unwrap_or(0);
        Self { sec, nanosec }
    }
}

/// `std_msgs/Header`.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Header {
    /// When the data was taken.
    pub stamp: Time,
    /// The frame the data is in.
    pub frame_id: String,
}

/// `sensor_msgs/NavSatStatus`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct NavSatStatus {
    /// -1 no fix, 0 fix, 1 SBAS, 2 GBAS.
    pub status: i8,
    /// GNSS constellations used (bits).
    pub service: u16,
}

/// `NavSatStatus.status` for "no fix".
pub const STATUS_NO_FIX: i8 = -1;

/// `sensor_msgs/NavSatFix`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct NavSatFix {
    /// Time and frame.
    pub header: Header,
    /// Fix status.
    pub status: NavSatStatus,
    /// Latitude, degrees; NaN if unknown.
    pub latitude: f64,
    /// Longitude, degrees; NaN if unknown.
    pub longitude: f64,
    /// Altitude above the WGS84 ellipsoid, metres; NaN if unknown.
    pub altitude: f64,
    /// Position covariance, m², ENU, row-major.
    pub position_covariance: [f64; 9],
    /// 0 unknown, 1 approximated, 2 diagonal known, 3 known.
    pub position_covariance_type: u8,
}

/// `geometry_msgs/Point`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Point {
    /// x, metres.
    pub x: f64,
    /// y, metres.
    pub y: f64,
    /// z, metres.
    pub z: f64,
}

/// `geometry_msgs/Vector3`.
pub type Vector3 = Point;

/// `geometry_msgs/Quaternion`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
    /// w.
    pub w: f64,
}

impl Default for Quaternion {
    /// The identity rotation, as ROS 2 defaults it.
    fn default() -> Self {
        Self {
            x: 0.0,
            y: 0.0,
            z: 0.0,
            w: 1.0,
        }
    }
}

/// `geometry_msgs/Pose`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Pose {
    /// Position.
    pub position: Point,
    /// Orientation.
    pub orientation: Quaternion,
}

/// `geometry_msgs/Twist`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Twist {
    /// Linear velocity, m/s.
    pub linear: Vector3,
    /// Angular velocity, rad/s.
    pub angular: Vector3,
}

/// A 6×6 covariance (`float64[36]`): serde has no impls for arrays longer than 32, and
/// CDR writes fixed arrays without a length, as a tuple.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Covariance6(pub [f64; 36]);

impl Default for Covariance6 {
    fn default() -> Self {
        Self([0.0; 36])
    }
}

impl Serialize for Covariance6 {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut t = s.serialize_tuple(36)?;
        for v in &self.0 {
            t.serialize_element(v)?;
        }
        t.end()
    }
}

impl<'de> Deserialize<'de> for Covariance6 {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> Visitor<'de> for V {
            type Value = Covariance6;
            fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str("36 float64")
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Covariance6, A::Error> {
                let mut out = [0.0; 36];
                for (i, slot) in out.iter_mut().enumerate() {
                    *slot = seq
                        .next_element()?
                        .ok_or_else(|| de::Error::invalid_length(i, &self))?;
                }
                Ok(Covariance6(out))
            }
        }
        d.deserialize_tuple(36, V)
    }
}

/// `geometry_msgs/PoseWithCovariance`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct PoseWithCovariance {
    /// The pose.
    pub pose: Pose,
    /// Its covariance.
    pub covariance: Covariance6,
}

/// `geometry_msgs/TwistWithCovariance`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct TwistWithCovariance {
    /// The twist.
    pub twist: Twist,
    /// Its covariance.
    pub covariance: Covariance6,
}

/// `nav_msgs/Odometry`: pose in `header.frame_id`, twist in `child_frame_id`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Odometry {
    /// Time and the pose's frame.
    pub header: Header,
    /// The twist's frame (the body).
    pub child_frame_id: String,
    /// Pose.
    pub pose: PoseWithCovariance,
    /// Velocity.
    pub twist: TwistWithCovariance,
}

/// `sensor_msgs/BatteryState`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct BatteryState {
    /// Time and frame.
    pub header: Header,
    /// Voltage, V.
    pub voltage: f32,
    /// Temperature, °C (NaN unknown).
    pub temperature: f32,
    /// Current, A (negative discharging).
    pub current: f32,
    /// Charge, Ah.
    pub charge: f32,
    /// Capacity, Ah.
    pub capacity: f32,
    /// Design capacity, Ah.
    pub design_capacity: f32,
    /// Charge fraction, [0, 1] (NaN unknown): not percent.
    pub percentage: f32,
    /// `POWER_SUPPLY_STATUS_*`.
    pub power_supply_status: u8,
    /// `POWER_SUPPLY_HEALTH_*`.
    pub power_supply_health: u8,
    /// `POWER_SUPPLY_TECHNOLOGY_*`.
    pub power_supply_technology: u8,
    /// Whether a battery is present.
    pub present: bool,
    /// Cell voltages, V.
    pub cell_voltage: Vec<f32>,
    /// Cell temperatures, °C.
    pub cell_temperature: Vec<f32>,
    /// Where the battery is.
    pub location: String,
    /// Its serial number.
    pub serial_number: String,
}

/// `geometry_msgs/PoseStamped`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct PoseStamped {
    /// Time and frame.
    pub header: Header,
    /// The pose.
    pub pose: Pose,
}

/// `rcl_interfaces/Log`: what ROS 2 nodes publish on `/rosout`.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
pub struct Log {
    /// When.
    pub stamp: Time,
    /// 10 debug, 20 info, 30 warn, 40 error, 50 fatal.
    pub level: u8,
    /// The logger (node) name.
    pub name: String,
    /// The message.
    pub msg: String,
    /// Source file.
    pub file: String,
    /// Source function.
    pub function: String,
    /// Source line.
    pub line: u32,
}

/// `rcl_interfaces/Log` levels.
pub mod log_level {
    /// Warnings.
    pub const WARN: u8 = 30;
    /// Errors.
    pub const ERROR: u8 = 40;
    /// Fatal errors.
    pub const FATAL: u8 = 50;
}

/// Longest string accepted from a ROS 2 peer, bytes: protects memory from a hostile or
/// broken writer, far above any real frame id or log line.
pub const MAX_STRING: usize = 4096;

fn text(field: &'static str, s: &str) -> Result<(), ValidationError> {
    if s.len() > MAX_STRING {
        return Err(ValidationError::BadText {
            field,
            rule: "at most 4096 bytes",
        });
    }
    Ok(())
}

fn header(h: &Header) -> Result<(), ValidationError> {
    if h.stamp.nanosec >= 1_000_000_000 {
        return Err(ValidationError::OutOfRange {
            field: "header.stamp.nanosec",
            value: f64::from(h.stamp.nanosec),
            min: 0.0,
            max: 999_999_999.0,
        });
    }
    text("header.frame_id", &h.frame_id)
}

// Only the wire form is checked here: NaN positions (ROS's "unknown") and out-of-range
// values are the adapter's to count, not reasons to discard the sample unseen.
impl Validate for NavSatFix {
    fn validate(&self) -> Result<(), ValidationError> {
        header(&self.header)
    }
}

impl Validate for Odometry {
    fn validate(&self) -> Result<(), ValidationError> {
        header(&self.header)?;
        text("child_frame_id", &self.child_frame_id)
    }
}

impl Validate for BatteryState {
    fn validate(&self) -> Result<(), ValidationError> {
        header(&self.header)?;
        text("location", &self.location)?;
        text("serial_number", &self.serial_number)?;
        if self.cell_voltage.len() > 1024 || self.cell_temperature.len() > 1024 {
            return Err(ValidationError::Inconsistent {
                field: "cell_voltage",
                rule: "at most 1024 cells",
            });
        }
        Ok(())
    }
}

impl Validate for PoseStamped {
    fn validate(&self) -> Result<(), ValidationError> {
        header(&self.header)?;
        let p = &self.pose;
        for (field, v) in [
            ("pose.position.x", p.position.x),
            ("pose.position.y", p.position.y),
            ("pose.position.z", p.position.z),
            ("pose.orientation.w", p.orientation.w),
        ] {
            if !v.is_finite() {
                return Err(ValidationError::NotFinite { field });
            }
        }
        Ok(())
    }
}

impl Validate for Log {
    fn validate(&self) -> Result<(), ValidationError> {
        text("name", &self.name)?;
        text("msg", &self.msg)
    }
}

macro_rules! ros_topic_type {
    ($t:ty, $name:literal, $topic:literal) => {
        impl TopicType for $t {
            /// The topic name without a namespace; the adapter builds `rt/<ns>/<name>`.
            const TOPIC: &'static str = $topic;
            const TYPE_NAME: &'static str = $name;
            // Reliable and volatile, like ROS 2's default (see the module docs of `ros2`).
            const PROFILE: QosProfile = QosProfile::State;
            const DEFAULT_PRIORITY: Priority = Priority::Telemetry;
            // ROS 2 message types have no key: every sample is the same instance, and the
            // endpoints are unkeyed on the wire (peers match only the same keyedness).
            const KEYED: bool = false;
            type Key = ();
            fn key(&self) {}
        }
    };
}

ros_topic_type!(NavSatFix, "sensor_msgs::msg::dds_::NavSatFix_", "rt/fix");
ros_topic_type!(Odometry, "nav_msgs::msg::dds_::Odometry_", "rt/odom");
ros_topic_type!(
    BatteryState,
    "sensor_msgs::msg::dds_::BatteryState_",
    "rt/battery"
);
ros_topic_type!(
    PoseStamped,
    "geometry_msgs::msg::dds_::PoseStamped_",
    "rt/goal_pose"
);
ros_topic_type!(Log, "rcl_interfaces::msg::dds_::Log_", "rt/rosout");

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pose_stamped_is_plain_cdr_in_msg_order() {
        let p = PoseStamped {
            header: Header {
                stamp: Time { sec: 1, nanosec: 2 },
                frame_id: "map".into(),
            },
            pose: Pose {
                position: Point {
                    x: 1.0,
                    y: 2.0,
                    z: -3.0,
                },
                orientation: Quaternion::default(),
            },
        };
        let b = shoal_dds::to_cdr_le(&p).unwrap();
        // Encapsulation CDR_LE; sec; nanosec; "map\0" with its length; then the doubles,
        // 8-aligned from the start of the payload (offset 16: no padding needed).
        assert_eq!(
            hex::encode(&b[..20]),
            "000100000100000002000000040000006d617000"
        );
        assert_eq!(b.len(), 4 + 16 + 7 * 8);
        assert_eq!(&b[20..28], &1.0f64.to_le_bytes());
        assert_eq!(&b[36..44], &(-3.0f64).to_le_bytes());
        assert_eq!(
            &b[68..76],
            &1.0f64.to_le_bytes(),
            "w of the identity quaternion"
        );
    }

    #[test]
    fn a_navsatfix_aligns_its_doubles_after_the_status() {
        let f = NavSatFix {
            header: Header {
                stamp: Time::from_ms(1_700_000_000_250),
                frame_id: "gps".into(),
            },
            status: NavSatStatus {
                status: 0,
                service: 1,
            },
            latitude: 41.5,
            ..NavSatFix::default()
        };
        let b = shoal_dds::to_cdr_le(&f).unwrap();
        // Payload: stamp 8, "gps" 4+4 = 16; status i8 at 16, pad 1, service u16 at 18;
        // pad 4 to 24 for the first double.
        let p = &b[4..];
        assert_eq!(p[16], 0);
        assert_eq!(&p[18..20], &1u16.to_le_bytes());
        assert_eq!(&p[24..32], &41.5f64.to_le_bytes());
        // 3 doubles + 9 covariance + 1 byte type.
        assert_eq!(p.len(), 24 + 3 * 8 + 9 * 8 + 1);
        let t = Time::from_ms(1_700_000_000_250);
        assert_eq!((t.sec, t.nanosec), (1_700_000_000, 250_000_000));
    }

    #[test]
    fn odometry_puts_its_36_covariances_inline_without_a_length() {
        let mut o = Odometry::default();
        o.pose.covariance.0[35] = 7.0;
        o.twist.twist.linear.x = 1.5;
        let b = shoal_dds::to_cdr_le(&o).unwrap();
        let p = &b[4..];
        let f = |i: usize| f64::from_le_bytes(p[i..i + 8].try_into().unwrap());
        // Header: stamp 8, empty frame id (length 1, NUL) to 13; child frame id at 16 to
        // 21; the pose's doubles from 24: 7 of the pose, 36 of covariance; then the twist.
        assert_eq!(p.len(), 24 + (7 + 36 + 6 + 36) * 8);
        assert_eq!(f(24 + 6 * 8), 1.0, "w of the identity quaternion");
        assert_eq!(f(24 + (7 + 35) * 8), 7.0);
        assert_eq!(f(24 + 43 * 8), 1.5);
    }

    #[test]
    fn validation_checks_the_wire_form_only() {
        let mut f = NavSatFix {
            latitude: f64::NAN,
            ..NavSatFix::default()
        };
        assert_eq!(
            f.validate(),
            Ok(()),
            "NaN is ROS's unknown, counted by the adapter"
        );
        f.header.stamp.nanosec = 1_000_000_000;
        assert!(f.validate().is_err());
        let mut g = PoseStamped::default();
        g.pose.position.x = f64::INFINITY;
        assert!(g.validate().is_err());
    }
}
