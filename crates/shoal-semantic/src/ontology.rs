//! The Common Information Model: the ontology files and the vocabulary the code maps through.
//!
//! The Turtle files are compiled into the binary (`include_str!`) because stations run
//! without network and must not depend on a working directory.

use std::collections::HashMap;

use oxrdf::{GraphNameRef, NamedNode, NamedOrBlankNode, Quad, Term};
use oxrdfio::{RdfFormat, RdfParser};

use crate::error::StoreError;
use crate::reasoner::TBox;
use crate::vocab::{self, GRAPH_ONTOLOGY, shoal};

/// Shoal's own ontology (`ontology/shoal.ttl`).
pub const SHOAL_TTL: &str = include_str!("../../../ontology/shoal.ttl");
/// The W3C SOSA ontology as vendored in `ontology/vendor/sosa.ttl`.
pub const SOSA_TTL: &str = include_str!("../../../ontology/vendor/sosa.ttl");
/// The W3C SSN ontology as vendored in `ontology/vendor/ssn.ttl`.
pub const SSN_TTL: &str = include_str!("../../../ontology/vendor/ssn.ttl");
/// The W3C WGS84 geo vocabulary as vendored in `ontology/vendor/wgs84_pos.ttl`.
pub const WGS84_TTL: &str = include_str!("../../../ontology/vendor/wgs84_pos.ttl");

/// The ontology files loaded into the ontology graph, by name.
pub const FILES: [(&str, &str); 4] = [
    ("shoal.ttl", SHOAL_TTL),
    ("vendor/sosa.ttl", SOSA_TTL),
    ("vendor/ssn.ttl", SSN_TTL),
    ("vendor/wgs84_pos.ttl", WGS84_TTL),
];

/// Parses every ontology file into quads of the ontology graph.
pub(crate) fn ontology_quads() -> Result<Vec<Quad>, StoreError> {
    let graph = vocab::iri(GRAPH_ONTOLOGY);
    let mut quads = Vec::new();
    for (name, text) in FILES {
        let parser = RdfParser::from_format(RdfFormat::Turtle)
            .without_named_graphs()
            .with_default_graph(graph.clone());
        for quad in parser.for_slice(text.as_bytes()) {
            quads.push(quad.map_err(|e| StoreError::Ontology {
                file: name.to_owned(),
                message: e.to_string(),
            })?);
        }
    }
    Ok(quads)
}

/// Which family a `shoal:code` belongs to; the same code may name a task kind and a capability.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(crate) enum Family {
    /// Subclasses of `shoal:Vehicle`.
    VehicleClass,
    /// Subclasses of `shoal:Sensor`.
    SensorClass,
    /// Subclasses of `shoal:CommunicationLink`.
    LinkClass,
    /// Subclasses of `shoal:Task`.
    TaskClass,
    /// Subclasses of `shoal:Event`.
    EventClass,
    /// Individuals of `shoal:Capability` (or a subclass).
    Capability,
    /// Individuals of `shoal:TaskState` (or a subclass).
    TaskState,
    /// Individuals of `shoal:Severity`.
    Severity,
}

impl Family {
    const ALL: [Self; 8] = [
        Self::VehicleClass,
        Self::SensorClass,
        Self::LinkClass,
        Self::TaskClass,
        Self::EventClass,
        Self::Capability,
        Self::TaskState,
        Self::Severity,
    ];

    fn root(self) -> &'static str {
        match self {
            Self::VehicleClass => "Vehicle",
            Self::SensorClass => "Sensor",
            Self::LinkClass => "CommunicationLink",
            Self::TaskClass => "Task",
            Self::EventClass => "Event",
            Self::Capability => "Capability",
            Self::TaskState => "TaskState",
            Self::Severity => "Severity",
        }
    }

    fn is_class_family(self) -> bool {
        !matches!(self, Self::Capability | Self::TaskState | Self::Severity)
    }
}

/// Maps wire codes (`"sidescan_sonar"`, `"running"`) to ontology terms, read from `shoal:code`.
#[derive(Debug, Clone, Default)]
pub(crate) struct Vocabulary {
    by_code: HashMap<(Family, String), NamedNode>,
}

