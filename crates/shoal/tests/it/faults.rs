//! Faults with the `shoal` binary: a station killed with SIGKILL under load loses no record
//! it had committed, finds its vehicles again after a restart, and its Task Register picks
//! up the task under way (domain 54); processes stopped and resumed (SIGSTOP/SIGCONT) go
//! on exchanging data (domain 90); a vehicle restarted after finishing a task does not run
//! it again (domain 91).

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use shoal_model::{Task, TaskAssignment, now_ms};

use crate::common::{http_get, http_post};

struct Proc(Child);

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn station(dir: &std::path::Path, port: u16) -> Proc {
    station_on(dir, port, 54)
}

fn station_on(dir: &std::path::Path, port: u16, domain: u16) -> Proc {
    // The key store first, so vehicles started in `dir` right after the station find it
    // (security is on by default; a vehicle on the station's host takes its identity from
    // the store).
    if !dir.join("shoal-data/keys").exists() {
        let init = Command::new(env!("CARGO_BIN_EXE_shoal"))
            .args(["keys", "init"])
            .current_dir(dir)
            .output()
            .unwrap();
        assert!(init.status.success(), "{init:?}");
    }
    Proc(
        Command::new(env!("CARGO_BIN_EXE_shoal"))
            .args(["station", "--listen", &format!("127.0.0.1:{port}")])
            .arg("--db")
            .arg(dir.join("history.db"))
            .current_dir(dir)
            .env("SHOAL_DDS__DOMAIN_ID", domain.to_string())
            // Logins are on by default; these tests use the API without credentials.
            .env("SHOAL_CONSOLE__AUTH__ENABLED", "false")
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    )
}

fn json(port: u16, path: &str) -> serde_json::Value {
    http_get(port, path)
        .ok()
        .and_then(|b| serde_json::from_str(&b).ok())
        .unwrap_or(serde_json::Value::Null)
}

fn alive(port: u16) -> usize {
    json(port, "/api/fleet")
        .as_array()
        .map_or(0, |a| a.iter().filter(|v| v["contact"] == "alive").count())
}

fn wait_for(secs: u64, what: &str, mut check: impl FnMut() -> bool) -> Duration {
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(secs) {
        if check() {
            return start.elapsed();
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    panic!("timed out after {secs} s waiting for {what}");
}

#[test]
fn a_station_killed_under_load_loses_no_committed_record_and_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let port = crate::common::free_port();
    let first = station(dir.path(), port);
    let ids = ["k-1", "k-2", "k-3"];
    let _vehicles: Vec<Proc> = ids
        .iter()
        .map(|id| {
            Proc(
                Command::new(env!("CARGO_BIN_EXE_shoal"))
                    .args(["vehicle", "--sim", "auv", "--id", id, "--rate", "20"])
                    .arg("--lat")
                    .arg("63.0")
                    .arg("--lon")
                    .arg("10.0")
                    .current_dir(dir.path())
                    .env("SHOAL_DDS__DOMAIN_ID", "54")
                    .stdout(Stdio::null())
                    .stderr(Stdio::null())
                    .spawn()
                    .unwrap(),
            )
        })
        .collect();
    wait_for(60, "three vehicles alive", || alive(port) == 3);

    // A long task under way when the station dies.
    let task = TaskAssignment::new(
        "t-kill",
        "m-kill",
        "k-1",
        now_ms(),
        &Task::Hold { duration_s: 3600.0 },
    );
    let (code, body) =
        http_post(port, "/api/tasks", &serde_json::to_string(&task).unwrap()).unwrap();
    assert_eq!(code, 202, "{body}");
    wait_for(30, "the task running", || {
        json(port, "/api/tasks/t-kill")["state"] == "running"
    });

    // Load for a while, then note what the history holds (reads see committed rows
    // only) and kill the station at once.
    std::thread::sleep(Duration::from_secs(3));
    let committed: Vec<usize> = ids
        .iter()
        .map(|id| {
            json(port, &format!("/api/vehicles/{id}/track?limit=10000"))
                .as_array()
                .map_or(0, Vec::len)
        })
        .collect();
    let mut first = first;
    first.0.kill().unwrap(); // SIGKILL
    first.0.wait().unwrap();
    assert!(committed.iter().all(|n| *n > 20), "{committed:?}");

    let history = shoal_history::History::open(&shoal_history::HistoryConfig {
        path: dir.path().join("history.db"),
        ..shoal_history::HistoryConfig::default()
    })
    .unwrap();
    for (id, before) in ids.iter().zip(&committed) {
        let after = history.count_states(Some(id)).unwrap();
        assert!(
            after >= *before as u64,
            "{id}: {before} rows committed before the kill, {after} after"
        );
    }
    drop(history);

    // Restarted on the same database: the vehicles are found again, and the task under way
    // is back in the register, still running.
    let _second = station(dir.path(), port);
    let rediscovered = wait_for(60, "three vehicles alive after the restart", || {
        alive(port) == 3
    });
    eprintln!("vehicles rediscovered {rediscovered:?} after the restart");
    let t = json(port, "/api/tasks/t-kill");
    assert_eq!(t["state"], "running", "{t}");
    wait_for(30, "fresh state from k-1", || {
        json(port, "/api/vehicles/k-1")["latest"]["timestamp_ms"]
            .as_i64()
            .is_some_and(|ts| now_ms() - ts < 5_000)
    });
}

/// Processes stopped and resumed (SIGSTOP/SIGCONT, as Ctrl-Z then `fg`, or a suspend)
/// get EINTR in whatever system call they were in; their DDS must carry on, not go deaf
/// and mute (RustDDS, Shoal's earlier DDS library, lost its threads to it). Domain 90.
#[test]
fn processes_stopped_and_resumed_go_on_exchanging_data() {
    let dir = tempfile::tempdir().unwrap();
    let port = crate::common::free_port();
    let station = station_on(dir.path(), port, 90);
    let log = dir.path().join("vehicle.log");
    let mut vehicle = Proc(
        Command::new(env!("CARGO_BIN_EXE_shoal"))
            .args(["vehicle", "--sim", "auv", "--id", "auv-z"])
            .current_dir(dir.path())
            .env("SHOAL_DDS__DOMAIN_ID", "90")
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&log).unwrap())
            .spawn()
            .unwrap(),
    );
    let text = || std::fs::read_to_string(&log).unwrap_or_default();
    let fresh_since = |t0: i64| {
        json(port, "/api/vehicles/auv-z")["latest"]["timestamp_ms"]
            .as_i64()
            .is_some_and(|ts| ts > t0)
    };
    wait_for(30, "state from auv-z", || fresh_since(0));
    let signal = |pid: u32, sig: &str| {
        let ok = Command::new("kill")
            .args([sig, &pid.to_string()])
            .status()
            .is_ok_and(|s| s.success());
        assert!(ok, "kill {sig} {pid}");
    };
    // Several times each, so that some stop lands inside a blocking call.
    for pid in [vehicle.0.id(), station.0.id()] {
        for _ in 0..5 {
            signal(pid, "-STOP");
            std::thread::sleep(Duration::from_millis(300));
            signal(pid, "-CONT");
            std::thread::sleep(Duration::from_millis(200));
        }
    }
    let resumed = now_ms();
    wait_for(15, "state sent after the last resume", || {
        fresh_since(resumed)
    });
    assert!(
        vehicle.0.try_wait().unwrap().is_none(),
        "the vehicle exited: {}",
        text()
    );
    assert!(!text().contains("panicked"), "{}", text());
}

