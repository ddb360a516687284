// The map: an offline vector chart (coastline and operating area shipped in the bundle, no
// tiles), vehicles with their heading, trails, task waypoints and survey polygons, the
// station's out-of-area rule polygons, the mission editor's drawing and the replay.

import 'ol/ol.css';
import Map from 'ol/Map.js';
import View from 'ol/View.js';
import Feature from 'ol/Feature.js';
import VectorLayer from 'ol/layer/Vector.js';
import VectorSource from 'ol/source/Vector.js';
import GeoJSON from 'ol/format/GeoJSON.js';
import Point from 'ol/geom/Point.js';
import LineString from 'ol/geom/LineString.js';
import Polygon from 'ol/geom/Polygon.js';
import Draw from 'ol/interaction/Draw.js';
import Modify from 'ol/interaction/Modify.js';
import { fromLonLat, toLonLat } from 'ol/proj.js';
import { Circle as CircleStyle, Fill, Icon, Stroke, Style, Text } from 'ol/style.js';
import { defaults as defaultControls, MousePosition, ScaleLine } from 'ol/control.js';
import { createStringXY } from 'ol/coordinate.js';

import coastlineText from './data/coastline.geojson?raw';
import areaText from './data/operating-area.geojson?raw';
import { emit, FINAL, on, state } from './store.js';

const geojson = new GeoJSON({ featureProjection: 'EPSG:3857' });

export const sources = {
  land: new VectorSource({ features: geojson.readFeatures(JSON.parse(coastlineText)) }),
  area: new VectorSource({ features: geojson.readFeatures(JSON.parse(areaText)) }),
  ruleAreas: new VectorSource(),
  tasks: new VectorSource(),
  trails: new VectorSource(),
  vehicles: new VectorSource(),
  draft: new VectorSource(),
  replay: new VectorSource(),
  traffic: new VectorSource(),
  remote: new VectorSource(),
  acoustic: new VectorSource(),
};

const CONTACT_COLOUR = { alive: '#0b6e4f', stale: '#d98200', lost: '#c0262d', silent: '#777' };
const TASK_COLOUR = {
  pending: '#7a7a7a',
  sent: '#5577aa',
  accepted: '#2f6fd0',
  running: '#1b5fd1',
  done: '#1f8a3c',
  failed: '#c0262d',
  expired: '#c0262d',
  aborted: '#555',
};
const TRAIL_COLOURS = ['#1b5fd1', '#8a3ffc', '#007d79', '#b28600', '#d12771', '#198038', '#6929c4', '#ba4e00'];

/** A stable colour per vehicle, for its trail and replay track. */
export function vehicleColour(id) {
  let h = 0;
  for (const c of id) h = (h * 31 + c.charCodeAt(0)) >>> 0;
  return TRAIL_COLOURS[h % TRAIL_COLOURS.length];
}

/** Icon per kind, pointing up (north); rotated by the vehicle's yaw. */
function glyph(kind, colour, selected) {
  const stroke = selected ? '#ffd400' : '#fff';
  const sw = selected ? 3 : 1.5;
  const shapes = {
    auv: '<path d="M16 2 C20 8 20 24 18 28 L14 28 C12 24 12 8 16 2 Z"/><path d="M12 26 L20 26 L21 30 L11 30 Z"/>',
    glider: '<path d="M16 2 C19 8 19 24 17 29 L15 29 C13 24 13 8 16 2 Z"/><path d="M4 16 L28 16 L28 18 L4 18 Z"/>',
    usv: '<path d="M16 2 L23 12 L23 29 L9 29 L9 12 Z"/>',
    asv: '<path d="M16 2 L23 12 L23 29 L9 29 L9 12 Z"/>',
    rov: '<path d="M16 3 L25 11 L25 28 L7 28 L7 11 Z"/><circle cx="16" cy="18" r="3" fill="#fff"/>',
  };
  const body = shapes[kind] || shapes.usv;
  const svg = `<svg xmlns="http://www.w3.org/2000/svg" width="32" height="32" viewBox="0 0 32 32"><g fill="${colour}" stroke="${stroke}" stroke-width="${sw}" stroke-linejoin="round">${body}</g></svg>`;
  return `data:image/svg+xml;charset=utf-8,${encodeURIComponent(svg)}`;
}

