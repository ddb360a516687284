//! Semantic Query: read-only SPARQL 1.1 over the model, with limits.
//!
//! [`SemanticStore::query`] parses (refusing UPDATE and over-long text) with `spargebra`,
//! evaluates with `spareval` (Oxigraph's parser and evaluator) over the union of all
//! graphs of the store's [`crate::dataset::Dataset`] (so derived facts are visible
//! without `GRAPH` clauses), stops at the row limit and cancels evaluation at the
//! timeout. [`QueryResult`] serialises as SPARQL 1.1 Query Results JSON, CSV, TSV or XML
//! (`sparesults`), and graph results (CONSTRUCT/DESCRIBE) as N-Triples or Turtle
//! (`oxrdfio`).

use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::io::Write;
use std::sync::mpsc::{self, RecvTimeoutError, Sender};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Duration, Instant};

use oxrdf::{Term, Triple, Variable};
use oxrdfio::{RdfFormat, RdfSerializer};
use sparesults::{QueryResultsFormat, QueryResultsSerializer, QuerySolution};
use spareval::{
    CancellationToken, QueryEvaluationError, QueryEvaluator, QueryResults, QuerySolutionIter,
};
use spargebra::Query;

use crate::dataset::Dataset;
use crate::error::QueryError;
use crate::rules::sparql_parser;
use crate::store::SemanticStore;

/// Limits applied to one query.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct QueryLimits {
    /// Evaluation is cancelled after this long.
    pub timeout: Duration,
    /// At most this many solutions (or triples) are returned; more set `truncated`.
    pub max_rows: usize,
    /// Longest accepted query text, in bytes.
    pub max_len: usize,
    /// Most solutions an `ORDER BY` may sort (it must hold them all); a query that would
    /// sort more is refused with a message instead of filling memory.
    pub max_sorted_rows: usize,
}

impl Default for QueryLimits {
    /// 10 s, 10 000 rows, 64 KiB.
    fn default() -> Self {
        Self {
            timeout: Duration::from_secs(10),
            max_rows: 10_000,
            max_len: 64 * 1024,
            max_sorted_rows: 100_000,
        }
    }
}

/// The answer to a query, fully materialised (bounded by [`QueryLimits::max_rows`]).
#[derive(Debug, PartialEq)]
#[non_exhaustive]
pub enum QueryResult {
    /// ASK.
    Boolean(bool),
    /// SELECT.
    Solutions {
        /// Projected variables, in order.
        variables: Vec<Variable>,
        /// One row per solution (its `values()` hold one cell per variable, `None` when
        /// unbound), as the evaluator produced them: keeping them saves a copy of every
        /// term.
        rows: Vec<QuerySolution>,
        /// True when rows were cut at `max_rows`.
        truncated: bool,
    },
    /// CONSTRUCT or DESCRIBE.
    Graph {
        /// The triples.
        triples: Vec<Triple>,
        /// True when triples were cut at `max_rows`.
        truncated: bool,
    },
}

/// A serialisation of a [`QueryResult`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum ResultFormat {
    /// SPARQL 1.1 Query Results JSON (`application/sparql-results+json`).
    Json,
    /// SPARQL 1.1 Query Results CSV (`text/csv`).
    Csv,
    /// SPARQL 1.1 Query Results TSV (`text/tab-separated-values`).
    Tsv,
    /// SPARQL Query Results XML (`application/sparql-results+xml`).
    Xml,
}

impl ResultFormat {
    /// The media type to send with it (graph results are sent as N-Triples or Turtle).
    pub fn media_type(self) -> &'static str {
        match self {
            Self::Json => "application/sparql-results+json",
            Self::Csv => "text/csv; charset=utf-8",
            Self::Tsv => "text/tab-separated-values; charset=utf-8",
            Self::Xml => "application/sparql-results+xml",
        }
    }
}

