//! The acoustic link's frames and modem events into MCAP files (docs/recorder.md,
//! "Acoustic frames").
//!
//! A CDT given a [`FrameTap`] ([`shoal_converter::CdtConfig::tap`]) copies what it sends,
//! what it receives and what became of each message into the tap's bounded queue;
//! [`AcousticRecorder`] takes them from there on a thread of its own and writes them with
//! [`AcousticWriter`] as JSON messages with JSON Schemas, which Foxglove and the Python
//! `mcap` reader open as they are. The files are the DDS recorder's kind (chunked, zstd,
//! rotated, crash-safe, pruned: [`crate::writer::McapSeries`]), under their own prefix
//! `PREFIX-acoustic`, so that `shoal replay` of the directory is unaffected.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::RecvTimeoutError;
use std::time::{Duration, Instant};

use serde::Serialize;
use shoal_acoustic::link::Class;
use shoal_acoustic::pdu::{self, Pdu};
use shoal_converter::tap::{FrameTap, TapEvent, TapQueue, TapRecord};
use tracing::error;

use crate::config::RecorderConfig;
use crate::error::RecordError;
use crate::recorder::join_writer;
use crate::writer::{ChannelSpec, McapSeries, WriterStats};

/// The channel of frames sent and received.
pub const FRAME_TOPIC: &str = "acoustic/frame";
/// The channel of what became of each sent message.
pub const LINK_EVENT_TOPIC: &str = "acoustic/link_event";
/// The schema name of [`FRAME_TOPIC`]'s messages.
pub const FRAME_SCHEMA_NAME: &str = "shoal.acoustic.Frame";
/// The schema name of [`LINK_EVENT_TOPIC`]'s messages.
pub const LINK_EVENT_SCHEMA_NAME: &str = "shoal.acoustic.LinkEvent";
/// The message encoding of the acoustic channels.
pub const ACOUSTIC_MESSAGE_ENCODING: &str = "json";
/// The schema encoding of the acoustic channels.
pub const ACOUSTIC_SCHEMA_ENCODING: &str = "jsonschema";
/// What the acoustic files' prefix adds to `recorder.prefix`.
pub const ACOUSTIC_PREFIX_SUFFIX: &str = "-acoustic";

/// Most records waiting for the acoustic file writer: an acoustic link carries a few
/// frames a second, so this is minutes of traffic; `recorder.queue_samples` if smaller.
pub const ACOUSTIC_QUEUE_MAX: usize = 4096;

/// The JSON Schema of [`FRAME_TOPIC`]'s messages.
pub const FRAME_SCHEMA: &str = r#"{
  "$schema": "https://json-schema.org/draft/2020-12/schema",
  "title": "shoal.acoustic.Frame",
  "description": "A frame a Shoal CDT received from its modem, or a PDU it handed to its acoustic link layer (which packs PDUs for one destination into a modem frame). Fields marked optional are absent when they do not apply.",
  "type": "object",
  "properties": {
    "direction": {"type": "string", "enum": ["sent", "received"], "description": "sent: handed to the link layer; received: delivered by the modem"},
    "local": {"type": "integer", "minimum": 0, "maximum": 255, "description": "the recording CDT's acoustic address"},
    "src": {"type": "integer", "minimum": 0, "maximum": 255, "description": "sender's acoustic address"},
    "dst": {"type": "integer", "minimum": 0, "maximum": 255, "description": "destination's acoustic address (255: broadcast)"},
    "message_id": {"type": "integer", "minimum": 0, "description": "sent only: the link's id for the message, named again by its acoustic/link_event"},
    "class": {"type": "string", "enum": ["emergency", "control", "telemetry", "bulk"], "description": "sent only: the link class"},
    "length": {"type": "integer", "minimum": 0, "description": "bytes"},
    "hex": {"type": "string", "pattern": "^([0-9a-f]{2})*$", "description": "the bytes, lower-case hex"},
    "rssi_db": {"type": "integer", "description": "received only, where the modem reports it: RSSI, dB"},
    "integrity": {"type": "integer", "minimum": 0, "description": "received only, where the modem reports it: signal integrity"},
    "converter_ms": {"type": "integer", "description": "the CDT's clock, ms since the Unix epoch (a scenario run's simulated time)"},
    "pdus": {"type": "array", "description": "the compact PDUs decoded, as `shoal pdu decode` prints them; absent when the bytes do not decode", "items": {"type": "object", "properties": {"type": {"type": "string"}}, "required": ["type"]}},
    "decode_error": {"type": "string", "description": "why the bytes do not decode as PDUs, when they do not"}
  },
  "required": ["direction", "local", "src", "dst", "length", "hex", "converter_ms"],
  "additionalProperties": false
}
"#;

