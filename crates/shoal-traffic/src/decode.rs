//! Field decoding through `nmea-parser`: a checked sentence or reassembled AIS payload in,
//! the facts the picture keeps out.
//!
//! Each call uses a fresh `NmeaParser`, because its own state is unbounded: it keeps
//! fragments and type 24 halves per key with no limit or time-out. Shoal reassembles
//! fragments itself (`framing::Reassembler`, bounded) and gives the parser whole
//! single-sentence messages; the two halves of a type 24 meet in the target table instead.

use std::panic::{AssertUnwindSafe, catch_unwind};

use nmea_parser::ais::{AisClass, VesselDynamicData, VesselStaticData};
use nmea_parser::gnss::GgaQualityIndicator;
use nmea_parser::{NmeaParser, ParseError, ParsedMessage};

use crate::framing::{AisPayload, sixbit_value};

/// AIS equipment class of a target.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum Class {
    /// Class A (types 1, 2, 3, 5).
    A,
    /// Class B (types 18, 19, 24).
    B,
}

/// Reference-point distances of a vessel's antenna, in metres (AIS dimensions).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Dimensions {
    /// Antenna to bow.
    pub to_bow: u16,
    /// Antenna to stern.
    pub to_stern: u16,
    /// Antenna to port side.
    pub to_port: u16,
    /// Antenna to starboard side.
    pub to_starboard: u16,
}

/// A position report (AIS types 1, 2, 3, 18, 19).
#[derive(Clone, Debug, PartialEq)]
pub struct PositionReport {
    /// From a VDO sentence: the own ship.
    pub own: bool,
    /// Maritime Mobile Service Identity.
    pub mmsi: u32,
    /// Equipment class.
    pub class: Class,
    /// Message type (1, 2, 3, 18, 19).
    pub msg_type: u8,
    /// Latitude and longitude in degrees, if available and in range.
    pub position: Option<(f64, f64)>,
    /// Course over ground, degrees true.
    pub cog_deg: Option<f64>,
    /// Speed over ground, knots.
    pub sog_kn: Option<f64>,
    /// True heading, degrees.
    pub heading_deg: Option<f64>,
    /// Navigational status code (class A only).
    pub nav_status: Option<u8>,
}

/// Static data (AIS types 5, 19, 24 part A or B); absent fields were not in the message.
#[derive(Clone, Debug, PartialEq)]
pub struct StaticReport {
    /// From a VDO sentence: the own ship.
    pub own: bool,
    /// Maritime Mobile Service Identity.
    pub mmsi: u32,
    /// Equipment class.
    pub class: Class,
    /// Vessel name.
    pub name: Option<String>,
    /// Radio call sign.
    pub call_sign: Option<String>,
    /// IMO number.
    pub imo: Option<u32>,
    /// Ship type category code (`nmea-parser` keeps the category: 60 for 60..=69, etc.).
    pub ship_type: Option<u8>,
    /// Its text.
    pub ship_type_text: Option<String>,
    /// Dimensions, if given and not all zero.
    pub dimensions: Option<Dimensions>,
}

/// What one sentence or AIS message says.
#[derive(Clone, Debug, PartialEq)]
pub enum Fact {
    /// An AIS position report.
    Position(PositionReport),
    /// AIS static data.
    Static(StaticReport),
    /// Own-ship position from GGA (with a fix).
    Gga {
        /// Latitude, degrees.
        lat: f64,
        /// Longitude, degrees.
        lon: f64,
    },
    /// Own-ship position, course and speed from RMC (status active).
    Rmc {
        /// Latitude and longitude, degrees.
        position: Option<(f64, f64)>,
        /// Speed over ground, knots.
        sog_kn: Option<f64>,
        /// Course over ground, degrees true.
        cog_deg: Option<f64>,
    },
    /// Own-ship true heading from HDT.
    Hdt {
        /// Heading, degrees true.
        heading_deg: f64,
    },
}

/// Why a well-framed sentence yielded nothing.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    /// An AIS message type the picture does not read.
    #[error("AIS message type {0} is not read")]
    UnsupportedAisType(u8),
    /// The payload is shorter than its message type needs.
    #[error("AIS payload too short for its type")]
    ShortPayload,
    /// The decoder refused a field (or a type 24 part number).
    #[error("a field is malformed")]
    BadFields,
    /// MMSI 0 or out of range.
    #[error("invalid MMSI")]
    BadMmsi,
    /// GGA without a fix or RMC with status void: nothing to take.
    #[error("no valid fix")]
    NoFix,
    /// The decoder panicked on this input (a bug there; the sentence is dropped).
    #[error("decoder panicked")]
    DecoderPanic,
}