impl QueryResult {
    /// Writes the result. Graph results are written as N-Triples for CSV/TSV and Turtle
    /// otherwise, since the SPARQL results formats cannot carry triples.
    pub fn write<W: Write>(&self, format: ResultFormat, writer: W) -> Result<W, QueryError> {
        let ser = |e: std::io::Error| QueryError::Serialize(e.to_string());
        let results_format = match format {
            ResultFormat::Json => QueryResultsFormat::Json,
            ResultFormat::Csv => QueryResultsFormat::Csv,
            ResultFormat::Tsv => QueryResultsFormat::Tsv,
            ResultFormat::Xml => QueryResultsFormat::Xml,
        };
        let serializer = QueryResultsSerializer::from_format(results_format);
        match self {
            Self::Boolean(b) => serializer
                .serialize_boolean_to_writer(writer, *b)
                .map_err(ser),
            Self::Solutions {
                variables, rows, ..
            } => {
                let mut out = serializer
                    .serialize_solutions_to_writer(writer, variables.clone())
                    .map_err(ser)?;
                for row in rows {
                    out.serialize(row).map_err(ser)?;
                }
                out.finish().map_err(ser)
            }
            Self::Graph { triples, .. } => {
                let rdf = if matches!(format, ResultFormat::Csv | ResultFormat::Tsv) {
                    RdfFormat::NTriples
                } else {
                    RdfFormat::Turtle
                };
                let mut out = RdfSerializer::from_format(rdf).for_writer(writer);
                for t in triples {
                    out.serialize_triple(t).map_err(ser)?;
                }
                out.finish().map_err(ser)
            }
        }
    }

    /// SPARQL 1.1 Query Results JSON as a string.
    pub fn to_json(&self) -> Result<String, QueryError> {
        self.to_string_in(ResultFormat::Json)
    }

    /// SPARQL 1.1 Query Results CSV as a string.
    pub fn to_csv(&self) -> Result<String, QueryError> {
        self.to_string_in(ResultFormat::Csv)
    }

    fn to_string_in(&self, format: ResultFormat) -> Result<String, QueryError> {
        let bytes = self.write(format, Vec::new())?;
        String::from_utf8(bytes).map_err(|e| QueryError::Serialize(e.to_string()))
    }

    /// Number of rows (solutions or triples; 1 for a boolean).
    pub fn len(&self) -> usize {
        match self {
            Self::Boolean(_) => 1,
            Self::Solutions { rows, .. } => rows.len(),
            Self::Graph { triples, .. } => triples.len(),
        }
    }

    /// True for a SELECT or CONSTRUCT with no results.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Cancels queries at their deadline from one background thread.
///
/// spareval checks a `CancellationToken` each time it reads quads, so cancelling from a
/// second thread stops even a query that would never yield a row (a huge aggregate). One
/// lazily started thread serves every query of a store and ends with it.
#[derive(Debug, Default)]
pub(crate) struct Watchdog {
    sender: OnceLock<Mutex<Sender<(Instant, CancellationToken)>>>,
}

impl Watchdog {
    pub(crate) fn watch(&self, deadline: Instant, token: CancellationToken) {
        let sender = self.sender.get_or_init(|| {
            let (tx, rx) = mpsc::channel::<(Instant, CancellationToken)>();
            let spawned = std::thread::Builder::new()
                .name("shoal-query-watchdog".into())
                .spawn(move || {
                    let mut heap: BinaryHeap<Reverse<(Instant, u64)>> = BinaryHeap::new();
                    let mut tokens = std::collections::HashMap::new();
                    let mut seq = 0u64;
                    loop {
                        let now = Instant::now();
                        while let Some(Reverse((d, k))) = heap.peek().copied() {
                            if d > now {
                                break;
                            }
                            heap.pop();
                            if let Some(t) = tokens.remove(&k) {
                                CancellationToken::cancel(&t);
                            }
                        }
                        let next = match heap.peek() {
                            Some(Reverse((d, _))) => {
                                rx.recv_timeout(d.saturating_duration_since(now))
                            }
                            None => rx.recv().map_err(|_| RecvTimeoutError::Disconnected),
                        };
                        match next {
                            Ok((d, t)) => {
                                seq += 1;
                                heap.push(Reverse((d, seq)));
                                tokens.insert(seq, t);
                            }
                            Err(RecvTimeoutError::Timeout) => {}
                            Err(RecvTimeoutError::Disconnected) => return,
                        }
                    }
                });
            if let Err(e) = spawned {
                // Without the thread, timeouts are still checked between rows.
                tracing::warn!(error = %e, "cannot start the query watchdog thread");
            }
            Mutex::new(tx)
        });
        if let Ok(tx) = sender.lock() {
            // A send error means the thread is gone; the per-row deadline check remains.
            let _ = tx.send((deadline, token));
        }
    }
}

impl SemanticStore {
    /// Runs a read-only SPARQL 1.1 query (SELECT, ASK, CONSTRUCT, DESCRIBE) over the
    /// union of all graphs, within `limits`.
    ///
    /// The prefixes of [`crate::vocab::PREFIXES`] (`shoal:`, `geo:`, `sosa:`, ...) may be
    /// used without declaring them. UPDATE is refused: data changes only through the
    /// store's typed methods.
    pub fn query(&self, sparql: &str, limits: &QueryLimits) -> Result<QueryResult, QueryError> {
        run_query(&self.data, &self.watchdog, sparql, limits)
    }

