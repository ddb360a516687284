//! The command lease on the network: the transport's side of [`crate::lease`].
//!
//! - A site answers `shoal/<site>/leases/*` with the records it made that are still
//!   current, and asks the same of every remote site whose session comes up, so that a
//!   site that was away (or restarted) learns what changed.
//! - The keeper, every [`TICK`]: once the site has *settled* (every remote site answered,
//!   or `settle_ms` passed), claims the vehicles registered here that no site holds (when
//!   `home`); takes over, as home or standby, the leases of a holder offline for
//!   `failover_timeout_ms`; and writes the table to `state_file` when it changed.
//!
//! Records this site makes are published at once (reliably, with the task transitions'
//! QoS), under `shoal/<site>/leases/<vehicle>`.

use std::collections::{BTreeSet, HashSet};
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use shoal_model::now_ms;
use tokio::sync::mpsc;
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;
use tracing::{debug, info, warn};
use zenoh::Session;
use zenoh::handlers::FifoChannelHandler;
use zenoh::query::{Query, Queryable};

use crate::config::LeasePolicy;
use crate::federation::ask_above_positions;
use crate::keys;
use crate::lease::{Current, LeaseRecord};
use crate::site_keys::{SiteSigner, sealed};
use crate::wire;

/// How often the keeper looks at the leases.
pub(crate) const TICK: Duration = Duration::from_millis(500);
/// Own vehicles remembered for claims, at most.
const OWN_VEHICLES: usize = 100_000;

/// Why the lease state file could not be used.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LeaseFileError {
    /// Reading or writing failed.
    #[error("lease state file {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// The file is not a lease table.
    #[error("lease state file {path} is unreadable: {source}")]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: serde_json::Error,
    },
}

/// Reads the leases kept by an earlier run; none when the file does not exist.
pub(crate) fn load(path: &Path) -> Result<Vec<Current>, LeaseFileError> {
    let bytes = match std::fs::read(path) {
        Ok(b) => b,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(source) => {
            return Err(LeaseFileError::Io {
                path: path.to_owned(),
                source,
            });
        }
    };
    serde_json::from_slice(&bytes).map_err(|source| LeaseFileError::Corrupt {
        path: path.to_owned(),
        source,
    })
}

/// Replaces the file atomically (written beside, synced, renamed): a crash leaves the old
/// table or the new one.
pub(crate) fn save(path: &Path, leases: &[Current]) -> Result<(), LeaseFileError> {
    let io = |source| LeaseFileError::Io {
        path: path.to_owned(),
        source,
    };
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(io)?;
    }
    let tmp = path.with_extension("json.tmp");
    let bytes = serde_json::to_vec_pretty(leases).map_err(|source| LeaseFileError::Corrupt {
        path: path.to_owned(),
        source,
    })?;
    let mut f = std::fs::File::create(&tmp).map_err(io)?;
    f.write_all(&bytes).map_err(io)?;
    f.sync_all().map_err(io)?;
    std::fs::rename(&tmp, path).map_err(io)
}

/// Why this station may not command a vehicle now.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum CommandDenied {
    /// Another site holds the vehicle's lease.
    #[error(
        "{vehicle} is commanded by site {holder} (lease term {term}); ask {holder} to hand it over"
    )]
    HeldElsewhere {
        /// The vehicle.
        vehicle: String,
        /// The site that holds it.
        holder: String,
        /// Its term.
        term: u64,
    },
    /// The site has just started and is still learning the remote sites' leases.
    #[error(
        "the command lease of {vehicle} is not settled yet (this site started {waited_ms} ms ago and waits up to {settle_ms} ms for the remote sites' leases)"
    )]
    NotSettled {
        /// The vehicle.
        vehicle: String,
        /// Time since start, ms.
        waited_ms: u64,
        /// `lease.settle_ms`.
        settle_ms: u64,
    },
    /// No site holds the vehicle's lease, and this site does not claim (`lease.home =
    /// false`).
    #[error(
        "no site holds the command lease of {0}, and this site does not claim leases (lease.home = false)"
    )]
    NoLease(String),
    /// The lease table is full.
    #[error("no lease can be claimed for {0}: the lease table is full")]
    Full(String),
}

