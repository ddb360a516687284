//! Reading MCAP files front to back, chunk by chunk, without the summary: what a
//! recorder killed mid-file left is read up to its last complete chunk.

use std::collections::{HashMap, VecDeque};
use std::io::Read;
use std::path::{Path, PathBuf};

use mcap::records::{ChunkHeader, Record, op};
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};

use crate::error::{ReadError, ReplayError};
use crate::topic::Topic;
use crate::{MESSAGE_ENCODING, SCHEMA_ENCODING};

/// Largest record (or chunk, compressed or not) accepted: bounds the memory a hostile
/// file can make the reader take. The recorder's chunks are at most 16 MiB
/// (`recorder.max_chunk_bytes`).
pub const MAX_RECORD_BYTES: u64 = 64 * 1024 * 1024;

/// Most bytes read from the source at once, so that a record claiming a huge length
/// costs memory only as far as the file really goes.
const READ_STEP: usize = 64 * 1024;

/// Every MCAP record starts with an opcode byte and a 64-bit length.
const RECORD_PREFIX: u64 = 9;

/// Most topic names of skipped channels kept per file ([`McapMessages::unknown_topics`]).
const MAX_UNKNOWN_TOPICS: usize = 16;

/// Longest topic name of a skipped channel kept, bytes (longer ones are cut).
const MAX_UNKNOWN_TOPIC_LEN: usize = 128;

/// A recorded message of a Shoal topic.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecordedMessage {
    /// Its topic.
    pub topic: Topic,
    /// When it was received, ns since the Unix epoch.
    pub log_time_ns: u64,
    /// When it was sent (its DDS source timestamp), ns since the Unix epoch.
    pub publish_time_ns: u64,
    /// The CDR sample: encapsulation header and XCDR1 body.
    pub data: Vec<u8>,
}

/// What a reader met so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ReaderStats {
    /// Messages of Shoal channels delivered.
    pub messages: u64,
    /// Messages skipped: their channel is not a Shoal topic with the `omgidl` schema of
    /// its type and `cdr` messages (or names no channel at all).
    pub unknown_messages: u64,
    /// Channels seen that are not Shoal channels.
    pub unknown_channels: u64,
    /// Chunks read.
    pub chunks: u64,
}

/// The messages of one MCAP file in file order, read sequentially.
///
/// Iterates `Ok(message)` for each message of a Shoal channel; stops with one `Err` naming
/// the byte offset where reading stopped when the file is truncated or corrupt. Messages
/// of a chunk are delivered only once the whole chunk was read and its CRC checked.
pub struct McapMessages<R> {
    source: R,
    reader: LinearReader,
    /// Bytes handed to `reader`: it asks for exactly what its next record needs, so at
    /// each record this is where the record ends.
    fed: u64,
    /// Where the last record read ended: everything before it was used.
    good: u64,
    schemas: HashMap<u16, (String, String)>,
    channels: HashMap<u16, Option<Topic>>,
    unknown_topics: Vec<String>,
    queue: VecDeque<RecordedMessage>,
    stats: ReaderStats,
    done: bool,
}

impl<R> std::fmt::Debug for McapMessages<R> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("McapMessages")
            .field("offset", &self.good)
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

impl<R: Read> McapMessages<R> {
    /// A reader of the MCAP bytes `source` gives (a file, a slice).
    pub fn new(source: R) -> Self {
        let options = LinearReaderOptions::default()
            .with_emit_chunks(true)
            .with_record_length_limit(usize::try_from(MAX_RECORD_BYTES).unwrap_or(usize::MAX));
        Self {
            source,
            reader: LinearReader::new_with_options(options),
            fed: 0,
            good: 0,
            schemas: HashMap::new(),
            channels: HashMap::new(),
            unknown_topics: Vec::new(),
            queue: VecDeque::new(),
            stats: ReaderStats::default(),
            done: false,
        }
    }

    /// Counters so far.
    pub fn stats(&self) -> ReaderStats {
        self.stats
    }

