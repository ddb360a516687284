//! `FederationConfig`: the `[federation]` section of a station's configuration.
//!
//! Every key has a default (`federation.default.toml` beside this crate's manifest lists
//! them, and a test checks it parses to `FederationConfig::default()`). Defaults never
//! reach beyond this machine: the site listens on loopback only, connects nowhere, and
//! Zenoh's multicast scouting (UDP 224.0.0.224:7446) and gossip are off unless turned on.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use shoal_model::{MAX_NAME_LEN, Severity, is_identifier};

use crate::types::is_site_name;

/// A configuration value that cannot work, with the key that holds it.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum ConfigError {
    /// The value at `federation.<key>` is refused.
    #[error("federation.{key}: {problem}")]
    Invalid {
        /// Dotted key under `federation`, e.g. `positions.max_rate_hz`.
        key: String,
        /// What is wrong and what is accepted.
        problem: String,
    },
}

pub(crate) fn invalid(key: impl Into<String>, problem: impl Into<String>) -> ConfigError {
    ConfigError::Invalid {
        key: key.into(),
        problem: problem.into(),
    }
}

/// The federation settings of one site.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FederationConfig {
    /// Join the federation: `shoal station` starts the Zenoh transport and feeds it only
    /// when this is true.
    pub enabled: bool,
    /// This site's name, the `<site>` of every key it publishes.
    pub site: String,
    /// How this site joins the Zenoh network.
    pub mode: Mode,
    /// Endpoints to listen on, e.g. `tcp/127.0.0.1:7447`; empty for a client.
    pub listen: Vec<String>,
    /// Endpoints to connect to: remote sites or a `zenohd` router.
    pub connect: Vec<String>,
    /// Remote sites whose data is accepted; data from any other site is refused.
    pub remote_sites: Vec<String>,
    /// Zenoh's UDP multicast scouting (224.0.0.224:7446): off unless asked for.
    pub multicast_scouting: bool,
    /// Zenoh's gossip: peers learn and connect to each other's peers. Off, so the links
    /// are exactly those configured.
    pub gossip: bool,
    /// Run without site identity (no Zenoh authentication or access control): any peer
    /// that reaches this site may claim any site name. Off: identity is required.
    pub insecure_open: bool,
    /// File holding this site's password (its Zenoh username is `site`); empty: none.
    pub password_file: PathBuf,
    /// This site's password itself, for `SHOAL_FEDERATION__PASSWORD`; exclusive with
    /// `password_file`. Never logged, never written out.
    pub password: Secret,
    /// Zenoh's user-password dictionary (`<site>:<password>` a line) of the remote sites
    /// this site accepts connections from; empty: none.
    pub credentials_file: PathBuf,
    /// How long a silent link to a remote site lives before the site is seen lost, ms
    /// (Zenoh's link lease; a keep-alive crosses every quarter of it). The command lease's
    /// failover starts counting then.
    pub link_lease_ms: u64,
    /// The rate of this site's slowest WAN link, kbit/s; 0: a fast link. Over a slow link
    /// Zenoh's priorities act only on what has not yet left for the kernel, so with a rate
    /// the site keeps the kernel's send buffer and Zenoh's batches to a fraction of a
    /// second of the link (see [`LinkShaping`]), so that more of a backlog waits where the
    /// priorities act (the kernel may still queue up to a segment of about 64 kB).
    pub link_rate_kbps: u32,
    /// Mutual TLS between sites: encryption, and each side of a link checks the other's
    /// certificate.
    pub tls: TlsConfig,
    /// Vehicle positions.
    pub positions: PositionsPolicy,
    /// Alarms.
    pub alarms: AlarmsPolicy,
    /// Task transitions.
    pub tasks: TasksPolicy,
    /// Environment observations.
    pub environment: EnvironmentPolicy,
    /// The command lease: which site commands each vehicle.
    pub lease: LeasePolicy,
    /// Bounds on what remote sites can make this site hold.
    pub limits: Limits,
}

impl Default for FederationConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            site: "local".into(),
            mode: Mode::Peer,
            listen: vec!["tcp/127.0.0.1:7447".into()],
            connect: Vec::new(),
            remote_sites: Vec::new(),
            multicast_scouting: false,
            gossip: false,
            insecure_open: false,
            password_file: PathBuf::new(),
            password: Secret::default(),
            credentials_file: PathBuf::new(),
            tls: TlsConfig::default(),
            positions: PositionsPolicy::default(),
            alarms: AlarmsPolicy::default(),
            tasks: TasksPolicy::default(),
            environment: EnvironmentPolicy::default(),
            lease: LeasePolicy::default(),
            link_lease_ms: 10_000,
            link_rate_kbps: 0,
            limits: Limits::default(),
        }
    }
}

/// `[federation.tls]`: Zenoh's TLS link with client certificates (mutual TLS). Each site
/// has a certificate whose common name is its site name (`shoal keys site-cert`); a link
/// is accepted only when each side's certificate chains to one of the other's
/// `trusted_cas`, and Zenoh's access control lets each site publish only under its own
/// `shoal/<site>/**` (by that common name).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TlsConfig {
    /// Every link is TLS (`tls/<host>:<port>` endpoints) with client certificates.
    pub enabled: bool,
    /// This site's certificate (PEM; common name = `site`), presented both when it
    /// listens and when it connects. A chain (leaf first) is accepted.
    pub certificate: PathBuf,
    /// Its private key (PEM: PKCS#8, or PKCS#1 RSA / SEC1 EC), readable by this site only.
    pub private_key: PathBuf,
    /// PEM bundle of the CA certificates whose site certificates this site accepts: the
    /// remote sites' CAs (and this site's own if it issued theirs), also of sites reached
    /// only through a router, whose signed lease records and orders are checked here.
    pub trusted_cas: PathBuf,
    /// The connecting side checks that the listener's certificate names the host of the
    /// endpoint (`tls/<host>:<port>`) in its subject alternative names.
    pub verify_name: bool,
}

impl Default for TlsConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            certificate: PathBuf::new(),
            private_key: PathBuf::new(),
            trusted_cas: PathBuf::new(),
            verify_name: true,
        }
    }
}

/// A password: `Debug` and `Serialize` never show it (`shoal config` prints
/// `<redacted>`).
#[derive(Clone, Default, PartialEq, Eq, Deserialize)]
#[serde(transparent)]
pub struct Secret(String);

