//! The station on the bus: the core ([`StationHandle`]) fed by the Publish/Subscribe
//! Manager's subscriptions, publishing through its writers, with the once-a-second work
//! (contact, task expiry, time rules, the log summary) and a clean shutdown.

use std::sync::Arc;
use std::time::Duration;

use futures::StreamExt;
use serde::Serialize;
use shoal_dds::{ParticipantEvent, PubSub, SampleMeta, Subscription, TopicType};
use shoal_history::History;
use shoal_model::{
    EnvironmentObservation, Event, StateVector, TaskStatus, Validated, VehicleAnnouncement,
};
use tokio_util::sync::CancellationToken;
use tracing::{info, warn};

use crate::bus::DdsOutbox;
use crate::clock::Clock;
use crate::config::StationConfig;
use crate::core::StationHandle;
use crate::error::StationError;
use crate::ingest::{FLUSH_STEP, IngestStats};

/// The station core on DDS, ready to run.
pub struct Station {
    handle: StationHandle,
    dds: Arc<PubSub>,
    history: History,
}

impl std::fmt::Debug for Station {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Station")
            .field("dds", &self.dds)
            .finish_non_exhaustive()
    }
}

/// What the station did, returned when it stops.
#[derive(Debug, Clone, Serialize)]
pub struct StationReport {
    /// Final counters.
    pub stats: IngestStats,
    /// Records committed to the history store over the run.
    pub history_committed: u64,
}

/// What one subscription hands the core.
type Deliver<T> = fn(&StationHandle, Validated<T>, &SampleMeta, &str);

impl Station {
    /// Creates the station's DDS writers and loads what it knew before a restart.
    pub fn new(
        config: StationConfig,
        dds: Arc<PubSub>,
        history: History,
    ) -> Result<Self, StationError> {
        Self::with_clock(config, dds, history, Clock::system())
    }

    /// [`Self::new`] on a given clock (a benchmark steps its system clock).
    pub fn with_clock(
        config: StationConfig,
        dds: Arc<PubSub>,
        history: History,
        clock: Clock,
    ) -> Result<Self, StationError> {
        let outbox = Arc::new(DdsOutbox::new(&dds)?);
        let handle = StationHandle::with_clock(config, &history, outbox, clock)?;
        Ok(Self {
            handle,
            dds,
            history,
        })
    }

    /// A handle for the API; valid while the station runs.
    pub fn handle(&self) -> StationHandle {
        self.handle.clone()
    }

