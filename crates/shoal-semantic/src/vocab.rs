//! IRIs of the Shoal ontology and of the individuals and graphs the store writes.
//!
//! Everything the code names lives here so that the namespaces can move in one place.
//! The namespaces sit under `example.invalid` (like the workspace's repository URL) until
//! the project owns a persistent domain; changing them changes the IRIs in exports.

use oxrdf::vocab::xsd;
use oxrdf::{Literal, NamedNode};
use shoal_model::datetime::format_utc;

/// Namespace of the Shoal ontology (classes and properties), prefix `shoal:`.
pub const NS: &str = "https://example.invalid/shoal/ontology#";
/// Namespace of individuals (vehicles, tasks, events, ...) and named graphs.
pub const ID: &str = "https://example.invalid/shoal/id/";
/// W3C SOSA namespace, prefix `sosa:`.
pub const SOSA: &str = "http://www.w3.org/ns/sosa/";
/// W3C SSN namespace, prefix `ssn:`.
pub const SSN: &str = "http://www.w3.org/ns/ssn/";
/// W3C WGS84 geo namespace, prefix `geo:`.
pub const GEO: &str = "http://www.w3.org/2003/01/geo/wgs84_pos#";
/// OGC GeoSPARQL namespace, prefix `geosparql:`.
pub const GEOSPARQL: &str = "http://www.opengis.net/ont/geosparql#";
/// RDF namespace.
pub const RDF: &str = "http://www.w3.org/1999/02/22-rdf-syntax-ns#";
/// RDFS namespace.
pub const RDFS: &str = "http://www.w3.org/2000/01/rdf-schema#";
/// OWL namespace.
pub const OWL: &str = "http://www.w3.org/2002/07/owl#";
/// XSD namespace.
pub const XSD: &str = "http://www.w3.org/2001/XMLSchema#";

/// Prefixes every query may use without declaring them, and that exports declare.
pub const PREFIXES: [(&str, &str); 10] = [
    ("shoal", NS),
    ("id", ID),
    ("sosa", SOSA),
    ("ssn", SSN),
    ("geo", GEO),
    ("geosparql", GEOSPARQL),
    ("rdf", RDF),
    ("rdfs", RDFS),
    ("owl", OWL),
    ("xsd", XSD),
];

/// Named graph holding the ontology and the vendored standard vocabularies.
pub const GRAPH_ONTOLOGY: &str = "https://example.invalid/shoal/id/graph/ontology";
/// Named graph holding the asserted live model (vehicles, state, tasks, events, ...).
pub const GRAPH_MODEL: &str = "https://example.invalid/shoal/id/graph/model";
/// Named graph holding every derived (inferred) fact not asserted elsewhere.
pub const GRAPH_INFERRED: &str = "https://example.invalid/shoal/id/graph/inferred";

/// An IRI built from trusted parts (constants and validated identifiers).
///
/// Identifiers reaching this point passed `shoal_model::Validate` (only `[A-Za-z0-9_.-]`),
/// so the IRI is always valid; `new_unchecked` avoids re-parsing on the hot path.
pub(crate) fn iri(s: impl Into<String>) -> NamedNode {
    NamedNode::new_unchecked(s)
}

/// A term of the Shoal ontology, e.g. `shoal("Vehicle")`.
pub(crate) fn shoal(local: &str) -> NamedNode {
    iri(format!("{NS}{local}"))
}

/// A term of another namespace, e.g. `ns(GEO, "lat")`.
pub(crate) fn ns(namespace: &str, local: &str) -> NamedNode {
    iri(format!("{namespace}{local}"))
}

/// `rdf:type`.
pub(crate) fn rdf_type() -> NamedNode {
    ns(RDF, "type")
}

/// Expands `prefix:local` with [`PREFIXES`]; full IRIs (`<...>` or `http...`) pass through.
pub fn expand(name: &str) -> Option<String> {
    let name = name.trim();
    if let Some(inner) = name.strip_prefix('<').and_then(|n| n.strip_suffix('>')) {
        return Some(inner.to_owned());
    }
    if name.starts_with("http://") || name.starts_with("https://") || name.starts_with("urn:") {
        return Some(name.to_owned());
    }
    let (prefix, local) = name.split_once(':')?;
    PREFIXES
        .iter()
        .find(|(p, _)| *p == prefix)
        .map(|(_, namespace)| format!("{namespace}{local}"))
}

/// The kind of entity a set of facts describes; with an identifier it is the unit the
/// store writes and re-infers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub(crate) enum EntityKind {
    /// The ontology (one entity).
    Ontology,
    /// A vehicle's registration (announcement) facts.
    Vehicle,
    /// A vehicle's availability.
    Availability,
    /// A task and its state.
    Task,
    /// An event.
    Event,
    /// The latest observation of one property by one vehicle.
    Observation,
    /// A rule.
    Rule,
    /// A vessel known from AIS.
    TrafficTarget,
    /// A surface vehicle's encounter with an AIS target (closest point of approach).
    Encounter,
}

/// IRI of a vehicle.
pub fn vehicle_iri(vehicle_id: &str) -> NamedNode {
    iri(format!("{ID}vehicle/{vehicle_id}"))
}

/// IRI of a task.
pub fn task_iri(task_id: &str) -> NamedNode {
    iri(format!("{ID}task/{task_id}"))
}

/// IRI of a mission.
pub fn mission_iri(mission_id: &str) -> NamedNode {
    iri(format!("{ID}mission/{mission_id}"))
}

/// IRI of an event.
pub fn event_iri(event_id: &str) -> NamedNode {
    iri(format!("{ID}event/{event_id}"))
}

/// IRI of the latest observation of `property` by `vehicle_id`.
pub fn observation_iri(vehicle_id: &str, property: &str) -> NamedNode {
    iri(format!("{ID}observation/{vehicle_id}/{property}"))
}

/// IRI of a vessel known from AIS, by its MMSI.
pub fn traffic_iri(mmsi: u32) -> NamedNode {
    iri(format!("{ID}traffic/{mmsi}"))
}

/// IRI of a vehicle's encounter with an AIS target.
pub fn encounter_iri(vehicle_id: &str, mmsi: u32) -> NamedNode {
    iri(format!("{ID}encounter/{vehicle_id}/{mmsi}"))
}

/// IRI of a rule.
pub fn rule_iri(rule_id: &str) -> NamedNode {
    iri(format!("{ID}rule/{rule_id}"))
}

/// An `xsd:double` literal.
pub(crate) fn double(v: f64) -> Literal {
    Literal::from(v)
}

/// An `xsd:dateTime` literal (UTC) for milliseconds since the Unix epoch: the model's
/// timestamp text, `YYYY-MM-DDThh:mm:ss.sssZ`, is one.
pub(crate) fn date_time(ms: i64) -> Literal {
    Literal::new_typed_literal(format_utc(ms), xsd::DATE_TIME)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn date_times_format_as_utc_iso_8601() {
        assert_eq!(format_utc(0), "1970-01-01T00:00:00.000Z");
        assert_eq!(format_utc(1_700_000_000_123), "2023-11-14T22:13:20.123Z");
        assert_eq!(format_utc(951_782_400_000), "2000-02-29T00:00:00.000Z");
    }

    #[test]
    fn prefixed_names_expand_and_unknown_prefixes_do_not() {
        assert_eq!(
            expand("shoal:batteryLevel").as_deref(),
            Some("https://example.invalid/shoal/ontology#batteryLevel")
        );
        assert_eq!(expand("<http://x/y>").as_deref(), Some("http://x/y"));
        assert_eq!(expand("nope:x"), None);
    }
}
