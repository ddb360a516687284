//! `shoal bench federation`: the federation over an emulated satellite WAN. Three sites,
//! each a real `shoal station` in its own network namespace on its own DDS domain:
//! `ship-1`, the `shore` and `ship-2`, joined by the user-space WAN of
//! [`super::wan`] (10.77.0.1, .2, .3). The shore is a Zenoh router listening on
//! tcp/10.77.0.2:7447 with site identity; the ships are clients of it (the documented
//! star, docs/federation.md "Topologies"), each behind the satellite profile (600 ms RTT,
//! 64 kbit/s, 2 % loss by default, both ways); the shore's own link is clear.
//!
//! Each ship's load is a helper process in its namespace (`bench wan-load`): `shoal
//! swarm`'s vehicles on one participant, four vehicles that take `hold` tasks (dispatched
//! through the ship's HTTP API and answered accepted, running, done), and an alarm
//! (a warning `Event`, stamped when published) at a fixed period.
//!
//! The run, of `--seconds` D after the shore first sees ship-1's fleet: two sites until
//! D/4, when ship-2 joins; ship-1's link is cut from D/2 for `--outage` seconds; at D the
//! loads stop raising alarms and tasks and the benchmark waits for the shore to settle.
//! Measured at the shore through `GET /api/federation`, polled every 100 ms, and at the
//! emulator: the alarm latency (ship publish → first poll that shows it), the age of
//! ship-1's positions and the uplink's queue over time, ship-1's uplink bytes/s with two
//! sites ([D/8, D/4)) and with three ([3D/8, D/2)), and, once settled, each alarm and task
//! transition ship-1 numbered present at the shore exactly once. The shore is ship-1's
//! command-lease standby (`--lease-timeout`): when it sees ship-1 lost in the outage it
//! takes its vehicles' leases over, timed from the cut and from the loss, and once the link
//! is back both sites must agree on every lease.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use shoal_model::now_ms;
use tokio::io::{AsyncBufReadExt as _, AsyncWriteExt as _};
use tokio_util::sync::CancellationToken;

mod load;

pub use self::load::LoadArgs;
pub(super) use self::load::wan_load;
use super::helpers::{date, machine, percentile};
use super::wan::{self, Namespaces, Profile, SiteLink, Wan};

/// The sites, in the emulator's order; host `i + 1` in 10.77.0.0/24.
const SITES: [&str; 3] = ["ship-1", "shore", "ship-2"];
const SHIP: usize = 0;
const SHORE: usize = 1;
const SHIP2: usize = 2;
/// Each station's HTTP API, on its own namespace's loopback.
const API_PORT: u16 = 8080;
/// The shore's Zenoh endpoint.
const ZENOH: &str = "tcp/10.77.0.2:7447";
/// How often the shore's picture is read (the alarm latency's resolution).
const POLL: Duration = Duration::from_millis(100);
/// Vehicles of each ship that take tasks (the rest are `shoal swarm`'s).
const TASK_VEHICLES: usize = 4;

/// `shoal bench federation`'s flags.
#[derive(Debug, Clone, clap::Args)]
pub struct Plan {
    /// Seconds of the run, the outage included (the long run: 30 minutes).
    #[arg(long, default_value_t = 1800)]
    pub seconds: u64,
    /// Seconds ship-1's link is cut, from the middle of the run.
    #[arg(long, default_value_t = 300)]
    pub outage: u64,
    /// Vehicles on each ship (four of them take tasks).
    #[arg(long, default_value_t = 500)]
    pub vehicles: usize,
    /// State vectors per second per vehicle on the ships' DDS (the federation sends
    /// positions at its own `positions.max_rate_hz`, 0.2 Hz).
    #[arg(long, default_value_t = 1.0)]
    pub state_rate: f64,
    /// Round-trip time between a ship and the shore, ms.
    #[arg(long, default_value_t = 600.0)]
    pub rtt_ms: f64,
    /// A ship's link rate each way, kbit/s.
    #[arg(long, default_value_t = 64.0)]
    pub rate_kbps: f64,
    /// Packet loss each way, percent.
    #[arg(long, default_value_t = 2.0)]
    pub loss_pct: f64,
    /// The satellite modem's buffer each way, bytes (tail drop beyond it).
    #[arg(long, default_value_t = 32_768)]
    pub queue_bytes: usize,
    /// Seconds between two alarms of a ship.
    #[arg(long, default_value_t = 2.0)]
    pub alarm_every: f64,
    /// Seconds between two tasks of a ship (each makes four transitions).
    #[arg(long, default_value_t = 10.0)]
    pub task_every: f64,
    /// Seeds the links' loss.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// First of the three DDS domains (one per site).
    #[arg(long, default_value_t = 10)]
    pub domain: u16,
    /// The command lease's failover timeout, s: the shore is ship-1's standby and takes
    /// its vehicles' leases over this long after it sees ship-1 offline in the outage.
    #[arg(long, default_value_t = 10)]
    pub lease_timeout: u64,
    /// Zenoh's link lease on every site, ms (`[federation] link_lease_ms`): how long a
    /// silent link lives, so how soon the shore sees ship-1 lost in the outage.
    #[arg(long, default_value_t = 10_000)]
    pub link_lease_ms: u64,
    /// Leave every site's `link_rate_kbps` at 0 (a fast link's buffers) instead of the
    /// ships' rate, to see what the shaping does.
    #[arg(long)]
    pub unshaped: bool,
    /// `net.ipv4.tcp_notsent_lowat` in every site's namespace, bytes (0: the kernel's
    /// default, unlimited): how much data a TCP socket holds not yet sent. Zenoh's
    /// priorities act only on what is not yet in the socket, and `SO_SNDBUF` does not bound
    /// it on this kernel (a shaped link was measured with 35 kB unsent).
    #[arg(long, default_value_t = 0)]
    pub notsent_lowat: u32,
    /// Keep the stations' logs (their directory is printed) even when the run succeeds.
    #[arg(long)]
    pub keep_logs: bool,
    /// The stations' log filter (`RUST_LOG` syntax), e.g. `warn,shoal_federation=debug`
    /// to follow their catch-up and lease queries (with --keep-logs).
    #[arg(long, value_name = "FILTER", default_value = STATION_LOG)]
    pub station_log: String,
    /// Also write the figures as JSON here (what the test suite checks).
    #[arg(long)]
    pub summary: Option<PathBuf>,
}

/// The stations' log filter by default: warnings, and Cyclone's errors only.
const STATION_LOG: &str = "warn,cyclonedds=error";

