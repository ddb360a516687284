//! The Publish/Subscribe Manager: one DDS participant per process and typed endpoints.

use std::collections::HashMap;
use std::pin::Pin;
use std::sync::Mutex;
use std::task::{Context, Poll};

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use futures::Stream;
use rustdds::with_key::{DataReader, DataWriter, Sample};
use rustdds::{
    CDRDeserializerAdapter, CDRSerializerAdapter, DomainParticipant, DomainParticipantBuilder,
    DomainParticipantStatusEvent, DomainParticipantStatusListener, Publisher, ReadCondition,
    StatusEvented, Subscriber, Topic, TopicKind,
};
use tracing::{debug, info, warn};

use crate::config::DdsConfig;
use crate::error::{CreateError, ReadError, WriteError};
use crate::qos::{QosProfile, WriterOptions};
use crate::secure::{
    Refused, SIGNED_TYPE_NAME, Security, SecurityCounts, SignedWire, signed_topic,
};
use crate::topics::{TopicType, Wire};

fn dds_err(what: impl Into<String>, e: impl std::fmt::Display) -> CreateError {
    CreateError::Dds {
        what: what.into(),
        detail: e.to_string(),
    }
}

/// Owns the process's DDS participant, its publisher and subscriber, and the topics.
pub struct PubSub {
    /// Counted by the watchdog while the participant lives (see [`crate::failure`]).
    _registration: crate::watchdog::Registration,
    /// The reader threads, stopped before the participant goes (see `Drop`).
    readers: Mutex<Vec<ReaderThread>>,
    participant: DomainParticipant,
    publisher: Publisher,
    subscriber: Subscriber,
    topics: Mutex<HashMap<String, Topic>>,
    status: DomainParticipantStatusListener,
    config: DdsConfig,
    security: Option<Arc<Security>>,
}

impl std::fmt::Debug for PubSub {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PubSub")
            .field("domain_id", &self.config.domain_id)
            .field("interfaces", &self.config.interfaces)
            .finish_non_exhaustive()
    }
}

impl Drop for PubSub {
    /// Stops the reader threads and waits for them (half a second at most) before the
    /// participant goes: a RustDDS reader dropped after its participant's event loop has
    /// ended logs an error, which every station shutdown showed once per topic.
    fn drop(&mut self) {
        let readers = std::mem::take(
            self.readers
                .get_mut()
                .unwrap_or_else(std::sync::PoisonError::into_inner),
        );
        for r in &readers {
            r.stop.store(true, Ordering::Relaxed);
            // A failed wake leaves the thread to its poll timeout.
            let _ = r.waker.wake();
        }
        let deadline = std::time::Instant::now() + std::time::Duration::from_millis(500);
        for r in readers {
            // Disconnected once the thread has ended; a timeout leaves it behind (a thread
            // blocked on a consumer that no longer reads).
            let _ = r
                .exited
                .recv_timeout(deadline.saturating_duration_since(std::time::Instant::now()));
        }
    }
}

impl PubSub {
    /// Joins the configured DDS domain on the configured interfaces.
    pub fn new(config: &DdsConfig) -> Result<Self, CreateError> {
        if config.domain_id > 232 {
            // RTPS 9.6.1.1: port numbers overflow 65535 above domain 232.
            return Err(CreateError::Config(format!(
                "dds.domain_id = {} is above 232, the highest domain RTPS ports allow",
                config.domain_id
            )));
        }
        if config.interfaces.is_empty() {
            return Err(CreateError::Config(
                "dds.interfaces must list at least one address".into(),
            ));
        }
        if config.topic_cache_samples < 1 {
            return Err(CreateError::Config(
                "dds.topic_cache_samples must be at least 1".into(),
            ));
        }
        let participant = DomainParticipantBuilder::new(config.domain_id)
            .with_only_networks(config.interfaces.iter().copied())
            .same_host_loopback(config.same_host_loopback)
            .socket_receive_buffer_size(config.socket_receive_buffer)
            .build()
            .map_err(|e| dds_err("the domain participant", e))?;
        let default_qos = rustdds::QosPolicyBuilder::new().build();
        let publisher = participant
            .create_publisher(&default_qos)
            .map_err(|e| dds_err("the publisher", e))?;
        let subscriber = participant
            .create_subscriber(&default_qos)
            .map_err(|e| dds_err("the subscriber", e))?;
        let status = participant.status_listener();
        info!(
            domain = config.domain_id,
            interfaces = ?config.interfaces,
            guid = ?rustdds::RTPSEntity::guid(&participant),
            "DDS participant joined"
        );
        Ok(Self {
            _registration: crate::watchdog::Registration::new(),
            readers: Mutex::new(Vec::new()),
            participant,
            publisher,
            subscriber,
            topics: Mutex::new(HashMap::new()),
            status,
            config: config.clone(),
            security: None,
        })
    }

