//! The `[traffic]` configuration: inputs, collision thresholds and the limits on what a
//! sender can make the picture hold.

use std::fmt;
use std::net::SocketAddr;
use std::str::FromStr;
use std::time::Duration;

use serde::{Deserialize, Serialize};

/// Why a traffic configuration is refused.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ConfigError {
    /// An input is not `udp://ADDR:PORT` or `tcp://HOST:PORT`.
    #[error("input {0:?}: expected udp://ADDRESS:PORT or tcp://HOST:PORT")]
    BadInput(String),
    /// A numeric setting is out of its range.
    #[error("{key} = {value}: {why}")]
    OutOfRange {
        /// The configuration key.
        key: &'static str,
        /// The refused value, as text.
        value: String,
        /// What the range is.
        why: &'static str,
    },
}

/// One NMEA 0183 source.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(try_from = "String", into = "String")]
pub enum Input {
    /// Listen for datagrams on this local address (`udp://127.0.0.1:10110`).
    Udp(SocketAddr),
    /// Connect to this server and read its stream (`tcp://HOST:PORT`), reconnecting.
    Tcp {
        /// Host name or address of the server.
        host: String,
        /// Its port.
        port: u16,
    },
}

impl FromStr for Input {
    type Err = ConfigError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let bad = || ConfigError::BadInput(s.to_string());
        if let Some(rest) = s.strip_prefix("udp://") {
            return rest
                .parse::<SocketAddr>()
                .map(Input::Udp)
                .map_err(|_| bad());
        }
        let rest = s.strip_prefix("tcp://").ok_or_else(bad)?;
        // rsplit so that a bracketed IPv6 address keeps its colons.
        let (host, port) = rest.rsplit_once(':').ok_or_else(bad)?;
        let host = host.trim_start_matches('[').trim_end_matches(']');
        let port = port.parse::<u16>().map_err(|_| bad())?;
        if host.is_empty() || port == 0 || host.contains('/') {
            return Err(bad());
        }
        Ok(Input::Tcp {
            host: host.to_string(),
            port,
        })
    }
}

impl TryFrom<String> for Input {
    type Error = ConfigError;

    fn try_from(s: String) -> Result<Self, Self::Error> {
        s.parse()
    }
}

impl From<Input> for String {
    fn from(i: Input) -> Self {
        i.to_string()
    }
}

impl fmt::Display for Input {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Input::Udp(a) => write!(f, "udp://{a}"),
            Input::Tcp { host, port } if host.contains(':') => write!(f, "tcp://[{host}]:{port}"),
            Input::Tcp { host, port } => write!(f, "tcp://{host}:{port}"),
        }
    }
}

/// The traffic picture's settings; every field has a default (see docs/traffic.md).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrafficConfig {
    /// NMEA 0183 sources (default: none).
    pub inputs: Vec<Input>,
    /// A target not heard from for this many seconds is dropped (default 600).
    pub target_timeout_s: u64,
    /// At most this many targets; a new one evicts the least recently heard (default 2000).
    pub max_targets: usize,
    /// Lines longer than this many bytes are dropped (default 512; NMEA allows 82 plus any
    /// tag block).
    pub max_line_len: usize,
    /// At most this many multi-sentence AIS messages awaiting fragments (default 256).
    pub max_pending_fragments: usize,
    /// A multi-sentence message not completed within this many milliseconds is dropped
    /// (default 5000).
    pub fragment_timeout_ms: u64,
    /// First delay before reconnecting a TCP input, doubled after each failure (default 500).
    pub reconnect_min_ms: u64,
    /// Longest delay between TCP reconnection attempts (default 30000).
    pub reconnect_max_ms: u64,
}

impl Default for TrafficConfig {
    fn default() -> Self {
        Self {
            inputs: Vec::new(),
            target_timeout_s: 600,
            max_targets: 2000,
            max_line_len: 512,
            max_pending_fragments: 256,
            fragment_timeout_ms: 5000,
            reconnect_min_ms: 500,
            reconnect_max_ms: 30_000,
        }
    }
}

impl TrafficConfig {
    /// Checks the ranges that serde cannot express.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let range = |key, value: String, why| Err(ConfigError::OutOfRange { key, value, why });
        if self.target_timeout_s == 0 {
            return range("target_timeout_s", "0".into(), "must be > 0");
        }
        if self.max_targets == 0 {
            return range("max_targets", "0".into(), "must be > 0");
        }
        if !(82..=65_536).contains(&self.max_line_len) {
            return range(
                "max_line_len",
                self.max_line_len.to_string(),
                "must be within 82..=65536",
            );
        }
        if self.max_pending_fragments == 0 {
            return range("max_pending_fragments", "0".into(), "must be > 0");
        }
        if self.fragment_timeout_ms == 0 {
            return range("fragment_timeout_ms", "0".into(), "must be > 0");
        }
        if self.reconnect_min_ms == 0 || self.reconnect_max_ms < self.reconnect_min_ms {
            return range(
                "reconnect_min_ms",
                self.reconnect_min_ms.to_string(),
                "must be > 0 and <= reconnect_max_ms",
            );
        }
        Ok(())
    }

    pub(crate) fn target_timeout(&self) -> Duration {
        Duration::from_secs(self.target_timeout_s)
    }

    pub(crate) fn fragment_timeout(&self) -> Duration {
        Duration::from_millis(self.fragment_timeout_ms)
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn inputs_parse_and_print() {
        let udp: Input = "udp://127.0.0.1:10110".parse().unwrap();
        assert_eq!(udp, Input::Udp("127.0.0.1:10110".parse().unwrap()));
        assert_eq!(udp.to_string(), "udp://127.0.0.1:10110");
        let tcp: Input = "tcp://opencpn.local:10110".parse().unwrap();
        assert_eq!(
            tcp,
            Input::Tcp {
                host: "opencpn.local".into(),
                port: 10110
            }
        );
        let v6: Input = "tcp://[::1]:2000".parse().unwrap();
        assert_eq!(v6.to_string(), "tcp://[::1]:2000");
        for bad in [
            "udp://host:1",
            "tcp://host",
            "tcp://:1",
            "tcp://h:0",
            "http://x:1",
            "",
        ] {
            assert!(bad.parse::<Input>().is_err(), "{bad}");
        }
    }

    #[test]
    fn defaults_validate_and_bad_values_do_not() {
        TrafficConfig::default().validate().unwrap();
        let c = TrafficConfig {
            target_timeout_s: 0,
            ..TrafficConfig::default()
        };
        assert!(c.validate().is_err());
        let c = TrafficConfig {
            max_line_len: 10,
            ..TrafficConfig::default()
        };
        assert!(c.validate().is_err());
        let c = TrafficConfig {
            reconnect_min_ms: 10_000,
            reconnect_max_ms: 100,
            ..TrafficConfig::default()
        };
        assert!(c.validate().is_err());
    }

    #[test]
    fn serde_rejects_unknown_keys_and_bad_inputs() {
        let c: TrafficConfig = serde_json::from_str(
            r#"{"inputs":["udp://127.0.0.1:1","tcp://h:2"],"max_targets":100}"#,
        )
        .unwrap();
        assert_eq!(c.inputs.len(), 2);
        assert_eq!(c.max_targets, 100);
        assert_eq!(c.target_timeout_s, 600);
        // The collision-risk thresholds are the rules engine's, not the inputs'.
        assert!(serde_json::from_str::<TrafficConfig>(r#"{"cpa_alarm_m":1}"#).is_err());
        assert!(serde_json::from_str::<TrafficConfig>(r#"{"inputs":["ftp://x:1"]}"#).is_err());
    }
}
