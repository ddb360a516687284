// Replay: a past time window on the map, from the history (GET /api/vehicles/{id}/track),
// or the tracks of an MCAP recording the operator opens (POST /api/recordings/tracks, the
// files `shoal record` writes), scrubbed with a slider or played faster than real time.

import { api, describe } from './api.js';
import { Feature, fromLonLat, LineString, Point, setLiveVisible, sources } from './map.js';
import { state } from './store.js';
import { h, time, toLocalInput } from './util.js';

let root;
/** vehicle_id -> { kind, rows: [StateVector...] } */
let tracks = new Map();
let t0 = 0;
let t1 = 0;
let playing = null;
let speed = 10;

/** Index of the last row at or before t (rows sorted by time). */
function at(rows, t) {
  let lo = 0;
  let hi = rows.length - 1;
  if (!rows.length || rows[0].timestamp_ms > t) return -1;
  while (lo < hi) {
    const mid = (lo + hi + 1) >> 1;
    if (rows[mid].timestamp_ms <= t) lo = mid;
    else hi = mid - 1;
  }
  return lo;
}

function draw(t) {
  const features = [];
  for (const [id, tr] of tracks) {
    const i = at(tr.rows, t);
    if (i < 0) continue;
    const coords = tr.rows.slice(0, i + 1).map((r) => fromLonLat([r.longitude_deg, r.latitude_deg]));
    if (coords.length >= 2) {
      const line = new Feature(new LineString(coords));
      line.set('vehicle', id);
      features.push(line);
    }
    const r = tr.rows[i];
    const p = new Feature(new Point(coords[coords.length - 1]));
    p.setProperties({ vehicle: id, kind: tr.kind, yaw: (r.yaw_deg * Math.PI) / 180, label: `${id} ${r.depth_m.toFixed(0)} m ${r.battery_pct.toFixed(0)}%` });
    features.push(p);
  }
  sources.replay.clear(true);
  sources.replay.addFeatures(features);
  root.querySelector('#replay-time').textContent = `${new Date(t).toLocaleDateString()} ${time(t)}`;
}

function stop() {
  clearInterval(playing);
  playing = null;
  const b = root.querySelector('#replay-play');
  if (b) b.textContent = '▶ Play';
}

function play() {
  if (playing) {
    stop();
    return;
  }
  const slider = root.querySelector('#replay-slider');
  if (Number(slider.value) >= t1) slider.value = String(t0);
  root.querySelector('#replay-play').textContent = '⏸ Pause';
  const tick = 100;
  playing = setInterval(() => {
    const next = Math.min(t1, Number(slider.value) + tick * speed);
    slider.value = String(next);
    draw(next);
    if (next >= t1) stop();
  }, tick);
}

/** Sets the slider to [from, to] and shows the tracks loaded, from the start. */
function ready(from, to) {
  t0 = from;
  t1 = to;
  const slider = root.querySelector('#replay-slider');
  slider.min = String(t0);
  slider.max = String(t1);
  slider.step = '1000';
  slider.value = String(t0);
  slider.disabled = false;
  root.querySelector('#replay-play').disabled = false;
  setLiveVisible(false);
  draw(t0);
}

function plural(n, one, many = `${one}s`) {
  return `${n.toLocaleString()} ${n === 1 ? one : many}`;
}

/** Opens an MCAP recording: the station reads its tracks; they replace those shown. */
async function openRecording(file) {
  stop();
  const out = root.querySelector('#replay-status');
  const err = root.querySelector('#replay-error');
  err.textContent = '';
  out.textContent = `Reading ${file.name}…`;
  try {
    const res = await api('POST', '/api/recordings/tracks', undefined, { raw: file, contentType: 'application/octet-stream' });
    const loaded = new Map();
    for (const v of res.vehicles) {
      const live = state.vehicles.get(v.vehicle_id);
      loaded.set(v.vehicle_id, { kind: v.kind || (live ? live.announcement.kind : 'auv'), rows: v.rows });
    }
    const summary = `${file.name}: ${plural(res.vehicles.length, 'vehicle')}, ${plural(res.messages, 'message')} (${plural(res.state_vectors, 'state vector')})${res.skipped ? `, ${res.skipped.toLocaleString()} skipped` : ''}.`;
    const notes = [];
    if (res.thinned) notes.push('Long tracks were thinned evenly to fit the answer.');
    if (res.omitted) notes.push(`${plural(res.omitted, 'state vector')} of vehicles beyond the first 1000 left out.`);
    if (res.error) err.textContent = `The file could not be read to its end: ${res.error}. What came before is shown.`;
    if (!loaded.size || res.from_ms === null) {
      out.textContent = `${summary} No state vectors to replay.`;
      return;
    }
    tracks = loaded;
    out.textContent = [summary, ...notes].join(' ');
    ready(res.from_ms, Math.max(res.to_ms, res.from_ms + 1000));
  } catch (e) {
    out.textContent = `${file.name}: not opened.`;
    err.textContent = e.status === 0 && file.size > 1 << 20
      ? `${describe(e)} (a file this large may be over the station's [console.limits] max_recording_bytes)`
      : describe(e);
  }
}

