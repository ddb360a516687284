//! What the Publish/Subscribe Manager's loopback tests share: a participant's
//! configuration, a valid state vector, and a raw RustDDS publisher that sends what no
//! Shoal writer would.
#![allow(dead_code, clippy::unwrap_used)]

use shoal_dds::DdsConfig;
use shoal_model::StateVector;

/// The default configuration on `domain_id`.
pub fn config(domain_id: u16) -> DdsConfig {
    DdsConfig {
        domain_id,
        ..DdsConfig::default()
    }
}

/// A valid state vector of `vehicle_id`, stamped `timestamp_ms`.
pub fn state_at(vehicle_id: &str, timestamp_ms: i64) -> StateVector {
    StateVector {
        vehicle_id: vehicle_id.into(),
        timestamp_ms,
        latitude_deg: 43.0,
        longitude_deg: 5.9,
        depth_m: 10.0,
        altitude_m: -1.0,
        speed_mps: 1.0,
        yaw_deg: 90.0,
        pitch_deg: 0.0,
        roll_deg: 0.0,
        battery_pct: 80.0,
    }
}

/// A plain RustDDS participant on loopback with a publisher for one keyed topic, for
/// writers of foreign or malformed types (reliable, keep last 16).
pub struct Foreign {
    /// Kept alive for the writers.
    pub participant: rustdds::DomainParticipant,
    pub publisher: rustdds::Publisher,
    pub topic: rustdds::Topic,
}

impl Foreign {
    /// Joins `domain_id` and creates `topic` of DDS type `type_name`.
    pub fn new(domain_id: u16, topic: &str, type_name: &str) -> Self {
        use rustdds::{DomainParticipantBuilder, QosPolicyBuilder, TopicKind};
        let participant = DomainParticipantBuilder::new(domain_id)
            .with_only_networks([std::net::Ipv4Addr::LOCALHOST])
            .build()
            .unwrap();
        let qos = QosPolicyBuilder::new()
            .reliable(rustdds::Duration::from_secs(1))
            .history(rustdds::policy::History::KeepLast { depth: 16 })
            .build();
        let topic = participant
            .create_topic(topic.into(), type_name.into(), &qos, TopicKind::WithKey)
            .unwrap();
        let publisher = participant.create_publisher(&qos).unwrap();
        Self {
            participant,
            publisher,
            topic,
        }
    }
}