impl Secret {
    /// Wraps a password.
    pub fn new(value: impl Into<String>) -> Self {
        Self(value.into())
    }

    /// The password itself, for Zenoh's configuration only.
    pub fn expose(&self) -> &str {
        &self.0
    }

    /// Whether none is set.
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
}

impl std::fmt::Debug for Secret {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(if self.0.is_empty() {
            "\"\""
        } else {
            "<redacted>"
        })
    }
}

impl Serialize for Secret {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(if self.0.is_empty() { "" } else { "<redacted>" })
    }
}

/// The Zenoh role of a site.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// Talks directly to the peers it connects to or accepts.
    Peer,
    /// Connects to one router (e.g. a shore `zenohd`) that relays everything.
    Client,
    /// Routes for others too (a shore station relaying between ships).
    Router,
}

impl Mode {
    /// Zenoh's name of the mode.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Peer => "peer",
            Self::Client => "client",
            Self::Router => "router",
        }
    }
}

/// Zenoh's priority classes, highest first (so a higher priority compares less).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[allow(missing_docs)]
pub enum Priority {
    RealTime,
    InteractiveHigh,
    InteractiveLow,
    DataHigh,
    Data,
    DataLow,
    Background,
}

/// What a publisher does when the link's queue is full.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Congestion {
    /// Drop the message (a later value replaces it).
    Drop,
    /// Wait for room (the federation's own queue absorbs the wait).
    Block,
}

/// Zenoh QoS of one kind of data.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Qos {
    /// Priority class.
    pub priority: Priority,
    /// Congestion control.
    pub congestion: Congestion,
    /// Sent at once rather than batched with other messages.
    pub express: bool,
}

/// Policy for vehicle positions: latest value wins, at most `max_rate_hz` per vehicle.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PositionsPolicy {
    /// Whether this site's positions cross.
    pub crosses: bool,
    /// Most positions per second per vehicle; newer values replace unsent ones.
    pub max_rate_hz: f64,
    /// Zenoh QoS.
    pub qos: Qos,
}

impl Default for PositionsPolicy {
    fn default() -> Self {
        Self {
            crosses: true,
            max_rate_hz: 0.2,
            qos: Qos {
                priority: Priority::Data,
                congestion: Congestion::Drop,
                express: false,
            },
        }
    }
}

/// Policy for alarms: sent at once; with `reliable`, caught up after an outage.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AlarmsPolicy {
    /// Whether this site's alarms cross.
    pub crosses: bool,
    /// Least severity that crosses.
    pub min_severity: Severity,
    /// Keep the last `catchup` alarms for remote sites to catch up on after an outage.
    pub reliable: bool,
    /// How many recent alarms are kept for catch-up.
    pub catchup: usize,
    /// A site that connects (and listens nowhere) gives alarms a Zenoh session (so a TCP
    /// or TLS connection) of their own, so that an alarm never waits behind positions, lease records or catch-up
    /// already written to the other connection's socket.
    pub own_link: bool,
    /// Zenoh QoS.
    pub qos: Qos,
}

impl Default for AlarmsPolicy {
    fn default() -> Self {
        Self {
            crosses: true,
            min_severity: Severity::Warning,
            reliable: true,
            catchup: 1000,
            own_link: true,
            qos: Qos {
                priority: Priority::RealTime,
                congestion: Congestion::Block,
                express: true,
            },
        }
    }
}

/// Policy for task transitions: reliable, caught up after an outage.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TasksPolicy {
    /// Whether this site's task transitions cross.
    pub crosses: bool,
    /// Keep the last `catchup` transitions for remote sites to catch up on.
    pub reliable: bool,
    /// How many recent transitions are kept for catch-up.
    pub catchup: usize,
    /// Zenoh QoS.
    pub qos: Qos,
}

impl Default for TasksPolicy {
    fn default() -> Self {
        Self {
            crosses: true,
            reliable: true,
            catchup: 1000,
            qos: Qos {
                priority: Priority::InteractiveHigh,
                congestion: Congestion::Block,
                express: false,
            },
        }
    }
}

/// The command lease (`[federation.lease]`): exactly one site commands a vehicle at a time.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LeasePolicy {
    /// In force: this station commands only the vehicles whose lease it holds. Off, every
    /// federated station commands the vehicles it reaches, as if alone.
    pub enabled: bool,
    /// Claim the lease of each vehicle registered here that no site holds (this site is its
    /// home). False for a standby that reaches another site's vehicles but must never
    /// claim them as its own.
    pub home: bool,
    /// The site that takes over this site's vehicles when this site has been offline for
    /// `failover_timeout_ms` (it must reach them); empty: none.
    pub standby: String,
    /// How long the holder's site must be offline before the home or the standby takes
    /// its leases, ms.
    pub failover_timeout_ms: u64,
    /// After start, how long this site waits for the remote sites' leases before it
    /// claims its own vehicles (sooner when every remote site has answered), ms.
    pub settle_ms: u64,
    /// Where the leases this site knows are kept across restarts (written on every
    /// change): a path; `auto` for `shoal-data/leases-<site>.json` (`shoal station` puts
    /// it beside its SQLite history instead); empty: not kept (a restarted site then
    /// relearns them from the others).
    pub state_file: PathBuf,
}

impl LeasePolicy {
    /// The file the leases are kept in for `site`, `None` when they are not kept.
    pub fn state_path(&self, site: &str) -> Option<PathBuf> {
        if self.state_file.as_os_str().is_empty() {
            None
        } else if self.state_file == Path::new(AUTO) {
            Some(PathBuf::from(format!("shoal-data/leases-{site}.json")))
        } else {
            Some(self.state_file.clone())
        }
    }
}

/// `lease.state_file`'s default: the place is chosen for the site.
pub const AUTO: &str = "auto";

impl Default for LeasePolicy {
    fn default() -> Self {
        Self {
            enabled: true,
            home: true,
            standby: String::new(),
            failover_timeout_ms: 30_000,
            settle_ms: 10_000,
            state_file: PathBuf::from(AUTO),
        }
    }
}

/// Policy for environment observations.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EnvironmentPolicy {
    /// `off` (nothing crosses), or `aggregated`: per vehicle and property, one summary
    /// (count, min, max, mean, latest) per window instead of every observation.
    pub mode: EnvironmentMode,
    /// Length of a window, seconds, in 5..=3600. Each vehicle's windows are on its own
    /// phase of the wall clock, so a fleet's summaries do not leave as one burst.
    pub window_s: u64,
    /// Properties that cross (e.g. `sea_water_temperature`); empty: every property.
    pub properties: Vec<String>,
    /// Zenoh QoS: the lowest priority, dropped on congestion (the next window replaces a
    /// lost summary).
    pub qos: Qos,
}