    /// A read-only view of the model as it is now, for queries that must not hold the
    /// caller's lock on the store while they run.
    ///
    /// Taking it is cheap (the view shares the data); it sees no later change, because the
    /// store's next write while the view is alive copies the data once and writes to the
    /// copy (about 1 ms per 10 000 quads, see the benchmark).
    pub fn snapshot(&self) -> QuerySnapshot {
        QuerySnapshot {
            data: Arc::clone(&self.data),
            watchdog: Arc::clone(&self.watchdog),
        }
    }
}

/// A read-only view of the semantic model taken by [`SemanticStore::snapshot`].
#[derive(Clone)]
pub struct QuerySnapshot {
    data: Arc<Dataset>,
    watchdog: Arc<Watchdog>,
}

impl std::fmt::Debug for QuerySnapshot {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("QuerySnapshot").finish_non_exhaustive()
    }
}

impl QuerySnapshot {
    /// Same as [`SemanticStore::query`], on this view.
    pub fn query(&self, sparql: &str, limits: &QueryLimits) -> Result<QueryResult, QueryError> {
        run_query(&self.data, &self.watchdog, sparql, limits)
    }
}

/// Solutions as [`QueryResult::Solutions`] holds them.
type Rows = Vec<QuerySolution>;

fn run_query(
    data: &Dataset,
    watchdog: &Watchdog,
    sparql: &str,
    limits: &QueryLimits,
) -> Result<QueryResult, QueryError> {
    if sparql.len() > limits.max_len {
        return Err(QueryError::TooLong {
            len: sparql.len(),
            max: limits.max_len,
        });
    }
    let deadline = Instant::now() + limits.timeout;
    if let Some(split) = crate::order::split(sparql)
        && let Some(result) = run_sorted(data, watchdog, &split, limits, deadline)?
    {
        return Ok(result);
    }
    let query = match sparql_parser().parse_query(sparql) {
        Ok(q) => q,
        Err(e) => {
            if sparql_parser().parse_update(sparql).is_ok() {
                return Err(QueryError::UpdateNotAllowed);
            }
            return Err(QueryError::Syntax(e.to_string()));
        }
    };
    let token = CancellationToken::new();
    watchdog.watch(deadline, token.clone());
    match execute(&query, data, token, limits)? {
        QueryResults::Boolean(b) => Ok(QueryResult::Boolean(b)),
        QueryResults::Solutions(solutions) => {
            let variables = solutions.variables().to_vec();
            let (rows, truncated) = collect(solutions, limits.max_rows, limits, deadline)?;
            Ok(QueryResult::Solutions {
                variables,
                rows,
                truncated,
            })
        }
        QueryResults::Graph(triples) => {
            let mut out = Vec::new();
            let mut truncated = false;
            for t in triples {
                if out.len() >= limits.max_rows {
                    truncated = true;
                    break;
                }
                out.push(t.map_err(|e| evaluation_error(e, limits))?);
                if out.len().is_multiple_of(DEADLINE_EVERY) {
                    check_deadline(deadline, limits)?;
                }
            }
            Ok(QueryResult::Graph {
                triples: out,
                truncated,
            })
        }
    }
}

