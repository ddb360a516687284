// Vehicles: the selected vehicle's details with depth and battery charts from the history
// (GET /api/vehicles/{id}/track), commands for it (one task now, POST /api/tasks: hold,
// surface, return home, request state, reporting rate, abort; operators), and registering
// or editing a vehicle (POST /api/vehicles, admins only).

import { api, describe } from './api.js';
import { lineChart } from './chart.js';
import { vehicleColour } from './map.js';
import { currentTask, may, on, state } from './store.js';
import { ago, confirmDialog, fieldError, fmt, h, toast } from './util.js';

let root;
let windowMin = 10;
let form;

const KINDS = ['auv', 'usv', 'asv', 'rov', 'glider'];
const LINKS = ['ip', 'acoustic', 'radio', 'satellite', 'tether'];
const list = (s) => s.split(',').map((x) => x.trim()).filter(Boolean);
/** The station's sentinel for a value not available (altitude at the surface, ...). */
const UNKNOWN = -1;
/** The capability a vehicle announces for each command's task kind (TaskKind::capability). */
const CAPABILITY = {
  hold: 'hold',
  surface: 'surface',
  return_home: 'return_home',
  request_state: 'request_state',
  set_reporting_rate: 'set_reporting_rate',
};

/**
 * A task for one vehicle, outside missions, as POST /api/tasks takes it from a person: the
 * vehicle and the typed task; the station gives it its id, issue time, sequence and expiry.
 */
function order(vehicleId, kind, params = {}) {
  return { vehicle_id: vehicleId, task: { kind, ...params } };
}

/** "hold: running 40%", or "none": the vehicle's current (or latest) task. */
function taskLine(id) {
  const t = currentTask(id);
  if (!t) return 'none';
  const progress = t.state === 'running' ? ` ${Math.round(t.progress_pct)}%` : '';
  return `${t.assignment.kind.replace(/_/g, ' ')} (${t.assignment.task_id}): ${t.state}${progress}${t.message ? ` — ${t.message}` : ''}`;
}

/**
 * The commands for one vehicle: each sends one task now, outside any mission. A vehicle
 * queues it behind the task it is running (an open-ended hold ends); an abort stops
 * everything at once. A command the vehicle does not announce is greyed out with why;
 * the station's refusal (lost, battery, ...) shows under the buttons.
 */
function commandsCard(v) {
  const a = v.announcement;
  const id = a.vehicle_id;
  const result = h('p', { id: 'command-result', role: 'status' });
  const able = (kind) => a.capabilities.includes(CAPABILITY[kind]);
  const send = async (kind, params, label) => {
    result.className = '';
    result.textContent = `${label}: sending…`;
    try {
      const sent = await api('POST', '/api/tasks', order(id, kind, params));
      result.textContent = `${label} sent to ${id} as ${sent.task_id}.`;
      toast(`${label} sent to ${id}`, kind === 'abort' ? 'warn' : 'ok');
    } catch (e) {
      result.className = 'error';
      result.textContent = `${label}: ${describe(e)}`;
    }
  };
  const button = (kind, label, onclick, attrs = {}) => {
    if (kind !== 'abort' && !able(kind)) {
      const why = kind === 'surface' && ['usv', 'asv'].includes(a.kind)
        ? `${id} is a ${a.kind.toUpperCase()}: it is at the surface already`
        : `${id} does not announce the "${CAPABILITY[kind]}" capability`;
      return h('button', { type: 'button', disabled: true, title: why, dataset: { command: kind } }, label);
    }
    return h('button', { type: 'button', class: `needs-operator ${attrs.class || ''}`.trim(), title: attrs.title, disabled: !may('operator'), dataset: { command: kind }, onclick }, label);
  };
  const duration = h('input', { name: 'hold_s', type: 'number', step: 'any', min: '0', max: '86400', value: '0' });
  const rate = h('input', { name: 'rate_hz', type: 'number', step: 'any', min: '0', max: '100', value: '1' });
  const value = (input) => (input.value.trim() === '' ? NaN : Number(input.value));
  return h('div', { class: 'card', id: 'vehicle-commands', dataset: { vehicle: id } },
    h('h3', {}, `Commands for ${id}`),
    h('p', { class: 'field-note' }, 'One task now, outside any mission: the vehicle does it after the task it is running (a hold without an end gives way to it). Abort stops everything at once.'),
    h('p', {}, 'Task: ', h('span', { id: 'command-task' }, taskLine(id))),
    h('div', { class: 'row' },
      h('label', { title: '0: until the next task' }, 'Hold for s (0: until the next task)', duration),
      button('hold', 'Hold position', () => {
        const s = value(duration);
        if (!fieldError(duration, Number.isFinite(s) && s >= 0 && s <= 86400 ? '' : 'Hold for [0, 86400] s; 0 holds until the next task.')) return;
        send('hold', { duration_s: s }, 'Hold');
      })),
    h('div', { class: 'row' },
      button('surface', 'Surface', () => send('surface', {}, 'Surface')),
      button('return_home', 'Return home', () => send('return_home', {}, 'Return home')),
      button('request_state', 'Request state', () => send('request_state', {}, 'State request'), { title: 'the vehicle reports its state at once' })),
    h('div', { class: 'row' },
      h('label', {}, 'States per second (0, 100]', rate),
      button('set_reporting_rate', 'Set reporting rate', () => {
        const hz = value(rate);
        if (!fieldError(rate, Number.isFinite(hz) && hz > 0 && hz <= 100 ? '' : 'The rate must be in (0, 100] states per second.')) return;
        send('set_reporting_rate', { rate_hz: hz }, 'Reporting rate');
      })),
    h('div', { class: 'row' },
      button('abort', `Abort ${id}`, async () => {
        const what = ['usv', 'asv'].includes(a.kind) ? 'stops' : 'surfaces and stops';
        if (await confirmDialog(`Abort ${id}?`, `${id} drops every task (its missions' tasks too) and ${what}.`, `Abort ${id}`)) send('abort', {}, 'Abort');
      }, { class: 'danger' })),
    result);
}

