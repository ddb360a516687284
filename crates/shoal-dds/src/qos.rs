//! Named QoS profiles and message priority classes.
//!
//! Readers are lenient and writers strict: DDS matches a writer to a reader only when what
//! the writer offers is at least what the reader requests (request/offered, DDS 1.4
//! §2.2.3). The station's readers therefore request no deadline and automatic liveliness,
//! so any vendor's writer matches them, while Shoal's own writers offer a deadline and a
//! liveliness lease so that readers that do ask for them are served.

use std::time::Duration;

use serde::{Deserialize, Serialize};

use crate::cyclone::{self, Reliability};

/// The QoS profile of a topic.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum QosProfile {
    /// State vectors: reliable, volatile, keep-last per vehicle; writers offer a deadline.
    State,
    /// Task assignments: reliable, transient-local so a vehicle that joins late gets its task.
    Tasks,
    /// Task status: reliable, transient-local, keep-last 16 per task.
    TaskStatus,
    /// Events: reliable, transient-local, keep-last 1 per event, bounded in number.
    Events,
    /// Announcements: reliable, transient-local, the latest per vehicle.
    Announcements,
    /// Environment observations: readers accept best effort, writers send reliably.
    Environment,
}

/// Message priority classes, highest first; each class has its own DDS writers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Priority {
    /// Safety: aborts, critical alarms.
    Emergency,
    /// Tasks, task status, announcements.
    Control,
    /// State vectors.
    Telemetry,
    /// Environment data and anything that can wait.
    Bulk,
}

impl Priority {
    /// All classes, highest first.
    pub const ALL: [Priority; 4] = [Self::Emergency, Self::Control, Self::Telemetry, Self::Bulk];

    /// Lower-case name for logs.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Emergency => "emergency",
            Self::Control => "control",
            Self::Telemetry => "telemetry",
            Self::Bulk => "bulk",
        }
    }
}

/// Options a writer is created with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WriterOptions {
    /// Priority class (which writer of the topic to use).
    pub priority: Priority,
    /// Deadline the writer promises per instance (e.g. three reporting periods).
    pub deadline: Option<Duration>,
    /// How long a reliable write may block when the history is full of unacknowledged data.
    pub max_blocking: Duration,
    /// How many instances the writer keeps for late joiners; beyond, the oldest is
    /// unregistered. `None` takes the topic's default ([`QosProfile::kept_instances`]).
    pub kept_instances: Option<usize>,
}

impl WriterOptions {
    /// Defaults for a priority class.
    pub fn new(priority: Priority) -> Self {
        Self {
            priority,
            deadline: None,
            max_blocking: Duration::from_millis(200),
            kept_instances: None,
        }
    }
}

/// DDS's "no limit" for resource limits (`DDS_LENGTH_UNLIMITED`).
const UNLIMITED: i32 = -1;

/// The policies Shoal sets on an endpoint; everything else is the DDS default.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Policies {
    pub(crate) reliability: Reliability,
    pub(crate) transient_local: bool,
    /// Keep-last depth per instance.
    pub(crate) depth: i32,
    pub(crate) deadline: Option<Duration>,
    pub(crate) liveliness_lease: Option<Duration>,
    /// (samples, instances, samples per instance); `None`, and -1 in each, is unlimited.
    pub(crate) limits: Option<(i32, i32, i32)>,
}

impl Policies {
    /// The Cyclone QoS object for these policies.
    pub(crate) fn to_qos(self) -> cyclone::Qos {
        let mut q = cyclone::Qos::new();
        q.xcdr1_only();
        q.reliability(self.reliability);
        q.transient_local(self.transient_local);
        q.keep_last(self.depth);
        if let Some(d) = self.deadline {
            q.deadline(d);
        }
        if let Some(lease) = self.liveliness_lease {
            q.automatic_liveliness(lease);
        }
        if let Some((samples, instances, per_instance)) = self.limits {
            q.resource_limits(samples, instances, per_instance);
        }
        q
    }
}

impl QosProfile {
    /// How many instances a writer of the topic keeps by default: events and task status
    /// reports are a new instance each, and would otherwise pile up in the writer's
    /// transient-local history for ever (and reach every late joiner). Tasks are disposed
    /// when they end; states and announcements are one instance per vehicle.
    pub fn kept_instances(self) -> Option<usize> {
        match self {
            Self::Events => Some(256),
            Self::TaskStatus => Some(1024),
            _ => None,
        }
    }

