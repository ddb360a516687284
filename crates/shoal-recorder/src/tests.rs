//! Unit tests of the file writer and reader together: round trips, rotation, damage.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::Path;

use mcap::records::op;
use proptest::prelude::*;
use shoal_model::{
    EnvironmentObservation, Event, EventKind, Severity, StateVector, Task, TaskAssignment,
    TaskState, TaskStatus, VehicleAnnouncement, VehicleKind,
};

use crate::{
    Compression, McapMessages, ReadError, RecordWriter, RecordedMessage, RecorderConfig, Sample,
    Topic, decode_message,
};

const T0_MS: i64 = 1_780_000_000_000;

pub(crate) fn state(id: &str, i: u32) -> StateVector {
    StateVector {
        vehicle_id: id.into(),
        timestamp_ms: T0_MS + i64::from(i) * 100,
        latitude_deg: 63.44 + f64::from(i) * 1e-6,
        longitude_deg: 10.39 + f64::from(i) * 2e-6,
        depth_m: 12.5,
        altitude_m: shoal_model::UNKNOWN,
        speed_mps: 1.5,
        yaw_deg: 90.0,
        pitch_deg: 0.0,
        roll_deg: 0.0,
        battery_pct: 80.0,
    }
}

/// One valid sample of every topic.
pub(crate) fn one_of_each() -> Vec<Sample> {
    vec![
        Sample::StateVector(state("auv-1", 0)),
        Sample::VehicleAnnouncement(VehicleAnnouncement {
            vehicle_id: "auv-1".into(),
            name: "AUV one".into(),
            kind: VehicleKind::Auv,
            vendor: "test".into(),
            capabilities: vec!["goto".into()],
            sensors: vec!["ctd".into()],
            links: vec![shoal_model::LinkKind::Ip],
            max_speed_mps: 2.0,
            timestamp_ms: T0_MS,
        }),
        Sample::TaskAssignment(TaskAssignment::new(
            "task-1",
            "m-1",
            "auv-1",
            T0_MS,
            &Task::Hold { duration_s: 30.0 },
        )),
        Sample::TaskStatus(TaskStatus {
            task_id: "task-1".into(),
            vehicle_id: "auv-1".into(),
            timestamp_ms: T0_MS,
            state: TaskState::Running,
            progress_pct: 40.0,
            message: "holding".into(),
        }),
        Sample::Event(Event {
            event_id: "ev-1".into(),
            timestamp_ms: T0_MS,
            severity: Severity::Warning,
            kind: EventKind::LowBattery,
            vehicle_id: "auv-1".into(),
            task_id: String::new(),
            text: "battery at 20 %".into(),
        }),
        Sample::Environment(EnvironmentObservation {
            vehicle_id: "auv-1".into(),
            property: "sea_water_temperature".into(),
            timestamp_ms: T0_MS,
            value: 7.25,
            unit: "Cel".into(),
            latitude_deg: 63.44,
            longitude_deg: 10.39,
            depth_m: 12.5,
        }),
    ]
}

fn config(dir: &Path) -> RecorderConfig {
    RecorderConfig {
        directory: dir.to_path_buf(),
        ..RecorderConfig::default()
    }
}

fn read_all(path: &Path) -> (Vec<RecordedMessage>, Option<ReadError>) {
    read_bytes(&std::fs::read(path).unwrap())
}

fn read_bytes(bytes: &[u8]) -> (Vec<RecordedMessage>, Option<ReadError>) {
    let mut out = Vec::new();
    for m in McapMessages::new(bytes) {
        match m {
            Ok(m) => out.push(m),
            Err(e) => return (out, Some(e)),
        }
    }
    (out, None)
}