impl Default for EnvironmentPolicy {
    fn default() -> Self {
        Self {
            mode: EnvironmentMode::Off,
            window_s: 60,
            properties: Vec::new(),
            qos: Qos {
                priority: Priority::Background,
                congestion: Congestion::Drop,
                express: false,
            },
        }
    }
}

/// Whether environment data crosses.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum EnvironmentMode {
    /// Nothing crosses.
    #[default]
    Off,
    /// Aggregates per vehicle, property and window.
    Aggregated,
}

/// Shortest environment window accepted, seconds.
pub const MIN_ENVIRONMENT_WINDOW_S: u64 = 5;
/// Longest environment window accepted, seconds.
pub const MAX_ENVIRONMENT_WINDOW_S: u64 = 3600;

/// Bounds on what remote sites can make this site hold or do.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Limits {
    /// Remote vehicles held in the picture; positions of further ones are refused.
    pub remote_vehicles: usize,
    /// Remote alarms kept in the picture (oldest dropped).
    pub remote_alarms: usize,
    /// Remote task transitions kept in the picture (oldest dropped).
    pub remote_transitions: usize,
    /// Sequence numbers held above a gap per site and stream before the gap is given up.
    pub reorder_window: usize,
    /// Replies read from one catch-up query at most.
    pub catchup_replies: usize,
    /// Frames asked for in one catch-up query (`limit=`); a full answer is followed by the
    /// next query at once. Small enough that an answer crosses a slow link within
    /// `catchup_timeout_ms`: 100 frames are about 10 kB, 1.3 s at 64 kbit/s.
    pub catchup_batch: usize,
    /// How long a catch-up query waits for its replies, ms.
    pub catchup_timeout_ms: u64,
    /// Remote environment aggregates held in the picture, one per (site, vehicle,
    /// property); aggregates of further ones are refused.
    pub remote_environment: usize,
}

impl Default for Limits {
    fn default() -> Self {
        Self {
            remote_vehicles: 5000,
            remote_alarms: 1000,
            remote_transitions: 1000,
            reorder_window: 1024,
            catchup_replies: 1000,
            catchup_batch: 100,
            catchup_timeout_ms: 10_000,
            remote_environment: 10_000,
        }
    }
}

/// Most positions per second per vehicle the federation accepts to send.
pub const MAX_POSITION_RATE_HZ: f64 = 10.0;
/// Largest catch-up buffer and limit accepted.
pub const MAX_BUFFER: usize = 100_000;

/// About what one catch-up answer (an alarm or transition frame, its key, Zenoh's and
/// TCP's share) costs on the link, bytes: sizes the parts asked for on a slow link.
pub const CATCHUP_ITEM_BYTES: usize = 120;
/// About what one lease record answered costs on the link, bytes (signed: about 70 more).
pub const LEASE_ITEM_BYTES: usize = 100;

/// The slowest `link_rate_kbps` accepted (a 2.4 kbit/s HF or Iridium data line).
pub const LINK_RATE_KBPS_MIN: u32 = 2;
/// The fastest `link_rate_kbps` accepted (10 Gbit/s).
pub const LINK_RATE_KBPS_MAX: u32 = 10_000_000;

/// What `link_rate_kbps` makes of the kernel's and Zenoh's buffers on every link.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LinkShaping {
    /// Each link's TCP send buffer (`SO_SNDBUF`), bytes: half a second of the link, at
    /// least 4 KiB. What the kernel holds leaves in order, whatever its priority.
    pub send_buffer_bytes: u32,
    /// Zenoh's batch, bytes: an eighth of a second of the link, 8 KiB to 64 KiB. A batch
    /// once started goes out whole, so an alarm may wait behind one; but Zenoh's queues
    /// hold at most 16 batches a priority, and smaller batches would make its queues too
    /// small (below).
    pub batch_bytes: u16,
    /// Batches each of Zenoh's queues for reliable data holds (2 to 16): 128 KiB a
    /// priority, as with Zenoh's defaults (two 64 KiB batches). A full queue blocks a
    /// reliable publisher, and in a router the link a message came in on, for up to 5 s: a
    /// site whose link falls silent must not fill it in seconds. The queues of positions
    /// and environment summaries, which a newer value replaces, keep Zenoh's least (2).
    pub queue_batches: u8,
    /// How fast this site's answers to catch-up and lease queries leave, bytes per
    /// second: a quarter of the link, at least 250 B/s. A burst of answers would fill the
    /// link and the modem's buffer ahead of it, and live data would wait behind it.
    pub bulk_bytes_per_s: u32,
}

impl LinkShaping {
    /// The shaping for a link of `kbps` kbit/s.
    pub fn for_rate(kbps: u32) -> Self {
        let bytes_per_s = u64::from(kbps) * 1000 / 8;
        let send = (bytes_per_s / 2).clamp(4096, 4 << 20);
        let batch = (bytes_per_s / 8).clamp(8 * 1024, u64::from(u16::MAX));
        let queue = (128 * 1024 / batch).clamp(2, 16);
        let bulk = (bytes_per_s / 4).max(250);
        Self {
            send_buffer_bytes: u32::try_from(send).unwrap_or(u32::MAX),
            batch_bytes: u16::try_from(batch).unwrap_or(u16::MAX),
            queue_batches: u8::try_from(queue).unwrap_or(16),
            bulk_bytes_per_s: u32::try_from(bulk).unwrap_or(u32::MAX),
        }
    }

    /// Items (of about `item_bytes` on the link) to ask for in one part of a catch-up or
    /// lease query that waits `timeout_ms`, at most `limit`: as many as the bulk rate
    /// carries in a quarter of the timeout, at least 10. The answering site paces at that
    /// rate too (a site on a slow link sets `link_rate_kbps` on every site of it).
    pub fn part_items(&self, item_bytes: usize, timeout_ms: u64, limit: usize) -> usize {
        let budget = u64::from(self.bulk_bytes_per_s).saturating_mul(timeout_ms) / 4000;
        let items = usize::try_from(budget).unwrap_or(usize::MAX) / item_bytes.max(1);
        items.clamp(10, limit.max(10))
    }
}

