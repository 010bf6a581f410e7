#!/usr/bin/env node
// Drives the service's web page in headless Chromium (Debian `chromium`) through
// playwright-core, as an operator would: open the page with the token in the URL
// fragment, start a job, watch its live progress and see it finish in the history, look
// at its chart and the error map's heat map, activate a profile version and roll back.
// Every wait is a Playwright wait on the DOM (no sleeps).
//
// Usage: node drive_page.js BASE_URL TOKEN MACHINE KIND PARAMS_JSON SCREENSHOT USER_DATA_DIR [CHARTS]
//   CHARTS: "required" (default: the finished job must show a chart that loads) or
//   "optional" (a job kind that draws none; the chart list is still checked if present).
// Prints one JSON object with what it saw; exit status 1 (with {"ok": false, "why"})
// on any failure.
'use strict';
const path = require('path');
const { chromium } = require(path.join(__dirname, 'node_modules', 'playwright-core'));

const [base, token, machine, kind, paramsJson, screenshot, userDataDir, chartsArg, walksArg] = process.argv.slice(2);
// WALKS (optional JSON): {"queue": {"long": PARAMS, "short": PARAMS, "kind": KIND}} walks a
// machine's queue (up, down, cancel) while a long job runs; {"kinds": ...} starts every
// job kind from its form (kindsWalk).
// The walks as JSON, or `@FILE` holding it (uploads of pictures and campaigns pass the
// size of one command-line argument).
const walks = walksArg ? JSON.parse(walksArg.startsWith('@') ? require('fs').readFileSync(walksArg.slice(1), 'utf8') : walksArg) : {};
const chartsRequired = (chartsArg || 'required') === 'required';
const JOB_TIMEOUT_MS = 180000;
const DESKTOP = { width: 1366, height: 900 };
const PHONE = { width: 390, height: 844 };
const AXE = path.join(__dirname, 'node_modules', 'axe-core', 'axe.min.js');

// The widest element of the page, px (at most the viewport's width when nothing spills).
function pageWidth(page) {
  return page.evaluate(() => Math.max(document.documentElement.scrollWidth, document.body.scrollWidth));
}

// axe-core on the page as it is: the serious and critical violations, each with the
// elements it found. (Evaluated through the DevTools protocol, which the page's
// Content-Security-Policy does not apply to.)
async function axeCheck(page, view) {
  if (!(await page.evaluate(() => typeof window.axe !== 'undefined'))) {
    await page.evaluate(require('fs').readFileSync(AXE, 'utf8'));
  }
  const result = await page.evaluate(() => window.axe.run(document, { resultTypes: ['violations'] }));
  return result.violations.filter((v) => v.impact === 'serious' || v.impact === 'critical')
    .map((v) => ({ view, id: v.id, impact: v.impact, nodes: v.nodes.map((n) => n.target.join(' ')).slice(0, 5) }));
}
const UI_TIMEOUT_MS = 20000;
const out = { ok: false, steps: [] };

// The test runs the service: `ask("stop")` has it shut the service down (as SIGTERM
// does) and `ask("start")` start it again on the same port and data; each answers a line
// on stdin once done.
const asked = [];
require('readline').createInterface({ input: process.stdin })
  .on('line', (line) => { const answer = asked.shift(); if (answer) answer(line); });
function ask(what) {
  return new Promise((resolve) => {
    asked.push(resolve);
    process.stdout.write(JSON.stringify({ ask: what }) + '\n');
  });
}

