//! AUV on DDS domain A → VDT → modem 2 → emulated sea → modem 1 → CDT → DDS domain B, and
//! tasks back. Domains 101 (vehicle side) and 102 (station side).

use std::sync::{Arc, Mutex};

use futures::StreamExt;
use shoal_converter::{LinkStatus, Modem, ModemKind, run_cdt, run_vdt};
use shoal_dds::{Priority, WriterOptions};
use shoal_model::{
    Event, LinkKind, StateVector, TaskAssignment, TaskState, TaskStatus, VehicleAnnouncement,
    VehicleKind,
};
use tokio_util::sync::CancellationToken;

use super::common::*;

/// True if `b` (received acoustically) is `a` within the PDU resolution: keyframe 1e-5°,
/// 0.1 m, 0.05 m/s, 0.5°, 1 %; deltas 2e-5°, 0.25 m/s, 3° (half a step each way, plus the
/// keyframe's own rounding).
fn within_resolution(a: &StateVector, b: &StateVector) -> bool {
    let yaw = (a.yaw_deg - b.yaw_deg).rem_euclid(360.0);
    a.vehicle_id == b.vehicle_id
        && a.timestamp_ms / 1000 == b.timestamp_ms / 1000
        && (a.latitude_deg - b.latitude_deg).abs() <= 2.1e-5
        && (a.longitude_deg - b.longitude_deg).abs() <= 2.1e-5
        && (a.depth_m - b.depth_m).abs() <= 0.16
        && (a.speed_mps - b.speed_mps).abs() <= 0.16
        && yaw.min(360.0 - yaw) <= 1.8
        && (a.pitch_deg - b.pitch_deg).abs() <= 1.3
        && (a.roll_deg - b.roll_deg).abs() <= 1.3
        && (a.battery_pct - b.battery_pct).abs() <= 1.5
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn state_and_announcement_cross_the_water_and_tasks_come_back() {
    let emu = emulator([(0, 0), (0, 0)]).await;
    let (cdt_modem, auv_modem) = (emu.modems()[0].clone(), emu.modems()[1].clone());
    let shutdown = CancellationToken::new();

    // Vehicle side (domain A = 101): the simulated AUV, the VDT, and an observer.
    let sim_dds = participant(101);
    let vdt_dds = participant(101);
    let observer_a = participant(101);
    // Station side (domain B = 102): the CDT and the "station".
    let cdt_dds = participant(102);
    let station = participant(102);

    let mut b_states = station.subscribe::<StateVector>().unwrap();
    let mut b_ann = station.subscribe::<VehicleAnnouncement>().unwrap();
    let mut b_status = station.subscribe::<TaskStatus>().unwrap();
    let mut b_events = station.subscribe::<Event>().unwrap();
    let mut a_tasks = observer_a.subscribe::<TaskAssignment>().unwrap();
    let a_seen: Arc<Mutex<Vec<StateVector>>> = Arc::default();
    {
        let mut a_states = observer_a.subscribe::<StateVector>().unwrap();
        let seen = a_seen.clone();
        tokio::spawn(async move {
            while let Some(Ok((s, _))) = a_states.next().await {
                seen.lock().unwrap().push(s.into_inner());
            }
        });
    }

    tokio::spawn(shoal_proxy::run_sim(auv(), sim_dds, shutdown.clone()));
    let vdt_cfg = vdt_config(ModemKind::EvinsNl, auv_modem.nl);
    let vdt_driver = Modem::start(&vdt_cfg.modem, SCALE);
    let vdt = tokio::spawn(run_vdt(vdt_cfg, vdt_dds, vdt_driver, shutdown.clone()));
    // Both speak EviNS NL here (the emulator reports a packet on the protocol it was sent
    // with); the reconnect and relay tests use EvoLogics AT.
    let cdt_cfg = cdt_config(ModemKind::EvinsNl, cdt_modem.nl);
    let cdt_driver = Modem::start(&cdt_cfg.modem, SCALE);
    let cdt = tokio::spawn(run_cdt(
        cdt_cfg,
        cdt_dds.clone(),
        cdt_driver,
        shutdown.clone(),
    ));

    // The announcement arrives, compacted: id, kind, known capabilities, links.
    let (ann, _) = wait_for(
        &mut b_ann,
        60,
        "announcement on B",
        |a: &VehicleAnnouncement, _| a.vehicle_id == "auv-1",
    )
    .await;
    assert_eq!(ann.kind, VehicleKind::Auv);
    assert!(ann.capabilities.iter().any(|c| c == "goto"), "{ann:?}");
    assert!(ann.links.contains(&LinkKind::Acoustic));
    assert!((ann.max_speed_mps - 2.5).abs() < 0.06);

    // Several state vectors arrive (the first a keyframe, later ones deltas once the
    // keyframe is acknowledged), each equal to a published one within PDU resolution.
    let mut received = Vec::new();
    while received.len() < 6 {
        let (s, meta) = wait_for(
            &mut b_states,
            60,
            "state vector on B",
            |s: &StateVector, _| s.vehicle_id == "auv-1",
        )
        .await;
        received.push((s, meta));
    }
    {
        let seen = a_seen.lock().unwrap();
        for (b, _) in &received {
            assert!(
                seen.iter().any(|a| within_resolution(a, b)),
                "{b:?} matches no published state"
            );
        }
    }

    // The link table says auv-1 is acoustic, and the states were written by that CDT.
    let (ev, _) = wait_for(&mut b_events, 60, "link status", |e: &Event, _| {
        e.event_id == LinkStatus::event_id("auv-1")
    })
    .await;
    let status = LinkStatus::from_event(&ev).expect("a link-status event");
    assert_eq!(status.link, LinkKind::Acoustic);
    assert_eq!((status.cdt_address, status.vehicle_address), (CDT, AUV));
    assert_eq!(status.participant, cdt_dds.participant_id());
    assert!(received.iter().all(|(_, meta)| status.wrote(&meta.writer)));

    // A task published on the station's domain reaches the AUV's domain and runs there.
    let writer = station
        .writer::<TaskAssignment>(WriterOptions::new(Priority::Control))
        .unwrap();
    writer.write(goto_task("t-e2e-1")).await.unwrap();
    let (on_a, _) = wait_for(&mut a_tasks, 60, "task on A", |t: &TaskAssignment, _| {
        t.vehicle_id == "auv-1"
    })
    .await;
    assert_eq!(on_a.kind, shoal_model::TaskKind::GotoWaypoint);
    assert!((on_a.area[0].latitude_deg - (LAT + 0.002)).abs() < 1e-5);
    let mut states = Vec::new();
    wait_for(
        &mut b_status,
        60,
        "task running on B",
        |s: &TaskStatus, _| {
            if s.task_id == "t-e2e-1" {
                states.push(s.state);
            }
            s.task_id == "t-e2e-1" && s.state == TaskState::Running
        },
    )
    .await;
    assert!(states.contains(&TaskState::Sent), "{states:?}");

    shutdown.cancel();
    within(10, "VDT stop", vdt).await.unwrap().unwrap();
    within(10, "CDT stop", cdt).await.unwrap().unwrap();
}
