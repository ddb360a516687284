// The console's entry point: login (when the station requires it), tabs, the live feed and
// the global "abort all".

import './style.css';
import { api, describe, onUnauthorized, setCsrfToken } from './api.js';
import { dropLive, startLive, stopLive } from './live.js';
import { createMap } from './map.js';
import { initFleet } from './fleet.js';
import { initMissions, leaveMissions, showMissions } from './missions.js';
import { initTimeline, showTimeline } from './timeline.js';
import { initEvents } from './events.js';
import { initRules, loadRules } from './rules.js';
import { initQuery } from './query.js';
import { initEnvironment } from './environment.js';
import { initVehicles, showVehicles } from './vehicles.js';
import { initReplay, showReplay } from './replay.js';
import { startTraffic } from './traffic.js';
import { initAcoustic, startAcoustic } from './acoustic.js';
import { initFederation, startFederation, stopFederation } from './federation.js';
import { emit, may, on, state } from './store.js';
import { confirmDialog, toast } from './util.js';

function showTab(name) {
  for (const b of document.querySelectorAll('#tabs button')) b.classList.toggle('active', b.dataset.tab === name);
  for (const s of document.querySelectorAll('.tab')) s.classList.toggle('active', s.id === `tab-${name}`);
  if (name !== 'missions') leaveMissions();
  if (name === 'missions') showMissions();
  if (name === 'timeline') showTimeline();
  if (name === 'vehicles') showVehicles();
  if (name === 'replay') showReplay();
  if (name === 'rules') loadRules();
}

/** Greys out what the role may not do (the station refuses it anyway, with 403). */
function applyRole() {
  const { enabled, user, role } = state.session;
  document.body.dataset.role = role;
  document.getElementById('who').textContent = enabled ? `${user} (${role})` : 'authentication off';
  document.getElementById('logout').hidden = !enabled;
  for (const el of document.querySelectorAll('.needs-operator')) {
    el.disabled = !may('operator');
    el.title = may('operator') ? el.title.replace(/ — .*$/, '') : `${el.title ? `${el.title} ` : ''}— your role (${role}) is read-only`;
  }
  for (const el of document.querySelectorAll('.needs-admin')) el.disabled = !may('admin');
}

function showLogin(message) {
  stopLive();
  stopFederation();
  const overlay = document.getElementById('login');
  overlay.hidden = false;
  document.getElementById('login-error').textContent = message || '';
  overlay.querySelector('input[name=user]').focus();
}

async function loadSession() {
  state.session = await api('GET', '/api/auth/session');
  setCsrfToken(state.session.csrf_token);
  if (state.session.enabled && !state.session.user) {
    showLogin('');
    return false;
  }
  document.getElementById('login').hidden = true;
  applyRole();
  emit('session', state.session);
  startLive();
  startTraffic();
  startAcoustic();
  startFederation();
  return true;
}

async function login(e) {
  e.preventDefault();
  const f = e.target.elements;
  try {
    await api('POST', '/api/auth/login', { user: f.user.value.trim(), password: f.password.value });
    f.password.value = '';
    await loadSession();
  } catch (err) {
    document.getElementById('login-error').textContent = describe(err);
  }
}

async function logout() {
  try {
    await api('POST', '/api/auth/logout');
  } catch (e) {
    toast(describe(e), 'error');
  }
  state.session = { enabled: true, user: null, role: 'viewer' };
  setCsrfToken(null);
  applyRole();
  showLogin('Logged out.');
}

async function abortAll() {
  const n = [...state.vehicles.values()].filter((v) => v.contact === 'alive' || v.contact === 'stale').length;
  const ok = await confirmDialog('Abort everything?', `Every mission is aborted and every vehicle in contact (${n}) gets an abort: it surfaces and stops.`, 'Abort all');
  if (!ok) return;
  try {
    const res = await api('POST', '/api/abort-all', { confirm: true });
    toast(`Abort sent to ${res.aborted_vehicles.length} vehicle(s): ${res.aborted_vehicles.join(', ') || 'none'}`, 'warn');
  } catch (e) {
    toast(describe(e), 'error');
  }
}

function init() {
  createMap();
  initAcoustic();
  initFederation();
  initFleet();
  initMissions();
  initTimeline();
  initEvents();
  initRules();
  initQuery();
  initEnvironment();
  initVehicles();
  initReplay();
  document.getElementById('tabs').addEventListener('click', (e) => {
    const b = e.target.closest('button[data-tab]');
    if (b) showTab(b.dataset.tab);
  });
  document.getElementById('login-form').addEventListener('submit', login);
  document.getElementById('logout').addEventListener('click', logout);
  document.getElementById('abort-all').addEventListener('click', abortAll);
  // Views re-render their buttons; keep them in line with the role.
  new MutationObserver(() => applyRole()).observe(document.getElementById('side'), { childList: true, subtree: true });
  on('select', () => {
    if (document.getElementById('tab-vehicles').classList.contains('active')) showVehicles();
  });
  onUnauthorized((message) => {
    if (state.session.enabled) showLogin(message);
  });
  // Test hook beside the map's (map.js): simulate a dropped link.
  window.shoalConsole.dropLive = dropLive;
  connectSession();
}

/** Asks the station who we are, retrying while it is unreachable. */
function connectSession() {
  loadSession().catch((e) => {
    toast(`${describe(e)} — retrying`, 'error');
    setTimeout(connectSession, 3000);
  });
}

init();
