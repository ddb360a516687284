//! Fuzzes the compact PDU decoders: arbitrary bytes must never panic, and whatever decodes
//! must re-encode to the same bytes.
#![no_main]

use libfuzzer_sys::fuzz_target;
use shoal_acoustic::pdu;

fuzz_target!(|data: &[u8]| {
    let _ = pdu::decode(data);
    let _ = pdu::decode_to_json(data);
    if let Ok(pdus) = pdu::unpack_frame(data) {
        let mut again = Vec::new();
        for p in &pdus {
            again.extend(pdu::encode(p).expect("a decoded PDU re-encodes"));
        }
        assert_eq!(&again[..], &data[..again.len()], "re-encoding differs");
        let mut dec = pdu::DeltaDecoder::new();
        for p in &pdus {
            let _ = dec.decode(p);
        }
    }
});