    /// Whether a reader drops the data of an instance that its writer has disposed by
    /// the time the sample is taken. Tasks only: the station disposes a task when it ends,
    /// and a reader that joins, or falls behind, while the writer still holds ended tasks
    /// for a slower reader (a reliable writer keeps every sample until all its readers
    /// acknowledge it, and a reader that vanished without a goodbye counts until its lease
    /// ends) would otherwise be handed a burst of tasks that are over. The other topics
    /// keep their last value: a vehicle's final state is still news.
    pub fn skips_disposed(self) -> bool {
        self == Self::Tasks
    }

    /// Durability and writer history depth of the profile.
    fn base(self) -> (bool, i32) {
        match self {
            Self::State => (false, 64),
            Self::Tasks | Self::Announcements | Self::Events => (true, 1),
            Self::TaskStatus => (true, 16),
            Self::Environment => (false, 8),
        }
    }

    /// QoS of Shoal's writers on this topic.
    pub(crate) fn writer_qos(self, options: &WriterOptions) -> Policies {
        let (transient_local, depth) = self.base();
        Policies {
            reliability: Reliability::Reliable(options.max_blocking),
            transient_local,
            depth,
            deadline: options.deadline,
            liveliness_lease: (self == Self::State).then_some(Duration::from_secs(10)),
            limits: None,
        }
    }

    /// QoS of Shoal's readers on this topic; `cache_samples` bounds the reader's cache.
    pub(crate) fn reader_qos(self, cache_samples: i32) -> Policies {
        let (transient_local, depth) = self.base();
        let reliability = match self {
            // Best effort accepts every writer, reliable or not: environment data is bulk.
            Self::Environment => Reliability::BestEffort,
            _ => Reliability::Reliable(Duration::ZERO),
        };
        let depth = match self {
            Self::State => 256,
            Self::TaskStatus | Self::Environment => depth,
            // Late joiners get the history the writer kept; keep several per instance so a
            // re-issued task or a burst of announcements is not collapsed before we read.
            Self::Tasks | Self::Announcements | Self::Events => 4,
        };
        let cache = cache_samples.max(1);
        // DDS counts every instance a reader has seen against max_instances for as long
        // as the instance exists, so that one stays unlimited: ten thousand vehicles are
        // ten thousand instances. What bounds memory is the samples not yet taken.
        Policies {
            reliability,
            transient_local,
            // DDS requires the depth to fit the per-instance limit.
            depth: depth.min(cache),
            deadline: None,
            liveliness_lease: None,
            limits: Some((cache, UNLIMITED, UNLIMITED)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tasks_are_reliable_and_transient_local_for_late_joiners() {
        let q = QosProfile::Tasks.writer_qos(&WriterOptions::new(Priority::Control));
        assert!(matches!(q.reliability, Reliability::Reliable(_)));
        assert!(q.transient_local);
        let r = QosProfile::Tasks.reader_qos(1000);
        assert!(r.transient_local && matches!(r.reliability, Reliability::Reliable(_)));
    }

    #[test]
    fn reader_cache_is_bounded_by_configuration_not_the_library_default() {
        let r = QosProfile::State.reader_qos(5000);
        assert_eq!(r.limits, Some((5000, UNLIMITED, UNLIMITED)));
        // A cache smaller than the history depth shrinks the depth, which DDS requires.
        assert_eq!(QosProfile::State.reader_qos(10).depth, 10);
    }

    #[test]
    fn station_readers_request_no_deadline_so_any_writer_matches() {
        for p in [QosProfile::State, QosProfile::Tasks, QosProfile::Events] {
            assert_eq!(p.reader_qos(10).deadline, None);
            assert_eq!(p.reader_qos(10).liveliness_lease, None);
        }
    }

    #[test]
    fn environment_readers_accept_best_effort_writers() {
        assert_eq!(
            QosProfile::Environment.reader_qos(10).reliability,
            Reliability::BestEffort
        );
    }

    #[test]
    fn writers_offer_their_deadline() {
        let mut o = WriterOptions::new(Priority::Telemetry);
        o.deadline = Some(Duration::from_secs(3));
        let q = QosProfile::State.writer_qos(&o);
        assert_eq!(q.deadline, Some(Duration::from_secs(3)));
        assert_eq!(q.liveliness_lease, Some(Duration::from_secs(10)));
    }

    #[test]
    fn priorities_order_emergency_first() {
        assert!(Priority::Emergency < Priority::Control && Priority::Telemetry < Priority::Bulk);
    }
}
