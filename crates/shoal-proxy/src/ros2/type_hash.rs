//! REP 2016 type hashes ("RIHS01"): what rmw_zenoh puts in every topic's key expression and
//! liveliness token so that only endpoints of the same type definition talk.
//!
//! A type's hash is `RIHS01_` and the hex SHA-256 of a canonical JSON text of its type
//! description: the type's own fields and, sorted by name, the descriptions of every type
//! it refers to, directly or not. The text is what `rosidl_generator_type_description`
//! (`calculate_type_hash`) makes with Python's `json.dumps(..., separators=(', ', ': '))`:
//! keys in declaration order, default values left out. Field types are REP 2016's
//! `FieldType` ids: a base id for the element type, plus 48 for a fixed array, 96 for a
//! bounded and 144 for an unbounded sequence. Constants are not fields, so they do not
//! count.
//!
//! [`CATALOGUE`] holds the descriptions of the types the ROS 2 proxy uses, written from
//! their `.msg` files (a `.msg` `float32` is IDL `float`, `float64` is `double`); the hashes
//! are computed from it, never pasted, and the tests check them against hashes rosidl
//! generated.

use std::collections::BTreeSet;
use std::fmt::Write as _;

use sha2::{Digest, Sha256};

/// The prefix of a version 1 hash.
pub const RIHS01_PREFIX: &str = "RIHS01_";

/// The element type of a field.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Element {
    /// Another message type, by its full name (`std_msgs/msg/Header`).
    Nested(&'static str),
    /// `int8`.
    Int8,
    /// `uint8` (and `.msg` `char`).
    Uint8,
    /// `uint16`.
    Uint16,
    /// `int32`.
    Int32,
    /// `uint32`.
    Uint32,
    /// `float32` (IDL `float`).
    Float,
    /// `float64` (IDL `double`).
    Double,
    /// `bool`.
    Boolean,
    /// An unbounded `string`.
    String,
}

impl Element {
    /// REP 2016 `FieldType` id of a single value of this type.
    fn base_id(self) -> u8 {
        match self {
            Self::Nested(_) => 1,
            Self::Int8 => 2,
            Self::Uint8 => 3,
            Self::Uint16 => 5,
            Self::Int32 => 6,
            Self::Uint32 => 7,
            Self::Float => 10,
            Self::Double => 11,
            Self::Boolean => 15,
            Self::String => 17,
        }
    }
}

/// How many values a field holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Shape {
    /// One.
    Single,
    /// A fixed array of this many (`float64[9]`).
    Array(u32),
    /// An unbounded sequence (`float32[]`).
    Sequence,
}

/// One field of a type description.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Field {
    /// Field name.
    pub name: &'static str,
    /// Element type.
    pub element: Element,
    /// Array or sequence.
    pub shape: Shape,
}

/// The description of one message type: its full name and fields in `.msg` order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TypeDescription {
    /// `package/msg/Name`.
    pub name: &'static str,
    /// Fields, in declaration order.
    pub fields: &'static [Field],
}

/// Why a hash cannot be computed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum TypeHashError {
    /// A type, or a type it refers to, is not in the catalogue.
    #[error("no type description of {0}")]
    Unknown(String),
}

const fn one(name: &'static str, element: Element) -> Field {
    Field {
        name,
        element,
        shape: Shape::Single,
    }
}

const fn array(name: &'static str, element: Element, n: u32) -> Field {
    Field {
        name,
        element,
        shape: Shape::Array(n),
    }
}

const fn sequence(name: &'static str, element: Element) -> Field {
    Field {
        name,
        element,
        shape: Shape::Sequence,
    }
}

use Element::{Boolean, Double, Float, Int8, Int32, Nested, String as Str, Uint8, Uint16, Uint32};

const TIME: &str = "builtin_interfaces/msg/Time";
const HEADER: &str = "std_msgs/msg/Header";
const POINT: &str = "geometry_msgs/msg/Point";
const QUATERNION: &str = "geometry_msgs/msg/Quaternion";
const POSE: &str = "geometry_msgs/msg/Pose";
const VECTOR3: &str = "geometry_msgs/msg/Vector3";
const TWIST: &str = "geometry_msgs/msg/Twist";

