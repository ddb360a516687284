//! [`SemanticStore`]: the live RDF model of the swarm, with typed latest state in front.
//!
//! Writes go through typed methods, never through SPARQL UPDATE. Each entity (a vehicle's
//! registration, its latest state, a task, an event, an observation) is written as a whole:
//! the store diffs its new facts, and the facts the reasoner derives from them, against
//! what the entity contributed before, and applies the difference within one `&mut self`
//! call, so a query never sees half an entity (queries borrow the store, or run on a
//! snapshot that a write never touches).
//!
//! Facts are reference-counted across entities and stored once, in the first graph of
//! ontology ([`crate::vocab::GRAPH_ONTOLOGY`]) > asserted model
//! ([`crate::vocab::GRAPH_MODEL`]) > derived ([`crate::vocab::GRAPH_INFERRED`]) that
//! holds them. SPARQL's union default graph (spareval's, as Oxigraph's) is a multiset, so
//! a triple stored in two graphs (a vehicle typed `shoal:Vehicle` by its class and by the
//! range of every task's `shoal:assignedTo`) would answer a query twice; the cross-check
//! with rdflib caught it.
//!
//! State vectors are the high-rate stream: [`SemanticStore::update_state`] only validates,
//! keeps the newest state in a typed map and runs the native rules; the RDF mirror is
//! refreshed by [`SemanticStore::flush_dirty`] at most once per
//! [`StoreConfig::min_state_interval_ms`] per vehicle, replacing only the values that
//! changed, outside the reference counting (nothing else states them).
//!
//! The quads live in [`Dataset`], an integer-coded hash index that `spareval` evaluates
//! SPARQL over (see [`crate::dataset`]). A removed quad is gone, together with any term
//! only it used, so an hour of state mirrors leaves the model as large and as fast as
//! it was (an earlier Oxigraph memory store kept every removed quad until a periodic
//! rebuild). The dataset sits behind an `Arc`: [`SemanticStore::snapshot`] shares it, and
//! a write while a snapshot is alive copies it first ([`StoreStats::snapshot_copies`]).

use std::collections::{HashMap, HashSet, VecDeque};
use std::io::Write;
use std::sync::Arc;
use std::time::{Duration, Instant};

use oxrdf::{GraphName, GraphNameRef, Literal, NamedNode, QuadRef, Triple};
use oxrdfio::{RdfFormat, RdfSerializer};
use shoal_model::{
    Availability, EnvironmentObservation, Event, EventKind, GeoPoint, LinkKind, MAX_VEHICLE_ID_LEN,
    Severity, StateVector, Task, TaskAssignment, TaskKind, TaskState, TaskStatus, Validate,
    ValidationError, VehicleAnnouncement, VehicleKind,
};
use spareval::{CancellationToken, QueryResults};

use crate::config::StoreConfig;
use crate::dataset::Dataset;
use crate::error::{RuleError, StoreError};
use crate::ontology::{self, Family, Vocabulary};
use crate::reasoner::TBox;
use crate::rules::{
    self, Compiled, Condition, RuleInfo, RuleSpec, Rules, StateField, Threshold, builtin,
};
use crate::vocab::{
    self, EntityKind, GEO, GEOSPARQL, ID, SOSA, date_time, double, event_iri, mission_iri,
    observation_iri, rule_iri, shoal, task_iri, vehicle_iri,
};

/// Counters describing the store, for metrics and tests.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct StoreStats {
    /// Quads (ontology, model, derived facts, rules).
    pub quads: usize,
    /// Distinct RDF terms the quads use (the dictionary holds no others).
    pub terms: usize,
    /// Writes that found a [`crate::QuerySnapshot`] alive and copied the model first.
    pub snapshot_copies: u64,
    /// Time spent in those copies.
    pub snapshot_copy_time: Duration,
    /// Vehicles known.
    pub vehicles: usize,
    /// Tasks known.
    pub tasks: usize,
    /// Events kept in the model.
    pub events: usize,
    /// State vectors accepted by `update_state`.
    pub states_accepted: u64,
    /// State vectors ignored because an equal or newer one was already held.
    pub states_stale: u64,
    /// State mirrors written to RDF by `flush_dirty`.
    pub state_flushes: u64,
    /// SPARQL rules disabled because an evaluation ran over `rule_budget_ms`.
    pub rules_over_budget: u64,
}

/// The ontology's individual of `shoal:Availability` naming `a`.
fn availability_iri(a: Availability) -> NamedNode {
    shoal(match a {
        Availability::Idle => "Idle",
        Availability::Busy => "Busy",
        Availability::Charging => "Charging",
        // `shoal:Fault` is the class of fault events; the availability is another term.
        Availability::Fault => "Faulty",
        Availability::Lost => "Lost",
    })
}

/// Typed latest state of one vehicle; `Copy` so the hot path never allocates.
#[derive(Debug, Clone, Copy, PartialEq)]
struct State {
    timestamp_ms: i64,
    values: [f64; 9],
}

impl State {
    fn of(s: &StateVector) -> Self {
        Self {
            timestamp_ms: s.timestamp_ms,
            values: StateField::ALL.map(|f| f.get(s)),
        }
    }
}

/// What the RDF model holds of a vehicle's state: the values of its last mirror.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Mirror {
    timestamp_ms: i64,
    values: [f64; 9],
}

#[derive(Debug)]
struct VehicleEntry {
    /// The vehicle's IRI, built once: every mirror writes ten quads about it.
    iri: NamedNode,
    announced: Option<VehicleKind>,
    latest: Option<State>,
    /// The state as last written to RDF; the next mirror replaces only what changed.
    mirror: Option<Mirror>,
    /// When the state graph was last written (the caller's clock), ms.
    last_flush_ms: Option<i64>,
    dirty: bool,
    /// A lost-contact rule fired for it since its last state: the next state re-arms
    /// those rules. A flag, so that `update_state` looks at the rules only then.
    silence_reported: bool,
    /// As the Vehicle Register last set it ([`SemanticStore::set_availability`]); the
    /// store never decides it.
    availability: Option<Availability>,
    /// The period lost-contact rules expect between two states, ms.
    expected_period_ms: i64,
}

#[derive(Debug)]
struct TaskEntry {
    assignment: TaskAssignment,
    state: TaskState,
    progress_pct: f64,
    message: String,
    state_changed_ms: i64,
    deadline_ms: i64,
}

fn state_code(s: TaskState) -> &'static str {
    match s {
        TaskState::Pending => "pending",
        TaskState::Sent => "sent",
        TaskState::Accepted => "accepted",
        TaskState::Running => "running",
        TaskState::Done => "done",
        TaskState::Failed => "failed",
        TaskState::Aborted => "aborted",
        TaskState::Expired => "expired",
    }
}

fn task_kind_code(k: TaskKind) -> &'static str {
    match k {
        TaskKind::GotoWaypoint => "goto_waypoint",
        TaskKind::SurveyArea => "survey_area",
        TaskKind::Hold => "hold",
        TaskKind::Surface => "surface",
        TaskKind::ReturnHome => "return_home",
        TaskKind::Abort => "abort",
        TaskKind::RequestState => "request_state",
        TaskKind::SetReportingRate => "set_reporting_rate",
    }
}

fn event_kind_code(k: EventKind) -> &'static str {
    match k {
        EventKind::LowBattery => "low_battery",
        EventKind::OutOfArea => "out_of_area",
        EventKind::CommLost => "comm_lost",
        EventKind::Fault => "fault",
        EventKind::Detection => "detection",
        EventKind::Task => "task",
        EventKind::Rule => "rule",
        EventKind::DataRejected => "data_rejected",
        _ => "other",
    }
}

fn severity_code(s: Severity) -> &'static str {
    match s {
        Severity::Info => "info",
        Severity::Warning => "warning",
        Severity::Alarm => "alarm",
        Severity::Critical => "critical",
    }
}

fn link_code(l: LinkKind) -> &'static str {
    match l {
        LinkKind::Ip => "ip",
        LinkKind::Acoustic => "acoustic",
        LinkKind::Radio => "radio",
        LinkKind::Satellite => "satellite",
        LinkKind::Tether => "tether",
    }
}

fn text(s: &str) -> Literal {
    Literal::new_simple_literal(s)
}

mod traffic;
pub use traffic::{Encounter, TrafficTarget};

/// Export options: which graphs, which format.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ExportOptions {
    /// Output format: a dataset format (N-Quads, TriG) keeps graphs; a graph format
    /// (Turtle, N-Triples) merges them.
    pub format: ExportFormat,
    /// Include the ontology graph (Shoal's ontology and the vendored vocabularies).
    pub include_ontology: bool,
    /// Include the graphs of derived facts.
    pub include_inferred: bool,
}

/// A format [`SemanticStore::export`] writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum ExportFormat {
    /// N-Quads: one quad per line, graphs kept.
    NQuads,
    /// TriG: Turtle with graphs.
    TriG,
    /// Turtle, all graphs merged.
    Turtle,
    /// N-Triples, all graphs merged.
    NTriples,
}

/// The live semantic model of the swarm: ontology, vehicles, tasks, events, observations,
/// derived facts and rules, in an in-memory [`Dataset`] queried with `spareval`.
pub struct SemanticStore {
    /// Shared with the snapshots taken since the last write (copy on write).
    pub(crate) data: Arc<Dataset>,
    pub(crate) config: StoreConfig,
    tbox: TBox,
    vocabulary: Vocabulary,
    vehicles: HashMap<String, VehicleEntry>,
    /// Vehicles with a state newer than their RDF mirror, each listed once, oldest first.
    dirty: VecDeque<String>,
    tasks: HashMap<String, TaskEntry>,
    events: VecDeque<String>,
    observations: HashSet<(String, String)>,
    /// AIS targets and vehicles' encounters with them (bounded by the traffic picture).
    traffic: traffic::TrafficEntries,
    pub(crate) rules: Rules,
    /// How many entities assert (per layer) each stored triple.
    counts: HashMap<Triple, [u32; 3]>,
    /// What each entity contributes: (layer of its assertions, asserted, derived).
    contributions: HashMap<(EntityKind, String), Contribution>,
    /// The RDF properties of the state fields, in [`StateField::ALL`] order, then `shoal:lastSeen`.
    state_properties: [NamedNode; 10],
    model_graph: GraphName,
    stats: StoreStats,
    pub(crate) watchdog: Arc<crate::query::Watchdog>,
}

impl std::fmt::Debug for SemanticStore {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SemanticStore")
            .field("config", &self.config)
            .field("vehicles", &self.vehicles.len())
            .field("tasks", &self.tasks.len())
            .field("data", &self.data)
            .finish_non_exhaustive()
    }
}

/// One entity's facts: the layer of its assertions, its asserted and its derived triples.
type Contribution = (Layer, HashSet<Triple>, HashSet<Triple>);

/// The changes one entity write made: the predicates whose triples changed.
type Changed = HashSet<NamedNode>;

impl SemanticStore {
    /// A store holding the ontology, the built-in rules and an empty swarm.
    pub fn new(config: StoreConfig) -> Result<Self, StoreError> {
        config.check()?;
        let (tbox, vocabulary, quads) = ontology::load()?;
        let mut s = Self {
            data: Arc::new(Dataset::new()),
            config,
            tbox,
            vocabulary,
            vehicles: HashMap::new(),
            dirty: VecDeque::new(),
            tasks: HashMap::new(),
            events: VecDeque::new(),
            observations: HashSet::new(),
            traffic: traffic::TrafficEntries::default(),
            rules: Rules::default(),
            counts: HashMap::new(),
            contributions: HashMap::new(),
            state_properties: std::array::from_fn(|i| {
                StateField::ALL
                    .get(i)
                    .map_or_else(|| shoal("lastSeen"), |f| f.property())
            }),
            model_graph: Layer::Model.graph(),
            stats: StoreStats::default(),
            watchdog: Arc::default(),
        };
        // The ontology's own closure (transitive sub-class edges, typed individuals).
        let triples: Vec<Triple> = quads.into_iter().map(Triple::from).collect();
        let mut derived = s.tbox.infer(&triples);
        derived.extend(s.tbox.schema_closure());
        s.set_entity(EntityKind::Ontology, "", Layer::Ontology, triples, derived)?;
        s.install_builtin_rules()?;
        Ok(s)
    }

