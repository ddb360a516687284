//! A ten-minute acoustic outage (the AUV's modem far out of range, simulated time 100×
//! faster): tasks the station sends meanwhile are kept by the CDT, retransmitted, and all
//! reach the vehicle once it is back in range; its acknowledgements come back. Nothing of
//! the persistent (control) class is lost. Domains 107, 108.

use std::time::Duration;

use shoal_acoustic::emulator::{Emulator, EmulatorConfig};
use shoal_dds::{Priority, WriterOptions};
use shoal_model::{TaskAssignment, TaskState};
use tokio_util::sync::CancellationToken;

use super::common::*;

/// Simulated seconds pass 100× faster than wall-clock ones here.
const FAST: f64 = 0.01;

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn tasks_sent_during_a_ten_minute_outage_are_all_delivered_afterwards() {
    let emu = Emulator::start(
        EmulatorConfig {
            time_scale: FAST,
            seed: 11,
            modems: vec![modem(CDT, 800.0, 0, 0), modem(AUV, 0.0, 0, 0)],
            ..EmulatorConfig::default()
        },
        std::future::pending(),
    )
    .await
    .unwrap();
    let (cdt_modem, auv_modem) = (emu.modems()[0].clone(), emu.modems()[1].clone());
    let shutdown = CancellationToken::new();
    let AcousticAuv {
        station,
        status: mut b_status,
        ..
    } = AcousticAuv::start((107, 108), (cdt_modem.at, auv_modem.at), FAST, &shutdown).await;

    // The AUV goes 100 km away: far beyond any acoustic range.
    let home = emu.position(AUV).unwrap();
    emu.set_position(
        AUV,
        home.latitude_deg,
        home.longitude_deg + 1.3,
        home.depth_m,
    )
    .unwrap();
    let writer = station
        .writer::<TaskAssignment>(WriterOptions::new(Priority::Control))
        .unwrap();
    let ids = ["t-out-1", "t-out-2", "t-out-3"];
    for id in ids {
        writer.write(goto_task(id)).await.unwrap();
    }
    // Ten simulated minutes out of range (the control class lives 15 minutes).
    tokio::time::sleep(Duration::from_secs_f64(600.0 * FAST)).await;
    let mut accepted = std::collections::BTreeSet::new();
    while let Ok(Some(Ok((s, _)))) = tokio::time::timeout(
        Duration::from_millis(100),
        futures::StreamExt::next(&mut b_status),
    )
    .await
    {
        if matches!(s.state, TaskState::Accepted | TaskState::Running) {
            accepted.insert(s.task_id.clone());
        }
    }
    assert!(
        accepted.is_empty(),
        "delivered while out of range: {accepted:?}"
    );

    // Back in range: every task arrives and is acknowledged.
    emu.set_position(AUV, home.latitude_deg, home.longitude_deg, home.depth_m)
        .unwrap();
    let deadline = tokio::time::Instant::now() + Duration::from_secs(60);
    while accepted.len() < ids.len() {
        let left = deadline.saturating_duration_since(tokio::time::Instant::now());
        assert!(
            !left.is_zero(),
            "only {accepted:?} acknowledged after the outage"
        );
        if let Ok(Some(Ok((s, _)))) =
            tokio::time::timeout(left, futures::StreamExt::next(&mut b_status)).await
            && ids.contains(&s.task_id.as_str())
            && matches!(
                s.state,
                TaskState::Accepted | TaskState::Running | TaskState::Done
            )
        {
            accepted.insert(s.task_id.clone());
        }
    }
    shutdown.cancel();
}
