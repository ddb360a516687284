//! The Semantic Reasoner: RDFS-lite closure and capability inference.
//!
//! The T-box (class and property hierarchy, domains, ranges, `shoal:enablesCapability`)
//! comes from the ontology graph and changes only when the ontology does, so its
//! transitive closures are computed once ([`TBox::from_quads`]). With a fixed, closed
//! T-box every RDFS rule that the reasoner applies to instance data (rdfs2 domain, rdfs3
//! range, rdfs7 sub-property, rdfs9 sub-class) derives facts from *one* asserted triple,
//! so the closure of an entity's graph depends on that graph alone. That is what lets the
//! store recompute derived facts per entity when the entity changes, instead of
//! re-reasoning over the whole model; capability inference needs two triples of the same
//! vehicle graph (`sosa:hosts` and the sensor's `rdf:type`), which are both there.
//!
//! Not derived, on purpose: facts about literals (`"1.5" rdf:type xsd:double`, which RDF
//! cannot state) and the reflexive `C rdfs:subClassOf C` triples, which no query needs.

use std::collections::BTreeSet;

// Fx: these maps are hashed on every entity write (IRIs and whole triples), where
// SipHash's resistance to chosen keys buys nothing (the keys are the ontology's and the
// entity's own) and cost a tenth of a write burst's time.
use rustc_hash::{FxHashMap as HashMap, FxHashSet as HashSet};

use oxrdf::{NamedNode, NamedOrBlankNode, Quad, Term, Triple};

use crate::vocab::{self, RDFS, SOSA, shoal};

/// The closed terminology: super-classes, super-properties, domains and ranges.
#[derive(Debug, Clone, Default)]
pub struct TBox {
    /// Class → its strict super-classes (transitive).
    super_classes: HashMap<NamedNode, Vec<NamedNode>>,
    /// Property → its strict super-properties (transitive).
    super_properties: HashMap<NamedNode, Vec<NamedNode>>,
    /// Property → every class its subjects belong to (domains of it and its supers, closed).
    domains: HashMap<NamedNode, Vec<NamedNode>>,
    /// Property → every class its (non-literal) objects belong to.
    ranges: HashMap<NamedNode, Vec<NamedNode>>,
    /// Sensor class → capabilities it enables (inherited by sub-classes).
    enables: HashMap<NamedNode, Vec<NamedNode>>,
}

/// Strict transitive closure of a relation given as direct edges.
fn closure(direct: &HashMap<NamedNode, Vec<NamedNode>>) -> HashMap<NamedNode, Vec<NamedNode>> {
    let mut out = HashMap::with_capacity_and_hasher(direct.len(), Default::default());
    for start in direct.keys() {
        // BTreeSet keeps the output deterministic, which keeps exports diffable.
        let mut seen = BTreeSet::new();
        let mut stack: Vec<&NamedNode> = direct
            .get(start)
            .map(|v| v.iter().collect())
            .unwrap_or_default();
        while let Some(n) = stack.pop() {
            if n != start
                && seen.insert(n.clone())
                && let Some(next) = direct.get(n)
            {
                stack.extend(next.iter());
            }
        }
        out.insert(start.clone(), seen.into_iter().collect());
    }
    out
}

