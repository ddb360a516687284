//! The model's storage: an integer-coded, hash-indexed in-memory quad set that
//! [`spareval`] (Oxigraph's SPARQL evaluator) queries through [`QueryableDataset`].
//!
//! spareval leaves storage to its user; this is ours because the store's workload is a
//! small model (a few hundred thousand quads) rewritten continuously by the state
//! mirror, and queried at interactive rates:
//!
//! - Terms are interned into a reference-counted [`Dictionary`]: a quad holds four `u32`s,
//!   and a term whose last quad goes is freed, so replacing a battery value leaves
//!   nothing behind (no garbage, no compaction).
//! - Two indexes answer every pattern spareval asks for: subject → (predicate, object,
//!   graph) and predicate → object → (subject, graph). A subject's facts are few, so
//!   filtering them is cheap; an object with no predicate is looked up under each
//!   predicate (a few hundred), which is rare in queries and cheaper than a third index
//!   that every state value would have to maintain.
//! - [`Dataset`] is plain data, `Clone`: the store keeps it in an `Arc`, a query snapshot
//!   is a clone of the `Arc`, and a write while a snapshot is alive copies the dataset
//!   once, so queries never wait for writes nor see half of one. The copy is shallow:
//!   terms and index buckets are themselves behind `Arc`s, so it costs a reference-count
//!   increment per term and per bucket, and a write then copies only the buckets it
//!   changes (copy on write all the way down).

use std::hash::{Hash, Hasher};
use std::sync::Arc;

use hashbrown::HashTable;
use oxrdf::vocab::xsd;
use oxrdf::{GraphName, GraphNameRef, NamedOrBlankNode, Quad, QuadRef, Term, TermRef};
use rustc_hash::{FxHashMap, FxHasher};
use spareval::{ExpressionTerm, InternalQuad, QueryableDataset};

/// A term's number in the [`Dictionary`].
type Id = u32;

/// The default graph, which has no term: never interned, never equal to an [`Id`] in use.
const DEFAULT_GRAPH: Id = Id::MAX;

/// An interned term, shared between a dataset and its copies.
struct Entry {
    term: Term,
    /// The evaluator's form of a typed literal, parsed once: FILTERs compare numbers and
    /// dates, and would otherwise parse the lexical form at every comparison.
    expression: Option<ExpressionTerm>,
}

/// A dictionary slot in use.
#[derive(Clone)]
struct Slot {
    entry: Arc<Entry>,
    /// Quads using the term (once per position it takes in each).
    refs: u32,
}

/// Terms ↔ [`Id`]s, reference-counted by the quads that use them.
#[derive(Clone, Default)]
struct Dictionary {
    slots: Vec<Option<Slot>>,
    /// Freed ids, reused first so the slot vector stays as large as the live terms need.
    free: Vec<Id>,
    /// Ids by term; hashed with [`term_hash`] so a [`TermRef`] finds its id without
    /// building an owned term.
    ids: HashTable<Id>,
}

fn term_hash(t: TermRef<'_>) -> u64 {
    let mut h = FxHasher::default();
    match t {
        TermRef::NamedNode(n) => {
            0u8.hash(&mut h);
            n.as_str().hash(&mut h);
        }
        TermRef::BlankNode(b) => {
            1u8.hash(&mut h);
            b.as_str().hash(&mut h);
        }
        TermRef::Literal(l) => {
            2u8.hash(&mut h);
            l.value().hash(&mut h);
            l.datatype().as_str().hash(&mut h);
            l.language().hash(&mut h);
        }
    }
    h.finish()
}

impl Dictionary {
    fn slot(&self, id: Id) -> Option<&Slot> {
        self.slots.get(id as usize)?.as_ref()
    }

    fn lookup(&self, t: TermRef<'_>) -> Option<Id> {
        let slots = &self.slots;
        self.ids
            .find(term_hash(t), |&id| {
                slots[id as usize]
                    .as_ref()
                    .is_some_and(|s| s.entry.term.as_ref() == t)
            })
            .copied()
    }

