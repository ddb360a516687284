//! The bridge: subscribes to every Shoal topic on the station's participant and logs
//! each sample to its Foxglove channel, served by the Foxglove SDK's WebSocket server on
//! an ephemeral loopback port that only the station's gateway reaches.

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use foxglove::schemas::LocationFix;
use foxglove::{
    Channel, Context, PartialMetadata, RawChannel, WebSocketServer, WebSocketServerHandle,
};
use futures::StreamExt;
use shoal_dds::{PubSub, Subscription, TopicType};
use shoal_model::{
    EnvironmentObservation, Event, StateVector, TaskAssignment, TaskStatus, VehicleAnnouncement,
};
use tokio::sync::Semaphore;
use tokio::task::JoinSet;
use tokio_util::sync::CancellationToken;
use tracing::{debug, info, warn};

use crate::BridgeError;
use crate::channels::{self, Limiter};
use crate::config::{BridgeConfig, RateLimit};

/// Counters of what the bridge did, for logs, metrics and tests.
#[derive(Debug, Default)]
pub struct BridgeStats {
    /// Samples logged to a channel with at least one subscriber.
    pub logged: AtomicU64,
    /// Samples skipped by a rate limit.
    pub rate_limited: AtomicU64,
    /// Samples that could not be encoded or were refused by the bus (malformed, invalid).
    pub bad_samples: AtomicU64,
    /// Clients dropped because they read too slowly.
    pub slow_clients_dropped: AtomicU64,
    /// Clients refused because `max_clients` were connected.
    pub clients_refused: AtomicU64,
    /// Clients served so far.
    pub clients_served: AtomicU64,
}

/// What the bridge's handle shares with its tasks and gateways.
#[derive(Debug)]
pub(crate) struct Shared {
    pub(crate) config: BridgeConfig,
    pub(crate) internal: SocketAddr,
    pub(crate) places: Arc<Semaphore>,
    pub(crate) stats: BridgeStats,
    pub(crate) cancel: CancellationToken,
}

/// The running bridge. Cheap to clone; the bridge stops when its cancel token fires or
/// [`BridgeHandle::stop`] is called.
#[derive(Clone)]
pub struct BridgeHandle {
    pub(crate) shared: Arc<Shared>,
    server: Arc<std::sync::Mutex<Option<WebSocketServerHandle>>>,
    /// The SDK's server holds its context only weakly: without this, the context would
    /// go with `Bridge::start`'s stack and clients would see no channels.
    _ctx: Arc<Context>,
}

impl std::fmt::Debug for BridgeHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BridgeHandle")
            .field("internal", &self.shared.internal)
            .field("clients", &self.clients())
            .finish_non_exhaustive()
    }
}

/// Starts bridges; see [`Bridge::start`].
#[derive(Debug)]
pub struct Bridge;

impl Bridge {
    /// Subscribes to every Shoal topic on `pubsub`, starts the Foxglove SDK's server on
    /// 127.0.0.1 (ephemeral port) and returns the handle through which clients are
    /// admitted ([`BridgeHandle::admit`], [`BridgeHandle::serve`]). Must be called
    /// within a Tokio runtime; everything stops when `cancel` fires.
    pub async fn start(
        pubsub: Arc<PubSub>,
        config: BridgeConfig,
        cancel: CancellationToken,
    ) -> Result<BridgeHandle, BridgeError> {
        let (handle, ctx) = launch(config, cancel).await?;
        if let Err(e) = handle.spawn_topics(&pubsub, &ctx) {
            handle.stop();
            return Err(e);
        }
        info!(internal = %handle.internal_addr(), "Foxglove bridge running (SDK server on loopback, clients through the console)");
        Ok(handle)
    }
}

