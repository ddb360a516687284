//! The queue in front of the database and the one thread that writes it.
//!
//! Producers ([`HistoryWriter`]) push records into a bounded FIFO and get a sequence number
//! back. Numbers are given under the queue lock, so queue order is number order, and the
//! writer commits batches in queue order: after a batch is committed, every record up to its
//! last number is in the database. That makes one integer, [`HistoryWriter::committed`], a
//! complete acknowledgement, and "acknowledged" means "committed".
//!
//! The queue is a `Mutex<VecDeque>` with two condition variables rather than a channel: the
//! writer takes a whole batch under one lock, `submit` can hand the record back when the
//! queue is full (`std::sync::mpsc` cannot report its length), and producers only wake the
//! writer when it has a reason to wake (work arrived, or a batch is full).

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};

use tokio::sync::watch;
use tracing::{debug, error, warn};

use crate::backend::WriteStore;
use crate::retention::{self, Maintainer, MaintenanceStats, PassError};
use crate::store::Outcome;
use crate::{Record, SubmitError, WaitError};

/// Attempts at a failing batch once the store is closing, before its records are given up.
const SHUTDOWN_ATTEMPTS: u32 = 3;
/// Longest pause between two attempts at a batch that fails for environment reasons.
const MAX_BACKOFF: Duration = Duration::from_secs(1);

/// Counters of the history store, for metrics and tests.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct HistoryStats {
    /// Records accepted by `submit` (the last sequence number given).
    pub submitted: u64,
    /// Records committed to their own table.
    pub committed_rows: u64,
    /// Records refused by the database and quarantined in `rejected` instead.
    pub failed_rows: u64,
    /// Transactions committed.
    pub batches: u64,
    /// Records waiting in the queue.
    pub queue_len: usize,
    /// Failed attempts to commit a batch for environment reasons (disk full, I/O, locks);
    /// each was retried.
    pub retries: u64,
    /// Records given up at shutdown because the database kept failing; never acknowledged.
    pub abandoned_rows: u64,
    /// Time the writer thread spent writing batches (successful or not), maintenance
    /// excluded: against wall time, how busy the history keeps its thread.
    pub write_busy: Duration,
}

/// The queue proper; guarded by `Shared::queue`.
#[derive(Debug, Default)]
struct Queue {
    records: VecDeque<Record>,
    /// Last sequence number given; sequence numbers start at 1.
    submitted: u64,
    /// Sequence number of the last record taken by the writer.
    taken: u64,
    /// No more submissions; the writer drains what is left and stops.
    closing: bool,
    /// A `flush` waits for records up to this number: the writer must not linger before.
    flush_upto: u64,
}

/// Acknowledgement state; guarded by `Shared::ack`.
#[derive(Debug)]
struct Ack {
    committed: u64,
    writer_alive: bool,
}

/// State shared by the producers, the writer thread and the `History` handle.
#[derive(Debug)]
pub(crate) struct Shared {
    queue: Mutex<Queue>,
    /// The writer waits here for work or for its batch to fill up.
    work: Condvar,
    /// `submit_blocking` waits here for space.
    space: Condvar,
    ack: Mutex<Ack>,
    acked: Condvar,
    ack_tx: watch::Sender<u64>,
    capacity: usize,
    batch_max: usize,
    linger: Duration,
    committed_rows: AtomicU64,
    failed_rows: AtomicU64,
    batches: AtomicU64,
    retries: AtomicU64,
    abandoned_rows: AtomicU64,
    /// Nanoseconds spent in `write_batch`; see [`HistoryStats::write_busy`].
    write_busy_ns: AtomicU64,
    /// What maintenance did; `maintained` is signalled after each pass.
    maintenance: Mutex<MaintenanceStats>,
    maintained: Condvar,
    /// A pass was asked for (`History::maintain`): run one now, whatever the schedule.
    maintenance_requested: AtomicBool,
}

/// Locks a mutex even if a thread panicked while holding it: every critical section here
/// leaves the state consistent, and refusing to work after a panic would lose data.
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(PoisonError::into_inner)
}