/// Runs a `SELECT` without its `ORDER BY`/`LIMIT`/`OFFSET` and applies them here (see
/// [`crate::order`]); `None` when the query has to run as written instead.
fn run_sorted(
    data: &Dataset,
    watchdog: &Watchdog,
    split: &crate::order::Split<'_>,
    limits: &QueryLimits,
    deadline: Instant,
) -> Result<Option<QueryResult>, QueryError> {
    // A body that does not parse is reported by the normal path, with the whole text.
    let Ok(query) = sparql_parser().parse_query(split.body) else {
        return Ok(None);
    };
    let token = CancellationToken::new();
    watchdog.watch(deadline, token.clone());
    let QueryResults::Solutions(solutions) = execute(&query, data, token, limits)? else {
        return Ok(None);
    };
    let variables = solutions.variables().to_vec();
    let (mut rows, too_many) = collect(solutions, limits.max_sorted_rows, limits, deadline)?;
    if too_many {
        return Err(QueryError::Evaluation(format!(
            "the query would sort more than {} solutions; narrow it (e.g. by a FILTER)",
            limits.max_sorted_rows
        )));
    }
    if !crate::order::sort(&mut rows, &variables, &split.keys) {
        return Ok(None);
    }
    rows.drain(..split.offset.min(rows.len()));
    if let Some(limit) = split.limit {
        rows.truncate(limit);
    }
    let truncated = rows.len() > limits.max_rows;
    rows.truncate(limits.max_rows);
    Ok(Some(QueryResult::Solutions {
        variables,
        rows,
        truncated,
    }))
}

/// Evaluates over the union of all graphs unless the query names its dataset (`FROM`),
/// cancellable through `token`.
pub(crate) fn execute<'a>(
    query: &Query,
    data: &'a Dataset,
    token: CancellationToken,
    limits: &QueryLimits,
) -> Result<QueryResults<'a>, QueryError> {
    evaluate(query, data, token, None).map_err(|e| evaluation_error(e, limits))
}

/// Evaluates `query` over `data` (the union of all graphs unless the query names its
/// dataset), with `?this` bound to `this` if given (SPARQL rules).
pub(crate) fn evaluate<'a>(
    query: &Query,
    data: &'a Dataset,
    token: CancellationToken,
    this: Option<Term>,
) -> Result<QueryResults<'a>, QueryEvaluationError> {
    let evaluator = QueryEvaluator::new().with_cancellation_token(token);
    let mut prepared = evaluator.prepare(query);
    if prepared.dataset().is_default_dataset() {
        prepared.dataset_mut().set_default_graph_as_union();
    }
    if let Some(this) = this {
        prepared = prepared.substitute_variable(Variable::new_unchecked("this"), this);
    }
    prepared.execute(data)
}

/// At most `max` solutions, and whether there were more.
fn collect(
    solutions: QuerySolutionIter<'_>,
    max: usize,
    limits: &QueryLimits,
    deadline: Instant,
) -> Result<(Rows, bool), QueryError> {
    let mut rows = Vec::new();
    for s in solutions {
        if rows.len() >= max {
            return Ok((rows, true));
        }
        rows.push(s.map_err(|e| evaluation_error(e, limits))?);
        if rows.len().is_multiple_of(DEADLINE_EVERY) {
            check_deadline(deadline, limits)?;
        }
    }
    Ok((rows, false))
}

fn evaluation_error(e: QueryEvaluationError, limits: &QueryLimits) -> QueryError {
    match e {
        QueryEvaluationError::Cancelled => QueryError::Timeout(limits.timeout),
        e => QueryError::Evaluation(e.to_string()),
    }
}

/// Rows between two looks at the clock in [`check_deadline`]: reading it per row cost
/// a few percent of a 2000-row query, and the watchdog is the usual way out anyway.
const DEADLINE_EVERY: usize = 256;