    /// Like [`PubSub::new`] with security on: Shoal's topics are written signed on their
    /// twins, and only samples `security`'s gate admits are delivered; unsigned samples
    /// are counted and dropped.
    pub fn new_secure(config: &DdsConfig, security: Security) -> Result<Self, CreateError> {
        let mut pubsub = Self::new(config)?;
        info!(identity = %security.identity(), "DDS security on: samples are signed and verified");
        pubsub.security = Some(Arc::new(security));
        Ok(pubsub)
    }

    /// The credentials, when security is on.
    pub fn security(&self) -> Option<&Security> {
        self.security.as_deref()
    }

    /// Refusals so far, when security is on.
    pub fn security_counts(&self) -> Option<SecurityCounts> {
        self.security.as_ref().map(|s| s.counts())
    }

    /// The configuration this participant was created with.
    pub fn config(&self) -> &DdsConfig {
        &self.config
    }

    /// This participant's GUID prefix, as text, for logs and link metadata.
    pub fn participant_id(&self) -> String {
        format!("{:?}", rustdds::RTPSEntity::guid(&self.participant).prefix)
    }

    fn topic<T: TopicType>(&self, name: &str) -> Result<Topic, CreateError> {
        self.topic_raw(name, T::TYPE_NAME, T::PROFILE, T::KEYED)
    }

    fn topic_raw(
        &self,
        name: &str,
        type_name: &str,
        profile: QosProfile,
        keyed: bool,
    ) -> Result<Topic, CreateError> {
        let mut topics = self
            .topics
            .lock()
            .map_err(|_| CreateError::Config("topic table lock poisoned".into()))?;
        if let Some(t) = topics.get(name) {
            return Ok(t.clone());
        }
        let t = self
            .participant
            .create_topic(
                name.to_string(),
                type_name.to_string(),
                &profile.topic_qos(self.config.topic_cache_samples),
                if keyed {
                    TopicKind::WithKey
                } else {
                    TopicKind::NoKey
                },
            )
            .map_err(|e| dds_err(format!("topic {name}"), e))?;
        topics.insert(name.to_string(), t.clone());
        Ok(t)
    }

    /// A writer for `T` in the given priority class. Each call creates a distinct DDS
    /// writer, so traffic of one class never waits behind another class's history.
    pub fn writer<T: TopicType>(&self, options: WriterOptions) -> Result<Writer<T>, CreateError> {
        self.writer_on(T::TOPIC, options)
    }

    /// A reader for `T` as an async stream of validated samples.
    pub fn subscribe<T: TopicType>(&self) -> Result<Subscription<T>, CreateError> {
        self.subscribe_on(T::TOPIC)
    }

