//! The recorder end to end on a private DDS domain (170): samples of every topic published,
//! recorded, read back by the reference Python MCAP reader and by ours, and replayed (an
//! acoustic recording in the same directory skipped with a note).
//!
//! Must run inside the private network namespace (`scripts/netns-run.sh`). The Python
//! check is skipped with the reason printed when `.venv` lacks `mcap`, unless
//! `SHOAL_INTEROP_REQUIRED=1`, when it fails.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use futures::StreamExt;
use serde_json::Value;
use shoal_dds::{DdsConfig, Priority, PubSub, TopicType, Writer, WriterOptions};
use shoal_model::{
    EnvironmentObservation, Event, EventKind, Severity, StateVector, Task, TaskAssignment,
    TaskState, TaskStatus, VehicleAnnouncement, VehicleKind,
};
use shoal_recorder::{
    McapMessages, Publishers, Recorder, RecorderConfig, ReplayOptions, Replayer, Sample, Speed,
    Topic,
};
use tokio_util::sync::CancellationToken;

const DOMAIN: u16 = 170;

fn dds() -> PubSub {
    PubSub::new(&DdsConfig {
        domain_id: DOMAIN,
        ..DdsConfig::default()
    })
    .unwrap()
}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The venv's Python if it can import `mcap`; else the test is skipped (or fails when
/// interop is required).
fn python_with_mcap() -> Option<PathBuf> {
    let python = repo().join(".venv/bin/python");
    let reason = if !python.exists() {
        format!(
            "{} not found: run scripts/install-test-deps.sh",
            python.display()
        )
    } else {
        let ok = std::process::Command::new(&python)
            .args(["-c", "import mcap"])
            .status()
            .is_ok_and(|s| s.success());
        if ok {
            return Some(python);
        }
        "the Python package mcap is not installed in .venv".to_string()
    };
    assert!(
        std::env::var("SHOAL_INTEROP_REQUIRED").as_deref() != Ok("1"),
        "the Python MCAP reader is required (SHOAL_INTEROP_REQUIRED=1) but cannot run: {reason}"
    );
    eprintln!("SKIPPED: the Python MCAP reader check: {reason}");
    None
}

