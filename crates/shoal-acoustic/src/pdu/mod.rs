//! Compact PDUs: the DCCL rule, the messages, frame packing and model conversions.
//!
//! - [`schema`]: [`Field`] / [`Schema`] and the bit writer/reader
//!   (docs/acoustic.md#compact-messages).
//! - [`Pdu`]: the compact messages (keyframe and delta State Vector, task with the
//!   station's identity and command lease, task status, event, announcement, environment observation, ack);
//!   `serde` gives their JSON form.
//! - [`encode`] / [`decode`]: one PDU ↔ bytes; [`pack_frame`] / [`unpack_frame`]: several
//!   PDUs in one modem frame of at most [`MAX_FRAME`] bytes (an instant message).
//! - [`DeltaEncoder`] / [`DeltaDecoder`]: keyframe + delta State Vector coding, with
//!   [`PredictedDelta`] (delta layout 2: residuals from a dead-reckoning [`predict`]ion).
//! - [`convert`]: to and from `shoal-model` types, with the precision each field loses.
//! - [`size_table`]: each message's size in bits and bytes, for the benchmark.

pub mod convert;
mod delta;
mod messages;
mod predict;
pub mod schema;

pub use convert::{AddressBook, CAPABILITIES, ConvertError, SENSORS};
pub use delta::{DeltaDecoder, DeltaEncoder};
pub use messages::*;
pub use predict::{DIVE_PITCH_DEG, MAX_DT_S, PredictedDelta, RESIDUALS, Residual, predict};
pub use schema::{BitReader, BitWriter, Field, Schema};

/// Largest modem frame: an EvoLogics instant message carries at most 64 bytes
/// (docs/acoustic.md#frame-sizes-and-bit-rates).
pub const MAX_FRAME: usize = 64;

/// Why a message could not be encoded.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum EncodeError {
    /// A value lies outside its field's bounds.
    #[error("{field} = {value} is outside [{min}, {max}]")]
    OutOfRange {
        /// Field name.
        field: &'static str,
        /// Offending value.
        value: f64,
        /// Lower bound.
        min: f64,
        /// Upper bound.
        max: f64,
    },
    /// A value is NaN or infinite.
    #[error("{field} is not a finite number")]
    NotFinite {
        /// Field name.
        field: &'static str,
    },
    /// A required field has no value.
    #[error("{field} is required")]
    Missing {
        /// Field name.
        field: &'static str,
    },
    /// Field values contradict each other.
    #[error("{field}: {rule}")]
    Inconsistent {
        /// Field name.
        field: &'static str,
        /// Broken rule.
        rule: &'static str,
    },
    /// The PDUs do not fit in one frame.
    #[error("frame of {bytes} bytes exceeds {max}")]
    FrameTooLong {
        /// Size needed.
        bytes: usize,
        /// Limit.
        max: usize,
    },
}

/// Why bytes could not be decoded; decoders never panic on any input.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum DecodeError {
    /// Input ended inside a message.
    #[error("truncated: needed {needed_bits} bits, have {available_bits}")]
    Truncated {
        /// Bits needed.
        needed_bits: usize,
        /// Bits available.
        available_bits: usize,
    },
    /// The message id byte is not one of [`id`].
    #[error("unknown message id {id}: a message or layout this build does not know")]
    UnknownMessage {
        /// The id byte.
        id: u8,
    },
    /// A field held a code above its maximum (garbage).
    #[error("invalid code {code} for {field}")]
    InvalidCode {
        /// Field name.
        field: &'static str,
        /// The code read.
        code: u64,
    },
    /// Padding bits were not zero (garbage).
    #[error("non-zero padding")]
    BadPadding,
    /// Bytes remain after the message.
    #[error("{0} trailing bytes")]
    TrailingBytes(usize),
    /// Structurally impossible content.
    #[error("inconsistent message: {rule}")]
    Inconsistent {
        /// Broken rule.
        rule: &'static str,
    },
    /// A delta refers to a keyframe this decoder has not seen.
    #[error("delta for vehicle {vehicle} refers to unknown keyframe {seq}")]
    UnknownKeyframe {
        /// Vehicle address.
        vehicle: u8,
        /// Keyframe sequence number.
        seq: u8,
    },
    /// A variable-length code has more leading zeros than its field's largest value needs
    /// (garbage, or a code from a layout this build does not know).
    #[error("overlong variable-length code for {field}")]
    Overlong {
        /// Field name.
        field: &'static str,
    },
    /// Not valid hexadecimal.
    #[error("invalid hex")]
    BadHex,
}