    /// The term's id, interning it if new, with one more reference.
    fn acquire(&mut self, t: TermRef<'_>) -> Id {
        if let Some(id) = self.lookup(t) {
            if let Some(s) = self.slots[id as usize].as_mut() {
                s.refs += 1;
            }
            return id;
        }
        let term = t.into_owned();
        let expression = match &term {
            Term::Literal(l) if l.language().is_none() && l.datatype() != xsd::STRING => {
                Some(ExpressionTerm::from(term.clone()))
            }
            _ => None,
        };
        let slot = Slot {
            entry: Arc::new(Entry { term, expression }),
            refs: 1,
        };
        let id = match self.free.pop() {
            Some(id) => {
                self.slots[id as usize] = Some(slot);
                id
            }
            None => {
                // u32::MAX is the default graph; 4 billion live terms is far beyond memory.
                let id = Id::try_from(self.slots.len()).unwrap_or(DEFAULT_GRAPH - 1);
                self.slots.push(Some(slot));
                id
            }
        };
        let slots = &self.slots;
        self.ids.insert_unique(term_hash(t), id, |&i| {
            slots[i as usize]
                .as_ref()
                .map_or(0, |s| term_hash(s.entry.term.as_ref()))
        });
        id
    }

    /// Drops one reference; frees the term with its last one.
    fn release(&mut self, id: Id) {
        let Some(slot) = self.slots.get_mut(id as usize).and_then(Option::as_mut) else {
            return;
        };
        slot.refs -= 1;
        if slot.refs > 0 {
            return;
        }
        let hash = term_hash(slot.entry.term.as_ref());
        if let Ok(entry) = self.ids.find_entry(hash, |&i| i == id) {
            entry.remove();
        }
        self.slots[id as usize] = None;
        self.free.push(id);
    }

    fn len(&self) -> usize {
        self.slots.len() - self.free.len()
    }
}

/// A subject's facts: (predicate, object, graph). A slice, not a `Vec`, so a join probing
/// a subject reads its length from the index and touches one allocation, not two; a
/// subject's facts are few, so a change rebuilds them.
type Facts = Arc<[[Id; 3]]>;
/// The holders of a (predicate, object): (subject, graph).
type Holders = Arc<Vec<[Id; 2]>>;
/// A predicate's objects and their holders.
type ByObject = Arc<FxHashMap<Id, Holders>>;

/// Subject → its facts, as a vector indexed by the subject's id: ids are dense (the
/// dictionary reuses freed ones), so a join probing thousands of subjects pays one
/// indexed load each instead of a hash probe.
#[derive(Clone, Default)]
struct BySubject(Vec<Option<Facts>>);

impl BySubject {
    fn get(&self, s: Id) -> Option<&Facts> {
        self.0.get(s as usize)?.as_ref()
    }

    fn get_mut(&mut self, s: Id) -> Option<&mut Facts> {
        self.0.get_mut(s as usize)?.as_mut()
    }

    fn or_default(&mut self, s: Id) -> &mut Facts {
        let i = s as usize;
        if i >= self.0.len() {
            self.0.resize(i + 1, None);
        }
        self.0[i].get_or_insert_with(|| Arc::from([]))
    }

    fn remove(&mut self, s: Id) {
        if let Some(slot) = self.0.get_mut(s as usize) {
            *slot = None;
        }
        while self.0.last().is_some_and(Option::is_none) {
            self.0.pop();
        }
    }

    fn iter(&self) -> impl Iterator<Item = (Id, &Facts)> {
        self.0.iter().enumerate().filter_map(|(s, f)| {
            // The vector is never longer than the dictionary, whose ids are u32.
            Some((Id::try_from(s).ok()?, f.as_ref()?))
        })
    }
}

/// Quads as ids, indexed by subject and by predicate then object.
#[derive(Clone, Default)]
struct Index {
    /// Subject → (predicate, object, graph).
    spo: BySubject,
    /// Predicate → object → (subject, graph).
    pos: FxHashMap<Id, ByObject>,
    /// Graph → quads in it, so listing graphs needs no scan.
    graphs: FxHashMap<Id, usize>,
    len: usize,
}

impl Index {
    fn contains(&self, [s, p, o, g]: [Id; 4]) -> bool {
        self.spo.get(s).is_some_and(|v| v.contains(&[p, o, g]))
    }

