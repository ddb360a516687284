//! The transport: one Zenoh session per site, glue between it and the cores.
//!
//! [`Federation::start`] opens the session and declares, for this site `S`:
//! - a liveliness token `shoal/S/alive`, and a liveliness subscriber on `shoal/*/alive`
//!   (a remote site coming up is asked what it published while it was away);
//! - subscribers on `shoal/*/vehicles/*/position`, `shoal/*/alarms` and `shoal/*/tasks/*`
//!   (every site, so that data from unknown sites is seen, refused and counted);
//! - a queryable on `shoal/S/catchup/*` answering from the outbound journals;
//! - tasks: one publishing positions as their vehicles fall due, one publishing alarms
//!   and task transitions from a bounded queue, one asking catch-up queries.
//!
//! With site identity (the default), the session authenticates as its site (TLS client
//! certificates and/or user-password) and Zenoh's access control lets each remote site
//! send only under its own `shoal/<site>/**` (see `zenoh_config`: on every link with TLS,
//! on accepted links with user-password alone); the inbound checks below still refuse
//! what an authorised site sends that is inconsistent or from a site not configured.
//!
//! Zenoh calls the subscribers' callbacks on its own threads; they only lock a core for
//! the time of one sample and hand catch-up queries to a task through a bounded channel.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use shoal_model::{Event, now_ms};
use tokio::sync::{mpsc, watch};
use tokio::task::JoinHandle;
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;
use tracing::{debug, info, warn};
use zenoh::Session;
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::{Publisher, Subscriber};
use zenoh::query::{ConsolidationMode, Query, Queryable};
use zenoh::sample::{Locality, Sample, SampleKind};

use crate::config::{Congestion, FederationConfig, Priority, Qos};
use crate::error::{ShutdownError, StartError};
use crate::inbound::{CatchupRequest, Inbound, InboundCounters};
use crate::keys::{self, ROOT, Stream};
use crate::outbound::{Outbound, OutboundCounters, Publication, PushError};
use crate::picture::FederatedPicture;
use crate::types::{TaskTransition, VehiclePosition};
use crate::zenoh_config::{polices, zenoh_config};

/// Alarms and transitions waiting to be published; beyond, remote sites catch up.
const PUBLISH_QUEUE: usize = 1024;
/// Catch-up queries waiting to be asked; beyond, the next gap or reconnection asks again.
const CATCHUP_QUEUE: usize = 64;

/// Both sides' counters.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Counters {
    /// What was received, refused, deduplicated and caught up.
    pub inbound: InboundCounters,
    /// What was sent, coalesced and served.
    pub outbound: OutboundCounters,
}

/// The cores, shared by the handle, the Zenoh callbacks and the tasks.
#[derive(Debug)]
struct Shared {
    inbound: Mutex<Inbound>,
    outbound: Mutex<Outbound>,
    /// Bumped when the picture changes, so a reader can wait for news.
    changed: watch::Sender<u64>,
    catchup: mpsc::Sender<CatchupRequest>,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // A panic while holding a core would be a bug; its state is still consistent enough
    // to count and refuse, so go on rather than take the station down.
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

impl Shared {
    fn receive(&self, sample: &Sample) {
        let key = sample.key_expr().as_str();
        let payload = sample.payload().to_bytes();
        let result = lock(&self.inbound).receive(key, &payload, now_ms());
        match result {
            Ok(request) => {
                self.changed.send_modify(|n| *n += 1);
                if let Some(request) = request {
                    self.ask(request);
                }
            }
            Err(refusal) => debug!(key, reason = %refusal, "refused"),
        }
    }

    fn alive(&self, sample: &Sample) {
        let online = sample.kind() == SampleKind::Put;
        let key = sample.key_expr().as_str();
        let requests = lock(&self.inbound).site_alive(key, online, now_ms());
        self.changed.send_modify(|n| *n += 1);
        for request in requests {
            self.ask(request);
        }
    }

