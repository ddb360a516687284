// The mission timeline, a Gantt chart of the fleet's work: one row per vehicle with tasks,
// one bar per task from when it started (or went out) to when it ended, or to now while it
// is under way, coloured by its state. Live: it follows the task and mission updates, and
// bars under way grow once a second while the tab is shown (nothing is drawn while hidden).
//
// Plain SVG like chart.js. The bars are kept and updated in place, keyed by task id, rather
// than redrawn: a bar the operator is clicking must not be replaced under the pointer by
// the once-a-second update.

import { FINAL, on, state } from './store.js';
import { dateTime, fmt, h } from './util.js';

const NS = 'http://www.w3.org/2000/svg';

/** The windows offered: [value, label, span in ms]. */
const WINDOWS = [
  ['15m', 'last 15 min', 15 * 60e3],
  ['1h', 'last hour', 60 * 60e3],
  ['6h', 'last 6 h', 6 * 60 * 60e3],
  ['all', 'all', Infinity],
];
/** Every task state, in the order of a task's life, for the legend. */
const STATES = ['pending', 'sent', 'accepted', 'running', 'done', 'failed', 'aborted', 'expired'];
/** The narrowest time span drawn: a task that just started still has room to grow. */
const MIN_SPAN_MS = 60e3;
/** Tick steps to choose from, in seconds: round times of day. */
const STEPS_S = [1, 2, 5, 10, 15, 30, 60, 120, 300, 600, 900, 1800, 3600, 7200, 10800, 21600, 43200, 86400];

// Geometry in viewBox units (the SVG scales to the tab's width).
const W = 720;
const LEFT = 96;
const RIGHT = 12;
const TOP = 22;
const LANE = 16;
const PAD = 4;

let root;
let windowSel;
let summary;
let svg;
let gGrid;
let gRows;
let gBars;
let nowLine;
let nowLabel;
let empty;
let detailBox;
/** task_id -> its <rect>, kept across renders. */
const bars = new Map();
/** The task whose details show under the chart. */
let selected = null;
let frame = 0;

