//! The transport: one Zenoh session per site (two on a site that connects, see below),
//! glue between it and the cores.
//!
//! [`Federation::start`] opens the session and declares, for this site `S`:
//! - a liveliness token `shoal/S/alive`, and a liveliness subscriber on `shoal/*/alive`
//!   (a remote site coming up is asked what it published while it was away);
//! - subscribers on `shoal/*/vehicles/*/position`, `shoal/*/alarms`, `shoal/*/tasks/*`,
//!   `shoal/*/leases/*`, `shoal/*/environment/*` (every site, so that data from unknown
//!   sites is seen, refused and counted), and `shoal/*/orders/S/*` (orders for this
//!   site's vehicles, from any site);
//! - a queryable on `shoal/S/catchup/*` answering from the outbound journals, and with
//!   TLS one on `shoal/S/identity` answering this site's certificate chain;
//! - tasks: one publishing positions as their vehicles fall due, one publishing alarms
//!   from a bounded queue of their own, one publishing task transitions, lease records and
//!   orders from another, one asking catch-up queries, and (with `environment.mode =
//!   "aggregated"`) one publishing environment summaries as their vehicles' windows end.
//!
//! A site that connects somewhere and listens nowhere opens, with `alarms.own_link` (the
//! default), a second session to the same endpoints that carries alarms alone: their
//! publisher and their subscriber. Zenoh's priorities order only what waits in its own
//! queues; what it has written to a TCP socket leaves in order, and on a slow link that
//! can be tens of kB of positions, lease records or catch-up ahead of an alarm. A
//! connection of their own carries alarms past it.
//!
//! Orders this site accepts (it is the vehicle's home, the sender holds the lease) wait in
//! a bounded queue for the station, which takes its receiver with
//! [`Federation::take_orders`].
//!
//! With site identity (the default), the session authenticates as its site (TLS client
//! certificates and/or user-password) and Zenoh's access control lets each remote site
//! send only under its own `shoal/<site>/**` (see `zenoh_config`: on every link with TLS,
//! on accepted links with user-password alone); the inbound checks below still refuse
//! what an authorised site sends that is inconsistent or from a site not configured.
//! With TLS, lease records and orders are also signed end to end with the site's key
//! ([`crate::signed`]): a router relaying them cannot forge or alter them. A remote site's
//! certificate is asked of it (`shoal/<site>/identity`) when its session comes up, and
//! whenever a signed sample arrives before it.
//!
//! Zenoh calls the subscribers' callbacks on its own threads; they only lock a core for
//! the time of one sample and hand catch-up queries to a task through a bounded channel.

use std::collections::{HashMap, HashSet, VecDeque};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use futures::StreamExt;
use futures::stream::FuturesUnordered;
use shoal_model::{EnvironmentObservation, Event, TaskAssignment, now_ms};
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

use crate::config::{Congestion, EnvironmentMode, FederationConfig, Priority, Qos};
use crate::error::{ShutdownError, StartError};
use crate::inbound::{CatchupOutcome, CatchupRequest, Inbound, InboundCounters, Refusal};
use crate::keys::{self, ROOT, Stream};
use crate::lease::{HandoverError, LeaseRecord};
use crate::lease_keeper::{self, CommandDenied, Keeper, LeaseRun};
use crate::orders::{self, OrderError, OrderRefusal, RelayedOrder};
use crate::outbound::{Outbound, OutboundCounters, Publication, PushError};
use crate::pacing::{Pacer, REPLY_OVERHEAD, Waits};
use crate::picture::FederatedPicture;
use crate::signed::HeldSample;
use crate::site_keys::{SiteCertificates, SiteSigner, sealed};
use crate::types::{TaskTransition, VehiclePosition};
use crate::zenoh_config::{polices, zenoh_config};

/// Alarms and transitions waiting to be published; beyond, remote sites catch up.
const PUBLISH_QUEUE: usize = 1024;
/// Catch-up queries waiting to be asked; beyond, the next gap or reconnection asks again.
const CATCHUP_QUEUE: usize = 64;
/// Accepted orders waiting for the station; beyond, an order is refused
/// (`order_queue_full`) and its sender sees no task transition. Also what a station that
/// never takes the receiver holds at most.
const ORDER_QUEUE: usize = 256;

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
    /// The lease keeper's state; locked before `inbound` when both are.
    lease_run: Mutex<LeaseRun>,
    /// `lease.enabled`, fixed at start: read without the lease state's lock, so that no
    /// getter takes two locks.
    lease_enabled: bool,
    /// Remote sites to ask for their lease records.
    lease_ask: mpsc::Sender<String>,
    site: String,
    state_file: std::path::PathBuf,
    outgoing: mpsc::Sender<Outgoing>,
    /// Accepted orders, to the station.
    orders: mpsc::Sender<RelayedOrder>,
    /// This site's key when it signs (with TLS).
    signer: Option<Arc<SiteSigner>>,
    /// Remote sites whose certificate to ask for.
    identity_ask: mpsc::Sender<String>,
    /// Paces this site's answers to catch-up and lease queries (`link_rate_kbps`).
    pacer: Option<Mutex<Pacer>>,
}

impl Shared {
    /// Waits until an answer of `bytes` (payload and key) may leave, on a paced link.
    async fn pace(&self, bytes: usize) {
        let Some(pacer) = &self.pacer else {
            return;
        };
        let wait = lock(pacer).reserve(bytes + REPLY_OVERHEAD, Instant::now());
        if !wait.is_zero() {
            tokio::time::sleep(wait).await;
        }
    }

