//! Fuzzes both AT parsers (host → modem commands, modem → host frames) and the
//! notification parser, fed in two chunks to exercise incremental parsing.
#![no_main]

use libfuzzer_sys::fuzz_target;
use shoal_acoustic::at::{CommandParser, FrameParser, Notification};

fuzz_target!(|data: &[u8]| {
    let split = data.first().map_or(0, |&b| usize::from(b)).min(data.len());
    let (a, b) = data.split_at(split);
    let mut cmds = CommandParser::new();
    cmds.push(a);
    for c in cmds.by_ref() {
        if let Ok(c) = c {
            // A parsed command's wire form parses back to itself.
            let mut again = CommandParser::new();
            again.push(&c.to_bytes());
            assert_eq!(again.next(), Some(Ok(c)));
        }
    }
    cmds.push(b);
    for _ in cmds.by_ref() {}
    let mut frames = FrameParser::new();
    frames.push(a);
    frames.push(b);
    for f in frames {
        let _ = Notification::parse(&f.body);
    }
    let _ = Notification::parse(data);
});