impl TBox {
    /// Builds and closes the T-box from the ontology's quads (graph names are ignored).
    pub fn from_quads(quads: &[Quad]) -> Self {
        let (sub_class, sub_prop) = (
            vocab::ns(RDFS, "subClassOf"),
            vocab::ns(RDFS, "subPropertyOf"),
        );
        let (domain, range) = (vocab::ns(RDFS, "domain"), vocab::ns(RDFS, "range"));
        let enables = shoal("enablesCapability");
        let mut edges: [HashMap<NamedNode, Vec<NamedNode>>; 5] = Default::default();
        for q in quads {
            // Blank-node classes (OWL restrictions in SSN) are outside RDFS-lite: skipped.
            let (NamedOrBlankNode::NamedNode(s), Term::NamedNode(o)) = (&q.subject, &q.object)
            else {
                continue;
            };
            let slot = if q.predicate == sub_class {
                0
            } else if q.predicate == sub_prop {
                1
            } else if q.predicate == domain {
                2
            } else if q.predicate == range {
                3
            } else if q.predicate == enables {
                4
            } else {
                continue;
            };
            edges[slot].entry(s.clone()).or_default().push(o.clone());
        }
        let [sc, sp, dom, ran, ena] = edges;
        let super_classes = closure(&sc);
        let super_properties = closure(&sp);
        let mut tbox = Self {
            super_classes,
            super_properties,
            ..Self::default()
        };
        // Close domains/ranges over super-properties (rdfs7 then rdfs2/3) and super-classes (rdfs9).
        let properties: HashSet<&NamedNode> =
            dom.keys().chain(ran.keys()).chain(sp.keys()).collect();
        for p in properties {
            for (direct, target) in [(&dom, &mut tbox.domains), (&ran, &mut tbox.ranges)] {
                let mut classes = BTreeSet::new();
                for q in
                    std::iter::once(p).chain(tbox.super_properties.get(p).into_iter().flatten())
                {
                    for c in direct.get(q).into_iter().flatten() {
                        classes.insert(c.clone());
                        classes.extend(tbox.super_classes.get(c).into_iter().flatten().cloned());
                    }
                }
                if !classes.is_empty() {
                    target.insert(p.clone(), classes.into_iter().collect());
                }
            }
        }
        // A sensor class enables what it states plus what its super-classes state.
        let classes: HashSet<&NamedNode> = sc.keys().chain(ena.keys()).collect();
        for c in classes {
            let mut caps = BTreeSet::new();
            for k in std::iter::once(c).chain(tbox.super_classes.get(c).into_iter().flatten()) {
                caps.extend(ena.get(k).into_iter().flatten().cloned());
            }
            if !caps.is_empty() {
                tbox.enables.insert(c.clone(), caps.into_iter().collect());
            }
        }
        tbox
    }

    /// True when `class` is `ancestor` or one of its (transitive) sub-classes.
    pub fn is_subclass_of(&self, class: &NamedNode, ancestor: &NamedNode) -> bool {
        class == ancestor
            || self
                .super_classes
                .get(class)
                .is_some_and(|s| s.contains(ancestor))
    }

    /// Strict super-classes of `class`.
    pub fn super_classes(&self, class: &NamedNode) -> &[NamedNode] {
        self.super_classes.get(class).map_or(&[], Vec::as_slice)
    }

    /// The T-box's own entailments: the transitive `rdfs:subClassOf`/`rdfs:subPropertyOf` edges.
    pub fn schema_closure(&self) -> Vec<Triple> {
        let (sub_class, sub_prop) = (
            vocab::ns(RDFS, "subClassOf"),
            vocab::ns(RDFS, "subPropertyOf"),
        );
        let mut out = Vec::new();
        for (map, p) in [
            (&self.super_classes, &sub_class),
            (&self.super_properties, &sub_prop),
        ] {
            for (s, supers) in map {
                for o in supers {
                    out.push(Triple::new(s.clone(), p.clone(), o.clone()));
                }
            }
        }
        out
    }

