//! Round trips, the documented layout, and refusal of every kind of bad bytes.

use proptest::prelude::*;
use shoal_model::{Event, EventKind, Severity, Task, TaskState, VehicleKind};

use super::*;
use crate::environment::tests::{T0, aggregate, aggregates};
use crate::types::tests::position;

pub(crate) fn alarm(id: &str) -> Event {
    Event {
        event_id: id.into(),
        timestamp_ms: 1_700_000_000_123,
        severity: Severity::Critical,
        kind: EventKind::LowBattery,
        vehicle_id: "auv-1".into(),
        task_id: String::new(),
        text: "battery 9 %, surfacing".into(),
    }
}

pub(crate) fn transition(task: &str, state: TaskState) -> TaskTransition {
    TaskTransition {
        task_id: task.into(),
        mission_id: "m-1".into(),
        vehicle_id: "auv-1".into(),
        state,
        timestamp_ms: 1_700_000_000_456,
    }
}

#[test]
fn a_position_frame_has_the_documented_layout() {
    let bytes = encode_position(&position("auv-1")).unwrap();
    assert_eq!(bytes.len(), POSITION_LEN);
    assert_eq!(&bytes[0..3], &[1, 1, 0]); // version, kind, AUV
    assert_eq!(&bytes[3..9], &1_700_000_000_000i64.to_le_bytes()[..6]);
    assert_eq!(&bytes[9..13], &431_000_000i32.to_le_bytes());
    assert_eq!(&bytes[13..17], &59_000_000i32.to_le_bytes());
    assert_eq!(&bytes[17..19], &62u16.to_le_bytes()); // 12.4 m / 0.2
    assert_eq!(&bytes[19..21], &49_425u16.to_le_bytes()); // 271.5° * 65536 / 360
    assert_eq!(&bytes[21..23], &150u16.to_le_bytes());
    assert_eq!(bytes[23], 160);
}

#[test]
fn an_alarm_frame_has_the_documented_layout() {
    let bytes = encode_alarm("ship-1", 7, 3, &alarm("e1")).unwrap();
    let mut expected = vec![1, 2, 6];
    expected.extend(b"ship-1");
    expected.extend(7u64.to_le_bytes());
    expected.extend(3u64.to_le_bytes());
    expected.extend(&1_700_000_000_123i64.to_le_bytes()[..6]);
    expected.extend([3, 0, 2]);
    expected.extend(b"e1");
    expected.push(5);
    expected.extend(b"auv-1");
    expected.push(0);
    expected.extend(22u16.to_le_bytes());
    expected.extend(b"battery 9 %, surfacing");
    assert_eq!(bytes, expected);
}

#[test]
fn the_example_in_the_doc_is_what_the_encoder_writes() {
    // docs/federation.md is the specification third parties decode from.
    let doc = include_str!("../../../../docs/federation.md");
    let example = doc
        .split("### Example")
        .nth(1)
        .and_then(|s| s.split("```").nth(1))
        .expect("the doc has an example block");
    let hex: String = example.split_whitespace().collect();
    let bytes = hex::decode(hex).unwrap();
    assert_eq!(bytes, encode_alarm("ship-1", 7, 3, &alarm("e1")).unwrap());
    assert_eq!(decode_alarm(&bytes).unwrap().item, alarm("e1"));
}

#[test]
fn a_task_frame_has_the_documented_layout() {
    let bytes = encode_task("s", 1, 1, &transition("t-9", TaskState::Done)).unwrap();
    let mut expected = vec![1, 3, 1, b's'];
    expected.extend(1u64.to_le_bytes());
    expected.extend(1u64.to_le_bytes());
    expected.extend(&1_700_000_000_456i64.to_le_bytes()[..6]);
    expected.extend([4, 3]);
    expected.extend(b"t-9");
    expected.push(3);
    expected.extend(b"m-1");
    expected.push(5);
    expected.extend(b"auv-1");
    assert_eq!(bytes, expected);
}

fn lease(term: u64) -> LeaseRecord {
    LeaseRecord {
        vehicle_id: "auv-1".into(),
        term,
        holder: "shore".into(),
        home: "ship".into(),
        standby: "bk".into(),
        reason: LeaseReason::Handover,
        granted_ms: 1_700_000_000_456,
    }
}

#[test]
fn a_lease_frame_has_the_documented_layout() {
    let bytes = encode_lease(&lease(7)).unwrap();
    let mut expected = vec![1, 4, 2];
    expected.extend(7u64.to_le_bytes());
    expected.extend(&1_700_000_000_456i64.to_le_bytes()[..6]);
    expected.push(5);
    expected.extend(b"shore");
    expected.push(4);
    expected.extend(b"ship");
    expected.push(2);
    expected.extend(b"bk");
    assert_eq!(bytes, expected);
    assert_eq!(decode_lease("auv-1", &bytes), Ok(lease(7)));
}