function vehicleStyle(feature, resolution) {
  const v = feature.get('view');
  const id = v.announcement.vehicle_id;
  const selected = state.selected === id;
  const colour = CONTACT_COLOUR[v.contact] || '#777';
  const yaw = v.latest ? (v.latest.yaw_deg * Math.PI) / 180 : 0;
  const depth = v.latest && v.latest.depth_m > 0.5 ? ` ${v.latest.depth_m.toFixed(0)} m` : '';
  return new Style({
    image: new Icon({ src: glyph(v.announcement.kind, colour, selected), rotation: yaw, rotateWithView: true, scale: selected ? 1.1 : 0.9 }),
    text: new Text({
      text: `${id}${depth}${v.contact === 'alive' ? '' : ` (${v.contact})`}`,
      offsetY: 22,
      font: `${selected ? 'bold ' : ''}12px system-ui, sans-serif`,
      fill: new Fill({ color: '#102030' }),
      stroke: new Stroke({ color: 'rgba(255,255,255,0.9)', width: 3 }),
      // Labels of crowded vehicles would hide each other when zoomed out.
      overflow: resolution < 20,
    }),
    zIndex: selected ? 10 : 5,
  });
}

function trailStyle(feature) {
  return new Style({ stroke: new Stroke({ color: `${vehicleColour(feature.get('vehicle'))}aa`, width: 2 }) });
}

function taskStyle(feature) {
  const st = feature.get('state');
  const colour = TASK_COLOUR[st] || '#555';
  const geom = feature.getGeometry().getType();
  if (geom === 'Polygon') {
    return new Style({
      stroke: new Stroke({ color: colour, width: 2 }),
      fill: new Fill({ color: `${colour}22` }),
      text: new Text({ text: feature.get('label'), font: '12px system-ui', fill: new Fill({ color: colour }), overflow: true }),
    });
  }
  if (geom === 'LineString') {
    return new Style({ stroke: new Stroke({ color: colour, width: 1.5, lineDash: [6, 4] }) });
  }
  return new Style({
    image: new CircleStyle({ radius: 6, fill: new Fill({ color: '#fff' }), stroke: new Stroke({ color: colour, width: 3 }) }),
    text: new Text({
      text: feature.get('label'),
      offsetY: -14,
      font: '11px system-ui',
      fill: new Fill({ color: colour }),
      stroke: new Stroke({ color: '#fff', width: 3 }),
    }),
  });
}

const draftStyle = [
  new Style({
    stroke: new Stroke({ color: '#ff6a00', width: 2, lineDash: [4, 4] }),
    fill: new Fill({ color: 'rgba(255,106,0,0.12)' }),
    image: new CircleStyle({ radius: 6, fill: new Fill({ color: '#ff6a00' }), stroke: new Stroke({ color: '#fff', width: 2 }) }),
  }),
];

function replayStyle(feature) {
  const colour = vehicleColour(feature.get('vehicle'));
  if (feature.getGeometry().getType() === 'LineString') {
    return new Style({ stroke: new Stroke({ color: colour, width: 3 }) });
  }
  return new Style({
    image: new Icon({ src: glyph(feature.get('kind'), colour, true), rotation: feature.get('yaw') || 0, rotateWithView: true }),
    text: new Text({ text: feature.get('label'), offsetY: 22, font: 'bold 12px system-ui', stroke: new Stroke({ color: '#fff', width: 3 }) }),
  });
}

/** A vessel from AIS: an outlined hull pointing along its course, grey once its reports are old. */
function vesselGlyph(colour) {
  const svg = `<svg xmlns="http://www.w3.org/2000/svg" width="24" height="24" viewBox="0 0 24 24"><path d="M12 1 L18 21 L12 17 L6 21 Z" fill="${colour}" fill-opacity="0.35" stroke="${colour}" stroke-width="2" stroke-linejoin="round"/></svg>`;
  return `data:image/svg+xml;charset=utf-8,${encodeURIComponent(svg)}`;
}

