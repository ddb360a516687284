//! The recorder's configuration: the `[recorder]` section a station can embed.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::error::RecordError;
use crate::topic::Topic;

/// How chunks are compressed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Compression {
    /// Zstandard (what Foxglove and the MCAP CLI write by default).
    #[default]
    Zstd,
    /// No compression: larger files, least CPU.
    None,
}

/// Where and how the recorder writes MCAP files.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RecorderConfig {
    /// Whether the station records (its `[recorder]` section); `shoal record` always does.
    pub enabled: bool,
    /// Directory the files are written in (created if missing).
    pub directory: PathBuf,
    /// File names are `PREFIX-YYYYmmddTHHMMSSZ-N.mcap` (UTC time the file was opened, N
    /// counting the files of one recorder from 1).
    pub prefix: String,
    /// A file is closed and the next one opened once it holds this many bytes (it may
    /// exceed it by at most one chunk and the summary, which repeats the schemas: about 32 KiB).
    /// At least 1 MiB.
    pub max_file_bytes: u64,
    /// A file is closed and the next one opened once it has been open this long, seconds.
    pub max_file_seconds: u64,
    /// The recorder's files (`PREFIX-*.mcap` in `directory`) are kept under this many
    /// bytes: after each file is closed, the oldest are deleted until they fit (the newest
    /// is always kept). At least twice `max_file_bytes`.
    pub max_total_bytes: u64,
    /// Chunk compression.
    pub compression: Compression,
    /// DDS topic names to record; empty records every Shoal topic.
    pub topics: Vec<String>,
    /// Samples waiting for the file writer at most; beyond, new samples are dropped and
    /// counted (the recorder never buffers without limit).
    pub queue_samples: usize,
}

impl Default for RecorderConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            directory: PathBuf::from("recordings"),
            prefix: "shoal".into(),
            max_file_bytes: 512 * 1024 * 1024,
            max_file_seconds: 3600,
            max_total_bytes: 16 * 1024 * 1024 * 1024,
            compression: Compression::Zstd,
            topics: Vec::new(),
            queue_samples: 65_536,
        }
    }
}

/// Smallest `max_file_bytes`: each file carries the IDL six times in its summary (about
/// 32 KiB), which should stay a small part of it.
const MIN_FILE_BYTES: u64 = 1024 * 1024;

impl RecorderConfig {
    /// Checks the values and returns the topics to record, in [`Topic::ALL`] order.
    pub fn check(&self) -> Result<Vec<Topic>, RecordError> {
        let bad = |m: String| Err(RecordError::Config(m));
        if self.prefix.is_empty()
            || self.prefix.len() > 64
            || !self
                .prefix
                .bytes()
                .all(|b| b.is_ascii_alphanumeric() || b"_.-".contains(&b))
        {
            return bad(format!(
                "recorder.prefix {:?} must be 1..64 of [A-Za-z0-9_.-]",
                self.prefix
            ));
        }
        if self.max_file_bytes < MIN_FILE_BYTES {
            return bad(format!(
                "recorder.max_file_bytes = {} is below the smallest, {MIN_FILE_BYTES}",
                self.max_file_bytes
            ));
        }
        if self.max_total_bytes < self.max_file_bytes.saturating_mul(2) {
            return bad(format!(
                "recorder.max_total_bytes = {} is below twice max_file_bytes ({})",
                self.max_total_bytes, self.max_file_bytes
            ));
        }
        if self.max_file_seconds == 0 {
            return bad("recorder.max_file_seconds must be at least 1".into());
        }
        if self.queue_samples == 0 {
            return bad("recorder.queue_samples must be at least 1".into());
        }
        let mut topics = Vec::new();
        for name in &self.topics {
            let Some(topic) = Topic::from_name(name) else {
                let known: Vec<&str> = Topic::ALL.iter().map(|t| t.name()).collect();
                return bad(format!(
                    "recorder.topics: {name:?} is not a Shoal topic (one of {})",
                    known.join(", ")
                ));
            };
            topics.push(topic);
        }
        if topics.is_empty() {
            topics = Topic::ALL.to_vec();
        }
        topics.sort();
        topics.dedup();
        Ok(topics)
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn defaults_record_every_topic_and_unknown_keys_are_refused() {
        assert_eq!(RecorderConfig::default().check().unwrap(), Topic::ALL);
        let cfg: RecorderConfig =
            toml_like(r#"{"directory": "/tmp/x", "topics": ["shoal/event"]}"#).unwrap();
        assert_eq!(cfg.check().unwrap(), [Topic::Event]);
        assert!(toml_like(r#"{"directroy": "/tmp/x"}"#).is_err());
        let cfg = RecorderConfig {
            topics: vec!["shoal/nope".into()],
            ..RecorderConfig::default()
        };
        assert!(cfg.check().unwrap_err().to_string().contains("shoal/nope"));
        let cfg = RecorderConfig {
            prefix: "../x".into(),
            ..RecorderConfig::default()
        };
        assert!(cfg.check().is_err());
    }

    fn toml_like(json: &str) -> Result<RecorderConfig, serde_json::Error> {
        serde_json::from_str(json)
    }
}
