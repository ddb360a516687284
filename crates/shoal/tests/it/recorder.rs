//! `shoal record` and `shoal replay` through the binary: a secure fleet recorded and
//! replayed into a fresh station (domains 171, 172), and a recorder killed with SIGKILL
//! (domains 173, 174). The reference Python MCAP reader (`.venv`, package `mcap`) checks
//! the files; without it that check is skipped with the reason printed, unless
//! `SHOAL_INTEROP_REQUIRED=1`, when the test fails.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use futures::StreamExt;
use serde_json::Value;
use shoal_dds::{Priority, WriterOptions};
use shoal_history::{History, HistoryConfig};
use shoal_model::StateVector;
use shoal_recorder::{McapMessages, ReadError, Sample, Topic};

use crate::common::{dds, free_port, http_get};

/// A child process, killed if the test ends before it does.
pub(crate) struct Proc {
    child: Child,
    name: &'static str,
    log: PathBuf,
}

impl Proc {
    fn start(name: &'static str, dir: &Path, domain: u16, args: &[&str]) -> Self {
        Self::start_with(name, dir, domain, args, &[])
    }

    pub(crate) fn start_with(
        name: &'static str,
        dir: &Path,
        domain: u16,
        args: &[&str],
        env: &[(&str, &str)],
    ) -> Self {
        let log = dir.join(format!("{name}.log"));
        let child = Command::new(env!("CARGO_BIN_EXE_shoal"))
            .args(args)
            .envs(env.iter().copied())
            .current_dir(dir)
            .env("SHOAL_DDS__DOMAIN_ID", domain.to_string())
            .env("SHOAL_CONSOLE__AUTH__ENABLED", "false")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&log).unwrap())
            .spawn()
            .unwrap();
        Self { child, name, log }
    }

    fn signal(&self, sig: &str) {
        let pid = self.child.id().to_string();
        assert!(
            Command::new("kill")
                .args([sig, &pid])
                .status()
                .unwrap()
                .success()
        );
    }

    /// Waits for the process to exit on its own; its exit status.
    fn wait(&mut self, secs: u64) -> std::process::ExitStatus {
        let deadline = Instant::now() + Duration::from_secs(secs);
        loop {
            if let Some(status) = self.child.try_wait().unwrap() {
                return status;
            }
            assert!(
                Instant::now() < deadline,
                "{} did not exit within {secs} s; its log:\n{}",
                self.name,
                self.log()
            );
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// Polls `check` until it holds; fails at once, with this process's log, if the
    /// process exits first, and with the log after `secs`.
    pub(crate) fn wait_for(&mut self, secs: u64, what: &str, mut check: impl FnMut() -> bool) {
        let deadline = Instant::now() + Duration::from_secs(secs);
        while !check() {
            if let Some(status) = self.child.try_wait().unwrap() {
                panic!(
                    "{} exited ({status}) while waiting for {what}; its log:\n{}",
                    self.name,
                    self.log()
                );
            }
            assert!(
                Instant::now() < deadline,
                "timed out after {secs} s waiting for {what}; {}'s log:\n{}",
                self.name,
                self.log()
            );
            std::thread::sleep(Duration::from_millis(200));
        }
    }

    pub(crate) fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

pub(crate) fn python_with_mcap() -> Option<PathBuf> {
    let python = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../.venv/bin/python");
    let works = python.exists()
        && Command::new(&python)
            .args(["-c", "import mcap"])
            .status()
            .is_ok_and(|s| s.success());
    if works {
        return Some(python);
    }
    let reason = format!("{} cannot import mcap", python.display());
    assert!(
        std::env::var("SHOAL_INTEROP_REQUIRED").as_deref() != Ok("1"),
        "the Python MCAP reader is required (SHOAL_INTEROP_REQUIRED=1): {reason}"
    );
    eprintln!("SKIPPED: the Python MCAP reader check: {reason}");
    None
}

fn check_mcap(python: &Path, file: &Path, mode: &str) -> Value {
    run_checker(python, "check_mcap.py", &[file.as_os_str(), mode.as_ref()])
}

/// What `tests/recorder/check_acoustic_mcap.py` (the Python MCAP reader) finds in the
/// acoustic recordings `files`.
pub(crate) fn check_acoustic_mcap(python: &Path, files: &[PathBuf]) -> Value {
    let args: Vec<&std::ffi::OsStr> = files.iter().map(|f| f.as_os_str()).collect();
    run_checker(python, "check_acoustic_mcap.py", &args)
}

/// Runs a checker of `tests/recorder/` with `args`; its JSON output.
fn run_checker(python: &Path, script: &str, args: &[&std::ffi::OsStr]) -> Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/recorder")
        .join(script);
    let out = Command::new(python)
        .arg(script)
        .args(args)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

/// Every state vector of a directory's recordings, and the first read error.
fn recorded_states(dir: &Path) -> (Vec<StateVector>, Option<ReadError>) {
    let mut out = Vec::new();
    let mut error = None;
    for file in shoal_recorder::mcap_files(dir).unwrap() {
        for m in McapMessages::new(std::fs::File::open(&file).unwrap()) {
            match m {
                Ok(m) if m.topic == Topic::StateVector => {
                    match shoal_recorder::decode_message(&m).unwrap() {
                        Sample::StateVector(s) => out.push(s),
                        other => panic!("{other:?}"),
                    }
                }
                Ok(_) => {}
                Err(e) => {
                    error.get_or_insert(e);
                    break;
                }
            }
        }
    }
    (out, error)
}

/// A station's stored track of rec-auv, oldest first, read from its history file.
fn track(db: &Path) -> Vec<StateVector> {
    let history = History::open(&HistoryConfig {
        path: db.to_path_buf(),
        ..HistoryConfig::default()
    })
    .unwrap();
    let mut v = history.track("rec-auv", 0, i64::MAX, 100_000).unwrap();
    v.sort_by_key(|s| s.timestamp_ms);
    v
}

fn fleet_states(port: u16, vehicle: &str) -> u64 {
    http_get(port, "/api/fleet")
        .ok()
        .and_then(|b| serde_json::from_str::<Value>(&b).ok())
        .and_then(|f| {
            f.as_array()?
                .iter()
                .find(|v| v["announcement"]["vehicle_id"] == vehicle)
                .and_then(|v| v["states_accepted"].as_u64())
        })
        .unwrap_or(0)
}

fn wait_until(secs: u64, what: &str, mut check: impl FnMut() -> bool) {
    let deadline = Instant::now() + Duration::from_secs(secs);
    while !check() {
        assert!(
            Instant::now() < deadline,
            "timed out after {secs} s waiting for {what}"
        );
        std::thread::sleep(Duration::from_millis(200));
    }
}

fn station(dir: &Path, name: &'static str, db: &str, port: u16, domain: u16) -> Proc {
    station_with(dir, name, db, port, domain, &[])
}

fn station_with(
    dir: &Path,
    name: &'static str,
    db: &str,
    port: u16,
    domain: u16,
    env: &[(&str, &str)],
) -> Proc {
    let listen = format!("127.0.0.1:{port}");
    let mut p = Proc::start_with(
        name,
        dir,
        domain,
        &["station", "--listen", &listen, "--db", db],
        env,
    );
    p.wait_for(30, "the station's API", || {
        http_get(port, "/api/fleet").is_ok()
    });
    p
}

/// Security on (the default): the recorder reads with the station's identity; the replay
/// publishes the vehicle's samples under the vehicle's own identity from the key store,
/// and a fresh station's history then holds exactly the recorded state vectors.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_secure_fleet_is_recorded_and_its_replay_rebuilds_a_fresh_stations_history() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let init = Command::new(env!("CARGO_BIN_EXE_shoal"))
        .args(["keys", "init"])
        .current_dir(d)
        .output()
        .unwrap();
    assert!(init.status.success(), "{init:?}");

    let port_a = free_port();
    // Station A records too, through its own [recorder] on its own participant.
    let mut station_a = station_with(
        d,
        "station-a",
        "a.db",
        port_a,
        171,
        &[
            ("SHOAL_RECORDER__ENABLED", "true"),
            ("SHOAL_RECORDER__DIRECTORY", "rec-station"),
        ],
    );
    let mut recorder = Proc::start("recorder", d, 171, &["record", "--output", "rec"]);
    // The recorder's readers are up once it prints its first progress line.
    let log = recorder.log.clone();
    recorder.wait_for(30, "the recorder to start", || {
        std::fs::read_to_string(&log).is_ok_and(|l| l.contains("shoal record:"))
    });
    let mut vehicle = Proc::start(
        "vehicle",
        d,
        171,
        &["vehicle", "--sim", "auv", "--id", "rec-auv", "--rate", "5"],
    );
    wait_until(60, "station A to accept 15 state vectors", || {
        fleet_states(port_a, "rec-auv") >= 15
    });
    vehicle.signal("-TERM");
    vehicle.wait(20);
    // A chunk reaches the disk within a second; Ctrl-C then closes the file properly.
    std::thread::sleep(Duration::from_millis(1500));
    recorder.signal("-INT");
    let status = recorder.wait(30);
    assert!(status.success(), "{}", recorder.log());
    assert!(
        recorder.log().contains("shoal record: done: 1 files"),
        "{}",
        recorder.log()
    );
    station_a.signal("-TERM");
    station_a.wait(30);

    let rec = d.join("rec");
    let (recorded, error) = recorded_states(&rec);
    assert!(
        error.is_none(),
        "a file closed with Ctrl-C is complete: {error:?}"
    );
    assert!(recorded.len() >= 10, "{} recorded", recorded.len());
    // The recorder and station A are separate participants, each matched with the vehicle
    // after its own (secure) handshake: either may hear the first states the other missed.
    // From the moment both listened, the recording is station A's history.
    let history_a = track(&d.join("a.db"));
    let mut recorded_sorted = recorded.clone();
    recorded_sorted.sort_by_key(|s| s.timestamp_ms);
    let both = recorded_sorted[0]
        .timestamp_ms
        .max(history_a[0].timestamp_ms);
    let since = |v: &[StateVector]| -> Vec<StateVector> {
        v.iter()
            .filter(|s| s.timestamp_ms >= both)
            .cloned()
            .collect()
    };
    assert_eq!(
        since(&recorded_sorted),
        since(&history_a),
        "from the moment both listened, the recording holds what station A accepted"
    );
    // The station's own recording holds every state it accepted (and any it refused).
    assert!(
        station_a.log().contains("recording closed"),
        "{}",
        station_a.log()
    );
    let (by_station, error) = recorded_states(&d.join("rec-station"));
    assert!(
        error.is_none(),
        "a station stopped with SIGTERM closes its file: {error:?}"
    );
    for s in &history_a {
        assert!(
            by_station.contains(s),
            "{s:?} is in station A's history but not in its recording"
        );
    }
    if let Some(python) = python_with_mcap() {
        let file = shoal_recorder::mcap_files(&rec).unwrap().remove(0);
        let v = check_mcap(&python, &file, "summary");
        assert_eq!(v["error"], Value::Null, "{v}");
        assert_eq!(
            v["counts"]["shoal/state_vector"],
            recorded.len() as u64,
            "{v}"
        );
        assert_eq!(v["counts"]["shoal/vehicle_announcement"], 1, "{v}");
        assert_eq!(
            v["channels"]["shoal/state_vector"]["schema"],
            "shoal::StateVector"
        );
    }

    // A fresh station on another domain; the replay, at 4x, publishes as rec-auv.
    let port_b = free_port();
    let mut station_b = station(d, "station-b", "b.db", port_b, 172);
    let mut replay = Proc::start("replay", d, 172, &["replay", "rec", "--speed", "4"]);
    let status = replay.wait(120);
    assert!(status.success(), "{}", replay.log());
    assert!(
        replay.log().contains("replaying as this vehicle"),
        "{}",
        replay.log()
    );
    let deadline = Instant::now() + Duration::from_secs(30);
    while fleet_states(port_b, "rec-auv") < recorded.len() as u64 {
        assert!(
            Instant::now() < deadline,
            "station B accepted {} of {}: {}\n---replay---\n{}",
            fleet_states(port_b, "rec-auv"),
            recorded.len(),
            station_b.log(),
            replay.log()
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    station_b.signal("-TERM");
    station_b.wait(30);
    let replayed = track(&d.join("b.db"));
    assert_eq!(replayed.len(), recorded_sorted.len());
    assert_eq!(
        replayed, recorded_sorted,
        "station B's history is the recording"
    );
}

/// With security on, a vehicle the key store has no identity for is refused by name
/// rather than given one: a recording cannot mint identities.
#[test]
fn replay_refuses_a_vehicle_without_an_identity_in_the_key_store() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let init = Command::new(env!("CARGO_BIN_EXE_shoal"))
        .args(["keys", "init"])
        .current_dir(d)
        .output()
        .unwrap();
    assert!(init.status.success(), "{init:?}");
    // A recording of one state vector of a vehicle never issued an identity, written
    // without DDS.
    let config = shoal_recorder::RecorderConfig {
        directory: d.join("rec"),
        ..shoal_recorder::RecorderConfig::default()
    };
    let mut w = shoal_recorder::RecordWriter::new(&config).unwrap();
    let s = Sample::StateVector(state(0));
    w.write(Topic::StateVector, 1, 1, &s.encode().unwrap())
        .unwrap();
    w.close().unwrap();
    drop(w);
    let mut replay = Proc::start("replay", d, 174, &["replay", "rec", "--speed", "max"]);
    let status = replay.wait(60);
    assert!(!status.success());
    let log = replay.log();
    assert!(
        log.contains("cannot publish as vehicle \"kill-1\""),
        "{log}"
    );
    assert!(log.contains("no identity"), "{log}");
    assert!(
        !mentions(d, "kill-1"),
        "no file in the key store is named after the vehicle"
    );
}

/// Whether a path under `dir` (other than the recording and logs) names `what`.
fn mentions(dir: &Path, what: &str) -> bool {
    std::fs::read_dir(dir).unwrap().flatten().any(|e| {
        let p = e.path();
        let named = e.file_name().to_string_lossy().contains(what);
        named || (p.is_dir() && p.file_name().is_some_and(|n| n != "rec") && mentions(&p, what))
    })
}

fn state(i: u32) -> StateVector {
    StateVector {
        vehicle_id: "kill-1".into(),
        timestamp_ms: shoal_model::now_ms() + i64::from(i),
        latitude_deg: 63.0 + f64::from(i) * 1e-6,
        longitude_deg: 10.0,
        depth_m: 3.0,
        altitude_m: shoal_model::UNKNOWN,
        speed_mps: 1.0,
        yaw_deg: 10.0,
        pitch_deg: 0.0,
        roll_deg: 0.0,
        battery_pct: 50.0,
    }
}

/// A recorder killed with SIGKILL mid-file: what was published up to a second or two
/// before the kill is in complete chunks, which the Python reader and our replay both
/// read; the replay names the byte offset where the file stops.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_recorder_killed_with_sigkill_leaves_a_file_read_to_its_last_chunk() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut recorder = Proc::start(
        "recorder",
        d,
        173,
        &[
            "--insecure",
            "record",
            "--output",
            "rec",
            "--topics",
            "shoal/state_vector",
        ],
    );
    let pubsub = dds(173);
    let writer = pubsub
        .writer::<StateVector>(WriterOptions::new(Priority::Telemetry))
        .unwrap();
    let start = Instant::now();
    while writer.matched_readers() < 1 {
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "{}",
            recorder.log()
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    // 100 samples a second for 3.5 s, then SIGKILL.
    let mut sent_at = Vec::new();
    let t0 = shoal_model::now_ms();
    for i in 0..350u32 {
        let mut s = state(i);
        s.timestamp_ms = t0 + i64::from(i);
        writer.write(s).await.unwrap();
        sent_at.push(Instant::now());
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    recorder.child.kill().unwrap();
    let killed = Instant::now();
    recorder.wait(10);

    let rec = d.join("rec");
    let file = shoal_recorder::mcap_files(&rec).unwrap().remove(0);
    let len = std::fs::metadata(&file).unwrap().len();
    let (states, error) = recorded_states(&rec);
    let error = error.expect("a killed recorder's file has no footer");
    assert!(error.offset() <= len, "{error}");
    assert!(matches!(error, ReadError::Truncated { .. }), "{error}");
    // In order, none missing, none invented.
    for (i, s) in states.iter().enumerate() {
        assert_eq!(s.timestamp_ms, t0 + i as i64, "sample {i}");
    }
    // Crash safety: whatever was sent 2 s before the kill is on disk.
    let must = sent_at
        .iter()
        .filter(|t| killed.duration_since(**t) > Duration::from_secs(2))
        .count();
    assert!(
        states.len() >= must,
        "{} recorded, {must} sent 2 s before the kill",
        states.len()
    );
    assert!(must >= 100);

    if let Some(python) = python_with_mcap() {
        let v = check_mcap(&python, &file, "stream");
        assert_ne!(
            v["error"],
            Value::Null,
            "the reference reader sees the cut: {v}"
        );
        assert_eq!(
            v["counts"]["shoal/state_vector"],
            states.len() as u64,
            "{v}"
        );
    }

    // Our replay of the cut file: every complete chunk's samples, then the offset.
    let sub = dds(174);
    let mut received = sub.subscribe::<StateVector>().unwrap();
    let mut replay = Proc::start(
        "replay",
        d,
        174,
        &["--insecure", "replay", "rec", "--speed", "2"],
    );
    let mut got = Vec::new();
    while got.len() < states.len() {
        let next = tokio::time::timeout(Duration::from_secs(30), received.next())
            .await
            .unwrap_or_else(|_| {
                panic!(
                    "{} of {} replayed; {}",
                    got.len(),
                    states.len(),
                    replay.log()
                )
            });
        got.push(next.unwrap().unwrap().0.into_inner());
    }
    assert_eq!(got, states);
    let status = replay.wait(60);
    assert!(
        !status.success(),
        "a damaged file fails the replay after replaying it"
    );
    let log = replay.log();
    assert!(
        log.contains(&format!("byte offset {}", error.offset())),
        "{log}"
    );
    assert!(
        log.contains(&format!("{} published", states.len())),
        "{log}"
    );
}