/// An encoded PDU with its exact size before padding.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Encoded {
    /// The bytes, padded to a byte.
    pub bytes: Vec<u8>,
    /// Significant bits (message id included, padding excluded).
    pub bits: usize,
}

/// Encodes one PDU (1-byte id, fields, zero padding to a byte).
pub fn encode(pdu: &Pdu) -> Result<Vec<u8>, EncodeError> {
    encode_sized(pdu).map(|e| e.bytes)
}

/// Encodes one PDU and reports its size in bits.
pub fn encode_sized(pdu: &Pdu) -> Result<Encoded, EncodeError> {
    let mut w = BitWriter::new();
    pdu.write(&mut w)?;
    let bits = w.bit_len();
    Ok(Encoded {
        bytes: w.finish(),
        bits,
    })
}

/// Decodes exactly one PDU occupying all of `bytes`.
pub fn decode(bytes: &[u8]) -> Result<Pdu, DecodeError> {
    let (pdu, used) = decode_prefix(bytes)?;
    match bytes.len() - used {
        0 => Ok(pdu),
        n => Err(DecodeError::TrailingBytes(n)),
    }
}

/// Decodes the PDU at the start of `bytes`; returns it and the bytes it occupied.
pub fn decode_prefix(bytes: &[u8]) -> Result<(Pdu, usize), DecodeError> {
    let mut r = BitReader::new(bytes);
    let pdu = Pdu::read(&mut r)?;
    let used = r.align()?;
    Ok((pdu, used))
}

/// Packs PDUs back to back into one frame of at most [`MAX_FRAME`] bytes. PDUs are
/// self-delimiting (the id fixes the layout), so no lengths are needed.
pub fn pack_frame(pdus: &[Pdu]) -> Result<Vec<u8>, EncodeError> {
    let mut frame = Vec::new();
    for p in pdus {
        frame.extend(encode(p)?);
    }
    if frame.len() > MAX_FRAME {
        return Err(EncodeError::FrameTooLong {
            bytes: frame.len(),
            max: MAX_FRAME,
        });
    }
    Ok(frame)
}

/// Unpacks a frame into its PDUs. Trailing zero bytes are padding (id 0 is reserved), so
/// frames padded by a modem or a burst still decode.
pub fn unpack_frame(mut frame: &[u8]) -> Result<Vec<Pdu>, DecodeError> {
    let mut out = Vec::new();
    while let Some(&first) = frame.first() {
        if first == 0 {
            if frame.iter().all(|&b| b == 0) {
                break;
            }
            return Err(DecodeError::UnknownMessage { id: 0 });
        }
        let (pdu, used) = decode_prefix(frame)?;
        out.push(pdu);
        frame = frame.get(used..).unwrap_or_default();
    }
    Ok(out)
}

/// Greedily fills frames of at most `max` bytes with already-encoded PDUs, in order.
#[derive(Debug, Clone)]
pub struct FramePacker {
    max: usize,
    frame: Vec<u8>,
}

impl FramePacker {
    /// A packer for frames of at most `max` bytes.
    pub fn new(max: usize) -> Self {
        Self {
            max,
            frame: Vec::new(),
        }
    }

    /// Appends `pdu` if it fits; returns whether it did.
    pub fn try_push(&mut self, pdu: &[u8]) -> bool {
        if self.frame.len() + pdu.len() > self.max {
            return false;
        }
        self.frame.extend_from_slice(pdu);
        true
    }

    /// Bytes still free.
    pub fn remaining(&self) -> usize {
        self.max.saturating_sub(self.frame.len())
    }

    /// The frame so far.
    pub fn finish(self) -> Vec<u8> {
        self.frame
    }
}

/// Lowercase hex of `bytes`: the text form of a PDU on the command line (`shoal pdu`).
pub fn to_hex(bytes: &[u8]) -> String {
    hex::encode(bytes)
}

