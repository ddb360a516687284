//! The recorder: every chosen Shoal topic of a DDS participant into MCAP files.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::time::Instant;

use futures::StreamExt;
use shoal_dds::{PubSub, TopicType};
use shoal_model::{
    EnvironmentObservation, Event, StateVector, TaskAssignment, TaskStatus, VehicleAnnouncement,
};
use tokio_util::sync::CancellationToken;
use tracing::{debug, error, warn};

use crate::config::RecorderConfig;
use crate::error::RecordError;
use crate::topic::Topic;
use crate::writer::RecordWriter;

/// What a recorder has done so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RecorderStats {
    /// Samples received from DDS (valid ones; the rest are in `refused`).
    pub received: u64,
    /// Messages written to files.
    pub messages: u64,
    /// Bytes on disk, all files together.
    pub bytes: u64,
    /// Files opened.
    pub files: u64,
    /// Samples dropped because the file writer was behind (its queue was full).
    pub dropped: u64,
    /// Samples the subscriptions refused (malformed, invalid, impersonating, revoked):
    /// not recorded, as no Shoal subscriber would have used them.
    pub refused: u64,
}

#[derive(Debug, Default)]
struct Counters {
    received: AtomicU64,
    messages: AtomicU64,
    bytes: AtomicU64,
    files: AtomicU64,
    dropped: AtomicU64,
    refused: AtomicU64,
    writer_done: AtomicBool,
}

/// One received sample on its way to the file writer.
struct Entry {
    topic: Topic,
    log_time_ns: u64,
    publish_time_ns: u64,
    data: Vec<u8>,
}

/// Records Shoal topics from a DDS participant until stopped.
///
/// One task per topic takes samples from its subscription and hands them, serialised, to
/// a writer thread through a bounded queue; a full queue drops (and counts) samples
/// instead of growing. The writer thread owns the [`RecordWriter`].
pub struct Recorder {
    counters: Arc<Counters>,
    stop: CancellationToken,
    tasks: Vec<tokio::task::JoinHandle<()>>,
    sender: Option<SyncSender<Entry>>,
    thread: Option<std::thread::JoinHandle<Result<(), RecordError>>>,
}

impl std::fmt::Debug for Recorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recorder")
            .field("stats", &self.stats())
            .finish_non_exhaustive()
    }
}

impl Recorder {
    /// Subscribes to `config`'s topics on `pubsub` and starts writing files. Must be
    /// called within a tokio runtime. On a secure domain `pubsub` needs credentials that
    /// may read every topic (the station's).
    pub fn start(pubsub: &PubSub, config: &RecorderConfig) -> Result<Self, RecordError> {
        let writer = RecordWriter::new(config)?;
        let topics = writer.topics().to_vec();
        let counters = Arc::new(Counters::default());
        let (sender, receiver) = std::sync::mpsc::sync_channel(config.queue_samples);
        let thread_counters = Arc::clone(&counters);
        let thread = std::thread::Builder::new()
            .name("shoal-recorder".into())
            .spawn(move || write_loop(writer, &receiver, &thread_counters))
            .map_err(|e| RecordError::Thread(e.to_string()))?;
        let mut recorder = Self {
            counters,
            stop: CancellationToken::new(),
            tasks: Vec::new(),
            sender: Some(sender),
            thread: Some(thread),
        };
        for topic in topics {
            let task = match topic {
                Topic::StateVector => recorder.spawn::<StateVector>(pubsub, topic),
                Topic::VehicleAnnouncement => recorder.spawn::<VehicleAnnouncement>(pubsub, topic),
                Topic::TaskAssignment => recorder.spawn::<TaskAssignment>(pubsub, topic),
                Topic::TaskStatus => recorder.spawn::<TaskStatus>(pubsub, topic),
                Topic::Event => recorder.spawn::<Event>(pubsub, topic),
                Topic::Environment => recorder.spawn::<EnvironmentObservation>(pubsub, topic),
            }?;
            recorder.tasks.push(task);
        }
        Ok(recorder)
    }

