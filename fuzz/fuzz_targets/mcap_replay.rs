//! Replay's reading path on arbitrary bytes, without DDS: the MCAP reader (records,
//! chunks, decompression), then each message decoded into its Shoal type and validated.
//! It must never panic, hang or take unbounded memory.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let mut messages = shoal_recorder::McapMessages::new(data);
    for message in messages.by_ref() {
        let Ok(message) = message else {
            break;
        };
        let _ = shoal_recorder::decode_message(&message);
    }
    assert!(messages.offset() <= data.len() as u64);
});