// What the page says while the service is down and after it is back, with the job it
// was running: not live (actions disabled, no time left), then the job as the service
// recorded it and, for a stopped scan, a Resume that measures only what is missing.
async function restartWalk(page, spec) {
  const result = {};
  const id = await submitForm(page, 'map', spec.params);
  result.job = id;
  await page.locator(`#running-jobs li[data-job-id="${id}"] progress:not([data-done="0"])`)
    .waitFor({ timeout: JOB_TIMEOUT_MS });
  await page.click(`button.show-job[data-job-id="${id}"]`);
  await page.locator(`#job-detail[data-job-id="${id}"][data-state="running"]`).waitFor({ timeout: UI_TIMEOUT_MS });
  if (await ask('stop') !== 'stopped') throw new Error('the service did not stop');
  await page.locator('body[data-live="false"]').waitFor({ timeout: UI_TIMEOUT_MS });
  result.down = await page.evaluate(() => ({
    stale_shown: !document.getElementById('stale').hidden,
    connection: document.getElementById('connection').textContent,
    actions_disabled: [...document.querySelectorAll('button.live-action')].every((b) => b.disabled),
    actions: document.querySelectorAll('button.live-action').length,
    progress: [...document.querySelectorAll('.running-progress-text')].map((p) => p.textContent),
  }));
  await page.screenshot({ path: path.join(spec.screenshots, 'restart-down-1366.png'), fullPage: true });
  await page.setViewportSize(PHONE);
  await page.screenshot({ path: path.join(spec.screenshots, 'restart-down-390.png'), fullPage: true });
  await page.setViewportSize(DESKTOP);
  if (await ask('start') !== 'started') throw new Error('the service did not start again');
  // Back: live once the service has said what happened (the reconnect backs off up to 10 s).
  await page.locator('body[data-live="true"]').waitFor({ timeout: 60000 });
  await page.locator(`#job-detail[data-job-id="${id}"]:not([data-state="running"])`).waitFor({ timeout: UI_TIMEOUT_MS });
  result.after = await page.evaluate((jobId) => ({
    state: document.getElementById('job-detail').dataset.state,
    row_state: document.querySelector(`#history-rows tr[data-job-id="${jobId}"]`).dataset.state,
    next: document.getElementById('job-next').textContent,
    running: document.querySelectorAll('#running-jobs li').length,
    frames: document.querySelectorAll('figure.live-frame').length,
  }), id);
  await page.screenshot({ path: path.join(spec.screenshots, 'restart-after-1366.png'), fullPage: true });
  await page.setViewportSize(PHONE);
  await page.screenshot({ path: path.join(spec.screenshots, 'restart-after-390.png'), fullPage: true });
  await page.setViewportSize(DESKTOP);
  // Resume: the same scan queued again; it copies the frames measured and ends.
  const before = await page.$$eval('#history-rows tr[data-job-id]', (rows) =>
    rows.reduce((max, row) => Math.max(max, Number(row.dataset.jobId)), 0));
  await page.click('#job-next button.resume-job');
  const handle = await page.waitForFunction((earlier) => {
    const row = document.querySelector('#history-rows tr[data-job-id]');
    return row && Number(row.dataset.jobId) > earlier ? Number(row.dataset.jobId) : null;
  }, before, { timeout: UI_TIMEOUT_MS });
  const resumed = await handle.jsonValue();
  await page.locator(`#history-rows tr[data-job-id="${resumed}"][data-state="succeeded"]`).waitFor({ timeout: JOB_TIMEOUT_MS });
  result.resumed = await page.evaluate(async ([jobId, t]) => {
    const job = await (await fetch('/api/v1/jobs/' + jobId, { headers: { Authorization: 'Bearer ' + t } })).json();
    return { id: jobId, state: job.state, resumed_frames: job.result.resumed_frames, resumed_from_job: job.result.resumed_from_job };
  }, [resumed, token]);
  step('restart walked', result);
  return result;
}

function step(name, detail) {
  out.steps.push(detail === undefined ? name : { [name]: detail });
}

async function startJob(page) {
  const before = await page.$$eval('#history-rows tr[data-job-id]', (rows) =>
    rows.reduce((max, row) => Math.max(max, Number(row.dataset.jobId)), 0));
  await page.selectOption('#job-machine', machine);
  await page.selectOption('#job-kind', kind);
  // The form is built from the API's schema of the kind: one input per param.
  for (const [name, value] of Object.entries(JSON.parse(paramsJson))) {
    await page.fill(`#job-fields [data-field-input="${name}"]`, String(value));
  }
  await page.click('#start-job');
  // The new job is the newest row, with an id above every earlier one.
  const handle = await page.waitForFunction((earlier) => {
    const row = document.querySelector('#history-rows tr[data-job-id]');
    return row && Number(row.dataset.jobId) > earlier ? Number(row.dataset.jobId) : null;
  }, before, { timeout: UI_TIMEOUT_MS });
  const id = await handle.jsonValue();
  step('started', id);
  // Live progress over the WebSocket: at least one progress event for this job, counted
  // by the page on its history row (kept after the job ends, so a fast job is not missed).
  await page.locator(`#history-rows tr[data-job-id="${id}"]:not([data-live-progress="0"])`)
    .waitFor({ timeout: JOB_TIMEOUT_MS });
  step('live progress');
  const finished = page.locator(`#history-rows tr[data-job-id="${id}"]`)
    .and(page.locator('[data-state="succeeded"], [data-state="failed"], [data-state="cancelled"], [data-state="interrupted"]'));
  await finished.waitFor({ timeout: JOB_TIMEOUT_MS });
  const state = await finished.getAttribute('data-state');
  step('finished', state);
  if (state !== 'succeeded') throw new Error(`job ${id} ended ${state}`);
  return id;
}

// Fills the start form (every param of `params`; a param given as null is emptied, the
// API's default) and submits it; returns the id of the queued job (the newest row).
async function submitForm(page, formKind, params, onMachine = machine) {
  const before = await page.$$eval('#history-rows tr[data-job-id]', (rows) =>
    rows.reduce((max, row) => Math.max(max, Number(row.dataset.jobId)), 0));
  await page.selectOption('#job-machine', onMachine);
  await page.selectOption('#job-kind', formKind);
  for (const [name, value] of Object.entries(params)) {
    const input = page.locator(`#job-fields [data-field-input="${name}"]`);
    const [tag, type] = await input.evaluate((e) => [e.tagName, e.type]);
    if (tag === 'SELECT') await input.selectOption(String(value));
    else if (type === 'checkbox') await input.setChecked(Boolean(value));
    else if (type === 'file') {
      // `{name, text}`, or a picture as `{name, base64}`.
      const picture = value.base64 !== undefined;
      await input.setInputFiles({ name: value.name, mimeType: picture ? 'image/png' : 'text/plain',
        buffer: picture ? Buffer.from(value.base64, 'base64') : Buffer.from(value.text) });
    } else await input.fill(value === null ? '' : String(value));
  }
  await page.click('#start-job');
  const handle = await page.waitForFunction((earlier) => {
    const row = document.querySelector('#history-rows tr[data-job-id]');
    return row && Number(row.dataset.jobId) > earlier ? Number(row.dataset.jobId) : null;
  }, before, { timeout: UI_TIMEOUT_MS });
  return handle.jsonValue();
}