/** Seconds after which a vessel is drawn as stale (AIS class A reports every 2-10 s). */
const VESSEL_STALE_S = 180;

function vesselStyle(feature, resolution) {
  const t = feature.get('target');
  const stale = (t.position_age_s ?? t.age_s) > VESSEL_STALE_S;
  const colour = stale ? '#8a8a8a' : '#6b2fa3';
  const course = ((t.cog_deg ?? t.heading_deg ?? 0) * Math.PI) / 180;
  const speed = t.sog_kn != null ? ` ${t.sog_kn.toFixed(1)} kn` : '';
  return new Style({
    image: new Icon({ src: vesselGlyph(colour), rotation: course, rotateWithView: true }),
    text: new Text({
      text: `${t.name || t.mmsi}${speed}`,
      offsetY: 18,
      font: '11px system-ui, sans-serif',
      fill: new Fill({ color: colour }),
      stroke: new Stroke({ color: 'rgba(255,255,255,0.9)', width: 3 }),
      overflow: resolution < 20,
    }),
    zIndex: 3,
  });
}

/** Draws or moves one AIS target (from `GET /api/traffic` or the live feed); one without
 *  a position is left out. Returns its feature id, or null. */
export function renderVessel(t) {
  if (t.lat == null || t.lon == null) return null;
  const id = `ais-${t.mmsi}`;
  let f = sources.traffic.getFeatureById(id);
  if (!f) {
    f = new Feature();
    f.setId(id);
    sources.traffic.addFeature(f);
  }
  f.setGeometry(new Point(fromLonLat([t.lon, t.lat])));
  f.set('target', t);
  return id;
}

/** Removes an AIS target whose reports stopped. */
export function removeVessel(mmsi) {
  const f = sources.traffic.getFeatureById(`ais-${mmsi}`);
  if (f) sources.traffic.removeFeature(f);
}

/** Draws the AIS targets of `GET /api/traffic` (those with a position), removing others. */
export function renderTraffic(targets) {
  const seen = new Set(targets.map(renderVessel).filter((id) => id !== null));
  for (const f of sources.traffic.getFeatures()) if (!seen.has(f.getId())) sources.traffic.removeFeature(f);
}

/** A vehicle of another site: the kind's outline, hollow, in a dashed ring, so it can
 *  never be mistaken for one of this station's own (filled, coloured by contact). */
function remoteGlyph(kind, colour, selected) {
  const shapes = {
    auv: '<path d="M16 2 C20 8 20 24 18 28 L14 28 C12 24 12 8 16 2 Z"/>',
    glider: '<path d="M16 2 C19 8 19 24 17 29 L15 29 C13 24 13 8 16 2 Z"/><path d="M4 16 L28 16"/>',
    usv: '<path d="M16 2 L23 12 L23 29 L9 29 L9 12 Z"/>',
    asv: '<path d="M16 2 L23 12 L23 29 L9 29 L9 12 Z"/>',
    rov: '<path d="M16 3 L25 11 L25 28 L7 28 L7 11 Z"/>',
  };
  // A dashed ring makes even a slender hull (an AUV's) stand out as "not ours" at a glance.
  const ring = `<circle cx="16" cy="16" r="14" fill="#ffffff" fill-opacity="0.45" stroke="${selected ? '#ffd400' : colour}" stroke-width="${selected ? 3 : 1.5}" stroke-dasharray="4 3"/>`;
  const svg = `<svg xmlns="http://www.w3.org/2000/svg" width="32" height="32" viewBox="0 0 32 32">${ring}<g fill="none" stroke="${colour}" stroke-width="1.8" stroke-linejoin="round">${shapes[kind] || shapes.usv}</g></svg>`;
  return `data:image/svg+xml;charset=utf-8,${encodeURIComponent(svg)}`;
}

const REMOTE_COLOUR = '#4a5868';