    /// Like [`PubSub::writer`] on another topic name with `T`'s type and QoS (benchmarks,
    /// private channels).
    pub fn writer_on<T: TopicType>(
        &self,
        topic_name: &str,
        options: WriterOptions,
    ) -> Result<Writer<T>, CreateError> {
        let qos = T::PROFILE.writer_qos(&options);
        let err = |e| dds_err(format!("a writer on {}", T::TOPIC), e);
        let inner = if let Some(security) = self.security.as_ref().filter(|_| T::SIGNED) {
            let name = signed_topic(topic_name);
            let topic = self.topic_raw(&name, SIGNED_TYPE_NAME, T::PROFILE, true)?;
            WriterInner::Signed(
                self.publisher
                    .create_datawriter_cdr::<SignedWire>(&topic, Some(qos))
                    .map_err(err)?,
                Arc::clone(security),
            )
        } else if T::KEYED {
            let topic = self.topic::<T>(topic_name)?;
            WriterInner::Keyed(
                self.publisher
                    .create_datawriter_cdr::<Wire<T>>(&topic, Some(qos))
                    .map_err(err)?,
            )
        } else {
            let topic = self.topic::<T>(topic_name)?;
            WriterInner::Unkeyed(
                self.publisher
                    .create_datawriter_no_key_cdr::<Wire<T>>(&topic, Some(qos))
                    .map_err(err)?,
            )
        };
        debug!(
            topic = T::TOPIC,
            priority = options.priority.as_str(),
            "writer created"
        );
        Ok(Writer {
            inner,
            options,
            matched: Mutex::new(0),
        })
    }

    /// Like [`PubSub::subscribe`] on another topic name with `T`'s type and QoS.
    ///
    /// With security on, a signed topic is read from its signed twin through the gate; the
    /// plain topic is still read, to count and drop what arrives there unsigned.
    pub fn subscribe_on<T: TopicType>(
        &self,
        topic_name: &str,
    ) -> Result<Subscription<T>, CreateError> {
        let qos = T::PROFILE.reader_qos(self.config.topic_cache_samples);
        let err = |e| dds_err(format!("a reader on {topic_name}"), e);
        let (tx, rx) = tokio::sync::mpsc::channel(CHANNEL);
        let stop = Arc::new(AtomicBool::new(false));
        let topic = self.topic::<T>(topic_name)?;
        let security = self.security.as_ref().filter(|_| T::SIGNED);
        if let Some(security) = security {
            let name = signed_topic(topic_name);
            let signed = self.topic_raw(&name, SIGNED_TYPE_NAME, T::PROFILE, true)?;
            let reader = self
                .subscriber
                .create_datareader_cdr::<SignedWire>(&signed, Some(qos.clone()))
                .map_err(err)?;
            let sec = Arc::clone(security);
            self.keep(spawn_reader(
                &name,
                reader,
                tx.clone(),
                Arc::clone(&stop),
                move |w, info| open_signed::<T>(&sec, &w, info),
            )?);
        }
        let unsigned = security.cloned();
        let plain = move |Wire(value): Wire<T>, info: &rustdds::SampleInfo| match &unsigned {
            Some(sec) => {
                sec.count_unsigned(T::TOPIC);
                Err(ReadError::Unsigned { topic: T::TOPIC })
            }
            None => validated(value, info),
        };
        let thread = if T::KEYED {
            let reader = self
                .subscriber
                .create_datareader_cdr::<Wire<T>>(&topic, Some(qos))
                .map_err(err)?;
            spawn_reader(topic_name, reader, tx, Arc::clone(&stop), plain)?
        } else {
            let reader = self
                .subscriber
                .create_datareader_no_key_cdr::<Wire<T>>(&topic, Some(qos))
                .map_err(err)?;
            spawn_reader(topic_name, reader, tx, Arc::clone(&stop), plain)?
        };
        self.keep(thread);
        Ok(Subscription { rx, stop })
    }

    /// Remembers a reader thread, forgetting those that have ended.
    fn keep(&self, thread: ReaderThread) {
        let mut readers = self
            .readers
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        readers.retain(ReaderThread::running);
        readers.push(thread);
    }

    /// Discovery events that happened since the last call (never blocks).
    pub fn participant_events(&self) -> Vec<ParticipantEvent> {
        let mut out = Vec::new();
        while let Some(e) = self.status.try_recv_status() {
            if let Some(ev) = ParticipantEvent::from_dds(e) {
                out.push(ev);
            }
        }
        out
    }
}

