//! `shoal up` with its default scenario (scenarios/sea-trial.toml), read through the HTTP
//! API as a newcomer's browser would. Domain 72.

use std::io::Read;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::common::{free_port, http_get};

/// Stops `shoal up` with SIGTERM (its children with it) however the test ends.
struct Up(std::process::Child);

impl Drop for Up {
    fn drop(&mut self) {
        let _ = Command::new("kill")
            .args(["-TERM", &self.0.id().to_string()])
            .status();
        for _ in 0..150 {
            if matches!(self.0.try_wait(), Ok(Some(_))) {
                return;
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        let _ = self.0.kill();
    }
}

fn json(port: u16, path: &str) -> Option<serde_json::Value> {
    serde_json::from_str(&http_get(port, path).ok()?).ok()
}

/// The target of issue 24: within 30 s of `shoal up`, a vehicle moves and a task runs,
/// with nobody touching the console.
#[test]
fn up_runs_the_default_scenario_and_vehicles_move_within_30_s() {
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let started = Instant::now();
    let mut up = Up(Command::new(env!("CARGO_BIN_EXE_shoal"))
        .arg("up")
        .current_dir(dir.path())
        .env("SHOAL_DDS__DOMAIN_ID", "72")
        .env("SHOAL_CONSOLE__LISTEN", format!("127.0.0.1:{port}"))
        // Logins are on by default; this test reads the API without credentials.
        .env("SHOAL_CONSOLE__AUTH__ENABLED", "false")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap());
    let mut moving = None;
    let mut running = None;
    while started.elapsed() < Duration::from_secs(30) && (moving.is_none() || running.is_none()) {
        std::thread::sleep(Duration::from_millis(500));
        if moving.is_none()
            && let Some(fleet) = json(port, "/api/fleet")
        {
            moving = fleet.as_array().and_then(|vs| {
                vs.iter().find_map(|v| {
                    let speed = v["latest"]["speed_mps"].as_f64()?;
                    (speed > 0.0).then(|| (v["announcement"]["vehicle_id"].clone(), speed))
                })
            });
        }
        if running.is_none()
            && let Some(tasks) = json(port, "/api/tasks")
        {
            running = tasks.as_array().and_then(|ts| {
                ts.iter()
                    .find(|t| t["state"] == "running")
                    .map(|t| t["assignment"]["task_id"].clone())
            });
        }
    }
    let elapsed = started.elapsed();
    let fleet = http_get(port, "/api/fleet").unwrap_or_default();
    let tasks = http_get(port, "/api/tasks").unwrap_or_default();
    let mut log = String::new();
    if moving.is_none() || running.is_none() {
        let mut stderr = up.0.stderr.take().unwrap();
        drop(up);
        let _ = stderr.read_to_string(&mut log);
    }
    assert!(
        moving.is_some() && running.is_some(),
        "after {elapsed:?}: moving {moving:?}, running {running:?}\nfleet {fleet}\ntasks {tasks}\nlog:\n{log}"
    );
    eprintln!("moving {moving:?}, running {running:?} after {elapsed:?}");
}