    fn install_builtin_rules(&mut self) -> Result<(), StoreError> {
        let mut specs = vec![
            RuleSpec {
                id: builtin::LOW_BATTERY.into(),
                description: "Battery below the configured level".into(),
                severity: Severity::Warning,
                kind: EventKind::LowBattery,
                condition: Condition::Threshold(Threshold {
                    field: StateField::Battery,
                    op: rules::Comparison::Lt,
                    value: self.config.low_battery_pct,
                }),
            },
            RuleSpec {
                id: builtin::TASK_OVERDUE.into(),
                description: "Task still not finished after its deadline".into(),
                severity: Severity::Warning,
                kind: EventKind::Task,
                condition: Condition::TaskOverdue { grace_ms: 0 },
            },
        ];
        specs.push(traffic::collision_rule(&self.config));
        if !self.config.operating_area.is_empty() {
            specs.push(RuleSpec {
                id: builtin::OUT_OF_AREA.into(),
                description: "Vehicle outside the operating area".into(),
                severity: Severity::Alarm,
                kind: EventKind::OutOfArea,
                condition: Condition::OutsideArea {
                    polygon: self.config.operating_area.clone(),
                },
            });
        }
        for spec in specs {
            let info = RuleInfo {
                spec,
                enabled: true,
                built_in: true,
            };
            let rule_id = info.spec.id.clone();
            let compiled = rules::compile(info).map_err(|e| StoreError::BuiltinRule {
                rule_id,
                message: e.to_string(),
            })?;
            self.put_rule(compiled)?;
        }
        Ok(())
    }

    /// The configuration in force.
    pub fn config(&self) -> &StoreConfig {
        &self.config
    }

    /// SPARQL rules disabled so far because an evaluation ran over its time budget.
    pub fn rules_over_budget(&self) -> u64 {
        self.stats.rules_over_budget
    }

    /// Counters for metrics and tests.
    pub fn stats(&self) -> Result<StoreStats, StoreError> {
        Ok(StoreStats {
            quads: self.data.len(),
            terms: self.data.term_count(),
            vehicles: self.vehicles.len(),
            tasks: self.tasks.len(),
            events: self.events.len(),
            ..self.stats
        })
    }

    // ---------------------------------------------------------------------------------
    // Graph maintenance
    // ---------------------------------------------------------------------------------

    /// Makes `key`'s contribution exactly `asserted` (in `layer`) plus `derived`, applying
    /// the difference at once; returns the predicates whose stored triples changed.
    fn set_entity(
        &mut self,
        kind: EntityKind,
        key: &str,
        layer: Layer,
        asserted: Vec<Triple>,
        derived: Vec<Triple>,
    ) -> Result<Changed, StoreError> {
        let (_, old_asserted, old_derived) = self
            .contributions
            .remove(&(kind, key.to_owned()))
            .unwrap_or((layer, HashSet::new(), HashSet::new()));
        let new_asserted: HashSet<Triple> = asserted.into_iter().collect();
        let new_derived: HashSet<Triple> = derived.into_iter().collect();
        let mut changed = Changed::new();
        for (l, old, new) in [
            (layer, &old_asserted, &new_asserted),
            (Layer::Inferred, &old_derived, &new_derived),
        ] {
            let steps = old
                .difference(new)
                .map(|t| (t, -1))
                .chain(new.difference(old).map(|t| (t, 1)));
            for (t, delta) in steps {
                let counts = self.counts.entry(t.clone()).or_insert([0; 3]);
                let before = placement(counts);
                counts[l as usize] = counts[l as usize].saturating_add_signed(delta);
                let after = placement(counts);
                if after.is_none() {
                    self.counts.remove(t);
                }
                if before != after {
                    let data = writable(&mut self.data, &mut self.stats);
                    if let Some(b) = before {
                        data.remove(t.as_ref().in_graph(b.graph().as_ref()));
                    }
                    if let Some(a) = after {
                        data.insert(t.as_ref().in_graph(a.graph().as_ref()));
                    }
                    changed.insert(t.predicate.clone());
                }
            }
        }
        if !(new_asserted.is_empty() && new_derived.is_empty()) {
            self.contributions
                .insert((kind, key.to_owned()), (layer, new_asserted, new_derived));
        }
        Ok(changed)
    }

    /// Writes an entity's asserted facts and recomputes the facts derived from them.
    fn write_entity(
        &mut self,
        kind: EntityKind,
        key: &str,
        triples: Vec<Triple>,
    ) -> Result<Changed, StoreError> {
        let derived = self.tbox.infer(&triples);
        self.set_entity(kind, key, Layer::Model, triples, derived)
    }

    fn drop_entity(&mut self, kind: EntityKind, key: &str) -> Result<(), StoreError> {
        self.set_entity(kind, key, Layer::Model, Vec::new(), Vec::new())?;
        Ok(())
    }

    // ---------------------------------------------------------------------------------
    // Vehicles and state
    // ---------------------------------------------------------------------------------

    fn ensure_vehicle(&mut self, vehicle_id: &str) -> Result<(), StoreError> {
        if self.vehicles.contains_key(vehicle_id) {
            return Ok(());
        }
        self.vehicles.insert(
            vehicle_id.to_owned(),
            VehicleEntry {
                iri: vehicle_iri(vehicle_id),
                announced: None,
                latest: None,
                mirror: None,
                last_flush_ms: None,
                dirty: false,
                silence_reported: false,
                availability: None,
                expected_period_ms: self.config.expected_state_period_ms,
            },
        );
        // A vehicle heard of before its announcement: known to exist, type unknown.
        let v = vehicle_iri(vehicle_id);
        let triples = vec![
            Triple::new(v.clone(), vocab::rdf_type(), shoal("Vehicle")),
            Triple::new(v, shoal("vehicleId"), text(vehicle_id)),
        ];
        // No availability yet: the Vehicle Register sets it when it registers the vehicle.
        self.write_entity(EntityKind::Vehicle, vehicle_id, triples)?;
        Ok(())
    }

    /// Registers or updates a vehicle from its announcement (Vehicle and Service Register).
    pub fn upsert_vehicle(&mut self, a: &VehicleAnnouncement) -> Result<Vec<Event>, StoreError> {
        a.validate()
            .map_err(StoreError::invalid("vehicle announcement"))?;
        self.ensure_vehicle(&a.vehicle_id)?;
        if let Some(e) = self.vehicles.get_mut(&a.vehicle_id) {
            e.announced = Some(a.kind);
        }
        let v = vehicle_iri(&a.vehicle_id);
        let class = self
            .vocabulary
            .lookup(Family::VehicleClass, a.kind.as_str())
            .cloned()
            .unwrap_or_else(|| shoal("Vehicle"));
        let mut t = vec![
            Triple::new(v.clone(), vocab::rdf_type(), class),
            Triple::new(v.clone(), shoal("vehicleId"), text(&a.vehicle_id)),
            Triple::new(v.clone(), shoal("name"), text(&a.name)),
            Triple::new(v.clone(), shoal("vendor"), text(&a.vendor)),
            Triple::new(v.clone(), shoal("maxSpeed"), double(a.max_speed_mps)),
            Triple::new(v.clone(), shoal("registeredAt"), date_time(a.timestamp_ms)),
        ];
        for code in &a.sensors {
            let s = vocab::iri(format!("{}/sensor/{code}", v.as_str()));
            let class = self
                .vocabulary
                .lookup(Family::SensorClass, code)
                .cloned()
                .unwrap_or_else(|| shoal("Sensor"));
            t.push(Triple::new(v.clone(), vocab::ns(SOSA, "hosts"), s.clone()));
            t.push(Triple::new(
                s.clone(),
                vocab::ns(SOSA, "isHostedBy"),
                v.clone(),
            ));
            t.push(Triple::new(s.clone(), vocab::rdf_type(), class));
            t.push(Triple::new(s, shoal("sensorCode"), text(code)));
        }
        for code in &a.capabilities {
            let cap = match self.vocabulary.lookup(Family::Capability, code) {
                Some(c) => c.clone(),
                None => {
                    // An capability the ontology does not know yet: still queryable by code.
                    let c = vocab::iri(format!("{ID}capability/{code}"));
                    t.push(Triple::new(c.clone(), shoal("code"), text(code)));
                    c
                }
            };
            t.push(Triple::new(v.clone(), shoal("declaresCapability"), cap));
        }
        for link in &a.links {
            let l = vocab::iri(format!("{}/link/{}", v.as_str(), link_code(*link)));
            let class = self
                .vocabulary
                .lookup(Family::LinkClass, link_code(*link))
                .cloned()
                .unwrap_or_else(|| shoal("CommunicationLink"));
            t.push(Triple::new(v.clone(), shoal("hasLink"), l.clone()));
            t.push(Triple::new(l, vocab::rdf_type(), class));
        }
        let changed = self.write_entity(EntityKind::Vehicle, &a.vehicle_id, t)?;
        let events = self.run_sparql_rules(&v, &a.vehicle_id, "", a.timestamp_ms, &changed)?;
        Ok(events)
    }

    /// Sets the reporting period lost-contact rules expect from a vehicle, ms.
    pub fn set_expected_period(&mut self, vehicle_id: &str, period_ms: i64) {
        if let Some(e) = self.vehicles.get_mut(vehicle_id) {
            e.expected_period_ms = period_ms.max(1);
        }
    }

    /// Takes a state vector: keeps it as the vehicle's latest (if newer), runs the native
    /// rules and marks the vehicle for the next [`Self::flush_dirty`]. Never touches RDF.
    pub fn update_state(&mut self, s: &StateVector) -> Result<Vec<Event>, StoreError> {
        s.validate().map_err(StoreError::invalid("state vector"))?;
        if !self.vehicles.contains_key(&s.vehicle_id) {
            self.ensure_vehicle(&s.vehicle_id)?;
        }
        let Some(entry) = self.vehicles.get_mut(&s.vehicle_id) else {
            return Ok(Vec::new());
        };
        let new = State::of(s);
        let previous = entry.latest;
        if previous.is_some_and(|p| p.timestamp_ms >= new.timestamp_ms) {
            // Out of order (acoustic retransmission, replay): the newest state wins.
            self.stats.states_stale += 1;
            return Ok(Vec::new());
        }
        self.stats.states_accepted += 1;
        entry.latest = Some(new);
        let regained = std::mem::take(&mut entry.silence_reported);
        if !entry.dirty {
            entry.dirty = true;
            self.dirty.push_back(s.vehicle_id.clone());
        }
        let mut events = Vec::new();
        // Fast path: only rules watching a field that changed run.
        for field in StateField::ALL {
            let i = field.index();
            if previous.is_some_and(|p| p.values[i] == new.values[i]) {
                continue;
            }
            for k in 0..self.rules.by_field[i].len() {
                let rule = Arc::clone(&self.rules.by_field[i][k]);
                if let Condition::Threshold(t) = &rule.info.spec.condition
                    && self.rules.edge(&s.vehicle_id, &rule.id, t.holds(s))
                {
                    let msg = format!("{} = {} {}", field.name(), field.get(s), t);
                    events.push(
                        self.rules
                            .event(&rule, s.timestamp_ms, &s.vehicle_id, "", &msg),
                    );
                }
            }
        }
        let moved =
            previous.is_none_or(|p| p.values[0] != new.values[0] || p.values[1] != new.values[1]);
        if moved {
            for k in 0..self.rules.area.len() {
                let rule = Arc::clone(&self.rules.area[k]);
                if let Condition::OutsideArea { polygon } = &rule.info.spec.condition {
                    let out = rules::outside(polygon, s.latitude_deg, s.longitude_deg);
                    if self.rules.edge(&s.vehicle_id, &rule.id, out) {
                        let msg = format!(
                            "position {:.6}, {:.6} is outside the operating area",
                            s.latitude_deg, s.longitude_deg
                        );
                        events.push(self.rules.event(
                            &rule,
                            s.timestamp_ms,
                            &s.vehicle_id,
                            "",
                            &msg,
                        ));
                    }
                }
            }
        }
        if regained {
            // Heard from again: each lost-contact rule may fire again at the next silence.
            // Availability is left alone: contact is the Vehicle Register's to decide.
            for k in 0..self.rules.lost_contact.len() {
                let id = Arc::clone(&self.rules.lost_contact[k].id);
                self.rules.edge(&s.vehicle_id, &id, false);
            }
        }
        Ok(events)
    }