fn check_mcap(python: &Path, file: &Path, mode: &str) -> Value {
    let out = std::process::Command::new(python)
        .arg(repo().join("tests/recorder/check_mcap.py"))
        .arg(file)
        .arg(mode)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

const T0: i64 = 1_780_000_000_000;

fn state(i: u32) -> StateVector {
    StateVector {
        vehicle_id: "rec-1".into(),
        timestamp_ms: T0 + i64::from(i) * 20,
        latitude_deg: 63.44 + f64::from(i) * 1e-5,
        longitude_deg: 10.39,
        depth_m: 5.0 + f64::from(i) * 0.1,
        altitude_m: shoal_model::UNKNOWN,
        speed_mps: 1.2,
        yaw_deg: 45.0,
        pitch_deg: -2.0,
        roll_deg: 1.0,
        battery_pct: 90.0 - f64::from(i) * 0.01,
    }
}

/// What is published: per topic, in order.
fn samples() -> Vec<Sample> {
    let mut out = vec![Sample::VehicleAnnouncement(VehicleAnnouncement {
        vehicle_id: "rec-1".into(),
        name: "recorded AUV".into(),
        kind: VehicleKind::Auv,
        vendor: "test".into(),
        capabilities: vec!["goto".into(), "hold".into()],
        sensors: vec!["ctd".into()],
        links: vec![shoal_model::LinkKind::Ip],
        max_speed_mps: 2.0,
        timestamp_ms: T0,
    })];
    out.extend((0..50).map(|i| Sample::StateVector(state(i))));
    out.push(Sample::TaskAssignment(TaskAssignment::new(
        "rec-task-1",
        "rec-m",
        "rec-1",
        T0,
        &Task::Hold { duration_s: 10.0 },
    )));
    for (i, st) in [TaskState::Accepted, TaskState::Running]
        .into_iter()
        .enumerate()
    {
        out.push(Sample::TaskStatus(TaskStatus {
            task_id: "rec-task-1".into(),
            vehicle_id: "rec-1".into(),
            timestamp_ms: T0 + i as i64,
            state: st,
            progress_pct: 10.0 * i as f64,
            message: String::new(),
        }));
    }
    for i in 0..3 {
        out.push(Sample::Event(Event {
            event_id: format!("rec-ev-{i}"),
            timestamp_ms: T0 + i,
            severity: Severity::Info,
            kind: EventKind::Other,
            vehicle_id: if i == 0 {
                String::new()
            } else {
                "rec-1".into()
            },
            task_id: String::new(),
            text: format!("event {i}"),
        }));
    }
    for i in 0..4 {
        out.push(Sample::Environment(EnvironmentObservation {
            vehicle_id: "rec-1".into(),
            property: format!("prop_{i}"),
            timestamp_ms: T0 + i,
            value: 7.0 + i as f64,
            unit: "Cel".into(),
            latitude_deg: 63.44,
            longitude_deg: 10.39,
            depth_m: 5.0,
        }));
    }
    out
}

fn expected_counts(samples: &[Sample]) -> Vec<(Topic, u64)> {
    Topic::ALL
        .iter()
        .map(|t| {
            (
                *t,
                samples.iter().filter(|s| s.topic() == *t).count() as u64,
            )
        })
        .collect()
}

struct Writers {
    sv: Writer<StateVector>,
    va: Writer<VehicleAnnouncement>,
    ta: Writer<TaskAssignment>,
    ts: Writer<TaskStatus>,
    ev: Writer<Event>,
    env: Writer<EnvironmentObservation>,
}

fn opts<T: TopicType>() -> WriterOptions {
    WriterOptions::new(T::DEFAULT_PRIORITY)
}

impl Writers {
    fn new(dds: &PubSub) -> Self {
        Self {
            sv: dds.writer(opts::<StateVector>()).unwrap(),
            va: dds.writer(opts::<VehicleAnnouncement>()).unwrap(),
            ta: dds.writer(opts::<TaskAssignment>()).unwrap(),
            ts: dds.writer(opts::<TaskStatus>()).unwrap(),
            ev: dds.writer(WriterOptions::new(Priority::Control)).unwrap(),
            env: dds.writer(opts::<EnvironmentObservation>()).unwrap(),
        }
    }

    fn all_matched(&self) -> bool {
        [
            self.sv.matched_readers(),
            self.va.matched_readers(),
            self.ta.matched_readers(),
            self.ts.matched_readers(),
            self.ev.matched_readers(),
            self.env.matched_readers(),
        ]
        .iter()
        .all(|n| *n >= 1)
    }

    async fn write(&self, s: Sample) {
        match s {
            Sample::StateVector(s) => self.sv.write(s).await.unwrap(),
            Sample::VehicleAnnouncement(s) => self.va.write(s).await.unwrap(),
            Sample::TaskAssignment(s) => self.ta.write(s).await.unwrap(),
            Sample::TaskStatus(s) => self.ts.write(s).await.unwrap(),
            Sample::Event(s) => self.ev.write(s).await.unwrap(),
            Sample::Environment(s) => self.env.write(s).await.unwrap(),
        }
    }
}

async fn eventually(secs: u64, what: &str, mut check: impl FnMut() -> bool) {
    let deadline = Instant::now() + Duration::from_secs(secs);
    while !check() {
        assert!(
            Instant::now() < deadline,
            "timed out after {secs} s waiting for {what}"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_topic_is_recorded_read_by_the_reference_reader_and_replayed() {
    let dir = tempfile::tempdir().unwrap();
    let config = RecorderConfig {
        directory: dir.path().join("rec"),
        ..RecorderConfig::default()
    };
    let rec_dds = dds();
    let recorder = Recorder::start(&rec_dds, &config).unwrap();
    let pub_dds = dds();
    let writers = Writers::new(&pub_dds);
    eventually(10, "the recorder's readers to match", || {
        writers.all_matched()
    })
    .await;

    let published = samples();
    let total = published.len() as u64;
    for s in published.clone() {
        writers.write(s).await;
        // State vectors 20 ms apart: the replay's pace is measured on them.
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    eventually(10, "every sample to be recorded", || {
        recorder.stats().received >= total
    })
    .await;
    let stats = recorder.stop().await.unwrap();
    assert_eq!(stats.messages, total);
    assert_eq!(stats.dropped, 0);
    assert_eq!(stats.files, 1);
    drop(writers);
    drop(pub_dds);
    drop(rec_dds);

    let file = shoal_recorder::mcap_files(&config.directory)
        .unwrap()
        .remove(0);
    assert_eq!(stats.bytes, std::fs::metadata(&file).unwrap().len());

    // Our reader: the same samples, per topic in publication order, with times.
    let recorded: Vec<_> = McapMessages::new(std::fs::File::open(&file).unwrap())
        .collect::<Result<_, _>>()
        .unwrap();
    for topic in Topic::ALL {
        let sent: Vec<&Sample> = published.iter().filter(|s| s.topic() == topic).collect();
        let got: Vec<Sample> = recorded
            .iter()
            .filter(|m| m.topic == topic)
            .map(|m| shoal_recorder::decode_message(m).unwrap())
            .collect();
        assert_eq!(got.iter().collect::<Vec<_>>(), sent, "{topic:?}");
    }
    for m in &recorded {
        assert!(m.publish_time_ns > 0 && m.publish_time_ns <= m.log_time_ns + 1_000_000);
    }

    // The reference reader, through the summary as a viewer reads a complete file.
    if let Some(python) = python_with_mcap() {
        let v = check_mcap(&python, &file, "summary");
        assert_eq!(v["error"], Value::Null, "{v}");
        assert_eq!(v["statistics_count"], total, "{v}");
        for (topic, n) in expected_counts(&published) {
            assert_eq!(v["counts"][topic.name()], n, "{}: {v}", topic.name());
            assert_eq!(v["channels"][topic.name()]["schema"], topic.type_name());
            assert_eq!(v["channels"][topic.name()]["message_encoding"], "cdr");
        }
        let schemas = v["schemas"].as_object().unwrap();
        assert_eq!(schemas.len(), 6);
        for s in schemas.values() {
            assert_eq!(s["encoding"], "omgidl");
            assert_eq!(s["idl_has_module"], true);
        }
        assert_eq!(v["cdr_headers"], serde_json::json!(["00010000"]));
        let states: Vec<Value> = (0..50)
            .map(|i| {
                let s = state(i);
                serde_json::json!([s.vehicle_id, s.timestamp_ms, s.latitude_deg.to_bits()])
            })
            .collect();
        assert_eq!(v["state_vectors"], Value::Array(states));
        let stream = check_mcap(&python, &file, "stream");
        assert_eq!(stream["error"], Value::Null, "{stream}");
        assert_eq!(stream["counts"], v["counts"]);
    }

    // An acoustic recording beside it (`[recorder] acoustic`): not DDS topics, so replay
    // skips its channels and says so once.
    let mut acoustic = shoal_recorder::AcousticWriter::new(&config).unwrap();
    for message_id in 1..=3 {
        let record = shoal_converter::TapRecord::now(
            1,
            T0,
            shoal_converter::TapEvent::Fate {
                message_id,
                fate: shoal_converter::MessageFate::Delivered,
            },
        );
        acoustic.write(&record).unwrap();
    }
    acoustic.close().unwrap();
    assert_eq!(
        shoal_recorder::mcap_files(&config.directory).unwrap().len(),
        2
    );

    // Replay at 5x onto the domain: a subscriber gets every state vector, at the pace.
    let sub_dds = dds();
    let mut states = sub_dds.subscribe::<StateVector>().unwrap();
    let mut events = sub_dds.subscribe::<Event>().unwrap();
    let replay_dds = Arc::new(dds());
    let mut replayer = Replayer::new(
        Publishers::insecure(replay_dds).unwrap(),
        ReplayOptions {
            speed: Speed::factor(5.0).unwrap(),
            ..ReplayOptions::default()
        },
    );
    let notes = Arc::new(std::sync::Mutex::new(Vec::new()));
    {
        let notes = Arc::clone(&notes);
        replayer.on_skipped_channels(move |file, topics| {
            notes
                .lock()
                .unwrap()
                .push((file.to_path_buf(), topics.to_vec()));
        });
    }
    let span_ns = recorded.last().unwrap().log_time_ns - recorded[0].log_time_ns;
    let started = Instant::now();
    let damaged = replayer
        .replay_path(&config.directory, &CancellationToken::new())
        .await
        .unwrap();
    let took = started.elapsed();
    assert!(damaged.is_empty());
    assert!(
        took >= Duration::from_nanos(span_ns / 5) * 9 / 10,
        "5x of {span_ns} ns took only {took:?}"
    );
    let s = replayer.stats();
    assert_eq!(s.read, total);
    assert_eq!(
        s.tasks_skipped, 1,
        "task assignments are held back by default"
    );
    assert_eq!(s.published, total - 1);
    assert_eq!(
        (s.invalid, s.undecodable, s.unknown, s.write_failed),
        (0, 0, 3, 0)
    );
    let notes = notes.lock().unwrap().clone();
    assert_eq!(notes.len(), 1, "{notes:?}");
    assert!(notes[0].0.to_string_lossy().contains("shoal-acoustic-"));
    assert_eq!(notes[0].1, ["acoustic/frame", "acoustic/link_event"]);
    let mut got = Vec::new();
    while got.len() < 50 {
        let item = tokio::time::timeout(Duration::from_secs(10), states.next())
            .await
            .expect("the replayed state vectors")
            .unwrap()
            .unwrap();
        got.push(item.0.into_inner());
    }
    assert_eq!(got, (0..50).map(state).collect::<Vec<_>>());
    let mut got_events = Vec::new();
    while got_events.len() < 3 {
        let item = tokio::time::timeout(Duration::from_secs(10), events.next())
            .await
            .expect("the replayed events")
            .unwrap()
            .unwrap();
        got_events.push(item.0.into_inner().event_id);
    }
    got_events.sort();
    assert_eq!(got_events, ["rec-ev-0", "rec-ev-1", "rec-ev-2"]);
}
