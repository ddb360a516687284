// The fleet list: every vehicle with its link, contact, availability, state and current task,
// live from the WebSocket; stale and lost vehicles stand out. Other sites' vehicles follow
// in a section of their own (federation.js), never in this table.

import { remoteSection } from './federation.js';
import { centerOn } from './map.js';
import { currentTask, emit, on, state } from './store.js';
import { ago, fmt, h } from './util.js';

let root;
/** Last contact seen per vehicle, to mark the moment it changes. */
const lastContact = new Map();
/** vehicle_id -> time until which its row is marked as just changed. */
const changedUntil = new Map();
const CHANGE_MARK_MS = 6000;

/** Notes contact changes (alive → stale → lost and back) so the row stands out for a while. */
function noteContact(rows, now) {
  for (const v of rows) {
    const id = v.announcement.vehicle_id;
    const before = lastContact.get(id);
    if (before && before !== v.contact) changedUntil.set(id, now + CHANGE_MARK_MS);
    lastContact.set(id, v.contact);
  }
}

function linkCell(v) {
  const parts = [h('span', { class: `link link-${v.link}` }, v.link)];
  const ls = v.link_status;
  if (ls) {
    const q = [];
    if (ls.rssi_db !== null && ls.rssi_db !== undefined) q.push(`${ls.rssi_db} dB`);
    if (ls.integrity !== null && ls.integrity !== undefined) q.push(`integrity ${ls.integrity}`);
    q.push(`modem ${ls.vehicle_address}↔${ls.cdt_address}`);
    parts.push(h('small', { class: 'quality', title: `CDT participant ${ls.participant}; heard ${ago(ls.heard_ms)}` }, q.join(', ')));
  }
  return parts;
}

function battery(pct) {
  if (typeof pct !== 'number') return '–';
  const cls = pct < 20 ? 'low' : pct < 40 ? 'mid' : 'ok';
  return h('span', { class: `battery ${cls}`, title: `${pct.toFixed(1)} %` }, h('span', { class: 'fill', style: `width:${Math.max(0, Math.min(100, pct))}%` }), h('span', { class: 'pct' }, `${pct.toFixed(0)}%`));
}

function taskCell(id) {
  const t = currentTask(id);
  if (!t) return h('span', { class: 'muted' }, 'none');
  const a = t.assignment;
  const progress = t.state === 'running' ? ` ${Math.round(t.progress_pct)}%` : '';
  return h('span', { class: `state state-${t.state}`, title: `${a.task_id} (mission ${a.mission_id || '–'}) ${t.message || ''}` }, `${a.kind.replace('_', ' ')}: ${t.state}${progress}`);
}

function render() {
  const now = Date.now();
  const rows = [...state.vehicles.values()].sort((a, b) => a.announcement.vehicle_id.localeCompare(b.announcement.vehicle_id));
  const counts = { alive: 0, stale: 0, lost: 0, silent: 0 };
  noteContact(rows, now);
  const body = rows.map((v) => {
    const a = v.announcement;
    const s = v.latest || {};
    counts[v.contact] = (counts[v.contact] || 0) + 1;
    const changed = (changedUntil.get(a.vehicle_id) || 0) > now;
    return h(
      'tr',
      {
        class: `contact-${v.contact}${changed ? ' contact-changed' : ''}${state.selected === a.vehicle_id ? ' selected' : ''}`,
        title: v.contact === 'alive' ? undefined : `${a.vehicle_id}: ${v.contact}, last heard ${ago(v.last_contact_ms, now)}`,
        dataset: { vehicle: a.vehicle_id },
        onclick: () => {
          state.selected = a.vehicle_id;
          emit('select', a.vehicle_id);
          if (v.latest) centerOn(v.latest.longitude_deg, v.latest.latitude_deg);
        },
      },
      h('td', {}, h('strong', {}, a.vehicle_id), a.name && a.name !== a.vehicle_id ? h('small', {}, a.name) : null),
      h('td', {}, a.kind.toUpperCase()),
      h('td', {}, a.vendor || '–'),
      h('td', {}, linkCell(v)),
      h('td', { class: 'contact' }, h('span', { class: `pill contact-${v.contact}` }, v.contact), h('small', {}, ago(v.last_contact_ms, now))),
      h('td', {}, h('span', { class: `pill avail-${v.availability}` }, v.availability)),
      h('td', { class: 'num' }, fmt(s.depth_m)),
      h('td', { class: 'num' }, fmt(s.speed_mps)),
      h('td', {}, battery(s.battery_pct)),
      h('td', {}, taskCell(a.vehicle_id)),
    );
  });
  const tableEl = h(
    'table',
    { class: 'grid fleet', id: 'fleet-table' },
    h('thead', {}, h('tr', {}, ['vehicle', 'kind', 'vendor', 'link', 'contact', 'availability', 'depth m', 'speed m/s', 'battery', 'task'].map((t) => h('th', {}, t)))),
    h('tbody', {}, body),
  );
  root.replaceChildren(
    h('p', { class: 'summary' }, `${rows.length} vehicles: ${counts.alive} alive, ${counts.stale} stale, ${counts.lost} lost, ${counts.silent} silent`),
    rows.length ? tableEl : h('p', { class: 'muted' }, 'No vehicle has announced itself yet.'),
    remoteSection(),
  );
  const remote = state.federation.enabled ? state.federation.vehicles.length : 0;
  document.getElementById('counts').textContent = `${counts.alive}/${rows.length} vehicles alive${remote ? ` · ${remote} at other sites` : ''}`;
}

export function initFleet() {
  root = document.getElementById('tab-fleet');
  on('vehicles', render);
  on('tasks', render);
  on('select', render);
  on('federation', render);
  // "time since last contact" keeps moving between updates.
  setInterval(render, 1000);
  render();
}
