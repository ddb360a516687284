//! `run_emulated_relay` as `shoal up`'s acoustic demo runs it: the SWARMs relay topology,
//! seen from the station's domain only. Domains 105 (the AUV's private domain) and 106
//! (station).

use shoal_converter::LinkStatus;
use shoal_dds::{DdsConfig, Priority, WriterOptions};
use shoal_model::{Event, StateVector, TaskAssignment, TaskState, TaskStatus};
use tokio_util::sync::CancellationToken;

use super::common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn the_demo_auv_reports_to_the_station_only_through_the_relay() {
    let station_cfg = DdsConfig {
        domain_id: 106,
        ..DdsConfig::default()
    };
    let (demo, sim) = demo_relay(105, SCALE);
    let id = sim.id.clone();

    // The station's domain must be refused as the vehicle's private one.
    let mut clash = demo.clone();
    clash.vehicles[0].domain_id = 106;
    assert!(clash.check(&station_cfg).is_err());

    let station = participant(106);
    let mut states = station.subscribe::<StateVector>().unwrap();
    let mut events = station.subscribe::<Event>().unwrap();
    let mut status = station.subscribe::<TaskStatus>().unwrap();
    let shutdown = CancellationToken::new();
    let run = {
        let shutdown = shutdown.clone();
        tokio::spawn(async move { run_relayed_sim(demo, sim, station_cfg, shutdown).await })
    };

    let (_, meta) = wait_for(&mut states, 60, "demo AUV state", |s: &StateVector, _| {
        s.vehicle_id == id
    })
    .await;
    let (ev, _) = wait_for(&mut events, 60, "link status", |e: &Event, _| {
        e.event_id == LinkStatus::event_id(&id)
    })
    .await;
    let link = LinkStatus::from_event(&ev).unwrap();
    assert!(
        link.wrote(&meta.writer),
        "state not written by the relay's CDT"
    );

    let writer = station
        .writer::<TaskAssignment>(WriterOptions::new(Priority::Control))
        .unwrap();
    let mut task = goto_task("t-relay");
    task.vehicle_id.clone_from(&id);
    // A waypoint near the demo AUV, off Trondheim.
    task.area[0].latitude_deg = 63.468;
    task.area[0].longitude_deg = 10.373;
    writer.write(task).await.unwrap();
    wait_for(&mut status, 60, "task running", |s: &TaskStatus, _| {
        s.task_id == "t-relay" && s.state == TaskState::Running
    })
    .await;

    shutdown.cancel();
    within(20, "demo stop", run).await.unwrap().unwrap();
}