#[test]
fn every_topic_round_trips_through_a_file_with_its_times_and_cdr_header() {
    let dir = tempfile::tempdir().unwrap();
    let mut w = RecordWriter::new(&config(dir.path())).unwrap();
    let samples = one_of_each();
    for (i, s) in samples.iter().enumerate() {
        let t = 1_000_000_000 * (i as u64 + 1);
        w.write(s.topic(), t, t - 5, &s.encode().unwrap()).unwrap();
    }
    w.close().unwrap();
    assert_eq!(w.files().len(), 1);
    let name = w.files()[0]
        .file_name()
        .unwrap()
        .to_string_lossy()
        .into_owned();
    assert!(
        name.starts_with("shoal-") && name.ends_with("-1.mcap"),
        "{name}"
    );
    let (messages, error) = read_all(&w.files()[0]);
    assert!(error.is_none(), "{error:?}");
    assert_eq!(messages.len(), samples.len());
    for (i, (m, s)) in messages.iter().zip(&samples).enumerate() {
        assert_eq!(m.topic, s.topic());
        assert_eq!(m.log_time_ns, 1_000_000_000 * (i as u64 + 1));
        assert_eq!(m.publish_time_ns, m.log_time_ns - 5);
        assert_eq!(
            m.data[..4],
            [0x00, 0x01, 0x00, 0x00],
            "CDR_LE encapsulation"
        );
        assert_eq!(&decode_message(m).unwrap(), s);
    }
    assert_eq!(w.stats().messages, 6);
    assert_eq!(w.stats().files, 1);
    assert_eq!(
        w.stats().bytes,
        std::fs::metadata(&w.files()[0]).unwrap().len()
    );
}

#[test]
fn a_topic_filter_records_only_its_topics() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = config(dir.path());
    cfg.topics = vec!["shoal/event".into()];
    let mut w = RecordWriter::new(&cfg).unwrap();
    for s in one_of_each() {
        w.write(s.topic(), 1, 1, &s.encode().unwrap()).unwrap();
    }
    w.close().unwrap();
    let (messages, error) = read_all(&w.files()[0]);
    assert!(error.is_none());
    assert_eq!(messages.len(), 1);
    assert_eq!(messages[0].topic, Topic::Event);
}

#[test]
fn files_rotate_by_size_and_every_file_is_complete() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = config(dir.path());
    cfg.max_file_bytes = 1024 * 1024;
    cfg.compression = Compression::None;
    let mut w = RecordWriter::new(&cfg).unwrap();
    for i in 0..30_000 {
        let s = state("auv-1", i);
        let data = shoal_dds::to_cdr_le(&s).unwrap();
        w.write(
            Topic::StateVector,
            u64::from(i) + 1,
            u64::from(i) + 1,
            &data,
        )
        .unwrap();
    }
    w.close().unwrap();
    let files = crate::mcap_files(dir.path()).unwrap();
    assert_eq!(files, w.files(), "the directory lists the files in order");
    assert!(files.len() >= 4, "{} files", files.len());
    let mut next = 1;
    for (i, f) in files.iter().enumerate() {
        let len = std::fs::metadata(f).unwrap().len();
        if i + 1 < files.len() {
            // At most one chunk (a quarter of the limit) and the summary (the IDL once per
            // schema, and the indexes) beyond the limit.
            let summary = 6 * crate::SHOAL_IDL.len() as u64 + 8192;
            assert!(len <= cfg.max_file_bytes * 5 / 4 + summary, "{len}");
            assert!(len >= cfg.max_file_bytes, "{len}: rotated too early");
        }
        let (messages, error) = read_all(f);
        assert!(error.is_none(), "{}: {error:?}", f.display());
        for m in messages {
            assert_eq!(m.log_time_ns, next, "in order, none lost");
            next += 1;
        }
    }
    assert_eq!(next, 30_001);
    assert_eq!(w.stats().files, files.len() as u64);
}

