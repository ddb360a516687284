// The console's picture of the station, fed by REST snapshots and the live WebSocket; views
// subscribe to the kinds of change they show.

export const state = {
  /** vehicle_id -> VehicleView */
  vehicles: new Map(),
  /** task_id -> TaskView */
  tasks: new Map(),
  /** mission_id -> MissionView */
  missions: new Map(),
  /** event_id -> EventView */
  events: new Map(),
  /** Recent positions per vehicle for the trails: vehicle_id -> [[lon, lat, t], ...] */
  trails: new Map(),
  /** { enabled, user, role } from /api/auth/session */
  session: { enabled: false, user: null, role: 'admin' },
  selected: null,
  /** Other sites' picture from GET /api/federation (federation.js); `enabled` is null
   *  until the station first answered, `error` set while the last poll failed. */
  federation: { enabled: null, site: '', sites: [], vehicles: [], alarms: [], transitions: [], environment: [], leases: [], leaseEnabled: false, receivedMs: 0, error: null },
  /** `site/vehicle_id` of the remote vehicle picked on the map or in the list: kept apart
   *  from `selected`, which the command views act on. */
  remoteSelected: null,
};

/** Longest trail kept per vehicle (points, about ten minutes at 1 Hz). */
export const TRAIL_POINTS = 600;

const bus = new EventTarget();

/** Subscribes to a change: 'vehicles', 'tasks', 'missions', 'events', 'select', 'session',
 *  'federation'. */
export function on(kind, fn) {
  bus.addEventListener(kind, (e) => fn(e.detail));
}

export function emit(kind, detail) {
  bus.dispatchEvent(new CustomEvent(kind, { detail }));
}

export function putVehicle(v) {
  const id = v.announcement.vehicle_id;
  state.vehicles.set(id, v);
  const s = v.latest;
  if (s) {
    const trail = state.trails.get(id) || [];
    const last = trail[trail.length - 1];
    if (!last || last[2] < s.timestamp_ms) {
      trail.push([s.longitude_deg, s.latitude_deg, s.timestamp_ms]);
      if (trail.length > TRAIL_POINTS) trail.splice(0, trail.length - TRAIL_POINTS);
      state.trails.set(id, trail);
    }
  }
}

export function putTask(t) {
  state.tasks.set(t.assignment.task_id, t);
}

export function putMission(m) {
  state.missions.set(m.mission_id, m);
  for (const t of m.tasks) putTask(t);
}

export function putEvent(e) {
  state.events.set(e.event_id, e);
}

/** The task a vehicle is working on now (not final), or its latest one. */
export function currentTask(vehicleId) {
  let best = null;
  for (const t of state.tasks.values()) {
    if (t.assignment.vehicle_id !== vehicleId) continue;
    const active = !FINAL.has(t.state);
    const score = [active ? 1 : 0, t.updated_ms];
    if (!best || score[0] > best.score[0] || (score[0] === best.score[0] && score[1] > best.score[1])) {
      best = { t, score };
    }
  }
  return best ? best.t : null;
}

export const FINAL = new Set(['done', 'failed', 'aborted', 'expired']);

/** True when the logged-in role may do what `need` requires ('viewer' | 'operator' | 'admin'). */
export function may(need) {
  const rank = { viewer: 0, operator: 1, admin: 2 };
  return rank[state.session.role] >= rank[need];
}
