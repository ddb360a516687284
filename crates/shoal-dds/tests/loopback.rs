//! Publish/Subscribe Manager over real RTPS on loopback.
//!
//! These open DDS participants: run them inside the test network namespace
//! (`scripts/netns-run.sh`), as the README's test command does. Each test uses its own
//! domain id so that tests running in parallel never see each other.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::time::Duration;

use futures::StreamExt;
use shoal_dds::{Priority, PubSub, ReadError, WriterOptions};
use shoal_model::{Event, EventKind, Severity, StateVector, Task, TaskAssignment, TaskKind};

mod common;
use common::{Foreign, config};

fn state(i: u32) -> StateVector {
    common::state_at("auv-7", 1_700_000_000_000 + i64::from(i))
}

async fn wait_matched<T: shoal_dds::TopicType>(w: &shoal_dds::Writer<T>) {
    for _ in 0..200 {
        if w.matched_readers() > 0 {
            return;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    panic!("no reader matched within 10 s");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn state_vectors_arrive_in_order_and_complete() {
    let a = PubSub::new(&config(40)).unwrap();
    let b = PubSub::new(&config(40)).unwrap();
    let mut sub = b.subscribe::<StateVector>().unwrap();
    let w = a
        .writer::<StateVector>(WriterOptions::new(Priority::Telemetry))
        .unwrap();
    wait_matched(&w).await;
    // Discovery is asymmetric: the writer may know the reader before the reader knows the
    // writer and accepts its data. Probe until one sample arrives, then test ordering.
    let mut probe = state(0);
    probe.timestamp_ms -= 1;
    loop {
        w.write(probe.clone()).await.unwrap();
        if let Ok(got) = tokio::time::timeout(Duration::from_millis(200), sub.next()).await {
            got.unwrap().unwrap();
            break;
        }
    }
    while let Ok(Some(_)) = tokio::time::timeout(Duration::from_millis(300), sub.next()).await {}
    // Reliable keep-last delivers every sample the writer's history still holds: a burst
    // no deeper than the state profile's history (64) must arrive whole and in order.
    for i in 0..60 {
        w.write(state(i)).await.unwrap();
    }
    for i in 0..60 {
        let (s, meta) = tokio::time::timeout(Duration::from_secs(10), sub.next())
            .await
            .expect("timed out")
            .unwrap()
            .unwrap();
        assert_eq!(s.timestamp_ms, state(i).timestamp_ms);
        assert!(!meta.writer.is_empty());
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn invalid_samples_are_refused_by_the_writer_and_handed_back() {
    let a = PubSub::new(&config(41)).unwrap();
    let w = a
        .writer::<StateVector>(WriterOptions::new(Priority::Telemetry))
        .unwrap();
    let mut bad = state(0);
    bad.latitude_deg = f64::NAN;
    let err = w.write(bad).await.unwrap_err();
    assert!(err.to_string().contains("latitude_deg"));
    assert!(err.into_sample().latitude_deg.is_nan());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_late_joining_reader_still_gets_transient_local_tasks() {
    let station = PubSub::new(&config(42)).unwrap();
    let w = station
        .writer::<TaskAssignment>(WriterOptions::new(Priority::Control))
        .unwrap();
    let task = TaskAssignment::new("t-late", "m1", "auv-7", 1_700_000_000_000, &Task::Surface);
    w.write(task.clone()).await.unwrap();
    // The vehicle joins only after the task was published.
    tokio::time::sleep(Duration::from_millis(300)).await;
    let vehicle = PubSub::new(&config(42)).unwrap();
    let mut sub = vehicle.subscribe::<TaskAssignment>().unwrap();
    let (got, _) = tokio::time::timeout(Duration::from_secs(15), sub.next())
        .await
        .expect("late joiner got no task")
        .unwrap()
        .unwrap();
    assert_eq!(*got, task);
    assert_eq!(got.kind, TaskKind::Surface);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_disposed_task_is_not_handed_to_late_joiners_and_a_live_one_is() {
    let station = PubSub::new(&config(48)).unwrap();
    let w = station
        .writer::<TaskAssignment>(WriterOptions::new(Priority::Control))
        .unwrap();
    // A reader matched before the dispose gets the task, then nothing more: the dispose
    // carries no data and must not surface as a sample or an error.
    let early = PubSub::new(&config(48)).unwrap();
    let mut early_sub = early.subscribe::<TaskAssignment>().unwrap();
    let ended = TaskAssignment::new("t-ended", "m1", "auv-7", 1_700_000_000_000, &Task::Surface);
    let live = TaskAssignment::new("t-live", "m1", "auv-7", 1_700_000_000_001, &Task::Surface);
    w.write(ended.clone()).await.unwrap();
    let (got, _) = tokio::time::timeout(Duration::from_secs(15), early_sub.next())
        .await
        .expect("matched reader got no task")
        .unwrap()
        .unwrap();
    assert_eq!(got.task_id, "t-ended");
    w.dispose(&ended).unwrap();
    w.write(live.clone()).await.unwrap();
    let (got, _) = tokio::time::timeout(Duration::from_secs(15), early_sub.next())
        .await
        .expect("matched reader got no second task")
        .unwrap()
        .unwrap();
    assert_eq!(got.task_id, "t-live", "the dispose surfaced as a sample");

    tokio::time::sleep(Duration::from_millis(300)).await;
    let vehicle = PubSub::new(&config(48)).unwrap();
    let mut sub = vehicle.subscribe::<TaskAssignment>().unwrap();
    let (got, _) = tokio::time::timeout(Duration::from_secs(15), sub.next())
        .await
        .expect("late joiner got no task")
        .unwrap()
        .unwrap();
    assert_eq!(*got, live, "the disposed task was handed to a late joiner");
    let more = tokio::time::timeout(Duration::from_secs(1), sub.next()).await;
    assert!(
        more.is_err(),
        "a second task reached the late joiner: {more:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_task_disposed_before_the_reader_takes_it_is_not_handed_over() {
    // A reader that falls behind (or joins while the writer still holds samples for a
    // slower reader) has a task's data and its dispose waiting together: the task is
    // over, and the reader must not start it.
    let station = PubSub::new(&config(45)).unwrap();
    let w = station
        .writer::<TaskAssignment>(WriterOptions::new(Priority::Control))
        .unwrap();
    let vehicle = PubSub::new(&config(45)).unwrap();
    let mut sub = vehicle.subscribe::<TaskAssignment>().unwrap();
    wait_matched(&w).await;
    let gone = TaskAssignment::new("t-gone", "m1", "auv-7", 1_700_000_000_000, &Task::Surface);
    let live = TaskAssignment::new("t-live", "m1", "auv-7", 1_700_000_000_001, &Task::Surface);
    w.write(gone.clone()).await.unwrap();
    w.dispose(&gone).unwrap();
    w.write(live.clone()).await.unwrap();
    // Not polled until all three are in the reader's cache.
    tokio::time::sleep(Duration::from_millis(500)).await;
    let (got, _) = tokio::time::timeout(Duration::from_secs(15), sub.next())
        .await
        .expect("no task arrived")
        .unwrap()
        .unwrap();
    assert_eq!(got.task_id, "t-live", "a disposed task was handed over");

    // Other topics keep the data of an ended instance: an event disposed before it was
    // read is still delivered.
    let ew = station
        .writer::<Event>(WriterOptions::new(Priority::Control))
        .unwrap();
    let mut events = vehicle.subscribe::<Event>().unwrap();
    wait_matched(&ew).await;
    let e = Event {
        event_id: "e-1".into(),
        timestamp_ms: 1_700_000_000_000,
        severity: Severity::Info,
        kind: EventKind::Other,
        vehicle_id: "auv-7".into(),
        task_id: String::new(),
        text: "hello".into(),
    };
    ew.write(e.clone()).await.unwrap();
    ew.dispose(&e).unwrap();
    tokio::time::sleep(Duration::from_millis(500)).await;
    let (got, _) = tokio::time::timeout(Duration::from_secs(15), events.next())
        .await
        .expect("the ended event was dropped")
        .unwrap()
        .unwrap();
    assert_eq!(got.event_id, "e-1");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_writer_keeps_only_its_newest_instances_for_late_joiners() {
    let vehicle = PubSub::new(&config(50)).unwrap();
    let options = WriterOptions {
        kept_instances: Some(3),
        ..WriterOptions::new(Priority::Control)
    };
    let w = vehicle.writer::<Event>(options).unwrap();
    for i in 0..5 {
        w.write(Event {
            event_id: format!("e-{i}"),
            timestamp_ms: 1_700_000_000_000 + i,
            severity: Severity::Info,
            kind: EventKind::Other,
            vehicle_id: "auv-7".into(),
            task_id: String::new(),
            text: String::new(),
        })
        .await
        .unwrap();
    }
    tokio::time::sleep(Duration::from_millis(300)).await;
    let station = PubSub::new(&config(50)).unwrap();
    let mut sub = station.subscribe::<Event>().unwrap();
    let mut got = Vec::new();
    while let Ok(Some(item)) = tokio::time::timeout(Duration::from_secs(3), sub.next()).await {
        got.push(item.unwrap().0.event_id.clone());
    }
    got.sort();
    assert_eq!(got, ["e-2", "e-3", "e-4"]);
}

/// A foreign writer with another idea of the type: the reader reports it and goes on.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn malformed_foreign_samples_are_reported_and_do_not_block_good_ones() {
    use rustdds::Keyed;
    #[derive(serde::Serialize, serde::Deserialize, Clone, Debug)]
    struct Truncated {
        vehicle_id: String,
        timestamp_ms: i64,
    }
    impl Keyed for Truncated {
        type K = String;
        fn key(&self) -> String {
            self.vehicle_id.clone()
        }
    }
    let station = PubSub::new(&config(43)).unwrap();
    let mut sub = station.subscribe::<StateVector>().unwrap();

    let foreign = Foreign::new(43, "shoal/state_vector", "shoal::StateVector");
    let bad_writer = foreign
        .publisher
        .create_datawriter_cdr::<Truncated>(&foreign.topic, None)
        .unwrap();
    #[derive(serde::Serialize, serde::Deserialize, Clone, Debug)]
    #[serde(transparent)]
    struct Raw(StateVector);
    impl Keyed for Raw {
        type K = String;
        fn key(&self) -> String {
            self.0.vehicle_id.clone()
        }
    }
    // A NaN cannot go through a Shoal writer (it validates), so a raw writer sends it; it
    // is created before discovery is awaited, or its volatile sample would find no reader.
    let raw_writer = foreign
        .publisher
        .create_datawriter_cdr::<Raw>(&foreign.topic, None)
        .unwrap();

    let good = PubSub::new(&config(43)).unwrap();
    let good_writer = good
        .writer::<StateVector>(WriterOptions::new(Priority::Telemetry))
        .unwrap();
    wait_matched(&good_writer).await;
    tokio::time::sleep(Duration::from_millis(500)).await;

    bad_writer
        .write(
            Truncated {
                vehicle_id: "evil".into(),
                timestamp_ms: 1,
            },
            None,
        )
        .unwrap();
    let mut nan = state(1);
    nan.vehicle_id = "nan-1".into();
    nan.depth_m = f64::NAN;
    raw_writer.write(Raw(nan), None).unwrap();
    good_writer.write(state(2)).await.unwrap();

    let (mut malformed, mut invalid, mut good_seen) = (0, 0, false);
    while !(good_seen && malformed > 0 && invalid > 0) {
        match tokio::time::timeout(Duration::from_secs(10), sub.next())
            .await
            .expect("timed out")
            .unwrap()
        {
            Ok((s, _)) => {
                assert_eq!(s.vehicle_id, "auv-7");
                good_seen = true;
            }
            Err(ReadError::Malformed { .. }) => malformed += 1,
            Err(ReadError::Invalid { error, payload, .. }) => {
                assert!(payload.contains("nan-1"), "{payload}");
                assert_eq!(error.reason().to_string(), "not_finite:depth_m");
                invalid += 1;
            }
            Err(e) => panic!("unexpected {e}"),
        }
    }
}

/// A sample over `max_sample_bytes` is dropped before it is reassembled, counted against
/// its topic as malformed, and the good samples after it still arrive.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_oversize_foreign_sample_is_dropped_and_counted_and_good_ones_still_arrive() {
    use rustdds::Keyed;
    #[derive(serde::Serialize, serde::Deserialize, Clone, Debug)]
    struct Huge {
        vehicle_id: String,
        padding: String,
    }
    impl Keyed for Huge {
        type K = String;
        fn key(&self) -> String {
            self.vehicle_id.clone()
        }
    }
    let station = PubSub::new(&config(49)).unwrap();
    let mut sub = station.subscribe::<StateVector>().unwrap();
    let foreign = Foreign::new(49, "shoal/state_vector", "shoal::StateVector");
    let huge_writer = foreign
        .publisher
        .create_datawriter_cdr::<Huge>(&foreign.topic, None)
        .unwrap();
    let good = PubSub::new(&config(49)).unwrap();
    let good_writer = good
        .writer::<StateVector>(WriterOptions::new(Priority::Telemetry))
        .unwrap();
    wait_matched(&good_writer).await;
    tokio::time::sleep(Duration::from_millis(500)).await;
    huge_writer
        .write(
            Huge {
                vehicle_id: "evil".into(),
                padding: "x".repeat(1_000_000),
            },
            None,
        )
        .unwrap();
    good_writer.write(state(3)).await.unwrap();
    let (mut oversize, mut good_seen) = (false, false);
    while !(good_seen && oversize) {
        match tokio::time::timeout(Duration::from_secs(15), sub.next())
            .await
            .unwrap_or_else(|_| panic!("timed out: good {good_seen}, oversize {oversize}"))
            .unwrap()
        {
            Ok((s, _)) => {
                assert_eq!(s.vehicle_id, "auv-7");
                good_seen = true;
            }
            Err(ReadError::Malformed { detail, .. }) => {
                assert!(detail.contains("oversize"), "{detail}");
                oversize = true;
            }
            Err(e) => panic!("unexpected {e}"),
        }
    }
}

/// Regression: a writer of many instances leaving left the reader one state-change
/// (invalid) sample per instance; a take of 64 of them handed nothing on and no new
/// data-available came for the rest, so the subscription stalled and a live writer's
/// samples were never handed on again (found by the station's attack test: 100,000 made-up
/// vehicles, then their participant left). Domain 152.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn many_instances_ending_at_once_do_not_stall_the_subscription() {
    const INSTANCES: u32 = 2_000;
    let station = PubSub::new(&config(152)).unwrap();
    let mut sub = station.subscribe::<StateVector>().unwrap();
    let good = PubSub::new(&config(152)).unwrap();
    let good_writer = good
        .writer::<StateVector>(WriterOptions::new(Priority::Telemetry))
        .unwrap();
    let many = PubSub::new(&config(152)).unwrap();
    let many_writer = many
        .writer::<StateVector>(WriterOptions::new(Priority::Telemetry))
        .unwrap();
    wait_matched(&good_writer).await;
    wait_matched(&many_writer).await;
    tokio::time::sleep(Duration::from_millis(500)).await;
    for i in 0..INSTANCES {
        many_writer
            .write(common::state_at(&format!("many-{i}"), 1_700_000_000_000))
            .await
            .unwrap();
    }
    let mut seen = 0;
    while seen < INSTANCES {
        let (s, _) = tokio::time::timeout(Duration::from_secs(10), sub.next())
            .await
            .unwrap_or_else(|_| panic!("{seen} of {INSTANCES} instances arrived"))
            .unwrap()
            .unwrap();
        assert!(s.vehicle_id.starts_with("many-"));
        seen += 1;
    }
    // Every instance ends (no writer left) at once.
    drop(many_writer);
    drop(many);
    tokio::time::sleep(Duration::from_secs(1)).await;
    // The live writer is still heard, every sample.
    for i in 0..10 {
        good_writer.write(state(i)).await.unwrap();
        let (s, _) = tokio::time::timeout(Duration::from_secs(5), sub.next())
            .await
            .unwrap_or_else(|_| panic!("sample {i} of the live writer never arrived"))
            .unwrap()
            .unwrap();
        assert_eq!(s.vehicle_id, "auv-7");
    }
}

#[test]
fn the_wire_bytes_are_plain_little_endian_cdr() {
    let bytes = shoal_dds::to_cdr_le(&state(0)).unwrap();
    // encapsulation CDR_LE, then the key string: length 6 ("auv-7" + NUL)
    assert_eq!(&bytes[..4], &[0, 1, 0, 0]);
    assert_eq!(&bytes[4..8], &6u32.to_le_bytes());
    assert_eq!(&bytes[8..14], b"auv-7\0");
    // int64 timestamp aligned to 8 relative to the start of the CDR body (XCDR1)
    assert_eq!(&bytes[4 + 16..4 + 24], &1_700_000_000_000i64.to_le_bytes());
    // 11 fields: 12 (string+pad) + 4 pad.. = 16 + 8 + 9 * 8 = 96 bytes of body
    assert_eq!(bytes.len() - 4, 96);
}

/// Every Shoal topic type becomes a DDS type Cyclone accepts (signed twins too), and a
/// sample of each crosses: the layout traced from serde matches the bytes serde writes.
#[tokio::test(flavor = "multi_thread")]
async fn every_topic_type_is_accepted_by_dds_and_crosses() {
    use shoal_model::{EnvironmentObservation, Event, TaskStatus, VehicleAnnouncement};
    let dds = PubSub::new(&config(44)).unwrap();
    dds.writer::<VehicleAnnouncement>(WriterOptions::new(Priority::Control))
        .unwrap();
    dds.writer::<TaskAssignment>(WriterOptions::new(Priority::Control))
        .unwrap();
    dds.writer::<TaskStatus>(WriterOptions::new(Priority::Control))
        .unwrap();
    dds.writer::<Event>(WriterOptions::new(Priority::Control))
        .unwrap();
    dds.writer::<EnvironmentObservation>(WriterOptions::new(Priority::Bulk))
        .unwrap();
    dds.subscribe::<VehicleAnnouncement>().unwrap();
    let announcement: VehicleAnnouncement = serde_json::from_value(serde_json::json!({
        "vehicle_id": "auv-9", "name": "Nine", "kind": "glider", "vendor": "acme",
        "capabilities": ["goto", "survey"], "sensors": ["ctd"], "links": ["ip", "acoustic"],
        "max_speed_mps": 1.5, "timestamp_ms": 1_700_000_000_000i64
    }))
    .unwrap();
    let w = dds
        .writer_on::<VehicleAnnouncement>("test/announce", WriterOptions::new(Priority::Control))
        .unwrap();
    let mut sub = dds
        .subscribe_on::<VehicleAnnouncement>("test/announce")
        .unwrap();
    w.write(announcement.clone()).await.unwrap();
    let (got, _) = tokio::time::timeout(Duration::from_secs(10), sub.next())
        .await
        .expect("timed out")
        .unwrap()
        .unwrap();
    assert_eq!(*got, announcement);
}

/// A listening reader hands every sample to its function as it is delivered, in order,
/// and the function can answer at once with a blocking write; an invalid sample reaches
/// it as an error and the next good one still comes. (Both participants are in this
/// process, so Cyclone delivers in the writing task's thread, not its receive thread.)
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_listener_gets_every_sample_on_the_receive_thread_and_can_answer_there() {
    const ECHO: &str = "shoal/test/echo";
    let a = PubSub::new(&config(153)).unwrap();
    let b = PubSub::new(&config(153)).unwrap();
    let echo = std::sync::Arc::new(
        a.writer_on::<StateVector>(ECHO, WriterOptions::new(Priority::Telemetry))
            .unwrap(),
    );
    let (tx, rx) = std::sync::mpsc::channel();
    let answer = std::sync::Arc::clone(&echo);
    let _listening = a
        .listen::<StateVector, _>(move |delivery| {
            if let Ok((s, _)) = &delivery {
                answer.write_blocking(s.clone().into_inner()).unwrap();
            }
            let _ = tx.send(delivery.map(|(s, _)| s.into_inner()));
        })
        .unwrap();
    let mut echoes = b.subscribe_on::<StateVector>(ECHO).unwrap();
    let w = b
        .writer::<StateVector>(WriterOptions::new(Priority::Telemetry))
        .unwrap();
    wait_matched(&w).await;
    wait_matched(&echo).await;
    // As in the first test: probe until the reader knows the writer.
    let mut probe = state(0);
    probe.timestamp_ms -= 1;
    loop {
        w.write(probe.clone()).await.unwrap();
        if let Ok(got) = tokio::time::timeout(Duration::from_millis(200), echoes.next()).await {
            got.unwrap().unwrap();
            break;
        }
    }
    while let Ok(Some(_)) = tokio::time::timeout(Duration::from_millis(300), echoes.next()).await {}
    while rx.try_recv().is_ok() {}

    for i in 0..40 {
        w.write(state(i)).await.unwrap();
    }
    let mut nan = state(40);
    nan.depth_m = f64::NAN;
    w.write_unchecked(nan).await.unwrap();
    w.write(state(41)).await.unwrap();

    for i in 0..42 {
        let got = tokio::task::block_in_place(|| rx.recv_timeout(Duration::from_secs(10)))
            .unwrap_or_else(|_| panic!("delivery {i} never came"));
        match got {
            Ok(s) => assert_eq!(s.timestamp_ms, state(i).timestamp_ms, "delivery {i}"),
            Err(ReadError::Invalid { error, .. }) => {
                assert_eq!(i, 40);
                assert_eq!(error.reason().to_string(), "not_finite:depth_m");
            }
            Err(e) => panic!("unexpected {e}"),
        }
    }
    for i in (0..40).chain([41]) {
        let (s, _) = tokio::time::timeout(Duration::from_secs(10), echoes.next())
            .await
            .unwrap_or_else(|_| panic!("echo of {i} never came"))
            .unwrap()
            .unwrap();
        assert_eq!(s.timestamp_ms, state(i).timestamp_ms);
    }
}