async function renderDetail() {
  const box = root.querySelector('#vehicle-detail');
  const id = state.selected;
  const v = id && state.vehicles.get(id);
  if (!v) {
    box.replaceChildren(h('p', { class: 'muted' }, 'Select a vehicle on the map or in the fleet list.'));
    return;
  }
  const a = v.announcement;
  const s = v.latest || {};
  const head = h('div', { class: 'card' },
    h('h2', {}, `${a.vehicle_id} `, h('small', {}, `${a.name} · ${a.kind.toUpperCase()} · ${a.vendor}`)),
    h('dl', { class: 'facts' },
      h('dt', {}, 'contact'), h('dd', {}, `${v.contact}, ${ago(v.last_contact_ms)}`),
      h('dt', {}, 'availability'), h('dd', {}, v.availability),
      h('dt', {}, 'link'), h('dd', {}, v.link),
      h('dt', {}, 'position'), h('dd', {}, s.latitude_deg !== undefined ? `${fmt(s.latitude_deg, 5)}, ${fmt(s.longitude_deg, 5)}` : '–'),
      h('dt', {}, 'depth / altitude'), h('dd', {}, `${fmt(s.depth_m)} m / ${s.altitude_m === UNKNOWN ? '–' : `${fmt(s.altitude_m)} m`}`),
      h('dt', {}, 'speed / heading'), h('dd', {}, `${fmt(s.speed_mps)} m/s / ${fmt(s.yaw_deg, 0)}°`),
      h('dt', {}, 'battery'), h('dd', {}, `${fmt(s.battery_pct)} %`),
      h('dt', {}, 'capabilities'), h('dd', {}, a.capabilities.join(', ') || '–'),
      h('dt', {}, 'sensors'), h('dd', {}, a.sensors.join(', ') || '–'),
      h('dt', {}, 'links'), h('dd', {}, a.links.join(', ')),
      h('dt', {}, 'max speed'), h('dd', {}, `${a.max_speed_mps} m/s`),
      h('dt', {}, 'states accepted / rejected'), h('dd', {}, `${v.states_accepted} / ${v.states_rejected}`)),
    h('div', { class: 'row' },
      h('label', {}, 'Window ', h('select', {
        onchange: (e) => { windowMin = Number(e.target.value); renderDetail(); },
      }, [10, 60, 360, 1440].map((m) => h('option', { value: m, selected: m === windowMin }, m < 60 ? `${m} min` : `${m / 60} h`)))),
      h('button', { type: 'button', class: 'needs-admin', onclick: () => edit(a) }, 'Edit registration')));
  const charts = h('div', { id: 'charts' }, h('p', { class: 'muted' }, 'Loading the track…'));
  box.replaceChildren(head, commandsCard(v), charts);
  try {
    const now = Date.now();
    const rows = await api('GET', `/api/vehicles/${encodeURIComponent(id)}/track?from_ms=${now - windowMin * 60000}&to_ms=${now}&limit=10000`);
    if (state.selected !== id) return;
    const depth = rows.map((r) => ({ t: r.timestamp_ms, y: r.depth_m }));
    const batteryPts = rows.map((r) => ({ t: r.timestamp_ms, y: r.battery_pct }));
    charts.replaceChildren(
      h('p', { class: 'muted' }, `${rows.length} state vectors in the last ${windowMin < 60 ? `${windowMin} min` : `${windowMin / 60} h`}`),
      lineChart(depth, { title: 'Depth', unit: 'm', invert: true, min: 0, colour: vehicleColour(id) }),
      lineChart(batteryPts, { title: 'Battery', unit: '%', min: 0, max: 100, colour: '#1f8a3c' }),
    );
  } catch (e) {
    charts.replaceChildren(h('p', { class: 'error' }, describe(e)));
  }
}