/// Between rows, in case the watchdog thread could not be started.
fn check_deadline(deadline: Instant, limits: &QueryLimits) -> Result<(), QueryError> {
    if Instant::now() > deadline {
        Err(QueryError::Timeout(limits.timeout))
    } else {
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::StoreConfig;

    fn store() -> SemanticStore {
        let mut s = SemanticStore::new(StoreConfig::default()).unwrap();
        crate::synthetic::populate_fleet(&mut s, 10, 3).unwrap();
        s
    }

    #[test]
    fn updates_are_refused_as_read_only() {
        let s = store();
        let e = s
            .query("DELETE WHERE { ?s ?p ?o }", &QueryLimits::default())
            .unwrap_err();
        assert_eq!(e, QueryError::UpdateNotAllowed);
        let e = s
            .query(
                "INSERT DATA { <http://a> <http://b> <http://c> }",
                &QueryLimits::default(),
            )
            .unwrap_err();
        assert_eq!(e, QueryError::UpdateNotAllowed);
    }

    #[test]
    fn bad_sparql_carries_the_parser_message() {
        let e = store()
            .query("SELECT ?x WHERE { ?x ", &QueryLimits::default())
            .unwrap_err();
        let QueryError::Syntax(msg) = &e else {
            panic!("{e:?}")
        };
        assert!(!msg.is_empty());
        assert!(e.to_string().starts_with("SPARQL syntax error: "), "{e}");
    }

    #[test]
    fn over_long_queries_are_refused_before_parsing() {
        let limits = QueryLimits {
            max_len: 20,
            ..QueryLimits::default()
        };
        let e = store()
            .query("SELECT * WHERE { ?s ?p ?o }", &limits)
            .unwrap_err();
        assert_eq!(e, QueryError::TooLong { len: 27, max: 20 });
    }

    #[test]
    fn rows_are_cut_at_the_limit() {
        let limits = QueryLimits {
            max_rows: 7,
            ..QueryLimits::default()
        };
        match store()
            .query("SELECT * WHERE { ?s ?p ?o }", &limits)
            .unwrap()
        {
            QueryResult::Solutions {
                rows, truncated, ..
            } => assert_eq!((rows.len(), truncated), (7, true)),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn a_sort_over_more_solutions_than_allowed_is_refused_with_a_reason() {
        let limits = QueryLimits {
            max_sorted_rows: 10,
            ..QueryLimits::default()
        };
        let e = store()
            .query("SELECT ?s WHERE { ?s ?p ?o } ORDER BY ?s", &limits)
            .unwrap_err();
        assert!(e.to_string().contains("more than 10 solutions"), "{e}");
        // Within the cap, the sort runs.
        let ok = store().query(
            "SELECT ?s WHERE { ?s a shoal:Vehicle } ORDER BY ?s",
            &limits,
        );
        assert!(ok.is_ok(), "{ok:?}");
    }

    #[test]
    fn a_runaway_query_is_cancelled_at_the_timeout() {
        let s = store();
        let limits = QueryLimits {
            timeout: Duration::from_millis(100),
            ..QueryLimits::default()
        };
        let start = Instant::now();
        // The closure of every node over every property: it reads quads all along, which
        // is where spareval checks for cancellation. (A cartesian product of whole-graph
        // patterns is no good here: once both sides are read, spareval combines them for
        // seconds without a check, however early it was cancelled.)
        let e = s
            .query(
                "SELECT (COUNT(*) AS ?n) WHERE { ?a (<urn:x>|!<urn:x>)* ?b }",
                &limits,
            )
            .unwrap_err();
        assert_eq!(e, QueryError::Timeout(Duration::from_millis(100)));
        assert!(
            start.elapsed() < Duration::from_secs(5),
            "{:?}",
            start.elapsed()
        );
    }

    #[test]
    fn results_serialise_as_sparql_json_and_csv() {
        let s = store();
        let r = s
            .query(
                "SELECT ?v WHERE { ?v shoal:vehicleId \"v0003\" }",
                &QueryLimits::default(),
            )
            .unwrap();
        let json: serde_json::Value = serde_json::from_str(&r.to_json().unwrap()).unwrap();
        assert_eq!(json["head"]["vars"][0], "v");
        assert_eq!(
            json["results"]["bindings"][0]["v"]["value"],
            "https://example.invalid/shoal/id/vehicle/v0003"
        );
        assert_eq!(
            r.to_csv().unwrap(),
            "v\r\nhttps://example.invalid/shoal/id/vehicle/v0003\r\n"
        );
        let ask = s
            .query("ASK { ?v a shoal:Glider }", &QueryLimits::default())
            .unwrap();
        assert_eq!(ask.to_json().unwrap(), r#"{"head":{},"boolean":true}"#);
        let g = s
            .query(
                "CONSTRUCT { ?v a shoal:Vehicle } WHERE { ?v a shoal:Glider }",
                &QueryLimits::default(),
            )
            .unwrap();
        let ttl = String::from_utf8(g.write(ResultFormat::Json, Vec::new()).unwrap()).unwrap();
        assert!(ttl.contains("vehicle/v0004"), "{ttl}");
    }

    /// The key columns of `q`'s rows, in order, as Shoal answers and as spareval's own
    /// `ORDER BY` does (rows tied on every key may come in any order in both).
    fn both_orders(
        s: &SemanticStore,
        q: &str,
        keys: &[usize],
    ) -> (Vec<Vec<String>>, Vec<Vec<String>>) {
        let pick = |rows: Vec<QuerySolution>| -> Vec<Vec<String>> {
            rows.into_iter()
                .map(|r| {
                    keys.iter()
                        .map(|k| r.get(*k).map_or("UNBOUND".into(), Term::to_string))
                        .collect()
                })
                .collect()
        };
        let QueryResult::Solutions { rows, .. } = s.query(q, &QueryLimits::default()).unwrap()
        else {
            panic!("{q}")
        };
        let query = sparql_parser().parse_query(q).unwrap();
        let QueryResults::Solutions(solutions) =
            evaluate(&query, &s.data, CancellationToken::new(), None).unwrap()
        else {
            panic!("{q}")
        };
        let theirs = solutions.map(Result::unwrap).collect();
        (pick(rows), pick(theirs))
    }

    #[test]
    fn order_by_gives_the_engines_order() {
        let mut s = store();
        // Unbound altitudes, so that the unbound-first rule is exercised.
        for i in 0..3 {
            let mut st = s.latest_state(&format!("v000{i}")).unwrap();
            st.timestamp_ms += 1000;
            st.altitude_m = shoal_model::UNKNOWN;
            s.update_state(&st).unwrap();
        }
        s.flush_dirty(crate::synthetic::T0_MS + 60_000).unwrap();
        for (q, keys) in [
            (
                "SELECT ?v ?b WHERE { ?v shoal:batteryLevel ?b } ORDER BY DESC(?b) ?v",
                &[1, 0][..],
            ),
            (
                "SELECT ?v ?b WHERE { ?v shoal:batteryLevel ?b } ORDER BY ?b ?v LIMIT 4 OFFSET 3",
                &[1, 0],
            ),
            (
                "SELECT ?s ?t WHERE { ?t shoal:hasState ?s } ORDER BY ?s DESC(?t)",
                &[0, 1],
            ),
            (
                "SELECT ?x ?e WHERE { ?e shoal:eventId ?x } ORDER BY ?x",
                &[0],
            ),
            (
                "SELECT ?v ?a WHERE { ?v a shoal:Vehicle OPTIONAL { ?v shoal:altitude ?a } } ORDER BY ?a ?v",
                &[1, 0],
            ),
            (
                "SELECT ?w ?n WHERE { ?w shoal:sequence ?n } ORDER BY DESC(?n) ?w",
                &[1, 0],
            ),
            ("SELECT ?l WHERE { ?x rdfs:label ?l } ORDER BY ?l", &[0]),
            // Mixed literals, and a key that is not projected: left to the engine.
            (
                "SELECT ?o WHERE { ?v a shoal:Vehicle ; ?p ?o } ORDER BY ?o",
                &[0],
            ),
            (
                "SELECT ?v WHERE { ?v shoal:batteryLevel ?b } ORDER BY ?b",
                &[0],
            ),
        ] {
            let (ours, theirs) = both_orders(&s, q, keys);
            assert!(!ours.is_empty(), "{q}");
            assert_eq!(ours, theirs, "{q}");
        }
        for (name, q) in crate::STANDARD_QUERIES {
            let keys: &[usize] = if name == "q3_tasks_by_state" {
                &[0, 1]
            } else {
                &[0]
            };
            let (ours, theirs) = both_orders(&s, q, keys);
            assert_eq!(ours, theirs, "{name}");
        }
    }

    #[test]
    fn sorted_rows_are_cut_at_the_limit_after_sorting() {
        let s = store();
        let q = "SELECT ?v ?b WHERE { ?v shoal:batteryLevel ?b } ORDER BY DESC(?b)";
        let all = s.query(q, &QueryLimits::default()).unwrap();
        let limits = QueryLimits {
            max_rows: 3,
            ..QueryLimits::default()
        };
        match (s.query(q, &limits).unwrap(), all) {
            (
                QueryResult::Solutions {
                    rows, truncated, ..
                },
                QueryResult::Solutions { rows: all, .. },
            ) => {
                assert!(truncated);
                assert_eq!(rows, all[..3]);
            }
            other => panic!("{other:?}"),
        }
    }
}
