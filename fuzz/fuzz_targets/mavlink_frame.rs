//! Fuzzes Shoal's MAVLink frame parser (`shoal_proxy::mavlink::frame`), which reads the UDP
//! datagrams anyone who reaches the proxy's port can send: arbitrary bytes must never
//! panic, each frame must take at least one byte and no more than are left, and every
//! message that decodes must re-encode to a frame that decodes to the same header and to
//! the same bytes again.
//!
//! Random bytes almost never carry a valid CRC, so each input is also wrapped as the
//! payload of a well-formed frame: that drives the dialect's payload parsers.
#![no_main]

use libfuzzer_sys::fuzz_target;
use shoal_proxy::mavlink::frame::{self, Frame, MavHeader, MavlinkVersion};

/// Reads a datagram the way the adapter does: frame after frame until it is used up.
fn walk(data: &[u8]) {
    let mut rest = data;
    while !rest.is_empty() {
        let (found, used) = frame::next(rest);
        assert!(
            (1..=rest.len()).contains(&used),
            "took {used} of {} bytes",
            rest.len()
        );
        if let Frame::Message {
            header, message, ..
        } = found
        {
            let once = frame::encode(header, &message).expect("a decoded message encodes");
            let (again, n) = frame::next(&once);
            assert_eq!(n, once.len(), "a re-encoded frame is not read whole");
            let Frame::Message {
                header: h,
                message: m,
                ..
            } = again
            else {
                panic!("a re-encoded message does not decode: {again:?}");
            };
            assert_eq!(h, header, "the header changed");
            let twice = frame::encode(h, &m).expect("a decoded message encodes");
            assert_eq!(twice, once, "encode, decode, encode changed the frame");
        }
        rest = &rest[used..];
    }
}

fuzz_target!(|data: &[u8]| {
    walk(data);
    // First byte: the version (low bit) and sequence; next two: the message id; the rest:
    // its payload.
    if let [head, lo, hi, payload @ ..] = data {
        let version = if head & 1 == 0 {
            MavlinkVersion::V2
        } else {
            MavlinkVersion::V1
        };
        let header = MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: *head,
        };
        let id = u32::from(u16::from_le_bytes([*lo, *hi]));
        if let Some(bytes) = frame::wrap(version, header, id, payload) {
            walk(&bytes);
        }
    }
});