impl FederationConfig {
    /// Whether alarms get a Zenoh session of their own: `alarms.own_link` on a site that
    /// connects somewhere and listens nowhere. A site that only listens has the far end's
    /// alarm link; one that listens too keeps alarms on its one session, where the sites
    /// connecting to it send theirs (a second subscriber would bring every alarm twice,
    /// and its own back).
    pub fn alarm_link(&self) -> bool {
        self.alarms.own_link && !self.connect.is_empty() && self.listen.is_empty()
    }

    /// The buffers to use for `link_rate_kbps`; `None` for a fast link (the kernel's and
    /// Zenoh's own defaults).
    pub fn link_shaping(&self) -> Option<LinkShaping> {
        (self.link_rate_kbps != 0).then(|| LinkShaping::for_rate(self.link_rate_kbps))
    }

    /// Checks every key; the error names the first one that cannot work.
    pub fn validate(&self) -> Result<(), ConfigError> {
        if !is_site_name(&self.site) {
            return Err(invalid("site", "must be 1..=32 of [A-Za-z0-9_.-]"));
        }
        for (i, remote) in self.remote_sites.iter().enumerate() {
            let key = format!("remote_sites[{i}]");
            if !is_site_name(remote) {
                return Err(invalid(key, "must be 1..=32 of [A-Za-z0-9_.-]"));
            }
            if *remote == self.site {
                return Err(invalid(key, "is this site's own name"));
            }
            if self.remote_sites[..i].contains(remote) {
                return Err(invalid(key, format!("{remote} is listed twice")));
            }
        }
        let scheme = if self.tls.enabled { "tls" } else { "tcp" };
        endpoints("listen", &self.listen, scheme)?;
        endpoints("connect", &self.connect, scheme)?;
        if self.tls.enabled && self.insecure_open {
            return Err(invalid(
                "insecure_open",
                "tls.enabled is site identity (certificates): set insecure_open = false",
            ));
        }
        if self.mode == Mode::Client && !self.listen.is_empty() {
            return Err(invalid(
                "listen",
                "a client does not listen: set listen = []",
            ));
        }
        if self.mode == Mode::Client && self.connect.is_empty() {
            return Err(invalid("connect", "a client needs a router to connect to"));
        }
        let rate = self.positions.max_rate_hz;
        if !(rate.is_finite() && rate > 0.0 && rate <= MAX_POSITION_RATE_HZ) {
            return Err(invalid(
                "positions.max_rate_hz",
                format!("{rate} is not in (0, {MAX_POSITION_RATE_HZ}]"),
            ));
        }
        bounded("alarms.catchup", self.alarms.catchup)?;
        bounded("tasks.catchup", self.tasks.catchup)?;
        self.validate_environment()?;
        if !(1_000..=600_000).contains(&self.link_lease_ms) {
            return Err(invalid("link_lease_ms", "must be in 1000..=600000"));
        }
        if self.link_rate_kbps != 0
            && !(LINK_RATE_KBPS_MIN..=LINK_RATE_KBPS_MAX).contains(&self.link_rate_kbps)
        {
            return Err(invalid(
                "link_rate_kbps",
                format!(
                    "must be 0 (a fast link) or in {LINK_RATE_KBPS_MIN}..={LINK_RATE_KBPS_MAX}"
                ),
            ));
        }
        let lease = &self.lease;
        if !lease.standby.is_empty() && !self.remote_sites.contains(&lease.standby) {
            return Err(invalid(
                "lease.standby",
                format!("{} is not one of remote_sites", lease.standby),
            ));
        }
        if !(1_000..=86_400_000).contains(&lease.failover_timeout_ms) {
            return Err(invalid(
                "lease.failover_timeout_ms",
                "must be in 1000..=86400000 (1 s to a day)",
            ));
        }
        if lease.settle_ms > 600_000 {
            return Err(invalid("lease.settle_ms", "must be at most 600000"));
        }
        let l = &self.limits;
        bounded("limits.remote_vehicles", l.remote_vehicles)?;
        bounded("limits.remote_alarms", l.remote_alarms)?;
        bounded("limits.remote_transitions", l.remote_transitions)?;
        bounded("limits.reorder_window", l.reorder_window)?;
        bounded("limits.catchup_replies", l.catchup_replies)?;
        bounded("limits.catchup_batch", l.catchup_batch)?;
        bounded("limits.remote_environment", l.remote_environment)?;
        if l.catchup_batch > l.catchup_replies {
            return Err(invalid(
                "limits.catchup_batch",
                "must not exceed limits.catchup_replies",
            ));
        }
        if !(1..=600_000).contains(&l.catchup_timeout_ms) {
            return Err(invalid(
                "limits.catchup_timeout_ms",
                "must be in 1..=600000",
            ));
        }
        if !self.insecure_open {
            self.identity_topology()?;
        }
        if self.enabled {
            // Read the files now, so that a station refuses to start naming the key.
            self.identity()?;
        }
        Ok(())
    }

    /// `[federation.environment]`, checked whatever the mode, so that turning it on later
    /// does not reveal a bad value.
    fn validate_environment(&self) -> Result<(), ConfigError> {
        let env = &self.environment;
        let window = MIN_ENVIRONMENT_WINDOW_S..=MAX_ENVIRONMENT_WINDOW_S;
        if !window.contains(&env.window_s) {
            return Err(invalid(
                "environment.window_s",
                format!(
                    "{} is not in {MIN_ENVIRONMENT_WINDOW_S}..={MAX_ENVIRONMENT_WINDOW_S}",
                    env.window_s
                ),
            ));
        }
        for (i, property) in env.properties.iter().enumerate() {
            let key = format!("environment.properties[{i}]");
            // The model's rule for a property name: anything else would never match.
            if !is_identifier(property, MAX_NAME_LEN) {
                return Err(invalid(key, "must be 1..=64 of [A-Za-z0-9_.-]"));
            }
            if env.properties[..i].contains(property) {
                return Err(invalid(key, format!("{property} is listed twice")));
            }
        }
        Ok(())
    }

