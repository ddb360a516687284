//! The Publish/Subscribe Manager: one DDS participant per process and typed endpoints.

use std::collections::{HashMap, VecDeque};
use std::marker::PhantomData;
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};

use futures::Stream;
use futures::task::AtomicWaker;
use shoal_model::Validated;
use tracing::{debug, info, warn};

use crate::config::DdsConfig;
use crate::cyclone::{self, Entity, QosReports, ReaderHandle, SerType, TopicRef};
use crate::error::{
    CdrError, CreateError, DdsError, EndError, ReadError, SendError, TypeError, WriteError,
};
use crate::omg::{Credentials, PublisherGuard, READ_PARTITIONS, partition_vehicle};
use crate::qos::WriterOptions;
use crate::shape::Shape;
use crate::topics::TopicType;

fn dds_err(what: impl Into<String>, source: DdsError) -> CreateError {
    CreateError::Dds {
        what: what.into(),
        source,
    }
}

/// The participant and its topics, shared by the [`PubSub`] and every endpoint made from
/// it: the participant (and the topic types samples are serialised with) stays until the
/// last of them is gone. Fields drop in order: topics, then the participant, then what
/// its listener points at.
struct Participant {
    topics: Mutex<HashMap<String, Topic>>,
    builtin: Entity,
    entity: Entity,
    guid: cyclone::Guid,
    _reports: Arc<QosReports>,
}

/// A topic and the type its samples are serialised with.
struct Topic {
    entity: Entity,
    sertype: SerType,
    type_name: String,
}

impl Participant {
    /// The topic `name` of type `type_name` with `shape`'s layout, created on first use.
    fn topic(
        &self,
        name: &str,
        type_name: &str,
        shape: impl FnOnce() -> Result<Shape, TypeError>,
    ) -> Result<(TopicRef, SerType), CreateError> {
        let mut topics = self
            .topics
            .lock()
            .map_err(|_| CreateError::Config("topic table lock poisoned".into()))?;
        if let Some(t) = topics.get(name) {
            if t.type_name != type_name {
                return Err(CreateError::TopicTypeMismatch {
                    topic: name.to_string(),
                    existing: t.type_name.clone(),
                    requested: type_name.to_string(),
                });
            }
            return Ok((t.entity.topic_ref(), t.sertype));
        }
        let shape = shape().map_err(|source| CreateError::Type {
            topic: name.to_string(),
            source,
        })?;
        let qos = cyclone::Qos::new();
        let entity = cyclone::topic(&self.entity, name, &shape, &qos)?;
        let sertype = cyclone::sertype(&entity).map_err(|e| dds_err(format!("topic {name}"), e))?;
        let shared = entity.topic_ref();
        topics.insert(
            name.to_string(),
            Topic {
                entity,
                sertype,
                type_name: type_name.to_string(),
            },
        );
        Ok((shared, sertype))
    }
}

/// Owns the process's DDS participant and creates typed endpoints on it.
pub struct PubSub {
    participant: Arc<Participant>,
    config: DdsConfig,
    /// OMG DDS Security credentials, when the participant was created with them.
    credentials: Option<Credentials>,
    /// The partition every writer publishes in (a vehicle's own), if any.
    writer_partition: Option<String>,
    guard: Arc<PublisherGuard>,
}

impl std::fmt::Debug for PubSub {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PubSub")
            .field("domain_id", &self.config.domain_id)
            .field("interfaces", &self.config.interfaces)
            .finish_non_exhaustive()
    }
}

impl PubSub {
    /// Joins the configured DDS domain on the configured interfaces.
    pub fn new(config: &DdsConfig) -> Result<Self, CreateError> {
        Self::create(config, None)
    }

