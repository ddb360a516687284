//! The bridge's settings: the station's `[foxglove]` section.

use serde::{Deserialize, Serialize};

use crate::BridgeError;

/// How often one channel may send: per instance (vehicle, task, ...) and in all.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RateLimit {
    /// Most messages per second for one instance (one vehicle's state, one observed
    /// property of one vehicle); a faster instance's extra samples are skipped, not
    /// queued. 0 means no per-instance limit.
    pub per_instance_hz: f64,
    /// Most messages per second on the channel in all, whichever instances they are
    /// of; 0 means no limit.
    pub per_channel_per_s: u32,
}

impl RateLimit {
    /// A limit of `per_instance_hz` per instance and `per_channel_per_s` in all.
    pub const fn new(per_instance_hz: f64, per_channel_per_s: u32) -> Self {
        Self {
            per_instance_hz,
            per_channel_per_s,
        }
    }

    /// No limit at all (tests, benchmarks).
    pub const UNLIMITED: Self = Self::new(0.0, 0);
}

impl Default for RateLimit {
    fn default() -> Self {
        Self::UNLIMITED
    }
}

/// Rate limits of each channel the bridge advertises.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RateLimits {
    /// `shoal/state_vector` and `shoal/location_fix` (one decision for both, per
    /// vehicle). Default: 2 Hz per vehicle, 5000 per second in all (a fleet of 1000 at
    /// 1 Hz passes whole).
    pub state_vector: RateLimit,
    /// `shoal/vehicle_announcement`. Default: 1 Hz per vehicle, 500 per second.
    pub vehicle_announcement: RateLimit,
    /// `shoal/task_assignment`. Default: no per-task limit (each assignment matters),
    /// 1000 per second.
    pub task_assignment: RateLimit,
    /// `shoal/task_status`. Default: 2 Hz per task, 2000 per second.
    pub task_status: RateLimit,
    /// `shoal/event`. Default: no per-event limit (each has its own id), 1000 per second.
    pub event: RateLimit,
    /// `shoal/environment`. Default: 1 Hz per vehicle and property, 2000 per second.
    pub environment: RateLimit,
}

impl Default for RateLimits {
    fn default() -> Self {
        Self {
            state_vector: RateLimit::new(2.0, 5000),
            vehicle_announcement: RateLimit::new(1.0, 500),
            task_assignment: RateLimit::new(0.0, 1000),
            task_status: RateLimit::new(2.0, 2000),
            event: RateLimit::new(0.0, 1000),
            environment: RateLimit::new(1.0, 2000),
        }
    }
}

impl RateLimits {
    /// No limit on any channel.
    pub fn unlimited() -> Self {
        Self {
            state_vector: RateLimit::UNLIMITED,
            vehicle_announcement: RateLimit::UNLIMITED,
            task_assignment: RateLimit::UNLIMITED,
            task_status: RateLimit::UNLIMITED,
            event: RateLimit::UNLIMITED,
            environment: RateLimit::UNLIMITED,
        }
    }

    fn all(&self) -> [(&'static str, &RateLimit); 6] {
        [
            ("state_vector", &self.state_vector),
            ("vehicle_announcement", &self.vehicle_announcement),
            ("task_assignment", &self.task_assignment),
            ("task_status", &self.task_status),
            ("event", &self.event),
            ("environment", &self.environment),
        ]
    }
}

/// The Foxglove bridge's settings (`[foxglove]` in the station's configuration).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BridgeConfig {
    /// Whether the station runs the bridge. Default: false.
    pub enabled: bool,
    /// Most Foxglove clients connected at once; one more is refused (503). Default: 8.
    pub max_clients: usize,
    /// Messages queued toward one client. A burst beyond it waits (in the SDK's own
    /// bounded queue) for at most `send_timeout_ms`; a client that leaves the queue
    /// full that long is dropped rather than buffered further. Default: 4096 (a fleet
    /// of 1000 at 1 Hz is 2000 messages a second on the two position channels).
    pub client_queue: usize,
    /// Longest a client may go without taking a message it has waiting (one send to its
    /// connection, or room in its full queue); a client that reads slower is dropped.
    /// Default: 5000 ms.
    pub send_timeout_ms: u64,
    /// Messages the Foxglove SDK's own server keeps per client on loopback before it
    /// drops the oldest (its `message_backlog_size`). Default: 4096.
    pub sdk_backlog: usize,
    /// Largest message a client may send (subscribe requests are small). Default: 65536.
    pub max_client_message_bytes: usize,
    /// Per-channel rate limits.
    pub rates: RateLimits,
}

impl Default for BridgeConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            max_clients: 8,
            client_queue: 4096,
            send_timeout_ms: 5000,
            sdk_backlog: 4096,
            max_client_message_bytes: 65536,
            rates: RateLimits::default(),
        }
    }
}

impl BridgeConfig {
    /// Refuses settings the bridge cannot run with, naming the key.
    pub fn validate(&self) -> Result<(), BridgeError> {
        let bad = |key: &str, why: &str| Err(BridgeError::Config(format!("foxglove.{key} {why}")));
        if self.max_clients == 0 {
            return bad("max_clients", "must be at least 1");
        }
        if self.client_queue == 0 {
            return bad("client_queue", "must be at least 1");
        }
        if self.sdk_backlog == 0 {
            return bad("sdk_backlog", "must be at least 1");
        }
        if self.send_timeout_ms == 0 {
            return bad("send_timeout_ms", "must be at least 1");
        }
        if self.max_client_message_bytes < 1024 {
            return bad("max_client_message_bytes", "must be at least 1024");
        }
        for (name, limit) in self.rates.all() {
            if !limit.per_instance_hz.is_finite() || limit.per_instance_hz < 0.0 {
                return Err(BridgeError::Config(format!(
                    "foxglove.rates.{name}.per_instance_hz must be a finite number >= 0"
                )));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_and_an_empty_section_gives_them() {
        BridgeConfig::default()
            .validate()
            .unwrap_or_else(|e| unreachable!("{e}"));
        let parsed: BridgeConfig =
            serde_json::from_str("{}").unwrap_or_else(|e| unreachable!("{e}"));
        assert_eq!(parsed, BridgeConfig::default());
    }

    #[test]
    fn unknown_keys_and_bad_values_are_refused() {
        assert!(serde_json::from_str::<BridgeConfig>(r#"{"max_client": 3}"#).is_err());
        assert!(
            serde_json::from_str::<BridgeConfig>(r#"{"rates": {"state_vector": {"hz": 1}}}"#)
                .is_err()
        );
        let zero = BridgeConfig {
            max_clients: 0,
            ..BridgeConfig::default()
        };
        assert!(zero.validate().is_err());
        let mut negative = BridgeConfig::default();
        negative.rates.event.per_instance_hz = -1.0;
        let e = negative.validate().err().map(|e| e.to_string());
        assert!(e.is_some_and(|e| e.contains("rates.event")));
    }

    #[test]
    fn a_partial_section_keeps_the_other_defaults() {
        let parsed: BridgeConfig = serde_json::from_str(
            r#"{"max_clients": 3, "rates": {"event": {"per_channel_per_s": 7}}}"#,
        )
        .unwrap_or_else(|e| unreachable!("{e}"));
        assert_eq!(parsed.max_clients, 3);
        assert_eq!(parsed.rates.event, RateLimit::new(0.0, 7));
        assert_eq!(parsed.rates.state_vector, RateLimit::new(2.0, 5000));
    }
}