#[test]
fn a_lease_frame_with_term_zero_a_bad_reason_or_a_bad_site_is_refused() {
    assert!(encode_lease(&lease(0)).is_err());
    let good = encode_lease(&lease(1)).unwrap();
    let mut zero = good.clone();
    zero[3..11].copy_from_slice(&0u64.to_le_bytes());
    assert_eq!(
        decode_lease("auv-1", &zero),
        Err(DecodeError::Range {
            field: "term",
            value: 0
        })
    );
    let mut reason = good.clone();
    reason[2] = 9;
    assert_eq!(
        decode_lease("auv-1", &reason),
        Err(DecodeError::Code {
            field: "reason",
            value: 9
        })
    );
    let mut holder = good;
    holder[18] = b'/';
    assert!(matches!(
        decode_lease("auv-1", &holder),
        Err(DecodeError::Invalid(_))
    ));
}

/// A survey under the shore's lease, term `term`, of the ship's `auv-1`.
pub(crate) fn order_task(term: u64) -> TaskAssignment {
    let p = |lat: f64, lon: f64| GeoPoint {
        latitude_deg: lat,
        longitude_deg: lon,
    };
    let mut t = TaskAssignment::new(
        "t-9",
        "m-1",
        "auv-1",
        1_700_000_000_456,
        &Task::SurveyArea {
            polygon: vec![p(43.1, 5.9), p(43.1, 5.91), p(43.11, 5.91)],
            line_spacing_m: 20.0,
            depth_m: Some(12.5),
            altitude_m: None,
            speed_mps: 1.5,
        },
    );
    t.lease_term = term;
    t.lease_holder = "shore".into();
    t
}

#[test]
fn an_order_frame_has_the_documented_layout() {
    let task = order_task(7);
    let bytes = encode_order("shore", 9, 4, &task).unwrap();
    let mut expected = vec![1, 5, 5];
    expected.extend(b"shore");
    // s = 3 + 5 = 8: where the fixed part after the site starts.
    expected.extend(9u64.to_le_bytes()); // s
    expected.extend(4u64.to_le_bytes()); // s+8
    expected.extend(&1_700_000_000_456i64.to_le_bytes()[..6]); // s+16
    expected.push(1); // s+22: survey_area
    expected.extend(7u64.to_le_bytes()); // s+23
    for v in [12.5f64, -1.0, 1.5, 20.0, 0.0, 0.0] {
        expected.extend(v.to_le_bytes()); // s+31 .. s+71
    }
    expected.push(3); // s+79
    expected.extend(b"t-9");
    expected.push(3);
    expected.extend(b"m-1");
    expected.extend(3u16.to_le_bytes());
    for (lat, lon) in [(43.1f64, 5.9f64), (43.1, 5.91), (43.11, 5.91)] {
        expected.extend(lat.to_le_bytes());
        expected.extend(lon.to_le_bytes());
    }
    assert_eq!(bytes, expected);
    let back = decode_order("auv-1", &bytes).unwrap();
    assert_eq!((back.site.as_str(), back.epoch, back.seq), ("shore", 9, 4));
    assert_eq!(back.item, task);
}

#[test]
fn the_order_table_in_the_doc_has_the_offsets_the_encoder_writes() {
    // docs/federation.md is the specification third parties decode from; the offsets after
    // the site are `s+k`, and the test above checks the encoder against the same ones.
    let doc = include_str!("../../../../docs/federation.md");
    let table = doc
        .split("### Order frame (kind 5)")
        .nth(1)
        .and_then(|s| s.split("\n### ").next())
        .expect("the doc has the order frame's table");
    let rows: Vec<(String, String)> = table
        .lines()
        .filter(|l| l.starts_with("| ") && !l.starts_with("| offset"))
        .map(|l| {
            let cells: Vec<&str> = l.split('|').map(str::trim).collect();
            (cells[1].to_string(), cells[2].to_string())
        })
        .collect();
    let expected = [
        ("0", "1"),
        ("1", "1"),
        ("2", "1 + n"),
        ("s", "8"),
        ("s+8", "8"),
        ("s+16", "6"),
        ("s+22", "1"),
        ("s+23", "8"),
        ("s+31", "8"),
        ("s+39", "8"),
        ("s+47", "8"),
        ("s+55", "8"),
        ("s+63", "8"),
        ("s+71", "8"),
        ("s+79", "1 + t"),
        ("…", "1 + m"),
        ("…", "2"),
        ("…", "16 × count"),
    ];
    let rows: Vec<(&str, &str)> = rows.iter().map(|(a, b)| (a.as_str(), b.as_str())).collect();
    assert_eq!(rows, expected);
}