    /// Mirrors into RDF the latest state of every dirty vehicle whose last mirror is at
    /// least `min_state_interval_ms` old at `now_ms`; runs the SPARQL rules watching state
    /// properties for those vehicles.
    ///
    /// This is the model's only high-rate write, so it skips the generic entity
    /// bookkeeping: a vehicle's state properties are stated by nothing else (other
    /// entities use `geo:lat` and `shoal:depth` on their own subjects), so they need no
    /// reference counts, and the previous mirror, kept typed, says exactly which quads to
    /// replace. All due vehicles are written in this one call (see
    /// [`Self::flush_dirty_at_most`] to spread them). No inference either: the state's
    /// only entailments are `shoal:stateProperty` copies of each value, which no query
    /// needs and which would double the churn.
    pub fn flush_dirty(&mut self, now_ms: i64) -> Result<Vec<Event>, StoreError> {
        self.flush_dirty_at_most(now_ms, usize::MAX)
    }

    /// Vehicles waiting in the dirty list (each listed once).
    pub fn dirty_len(&self) -> usize {
        self.dirty.len()
    }

    /// [`Self::flush_dirty`] for at most `max` entries of the dirty list, oldest first, so
    /// that a caller sharing the store behind a lock can release it between parts: a
    /// thousand mirrors at once hold it for tens of milliseconds, which every state vector
    /// arriving meanwhile would wait for. Entries not yet due go to the back of the list,
    /// so a caller that visits [`Self::dirty_len`] entries in parts visits each once.
    pub fn flush_dirty_at_most(
        &mut self,
        now_ms: i64,
        max: usize,
    ) -> Result<Vec<Event>, StoreError> {
        let interval = self.config.min_state_interval_ms;
        let mut keep = Vec::new();
        let mut flushed: Vec<(String, Changed, i64)> = Vec::new();
        let watched = !self.rules.by_property.is_empty();
        let part: Vec<String> = self.dirty.drain(..max.min(self.dirty.len())).collect();
        for id in part {
            let Some(e) = self.vehicles.get_mut(&id) else {
                continue;
            };
            if e.last_flush_ms.is_some_and(|t| now_ms - t < interval) {
                keep.push(id);
                continue;
            }
            e.dirty = false;
            let Some(state) = e.latest else { continue };
            e.last_flush_ms = Some(now_ms);
            let new = Mirror {
                timestamp_ms: state.timestamp_ms,
                values: state.values,
            };
            let old = e.mirror.replace(new);
            let mut changed = Changed::new();
            for (i, property) in self.state_properties.iter().enumerate() {
                let (before, after) = match StateField::ALL.get(i) {
                    Some(field) => {
                        let stored = |v: f64| {
                            // An unknown altitude is left out rather than stated as -1.
                            (*field != StateField::Altitude || v != shoal_model::UNKNOWN)
                                .then(|| double(v))
                        };
                        // Bitwise: 0.0 and -0.0 are equal but are different literals.
                        if old.is_some_and(|o| o.values[i].to_bits() == new.values[i].to_bits()) {
                            continue;
                        }
                        (old.and_then(|o| stored(o.values[i])), stored(new.values[i]))
                    }
                    None => {
                        if old.is_some_and(|o| o.timestamp_ms == new.timestamp_ms) {
                            continue;
                        }
                        (
                            old.map(|o| date_time(o.timestamp_ms)),
                            Some(date_time(new.timestamp_ms)),
                        )
                    }
                };
                let graph = self.model_graph.as_ref();
                let data = writable(&mut self.data, &mut self.stats);
                if let Some(b) = &before {
                    data.remove(QuadRef::new(&e.iri, property, b, graph));
                }
                if let Some(a) = &after {
                    data.insert(QuadRef::new(&e.iri, property, a, graph));
                }
                if watched && before != after {
                    changed.insert(property.clone());
                }
            }
            flushed.push((id, changed, state.timestamp_ms));
        }
        self.stats.state_flushes += flushed.len() as u64;
        self.dirty.extend(keep);
        let mut events = Vec::new();
        for (id, changed, ts) in flushed {
            if changed.is_empty() {
                continue;
            }
            let Some(v) = self.vehicles.get(&id).map(|e| e.iri.clone()) else {
                continue;
            };
            events.extend(self.run_sparql_rules(&v, &id, "", ts, &changed)?);
        }
        Ok(events)
    }

    /// The latest state held for a vehicle (typed; may be newer than its RDF mirror).
    pub fn latest_state(&self, vehicle_id: &str) -> Option<StateVector> {
        let s = self.vehicles.get(vehicle_id)?.latest?;
        let v = s.values;
        Some(StateVector {
            vehicle_id: vehicle_id.to_owned(),
            timestamp_ms: s.timestamp_ms,
            latitude_deg: v[0],
            longitude_deg: v[1],
            depth_m: v[2],
            altitude_m: v[3],
            speed_mps: v[4],
            yaw_deg: v[5],
            pitch_deg: v[6],
            roll_deg: v[7],
            battery_pct: v[8],
        })
    }

    /// A vehicle's availability, as last set by [`Self::set_availability`]; `None` for a
    /// vehicle whose availability was never set.
    pub fn availability(&self, vehicle_id: &str) -> Option<Availability> {
        self.vehicles.get(vehicle_id)?.availability
    }

    /// Mirrors a vehicle's availability, as the station's Vehicle Register decided it, into
    /// `shoal:availability`; creates the vehicle if it is not known yet.
    ///
    /// The register is the one owner of contact and availability (it weighs contact,
    /// faults, tasks and charging); the store only mirrors what it is told, so the model
    /// and the register cannot disagree. Writes only when the value changed, in the
    /// vehicle's own small availability graph. Runs no rules: it has no events to hand
    /// back, and contact loss is the register's own CommLost alarm.
    pub fn set_availability(
        &mut self,
        vehicle_id: &str,
        availability: Availability,
    ) -> Result<(), StoreError> {
        if !self.vehicles.contains_key(vehicle_id)
            && !shoal_model::is_identifier(vehicle_id, MAX_VEHICLE_ID_LEN)
        {
            // The id becomes an IRI: the rule every datum's vehicle_id follows applies here.
            return Err(StoreError::Invalid {
                what: "vehicle id",
                source: ValidationError::BadText {
                    field: "vehicle_id",
                    rule: "must be 1..=32 of letters, digits, '_', '-' and '.'",
                },
            });
        }
        self.ensure_vehicle(vehicle_id)?;
        let Some(e) = self.vehicles.get_mut(vehicle_id) else {
            return Ok(());
        };
        if e.availability == Some(availability) {
            return Ok(());
        }
        e.availability = Some(availability);
        let t = vec![Triple::new(
            e.iri.clone(),
            shoal("availability"),
            availability_iri(availability),
        )];
        // Its own small graph: availability changes with tasks and contact, not telemetry,
        // and rewriting it must not touch the vehicle's registration facts.
        self.set_entity(
            EntityKind::Availability,
            vehicle_id,
            Layer::Model,
            t,
            Vec::new(),
        )?;
        Ok(())
    }

    // ---------------------------------------------------------------------------------
    // Tasks
    // ---------------------------------------------------------------------------------

    /// Registers or replaces a task assignment (Mission and Task Register); a new task is
    /// `pending`, a replaced one keeps its state.
    pub fn upsert_task(&mut self, a: &TaskAssignment) -> Result<Vec<Event>, StoreError> {
        let task = a.task().map_err(StoreError::invalid("task assignment"))?;
        self.ensure_vehicle(&a.vehicle_id)?;
        let mut deadline_ms = a.issued_ms.saturating_add(self.config.task_deadline_ms);
        if let Task::Hold { duration_s } = task {
            deadline_ms = deadline_ms.saturating_add((duration_s * 1000.0) as i64);
        }
        if let Task::SetReportingRate { rate_hz } = task {
            // Lost-contact rules should expect the new period from now on.
            self.set_expected_period(&a.vehicle_id, (1000.0 / rate_hz).ceil() as i64);
        }
        let previous = self.tasks.remove(&a.task_id);
        let (state, progress, message, changed_ms) = match &previous {
            Some(p) => (
                p.state,
                p.progress_pct,
                p.message.clone(),
                p.state_changed_ms,
            ),
            None => (TaskState::Pending, 0.0, String::new(), a.issued_ms),
        };
        self.tasks.insert(
            a.task_id.clone(),
            TaskEntry {
                assignment: a.clone(),
                state,
                progress_pct: progress,
                message,
                state_changed_ms: changed_ms,
                deadline_ms,
            },
        );
        let ts = a.issued_ms;
        self.write_task(&a.task_id, ts)
    }

    /// Applies a vehicle's report on a task (Tasks Reporter); a final state is never left.
    pub fn task_status(&mut self, s: &TaskStatus) -> Result<Vec<Event>, StoreError> {
        s.validate().map_err(StoreError::invalid("task status"))?;
        let Some(entry) = self.tasks.get_mut(&s.task_id) else {
            return Err(StoreError::UnknownTask {
                task_id: s.task_id.clone(),
            });
        };
        if entry.assignment.vehicle_id != s.vehicle_id {
            return Err(StoreError::WrongVehicle {
                task_id: s.task_id.clone(),
                assigned: entry.assignment.vehicle_id.clone(),
                reporter: s.vehicle_id.clone(),
            });
        }
        if entry.state.is_final() && entry.state != s.state {
            tracing::debug!(task = %s.task_id, from = state_code(entry.state), to = state_code(s.state), "transition out of a final state ignored");
            return Ok(Vec::new());
        }
        entry.state = s.state;
        entry.progress_pct = s.progress_pct;
        entry.message.clone_from(&s.message);
        entry.state_changed_ms = s.timestamp_ms;
        self.write_task(&s.task_id, s.timestamp_ms)
    }

