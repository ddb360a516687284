//! OMG DDS Security 1.1 through Cyclone's plugins, over real RTPS on loopback: a station
//! and a vehicle in another process, each with an enclave from one keystore, exchange
//! state and tasks; a participant without credentials sees and injects nothing; a vehicle
//! may not assign tasks nor speak for another vehicle; bad files are refused by name.
//! Domains 51–53; run inside the test network namespace.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use futures::StreamExt;
use shoal_dds::{CreateError, Credentials, Priority, PubSub, ReadError, WriterOptions};
use shoal_model::{StateVector, Task, TaskAssignment};
use shoal_security::dds::{DdsKeystore, Enclave, Grant, KeystoreOptions, names};

mod common;
use common::{Foreign, config};

/// A state vector as a foreign, credential-less DDS stack writes it.
#[derive(serde::Serialize, serde::Deserialize, Clone, Debug)]
#[serde(transparent)]
struct ForeignState(StateVector);

impl rustdds::Keyed for ForeignState {
    type K = String;
    fn key(&self) -> String {
        self.0.vehicle_id.clone()
    }
}

fn now_s() -> i64 {
    shoal_model::now_ms() / 1000
}

fn keystore(dir: &std::path::Path) -> DdsKeystore {
    DdsKeystore::create(&dir.join("dds"), KeystoreOptions::default(), now_s()).unwrap()
}

/// Runs `omg_child` (below) in a new process of this test binary, as vehicle `enclave_id`
/// (or without credentials when `None`), doing `action`.
fn child(domain: u16, ks_dir: &std::path::Path, enclave_id: Option<&str>, action: &str) -> Child {
    let mut c = Command::new(std::env::current_exe().unwrap());
    c.args(["--ignored", "--exact", "omg_child", "--nocapture"])
        .env("OMG_CHILD_DOMAIN", domain.to_string())
        .env("OMG_CHILD_KEYSTORE", ks_dir)
        .env("OMG_CHILD_ACTION", action)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit());
    if let Some(id) = enclave_id {
        c.env("OMG_CHILD_VEHICLE", id);
    }
    c.spawn().unwrap()
}

/// Lines the child printed, until `want` is seen or `timeout` passes.
fn wait_line(child: &mut Child, want: &str, timeout: Duration) -> Vec<String> {
    let out = child.stdout.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(out).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let deadline = Instant::now() + timeout;
    let mut lines = Vec::new();
    while let Some(left) = deadline.checked_duration_since(Instant::now()) {
        match rx.recv_timeout(left) {
            Ok(l) => {
                let done = l.contains(want);
                lines.push(l);
                if done {
                    break;
                }
            }
            Err(_) => break,
        }
    }
    lines
}

