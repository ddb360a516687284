//! Fuzzes the multi-hop relay header: any bytes a modem hands up must decode or be refused
//! without panicking, and what decodes must encode back to an envelope that decodes the same.
#![no_main]

use libfuzzer_sys::fuzz_target;
use shoal_acoustic::relay::Envelope;

fuzz_target!(|data: &[u8]| {
    if let Ok(envelope) = Envelope::decode(data) {
        let wire = envelope.encode().expect("a decoded envelope encodes");
        assert_eq!(Envelope::decode(&wire).ok(), Some(envelope));
    }
});