    /// Waits for room for `bytes` if they may leave by `deadline`; `false` (and no wait)
    /// when they would leave later. Without pacing, or without a deadline, always room.
    async fn pace_by(&self, bytes: usize, deadline: Option<Instant>) -> bool {
        let (Some(pacer), Some(deadline)) = (&self.pacer, deadline) else {
            self.pace(bytes).await;
            return true;
        };
        let wait = lock(pacer).reserve_by(bytes + REPLY_OVERHEAD, Instant::now(), deadline);
        match wait {
            Some(wait) => {
                if !wait.is_zero() {
                    tokio::time::sleep(wait).await;
                }
                true
            }
            None => false,
        }
    }
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
        self.receive_bytes(key, &payload);
    }

    fn receive_bytes(&self, key: &str, payload: &[u8]) {
        let result = lock(&self.inbound).receive(key, payload, now_ms());
        match result {
            Ok(request) => {
                self.changed.send_modify(|n| *n += 1);
                if let Some(request) = request {
                    self.ask(request);
                }
            }
            Err(refusal) => self.refused(key, &refusal),
        }
    }

    /// Logs a refusal; asks for the signer's certificate when a sample waits for it.
    fn refused(&self, key: &str, refusal: &Refusal) {
        match refusal {
            Refusal::AwaitingIdentity { site, ask } => {
                debug!(
                    key,
                    site, "held until the signing site's certificate arrives"
                );
                if *ask {
                    self.ask_identity(site);
                }
            }
            Refusal::AwaitingIdentityFull => {
                warn!(
                    key,
                    "signed sample dropped: too many wait for their signer's certificate"
                );
            }
            Refusal::Signature(e) => warn!(key, reason = %e, "signed sample refused"),
            _ => debug!(key, reason = %refusal, "refused"),
        }
    }

    fn ask_identity(&self, site: &str) {
        if self.identity_ask.try_send(site.to_owned()).is_err() {
            // The next held sample, or the site's next session, asks again.
            lock(&self.inbound).identity_unanswered(site);
        }
    }

    /// Takes a remote site's identity frame, and receives again what waited for it.
    fn identity(&self, site: &str, payload: &[u8]) -> bool {
        let held: Vec<HeldSample> = match lock(&self.inbound).identity(site, payload, now_ms()) {
            Ok(held) => held,
            Err(refusal) => {
                warn!(site, reason = %refusal, "remote site's identity refused");
                return false;
            }
        };
        debug!(site, held = held.len(), "remote site's certificate taken");
        for (key, payload) in held {
            if matches!(keys::Key::parse(&key), Some(keys::Key::Order { .. })) {
                self.order_bytes(&key, &payload);
            } else {
                self.receive_bytes(&key, &payload);
            }
        }
        true
    }

    /// Takes an order sample: checked, and delivered to the station's queue if new.
    fn order(&self, sample: &Sample) {
        let key = sample.key_expr().as_str();
        let payload = sample.payload().to_bytes();
        self.order_bytes(key, &payload);
    }

    fn order_bytes(&self, key: &str, payload: &[u8]) {
        // Under the inbound lock: `try_send` never waits, and an order is remembered as
        // delivered only once it is in the queue.
        let result = lock(&self.inbound).receive_order(key, payload, now_ms(), |order| {
            self.orders.try_send(order).map_err(|e| match e {
                mpsc::error::TrySendError::Full(_) => OrderRefusal::QueueFull,
                mpsc::error::TrySendError::Closed(_) => OrderRefusal::ReceiverClosed,
            })
        });
        match result {
            Ok(()) => debug!(key, "order accepted"),
            Err(refusal @ Refusal::AwaitingIdentity { .. }) => self.refused(key, &refusal),
            // Logged by the inbound core, rate limited.
            Err(_) => {}
        }
    }

    fn alive(&self, sample: &Sample) {
        let online = sample.kind() == SampleKind::Put;
        let key = sample.key_expr().as_str();
        let requests = lock(&self.inbound).site_alive(key, online, now_ms());
        self.changed.send_modify(|n| *n += 1);
        if online && let Some(keys::Key::Alive { site }) = keys::Key::parse(key) {
            if self.signer.is_some() {
                self.ask_identity(site);
            }
            if self.lease_enabled {
                // Queued behind the others; a full queue: the next reconnection asks again.
                let _ = self.lease_ask.try_send(site.to_owned());
            }
        }
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
            lock(&self.inbound).abandon_catchup(&request);
        }
    }

    /// Takes a lease record from a reply to a lease query.
    fn lease_reply(&self, key: &str, payload: &[u8]) {
        let result = lock(&self.inbound).receive(key, payload, now_ms());
        match result {
            Ok(_) => self.changed.send_modify(|n| *n += 1),
            Err(refusal) => self.refused(key, &refusal),
        }
    }

    /// Queues a record this site made for publishing.
    fn publish_lease(&self, record: LeaseRecord) {
        match record.reason {
            crate::lease::LeaseReason::Claim => {
                debug!(vehicle = %record.vehicle_id, term = record.term, "command lease claimed");
            }
            reason => info!(
                vehicle = %record.vehicle_id,
                holder = %record.holder,
                term = record.term,
                reason = reason.as_str(),
                "command lease changed here"
            ),
        }
        self.changed.send_modify(|n| *n += 1);
        if self.outgoing.try_send(Outgoing::Lease(record)).is_err() {
            // A remote site that missed it learns it by its lease query at reconnection;
            // one that stays connected does not: say so.
            lock(&self.outbound).queue_full();
            warn!(site = %self.site, "federation publishing queue full: a lease record was not sent");
        }
    }
}

impl lease_keeper::Paced for Shared {
    fn pace(&self, bytes: usize) -> impl Future<Output = ()> + Send {
        Shared::pace(self, bytes)
    }
}

