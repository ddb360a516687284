// Missions: the editor (waypoints clicked or a survey polygon drawn on the map at the
// surface, a depth or an altitude, and a speed; or a hold, return home or surface step; a
// vehicle the semantic model finds capable and the station would dispatch to, or another
// site's whose command lease the station holds), then confirm and start; the list of
// missions with their tasks' progress, abort, export and replay.

import { api, describe } from './api.js';
import { clearDraft, draftPoints, setDraft, startDrawing, stopDrawing } from './map.js';
import { FINAL, may, on, putMission, state } from './store.js';
import { confirmDialog, dateTime, fieldError, fmt, h, ID_PATTERN, table, toast } from './util.js';
import { replayMission } from './replay.js';

let root;
let form;
/** Tasks added to the mission being written: [{vehicle_id, task}]. */
let draftTasks = [];
let points = [];

/** What a survey is for: a capability the vehicle needs besides "survey", which the semantic
 *  model also infers from hosted sensors (a side-scan sonar gives sidescan_survey). */
const PAYLOADS = [
  ['', 'any area survey'],
  ['sidescan_survey', 'side-scan sonar survey'],
  ['bathymetry', 'bathymetry survey'],
  ['seabed_imaging', 'seabed imaging'],
  ['water_column_profiling', 'water-column profiling'],
];

/** The station's last answer to "who can do this task": vehicle_id -> candidate. */
let offered = new Map();
let capableSeq = 0;
let capableTimer = null;
let lastCapableMs = 0;
/** What the last answer was for, to word the messages. */
let needText = 'goto';

/** The task kinds that move a vehicle over a route: they need points, a speed and a level. */
const MOVES = new Set(['goto_waypoint', 'survey_area']);
/** Vehicle kinds that only go at the surface: a goto or survey sent to one with neither depth
 *  nor altitude goes at the surface (the station sets depth 0); the editor offers no other. */
const SURFACE_CRAFT = new Set(['usv', 'asv']);
/** Whether the "Keep" choice was made by the editor (a surface vehicle chosen), not the
 *  operator: it goes back to a depth when an underwater vehicle is chosen next. */
let vrefAuto = false;

function newMissionId() {
  const d = new Date();
  const p = (n) => String(n).padStart(2, '0');
  return `m-${d.getFullYear()}${p(d.getMonth() + 1)}${p(d.getDate())}-${p(d.getHours())}${p(d.getMinutes())}${p(d.getSeconds())}`;
}

function kind() {
  return form.elements.kind.value;
}

/** The kind of a vehicle (`auv`, `usv`, ...), from the fleet or the station's offer. */
function vehicleKind(vehicleId) {
  const v = state.vehicles.get(vehicleId);
  if (v) return v.announcement.kind;
  const c = offered.get(vehicleId);
  return c ? c.kind : '';
}

/**
 * Fits the "Keep" choice to the vehicle: a surface vehicle (USV, ASV) goes at the surface
 * and nothing else is offered for it; an underwater one may keep a depth, an altitude above
 * the seabed, or stay at the surface (depth 0). The metres field shows only for a depth or
 * an altitude.
 */
function syncVertical() {
  const sel = form.elements.vref;
  const id = form.elements.vehicle.value;
  const kindOf = vehicleKind(id);
  const surfaceCraft = SURFACE_CRAFT.has(kindOf);
  for (const o of sel.options) {
    if (o.value === 'surface') continue;
    o.disabled = surfaceCraft;
    o.title = surfaceCraft ? `${id} is a ${kindOf.toUpperCase()}: it has no depth or altitude to keep` : '';
  }
  if (surfaceCraft && sel.value !== 'surface') {
    sel.value = 'surface';
    vrefAuto = true;
  } else if (!surfaceCraft && vrefAuto && sel.value === 'surface') {
    sel.value = 'depth';
    vrefAuto = false;
  }
  form.querySelector('#vref-note').textContent = surfaceCraft ? `${id} is a ${kindOf.toUpperCase()}: it goes at the surface.` : '';
  form.classList.toggle('at-surface', sel.value === 'surface');
  if (sel.value === 'surface' && form.elements.level.getAttribute('aria-invalid') === 'true') fieldError(form.elements.level, '');
}

