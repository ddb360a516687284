//! Replay: recorded samples published again on DDS at the recorded pace.

use std::collections::{BTreeSet, HashMap};
use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, SystemTime};

use shoal_dds::{CdrError, PubSub, TopicType, Writer, WriterOptions};
use shoal_model::ValidationError;
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;
use tracing::{debug, info, warn};

use crate::error::{ReadError, ReplayError};
use crate::reader::{McapMessages, RecordedMessage, mcap_files};
use crate::topic::{Sample, Topic};

/// How fast a recording is replayed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Speed {
    /// This many times the recorded pace, 1 to 100.
    Factor(f64),
    /// No waiting between messages (tests, bulk loading).
    AsFastAsPossible,
}

impl Speed {
    /// The speed `factor` times the recorded pace, if it lies in 1..=100.
    pub fn factor(factor: f64) -> Option<Self> {
        (1.0..=100.0)
            .contains(&factor)
            .then_some(Self::Factor(factor))
    }
}

/// How a replay runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReplayOptions {
    /// Pace.
    pub speed: Speed,
    /// Publish recorded task assignments too. Off by default: a replayed assignment
    /// commands whichever live vehicle has that id.
    pub include_tasks: bool,
    /// How long a new writer waits for a first matched reader before the replay goes on
    /// (samples written before any reader matched are lost); the replay clock pauses.
    pub match_timeout: Duration,
    /// When the first message is due (by the wall clock, so that the processes of one
    /// secure replay keep one pace); `None`: at once.
    pub start_at: Option<SystemTime>,
}

impl Default for ReplayOptions {
    fn default() -> Self {
        Self {
            speed: Speed::Factor(1.0),
            include_tasks: false,
            match_timeout: Duration::from_secs(5),
            start_at: None,
        }
    }
}

/// What a replay has done so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ReplayStats {
    /// Files opened.
    pub files: u64,
    /// Files that could not be read to their end (what came before the damage was
    /// replayed).
    pub damaged_files: u64,
    /// Messages of Shoal channels read.
    pub read: u64,
    /// Samples published.
    pub published: u64,
    /// Messages of channels that are not Shoal channels, skipped.
    pub unknown: u64,
    /// Messages whose payload does not decode as their topic's type, skipped.
    pub undecodable: u64,
    /// Samples that fail validation, skipped.
    pub invalid: u64,
    /// Task assignments not published (see [`ReplayOptions::include_tasks`]).
    pub tasks_skipped: u64,
    /// Samples DDS refused to send.
    pub write_failed: u64,
    /// Samples of another identity, published by the process that holds it.
    pub elsewhere: u64,
}

/// Why a recorded message cannot be replayed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SampleError {
    /// The payload is not CDR of the topic's type.
    #[error("cannot decode: {0}")]
    Cdr(#[from] CdrError),
    /// The sample decodes but is not valid.
    #[error("invalid: {0}")]
    Invalid(#[from] ValidationError),
}

/// Decodes a recorded message into its typed sample and validates it: what replay does
/// with each message before publishing it.
pub fn decode_message(message: &RecordedMessage) -> Result<Sample, SampleError> {
    let sample = Sample::decode(message.topic, &message.data)?;
    sample.validate()?;
    Ok(sample)
}

/// Whose samples a participant with DDS Security credentials publishes.
///
/// Cyclone DDS holds one security identity per process (a second participant with other
/// credentials presents the first one's permissions), so a secure replay runs one process
/// per identity: the station's samples in one, each vehicle's in its own.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Identity {
    /// Samples no vehicle publishes (task assignments, events that name no vehicle).
    Station,
    /// The samples this vehicle publishes.
    Vehicle(String),
}

/// The DDS participant a replay publishes through, and which samples it may publish.
///
/// On a secure domain each vehicle may publish only in its own partition and the station's
/// identity cannot speak for vehicles, so a participant with credentials publishes only
/// the samples of its [`Identity`]; the others are left to the process that holds theirs.
#[derive(Debug)]
pub struct Publishers {
    pubsub: Arc<PubSub>,
    /// `None`: everything (a domain without DDS Security).
    only: Option<Identity>,
}

