//! The station's own health, measured where it can be: the bus (tasks' matched readers),
//! the history writer (lag, whether its thread runs), the semantic store's lock (how long
//! taking it waits now), disabled rules and the clock's skew. [`HealthThresholds`] say
//! when these figures make the station *degraded*; [`StationHealth::verdict`] applies
//! them. The console serves the result at `/api/health` and `/metrics`.
//!
//! Measuring never blocks for long: the lock is probed with `try_lock` until a give-up
//! time, so a station whose semantic lock is stuck answers "stuck for at least this long"
//! instead of hanging its health check too.

use std::sync::TryLockError;
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};
use shoal_history::WaitError;

use crate::core::StationHandle;
use crate::rules::RuleDoc;

/// When the station counts as degraded (`[console.health]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HealthThresholds {
    /// Records submitted to the history but not yet committed above which the writer is
    /// behind. Default 20,000: a tenth of the writer's queue, minutes of a large fleet.
    pub max_history_lag: u64,
    /// Seconds without any commit while records are pending, after which the writer is
    /// stalled (a locked database, a full disk). Default 10.
    pub max_commit_stall_s: f64,
    /// Milliseconds a probe may wait for the semantic store's lock; longer means ingest is
    /// held up (a slow rule, a huge update). Default 500.
    pub max_semantic_lock_wait_ms: u64,
    /// Clock skew (system clock against station time) reported as a warning, not a
    /// degradation: the station keeps its monotonic time. Milliseconds; default 2,000.
    pub warn_clock_skew_ms: u64,
}

impl Default for HealthThresholds {
    fn default() -> Self {
        Self {
            max_history_lag: 20_000,
            max_commit_stall_s: 10.0,
            max_semantic_lock_wait_ms: 500,
            warn_clock_skew_ms: 2_000,
        }
    }
}

/// The DDS side as the station sees it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct DdsHealth {
    /// Whether the station's participant is up. The station's run loop owns the
    /// participant and the history writer and ends both together, so a stopped writer
    /// means the station has left the bus.
    pub participant_up: bool,
    /// Remote readers of tasks matched now (0 when no vehicle listens; not an error).
    pub task_readers: i32,
}

/// The history writer.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct HistoryHealth {
    /// Whether the writer thread runs.
    pub writer_running: bool,
    /// Records handed to the writer so far.
    pub submitted: u64,
    /// Records committed so far.
    pub committed: u64,
    /// Submitted but not yet committed.
    pub lag: u64,
    /// Failed commit attempts so far (each retried).
    pub retries: u64,
    /// Milliseconds since the last commit was seen, when one has been (filled in by
    /// whoever watches commits, see [`StationHandle::subscribe_history_committed`]).
    pub since_last_commit_ms: Option<u64>,
}

/// The semantic store.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct SemanticHealth {
    /// How long the probe waited for the store's lock, ms (at most the give-up time).
    pub lock_wait_ms: u64,
    /// False when the probe gave up: the lock was held at least `lock_wait_ms`.
    pub lock_taken: bool,
    /// Identifiers of disabled rules, built-in ones included; `None` when the lock was
    /// not taken, so they could not be read.
    pub disabled_rules: Option<Vec<String>>,
}

/// One measurement of the station's health, before thresholds are applied.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct StationHealth {
    /// The bus.
    pub dds: DdsHealth,
    /// The history writer.
    pub history: HistoryHealth,
    /// The semantic store.
    pub semantic: SemanticHealth,
    /// System clock minus station time, ms (see [`StationHandle::clock_skew_ms`]).
    pub clock_skew_ms: i64,
}

/// What the thresholds make of a [`StationHealth`].
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct HealthVerdict {
    /// Why the station is degraded; empty when it is not.
    pub degraded: Vec<String>,
    /// What an operator should know that does not degrade the station.
    pub warnings: Vec<String>,
}

impl HealthVerdict {
    /// True when nothing degrades the station.
    pub fn is_ok(&self) -> bool {
        self.degraded.is_empty()
    }
}