/// `compression_level` and `max_chunk_bytes` reach the file: the same state vectors
/// written at zstd level 1 and 19 read back the same and the level-19 file is smaller;
/// chunks of at most 64 KiB make more chunks than of at most 1 MiB.
#[test]
fn the_compression_level_and_the_chunk_size_are_applied() {
    let write = |compression_level: u32, max_chunk_bytes: u64| {
        let dir = tempfile::tempdir().unwrap();
        let cfg = RecorderConfig {
            compression_level,
            max_chunk_bytes,
            ..config(dir.path())
        };
        let mut w = RecordWriter::new(&cfg).unwrap();
        for i in 0..5_000 {
            let s = state(&format!("auv-{}", i % 7), i);
            let data = shoal_dds::to_cdr_le(&s).unwrap();
            let t = u64::from(i) + 1;
            w.write(Topic::StateVector, t, t, &data).unwrap();
        }
        w.close().unwrap();
        let bytes = std::fs::read(&w.files()[0]).unwrap();
        let mut reader = McapMessages::new(bytes.as_slice());
        let messages: Vec<RecordedMessage> = reader.by_ref().map(Result::unwrap).collect();
        (bytes.len(), reader.stats().chunks, messages)
    };
    let (fast, fast_chunks, fast_messages) = write(1, 1024 * 1024);
    let (small, small_chunks, small_messages) = write(19, 1024 * 1024);
    assert_eq!(fast_messages.len(), 5_000);
    assert_eq!(fast_messages, small_messages);
    assert!(small < fast, "level 19: {small} bytes, level 1: {fast}");
    // The schemas' and channels' chunk (written when the file opens), and the messages'.
    assert_eq!((fast_chunks, small_chunks), (2, 2));
    let (_, chunks, messages) = write(9, 64 * 1024);
    assert_eq!(messages, fast_messages);
    // About 650 KB of records in chunks of at most 64 KiB (and one message).
    assert!(chunks >= 10, "{chunks} chunks");
}

/// Over a long deployment the recordings stay under `max_total_bytes`: the oldest files of
/// this prefix go, the newest and other prefixes' files stay, and the rest still read.
#[test]
fn the_oldest_files_are_deleted_to_keep_under_the_total() {
    let dir = tempfile::tempdir().unwrap();
    let other = dir.path().join("other-20260101T000000Z-1.mcap");
    std::fs::write(&other, b"not ours").unwrap();
    let mut cfg = config(dir.path());
    cfg.max_file_bytes = 1024 * 1024;
    cfg.max_total_bytes = 3 * 1024 * 1024;
    cfg.compression = Compression::None;
    let mut w = RecordWriter::new(&cfg).unwrap();
    for i in 0..60_000 {
        let data = shoal_dds::to_cdr_le(&state("auv-1", i)).unwrap();
        w.write(
            Topic::StateVector,
            u64::from(i) + 1,
            u64::from(i) + 1,
            &data,
        )
        .unwrap();
    }
    w.close().unwrap();
    let ours: Vec<_> = crate::mcap_files(dir.path())
        .unwrap()
        .into_iter()
        .filter(|p| p != &other)
        .collect();
    let total: u64 = ours
        .iter()
        .map(|p| std::fs::metadata(p).unwrap().len())
        .sum();
    assert!(total <= cfg.max_total_bytes, "{total} bytes kept");
    assert!(w.stats().files_deleted >= 2, "{:?}", w.stats());
    assert_eq!(w.stats().files, w.stats().files_deleted + ours.len() as u64);
    assert_eq!(ours, w.files(), "the writer lists only what is left");
    assert!(
        other.exists(),
        "another prefix's file is not ours to delete"
    );
    // What is left is the newest part of the recording, every file whole.
    let mut last = 0;
    for f in &ours {
        let (messages, error) = read_all(f);
        assert!(error.is_none(), "{error:?}");
        for m in messages {
            assert!(m.log_time_ns > last);
            last = m.log_time_ns;
        }
    }
    assert_eq!(last, 60_000);
    // A cap under two files is refused at the start.
    cfg.max_total_bytes = cfg.max_file_bytes;
    assert!(RecordWriter::new(&cfg).is_err());
}

