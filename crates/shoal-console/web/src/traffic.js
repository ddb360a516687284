// Vessel traffic from AIS: the live feed moves each vessel as its reports come (live.js);
// this polls GET /api/traffic for the traffic summary (count, inputs' dropped lines) and
// to catch up on what a dropped message or a reconnection missed.

import { api, describe } from './api.js';
import { renderTraffic } from './map.js';

/** Seconds between polls while traffic inputs are configured, and while they are not. */
const POLL_S = 10;
const IDLE_POLL_S = 30;

/** The counters of lines the inputs refused, one per reason (see docs/traffic.md). */
const DROPPED = [
  'too_long', 'garbage', 'no_checksum', 'bad_checksum', 'unsupported_sentence',
  'unsupported_ais_type', 'bad_fields', 'bad_payload', 'bad_mmsi', 'no_fix',
  'fragment_out_of_order', 'fragment_missing', 'fragment_over_limit', 'decoder_panics',
];

let timer = null;

function summary(doc) {
  const el = document.getElementById('traffic-summary');
  if (!el) return;
  if (!doc.enabled) {
    el.textContent = '';
    el.hidden = true;
    return;
  }
  const s = doc.stats || {};
  const dropped = DROPPED.reduce((n, k) => n + (s[k] || 0), 0);
  el.hidden = false;
  el.textContent = `AIS: ${doc.targets.length} vessel(s)${dropped > 0 ? `, ${dropped} line(s) dropped` : ''}`;
  el.title = `lines read ${s.lines || 0}, accepted ${s.accepted || 0}, AIS messages ${s.ais_messages || 0}; dropped: ${
    DROPPED.filter((k) => s[k]).map((k) => `${k} ${s[k]}`).join(', ') || 'none'}`;
}

async function poll() {
  let next = POLL_S;
  try {
    const doc = await api('GET', '/api/traffic');
    renderTraffic(doc.targets);
    summary(doc);
    if (!doc.enabled) next = IDLE_POLL_S;
  } catch (e) {
    // Logged out or station gone: the session and live-feed code tell the operator.
    if (e.status !== 401) console.warn(`traffic: ${describe(e)}`);
  }
  timer = setTimeout(poll, next * 1000);
}

/** Starts polling (once; later calls do nothing). */
export function startTraffic() {
  if (timer === null) poll();
}
