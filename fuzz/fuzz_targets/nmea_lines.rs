//! Fuzzes the traffic picture's core with arbitrary bytes as NMEA 0183 lines: it must not
//! panic, must stay within its limits, and must still read a good sentence afterwards.
#![no_main]

use std::time::{Duration, Instant};

use libfuzzer_sys::fuzz_target;
use shoal_traffic::{ApproachWindow, Motion, OwnVehicle, Picture, TrafficConfig};

const GOOD: &str = "!AIVDM,1,1,,A,13KF5P@P1s1hntRRIjFQj1H1P000,0*2B";

fuzz_target!(|data: &[u8]| {
    let config = TrafficConfig {
        max_targets: 16,
        max_pending_fragments: 4,
        ..TrafficConfig::default()
    };
    let mut picture = Picture::new(&config);
    let start = Instant::now();
    let mut now = start;
    for line in data.split(|b| *b == b'\n') {
        // The first byte of each line also moves the clock, so time-outs are reached.
        if let Some(b) = line.first() {
            now += Duration::from_millis(u64::from(*b) * 50);
        }
        picture.ingest_line(line, now);
        assert!(picture.len() <= config.max_targets);
        assert!(picture.stats().pending_fragments <= config.max_pending_fragments);
    }
    let vehicles = [OwnVehicle {
        id: "fuzz".into(),
        motion: Motion {
            lat: 60.12,
            lon: 24.65,
            cog_deg: 10.0,
            sog_kn: 5.0,
        },
    }];
    let window = ApproachWindow {
        within_m: 2000.0,
        past_s: 60.0,
        ahead_s: 1200.0,
    };
    for a in picture.approaches(&vehicles, now, window) {
        assert!(a.cpa_m.is_finite() && a.cpa_m < window.within_m);
    }
    let _ = picture.own_ship(now);
    for t in picture.targets(now) {
        if let (Some(lat), Some(lon)) = (t.lat, t.lon) {
            assert!((-90.0..=90.0).contains(&lat) && (-180.0..=180.0).contains(&lon));
        }
    }
    assert!(picture.ingest_line(GOOD.as_bytes(), now));
    assert!(picture.target_view(230_000_001, now).is_some());
});
