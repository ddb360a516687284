// Environment data: subscribe to observations by property, area and rate
// (POST /api/environment/subscriptions), then watch what a subscription matched, polled and
// pushed live.

import { api, describe } from './api.js';
import { draftPoints } from './map.js';
import { on } from './store.js';
import { dateTime, fieldError, fmt, h, toast } from './util.js';

let root;
let current = null;
let observations = [];
let timer = null;

function renderObservations() {
  const box = root.querySelector('#env-observations');
  if (!current) {
    box.replaceChildren(h('p', { class: 'muted' }, 'Choose a subscription to see its observations.'));
    return;
  }
  const rows = observations.slice(-200).reverse();
  box.replaceChildren(
    h('p', { class: 'summary', id: 'env-count' }, `${observations.length} observation(s) for ${current}`),
    h('table', { class: 'grid compact', id: 'env-table' },
      h('thead', {}, h('tr', {}, ['time', 'vehicle', 'property', 'value', 'lat', 'lon', 'depth m'].map((t) => h('th', {}, t)))),
      h('tbody', {}, rows.map((o) => h('tr', {},
        h('td', {}, dateTime(o.timestamp_ms)),
        h('td', {}, o.vehicle_id),
        h('td', {}, o.property),
        h('td', { class: 'num' }, `${fmt(o.value, 3)} ${o.unit}`),
        h('td', { class: 'num' }, fmt(o.latitude_deg, 5)),
        h('td', { class: 'num' }, fmt(o.longitude_deg, 5)),
        h('td', { class: 'num' }, fmt(o.depth_m)))))),
  );
}

async function poll() {
  if (!current) return;
  try {
    observations = await api('GET', `/api/environment/subscriptions/${encodeURIComponent(current)}`);
    renderObservations();
  } catch (e) {
    root.querySelector('#env-observations').replaceChildren(h('p', { class: 'error' }, describe(e)));
  }
}

function select(id) {
  current = id;
  clearInterval(timer);
  // Live messages carry new observations; the poll catches up after reconnects.
  timer = setInterval(poll, 5000);
  poll();
  loadSubscriptions();
}

async function loadSubscriptions() {
  const box = root.querySelector('#env-subs');
  try {
    const subs = await api('GET', '/api/environment/subscriptions');
    box.replaceChildren(
      subs.length
        ? h('ul', { class: 'subs' }, subs.map((s) => h('li', { class: s.id === current ? 'selected' : '' },
          h('button', { type: 'button', class: 'link-button', onclick: () => select(s.id) }, s.id),
          ` ${s.spec.property || 'every property'}, ${s.spec.area ? `${s.spec.area.length}-corner area` : 'anywhere'}, ≤ ${s.spec.max_rate_hz} Hz; ${s.delivered} delivered `,
          h('button', {
            type: 'button',
            class: 'link-button needs-operator',
            onclick: async () => {
              try {
                await api('DELETE', `/api/environment/subscriptions/${encodeURIComponent(s.id)}`);
                if (current === s.id) current = null;
                renderObservations();
                loadSubscriptions();
              } catch (e) {
                toast(describe(e), 'error');
              }
            },
          }, 'unsubscribe'))))
        : h('p', { class: 'muted' }, 'No subscription yet.'),
    );
  } catch (e) {
    box.replaceChildren(h('p', { class: 'error' }, describe(e)));
  }
}

export function initEnvironment() {
  root = document.getElementById('tab-environment');
  const form = h('form', { class: 'card', id: 'env-form', novalidate: true },
    h('h2', {}, 'Subscribe to environment data'),
    h('div', { class: 'row' },
      h('label', {}, 'Property', h('input', { name: 'property', placeholder: 'sea_water_temperature (empty: all)' })),
      h('label', {}, 'Max rate Hz', h('input', { name: 'rate', type: 'number', step: 'any', value: '1' }))),
    h('label', { class: 'inline' }, h('input', { type: 'checkbox', name: 'area' }), 'only inside the polygon drawn on the map (Missions → Survey → Draw)'),
    h('p', { class: 'error', id: 'env-error', role: 'alert' }),
    h('button', { type: 'submit', class: 'primary needs-operator' }, 'Subscribe'));
  form.addEventListener('submit', async (e) => {
    e.preventDefault();
    const f = form.elements;
    const rate = Number(f.rate.value);
    let ok = fieldError(f.rate, rate > 0 && rate <= 100 ? '' : 'Rate must be in (0, 100] observations per second.');
    const spec = { max_rate_hz: rate };
    if (f.property.value.trim()) spec.property = f.property.value.trim();
    if (f.area.checked) {
      const pts = draftPoints();
      ok = fieldError(f.area, pts.length >= 3 ? '' : 'Draw a polygon of at least 3 corners on the map first.') && ok;
      spec.area = pts;
    }
    if (!ok) return;
    try {
      const sub = await api('POST', '/api/environment/subscriptions', spec);
      toast(`Subscribed: ${sub.id}`, 'ok');
      select(sub.id);
    } catch (err) {
      form.querySelector('#env-error').textContent = describe(err);
    }
  });
  root.replaceChildren(form, h('h2', {}, 'Subscriptions'), h('div', { id: 'env-subs' }), h('div', { id: 'env-observations' }));
  on('observation', (o) => {
    if (o.subscription === current) {
      observations.push(o.observation);
      if (observations.length > 1000) observations.shift();
      renderObservations();
    }
  });
  on('session', loadSubscriptions);
  renderObservations();
}