/// Bytes from hex (whitespace ignored, so a dump split into groups or lines reads back;
/// either case).
pub fn from_hex(text: &str) -> Result<Vec<u8>, DecodeError> {
    let digits: Vec<u8> = text.bytes().filter(|b| !b.is_ascii_whitespace()).collect();
    hex::decode(digits).map_err(|_| DecodeError::BadHex)
}

/// Why a JSON PDU could not be turned into bytes.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum JsonError {
    /// Not a PDU in JSON form.
    #[error("invalid PDU JSON: {0}")]
    Json(#[from] serde_json::Error),
    /// Valid JSON that does not fit the compact encoding.
    #[error(transparent)]
    Encode(#[from] EncodeError),
    /// Bytes that do not decode.
    #[error(transparent)]
    Decode(#[from] DecodeError),
}

/// `shoal pdu encode`: a PDU in JSON (`{"type": "ack", "from": 1, ...}`) or a JSON array
/// of PDUs (packed as one frame) → bytes and significant bits.
pub fn encode_json(json: &str) -> Result<Encoded, JsonError> {
    let v: serde_json::Value = serde_json::from_str(json)?;
    if v.is_array() {
        let pdus: Vec<Pdu> = serde_json::from_value(v)?;
        let mut bits = 0;
        for p in &pdus {
            bits += encode_sized(p)?.bits;
        }
        return Ok(Encoded {
            bytes: pack_frame(&pdus)?,
            bits,
        });
    }
    let pdu: Pdu = serde_json::from_value(v)?;
    Ok(encode_sized(&pdu)?)
}

/// `shoal pdu decode`: a frame's bytes → a pretty JSON array of its PDUs.
pub fn decode_to_json(frame: &[u8]) -> Result<String, JsonError> {
    let pdus = unpack_frame(frame)?;
    Ok(serde_json::to_string_pretty(&pdus)?)
}

/// One row of the PDU size table.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct SizeEntry {
    /// Message (and variant) name.
    pub message: &'static str,
    /// Significant bits, message id included.
    pub bits: usize,
    /// Bytes on the wire (padded).
    pub bytes: usize,
}

/// Each message's size in bits and bytes (for `shoal bench` and the docs). The reference
/// points are DCCL's 158 bits / 20 bytes and the SWARMs paper's 51 ASCII bytes
/// (docs/acoustic.md#dccl-comparison).
pub fn size_table() -> Vec<SizeEntry> {
    samples()
        .into_iter()
        .filter_map(|(message, pdu)| {
            let e = encode_sized(&pdu).ok()?;
            Some(SizeEntry {
                message,
                bits: e.bits,
                bytes: e.bytes.len(),
            })
        })
        .collect()
}

/// One representative PDU per message (and task variant), all encodable.
pub fn samples() -> Vec<(&'static str, Pdu)> {
    let key = StateKeyframe {
        vehicle: 3,
        seq: 1,
        seconds_of_day: 43_200,
        latitude_deg: 43.1,
        longitude_deg: 5.9,
        depth_m: 12.5,
        altitude_m: Some(8.2),
        speed_mps: 1.5,
        yaw_deg: 90.0,
        pitch_deg: -2.0,
        roll_deg: 1.0,
        battery_pct: 80.0,
    };
    let motion = Motion {
        depth_m: Some(10.0),
        altitude_m: None,
        speed_mps: 1.5,
    };
    let p = |a: f64, b: f64| Point {
        latitude_deg: a,
        longitude_deg: b,
    };
    let task = |action| {
        Pdu::Task(CompactTask {
            vehicle: 3,
            task_no: 7,
            action,
        })
    };
    let survey_action = |n: usize| TaskAction::Survey {
        polygon: [
            (43.1, 5.9),
            (43.1, 5.91),
            (43.11, 5.91),
            (43.11, 5.9),
            (43.12, 5.9),
            (43.12, 5.91),
            (43.13, 5.91),
            (43.13, 5.9),
        ]
        .into_iter()
        .take(n)
        .map(|(a, b)| p(a, b))
        .collect(),
        line_spacing_m: 20.0,
        motion,
    };
    let survey = |n: usize| task(survey_action(n));
    let identified = |action| {
        Pdu::IdentifiedTask(IdentifiedTask {
            vehicle: 3,
            task_no: 7,
            task_id: "m-1-1".into(),
            issue_seq: 1_780_000_000_000_000,
            expires_s_of_day: Some(43_875),
            lease: None,
            action,
        })
    };
    vec![
        ("state_keyframe", Pdu::StateKeyframe(key)),
        (
            "state_delta",
            Pdu::StateDelta(StateDelta {
                vehicle: 3,
                keyframe_seq: 1,
                dt_s: 10,
                dlat_deg: 0.0001,
                dlon_deg: 0.0001,
                ddepth_m: 0.5,
                daltitude_m: Some(-0.4),
                speed_mps: 1.5,
                yaw_deg: 90.0,
                pitch_deg: -2.0,
                roll_deg: 0.0,
                dbattery_pct: 0.0,
            }),
        ),
        (
            // A straight, level leg 10 s after the keyframe: 1.1 m along and 0.2 m of
            // altitude off the prediction.
            "predicted_delta_straight_leg",
            Pdu::PredictedDelta(PredictedDelta {
                vehicle: 3,
                keyframe_seq: 1,
                dt_s: 10,
                lat_steps: 0,
                lon_steps: -1,
                depth_steps: 0,
                altitude_steps: Some(1),
                speed_steps: 0,
                yaw_steps: 0,
                pitch_steps: 0,
                roll_steps: 0,
                battery_steps: 0,
            }),
        ),
        (
            "task_goto",
            task(TaskAction::Goto {
                target: p(43.1, 5.9),
                motion,
            }),
        ),
        ("task_survey_4_points", survey(4)),
        ("task_survey_8_points", survey(8)),
        ("task_hold", task(TaskAction::Hold { duration_s: 600 })),
        ("task_surface", task(TaskAction::Surface)),
        ("task_return_home", task(TaskAction::ReturnHome)),
        ("task_abort", task(TaskAction::Abort)),
        ("task_request_state", task(TaskAction::RequestState)),
        ("task_set_rate", task(TaskAction::SetRate { rate_hz: 0.05 })),
        (
            "identified_task_goto",
            identified(TaskAction::Goto {
                target: p(43.1, 5.9),
                motion,
            }),
        ),
        (
            // Layout 3: the same goto, issued under the command lease "shore" took at term 3.
            "identified_task_goto_leased",
            Pdu::IdentifiedTask(IdentifiedTask {
                vehicle: 3,
                task_no: 7,
                task_id: "m-1-1".into(),
                issue_seq: 1_780_000_000_000_000,
                expires_s_of_day: Some(43_875),
                lease: Some(TaskLease {
                    term: 3,
                    holder: "shore".into(),
                }),
                action: TaskAction::Goto {
                    target: p(43.1, 5.9),
                    motion,
                },
            }),
        ),
        (
            "identified_task_survey_4_points",
            identified(survey_action(4)),
        ),
        (
            "identified_task_hold",
            identified(TaskAction::Hold { duration_s: 600 }),
        ),
        ("identified_task_abort", identified(TaskAction::Abort)),
        (
            "task_status",
            Pdu::TaskStatus(CompactTaskStatus {
                vehicle: 3,
                task_no: 7,
                state: 3,
                progress_pct: 40.0,
                seconds_of_day: 43_200,
            }),
        ),
        (
            "event",
            Pdu::Event(CompactEvent {
                vehicle: Some(3),
                event_no: 9,
                severity: 3,
                kind: 0,
                task_no: None,
                seconds_of_day: 43_200,
            }),
        ),
        (
            "announcement",
            Pdu::Announcement(CompactAnnouncement {
                vehicle: 3,
                kind: 0,
                links: 0b10,
                capabilities: 0b111,
                sensors: 0b11,
                max_speed_mps: 2.5,
                seconds_of_day: 43_200,
            }),
        ),
        (
            "environment_temperature",
            Pdu::Environment(CompactEnvironment {
                vehicle: 3,
                property: 0,
                seconds_of_day: 43_200,
                value: 13.25,
                latitude_deg: 43.1,
                longitude_deg: 5.9,
                depth_m: 12.5,
            }),
        ),
        (
            "ack",
            Pdu::Ack(Ack {
                from: 0,
                msg_id: id::STATE_KEYFRAME,
                ref_no: 1,
            }),
        ),
    ]
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod tests;
