//! Rules & Policies: user and built-in rules, stored as data, evaluated on insert.
//!
//! A rule is a [`RuleSpec`]: an identifier, the event it raises and a [`Condition`].
//! Conditions on a state-vector field ([`Threshold`]) and on the operating area run
//! natively on the typed state at every [`crate::SemanticStore::update_state`], without
//! touching RDF (the fast path); lost contact and task overdue run in
//! [`crate::SemanticStore::tick`] (lost contact only as operators' rules, which raise an
//! event and change nothing: contact is the station's Vehicle Register's); SPARQL
//! conditions run on the RDF model after the entity they watch changed, with `?this`
//! bound to that entity. Rules are indexed by what they watch (state field or RDF
//! property), so an insert runs only the rules it can affect, and only for the changed
//! entity. Rules are edge-triggered: a rule fires once when its condition becomes true for
//! an entity and re-arms when it becomes false, so a vehicle at 19 % battery reporting at
//! 10 Hz raises one event, not ten a second.

use std::collections::{BTreeMap, HashMap, HashSet};
use std::fmt;
use std::str::FromStr;
use std::sync::Arc;

use oxrdf::NamedNode;
use shoal_model::{Event, EventKind, GeoPoint, MAX_TEXT_LEN, Severity, StateVector};
use spargebra::{Query, SparqlParser};

use crate::error::RuleError;
use crate::vocab::{self, GEO, shoal};

/// A numeric field of the state vector a [`Threshold`] can watch.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum StateField {
    /// `latitude_deg`.
    Latitude,
    /// `longitude_deg`.
    Longitude,
    /// `depth_m`.
    Depth,
    /// `altitude_m` (-1 when unknown: thresholds on it skip unknown values).
    Altitude,
    /// `speed_mps`.
    Speed,
    /// `yaw_deg`.
    Yaw,
    /// `pitch_deg`.
    Pitch,
    /// `roll_deg`.
    Roll,
    /// `battery_pct`.
    Battery,
}

impl StateField {
    /// Every field, in state-vector order.
    pub const ALL: [Self; 9] = [
        Self::Latitude,
        Self::Longitude,
        Self::Depth,
        Self::Altitude,
        Self::Speed,
        Self::Yaw,
        Self::Pitch,
        Self::Roll,
        Self::Battery,
    ];

    /// The field's name in the IDL and in rule text, e.g. `battery_pct`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Latitude => "latitude_deg",
            Self::Longitude => "longitude_deg",
            Self::Depth => "depth_m",
            Self::Altitude => "altitude_m",
            Self::Speed => "speed_mps",
            Self::Yaw => "yaw_deg",
            Self::Pitch => "pitch_deg",
            Self::Roll => "roll_deg",
            Self::Battery => "battery_pct",
        }
    }

    /// The field's value in a state vector.
    pub fn get(self, s: &StateVector) -> f64 {
        match self {
            Self::Latitude => s.latitude_deg,
            Self::Longitude => s.longitude_deg,
            Self::Depth => s.depth_m,
            Self::Altitude => s.altitude_m,
            Self::Speed => s.speed_mps,
            Self::Yaw => s.yaw_deg,
            Self::Pitch => s.pitch_deg,
            Self::Roll => s.roll_deg,
            Self::Battery => s.battery_pct,
        }
    }

    /// The RDF property mirroring the field on the vehicle.
    pub fn property(self) -> NamedNode {
        match self {
            Self::Latitude => vocab::ns(GEO, "lat"),
            Self::Longitude => vocab::ns(GEO, "long"),
            Self::Depth => shoal("depth"),
            Self::Altitude => shoal("altitude"),
            Self::Speed => shoal("speed"),
            Self::Yaw => shoal("yaw"),
            Self::Pitch => shoal("pitch"),
            Self::Roll => shoal("roll"),
            Self::Battery => shoal("batteryLevel"),
        }
    }

    pub(crate) fn index(self) -> usize {
        self as usize
    }
}

impl FromStr for StateField {
    type Err = RuleError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let s = s.trim();
        Self::ALL
            .into_iter()
            .find(|f| f.name() == s || f.name().split('_').next() == Some(s))
            .ok_or_else(|| {
                RuleError::Parse(format!(
                    "unknown state field {s:?}; expected one of {}",
                    Self::ALL.map(Self::name).join(", ")
                ))
            })
    }
}

/// A comparison operator of a [`Threshold`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum Comparison {
    /// `<`
    Lt,
    /// `<=`
    Le,
    /// `>`
    Gt,
    /// `>=`
    Ge,
}