impl Publishers {
    /// Everything through one participant: only on a domain without DDS Security; a
    /// participant with credentials is refused ([`ReplayError::SecureShared`]).
    pub fn insecure(pubsub: Arc<PubSub>) -> Result<Self, ReplayError> {
        if pubsub.credentials().is_some() {
            return Err(ReplayError::SecureShared);
        }
        Ok(Self { pubsub, only: None })
    }

    /// Only the samples of `identity`, through `pubsub`, which holds its credentials.
    pub fn secure(pubsub: Arc<PubSub>, identity: Identity) -> Self {
        Self {
            pubsub,
            only: Some(identity),
        }
    }

    /// Whether a sample published by `vehicle` (`None`: the station) goes out here.
    fn publishes(&self, vehicle: Option<&str>) -> bool {
        match (&self.only, vehicle) {
            (None, _) | (Some(Identity::Station), None) => true,
            (Some(Identity::Vehicle(id)), Some(v)) => id == v,
            _ => false,
        }
    }
}

/// The vehicles whose samples a replay of `path` publishes (task assignments only with
/// `include_tasks`), read ahead so that a secure replay can start one process per
/// identity. More than `max` vehicles is an error; unreadable parts are skipped here (the
/// replay itself reports them).
pub fn publishing_vehicles(
    path: &Path,
    include_tasks: bool,
    max: usize,
) -> Result<BTreeSet<String>, ReplayError> {
    let mut ids = BTreeSet::new();
    for file in mcap_files(path)? {
        let f = std::fs::File::open(&file).map_err(|source| ReplayError::Open {
            path: file.clone(),
            source,
        })?;
        for message in McapMessages::new(std::io::BufReader::new(f)) {
            let Ok(message) = message else { break };
            let Ok(sample) = decode_message(&message) else {
                continue;
            };
            if sample.topic() == Topic::TaskAssignment && !include_tasks {
                continue;
            }
            if let Some(id) = sample.publishing_vehicle()
                && !ids.contains(id)
            {
                if ids.len() == max {
                    return Err(ReplayError::TooManyVehicles { max });
                }
                ids.insert(id.to_string());
            }
        }
    }
    Ok(ids)
}

/// A writer of any Shoal topic.
enum AnyWriter {
    StateVector(Writer<shoal_model::StateVector>),
    VehicleAnnouncement(Writer<shoal_model::VehicleAnnouncement>),
    TaskAssignment(Writer<shoal_model::TaskAssignment>),
    TaskStatus(Writer<shoal_model::TaskStatus>),
    Event(Writer<shoal_model::Event>),
    Environment(Writer<shoal_model::EnvironmentObservation>),
}

fn writer<T: TopicType>(pubsub: &PubSub) -> Result<Writer<T>, ReplayError> {
    pubsub
        .writer::<T>(WriterOptions::new(T::DEFAULT_PRIORITY))
        .map_err(|source| ReplayError::Dds {
            what: T::TOPIC.to_string(),
            source: Box::new(source),
        })
}

impl AnyWriter {
    fn new(topic: Topic, pubsub: &PubSub) -> Result<Self, ReplayError> {
        Ok(match topic {
            Topic::StateVector => Self::StateVector(writer(pubsub)?),
            Topic::VehicleAnnouncement => Self::VehicleAnnouncement(writer(pubsub)?),
            Topic::TaskAssignment => Self::TaskAssignment(writer(pubsub)?),
            Topic::TaskStatus => Self::TaskStatus(writer(pubsub)?),
            Topic::Event => Self::Event(writer(pubsub)?),
            Topic::Environment => Self::Environment(writer(pubsub)?),
        })
    }

    fn matched_readers(&self) -> i32 {
        match self {
            Self::StateVector(w) => w.matched_readers(),
            Self::VehicleAnnouncement(w) => w.matched_readers(),
            Self::TaskAssignment(w) => w.matched_readers(),
            Self::TaskStatus(w) => w.matched_readers(),
            Self::Event(w) => w.matched_readers(),
            Self::Environment(w) => w.matched_readers(),
        }
    }

