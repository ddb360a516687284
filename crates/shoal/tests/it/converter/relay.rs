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
    let relay_at = (
        Some(demo.relay_latitude_deg),
        Some(demo.relay_longitude_deg),
    );

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
    // What the console's map draws: the relay's modem, and frames arriving.
    assert_eq!((link.cdt_latitude_deg, link.cdt_longitude_deg), relay_at);
    assert!(link.frames.is_some_and(|n| n >= 1), "{link:?}");

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

/// A relay that rides on a USV of the station's domain follows that USV's reported
/// position, and no other vehicle's.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_relay_on_a_usv_follows_the_usvs_position() {
    let station_cfg = DdsConfig {
        domain_id: 122,
        ..DdsConfig::default()
    };
    let (mut demo, sim) = demo_relay(121, SCALE);
    demo.relay_vehicle = Some("usv-r".into());
    let (tx, rx) = tokio::sync::oneshot::channel();
    let shutdown = CancellationToken::new();
    let run = {
        let (shutdown, cfg) = (shutdown.clone(), station_cfg.clone());
        tokio::spawn(async move {
            let cdt_dds = std::sync::Arc::new(shoal_dds::PubSub::new(&cfg)?);
            let start_sim =
                move |_: &shoal_converter::emulated_relay::RelayedVehicle, dds, stop| {
                    let spec = sim.clone();
                    async move {
                        shoal_proxy::run_sim(spec, dds, stop)
                            .await
                            .map_err(shoal_converter::ConverterError::from)
                    }
                };
            let mut tx = Some(tx);
            shoal_converter::emulated_relay::run_emulated_relay_with(
                demo,
                cdt_dds,
                None,
                start_sim,
                |emu| {
                    if let Some(tx) = tx.take() {
                        let _ = tx.send(std::sync::Arc::clone(emu));
                    }
                },
                shutdown,
            )
            .await
        })
    };
    let emu = within(30, "the emulated sea", rx).await.unwrap();
    let station = participant(122);
    let writer = station
        .writer::<StateVector>(WriterOptions::new(Priority::Telemetry))
        .unwrap();
    let at = |id: &str, lat: f64| StateVector {
        vehicle_id: id.into(),
        timestamp_ms: shoal_model::now_ms(),
        latitude_deg: lat,
        longitude_deg: 10.39,
        depth_m: 0.0,
        altitude_m: -1.0,
        speed_mps: 2.0,
        yaw_deg: 90.0,
        pitch_deg: 0.0,
        roll_deg: 0.0,
        battery_pct: 90.0,
    };
    // Another vehicle's position moves nothing; the USV's moves the relay.
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(30);
    loop {
        writer.write(at("usv-other", 63.40)).await.unwrap();
        writer.write(at("usv-r", 63.465)).await.unwrap();
        let p = emu.position(1).unwrap();
        if (p.latitude_deg - 63.465).abs() < 1e-9 {
            assert!((p.longitude_deg - 10.39).abs() < 1e-9, "{p:?}");
            break;
        }
        assert!(
            (p.latitude_deg - 63.40).abs() > 1e-6,
            "followed another vehicle: {p:?}"
        );
        assert!(
            std::time::Instant::now() < deadline,
            "the relay never followed usv-r: {p:?}"
        );
        tokio::time::sleep(std::time::Duration::from_millis(200)).await;
    }
    drop(emu);
    shutdown.cancel();
    within(20, "relay stop", run).await.unwrap().unwrap();
}