/// Starts the SDK's server in a context of its own, and the handle around it.
async fn launch(
    config: BridgeConfig,
    cancel: CancellationToken,
) -> Result<(BridgeHandle, Arc<Context>), BridgeError> {
    config.validate()?;
    // A context of its own: the process-wide default would mix in anything else that
    // logs through the SDK, and two bridges (tests) would share channels.
    let ctx = Context::new();
    let server = WebSocketServer::new()
        .name("Shoal station")
        .context(&ctx)
        .bind("127.0.0.1", 0)
        .message_backlog_size(config.sdk_backlog)
        .tokio_runtime(&tokio::runtime::Handle::current())
        .start()
        .await
        .map_err(|e| BridgeError::Sdk(format!("the WebSocket server: {e}")))?;
    let internal = SocketAddr::from(([127, 0, 0, 1], server.port()));
    let shared = Arc::new(Shared {
        places: Arc::new(Semaphore::new(config.max_clients)),
        config,
        internal,
        stats: BridgeStats::default(),
        cancel: cancel.clone(),
    });
    let handle = BridgeHandle {
        shared,
        server: Arc::new(std::sync::Mutex::new(Some(server))),
        _ctx: Arc::clone(&ctx),
    };
    let stopper = handle.clone();
    tokio::spawn(async move {
        cancel.cancelled().await;
        stopper.stop();
    });
    Ok((handle, ctx))
}

impl BridgeHandle {
    fn spawn_topics(&self, pubsub: &PubSub, ctx: &Arc<Context>) -> Result<(), BridgeError> {
        let rates = &self.shared.config.rates;
        let mut tasks = JoinSet::new();
        let location = channels::location_channel(ctx);
        tasks.spawn(pump(
            pubsub.subscribe::<StateVector>()?,
            channels::topic_channel::<StateVector>(ctx)?,
            rates.state_vector,
            Arc::clone(&self.shared),
            Some(location),
        ));
        tasks.spawn(pump(
            pubsub.subscribe::<VehicleAnnouncement>()?,
            channels::topic_channel::<VehicleAnnouncement>(ctx)?,
            rates.vehicle_announcement,
            Arc::clone(&self.shared),
            None,
        ));
        tasks.spawn(pump(
            pubsub.subscribe::<TaskAssignment>()?,
            channels::topic_channel::<TaskAssignment>(ctx)?,
            rates.task_assignment,
            Arc::clone(&self.shared),
            None,
        ));
        tasks.spawn(pump(
            pubsub.subscribe::<TaskStatus>()?,
            channels::topic_channel::<TaskStatus>(ctx)?,
            rates.task_status,
            Arc::clone(&self.shared),
            None,
        ));
        tasks.spawn(pump(
            pubsub.subscribe::<Event>()?,
            channels::topic_channel::<Event>(ctx)?,
            rates.event,
            Arc::clone(&self.shared),
            None,
        ));
        tasks.spawn(pump(
            pubsub.subscribe::<EnvironmentObservation>()?,
            channels::topic_channel::<EnvironmentObservation>(ctx)?,
            rates.environment,
            Arc::clone(&self.shared),
            None,
        ));
        // The channels live as long as their pumps; the pumps as long as the token.
        tokio::spawn(async move { while tasks.join_next().await.is_some() {} });
        Ok(())
    }

    /// Where the SDK's server listens (loopback only; not for clients: they come through
    /// the console's authenticated `/api/foxglove`).
    pub fn internal_addr(&self) -> SocketAddr {
        self.shared.internal
    }

    /// The settings the bridge runs with.
    pub fn config(&self) -> &BridgeConfig {
        &self.shared.config
    }

    /// What the bridge did so far.
    pub fn stats(&self) -> &BridgeStats {
        &self.shared.stats
    }

    /// Clients connected through the gateway now.
    pub fn clients(&self) -> usize {
        self.shared
            .config
            .max_clients
            .saturating_sub(self.shared.places.available_permits())
    }

    /// Stops the SDK's server and the topic pumps (idempotent).
    pub fn stop(&self) {
        self.shared.cancel.cancel();
        let server = self.server.lock().ok().and_then(|mut s| s.take());
        if let Some(server) = server {
            // Dropping the shutdown handle aborts the client tasks at once, which is what
            // a stopping station wants.
            drop(server.stop());
            debug!("Foxglove SDK server stopped");
        }
    }
}

