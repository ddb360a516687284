//! The ROS 2 proxy: a vehicle whose software is a ROS 2 graph, reached over DDS (Shoal's
//! own participant) or over rmw_zenoh, wire-compatible without ROS installed.
//!
//! Over DDS, ROS 2 topics are DDS topics named `rt/<namespace>/<name>` whose types are the
//! `.msg` types as plain CDR under the names `<package>::msg::dds_::<Name>_` ([`msgs`]).
//! Over rmw_zenoh (`rmw = "zenoh"`, ROS 2's Tier-1 middleware since Kilted) the same CDR
//! travels on Zenoh key expressions with the type's REP 2016 hash ([`type_hash`]), a
//! 33-byte attachment per sample, and liveliness tokens for the graph ([`zenoh_wire`]).
//! Both sit behind one seam (`transport`), so everything below holds for either.
//! [`Ros2Adapter::new`] (DDS) or [`Ros2Adapter::zenoh`] subscribes, in the configured
//! namespace, to
//!
//! - `sensor_msgs/NavSatFix` (`fix`): latitude and longitude (`status` -1, no fix, and NaN
//!   positions are counted and dropped);
//! - `nav_msgs/Odometry` (`odom`): depth as the negative of the pose's z (the odometry
//!   frame's z = 0 must be the sea surface), attitude from the REP 103 quaternion, speed
//!   from the body-frame twist;
//! - `sensor_msgs/BatteryState` (`battery`): `percentage` is a fraction, made percent;
//! - `rcl_interfaces/Log` on `rt/rosout`: warnings and errors of the namespace's nodes
//!   become events;
//!
//! and publishes `geometry_msgs/PoseStamped` goals (`goal_pose`) in a local ENU frame
//! (`goal_frame_id`, "map" by default) whose origin is [`Ros2Config::datum`] (or the first
//! fix): x east, y north, z up (so z = -depth), oriented towards the target.
//!
//! QoS is ROS 2's default for topics: reliable, volatile. Shoal's DDS layer keeps 64
//! samples of history per writer rather than ROS's 10; history depth is not part of QoS
//! matching, so ROS 2 nodes match either way.
//!
//! **Keyedness.** ROS 2 message types have no key, and DDS implementations match a writer
//! and a reader only if both are keyed or both unkeyed (Cyclone DDS, rmw_cyclonedds'
//! middleware, ignores a mismatched endpoint without a word), so the types of [`msgs`]
//! declare themselves unkeyed (`TopicType::KEYED`) while Shoal's own topics stay keyed.
//!
//! **Loss.** ROS 2 topics have no connection to lose: the vehicle counts as lost when none
//! of its topics (fix, odometry, battery) has delivered a sample for
//! [`Ros2Config::lost_after_ms`] (a `comm_lost` alarm, and no state vector until it is
//! heard again), and as back with the first sample after that, from whichever participant
//! (a restarted vehicle process is a new one).
//!
//! Tasks become goals: `goto_waypoint` one, `survey_area` one per lawnmower point (the
//! next published when the vehicle reaches the last), `hold` one at the current position
//! for the duration, `surface` and `abort` one at the current position at depth 0,
//! `return_home` one at the datum at the surface. ROS 2 goals have no acknowledgement
//! without actions: a goal counts as taken when the middleware delivered it to at least
//! one subscriber (DDS's matched readers; over rmw_zenoh, the subscriptions the graph's
//! liveliness tokens announce on the goal topic with the goal's type hash; none: the task
//! is refused), and progress and arrival come from the vehicle's fix and odometry.

pub mod config;
pub mod mapping;
pub mod msgs;
#[cfg(feature = "rmw-zenoh")]
mod rmw_zenoh;
mod transport;
pub mod type_hash;
pub mod zenoh_wire;

pub use config::{Datum, Rmw, Ros2Config, ZenohMode, ZenohSettings};
pub use transport::GoalError;

