//! The DCCL rule: bounded numeric fields packed MSB-first into a bit string
//! (docs/acoustic.md#compact-messages).
//!
//! A [`Field`] is `(name, min, max, resolution, optional)`. Its value `x` travels as the
//! integer `round((x - min) / resolution)` in `ceil(log2((max - min) / resolution + 1))`
//! bits; an optional field reserves one more code value (0 = absent, so present values are
//! shifted by one). No tags and no lengths: both ends know the schema.

use super::{DecodeError, EncodeError};

/// Appends fixed-width unsigned integers to a byte buffer, most significant bit first.
#[derive(Debug, Default, Clone)]
pub struct BitWriter {
    bytes: Vec<u8>,
    bit_len: usize,
}

impl BitWriter {
    /// An empty writer.
    pub fn new() -> Self {
        Self::default()
    }

    /// Appends the low `bits` bits of `value` (at most 64); higher bits are ignored.
    pub fn write(&mut self, value: u64, bits: u32) {
        for i in (0..bits.min(64)).rev() {
            let bit = (value >> i) & 1;
            if self.bit_len.is_multiple_of(8) {
                self.bytes.push(0);
            }
            if bit == 1
                && let Some(last) = self.bytes.last_mut()
            {
                *last |= 0x80 >> (self.bit_len % 8);
            }
            self.bit_len += 1;
        }
    }

    /// Number of bits written so far (before padding).
    pub fn bit_len(&self) -> usize {
        self.bit_len
    }

    /// The bytes, zero-padded to a whole byte as DCCL does (docs/acoustic.md#compact-messages).
    pub fn finish(self) -> Vec<u8> {
        self.bytes
    }
}

/// Reads fixed-width unsigned integers from a byte slice, most significant bit first.
#[derive(Debug, Clone)]
pub struct BitReader<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> BitReader<'a> {
    /// A reader positioned at the first bit of `bytes`.
    pub fn new(bytes: &'a [u8]) -> Self {
        Self { bytes, pos: 0 }
    }

    /// Reads `bits` bits (at most 64); [`DecodeError::Truncated`] if the input ends first.
    pub fn read(&mut self, bits: u32) -> Result<u64, DecodeError> {
        let bits = bits.min(64);
        let end = self.pos + bits as usize;
        if end > self.bytes.len() * 8 {
            return Err(DecodeError::Truncated {
                needed_bits: end,
                available_bits: self.bytes.len() * 8,
            });
        }
        let mut v = 0u64;
        for p in self.pos..end {
            let byte = self.bytes.get(p / 8).copied().unwrap_or(0);
            v = (v << 1) | u64::from((byte >> (7 - p % 8)) & 1);
        }
        self.pos = end;
        Ok(v)
    }

    /// Bits consumed so far.
    pub fn bit_pos(&self) -> usize {
        self.pos
    }

    /// Skips the padding to the next byte boundary; the padding must be zero bits, which
    /// catches most garbage cheaply. Returns the number of whole bytes consumed.
    pub fn align(&mut self) -> Result<usize, DecodeError> {
        let pad = (8 - self.pos % 8) % 8;
        // `pad` < 8, so the cast is exact.
        #[allow(clippy::cast_possible_truncation)]
        let v = self.read(pad as u32)?;
        if v != 0 {
            return Err(DecodeError::BadPadding);
        }
        Ok(self.pos / 8)
    }
}

/// Bits needed to tell `n` values apart: `ceil(log2(n))`, 0 for a single value.
pub fn bits_for_values(n: u64) -> u32 {
    if n <= 1 {
        0
    } else {
        64 - (n - 1).leading_zeros()
    }
}

