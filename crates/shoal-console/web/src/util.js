// Small DOM and formatting helpers shared by the views.

/** Creates an element: h('td', {class: 'x', onclick: fn}, 'text', child, ...). */
export function h(tag, attrs = {}, ...children) {
  const el = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (v === undefined || v === null || v === false) continue;
    if (k.startsWith('on') && typeof v === 'function') el.addEventListener(k.slice(2), v);
    else if (k === 'class') el.className = v;
    else if (k === 'dataset') Object.assign(el.dataset, v);
    else if (k in el && typeof v !== 'string') el[k] = v;
    else el.setAttribute(k, v === true ? '' : v);
  }
  for (const c of children.flat()) {
    if (c === undefined || c === null || c === false) continue;
    el.append(c instanceof Node ? c : document.createTextNode(String(c)));
  }
  return el;
}

export function fmt(x, digits = 1) {
  return typeof x === 'number' && Number.isFinite(x) ? x.toFixed(digits) : '–';
}

/** "4 s ago", "3 min ago", "2 h ago". */
export function ago(ms, now = Date.now()) {
  if (!ms) return 'never';
  const s = Math.max(0, Math.round((now - ms) / 1000));
  if (s < 90) return `${s} s ago`;
  if (s < 5400) return `${Math.round(s / 60)} min ago`;
  return `${Math.round(s / 3600)} h ago`;
}

export function time(ms) {
  if (!ms) return '–';
  const d = new Date(ms);
  return d.toLocaleTimeString(undefined, { hour12: false });
}

export function dateTime(ms) {
  if (!ms) return '–';
  const d = new Date(ms);
  return `${d.toLocaleDateString()} ${d.toLocaleTimeString(undefined, { hour12: false })}`;
}

/** Value for an <input type="datetime-local"> in local time. */
export function toLocalInput(ms) {
  const d = new Date(ms - new Date(ms).getTimezoneOffset() * 60000);
  return d.toISOString().slice(0, 19);
}

const toastBox = () => document.getElementById('toasts');

/** A short message in the corner; errors stay until clicked. */
export function toast(message, kind = 'info') {
  const el = h('div', { class: `toast ${kind}`, role: kind === 'error' ? 'alert' : 'status' }, message);
  el.addEventListener('click', () => el.remove());
  toastBox().append(el);
  if (kind !== 'error') setTimeout(() => el.remove(), 5000);
  return el;
}

/** Asks the operator to confirm; resolves true on Confirm. */
export function confirmDialog(title, body, okLabel = 'Confirm') {
  const dlg = document.getElementById('confirm');
  document.getElementById('confirm-title').textContent = title;
  const box = document.getElementById('confirm-body');
  box.replaceChildren(typeof body === 'string' ? h('p', {}, body) : body);
  document.getElementById('confirm-ok').textContent = okLabel;
  dlg.returnValue = '';
  dlg.showModal();
  return new Promise((resolve) => {
    dlg.addEventListener('close', () => resolve(dlg.returnValue === 'ok'), { once: true });
  });
}

/** Shows `message` under a form field (or clears it). */
export function fieldError(input, message) {
  let el = input.parentElement.querySelector('.field-error');
  if (!el) {
    el = h('span', { class: 'field-error', role: 'alert' });
    input.parentElement.append(el);
  }
  el.textContent = message || '';
  input.setAttribute('aria-invalid', message ? 'true' : 'false');
  return !message;
}

/** A simple table: columns [{title, cell: (row) => node|string, class?}]. */
export function table(columns, rows, opts = {}) {
  return h(
    'table',
    { class: opts.class || 'grid' },
    h('thead', {}, h('tr', {}, columns.map((c) => h('th', { class: c.class }, c.title)))),
    h(
      'tbody',
      {},
      rows.map((r) => {
        const tr = h('tr', opts.row ? opts.row(r) : {}, columns.map((c) => h('td', { class: c.class }, c.cell(r))));
        return tr;
      }),
    ),
  );
}

export const ID_PATTERN = /^[A-Za-z0-9_.-]{1,64}$/;
