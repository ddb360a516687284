//! Whether RustDDS is still running in this process.
//!
//! RustDDS ends its participant's event loop and discovery thread on any error from
//! `epoll_wait`, `EINTR` included, and Linux returns `EINTR` from `epoll_wait` to every
//! thread of a process that was stopped and resumed (SIGSTOP/SIGCONT, Ctrl-Z then `fg`, a
//! debugger) and after a system suspend. The participant then neither sends nor receives,
//! and says nothing: a station would keep serving stale data and a vehicle would stop
//! reporting. The library exposes neither thread, so a watchdog thread compares the
//! number of Shoal participants alive with the RustDDS threads Linux lists for the
//! process (`/proc/self/task/*/comm`, where RustDDS names them), and records a failure
//! when some are missing for three seconds in a row. Daemons poll [`failure`] and exit
//! with its text, so a supervisor can restart them.

use std::sync::OnceLock;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use tracing::error;

/// Shoal participants alive in this process.
static LIVE: AtomicUsize = AtomicUsize::new(0);
/// Set once, when RustDDS threads went missing.
static FAILED: OnceLock<String> = OnceLock::new();
static STARTED: std::sync::Once = std::sync::Once::new();

/// How the two threads of a RustDDS participant are named, as `comm` shows them (15 bytes).
const EVENT_LOOP: &str = "RustDDS Partici";
const DISCOVERY: &str = "RustDDS discove";
/// Checks in a row with threads missing before the participant counts as stopped.
const CHECKS: u32 = 3;

/// Counts one live participant for as long as it is held.
#[derive(Debug)]
pub(crate) struct Registration(());

impl Registration {
    /// Called once the participant's threads are running.
    pub(crate) fn new() -> Self {
        LIVE.fetch_add(1, Ordering::SeqCst);
        STARTED.call_once(|| {
            let spawned = std::thread::Builder::new()
                .name("dds-watchdog".into())
                .spawn(watch);
            if let Err(e) = spawned {
                error!(error = %e, "cannot start the DDS watchdog");
            }
        });
        Self(())
    }
}

impl Drop for Registration {
    fn drop(&mut self) {
        LIVE.fetch_sub(1, Ordering::SeqCst);
    }
}

/// Why DDS stopped working in this process, once it has: RustDDS threads are gone while
/// participants that need them are alive. Nothing recovers them; the process must restart.
pub fn failure() -> Option<&'static str> {
    FAILED.get().map(String::as_str)
}

/// RustDDS event loops and discovery threads running in this process; `None` where
/// `/proc` cannot tell (the watchdog then stops watching).
fn rustdds_threads() -> Option<(usize, usize)> {
    let (mut event_loops, mut discovery) = (0, 0);
    for task in std::fs::read_dir("/proc/self/task").ok()? {
        let Ok(task) = task else { continue };
        // A thread may end between the listing and the read: not counted, as it should.
        let Ok(comm) = std::fs::read_to_string(task.path().join("comm")) else {
            continue;
        };
        if comm.starts_with(EVENT_LOOP) {
            event_loops += 1;
        } else if comm.starts_with(DISCOVERY) {
            discovery += 1;
        }
    }
    Some((event_loops, discovery))
}

fn watch() {
    let mut missing_for = 0;
    loop {
        std::thread::sleep(Duration::from_secs(1));
        let live = LIVE.load(Ordering::SeqCst);
        let Some((event_loops, discovery)) = rustdds_threads() else {
            return;
        };
        if live == 0 || event_loops.min(discovery) >= live {
            missing_for = 0;
            continue;
        }
        missing_for += 1;
        if missing_for < CHECKS {
            continue;
        }
        let text = format!(
            "DDS stopped in this process: {live} participant(s) but {event_loops} RustDDS event loop(s) and {discovery} discovery thread(s) left. RustDDS ends them when a system call is interrupted, as when the process is stopped and resumed (SIGSTOP/SIGCONT, Ctrl-Z) or the machine suspends; nothing is sent or received any more, restart the process"
        );
        error!("{text}");
        let _ = FAILED.set(text);
        return;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn this_process_lists_its_threads_and_has_no_rustdds_ones_without_a_participant() {
        // Unit tests create no participant in this module; other tests of the crate may,
        // so only the listing itself is checked.
        assert!(
            rustdds_threads().is_some(),
            "/proc/self/task is readable on Linux"
        );
        assert!(failure().is_none());
    }
}