/// The keeper's own state (beside the table, which lives in the inbound core).
#[derive(Debug)]
pub(crate) struct LeaseRun {
    pub(crate) policy: LeasePolicy,
    started: Instant,
    started_ms: i64,
    remote_sites: Vec<String>,
    answered: HashSet<String>,
    settled: bool,
    own: BTreeSet<String>,
    saved_generation: u64,
}

impl LeaseRun {
    pub(crate) fn new(policy: LeasePolicy, remote_sites: &[String]) -> Self {
        Self {
            policy,
            started: Instant::now(),
            started_ms: now_ms(),
            remote_sites: remote_sites.to_vec(),
            answered: HashSet::new(),
            settled: false,
            own: BTreeSet::new(),
            saved_generation: 0,
        }
    }

    pub(crate) fn started_ms(&self) -> i64 {
        self.started_ms
    }

    /// Notes a vehicle registered at this site (a claim candidate).
    pub(crate) fn own(&mut self, vehicle: &str) {
        if self.policy.enabled
            && self.policy.home
            && self.own.len() < OWN_VEHICLES
            && !self.own.contains(vehicle)
        {
            self.own.insert(vehicle.to_owned());
        }
    }

    /// The vehicles to claim, forgotten here (each comes back with its next position).
    pub(crate) fn take_own(&mut self) -> BTreeSet<String> {
        std::mem::take(&mut self.own)
    }

    pub(crate) fn answered(&mut self, site: &str) {
        self.answered.insert(site.to_owned());
    }

    /// Whether the site has learnt the remote leases (or waited long enough).
    pub(crate) fn settled(&mut self) -> bool {
        if !self.settled {
            let waited = self.started.elapsed() >= Duration::from_millis(self.policy.settle_ms);
            let all = self.remote_sites.iter().all(|s| self.answered.contains(s));
            if waited || all {
                self.settled = true;
                info!(
                    answered = self.answered.len(),
                    sites = self.remote_sites.len(),
                    "command leases settled"
                );
            }
        }
        self.settled
    }

    pub(crate) fn waited_ms(&self) -> u64 {
        u64::try_from(self.started.elapsed().as_millis()).unwrap_or(u64::MAX)
    }

    /// Whether the table changed since it was last saved (and notes it saved).
    pub(crate) fn needs_saving(&mut self, generation: u64) -> bool {
        if generation == self.saved_generation {
            return false;
        }
        self.saved_generation = generation;
        true
    }
}

/// Records a lease query asks for in one part: about 7 kB, under a second of a 64 kbit/s
/// link, so each part arrives well within the query's timeout behind other traffic.
pub(crate) const ASK_PART: usize = 100;

/// The part of `records` a lease query's parameters ask for: sorted by vehicle, those
/// after the vehicle `after` (all without it), at most `limit` (all without it, or when it
/// is not a number).
pub(crate) fn answer_part(
    mut records: Vec<LeaseRecord>,
    after: Option<&str>,
    limit: Option<&str>,
) -> Vec<LeaseRecord> {
    records.sort_by(|a, b| a.vehicle_id.cmp(&b.vehicle_id));
    let limit = limit
        .and_then(|v| v.parse::<usize>().ok())
        .map_or(usize::MAX, |n| n.max(1));
    records
        .into_iter()
        .filter(|r| after.is_none_or(|a| r.vehicle_id.as_str() > a))
        .take(limit)
        .collect()
}

/// Answers `shoal/<site>/leases/*` with the records this site made that are current, in
/// the part the query asks for (`?after=<vehicle>;limit=<n>`, both optional).
pub(crate) async fn serve(
    queryable: Queryable<FifoChannelHandler<Query>>,
    site: String,
    signer: Option<Arc<SiteSigner>>,
    pacer: Arc<impl Paced>,
    records: impl Fn() -> Vec<LeaseRecord>,
    stop: CancellationToken,
) {
    loop {
        let query = tokio::select! {
            () = stop.cancelled() => break,
            q = queryable.recv_async() => match q { Ok(q) => q, Err(_) => break },
        };
        let params = query.parameters();
        let part = answer_part(records(), params.get("after"), params.get("limit"));
        debug!(count = part.len(), "lease query served");
        for r in part {
            let frame = match wire::encode_lease(&r) {
                Ok(f) => f,
                Err(e) => {
                    warn!(vehicle = %r.vehicle_id, error = %e, "lease record not encodable");
                    continue;
                }
            };
            let key = keys::lease(&site, &r.vehicle_id);
            let Some(frame) = sealed(signer.as_deref(), &key, frame) else {
                continue;
            };
            pacer.pace(key.len() + frame.len()).await;
            if let Err(e) = query.reply(key, frame).await {
                warn!(error = %e, "lease reply not sent");
                break;
            }
        }
    }
}