/// What discovery saw, reduced to what the station needs.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum ParticipantEvent {
    /// A remote participant appeared.
    Discovered {
        /// Its GUID prefix.
        participant: String,
        /// Its entity name, when it advertised one.
        name: Option<String>,
    },
    /// A remote participant left or its lease expired.
    Lost {
        /// Its GUID prefix.
        participant: String,
        /// Why, as the library reports it.
        reason: String,
    },
    /// A remote writer's QoS cannot serve one of our readers: it will never deliver.
    IncompatibleWriter {
        /// The remote writer's GUID.
        writer: String,
        /// The requested and offered QoS, for the operator.
        detail: String,
    },
    /// A remote reader's QoS cannot be served by one of our writers.
    IncompatibleReader {
        /// The remote reader's GUID.
        reader: String,
        /// The requested and offered QoS, for the operator.
        detail: String,
    },
}

impl ParticipantEvent {
    fn from_dds(e: DomainParticipantStatusEvent) -> Option<Self> {
        match e {
            DomainParticipantStatusEvent::ParticipantDiscovered { dpd } => Some(Self::Discovered {
                participant: format!("{:?}", dpd.guid.prefix),
                name: dpd.entity_name,
            }),
            DomainParticipantStatusEvent::ParticipantLost { id, reason } => Some(Self::Lost {
                participant: format!("{id:?}"),
                reason: format!("{reason:?}"),
            }),
            DomainParticipantStatusEvent::RemoteWriterQosIncompatible {
                remote_writer,
                requested_qos,
                offered_qos,
                ..
            } => Some(Self::IncompatibleWriter {
                writer: format!("{remote_writer:?}"),
                detail: format!("requested {requested_qos:?}, offered {offered_qos:?}"),
            }),
            DomainParticipantStatusEvent::RemoteReaderQosIncompatible {
                remote_reader,
                requested_qos,
                offered_qos,
                ..
            } => Some(Self::IncompatibleReader {
                reader: format!("{remote_reader:?}"),
                detail: format!("requested {requested_qos:?}, offered {offered_qos:?}"),
            }),
            _ => None,
        }
    }
}

/// A DDS writer of a keyed, an unkeyed or a signed topic.
enum WriterInner<T: TopicType> {
    Keyed(DataWriter<Wire<T>, CDRSerializerAdapter<Wire<T>>>),
    Unkeyed(rustdds::no_key::DataWriter<Wire<T>, CDRSerializerAdapter<Wire<T>>>),
    Signed(
        DataWriter<SignedWire, CDRSerializerAdapter<SignedWire>>,
        Arc<Security>,
    ),
}

/// A DDS write failure in words (the sample itself is handed back by the caller).
fn describe<D>(e: rustdds::dds::result::WriteError<D>) -> String {
    use rustdds::dds::result::WriteError as E;
    match e {
        E::Serialization { reason, .. } | E::Poisoned { reason, .. } => reason,
        E::WouldBlock { .. } => "reliable history full: readers are not acknowledging".into(),
        E::Io(e) => e.to_string(),
        E::Internal { reason } => reason,
    }
}

impl<T: TopicType> WriterInner<T> {
    async fn async_write(&self, sample: T) -> Result<(), String> {
        match self {
            Self::Keyed(w) => w.async_write(Wire(sample), None).await.map_err(describe),
            Self::Unkeyed(w) => w.async_write(Wire(sample), None).await.map_err(describe),
            Self::Signed(w, security) => {
                let wire = security.seal(&sample)?;
                w.async_write(wire, None).await.map_err(describe)
            }
        }
    }

    fn write(&self, sample: T) -> Result<(), String> {
        match self {
            Self::Keyed(w) => w.write(Wire(sample), None).map_err(describe),
            Self::Unkeyed(w) => w.write(Wire(sample), None).map_err(describe),
            Self::Signed(w, security) => {
                let wire = security.seal(&sample)?;
                w.write(wire, None).map_err(describe)
            }
        }
    }

    fn try_recv_status(&self) -> Option<rustdds::DataWriterStatus> {
        match self {
            Self::Keyed(w) => w.try_recv_status(),
            Self::Unkeyed(w) => w.try_recv_status(),
            Self::Signed(w, _) => w.try_recv_status(),
        }
    }
}

/// A typed DDS writer in one priority class.
pub struct Writer<T: TopicType> {
    inner: WriterInner<T>,
    options: WriterOptions,
    matched: Mutex<i32>,
}