    /// Bytes read and used so far.
    pub fn offset(&self) -> u64 {
        self.good
    }

    /// The topics of the channels skipped so far (not Shoal channels: an acoustic
    /// recording's `acoustic/frame`, another tool's topics), in the order met; at most 16,
    /// each cut to 128 bytes.
    pub fn unknown_topics(&self) -> &[String] {
        &self.unknown_topics
    }

    /// Reads on until there are messages queued or the file ends (`Ok(false)`).
    fn advance(&mut self) -> Result<bool, ReadError> {
        while self.queue.is_empty() {
            let Some(event) = self.reader.next_event() else {
                return Ok(false);
            };
            match event {
                Ok(LinearReadEvent::ReadRequest(need)) => {
                    let step = need.clamp(1, READ_STEP);
                    let buf = self.reader.insert(step);
                    let n = loop {
                        match self.source.read(buf) {
                            Ok(n) => break n,
                            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                            Err(source) => {
                                return Err(ReadError::Io {
                                    offset: self.good,
                                    source,
                                });
                            }
                        }
                    };
                    self.reader.notify_read(n);
                    self.fed += n as u64;
                }
                Ok(LinearReadEvent::Record { opcode, data }) => {
                    let start = self.fed.saturating_sub(RECORD_PREFIX + data.len() as u64);
                    let corrupt = |detail: String| ReadError::Corrupt {
                        offset: start,
                        detail,
                    };
                    // Records replay does not use are skipped unparsed: each parse is a
                    // chance for a hostile length to cost memory.
                    if !matches!(opcode, op::SCHEMA | op::CHANNEL | op::MESSAGE | op::CHUNK) {
                        self.good = self.fed;
                        continue;
                    }
                    check_lengths(opcode, data).map_err(corrupt)?;
                    let record =
                        mcap::parse_record(opcode, data).map_err(|e| corrupt(e.to_string()))?;
                    let records = match record {
                        Record::Chunk { header, data } => {
                            if header.uncompressed_size > MAX_RECORD_BYTES {
                                return Err(ReadError::Corrupt {
                                    offset: start,
                                    detail: format!(
                                        "a chunk of {} bytes uncompressed, more than the {MAX_RECORD_BYTES} accepted",
                                        header.uncompressed_size
                                    ),
                                });
                            }
                            // The whole chunk first: a damaged chunk delivers nothing.
                            let chunk = chunk_records(&header, &data)
                                .map_err(|e| corrupt(format!("chunk: {e}")))?;
                            self.stats.chunks += 1;
                            chunk
                        }
                        other => vec![other.into_owned()],
                    };
                    for record in records {
                        self.take(record);
                    }
                    self.good = self.fed;
                }
                Err(mcap::McapError::UnexpectedEof) => {
                    return Err(ReadError::Truncated {
                        offset: self.good,
                        file_len: self.fed,
                    });
                }
                Err(e) => {
                    return Err(ReadError::Corrupt {
                        offset: self.good,
                        detail: e.to_string(),
                    });
                }
            }
        }
        Ok(true)
    }

    /// Notes a schema or channel, queues a message of a Shoal channel.
    fn take(&mut self, record: Record<'static>) {
        match record {
            Record::Schema { header, .. } => {
                self.schemas
                    .insert(header.id, (header.name, header.encoding));
            }
            Record::Channel(channel) => {
                let topic = Topic::from_name(&channel.topic).filter(|topic| {
                    channel.message_encoding == MESSAGE_ENCODING
                        && self
                            .schemas
                            .get(&channel.schema_id)
                            .is_some_and(|(name, encoding)| {
                                name == topic.type_name() && encoding == SCHEMA_ENCODING
                            })
                });
                if topic.is_none() && !self.channels.contains_key(&channel.id) {
                    self.stats.unknown_channels += 1;
                    let mut name = channel.topic;
                    if name.len() > MAX_UNKNOWN_TOPIC_LEN {
                        let mut cut = MAX_UNKNOWN_TOPIC_LEN;
                        while !name.is_char_boundary(cut) {
                            cut -= 1;
                        }
                        name.truncate(cut);
                    }
                    if self.unknown_topics.len() < MAX_UNKNOWN_TOPICS
                        && !self.unknown_topics.contains(&name)
                    {
                        self.unknown_topics.push(name);
                    }
                }
                self.channels.insert(channel.id, topic);
            }
            Record::Message { header, data } => {
                match self.channels.get(&header.channel_id).copied().flatten() {
                    Some(topic) => {
                        self.stats.messages += 1;
                        self.queue.push_back(RecordedMessage {
                            topic,
                            log_time_ns: header.log_time,
                            publish_time_ns: header.publish_time,
                            data: data.into_owned(),
                        });
                    }
                    None => self.stats.unknown_messages += 1,
                }
            }
            _ => {}
        }
    }
}