impl Comparison {
    fn symbol(self) -> &'static str {
        match self {
            Self::Lt => "<",
            Self::Le => "<=",
            Self::Gt => ">",
            Self::Ge => ">=",
        }
    }

    fn holds(self, a: f64, b: f64) -> bool {
        match self {
            Self::Lt => a < b,
            Self::Le => a <= b,
            Self::Gt => a > b,
            Self::Ge => a >= b,
        }
    }
}

/// `field op value`, e.g. `battery_pct < 20`: the native fast path.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Threshold {
    /// Watched field.
    pub field: StateField,
    /// Operator.
    pub op: Comparison,
    /// Constant compared with, in the field's unit.
    pub value: f64,
}

impl Threshold {
    /// True when the state vector meets the condition (unknown altitude never does).
    pub fn holds(&self, s: &StateVector) -> bool {
        let v = self.field.get(s);
        if self.field == StateField::Altitude && v == shoal_model::UNKNOWN {
            return false;
        }
        self.op.holds(v, self.value)
    }
}

impl fmt::Display for Threshold {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} {} {}",
            self.field.name(),
            self.op.symbol(),
            self.value
        )
    }
}

impl FromStr for Threshold {
    type Err = RuleError;

    /// Parses `field op number`, e.g. `battery_pct < 20` or `depth_m >= 300`.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        // Two-character operators first so that `<=` is not read as `<`.
        for (sym, op) in [
            ("<=", Comparison::Le),
            (">=", Comparison::Ge),
            ("<", Comparison::Lt),
            (">", Comparison::Gt),
        ] {
            if let Some((field, value)) = s.split_once(sym) {
                let field = field.parse()?;
                let value: f64 = value
                    .trim()
                    .parse()
                    .map_err(|_| RuleError::Parse(format!("{:?} is not a number", value.trim())))?;
                if !value.is_finite() {
                    return Err(RuleError::Parse("threshold must be finite".into()));
                }
                return Ok(Self { field, op, value });
            }
        }
        Err(RuleError::Parse(format!(
            "{s:?}: expected `field op number` with op one of <, <=, >, >="
        )))
    }
}

/// What a rule checks.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum Condition {
    /// A state-vector field against a constant (native, on every state update).
    Threshold(Threshold),
    /// The vehicle's position is outside this polygon (native, on every state update).
    OutsideArea {
        /// Polygon corners, at least 3, in order; longitude/latitude treated as planar.
        polygon: Vec<GeoPoint>,
    },
    /// No state for `factor` × the vehicle's expected reporting period (in `tick`). Only
    /// raises the rule's event: contact and availability are the Vehicle Register's.
    LostContact {
        /// How many missed periods make contact lost.
        factor: f64,
    },
    /// A task is still not final `grace_ms` after its deadline (in `tick`).
    TaskOverdue {
        /// Extra time after `shoal:deadline`, in milliseconds.
        grace_ms: i64,
    },
    /// A SPARQL ASK (fires when true) or SELECT (fires when non-empty) with `?this` bound
    /// to the changed entity; runs only when one of `watches` changed on it.
    Sparql {
        /// The query; default prefixes (`shoal:`, `geo:`, `sosa:` ...) need no declaration.
        query: String,
        /// Watched properties, as IRIs or prefixed names (`shoal:batteryLevel`).
        watches: Vec<String>,
    },
}

impl fmt::Display for Condition {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Threshold(t) => t.fmt(f),
            Self::OutsideArea { polygon } => {
                write!(f, "outside POLYGON((")?;
                for (i, p) in polygon.iter().chain(polygon.first()).enumerate() {
                    let sep = if i == 0 { "" } else { ", " };
                    write!(f, "{sep}{} {}", p.longitude_deg, p.latitude_deg)?;
                }
                write!(f, "))")
            }
            Self::LostContact { factor } => write!(f, "no state for {factor} x expected period"),
            Self::TaskOverdue { grace_ms } => {
                write!(f, "task active {grace_ms} ms past its deadline")
            }
            Self::Sparql { query, .. } => f.write_str(query),
        }
    }
}

/// A rule as created through the API.
#[derive(Debug, Clone, PartialEq)]
pub struct RuleSpec {
    /// Identifier: 1..=32 of `[A-Za-z0-9_.-]`.
    pub id: String,
    /// What the rule is for, shown to operators.
    pub description: String,
    /// Severity of the events it raises.
    pub severity: Severity,
    /// Kind of the events it raises.
    pub kind: EventKind,
    /// What it checks.
    pub condition: Condition,
}

