//! The compact messages and their declarative schemas (docs/acoustic.md#compact-messages).
//!
//! Every message starts with a 1-byte message id, then its fields by the DCCL rule, then
//! zero padding to a byte. Sizes (bits before padding / bytes) are listed by
//! [`super::size_table`].

use serde::{Deserialize, Serialize};

use super::predict::PredictedDelta;
use super::schema::{BitReader, BitWriter, Field, Schema, bits_for_values};
use super::{DecodeError, EncodeError};

/// Message ids (the 1-byte DCCL id, docs/acoustic.md#compact-messages). 0 is reserved: a
/// zero byte where a message should start is frame padding.
pub mod id {
    /// [`super::StateKeyframe`].
    pub const STATE_KEYFRAME: u8 = 1;
    /// [`super::StateDelta`].
    pub const STATE_DELTA: u8 = 2;
    /// [`super::CompactTask`]: task layout 1, without the station's task identity. Still
    /// read and written (tools, the link benchmark, old captures), but a VDT refuses to run
    /// it: a re-delivery could not be told from a new task (docs/acoustic.md#task-identity).
    pub const TASK: u8 = 3;
    /// [`super::CompactTaskStatus`].
    pub const TASK_STATUS: u8 = 4;
    /// [`super::CompactEvent`].
    pub const EVENT: u8 = 5;
    /// [`super::CompactAnnouncement`].
    pub const ANNOUNCEMENT: u8 = 6;
    /// [`super::CompactEnvironment`].
    pub const ENVIRONMENT: u8 = 7;
    /// [`super::Ack`].
    pub const ACK: u8 = 8;
    /// [`super::IdentifiedTask`]: task layout 2, carrying the station's task id, issue
    /// sequence and expiry (docs/acoustic.md#task-identity). A build that predates it
    /// refuses it as an unknown message id.
    pub const IDENTIFIED_TASK: u8 = 9;
    /// [`super::PredictedDelta`]: delta layout 2, residuals from a dead-reckoning
    /// prediction (docs/acoustic.md#predicted-deltas). A build that predates it refuses it
    /// as an unknown message id; [`STATE_DELTA`] stays readable and writable.
    pub const PREDICTED_DELTA: u8 = 10;
    /// [`super::IdentifiedTask`] with a command lease: task layout 3, layout 2 plus the
    /// lease's term and holder (docs/acoustic.md#task-identity). Only a leased task takes
    /// it; a task without a lease still goes as [`IDENTIFIED_TASK`], bit for bit.
    pub const LEASED_TASK: u8 = 11;
}

const VEHICLE: Field = Field::new("vehicle", 0.0, 15.0, 1.0);
const SECONDS_OF_DAY: Field = Field::new("seconds_of_day", 0.0, 86_399.0, 1.0);
const LATITUDE: Field = Field::new("latitude_deg", -90.0, 90.0, 1e-5);
const LONGITUDE: Field = Field::new("longitude_deg", -180.0, 180.0, 1e-5);
const DEPTH: Field = Field::new("depth_m", 0.0, 6000.0, 0.1);
const SPEED: Field = Field::new("speed_mps", 0.0, 10.0, 0.05);
const NUMBER: Field = Field::new("number", 0.0, 255.0, 1.0);

/// Keyframe State Vector: the SWARMs field set and bounds of
/// docs/acoustic.md#compact-messages, 158 bits → 20 bytes. The SWARMs "subtype" nibble
/// carries the keyframe sequence number deltas refer to.
pub const STATE_KEYFRAME_SCHEMA: Schema = Schema {
    name: "state_keyframe",
    fields: &[
        VEHICLE,
        Field::new("seq", 0.0, 15.0, 1.0),
        SECONDS_OF_DAY,
        LATITUDE,
        LONGITUDE,
        DEPTH,
        // Optional costs nothing here: 10001 values + 1 still fit 14 bits.
        Field::new("altitude_m", 0.0, 1000.0, 0.1).optional(),
        SPEED,
        Field::new("yaw_deg", 0.0, 359.5, 0.5).circular(),
        Field::new("pitch_deg", -90.0, 90.0, 0.5),
        Field::new("roll_deg", -180.0, 180.0, 0.5),
        Field::new("battery_pct", 0.0, 100.0, 1.0),
    ],
};

/// Delta State Vector against a keyframe: 80 bits → 10 bytes. Position, depth, altitude
/// and battery are differences from the keyframe; attitude and speed are absolute but
/// coarser. A state that does not fit these ranges is sent as a keyframe instead.
pub const STATE_DELTA_SCHEMA: Schema = Schema {
    name: "state_delta",
    fields: &[
        VEHICLE,
        Field::new("keyframe_seq", 0.0, 15.0, 1.0),
        Field::new("dt_s", 0.0, 127.0, 1.0),
        // ±0.0051° ≈ ±570 m north at 2e-5° ≈ 2.2 m: finer than acoustic navigation error.
        Field::new("dlat_deg", -0.0051, 0.0051, 2e-5),
        Field::new("dlon_deg", -0.0051, 0.0051, 2e-5),
        Field::new("ddepth_m", -12.7, 12.7, 0.1),
        Field::new("daltitude_m", -12.6, 12.6, 0.2).optional(),
        Field::new("speed_mps", 0.0, 10.0, 0.25),
        Field::new("yaw_deg", 0.0, 357.0, 3.0).circular(),
        Field::new("pitch_deg", -14.0, 14.0, 2.0),
        Field::new("roll_deg", -14.0, 14.0, 2.0),
        Field::new("dbattery_pct", -3.0, 3.0, 1.0),
    ],
};

/// Task header: addressee, task number and kind (the [`shoal_model::TaskKind`] order).
pub const TASK_HEADER_SCHEMA: Schema = Schema {
    name: "task_header",
    fields: &[
        VEHICLE,
        Field::new("task_no", 0.0, 255.0, 1.0),
        Field::new("kind", 0.0, 7.0, 1.0),
    ],
};
/// One polygon or waypoint corner of a task.
pub const TASK_POINT_SCHEMA: Schema = Schema {
    name: "task_point",
    fields: &[LATITUDE, LONGITUDE],
};
/// Vertical target and speed of a moving task: a mode bit (0 depth, 1 altitude), the
/// target in metres, and the speed.
pub const TASK_MOTION_SCHEMA: Schema = Schema {
    name: "task_motion",
    fields: &[
        Field::new("z_is_altitude", 0.0, 1.0, 1.0),
        Field::new("z_m", 0.0, 6000.0, 0.1),
        SPEED,
    ],
};
/// Survey-specific fields: number of corners (3..=8) and line spacing.
pub const TASK_SURVEY_SCHEMA: Schema = Schema {
    name: "task_survey",
    fields: &[
        Field::new("points", 3.0, 8.0, 1.0),
        Field::new("line_spacing_m", 1.0, 2048.0, 1.0),
    ],
};
/// Hold duration, seconds (0 = until the next task).
pub const TASK_HOLD_SCHEMA: Schema = Schema {
    name: "task_hold",
    fields: &[Field::new("duration_s", 0.0, 86_400.0, 1.0)],
};
/// Reporting rate, Hz.
pub const TASK_RATE_SCHEMA: Schema = Schema {
    name: "task_rate",
    fields: &[Field::new("rate_hz", 0.0, 100.0, 0.001)],
};

