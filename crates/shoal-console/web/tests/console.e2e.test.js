// The console in a real browser (Debian's Chromium driven by playwright-core) against a
// running `shoal up` with authentication on. Started by scripts/console-e2e.sh, which
// passes SHOAL_URL, SHOAL_ADMIN_TOKEN and SHOAL_E2E_OUT (screenshots, request log).
//
// Every request the browser makes is recorded; the last test asserts none left this host.

import { after, before, describe, test } from 'node:test';
import assert from 'node:assert/strict';
import { mkdirSync, mkdtempSync, readdirSync, readFileSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { spawn } from 'node:child_process';
import dgram from 'node:dgram';
import { request as httpRequest } from 'node:http';
import { chromium } from 'playwright-core';
import { clickMap } from './map.js';

const BASE = process.env.SHOAL_URL || 'http://127.0.0.1:8640';
const TOKEN = process.env.SHOAL_ADMIN_TOKEN;
const OUT = process.env.SHOAL_E2E_OUT || 'target/console-e2e';
const CHROMIUM = process.env.CHROMIUM || '/usr/bin/chromium';
const ARGS = ['--headless', '--no-sandbox', '--disable-gpu', '--no-first-run', '--disable-background-networking', '--disable-component-update', '--disable-sync'];
const FLEET = ['auv-1', 'auv-2', 'usv-1', 'rov-1', 'auv-ac1'];

const users = {
  operator: { user: 'e2e-operator', password: `op-${Date.now()}-pw` },
  viewer: { user: 'e2e-viewer', password: `view-${Date.now()}-pw` },
  admin: { user: 'e2e-admin', password: `admin-${Date.now()}-pw` },
};
const requests = [];
/** Live-feed messages about vehicles not alive (contact changes), as the browsers got them. */
const contactFrames = [];
const contexts = [];
const profiles = [];

/** The admin's API token, as a tool would use it. */
async function admin(method, path, body) {
  const res = await fetch(BASE + path, {
    method,
    headers: { Authorization: `Bearer ${TOKEN}`, 'Content-Type': 'application/json' },
    body: body === undefined ? undefined : JSON.stringify(body),
  });
  const text = await res.text();
  if (!res.ok) throw new Error(`${method} ${path}: ${res.status} ${text}`);
  return text ? JSON.parse(text) : null;
}

/** A browser with a fresh profile; every request and WebSocket it opens is recorded. */
async function browser() {
  const dir = mkdtempSync(join(tmpdir(), 'shoal-e2e-profile-'));
  profiles.push(dir);
  const ctx = await chromium.launchPersistentContext(dir, {
    executablePath: CHROMIUM,
    headless: true,
    args: ARGS,
    viewport: { width: 1600, height: 950 },
  });
  contexts.push(ctx);
  ctx.on('request', (r) => requests.push(r.url()));
  const page = ctx.pages()[0] || (await ctx.newPage());
  page.on('websocket', (ws) => {
    requests.push(ws.url());
    ws.on('framereceived', (f) => {
      const text = String(f.payload);
      if (text.startsWith('{"type":"vehicle"') && !text.includes('"contact":"alive"')) contactFrames.push(text);
    });
  });
  page.on('pageerror', (e) => console.error('page error:', e.message));
  return page;
}

async function login(page, who) {
  await page.goto(BASE + '/');
  await page.locator('#login').waitFor({ state: 'visible' });
  await page.fill('#login-form input[name=user]', who.user);
  await page.fill('#login-form input[name=password]', who.password);
  await page.click('#login-form button[type=submit]');
  await page.locator('#login').waitFor({ state: 'hidden' });
  await page.locator('#conn[data-state=live]').waitFor({ timeout: 15000 });
}

const shot = (page, name) => page.screenshot({ path: join(OUT, `${name}.png`) });

describe('Shoal console in Chromium', { concurrency: false }, () => {
  let page;
  let adminTab = null;
  /** The mission the first mission test drew and saw done, for the timeline's test. */
  let doneMissionId = null;

  /** One admin's browser, logged in once, for the tests that change rules. */
  async function adminBrowser() {
    if (!adminTab) {
      adminTab = await browser();
      await login(adminTab, users.admin);
    }
    return adminTab;
  }

  before(async () => {
    assert.ok(TOKEN, 'SHOAL_ADMIN_TOKEN is not set (scripts/console-e2e.sh sets it as [console.auth] initial_admin_token)');
    mkdirSync(OUT, { recursive: true });
    const session = await admin('GET', '/api/auth/session');
    assert.equal(session.enabled, true, 'the station runs without [console.auth]');
    await admin('POST', '/api/auth/users', { name: users.operator.user, password: users.operator.password, role: 'operator' });
    await admin('POST', '/api/auth/users', { name: users.viewer.user, password: users.viewer.password, role: 'viewer' });
    await admin('POST', '/api/auth/users', { name: users.admin.user, password: users.admin.password, role: 'admin' });
    page = await browser();
  });

  after(async () => {
    for (const c of contexts) await c.close();
    for (const d of profiles) rmSync(d, { recursive: true, force: true });
  });

  test('the API refuses requests without credentials', async () => {
    const res = await fetch(BASE + '/api/fleet');
    assert.equal(res.status, 401);
    assert.match((await res.json()).error, /log in/);
  });

  test('an operator logs in; vehicles appear in the list and on the map', async () => {
    await login(page, users.operator);
    for (const id of FLEET) {
      await page.locator(`#fleet-table tr[data-vehicle="${id}"]`).waitFor({ timeout: 60000 });
    }
    // Each vehicle is drawn inside the visible map.
    await page.waitForFunction((ids) => {
      const { map, sources } = window.shoalConsole;
      const extent = map.getView().calculateExtent(map.getSize());
      return ids.every((id) => {
        const f = sources.vehicles.getFeatureById(id);
        if (!f) return false;
        const [x, y] = f.getGeometry().getCoordinates();
        return x >= extent[0] && x <= extent[2] && y >= extent[1] && y <= extent[3];
      });
    }, FLEET, { timeout: 30000 });
    // The submerged AUV is heard through the CDT, whose link status follows its first data.
    await page.waitForFunction(() => {
      const cell = document.querySelector('#fleet-table tr[data-vehicle="auv-ac1"] .link');
      return cell && cell.textContent.trim() === 'acoustic';
    }, null, { timeout: 60000 });
    assert.ok(await page.locator('#who').textContent().then((t) => t.includes('operator')));
    await shot(page, '01-fleet-and-map');
  });

  test('a mission is drawn on the map, checked, started and reaches done', async () => {
    await page.click('#tabs button[data-tab=missions]');
    const form = page.locator('#mission-form');
    await form.locator('select[name=vehicle]').selectOption('usv-1');
    // Invalid input is explained next to the field.
    await form.locator('input[name=speed]').fill('');
    await page.click('#start-mission');
    await assert.doesNotReject(form.locator('input[name=speed] ~ .field-error', { hasText: 'Speed' }).waitFor());
    assert.match(await form.locator('#points ~ .field-error, #points + .field-error').first().textContent(), /waypoint/);
    await form.locator('input[name=speed]').fill('3');
    // A surface vehicle: the editor keeps it at the surface, with no depth to fill in.
    assert.equal(await form.locator('select[name=vref]').inputValue(), 'surface');
    const v = await page.evaluate(() => window.shoalConsole.sources.vehicles.getFeatureById('usv-1').get('view').latest);
    await page.click('#draw');
    // About 60 m north-east of the USV.
    await clickMap(page, v.latitude_deg + 0.0004, v.longitude_deg + 0.0006);
    await page.locator('#points li', { hasText: 'waypoint 1' }).waitFor();
    const missionId = await form.locator('input[name=mission_id]').inputValue();
    await page.click('#start-mission');
    await page.locator('#confirm[open]').waitFor();
    await page.click('#confirm-ok');
    const card = page.locator(`.mission[data-mission="${missionId}"]`);
    await card.waitFor({ timeout: 10000 });
    await shot(page, '02-mission-running');
    await card.locator('.pill[data-state=done]').waitFor({ timeout: 150000 });
    doneMissionId = missionId;
    // The waypoint shows on the map as a task.
    const tasksDrawn = await page.evaluate(() => window.shoalConsole.sources.tasks.getFeatures().length);
    assert.ok(tasksDrawn >= 1);
    await shot(page, '03-mission-done');
    // Its log exports as CSV and GeoJSON.
    const exported = await page.evaluate(async (id) => {
      const csv = await (await fetch(`/api/missions/${id}/export.csv`)).text();
      const geo = await (await fetch(`/api/missions/${id}/export.geojson`)).json();
      return { rows: csv.trim().split('\n').length, features: geo.features.map((f) => f.geometry && f.geometry.type) };
    }, missionId);
    assert.ok(exported.rows > 2, `CSV rows: ${exported.rows}`);
    assert.ok(exported.features.includes('LineString') && exported.features.includes('Point'), JSON.stringify(exported.features));
  });

  test('the mission timeline shows each vehicle\'s tasks over time, live', async () => {
    assert.ok(doneMissionId, 'no mission reached done in the test before');
    await page.click('#tabs button[data-tab=timeline]');
    const tab = page.locator('#tab-timeline');
    // The station says when each of that mission's tasks went out, started and ended.
    const mission = await admin('GET', `/api/missions/${doneMissionId}`);
    assert.ok(mission.tasks.length >= 1);
    for (const t of mission.tasks) {
      const { task_id: id } = t.assignment;
      assert.ok(t.dispatched_ms && t.started_ms && t.ended_ms, `${id}: ${JSON.stringify(t)}`);
      assert.ok(t.dispatched_ms <= t.started_ms && t.started_ms <= t.ended_ms, `${id}: ${t.dispatched_ms} ${t.started_ms} ${t.ended_ms}`);
      // Its bar is done, has a width, and ended left of "now".
      const bar = tab.locator(`.bar.state-done[data-task="${id}"]`);
      await bar.waitFor({ timeout: 10000 });
      assert.equal(await bar.getAttribute('data-vehicle'), t.assignment.vehicle_id);
      assert.ok((await bar.boundingBox()).width > 0, `${id} has no width`);
      await page.waitForFunction((task) => {
        const r = document.querySelector(`#tab-timeline .bar[data-task="${task}"]`).getBoundingClientRect();
        return r.right < document.querySelector('#tab-timeline .now-line').getBoundingClientRect().left;
      }, id, { timeout: 10000 });
    }
    // A short task on an idle vehicle: its bar appears under way and grows with the time.
    const taskId = `e2e-hold-${Date.now() % 100000}`;
    await admin('POST', '/api/tasks', {
      task_id: taskId, mission_id: '', vehicle_id: 'rov-1', issued_ms: Date.now(), kind: 'hold', area: [],
      depth_m: -1, altitude_m: -1, speed_mps: 0, line_spacing_m: 0, duration_s: 20, rate_hz: 0, issue_seq: 0, expires_ms: 0,
    });
    const held = tab.locator(`.bar[data-task="${taskId}"]`);
    await tab.locator(`.bar[data-task="${taskId}"]:is(.state-running, .state-accepted)`).waitFor({ timeout: 15000 });
    assert.equal(await held.getAttribute('data-vehicle'), 'rov-1');
    const before = (await held.boundingBox()).width;
    await page.waitForTimeout(2500);
    assert.match(await held.getAttribute('class'), /state-(running|accepted)/);
    const grown = (await held.boundingBox()).width;
    assert.ok(grown > before + 1, `the bar under way did not grow: ${before} -> ${grown}`);
    // Clicked, it names its task below the chart.
    await held.click();
    const detail = page.locator('#timeline-detail');
    await detail.locator('h3', { hasText: taskId }).waitFor({ timeout: 5000 });
    assert.match(await detail.textContent(), /rov-1.*hold.*(running|accepted)/s);
    assert.match(await held.getAttribute('class'), /selected/);
    await shot(page, '22-timeline');
  });

  test('an alarm appears live and is acknowledged', async () => {
    const ruleId = `e2e-alarm-${Date.now() % 100000}`;
    await page.click('#tabs button[data-tab=alarms]');
    await admin('POST', '/api/rules', { id: ruleId, description: 'end-to-end test alarm', severity: 'alarm', condition: { type: 'threshold', expr: 'battery_pct < 101' } });
    try {
      const row = page.locator('#event-table tr.sev-alarm:not(.acked)').first();
      await row.waitFor({ timeout: 30000 });
      const eventId = await row.getAttribute('data-event');
      // The list re-renders as further alarms arrive: name the row by its event id.
      const acked = page.locator(`#event-table tr[data-event="${eventId}"]`);
      await acked.locator('button.ack').click();
      await page.waitForFunction((id) => {
        const tr = document.querySelector(`#event-table tr[data-event="${id}"]`);
        return tr && tr.classList.contains('acked');
      }, eventId, { timeout: 10000 });
      assert.match(await acked.textContent(), new RegExp(users.operator.user));
      await shot(page, '04-alarm-acknowledged');
    } finally {
      await admin('DELETE', `/api/rules/${ruleId}`);
    }
  });

  test('a semantic query returns rows', async () => {
    await page.click('#tabs button[data-tab=query]');
    await page.click('#run-query');
    await page.locator('#query-table tbody tr').first().waitFor({ timeout: 15000 });
    const rows = await page.locator('#query-table tbody tr').count();
    assert.ok(rows >= FLEET.length, `${rows} rows`);
    await shot(page, '05-query');
  });

  test('the vehicle detail shows depth and battery charts', async () => {
    await page.click('#tabs button[data-tab=fleet]');
    await page.click('#fleet-table tr[data-vehicle="auv-1"]');
    await page.click('#tabs button[data-tab=vehicles]');
    // A flat line (a full battery) has no height, so wait for the paths, not their visibility.
    await page.locator('#charts svg.chart path.series').nth(1).waitFor({ state: 'attached', timeout: 15000 });
    const segments = await page.locator('#charts svg.chart path.series').evaluateAll((paths) => paths.map((p) => p.getAttribute('d').split('L').length));
    assert.equal(segments.length, 2);
    assert.ok(segments.every((n) => n >= 2), `points per chart: ${segments}`);
    await shot(page, '06-vehicle-charts');
  });

  test('the live feed shows "reconnecting" when the link drops and recovers by itself', async () => {
    // Offline, the socket is cut and every new handshake fails until the link is back.
    await page.context().setOffline(true);
    try {
      await page.evaluate(() => window.shoalConsole.dropLive());
      await page.locator('#conn[data-state=reconnecting]').waitFor({ timeout: 10000 });
      await page.waitForTimeout(3000);
      assert.equal(await page.locator('#conn').getAttribute('data-state'), 'reconnecting');
      await shot(page, '07-reconnecting');
    } finally {
      // Whatever happened, the later tests need this page online.
      await page.context().setOffline(false);
    }
    await page.locator('#conn[data-state=live]').waitFor({ timeout: 20000 });
  });

  test('an admin registers a vehicle; it shows as silent until it reports', async () => {
    const adminPage = await browser();
    await login(adminPage, users.admin);
    await adminPage.click('#tabs button[data-tab=vehicles]');
    const form = adminPage.locator('#vehicle-form');
    await form.locator('input[name=vehicle_id]').fill('glider-e2e');
    await form.locator('input[name=name]').fill('Test glider');
    await form.locator('select[name=kind]').selectOption('glider');
    await form.locator('input[name=vendor]').fill('e2e');
    await form.locator('input[name=max_speed]').fill('99');
    await form.locator('button[type=submit]').click();
    await form.locator('input[name=max_speed] ~ .field-error', { hasText: '30' }).waitFor();
    await form.locator('input[name=max_speed]').fill('0.5');
    await form.locator('button[type=submit]').click();
    await adminPage.click('#tabs button[data-tab=fleet]');
    const row = adminPage.locator('#fleet-table tr[data-vehicle="glider-e2e"].contact-silent');
    await row.waitFor({ timeout: 10000 });
    assert.match(await row.textContent(), /GLIDER.*e2e.*silent/s);
    await shot(adminPage, '08-registered-vehicle');
  });

  test('a viewer sees everything but cannot dispatch', async () => {
    const viewer = await browser();
    await login(viewer, users.viewer);
    await viewer.locator('#fleet-table tr[data-vehicle="auv-1"]').waitFor({ timeout: 30000 });
    await viewer.click('#tabs button[data-tab=missions]');
    assert.equal(await viewer.locator('#start-mission').isDisabled(), true);
    assert.equal(await viewer.locator('#abort-all').isDisabled(), true);
    const refused = await viewer.evaluate(async () => {
      const post = (path, body) => fetch(path, { method: 'POST', headers: { 'Content-Type': 'application/json' }, body: JSON.stringify(body) });
      const mission = await post('/api/missions?start=true', {
        mission_id: 'viewer-try',
        name: '',
        tasks: [{ vehicle_id: 'auv-1', task: { kind: 'goto_waypoint', target: { latitude_deg: 63.466, longitude_deg: 10.371 }, depth_m: 5, speed_mps: 1 } }],
      });
      const abort = await post('/api/abort-all', { confirm: true });
      return { mission: mission.status, abort: abort.status, error: (await mission.json()).error };
    });
    assert.deepEqual([refused.mission, refused.abort], [403, 403]);
    assert.match(refused.error, /operator role/);
    await shot(viewer, '09-viewer-read-only');
  });

  test('a change on the session without its CSRF token, or from another host name, is refused', async () => {
    const answer = await page.evaluate(async () => {
      const ack = (headers) => fetch('/api/events/no-such-event/ack', { method: 'POST', headers: { 'Content-Type': 'application/json', ...headers }, body: '{}' });
      const bare = await ack({});
      return { bare: bare.status, error: (await bare.json()).error, wrong: (await ack({ 'X-CSRF-Token': 'forged' })).status };
    });
    assert.deepEqual([answer.bare, answer.wrong], [403, 403]);
    assert.match(answer.error, /x-csrf-token/);
    // The console's own page sends it: the same request gets past the guard (404: no such event).
    const csrf = (await page.evaluate(async () => (await fetch('/api/auth/session')).json())).csrf_token;
    assert.ok(csrf, 'the session names no csrf_token');
    const own = await page.evaluate(async (t) => (await fetch('/api/events/no-such-event/ack', { method: 'POST', headers: { 'Content-Type': 'application/json', 'X-CSRF-Token': t }, body: '{}' })).status, csrf);
    assert.equal(own, 404);
    // DNS rebinding: the same station under a name it does not answer to gets 421 (node:http,
    // since fetch may not set Host).
    const rebound = await new Promise((resolve, reject) => {
      const url = new URL(BASE);
      httpRequest({ host: url.hostname, port: url.port, path: '/api/health', headers: { Host: `rebind.example:${url.port}` } }, (res) => {
        res.resume();
        resolve(res.statusCode);
      }).on('error', reject).end();
    });
    assert.equal(rebound, 421);
  });

  test('an admin creates a threshold rule, edits it in place and disables it', async () => {
    const adminPage = await adminBrowser();
    const ruleId = `e2e-edit-${Date.now() % 100000}`;
    await adminPage.click('#tabs button[data-tab=rules]');
    const form = adminPage.locator('#rule-form');
    try {
      await form.locator('input[name=id]').fill(ruleId);
      await form.locator('select[name=severity]').selectOption('info');
      await form.locator('input[name=description]').fill('deep dive (e2e)');
      // Invalid input is explained next to the field, before anything is sent.
      await form.locator('input[name=expr]').fill('depth_m >');
      await form.locator('#rule-submit').click();
      await form.locator('input[name=expr] ~ .field-error', { hasText: 'field op number' }).waitFor();
      await form.locator('input[name=expr]').fill('depth_m > 9000');
      await form.locator('#rule-submit').click();
      const row = adminPage.locator(`#rule-table tr[data-rule="${ruleId}"]`);
      await row.waitFor({ timeout: 10000 });
      assert.match(await row.textContent(), /depth_m > 9000/);

      // Edit in place: the form takes the rule, the id stays fixed.
      await row.locator('button.edit').click();
      await form.locator('h2', { hasText: `Edit rule ${ruleId}` }).waitFor();
      assert.equal(await form.locator('input[name=id]').getAttribute('readonly'), '');
      assert.equal(await form.locator('input[name=expr]').inputValue(), 'depth_m > 9000');
      // The station checks the new definition as it checks a new rule; refused, the rule
      // stays as it was and the parser's message is under the field.
      await form.locator('input[name=expr]').fill('no_such_field > 3');
      await form.locator('#rule-submit').click();
      const refusal = form.locator('input[name=expr] ~ .field-error');
      await refusal.filter({ hasText: /\S/ }).waitFor({ timeout: 10000 });
      assert.match(await refusal.textContent(), /no_such_field|field/);
      assert.equal((await admin('GET', `/api/rules/${ruleId}`)).condition.expr, 'depth_m > 9000');
      await shot(adminPage, '10-rule-edit-refused');
      await form.locator('input[name=expr]').fill('depth_m > 8000');
      await form.locator('select[name=severity]').selectOption('warning');
      await form.locator('#rule-submit').click();
      await adminPage.waitForFunction((id) => {
        const tr = document.querySelector(`#rule-table tr[data-rule="${id}"]`);
        return tr && /depth_m > 8000/.test(tr.textContent) && /warning/.test(tr.textContent);
      }, ruleId, { timeout: 10000 });
      const changed = await admin('GET', `/api/rules/${ruleId}`);
      assert.deepEqual([changed.condition.expr, changed.severity, changed.description, changed.enabled], ['depth_m > 8000', 'warning', 'deep dive (e2e)', true]);
      // Back to creating: the form is empty again.
      await form.locator('h2', { hasText: 'New rule' }).waitFor();

      // Disable it.
      await adminPage.locator(`#rule-table tr[data-rule="${ruleId}"] input[type=checkbox]`).uncheck();
      await adminPage.locator(`#rule-table tr[data-rule="${ruleId}"].disabled`).waitFor({ timeout: 10000 });
      assert.equal((await admin('GET', `/api/rules/${ruleId}`)).enabled, false);
      await shot(adminPage, '11-rule-edited-disabled');
    } finally {
      await admin('DELETE', `/api/rules/${ruleId}`).catch(() => {});
    }
  });

  test("a bad SPARQL rule shows the parser's message next to the query", async () => {
    const adminPage = await adminBrowser();
    await adminPage.click('#tabs button[data-tab=rules]');
    const form = adminPage.locator('#rule-form');
    const ruleId = `e2e-sparql-${Date.now() % 100000}`;
    await form.locator('input[name=id]').fill(ruleId);
    await form.locator('select[name=type]').selectOption('sparql');
    await form.locator('textarea[name=query]').fill('ASK { ?this shoal:batteryLevel ?b FILTER(?b < 15 }');
    // No watched property: explained next to that field first.
    await form.locator('#rule-submit').click();
    await form.locator('input[name=watches] ~ .field-error', { hasText: 'watches' }).waitFor();
    await form.locator('input[name=watches]').fill('shoal:batteryLevel');
    await form.locator('#rule-submit').click();
    const msg = form.locator('textarea[name=query] ~ .field-error');
    await msg.filter({ hasText: /\S/ }).waitFor({ timeout: 10000 });
    assert.match(await msg.textContent(), /does not parse/);
    assert.equal(await form.locator('textarea[name=query]').getAttribute('aria-invalid'), 'true');
    await shot(adminPage, '12-sparql-rule-refused');
    // Nothing was created.
    const rules = await admin('GET', '/api/rules');
    assert.ok(!rules.some((r) => r.id === ruleId));
    // Fixed, it is accepted.
    await form.locator('textarea[name=query]').fill('ASK { ?this shoal:batteryLevel ?b FILTER(?b < 1) }');
    await form.locator('#rule-submit').click();
    await adminPage.locator(`#rule-table tr[data-rule="${ruleId}"]`).waitFor({ timeout: 10000 });
    await admin('DELETE', `/api/rules/${ruleId}`);
  });

  test('the environment view shows observations', async () => {
    await page.click('#tabs button[data-tab=environment]');
    const form = page.locator('#env-form');
    await form.locator('input[name=rate]').fill('0');
    await form.locator('button[type=submit]').click();
    await form.locator('input[name=rate] ~ .field-error', { hasText: 'Rate' }).waitFor();
    await form.locator('input[name=rate]').fill('5');
    await form.locator('button[type=submit]').click();
    // The simulated vehicles' CTDs report every ten seconds or so.
    await page.locator('#env-table tbody tr').first().waitFor({ timeout: 60000 });
    const first = await page.locator('#env-table tbody tr').first().textContent();
    assert.match(first, /(auv|usv|rov)-/);
    await shot(page, '13-environment');
  });

  test('AIS vessels sent over UDP appear on the map with their names', { skip: !process.env.SHOAL_AIS_PORT && 'SHOAL_AIS_PORT is not set' }, async () => {
    // Encoded by pyais 3.3.1: MMSI 257000001 (class A, NORNE, 8 kn on 270, with its
    // two-sentence static report) and 258000002 (class B, 5 kn on 045), near the fleet;
    // and one line with a broken checksum, which must be counted and dropped.
    const lines = [
      '!AIVDM,1,1,,A,13m62@@P1@PgRNhTD34:S8L1P000,0*74',
      '!AIVDM,2,1,0,A,53m62@@00000hpu8000pu8pD0000000000000016000001Pd000000000000,0*14',
      '!AIVDM,2,2,0,A,00000000000,2*24',
      '!AIVDM,1,1,,A,B3n34PP0<`;njP94vK0L8FP00000,0*6F',
      '!AIVDM,1,1,,A,B3n34PP0<`;njP94vK0L8FP00000,0*00',
    ];
    const socket = dgram.createSocket('udp4');
    for (const l of lines) {
      await new Promise((ok, fail) => socket.send(`${l}\r\n`, Number(process.env.SHOAL_AIS_PORT), '127.0.0.1', (e) => (e ? fail(e) : ok())));
    }
    socket.close();
    // The live feed moves vessels on the map within the station's next second; the
    // summary comes with the 10-second poll.
    await page.waitForFunction(
      () => ['ais-257000001', 'ais-258000002'].every((id) => window.shoalConsole.sources.traffic.getFeatureById(id)),
      null,
      { timeout: 5000 },
    );
    await page.locator('#traffic-summary', { hasText: 'AIS: 2 vessel(s), 1 line(s) dropped' }).waitFor({ timeout: 15000 });
    const doc = await page.evaluate(async () => (await fetch('/api/traffic')).json());
    const norne = doc.targets.find((t) => t.mmsi === 257000001);
    assert.equal(norne.name, 'NORNE');
    assert.ok(Math.abs(norne.sog_kn - 8) < 0.1 && Math.abs(norne.cog_deg - 270) < 0.1, JSON.stringify(norne));
    assert.equal(doc.stats.bad_checksum, 1);
    await shot(page, '14-ais-traffic');
  });

  test('a survey polygon is drawn and only capable vehicles are offered', async () => {
    await page.click('#tabs button[data-tab=missions]');
    const form = page.locator('#mission-form');
    await form.locator('input[name=kind][value=survey_area]').check();
    await form.locator('select[name=payload]').selectOption('sidescan_survey');
    const offered = async () => form.locator('select[name=vehicle] option').evaluateAll((os) => os.map((o) => o.value).filter(Boolean));
    // The AUVs carry a side-scan sonar: the semantic model infers the capability. Wait for
    // the side-scan answer itself (the USV listed as unable), not a list the editor showed
    // for the previous choice (seen in CI: the USV still offered for "any survey").
    await page.waitForFunction(() => {
      const vals = [...document.querySelectorAll('#mission-form select[name=vehicle] option')].map((o) => o.value);
      return vals.includes('auv-1') && vals.includes('auv-2') && !vals.includes('usv-1')
        && document.querySelector('#vehicle-why li[data-vehicle="rov-1"]')
        && document.querySelector('#vehicle-why li[data-vehicle="usv-1"]');
    }, null, { timeout: 15000 });
    let ids = await offered();
    assert.ok(!ids.includes('usv-1') && !ids.includes('rov-1'), `offered: ${ids}`);
    assert.match(await page.locator('#vehicle-why li[data-vehicle="usv-1"]').textContent(), /sidescan_survey/);
    assert.match(await page.locator('#vehicle-why li[data-vehicle="rov-1"]').textContent(), /"survey"/);
    assert.match(await form.locator('select[name=vehicle] option[value="auv-1"]').textContent(), /sidescan_survey from sidescan_sonar/);
    const answer = await page.evaluate(async () => (await fetch('/api/fleet/capable?kind=survey_area&capability=sidescan_survey')).json());
    const auv1 = answer.vehicles.find((v) => v.vehicle_id === 'auv-1');
    assert.ok(auv1.capable && auv1.dispatchable, JSON.stringify(auv1));
    assert.deepEqual(auv1.capabilities.find((c) => c.capability === 'sidescan_survey').inferred_from, ['sidescan_sonar']);
    // Any area survey: the USV (multibeam) is offered too, the ROV (camera) still not.
    await form.locator('select[name=payload]').selectOption('');
    await page.waitForFunction(() => [...document.querySelectorAll('#mission-form select[name=vehicle] option')].some((o) => o.value === 'usv-1'), null, { timeout: 15000 });
    ids = await offered();
    assert.ok(!ids.includes('rov-1'), `offered: ${ids}`);
    await form.locator('select[name=payload]').selectOption('sidescan_survey');
    await page.waitForFunction(() => ![...document.querySelectorAll('#mission-form select[name=vehicle] option')].some((o) => o.value === 'usv-1'), null, { timeout: 15000 });
    await form.locator('select[name=vehicle]').selectOption('auv-1');

    // Draw a triangle beside auv-1; clicking the first corner again closes it.
    const v = await page.evaluate(() => window.shoalConsole.sources.vehicles.getFeatureById('auv-1').get('view').latest);
    await page.click('#draw');
    const corners = [[0.0006, -0.001], [0.0006, 0.001], [0.0016, 0]];
    for (const [dlat, dlon] of corners) {
      await clickMap(page, v.latitude_deg + dlat, v.longitude_deg + dlon);
      await page.waitForTimeout(400);
    }
    await clickMap(page, v.latitude_deg + corners[0][0], v.longitude_deg + corners[0][1]);
    await page.locator('#points li', { hasText: 'corner 3' }).waitFor({ timeout: 10000 });
    // Invalid input is explained next to each field: the spacing, and a speed beyond
    // what this AUV announced.
    await form.locator('input[name=spacing]').fill('0');
    await form.locator('input[name=speed]').fill('25');
    await page.locator('#mission-form button', { hasText: 'Plan only' }).click();
    await form.locator('input[name=spacing] ~ .field-error', { hasText: 'Line spacing' }).waitFor();
    await form.locator('input[name=speed] ~ .field-error', { hasText: 'auv-1 goes at most' }).waitFor();
    await shot(page, '14-survey-invalid-input');
    await form.locator('input[name=spacing]').fill('25');
    await form.locator('input[name=speed]').fill('1');
    const missionId = `e2e-survey-${Date.now() % 100000}`;
    await form.locator('input[name=mission_id]').fill(missionId);
    await page.locator('#mission-form button', { hasText: 'Plan only' }).click();
    await page.locator('#confirm[open]').waitFor();
    assert.match(await page.locator('#confirm-body').textContent(), /auv-1: survey 3 corners/);
    // The review carries the station's estimate for the vehicle: a small survey, no warning.
    const estimate = page.locator('#plan-preview tr[data-vehicle="auv-1"]');
    await estimate.waitFor();
    assert.equal(await estimate.getAttribute('data-warn'), 'no');
    assert.match(await estimate.textContent(), /\d+ (s|min)/);
    assert.match(await page.locator('#plan-preview h4').textContent(), /Estimate: about \d+/);
    await shot(page, '15-survey-review');
    await page.click('#confirm-ok');
    const card = page.locator(`.mission[data-mission="${missionId}"]`);
    await card.locator('.pill[data-state=planned]').waitFor({ timeout: 10000 });
    const planned = await admin('GET', `/api/missions/${missionId}`);
    assert.equal(planned.tasks[0].assignment.kind, 'survey_area');
    assert.equal(planned.tasks[0].assignment.vehicle_id, 'auv-1');
    await shot(page, '16-survey-planned');
    // Planned only: it leaves the vehicles alone; abort it so nothing waits for it.
    await admin('POST', `/api/missions/${missionId}/abort`);
  });

  test('the review warns when a vehicle\'s battery would not last the mission', async () => {
    await page.click('#tabs button[data-tab=missions]');
    const form = page.locator('#mission-form');
    await form.locator('input[name=kind][value=survey_area]').check();
    await form.locator('select[name=payload]').selectOption('');
    await page.waitForFunction(() => [...document.querySelectorAll('#mission-form select[name=vehicle] option')].some((o) => o.value === 'auv-2'), null, { timeout: 15000 });
    await form.locator('select[name=vehicle]').selectOption('auv-2');
    // A triangle over the middle of the map's view, surveyed with about 400 lines: far more
    // than an AUV's battery lasts.
    const view = await page.evaluate(() => {
      const { map } = window.shoalConsole;
      const [x0, y0, x1, y1] = map.getView().calculateExtent(map.getSize());
      const R = 6378137;
      const lon = (x) => (x / R) * (180 / Math.PI);
      const lat = (y) => (2 * Math.atan(Math.exp(y / R)) - Math.PI / 2) * (180 / Math.PI);
      return { s: lat(y0), n: lat(y1), w: lon(x0), e: lon(x1) };
    });
    const at = (fy, fx) => [view.s + (view.n - view.s) * fy, view.w + (view.e - view.w) * fx];
    const corners = [at(0.3, 0.3), at(0.3, 0.7), at(0.7, 0.5)];
    const heightM = (view.n - view.s) * 0.4 * 111000;
    await form.locator('input[name=spacing]').fill(String(Math.max(1, Math.round(heightM / 400))));
    await form.locator('input[name=speed]').fill('2');
    await form.locator('select[name=vref]').selectOption('depth');
    await form.locator('input[name=level]').fill('5');
    await page.click('#draw');
    for (const [la, lo] of corners) {
      await clickMap(page, la, lo);
      await page.waitForTimeout(300);
    }
    await clickMap(page, corners[0][0], corners[0][1]);
    await page.locator('#points li', { hasText: 'corner 3' }).waitFor({ timeout: 10000 });
    const missionId = `e2e-long-${Date.now() % 100000}`;
    await form.locator('input[name=mission_id]').fill(missionId);
    await page.click('#start-mission');
    await page.locator('#confirm[open]').waitFor();
    const row = page.locator('#plan-preview tr[data-vehicle="auv-2"]');
    await row.waitFor();
    assert.equal(await row.getAttribute('data-warn'), 'yes');
    assert.match(await page.locator('#plan-preview .preview-warnings li[data-vehicle="auv-2"]').textContent(), /battery would (run out|end at about)/);
    assert.equal(await page.locator('#confirm-ok').textContent(), 'Start anyway');
    await shot(page, '24-plan-preview-warning');
    // Cancelled: nothing was planned.
    await page.locator('#confirm button[value=cancel]').click();
    await page.locator('#confirm[open]').waitFor({ state: 'detached' }).catch(() => {});
    const none = await page.evaluate(async (id) => (await fetch(`/api/missions/${id}`)).status, missionId);
    assert.equal(none, 404);
    // The survey stays in the mission being edited; the operator removes it.
    await page.locator('#draft-tasks li', { hasText: 'auv-2' }).locator('button').click();
    assert.equal(await page.locator('#draft-tasks li', { hasText: 'auv-2' }).count(), 0);
  });

  test('a goto for the USV goes at the surface: no depth asked, none sent', async () => {
    await page.click('#tabs button[data-tab=missions]');
    const form = page.locator('#mission-form');
    await form.locator('input[name=kind][value=goto_waypoint]').check();
    await page.waitForFunction(() => [...document.querySelectorAll('#mission-form select[name=vehicle] option')].some((o) => o.value === 'usv-1'), null, { timeout: 15000 });
    // An underwater vehicle first: a depth, its metres asked.
    await form.locator('select[name=vehicle]').selectOption('auv-1');
    await form.locator('select[name=vref]').selectOption('depth');
    assert.equal(await form.locator('input[name=level]').isVisible(), true);
    // The USV: at the surface, the only choice, and no metres to fill in.
    await form.locator('select[name=vehicle]').selectOption('usv-1');
    assert.equal(await form.locator('select[name=vref]').inputValue(), 'surface');
    assert.equal(await form.locator('select[name=vref] option[value=depth]').isDisabled(), true);
    assert.equal(await form.locator('select[name=vref] option[value=altitude]').isDisabled(), true);
    assert.equal(await form.locator('input[name=level]').isVisible(), false);
    assert.match(await form.locator('#vref-note').textContent(), /usv-1 is a USV: it goes at the surface/);
    // Speed 0: the vehicle's own cruise speed, as the station takes it.
    await form.locator('input[name=speed]').fill('0');
    const v = await page.evaluate(() => window.shoalConsole.sources.vehicles.getFeatureById('usv-1').get('view').latest);
    await page.click('#draw');
    await clickMap(page, v.latitude_deg - 0.0004, v.longitude_deg + 0.0006);
    await page.locator('#points li', { hasText: 'waypoint 1' }).waitFor();
    const missionId = `e2e-surface-${Date.now() % 100000}`;
    await form.locator('input[name=mission_id]').fill(missionId);
    const previewed = page.waitForRequest((r) => r.url().endsWith('/api/mission-preview') && r.method() === 'POST');
    await page.locator('#mission-form button', { hasText: 'Plan only' }).click();
    const sentTask = JSON.parse((await previewed).postData()).tasks[0].task;
    assert.deepEqual(Object.keys(sentTask).sort(), ['kind', 'speed_mps', 'target'], JSON.stringify(sentTask));
    assert.equal(sentTask.speed_mps, 0);
    await page.locator('#confirm[open]').waitFor();
    const planText = await page.locator('#confirm-body ol').textContent();
    assert.match(planText, /usv-1: go to .*, at the surface, cruise speed/);
    assert.doesNotMatch(planText, /depth|altitude/);
    await page.locator('#plan-preview tr[data-vehicle="usv-1"]').waitFor();
    await shot(page, '25-usv-at-the-surface-review');
    const planned = page.waitForRequest((r) => /\/api\/missions$/.test(r.url()) && r.method() === 'POST');
    await page.click('#confirm-ok');
    assert.ok(!/depth_m|altitude_m/.test((await planned).postData()), (await planned).postData());
    await page.locator(`.mission[data-mission="${missionId}"] .pill[data-state=planned]`).waitFor({ timeout: 10000 });
    // The station took it and keeps the USV at the surface.
    const mission = await admin('GET', `/api/missions/${missionId}`);
    const a = mission.tasks[0].assignment;
    assert.deepEqual([a.vehicle_id, a.kind, a.depth_m, a.altitude_m, a.speed_mps], ['usv-1', 'goto_waypoint', 0, -1, 0]);
    await admin('POST', `/api/missions/${missionId}/abort`);
    // Back to an underwater vehicle: a depth again, as before the editor chose the surface.
    await form.locator('select[name=vehicle]').selectOption('auv-1');
    assert.equal(await form.locator('select[name=vref]').inputValue(), 'depth');
    assert.equal(await form.locator('input[name=level]').isVisible(), true);

    // A hold as a mission step: it needs an end, or the vehicle's later tasks would wait.
    await form.locator('input[name=kind][value=hold]').check();
    await page.waitForFunction(() => [...document.querySelectorAll('#mission-form select[name=vehicle] option')].some((o) => o.value === 'rov-1'), null, { timeout: 15000 });
    await form.locator('select[name=vehicle]').selectOption('rov-1');
    assert.equal(await page.locator('#draw').isVisible(), false);
    await form.locator('input[name=duration]').fill('0');
    await page.click('#add-task');
    await form.locator('input[name=duration] ~ .field-error', { hasText: 'must end' }).waitFor();
    await form.locator('input[name=duration]').fill('30');
    await page.click('#add-task');
    const step = page.locator('#draft-tasks li', { hasText: 'rov-1: hold position 30 s' });
    await step.waitFor();
    await step.locator('button').click();
    assert.equal(await page.locator('#draft-tasks li', { hasText: 'rov-1' }).count(), 0);
    await form.locator('input[name=kind][value=goto_waypoint]').check();
  });

  test('a single vehicle is given a command from its detail: state request, hold', async () => {
    await page.click('#tabs button[data-tab=fleet]');
    // The USV announces no "surface" capability: it is at the surface already.
    await page.click('#fleet-table tr[data-vehicle="usv-1"]');
    await page.click('#tabs button[data-tab=vehicles]');
    const usvCard = page.locator('#vehicle-commands[data-vehicle="usv-1"]');
    await usvCard.waitFor({ timeout: 10000 });
    const surface = usvCard.locator('button[data-command=surface]');
    assert.equal(await surface.isDisabled(), true);
    assert.match(await surface.getAttribute('title'), /at the surface already/);
    assert.equal(await usvCard.locator('button[data-command=return_home]').isDisabled(), false);

    await page.click('#tabs button[data-tab=fleet]');
    await page.click('#fleet-table tr[data-vehicle="rov-1"]');
    await page.click('#tabs button[data-tab=vehicles]');
    const card = page.locator('#vehicle-commands[data-vehicle="rov-1"]');
    await card.waitFor({ timeout: 10000 });
    const result = card.locator('#command-result');
    // A state request, served by the vehicle's DDS proxy.
    await card.locator('button[data-command=request_state]').click();
    await result.filter({ hasText: 'sent to rov-1' }).waitFor({ timeout: 10000 });
    // A rate the station would refuse is explained under its field; nothing is sent.
    await card.locator('input[name=rate_hz]').fill('0');
    await card.locator('button[data-command=set_reporting_rate]').click();
    await card.locator('input[name=rate_hz] ~ .field-error', { hasText: '(0, 100]' }).waitFor();
    // A hold of a few seconds: the station registers it as asked, and the card follows it.
    await card.locator('input[name=hold_s]').fill('3');
    await card.locator('button[data-command=hold]').click();
    await result.filter({ hasText: /Hold sent to rov-1 as task-/ }).waitFor({ timeout: 10000 });
    const taskId = (await result.textContent()).match(/as (\S+)\.$/)[1];
    const task = await admin('GET', `/api/tasks/${taskId}`);
    assert.deepEqual([task.assignment.kind, task.assignment.vehicle_id, task.assignment.duration_s, task.assignment.mission_id], ['hold', 'rov-1', 3, '']);
    await card.locator('#command-task', { hasText: taskId }).waitFor({ timeout: 10000 });
    await card.locator('#command-task', { hasText: /: done/ }).waitFor({ timeout: 30000 });
    await shot(page, '26-vehicle-commands');
  });

  test('a vehicle that falls silent turns stale, then lost, live in the list', { skip: !process.env.SHOAL_BIN && 'SHOAL_BIN is not set' }, async () => {
    // A simulated vehicle of this test's own on the station's DDS domain; stopping the
    // process (SIGSTOP) silences it without leaving DDS, as a vehicle out of range would.
    const id = 'usv-e2e';
    const child = spawn(process.env.SHOAL_BIN, ['--config', process.env.SHOAL_E2E_CONFIG, 'vehicle', '--sim', 'usv', '--id', id, '--lat', '63.4655', '--lon', '10.372'], { stdio: ['ignore', 'ignore', 'pipe'] });
    let log = '';
    child.stderr.on('data', (d) => { log = (log + d).slice(-4000); });
    try {
      await page.click('#tabs button[data-tab=fleet]');
      const row = (contact) => page.locator(`#fleet-table tr[data-vehicle="${id}"].contact-${contact}`);
      await row('alive').waitFor({ timeout: 60000 }).catch((e) => { throw new Error(`${e.message}\nshoal vehicle: ${log}`); });
      const framesBefore = contactFrames.length;
      child.kill('SIGSTOP');
      // station.stale_after_s is 5 s, lost_after_s 30 s: each change shows as it happens.
      await row('stale').waitFor({ timeout: 20000 });
      assert.match(await row('stale').locator('.pill').first().textContent(), /stale/);
      await shot(page, '17-vehicle-stale');
      // The station pushed the change (no state carries it); the page did not just poll.
      assert.ok(contactFrames.slice(framesBefore).some((t) => t.includes(`"vehicle_id":"${id}"`) && t.includes('"contact":"stale"')), 'no stale vehicle message on the live feed');
      await row('lost').waitFor({ timeout: 45000 });
      await shot(page, '18-vehicle-lost');
      assert.ok(contactFrames.slice(framesBefore).some((t) => t.includes(`"vehicle_id":"${id}"`) && t.includes('"contact":"lost"')), 'no lost vehicle message on the live feed');
      // On the map too: its icon follows the contact.
      const mapped = await page.evaluate((v) => window.shoalConsole.sources.vehicles.getFeatureById(v).get('view').contact, id);
      assert.equal(mapped, 'lost');
    } finally {
      child.kill('SIGCONT');
      child.kill('SIGINT');
      await new Promise((resolve) => {
        const t = setTimeout(() => { child.kill('SIGKILL'); resolve(); }, 10000);
        child.once('exit', () => { clearTimeout(t); resolve(); });
        if (child.exitCode !== null) { clearTimeout(t); resolve(); }
      });
    }
  });

  test('a recording made by shoal record opens in a viewer\'s replay', { skip: !process.env.SHOAL_BIN && 'SHOAL_BIN is not set' }, async () => {
    // Record the simulated fleet for a few seconds with the binary, as an operator would.
    const dir = mkdtempSync(join(tmpdir(), 'shoal-e2e-recording-'));
    try {
      const child = spawn(process.env.SHOAL_BIN, ['--config', process.env.SHOAL_E2E_CONFIG, 'record', '--output', dir], { stdio: ['ignore', 'ignore', 'pipe'] });
      let log = '';
      child.stderr.on('data', (d) => { log = (log + d).slice(-4000); });
      const exited = new Promise((resolve) => child.once('exit', resolve));
      await new Promise((resolve) => setTimeout(resolve, 12000));
      child.kill('SIGINT');
      const done = await Promise.race([exited.then(() => true), new Promise((resolve) => setTimeout(() => resolve(false), 15000))]);
      if (!done) child.kill('SIGKILL');
      const files = readdirSync(dir).filter((f) => f.endsWith('.mcap'));
      assert.equal(files.length, 1, `shoal record wrote ${files.join(', ')}\n${log}`);
      const file = join(dir, files[0]);
      const bytes = readFileSync(file);

      const viewer = await browser();
      await login(viewer, users.viewer);
      await viewer.click('#tabs button[data-tab=replay]');
      await viewer.setInputFiles('#replay-file', file);
      const status = viewer.locator('#replay-status');
      await viewer.waitForFunction(() => /vehicles?, [\d,]+ messages?/.test(document.querySelector('#replay-status').textContent), null, { timeout: 30000 });
      assert.equal(await viewer.locator('#replay-error').textContent(), '', await status.textContent());
      assert.equal(await viewer.locator('#replay-slider').isDisabled(), false);
      // At the end of the recording, every recorded vehicle is on the replay map.
      const drawn = await viewer.evaluate(() => {
        const slider = document.querySelector('#replay-slider');
        slider.value = slider.max;
        slider.dispatchEvent(new Event('input'));
        return window.shoalConsole.sources.replay.getFeatures().filter((f) => f.getGeometry().getType() === 'Point').map((f) => f.get('vehicle')).sort();
      });
      const fleetDrawn = FLEET.filter((id) => drawn.includes(id));
      assert.ok(fleetDrawn.length >= 3, `replayed: ${drawn} (${await status.textContent()})`);
      assert.match(await status.textContent(), new RegExp(`${files[0]}: \\d+ vehicles`));
      await shot(viewer, '19-replay-recording');

      // A copy cut short (a recorder killed mid-file): what was readable, and where it stopped.
      const cut = join(dir, 'cut.mcap');
      writeFileSync(cut, bytes.subarray(0, Math.floor(bytes.length * 0.6)));
      await viewer.setInputFiles('#replay-file', cut);
      await viewer.locator('#replay-error', { hasText: 'offset' }).waitFor({ timeout: 30000 });
      assert.match(await viewer.locator('#replay-error').textContent(), /could not be read to its end: (truncated|corrupt)/);
      await shot(viewer, '20-replay-truncated-recording');

      // Not a recording at all: explained, and the tracks shown stay.
      const junk = join(dir, 'junk.mcap');
      writeFileSync(junk, 'not an MCAP file');
      await viewer.setInputFiles('#replay-file', junk);
      await viewer.locator('#replay-error', { hasText: 'Rejected' }).waitFor({ timeout: 30000 });
      assert.match(await viewer.locator('#replay-error').textContent(), /no Shoal message could be read/);
    } finally {
      rmSync(dir, { recursive: true, force: true });
    }
  });

  test('the acoustic network shows on the map: relay, links, range rings', async () => {
    // The CDT's first link status follows auv-ac1's first frame through the relay.
    await page.waitForFunction(() => window.shoalConsole.sources.acoustic.getFeatureById('link:auv-ac1'), null, { timeout: 60000 });
    assert.equal(await page.locator('#acoustic-toggle input').isChecked(), true, 'the layer is on when there is an acoustic vehicle');
    // The relay rides on usv-1: its modem is drawn where usv-1 is now (it moved in the
    // mission test), within a few metres.
    const offset = await page.evaluate(() => {
      const { sources, toLonLat } = window.shoalConsole;
      const relay = sources.acoustic.getFeatureById('relay');
      const usv = sources.vehicles.getFeatureById('usv-1');
      if (!relay || !usv) return null;
      const [a, b] = [relay, usv].map((f) => toLonLat(f.getGeometry().getCoordinates()));
      const dy = (a[1] - b[1]) * 111_320;
      const dx = (a[0] - b[0]) * 111_320 * Math.cos((a[1] * Math.PI) / 180);
      return { metres: Math.hypot(dx, dy), carrier: relay.get('carrier') };
    });
    assert.ok(offset, 'no relay or no usv-1 on the map');
    assert.equal(offset.carrier, 'usv-1');
    assert.ok(offset.metres < 5, `relay ${offset.metres.toFixed(1)} m from usv-1`);
    // Three range rings (10, 50, 90 % packet error rate), each wider than the one before.
    const rings = await page.evaluate(() => ['0.1', '0.5', '0.9'].map((per) => {
      const f = window.shoalConsole.sources.acoustic.getFeatureById(`ring:${per}`);
      if (!f) return null;
      const e = f.getGeometry().getExtent();
      return { range: f.get('range_m'), width: e[2] - e[0], label: f.get('label') };
    }));
    assert.ok(rings.every(Boolean), JSON.stringify(rings));
    for (let i = 1; i < rings.length; i++) {
      assert.ok(rings[i].range > rings[i - 1].range && rings[i].width > rings[i - 1].width, JSON.stringify(rings));
    }
    assert.match(rings[0].label, /PER 10 %/);
    // Frames keep arriving: the counter rises and pulses run up the line.
    const linkProp = (name) => page.evaluate((n) => window.shoalConsole.sources.acoustic.getFeatureById('link:auv-ac1').get(n), name);
    const frames0 = await linkProp('frames');
    assert.equal(typeof frames0, 'number');
    await page.waitForFunction((f0) => window.shoalConsole.sources.acoustic.getFeatureById('link:auv-ac1').get('frames') > f0, frames0, { timeout: 30000 });
    await page.waitForFunction(() => window.shoalConsole.sources.acoustic.getFeatureById('link:auv-ac1').get('pulses') > 0, null, { timeout: 10000 });
    assert.notEqual(await linkProp('quality'), 'lost');
    // Hovering the link names its RSSI and age.
    await page.evaluate(() => {
      const { map, sources } = window.shoalConsole;
      const ext = sources.acoustic.getFeatureById('link:auv-ac1').getGeometry().getExtent();
      map.getView().fit(ext, { padding: [120, 120, 120, 120], maxZoom: 16 });
      map.renderSync();
    });
    const [x, y] = await page.evaluate(() => {
      const { map, sources } = window.shoalConsole;
      return map.getPixelFromCoordinate(sources.acoustic.getFeatureById('link:auv-ac1').getGeometry().getCoordinateAt(0.5));
    });
    const box = await page.locator('#map').boundingBox();
    await page.mouse.move(box.x + x - 3, box.y + y - 3);
    await page.mouse.move(box.x + x, box.y + y);
    const tip = page.locator('#acoustic-tip');
    await tip.waitFor({ state: 'visible', timeout: 5000 });
    assert.match(await tip.textContent(), /auv-ac1 .*RSSI -?\d+ dB.*heard \d+ s ago/);
    await shot(page, '23-acoustic-map');
    // The layer can be switched off and on again.
    await page.click('#acoustic-toggle input');
    assert.equal(await page.evaluate(() => window.shoalConsole.map.getLayers().getArray().some((l) => l.getSource() === window.shoalConsole.sources.acoustic && l.getVisible())), false);
    await page.click('#acoustic-toggle input');
    assert.equal(await page.evaluate(() => window.shoalConsole.map.getLayers().getArray().some((l) => l.getSource() === window.shoalConsole.sources.acoustic && l.getVisible())), true);
  });

  test('no request left this host', async () => {
    assert.ok(requests.length > 10, `only ${requests.length} requests recorded`);
    writeFileSync(join(OUT, 'requests.txt'), `${requests.join('\n')}\n`);
    const outside = requests.filter((u) => {
      const url = new URL(u);
      if (url.protocol === 'data:' || url.protocol === 'blob:') return false;
      return !['127.0.0.1', 'localhost', '[::1]'].includes(url.hostname);
    });
    assert.deepEqual(outside, []);
  });
});