impl Plan {
    fn check(&self) -> Result<()> {
        if self.seconds < 40 {
            bail!("--seconds {} is too short (at least 40)", self.seconds);
        }
        if self.outage * 8 >= self.seconds * 3 {
            bail!(
                "--outage {} must be under 3/8 of --seconds {} (the run's last eighth is measured with the link up)",
                self.outage,
                self.seconds
            );
        }
        if !(1_000..=600_000).contains(&self.link_lease_ms) {
            bail!(
                "--link-lease-ms {} is outside 1000..=600000",
                self.link_lease_ms
            );
        }
        if !(1..=86_400).contains(&self.lease_timeout) {
            bail!(
                "--lease-timeout {} is outside 1..=86400",
                self.lease_timeout
            );
        }
        if !(TASK_VEHICLES + 1..=5000).contains(&self.vehicles) {
            bail!("--vehicles {} is outside 5..=5000", self.vehicles);
        }
        let ok = (0.0..=100.0).contains(&self.loss_pct)
            && (0.0..=60_000.0).contains(&self.rtt_ms)
            && (1.0..=1_000_000.0).contains(&self.rate_kbps)
            && (0.1..=3600.0).contains(&self.alarm_every)
            && (0.1..=3600.0).contains(&self.task_every)
            && (0.01..=10.0).contains(&self.state_rate)
            && self.queue_bytes >= 1500;
        if !ok {
            bail!("a profile value is out of range: {self:?}");
        }
        Ok(())
    }

    /// A ship's link, both ways.
    fn satellite(&self) -> Profile {
        Profile {
            one_way: Duration::from_secs_f64(self.rtt_ms / 2000.0),
            rate_bps: Some(self.rate_kbps * 1000.0),
            loss: self.loss_pct / 100.0,
            queue_bytes: self.queue_bytes,
        }
    }

    /// Every site's `[federation] link_rate_kbps`: the ships' rate, as an operator sets it
    /// on the sites facing the satellite links, or 0 with `--unshaped`.
    fn link_rate_kbps(&self) -> String {
        if self.unshaped {
            "0".into()
        } else {
            format!("{}", self.rate_kbps.round().max(2.0))
        }
    }

    fn at(&self, fraction: f64) -> Duration {
        #[allow(clippy::cast_precision_loss)]
        Duration::from_secs_f64(self.seconds as f64 * fraction)
    }
}

/// One ship's alarms or transitions as the shore holds them, against what the ship
/// numbered.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub(super) struct Tally {
    /// What the ship numbered and published (its `sent_*` counter).
    pub(super) sent: u64,
    /// Distinct ones at the shore.
    pub(super) distinct: u64,
    /// Entries beyond the first of the same one.
    pub(super) duplicated: u64,
    /// Numbered by the ship, not at the shore when counted (lost, or still on its way).
    pub(super) lost: u64,
}

impl Tally {
    /// `keys`: one per entry the shore holds for the ship (an alarm's event id, a
    /// transition's task and state).
    fn of<'a>(sent: u64, keys: impl Iterator<Item = &'a str>) -> Self {
        let mut counts: HashMap<&str, u64> = HashMap::new();
        for k in keys {
            *counts.entry(k).or_default() += 1;
        }
        let distinct = counts.len() as u64;
        Self {
            sent,
            distinct,
            duplicated: counts.values().map(|n| n - 1).sum(),
            lost: sent.saturating_sub(distinct),
        }
    }

    fn exact(&self) -> bool {
        self.duplicated == 0 && self.lost == 0 && self.distinct == self.sent
    }
}

/// What the test suite checks, written with `--summary`.
#[derive(Debug, Default, serde::Serialize)]
struct Summary {
    seconds: u64,
    outage_s: u64,
    vehicles: usize,
    alarms_raised: usize,
    alarms_seen: usize,
    alarm_latency_p50_ms: f64,
    alarm_latency_p99_ms: f64,
    alarms: Tally,
    transitions: Tally,
    raised_alarms_missing: usize,
    uplink_2_sites_bps: f64,
    uplink_3_sites_bps: f64,
    ship_vehicles_at_shore: usize,
    settled: bool,
    lease: LeaseFigures,
}

/// The command lease of ship-1's vehicles through the outage: the shore, its standby,
/// takes them over; ship-1 gives way when its link is back.
#[derive(Debug, Default, Clone, serde::Serialize)]
struct LeaseFigures {
    timeout_s: u64,
    /// ship-1's vehicles with a lease at the shore before the cut.
    leased_before: usize,
    /// From the cut until the shore saw ship-1 offline, s.
    detected_s: Option<f64>,
    /// From the cut until the shore held every lease it had seen ship-1 hold, s.
    taken_over_s: Option<f64>,
    /// Leases the shore held at the end.
    held_by_shore_at_end: usize,
    /// Leases ship-1 still believed it held at the end.
    held_by_ship_at_end: usize,
    /// Vehicles on which the shore and ship-1 disagree at the end (holder or term).
    disagreeing_at_end: usize,
}

/// ship-1's vehicles' leases in a site's document: vehicle → (holder, term).
fn leases_of_ship(doc: &serde_json::Value) -> BTreeMap<String, (String, u64)> {
    doc["leases"]
        .as_array()
        .into_iter()
        .flatten()
        .filter(|l| l["home"] == SITES[SHIP])
        .filter_map(|l| {
            Some((
                l["vehicle_id"].as_str()?.to_owned(),
                (l["holder"].as_str()?.to_owned(), l["term"].as_u64()?),
            ))
        })
        .collect()
}

/// The shore's picture as the poller keeps it.
#[derive(Debug, Default)]
struct Seen {
    /// ship-1's alarms by event id: when a poll first showed each, ms.
    alarms: HashMap<String, i64>,
    /// ship-1's transitions (task, state): when first shown.
    transitions: HashMap<String, i64>,
    /// The latest document.
    doc: serde_json::Value,
    polls: u64,
    failed: u64,
}

/// One sample of the backlog: the polls of one sampling period, averaged. Every poll
/// counts, not one per period: positions cross in bursts every 5 s (each vehicle once per
/// period, all due together), and a sample a period taken at a fixed phase of that burst
/// would show the queue always full or always empty.
#[derive(Debug, Clone, Copy)]
struct Sample {
    t: Duration,
    /// The median age of ship-1's vehicles' data at the shore, s, averaged over the polls.
    age_p50_s: f64,
    /// The largest age any poll saw, s.
    age_max_s: f64,
    /// Bytes in ship-1's uplink queue, averaged over the polls.
    queued: f64,
    /// ship-1's uplink bytes so far.
    up_bytes: u64,
}

/// The polls of the current sampling period.
#[derive(Debug, Default)]
struct Period {
    polls: u32,
    age_p50_sum: f64,
    age_max: f64,
    queued_sum: f64,
}

impl Period {
    fn add(&mut self, age_p50_s: f64, age_max_s: f64, queued: u64) {
        if age_p50_s.is_finite() {
            self.polls += 1;
            self.age_p50_sum += age_p50_s;
            self.age_max = self.age_max.max(age_max_s);
            #[allow(clippy::cast_precision_loss)]
            let q = queued as f64;
            self.queued_sum += q;
        }
    }