impl<T: TopicType> std::fmt::Debug for Writer<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Writer")
            .field("topic", &T::TOPIC)
            .field("options", &self.options)
            .finish()
    }
}

impl<T: TopicType> Writer<T> {
    fn check(sample: T) -> Result<T, WriteError<T>> {
        match sample.validate() {
            Ok(()) => Ok(sample),
            Err(error) => Err(WriteError::Invalid { error, sample }),
        }
    }

    /// Validates and publishes one sample; on failure the sample comes back in the error.
    pub async fn write(&self, sample: T) -> Result<(), WriteError<T>> {
        let sample = Self::check(sample)?;
        self.write_unchecked(sample).await
    }

    /// Publishes a sample WITHOUT validating it: for fault-injection tests and tools that
    /// must reproduce what a faulty foreign writer sends. Never use it for real data.
    pub async fn write_unchecked(&self, sample: T) -> Result<(), WriteError<T>> {
        let backup = sample.clone();
        self.inner
            .async_write(sample)
            .await
            .map_err(|detail| WriteError::Dds {
                detail,
                sample: backup,
            })
    }

    /// Like [`Writer::write`] but synchronous (blocks at most the writer's `max_blocking`).
    pub fn write_blocking(&self, sample: T) -> Result<(), WriteError<T>> {
        let sample = Self::check(sample)?;
        let backup = sample.clone();
        self.inner.write(sample).map_err(|detail| WriteError::Dds {
            detail,
            sample: backup,
        })
    }

    /// How many remote readers are matched now, from the writer's status events (RustDDS's
    /// `get_matched_subscriptions` is a placeholder that panics, so it is never called).
    pub fn matched_readers(&self) -> i32 {
        let Ok(mut matched) = self.matched.lock() else {
            return 0;
        };
        while let Some(status) = self.inner.try_recv_status() {
            if let rustdds::DataWriterStatus::PublicationMatched { current, .. } = status {
                *matched = current.count();
            }
        }
        *matched
    }

    /// The options this writer was created with.
    pub fn options(&self) -> &WriterOptions {
        &self.options
    }
}

/// Metadata that comes with a received sample.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SampleMeta {
    /// GUID of the writer that sent it.
    pub writer: String,
    /// GUID prefix of the writer's participant, comparable with [`PubSub::participant_id`]
    /// (e.g. to recognise one's own samples coming back).
    pub participant: String,
    /// The writer's source timestamp, ms since the Unix epoch, when it sent one.
    pub source_timestamp_ms: Option<i64>,
}

/// A typed, validated stream of samples from one topic.
///
/// A dedicated thread per subscription waits on the DDS reader (mio readiness) and takes
/// samples in batches: RustDDS's own async stream takes one sample per call and scans the
/// reader's whole cache each time, which turns a backlog into quadratic work. Samples cross
/// to async code through a bounded channel, so a slow consumer slows the reader instead of
/// growing memory.
pub struct Subscription<T: TopicType> {
    rx: tokio::sync::mpsc::Receiver<Result<(T, SampleMeta), ReadError>>,
    stop: Arc<AtomicBool>,
}

impl<T: TopicType> std::fmt::Debug for Subscription<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Subscription")
            .field("topic", &T::TOPIC)
            .finish_non_exhaustive()
    }
}

impl<T: TopicType> Drop for Subscription<T> {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

impl<T: TopicType> Stream for Subscription<T> {
    /// A valid sample with its metadata, or why a received sample was unusable. The stream
    /// goes on after an error: one bad sample never blocks the ones behind it.
    type Item = Result<(T, SampleMeta), ReadError>;

    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Self::Item>> {
        self.rx.poll_recv(cx)
    }
}

/// Samples a reader thread takes per call.
const BATCH: usize = 1024;
/// Samples buffered between the reader thread and the async consumer.
const CHANNEL: usize = 4096;

type Tx<T> = tokio::sync::mpsc::Sender<Result<(T, SampleMeta), ReadError>>;

/// A DDS reader reduced to what the reader thread needs: readiness and "take a batch".
trait TakeBatch<D>: rustdds::mio1::event::Source + Send + 'static {
    /// Up to [`BATCH`] unread samples; `None` values are disposals.
    fn take_batch(
        &mut self,
    ) -> Result<Vec<(Option<D>, rustdds::SampleInfo)>, rustdds::dds::result::ReadError>;
}