/// Task status: 47 bits → 6 bytes (the free-text message is not carried).
pub const TASK_STATUS_SCHEMA: Schema = Schema {
    name: "task_status",
    fields: &[
        VEHICLE,
        Field::new("task_no", 0.0, 255.0, 1.0),
        Field::new("state", 0.0, 7.0, 1.0),
        Field::new("progress_pct", 0.0, 100.0, 1.0),
        SECONDS_OF_DAY,
    ],
};

/// Event/alarm: 53 bits → 7 bytes (the free text is not carried).
pub const EVENT_SCHEMA: Schema = Schema {
    name: "event",
    fields: &[
        Field::new("vehicle", 0.0, 15.0, 1.0).optional(),
        Field::new("event_no", 0.0, 255.0, 1.0),
        Field::new("severity", 0.0, 3.0, 1.0),
        Field::new("kind", 0.0, 8.0, 1.0),
        Field::new("task_no", 0.0, 255.0, 1.0).optional(),
        SECONDS_OF_DAY,
    ],
};

/// Compact announcement: 62 bits → 8 bytes; capabilities, sensors and links as bit sets.
pub const ANNOUNCEMENT_SCHEMA: Schema = Schema {
    name: "announcement",
    fields: &[
        VEHICLE,
        Field::new("kind", 0.0, 4.0, 1.0),
        Field::new("links", 0.0, 31.0, 1.0),
        Field::new("capabilities", 0.0, 255.0, 1.0),
        Field::new("sensors", 0.0, 255.0, 1.0),
        Field::new("max_speed_mps", 0.0, 30.0, 0.1),
        SECONDS_OF_DAY,
    ],
};

/// Environment observation header; the value field depends on the property
/// ([`ENVIRONMENT_PROPERTIES`]), then the position follows.
pub const ENVIRONMENT_HEADER_SCHEMA: Schema = Schema {
    name: "environment_header",
    fields: &[
        VEHICLE,
        Field::new("property", 0.0, 15.0, 1.0),
        SECONDS_OF_DAY,
    ],
};
/// Where an environment observation was made.
pub const ENVIRONMENT_POSITION_SCHEMA: Schema = Schema {
    name: "environment_position",
    fields: &[LATITUDE, LONGITUDE, DEPTH],
};

/// An environment property the compact encoding knows: CF standard name, UCUM unit and
/// the value field's bounds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EnvironmentProperty {
    /// CF standard name (as in [`shoal_model::EnvironmentObservation::property`]).
    pub name: &'static str,
    /// UCUM unit the value must be in.
    pub unit: &'static str,
    /// Bounds and resolution of the value.
    pub value: Field,
}

/// The property table: the index is the 4-bit property code on the wire.
pub const ENVIRONMENT_PROPERTIES: &[EnvironmentProperty] = &[
    EnvironmentProperty {
        name: "sea_water_temperature",
        unit: "Cel",
        value: Field::new("value", -5.0, 45.0, 0.001),
    },
    EnvironmentProperty {
        name: "sea_water_salinity",
        unit: "[ppth]",
        value: Field::new("value", 0.0, 45.0, 0.001),
    },
    EnvironmentProperty {
        name: "sea_water_pressure",
        unit: "dbar",
        value: Field::new("value", 0.0, 6500.0, 0.1),
    },
    EnvironmentProperty {
        name: "dissolved_oxygen",
        unit: "umol/kg",
        value: Field::new("value", 0.0, 500.0, 0.1),
    },
    EnvironmentProperty {
        name: "sea_water_turbidity",
        unit: "[NTU]",
        value: Field::new("value", 0.0, 1000.0, 0.1),
    },
    EnvironmentProperty {
        name: "chlorophyll_concentration",
        unit: "ug/L",
        value: Field::new("value", 0.0, 100.0, 0.01),
    },
    EnvironmentProperty {
        name: "sea_water_ph",
        unit: "[pH]",
        value: Field::new("value", 0.0, 14.0, 0.001),
    },
    EnvironmentProperty {
        name: "speed_of_sound_in_sea_water",
        unit: "m/s",
        value: Field::new("value", 1400.0, 1600.0, 0.01),
    },
    EnvironmentProperty {
        name: "sea_water_speed",
        unit: "m/s",
        value: Field::new("value", 0.0, 10.0, 0.01),
    },
    EnvironmentProperty {
        name: "sea_water_to_direction",
        unit: "deg",
        value: Field::new("value", 0.0, 359.0, 1.0).circular(),
    },
];

/// Ack: 28 bits → 4 bytes; acknowledges message `msg_id` number `ref_no` from `from`.
pub const ACK_SCHEMA: Schema = Schema {
    name: "ack",
    fields: &[VEHICLE, Field::new("msg_id", 0.0, 255.0, 1.0), NUMBER],
};

/// Converts a decoded small integer (bounded by its schema) to `u8`.
fn small(v: Option<f64>) -> u8 {
    // Schema bounds keep these within 0..=255.
    #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
    let x = v.unwrap_or(0.0).clamp(0.0, 255.0) as u8;
    x
}

/// Converts a decoded bounded integer to `u32`.
fn int(v: Option<f64>) -> u32 {
    #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
    let x = v.unwrap_or(0.0).clamp(0.0, f64::from(u32::MAX)) as u32;
    x
}

fn num(v: Option<f64>) -> f64 {
    v.unwrap_or(0.0)
}

fn values<const N: usize>(
    r: &mut BitReader<'_>,
    s: &Schema,
) -> Result<[Option<f64>; N], DecodeError> {
    let v = s.decode(r)?;
    v.try_into().map_err(|_| DecodeError::Inconsistent {
        rule: "schema length",
    })
}

