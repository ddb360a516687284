//! Proactive content negotiation on the `Accept` request header (RFC 9110 §12.5.1).
//!
//! [`Accept`] holds the media ranges a client sent; [`Accept::choose`] picks, among the
//! representations a handler can produce (its offers, in the server's order of
//! preference), the one the client prefers. The SPARQL endpoint uses it to pick a results
//! or RDF format; anything that cannot be served becomes a 406.

use std::cmp::Reverse;

use axum::http::{HeaderMap, header};

/// How well an offer fits: weight, specificity of the range naming it, and the range's
/// position (earlier is better).
type Rank = (u16, u8, Reverse<usize>);

/// One media range of an `Accept` header, lower-cased.
#[derive(Debug, Clone, PartialEq)]
struct MediaRange {
    /// `*` or a type such as `application`.
    kind: String,
    /// `*` or a subtype such as `n-triples`.
    subtype: String,
    /// The weight, in thousandths (RFC 9110 §12.4.2 allows three decimals).
    q: u16,
}

impl MediaRange {
    /// How closely the range names `kind/subtype`: 2 exactly, 1 by `type/*`, 0 by `*/*`.
    fn specificity(&self, kind: &str, subtype: &str) -> Option<u8> {
        match (self.kind.as_str(), self.subtype.as_str()) {
            ("*", "*") => Some(0),
            (k, "*") if k == kind => Some(1),
            (k, s) if k == kind && s == subtype => Some(2),
            _ => None,
        }
    }
}

/// The media ranges of a request's `Accept` header(s), in the order sent.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Accept {
    ranges: Vec<MediaRange>,
}

impl Accept {
    /// Anything is acceptable: what a request without `Accept` means (RFC 9110 §12.5.1).
    pub(crate) fn any() -> Self {
        Self::parse("*/*")
    }

    /// The request's `Accept` headers (several are one comma-separated list); [`Accept::any`]
    /// when there is none or it is blank.
    pub(crate) fn from_headers(headers: &HeaderMap) -> Self {
        let values: Vec<&str> = headers
            .get_all(header::ACCEPT)
            .iter()
            // A value that is not visible ASCII names no media type we could match.
            .map(|v| v.to_str().unwrap_or(""))
            .collect();
        let joined = values.join(",");
        if joined.trim().is_empty() {
            return Self::any();
        }
        Self::parse(&joined)
    }

    /// Parses an `Accept` value. Malformed elements (no `/`, `*/subtype`, a weight that is
    /// not a number from 0 to 1) are skipped, so a header of nothing but garbage accepts
    /// nothing. A `charset` other than UTF-8 makes its range match nothing: every body
    /// here is UTF-8. Other parameters are ignored.
    pub(crate) fn parse(value: &str) -> Self {
        let ranges = value.split(',').filter_map(parse_range).collect();
        Self { ranges }
    }

    /// The offer the client prefers: the highest weight of the most specific range naming
    /// each offer, ties going to the more specific range, then to the range the client
    /// listed first, then to the earlier offer. `None` when every offer has weight 0.
    /// Offers are `type/subtype` in lower case.
    pub(crate) fn choose<T: Copy>(&self, offers: &[(&str, T)]) -> Option<T> {
        let mut best: Option<(Rank, T)> = None;
        for (media_type, value) in offers {
            let Some((kind, subtype)) = media_type.split_once('/') else {
                continue;
            };
            // The most specific range naming this offer decides its weight; among equally
            // specific ones, the first.
            let mut named: Option<(u8, usize, u16)> = None;
            for (i, r) in self.ranges.iter().enumerate() {
                if let Some(s) = r.specificity(kind, subtype)
                    && named.is_none_or(|(best_s, _, _)| s > best_s)
                {
                    named = Some((s, i, r.q));
                }
            }
            let Some((specificity, index, q)) = named else {
                continue;
            };
            if q == 0 {
                continue;
            }
            let key: Rank = (q, specificity, Reverse(index));
            // Strictly better only: an equal key keeps the earlier offer.
            if best.as_ref().is_none_or(|(k, _)| key > *k) {
                best = Some((key, *value));
            }
        }
        best.map(|(_, v)| v)
    }
}

fn parse_range(element: &str) -> Option<MediaRange> {
    let mut parts = element.split(';');
    let (kind, subtype) = parts.next()?.trim().split_once('/')?;
    let (kind, subtype) = (kind.trim(), subtype.trim());
    let token = |s: &str| {
        !s.is_empty()
            && s.bytes()
                .all(|b| b.is_ascii_alphanumeric() || b"!#$&-^_.+*".contains(&b))
    };
    if !token(kind) || !token(subtype) || (kind == "*" && subtype != "*") {
        return None;
    }
    let mut q = 1000;
    let mut utf8 = true;
    for param in parts {
        let Some((name, value)) = param.split_once('=') else {
            continue;
        };
        let value = value.trim().trim_matches('"');
        match name.trim().to_ascii_lowercase().as_str() {
            "q" => q = parse_weight(value)?,
            "charset" => {
                utf8 = matches!(value.to_ascii_lowercase().as_str(), "utf-8" | "utf8");
            }
            _ => {}
        }
    }
    Some(MediaRange {
        kind: kind.to_ascii_lowercase(),
        subtype: subtype.to_ascii_lowercase(),
        q: if utf8 { q } else { 0 },
    })
}