#[test]
fn an_environment_frame_has_the_documented_layout() {
    let mut a = aggregates("auv-1", &["sea_water_temperature"]);
    a.properties[0].unit = "Cel".into();
    let bytes = encode_environment("ship", 9, 4, &a).unwrap();
    let mut expected = vec![1, 6, 4];
    expected.extend(b"ship");
    // s = 3 + 4 = 7: where the fixed part after the site starts.
    expected.extend(9u64.to_le_bytes()); // s
    expected.extend(4u64.to_le_bytes()); // s+8
    expected.extend(&(T0 + 60_000).to_le_bytes()[..6]); // s+16: the window's end
    expected.extend(&T0.to_le_bytes()[..6]); // s+22: its start
    expected.push(1); // s+28: one property
    // s+29, the property: p = its name's length, u = its unit's, q = 2 + p + u.
    expected.push(21);
    expected.extend(b"sea_water_temperature");
    expected.push(3);
    expected.extend(b"Cel");
    expected.extend(3u32.to_le_bytes()); // q
    for v in [12.5f64, 14.25, 13.0, 14.25] {
        expected.extend(v.to_le_bytes()); // q+4 .. q+28
    }
    expected.extend(&(T0 + 59_000).to_le_bytes()[..6]); // q+36
    expected.extend(431_000_000i32.to_le_bytes()); // q+42
    expected.extend(59_000_000i32.to_le_bytes()); // q+46
    expected.extend(62u16.to_le_bytes()); // q+50: 12.4 m / 0.2
    assert_eq!(bytes, expected);
    assert_eq!(bytes.len(), SE + 29 + (1 + 21) + (1 + 3) + 52);
    let back = decode_environment("auv-1", &bytes).unwrap();
    assert_eq!((back.site.as_str(), back.epoch, back.seq), ("ship", 9, 4));
    assert_eq!(back.item, a);
}

/// The rows (offset, size) of the table that follows `heading` in docs/federation.md, up
/// to the next heading or paragraph after it.
fn doc_rows(doc: &str, heading: &str) -> Vec<(String, String)> {
    let table = doc
        .split(heading)
        .nth(1)
        .and_then(|s| s.split("\n### ").next())
        .unwrap_or_else(|| panic!("the doc has {heading}"));
    table
        .lines()
        .skip_while(|l| !l.starts_with("| offset"))
        .take_while(|l| l.starts_with('|'))
        .filter(|l| l.starts_with("| ") && !l.starts_with("| offset"))
        .map(|l| {
            let cells: Vec<&str> = l.split('|').map(str::trim).collect();
            (cells[1].to_string(), cells[2].to_string())
        })
        .collect()
}

#[test]
fn the_environment_tables_in_the_doc_have_the_offsets_the_encoder_writes() {
    // docs/federation.md is the specification third parties decode from; the test above
    // checks the encoder against the same offsets.
    let doc = include_str!("../../../../docs/federation.md");
    let frame = doc_rows(doc, "### Environment frame (kind 6)");
    let expected = [
        ("0", "1"),
        ("1", "1"),
        ("2", "1 + n"),
        ("s", "8"),
        ("s+8", "8"),
        ("s+16", "6"),
        ("s+22", "6"),
        ("s+28", "1"),
        ("s+29", "count × property"),
    ];
    let frame: Vec<(&str, &str)> = frame
        .iter()
        .map(|(a, b)| (a.as_str(), b.as_str()))
        .collect();
    assert_eq!(frame, expected);
    let property = doc_rows(doc, "Each property, from its first byte:");
    let expected = [
        ("0", "1 + p"),
        ("1+p", "1 + u"),
        ("q", "4"),
        ("q+4", "8"),
        ("q+12", "8"),
        ("q+20", "8"),
        ("q+28", "8"),
        ("q+36", "6"),
        ("q+42", "4"),
        ("q+46", "4"),
        ("q+50", "2"),
    ];
    let property: Vec<(&str, &str)> = property
        .iter()
        .map(|(a, b)| (a.as_str(), b.as_str()))
        .collect();
    assert_eq!(property, expected);
}

/// Offset of the fixed part after the site `ship` (s = 3 + 4).
const SE: usize = 7;

