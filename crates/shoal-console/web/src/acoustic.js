// The acoustic network on the map, as Neptus shows it: the relay's modem (on its carrier
// USV when it rides one), each acoustic vehicle's modem, a line per link coloured by its
// quality (grey and dashed once the CDT has not heard the vehicle for a while), the
// channel model's range rings around the relay, and a pulse running up the line for the
// frames the relay heard. Link status comes with the live feed's vehicle views; the rings
// (and the station's clock) from GET /api/acoustic.

import { circular } from 'ol/geom/Polygon.js';
import { Circle as CircleStyle, Fill, Stroke, Style, Text } from 'ol/style.js';
import { api, describe } from './api.js';
import { acousticLayer, Feature, fromLonLat, LineString, map, Point, sources } from './map.js';
import { on, state } from './store.js';

const POLL_S = 5;
/** A link is shown as lost after 3 link-status intervals, never sooner than this. */
const MIN_STALE_MS = 30_000;
/** One pulse's trip along the line, and the least time between two on one link: a burst of
 *  frames must not turn into a blur (nor a busy loop). */
const PULSE_MS = 1200;
const PULSE_GAP_MS = 600;
/** Pulses waiting per link at most; a bigger jump in the frame count is shown as this many. */
const MAX_QUEUED = 4;

const RING_COLOUR = '#0b4f8a';
const QUALITY_COLOUR = { good: '#1f8a3c', fair: '#d98200', poor: '#c0262d', lost: '#8a8a8a' };

let doc = null;
/** Station clock minus the browser's, from the last answer: ages are the station's. */
let clockOffsetMs = 0;
/** null until the operator ticks or unticks the layer: until then it shows when there is
 *  an acoustic vehicle. */
let chosen = null;
let toggle = null;
let tip = null;
const lastFrames = new Map();
/** vehicle -> { queued, lastStart, launched } */
const pulseState = new Map();
const pulses = new Set();
let pulseNo = 0;
let animating = false;

const stationNow = () => Date.now() + clockOffsetMs;

/** Every acoustic link known: the live feed's status when newer than the last poll's. */
function links() {
  const byId = new Map();
  for (const l of doc ? doc.links : []) byId.set(l.vehicle_id, l);
  for (const v of state.vehicles.values()) {
    const ls = v.link_status;
    if (!ls || ls.link !== 'acoustic') continue;
    const known = byId.get(ls.vehicle_id);
    if (!known || ls.heard_ms >= known.heard_ms) byId.set(ls.vehicle_id, { ...known, ...ls });
  }
  return [...byId.values()].sort((a, b) => a.vehicle_id.localeCompare(b.vehicle_id));
}

function livePosition(id) {
  const v = state.vehicles.get(id);
  return v && v.latest ? [v.latest.longitude_deg, v.latest.latitude_deg] : null;
}

/** Where the relay's modem is: on its carrier as the live feed has it, else what the
 *  station or the CDT said. */
function relayLonLat(l) {
  const carried = l.cdt_vehicle ? livePosition(l.cdt_vehicle) : null;
  if (carried) return { at: carried, carrier: l.cdt_vehicle };
  if (l.relay_position) return { at: [l.relay_position.longitude_deg, l.relay_position.latitude_deg], carrier: l.relay_position.from === 'carrier' ? l.cdt_vehicle : null };
  if (l.cdt_latitude_deg != null && l.cdt_longitude_deg != null) return { at: [l.cdt_longitude_deg, l.cdt_latitude_deg], carrier: null };
  return null;
}

function quality(l, stale) {
  if (stale) return 'lost';
  if (l.integrity != null) return l.integrity >= 150 ? 'good' : l.integrity >= 80 ? 'fair' : 'poor';
  if (l.rssi_db != null) return l.rssi_db >= -70 ? 'good' : l.rssi_db >= -85 ? 'fair' : 'poor';
  return 'fair';
}

function upsert(id, geometry, props) {
  let f = sources.acoustic.getFeatureById(id);
  if (!f) {
    f = new Feature(geometry);
    f.setId(id);
    f.setProperties(props);
    sources.acoustic.addFeature(f);
  } else {
    f.setGeometry(geometry);
    f.setProperties(props);
  }
  return f;
}

const km = (m) => (m >= 1000 ? `${(m / 1000).toFixed(1)} km` : `${Math.round(m)} m`);