impl StationHealth {
    /// Applies `t`: degraded when the station has left the bus, the history writer stopped,
    /// lags by more than `max_history_lag`, or committed nothing for `max_commit_stall_s`
    /// while records are pending, or when the semantic lock waited longer than
    /// `max_semantic_lock_wait_ms`. Clock skew and disabled rules are warnings.
    pub fn verdict(&self, t: &HealthThresholds) -> HealthVerdict {
        let mut v = HealthVerdict::default();
        if !self.dds.participant_up {
            v.degraded
                .push("the station's DDS participant is gone (the station stopped)".into());
        }
        let h = &self.history;
        if !h.writer_running {
            v.degraded.push("the history writer stopped".into());
        }
        if h.lag > t.max_history_lag {
            v.degraded.push(format!(
                "the history writer is {} records behind (more than {})",
                h.lag, t.max_history_lag
            ));
        }
        let stall_ms = duration_ms(Duration::from_secs_f64(t.max_commit_stall_s.max(0.0)));
        if let Some(since) = h.since_last_commit_ms
            && h.lag > 0
            && since > stall_ms
        {
            v.degraded.push(format!(
                "no history commit for {} s while {} records are pending",
                since / 1000,
                h.lag
            ));
        }
        let s = &self.semantic;
        if !s.lock_taken || s.lock_wait_ms > t.max_semantic_lock_wait_ms {
            v.degraded.push(format!(
                "the semantic store's lock waited {}{} ms (more than {})",
                if s.lock_taken { "" } else { "at least " },
                s.lock_wait_ms,
                t.max_semantic_lock_wait_ms
            ));
        }
        if let Some(rules) = s.disabled_rules.as_ref().filter(|r| !r.is_empty()) {
            v.warnings.push(format!("{} rule(s) disabled", rules.len()));
        }
        if self.clock_skew_ms.unsigned_abs() > t.warn_clock_skew_ms {
            v.warnings.push(format!(
                "the system clock is {} ms from station time; the station keeps its own",
                self.clock_skew_ms
            ));
        }
        v
    }
}

fn duration_ms(d: Duration) -> u64 {
    u64::try_from(d.as_millis()).unwrap_or(u64::MAX)
}

impl StationHandle {
    /// Measures the station's health now, waiting at most `lock_give_up` for the semantic
    /// store's lock. Blocks up to that long: call it off the async threads.
    pub fn health(&self, lock_give_up: Duration) -> StationHealth {
        let (lock_wait, disabled) = self.probe_semantic_lock(lock_give_up);
        let writer = &self.core.history;
        let stats = writer.stats();
        let committed = writer.committed();
        // A zero wait for the next record tells a stopped writer from a running one
        // without blocking (a record already committed answers Ok: running).
        let writer_running = !matches!(
            writer.wait_committed(committed.saturating_add(1), Duration::ZERO),
            Err(WaitError::Stopped { .. })
        );
        StationHealth {
            dds: DdsHealth {
                participant_up: writer_running,
                task_readers: self.task_readers(),
            },
            history: HistoryHealth {
                writer_running,
                submitted: stats.submitted,
                committed,
                lag: stats.submitted.saturating_sub(committed),
                retries: stats.retries,
                since_last_commit_ms: None,
            },
            semantic: SemanticHealth {
                lock_wait_ms: duration_ms(lock_wait),
                lock_taken: disabled.is_some(),
                disabled_rules: disabled,
            },
            clock_skew_ms: self.clock_skew_ms(),
        }
    }

    /// The history's committed record number as a `watch` channel: whoever wants the
    /// time of the last commit (the console's health) awaits its changes.
    pub fn subscribe_history_committed(&self) -> tokio::sync::watch::Receiver<u64> {
        self.core.history.subscribe_committed()
    }