/// The bug as a new user met it: a one-goto task reaches `done`; the vehicle process is
/// stopped and started again with the same id; transient-local history used to hand the
/// task back and the vehicle drove to the old waypoint again. Domain 91.
#[test]
fn a_vehicle_restarted_after_finishing_a_task_does_not_run_it_again() {
    let dir = tempfile::tempdir().unwrap();
    let port = crate::common::free_port();
    let _station = station_on(dir.path(), port, 91);
    let vehicle = |log: &str| {
        Proc(
            Command::new(env!("CARGO_BIN_EXE_shoal"))
                .args(["vehicle", "--sim", "auv", "--id", "auv-9", "--lat", "63.0"])
                .args(["--lon", "10.0"])
                .current_dir(dir.path())
                .env("SHOAL_DDS__DOMAIN_ID", "91")
                .stdout(Stdio::null())
                .stderr(std::fs::File::create(dir.path().join(log)).unwrap())
                .spawn()
                .unwrap(),
        )
    };
    let mut first = vehicle("first.log");
    wait_for(60, "auv-9 alive", || alive(port) == 1);
    let task = TaskAssignment::new(
        "r-1-1",
        "",
        "auv-9",
        now_ms(),
        &Task::GotoWaypoint {
            target: shoal_model::GeoPoint {
                latitude_deg: 63.0002,
                longitude_deg: 10.0,
            },
            depth_m: Some(2.0),
            altitude_m: None,
            speed_mps: 2.0,
        },
    );
    let (code, body) =
        http_post(port, "/api/tasks", &serde_json::to_string(&task).unwrap()).unwrap();
    assert_eq!(code, 202, "{body}");
    wait_for(120, "the goto done", || {
        json(port, "/api/tasks/r-1-1")["state"] == "done"
    });
    first.0.kill().unwrap();
    first.0.wait().unwrap();

    let _second = vehicle("second.log");
    wait_for(60, "auv-9 alive again", || {
        json(port, "/api/vehicles/auv-9")["latest"]["timestamp_ms"]
            .as_i64()
            .is_some_and(|ts| now_ms() - ts < 2_000)
    });
    // Give DDS time to hand over whatever it still holds for late joiners.
    std::thread::sleep(Duration::from_secs(5));
    let log = std::fs::read_to_string(dir.path().join("second.log")).unwrap();
    assert!(
        !log.contains("task received"),
        "the restarted vehicle took the finished task again:\n{log}"
    );
    assert_eq!(json(port, "/api/tasks/r-1-1")["state"], "done");
    // The vehicle's ledger is where [vehicle] puts it.
    assert!(
        dir.path()
            .join("shoal-data/vehicles/auv-9.tasks.json")
            .exists()
    );
}