function payload() {
  return kind() === 'survey_area' ? form.elements.payload.value : '';
}

function optionText(c) {
  const v = state.vehicles.get(c.vehicle_id);
  const max = v ? `, max ${fmt(v.announcement.max_speed_mps)} m/s` : '';
  // Say when the model inferred a capability from a sensor rather than the announcement.
  const inferred = c.capabilities.filter((x) => !x.declared && x.inferred_from.length).map((x) => `${x.capability} from ${x.inferred_from.join(', ')}`);
  const extra = [...inferred, ...c.notes.map((n) => n.split(':')[0])];
  const battery = typeof c.battery_pct === 'number' ? `, ${c.battery_pct.toFixed(0)} %` : '';
  const site = c.site ? ` · ${c.site}` : '';
  return `${c.vehicle_id}${site} (${c.kind}${max}${battery})${extra.length ? ` — ${extra.join('; ')}` : ''}`;
}

/**
 * Asks the station which vehicles can do the task being written (GET /api/fleet/capable:
 * capabilities from the semantic model, dispatchability from the station's own checks);
 * offers those it would dispatch to and says why the others are not offered.
 */
async function refreshVehicles() {
  clearTimeout(capableTimer);
  capableTimer = null;
  const sel = form.elements.vehicle;
  const k = kind();
  const extra = payload();
  const q = new URLSearchParams({ kind: k });
  if (extra) q.set('capability', extra);
  const seq = ++capableSeq;
  let answer;
  try {
    answer = await api('GET', `/api/fleet/capable?${q}`);
  } catch (e) {
    if (seq === capableSeq) fieldError(sel, `Cannot learn which vehicles can do this: ${describe(e)}`);
    return;
  }
  // A later question (the operator changed the task meanwhile) wins.
  if (seq !== capableSeq) return;
  lastCapableMs = Date.now();
  const keep = sel.value;
  needText = answer.requires.map((r) => r.label || r.capability).join(' + ') || k.replace('_', ' ');
  offered = new Map(answer.vehicles.filter((c) => c.dispatchable).map((c) => [c.vehicle_id, c]));
  const option = (c) => h('option', { value: c.vehicle_id, selected: c.vehicle_id === keep, dataset: c.site ? { site: c.site } : {} }, optionText(c));
  const own = [...offered.values()].filter((c) => !c.site).map(option);
  // Other sites' vehicles under a lease held here: their own station checks the task.
  const leased = [...offered.values()].filter((c) => c.site).map(option);
  sel.replaceChildren(
    h('option', { value: '' }, `— ${offered.size} of ${answer.vehicles.length} vehicles can do ${needText} now —`),
    ...own,
    ...(leased.length ? [h('optgroup', { label: 'Other sites (command lease held here)' }, ...leased)] : []),
  );
  if (offered.has(keep)) sel.value = keep;
  syncVertical();
  const others = answer.vehicles.filter((c) => !c.dispatchable);
  form.querySelector('#vehicle-why').replaceChildren(
    ...others.map((c) => h('li', { dataset: { vehicle: c.vehicle_id, capable: String(c.capable) } }, h('strong', {}, c.vehicle_id), ` not offered: ${c.reasons.join('; ')}`)),
  );
  if (keep && !offered.has(keep)) {
    const c = others.find((x) => x.vehicle_id === keep);
    fieldError(sel, `${keep} is no longer offered${c ? `: ${c.reasons.join('; ')}` : ''}. Choose another vehicle.`);
  } else if (sel.getAttribute('aria-invalid') === 'true' && sel.value) {
    fieldError(sel, '');
  }
}

/** Vehicle updates arrive every second: ask again at most every few seconds, and only
 *  while the editor is shown. */
function scheduleVehicles() {
  if (capableTimer || !root.classList.contains('active')) return;
  // Re-rendering the list would close it under the operator's pointer.
  if (document.activeElement === form.elements.vehicle) return;
  const wait = Math.max(0, 3000 - (Date.now() - lastCapableMs));
  capableTimer = setTimeout(() => {
    capableTimer = null;
    refreshVehicles();
  }, wait);
}

