//! Fuzzes the EviNS NL parsers in both directions.
#![no_main]

use libfuzzer_sys::fuzz_target;
use shoal_acoustic::nl::{NlCommandParser, NlEventParser};

fuzz_target!(|data: &[u8]| {
    let mut cmds = NlCommandParser::new();
    cmds.push(data);
    for c in cmds.by_ref() {
        if let Ok(c) = c {
            let mut again = NlCommandParser::new();
            again.push(&c.to_bytes());
            assert_eq!(again.next(), Some(Ok(c)));
        }
    }
    let mut events = NlEventParser::new();
    events.push(data);
    for _ in events {}
});
