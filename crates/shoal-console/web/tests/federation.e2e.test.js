// Another site's vehicle in the console (Debian's Chromium driven by playwright-core):
// scripts/console-e2e.sh federates the `shoal up` station (site "shore") over Zenoh with a
// second station (site "ship", DDS domain 147) that has one simulated AUV, ship-auv-1.
// The shore's console must show it on the map and under "Other sites", as the ship's,
// with the ship's task transitions, and never offer it in a task form unless the shore holds its lease; it lists who holds
// each command lease, shows the ship's environment summaries, commands the ship's
// vehicle through the ship while it holds the lease (a command, and a mission drawn in its
// mission editor), and hands back a lease it was handed.

import { after, before, describe, test } from 'node:test';
import assert from 'node:assert/strict';
import { mkdirSync, mkdtempSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { chromium } from 'playwright-core';
import { clickMap } from './map.js';

const BASE = process.env.SHOAL_URL || 'http://127.0.0.1:8640';
const TOKEN = process.env.SHOAL_ADMIN_TOKEN;
const OUT = process.env.SHOAL_E2E_OUT || 'target/console-e2e';
const CHROMIUM = process.env.CHROMIUM || '/usr/bin/chromium';
const ARGS = ['--headless', '--no-sandbox', '--disable-gpu', '--no-first-run', '--disable-background-networking', '--disable-component-update', '--disable-sync'];
const REMOTE = 'ship/ship-auv-1';
/** The ship station's API (console logins off there: a lab station of its own). */
const SHIP = process.env.SHOAL_SHIP_URL;
const operator = { user: 'fed-operator', password: `fed-op-${Date.now()}-pw` };

async function admin(method, path, body) {
  const res = await fetch(BASE + path, {
    method,
    headers: { Authorization: `Bearer ${TOKEN}`, 'Content-Type': 'application/json' },
    body: body === undefined ? undefined : JSON.stringify(body),
  });
  const text = await res.text();
  return { status: res.status, body: text ? JSON.parse(text) : null };
}

describe('Another site in the console', { concurrency: false }, () => {
  let ctx;
  let page;
  let profile;
  const requests = [];

  before(async () => {
    assert.ok(TOKEN, 'SHOAL_ADMIN_TOKEN is not set (scripts/console-e2e.sh sets it)');
    mkdirSync(OUT, { recursive: true });
    const made = await admin('POST', '/api/auth/users', { name: operator.user, password: operator.password, role: 'operator' });
    assert.ok(made.status < 300, JSON.stringify(made));
    profile = mkdtempSync(join(tmpdir(), 'shoal-fed-profile-'));
    ctx = await chromium.launchPersistentContext(profile, { executablePath: CHROMIUM, headless: true, args: ARGS, viewport: { width: 1600, height: 950 } });
    ctx.on('request', (r) => requests.push(r.url()));
    page = ctx.pages()[0] || (await ctx.newPage());
    page.on('pageerror', (e) => console.error('page error:', e.message));
  });

  after(async () => {
    await ctx?.close();
    if (profile) rmSync(profile, { recursive: true, force: true });
  });

  test("the shore station serves the ship's vehicle as the ship's, not its own", async () => {
    let doc;
    for (let i = 0; i < 120; i++) {
      doc = (await admin('GET', '/api/federation')).body;
      if (doc.vehicles.some((v) => v.vehicle_id === 'ship-auv-1')) break;
      await new Promise((resolve) => setTimeout(resolve, 1000));
    }
    assert.equal(doc.enabled, true);
    assert.equal(doc.site, 'shore');
    const v = doc.vehicles.find((x) => x.vehicle_id === 'ship-auv-1');
    assert.ok(v, `no ship-auv-1 at the shore within 2 min: ${JSON.stringify(doc)}`);
    assert.equal(v.site, 'ship');
    assert.equal(v.kind, 'auv');
    assert.deepEqual(doc.sites.map((s) => [s.site, s.online]), [['ship', true]]);
    const fleet = (await admin('GET', '/api/fleet')).body;
    assert.ok(!JSON.stringify(fleet).includes('ship-auv-1'), 'the ship\'s vehicle is in the shore\'s own fleet');
  });

  test('an operator sees it on the map and under Other sites, read-only', async () => {
    await page.goto(BASE + '/');
    await page.locator('#login').waitFor({ state: 'visible' });
    await page.fill('#login-form input[name=user]', operator.user);
    await page.fill('#login-form input[name=password]', operator.password);
    await page.click('#login-form button[type=submit]');
    await page.locator('#login').waitFor({ state: 'hidden' });

    // The fleet panel: the site, online, and its vehicle with kind and age; not in the own list.
    const row = page.locator(`#remote-fleet tr[data-remote="${REMOTE}"]`);
    await row.waitFor({ timeout: 30000 });
    await page.locator('#remote-fleet .remote-site[data-site="ship"][data-online="online"]').waitFor();
    const text = await row.textContent();
    assert.match(text, /ship-auv-1/);
    assert.match(text, /· ship/);
    assert.match(text, /AUV/);
    assert.match(text, /\d+ (s|min)$/);
    await page.locator('#fleet-table tr[data-vehicle="auv-1"]').waitFor({ timeout: 60000 });
    assert.equal(await page.locator('#fleet-table tr[data-vehicle="ship-auv-1"]').count(), 0);

    // The map: labelled with its site, in its own layer (never among the own fleet), in view.
    const drawn = await page.waitForFunction((key) => {
      const { map, sources } = window.shoalConsole;
      const f = sources.remote.getFeatureById(key);
      if (!f) return null;
      const extent = map.getView().calculateExtent(map.getSize());
      const [x, y] = f.getGeometry().getCoordinates();
      const inView = x >= extent[0] && x <= extent[2] && y >= extent[1] && y <= extent[3];
      return {
        label: f.get('label'),
        site: f.get('remote').site,
        own: sources.vehicles.getFeatures().some((o) => o.getId() === 'ship-auv-1'),
        inView,
        pixel: map.getPixelFromCoordinate(f.getGeometry().getCoordinates()),
      };
    }, REMOTE, { timeout: 30000 }).then((h) => h.jsonValue());
    assert.equal(drawn.label, 'ship-auv-1 · ship');
    assert.equal(drawn.site, 'ship');
    assert.equal(drawn.own, false);
    assert.ok(drawn.inView, 'the ship\'s vehicle is outside the map\'s view');

    // Hovering shows what is known of it.
    const box = await page.locator('#map').boundingBox();
    await page.mouse.move(box.x + drawn.pixel[0], box.y + drawn.pixel[1]);
    const info = page.locator(`#remote-info[data-remote="${REMOTE}"]`);
    await info.waitFor({ state: 'visible', timeout: 10000 });
    assert.equal(await info.locator('dd[data-fact=site]').textContent(), 'ship');
    assert.equal(await info.locator('dd[data-fact=kind]').textContent(), 'AUV');
    for (const fact of ['depth', 'battery', 'speed', 'age']) {
      assert.notEqual(await info.locator(`dd[data-fact=${fact}]`).count(), 0, fact);
    }

    // Clicking it pins that information; it does not become the vehicle the command views act on.
    await page.mouse.click(box.x + drawn.pixel[0], box.y + drawn.pixel[1]);
    await page.locator('#remote-info.pinned').waitFor({ timeout: 5000 });
    await page.locator(`#remote-fleet tr.selected[data-remote="${REMOTE}"]`).waitFor({ timeout: 5000 });
    assert.equal(await page.locator('#fleet-table tr.selected').count(), 0);
    await page.click('#tabs button[data-tab=fleet]');
    // The section is rebuilt on every update, so a locator's element can be replaced between
    // Playwright's stability check and the scroll: scroll in one step inside the page.
    await page.locator('#remote-fleet').waitFor();
    await page.evaluate(() => document.getElementById('remote-fleet')?.scrollIntoView({ block: 'nearest' }));
    await page.screenshot({ path: join(OUT, '21-federation-other-site.png') });
    await page.click('#tabs button[data-tab=vehicles]');
    assert.ok(!(await page.locator('#tab-vehicles').textContent()).includes('ship-auv-1'), 'the vehicle view shows the ship\'s vehicle');

    // Not offered for a task: neither in the waypoint nor in the survey vehicle list, nor
    // among the vehicles "not offered" (it is not this station's to dispatch at all).
    await page.click('#tabs button[data-tab=missions]');
    const form = page.locator('#mission-form');
    // Wait for the station's answer on who can do the task (an own vehicle offered).
    await page.waitForFunction(() => document.querySelectorAll('#mission-form select[name=vehicle] option[value]:not([value=""])').length > 0, null, { timeout: 30000 });
    const offered = await form.locator('select[name=vehicle] option').evaluateAll((os) => os.map((o) => o.value));
    assert.ok(!offered.includes('ship-auv-1'), `offered: ${offered}`);
    assert.equal(await form.locator('#vehicle-why li[data-vehicle="ship-auv-1"]').count(), 0);
    assert.ok(!(await page.locator('#tab-missions').textContent()).includes('ship-auv-1'));
    // And the station refuses a task for it, whoever asks.
    const refused = await admin('POST', '/api/missions?start=true', {
      mission_id: `fed-${Date.now()}`,
      name: 'a remote vehicle',
      tasks: [{ vehicle_id: 'ship-auv-1', task: { kind: 'goto_waypoint', target: { latitude_deg: 63.456, longitude_deg: 10.35 }, depth_m: 5, speed_mps: 1 } }],
    });
    assert.ok(refused.status >= 400 && refused.status < 500, `planning a mission for ship-auv-1 answered ${refused.status}`);
  });

  test("the ship's task transitions show at the shore, under its site, read-only", async () => {
    assert.ok(SHIP, 'SHOAL_SHIP_URL is not set (scripts/console-e2e.sh sets it)');
    const mission = `ship-m-${Date.now()}`;
    const res = await fetch(`${SHIP}/api/missions?start=true`, {
      method: 'POST',
      headers: { 'Content-Type': 'application/json' },
      body: JSON.stringify({
        mission_id: mission,
        name: 'a ship mission seen from shore',
        tasks: [{ vehicle_id: 'ship-auv-1', task: { kind: 'goto_waypoint', target: { latitude_deg: 63.4555, longitude_deg: 10.35 }, depth_m: 2, speed_mps: 1.5 } }],
      }),
    });
    const body = await res.text();
    assert.ok(res.status < 300, `the ship refused the mission: ${res.status} ${body}`);
    const task = JSON.parse(body).tasks[0].assignment.task_id;

    // The shore's API carries the transitions, with the ship's site.
    let seen = [];
    for (let i = 0; i < 60 && !seen.length; i++) {
      const doc = (await admin('GET', '/api/federation')).body;
      seen = doc.transitions.filter((t) => t.task_id === task);
      if (!seen.length) await new Promise((resolve) => setTimeout(resolve, 1000));
    }
    assert.ok(seen.length, `no transition of ${task} at the shore within a minute`);
    assert.ok(seen.every((t) => t.site === 'ship' && t.vehicle_id === 'ship-auv-1' && t.mission_id === mission), JSON.stringify(seen));

    // The console lists the task under the ship with its latest state.
    await page.click('#tabs button[data-tab=fleet]');
    const row = page.locator(`#remote-fleet .remote-site[data-site="ship"] tr.remote-task[data-task="${task}"]`);
    await row.waitFor({ timeout: 30000 });
    const text = await row.textContent();
    assert.match(text, /ship-auv-1/);
    assert.match(text, /sent|accepted|running|done/);
    // Not among the shore's own missions or tasks.
    assert.equal((await admin('GET', `/api/missions/${mission}`)).status, 404);
  });

  test("the ship's environment data shows at the shore, aggregated per property and window", async () => {
    // The ship sends summaries of 5 s windows (scripts/console-e2e.sh); its AUV's CTD
    // samples the water every 10 s.
    let env = [];
    for (let i = 0; i < 60 && !env.length; i++) {
      const doc = (await admin('GET', '/api/federation')).body;
      env = (doc.environment || []).filter((e) => e.site === 'ship' && e.vehicle_id === 'ship-auv-1');
      if (!env.length) await new Promise((resolve) => setTimeout(resolve, 1000));
    }
    assert.ok(env.length, 'no environment summary from the ship within a minute');
    for (const e of env) {
      assert.ok(e.count >= 1 && e.min <= e.mean && e.mean <= e.max, JSON.stringify(e));
      assert.ok(e.window_start_ms < e.window_end_ms, JSON.stringify(e));
    }
    await page.click('#tabs button[data-tab=fleet]');
    const row = page.locator(`#remote-fleet .remote-site[data-site="ship"] .remote-environment tr[data-vehicle="ship-auv-1"][data-property="${env[0].property}"]`);
    await row.waitFor({ timeout: 30000 });
    assert.match(await row.textContent(), new RegExp(env[0].property));
  });

  test('the command leases: the ship commands its vehicle; a lease handed to the shore is handed back from its console', async () => {
    assert.ok(SHIP, 'SHOAL_SHIP_URL is not set (scripts/console-e2e.sh sets it)');
    await page.click('#tabs button[data-tab=fleet]');
    const row = () => page.locator('#leases tr.lease[data-vehicle="ship-auv-1"]');
    await row().waitFor({ timeout: 30000 });
    assert.equal(await row().getAttribute('data-holder'), 'ship');
    assert.equal(await row().locator('button.hand-over').count(), 0, 'a lease held elsewhere offers no hand-over');

    // The ship's operator hands it to the shore (the ship's API).
    const res = await fetch(`${SHIP}/api/federation/leases/ship-auv-1`, {
      method: 'POST',
      headers: { 'Content-Type': 'application/json' },
      body: JSON.stringify({ to: 'shore' }),
    });
    const body = await res.text();
    assert.equal(res.status, 200, body);
    const handed = JSON.parse(body);
    await page.locator('#leases tr.lease[data-vehicle="ship-auv-1"][data-held="true"]').waitFor({ timeout: 30000 });

    // Holding the lease, the shore commands the ship's vehicle: the task goes through the
    // ship's station, which gives it to the vehicle under the shore's lease.
    await row().locator('button.command-surface').click();
    let relayed = null;
    for (let i = 0; i < 30 && !relayed; i++) {
      const tasks = await (await fetch(`${SHIP}/api/tasks`)).json();
      relayed = tasks.find((t) => t.assignment.vehicle_id === 'ship-auv-1' && t.assignment.kind === 'surface'
        && t.assignment.lease_holder === 'shore') || null;
      if (!relayed) await new Promise((resolve) => setTimeout(resolve, 1000));
    }
    assert.ok(relayed, 'the ship never dispatched the shore\'s task');
    assert.equal(relayed.assignment.lease_term, handed.term);
    const mine = await admin('GET', `/api/tasks/${relayed.assignment.task_id}`);
    assert.equal(mine.status, 200);
    assert.equal(mine.body.via_site, 'ship');

    // Holding the lease, the shore's mission editor offers the ship's vehicle (under the
    // other sites), and a mission drawn on the shore's map goes to it through the ship.
    await page.click('#tabs button[data-tab=missions]');
    const form = page.locator('#mission-form');
    await form.locator('input[name=kind][value=goto_waypoint]').check();
    const option = form.locator('select[name=vehicle] optgroup option[value="ship-auv-1"][data-site="ship"]');
    await option.waitFor({ state: 'attached', timeout: 30000 });
    assert.match(await option.textContent(), /ship-auv-1 · ship \(auv.*at site ship/);
    await form.locator('select[name=vehicle]').selectOption('ship-auv-1');
    await form.locator('input[name=level]').fill('2');
    await form.locator('input[name=speed]').fill('1');
    const at = (await admin('GET', '/api/federation')).body.vehicles.find((v) => v.vehicle_id === 'ship-auv-1');
    await page.click('#draw');
    await clickMap(page, at.latitude_deg + 0.0004, at.longitude_deg + 0.0006);
    await page.locator('#points li', { hasText: 'waypoint 1' }).waitFor();
    const missionId = await form.locator('input[name=mission_id]').inputValue();
    await page.click('#start-mission');
    await page.locator('#confirm[open]').waitFor();
    await page.locator('#plan-preview tr[data-vehicle="ship-auv-1"]').waitFor({ timeout: 10000 });
    await page.screenshot({ path: join(OUT, '22-federation-mission-on-a-leased-vehicle.png') });
    await page.click('#confirm-ok');
    await page.locator(`.mission[data-mission="${missionId}"]`).waitFor({ timeout: 10000 });
    let sent = null;
    for (let i = 0; i < 30 && !sent; i++) {
      const tasks = await (await fetch(`${SHIP}/api/tasks`)).json();
      sent = tasks.find((t) => t.assignment.vehicle_id === 'ship-auv-1' && t.assignment.kind === 'goto_waypoint'
        && t.assignment.lease_holder === 'shore' && t.assignment.mission_id === missionId) || null;
      if (!sent) await new Promise((resolve) => setTimeout(resolve, 1000));
    }
    assert.ok(sent, `the ship never dispatched mission ${missionId}'s task`);
    assert.equal(sent.assignment.lease_term, handed.term);
    await page.click('#tabs button[data-tab=fleet]');

    // The shore's operator hands it back to the ship from the console.
    await row().locator('select.lease-to').selectOption('ship');
    await row().locator('button.hand-over').click();
    await page.locator('#leases tr.lease[data-vehicle="ship-auv-1"][data-holder="ship"]').waitFor({ timeout: 30000 });
    let back = null;
    for (let i = 0; i < 30 && !back; i++) {
      const doc = await (await fetch(`${SHIP}/api/federation`)).json();
      back = doc.leases.find((l) => l.vehicle_id === 'ship-auv-1' && l.held_here && l.term === handed.term + 1) || null;
      if (!back) await new Promise((resolve) => setTimeout(resolve, 1000));
    }
    assert.ok(back, 'the ship did not get the lease back');
    // Without the lease the editor no longer offers it.
    await page.click('#tabs button[data-tab=missions]');
    await page.waitForFunction(() => !document.querySelector('#mission-form select[name=vehicle] option[value="ship-auv-1"]'), null, { timeout: 30000 });
  });

  test('no request left this host', async () => {
    assert.ok(requests.some((u) => u.includes('/api/federation')), 'the console never asked for /api/federation');
    const outside = requests.filter((u) => {
      const url = new URL(u);
      if (url.protocol === 'data:' || url.protocol === 'blob:') return false;
      return !['127.0.0.1', 'localhost', '[::1]'].includes(url.hostname);
    });
    assert.deepEqual(outside, []);
  });
});