    fn ask(&self, request: CatchupRequest) {
        if let Err(e) = self.catchup.try_send(request) {
            // Forget the query so that the next gap or reconnection asks again.
            let request = match e {
                mpsc::error::TrySendError::Full(r) | mpsc::error::TrySendError::Closed(r) => r,
            };
            lock(&self.inbound).finish_catchup(&request, false);
        }
    }
}

/// What the publishing task sends.
#[derive(Debug)]
enum Outgoing {
    Alarm(Publication),
    Task(Publication),
}

/// A running federation of this site with its remote sites.
#[derive(Debug)]
pub struct Federation {
    site: String,
    /// `tls`, `usrpwd`, `tls+usrpwd` or `none` (`Identity::mechanisms`).
    identity: &'static str,
    /// Whether the links are TLS.
    encrypted: bool,
    epoch: u64,
    shared: Arc<Shared>,
    outgoing: mpsc::Sender<Outgoing>,
    session: Session,
    stop: CancellationToken,
    tasks: Vec<JoinHandle<()>>,
    // Held for their lifetime: dropping one undeclares it.
    token: Option<LivelinessToken>,
    subscribers: Vec<Subscriber<()>>,
}

impl Federation {
    /// Validates `config`, opens the Zenoh session and starts federating. Never waits
    /// for a remote site (except in client mode, where Zenoh waits for the router).
    pub async fn start(config: FederationConfig) -> Result<Self, StartError> {
        config.validate()?;
        // Read here too: `validate` reads the files only when `enabled`, and a program
        // starting the transport means to federate.
        let identity = config.identity()?;
        let zconfig = zenoh_config(&config, identity.as_ref())?;
        let zerr = |what| move |source| StartError::Zenoh { what, source };
        let session = zenoh::open(zconfig).await.map_err(zerr("open a session"))?;
        // The epoch tells a remote site that sequence numbers restarted from 1.
        let epoch = u64::try_from(now_ms()).unwrap_or(0);
        let (catchup_tx, catchup_rx) = mpsc::channel(CATCHUP_QUEUE);
        let shared = Arc::new(Shared {
            inbound: Mutex::new(Inbound::new(&config)),
            outbound: Mutex::new(Outbound::new(&config, epoch)),
            changed: watch::Sender::new(0),
            catchup: catchup_tx,
        });
        let site = config.site.clone();

        let mut subscribers = Vec::new();
        for pattern in [
            format!("{ROOT}/*/vehicles/*/position"),
            format!("{ROOT}/*/alarms"),
            format!("{ROOT}/*/tasks/*"),
        ] {
            let shared = Arc::clone(&shared);
            let sub = session
                .declare_subscriber(pattern)
                .allowed_origin(Locality::Remote)
                .callback(move |sample| shared.receive(&sample))
                .await
                .map_err(zerr("declare a subscriber"))?;
            subscribers.push(sub);
        }
        let queryable = session
            .declare_queryable(format!("{ROOT}/{site}/catchup/*"))
            .allowed_origin(Locality::Remote)
            .await
            .map_err(zerr("declare the catch-up queryable"))?;
        let alarm_publisher = declare(&session, keys::alarms(&site), config.alarms.qos)
            .await
            .map_err(zerr("declare the alarm publisher"))?;
        let token = session
            .liveliness()
            .declare_token(keys::alive(&site))
            .await
            .map_err(zerr("declare the liveliness token"))?;
        let alive = {
            let shared = Arc::clone(&shared);
            let own = keys::alive(&site);
            session
                .liveliness()
                .declare_subscriber(format!("{ROOT}/*/alive"))
                .history(true)
                .callback(move |sample| {
                    if sample.key_expr().as_str() != own {
                        shared.alive(&sample);
                    }
                })
                .await
                .map_err(zerr("declare the liveliness subscriber"))?
        };
        subscribers.push(alive);

        let stop = CancellationToken::new();
        let (outgoing, outgoing_rx) = mpsc::channel(PUBLISH_QUEUE);
        let tasks = vec![
            tokio::spawn(publish_positions(
                session.clone(),
                Arc::clone(&shared),
                config.clone(),
                stop.clone(),
            )),
            tokio::spawn(publish_sequenced(
                session.clone(),
                alarm_publisher,
                config.tasks.qos,
                outgoing_rx,
                stop.clone(),
            )),
            tokio::spawn(serve_catchup(
                queryable,
                Arc::clone(&shared),
                config.limits.catchup_replies,
                stop.clone(),
            )),
            tokio::spawn(ask_catchup(
                session.clone(),
                Arc::clone(&shared),
                catchup_rx,
                CatchupQos {
                    alarms: config.alarms.qos,
                    tasks: config.tasks.qos,
                    timeout: Duration::from_millis(config.limits.catchup_timeout_ms),
                },
                stop.clone(),
            )),
        ];
        let mechanisms = identity.as_ref().map_or("none", |id| id.mechanisms());
        let encrypted = identity.as_ref().is_some_and(|id| id.encrypted());
        info!(
            site = %site,
            epoch,
            zid = %session.zid(),
            identity = mechanisms,
            encrypted,
            access_control = identity.as_ref().is_some_and(|id| polices(&config, id)),
            "federation started"
        );
        Ok(Self {
            site,
            identity: mechanisms,
            encrypted,
            epoch,
            shared,
            outgoing,
            session,
            stop,
            tasks,
            token: Some(token),
            subscribers,
        })
    }