    /// The sample at `t` with ship-1's uplink bytes so far; starts a new period.
    fn take(&mut self, t: Duration, up_bytes: u64) -> Sample {
        let n = f64::from(self.polls.max(1));
        let s = Sample {
            t,
            age_p50_s: if self.polls == 0 {
                f64::NAN
            } else {
                self.age_p50_sum / n
            },
            age_max_s: self.age_max,
            queued: self.queued_sum / n,
            up_bytes,
        };
        *self = Self::default();
        s
    }
}

/// A child of the run, in a site's namespace.
struct Child {
    name: String,
    child: tokio::process::Child,
}

impl Child {
    /// Starts `shoal <args>` in `netns` with `env`; its stderr goes to `log`.
    fn start(
        name: &str,
        netns: &str,
        args: &[String],
        env: &[(String, String)],
        log: &Path,
        stdout: bool,
    ) -> Result<Self> {
        let exe = std::env::current_exe()?;
        let err = std::fs::File::create(log)?;
        let child = tokio::process::Command::new("ip")
            .args(["netns", "exec", netns])
            .arg(exe)
            .args(args)
            .envs(env.iter().map(|(k, v)| (k, v)))
            .stdin(Stdio::piped())
            .stdout(if stdout {
                Stdio::piped()
            } else {
                Stdio::null()
            })
            .stderr(err)
            .kill_on_drop(true)
            .spawn()
            .with_context(|| format!("cannot start the {name}"))?;
        Ok(Self {
            name: name.to_owned(),
            child,
        })
    }

    /// Closes its stdin (it stops) and waits; kills it after 15 s.
    async fn stop(mut self) {
        drop(self.child.stdin.take());
        if tokio::time::timeout(Duration::from_secs(15), self.child.wait())
            .await
            .is_err()
        {
            eprintln!("federation: the {} did not stop; killed", self.name);
            let _ = self.child.kill().await;
        }
    }
}

/// `GET path` on a station's API inside `netns`; the body.
async fn get(netns: &str, path: &str) -> Result<String> {
    let (netns, path) = (netns.to_owned(), path.to_owned());
    tokio::task::spawn_blocking(move || {
        wan::in_netns(&netns, move || {
            use std::io::{Read as _, Write as _};
            let mut s = std::net::TcpStream::connect(("127.0.0.1", API_PORT))?;
            s.set_read_timeout(Some(Duration::from_secs(10)))?;
            write!(s, "GET {path} HTTP/1.0\r\nHost: localhost\r\n\r\n")?;
            let mut out = Vec::new();
            s.read_to_end(&mut out)?;
            let text = String::from_utf8_lossy(&out);
            match text.split_once("\r\n\r\n") {
                Some((head, body))
                    if head.starts_with("HTTP/1.1 200") || head.starts_with("HTTP/1.0 200") =>
                {
                    Ok(body.to_owned())
                }
                _ => Err(std::io::Error::other(format!(
                    "not 200: {}",
                    text.lines().next().unwrap_or("")
                ))),
            }
        })
    })
    .await?
}

async fn get_json(netns: &str, path: &str) -> Result<serde_json::Value> {
    Ok(serde_json::from_str(&get(netns, path).await?)?)
}

/// Writes a site's password and its dictionary of the others; the environment pointing
/// its station at them.
fn identity(
    dir: &Path,
    site: &str,
    passwords: &BTreeMap<&str, String>,
    remotes: &[&str],
) -> Result<Vec<(String, String)>> {
    use std::os::unix::fs::OpenOptionsExt as _;
    let write = |path: &Path, text: &str| -> Result<()> {
        use std::io::Write as _;
        let mut f = std::fs::OpenOptions::new()
            .write(true)
            .create(true)
            .truncate(true)
            .mode(0o600)
            .open(path)?;
        f.write_all(text.as_bytes())?;
        Ok(())
    };
    let password_file = dir.join(format!("{site}.password"));
    let sites_file = dir.join(format!("{site}.sites"));
    write(&password_file, &format!("{}\n", passwords[site]))?;
    let dictionary: String = remotes
        .iter()
        .map(|r| format!("{r}:{}\n", passwords[r]))
        .collect();
    write(&sites_file, &dictionary)?;
    let list = remotes
        .iter()
        .map(|r| format!("\"{r}\""))
        .collect::<Vec<_>>()
        .join(", ");
    Ok(vec![
        ("SHOAL_FEDERATION__ENABLED".into(), "true".into()),
        ("SHOAL_FEDERATION__SITE".into(), site.into()),
        ("SHOAL_FEDERATION__REMOTE_SITES".into(), format!("[{list}]")),
        (
            "SHOAL_FEDERATION__PASSWORD_FILE".into(),
            password_file.display().to_string(),
        ),
        (
            "SHOAL_FEDERATION__CREDENTIALS_FILE".into(),
            sites_file.display().to_string(),
        ),
    ])
}

/// The sites' processes and the emulator: dropped in reverse order, so the namespaces go
/// last.
struct Run {
    dir: PathBuf,
    netns: Namespaces,
    wan: Wan,
    stations: Vec<Option<Child>>,
    loads: Vec<Option<Child>>,
    raised: Arc<Mutex<Vec<(String, i64)>>>,
    tasks: Arc<Mutex<Vec<String>>>,
}

impl Run {
    fn station(
        &mut self,
        plan: &Plan,
        site: usize,
        passwords: &BTreeMap<&str, String>,
    ) -> Result<()> {
        let name = SITES[site];
        let mut env = if site == SHORE {
            let mut env = identity(&self.dir, name, passwords, &["ship-1", "ship-2"])?;
            env.extend([
                // ship-1's standby: takes its leases over when it is lost, never claims.
                ("SHOAL_FEDERATION__LEASE__HOME".into(), "false".into()),
                ("SHOAL_FEDERATION__MODE".into(), "router".into()),
                ("SHOAL_FEDERATION__LISTEN".into(), format!("[\"{ZENOH}\"]")),
                ("SHOAL_FEDERATION__CONNECT".into(), "[]".into()),
                // Every alarm and transition of the run stays in the picture, to be
                // counted at the end.
                (
                    "SHOAL_FEDERATION__LIMITS__REMOTE_ALARMS".into(),
                    "100000".into(),
                ),
                (
                    "SHOAL_FEDERATION__LIMITS__REMOTE_TRANSITIONS".into(),
                    "100000".into(),
                ),
            ]);
            env
        } else {
            let other = if site == SHIP { "ship-2" } else { "ship-1" };
            let mut env = identity(&self.dir, name, passwords, &["shore", other])?;
            if site == SHIP {
                env.push(("SHOAL_FEDERATION__LEASE__STANDBY".into(), "shore".into()));
            }
            env.extend([
                (
                    "SHOAL_FEDERATION__MODE".into(),
                    if std::env::var_os("SHOAL_EXPERIMENT_URGENT").is_some() {
                        "peer"
                    } else {
                        "client"
                    }
                    .into(),
                ),
                ("SHOAL_FEDERATION__LISTEN".into(), "[]".into()),
                ("SHOAL_FEDERATION__CONNECT".into(), format!("[\"{ZENOH}\"]")),
            ]);
            env
        };
        env.extend([
            (
                "SHOAL_DDS__DOMAIN_ID".into(),
                (plan.domain + site as u16).to_string(),
            ),
            ("SHOAL_SECURITY__ENABLED".into(), "false".into()),
            (
                "SHOAL_FEDERATION__LEASE__FAILOVER_TIMEOUT_MS".into(),
                (plan.lease_timeout * 1000).to_string(),
            ),
            (
                "SHOAL_FEDERATION__LINK_LEASE_MS".into(),
                plan.link_lease_ms.to_string(),
            ),
            (
                "SHOAL_FEDERATION__LINK_RATE_KBPS".into(),
                plan.link_rate_kbps(),
            ),
            // Reached only from inside the site's own namespace.
            ("SHOAL_CONSOLE__AUTH__ENABLED".into(), "false".into()),
            ("RUST_LOG".into(), plan.station_log.clone()),
        ]);
        let db = self.dir.join(format!("{name}.db"));
        let args = [
            "--insecure",
            "station",
            "--scenario",
            "none",
            "--listen",
            &format!("127.0.0.1:{API_PORT}"),
            "--db",
            &db.display().to_string(),
            "--exit-on-stdin-close",
        ]
        .map(String::from);
        let log = self.dir.join(format!("{name}.log"));
        self.stations[site] = Some(Child::start(
            &format!("{name} station"),
            self.netns.name(site),
            &args,
            &env,
            &log,
            false,
        )?);
        Ok(())
    }