    /// Runs until `shutdown` is cancelled, then drains and closes the history store.
    pub async fn run(self, shutdown: CancellationToken) -> Result<StationReport, StationError> {
        let h = self.handle();
        let own = self.dds.participant_id();
        let mut tasks = tokio::task::JoinSet::new();
        let on_state: Deliver<StateVector> = |h, s, _, _| h.ingest_bus_state(s);
        let on_announcement: Deliver<VehicleAnnouncement> =
            |h, a, meta, _| h.ingest_announcement(a, &meta.writer, &meta.participant);
        let on_status: Deliver<TaskStatus> = |h, s, _, _| {
            let _ = h.ingest_task_status(s);
        };
        let on_event: Deliver<Event> = |h, e, meta, own| {
            // The station hears its own events (alarms, rule firings) on the same topic;
            // they are recorded already.
            if meta.participant != own {
                let _ = h.ingest_event(e);
            }
        };
        let on_observation: Deliver<EnvironmentObservation> = |h, o, _, _| {
            let _ = h.ingest_observation(o);
        };
        let (d, c, o) = (&self.dds, &shutdown, &own);
        tasks.spawn(consume(
            d.subscribe()?,
            h.clone(),
            c.clone(),
            o.clone(),
            on_state,
        ));
        tasks.spawn(consume(
            d.subscribe()?,
            h.clone(),
            c.clone(),
            o.clone(),
            on_announcement,
        ));
        tasks.spawn(consume(
            d.subscribe()?,
            h.clone(),
            c.clone(),
            o.clone(),
            on_status,
        ));
        tasks.spawn(consume(
            d.subscribe()?,
            h.clone(),
            c.clone(),
            o.clone(),
            on_event,
        ));
        tasks.spawn(consume(
            d.subscribe()?,
            h.clone(),
            c.clone(),
            o.clone(),
            on_observation,
        ));
        info!(participant = %own, "station running");
        h.resume_missions();

        let summary_every = Duration::from_secs_f64(h.config().summary_interval_s.max(0.0));
        let mut last_summary = tokio::time::Instant::now();
        let mut tick = tokio::time::interval(Duration::from_secs(1));
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
        let mut flush = tokio::time::interval(FLUSH_STEP);
        flush.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
        loop {
            tokio::select! {
                () = shutdown.cancelled() => break,
                _ = flush.tick() => h.semantic_flush_step(h.now()),
                _ = tick.tick() => {
                    for ev in self.dds.participant_events() {
                        log_participant_event(&ev);
                        if let ParticipantEvent::Lost { participant, reason } = &ev {
                            h.participant_left(participant, reason);
                        }
                    }
                    h.tick(h.now());
                    if !summary_every.is_zero() && last_summary.elapsed() >= summary_every {
                        last_summary = tokio::time::Instant::now();
                        h.log_summary();
                    }
                }
            }
        }
        info!("station stopping: draining subscriptions and history");
        while tasks.join_next().await.is_some() {}
        let stats = h.stats();
        drop(h);
        drop(self.handle);
        let history = self.history;
        let closed = tokio::task::spawn_blocking(move || history.close())
            .await
            .map_err(StationError::Shutdown)?
            .map_err(StationError::History)?;
        info!(committed = closed.committed_rows, "history closed");
        Ok(StationReport {
            stats,
            history_committed: closed.committed_rows,
        })
    }
}

impl StationHandle {
    /// The once-a-second work at `now`: contact, task expiry, time rules, availability
    /// (faults age out).
    pub(crate) fn tick(&self, now: i64) {
        self.watch_clock();
        self.expire_early_states(now);
        self.refresh_contact(now);
        self.expire_tasks(now);
        self.prune_tasks(now);
        self.semantic_tick(now);
        self.traffic_tick(now);
        self.refresh_availability_all(now);
    }
}

impl StationHandle {
    /// Warns when the system clock moves away from station time by more than a second
    /// since the last warning: station time does not follow it until a restart.
    fn watch_clock(&self) {
        use std::sync::atomic::Ordering;
        let skew = self.clock_skew_ms();
        let reported = self.core.reported_skew_ms.load(Ordering::Relaxed);
        if (skew - reported).abs() > 1_000 {
            self.core.reported_skew_ms.store(skew, Ordering::Relaxed);
            warn!(
                skew_s = skew / 1000,
                "the system clock moved away from station time; timeouts and timestamps keep \
                 station time (monotonic) until the station restarts"
            );
        }
    }
}

/// Hands every sample of `sub` to the core until shutdown; read errors are counted there.
async fn consume<T: TopicType>(
    mut sub: Subscription<T>,
    h: StationHandle,
    shutdown: CancellationToken,
    own: String,
    deliver: Deliver<T>,
) {
    loop {
        let item = tokio::select! {
            () = shutdown.cancelled() => return,
            item = sub.next() => item,
        };
        match item {
            None => return,
            Some(Ok((sample, meta))) => deliver(&h, sample, &meta, &own),
            Some(Err(e)) => h.on_read_error::<T>(&e),
        }
    }
}

fn log_participant_event(ev: &ParticipantEvent) {
    match ev {
        ParticipantEvent::Discovered { participant, name } => {
            info!(%participant, name = name.as_deref().unwrap_or("-"), "DDS participant discovered");
        }
        ParticipantEvent::Lost {
            participant,
            reason,
        } => {
            info!(%participant, %reason, "DDS participant lost");
        }
        ParticipantEvent::IncompatibleWriter { writer, detail } => {
            warn!(%writer, %detail, "a remote writer's QoS cannot serve the station; it will not be heard");
        }
        ParticipantEvent::IncompatibleReader { reader, detail } => {
            warn!(%reader, %detail, "a remote reader's QoS cannot be served by the station");
        }
        _ => {}
    }
}
