//! `ORDER BY` on projected variables, done on the materialised rows.
//!
//! The SPARQL evaluator sorts by turning both compared terms back into owned values at
//! every comparison (an allocation and a dictionary look-up per IRI, twice per
//! comparison): sorting the 2000 tasks of the standard query `q3_tasks_by_state` took
//! longer than finding them. [`SemanticStore::query`](crate::SemanticStore::query) has to
//! materialise the rows anyway, so for the common shape, a `SELECT` ending in
//! `ORDER BY` on plain variables (optionally `LIMIT`/`OFFSET`), it runs the query without
//! its solution modifiers and sorts the rows by reference.
//!
//! The order must be exactly SPARQL's (as spareval implements it): unbound first, then
//! blank nodes, IRIs and literals, literals by value where SPARQL compares them. Only
//! columns whose literals are all of one kind that compares as a total order (plain or
//! `xsd:string` strings, strings of one language, valid `xsd:double` except NaN, valid
//! `xsd:integer`) are sorted here; anything else returns `None` and the query runs as
//! written. The text is split with a small lexer that knows strings, IRIs and comments,
//! and anything unexpected after the last top-level `}` also means "run it as written".

use std::cmp::Ordering;

use oxrdf::{Term, Variable, vocab::rdf, vocab::xsd};

/// A query split into its body and the solution modifiers done here.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Split<'a> {
    /// The query without its trailing `ORDER BY`/`LIMIT`/`OFFSET`.
    pub(crate) body: &'a str,
    /// Sort keys in order, `true` for `DESC`.
    pub(crate) keys: Vec<(Variable, bool)>,
    /// `OFFSET`, 0 if absent.
    pub(crate) offset: usize,
    /// `LIMIT`, if any.
    pub(crate) limit: Option<usize>,
}

/// Splits a `SELECT` query ending in `ORDER BY` on variables; `None` for anything else.
pub(crate) fn split(query: &str) -> Option<Split<'_>> {
    let b = query.as_bytes();
    let (mut i, mut depth) = (0usize, 0usize);
    let (mut end_of_body, mut form_seen) = (None, false);
    while i < b.len() {
        match b[i] {
            b'#' => {
                while i < b.len() && b[i] != b'\n' {
                    i += 1;
                }
            }
            q @ (b'"' | b'\'') => i = skip_string(b, i, q)?,
            b'<' => {
                if let Some(close) = iri_end(b, i) {
                    i = close;
                }
            }
            b'{' => depth += 1,
            b'}' => {
                depth = depth.checked_sub(1)?;
                if depth == 0 {
                    end_of_body = Some(i + 1);
                }
            }
            c if c.is_ascii_alphabetic() && depth == 0 && !form_seen => {
                let start = i;
                while i < b.len() && (b[i].is_ascii_alphanumeric() || b[i] == b'_') {
                    i += 1;
                }
                let word = &query[start..i];
                // `select:` is a prefix name, not the keyword.
                if b.get(i) == Some(&b':') {
                    continue;
                }
                let preceded_by_name_char = start > 0
                    && (b[start - 1].is_ascii_alphanumeric()
                        || matches!(b[start - 1], b'_' | b':' | b'?' | b'$' | b'.' | b'-'));
                if preceded_by_name_char {
                    continue;
                }
                if word.eq_ignore_ascii_case("SELECT") {
                    form_seen = true;
                } else if !(word.eq_ignore_ascii_case("PREFIX")
                    || word.eq_ignore_ascii_case("BASE"))
                {
                    // CONSTRUCT, ASK, DESCRIBE or something unexpected.
                    return None;
                }
                continue;
            }
            _ => {}
        }
        i += 1;
    }
    if depth != 0 || !form_seen {
        return None;
    }
    let end_of_body = end_of_body?;
    let mut tail = Tail {
        b,
        text: query,
        i: end_of_body,
    };
    if !(tail.keyword("ORDER") && tail.keyword("BY")) {
        return None;
    }
    let mut keys = Vec::new();
    loop {
        let desc = if tail.keyword("ASC") {
            Some(false)
        } else if tail.keyword("DESC") {
            Some(true)
        } else {
            None
        };
        match desc {
            Some(desc) => {
                if !tail.punct(b'(') {
                    return None;
                }
                let v = tail.variable()?;
                if !tail.punct(b')') {
                    return None;
                }
                keys.push((v, desc));
            }
            None => match tail.variable() {
                Some(v) => keys.push((v, false)),
                None => break,
            },
        }
    }
    if keys.is_empty() {
        return None;
    }
    let (mut offset, mut limit) = (None, None);
    loop {
        if limit.is_none() && tail.keyword("LIMIT") {
            limit = Some(tail.integer()?);
        } else if offset.is_none() && tail.keyword("OFFSET") {
            offset = Some(tail.integer()?);
        } else {
            break;
        }
    }
    tail.skip_blank();
    if tail.i != b.len() {
        return None;
    }
    Some(Split {
        body: &query[..end_of_body],
        keys,
        offset: offset.unwrap_or(0),
        limit,
    })
}

