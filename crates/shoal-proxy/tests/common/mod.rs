//! Running the Python test peers of `tests/peers/` (installed into the repository's
//! `.venv` by `scripts/install-proxy-peers.sh`).
//!
//! A peer that cannot run here (no venv, or its module not installed) skips its test with
//! the reason printed, unless `SHOAL_INTEROP_REQUIRED=1`, when the test fails: CI sets it.

// A test helper: a failed step is a failed test, so it panics with the reason.
#![allow(dead_code, clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::Duration;

use serde_json::Value;
use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::process::{Child, ChildStdin, Command};
use tokio::sync::mpsc;

/// The repository root, from this crate's manifest directory.
pub fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// The venv's Python, if it can import `module`; else why not.
fn python_with(module: &str) -> Result<PathBuf, String> {
    let python = repo().join(".venv/bin/python");
    if !python.exists() {
        return Err(format!(
            "{} not found: run scripts/install-test-deps.sh and scripts/install-proxy-peers.sh",
            python.display()
        ));
    }
    let ok = std::process::Command::new(&python)
        .args(["-c", &format!("import {module}")])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .map_err(|e| format!("cannot run {}: {e}", python.display()))?;
    if !ok.success() {
        return Err(format!(
            "Python module {module} is not installed in .venv: run scripts/install-proxy-peers.sh"
        ));
    }
    Ok(python)
}

/// A running peer program: its JSON lines from stdout, and its stdin (closing it stops it).
pub struct Peer {
    child: Child,
    stdin: Option<ChildStdin>,
    lines: mpsc::UnboundedReceiver<Value>,
    backlog: Vec<Value>,
    name: String,
}

/// Starts `tests/peers/<script>` with `args`, or returns `None` (after printing why) when
/// the peer cannot run here and interop is not required.
pub fn start_peer(script: &str, module: &str, args: &[String]) -> Option<Peer> {
    let python = match python_with(module) {
        Ok(p) => p,
        Err(reason) => {
            assert!(
                std::env::var("SHOAL_INTEROP_REQUIRED").as_deref() != Ok("1"),
                "peer {script} is required (SHOAL_INTEROP_REQUIRED=1) but cannot run: {reason}"
            );
            eprintln!("SKIPPED: peer {script} cannot run: {reason}");
            return None;
        }
    };
    Some(spawn(&python, script, args))
}

/// Starts a peer with a Python already known to work (for restarts).
pub fn restart_peer(script: &str, module: &str, args: &[String]) -> Peer {
    let python = python_with(module).unwrap();
    spawn(&python, script, args)
}

fn spawn(python: &Path, script: &str, args: &[String]) -> Peer {
    let mut child = Command::new(python)
        .arg(repo().join("tests/peers").join(script))
        .args(args)
        .env("PYTHONUNBUFFERED", "1")
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .kill_on_drop(true)
        .spawn()
        .unwrap_or_else(|e| panic!("cannot start peer {script}: {e}"));
    let stdout = child.stdout.take().unwrap();
    let stdin = child.stdin.take();
    let (tx, lines) = mpsc::unbounded_channel();
    let name = script.to_string();
    let tag = name.clone();
    tokio::spawn(async move {
        let mut reader = BufReader::new(stdout).lines();
        while let Ok(Some(line)) = reader.next_line().await {
            match serde_json::from_str::<Value>(&line) {
                Ok(v) => {
                    if tx.send(v).is_err() {
                        break;
                    }
                }
                Err(_) => eprintln!("[{tag}] {line}"),
            }
        }
    });
    Peer {
        child,
        stdin,
        lines,
        backlog: Vec::new(),
        name,
    }
}

impl Peer {
    /// The next line whose `event` is `event`, within `secs` seconds; other lines are kept
    /// for later calls.
    pub async fn expect(&mut self, event: &str, secs: u64) -> Value {
        if let Some(i) = self.backlog.iter().position(|v| v["event"] == event) {
            return self.backlog.remove(i);
        }
        let deadline = tokio::time::Instant::now() + Duration::from_secs(secs);
        loop {
            let line = tokio::time::timeout_at(deadline, self.lines.recv())
                .await
                .unwrap_or_else(|_| {
                    panic!(
                        "peer {} printed no {event:?} within {secs} s (seen: {:?})",
                        self.name, self.backlog
                    )
                })
                .unwrap_or_else(|| panic!("peer {} exited before {event:?}", self.name));
            if line["event"] == event {
                return line;
            }
            self.backlog.push(line);
        }
    }

    /// Stops the peer now (as a crash would), and waits for it to be gone.
    pub async fn kill(mut self) {
        self.stdin.take();
        let _ = self.child.kill().await;
    }
}

/// Waits up to `secs` seconds for `f` to give a value, polling every 50 ms.
pub async fn eventually<T>(secs: u64, what: &str, mut f: impl FnMut() -> Option<T>) -> T {
    let deadline = tokio::time::Instant::now() + Duration::from_secs(secs);
    loop {
        if let Some(v) = f() {
            return v;
        }
        assert!(
            tokio::time::Instant::now() < deadline,
            "timed out after {secs} s waiting for {what}"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// A task order outside any mission.
pub fn order(id: &str, task: shoal_model::Task) -> shoal_proxy::TaskOrder {
    shoal_proxy::TaskOrder {
        task_id: id.into(),
        mission_id: String::new(),
        issued_ms: shoal_model::now_ms(),
        task,
    }
}

/// Reads an adapter's outputs until `task_id` ends; the states it went through, with
/// progress and message.
pub async fn run_to_end<A: shoal_proxy::VehicleAdapter>(
    adapter: &mut A,
    task_id: &str,
) -> Vec<(shoal_model::TaskState, f64, String)> {
    let mut states = Vec::new();
    loop {
        let out = tokio::time::timeout(Duration::from_secs(30), adapter.next_output())
            .await
            .unwrap_or_else(|_| panic!("{task_id} did not end within 30 s: {states:?}"))
            .unwrap();
        if let shoal_proxy::VehicleOutput::Task(u) = out
            && u.task_id == task_id
        {
            states.push((u.state, u.progress_pct, u.message.clone()));
            if u.state.is_final() {
                return states;
            }
        }
    }
}