/// How a lease query is asked: records a part, and how long a part is waited for.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Parts {
    /// Waited for each part at first (longer for a site whose parts ran out of time:
    /// [`crate::pacing::Waits`]).
    pub(crate) timeout: Duration,
    /// Records asked for in a part.
    pub(crate) part: usize,
}

/// Wait before asking a site again whose answer ran out of time.
const ASK_RETRY: Duration = Duration::from_secs(2);

/// Asks each remote site that comes up for its lease records, one site at a time and in
/// parts of `parts.part` records ([`ASK_PART`], fewer on a slow link:
/// `LinkShaping::part_items`) each waited for `parts.timeout`, up to four times that for a
/// site whose parts keep running out of time (a whole fleet's records in one answer would
/// not cross a satellite link within the timeout); each reply goes to `take` (which checks it like a
/// published record), and `done` notes the site answered. A part that ran out of time is
/// asked for again after [`ASK_RETRY`] while `online` says the site is still up: nothing
/// else would tell this site of a takeover it missed while the link was down. Records are
/// idempotent, so a repeated one changes nothing.
pub(crate) async fn ask(
    session: Session,
    mut sites: mpsc::Receiver<String>,
    parts: Parts,
    take: impl Fn(&str, &[u8]),
    done: impl Fn(&str),
    online: impl Fn(&str) -> bool,
    stop: CancellationToken,
) {
    let Parts { timeout, part } = parts;
    let max_wait = timeout * crate::federation::MAX_WAIT_FACTOR;
    let mut waits = crate::pacing::Waits::new(timeout, max_wait);
    // (when, site, the vehicle after which the part starts)
    let mut retries: Vec<(Instant, String, Option<String>)> = Vec::new();
    let mut next: Option<(String, Option<String>)> = None;
    loop {
        let (site, after) = match next.take() {
            Some(n) => n,
            None => {
                let due = retries.iter().map(|r| r.0).min();
                tokio::select! {
                    () = stop.cancelled() => break,
                    s = sites.recv() => match s { Some(s) => (s, None), None => break },
                    () = crate::federation::sleep_until_due(due) => {
                        let now = Instant::now();
                        let Some(i) = retries.iter().position(|r| r.0 <= now) else { continue };
                        let (_, site, after) = retries.swap_remove(i);
                        if !online(&site) {
                            continue;
                        }
                        debug!(site, "lease query ran out of time before; asking again");
                        (site, after)
                    }
                }
            }
        };
        retries.retain(|r| r.1 != site);
        let mut selector = format!("{}?limit={part}", keys::leases(&site));
        if let Some(a) = &after {
            selector.push_str(&format!(";after={a}"));
        }
        let started = Instant::now();
        let timeout = waits.of(&site);
        // Above positions, like catch-up.
        let replies = match ask_above_positions(&session, &selector, timeout).await {
            Ok(r) => r,
            Err(e) => {
                warn!(site, error = %e, "lease query not sent");
                continue;
            }
        };
        let (mut n, mut failed, mut last) = (0usize, false, None::<String>);
        loop {
            let reply = tokio::select! {
                () = stop.cancelled() => return,
                r = replies.recv_async() => match r { Ok(r) => r, Err(_) => break },
            };
            match reply.result() {
                Ok(sample) => {
                    n += 1;
                    let key = sample.key_expr().as_str();
                    if let Some(keys::Key::Lease { vehicle, .. }) = keys::Key::parse(key)
                        && last.as_deref().is_none_or(|l| vehicle > l)
                    {
                        last = Some(vehicle.to_owned());
                    }
                    take(key, &sample.payload().to_bytes());
                }
                // Zenoh's "timeout" reply among them.
                Err(_) => failed = true,
            }
        }
        debug!(site, records = n, failed, after = ?after, wait_ms = timeout.as_millis(), ms = started.elapsed().as_millis(), "lease query answered");
        let incomplete = failed || started.elapsed() >= timeout.mul_f64(0.95);
        waits.answered(&site, !incomplete, started.elapsed());
        if incomplete {
            // The part again, from what arrived of it.
            retries.push((Instant::now() + ASK_RETRY, site, last.or(after)));
        } else if n >= part {
            next = Some((site, last.or(after)));
        } else {
            done(&site);
        }
    }
}