// The machine's queue as the page shows it, in run order.
function queueOrder(page) {
  return page.$$eval(`#machines ol.machine-queue[data-machine="${machine}"] li.queued-job`,
    (items) => items.map((li) => Number(li.dataset.jobId)));
}

async function waitQueue(page, ids) {
  await page.waitForFunction(([m, want]) => {
    const got = [...document.querySelectorAll(`#machines ol.machine-queue[data-machine="${m}"] li.queued-job`)]
      .map((li) => Number(li.dataset.jobId));
    return got.join() === want.join();
  }, [machine, ids], { timeout: UI_TIMEOUT_MS });
}

// A long job runs; three short ones wait. Down, Up and Cancel in the machine's queue
// reorder it; the running job is cancelled and the rest run in the queue's order.
async function queueWalk(page, spec) {
  const result = {};
  const queueItem = (id) => page.locator(`#machines li.queued-job[data-job-id="${id}"]`);
  const long = await submitForm(page, spec.kind, spec.long);
  await page.locator(`#running-jobs li[data-job-id="${long}"]`).waitFor({ timeout: JOB_TIMEOUT_MS });
  // The tab reopened mid-job: the machine's picture is a frame of the job it runs now
  // (never one of the earlier job), with the dots and the measured point drawn over it.
  await page.reload();
  await page.locator('body[data-live="true"]').waitFor({ timeout: UI_TIMEOUT_MS });
  await page.locator(`#running-jobs li[data-job-id="${long}"]`).waitFor({ timeout: UI_TIMEOUT_MS });
  const frameSel = `#machines li[data-machine="${machine}"] figure.live-frame[data-job-id="${long}"]`;
  await page.waitForFunction((sel) => {
    const img = document.querySelector(sel + ' img.frame-image');
    return img && img.complete && img.naturalWidth > 0
      && document.querySelectorAll(sel + ' svg.frame-overlay circle.frame-dot').length > 0;
  }, frameSel, { timeout: JOB_TIMEOUT_MS });
  out.frame = await page.$eval(frameSel, (f) => ({
    width: f.querySelector('img').naturalWidth,
    height: f.querySelector('img').naturalHeight,
    dots: f.querySelectorAll('svg.frame-overlay circle.frame-dot').length,
    centre: f.querySelectorAll('svg.frame-overlay .frame-centre').length > 0,
    caption: f.querySelector('figcaption').textContent,
  }));
  out.frame.jobs_shown = await page.$$eval('#machines figure.live-frame', (fs) => fs.map((f) => Number(f.dataset.jobId)));
  out.frame.running_job = long;
  step('frame shown after reopening', out.frame);
  const short = [];
  for (let i = 0; i < 3; i++) short.push(await submitForm(page, spec.kind, spec.short));
  await waitQueue(page, short);
  result.queued = await queueOrder(page);
  const [a, b, c] = short;
  await queueItem(a).locator('button.queue-down').click();
  await waitQueue(page, [b, a, c]);
  await queueItem(c).locator('button.queue-up').click();
  await waitQueue(page, [b, c, a]);
  result.after_moves = await queueOrder(page);
  await queueItem(a).locator('button.queue-cancel').click();
  await waitQueue(page, [b, c]);
  await page.locator(`#history-rows tr[data-job-id="${a}"][data-state="cancelled"]`).waitFor({ timeout: UI_TIMEOUT_MS });
  result.after_cancel = await queueOrder(page);
  await page.locator(`#running-jobs li[data-job-id="${long}"] button.cancel-running`).click();
  await page.locator(`#history-rows tr[data-job-id="${long}"][data-state="cancelled"]`).waitFor({ timeout: JOB_TIMEOUT_MS });
  // Its frame went with it (the next job's, if any, is that job's).
  await page.locator(`figure.live-frame[data-job-id="${long}"]`).waitFor({ state: 'detached', timeout: UI_TIMEOUT_MS });
  out.frame.dropped_after_end = true;
  for (const id of [b, c]) {
    await page.locator(`#history-rows tr[data-job-id="${id}"][data-state="succeeded"]`).waitFor({ timeout: JOB_TIMEOUT_MS });
  }
  await waitQueue(page, []);
  // The order they ran in, from their records.
  const started = await page.evaluate(async ([ids, t]) => Promise.all(ids.map((id) =>
    fetch('/api/v1/jobs/' + id, { headers: { Authorization: 'Bearer ' + t } })
      .then((r) => r.json()).then((j) => ({ id, started_at: j.started_at })))), [[b, c], token]);
  result.run_order = started.sort((x, y) => x.started_at.localeCompare(y.started_at)).map((j) => j.id);
  result.expected_run_order = [b, c];
  result.long = long;
  step('queue walked', result);
  return result;
}

