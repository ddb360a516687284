//! The modem connection drops (the emulator stops) and comes back on the same ports: the
//! converters reconnect and a task queued meanwhile is still delivered. Domains 103, 104.

use shoal_dds::{Priority, WriterOptions};
use shoal_model::{TaskAssignment, TaskState, TaskStatus};
use tokio_util::sync::CancellationToken;

use super::common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_task_queued_while_the_modem_is_gone_is_delivered_after_it_returns() {
    let ports = [(free_port(), free_port()), (free_port(), free_port())];
    let emu = emulator(ports).await;
    let (cdt_modem, auv_modem) = (emu.modems()[0].clone(), emu.modems()[1].clone());
    let shutdown = CancellationToken::new();
    let AcousticAuv {
        station,
        status: mut b_status,
        cdt,
    } = AcousticAuv::start((103, 104), (cdt_modem.at, auv_modem.at), SCALE, &shutdown).await;

    // The sea goes away: every modem connection drops.
    emu.shutdown();
    emu.stopped().await;

    let writer = station
        .writer::<TaskAssignment>(WriterOptions::new(Priority::Control))
        .unwrap();
    writer.write(goto_task("t-reconnect")).await.unwrap();
    // The CDT accepted it into its queue although it cannot transmit.
    wait_for(&mut b_status, 30, "sent status", |s: &TaskStatus, _| {
        s.task_id == "t-reconnect" && s.state == TaskState::Sent
    })
    .await;
    tokio::time::sleep(std::time::Duration::from_secs(2)).await;

    // The modems come back on the same ports; the drivers reconnect by themselves.
    let _emu = emulator(ports).await;
    wait_for(
        &mut b_status,
        60,
        "task accepted after reconnect",
        |s: &TaskStatus, _| {
            s.task_id == "t-reconnect"
                && matches!(s.state, TaskState::Accepted | TaskState::Running)
        },
    )
    .await;

    shutdown.cancel();
    within(10, "CDT stop", cdt).await.unwrap().unwrap();
}