/// Waits on `cv` until notified or `deadline` (`None`: no deadline); false once it passed.
fn wait_until<'a, T>(
    cv: &Condvar,
    guard: MutexGuard<'a, T>,
    deadline: Option<Instant>,
) -> (MutexGuard<'a, T>, bool) {
    match deadline {
        None => (cv.wait(guard).unwrap_or_else(PoisonError::into_inner), true),
        Some(d) => {
            let left = d.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return (guard, false);
            }
            let (g, _) = cv
                .wait_timeout(guard, left)
                .unwrap_or_else(PoisonError::into_inner);
            (g, true)
        }
    }
}

impl Shared {
    pub(crate) fn new(capacity: usize, batch_max: usize, linger: Duration) -> Self {
        Self {
            queue: Mutex::new(Queue::default()),
            work: Condvar::new(),
            space: Condvar::new(),
            ack: Mutex::new(Ack {
                committed: 0,
                writer_alive: true,
            }),
            acked: Condvar::new(),
            ack_tx: watch::Sender::new(0),
            capacity,
            batch_max,
            linger,
            committed_rows: AtomicU64::new(0),
            failed_rows: AtomicU64::new(0),
            batches: AtomicU64::new(0),
            retries: AtomicU64::new(0),
            abandoned_rows: AtomicU64::new(0),
            write_busy_ns: AtomicU64::new(0),
            maintenance: Mutex::new(MaintenanceStats::default()),
            maintained: Condvar::new(),
            maintenance_requested: AtomicBool::new(false),
        }
    }

    /// The maintenance counters.
    pub(crate) fn maintenance_stats(&self) -> MaintenanceStats {
        lock(&self.maintenance).clone()
    }

    /// Asks the writer for a maintenance pass now and waits until one has ended (or the
    /// writer stopped, or `timeout` passed); returns the counters then.
    pub(crate) fn maintain(&self, timeout: Duration) -> Result<MaintenanceStats, WaitError> {
        let deadline = Instant::now().checked_add(timeout);
        let mut stats = lock(&self.maintenance);
        if !stats.enabled {
            return Ok(stats.clone());
        }
        let before = stats.passes + stats.failed_passes;
        {
            // Set under the queue lock, so the writer cannot miss the wake-up between
            // checking the flag and waiting.
            let _q = lock(&self.queue);
            self.maintenance_requested.store(true, Ordering::SeqCst);
            self.work.notify_one();
        }
        loop {
            if stats.passes + stats.failed_passes > before {
                return Ok(stats.clone());
            }
            if !lock(&self.ack).writer_alive {
                let committed = lock(&self.ack).committed;
                return Err(WaitError::Stopped {
                    target: 0,
                    committed,
                });
            }
            let (g, waited) = wait_until(&self.maintained, stats, deadline);
            stats = g;
            if !waited {
                return Err(WaitError::Timeout {
                    target: 0,
                    committed: lock(&self.ack).committed,
                });
            }
        }
    }

    /// Takes what is queued, up to a batch, without lingering; `None` when nothing is.
    fn take_ready(&self, batch: &mut Vec<Record>) -> Option<u64> {
        let mut q = lock(&self.queue);
        if q.records.is_empty() {
            return None;
        }
        let n = q.records.len().min(self.batch_max);
        batch.extend(q.records.drain(..n));
        q.taken += n as u64;
        let last = q.taken;
        drop(q);
        self.space.notify_all();
        Some(last)
    }

    /// Appends to the queue (the caller checked there is room) and returns the number.
    fn push(&self, q: &mut Queue, record: Record) -> u64 {
        q.records.push_back(record);
        q.submitted += 1;
        // Wake the writer only on the two transitions it waits for, not on every record, so
        // a busy queue does not cost a wake-up per record.
        let len = q.records.len();
        if len == 1 || len == self.batch_max {
            self.work.notify_one();
        }
        q.submitted
    }

    /// Stops accepting records and wakes everyone so that they notice.
    pub(crate) fn close(&self) {
        lock(&self.queue).closing = true;
        self.work.notify_all();
        self.space.notify_all();
    }

