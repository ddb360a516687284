//! The DDS Proxy loop, written once for every [`VehicleAdapter`].
//!
//! [`serve`] holds all the logic (announcing, state rate, task filtering and life cycle,
//! event ids) and talks to DDS only through an [`Outbox`] and a stream of task samples, so
//! it is tested without a network; [`crate::run_proxy`] plugs in the DDS writers and
//! subscription.

use std::collections::HashMap;
use std::future::Future;
use std::path::PathBuf;
use std::time::Duration;

use futures::{Stream, StreamExt};
use shoal_dds::{
    CreateError, Priority, PubSub, ReadError, SampleMeta, WriteError, Writer, WriterOptions,
};
use shoal_model::{
    EnvironmentObservation, Event, MAX_TEXT_LEN, Severity, StateVector, Task, TaskAssignment,
    TaskState, TaskStatus, Validated, ValidationError, VehicleAnnouncement, Warp, now_ms,
};
use tokio::time::{Instant, Interval, MissedTickBehavior};
use tokio_util::sync::CancellationToken;
use tracing::{debug, info, warn};

use crate::adapter::{TaskOrder, TaskUpdate, VehicleAdapter, VehicleEvent, VehicleOutput};
use crate::ledger::{Admission, LedgerError, TaskLedger};

/// Capabilities every vehicle behind [`crate::run_proxy`] has, because the proxy serves them.
pub const PROXY_CAPABILITIES: [&str; 2] = ["request_state", "set_reporting_rate"];

/// How a DDS Proxy runs, whatever the vehicle.
#[derive(Debug, Clone, PartialEq)]
pub struct ProxyOptions {
    /// State vectors per second, (0, 100]; `set_reporting_rate` tasks change it at run time.
    pub state_rate_hz: f64,
    /// How often the announcement is repeated after the first one, so a station that
    /// restarts, or a reader that does not keep history, learns the vehicle again.
    pub announce_interval: Duration,
    /// Tasks that carry no expiry and were issued longer ago than this when they arrive
    /// are refused as expired. `None` takes any age. (Station tasks carry an expiry.)
    pub max_task_age: Option<Duration>,
    /// The directory of the vehicle's task ledger (`<id>.tasks.json`), which makes a task
    /// run at most once across restarts. `None` keeps it in memory only, so a restart
    /// forgets what ran: for tests and tools, never for a vehicle.
    pub ledger_dir: Option<PathBuf>,
    /// The simulated clock of a scenario run (`None`: the system clock). The proxy's
    /// timestamps come from it and its reporting rate is in simulated time, so a vehicle
    /// run ten times as fast reports ten times as often in real time.
    pub clock: Option<Warp>,
}

impl Default for ProxyOptions {
    fn default() -> Self {
        Self {
            state_rate_hz: 1.0,
            announce_interval: Duration::from_secs(60),
            max_task_age: Some(Duration::from_secs(15 * 60)),
            ledger_dir: None,
            clock: None,
        }
    }
}

