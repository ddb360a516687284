// The live feed: GET /api/ws as a WebSocket. When it drops, the console shows
// "reconnecting", retries with a growing delay, and on reconnect reloads the snapshots so
// nothing missed in between is lost (the same happens on a "lagged" notice).

import { api, describe } from './api.js';
import { removeVessel, renderVessel } from './map.js';
import { emit, putEvent, putMission, putTask, putVehicle, state } from './store.js';
import { toast } from './util.js';

let socket = null;
let retryMs = 500;
let wanted = false;
let retryTimer = null;
let fleetTimer = null;

/** How often the fleet is re-read anyway. The feed carries every vehicle's state and its
 *  contact changes (the station pushes the vehicle when it turns stale or lost, which
 *  happens exactly when it sends nothing); this only catches up on what a dropped message
 *  or an idle socket could miss. */
const FLEET_REFRESH_MS = 10000;

async function refreshFleet() {
  if (!socket || socket.readyState !== WebSocket.OPEN) return;
  try {
    const fleet = await api('GET', '/api/fleet');
    const seen = new Set();
    for (const v of fleet) {
      putVehicle(v);
      seen.add(v.announcement.vehicle_id);
    }
    for (const id of [...state.vehicles.keys()]) if (!seen.has(id)) state.vehicles.delete(id);
    emit('vehicles');
  } catch {
    // The socket's own close handling reports a lost station.
  }
}

function setConn(kind, text) {
  const el = document.getElementById('conn');
  el.dataset.state = kind;
  el.textContent = text;
}

/** Reloads fleet, tasks, missions and events from the REST API. */
export async function resync() {
  const [fleet, tasks, missions, events] = await Promise.all([
    api('GET', '/api/fleet'),
    api('GET', '/api/tasks'),
    api('GET', '/api/missions'),
    api('GET', '/api/events'),
  ]);
  const seen = new Set();
  for (const v of fleet) {
    putVehicle(v);
    seen.add(v.announcement.vehicle_id);
  }
  for (const id of [...state.vehicles.keys()]) if (!seen.has(id)) state.vehicles.delete(id);
  for (const t of tasks) putTask(t);
  for (const m of missions) putMission(m);
  for (const e of events) putEvent(e);
  emit('vehicles');
  emit('tasks');
  emit('missions');
  emit('events');
}

function handle(msg) {
  switch (msg.type) {
    case 'vehicle':
      putVehicle(msg.data);
      emit('vehicles', msg.data.announcement.vehicle_id);
      break;
    case 'task':
      putTask(msg.data);
      emit('tasks', msg.data.assignment.task_id);
      break;
    case 'mission':
      putMission(msg.data);
      emit('missions', msg.data.mission_id);
      emit('tasks');
      break;
    case 'event':
      putEvent(msg.data);
      emit('events', msg.data);
      break;
    case 'observation':
      emit('observation', msg.data);
      break;
    case 'vessel':
      // An AIS target's new report; the traffic poll keeps the summary and catches up.
      renderVessel(msg.data);
      break;
    case 'vessel_gone':
      removeVessel(msg.data.mmsi);
      break;
    case 'lagged':
      // Updates were dropped for this slow client: the snapshots are the truth.
      resync().catch(() => {});
      break;
    default:
      break;
  }
}

function connect() {
  if (!wanted) return;
  const proto = location.protocol === 'https:' ? 'wss:' : 'ws:';
  const ws = new WebSocket(`${proto}//${location.host}/api/ws`);
  socket = ws;
  ws.addEventListener('open', async () => {
    retryMs = 500;
    setConn('live', 'live');
    try {
      await resync();
    } catch (e) {
      toast(describe(e), 'error');
    }
  });
  ws.addEventListener('message', (ev) => {
    try {
      handle(JSON.parse(ev.data));
    } catch (e) {
      console.warn('bad live message', e);
    }
  });
  ws.addEventListener('close', () => closed(ws));
}

/** The socket `ws` is gone: show it and retry with a growing delay. */
function closed(ws) {
  if (socket !== ws) return;
  socket = null;
  if (!wanted) return;
  setConn('reconnecting', `reconnecting in ${Math.round(retryMs / 100) / 10} s…`);
  // A handshake refused for want of a login looks like any drop: asking the API tells
  // them apart (a 401 brings up the login form, which stops the retries).
  api('GET', '/api/auth/session')
    .then((s) => {
      if (s.enabled && !s.user) return api('GET', '/api/fleet');
      return null;
    })
    .catch(() => {});
  retryTimer = setTimeout(connect, retryMs);
  retryMs = Math.min(retryMs * 2, 5000);
}

/** Opens the live feed (again); safe to call when already open. */
export function startLive() {
  wanted = true;
  clearInterval(fleetTimer);
  fleetTimer = setInterval(refreshFleet, FLEET_REFRESH_MS);
  if (!socket) {
    clearTimeout(retryTimer);
    setConn('connecting', 'connecting…');
    connect();
  }
}

/** Closes the live feed (on logout). */
export function stopLive() {
  wanted = false;
  clearInterval(fleetTimer);
  clearTimeout(retryTimer);
  if (socket) {
    const s = socket;
    socket = null;
    s.close();
  }
  setConn('offline', 'offline');
}

/** Closes the socket as a network drop would, leaving the retries on (used by the tests).
 *  Offline, the closing handshake cannot finish and the close event may come late, so the
 *  drop is handled at once; the late event then finds the socket already replaced. */
export function dropLive() {
  const ws = socket;
  if (!ws) return;
  ws.close(4000, 'dropped');
  closed(ws);
}