function renderPoints() {
  const list = form.querySelector('#points');
  const k = kind();
  const what = k === 'survey_area' ? 'corner' : 'waypoint';
  list.replaceChildren(
    ...points.map((p, i) =>
      h(
        'li',
        {},
        `${what} ${i + 1}: ${p.latitude_deg.toFixed(5)}, ${p.longitude_deg.toFixed(5)} `,
        h('button', {
          type: 'button',
          class: 'link-button',
          title: `remove ${what} ${i + 1}`,
          onclick: () => {
            points.splice(i, 1);
            setDraft(k === 'survey_area' ? 'Polygon' : 'Point', points);
            renderPoints();
          },
        }, '✕'),
      ),
    ),
  );
  if (!points.length && MOVES.has(k)) list.append(h('li', { class: 'muted' }, k === 'survey_area' ? 'Draw the survey polygon on the map (double-click closes it).' : 'Click waypoints on the map, in order.'));
  form.querySelector('.points-count').textContent = `${points.length} ${what}${points.length === 1 ? '' : 's'}`;
}

function startDraw() {
  const k = kind();
  points = [];
  renderPoints();
  startDrawing(k === 'survey_area' ? 'Polygon' : 'Point', (pts) => {
    points = pts;
    renderPoints();
    fieldError(form.querySelector('#points'), '');
  });
  form.querySelector('#draw').textContent = 'Drawing… (click on the map)';
  form.querySelector('#draw').classList.add('active');
}

function stopDraw() {
  stopDrawing();
  const b = form.querySelector('#draw');
  b.textContent = 'Draw on map';
  b.classList.remove('active');
}

function num(name) {
  const raw = form.elements[name].value.trim();
  return raw === '' ? NaN : Number(raw);
}

/** Checks the task fields; marks each wrong field and returns the tasks, or null. */
function readTasks() {
  const k = kind();
  let ok = true;
  const vehicleId = form.elements.vehicle.value;
  const vehicle = state.vehicles.get(vehicleId);
  let vehicleMsg = '';
  if (!vehicleId) vehicleMsg = offered.size ? `Choose a vehicle that can do ${needText}.` : `No vehicle can do ${needText} now: see why under the list.`;
  else if (!offered.has(vehicleId)) vehicleMsg = `${vehicleId} cannot do ${needText} now.`;
  ok = fieldError(form.elements.vehicle, vehicleMsg) && ok;
  if (!MOVES.has(k)) {
    if (k !== 'hold') return ok ? [{ vehicle_id: vehicleId, task: { kind: k } }] : null;
    // In a mission the vehicle's next task waits for the hold to end: it must have a time.
    const seconds = num('duration');
    ok = fieldError(form.elements.duration, Number.isFinite(seconds) && seconds > 0 && seconds <= 86400 ? '' : 'Hold for (0, 86400] s: in a mission a hold must end, or the vehicle\'s later tasks would wait for it.') && ok;
    return ok ? [{ vehicle_id: vehicleId, task: { kind: 'hold', duration_s: seconds } }] : null;
  }
  syncVertical();
  const vref = form.elements.vref.value;
  let vertical = {};
  if (vref === 'surface') {
    // A surface vehicle is sent neither (the station keeps it at the surface); an
    // underwater one goes at depth 0.
    if (!SURFACE_CRAFT.has(vehicleKind(vehicleId))) vertical = { depth_m: 0 };
  } else {
    const level = num('level');
    const [lo, hi] = vref === 'depth' ? [0, 11000] : [0, 10000];
    ok = fieldError(form.elements.level, Number.isFinite(level) && level >= lo && level <= hi ? '' : `${vref} must be a number of metres in [${lo}, ${hi}].`) && ok;
    vertical = vref === 'depth' ? { depth_m: level } : { altitude_m: level };
  }
  const speed = num('speed');
  let speedMsg = '';
  if (!(Number.isFinite(speed) && speed >= 0 && speed <= 30)) speedMsg = "Speed must be in [0, 30] m/s (0: the vehicle's cruise speed).";
  else if (vehicle && speed > vehicle.announcement.max_speed_mps) speedMsg = `${vehicleId} goes at most ${vehicle.announcement.max_speed_mps} m/s.`;
  ok = fieldError(form.elements.speed, speedMsg) && ok;
  let spacing = NaN;
  if (k === 'survey_area') {
    spacing = num('spacing');
    ok = fieldError(form.elements.spacing, Number.isFinite(spacing) && spacing >= 1 && spacing <= 10000 ? '' : 'Line spacing must be in [1, 10000] m.') && ok;
  }
  const pointsEl = form.querySelector('#points');
  if (k === 'survey_area') ok = fieldError(pointsEl, points.length >= 3 ? '' : 'A survey needs a polygon of at least 3 corners: draw it on the map.') && ok;
  else ok = fieldError(pointsEl, points.length >= 1 ? '' : 'Click at least one waypoint on the map.') && ok;
  if (!ok) return null;
  if (k === 'survey_area') {
    return [{ vehicle_id: vehicleId, task: { kind: 'survey_area', polygon: points.slice(), line_spacing_m: spacing, ...vertical, speed_mps: speed } }];
  }
  return points.map((p) => ({ vehicle_id: vehicleId, task: { kind: 'goto_waypoint', target: p, ...vertical, speed_mps: speed } }));
}