    /// This site's name.
    pub fn site(&self) -> &str {
        &self.site
    }

    /// The site identity in force: `tls`, `usrpwd`, `tls+usrpwd` (see
    /// [`crate::Identity::mechanisms`]) or `none` (`insecure_open`).
    pub fn identity(&self) -> &'static str {
        self.identity
    }

    /// Whether the links are encrypted (`[federation.tls]`).
    pub fn encrypted(&self) -> bool {
        self.encrypted
    }

    /// This run's epoch (ms since the Unix epoch when it started).
    pub fn epoch(&self) -> u64 {
        self.epoch
    }

    /// Takes a local vehicle position; it crosses when its vehicle is next due.
    pub fn push_position(&self, position: VehiclePosition) -> Result<(), PushError> {
        lock(&self.shared.outbound).position(position).map(|_| ())
    }

    /// Takes a local alarm; it crosses at once (if its severity crosses).
    pub fn push_alarm(&self, alarm: &Event) -> Result<(), PushError> {
        let publication = lock(&self.shared.outbound).alarm(alarm)?;
        if let Some(p) = publication {
            self.enqueue(Outgoing::Alarm(p));
        }
        Ok(())
    }

    /// Takes a local task transition; it crosses at once.
    pub fn push_transition(&self, transition: &TaskTransition) -> Result<(), PushError> {
        let publication = lock(&self.shared.outbound).task(transition)?;
        if let Some(p) = publication {
            self.enqueue(Outgoing::Task(p));
        }
        Ok(())
    }

    fn enqueue(&self, item: Outgoing) {
        if self.outgoing.try_send(item).is_err() {
            // It is in the journal: remote sites see the gap and catch up on it.
            lock(&self.shared.outbound).queue_full();
            warn!(site = %self.site, "federation publishing queue full");
        }
    }

    /// Reads the federated picture.
    pub fn picture<R>(&self, read: impl FnOnce(&FederatedPicture) -> R) -> R {
        read(lock(&self.shared.inbound).picture())
    }

    /// Both sides' counters now.
    pub fn counters(&self) -> Counters {
        Counters {
            inbound: lock(&self.shared.inbound).counters().clone(),
            outbound: lock(&self.shared.outbound).counters().clone(),
        }
    }

    /// A receiver that sees a new value whenever the picture changes.
    pub fn changed(&self) -> watch::Receiver<u64> {
        self.shared.changed.subscribe()
    }

    /// Stops the tasks, undeclares everything and closes the session.
    pub async fn shutdown(mut self) -> Result<(), ShutdownError> {
        self.stop.cancel();
        for task in std::mem::take(&mut self.tasks) {
            // A task that panicked has nothing left to clean up.
            let _ = task.await;
        }
        self.subscribers.clear();
        self.token = None;
        self.session.close().await.map_err(ShutdownError::Close)?;
        info!(site = %self.site, "federation stopped");
        Ok(())
    }
}

impl Drop for Federation {
    /// Dropped without `shutdown`: the tasks stop, and with them the last handles on the
    /// session, which Zenoh then closes.
    fn drop(&mut self) {
        self.stop.cancel();
    }
}

fn priority(p: Priority) -> zenoh::qos::Priority {
    use zenoh::qos::Priority as Z;
    match p {
        Priority::RealTime => Z::RealTime,
        Priority::InteractiveHigh => Z::InteractiveHigh,
        Priority::InteractiveLow => Z::InteractiveLow,
        Priority::DataHigh => Z::DataHigh,
        Priority::Data => Z::Data,
        Priority::DataLow => Z::DataLow,
        Priority::Background => Z::Background,
    }
}

fn congestion(c: Congestion) -> zenoh::qos::CongestionControl {
    match c {
        Congestion::Drop => zenoh::qos::CongestionControl::Drop,
        Congestion::Block => zenoh::qos::CongestionControl::Block,
    }
}

