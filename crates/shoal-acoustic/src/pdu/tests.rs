//! PDU codec tests: sizes against docs/acoustic.md#dccl-comparison, round trips, garbage,
//! the delta track.

use proptest::prelude::*;
use rand::SeedableRng as _;

use super::*;

fn sample(name: &str) -> Pdu {
    samples()
        .into_iter()
        .find(|(n, _)| *n == name)
        .map(|(_, p)| p)
        .unwrap_or_else(|| panic!("no sample {name}"))
}

#[test]
fn keyframe_is_158_bits_20_bytes_as_the_dccl_reference() {
    let e = encode_sized(&sample("state_keyframe")).unwrap();
    assert_eq!((e.bits, e.bytes.len()), (158, 20));
}

#[test]
fn delta_is_at_most_10_bytes() {
    let e = encode_sized(&sample("state_delta")).unwrap();
    assert_eq!((e.bits, e.bytes.len()), (80, 10));
}

#[test]
fn every_sample_round_trips_exactly_and_fits_a_frame() {
    for (name, pdu) in samples() {
        let bytes = encode(&pdu).unwrap();
        assert!(bytes.len() <= MAX_FRAME, "{name}");
        assert_eq!(decode(&bytes).unwrap(), pdu, "{name}");
    }
}

#[test]
fn size_table_lists_every_sample() {
    let t = size_table();
    for r in &t {
        eprintln!("{:<24} {:>4} bits {:>3} bytes", r.message, r.bits, r.bytes);
    }
    assert_eq!(t.len(), samples().len());
    assert!(t.iter().all(|r| r.bytes == r.bits.div_ceil(8)));
}

#[test]
fn several_pdus_share_one_instant_message() {
    let pdus = vec![
        sample("state_delta"),
        sample("task_status"),
        sample("event"),
        sample("ack"),
        sample("state_keyframe"),
    ];
    let frame = pack_frame(&pdus).unwrap();
    assert_eq!(frame.len(), 10 + 6 + 7 + 4 + 20);
    assert_eq!(unpack_frame(&frame).unwrap(), pdus);
    // Zero padding after the PDUs (a padded burst) is accepted.
    let mut padded = frame;
    padded.extend([0; 5]);
    assert_eq!(unpack_frame(&padded).unwrap(), pdus);
}

#[test]
fn an_overfull_frame_is_refused() {
    let pdus = vec![sample("state_keyframe"); 4];
    assert!(matches!(
        pack_frame(&pdus),
        Err(EncodeError::FrameTooLong { bytes: 80, max: 64 })
    ));
}

#[test]
fn truncated_input_is_an_error() {
    let bytes = encode(&sample("state_keyframe")).unwrap();
    for n in 0..bytes.len() {
        assert!(decode(&bytes[..n]).is_err(), "prefix of {n} bytes decoded");
    }
}

#[test]
fn unknown_message_id_and_garbage_padding_are_errors() {
    assert_eq!(
        decode(&[0xff, 0, 0]),
        Err(DecodeError::UnknownMessage { id: 0xff })
    );
    let mut bytes = encode(&sample("ack")).unwrap();
    if let Some(last) = bytes.last_mut() {
        *last |= 1; // a padding bit
    }
    assert_eq!(decode(&bytes), Err(DecodeError::BadPadding));
}

#[test]
fn an_identified_task_carries_the_station_id_for_75_bits_plus_6_3_a_character() {
    let Pdu::IdentifiedTask(t) = sample("identified_task_goto") else {
        panic!()
    };
    let e = encode_sized(&Pdu::IdentifiedTask(t)).unwrap();
    let plain = encode_sized(&sample("task_goto")).unwrap();
    // m-1-1: 52 (sequence) + 17 (expiry) + 6 (length) + 19 + 13 (five characters).
    assert_eq!(e.bits - plain.bits, 107);
    assert_eq!((e.bits, e.bytes.len()), (206, 26));
    assert_eq!(e.bytes[0], id::IDENTIFIED_TASK);
    assert_eq!(task_id_bits(64), 6 + 21 * 19 + 7);
}

#[test]
fn an_identified_task_refuses_what_it_cannot_carry_exactly() {
    let Pdu::IdentifiedTask(t) = sample("identified_task_abort") else {
        panic!()
    };
    for bad in ["", "a b", "é", &"x".repeat(65)] {
        let mut u = t.clone();
        u.task_id = bad.into();
        assert!(
            matches!(
                encode(&Pdu::IdentifiedTask(u)),
                Err(EncodeError::Inconsistent {
                    field: "task_id",
                    ..
                })
            ),
            "{bad:?}"
        );
    }
    let mut u = t;
    u.issue_seq = MAX_ISSUE_SEQ + 1;
    assert!(matches!(
        encode(&Pdu::IdentifiedTask(u)),
        Err(EncodeError::OutOfRange {
            field: "issue_seq",
            ..
        })
    ));
}

/// An abort to auv 3, task 7, written bit by bit from the docs' table of layout 2: issue
/// sequence `seq`, no expiry, a one-character id of code `id_code`.
fn layout_2_abort(seq: u64, id_code: u64) -> Vec<u8> {
    let mut w = BitWriter::new();
    w.write(u64::from(id::IDENTIFIED_TASK), 8);
    w.write(3, 4);
    w.write(7, 8);
    w.write(5, 3);
    w.write(seq, 52);
    w.write(0, 17);
    w.write(0, 6);
    w.write(id_code, 7);
    w.finish()
}

/// A task id chunk above 65³ is garbage: refused, never read as some other id.
#[test]
fn an_identified_task_with_an_impossible_id_code_is_refused() {
    assert_eq!(
        decode(&layout_2_abort(0, 127)),
        Err(DecodeError::InvalidCode {
            field: "task_id",
            code: 127
        })
    );
    // A build that predates a layout names the id it does not know.
    let e = DecodeError::UnknownMessage { id: 10 }.to_string();
    assert!(e.contains("does not know"), "{e}");
}

#[test]
fn a_lease_costs_57_bits_for_a_five_character_holder_and_nothing_when_absent() {
    let plain = encode_sized(&sample("identified_task_goto")).unwrap();
    let leased = encode_sized(&sample("identified_task_goto_leased")).unwrap();
    // shore at term 3: 20 (term) + 5 (length) + 19 + 13 (five characters).
    assert_eq!(leased.bits - plain.bits, 57);
    assert_eq!(lease_bits(5), 57);
    assert_eq!((leased.bits, leased.bytes.len()), (263, 33));
    assert_eq!(leased.bytes[0], id::LEASED_TASK);
    // Without a lease the task is layout 2, as before leases existed.
    assert_eq!((plain.bits, plain.bytes[0]), (206, id::IDENTIFIED_TASK));
    // The longest holder and term still fit a frame with the sample's id (a 64-character
    // id alone takes 61 bytes).
    assert_eq!(lease_bits(MAX_LEASE_HOLDER_LEN), 20 + 5 + 10 * 19 + 13);
    let Pdu::IdentifiedTask(mut t) = sample("identified_task_abort") else {
        panic!()
    };
    t.lease = Some(TaskLease {
        term: MAX_LEASE_TERM,
        holder: "y".repeat(MAX_LEASE_HOLDER_LEN),
    });
    let e = encode_sized(&Pdu::IdentifiedTask(t.clone())).unwrap();
    assert_eq!((e.bits, e.bytes.len()), (358, 45));
    assert_eq!(decode(&e.bytes).unwrap(), Pdu::IdentifiedTask(t));
}

