//! Predictive State Vector deltas: delta layout 2, message id [`id::PREDICTED_DELTA`]
//! (docs/acoustic.md#predicted-deltas).
//!
//! Both ends run the same dead-reckoning predictor ([`predict`]) from the keyframe the
//! receiver acknowledged — the only state both provably share, since deltas are never acknowledged —
//! and the PDU carries only the quantised residuals between the real state and the
//! prediction, each as a zigzag-mapped exp-Golomb code, so a residual of zero costs one
//! bit. Every field is carried at the precision of the layout-1 [`StateDelta`]
//! (the [`RESIDUALS`] table), so the two layouts are compared at equal precision.
//!
//! The layout does not depend on the keyframe: a frame of PDUs splits without it, and a
//! receiver that lacks the keyframe refuses the delta instead of guessing.

use serde::{Deserialize, Serialize};
use shoal_model::geo::{EARTH_RADIUS_M, angle_diff};

use super::messages::{StateKeyframe, id};
use super::schema::{BitReader, BitWriter};
use super::{DecodeError, EncodeError};

/// Bits of the fixed header after the message id: vehicle 4, keyframe seq 4, dt 7.
const HEADER_BITS: [u32; 3] = [4, 4, 7];

/// Largest `dt_s` (7 bits), as in layout 1.
pub const MAX_DT_S: u32 = 127;

/// Pitch beyond which the predictor extrapolates depth along it. Below it the vehicle is
/// taken to hold depth: trim and wave-induced pitch of a few degrees do not mean a depth
/// change, and extrapolating them over a minute would cost more bits than it saves.
pub const DIVE_PITCH_DEG: f64 = 5.0;

/// Steepest pitch the predictor extrapolates along (tan grows without bound near 90°).
const MAX_PREDICTED_PITCH_DEG: f64 = 45.0;

/// One residual field: its quantisation step, the largest residual it carries (in steps)
/// and its exp-Golomb order.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Residual {
    /// Field name, used in errors and docs.
    pub name: &'static str,
    /// Quantisation step in the field's unit; the decoded value is within half of it.
    pub step: f64,
    /// Largest |residual| in steps; a larger one is not encodable (the encoder falls back).
    pub max_steps: i32,
    /// Exp-Golomb order k: values below 2^k cost k + 1 bits.
    pub order: u32,
    /// Whether the field may be absent (altitude): code 1 then means absent.
    pub optional: bool,
}

impl Residual {
    const fn new(name: &'static str, step: f64, max_steps: i32, order: u32) -> Self {
        Self {
            name,
            step,
            max_steps,
            order,
            optional: false,
        }
    }

    /// Largest code value: zigzag of ±`max_steps`, plus one for the absent code.
    fn max_code(&self) -> u64 {
        let m = u64::from(self.max_steps.unsigned_abs());
        2 * m + u64::from(self.optional)
    }

    /// Most leading zeros a valid code of this field has; more is an overlong code.
    fn max_zeros(&self) -> u32 {
        63 - ((self.max_code() >> self.order) + 1).leading_zeros()
    }

    fn check(&self, r: i32) -> Result<(), EncodeError> {
        if r.unsigned_abs() > self.max_steps.unsigned_abs() {
            return Err(EncodeError::OutOfRange {
                field: self.name,
                value: f64::from(r),
                min: -f64::from(self.max_steps),
                max: f64::from(self.max_steps),
            });
        }
        Ok(())
    }
}

/// The residual fields in wire order, at the layout-1 delta's precision:
/// latitude and longitude 2e-5° (≈ 2.2 m north), depth 0.1 m, altitude 0.2 m, speed
/// 0.25 m/s, yaw 3°, pitch and roll 2°, battery 1 %.
pub const RESIDUALS: [Residual; 9] = [
    // ±4095 steps ≈ ±9 km: beyond any miss of dead reckoning over 127 s at 10 m/s.
    Residual::new("lat_steps", 2e-5, 4095, 0),
    Residual::new("lon_steps", 2e-5, 4095, 0),
    Residual::new("depth_steps", 0.1, 1270, 0),
    Residual {
        optional: true,
        ..Residual::new("altitude_steps", 0.2, 1000, 0)
    },
    Residual::new("speed_steps", 0.25, 40, 0),
    // ±60 steps of 3° is the whole circle.
    Residual::new("yaw_steps", 3.0, 60, 0),
    Residual::new("pitch_steps", 2.0, 90, 0),
    Residual::new("roll_steps", 2.0, 180, 0),
    Residual::new("battery_steps", 1.0, 100, 0),
];