/// A rule as listed: its spec and whether it is enabled or built in.
#[derive(Debug, Clone, PartialEq)]
pub struct RuleInfo {
    /// The rule.
    pub spec: RuleSpec,
    /// Disabled rules are kept but never run.
    pub enabled: bool,
    /// Built-in rules can be disabled but not deleted.
    pub built_in: bool,
}

/// Longest rule identifier: keeps generated event identifiers within 64 bytes.
pub const MAX_RULE_ID_LEN: usize = 32;

/// A rule ready to run.
pub(crate) struct Compiled {
    pub(crate) id: Arc<str>,
    pub(crate) info: RuleInfo,
    /// Parsed query of a SPARQL rule (parsed once, at creation).
    pub(crate) prepared: Option<Query>,
    /// Expanded IRIs of the properties a SPARQL rule watches.
    pub(crate) watches: Vec<String>,
}

impl fmt::Debug for Compiled {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Compiled")
            .field("info", &self.info)
            .field("watches", &self.watches)
            .finish_non_exhaustive()
    }
}

/// The rule base and its indexes.
#[derive(Debug, Default)]
pub(crate) struct Rules {
    rules: BTreeMap<String, Arc<Compiled>>,
    /// Enabled threshold rules by watched field.
    pub(crate) by_field: [Vec<Arc<Compiled>>; 9],
    /// Enabled operating-area rules.
    pub(crate) area: Vec<Arc<Compiled>>,
    /// Enabled lost-contact rules.
    pub(crate) lost_contact: Vec<Arc<Compiled>>,
    /// Enabled task-overdue rules.
    pub(crate) overdue: Vec<Arc<Compiled>>,
    /// Enabled SPARQL rules by watched property IRI.
    pub(crate) by_property: HashMap<String, Vec<Arc<Compiled>>>,
    /// Rules whose condition currently holds, per entity (vehicle id, or entity IRI).
    active: HashMap<String, HashSet<Arc<str>>>,
    seq: u32,
}

/// A SPARQL parser that knows the default prefixes ([`vocab::PREFIXES`]).
pub(crate) fn sparql_parser() -> SparqlParser {
    let mut parser = SparqlParser::new();
    for (prefix, iri) in vocab::PREFIXES {
        // The prefixes are constants known to be valid IRIs.
        if let Ok(next) = parser.clone().with_prefix(prefix, iri) {
            parser = next;
        }
    }
    parser
}

fn check_id(id: &str) -> Result<(), RuleError> {
    let ok = !id.is_empty()
        && id.len() <= MAX_RULE_ID_LEN
        && id
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || matches!(b, b'_' | b'-' | b'.'));
    if ok {
        Ok(())
    } else {
        Err(RuleError::BadId(id.to_owned()))
    }
}

/// Checks a spec and prepares what it needs to run.
pub(crate) fn compile(info: RuleInfo) -> Result<Compiled, RuleError> {
    check_id(&info.spec.id)?;
    if info.spec.description.len() > MAX_TEXT_LEN {
        return Err(RuleError::Invalid(
            "description longer than 512 bytes".into(),
        ));
    }
    let (mut prepared, mut watches) = (None, Vec::new());
    match &info.spec.condition {
        Condition::Threshold(t) if !t.value.is_finite() => {
            return Err(RuleError::Invalid("threshold must be finite".into()));
        }
        Condition::OutsideArea { polygon } => {
            if polygon.len() < 3 {
                return Err(RuleError::Invalid(
                    "an area needs at least 3 corners".into(),
                ));
            }
            for p in polygon {
                shoal_model::Validate::validate(p)
                    .map_err(|e| RuleError::Invalid(e.to_string()))?;
            }
        }
        Condition::LostContact { factor } if !(factor.is_finite() && *factor >= 1.0) => {
            return Err(RuleError::Invalid(
                "lost-contact factor must be >= 1".into(),
            ));
        }
        Condition::TaskOverdue { grace_ms } if *grace_ms < 0 => {
            return Err(RuleError::Invalid("grace must not be negative".into()));
        }
        Condition::Sparql { query, watches: w } => {
            let q = sparql_parser()
                .parse_query(query)
                .map_err(|e| RuleError::Parse(e.to_string()))?;
            if !(query.contains("?this") || query.contains("$this")) {
                return Err(RuleError::Invalid(
                    "a SPARQL rule must use ?this, the entity that changed".into(),
                ));
            }
            if matches!(q, Query::Construct { .. } | Query::Describe { .. }) {
                return Err(RuleError::Invalid(
                    "a rule must be an ASK or SELECT query".into(),
                ));
            }
            if w.is_empty() {
                return Err(RuleError::Invalid(
                    "a SPARQL rule must watch at least one property".into(),
                ));
            }
            for name in w {
                watches.push(vocab::expand(name).ok_or_else(|| {
                    RuleError::Parse(format!(
                        "watched property {name:?} is not an IRI or known prefixed name"
                    ))
                })?);
            }
            prepared = Some(q);
        }
        _ => {}
    }
    Ok(Compiled {
        id: Arc::from(info.spec.id.as_str()),
        info,
        prepared,
        watches,
    })
}

