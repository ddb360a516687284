//! At most once over the acoustic link: a task the vehicle finished, delivered again after
//! its VDT and the vehicle restarted, is answered from the vehicle's task ledger and not run
//! again. Domains 109 (vehicle side) and 110 (station side).

use std::path::Path;
use std::sync::Arc;

use shoal_acoustic::emulator::ModemEndpoints;
use shoal_converter::{Modem, ModemKind, run_cdt, run_vdt};
use shoal_dds::{Priority, PubSub, WriterOptions};
use shoal_model::{Task, TaskAssignment, TaskState, TaskStatus, now_ms};
use shoal_proxy::ProxyOptions;
use shoal_proxy::ledger::{Progress, TaskLedger};
use shoal_proxy::sim::SimSettings;
use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;

use super::common::*;

/// The simulated AUV (task ledger in `ledgers`) and its VDT, both on domain 109, until the
/// returned token is cancelled.
fn vehicle_side(
    auv_modem: &ModemEndpoints,
    ledgers: &Path,
) -> (CancellationToken, Vec<JoinHandle<()>>) {
    let stop = CancellationToken::new();
    let options = ProxyOptions {
        ledger_dir: Some(ledgers.to_path_buf()),
        ..ProxyOptions::default()
    };
    let sim = tokio::spawn(shoal_proxy::run_sim_on(
        auv(),
        SimSettings::default(),
        options,
        participant(109),
        stop.clone(),
    ));
    let cfg = vdt_config(ModemKind::EvologicsAt, auv_modem.at);
    let driver = Modem::start(&cfg.modem, SCALE);
    let vdt = tokio::spawn(run_vdt(cfg, participant(109), driver, stop.clone()));
    let handles = vec![
        tokio::spawn(async move { sim.await.unwrap().unwrap() }),
        tokio::spawn(async move { vdt.await.unwrap().unwrap() }),
    ];
    (stop, handles)
}

/// The CDT on domain 110 until the returned token is cancelled.
fn cdt(cdt_modem: &ModemEndpoints) -> (CancellationToken, JoinHandle<()>) {
    let stop = CancellationToken::new();
    let cfg = cdt_config(ModemKind::EvologicsAt, cdt_modem.at);
    let driver = Modem::start(&cfg.modem, SCALE);
    let run = tokio::spawn(run_cdt(cfg, participant(110), driver, stop.clone()));
    (
        stop,
        tokio::spawn(async move { run.await.unwrap().unwrap() }),
    )
}

async fn stop(token: CancellationToken, handles: Vec<JoinHandle<()>>) {
    token.cancel();
    for h in handles {
        within(20, "a converter or vehicle to stop", h)
            .await
            .unwrap();
    }
}

/// Broke before the compact task carried the station's identity: the restarted VDT named
/// the re-delivered task `auv-1-ac0-<time>`, a task the vehicle's ledger had never seen,
/// so the vehicle ran it a second time.
#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_finished_task_delivered_again_after_the_vdt_and_vehicle_restart_is_not_run_again() {
    let emu = emulator([(0, 0), (0, 0)]).await;
    let (cdt_modem, auv_modem) = (emu.modems()[0].clone(), emu.modems()[1].clone());
    let ledgers = tempfile::tempdir().unwrap();

    // The "station" on domain 110, an observer of the vehicle's own bus on 109.
    let station: Arc<PubSub> = participant(110);
    let mut b_status = station.subscribe::<TaskStatus>().unwrap();
    let observer = participant(109);
    let writer = station
        .writer::<TaskAssignment>(WriterOptions::new(Priority::Control))
        .unwrap();
    let mut task = TaskAssignment::new(
        "t-once-1",
        "m-once",
        "auv-1",
        now_ms(),
        &Task::Hold { duration_s: 1.0 },
    );
    // What a station stamps on a send (µs-seeded sequence, a start-by expiry).
    task.issue_seq = 1_780_000_000_000_001;
    task.expires_ms = now_ms() + 600_000;

    let (vehicle_stop, vehicle) = vehicle_side(&auv_modem, ledgers.path());
    let (cdt_stop, cdt_run) = cdt(&cdt_modem);
    writer.write(task.clone()).await.unwrap();
    wait_for(
        &mut b_status,
        90,
        "the task done on B",
        |s: &TaskStatus, _| s.task_id == "t-once-1" && s.state == TaskState::Done,
    )
    .await;

    // Everything on the water restarts; the vehicle keeps its state directory.
    stop(vehicle_stop, vehicle).await;
    stop(cdt_stop, vec![cdt_run]).await;
    let mut a_status = observer.subscribe::<TaskStatus>().unwrap();
    let mut a_tasks = observer.subscribe::<TaskAssignment>().unwrap();
    let (vehicle_stop, vehicle) = vehicle_side(&auv_modem, ledgers.path());
    let (cdt_stop, cdt_run) = cdt(&cdt_modem);
    // The station sends the same task again: the new CDT has not seen it, so the same
    // task PDU crosses the water once more.
    writer.write(task.clone()).await.unwrap();

    let (again, _) = wait_for(
        &mut a_tasks,
        90,
        "the re-delivered task on A",
        |t: &TaskAssignment, _| t.vehicle_id == "auv-1",
    )
    .await;
    // The vehicle's first word on it: started again, or answered from its ledger.
    let (answer, _) = wait_for(
        &mut a_status,
        60,
        "the vehicle's answer to the re-delivery",
        |s: &TaskStatus, _| s.task_id == again.task_id,
    )
    .await;
    assert!(
        answer.state == TaskState::Done && answer.message.contains("not run again"),
        "the vehicle ran the task again: {answer:?}"
    );
    assert_eq!(
        (again.task_id.as_str(), again.issue_seq),
        ("t-once-1", task.issue_seq),
        "the VDT hands the task over under the station's identity"
    );
    assert_eq!(again.expires_ms, task.expires_ms / 1000 * 1000);
    // The station hears it is done again, through the new CDT.
    wait_for(&mut b_status, 60, "done again on B", |s: &TaskStatus, _| {
        s.task_id == "t-once-1" && s.state == TaskState::Done
    })
    .await;

    stop(vehicle_stop, vehicle).await;
    stop(cdt_stop, vec![cdt_run]).await;
    // One task in the ledger, the station's, done once.
    let ledger = TaskLedger::open(ledgers.path(), "auv-1", None).unwrap();
    assert_eq!(ledger.len(), 1);
    assert_eq!(
        ledger.progress("t-once-1"),
        Some(Progress::Ended(TaskState::Done))
    );
}