/// The wire holder length is fixed by this layout; a longer model holder needs a new one.
#[test]
fn the_wire_lease_holder_limit_is_the_models() {
    assert_eq!(MAX_LEASE_HOLDER_LEN, shoal_model::MAX_LEASE_HOLDER_LEN);
}

/// Layout 2 is read as before leases existed: a task built bit by bit from the docs' table
/// decodes with no lease, and re-encodes to the same bytes.
#[test]
fn a_layout_2_task_from_an_older_station_decodes_without_a_lease() {
    // Sequence 5, the one-character id "a" (index 39).
    let bytes = layout_2_abort(5, 39);
    let Pdu::IdentifiedTask(t) = decode(&bytes).unwrap() else {
        panic!()
    };
    assert_eq!(
        (t.task_id.as_str(), t.issue_seq, t.lease.as_ref()),
        ("a", 5, None)
    );
    assert_eq!(encode(&Pdu::IdentifiedTask(t)).unwrap(), bytes);
}

#[test]
fn an_identified_task_refuses_a_lease_it_cannot_carry_exactly() {
    let Pdu::IdentifiedTask(t) = sample("identified_task_goto_leased") else {
        panic!()
    };
    for term in [0, MAX_LEASE_TERM + 1] {
        let mut u = t.clone();
        u.lease = Some(TaskLease {
            term,
            holder: "shore".into(),
        });
        assert!(
            matches!(
                encode(&Pdu::IdentifiedTask(u)),
                Err(EncodeError::OutOfRange {
                    field: "lease_term",
                    ..
                })
            ),
            "{term}"
        );
    }
    for bad in ["", "a b", "é", &"x".repeat(MAX_LEASE_HOLDER_LEN + 1)] {
        let mut u = t.clone();
        u.lease = Some(TaskLease {
            term: 3,
            holder: bad.into(),
        });
        assert!(
            matches!(
                encode(&Pdu::IdentifiedTask(u)),
                Err(EncodeError::Inconsistent {
                    field: "lease_holder",
                    ..
                })
            ),
            "{bad:?}"
        );
    }
}

/// A leased task (layout 3) whose lease is garbage is refused, never read as some lease.
#[test]
fn a_leased_task_with_a_malformed_lease_is_refused() {
    // Abort to auv 3, task 7, seq 0, no expiry, task id "a", then the lease.
    let leased = |term: u64, holder: &[(u64, u32)]| {
        let mut w = BitWriter::new();
        w.write(u64::from(id::LEASED_TASK), 8);
        w.write(3, 4);
        w.write(7, 8);
        w.write(5, 3);
        w.write(0, 52);
        w.write(0, 17);
        w.write(0, 6);
        w.write(39, 7);
        w.write(term, 20);
        for &(v, bits) in holder {
            w.write(v, bits);
        }
        w.finish()
    };
    // "s" at term 1 decodes: the frame is right.
    let Pdu::IdentifiedTask(t) = decode(&leased(1, &[(0, 5), (57, 7)])).unwrap() else {
        panic!()
    };
    assert_eq!(
        t.lease,
        Some(TaskLease {
            term: 1,
            holder: "s".into()
        })
    );
    // Term 0 is "no lease", which layout 3 never carries.
    assert_eq!(
        decode(&leased(0, &[(0, 5), (57, 7)])),
        Err(DecodeError::InvalidCode {
            field: "lease_term",
            code: 0
        })
    );
    // A character code beyond the alphabet (65 values in 7 bits).
    assert_eq!(
        decode(&leased(1, &[(0, 5), (127, 7)])),
        Err(DecodeError::InvalidCode {
            field: "lease_holder",
            code: 127
        })
    );
    // A pair beyond 65² in 13 bits, in a two-character holder.
    assert_eq!(
        decode(&leased(1, &[(1, 5), (65 * 65, 13)])),
        Err(DecodeError::InvalidCode {
            field: "lease_holder",
            code: 65 * 65
        })
    );
    // A holder length (32) whose characters are missing.
    assert!(matches!(
        decode(&leased(1, &[(31, 5)])),
        Err(DecodeError::Truncated { .. })
    ));
}

#[test]
fn every_truncation_of_a_leased_task_is_refused() {
    let bytes = encode(&sample("identified_task_goto_leased")).unwrap();
    for n in 0..bytes.len() {
        assert!(decode(&bytes[..n]).is_err(), "prefix of {n} bytes decoded");
        assert!(
            n == 0 || unpack_frame(&bytes[..n]).is_err(),
            "prefix of {n} bytes unpacked"
        );
    }
}

#[test]
fn a_lease_travels_in_json_only_when_present() {
    let leased = decode_to_json(&encode(&sample("identified_task_goto_leased")).unwrap()).unwrap();
    assert!(leased.contains("\"holder\": \"shore\""), "{leased}");
    let plain = decode_to_json(&encode(&sample("identified_task_goto")).unwrap()).unwrap();
    assert!(!plain.contains("lease"), "{plain}");
    // JSON written before leases existed still encodes, as layout 2.
    let json = r#"{"type":"identified_task","vehicle":3,"task_no":7,"task_id":"m-1-1",
        "issue_seq":1,"expires_s_of_day":null,"action":{"kind":"abort"}}"#;
    assert_eq!(encode_json(json).unwrap().bytes[0], id::IDENTIFIED_TASK);
}

#[test]
fn out_of_range_values_are_refused_by_the_encoder() {
    let Pdu::StateKeyframe(mut k) = sample("state_keyframe") else {
        panic!()
    };
    k.depth_m = 6000.1;
    assert!(matches!(
        encode(&Pdu::StateKeyframe(k.clone())),
        Err(EncodeError::OutOfRange {
            field: "depth_m",
            ..
        })
    ));
    k.depth_m = f64::NAN;
    assert!(matches!(
        encode(&Pdu::StateKeyframe(k)),
        Err(EncodeError::NotFinite { field: "depth_m" })
    ));
}