    /// Adds a quad known to be absent.
    fn insert_new(&mut self, [s, p, o, g]: [Id; 4]) {
        let facts = self.spo.or_default(s);
        *facts = facts.iter().copied().chain([[p, o, g]]).collect();
        let by_o = Arc::make_mut(self.pos.entry(p).or_default());
        Arc::make_mut(by_o.entry(o).or_default()).push([s, g]);
        *self.graphs.entry(g).or_default() += 1;
        self.len += 1;
    }

    /// Removes a quad; false if it was not there.
    fn remove(&mut self, [s, p, o, g]: [Id; 4]) -> bool {
        let Some(facts) = self.spo.get_mut(s) else {
            return false;
        };
        let Some(i) = facts.iter().position(|x| *x == [p, o, g]) else {
            return false;
        };
        if facts.len() == 1 {
            self.spo.remove(s);
        } else {
            *facts = facts[..i].iter().chain(&facts[i + 1..]).copied().collect();
        }
        if let Some(by_o) = self.pos.get_mut(&p) {
            let by_o = Arc::make_mut(by_o);
            if let Some(v) = by_o.get_mut(&o) {
                // From the end: the state mirror removes values it added recently.
                if let Some(i) = v.iter().rposition(|x| *x == [s, g]) {
                    Arc::make_mut(v).swap_remove(i);
                }
                if v.is_empty() {
                    by_o.remove(&o);
                }
            }
            if by_o.is_empty() {
                self.pos.remove(&p);
            }
        }
        if let Some(n) = self.graphs.get_mut(&g) {
            *n -= 1;
            if *n == 0 {
                self.graphs.remove(&g);
            }
        }
        self.len -= 1;
        true
    }
}

/// The model's quads: a dictionary and its indexes. See the module documentation.
#[derive(Clone, Default)]
pub(crate) struct Dataset {
    dict: Dictionary,
    index: Index,
}

impl std::fmt::Debug for Dataset {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Dataset")
            .field("quads", &self.index.len)
            .field("terms", &self.dict.len())
            .finish_non_exhaustive()
    }
}

fn graph_ref(g: GraphNameRef<'_>) -> Option<TermRef<'_>> {
    match g {
        GraphNameRef::NamedNode(n) => Some(n.into()),
        GraphNameRef::BlankNode(b) => Some(b.into()),
        GraphNameRef::DefaultGraph => None,
    }
}

impl Dataset {
    /// An empty dataset.
    pub(crate) fn new() -> Self {
        Self::default()
    }

    /// The quad's ids if every term of it is known.
    fn encode(&self, q: QuadRef<'_>) -> Option<[Id; 4]> {
        let g = match graph_ref(q.graph_name) {
            Some(t) => self.dict.lookup(t)?,
            None => DEFAULT_GRAPH,
        };
        Some([
            self.dict.lookup(q.subject.into())?,
            self.dict.lookup(q.predicate.into())?,
            self.dict.lookup(q.object)?,
            g,
        ])
    }

    /// Whether the quad is in the dataset.
    pub(crate) fn contains(&self, q: QuadRef<'_>) -> bool {
        self.encode(q).is_some_and(|ids| self.index.contains(ids))
    }

    /// Adds a quad; false if it was there already.
    pub(crate) fn insert(&mut self, q: QuadRef<'_>) -> bool {
        if self.contains(q) {
            return false;
        }
        let g = match graph_ref(q.graph_name) {
            Some(t) => self.dict.acquire(t),
            None => DEFAULT_GRAPH,
        };
        let ids = [
            self.dict.acquire(q.subject.into()),
            self.dict.acquire(q.predicate.into()),
            self.dict.acquire(q.object),
            g,
        ];
        self.index.insert_new(ids);
        true
    }

    /// Removes a quad, and the terms only it used; false if it was not there.
    pub(crate) fn remove(&mut self, q: QuadRef<'_>) -> bool {
        let Some(ids) = self.encode(q) else {
            return false;
        };
        if !self.index.remove(ids) {
            return false;
        }
        for id in ids {
            if id != DEFAULT_GRAPH {
                self.dict.release(id);
            }
        }
        true
    }

    /// Number of quads.
    pub(crate) fn len(&self) -> usize {
        self.index.len
    }

    /// Number of distinct terms held (a term used by no quad is not).
    pub(crate) fn term_count(&self) -> usize {
        self.dict.len()
    }

    fn term(&self, id: Id) -> Result<&Term, DanglingId> {
        self.dict
            .slot(id)
            .map(|s| &s.entry.term)
            .ok_or(DanglingId(id))
    }

    fn decode(&self, [s, p, o, g]: [Id; 4]) -> Result<Quad, DanglingId> {
        let subject = match self.term(s)? {
            Term::NamedNode(n) => NamedOrBlankNode::from(n.clone()),
            Term::BlankNode(b) => NamedOrBlankNode::from(b.clone()),
            Term::Literal(_) => return Err(DanglingId(s)),
        };
        let Term::NamedNode(predicate) = self.term(p)? else {
            return Err(DanglingId(p));
        };
        let graph_name = match g {
            DEFAULT_GRAPH => GraphName::DefaultGraph,
            g => match self.term(g)? {
                Term::NamedNode(n) => GraphName::from(n.clone()),
                Term::BlankNode(b) => GraphName::from(b.clone()),
                Term::Literal(_) => return Err(DanglingId(g)),
            },
        };
        Ok(Quad::new(
            subject,
            predicate.clone(),
            self.term(o)?.clone(),
            graph_name,
        ))
    }

    /// Every quad, grouped by subject.
    pub(crate) fn iter(&self) -> impl Iterator<Item = Quad> + '_ {
        self.index.spo.iter().flat_map(move |(s, v)| {
            v.iter()
                .filter_map(move |&[p, o, g]| self.decode([s, p, o, g]).ok())
        })
    }
}