/// A full State Vector at keyframe precision (also what a decoded delta expands to).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StateKeyframe {
    /// Acoustic address of the vehicle, 0..=15.
    pub vehicle: u8,
    /// Keyframe sequence number, 0..=15, that deltas refer to.
    pub seq: u8,
    /// Seconds since UTC midnight of the fix, 0..=86399 (the date is implied).
    pub seconds_of_day: u32,
    /// Latitude, degrees, at 1e-5°.
    pub latitude_deg: f64,
    /// Longitude, degrees, at 1e-5°.
    pub longitude_deg: f64,
    /// Depth, metres, 0..=6000 at 0.1.
    pub depth_m: f64,
    /// Altitude above the seabed, metres, 0..=1000 at 0.1, or `None` when unknown.
    pub altitude_m: Option<f64>,
    /// Speed, m/s, 0..=10 at 0.05.
    pub speed_mps: f64,
    /// Yaw, degrees, at 0.5 (wraps).
    pub yaw_deg: f64,
    /// Pitch, degrees, ±90 at 0.5.
    pub pitch_deg: f64,
    /// Roll, degrees, ±180 at 0.5.
    pub roll_deg: f64,
    /// Battery, percent, at 1.
    pub battery_pct: f64,
}

impl StateKeyframe {
    fn write(&self, w: &mut BitWriter) -> Result<(), EncodeError> {
        STATE_KEYFRAME_SCHEMA.encode(
            w,
            &[
                Some(f64::from(self.vehicle)),
                Some(f64::from(self.seq)),
                Some(f64::from(self.seconds_of_day)),
                Some(self.latitude_deg),
                Some(self.longitude_deg),
                Some(self.depth_m),
                self.altitude_m,
                Some(self.speed_mps),
                Some(self.yaw_deg),
                Some(self.pitch_deg),
                Some(self.roll_deg),
                Some(self.battery_pct),
            ],
        )
    }

    fn read(r: &mut BitReader<'_>) -> Result<Self, DecodeError> {
        let [
            vehicle,
            seq,
            sod,
            lat,
            lon,
            depth,
            alt,
            speed,
            yaw,
            pitch,
            roll,
            battery,
        ] = values::<12>(r, &STATE_KEYFRAME_SCHEMA)?;
        Ok(Self {
            vehicle: small(vehicle),
            seq: small(seq),
            seconds_of_day: int(sod),
            latitude_deg: num(lat),
            longitude_deg: num(lon),
            depth_m: num(depth),
            altitude_m: alt,
            speed_mps: num(speed),
            yaw_deg: num(yaw),
            pitch_deg: num(pitch),
            roll_deg: num(roll),
            battery_pct: num(battery),
        })
    }

    /// This state as a round trip through the keyframe encoding would return it.
    pub fn quantised(&self) -> Result<Self, EncodeError> {
        let mut w = BitWriter::new();
        self.write(&mut w)?;
        let bytes = w.finish();
        Self::read(&mut BitReader::new(&bytes)).map_err(|_| EncodeError::Inconsistent {
            field: "state_keyframe",
            rule: "re-decoding failed",
        })
    }
}

/// A State Vector coded as differences from keyframe `keyframe_seq` of the same vehicle.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StateDelta {
    /// Acoustic address of the vehicle, 0..=15.
    pub vehicle: u8,
    /// Sequence number of the reference keyframe.
    pub keyframe_seq: u8,
    /// Seconds since the keyframe's fix, 0..=127.
    pub dt_s: u32,
    /// Latitude difference, degrees, ±0.0051 at 2e-5.
    pub dlat_deg: f64,
    /// Longitude difference, degrees, ±0.0051 at 2e-5.
    pub dlon_deg: f64,
    /// Depth difference, metres, ±12.7 at 0.1.
    pub ddepth_m: f64,
    /// Altitude difference, metres, ±12.6 at 0.2; `None` when altitude is now unknown.
    pub daltitude_m: Option<f64>,
    /// Speed, m/s, 0..=10 at 0.25.
    pub speed_mps: f64,
    /// Yaw, degrees, at 3 (wraps).
    pub yaw_deg: f64,
    /// Pitch, degrees, ±14 at 2.
    pub pitch_deg: f64,
    /// Roll, degrees, ±14 at 2.
    pub roll_deg: f64,
    /// Battery difference, percent, ±3 at 1.
    pub dbattery_pct: f64,
}

impl StateDelta {
    fn write(&self, w: &mut BitWriter) -> Result<(), EncodeError> {
        STATE_DELTA_SCHEMA.encode(
            w,
            &[
                Some(f64::from(self.vehicle)),
                Some(f64::from(self.keyframe_seq)),
                Some(f64::from(self.dt_s)),
                Some(self.dlat_deg),
                Some(self.dlon_deg),
                Some(self.ddepth_m),
                self.daltitude_m,
                Some(self.speed_mps),
                Some(self.yaw_deg),
                Some(self.pitch_deg),
                Some(self.roll_deg),
                Some(self.dbattery_pct),
            ],
        )
    }

    fn read(r: &mut BitReader<'_>) -> Result<Self, DecodeError> {
        let [
            vehicle,
            seq,
            dt,
            dlat,
            dlon,
            ddepth,
            dalt,
            speed,
            yaw,
            pitch,
            roll,
            dbat,
        ] = values::<12>(r, &STATE_DELTA_SCHEMA)?;
        Ok(Self {
            vehicle: small(vehicle),
            keyframe_seq: small(seq),
            dt_s: int(dt),
            dlat_deg: num(dlat),
            dlon_deg: num(dlon),
            ddepth_m: num(ddepth),
            daltitude_m: dalt,
            speed_mps: num(speed),
            yaw_deg: num(yaw),
            pitch_deg: num(pitch),
            roll_deg: num(roll),
            dbattery_pct: num(dbat),
        })
    }

    /// The delta from `key` to `state`, or `None` if some difference is outside the delta
    /// ranges (or altitude became known), in which case a keyframe must be sent.
    pub fn between(key: &StateKeyframe, state: &StateKeyframe) -> Option<Self> {
        if key.vehicle != state.vehicle {
            return None;
        }
        let daltitude_m = match (key.altitude_m, state.altitude_m) {
            (Some(a), Some(b)) => Some(b - a),
            (_, None) => None,
            (None, Some(_)) => return None,
        };
        let d = Self {
            vehicle: state.vehicle,
            keyframe_seq: key.seq,
            dt_s: u32::try_from(
                (i64::from(state.seconds_of_day) - i64::from(key.seconds_of_day))
                    .rem_euclid(86_400),
            )
            .ok()?,
            dlat_deg: state.latitude_deg - key.latitude_deg,
            dlon_deg: state.longitude_deg - key.longitude_deg,
            ddepth_m: state.depth_m - key.depth_m,
            daltitude_m,
            speed_mps: state.speed_mps,
            yaw_deg: state.yaw_deg,
            pitch_deg: state.pitch_deg,
            roll_deg: state.roll_deg,
            dbattery_pct: state.battery_pct - key.battery_pct,
        };
        // The encoder is the range check: if it accepts, the delta fits.
        let mut w = BitWriter::new();
        d.write(&mut w).ok()?;
        Some(d)
    }