    /// Publishes `sample` (of this writer's topic); the error says why not.
    async fn write(&self, sample: Sample) -> Result<(), SendFailure> {
        fn dds<T: std::fmt::Debug + Send + Sync + 'static>(
            r: Result<(), shoal_dds::WriteError<T>>,
        ) -> Result<(), SendFailure> {
            r.map_err(|e| SendFailure::Dds(Box::new(e)))
        }
        match (self, sample) {
            (Self::StateVector(w), Sample::StateVector(s)) => dds(w.write(s).await),
            (Self::VehicleAnnouncement(w), Sample::VehicleAnnouncement(s)) => dds(w.write(s).await),
            (Self::TaskAssignment(w), Sample::TaskAssignment(s)) => dds(w.write(s).await),
            (Self::TaskStatus(w), Sample::TaskStatus(s)) => dds(w.write(s).await),
            (Self::Event(w), Sample::Event(s)) => dds(w.write(s).await),
            (Self::Environment(w), Sample::Environment(s)) => dds(w.write(s).await),
            _ => Err(SendFailure::OtherTopic),
        }
    }
}

/// Why one replayed sample was not sent (counted and logged; the replay goes on).
#[derive(Debug, thiserror::Error)]
enum SendFailure {
    /// The writer refused or could not send it.
    #[error(transparent)]
    Dds(Box<dyn std::error::Error + Send + Sync>),
    /// A sample reached the writer of another topic.
    #[error("sample of another topic than its writer's")]
    OtherTopic,
}

/// Publishes recordings on DDS.
pub struct Replayer {
    publishers: Publishers,
    options: ReplayOptions,
    writers: HashMap<Topic, AnyWriter>,
    stats: ReplayStats,
    /// Recorded time and the instant it is replayed at, of the replay's first message.
    clock: Option<(u64, Instant)>,
    progress: Option<Progress>,
    /// Topics of skipped channels already told of, so each is told once per replayer.
    skipped: BTreeSet<String>,
    on_skipped: Option<SkippedNote>,
}

/// A caller's note of skipped channels: the file and the topics new in it.
type SkippedNote = Box<dyn FnMut(&Path, &[String]) + Send>;

/// A caller's progress report and how often it wants it.
struct Progress {
    every: Duration,
    last: Instant,
    report: Box<dyn FnMut(&ReplayStats) + Send>,
}

impl std::fmt::Debug for Replayer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Replayer")
            .field("options", &self.options)
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

impl Replayer {
    /// A replayer publishing through `publishers`.
    pub fn new(publishers: Publishers, options: ReplayOptions) -> Self {
        Self {
            publishers,
            options,
            writers: HashMap::new(),
            stats: ReplayStats::default(),
            clock: None,
            progress: None,
            skipped: BTreeSet::new(),
            on_skipped: None,
        }
    }

    /// Calls `note` with a file and the topics of its channels that are not Shoal DDS
    /// topics (an acoustic recording's `acoustic/frame`, another tool's topics), which
    /// are skipped, each topic once per replayer; without it they are logged.
    pub fn on_skipped_channels(&mut self, note: impl FnMut(&Path, &[String]) + Send + 'static) {
        self.on_skipped = Some(Box::new(note));
    }

    /// Calls `report` with the counters at most every `every` while replaying.
    pub fn on_progress(
        &mut self,
        every: Duration,
        report: impl FnMut(&ReplayStats) + Send + 'static,
    ) {
        self.progress = Some(Progress {
            every,
            last: Instant::now(),
            report: Box::new(report),
        });
    }

    /// Counters so far.
    pub fn stats(&self) -> ReplayStats {
        self.stats
    }

    /// Replays a file, or a directory's files in recording order, with the recorded pace
    /// kept across files. A damaged file is replayed up to the damage and its error
    /// returned in the list; the next file follows. Errors that stop the replay (no files,
    /// no participant for a vehicle) are `Err`.
    pub async fn replay_path(
        &mut self,
        path: &Path,
        cancel: &CancellationToken,
    ) -> Result<Vec<ReplayError>, ReplayError> {
        let mut damaged = Vec::new();
        self.clock = None;
        for file in mcap_files(path)? {
            if cancel.is_cancelled() {
                break;
            }
            let f = std::fs::File::open(&file).map_err(|source| ReplayError::Open {
                path: file.clone(),
                source,
            })?;
            self.stats.files += 1;
            info!(file = %file.display(), "replaying");
            let mut messages = McapMessages::new(std::io::BufReader::new(f));
            let stopped = self.replay_messages(&mut messages, cancel).await?;
            self.stats.unknown += messages.stats().unknown_messages;
            self.note_skipped(&file, messages.unknown_topics());
            if let Some(source) = stopped {
                self.stats.damaged_files += 1;
                warn!(file = %file.display(), error = %source, "file not read to its end");
                damaged.push(ReplayError::Read { path: file, source });
            }
        }
        Ok(damaged)
    }