/// One bounded numeric field of a compact message (the DCCL rule,
/// docs/acoustic.md#compact-messages).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Field {
    /// Field name, used in errors and docs.
    pub name: &'static str,
    /// Smallest encodable value.
    pub min: f64,
    /// Largest encodable value.
    pub max: f64,
    /// Quantisation step; decoded values are within half of it of the original.
    pub resolution: f64,
    /// Whether the field may be absent (costs one extra code value).
    pub optional: bool,
    /// Whether the field is an angle that wraps (e.g. yaw): values are reduced modulo
    /// `max - min + resolution` instead of being rejected as out of range.
    pub circular: bool,
}

impl Field {
    /// A required field with inclusive bounds `[min, max]` and step `resolution`.
    pub const fn new(name: &'static str, min: f64, max: f64, resolution: f64) -> Self {
        Self {
            name,
            min,
            max,
            resolution,
            optional: false,
            circular: false,
        }
    }

    /// The same field, but optional (code 0 means absent).
    pub const fn optional(self) -> Self {
        Self {
            optional: true,
            ..self
        }
    }

    /// The same field, but circular (wraps instead of going out of range).
    pub const fn circular(self) -> Self {
        Self {
            circular: true,
            ..self
        }
    }

    /// Largest code of a present value: `round((max - min) / resolution)`.
    pub fn max_code(&self) -> u64 {
        // Bounds are compile-time constants of this crate, small and positive.
        #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
        let c = ((self.max - self.min) / self.resolution).round().max(0.0) as u64;
        c
    }

    /// Width in bits: `ceil(log2((max - min) / resolution + 1 [+ 1 if optional]))`.
    pub fn bits(&self) -> u32 {
        bits_for_values(self.max_code() + 1 + u64::from(self.optional))
    }

    /// Quantises and writes `value`; `None` is only allowed for optional fields.
    pub fn encode(&self, w: &mut BitWriter, value: Option<f64>) -> Result<(), EncodeError> {
        let raw = match value {
            None if self.optional => 0,
            None => return Err(EncodeError::Missing { field: self.name }),
            Some(x) => self.code(x)? + u64::from(self.optional),
        };
        w.write(raw, self.bits());
        Ok(())
    }

    /// The code of a present value, checking range (or wrapping a circular field).
    fn code(&self, x: f64) -> Result<u64, EncodeError> {
        if !x.is_finite() {
            return Err(EncodeError::NotFinite { field: self.name });
        }
        let steps = ((x - self.min) / self.resolution).round();
        let n = self.max_code() + 1;
        #[allow(clippy::cast_precision_loss)]
        let n_f = n as f64;
        let steps = if self.circular {
            steps.rem_euclid(n_f)
        } else {
            steps
        };
        if steps < 0.0 || steps >= n_f {
            return Err(EncodeError::OutOfRange {
                field: self.name,
                value: x,
                min: self.min,
                max: self.max,
            });
        }
        // In [0, n) after the check above.
        #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
        Ok(steps as u64)
    }

    /// Reads a value; codes beyond `max` (possible when the range is not a power of two)
    /// are garbage and rejected.
    pub fn decode(&self, r: &mut BitReader<'_>) -> Result<Option<f64>, DecodeError> {
        let raw = r.read(self.bits())?;
        let code = if self.optional {
            match raw.checked_sub(1) {
                None => return Ok(None),
                Some(c) => c,
            }
        } else {
            raw
        };
        if code > self.max_code() {
            return Err(DecodeError::InvalidCode {
                field: self.name,
                code,
            });
        }
        Ok(Some(self.value_of(code)))
    }

    /// The decoded value of a code, computed so that decimal resolutions print cleanly
    /// (43.1, not 43.100000000000001).
    pub fn value_of(&self, code: u64) -> f64 {
        #[allow(clippy::cast_precision_loss)]
        let c = code as f64;
        let scale = (1.0 / self.resolution).round();
        if self.resolution < 1.0 && (scale * self.resolution - 1.0).abs() < 1e-9 {
            ((self.min * scale).round() + c) / scale
        } else {
            self.min + c * self.resolution
        }
    }

    /// Quantises a value as a round trip would, without encoding it.
    pub fn quantise(&self, x: f64) -> Result<f64, EncodeError> {
        self.code(x).map(|c| self.value_of(c))
    }
}