    /// Joins the domain with OMG DDS Security on: authenticated, access-controlled and
    /// encrypted as the enclave's governance and permissions say. Every file is checked
    /// first; a bad one is an error naming it, and no participant is created.
    pub fn with_credentials(
        config: &DdsConfig,
        credentials: Credentials,
    ) -> Result<Self, CreateError> {
        let now_s = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| i64::try_from(d.as_secs()).unwrap_or(i64::MAX));
        let info = credentials.enclave().check(now_s)?;
        let pubsub = Self::create(config, Some(credentials))?;
        info!(
            identity = %info.common_name,
            certificate_expires = %info.not_after,
            "DDS Security on (OMG DDS Security 1.1: authenticated, access-controlled, encrypted)"
        );
        Ok(pubsub)
    }

    fn create(config: &DdsConfig, credentials: Option<Credentials>) -> Result<Self, CreateError> {
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
        if config.same_host_loopback.is_some() {
            warn!("dds.same_host_loopback has no effect any more (it was a RustDDS setting)");
        }
        cyclone::domain(config).map_err(|e| dds_err("the domain", e))?;
        let name = format!("shoal {}", std::process::id());
        let properties = credentials
            .as_ref()
            .map(Credentials::properties)
            .unwrap_or_default();
        let entity = cyclone::participant(config.domain_id, &name, &properties)
            .map_err(|e| dds_err("the participant", e))?;
        let reports = Arc::new(QosReports::default());
        cyclone::listen_for_qos(&entity, &reports);
        let builtin = cyclone::participant_reader(&entity)
            .map_err(|e| dds_err("the participant discovery reader", e))?;
        let guid = cyclone::guid(&entity);
        info!(
            domain = config.domain_id,
            interfaces = ?config.interfaces,
            participant = %hex::encode(&guid[..12]),
            "DDS participant joined"
        );
        Ok(Self {
            participant: Arc::new(Participant {
                topics: Mutex::new(HashMap::new()),
                builtin,
                entity,
                guid,
                _reports: reports,
            }),
            config: config.clone(),
            writer_partition: credentials.as_ref().and_then(Credentials::writer_partition),
            credentials,
            guard: Arc::new(PublisherGuard::default()),
        })
    }

    /// The DDS Security credentials this participant was created with, if any.
    pub fn credentials(&self) -> Option<&Credentials> {
        self.credentials.as_ref()
    }

    /// Samples refused so far because they spoke for another vehicle than the one whose
    /// partition they were published in.
    pub fn impersonations_refused(&self) -> u64 {
        self.guard.impersonations()
    }

    /// Refuses from now on every sample published in these vehicles' partitions (their
    /// certificates were revoked while this participant runs; DDS Security reads the
    /// revocation list only when a participant starts). Replaces the previous set.
    pub fn set_revoked_vehicles(&self, vehicles: std::collections::HashSet<String>) {
        self.guard.set_revoked(vehicles);
    }

    /// Samples refused so far because their vehicle was revoked.
    pub fn revoked_refused(&self) -> u64 {
        self.guard.revoked()
    }

    /// The configuration this participant was created with.
    pub fn config(&self) -> &DdsConfig {
        &self.config
    }

    /// This participant's GUID prefix, as hex text, for logs and link metadata; the same
    /// text as [`SampleMeta::participant`] of its own samples.
    pub fn participant_id(&self) -> String {
        hex::encode(&self.participant.guid[..12])
    }

    fn model_topic<T: TopicType>(&self, name: &str) -> Result<(TopicRef, SerType), CreateError> {
        if T::KEYED && T::KEY_FIELDS.is_empty() {
            return Err(CreateError::Config(format!(
                "{} is keyed but names no key fields",
                T::TYPE_NAME
            )));
        }
        let keys = if T::KEYED { T::KEY_FIELDS } else { &[] };
        self.participant
            .topic(name, T::TYPE_NAME, || Shape::of::<T>(T::TYPE_NAME, keys))
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
        let mut qos = T::PROFILE.writer_qos(&options).to_qos();
        if let Some(p) = &self.writer_partition {
            qos.partitions(&[p])
                .map_err(|e| dds_err(format!("a writer on {topic_name}"), e))?;
        }
        let (topic, sertype) = self.model_topic::<T>(topic_name)?;
        let entity = cyclone::writer(&self.participant.entity, topic, &qos)
            .map_err(|e| dds_err(format!("a writer on {topic_name}"), e))?;
        debug!(
            topic = topic_name,
            priority = options.priority.as_str(),
            "writer created"
        );
        let limit = options.kept_instances.or(T::PROFILE.kept_instances());
        Ok(Writer {
            entity,
            sertype,
            options,
            kept: limit.map(|limit| Mutex::new(KeptInstances::new(limit))),
            _participant: Arc::clone(&self.participant),
            _type: PhantomData,
        })
    }

    /// Like [`PubSub::subscribe`] on another topic name with `T`'s type and QoS.
    ///
    pub fn subscribe_on<T: TopicType>(
        &self,
        topic_name: &str,
    ) -> Result<Subscription<T>, CreateError> {
        let signal = Arc::new(Signal::default());
        let readers = vec![Source {
            reader: self.reader::<T, _>(topic_name, Arc::clone(&signal))?,
            topic: topic_name.to_string(),
            samples: self.samples(),
        }];
        let watch: Arc<dyn cyclone::Wake> = signal.clone();
        cyclone::watch_malformed(Arc::downgrade(&watch));
        // Read before the counts: a report between the two is then looked at again.
        let malformed_total = cyclone::malformed_total();
        let malformed_seen = readers
            .iter()
            .map(|r| cyclone::malformed_count(&r.topic))
            .collect();
        Ok(Subscription {
            readers,
            malformed_seen,
            malformed_total,
            buffer: VecDeque::new(),
            signal,
            _participant: Arc::clone(&self.participant),
            _type: PhantomData,
        })
    }

    /// Hands each sample of `T`'s topic to `handler` as Cyclone delivers it: on its receive
    /// thread, or in the writing thread for a writer in this process. No task to wake, so
    /// the lowest latency the bus has (what ddsperf's default listener mode does).
    /// `handler` must be quick and must not block: the delivering thread waits for it. Checks and errors are those of [`PubSub::subscribe`]; a malformed
    /// sample's error comes with the next sample of the topic.
    pub fn listen<T, F>(&self, handler: F) -> Result<Listening<T>, CreateError>
    where
        T: TopicType,
        F: FnMut(Delivery<T>) + Send + 'static,
    {
        self.listen_on(T::TOPIC, handler)
    }

    /// Like [`PubSub::listen`] on another topic name with `T`'s type and QoS.
    pub fn listen_on<T, F>(&self, topic_name: &str, handler: F) -> Result<Listening<T>, CreateError>
    where
        T: TopicType,
        F: FnMut(Delivery<T>) + Send + 'static,
    {
        let deliver = Arc::new(Deliver {
            state: Mutex::new(DeliverState {
                samples: self.samples(),
                topic: topic_name.to_string(),
                malformed_total: cyclone::malformed_total(),
                malformed_seen: cyclone::malformed_count(topic_name),
                handler: Box::new(handler),
            }),
        });
        Ok(Listening {
            _reader: self.reader::<T, _>(topic_name, deliver)?,
            _participant: Arc::clone(&self.participant),
        })
    }

    /// A reader of `T`'s QoS on `topic_name` whose arriving data calls `wake`.
    fn reader<T: TopicType, W: cyclone::Wake>(
        &self,
        topic_name: &str,
        wake: Arc<W>,
    ) -> Result<ReaderHandle<W>, CreateError> {
        let mut qos = T::PROFILE
            .reader_qos(self.config.topic_cache_samples)
            .to_qos();
        qos.partitions(&READ_PARTITIONS)
            .map_err(|e| dds_err(format!("a reader on {topic_name}"), e))?;
        let (topic, _) = self.model_topic::<T>(topic_name)?;
        cyclone::reader(&self.participant.entity, topic, &qos, wake)
            .map_err(|e| dds_err(format!("a reader on {topic_name}"), e))
    }

    fn samples(&self) -> Samples {
        Samples {
            writers: HashMap::new(),
            guard: Arc::clone(&self.guard),
        }
    }

    /// Discovery events that happened since the last call (never blocks).
    pub fn participant_events(&self) -> Vec<ParticipantEvent> {
        let own = &self.participant.guid[..12];
        let mut out: Vec<ParticipantEvent> = cyclone::take_participants(&self.participant.builtin)
            .into_iter()
            .filter(|p| p.guid[..12] != *own)
            .map(|p| {
                let participant = hex::encode(&p.guid[..12]);
                if p.alive {
                    ParticipantEvent::Discovered {
                        participant,
                        name: p.name,
                    }
                } else {
                    ParticipantEvent::Lost {
                        participant,
                        reason: "left the domain or its lease expired".into(),
                    }
                }
            })
            .collect();
        if let Ok(mut reports) = self.participant._reports.events.lock() {
            for (guid, requested, policy) in reports.drain(..) {
                out.push(if requested {
                    ParticipantEvent::IncompatibleWriter {
                        writer: guid,
                        detail: format!("our reader requests more {policy} than a writer offers"),
                    }
                } else {
                    ParticipantEvent::IncompatibleReader {
                        reader: guid,
                        detail: format!("a reader requests more {policy} than our writer offers"),
                    }
                });
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
        /// Our reader's GUID (DDS names the local side of the failed match).
        writer: String,
        /// The policy that did not match, for the operator.
        detail: String,
    },
    /// A remote reader's QoS cannot be served by one of our writers.
    IncompatibleReader {
        /// Our writer's GUID (DDS names the local side of the failed match).
        reader: String,
        /// The policy that did not match, for the operator.
        detail: String,
    },
}

/// The instances a writer keeps, oldest first, by key (as key-only CDR).
#[derive(Debug)]
struct KeptInstances {
    limit: usize,
    order: VecDeque<Vec<u8>>,
    keys: std::collections::HashSet<Vec<u8>>,
}

impl KeptInstances {
    fn new(limit: usize) -> Self {
        Self {
            limit: limit.max(1),
            order: VecDeque::new(),
            keys: std::collections::HashSet::new(),
        }
    }

    /// Notes a written key; returns the keys to unregister, oldest first.
    fn written(&mut self, key: Vec<u8>) -> Vec<Vec<u8>> {
        if self.keys.insert(key.clone()) {
            self.order.push_back(key);
        }
        let mut out = Vec::new();
        while self.order.len() > self.limit {
            if let Some(old) = self.order.pop_front() {
                self.keys.remove(&old);
                out.push(old);
            }
        }
        out
    }

    /// Forgets a key the writer ended itself.
    fn ended(&mut self, key: &[u8]) {
        if self.keys.remove(key) {
            self.order.retain(|k| k != key);
        }
    }
}

/// A typed DDS writer in one priority class.
pub struct Writer<T: TopicType> {
    entity: Entity,
    sertype: SerType,
    options: WriterOptions,
    /// The instances kept for late joiners, when the writer bounds them.
    kept: Option<Mutex<KeptInstances>>,
    _participant: Arc<Participant>,
    _type: PhantomData<fn(T)>,
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

    fn send(&self, sample: &T) -> Result<(), SendError> {
        let mut cdr = crate::to_cdr_le(sample)?;
        cyclone::write_cdr(&self.entity, self.sertype, &mut cdr).map_err(|code| {
            if code == cyclone::TIMEOUT {
                SendError::HistoryFull
            } else {
                SendError::Dds(cyclone::error(code))
            }
        })
    }

    fn send_or_return(&self, sample: T) -> Result<(), WriteError<T>> {
        if let Err(e) = self.send(&sample) {
            return Err(e.with(sample));
        }
        self.bound_instances(&sample);
        Ok(())
    }

    /// Unregisters the oldest instances beyond the writer's limit, if it has one.
    fn bound_instances(&self, sample: &T) {
        let Some(kept) = &self.kept else { return };
        let Ok(key) = self.key_cdr(sample) else {
            return;
        };
        let old = kept
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .written(key);
        for mut key in old {
            if let Err(code) = cyclone::end_instance_cdr(
                &self.entity,
                self.sertype,
                &mut key,
                cyclone::Ending::Unregister,
            ) {
                warn!(topic = T::TOPIC, error = %cyclone::error(code), "old instance not unregistered");
            }
        }
    }

    /// The sample's key, serialised as the topic holds it.
    fn key_cdr(&self, sample: &T) -> Result<Vec<u8>, CdrError> {
        crate::to_cdr_le(&sample.key())
    }

    /// Validates and publishes one sample; on failure the sample comes back in the error.
    ///
    /// DDS sends at once from the calling thread; only a reliable writer whose history is
    /// full of unacknowledged samples waits, for the writer's `max_blocking` at most.
    pub async fn write(&self, sample: T) -> Result<(), WriteError<T>> {
        self.send_or_return(Self::check(sample)?)
    }

    /// Publishes a sample WITHOUT validating it: for fault-injection tests and tools that
    /// must reproduce what a faulty foreign writer sends. Never use it for real data.
    pub async fn write_unchecked(&self, sample: T) -> Result<(), WriteError<T>> {
        self.send_or_return(sample)
    }

    /// Like [`Writer::write`], for code that is not async.
    pub fn write_blocking(&self, sample: T) -> Result<(), WriteError<T>> {
        self.send_or_return(Self::check(sample)?)
    }

    /// Disposes the sample's instance and forgets it: matched readers learn it no longer
    /// exists, and late joiners no longer receive it from this writer's history. What
    /// keeps a transient-local topic's history bounded by live instances, not past ones.
    pub fn dispose(&self, sample: &T) -> Result<(), EndError> {
        self.end(sample, cyclone::Ending::Dispose)
    }

    /// Forgets the sample's instance without disposing it: its last value stays valid for
    /// readers that have it, and late joiners no longer receive it.
    pub fn unregister(&self, sample: &T) -> Result<(), EndError> {
        self.end(sample, cyclone::Ending::Unregister)
    }

    fn end(&self, sample: &T, ending: cyclone::Ending) -> Result<(), EndError> {
        let mut key = self.key_cdr(sample)?;
        if let Some(kept) = &self.kept {
            kept.lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
                .ended(&key);
        }
        cyclone::end_instance_cdr(&self.entity, self.sertype, &mut key, ending)
            .map_err(|code| EndError::Dds(cyclone::error(code)))
    }

    /// How many readers are matched now.
    pub fn matched_readers(&self) -> i32 {
        cyclone::matched_readers(&self.entity)
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
    /// The vehicle whose partition the writer publishes in (`shoal.vehicle.<id>`), if any:
    /// with DDS Security on, the authenticated vehicle that sent the sample.
    pub publisher_vehicle: Option<String>,
}

/// Wakes a subscription's task when its readers have data (or a malformed report).
#[derive(Debug, Default)]
struct Signal {
    waker: AtomicWaker,
    ready: AtomicBool,
}

impl cyclone::Wake for Signal {
    fn wake(&self) {
        self.ready.store(true, Ordering::Release);
        self.waker.wake();
    }
}

/// One DDS reader of a subscription.
struct Source {
    reader: ReaderHandle<Signal>,
    topic: String,
    samples: Samples,
}

/// How one reader's samples are turned into stream items.
struct Samples {
    /// Writer and participant GUIDs as text and the vehicle whose partition the writer
    /// publishes in, by the writer's instance handle in this reader: looked up once per
    /// writer rather than once per sample.
    writers: HashMap<u64, (String, String, Option<String>)>,
    guard: Arc<PublisherGuard>,
}

impl Samples {
    fn meta(&mut self, reader: &Entity, taken: &cyclone::Taken) -> SampleMeta {
        let (writer, participant, vehicle) =
            self.writers.entry(taken.publication).or_insert_with(|| {
                let (guid, partitions) =
                    cyclone::publication_info(reader, taken.publication).unwrap_or_default();
                let participant = hex::encode(&guid[..12]);
                (
                    format!("{participant}.{}", hex::encode(&guid[12..])),
                    participant,
                    partition_vehicle(&partitions),
                )
            });
        SampleMeta {
            writer: writer.clone(),
            participant: participant.clone(),
            publisher_vehicle: vehicle.clone(),
            source_timestamp_ms: (taken.source_timestamp_ns > 0)
                .then_some(taken.source_timestamp_ns / 1_000_000),
        }
    }

    fn item<T: TopicType>(
        &mut self,
        reader: &Entity,
        taken: &cyclone::Taken,
    ) -> Result<(Validated<T>, SampleMeta), ReadError> {
        let malformed = |e: CdrError| {
            let detail = e.to_string();
            warn!(topic = T::TOPIC, %detail, "malformed sample dropped");
            ReadError::Malformed {
                topic: T::TOPIC,
                detail,
            }
        };
        let value: T = crate::from_cdr(taken.cdr).map_err(malformed)?;
        let meta = self.meta(reader, taken);
        if let Some(publisher) = meta.publisher_vehicle.as_deref() {
            if self.guard.is_revoked(publisher) {
                self.guard.count_revoked();
                debug!(
                    topic = T::TOPIC,
                    publisher, "sample from a revoked vehicle refused"
                );
                return Err(ReadError::Revoked {
                    topic: T::TOPIC,
                    vehicle: publisher.to_string(),
                });
            }
            if let Some(claimed) = value.owner_vehicle()
                && publisher != claimed
            {
                self.guard.count_impersonation();
                warn!(
                    topic = T::TOPIC,
                    publisher, claimed, "sample about another vehicle refused"
                );
                return Err(ReadError::Impersonation {
                    topic: T::TOPIC,
                    publisher: publisher.to_string(),
                    claimed: claimed.to_string(),
                });
            }
        }
        validated(value, meta)
    }
}

/// A typed, validated stream of samples from one topic.
///
/// Each DDS reader has a data-available listener that wakes the stream's task, which then
/// takes the samples in batches itself. Samples wait in the reader's cache, bounded by its
/// history and resource limits, until the consumer asks for them, so a slow consumer
/// slows acknowledgements (and so the reliable writer) instead of growing memory.
pub struct Subscription<T: TopicType> {
    readers: Vec<Source>,
    /// Malformed-sample reports already turned into errors, per reader.
    malformed_seen: Vec<u64>,
    /// [`cyclone::malformed_total`] when `malformed_seen` was last brought up to date.
    malformed_total: u64,
    buffer: VecDeque<Result<(Validated<T>, SampleMeta), ReadError>>,
    signal: Arc<Signal>,
    _participant: Arc<Participant>,
    _type: PhantomData<fn() -> T>,
}

impl<T: TopicType> std::fmt::Debug for Subscription<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Subscription")
            .field("topic", &T::TOPIC)
            .finish_non_exhaustive()
    }
}