#[test]
fn json_entry_points_round_trip() {
    let json = r#"{"type":"ack","from":1,"msg_id":1,"ref_no":5}"#;
    let e = encode_json(json).unwrap();
    assert_eq!((e.bits, e.bytes.len()), (28, 4));
    let back = decode_to_json(&e.bytes).unwrap();
    assert!(back.contains("\"ref_no\": 5"), "{back}");
    assert_eq!(from_hex(&to_hex(&e.bytes)).unwrap(), e.bytes);
    let frame = encode_json(&format!("[{json},{json}]")).unwrap();
    assert_eq!(frame.bytes.len(), 8);
}

/// A lawnmower survey at 1.5 m/s reported every 10 s for two hours, with a wavy depth
/// and small attitude noise; the receiver acknowledges 70 % of keyframes.
#[test]
fn delta_coding_median_is_at_most_10_bytes_over_a_simulated_track() {
    let mut enc = DeltaEncoder::new();
    let mut dec = DeltaDecoder::new();
    let mut rng = rand_xoshiro::SplitMix64::seed_from_u64(7);
    let (mut lat, mut lon) = (43.0_f64, 5.9_f64);
    let mut sizes = Vec::new();
    let m_per_deg = 111_320.0;
    for i in 0..720u32 {
        let t = 36_000 + i * 10;
        // Legs of 400 m north/south joined by 50 m east.
        let leg = (i / 30) % 2;
        let yaw = if i % 30 == 29 {
            lon += 50.0 / (m_per_deg * lat.to_radians().cos());
            90.0
        } else {
            let d = 15.0 * if leg == 0 { 1.0 } else { -1.0 };
            lat += d / m_per_deg;
            if leg == 0 { 0.0 } else { 180.0 }
        };
        let f = f64::from(i);
        let state = StateKeyframe {
            vehicle: 3,
            seq: 0,
            seconds_of_day: t,
            latitude_deg: lat,
            longitude_deg: lon,
            depth_m: 30.0 + 5.0 * (f / 20.0).sin(),
            altitude_m: Some(20.0 - 5.0 * (f / 20.0).sin() + rng.random::<f64>()),
            speed_mps: 1.5 + 0.1 * rng.random::<f64>(),
            yaw_deg: yaw + 2.0 * rng.random::<f64>() - 1.0,
            pitch_deg: 2.0 * rng.random::<f64>() - 1.0,
            roll_deg: rng.random::<f64>(),
            battery_pct: 90.0 - f / 72.0,
        };
        let pdu = enc.encode(&state).unwrap();
        let bytes = encode(&pdu).unwrap();
        sizes.push(bytes.len());
        let decoded = dec.decode(&decode(&bytes).unwrap()).unwrap().unwrap();
        // Keyframe quantisation plus half the delta's (coarser) resolution at most.
        assert!(
            (decoded.latitude_deg - state.latitude_deg).abs() <= 1.5e-5 + 1e-9,
            "lat at {i}"
        );
        assert!(
            (decoded.depth_m - state.depth_m).abs() <= 0.1 + 1e-9,
            "depth at {i}"
        );
        if let Pdu::StateKeyframe(k) = &pdu
            && rng.random::<f64>() < 0.7
        {
            assert!(enc.acknowledge(k.seq));
        }
    }
    sizes.sort_unstable();
    let median = sizes[sizes.len() / 2];
    let keyframes = sizes.iter().filter(|&&s| s == 20).count();
    eprintln!(
        "delta track: median {median} bytes, {keyframes} keyframes of {}",
        sizes.len()
    );
    assert!(
        median <= 10,
        "median {median} bytes, {keyframes} keyframes of {}",
        sizes.len()
    );
}

/// A documented track generator for the predictive coding measurement: the simulator's AUV
/// kinematics (turn 10°/s, first-order speed response with a 2 s time constant, 0.5 m/s
/// vertical rate, pitch into dives, 80 m seabed), stepped at 0.1 s and reported every 2 s
/// (the VDT's interval) with sensor noise (yaw ±0.5°, speed ±0.03 m/s, pitch ±0.5°,
/// roll ±1°, altitude ±0.3 m). Legs of 60–240 s each turn by 60–180° either way, change
/// speed to 0.8–2.2 m/s, and every other leg dives or climbs to 5–60 m.
fn manoeuvring_track(seed: u64, reports: u32) -> Vec<StateKeyframe> {
    let mut rng = rand_xoshiro::SplitMix64::seed_from_u64(seed);
    let r = 6_371_000.0_f64;
    let (mut lat, mut lon, mut depth, mut yaw, mut speed) = (43.0_f64, 5.9_f64, 10.0, 0.0_f64, 1.5);
    let (mut battery, mut pitch) = (95.0_f64, 0.0_f64);
    let (mut target_yaw, mut target_speed, mut target_depth) = (0.0_f64, 1.5, 10.0);
    let mut leg_left = 0.0_f64;
    let mut leg = 0u32;
    let mut out = Vec::new();
    let sym = |rng: &mut rand_xoshiro::SplitMix64, a: f64| a * (2.0 * rng.random::<f64>() - 1.0);
    for i in 0..reports {
        for _ in 0..20 {
            let dt = 0.1;
            if leg_left <= 0.0 {
                leg += 1;
                leg_left = 60.0 + 180.0 * rng.random::<f64>();
                let turn = 60.0 + 120.0 * rng.random::<f64>();
                target_yaw = (target_yaw + if rng.random::<bool>() { turn } else { -turn })
                    .rem_euclid(360.0);
                target_speed = 0.8 + 1.4 * rng.random::<f64>();
                if leg.is_multiple_of(2) {
                    target_depth = 5.0 + 55.0 * rng.random::<f64>();
                }
            }
            leg_left -= dt;
            let err = (target_yaw - yaw + 540.0).rem_euclid(360.0) - 180.0;
            yaw = (yaw + err.clamp(-10.0 * dt, 10.0 * dt)).rem_euclid(360.0);
            speed += (target_speed - speed) * dt / 2.0;
            let dz = (target_depth - depth).clamp(-0.5 * dt, 0.5 * dt);
            depth += dz;
            pitch = if dz == 0.0 {
                0.0
            } else {
                -(dz / dt).atan2(speed.max(0.3)).to_degrees()
            };
            let d = speed * dt;
            lat += (d * yaw.to_radians().cos() / r).to_degrees();
            lon += (d * yaw.to_radians().sin() / (r * lat.to_radians().cos())).to_degrees();
            battery -= (2.0 + 20.0 * (speed / 2.5).powi(3)) * dt / 3600.0;
        }
        out.push(StateKeyframe {
            vehicle: 3,
            seq: 0,
            seconds_of_day: 36_000 + 2 * i,
            latitude_deg: lat,
            longitude_deg: lon,
            depth_m: depth,
            altitude_m: Some((80.0 - depth + sym(&mut rng, 0.3)).max(0.0)),
            speed_mps: (speed + sym(&mut rng, 0.03)).max(0.0),
            yaw_deg: (yaw + sym(&mut rng, 0.5)).rem_euclid(360.0),
            pitch_deg: pitch + sym(&mut rng, 0.5),
            roll_deg: sym(&mut rng, 1.0),
            battery_pct: battery,
        });
    }
    out
}

