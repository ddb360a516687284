//! Configuration of the Publish/Subscribe Manager.

use std::net::{IpAddr, Ipv4Addr};

use serde::{Deserialize, Serialize};

/// The `[dds]` section of Shoal's configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DdsConfig {
    /// DDS domain id (0..=232): separate swarms on one network use different domains.
    pub domain_id: u16,
    /// Local interface addresses DDS may use for discovery and data. The default,
    /// `["127.0.0.1"]`, keeps everything on this host; list a radio or Ethernet
    /// interface's address for a real deployment.
    pub interfaces: Vec<IpAddr>,
    /// No longer used: a setting of RustDDS, Shoal's earlier DDS library; Cyclone DDS
    /// reaches every peer at the addresses it advertises. Accepted (with a warning) so
    /// that older configuration files still load.
    #[serde(skip_serializing)]
    pub same_host_loopback: Option<bool>,
    /// Samples each reader holds untaken, all instances together; beyond it DDS refuses
    /// new samples (a reliable writer sends them again later). The per-instance history
    /// depth is capped to it.
    pub topic_cache_samples: i32,
    /// Kernel receive buffer per UDP socket, bytes.
    pub socket_receive_buffer: usize,
    /// Largest sample, serialised, that DDS sends or accepts, bytes; larger ones are
    /// dropped on arrival before they are reassembled (a 10 MB sample costs nothing).
    /// Shoal's largest valid sample is a few kilobytes.
    pub max_sample_bytes: u32,
}

impl Default for DdsConfig {
    fn default() -> Self {
        Self {
            domain_id: 0,
            interfaces: vec![IpAddr::V4(Ipv4Addr::LOCALHOST)],
            same_host_loopback: None,
            topic_cache_samples: 8192,
            socket_receive_buffer: 8 * 1024 * 1024,
            max_sample_bytes: 64 * 1024,
        }
    }
}

impl DdsConfig {
    /// True when every configured interface is a loopback address.
    pub fn is_loopback_only(&self) -> bool {
        !self.interfaces.is_empty() && self.interfaces.iter().all(IpAddr::is_loopback)
    }
}