use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use shoal_dds::{CreateError, Priority, PubSub, WriterOptions};
use shoal_model::{
    EventKind, GeoPoint, LinkKind, Severity, StateVector, Task, TaskKind, TaskState, UNKNOWN,
    VehicleAnnouncement, now_ms,
};
use tokio::sync::mpsc;
use tokio::task::JoinHandle;
use tokio::time::{Instant, MissedTickBehavior};
use tracing::{debug, info, warn};

use crate::adapter::{
    Acceptance, Refusal, TaskOrder, VehicleAdapter, VehicleOutput, capability_of,
};
use crate::link::{Liveness, Outputs, bump};
use crate::sim::{distance, distance_bearing, lawnmower};
use config::check;
use mapping::EnuFrame;
use msgs::{
    BatteryState, Header, Log, NavSatFix, Odometry, Point, Pose, PoseStamped, STATUS_NO_FIX, Time,
    log_level,
};
use transport::{DdsInbox, Goals, Inbox, Rejection, Sample, Topic};

/// How often silence and goals are checked.
const WATCH_EVERY: Duration = Duration::from_millis(200);
/// Least progress change worth a report, percent.
const PROGRESS_STEP: f64 = 1.0;

/// Why the ROS 2 adapter cannot start or goes on no more.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum Ros2Error {
    /// The configuration cannot work.
    #[error("invalid ROS 2 configuration: {0}")]
    Config(String),
    /// The DDS readers or the goal writer could not be created.
    #[error("ROS 2 topics could not be opened: {0}")]
    Dds(#[from] CreateError),
    /// The rmw_zenoh session or one of its entities could not be opened.
    #[cfg(feature = "rmw-zenoh")]
    #[error("rmw_zenoh: cannot {what}: {source}")]
    Zenoh {
        /// What was being done.
        what: &'static str,
        /// Zenoh's error.
        source: zenoh::Error,
    },
    /// The link task ended.
    #[error("the ROS 2 link stopped: {0}")]
    LinkStopped(String),
}

crate::link::link_counters! {
    /// What the link has seen so far; a snapshot from [`Ros2Adapter::counters`].
    pub struct Ros2Counters {
        /// Samples received and used.
        samples,
        /// Samples that did not decode as their ROS type.
        malformed,
        /// Samples that failed their wire checks (e.g. oversized strings).
        invalid,
        /// Fixes without a fix (`status` -1).
        no_fix,
        /// Values out of range (NaN position, battery fraction above 1, ...).
        out_of_range,
        /// Goals published.
        goals_sent,
        /// Goals that could not be published.
        goal_errors,
        /// rmw_zenoh: samples whose key names another type or type hash than the topic's.
        wrong_type,
        /// rmw_zenoh: samples without the attachment rmw_zenoh specifies, or with a
        /// malformed one.
        bad_attachment,
        /// rmw_zenoh: samples dropped because they arrived faster than the link took them.
        flooded,
    }
}

/// What the odometry says, in Shoal's terms.
#[derive(Debug, Clone, Copy)]
struct Odo {
    depth: f64,
    speed: f64,
    roll: f64,
    pitch: f64,
    heading: f64,
}

/// What the adapter and the link task share.
#[derive(Debug, Default)]
struct Shared {
    fix: Option<(GeoPoint, i64)>,
    odo: Option<Odo>,
    battery_pct: Option<f64>,
    datum: Option<EnuFrame>,
    heard: bool,
    lost: bool,
}

fn lock(shared: &Mutex<Shared>) -> std::sync::MutexGuard<'_, Shared> {
    // Plain values, consistent between statements: a poisoned lock is still usable.
    shared.lock().unwrap_or_else(PoisonError::into_inner)
}

impl Shared {
    fn state(&self, vehicle_id: &str) -> Option<StateVector> {
        if self.lost {
            return None;
        }
        let (p, at_ms) = self.fix?;
        let odo = self.odo?;
        Some(StateVector {
            vehicle_id: vehicle_id.to_string(),
            timestamp_ms: at_ms,
            latitude_deg: p.latitude_deg,
            longitude_deg: p.longitude_deg,
            depth_m: odo.depth,
            altitude_m: UNKNOWN,
            speed_mps: odo.speed,
            yaw_deg: odo.heading,
            pitch_deg: odo.pitch,
            roll_deg: odo.roll,
            battery_pct: self.battery_pct?,
        })
    }
}

