//! What the vehicle links of the MAVLink, IMC and ROS 2 adapters do the same way.
//!
//! Each of those adapters runs a link task that owns the vehicle's socket or topics and
//! hands its results to the proxy through a channel. Three parts of that are the same
//! whatever the protocol, and live here:
//!
//! - [`Outputs`]: the link's end of the channel. It never waits for the proxy (the link
//!   must go on reading the vehicle): an output the proxy has no room for is dropped and
//!   counted.
//! - [`Liveness`]: when the vehicle was last heard, when its silence makes it lost, and
//!   how long it had been silent when it comes back.
//! - [`Outputs::replaced`]: what becomes of the task a new one replaces (one task at a
//!   time on every vehicle): done if it was holding until the next task, else aborted.
//! - [`link_counters!`]: a link's counters, declared once for both the public snapshot and
//!   the atomics the link task bumps.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use shoal_model::{EventKind, Severity, TaskState, now_ms};
use tokio::sync::mpsc;
use tokio::time::Instant;

use crate::adapter::{TaskUpdate, VehicleEvent, VehicleOutput};

/// Outputs buffered for the proxy before new ones are dropped (and counted).
pub(crate) const OUTPUT_QUEUE: usize = 1024;

/// Adds one to a counter.
pub(crate) fn bump(c: &AtomicU64) {
    c.fetch_add(1, Ordering::Relaxed);
}