impl<D> TakeBatch<D> for DataReader<D, CDRDeserializerAdapter<D>>
where
    D: rustdds::Keyed + serde::de::DeserializeOwned + Send + 'static,
    D::K: rustdds::Key + serde::de::DeserializeOwned + Send,
{
    fn take_batch(
        &mut self,
    ) -> Result<Vec<(Option<D>, rustdds::SampleInfo)>, rustdds::dds::result::ReadError> {
        Ok(self
            .take(BATCH, ReadCondition::not_read())?
            .into_iter()
            .map(|s| {
                let info = s.sample_info().clone();
                match s.into_value() {
                    Sample::Value(v) => (Some(v), info),
                    // Disposals carry no data for Shoal: instances end by being superseded.
                    Sample::Dispose(_) => (None, info),
                }
            })
            .collect())
    }
}

impl<D> TakeBatch<D> for rustdds::no_key::DataReader<D, CDRDeserializerAdapter<D>>
where
    D: serde::de::DeserializeOwned + Send + 'static,
{
    fn take_batch(
        &mut self,
    ) -> Result<Vec<(Option<D>, rustdds::SampleInfo)>, rustdds::dds::result::ReadError> {
        Ok(self
            .take(BATCH, ReadCondition::not_read())?
            .into_iter()
            .map(|s| {
                let info = s.sample_info().clone();
                (Some(s.into_value()), info)
            })
            .collect())
    }
}

/// A reader thread as its [`PubSub`] sees it.
struct ReaderThread {
    stop: Arc<AtomicBool>,
    /// Wakes the thread's poll, so a stop is seen at once.
    waker: Arc<rustdds::mio1::Waker>,
    /// Disconnected when the thread ends.
    exited: std::sync::mpsc::Receiver<()>,
}

impl ReaderThread {
    fn running(&self) -> bool {
        matches!(
            self.exited.try_recv(),
            Err(std::sync::mpsc::TryRecvError::Empty)
        )
    }
}

/// Token of the reader in its thread's poll; the waker has the other.
const READER: rustdds::mio1::Token = rustdds::mio1::Token(0);
const WAKER: rustdds::mio1::Token = rustdds::mio1::Token(1);

/// Starts a reader thread turning each sample of `reader` into a stream item with `convert`.
fn spawn_reader<T, D, R, F>(
    topic_name: &str,
    mut reader: R,
    tx: Tx<T>,
    stop: Arc<AtomicBool>,
    convert: F,
) -> Result<ReaderThread, CreateError>
where
    T: TopicType,
    R: TakeBatch<D>,
    F: FnMut(D, &rustdds::SampleInfo) -> Result<(T, SampleMeta), ReadError> + Send + 'static,
{
    use rustdds::mio1::{Interest, Poll as MioPoll, Waker};
    let name = format!("dds-reader {topic_name}");
    let topic: &'static str = T::TOPIC;
    // mio 1 readiness: RustDDS drains this event source inside `take`, so an edge is never
    // lost (its mio 0.6 channel is never drained by `take` and goes silent once full).
    let poll = MioPoll::new().map_err(|e| dds_err(&name, e))?;
    poll.registry()
        .register(&mut reader, READER, Interest::READABLE)
        .map_err(|e| dds_err(&name, e))?;
    let waker = Arc::new(Waker::new(poll.registry(), WAKER).map_err(|e| dds_err(&name, e))?);
    let (exit_tx, exited) = std::sync::mpsc::channel::<()>();
    let thread_stop = Arc::clone(&stop);
    std::thread::Builder::new()
        .name(name.chars().take(15).collect())
        .spawn(move || {
            let _exit = exit_tx;
            if let Err(e) = reader_loop(reader, poll, &tx, &thread_stop, convert) {
                warn!(topic, error = %e, "DDS reader thread stopped");
            }
        })
        .map_err(|e| dds_err(name, e))?;
    Ok(ReaderThread {
        stop,
        waker,
        exited,
    })
}

