//! Fuzzes the acoustic frame check: any bytes from any address must be refused or opened
//! without panicking; what opens must be the frame a tagger with the same key sealed.
#![no_main]

use libfuzzer_sys::fuzz_target;
use shoal_security::{AcousticKey, AcousticTagger, TagSize};

fuzz_target!(|data: &[u8]| {
    let Some((&head, frame)) = data.split_first() else {
        return;
    };
    let key = AcousticKey::from_bytes([0x5a; 32]);
    let size = if head & 1 == 0 { TagSize::Bits32 } else { TagSize::Bits64 };
    let (src, dst) = (head >> 4, (head >> 1) & 0x07);
    let mut rx = AcousticTagger::new(dst, size, 0);
    rx.set_key(src, &key);
    rx.set_key(255, &key);
    let _ = rx.open(src, dst, frame);
    let _ = rx.open(src, 255, frame);
    // A genuine frame with the fuzz bytes as content opens to exactly those bytes, once.
    let mut tx = AcousticTagger::new(src, size, 7);
    tx.set_key(dst, &key);
    if let Ok(sealed) = tx.seal(dst, frame) {
        let mut rx = AcousticTagger::new(dst, size, 0);
        rx.set_key(src, &key);
        assert_eq!(rx.open(src, dst, &sealed).ok(), Some(frame));
        assert!(rx.open(src, dst, &sealed).is_err(), "a replay opened");
    }
});
