//! Shoal's semantic core: the Common Information Model of the swarm, kept live in RDF.
//!
//! - [`SemanticStore`]: the ontology (`ontology/`) and the live model in an in-memory,
//!   integer-coded quad index of our own (`dataset`, the storage layer spareval leaves
//!   to its user): vehicles ([`SemanticStore::upsert_vehicle`]), their latest state
//!   ([`SemanticStore::update_state`] is cheap and typed; [`SemanticStore::flush_dirty`]
//!   mirrors it into RDF at a bounded rate per vehicle), tasks
//!   ([`SemanticStore::upsert_task`], [`SemanticStore::task_status`]), events,
//!   environment observations, and each vehicle's availability as the station's Vehicle
//!   Register decides it ([`SemanticStore::set_availability`]: the store mirrors it and
//!   never decides contact or availability by itself). Removed facts are freed at once,
//!   so the model stays the same size and speed under continuous updates.
//! - Semantic Reasoner ([`reasoner::TBox`]): RDFS-lite closure and capability inference
//!   from sensors, materialised per entity into graphs of derived facts when the model
//!   changes, never per telemetry update.
//! - Rules & Policies ([`RuleSpec`], [`Condition`]): user and built-in rules stored as
//!   data, indexed by what they watch, evaluated on insert (native fast path for
//!   thresholds and areas, SPARQL ASK/SELECT otherwise) and in [`SemanticStore::tick`]
//!   for time-driven ones; every firing is a [`shoal_model::Event`] handed back to the
//!   caller to publish and store.
//! - Semantic Query ([`SemanticStore::query`], [`QuerySnapshot`]): read-only SPARQL with
//!   [`QueryLimits`], parsed by `spargebra` and evaluated by `spareval` (Oxigraph's
//!   parser and evaluator); [`QueryResult`] serialises as SPARQL JSON/CSV/TSV/XML
//!   (`sparesults`). A trailing `ORDER BY` on projected variables is applied to the
//!   materialised rows, which is much cheaper than the evaluator's own sort.
//! - Export ([`SemanticStore::export`]) as N-Quads/TriG/Turtle/N-Triples, and the five
//!   standard queries ([`STANDARD_QUERIES`]) cross-checked against rdflib.
//! - [`synthetic`]: a deterministic synthetic fleet, for tests, the rdflib cross-check and
//!   `shoal bench semantic`.
//! - [`StoreConfig`]: the store's tuning, deserialisable from the station's TOML, checked
//!   by [`StoreConfig::check`].
//!
//! The crate is synchronous and runtime-free; the one thread it may start is the query
//! watchdog that cancels queries at their timeout. It is not `Sync`-shared by itself: the
//! station owns it behind its Data Access Manager (a `Mutex`/`RwLock` around it).

#![forbid(unsafe_code)]

mod config;
mod dataset;
mod error;
pub mod ontology;
mod order;
mod query;
pub mod reasoner;
mod rules;
mod store;
pub mod synthetic;
pub mod vocab;

pub use config::{ConfigError, StoreConfig};
pub use error::{QueryError, RuleError, StoreError};
pub use query::{QueryLimits, QueryResult, QuerySnapshot, ResultFormat};
pub use rules::{
    Comparison, Condition, MAX_RULE_ID_LEN, RuleInfo, RuleSpec, StateField, Threshold, builtin,
    outside,
};
/// A vehicle's availability, as the station's Vehicle Register decides it and
/// [`SemanticStore::set_availability`] mirrors it (re-exported from `shoal_model`).
pub use shoal_model::Availability;
/// A row of [`QueryResult::Solutions`].
pub use sparesults::QuerySolution;
pub use store::{Encounter, ExportFormat, ExportOptions, SemanticStore, StoreStats, TrafficTarget};

/// The five standard queries (name, SPARQL), from `ontology/queries/`; the cross-check
/// runs the same files with rdflib.
pub const STANDARD_QUERIES: [(&str, &str); 5] = [
    (
        "q1_idle_low_battery",
        include_str!("../../../ontology/queries/q1_idle_low_battery.rq"),
    ),
    (
        "q2_vehicles_in_box",
        include_str!("../../../ontology/queries/q2_vehicles_in_box.rq"),
    ),
    (
        "q3_tasks_by_state",
        include_str!("../../../ontology/queries/q3_tasks_by_state.rq"),
    ),
    (
        "q4_sidescan_capable",
        include_str!("../../../ontology/queries/q4_sidescan_capable.rq"),
    ),
    (
        "q5_running_tasks_low_battery",
        include_str!("../../../ontology/queries/q5_running_tasks_low_battery.rq"),
    ),
];