/// Waits until an answer of so many bytes may leave (a slow link's pacing).
pub(crate) trait Paced: Send + Sync {
    /// Waits for room for `bytes` (payload and key).
    fn pace(&self, bytes: usize) -> impl Future<Output = ()> + Send;
}

/// What the keeper needs of the federation, so that it can be driven by the transport.
pub(crate) trait Keeper: Send + Sync {
    /// One pass: settle, claim, fail over; the records made (to publish).
    fn pass(&self) -> Vec<LeaseRecord>;
    /// Publishes a record this site made.
    fn publish(&self, record: LeaseRecord);
    /// Writes the table if it changed.
    fn persist(&self);
}

/// Runs the keeper every [`TICK`] until `stop`.
pub(crate) async fn keep(keeper: Arc<dyn Keeper>, stop: CancellationToken) {
    let mut interval = tokio::time::interval(TICK);
    interval.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            () = stop.cancelled() => break,
            _ = interval.tick() => {}
        }
        for record in keeper.pass() {
            keeper.publish(record);
        }
        keeper.persist();
    }
    keeper.persist();
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::lease::LeaseReason;

    fn record(vehicle: &str) -> LeaseRecord {
        LeaseRecord {
            vehicle_id: vehicle.into(),
            term: 1,
            holder: "ship".into(),
            home: "ship".into(),
            standby: String::new(),
            reason: LeaseReason::Claim,
            granted_ms: 0,
        }
    }

    fn ids(part: &[LeaseRecord]) -> Vec<&str> {
        part.iter().map(|r| r.vehicle_id.as_str()).collect()
    }

    #[test]
    fn a_lease_answer_comes_in_parts_sorted_by_vehicle() {
        let all = || ["auv-3", "auv-1", "usv-1", "auv-2"].map(record).to_vec();
        // No parameters (an older site, a client reading the doc): everything, sorted.
        assert_eq!(
            ids(&answer_part(all(), None, None)),
            ["auv-1", "auv-2", "auv-3", "usv-1"]
        );
        assert_eq!(
            ids(&answer_part(all(), None, Some("2"))),
            ["auv-1", "auv-2"]
        );
        // The next part starts after the last vehicle received.
        assert_eq!(
            ids(&answer_part(all(), Some("auv-2"), Some("2"))),
            ["auv-3", "usv-1"]
        );
        assert!(answer_part(all(), Some("usv-1"), Some("2")).is_empty());
        // A nonsensical limit is ignored, 0 is taken as 1: never an empty part that would
        // read as the end.
        assert_eq!(answer_part(all(), None, Some("x")).len(), 4);
        assert_eq!(ids(&answer_part(all(), None, Some("0"))), ["auv-1"]);
    }

    #[test]
    fn a_missing_file_is_no_leases_and_a_corrupt_one_is_an_error_naming_it() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("leases-ship.json");
        assert!(load(&path).unwrap().is_empty());
        std::fs::write(&path, b"{not json").unwrap();
        let err = load(&path).unwrap_err();
        assert!(matches!(err, LeaseFileError::Corrupt { .. }), "{err}");
        assert!(err.to_string().contains("leases-ship.json"), "{err}");
        // The file is left as it was: nothing is overwritten before someone looks.
        assert_eq!(std::fs::read(&path).unwrap(), b"{not json");
    }

    #[test]
    fn what_is_saved_loads_back() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("sub/leases.json");
        let mut table = crate::lease::LeaseTable::new("ship", "", &[], 10);
        table.claim("auv-1", 1_800_000_000_000).unwrap();
        save(&path, &table.snapshot()).unwrap();
        assert_eq!(load(&path).unwrap(), table.snapshot());
    }
}