/// One goal of a task.
#[derive(Debug, Clone, Copy)]
struct Leg {
    target: GeoPoint,
    depth: f64,
    /// Only the depth counts (surfacing where the vehicle is).
    depth_only: bool,
}

/// The task the vehicle is working on.
#[derive(Debug)]
struct Job {
    task_id: String,
    legs: Vec<Leg>,
    index: usize,
    leg_start: Option<f64>,
    /// After the last leg: hold this long (`Some(None)`: until the next task).
    hold: Option<Option<Duration>>,
    held_since: Option<Instant>,
    last_progress: f64,
}

/// What the adapter asks of the link task.
#[derive(Debug)]
struct Command {
    job: Job,
    abort: bool,
}

/// A ROS 2 vehicle behind a DDS Proxy.
#[derive(Debug)]
pub struct Ros2Adapter {
    /// Kept: DDS readers and writers stop working when their participant is dropped (none
    /// over rmw_zenoh).
    dds: Option<Arc<PubSub>>,
    config: Ros2Config,
    shared: Arc<Mutex<Shared>>,
    counters: Arc<Counters>,
    goals: Arc<Goals>,
    commands: mpsc::Sender<Command>,
    outputs: mpsc::Receiver<VehicleOutput>,
    link: JoinHandle<()>,
}

impl Drop for Ros2Adapter {
    fn drop(&mut self) {
        self.link.abort();
    }
}

fn announcement_of(c: &Ros2Config) -> VehicleAnnouncement {
    VehicleAnnouncement {
        vehicle_id: c.vehicle_id.clone(),
        name: c.name.clone(),
        kind: c.kind,
        vendor: c.vendor.clone(),
        capabilities: [
            TaskKind::GotoWaypoint,
            TaskKind::SurveyArea,
            TaskKind::Hold,
            TaskKind::Surface,
            TaskKind::ReturnHome,
            TaskKind::Abort,
        ]
        .into_iter()
        .map(|k| capability_of(k).to_string())
        .collect(),
        sensors: vec!["gps".into()],
        links: vec![LinkKind::Ip],
        max_speed_mps: c.max_speed_mps,
        timestamp_ms: 0,
    }
}

impl Ros2Adapter {
    /// Subscribes to the vehicle's topics and opens its goal topic on `dds`, for a vehicle
    /// on DDS (`rmw = "dds"`; [`Ros2Adapter::zenoh`] is for rmw_zenoh). Must be called
    /// within a Tokio runtime (it starts the link task).
    pub fn new(dds: Arc<PubSub>, config: Ros2Config) -> Result<Self, Ros2Error> {
        check(&config)?;
        if config.rmw != Rmw::Dds {
            return Err(Ros2Error::Config(
                "Ros2Adapter::new is for DDS: a vehicle on rmw_zenoh needs Ros2Adapter::zenoh"
                    .into(),
            ));
        }
        let runtime = tokio::runtime::Handle::try_current()
            .map_err(|_| Ros2Error::Config("Ros2Adapter::new needs a Tokio runtime".into()))?;
        let inbox = DdsInbox {
            fix: dds.subscribe_on(&config.dds_topic(&config.fix_topic))?,
            odom: dds.subscribe_on(&config.dds_topic(&config.odom_topic))?,
            battery: dds.subscribe_on(&config.dds_topic(&config.battery_topic))?,
            rosout: if config.rosout {
                Some(dds.subscribe_on("rt/rosout")?)
            } else {
                None
            },
        };
        let goals = Goals::Dds(dds.writer_on::<PoseStamped>(
            &config.dds_topic(&config.goal_topic),
            WriterOptions::new(Priority::Control),
        )?);
        info!(vehicle = %config.vehicle_id, namespace = %config.namespace, "ROS 2 topics open");
        Ok(Self::start(
            &runtime,
            Some(dds),
            config,
            Arc::new(Counters::default()),
            Inbox::Dds(Box::new(inbox)),
            goals,
        ))
    }