    /// With identity, every link must be one whose far end Zenoh identifies or one this
    /// site chose: Zenoh's user-password authentication identifies the side that
    /// connects, to the side that accepts, and never the other way round.
    fn identity_topology(&self) -> Result<(), ConfigError> {
        const WHY: &str = "with site identity (insecure_open = false), ";
        // With TLS both ends of every link are identified by certificate: a site may
        // listen and connect.
        if !self.tls.enabled && !self.listen.is_empty() && !self.connect.is_empty() {
            return Err(invalid(
                "connect",
                format!(
                    "{WHY}a site either listens (and checks the sites that connect to it) or \
                     connects (to the endpoints it trusts), not both: Zenoh's user-password \
                     scheme identifies only the connecting side of a link (tls.enabled \
                     identifies both)"
                ),
            ));
        }
        if self.gossip {
            return Err(invalid(
                "gossip",
                format!("{WHY}links are the configured ones only: set gossip = false"),
            ));
        }
        if self.multicast_scouting {
            return Err(invalid(
                "multicast_scouting",
                format!("{WHY}links are the configured ones only: set multicast_scouting = false"),
            ));
        }
        Ok(())
    }

    /// This site's identity, read from its files; `None` with `insecure_open`. Errors
    /// name the key and the file, never a password or a key.
    ///
    /// TLS (`tls.enabled`), user-password (`password_file`/`password` and
    /// `credentials_file`), or both; at least one unless `insecure_open`.
    pub fn identity(&self) -> Result<Option<Identity>, ConfigError> {
        if self.insecure_open {
            return Ok(None);
        }
        let tls = if self.tls.enabled {
            Some(self.tls_identity()?)
        } else {
            None
        };
        let usrpwd_set = !self.password_file.as_os_str().is_empty()
            || !self.password.is_empty()
            || !self.credentials_file.as_os_str().is_empty();
        let usrpwd = if tls.is_none() || usrpwd_set {
            Some(self.user_password()?)
        } else {
            None
        };
        Ok(Some(Identity {
            site: self.site.clone(),
            usrpwd,
            tls,
        }))
    }

    /// The user-password half of the identity.
    fn user_password(&self) -> Result<UserPassword, ConfigError> {
        let password = match (
            self.password_file.as_os_str().is_empty(),
            self.password.is_empty(),
        ) {
            (false, false) => {
                return Err(invalid(
                    "password",
                    "set either password or password_file, not both",
                ));
            }
            (true, true) => {
                return Err(invalid(
                    "password_file",
                    "site identity needs TLS (tls.enabled, with tls.certificate, \
                     tls.private_key and tls.trusted_cas) or this site's password: set \
                     password_file (or password, e.g. from SHOAL_FEDERATION__PASSWORD), or \
                     insecure_open = true to federate without identity",
                ));
            }
            (false, true) => {
                let text = read(&self.password_file, "password_file")?;
                text.trim().to_string()
            }
            (true, false) => self.password.expose().trim().to_string(),
        };
        if password.is_empty() {
            let key = if self.password.is_empty() {
                "password_file"
            } else {
                "password"
            };
            return Err(invalid(key, "the password is empty"));
        }
        if self.credentials_file.as_os_str().is_empty() {
            return Err(invalid(
                "credentials_file",
                "site identity needs the dictionary of the remote sites' usernames and \
                 passwords (<site>:<password> a line), or insecure_open = true to federate \
                 without identity",
            ));
        }
        let path = &self.credentials_file;
        let dictionary_file = utf8_path(path, "credentials_file")?;
        let text = read(path, "credentials_file")?;
        let users = dictionary_users(&text)
            .map_err(|p| invalid("credentials_file", format!("{}: {p}", path.display())))?;
        for (i, remote) in self.remote_sites.iter().enumerate() {
            if !users.contains(remote) {
                return Err(invalid(
                    format!("remote_sites[{i}]"),
                    format!(
                        "{remote} has no entry in credentials_file {}",
                        path.display()
                    ),
                ));
            }
        }
        Ok(UserPassword {
            user: self.site.clone(),
            password: Secret(password),
            credentials_file: dictionary_file,
            users,
        })
    }

    /// The TLS half of the identity: the three files, each read and checked as Zenoh's
    /// rustls will load it, so that a bad one stops the start naming its key (Zenoh
    /// itself would only log it at each connection attempt).
    fn tls_identity(&self) -> Result<TlsIdentity, ConfigError> {
        let t = &self.tls;
        let mut paths = Vec::new();
        for (key, path) in [
            ("tls.certificate", &t.certificate),
            ("tls.private_key", &t.private_key),
            ("tls.trusted_cas", &t.trusted_cas),
        ] {
            if path.as_os_str().is_empty() {
                return Err(invalid(
                    key,
                    "tls.enabled needs this site's certificate, its private key and the \
                     trusted CAs (PEM files; `shoal keys site-cert` issues the first two)",
                ));
            }
            paths.push(utf8_path(path, key)?);
        }
        let [certificate, private_key, trusted_cas] =
            <[String; 3]>::try_from(paths).map_err(|_| invalid("tls", "three files"))?;
        let not_after_ms = crate::tls::check_files(&self.site, t, shoal_model::now_ms())?;
        Ok(TlsIdentity {
            certificate,
            private_key,
            trusted_cas,
            verify_name: t.verify_name,
            not_after_ms,
        })
    }

    /// Whether data from `site` is accepted.
    pub fn accepts(&self, site: &str) -> bool {
        self.remote_sites.iter().any(|s| s == site)
    }
}

/// This site's identity in the federation: TLS, user-password, or both.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Identity {
    /// This site's name: its certificate's common name and its Zenoh username.
    pub site: String,
    /// Zenoh's user-password authentication, if configured.
    pub usrpwd: Option<UserPassword>,
    /// Mutual TLS, if `tls.enabled`.
    pub tls: Option<TlsIdentity>,
}

impl Identity {
    /// Which mechanisms are on: `tls`, `usrpwd` or `tls+usrpwd`, for the logs.
    pub fn mechanisms(&self) -> &'static str {
        match (self.tls.is_some(), self.usrpwd.is_some()) {
            (true, true) => "tls+usrpwd",
            (true, false) => "tls",
            _ => "usrpwd",
        }
    }

    /// Whether the links are encrypted (TLS).
    pub fn encrypted(&self) -> bool {
        self.tls.is_some()
    }
}

/// Zenoh's user-password authentication: this site's username and password, and the
/// dictionary of the remote sites it accepts connections from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct UserPassword {
    /// This site's Zenoh username: its site name.
    pub user: String,
    /// This site's password (trimmed, as Zenoh trims the dictionary's).
    pub password: Secret,
    /// Zenoh's user-password dictionary file, as configured.
    pub credentials_file: String,
    /// The usernames in that file, in file order.
    pub users: Vec<String>,
}