/// The descriptions of the types the ROS 2 proxy uses and of every type they refer to.
pub const CATALOGUE: &[TypeDescription] = &[
    TypeDescription {
        name: TIME,
        fields: &[one("sec", Int32), one("nanosec", Uint32)],
    },
    TypeDescription {
        name: HEADER,
        fields: &[one("stamp", Nested(TIME)), one("frame_id", Str)],
    },
    TypeDescription {
        name: "std_msgs/msg/String",
        fields: &[one("data", Str)],
    },
    TypeDescription {
        name: "sensor_msgs/msg/NavSatStatus",
        fields: &[one("status", Int8), one("service", Uint16)],
    },
    TypeDescription {
        name: "sensor_msgs/msg/NavSatFix",
        fields: &[
            one("header", Nested(HEADER)),
            one("status", Nested("sensor_msgs/msg/NavSatStatus")),
            one("latitude", Double),
            one("longitude", Double),
            one("altitude", Double),
            array("position_covariance", Double, 9),
            one("position_covariance_type", Uint8),
        ],
    },
    TypeDescription {
        name: POINT,
        fields: &[one("x", Double), one("y", Double), one("z", Double)],
    },
    TypeDescription {
        name: VECTOR3,
        fields: &[one("x", Double), one("y", Double), one("z", Double)],
    },
    TypeDescription {
        name: QUATERNION,
        fields: &[
            one("x", Double),
            one("y", Double),
            one("z", Double),
            one("w", Double),
        ],
    },
    TypeDescription {
        name: POSE,
        fields: &[
            one("position", Nested(POINT)),
            one("orientation", Nested(QUATERNION)),
        ],
    },
    TypeDescription {
        name: "geometry_msgs/msg/PoseStamped",
        fields: &[one("header", Nested(HEADER)), one("pose", Nested(POSE))],
    },
    TypeDescription {
        name: "geometry_msgs/msg/PoseWithCovariance",
        fields: &[one("pose", Nested(POSE)), array("covariance", Double, 36)],
    },
    TypeDescription {
        name: TWIST,
        fields: &[
            one("linear", Nested(VECTOR3)),
            one("angular", Nested(VECTOR3)),
        ],
    },
    TypeDescription {
        name: "geometry_msgs/msg/TwistWithCovariance",
        fields: &[one("twist", Nested(TWIST)), array("covariance", Double, 36)],
    },
    TypeDescription {
        name: "nav_msgs/msg/Odometry",
        fields: &[
            one("header", Nested(HEADER)),
            one("child_frame_id", Str),
            one("pose", Nested("geometry_msgs/msg/PoseWithCovariance")),
            one("twist", Nested("geometry_msgs/msg/TwistWithCovariance")),
        ],
    },
    TypeDescription {
        name: "sensor_msgs/msg/BatteryState",
        fields: &[
            one("header", Nested(HEADER)),
            one("voltage", Float),
            one("temperature", Float),
            one("current", Float),
            one("charge", Float),
            one("capacity", Float),
            one("design_capacity", Float),
            one("percentage", Float),
            one("power_supply_status", Uint8),
            one("power_supply_health", Uint8),
            one("power_supply_technology", Uint8),
            one("present", Boolean),
            sequence("cell_voltage", Float),
            sequence("cell_temperature", Float),
            one("location", Str),
            one("serial_number", Str),
        ],
    },
    TypeDescription {
        name: "rcl_interfaces/msg/Log",
        fields: &[
            one("stamp", Nested(TIME)),
            one("level", Uint8),
            one("name", Str),
            one("msg", Str),
            one("file", Str),
            one("function", Str),
            one("line", Uint32),
        ],
    },
];

fn find(name: &str) -> Result<&'static TypeDescription, TypeHashError> {
    CATALOGUE
        .iter()
        .find(|t| t.name == name)
        .ok_or_else(|| TypeHashError::Unknown(name.to_string()))
}

/// A JSON string literal; the catalogue's names are ASCII identifiers, so this matches
/// Python's `ensure_ascii` output.
fn json_str(out: &mut String, s: &str) {
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            c if c.is_ascii() && !c.is_ascii_control() => out.push(c),
            c => {
                let mut units = [0u16; 2];
                for u in c.encode_utf16(&mut units) {
                    let _ = write!(out, "\\u{u:04x}");
                }
            }
        }
    }
    out.push('"');
}

fn individual_json(out: &mut String, t: &TypeDescription) {
    out.push_str("{\"type_name\": ");
    json_str(out, t.name);
    out.push_str(", \"fields\": [");
    for (i, f) in t.fields.iter().enumerate() {
        if i > 0 {
            out.push_str(", ");
        }
        let (offset, capacity) = match f.shape {
            Shape::Single => (0, 0),
            Shape::Array(n) => (48, n),
            Shape::Sequence => (144, 0),
        };
        let nested = match f.element {
            Nested(n) => n,
            _ => "",
        };
        out.push_str("{\"name\": ");
        json_str(out, f.name);
        let _ = write!(
            out,
            ", \"type\": {{\"type_id\": {}, \"capacity\": {capacity}, \"string_capacity\": 0, \
             \"nested_type_name\": ",
            f.element.base_id() + offset
        );
        json_str(out, nested);
        out.push_str("}}");
    }
    out.push_str("]}");
}