/// The child: joins with the vehicle's enclave (or none), then does its action.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "run by the other tests in a child process"]
async fn omg_child() {
    let domain: u16 = std::env::var("OMG_CHILD_DOMAIN").unwrap().parse().unwrap();
    let ks_dir = std::path::PathBuf::from(std::env::var("OMG_CHILD_KEYSTORE").unwrap());
    let action = std::env::var("OMG_CHILD_ACTION").unwrap();
    let vehicle = std::env::var("OMG_CHILD_VEHICLE").ok();
    let enclave_dir = std::env::var_os("OMG_CHILD_ENCLAVE");
    let dds = match &vehicle {
        // Files used as they are, no revocation list: what a revoked vehicle that kept its
        // files would present.
        Some(id) if enclave_dir.is_some() => {
            let enclave = Enclave::new(enclave_dir.unwrap(), None);
            PubSub::with_credentials(&config(domain), Credentials::vehicle(enclave, id)).unwrap()
        }
        Some(id) => {
            let ks = DdsKeystore::open(&ks_dir, KeystoreOptions::default()).unwrap();
            let enclave = ks.enclave(&Grant::Vehicle(id.clone())).unwrap();
            PubSub::with_credentials(&config(domain), Credentials::vehicle(enclave, id)).unwrap()
        }
        None => PubSub::new(&config(domain)).unwrap(),
    };
    println!("joined");
    match action.as_str() {
        // Publish state as `about` every 100 ms and print each task received.
        a if a.starts_with("state:") => {
            let about = &a["state:".len()..];
            let w = dds
                .writer::<StateVector>(WriterOptions::new(Priority::Telemetry))
                .unwrap();
            let mut tasks = dds.subscribe::<TaskAssignment>().unwrap();
            for _ in 0..300 {
                w.write(common::state_at(about, shoal_model::now_ms()))
                    .await
                    .unwrap();
                if let Ok(Some(Ok((t, _)))) =
                    tokio::time::timeout(Duration::from_millis(100), tasks.next()).await
                {
                    println!("task {}", t.task_id);
                }
            }
        }
        // Try to create a task writer.
        "assign" => match dds.writer::<TaskAssignment>(WriterOptions::new(Priority::Control)) {
            Ok(_) => println!("task writer created"),
            Err(e) => println!("task writer refused: {e}"),
        },
        other => panic!("unknown action {other}"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_secured_vehicle_and_station_exchange_state_and_tasks_and_others_are_shut_out() {
    let dir = tempfile::tempdir().unwrap();
    let ks = keystore(dir.path());
    let station_enclave = ks.issue(&Grant::Station, now_s()).unwrap();
    ks.issue(&Grant::Vehicle("auv-1".into()), now_s()).unwrap();
    ks.issue(&Grant::Vehicle("auv-2".into()), now_s()).unwrap();
    // Revoked before the station starts (participants read the list when they start); its
    // files are kept to be presented anyway.
    let revoked_enclave = ks.issue(&Grant::Vehicle("auv-r".into()), now_s()).unwrap();
    let revoked_dir = dir.path().join("kept-auv-r");
    std::fs::create_dir(&revoked_dir).unwrap();
    for n in [
        names::CERT,
        names::KEY,
        names::IDENTITY_CA,
        names::PERMISSIONS_CA,
        names::GOVERNANCE,
        names::PERMISSIONS,
    ] {
        std::fs::copy(revoked_enclave.file(n), revoked_dir.join(n)).unwrap();
    }
    ks.revoke(&Grant::Vehicle("auv-r".into()), now_s()).unwrap();

    let station =
        PubSub::with_credentials(&config(51), Credentials::station(station_enclave)).unwrap();
    let mut states = station.subscribe::<StateVector>().unwrap();

    // A participant with no credentials (another DDS stack, RustDDS) publishing a state.
    let foreign = Foreign::new(51, "shoal/state_vector", "shoal::StateVector");
    let fw = foreign
        .publisher
        .create_datawriter_cdr::<ForeignState>(&foreign.topic, None)
        .unwrap();

    // The vehicle, in its own process.
    let mut vehicle = child(51, ks.dir(), Some("auv-1"), "state:auv-1");
    let tw = station
        .writer::<TaskAssignment>(WriterOptions::new(Priority::Control))
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(30);
    let mut from_auv1 = 0;
    while from_auv1 < 5 {
        assert!(Instant::now() < deadline, "no state from auv-1 in 30 s");
        fw.write(
            ForeignState(common::state_at("rogue-1", shoal_model::now_ms())),
            None,
        )
        .unwrap();
        if let Ok(Some(item)) =
            tokio::time::timeout(Duration::from_millis(200), states.next()).await
        {
            let (s, meta) = item.unwrap();
            assert_eq!(
                s.vehicle_id, "auv-1",
                "only the authenticated vehicle is heard"
            );
            assert_eq!(meta.publisher_vehicle.as_deref(), Some("auv-1"));
            from_auv1 += 1;
        }
    }
    let task = TaskAssignment::new("t-1", "m-1", "auv-1", shoal_model::now_ms(), &Task::Surface);
    tw.write(task).await.unwrap();
    let lines = wait_line(&mut vehicle, "task t-1", Duration::from_secs(20));
    assert!(
        lines.iter().any(|l| l == "task t-1"),
        "the vehicle did not receive the station's task: {lines:?}"
    );
    vehicle.kill().unwrap();
    vehicle.wait().unwrap();

    // Without credentials: the station's task never reaches it.
    let mut outsider = child(51, ks.dir(), None, "state:auv-1");
    let lines = wait_line(&mut outsider, "task ", Duration::from_secs(8));
    assert!(
        !lines.iter().any(|l| l.starts_with("task ")),
        "an unauthenticated participant received a task: {lines:?}"
    );
    outsider.kill().unwrap();
    outsider.wait().unwrap();
    // A vehicle revoked before the station started, presenting its old files: the
    // station's handshake with it fails on the revocation list, counted by reason in this
    // (the station's) process, and nothing it says arrives.
    let refused = |reason| {
        shoal_dds::handshake_refusals()
            .get(reason)
            .copied()
            .unwrap_or(0)
    };
    let before = refused("revoked");
    let mut c = Command::new(std::env::current_exe().unwrap());
    c.args(["--ignored", "--exact", "omg_child", "--nocapture"])
        .env("OMG_CHILD_DOMAIN", "51")
        .env("OMG_CHILD_KEYSTORE", ks.dir())
        .env("OMG_CHILD_ACTION", "state:auv-r")
        .env("OMG_CHILD_VEHICLE", "auv-r")
        .env("OMG_CHILD_ENCLAVE", &revoked_dir)
        .stdout(Stdio::null())
        .stderr(Stdio::null());
    let mut revoked = c.spawn().unwrap();
    let deadline = Instant::now() + Duration::from_secs(20);
    while refused("revoked") == before && Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    assert!(
        refused("revoked") > before,
        "no refused handshake counted as revoked: {:?}",
        shoal_dds::handshake_refusals()
    );
    revoked.kill().unwrap();
    revoked.wait().unwrap();
    // Nor did anything it, the outsider or RustDDS wrote arrive (only auv-1's retries are
    // drained).
    while let Ok(Some(item)) = tokio::time::timeout(Duration::from_millis(300), states.next()).await
    {
        let (s, _) = item.unwrap();
        assert_eq!(s.vehicle_id, "auv-1");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_vehicle_may_neither_assign_tasks_nor_speak_for_another() {
    let dir = tempfile::tempdir().unwrap();
    let ks = keystore(dir.path());
    let station_enclave = ks.issue(&Grant::Station, now_s()).unwrap();
    ks.issue(&Grant::Vehicle("auv-2".into()), now_s()).unwrap();
    let station =
        PubSub::with_credentials(&config(52), Credentials::station(station_enclave)).unwrap();
    let mut states = station.subscribe::<StateVector>().unwrap();

    let mut assign = child(52, ks.dir(), Some("auv-2"), "assign");
    let lines = wait_line(&mut assign, "task writer", Duration::from_secs(20));
    assert!(
        lines.iter().any(|l| l.starts_with("task writer refused")),
        "a vehicle could create a task writer: {lines:?}"
    );
    assign.wait().unwrap();

    // auv-2, authenticated, publishing auv-1's state: refused and counted.
    let mut liar = child(52, ks.dir(), Some("auv-2"), "state:auv-1");
    let deadline = Instant::now() + Duration::from_secs(30);
    let err = loop {
        assert!(Instant::now() < deadline, "nothing from auv-2 in 30 s");
        if let Ok(Some(item)) =
            tokio::time::timeout(Duration::from_millis(200), states.next()).await
        {
            match item {
                Ok((s, _)) => panic!("a state about {} was delivered", s.vehicle_id),
                Err(e) => break e,
            }
        }
    };
    assert!(
        matches!(&err, ReadError::Impersonation { publisher, claimed, .. } if publisher == "auv-2" && claimed == "auv-1"),
        "{err}"
    );
    assert!(station.impersonations_refused() >= 1);
    liar.kill().unwrap();
    liar.wait().unwrap();
}

#[test]
fn a_bad_credentials_file_is_named_and_nothing_is_created() {
    let dir = tempfile::tempdir().unwrap();
    let ks = keystore(dir.path());
    let enclave = ks.issue(&Grant::Vehicle("auv-3".into()), now_s()).unwrap();
    std::fs::write(enclave.file(names::GOVERNANCE), b"<dds/>").unwrap();
    let err =
        PubSub::with_credentials(&config(53), Credentials::vehicle(enclave, "auv-3")).unwrap_err();
    assert!(matches!(err, CreateError::Credentials(_)), "{err}");
    let text = err.to_string();
    assert!(
        text.contains("governance.p7s") && text.contains("permissions CA"),
        "{text}"
    );
}
