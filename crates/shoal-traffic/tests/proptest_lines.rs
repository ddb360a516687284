//! Property tests: no input line panics the picture, the table stays within its limits, and
//! a good sentence after any junk still lands correctly.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::time::{Duration, Instant};

use proptest::prelude::*;
use shoal_traffic::{Picture, TrafficConfig};

const T1: &str = "!AIVDM,1,1,,A,13KF5P@P1s1hntRRIjFQj1H1P000,0*2B";

fn with_checksum(start: char, body: &str) -> String {
    let sum = body.bytes().fold(0u8, |a, b| a ^ b);
    format!("{start}{body}*{sum:02X}")
}

fn small_config() -> TrafficConfig {
    TrafficConfig {
        max_targets: 8,
        max_pending_fragments: 4,
        ..TrafficConfig::default()
    }
}

/// Lines that pass the checksum, so that the decoder sees arbitrary fields.
fn checked_line() -> impl Strategy<Value = Vec<u8>> {
    let sixbit = "[0-9:;<=>?@A-W`a-w]{0,90}";
    prop_oneof![
        // VDM/VDO with a random six-bit payload and random fragment fields.
        (
            prop::sample::select(vec!["AIVDM", "AIVDO", "BSVDM"]),
            0u8..11,
            0u8..11,
            "[0-9]?",
            "[AB12]?",
            sixbit,
            0u8..7
        )
            .prop_map(|(t, c, n, s, ch, p, f)| {
                with_checksum('!', &format!("{t},{c},{n},{s},{ch},{p},{f}")).into_bytes()
            }),
        // Own-ship sentences with random printable fields.
        (
            prop::sample::select(vec!["GPGGA", "GNRMC", "HEHDT", "GPRMC", "GNGGA"]),
            "[ -)+-~]{0,80}"
        )
            .prop_map(|(t, rest)| with_checksum('$', &format!("{t},{rest}")).into_bytes()),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn arbitrary_bytes_never_panic_and_stay_bounded(
        lines in prop::collection::vec(prop::collection::vec(any::<u8>(), 0..700), 0..40)
    ) {
        let cfg = small_config();
        let mut p = Picture::new(&cfg);
        let t = Instant::now();
        for l in &lines {
            p.ingest_line(l, t);
        }
        let s = p.stats();
        prop_assert!(p.len() <= cfg.max_targets);
        prop_assert!(s.pending_fragments <= cfg.max_pending_fragments);
        prop_assert!(s.lines <= lines.len() as u64);
        // The table still takes a good sentence, with the right fields.
        prop_assert!(p.ingest_line(T1.as_bytes(), t));
        let v = p.target_view(230_000_001, t).unwrap();
        prop_assert!((v.lat.unwrap() - 60.123456).abs() < 2e-6);
    }

    #[test]
    fn checksummed_random_sentences_never_panic_and_stay_bounded(
        lines in prop::collection::vec(checked_line(), 0..60),
        step_ms in 0u64..3000,
    ) {
        let cfg = small_config();
        let mut p = Picture::new(&cfg);
        let t0 = Instant::now();
        for (i, l) in lines.iter().enumerate() {
            p.ingest_line(l, t0 + Duration::from_millis(step_ms * i as u64));
        }
        let s = p.stats();
        prop_assert_eq!(s.decoder_panics, 0);
        prop_assert!(p.len() <= cfg.max_targets);
        prop_assert!(s.pending_fragments <= cfg.max_pending_fragments);
        let now = t0 + Duration::from_millis(step_ms * lines.len() as u64);
        prop_assert!(p.targets(now).len() <= cfg.max_targets);
        for v in p.targets(now) {
            if let (Some(lat), Some(lon)) = (v.lat, v.lon) {
                prop_assert!((-90.0..=90.0).contains(&lat) && (-180.0..=180.0).contains(&lon));
            }
        }
        // Every accepted line is one of the counted lines; nothing is counted twice.
        let dropped = s.too_long + s.garbage + s.no_checksum + s.bad_checksum
            + s.unsupported_sentence + s.unsupported_ais_type + s.bad_fields + s.bad_payload
            + s.bad_mmsi + s.no_fix + s.fragment_out_of_order + s.decoder_panics;
        prop_assert!(s.accepted + dropped <= s.lines, "{:?}", s);
    }

    #[test]
    fn many_distinct_targets_evict_within_the_limit(mmsis in prop::collection::vec(1u32..1_000_000_000, 1..100)) {
        let cfg = small_config();
        let mut p = Picture::new(&cfg);
        let t = Instant::now();
        for (i, m) in mmsis.iter().enumerate() {
            // Type 24 part A for this MMSI, first 42 bits: type 24, repeat 0, MMSI, part 0.
            let bits: u64 = (24u64 << 36) | (u64::from(*m) << 4);
            let mut payload = String::new();
            for k in (0..7).rev() {
                let v = ((bits >> (k * 6)) & 0x3f) as u8;
                payload.push(char::from(if v < 40 { v + 48 } else { v + 56 }));
            }
            payload.push_str(&"0".repeat(21));
            let l = with_checksum('!', &format!("AIVDM,1,1,,A,{payload},0"));
            p.ingest_line(l.as_bytes(), t + Duration::from_millis(i as u64));
            prop_assert!(p.len() <= cfg.max_targets);
        }
        let distinct: std::collections::HashSet<_> = mmsis.iter().collect();
        prop_assert_eq!(p.len(), distinct.len().min(cfg.max_targets));
        // The most recent MMSI is always held.
        prop_assert!(p.target_view(*mmsis.last().unwrap(), t).is_some());
    }
}