    /// Takes the next batch into `batch` (empty on entry): `Next::Idle` when the queue
    /// stayed empty until `wake` (maintenance is due) or a pass was asked for,
    /// `Next::Closed` when closed and drained.
    ///
    /// Once there is work the writer lingers up to `linger` for a full batch, so that a
    /// trickle of records costs one transaction (one fsync with `synchronous = full`) per
    /// interval rather than one per record. The interval counts from the first record, not
    /// from the last one, so that a steady trickle cannot delay a commit indefinitely.
    fn next_batch(&self, batch: &mut Vec<Record>, wake: Option<Instant>) -> Next {
        let mut q = lock(&self.queue);
        while q.records.is_empty() {
            if q.closing {
                return Next::Closed;
            }
            if self.maintenance_requested.load(Ordering::SeqCst) {
                return Next::Idle;
            }
            let (g, waited) = wait_until(&self.work, q, wake);
            q = g;
            if !waited {
                return Next::Idle;
            }
        }
        if !self.linger.is_zero() {
            let deadline = Instant::now().checked_add(self.linger);
            while q.records.len() < self.batch_max && !q.closing && q.taken >= q.flush_upto {
                let (g, waited) = wait_until(&self.work, q, deadline);
                q = g;
                if !waited {
                    break;
                }
            }
        }
        let n = q.records.len().min(self.batch_max);
        batch.extend(q.records.drain(..n));
        q.taken += n as u64;
        let last = q.taken;
        drop(q);
        self.space.notify_all();
        Next::Batch(last)
    }

    fn is_closing(&self) -> bool {
        lock(&self.queue).closing
    }

    /// Publishes that every record up to `seq` is committed. The watch channel is updated
    /// first: whoever returns from a blocking wait must also find it updated.
    fn acknowledge(&self, seq: u64) {
        self.ack_tx.send_replace(seq);
        lock(&self.ack).committed = seq;
        self.acked.notify_all();
    }

    /// Counts what a committed batch did and acknowledges it.
    fn committed(&self, last_seq: u64, outcome: Outcome) {
        self.committed_rows
            .fetch_add(outcome.stored, Ordering::Relaxed);
        self.failed_rows
            .fetch_add(outcome.failed, Ordering::Relaxed);
        self.batches.fetch_add(1, Ordering::Relaxed);
        self.acknowledge(last_seq);
    }

    pub(crate) fn stats(&self) -> HistoryStats {
        let (submitted, queue_len) = {
            let q = lock(&self.queue);
            (q.submitted, q.records.len())
        };
        HistoryStats {
            submitted,
            committed_rows: self.committed_rows.load(Ordering::Relaxed),
            failed_rows: self.failed_rows.load(Ordering::Relaxed),
            batches: self.batches.load(Ordering::Relaxed),
            queue_len,
            retries: self.retries.load(Ordering::Relaxed),
            abandoned_rows: self.abandoned_rows.load(Ordering::Relaxed),
            write_busy: Duration::from_nanos(self.write_busy_ns.load(Ordering::Relaxed)),
        }
    }
}

/// Marks the writer as gone when its thread ends, however it ends, so that waiters and
/// producers are told instead of waiting for a commit that will never come.
struct WriterAlive<'a>(&'a Shared);

impl Drop for WriterAlive<'_> {
    fn drop(&mut self) {
        self.0.close();
        let left = lock(&self.0.queue).records.len() as u64;
        if left > 0 {
            error!(
                records = left,
                "history writer stopped with records still queued"
            );
            self.0.abandoned_rows.fetch_add(left, Ordering::Relaxed);
        }
        lock(&self.0.ack).writer_alive = false;
        self.0.acked.notify_all();
    }
}

/// What [`Shared::next_batch`] found.
enum Next {
    /// A batch, up to this sequence number.
    Batch(u64),
    /// No records, and maintenance is due (or was asked for).
    Idle,
    /// Closed and drained.
    Closed,
}

/// The writer thread's body: batches until closed and drained, and a maintenance pass
/// whenever one is due (with `maintainer`).
pub(crate) fn run(mut store: WriteStore, shared: &Shared, mut maintainer: Option<Maintainer>) {
    let _alive = WriterAlive(shared);
    let mut batch = Vec::with_capacity(shared.batch_max);
    if maintainer.is_some() {
        let bytes = store.database_bytes().unwrap_or(0);
        let mut stats = lock(&shared.maintenance);
        stats.enabled = true;
        stats.database_bytes = bytes;
    }
    loop {
        if let Some(m) = maintainer.as_mut() {
            let asked = shared.maintenance_requested.swap(false, Ordering::SeqCst);
            if (asked || Instant::now() >= m.next_due()) && !shared.is_closing() {
                if !maintain(&mut store, shared, m, &mut batch) {
                    return give_up(shared, &mut batch);
                }
                continue;
            }
        }
        let wake = maintainer.as_ref().map(Maintainer::next_due);
        match shared.next_batch(&mut batch, wake) {
            Next::Batch(last_seq) => {
                if !commit_with_retries(&mut store, shared, &batch, last_seq) {
                    return give_up(shared, &mut batch);
                }
                batch.clear();
            }
            Next::Idle => {}
            Next::Closed => break,
        }
    }
    debug!("history writer drained and stopped");
}