/** Remote positions cross at a low rate (0.2 Hz by default): only a fix missing for several
 *  periods is worth fading, and one minutes old is a guess at where the vehicle is. */
export const REMOTE_OLD_MS = 30_000;
export const REMOTE_VERY_OLD_MS = 300_000;

function remoteStyle(feature, resolution) {
  const v = feature.get('remote');
  const age = feature.get('age_ms');
  const selected = feature.get('selected');
  const opacity = age > REMOTE_VERY_OLD_MS ? 0.35 : age > REMOTE_OLD_MS ? 0.6 : 1;
  const old = age > REMOTE_OLD_MS ? ` (${Math.round(age / 60000) || '<1'} min old)` : '';
  return new Style({
    image: new Icon({
      src: remoteGlyph(v.kind, REMOTE_COLOUR, selected),
      rotation: (v.heading_deg * Math.PI) / 180,
      rotateWithView: true,
      opacity,
    }),
    text: new Text({
      text: `${feature.get('label')}${old}`,
      offsetY: 22,
      font: `italic ${selected ? 'bold ' : ''}12px system-ui, sans-serif`,
      fill: new Fill({ color: `rgba(74,88,104,${opacity})` }),
      stroke: new Stroke({ color: 'rgba(255,255,255,0.85)', width: 3 }),
      overflow: resolution < 20,
    }),
    zIndex: selected ? 9 : 4,
  });
}

/** The feature id of a remote vehicle: ids are unique only within their site. */
export const remoteKey = (v) => `${v.site}/${v.vehicle_id}`;

/** Draws the remote sites' vehicles (`GET /api/federation`), removing those gone; `ageOf`
 *  gives each one's age now, `selectedKey` the one the operator picked. */
export function renderRemoteVehicles(vehicles, ageOf, selectedKey) {
  const seen = new Set();
  for (const v of vehicles) {
    const id = remoteKey(v);
    seen.add(id);
    let f = sources.remote.getFeatureById(id);
    const xy = fromLonLat([v.longitude_deg, v.latitude_deg]);
    if (!f) {
      f = new Feature(new Point(xy));
      f.setId(id);
      sources.remote.addFeature(f);
    } else {
      f.getGeometry().setCoordinates(xy);
    }
    f.setProperties({ remote: v, label: `${v.vehicle_id} · ${v.site}`, age_ms: ageOf(v), selected: id === selectedKey });
  }
  for (const f of sources.remote.getFeatures()) if (!seen.has(f.getId())) sources.remote.removeFeature(f);
}

/** The remote vehicle drawn at a pixel, or null. */
export function remoteAtPixel(pixel) {
  return map.forEachFeatureAtPixel(pixel, (f) => f, { layerFilter: (l) => l === layers.remote, hitTolerance: 6 }) || null;
}

/** The acoustic network (acoustic.js styles it and decides when it shows). */
export const acousticLayer = new VectorLayer({ source: sources.acoustic, visible: false });

const layers = {
  land: new VectorLayer({
    source: sources.land,
    style: new Style({ fill: new Fill({ color: '#efe6cf' }), stroke: new Stroke({ color: '#9a8a66', width: 1 }) }),
  }),
  area: new VectorLayer({
    source: sources.area,
    style: new Style({
      stroke: new Stroke({ color: '#0b4f8a', width: 2, lineDash: [10, 6] }),
      text: new Text({ text: 'operating area', placement: 'line', font: '11px system-ui', fill: new Fill({ color: '#0b4f8a' }) }),
    }),
  }),
  ruleAreas: new VectorLayer({
    source: sources.ruleAreas,
    style: (f) =>
      new Style({
        stroke: new Stroke({ color: '#c0262d', width: 1.5, lineDash: [3, 5] }),
        text: new Text({ text: `rule ${f.get('rule')}`, placement: 'line', font: '11px system-ui', fill: new Fill({ color: '#c0262d' }) }),
      }),
  }),
  tasks: new VectorLayer({ source: sources.tasks, style: taskStyle }),
  trails: new VectorLayer({ source: sources.trails, style: trailStyle }),
  // Under the vehicles: a vehicle's modem is drawn at the vehicle, which stays clickable.
  acoustic: acousticLayer,
  traffic: new VectorLayer({ source: sources.traffic, style: vesselStyle }),
  // Under the own fleet: where a remote and an own vehicle overlap, the own one is clicked.
  remote: new VectorLayer({ source: sources.remote, style: remoteStyle }),
  vehicles: new VectorLayer({ source: sources.vehicles, style: vehicleStyle }),
  draft: new VectorLayer({ source: sources.draft, style: draftStyle }),
  replay: new VectorLayer({ source: sources.replay, style: replayStyle, zIndex: 20 }),
};