impl<R: Read> Iterator for McapMessages<R> {
    type Item = Result<RecordedMessage, ReadError>;

    fn next(&mut self) -> Option<Self::Item> {
        if let Some(m) = self.queue.pop_front() {
            return Some(Ok(m));
        }
        if self.done {
            return None;
        }
        match self.advance() {
            Ok(true) => self.queue.pop_front().map(Ok),
            Ok(false) => {
                self.done = true;
                None
            }
            Err(e) => {
                self.done = true;
                Some(Err(e))
            }
        }
    }
}

/// Checks every length a record of `opcode` declares inside `body` against what `body`
/// holds, before the `mcap` crate parses it: the crate reserves memory for a string's or
/// map's declared length first, so one hostile length field would cost gigabytes.
fn check_lengths(opcode: u8, body: &[u8]) -> Result<(), String> {
    let mut at = Fields { body, pos: 0 };
    match opcode {
        // id; name, encoding; the data's own length the crate checks.
        op::SCHEMA => {
            at.skip(2)?;
            at.string("schema name")?;
            at.string("schema encoding")?;
        }
        // id, schema id; topic, message encoding; metadata map.
        op::CHANNEL => {
            at.skip(4)?;
            at.string("channel topic")?;
            at.string("message encoding")?;
            let map_len = at.length("channel metadata")?;
            let end = at.pos + map_len;
            let mut map = Fields {
                body: &body[..end],
                pos: at.pos,
            };
            while map.pos < end {
                map.string("metadata key")?;
                map.string("metadata value")?;
            }
        }
        // start and end times, uncompressed size and CRC; compression.
        op::CHUNK => {
            at.skip(28)?;
            at.string("chunk compression")?;
        }
        _ => {}
    }
    Ok(())
}

/// A cursor over a record body that checks each declared length.
struct Fields<'a> {
    body: &'a [u8],
    pos: usize,
}

impl Fields<'_> {
    fn skip(&mut self, n: usize) -> Result<(), String> {
        if self.body.len() - self.pos < n {
            return Err(format!("record ends after {} bytes", self.body.len()));
        }
        self.pos += n;
        Ok(())
    }

    /// A u32 length prefix, checked against the bytes left; the position moves past it.
    fn length(&mut self, what: &str) -> Result<usize, String> {
        let start = self.pos;
        self.skip(4)?;
        let mut le = [0u8; 4];
        le.copy_from_slice(&self.body[start..start + 4]);
        let len = u32::from_le_bytes(le) as usize;
        let left = self.body.len() - self.pos;
        if len > left {
            return Err(format!("{what} declares {len} bytes where {left} are left"));
        }
        Ok(len)
    }

    fn string(&mut self, what: &str) -> Result<(), String> {
        let len = self.length(what)?;
        self.pos += len;
        Ok(())
    }
}