impl Rules {
    pub(crate) fn get(&self, id: &str) -> Option<&Arc<Compiled>> {
        self.rules.get(id)
    }

    pub(crate) fn list(&self) -> Vec<RuleInfo> {
        self.rules.values().map(|c| c.info.clone()).collect()
    }

    pub(crate) fn insert(&mut self, compiled: Compiled) {
        self.rules
            .insert(compiled.info.spec.id.clone(), Arc::new(compiled));
        self.reindex();
    }

    pub(crate) fn remove(&mut self, id: &str) -> Option<Arc<Compiled>> {
        let r = self.rules.remove(id);
        for set in self.active.values_mut() {
            set.remove(id);
        }
        self.reindex();
        r
    }

    /// Rebuilds the indexes; rules change rarely, so simplicity beats incremental upkeep.
    fn reindex(&mut self) {
        let mut by_field: [Vec<Arc<Compiled>>; 9] = Default::default();
        let (mut area, mut lost, mut overdue) = (Vec::new(), Vec::new(), Vec::new());
        let mut by_property: HashMap<String, Vec<Arc<Compiled>>> = HashMap::new();
        for r in self.rules.values().filter(|r| r.info.enabled) {
            match &r.info.spec.condition {
                Condition::Threshold(t) => by_field[t.field.index()].push(Arc::clone(r)),
                Condition::OutsideArea { .. } => area.push(Arc::clone(r)),
                Condition::LostContact { .. } => lost.push(Arc::clone(r)),
                Condition::TaskOverdue { .. } => overdue.push(Arc::clone(r)),
                Condition::Sparql { .. } => {
                    for w in &r.watches {
                        by_property
                            .entry(w.clone())
                            .or_default()
                            .push(Arc::clone(r));
                    }
                }
            }
        }
        (
            self.by_field,
            self.area,
            self.lost_contact,
            self.overdue,
            self.by_property,
        ) = (by_field, area, lost, overdue, by_property);
    }

    /// Records whether `rule`'s condition holds for `entity`; true when it just became true.
    pub(crate) fn edge(&mut self, entity: &str, rule: &Arc<str>, holds: bool) -> bool {
        if holds {
            match self.active.get_mut(entity) {
                Some(set) => set.insert(Arc::clone(rule)),
                None => {
                    self.active
                        .insert(entity.to_owned(), HashSet::from([Arc::clone(rule)]));
                    true
                }
            }
        } else {
            if let Some(set) = self.active.get_mut(entity) {
                set.remove(rule);
                if set.is_empty() {
                    self.active.remove(entity);
                }
            }
            false
        }
    }

    /// True when `rule` currently holds for `entity`.
    pub(crate) fn is_active(&self, entity: &str, rule: &str) -> bool {
        self.active.get(entity).is_some_and(|s| s.contains(rule))
    }

    /// Forgets every active condition of `entity` (it was deleted).
    pub(crate) fn forget(&mut self, entity: &str) {
        self.active.remove(entity);
    }

    /// The event a firing produces.
    pub(crate) fn event(
        &mut self,
        rule: &Compiled,
        timestamp_ms: i64,
        vehicle_id: &str,
        task_id: &str,
        text: &str,
    ) -> Event {
        self.seq = self.seq.wrapping_add(1);
        let mut text = format!("{} (rule {})", text, rule.id);
        if text.len() > MAX_TEXT_LEN {
            let mut cut = MAX_TEXT_LEN;
            while !text.is_char_boundary(cut) {
                cut -= 1;
            }
            text.truncate(cut);
        }
        Event {
            // rule id ≤ 32 + '-' + 13-digit ms + '-' + ≤ 10-digit seq ≤ 57 bytes.
            event_id: format!("{}-{}-{}", rule.id, timestamp_ms, self.seq),
            timestamp_ms,
            severity: rule.info.spec.severity,
            kind: rule.info.spec.kind,
            vehicle_id: vehicle_id.to_owned(),
            task_id: task_id.to_owned(),
            text,
        }
    }
}