// Nothing in a subscription is pinned: it is only ever moved whole.
impl<T: TopicType> Unpin for Subscription<T> {}

/// Samples taken per reader per call.
const BATCH: usize = 64;

impl<T: TopicType> Subscription<T> {
    /// Moves what the readers hold (and new malformed reports) into the buffer; true when
    /// a reader gave a full batch, so it may hold more.
    fn fill(&mut self) -> bool {
        let mut more = false;
        let total = cyclone::malformed_total();
        let check_malformed = total != self.malformed_total;
        self.malformed_total = total;
        for (i, source) in self.readers.iter_mut().enumerate() {
            let count = if check_malformed {
                cyclone::malformed_count(&source.topic)
            } else {
                0
            };
            if self.malformed_seen[i] < count {
                let last = cyclone::malformed_last(&source.topic);
                while self.malformed_seen[i] < count {
                    self.malformed_seen[i] += 1;
                    self.buffer.push_back(Err(ReadError::Malformed {
                        topic: T::TOPIC,
                        detail: format!("Cyclone DDS could not decode it: {last}"),
                    }));
                }
            }
            let Source {
                reader, samples, ..
            } = source;
            let reader = reader.entity();
            let buffer = &mut self.buffer;
            match cyclone::take_cdr(reader, BATCH, T::PROFILE.skips_disposed(), |t| {
                buffer.push_back(samples.item::<T>(reader, &t));
            }) {
                Ok(taken) => more |= taken >= BATCH,
                Err(e) => self.buffer.push_back(Err(ReadError::Dds {
                    topic: T::TOPIC,
                    detail: e.to_string(),
                })),
            }
        }
        more
    }
}

