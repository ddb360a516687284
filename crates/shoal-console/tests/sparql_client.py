#!/usr/bin/env python3
"""An independent SPARQL 1.1 Protocol client against Shoal's /api/sparql.

Usage: sparql_client.py BASE_URL VEHICLE_ID

Asks the station for query results in every format it offers, with Accept headers as
clients write them (exact types, q-values, wildcards, none), and parses each answer with
rdflib chosen by the response's Content-Type alone: a mislabelled body fails to parse or
parses to the wrong thing. Graph results in every format must be the same graph
(isomorphic) as the N-Triples answer. What cannot be served must be a 406 whose JSON
message lists what can. Prints one line per case and a closing "N passed, N failed" line;
exits non-zero on any failure. Driven by crates/shoal-console/tests/sparql_protocol.rs.
"""
import io
import json
import sys
import urllib.error
import urllib.parse
import urllib.request

import rdflib
from rdflib.compare import isomorphic
from rdflib.query import Result

BASE = sys.argv[1].rstrip("/")
VEHICLE = sys.argv[2]
ENDPOINT = BASE + "/api/sparql"

CONSTRUCT = (
    "CONSTRUCT { ?v shoal:vehicleId ?id ; shoal:batteryLevel ?b } "
    "WHERE { ?v shoal:vehicleId ?id . OPTIONAL { ?v shoal:batteryLevel ?b } }"
)
DESCRIBE = f'DESCRIBE ?v WHERE {{ ?v shoal:vehicleId "{VEHICLE}" }}'
SELECT = "SELECT ?v ?id WHERE { ?v shoal:vehicleId ?id } ORDER BY ?id"
ASK = f'ASK {{ ?v shoal:vehicleId "{VEHICLE}" }}'

GRAPH_TYPES = [
    "text/turtle",
    "application/n-triples",
    "application/rdf+xml",
    "application/n-quads",
    "application/trig",
    "application/ld+json",
]
RESULT_TYPES = [
    "application/sparql-results+json",
    "application/sparql-results+xml",
    "text/csv",
    "text/tab-separated-values",
]

passed = 0
failed = 0


def check(name, ok, detail=""):
    global passed, failed
    if ok:
        passed += 1
        print(f"ok   {name}")
    else:
        failed += 1
        print(f"FAIL {name}: {detail}")


def request(query, accept=None, post=False, params=None):
    """(status, essence of Content-Type, full Content-Type, Vary, body)."""
    headers = {}
    if accept is not None:
        headers["Accept"] = accept
    if post:
        url = ENDPOINT + ("?" + urllib.parse.urlencode(params) if params else "")
        headers["Content-Type"] = "application/sparql-query"
        req = urllib.request.Request(url, data=query.encode(), headers=headers, method="POST")
    else:
        q = {"query": query, **(params or {})}
        req = urllib.request.Request(ENDPOINT + "?" + urllib.parse.urlencode(q), headers=headers)
    try:
        with urllib.request.urlopen(req, timeout=30) as res:
            status, h, body = res.status, res.headers, res.read()
    except urllib.error.HTTPError as e:
        status, h, body = e.code, e.headers, e.read()
    ct = h.get("Content-Type", "")
    return status, ct.split(";")[0].strip().lower(), ct, h.get("Vary", ""), body


def parse_graph(essence, body):
    """rdflib's parser registered for exactly this media type; the default graph."""
    ds = rdflib.Dataset()
    ds.parse(data=body, format=essence)
    g = rdflib.Graph()
    for s, p, o, _ in ds.quads((None, None, None, None)):
        g.add((s, p, o))
    return g


def parse_results(essence, body):
    return Result.parse(io.BytesIO(body), format=essence)


# Reference: the graph as N-Triples.
status, essence, _, _, body = request(CONSTRUCT, "application/n-triples")
check("CONSTRUCT as N-Triples", status == 200 and essence == "application/n-triples",
      f"{status} {essence}")
reference = parse_graph(essence, body)
ids = {str(o) for o in reference.objects(None, rdflib.URIRef(
    "https://example.invalid/shoal/ontology#vehicleId"))}
check("the reference graph names the vehicle", VEHICLE in ids, f"vehicle ids {sorted(ids)}")