    fn load(&mut self, plan: &Plan, site: usize) -> Result<()> {
        let name = SITES[site];
        let args = [
            "--insecure".to_string(),
            "bench".into(),
            "wan-load".into(),
            "--domain".into(),
            (plan.domain + site as u16).to_string(),
            "--site".into(),
            name.into(),
            "--vehicles".into(),
            plan.vehicles.to_string(),
            "--rate".into(),
            plan.state_rate.to_string(),
            "--alarm-every".into(),
            plan.alarm_every.to_string(),
            "--task-every".into(),
            plan.task_every.to_string(),
            "--api".into(),
            API_PORT.to_string(),
        ];
        let env = [
            ("SHOAL_SECURITY__ENABLED".to_string(), "false".to_string()),
            ("RUST_LOG".into(), "warn,cyclonedds=error".into()),
        ];
        let log = self.dir.join(format!("{name}-load.log"));
        let mut child = Child::start(
            &format!("{name} load"),
            self.netns.name(site),
            &args,
            &env,
            &log,
            true,
        )?;
        // Only ship-1's alarms and tasks are checked one by one.
        let stdout = child.child.stdout.take().context("no stdout")?;
        let (raised, tasks) = (Arc::clone(&self.raised), Arc::clone(&self.tasks));
        let mine = site == SHIP;
        tokio::spawn(async move {
            let mut lines = tokio::io::BufReader::new(stdout).lines();
            while let Ok(Some(line)) = lines.next_line().await {
                let mut words = line.split_whitespace();
                match (words.next(), words.next(), words.next()) {
                    (Some("alarm"), Some(id), Some(ts)) if mine => {
                        if let Ok(ts) = ts.parse() {
                            lock(&raised).push((id.to_owned(), ts));
                        }
                    }
                    (Some("task"), Some(id), _) if mine => lock(&tasks).push(id.to_owned()),
                    (Some("alarm" | "task"), _, _) => {}
                    _ => eprintln!("federation: {name} load: {line}"),
                }
            }
        });
        self.loads[site] = Some(child);
        Ok(())
    }

