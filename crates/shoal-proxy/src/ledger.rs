//! The vehicle's task ledger: which tasks this vehicle has started and how each ended,
//! kept in a small file per vehicle so that no restart (of the vehicle, its proxy or the
//! station) makes it run a task a second time.
//!
//! - A task is written down as started *before* the vehicle is given it: if the write
//!   fails, the task is refused rather than run without a record.
//! - A task the ledger knows is never started again. One that ended is answered with its
//!   final state again (the station may have missed it); one that was under way when the
//!   process stopped is resumed, once, if the station still publishes it.
//! - A task the ledger does not know starts only before its expiry (or, without one,
//!   within the vehicle's maximum task age).
//! - Entries are forgotten once their task could no longer start anyway (an hour after
//!   the later of its expiry and its end, against clock skew), and the ledger holds at most
//!   [`MAX_ENTRIES`], so the file stays small over a deployment of any length.
//!
//! - It also keeps the newest command lease the vehicle has obeyed (the issuing site and
//!   the lease's term, which every task carries): a new task under an older lease is
//!   refused, so two stations that both believe they command the vehicle (a partition
//!   between them) cannot both have it obeyed. The lease moves on only with a task that
//!   is started, and is written down with it.
//!
//! The file is JSON, replaced atomically (written beside, synced, renamed), so a crash or
//! power cut leaves either the old or the new ledger, never a torn one.

use std::collections::BTreeMap;
use std::fs::{self, File};
use std::io::Write as _;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use shoal_model::{TaskAssignment, TaskState};

/// Most tasks the ledger remembers; beyond, the oldest ended ones are forgotten first.
pub const MAX_ENTRIES: usize = 10_000;
/// How long past a task's expiry (or end) it is still remembered: covers clock skew
/// between the station and the vehicle.
const FORGET_AFTER_MS: i64 = 3_600_000;
/// The file layout version.
const VERSION: u32 = 1;

/// The ledger file could not be read or written.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LedgerError {
    /// Reading, writing, syncing or renaming failed.
    #[error("task ledger {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// [`MAX_ENTRIES`] tasks are under way and none has ended: a flood of tasks, refused
    /// rather than remembered without limit.
    #[error("task ledger full: {0} tasks under way")]
    Full(usize),
    /// The file is not a ledger this build can read.
    #[error("task ledger {path} is unreadable: {detail}")]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        detail: String,
    },
}

/// Where a remembered task got to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Progress {
    /// Handed to the vehicle; no final state yet.
    Started,
    /// Ended in this state.
    Ended(TaskState),
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct Entry {
    issue_seq: u64,
    progress: Progress,
    /// When the entry may be forgotten, ms since the Unix epoch.
    forget_after_ms: i64,
    /// Last change, ms since the Unix epoch (orders what to forget first at capacity).
    updated_ms: i64,
}

/// The newest command lease a vehicle has obeyed.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ObeyedLease {
    /// The lease's term.
    pub term: u64,
    /// The site that held it.
    pub holder: String,
}

impl ObeyedLease {
    /// Whether a task issued under `a`'s lease may still be obeyed: its lease is this one
    /// or a newer one.
    fn admits(&self, a: &TaskAssignment) -> bool {
        (a.lease_term == self.term && a.lease_holder == self.holder)
            || shoal_model::lease_supersedes(a.lease_term, &a.lease_holder, self.term, &self.holder)
    }
}

#[derive(Debug, Serialize, Deserialize)]
struct File1 {
    version: u32,
    vehicle_id: String,
    tasks: BTreeMap<String, Entry>,
    /// Absent in a ledger written before leases, or by a vehicle never commanded under one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    lease: Option<ObeyedLease>,
}

/// What to do with a task assignment addressed to this vehicle.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Admission {
    /// New and still in time: start it (the ledger has it as started).
    Start,
    /// Started before this process and still published: resume it (once).
    Resume,
    /// Already handed to the vehicle by this process: a duplicate, ignore it.
    Duplicate,
    /// It ended before, in this state: never again; report the state again.
    Ended(TaskState),
    /// New but past its expiry (or too old): refuse it as expired.
    Expired,
    /// Issued under an older command lease than one the vehicle has obeyed (the lease
    /// named): refuse it. A task under way from an earlier run is ended as failed.
    Fenced(ObeyedLease),
}