export let map = null;

/** Builds the map in #map; the view starts over the default fleet off Trondheim. */
export function createMap() {
  map = new Map({
    target: 'map',
    layers: Object.values(layers),
    // The fleet's waters with Trondheim's shore in sight.
    view: new View({ center: fromLonLat([10.375, 63.459]), zoom: 13.4, maxZoom: 20 }),
    controls: defaultControls().extend([
      new ScaleLine({ units: 'nautical' }),
      new ScaleLine({ units: 'metric', className: 'ol-scale-line ol-scale-metric' }),
      new MousePosition({
        projection: 'EPSG:4326',
        coordinateFormat: (c) => `${createStringXY(5)([c[1], c[0]])} (lat, lon)`,
      }),
    ]),
  });
  map.on('singleclick', (evt) => {
    if (drawing) return;
    const hit = map.forEachFeatureAtPixel(evt.pixel, (f) => f, { layerFilter: (l) => l === layers.vehicles, hitTolerance: 6 });
    if (hit) {
      state.selected = hit.getId();
      emit('select', state.selected);
    }
  });
  on('vehicles', renderVehicles);
  on('select', () => layers.vehicles.changed());
  on('tasks', renderTasks);
  on('missions', renderTasks);
  // Test and debugging hook: what is drawn, without reading pixels.
  window.shoalConsole = { map, sources, toLonLat };
  return map;
}

function renderVehicles() {
  for (const [id, v] of state.vehicles) {
    if (!v.latest) continue;
    const xy = fromLonLat([v.latest.longitude_deg, v.latest.latitude_deg]);
    let f = sources.vehicles.getFeatureById(id);
    if (!f) {
      f = new Feature(new Point(xy));
      f.setId(id);
      sources.vehicles.addFeature(f);
    } else {
      f.getGeometry().setCoordinates(xy);
    }
    f.set('view', v);
    const trail = state.trails.get(id) || [];
    let t = sources.trails.getFeatureById(id);
    const coords = trail.map((p) => fromLonLat([p[0], p[1]]));
    if (coords.length >= 2) {
      if (!t) {
        t = new Feature(new LineString(coords));
        t.setId(id);
        t.set('vehicle', id);
        sources.trails.addFeature(t);
      } else {
        t.getGeometry().setCoordinates(coords);
      }
    }
  }
  for (const f of sources.vehicles.getFeatures()) {
    if (!state.vehicles.has(f.getId())) sources.vehicles.removeFeature(f);
  }
}

/** Tasks worth drawing: unfinished ones, and finished ones from the last half hour. */
function renderTasks() {
  const now = Date.now();
  const features = [];
  const legs = new globalThis.Map();
  const tasks = [...state.tasks.values()].sort((a, b) => a.assignment.task_id.localeCompare(b.assignment.task_id, undefined, { numeric: true }));
  for (const t of tasks) {
    const a = t.assignment;
    if (FINAL.has(t.state) && now - t.updated_ms > 30 * 60 * 1000) continue;
    const pts = a.area.map((p) => fromLonLat([p.longitude_deg, p.latitude_deg]));
    const label = `${a.task_id} · ${a.vehicle_id} · ${t.state}${t.state === 'running' ? ` ${Math.round(t.progress_pct)}%` : ''}`;
    if (a.kind === 'survey_area' && pts.length >= 3) {
      const f = new Feature(new Polygon([[...pts, pts[0]]]));
      f.setProperties({ state: t.state, label });
      features.push(f);
    } else if (a.kind === 'goto_waypoint' && pts.length === 1) {
      const f = new Feature(new Point(pts[0]));
      f.setProperties({ state: t.state, label });
      features.push(f);
      const key = `${a.mission_id}/${a.vehicle_id}`;
      if (a.mission_id) legs.set(key, [...(legs.get(key) || []), { xy: pts[0], state: t.state }]);
    }
  }
  // Consecutive waypoints of one vehicle in one mission, joined in order.
  for (const leg of legs.values()) {
    for (let i = 1; i < leg.length; i++) {
      const f = new Feature(new LineString([leg[i - 1].xy, leg[i].xy]));
      f.set('state', leg[i].state);
      features.push(f);
    }
  }
  sources.tasks.clear(true);
  sources.tasks.addFeatures(features);
}