/// Index just past the string starting at `i` (short or long form, with escapes).
fn skip_string(b: &[u8], i: usize, q: u8) -> Option<usize> {
    let long = b.get(i + 1) == Some(&q) && b.get(i + 2) == Some(&q);
    let mut j = if long { i + 3 } else { i + 1 };
    while j < b.len() {
        match b[j] {
            b'\\' => j += 2,
            c if c == q => {
                if !long {
                    return Some(j);
                }
                if b.get(j + 1) == Some(&q) && b.get(j + 2) == Some(&q) {
                    // A long string may end with quotes of its own kind: `'''a''''`.
                    let mut k = j + 3;
                    while b.get(k) == Some(&q) {
                        k += 1;
                    }
                    return Some(k - 1);
                }
                j += 1;
            }
            b'\n' | b'\r' if !long => return None,
            _ => j += 1,
        }
    }
    None
}

/// Index of the `>` closing an IRI reference opened at `i`, if it is one (`<` is also
/// the less-than operator; an IRI cannot contain spaces, quotes or braces).
fn iri_end(b: &[u8], i: usize) -> Option<usize> {
    for (j, &c) in b.iter().enumerate().skip(i + 1) {
        match c {
            b'>' => return Some(j),
            b'<' | b'"' | b'{' | b'}' | b'|' | b'^' | b'`' | b'\\' => return None,
            c if c <= b' ' => return None,
            _ => {}
        }
    }
    None
}

/// The solution modifiers after the body.
struct Tail<'a> {
    b: &'a [u8],
    text: &'a str,
    i: usize,
}

impl Tail<'_> {
    fn skip_blank(&mut self) {
        while self.i < self.b.len() {
            match self.b[self.i] {
                c if c.is_ascii_whitespace() => self.i += 1,
                b'#' => {
                    while self.i < self.b.len() && self.b[self.i] != b'\n' {
                        self.i += 1;
                    }
                }
                _ => break,
            }
        }
    }

    fn keyword(&mut self, word: &str) -> bool {
        self.skip_blank();
        let end = self.i + word.len();
        let matches = self
            .text
            .get(self.i..end)
            .is_some_and(|w| w.eq_ignore_ascii_case(word))
            && !self
                .b
                .get(end)
                .is_some_and(|c| c.is_ascii_alphanumeric() || *c == b'_' || *c >= 0x80);
        if matches {
            self.i = end;
        }
        matches
    }

    fn punct(&mut self, c: u8) -> bool {
        self.skip_blank();
        let matches = self.b.get(self.i) == Some(&c);
        if matches {
            self.i += 1;
        }
        matches
    }

    fn variable(&mut self) -> Option<Variable> {
        self.skip_blank();
        if !matches!(self.b.get(self.i), Some(b'?' | b'$')) {
            return None;
        }
        let start = self.i + 1;
        let mut end = start;
        while end < self.b.len()
            && (self.b[end].is_ascii_alphanumeric() || self.b[end] == b'_' || self.b[end] >= 0x80)
        {
            end += 1;
        }
        let v = Variable::new(self.text.get(start..end)?).ok()?;
        self.i = end;
        Some(v)
    }

    fn integer(&mut self) -> Option<usize> {
        self.skip_blank();
        let start = self.i;
        while self.i < self.b.len() && self.b[self.i].is_ascii_digit() {
            self.i += 1;
        }
        self.text.get(start..self.i)?.parse().ok()
    }
}

/// How the literals of one sort column compare; one kind per column.
#[derive(Debug, Clone, PartialEq)]
enum Kind {
    /// Plain or `xsd:string`: by value.
    Text,
    /// Language-tagged, all with this tag: by value.
    Lang(String),
    /// `xsd:double`, none NaN: by number.
    Double,
    /// `xsd:integer`: by number.
    Integer,
}