function edit(a) {
  const f = form.elements;
  f.vehicle_id.value = a.vehicle_id;
  f.name.value = a.name;
  f.kind.value = a.kind;
  f.vendor.value = a.vendor;
  f.capabilities.value = a.capabilities.join(', ');
  f.sensors.value = a.sensors.join(', ');
  f.max_speed.value = a.max_speed_mps;
  for (const l of LINKS) f[`link_${l}`].checked = a.links.includes(l);
  form.scrollIntoView({ behavior: 'smooth' });
}

function buildForm() {
  form = h('form', { class: 'card', id: 'vehicle-form', novalidate: true },
    h('h2', {}, 'Register or edit a vehicle'),
    h('p', { class: 'muted' }, 'As if the vehicle announced itself; a vehicle that announces later overrides this. Admins only.'),
    h('div', { class: 'row' },
      h('label', {}, 'Id', h('input', { name: 'vehicle_id', placeholder: 'auv-7' })),
      h('label', {}, 'Name', h('input', { name: 'name' })),
      h('label', {}, 'Kind', h('select', { name: 'kind' }, KINDS.map((k) => h('option', { value: k }, k.toUpperCase())))),
      h('label', {}, 'Vendor', h('input', { name: 'vendor' }))),
    h('label', { class: 'wide' }, 'Capabilities (comma separated)', h('input', { name: 'capabilities', value: 'goto, survey, hold, surface, return_home, abort' })),
    h('label', { class: 'wide' }, 'Sensors (comma separated)', h('input', { name: 'sensors', placeholder: 'ctd, sidescan_sonar' })),
    h('fieldset', { class: 'row' }, h('legend', {}, 'Links'), LINKS.map((l) => h('label', { class: 'inline' }, h('input', { type: 'checkbox', name: `link_${l}`, checked: l === 'ip' }), l))),
    h('label', {}, 'Max speed m/s', h('input', { name: 'max_speed', type: 'number', step: 'any', value: '2' })),
    h('p', { class: 'error', id: 'vehicle-error', role: 'alert' }),
    h('button', { type: 'submit', class: 'primary needs-admin' }, 'Save vehicle'));
  form.addEventListener('submit', async (e) => {
    e.preventDefault();
    const f = form.elements;
    const out = form.querySelector('#vehicle-error');
    out.textContent = '';
    const id = f.vehicle_id.value.trim();
    let ok = fieldError(f.vehicle_id, /^[A-Za-z0-9_.-]{1,32}$/.test(id) ? '' : 'Id: 1 to 32 letters, digits, "_", "." or "-".');
    const speed = Number(f.max_speed.value);
    ok = fieldError(f.max_speed, speed > 0 && speed <= 30 ? '' : 'Max speed must be in (0, 30] m/s.') && ok;
    const links = LINKS.filter((l) => f[`link_${l}`].checked);
    ok = fieldError(f.link_ip, links.length ? '' : 'Choose at least one link.') && ok;
    if (!ok) return;
    const announcement = {
      vehicle_id: id,
      name: f.name.value.trim() || id,
      kind: f.kind.value,
      vendor: f.vendor.value.trim(),
      capabilities: list(f.capabilities.value),
      sensors: list(f.sensors.value),
      links,
      max_speed_mps: speed,
      timestamp_ms: Date.now(),
    };
    try {
      await api('POST', '/api/vehicles', announcement);
      toast(`Vehicle ${id} saved`, 'ok');
    } catch (err) {
      out.textContent = describe(err);
    }
  });
  return form;
}

export function initVehicles() {
  root = document.getElementById('tab-vehicles');
  root.replaceChildren(h('div', { id: 'vehicle-detail' }), buildForm());
  on('select', () => {
    if (root.classList.contains('active')) renderDetail();
  });
  // The selected vehicle's task, as it moves (the rest of the detail is drawn on selection).
  on('tasks', () => {
    const line = root.querySelector('#command-task');
    const card = root.querySelector('#vehicle-commands');
    if (line && card) line.textContent = taskLine(card.dataset.vehicle);
  });
  renderDetail();
}

/** Called when the tab is shown: charts load only then. */
export function showVehicles() {
  renderDetail();
}