/// Indices into [`RESIDUALS`].
const LAT: usize = 0;
const LON: usize = 1;
const DEPTH: usize = 2;
const ALT: usize = 3;
const SPEED: usize = 4;
const YAW: usize = 5;
const PITCH: usize = 6;
const ROLL: usize = 7;
const BATTERY: usize = 8;

/// Writes `u` as an exp-Golomb code of order `k`: `q = (u >> k) + 1` as Elias-gamma
/// (`floor(log2 q)` zeros, then `q` in binary), then the low `k` bits of `u`.
fn write_exp_golomb(w: &mut BitWriter, u: u64, k: u32) {
    let q = (u >> k) + 1;
    let n = 63 - q.leading_zeros();
    w.write(0, n);
    w.write(q, n + 1);
    w.write(u, k);
}

/// Reads an exp-Golomb code of order `k` of field `f`; refuses a code with more leading
/// zeros than the field's largest value needs (overlong) or a value above it.
fn read_exp_golomb(r: &mut BitReader<'_>, f: &Residual) -> Result<u64, DecodeError> {
    let mut zeros = 0u32;
    while r.read(1)? == 0 {
        zeros += 1;
        if zeros > f.max_zeros() {
            return Err(DecodeError::Overlong { field: f.name });
        }
    }
    // The leading 1 was just read; `zeros` ≤ 63 by the check above.
    let q = (1u64 << zeros) | r.read(zeros)?;
    let u = ((q - 1) << f.order) | r.read(f.order)?;
    if u > f.max_code() {
        return Err(DecodeError::InvalidCode {
            field: f.name,
            code: u,
        });
    }
    Ok(u)
}

/// Zigzag map: 0, -1, 1, -2, 2, ... → 0, 1, 2, 3, 4, ... so small magnitudes get short codes.
fn zigzag(r: i32) -> u64 {
    u64::from(((r << 1) ^ (r >> 31)).cast_unsigned())
}

fn unzigzag(u: u64) -> i32 {
    // Callers bound `u` by a field's max_code (< 2^14), so it fits in u32.
    let v = u32::try_from(u).unwrap_or(u32::MAX);
    (v >> 1).cast_signed() ^ -((v & 1).cast_signed())
}

/// What the receiver predicts from keyframe `key` `dt_s` seconds later: the position advanced
/// along the keyframe's yaw at its speed, depth extrapolated along its pitch when it is
/// diving or climbing (beyond [`DIVE_PITCH_DEG`]), everything else held.
///
/// The decoder adds residuals to this prediction without rounding it, so a last-bit
/// difference between platforms' `sin`/`cos` (the vehicle's aarch64 vs the station's
/// x86_64) moves a decoded value by a last bit, never by a quantisation step.
pub fn predict(key: &StateKeyframe, dt_s: u32) -> StateKeyframe {
    let dt = f64::from(dt_s);
    let d = key.speed_mps * dt;
    let yaw = key.yaw_deg.to_radians();
    let lat = key.latitude_deg;
    let north = d * yaw.cos();
    let east = d * yaw.sin();
    let latitude_deg = lat + (north / EARTH_RADIUS_M).to_degrees();
    let longitude_deg = key.longitude_deg
        + (east / (EARTH_RADIUS_M * lat.to_radians().cos().max(1e-6))).to_degrees();
    // The simulator (and a flying AUV) pitches nose down (negative) into a dive, with
    // speed the horizontal component: depth rate = -speed · tan(pitch).
    let depth_m = if key.pitch_deg.abs() >= DIVE_PITCH_DEG {
        let pitch = key
            .pitch_deg
            .clamp(-MAX_PREDICTED_PITCH_DEG, MAX_PREDICTED_PITCH_DEG)
            .to_radians();
        (key.depth_m - d * pitch.tan()).max(0.0)
    } else {
        key.depth_m
    };
    StateKeyframe {
        // Reduced first, so a caller's out-of-range keyframe cannot overflow the sum.
        seconds_of_day: (key.seconds_of_day % 86_400 + dt_s % 86_400) % 86_400,
        latitude_deg,
        longitude_deg,
        depth_m,
        ..key.clone()
    }
}

