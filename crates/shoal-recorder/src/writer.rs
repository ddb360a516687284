//! MCAP files: one channel per topic, chunked and compressed, flushed at least every
//! second, rotated by size and time.
//!
//! [`McapSeries`] does the file handling for any fixed set of channels; [`RecordWriter`]
//! puts the DDS topics through it, `crate::acoustic` the acoustic link's records.

use std::collections::BTreeMap;
use std::fs::{File, OpenOptions};
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use mcap::records::MessageHeader;
use tracing::{debug, info};

use crate::config::{Compression, RecorderConfig};
use crate::error::RecordError;
use crate::topic::Topic;
use crate::{MESSAGE_ENCODING, PROFILE, SCHEMA_ENCODING, SHOAL_IDL};

/// Longest a written sample waits in memory before its chunk is on disk: what a recorder
/// killed with SIGKILL loses at most.
pub const FLUSH_INTERVAL: Duration = Duration::from_secs(1);

/// What a [`RecordWriter`] has written so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct WriterStats {
    /// Messages written.
    pub messages: u64,
    /// Bytes of closed files plus what the open file holds on disk.
    pub bytes: u64,
    /// Files opened.
    pub files: u64,
    /// Old files deleted to keep the recordings under `max_total_bytes`.
    pub files_deleted: u64,
}

/// A file being written; its length is shared so it can be read while the MCAP writer
/// owns the file.
struct Counting {
    inner: BufWriter<File>,
    pos: u64,
    len: Arc<AtomicU64>,
}

impl Write for Counting {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.pos += n as u64;
        self.len.fetch_max(self.pos, Ordering::Relaxed);
        Ok(n)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

impl Seek for Counting {
    fn seek(&mut self, to: SeekFrom) -> std::io::Result<u64> {
        // The writer runs with seeking disabled and only asks where it is; a real seek
        // (never expected) goes through, so the position stays right either way.
        if to == SeekFrom::Current(0) {
            return Ok(self.pos);
        }
        self.pos = self.inner.seek(to)?;
        Ok(self.pos)
    }
}

/// One channel of the files a [`McapSeries`] writes, with its schema.
#[derive(Debug, Clone, Copy)]
pub(crate) struct ChannelSpec {
    /// The channel's topic.
    pub topic: &'static str,
    /// The channel's message encoding.
    pub message_encoding: &'static str,
    /// The schema's name.
    pub schema_name: &'static str,
    /// The schema's encoding.
    pub schema_encoding: &'static str,
    /// The schema's text.
    pub schema: &'static str,
}

struct OpenFile {
    path: PathBuf,
    writer: mcap::Writer<Counting>,
    len: Arc<AtomicU64>,
    /// Channel id per channel of the series, in its order.
    channels: Vec<u16>,
    sequence: Vec<u32>,
    opened: Instant,
    messages: u64,
    /// Messages and uncompressed bytes in the chunk not yet on disk.
    unflushed: u64,
    unflushed_bytes: u64,
    last_flush: Instant,
}

/// Writes recorded messages into a series of MCAP files in one directory.
///
/// Each file has one `omgidl` schema per type and one `cdr` channel per recorded topic.
/// The current chunk is written out (and handed to the operating system) once it holds
/// a second's samples or `max_chunk_bytes`, so a process killed at any instant leaves a
/// file of complete chunks followed by at most one partial record, which readers stop at.
pub struct RecordWriter {
    series: McapSeries,
    topics: Vec<Topic>,
    /// The series' channel of each topic ([`Topic::index`]), for the topics recorded.
    slots: [Option<usize>; 6],
}

impl std::fmt::Debug for RecordWriter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RecordWriter")
            .field("series", &self.series)
            .field("topics", &self.topics)
            .finish_non_exhaustive()
    }
}

impl RecordWriter {
    /// A writer for `config`'s directory (created if missing); the first file is opened
    /// with the first message.
    pub fn new(config: &RecorderConfig) -> Result<Self, RecordError> {
        let topics = config.check()?;
        let mut slots = [None; 6];
        let specs: Vec<ChannelSpec> = topics
            .iter()
            .enumerate()
            .map(|(slot, topic)| {
                slots[topic.index()] = Some(slot);
                ChannelSpec {
                    topic: topic.name(),
                    message_encoding: MESSAGE_ENCODING,
                    schema_name: topic.type_name(),
                    schema_encoding: SCHEMA_ENCODING,
                    schema: SHOAL_IDL,
                }
            })
            .collect();
        Ok(Self {
            series: McapSeries::new(config, &config.prefix, specs)?,
            topics,
            slots,
        })
    }

    /// The topics this writer records.
    pub fn topics(&self) -> &[Topic] {
        &self.topics
    }

    /// Counters so far.
    pub fn stats(&self) -> WriterStats {
        self.series.stats()
    }