async function load() {
  stop();
  root.querySelector('#replay-error').textContent = '';
  const f = root.querySelector('#replay-form').elements;
  const out = root.querySelector('#replay-status');
  const from = new Date(f.from.value).getTime();
  const to = new Date(f.to.value).getTime();
  if (!(from < to)) {
    out.textContent = 'The window must start before it ends.';
    return;
  }
  const ids = [...root.querySelectorAll('input[name=replay-vehicle]:checked')].map((c) => c.value);
  if (!ids.length) {
    out.textContent = 'Choose at least one vehicle.';
    return;
  }
  out.textContent = 'Loading…';
  try {
    const results = await Promise.all(ids.map((id) => api('GET', `/api/vehicles/${encodeURIComponent(id)}/track?from_ms=${from}&to_ms=${to}&limit=10000`)));
    tracks = new Map();
    let n = 0;
    ids.forEach((id, i) => {
      const v = state.vehicles.get(id);
      tracks.set(id, { kind: v ? v.announcement.kind : 'auv', rows: results[i] });
      n += results[i].length;
    });
    out.textContent = `${n} state vectors of ${ids.length} vehicle(s).${n >= 10000 * ids.length ? ' Some tracks were cut at 10 000 points: choose a shorter window.' : ''}`;
    ready(from, to);
  } catch (e) {
    out.textContent = describe(e);
  }
}

function exit() {
  stop();
  tracks = new Map();
  sources.replay.clear();
  setLiveVisible(true);
  const slider = root.querySelector('#replay-slider');
  slider.disabled = true;
  root.querySelector('#replay-play').disabled = true;
  root.querySelector('#replay-status').textContent = 'Live view.';
  root.querySelector('#replay-error').textContent = '';
  root.querySelector('#replay-time').textContent = '';
}

function vehicleChoices(selected) {
  const box = root.querySelector('#replay-vehicles');
  const ids = [...state.vehicles.keys()].sort();
  box.replaceChildren(...ids.map((id) => h('label', { class: 'inline' }, h('input', { type: 'checkbox', name: 'replay-vehicle', value: id, checked: !selected || selected.includes(id) }), id)));
}

/** Opens the replay on a mission's vehicles and time window. */
export function replayMission(m) {
  document.querySelector('#tabs button[data-tab=replay]').click();
  const f = root.querySelector('#replay-form').elements;
  f.from.value = toLocalInput(m.started_ms || m.created_ms);
  f.to.value = toLocalInput(m.ended_ms || Date.now());
  vehicleChoices([...new Set(m.tasks.map((t) => t.assignment.vehicle_id))]);
  load();
}

export function initReplay() {
  root = document.getElementById('tab-replay');
  const now = Date.now();
  root.replaceChildren(
    h('h2', {}, 'Replay a time window or a recording'),
    h('form', { id: 'replay-form', class: 'card', onsubmit: (e) => { e.preventDefault(); load(); } },
      h('div', { class: 'row' },
        h('label', {}, 'From', h('input', { type: 'datetime-local', name: 'from', step: 1, value: toLocalInput(now - 15 * 60000) })),
        h('label', {}, 'To', h('input', { type: 'datetime-local', name: 'to', step: 1, value: toLocalInput(now) }))),
      h('div', { id: 'replay-vehicles', class: 'row' }),
      h('div', { class: 'row' },
        h('button', { type: 'submit', class: 'primary', id: 'replay-load' }, 'Load'),
        h('button', { type: 'button', onclick: exit }, 'Back to live'),
        h('label', { class: 'inline', title: 'A file shoal record wrote: the station reads its state vectors and nothing is stored' }, 'Open recording (.mcap)',
          h('input', {
            type: 'file',
            id: 'replay-file',
            accept: '.mcap,application/x-mcap',
            onchange: (e) => {
              const file = e.target.files[0];
              // Cleared, so that choosing the same file again opens it again.
              e.target.value = '';
              if (file) openRecording(file);
            },
          })))),
    h('div', { class: 'card' },
      h('input', { type: 'range', id: 'replay-slider', disabled: true, oninput: (e) => draw(Number(e.target.value)) }),
      h('div', { class: 'row' },
        h('button', { type: 'button', id: 'replay-play', disabled: true, onclick: play }, '▶ Play'),
        h('label', {}, 'Speed ', h('select', { onchange: (e) => { speed = Number(e.target.value); } }, [1, 10, 60, 300].map((s) => h('option', { value: s, selected: s === speed }, `×${s}`)))),
        h('strong', { id: 'replay-time' })),
      h('p', { id: 'replay-status', class: 'muted' }, 'Live view.'),
      h('p', { id: 'replay-error', class: 'field-error', role: 'alert' })),
  );
}

/** Called when the tab is shown: the vehicle list may have grown. */
export function showReplay() {
  if (!tracks.size) vehicleChoices(null);
}