    /// Tells of the skipped channels' topics of `file` not told of before.
    fn note_skipped(&mut self, file: &Path, topics: &[String]) {
        // Bounded: a directory of another tool's files could name any number of topics.
        let room = 256usize.saturating_sub(self.skipped.len());
        let new: Vec<String> = topics
            .iter()
            .filter(|t| !self.skipped.contains(*t))
            .take(room)
            .cloned()
            .collect();
        if new.is_empty() {
            return;
        }
        self.skipped.extend(new.iter().cloned());
        match self.on_skipped.as_mut() {
            Some(note) => note(file, &new),
            None => info!(
                file = %file.display(),
                topics = %new.join(", "),
                "channels that are not Shoal DDS topics skipped"
            ),
        }
    }

    /// Replays messages until they end, the replay is cancelled, or reading stops with an
    /// error, which is returned (after everything before it was published).
    pub async fn replay_messages<I>(
        &mut self,
        messages: I,
        cancel: &CancellationToken,
    ) -> Result<Option<ReadError>, ReplayError>
    where
        I: IntoIterator<Item = Result<RecordedMessage, ReadError>>,
    {
        for message in messages {
            if cancel.is_cancelled() {
                break;
            }
            let message = match message {
                Ok(m) => m,
                Err(e) => return Ok(Some(e)),
            };
            self.stats.read += 1;
            if let Some(p) = self.progress.as_mut()
                && p.last.elapsed() >= p.every
            {
                p.last = Instant::now();
                (p.report)(&self.stats);
            }
            self.pace(message.log_time_ns, cancel).await;
            let sample = match decode_message(&message) {
                Ok(s) => s,
                Err(SampleError::Cdr(e)) => {
                    self.stats.undecodable += 1;
                    debug!(topic = message.topic.name(), error = %e, "recorded sample skipped");
                    continue;
                }
                Err(SampleError::Invalid(e)) => {
                    self.stats.invalid += 1;
                    debug!(topic = message.topic.name(), error = %e, "recorded sample skipped");
                    continue;
                }
            };
            if sample.topic() == Topic::TaskAssignment && !self.options.include_tasks {
                self.stats.tasks_skipped += 1;
                continue;
            }
            self.publish(sample).await?;
        }
        Ok(None)
    }

    /// Waits until the instant `log_time_ns` is due at, at the replay's speed.
    async fn pace(&mut self, log_time_ns: u64, cancel: &CancellationToken) {
        let Speed::Factor(factor) = self.options.speed else {
            return;
        };
        let start_at = self.options.start_at.take();
        let (start_ns, start) = *self.clock.get_or_insert_with(|| {
            let now = Instant::now();
            let start = start_at
                .and_then(|at| at.duration_since(SystemTime::now()).ok())
                .map_or(now, |wait| now + wait);
            (log_time_ns, start)
        });
        // A message logged before the first (clocks stepped, files of two recorders) is
        // due at once.
        let offset_ns = log_time_ns.saturating_sub(start_ns) as f64 / factor;
        let due = start + Duration::from_nanos(offset_ns as u64);
        tokio::select! {
            () = tokio::time::sleep_until(due) => {}
            () = cancel.cancelled() => {}
        }
    }

