// Semantic query: SPARQL over the station's live model (POST /api/sparql), results as a table.

import { api, describe } from './api.js';
import { h } from './util.js';

const EXAMPLES = {
  'Vehicles with battery and depth': `SELECT ?id ?battery ?depth WHERE {
  ?v a shoal:Vehicle ; shoal:vehicleId ?id .
  OPTIONAL { ?v shoal:batteryLevel ?battery }
  OPTIONAL { ?v shoal:depth ?depth }
}
ORDER BY ?id`,
  'Idle vehicles below 20 % battery': `SELECT ?vehicle ?battery WHERE {
  ?vehicle a shoal:Vehicle ; shoal:availability shoal:Idle ; shoal:batteryLevel ?battery .
  FILTER(?battery < 20)
}
ORDER BY ?vehicle`,
  'Tasks by state': `SELECT ?state ?task WHERE {
  ?task a shoal:Task ; shoal:hasState ?state .
}
ORDER BY ?state ?task`,
  'Vehicles able to survey with side-scan sonar': `SELECT ?vehicle WHERE {
  ?vehicle a shoal:Vehicle ; shoal:hasCapability shoal:SidescanSurvey .
}
ORDER BY ?vehicle`,
};

/** Shortens IRIs of the known vocabularies for display. */
function short(term) {
  if (!term) return '';
  if (term.type === 'uri') {
    return term.value
      .replace('https://example.invalid/shoal/ontology#', 'shoal:')
      .replace('http://www.w3.org/2003/01/geo/wgs84_pos#', 'geo:')
      .replace('http://www.w3.org/ns/sosa/', 'sosa:')
      .replace('http://www.w3.org/1999/02/22-rdf-syntax-ns#', 'rdf:');
  }
  return term.value;
}

export function initQuery() {
  const root = document.getElementById('tab-query');
  const text = h('textarea', { id: 'sparql', rows: 9, spellcheck: false }, EXAMPLES['Vehicles with battery and depth']);
  const out = h('div', { id: 'query-result' });
  const run = async () => {
    out.replaceChildren(h('p', { class: 'muted' }, 'Running…'));
    const started = performance.now();
    try {
      const res = await api('POST', '/api/sparql', undefined, {
        raw: text.value,
        contentType: 'application/sparql-query',
        accept: 'application/sparql-results+json',
      });
      const ms = Math.round(performance.now() - started);
      if (typeof res.boolean === 'boolean') {
        out.replaceChildren(h('p', { class: 'summary' }, `ASK: ${res.boolean} (${ms} ms)`));
        return;
      }
      const vars = res.head.vars;
      const rows = res.results.bindings;
      out.replaceChildren(
        h('p', { class: 'summary', id: 'query-count' }, `${rows.length} row(s) in ${ms} ms`),
        h('table', { class: 'grid', id: 'query-table' },
          h('thead', {}, h('tr', {}, vars.map((v) => h('th', {}, `?${v}`)))),
          h('tbody', {}, rows.map((b) => h('tr', {}, vars.map((v) => h('td', { title: b[v] ? b[v].value : '' }, short(b[v]))))))),
      );
    } catch (e) {
      out.replaceChildren(h('p', { class: 'error', role: 'alert' }, describe(e)));
    }
  };
  root.replaceChildren(
    h('h2', {}, 'Semantic query (SPARQL 1.1, read-only)'),
    h('p', { class: 'muted' }, 'Prefixes shoal:, geo:, sosa: need no declaration. The model holds the live swarm: vehicles, capabilities, latest state, tasks, events, observations.'),
    h('div', { class: 'row' },
      h('label', {}, 'Examples ', h('select', { onchange: (e) => { if (e.target.value) text.value = EXAMPLES[e.target.value]; } },
        h('option', { value: '' }, '—'), Object.keys(EXAMPLES).map((k) => h('option', { value: k }, k))))),
    text,
    h('div', { class: 'row' }, h('button', { type: 'button', class: 'primary', id: 'run-query', onclick: run }, 'Run query'), h('small', { class: 'muted' }, 'Ctrl+Enter runs it')),
    out,
  );
  text.addEventListener('keydown', (e) => {
    if (e.key === 'Enter' && (e.ctrlKey || e.metaKey)) run();
  });
}