    fn write_task(&mut self, task_id: &str, ts: i64) -> Result<Vec<Event>, StoreError> {
        let Some(e) = self.tasks.get(task_id) else {
            return Ok(Vec::new());
        };
        let a = &e.assignment;
        let t_iri = task_iri(task_id);
        let class = self
            .vocabulary
            .lookup(Family::TaskClass, task_kind_code(a.kind))
            .cloned()
            .unwrap_or_else(|| shoal("Task"));
        let state = self
            .vocabulary
            .lookup(Family::TaskState, state_code(e.state))
            .cloned()
            .unwrap_or_else(|| shoal("Pending"));
        let mut t = vec![
            Triple::new(t_iri.clone(), vocab::rdf_type(), class),
            Triple::new(t_iri.clone(), shoal("taskId"), text(task_id)),
            Triple::new(
                t_iri.clone(),
                shoal("assignedTo"),
                vehicle_iri(&a.vehicle_id),
            ),
            Triple::new(t_iri.clone(), shoal("issuedAt"), date_time(a.issued_ms)),
            Triple::new(t_iri.clone(), shoal("deadline"), date_time(e.deadline_ms)),
            Triple::new(t_iri.clone(), shoal("hasState"), state),
            Triple::new(t_iri.clone(), shoal("progress"), double(e.progress_pct)),
            Triple::new(
                t_iri.clone(),
                shoal("stateChangedAt"),
                date_time(e.state_changed_ms),
            ),
        ];
        if !e.message.is_empty() {
            t.push(Triple::new(
                t_iri.clone(),
                shoal("statusMessage"),
                text(&e.message),
            ));
        }
        if !a.mission_id.is_empty() {
            let m = mission_iri(&a.mission_id);
            t.push(Triple::new(
                m.clone(),
                shoal("missionId"),
                text(&a.mission_id),
            ));
            t.push(Triple::new(m.clone(), shoal("hasTask"), t_iri.clone()));
            t.push(Triple::new(t_iri.clone(), shoal("partOfMission"), m));
        }
        let moves = matches!(a.kind, TaskKind::GotoWaypoint | TaskKind::SurveyArea);
        if moves {
            if a.depth_m != shoal_model::UNKNOWN {
                t.push(Triple::new(
                    t_iri.clone(),
                    shoal("targetDepth"),
                    double(a.depth_m),
                ));
            }
            if a.altitude_m != shoal_model::UNKNOWN {
                t.push(Triple::new(
                    t_iri.clone(),
                    shoal("targetAltitude"),
                    double(a.altitude_m),
                ));
            }
            t.push(Triple::new(
                t_iri.clone(),
                shoal("targetSpeed"),
                double(a.speed_mps),
            ));
        }
        match a.kind {
            TaskKind::GotoWaypoint => {
                for (i, p) in a.area.iter().enumerate() {
                    let wp = vocab::iri(format!("{}/waypoint/{i}", t_iri.as_str()));
                    t.push(Triple::new(t_iri.clone(), shoal("hasWaypoint"), wp.clone()));
                    t.push(Triple::new(
                        wp.clone(),
                        vocab::rdf_type(),
                        shoal("Waypoint"),
                    ));
                    t.push(Triple::new(
                        wp.clone(),
                        vocab::ns(GEO, "lat"),
                        double(p.latitude_deg),
                    ));
                    t.push(Triple::new(
                        wp.clone(),
                        vocab::ns(GEO, "long"),
                        double(p.longitude_deg),
                    ));
                    t.push(Triple::new(wp, shoal("sequence"), Literal::from(i as i64)));
                }
            }
            TaskKind::SurveyArea => {
                let area = vocab::iri(format!("{}/area", t_iri.as_str()));
                let wkt = wkt_polygon(&a.area);
                t.push(Triple::new(t_iri.clone(), shoal("hasArea"), area.clone()));
                t.push(Triple::new(area.clone(), vocab::rdf_type(), shoal("Area")));
                t.push(Triple::new(
                    area,
                    vocab::ns(GEOSPARQL, "asWKT"),
                    Literal::new_typed_literal(wkt, vocab::ns(GEOSPARQL, "wktLiteral")),
                ));
                t.push(Triple::new(
                    t_iri.clone(),
                    shoal("lineSpacing"),
                    double(a.line_spacing_m),
                ));
            }
            TaskKind::Hold => t.push(Triple::new(
                t_iri.clone(),
                shoal("duration"),
                double(a.duration_s),
            )),
            TaskKind::SetReportingRate => {
                t.push(Triple::new(t_iri.clone(), shoal("rate"), double(a.rate_hz)));
            }
            _ => {}
        }
        let vehicle_id = a.vehicle_id.clone();
        let changed = self.write_entity(EntityKind::Task, task_id, t)?;
        let events = self.run_sparql_rules(&t_iri, &vehicle_id, task_id, ts, &changed)?;
        Ok(events)
    }

    /// Forgets a task (its triples and its rules' memory of it), e.g. once the station's
    /// retention has passed; returns whether it was known. Its mission's triples go with
    /// its last task.
    pub fn forget_task(&mut self, task_id: &str) -> Result<bool, StoreError> {
        if self.tasks.remove(task_id).is_none() {
            return Ok(false);
        }
        self.drop_entity(EntityKind::Task, task_id)?;
        self.rules.forget(task_iri(task_id).as_str());
        Ok(true)
    }

    /// How many tasks the model holds.
    pub fn task_count(&self) -> usize {
        self.tasks.len()
    }

    /// The state of a task, if known.
    pub fn task_state(&self, task_id: &str) -> Option<TaskState> {
        self.tasks.get(task_id).map(|t| t.state)
    }

    // ---------------------------------------------------------------------------------
    // Events and observations
    // ---------------------------------------------------------------------------------

    /// Adds an event to the model (keeping the newest [`StoreConfig::max_events`]).
    pub fn add_event(&mut self, ev: &Event) -> Result<Vec<Event>, StoreError> {
        ev.validate().map_err(StoreError::invalid("event"))?;
        let e = event_iri(&ev.event_id);
        let class = self
            .vocabulary
            .lookup(Family::EventClass, event_kind_code(ev.kind))
            .cloned()
            .unwrap_or_else(|| shoal("Event"));
        let severity = self
            .vocabulary
            .lookup(Family::Severity, severity_code(ev.severity))
            .cloned()
            .unwrap_or_else(|| shoal("Info"));
        let mut t = vec![
            Triple::new(e.clone(), vocab::rdf_type(), class),
            Triple::new(e.clone(), shoal("eventId"), text(&ev.event_id)),
            Triple::new(e.clone(), shoal("severity"), severity),
            Triple::new(e.clone(), shoal("occurredAt"), date_time(ev.timestamp_ms)),
            Triple::new(e.clone(), shoal("text"), text(&ev.text)),
        ];
        if !ev.vehicle_id.is_empty() {
            t.push(Triple::new(
                e.clone(),
                shoal("concernsVehicle"),
                vehicle_iri(&ev.vehicle_id),
            ));
        }
        if !ev.task_id.is_empty() {
            t.push(Triple::new(
                e.clone(),
                shoal("concernsTask"),
                task_iri(&ev.task_id),
            ));
        }
        if let Some(rule_id) = ev.event_id.rsplitn(3, '-').nth(2)
            && self.rules.get(rule_id).is_some()
        {
            t.push(Triple::new(e.clone(), shoal("firedBy"), rule_iri(rule_id)));
        }
        let is_new = !self
            .contributions
            .contains_key(&(EntityKind::Event, ev.event_id.clone()));
        let changed = self.write_entity(EntityKind::Event, &ev.event_id, t)?;
        if is_new {
            self.events.push_back(ev.event_id.clone());
        }
        while self.events.len() > self.config.max_events {
            if let Some(old) = self.events.pop_front() {
                self.drop_entity(EntityKind::Event, &old)?;
                self.rules.forget(event_iri(&old).as_str());
            }
        }
        let events =
            self.run_sparql_rules(&e, &ev.vehicle_id, &ev.task_id, ev.timestamp_ms, &changed)?;
        Ok(events)
    }

    /// Keeps the latest observation of each (vehicle, property) as a `sosa:Observation`.
    pub fn add_observation(
        &mut self,
        o: &EnvironmentObservation,
    ) -> Result<Vec<Event>, StoreError> {
        o.validate()
            .map_err(StoreError::invalid("environment observation"))?;
        self.ensure_vehicle(&o.vehicle_id)?;
        let obs = observation_iri(&o.vehicle_id, &o.property);
        let property = shoal(&o.property);
        let t = vec![
            Triple::new(
                obs.clone(),
                vocab::rdf_type(),
                shoal("EnvironmentObservation"),
            ),
            Triple::new(
                obs.clone(),
                vocab::ns(SOSA, "observedProperty"),
                property.clone(),
            ),
            Triple::new(property, vocab::rdf_type(), shoal("EnvironmentProperty")),
            Triple::new(
                obs.clone(),
                vocab::ns(SOSA, "hasFeatureOfInterest"),
                shoal("SeaWater"),
            ),
            Triple::new(
                obs.clone(),
                vocab::ns(SOSA, "hasSimpleResult"),
                double(o.value),
            ),
            Triple::new(obs.clone(), shoal("unit"), text(&o.unit)),
            Triple::new(
                obs.clone(),
                vocab::ns(SOSA, "resultTime"),
                date_time(o.timestamp_ms),
            ),
            Triple::new(
                obs.clone(),
                shoal("observedByVehicle"),
                vehicle_iri(&o.vehicle_id),
            ),
            Triple::new(obs.clone(), vocab::ns(GEO, "lat"), double(o.latitude_deg)),
            Triple::new(obs.clone(), vocab::ns(GEO, "long"), double(o.longitude_deg)),
            Triple::new(obs.clone(), shoal("depth"), double(o.depth_m)),
        ];
        let key = format!("{}/{}", o.vehicle_id, o.property);
        let changed = self.write_entity(EntityKind::Observation, &key, t)?;
        self.observations
            .insert((o.vehicle_id.clone(), o.property.clone()));
        let events = self.run_sparql_rules(&obs, &o.vehicle_id, "", o.timestamp_ms, &changed)?;
        Ok(events)
    }

    // ---------------------------------------------------------------------------------
    // Rules
    // ---------------------------------------------------------------------------------

    /// Time-driven rules, evaluated at `now_ms`: task overdue, and the lost-contact rules
    /// operators created. A lost-contact rule raises its event once per silence (a newer
    /// state re-arms it) and does nothing else: contact and availability are the Vehicle
    /// Register's, which raises its own CommLost alarm.
    pub fn tick(&mut self, now_ms: i64) -> Result<Vec<Event>, StoreError> {
        let mut events = Vec::new();
        let lost_rules = self.rules.lost_contact.clone();
        let mut newly_lost = Vec::new();
        for rule in &lost_rules {
            let Condition::LostContact { factor } = rule.info.spec.condition else {
                continue;
            };
            for (id, e) in &self.vehicles {
                let Some(s) = e.latest else { continue };
                let silent = now_ms - s.timestamp_ms;
                let limit = factor * e.expected_period_ms as f64;
                if (silent as f64) > limit && !self.rules.is_active(id, &rule.id) {
                    newly_lost.push((Arc::clone(rule), id.clone(), silent));
                }
            }
        }
        for (rule, id, silent) in newly_lost {
            self.rules.edge(&id, &rule.id, true);
            let msg = format!("no state vector for {:.1} s", silent as f64 / 1000.0);
            events.push(self.rules.event(&rule, now_ms, &id, "", &msg));
            if let Some(e) = self.vehicles.get_mut(&id) {
                e.silence_reported = true;
            }
        }
        let overdue_rules = self.rules.overdue.clone();
        let mut fired = Vec::new();
        for rule in &overdue_rules {
            let Condition::TaskOverdue { grace_ms } = rule.info.spec.condition else {
                continue;
            };
            for (id, t) in &self.tasks {
                let late = !t.state.is_final() && now_ms > t.deadline_ms.saturating_add(grace_ms);
                let key = task_iri(id);
                if late && !self.rules.is_active(key.as_str(), &rule.id) {
                    fired.push((
                        Arc::clone(rule),
                        key,
                        id.clone(),
                        t.assignment.vehicle_id.clone(),
                        now_ms - t.deadline_ms,
                    ));
                } else if !late {
                    self.rules.edge(key.as_str(), &rule.id, false);
                }
            }
        }
        for (rule, key, task_id, vehicle_id, late_ms) in fired {
            self.rules.edge(key.as_str(), &rule.id, true);
            let msg = format!(
                "task {task_id} is {:.0} s past its deadline",
                late_ms as f64 / 1000.0
            );
            events.push(self.rules.event(&rule, now_ms, &vehicle_id, &task_id, &msg));
        }
        Ok(events)
    }