    /// How long taking the semantic store's lock waits now, and the disabled rules read
    /// under it; `None` for the rules when the lock stayed taken past `give_up`.
    ///
    /// `try_lock` with a short, growing pause between attempts: the probe never queues on
    /// the lock itself, so it cannot delay ingest, and it costs nothing when the lock is
    /// free (the common case: one attempt).
    fn probe_semantic_lock(&self, give_up: Duration) -> (Duration, Option<Vec<String>>) {
        let start = Instant::now();
        let mut pause = Duration::from_micros(50);
        loop {
            let guard = match self.core.semantic.try_lock() {
                Ok(g) => Some(g),
                Err(TryLockError::Poisoned(p)) => Some(p.into_inner()),
                Err(TryLockError::WouldBlock) => None,
            };
            if let Some(sem) = guard {
                let waited = start.elapsed();
                let disabled = sem
                    .rules()
                    .iter()
                    .filter(|r| !r.enabled)
                    .map(|r| RuleDoc::from_info(r).id)
                    .collect();
                return (waited, Some(disabled));
            }
            let waited = start.elapsed();
            if waited >= give_up {
                return (waited, None);
            }
            std::thread::sleep(pause.min(give_up - waited));
            pause = (pause * 2).min(Duration::from_millis(5));
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;
    use crate::testing::Fixture;

    fn healthy() -> StationHealth {
        StationHealth {
            dds: DdsHealth {
                participant_up: true,
                task_readers: 0,
            },
            history: HistoryHealth {
                writer_running: true,
                submitted: 10,
                committed: 10,
                lag: 0,
                retries: 0,
                since_last_commit_ms: Some(60_000),
            },
            semantic: SemanticHealth {
                lock_wait_ms: 0,
                lock_taken: true,
                disabled_rules: Some(vec![]),
            },
            clock_skew_ms: 0,
        }
    }

    /// Makes a healthy measurement unhealthy in one way.
    type Spoil = fn(&mut StationHealth);

    #[test]
    fn each_condition_degrades_and_says_why() {
        let t = HealthThresholds::default();
        assert_eq!(healthy().verdict(&t), HealthVerdict::default());
        let cases: [(Spoil, &str); 6] = [
            (|h| h.dds.participant_up = false, "DDS participant"),
            (|h| h.history.writer_running = false, "writer stopped"),
            (|h| h.history.lag = 20_001, "20001 records behind"),
            (
                |h| {
                    h.history.lag = 1;
                    h.history.since_last_commit_ms = Some(11_000);
                },
                "no history commit for 11 s",
            ),
            (|h| h.semantic.lock_wait_ms = 501, "waited 501 ms"),
            (
                |h| {
                    h.semantic.lock_taken = false;
                    h.semantic.disabled_rules = None;
                },
                "at least",
            ),
        ];
        for (spoil, why) in cases {
            let mut h = healthy();
            spoil(&mut h);
            let v = h.verdict(&t);
            assert!(!v.is_ok(), "{why}");
            assert!(v.degraded.iter().any(|r| r.contains(why)), "{why}: {v:?}");
        }
    }

    #[test]
    fn an_idle_writer_with_nothing_pending_is_not_stalled() {
        let mut h = healthy();
        h.history.since_last_commit_ms = Some(3_600_000);
        assert!(h.verdict(&HealthThresholds::default()).is_ok());
    }

    #[test]
    fn skew_and_disabled_rules_warn_without_degrading() {
        let mut h = healthy();
        h.clock_skew_ms = -3_600_000;
        h.semantic.disabled_rules = Some(vec!["low_battery".into()]);
        let v = h.verdict(&HealthThresholds::default());
        assert!(v.is_ok());
        assert_eq!(v.warnings.len(), 2, "{v:?}");
    }

    #[test]
    fn a_held_semantic_lock_is_measured_and_the_probe_gives_up() {
        let f = Fixture::new();
        let h = f.h.health(Duration::from_millis(200));
        assert!(
            h.semantic.lock_taken && h.semantic.lock_wait_ms < 200,
            "{h:?}"
        );
        assert!(h.history.writer_running && h.dds.participant_up);
        let core = f.h.core.clone();
        let (held_tx, held_rx) = std::sync::mpsc::channel();
        let holder = std::thread::spawn(move || {
            let _sem = crate::core::lock(&core.semantic);
            held_tx.send(()).unwrap();
            std::thread::sleep(Duration::from_millis(300));
        });
        held_rx.recv().unwrap();
        let h = f.h.health(Duration::from_millis(100));
        assert!(!h.semantic.lock_taken, "{h:?}");
        assert!(h.semantic.lock_wait_ms >= 100, "{h:?}");
        assert!(!h.verdict(&HealthThresholds::default()).is_ok());
        holder.join().unwrap();
    }
}