/** "at the surface", "depth 5 m", "altitude 3 m": how a moving task keeps its level. */
function levelText(x) {
  if (x.altitude_m !== undefined && x.altitude_m !== null) return `altitude ${x.altitude_m} m`;
  if (x.depth_m === undefined || x.depth_m === null || x.depth_m === 0) return 'at the surface';
  return `depth ${x.depth_m} m`;
}

function describeTask(t) {
  const x = t.task;
  switch (x.kind) {
    case 'hold':
      return `${t.vehicle_id}: hold position ${x.duration_s} s`;
    case 'return_home':
      return `${t.vehicle_id}: return home`;
    case 'surface':
      return `${t.vehicle_id}: surface`;
    default:
      break;
  }
  const speed = x.speed_mps > 0 ? `${x.speed_mps} m/s` : 'cruise speed';
  if (x.kind === 'survey_area') return `${t.vehicle_id}: survey ${x.polygon.length} corners, lines ${x.line_spacing_m} m apart, ${levelText(x)}, ${speed}`;
  return `${t.vehicle_id}: go to ${x.target.latitude_deg.toFixed(5)}, ${x.target.longitude_deg.toFixed(5)}, ${levelText(x)}, ${speed}`;
}

function renderDraftTasks() {
  const box = form.querySelector('#draft-tasks');
  box.replaceChildren(
    ...draftTasks.map((t, i) =>
      h('li', {}, `${describeTask(t)} `, h('button', { type: 'button', class: 'link-button', onclick: () => { draftTasks.splice(i, 1); renderDraftTasks(); } }, '✕')),
    ),
  );
  if (!draftTasks.length) box.append(h('li', { class: 'muted' }, 'No task yet: draw, then "Add to mission" (or start the drawn task directly).'));
}

function addTask() {
  const tasks = readTasks();
  if (!tasks) return false;
  draftTasks.push(...tasks);
  points = [];
  clearDraft();
  stopDraw();
  renderPoints();
  renderDraftTasks();
  return true;
}

/** A duration for people: `45 s`, `12 min`, `3 h 20 min`. */
function duration(seconds) {
  const s = Math.round(Math.max(0, seconds));
  if (s < 60) return `${s} s`;
  if (s < 3600) return `${Math.floor(s / 60)} min`;
  return `${Math.floor(s / 3600)} h ${Math.floor((s % 3600) / 60)} min`;
}