/// An id no term has: only possible if the dataset were changed under a query, which the
/// store's ownership rules out; reported rather than trusted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("internal error: term #{0} is not in the dictionary")]
pub(crate) struct DanglingId(Id);

/// A term as the evaluator holds it: an id, or a term the dataset does not have (a query
/// constant or a computed value). A term the dataset has is always an id, so equality of
/// `Encoded` is term equality.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub(crate) enum Encoded {
    /// A term of the dictionary.
    Id(Id),
    /// Any other term.
    Other(Arc<Term>),
}

/// Which graphs a pattern looks in, as spareval says it.
#[derive(Clone, Copy)]
enum GraphFilter {
    AnyNamed,
    Default,
    Named(Id),
}

impl GraphFilter {
    fn accepts(self, g: Id) -> bool {
        match self {
            Self::AnyNamed => g != DEFAULT_GRAPH,
            Self::Default => g == DEFAULT_GRAPH,
            Self::Named(n) => g == n,
        }
    }
}

type QuadResult = Result<InternalQuad<Encoded>, DanglingId>;

fn internal(s: Id, p: Id, o: Id, g: Id) -> QuadResult {
    Ok(InternalQuad {
        subject: Encoded::Id(s),
        predicate: Encoded::Id(p),
        object: Encoded::Id(o),
        graph_name: (g != DEFAULT_GRAPH).then_some(Encoded::Id(g)),
    })
}

/// `Ok(None)` for "any", `Ok(Some(id))` for a term the dataset has, `Err(())` for a term it
/// does not have (nothing can match).
fn bound(t: Option<&Encoded>) -> Result<Option<Id>, ()> {
    match t {
        None => Ok(None),
        Some(Encoded::Id(id)) => Ok(Some(*id)),
        Some(Encoded::Other(_)) => Err(()),
    }
}

/// The quads matching a pattern; see [`QueryableDataset::internal_quads_for_pattern`].
enum QuadIter<'a> {
    Empty,
    /// A subject's facts, filtered.
    Subject {
        s: Id,
        p: Option<Id>,
        o: Option<Id>,
        graph: GraphFilter,
        facts: std::slice::Iter<'a, [Id; 3]>,
    },
    /// The holders of a (predicate, object).
    Holders {
        p: Id,
        o: Id,
        graph: GraphFilter,
        holders: std::slice::Iter<'a, [Id; 2]>,
    },
    Boxed(Box<dyn Iterator<Item = QuadResult> + 'a>),
}

impl Iterator for QuadIter<'_> {
    type Item = QuadResult;

    fn next(&mut self) -> Option<QuadResult> {
        match self {
            Self::Empty => None,
            Self::Subject {
                s,
                p,
                o,
                graph,
                facts,
            } => facts
                .find(|[fp, fo, fg]| {
                    p.is_none_or(|p| p == *fp) && o.is_none_or(|o| o == *fo) && graph.accepts(*fg)
                })
                .map(|&[fp, fo, fg]| internal(*s, fp, fo, fg)),
            Self::Holders {
                p,
                o,
                graph,
                holders,
            } => holders
                .find(|[_, g]| graph.accepts(*g))
                .map(|&[s, g]| internal(s, *p, *o, g)),
            Self::Boxed(b) => b.next(),
        }
    }
}