    /// The full state this delta describes relative to `key` (which must be keyframe
    /// `keyframe_seq` of the same vehicle).
    pub fn apply(&self, key: &StateKeyframe) -> StateKeyframe {
        let clean = |x: f64, step: f64| (x / step).round() * step;
        StateKeyframe {
            vehicle: self.vehicle,
            seq: key.seq,
            seconds_of_day: (key.seconds_of_day + self.dt_s) % 86_400,
            // Re-rounding to 1e-7° only removes float noise from the addition.
            latitude_deg: clean(key.latitude_deg + self.dlat_deg, 1e-7).clamp(-90.0, 90.0),
            longitude_deg: clean(key.longitude_deg + self.dlon_deg, 1e-7).clamp(-180.0, 180.0),
            depth_m: clean(key.depth_m + self.ddepth_m, 1e-3).max(0.0),
            altitude_m: match (key.altitude_m, self.daltitude_m) {
                (Some(a), Some(d)) => Some(clean(a + d, 1e-3).max(0.0)),
                _ => None,
            },
            speed_mps: self.speed_mps,
            yaw_deg: self.yaw_deg,
            pitch_deg: self.pitch_deg,
            roll_deg: self.roll_deg,
            battery_pct: (key.battery_pct + self.dbattery_pct).clamp(0.0, 100.0),
        }
    }
}

/// A WGS84 point of a task, degrees at 1e-5°.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Point {
    /// Latitude, degrees.
    pub latitude_deg: f64,
    /// Longitude, degrees.
    pub longitude_deg: f64,
}

/// How a moving task controls its vertical position and speed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Motion {
    /// Target depth in metres (0..=6000 at 0.1), or `None` to hold altitude.
    pub depth_m: Option<f64>,
    /// Target altitude in metres (0..=6000 at 0.1), or `None` to hold depth.
    pub altitude_m: Option<f64>,
    /// Speed, m/s, 0..=10 at 0.05 (0 = the vehicle chooses).
    pub speed_mps: f64,
}

impl Motion {
    fn write(&self, w: &mut BitWriter) -> Result<(), EncodeError> {
        let (mode, z) = match (self.depth_m, self.altitude_m) {
            (Some(d), None) => (0.0, d),
            (None, Some(a)) => (1.0, a),
            _ => {
                return Err(EncodeError::Inconsistent {
                    field: "depth_m",
                    rule: "exactly one of depth_m and altitude_m must be set",
                });
            }
        };
        TASK_MOTION_SCHEMA.encode(w, &[Some(mode), Some(z), Some(self.speed_mps)])
    }

    fn read(r: &mut BitReader<'_>) -> Result<Self, DecodeError> {
        let [mode, z, speed] = values::<3>(r, &TASK_MOTION_SCHEMA)?;
        let altitude = mode == Some(1.0);
        Ok(Self {
            depth_m: if altitude { None } else { z },
            altitude_m: if altitude { z } else { None },
            speed_mps: num(speed),
        })
    }
}

/// What a compact task asks for; the variants follow [`shoal_model::TaskKind`]'s order.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
#[non_exhaustive]
pub enum TaskAction {
    /// Go to one waypoint.
    Goto {
        /// Where.
        target: Point,
        /// Depth or altitude and speed.
        motion: Motion,
    },
    /// Lawnmower survey over a polygon of 3..=8 corners.
    Survey {
        /// Corners.
        polygon: Vec<Point>,
        /// Line spacing, metres, 1..=2048 at 1.
        line_spacing_m: f64,
        /// Depth or altitude and speed.
        motion: Motion,
    },
    /// Hold for a duration (0 = until the next task), seconds 0..=86400.
    Hold {
        /// Seconds.
        duration_s: u32,
    },
    /// Come to the surface.
    Surface,
    /// Return to the launch point.
    ReturnHome,
    /// Emergency surface.
    Abort,
    /// Send a State Vector now.
    RequestState,
    /// Report state at this rate, Hz, 0..=100 at 0.001.
    SetRate {
        /// State vectors per second.
        rate_hz: f64,
    },
}

impl TaskAction {
    fn code(&self) -> u8 {
        match self {
            Self::Goto { .. } => 0,
            Self::Survey { .. } => 1,
            Self::Hold { .. } => 2,
            Self::Surface => 3,
            Self::ReturnHome => 4,
            Self::Abort => 5,
            Self::RequestState => 6,
            Self::SetRate { .. } => 7,
        }
    }
}

/// A task for one vehicle, compact form of [`shoal_model::TaskAssignment`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CompactTask {
    /// Acoustic address of the vehicle that must execute it.
    pub vehicle: u8,
    /// Small task number, 0..=255, mapped to the task id by the caller.
    pub task_no: u8,
    /// What to do.
    pub action: TaskAction,
}

fn write_point(w: &mut BitWriter, p: &Point) -> Result<(), EncodeError> {
    TASK_POINT_SCHEMA.encode(w, &[Some(p.latitude_deg), Some(p.longitude_deg)])
}

fn read_point(r: &mut BitReader<'_>) -> Result<Point, DecodeError> {
    let [lat, lon] = values::<2>(r, &TASK_POINT_SCHEMA)?;
    Ok(Point {
        latitude_deg: num(lat),
        longitude_deg: num(lon),
    })
}

impl CompactTask {
    fn write(&self, w: &mut BitWriter) -> Result<(), EncodeError> {
        write_task_header(w, self.vehicle, self.task_no, &self.action)?;
        self.action.write(w)
    }

    fn read(r: &mut BitReader<'_>) -> Result<Self, DecodeError> {
        let (vehicle, task_no, kind) = read_task_header(r)?;
        Ok(Self {
            vehicle,
            task_no,
            action: TaskAction::read(kind, r)?,
        })
    }
}

fn write_task_header(
    w: &mut BitWriter,
    vehicle: u8,
    task_no: u8,
    action: &TaskAction,
) -> Result<(), EncodeError> {
    TASK_HEADER_SCHEMA.encode(
        w,
        &[
            Some(f64::from(vehicle)),
            Some(f64::from(task_no)),
            Some(f64::from(action.code())),
        ],
    )
}

fn read_task_header(r: &mut BitReader<'_>) -> Result<(u8, u8, u8), DecodeError> {
    let [vehicle, task_no, kind] = values::<3>(r, &TASK_HEADER_SCHEMA)?;
    Ok((small(vehicle), small(task_no), small(kind)))
}