    /// Every file opened so far (and not deleted by `max_total_bytes`), oldest first.
    pub fn files(&self) -> &[PathBuf] {
        self.series.files()
    }

    /// Writes one message: `payload` is the CDR sample with its encapsulation header;
    /// times are ns since the Unix epoch. A topic not recorded is ignored.
    pub fn write(
        &mut self,
        topic: Topic,
        log_time_ns: u64,
        publish_time_ns: u64,
        payload: &[u8],
    ) -> Result<(), RecordError> {
        let Some(slot) = self.slots[topic.index()] else {
            return Ok(());
        };
        self.series
            .write(slot, log_time_ns, publish_time_ns, payload)
    }

    /// Writes the current chunk out if it is a second old, and closes the file if it is
    /// due for rotation. Call it at least every second, whatever the traffic.
    pub fn tick(&mut self, now: Instant) -> Result<(), RecordError> {
        self.series.tick(now)
    }

    /// The longest the caller may wait before the next [`RecordWriter::tick`].
    pub fn next_tick(&self, now: Instant) -> Duration {
        self.series.next_tick(now)
    }

    /// Writes the current chunk to the file and the file to the operating system.
    pub fn flush(&mut self) -> Result<(), RecordError> {
        self.series.flush()
    }

    /// Finishes the current file (summary, footer) and syncs it; the next message opens
    /// a new one.
    pub fn close(&mut self) -> Result<(), RecordError> {
        self.series.close()
    }
}

/// A series of MCAP files with a fixed set of channels, in one directory under one
/// prefix: opened with the first message, chunked and compressed, a chunk on disk at least
/// every second, rotated by size and time, the oldest deleted past `max_total_bytes`.
pub(crate) struct McapSeries {
    directory: PathBuf,
    prefix: String,
    max_file_bytes: u64,
    max_total_bytes: u64,
    max_file_age: Duration,
    compression: Compression,
    compression_level: u32,
    specs: Vec<ChannelSpec>,
    chunk_bytes: u64,
    current: Option<OpenFile>,
    closed_bytes: u64,
    stats: WriterStats,
    files: Vec<PathBuf>,
}

impl std::fmt::Debug for McapSeries {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("McapSeries")
            .field("directory", &self.directory)
            .field("prefix", &self.prefix)
            .field("current", &self.current.as_ref().map(|c| &c.path))
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

impl McapSeries {
    /// A series of `PREFIX-*.mcap` files with `specs`' channels, written with `config`'s
    /// directory (created if missing), limits and compression. `config` must have been
    /// checked ([`RecorderConfig::check`]) and `prefix` be one it allows, or one with a
    /// fixed suffix of the same characters.
    pub(crate) fn new(
        config: &RecorderConfig,
        prefix: &str,
        specs: Vec<ChannelSpec>,
    ) -> Result<Self, RecordError> {
        std::fs::create_dir_all(&config.directory).map_err(|source| RecordError::Io {
            path: config.directory.clone(),
            source,
        })?;
        Ok(Self {
            directory: config.directory.clone(),
            prefix: prefix.to_owned(),
            max_file_bytes: config.max_file_bytes,
            max_total_bytes: config.max_total_bytes,
            max_file_age: Duration::from_secs(config.max_file_seconds),
            compression: config.compression,
            compression_level: config.compression_level,
            specs,
            // Small files get small chunks, so that rotation by size stays close.
            chunk_bytes: (config.max_file_bytes / 4).min(config.max_chunk_bytes),
            current: None,
            closed_bytes: 0,
            stats: WriterStats::default(),
            files: Vec::new(),
        })
    }

    /// Counters so far.
    pub fn stats(&self) -> WriterStats {
        let open = self
            .current
            .as_ref()
            .map_or(0, |f| f.len.load(Ordering::Relaxed));
        WriterStats {
            bytes: self.closed_bytes + open,
            ..self.stats
        }
    }

    /// Every file opened so far (and not deleted by `max_total_bytes`), oldest first.
    pub fn files(&self) -> &[PathBuf] {
        &self.files
    }