    /// Joins a vehicle on rmw_zenoh (`rmw = "zenoh"`): opens a Zenoh session as the
    /// configuration's `[zenoh]` table says and joins the vehicle's ROS graph as a node.
    /// Shoal's own side stays on its DDS participant, which the caller keeps. Must be
    /// called within a Tokio runtime.
    #[cfg(feature = "rmw-zenoh")]
    pub async fn zenoh(config: Ros2Config) -> Result<Self, Ros2Error> {
        check(&config)?;
        if config.rmw != Rmw::Zenoh {
            return Err(Ros2Error::Config(
                "Ros2Adapter::zenoh is for rmw_zenoh: set rmw = \"zenoh\"".into(),
            ));
        }
        let runtime = tokio::runtime::Handle::try_current()
            .map_err(|_| Ros2Error::Config("Ros2Adapter::zenoh needs a Tokio runtime".into()))?;
        let counters = Arc::new(Counters::default());
        let (inbox, goals) = rmw_zenoh::open(&config, &counters).await?;
        info!(
            vehicle = %config.vehicle_id,
            namespace = %config.namespace,
            domain = config.zenoh.domain_id,
            "ROS 2 topics open over rmw_zenoh"
        );
        Ok(Self::start(
            &runtime,
            None,
            config,
            counters,
            Inbox::Zenoh(inbox),
            Goals::Zenoh(goals),
        ))
    }

    fn start(
        runtime: &tokio::runtime::Handle,
        dds: Option<Arc<PubSub>>,
        config: Ros2Config,
        counters: Arc<Counters>,
        inbox: Inbox,
        goals: Goals,
    ) -> Self {
        let goals = Arc::new(goals);
        let shared = Arc::new(Mutex::new(Shared {
            datum: config.datum.map(|d| {
                EnuFrame::new(GeoPoint {
                    latitude_deg: d.latitude_deg,
                    longitude_deg: d.longitude_deg,
                })
            }),
            ..Shared::default()
        }));
        let (commands, command_rx) = mpsc::channel(crate::adapter::COMMAND_QUEUE);
        let (output_tx, outputs) = Outputs::channel(Arc::clone(&counters.outputs_dropped));
        let link = Link {
            logger_prefix: format!("{}.", config.namespace.trim_matches('/').replace('/', ".")),
            config: config.clone(),
            shared: Arc::clone(&shared),
            counters: Arc::clone(&counters),
            goals: Arc::clone(&goals),
            outputs: output_tx,
            liveness: Liveness::new(config.lost_after_ms),
            job: None,
        };
        let link = runtime.spawn(link.run(inbox, command_rx));
        Self {
            dds,
            config,
            shared,
            counters,
            goals,
            commands,
            outputs,
            link,
        }
    }

    /// The goal topic as the vehicle's middleware names it, for messages.
    fn goal_topic_name(&self) -> String {
        match self.config.rmw {
            Rmw::Dds => self.config.dds_topic(&self.config.goal_topic),
            Rmw::Zenoh => {
                zenoh_wire::fully_qualified(&self.config.namespace, &self.config.goal_topic)
            }
        }
    }

    /// Sample and error counts so far.
    pub fn counters(&self) -> Ros2Counters {
        self.counters.snapshot()
    }

    /// True while the vehicle's topics are heard.
    pub fn is_connected(&self) -> bool {
        let s = lock(&self.shared);
        s.heard && !s.lost
    }

    /// The DDS participant the vehicle's topics live on; `None` over rmw_zenoh.
    pub fn dds(&self) -> Option<&Arc<PubSub>> {
        self.dds.as_ref()
    }

    /// The goal frame's origin, once known.
    pub fn datum(&self) -> Option<GeoPoint> {
        lock(&self.shared).datum.map(|d| d.origin())
    }