impl<T: TopicType> Stream for Subscription<T> {
    /// A valid sample with its metadata, or why a received sample was unusable. The stream
    /// goes on after an error: one bad sample never blocks the ones behind it.
    type Item = Result<(Validated<T>, SampleMeta), ReadError>;

    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Self::Item>> {
        loop {
            if let Some(item) = self.buffer.pop_front() {
                return Poll::Ready(Some(item));
            }
            self.signal.ready.store(false, Ordering::Release);
            let more = self.fill();
            if !self.buffer.is_empty() {
                continue;
            }
            if more {
                // A full batch of state-only samples (a writer of many instances left):
                // the rest wait in the reader, and no data-available will come for them,
                // nor through them for the live writers' samples behind. Take again,
                // after letting other tasks run.
                cx.waker().wake_by_ref();
                return Poll::Pending;
            }
            self.signal.waker.register(cx.waker());
            // Data that arrived between the take and the registration woke no one.
            if !self.signal.ready.load(Ordering::Acquire) {
                return Poll::Pending;
            }
        }
    }
}

/// What a [`Listening`] handler receives: a valid sample with its metadata, or why a
/// received sample was unusable.
pub type Delivery<T> = Result<(Validated<T>, SampleMeta), ReadError>;

/// A reader whose samples go to a function on Cyclone's receive thread
/// ([`PubSub::listen`]). Dropping it deletes the reader, after a call in progress ends.
pub struct Listening<T: TopicType> {
    _reader: ReaderHandle<Deliver<T>>,
    _participant: Arc<Participant>,
}