/// Sizes of the state PDUs an encoder sends for `track`; the receiver acknowledges 70 % of
/// keyframes, one report later. Every decoded state is checked against the precision of the
/// PDU that carried it.
struct TrackSizes {
    deltas: Vec<usize>,
    predicted: usize,
    keyframes: usize,
}

fn code_track(mut enc: DeltaEncoder, track: &[StateKeyframe], seed: u64) -> TrackSizes {
    let mut dec = DeltaDecoder::new();
    let mut rng = rand_xoshiro::SplitMix64::seed_from_u64(seed);
    let mut pending_ack = None;
    let mut out = TrackSizes {
        deltas: Vec::new(),
        predicted: 0,
        keyframes: 0,
    };
    for (i, state) in track.iter().enumerate() {
        let pdu = enc.encode(state).unwrap();
        if let Some(seq) = pending_ack.take() {
            assert!(enc.acknowledge(seq));
        }
        let bytes = encode(&pdu).unwrap();
        let decoded = dec.decode(&decode(&bytes).unwrap()).unwrap().unwrap();
        // (lat/lon, depth, altitude, speed, yaw, pitch/roll, battery) worst error.
        let tol = match &pdu {
            Pdu::StateKeyframe(k) => {
                out.keyframes += 1;
                if rng.random::<f64>() < 0.7 {
                    pending_ack = Some(k.seq);
                }
                [0.5e-5, 0.05, 0.05, 0.025, 0.25, 0.25, 0.5]
            }
            // Layout 1: keyframe quantisation plus half its own step.
            Pdu::StateDelta(_) => {
                out.deltas.push(bytes.len());
                [1.5e-5, 0.1, 0.15, 0.125, 1.5, 1.0, 1.0]
            }
            Pdu::PredictedDelta(_) => {
                out.deltas.push(bytes.len());
                out.predicted += 1;
                [1e-5, 0.05, 0.1, 0.125, 1.5, 1.0, 0.5]
            }
            other => panic!("unexpected {other:?}"),
        };
        let e = 1e-9;
        assert!(
            close(decoded.latitude_deg, state.latitude_deg, 2.0 * tol[0] + e),
            "lat at {i}: {pdu:?} {} vs {}",
            decoded.latitude_deg,
            state.latitude_deg
        );
        assert!(
            close(decoded.longitude_deg, state.longitude_deg, 2.0 * tol[0] + e),
            "lon at {i}: {pdu:?}"
        );
        assert!(
            close(decoded.depth_m, state.depth_m, 2.0 * tol[1] + e),
            "depth at {i}: {pdu:?}"
        );
        let (a, b) = (decoded.altitude_m.unwrap(), state.altitude_m.unwrap());
        assert!(close(a, b, 2.0 * tol[2] + e), "altitude at {i}: {pdu:?}");
        assert!(
            close(decoded.speed_mps, state.speed_mps, 2.0 * tol[3] + e),
            "speed at {i}"
        );
        assert!(
            close_angle(decoded.yaw_deg, state.yaw_deg, 2.0 * tol[4] + e, 360.0),
            "yaw at {i}"
        );
        assert!(
            close(decoded.pitch_deg, state.pitch_deg, 2.0 * tol[5] + e),
            "pitch at {i}"
        );
        assert!(
            close(decoded.roll_deg, state.roll_deg, 2.0 * tol[5] + e),
            "roll at {i}"
        );
        assert!(
            close(decoded.battery_pct, state.battery_pct, 2.0 * tol[6] + e),
            "battery at {i}"
        );
    }
    out
}

fn percentile(sorted: &[usize], p: f64) -> usize {
    #[allow(
        clippy::cast_possible_truncation,
        clippy::cast_sign_loss,
        clippy::cast_precision_loss
    )]
    let i = ((sorted.len() as f64 - 1.0) * p).round() as usize;
    sorted[i]
}

/// Issue 25 item 1: over a manoeuvring track (fixed seed) the predicted deltas' median must be
/// strictly below the layout-1 deltas'; the figures are printed for the record.
#[test]
fn predicted_delta_median_is_below_the_layout_1_delta_over_a_manoeuvring_track() {
    let track = manoeuvring_track(25, 3600);
    let mut old = code_track(DeltaEncoder::new(), &track, 1);
    let mut new = code_track(DeltaEncoder::predictive(), &track, 1);
    old.deltas.sort_unstable();
    new.deltas.sort_unstable();
    let (om, op) = (percentile(&old.deltas, 0.5), percentile(&old.deltas, 0.9));
    let (nm, np) = (percentile(&new.deltas, 0.5), percentile(&new.deltas, 0.9));
    eprintln!(
        "layout 1: median {om} B, p90 {op} B, {} keyframes; predictive: median {nm} B, p90 {np} B, \
         {} keyframes, {} of {} deltas predicted",
        old.keyframes,
        new.keyframes,
        new.predicted,
        new.deltas.len()
    );
    assert_eq!(om, 10);
    assert!(nm < om, "predictive median {nm} B is not below {om} B");
}

#[test]
fn a_delta_against_an_unknown_keyframe_is_an_error() {
    let mut dec = DeltaDecoder::new();
    assert_eq!(
        dec.decode(&sample("state_delta")),
        Err(DecodeError::UnknownKeyframe { vehicle: 3, seq: 1 })
    );
}

#[test]
fn a_predicted_delta_against_an_unknown_keyframe_is_refused() {
    let Pdu::PredictedDelta(d) = sample("predicted_delta_straight_leg") else {
        panic!("sample is not a predicted delta")
    };
    let mut dec = DeltaDecoder::new();
    let refused = Err(DecodeError::UnknownKeyframe { vehicle: 3, seq: 1 });
    assert_eq!(dec.decode(&Pdu::PredictedDelta(d.clone())), refused);
    // Keyframes of another seq or another vehicle are not its reference either.
    let Pdu::StateKeyframe(key) = sample("state_keyframe") else {
        panic!()
    };
    for (vehicle, seq) in [(3, 2), (4, 1)] {
        let k = StateKeyframe {
            vehicle,
            seq,
            ..key.clone()
        };
        dec.decode(&Pdu::StateKeyframe(k)).unwrap();
    }
    assert_eq!(dec.decode(&Pdu::PredictedDelta(d.clone())), refused);
    // `apply` checks the reference too, for callers that hold keyframes themselves.
    let other = StateKeyframe { seq: 2, ..key };
    assert_eq!(
        d.apply(&other),
        Err(DecodeError::UnknownKeyframe { vehicle: 3, seq: 1 })
    );
    dec.decode(&Pdu::StateKeyframe(key)).unwrap();
    assert!(dec.decode(&Pdu::PredictedDelta(d)).unwrap().is_some());
}

