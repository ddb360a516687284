// Derives web/src/data/coastline.geojson: Natural Earth's 1:10m land (public domain, via
// the world-atlas npm package's TopoJSON) clipped to the waters off Trondheim where the
// default fleet runs. Run once by hand; the output is committed so builds need neither
// package:
//   npm install --no-save world-atlas@2.0.2 topojson-client@3
//   node tools/coastline.mjs > src/data/coastline.geojson
import { readFileSync } from 'node:fs';
import { createRequire } from 'node:module';
import { feature } from 'topojson-client';

const require = createRequire(import.meta.url);
const topo = JSON.parse(readFileSync(require.resolve('world-atlas/land-10m.json'), 'utf8'));
// lon/lat box: the fjord from Orkanger to Stjørdal, wide enough for any zoom the console uses.
const [W, S, E, N] = [9.6, 63.25, 11.2, 63.75];

// Sutherland–Hodgman against one edge of the box; the box is convex, so four passes clip.
function clipEdge(ring, inside, cut) {
  const out = [];
  for (let i = 0; i < ring.length; i++) {
    const a = ring[i];
    const b = ring[(i + 1) % ring.length];
    if (inside(a)) {
      out.push(a);
      if (!inside(b)) out.push(cut(a, b));
    } else if (inside(b)) {
      out.push(cut(a, b));
    }
  }
  return out;
}
const atX = (x) => (a, b) => [x, a[1] + ((b[1] - a[1]) * (x - a[0])) / (b[0] - a[0])];
const atY = (y) => (a, b) => [a[0] + ((b[0] - a[0]) * (y - a[1])) / (b[1] - a[1]), y];
function clip(ring) {
  let r = ring.slice(0, -1);
  r = clipEdge(r, (p) => p[0] >= W, atX(W));
  r = clipEdge(r, (p) => p[0] <= E, atX(E));
  r = clipEdge(r, (p) => p[1] >= S, atY(S));
  r = clipEdge(r, (p) => p[1] <= N, atY(N));
  if (r.length < 3) return null;
  const round = (p) => [Math.round(p[0] * 1e5) / 1e5, Math.round(p[1] * 1e5) / 1e5];
  const closed = r.map(round);
  closed.push(closed[0]);
  return closed;
}

const land = feature(topo, topo.objects.land);
const polygons = [];
for (const f of land.features) {
  const g = f.geometry;
  const polys = g.type === 'Polygon' ? [g.coordinates] : g.coordinates;
  for (const poly of polys) {
    const rings = poly.map(clip).filter(Boolean);
    if (rings.length && rings[0]) polygons.push(rings);
  }
}
const out = {
  type: 'FeatureCollection',
  features: [
    {
      type: 'Feature',
      properties: {
        name: 'land',
        source: 'Natural Earth 1:10m land (public domain), via world-atlas 2.0.2, clipped',
        bbox: [W, S, E, N],
      },
      geometry: { type: 'MultiPolygon', coordinates: polygons },
    },
  ],
};
process.stdout.write(JSON.stringify(out) + '\n');
