//! The relay's CDT recorded (`[recorder] acoustic`): `shoal up`'s acoustic demo topology
//! with the CDT's frame tap feeding `shoal-recorder`'s acoustic recorder, and the file
//! read back by the reference Python MCAP reader, each message checked against its JSON
//! Schema. Domains 216 (the AUV's private domain) and 217 (station).

use std::path::PathBuf;

use shoal_dds::{DdsConfig, Priority, WriterOptions};
use shoal_model::{StateVector, TaskAssignment, TaskState, TaskStatus};
use shoal_recorder::{AcousticRecorder, RecorderConfig};
use tokio_util::sync::CancellationToken;

use super::common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn the_relays_frames_and_link_events_are_recorded_and_read_by_the_reference_reader() {
    let dir = tempfile::tempdir().unwrap();
    let config = RecorderConfig {
        directory: dir.path().to_path_buf(),
        acoustic: true,
        ..RecorderConfig::default()
    };
    let (recorder, tap) = AcousticRecorder::start(&config).unwrap();
    let station_cfg = DdsConfig {
        domain_id: 217,
        ..DdsConfig::default()
    };
    let (mut demo, sim) = demo_relay(216, SCALE);
    demo.tap = Some(tap);
    let id = sim.id.clone();
    let station = participant(217);
    let mut states = station.subscribe::<StateVector>().unwrap();
    let mut status = station.subscribe::<TaskStatus>().unwrap();
    let shutdown = CancellationToken::new();
    let run = {
        let shutdown = shutdown.clone();
        tokio::spawn(async move { run_relayed_sim(demo, sim, station_cfg, shutdown).await })
    };

    wait_for(&mut states, 60, "the AUV's state", |s: &StateVector, _| {
        s.vehicle_id == id
    })
    .await;
    // A task down the link: the CDT sends it, the vehicle's modem acknowledges it.
    let writer = station
        .writer::<TaskAssignment>(WriterOptions::new(Priority::Control))
        .unwrap();
    let mut task = goto_task("t-recorded");
    task.vehicle_id.clone_from(&id);
    task.area[0].latitude_deg = 63.468;
    task.area[0].longitude_deg = 10.373;
    writer.write(task).await.unwrap();
    wait_for(&mut status, 60, "task running", |s: &TaskStatus, _| {
        s.task_id == "t-recorded" && s.state == TaskState::Running
    })
    .await;

    shutdown.cancel();
    within(20, "relay stop", run).await.unwrap().unwrap();
    // The relay is gone, its tap with it: the recorder closes its file at once.
    let stats = within(10, "the acoustic recorder", recorder.stop())
        .await
        .unwrap();
    assert_eq!(stats.dropped, 0, "{stats:?}");
    assert!(stats.messages >= 5, "{stats:?}");
    assert_eq!(stats.messages, stats.received);

    let files: Vec<PathBuf> = shoal_recorder::mcap_files(dir.path()).unwrap();
    assert_eq!(files.len() as u64, stats.files);
    for f in &files {
        let name = f.file_name().unwrap().to_string_lossy().into_owned();
        assert!(name.starts_with("shoal-acoustic-"), "{name}");
    }
    // The DDS side's reader (and so `shoal replay`) skips these channels, naming them.
    let mut dds_reader = shoal_recorder::McapMessages::new(std::fs::File::open(&files[0]).unwrap());
    assert_eq!(dds_reader.by_ref().count(), 0);
    assert_eq!(
        dds_reader.unknown_topics(),
        ["acoustic/frame", "acoustic/link_event"]
    );

    let Some(python) = crate::recorder::python_with_mcap() else {
        return;
    };
    let found = crate::recorder::check_acoustic_mcap(&python, &files);
    let schema = |topic: &str| found["schemas"][topic].clone();
    assert_eq!(
        schema("acoustic/frame"),
        serde_json::json!({"name": "shoal.acoustic.Frame", "encoding": "jsonschema", "title": "shoal.acoustic.Frame"})
    );
    assert_eq!(
        schema("acoustic/link_event")["name"],
        "shoal.acoustic.LinkEvent"
    );
    assert_eq!(found["message_encodings"]["acoustic/frame"], "json");
    let count = |topic: &str| found["counts"][topic].as_u64().unwrap_or(0);
    assert_eq!(
        count("acoustic/frame") + count("acoustic/link_event"),
        stats.messages,
        "{found}"
    );
    assert!(found["log_times_ordered"].as_bool().unwrap(), "{found}");
    // The AUV's frames came in from its modem (address 2), with the modem's RSSI, and
    // carried its states.
    assert_eq!(found["received_from"], serde_json::json!([2]), "{found}");
    assert!(found["rssi_seen"].as_bool().unwrap(), "{found}");
    let pdus = |t: &str| found["pdu_types"][t].as_u64().unwrap_or(0);
    assert!(pdus("state_keyframe") >= 1, "{found}");
    assert_eq!(found["decode_errors"], 0, "{found}");
    // What the CDT sent: keyframe acks and the task, each named again by its fate; the
    // task was delivered (acknowledged by the AUV's modem).
    assert!(pdus("ack") >= 1 && pdus("identified_task") >= 1, "{found}");
    let sent: Vec<u64> = found["sent_ids"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(serde_json::Value::as_u64)
        .collect();
    let fates: Vec<u64> = found["event_ids"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(serde_json::Value::as_u64)
        .collect();
    assert!(fates.iter().all(|id| sent.contains(id)), "{found}");
    assert!(
        found["events"]["delivered"].as_u64().unwrap_or(0) >= 1,
        "{found}"
    );
    // Every message matched its channel's JSON Schema (when the venv has jsonschema, as
    // the test command's does).
    assert_eq!(found["invalid"], serde_json::json!([]), "{found}");
    if !found["validated"].as_bool().unwrap() {
        eprintln!(
            "NOTE: the acoustic messages were not checked against their JSON Schemas: no jsonschema in .venv"
        );
    }
}