/// The schema, channel and message records of a chunk, decompressed within its declared
/// size (checked beforehand) and CRC-checked; each record's lengths are checked before
/// it is parsed, and records replay does not use are skipped unparsed.
fn chunk_records(header: &ChunkHeader, data: &[u8]) -> Result<Vec<Record<'static>>, String> {
    let size = usize::try_from(header.uncompressed_size).map_err(|e| e.to_string())?;
    let plain = match header.compression.as_str() {
        "" => data.to_vec(),
        "zstd" => zstd::bulk::decompress(data, size).map_err(|e| format!("zstd: {e}"))?,
        other => return Err(format!("unsupported compression {other:?}")),
    };
    if plain.len() != size {
        return Err(format!(
            "{} bytes uncompressed where the header says {size}",
            plain.len()
        ));
    }
    if header.uncompressed_crc != 0 && crc32fast::hash(&plain) != header.uncompressed_crc {
        return Err("CRC mismatch".into());
    }
    let mut records = Vec::new();
    let mut rest = plain.as_slice();
    while !rest.is_empty() {
        if rest.len() < 9 {
            return Err("a record prefix is cut short".into());
        }
        let opcode = rest[0];
        let mut le = [0u8; 8];
        le.copy_from_slice(&rest[1..9]);
        let len = u64::from_le_bytes(le);
        let body_len = usize::try_from(len)
            .ok()
            .filter(|l| *l <= rest.len() - 9)
            .ok_or_else(|| format!("a record declares {len} bytes past the chunk's end"))?;
        let body = &rest[9..9 + body_len];
        rest = &rest[9 + body_len..];
        if !matches!(opcode, op::SCHEMA | op::CHANNEL | op::MESSAGE) {
            continue;
        }
        check_lengths(opcode, body)?;
        let record = mcap::parse_record(opcode, body).map_err(|e| e.to_string())?;
        records.push(record.into_owned());
    }
    Ok(records)
}

/// The MCAP files to replay for `path`: the file itself, or a directory's `.mcap` files in
/// recording order (by the time and number in the recorder's names, then by name).
pub fn mcap_files(path: &Path) -> Result<Vec<PathBuf>, ReplayError> {
    let open_err = |source| ReplayError::Open {
        path: path.to_path_buf(),
        source,
    };
    let meta = std::fs::metadata(path).map_err(open_err)?;
    if !meta.is_dir() {
        return Ok(vec![path.to_path_buf()]);
    }
    let mut files = Vec::new();
    for entry in std::fs::read_dir(path).map_err(open_err)? {
        let p = entry.map_err(open_err)?.path();
        if p.extension().is_some_and(|e| e == "mcap") && p.is_file() {
            files.push(p);
        }
    }
    if files.is_empty() {
        return Err(ReplayError::NoFiles(path.to_path_buf()));
    }
    files.sort_by_cached_key(|p| {
        let name = p
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        (order_key(&name), name)
    });
    Ok(files)
}

/// (`YYYYmmddTHHMMSSZ`, N) of a recorder's file name `PREFIX-YYYYmmddTHHMMSSZ-N`, so that
/// file 10 comes after file 9; names of another form sort first, by name.
fn order_key(stem: &str) -> Option<(String, u64)> {
    let (rest, n) = stem.rsplit_once('-')?;
    let n: u64 = n.parse().ok()?;
    let (_, stamp) = rest.rsplit_once('-')?;
    is_stamp(stamp).then(|| (stamp.to_string(), n))
}

/// Whether `stamp` is a recorder's `YYYYmmddTHHMMSSZ` (checked byte by byte: a file name
/// is whatever the directory holds, not necessarily ASCII).
pub(crate) fn is_stamp(stamp: &str) -> bool {
    let b = stamp.as_bytes();
    b.len() == 16
        && b[8] == b'T'
        && b[15] == b'Z'
        && b[..8].iter().chain(&b[9..15]).all(u8::is_ascii_digit)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recorder_file_names_sort_by_time_then_number() {
        let mut names = vec![
            "shoal-20260101T000000Z-10",
            "shoal-20260101T000000Z-9",
            "other",
            "shoal-20251231T235959Z-11",
        ];
        names.sort_by_key(|n| (order_key(n), n.to_string()));
        assert_eq!(
            names,
            [
                "other",
                "shoal-20251231T235959Z-11",
                "shoal-20260101T000000Z-9",
                "shoal-20260101T000000Z-10"
            ]
        );
    }
}
