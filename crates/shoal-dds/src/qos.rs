//! Named QoS profiles and message priority classes.
//!
//! Readers are lenient and writers strict: DDS matches a writer to a reader only when what
//! the writer offers is at least what the reader requests (request/offered, DDS 1.4
//! §2.2.3). The station's readers therefore request no deadline and automatic liveliness,
//! so any vendor's writer matches them, while Shoal's own writers offer a deadline and a
//! liveliness lease so that readers that do ask for them are served.

use std::time::Duration;

use rustdds::policy::{Deadline, Durability, History, Liveliness, Reliability, ResourceLimits};
use rustdds::{QosPolicies, QosPolicyBuilder};
use serde::{Deserialize, Serialize};

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

fn dds_duration(d: Duration) -> rustdds::Duration {
    rustdds::Duration::from_frac_seconds(d.as_secs_f64())
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
}

impl WriterOptions {
    /// Defaults for a priority class.
    pub fn new(priority: Priority) -> Self {
        Self {
            priority,
            deadline: None,
            max_blocking: Duration::from_millis(200),
        }
    }
}

impl QosProfile {
    fn base(self) -> QosPolicyBuilder {
        let b = QosPolicyBuilder::new();
        match self {
            Self::State => b
                .durability(Durability::Volatile)
                .history(History::KeepLast { depth: 64 }),
            Self::Tasks | Self::Announcements | Self::Events => b
                .durability(Durability::TransientLocal)
                .history(History::KeepLast { depth: 1 }),
            Self::TaskStatus => b
                .durability(Durability::TransientLocal)
                .history(History::KeepLast { depth: 16 }),
            Self::Environment => b
                .durability(Durability::Volatile)
                .history(History::KeepLast { depth: 8 }),
        }
    }

    /// QoS of Shoal's writers on this topic.
    pub fn writer_qos(self, options: &WriterOptions) -> QosPolicies {
        let mut b = self.base().reliability(Reliability::Reliable {
            max_blocking_time: dds_duration(options.max_blocking),
        });
        if let Some(deadline) = options.deadline {
            b = b.deadline(Deadline(dds_duration(deadline)));
        }
        if self == Self::State {
            b = b.liveliness(Liveliness::Automatic {
                lease_duration: rustdds::Duration::from_secs(10),
            });
        }
        b.build()
    }

    /// QoS of Shoal's readers on this topic; `cache_samples` bounds the reader's cache.
    pub fn reader_qos(self, cache_samples: i32) -> QosPolicies {
        let b = match self {
            // Best effort accepts every writer, reliable or not: environment data is bulk.
            Self::Environment => self.base().best_effort(),
            _ => self.base().reliable(rustdds::Duration::ZERO),
        };
        let b = match self {
            Self::State => b.history(History::KeepLast { depth: 256 }),
            Self::TaskStatus | Self::Environment => b,
            // Late joiners get the history the writer kept; keep several per instance so a
            // re-issued task or a burst of announcements is not collapsed before we read.
            Self::Tasks | Self::Announcements | Self::Events => {
                b.history(History::KeepLast { depth: 4 })
            }
        };
        b.resource_limits(ResourceLimits {
            max_samples: cache_samples,
            max_instances: cache_samples,
            max_samples_per_instance: cache_samples,
        })
        .build()
    }

    /// QoS of the topic object, which sizes RustDDS's per-topic cache.
    pub fn topic_qos(self, cache_samples: i32) -> QosPolicies {
        self.reader_qos(cache_samples)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tasks_are_reliable_and_transient_local_for_late_joiners() {
        let q = QosProfile::Tasks.writer_qos(&WriterOptions::new(Priority::Control));
        assert!(q.is_reliable());
        assert_eq!(q.durability(), Some(Durability::TransientLocal));
        let r = QosProfile::Tasks.reader_qos(1000);
        assert_eq!(r.durability(), Some(Durability::TransientLocal));
    }

    #[test]
    fn reader_cache_is_bounded_by_configuration_not_the_library_default() {
        let r = QosProfile::State.reader_qos(5000);
        assert_eq!(r.resource_limits().map(|l| l.max_samples), Some(5000));
    }

    #[test]
    fn station_readers_request_no_deadline_so_any_writer_matches() {
        for p in [QosProfile::State, QosProfile::Tasks, QosProfile::Events] {
            assert_eq!(p.reader_qos(10).deadline(), None);
        }
    }

    #[test]
    fn priorities_order_emergency_first() {
        assert!(Priority::Emergency < Priority::Control && Priority::Telemetry < Priority::Bulk);
    }
}