    fn job_for(&self, order: &TaskOrder) -> Result<Job, Refusal> {
        let (here, depth, datum) = {
            let s = lock(&self.shared);
            (s.fix.map(|f| f.0), s.odo.map(|o| o.depth), s.datum)
        };
        let here = || here.ok_or_else(|| Refusal::new("no fix from the vehicle yet"));
        let depth = || depth.ok_or_else(|| Refusal::new("no odometry from the vehicle yet"));
        let datum = datum.ok_or_else(|| Refusal::new("no datum for the goal frame yet"))?;
        let leg = |target, depth| Leg {
            target,
            depth,
            depth_only: false,
        };
        let no_altitude = |altitude_m: &Option<f64>| {
            if altitude_m.is_some() {
                Err(Refusal::new(
                    "a PoseStamped goal carries a depth, not an altitude above the seabed",
                ))
            } else {
                Ok(())
            }
        };
        let (legs, hold) = match &order.task {
            Task::GotoWaypoint {
                target,
                depth_m,
                altitude_m,
                ..
            } => {
                no_altitude(altitude_m)?;
                (vec![leg(*target, depth_m.unwrap_or(0.0))], None)
            }
            Task::SurveyArea {
                polygon,
                line_spacing_m,
                depth_m,
                altitude_m,
                ..
            } => {
                no_altitude(altitude_m)?;
                let points = lawnmower(polygon, *line_spacing_m)
                    .map_err(|e| Refusal::new(format!("no survey pattern: {e}")))?;
                if points.is_empty() {
                    return Err(Refusal::new("the survey polygon gives no survey lines"));
                }
                let z = depth_m.unwrap_or(0.0);
                (points.into_iter().map(|p| leg(p, z)).collect(), None)
            }
            Task::Hold { duration_s } => {
                let d = (*duration_s > 0.0).then(|| Duration::from_secs_f64(*duration_s));
                (vec![leg(here()?, depth()?)], Some(d))
            }
            Task::Surface | Task::Abort => (
                vec![Leg {
                    target: here()?,
                    depth: 0.0,
                    depth_only: true,
                }],
                None,
            ),
            Task::ReturnHome => (vec![leg(datum.origin(), 0.0)], None),
            Task::RequestState | Task::SetReportingRate { .. } => {
                return Err(Refusal::new("served by the proxy, not the vehicle"));
            }
        };
        Ok(Job {
            task_id: order.task_id.clone(),
            legs,
            index: 0,
            leg_start: None,
            hold,
            held_since: None,
            last_progress: 0.0,
        })
    }
}

impl VehicleAdapter for Ros2Adapter {
    type Error = Ros2Error;

    fn announcement(&self) -> VehicleAnnouncement {
        announcement_of(&self.config)
    }

    fn state(&mut self) -> Option<StateVector> {
        lock(&self.shared).state(&self.config.vehicle_id)
    }

    async fn next_output(&mut self) -> Result<VehicleOutput, Ros2Error> {
        match self.outputs.recv().await {
            Some(out) => Ok(out),
            None => Err(Ros2Error::LinkStopped(
                "the link task ended; see the log for why".into(),
            )),
        }
    }

    async fn submit(&mut self, order: TaskOrder) -> Result<Acceptance, Refusal> {
        let abort = matches!(order.task, Task::Abort);
        if !abort && !self.is_connected() {
            return Err(Refusal::new("no data from the vehicle's ROS 2 topics"));
        }
        let subscribers = self.goals.subscribers();
        if subscribers == 0 {
            return Err(Refusal::new(format!(
                "nothing subscribes to {}",
                self.goal_topic_name()
            )));
        }
        let job = self.job_for(&order)?;
        let legs = job.legs.len();
        self.commands
            .try_send(Command { job, abort })
            .map_err(|e| crate::adapter::queue_refusal("ROS 2", &e))?;
        Ok(Acceptance::with_message(format!(
            "{legs} goal(s) for {subscribers} subscriber(s)"
        )))
    }
}

/// The task that owns the subscriptions.
struct Link {
    config: Ros2Config,
    shared: Arc<Mutex<Shared>>,
    counters: Arc<Counters>,
    goals: Arc<Goals>,
    outputs: Outputs,
    logger_prefix: String,
    liveness: Liveness,
    job: Option<Job>,
}