    /// Runs the enabled SPARQL rules watching one of `changed`, with `?this` = `entity`.
    fn run_sparql_rules(
        &mut self,
        entity: &NamedNode,
        vehicle_id: &str,
        task_id: &str,
        ts: i64,
        changed: &Changed,
    ) -> Result<Vec<Event>, StoreError> {
        if self.rules.by_property.is_empty() || changed.is_empty() {
            return Ok(Vec::new());
        }
        let mut candidates: Vec<Arc<Compiled>> = Vec::new();
        for p in changed {
            for r in self.rules.by_property.get(p.as_str()).into_iter().flatten() {
                if !candidates.iter().any(|c| Arc::ptr_eq(c, r)) {
                    candidates.push(Arc::clone(r));
                }
            }
        }
        let mut events = Vec::new();
        let budget = Duration::from_millis(self.config.rule_budget_ms);
        let mut over_budget: Vec<(Arc<Compiled>, Duration)> = Vec::new();
        for rule in candidates {
            let Some(prepared) = &rule.prepared else {
                continue;
            };
            let token = CancellationToken::new();
            let started = Instant::now();
            self.watchdog.watch(started + budget, token.clone());
            let result =
                crate::query::evaluate(prepared, &self.data, token, Some(entity.clone().into()));
            let evaluated = result.and_then(|r| match r {
                QueryResults::Boolean(b) => Ok((b, String::new())),
                QueryResults::Solutions(mut rows) => match rows.next().transpose()? {
                    None => Ok((false, String::new())),
                    Some(row) => Ok((
                        true,
                        row.iter()
                            .map(|(v, t)| format!("{}={t}", v.as_str()))
                            .collect::<Vec<_>>()
                            .join(", "),
                    )),
                },
                QueryResults::Graph(_) => Ok((false, String::new())),
            });
            let took = started.elapsed();
            if took > budget {
                over_budget.push((Arc::clone(&rule), took));
                continue;
            }
            let (holds, detail) = match evaluated {
                Ok(r) => r,
                Err(e) => {
                    // A failing user rule must not fail the insert that triggered it: the
                    // datum is already stored, and the other rules still run.
                    tracing::warn!(rule = %rule.id, error = %e, "rule evaluation failed");
                    continue;
                }
            };
            if self.rules.edge(entity.as_str(), &rule.id, holds) {
                let mut msg = format!(
                    "{} matched {}",
                    rule.info.spec.description,
                    entity.as_str().trim_start_matches(ID)
                );
                if !detail.is_empty() {
                    msg.push_str(": ");
                    msg.push_str(&detail);
                }
                events.push(self.rules.event(&rule, ts, vehicle_id, task_id, &msg));
            }
        }
        for (rule, took) in over_budget {
            // Disabled in the model, which every later insert sees; the operator turns it
            // back on (after fixing it) through the rules API.
            tracing::warn!(rule = %rule.id, took_ms = took.as_millis(), budget_ms = budget.as_millis(), "rule over its time budget disabled");
            self.stats.rules_over_budget += 1;
            if let Err(e) = self.set_rule_enabled(&rule.id, false) {
                tracing::warn!(rule = %rule.id, error = %e, "rule over budget could not be disabled");
            }
            let msg = format!(
                "rule disabled: one evaluation took {} ms, over the budget of {} ms",
                took.as_millis(),
                budget.as_millis()
            );
            let mut e = self.rules.event(&rule, ts, vehicle_id, task_id, &msg);
            e.severity = Severity::Warning;
            e.kind = EventKind::Other;
            events.push(e);
        }
        Ok(events)
    }

    fn put_rule(&mut self, compiled: Compiled) -> Result<(), StoreError> {
        let r = rule_iri(&compiled.info.spec.id);
        let spec = &compiled.info.spec;
        let class = match &spec.condition {
            Condition::Threshold(_) => "ThresholdRule",
            Condition::OutsideArea { .. } => "AreaRule",
            Condition::LostContact { .. } => "LostContactRule",
            Condition::TaskOverdue { .. } => "TaskOverdueRule",
            Condition::Sparql { .. } => "SparqlRule",
            #[allow(unreachable_patterns)]
            _ => "Rule",
        };
        let mut t = vec![
            Triple::new(r.clone(), vocab::rdf_type(), shoal(class)),
            Triple::new(r.clone(), shoal("ruleId"), text(&spec.id)),
            Triple::new(
                r.clone(),
                vocab::ns(vocab::RDFS, "comment"),
                text(&spec.description),
            ),
            Triple::new(
                r.clone(),
                shoal("enabled"),
                Literal::from(compiled.info.enabled),
            ),
            Triple::new(
                r.clone(),
                shoal("builtIn"),
                Literal::from(compiled.info.built_in),
            ),
            Triple::new(
                r.clone(),
                shoal("definition"),
                text(&spec.condition.to_string()),
            ),
        ];
        if let Some(c) = self
            .vocabulary
            .lookup(Family::EventClass, event_kind_code(spec.kind))
        {
            t.push(Triple::new(r.clone(), shoal("raises"), c.clone()));
        }
        if let Some(s) = self
            .vocabulary
            .lookup(Family::Severity, severity_code(spec.severity))
        {
            t.push(Triple::new(r.clone(), shoal("ruleSeverity"), s.clone()));
        }
        let watched: Vec<String> = match &spec.condition {
            Condition::Threshold(th) => vec![th.field.property().into_string()],
            Condition::OutsideArea { .. } => vec![
                StateField::Latitude.property().into_string(),
                StateField::Longitude.property().into_string(),
            ],
            Condition::LostContact { .. } => vec![shoal("lastSeen").into_string()],
            Condition::TaskOverdue { .. } => vec![shoal("hasState").into_string()],
            _ => compiled.watches.clone(),
        };
        for w in watched {
            t.push(Triple::new(r.clone(), shoal("watches"), vocab::iri(w)));
        }
        let id = spec.id.clone();
        self.set_entity(EntityKind::Rule, &id, Layer::Model, t, Vec::new())?;
        self.rules.insert(compiled);
        Ok(())
    }

    /// Creates a rule; its condition is checked (and a SPARQL query parsed) now.
    pub fn create_rule(&mut self, spec: RuleSpec) -> Result<(), RuleError> {
        if self.rules.get(&spec.id).is_some() {
            return Err(RuleError::Exists(spec.id));
        }
        let compiled = rules::compile(RuleInfo {
            spec,
            enabled: true,
            built_in: false,
        })?;
        self.put_rule(compiled)
            .map_err(|e| RuleError::Invalid(e.to_string()))
    }

    /// Every rule, built-in ones included, ordered by identifier.
    pub fn rules(&self) -> Vec<RuleInfo> {
        self.rules.list()
    }

    /// Enables or disables a rule.
    pub fn set_rule_enabled(&mut self, id: &str, enabled: bool) -> Result<(), RuleError> {
        let current = self
            .rules
            .get(id)
            .ok_or_else(|| RuleError::NotFound(id.to_owned()))?;
        let mut info = current.info.clone();
        info.enabled = enabled;
        let compiled = rules::compile(info)?;
        if !enabled {
            self.rules.remove(id);
        }
        self.put_rule(compiled)
            .map_err(|e| RuleError::Invalid(e.to_string()))
    }

    /// Deletes a user rule.
    pub fn delete_rule(&mut self, id: &str) -> Result<(), RuleError> {
        let current = self
            .rules
            .get(id)
            .ok_or_else(|| RuleError::NotFound(id.to_owned()))?;
        if current.info.built_in {
            return Err(RuleError::BuiltIn(id.to_owned()));
        }
        self.rules.remove(id);
        self.set_entity(EntityKind::Rule, id, Layer::Model, Vec::new(), Vec::new())
            .map_err(|e| RuleError::Invalid(e.to_string()))?;
        Ok(())
    }

    // ---------------------------------------------------------------------------------
    // Export
    // ---------------------------------------------------------------------------------

    /// Writes the model in `options.format`; returns the writer.
    pub fn export<W: Write>(&self, options: ExportOptions, writer: W) -> Result<W, StoreError> {
        let format = match options.format {
            ExportFormat::NQuads => RdfFormat::NQuads,
            ExportFormat::TriG => RdfFormat::TriG,
            ExportFormat::Turtle => RdfFormat::Turtle,
            ExportFormat::NTriples => RdfFormat::NTriples,
        };
        let mut serializer = RdfSerializer::from_format(format);
        if matches!(options.format, ExportFormat::Turtle | ExportFormat::TriG) {
            for (prefix, iri) in vocab::PREFIXES {
                serializer = serializer
                    .with_prefix(prefix, iri)
                    .map_err(|e| std::io::Error::other(e.to_string()))?;
            }
        }
        let mut out = serializer.for_writer(writer);
        let dataset = format.supports_datasets();
        let mut seen: HashSet<Triple> = HashSet::new();
        for quad in self.data.iter() {
            if !options.include_ontology && ontology::is_ontology_graph(quad.graph_name.as_ref()) {
                continue;
            }
            let inferred = matches!(quad.graph_name.as_ref(), GraphNameRef::NamedNode(n)
                if n.as_str() == vocab::GRAPH_INFERRED);
            if !options.include_inferred && inferred {
                continue;
            }
            if dataset {
                out.serialize_quad(QuadRef::from(&quad))?;
            } else {
                let t = Triple::from(quad);
                // Merged graphs repeat facts (a mission in each of its tasks' graphs).
                if !seen.contains(&t) {
                    out.serialize_triple(&t)?;
                    seen.insert(t);
                }
            }
        }
        Ok(out.finish()?)
    }
}

/// Where a triple is stored; the order is the priority when several entities state it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Layer {
    Ontology = 0,
    Model = 1,
    Inferred = 2,
}

impl Layer {
    fn graph(self) -> GraphName {
        GraphName::NamedNode(vocab::iri(match self {
            Self::Ontology => vocab::GRAPH_ONTOLOGY,
            Self::Model => vocab::GRAPH_MODEL,
            Self::Inferred => vocab::GRAPH_INFERRED,
        }))
    }
}

/// The graph a triple with these per-layer counts is stored in, if any.
fn placement(counts: &[u32; 3]) -> Option<Layer> {
    [Layer::Ontology, Layer::Model, Layer::Inferred]
        .into_iter()
        .find(|l| counts[*l as usize] > 0)
}

/// The dataset, ready to change: copied first if a snapshot shares it, so that the
/// snapshot keeps the state it was taken in. (A function of the two fields rather than
/// a method, so callers can hold other fields of the store meanwhile.)
fn writable<'a>(data: &'a mut Arc<Dataset>, stats: &mut StoreStats) -> &'a mut Dataset {
    if Arc::get_mut(data).is_none() {
        let start = Instant::now();
        *data = Arc::new(Dataset::clone(data));
        stats.snapshot_copies += 1;
        stats.snapshot_copy_time += start.elapsed();
    }
    Arc::make_mut(data)
}