/// The JSON Schema of [`LINK_EVENT_TOPIC`]'s messages.
pub const LINK_EVENT_SCHEMA: &str = r#"{
  "$schema": "https://json-schema.org/draft/2020-12/schema",
  "title": "shoal.acoustic.LinkEvent",
  "description": "What a Shoal CDT's acoustic link layer reported for a message it had: delivered (acknowledged by the destination's modem), sent (without acknowledgement), expired (its TTL ran out) or dropped (queue full, superseded, refused by the modem, larger than a frame).",
  "type": "object",
  "properties": {
    "event": {"type": "string", "enum": ["delivered", "sent", "expired", "dropped"]},
    "local": {"type": "integer", "minimum": 0, "maximum": 255, "description": "the recording CDT's acoustic address"},
    "message_id": {"type": "integer", "minimum": 0, "description": "the message, as its acoustic/frame record (direction sent) names it"},
    "converter_ms": {"type": "integer", "description": "the CDT's clock, ms since the Unix epoch (a scenario run's simulated time)"}
  },
  "required": ["event", "local", "message_id", "converter_ms"],
  "additionalProperties": false
}
"#;

/// The acoustic channels, in their slot order.
const CHANNELS: [ChannelSpec; 2] = [
    ChannelSpec {
        topic: FRAME_TOPIC,
        message_encoding: ACOUSTIC_MESSAGE_ENCODING,
        schema_name: FRAME_SCHEMA_NAME,
        schema_encoding: ACOUSTIC_SCHEMA_ENCODING,
        schema: FRAME_SCHEMA,
    },
    ChannelSpec {
        topic: LINK_EVENT_TOPIC,
        message_encoding: ACOUSTIC_MESSAGE_ENCODING,
        schema_name: LINK_EVENT_SCHEMA_NAME,
        schema_encoding: ACOUSTIC_SCHEMA_ENCODING,
        schema: LINK_EVENT_SCHEMA,
    },
];
const FRAME_SLOT: usize = 0;
const LINK_EVENT_SLOT: usize = 1;

/// The file name prefix of `config`'s acoustic files: `recorder.prefix` and `-acoustic`.
pub fn acoustic_prefix(config: &RecorderConfig) -> String {
    format!("{}{ACOUSTIC_PREFIX_SUFFIX}", config.prefix)
}

/// An `acoustic/frame` message.
#[derive(Debug, Serialize)]
struct FrameJson {
    direction: &'static str,
    local: u8,
    src: u8,
    dst: u8,
    #[serde(skip_serializing_if = "Option::is_none")]
    message_id: Option<u64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    class: Option<Class>,
    length: usize,
    hex: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    rssi_db: Option<i32>,
    #[serde(skip_serializing_if = "Option::is_none")]
    integrity: Option<u32>,
    converter_ms: i64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pdus: Option<Vec<Pdu>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    decode_error: Option<String>,
}

impl FrameJson {
    fn new(record: &TapRecord, direction: &'static str, src: u8, dst: u8, bytes: &[u8]) -> Self {
        // The bytes came over the water (or are about to): a frame that does not decode is
        // recorded with the reason, never an error.
        let (pdus, decode_error) = match pdu::unpack_frame(bytes) {
            Ok(p) => (Some(p), None),
            Err(e) => (None, Some(e.to_string())),
        };
        Self {
            direction,
            local: record.local,
            src,
            dst,
            message_id: None,
            class: None,
            length: bytes.len(),
            hex: hex::encode(bytes),
            rssi_db: None,
            integrity: None,
            converter_ms: record.converter_ms,
            pdus,
            decode_error,
        }
    }
}

/// An `acoustic/link_event` message.
#[derive(Debug, Serialize)]
struct LinkEventJson {
    event: &'static str,
    local: u8,
    message_id: u64,
    converter_ms: i64,
}

