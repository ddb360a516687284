//! The Data Access Manager's side of the semantic model: the coalesced RDF mirror of
//! vehicles' states, time-driven rules, and read-only SPARQL on snapshots.

use std::time::Duration;

use shoal_semantic::{QueryLimits, QueryResult, QuerySnapshot};

use crate::core::{StationHandle, lock};

/// How often a share of the dirty state mirrors is written to the semantic model.
pub(crate) const FLUSH_STEP: Duration = Duration::from_millis(100);
/// Steps in a second: each writes this fraction of the mirrors waiting.
const FLUSH_STEPS_PER_S: usize = 10;

impl StationHandle {
    /// Every [`FLUSH_STEP`]: mirrors a share of the dirty states into RDF (coalesced: a
    /// vehicle at most once per `semantic.min_state_interval_ms`), so that the mirrors of a
    /// second are written in [`FLUSH_STEPS_PER_S`] small parts spread over it. Written all
    /// at once, a thousand mirrors took 10 to 15 ms of one core each second, and the state
    /// vectors arriving meanwhile waited behind them (the 5 to 10 ms tail of vehicle ->
    /// console latency). Each part is written a few vehicles per hold of the model's lock,
    /// which ingest takes for every state vector.
    pub(crate) fn semantic_flush_step(&self, now: i64) {
        const MIRRORS_PER_LOCK: usize = 32;
        let mut left = lock(&self.core.semantic)
            .dirty_len()
            .div_ceil(FLUSH_STEPS_PER_S);
        while left > 0 {
            let part = left.min(MIRRORS_PER_LOCK);
            let fired = lock(&self.core.semantic).flush_dirty_at_most(now, part);
            left -= part;
            self.emit_fired(fired);
        }
    }

    /// Once a second: the time-based rules.
    pub(crate) fn semantic_tick(&self, now: i64) {
        let fired = lock(&self.core.semantic).tick(now);
        self.emit_fired(fired);
    }

    /// A read-only view of the semantic model for SPARQL queries, taken without holding
    /// the model's lock while the query runs.
    pub fn semantic_snapshot(&self) -> QuerySnapshot {
        lock(&self.core.semantic).snapshot()
    }

    /// Runs a read-only SPARQL query over the semantic model, within `limits`.
    pub fn sparql(
        &self,
        query: &str,
        limits: &QueryLimits,
    ) -> Result<QueryResult, shoal_semantic::QueryError> {
        self.semantic_snapshot().query(query, limits)
    }
}