    fn spawn<T: TopicType>(
        &self,
        pubsub: &PubSub,
        topic: Topic,
    ) -> Result<tokio::task::JoinHandle<()>, RecordError> {
        let mut subscription = pubsub.subscribe::<T>()?;
        let counters = Arc::clone(&self.counters);
        let stop = self.stop.clone();
        let Some(sender) = self.sender.clone() else {
            return Err(RecordError::Thread("the recorder is stopped".into()));
        };
        Ok(tokio::spawn(async move {
            loop {
                let item = tokio::select! {
                    () = stop.cancelled() => break,
                    item = subscription.next() => item,
                };
                let (sample, meta) = match item {
                    Some(Ok(s)) => s,
                    Some(Err(e)) => {
                        counters.refused.fetch_add(1, Ordering::Relaxed);
                        debug!(topic = topic.name(), error = %e, "sample not recorded");
                        continue;
                    }
                    None => break,
                };
                counters.received.fetch_add(1, Ordering::Relaxed);
                let log_time_ns = now_ns();
                let publish_time_ns = meta
                    .source_timestamp_ms
                    .and_then(|ms| u64::try_from(ms).ok())
                    .map_or(log_time_ns, |ms| ms.saturating_mul(1_000_000));
                let data = match shoal_dds::to_cdr_le(&*sample) {
                    Ok(d) => d,
                    Err(e) => {
                        warn!(topic = topic.name(), error = %e, "sample cannot be encoded");
                        counters.refused.fetch_add(1, Ordering::Relaxed);
                        continue;
                    }
                };
                let entry = Entry {
                    topic,
                    log_time_ns,
                    publish_time_ns,
                    data,
                };
                match sender.try_send(entry) {
                    Ok(()) => {}
                    Err(TrySendError::Full(_)) => {
                        counters.dropped.fetch_add(1, Ordering::Relaxed);
                    }
                    // The writer thread ended (its error is in `stop`'s result).
                    Err(TrySendError::Disconnected(_)) => break,
                }
            }
        }))
    }

    /// Counters so far.
    pub fn stats(&self) -> RecorderStats {
        let c = &self.counters;
        RecorderStats {
            received: c.received.load(Ordering::Relaxed),
            messages: c.messages.load(Ordering::Relaxed),
            bytes: c.bytes.load(Ordering::Relaxed),
            files: c.files.load(Ordering::Relaxed),
            dropped: c.dropped.load(Ordering::Relaxed),
            refused: c.refused.load(Ordering::Relaxed),
        }
    }

    /// True once the file writer has stopped on its own (an error, which
    /// [`Recorder::stop`] returns).
    pub fn failed(&self) -> bool {
        self.counters.writer_done.load(Ordering::Acquire)
    }

    /// Stops the subscriptions, writes what is queued and closes the file properly.
    pub async fn stop(mut self) -> Result<RecorderStats, RecordError> {
        self.stop.cancel();
        for task in self.tasks.drain(..) {
            if let Err(e) = task.await {
                warn!(error = %e, "a recorder task ended abnormally");
            }
        }
        // The tasks' senders are gone with them; this one goes now, so the writer drains
        // the queue and sees the channel closed.
        self.sender = None;
        let thread = self.thread.take();
        join_writer(thread).await?;
        Ok(self.stats())
    }
}

/// Waits, off the runtime, for a writer thread to finish, and returns what it returned.
pub(crate) async fn join_writer(
    thread: Option<std::thread::JoinHandle<Result<(), RecordError>>>,
) -> Result<(), RecordError> {
    let joined = tokio::task::spawn_blocking(move || thread.map(std::thread::JoinHandle::join))
        .await
        .map_err(|e| RecordError::Thread(e.to_string()))?;
    match joined {
        Some(Ok(result)) => result,
        Some(Err(_)) => Err(RecordError::Thread("it panicked".into())),
        None => Ok(()),
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        // Without `stop`: the tasks end, the queue closes, the thread closes the file.
        self.stop.cancel();
        for task in &self.tasks {
            task.abort();
        }
    }
}

/// The writer thread: samples into files, a chunk on disk at least every second.
fn write_loop(
    mut writer: RecordWriter,
    receiver: &Receiver<Entry>,
    counters: &Counters,
) -> Result<(), RecordError> {
    let result = (|| {
        loop {
            match receiver.recv_timeout(writer.next_tick(Instant::now())) {
                Ok(entry) => {
                    write_entry(&mut writer, &entry)?;
                    // What else is queued, in one go, before looking at the clock again.
                    for entry in receiver.try_iter().take(4096) {
                        write_entry(&mut writer, &entry)?;
                    }
                }
                Err(RecvTimeoutError::Timeout) => {}
                Err(RecvTimeoutError::Disconnected) => break,
            }
            writer.tick(Instant::now())?;
            publish(&writer, counters);
        }
        writer.close()?;
        publish(&writer, counters);
        Ok(())
    })();
    if let Err(e) = &result {
        error!(error = %e, "recording stopped");
    }
    counters.writer_done.store(true, Ordering::Release);
    result
}

fn write_entry(writer: &mut RecordWriter, e: &Entry) -> Result<(), RecordError> {
    writer.write(e.topic, e.log_time_ns, e.publish_time_ns, &e.data)
}

fn publish(writer: &RecordWriter, counters: &Counters) {
    let s = writer.stats();
    counters.messages.store(s.messages, Ordering::Relaxed);
    counters.bytes.store(s.bytes, Ordering::Relaxed);
    counters.files.store(s.files, Ordering::Relaxed);
}

/// Now, ns since the Unix epoch.
pub(crate) fn now_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX))
}