#[test]
fn a_bad_environment_frame_is_refused_naming_what_is_wrong() {
    let mut one = aggregates("auv-1", &["t"]);
    one.properties[0].unit = "Cel".into();
    let good = encode_environment("ship", 1, 1, &one).unwrap();
    // q: the property's fixed part, after its name (`t`) and unit (`Cel`).
    let q = SE + 29 + 2 + 3 + 1;
    let refused = |edit: &dyn Fn(&mut Vec<u8>)| {
        let mut b = good.clone();
        edit(&mut b);
        decode_environment("auv-1", &b).unwrap_err().reason()
    };
    let f64_at =
        |at: usize, v: f64| move |b: &mut Vec<u8>| b[at..at + 8].copy_from_slice(&v.to_le_bytes());
    assert_eq!(refused(&|b| b[SE + 28] = 0), "range:properties");
    // 33 announced: refused before they are read.
    assert_eq!(refused(&|b| b[SE + 28] = 33), "range:properties");
    assert_eq!(refused(&|b| b.push(0)), "trailing");
    assert_eq!(
        refused(&|b| b[q..q + 4].copy_from_slice(&0u32.to_le_bytes())),
        "invalid:inconsistent:count"
    );
    assert_eq!(refused(&f64_at(q + 4, f64::NAN)), "invalid:not_finite:min");
    assert_eq!(
        refused(&f64_at(q + 12, f64::INFINITY)),
        "invalid:not_finite:max"
    );
    // min 12.5 > max.
    assert_eq!(refused(&f64_at(q + 12, 12.0)), "invalid:inconsistent:min");
    assert_eq!(refused(&f64_at(q + 20, 15.0)), "invalid:inconsistent:mean");
    assert_eq!(refused(&f64_at(q + 20, 12.0)), "invalid:inconsistent:mean");
    assert_eq!(
        refused(&f64_at(q + 28, 1.0)),
        "invalid:inconsistent:last_value"
    );
    assert_eq!(
        refused(&|b| b[q + 36..q + 42].copy_from_slice(&[0; 6])),
        "range:last_ms"
    );
    assert_eq!(
        refused(&|b| b[q + 42..q + 46].copy_from_slice(&900_000_001i32.to_le_bytes())),
        "range:latitude"
    );
    assert_eq!(
        refused(&|b| b[q + 50..q + 52].copy_from_slice(&55_001u16.to_le_bytes())),
        "range:depth"
    );
    // The window: its start after its end, or longer than an hour.
    assert_eq!(
        refused(&|b| b[SE + 22..SE + 28].copy_from_slice(&(T0 + 60_001).to_le_bytes()[..6])),
        "invalid:inconsistent:window_start_ms"
    );
    assert_eq!(
        refused(&|b| b[SE + 22..SE + 28].copy_from_slice(&(T0 - 3_600_000).to_le_bytes()[..6])),
        "invalid:inconsistent:window_start_ms"
    );
    assert_eq!(
        refused(&|b| b[SE + 22..SE + 28].copy_from_slice(&[0xff; 6])),
        "range:window_start_ms"
    );
    // Identifiers: the property name (`t` at SE + 30), the unit, the site, the vehicle.
    assert_eq!(refused(&|b| b[SE + 30] = b' '), "invalid:bad_text:property");
    assert_eq!(refused(&|b| b[SE + 32] = b'\n'), "invalid:bad_text:unit");
    assert_eq!(refused(&|b| b[SE + 32] = 0xff), "utf8:unit");
    assert_eq!(refused(&|b| b[3] = b'*'), "invalid:bad_text:site");
    assert_eq!(
        decode_environment("bad id", &good).unwrap_err().reason(),
        "invalid:bad_text:vehicle_id"
    );
    assert_eq!(
        refused(&|b| b[SE + 8..SE + 16].copy_from_slice(&[0; 8])),
        "range:seq"
    );
    // The same property twice in a frame.
    let twice = {
        let mut b = good.clone();
        b[SE + 28] = 2;
        b.extend_from_slice(&good[SE + 29..]);
        b
    };
    assert_eq!(
        decode_environment("auv-1", &twice).unwrap_err().reason(),
        "invalid:inconsistent:property"
    );
    assert_eq!(
        decode_alarm(&good).unwrap_err(),
        DecodeError::Kind {
            expected: KIND_ALARM,
            found: KIND_ENVIRONMENT
        }
    );
    // And what the encoder is given is checked the same.
    let mut bad = one.clone();
    bad.properties[0].mean = 99.0;
    assert!(encode_environment("ship", 1, 1, &bad).is_err());
    assert!(encode_environment("a/b", 1, 1, &one).is_err());
    let mut many = aggregates("auv-1", &[]);
    many.properties = (0..33).map(|i| aggregate(&format!("p{i}"))).collect();
    assert!(encode_environment("ship", 1, 1, &many).is_err());
}