/// Declares a link's counters from one list of fields: the public snapshot struct
/// `$snapshot` (each field with its doc) and a private `Counters` of atomics that the link
/// task bumps and the adapter reads with `Counters::snapshot`. Every link also counts
/// `outputs_dropped`, shared with its [`Outputs`].
macro_rules! link_counters {
    (
        $(#[doc = $sdoc:literal])*
        pub struct $snapshot:ident {
            $( $(#[doc = $doc:literal])* $field:ident, )*
        }
    ) => {
        $(#[doc = $sdoc])*
        #[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
        pub struct $snapshot {
            $( $(#[doc = $doc])* pub $field: u64, )*
            /// Outputs dropped because the proxy was not reading them.
            pub outputs_dropped: u64,
        }

        #[derive(Debug, Default)]
        struct Counters {
            $( $field: std::sync::atomic::AtomicU64, )*
            /// Shared with the link's `Outputs`, which counts its drops.
            outputs_dropped: std::sync::Arc<std::sync::atomic::AtomicU64>,
        }

        impl Counters {
            fn snapshot(&self) -> $snapshot {
                let g = |c: &std::sync::atomic::AtomicU64| {
                    c.load(std::sync::atomic::Ordering::Relaxed)
                };
                $snapshot {
                    $( $field: g(&self.$field), )*
                    outputs_dropped: g(&self.outputs_dropped),
                }
            }
        }
    };
}
pub(crate) use link_counters;

/// The link task's end of the outputs channel.
#[derive(Debug)]
pub(crate) struct Outputs {
    tx: mpsc::Sender<VehicleOutput>,
    dropped: Arc<AtomicU64>,
}

impl Outputs {
    /// A channel of [`OUTPUT_QUEUE`] outputs; drops are counted in `dropped` (the
    /// adapter's `outputs_dropped` counter).
    pub(crate) fn channel(dropped: Arc<AtomicU64>) -> (Self, mpsc::Receiver<VehicleOutput>) {
        let (tx, rx) = mpsc::channel(OUTPUT_QUEUE);
        (Self { tx, dropped }, rx)
    }

    /// Hands `out` to the proxy, or drops and counts it when the queue is full.
    pub(crate) fn send(&self, out: VehicleOutput) {
        if self.tx.try_send(out).is_err() {
            self.dropped.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// A task's new state; progress is clamped to [0, 100], as statuses require.
    pub(crate) fn task(&self, task_id: &str, state: TaskState, progress: f64, message: &str) {
        self.send(VehicleOutput::Task(TaskUpdate::new(
            task_id,
            state,
            progress.clamp(0.0, 100.0),
            message,
        )));
    }

    /// An event that happened now; `task_id` empty when it concerns no task.
    pub(crate) fn event(&self, severity: Severity, kind: EventKind, task_id: &str, text: String) {
        self.send(VehicleOutput::Event(VehicleEvent {
            timestamp_ms: now_ms(),
            severity,
            kind,
            task_id: task_id.to_string(),
            text,
        }));
    }

    /// Ends the task `old_task` because task `by` replaces it: a task holding until the
    /// next one is done by then (unless `by` is an abort); any other is aborted, with
    /// `last_progress` and why.
    pub(crate) fn replaced(
        &self,
        old_task: &str,
        last_progress: f64,
        held_until_next: bool,
        by: &str,
        abort: bool,
    ) {
        if held_until_next && !abort {
            self.task(old_task, TaskState::Done, 100.0, "held until the next task");
        } else {
            let why = if abort {
                format!("aborted by task {by}")
            } else {
                format!("superseded by task {by}")
            };
            self.task(old_task, TaskState::Aborted, last_progress, &why);
        }
    }
}

/// When the vehicle was last heard, and whether its silence makes it lost.
#[derive(Debug)]
pub(crate) struct Liveness {
    lost_after: Duration,
    last_heard: Option<Instant>,
    /// When the silence that made it lost began.
    lost_since: Option<Instant>,
}

/// What hearing the vehicle changed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Heard {
    /// It had never been heard before.
    pub(crate) first: bool,
    /// It was lost, and had been silent this long.
    pub(crate) back_after: Option<Duration>,
}

impl Liveness {
    /// A vehicle not heard yet, lost after `lost_after_ms` of silence once it has been.
    pub(crate) fn new(lost_after_ms: u64) -> Self {
        Self {
            lost_after: Duration::from_millis(lost_after_ms),
            last_heard: None,
            lost_since: None,
        }
    }

    /// The vehicle spoke now.
    pub(crate) fn heard(&mut self) -> Heard {
        let first = self.last_heard.is_none();
        self.last_heard = Some(Instant::now());
        Heard {
            first,
            back_after: self.lost_since.take().map(|t| t.elapsed()),
        }
    }

    /// Checks the silence; true once, when it has just made the vehicle lost.
    pub(crate) fn check(&mut self) -> bool {
        match self.last_heard {
            Some(t) if self.lost_since.is_none() && t.elapsed() > self.lost_after => {
                self.lost_since = Some(t);
                true
            }
            _ => false,
        }
    }

    /// True from [`check`](Self::check) reporting it lost until it is heard again.
    pub(crate) fn is_lost(&self) -> bool {
        self.lost_since.is_some()
    }

    /// The silence after which the vehicle is lost.
    pub(crate) fn lost_after(&self) -> Duration {
        self.lost_after
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test(start_paused = true)]
    async fn silence_makes_a_heard_vehicle_lost_once_and_hearing_it_brings_it_back() {
        let mut l = Liveness::new(1000);
        tokio::time::advance(Duration::from_secs(5)).await;
        assert!(!l.check(), "never heard: not lost");
        assert_eq!(
            l.heard(),
            Heard {
                first: true,
                back_after: None
            }
        );
        tokio::time::advance(Duration::from_millis(900)).await;
        assert!(!l.check());
        tokio::time::advance(Duration::from_millis(200)).await;
        assert!(l.check());
        assert!(!l.check(), "reported once");
        assert!(l.is_lost());
        tokio::time::advance(Duration::from_millis(400)).await;
        let h = l.heard();
        assert!(!h.first);
        assert_eq!(h.back_after, Some(Duration::from_millis(1500)));
        assert!(!l.is_lost());
    }

    #[tokio::test]
    async fn a_full_queue_drops_and_counts() {
        let dropped = Arc::new(AtomicU64::new(0));
        let (out, mut rx) = Outputs::channel(Arc::clone(&dropped));
        for _ in 0..OUTPUT_QUEUE + 2 {
            out.task("t", TaskState::Running, 150.0, "");
        }
        assert_eq!(dropped.load(Ordering::Relaxed), 2);
        let Some(VehicleOutput::Task(u)) = rx.recv().await else {
            panic!("a task update")
        };
        assert_eq!(u.progress_pct, 100.0, "clamped");
    }

    #[tokio::test]
    async fn a_replaced_task_is_aborted_unless_it_held_until_the_next() {
        let (out, mut rx) = Outputs::channel(Arc::default());
        out.replaced("a", 40.0, false, "b", false);
        out.replaced("b", 0.0, true, "c", false);
        out.replaced("c", 0.0, true, "stop", true);
        let mut got = Vec::new();
        while let Ok(VehicleOutput::Task(u)) = rx.try_recv() {
            got.push((u.task_id, u.state, u.progress_pct, u.message));
        }
        assert_eq!(
            got,
            [
                (
                    "a".into(),
                    TaskState::Aborted,
                    40.0,
                    "superseded by task b".into()
                ),
                (
                    "b".into(),
                    TaskState::Done,
                    100.0,
                    "held until the next task".into()
                ),
                (
                    "c".into(),
                    TaskState::Aborted,
                    0.0,
                    "aborted by task stop".into()
                ),
            ]
        );
    }
}