/// Why a DDS Proxy stopped.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ProxyError<E> {
    /// The DDS writers or the task subscription could not be created.
    #[error("DDS endpoints could not be created: {0}")]
    Dds(#[from] CreateError),
    /// The adapter's announcement is invalid, so the station would never accept the vehicle.
    #[error("the vehicle cannot be announced: {0}")]
    Announcement(ValidationError),
    /// The task ledger cannot be opened: without it a task could run twice.
    #[error("the vehicle's task ledger cannot be used: {0}")]
    Ledger(#[from] LedgerError),
    /// The adapter failed for good.
    #[error("vehicle adapter failed: {0}")]
    Adapter(#[source] E),
}

/// A sample for one of Shoal's topics.
#[derive(Debug, Clone, PartialEq)]
pub(crate) enum Outgoing {
    Announcement(VehicleAnnouncement),
    State(StateVector),
    Status(TaskStatus),
    Event(Event),
    Observation(EnvironmentObservation),
}

/// Where the proxy's samples go: DDS in production, a list in tests.
pub(crate) trait Outbox: Send {
    /// Publishes one sample; failures are logged, not returned (the loop goes on).
    fn publish(&mut self, sample: Outgoing) -> impl Future<Output = ()> + Send;
}

/// The DDS writers of one proxy.
#[derive(Debug)]
pub(crate) struct DdsOutbox {
    vehicle_id: String,
    announcement: Writer<VehicleAnnouncement>,
    state: Writer<StateVector>,
    status: Writer<TaskStatus>,
    event: Writer<Event>,
    alarm: Writer<Event>,
    observation: Writer<EnvironmentObservation>,
}

impl DdsOutbox {
    pub(crate) fn new(
        dds: &PubSub,
        vehicle_id: &str,
        options: &ProxyOptions,
    ) -> Result<Self, CreateError> {
        let mut state = WriterOptions::new(Priority::Telemetry);
        // Promise three reporting periods, so a reader asking for a deadline learns of silence.
        state.deadline = Some(3 * state_period(options.state_rate_hz));
        Ok(Self {
            vehicle_id: vehicle_id.to_string(),
            announcement: dds.writer(WriterOptions::new(Priority::Control))?,
            state: dds.writer(state)?,
            status: dds.writer(WriterOptions::new(Priority::Control))?,
            event: dds.writer(WriterOptions::new(Priority::Control))?,
            alarm: dds.writer(WriterOptions::new(Priority::Emergency))?,
            observation: dds.writer(WriterOptions::new(Priority::Bulk))?,
        })
    }
}

fn log_failure<T>(vehicle: &str, what: &str, result: Result<(), WriteError<T>>) {
    if let Err(e) = result {
        warn!(vehicle, error = %e, "{what} not sent");
    }
}

impl Outbox for DdsOutbox {
    async fn publish(&mut self, sample: Outgoing) {
        let id = self.vehicle_id.as_str();
        match sample {
            Outgoing::Announcement(a) => {
                log_failure(id, "announcement", self.announcement.write(a).await);
            }
            Outgoing::State(s) => log_failure(id, "state vector", self.state.write(s).await),
            Outgoing::Status(s) => log_failure(id, "task status", self.status.write(s).await),
            // Alarms must not queue behind routine events (Priority::Emergency).
            Outgoing::Event(e) if e.severity >= Severity::Alarm => {
                log_failure(id, "alarm", self.alarm.write(e).await);
            }
            Outgoing::Event(e) => log_failure(id, "event", self.event.write(e).await),
            Outgoing::Observation(o) => {
                log_failure(id, "observation", self.observation.write(o).await);
            }
        }
    }
}

/// Time between state vectors at a rate; rates outside (0, 100] Hz are brought into it
/// (a NaN rate means 1 Hz).
pub(crate) fn state_period(rate_hz: f64) -> Duration {
    let rate = if rate_hz.is_nan() {
        1.0
    } else {
        rate_hz.clamp(0.001, 100.0)
    };
    Duration::from_secs_f64(1.0 / rate)
}

fn state_ticker(rate_hz: f64) -> Interval {
    let mut t = tokio::time::interval(state_period(rate_hz));
    // A late tick is not worth a burst of stale states.
    t.set_missed_tick_behavior(MissedTickBehavior::Skip);
    t
}

/// Free text made valid for the model: no control characters, at most 512 bytes.
fn clean_text(text: &str) -> String {
    let mut out = String::with_capacity(text.len().min(MAX_TEXT_LEN));
    for c in text.chars() {
        let c = if c.is_control() && c != '\t' { ' ' } else { c };
        if out.len() + c.len_utf8() > MAX_TEXT_LEN {
            break;
        }
        out.push(c);
    }
    out
}

/// The proxy's own state: the task ledger, which tasks are live, the reporting rate and
/// event numbering.
#[derive(Debug)]
struct Proxy {
    vehicle_id: String,
    options: ProxyOptions,
    ledger: TaskLedger,
    /// Tasks accepted and not yet final, with their last reported state.
    live: HashMap<String, TaskState>,
    event_prefix: String,
    event_seq: u64,
}

impl Proxy {
    /// The vehicle's time now: the system clock, or the scenario run's simulated one.
    fn now(&self) -> i64 {
        self.options.clock.map_or_else(now_ms, |w| w.now_ms())
    }

    /// The real-time rate of a reporting rate in the vehicle's time.
    fn real_rate(&self, rate_hz: f64) -> f64 {
        rate_hz * self.options.clock.map_or(1.0, |w| w.scale())
    }

    fn new(vehicle_id: &str, options: ProxyOptions, ledger: TaskLedger, started_ms: i64) -> Self {
        Self {
            vehicle_id: vehicle_id.to_string(),
            options,
            ledger,
            live: HashMap::new(),
            // Vehicle id (≤ 32) + start time + sequence, in hex: ≤ 61 bytes, unique across
            // restarts of the proxy, within the 64 an event id may have.
            event_prefix: format!("{vehicle_id}-{started_ms:x}"),
            event_seq: 0,
        }
    }

    fn announcement<A: VehicleAdapter>(&self, adapter: &A) -> VehicleAnnouncement {
        let mut a = adapter.announcement();
        a.vehicle_id.clone_from(&self.vehicle_id);
        a.timestamp_ms = self.now();
        for code in PROXY_CAPABILITIES {
            if a.capabilities.len() < VehicleAnnouncement::MAX_LIST
                && !a.capabilities.iter().any(|c| c == code)
            {
                a.capabilities.push(code.to_string());
            }
        }
        a
    }

    fn state<A: VehicleAdapter>(&self, adapter: &mut A) -> Option<StateVector> {
        let mut s = adapter.state()?;
        s.vehicle_id.clone_from(&self.vehicle_id);
        Some(s)
    }

    fn status(&self, task_id: &str, state: TaskState, progress: f64, message: &str) -> Outgoing {
        Outgoing::Status(TaskStatus {
            task_id: task_id.to_string(),
            vehicle_id: self.vehicle_id.clone(),
            timestamp_ms: self.now(),
            state,
            progress_pct: if progress.is_finite() {
                progress.clamp(0.0, 100.0)
            } else {
                0.0
            },
            message: clean_text(message),
        })
    }

    /// Records a task's end in the ledger; a failure is loud, since a restart would then
    /// take the task for one still under way.
    fn ended(&mut self, task_id: &str, state: TaskState) {
        if let Err(e) = self.ledger.end(task_id, state, self.now()) {
            warn!(vehicle = %self.vehicle_id, task = task_id, error = %e, "task end not recorded in the ledger");
        }
    }

    /// What to publish for a vehicle output, if anything.
    fn output(&mut self, out: VehicleOutput) -> Option<Outgoing> {
        match out {
            VehicleOutput::Task(u) => self.update(&u),
            VehicleOutput::Event(e) => Some(self.event(e)),
            VehicleOutput::Observation(mut o) => {
                o.vehicle_id.clone_from(&self.vehicle_id);
                Some(Outgoing::Observation(o))
            }
        }
    }

    /// A task update, unless it is about a task that is not live (unknown, or already
    /// final): a task's life never goes on after `done`, `failed` or `aborted`.
    fn update(&mut self, u: &TaskUpdate) -> Option<Outgoing> {
        let Some(last) = self.live.get_mut(&u.task_id) else {
            warn!(vehicle = %self.vehicle_id, task = %u.task_id, state = ?u.state, "update for a task that is not live dropped");
            return None;
        };
        *last = u.state;
        if u.state.is_final() {
            self.live.remove(&u.task_id);
            self.ended(&u.task_id, u.state);
            info!(vehicle = %self.vehicle_id, task = %u.task_id, state = ?u.state, message = %u.message, "task ended");
        }
        Some(self.status(&u.task_id, u.state, u.progress_pct, &u.message))
    }

    fn event(&mut self, e: VehicleEvent) -> Outgoing {
        let event_id = format!("{}-{:x}", self.event_prefix, self.event_seq);
        self.event_seq += 1;
        Outgoing::Event(Event {
            event_id,
            timestamp_ms: e.timestamp_ms,
            severity: e.severity,
            kind: e.kind,
            vehicle_id: self.vehicle_id.clone(),
            task_id: e.task_id,
            text: clean_text(&e.text),
        })
    }
}

/// Runs the proxy loop until `shutdown` (or an adapter error).
///
/// On joining it announces the vehicle; then it re-announces every
/// `announce_interval`, publishes the adapter's state at the reporting rate, serves the
/// tasks addressed to this vehicle and publishes whatever the adapter reports.
pub(crate) async fn serve<A, O, S>(
    mut adapter: A,
    outbox: &mut O,
    mut tasks: S,
    options: ProxyOptions,
    ledger: TaskLedger,
    shutdown: CancellationToken,
) -> Result<(), A::Error>
where
    A: VehicleAdapter,
    O: Outbox,
    S: Stream<Item = Result<(Validated<TaskAssignment>, SampleMeta), ReadError>> + Unpin + Send,
{
    let vehicle_id = adapter.announcement().vehicle_id;
    let announce_every = options.announce_interval.max(Duration::from_secs(1));
    let started_ms = options.clock.map_or_else(now_ms, |w| w.now_ms());
    let mut proxy = Proxy::new(&vehicle_id, options, ledger, started_ms);
    outbox
        .publish(Outgoing::Announcement(proxy.announcement(&adapter)))
        .await;
    let mut announce = tokio::time::interval_at(Instant::now() + announce_every, announce_every);
    announce.set_missed_tick_behavior(MissedTickBehavior::Delay);
    let mut state_tick = state_ticker(proxy.real_rate(proxy.options.state_rate_hz));
    let mut tasks_open = true;
    loop {
        // Biased: shutdown first, then tasks (operators' commands), then the timers, and the
        // adapter's outputs last, so a chatty vehicle cannot starve the rest.
        tokio::select! {
            biased;
            () = shutdown.cancelled() => break,
            item = tasks.next(), if tasks_open => match item {
                None => {
                    warn!(vehicle = %vehicle_id, "task subscription ended; no more tasks will arrive");
                    tasks_open = false;
                }
                Some(Err(e)) => warn!(vehicle = %vehicle_id, error = %e, "bad task sample ignored"),
                Some(Ok((a, _))) => {
                    if let Some(rate_hz) = on_assignment(&mut proxy, &mut adapter, outbox, a.into_inner()).await {
                        state_tick = state_ticker(proxy.real_rate(rate_hz));
                    }
                }
            },
            _ = state_tick.tick() => {
                if let Some(s) = proxy.state(&mut adapter) {
                    outbox.publish(Outgoing::State(s)).await;
                }
            }
            _ = announce.tick() => {
                outbox.publish(Outgoing::Announcement(proxy.announcement(&adapter))).await;
            }
            out = adapter.next_output() => {
                if let Some(sample) = proxy.output(out?) {
                    outbox.publish(sample).await;
                }
            }
        }
    }
    Ok(())
}

/// A task state as operators read it (`done`, `failed`, ...).
fn state_name(state: TaskState) -> String {
    format!("{state:?}").to_lowercase()
}

/// Serves one task assignment; returns the new reporting rate if it changed.
async fn on_assignment<A: VehicleAdapter, O: Outbox>(
    proxy: &mut Proxy,
    adapter: &mut A,
    outbox: &mut O,
    a: TaskAssignment,
) -> Option<f64> {
    if a.vehicle_id != proxy.vehicle_id {
        return None;
    }
    let vehicle = proxy.vehicle_id.clone();
    let id = a.task_id.as_str();
    let now = proxy.now();
    let resumed = match proxy.ledger.admit(&a, now) {
        Ok(Admission::Start) => false,
        Ok(Admission::Resume) => true,
        Ok(Admission::Duplicate) => {
            debug!(vehicle = %vehicle, task = id, "duplicate task ignored");
            return None;
        }
        Ok(Admission::Ended(state)) => {
            // Never run again; say again how it ended, in case the station missed it.
            info!(vehicle = %vehicle, task = id, ?state, "task already ended, not run again");
            let msg = format!("already {} before; not run again", state_name(state));
            let progress = if state == TaskState::Done { 100.0 } else { 0.0 };
            outbox
                .publish(proxy.status(id, state, progress, &msg))
                .await;
            return None;
        }
        Ok(Admission::Expired) => {
            info!(vehicle = %vehicle, task = id, expires_ms = a.expires_ms, "expired task not started");
            let msg = "arrived after its start-by time; not started";
            outbox
                .publish(proxy.status(id, TaskState::Expired, 0.0, msg))
                .await;
            return None;
        }
        Ok(Admission::Fenced(obeyed)) => {
            // Counted where it is reported: the station that sent it sees it fail, with why.
            warn!(
                vehicle = %vehicle, task = id,
                task_lease_term = a.lease_term, task_lease_holder = %a.lease_holder,
                obeyed_term = obeyed.term, obeyed_holder = %obeyed.holder,
                "task refused: issued under an older command lease"
            );
            let issued = if a.lease_term == 0 {
                "without a command lease".to_owned()
            } else {
                format!(
                    "under command lease term {} of site {}",
                    a.lease_term, a.lease_holder
                )
            };
            let msg = format!(
                "refused: issued {issued}, but this vehicle obeys site {} (command lease term {})",
                obeyed.holder, obeyed.term
            );
            outbox
                .publish(proxy.status(id, TaskState::Failed, 0.0, &msg))
                .await;
            return None;
        }
        Err(e) => {
            warn!(vehicle = %vehicle, task = id, error = %e, "task refused: the ledger cannot record it");
            let msg = format!("not started: the task ledger cannot record it ({e})");
            outbox
                .publish(proxy.status(id, TaskState::Failed, 0.0, &msg))
                .await;
            return None;
        }
    };
    info!(vehicle = %vehicle, task = id, kind = ?a.kind, seq = a.issue_seq, resumed, "task received");
    let task = match a.task() {
        Ok(t) => t,
        Err(e) => {
            let msg = format!("invalid task: {e}");
            proxy.ended(id, TaskState::Failed);
            outbox
                .publish(proxy.status(id, TaskState::Failed, 0.0, &msg))
                .await;
            return None;
        }
    };
    let status = match task {
        Task::RequestState => match proxy.state(adapter) {
            Some(s) => {
                outbox.publish(Outgoing::State(s)).await;
                proxy.ended(id, TaskState::Done);
                proxy.status(id, TaskState::Done, 100.0, "state vector sent")
            }
            None => {
                proxy.ended(id, TaskState::Failed);
                proxy.status(id, TaskState::Failed, 0.0, "no navigation fix yet")
            }
        },
        Task::SetReportingRate { rate_hz } => {
            proxy.options.state_rate_hz = rate_hz;
            info!(vehicle = %vehicle, rate_hz, "reporting rate changed");
            let msg = format!("reporting at {rate_hz} Hz");
            proxy.ended(id, TaskState::Done);
            outbox
                .publish(proxy.status(id, TaskState::Done, 100.0, &msg))
                .await;
            return Some(rate_hz);
        }
        task => {
            let order = TaskOrder {
                task_id: a.task_id.clone(),
                mission_id: a.mission_id.clone(),
                issued_ms: a.issued_ms,
                task,
            };
            match adapter.submit(order).await {
                Ok(acc) => {
                    proxy.live.insert(a.task_id.clone(), TaskState::Accepted);
                    let msg = if resumed {
                        format!("resumed after a restart: {}", acc.message)
                    } else {
                        acc.message
                    };
                    proxy.status(id, TaskState::Accepted, 0.0, &msg)
                }
                Err(refusal) => {
                    info!(vehicle = %vehicle, task = id, reason = %refusal, "task refused");
                    let msg = format!("refused: {refusal}");
                    proxy.ended(id, TaskState::Failed);
                    proxy.status(id, TaskState::Failed, 0.0, &msg)
                }
            }
        }
    };
    outbox.publish(status).await;
    None
}

#[cfg(test)]
mod tests {
    use std::collections::HashSet;
    use std::sync::{Arc, Mutex};

    use futures::channel::mpsc;
    use shoal_model::{EventKind, GeoPoint, Validate, VehicleKind};
    use tokio::task::JoinHandle;

    use super::*;
    use crate::adapter::Acceptance;
    use crate::adapter::Refusal;
    use crate::sim::{SimAdapter, SimSettings, SimSpec};

    type TaskTx = mpsc::UnboundedSender<Result<(Validated<TaskAssignment>, SampleMeta), ReadError>>;

    /// Records what the proxy publishes.
    #[derive(Debug, Clone, Default)]
    struct Recorder(Arc<Mutex<Vec<Outgoing>>>);

    impl Outbox for Recorder {
        fn publish(&mut self, sample: Outgoing) -> impl Future<Output = ()> + Send {
            self.0.lock().unwrap().push(sample);
            std::future::ready(())
        }
    }

    impl Recorder {
        fn all(&self) -> Vec<Outgoing> {
            self.0.lock().unwrap().clone()
        }

        fn statuses(&self, task_id: &str) -> Vec<TaskStatus> {
            self.all()
                .into_iter()
                .filter_map(|o| match o {
                    Outgoing::Status(s) if s.task_id == task_id => Some(s),
                    _ => None,
                })
                .collect()
        }

        fn states(&self) -> usize {
            self.all()
                .iter()
                .filter(|o| matches!(o, Outgoing::State(_)))
                .count()
        }

        fn announcements(&self) -> Vec<VehicleAnnouncement> {
            self.all()
                .into_iter()
                .filter_map(|o| match o {
                    Outgoing::Announcement(a) => Some(a),
                    _ => None,
                })
                .collect()
        }
    }

    struct Running<E> {
        out: Recorder,
        tasks: TaskTx,
        stop: CancellationToken,
        handle: JoinHandle<Result<(), E>>,
    }

    impl<E> Running<E> {
        fn send(&self, a: TaskAssignment) {
            let meta = SampleMeta {
                writer: "station".into(),
                participant: "station".into(),
                source_timestamp_ms: None,
                publisher_vehicle: None,
            };
            let a = Validated::new(a).expect("a test task is valid");
            self.tasks.unbounded_send(Ok((a, meta))).unwrap();
        }

        async fn stop(self) -> Result<(), E> {
            self.stop.cancel();
            self.handle.await.unwrap()
        }
    }

    fn start<A: VehicleAdapter + 'static>(adapter: A, options: ProxyOptions) -> Running<A::Error> {
        let ledger = TaskLedger::in_memory("auv-1", Some(15 * 60 * 1000));
        start_with(adapter, options, ledger)
    }

    fn start_with<A: VehicleAdapter + 'static>(
        adapter: A,
        options: ProxyOptions,
        ledger: TaskLedger,
    ) -> Running<A::Error> {
        let out = Recorder::default();
        let (tasks, rx) = mpsc::unbounded();
        let stop = CancellationToken::new();
        let (mut outbox, token) = (out.clone(), stop.clone());
        let handle =
            tokio::spawn(
                async move { serve(adapter, &mut outbox, rx, options, ledger, token).await },
            );
        Running {
            out,
            tasks,
            stop,
            handle,
        }
    }

    fn sim(battery_pct: f64, settings: &SimSettings) -> SimAdapter {
        let spec = SimSpec {
            id: "auv-1".into(),
            kind: VehicleKind::Auv,
            latitude_deg: 63.0,
            longitude_deg: 10.0,
            rate_hz: 1.0,
            battery_pct,
        };
        SimAdapter::new(&spec, settings)
    }

    fn quiet() -> SimSettings {
        SimSettings {
            environment_hz: 0.0,
            detection_per_s: 0.0,
            ..SimSettings::default()
        }
    }

    fn assign(task_id: &str, vehicle_id: &str, task: &Task) -> TaskAssignment {
        TaskAssignment::new(task_id, "m1", vehicle_id, now_ms(), task)
    }

    fn goto(lat: f64, lon: f64) -> Task {
        Task::GotoWaypoint {
            target: GeoPoint {
                latitude_deg: lat,
                longitude_deg: lon,
            },
            depth_m: Some(5.0),
            altitude_m: None,
            speed_mps: 1.5,
        }
    }

    fn states_of(statuses: &[TaskStatus]) -> Vec<TaskState> {
        statuses.iter().map(|s| s.state).collect()
    }

    async fn sleep_s(s: f64) {
        tokio::time::sleep(Duration::from_secs_f64(s)).await;
    }

    #[tokio::test(start_paused = true)]
    async fn announces_on_joining_and_again_periodically() {
        let options = ProxyOptions {
            announce_interval: Duration::from_secs(30),
            ..ProxyOptions::default()
        };
        let p = start(sim(100.0, &quiet()), options);
        sleep_s(95.0).await;
        let ann = p.out.announcements();
        assert_eq!(ann.len(), 4, "at 0, 30, 60 and 90 s");
        for a in &ann {
            assert_eq!(a.validate(), Ok(()));
            assert_eq!(a.vehicle_id, "auv-1");
        }
        assert!(
            PROXY_CAPABILITIES.iter().all(|c| ann[0]
                .capabilities
                .iter()
                .filter(|x| x == c)
                .count()
                == 1),
            "{:?}",
            ann[0].capabilities
        );
        p.stop().await.unwrap();
    }

    #[tokio::test(start_paused = true)]
    async fn publishes_state_at_the_reporting_rate_and_changes_rate_on_request() {
        let p = start(sim(100.0, &quiet()), ProxyOptions::default());
        sleep_s(10.5).await;
        assert_eq!(p.out.states(), 11, "at 0, 1, ..., 10 s");
        p.send(assign(
            "rate",
            "auv-1",
            &Task::SetReportingRate { rate_hz: 5.0 },
        ));
        sleep_s(0.01).await;
        let before = p.out.states();
        sleep_s(10.0).await;
        let after = p.out.states() - before;
        assert!((49..=51).contains(&after), "{after} states in 10 s at 5 Hz");
        let st = p.out.statuses("rate");
        assert_eq!(states_of(&st), [TaskState::Done]);
        assert_eq!(st[0].message, "reporting at 5 Hz");
        p.stop().await.unwrap();
    }

    #[tokio::test(start_paused = true)]
    async fn request_state_publishes_one_at_once() {
        let options = ProxyOptions {
            state_rate_hz: 0.1,
            ..ProxyOptions::default()
        };
        let p = start(sim(100.0, &quiet()), options);
        sleep_s(1.0).await;
        assert_eq!(p.out.states(), 1);
        p.send(assign("now", "auv-1", &Task::RequestState));
        sleep_s(0.01).await;
        assert_eq!(p.out.states(), 2);
        let st = p.out.statuses("now");
        assert_eq!(states_of(&st), [TaskState::Done]);
        assert_eq!(st[0].progress_pct, 100.0);
        p.stop().await.unwrap();
    }

    #[tokio::test(start_paused = true)]
    async fn ignores_other_vehicles_and_duplicates_and_refuses_stale_replays() {
        let p = start(sim(100.0, &quiet()), ProxyOptions::default());
        let hold = Task::Hold { duration_s: 20.0 };
        p.send(assign("theirs", "auv-2", &hold));
        let mine = assign("mine", "auv-1", &hold);
        p.send(mine.clone());
        sleep_s(1.0).await;
        // A transient-local replay of the same task, e.g. after a reconnection.
        p.send(mine);
        let mut stale = assign("old", "auv-1", &hold);
        stale.issued_ms -= 3_600_000;
        p.send(stale);
        sleep_s(30.0).await;
        assert!(p.out.statuses("theirs").is_empty());
        // Too old to start: refused, and the station is told so.
        assert_eq!(states_of(&p.out.statuses("old")), [TaskState::Expired]);
        let st = p.out.statuses("mine");
        assert_eq!(
            states_of(&st)
                .into_iter()
                .filter(|s| *s != TaskState::Running)
                .collect::<Vec<_>>(),
            [TaskState::Accepted, TaskState::Done],
            "{st:?}"
        );
        assert!(st.iter().all(|s| s.vehicle_id == "auv-1"));
        p.stop().await.unwrap();
    }

    #[tokio::test(start_paused = true)]
    async fn a_refused_task_fails_with_refused_and_the_reason() {
        let p = start(sim(12.0, &quiet()), ProxyOptions::default());
        p.send(assign("far", "auv-1", &goto(63.1, 10.0)));
        sleep_s(1.0).await;
        let st = p.out.statuses("far");
        assert_eq!(states_of(&st), [TaskState::Failed]);
        assert!(
            st[0].message.starts_with("refused: needs about"),
            "{}",
            st[0].message
        );
        p.stop().await.unwrap();
    }

    #[tokio::test(start_paused = true)]
    async fn an_inconsistent_task_is_refused_on_receipt_and_never_reaches_the_vehicle() {
        let p = start(sim(100.0, &quiet()), ProxyOptions::default());
        let mut bad = assign("bad", "auv-1", &goto(63.001, 10.0));
        bad.area.push(bad.area[0]);
        // The P/S Manager validates on receipt, so the proxy is handed a read error, not
        // a task: the type it takes tasks as (`Validated`) cannot hold this one.
        let Err((error, bad)) = Validated::new(bad) else {
            panic!("an inconsistent task passed validation");
        };
        assert_eq!(
            error.to_string(),
            "area: goto_waypoint needs exactly one point"
        );
        p.tasks
            .unbounded_send(Err(ReadError::Invalid {
                topic: "shoal/task_assignment",
                error,
                payload: serde_json::to_string(&bad).unwrap(),
            }))
            .unwrap();
        sleep_s(1.0).await;
        assert!(p.out.statuses("bad").is_empty());
        // The proxy goes on: the next good task runs.
        p.send(assign("good", "auv-1", &goto(63.001, 10.0)));
        sleep_s(1.0).await;
        assert!(!p.out.statuses("good").is_empty());
        p.stop().await.unwrap();
    }

    #[tokio::test(start_paused = true)]
    async fn a_mission_runs_in_order_and_everything_published_is_valid() {
        let settings = SimSettings {
            seed: Some(3),
            detection_per_s: 0.2,
            environment_hz: 1.0,
            ..SimSettings::default()
        };
        let p = start(sim(100.0, &settings), ProxyOptions::default());
        let area = vec![
            GeoPoint {
                latitude_deg: 63.001,
                longitude_deg: 10.0,
            },
            GeoPoint {
                latitude_deg: 63.001,
                longitude_deg: 10.002,
            },
            GeoPoint {
                latitude_deg: 63.0015,
                longitude_deg: 10.002,
            },
        ];
        let survey = Task::SurveyArea {
            polygon: area,
            line_spacing_m: 20.0,
            depth_m: Some(10.0),
            altitude_m: None,
            speed_mps: 1.5,
        };
        p.send(assign("1-goto", "auv-1", &goto(63.001, 10.0)));
        p.send(assign("2-survey", "auv-1", &survey));
        p.send(assign("3-home", "auv-1", &Task::ReturnHome));
        sleep_s(1500.0).await;
        for id in ["1-goto", "2-survey", "3-home"] {
            let st = states_of(&p.out.statuses(id));
            assert_eq!(st.first(), Some(&TaskState::Accepted), "{id}: {st:?}");
            assert_eq!(st.get(1), Some(&TaskState::Running), "{id}: {st:?}");
            assert_eq!(st.last(), Some(&TaskState::Done), "{id}: {st:?}");
        }
        let all = p.out.all();
        let mut event_ids = HashSet::new();
        let mut detections = 0;
        let mut observations = 0;
        for o in &all {
            let valid = match o {
                Outgoing::Announcement(a) => a.validate(),
                Outgoing::State(s) => s.validate(),
                Outgoing::Status(s) => s.validate(),
                Outgoing::Event(e) => {
                    assert!(
                        event_ids.insert(e.event_id.clone()),
                        "duplicate {}",
                        e.event_id
                    );
                    detections += usize::from(e.kind == EventKind::Detection);
                    e.validate()
                }
                Outgoing::Observation(ob) => {
                    observations += 1;
                    ob.validate()
                }
            };
            assert_eq!(valid, Ok(()), "{o:?}");
        }
        assert!(
            detections > 0,
            "a 0.2/s detector on a survey detects something"
        );
        assert!(observations >= 4 * 1400, "{observations} observations");
        p.stop().await.unwrap();
    }

    #[tokio::test(start_paused = true)]
    async fn abort_reports_every_aborted_task_and_surfaces() {
        let p = start(sim(100.0, &quiet()), ProxyOptions::default());
        p.send(assign("g", "auv-1", &goto(63.01, 10.0)));
        p.send(assign("h", "auv-1", &Task::Hold { duration_s: 60.0 }));
        sleep_s(30.0).await;
        p.send(assign("stop", "auv-1", &Task::Abort));
        sleep_s(60.0).await;
        for id in ["g", "h"] {
            let st = p.out.statuses(id);
            let last = st.last().unwrap();
            assert_eq!(last.state, TaskState::Aborted, "{id}: {st:?}");
            assert_eq!(last.message, "aborted by stop (emergency surface)");
        }
        let mut stop = states_of(&p.out.statuses("stop"));
        stop.dedup();
        assert_eq!(
            stop,
            [TaskState::Accepted, TaskState::Running, TaskState::Done]
        );
        p.stop().await.unwrap();
    }

    /// An adapter whose outputs a test scripts.
    #[derive(Debug)]
    struct Scripted {
        outputs: mpsc::UnboundedReceiver<Result<VehicleOutput, LinkLost>>,
    }

    #[derive(Debug, thiserror::Error)]
    #[error("link to the vehicle lost")]
    struct LinkLost;

    impl VehicleAdapter for Scripted {
        type Error = LinkLost;

        fn announcement(&self) -> VehicleAnnouncement {
            VehicleAnnouncement {
                vehicle_id: "rov-7".into(),
                name: "Scripted".into(),
                kind: VehicleKind::Rov,
                vendor: "test".into(),
                capabilities: vec!["hold".into()],
                sensors: Vec::new(),
                links: Vec::new(),
                max_speed_mps: 1.0,
                timestamp_ms: 0,
            }
        }

        fn state(&mut self) -> Option<StateVector> {
            None
        }

        async fn next_output(&mut self) -> Result<VehicleOutput, LinkLost> {
            match self.outputs.next().await {
                Some(out) => out,
                None => std::future::pending().await,
            }
        }

        async fn submit(&mut self, order: TaskOrder) -> Result<Acceptance, Refusal> {
            match order.task {
                Task::Hold { .. } => Ok(Acceptance::with_message("ok")),
                _ => Err(Refusal::new("only holds")),
            }
        }
    }

    fn scripted() -> (
        Scripted,
        mpsc::UnboundedSender<Result<VehicleOutput, LinkLost>>,
    ) {
        let (tx, outputs) = mpsc::unbounded();
        (Scripted { outputs }, tx)
    }

    fn update(id: &str, state: TaskState) -> Result<VehicleOutput, LinkLost> {
        Ok(VehicleOutput::Task(TaskUpdate::new(id, state, 50.0, "")))
    }

    #[tokio::test(start_paused = true)]
    async fn updates_for_tasks_that_are_not_live_are_dropped() {
        let (adapter, script) = scripted();
        let p = start(adapter, ProxyOptions::default());
        script
            .unbounded_send(update("t", TaskState::Running))
            .unwrap();
        sleep_s(0.1).await;
        assert!(p.out.statuses("t").is_empty(), "not submitted yet");
        p.send(assign("t", "rov-7", &Task::Hold { duration_s: 5.0 }));
        sleep_s(0.1).await;
        for s in [TaskState::Running, TaskState::Done, TaskState::Running] {
            script.unbounded_send(update("t", s)).unwrap();
        }
        sleep_s(0.1).await;
        let st = p.out.statuses("t");
        assert_eq!(
            states_of(&st),
            [TaskState::Accepted, TaskState::Running, TaskState::Done]
        );
        assert_eq!(st[0].message, "ok");
        p.stop().await.unwrap();
    }

    #[tokio::test(start_paused = true)]
    async fn without_a_fix_no_state_is_sent_and_request_state_fails() {
        let (adapter, _script) = scripted();
        let p = start(adapter, ProxyOptions::default());
        p.send(assign("now", "rov-7", &Task::RequestState));
        sleep_s(5.0).await;
        assert_eq!(p.out.states(), 0);
        let st = p.out.statuses("now");
        assert_eq!(states_of(&st), [TaskState::Failed]);
        assert_eq!(st[0].message, "no navigation fix yet");
        p.stop().await.unwrap();
    }

    #[tokio::test(start_paused = true)]
    async fn events_get_unique_ids_and_clean_text() {
        let (adapter, script) = scripted();
        let p = start(adapter, ProxyOptions::default());
        for _ in 0..3 {
            let e = VehicleEvent {
                timestamp_ms: now_ms(),
                severity: Severity::Alarm,
                kind: EventKind::Fault,
                task_id: String::new(),
                text: "thruster\u{1b}[31m 2 failed\n".into(),
            };
            script.unbounded_send(Ok(VehicleOutput::Event(e))).unwrap();
        }
        sleep_s(0.1).await;
        let events: Vec<Event> = p
            .out
            .all()
            .into_iter()
            .filter_map(|o| match o {
                Outgoing::Event(e) => Some(e),
                _ => None,
            })
            .collect();
        assert_eq!(events.len(), 3);
        let ids: HashSet<_> = events.iter().map(|e| e.event_id.clone()).collect();
        assert_eq!(ids.len(), 3);
        for e in &events {
            assert_eq!(e.validate(), Ok(()));
            assert_eq!(e.vehicle_id, "rov-7");
            assert_eq!(e.text, "thruster [31m 2 failed ");
        }
        p.stop().await.unwrap();
    }

    #[tokio::test(start_paused = true)]
    async fn an_adapter_error_ends_the_proxy() {
        let (adapter, script) = scripted();
        let p = start(adapter, ProxyOptions::default());
        script.unbounded_send(Err(LinkLost)).unwrap();
        let result = p.handle.await.unwrap();
        assert!(matches!(result, Err(LinkLost)));
    }

    #[tokio::test(start_paused = true)]
    async fn the_proxy_survives_the_end_of_the_task_stream() {
        let p = start(sim(100.0, &quiet()), ProxyOptions::default());
        p.tasks.close_channel();
        sleep_s(5.0).await;
        assert!(!p.handle.is_finished());
        assert!(p.out.states() >= 5, "still reporting");
        p.stop().await.unwrap();
    }

    #[test]
    fn text_is_cleaned_and_bounded() {
        assert_eq!(clean_text("a\tb\nc\u{7}"), "a\tb c ");
        let long = "é".repeat(400); // 800 bytes
        let cleaned = clean_text(&long);
        assert_eq!(cleaned.len(), 512);
        assert!(cleaned.chars().all(|c| c == 'é'));
    }

    #[test]
    fn state_periods_stay_in_range_whatever_the_rate() {
        assert_eq!(state_period(2.0), Duration::from_millis(500));
        assert_eq!(state_period(f64::NAN), Duration::from_secs(1));
        assert_eq!(state_period(1e9), Duration::from_millis(10));
        assert_eq!(state_period(-5.0), Duration::from_secs(1000));
        assert_eq!(state_period(f64::INFINITY), Duration::from_millis(10));
    }

    fn ledger_in(dir: &std::path::Path) -> TaskLedger {
        TaskLedger::open(dir, "auv-1", Some(15 * 60 * 1000)).unwrap()
    }

    #[tokio::test(start_paused = true)]
    async fn a_restarted_vehicle_never_runs_a_finished_task_again_and_says_how_it_ended() {
        let dir = tempfile::tempdir().unwrap();
        let mut goto = assign("r-1-1", "auv-1", &goto(63.0005, 10.0));
        goto.issue_seq = 1;
        goto.expires_ms = now_ms() + 45_000;
        let p = start_with(
            sim(100.0, &quiet()),
            ProxyOptions::default(),
            ledger_in(dir.path()),
        );
        p.send(goto.clone());
        sleep_s(300.0).await;
        assert_eq!(
            p.out.statuses("r-1-1").last().map(|s| s.state),
            Some(TaskState::Done)
        );
        p.stop().await.unwrap();
        // The same vehicle id starts again; transient-local history hands the task back.
        let p = start_with(
            sim(100.0, &quiet()),
            ProxyOptions::default(),
            ledger_in(dir.path()),
        );
        p.send(goto);
        sleep_s(300.0).await;
        let st = p.out.statuses("r-1-1");
        assert_eq!(states_of(&st), [TaskState::Done], "{st:?}");
        assert_eq!(st[0].message, "already done before; not run again");
        p.stop().await.unwrap();
    }

    #[tokio::test(start_paused = true)]
    async fn a_task_under_way_when_the_vehicle_stopped_is_resumed_and_says_so() {
        let dir = tempfile::tempdir().unwrap();
        let mut hold = assign("h-1", "auv-1", &Task::Hold { duration_s: 600.0 });
        hold.expires_ms = now_ms() + 45_000;
        let p = start_with(
            sim(100.0, &quiet()),
            ProxyOptions::default(),
            ledger_in(dir.path()),
        );
        p.send(hold.clone());
        sleep_s(10.0).await;
        p.stop().await.unwrap();
        // Restarted: it had started, so it resumes (whatever its start-by time; the
        // ledger's own tests cover that).
        let p = start_with(
            sim(100.0, &quiet()),
            ProxyOptions::default(),
            ledger_in(dir.path()),
        );
        p.send(hold.clone());
        p.send(hold);
        sleep_s(1.0).await;
        let st = p.out.statuses("h-1");
        assert_eq!(st[0].state, TaskState::Accepted, "{st:?}");
        assert!(
            st[0].message.starts_with("resumed after a restart"),
            "{}",
            st[0].message
        );
        assert_eq!(
            st.iter().filter(|s| s.state == TaskState::Accepted).count(),
            1,
            "the duplicate delivery ran it twice: {st:?}"
        );
        p.stop().await.unwrap();
    }

    #[tokio::test(start_paused = true)]
    async fn a_task_from_a_station_that_lost_the_lease_is_refused_and_says_who_commands() {
        let p = start(sim(100.0, &quiet()), ProxyOptions::default());
        let under = |id: &str, term: u64, holder: &str| {
            let mut a = assign(id, "auv-1", &Task::Hold { duration_s: 0.0 });
            a.lease_term = term;
            a.lease_holder = holder.to_owned();
            a
        };
        p.send(under("ship-1", 1, "ship"));
        sleep_s(1.0).await;
        p.send(under("shore-1", 2, "shore"));
        sleep_s(1.0).await;
        // The ship, partitioned from the shore, still believes it holds term 1.
        p.send(under("ship-2", 1, "ship"));
        sleep_s(1.0).await;
        assert_eq!(
            p.out.statuses("shore-1").first().map(|s| s.state),
            Some(TaskState::Accepted)
        );
        let st = p.out.statuses("ship-2");
        assert_eq!(states_of(&st), [TaskState::Failed], "{st:?}");
        assert_eq!(
            st[0].message,
            "refused: issued under command lease term 1 of site ship, but this vehicle obeys site shore (command lease term 2)"
        );
        p.stop().await.unwrap();
    }

    #[tokio::test(start_paused = true)]
    async fn a_task_that_arrives_after_its_expiry_is_refused_as_expired() {
        let p = start(sim(100.0, &quiet()), ProxyOptions::default());
        let mut late = assign("late", "auv-1", &Task::Surface);
        late.expires_ms = now_ms() - 1;
        late.issued_ms = late.expires_ms - 45_000;
        p.send(late);
        sleep_s(1.0).await;
        let st = p.out.statuses("late");
        assert_eq!(states_of(&st), [TaskState::Expired]);
        p.stop().await.unwrap();
    }
}