/// The database keeps failing and we are closing: what is left cannot be stored either.
/// It was never acknowledged, so nothing acknowledged is lost.
fn give_up(shared: &Shared, batch: &mut Vec<Record>) {
    let mut q = lock(&shared.queue);
    let left = batch.len() + q.records.len();
    q.records.clear();
    drop(q);
    batch.clear();
    shared
        .abandoned_rows
        .fetch_add(left as u64, Ordering::Relaxed);
    error!(
        records = left,
        "history store closed with records it could not store"
    );
}

/// Runs one maintenance pass, committing queued records between its statements, and
/// records what it did. False when a batch could not be committed at shutdown (give up).
fn maintain(
    store: &mut WriteStore,
    shared: &Shared,
    maintainer: &mut Maintainer,
    batch: &mut Vec<Record>,
) -> bool {
    let started = Instant::now();
    let mut committed_ok = true;
    let mut between = |store: &mut WriteStore| {
        if let Some(last_seq) = shared.take_ready(batch) {
            if !commit_with_retries(store, shared, batch, last_seq) {
                committed_ok = false;
                return false;
            }
            batch.clear();
        }
        !shared.is_closing()
    };
    let result = maintainer
        .run_pass(store, shoal_model::now_ms(), &mut between)
        .and_then(|report| retention::release_free_pages(store, &mut between).map(|_| report));
    let took = started.elapsed();
    let bytes = store.database_bytes().ok();
    let mut stats = lock(&shared.maintenance);
    match result {
        Ok(report) => {
            retention::log_pass(&report, took);
            stats.passes += 1;
            stats.rows_downsampled += report.downsampled;
            stats.rows_deleted += report.deleted;
            stats.statements += report.statements;
            stats.cap_passes += u64::from(report.cap_acted);
            stats.rows = report.rows;
            stats.last_error = None;
        }
        Err(PassError::Stopped) => {
            debug!("history maintenance pass stopped: the store is closing");
            return committed_ok;
        }
        Err(PassError::Store(e)) => {
            warn!(error = %e, "history maintenance pass failed; retrying at the next interval");
            stats.failed_passes += 1;
            stats.last_error = Some(e.to_string());
        }
    }
    stats.last_pass_ms = shoal_model::now_ms();
    stats.last_duration_ms = u64::try_from(took.as_millis()).unwrap_or(u64::MAX);
    if let Some(bytes) = bytes {
        stats.database_bytes = bytes;
    }
    drop(stats);
    shared.maintained.notify_all();
    committed_ok
}

/// Commits one batch, retrying environment failures with backoff for as long as the store
/// is open (the queue then fills up and producers see `Full`, which is the back-pressure we
/// want). Returns false only when closing and the failures persist.
fn commit_with_retries(
    store: &mut WriteStore,
    shared: &Shared,
    batch: &[Record],
    last_seq: u64,
) -> bool {
    let mut attempt: u32 = 0;
    let mut closing_attempts: u32 = 0;
    loop {
        let started = Instant::now();
        let written = store.write_batch(batch);
        let took = u64::try_from(started.elapsed().as_nanos()).unwrap_or(u64::MAX);
        shared.write_busy_ns.fetch_add(took, Ordering::Relaxed);
        match written {
            Ok(outcome) => {
                if outcome.failed > 0 {
                    warn!(
                        failed = outcome.failed,
                        lost = outcome.lost,
                        stored = outcome.stored,
                        "history batch had rows refused by the database"
                    );
                }
                shared.committed(last_seq, outcome);
                return true;
            }
            Err(e) => {
                attempt = attempt.saturating_add(1);
                shared.retries.fetch_add(1, Ordering::Relaxed);
                if shared.is_closing() {
                    closing_attempts += 1;
                    if closing_attempts >= SHUTDOWN_ATTEMPTS {
                        error!(error = %e, rows = batch.len(), "giving up on a history batch at shutdown");
                        return false;
                    }
                }
                warn!(error = %e, attempt, rows = batch.len(), "history batch not committed; will retry");
                let backoff = Duration::from_millis(10u64.saturating_mul(1 << attempt.min(7)));
                std::thread::sleep(backoff.min(MAX_BACKOFF));
            }
        }
    }
}

