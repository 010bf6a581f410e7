#!/usr/bin/env node
// The page's figures in headless Chromium, run by
// `cargo run --release -p service --example page_bench` (which starts the service with
// its history and passes: BASE TOKEN MAP_PARAMS_JSON USER_DATA_DIR). Prints the figures;
// asserts nothing.
'use strict';
const path = require('path');
const { chromium } = require(path.join(__dirname, 'node_modules', 'playwright-core'));

const [base, token, mapParams, userDataDir, spki] = process.argv.slice(2);
const LONG_MS = 30 * 60 * 1000;

const stats = (values) => {
  const v = [...values].sort((a, b) => a - b);
  const q = (p) => v[Math.min(v.length - 1, Math.floor(v.length * p))];
  return { n: v.length, p50: q(0.5), p99: q(0.99), max: v[v.length - 1] };
};
const ms = (x) => x.toFixed(1) + ' ms';

async function main() {
  const context = await chromium.launchPersistentContext(userDataDir, {
    executablePath: '/usr/bin/chromium',
    headless: true,
    args: ['--headless', '--no-sandbox', '--disable-gpu', '--no-first-run',
      '--disable-background-networking', '--disable-component-update', '--disable-sync',
      // HTTPS with the box's self-signed pair: its public key trusted (SPKI pin).
      ...(spki ? [`--ignore-certificate-errors-spki-list=${spki}`] : [])],
    viewport: { width: 1280, height: 1600 },
  });
  const page = context.pages()[0] || await context.newPage();

  // 1. Page loads with the history: navigation to machines + history + live shown.
  const loads = [];
  for (let i = 0; i < 5; i++) {
    const t0 = Date.now();
    await page.goto(`${base}/#token=${encodeURIComponent(token)}`);
    await page.locator('#connection[data-state="open"]').waitFor({ timeout: 60000 });
    await page.locator('#history-rows tr[data-job-id]').first().waitFor({ timeout: 60000 });
    await page.locator('#machines li[data-machine]').first().waitFor({ timeout: 60000 });
    loads.push(Date.now() - t0);
    if (i < 4) await page.goto('about:blank');
  }
  const rows = await page.locator('#history-rows tr[data-job-id]').count();
  const total = await page.evaluate(async (t) => {
    const r = await fetch('/api/v1/jobs?limit=1000', { headers: { Authorization: 'Bearer ' + t } });
    return (await r.json()).length;
  }, token);
  const list = await page.evaluate(async (t) => {
    const r = await fetch('/api/v1/jobs?limit=50', { headers: { Authorization: 'Bearer ' + t } });
    return (await r.arrayBuffer()).byteLength;
  }, token);
  const files = await page.evaluate(() => performance.getEntriesByType('resource')
    .filter((e) => /\/(app\.js|style\.css)$/.test(e.name))
    .map((e) => e.name.split('/').pop() + ' ' + e.transferSize + ' B transferred, ' + e.decodedBodySize + ' B'));
  console.log(`GET /api/v1/jobs?limit=50 with a 15 MB layout job in the history: ${list} bytes; ` +
    `page files on the last load: ${files.join('; ')}`);
  console.log(`page load with ${total}+ jobs in history (${rows} rows shown): ` +
    loads.map((x) => x + ' ms').join(', ') + ` (first: a cold browser cache)`);

  // 2. A map job shown while its measurements arrive, each update timed.
  await page.evaluate(() => {
    window.__updates = [];
    const handle = window.handleEvent;
    window.handleEvent = function (message) {
      if (message.type !== 'measurement' || view.detailJob !== message.job_id) return handle(message);
      const t0 = performance.now();
      handle(message);
      document.body.getBoundingClientRect(); // the layout the update causes
      window.__updates.push(performance.now() - t0);
      return undefined;
    };
  });
  const window0 = await page.evaluate(() => performance.now());
  const job = await page.evaluate(async ([t, params]) => {
    const r = await fetch('/api/v1/machines/demo/jobs', { method: 'POST',
      headers: { Authorization: 'Bearer ' + t, 'Content-Type': 'application/json' },
      body: JSON.stringify({ kind: 'map', params: JSON.parse(params) }) });
    return r.json();
  }, [token, mapParams]);
  if (!job.id) throw new Error('the map job was refused: ' + JSON.stringify(job));
  await page.waitForFunction((id) => {
    const img = document.querySelector(`figure.live-frame[data-job-id="${id}"] img.frame-image`);
    return img && img.complete && img.naturalWidth > 0;
  }, job.id, { timeout: 60000 });
  const firstFrame = await page.evaluate(() => performance.now());
  console.log(`first frame of map job ${job.id} shown ${(firstFrame - window0).toFixed(0)} ms after its request`);
  await page.locator(`button.show-job[data-job-id="${job.id}"]`).click();
  await page.locator(`#job-detail[data-job-id="${job.id}"]`).waitFor({ timeout: 60000 });
  const t0 = Date.now();
  await page.locator(`#history-rows tr[data-job-id="${job.id}"]`)
    .and(page.locator('[data-state="succeeded"], [data-state="failed"], [data-state="cancelled"]'))
    .waitFor({ timeout: LONG_MS });
  const wall = (Date.now() - t0) / 1000;
  const updates = await page.evaluate(() => window.__updates);
  const shown = Number(await page.locator('#job-measurement-count').getAttribute('data-count'));
  const fetches = await page.evaluate((id) => performance.getEntriesByType('resource')
    .filter((e) => e.name.includes('/api/v1/jobs/' + id + '/measurements')).length, job.id);
  const s = stats(updates);
  const state = await page.locator(`#history-rows tr[data-job-id="${job.id}"]`).getAttribute('data-state');
  console.log(`map job ${job.id} (${state}, ${wall.toFixed(1)} s): ${s.n} measurements appended live, ` +
    `${shown} counted by the page; per update p50 ${ms(s.p50)}, p99 ${ms(s.p99)}, max ${ms(s.max)}; ` +
    `${updates.filter((x) => x > 50).length} above 50 ms, ${updates.filter((x) => x > 200).length} above 200 ms; ` +
    `the measurements fetched ${fetches} time(s)`);
  await context.close();
}

main().catch((error) => {
  console.error(String(error && error.stack || error));
  process.exit(1);
});