#[test]
fn an_overlong_predicted_delta_code_is_refused() {
    // Header (vehicle 3, seq 1, dt 10), then a latitude code of 13 zeros: the largest
    // latitude residual (zigzag 8190) needs 12.
    let mut w = BitWriter::new();
    w.write(u64::from(id::PREDICTED_DELTA), 8);
    w.write(3, 4);
    w.write(1, 4);
    w.write(10, 7);
    w.write(0, 13);
    w.write(1, 1);
    w.write(0, 30);
    assert_eq!(
        decode(&w.finish()),
        Err(DecodeError::Overlong { field: "lat_steps" })
    );
    // Zero residuals up to speed, then a speed code of the right length (6 zeros) whose
    // value 126 is above the field's largest code 80 (±40 steps).
    let mut w = BitWriter::new();
    w.write(u64::from(id::PREDICTED_DELTA), 8);
    w.write(0x31, 8);
    w.write(10, 7);
    w.write(0b1111, 4);
    w.write(0, 6);
    w.write(127, 7);
    w.write(0, 30);
    assert_eq!(
        decode(&w.finish()),
        Err(DecodeError::InvalidCode {
            field: "speed_steps",
            code: 126
        })
    );
}

#[test]
fn a_predicted_delta_too_far_from_its_prediction_falls_back_to_layout_1_or_a_keyframe() {
    let Pdu::StateKeyframe(key) = sample("state_keyframe") else {
        panic!()
    };
    let mut enc = DeltaEncoder::predictive();
    let Pdu::StateKeyframe(k) = enc.encode(&key).unwrap() else {
        panic!()
    };
    assert!(enc.acknowledge(k.seq));
    let size = |p: Pdu| encode(&p).unwrap().len();
    // Whichever delta is smaller goes, the older layout on a tie: a vehicle at full speed
    // in the keyframe that stopped and turned about (1.3 km off the prediction, large speed
    // and yaw residuals), and one that kept going.
    let fast = StateKeyframe {
        speed_mps: 10.0,
        ..key.clone()
    };
    let mut enc = DeltaEncoder::predictive();
    let Pdu::StateKeyframe(k) = enc.encode(&fast).unwrap() else {
        panic!()
    };
    assert!(enc.acknowledge(k.seq));
    let stopped = StateKeyframe {
        seconds_of_day: key.seconds_of_day + 127,
        yaw_deg: 270.0,
        speed_mps: 0.0,
        ..key.clone()
    };
    let kept_going = StateKeyframe {
        seconds_of_day: key.seconds_of_day + 10,
        latitude_deg: predict(&k, 10).latitude_deg,
        longitude_deg: predict(&k, 10).longitude_deg,
        ..fast.clone()
    };
    for s in [stopped.clone(), kept_going] {
        let old = size(Pdu::StateDelta(StateDelta::between(&k, &s).unwrap()));
        let new = size(Pdu::PredictedDelta(
            PredictedDelta::between(&k, &s).unwrap(),
        ));
        let sent = enc.encode(&s).unwrap();
        assert_eq!(encode(&sent).unwrap().len(), old.min(new), "{sent:?}");
        assert_eq!(
            matches!(sent, Pdu::PredictedDelta(_)),
            new < old,
            "{sent:?}"
        );
    }
    let s = stopped;
    // 20 km away: neither delta reaches; a keyframe.
    let s = StateKeyframe {
        latitude_deg: key.latitude_deg + 0.2,
        ..s
    };
    assert!(matches!(enc.encode(&s).unwrap(), Pdu::StateKeyframe(_)));
}

/// A stale reference: after 16 unacknowledged keyframes the receiver may hold a newer
/// keyframe under the acknowledged one's 4-bit seq, so no delta may name it any more.
#[test]
fn no_delta_names_a_keyframe_whose_seq_has_wrapped() {
    let Pdu::StateKeyframe(key) = sample("state_keyframe") else {
        panic!()
    };
    for mut enc in [DeltaEncoder::new(), DeltaEncoder::predictive()] {
        let Pdu::StateKeyframe(k) = enc.encode(&key).unwrap() else {
            panic!()
        };
        assert!(enc.acknowledge(k.seq));
        let near = StateKeyframe {
            seconds_of_day: key.seconds_of_day + 2,
            ..key.clone()
        };
        let far = StateKeyframe {
            latitude_deg: key.latitude_deg + 1.0,
            ..near.clone()
        };
        assert!(!matches!(enc.encode(&near).unwrap(), Pdu::StateKeyframe(_)));
        // 16 keyframes nobody acknowledges: the last one reuses the reference's seq.
        for _ in 0..16 {
            assert!(matches!(enc.encode(&far).unwrap(), Pdu::StateKeyframe(_)));
        }
        assert!(matches!(enc.encode(&near).unwrap(), Pdu::StateKeyframe(_)));
    }
}

/// After a turn a predicted delta grows; from 8 bytes (and a keyframe at least 10 s old) the
/// predictive encoder re-anchors with a keyframe, every other message until one is acked.
#[test]
fn a_grown_predicted_delta_re_anchors_with_a_keyframe() {
    let Pdu::StateKeyframe(key) = sample("state_keyframe") else {
        panic!()
    };
    let mut enc = DeltaEncoder::predictive();
    let Pdu::StateKeyframe(k) = enc.encode(&key).unwrap() else {
        panic!()
    };
    assert!(enc.acknowledge(k.seq));
    let at = |dt: u32, north_m: f64, yaw_deg: f64| StateKeyframe {
        seconds_of_day: k.seconds_of_day + dt,
        latitude_deg: k.latitude_deg + north_m / 111_195.0,
        yaw_deg,
        ..predict(&k, dt)
    };
    assert!(matches!(
        enc.encode(&at(2, 0.0, 90.0)).unwrap(),
        Pdu::PredictedDelta(_)
    ));
    // Turned north 30 s ago: 45 m off the prediction each way, yaw 90° off.
    let turned = StateKeyframe {
        longitude_deg: k.longitude_deg,
        ..at(30, 45.0, 0.0)
    };
    let d = PredictedDelta::between(&k, &turned).unwrap();
    assert!(encode(&Pdu::PredictedDelta(d)).unwrap().len() >= 8);
    assert!(matches!(
        enc.encode(&turned).unwrap(),
        Pdu::StateKeyframe(_)
    ));
    assert!(!matches!(
        enc.encode(&turned).unwrap(),
        Pdu::StateKeyframe(_)
    ));
    // The layout-1 encoder does not re-anchor (its deltas do not grow with a turn).
    let mut old = DeltaEncoder::new();
    let Pdu::StateKeyframe(k) = old.encode(&key).unwrap() else {
        panic!()
    };
    assert!(old.acknowledge(k.seq));
    assert!(matches!(old.encode(&turned).unwrap(), Pdu::StateDelta(_)));
}

