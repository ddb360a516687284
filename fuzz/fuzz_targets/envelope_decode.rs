//! Fuzzes the signed-envelope decoder: arbitrary bytes must never panic, whatever decodes
//! must re-encode to the same bytes, and verifying it must refuse it (or accept it) without
//! panicking.
#![no_main]

use libfuzzer_sys::fuzz_target;
use shoal_security::envelope::Envelope;

fuzz_target!(|data: &[u8]| {
    if let Ok(env) = Envelope::decode(data) {
        assert_eq!(env.encode(), data, "re-encoding differs");
        assert_eq!(env.encoded_len(), data.len());
        let compact = env.to_compact();
        assert_eq!(Envelope::decode(&compact.encode()).as_ref(), Ok(&compact));
        // The embedded certificate is attacker-controlled too: parsing it must not panic.
        if let shoal_security::envelope::Credential::Certificate(der) = env.credential() {
            let _ = shoal_security::Certificate::from_der(der);
        }
    }
});
