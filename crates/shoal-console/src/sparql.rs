//! The SPARQL 1.1 Protocol's query operation at `/api/sparql` (GET, and POST as
//! `application/sparql-query` or a form), with content negotiation.
//!
//! The answer's format follows the request's `Accept` header ([`crate::negotiate`]), or
//! the `format` parameter when it is given: SELECT and ASK results as SPARQL 1.1 Query
//! Results JSON, XML, CSV or TSV (`sparesults`, through [`shoal_semantic::QueryResult`]),
//! CONSTRUCT and DESCRIBE results as Turtle, N-Triples, RDF/XML, N-Quads, TriG or JSON-LD
//! (`oxrdfio`). Each response is labelled with its format's media type and `Vary:
//! Accept`; what the client accepts but cannot be served gets 406 Not Acceptable naming
//! what can (SPARQL 1.1 Protocol §2.1.5 leaves the choice to HTTP negotiation).

use std::sync::Arc;

use axum::body::Bytes;
use axum::extract::rejection::{BytesRejection, QueryRejection};
use axum::extract::{Query, State};
use axum::http::{HeaderMap, header};
use axum::response::{IntoResponse, Response};
use oxrdf::Triple;
use oxrdfio::{JsonLdProfileSet, RdfFormat, RdfSerializer};
use serde::Deserialize;
use shoal_semantic::{QueryError, QueryLimits, QueryResult, ResultFormat};
use shoal_station::StationHandle;

use crate::ApiError;
use crate::limits::Limits;
use crate::negotiate::Accept;

/// What SELECT and ASK results can be sent as, in the order preferred when the client
/// does not mind. `application/json` and `application/xml` are generic names clients use
/// for the same formats; the response carries the specific media type.
const SOLUTION_OFFERS: [(&str, ResultFormat); 6] = [
    ("application/sparql-results+json", ResultFormat::Json),
    ("application/sparql-results+xml", ResultFormat::Xml),
    ("text/csv", ResultFormat::Csv),
    ("text/tab-separated-values", ResultFormat::Tsv),
    ("application/json", ResultFormat::Json),
    ("application/xml", ResultFormat::Xml),
];

/// JSON-LD as `oxrdfio` writes it: streaming JSON-LD, a valid JSON-LD 1.1 document.
const JSON_LD: RdfFormat = RdfFormat::JsonLd {
    profile: JsonLdProfileSet::empty(),
};

/// What CONSTRUCT and DESCRIBE results can be sent as, in the order preferred when the
/// client does not mind (Turtle: the most readable). The dataset formats carry the triples
/// in the default graph.
const GRAPH_OFFERS: [(&str, RdfFormat); 8] = [
    ("text/turtle", RdfFormat::Turtle),
    ("application/n-triples", RdfFormat::NTriples),
    ("application/rdf+xml", RdfFormat::RdfXml),
    ("application/n-quads", RdfFormat::NQuads),
    ("application/trig", RdfFormat::TriG),
    ("application/ld+json", JSON_LD),
    ("application/json", JSON_LD),
    ("application/xml", RdfFormat::RdfXml),
];

/// The short names the `format` parameter takes, and the media types each stands for
/// (one per kind of result where both kinds have one).
const FORMAT_NAMES: [(&str, &str); 16] = [
    (
        "json",
        "application/sparql-results+json, application/ld+json",
    ),
    ("xml", "application/sparql-results+xml, application/rdf+xml"),
    ("csv", "text/csv"),
    ("tsv", "text/tab-separated-values"),
    ("turtle", "text/turtle"),
    ("ttl", "text/turtle"),
    ("ntriples", "application/n-triples"),
    ("nt", "application/n-triples"),
    ("rdfxml", "application/rdf+xml"),
    ("rdf", "application/rdf+xml"),
    ("nquads", "application/n-quads"),
    ("nq", "application/n-quads"),
    ("trig", "application/trig"),
    ("jsonld", "application/ld+json"),
    ("srj", "application/sparql-results+json"),
    ("srx", "application/sparql-results+xml"),
];

/// The SPARQL 1.1 Protocol's query parameters (query operation).
#[derive(Debug, Deserialize)]
pub(crate) struct SparqlParams {
    query: Option<String>,
    /// Overrides the `Accept` header: a short name of [`FORMAT_NAMES`] or a media type.
    format: Option<String>,
    #[serde(rename = "default-graph-uri")]
    default_graph_uri: Option<String>,
    #[serde(rename = "named-graph-uri")]
    named_graph_uri: Option<String>,
}

/// The formats a request accepts, one per kind of result; `None` where nothing fits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Negotiated {
    /// For SELECT and ASK.
    pub(crate) solutions: Option<ResultFormat>,
    /// For CONSTRUCT and DESCRIBE.
    pub(crate) graph: Option<RdfFormat>,
}