fn arb_keyframe() -> impl Strategy<Value = StateKeyframe> {
    (
        (
            0u8..16,
            0u8..16,
            0u32..86_400,
            -90.0..=90.0f64,
            -180.0..=180.0f64,
            0.0..=6000.0f64,
        ),
        (
            prop::option::of(0.0..=1000.0f64),
            0.0..=10.0f64,
            0.0..360.0f64,
            -90.0..=90.0f64,
            -180.0..=180.0f64,
            0.0..=100.0f64,
        ),
    )
        .prop_map(
            |((vehicle, seq, sod, lat, lon, depth), (alt, speed, yaw, pitch, roll, bat))| {
                StateKeyframe {
                    vehicle,
                    seq,
                    seconds_of_day: sod,
                    latitude_deg: lat,
                    longitude_deg: lon,
                    depth_m: depth,
                    altitude_m: alt,
                    speed_mps: speed,
                    yaw_deg: yaw,
                    pitch_deg: pitch,
                    roll_deg: roll,
                    battery_pct: bat,
                }
            },
        )
}

fn arb_point() -> impl Strategy<Value = Point> {
    (-90.0..=90.0f64, -180.0..=180.0f64).prop_map(|(a, b)| Point {
        latitude_deg: a,
        longitude_deg: b,
    })
}

fn arb_motion() -> impl Strategy<Value = Motion> {
    (any::<bool>(), 0.0..=6000.0f64, 0.0..=10.0f64).prop_map(|(alt, z, speed)| Motion {
        depth_m: (!alt).then_some(z),
        altitude_m: alt.then_some(z),
        speed_mps: speed,
    })
}

fn arb_action() -> impl Strategy<Value = TaskAction> {
    prop_oneof![
        (arb_point(), arb_motion())
            .prop_map(|(target, motion)| TaskAction::Goto { target, motion }),
        (
            prop::collection::vec(arb_point(), 3..=8),
            1.0..=2048.0f64,
            arb_motion()
        )
            .prop_map(|(polygon, line_spacing_m, motion)| TaskAction::Survey {
                polygon,
                line_spacing_m,
                motion
            }),
        (0u32..=86_400).prop_map(|duration_s| TaskAction::Hold { duration_s }),
        Just(TaskAction::Surface),
        Just(TaskAction::ReturnHome),
        Just(TaskAction::Abort),
        Just(TaskAction::RequestState),
        (0.0..=100.0f64).prop_map(|rate_hz| TaskAction::SetRate { rate_hz }),
    ]
}

fn close(a: f64, b: f64, res: f64) -> bool {
    (a - b).abs() <= res / 2.0 + 1e-9
}

fn close_angle(a: f64, b: f64, res: f64, period: f64) -> bool {
    let d = (a - b).rem_euclid(period);
    d.min(period - d) <= res / 2.0 + 1e-9
}

fn round_trip(p: &Pdu) -> Pdu {
    let bytes = encode(p).unwrap();
    decode(&bytes).unwrap()
}