impl Vocabulary {
    /// Reads every `shoal:code` of the ontology graph, sorted into families by the T-box.
    pub(crate) fn from_quads(quads: &[Quad], tbox: &TBox) -> Self {
        let code = shoal("code");
        let rdf_type = vocab::rdf_type();
        let mut types: HashMap<&NamedNode, Vec<&NamedNode>> = HashMap::new();
        for q in quads {
            if let (NamedOrBlankNode::NamedNode(s), Term::NamedNode(o)) = (&q.subject, &q.object)
                && q.predicate == rdf_type
            {
                types.entry(s).or_default().push(o);
            }
        }
        let mut by_code = HashMap::new();
        for q in quads {
            let (NamedOrBlankNode::NamedNode(s), Term::Literal(l)) = (&q.subject, &q.object) else {
                continue;
            };
            if q.predicate != code {
                continue;
            }
            for family in Family::ALL {
                let root = shoal(family.root());
                let member = if family.is_class_family() {
                    tbox.is_subclass_of(s, &root)
                } else {
                    types
                        .get(s)
                        .is_some_and(|ts| ts.iter().any(|t| tbox.is_subclass_of(t, &root)))
                };
                if member {
                    by_code
                        .entry((family, l.value().to_owned()))
                        .or_insert_with(|| s.clone());
                }
            }
        }
        Self { by_code }
    }

    /// The term a code names in a family, if the ontology defines one.
    pub(crate) fn lookup(&self, family: Family, code: &str) -> Option<&NamedNode> {
        self.by_code.get(&(family, code.to_owned()))
    }
}

/// Parses the ontology and returns its quads, T-box and vocabulary.
pub(crate) fn load() -> Result<(TBox, Vocabulary, Vec<Quad>), StoreError> {
    let quads = ontology_quads()?;
    let tbox = TBox::from_quads(&quads);
    let vocabulary = Vocabulary::from_quads(&quads, &tbox);
    Ok((tbox, vocabulary, quads))
}

/// True when `graph` is the ontology graph.
pub(crate) fn is_ontology_graph(graph: GraphNameRef<'_>) -> bool {
    matches!(graph, GraphNameRef::NamedNode(n) if n.as_str() == GRAPH_ONTOLOGY)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_ontology_file_parses() {
        let quads = ontology_quads().unwrap();
        // shoal.ttl alone has ~700 triples, the vendored files ~900.
        assert!(quads.len() > 1500, "only {} quads", quads.len());
    }

    #[test]
    fn codes_map_to_ontology_terms_by_family() {
        let quads = ontology_quads().unwrap();
        let tbox = TBox::from_quads(&quads);
        let v = Vocabulary::from_quads(&quads, &tbox);
        let local = |f, c| {
            v.lookup(f, c)
                .map(|n| n.as_str().trim_start_matches(vocab::NS).to_owned())
        };
        assert_eq!(
            local(Family::SensorClass, "sss").as_deref(),
            Some("SidescanSonar")
        );
        assert_eq!(
            local(Family::VehicleClass, "glider").as_deref(),
            Some("Glider")
        );
        assert_eq!(
            local(Family::Capability, "hold").as_deref(),
            Some("HoldPosition")
        );
        assert_eq!(
            local(Family::TaskClass, "hold").as_deref(),
            Some("HoldTask")
        );
        assert_eq!(
            local(Family::TaskState, "running").as_deref(),
            Some("Running")
        );
        assert_eq!(
            local(Family::EventClass, "low_battery").as_deref(),
            Some("LowBattery")
        );
        assert_eq!(
            local(Family::LinkClass, "acoustic").as_deref(),
            Some("AcousticLink")
        );
        assert_eq!(local(Family::Severity, "alarm").as_deref(), Some("Alarm"));
        assert_eq!(local(Family::SensorClass, "no_such_sensor"), None);
    }

    #[test]
    fn the_ontology_uses_the_official_sosa_iris() {
        let quads = ontology_quads().unwrap();
        let sosa_platform = vocab::ns(vocab::SOSA, "Platform");
        let tbox = TBox::from_quads(&quads);
        assert!(tbox.is_subclass_of(&shoal("AUV"), &sosa_platform));
        // And the vendored SOSA file itself declares the class.
        assert!(
            quads
                .iter()
                .any(|q| q.subject == sosa_platform.clone().into())
        );
    }
}