/// True when `p` lies outside `polygon` ([`shoal_model::geo::inside`]); an area crossing
/// the antimeridian must be split by the operator.
pub fn outside(polygon: &[GeoPoint], lat: f64, lon: f64) -> bool {
    !shoal_model::geo::inside(polygon, lat, lon)
}

/// Identifiers of the built-in rules.
///
/// None watches contact: the station's Vehicle Register owns contact and raises its own
/// CommLost alarm, so a built-in lost-contact rule would only raise it twice.
pub mod builtin {
    /// Battery below the configured threshold.
    pub const LOW_BATTERY: &str = "builtin.low_battery";
    /// Outside the configured operating area.
    pub const OUT_OF_AREA: &str = "builtin.out_of_area";
    /// Task still active after its deadline.
    pub const TASK_OVERDUE: &str = "builtin.task_overdue";
    /// A surface vehicle's closest approach to an AIS target under the configured distance.
    pub const COLLISION_RISK: &str = "builtin.collision_risk";
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(lat: f64, lon: f64) -> GeoPoint {
        GeoPoint {
            latitude_deg: lat,
            longitude_deg: lon,
        }
    }

    #[test]
    fn thresholds_parse_from_text() {
        let t: Threshold = "battery_pct < 20".parse().unwrap();
        assert_eq!(
            (t.field, t.op, t.value),
            (StateField::Battery, Comparison::Lt, 20.0)
        );
        let t: Threshold = "depth>=300.5".parse().unwrap();
        assert_eq!(
            (t.field, t.op, t.value),
            (StateField::Depth, Comparison::Ge, 300.5)
        );
        assert_eq!(t.to_string(), "depth_m >= 300.5");
    }

    #[test]
    fn bad_thresholds_say_what_is_wrong() {
        let e = "fuel < 3".parse::<Threshold>().unwrap_err().to_string();
        assert!(e.contains("unknown state field \"fuel\""), "{e}");
        let e = "battery_pct < lots"
            .parse::<Threshold>()
            .unwrap_err()
            .to_string();
        assert!(e.contains("not a number"), "{e}");
        assert!("battery_pct == 3".parse::<Threshold>().is_err());
    }

    #[test]
    fn point_in_polygon() {
        let square = [p(0.0, 0.0), p(0.0, 1.0), p(1.0, 1.0), p(1.0, 0.0)];
        assert!(!outside(&square, 0.5, 0.5));
        assert!(outside(&square, 1.5, 0.5));
        assert!(outside(&square, 0.5, -0.1));
    }

    #[test]
    fn a_sparql_rule_that_does_not_parse_is_a_clear_error() {
        let info = RuleInfo {
            spec: RuleSpec {
                id: "bad".into(),
                description: String::new(),
                severity: Severity::Warning,
                kind: EventKind::Rule,
                condition: Condition::Sparql {
                    query: "ASK { ?this shoal:batteryLevel ?b FILTER(?b < }".into(),
                    watches: vec!["shoal:batteryLevel".into()],
                },
            },
            enabled: true,
            built_in: false,
        };
        let e = compile(info).unwrap_err();
        assert!(matches!(e, RuleError::Parse(_)), "{e:?}");
        assert!(e.to_string().starts_with("rule does not parse:"), "{e}");
    }

    #[test]
    fn construct_rules_and_rules_without_this_are_refused() {
        let mk = |query: &str| RuleInfo {
            spec: RuleSpec {
                id: "r".into(),
                description: String::new(),
                severity: Severity::Info,
                kind: EventKind::Rule,
                condition: Condition::Sparql {
                    query: query.into(),
                    watches: vec!["shoal:depth".into()],
                },
            },
            enabled: true,
            built_in: false,
        };
        assert!(matches!(
            compile(mk("CONSTRUCT { ?this ?p ?o } WHERE { ?this ?p ?o }")),
            Err(RuleError::Invalid(_))
        ));
        assert!(matches!(
            compile(mk("ASK { ?s ?p ?o }")),
            Err(RuleError::Invalid(_))
        ));
        assert!(compile(mk("ASK { ?this shoal:depth ?d FILTER(?d > 100) }")).is_ok());
    }

    #[test]
    fn rule_ids_are_checked() {
        assert!(check_id("low-battery.2").is_ok());
        assert!(
            check_id("").is_err() && check_id("a b").is_err() && check_id(&"x".repeat(33)).is_err()
        );
    }
}