/// A publisher with the configured QoS.
async fn declare(session: &Session, key: String, qos: Qos) -> zenoh::Result<Publisher<'static>> {
    session
        .declare_publisher(key)
        .priority(priority(qos.priority))
        .congestion_control(congestion(qos.congestion))
        .express(qos.express)
        .allowed_destination(Locality::Remote)
        .await
}

/// Publishes positions as their vehicles fall due, one publisher per vehicle.
async fn publish_positions(
    session: Session,
    shared: Arc<Shared>,
    config: FederationConfig,
    stop: CancellationToken,
) {
    let start = Instant::now();
    // A quarter of the period, so a position waits at most that long past its due time.
    let period_ms = (1000.0 / config.positions.max_rate_hz) / 4.0;
    let tick = Duration::from_secs_f64(period_ms.clamp(50.0, 1000.0) / 1000.0);
    let mut interval = tokio::time::interval(tick);
    interval.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut publishers: HashMap<String, Publisher<'static>> = HashMap::new();
    loop {
        tokio::select! {
            () = stop.cancelled() => break,
            _ = interval.tick() => {}
        }
        let now = i64::try_from(start.elapsed().as_millis()).unwrap_or(i64::MAX);
        let due = lock(&shared.outbound).due_positions(now);
        for p in due {
            if !publishers.contains_key(&p.key) {
                match declare(&session, p.key.clone(), config.positions.qos).await {
                    Ok(publisher) => {
                        publishers.insert(p.key.clone(), publisher);
                    }
                    Err(e) => {
                        warn!(key = %p.key, error = %e, "cannot declare a position publisher");
                        continue;
                    }
                }
            }
            if let Some(publisher) = publishers.get(&p.key)
                && let Err(e) = publisher.put(p.frame).await
            {
                warn!(key = %p.key, error = %e, "position not published");
            }
        }
    }
}

/// Publishes alarms and task transitions in the order they were numbered.
async fn publish_sequenced(
    session: Session,
    alarms: Publisher<'static>,
    task_qos: Qos,
    mut queue: mpsc::Receiver<Outgoing>,
    stop: CancellationToken,
) {
    loop {
        let item = tokio::select! {
            () = stop.cancelled() => break,
            item = queue.recv() => match item { Some(i) => i, None => break },
        };
        let result = match item {
            Outgoing::Alarm(p) => alarms.put(p.frame).await,
            Outgoing::Task(p) => {
                session
                    .put(p.key, p.frame)
                    .priority(priority(task_qos.priority))
                    .congestion_control(congestion(task_qos.congestion))
                    .express(task_qos.express)
                    .allowed_destination(Locality::Remote)
                    .await
            }
        };
        if let Err(e) = result {
            // Still in the journal: a remote site catches up on it.
            warn!(error = %e, "alarm or transition not published");
        }
    }
}

/// Answers catch-up queries from the outbound journals.
async fn serve_catchup(
    queryable: Queryable<zenoh::handlers::FifoChannelHandler<Query>>,
    shared: Arc<Shared>,
    limit: usize,
    stop: CancellationToken,
) {
    loop {
        let query = tokio::select! {
            () = stop.cancelled() => break,
            q = queryable.recv_async() => match q { Ok(q) => q, Err(_) => break },
        };
        let stream = match query.key_expr().as_str().rsplit('/').next() {
            Some("alarms") => Stream::Alarms,
            Some("tasks") => Stream::Tasks,
            _ => continue,
        };
        let params = query.parameters();
        let after = params
            .get("after")
            .and_then(|v| v.parse().ok())
            .unwrap_or(0);
        let epoch = params.get("epoch").and_then(|v| v.parse().ok());
        let asked = crate::outbound::catchup_limit(params.get("limit"), limit);
        let frames = lock(&shared.outbound).catchup(stream, epoch, after, asked);
        debug!(
            stream = stream.as_str(),
            after,
            count = frames.len(),
            "catch-up served"
        );
        for frame in frames {
            if let Err(e) = query.reply(query.key_expr().clone(), frame).await {
                warn!(error = %e, "catch-up reply not sent");
                break;
            }
        }
    }
}

/// How catch-up queries are sent: each with its stream's QoS (the replies travel with the
/// query's priority and congestion control), and how long each waits.
#[derive(Debug, Clone, Copy)]
struct CatchupQos {
    alarms: Qos,
    tasks: Qos,
    timeout: Duration,
}

/// Wait before asking again for what a query that ran out of time did not bring.
const CATCHUP_RETRY: Duration = Duration::from_secs(2);

