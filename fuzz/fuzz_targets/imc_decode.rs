//! Fuzzes the IMC codec: arbitrary bytes must never panic, and every packet that decodes
//! must re-encode, in the byte order it came in, to exactly the bytes it was read from.
//!
//! Random bytes almost never carry a valid CRC, so each input is also wrapped as the
//! payload of a well-formed header and footer: that drives the field decoders.
#![no_main]

use libfuzzer_sys::fuzz_target;
use shoal_proxy::imc::codec;

/// Decodes a datagram the way the adapter does: a packet, or a skip to the next sync.
fn walk(data: &[u8]) {
    let mut rest = data;
    while !rest.is_empty() {
        match codec::decode(rest) {
            Ok((packet, order, used)) => {
                let again = codec::encode_with(&packet, order).expect("a decoded packet re-encodes");
                assert_eq!(&again[..], &rest[..used], "re-encoding differs");
                rest = &rest[used..];
            }
            Err(_) => {
                let skip = codec::resync(rest).max(1);
                rest = &rest[skip.min(rest.len())..];
            }
        }
    }
}

fuzz_target!(|data: &[u8]| {
    walk(data);
    // First two bytes: the message id; the rest: its payload.
    if data.len() >= 2 && data.len() - 2 <= usize::from(u16::MAX) {
        let mut p = Vec::with_capacity(data.len() + 20);
        p.extend_from_slice(&codec::SYNC.to_le_bytes());
        p.extend_from_slice(&data[..2]);
        p.extend_from_slice(&u16::try_from(data.len() - 2).unwrap_or(0).to_le_bytes());
        p.extend_from_slice(&[0u8; 14]);
        p.extend_from_slice(&data[2..]);
        let crc = codec::crc16(&p);
        p.extend_from_slice(&crc.to_le_bytes());
        walk(&p);
    }
});