/** The plan preview: per vehicle, how long, how far and how much battery, and warnings. */
function previewTable(p) {
  const battery = (v) => {
    if (v.battery_pct === null) return '–';
    // Below zero it has run out before the end: say so rather than print a negative level.
    const after = v.battery_after_pct < 0 ? 'empty' : `${fmt(v.battery_after_pct, 0)} %`;
    return `${fmt(v.battery_pct, 0)} % → ${after}`;
  };
  return h('div', { id: 'plan-preview', class: p.warnings ? 'warn' : '' },
    h('h4', {}, `Estimate: about ${duration(p.duration_s)} `, h('small', { class: 'muted' }, "(each vehicle's nominal speed and battery use for its kind)")),
    table([
      { title: 'vehicle', cell: (v) => v.vehicle_id },
      { title: 'tasks', cell: (v) => String(v.tasks), class: 'num' },
      { title: 'distance', cell: (v) => (v.distance_m >= 1000 ? `${fmt(v.distance_m / 1000, 1)} km` : `${fmt(v.distance_m, 0)} m`), class: 'num' },
      { title: 'duration', cell: (v) => duration(v.duration_s), class: 'num' },
      { title: 'energy', cell: (v) => `${fmt(v.energy_pct, 1)} %`, class: 'num' },
      { title: 'battery now → after', cell: battery, class: 'num' },
    ], p.vehicles, { class: 'grid compact', row: (v) => ({ dataset: { vehicle: v.vehicle_id, warn: v.warnings.length ? 'yes' : 'no' } }) }),
    p.vehicles.some((v) => v.warnings.length)
      ? h('ul', { class: 'preview-warnings', role: 'alert' }, p.vehicles.flatMap((v) => v.warnings.map((w) => h('li', { dataset: { vehicle: v.vehicle_id } }, h('strong', {}, v.vehicle_id), `: ${w}`))))
      : null);
}

async function submit(start) {
  const out = form.querySelector('#mission-error');
  out.textContent = '';
  const id = form.elements.mission_id.value.trim();
  let ok = fieldError(form.elements.mission_id, ID_PATTERN.test(id) ? '' : 'Mission id: 1 to 64 letters, digits, "_", "." or "-".');
  if (state.missions.has(id)) ok = fieldError(form.elements.mission_id, `Mission ${id} exists already; choose another id.`) && ok;
  // A drawn but not yet added task goes in too; with nothing at all, the task fields say
  // what is missing.
  if ((points.length || !draftTasks.length) && !addTask()) {
    out.textContent = 'Fix the marked fields first.';
    return;
  }
  if (!ok) return;
  const spec = { mission_id: id, name: form.elements.name.value.trim(), tasks: draftTasks };
  // The station checks the mission as planning would and estimates each vehicle's part;
  // what it refuses here it would refuse on start, so the operator learns it now.
  let preview;
  try {
    preview = await api('POST', '/api/mission-preview', spec);
  } catch (e) {
    out.textContent = describe(e);
    return;
  }
  const body = h('div', {},
    h('p', {}, `${start ? 'Start' : 'Plan'} mission ${id}${spec.name ? ` (${spec.name})` : ''} with ${spec.tasks.length} task(s):`),
    h('ol', {}, spec.tasks.map((t) => h('li', {}, describeTask(t)))),
    previewTable(preview));
  const label = start ? (preview.warnings ? 'Start anyway' : 'Start mission') : 'Plan';
  if (!(await confirmDialog(start ? 'Start mission?' : 'Plan mission?', body, label))) return;
  try {
    const view = await api('POST', `/api/missions${start ? '?start=true' : ''}`, spec);
    putMission(view);
    toast(`Mission ${id} ${view.state}`, 'ok');
    draftTasks = [];
    renderDraftTasks();
    form.elements.mission_id.value = newMissionId();
    renderList();
  } catch (e) {
    out.textContent = describe(e);
  }
}