function el(tag, attrs = {}, text) {
  const e = document.createElementNS(NS, tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  if (text !== undefined) e.textContent = text;
  return e;
}

/** HH:MM:SS in local time, whatever the browser's locale. */
function hms(ms) {
  const d = new Date(ms);
  const p = (n) => String(n).padStart(2, '0');
  return `${p(d.getHours())}:${p(d.getMinutes())}:${p(d.getSeconds())}`;
}

/** "45 s", "12 min 5 s", "2 h 3 min". */
function duration(ms) {
  const s = Math.max(0, Math.round(ms / 1000));
  if (s < 60) return `${s} s`;
  if (s < 3600) return `${Math.floor(s / 60)} min ${s % 60} s`;
  return `${Math.floor(s / 3600)} h ${Math.floor((s % 3600) / 60)} min`;
}

/**
 * Where a task's bar lies: from its start (or its dispatch, or its last change for a task
 * the station has no times for) to its end, or to now while it is not final. A final task
 * without an end time (a station before these times existed) ends at its last change.
 */
function extent(t, now) {
  const start = t.started_ms ?? t.dispatched_ms ?? t.updated_ms;
  const end = t.ended_ms ?? (FINAL.has(t.state) ? t.updated_ms : now);
  // A browser clock behind the station's would otherwise draw bars backwards.
  return { start, end: Math.max(start, end) };
}

/** Spreads a vehicle's bars over lanes so that overlapping ones (a queued task beside the
 *  running one, an abort sent during a task) stack instead of hiding each other. */
function lanes(items) {
  const ends = [];
  for (const it of items.sort((a, b) => a.start - b.start || a.end - b.end)) {
    let lane = ends.findIndex((e) => e <= it.start);
    if (lane < 0) lane = ends.length;
    ends[lane] = it.end;
    it.lane = lane;
  }
  return Math.max(1, ends.length);
}

function tickStep(span) {
  const s = STEPS_S.find((x) => (x * 1000 * 6) >= span) ?? STEPS_S[STEPS_S.length - 1];
  return s * 1000;
}

function title(t, s) {
  const a = t.assignment;
  const lines = [
    `${a.task_id}: ${a.kind.replace(/_/g, ' ')} (mission ${a.mission_id || 'none'})`,
    `state ${t.state}, ${fmt(t.progress_pct, 0)} %`,
    `dispatched ${t.dispatched_ms ? hms(t.dispatched_ms) : '–'}, started ${t.started_ms ? hms(t.started_ms) : '–'}, ended ${t.ended_ms ? hms(t.ended_ms) : '–'}`,
    `${duration(s.end - s.start)}${t.message ? ` — ${t.message}` : ''}`,
  ];
  return lines.join('\n');
}

/** The bar of task `id`, made once with its tooltip. */
function bar(id) {
  let r = bars.get(id);
  if (!r) {
    r = el('rect', { tabindex: '0', role: 'button' });
    r.append(el('title'));
    bars.set(id, r);
    gBars.append(r);
  }
  return r;
}

function fact(name, value) {
  return [h('dt', {}, name), h('dd', {}, value)];
}

function renderDetail(now) {
  const t = selected && state.tasks.get(selected);
  if (!t) {
    detailBox.replaceChildren(h('p', { class: 'muted' }, 'Click a bar for its task.'));
    return;
  }
  const a = t.assignment;
  const s = extent(t, now);
  const ended = FINAL.has(t.state) ? dateTime(t.ended_ms ?? t.updated_ms) : '– (under way)';
  detailBox.replaceChildren(
    h('div', { class: 'card' },
      h('h3', {}, `Task ${a.task_id}`),
      h('dl', { class: 'facts' },
        fact('vehicle', a.vehicle_id),
        fact('mission', a.mission_id || '– (a task of its own)'),
        fact('kind', a.kind.replace(/_/g, ' ')),
        fact('state', h('span', { class: `pill state-${t.state}` }, t.state)),
        fact('progress', `${fmt(t.progress_pct, 0)} %`),
        fact('dispatched', dateTime(t.dispatched_ms)),
        fact('started', dateTime(t.started_ms)),
        fact('ended', ended),
        fact('on the timeline', duration(s.end - s.start)),
        t.link ? fact('link', t.link) : null,
        t.message ? fact('message', t.message) : null)),
  );
}

function render() {
  if (!root.classList.contains('active')) return;
  const now = Date.now();
  const win = WINDOWS.find((w) => w[0] === windowSel.value) || WINDOWS[1];
  const from = now - win[2];
  const byVehicle = new Map();
  let first = Infinity;
  let live = 0;
  for (const t of state.tasks.values()) {
    const s = extent(t, now);
    if (s.end < from) continue;
    const v = t.assignment.vehicle_id;
    if (!byVehicle.has(v)) byVehicle.set(v, []);
    byVehicle.get(v).push({ t, ...s });
    first = Math.min(first, s.start);
    if (!FINAL.has(t.state)) live += 1;
  }
  const count = [...byVehicle.values()].reduce((n, xs) => n + xs.length, 0);
  summary.textContent = count ? `${count} task(s) on ${byVehicle.size} vehicle(s), ${live} not ended` : '';
  empty.hidden = count > 0;
  svg.style.display = count ? '' : 'none';
  renderDetail(now);
  if (!count) {
    for (const r of bars.values()) r.remove();
    bars.clear();
    return;
  }

  // From the earliest start in the window (no earlier than the window) to now.
  const t0 = Math.min(Math.max(first, from), now - MIN_SPAN_MS);
  const x = (t) => LEFT + ((Math.max(t, t0) - t0) / (now - t0)) * (W - LEFT - RIGHT);
  const vehicles = [...byVehicle.keys()].sort((a, b) => a.localeCompare(b));
  let y = TOP;
  gRows.replaceChildren();
  const seen = new Set();
  vehicles.forEach((v, i) => {
    const items = byVehicle.get(v);
    const n = lanes(items);
    const height = n * LANE + 2 * PAD;
    gRows.append(el('rect', { x: 0, y, width: W, height, class: `vehicle-row${i % 2 ? ' odd' : ''}` }));
    const label = el('text', { x: 6, y: y + PAD + LANE - 4, class: 'row-label' }, v.length > 13 ? `${v.slice(0, 12)}…` : v);
    label.append(el('title', {}, v));
    gRows.append(label);
    for (const it of items) {
      const id = it.t.assignment.task_id;
      seen.add(id);
      const r = bar(id);
      const x1 = x(it.start);
      r.setAttribute('x', x1.toFixed(1));
      r.setAttribute('y', y + PAD + it.lane * LANE + 1);
      r.setAttribute('width', Math.max(2, x(it.end) - x1).toFixed(1));
      r.setAttribute('height', LANE - 3);
      r.setAttribute('class', `bar state-${it.t.state}${id === selected ? ' selected' : ''}`);
      r.dataset.task = id;
      r.dataset.vehicle = v;
      r.firstChild.textContent = title(it.t, it);
    }
    y += height;
  });
  for (const [id, r] of bars) {
    if (!seen.has(id)) {
      r.remove();
      bars.delete(id);
    }
  }
  const H = y + 2;
  svg.setAttribute('viewBox', `0 0 ${W} ${H}`);

  // Time ticks over the rows, labelled on top where the labels of the axis's start and of
  // "now" leave room (a label is about 50 units wide, "now HH:MM:SS" about 70).
  gGrid.replaceChildren();
  const xn = x(now);
  const step = tickStep(now - t0);
  for (let t = Math.ceil(t0 / step) * step; t <= now; t += step) {
    const xt = x(t);
    gGrid.append(el('line', { x1: xt, x2: xt, y1: TOP - 4, y2: H, class: 'grid-line' }));
    if (xt > LEFT + 90 && xt < xn - 105) gGrid.append(el('text', { x: xt, y: 12, 'text-anchor': 'middle', class: 'tick' }, hms(t)));
  }
  gGrid.append(el('text', { x: LEFT, y: 12, 'text-anchor': 'start', class: 'tick' }, hms(t0)));
  for (const [k, v] of Object.entries({ x1: xn, x2: xn, y1: TOP - 6, y2: H })) nowLine.setAttribute(k, v);
  nowLabel.setAttribute('x', xn);
  nowLabel.textContent = `now ${hms(now)}`;
}

/** Draws on the next frame: a burst of task updates costs one render. */
function schedule() {
  if (frame || !root.classList.contains('active')) return;
  frame = requestAnimationFrame(() => {
    frame = 0;
    render();
  });
}

function pick(e) {
  const r = e.target.closest('.bar');
  if (!r) return;
  if (e.type === 'keydown' && e.key !== 'Enter' && e.key !== ' ') return;
  e.preventDefault();
  selected = r.dataset.task;
  render();
}

/** Builds the Timeline tab; it draws only while shown. */
export function initTimeline() {
  root = document.getElementById('tab-timeline');
  windowSel = h('select', { id: 'timeline-window', onchange: () => render() }, WINDOWS.map(([v, label]) => h('option', { value: v, selected: v === '1h' }, label)));
  summary = h('span', { id: 'timeline-summary', class: 'muted' });
  svg = el('svg', { class: 'timeline', role: 'img', 'aria-label': 'Tasks per vehicle over time', viewBox: `0 0 ${W} ${TOP}` });
  gRows = el('g');
  gGrid = el('g');
  gBars = el('g', { class: 'bars' });
  nowLine = el('line', { class: 'now-line' });
  nowLabel = el('text', { y: 12, 'text-anchor': 'end', class: 'now-label' });
  svg.append(gRows, gGrid, gBars, nowLine, nowLabel);
  gBars.addEventListener('click', pick);
  gBars.addEventListener('keydown', pick);
  empty = h('p', { class: 'muted' }, 'No task in this window.');
  detailBox = h('div', { id: 'timeline-detail' });
  root.replaceChildren(
    h('div', { class: 'row spread' }, h('label', { class: 'inline' }, 'Show', windowSel), summary),
    svg,
    empty,
    h('ul', { class: 'timeline-legend', 'aria-label': 'task states' }, STATES.map((s) => h('li', {}, h('span', { class: `swatch state-${s}` }), s))),
    detailBox,
  );
  on('tasks', schedule);
  on('missions', schedule);
  // Bars under way end at "now", which moves.
  setInterval(render, 1000);
}

/** Called when the operator opens the tab: draws at once. */
export function showTimeline() {
  render();
}