proptest! {
    #[test]
    fn keyframe_round_trips_within_resolution(k in arb_keyframe()) {
        let Pdu::StateKeyframe(b) = round_trip(&Pdu::StateKeyframe(k.clone())) else { panic!() };
        prop_assert_eq!((b.vehicle, b.seq, b.seconds_of_day), (k.vehicle, k.seq, k.seconds_of_day));
        prop_assert!(close(b.latitude_deg, k.latitude_deg, 1e-5));
        prop_assert!(close(b.longitude_deg, k.longitude_deg, 1e-5));
        prop_assert!(close(b.depth_m, k.depth_m, 0.1));
        prop_assert_eq!(b.altitude_m.is_some(), k.altitude_m.is_some());
        if let (Some(x), Some(y)) = (b.altitude_m, k.altitude_m) { prop_assert!(close(x, y, 0.1)); }
        prop_assert!(close(b.speed_mps, k.speed_mps, 0.05));
        prop_assert!(close_angle(b.yaw_deg, k.yaw_deg, 0.5, 360.0));
        prop_assert!(close(b.pitch_deg, k.pitch_deg, 0.5));
        prop_assert!(close(b.roll_deg, k.roll_deg, 0.5));
        prop_assert!(close(b.battery_pct, k.battery_pct, 1.0));
    }

    #[test]
    fn delta_round_trips_within_resolution(
        key in arb_keyframe(),
        dt in 0u32..=127, dlat in -0.005..0.005f64, dlon in -0.005..0.005f64, dd in -12.0..12.0f64,
        speed in 0.0..=10.0f64, yaw in 0.0..360.0f64, pitch in -14.0..=14.0f64, roll in -14.0..=14.0f64,
    ) {
        let key = key.quantised().unwrap();
        let mut s = key.clone();
        s.seconds_of_day = (key.seconds_of_day + dt) % 86_400;
        s.latitude_deg = (key.latitude_deg + dlat).clamp(-90.0, 90.0);
        s.longitude_deg = (key.longitude_deg + dlon).clamp(-180.0, 180.0);
        s.depth_m = (key.depth_m + dd).clamp(0.0, 6000.0);
        s.speed_mps = speed;
        s.yaw_deg = yaw;
        s.pitch_deg = pitch;
        s.roll_deg = roll;
        let d = StateDelta::between(&key, &s).unwrap();
        let Pdu::StateDelta(d) = round_trip(&Pdu::StateDelta(d)) else { panic!() };
        let b = d.apply(&key);
        prop_assert_eq!(b.seconds_of_day, s.seconds_of_day);
        prop_assert!(close(b.latitude_deg, s.latitude_deg, 2e-5));
        prop_assert!(close(b.longitude_deg, s.longitude_deg, 2e-5));
        prop_assert!(close(b.depth_m, s.depth_m, 0.1));
        prop_assert!(close(b.speed_mps, s.speed_mps, 0.25));
        prop_assert!(close_angle(b.yaw_deg, s.yaw_deg, 3.0, 360.0));
        prop_assert!(close(b.pitch_deg, s.pitch_deg, 2.0));
    }

    #[test]
    fn predicted_delta_round_trips_within_its_precision_for_every_field(
        key in arb_keyframe(),
        dt in 0u32..=127, dnorth in -300.0..300.0f64, deast in -300.0..300.0f64, dd in -20.0..20.0f64,
        dalt in prop::option::of(-150.0..150.0f64),
        speed in 0.0..=10.0f64, yaw in 0.0..360.0f64, pitch in -90.0..=90.0f64, roll in -180.0..180.0f64,
        battery in 0.0..=100.0f64,
    ) {
        let mut key = key.quantised().unwrap();
        // Away from the poles, where a few hundred metres are not a wrap of longitude.
        key.latitude_deg = key.latitude_deg.clamp(-80.0, 80.0);
        let p = predict(&key, dt);
        let mut s = key.clone();
        s.seconds_of_day = (key.seconds_of_day + dt) % 86_400;
        s.latitude_deg = p.latitude_deg + dnorth / 111_000.0;
        s.longitude_deg = p.longitude_deg + deast / 111_000.0;
        s.longitude_deg = (s.longitude_deg + 180.0).rem_euclid(360.0) - 180.0;
        s.depth_m = (p.depth_m + dd).max(0.0);
        // The altitude residual reaches ±200 m from the predicted (same seabed) altitude.
        s.altitude_m = key.altitude_m.and_then(|a| dalt.map(|d| (a - (s.depth_m - key.depth_m) + d).max(0.0)));
        s.speed_mps = speed;
        s.yaw_deg = yaw;
        s.pitch_deg = pitch;
        s.roll_deg = roll;
        s.battery_pct = battery;
        let d = PredictedDelta::between(&key, &s);
        prop_assert!(d.is_some(), "{s:?} not codable against {key:?}");
        let Some(d) = d else { unreachable!() };
        let e = encode_sized(&Pdu::PredictedDelta(d.clone())).unwrap();
        let Pdu::PredictedDelta(back) = decode(&e.bytes).unwrap() else { panic!() };
        prop_assert_eq!(&back, &d);
        let b = back.apply(&key).unwrap();
        prop_assert_eq!(b.seconds_of_day, s.seconds_of_day);
        prop_assert!(close(b.latitude_deg, s.latitude_deg, 2e-5), "lat {} vs {}", b.latitude_deg, s.latitude_deg);
        prop_assert!(close_angle(b.longitude_deg, s.longitude_deg, 2e-5, 360.0), "lon {} vs {}", b.longitude_deg, s.longitude_deg);
        prop_assert!(close(b.depth_m, s.depth_m, 0.1), "depth {} vs {}", b.depth_m, s.depth_m);
        prop_assert_eq!(b.altitude_m.is_some(), s.altitude_m.is_some());
        if let (Some(x), Some(y)) = (b.altitude_m, s.altitude_m) { prop_assert!(close(x, y, 0.2), "alt {x} vs {y}"); }
        prop_assert!(close(b.speed_mps, s.speed_mps, 0.25));
        prop_assert!(close_angle(b.yaw_deg, s.yaw_deg, 3.0, 360.0));
        prop_assert!(close(b.pitch_deg, s.pitch_deg, 2.0));
        prop_assert!(close_angle(b.roll_deg, s.roll_deg, 2.0, 360.0));
        prop_assert!(close(b.battery_pct, s.battery_pct, 1.0));
    }

    #[test]
    fn every_truncation_of_a_predicted_delta_is_refused(
        vehicle in 0u8..16, seq in 0u8..16, dt in 0u32..=127,
        r in prop::array::uniform8(-4095i32..=4095), alt in prop::option::of(-1000i32..=1000),
    ) {
        let d = PredictedDelta {
            vehicle, keyframe_seq: seq, dt_s: dt,
            lat_steps: r[0], lon_steps: r[1], depth_steps: r[2].clamp(-1270, 1270),
            altitude_steps: alt, speed_steps: r[3].clamp(-40, 40), yaw_steps: r[4].clamp(-60, 60),
            pitch_steps: r[5].clamp(-90, 90), roll_steps: r[6].clamp(-180, 180),
            battery_steps: r[7].clamp(-100, 100),
        };
        let bytes = encode(&Pdu::PredictedDelta(d.clone())).unwrap();
        prop_assert_eq!(decode(&bytes).unwrap(), Pdu::PredictedDelta(d));
        for n in 0..bytes.len() {
            prop_assert!(decode(&bytes[..n]).is_err(), "prefix of {} bytes decoded", n);
            // An empty frame is a valid frame of no PDUs.
            prop_assert!(n == 0 || unpack_frame(&bytes[..n]).is_err(), "prefix of {} bytes unpacked", n);
        }
    }

    #[test]
    fn task_round_trips_within_resolution(vehicle in 0u8..16, task_no in any::<u8>(), action in arb_action()) {
        let t = CompactTask { vehicle, task_no, action };
        let Pdu::Task(b) = round_trip(&Pdu::Task(t.clone())) else { panic!() };
        prop_assert_eq!((b.vehicle, b.task_no), (t.vehicle, t.task_no));
        let motion_close = |x: &Motion, y: &Motion| {
            x.depth_m.is_some() == y.depth_m.is_some()
                && close(x.depth_m.or(x.altitude_m).unwrap_or(0.0), y.depth_m.or(y.altitude_m).unwrap_or(0.0), 0.1)
                && close(x.speed_mps, y.speed_mps, 0.05)
        };
        let pt_close = |x: &Point, y: &Point| close(x.latitude_deg, y.latitude_deg, 1e-5) && close(x.longitude_deg, y.longitude_deg, 1e-5);
        match (&b.action, &t.action) {
            (TaskAction::Goto { target: a, motion: m }, TaskAction::Goto { target: c, motion: n }) => {
                prop_assert!(pt_close(a, c) && motion_close(m, n));
            }
            (TaskAction::Survey { polygon: a, line_spacing_m: s, motion: m }, TaskAction::Survey { polygon: c, line_spacing_m: u, motion: n }) => {
                prop_assert_eq!(a.len(), c.len());
                prop_assert!(a.iter().zip(c).all(|(x, y)| pt_close(x, y)));
                prop_assert!(close(*s, *u, 1.0) && motion_close(m, n));
            }
            (TaskAction::SetRate { rate_hz: a }, TaskAction::SetRate { rate_hz: c }) => prop_assert!(close(*a, *c, 0.001)),
            (a, c) => prop_assert_eq!(a, c),
        }
    }

    #[test]
    fn identified_task_round_trips_its_identity_exactly(
        vehicle in 0u8..16, task_no in any::<u8>(), action in arb_action(),
        task_id in "[A-Za-z0-9_.-]{1,64}", issue_seq in 0..=MAX_ISSUE_SEQ,
        expires in prop::option::of(0u32..86_400),
        lease in prop::option::of((1..=MAX_LEASE_TERM, "[A-Za-z0-9_.-]{1,32}")),
    ) {
        let lease = lease.map(|(term, holder)| TaskLease { term, holder });
        let t = IdentifiedTask { vehicle, task_no, task_id, issue_seq, expires_s_of_day: expires, lease, action };
        let e = encode_sized(&Pdu::IdentifiedTask(t.clone())).unwrap();
        let Pdu::IdentifiedTask(b) = decode(&e.bytes).unwrap() else { panic!() };
        prop_assert_eq!(
            (&b.task_id, b.issue_seq, b.expires_s_of_day, b.vehicle, b.task_no, &b.lease),
            (&t.task_id, t.issue_seq, t.expires_s_of_day, t.vehicle, t.task_no, &t.lease)
        );
        // Layout 3 exactly when there is a lease.
        let layout = if t.lease.is_some() { id::LEASED_TASK } else { id::IDENTIFIED_TASK };
        prop_assert_eq!(e.bytes[0], layout);
        // The action travels exactly as in layout 1; the identity and the lease cost what
        // docs/acoustic.md#task-identity says.
        let plain = encode_sized(&Pdu::Task(CompactTask { vehicle, task_no, action: t.action.clone() })).unwrap();
        let Pdu::Task(p) = decode(&plain.bytes).unwrap() else { panic!() };
        prop_assert_eq!(&b.action, &p.action);
        let lease_cost = t.lease.as_ref().map_or(0, |l| lease_bits(l.holder.len()));
        prop_assert_eq!(e.bits - plain.bits, 52 + 17 + task_id_bits(t.task_id.len()) + lease_cost);
        // Every truncation is refused, also inside the lease.
        for n in 0..e.bytes.len() {
            prop_assert!(decode(&e.bytes[..n]).is_err(), "prefix of {} bytes decoded", n);
        }
    }

    #[test]
    fn small_messages_round_trip_within_resolution(
        vehicle in 0u8..16, no in any::<u8>(), state in 0u8..8, progress in 0.0..=100.0f64, sod in 0u32..86_400,
        opt_vehicle in prop::option::of(0u8..16), opt_task in prop::option::of(any::<u8>()), sev in 0u8..4, kind in 0u8..9,
        vkind in 0u8..5, links in 0u8..32, caps in any::<u8>(), sensors in any::<u8>(), max_speed in 0.0..=30.0f64,
        prop_code in 0u8..10, frac in 0.0..=1.0f64, lat in -90.0..=90.0f64, lon in -180.0..=180.0f64, depth in 0.0..=6000.0f64,
    ) {
        let s = CompactTaskStatus { vehicle, task_no: no, state, progress_pct: progress, seconds_of_day: sod };
        let Pdu::TaskStatus(b) = round_trip(&Pdu::TaskStatus(s.clone())) else { panic!() };
        prop_assert!(close(b.progress_pct, s.progress_pct, 1.0));
        prop_assert_eq!((b.vehicle, b.task_no, b.state, b.seconds_of_day), (vehicle, no, state, sod));

        let e = CompactEvent { vehicle: opt_vehicle, event_no: no, severity: sev, kind, task_no: opt_task, seconds_of_day: sod };
        prop_assert_eq!(round_trip(&Pdu::Event(e.clone())), Pdu::Event(e));

        let a = CompactAnnouncement { vehicle, kind: vkind, links, capabilities: caps, sensors, max_speed_mps: max_speed, seconds_of_day: sod };
        let Pdu::Announcement(b) = round_trip(&Pdu::Announcement(a.clone())) else { panic!() };
        prop_assert!(close(b.max_speed_mps, a.max_speed_mps, 0.1));
        prop_assert_eq!((b.capabilities, b.sensors, b.links, b.kind), (caps, sensors, links, vkind));

        let p = ENVIRONMENT_PROPERTIES[usize::from(prop_code)];
        let value = p.value.min + frac * (p.value.max - p.value.min);
        let o = CompactEnvironment { vehicle, property: prop_code, seconds_of_day: sod, value, latitude_deg: lat, longitude_deg: lon, depth_m: depth };
        let Pdu::Environment(b) = round_trip(&Pdu::Environment(o)) else { panic!() };
        prop_assert!(close(b.value, value, p.value.resolution) || p.value.circular);
        prop_assert!(close(b.depth_m, depth, 0.1));

        let k = Ack { from: vehicle, msg_id: no, ref_no: state };
        prop_assert_eq!(round_trip(&Pdu::Ack(k)), Pdu::Ack(k));
    }

    #[test]
    fn arbitrary_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..80)) {
        let _ = decode(&bytes);
        let _ = unpack_frame(&bytes);
        let _ = decode_to_json(&bytes);
    }

    #[test]
    fn arbitrary_bytes_after_a_valid_id_never_panic(id in 1u8..=11, rest in prop::collection::vec(any::<u8>(), 0..70)) {
        let mut bytes = vec![id];
        bytes.extend(rest);
        if let Ok(pdus) = unpack_frame(&bytes) {
            // Whatever decodes re-encodes to the same bytes (no hidden state).
            let mut again = Vec::new();
            for p in &pdus {
                again.extend(encode(p).unwrap());
            }
            prop_assert_eq!(&again[..], &bytes[..again.len()]);
        }
    }
}