#[test]
fn an_order_round_trips_every_kind_and_drops_what_it_does_not_carry() {
    let p = |lat: f64, lon: f64| GeoPoint {
        latitude_deg: lat,
        longitude_deg: lon,
    };
    let tasks = [
        Task::GotoWaypoint {
            target: p(-89.999_999_999, 179.999_999_999),
            depth_m: None,
            altitude_m: Some(5.0),
            speed_mps: 0.0,
        },
        Task::Hold {
            duration_s: 86_400.0,
        },
        Task::Surface,
        Task::ReturnHome,
        Task::Abort,
        Task::RequestState,
        Task::SetReportingRate { rate_hz: 0.25 },
    ];
    for t in tasks {
        let mut a = TaskAssignment::new("t", "", "auv-1", 1_700_000_000_000, &t);
        a.lease_term = u64::MAX;
        a.lease_holder = "shore".into();
        // Not carried: the home station stamps its own.
        a.issue_seq = 42;
        a.expires_ms = a.issued_ms + 1;
        let back = decode_order("auv-1", &encode_order("shore", 1, 1, &a).unwrap()).unwrap();
        a.issue_seq = 0;
        a.expires_ms = 0;
        assert_eq!(back.item, a);
    }
}

#[test]
fn an_order_without_the_senders_lease_is_not_encoded() {
    let mut t = order_task(0);
    t.lease_holder = String::new();
    assert_eq!(
        encode_order("shore", 1, 1, &t)
            .unwrap_err()
            .reason()
            .to_string(),
        "inconsistent:lease_term"
    );
    // Under another site's lease: it would come out as the sender's.
    let t = order_task(3);
    assert_eq!(
        encode_order("ship", 1, 1, &t)
            .unwrap_err()
            .reason()
            .to_string(),
        "inconsistent:lease_holder"
    );
    let mut t = order_task(3);
    t.speed_mps = f64::NAN;
    assert!(encode_order("shore", 1, 1, &t).is_err());
}

/// Offset of the fixed part after the site `shore` (s = 3 + 5).
const S: usize = 8;

#[test]
fn a_bad_order_frame_is_refused_naming_what_is_wrong() {
    let good = encode_order("shore", 1, 1, &order_task(2)).unwrap();
    let refused = |edit: &dyn Fn(&mut Vec<u8>)| {
        let mut b = good.clone();
        edit(&mut b);
        decode_order("auv-1", &b).unwrap_err().reason()
    };
    assert_eq!(
        refused(&|b| b[S + 23..S + 31].copy_from_slice(&0u64.to_le_bytes())),
        "range:lease_term"
    );
    assert_eq!(refused(&|b| b[S + 22] = 8), "code:task_kind");
    // 257 points announced (and even present): refused before they are read.
    assert_eq!(
        refused(&|b| {
            let at = b.len() - 3 * 16 - 2;
            b[at..at + 2].copy_from_slice(&257u16.to_le_bytes());
            b.extend(std::iter::repeat_n(0u8, 254 * 16));
        }),
        "range:area"
    );
    assert_eq!(refused(&|b| b.push(0)), "trailing");
    assert_eq!(
        refused(&|b| b[S + 47..S + 55].copy_from_slice(&f64::INFINITY.to_le_bytes())),
        "invalid:not_finite:speed_mps"
    );
    assert_eq!(
        refused(&|b| b[S + 31..S + 39].copy_from_slice(&(-1.0f64).to_le_bytes())),
        "invalid:inconsistent:depth_m"
    );
    // The envelope's site is the lease holder: it must be a site name.
    assert_eq!(refused(&|b| b[3] = b'*'), "invalid:bad_text:site");
    assert_eq!(
        decode_order("bad id", &good).unwrap_err().reason(),
        "invalid:bad_text:vehicle_id"
    );
    assert_eq!(
        decode_task(&good).unwrap_err(),
        DecodeError::Kind {
            expected: KIND_TASK,
            found: KIND_ORDER
        }
    );
}

#[test]
fn every_truncation_of_every_frame_is_refused() {
    let frames = [
        encode_position(&position("auv-1")).unwrap(),
        encode_alarm("ship-1", 7, 3, &alarm("e1")).unwrap(),
        encode_task("s", 1, 1, &transition("t-9", TaskState::Done)).unwrap(),
        encode_lease(&lease(3)).unwrap(),
        encode_order("shore", 9, 4, &order_task(7)).unwrap(),
        encode_environment("ship", 9, 4, &aggregates("auv-1", &["s", "t"])).unwrap(),
    ];
    for frame in &frames {
        for len in 0..frame.len() {
            let cut = &frame[..len];
            assert!(decode_position("v", cut).is_err(), "{len}");
            assert!(decode_alarm(cut).is_err(), "{len}");
            assert!(decode_task(cut).is_err(), "{len}");
            assert!(decode_lease("v", cut).is_err(), "{len}");
            assert!(decode_order("v", cut).is_err(), "{len}");
            assert!(decode_environment("v", cut).is_err(), "{len}");
        }
    }
}