/// A handle to submit records and follow their acknowledgement; cheap to clone, usable from
/// any thread, and needs no async runtime.
#[derive(Debug, Clone)]
pub struct HistoryWriter {
    pub(crate) shared: Arc<Shared>,
}

impl HistoryWriter {
    /// Queues a record without blocking and returns its sequence number; when the queue is
    /// full or the store closed, hands the record back.
    pub fn submit(&self, record: impl Into<Record>) -> Result<u64, SubmitError> {
        let record = record.into();
        let mut q = lock(&self.shared.queue);
        if q.closing {
            return Err(SubmitError::Closed(Box::new(record)));
        }
        if q.records.len() >= self.shared.capacity {
            return Err(SubmitError::Full(Box::new(record)));
        }
        Ok(self.shared.push(&mut q, record))
    }

    /// Queues a record, waiting for space if the queue is full; fails only when closed.
    pub fn submit_blocking(&self, record: impl Into<Record>) -> Result<u64, SubmitError> {
        let record = record.into();
        let mut q = lock(&self.shared.queue);
        loop {
            if q.closing {
                return Err(SubmitError::Closed(Box::new(record)));
            }
            if q.records.len() < self.shared.capacity {
                return Ok(self.shared.push(&mut q, record));
            }
            q = wait_until(&self.shared.space, q, None).0;
        }
    }

    /// The highest sequence number committed: every record up to it is in the database.
    pub fn committed(&self) -> u64 {
        lock(&self.shared.ack).committed
    }

    /// Blocks until record `seq` is committed, the timeout elapses, or the writer stops.
    pub fn wait_committed(&self, seq: u64, timeout: Duration) -> Result<(), WaitError> {
        let deadline = Instant::now().checked_add(timeout);
        let mut ack = lock(&self.shared.ack);
        loop {
            if ack.committed >= seq {
                return Ok(());
            }
            if !ack.writer_alive {
                return Err(WaitError::Stopped {
                    target: seq,
                    committed: ack.committed,
                });
            }
            let (g, waited) = wait_until(&self.shared.acked, ack, deadline);
            ack = g;
            if !waited {
                return Err(WaitError::Timeout {
                    target: seq,
                    committed: ack.committed,
                });
            }
        }
    }

    /// The committed sequence number as a `watch` channel, for async code: `changed().await`
    /// on it instead of blocking a runtime thread in [`Self::wait_committed`].
    pub fn subscribe_committed(&self) -> watch::Receiver<u64> {
        self.shared.ack_tx.subscribe()
    }

    /// Blocks until everything submitted so far is committed; the writer stops lingering.
    pub fn flush(&self, timeout: Duration) -> Result<(), WaitError> {
        let target = {
            let mut q = lock(&self.shared.queue);
            q.flush_upto = q.flush_upto.max(q.submitted);
            q.submitted
        };
        self.shared.work.notify_one();
        self.wait_committed(target, timeout)
    }

    /// Current counters.
    pub fn stats(&self) -> HistoryStats {
        self.shared.stats()
    }

    /// What retention maintenance has done so far (rows downsampled and deleted, the last
    /// pass's time and duration, the database size); see [`MaintenanceStats`].
    pub fn maintenance_stats(&self) -> MaintenanceStats {
        self.shared.maintenance_stats()
    }

    /// Runs a maintenance pass now rather than at its next interval, and waits until it
    /// has ended: `Ok` with the counters then (also when it failed: see
    /// [`MaintenanceStats::last_error`]), at once when retention is off. Ingest goes on
    /// meanwhile, as it does during scheduled passes.
    pub fn maintain(&self, timeout: Duration) -> Result<MaintenanceStats, WaitError> {
        self.shared.maintain(timeout)
    }
}