impl Keeper for Shared {
    fn pass(&self) -> Vec<LeaseRecord> {
        let mut run = lock(&self.lease_run);
        if !run.policy.enabled || !run.settled() {
            return Vec::new();
        }
        let now = now_ms();
        let timeout = i64::try_from(run.policy.failover_timeout_ms).unwrap_or(i64::MAX);
        let started = run.started_ms();
        let own = run.take_own();
        let mut inbound = lock(&self.inbound);
        let mut made: Vec<LeaseRecord> = own
            .iter()
            .filter_map(|v| inbound.leases_mut().claim(v, now))
            .collect();
        let offline: HashMap<String, Option<i64>> = inbound
            .leases()
            .leases()
            .map(|r| r.holder.clone())
            .collect::<std::collections::BTreeSet<_>>()
            .into_iter()
            .filter(|s| *s != self.site)
            .map(|s| {
                let since = inbound.offline_since(&s, started);
                (s, since)
            })
            .collect();
        let failed_over =
            inbound
                .leases_mut()
                .fail_over(|s| offline.get(s).copied().flatten(), timeout, now);
        // One line per takeover, not per vehicle: a site's whole fleet fails over at once.
        if let Some(first) = failed_over.first() {
            warn!(
                vehicles = failed_over.len(),
                first = %first.vehicle_id,
                term = first.term,
                "command leases taken over: their holder's site has been offline for lease.failover_timeout_ms"
            );
            for r in &failed_over {
                debug!(vehicle = %r.vehicle_id, term = r.term, "command lease taken over");
            }
        }
        made.extend(failed_over);
        made
    }

    fn publish(&self, record: LeaseRecord) {
        self.publish_lease(record);
    }

    fn persist(&self) {
        if self.state_file.as_os_str().is_empty() {
            return;
        }
        let (generation, snapshot) = {
            let inbound = lock(&self.inbound);
            (inbound.leases().generation(), inbound.leases().snapshot())
        };
        if !lock(&self.lease_run).needs_saving(generation) {
            return;
        }
        if let Err(e) = lease_keeper::save(&self.state_file, &snapshot) {
            warn!(error = %e, "command leases not saved");
        }
    }
}

/// What the publishing task sends.
#[derive(Debug)]
enum Outgoing {
    Task(Publication),
    Lease(LeaseRecord),
    Order(Publication),
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
    /// Alarms to publish, apart from the rest so that none waits behind it.
    alarms_out: mpsc::Sender<Publication>,
    session: Session,
    /// The session carrying alarms alone ([`FederationConfig::alarm_link`]).
    alarm_session: Option<Session>,
    stop: CancellationToken,
    tasks: Vec<JoinHandle<()>>,
    // Held for their lifetime: dropping one undeclares it.
    token: Option<LivelinessToken>,
    subscribers: Vec<Subscriber<()>>,
    /// The receiving end of the accepted orders, until the station takes it.
    orders: Mutex<Option<mpsc::Receiver<RelayedOrder>>>,
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
        let alarm_session = if config.alarm_link() {
            // The same endpoints and identity; listening stays with the first session.
            let alarm_config = FederationConfig {
                listen: Vec::new(),
                ..config.clone()
            };
            let z = zenoh_config(&alarm_config, identity.as_ref())?;
            Some(
                zenoh::open(z)
                    .await
                    .map_err(zerr("open the alarm session"))?,
            )
        } else {
            None
        };
        // The epoch tells a remote site that sequence numbers restarted from 1.
        let epoch = u64::try_from(now_ms()).unwrap_or(0);
        let (catchup_tx, catchup_rx) = mpsc::channel(CATCHUP_QUEUE);
        let (lease_ask_tx, lease_ask_rx) = mpsc::channel(CATCHUP_QUEUE);
        let (outgoing, outgoing_rx) = mpsc::channel(PUBLISH_QUEUE);
        let (alarms_out, alarms_rx) = mpsc::channel(PUBLISH_QUEUE);
        let (orders_tx, orders_rx) = mpsc::channel(ORDER_QUEUE);
        let (identity_tx, identity_rx) = mpsc::channel(CATCHUP_QUEUE);
        let mut inbound = Inbound::new(&config);
        // End-to-end signatures go with TLS: its key signs, its trusted CAs check.
        let signer = match identity.as_ref().and_then(|id| id.tls.as_ref()) {
            Some(_) => {
                inbound.require_signatures(Box::new(SiteCertificates::load(&config.tls)?));
                Some(Arc::new(SiteSigner::load(&config.tls)?))
            }
            None => None,
        };
        let policy = &config.lease;
        let state_file = policy
            .state_path(&config.site)
            .filter(|_| policy.enabled)
            .unwrap_or_default();
        if !state_file.as_os_str().is_empty() {
            let saved = lease_keeper::load(&state_file)?;
            let taken = inbound.leases_mut().restore(saved);
            info!(file = %state_file.display(), leases = taken, "command leases restored");
        }
        let shared = Arc::new(Shared {
            inbound: Mutex::new(inbound),
            outbound: Mutex::new(Outbound::new(&config, epoch)),
            changed: watch::Sender::new(0),
            catchup: catchup_tx,
            lease_run: Mutex::new(LeaseRun::new(config.lease.clone(), &config.remote_sites)),
            lease_enabled: config.lease.enabled,
            lease_ask: lease_ask_tx,
            site: config.site.clone(),
            state_file,
            outgoing: outgoing.clone(),
            orders: orders_tx,
            signer: signer.clone(),
            identity_ask: identity_tx,
            pacer: config
                .link_shaping()
                .map(|s| Mutex::new(Pacer::new(s.bulk_bytes_per_s, Instant::now()))),
        });
        let site = config.site.clone();