function buildForm() {
  form = h(
    'form',
    { id: 'mission-form', class: 'card moves', novalidate: true, onsubmit: (e) => { e.preventDefault(); submit(true); } },
    h('h2', {}, 'New mission'),
    h('div', { class: 'row' },
      h('label', {}, 'Mission id', h('input', { name: 'mission_id', value: newMissionId(), required: true })),
      h('label', {}, 'Name', h('input', { name: 'name', placeholder: 'e.g. harbour survey' }))),
    h('fieldset', { class: 'row' },
      h('legend', {}, 'Task'),
      h('label', { class: 'inline' }, h('input', { type: 'radio', name: 'kind', value: 'goto_waypoint', checked: true }), 'Go to waypoints'),
      h('label', { class: 'inline' }, h('input', { type: 'radio', name: 'kind', value: 'survey_area' }), 'Survey an area'),
      h('label', { class: 'inline' }, h('input', { type: 'radio', name: 'kind', value: 'hold' }), 'Hold position'),
      h('label', { class: 'inline' }, h('input', { type: 'radio', name: 'kind', value: 'return_home' }), 'Return home'),
      h('label', { class: 'inline' }, h('input', { type: 'radio', name: 'kind', value: 'surface' }), 'Surface')),
    h('div', { class: 'row survey-only' },
      h('label', { class: 'wide' }, 'Survey for', h('select', { name: 'payload', title: 'the capability the survey needs besides "survey"; sensors count (the semantic model infers it)' }, PAYLOADS.map(([v, t]) => h('option', { value: v }, t))))),
    h('div', { class: 'row' },
      h('label', { class: 'wide' }, 'Vehicle (able to do it, per the semantic model)', h('select', { name: 'vehicle' }))),
    h('ul', { id: 'vehicle-why', class: 'why', 'aria-label': 'vehicles not offered and why' }),
    h('div', { class: 'row moves-only' },
      h('label', {}, 'Keep', h('select', { name: 'vref' },
        h('option', { value: 'depth' }, 'depth (m)'),
        h('option', { value: 'altitude' }, 'altitude above seabed (m)'),
        h('option', { value: 'surface' }, 'at the surface'))),
      h('label', { class: 'level-field' }, 'Metres', h('input', { name: 'level', type: 'number', step: 'any', value: '5' })),
      h('label', { title: "0: the vehicle's own cruise speed" }, 'Speed m/s', h('input', { name: 'speed', type: 'number', step: 'any', min: '0', value: '1.5' })),
      h('label', { class: 'survey-only' }, 'Line spacing m', h('input', { name: 'spacing', type: 'number', step: 'any', value: '20' }))),
    h('p', { id: 'vref-note', class: 'field-note moves-only' }),
    h('div', { class: 'row hold-only' },
      h('label', {}, 'Hold for s', h('input', { name: 'duration', type: 'number', step: 'any', min: '0', value: '60' }))),
    h('div', { class: 'row moves-only' },
      h('button', { type: 'button', id: 'draw', onclick: () => startDraw() }, 'Draw on map'),
      h('button', { type: 'button', onclick: () => { points = []; clearDraft(); stopDraw(); renderPoints(); } }, 'Clear drawing'),
      h('span', { class: 'points-count muted' })),
    h('div', { class: 'moves-only' }, h('ul', { id: 'points', class: 'points' })),
    h('div', { class: 'row' }, h('button', { type: 'button', id: 'add-task', onclick: () => addTask() }, 'Add to mission')),
    h('h3', {}, 'Tasks in this mission'),
    h('ol', { id: 'draft-tasks', class: 'points' }),
    h('p', { id: 'mission-error', class: 'error', role: 'alert' }),
    h('div', { class: 'row' },
      h('button', { type: 'submit', id: 'start-mission', class: 'primary needs-operator' }, 'Review & start'),
      h('button', { type: 'button', class: 'needs-operator', onclick: () => submit(false) }, 'Plan only')),
  );
  form.addEventListener('change', (e) => {
    if (e.target.name === 'kind') {
      form.classList.toggle('survey', kind() === 'survey_area');
      form.classList.toggle('moves', MOVES.has(kind()));
      form.classList.toggle('hold', kind() === 'hold');
      points = [];
      clearDraft();
      stopDraw();
      renderPoints();
      refreshVehicles();
    }
    if (e.target.name === 'payload') refreshVehicles();
    if (e.target.name === 'vehicle') syncVertical();
    if (e.target.name === 'vref') {
      // The operator's own choice: kept until they change it.
      vrefAuto = false;
      syncVertical();
    }
  });
  form.addEventListener('input', (e) => {
    if (e.target.getAttribute('aria-invalid') === 'true') fieldError(e.target, '');
  });
  return form;
}

async function act(method, path, what) {
  try {
    const view = await api(method, path);
    if (view && view.mission_id) putMission(view);
    toast(what, 'ok');
    renderList();
  } catch (e) {
    toast(describe(e), 'error');
  }
}