fn reader_loop<T, D, R, F>(
    mut reader: R,
    mut poll: rustdds::mio1::Poll,
    tx: &Tx<T>,
    stop: &AtomicBool,
    mut convert: F,
) -> std::io::Result<()>
where
    T: TopicType,
    R: TakeBatch<D>,
    F: FnMut(D, &rustdds::SampleInfo) -> Result<(T, SampleMeta), ReadError>,
{
    use rustdds::mio1::Events;
    let mut events = Events::with_capacity(4);
    loop {
        // Edge-triggered: drain everything before waiting again.
        loop {
            if stop.load(Ordering::Relaxed) || tx.is_closed() {
                return Ok(());
            }
            let item = match reader.take_batch() {
                Ok(batch) if batch.is_empty() => break,
                Ok(batch) => {
                    for (value, info) in batch {
                        if let Some(value) = value
                            && tx.blocking_send(convert(value, &info)).is_err()
                        {
                            return Ok(());
                        }
                    }
                    continue;
                }
                // The reader has moved past the bad sample; report it and go on.
                Err(rustdds::dds::result::ReadError::Deserialization { reason }) => {
                    warn!(topic = T::TOPIC, %reason, "malformed sample dropped");
                    Err(ReadError::Malformed {
                        topic: T::TOPIC,
                        detail: reason,
                    })
                }
                Err(rustdds::dds::result::ReadError::UnknownKey { .. }) => continue,
                Err(e) => {
                    std::thread::sleep(std::time::Duration::from_millis(100));
                    Err(ReadError::Dds {
                        topic: T::TOPIC,
                        detail: e.to_string(),
                    })
                }
            };
            if tx.blocking_send(item).is_err() {
                return Ok(());
            }
        }
        // The timeout bounds how long a dropped subscription keeps its thread. EINTR (the
        // process was stopped and resumed, or a signal landed here) is no reason to stop.
        match poll.poll(&mut events, Some(std::time::Duration::from_millis(200))) {
            Err(e) if e.kind() != std::io::ErrorKind::Interrupted => return Err(e),
            _ => {}
        }
    }
}

fn meta(info: &rustdds::SampleInfo) -> SampleMeta {
    SampleMeta {
        writer: format!("{:?}", info.writer_guid()),
        participant: format!("{:?}", info.writer_guid().prefix),
        source_timestamp_ms: info.source_timestamp().map(timestamp_ms),
    }
}

/// A signed sample through the gate: the model sample, or why it was refused.
fn open_signed<T: TopicType>(
    security: &Security,
    wire: &SignedWire,
    info: &rustdds::SampleInfo,
) -> Result<(T, SampleMeta), ReadError> {
    match security.open::<T>(wire) {
        Ok(sample) => Ok((sample, meta(info))),
        Err(Refused::Gate(reason, detail)) => {
            debug!(topic = T::TOPIC, reason, %detail, "signed sample refused");
            Err(ReadError::Refused {
                topic: T::TOPIC,
                reason,
                detail,
            })
        }
        Err(Refused::Invalid(error, payload)) => Err(ReadError::Invalid {
            topic: T::TOPIC,
            error,
            payload,
        }),
    }
}

fn validated<T: TopicType>(
    value: T,
    info: &rustdds::SampleInfo,
) -> Result<(T, SampleMeta), ReadError> {
    match value.validate() {
        Ok(()) => Ok((value, meta(info))),
        Err(error) => Err(ReadError::Invalid {
            topic: T::TOPIC,
            error,
            payload: serde_json::to_string(&value).unwrap_or_else(|e| format!("\"{e}\"")),
        }),
    }
}

/// RTPS time (9.3.2): 32-bit seconds since 1970 and a 32-bit binary fraction.
fn timestamp_ms(t: rustdds::Timestamp) -> i64 {
    let ticks = t.to_ticks();
    let seconds = i64::try_from(ticks >> 32).unwrap_or(0);
    let fraction_ms = i64::try_from(((ticks & 0xFFFF_FFFF) * 1000) >> 32).unwrap_or(0);
    seconds * 1000 + fraction_ms
}