/// The channel slot and JSON message of a tap record; `None` for an event kind this
/// recorder does not know (a newer converter's).
fn encode(record: &TapRecord) -> Result<Option<(usize, Vec<u8>)>, RecordError> {
    let encoded = match &record.event {
        TapEvent::Sent {
            dst,
            class,
            message_id,
            bytes,
        } => {
            let mut json = FrameJson::new(record, "sent", record.local, *dst, bytes);
            json.message_id = Some(*message_id);
            json.class = Some(*class);
            (FRAME_SLOT, serde_json::to_vec(&json)?)
        }
        TapEvent::Received {
            src,
            dst,
            bytes,
            rssi,
            integrity,
        } => {
            let mut json = FrameJson::new(record, "received", *src, *dst, bytes);
            json.rssi_db = *rssi;
            json.integrity = *integrity;
            (FRAME_SLOT, serde_json::to_vec(&json)?)
        }
        TapEvent::Fate { message_id, fate } => {
            let json = LinkEventJson {
                event: fate.name(),
                local: record.local,
                message_id: *message_id,
                converter_ms: record.converter_ms,
            };
            (LINK_EVENT_SLOT, serde_json::to_vec(&json)?)
        }
        _ => return Ok(None),
    };
    Ok(Some(encoded))
}

/// Writes tap records into a series of MCAP files `PREFIX-acoustic-YYYYmmddTHHMMSSZ-N.mcap`
/// with the channels `acoustic/frame` and `acoustic/link_event` (JSON messages, JSON
/// Schemas), with the DDS recorder's file handling: chunks, compression, a chunk on disk
/// at least every second, rotation by size and time, the oldest of these files deleted
/// past `max_total_bytes` (counted apart from the DDS files).
#[derive(Debug)]
pub struct AcousticWriter {
    series: McapSeries,
}

impl AcousticWriter {
    /// A writer for `config`'s directory (created if missing), limits and compression;
    /// `enabled`, `acoustic`, `topics` and `queue_samples` play no part here. The first
    /// file is opened with the first record.
    pub fn new(config: &RecorderConfig) -> Result<Self, RecordError> {
        config.check()?;
        let series = McapSeries::new(config, &acoustic_prefix(config), CHANNELS.to_vec())?;
        Ok(Self { series })
    }

    /// Writes one record, at its wall-clock time (`log_time` and `publish_time`).
    pub fn write(&mut self, record: &TapRecord) -> Result<(), RecordError> {
        let Some((slot, json)) = encode(record)? else {
            return Ok(());
        };
        self.series
            .write(slot, record.time_ns, record.time_ns, &json)
    }

    /// Writes the current chunk out if it is a second old, and closes the file if it is
    /// due for rotation. Call it at least every second, whatever the traffic.
    pub fn tick(&mut self, now: Instant) -> Result<(), RecordError> {
        self.series.tick(now)
    }

    /// The longest the caller may wait before the next [`AcousticWriter::tick`].
    pub fn next_tick(&self, now: Instant) -> Duration {
        self.series.next_tick(now)
    }

    /// Writes the current chunk to the file and the file to the operating system.
    pub fn flush(&mut self) -> Result<(), RecordError> {
        self.series.flush()
    }

    /// Finishes the current file (summary, footer) and syncs it.
    pub fn close(&mut self) -> Result<(), RecordError> {
        self.series.close()
    }

    /// Counters so far.
    pub fn stats(&self) -> WriterStats {
        self.series.stats()
    }

    /// Every file opened so far (and not deleted by `max_total_bytes`), oldest first.
    pub fn files(&self) -> &[PathBuf] {
        self.series.files()
    }
}

/// What an acoustic recorder has done so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct AcousticStats {
    /// Records taken from the tap.
    pub received: u64,
    /// Messages written to files.
    pub messages: u64,
    /// Bytes on disk, all its files together.
    pub bytes: u64,
    /// Files opened.
    pub files: u64,
    /// Old files deleted to keep them under `max_total_bytes`.
    pub files_deleted: u64,
    /// Records the tap dropped because its queue was full (the writer was behind).
    pub dropped: u64,
}