impl Link {
    async fn run(mut self, mut inbox: Inbox, mut commands: mpsc::Receiver<Command>) {
        let mut watch = tokio::time::interval(WATCH_EVERY);
        watch.set_missed_tick_behavior(MissedTickBehavior::Delay);
        loop {
            tokio::select! {
                Some((topic, received)) = inbox.next() => match received {
                    Ok(sample) => self.on_sample(sample).await,
                    Err(why) => self.rejected(topic, &why),
                },
                command = commands.recv() => match command {
                    Some(c) => self.on_command(c).await,
                    None => return,
                },
                _ = watch.tick() => self.on_watch().await,
            }
        }
    }

    async fn on_sample(&mut self, sample: Sample) {
        match sample {
            Sample::Fix(fix) => {
                bump(&self.counters.samples);
                self.on_fix(&fix).await;
            }
            Sample::Odom(odom) => {
                bump(&self.counters.samples);
                self.on_odom(&odom).await;
            }
            Sample::Battery(b) => {
                bump(&self.counters.samples);
                self.on_battery(&b);
            }
            Sample::Log(log) => self.on_log(&log),
        }
    }

    fn rejected(&self, topic: Topic, why: &Rejection) {
        let counter = match why {
            // `/rosout` carries every node's logs and Shoal only peeks at them: one that
            // does not decode is no fault of the vehicle's telemetry, and is not counted.
            Rejection::Malformed(_) | Rejection::Invalid(_) if topic == Topic::Rosout => None,
            Rejection::Malformed(_) => Some(&self.counters.malformed),
            Rejection::Invalid(_) => Some(&self.counters.invalid),
            Rejection::WrongType(_) => Some(&self.counters.wrong_type),
            Rejection::BadAttachment(_) => Some(&self.counters.bad_attachment),
        };
        if let Some(c) = counter {
            bump(c);
        }
        debug!(?topic, reason = %why, "ROS 2 sample dropped");
    }

    fn heard(&mut self) {
        let heard = self.liveness.heard();
        {
            let mut s = lock(&self.shared);
            s.heard = true;
            s.lost = false;
        }
        if let Some(silent) = heard.back_after {
            let silent = silent.as_secs_f64();
            info!(vehicle = %self.config.vehicle_id, "ROS 2 topics heard again");
            self.outputs.event(
                Severity::Info,
                EventKind::CommLost,
                "",
                format!("ROS 2 topics heard again after {silent:.1} s of silence"),
            );
        }
    }

    async fn on_fix(&mut self, fix: &NavSatFix) {
        self.heard();
        if fix.status.status == STATUS_NO_FIX {
            bump(&self.counters.no_fix);
            return;
        }
        let (lat, lon) = (fix.latitude, fix.longitude);
        if !((-90.0..=90.0).contains(&lat) && (-180.0..=180.0).contains(&lon)) {
            bump(&self.counters.out_of_range);
            return;
        }
        let p = GeoPoint {
            latitude_deg: lat,
            longitude_deg: lon,
        };
        {
            let mut s = lock(&self.shared);
            s.fix = Some((p, now_ms()));
            if s.datum.is_none() {
                info!(lat, lon, "ROS 2 goal frame datum set at the first fix");
                s.datum = Some(EnuFrame::new(p));
            }
        }
        self.check_goal().await;
    }

    async fn on_odom(&mut self, o: &Odometry) {
        self.heard();
        let pose = &o.pose.pose;
        let twist = &o.twist.twist;
        let Some((roll, pitch, heading)) = mapping::attitude_deg(&pose.orientation) else {
            bump(&self.counters.out_of_range);
            return;
        };
        let odo = Odo {
            // Above the surface (a wave, a datum offset) is depth 0.
            depth: (-pose.position.z).max(0.0),
            speed: twist.linear.x.hypot(twist.linear.y),
            roll,
            pitch,
            heading,
        };
        let ok = odo.depth.is_finite()
            && odo.depth <= StateVector::DEPTH.1
            && (0.0..=StateVector::SPEED.1).contains(&odo.speed)
            && (-90.0..=90.0).contains(&odo.pitch);
        if !ok {
            bump(&self.counters.out_of_range);
            return;
        }
        lock(&self.shared).odo = Some(odo);
        self.check_goal().await;
    }