/// Runs the decoder on one complete sentence with a fresh parser, containing any panic.
fn parse(sentence: &str) -> Result<ParsedMessage, DecodeError> {
    let result = catch_unwind(AssertUnwindSafe(|| {
        NmeaParser::new().parse_sentence(sentence)
    }));
    match result {
        Ok(Ok(m)) => Ok(m),
        Ok(Err(ParseError::UnsupportedSentenceType(_))) => Err(DecodeError::BadFields),
        Ok(Err(_)) => Err(DecodeError::BadFields),
        Err(_) => Err(DecodeError::DecoderPanic),
    }
}

/// Minimum payload bits per message type: the fields read must be present (the decoder
/// reads missing bits as zeros).
fn min_bits(msg_type: u8) -> Option<usize> {
    match msg_type {
        1..=3 | 18 => Some(168),
        5 => Some(420),
        19 => Some(312),
        24 => Some(160),
        _ => None,
    }
}

fn valid_position(lat: Option<f64>, lon: Option<f64>) -> Option<(f64, f64)> {
    match (lat, lon) {
        (Some(lat), Some(lon))
            if lat.is_finite()
                && lon.is_finite()
                && (-90.0..=90.0).contains(&lat)
                && (-180.0..=180.0).contains(&lon) =>
        {
            Some((lat, lon))
        }
        _ => None,
    }
}

fn check_mmsi(mmsi: u32) -> Result<u32, DecodeError> {
    if mmsi == 0 || mmsi > 999_999_999 {
        Err(DecodeError::BadMmsi)
    } else {
        Ok(mmsi)
    }
}

/// Decodes a reassembled AIS message: one fact, or two for type 19 (position and static).
pub fn decode_ais(p: &AisPayload) -> Result<Vec<Fact>, DecodeError> {
    let first = *p
        .payload
        .as_bytes()
        .first()
        .ok_or(DecodeError::ShortPayload)?;
    let msg_type = sixbit_value(first);
    let need = min_bits(msg_type).ok_or(DecodeError::UnsupportedAisType(msg_type))?;
    let bits = (p.payload.len() * 6).saturating_sub(usize::from(p.fill));
    if bits < need {
        return Err(DecodeError::ShortPayload);
    }
    let talker = if p.own { "AIVDO" } else { "AIVDM" };
    let sentence = |payload: &str| format!("!{talker},1,1,,A,{payload},{}", p.fill);
    match msg_type {
        19 => decode_type19(p, &sentence),
        24 => {
            // A fresh parser holds the first half it sees and merges it with the next: the
            // same half given twice comes back alone (see the module comment).
            let s = sentence(&p.payload);
            let mut parser = NmeaParser::new();
            let once = catch_unwind(AssertUnwindSafe(|| {
                let _ = parser.parse_sentence(&s);
                parser.parse_sentence(&s)
            }));
            match once {
                Ok(Ok(ParsedMessage::VesselStaticData(v))) => {
                    Ok(vec![Fact::Static(static_report(&v, Class::B)?)])
                }
                Ok(_) => Err(DecodeError::BadFields),
                Err(_) => Err(DecodeError::DecoderPanic),
            }
        }
        _ => match parse(&sentence(&p.payload))? {
            ParsedMessage::VesselDynamicData(v) => {
                Ok(vec![Fact::Position(position_report(&v, msg_type)?)])
            }
            ParsedMessage::VesselStaticData(v) => {
                Ok(vec![Fact::Static(static_report(&v, Class::A)?)])
            }
            _ => Err(DecodeError::BadFields),
        },
    }
}

/// Type 19 (extended class B report): `nmea-parser` 0.11 does not implement it. Its first
/// 143 bits are laid out as type 18's, so the crate decodes them with the type field
/// rewritten to 18; name, ship type and dimensions follow at fixed offsets and are read
/// here (ITU-R M.1371-5, table 50).
fn decode_type19(
    p: &AisPayload,
    sentence: &dyn Fn(&str) -> String,
) -> Result<Vec<Fact>, DecodeError> {
    // '@' never occurs in armouring, but 'B' encodes 18.
    let as18 = format!("B{}", p.payload.get(1..).unwrap_or(""));
    let mut pos = match parse(&sentence(&as18))? {
        ParsedMessage::VesselDynamicData(v) => position_report(&v, 19)?,
        _ => return Err(DecodeError::BadFields),
    };
    pos.class = Class::B;
    let bits = SixBits(p.payload.as_bytes());
    let name = bits.text(143, 20);
    let ship_type = bits.uint(263, 8) as u8;
    let dims = Dimensions {
        to_bow: bits.uint(271, 9) as u16,
        to_stern: bits.uint(280, 9) as u16,
        to_port: bits.uint(289, 6) as u16,
        to_starboard: bits.uint(295, 6) as u16,
    };
    let kind = nmea_parser::ais::ShipType::new(ship_type);
    let stat = StaticReport {
        own: p.own,
        mmsi: pos.mmsi,
        class: Class::B,
        name: (!name.is_empty()).then_some(name),
        call_sign: None,
        imo: None,
        ship_type: (kind.to_value() != 0).then(|| kind.to_value()),
        ship_type_text: (kind.to_value() != 0).then(|| kind.to_string()),
        dimensions: nonzero(dims),
    };
    Ok(vec![Fact::Position(pos), Fact::Static(stat)])
}