/** Draws the station's out-of-area rule polygons (from GET /api/rules). */
export function showRuleAreas(rules) {
  sources.ruleAreas.clear(true);
  for (const r of rules) {
    if (r.condition.type !== 'outside_area' || !r.enabled) continue;
    const pts = r.condition.polygon.map((p) => fromLonLat([p.longitude_deg, p.latitude_deg]));
    if (pts.length < 3) continue;
    const f = new Feature(new Polygon([[...pts, pts[0]]]));
    f.set('rule', r.id);
    sources.ruleAreas.addFeature(f);
  }
}

export function centerOn(lon, lat) {
  map.getView().animate({ center: fromLonLat([lon, lat]), duration: 300 });
}

let drawing = null;
let modify = null;

/**
 * Lets the operator click waypoints ('Point', each click one more) or draw a polygon
 * ('Polygon', double-click closes). `changed(points)` gets [{latitude_deg, longitude_deg}].
 */
export function startDrawing(type, changed) {
  stopDrawing();
  sources.draft.clear();
  drawing = new Draw({ source: sources.draft, type });
  modify = new Modify({ source: sources.draft });
  const report = () => changed(draftPoints());
  drawing.on('drawend', () => setTimeout(() => {
    report();
    // One polygon per survey: drawing stops once it is closed; corners can still be moved.
    if (type === 'Polygon') {
      map.removeInteraction(drawing);
      drawing = null;
    }
  }));
  modify.on('modifyend', report);
  map.addInteraction(drawing);
  map.addInteraction(modify);
}

export function stopDrawing() {
  if (drawing) map.removeInteraction(drawing);
  if (modify) map.removeInteraction(modify);
  drawing = null;
  modify = null;
}

export function clearDraft() {
  sources.draft.clear();
}

/** The drafted points, in order: waypoints, or the polygon's corners. */
export function draftPoints() {
  const out = [];
  for (const f of sources.draft.getFeatures()) {
    const g = f.getGeometry();
    const coords = g.getType() === 'Polygon' ? g.getCoordinates()[0].slice(0, -1) : [g.getCoordinates()];
    for (const c of coords) {
      const [lon, lat] = toLonLat(c);
      out.push({ latitude_deg: Math.round(lat * 1e7) / 1e7, longitude_deg: Math.round(lon * 1e7) / 1e7 });
    }
  }
  return out;
}

/** Puts points on the draft layer (the editor's list edited by hand, or a mission re-used). */
export function setDraft(type, points) {
  sources.draft.clear();
  const xy = points.map((p) => fromLonLat([p.longitude_deg, p.latitude_deg]));
  if (type === 'Polygon' && xy.length >= 3) sources.draft.addFeature(new Feature(new Polygon([[...xy, xy[0]]])));
  else for (const c of xy) sources.draft.addFeature(new Feature(new Point(c)));
}

/** Shows or hides the live vehicles and trails (the replay dims them). */
export function setLiveVisible(visible) {
  layers.vehicles.setOpacity(visible ? 1 : 0.25);
  layers.remote.setOpacity(visible ? 1 : 0.25);
  layers.trails.setVisible(visible);
}

export { Feature, Point, LineString, fromLonLat };