    /// Writes one message on channel `slot` (its place in the specs); times are ns since
    /// the Unix epoch. A slot out of range is ignored.
    pub fn write(
        &mut self,
        slot: usize,
        log_time_ns: u64,
        publish_time_ns: u64,
        payload: &[u8],
    ) -> Result<(), RecordError> {
        if slot >= self.specs.len() {
            return Ok(());
        }
        self.rotate_if_due(Instant::now())?;
        let chunk_bytes = self.chunk_bytes;
        let file = match self.current.as_mut() {
            Some(file) => file,
            None => self.open()?,
        };
        let (Some(&channel_id), Some(sequence)) =
            (file.channels.get(slot), file.sequence.get_mut(slot))
        else {
            return Ok(());
        };
        *sequence = sequence.wrapping_add(1);
        let header = MessageHeader {
            channel_id,
            sequence: *sequence,
            log_time: log_time_ns,
            publish_time: publish_time_ns,
        };
        file.writer
            .write_to_known_channel(&header, payload)
            .map_err(|source| RecordError::Mcap {
                path: file.path.clone(),
                source,
            })?;
        file.messages += 1;
        file.unflushed += 1;
        // Opcode, length, channel, sequence and the two times.
        file.unflushed_bytes += 31 + payload.len() as u64;
        let chunk_full = file.unflushed_bytes >= chunk_bytes;
        self.stats.messages += 1;
        if chunk_full {
            self.flush()?;
        }
        Ok(())
    }

    /// Writes the current chunk out if it is a second old, and closes the file if it is
    /// due for rotation. Call it at least every second, whatever the traffic.
    pub fn tick(&mut self, now: Instant) -> Result<(), RecordError> {
        if let Some(file) = &self.current
            && file.unflushed > 0
            && now.duration_since(file.last_flush) >= FLUSH_INTERVAL
        {
            self.flush()?;
        }
        self.rotate_if_due(now)
    }

    /// The longest the caller may wait before the next [`McapSeries::tick`].
    pub fn next_tick(&self, now: Instant) -> Duration {
        match &self.current {
            Some(file) if file.unflushed > 0 => {
                FLUSH_INTERVAL.saturating_sub(now.duration_since(file.last_flush))
            }
            _ => FLUSH_INTERVAL,
        }
    }

    /// Writes the current chunk to the file and the file to the operating system.
    pub fn flush(&mut self) -> Result<(), RecordError> {
        let Some(file) = self.current.as_mut() else {
            return Ok(());
        };
        file.writer.flush().map_err(|source| RecordError::Mcap {
            path: file.path.clone(),
            source,
        })?;
        file.unflushed = 0;
        file.unflushed_bytes = 0;
        file.last_flush = Instant::now();
        if file.len.load(Ordering::Relaxed) >= self.max_file_bytes {
            self.close()?;
        }
        Ok(())
    }

    /// Closes the current file if it is too old or (after its last chunk) too large.
    fn rotate_if_due(&mut self, now: Instant) -> Result<(), RecordError> {
        let Some(file) = &self.current else {
            return Ok(());
        };
        if file.messages > 0 && now.duration_since(file.opened) >= self.max_file_age {
            self.close()?;
        }
        Ok(())
    }

    /// Finishes the current file (summary, footer) and syncs it; the next message opens
    /// a new one.
    pub fn close(&mut self) -> Result<(), RecordError> {
        let Some(mut file) = self.current.take() else {
            return Ok(());
        };
        let mcap_err = |source| RecordError::Mcap {
            path: file.path.clone(),
            source,
        };
        file.writer.finish().map_err(mcap_err)?;
        let len = file.len.load(Ordering::Relaxed);
        let mut inner = file.writer.into_inner();
        let io_err = |source| RecordError::Io {
            path: file.path.clone(),
            source,
        };
        inner.flush().map_err(io_err)?;
        inner.inner.get_ref().sync_all().map_err(io_err)?;
        self.closed_bytes += len;
        info!(file = %file.path.display(), messages = file.messages, bytes = len, "recording file closed");
        self.prune();
        Ok(())
    }

    /// Deletes this prefix's oldest files until they fit in `max_total_bytes`, keeping
    /// the newest. A failure is logged, not fatal: recording goes on.
    fn prune(&mut self) {
        let Ok(all) = crate::reader::mcap_files(&self.directory) else {
            return;
        };
        let mine: Vec<(PathBuf, u64)> = all
            .into_iter()
            .filter(|p| {
                p.file_stem()
                    .and_then(|n| n.to_str())
                    .is_some_and(|n| is_series_file(n, &self.prefix))
            })
            .filter_map(|p| std::fs::metadata(&p).ok().map(|m| (p, m.len())))
            .collect();
        let mut total: u64 = mine.iter().map(|(_, len)| len).sum();
        let keep_newest = mine.len().saturating_sub(1);
        for (path, len) in mine.into_iter().take(keep_newest) {
            if total <= self.max_total_bytes {
                break;
            }
            match std::fs::remove_file(&path) {
                Ok(()) => {
                    total -= len;
                    self.stats.files_deleted += 1;
                    self.files.retain(|f| f != &path);
                    info!(file = %path.display(), bytes = len, "oldest recording deleted (recorder.max_total_bytes)");
                }
                Err(e) => {
                    tracing::warn!(file = %path.display(), error = %e, "oldest recording not deleted");
                    break;
                }
            }
        }
    }