/// RFC 9110 §12.4.2: `0[.ddd]` or `1[.000]`, in thousandths.
fn parse_weight(s: &str) -> Option<u16> {
    let (int, frac) = s.split_once('.').unwrap_or((s, ""));
    if frac.len() > 3 || !frac.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    let frac_value = format!("{frac:0<3}").parse::<u16>().ok()?;
    match int {
        "0" => Some(frac_value),
        "1" if frac_value == 0 => Some(1000),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::http::HeaderValue;

    const OFFERS: [(&str, char); 4] = [
        ("text/turtle", 't'),
        ("application/n-triples", 'n'),
        ("application/rdf+xml", 'x'),
        ("application/ld+json", 'j'),
    ];

    fn pick(accept: &str) -> Option<char> {
        Accept::parse(accept).choose(&OFFERS)
    }

    #[test]
    fn no_accept_header_takes_the_servers_first_choice() {
        assert_eq!(
            Accept::from_headers(&HeaderMap::new()).choose(&OFFERS),
            Some('t')
        );
        let mut blank = HeaderMap::new();
        blank.insert(header::ACCEPT, HeaderValue::from_static("  "));
        assert_eq!(Accept::from_headers(&blank).choose(&OFFERS), Some('t'));
        assert_eq!(pick("*/*"), Some('t'));
    }

    #[test]
    fn an_exact_type_wins_over_wildcards_at_the_same_weight() {
        assert_eq!(pick("*/*, application/ld+json"), Some('j'));
        assert_eq!(pick("application/*, text/plain"), Some('n'));
        assert_eq!(
            pick("application/*;q=0.9, application/rdf+xml;q=0.9"),
            Some('x')
        );
    }

    #[test]
    fn weights_order_the_choice() {
        assert_eq!(
            pick("text/turtle;q=0.5, application/n-triples;q=0.8"),
            Some('n')
        );
        assert_eq!(pick("text/turtle;q=0.001, */*;q=0"), Some('t'));
        // The most specific range decides an offer's weight, even when lower.
        assert_eq!(pick("*/*;q=0.9, text/turtle;q=0.1"), Some('n'));
        // Equal weight and specificity: the client's first listed.
        assert_eq!(
            pick("application/rdf+xml, application/n-triples"),
            Some('x')
        );
    }

    #[test]
    fn weight_zero_refuses_an_offer_even_under_a_wildcard() {
        assert_eq!(pick("text/turtle;q=0, */*"), Some('n'));
        assert_eq!(pick("*/*;q=0"), None);
        assert_eq!(pick("text/turtle;q=0"), None);
    }

    #[test]
    fn what_names_no_offer_is_not_acceptable() {
        assert_eq!(pick("application/sparql-results+json"), None);
        assert_eq!(pick("image/*"), None);
        assert_eq!(pick("garbage"), None);
        assert_eq!(pick("text/turtle;charset=latin1"), None);
        assert_eq!(pick("text/turtle;charset=latin1;q=1"), None);
    }

    #[test]
    fn matching_ignores_case_spaces_and_other_parameters() {
        assert_eq!(pick(" Text/Turtle ; Charset=UTF-8 ; q=1.0"), Some('t'));
        assert_eq!(
            pick("application/ld+json;profile=\"http://www.w3.org/ns/json-ld#expanded\""),
            Some('j')
        );
    }

    #[test]
    fn malformed_elements_are_skipped_not_fatal() {
        assert_eq!(pick("*/turtle, application/n-triples"), Some('n'));
        assert_eq!(
            pick("text/turtle;q=2, application/rdf+xml;q=0.5"),
            Some('x')
        );
        assert_eq!(pick("text/turtle;q=0.1234, application/rdf+xml"), Some('x'));
        assert_eq!(pick(",,application/ld+json,"), Some('j'));
    }

    #[test]
    fn several_accept_headers_are_one_list() {
        let mut h = HeaderMap::new();
        h.append(
            header::ACCEPT,
            HeaderValue::from_static("text/turtle;q=0.2"),
        );
        h.append(
            header::ACCEPT,
            HeaderValue::from_static("application/rdf+xml"),
        );
        assert_eq!(Accept::from_headers(&h).choose(&OFFERS), Some('x'));
    }

    #[test]
    fn weights_parse_as_rfc_9110_says() {
        assert_eq!(parse_weight("1"), Some(1000));
        assert_eq!(parse_weight("1.000"), Some(1000));
        assert_eq!(parse_weight("0.5"), Some(500));
        assert_eq!(parse_weight("0.05"), Some(50));
        assert_eq!(parse_weight("0"), Some(0));
        assert_eq!(parse_weight("1.5"), None);
        assert_eq!(parse_weight("-0"), None);
        assert_eq!(parse_weight("0.1234"), None);
        assert_eq!(parse_weight(""), None);
    }
}