/// Altitude the receiver predicts once it knows the depth: the seabed under the keyframe
/// held (altitude + depth constant), never below zero.
fn predict_altitude(key_alt: f64, key: &StateKeyframe, depth_m: f64) -> f64 {
    (key_alt - (depth_m - key.depth_m)).max(0.0)
}

/// A State Vector coded as residuals from the dead-reckoning prediction of keyframe
/// `keyframe_seq` (delta layout 2, docs/acoustic.md#predicted-deltas). Residuals are in
/// steps of the [`RESIDUALS`] table.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PredictedDelta {
    /// Acoustic address of the vehicle, 0..=15.
    pub vehicle: u8,
    /// Sequence number of the reference keyframe, 0..=15.
    pub keyframe_seq: u8,
    /// Seconds since the keyframe's fix, 0..=127.
    pub dt_s: u32,
    /// Latitude residual, steps of 2e-5°.
    pub lat_steps: i32,
    /// Longitude residual, steps of 2e-5°.
    pub lon_steps: i32,
    /// Depth residual, steps of 0.1 m.
    pub depth_steps: i32,
    /// Altitude residual, steps of 0.2 m; `None` when altitude is now unknown. `Some(0)`
    /// against a keyframe without altitude means still unknown.
    pub altitude_steps: Option<i32>,
    /// Speed residual, steps of 0.25 m/s.
    pub speed_steps: i32,
    /// Yaw residual, steps of 3° (wraps).
    pub yaw_steps: i32,
    /// Pitch residual, steps of 2°.
    pub pitch_steps: i32,
    /// Roll residual, steps of 2°.
    pub roll_steps: i32,
    /// Battery residual, steps of 1 %.
    pub battery_steps: i32,
}

impl PredictedDelta {
    fn residuals(&self) -> [i32; 9] {
        [
            self.lat_steps,
            self.lon_steps,
            self.depth_steps,
            self.altitude_steps.unwrap_or(0),
            self.speed_steps,
            self.yaw_steps,
            self.pitch_steps,
            self.roll_steps,
            self.battery_steps,
        ]
    }

    /// Writes the fields after the message id.
    pub(super) fn write(&self, w: &mut BitWriter) -> Result<(), EncodeError> {
        let header = [
            ("vehicle", u32::from(self.vehicle), 15),
            ("keyframe_seq", u32::from(self.keyframe_seq), 15),
            ("dt_s", self.dt_s, MAX_DT_S),
        ];
        for ((name, v, max), bits) in header.into_iter().zip(HEADER_BITS) {
            if v > max {
                return Err(EncodeError::OutOfRange {
                    field: name,
                    value: f64::from(v),
                    min: 0.0,
                    max: f64::from(max),
                });
            }
            w.write(u64::from(v), bits);
        }
        for (f, r) in RESIDUALS.iter().zip(self.residuals()) {
            f.check(r)?;
        }
        for (i, (f, r)) in RESIDUALS.iter().zip(self.residuals()).enumerate() {
            // Altitude: 0 = as predicted, 1 = absent, then the other residuals shifted by
            // one, so the common "as predicted" stays a single bit.
            let u = match (i == ALT, self.altitude_steps) {
                (true, None) => 1,
                (true, Some(0)) => 0,
                (true, Some(a)) => zigzag(a) + 1,
                (false, _) => zigzag(r),
            };
            write_exp_golomb(w, u, f.order);
        }
        Ok(())
    }