/// A literal's kind and its sort key, from one look at it; `None` for a literal this
/// module does not compare.
fn literal_key(l: &oxrdf::Literal) -> Option<(Kind, Key<'_>)> {
    if let Some(lang) = l.language() {
        return Some((Kind::Lang(lang.to_owned()), Key::Text(l.value())));
    }
    let d = l.datatype();
    if d == xsd::STRING {
        Some((Kind::Text, Key::Text(l.value())))
    } else if d == xsd::DOUBLE {
        xsd_double(l.value())
            .filter(|v| !v.is_nan())
            .map(|v| (Kind::Double, Key::Double(v)))
    } else if d == xsd::INTEGER {
        xsd_integer(l.value()).map(|v| (Kind::Integer, Key::Integer(v)))
    } else {
        // rdf:langString without a tag cannot occur; everything else is not handled.
        debug_assert_ne!(d, rdf::LANG_STRING);
        None
    }
}

/// The value of a valid `xsd:double` lexical form (`(+|-)?(digits(.digits?)?|.digits)(e(+|-)?digits)?`,
/// `INF`, `-INF`, `+INF`, `NaN`); `None` for an invalid one, which SPARQL does not compare.
fn xsd_double(s: &str) -> Option<f64> {
    match s {
        "INF" | "+INF" => return Some(f64::INFINITY),
        "-INF" => return Some(f64::NEG_INFINITY),
        "NaN" => return Some(f64::NAN),
        _ => {}
    }
    let b = s.as_bytes();
    let mut i = usize::from(matches!(b.first(), Some(b'+' | b'-')));
    let int_digits = b[i..].iter().take_while(|c| c.is_ascii_digit()).count();
    i += int_digits;
    let mut frac_digits = 0;
    if b.get(i) == Some(&b'.') {
        i += 1;
        frac_digits = b[i..].iter().take_while(|c| c.is_ascii_digit()).count();
        i += frac_digits;
    }
    if int_digits + frac_digits == 0 {
        return None;
    }
    if matches!(b.get(i), Some(b'e' | b'E')) {
        i += 1;
        i += usize::from(matches!(b.get(i), Some(b'+' | b'-')));
        let exp_digits = b[i..].iter().take_while(|c| c.is_ascii_digit()).count();
        if exp_digits == 0 {
            return None;
        }
        i += exp_digits;
    }
    if i != b.len() {
        return None;
    }
    s.parse().ok()
}

/// The value of a valid `xsd:integer` that fits 64 bits (Oxigraph's range).
fn xsd_integer(s: &str) -> Option<i64> {
    let digits = s.strip_prefix(['+', '-']).unwrap_or(s);
    if digits.is_empty() || !digits.bytes().all(|c| c.is_ascii_digit()) {
        return None;
    }
    s.parse().ok()
}

/// A row of terms, one cell per projected variable (`None` = unbound).
pub(crate) trait Cells {
    fn cells(&self) -> &[Option<Term>];
}

impl Cells for Vec<Option<Term>> {
    fn cells(&self) -> &[Option<Term>] {
        self
    }
}

impl Cells for sparesults::QuerySolution {
    fn cells(&self) -> &[Option<Term>] {
        self.values()
    }
}