function missionCard(m) {
  const active = m.state === 'running' || m.state === 'planned';
  return h(
    'div',
    { class: `mission card state-${m.state}`, dataset: { mission: m.mission_id } },
    h('div', { class: 'row spread' },
      h('strong', {}, m.mission_id), m.name ? h('span', {}, m.name) : null,
      h('span', { class: `pill state-${m.state}`, dataset: { state: m.state } }, m.state),
      h('progress', { max: 100, value: m.progress_pct, title: `${fmt(m.progress_pct, 0)} %` }),
      h('span', { class: 'muted' }, `${fmt(m.progress_pct, 0)} %`)),
    h('small', { class: 'muted' }, `created ${dateTime(m.created_ms)}`, m.started_ms ? `, started ${dateTime(m.started_ms)}` : '', m.ended_ms ? `, ended ${dateTime(m.ended_ms)}` : ''),
    h('table', { class: 'grid compact' },
      h('thead', {}, h('tr', {}, ['task', 'vehicle', 'kind', 'state', 'progress', 'message'].map((t) => h('th', {}, t)))),
      h('tbody', {}, m.tasks.map((t) => h('tr', {},
        h('td', {}, t.assignment.task_id),
        h('td', {}, t.assignment.vehicle_id),
        h('td', {}, t.assignment.kind),
        h('td', {}, h('span', { class: `state state-${t.state}` }, t.state)),
        h('td', { class: 'num' }, `${fmt(t.progress_pct, 0)} %`),
        h('td', { class: 'msg' }, t.message || ''))))),
    h('div', { class: 'row' },
      m.state === 'planned' ? h('button', { type: 'button', class: 'needs-operator', onclick: () => act('POST', `/api/missions/${encodeURIComponent(m.mission_id)}/start`, `Mission ${m.mission_id} started`) }, 'Start') : null,
      active ? h('button', {
        type: 'button',
        class: 'danger needs-operator',
        onclick: async () => {
          if (await confirmDialog('Abort mission?', `Abort ${m.mission_id}: pending tasks end and busy vehicles get an abort.`, 'Abort mission')) {
            act('POST', `/api/missions/${encodeURIComponent(m.mission_id)}/abort`, `Mission ${m.mission_id} aborted`);
          }
        },
      }, 'Abort') : null,
      h('a', { href: `/api/missions/${encodeURIComponent(m.mission_id)}/export.csv`, download: `${m.mission_id}.csv` }, 'CSV'),
      h('a', { href: `/api/missions/${encodeURIComponent(m.mission_id)}/export.geojson`, download: `${m.mission_id}.geojson` }, 'GeoJSON'),
      m.started_ms ? h('button', { type: 'button', onclick: () => replayMission(m) }, 'Replay') : null),
  );
}

function renderList() {
  const list = root.querySelector('#mission-list');
  const missions = [...state.missions.values()].sort((a, b) => b.created_ms - a.created_ms);
  const running = missions.filter((m) => !['done', 'failed', 'aborted'].includes(m.state)).length;
  list.replaceChildren(
    h('h2', {}, `Missions (${running} active, ${missions.length} in all)`),
    ...(missions.length ? missions.map(missionCard) : [h('p', { class: 'muted' }, 'No mission yet.')]),
  );
  // Standalone tasks (dispatched through POST /api/tasks) show too.
  const loose = [...state.tasks.values()].filter((t) => !t.assignment.mission_id && !FINAL.has(t.state));
  if (loose.length) list.append(h('p', { class: 'muted' }, `${loose.length} task(s) outside missions under way.`));
}

export function initMissions() {
  root = document.getElementById('tab-missions');
  root.replaceChildren(buildForm(), h('div', { id: 'mission-list' }));
  renderPoints();
  renderDraftTasks();
  renderList();
  on('vehicles', scheduleVehicles);
  on('missions', renderList);
  on('session', () => {
    if (!may('operator')) stopDraw();
    // Logged in now: the station answers who can do the task.
    refreshVehicles();
  });
}

/** Called when the operator opens the tab: the vehicles able to do the task, now. */
export function showMissions() {
  refreshVehicles();
}

/** Called when the operator leaves the tab: drawing clicks must not land on a hidden form. */
export function leaveMissions() {
  stopDraw();
}

export { draftPoints };