#[test]
fn files_rotate_by_time() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = config(dir.path());
    cfg.max_file_seconds = 1;
    let mut w = RecordWriter::new(&cfg).unwrap();
    let data = state("auv-1", 0);
    let data = shoal_dds::to_cdr_le(&data).unwrap();
    w.write(Topic::StateVector, 1, 1, &data).unwrap();
    std::thread::sleep(std::time::Duration::from_millis(1100));
    w.tick(std::time::Instant::now()).unwrap();
    // Rotated on the tick: the first file is closed before the next message comes.
    let (first, error) = read_all(&w.files()[0]);
    assert!(error.is_none(), "{error:?}");
    assert_eq!(first.len(), 1);
    w.write(Topic::StateVector, 2, 2, &data).unwrap();
    w.close().unwrap();
    assert_eq!(w.files().len(), 2);
    let (second, _) = read_all(&w.files()[1]);
    assert_eq!(second.len(), 1);
}

/// A file written in chunks of 100 messages and left open (as a killed recorder leaves
/// it): its bytes, and where each chunk ends.
fn unfinished_file(dir: &Path, chunks: u32) -> (Vec<u8>, Vec<u64>) {
    let mut w = RecordWriter::new(&config(dir)).unwrap();
    let mut ends = Vec::new();
    for c in 0..chunks {
        for i in 0..100 {
            let n = c * 100 + i;
            let data = shoal_dds::to_cdr_le(&state("auv-1", n)).unwrap();
            w.write(Topic::StateVector, u64::from(n) + 1, 0, &data)
                .unwrap();
        }
        w.flush().unwrap();
        ends.push(w.stats().bytes);
    }
    let bytes = std::fs::read(&w.files()[0]).unwrap();
    // The writer would finish the file when dropped; this one is "killed" instead.
    std::mem::forget(w);
    (bytes, ends)
}

#[test]
fn a_killed_recorders_file_is_read_up_to_its_last_chunk_and_says_where_it_ends() {
    let dir = tempfile::tempdir().unwrap();
    let (bytes, ends) = unfinished_file(dir.path(), 3);
    assert_eq!(bytes.len() as u64, ends[2]);
    // All three chunks, then the missing footer: truncated at the end of the third.
    let (messages, error) = read_bytes(&bytes);
    assert_eq!(messages.len(), 300);
    match error {
        Some(ReadError::Truncated { offset, file_len }) => {
            assert_eq!(offset, ends[2]);
            assert_eq!(file_len, ends[2]);
        }
        other => panic!("{other:?}"),
    }
    // Cut inside the third chunk: the first two are replayed, the error names where the
    // third starts.
    let cut = &bytes[..(ends[1] + 20) as usize];
    let (messages, error) = read_bytes(cut);
    assert_eq!(messages.len(), 200);
    let error = error.unwrap();
    assert_eq!(error.offset(), ends[1]);
    assert!(
        error
            .to_string()
            .contains(&format!("byte offset {}", ends[1])),
        "{error}"
    );
}

#[test]
fn a_corrupt_chunk_stops_reading_at_its_offset_after_the_good_ones() {
    let dir = tempfile::tempdir().unwrap();
    let (mut bytes, ends) = unfinished_file(dir.path(), 3);
    // A byte in the middle of the second chunk's compressed data.
    let middle = ((ends[0] + ends[1]) / 2) as usize;
    bytes[middle] ^= 0x5a;
    let (messages, error) = read_bytes(&bytes);
    assert_eq!(
        messages.len(),
        100,
        "only the first chunk, nothing of the bad one"
    );
    match error {
        Some(ReadError::Corrupt { offset, .. }) => assert_eq!(offset, ends[0]),
        other => panic!("{other:?}"),
    }
}

#[test]
fn garbage_and_empty_input_are_errors_at_offset_zero_not_panics() {
    for bytes in [&b""[..], b"not an mcap file at all", &[0x89; 100]] {
        let (messages, error) = read_bytes(bytes);
        assert!(messages.is_empty());
        assert_eq!(error.unwrap().offset(), 0);
    }
}

