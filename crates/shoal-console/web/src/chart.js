// A time-series line chart in plain SVG: no charting library, nothing fetched.

import { time } from './util.js';

const NS = 'http://www.w3.org/2000/svg';

function el(tag, attrs, text) {
  const e = document.createElementNS(NS, tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  if (text !== undefined) e.textContent = text;
  return e;
}

/** Rounded tick values covering [lo, hi]. */
function ticks(lo, hi, n) {
  const span = hi - lo || 1;
  const step0 = span / n;
  const mag = 10 ** Math.floor(Math.log10(step0));
  const step = [1, 2, 5, 10].map((m) => m * mag).find((s) => s >= step0);
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + 1e-9; v += step) out.push(Math.round(v / step) * step);
  return out;
}

/**
 * Draws points [{t, y}] as a line: `opts` {title, unit, invert (depth grows downwards),
 * min, max, colour}. Returns an <svg> element.
 */
export function lineChart(points, opts) {
  const W = 560;
  const H = 180;
  const m = { l: 48, r: 12, t: 22, b: 26 };
  const svg = el('svg', { viewBox: `0 0 ${W} ${H}`, class: 'chart', role: 'img', 'aria-label': opts.title });
  svg.append(el('text', { x: m.l, y: 14, class: 'chart-title' }, `${opts.title} (${opts.unit})`));
  if (points.length < 2) {
    svg.append(el('text', { x: W / 2, y: H / 2, 'text-anchor': 'middle', class: 'chart-empty' }, 'not enough data in this window'));
    return svg;
  }
  const t0 = points[0].t;
  const t1 = points[points.length - 1].t;
  let lo = opts.min ?? Math.min(...points.map((p) => p.y));
  let hi = opts.max ?? Math.max(...points.map((p) => p.y));
  if (hi - lo < 1e-6) {
    // A flat series still needs a span; never below a given minimum (no negative depth).
    if (opts.min !== undefined) hi = lo + 1;
    else {
      lo -= 1;
      hi += 1;
    }
  }
  const x = (t) => m.l + ((t - t0) / (t1 - t0 || 1)) * (W - m.l - m.r);
  const yRaw = (v) => (v - lo) / (hi - lo);
  const y = (v) => (opts.invert ? m.t + yRaw(v) * (H - m.t - m.b) : H - m.b - yRaw(v) * (H - m.t - m.b));
  for (const v of ticks(lo, hi, 4)) {
    svg.append(el('line', { x1: m.l, x2: W - m.r, y1: y(v), y2: y(v), class: 'grid-line' }));
    svg.append(el('text', { x: m.l - 4, y: y(v) + 4, 'text-anchor': 'end', class: 'tick' }, String(v)));
  }
  for (const [t, anchor] of [[t0, 'start'], [(t0 + t1) / 2, 'middle'], [t1, 'end']]) {
    svg.append(el('text', { x: x(t), y: H - 8, 'text-anchor': anchor, class: 'tick' }, time(t)));
  }
  const d = points.map((p, i) => `${i ? 'L' : 'M'}${x(p.t).toFixed(1)},${y(p.y).toFixed(1)}`).join('');
  svg.append(el('path', { d, class: 'series', stroke: opts.colour || '#1b5fd1' }));
  const last = points[points.length - 1];
  svg.append(el('circle', { cx: x(last.t), cy: y(last.y), r: 3, fill: opts.colour || '#1b5fd1' }));
  return svg;
}