/// Picks the formats from the `format` parameter, or else the `Accept` header. 406 when
/// the request accepts no format of either kind: no query needs to run to know that.
pub(crate) fn negotiate(format: Option<&str>, headers: &HeaderMap) -> Result<Negotiated, ApiError> {
    let accept = match format {
        Some(f) => Accept::parse(format_media_types(f)?),
        None => Accept::from_headers(headers),
    };
    let n = Negotiated {
        solutions: accept.choose(&SOLUTION_OFFERS),
        graph: accept.choose(&GRAPH_OFFERS),
    };
    if n.solutions.is_none() && n.graph.is_none() {
        return Err(ApiError::NotAcceptable(format!(
            "{}: SELECT and ASK results are served as {}; CONSTRUCT and DESCRIBE results as {}",
            asked(format, headers),
            offered(&SOLUTION_OFFERS),
            offered(&GRAPH_OFFERS)
        )));
    }
    Ok(n)
}

/// The `format` parameter as an `Accept` value.
fn format_media_types(f: &str) -> Result<&str, ApiError> {
    if f.contains('/') {
        return Ok(f);
    }
    FORMAT_NAMES
        .iter()
        .find(|(name, _)| name.eq_ignore_ascii_case(f))
        .map(|(_, types)| *types)
        .ok_or_else(|| {
            let names: Vec<&str> = FORMAT_NAMES.iter().map(|(n, _)| *n).collect();
            ApiError::BadRequest(format!(
                "unknown format {f:?}: use a media type or one of {}",
                names.join(", ")
            ))
        })
}

/// What the client asked for, for a 406's message.
fn asked(format: Option<&str>, headers: &HeaderMap) -> String {
    match format {
        Some(f) => format!("format={f:?} cannot be served"),
        None => {
            let accept: Vec<&str> = headers
                .get_all(header::ACCEPT)
                .iter()
                .map(|v| v.to_str().unwrap_or("?"))
                .collect();
            format!("nothing in Accept: {:?} can be served", accept.join(", "))
        }
    }
}

/// The canonical media types of `offers`, without the aliases.
fn offered<T: Copy + PartialEq>(offers: &[(&str, T)]) -> String {
    let mut names: Vec<&str> = Vec::new();
    for (i, (name, value)) in offers.iter().enumerate() {
        if !offers[..i].iter().any(|(_, v)| v == value) {
            names.push(name);
        }
    }
    names.join(", ")
}

/// Writes `triples` in `format`. Turtle and TriG get the model's prefixes, for people.
pub(crate) fn write_graph(
    triples: &[Triple],
    format: RdfFormat,
) -> Result<Vec<u8>, std::io::Error> {
    let mut serializer = RdfSerializer::from_format(format);
    if matches!(format, RdfFormat::Turtle | RdfFormat::TriG) {
        for (prefix, iri) in shoal_semantic::vocab::PREFIXES {
            serializer = serializer
                .with_prefix(prefix, iri)
                .map_err(std::io::Error::other)?;
        }
    }
    let mut out = serializer.for_writer(Vec::new());
    for t in triples {
        out.serialize_triple(t)?;
    }
    out.finish()
}

/// The body and media type of `result` in the negotiated format; 406 when the request
/// accepts no format for this kind of result.
pub(crate) fn render(
    result: &QueryResult,
    n: Negotiated,
) -> Result<(Vec<u8>, &'static str), ApiError> {
    match result {
        QueryResult::Graph { triples, .. } => {
            let format = n.graph.ok_or_else(|| {
                ApiError::NotAcceptable(format!(
                    "a CONSTRUCT or DESCRIBE result is served as {}, which the request does not accept",
                    offered(&GRAPH_OFFERS)
                ))
            })?;
            // RDF/XML cannot write every predicate (one whose IRI ends in no XML name):
            // the request asked for a format this result has no form in.
            let body = write_graph(triples, format).map_err(|e| {
                ApiError::NotAcceptable(format!(
                    "this result cannot be written as {}: {e}; ask for another format",
                    format.name()
                ))
            })?;
            Ok((body, format.media_type()))
        }
        _ => {
            let format = n.solutions.ok_or_else(|| {
                ApiError::NotAcceptable(format!(
                    "a SELECT or ASK result is served as {}, which the request does not accept",
                    offered(&SOLUTION_OFFERS)
                ))
            })?;
            let body = result
                .write(format, Vec::new())
                .map_err(|e| ApiError::Internal(e.to_string()))?;
            Ok((body, format.media_type()))
        }
    }
}