    async fn stop_children(&mut self) {
        for c in self.loads.iter_mut().chain(self.stations.iter_mut()) {
            if let Some(c) = c.take() {
                c.stop().await;
            }
        }
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// A transition's key at the shore.
fn transition_key(t: &serde_json::Value) -> String {
    format!("{} {}", t["task_id"].as_str().unwrap_or(""), t["state"])
}

/// Reads one shore document into `seen`, at `now` ms.
fn observe(seen: &mut Seen, doc: serde_json::Value, now: i64) {
    let of_ship = |v: &&serde_json::Value| v["site"] == SITES[SHIP];
    if let Some(alarms) = doc["alarms"].as_array() {
        for a in alarms.iter().filter(of_ship) {
            if let Some(id) = a["alarm"]["event_id"].as_str() {
                seen.alarms.entry(id.to_owned()).or_insert(now);
            }
        }
    }
    if let Some(ts) = doc["transitions"].as_array() {
        for t in ts.iter().filter(of_ship) {
            seen.transitions.entry(transition_key(t)).or_insert(now);
        }
    }
    seen.doc = doc;
    seen.polls += 1;
}

/// ship-1's vehicles in a shore document: how many, median and largest age, s.
fn ages(doc: &serde_json::Value) -> (usize, f64, f64) {
    let mut ages: Vec<f64> = doc["vehicles"]
        .as_array()
        .map(|vs| {
            vs.iter()
                .filter(|v| v["site"] == SITES[SHIP])
                .filter_map(|v| v["age_ms"].as_f64())
                .map(|ms| ms / 1000.0)
                .collect()
        })
        .unwrap_or_default();
    ages.sort_by(f64::total_cmp);
    (
        ages.len(),
        percentile(&ages, 50.0),
        ages.last().copied().unwrap_or(f64::NAN),
    )
}

fn online(doc: &serde_json::Value, site: &str) -> bool {
    doc["sites"]
        .as_array()
        .is_some_and(|s| s.iter().any(|x| x["site"] == site && x["online"] == true))
}

fn counter(doc: &serde_json::Value, name: &str) -> u64 {
    doc["counters"][name].as_u64().unwrap_or(0)
}

/// The run's tallies from the final shore document and ship-1's counters.
fn tallies(shore: &serde_json::Value, ship: &serde_json::Value) -> (Tally, Tally) {
    let of_ship = |v: &&serde_json::Value| v["site"] == SITES[SHIP];
    let empty = Vec::new();
    let alarms = Tally::of(
        counter(ship, "sent_alarms"),
        shore["alarms"]
            .as_array()
            .unwrap_or(&empty)
            .iter()
            .filter(of_ship)
            .filter_map(|a| a["alarm"]["event_id"].as_str()),
    );
    let keys: Vec<String> = shore["transitions"]
        .as_array()
        .unwrap_or(&empty)
        .iter()
        .filter(of_ship)
        .map(transition_key)
        .collect();
    let transitions = Tally::of(
        counter(ship, "sent_transitions"),
        keys.iter().map(String::as_str),
    );
    (alarms, transitions)
}

/// Runs the benchmark (see the module doc).
pub(super) async fn federation(plan: Plan) -> Result<()> {
    plan.check()?;
    wan::check_can_run().context("bench federation needs root, /dev/net/tun and ip")?;
    let stop = CancellationToken::new();
    {
        let stop = stop.clone();
        // Ctrl-C or SIGTERM: stop the children and delete the namespaces before leaving.
        let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())?;
        tokio::spawn(async move {
            tokio::select! {
                _ = tokio::signal::ctrl_c() => {}
                _ = term.recv() => {}
            }
            eprintln!("federation: interrupted, cleaning up");
            stop.cancel();
        });
    }
    Namespaces::delete_stale();
    let pid = std::process::id();
    let dir = std::env::temp_dir().join(format!("shoal-wan-{pid}"));
    std::fs::create_dir_all(&dir)?;
    let netns = Namespaces::create(&format!("shoal-wan-{pid}"), &SITES)?;
    if plan.notsent_lowat > 0 {
        netns.sysctl(
            "net.ipv4.tcp_notsent_lowat",
            &plan.notsent_lowat.to_string(),
        )?;
    }
    let links: Vec<SiteLink> = (0..SITES.len())
        .map(|i| SiteLink {
            netns: netns.name(i).to_owned(),
            host: u8::try_from(i + 1).unwrap_or(1),
            profile: if i == SHORE {
                Profile::CLEAR
            } else {
                plan.satellite()
            },
        })
        .collect();
    let wan = Wan::start(&links, plan.seed)?;
    let mut run = Run {
        dir: dir.clone(),
        netns,
        wan,
        stations: vec![None, None, None],
        loads: vec![None, None, None],
        raised: Arc::default(),
        tasks: Arc::default(),
    };
    let result = tokio::select! {
        r = measure(&plan, &mut run) => r,
        () = stop.cancelled() => Err(anyhow::anyhow!("interrupted")),
    };
    run.stop_children().await;
    if result.is_err() || plan.keep_logs {
        eprintln!("federation: the stations' logs are in {}", dir.display());
    } else {
        let _ = std::fs::remove_dir_all(&dir);
    }
    drop(run);
    result
}

async fn measure(plan: &Plan, run: &mut Run) -> Result<()> {
    let secret = |site: &str| format!("wan-{site}-{}-{}", std::process::id(), now_ms());
    let passwords: BTreeMap<&str, String> = SITES.iter().map(|s| (*s, secret(s))).collect();
    let shore_ns = run.netns.name(SHORE).to_owned();
    let ship_ns = run.netns.name(SHIP).to_owned();
    println!(
        "# shoal bench federation — {} — {}\nship-1 and ship-2 behind {} ms RTT, {} kbit/s, {} % loss each way ({} B modem buffer, seed {}); {} vehicles per ship; {} s run, ship-1's link cut for {} s from its middle; every site's link_rate_kbps {}, tcp_notsent_lowat {}",
        machine(),
        date(),
        plan.rtt_ms,
        plan.rate_kbps,
        plan.loss_pct,
        plan.queue_bytes,
        plan.seed,
        plan.vehicles,
        plan.seconds,
        plan.outage,
        plan.link_rate_kbps(),
        match plan.notsent_lowat {
            0 => "unlimited".to_string(),
            n => format!("{n} B"),
        }
    );
    let api = "/api/federation";
    run.station(plan, SHORE, &passwords)?;
    wait_for(
        Duration::from_secs(90),
        "the shore's API",
        &shore_ns,
        api,
        |_| true,
    )
    .await?;
    run.station(plan, SHIP, &passwords)?;
    wait_for(
        Duration::from_secs(120),
        "ship-1's API",
        &ship_ns,
        api,
        |_| true,
    )
    .await?;
    run.load(plan, SHIP)?;
    let begin = Instant::now();
    let fleet_there = |body: &str| {
        serde_json::from_str(body).is_ok_and(|d: serde_json::Value| ages(&d).0 >= plan.vehicles)
    };
    wait_for(
        Duration::from_secs(180),
        "ship-1's fleet at the shore",
        &shore_ns,
        api,
        fleet_there,
    )
    .await?;
    println!(
        "ship-1's {} vehicles at the shore {:.1} s after its load started; the run starts",
        plan.vehicles,
        begin.elapsed().as_secs_f64()
    );

    let t0 = Instant::now();
    let (a_start, a_end) = (plan.at(1.0 / 8.0), plan.at(1.0 / 4.0));
    let (b_start, b_end) = (plan.at(3.0 / 8.0), plan.at(1.0 / 2.0));
    let cut = plan.at(0.5);
    let restore = cut + Duration::from_secs(plan.outage);
    let end = plan.at(1.0);
    let late = plan.at(7.0 / 8.0);
    let mut seen = Seen::default();
    let mut samples: Vec<Sample> = Vec::new();
    let mut marks: BTreeMap<&str, u64> = BTreeMap::new();
    let (mut ship2_started, mut ship2_loaded) = (false, false);
    let (mut outage_on, mut outage_done) = (false, false);
    let mut reconnected: Option<Duration> = None;
    let mut lease = LeaseFigures {
        timeout_s: plan.lease_timeout,
        ..LeaseFigures::default()
    };
    let mut leased_at_cut: BTreeMap<String, (String, u64)> = BTreeMap::new();
    let mut ticker = tokio::time::interval(POLL);
    ticker.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    // A hundred samples a run, one every 1 to 10 s; a progress line every 10 s.
    let sample_every = plan
        .at(0.01)
        .clamp(Duration::from_secs(1), Duration::from_secs(10));
    let mut next_sample = Duration::ZERO;
    let mut next_line = Duration::ZERO;
    let mut period = Period::default();
    while t0.elapsed() < end {
        ticker.tick().await;
        let t = t0.elapsed();
        let up = run.wan.counters().0[SHIP].up;
        let up_bytes = up.offered_bytes;
        for (name, at) in [
            ("a0", a_start),
            ("a1", a_end),
            ("b0", b_start),
            ("b1", b_end),
        ] {
            if t >= at && !marks.contains_key(name) {
                marks.insert(name, up_bytes);
            }
        }
        if !ship2_started && t >= a_end {
            ship2_started = true;
            println!("t={:>5.0}s ship-2 joins", t.as_secs_f64());
            run.station(plan, SHIP2, &passwords)?;
        }
        // Its load once its API answers, without holding up the shore's polling.
        if ship2_started && !ship2_loaded && get(run.netns.name(SHIP2), api).await.is_ok() {
            ship2_loaded = true;
            run.load(plan, SHIP2)?;
        }
        if !outage_on && !outage_done && t >= cut {
            outage_on = true;
            run.wan.set_outage(SHIP, true);
            println!("t={:>5.0}s ship-1's link cut", t.as_secs_f64());
        }
        if outage_on && t >= restore {
            outage_on = false;
            outage_done = true;
            run.wan.set_outage(SHIP, false);
            println!("t={:>5.0}s ship-1's link back", t.as_secs_f64());
        }
        match get_json(run.netns.name(SHORE), "/api/federation").await {
            Ok(doc) => {
                let leases = leases_of_ship(&doc);
                if !outage_on && !outage_done {
                    leased_at_cut = leases.clone();
                } else if outage_on {
                    if lease.detected_s.is_none() && !online(&doc, SITES[SHIP]) {
                        lease.detected_s = Some((t - cut).as_secs_f64());
                        println!(
                            "t={:>5.0}s the shore sees ship-1 offline, {:.1} s after the cut",
                            t.as_secs_f64(),
                            (t - cut).as_secs_f64()
                        );
                    }
                    let all_taken = !leased_at_cut.is_empty()
                        && leased_at_cut
                            .keys()
                            .all(|v| leases.get(v).is_some_and(|(h, _)| h == SITES[SHORE]));
                    if lease.taken_over_s.is_none() && all_taken {
                        lease.taken_over_s = Some((t - cut).as_secs_f64());
                        println!(
                            "t={:>5.0}s the shore holds the leases of ship-1's {} vehicles, {:.1} s after the cut",
                            t.as_secs_f64(),
                            leased_at_cut.len(),
                            (t - cut).as_secs_f64()
                        );
                    }
                }
                if outage_done && reconnected.is_none() && online(&doc, SITES[SHIP]) {
                    reconnected = Some(t0.elapsed());
                    println!(
                        "t={:>5.0}s ship-1 online at the shore again, {:.1} s after its link came back",
                        t.as_secs_f64(),
                        (t - restore).as_secs_f64()
                    );
                }
                observe(&mut seen, doc, now_ms());
            }
            Err(_) => seen.failed += 1,
        }
        let (_, p50, max) = ages(&seen.doc);
        period.add(p50, max, up.queued_bytes);
        if t >= next_sample {
            next_sample += sample_every;
            let (n, _, _) = ages(&seen.doc);
            let s = period.take(t, up_bytes);
            let rate = samples
                .iter()
                .find(|p| p.t + Duration::from_millis(10_500) >= s.t)
                .map_or(0.0, |p| rate_bps(p.up_bytes, s.up_bytes, s.t - p.t));
            samples.push(s);
            if t < next_line {
                continue;
            }
            next_line += Duration::from_secs(10);
            let raised = lock(&run.raised).len();
            println!(
                "t={:>5.0}s [{}] ship-1 at the shore: {} vehicles, age p50 {:.1} s (mean of {} s of polls), max {:.1} s; uplink {:.0} B/s, queued {:.0} B on average; alarms {}/{} raised seen, transitions {}",
                t.as_secs_f64(),
                if outage_on {
                    "outage"
                } else if ship2_started {
                    "3 sites"
                } else {
                    "2 sites"
                },
                n,
                s.age_p50_s,
                sample_every.as_secs(),
                s.age_max_s,
                rate,
                s.queued,
                seen.alarms.len(),
                raised,
                seen.transitions.len()
            );
        }
    }

    // Stop raising; wait until the shore holds what ship-1 numbered.
    for l in run.loads.iter_mut().flatten() {
        if let Some(stdin) = l.child.stdin.as_mut() {
            let _ = stdin.write_all(b"stop\n").await;
            let _ = stdin.flush().await;
        }
    }
    let settle_from = Instant::now();
    let mut settled = false;
    let (mut shore_doc, mut ship_doc) = (serde_json::Value::Null, serde_json::Value::Null);
    // As long as the outage, at least two minutes: what a ship queued in an outage crosses
    // at the link's rate afterwards.
    let settle_limit = Duration::from_secs(plan.outage.max(120));
    while settle_from.elapsed() < settle_limit {
        tokio::time::sleep(Duration::from_secs(1)).await;
        let (Ok(shore), Ok(ship)) = (
            get_json(run.netns.name(SHORE), "/api/federation").await,
            get_json(run.netns.name(SHIP), "/api/federation").await,
        ) else {
            continue;
        };
        observe(&mut seen, shore.clone(), now_ms());
        let (a, t) = tallies(&shore, &ship);
        (shore_doc, ship_doc) = (shore, ship);
        // Everything matched, and the last tasks dispatched have had time to finish.
        if a.exact() && t.exact() && settle_from.elapsed() > Duration::from_secs(5) {
            settled = true;
            break;
        }
    }
    let (alarms, transitions) = tallies(&shore_doc, &ship_doc);
    // The leases have had the whole settling time to converge after the link came back.
    lease.leased_before = leased_at_cut.len();
    let (at_shore, at_ship) = (leases_of_ship(&shore_doc), leases_of_ship(&ship_doc));
    lease.held_by_shore_at_end = at_shore.values().filter(|(h, _)| h == SITES[SHORE]).count();
    lease.held_by_ship_at_end = at_ship.values().filter(|(h, _)| h == SITES[SHIP]).count();
    lease.disagreeing_at_end = at_shore
        .keys()
        .chain(at_ship.keys())
        .collect::<std::collections::BTreeSet<_>>()
        .into_iter()
        .filter(|v| at_shore.get(*v) != at_ship.get(*v))
        .count();
    println!(
        "{} {:.0} s after the loads stopped raising",
        if settled {
            "the shore holds everything ship-1 numbered"
        } else {
            "NOT SETTLED: the shore still misses some of what ship-1 numbered"
        },
        settle_from.elapsed().as_secs_f64()
    );

    // Alarm latency: those raised with the link up, away from the outage, once the run
    // started. The shore is read for alarms only from then on: one raised while ship-1's
    // fleet was still arriving would be timed to the first read, not to its arrival.
    let raised = lock(&run.raised).clone();
    let quiet_from = cut.saturating_sub(Duration::from_millis((2.0 * plan.rtt_ms) as u64 + 5000));
    let quiet_to = reconnected.unwrap_or(restore) + Duration::from_secs(10);
    let t0_ms = now_ms() - i64::try_from(t0.elapsed().as_millis()).unwrap_or(0);
    let in_quiet = |ts: i64| {
        let at = Duration::from_millis(u64::try_from(ts - t0_ms).unwrap_or(0));
        at >= quiet_from && at < quiet_to
    };
    let mut latencies: Vec<f64> = Vec::new();
    // Those over the budget, with when they were raised (s into the run), to tell a start-up
    // burst or a catch-up from a retransmission.
    let budget_ms = 2.0 * plan.rtt_ms + 1000.0;
    let mut over_budget: Vec<(f64, f64)> = Vec::new();
    // The same with two sites only (before ship-2 joins).
    let mut latencies_2: Vec<f64> = Vec::new();
    let two_sites_until = t0_ms + i64::try_from(a_end.as_millis()).unwrap_or(0);
    let mut caught_up_after = 0.0f64;
    let mut missing = 0usize;
    let mut before_start = 0usize;
    for (id, ts) in &raised {
        match seen.alarms.get(id) {
            Some(_) if *ts < t0_ms => before_start += 1,
            Some(at) if !in_quiet(*ts) => {
                #[allow(clippy::cast_precision_loss)]
                let ms = (at - ts) as f64;
                latencies.push(ms);
                if ms > budget_ms {
                    #[allow(clippy::cast_precision_loss)]
                    over_budget.push(((ts - t0_ms) as f64 / 1000.0, ms));
                }
                if *ts < two_sites_until {
                    latencies_2.push(ms);
                }
            }
            Some(at) => {
                #[allow(clippy::cast_precision_loss)]
                let after = (*at - t0_ms) as f64 / 1000.0 - restore.as_secs_f64();
                caught_up_after = caught_up_after.max(after);
            }
            None => missing += 1,
        }
    }
    latencies.sort_by(f64::total_cmp);
    latencies_2.sort_by(f64::total_cmp);
    let (p50, p99) = (percentile(&latencies, 50.0), percentile(&latencies, 99.0));
    let mark = |k: &str| marks.get(k).copied().unwrap_or(0);
    let up2 = rate_bps(mark("a0"), mark("a1"), a_end - a_start);
    let up3 = rate_bps(mark("b0"), mark("b1"), b_end - b_start);
    let (links, unroutable) = run.wan.counters();
    let (n_end, _, _) = ages(&shore_doc);

    // Backlog: the first window with two sites against the run's last eighth.
    let window = |from: Duration, to: Duration| -> (f64, f64) {
        let mut ages: Vec<f64> = Vec::new();
        let mut queued: Vec<f64> = Vec::new();
        for s in samples.iter().filter(|s| s.t >= from && s.t < to) {
            ages.push(s.age_p50_s);
            queued.push(s.queued);
        }
        ages.sort_by(f64::total_cmp);
        queued.sort_by(f64::total_cmp);
        (percentile(&ages, 50.0), percentile(&queued, 50.0))
    };
    let (age_early, queue_early) = window(a_start, a_end);
    let (age_late, queue_late) = window(late, end);
    let age_max_up = samples
        .iter()
        .filter(|s| s.t < quiet_from || s.t >= quiet_to)
        .map(|s| s.age_max_s)
        .fold(0.0f64, f64::max);
    let no_growth =
        age_late <= age_early + 1.0 && queue_late <= queue_early + 1500.0 && n_end >= plan.vehicles;
    let up = links[SHIP].up;
    let down = links[SHIP].down;
    let increase = (up3 - up2) / up2 * 100.0;
    let yes = |b: bool| if b { "yes" } else { "no" };

    println!();
    println!("| target | measured | met |");
    println!("|---|---|---|");
    println!(
        "| {} vehicles' positions at 0.2 Hz + alarms over {} kbit/s, no backlog growth over {} s | age of ship-1's positions at the shore (median over its vehicles, averaged over every poll): {:.1} s in [{:.0}, {:.0}) s, {:.1} s in the run's last eighth; largest age with the link up {:.1} s; uplink queue on average {:.0} B → {:.0} B; {} of {} vehicles at the shore at the end; uplink {:.0} B/s on average ({:.0} % of the link) | {} |",
        plan.vehicles,
        plan.rate_kbps,
        plan.seconds,
        age_early,
        a_start.as_secs_f64(),
        a_end.as_secs_f64(),
        age_late,
        age_max_up,
        queue_early,
        queue_late,
        n_end,
        plan.vehicles,
        rate_bps(0, up.offered_bytes, end),
        rate_bps(0, up.offered_bytes, end) * 8.0 / (plan.rate_kbps * 10.0),
        yes(no_growth)
    );
    println!(
        "| WAN bytes per added site O(1): a third site raises the ship's uplink ≤ 10 % | ship-1's uplink (IP bytes) {up2:.0} B/s with 2 sites, {up3:.0} B/s with 3 ({increase:+.1} %) | {} |",
        yes(increase <= 10.0)
    );
    println!(
        "| alarm ship → shore p99 ≤ 2 × RTT + 1 s = {:.1} s | p50 {:.0} ms, p99 {:.0} ms, max {:.0} ms over {} alarms raised with the link up; of them the {} raised with two sites only: p50 {:.0} ms, p99 {:.0} ms (shore polled every {} ms: up to {} ms late; {} raised before the run started not timed) | {} |",
        budget_ms / 1000.0,
        p50,
        p99,
        latencies.last().copied().unwrap_or(f64::NAN),
        latencies.len(),
        latencies_2.len(),
        percentile(&latencies_2, 50.0),
        percentile(&latencies_2, 99.0),
        POLL.as_millis(),
        POLL.as_millis(),
        before_start,
        yes(p99 <= budget_ms)
    );
    println!(
        "| zero duplicated or lost task transitions across the {} s outage | ship-1 numbered {}; at the shore {} distinct, {} duplicated, {} missing at the end | {} |",
        plan.outage,
        transitions.sent,
        transitions.distinct,
        transitions.duplicated,
        transitions.lost,
        yes(transitions.exact() && transitions.sent > 0)
    );
    println!(
        "| (and alarms) zero duplicated or lost | ship-1 numbered {}; at the shore {} distinct, {} duplicated, {} missing at the end; of the {} the load raised, {} missing; those raised around the outage shown at most {:.1} s after the link came back | {} |",
        alarms.sent,
        alarms.distinct,
        alarms.duplicated,
        alarms.lost,
        raised.len(),
        missing,
        caught_up_after,
        yes(alarms.exact() && missing == 0 && alarms.sent > 0)
    );
    let secs = |v: Option<f64>| v.map_or("never".to_string(), |s| format!("{s:.1} s"));
    let failover_s = match (lease.detected_s, lease.taken_over_s) {
        (Some(d), Some(t)) => Some(t - d),
        _ => None,
    };
    #[allow(clippy::cast_precision_loss)]
    let failover_budget = plan.lease_timeout as f64 + 2.0;
    println!(
        "| lease failover ≤ configured timeout + 2 s = {:.0} s | link lease {} ms: the shore (ship-1's standby) saw ship-1 offline {} after the cut and held all {} of its leases {} after the cut: {} after it saw ship-1 lost; at the end (link back) the shore holds {}, ship-1 still believes it holds {}, they disagree on {} | {} |",
        failover_budget,
        plan.link_lease_ms,
        secs(lease.detected_s),
        lease.leased_before,
        secs(lease.taken_over_s),
        secs(failover_s),
        lease.held_by_shore_at_end,
        lease.held_by_ship_at_end,
        lease.disagreeing_at_end,
        match (failover_s, lease.taken_over_s) {
            (Some(f), Some(t)) if t <= failover_budget => yes(f <= failover_budget).to_string(),
            (Some(f), _) => format!(
                "{} from the loss; not from the cut (Zenoh noticed the silent link only after its own lease)",
                yes(f <= failover_budget)
            ),
            _ => "no".into(),
        }
    );
    println!();
    if !over_budget.is_empty() {
        over_budget.sort_by(|a, b| a.0.total_cmp(&b.0));
        let shown: Vec<String> = over_budget
            .iter()
            .take(12)
            .map(|(t, ms)| format!("t={t:.0}s {:.1} s", ms / 1000.0))
            .collect();
        println!(
            "alarms over {:.1} s with the link up: {} of {} (raised at: {}{})",
            budget_ms / 1000.0,
            over_budget.len(),
            latencies.len(),
            shown.join(", "),
            if over_budget.len() > shown.len() {
                ", ..."
            } else {
                ""
            }
        );
    }
    println!(
        "ship-1's uplink: {} packets ({} B) offered, {} lost at random, {} dropped by the full queue, {} in the outage; largest queue {} B",
        up.offered_packets,
        up.offered_bytes,
        up.dropped_loss,
        up.dropped_queue,
        up.dropped_outage,
        up.max_queued_bytes
    );
    println!(
        "ship-1's downlink: {} packets ({} B, {:.0} B/s) offered, {} lost at random, {} dropped by the full queue, {} in the outage; largest queue {} B; {} packets for no site dropped",
        down.offered_packets,
        down.offered_bytes,
        rate_bps(0, down.offered_bytes, end),
        down.dropped_loss,
        down.dropped_queue,
        down.dropped_outage,
        down.max_queued_bytes,
        unroutable
    );
    println!(
        "ship-1 online again at the shore {} after the link came back; tasks dispatched on ship-1: {}; shore polls: {} ({} failed); shore counters: duplicates suppressed {}, lost {}, catch-up queries {}, replies {}; ship-1 counters: queue_full {}, coalesced positions {}, catch-up frames served to other sites {} (answers cut for time {}, queries dropped {})",
        reconnected.map_or("never".to_string(), |r| format!(
            "{:.1} s",
            (r.saturating_sub(restore)).as_secs_f64()
        )),
        lock(&run.tasks).len(),
        seen.polls,
        seen.failed,
        counter(&shore_doc, "duplicates"),
        counter(&shore_doc, "lost"),
        counter(&shore_doc, "catchup_queries"),
        counter(&shore_doc, "catchup_replies"),
        counter(&ship_doc, "queue_full"),
        counter(&ship_doc, "coalesced_positions"),
        counter(&ship_doc, "catchup_served"),
        counter(&ship_doc, "catchup_cut"),
        counter(&ship_doc, "catchup_dropped"),
    );
    if let Some(path) = &plan.summary {
        let summary = Summary {
            seconds: plan.seconds,
            outage_s: plan.outage,
            vehicles: plan.vehicles,
            alarms_raised: raised.len(),
            alarms_seen: raised.len() - missing,
            alarm_latency_p50_ms: p50,
            alarm_latency_p99_ms: p99,
            alarms,
            transitions,
            raised_alarms_missing: missing,
            uplink_2_sites_bps: up2,
            uplink_3_sites_bps: up3,
            ship_vehicles_at_shore: n_end,
            settled,
            lease,
        };
        std::fs::write(path, serde_json::to_string_pretty(&summary)?)
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    Ok(())
}

fn rate_bps(from: u64, to: u64, over: Duration) -> f64 {
    #[allow(clippy::cast_precision_loss)]
    let bytes = to.saturating_sub(from) as f64;
    bytes / over.as_secs_f64().max(1e-9)
}

/// Polls `GET path` on `netns`'s station every 500 ms until `ok` holds of its body, for
/// at most `limit`.
async fn wait_for(
    limit: Duration,
    what: &str,
    netns: &str,
    path: &str,
    ok: impl Fn(&str) -> bool,
) -> Result<()> {
    let start = Instant::now();
    while start.elapsed() < limit {
        if get(netns, path).await.is_ok_and(|b| ok(&b)) {
            return Ok(());
        }
        tokio::time::sleep(Duration::from_millis(500)).await;
    }
    bail!("{what} not there after {} s", limit.as_secs())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_tally_counts_duplicates_and_losses_against_what_was_numbered() {
        let t = Tally::of(4, ["a", "b", "b", "c"].into_iter());
        assert_eq!(
            t,
            Tally {
                sent: 4,
                distinct: 3,
                duplicated: 1,
                lost: 1
            }
        );
        assert!(!t.exact());
        assert!(Tally::of(2, ["x", "y"].into_iter()).exact());
    }

    #[test]
    fn tallies_read_only_ship_1_from_the_shore() {
        let shore = serde_json::json!({
            "alarms": [
                {"site": "ship-1", "alarm": {"event_id": "ship-1-a1"}},
                {"site": "ship-1", "alarm": {"event_id": "ship-1-a1"}},
                {"site": "ship-2", "alarm": {"event_id": "ship-2-a1"}},
            ],
            "transitions": [
                {"site": "ship-1", "task_id": "k1", "state": "sent"},
                {"site": "ship-1", "task_id": "k1", "state": "done"},
                {"site": "ship-2", "task_id": "k1", "state": "sent"},
            ],
        });
        let ship = serde_json::json!({"counters": {"sent_alarms": 1, "sent_transitions": 3}});
        let (a, t) = tallies(&shore, &ship);
        assert_eq!((a.distinct, a.duplicated, a.lost), (1, 1, 0));
        assert_eq!((t.distinct, t.duplicated, t.lost), (2, 0, 1));
    }

    #[test]
    fn the_ages_are_of_ship_1s_vehicles() {
        let doc = serde_json::json!({"vehicles": [
            {"site": "ship-1", "age_ms": 1000},
            {"site": "ship-1", "age_ms": 3000},
            {"site": "ship-1", "age_ms": 2000},
            {"site": "ship-2", "age_ms": 99000},
        ]});
        assert_eq!(ages(&doc), (3, 2.0, 3.0));
    }

    #[test]
    fn a_sample_averages_every_poll_of_its_period() {
        let mut p = Period::default();
        // A queue full at one poll in four (a burst) averages to a quarter, whichever
        // poll a once-a-period sample would have hit.
        for q in [4000, 0, 0, 0] {
            p.add(2.0, 3.0, q);
        }
        p.add(f64::NAN, f64::NAN, 9999);
        let s = p.take(Duration::from_secs(10), 123);
        assert_eq!((s.age_p50_s, s.age_max_s, s.queued), (2.0, 3.0, 1000.0));
        assert!(p.take(Duration::from_secs(20), 123).age_p50_s.is_nan());
    }

    #[test]
    fn a_plan_refuses_an_outage_that_leaves_no_late_window() {
        let plan = |seconds, outage| Plan {
            seconds,
            outage,
            vehicles: 50,
            state_rate: 1.0,
            rtt_ms: 600.0,
            rate_kbps: 64.0,
            loss_pct: 2.0,
            queue_bytes: 32_768,
            alarm_every: 2.0,
            task_every: 10.0,
            seed: 1,
            domain: 10,
            lease_timeout: 10,
            link_lease_ms: 10_000,
            unshaped: false,
            notsent_lowat: 0,
            keep_logs: false,
            station_log: STATION_LOG.into(),
            summary: None,
        };
        plan(1800, 300).check().unwrap();
        plan(80, 15).check().unwrap();
        assert!(plan(80, 30).check().is_err());
        assert!(plan(30, 5).check().is_err());
    }
}