#[test]
fn channels_that_are_not_shoal_channels_are_skipped_and_counted() {
    let mut buf = std::io::Cursor::new(Vec::new());
    {
        let mut w = mcap::Writer::new(&mut buf).unwrap();
        let json = w.add_schema("Chat", "jsonschema", b"{}").unwrap();
        let chat = w
            .add_channel(json, "rt/chatter", "json", &Default::default())
            .unwrap();
        // A Shoal topic name with another schema encoding is not ours either.
        let ros = w
            .add_schema("shoal::StateVector", "ros2msg", b"string vehicle_id")
            .unwrap();
        let fake = w
            .add_channel(ros, "shoal/state_vector", "cdr", &Default::default())
            .unwrap();
        let idl = w
            .add_schema("shoal::StateVector", "omgidl", crate::SHOAL_IDL.as_bytes())
            .unwrap();
        let real = w
            .add_channel(idl, "shoal/state_vector", "cdr", &Default::default())
            .unwrap();
        let data = shoal_dds::to_cdr_le(&state("auv-1", 0)).unwrap();
        for (channel, payload) in [(chat, &b"{}"[..]), (fake, &data), (real, &data)] {
            let header = mcap::records::MessageHeader {
                channel_id: channel,
                sequence: 1,
                log_time: 1,
                publish_time: 1,
            };
            w.write_to_known_channel(&header, payload).unwrap();
        }
        w.finish().unwrap();
    }
    let bytes = buf.into_inner();
    let mut reader = McapMessages::new(&bytes[..]);
    let messages: Vec<_> = reader.by_ref().collect::<Result<_, _>>().unwrap();
    assert_eq!(messages.len(), 1);
    assert_eq!(reader.stats().unknown_messages, 2);
    assert_eq!(reader.stats().unknown_channels, 2);
    assert_eq!(
        reader.unknown_topics(),
        ["rt/chatter", "shoal/state_vector"]
    );
}

#[test]
fn undecodable_and_invalid_payloads_are_told_apart() {
    let mut bad = state("auv-1", 0);
    bad.latitude_deg = 123.0;
    let invalid = RecordedMessage {
        topic: Topic::StateVector,
        log_time_ns: 1,
        publish_time_ns: 1,
        data: shoal_dds::to_cdr_le(&bad).unwrap(),
    };
    assert!(matches!(
        decode_message(&invalid),
        Err(crate::replay::SampleError::Invalid(_))
    ));
    let garbage = RecordedMessage {
        data: vec![0, 1, 0, 0, 7],
        ..invalid
    };
    assert!(matches!(
        decode_message(&garbage),
        Err(crate::replay::SampleError::Cdr(_))
    ));
}

fn identifier() -> impl Strategy<Value = String> {
    "[A-Za-z0-9_.-]{1,32}"
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    /// Any state vector (valid or not, NaN included) comes back from a file byte for byte
    /// and decodes to the same value.
    #[test]
    fn state_vector_payloads_round_trip_through_a_file(
        id in identifier(),
        t in any::<i64>(),
        f in proptest::array::uniform10(any::<f64>()),
        log in any::<u64>(),
    ) {
        let s = StateVector {
            vehicle_id: id,
            timestamp_ms: t,
            latitude_deg: f[0],
            longitude_deg: f[1],
            depth_m: f[2],
            altitude_m: f[3],
            speed_mps: f[4],
            yaw_deg: f[5],
            pitch_deg: f[6],
            roll_deg: f[7],
            battery_pct: f[8] + f[9],
        };
        let sample = Sample::StateVector(s);
        let data = sample.encode().unwrap();
        let dir = tempfile::tempdir().unwrap();
        let mut w = RecordWriter::new(&config(dir.path())).unwrap();
        w.write(Topic::StateVector, log, log, &data).unwrap();
        w.close().unwrap();
        let (messages, error) = read_all(&w.files()[0]);
        prop_assert!(error.is_none());
        prop_assert_eq!(&messages[0].data, &data);
        prop_assert_eq!(messages[0].log_time_ns, log);
        let back = Sample::decode(Topic::StateVector, &messages[0].data).unwrap();
        prop_assert_eq!(back.encode().unwrap(), data);
    }

    /// Arbitrary bytes never panic the reader, and its error offset lies within them.
    #[test]
    fn arbitrary_bytes_never_panic_the_reader(bytes in proptest::collection::vec(any::<u8>(), 0..2048)) {
        let mut prefixed = mcap::MAGIC.to_vec();
        prefixed.extend_from_slice(&bytes);
        for input in [&bytes, &prefixed] {
            let (_, error) = read_bytes(input);
            if let Some(e) = error {
                prop_assert!(e.offset() <= input.len() as u64);
            }
        }
    }
}

