//! Fuzzes the compact PDU decoders (predicted deltas included): arbitrary bytes must never
//! panic, and whatever decodes must re-encode to the same bytes.
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
        // A predicted delta is also applied to a keyframe of its own vehicle and seq, so
        // the predictor and residual arithmetic see every decodable delta, not only those
        // that follow a keyframe in the same input.
        let key = pdu::samples().into_iter().find_map(|(_, p)| match p {
            pdu::Pdu::StateKeyframe(k) => Some(k),
            _ => None,
        });
        for p in &pdus {
            if let (pdu::Pdu::PredictedDelta(d), Some(k)) = (p, &key) {
                let k = pdu::StateKeyframe {
                    vehicle: d.vehicle,
                    seq: d.keyframe_seq,
                    ..k.clone()
                };
                let _ = d.apply(&k);
            }
        }
    }
});