#[derive(Debug, Default)]
struct Counters {
    received: AtomicU64,
    messages: AtomicU64,
    bytes: AtomicU64,
    files: AtomicU64,
    files_deleted: AtomicU64,
    dropped: AtomicU64,
    failed: AtomicBool,
}

/// How long the writer thread waits at most before looking at the stop flag again (the
/// tap's end closing wakes it at once; a tap still held somewhere does not).
const STOP_POLL: Duration = Duration::from_millis(250);

/// Records what a CDT's frame tap reports into MCAP files until stopped: a thread owns the
/// [`AcousticWriter`] and empties the tap's bounded queue; a full queue drops and counts
/// at the tap, never making the CDT wait.
pub struct AcousticRecorder {
    counters: Arc<Counters>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<Result<(), RecordError>>>,
}

impl std::fmt::Debug for AcousticRecorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("AcousticRecorder")
            .field("stats", &self.stats())
            .finish_non_exhaustive()
    }
}

impl AcousticRecorder {
    /// Starts recording into `config`'s directory, and returns the tap to give the CDT
    /// (clone it for several). Its queue holds `queue_samples` records, at most
    /// [`ACOUSTIC_QUEUE_MAX`].
    pub fn start(config: &RecorderConfig) -> Result<(Self, FrameTap), RecordError> {
        let (tap, queue) = FrameTap::bounded(config.queue_samples.min(ACOUSTIC_QUEUE_MAX));
        let recorder = Self::start_with(config, queue)?;
        Ok((recorder, tap))
    }

    /// Starts recording what `queue`'s taps report into `config`'s directory.
    pub fn start_with(config: &RecorderConfig, queue: TapQueue) -> Result<Self, RecordError> {
        let writer = AcousticWriter::new(config)?;
        let counters = Arc::new(Counters::default());
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let (counters, stop) = (Arc::clone(&counters), Arc::clone(&stop));
            std::thread::Builder::new()
                .name("shoal-acoustic-rec".into())
                .spawn(move || write_loop(writer, &queue, &stop, &counters))
                .map_err(|e| RecordError::Thread(e.to_string()))?
        };
        Ok(Self {
            counters,
            stop,
            thread: Some(thread),
        })
    }

    /// Counters so far.
    pub fn stats(&self) -> AcousticStats {
        let c = &self.counters;
        AcousticStats {
            received: c.received.load(Ordering::Relaxed),
            messages: c.messages.load(Ordering::Relaxed),
            bytes: c.bytes.load(Ordering::Relaxed),
            files: c.files.load(Ordering::Relaxed),
            files_deleted: c.files_deleted.load(Ordering::Relaxed),
            dropped: c.dropped.load(Ordering::Relaxed),
        }
    }

    /// True once the writer has stopped on an error, which [`AcousticRecorder::stop`]
    /// returns (the files stay readable up to their last chunk).
    pub fn failed(&self) -> bool {
        self.counters.failed.load(Ordering::Acquire)
    }

    /// Writes what is queued, closes the file properly and returns the counters. Quick
    /// once every tap is dropped (the CDT stopped); otherwise within a quarter second.
    pub async fn stop(mut self) -> Result<AcousticStats, RecordError> {
        self.stop.store(true, Ordering::Release);
        let thread = self.thread.take();
        join_writer(thread).await?;
        Ok(self.stats())
    }
}

impl Drop for AcousticRecorder {
    fn drop(&mut self) {
        // Without `stop`: the thread writes what is queued and closes the file by itself.
        self.stop.store(true, Ordering::Release);
    }
}