/// Sorts `rows` (cells in `variables` order) by `keys` as SPARQL `ORDER BY` does; `false`,
/// leaving `rows` untouched, when a key is not projected or a column holds literals this
/// module does not compare.
pub(crate) fn sort<R: Cells>(
    rows: &mut [R],
    variables: &[Variable],
    keys: &[(Variable, bool)],
) -> bool {
    // Each cell is reduced once to what the order looks at (a number parsed, a string
    // borrowed) while its column's kind is checked, and the sort moves row numbers over
    // those keys: comparing terms in place re-parsed numbers and compared datatype IRIs at
    // every comparison, and chased two pointers per cell.
    let mut columns: Vec<(Vec<Key<'_>>, bool)> = Vec::with_capacity(keys.len());
    for (v, desc) in keys {
        let Some(c) = variables.iter().position(|x| x == v) else {
            return false;
        };
        let Some(column) = column_keys(rows, c) else {
            return false;
        };
        columns.push((column, *desc));
    }
    let mut order: Vec<usize> = (0..rows.len()).collect();
    order.sort_unstable_by(|&a, &b| {
        for (column, desc) in &columns {
            let o = column[a].cmp(&column[b]);
            let o = if *desc { o.reverse() } else { o };
            if o != Ordering::Equal {
                return o;
            }
        }
        Ordering::Equal
    });
    permute(rows, order);
    true
}

/// Reorders `rows` so that row `i` becomes the one that was at `order[i]`, by swaps along
/// the permutation's cycles (the rows need not be `Clone`).
fn permute<R>(rows: &mut [R], mut order: Vec<usize>) {
    for start in 0..order.len() {
        let mut at = start;
        loop {
            let from = order[at];
            order[at] = at;
            if from == start {
                break;
            }
            rows.swap(at, from);
            at = from;
        }
    }
}

/// A cell as SPARQL's order sees it, within a column already checked by [`sort`] (its
/// literals all of one [`Kind`]).
#[derive(Debug, Clone, Copy)]
enum Key<'a> {
    Unbound,
    Blank(&'a str),
    Iri(&'a str),
    /// A string, plain, `xsd:string` or of the column's one language.
    Text(&'a str),
    Double(f64),
    Integer(i64),
}

impl Key<'_> {
    /// Unbound first, then blank nodes, IRIs and literals.
    fn rank(&self) -> u8 {
        match self {
            Self::Unbound => 0,
            Self::Blank(_) => 1,
            Self::Iri(_) => 2,
            Self::Text(_) | Self::Double(_) | Self::Integer(_) => 3,
        }
    }

    fn cmp(&self, other: &Self) -> Ordering {
        match (self, other) {
            (Self::Blank(x), Self::Blank(y))
            | (Self::Iri(x), Self::Iri(y))
            | (Self::Text(x), Self::Text(y)) => x.cmp(y),
            (Self::Double(x), Self::Double(y)) => x.partial_cmp(y).unwrap_or(Ordering::Equal),
            (Self::Integer(x), Self::Integer(y)) => x.cmp(y),
            _ => self.rank().cmp(&other.rank()),
        }
    }
}

/// Column `c`'s sort keys, one per row; `None` when its literals are not all of one
/// [`Kind`] that this module compares.
fn column_keys<R: Cells>(rows: &[R], c: usize) -> Option<Vec<Key<'_>>> {
    let mut kind: Option<Kind> = None;
    let mut keys = Vec::with_capacity(rows.len());
    for row in rows {
        keys.push(match row.cells().get(c).and_then(Option::as_ref) {
            None => Key::Unbound,
            Some(Term::BlankNode(b)) => Key::Blank(b.as_str()),
            Some(Term::NamedNode(n)) => Key::Iri(n.as_str()),
            Some(Term::Literal(l)) => {
                let (k, key) = literal_key(l)?;
                match &kind {
                    None => kind = Some(k),
                    Some(seen) if *seen == k => {}
                    Some(_) => return None,
                }
                key
            }
            #[allow(unreachable_patterns)]
            Some(_) => return None,
        });
    }
    Some(keys)
}

#[cfg(test)]
mod tests {
    use super::*;

    use proptest::prelude::{Just, Strategy};

    proptest::proptest! {
        /// Any permutation is applied as "row i becomes the row that was at order[i]".
        #[test]
        fn permute_applies_any_order(order in Just(()).prop_flat_map(|()| {
            (0usize..40).prop_flat_map(|n| Just((0..n).collect::<Vec<_>>()).prop_shuffle())
        })) {
            let rows: Vec<String> = (0..order.len()).map(|i| format!("row {i}")).collect();
            let mut moved = rows.clone();
            permute(&mut moved, order.clone());
            let expected: Vec<String> = order.iter().map(|&i| rows[i].clone()).collect();
            proptest::prop_assert_eq!(moved, expected);
        }
    }

    fn keys(s: &Split<'_>) -> Vec<(String, bool)> {
        s.keys
            .iter()
            .map(|(v, d)| (v.as_str().to_owned(), *d))
            .collect()
    }

    #[test]
    fn the_standard_queries_split_at_their_order_by() {
        for (name, q) in crate::STANDARD_QUERIES {
            let s = split(q).unwrap_or_else(|| panic!("{name}"));
            assert!(s.body.trim_end().ends_with('}'), "{name}");
            assert!(!s.body.contains("ORDER BY"), "{name}");
        }
        let q3 = split(crate::STANDARD_QUERIES[2].1).unwrap();
        assert_eq!(keys(&q3), [("state".into(), false), ("task".into(), false)]);
    }

    #[test]
    fn modifiers_are_read_in_any_spelling_and_order() {
        let s = split(
            "PREFIX select: <http://x/> select ?a ?b { ?a ?p ?b } order by desc(?b) $a\n# done\n offset 2 limit 10",
        )
        .unwrap();
        assert_eq!(
            s.body,
            "PREFIX select: <http://x/> select ?a ?b { ?a ?p ?b }"
        );
        assert_eq!(keys(&s), [("b".into(), true), ("a".into(), false)]);
        assert_eq!((s.offset, s.limit), (2, Some(10)));
    }

    #[test]
    fn braces_in_strings_iris_and_comments_do_not_count() {
        let q = "SELECT ?s WHERE { ?s ?p \"}\" . ?s ?q '''}'''. # }\n ?s <http://x/}> ?o FILTER(?o < 3) } ORDER BY ?s";
        // `<http://x/}>` is not an IRI (braces are not allowed), so its `}` counts: the
        // body would end early and the rest cannot be read as modifiers.
        assert_eq!(split(q), None);
        let q = "SELECT ?s WHERE { ?s ?p \"}\" . ?s ?q '''}'''. # }\n ?s <http://x/#y> ?o FILTER(?o < 3) } ORDER BY ?s";
        let s = split(q).unwrap();
        assert!(s.body.ends_with("FILTER(?o < 3) }"));
    }

    #[test]
    fn other_shapes_are_left_to_the_engine() {
        for q in [
            "SELECT ?s WHERE { ?s ?p ?o }",
            "SELECT ?s WHERE { ?s ?p ?o } LIMIT 3",
            "SELECT ?s WHERE { ?s ?p ?o } ORDER BY STR(?s)",
            "SELECT ?s WHERE { ?s ?p ?o } ORDER BY ?s LIMIT",
            "SELECT ?s WHERE { ?s ?p ?o } GROUP BY ?s ORDER BY ?s",
            "SELECT ?s WHERE { ?s ?p ?o } ORDER BY ?s VALUES ?s { <http://x> }",
            "CONSTRUCT { ?s ?p ?o } WHERE { ?s ?p ?o } ORDER BY ?s",
            "ASK { ?s ?p ?o }",
            "SELECT ?s WHERE { ?s ?p ?o } ORDER BY ?s LIMIT 1 LIMIT 2",
        ] {
            assert_eq!(split(q), None, "{q}");
        }
    }

    #[test]
    fn xsd_lexical_forms_are_checked() {
        assert_eq!(xsd_double("1.95E1"), Some(19.5));
        assert_eq!(xsd_double("-.5e-1"), Some(-0.05));
        assert_eq!(xsd_double("-INF"), Some(f64::NEG_INFINITY));
        for bad in ["", ".", "1e", "inf", "infinity", "1,5", "0x10", " 1"] {
            assert_eq!(xsd_double(bad), None, "{bad:?}");
        }
        assert_eq!(xsd_integer("+42"), Some(42));
        assert_eq!(xsd_integer("4.0"), None);
        assert_eq!(xsd_integer("99999999999999999999"), None);
    }

    #[test]
    fn columns_mixing_literal_kinds_are_refused() {
        use oxrdf::Literal;
        let v = [Variable::new_unchecked("x")];
        let keys = [(Variable::new_unchecked("x"), false)];
        let row = |t: Term| vec![Some(t)];
        let mut rows = vec![
            row(Literal::from(2.5).into()),
            row(Literal::from(-1.0).into()),
            row(oxrdf::NamedNode::new_unchecked("http://x").into()),
        ];
        assert!(sort(&mut rows, &v, &keys));
        assert_eq!(
            rows[0][0],
            Some(oxrdf::NamedNode::new_unchecked("http://x").into())
        );
        assert_eq!(rows[1][0], Some(Literal::from(-1.0).into()));
        rows.push(row(Literal::from("a").into()));
        let before = rows.clone();
        assert!(!sort(&mut rows, &v, &keys));
        assert_eq!(rows, before);
        let mut nan = vec![
            row(Literal::from(f64::NAN).into()),
            row(Literal::from(1.0).into()),
        ];
        assert!(!sort(&mut nan, &v, &keys));
        let other = [(Variable::new_unchecked("y"), false)];
        assert!(!sort(&mut rows, &v, &other));
    }
}
