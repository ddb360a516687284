// Rules & Policies: the station's rules (built-in and user-defined), enable/disable,
// delete, and new threshold or SPARQL rules. Changing rules is for admins.

import { api, describe } from './api.js';
import { showRuleAreas } from './map.js';
import { on } from './store.js';
import { fieldError, h, toast } from './util.js';

let root;
let rules = [];

function conditionText(c) {
  switch (c.type) {
    case 'threshold':
      return c.expr;
    case 'outside_area':
      return `outside a ${c.polygon.length}-corner area`;
    case 'lost_contact':
      return `no data for ${c.factor} reporting periods`;
    case 'task_overdue':
      return `task overdue by ${c.grace_ms / 1000} s`;
    case 'sparql':
      return h('code', { class: 'query', title: c.query }, c.query.length > 120 ? `${c.query.slice(0, 120)}…` : c.query);
    default:
      return JSON.stringify(c);
  }
}

export async function loadRules() {
  try {
    rules = await api('GET', '/api/rules');
    showRuleAreas(rules);
    render();
  } catch (e) {
    root.querySelector('#rule-list').replaceChildren(h('p', { class: 'error' }, describe(e)));
  }
}

async function change(method, path, body, what) {
  try {
    await api(method, path, body);
    toast(what, 'ok');
  } catch (e) {
    toast(describe(e), 'error');
  }
  loadRules();
}

function render() {
  const list = root.querySelector('#rule-list');
  list.replaceChildren(
    h('table', { class: 'grid', id: 'rule-table' },
      h('thead', {}, h('tr', {}, ['rule', 'severity', 'condition', 'enabled', ''].map((t) => h('th', {}, t)))),
      h('tbody', {}, rules.map((r) => h('tr', { dataset: { rule: r.id }, class: r.enabled ? '' : 'disabled' },
        h('td', {}, h('strong', {}, r.id), r.built_in ? h('small', {}, ' built-in') : null, h('div', { class: 'muted' }, r.description)),
        h('td', {}, h('span', { class: `pill sev-${r.severity}` }, r.severity)),
        h('td', {}, conditionText(r.condition)),
        h('td', {}, h('input', {
          type: 'checkbox',
          class: 'needs-admin',
          checked: r.enabled,
          title: r.enabled ? 'disable' : 'enable',
          onchange: (e) => change('PATCH', `/api/rules/${encodeURIComponent(r.id)}`, { enabled: e.target.checked }, `Rule ${r.id} ${e.target.checked ? 'enabled' : 'disabled'}`),
        })),
        h('td', {}, r.built_in ? '' : h('button', {
          type: 'button',
          class: 'danger needs-admin',
          onclick: () => change('DELETE', `/api/rules/${encodeURIComponent(r.id)}`, undefined, `Rule ${r.id} deleted`),
        }, 'Delete')))))),
  );
}

function buildForm() {
  const form = h('form', { id: 'rule-form', class: 'card', novalidate: true },
    h('h2', {}, 'New rule'),
    h('p', { class: 'muted needs-admin-note' }, 'Only admins create and change rules.'),
    h('div', { class: 'row' },
      h('label', {}, 'Id', h('input', { name: 'id', placeholder: 'battery-low-15' })),
      h('label', {}, 'Severity', h('select', { name: 'severity' }, ['info', 'warning', 'alarm', 'critical'].map((s) => h('option', { value: s, selected: s === 'warning' }, s)))),
      h('label', {}, 'Type', h('select', { name: 'type' }, h('option', { value: 'threshold' }, 'threshold on state vectors'), h('option', { value: 'sparql' }, 'SPARQL')))),
    h('label', { class: 'wide' }, 'Description', h('input', { name: 'description', placeholder: 'what the operator should do' })),
    h('label', { class: 'wide threshold-only' }, 'Condition', h('input', { name: 'expr', placeholder: 'battery_pct < 20' })),
    h('label', { class: 'wide sparql-only' }, 'Query (?this is the changed entity)', h('textarea', { name: 'query', rows: 5, placeholder: 'ASK { ?this shoal:batteryLevel ?b FILTER(?b < 15) }' })),
    h('label', { class: 'wide sparql-only' }, 'Watched properties (comma separated)', h('input', { name: 'watches', placeholder: 'shoal:batteryLevel' })),
    h('p', { class: 'error', id: 'rule-error', role: 'alert' }),
    h('button', { type: 'submit', class: 'primary needs-admin' }, 'Create rule'));
  const sync = () => form.classList.toggle('sparql', form.elements.type.value === 'sparql');
  form.addEventListener('change', sync);
  sync();
  form.addEventListener('submit', async (e) => {
    e.preventDefault();
    const f = form.elements;
    const out = form.querySelector('#rule-error');
    out.textContent = '';
    let ok = fieldError(f.id, /^[A-Za-z0-9_.-]{1,32}$/.test(f.id.value.trim()) ? '' : 'Id: 1 to 32 letters, digits, "_", "." or "-".');
    let condition;
    if (f.type.value === 'threshold') {
      const expr = f.expr.value.trim();
      ok = fieldError(f.expr, /^[a-z_]+\s*(<=|>=|==|!=|<|>)\s*-?[0-9.]+$/.test(expr) ? '' : 'Write "field op number", e.g. battery_pct < 20 or depth_m > 300.') && ok;
      condition = { type: 'threshold', expr };
    } else {
      const query = f.query.value.trim();
      const watches = f.watches.value.split(',').map((s) => s.trim()).filter(Boolean);
      ok = fieldError(f.query, query ? '' : 'Write an ASK or SELECT query.') && ok;
      ok = fieldError(f.watches, watches.length ? '' : 'Name at least one property the rule watches.') && ok;
      condition = { type: 'sparql', query, watches };
    }
    if (!ok) return;
    try {
      await api('POST', '/api/rules', { id: f.id.value.trim(), description: f.description.value.trim(), severity: f.severity.value, condition });
      toast(`Rule ${f.id.value.trim()} created`, 'ok');
      form.reset();
      sync();
      loadRules();
    } catch (err) {
      out.textContent = describe(err);
    }
  });
  return form;
}

export function initRules() {
  root = document.getElementById('tab-rules');
  root.replaceChildren(h('div', { id: 'rule-list' }), buildForm());
  on('session', loadRules);
}