/// A receiver that lost its keyframes (a restarted CDT) says which reference it lacks: the
/// encoder drops that reference and sends a keyframe next, instead of deltas nobody can
/// decode until the periodic refresh; a report naming an older reference changes nothing.
#[test]
fn a_receiver_lacking_the_reference_gets_a_keyframe_next() {
    let state = |t: u32| StateKeyframe {
        vehicle: 3,
        seq: 0,
        seconds_of_day: t,
        latitude_deg: 43.0,
        longitude_deg: 5.9,
        depth_m: 10.0,
        altitude_m: None,
        speed_mps: 1.0,
        yaw_deg: 90.0,
        pitch_deg: 0.0,
        roll_deg: 0.0,
        battery_pct: 80.0,
    };
    for mut enc in [DeltaEncoder::new(), DeltaEncoder::predictive()] {
        let Pdu::StateKeyframe(k) = enc.encode(&state(100)).unwrap() else {
            panic!("the first state is a keyframe");
        };
        assert!(enc.acknowledge(k.seq));
        let delta = enc.encode(&state(102)).unwrap();
        assert!(!matches!(delta, Pdu::StateKeyframe(_)), "{delta:?}");
        let mut restarted = DeltaDecoder::new();
        assert!(matches!(
            restarted.decode(&delta),
            Err(DecodeError::UnknownKeyframe { .. })
        ));
        assert!(
            !enc.reference_unknown((k.seq + 1) % 16),
            "not the reference"
        );
        assert!(enc.reference_unknown(k.seq));
        let Pdu::StateKeyframe(fresh) = enc.encode(&state(104)).unwrap() else {
            panic!("a keyframe after the receiver said it lacks the reference");
        };
        restarted
            .decode(&Pdu::StateKeyframe(fresh.clone()))
            .unwrap();
        assert!(enc.acknowledge(fresh.seq));
        let next = enc.encode(&state(106)).unwrap();
        assert!(restarted.decode(&next).unwrap().is_some());
    }
}