/// A declarative list of fields encoded in order; one block of a message.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Schema {
    /// Block name (message or part of one), for docs and the size table.
    pub name: &'static str,
    /// The fields, in wire order.
    pub fields: &'static [Field],
}

impl Schema {
    /// Total width of the block in bits.
    pub fn bits(&self) -> u32 {
        self.fields.iter().map(Field::bits).sum()
    }

    /// Writes `values` (one per field, in order).
    pub fn encode(&self, w: &mut BitWriter, values: &[Option<f64>]) -> Result<(), EncodeError> {
        if values.len() != self.fields.len() {
            return Err(EncodeError::Inconsistent {
                field: self.name,
                rule: "wrong number of values for schema",
            });
        }
        for (f, v) in self.fields.iter().zip(values) {
            f.encode(w, *v)?;
        }
        Ok(())
    }

    /// Reads one value per field, in order.
    pub fn decode(&self, r: &mut BitReader<'_>) -> Result<Vec<Option<f64>>, DecodeError> {
        self.fields.iter().map(|f| f.decode(r)).collect()
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod tests {
    use super::*;

    #[test]
    fn state_vector_reference_field_widths_match_acoustic_md() {
        // docs/acoustic.md#compact-messages: latitude ±90° at 1e-5 → 25 bits, longitude 26,
        // depth 16, altitude 14, ...
        let cases = [
            (Field::new("lat", -90.0, 90.0, 1e-5), 25),
            (Field::new("lon", -180.0, 180.0, 1e-5), 26),
            (Field::new("sod", 0.0, 86_399.0, 1.0), 17),
            (Field::new("depth", 0.0, 6000.0, 0.1), 16),
            (Field::new("alt", 0.0, 1000.0, 0.1), 14),
            (Field::new("speed", 0.0, 10.0, 0.05), 8),
            (Field::new("yaw", 0.0, 359.5, 0.5), 10),
            (Field::new("pitch", -90.0, 90.0, 0.5), 9),
            (Field::new("roll", -180.0, 180.0, 0.5), 10),
            (Field::new("battery", 0.0, 100.0, 1.0), 7),
            (Field::new("vehicle", 0.0, 15.0, 1.0), 4),
        ];
        for (f, bits) in cases {
            assert_eq!(f.bits(), bits, "{}", f.name);
        }
    }

    #[test]
    fn optional_adds_one_code_value() {
        // 0..15 has 16 values (4 bits); optional needs 17 → 5 bits.
        assert_eq!(Field::new("v", 0.0, 15.0, 1.0).optional().bits(), 5);
    }

    #[test]
    fn writer_and_reader_agree_across_byte_boundaries() {
        let mut w = BitWriter::new();
        w.write(0b101, 3);
        w.write(0x1_2345, 17);
        w.write(1, 1);
        assert_eq!(w.bit_len(), 21);
        let bytes = w.finish();
        assert_eq!(bytes.len(), 3);
        let mut r = BitReader::new(&bytes);
        assert_eq!(r.read(3).unwrap(), 0b101);
        assert_eq!(r.read(17).unwrap(), 0x1_2345);
        assert_eq!(r.read(1).unwrap(), 1);
        assert_eq!(r.align().unwrap(), 3);
        assert!(matches!(r.read(1), Err(DecodeError::Truncated { .. })));
    }

    #[test]
    fn circular_field_wraps_yaw_of_359_9_to_zero() {
        let yaw = Field::new("yaw", 0.0, 359.5, 0.5).circular();
        assert_eq!(yaw.quantise(359.9).unwrap(), 0.0);
        assert_eq!(yaw.quantise(-0.5).unwrap(), 359.5);
    }

    #[test]
    fn decimal_resolutions_decode_cleanly() {
        let lat = Field::new("lat", -90.0, 90.0, 1e-5);
        assert_eq!(lat.quantise(43.1).unwrap(), 43.1);
    }
}