// Every job kind started from its form: the job succeeds, its detail shows its result
// table and (when the kind draws one) its chart, and a screenshot is kept per kind.
// spec: {"screenshots": DIR, "jobs": [{"kind", "params", "chart": bool, "activate": NAME}]}
// What a chart (an SVG of the API, fetched with the token) puts where, measured by the
// browser's own layout of it (getBBox, in the SVG's pixels):
// - legend: its entries (texts of "mean up/down" and the bands' line, each with the 30 px
//   line sample on its left), how many data points (circles) any entry covers, and
//   whether every entry is inside the picture;
// - heat map: its arrows (strokes #141414) outside the plot (the union of the cells, the
//   colour bar's 90 px strip on the right left out), the arrow-length scale's arrows and
//   text in that strip, and the numbers written at the colour bar's top and bottom;
// - units: the axis titles that carry a unit in brackets or after a comma.
async function chartGeometry(page, url) {
  return page.evaluate(async ([url, t]) => {
    const response = await fetch(url, { headers: { Authorization: 'Bearer ' + t } });
    const text = await response.text();
    if (!response.ok || !/<svg[\s>]/.test(text)) {
      throw new Error(`${url} answered ${response.status} ${response.headers.get('content-type')}, not an SVG: ${text.slice(0, 300)}`);
    }
    const holder = document.createElement('div');
    holder.style.position = 'absolute';
    holder.style.visibility = 'hidden';
    holder.innerHTML = text;
    document.body.append(holder);
    try {
      const svg = holder.querySelector('svg');
      const W = svg.width.baseVal.value;
      const H = svg.height.baseVal.value;
      const box = (e) => { const b = e.getBBox(); return { x: b.x, y: b.y, w: b.width, h: b.height }; };
      const hit = (a, b) => a.x < b.x + b.w && b.x < a.x + a.w && a.y < b.y + b.h && b.y < a.y + a.h;
      const inside = (a, b, slack) => a.x >= b.x - slack && a.y >= b.y - slack &&
        a.x + a.w <= b.x + b.w + slack && a.y + a.h <= b.y + b.h + slack;
      const texts = [...svg.querySelectorAll('text')].map((e) => ({ ...box(e), text: e.textContent.trim() }));
      const result = { width: W, height: H };
      result.units = texts.filter((e) => /\((mm|µm)\)$|, µm$/.test(e.text)).map((e) => e.text);
      const legend = texts.filter((e) => /mean (up|down)|^thin lines/.test(e.text))
        .map((e) => ({ x: e.x - 30, y: e.y, w: e.w + 30, h: e.h }));
      const points = [...svg.querySelectorAll('circle')].map(box);
      result.legend = {
        entries: legend.length,
        points: points.length,
        covered: points.filter((p) => legend.some((l) => hit(l, p))).length,
        inside: legend.every((l) => inside(l, { x: 0, y: 0, w: W, h: H }, 0)),
      };
      const strip = W - 90;
      const rects = [...svg.querySelectorAll('rect')].map(box).filter((r) => r.w < W || r.h < H);
      const cells = rects.filter((r) => r.x + r.w <= strip + 0.5);
      const bar = rects.filter((r) => r.x >= strip);
      if (cells.length && bar.length) {
        const union = (bs) => {
          const x = Math.min(...bs.map((b) => b.x)); const y = Math.min(...bs.map((b) => b.y));
          return { x, y, w: Math.max(...bs.map((b) => b.x + b.w)) - x, h: Math.max(...bs.map((b) => b.y + b.h)) - y };
        };
        const plot = union(cells);
        const strokes = [...svg.querySelectorAll('[stroke="#141414"]')].map(box);
        const arrows = strokes.filter((a) => a.x < strip);
        const barBox = union(bar);
        const near = (y) => texts.filter((e) => e.x >= barBox.x + barBox.w - 1 && Math.abs(e.y + e.h / 2 - y) <= 12)
          .map((e) => e.text);
        result.heatmap = {
          arrows: arrows.length,
          arrows_outside_plot: arrows.filter((a) => !inside(a, plot, 0.5)).length,
          scale_arrow: strokes.length - arrows.length,
          scale_text: (texts.find((e) => /^arrow [0-9.]+ µm$/.test(e.text)) || {}).text || null,
          bar_top: near(barBox.y),
          bar_bottom: near(barBox.y + barBox.h),
        };
      }
      return result;
    } finally {
      holder.remove();
    }
  }, [url, token]);
}