impl TaskAction {
    /// The kind-specific fields (the header carries the kind).
    fn write(&self, w: &mut BitWriter) -> Result<(), EncodeError> {
        match self {
            TaskAction::Goto { target, motion } => {
                write_point(w, target)?;
                motion.write(w)
            }
            TaskAction::Survey {
                polygon,
                line_spacing_m,
                motion,
            } => {
                #[allow(clippy::cast_precision_loss)]
                let n = polygon.len() as f64;
                TASK_SURVEY_SCHEMA.encode(w, &[Some(n), Some(*line_spacing_m)])?;
                for p in polygon {
                    write_point(w, p)?;
                }
                motion.write(w)
            }
            TaskAction::Hold { duration_s } => {
                TASK_HOLD_SCHEMA.encode(w, &[Some(f64::from(*duration_s))])
            }
            TaskAction::SetRate { rate_hz } => TASK_RATE_SCHEMA.encode(w, &[Some(*rate_hz)]),
            TaskAction::Surface
            | TaskAction::ReturnHome
            | TaskAction::Abort
            | TaskAction::RequestState => Ok(()),
        }
    }

    fn read(kind: u8, r: &mut BitReader<'_>) -> Result<Self, DecodeError> {
        Ok(match kind {
            0 => {
                let target = read_point(r)?;
                TaskAction::Goto {
                    target,
                    motion: Motion::read(r)?,
                }
            }
            1 => {
                let [n, spacing] = values::<2>(r, &TASK_SURVEY_SCHEMA)?;
                let polygon = (0..small(n))
                    .map(|_| read_point(r))
                    .collect::<Result<Vec<_>, _>>()?;
                TaskAction::Survey {
                    polygon,
                    line_spacing_m: num(spacing),
                    motion: Motion::read(r)?,
                }
            }
            2 => {
                let [d] = values::<1>(r, &TASK_HOLD_SCHEMA)?;
                TaskAction::Hold { duration_s: int(d) }
            }
            3 => TaskAction::Surface,
            4 => TaskAction::ReturnHome,
            5 => TaskAction::Abort,
            6 => TaskAction::RequestState,
            _ => {
                let [rate] = values::<1>(r, &TASK_RATE_SCHEMA)?;
                TaskAction::SetRate { rate_hz: num(rate) }
            }
        })
    }
}

/// Bits of the issue sequence in [`IdentifiedTask`]: a station seeds its sequence with its
/// start time in microseconds (2^52 µs after 1970 is the year 2112).
pub const ISSUE_SEQ_BITS: u32 = 52;
/// Largest issue sequence an [`IdentifiedTask`] can carry.
pub const MAX_ISSUE_SEQ: u64 = (1 << ISSUE_SEQ_BITS) - 1;
/// Longest task id an [`IdentifiedTask`] carries (`shoal_model::MAX_ID_LEN`).
pub const MAX_TASK_ID_LEN: usize = 64;
/// The 65 characters a task id may hold, in ASCII order; a character travels as its index.
const ID_ALPHABET: &[u8; 65] = b"-.0123456789ABCDEFGHIJKLMNOPQRSTUVWXYZ_abcdefghijklmnopqrstuvwxyz";
/// The task's expiry, as the second of the UTC day (the receiver restores the date nearest
/// its own clock, as for every time of day); absent when the station set none.
const EXPIRES_FIELD: Field = Field::new("expires_s_of_day", 0.0, 86_399.0, 1.0).optional();

/// Bits a task id of `len` characters takes in an [`IdentifiedTask`]: a 6-bit length, then
/// the characters in base 65, three to 19 bits (65³ ≤ 2¹⁹), a last pair in 13, a last
/// single in 7 — about 6.3 bits a character.
pub fn task_id_bits(len: usize) -> usize {
    TASK_ID.bits(len)
}

/// Bits of a command lease's term in a leased [`IdentifiedTask`]. A term grows by one per
/// claim, hand-over or take-over of one vehicle, so 2^20 leaves room for years of
/// hand-overs every few minutes; a term beyond it is refused, never wrapped (a wrapped
/// term would order as older, and the vehicle would refuse the newest lease's tasks).
pub const LEASE_TERM_BITS: u32 = 20;
/// Largest lease term a leased [`IdentifiedTask`] can carry (term 0 means no lease, and
/// travels as layout 2).
pub const MAX_LEASE_TERM: u64 = (1 << LEASE_TERM_BITS) - 1;
/// Longest lease holder (a site name) an [`IdentifiedTask`] carries: the model's
/// `shoal_model::MAX_LEASE_HOLDER_LEN`, fixed here because it sets the width of the
/// holder's length field on the wire.
pub const MAX_LEASE_HOLDER_LEN: usize = 32;

/// Bits a command lease whose holder has `holder_len` characters adds to an
/// [`IdentifiedTask`]: the term in [`LEASE_TERM_BITS`], the holder's length − 1 in 5 bits,
/// then its characters as a task id's — 57 bits for a five-character site name.
pub fn lease_bits(holder_len: usize) -> usize {
    LEASE_TERM_BITS as usize + LEASE_HOLDER.bits(holder_len)
}

/// How an identifier (task id, lease holder) travels: its length − 1 in just enough bits
/// for `max_len`, then its characters from [`ID_ALPHABET`] in base 65, three at a time.
struct IdCode {
    field: &'static str,
    max_len: usize,
    rule: &'static str,
}

const TASK_ID: IdCode = IdCode {
    field: "task_id",
    max_len: MAX_TASK_ID_LEN,
    rule: "1..=64 characters of [A-Za-z0-9_.-]",
};
const LEASE_HOLDER: IdCode = IdCode {
    field: "lease_holder",
    max_len: MAX_LEASE_HOLDER_LEN,
    rule: "1..=32 characters of [A-Za-z0-9_.-]",
};

impl IdCode {
    /// Width of the length field: 6 bits for 1..=64, 5 for 1..=32. Every code of it is a
    /// valid length, so a length of 0 or above the maximum cannot even be written.
    fn len_bits(&self) -> u32 {
        bits_for_values(u64::try_from(self.max_len).unwrap_or(u64::MAX))
    }

    fn bits(&self, len: usize) -> usize {
        self.len_bits() as usize
            + len / 3 * 19
            + match len % 3 {
                0 => 0,
                1 => 7,
                _ => 13,
            }
    }