    /// Facts derived from `asserted` (one entity's graph) and not already asserted in it.
    ///
    /// Output order is deterministic for a given input order.
    pub fn infer(&self, asserted: &[Triple]) -> Vec<Triple> {
        let rdf_type = vocab::rdf_type();
        let hosts = vocab::ns(SOSA, "hosts");
        let has_capability = shoal("hasCapability");
        let present: HashSet<&Triple> = asserted.iter().collect();
        let mut seen: HashSet<Triple> = HashSet::default();
        let mut out = Vec::new();
        let mut add = |t: Triple, out: &mut Vec<Triple>| {
            if !present.contains(&t) && seen.insert(t.clone()) {
                out.push(t);
            }
        };
        // Capability inference first, so that the RDFS pass below also closes its output.
        let mut extra = Vec::new();
        let mut types_of: HashMap<&NamedOrBlankNode, Vec<&NamedNode>> = HashMap::default();
        for t in asserted {
            if let (true, Term::NamedNode(c)) = (t.predicate == rdf_type, &t.object) {
                types_of.entry(&t.subject).or_default().push(c);
            }
        }
        for t in asserted {
            if t.predicate != hosts {
                continue;
            }
            let sensor = match &t.object {
                Term::NamedNode(n) => NamedOrBlankNode::NamedNode(n.clone()),
                Term::BlankNode(b) => NamedOrBlankNode::BlankNode(b.clone()),
                Term::Literal(_) => continue,
            };
            for class in types_of.get(&sensor).into_iter().flatten() {
                for cap in self.enables.get(*class).into_iter().flatten() {
                    extra.push(Triple::new(
                        t.subject.clone(),
                        has_capability.clone(),
                        cap.clone(),
                    ));
                }
            }
        }
        for t in &extra {
            add(t.clone(), &mut out);
        }
        for t in asserted.iter().chain(extra.iter()) {
            for p in self
                .super_properties
                .get(&t.predicate)
                .into_iter()
                .flatten()
            {
                add(
                    Triple::new(t.subject.clone(), p.clone(), t.object.clone()),
                    &mut out,
                );
            }
            for c in self.domains.get(&t.predicate).into_iter().flatten() {
                add(
                    Triple::new(t.subject.clone(), rdf_type.clone(), c.clone()),
                    &mut out,
                );
            }
            let object = match &t.object {
                Term::NamedNode(n) => Some(NamedOrBlankNode::NamedNode(n.clone())),
                Term::BlankNode(b) => Some(NamedOrBlankNode::BlankNode(b.clone())),
                Term::Literal(_) => None,
            };
            if let Some(o) = &object {
                for c in self.ranges.get(&t.predicate).into_iter().flatten() {
                    add(
                        Triple::new(o.clone(), rdf_type.clone(), c.clone()),
                        &mut out,
                    );
                }
            }
            if t.predicate == rdf_type
                && let Term::NamedNode(c) = &t.object
            {
                for sup in self.super_classes(c) {
                    add(
                        Triple::new(t.subject.clone(), rdf_type.clone(), sup.clone()),
                        &mut out,
                    );
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ontology::ontology_quads;
    use crate::vocab::vehicle_iri;

    fn tbox() -> TBox {
        TBox::from_quads(&ontology_quads().unwrap())
    }

    #[test]
    fn sub_class_closure_is_transitive() {
        let t = tbox();
        assert!(t.is_subclass_of(&shoal("SyntheticApertureSonar"), &shoal("Sensor")));
        assert!(t.is_subclass_of(&shoal("Glider"), &shoal("Vehicle")));
        assert!(!t.is_subclass_of(&shoal("Vehicle"), &shoal("Glider")));
    }

    #[test]
    fn a_vehicle_hosting_a_sidescan_sonar_can_do_a_sidescan_survey() {
        let t = tbox();
        let v = vehicle_iri("auv-1");
        let s = vocab::iri(format!("{}/sensor/sss", v.as_str()));
        let asserted = vec![
            Triple::new(v.clone(), vocab::rdf_type(), shoal("AUV")),
            Triple::new(v.clone(), vocab::ns(SOSA, "hosts"), s.clone()),
            // A sub-class of SidescanSonar: the capability is inherited.
            Triple::new(s, vocab::rdf_type(), shoal("SyntheticApertureSonar")),
        ];
        let derived = t.infer(&asserted);
        let cap = Triple::new(v.clone(), shoal("hasCapability"), shoal("SidescanSurvey"));
        assert!(derived.contains(&cap), "{derived:#?}");
        // The derived capability is itself closed: its range types the capability.
        assert!(derived.contains(&Triple::new(
            shoal("SidescanSurvey"),
            vocab::rdf_type(),
            shoal("Capability")
        )));
        assert!(derived.contains(&Triple::new(v, vocab::rdf_type(), shoal("Vehicle"))));
    }

    #[test]
    fn sub_properties_domains_and_ranges_apply() {
        let t = tbox();
        let v = vehicle_iri("usv-1");
        let asserted = vec![Triple::new(
            v.clone(),
            shoal("declaresCapability"),
            shoal("Navigation"),
        )];
        let derived = t.infer(&asserted);
        assert!(derived.contains(&Triple::new(
            v.clone(),
            shoal("hasCapability"),
            shoal("Navigation")
        )));
        assert!(derived.contains(&Triple::new(v, vocab::rdf_type(), shoal("Platform"))));
        assert!(derived.contains(&Triple::new(
            shoal("Navigation"),
            vocab::rdf_type(),
            shoal("Capability")
        )));
    }

    #[test]
    fn ranges_of_datatype_properties_type_no_literal() {
        // shoal:batteryLevel has range xsd:double; RDF cannot type the literal, so nothing
        // is derived about it (the only output is about the vehicle).
        let t = tbox();
        let v = vehicle_iri("usv-1");
        let asserted = vec![Triple::new(
            v.clone(),
            shoal("batteryLevel"),
            oxrdf::Literal::from(50.0),
        )];
        let derived = t.infer(&asserted);
        assert!(!derived.is_empty());
        assert!(
            derived.iter().all(|d| d.subject == v.clone().into()),
            "{derived:#?}"
        );
    }
}