impl<'a> QueryableDataset<'a> for &'a Dataset {
    type InternalTerm = Encoded;
    type Error = DanglingId;

    fn internal_quads_for_pattern(
        &self,
        subject: Option<&Encoded>,
        predicate: Option<&Encoded>,
        object: Option<&Encoded>,
        graph_name: Option<Option<&Encoded>>,
    ) -> impl Iterator<Item = QuadResult> + use<'a> {
        let data: &'a Dataset = self;
        let (Ok(s), Ok(p), Ok(o)) = (bound(subject), bound(predicate), bound(object)) else {
            return QuadIter::Empty;
        };
        let graph = match graph_name {
            None => GraphFilter::AnyNamed,
            Some(None) => GraphFilter::Default,
            Some(Some(Encoded::Id(g))) => GraphFilter::Named(*g),
            Some(Some(Encoded::Other(_))) => return QuadIter::Empty,
        };
        // The shapes joins ask for thousands of times (subject bound; predicate and object
        // bound) get an iterator without an allocation; the rare ones are boxed.
        if let Some(s) = s {
            return match data.index.spo.get(s) {
                Some(facts) => QuadIter::Subject {
                    s,
                    p,
                    o,
                    graph,
                    facts: facts.iter(),
                },
                None => QuadIter::Empty,
            };
        }
        if let Some(p) = p {
            let Some(by_o) = data.index.pos.get(&p) else {
                return QuadIter::Empty;
            };
            if let Some(o) = o {
                return match by_o.get(&o) {
                    Some(holders) => QuadIter::Holders {
                        p,
                        o,
                        graph,
                        holders: holders.iter(),
                    },
                    None => QuadIter::Empty,
                };
            }
            return QuadIter::Boxed(Box::new(by_o.iter().flat_map(move |(&o, v)| {
                v.iter()
                    .filter(move |[_, g]| graph.accepts(*g))
                    .map(move |&[s, g]| internal(s, p, o, g))
            })));
        }
        if let Some(o) = o {
            return QuadIter::Boxed(Box::new(data.index.pos.iter().flat_map(
                move |(&p, by_o)| {
                    by_o.get(&o)
                        .into_iter()
                        .flat_map(|v| v.iter())
                        .filter(move |[_, g]| graph.accepts(*g))
                        .map(move |&[s, g]| internal(s, p, o, g))
                },
            )));
        }
        QuadIter::Boxed(Box::new(data.index.spo.iter().flat_map(move |(s, v)| {
            v.iter()
                .filter(move |[_, _, g]| graph.accepts(*g))
                .map(move |&[p, o, g]| internal(s, p, o, g))
        })))
    }

    fn internal_named_graphs(&self) -> impl Iterator<Item = Result<Encoded, DanglingId>> + use<'a> {
        let data: &'a Dataset = self;
        data.index
            .graphs
            .keys()
            .filter(|g| **g != DEFAULT_GRAPH)
            .map(|g| Ok(Encoded::Id(*g)))
    }

    fn contains_internal_graph_name(&self, graph_name: &Encoded) -> Result<bool, DanglingId> {
        Ok(match graph_name {
            Encoded::Id(g) => *g != DEFAULT_GRAPH && self.index.graphs.contains_key(g),
            Encoded::Other(_) => false,
        })
    }

    fn internalize_term(&self, term: Term) -> Result<Encoded, DanglingId> {
        Ok(match self.dict.lookup(term.as_ref()) {
            Some(id) => Encoded::Id(id),
            None => Encoded::Other(Arc::new(term)),
        })
    }

    fn externalize_term(&self, term: Encoded) -> Result<Term, DanglingId> {
        match term {
            Encoded::Id(id) => self.term(id).cloned(),
            Encoded::Other(t) => Ok(Arc::unwrap_or_clone(t)),
        }
    }

    fn externalize_expression_term(&self, term: Encoded) -> Result<ExpressionTerm, DanglingId> {
        match term {
            Encoded::Id(id) => {
                let slot = self.dict.slot(id).ok_or(DanglingId(id))?;
                Ok(match &slot.entry.expression {
                    Some(e) => e.clone(),
                    None => slot.entry.term.clone().into(),
                })
            }
            Encoded::Other(t) => Ok(Arc::unwrap_or_clone(t).into()),
        }
    }
}