    fn write(&self, w: &mut BitWriter, id: &str) -> Result<(), EncodeError> {
        let bad = EncodeError::Inconsistent {
            field: self.field,
            rule: self.rule,
        };
        if id.is_empty() || id.len() > self.max_len {
            return Err(bad);
        }
        let mut codes = Vec::with_capacity(id.len());
        for b in id.bytes() {
            let i = ID_ALPHABET
                .iter()
                .position(|&c| c == b)
                .ok_or(bad.clone())?;
            codes.push(u64::try_from(i).unwrap_or(0));
        }
        w.write(u64::try_from(id.len() - 1).unwrap_or(0), self.len_bits());
        for chunk in codes.chunks(3) {
            let v = chunk.iter().fold(0, |acc, c| acc * 65 + c);
            w.write(v, chunk_bits(chunk.len()));
        }
        Ok(())
    }

    fn read(&self, r: &mut BitReader<'_>) -> Result<String, DecodeError> {
        let len = usize::try_from(r.read(self.len_bits())?).unwrap_or(0) + 1;
        let mut id = String::with_capacity(len);
        let mut left = len;
        while left > 0 {
            let n = left.min(3);
            let mut v = r.read(chunk_bits(n))?;
            // 65^n codes are valid; anything above is garbage, never guessed at.
            let limit = 65u64.pow(u32::try_from(n).unwrap_or(3));
            if v >= limit {
                return Err(DecodeError::InvalidCode {
                    field: self.field,
                    code: v,
                });
            }
            let mut chars = [0u8; 3];
            for slot in chars[..n].iter_mut().rev() {
                let i = usize::try_from(v % 65).unwrap_or(0);
                *slot = ID_ALPHABET.get(i).copied().unwrap_or(b'-');
                v /= 65;
            }
            id.extend(chars[..n].iter().map(|&c| char::from(c)));
            left -= n;
        }
        Ok(id)
    }
}

fn chunk_bits(n: usize) -> u32 {
    match n {
        1 => 7,
        2 => 13,
        _ => 19,
    }
}

/// The command lease a task was issued under (`shoal_model::TaskAssignment::lease_term`
/// and `lease_holder`): a vehicle refuses a task under a lease older than one it has
/// obeyed, so the lease must cross the water with the task.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TaskLease {
    /// The lease's term, 1..=[`MAX_LEASE_TERM`].
    pub term: u64,
    /// The site that held it, 1..=[`MAX_LEASE_HOLDER_LEN`] of `[A-Za-z0-9_.-]`.
    pub holder: String,
}

impl TaskLease {
    fn write(&self, w: &mut BitWriter) -> Result<(), EncodeError> {
        if self.term == 0 || self.term > MAX_LEASE_TERM {
            #[allow(clippy::cast_precision_loss)]
            return Err(EncodeError::OutOfRange {
                field: "lease_term",
                value: self.term as f64,
                min: 1.0,
                max: MAX_LEASE_TERM as f64,
            });
        }
        w.write(self.term, LEASE_TERM_BITS);
        LEASE_HOLDER.write(w, &self.holder)
    }

    fn read(r: &mut BitReader<'_>) -> Result<Self, DecodeError> {
        let term = r.read(LEASE_TERM_BITS)?;
        // Term 0 is "no lease", which travels as layout 2: here it is garbage.
        if term == 0 {
            return Err(DecodeError::InvalidCode {
                field: "lease_term",
                code: term,
            });
        }
        Ok(Self {
            term,
            holder: LEASE_HOLDER.read(r)?,
        })
    }
}

/// A task for one vehicle with the station's identity: task layout 2 (message id
/// [`id::IDENTIFIED_TASK`], docs/acoustic.md#task-identity), or layout 3
/// ([`id::LEASED_TASK`]) when it carries a command lease. The vehicle receives it under
/// the station's own task id, issue sequence, expiry and lease, so its task ledger
/// recognises a re-delivery over any link, after any restart, exactly as over IP, and
/// refuses a task under a superseded lease.
///
/// Layout: the task header (vehicle 4, task number 8, kind 3 bits), the issue sequence in
/// [`ISSUE_SEQ_BITS`], the expiry as an optional second of the day (17 bits), the task id
/// ([`task_id_bits`]), in layout 3 the lease ([`lease_bits`]), then the kind's fields as in
/// [`CompactTask`]. The identity costs 75 bits plus about 6.3 a character of the id: 107
/// bits for `m-1-1`; a lease adds 25 bits plus about 6.3 a character of its holder.
///
/// The lease's presence is the message id, not a flag bit: a flag inside layout 2 would
/// make a build that predates leases misread every leased task (the lease bits taken for
/// the action, or for the next PDU of the frame), and a new id for every task would make
/// such a build refuse unleased tasks too. So a task without a lease stays layout 2, bit for
/// bit, and costs nothing more; a leased one is layout 3, which an older build refuses as
/// an unknown message instead of running it without the lease check.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct IdentifiedTask {
    /// Acoustic address of the vehicle that must execute it.
    pub vehicle: u8,
    /// Small task number, 0..=255, that status reports name on the way back.
    pub task_no: u8,
    /// The station's task id, 1..=64 of `[A-Za-z0-9_.-]`, carried exactly.
    pub task_id: String,
    /// The station's issue sequence, 0..=[`MAX_ISSUE_SEQ`] (0: a tool issued the task).
    pub issue_seq: u64,
    /// The last second (of the UTC day) the vehicle may start the task, rounded down; `None`
    /// when the station set no expiry.
    pub expires_s_of_day: Option<u32>,
    /// The command lease the station issued the task under; `None` when it holds none
    /// (then the task travels as layout 2). Absent from JSON when `None`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lease: Option<TaskLease>,
    /// What to do.
    pub action: TaskAction,
}

impl IdentifiedTask {
    /// The message id this task travels under: [`id::LEASED_TASK`] with a lease,
    /// [`id::IDENTIFIED_TASK`] without.
    pub fn msg_id(&self) -> u8 {
        if self.lease.is_some() {
            id::LEASED_TASK
        } else {
            id::IDENTIFIED_TASK
        }
    }

    fn write(&self, w: &mut BitWriter) -> Result<(), EncodeError> {
        write_task_header(w, self.vehicle, self.task_no, &self.action)?;
        if self.issue_seq > MAX_ISSUE_SEQ {
            #[allow(clippy::cast_precision_loss)]
            return Err(EncodeError::OutOfRange {
                field: "issue_seq",
                value: self.issue_seq as f64,
                min: 0.0,
                max: MAX_ISSUE_SEQ as f64,
            });
        }
        w.write(self.issue_seq, ISSUE_SEQ_BITS);
        EXPIRES_FIELD.encode(w, self.expires_s_of_day.map(f64::from))?;
        TASK_ID.write(w, &self.task_id)?;
        if let Some(lease) = &self.lease {
            lease.write(w)?;
        }
        self.action.write(w)
    }