/// Mutual TLS: the files as Zenoh reads them (checked at start).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TlsIdentity {
    /// This site's certificate (PEM), presented when listening and when connecting.
    pub certificate: String,
    /// Its private key (PEM).
    pub private_key: String,
    /// The CAs whose site certificates are accepted (PEM bundle).
    pub trusted_cas: String,
    /// Whether the connecting side checks the listener's name.
    pub verify_name: bool,
    /// When this site's certificate expires, ms since the Unix epoch.
    pub not_after_ms: i64,
}

/// A configured path as Zenoh's configuration takes it (a string).
fn utf8_path(path: &Path, key: &str) -> Result<String, ConfigError> {
    path.to_str()
        .map(str::to_owned)
        .ok_or_else(|| invalid(key, format!("{}: not UTF-8", path.display())))
}

/// Reads a file named by `key`; the error names the key and the file, not its content.
pub(crate) fn read(path: &Path, key: &str) -> Result<String, ConfigError> {
    std::fs::read_to_string(path)
        .map_err(|e| invalid(key, format!("cannot read {}: {e}", path.display())))
}

/// The usernames of Zenoh's user-password dictionary: one `<user>:<password>` a line,
/// each side trimmed, blank lines skipped; what Zenoh 1.10 refuses is refused here
/// first, so that the error is Shoal's and names the line (never its content).
pub fn dictionary_users(text: &str) -> Result<Vec<String>, String> {
    let mut users = Vec::new();
    for (n, line) in text.lines().enumerate().map(|(i, l)| (i + 1, l.trim())) {
        if line.is_empty() {
            continue;
        }
        let Some((user, password)) = line.split_once(':') else {
            return Err(format!("line {n}: expected <site>:<password>"));
        };
        let user = user.trim();
        if user.is_empty() {
            return Err(format!("line {n}: empty site name"));
        }
        if password.trim().is_empty() {
            return Err(format!("line {n}: empty password"));
        }
        users.push(user.to_string());
    }
    Ok(users)
}

fn bounded(key: &str, n: usize) -> Result<(), ConfigError> {
    if !(1..=MAX_BUFFER).contains(&n) {
        return Err(invalid(key, format!("{n} is not in 1..={MAX_BUFFER}")));
    }
    Ok(())
}