    fn on_battery(&mut self, b: &BatteryState) {
        self.heard();
        match mapping::battery_pct(b.percentage) {
            Ok(Some(pct)) => lock(&self.shared).battery_pct = Some(pct),
            Ok(None) => {}
            Err(_) => bump(&self.counters.out_of_range),
        }
    }

    fn on_log(&self, log: &Log) {
        let ours = self.logger_prefix == "." || log.name.starts_with(&self.logger_prefix);
        if !ours || log.level < log_level::WARN {
            return;
        }
        let (severity, kind) = match log.level {
            l if l >= log_level::FATAL => (Severity::Critical, EventKind::Fault),
            l if l >= log_level::ERROR => (Severity::Alarm, EventKind::Fault),
            _ => (Severity::Warning, EventKind::Other),
        };
        self.outputs
            .event(severity, kind, "", format!("{}: {}", log.name, log.msg));
    }

    async fn on_command(&mut self, command: Command) {
        let Command { job, abort } = command;
        if let Some(old) = self.job.take() {
            let held_until_next = matches!(old.hold, Some(None)) && old.held_since.is_some();
            self.outputs.replaced(
                &old.task_id,
                old.last_progress,
                held_until_next,
                &job.task_id,
                abort,
            );
        }
        self.job = Some(job);
        if self.publish_leg().await {
            if let Some(job) = &self.job {
                let n = job.legs.len();
                self.outputs.task(
                    &job.task_id,
                    TaskState::Running,
                    0.0,
                    &format!(
                        "goal 1 of {n} published to {} subscriber(s)",
                        self.goals.subscribers()
                    ),
                );
            }
            self.check_goal().await;
        }
    }

    /// Publishes the goal of the running task's current leg; fails the task if it cannot.
    async fn publish_leg(&mut self) -> bool {
        let (datum, here, heading) = {
            let s = lock(&self.shared);
            (s.datum, s.fix.map(|f| f.0), s.odo.map(|o| o.heading))
        };
        let Some(job) = self.job.as_ref() else {
            return false;
        };
        let Some(leg) = job.legs.get(job.index).copied() else {
            return false;
        };
        let Some(datum) = datum else {
            self.fail("no datum for the goal frame");
            return false;
        };
        let (east, north) = datum.to_enu(leg.target);
        // Face the target; a goal where the vehicle already is keeps its heading.
        let facing = match here {
            Some(h) if distance(h, leg.target) > self.config.arrival_radius_m => {
                distance_bearing(
                    h.latitude_deg,
                    h.longitude_deg,
                    leg.target.latitude_deg,
                    leg.target.longitude_deg,
                )
                .1
            }
            _ => heading.unwrap_or(0.0),
        };
        let goal = PoseStamped {
            header: Header {
                stamp: Time::from_ms(now_ms()),
                frame_id: self.config.goal_frame_id.clone(),
            },
            pose: Pose {
                position: Point {
                    x: east,
                    y: north,
                    z: -leg.depth,
                },
                orientation: mapping::heading_quaternion(facing),
            },
        };
        match self.goals.publish(goal).await {
            Ok(()) => {
                bump(&self.counters.goals_sent);
                debug!(east, north, depth = leg.depth, "ROS 2 goal published");
                true
            }
            Err(e) => {
                bump(&self.counters.goal_errors);
                self.fail(&format!("the goal could not be published: {e}"));
                false
            }
        }
    }

    fn fail(&mut self, why: &str) {
        if let Some(job) = self.job.take() {
            warn!(task = %job.task_id, why, "ROS 2 task failed");
            self.outputs
                .task(&job.task_id, TaskState::Failed, job.last_progress, why);
        }
    }