for media_type in GRAPH_TYPES:
    for method in ("GET", "POST"):
        status, essence, ct, vary, body = request(CONSTRUCT, media_type, post=method == "POST")
        name = f"CONSTRUCT {method} Accept: {media_type}"
        if status != 200 or essence != media_type:
            check(name, False, f"{status}, Content-Type {ct!r}: {body[:200]!r}")
            continue
        try:
            g = parse_graph(essence, body)
        except Exception as e:  # noqa: BLE001 - any parse failure is the finding
            check(name, False, f"rdflib cannot parse it as {essence}: {e}")
            continue
        check(name, isomorphic(g, reference) and "accept" in vary.lower(),
              f"{len(g)} triples against {len(reference)}; Vary {vary!r}")

status, essence, _, _, body = request(DESCRIBE, "application/rdf+xml")
ok = status == 200 and essence == "application/rdf+xml"
check("DESCRIBE as RDF/XML", ok and len(parse_graph(essence, body)) > 0, f"{status} {essence}")

# Negotiation as clients write it.
for accept, expected in [
    (None, "text/turtle"),
    ("*/*", "text/turtle"),
    ("text/turtle;q=0.5, application/rdf+xml", "application/rdf+xml"),
    ("application/ld+json;q=0.2, application/n-quads;q=0.9, */*;q=0.1", "application/n-quads"),
    ("application/*", "application/n-triples"),
    ("text/turtle;q=0, */*", "application/n-triples"),
    ("application/sparql-results+json, application/n-triples;q=0.1", "application/n-triples"),
]:
    status, essence, ct, _, body = request(CONSTRUCT, accept)
    ok = status == 200 and essence == expected
    if ok:
        try:
            ok = isomorphic(parse_graph(essence, body), reference)
        except Exception as e:  # noqa: BLE001
            ok, ct = False, f"{ct}: {e}"
    check(f"CONSTRUCT Accept: {accept!r} -> {expected}", ok, f"{status} {ct!r}")

for fmt, expected in [("nt", "application/n-triples"), ("jsonld", "application/ld+json"),
                      ("xml", "application/rdf+xml")]:
    status, essence, ct, _, body = request(CONSTRUCT, "text/csv", params={"format": fmt})
    ok = status == 200 and essence == expected and isomorphic(parse_graph(essence, body), reference)
    check(f"CONSTRUCT format={fmt} overrides Accept", ok, f"{status} {ct!r}")

# SELECT and ASK in every results format.
for media_type in RESULT_TYPES:
    status, essence, ct, _, body = request(SELECT, media_type)
    name = f"SELECT Accept: {media_type}"
    if status != 200 or essence != media_type:
        check(name, False, f"{status}, Content-Type {ct!r}")
        continue
    rows = list(parse_results(essence, body))
    got = {str(r[1]) for r in rows}
    check(name, got == ids, f"ids {sorted(got)} against {sorted(ids)}")
for media_type in ("application/sparql-results+json", "application/sparql-results+xml"):
    status, essence, ct, _, body = request(ASK, media_type)
    ok = status == 200 and essence == media_type and parse_results(essence, body).askAnswer is True
    check(f"ASK Accept: {media_type}", ok, f"{status} {ct!r}")
for accept, expected in [(None, "application/sparql-results+json"),
                         ("text/*", "text/csv"),
                         ("application/json", "application/sparql-results+json"),
                         ("text/csv;q=0.3, application/sparql-results+xml;q=0.6", "application/sparql-results+xml")]:
    status, essence, ct, _, body = request(SELECT, accept)
    ok = status == 200 and essence == expected and len(list(parse_results(essence, body))) == len(ids)
    check(f"SELECT Accept: {accept!r} -> {expected}", ok, f"{status} {ct!r}")

# What cannot be served: 406 with a JSON message listing what can.
for query, accept, must_list in [
    (CONSTRUCT, "application/sparql-results+json", "text/turtle"),
    (SELECT, "text/turtle", "application/sparql-results+json"),
    (ASK, "application/n-triples", "text/csv"),
    (SELECT, "image/png, text/html;q=0.9", "application/n-triples"),
    (CONSTRUCT, "text/turtle;q=0, application/n-triples;q=0", "application/rdf+xml"),
]:
    status, essence, ct, _, body = request(query, accept)
    try:
        message = json.loads(body)["error"]
    except Exception:  # noqa: BLE001
        message = ""
    check(f"{query.split()[0]} Accept: {accept!r} -> 406",
          status == 406 and essence == "application/json" and must_list in message,
          f"{status} {ct!r} {body[:300]!r}")

print(f"sparql-client (rdflib {rdflib.__version__}): {passed} passed, {failed} failed")
sys.exit(1 if failed else 0)