    /// Reads the fields after the message id; refuses truncated, overlong and out-of-range
    /// codes.
    pub(super) fn read(r: &mut BitReader<'_>) -> Result<Self, DecodeError> {
        let mut header = [0u64; 3];
        for (h, bits) in header.iter_mut().zip(HEADER_BITS) {
            *h = r.read(bits)?;
        }
        let [vehicle, seq, dt] = header;
        let mut v = [0i32; 9];
        let mut altitude_absent = false;
        for (i, (slot, f)) in v.iter_mut().zip(&RESIDUALS).enumerate() {
            let u = read_exp_golomb(r, f)?;
            *slot = if i == ALT {
                match u {
                    0 => 0,
                    1 => {
                        altitude_absent = true;
                        0
                    }
                    _ => unzigzag(u - 1),
                }
            } else {
                unzigzag(u)
            };
        }
        let [lat, lon, depth, alt, speed, yaw, pitch, roll, battery] = v;
        // Header widths are 4, 4 and 7 bits, so these conversions cannot fail.
        Ok(Self {
            vehicle: u8::try_from(vehicle).unwrap_or(u8::MAX),
            keyframe_seq: u8::try_from(seq).unwrap_or(u8::MAX),
            dt_s: u32::try_from(dt).unwrap_or(u32::MAX),
            lat_steps: lat,
            lon_steps: lon,
            depth_steps: depth,
            altitude_steps: (!altitude_absent).then_some(alt),
            speed_steps: speed,
            yaw_steps: yaw,
            pitch_steps: pitch,
            roll_steps: roll,
            battery_steps: battery,
        })
    }

    /// Significant bits of this PDU, message id included.
    pub fn bits(&self) -> Result<usize, EncodeError> {
        let mut w = BitWriter::new();
        w.write(u64::from(id::PREDICTED_DELTA), 8);
        self.write(&mut w)?;
        Ok(w.bit_len())
    }

    /// The predicted delta from `key` to `state`, or `None` when `state` cannot be coded
    /// against `key` (another vehicle, more than [`MAX_DT_S`] later, altitude became
    /// known, a residual beyond its field's range): then the old delta or a keyframe is due.
    pub fn between(key: &StateKeyframe, state: &StateKeyframe) -> Option<Self> {
        if key.vehicle != state.vehicle {
            return None;
        }
        let dt_s = u32::try_from(
            (i64::from(state.seconds_of_day) - i64::from(key.seconds_of_day)).rem_euclid(86_400),
        )
        .ok()?;
        if dt_s > MAX_DT_S {
            return None;
        }
        let p = predict(key, dt_s);
        let steps = |x: f64, pred: f64, i: usize| -> Option<i32> {
            let f = RESIDUALS.get(i)?;
            let s = ((x - pred) / f.step).round();
            if s.is_nan() || s.abs() > f64::from(f.max_steps) {
                return None;
            }
            // |s| ≤ max_steps < 2^31 after the check.
            #[allow(clippy::cast_possible_truncation)]
            Some(s as i32)
        };
        // Depth first: the altitude prediction uses the depth the receiver will decode.
        let depth_steps = steps(state.depth_m, p.depth_m, DEPTH)?;
        let depth = decoded_depth(&p, depth_steps);
        let altitude_steps = match (key.altitude_m, state.altitude_m) {
            (Some(ka), Some(a)) => Some(steps(a, predict_altitude(ka, key, depth), ALT)?),
            (None, None) => Some(0),
            (_, None) => None,
            (None, Some(_)) => return None,
        };
        let d = Self {
            vehicle: state.vehicle,
            keyframe_seq: key.seq,
            dt_s,
            lat_steps: steps(state.latitude_deg, p.latitude_deg, LAT)?,
            lon_steps: steps(angle_diff(state.longitude_deg, p.longitude_deg), 0.0, LON)?,
            depth_steps,
            altitude_steps,
            speed_steps: steps(state.speed_mps, p.speed_mps, SPEED)?,
            yaw_steps: steps(angle_diff(state.yaw_deg, p.yaw_deg), 0.0, YAW)?,
            pitch_steps: steps(state.pitch_deg, p.pitch_deg, PITCH)?,
            roll_steps: steps(angle_diff(state.roll_deg, p.roll_deg), 0.0, ROLL)?,
            battery_steps: steps(state.battery_pct, p.battery_pct, BATTERY)?,
        };
        // The encoder is the final range check (header fields included).
        d.bits().ok()?;
        Some(d)
    }