/// Checks each endpoint uses `scheme` (`tls` when `tls.enabled`, `tcp` otherwise: one
/// transport for every link, so none is left unencrypted or unidentified by mistake) and
/// (with the transport) parses as Zenoh's.
fn endpoints(key: &str, list: &[String], scheme: &str) -> Result<(), ConfigError> {
    for (i, e) in list.iter().enumerate() {
        #[cfg(feature = "transport")]
        e.parse::<zenoh::config::EndPoint>()
            .map_err(|err| invalid(format!("{key}[{i}]"), format!("{e:?}: {err}")))?;
        if !e.starts_with(&format!("{scheme}/")) {
            let why = if scheme == "tls" {
                "with tls.enabled every endpoint is tls/<host>:<port>"
            } else {
                "only tcp/<host>:<port> without TLS (tls.enabled = false); tls/ needs tls.enabled"
            };
            return Err(invalid(format!("{key}[{i}]"), format!("{e:?}: {why}")));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The commented default file, as a station's `[federation]` section.
    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    struct File {
        federation: FederationConfig,
    }

    #[test]
    fn the_default_file_is_the_default_config() {
        let text = include_str!("../federation.default.toml");
        let file: File = toml::from_str(text).unwrap();
        assert_eq!(file.federation, FederationConfig::default());
        assert_eq!(file.federation.validate(), Ok(()));
    }

    #[test]
    fn environment_aggregated_is_accepted_with_its_window_and_properties() {
        let text = "[federation.environment]\nmode = \"aggregated\"\nwindow_s = 5\n\
                    properties = [\"sea_water_temperature\", \"sea_water_salinity\"]\n";
        let file: File = toml::from_str(text).unwrap();
        let env = &file.federation.environment;
        assert_eq!(env.mode, EnvironmentMode::Aggregated);
        assert_eq!((env.window_s, env.properties.len()), (5, 2));
        // Lowest priority and dropped on congestion unless configured otherwise.
        assert_eq!(env.qos.priority, Priority::Background);
        assert_eq!(env.qos.congestion, Congestion::Drop);
        assert_eq!(file.federation.validate(), Ok(()));
        let both_ends = |window_s| FederationConfig {
            environment: EnvironmentPolicy {
                mode: EnvironmentMode::Aggregated,
                window_s,
                ..EnvironmentPolicy::default()
            },
            ..FederationConfig::default()
        };
        assert_eq!(both_ends(MIN_ENVIRONMENT_WINDOW_S).validate(), Ok(()));
        assert_eq!(both_ends(MAX_ENVIRONMENT_WINDOW_S).validate(), Ok(()));
        let e = toml::from_str::<File>("[federation.environment]\nwindow = 5\n").unwrap_err();
        assert!(e.to_string().contains("window"), "{e}");
    }

    #[test]
    fn the_default_listens_on_loopback_only_and_does_not_scout() {
        let c = FederationConfig::default();
        assert!(c.listen.iter().all(|e| e.starts_with("tcp/127.0.0.1:")));
        assert!(!c.multicast_scouting && !c.gossip && c.connect.is_empty());
    }

    #[test]
    fn alarms_get_a_link_of_their_own_only_on_a_site_that_connects() {
        let connecting = |own_link| FederationConfig {
            listen: Vec::new(),
            connect: vec!["tcp/127.0.0.1:7447".into()],
            alarms: AlarmsPolicy {
                own_link,
                ..AlarmsPolicy::default()
            },
            ..FederationConfig::default()
        };
        assert!(connecting(true).alarm_link());
        assert!(!connecting(false).alarm_link());
        // One that listens too keeps alarms where the sites connecting to it send theirs.
        let relay = FederationConfig {
            listen: vec!["tcp/127.0.0.1:7448".into()],
            ..connecting(true)
        };
        assert!(!relay.alarm_link());
        // A site that only listens (the default) has the connecting site's alarm link.
        assert!(FederationConfig::default().alarms.own_link);
        assert!(!FederationConfig::default().alarm_link());
    }

    #[test]
    fn an_unknown_key_is_refused() {
        let e = toml::from_str::<File>("[federation]\nsite = \"a\"\nsitee = \"b\"\n").unwrap_err();
        assert!(e.to_string().contains("sitee"), "{e}");
    }

    fn refused(edit: impl FnOnce(&mut FederationConfig)) -> String {
        let mut c = FederationConfig::default();
        edit(&mut c);
        c.validate().unwrap_err().to_string()
    }

    #[test]
    fn each_bad_value_names_its_key() {
        assert!(refused(|c| c.site = "a/b".into()).starts_with("federation.site:"));
        assert!(
            refused(|c| c.remote_sites = vec!["x".into(), "x".into()])
                .starts_with("federation.remote_sites[1]:")
        );
        assert!(
            refused(|c| c.remote_sites = vec!["local".into()])
                .starts_with("federation.remote_sites[0]:")
        );
        assert!(
            refused(|c| c.listen = vec!["udp/127.0.0.1:1".into()])
                .starts_with("federation.listen[0]:")
        );
        assert!(
            refused(|c| c.connect = vec!["nonsense".into()]).starts_with("federation.connect[0]:")
        );
        assert!(
            refused(|c| c.positions.max_rate_hz = f64::NAN)
                .starts_with("federation.positions.max_rate_hz:")
        );
        assert!(refused(|c| c.alarms.catchup = 0).starts_with("federation.alarms.catchup:"));
        assert!(
            refused(|c| c.environment.window_s = 4).starts_with("federation.environment.window_s:")
        );
        assert!(
            refused(|c| c.environment.window_s = 3601)
                .starts_with("federation.environment.window_s:")
        );
        assert!(
            refused(|c| c.environment.properties = vec!["sea water".into()])
                .starts_with("federation.environment.properties[0]:")
        );
        assert!(
            refused(|c| c.environment.properties = vec!["t".into(), "s".into(), "t".into()])
                .starts_with("federation.environment.properties[2]:")
        );
        assert!(
            refused(|c| c.limits.remote_environment = 0)
                .starts_with("federation.limits.remote_environment:")
        );
        assert!(refused(|c| c.link_rate_kbps = 1).starts_with("federation.link_rate_kbps:"));
        assert!(
            refused(|c| c.link_rate_kbps = LINK_RATE_KBPS_MAX + 1)
                .starts_with("federation.link_rate_kbps:")
        );
        assert!(refused(|c| c.mode = Mode::Client).starts_with("federation.listen:"));
        assert!(
            refused(|c| {
                c.mode = Mode::Client;
                c.listen.clear();
            })
            .starts_with("federation.connect:")
        );
    }

    /// A directory with this site's password file and a dictionary of `entries`.
    fn files(entries: &str) -> (tempdir::Dir, FederationConfig) {
        let dir = tempdir::Dir::new();
        std::fs::write(dir.path("password"), "s3cret-ship\n").unwrap();
        std::fs::write(dir.path("sites.txt"), entries).unwrap();
        let c = FederationConfig {
            enabled: true,
            site: "ship".into(),
            remote_sites: vec!["shore".into()],
            password_file: dir.path("password"),
            credentials_file: dir.path("sites.txt"),
            ..FederationConfig::default()
        };
        (dir, c)
    }

    /// A scratch directory removed on drop (no tempfile dependency for three files).
    mod tempdir {
        use std::path::PathBuf;

        pub struct Dir(PathBuf);

        impl Dir {
            pub fn new() -> Self {
                static N: std::sync::atomic::AtomicU32 = std::sync::atomic::AtomicU32::new(0);
                let n = N.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let dir = std::env::temp_dir()
                    .join(format!("shoal-fed-config-{}-{n}", std::process::id()));
                std::fs::create_dir_all(&dir).unwrap();
                Self(dir)
            }

            pub fn path(&self, name: &str) -> PathBuf {
                self.0.join(name)
            }
        }

        impl Drop for Dir {
            fn drop(&mut self) {
                let _ = std::fs::remove_dir_all(&self.0);
            }
        }
    }

    #[test]
    fn an_enabled_site_needs_identity_unless_insecure_open() {
        let c = FederationConfig {
            enabled: true,
            ..FederationConfig::default()
        };
        let e = c.validate().unwrap_err().to_string();
        assert!(e.starts_with("federation.password_file:"), "{e}");
        assert!(e.contains("insecure_open"), "{e}");
        let open = FederationConfig {
            insecure_open: true,
            ..c
        };
        assert_eq!(open.validate(), Ok(()));
        assert_eq!(open.identity(), Ok(None));
        // Not enabled: the files are not read (the station does not federate).
        assert_eq!(FederationConfig::default().validate(), Ok(()));
    }

    #[test]
    fn the_identity_is_read_from_the_files() {
        let (_dir, c) = files("shore:pw-shore\n\n  other : x \n");
        assert_eq!(c.validate(), Ok(()));
        let id = c.identity().unwrap().unwrap();
        assert_eq!((id.mechanisms(), id.encrypted()), ("usrpwd", false));
        let up = id.usrpwd.unwrap();
        assert_eq!(up.user, "ship");
        assert_eq!(up.password.expose(), "s3cret-ship");
        assert_eq!(up.users, ["shore", "other"]);
        assert_eq!(up.credentials_file, c.credentials_file.to_str().unwrap());
        // From the environment's key instead of a file.
        let c = FederationConfig {
            password_file: PathBuf::new(),
            password: Secret::new("from-env"),
            ..c
        };
        let id = c.identity().unwrap().unwrap();
        assert_eq!(id.usrpwd.unwrap().password.expose(), "from-env");
    }

    #[test]
    fn identity_errors_name_the_key_and_never_the_password() {
        let (dir, c) = files("shore:pw-shore\n");
        let error = |c: &FederationConfig| c.validate().unwrap_err().to_string();
        let e = error(&FederationConfig {
            password_file: dir.path("missing"),
            ..c.clone()
        });
        assert!(
            e.starts_with("federation.password_file: cannot read"),
            "{e}"
        );
        let e = error(&FederationConfig {
            credentials_file: dir.path("missing"),
            ..c.clone()
        });
        assert!(
            e.starts_with("federation.credentials_file: cannot read"),
            "{e}"
        );
        let e = error(&FederationConfig {
            credentials_file: PathBuf::new(),
            ..c.clone()
        });
        assert!(e.starts_with("federation.credentials_file:"), "{e}");
        let e = error(&FederationConfig {
            password: Secret::new("s3cret-ship"),
            ..c.clone()
        });
        assert!(e.starts_with("federation.password:"), "{e}");
        assert!(!e.contains("s3cret"), "{e}");
        // Every remote site needs an entry.
        let e = error(&FederationConfig {
            remote_sites: vec!["shore".into(), "ship2".into()],
            ..c.clone()
        });
        assert!(
            e.starts_with("federation.remote_sites[1]: ship2 has no entry"),
            "{e}"
        );
        // A malformed dictionary names the line, not its content.
        std::fs::write(dir.path("sites.txt"), "shore:pw-shore\nship2 pw-secret\n").unwrap();
        let e = error(&c);
        assert!(e.contains("line 2: expected <site>:<password>"), "{e}");
        assert!(!e.contains("pw-"), "{e}");
        std::fs::write(dir.path("sites.txt"), "shore:\n").unwrap();
        assert!(error(&c).contains("line 1: empty password"));
        std::fs::write(dir.path("password"), "  \n").unwrap();
        std::fs::write(dir.path("sites.txt"), "shore:pw\n").unwrap();
        assert!(error(&c).starts_with("federation.password_file: the password is empty"));
    }

    #[test]
    fn identity_takes_only_configured_links() {
        let (_dir, c) = files("shore:pw\n");
        let e = refused_from(&c, |c| c.connect = vec!["tcp/127.0.0.1:1".into()]);
        assert!(e.starts_with("federation.connect:"), "{e}");
        assert!(refused_from(&c, |c| c.gossip = true).starts_with("federation.gossip:"));
        assert!(
            refused_from(&c, |c| c.multicast_scouting = true)
                .starts_with("federation.multicast_scouting:")
        );
        // Without identity, a site may listen and connect as before.
        let mut open = c;
        open.insecure_open = true;
        open.connect = vec!["tcp/127.0.0.1:1".into()];
        assert_eq!(open.validate(), Ok(()));
    }

    fn refused_from(c: &FederationConfig, edit: impl FnOnce(&mut FederationConfig)) -> String {
        let mut c = c.clone();
        edit(&mut c);
        c.validate().unwrap_err().to_string()
    }

    #[test]
    fn the_password_is_never_shown() {
        let c = FederationConfig {
            password: Secret::new("s3cret"),
            ..FederationConfig::default()
        };
        assert!(!format!("{c:?}").contains("s3cret"));
        let text = toml::to_string(&c).unwrap();
        assert!(
            !text.contains("s3cret") && text.contains("<redacted>"),
            "{text}"
        );
    }

    /// An enabled site `ship` with TLS files issued by a station CA, and no password.
    #[cfg(feature = "transport")]
    fn tls_site() -> (tempfile::TempDir, FederationConfig) {
        let (dir, tls) = crate::tls::tests::site_files("ship");
        let c = FederationConfig {
            enabled: true,
            site: "ship".into(),
            listen: vec!["tls/127.0.0.1:7447".into()],
            remote_sites: vec!["shore".into()],
            tls,
            ..FederationConfig::default()
        };
        (dir, c)
    }

    #[cfg(feature = "transport")]
    #[test]
    fn tls_alone_is_site_identity() {
        let (_dir, c) = tls_site();
        assert_eq!(c.validate(), Ok(()));
        let id = c.identity().unwrap().unwrap();
        assert_eq!((id.mechanisms(), id.encrypted()), ("tls", true));
        assert!(id.usrpwd.is_none());
        let tls = id.tls.unwrap();
        assert_eq!(tls.certificate, c.tls.certificate.to_str().unwrap());
        assert!(tls.verify_name);
        // With both ends identified, a site may listen and connect.
        let mut both = c.clone();
        both.connect = vec!["tls/127.0.0.1:7448".into()];
        assert_eq!(both.validate(), Ok(()));
        // Gossip and scouting would still open links nobody configured.
        assert!(refused_from(&c, |c| c.gossip = true).starts_with("federation.gossip:"));
    }

    #[cfg(feature = "transport")]
    #[test]
    fn tls_and_a_password_together() {
        let (dir, c) = tls_site();
        std::fs::write(dir.path().join("password"), "pw\n").unwrap();
        std::fs::write(dir.path().join("sites.txt"), "shore:pw2\n").unwrap();
        let c = FederationConfig {
            password_file: dir.path().join("password"),
            credentials_file: dir.path().join("sites.txt"),
            ..c
        };
        let id = c.identity().unwrap().unwrap();
        assert_eq!(id.mechanisms(), "tls+usrpwd");
        // Half of the user-password settings is an error, not silently TLS alone.
        let e = refused_from(&c, |c| c.credentials_file = PathBuf::new());
        assert!(e.starts_with("federation.credentials_file:"), "{e}");
    }

    #[cfg(feature = "transport")]
    #[test]
    fn tls_endpoints_and_settings_are_checked() {
        let (_dir, c) = tls_site();
        // Every link is TLS with tls.enabled, and TCP without.
        let e = refused_from(&c, |c| c.listen = vec!["tcp/127.0.0.1:7447".into()]);
        assert!(e.starts_with("federation.listen[0]:"), "{e}");
        assert!(e.contains("tls/<host>:<port>"), "{e}");
        let e = refused(|c| c.connect = vec!["tls/127.0.0.1:7447".into()]);
        assert!(e.starts_with("federation.connect[0]:"), "{e}");
        assert!(e.contains("tls.enabled"), "{e}");
        let e = refused_from(&c, |c| c.insecure_open = true);
        assert!(e.starts_with("federation.insecure_open:"), "{e}");
        for (key, edit) in [
            (
                "tls.certificate",
                (|c: &mut FederationConfig| c.tls.certificate = PathBuf::new())
                    as fn(&mut FederationConfig),
            ),
            ("tls.private_key", |c| c.tls.private_key = PathBuf::new()),
            ("tls.trusted_cas", |c| c.tls.trusted_cas = PathBuf::new()),
        ] {
            let e = refused_from(&c, edit);
            assert!(e.starts_with(&format!("federation.{key}:")), "{e}");
            assert!(e.contains("shoal keys site-cert"), "{e}");
        }
        // A file that cannot be read is named with its key.
        let e = refused_from(&c, |c| c.tls.trusted_cas = "/nonexistent/cas.pem".into());
        assert!(
            e.starts_with("federation.tls.trusted_cas: cannot read /nonexistent/cas.pem"),
            "{e}"
        );
        // The certificate must be this site's.
        let e = refused_from(&c, |c| c.site = "ship2".into());
        assert!(e.starts_with("federation.tls.certificate:"), "{e}");
    }
}