        let mut subscribers = Vec::new();
        for (on, pattern) in [
            (&session, format!("{ROOT}/*/vehicles/*/position")),
            (
                alarm_session.as_ref().unwrap_or(&session),
                format!("{ROOT}/*/alarms"),
            ),
            (&session, format!("{ROOT}/*/tasks/*")),
            (&session, format!("{ROOT}/*/leases/*")),
            // Whatever this site's own mode: a site that sends none may still read others'.
            (&session, format!("{ROOT}/*/environment/*")),
        ] {
            let shared = Arc::clone(&shared);
            let sub = on
                .declare_subscriber(pattern)
                .allowed_origin(Locality::Remote)
                .callback(move |sample| shared.receive(&sample))
                .await
                .map_err(zerr("declare a subscriber"))?;
            subscribers.push(sub);
        }
        let orders_sub = {
            let shared = Arc::clone(&shared);
            session
                .declare_subscriber(keys::orders_to(&site))
                .allowed_origin(Locality::Remote)
                .callback(move |sample| shared.order(&sample))
                .await
                .map_err(zerr("declare the order subscriber"))?
        };
        subscribers.push(orders_sub);
        // Each query is stamped on arrival, so that its answer is fitted to the time its
        // asker has left; the queue is bounded, and a query it has no room for is dropped
        // (the asker asks again).
        let (query_tx, query_rx) = mpsc::channel::<(Instant, Query)>(CATCHUP_QUEUE);
        let queryable = {
            let shared = Arc::clone(&shared);
            session
                .declare_queryable(format!("{ROOT}/{site}/catchup/*"))
                .allowed_origin(Locality::Remote)
                .callback(move |query| {
                    if query_tx.try_send((Instant::now(), query)).is_err() {
                        lock(&shared.outbound).catchup_dropped();
                    }
                })
                .await
                .map_err(zerr("declare the catch-up queryable"))?
        };
        let lease_queryable = session
            .declare_queryable(keys::leases(&site))
            .allowed_origin(Locality::Remote)
            .await
            .map_err(zerr("declare the lease queryable"))?;
        let identity_queryable = match &signer {
            Some(_) => Some(
                session
                    .declare_queryable(keys::identity(&site))
                    .allowed_origin(Locality::Remote)
                    .await
                    .map_err(zerr("declare the identity queryable"))?,
            ),
            None => None,
        };
        let alarm_publisher = declare(
            alarm_session.as_ref().unwrap_or(&session),
            keys::alarms(&site),
            config.alarms.qos,
        )
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
        let lease_timeout = Duration::from_millis(config.limits.catchup_timeout_ms);
        let mut tasks = vec![
            tokio::spawn(publish_positions(
                session.clone(),
                Arc::clone(&shared),
                config.clone(),
                stop.clone(),
            )),
            spawn_may_block(publish_alarms(alarm_publisher, alarms_rx, stop.clone())),
            spawn_may_block(publish_sequenced(
                session.clone(),
                site.clone(),
                signer.clone(),
                config.tasks.qos,
                outgoing_rx,
                stop.clone(),
            )),
            spawn_may_block(serve_catchup(
                queryable,
                query_rx,
                Arc::clone(&shared),
                config.limits.catchup_replies,
                stop.clone(),
            )),
            spawn_may_block(ask_catchup(
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
        if let (Some(signer), Some(queryable)) = (&signer, identity_queryable) {
            tasks.push(spawn_may_block(serve_identity(
                queryable,
                signer.identity().to_vec(),
                stop.clone(),
            )));
            tasks.push(spawn_may_block(ask_identities(
                session.clone(),
                Arc::clone(&shared),
                identity_rx,
                lease_timeout,
                stop.clone(),
            )));
        }
        if config.environment.mode == EnvironmentMode::Aggregated {
            tasks.push(spawn_may_block(publish_environment(
                session.clone(),
                Arc::clone(&shared),
                config.environment.qos,
                stop.clone(),
            )));
        }
        if config.lease.enabled {
            let (answers, takes, done, up, served) = (
                Arc::clone(&shared),
                Arc::clone(&shared),
                Arc::clone(&shared),
                Arc::clone(&shared),
                site.clone(),
            );
            let ask_part = config.link_shaping().map_or(lease_keeper::ASK_PART, |s| {
                s.part_items(
                    crate::config::LEASE_ITEM_BYTES,
                    config.limits.catchup_timeout_ms,
                    lease_keeper::ASK_PART,
                )
            });
            tasks.push(spawn_may_block(lease_keeper::serve(
                lease_queryable,
                served,
                signer.clone(),
                Arc::clone(&shared),
                move || {
                    lock(&answers.inbound)
                        .leases()
                        .granted_here()
                        .cloned()
                        .collect()
                },
                stop.clone(),
            )));
            tasks.push(spawn_may_block(lease_keeper::ask(
                session.clone(),
                lease_ask_rx,
                lease_keeper::Parts {
                    timeout: lease_timeout,
                    part: ask_part,
                },
                move |key, payload| takes.lease_reply(key, payload),
                move |site| lock(&done.lease_run).answered(site),
                move |site| lock(&up.inbound).offline_since(site, 0).is_none(),
                stop.clone(),
            )));
            let keeper: Arc<dyn Keeper> = Arc::clone(&shared) as Arc<dyn Keeper>;
            tasks.push(tokio::spawn(lease_keeper::keep(keeper, stop.clone())));
        }
        let mechanisms = identity.as_ref().map_or("none", |id| id.mechanisms());
        let encrypted = identity.as_ref().is_some_and(|id| id.encrypted());
        info!(
            site = %site,
            epoch,
            zid = %session.zid(),
            alarm_link = alarm_session.is_some(),
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
            alarms_out,
            session,
            alarm_session,
            stop,
            tasks,
            token: Some(token),
            subscribers,
            orders: Mutex::new(Some(orders_rx)),
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

    /// Takes a local vehicle position; it crosses when its vehicle is next due. The
    /// vehicle counts as this site's own: its command lease is claimed here once settled.
    pub fn push_position(&self, position: VehiclePosition) -> Result<(), PushError> {
        lock(&self.shared.lease_run).own(&position.vehicle_id);
        lock(&self.shared.outbound).position(position).map(|_| ())
    }

    /// Whether this station may command `vehicle` (one of its own) now: the term of the
    /// lease it holds (0 with `lease.enabled = false`). A vehicle no site holds is claimed
    /// here, once the site has settled.
    pub fn may_command(&self, vehicle: &str) -> Result<u64, CommandDenied> {
        let mut run = lock(&self.shared.lease_run);
        if !run.policy.enabled {
            return Ok(0);
        }
        let known = lock(&self.shared.inbound).leases().lease(vehicle).cloned();
        if let Some(r) = known {
            if r.holder == self.site {
                return Ok(r.term);
            }
            return Err(CommandDenied::HeldElsewhere {
                vehicle: vehicle.to_owned(),
                holder: r.holder,
                term: r.term,
            });
        }
        if !run.settled() {
            return Err(CommandDenied::NotSettled {
                vehicle: vehicle.to_owned(),
                waited_ms: run.waited_ms(),
                settle_ms: run.policy.settle_ms,
            });
        }
        if !run.policy.home {
            return Err(CommandDenied::NoLease(vehicle.to_owned()));
        }
        drop(run);
        let claimed = lock(&self.shared.inbound)
            .leases_mut()
            .claim(vehicle, now_ms());
        match claimed {
            Some(r) => {
                let term = r.term;
                self.shared.publish_lease(r);
                Ok(term)
            }
            None => Err(CommandDenied::Full(vehicle.to_owned())),
        }
    }

    /// Hands the lease of a vehicle this site holds to site `to`.
    pub fn hand_over(&self, vehicle: &str, to: &str) -> Result<LeaseRecord, HandoverError> {
        let record = lock(&self.shared.inbound)
            .leases_mut()
            .hand_over(vehicle, to, now_ms())?;
        self.shared.publish_lease(record.clone());
        Ok(record)
    }

    /// Every command lease this site knows.
    pub fn leases(&self) -> Vec<LeaseRecord> {
        lock(&self.shared.inbound)
            .leases()
            .leases()
            .cloned()
            .collect()
    }

    /// The lease counters.
    pub fn lease_counters(&self) -> crate::lease::LeaseCounters {
        lock(&self.shared.inbound).leases().counters().clone()
    }

    /// Whether the command lease is in force (`lease.enabled`).
    pub fn lease_enabled(&self) -> bool {
        self.shared.lease_enabled
    }

    /// Sends `task` to the home site of its vehicle, another site's vehicle whose command
    /// lease this site holds, for that site's station to publish to the vehicle as it is.
    /// The task must carry this site's lease (`lease_term` = the term held,
    /// `lease_holder` = this site). Published at once, reliably; not caught up after an
    /// outage (the sender follows the task through the home site's task transitions).
    pub fn relay_order(&self, task: &TaskAssignment) -> Result<(), OrderError> {
        let enabled = self.shared.lease_enabled;
        let lease = lock(&self.shared.inbound)
            .leases()
            .lease(&task.vehicle_id)
            .cloned();
        orders::check_relay(&self.site, enabled, lease.as_ref(), task)?;
        // check_relay found the lease, naming the home.
        let home = lease.map(|l| l.home).unwrap_or_default();
        // A place in the queue first, so that an order with no room uses no number.
        let permit = self.outgoing.try_reserve().map_err(|e| match e {
            mpsc::error::TrySendError::Full(()) => {
                lock(&self.shared.outbound).queue_full();
                OrderError::QueueFull
            }
            mpsc::error::TrySendError::Closed(()) => OrderError::Stopped,
        })?;
        let publication = lock(&self.shared.outbound)
            .order(task, &home)
            .map_err(|e| match e {
                PushError::Invalid(e) => OrderError::Invalid(e),
            })?;
        info!(task = %task.task_id, vehicle = %task.vehicle_id, term = task.lease_term, "order sent to the vehicle's home site");
        permit.send(Outgoing::Order(publication));
        Ok(())
    }

    /// The orders this site accepted, as the vehicle's home, from the sites holding its
    /// vehicles' leases: the first call gets the receiver, later ones `None`. Until it is
    /// taken (and whenever it is not read) at most 256 wait; further ones are refused and
    /// counted (`order_queue_full`).
    pub fn take_orders(&self) -> Option<mpsc::Receiver<RelayedOrder>> {
        lock(&self.orders).take()
    }

    /// Takes a local alarm; it crosses at once (if its severity crosses).
    pub fn push_alarm(&self, alarm: &Event) -> Result<(), PushError> {
        let publication = lock(&self.shared.outbound).alarm(alarm)?;
        if let Some(p) = publication
            && self.alarms_out.try_send(p).is_err()
        {
            // It is in the journal: remote sites see the gap and catch up on it.
            lock(&self.shared.outbound).queue_full();
            warn!(site = %self.site, "federation alarm queue full");
        }
        Ok(())
    }

    /// Takes an environment observation the station accepted: with
    /// `environment.mode = "aggregated"` it is folded into its vehicle's summary of the
    /// current window (if its property is listed), which crosses when the window ends;
    /// with `off`, nothing is done. Refused only when invalid (and aggregated).
    pub fn push_observation(&self, observation: &EnvironmentObservation) -> Result<(), PushError> {
        lock(&self.shared.outbound).observation(observation, now_ms())
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
    ///
    /// `read` runs with the picture locked: it must not call back into this federation
    /// (the lease state is locked before the picture, so calling, say,
    /// [`Self::may_command`] from `read` could deadlock with the lease keeper, which holds
    /// the lease state and waits for the picture).
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
        if let Some(s) = self.alarm_session.take() {
            s.close().await.map_err(ShutdownError::Close)?;
        }
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

/// Runs a task whose Zenoh calls may block on a thread of its own.
///
/// Zenoh resolves a put, a reply or a query synchronously, `.await` included: under
/// congestion control `Block` it waits for room in the link's queue, up to Zenoh's
/// `wait_before_close` (5 s), holding its thread. On one of the runtime's workers (two on a
/// small machine) a stalled link would stall the station with it.
fn spawn_may_block<F>(task: F) -> JoinHandle<()>
where
    F: Future<Output = ()> + Send + 'static,
{
    let runtime = tokio::runtime::Handle::current();
    tokio::task::spawn_blocking(move || runtime.block_on(task))
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

/// How often the environment publisher looks for windows that ended: a summary leaves at
/// most this long after its window's end (windows are 5 s at least).
const ENVIRONMENT_TICK: Duration = Duration::from_millis(500);

/// Publishes each vehicle's environment summaries when its window ends, with the
/// environment's QoS (by default the lowest priority, dropped on congestion: the next
/// window's summary replaces a lost one, and nothing is caught up). Windows still open at
/// shutdown are not sent.
async fn publish_environment(
    session: Session,
    shared: Arc<Shared>,
    qos: Qos,
    stop: CancellationToken,
) {
    let mut interval = tokio::time::interval(ENVIRONMENT_TICK);
    interval.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            () = stop.cancelled() => break,
            _ = interval.tick() => {}
        }
        // The wall clock: a window's bounds cross as timestamps.
        let due = lock(&shared.outbound).due_environment(now_ms());
        for p in due {
            let result = session
                .put(&p.key, p.frame)
                .priority(priority(qos.priority))
                .congestion_control(congestion(qos.congestion))
                .express(qos.express)
                .allowed_destination(Locality::Remote)
                .await;
            if let Err(e) = result {
                warn!(key = %p.key, error = %e, "environment summary not published");
            }
        }
    }
}

/// Publishes alarms in the order they were numbered, on their own queue (and, with
/// `alarms.own_link`, their own session): none waits behind a lease record or a task.
async fn publish_alarms(
    alarms: Publisher<'static>,
    mut queue: mpsc::Receiver<Publication>,
    stop: CancellationToken,
) {
    loop {
        let p = tokio::select! {
            () = stop.cancelled() => break,
            p = queue.recv() => match p { Some(p) => p, None => break },
        };
        if let Err(e) = alarms.put(p.frame).await {
            // Still in the journal: a remote site catches up on it.
            warn!(error = %e, "alarm not published");
        }
    }
}

/// Publishes task transitions, lease records and orders in the order they were made.
async fn publish_sequenced(
    session: Session,
    site: String,
    signer: Option<Arc<SiteSigner>>,
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
            Outgoing::Lease(r) => match crate::wire::encode_lease(&r) {
                Ok(frame) => {
                    let key = keys::lease(&site, &r.vehicle_id);
                    let Some(frame) = sealed(signer.as_deref(), &key, frame) else {
                        continue;
                    };
                    session
                        .put(key, frame)
                        .priority(priority(task_qos.priority))
                        .congestion_control(congestion(task_qos.congestion))
                        .allowed_destination(Locality::Remote)
                        .await
                }
                Err(e) => {
                    warn!(vehicle = %r.vehicle_id, error = %e, "lease record not encodable");
                    Ok(())
                }
            },
            Outgoing::Task(p) => {
                session
                    .put(p.key, p.frame)
                    .priority(priority(task_qos.priority))
                    .congestion_control(congestion(task_qos.congestion))
                    .express(task_qos.express)
                    .allowed_destination(Locality::Remote)
                    .await
            }
            // The tasks' priority, but never dropped on congestion whatever `tasks.qos`
            // says: an order is not caught up, so a dropped one would be lost unseen.
            Outgoing::Order(p) => {
                let Some(frame) = sealed(signer.as_deref(), &p.key, p.frame) else {
                    continue;
                };
                session
                    .put(p.key, frame)
                    .priority(priority(task_qos.priority))
                    .congestion_control(zenoh::qos::CongestionControl::Block)
                    .express(task_qos.express)
                    .allowed_destination(Locality::Remote)
                    .await
            }
        };
        if let Err(e) = result {
            // Still in the journal (except an order): a remote site catches up on it.
            warn!(error = %e, "transition, lease record or order not published");
        }
    }
}

/// Answers `shoal/<site>/identity` with this site's identity frame.
async fn serve_identity(
    queryable: Queryable<zenoh::handlers::FifoChannelHandler<Query>>,
    frame: Vec<u8>,
    stop: CancellationToken,
) {
    loop {
        let query = tokio::select! {
            () = stop.cancelled() => break,
            q = queryable.recv_async() => match q { Ok(q) => q, Err(_) => break },
        };
        let key = query.key_expr().clone();
        if let Err(e) = query.reply(key, frame.clone()).await {
            warn!(error = %e, "identity reply not sent");
        }
    }
}

/// Asks `selector` at `data_high`, above positions (the replies travel at the query's
/// priority: at Zenoh's default they would queue behind a link's worth of positions),
/// blocking rather than dropped on congestion, every reply kept.
pub(crate) async fn ask_above_positions(
    session: &Session,
    selector: &str,
    timeout: Duration,
) -> zenoh::Result<zenoh::handlers::FifoChannelHandler<zenoh::query::Reply>> {
    session
        .get(selector)
        .consolidation(ConsolidationMode::None)
        .priority(zenoh::qos::Priority::DataHigh)
        .congestion_control(zenoh::qos::CongestionControl::Block)
        .timeout(timeout)
        .await
}

/// Wait before asking again for a certificate that samples wait for.
const IDENTITY_RETRY: Duration = Duration::from_secs(2);

/// Asks remote sites for their identity, one at a time; asks again after
/// [`IDENTITY_RETRY`] while samples wait for it and the site is online.
async fn ask_identities(
    session: Session,
    shared: Arc<Shared>,
    mut sites: mpsc::Receiver<String>,
    timeout: Duration,
    stop: CancellationToken,
) {
    loop {
        let site = tokio::select! {
            () = stop.cancelled() => break,
            s = sites.recv() => match s { Some(s) => s, None => break },
        };
        // Above positions: lease records and orders wait for it.
        let replies = match ask_above_positions(&session, &keys::identity(&site), timeout).await {
            Ok(r) => r,
            Err(e) => {
                warn!(site, error = %e, "identity query not sent");
                continue;
            }
        };
        let mut taken = false;
        while let Ok(reply) = tokio::select! {
            () = stop.cancelled() => return,
            r = replies.recv_async() => r,
        } {
            if let Ok(sample) = reply.result()
                && !taken
            {
                taken = shared.identity(&site, &sample.payload().to_bytes());
            }
        }
        if taken {
            continue;
        }
        let waiting = lock(&shared.inbound).identity_unanswered(&site);
        let online = lock(&shared.inbound).offline_since(&site, 0).is_none();
        debug!(site, waiting, online, "identity query unanswered");
        if waiting && online {
            let again = shared.identity_ask.clone();
            tokio::spawn(async move {
                tokio::time::sleep(IDENTITY_RETRY).await;
                let _ = again.try_send(site);
            });
        }
    }
}

/// Answers catch-up queries from the outbound journals, each within half its asker's
/// `wait=` from when it arrived (the other half is for the way across the link): on a
/// paced link the frames that would leave later are not sent. Every answer ends with its
/// end frame, which tells the asker how far the stream goes, so it asks for the rest.
async fn serve_catchup(
    _queryable: Queryable<()>,
    mut queries: mpsc::Receiver<(Instant, Query)>,
    shared: Arc<Shared>,
    limit: usize,
    stop: CancellationToken,
) {
    loop {
        let (arrived, query) = tokio::select! {
            () = stop.cancelled() => break,
            q = queries.recv() => match q { Some(q) => q, None => break },
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
        let deadline = params
            .get("wait")
            .and_then(|v| v.parse::<u64>().ok())
            .map(|ms| arrived + Duration::from_millis(ms.clamp(1, MAX_WAIT_MS)) / 2);
        let frames = lock(&shared.outbound).catchup(stream, epoch, after, asked);
        let key_len = query.key_expr().as_str().len();
        let (found, mut sent) = (frames.len(), 0);
        for frame in frames {
            if !shared.pace_by(frame.len() + key_len, deadline).await {
                break;
            }
            if let Err(e) = query.reply(query.key_expr().clone(), frame).await {
                warn!(error = %e, "catch-up reply not sent");
                break;
            }
            sent += 1;
        }
        // The end goes whatever the time: it is small, and says what is left.
        let end = {
            let mut outbound = lock(&shared.outbound);
            outbound.catchup_answered(sent, sent < found);
            outbound.catchup_end(stream)
        };
        if let Some(end) = end {
            shared.pace(end.len() + key_len).await;
            if let Err(e) = query.reply(query.key_expr().clone(), end).await {
                warn!(error = %e, "catch-up end not sent");
            }
        }
        debug!(
            stream = stream.as_str(),
            after,
            found,
            sent,
            since_arrival_ms = (Instant::now() - arrived).as_millis(),
            "catch-up served"
        );
    }
}

/// The longest `wait=` a catch-up query may ask for (`limits.catchup_timeout_ms`'s bound).
const MAX_WAIT_MS: u64 = 600_000;

/// How catch-up queries are sent: each with its stream's QoS (the replies travel with the
/// query's priority and congestion control), and how long each waits.
#[derive(Debug, Clone, Copy)]
struct CatchupQos {
    alarms: Qos,
    tasks: Qos,
    timeout: Duration,
}

/// The priority of a catch-up query and its replies: the stream's, but at most
/// `data_high`. Catch-up is history: behind a site's live alarms and transitions, which
/// would otherwise queue behind a whole outage's worth of it, and ahead of positions.
fn catchup_priority(stream: Priority) -> Priority {
    if stream < Priority::DataHigh {
        Priority::DataHigh
    } else {
        stream
    }
}

/// Wait before asking again for what an incomplete answer did not bring.
const CATCHUP_RETRY: Duration = Duration::from_secs(2);

/// Every remote site's streams are asked for what they have every so many catch-up waits
/// (30 s by default; [`Inbound::poll_catchup`]).
const POLL_WAITS: u32 = 3;

/// A remote site whose answers keep coming incomplete is waited for up to this many
/// times `limits.catchup_timeout_ms` ([`Waits`]).
pub(crate) const MAX_WAIT_FACTOR: u32 = 4;

/// Asks remote sites for what this site missed: one query at a time per remote site, each
/// for at most `limits.catchup_batch` frames and waited for as long as that site needs
/// ([`Waits`]). What follows an answer is [`CatchupOutcome`]'s: the next part at once, the
/// same query again after [`CATCHUP_RETRY`] (while the site is online), or nothing.
/// Every online site is also polled now and then: nothing else would ask for a gap no
/// later frame reveals.
async fn ask_catchup(
    session: Session,
    shared: Arc<Shared>,
    mut requests: mpsc::Receiver<CatchupRequest>,
    qos: CatchupQos,
    stop: CancellationToken,
) {
    let every = qos.timeout * POLL_WAITS;
    let mut poll = tokio::time::interval_at(Instant::now() + every, every);
    poll.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut waits = Waits::new(qos.timeout, qos.timeout * MAX_WAIT_FACTOR);
    let mut ready: VecDeque<CatchupRequest> = VecDeque::new();
    let mut retries: Vec<(Instant, String, Stream)> = Vec::new();
    let mut asking = FuturesUnordered::new();
    let mut busy: HashSet<String> = HashSet::new();
    loop {
        while let Some(i) = ready.iter().position(|r| !busy.contains(&r.site)) {
            let Some(request) = ready.remove(i) else {
                break;
            };
            busy.insert(request.site.clone());
            let wait = waits.of(&request.site);
            asking.push(ask_one(
                session.clone(),
                Arc::clone(&shared),
                request,
                CatchupQos {
                    timeout: wait,
                    ..qos
                },
                stop.clone(),
            ));
        }
        let due = retries.iter().map(|r| r.0).min();
        tokio::select! {
            () = stop.cancelled() => break,
            r = requests.recv() => match r {
                Some(r) => ready.push_back(r),
                None => break,
            },
            Some((request, outcome, took)) = asking.next(), if !asking.is_empty() => {
                busy.remove(&request.site);
                waits.answered(&request.site, outcome != CatchupOutcome::Retry, took);
                match outcome {
                    CatchupOutcome::Done => {}
                    CatchupOutcome::More(next) => ready.push_front(next),
                    CatchupOutcome::Retry => {
                        if !retries
                            .iter()
                            .any(|r| r.1 == request.site && r.2 == request.stream)
                        {
                            retries.push((
                                Instant::now() + CATCHUP_RETRY,
                                request.site,
                                request.stream,
                            ));
                        }
                    }
                }
            }
            _ = poll.tick() => ready.extend(lock(&shared.inbound).poll_catchup()),
            () = sleep_until_due(due) => {
                let now = Instant::now();
                let (due, later): (Vec<_>, Vec<_>) =
                    retries.drain(..).partition(|r| r.0 <= now);
                retries = later;
                let mut inbound = lock(&shared.inbound);
                ready.extend(
                    due.into_iter()
                        .filter_map(|(_, site, stream)| inbound.retry_catchup(&site, stream)),
                );
            }
        }
    }
}

/// Sleeps until `due`, or for ever when nothing is due.
pub(crate) async fn sleep_until_due(due: Option<Instant>) {
    match due {
        Some(at) => tokio::time::sleep_until(at).await,
        None => std::future::pending().await,
    }
}

/// Asks one catch-up query (waiting `qos.timeout`) and takes its answer; how long it took.
async fn ask_one(
    session: Session,
    shared: Arc<Shared>,
    request: CatchupRequest,
    qos: CatchupQos,
    stop: CancellationToken,
) -> (CatchupRequest, CatchupOutcome, Duration) {
    let stream_qos = match request.stream {
        Stream::Alarms => qos.alarms,
        Stream::Tasks => qos.tasks,
    };
    let mut selector = format!(
        "{}?after={};limit={};wait={}",
        keys::catchup(&request.site, request.stream),
        request.after,
        request.limit,
        qos.timeout.as_millis()
    );
    if let Some(epoch) = request.epoch {
        selector.push_str(&format!(";epoch={epoch}"));
    }
    let started = Instant::now();
    // Every reply has the same key: without this Zenoh would keep only the last.
    let replies = session
        .get(&selector)
        .consolidation(ConsolidationMode::None)
        .priority(priority(catchup_priority(stream_qos.priority)))
        .congestion_control(congestion(stream_qos.congestion))
        .timeout(qos.timeout)
        .await;
    let replies = match replies {
        Ok(r) => r,
        Err(e) => {
            warn!(selector, error = %e, "catch-up query not sent");
            lock(&shared.inbound).abandon_catchup(&request);
            return (request, CatchupOutcome::Retry, started.elapsed());
        }
    };
    let (mut taken, mut answered) = (0u64, 0usize);
    loop {
        let reply = tokio::select! {
            () = stop.cancelled() => break,
            r = replies.recv_async() => match r { Ok(r) => r, Err(_) => break },
        };
        answered += 1;
        match reply.result() {
            Ok(sample) => {
                let key = sample.key_expr().as_str();
                let payload = sample.payload().to_bytes();
                let result =
                    lock(&shared.inbound).receive_catchup(&request, key, &payload, now_ms());
                if result.is_ok() && !crate::wire::is_catchup_end(&payload) {
                    taken += 1;
                }
            }
            // Among them Zenoh's own when the wait ran out.
            Err(e) => debug!(selector, error = ?e, "catch-up error reply"),
        }
    }
    let outcome = lock(&shared.inbound).finish_catchup(&request);
    if taken > 0 {
        shared.changed.send_modify(|n| *n += 1);
    }
    debug!(
        site = %request.site,
        stream = request.stream.as_str(),
        taken,
        answered,
        outcome = match outcome {
            CatchupOutcome::Done => "done",
            CatchupOutcome::More(_) => "more",
            CatchupOutcome::Retry => "retry",
        },
        wait_ms = qos.timeout.as_millis(),
        ms = started.elapsed().as_millis(),
        "catch-up done"
    );
    (request, outcome, started.elapsed())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn catch_up_travels_below_live_alarms_and_transitions_and_above_positions() {
        assert_eq!(catchup_priority(Priority::RealTime), Priority::DataHigh);
        assert_eq!(
            catchup_priority(Priority::InteractiveHigh),
            Priority::DataHigh
        );
        assert_eq!(catchup_priority(Priority::DataHigh), Priority::DataHigh);
        // A stream configured lower keeps its own.
        assert_eq!(catchup_priority(Priority::Background), Priority::Background);
        assert!(catchup_priority(Priority::RealTime) < Priority::Data);
    }
}