/// Logs every sample of `sub` to `channel` within `limit` (and, for state vectors, to
/// the LocationFix channel too) until the bridge stops.
async fn pump<T: TopicType>(
    mut sub: Subscription<T>,
    channel: Arc<RawChannel>,
    limit: RateLimit,
    shared: Arc<Shared>,
    location: Option<Channel<LocationFix>>,
) {
    let mut limiter = Limiter::new(limit, Instant::now());
    loop {
        let item = tokio::select! {
            () = shared.cancel.cancelled() => break,
            item = sub.next() => item,
        };
        let Some(item) = item else { break };
        let (sample, _meta) = match item {
            Ok(s) => s,
            Err(e) => {
                shared.stats.bad_samples.fetch_add(1, Ordering::Relaxed);
                debug!(topic = T::TOPIC, error = %e, "sample not bridged");
                continue;
            }
        };
        let sample = sample.into_inner();
        let wanted = channel.has_sinks() || location.as_ref().is_some_and(|l| l.has_sinks());
        if !wanted {
            // Nobody listens: no encoding, and the rate budget is not spent.
            continue;
        }
        let key = serde_key(&sample);
        if !limiter.allow(&key, Instant::now()) {
            shared.stats.rate_limited.fetch_add(1, Ordering::Relaxed);
            continue;
        }
        log_sample(&sample, &channel, location.as_ref(), &shared.stats);
    }
    channel.close();
    if let Some(l) = location {
        l.close();
    }
    debug!(topic = T::TOPIC, "bridge pump ended");
}

/// Encodes and logs one sample; the per-sample work the benchmark measures.
pub(crate) fn log_sample<T: TopicType>(
    sample: &T,
    channel: &RawChannel,
    location: Option<&Channel<LocationFix>>,
    stats: &BridgeStats,
) {
    let time = PartialMetadata::with_log_time(channels::nanos(sample_time(sample)));
    if channel.has_sinks() {
        match channels::encode(sample) {
            Ok(bytes) => {
                channel.log_with_meta(&bytes, time);
                stats.logged.fetch_add(1, Ordering::Relaxed);
            }
            Err(e) => {
                stats.bad_samples.fetch_add(1, Ordering::Relaxed);
                warn!(error = %e, "sample not encodable for Foxglove");
            }
        }
    }
    if let Some(location) = location.filter(|l| l.has_sinks())
        && let Some(state) = as_state(sample)
    {
        location.log_with_meta(&channels::location_fix(state), time);
        stats.logged.fetch_add(1, Ordering::Relaxed);
    }
}

/// The instance key of a sample as text (the limiter's key).
fn serde_key<T: TopicType>(sample: &T) -> String {
    // Keys are strings or pairs of strings; their JSON is unambiguous and cheap.
    serde_json::to_string(&sample.key()).unwrap_or_default()
}

/// The sample's own time (ms since the epoch), which becomes the message's log time.
fn sample_time<T: TopicType>(sample: &T) -> i64 {
    let any: &dyn std::any::Any = sample;
    if let Some(s) = any.downcast_ref::<StateVector>() {
        s.timestamp_ms
    } else if let Some(a) = any.downcast_ref::<VehicleAnnouncement>() {
        a.timestamp_ms
    } else if let Some(t) = any.downcast_ref::<TaskAssignment>() {
        t.issued_ms
    } else if let Some(s) = any.downcast_ref::<TaskStatus>() {
        s.timestamp_ms
    } else if let Some(e) = any.downcast_ref::<Event>() {
        e.timestamp_ms
    } else if let Some(o) = any.downcast_ref::<EnvironmentObservation>() {
        o.timestamp_ms
    } else {
        now_ms()
    }
}

fn as_state<T: TopicType>(sample: &T) -> Option<&StateVector> {
    let any: &dyn std::any::Any = sample;
    any.downcast_ref::<StateVector>()
}

fn now_ms() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| i64::try_from(d.as_millis()).unwrap_or(i64::MAX))
}

/// A bridge without DDS, for the benchmark: the SDK server, the gateway and the
/// state-vector channels, fed by the caller.
#[doc(hidden)]
#[derive(Debug)]
pub struct BenchRig {
    /// The handle: clients connect through its gateway or to its internal address.
    pub handle: BridgeHandle,
    state: Arc<RawChannel>,
    location: Channel<LocationFix>,
}

impl BenchRig {
    /// Starts the server and the two state-vector channels.
    pub async fn start(config: BridgeConfig) -> Result<Self, BridgeError> {
        let (handle, ctx) = launch(config, CancellationToken::new()).await?;
        Ok(Self {
            handle,
            state: channels::topic_channel::<StateVector>(&ctx)?,
            location: channels::location_channel(&ctx),
        })
    }

    /// Encodes and fans out one state vector, as the bridge's pump does.
    pub fn log(&self, state: &StateVector) {
        log_sample(
            state,
            &self.state,
            Some(&self.location),
            &self.handle.shared.stats,
        );
    }
}