    /// The full state this delta describes relative to `key`, which must be keyframe
    /// `keyframe_seq` of the same vehicle. Refuses (never guesses) a delta for another
    /// vehicle or keyframe, or one whose altitude contradicts the keyframe's.
    pub fn apply(&self, key: &StateKeyframe) -> Result<StateKeyframe, DecodeError> {
        if key.vehicle != self.vehicle || key.seq != self.keyframe_seq {
            return Err(DecodeError::UnknownKeyframe {
                vehicle: self.vehicle,
                seq: self.keyframe_seq,
            });
        }
        let p = predict(key, self.dt_s);
        let step = |i: usize| RESIDUALS.get(i).map_or(0.0, |f| f.step);
        let add = |pred: f64, r: i32, i: usize| pred + f64::from(r) * step(i);
        // Re-rounding removes float noise from the additions only. It must stay far below
        // every field's half step, or it could push a value past the precision the layout
        // promises (a millimetre did, by 0.3 mm, on a depth a proptest found).
        let clean = |x: f64, q: f64| (x / q).round() * q;
        let depth_m = decoded_depth(&p, self.depth_steps);
        let altitude_m = match (key.altitude_m, self.altitude_steps) {
            (Some(ka), Some(r)) => Some(clean(
                add(predict_altitude(ka, key, depth_m), r, ALT).max(0.0),
                NOISE,
            )),
            (None, Some(0)) | (_, None) => None,
            (None, Some(_)) => {
                return Err(DecodeError::Inconsistent {
                    rule: "altitude residual against a keyframe without altitude",
                });
            }
        };
        let lon = add(p.longitude_deg, self.lon_steps, LON);
        Ok(StateKeyframe {
            vehicle: self.vehicle,
            seq: key.seq,
            seconds_of_day: p.seconds_of_day,
            latitude_deg: clean(add(p.latitude_deg, self.lat_steps, LAT), 1e-9).clamp(-90.0, 90.0),
            // Wraps across the antimeridian, as a longitude does.
            longitude_deg: clean((lon + 180.0).rem_euclid(360.0) - 180.0, 1e-9),
            depth_m,
            altitude_m,
            // Clamping to a physical bound the real value also respects can only shrink
            // the error.
            speed_mps: clean(add(p.speed_mps, self.speed_steps, SPEED), NOISE).clamp(0.0, 10.0),
            yaw_deg: clean(add(p.yaw_deg, self.yaw_steps, YAW).rem_euclid(360.0), NOISE) % 360.0,
            pitch_deg: clean(add(p.pitch_deg, self.pitch_steps, PITCH), NOISE).clamp(-90.0, 90.0),
            roll_deg: clean(
                (add(p.roll_deg, self.roll_steps, ROLL) + 180.0).rem_euclid(360.0) - 180.0,
                NOISE,
            ),
            battery_pct: add(p.battery_pct, self.battery_steps, BATTERY).clamp(0.0, 100.0),
        })
    }
}

/// Depth the receiver decodes: prediction plus residual, never above the surface.
/// The grain decoded values are re-rounded to, to remove float noise: far below every
/// field's half step (the coarsest error the layout allows).
const NOISE: f64 = 1e-9;

fn decoded_depth(p: &StateKeyframe, r: i32) -> f64 {
    let step = RESIDUALS.get(DEPTH).map_or(0.0, |f| f.step);
    (((p.depth_m + f64::from(r) * step) / NOISE).round() * NOISE).max(0.0)
}
