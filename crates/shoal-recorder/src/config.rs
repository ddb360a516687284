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
    /// Also record the acoustic link's frames and modem events wherever a CDT runs under
    /// this configuration (`shoal up`'s acoustic demo, `shoal scenario run`), whether or not
    /// `enabled` is set: into `directory` as `PREFIX-acoustic-*.mcap`, apart from the DDS
    /// files ([`crate::acoustic`], docs/recorder.md, "Acoustic frames").
    pub acoustic: bool,
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
    /// zstd level of the chunks, 1 (fastest) to 19 (smallest files). Recorded state
    /// vectors are mostly full-precision doubles, which no level compresses much: at
    /// 10,000 state vectors/s the levels from 3 to 19 differ by about 4 bytes per state
    /// vector, while the CPU time grows from a few percent of a core to most of one
    /// (docs/recorder.md, "Targets"). Ignored with `compression = "none"`.
    pub compression_level: u32,
    /// Largest chunk, uncompressed bytes (64 KiB to 16 MiB; for a small `max_file_bytes`
    /// a quarter of it, so that rotation by size stays close). Whatever its size, a chunk
    /// is written out at least every second, so this bounds memory and how much one chunk
    /// holds at high rates; a larger chunk compresses a little better.
    pub max_chunk_bytes: u64,
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
            acoustic: false,
            directory: PathBuf::from("recordings"),
            prefix: "shoal".into(),
            max_file_bytes: 512 * 1024 * 1024,
            max_file_seconds: 3600,
            max_total_bytes: 16 * 1024 * 1024 * 1024,
            compression: Compression::Zstd,
            compression_level: DEFAULT_COMPRESSION_LEVEL,
            max_chunk_bytes: DEFAULT_MAX_CHUNK_BYTES,
            topics: Vec::new(),
            queue_samples: 65_536,
        }
    }
}

/// Default `compression_level`: the data rate is low (a few MB/s at most), so a level
/// above zstd's default buys a little for CPU time that stays small.
const DEFAULT_COMPRESSION_LEVEL: u32 = 9;

/// Default `max_chunk_bytes`.
const DEFAULT_MAX_CHUNK_BYTES: u64 = 1024 * 1024;

/// Range of `max_chunk_bytes`: the reader refuses chunks above 64 MiB.
const CHUNK_BYTES: (u64, u64) = (64 * 1024, 16 * 1024 * 1024);

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
        if !(1..=19).contains(&self.compression_level) {
            return bad(format!(
                "recorder.compression_level = {} is not a zstd level from 1 to 19",
                self.compression_level
            ));
        }
        if !(CHUNK_BYTES.0..=CHUNK_BYTES.1).contains(&self.max_chunk_bytes) {
            return bad(format!(
                "recorder.max_chunk_bytes = {} is not within {} to {}",
                self.max_chunk_bytes, CHUNK_BYTES.0, CHUNK_BYTES.1
            ));
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

    #[test]
    fn the_compression_level_and_the_chunk_size_are_bounded() {
        let cfg = |compression_level, max_chunk_bytes| RecorderConfig {
            compression_level,
            max_chunk_bytes,
            ..RecorderConfig::default()
        };
        assert!(cfg(1, 64 * 1024).check().is_ok());
        assert!(cfg(19, 16 * 1024 * 1024).check().is_ok());
        for bad in [0, 20, 22] {
            let e = cfg(bad, 1024 * 1024).check().unwrap_err().to_string();
            assert!(e.contains("compression_level"), "{e}");
        }
        for bad in [0, 64 * 1024 - 1, 16 * 1024 * 1024 + 1] {
            let e = cfg(9, bad).check().unwrap_err().to_string();
            assert!(e.contains("max_chunk_bytes"), "{e}");
        }
        let parsed: RecorderConfig =
            toml_like(r#"{"compression_level": 3, "max_chunk_bytes": 4194304}"#).unwrap();
        assert_eq!(parsed, cfg(3, 4 * 1024 * 1024));
    }

    fn toml_like(json: &str) -> Result<RecorderConfig, serde_json::Error> {
        serde_json::from_str(json)
    }
}