/// An MCAP record: opcode, little-endian length, body.
fn record(opcode: u8, body: &[u8]) -> Vec<u8> {
    let mut r = vec![opcode];
    r.extend_from_slice(&(body.len() as u64).to_le_bytes());
    r.extend_from_slice(body);
    r
}

/// The file magic and then `records`.
fn file_of(records: &[Vec<u8>]) -> Vec<u8> {
    let mut f = b"\x89MCAP0\r\n".to_vec();
    for r in records {
        f.extend_from_slice(r);
    }
    f
}

/// A length field that claims 4 GiB must cost nothing: the fuzzer's finding (a Header
/// whose string length made the mcap crate reserve 4 GiB) and its kin in the records
/// replay parses, at the top level and inside a chunk.
#[test]
fn hostile_length_fields_are_refused_before_any_allocation() {
    // The fuzz artifact: unused records are skipped, the file then ends short.
    let found = b"\x89MCAP0\r\n\x00\x00\x00\x00\x00\x00\x00\x00\x00\x01\x05\x00\x00\x00\x00\x00\x00\x00\x7f\xff\xff\xff\xff\xff\xff\xff\x00\x00";
    let (messages, error) = read_bytes(found);
    assert!(messages.is_empty());
    assert!(error.is_some());
    // A Header (unused) claiming a 4 GiB profile string, then a good channel-less end.
    let mut header = u32::MAX.to_le_bytes().to_vec();
    header.extend_from_slice(b"x");
    let (messages, error) = read_bytes(&file_of(&[record(op::HEADER, &header)]));
    assert!(messages.is_empty());
    assert!(
        !matches!(error, Some(ReadError::Corrupt { .. })),
        "{error:?}"
    );
    // A Channel whose topic claims 4 GiB: corrupt, at the record's offset.
    let mut channel = vec![1, 0, 1, 0];
    channel.extend_from_slice(&u32::MAX.to_le_bytes());
    let (_, error) = read_bytes(&file_of(&[record(op::CHANNEL, &channel)]));
    match error {
        Some(ReadError::Corrupt { offset, detail }) => {
            assert_eq!(offset, 8);
            assert!(
                detail.contains("channel topic declares 4294967295 bytes"),
                "{detail}"
            );
        }
        other => panic!("{other:?}"),
    }
    // The same channel inside an uncompressed chunk: the chunk is refused.
    let inner = record(op::CHANNEL, &channel);
    let mut chunk = Vec::new();
    chunk.extend_from_slice(&0u64.to_le_bytes()); // message start time
    chunk.extend_from_slice(&0u64.to_le_bytes()); // message end time
    chunk.extend_from_slice(&(inner.len() as u64).to_le_bytes()); // uncompressed size
    chunk.extend_from_slice(&0u32.to_le_bytes()); // no CRC
    chunk.extend_from_slice(&0u32.to_le_bytes()); // compression "" (none)
    chunk.extend_from_slice(&(inner.len() as u64).to_le_bytes());
    chunk.extend_from_slice(&inner);
    let (_, error) = read_bytes(&file_of(&[record(op::CHUNK, &chunk)]));
    match error {
        Some(ReadError::Corrupt { offset, detail }) => {
            assert_eq!(offset, 8);
            assert!(detail.contains("channel topic declares"), "{detail}");
        }
        other => panic!("{other:?}"),
    }
}
