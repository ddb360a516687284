// Rules & Policies: the station's rules (built-in and user-defined), enable/disable,
// delete, new threshold or SPARQL rules, and editing a user rule in place (PATCH
// /api/rules/{id}, checked by the station exactly as a new rule). Changing rules is for admins.

import { api, describe } from './api.js';
import { showRuleAreas } from './map.js';
import { on } from './store.js';
import { fieldError, h, toast } from './util.js';

let root;
let form;
/** A threshold expression as the station parses it: `field op number`, op one of <, <=, >,
 *  >= (no == or !=), the number as Rust reads a float (`20`, `-0.5`, `.5`, `1e3`). */
const THRESHOLD = /^\s*[a-z_]+\s*(<=|>=|<|>)\s*[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?\s*$/;
let rules = [];
/** The rule being edited, or null while the form creates a new one. */
let editing = null;

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
        h('td', { class: 'actions' }, r.built_in || !editable(r) ? '' : h('button', {
          type: 'button',
          class: 'edit needs-admin',
          onclick: () => edit(r),
        }, 'Edit'), r.built_in ? '' : h('button', {
          type: 'button',
          class: 'danger needs-admin',
          onclick: () => change('DELETE', `/api/rules/${encodeURIComponent(r.id)}`, undefined, `Rule ${r.id} deleted`),
        }, 'Delete')))))),
  );
}

/** The form edits threshold and SPARQL conditions; other user rules are changed through the API. */
function editable(r) {
  return r.condition.type === 'threshold' || r.condition.type === 'sparql';
}

function clearErrors() {
  for (const el of form.querySelectorAll('[aria-invalid=true]')) fieldError(el, '');
  form.querySelector('#rule-error').textContent = '';
}

/** Loads a rule into the form; the id stays fixed (a rule is not renamed). */
function edit(r) {
  editing = r.id;
  const f = form.elements;
  clearErrors();
  f.id.value = r.id;
  f.id.readOnly = true;
  f.description.value = r.description || '';
  f.severity.value = r.severity;
  f.type.value = r.condition.type;
  f.expr.value = r.condition.type === 'threshold' ? r.condition.expr : '';
  f.query.value = r.condition.type === 'sparql' ? r.condition.query : '';
  f.watches.value = r.condition.type === 'sparql' ? r.condition.watches.join(', ') : '';
  form.querySelector('h2').textContent = `Edit rule ${r.id}`;
  form.querySelector('#rule-submit').textContent = 'Save changes';
  form.querySelector('#rule-cancel').hidden = false;
  form.classList.add('editing');
  form.classList.toggle('sparql', f.type.value === 'sparql');
  form.scrollIntoView({ block: 'nearest' });
  (r.condition.type === 'sparql' ? f.query : f.expr).focus();
}

function endEdit() {
  editing = null;
  form.reset();
  clearErrors();
  form.elements.id.readOnly = false;
  form.querySelector('h2').textContent = 'New rule';
  form.querySelector('#rule-submit').textContent = 'Create rule';
  form.querySelector('#rule-cancel').hidden = true;
  form.classList.remove('editing');
  form.classList.toggle('sparql', form.elements.type.value === 'sparql');
}

/**
 * Puts the station's refusal next to the field it is about: the parser's message under the
 * condition, a duplicate id under the id; anything else under the form.
 */
function showRefusal(err) {
  const f = form.elements;
  const msg = err && err.status === 400 ? err.message : null;
  if (err && err.status === 409 && /exists already/.test(err.message)) {
    fieldError(f.id, err.message);
    return;
  }
  if (!msg) {
    form.querySelector('#rule-error').textContent = describe(err);
    return;
  }
  let field;
  if (/watch/i.test(msg)) field = f.watches;
  else if (/description/i.test(msg)) field = f.description;
  else if (/rule id/i.test(msg)) field = f.id;
  else field = f.type.value === 'sparql' ? f.query : f.expr;
  fieldError(field, msg);
}

function buildForm() {
  form = h('form', { id: 'rule-form', class: 'card', novalidate: true },
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
    h('div', { class: 'row' },
      h('button', { type: 'submit', id: 'rule-submit', class: 'primary needs-admin' }, 'Create rule'),
      h('button', { type: 'button', id: 'rule-cancel', hidden: true, onclick: () => endEdit() }, 'Cancel')));
  const sync = () => form.classList.toggle('sparql', form.elements.type.value === 'sparql');
  form.addEventListener('change', sync);
  form.addEventListener('input', (e) => {
    if (e.target.getAttribute && e.target.getAttribute('aria-invalid') === 'true') fieldError(e.target, '');
  });
  sync();
  form.addEventListener('submit', async (e) => {
    e.preventDefault();
    const f = form.elements;
    clearErrors();
    const id = f.id.value.trim();
    let ok = fieldError(f.id, /^[A-Za-z0-9_.-]{1,32}$/.test(id) ? '' : 'Id: 1 to 32 letters, digits, "_", "." or "-".');
    let condition;
    if (f.type.value === 'threshold') {
      const expr = f.expr.value.trim();
      // What the station's parser takes: a state field, <, <=, > or >=, a number.
      ok = fieldError(f.expr, THRESHOLD.test(expr) ? '' : 'Write "field op number" with op one of <, <=, >, >=, e.g. battery_pct < 20 or depth_m > 300.') && ok;
      condition = { type: 'threshold', expr };
    } else {
      const query = f.query.value.trim();
      const watches = f.watches.value.split(',').map((s) => s.trim()).filter(Boolean);
      ok = fieldError(f.query, query ? '' : 'Write an ASK or SELECT query.') && ok;
      ok = fieldError(f.watches, watches.length ? '' : 'Name at least one property the rule watches.') && ok;
      condition = { type: 'sparql', query, watches };
    }
    if (!ok) return;
    const body = { description: f.description.value.trim(), severity: f.severity.value, condition };
    try {
      if (editing) {
        await api('PATCH', `/api/rules/${encodeURIComponent(editing)}`, body);
        toast(`Rule ${editing} changed`, 'ok');
        endEdit();
      } else {
        await api('POST', '/api/rules', { id, ...body });
        toast(`Rule ${id} created`, 'ok');
        form.reset();
        sync();
      }
      loadRules();
    } catch (err) {
      showRefusal(err);
    }
  });
  return form;
}

export function initRules() {
  root = document.getElementById('tab-rules');
  root.replaceChildren(h('div', { id: 'rule-list' }), buildForm());
  on('session', loadRules);
}