async function kindsWalk(page, spec) {
  const results = [];
  for (const job of spec.jobs) {
    // The fields the form offers for this kind, as an operator sees them.
    await page.selectOption('#job-kind', job.kind);
    const fields = await page.$$eval('#job-fields [data-field]', (els) => els.map((e) => e.dataset.field));
    const id = await submitForm(page, job.kind, job.params, job.machine || machine);
    if (job.sender) {
      // The pass-through's port, from the job's first measurement; the test's sender
      // then runs a session through it.
      // Its measurement events, subscribed before the measurements so far are read: the
      // port is in one or the other, with no wait on the clock.
      const port = await page.evaluate(([jobId, t]) => new Promise((resolve, reject) => {
        const scheme = location.protocol === 'https:' ? 'wss:' : 'ws:';
        const ws = new WebSocket(`${scheme}//${location.host}/api/v1/events`, ['gateway.v1', 'bearer.' + t]);
        const found = (m) => { if (m && m.sender_port) { ws.close(); resolve(m.sender_port); } };
        ws.onmessage = (e) => {
          const ev = JSON.parse(e.data);
          if (ev.type === 'measurement' && ev.job_id === jobId) found(ev.measurement);
        };
        ws.onerror = () => reject(new Error('the event stream failed'));
        ws.onopen = async () => {
          const r = await fetch(`/api/v1/jobs/${jobId}/measurements`, { headers: { Authorization: 'Bearer ' + t } });
          for (const m of await r.json()) found(m);
        };
      }), [id, token]);
      if (await ask('sender ' + port) !== 'sent') throw new Error('the sender did not run');
    }
    const row = page.locator(`#history-rows tr[data-job-id="${id}"]`);
    await row.and(page.locator('[data-state="succeeded"], [data-state="failed"], [data-state="cancelled"]'))
      .waitFor({ timeout: JOB_TIMEOUT_MS });
    const state = await row.getAttribute('data-state');
    const seen = { kind: job.kind, id, state, fields };
    results.push(seen);
    if (state !== 'succeeded') {
      await page.click(`button.show-job[data-job-id="${id}"]`);
      await page.locator(`#job-detail[data-job-id="${id}"]`).waitFor({ timeout: UI_TIMEOUT_MS });
      seen.summary = await page.locator('#job-summary').textContent();
      throw new Error(`${job.kind} job ${id} ended ${state}: ${seen.summary}`);
    }
    await page.click(`button.show-job[data-job-id="${id}"]`);
    await page.locator(`#job-detail[data-job-id="${id}"][data-state="succeeded"]`).waitFor({ timeout: UI_TIMEOUT_MS });
    await page.locator('#job-result table[data-result]').waitFor({ timeout: UI_TIMEOUT_MS });
    seen.table = await page.locator('#job-result table[data-result]').getAttribute('data-result');
    seen.table_rows = await page.locator('#job-result table[data-result] tbody tr').count();
    if (job.chart) {
      await page.waitForFunction(() => {
        const imgs = [...document.querySelectorAll('#job-charts img[data-chart]')];
        return imgs.length > 0 && imgs.every((img) => img.complete && img.naturalWidth > 0);
      }, null, { timeout: UI_TIMEOUT_MS });
    }
    seen.charts = await page.$$eval('#job-charts img[data-chart]', (imgs) => imgs.map((i) => i.dataset.chart));
    seen.chart_geometry = {};
    for (const name of seen.charts) {
      seen.chart_geometry[name] = await chartGeometry(page,
        `/api/v1/jobs/${id}/charts/${encodeURIComponent(name)}.svg`);
    }
    seen.raw_collapsed = await page.$eval('#job-raw', (d) => !d.open);
    // The raw record is only under the developer view.
    seen.raw_hidden = await page.$eval('#job-raw', (d) => getComputedStyle(d).display === 'none');
    seen.summary = await page.locator('#job-summary').textContent();
    // What the form sent, as the service stored it (a decimal comma read exactly).
    seen.params = await page.evaluate(async ([jobId, t]) =>
      (await (await fetch('/api/v1/jobs/' + jobId, { headers: { Authorization: 'Bearer ' + t } })).json()).params,
    [id, token]);
    delete seen.params.layout;
    seen.screenshot = path.join(spec.screenshots, `job-${job.kind}.png`);
    await page.screenshot({ path: seen.screenshot, fullPage: true });
    // The same job on a phone: nothing wider than the screen.
    await page.setViewportSize(PHONE);
    seen.phone_width = await pageWidth(page);
    seen.phone_screenshot = path.join(spec.screenshots, `job-${job.kind}-390.png`);
    await page.locator('#job-detail').screenshot({ path: seen.phone_screenshot });
    await page.setViewportSize(DESKTOP);
    if (job.activate) {
      // The map the next jobs use: its newest version, activated as an operator would.
      await page.selectOption('#profile-machine', machine);
      const rows = page.locator(`#profile-rows tr[data-profile="${job.activate}"]`);
      await rows.first().waitFor({ timeout: UI_TIMEOUT_MS });
      const version = Math.max(...await rows.evaluateAll((r) => r.map((x) => Number(x.dataset.version))));
      await page.locator(`#profile-rows tr[data-profile="${job.activate}"][data-version="${version}"] button.activate`).click();
      await page.locator(`#profile-rows tr[data-profile="${job.activate}"][data-version="${version}"][data-active="true"]`)
        .waitFor({ timeout: UI_TIMEOUT_MS });
      seen.activated = version;
      // Its heat map as the page shows it (drawn from the map).
      seen.heatmap_geometry = await chartGeometry(page, `/api/v1/machines/${encodeURIComponent(machine)}` +
        `/profiles/${encodeURIComponent(job.activate)}/${version}/heatmap.svg`);
    }
    step('kind walked', { kind: job.kind, id });
  }
  return results;
}