/// Reads big-endian fields of an armoured payload (missing bits read as zero).
struct SixBits<'a>(&'a [u8]);

impl SixBits<'_> {
    fn bit(&self, i: usize) -> u64 {
        self.0
            .get(i / 6)
            .map_or(0, |c| u64::from((sixbit_value(*c) >> (5 - i % 6)) & 1))
    }

    fn uint(&self, start: usize, len: usize) -> u64 {
        (start..start + len).fold(0, |acc, i| (acc << 1) | self.bit(i))
    }

    /// AIS six-bit text: `@` (0) ends it, trailing spaces are padding.
    fn text(&self, start: usize, chars: usize) -> String {
        let mut s = String::with_capacity(chars);
        for i in 0..chars {
            let v = self.uint(start + i * 6, 6) as u8;
            if v == 0 {
                break;
            }
            s.push(char::from(if v < 32 { v + 64 } else { v }));
        }
        s.trim_end().to_string()
    }
}

fn nonzero(d: Dimensions) -> Option<Dimensions> {
    (d.to_bow != 0 || d.to_stern != 0 || d.to_port != 0 || d.to_starboard != 0).then_some(d)
}

fn position_report(v: &VesselDynamicData, msg_type: u8) -> Result<PositionReport, DecodeError> {
    let class = if v.ais_type == AisClass::ClassA {
        Class::A
    } else {
        Class::B
    };
    Ok(PositionReport {
        own: v.own_vessel,
        mmsi: check_mmsi(v.mmsi)?,
        class,
        msg_type,
        position: valid_position(v.latitude, v.longitude),
        cog_deg: v.cog.filter(|c| (0.0..360.0).contains(c)),
        sog_kn: v.sog_knots.filter(|s| s.is_finite() && *s >= 0.0),
        heading_deg: v.heading_true.filter(|h| (0.0..360.0).contains(h)),
        nav_status: (class == Class::A).then(|| v.nav_status.to_value()),
    })
}

fn static_report(v: &VesselStaticData, class: Class) -> Result<StaticReport, DecodeError> {
    let dims = match (
        v.dimension_to_bow,
        v.dimension_to_stern,
        v.dimension_to_port,
        v.dimension_to_starboard,
    ) {
        (Some(to_bow), Some(to_stern), Some(to_port), Some(to_starboard)) => nonzero(Dimensions {
            to_bow,
            to_stern,
            to_port,
            to_starboard,
        }),
        _ => None,
    };
    let ship_type = v.ship_type.to_value();
    Ok(StaticReport {
        own: v.own_vessel,
        mmsi: check_mmsi(v.mmsi)?,
        class,
        name: v.name.clone(),
        call_sign: v.call_sign.clone(),
        imo: v.imo_number,
        ship_type: (ship_type != 0).then_some(ship_type),
        ship_type_text: (ship_type != 0).then(|| v.ship_type.to_string()),
        dimensions: dims,
    })
}

/// Decodes a checked `$--GGA`, `$--RMC` or `$--HDT` sentence body (talker ignored).
pub fn decode_nav(body: &str) -> Result<Fact, DecodeError> {
    // Normalise the talker: the crate tells some apart by it, Shoal reads any.
    let rest = body.get(2..).ok_or(DecodeError::BadFields)?;
    match parse(&format!("$GP{rest}"))? {
        ParsedMessage::Gga(g) => {
            if g.quality == GgaQualityIndicator::Invalid {
                return Err(DecodeError::NoFix);
            }
            let (lat, lon) = valid_position(g.latitude, g.longitude).ok_or(DecodeError::NoFix)?;
            Ok(Fact::Gga { lat, lon })
        }
        ParsedMessage::Rmc(r) => {
            if r.status_active != Some(true) {
                return Err(DecodeError::NoFix);
            }
            Ok(Fact::Rmc {
                position: valid_position(r.latitude, r.longitude),
                sog_kn: r.sog_knots.filter(|s| s.is_finite() && *s >= 0.0),
                cog_deg: r.bearing.filter(|c| (0.0..360.0).contains(c)),
            })
        }
        ParsedMessage::Hdt(h) => match h.heading_true {
            Some(hd) if (0.0..360.0).contains(&hd) => Ok(Fact::Hdt { heading_deg: hd }),
            _ => Err(DecodeError::BadFields),
        },
        _ => Err(DecodeError::BadFields),
    }
}