/// The writer thread: records into files, a chunk on disk at least every second.
fn write_loop(
    mut writer: AcousticWriter,
    queue: &TapQueue,
    stop: &AtomicBool,
    counters: &Counters,
) -> Result<(), RecordError> {
    let take = |writer: &mut AcousticWriter, record: &TapRecord| {
        counters.received.fetch_add(1, Ordering::Relaxed);
        writer.write(record)
    };
    let result = (|| {
        loop {
            let wait = writer.next_tick(Instant::now()).min(STOP_POLL);
            match queue.recv_timeout(wait) {
                Ok(record) => {
                    take(&mut writer, &record)?;
                    // What else is queued, in one go, before looking at the clock again.
                    for _ in 0..ACOUSTIC_QUEUE_MAX {
                        let Ok(record) = queue.try_recv() else { break };
                        take(&mut writer, &record)?;
                    }
                }
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => break,
            }
            writer.tick(Instant::now())?;
            publish(&writer, queue, counters);
            if stop.load(Ordering::Acquire) {
                // What was queued before the stop, and no more than a queue's worth: a
                // CDT still reporting must not keep the recorder from closing.
                for _ in 0..ACOUSTIC_QUEUE_MAX {
                    let Ok(record) = queue.try_recv() else { break };
                    take(&mut writer, &record)?;
                }
                break;
            }
        }
        writer.close()?;
        publish(&writer, queue, counters);
        Ok(())
    })();
    if let Err(e) = &result {
        error!(error = %e, "acoustic recording stopped");
        counters.failed.store(true, Ordering::Release);
    }
    result
}

