//! MAVLink framing over UDP datagrams: finding frames, checking their CRC, and saying
//! exactly why a frame was dropped, so the adapter can count it.
//!
//! The `mavlink` crate's readers skip what they cannot use without a word (a v1 frame on
//! a v2 reader, a bad CRC, an unknown id); a proxy must count those, so frames are found
//! and checked here, and only the payload is handed to the crate's generated parser.
//! Both MAVLink 1 (`0xFE`) and MAVLink 2 (`0xFD`) frames are accepted; signed MAVLink 2
//! frames are accepted without checking the signature (the link is not signed).
//!
//! [`next`] is the parser of untrusted bytes (anyone who reaches the proxy's UDP port can
//! send them); the `mavlink_frame` fuzz target in `fuzz/` drives it, through [`wrap`] for
//! frames whose CRC is right.

use mavlink::Message;
use mavlink::dialects::ardupilotmega::MavMessage;
// The types a decoded frame carries, so users of this module (the fuzz target) need not
// depend on the `mavlink` crate themselves.
pub use mavlink::{MavHeader, MavlinkVersion};

/// MAVLink 1 start byte.
pub const STX_V1: u8 = 0xFE;
/// MAVLink 2 start byte.
pub const STX_V2: u8 = 0xFD;
/// MAVLink 2 incompatibility flag: the frame carries a 13-byte signature.
const IFLAG_SIGNED: u8 = 0x01;
const SIGNATURE_LEN: usize = 13;

/// One frame taken from a datagram.
#[derive(Debug)]
pub enum Frame {
    /// A frame with a valid CRC and a known message.
    Message {
        /// Sender and sequence.
        header: MavHeader,
        /// The message (boxed: the dialect's largest messages are hundreds of bytes).
        message: Box<MavMessage>,
        /// MAVLink 1 or 2.
        version: MavlinkVersion,
    },
    /// Bytes before the next start byte: not MAVLink.
    Garbage(usize),
    /// A frame cut short by the end of the datagram.
    Truncated,
    /// A known message whose CRC did not match.
    BadCrc(u32),
    /// A message id the ardupilotmega dialect does not define.
    UnknownMessage(u32),
    /// A frame whose payload does not parse (e.g. an enum value out of range), or whose
    /// incompatibility flags this proxy does not understand.
    Malformed(u32),
}

fn is_known(id: u32) -> bool {
    MavMessage::default_message_from_id(id).is_some()
}

/// The frame at the start of `bytes` (never empty) and how many bytes it took (at least 1).
pub fn next(bytes: &[u8]) -> (Frame, usize) {
    match bytes.first() {
        Some(&STX_V2) => v2(bytes),
        Some(&STX_V1) => v1(bytes),
        Some(_) => {
            let skip = bytes
                .iter()
                .position(|b| *b == STX_V1 || *b == STX_V2)
                .unwrap_or(bytes.len());
            (Frame::Garbage(skip), skip)
        }
        None => (Frame::Truncated, 0),
    }
}

/// After a bad frame, retry from the next byte: a start byte inside a corrupt frame may
/// begin a good one.
fn retry() -> usize {
    1
}

fn checked(
    bytes: &[u8],
    crc_end: usize,
    id: u32,
    header: MavHeader,
    payload: &[u8],
    version: MavlinkVersion,
    total: usize,
) -> (Frame, usize) {
    if !is_known(id) {
        // The length is trustworthy enough to skip: the CRC cannot be checked without the
        // message's CRC_EXTRA, and the frame is dropped anyway.
        return (Frame::UnknownMessage(id), total);
    }
    let received = u16::from_le_bytes([bytes[crc_end], bytes[crc_end + 1]]);
    let computed = mavlink::calculate_crc(&bytes[1..crc_end], MavMessage::extra_crc(id));
    if received != computed {
        return (Frame::BadCrc(id), retry());
    }
    match MavMessage::parse(version, id, payload) {
        Ok(message) => (
            Frame::Message {
                header,
                message: Box::new(message),
                version,
            },
            total,
        ),
        Err(_) => (Frame::Malformed(id), total),
    }
}

fn v2(bytes: &[u8]) -> (Frame, usize) {
    const HEADER: usize = 10;
    if bytes.len() < HEADER + 2 {
        return (Frame::Truncated, bytes.len());
    }
    let len = usize::from(bytes[1]);
    let incompat = bytes[2];
    let id = u32::from_le_bytes([bytes[7], bytes[8], bytes[9], 0]);
    if incompat & !IFLAG_SIGNED != 0 {
        // The spec: a frame with an unknown incompatibility flag must be dropped.
        return (Frame::Malformed(id), retry());
    }
    let crc_end = HEADER + len;
    let total = crc_end
        + 2
        + if incompat & IFLAG_SIGNED != 0 {
            SIGNATURE_LEN
        } else {
            0
        };
    if bytes.len() < total {
        return (Frame::Truncated, bytes.len());
    }
    let header = MavHeader {
        system_id: u32::from(bytes[5]),
        component_id: bytes[6],
        sequence: bytes[4],
    };
    checked(
        bytes,
        crc_end,
        id,
        header,
        &bytes[HEADER..crc_end],
        MavlinkVersion::V2,
        total,
    )
}