// The start form as an operator meets it (the service's schemas): a decimal comma read
// exactly, the API's own refusal beside its field, and wrong uploads refused.
async function formWalk(page) {
    // A decimal comma is read exactly; the API's own refusal (here: the scan plan's
    // frames past their bound) is shown beside the field it names, in the page's words.
    await page.fill('#field-line_step_mm', '0,05');
    await page.fill('#field-passes', '10');
    await page.fill('#field-tool_offset_mm', '0; 0');
    await page.fill('#field-grid_step_mm', '0,25');
    await page.click('#start-job');
    const apiError = page.locator('#form-errors li');
    await apiError.first().waitFor({ timeout: UI_TIMEOUT_MS });
    out.api_field_errors = await page.$$eval('.field-error:not(:empty)', (spans) =>
      Object.fromEntries(spans.map((s) => [s.dataset.fieldError, s.textContent])));
    if (await page.locator('#history-rows tr[data-job-id]').count() !== 0) {
      throw new Error('a form the API refused started a job');
    }
    for (const [field, value] of [['grid_step_mm', ''], ['line_step_mm', ''], ['passes', ''], ['tool_offset_mm', '0; 0']]) {
      await page.fill(`[id="field-${field}"]`, value);
    }

    // Uploads: a picture is refused when chosen; a JSON that is no layout and a broken
    // DXF are refused by the service's layout reader when the job is queued, its
    // message beside the file field; nothing starts.
    await page.selectOption('#job-kind', 'layout');
    const png = Buffer.from('89504e470d0a1a0a0000000d49484452', 'hex');
    await page.locator('#field-layout').setInputFiles({ name: 'photo.png', mimeType: 'image/png', buffer: png });
    await page.locator('[data-field-error="layout"]:not(:empty)').waitFor({ timeout: UI_TIMEOUT_MS });
    out.upload_errors = { png: await page.locator('[data-field-error="layout"]').textContent() };
    await page.fill('#field-tools', '2');
    await page.fill('#field-window_mm', '25');
    await page.fill('#field-gap_mm', '2');
    for (const [label, name, text] of [['json', 'settings.json', '{"hello": 1}'],
      ['dxf', 'broken.dxf', '0\nSECTION\n2\nENTITIES\n0\nLINE\n10\nnot-a-number\n']]) {
      await page.locator('#field-layout').setInputFiles({ name, mimeType: 'text/plain', buffer: Buffer.from(text) });
      await page.waitForFunction(() => !document.querySelector('[data-field-error="layout"]').textContent);
      await page.click('#start-job');
      await page.locator('[data-field-error="layout"]:not(:empty)').waitFor({ timeout: UI_TIMEOUT_MS });
      out.upload_errors[label] = await page.locator('[data-field-error="layout"]').textContent();
    }
    if (await page.locator('#history-rows tr[data-job-id]').count() !== 0) {
      throw new Error('a refused upload started a job');
    }
    step('uploads refused', out.upload_errors);

    // Every other form (each registered kind the page offers): a word in each of its
    // number fields, then Start: every one of them is refused at once, beside its field
    // and in the list above Start, and nothing is queued.
    out.other_forms = [];
    const kinds = await page.$$eval('#job-kind option', (options) => options.map((o) => o.value));
    for (const kind of kinds.filter((k) => k !== 'map')) {
      await page.selectOption('#job-kind', kind);
      const numbers = await page.$$eval('#job-fields input[inputmode="numeric"], #job-fields input[inputmode="decimal"]',
        (inputs) => inputs.map((i) => i.dataset.fieldInput));
      if (numbers.length === 0) continue;
      for (const name of numbers) await page.fill(`[id="field-${name}"]`, 'many');
      await page.click('#start-job');
      await page.locator('#form-errors li').first().waitFor({ timeout: UI_TIMEOUT_MS });
      out.other_forms.push({
        kind,
        bad: numbers,
        marked: await page.$$eval('.field-error:not(:empty)', (spans) => spans.map((s) => s.dataset.fieldError)),
        listed: await page.locator('#form-errors li').count(),
      });
    }
    if (await page.locator('#history-rows tr[data-job-id]').count() !== 0) {
      throw new Error('a form with bad values started a job');
    }
    step('other forms refused', out.other_forms.map((f) => f.kind));
    await page.selectOption('#job-kind', 'map');

}