    fn open(&mut self) -> Result<&mut OpenFile, RecordError> {
        let stamp = utc_stamp(time::OffsetDateTime::now_utc());
        let mut n = self.stats.files + 1;
        // create_new: never overwrite a file, e.g. of a recorder started in the same second.
        let (path, file) = loop {
            let path = self
                .directory
                .join(format!("{}-{stamp}-{n}.mcap", self.prefix));
            match OpenOptions::new().write(true).create_new(true).open(&path) {
                Ok(f) => break (path, f),
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => n += 1,
                Err(source) => return Err(RecordError::Io { path, source }),
            }
        };
        let len = Arc::new(AtomicU64::new(0));
        let sink = Counting {
            inner: BufWriter::with_capacity(256 * 1024, file),
            pos: 0,
            len: Arc::clone(&len),
        };
        let compression = match self.compression {
            Compression::Zstd => Some(mcap::Compression::Zstd),
            Compression::None => None,
        };
        let mcap_err = |source| RecordError::Mcap {
            path: path.clone(),
            source,
        };
        let mut writer = mcap::WriteOptions::new()
            .profile(PROFILE)
            .library(concat!("shoal-recorder ", env!("CARGO_PKG_VERSION")))
            .compression(compression)
            .compression_level(self.compression_level)
            // Compress on this thread: a worker pool would cost threads and CPU for a
            // data rate of a few MB/s at most.
            .compression_threads(0)
            .chunk_size(Some(self.chunk_bytes.max(1)))
            // Whole chunks are built in memory and written at once: the file never holds
            // half a chunk with a placeholder header, only at most one partial write.
            .disable_seeking(true)
            // Readers find chunks through the chunk index; message indexes would cost 16
            // uncompressed bytes per message on disk.
            .emit_message_indexes(false)
            .create(sink)
            .map_err(mcap_err)?;
        let mut channels = Vec::with_capacity(self.specs.len());
        for spec in &self.specs {
            let schema = writer
                .add_schema(
                    spec.schema_name,
                    spec.schema_encoding,
                    spec.schema.as_bytes(),
                )
                .map_err(mcap_err)?;
            let id = writer
                .add_channel(schema, spec.topic, spec.message_encoding, &BTreeMap::new())
                .map_err(mcap_err)?;
            channels.push(id);
        }
        // Header, schemas and channels reach the disk at once: even a file killed before
        // its first flush says what it would have held.
        writer.flush().map_err(mcap_err)?;
        debug!(file = %path.display(), "recording file opened");
        self.stats.files += 1;
        self.files.push(path.clone());
        let now = Instant::now();
        Ok(self.current.insert(OpenFile {
            path,
            writer,
            len,
            sequence: vec![0; channels.len()],
            channels,
            opened: now,
            messages: 0,
            unflushed: 0,
            unflushed_bytes: 0,
            last_flush: now,
        }))
    }
}

impl Drop for McapSeries {
    fn drop(&mut self) {
        if let Err(e) = self.close() {
            tracing::warn!(error = %e, "recording file not closed cleanly");
        }
    }
}

/// Whether `stem` names a file of the series `prefix`: `PREFIX-YYYYmmddTHHMMSSZ-N`
/// exactly, so that another series whose prefix starts with this one (the acoustic files'
/// `PREFIX-acoustic`) is never counted or deleted as this one's.
fn is_series_file(stem: &str, prefix: &str) -> bool {
    stem.strip_prefix(prefix)
        .and_then(|rest| rest.strip_prefix('-'))
        .and_then(|rest| rest.split_once('-'))
        .is_some_and(|(stamp, n)| {
            crate::reader::is_stamp(stamp) && !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit())
        })
}

/// `YYYYmmddTHHMMSSZ` of a UTC time.
fn utc_stamp(t: time::OffsetDateTime) -> String {
    format!(
        "{:04}{:02}{:02}T{:02}{:02}{:02}Z",
        t.year(),
        u8::from(t.month()),
        t.day(),
        t.hour(),
        t.minute(),
        t.second()
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_series_counts_only_its_own_file_names() {
        assert!(is_series_file("shoal-20260101T000000Z-1", "shoal"));
        assert!(is_series_file("shoal-20260101T000000Z-12", "shoal"));
        assert!(is_series_file(
            "shoal-acoustic-20260101T000000Z-3",
            "shoal-acoustic"
        ));
        for other in [
            "shoal-acoustic-20260101T000000Z-3",
            "shoalx-20260101T000000Z-1",
            "shoal-20260101T000000Z-",
            "shoal-20260101T000000Z-1x",
            "shoal-2026010T000000Z-1",
            "shoal-2026010\u{e9}T00000Z-1",
            "shoal",
        ] {
            assert!(!is_series_file(other, "shoal"), "{other}");
        }
    }
}
