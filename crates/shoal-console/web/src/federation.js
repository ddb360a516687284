// Other sites' vehicles, alarms and task transitions, as the federation brings them
// (docs/federation.md): polled from GET /api/federation, drawn on the map apart from the
// own fleet and listed under "Other sites" in the fleet panel (each site's vehicles, then
// its latest tasks). The command leases (which site commands each vehicle) are listed
// too: an operator hands over a lease this site holds, and commands another site's vehicle
// whose lease is held here (surface, abort), which goes to that vehicle through its site.
// Nothing else offers another site's vehicles for a task.

import Overlay from 'ol/Overlay.js';
import { api, describe } from './api.js';
import { centerOn, map, remoteAtPixel, remoteKey, renderRemoteVehicles, REMOTE_OLD_MS, REMOTE_VERY_OLD_MS, sources } from './map.js';
import { emit, state } from './store.js';
import { ago, fmt, h, time, toast } from './util.js';

/** Seconds between polls while federated; a station answering `enabled: false` is asked
 *  again rarely, in case it is restarted federated. */
const POLL_S = 2;
const IDLE_POLL_S = 60;
/** The picture is marked stale once no answer came for this long. */
const STALE_MS = 3 * POLL_S * 1000;

let timer = null;
let running = false;
/** Bumped on every start and stop, so a poll still in flight from before a logout does
 *  not schedule a second loop beside the new one. */
let generation = 0;
/** Remote alarms already seen (`site/event_id`); null until the first answer, so that
 *  what a site raised before the console opened is listed without a toast each. */
let seenAlarms = null;
let popup = null;
/** `site/vehicle_id` of the vehicle the popup shows, and whether a click pinned it. */
let shown = null;
let pinned = false;

const fed = () => state.federation;

/** How old a remote vehicle's fix is now: the station's age plus the time since it answered. */
export function ageNow(v, now = Date.now()) {
  return v.age_ms + Math.max(0, now - fed().receivedMs);
}

/** True when the last answer is too old to trust (polls failing, or none for a while). */
function stale(now = Date.now()) {
  return fed().error !== null || now - fed().receivedMs > STALE_MS;
}

function ageText(ms) {
  const s = Math.round(ms / 1000);
  if (s < 90) return `${s} s`;
  if (s < 5400) return `${Math.round(s / 60)} min`;
  return `${Math.round(s / 3600)} h`;
}

function ageClass(ms) {
  return ms > REMOTE_VERY_OLD_MS ? 'age-very-old' : ms > REMOTE_OLD_MS ? 'age-old' : 'age-fresh';
}

function noteNewAlarms(alarms) {
  const keys = alarms.map((a) => `${a.site}/${a.alarm.event_id}`);
  if (seenAlarms !== null) {
    alarms.forEach((a, i) => {
      const e = a.alarm;
      if (seenAlarms.has(keys[i]) || !['alarm', 'critical'].includes(e.severity)) return;
      // Another site's alarm is acknowledged there; here it is news, not a task.
      toast(`${e.severity.toUpperCase()} at ${a.site}: ${e.vehicle_id ? `${e.vehicle_id}: ` : ''}${e.text}`, 'warn');
    });
  }
  seenAlarms = new Set(keys);
}

function redraw() {
  const now = Date.now();
  renderRemoteVehicles(fed().vehicles, (v) => ageNow(v, now), state.remoteSelected);
  refreshPopup();
}

async function poll(gen) {
  let next = POLL_S;
  try {
    const doc = await api('GET', '/api/federation');
    if (gen !== generation) return;
    if (!doc.enabled) next = IDLE_POLL_S;
    Object.assign(state.federation, {
      enabled: doc.enabled,
      site: doc.site,
      sites: doc.sites,
      vehicles: doc.vehicles,
      alarms: doc.alarms,
      transitions: doc.transitions || [],
      environment: doc.environment || [],
      leases: doc.leases || [],
      leaseEnabled: Boolean(doc.lease_enabled),
      receivedMs: Date.now(),
      error: null,
    });
    noteNewAlarms(doc.alarms);
  } catch (e) {
    // The last picture stays, marked stale, with its ages still growing.
    if (gen !== generation) return;
    fed().error = describe(e);
    if (e.status === 401) {
      // Logged out: polling would only keep asking the login form to show again; the
      // next login starts it anew (main.js).
      running = false;
      timer = null;
      emit('federation', fed());
      return;
    }
    if (fed().enabled === false) next = IDLE_POLL_S;
  }
  redraw();
  emit('federation', fed());
  if (running && gen === generation) timer = setTimeout(() => poll(gen), next * 1000);
}

/** Starts polling (again after a logout; while running, does nothing). */
export function startFederation() {
  if (running) return;
  running = true;
  generation += 1;
  poll(generation);
}