#[test]
fn a_byte_past_the_end_is_refused() {
    let mut bytes = encode_task("s", 1, 1, &transition("t", TaskState::Done)).unwrap();
    bytes.push(0);
    assert_eq!(decode_task(&bytes), Err(DecodeError::Trailing(1)));
}

#[test]
fn another_version_or_kind_is_refused() {
    let mut bytes = encode_position(&position("auv-1")).unwrap();
    assert_eq!(
        decode_alarm(&bytes).unwrap_err(),
        DecodeError::Kind {
            expected: KIND_ALARM,
            found: KIND_POSITION
        }
    );
    bytes[0] = 2;
    assert_eq!(
        decode_position("v", &bytes).unwrap_err(),
        DecodeError::Version(2)
    );
}

#[test]
fn out_of_range_codes_and_values_are_refused_with_their_field() {
    let good = encode_position(&position("auv-1")).unwrap();
    let mut b = good.clone();
    b[2] = 5;
    assert_eq!(
        decode_position("v", &b).unwrap_err().reason(),
        "code:vehicle_kind"
    );
    let mut b = good.clone();
    b[9..13].copy_from_slice(&900_000_001i32.to_le_bytes());
    assert_eq!(
        decode_position("v", &b).unwrap_err().reason(),
        "range:latitude"
    );
    let mut b = good;
    b[23] = 201;
    assert_eq!(
        decode_position("v", &b).unwrap_err().reason(),
        "range:battery"
    );

    let mut a = encode_alarm("ship-1", 7, 3, &alarm("e1")).unwrap();
    let severity_at = 2 + 1 + 6 + 8 + 8 + 6;
    a[severity_at] = 4;
    assert_eq!(decode_alarm(&a).unwrap_err().reason(), "code:severity");
}

#[test]
fn a_sequence_number_of_zero_is_refused() {
    let mut a = encode_alarm("s", 7, 1, &alarm("e1")).unwrap();
    a[4 + 8..4 + 16].copy_from_slice(&0u64.to_le_bytes());
    assert_eq!(decode_alarm(&a).unwrap_err().reason(), "range:seq");
}

#[test]
fn a_site_that_is_not_a_key_chunk_is_refused() {
    let mut a = encode_alarm("ab", 7, 1, &alarm("e1")).unwrap();
    a[3] = b'*';
    assert_eq!(
        decode_alarm(&a).unwrap_err().reason(),
        "invalid:bad_text:site"
    );
    assert!(encode_alarm("a/b", 1, 1, &alarm("e1")).is_err());
}

#[test]
fn text_that_is_not_utf8_is_refused() {
    let mut a = encode_alarm("s", 7, 1, &alarm("e1")).unwrap();
    let last = a.len() - 1;
    a[last] = 0xff;
    assert_eq!(decode_alarm(&a).unwrap_err().reason(), "utf8:text");
}

#[test]
fn a_heading_just_under_a_full_turn_comes_back_as_north() {
    let mut p = position("auv-1");
    p.heading_deg = 359.999_9;
    let back = decode_position("auv-1", &encode_position(&p).unwrap()).unwrap();
    assert_eq!(back.heading_deg, 0.0);
}

fn kinds() -> impl Strategy<Value = VehicleKind> {
    proptest::sample::select(VEHICLE_KINDS.to_vec())
}

fn ids() -> impl Strategy<Value = String> {
    "[A-Za-z0-9_.-]{1,32}"
}