#[cfg(test)]
mod tests {
    use std::collections::HashSet;

    use oxrdf::{BlankNode, Literal};
    use proptest::prelude::*;
    use spareval::{QueryEvaluator, QueryResults};
    use spargebra::SparqlParser;

    use super::*;
    use oxrdf::NamedNode;

    fn iri(s: &str) -> NamedNode {
        NamedNode::new_unchecked(format!("http://x/{s}"))
    }

    fn quad(s: u8, p: u8, o: u8, g: u8) -> Quad {
        let object: Term = if o.is_multiple_of(3) {
            Literal::from(f64::from(o) / 2.0).into()
        } else {
            iri(&format!("o{o}")).into()
        };
        let graph = if g == 0 {
            GraphName::DefaultGraph
        } else {
            iri(&format!("g{g}")).into()
        };
        Quad::new(iri(&format!("s{s}")), iri(&format!("p{p}")), object, graph)
    }

    fn select(d: &Dataset, q: &str) -> HashSet<Vec<Option<Term>>> {
        let query = SparqlParser::new().parse_query(q).unwrap();
        let evaluator = QueryEvaluator::new();
        let mut prepared = evaluator.prepare(&query);
        prepared.dataset_mut().set_default_graph_as_union();
        let QueryResults::Solutions(rows) = prepared.execute(d).unwrap() else {
            panic!("{q}")
        };
        rows.map(|r| r.unwrap().values().to_vec()).collect()
    }

    #[test]
    fn terms_are_freed_with_their_last_quad() {
        let mut d = Dataset::new();
        let a = quad(1, 1, 3, 1);
        let b = quad(2, 1, 3, 1);
        assert!(d.insert(a.as_ref()));
        assert!(!d.insert(a.as_ref()), "a set: no duplicates");
        assert!(d.insert(b.as_ref()));
        assert_eq!((d.len(), d.term_count()), (2, 5));
        assert!(d.remove(a.as_ref()));
        assert!(!d.remove(a.as_ref()));
        assert_eq!((d.len(), d.term_count()), (1, 4), "s1 is gone");
        assert!(d.remove(b.as_ref()));
        assert_eq!((d.len(), d.term_count()), (0, 0));
        // Ids are reused, so churn does not grow the dictionary.
        for i in 0..1000u32 {
            let q = Quad::new(
                iri("v"),
                iri("battery"),
                Literal::from(f64::from(i)),
                iri("g"),
            );
            d.insert(q.as_ref());
            d.remove(q.as_ref());
        }
        assert!(d.dict.slots.len() <= 5, "{}", d.dict.slots.len());
    }