function render() {
  const all = links();
  if (chosen === null) setVisible(all.length > 0, false);
  const seen = new Set();
  const relays = new Map();
  const now = stationNow();
  for (const l of all) {
    const key = `${l.participant}/${l.cdt_address}`;
    const relay = relayLonLat(l);
    if (relay && !relays.has(key)) relays.set(key, { ...relay, address: l.cdt_address, id: relays.size === 0 ? 'relay' : `relay:${key}` });
    const vehicleAt = livePosition(l.vehicle_id) || (l.position ? [l.position.longitude_deg, l.position.latitude_deg] : null);
    if (vehicleAt) {
      seen.add(`modem:${l.vehicle_id}`);
      upsert(`modem:${l.vehicle_id}`, new Point(fromLonLat(vehicleAt)), { kind: 'modem', vehicle: l.vehicle_id, address: l.vehicle_address });
    }
    const r = relays.get(key);
    if (!vehicleAt || !r) continue;
    const ageMs = Math.max(0, now - l.heard_ms);
    const staleMs = Math.max(MIN_STALE_MS, 3 * (l.interval_s || 0) * 1000);
    const stale = ageMs > staleMs;
    const id = `link:${l.vehicle_id}`;
    seen.add(id);
    const f = upsert(id, new LineString([fromLonLat(r.at), fromLonLat(vehicleAt)]), {
      kind: 'link', vehicle: l.vehicle_id, rssi_db: l.rssi_db ?? null, integrity: l.integrity ?? null,
      frames: l.frames ?? null, heard_ms: l.heard_ms, age_ms: ageMs, stale, quality: quality(l, stale),
      vehicle_address: l.vehicle_address, cdt_address: l.cdt_address,
    });
    notePulses(l, f);
  }
  for (const r of relays.values()) {
    seen.add(r.id);
    upsert(r.id, new Point(fromLonLat(r.at)), { kind: 'relay', address: r.address, carrier: r.carrier || null });
    for (const ring of doc ? doc.rings : []) {
      const id = r.id === 'relay' ? `ring:${ring.per}` : `ring:${ring.per}:${r.id}`;
      seen.add(id);
      const g = circular(r.at, ring.range_m, 96).transform('EPSG:4326', 'EPSG:3857');
      upsert(id, g, { kind: 'ring', per: ring.per, range_m: ring.range_m, label: `PER ${Math.round(ring.per * 100)} % · ${km(ring.range_m)}` });
    }
  }
  for (const f of sources.acoustic.getFeatures()) {
    if (f.get('kind') !== 'pulse' && !seen.has(f.getId())) sources.acoustic.removeFeature(f);
  }
}

/** Queues a pulse for each rise of a link's frame counter (a few at most). */
function notePulses(l, f) {
  const p = pulseState.get(l.vehicle_id) || { queued: 0, lastStart: 0, launched: 0 };
  pulseState.set(l.vehicle_id, p);
  const before = lastFrames.get(l.vehicle_id);
  if (l.frames != null) {
    if (before != null && l.frames > before) p.queued = Math.min(MAX_QUEUED, p.queued + (l.frames - before));
    lastFrames.set(l.vehicle_id, l.frames);
  }
  f.set('pulses', p.launched);
  if (p.queued > 0) animate();
}

function animate() {
  if (animating) return;
  animating = true;
  requestAnimationFrame(step);
}

function step() {
  const t = performance.now();
  for (const [vehicle, p] of pulseState) {
    if (p.queued > 0 && t - p.lastStart >= PULSE_GAP_MS && acousticLayer.getVisible()) {
      const line = sources.acoustic.getFeatureById(`link:${vehicle}`);
      if (!line) continue;
      p.queued -= 1;
      p.lastStart = t;
      p.launched += 1;
      line.set('pulses', p.launched);
      const f = new Feature(new Point(line.getGeometry().getLastCoordinate()));
      f.setId(`pulse:${vehicle}:${++pulseNo}`);
      f.setProperties({ kind: 'pulse', vehicle, start: t });
      sources.acoustic.addFeature(f);
      pulses.add(f);
    }
  }
  for (const f of pulses) {
    const line = sources.acoustic.getFeatureById(`link:${f.get('vehicle')}`);
    const done = (t - f.get('start')) / PULSE_MS;
    if (!line || done >= 1) {
      pulses.delete(f);
      sources.acoustic.removeFeature(f);
      continue;
    }
    // Up the line: the vehicle's frame travels to the relay's modem.
    f.getGeometry().setCoordinates(line.getGeometry().getCoordinateAt(1 - done));
  }
  const waiting = [...pulseState.values()].some((p) => p.queued > 0) && acousticLayer.getVisible();
  if (pulses.size > 0 || waiting) requestAnimationFrame(step);
  else animating = false;
}

