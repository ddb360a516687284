// Missions: the editor (waypoints clicked or a survey polygon drawn on the map, depth or
// altitude, speed, a capable vehicle), then confirm and start; the list of missions with
// their tasks' progress, abort, export and replay.

import { api, describe } from './api.js';
import { clearDraft, draftPoints, setDraft, startDrawing, stopDrawing } from './map.js';
import { FINAL, may, on, putMission, state } from './store.js';
import { confirmDialog, dateTime, fieldError, fmt, h, ID_PATTERN, toast } from './util.js';
import { replayMission } from './replay.js';

let root;
let form;
/** Tasks added to the mission being written: [{vehicle_id, task}]. */
let draftTasks = [];
let points = [];

const CAPABILITY = { goto_waypoint: 'goto', survey_area: 'survey' };

function newMissionId() {
  const d = new Date();
  const p = (n) => String(n).padStart(2, '0');
  return `m-${d.getFullYear()}${p(d.getMonth() + 1)}${p(d.getDate())}-${p(d.getHours())}${p(d.getMinutes())}${p(d.getSeconds())}`;
}

function kind() {
  return form.elements.kind.value;
}

/** Vehicles that announced the capability the task kind needs. */
function capableVehicles(k) {
  const need = CAPABILITY[k];
  return [...state.vehicles.values()].filter((v) => v.announcement.capabilities.includes(need));
}

function refreshVehicles() {
  const sel = form.elements.vehicle;
  const k = kind();
  const keep = sel.value;
  const capable = capableVehicles(k);
  const options = capable
    .sort((a, b) => a.announcement.vehicle_id.localeCompare(b.announcement.vehicle_id))
    .map((v) => {
      const a = v.announcement;
      const note = v.contact !== 'alive' ? ` — ${v.contact}` : v.availability !== 'idle' ? ` — ${v.availability}` : '';
      return h('option', { value: a.vehicle_id, selected: a.vehicle_id === keep }, `${a.vehicle_id} (${a.kind}, max ${fmt(a.max_speed_mps)} m/s)${note}`);
    });
  sel.replaceChildren(h('option', { value: '' }, `— ${capable.length} of ${state.vehicles.size} vehicles can ${CAPABILITY[k]} —`), ...options);
  if (capable.some((v) => v.announcement.vehicle_id === keep)) sel.value = keep;
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
  if (!points.length) list.append(h('li', { class: 'muted' }, k === 'survey_area' ? 'Draw the survey polygon on the map (double-click closes it).' : 'Click waypoints on the map, in order.'));
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
  ok = fieldError(form.elements.vehicle, vehicleId ? '' : `Choose a vehicle that can ${CAPABILITY[k]}.`) && ok;
  const vref = form.elements.vref.value;
  const level = num('level');
  const [lo, hi] = vref === 'depth' ? [0, 11000] : [0, 10000];
  ok = fieldError(form.elements.level, Number.isFinite(level) && level >= lo && level <= hi ? '' : `${vref} must be a number of metres in [${lo}, ${hi}].`) && ok;
  const speed = num('speed');
  let speedMsg = '';
  if (!(Number.isFinite(speed) && speed > 0 && speed <= 30)) speedMsg = 'Speed must be in (0, 30] m/s.';
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
  const vertical = vref === 'depth' ? { depth_m: level } : { altitude_m: level };
  if (k === 'survey_area') {
    return [{ vehicle_id: vehicleId, task: { kind: 'survey_area', polygon: points.slice(), line_spacing_m: spacing, ...vertical, speed_mps: speed } }];
  }
  return points.map((p) => ({ vehicle_id: vehicleId, task: { kind: 'goto_waypoint', target: p, ...vertical, speed_mps: speed } }));
}

function describeTask(t) {
  const x = t.task;
  const v = x.depth_m !== undefined ? `depth ${x.depth_m} m` : `altitude ${x.altitude_m} m`;
  if (x.kind === 'survey_area') return `${t.vehicle_id}: survey ${x.polygon.length} corners, lines ${x.line_spacing_m} m apart, ${v}, ${x.speed_mps} m/s`;
  return `${t.vehicle_id}: go to ${x.target.latitude_deg.toFixed(5)}, ${x.target.longitude_deg.toFixed(5)}, ${v}, ${x.speed_mps} m/s`;
}

function renderDraftTasks() {
  const box = form.querySelector('#draft-tasks');
  box.replaceChildren(
    ...draftTasks.map((t, i) =>
      h('li', {}, `${i + 1}. ${describeTask(t)} `, h('button', { type: 'button', class: 'link-button', onclick: () => { draftTasks.splice(i, 1); renderDraftTasks(); } }, '✕')),
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
  const body = h('div', {}, h('p', {}, `${start ? 'Start' : 'Plan'} mission ${id}${spec.name ? ` (${spec.name})` : ''} with ${spec.tasks.length} task(s):`), h('ol', {}, spec.tasks.map((t) => h('li', {}, describeTask(t)))));
  if (!(await confirmDialog(start ? 'Start mission?' : 'Plan mission?', body, start ? 'Start mission' : 'Plan'))) return;
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
    { id: 'mission-form', class: 'card', novalidate: true, onsubmit: (e) => { e.preventDefault(); submit(true); } },
    h('h2', {}, 'New mission'),
    h('div', { class: 'row' },
      h('label', {}, 'Mission id', h('input', { name: 'mission_id', value: newMissionId(), required: true })),
      h('label', {}, 'Name', h('input', { name: 'name', placeholder: 'e.g. harbour survey' }))),
    h('fieldset', { class: 'row' },
      h('legend', {}, 'Task'),
      h('label', { class: 'inline' }, h('input', { type: 'radio', name: 'kind', value: 'goto_waypoint', checked: true }), 'Go to waypoints'),
      h('label', { class: 'inline' }, h('input', { type: 'radio', name: 'kind', value: 'survey_area' }), 'Survey an area')),
    h('div', { class: 'row' },
      h('label', { class: 'wide' }, 'Vehicle', h('select', { name: 'vehicle' }))),
    h('div', { class: 'row' },
      h('label', {}, 'Keep', h('select', { name: 'vref' }, h('option', { value: 'depth' }, 'depth (m)'), h('option', { value: 'altitude' }, 'altitude above seabed (m)'))),
      h('label', {}, 'Metres', h('input', { name: 'level', type: 'number', step: 'any', value: '5' })),
      h('label', {}, 'Speed m/s', h('input', { name: 'speed', type: 'number', step: 'any', value: '1.5' })),
      h('label', { class: 'survey-only' }, 'Line spacing m', h('input', { name: 'spacing', type: 'number', step: 'any', value: '20' }))),
    h('div', { class: 'row' },
      h('button', { type: 'button', id: 'draw', onclick: () => startDraw() }, 'Draw on map'),
      h('button', { type: 'button', onclick: () => { points = []; clearDraft(); stopDraw(); renderPoints(); } }, 'Clear drawing'),
      h('span', { class: 'points-count muted' })),
    h('div', {}, h('ul', { id: 'points', class: 'points' })),
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
      points = [];
      clearDraft();
      stopDraw();
      renderPoints();
      refreshVehicles();
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
  refreshVehicles();
  renderList();
  on('vehicles', () => {
    if (!form.contains(document.activeElement) || document.activeElement !== form.elements.vehicle) refreshVehicles();
  });
  on('missions', renderList);
  on('session', () => {
    if (!may('operator')) stopDraw();
  });
}

/** Called when the operator leaves the tab: drawing clicks must not land on a hidden form. */
export function leaveMissions() {
  stopDraw();
}

export { draftPoints };