    #[test]
    fn every_pattern_shape_finds_the_same_quads_as_a_scan() {
        let mut d = Dataset::new();
        let mut all = Vec::new();
        for i in 0..60u8 {
            let q = quad(i % 7, i % 4, i % 9, (i / 2) % 3);
            d.insert(q.as_ref());
            all.push(q);
        }
        all.sort_by_key(ToString::to_string);
        all.dedup();
        let named: Vec<&Quad> = all
            .iter()
            .filter(|q| !q.graph_name.is_default_graph())
            .collect();
        let expect = |f: &dyn Fn(&Quad) -> bool| -> HashSet<Vec<Option<Term>>> {
            named
                .iter()
                .filter(|q| f(q))
                .map(|q| {
                    vec![
                        Some(q.subject.clone().into()),
                        Some(q.predicate.clone().into()),
                        Some(q.object.clone()),
                    ]
                })
                .collect()
        };
        let s = iri("s3");
        let p = iri("p2");
        let o: Term = iri("o5").into();
        let lit = Literal::from(3.0);
        assert_eq!(
            select(&d, "SELECT ?s ?p ?o WHERE { ?s ?p ?o }"),
            expect(&|_| true)
        );
        assert_eq!(
            select(
                &d,
                &format!("SELECT ?s ?p ?o WHERE {{ BIND({s} AS ?s) ?s ?p ?o }}")
            ),
            expect(&|q| q.subject == s.clone().into())
        );
        assert_eq!(
            select(
                &d,
                &format!("SELECT ?s ?p ?o WHERE {{ BIND({p} AS ?p) ?s ?p ?o }}")
            ),
            expect(&|q| q.predicate == p)
        );
        assert_eq!(
            select(
                &d,
                &format!("SELECT ?s ?p ?o WHERE {{ BIND({o} AS ?o) ?s ?p ?o }}")
            ),
            expect(&|q| q.object == o)
        );
        assert_eq!(
            select(
                &d,
                &format!("SELECT ?s ?p ?o WHERE {{ BIND({p} AS ?p) BIND({lit} AS ?o) ?s ?p ?o }}")
            ),
            expect(&|q| q.predicate == p && q.object == lit.clone().into())
        );
        // Named graphs only: the default graph is not part of the union.
        let graphs = select(&d, "SELECT DISTINCT ?g WHERE { GRAPH ?g { ?s ?p ?o } }");
        assert_eq!(graphs.len(), 2);
        let in_g1 = select(
            &d,
            "SELECT ?s ?p ?o WHERE { GRAPH <http://x/g1> { ?s ?p ?o } }",
        );
        assert_eq!(
            in_g1,
            expect(&|q| q.graph_name == GraphName::from(iri("g1")))
        );
        // A constant the dataset does not have matches nothing, and computed terms
        // compare with stored ones by value.
        assert!(select(&d, "SELECT * WHERE { ?s <http://x/nope> ?o }").is_empty());
        let halves = select(
            &d,
            "SELECT ?o WHERE { ?s ?p ?o FILTER(isLiteral(?o) && ?o * 2 = 3) }",
        );
        assert_eq!(halves.len(), 1);
    }

    #[test]
    fn a_clone_is_a_snapshot() {
        let mut d = Dataset::new();
        let a = quad(1, 1, 1, 1);
        d.insert(a.as_ref());
        let snapshot = d.clone();
        d.remove(a.as_ref());
        d.insert(quad(2, 2, 2, 1).as_ref());
        assert_eq!(select(&snapshot, "SELECT * WHERE { ?s ?p ?o }").len(), 1);
        assert!(snapshot.contains(a.as_ref()));
        assert!(!d.contains(a.as_ref()));
        let b = Quad::new(BlankNode::default(), iri("p"), iri("o"), iri("g"));
        assert!(d.insert(b.as_ref()));
        assert!(d.contains(b.as_ref()));
    }

    proptest! {
        /// Random insert/remove sequences leave the index equal to a naive set, and the
        /// dictionary holding exactly the terms of the remaining quads.
        #[test]
        fn random_edits_match_a_reference_set(
            ops in proptest::collection::vec((any::<bool>(), 0u8..5, 0u8..3, 0u8..7, 0u8..3), 0..300)
        ) {
            let mut d = Dataset::new();
            let mut reference: HashSet<Quad> = HashSet::new();
            for (add, s, p, o, g) in ops {
                let q = quad(s, p, o, g);
                if add {
                    prop_assert_eq!(d.insert(q.as_ref()), reference.insert(q));
                } else {
                    prop_assert_eq!(d.remove(q.as_ref()), reference.remove(&q));
                }
            }
            let stored: HashSet<Quad> = d.iter().collect();
            prop_assert_eq!(&stored, &reference);
            prop_assert_eq!(d.len(), reference.len());
            let mut terms: HashSet<Term> = HashSet::new();
            for q in &reference {
                terms.insert(q.subject.clone().into());
                terms.insert(q.predicate.clone().into());
                terms.insert(q.object.clone());
                match &q.graph_name {
                    GraphName::NamedNode(n) => { terms.insert(n.clone().into()); }
                    GraphName::BlankNode(b) => { terms.insert(b.clone().into()); }
                    GraphName::DefaultGraph => {}
                }
            }
            prop_assert_eq!(d.term_count(), terms.len());
            for t in &terms {
                prop_assert!(d.dict.lookup(t.as_ref()).is_some());
            }
            for q in &reference {
                prop_assert!(d.contains(q.as_ref()));
            }
        }
    }
}