fn publish(writer: &AcousticWriter, queue: &TapQueue, counters: &Counters) {
    let s = writer.stats();
    counters.messages.store(s.messages, Ordering::Relaxed);
    counters.bytes.store(s.bytes, Ordering::Relaxed);
    counters.files.store(s.files, Ordering::Relaxed);
    counters
        .files_deleted
        .store(s.files_deleted, Ordering::Relaxed);
    counters.dropped.store(queue.dropped(), Ordering::Relaxed);
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
mod tests {
    use std::collections::BTreeMap;
    use std::path::Path;

    use serde_json::Value;
    use shoal_converter::tap::MessageFate;

    use super::*;
    use crate::config::Compression;
    use crate::{McapMessages, RecordWriter, Topic};

    const T0_NS: u64 = 1_780_000_000_000_000_000;

    fn config(dir: &Path) -> RecorderConfig {
        RecorderConfig {
            directory: dir.to_path_buf(),
            ..RecorderConfig::default()
        }
    }

    fn record(i: u64, event: TapEvent) -> TapRecord {
        TapRecord {
            time_ns: T0_NS + i * 1_000_000,
            converter_ms: 1_780_000_000_000 + i64::try_from(i).unwrap(),
            local: 1,
            event,
        }
    }

    /// A frame of two real PDUs (a keyframe and an event), as a vehicle packs them.
    fn frame() -> Vec<u8> {
        let samples = pdu::samples();
        let pick = |name: &str| {
            samples
                .iter()
                .find(|(n, _)| n.starts_with(name))
                .map(|(_, p)| p.clone())
                .unwrap_or_else(|| panic!("no sample PDU {name}"))
        };
        pdu::pack_frame(&[pick("state_keyframe"), pick("event")]).unwrap()
    }

    /// One record of each kind, and a frame that does not decode.
    fn one_of_each() -> Vec<TapRecord> {
        let ack = pdu::encode(&Pdu::Ack(pdu::Ack {
            from: 1,
            msg_id: pdu::id::STATE_KEYFRAME,
            ref_no: 3,
        }))
        .unwrap();
        vec![
            record(
                0,
                TapEvent::Received {
                    src: 2,
                    dst: 1,
                    bytes: frame(),
                    rssi: Some(-62),
                    integrity: Some(180),
                },
            ),
            record(
                1,
                TapEvent::Sent {
                    dst: 2,
                    class: Class::Telemetry,
                    message_id: 7,
                    bytes: ack,
                },
            ),
            record(
                2,
                TapEvent::Fate {
                    message_id: 7,
                    fate: MessageFate::Sent,
                },
            ),
            record(
                3,
                TapEvent::Received {
                    src: 3,
                    dst: 1,
                    bytes: vec![0xff, 0x00, 0x13],
                    rssi: None,
                    integrity: None,
                },
            ),
            record(
                4,
                TapEvent::Fate {
                    message_id: 8,
                    fate: MessageFate::Expired,
                },
            ),
        ]
    }

    /// (topic, log_time, JSON) of every message of a complete file, read through its
    /// summary by the `mcap` crate, with the schemas by topic.
    #[allow(clippy::type_complexity)]
    fn read(
        path: &Path,
    ) -> (
        Vec<(String, u64, Value)>,
        BTreeMap<String, (String, String, Value)>,
    ) {
        let bytes = std::fs::read(path).unwrap();
        let summary = mcap::Summary::read(&bytes).unwrap().expect("a summary");
        let mut schemas = BTreeMap::new();
        for channel in summary.channels.values() {
            let schema = channel.schema.as_ref().expect("a schema");
            assert_eq!(channel.message_encoding, "json");
            schemas.insert(
                channel.topic.clone(),
                (
                    schema.name.clone(),
                    schema.encoding.clone(),
                    serde_json::from_slice(&schema.data).unwrap(),
                ),
            );
        }
        let messages = mcap::MessageStream::new(&bytes)
            .unwrap()
            .map(|m| {
                let m = m.unwrap();
                assert_eq!(m.log_time, m.publish_time);
                (
                    m.channel.topic.clone(),
                    m.log_time,
                    serde_json::from_slice(&m.data).unwrap(),
                )
            })
            .collect();
        (messages, schemas)
    }

    /// What the schemas promise, checked by hand: every required property present, no
    /// property the schema does not list, each of the JSON type it names.
    fn conforms(schema: &Value, message: &Value) {
        let props = schema["properties"].as_object().unwrap();
        let object = message.as_object().unwrap();
        for key in schema["required"].as_array().unwrap() {
            assert!(
                object.contains_key(key.as_str().unwrap()),
                "{key} in {message}"
            );
        }
        for (key, value) in object {
            let ty = props
                .get(key)
                .unwrap_or_else(|| panic!("{key} is not in the schema"))["type"]
                .as_str()
                .unwrap();
            let ok = match ty {
                "string" => value.is_string(),
                "integer" => value.is_i64() || value.is_u64(),
                "array" => value.is_array(),
                other => panic!("type {other}"),
            };
            assert!(ok, "{key} = {value} is not {ty}");
            if let Some(allowed) = props[key].get("enum") {
                assert!(
                    allowed.as_array().unwrap().contains(value),
                    "{key} = {value}"
                );
            }
        }
    }

    #[test]
    fn frames_and_link_events_round_trip_as_json_with_their_schemas() {
        let dir = tempfile::tempdir().unwrap();
        let mut w = AcousticWriter::new(&config(dir.path())).unwrap();
        let records = one_of_each();
        for r in &records {
            w.write(r).unwrap();
        }
        w.close().unwrap();
        assert_eq!(w.stats().messages, 5);
        let name = w.files()[0].file_name().unwrap().to_str().unwrap();
        assert!(name.starts_with("shoal-acoustic-2"), "{name}");
        let (messages, schemas) = read(&w.files()[0]);
        assert_eq!(
            schemas.keys().collect::<Vec<_>>(),
            ["acoustic/frame", "acoustic/link_event"]
        );
        let (frame_name, encoding, frame_schema) = &schemas["acoustic/frame"];
        assert_eq!(
            (frame_name.as_str(), encoding.as_str()),
            ("shoal.acoustic.Frame", "jsonschema")
        );
        let (event_name, _, event_schema) = &schemas["acoustic/link_event"];
        assert_eq!(event_name, "shoal.acoustic.LinkEvent");
        assert_eq!(messages.len(), 5);
        for ((topic, log_time, json), r) in messages.iter().zip(&records) {
            assert_eq!(*log_time, r.time_ns);
            assert_eq!(json["converter_ms"], r.converter_ms);
            assert_eq!(json["local"], 1);
            let schema = if topic == "acoustic/frame" {
                frame_schema
            } else {
                event_schema
            };
            conforms(schema, json);
        }
        // The vehicle's frame: its bytes, the modem's figures and both PDUs decoded.
        let rx = &messages[0].2;
        assert_eq!(rx["direction"], "received");
        assert_eq!((&rx["src"], &rx["dst"]), (&Value::from(2), &Value::from(1)));
        assert_eq!(rx["hex"], hex::encode(frame()));
        assert_eq!(rx["length"], frame().len());
        assert_eq!(
            (&rx["rssi_db"], &rx["integrity"]),
            (&Value::from(-62), &Value::from(180))
        );
        let types: Vec<&str> = rx["pdus"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| p["type"].as_str().unwrap())
            .collect();
        assert_eq!(types, ["state_keyframe", "event"]);
        assert!(rx.get("message_id").is_none() && rx.get("decode_error").is_none());
        // The CDT's ack: sent by it, with the link's id and class.
        let tx = &messages[1].2;
        assert_eq!(tx["direction"], "sent");
        assert_eq!((&tx["src"], &tx["dst"]), (&Value::from(1), &Value::from(2)));
        assert_eq!(
            (&tx["message_id"], &tx["class"]),
            (&Value::from(7), &Value::from("telemetry"))
        );
        assert_eq!(tx["pdus"][0]["type"], "ack");
        // Its fate names the same id.
        assert_eq!(messages[2].0, "acoustic/link_event");
        assert_eq!(
            (&messages[2].2["event"], &messages[2].2["message_id"]),
            (&Value::from("sent"), &Value::from(7))
        );
        // Junk is recorded as it came, with why it does not decode.
        let junk = &messages[3].2;
        assert_eq!(junk["hex"], "ff0013");
        assert!(junk.get("pdus").is_none());
        assert!(
            junk["decode_error"].as_str().is_some_and(|e| !e.is_empty()),
            "{junk}"
        );
        assert_eq!(messages[4].2["event"], "expired");
    }

    #[test]
    fn the_dds_reader_and_replay_skip_the_acoustic_channels_and_name_them() {
        let dir = tempfile::tempdir().unwrap();
        let mut w = AcousticWriter::new(&config(dir.path())).unwrap();
        for r in &one_of_each() {
            w.write(r).unwrap();
        }
        w.close().unwrap();
        let mut reader = McapMessages::new(std::fs::File::open(&w.files()[0]).unwrap());
        assert_eq!(reader.by_ref().count(), 0);
        assert_eq!(reader.stats().unknown_messages, 5);
        assert_eq!(
            reader.unknown_topics(),
            ["acoustic/frame", "acoustic/link_event"]
        );
    }

    /// The acoustic files rotate by size like the DDS files, each one complete; and the
    /// two series in one directory keep their own totals: neither deletes the other's.
    #[test]
    fn acoustic_files_rotate_and_are_pruned_apart_from_the_dds_files() {
        let dir = tempfile::tempdir().unwrap();
        let cfg = RecorderConfig {
            max_file_bytes: 1024 * 1024,
            max_total_bytes: 3 * 1024 * 1024,
            compression: Compression::None,
            ..config(dir.path())
        };
        let mut dds = RecordWriter::new(&cfg).unwrap();
        let sample = crate::tests::one_of_each().remove(0);
        dds.write(Topic::StateVector, 1, 1, &sample.encode().unwrap())
            .unwrap();
        dds.close().unwrap();
        let dds_file = dds.files()[0].clone();

        let mut w = AcousticWriter::new(&cfg).unwrap();
        // About 600 bytes of JSON each: 20,000 make about 12 MB, four times the total.
        let n = 20_000u64;
        for i in 0..n {
            let r = record(
                i,
                TapEvent::Received {
                    src: 2,
                    dst: 1,
                    bytes: frame(),
                    rssi: Some(-70),
                    integrity: Some(100),
                },
            );
            w.write(&r).unwrap();
        }
        w.close().unwrap();
        let s = w.stats();
        assert!(s.files >= 8, "{s:?}");
        assert!(s.files_deleted >= 4, "{s:?}");
        assert!(
            dds_file.exists(),
            "the DDS file is not the acoustic series' to delete"
        );
        let kept: u64 = w
            .files()
            .iter()
            .map(|p| std::fs::metadata(p).unwrap().len())
            .sum();
        assert!(kept <= cfg.max_total_bytes, "{kept}");
        // The newest part is left, every file whole and in order, up to the last record.
        let mut last = 0;
        for f in w.files() {
            assert!(std::fs::metadata(f).unwrap().len() <= cfg.max_file_bytes + 64 * 1024);
            let (messages, _) = read(f);
            for (_, t, _) in messages {
                assert!(t > last);
                last = t;
            }
        }
        assert_eq!(last, T0_NS + (n - 1) * 1_000_000);
        // And the DDS series closing again leaves the acoustic files alone.
        let acoustic_before = w.files().to_vec();
        let mut dds = RecordWriter::new(&cfg).unwrap();
        dds.write(Topic::StateVector, 2, 2, &sample.encode().unwrap())
            .unwrap();
        dds.close().unwrap();
        assert_eq!(dds.stats().files_deleted, 0);
        assert!(acoustic_before.iter().all(|p| p.exists()));
    }

    #[test]
    fn a_records_chunk_is_on_disk_within_a_second_before_any_close() {
        let dir = tempfile::tempdir().unwrap();
        let mut w = AcousticWriter::new(&config(dir.path())).unwrap();
        w.write(&one_of_each()[0]).unwrap();
        std::thread::sleep(Duration::from_millis(1050));
        w.tick(Instant::now()).unwrap();
        // What a recorder killed now would leave: the chunk, then the missing summary.
        let open = std::fs::read(&w.files()[0]).unwrap();
        let mut reader = McapMessages::new(open.as_slice());
        let stopped = reader.by_ref().last();
        assert!(
            matches!(stopped, Some(Err(crate::ReadError::Truncated { .. }))),
            "{stopped:?}"
        );
        assert_eq!(reader.stats().unknown_messages, 1);
        w.close().unwrap();
    }

    #[test]
    fn acoustic_files_rotate_by_time() {
        let dir = tempfile::tempdir().unwrap();
        let cfg = RecorderConfig {
            max_file_seconds: 1,
            ..config(dir.path())
        };
        let mut w = AcousticWriter::new(&cfg).unwrap();
        let records = one_of_each();
        w.write(&records[0]).unwrap();
        // Past its second the file is closed on the tick, the next record opens another.
        std::thread::sleep(Duration::from_millis(1100));
        w.tick(Instant::now()).unwrap();
        assert_eq!(read(&w.files()[0]).0.len(), 1);
        w.write(&records[1]).unwrap();
        w.close().unwrap();
        assert_eq!(w.files().len(), 2);
        assert_eq!(read(&w.files()[1]).0.len(), 1);
    }

    /// The recorder's thread writes what the tap reports; a tap whose queue is full drops
    /// and counts, at once, and the recorder says how many.
    #[tokio::test]
    async fn the_recorder_writes_what_the_tap_reports_and_counts_what_a_full_queue_dropped() {
        let dir = tempfile::tempdir().unwrap();
        let (tap, queue) = FrameTap::bounded(3);
        let records = one_of_each();
        let started = Instant::now();
        // No reader yet: three fit, two are dropped, and reporting never waits.
        for r in &records {
            tap.report(r.clone());
        }
        assert!(started.elapsed() < Duration::from_millis(100));
        assert_eq!(tap.dropped(), 2);
        let recorder = AcousticRecorder::start_with(&config(dir.path()), queue).unwrap();
        // A tap still held does not keep the recorder from stopping.
        let stats = tokio::time::timeout(Duration::from_secs(5), recorder.stop())
            .await
            .unwrap()
            .unwrap();
        assert_eq!(stats.dropped, 2, "{stats:?}");
        assert_eq!((stats.received, stats.messages), (3, 3), "{stats:?}");
        assert_eq!(stats.files, 1);
        let file = crate::mcap_files(dir.path()).unwrap().remove(0);
        let (messages, _) = read(&file);
        assert_eq!(messages.len() as u64, stats.messages);
        assert_eq!(messages[0].1, records[0].time_ns);

        // Started the usual way, it ends as soon as every tap is gone.
        let dir = tempfile::tempdir().unwrap();
        let (recorder, tap) = AcousticRecorder::start(&config(dir.path())).unwrap();
        for r in &records {
            tap.report(r.clone());
        }
        drop(tap);
        let stats = recorder.stop().await.unwrap();
        assert_eq!((stats.received, stats.messages, stats.dropped), (5, 5, 0));
    }

    #[test]
    fn the_acoustic_prefix_follows_the_recorders() {
        let cfg = RecorderConfig {
            prefix: "ship-7".into(),
            ..RecorderConfig::default()
        };
        assert_eq!(acoustic_prefix(&cfg), "ship-7-acoustic");
        // Their schemas are JSON.
        for spec in CHANNELS {
            let schema: Value = serde_json::from_str(spec.schema).unwrap();
            assert_eq!(schema["title"], spec.schema_name);
        }
    }
}