/// Asks remote sites for what this site missed, one query at a time, each for at most
/// `limits.catchup_batch` frames; a full answer is followed by the query for the next part,
/// and a query that ran out of time is asked again (after [`CATCHUP_RETRY`], while the
/// site is online): nothing else would ask for a gap no later frame reveals.
async fn ask_catchup(
    session: Session,
    shared: Arc<Shared>,
    mut requests: mpsc::Receiver<CatchupRequest>,
    qos: CatchupQos,
    stop: CancellationToken,
) {
    let timeout = qos.timeout;
    let mut retries: Vec<(Instant, String, Stream)> = Vec::new();
    let mut next: Option<CatchupRequest> = None;
    loop {
        let request = match next.take() {
            Some(r) => r,
            None => {
                let due = retries.iter().map(|r| r.0).min();
                tokio::select! {
                    () = stop.cancelled() => break,
                    r = requests.recv() => match r { Some(r) => r, None => break },
                    () = async {
                        match due {
                            Some(at) => tokio::time::sleep_until(at).await,
                            None => std::future::pending().await,
                        }
                    } => {
                        let now = Instant::now();
                        let (ready, later): (Vec<_>, Vec<_>) =
                            retries.drain(..).partition(|r| r.0 <= now);
                        retries = later;
                        let mut inbound = lock(&shared.inbound);
                        for (_, site, stream) in ready {
                            if let Some(r) = inbound.retry_catchup(&site, stream) {
                                match next {
                                    None => next = Some(r),
                                    // One at a time: the others wait their turn.
                                    Some(_) => retries.push((now, site, stream)),
                                }
                            }
                        }
                        continue;
                    }
                }
            }
        };
        let stream_qos = match request.stream {
            Stream::Alarms => qos.alarms,
            Stream::Tasks => qos.tasks,
        };
        let mut selector = format!(
            "{}?after={};limit={}",
            keys::catchup(&request.site, request.stream),
            request.after,
            request.limit
        );
        if let Some(epoch) = request.epoch {
            selector.push_str(&format!(";epoch={epoch}"));
        }
        // Every reply has the same key: without this Zenoh would keep only the last.
        let started = Instant::now();
        let replies = session
            .get(&selector)
            .consolidation(ConsolidationMode::None)
            .priority(priority(stream_qos.priority))
            .congestion_control(congestion(stream_qos.congestion))
            .timeout(timeout)
            .await;
        let replies = match replies {
            Ok(r) => r,
            Err(e) => {
                warn!(selector, error = %e, "catch-up query not sent");
                lock(&shared.inbound).finish_catchup(&request, false);
                continue;
            }
        };
        let (mut taken, mut answered) = (0u64, 0usize);
        loop {
            let reply = tokio::select! {
                () = stop.cancelled() => return,
                r = replies.recv_async() => match r { Ok(r) => r, Err(_) => break },
            };
            answered += 1;
            match reply.result() {
                Ok(sample) => {
                    let key = sample.key_expr().as_str();
                    let payload = sample.payload().to_bytes();
                    let result =
                        lock(&shared.inbound).receive_catchup(&request, key, &payload, now_ms());
                    if result.is_ok() {
                        taken += 1;
                    }
                }
                Err(e) => debug!(selector, error = ?e, "catch-up error reply"),
            }
        }
        let more = {
            let mut inbound = lock(&shared.inbound);
            inbound.finish_catchup(&request, true);
            // A full answer: the sender may have more; ask for the next part at once.
            (answered >= request.limit)
                .then(|| inbound.continue_catchup(&request.site, request.stream))
                .flatten()
        };
        if taken > 0 {
            shared.changed.send_modify(|n| *n += 1);
        }
        debug!(site = %request.site, stream = request.stream.as_str(), taken, answered, more = more.is_some(), "catch-up done");
        // Ran out of time short of a full answer: what it did not bring is asked for again.
        let out_of_time = started.elapsed() >= timeout.mul_f64(0.95);
        if more.is_none()
            && out_of_time
            && answered < request.limit
            && !retries
                .iter()
                .any(|r| r.1 == request.site && r.2 == request.stream)
        {
            debug!(site = %request.site, stream = request.stream.as_str(), answered, "catch-up ran out of time; asking again");
            retries.push((
                Instant::now() + CATCHUP_RETRY,
                request.site.clone(),
                request.stream,
            ));
        }
        next = more;
    }
}