fn v1(bytes: &[u8]) -> (Frame, usize) {
    const HEADER: usize = 6;
    if bytes.len() < HEADER + 2 {
        return (Frame::Truncated, bytes.len());
    }
    let len = usize::from(bytes[1]);
    let id = u32::from(bytes[5]);
    let crc_end = HEADER + len;
    let total = crc_end + 2;
    if bytes.len() < total {
        return (Frame::Truncated, bytes.len());
    }
    let header = MavHeader {
        system_id: u32::from(bytes[3]),
        component_id: bytes[4],
        sequence: bytes[2],
    };
    checked(
        bytes,
        crc_end,
        id,
        header,
        &bytes[HEADER..crc_end],
        MavlinkVersion::V1,
        total,
    )
}

/// A MAVLink 2 frame for a message.
pub fn encode(
    header: MavHeader,
    message: &MavMessage,
) -> Result<Vec<u8>, mavlink::error::MessageWriteError> {
    let mut out = Vec::with_capacity(64);
    mavlink::write_v2_msg(&mut out, header, message)?;
    Ok(out)
}

/// A frame of message `id` around any `payload`, with the CRC the ardupilotmega dialect
/// expects for `id` (CRC_EXTRA 0 for an id it does not define), whether or not the payload
/// parses; unsigned, no incompatibility flags. `None` when the payload is longer than a
/// frame holds (255 bytes), or the system id or message id does not fit its field (a byte;
/// the id 24 bits in MAVLink 2, a byte in MAVLink 1).
///
/// Random bytes almost never pass the CRC check: tests and the fuzz target wrap them with
/// this to reach the payload parser behind it.
pub fn wrap(
    version: MavlinkVersion,
    header: MavHeader,
    id: u32,
    payload: &[u8],
) -> Option<Vec<u8>> {
    // The length is one byte.
    let len = u8::try_from(payload.len()).ok()?;
    let system_id = u8::try_from(header.system_id).ok()?;
    let mut out = Vec::with_capacity(payload.len() + 12);
    match version {
        MavlinkVersion::V2 => {
            let [i0, i1, i2, i3] = id.to_le_bytes();
            if i3 != 0 {
                return None;
            }
            out.extend_from_slice(&[
                STX_V2,
                len,
                0,
                0,
                header.sequence,
                system_id,
                header.component_id,
                i0,
                i1,
                i2,
            ]);
        }
        MavlinkVersion::V1 => {
            let id = u8::try_from(id).ok()?;
            out.extend_from_slice(&[
                STX_V1,
                len,
                header.sequence,
                system_id,
                header.component_id,
                id,
            ]);
        }
    }
    out.extend_from_slice(payload);
    let extra = if is_known(id) {
        MavMessage::extra_crc(id)
    } else {
        0
    };
    let crc = mavlink::calculate_crc(&out[1..], extra);
    out.extend_from_slice(&crc.to_le_bytes());
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use mavlink::dialects::ardupilotmega::{HEARTBEAT_DATA, MavType, VFR_HUD_DATA};
    use proptest::prelude::*;

    fn header() -> MavHeader {
        MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: 7,
        }
    }

    fn heartbeat() -> MavMessage {
        MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            mavtype: MavType::MAV_TYPE_SUBMARINE,
            ..HEARTBEAT_DATA::default()
        })
    }

    #[test]
    fn an_encoded_frame_decodes_to_itself() {
        let bytes = encode(header(), &heartbeat()).unwrap();
        assert_eq!(bytes[0], STX_V2);
        let (frame, used) = next(&bytes);
        assert_eq!(used, bytes.len());
        let Frame::Message {
            header: h,
            message,
            version,
        } = frame
        else {
            panic!("{frame:?}");
        };
        assert_eq!(h, header());
        assert_eq!(version, MavlinkVersion::V2);
        assert_eq!(message.message_id(), 0);
    }

    #[test]
    fn a_v1_frame_is_understood_too() {
        let mut out = Vec::new();
        mavlink::write_v1_msg(&mut out, header(), &heartbeat()).unwrap();
        let (frame, used) = next(&out);
        assert_eq!(used, out.len());
        assert!(
            matches!(
                frame,
                Frame::Message {
                    version: MavlinkVersion::V1,
                    ..
                }
            ),
            "{frame:?}"
        );
    }

    #[test]
    fn corruption_is_a_crc_error_and_the_scan_moves_on() {
        let mut bytes = encode(header(), &heartbeat()).unwrap();
        bytes[12] ^= 0x40;
        let (frame, used) = next(&bytes);
        assert!(matches!(frame, Frame::BadCrc(0)), "{frame:?}");
        assert_eq!(used, 1);
        let (frame, _) = next(&bytes[used..]);
        assert!(
            matches!(
                frame,
                Frame::Garbage(_) | Frame::BadCrc(_) | Frame::Truncated
            ),
            "{frame:?}"
        );
    }

    #[test]
    fn unknown_ids_and_unknown_flags_are_reported() {
        let mut bytes = encode(header(), &heartbeat()).unwrap();
        bytes[7] = 0x10; // id 0xEA10 + ...: not in the dialect
        bytes[8] = 0xEA;
        let (frame, used) = next(&bytes);
        assert!(matches!(frame, Frame::UnknownMessage(0xEA10)), "{frame:?}");
        assert_eq!(used, bytes.len());
        let mut bytes = encode(header(), &heartbeat()).unwrap();
        bytes[2] = 0x02;
        assert!(matches!(next(&bytes).0, Frame::Malformed(0)));
    }

    #[test]
    fn several_frames_in_one_datagram_are_all_found() {
        let mut bytes = b"junk".to_vec();
        bytes.extend(encode(header(), &heartbeat()).unwrap());
        bytes.extend(
            encode(
                header(),
                &MavMessage::VFR_HUD(VFR_HUD_DATA {
                    groundspeed: 1.25,
                    ..VFR_HUD_DATA::default()
                }),
            )
            .unwrap(),
        );
        let mut rest = &bytes[..];
        let mut kinds = Vec::new();
        while !rest.is_empty() {
            let (f, used) = next(rest);
            kinds.push(match f {
                Frame::Message { message, .. } => message.message_name(),
                Frame::Garbage(_) => "garbage",
                other => panic!("{other:?}"),
            });
            rest = &rest[used..];
        }
        assert_eq!(kinds, ["garbage", "HEARTBEAT", "VFR_HUD"]);
    }

    #[test]
    fn a_wrapped_payload_is_the_message_it_encodes() {
        let bytes = encode(header(), &heartbeat()).unwrap();
        let payload = &bytes[10..bytes.len() - 2];
        assert_eq!(
            wrap(MavlinkVersion::V2, header(), 0, payload).unwrap(),
            bytes
        );
        let mut v1 = Vec::new();
        mavlink::write_v1_msg(&mut v1, header(), &heartbeat()).unwrap();
        let wrapped = wrap(MavlinkVersion::V1, header(), 0, &v1[6..v1.len() - 2]).unwrap();
        assert_eq!(wrapped, v1);
        assert!(wrap(MavlinkVersion::V1, header(), 256, &[]).is_none());
        assert!(wrap(MavlinkVersion::V2, header(), 1 << 24, &[]).is_none());
        assert!(wrap(MavlinkVersion::V2, header(), 0, &[0; 256]).is_none());
    }

    /// What the fuzz target checks of every decoded message: it re-encodes, the frame
    /// decodes to the same header and message, and encoding that gives the same bytes.
    fn assert_round_trips(header: MavHeader, message: &MavMessage) {
        let once = encode(header, message).unwrap();
        let (again, used) = next(&once);
        assert_eq!(used, once.len());
        let Frame::Message {
            header: h,
            message: m,
            ..
        } = again
        else {
            panic!(
                "a re-encoded {} does not decode: {again:?}",
                message.message_name()
            );
        };
        assert_eq!(h, header);
        assert_eq!(encode(h, &m).unwrap(), once);
    }

    proptest! {
        /// Random payloads behind a valid CRC reach the dialect's parsers: whatever they
        /// make of them is a whole frame, and every message they accept round-trips.
        #[test]
        fn wrapped_arbitrary_payloads_parse_or_are_refused_whole(
            v1 in any::<bool>(),
            id in prop_oneof![0u32..256, 0u32..60_000],
            payload in prop::collection::vec(any::<u8>(), 0..=255),
        ) {
            let version = if v1 { MavlinkVersion::V1 } else { MavlinkVersion::V2 };
            let Some(bytes) = wrap(version, header(), id, &payload) else {
                return Ok(());
            };
            let (frame, used) = next(&bytes);
            prop_assert_eq!(used, bytes.len());
            match frame {
                Frame::Message { header: h, message, version: v } => {
                    prop_assert_eq!(v, version);
                    prop_assert_eq!(message.message_id(), id);
                    assert_round_trips(h, &message);
                }
                Frame::UnknownMessage(u) | Frame::Malformed(u) => prop_assert_eq!(u, id),
                other => prop_assert!(false, "{other:?}"),
            }
        }

        #[test]
        fn arbitrary_bytes_never_panic_and_always_advance(bytes in prop::collection::vec(any::<u8>(), 1..300)) {
            let mut rest = &bytes[..];
            while !rest.is_empty() {
                let (_, used) = next(rest);
                prop_assert!(used >= 1 && used <= rest.len());
                rest = &rest[used..];
            }
        }
    }
}