function style(f, resolution) {
  switch (f.get('kind')) {
    case 'link': {
      const colour = QUALITY_COLOUR[f.get('quality')];
      return new Style({ stroke: new Stroke({ color: colour, width: f.get('stale') ? 2 : 3, lineDash: f.get('stale') ? [8, 6] : undefined }), zIndex: 2 });
    }
    case 'ring':
      return new Style({
        stroke: new Stroke({ color: `${RING_COLOUR}99`, width: 1.2, lineDash: [2, 5] }),
        // The label sits on the ring's northern edge, where the rings never overlap.
        text: new Text({ text: f.get('label'), font: '11px system-ui, sans-serif', fill: new Fill({ color: RING_COLOUR }), stroke: new Stroke({ color: 'rgba(255,255,255,0.9)', width: 3 }), overflow: true }),
        geometry: (g) => {
          const ext = g.getGeometry().getExtent();
          return new Point([(ext[0] + ext[2]) / 2, ext[3]]);
        },
      });
    case 'relay':
      return new Style({
        image: new CircleStyle({ radius: 7, fill: new Fill({ color: '#0b4f8a' }), stroke: new Stroke({ color: '#fff', width: 2 }) }),
        text: new Text({ text: `relay modem ${f.get('address')}`, offsetY: -14, font: '11px system-ui, sans-serif', fill: new Fill({ color: '#0b4f8a' }), stroke: new Stroke({ color: '#fff', width: 3 }), overflow: resolution < 20 }),
        zIndex: 3,
      });
    case 'modem':
      return new Style({ image: new CircleStyle({ radius: 4, fill: new Fill({ color: '#fff' }), stroke: new Stroke({ color: '#0b4f8a', width: 2 }) }), zIndex: 3 });
    case 'pulse':
      return new Style({ image: new CircleStyle({ radius: 5, fill: new Fill({ color: '#00b3ff' }), stroke: new Stroke({ color: '#fff', width: 1.5 }) }), zIndex: 4 });
    default:
      return null;
  }
}

function describeFeature(f) {
  const k = f.get('kind');
  if (k === 'link') {
    const parts = [`${f.get('vehicle')} ↔ relay (modem ${f.get('vehicle_address')}↔${f.get('cdt_address')})`];
    parts.push(f.get('rssi_db') != null ? `RSSI ${f.get('rssi_db')} dB` : 'RSSI –');
    if (f.get('integrity') != null) parts.push(`integrity ${f.get('integrity')}`);
    parts.push(`heard ${Math.round(f.get('age_ms') / 1000)} s ago${f.get('stale') ? ' (no contact)' : ''}`);
    if (f.get('frames') != null) parts.push(`${f.get('frames')} frames`);
    return parts.join(' · ');
  }
  if (k === 'relay') return `relay modem ${f.get('address')}${f.get('carrier') ? ` on ${f.get('carrier')}` : ''}`;
  if (k === 'modem') return `${f.get('vehicle')} modem ${f.get('address')}`;
  if (k === 'ring') return `${f.get('label')} for a ${doc.frame_bytes}-byte frame at ${doc.bit_rate_bps} bit/s`;
  return '';
}

const HOVER_ORDER = ['link', 'relay', 'modem', 'ring'];

function hover(evt) {
  if (evt.dragging || !acousticLayer.getVisible()) {
    tip.hidden = true;
    return;
  }
  const hits = map.getFeaturesAtPixel(evt.pixel, { layerFilter: (l) => l === acousticLayer, hitTolerance: 5 });
  const best = hits.filter((f) => HOVER_ORDER.includes(f.get('kind'))).sort((a, b) => HOVER_ORDER.indexOf(a.get('kind')) - HOVER_ORDER.indexOf(b.get('kind')))[0];
  if (!best) {
    tip.hidden = true;
    return;
  }
  tip.textContent = describeFeature(best);
  tip.style.left = `${evt.pixel[0] + 12}px`;
  tip.style.top = `${evt.pixel[1] + 12}px`;
  tip.hidden = false;
}

function setVisible(visible, byOperator) {
  if (byOperator) chosen = visible;
  acousticLayer.setVisible(visible);
  if (toggle) toggle.querySelector('input').checked = visible;
  if (!visible && tip) tip.hidden = true;
}

async function poll() {
  try {
    const sent = Date.now();
    const d = await api('GET', '/api/acoustic');
    clockOffsetMs = d.now_ms - (sent + Date.now()) / 2;
    doc = d;
    render();
  } catch (e) {
    // Logged out or station gone: the session and live-feed code tell the operator.
    if (e.status !== 401) console.warn(`acoustic: ${describe(e)}`);
  }
  setTimeout(poll, POLL_S * 1000);
}

let started = false;

/** Starts polling (once; later calls do nothing). */
export function startAcoustic() {
  if (started) return;
  started = true;
  poll();
}

/** Adds the layer's toggle and hover label to the map (after createMap). */
export function initAcoustic() {
  acousticLayer.setStyle(style);
  const el = document.getElementById('map');
  toggle = document.createElement('label');
  toggle.id = 'acoustic-toggle';
  toggle.className = 'map-toggle';
  toggle.title = 'The acoustic network: relay and vehicle modems, links, range rings (packet error rate), frames';
  toggle.innerHTML = '<input type="checkbox"> Acoustic';
  toggle.querySelector('input').addEventListener('change', (e) => setVisible(e.target.checked, true));
  tip = document.createElement('div');
  tip.id = 'acoustic-tip';
  tip.className = 'map-tip';
  tip.hidden = true;
  el.append(toggle, tip);
  map.on('pointermove', hover);
  on('vehicles', render);
  // Ages move on between updates: a silent link must turn grey by itself.
  setInterval(render, 2000);
}