    /// Reads layout 2, or layout 3 when `leased` (the message id says which).
    fn read(r: &mut BitReader<'_>, leased: bool) -> Result<Self, DecodeError> {
        let (vehicle, task_no, kind) = read_task_header(r)?;
        let issue_seq = r.read(ISSUE_SEQ_BITS)?;
        let expires = EXPIRES_FIELD.decode(r)?;
        let task_id = TASK_ID.read(r)?;
        let lease = if leased {
            Some(TaskLease::read(r)?)
        } else {
            None
        };
        Ok(Self {
            vehicle,
            task_no,
            task_id,
            issue_seq,
            expires_s_of_day: expires.map(|v| int(Some(v))),
            lease,
            action: TaskAction::read(kind, r)?,
        })
    }
}

/// A vehicle's report on a task, compact form of [`shoal_model::TaskStatus`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CompactTaskStatus {
    /// Acoustic address of the reporting vehicle.
    pub vehicle: u8,
    /// Task number.
    pub task_no: u8,
    /// [`shoal_model::TaskState`] as its declaration index, 0..=7.
    pub state: u8,
    /// Progress, percent at 1.
    pub progress_pct: f64,
    /// Seconds since UTC midnight of the report.
    pub seconds_of_day: u32,
}

impl CompactTaskStatus {
    fn write(&self, w: &mut BitWriter) -> Result<(), EncodeError> {
        TASK_STATUS_SCHEMA.encode(
            w,
            &[
                Some(f64::from(self.vehicle)),
                Some(f64::from(self.task_no)),
                Some(f64::from(self.state)),
                Some(self.progress_pct),
                Some(f64::from(self.seconds_of_day)),
            ],
        )
    }

    fn read(r: &mut BitReader<'_>) -> Result<Self, DecodeError> {
        let [vehicle, task_no, state, progress, sod] = values::<5>(r, &TASK_STATUS_SCHEMA)?;
        Ok(Self {
            vehicle: small(vehicle),
            task_no: small(task_no),
            state: small(state),
            progress_pct: num(progress),
            seconds_of_day: int(sod),
        })
    }
}

/// An event or alarm, compact form of [`shoal_model::Event`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CompactEvent {
    /// Acoustic address of the vehicle concerned, if any.
    pub vehicle: Option<u8>,
    /// Small event number, 0..=255, mapped to the event id by the caller.
    pub event_no: u8,
    /// [`shoal_model::Severity`] as its declaration index, 0..=3.
    pub severity: u8,
    /// [`shoal_model::EventKind`] as its declaration index, 0..=8.
    pub kind: u8,
    /// Task number concerned, if any.
    pub task_no: Option<u8>,
    /// Seconds since UTC midnight.
    pub seconds_of_day: u32,
}

impl CompactEvent {
    fn write(&self, w: &mut BitWriter) -> Result<(), EncodeError> {
        EVENT_SCHEMA.encode(
            w,
            &[
                self.vehicle.map(f64::from),
                Some(f64::from(self.event_no)),
                Some(f64::from(self.severity)),
                Some(f64::from(self.kind)),
                self.task_no.map(f64::from),
                Some(f64::from(self.seconds_of_day)),
            ],
        )
    }

    fn read(r: &mut BitReader<'_>) -> Result<Self, DecodeError> {
        let [vehicle, event_no, severity, kind, task_no, sod] = values::<6>(r, &EVENT_SCHEMA)?;
        Ok(Self {
            vehicle: vehicle.map(|v| small(Some(v))),
            event_no: small(event_no),
            severity: small(severity),
            kind: small(kind),
            task_no: task_no.map(|v| small(Some(v))),
            seconds_of_day: int(sod),
        })
    }
}

/// Who a vehicle is, compact form of [`shoal_model::VehicleAnnouncement`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CompactAnnouncement {
    /// Acoustic address of the vehicle.
    pub vehicle: u8,
    /// [`shoal_model::VehicleKind`] as its declaration index, 0..=4.
    pub kind: u8,
    /// Bit set of [`shoal_model::LinkKind`] declaration indices.
    pub links: u8,
    /// Bit set over [`super::CAPABILITIES`].
    pub capabilities: u8,
    /// Bit set over [`super::SENSORS`].
    pub sensors: u8,
    /// Maximum speed, m/s, 0..=30 at 0.1.
    pub max_speed_mps: f64,
    /// Seconds since UTC midnight.
    pub seconds_of_day: u32,
}

impl CompactAnnouncement {
    fn write(&self, w: &mut BitWriter) -> Result<(), EncodeError> {
        ANNOUNCEMENT_SCHEMA.encode(
            w,
            &[
                Some(f64::from(self.vehicle)),
                Some(f64::from(self.kind)),
                Some(f64::from(self.links)),
                Some(f64::from(self.capabilities)),
                Some(f64::from(self.sensors)),
                Some(self.max_speed_mps),
                Some(f64::from(self.seconds_of_day)),
            ],
        )
    }

    fn read(r: &mut BitReader<'_>) -> Result<Self, DecodeError> {
        let [vehicle, kind, links, caps, sensors, speed, sod] =
            values::<7>(r, &ANNOUNCEMENT_SCHEMA)?;
        Ok(Self {
            vehicle: small(vehicle),
            kind: small(kind),
            links: small(links),
            capabilities: small(caps),
            sensors: small(sensors),
            max_speed_mps: num(speed),
            seconds_of_day: int(sod),
        })
    }
}

/// One environment measurement, compact form of [`shoal_model::EnvironmentObservation`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CompactEnvironment {
    /// Acoustic address of the measuring vehicle.
    pub vehicle: u8,
    /// Index into [`ENVIRONMENT_PROPERTIES`].
    pub property: u8,
    /// Seconds since UTC midnight.
    pub seconds_of_day: u32,
    /// Value, in the property's unit and resolution.
    pub value: f64,
    /// Latitude, degrees at 1e-5.
    pub latitude_deg: f64,
    /// Longitude, degrees at 1e-5.
    pub longitude_deg: f64,
    /// Depth, metres 0..=6000 at 0.1.
    pub depth_m: f64,
}