/// The ledger of one vehicle, in memory or backed by a file.
#[derive(Debug)]
pub struct TaskLedger {
    vehicle_id: String,
    path: Option<PathBuf>,
    tasks: BTreeMap<String, Entry>,
    /// Tasks admitted (started or resumed) by this process, to tell a duplicate delivery
    /// from a task left under way by a previous run.
    this_run: std::collections::HashSet<String>,
    max_age_ms: Option<i64>,
    /// When entries were last checked for forgetting (the check is a full pass).
    pruned_ms: i64,
    /// The newest command lease obeyed.
    lease: Option<ObeyedLease>,
}

/// How often, at most, the ledger looks for entries to forget.
const PRUNE_EVERY_MS: i64 = 60_000;

impl TaskLedger {
    /// A ledger kept in memory only: a restart forgets it (tests, tools).
    pub fn in_memory(vehicle_id: &str, max_age_ms: Option<i64>) -> Self {
        Self {
            vehicle_id: vehicle_id.to_owned(),
            path: None,
            tasks: BTreeMap::new(),
            this_run: std::collections::HashSet::new(),
            max_age_ms,
            pruned_ms: i64::MIN,
            lease: None,
        }
    }

    /// Opens (or starts) the ledger of `vehicle_id` in `dir` (`<dir>/<vehicle_id>.tasks.json`),
    /// creating the directory. A file for another vehicle, or one that does not parse, is
    /// an error: silently starting afresh would forget what already ran.
    pub fn open(
        dir: &Path,
        vehicle_id: &str,
        max_age_ms: Option<i64>,
    ) -> Result<Self, LedgerError> {
        let path = dir.join(format!("{vehicle_id}.tasks.json"));
        let io = |source| LedgerError::Io {
            path: path.clone(),
            source,
        };
        fs::create_dir_all(dir).map_err(|source| LedgerError::Io {
            path: dir.to_path_buf(),
            source,
        })?;
        let (tasks, lease) = match fs::read(&path) {
            Ok(bytes) => {
                let file: File1 =
                    serde_json::from_slice(&bytes).map_err(|e| LedgerError::Corrupt {
                        path: path.clone(),
                        detail: e.to_string(),
                    })?;
                if file.version != VERSION || file.vehicle_id != vehicle_id {
                    return Err(LedgerError::Corrupt {
                        path,
                        detail: format!(
                            "version {} for vehicle {:?}; expected version {VERSION} for {vehicle_id:?}",
                            file.version, file.vehicle_id
                        ),
                    });
                }
                (file.tasks, file.lease)
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => (BTreeMap::new(), None),
            Err(e) => return Err(io(e)),
        };
        Ok(Self {
            vehicle_id: vehicle_id.to_owned(),
            path: Some(path),
            tasks,
            this_run: std::collections::HashSet::new(),
            max_age_ms,
            pruned_ms: i64::MIN,
            lease,
        })
    }

    /// The newest command lease this vehicle has obeyed, if any.
    pub fn lease(&self) -> Option<&ObeyedLease> {
        self.lease.as_ref()
    }

    /// Forgets the command lease this vehicle has obeyed, at once on disk: the vehicle left
    /// the federation whose stations issued it, and is to take tasks under no lease (term
    /// 0) again, or under any lease until the next one moves it on. The lease forgotten,
    /// if there was one.
    pub fn forget_lease(&mut self, now_ms: i64) -> Result<Option<ObeyedLease>, LedgerError> {
        let previous = self.lease.take();
        if previous.is_some()
            && let Err(e) = self.save(now_ms)
        {
            self.lease = previous;
            return Err(e);
        }
        Ok(previous)
    }

    /// The tasks remembered, by id, with where each got to.
    pub fn entries(&self) -> impl Iterator<Item = (&str, Progress)> {
        self.tasks.iter().map(|(id, e)| (id.as_str(), e.progress))
    }

    /// How many tasks it remembers.
    pub fn len(&self) -> usize {
        self.tasks.len()
    }

    /// Whether it remembers no task.
    pub fn is_empty(&self) -> bool {
        self.tasks.is_empty()
    }

    /// Where a task got to, if the ledger remembers it.
    pub fn progress(&self, task_id: &str) -> Option<Progress> {
        self.tasks.get(task_id).map(|e| e.progress)
    }

    /// Decides what to do with an assignment at `now_ms`; a task to start or resume is
    /// written down as started first (the error means: do not run it).
    pub fn admit(&mut self, a: &TaskAssignment, now_ms: i64) -> Result<Admission, LedgerError> {
        // The same id under another issue sequence is another task that reuses the id (a
        // station whose history was wiped): what the ledger holds is not about it.
        let same_issue =
            |e: &&Entry| e.issue_seq == a.issue_seq || e.issue_seq == 0 || a.issue_seq == 0;
        match self
            .tasks
            .get(&a.task_id)
            .filter(same_issue)
            .map(|e| e.progress)
        {
            Some(Progress::Ended(state)) => Ok(Admission::Ended(state)),
            Some(Progress::Started) if self.this_run.contains(&a.task_id) => {
                Ok(Admission::Duplicate)
            }
            Some(Progress::Started) => {
                if let Some(fence) = self.fence(a) {
                    // Left under way by an earlier run, and another site has commanded
                    // the vehicle since: not resumed, and ended so it is not kept forever.
                    self.end(&a.task_id, TaskState::Failed, now_ms)?;
                    return Ok(Admission::Fenced(fence));
                }
                let previous = self.obey(a);
                if self.lease != previous
                    && let Err(e) = self.save(now_ms)
                {
                    self.lease = previous;
                    return Err(e);
                }
                self.this_run.insert(a.task_id.clone());
                Ok(Admission::Resume)
            }
            None if !a.may_start(now_ms, self.max_age_ms) => Ok(Admission::Expired),
            None => {
                if let Some(fence) = self.fence(a) {
                    // Not written down: a task refused so stays refused (the lease only
                    // moves on), and a flood of them must not fill the ledger.
                    return Ok(Admission::Fenced(fence));
                }
                // Room for one more: the oldest ended entries go first.
                self.prune(now_ms, MAX_ENTRIES - 1);
                if self.tasks.len() >= MAX_ENTRIES && !self.tasks.contains_key(&a.task_id) {
                    return Err(LedgerError::Full(self.tasks.len()));
                }
                let forget_after_ms = self.forget_after(a, now_ms);
                self.tasks.insert(
                    a.task_id.clone(),
                    Entry {
                        issue_seq: a.issue_seq,
                        progress: Progress::Started,
                        forget_after_ms,
                        updated_ms: now_ms,
                    },
                );
                let previous = self.obey(a);
                if let Err(e) = self.save(now_ms) {
                    self.tasks.remove(&a.task_id);
                    self.lease = previous;
                    return Err(e);
                }
                self.this_run.insert(a.task_id.clone());
                Ok(Admission::Start)
            }
        }
    }

    /// The lease that refuses `a`: the one obeyed, when `a`'s is older.
    fn fence(&self, a: &TaskAssignment) -> Option<ObeyedLease> {
        self.lease.as_ref().filter(|l| !l.admits(a)).cloned()
    }

    /// Takes `a`'s lease as the one obeyed if it is newer (`a` passed [`Self::fence`]);
    /// returns the previous one, to restore if the ledger cannot be written.
    fn obey(&mut self, a: &TaskAssignment) -> Option<ObeyedLease> {
        let previous = self.lease.clone();
        if a.lease_term > 0
            && self
                .lease
                .as_ref()
                .is_none_or(|l| l.term != a.lease_term || l.holder != a.lease_holder)
        {
            self.lease = Some(ObeyedLease {
                term: a.lease_term,
                holder: a.lease_holder.clone(),
            });
        }
        previous
    }

    /// Records that a task ended (a final state); unknown tasks are ignored.
    pub fn end(&mut self, task_id: &str, state: TaskState, now_ms: i64) -> Result<(), LedgerError> {
        let Some(e) = self.tasks.get_mut(task_id) else {
            return Ok(());
        };
        if e.progress == Progress::Ended(state) {
            return Ok(());
        }
        e.progress = Progress::Ended(state);
        e.updated_ms = now_ms;
        e.forget_after_ms = e
            .forget_after_ms
            .max(now_ms.saturating_add(FORGET_AFTER_MS));
        self.save(now_ms)
    }

    /// When an entry for `a` may go: an hour after the last instant it could still start.
    fn forget_after(&self, a: &TaskAssignment, now_ms: i64) -> i64 {
        let last_start = if a.expires_ms != 0 {
            a.expires_ms
        } else {
            match self.max_age_ms {
                Some(max) => a.issued_ms.saturating_add(max),
                // Any age may start: remember it as long as capacity allows.
                None => i64::MAX - FORGET_AFTER_MS,
            }
        };
        last_start.max(now_ms).saturating_add(FORGET_AFTER_MS)
    }

    /// Forgets ended entries that can no longer matter, then the oldest ended ones beyond
    /// capacity. Tasks still under way are kept whatever their age.
    fn prune(&mut self, now_ms: i64, limit: usize) {
        let over = self.tasks.len() > limit;
        if !over && now_ms.saturating_sub(self.pruned_ms) < PRUNE_EVERY_MS {
            return;
        }
        self.pruned_ms = now_ms;
        self.tasks.retain(|_, e| {
            !(matches!(e.progress, Progress::Ended(_)) && e.forget_after_ms < now_ms)
        });
        if self.tasks.len() > limit {
            let mut ended: Vec<(i64, String)> = self
                .tasks
                .iter()
                .filter(|(_, e)| matches!(e.progress, Progress::Ended(_)))
                .map(|(id, e)| (e.updated_ms, id.clone()))
                .collect();
            ended.sort_unstable();
            let excess = self.tasks.len() - limit;
            for (_, id) in ended.into_iter().take(excess) {
                self.tasks.remove(&id);
            }
        }
        let tasks = &self.tasks;
        self.this_run.retain(|id| tasks.contains_key(id));
    }

    fn save(&mut self, now_ms: i64) -> Result<(), LedgerError> {
        self.prune(now_ms, MAX_ENTRIES);
        let Some(path) = &self.path else {
            return Ok(());
        };
        let file = File1 {
            version: VERSION,
            vehicle_id: self.vehicle_id.clone(),
            tasks: self.tasks.clone(),
            lease: self.lease.clone(),
        };
        let io = |source| LedgerError::Io {
            path: path.clone(),
            source,
        };
        let bytes = serde_json::to_vec(&file).map_err(|e| LedgerError::Corrupt {
            path: path.clone(),
            detail: e.to_string(),
        })?;
        let tmp = path.with_extension("json.tmp");
        let mut f = File::create(&tmp).map_err(io)?;
        f.write_all(&bytes).map_err(io)?;
        f.sync_all().map_err(io)?;
        drop(f);
        fs::rename(&tmp, path).map_err(io)?;
        // The rename itself must reach the disk before the task runs.
        if let Some(dir) = path.parent() {
            File::open(dir).and_then(|d| d.sync_all()).map_err(io)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use shoal_model::Task;

    use super::*;

    const T: i64 = 1_800_000_000_000;

    fn task(id: &str, seq: u64, expires_ms: i64) -> TaskAssignment {
        let mut a = TaskAssignment::new(id, "", "auv-9", T, &Task::Surface);
        a.issue_seq = seq;
        a.expires_ms = expires_ms;
        a
    }

    #[test]
    fn a_finished_task_is_never_started_again_after_a_restart() {
        let dir = tempfile::tempdir().unwrap();
        let a = task("r-1-1", 1, T + 45_000);
        let mut l = TaskLedger::open(dir.path(), "auv-9", None).unwrap();
        assert_eq!(l.admit(&a, T + 1).unwrap(), Admission::Start);
        assert_eq!(l.admit(&a, T + 2).unwrap(), Admission::Duplicate);
        l.end("r-1-1", TaskState::Done, T + 60_000).unwrap();
        drop(l);
        // The process restarts; the bus hands the same task back.
        let mut l = TaskLedger::open(dir.path(), "auv-9", None).unwrap();
        assert_eq!(
            l.admit(&a, T + 61_000).unwrap(),
            Admission::Ended(TaskState::Done)
        );
        assert_eq!(
            l.admit(&a, T + 30_000).unwrap(),
            Admission::Ended(TaskState::Done)
        );
    }

    #[test]
    fn a_reused_task_id_under_a_new_issue_sequence_is_a_new_task() {
        let mut l = TaskLedger::in_memory("auv-9", None);
        l.admit(&task("r-1-1", 5_000, T + 45_000), T).unwrap();
        l.end("r-1-1", TaskState::Done, T + 1_000).unwrap();
        assert_eq!(
            l.admit(&task("r-1-1", 5_000, T + 45_000), T + 2_000)
                .unwrap(),
            Admission::Ended(TaskState::Done)
        );
        // A station that lost its history issues r-1-1 again, with a later sequence.
        assert_eq!(
            l.admit(&task("r-1-1", 9_000, T + 99_000), T + 50_000)
                .unwrap(),
            Admission::Start
        );
        assert_eq!(
            l.admit(&task("r-1-1", 9_000, T + 99_000), T + 50_001)
                .unwrap(),
            Admission::Duplicate
        );
    }

    #[test]
    fn a_task_under_way_at_a_restart_is_resumed_once() {
        let dir = tempfile::tempdir().unwrap();
        let a = task("r-1-2", 2, T + 45_000);
        let mut l = TaskLedger::open(dir.path(), "auv-9", None).unwrap();
        assert_eq!(l.admit(&a, T).unwrap(), Admission::Start);
        drop(l);
        let mut l = TaskLedger::open(dir.path(), "auv-9", None).unwrap();
        // Past its start-by time, but it had started: resumed, then a duplicate.
        assert_eq!(l.admit(&a, T + 600_000).unwrap(), Admission::Resume);
        assert_eq!(l.admit(&a, T + 600_001).unwrap(), Admission::Duplicate);
    }

    #[test]
    fn a_new_task_starts_only_in_time() {
        let mut l = TaskLedger::in_memory("auv-9", Some(900_000));
        assert_eq!(
            l.admit(&task("late", 3, T + 45_000), T + 45_001).unwrap(),
            Admission::Expired
        );
        assert_eq!(
            l.progress("late"),
            None,
            "an expired task is not written down"
        );
        // No expiry: the vehicle's own maximum age.
        assert_eq!(
            l.admit(&task("old", 0, 0), T + 900_001).unwrap(),
            Admission::Expired
        );
        assert_eq!(
            l.admit(&task("fresh", 0, 0), T + 899_999).unwrap(),
            Admission::Start
        );
    }

    #[test]
    fn old_ended_entries_are_forgotten_and_capacity_is_bounded() {
        let mut l = TaskLedger::in_memory("auv-9", None);
        let a = task("a", 1, T + 1_000);
        l.admit(&a, T).unwrap();
        l.end("a", TaskState::Done, T + 500).unwrap();
        // Still remembered within the skew margin, forgotten after it.
        l.admit(&task("b", 2, T + FORGET_AFTER_MS), T + FORGET_AFTER_MS)
            .unwrap();
        assert_eq!(l.progress("a"), Some(Progress::Ended(TaskState::Done)));
        l.admit(
            &task("c", 3, T + 3 * FORGET_AFTER_MS),
            T + 2 * FORGET_AFTER_MS,
        )
        .unwrap();
        assert_eq!(l.progress("a"), None);
        assert_eq!(
            l.progress("b"),
            Some(Progress::Started),
            "a task under way is kept"
        );

        let mut l = TaskLedger::in_memory("auv-9", None);
        for i in 0..(MAX_ENTRIES + 50) {
            let id = format!("t-{i}");
            let now = T + i64::try_from(i).unwrap();
            l.admit(&task(&id, 1, now + 10_000), now).unwrap();
            l.end(&id, TaskState::Done, now).unwrap();
        }
        assert_eq!(l.len(), MAX_ENTRIES);
        assert_eq!(l.progress("t-0"), None, "the oldest go first");
        assert!(l.progress(&format!("t-{}", MAX_ENTRIES + 49)).is_some());
    }

    #[test]
    fn a_flood_of_tasks_that_never_end_fills_the_ledger_and_is_refused_not_remembered() {
        let mut l = TaskLedger::in_memory("auv-9", None);
        for i in 0..MAX_ENTRIES {
            let id = format!("f-{i}");
            assert_eq!(
                l.admit(&task(&id, 1, T + 45_000), T).unwrap(),
                Admission::Start
            );
        }
        let err = l.admit(&task("one-more", 1, T + 45_000), T).unwrap_err();
        assert!(
            matches!(err, LedgerError::Full(n) if n == MAX_ENTRIES),
            "{err}"
        );
        assert_eq!(l.len(), MAX_ENTRIES);
        // A task that ends makes room: ended entries go first at capacity.
        l.end("f-0", TaskState::Done, T).unwrap();
        assert_eq!(
            l.admit(&task("next", 2, T + 45_000), T).unwrap(),
            Admission::Start
        );
        assert_eq!(l.progress("f-0"), None);
    }

    #[test]
    fn a_ledger_that_cannot_be_written_refuses_to_start_the_task() {
        let dir = tempfile::tempdir().unwrap();
        let mut l = TaskLedger::open(dir.path(), "auv-9", None).unwrap();
        // The directory goes away under the vehicle (a full or failed disk).
        drop(dir);
        assert!(l.admit(&task("t", 1, T + 45_000), T).is_err());
        assert_eq!(l.progress("t"), None);
    }

    #[test]
    fn a_corrupt_or_foreign_ledger_is_an_error_not_a_fresh_start() {
        let dir = tempfile::tempdir().unwrap();
        fs::write(dir.path().join("auv-9.tasks.json"), b"{not json").unwrap();
        let err = TaskLedger::open(dir.path(), "auv-9", None).unwrap_err();
        assert!(err.to_string().contains("auv-9.tasks.json"), "{err}");
        let mut other = TaskLedger::open(dir.path(), "auv-8", None).unwrap();
        other.admit(&task("t", 1, T + 45_000), T).unwrap();
        fs::rename(
            dir.path().join("auv-8.tasks.json"),
            dir.path().join("auv-9.tasks.json"),
        )
        .unwrap();
        let err = TaskLedger::open(dir.path(), "auv-9", None).unwrap_err();
        assert!(err.to_string().contains("\"auv-8\""), "{err}");
    }

    fn leased(id: &str, seq: u64, term: u64, holder: &str) -> TaskAssignment {
        let mut a = task(id, seq, T + 45_000);
        a.lease_term = term;
        a.lease_holder = holder.to_owned();
        a
    }

    fn obeyed(term: u64, holder: &str) -> ObeyedLease {
        ObeyedLease {
            term,
            holder: holder.to_owned(),
        }
    }

    #[test]
    fn a_task_under_an_older_lease_is_refused_and_the_lease_survives_a_restart() {
        let dir = tempfile::tempdir().unwrap();
        let mut l = TaskLedger::open(dir.path(), "auv-9", None).unwrap();
        assert_eq!(
            l.admit(&leased("s-1", 1, 1, "ship"), T).unwrap(),
            Admission::Start
        );
        assert_eq!(l.lease(), Some(&obeyed(1, "ship")));
        // The shore took over (term 2) and commands the vehicle.
        assert_eq!(
            l.admit(&leased("h-1", 1, 2, "shore"), T + 1).unwrap(),
            Admission::Start
        );
        drop(l);
        let mut l = TaskLedger::open(dir.path(), "auv-9", None).unwrap();
        assert_eq!(l.lease(), Some(&obeyed(2, "shore")));
        // The ship, cut off from the shore, still believes it holds term 1.
        assert_eq!(
            l.admit(&leased("s-2", 2, 1, "ship"), T + 2).unwrap(),
            Admission::Fenced(obeyed(2, "shore"))
        );
        assert_eq!(
            l.progress("s-2"),
            None,
            "a refused task is not written down"
        );
        // The holder's own tasks still go, and so does a newer lease's.
        assert_eq!(
            l.admit(&leased("h-2", 2, 2, "shore"), T + 3).unwrap(),
            Admission::Start
        );
        assert_eq!(
            l.admit(&leased("s-3", 3, 3, "ship"), T + 4).unwrap(),
            Admission::Start
        );
        assert_eq!(
            l.admit(&leased("h-3", 3, 2, "shore"), T + 5).unwrap(),
            Admission::Fenced(obeyed(3, "ship"))
        );
    }

    #[test]
    fn the_same_term_from_two_sites_goes_to_the_name_that_sorts_first() {
        // Two sites that both took term 2 in a partition: every site and vehicle agrees
        // that "alpha" wins.
        let mut l = TaskLedger::in_memory("auv-9", None);
        assert_eq!(
            l.admit(&leased("b-1", 1, 2, "bravo"), T).unwrap(),
            Admission::Start
        );
        assert_eq!(
            l.admit(&leased("a-1", 1, 2, "alpha"), T + 1).unwrap(),
            Admission::Start
        );
        assert_eq!(
            l.admit(&leased("b-2", 2, 2, "bravo"), T + 2).unwrap(),
            Admission::Fenced(obeyed(2, "alpha"))
        );
    }

    #[test]
    fn a_task_without_a_lease_goes_only_to_a_vehicle_never_commanded_under_one() {
        let mut l = TaskLedger::in_memory("auv-9", None);
        assert_eq!(
            l.admit(&leased("t-1", 1, 0, ""), T).unwrap(),
            Admission::Start
        );
        assert_eq!(l.lease(), None, "no lease, nothing to obey");
        assert_eq!(
            l.admit(&leased("s-1", 2, 1, "ship"), T + 1).unwrap(),
            Admission::Start
        );
        assert_eq!(
            l.admit(&leased("t-2", 3, 0, ""), T + 2).unwrap(),
            Admission::Fenced(obeyed(1, "ship"))
        );
    }

    #[test]
    fn a_forgotten_lease_lets_a_task_without_one_go_and_stays_forgotten() {
        let dir = tempfile::tempdir().unwrap();
        let mut l = TaskLedger::open(dir.path(), "auv-9", None).unwrap();
        l.admit(&leased("s-1", 1, 3, "shore"), T).unwrap();
        drop(l);
        // The vehicle left the federation; its new station sends no lease.
        let mut l = TaskLedger::open(dir.path(), "auv-9", None).unwrap();
        assert_eq!(l.forget_lease(T + 1).unwrap(), Some(obeyed(3, "shore")));
        assert_eq!(l.forget_lease(T + 2).unwrap(), None);
        drop(l);
        let mut l = TaskLedger::open(dir.path(), "auv-9", None).unwrap();
        assert_eq!(l.lease(), None);
        // What ran before still never runs again.
        assert_eq!(
            l.entries().collect::<Vec<_>>(),
            vec![("s-1", Progress::Started)]
        );
        assert_eq!(
            l.admit(&leased("t-1", 2, 0, ""), T + 3).unwrap(),
            Admission::Start
        );
    }

    #[test]
    fn a_task_under_way_under_an_older_lease_is_not_resumed_and_ends() {
        let dir = tempfile::tempdir().unwrap();
        let old = leased("s-1", 1, 1, "ship");
        let mut l = TaskLedger::open(dir.path(), "auv-9", None).unwrap();
        assert_eq!(l.admit(&old, T).unwrap(), Admission::Start);
        assert_eq!(
            l.admit(&leased("h-1", 1, 2, "shore"), T + 1).unwrap(),
            Admission::Start
        );
        drop(l);
        let mut l = TaskLedger::open(dir.path(), "auv-9", None).unwrap();
        assert_eq!(
            l.admit(&old, T + 2).unwrap(),
            Admission::Fenced(obeyed(2, "shore"))
        );
        assert_eq!(l.progress("s-1"), Some(Progress::Ended(TaskState::Failed)));
        assert_eq!(
            l.admit(&old, T + 3).unwrap(),
            Admission::Ended(TaskState::Failed)
        );
    }

    #[test]
    fn a_ledger_written_before_leases_still_opens() {
        let dir = tempfile::tempdir().unwrap();
        fs::write(
            dir.path().join("auv-9.tasks.json"),
            r#"{"version":1,"vehicle_id":"auv-9","tasks":{}}"#,
        )
        .unwrap();
        let l = TaskLedger::open(dir.path(), "auv-9", None).unwrap();
        assert_eq!(l.lease(), None);
    }
}