export function stopFederation() {
  running = false;
  generation += 1;
  clearTimeout(timer);
  timer = null;
}

function find(key) {
  return fed().vehicles.find((v) => remoteKey(v) === key) || null;
}

function popupBody(v) {
  const age = ageNow(v);
  const facts = [
    ['site', v.site],
    ['kind', v.kind.toUpperCase()],
    ['depth', `${fmt(v.depth_m)} m`],
    ['battery', `${fmt(v.battery_pct, 0)} %`],
    ['speed', `${fmt(v.speed_mps)} m/s`],
    ['heading', `${fmt(v.heading_deg, 0)}°`],
    ['position', `${v.latitude_deg.toFixed(5)}, ${v.longitude_deg.toFixed(5)}`],
    ['age', `${ageText(age)} (fix at ${time(v.timestamp_ms)})`],
  ];
  return [
    pinned ? h('button', { type: 'button', class: 'close', title: 'Close', onclick: unpin }, '×') : null,
    h('strong', {}, `${v.vehicle_id} · ${v.site}`),
    h('small', { class: 'muted' }, `another site's vehicle: read-only${stale() ? '; picture not updating' : ''}`),
    h('dl', { class: 'facts' }, facts.flatMap(([k, val]) => [h('dt', {}, k), h('dd', { dataset: { fact: k } }, val)])),
  ];
}

function refreshPopup() {
  if (!popup) return;
  const v = shown && find(shown);
  const f = v && sources.remote.getFeatureById(shown);
  if (!f) {
    // Gone from the picture (or nothing hovered): a pinned one comes back if it reappears.
    popup.setPosition(undefined);
    return;
  }
  const el = popup.getElement();
  el.classList.toggle('pinned', pinned);
  el.classList.toggle('stale', stale());
  el.replaceChildren(...popupBody(v).filter(Boolean));
  el.dataset.remote = shown;
  popup.setPosition(f.getGeometry().getCoordinates());
}

/** Shows the popup of a remote vehicle; `pin` keeps it up (and the vehicle highlighted). */
function showRemote(key, pin) {
  shown = key;
  pinned = pin;
  if (pin) state.remoteSelected = key;
  redraw();
  if (pin) emit('federation', fed());
}

function unpin() {
  if (!pinned && state.remoteSelected === null) return;
  pinned = false;
  shown = null;
  state.remoteSelected = null;
  redraw();
  emit('federation', fed());
}

/** Hover and click on the map's remote vehicles; call once the map exists. */
export function initFederation() {
  const el = h('div', { id: 'remote-info', class: 'remote-info', role: 'tooltip' });
  popup = new Overlay({ element: el, offset: [14, -10], positioning: 'bottom-left', stopEvent: false });
  map.addOverlay(popup);
  let pointer = false;
  map.on('pointermove', (evt) => {
    if (evt.dragging) return;
    const f = remoteAtPixel(evt.pixel);
    if (Boolean(f) !== pointer) {
      pointer = Boolean(f);
      map.getTargetElement().style.cursor = pointer ? 'pointer' : '';
    }
    if (pinned) return;
    const key = f ? f.getId() : null;
    if (key !== shown) {
      shown = key;
      refreshPopup();
    }
  });
  map.on('singleclick', (evt) => {
    const f = remoteAtPixel(evt.pixel);
    // Never `select`: that is the own vehicle the command views act on.
    if (f) showRemote(f.getId(), true);
    else unpin();
  });
  // Ages keep growing between answers, and faster when polls fail.
  setInterval(() => {
    if (fed().vehicles.length) redraw();
  }, 5000);
}

function siteRows(site, vehicles, now) {
  return vehicles.map((v) => {
    const key = remoteKey(v);
    const age = ageNow(v, now);
    return h(
      'tr',
      {
        class: `remote-vehicle ${ageClass(age)}${state.remoteSelected === key ? ' selected' : ''}`,
        title: `${v.vehicle_id} at ${site}: fix ${ageText(age)} old; read-only (commanded by ${site})`,
        dataset: { remote: key, site },
        onclick: () => {
          centerOn(v.longitude_deg, v.latitude_deg);
          showRemote(key, true);
        },
      },
      h('td', {}, h('strong', {}, v.vehicle_id), h('small', {}, `· ${site}`)),
      h('td', {}, v.kind.toUpperCase()),
      h('td', { class: 'num' }, fmt(v.depth_m)),
      h('td', { class: 'num' }, fmt(v.speed_mps)),
      h('td', { class: 'num' }, `${fmt(v.battery_pct, 0)}%`),
      h('td', { class: 'num age' }, ageText(age)),
    );
  });
}