impl CompactEnvironment {
    fn property(code: u8) -> Option<&'static EnvironmentProperty> {
        ENVIRONMENT_PROPERTIES.get(usize::from(code))
    }

    fn write(&self, w: &mut BitWriter) -> Result<(), EncodeError> {
        let p = Self::property(self.property).ok_or(EncodeError::OutOfRange {
            field: "property",
            value: f64::from(self.property),
            min: 0.0,
            max: 15.0,
        })?;
        ENVIRONMENT_HEADER_SCHEMA.encode(
            w,
            &[
                Some(f64::from(self.vehicle)),
                Some(f64::from(self.property)),
                Some(f64::from(self.seconds_of_day)),
            ],
        )?;
        p.value.encode(w, Some(self.value))?;
        ENVIRONMENT_POSITION_SCHEMA.encode(
            w,
            &[
                Some(self.latitude_deg),
                Some(self.longitude_deg),
                Some(self.depth_m),
            ],
        )
    }

    fn read(r: &mut BitReader<'_>) -> Result<Self, DecodeError> {
        let [vehicle, property, sod] = values::<3>(r, &ENVIRONMENT_HEADER_SCHEMA)?;
        let code = small(property);
        let p = Self::property(code).ok_or(DecodeError::InvalidCode {
            field: "property",
            code: u64::from(code),
        })?;
        let value = p.value.decode(r)?;
        let [lat, lon, depth] = values::<3>(r, &ENVIRONMENT_POSITION_SCHEMA)?;
        Ok(Self {
            vehicle: small(vehicle),
            property: code,
            seconds_of_day: int(sod),
            value: num(value),
            latitude_deg: num(lat),
            longitude_deg: num(lon),
            depth_m: num(depth),
        })
    }
}

/// Acknowledges one numbered message (e.g. a keyframe by its `seq`, a task by `task_no`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Ack {
    /// Acoustic address of the acknowledging node.
    pub from: u8,
    /// Message id acknowledged (see [`id`]).
    pub msg_id: u8,
    /// Which one: keyframe seq, task number, event number...
    pub ref_no: u8,
}

impl Ack {
    fn write(&self, w: &mut BitWriter) -> Result<(), EncodeError> {
        ACK_SCHEMA.encode(
            w,
            &[
                Some(f64::from(self.from)),
                Some(f64::from(self.msg_id)),
                Some(f64::from(self.ref_no)),
            ],
        )
    }

    fn read(r: &mut BitReader<'_>) -> Result<Self, DecodeError> {
        let [from, msg_id, ref_no] = values::<3>(r, &ACK_SCHEMA)?;
        Ok(Self {
            from: small(from),
            msg_id: small(msg_id),
            ref_no: small(ref_no),
        })
    }
}

/// Any compact message; its JSON form (`{"type": "state_keyframe", ...}`) is what
/// `shoal pdu encode|decode` reads and prints.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
#[non_exhaustive]
pub enum Pdu {
    /// Full State Vector.
    StateKeyframe(StateKeyframe),
    /// State Vector relative to a keyframe (delta layout 1).
    StateDelta(StateDelta),
    /// State Vector as residuals from a keyframe's dead-reckoning prediction (layout 2).
    PredictedDelta(PredictedDelta),
    /// Task assignment without the station's identity (task layout 1).
    Task(CompactTask),
    /// Task assignment with the station's identity (task layout 2), and its command lease
    /// if any (task layout 3).
    IdentifiedTask(IdentifiedTask),
    /// Task status.
    TaskStatus(CompactTaskStatus),
    /// Event or alarm.
    Event(CompactEvent),
    /// Vehicle announcement.
    Announcement(CompactAnnouncement),
    /// Environment observation.
    Environment(CompactEnvironment),
    /// Acknowledgement.
    Ack(Ack),
}

impl Pdu {
    /// The 1-byte message id.
    pub fn msg_id(&self) -> u8 {
        match self {
            Self::StateKeyframe(_) => id::STATE_KEYFRAME,
            Self::StateDelta(_) => id::STATE_DELTA,
            Self::PredictedDelta(_) => id::PREDICTED_DELTA,
            Self::Task(_) => id::TASK,
            Self::IdentifiedTask(m) => m.msg_id(),
            Self::TaskStatus(_) => id::TASK_STATUS,
            Self::Event(_) => id::EVENT,
            Self::Announcement(_) => id::ANNOUNCEMENT,
            Self::Environment(_) => id::ENVIRONMENT,
            Self::Ack(_) => id::ACK,
        }
    }

    /// Snake-case message name, as in the JSON `type` tag.
    pub fn name(&self) -> &'static str {
        match self {
            Self::StateKeyframe(_) => "state_keyframe",
            Self::StateDelta(_) => "state_delta",
            Self::PredictedDelta(_) => "predicted_delta",
            Self::Task(_) => "task",
            Self::IdentifiedTask(_) => "identified_task",
            Self::TaskStatus(_) => "task_status",
            Self::Event(_) => "event",
            Self::Announcement(_) => "announcement",
            Self::Environment(_) => "environment",
            Self::Ack(_) => "ack",
        }
    }

    /// Writes id and fields (unpadded) into `w`.
    pub(super) fn write(&self, w: &mut BitWriter) -> Result<(), EncodeError> {
        w.write(u64::from(self.msg_id()), 8);
        match self {
            Self::StateKeyframe(m) => m.write(w),
            Self::StateDelta(m) => m.write(w),
            Self::PredictedDelta(m) => m.write(w),
            Self::Task(m) => m.write(w),
            Self::IdentifiedTask(m) => m.write(w),
            Self::TaskStatus(m) => m.write(w),
            Self::Event(m) => m.write(w),
            Self::Announcement(m) => m.write(w),
            Self::Environment(m) => m.write(w),
            Self::Ack(m) => m.write(w),
        }
    }

    /// Reads id and fields (not the padding) from `r`.
    pub(super) fn read(r: &mut BitReader<'_>) -> Result<Self, DecodeError> {
        let msg_id = r.read(8)?;
        #[allow(clippy::cast_possible_truncation)]
        Ok(match msg_id as u8 {
            id::STATE_KEYFRAME => Self::StateKeyframe(StateKeyframe::read(r)?),
            id::STATE_DELTA => Self::StateDelta(StateDelta::read(r)?),
            id::PREDICTED_DELTA => Self::PredictedDelta(PredictedDelta::read(r)?),
            id::TASK => Self::Task(CompactTask::read(r)?),
            id::IDENTIFIED_TASK => Self::IdentifiedTask(IdentifiedTask::read(r, false)?),
            id::LEASED_TASK => Self::IdentifiedTask(IdentifiedTask::read(r, true)?),
            id::TASK_STATUS => Self::TaskStatus(CompactTaskStatus::read(r)?),
            id::EVENT => Self::Event(CompactEvent::read(r)?),
            id::ANNOUNCEMENT => Self::Announcement(CompactAnnouncement::read(r)?),
            id::ENVIRONMENT => Self::Environment(CompactEnvironment::read(r)?),
            id::ACK => Self::Ack(Ack::read(r)?),
            other => return Err(DecodeError::UnknownMessage { id: other }),
        })
    }
}