    /// Advances or ends the running task from the latest fix and odometry.
    async fn check_goal(&mut self) {
        let (here, depth) = {
            let s = lock(&self.shared);
            (s.fix.map(|f| f.0), s.odo.map(|o| o.depth))
        };
        let (Some(here), Some(depth)) = (here, depth) else {
            return;
        };
        let radius = self.config.arrival_radius_m;
        let tolerance = self.config.depth_tolerance_m;
        let Some(job) = self.job.as_mut() else {
            return;
        };
        if let Some(since) = job.held_since {
            if let Some(Some(d)) = job.hold
                && since.elapsed() >= d
                && let Some(job) = self.job.take()
            {
                self.outputs.task(
                    &job.task_id,
                    TaskState::Done,
                    100.0,
                    "held for the duration",
                );
            }
            return;
        }
        let Some(leg) = job.legs.get(job.index).copied() else {
            return;
        };
        let d = distance(here, leg.target);
        let arrived = (leg.depth_only || d <= radius) && (depth - leg.depth).abs() <= tolerance;
        let n = job.legs.len();
        if !arrived {
            let start = *job.leg_start.get_or_insert(d);
            let frac = if leg.depth_only || start <= radius {
                0.0
            } else {
                (1.0 - (d - radius).max(0.0) / (start - radius)).clamp(0.0, 1.0)
            };
            #[allow(clippy::cast_precision_loss)]
            let progress = 100.0 * (job.index as f64 + frac) / n as f64;
            if (progress - job.last_progress).abs() >= PROGRESS_STEP {
                job.last_progress = progress;
                let task = job.task_id.clone();
                self.outputs
                    .task(&task, TaskState::Running, progress, "under way");
            }
            return;
        }
        job.index += 1;
        job.leg_start = None;
        if job.index < n {
            #[allow(clippy::cast_precision_loss)]
            let progress = 100.0 * job.index as f64 / n as f64;
            job.last_progress = progress;
            let (task, i) = (job.task_id.clone(), job.index);
            if self.publish_leg().await {
                self.outputs.task(
                    &task,
                    TaskState::Running,
                    progress,
                    &format!("goal {} of {n} published", i + 1),
                );
            }
            return;
        }
        match job.hold {
            Some(hold) => {
                job.held_since = Some(Instant::now());
                if hold.is_none() {
                    let task = job.task_id.clone();
                    self.outputs.task(
                        &task,
                        TaskState::Running,
                        100.0,
                        "holding until the next task",
                    );
                }
            }
            None => {
                if let Some(job) = self.job.take() {
                    let message = if leg.depth_only {
                        "at the surface"
                    } else {
                        "arrived"
                    };
                    self.outputs
                        .task(&job.task_id, TaskState::Done, 100.0, message);
                }
            }
        }
    }

    async fn on_watch(&mut self) {
        if self.liveness.check() {
            let lost_after = self.liveness.lost_after();
            lock(&self.shared).lost = true;
            warn!(vehicle = %self.config.vehicle_id, "ROS 2 topics silent");
            self.outputs.event(
                Severity::Alarm,
                EventKind::CommLost,
                "",
                format!(
                    "no data on the vehicle's ROS 2 topics for {:.1} s: link lost",
                    lost_after.as_secs_f64()
                ),
            );
        }
        self.check_goal().await;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shoal_model::Validate;

    #[test]
    fn a_state_needs_fix_odometry_and_battery() {
        let mut s = Shared {
            fix: Some((
                GeoPoint {
                    latitude_deg: 59.9,
                    longitude_deg: 10.7,
                },
                1_700_000_000_000,
            )),
            ..Shared::default()
        };
        assert!(s.state("auv").is_none());
        s.odo = Some(Odo {
            depth: 4.0,
            speed: 1.0,
            roll: 0.0,
            pitch: -5.0,
            heading: 359.0,
        });
        assert!(s.state("auv").is_none());
        s.battery_pct = Some(42.0);
        let v = s.state("auv").unwrap();
        assert_eq!(v.validate(), Ok(()));
        assert_eq!((v.depth_m, v.battery_pct, v.yaw_deg), (4.0, 42.0, 359.0));
        s.lost = true;
        assert!(s.state("auv").is_none());
    }
}