/** Tasks shown per site: the latest state of each, newest first. */
const TASKS_SHOWN = 8;

/** The latest transition of each of a site's tasks, newest first, at most TASKS_SHOWN. */
export function latestTasks(transitions, site) {
  const last = new Map();
  for (const t of transitions) {
    if (t.site !== site) continue;
    const seen = last.get(t.task_id);
    // Transitions come oldest first; equal times keep the later one (it arrived last).
    if (!seen || t.timestamp_ms >= seen.timestamp_ms) last.set(t.task_id, t);
  }
  return [...last.values()].sort((a, b) => b.timestamp_ms - a.timestamp_ms).slice(0, TASKS_SHOWN);
}

function taskRows(site, tasks, now) {
  return tasks.map((t) => h(
    'tr',
    {
      class: 'remote-task',
      title: `${t.task_id} at ${site}${t.mission_id ? ` (mission ${t.mission_id})` : ''}: ${t.state} at ${time(t.timestamp_ms)}; read-only`,
      dataset: { task: t.task_id, site, state: t.state },
    },
    h('td', {}, h('strong', {}, t.task_id)),
    h('td', {}, t.vehicle_id),
    h('td', {}, h('span', { class: `pill state-${t.state}` }, t.state)),
    h('td', { class: 'num age' }, ago(t.timestamp_ms, now)),
  ));
}

/** A site's environment data, aggregated per vehicle and property over each window
 *  (mean, range, count, the window's age), or nothing before the first window. */
function remoteEnvironment(site, environment, now) {
  const rows = (environment || []).filter((e) => e.site === site)
    .sort((a, b) => a.vehicle_id.localeCompare(b.vehicle_id) || a.property.localeCompare(b.property));
  if (!rows.length) return null;
  return h('table', { class: 'grid compact remote remote-environment' },
    h('thead', {}, h('tr', {}, ['vehicle', 'property', 'mean', 'range', 'n', 'age'].map((t) => h('th', {}, t)))),
    h('tbody', {}, rows.map((e) => h('tr', { dataset: { vehicle: e.vehicle_id, property: e.property } },
      h('td', {}, e.vehicle_id),
      h('td', {}, e.property),
      h('td', { class: 'num' }, `${fmt(e.mean, 2)} ${e.unit}`),
      h('td', { class: 'num' }, `${fmt(e.min, 2)} to ${fmt(e.max, 2)}`),
      h('td', { class: 'num' }, String(e.count)),
      h('td', { class: 'num age' }, ago(e.window_end_ms, now)),
    ))));
}

/** The fleet panel's "Other sites" section, or null when this station is not federated. */
export function remoteSection() {
  const f = fed();
  if (!f.enabled) return null;
  const now = Date.now();
  const bySite = new Map(f.sites.map((s) => [s.site, { info: s, vehicles: [] }]));
  for (const v of f.vehicles) {
    if (!bySite.has(v.site)) bySite.set(v.site, { info: null, vehicles: [] });
    bySite.get(v.site).vehicles.push(v);
  }
  const sites = [...bySite.entries()].sort((a, b) => a[0].localeCompare(b[0]));
  const since = now - f.receivedMs;
  const note = stale(now)
    ? h('span', { class: 'pill remote-stale', title: f.error || '' }, `not updated for ${ageText(since)}${f.error ? `: ${f.error}` : ''}`)
    : null;
  return h(
    'section',
    { id: 'remote-fleet', class: `remote-fleet${stale(now) ? ' stale' : ''}` },
    h('h3', {}, 'Other sites ', h('small', { class: 'muted' }, `read-only, via the federation (this site: ${f.site})`), ' ', note),
    sites.length === 0 ? h('p', { class: 'muted' }, 'No remote site configured.') : null,
    sites.map(([site, { info, vehicles }]) => {
      vehicles.sort((a, b) => a.vehicle_id.localeCompare(b.vehicle_id));
      const online = info ? info.online : null;
      const status = online === null ? 'unknown' : online ? 'online' : 'offline';
      return h(
        'div',
        { class: 'remote-site', dataset: { site, online: status } },
        h('h4', {},
          site, ' ',
          h('span', { class: `pill site-${status}`, title: info ? `${status} since ${time(info.since_ms)}` : 'not a configured remote site' }, status),
          info ? h('small', { class: 'muted' }, ` since ${ago(info.since_ms, now)}`) : null,
          h('small', { class: 'muted' }, ` · ${vehicles.length} vehicle(s)`)),
        vehicles.length
          ? h('table', { class: 'grid compact remote' },
            h('thead', {}, h('tr', {}, ['vehicle', 'kind', 'depth m', 'speed m/s', 'battery', 'age'].map((t) => h('th', {}, t)))),
            h('tbody', {}, siteRows(site, vehicles, now)))
          : h('p', { class: 'muted' }, online === false ? 'Offline: nothing heard.' : 'No vehicle position received yet.'),
        remoteTasks(site, f.transitions, now),
        remoteEnvironment(site, f.environment, now),
      );
    }),
    leaseSection(f),
  );
}