/// The canonical JSON text of `name`'s type description that REP 2016 hashes.
pub fn hashable_json(name: &str) -> Result<String, TypeHashError> {
    let top = find(name)?;
    // Every type reachable from the top one, once; BTreeSet sorts them by name as rosidl
    // does (`sorted(output_references)`).
    let mut referenced = BTreeSet::new();
    let mut queue: Vec<&str> = Vec::new();
    let nested_of = |t: &TypeDescription| {
        t.fields
            .iter()
            .filter_map(|f| match f.element {
                Nested(n) => Some(n),
                _ => None,
            })
            .collect::<Vec<_>>()
    };
    queue.extend(nested_of(top));
    while let Some(n) = queue.pop() {
        if referenced.insert(n) {
            queue.extend(nested_of(find(n)?));
        }
    }
    let mut out = String::from("{\"type_description\": ");
    individual_json(&mut out, top);
    out.push_str(", \"referenced_type_descriptions\": [");
    for (i, n) in referenced.iter().enumerate() {
        if i > 0 {
            out.push_str(", ");
        }
        individual_json(&mut out, find(n)?);
    }
    out.push_str("]}");
    Ok(out)
}

/// The RIHS01 hash of a catalogued type (`sensor_msgs/msg/NavSatFix`), as rmw_zenoh writes it.
pub fn type_hash(name: &str) -> Result<String, TypeHashError> {
    let json = hashable_json(name)?;
    Ok(format!(
        "{RIHS01_PREFIX}{}",
        hex::encode(Sha256::digest(json.as_bytes()))
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    // Expected values, each from a source independent of this code:
    // - std_msgs/String: the `chatter` examples of rmw_zenoh's docs/design.md (rolling);
    // - the others: rosidl_generator_c's output (`*__description.c`: `get_type_hash`, and
    //   the `*__EXPECTED_HASH` tables of referenced types), as committed in the build trees
    //   of public ROS 2 Jazzy workspaces (e.g. inertialsense/inertial-sense-sdk's
    //   `ros2/install/.../msg/detail/*__description.c` for Time and Header; generated
    //   `rcl_interfaces/msg/detail/log__description.c` for Log).
    const EXPECTED: &[(&str, &str)] = &[
        (
            "std_msgs/msg/String",
            "df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
        ),
        (
            "builtin_interfaces/msg/Time",
            "b106235e25a4c5ed35098aa0a61a3ee9c9b18d197f398b0e4206cea9acf9c197",
        ),
        (
            "std_msgs/msg/Header",
            "f49fb3ae2cf070f793645ff749683ac6b06203e41c891e17701b1cb597ce6a01",
        ),
        (
            "geometry_msgs/msg/Pose",
            "d501954e9476cea2996984e812054b68026ae0bfae789d9a10b23daf35cc90fa",
        ),
        (
            "geometry_msgs/msg/Vector3",
            "cc12fe83e4c02719f1ce8070bfd14aecd40f75a96696a67a2a1f37f7dbb0765d",
        ),
        (
            "sensor_msgs/msg/NavSatFix",
            "62223ab3fe210a15976021da7afddc9e200dc9ec75231c1b6a557fc598a65404",
        ),
        (
            "nav_msgs/msg/Odometry",
            "3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
        ),
        (
            "sensor_msgs/msg/BatteryState",
            "4bee5dfce981c98faa6828b868307a0a73f992ed0789f374ee96c8f840e69741",
        ),
        (
            "geometry_msgs/msg/PoseStamped",
            "10f3786d7d40fd2b54367835614bff85d4ad3b5dab62bf8bca0cc232d73b4cd8",
        ),
        (
            "rcl_interfaces/msg/Log",
            "e28ce254ca8abc06abf92773b74602cdbf116ed34fbaf294fb9f81da9f318eac",
        ),
    ];

    #[test]
    fn hashes_match_the_ones_rosidl_generated() {
        for (name, hex) in EXPECTED {
            assert_eq!(
                type_hash(name).unwrap(),
                format!("RIHS01_{hex}"),
                "{name}: {}",
                hashable_json(name).unwrap()
            );
        }
    }

    #[test]
    fn the_hashed_text_is_python_json_dumps_without_defaults() {
        assert_eq!(
            hashable_json("std_msgs/msg/String").unwrap(),
            "{\"type_description\": {\"type_name\": \"std_msgs/msg/String\", \"fields\": \
             [{\"name\": \"data\", \"type\": {\"type_id\": 17, \"capacity\": 0, \
             \"string_capacity\": 0, \"nested_type_name\": \"\"}}]}, \
             \"referenced_type_descriptions\": []}"
        );
        // Referenced types once each, sorted by name, whatever the order they are met in.
        let json = hashable_json("nav_msgs/msg/Odometry").unwrap();
        let at = |n: &str| json.find(&format!("{{\"type_name\": \"{n}\"")).unwrap();
        assert!(at(TIME) < at(POINT) && at(POINT) < at(POSE) && at(VECTOR3) < at(HEADER));
        assert_eq!(
            json.matches(&format!("\"type_name\": \"{VECTOR3}\""))
                .count(),
            1
        );
    }

    #[test]
    fn every_reference_in_the_catalogue_resolves() {
        for t in CATALOGUE {
            assert!(type_hash(t.name).is_ok(), "{}", t.name);
        }
        assert_eq!(
            type_hash("sensor_msgs/msg/Imu"),
            Err(TypeHashError::Unknown("sensor_msgs/msg/Imu".into()))
        );
    }
}