async function main() {
  const context = await chromium.launchPersistentContext(userDataDir, {
    executablePath: '/usr/bin/chromium',
    headless: true,
    args: ['--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
      '--disable-background-networking', '--disable-component-update', '--disable-sync',
      // HTTPS with the box's self-signed certificate: only its public key is trusted (the
      // pin the service logs), as an operator who checked its fingerprint would.
      ...(walks.spki ? [`--ignore-certificate-errors-spki-list=${walks.spki}`] : [])],
    viewport: DESKTOP,
  });
  const page = context.pages()[0] || await context.newPage();
  const pageErrors = [];
  page.on('pageerror', (error) => pageErrors.push(String(error)));
  out.tls = {};
  page.on('websocket', (ws) => { out.tls.socket = out.tls.socket || new URL(ws.url()).protocol; });
  // Activation asks the operator first; the question is kept to check it names the machine.
  out.dialogs = [];
  page.on('dialog', (dialog) => { out.dialogs.push(dialog.message()); dialog.accept(); });
  // Anything the service's Content-Security-Policy blocked is an error of the page.
  page.on('console', (message) => {
    if (message.type() === 'error' && /Content Security Policy/i.test(message.text())) {
      pageErrors.push('CSP: ' + message.text());
    }
  });
  try {
    // Without a token the page asks for one; a wrong one is refused with a message.
    await page.goto(`${base}/`);
    await page.locator('#login:not([hidden])').waitFor({ timeout: UI_TIMEOUT_MS });
    await page.fill('#token-input', 'not-the-token');
    await page.click('#login-button');
    await page.locator('#login-error:text("refused")').waitFor({ timeout: UI_TIMEOUT_MS });
    step('wrong token refused');
    out.axe = await axeCheck(page, 'sign-in');
    await page.goto(`${base}/#token=${encodeURIComponent(token)}`);
    await page.locator('#connection[data-state="open"]').waitFor({ timeout: UI_TIMEOUT_MS });
    // The token left the address bar and sits in sessionStorage.
    out.url_after_load = page.url();
    out.tls.protocol = await page.evaluate(() => location.protocol);
    out.tls.secure_context = await page.evaluate(() => window.isSecureContext);
    if (page.url().includes(token)) throw new Error('the token is still in the address bar');
    if (await page.evaluate(() => sessionStorage.getItem('gateway.token')) !== token) {
      throw new Error('the token is not in sessionStorage');
    }
    const machineRow = page.locator(`#machines li[data-machine="${machine}"]`);
    await machineRow.waitFor({ timeout: UI_TIMEOUT_MS });
    out.machine_state_before = await machineRow.getAttribute('data-state');

    // The start form: built from the API's schema (a field per param, with its range).
    // Every field is read as typed and checked before anything is queued: a too-fine
    // grid, a word and a fraction where whole numbers go are all refused at once, each
    // beside its field, and nothing starts.
    await page.selectOption('#job-machine', machine);
    await page.selectOption('#job-kind', 'map');
    const gridHelp = await page.locator('#field-grid_step_mm-help').textContent();
    if (!gridHelp.includes('between 0.25 and')) throw new Error(`map form: grid_step_mm help is "${gridHelp}"`);
    out.form_fields = await page.$$eval('#job-fields .field', (rows) => rows.map((r) => r.dataset.field));
    await page.fill('#field-grid_step_mm', '0.01');
    if (walks.form) {
      await page.fill('#field-line_step_mm', 'fine');
      await page.fill('#field-passes', '2,5');
      await page.fill('#field-tool_offset_mm', '1,250');
    }
    await page.click('#start-job');
    const fieldError = page.locator('[data-field-error="grid_step_mm"]:not(:empty)');
    await fieldError.waitFor({ timeout: UI_TIMEOUT_MS });
    out.field_error = await fieldError.textContent();
    out.field_errors = await page.$$eval('.field-error:not(:empty)', (spans) =>
      Object.fromEntries(spans.map((s) => [s.dataset.fieldError, s.textContent])));
    out.form_errors_listed = await page.locator('#form-errors li').count();
    out.axe.push(...await axeCheck(page, 'form with errors'));
    await page.setViewportSize(PHONE);
    out.phone_form_width = await pageWidth(page);
    await page.locator('#start-form').screenshot({ path: screenshot.replace(/\.png$/, '-form-errors-390.png') });
    await page.setViewportSize(DESKTOP);
    if (await page.locator('#history-rows tr[data-job-id]').count() !== 0) {
      throw new Error('a refused form started a job');
    }
    step('field errors shown', out.field_errors);
    if (walks.form) await formWalk(page);
    await page.fill('#field-grid_step_mm', ''); // back to the API's default
    const jobId = await startJob(page);
    out.job_id = jobId;
    await page.locator(`#machines li[data-machine="${machine}"][data-state="idle"]`)
      .waitFor({ timeout: UI_TIMEOUT_MS });
    out.machine_state_after = 'idle';

    // The job's detail: a chart (an SVG that loaded) and its measurements.
    await page.click(`button.show-job[data-job-id="${jobId}"]`);
    await page.locator(`#job-detail[data-job-id="${jobId}"]`).waitFor({ timeout: UI_TIMEOUT_MS });
    // Charts and measurements arrive together; wait for the measurement count first.
    await page.locator('#job-measurement-count[data-count]').waitFor({ timeout: UI_TIMEOUT_MS });
    const chart = page.locator('#job-charts img[data-chart]').first();
    if (chartsRequired || await chart.count() > 0) {
      await chart.waitFor({ timeout: UI_TIMEOUT_MS });
      await page.waitForFunction(() => {
        const img = document.querySelector('#job-charts img[data-chart]');
        return img && img.complete && img.naturalWidth > 0;
      }, null, { timeout: UI_TIMEOUT_MS });
      out.chart = await chart.getAttribute('data-chart');
    } else {
      out.chart = null;
    }
    out.job_detail_state = await page.locator('#job-detail').getAttribute('data-state');
    out.job_summary = await page.locator('#job-summary').textContent();
    out.measurements = Number(await page.locator('#job-measurement-count').getAttribute('data-count'));

    // Profiles: two versions of one error map are needed for activate/rollback; a
    // second job of the same kind makes the second version.
    const mapRows = page.locator('#profile-rows tr[data-kind="error_map"]');
    await mapRows.first().waitFor({ timeout: UI_TIMEOUT_MS });
    if (await mapRows.count() < 2) await startJob(page);
    await page.waitForFunction(() =>
      document.querySelectorAll('#profile-rows tr[data-kind="error_map"]').length >= 2,
    null, { timeout: UI_TIMEOUT_MS });
    const profiles = await mapRows.evaluateAll((rows) =>
      rows.map((r) => ({ name: r.dataset.profile, version: Number(r.dataset.version), active: r.dataset.active === 'true' })));
    const name = profiles[0].name;
    const versions = profiles.filter((p) => p.name === name).map((p) => p.version).sort((a, b) => a - b);
    if (versions.length < 2) throw new Error(`profile ${name} has only versions ${versions}`);
    const [older, newer] = versions.slice(-2);
    const row = (v) => page.locator(`#profile-rows tr[data-profile="${name}"][data-version="${v}"]`);
    const activeRow = (v) => page.locator(`#profile-rows tr[data-profile="${name}"][data-version="${v}"][data-active="true"]`);

    // What changed from the older version to the newer one.
    await row(newer).locator('button.show-diff').click();
    await page.locator(`#profile-diff[data-version="${newer}"]`).waitFor({ timeout: UI_TIMEOUT_MS });
    out.diff = await page.locator('#profile-diff').textContent();
    await row(newer).locator('button.activate').click();
    await activeRow(newer).waitFor({ timeout: UI_TIMEOUT_MS });
    await row(older).locator('button.activate').click();
    await activeRow(older).waitFor({ timeout: UI_TIMEOUT_MS });
    step('activated', [newer, older]);
    await row(older).locator('button.rollback').click();
    await activeRow(newer).waitFor({ timeout: UI_TIMEOUT_MS });
    out.rolled_back_to = newer;
    out.active_after_rollback = await page.$$eval(
      `#profile-rows tr[data-profile="${name}"][data-active="true"]`, (rows) => rows.map((r) => Number(r.dataset.version)));

    // The heat map of the active error map, an SVG that loaded.
    await page.locator(`#heatmap[data-profile="${name}"][data-version="${newer}"] img`).waitFor({ timeout: UI_TIMEOUT_MS });
    await page.waitForFunction(() => {
      const img = document.querySelector('#heatmap-image img');
      return img && img.complete && img.naturalWidth > 0;
    }, null, { timeout: UI_TIMEOUT_MS });
    out.heatmap = { profile: name, version: newer };

    if (walks.queue) out.queue = await queueWalk(page, walks.queue);
    if (walks.kinds) out.kinds = await kindsWalk(page, walks.kinds);
    if (walks.restart) out.restart = await restartWalk(page, walks.restart);
    // Which profile versions the page says jobs use (one per kind at most), and which
    // active versions it says are not in use.
    out.profile_rows = await page.$$eval('#profile-rows tr', (rows) => rows.map((r) => ({
      name: r.dataset.profile, version: Number(r.dataset.version), kind: r.dataset.kind,
      active: r.dataset.active === 'true', in_use: r.dataset.inUse === 'true',
      shown: r.querySelector('.profile-active').textContent,
      can_activate: !r.querySelector('button.activate').disabled })));

    // The whole page on a desktop and on a phone (nothing wider than the screen), and
    // axe-core on the views shown (the job detail, the profiles and their heat map).
    out.axe.push(...await axeCheck(page, 'page with a job shown'));
    out.widths = {};
    for (const [label, size] of [['1366', DESKTOP], ['390', PHONE]]) {
      await page.setViewportSize(size);
      out.widths[label] = await pageWidth(page);
      await page.screenshot({ path: screenshot.replace(/\.png$/, `-${label}.png`), fullPage: true });
    }
    out.axe.push(...await axeCheck(page, 'phone'));
    await page.setViewportSize(DESKTOP);
    out.page_errors = pageErrors;
    out.error_text = await page.locator('#error').textContent();
    await page.screenshot({ path: screenshot, fullPage: true });
    out.screenshot = screenshot;
    out.ok = pageErrors.length === 0;
    if (!out.ok) out.why = 'errors in the page: ' + pageErrors.join('; ');
  } catch (error) {
    out.why = String(error && error.message || error);
    out.page_errors = pageErrors;
    try { await page.screenshot({ path: screenshot, fullPage: true }); out.screenshot = screenshot; } catch (_) { /* best effort */ }
  } finally {
    await context.close();
  }
  report(out.ok ? 0 : 1);
}

// The report as the last line, exiting once it is written whole (a pipe takes 64 KiB
// at a time; process.exit would cut a longer line).
function report(code) {
  process.stdout.write(JSON.stringify(out) + '\n', () => process.exit(code));
}

main().catch((error) => {
  out.why = String(error && error.stack || error);
  report(1);
});