async fn run(
    s: StationHandle,
    limits: &Limits,
    query: String,
    n: Negotiated,
) -> Result<Response, ApiError> {
    // The turn is held by the query itself, not the request: one whose client gave up
    // still counts until it has finished.
    let turn = limits.sparql_turn().await?;
    let snapshot = s.semantic_snapshot();
    let result = tokio::task::spawn_blocking(move || {
        let _turn = turn;
        let result = snapshot.query(&query, &QueryLimits::default())?;
        Ok::<_, QueryError>((render(&result, n), result.len()))
    })
    .await
    .map_err(|e| ApiError::Internal(e.to_string()))?;
    match result {
        Ok((rendered, _)) => {
            let (body, media_type) = rendered?;
            Ok((
                [(header::CONTENT_TYPE, media_type), (header::VARY, "accept")],
                body,
            )
                .into_response())
        }
        Err(e @ QueryError::Timeout(_)) => Err(ApiError::Unavailable(e.to_string())),
        Err(e @ QueryError::Serialize(_)) => Err(ApiError::Internal(e.to_string())),
        // Syntax, UPDATE, length, and evaluation errors (a SERVICE call, say) are all
        // about the query the client sent.
        Err(e) => Err(ApiError::BadRequest(e.to_string())),
    }
}

fn check_dataset(p: &SparqlParams) -> Result<(), ApiError> {
    if p.default_graph_uri.is_some() || p.named_graph_uri.is_some() {
        return Err(ApiError::BadRequest(
            "default-graph-uri and named-graph-uri are not supported: queries run over the whole model".into(),
        ));
    }
    Ok(())
}

/// `GET /api/sparql?query=...`.
pub(crate) async fn get(
    State(s): State<StationHandle>,
    State(limits): State<Arc<Limits>>,
    headers: HeaderMap,
    q: Result<Query<SparqlParams>, QueryRejection>,
) -> Result<Response, ApiError> {
    let Query(p) = q.map_err(|e| ApiError::BadRequest(e.body_text()))?;
    check_dataset(&p)?;
    let query = p
        .query
        .ok_or_else(|| ApiError::BadRequest("missing the `query` parameter".into()))?;
    let n = negotiate(p.format.as_deref(), &headers)?;
    run(s, &limits, query, n).await
}