proptest! {
    #[test]
    fn positions_round_trip_within_half_a_step(
        kind in kinds(), id in ids(),
        ts in MIN_TIMESTAMP_MS..=MAX_TIMESTAMP_MS,
        lat in -90.0..=90.0f64, lon in -180.0..=180.0f64, depth in 0.0..=11_000.0f64,
        heading in 0.0..360.0f64, speed in 0.0..=30.0f64, battery in 0.0..=100.0f64,
    ) {
        let p = VehiclePosition {
            vehicle_id: id.clone(), kind, timestamp_ms: ts, latitude_deg: lat,
            longitude_deg: lon, depth_m: depth, heading_deg: heading, speed_mps: speed,
            battery_pct: battery,
        };
        let back = decode_position(&id, &encode_position(&p).unwrap()).unwrap();
        prop_assert_eq!(back.kind, kind);
        prop_assert_eq!(back.timestamp_ms, ts);
        prop_assert!((back.latitude_deg - lat).abs() <= 0.5e-7 + 1e-12);
        prop_assert!((back.longitude_deg - lon).abs() <= 0.5e-7 + 1e-12);
        prop_assert!((back.depth_m - depth).abs() <= DEPTH_STEP_M / 2.0 + 1e-9);
        let dh = shoal_model::geo::angle_diff(back.heading_deg, heading).abs();
        prop_assert!(dh <= HEADING_STEP_DEG / 2.0 + 1e-9);
        prop_assert!((back.speed_mps - speed).abs() <= SPEED_STEP_MPS / 2.0 + 1e-9);
        prop_assert!((back.battery_pct - battery).abs() <= BATTERY_STEP_PCT / 2.0 + 1e-9);
    }

    #[test]
    fn alarms_round_trip_exactly(
        site in "[a-z0-9-]{1,32}", epoch in any::<u64>(), seq in 1..u64::MAX,
        id in "[A-Za-z0-9_.-]{1,64}", severity in 0..4usize, kind in 0..9usize,
        text in "[ -~]{0,512}", vehicle in proptest::option::of(ids()),
    ) {
        let e = Event {
            event_id: id, timestamp_ms: 1_700_000_000_000, severity: SEVERITIES[severity],
            kind: EVENT_KINDS[kind], vehicle_id: vehicle.unwrap_or_default(),
            task_id: "t-1".into(), text,
        };
        let back = decode_alarm(&encode_alarm(&site, epoch, seq, &e).unwrap()).unwrap();
        prop_assert_eq!(back, Sequenced { site, epoch, seq, item: e });
    }

    #[test]
    fn transitions_round_trip_exactly(
        state in 0..8usize, task in "[A-Za-z0-9_.-]{1,64}", seq in 1..u64::MAX,
    ) {
        let mut t = transition(&task, TASK_STATES[state]);
        t.mission_id = String::new();
        let back = decode_task(&encode_task("shore", 9, seq, &t).unwrap()).unwrap();
        prop_assert_eq!(back.item, t);
        prop_assert_eq!(back.seq, seq);
    }

    #[test]
    fn garbage_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
        let _ = decode_position("v", &bytes);
        let _ = decode_alarm(&bytes);
        let _ = decode_task(&bytes);
        let _ = decode_lease("v", &bytes);
        let _ = decode_order("v", &bytes);
        let _ = decode_environment("v", &bytes);
        let _ = decode_catchup_end(&bytes);
    }

    #[test]
    fn catchup_ends_round_trip_exactly(
        site in "[a-z0-9-]{1,32}", epoch in any::<u64>(), oldest in any::<u64>(),
        highest in any::<u64>(),
    ) {
        let end = CatchupEnd { site, epoch, oldest, highest };
        let bytes = encode_catchup_end(&end).unwrap();
        prop_assert!(is_catchup_end(&bytes));
        prop_assert_eq!(decode_catchup_end(&bytes).unwrap(), end);
    }

    #[test]
    fn orders_round_trip_exactly(
        site in "[a-z0-9-]{1,32}", epoch in any::<u64>(), seq in 1..u64::MAX,
        kind in 0..8usize, task in "[A-Za-z0-9_.-]{1,64}", mission in "([A-Za-z0-9_.-]{1,64})?",
        vehicle in ids(), term in 1..=u64::MAX, issued in MIN_TIMESTAMP_MS..=MAX_TIMESTAMP_MS,
        depth in 0.0..=11_000.0f64, altitude in 0.0..=10_000.0f64, use_depth in any::<bool>(),
        speed in 0.0..=30.0f64, spacing in 1.0..=10_000.0f64, duration in 0.0..=86_400.0f64,
        rate in 0.001..=100.0f64,
        centre in (-80.0..=80.0f64, -170.0..=170.0f64), radius in 1e-6..=5.0f64,
        corners in 3..=256usize, phase in 0.0..1.0f64, points in 0..=8usize,
    ) {
        let kind = TASK_KINDS[kind];
        // A convex polygon (corners on a circle, in order) never crosses itself.
        let polygon = |n: usize| -> Vec<GeoPoint> {
            (0..n)
                .map(|i| {
                    let a = std::f64::consts::TAU * (i as f64 + phase) / n as f64;
                    GeoPoint {
                        latitude_deg: centre.0 + radius * a.sin(),
                        longitude_deg: centre.1 + radius * a.cos(),
                    }
                })
                .collect()
        };
        let area = match kind {
            TaskKind::GotoWaypoint => polygon(1),
            TaskKind::SurveyArea => polygon(corners),
            // Other kinds ignore the area, but it crosses as it is.
            _ => polygon(points),
        };
        let (depth_m, altitude_m) = if use_depth { (depth, -1.0) } else { (-1.0, altitude) };
        let t = TaskAssignment {
            task_id: task, mission_id: mission, vehicle_id: vehicle.clone(), issued_ms: issued,
            kind, area, depth_m, altitude_m, speed_mps: speed, line_spacing_m: spacing,
            duration_s: duration, rate_hz: rate, issue_seq: 0, expires_ms: 0,
            lease_term: term, lease_holder: site.clone(),
        };
        prop_assume!(t.validate().is_ok());
        let bytes = encode_order(&site, epoch, seq, &t).unwrap();
        let back = decode_order(&vehicle, &bytes).unwrap();
        prop_assert_eq!(back, Sequenced { site, epoch, seq, item: t });
    }

    #[test]
    fn environment_round_trips_exactly_but_for_the_place(
        site in "[a-z0-9-]{1,32}", epoch in any::<u64>(), seq in 1..u64::MAX,
        vehicle in ids(), start in MIN_TIMESTAMP_MS..MAX_TIMESTAMP_MS - 3_600_000,
        span in 1..=3_600_000i64,
        properties in proptest::collection::btree_map(
            "[A-Za-z0-9_.-]{1,64}",
            (
                "[ -~]{0,16}", 1..=u32::MAX, proptest::collection::vec(
                    proptest::num::f64::NORMAL | proptest::num::f64::ZERO
                        | proptest::num::f64::SUBNORMAL, 1..4),
                0..4usize, MIN_TIMESTAMP_MS..=MAX_TIMESTAMP_MS,
                -90.0..=90.0f64, -180.0..=180.0f64, 0.0..=11_000.0f64,
            ),
            1..=32,
        ),
    ) {
        let properties: Vec<PropertyAggregate> = properties
            .into_iter()
            .map(|(property, (unit, count, values, last, last_ms, lat, lon, depth))| {
                // Any finite values: the summary's own are among them (min, max, one as the
                // mean and one as the last), so it is consistent.
                let min = values.iter().copied().fold(f64::INFINITY, f64::min);
                let max = values.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                PropertyAggregate {
                    property, unit, count, min, max,
                    mean: values[values.len() / 2],
                    last_value: values[last % values.len()],
                    last_ms, latitude_deg: lat, longitude_deg: lon, depth_m: depth,
                }
            })
            .collect();
        let a = EnvironmentAggregates {
            vehicle_id: vehicle.clone(), window_start_ms: start, window_end_ms: start + span,
            properties,
        };
        let bytes = encode_environment(&site, epoch, seq, &a).unwrap();
        let back = decode_environment(&vehicle, &bytes).unwrap();
        prop_assert_eq!((&back.site, back.epoch, back.seq), (&site, epoch, seq));
        // The place is rounded as a position's; everything else is exact.
        prop_assert_eq!(back.item.properties.len(), a.properties.len());
        for (got, sent) in back.item.properties.iter().zip(&a.properties) {
            prop_assert!((got.latitude_deg - sent.latitude_deg).abs() <= 0.5e-7 + 1e-12);
            prop_assert!((got.longitude_deg - sent.longitude_deg).abs() <= 0.5e-7 + 1e-12);
            prop_assert!((got.depth_m - sent.depth_m).abs() <= DEPTH_STEP_M / 2.0 + 1e-9);
            let place = |p: &PropertyAggregate| PropertyAggregate {
                latitude_deg: 0.0, longitude_deg: 0.0, depth_m: 0.0, ..p.clone()
            };
            prop_assert_eq!(place(got), place(sent));
        }
        prop_assert_eq!(
            (back.item.window_start_ms, back.item.window_end_ms, back.item.vehicle_id.clone()),
            (start, start + span, vehicle)
        );
        // What decoded re-encodes to the very bytes (as the fuzz target checks).
        prop_assert_eq!(encode_environment(&site, epoch, seq, &back.item).unwrap(), bytes);
    }

    #[test]
    fn leases_round_trip_exactly(
        term in 1..u64::MAX, reason in 1..=3u8, standby in "([A-Za-z0-9_-]{1,32})?",
    ) {
        let mut r = lease(term);
        r.reason = LeaseReason::from_code(reason).unwrap();
        r.standby = standby;
        prop_assert_eq!(decode_lease("auv-1", &encode_lease(&r).unwrap()).unwrap(), r);
    }

    #[test]
    fn garbage_after_a_valid_header_is_refused(tail in proptest::collection::vec(any::<u8>(), 0..40)) {
        let mut bytes = vec![VERSION, KIND_ALARM];
        bytes.extend(tail);
        // Random bytes almost never form a valid alarm; when they do, it must validate.
        if let Ok(a) = decode_alarm(&bytes) {
            prop_assert!(a.item.validate().is_ok());
        }
    }
}
