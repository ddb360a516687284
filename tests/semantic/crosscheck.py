#!/usr/bin/env python3
"""Cross-check of Shoal's semantic store against rdflib.

Usage: crosscheck.py EXPORT.nq > answers.json

Loads an N-Quads export of the store (ontology, asserted and inferred graphs), then runs
  - "standard": the five standard queries of ontology/queries/*.rq, unchanged, over the
    union of all graphs (so it sees Shoal's materialised inferences, as the store does);
  - "independent": the same questions answered without Shoal's reasoner, over the asserted
    graphs plus the ontology only, with the inference spelled out as SPARQL property paths
    (rdf:type/rdfs:subClassOf*, sensor class -> shoal:enablesCapability).
The Rust test crates/shoal-semantic/tests/crosscheck.rs compares both with its own answers.
Output: JSON {"rdflib": version, "standard": {name: rows}, "independent": {name: rows}};
each row is a list of cells (IRI string, literal lexical form, or null).
"""
import json
import pathlib
import sys

import rdflib

QUERIES = pathlib.Path(__file__).resolve().parents[2] / "ontology" / "queries"
INFERRED = "https://example.invalid/shoal/id/graph/inferred"
PREFIXES = """
PREFIX shoal: <https://example.invalid/shoal/ontology#>
PREFIX geo: <http://www.w3.org/2003/01/geo/wgs84_pos#>
PREFIX sosa: <http://www.w3.org/ns/sosa/>
PREFIX rdfs: <http://www.w3.org/2000/01/rdf-schema#>
"""
IS_VEHICLE = "?vehicle a/rdfs:subClassOf* shoal:Vehicle ."
INDEPENDENT = {
    "q1_idle_low_battery": PREFIXES + """
SELECT ?vehicle ?battery WHERE {
  """ + IS_VEHICLE + """
  ?vehicle shoal:availability shoal:Idle ; shoal:batteryLevel ?battery .
  FILTER(?battery < 20)
}""",
    "q2_vehicles_in_box": PREFIXES + """
SELECT ?vehicle ?lat ?long WHERE {
  """ + IS_VEHICLE + """
  ?vehicle geo:lat ?lat ; geo:long ?long .
  FILTER(?lat >= 43.0 && ?lat <= 43.2 && ?long >= 5.8 && ?long <= 6.0)
}""",
    "q3_tasks_by_state": PREFIXES + """
SELECT ?state ?task WHERE {
  ?task a/rdfs:subClassOf* shoal:Task ; shoal:hasState ?state .
}""",
    "q4_sidescan_capable": PREFIXES + """
SELECT DISTINCT ?vehicle WHERE {
  """ + IS_VEHICLE + """
  { ?vehicle shoal:declaresCapability shoal:SidescanSurvey }
  UNION
  { ?vehicle sosa:hosts ?sensor .
    ?sensor a/rdfs:subClassOf* ?class .
    ?class shoal:enablesCapability shoal:SidescanSurvey }
}""",
    "q5_running_tasks_low_battery": PREFIXES + """
SELECT ?task ?vehicle ?battery WHERE {
  ?task shoal:hasState shoal:Running ; shoal:assignedTo ?vehicle .
  ?vehicle shoal:batteryLevel ?battery .
  FILTER(?battery < 20)
}""",
}


def cell(term):
    if term is None:
        return None
    return str(term)


def run(graph, query):
    return sorted(([cell(t) for t in row] for row in graph.query(query)), key=json.dumps)


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    everything = rdflib.Dataset(default_union=True)
    everything.parse(sys.argv[1], format="nquads")
    asserted = rdflib.Graph()
    for s, p, o, g in everything.quads((None, None, None, None)):
        name = str(g.identifier if hasattr(g, "identifier") else g)
        if name != INFERRED:
            asserted.add((s, p, o))
    standard = {}
    for path in sorted(QUERIES.glob("*.rq")):
        standard[path.stem] = run(everything, path.read_text())
    independent = {name: run(asserted, q) for name, q in INDEPENDENT.items()}
    json.dump({"rdflib": rdflib.__version__, "standard": standard, "independent": independent},
              sys.stdout, indent=1)


if __name__ == "__main__":
    main()