/// `POST /api/sparql`: `application/sparql-query` (the query is the body) or
/// `application/x-www-form-urlencoded` (`query=...`), as in the SPARQL 1.1 Protocol §2.1.
pub(crate) async fn post(
    State(s): State<StationHandle>,
    State(limits): State<Arc<Limits>>,
    headers: HeaderMap,
    q: Result<Query<SparqlParams>, QueryRejection>,
    body: Result<Bytes, BytesRejection>,
) -> Result<Response, ApiError> {
    let Query(url) = q.map_err(|e| ApiError::BadRequest(e.body_text()))?;
    check_dataset(&url)?;
    let content_type = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("")
        .to_ascii_lowercase();
    let is_query = content_type.starts_with("application/sparql-query");
    let is_form = content_type.starts_with("application/x-www-form-urlencoded");
    if !is_query && !is_form {
        return Err(ApiError::UnsupportedMediaType(
            "send the query as application/sparql-query or application/x-www-form-urlencoded"
                .into(),
        ));
    }
    let body = body.map_err(|e| crate::extract::bytes_rejection(&e))?;
    let text = std::str::from_utf8(&body)
        .map_err(|_| ApiError::BadRequest("the request body is not UTF-8".into()))?;
    let (query, form_format) = if is_query {
        (text.to_owned(), None)
    } else {
        let p: SparqlParams =
            serde_urlencoded::from_str(text).map_err(|e| ApiError::BadRequest(e.to_string()))?;
        check_dataset(&p)?;
        (
            p.query
                .ok_or_else(|| ApiError::BadRequest("missing the `query` field".into()))?,
            p.format,
        )
    };
    let n = negotiate(form_format.as_deref().or(url.format.as_deref()), &headers)?;
    run(s, &limits, query, n).await
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::http::HeaderValue;
    use oxrdf::{Literal, NamedNode};

    fn accept(value: &str) -> HeaderMap {
        let mut h = HeaderMap::new();
        h.insert(header::ACCEPT, HeaderValue::from_str(value).unwrap());
        h
    }

    fn graph(value: &str) -> Option<RdfFormat> {
        negotiate(None, &accept(value)).ok().and_then(|n| n.graph)
    }

    fn solutions(value: &str) -> Option<ResultFormat> {
        negotiate(None, &accept(value))
            .ok()
            .and_then(|n| n.solutions)
    }

    #[test]
    fn without_accept_solutions_are_json_and_graphs_turtle() {
        let n = negotiate(None, &HeaderMap::new()).unwrap();
        assert_eq!(n.solutions, Some(ResultFormat::Json));
        assert_eq!(n.graph, Some(RdfFormat::Turtle));
        assert_eq!(negotiate(None, &accept("*/*")).unwrap(), n);
    }

    #[test]
    fn each_rdf_media_type_gets_its_format() {
        for (media_type, format) in GRAPH_OFFERS {
            assert_eq!(graph(media_type), Some(format), "{media_type}");
        }
        assert_eq!(graph("application/n-triples"), Some(RdfFormat::NTriples));
        assert_eq!(graph("text/*"), Some(RdfFormat::Turtle));
        assert_eq!(graph("application/*"), Some(RdfFormat::NTriples));
    }

    #[test]
    fn each_results_media_type_gets_its_format() {
        for (media_type, format) in SOLUTION_OFFERS {
            assert_eq!(solutions(media_type), Some(format), "{media_type}");
        }
        assert_eq!(solutions("text/*"), Some(ResultFormat::Csv));
    }

    #[test]
    fn a_client_asking_for_one_kind_gets_406_for_the_other() {
        let n = negotiate(None, &accept("application/n-triples")).unwrap();
        assert_eq!(n.solutions, None);
        let ask = QueryResult::Boolean(true);
        let Err(ApiError::NotAcceptable(msg)) = render(&ask, n) else {
            panic!("an ASK answered as N-Triples");
        };
        assert!(msg.contains("application/sparql-results+json"), "{msg}");
        let n = negotiate(None, &accept("text/csv")).unwrap();
        let empty = QueryResult::Graph {
            triples: Vec::new(),
            truncated: false,
        };
        assert!(matches!(render(&empty, n), Err(ApiError::NotAcceptable(_))));
    }

    #[test]
    fn a_request_that_accepts_nothing_servable_is_refused_before_running() {
        let Err(ApiError::NotAcceptable(msg)) = negotiate(None, &accept("image/png, text/html"))
        else {
            panic!("image/png was accepted");
        };
        assert!(
            msg.contains("text/turtle") && msg.contains("text/csv"),
            "{msg}"
        );
        assert!(msg.contains("image/png"), "{msg}");
        // Aliases are not listed twice.
        assert!(!msg.contains("application/xml"), "{msg}");
    }

    #[test]
    fn the_format_parameter_overrides_accept() {
        let h = accept("text/csv");
        let n = negotiate(Some("json"), &h).unwrap();
        assert_eq!(n.solutions, Some(ResultFormat::Json));
        assert_eq!(n.graph, Some(JSON_LD));
        let n = negotiate(Some("nt"), &h).unwrap();
        assert_eq!((n.solutions, n.graph), (None, Some(RdfFormat::NTriples)));
        let n = negotiate(Some("application/rdf+xml"), &h).unwrap();
        assert_eq!(n.graph, Some(RdfFormat::RdfXml));
        assert!(matches!(
            negotiate(Some("yaml"), &h),
            Err(ApiError::BadRequest(_))
        ));
        assert!(matches!(
            negotiate(Some("image/png"), &h),
            Err(ApiError::NotAcceptable(_))
        ));
    }

    fn sample() -> Vec<Triple> {
        vec![Triple::new(
            NamedNode::new_unchecked("https://example.invalid/shoal/id/vehicle/auv-1"),
            NamedNode::new_unchecked("https://example.invalid/shoal/ontology#batteryLevel"),
            Literal::from(81.5),
        )]
    }

    #[test]
    fn graphs_are_written_in_every_offered_format() {
        for (media_type, format) in GRAPH_OFFERS {
            let body = write_graph(&sample(), format).unwrap();
            let text = String::from_utf8(body).unwrap();
            assert!(text.contains("81.5"), "{media_type}: {text}");
        }
        let ttl = String::from_utf8(write_graph(&sample(), RdfFormat::Turtle).unwrap()).unwrap();
        assert!(ttl.contains("@prefix shoal:"), "{ttl}");
    }

    #[test]
    fn a_graph_rdf_xml_cannot_carry_is_406_not_500() {
        let odd = vec![Triple::new(
            NamedNode::new_unchecked("https://example.invalid/s"),
            NamedNode::new_unchecked("https://example.invalid/p/1"),
            Literal::from(1),
        )];
        let result = QueryResult::Graph {
            triples: odd,
            truncated: false,
        };
        let n = negotiate(None, &accept("application/rdf+xml")).unwrap();
        match render(&result, n) {
            Ok((body, media_type)) => assert_eq!(media_type, "application/rdf+xml", "{body:?}"),
            Err(e) => assert!(matches!(e, ApiError::NotAcceptable(_)), "{e:?}"),
        }
    }
}