/** Hands the lease of `vehicle` to `to` (POST /api/federation/leases/{vehicle}). */
async function handOver(vehicle, to) {
  try {
    const lease = await api('POST', `/api/federation/leases/${encodeURIComponent(vehicle)}`, { to });
    toast(`${vehicle} is now commanded by ${lease.holder} (lease term ${lease.term})`);
    const i = fed().leases.findIndex((l) => l.vehicle_id === vehicle);
    if (i >= 0) fed().leases[i] = lease;
    emit('federation', fed());
  } catch (e) {
    toast(`hand-over of ${vehicle} refused: ${describe(e)}`, 'error');
  }
}

/** Orders another site's vehicle, whose lease this site holds, to `kind` (a task without
 *  parameters) through POST /api/tasks: the station sends it through the vehicle's site. */
async function commandThrough(vehicle, kind) {
  try {
    const sent = await api('POST', '/api/tasks', { vehicle_id: vehicle, task: { kind } });
    toast(`${kind} sent to ${vehicle} through its site (task ${sent.task_id})`);
  } catch (e) {
    toast(`${kind} for ${vehicle} refused: ${describe(e)}`, 'error');
  }
}

/** The site picked to hand each vehicle's lease to: kept across the list's redraws. */
const handTo = new Map();

/** The command leases: who commands each vehicle; a lease held here can be handed over,
 *  and another site's vehicle whose lease is held here can be ordered to surface or abort. */
function leaseSection(f) {
  if (!f.leaseEnabled) return null;
  const leases = [...f.leases].sort((a, b) => a.vehicle_id.localeCompare(b.vehicle_id));
  const others = [f.site, ...f.sites.map((s) => s.site)];
  return h('div', { id: 'leases', class: 'leases' },
    h('h4', {}, 'Command leases ', h('small', { class: 'muted' }, 'one site commands each vehicle')),
    leases.length === 0
      ? h('p', { class: 'muted' }, 'No lease known yet.')
      : h('table', { class: 'grid compact' },
        h('thead', {}, h('tr', {}, ['vehicle', 'commanded by', 'term', 'home', ''].map((t) => h('th', {}, t)))),
        h('tbody', {}, leases.map((l) => {
          const targets = others.filter((s) => s !== l.holder);
          const picked = targets.includes(handTo.get(l.vehicle_id)) ? handTo.get(l.vehicle_id) : targets[0];
          const select = h('select', {
            class: 'lease-to',
            'aria-label': `hand ${l.vehicle_id} to`,
            onchange: (e) => handTo.set(l.vehicle_id, e.target.value),
          }, targets.map((s) => h('option', { value: s, selected: s === picked }, s)));
          const command = (kind, label) => h('button', {
            type: 'button',
            class: `link-button needs-operator command-${kind}`,
            onclick: () => commandThrough(l.vehicle_id, kind),
          }, label);
          const remoteHeld = l.held_here && l.home !== f.site;
          return h('tr', { class: 'lease', dataset: { vehicle: l.vehicle_id, holder: l.holder, held: String(l.held_here) } },
            h('td', {}, h('strong', {}, l.vehicle_id)),
            h('td', {}, l.held_here ? h('span', { class: 'pill site-online' }, `${l.holder} (here)`) : l.holder),
            h('td', { class: 'num' }, String(l.term)),
            h('td', {}, l.home),
            h('td', {}, l.held_here && targets.length
              ? h('span', {}, select, ' ', h('button', {
                type: 'button',
                class: 'link-button needs-operator hand-over',
                onclick: () => handOver(l.vehicle_id, select.value),
              }, 'Hand over'),
              remoteHeld ? h('span', {}, ' · ', command('surface', 'Surface'), ' ', command('abort', 'Abort')) : null)
              : null));
        }))));
}

/** A site's latest tasks under its vehicles, or nothing before the first transition. */
function remoteTasks(site, transitions, now) {
  const tasks = latestTasks(transitions, site);
  if (!tasks.length) return null;
  return h('table', { class: 'grid compact remote remote-tasks' },
    h('thead', {}, h('tr', {}, ['task', 'vehicle', 'state', 'when'].map((t) => h('th', {}, t)))),
    h('tbody', {}, taskRows(site, tasks, now)));
}

/** Remote alarms for the events list: [{site, alarm}], oldest first. */
export function remoteAlarms() {
  return fed().enabled ? fed().alarms : [];
}
