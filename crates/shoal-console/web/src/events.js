// Alarms and events: the live list, coloured by severity, newest first; unacknowledged
// warnings and worse are counted on the tab and can be acknowledged. Other sites' alarms
// (federation.js) are listed among them, marked with their site; they are acknowledged
// at their own site, so they get no button here and do not count on the tab.

import { api, describe } from './api.js';
import { remoteAlarms } from './federation.js';
import { may, on, putEvent, state } from './store.js';
import { dateTime, h, toast } from './util.js';

let root;
let onlyOpen = false;
let showLinkStatus = false;
const RANK = { info: 0, warning: 1, alarm: 2, critical: 3 };
/** What the remote alarms were at the last render (their count and newest). */
let remoteMark = '';

/** Link-status entries (`link.<vehicle>`) are the acoustic link table, not alarms. */
const isLinkStatus = (e) => e.event_id.startsWith('link.');

async function ack(e) {
  try {
    const by = state.session.user || 'operator';
    const view = await api('POST', `/api/events/${encodeURIComponent(e.event_id)}/ack`, { by });
    putEvent(view);
    render();
  } catch (err) {
    toast(describe(err), 'error');
  }
}

function remoteRow(e) {
  return h('tr', { class: `sev-${e.severity} remote-event`, dataset: { remoteEvent: `${e.site}/${e.event_id}`, site: e.site } },
    h('td', {}, dateTime(e.timestamp_ms)),
    h('td', {}, h('span', { class: `pill sev-${e.severity}` }, e.severity)),
    h('td', {}, e.kind.replace('_', ' ')),
    h('td', {}, e.vehicle_id ? `${e.vehicle_id} · ${e.site}` : '–'),
    h('td', { class: 'msg' }, h('span', { class: 'pill site', title: `raised at site ${e.site}` }, e.site), ' ', e.text),
    h('td', { class: 'muted' }, `at ${e.site}`));
}

function render() {
  const all = [...state.events.values()].filter((e) => showLinkStatus || !isLinkStatus(e));
  const open = all.filter((e) => !e.acknowledged && RANK[e.severity] >= 1);
  const badge = document.getElementById('alarm-badge');
  badge.hidden = open.length === 0;
  badge.textContent = String(open.length);
  badge.className = `badge sev-${open.reduce((m, e) => (RANK[e.severity] > RANK[m] ? e.severity : m), 'warning')}`;
  const remote = remoteAlarms()
    .filter((r) => !onlyOpen || RANK[r.alarm.severity] >= 1)
    .map((r) => ({ ...r.alarm, site: r.site }));
  const rows = [...(onlyOpen ? open : all), ...remote].sort((a, b) => b.timestamp_ms - a.timestamp_ms).slice(0, 300);
  const list = h(
    'table',
    { class: 'grid events', id: 'event-table' },
    h('thead', {}, h('tr', {}, ['time', 'severity', 'kind', 'vehicle', 'text', 'acknowledged'].map((t) => h('th', {}, t)))),
    h('tbody', {}, rows.map((e) => (e.site ? remoteRow(e) : h('tr', { class: `sev-${e.severity}${e.acknowledged ? ' acked' : ''}`, dataset: { event: e.event_id } },
      h('td', {}, dateTime(e.timestamp_ms)),
      h('td', {}, h('span', { class: `pill sev-${e.severity}` }, e.severity)),
      h('td', {}, e.kind.replace('_', ' ')),
      h('td', {}, e.vehicle_id || '–'),
      h('td', { class: 'msg' }, e.text),
      h('td', {}, e.acknowledged
        ? `${e.acknowledged.by}, ${dateTime(e.acknowledged.at_ms)}`
        : h('button', { type: 'button', class: 'ack needs-operator', onclick: () => ack(e) }, 'Acknowledge')))))),
  );
  root.querySelector('#event-list').replaceChildren(
    h('p', { class: 'summary' }, `${open.length} unacknowledged warning(s) or worse; ${all.length} events in all${remote.length ? `; ${remote.length} from other sites` : ''}.`),
    rows.length ? list : h('p', { class: 'muted' }, 'No event.'),
  );
}

export function initEvents() {
  root = document.getElementById('tab-alarms');
  root.replaceChildren(
    h('div', { class: 'row' },
      h('label', { class: 'inline' }, h('input', { type: 'checkbox', onchange: (e) => { onlyOpen = e.target.checked; render(); } }), 'only unacknowledged warnings and worse'),
      h('label', { class: 'inline' }, h('input', { type: 'checkbox', onchange: (e) => { showLinkStatus = e.target.checked; render(); } }), 'show acoustic link status entries')),
    h('div', { id: 'event-list' }),
  );
  on('federation', () => {
    // Every poll answers the whole picture; redraw only when its alarms changed.
    const n = remoteAlarms().length;
    const last = remoteAlarms()[n - 1];
    const mark = `${n}/${last ? `${last.site}/${last.alarm.event_id}` : ''}`;
    if (mark !== remoteMark) {
      remoteMark = mark;
      render();
    }
  });
  on('events', (e) => {
    render();
    // A new alarm the operator has not seen is worth interrupting for.
    if (e && !e.acknowledged && RANK[e.severity] >= 2 && !isLinkStatus(e) && may('viewer')) {
      toast(`${e.severity.toUpperCase()}: ${e.vehicle_id ? `${e.vehicle_id}: ` : ''}${e.text}`, e.severity === 'critical' ? 'error' : 'warn');
    }
  });
  render();
}