impl<T: TopicType> std::fmt::Debug for Listening<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Listening")
            .field("topic", &T::TOPIC)
            .finish_non_exhaustive()
    }
}

/// A listening reader's handler and what it needs to turn samples into deliveries.
struct Deliver<T: TopicType> {
    state: Mutex<DeliverState<T>>,
}

struct DeliverState<T: TopicType> {
    samples: Samples,
    topic: String,
    /// As in [`Subscription`]: reports already delivered, and the total last seen.
    malformed_total: u64,
    malformed_seen: u64,
    handler: Box<dyn FnMut(Delivery<T>) + Send>,
}

impl<T: TopicType> cyclone::Wake for Deliver<T> {
    /// Nothing to wake: a malformed report is delivered with the topic's next sample, since
    /// Cyclone reports it from inside its logging, where no handler may run.
    fn wake(&self) {}

    fn data_available(&self, reader: &Entity) {
        let mut state = self
            .state
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let DeliverState {
            samples,
            topic,
            malformed_total,
            malformed_seen,
            handler,
        } = &mut *state;
        let total = cyclone::malformed_total();
        if total != *malformed_total {
            *malformed_total = total;
            let count = cyclone::malformed_count(topic);
            if *malformed_seen < count {
                let last = cyclone::malformed_last(topic);
                while *malformed_seen < count {
                    *malformed_seen += 1;
                    handler(Err(ReadError::Malformed {
                        topic: T::TOPIC,
                        detail: format!("Cyclone DDS could not decode it: {last}"),
                    }));
                }
            }
        }
        // Until the reader is empty: no further call comes for samples already there.
        loop {
            let skip = T::PROFILE.skips_disposed();
            match cyclone::take_cdr(reader, BATCH, skip, |t| {
                handler(samples.item::<T>(reader, &t));
            }) {
                Ok(taken) if taken >= BATCH => {}
                Ok(_) => return,
                Err(e) => {
                    handler(Err(ReadError::Dds {
                        topic: T::TOPIC,
                        detail: e.to_string(),
                    }));
                    return;
                }
            }
        }
    }
}

fn validated<T: TopicType>(
    value: T,
    meta: SampleMeta,
) -> Result<(Validated<T>, SampleMeta), ReadError> {
    match Validated::new(value) {
        Ok(value) => Ok((value, meta)),
        Err((error, value)) => Err(ReadError::Invalid {
            topic: T::TOPIC,
            error,
            payload: serde_json::to_string(&value).unwrap_or_else(|e| format!("\"{e}\"")),
        }),
    }
}