/// GeoSPARQL WKT of a closed polygon (WKT orders longitude first).
fn wkt_polygon(points: &[GeoPoint]) -> String {
    let mut s = String::from("POLYGON((");
    for (i, p) in points.iter().chain(points.first()).enumerate() {
        if i > 0 {
            s.push_str(", ");
        }
        s.push_str(&format!("{} {}", p.longitude_deg, p.latitude_deg));
    }
    s.push_str("))");
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{ConfigError, QueryLimits, QueryResult};
    use shoal_model::{EventKind, TaskState};

    const T: i64 = 1_700_000_000_000;

    fn announce(
        id: &str,
        kind: VehicleKind,
        sensors: &[&str],
        caps: &[&str],
    ) -> VehicleAnnouncement {
        VehicleAnnouncement {
            vehicle_id: id.into(),
            name: format!("{id} name"),
            kind,
            vendor: "Test".into(),
            capabilities: caps.iter().map(|s| (*s).to_owned()).collect(),
            sensors: sensors.iter().map(|s| (*s).to_owned()).collect(),
            links: vec![LinkKind::Acoustic],
            max_speed_mps: 2.0,
            timestamp_ms: T,
        }
    }

    fn state(id: &str, ts: i64, battery: f64) -> StateVector {
        StateVector {
            vehicle_id: id.into(),
            timestamp_ms: ts,
            latitude_deg: 43.1,
            longitude_deg: 5.9,
            depth_m: 10.0,
            altitude_m: 3.0,
            speed_mps: 1.0,
            yaw_deg: 90.0,
            pitch_deg: 0.0,
            roll_deg: 0.0,
            battery_pct: battery,
        }
    }

    fn goto(task_id: &str, vehicle: &str) -> TaskAssignment {
        TaskAssignment::new(
            task_id,
            "m1",
            vehicle,
            T,
            &Task::GotoWaypoint {
                target: GeoPoint {
                    latitude_deg: 43.0,
                    longitude_deg: 5.9,
                },
                depth_m: Some(5.0),
                altitude_m: None,
                speed_mps: 1.0,
            },
        )
    }

    fn status(task_id: &str, vehicle: &str, ts: i64, state: TaskState) -> TaskStatus {
        TaskStatus {
            task_id: task_id.into(),
            vehicle_id: vehicle.into(),
            timestamp_ms: ts,
            state,
            progress_pct: 0.0,
            message: String::new(),
        }
    }

    fn select_ids(s: &SemanticStore, q: &str) -> Vec<String> {
        match s.query(q, &QueryLimits::default()).unwrap() {
            QueryResult::Solutions { rows, .. } => rows
                .into_iter()
                .map(|r| match r.get(0) {
                    Some(oxrdf::Term::NamedNode(n)) => {
                        n.as_str().rsplit('/').next().unwrap_or("").to_owned()
                    }
                    other => format!("{other:?}"),
                })
                .collect(),
            other => panic!("not solutions: {other:?}"),
        }
    }

    fn battery_of(s: &SemanticStore, id: &str) -> f64 {
        let q = format!(
            "SELECT ?b WHERE {{ <{}> shoal:batteryLevel ?b }}",
            vehicle_iri(id).as_str()
        );
        match s.query(&q, &QueryLimits::default()).unwrap() {
            QueryResult::Solutions { rows, .. } => {
                assert_eq!(rows.len(), 1, "exactly one battery value");
                match rows[0].get(0) {
                    Some(oxrdf::Term::Literal(l)) => l.value().parse().unwrap(),
                    other => panic!("{other:?}"),
                }
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn capabilities_are_inferred_from_sensors_and_declarations() {
        let mut s = SemanticStore::new(StoreConfig::default()).unwrap();
        s.upsert_vehicle(&announce(
            "auv-1",
            VehicleKind::Auv,
            &["sidescan_sonar"],
            &[],
        ))
        .unwrap();
        s.upsert_vehicle(&announce(
            "auv-2",
            VehicleKind::Auv,
            &["ctd"],
            &["sidescan_survey"],
        ))
        .unwrap();
        s.upsert_vehicle(&announce("usv-1", VehicleKind::Usv, &["gps"], &["goto"]))
            .unwrap();
        let q = crate::STANDARD_QUERIES[3].1;
        assert_eq!(select_ids(&s, q), ["auv-1", "auv-2"]);
        // Class hierarchy: an AUV is an UnderwaterVehicle, a USV is not.
        let uw = select_ids(
            &s,
            "SELECT ?v WHERE { ?v a shoal:UnderwaterVehicle } ORDER BY ?v",
        );
        assert_eq!(uw, ["auv-1", "auv-2"]);
        // Re-announcing without the sonar removes the derived capability too.
        s.upsert_vehicle(&announce("auv-1", VehicleKind::Auv, &["ctd"], &[]))
            .unwrap();
        assert_eq!(select_ids(&s, q), ["auv-2"]);
    }

    /// The union default graph is a multiset: a vehicle typed by two graphs was
    /// listed once per task (found by the rdflib cross-check).
    #[test]
    fn a_vehicle_with_several_tasks_is_listed_once() {
        let mut s = SemanticStore::new(StoreConfig::default()).unwrap();
        s.upsert_vehicle(&announce("auv-1", VehicleKind::Auv, &[], &[]))
            .unwrap();
        s.upsert_task(&goto("t1", "auv-1")).unwrap();
        s.upsert_task(&goto("t2", "auv-1")).unwrap();
        assert_eq!(
            select_ids(&s, "SELECT ?v WHERE { ?v a shoal:Vehicle }"),
            ["auv-1"]
        );
        // Facts stay while any entity still states them.
        s.upsert_vehicle(&announce("auv-1", VehicleKind::Usv, &[], &[]))
            .unwrap();
        assert_eq!(
            select_ids(&s, "SELECT ?v WHERE { ?v a shoal:Vehicle }"),
            ["auv-1"]
        );
        assert!(select_ids(&s, "SELECT ?v WHERE { ?v a shoal:AUV }").is_empty());
    }

    #[test]
    fn a_forgotten_task_leaves_no_triple_and_its_mission_goes_with_its_last_task() {
        let mut s = SemanticStore::new(StoreConfig::default()).unwrap();
        s.upsert_vehicle(&announce("auv-1", VehicleKind::Auv, &[], &[]))
            .unwrap();
        s.upsert_task(&goto("t1", "auv-1")).unwrap();
        s.upsert_task(&goto("t2", "auv-1")).unwrap();
        let tasks = "SELECT ?x WHERE { ?x shoal:taskId ?t }";
        let missions = "SELECT ?x WHERE { ?x shoal:missionId ?m }";
        assert!(s.forget_task("t1").unwrap());
        assert!(!s.forget_task("t1").unwrap(), "forgotten twice");
        assert_eq!(select_ids(&s, tasks), ["t2"]);
        assert_eq!(select_ids(&s, missions), ["m1"]);
        assert!(s.forget_task("t2").unwrap());
        assert!(select_ids(&s, tasks).is_empty());
        assert!(select_ids(&s, missions).is_empty());
        assert_eq!(s.task_count(), 0);
        assert!(s.task_state("t2").is_none());
    }

    #[test]
    fn state_is_coalesced_to_one_rdf_write_per_interval() {
        let mut s = SemanticStore::new(StoreConfig::default()).unwrap();
        for i in 0..10 {
            s.update_state(&state("auv-1", T + i * 100, 80.0 - i as f64))
                .unwrap();
        }
        assert_eq!(
            s.stats().unwrap().state_flushes,
            0,
            "update_state never writes RDF"
        );
        s.flush_dirty(T + 1000).unwrap();
        assert_eq!(s.stats().unwrap().state_flushes, 1);
        assert_eq!(battery_of(&s, "auv-1"), 71.0);
        s.update_state(&state("auv-1", T + 1100, 60.0)).unwrap();
        s.flush_dirty(T + 1500).unwrap();
        assert_eq!(
            battery_of(&s, "auv-1"),
            71.0,
            "within the interval: not yet mirrored"
        );
        s.flush_dirty(T + 2000).unwrap();
        assert_eq!(battery_of(&s, "auv-1"), 60.0);
        assert_eq!(s.latest_state("auv-1").unwrap().battery_pct, 60.0);
    }

    /// Flushing in parts of the dirty list visits each vehicle once: the due ones are
    /// mirrored, the ones not yet due wait at the back, and a state arriving between two
    /// parts waits for the next round.
    #[test]
    fn a_flush_in_parts_mirrors_each_due_vehicle_once() {
        let mut s = SemanticStore::new(StoreConfig::default()).unwrap();
        for v in 0..5 {
            s.update_state(&state(&format!("v{v}"), T, 50.0)).unwrap();
        }
        s.flush_dirty(T).unwrap();
        // v0 and v1 are mirrored again later, so at T + 1500 only v2..v4 are due.
        for v in 0..2 {
            s.update_state(&state(&format!("v{v}"), T + 100, 45.0))
                .unwrap();
        }
        s.flush_dirty(T + 1000).unwrap();
        for v in 0..5 {
            s.update_state(&state(&format!("v{v}"), T + 1100 + v, 40.0))
                .unwrap();
        }
        let now = T + 1500;
        let due = |v: i64| v >= 2;
        let mut left = s.dirty_len();
        assert_eq!(left, 5);
        let mut parts = 0;
        while left > 0 {
            let n = left.min(2);
            s.flush_dirty_at_most(now, n).unwrap();
            left -= n;
            parts += 1;
            if parts == 1 {
                // Arrives between two parts: listed once, mirrored next round.
                s.update_state(&state("v9", T + 1200, 30.0)).unwrap();
            }
        }
        assert_eq!(parts, 3);
        for v in 0..5 {
            let expected = if due(v) { 40.0 } else { 45.0 };
            assert_eq!(battery_of(&s, &format!("v{v}")), expected, "v{v}");
        }
        assert_eq!(s.stats().unwrap().state_flushes, 5 + 2 + 3);
        assert_eq!(s.dirty_len(), 3, "v0, v1 not yet due, v9 new");
    }

    #[test]
    fn stale_and_invalid_states_change_nothing() {
        let mut s = SemanticStore::new(StoreConfig::default()).unwrap();
        s.update_state(&state("auv-1", T + 1000, 50.0)).unwrap();
        s.update_state(&state("auv-1", T, 10.0)).unwrap();
        assert_eq!(s.latest_state("auv-1").unwrap().battery_pct, 50.0);
        let mut bad = state("auv-1", T + 2000, 10.0);
        bad.latitude_deg = f64::NAN;
        let e = s.update_state(&bad).unwrap_err();
        assert!(e.to_string().contains("latitude_deg"), "{e}");
        assert_eq!(s.latest_state("auv-1").unwrap().battery_pct, 50.0);
        assert_eq!(s.stats().unwrap().states_stale, 1);
    }

    /// Replaced values are freed (an earlier Oxigraph store kept them, growing without
    /// bound and slowing queries 10–20× until compacted).
    #[test]
    fn fifty_thousand_state_updates_keep_the_store_bounded_and_correct() {
        let config = StoreConfig {
            min_state_interval_ms: 0,
            ..StoreConfig::default()
        };
        let mut s = SemanticStore::new(config).unwrap();
        for v in 0..10 {
            s.upsert_vehicle(&announce(&format!("v{v}"), VehicleKind::Auv, &["ctd"], &[]))
                .unwrap();
        }
        s.update_state(&state("v0", T, 99.0)).unwrap();
        s.flush_dirty(T).unwrap();
        let baseline = s.stats().unwrap();
        for i in 1..=50_000i64 {
            let v = format!("v{}", i % 10);
            s.update_state(&state(&v, T + i, (i % 1000) as f64 / 10.0))
                .unwrap();
            s.flush_dirty(T + i).unwrap();
        }
        let st = s.stats().unwrap();
        assert_eq!(st.state_flushes, 50_001);
        // 9 more vehicles' state (10 quads each, at most 10 new terms) is all that may be
        // added: every replaced value and timestamp was freed.
        assert!(
            st.quads <= baseline.quads + 9 * 10,
            "{} vs {}",
            st.quads,
            baseline.quads
        );
        assert!(
            st.terms <= baseline.terms + 10 * 10,
            "{} vs {}",
            st.terms,
            baseline.terms
        );
        assert_eq!(st.quads, quads_of(&s).len());
        // Updates 49_991..=50_000 were the last for each vehicle; v0 got i = 50_000.
        assert_eq!(battery_of(&s, "v0"), 0.0);
        assert_eq!(battery_of(&s, "v7"), 997.0 / 10.0);
    }

    #[test]
    fn low_battery_fires_once_and_rearms() {
        let mut s = SemanticStore::new(StoreConfig::default()).unwrap();
        assert!(s.update_state(&state("auv-1", T, 50.0)).unwrap().is_empty());
        let e = s.update_state(&state("auv-1", T + 1, 19.0)).unwrap();
        assert_eq!(e.len(), 1);
        assert_eq!(
            (e[0].kind, e[0].vehicle_id.as_str()),
            (EventKind::LowBattery, "auv-1")
        );
        assert!(e[0].text.contains("battery_pct = 19"), "{}", e[0].text);
        e[0].validate().unwrap();
        assert!(
            s.update_state(&state("auv-1", T + 2, 18.0))
                .unwrap()
                .is_empty(),
            "edge-triggered"
        );
        assert!(
            s.update_state(&state("auv-1", T + 3, 30.0))
                .unwrap()
                .is_empty()
        );
        assert_eq!(
            s.update_state(&state("auv-1", T + 4, 10.0)).unwrap().len(),
            1,
            "re-armed"
        );
        s.set_rule_enabled(builtin::LOW_BATTERY, false).unwrap();
        assert!(
            s.update_state(&state("auv-1", T + 5, 50.0))
                .unwrap()
                .is_empty()
        );
        assert!(
            s.update_state(&state("auv-1", T + 6, 5.0))
                .unwrap()
                .is_empty(),
            "disabled"
        );
        assert_eq!(
            s.delete_rule(builtin::LOW_BATTERY),
            Err(RuleError::BuiltIn(builtin::LOW_BATTERY.into()))
        );
    }

    #[test]
    fn a_rule_over_its_time_budget_is_cancelled_disabled_and_reported_and_ingest_goes_on() {
        let mut s = SemanticStore::new(StoreConfig {
            rule_budget_ms: 20,
            ..StoreConfig::default()
        })
        .unwrap();
        for i in 0..30 {
            s.upsert_vehicle(&announce(&format!("v{i}"), VehicleKind::Auv, &[], &[]))
                .unwrap();
        }
        // Paths over the whole model from every node reached: quadratic in the model, and
        // every step reads the index, which is where evaluation can be cancelled.
        s.create_rule(RuleSpec {
            id: "cartesian".into(),
            description: "A pathological rule".into(),
            severity: Severity::Info,
            kind: EventKind::Rule,
            condition: Condition::Sparql {
                query: "ASK { ?this shoal:batteryLevel ?b . ?a (!shoal:none)* ?x . \
                        ?x (^!shoal:none)* ?y . ?y (!shoal:none)* ?z \
                        FILTER(STRLEN(STR(?z)) < ?b - 100) }"
                    .into(),
                watches: vec!["shoal:batteryLevel".into()],
            },
        })
        .unwrap();
        s.update_state(&state("v1", T, 40.0)).unwrap();
        let started = Instant::now();
        let events = s.flush_dirty(T + 1000).unwrap();
        assert!(
            started.elapsed() < Duration::from_secs(5),
            "the rule was not cut short: {:?}",
            started.elapsed()
        );
        let warning = events
            .iter()
            .find(|e| e.text.contains("rule disabled"))
            .unwrap_or_else(|| panic!("no event says the rule was disabled: {events:?}"));
        assert_eq!(warning.severity, Severity::Warning);
        assert!(warning.text.contains("cartesian"), "{}", warning.text);
        assert_eq!(s.stats().unwrap().rules_over_budget, 1);
        let rule = s
            .rules()
            .into_iter()
            .find(|r| r.spec.id == "cartesian")
            .unwrap();
        assert!(!rule.enabled);
        // Ingest goes on, and the disabled rule no longer runs.
        s.update_state(&state("v2", T + 1000, 40.0)).unwrap();
        let started = Instant::now();
        s.flush_dirty(T + 2000).unwrap();
        assert!(started.elapsed() < Duration::from_secs(1));
        assert_eq!(s.latest_state("v2").unwrap().battery_pct, 40.0);
    }

    #[test]
    fn user_threshold_and_sparql_rules_fire_on_insert_for_the_changed_entity() {
        let mut s = SemanticStore::new(StoreConfig::default()).unwrap();
        s.create_rule(RuleSpec {
            id: "deep".into(),
            description: "Too deep".into(),
            severity: Severity::Alarm,
            kind: EventKind::Rule,
            condition: Condition::Threshold("depth_m > 100".parse().unwrap()),
        })
        .unwrap();
        s.create_rule(RuleSpec {
            id: "gliders-low".into(),
            description: "Glider below 50 %".into(),
            severity: Severity::Warning,
            kind: EventKind::Rule,
            condition: Condition::Sparql {
                query: "ASK { ?this a shoal:Glider ; shoal:batteryLevel ?b FILTER(?b < 50) }"
                    .into(),
                watches: vec!["shoal:batteryLevel".into()],
            },
        })
        .unwrap();
        assert_eq!(
            s.create_rule(RuleSpec {
                id: "deep".into(),
                description: String::new(),
                severity: Severity::Info,
                kind: EventKind::Rule,
                condition: Condition::Threshold("depth_m > 1".parse().unwrap()),
            }),
            Err(RuleError::Exists("deep".into()))
        );
        s.upsert_vehicle(&announce("g1", VehicleKind::Glider, &[], &[]))
            .unwrap();
        s.upsert_vehicle(&announce("a1", VehicleKind::Auv, &[], &[]))
            .unwrap();
        let mut deep = state("a1", T, 40.0);
        deep.depth_m = 150.0;
        let e = s.update_state(&deep).unwrap();
        assert_eq!(
            e.iter()
                .map(|e| e.event_id.split('-').next().unwrap())
                .collect::<Vec<_>>(),
            ["deep"]
        );
        s.update_state(&state("g1", T, 40.0)).unwrap();
        // The SPARQL rule runs on the RDF mirror, i.e. at flush, only for the glider.
        let e = s.flush_dirty(T + 1000).unwrap();
        assert_eq!(e.len(), 1, "{e:?}");
        assert_eq!(
            (e[0].vehicle_id.as_str(), e[0].severity),
            ("g1", Severity::Warning)
        );
        assert!(e[0].event_id.starts_with("gliders-low-"));
        // The rule is stored as data.
        let ids = select_ids(
            &s,
            "SELECT ?r WHERE { ?r a shoal:SparqlRule ; shoal:enabled true }",
        );
        assert_eq!(ids, ["builtin.collision_risk", "gliders-low"]);
        // Three built-in rules (low battery, task overdue, collision risk; out of area
        // needs an area) and the two created here.
        assert_eq!(s.rules().len(), 5);
        s.delete_rule("gliders-low").unwrap();
        assert_eq!(
            s.delete_rule("gliders-low"),
            Err(RuleError::NotFound("gliders-low".into()))
        );
        assert_eq!(
            select_ids(&s, "SELECT ?r WHERE { ?r a shoal:SparqlRule }"),
            ["builtin.collision_risk"]
        );
    }

    /// Contact is the Vehicle Register's: the store has no lost-contact rule of its own,
    /// and an operator's lost-contact rule raises its event without touching availability.
    #[test]
    fn a_user_lost_contact_rule_fires_in_tick_is_rearmed_by_a_state_and_leaves_availability() {
        let mut s = SemanticStore::new(StoreConfig::default()).unwrap();
        s.set_availability("auv-1", Availability::Idle).unwrap();
        s.update_state(&state("auv-1", T, 80.0)).unwrap();
        assert!(s.tick(T + 60_000).unwrap().is_empty(), "no built-in rule");
        s.create_rule(RuleSpec {
            id: "silent".into(),
            description: "No state for five periods".into(),
            severity: Severity::Alarm,
            kind: EventKind::CommLost,
            condition: Condition::LostContact { factor: 5.0 },
        })
        .unwrap();
        s.update_state(&state("auv-1", T + 1_000, 80.0)).unwrap();
        assert!(s.tick(T + 5_000).unwrap().is_empty());
        let e = s.tick(T + 7_000).unwrap();
        assert_eq!(e.len(), 1);
        assert_eq!(
            (e[0].kind, e[0].vehicle_id.as_str()),
            (EventKind::CommLost, "auv-1")
        );
        assert!(e[0].event_id.starts_with("silent-"), "{}", e[0].event_id);
        assert!(s.tick(T + 8_000).unwrap().is_empty(), "fires once");
        assert_eq!(s.availability("auv-1"), Some(Availability::Idle));
        assert!(select_ids(&s, "SELECT ?v WHERE { ?v shoal:availability shoal:Lost }").is_empty());
        assert_eq!(
            select_ids(&s, "SELECT ?v WHERE { ?v shoal:availability shoal:Idle }"),
            ["auv-1"]
        );
        // A newer state re-arms the rule; an older one (a late retransmission) does not.
        s.update_state(&state("auv-1", T, 80.0)).unwrap();
        assert!(
            s.tick(T + 20_000).unwrap().is_empty(),
            "a stale state re-arms nothing"
        );
        s.update_state(&state("auv-1", T + 9_000, 80.0)).unwrap();
        assert!(s.tick(T + 10_000).unwrap().is_empty());
        assert_eq!(s.tick(T + 15_000).unwrap().len(), 1, "re-armed");
        assert_eq!(s.availability("auv-1"), Some(Availability::Idle));
    }

    #[test]
    fn leaving_the_operating_area_raises_out_of_area() {
        let area = vec![
            GeoPoint {
                latitude_deg: 43.0,
                longitude_deg: 5.8,
            },
            GeoPoint {
                latitude_deg: 43.0,
                longitude_deg: 6.0,
            },
            GeoPoint {
                latitude_deg: 43.2,
                longitude_deg: 6.0,
            },
            GeoPoint {
                latitude_deg: 43.2,
                longitude_deg: 5.8,
            },
        ];
        let mut s = SemanticStore::new(StoreConfig {
            operating_area: area,
            ..StoreConfig::default()
        })
        .unwrap();
        assert!(s.update_state(&state("auv-1", T, 80.0)).unwrap().is_empty());
        let mut out = state("auv-1", T + 1, 80.0);
        out.latitude_deg = 43.3;
        let e = s.update_state(&out).unwrap();
        assert_eq!(e.len(), 1);
        assert_eq!(
            (e[0].kind, e[0].severity),
            (EventKind::OutOfArea, Severity::Alarm)
        );
    }

    #[test]
    fn a_bad_operating_area_is_a_configuration_error() {
        let area = vec![
            GeoPoint {
                latitude_deg: 43.0,
                longitude_deg: 5.8
            };
            2
        ];
        let e = SemanticStore::new(StoreConfig {
            operating_area: area,
            ..StoreConfig::default()
        })
        .unwrap_err();
        assert!(
            matches!(e, StoreError::Config(ConfigError::AreaTooSmall(2))),
            "{e}"
        );
        assert!(e.to_string().contains("operating_area"), "{e}");
    }

    /// Every quad in the store, as a set (the store holds each at most once).
    fn quads_of(s: &SemanticStore) -> HashSet<oxrdf::Quad> {
        s.data.iter().collect()
    }

    /// The quads the store's bookkeeping says it holds: each reference-counted triple in
    /// its graph, and each vehicle's mirrored state.
    fn bookkept_quads(s: &SemanticStore) -> HashSet<oxrdf::Quad> {
        let graphs = [
            Layer::Ontology.graph(),
            Layer::Model.graph(),
            Layer::Inferred.graph(),
        ];
        let mut out = HashSet::new();
        for (t, c) in &s.counts {
            if let Some(l) = placement(c) {
                out.insert(t.clone().in_graph(graphs[l as usize].clone()));
            }
        }
        for e in s.vehicles.values() {
            let Some(m) = e.mirror else { continue };
            for (i, p) in s.state_properties.iter().enumerate() {
                let o = match StateField::ALL.get(i) {
                    Some(StateField::Altitude) if m.values[i] == shoal_model::UNKNOWN => continue,
                    Some(_) => double(m.values[i]),
                    None => date_time(m.timestamp_ms),
                };
                out.insert(oxrdf::Quad::new(
                    e.iri.clone(),
                    p.clone(),
                    o,
                    s.model_graph.clone(),
                ));
            }
        }
        out
    }

    /// The state mirror bypasses the reference counts; this checks that the bookkeeping
    /// it relies on is exactly what the store holds, and that snapshots are isolated.
    #[test]
    fn mirrors_keep_exactly_the_live_quads_and_snapshots_keep_theirs() {
        let mut s = SemanticStore::new(StoreConfig {
            max_events: 5,
            ..StoreConfig::default()
        })
        .unwrap();
        crate::synthetic::populate_fleet(&mut s, 6, 3).unwrap();
        for i in 1..=5i64 {
            let mut st = state("v0002", T + 60_000 + i * 1000, 50.0 + i as f64);
            // Altitude comes and goes: an unknown altitude is not stated at all.
            if i % 2 == 0 {
                st.altitude_m = shoal_model::UNKNOWN;
            }
            s.update_state(&st).unwrap();
            s.flush_dirty(T + 60_000 + i * 1000).unwrap();
            assert_eq!(quads_of(&s), bookkept_quads(&s), "flush {i}");
        }
        let altitude = format!(
            "SELECT ?a WHERE {{ <{}> shoal:altitude ?a }}",
            vehicle_iri("v0002").as_str()
        );
        assert_eq!(
            s.query(&altitude, &QueryLimits::default()).unwrap().len(),
            1
        );
        assert_eq!(battery_of(&s, "v0002"), 55.0);
        let before = quads_of(&s);
        assert_eq!(s.stats().unwrap().quads, before.len());
        let snapshot = s.snapshot();
        let mut st = state("v0002", T + 70_000, 12.5);
        st.altitude_m = shoal_model::UNKNOWN;
        s.update_state(&st).unwrap();
        s.flush_dirty(T + 70_000).unwrap();
        assert_eq!(battery_of(&s, "v0002"), 12.5);
        assert!(
            s.query(&altitude, &QueryLimits::default())
                .unwrap()
                .is_empty()
        );
        assert_eq!(quads_of(&s), bookkept_quads(&s));
        // The snapshot still answers from the model as it was, and the write paid one copy.
        assert_eq!(
            snapshot
                .query(&altitude, &QueryLimits::default())
                .unwrap()
                .len(),
            1
        );
        assert_eq!(s.stats().unwrap().snapshot_copies, 1);
        drop(snapshot);
        s.update_state(&state("v0002", T + 80_000, 11.0)).unwrap();
        s.flush_dirty(T + 80_000).unwrap();
        assert_eq!(
            s.stats().unwrap().snapshot_copies,
            1,
            "no snapshot, no copy"
        );
    }

    /// Availability is what the Vehicle Register last set, mirrored into RDF; a task's
    /// state changes never touch it.
    #[test]
    fn availability_is_what_was_set_and_tasks_leave_it_alone_and_final_states_are_final() {
        let mut s = SemanticStore::new(StoreConfig::default()).unwrap();
        s.upsert_vehicle(&announce("auv-1", VehicleKind::Auv, &[], &[]))
            .unwrap();
        s.upsert_vehicle(&announce("auv-2", VehicleKind::Auv, &[], &[]))
            .unwrap();
        assert_eq!(s.availability("auv-1"), None, "not decided by the store");
        assert!(select_ids(&s, "SELECT ?v WHERE { ?v shoal:availability ?a }").is_empty());
        s.set_availability("auv-1", Availability::Charging).unwrap();
        s.set_availability("auv-2", Availability::Idle).unwrap();
        assert_eq!(
            select_ids(
                &s,
                "SELECT ?v WHERE { ?v shoal:availability shoal:Charging }"
            ),
            ["auv-1"]
        );
        s.upsert_task(&goto("t1", "auv-1")).unwrap();
        s.task_status(&status("t1", "auv-1", T + 1, TaskState::Running))
            .unwrap();
        assert_eq!(s.availability("auv-1"), Some(Availability::Charging));
        let q3 = crate::STANDARD_QUERIES[2].1;
        assert_eq!(s.query(q3, &QueryLimits::default()).unwrap().len(), 1);
        s.set_availability("auv-1", Availability::Busy).unwrap();
        assert_eq!(
            select_ids(&s, "SELECT ?v WHERE { ?v shoal:availability shoal:Busy }"),
            ["auv-1"]
        );
        assert!(
            select_ids(
                &s,
                "SELECT ?v WHERE { ?v shoal:availability shoal:Charging }"
            )
            .is_empty(),
            "the old value is replaced"
        );
        s.task_status(&status("t1", "auv-1", T + 2, TaskState::Done))
            .unwrap();
        assert_eq!(s.availability("auv-1"), Some(Availability::Busy));
        // Moving the task to another vehicle moves no availability either.
        s.upsert_task(&goto("t2", "auv-1")).unwrap();
        s.task_status(&status("t2", "auv-1", T + 3, TaskState::Accepted))
            .unwrap();
        s.upsert_task(&goto("t2", "auv-2")).unwrap();
        assert_eq!(s.availability("auv-1"), Some(Availability::Busy));
        assert_eq!(s.availability("auv-2"), Some(Availability::Idle));
        s.task_status(&status("t1", "auv-1", T + 3, TaskState::Running))
            .unwrap();
        assert_eq!(s.task_state("t1"), Some(TaskState::Done));
        assert!(matches!(
            s.task_status(&status("t9", "auv-1", T, TaskState::Running)),
            Err(StoreError::UnknownTask { .. })
        ));
        assert!(matches!(
            s.task_status(&status("t1", "auv-2", T, TaskState::Running)),
            Err(StoreError::WrongVehicle { .. })
        ));
        let done = select_ids(
            &s,
            "SELECT ?t WHERE { ?t shoal:hasState ?s . ?s a shoal:FinalTaskState }",
        );
        assert_eq!(done, ["t1"]);
    }

    #[test]
    fn set_availability_refuses_an_id_that_cannot_be_an_iri_and_keeps_the_model() {
        let mut s = SemanticStore::new(StoreConfig::default()).unwrap();
        let before = s.stats().unwrap();
        for bad in ["", "a b", "<x>", &"v".repeat(MAX_VEHICLE_ID_LEN + 1)] {
            let e = s.set_availability(bad, Availability::Idle).unwrap_err();
            assert!(e.to_string().contains("vehicle_id"), "{bad:?}: {e}");
        }
        assert_eq!(s.stats().unwrap().vehicles, before.vehicles);
        assert_eq!(s.stats().unwrap().quads, before.quads);
    }

    #[test]
    fn set_availability_on_an_unknown_vehicle_creates_it() {
        let mut s = SemanticStore::new(StoreConfig::default()).unwrap();
        s.set_availability("usv-9", Availability::Fault).unwrap();
        assert_eq!(s.stats().unwrap().vehicles, 1);
        assert_eq!(s.availability("usv-9"), Some(Availability::Fault));
        assert_eq!(
            select_ids(
                &s,
                "SELECT ?v WHERE { ?v a shoal:Vehicle ; shoal:vehicleId \"usv-9\" ; \
                 shoal:availability shoal:Faulty }"
            ),
            ["usv-9"]
        );
        // Its later announcement keeps the availability (a graph of its own).
        s.upsert_vehicle(&announce("usv-9", VehicleKind::Usv, &[], &[]))
            .unwrap();
        assert_eq!(
            select_ids(
                &s,
                "SELECT ?v WHERE { ?v a shoal:USV ; shoal:availability shoal:Faulty }"
            ),
            ["usv-9"]
        );
        // The id becomes an IRI, so it must be a well-formed identifier.
        let e = s
            .set_availability("no such>id", Availability::Idle)
            .unwrap_err();
        assert!(matches!(e, StoreError::Invalid { .. }), "{e}");
        assert!(e.to_string().contains("vehicle_id"), "{e}");
        assert_eq!(s.stats().unwrap().vehicles, 1);
    }

    #[test]
    fn setting_the_same_availability_twice_writes_nothing() {
        let mut s = SemanticStore::new(StoreConfig::default()).unwrap();
        s.upsert_vehicle(&announce("auv-1", VehicleKind::Auv, &[], &[]))
            .unwrap();
        s.set_availability("auv-1", Availability::Idle).unwrap();
        let before = s.stats().unwrap();
        let quads = quads_of(&s);
        // A live snapshot makes any write copy the model first, so a write would show.
        let snapshot = s.snapshot();
        s.set_availability("auv-1", Availability::Idle).unwrap();
        let after = s.stats().unwrap();
        assert_eq!(after, before);
        assert_eq!(after.snapshot_copies, 0, "nothing was written");
        assert_eq!(quads_of(&s), quads);
        drop(snapshot);
        s.set_availability("auv-1", Availability::Lost).unwrap();
        assert_eq!(
            s.stats().unwrap().quads,
            before.quads,
            "replaced, not added"
        );
        assert_ne!(quads_of(&s), quads);
        assert_eq!(quads_of(&s), bookkept_quads(&s));
    }

    #[test]
    fn every_availability_maps_to_its_ontology_individual() {
        let mut s = SemanticStore::new(StoreConfig::default()).unwrap();
        let q = format!(
            "SELECT ?a ?l WHERE {{ <{}> shoal:availability ?a . \
             ?a a shoal:Availability ; rdfs:label ?l }}",
            vehicle_iri("auv-1").as_str()
        );
        for (a, local) in [
            (Availability::Idle, "Idle"),
            (Availability::Busy, "Busy"),
            (Availability::Charging, "Charging"),
            (Availability::Fault, "Faulty"),
            (Availability::Lost, "Lost"),
        ] {
            s.set_availability("auv-1", a).unwrap();
            let QueryResult::Solutions { rows, .. } = s.query(&q, &QueryLimits::default()).unwrap()
            else {
                panic!("not solutions");
            };
            assert_eq!(
                rows.len(),
                1,
                "{a:?}: one value, an individual of the ontology"
            );
            assert_eq!(
                rows[0].get(0),
                Some(&oxrdf::Term::from(shoal(local))),
                "{a:?}"
            );
            // The ontology's label is the name the register's JSON uses.
            match rows[0].get(1) {
                Some(oxrdf::Term::Literal(l)) => assert_eq!(l.value(), a.as_str()),
                other => panic!("{a:?}: {other:?}"),
            }
            assert_eq!(s.availability("auv-1"), Some(a));
        }
    }

    #[test]
    fn an_active_task_past_its_deadline_is_overdue_once() {
        let mut s = SemanticStore::new(StoreConfig {
            task_deadline_ms: 60_000,
            ..StoreConfig::default()
        })
        .unwrap();
        s.upsert_task(&goto("t1", "auv-1")).unwrap();
        s.task_status(&status("t1", "auv-1", T + 1, TaskState::Running))
            .unwrap();
        assert!(
            s.tick(T + 59_000)
                .unwrap()
                .iter()
                .all(|e| e.kind != EventKind::Task)
        );
        let e: Vec<_> = s
            .tick(T + 61_000)
            .unwrap()
            .into_iter()
            .filter(|e| e.kind == EventKind::Task)
            .collect();
        assert_eq!(e.len(), 1);
        assert_eq!(e[0].task_id, "t1");
        assert!(
            s.tick(T + 62_000)
                .unwrap()
                .iter()
                .all(|e| e.kind != EventKind::Task)
        );
    }

    #[test]
    fn events_and_observations_are_in_the_model_and_events_are_bounded() {
        let mut s = SemanticStore::new(StoreConfig {
            max_events: 3,
            ..StoreConfig::default()
        })
        .unwrap();
        for i in 0..5 {
            s.add_event(&Event {
                event_id: format!("e{i}"),
                timestamp_ms: T + i,
                severity: Severity::Info,
                kind: EventKind::Detection,
                vehicle_id: "auv-1".into(),
                task_id: String::new(),
                text: "object".into(),
            })
            .unwrap();
        }
        assert_eq!(
            select_ids(&s, "SELECT ?e WHERE { ?e a shoal:Event } ORDER BY ?e"),
            ["e2", "e3", "e4"]
        );
        s.add_observation(&EnvironmentObservation {
            vehicle_id: "auv-1".into(),
            property: "sea_water_temperature".into(),
            timestamp_ms: T,
            value: 14.5,
            unit: "Cel".into(),
            latitude_deg: 43.0,
            longitude_deg: 5.9,
            depth_m: 20.0,
        })
        .unwrap();
        let obs = select_ids(
            &s,
            "SELECT ?o WHERE { ?o a sosa:Observation ; sosa:observedProperty shoal:sea_water_temperature }",
        );
        assert_eq!(obs, ["sea_water_temperature"]);
    }

    #[test]
    fn exports_reparse_to_the_same_quads() {
        let mut s = SemanticStore::new(StoreConfig::default()).unwrap();
        crate::synthetic::populate_fleet(&mut s, 5, 1).unwrap();
        let opts = ExportOptions {
            format: ExportFormat::NQuads,
            include_ontology: true,
            include_inferred: true,
        };
        let nq = s.export(opts, Vec::new()).unwrap();
        let parse = |format: RdfFormat, bytes: &[u8]| -> HashSet<oxrdf::Quad> {
            oxrdfio::RdfParser::from_format(format)
                .for_slice(bytes)
                .map(Result::unwrap)
                .collect()
        };
        assert_eq!(parse(RdfFormat::NQuads, &nq), quads_of(&s));
        let ttl = s
            .export(
                ExportOptions {
                    format: ExportFormat::Turtle,
                    include_ontology: false,
                    include_inferred: false,
                },
                Vec::new(),
            )
            .unwrap();
        assert!(parse(RdfFormat::Turtle, &ttl).len() > 50);
    }
}
