// The report of `shoal scenario run` opened from its file in a real browser (Debian's
// Chromium driven by playwright-core) inside a network namespace with no route out: it
// must render whole, offline, asking nothing of any server. scripts/console-e2e.sh runs
// the scenario and passes SHOAL_REPORT (the report.html) and SHOAL_E2E_OUT (screenshots).

import { after, test } from 'node:test';
import assert from 'node:assert/strict';
import { mkdtempSync, readFileSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { dirname, join } from 'node:path';
import { pathToFileURL } from 'node:url';
import { chromium } from 'playwright-core';

const REPORT = process.env.SHOAL_REPORT;
const OUT = process.env.SHOAL_E2E_OUT || 'target/console-e2e';
const CHROMIUM = process.env.CHROMIUM || '/usr/bin/chromium';
const ARGS = ['--headless', '--no-sandbox', '--disable-gpu', '--no-first-run', '--disable-background-networking', '--disable-component-update', '--disable-sync'];

const profile = mkdtempSync(join(tmpdir(), 'shoal-report-profile-'));
let ctx;
after(async () => {
  await ctx?.close();
  rmSync(profile, { recursive: true, force: true });
});

test('the scenario report opens offline with its plots, tables and every vehicle', async () => {
  assert.ok(REPORT, 'SHOAL_REPORT names the report.html of a scenario run');
  const summary = JSON.parse(readFileSync(join(dirname(REPORT), 'summary.json'), 'utf8'));
  const vehicles = Object.keys(summary.vehicles);
  assert.ok(vehicles.length >= 2, `vehicles in the summary: ${vehicles}`);

  ctx = await chromium.launchPersistentContext(profile, {
    executablePath: CHROMIUM, headless: true, args: ARGS, viewport: { width: 1000, height: 900 },
  });
  const requests = [];
  ctx.on('request', (r) => requests.push(r.url()));
  const page = ctx.pages()[0] || (await ctx.newPage());
  const errors = [];
  page.on('pageerror', (e) => errors.push(e.message));
  const url = pathToFileURL(REPORT).href;
  await page.goto(url);

  // Tracks, depth, battery, speed and the task timeline: five drawn figures; a run with
  // an acoustic network adds the link quality at the relay.
  const acoustic = Object.keys(summary.acoustic_links || {}).length > 0;
  const svgs = page.locator('svg');
  const figures = acoustic ? 6 : 5;
  assert.equal(await svgs.count(), figures);
  for (let i = 0; i < figures; i++) {
    const box = await svgs.nth(i).boundingBox();
    assert.ok(box && box.width > 300 && box.height > 100, `figure ${i} is drawn: ${JSON.stringify(box)}`);
  }
  // Each vehicle that moved has its track drawn, with its name on the map.
  const map = page.locator('svg.map');
  for (const id of vehicles) {
    assert.equal(await page.locator('table').first().locator(`td:text-is("${id}")`).count(), 1, `${id} in the vehicles table`);
    if (summary.vehicles[id].states > 1) {
      assert.equal(await map.locator(`polyline:has(title:text-is("${id}"))`).count(), 1, `${id}'s track`);
    }
  }
  // One timeline bar per task that started, and the task table lists every task.
  const tasks = Object.keys(summary.task_outcomes).length;
  assert.ok(tasks >= 1);
  const bars = await page.locator('svg[aria-label="Task timeline"] rect[rx]').count();
  assert.ok(bars >= 1 && bars <= tasks, `${bars} timeline bars for ${tasks} tasks`);
  assert.equal(await page.locator('table').nth(1).locator('tr').count(), tasks + 1);
  // The acoustic network's links (the default scenario relays auv-ac1), and the rules.
  if (acoustic) {
    assert.equal(await page.locator('h2:text-is("Acoustic network")').count(), 1);
    for (const key of Object.keys(summary.acoustic_links)) {
      const [from, to] = key.split('>');
      assert.equal(await page.locator(`td:text-is("${from} → ${to}")`).count(), 1, `link ${key}`);
    }
    assert.equal(await page.locator('svg[aria-label="Acoustic link quality (RSSI at the relay)"] polyline').count() >= 1, true);
  }
  assert.equal(await page.locator('h2:text-is("Rule firings")').count(), 1);

  await page.screenshot({ path: join(OUT, 'scenario-report.png'), fullPage: true });
  assert.deepEqual(errors, []);
  // Only the report's own file (and whatever local file Chromium itself may look for):
  // nothing over any network.
  assert.deepEqual(requests.filter((r) => !r.startsWith('file:')), [], 'the report fetches nothing');
  assert.ok(requests.includes(url));
});