    async fn publish(&mut self, sample: Sample) -> Result<(), ReplayError> {
        let topic = sample.topic();
        if !self.publishers.publishes(sample.publishing_vehicle()) {
            self.stats.elsewhere += 1;
            return Ok(());
        }
        let key = topic;
        if !self.writers.contains_key(&key) {
            let writer = AnyWriter::new(topic, &self.publishers.pubsub)?;
            let waited = wait_for_reader(&writer, self.options.match_timeout).await;
            // The clock pauses while a writer waits for its readers, so the pace of what
            // follows is kept.
            if let Some((_, start)) = self.clock.as_mut() {
                *start += waited;
            }
            self.writers.insert(key, writer);
        }
        let Some(writer) = self.writers.get(&key) else {
            return Ok(());
        };
        match writer.write(sample).await {
            Ok(()) => self.stats.published += 1,
            Err(e) => {
                self.stats.write_failed += 1;
                warn!(topic = topic.name(), error = %e, "replayed sample not sent");
            }
        }
        Ok(())
    }
}

/// Waits until `writer` has a matched reader, for `timeout` at most; returns how long.
async fn wait_for_reader(writer: &AnyWriter, timeout: Duration) -> Duration {
    let start = Instant::now();
    while writer.matched_readers() < 1 && start.elapsed() < timeout {
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    start.elapsed()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::RecordWriter;
    use crate::tests::{one_of_each, state};

    fn write(dir: &Path, samples: &[Sample]) {
        write_chunked(
            dir,
            samples,
            crate::RecorderConfig::default().max_chunk_bytes,
        );
    }

    fn write_chunked(dir: &Path, samples: &[Sample], max_chunk_bytes: u64) {
        let cfg = crate::RecorderConfig {
            directory: dir.to_path_buf(),
            max_chunk_bytes,
            ..crate::RecorderConfig::default()
        };
        let mut w = RecordWriter::new(&cfg).unwrap();
        for (t, s) in (1..).zip(samples) {
            w.write(s.topic(), t, t, &s.encode().unwrap()).unwrap();
        }
        w.close().unwrap();
    }

    #[test]
    fn the_vehicles_a_replay_publishes_as_are_read_ahead_and_bounded() {
        let dir = tempfile::tempdir().unwrap();
        let mut samples = one_of_each();
        samples.extend((0..3).map(|i| Sample::StateVector(state(&format!("v-{i}"), i))));
        write(dir.path(), &samples);
        let with_tasks = publishing_vehicles(dir.path(), true, 100).unwrap();
        let without = publishing_vehicles(dir.path(), false, 100).unwrap();
        // A task assignment is the station's, whatever vehicle it names.
        assert_eq!(with_tasks, without);
        for i in 0..3 {
            assert!(without.contains(&format!("v-{i}")), "{without:?}");
        }
        let n = without.len();
        assert!(matches!(
            publishing_vehicles(dir.path(), false, n - 1),
            Err(ReplayError::TooManyVehicles { max }) if max == n - 1
        ));
        assert_eq!(publishing_vehicles(dir.path(), false, n).unwrap().len(), n);
    }

    /// A damaged recording (cut at any byte, as a killed recorder or a bad copy leaves it)
    /// is read ahead as far as it is readable: never an error, never a vehicle that is not
    /// in the whole file. Replay then reports where reading stopped.
    #[test]
    fn reading_ahead_a_cut_recording_finds_what_precedes_the_cut() {
        let dir = tempfile::tempdir().unwrap();
        // Vehicles appear one after another over 2,000 samples, in the smallest chunks, so
        // that a cut keeps some chunks whole and so some of the vehicles.
        let samples: Vec<Sample> = (0..2000)
            .map(|i| Sample::StateVector(state(&format!("v-{}", i / 50), i)))
            .collect();
        write_chunked(dir.path(), &samples, 64 * 1024);
        let file = mcap_files(dir.path()).unwrap().remove(0);
        let whole = std::fs::read(&file).unwrap();
        let all = publishing_vehicles(&file, false, 100).unwrap();
        assert_eq!(all.len(), 40);
        let cut = dir.path().join("cut");
        std::fs::create_dir(&cut).unwrap();
        let cut_file = cut.join("cut.mcap");
        let mut partial = 0;
        for len in (0..whole.len()).step_by(whole.len() / 200 + 1) {
            std::fs::write(&cut_file, &whole[..len]).unwrap();
            let found = publishing_vehicles(&cut_file, false, 100).unwrap();
            assert!(found.is_subset(&all), "cut at {len}: {found:?}");
            if !found.is_empty() && found.len() < all.len() {
                partial += 1;
            }
        }
        assert!(partial > 0, "no cut kept part of the recording");
    }
}
