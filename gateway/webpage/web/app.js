// The service's web page: plain JavaScript, no build step, no outside scripts.
// It codes against the HTTP API v1 and the /api/v1/events WebSocket (see the service
// contract in docs/service.md). Every element a test looks at has a stable id or data-*
// attribute: #machines li[data-machine][data-state], #running-jobs li[data-job-id][data-machine],
// #machines ol.machine-queue[data-machine] li.queued-job[data-job-id][data-position] (button.queue-up,
// .queue-down, .queue-cancel),
// #history-rows tr[data-job-id][data-state][data-live-progress] (progress events seen), #job-charts img[data-chart],
// #job-result table[data-result] (iso230-figures, verify-before-after, compensate-before-after, figures),
// #profile-rows tr[data-profile][data-version][data-active], #heatmap-image img,
// #machines li[data-machine] figure.live-frame[data-machine][data-job-id][data-dots] (img.frame-image,
// svg.frame-overlay circle.frame-dot, .frame-centre).
'use strict';

const TOKEN_KEY = 'gateway.token';
const FINAL_STATES = ['succeeded', 'failed', 'cancelled', 'interrupted'];

const view = {
  token: null,
  machines: new Map(),   // id -> Machine
  jobs: new Map(),       // id -> JobRecord (history)
  detailJob: null,       // id of the job shown in #job-detail
  socket: null,
  reconnectDelayMs: 500,
  objectUrls: [],
  liveProgress: new Map(), // job id -> progress events received (shown as data-live-progress)
  schemas: {}, // job kind -> its params' JSON schema (the start form)
  frames: new Map(), // machine id -> { url (blob: of the PNG), data (frame.json) }
  frameFetch: new Map(), // machine id -> 'busy' | 'again' (one fetch in flight; one more after it)
};

const $ = (id) => document.getElementById(id);

function el(tag, attributes, ...children) {
  const node = document.createElement(tag);
  for (const [key, value] of Object.entries(attributes || {})) {
    if (value === null || value === undefined) continue;
    if (key === 'text') node.textContent = value;
    else if (key.startsWith('on')) node.addEventListener(key.slice(2), value);
    else node.setAttribute(key, value);
  }
  for (const child of children) node.append(child);
  return node;
}

// ---- token: from the fragment (then removed from the address bar), sessionStorage, or the form

function takeToken() {
  const fragment = new URLSearchParams(location.hash.replace(/^#/, ''));
  const fromFragment = fragment.get('token');
  if (fromFragment) {
    sessionStorage.setItem(TOKEN_KEY, fromFragment);
    // The token must not stay in the address bar, the history or a bookmark.
    history.replaceState(null, '', location.pathname + location.search);
    return fromFragment;
  }
  return sessionStorage.getItem(TOKEN_KEY);
}

function showLogin(message) {
  view.token = null;
  sessionStorage.removeItem(TOKEN_KEY);
  if (view.socket) view.socket.close();
  $('app').hidden = true;
  $('login').hidden = false;
  $('login-error').textContent = message || '';
  $('token-input').focus();
}

// ---- HTTP

class ApiError extends Error {}

async function api(path, options) {
  const response = await fetch(path, {
    ...(options || {}),
    headers: { Authorization: 'Bearer ' + view.token, ...((options && options.headers) || {}) },
  });
  if (response.status === 401) {
    showLogin('The token was refused; enter a valid one.');
    throw new ApiError('unauthorized');
  }
  if (!response.ok) {
    let message = response.status + ' ' + response.statusText;
    try {
      const body = await response.json();
      message = (body.error ? body.error + ': ' : '') + (body.message || '');
    } catch (_) { /* not JSON */ }
    throw new ApiError(message);
  }
  const type = response.headers.get('content-type') || '';
  return type.includes('json') ? response.json() : response.text();
}

function post(path, body) {
  return api(path, {
    method: 'POST',
    headers: { 'Content-Type': 'application/json' },
    body: JSON.stringify(body || {}),
  });
}

function reportError(error) {
  if (error instanceof ApiError && error.message === 'unauthorized') return;
  // fetch() rejects with a TypeError when the box cannot be reached (not an API answer).
  view.networkError = error instanceof TypeError;
  $('error').textContent = view.networkError
    ? 'The box cannot be reached (' + error.message + '); reconnecting.'
    : String(error.message || error);
}

// An SVG fetched with the token, shown as an <img> (an <img src> cannot send headers).
async function svgImage(url, attributes) {
  const text = await api(url);
  const objectUrl = URL.createObjectURL(new Blob([text], { type: 'image/svg+xml' }));
  view.objectUrls.push(objectUrl);
  return el('img', { src: objectUrl, ...attributes });
}

function releaseImages() {
  for (const url of view.objectUrls) URL.revokeObjectURL(url);
  view.objectUrls = [];
}

// ---- machines and the running job

function renderMachines() {
  const list = $('machines');
  list.replaceChildren();
  for (const machine of view.machines.values()) {
    const detail = machine.state_detail ? ' (' + machine.state_detail + ')' : '';
    list.append(el('li', { 'data-machine': machine.id, 'data-state': machine.state },
      el('strong', { class: 'machine-name', text: machine.id }), ' ',
      el('span', { class: 'state machine-state', 'data-state': machine.state, text: machine.state }),
      el('span', { class: 'machine-detail', text: detail }),
      el('span', { class: 'machine-queued', 'data-queued': machine.queued, text: ' queued: ' + machine.queued }),
      el('div', { class: 'machine-description', text: machine.description || '' }),
      el('div', { class: 'machine-links', text: 'stage ' + machine.stage + ', camera ' + machine.camera
        + (machine.rotary ? ', A/C table ' + machine.rotary : '') }),
      renderQueue(machine),
      view.frames.has(machine.id) ? frameFigure(machine.id) : ''));
  }
  for (const select of [$('job-machine'), $('profile-machine')]) {
    const chosen = select.value;
    select.replaceChildren(...[...view.machines.keys()].map((id) => el('option', { value: id, text: id })));
    if (view.machines.has(chosen)) select.value = chosen;
  }
  renderKinds();
  renderRunning();
}

// ---- the camera's last frame per machine: the service's thumbnail with the detected
// dots and the measured point drawn over it (an SVG in the thumbnail's pixels)

function frameFigure(machineId) {
  const { url, data } = view.frames.get(machineId);
  const o = data.overlay;
  const figure = $('frame-template').content.firstElementChild.cloneNode(true);
  figure.setAttribute('data-machine', machineId);
  figure.setAttribute('data-job-id', data.job_id);
  figure.setAttribute('data-dots', o.dots.length);
  const img = figure.querySelector('img');
  img.src = url;
  img.width = o.width;
  img.height = o.height;
  img.alt = 'camera frame of ' + machineId;
  const svg = figure.querySelector('svg');
  // Pixel centres at integers: pixel i spans i - 0.5 .. i + 0.5.
  svg.setAttribute('viewBox', '-0.5 -0.5 ' + o.width + ' ' + o.height);
  const shape = (tag, attributes) => {
    const node = document.createElementNS(svg.namespaceURI, tag);
    for (const [key, value] of Object.entries(attributes)) node.setAttribute(key, value);
    svg.append(node);
  };
  for (const [x, y] of o.dots) shape('circle', { class: 'frame-dot', cx: x, cy: y, r: 2.5 });
  if (o.centre_px) {
    const [cx, cy] = o.centre_px;
    shape('line', { class: 'frame-centre', x1: cx - 8, y1: cy, x2: cx + 8, y2: cy });
    shape('line', { class: 'frame-centre', x1: cx, y1: cy - 8, x2: cx, y2: cy + 8 });
    shape('circle', { class: 'frame-centre', cx, cy, r: 3 });
  }
  const fixed = (v) => Number(v).toFixed(3);
  let caption = 'job ' + data.job_id + ', ' + o.dots.length + ' dots';
  if (o.centre_mm) caption += ', measured (' + fixed(o.centre_mm[0]) + ', ' + fixed(o.centre_mm[1]) + ') mm';
  if (o.deviation_um) caption += ', off target (' + o.deviation_um[0].toFixed(1) + ', ' + o.deviation_um[1].toFixed(1) + ') µm';
  caption += ', ' + (data.at || '').replace('T', ' ').replace('Z', ' UTC');
  figure.querySelector('figcaption').textContent = caption;
  return figure;
}

function showFrame(machineId) {
  const item = document.querySelector('#machines li[data-machine="' + machineId + '"]');
  if (!item) return;
  const figure = frameFigure(machineId);
  const old = item.querySelector('figure.live-frame');
  if (old) old.replaceWith(figure);
  else item.append(figure);
}

// At most one fetch in flight per machine: a frame event during it asks for one more
// after it (the newest then), the ones between are dropped.
async function loadFrame(machineId) {
  if (view.frameFetch.has(machineId)) {
    view.frameFetch.set(machineId, 'again');
    return;
  }
  view.frameFetch.set(machineId, 'busy');
  try {
    const base = '/api/v1/machines/' + encodeURIComponent(machineId) + '/frame';
    const data = await api(base + '.json');
    const response = await fetch(base, { headers: { Authorization: 'Bearer ' + view.token } });
    if (!response.ok) throw new ApiError(response.status + ' ' + response.statusText);
    const url = URL.createObjectURL(await response.blob());
    const previous = view.frames.get(machineId);
    view.frames.set(machineId, { url, data });
    showFrame(machineId);
    if (previous) URL.revokeObjectURL(previous.url);
  } catch (error) {
    // No frame yet is not an error of the page.
    if (!(error instanceof ApiError && error.message.startsWith('no_frame'))) reportError(error);
  } finally {
    const again = view.frameFetch.get(machineId) === 'again';
    view.frameFetch.delete(machineId);
    if (again) loadFrame(machineId);
  }
}

// A machine's queue in run order (the first runs next), each job with Up, Down and
// Cancel; the machine's event after a move or a cancel redraws it.
function renderQueue(machine) {
  const queue = machine.queue || [];
  const list = el('ol', { class: 'machine-queue', 'data-machine': machine.id, 'aria-label': 'Queue of ' + machine.id });
  queue.forEach((job, index) => {
    const move = (position) => post('/api/v1/jobs/' + job.id + '/move', { position }).catch(reportError);
    list.append(el('li', { class: 'queued-job', 'data-job-id': job.id, 'data-position': index },
      el('span', { class: 'queued-label', text: 'job ' + job.id + ' (' + job.kind + ') ' }),
      el('button', { type: 'button', class: 'queue-up', text: 'Up', disabled: index === 0 ? '' : null,
        'aria-label': 'Run job ' + job.id + ' earlier', onclick: () => move(index - 1) }), ' ',
      el('button', { type: 'button', class: 'queue-down', text: 'Down', disabled: index === queue.length - 1 ? '' : null,
        'aria-label': 'Run job ' + job.id + ' later', onclick: () => move(index + 1) }), ' ',
      el('button', { type: 'button', class: 'queue-cancel', text: 'Cancel', 'aria-label': 'Cancel job ' + job.id,
        onclick: () => post('/api/v1/jobs/' + job.id + '/cancel').then(upsertAndRender).catch(reportError) })));
  });
  if (machine.queued > queue.length) {
    list.append(el('li', { class: 'queue-more', text: (machine.queued - queue.length) + ' more queued' }));
  }
  return list;
}

// Every running job, one per busy machine, each with its progress, an estimate of the
// time left (from its start and its progress so far) and its cancel button.
function runningJobs() {
  const jobs = new Map();
  for (const machine of view.machines.values()) {
    if (machine.job && machine.job.state === 'running') jobs.set(machine.job.id, machine.job);
  }
  for (const job of view.jobs.values()) if (job.state === 'running') jobs.set(job.id, job);
  return [...jobs.values()].sort((a, b) => a.machine.localeCompare(b.machine));
}

function renderRunning() {
  const jobs = runningJobs();
  $('running-none').hidden = jobs.length > 0;
  $('running-jobs').replaceChildren(...jobs.map((job) => {
    const bar = el('progress', { class: 'running-progress', max: 1, value: 0 });
    const item = el('li', { class: 'running-job', 'data-job-id': job.id, 'data-machine': job.machine },
      el('span', { class: 'running-label', text: job.machine + ': job ' + job.id + ' (' + job.kind + ') ' }),
      el('span', { class: 'state', 'data-state': job.state, text: job.state }), ' ',
      bar, ' ', el('span', { class: 'running-progress-text', 'aria-live': 'polite' }), ' ',
      el('button', { type: 'button', class: 'cancel-running', text: 'Cancel',
        onclick: () => post('/api/v1/jobs/' + job.id + '/cancel').then(upsertAndRender).catch(reportError) }));
    return item;
  }));
  for (const job of jobs) renderProgress(job.id, job.progress ? job.progress.done : 0, job.progress ? job.progress.total : 0);
}

// `12 s`, `4 min 05 s`, `1 h 02 min`.
function duration(seconds) {
  const s = Math.max(0, Math.round(seconds));
  if (s < 60) return s + ' s';
  if (s < 3600) return Math.floor(s / 60) + ' min ' + String(s % 60).padStart(2, '0') + ' s';
  return Math.floor(s / 3600) + ' h ' + String(Math.floor(s / 60) % 60).padStart(2, '0') + ' min';
}

function renderProgress(jobId, done, total) {
  const item = document.querySelector('#running-jobs li[data-job-id="' + jobId + '"]');
  if (!item) return;
  const bar = item.querySelector('progress');
  bar.max = Math.max(total, 1);
  bar.value = done;
  bar.setAttribute('data-done', done);
  bar.setAttribute('data-total', total);
  const job = view.jobs.get(jobId);
  const started = job && job.started_at ? Date.parse(job.started_at) : NaN;
  let text = done + ' / ' + total;
  if (done > 0 && total > done && Number.isFinite(started)) {
    const elapsed = (Date.now() - started) / 1000;
    text += ', about ' + duration(elapsed * (total - done) / done) + ' left';
  }
  item.querySelector('.running-progress-text').textContent = text;
}

// ---- history and one job

// A job's states only move forward; an event that arrives late (the `queued` answer of
// a job the worker had already started) never takes a job back.
const STATE_RANK = { queued: 0, running: 1 };
const rank = (state) => STATE_RANK[state] ?? 2;

function upsertJob(job) {
  const known = view.jobs.get(job.id);
  if (known && rank(known.state) > rank(job.state)) return;
  view.jobs.set(job.id, job);
  const machine = view.machines.get(job.machine);
  if (machine && machine.job && machine.job.id === job.id) machine.job = job;
}

function renderHistory() {
  const rows = [...view.jobs.values()].sort((a, b) => b.id - a.id).map((job) => {
    const actions = el('td', {},
      el('button', { type: 'button', class: 'show-job', 'data-job-id': job.id, text: 'Show',
        onclick: () => showJob(job.id).catch(reportError) }));
    if (job.state === 'queued' || job.state === 'running') {
      actions.append(' ', el('button', { type: 'button', class: 'cancel-job', text: 'Cancel',
        onclick: () => post('/api/v1/jobs/' + job.id + '/cancel').then(upsertAndRender).catch(reportError) }));
    }
    return el('tr', { 'data-job-id': job.id, 'data-state': job.state,
      'data-live-progress': view.liveProgress.get(job.id) || 0 },
      el('td', { text: String(job.id) }),
      el('td', { text: job.machine }),
      el('td', { text: job.kind }),
      el('td', {}, el('span', { class: 'state job-state', 'data-state': job.state, text: job.state })),
      el('td', { text: job.created_at }),
      el('td', { text: job.finished_at || '' }),
      actions);
  });
  $('history-rows').replaceChildren(...rows);
}

function upsertAndRender(job) {
  upsertJob(job);
  renderHistory();
  renderRunning();
  if (view.detailJob === job.id) showJob(job.id, true).catch(reportError);
}

// `again`: the job shown changed state; its measurements, fetched once and appended from
// their events since, are not fetched again.
async function showJob(id, again) {
  const known = again && view.detailJob === id && view.detailMeasurements;
  view.detailJob = id;
  if (!known) {
    // Measurement events that arrive while the list is fetched wait here; those after
    // the fetch's last row are appended to it.
    view.detailMeasurements = null;
    view.pendingMeasurements = [];
  }
  const [job, charts, files, measurements] = await Promise.all([
    api('/api/v1/jobs/' + id),
    api('/api/v1/jobs/' + id + '/charts'),
    api('/api/v1/jobs/' + id + '/files'),
    known ? null : fetchMeasurements(id),
  ]);
  if (view.detailJob !== id) return;
  releaseImages();
  const section = $('job-detail');
  section.hidden = false;
  section.setAttribute('data-job-id', id);
  section.setAttribute('data-state', job.state);
  $('job-detail-title').textContent = 'Job ' + id + ' (' + job.kind + ', ' + job.state + ')';
  // What a person reads first: the summary (the CLI's text) or the error; the whole
  // record stays one click away.
  $('job-summary').textContent = job.error ? 'Error: ' + job.error
    : (job.summary || (job.state === 'running' || job.state === 'queued' ? 'Not finished yet.' : ''));
  renderResult(job);
  $('job-record').textContent = JSON.stringify(
    { params: job.params, profile: job.profile, error: job.error, result: job.result }, null, 2);
  const images = await Promise.all(charts.map((chart) =>
    svgImage(chart.url, { 'data-chart': chart.name, alt: chart.title, title: chart.title })
      .then((img) => el('figure', {}, img, el('figcaption', { text: chart.title })))));
  $('job-charts').replaceChildren(...images);
  // Every file the job wrote (tables, reports, the shifted layout), fetched with the
  // token and saved under its own name.
  $('job-files').replaceChildren(...files.map((f) => el('li', { 'data-file': f.name },
    el('button', { type: 'button', class: 'download-file', text: f.name,
      onclick: () => downloadFile(f).catch(reportError) }),
    ' ' + (f.title ? f.title + ', ' : '') + (f.size / 1024).toFixed(1) + ' kB')));
  if (measurements) {
    const pending = (view.pendingMeasurements || []).filter((e) => e.job_id === id && !(e.row <= measurements.last));
    view.detailMeasurements = measurements.list.concat(pending.map((e) => e.measurement));
    view.pendingMeasurements = null;
  }
  renderMeasurements(view.detailMeasurements);
  // Heat maps change when a job made a new profile.
  loadProfiles().catch(reportError);
}

// ---- a finished job's numbers as tables (its charts are the job's SVG files)

const num = (v, digits) => (typeof v === 'number' && Number.isFinite(v) ? v.toFixed(digits ?? 3) : '');

function table(attributes, head, rows) {
  return el('table', attributes,
    el('thead', {}, el('tr', {}, ...head.map((h) => el('th', { scope: 'col', text: h })))),
    el('tbody', {}, ...rows.map(([rowAttributes, cells]) =>
      el('tr', rowAttributes, ...cells.map((c, i) => el(i === 0 ? 'th' : 'td', i === 0 ? { scope: 'row', text: c } : { text: c }))))));
}

// ISO 230-2 figures, one row per run (before, and this one): the standard's names.
const ISO_FIGURES = [['A_um', 'A'], ['A_up_um', 'A↑'], ['A_down_um', 'A↓'], ['B_um', 'B'],
  ['mean_reversal_um', 'mean reversal'], ['R_um', 'R'], ['R_up_um', 'R↑'], ['R_down_um', 'R↓'],
  ['E_um', 'E'], ['E_up_um', 'E↑'], ['E_down_um', 'E↓'], ['M_um', 'M']];

function iso230Table(r) {
  const runs = [];
  if (r.before) runs.push(['before', r.before]);
  runs.push([r.before && !r.cycle ? 'after' : (typeof r.map === 'string' ? 'with the map' : 'measured'), r]);
  return table({ class: 'result-table', 'data-result': 'iso230-figures' },
    ['axis ' + (r.axis || '?') + ' (µm)', ...ISO_FIGURES.map(([, label]) => label)],
    runs.map(([label, f]) => [{ 'data-run': label }, [label, ...ISO_FIGURES.map(([key]) => num(f[key]))]]));
}

// Verify: each check point without and with the map (before / after), and the figures.
function verifyTable(r) {
  const length = (v) => (Array.isArray(v) ? Math.hypot(v[0], v[1]) : NaN);
  const rows = (r.points || []).map((p, i) => [{ 'data-point': i },
    [num(p.x_mm, 2) + ', ' + num(p.y_mm, 2), num(p.uncompensated_um && p.uncompensated_um[0], 2),
      num(p.uncompensated_um && p.uncompensated_um[1], 2), num(length(p.uncompensated_um), 2),
      num(p.residual_um && p.residual_um[0], 2), num(p.residual_um && p.residual_um[1], 2), num(length(p.residual_um), 2)]]);
  const u = r.uncompensated_um || {};
  const e = r.residual_um || {};
  rows.push([{ 'data-point': 'max' }, ['max', '', '', num(u.max, 2), '', '', num(e.max, 2)]]);
  rows.push([{ 'data-point': 'rms' }, ['rms', '', '', num(u.rms, 2), '', '', num(e.rms, 2)]]);
  return table({ class: 'result-table', 'data-result': 'verify-before-after' },
    ['point (mm)', 'without map dx (µm)', 'dy', '|e|', 'with map dx (µm)', 'dy', '|e|'], rows);
}

function compensateTable(r) {
  const row = (key, label) => [{ 'data-run': label }, [label, num((r[key] || {}).mean), num((r[key] || {}).rms), num((r[key] || {}).max)]];
  return table({ class: 'result-table', 'data-result': 'compensate-before-after' },
    ['error (µm)', 'mean', 'rms', 'max'], [row('before_um', 'before'), row('after_um', 'after')]);
}

// Any other kind: its numbers, one level deep (`errors.dx_mm`), as name / value rows.
function figuresTable(r) {
  const rows = [];
  const add = (key, v) => {
    if (typeof v === 'number' || typeof v === 'boolean' || (typeof v === 'string' && v.length <= 80)) {
      rows.push([{ 'data-figure': key }, [key, typeof v === 'number' ? num(v, 4) : String(v)]]);
    }
  };
  for (const [key, v] of Object.entries(r || {})) {
    if (v && typeof v === 'object' && !Array.isArray(v)) {
      for (const [inner, w] of Object.entries(v)) add(key + '.' + inner, w);
    } else {
      add(key, v);
    }
    if (rows.length >= 60) break;
  }
  return table({ class: 'result-table', 'data-result': 'figures' }, ['figure', 'value'], rows);
}

const RESULT_TABLES = { iso230: iso230Table, verify: verifyTable, compensate: compensateTable };

function renderResult(job) {
  const box = $('job-result');
  if (!job.result || typeof job.result !== 'object') {
    box.replaceChildren();
    return;
  }
  try {
    box.replaceChildren((RESULT_TABLES[job.kind] || figuresTable)(job.result));
  } catch (error) {
    // A result of an unexpected shape still shows its numbers.
    box.replaceChildren(figuresTable(job.result));
  }
}

// Nested measurement objects become dotted columns: {"deviation": {"dx_mm": 1}} -> deviation.dx_mm.
function flatten(value, prefix, into) {
  if (value && typeof value === 'object' && !Array.isArray(value)) {
    for (const [key, inner] of Object.entries(value)) flatten(inner, prefix ? prefix + '.' + key : key, into);
  } else {
    into[prefix || 'value'] = value;
  }
  return into;
}

// The table shows the newest rows (a map has thousands); the CSV has them all.
const SHOWN_MEASUREMENTS = 200;

function countMeasurements(raw, shown) {
  $('job-measurement-count').textContent = raw.length + ' measurements'
    + (raw.length > shown ? ' (the newest ' + shown + ' shown; the CSV has all)' : '');
  $('job-measurement-count').setAttribute('data-count', raw.length);
  $('measurements-csv').hidden = raw.length === 0;
}

// One measurement arrived: its row is added and the oldest shown dropped (the table is
// redrawn only when the new one brings a column the table lacks).
function appendMeasurement(raw) {
  const table = $('job-measurements');
  const columns = table.dataset.columns ? JSON.parse(table.dataset.columns) : null;
  const row = flatten(raw[raw.length - 1], '', {});
  if (!columns || Object.keys(row).some((c) => !columns.includes(c))) {
    renderMeasurements(raw);
    return;
  }
  const body = table.tBodies[0];
  body.append(el('tr', { class: 'measurement' }, ...columns.map((c) => el('td', { text: format(row[c]) }))));
  while (body.rows.length > SHOWN_MEASUREMENTS) body.deleteRow(0);
  countMeasurements(raw, body.rows.length);
}

function renderMeasurements(raw) {
  const shown = raw.slice(-SHOWN_MEASUREMENTS).map((m) => flatten(m, '', {}));
  const table = $('job-measurements');
  const columns = [...new Set(shown.flatMap((m) => Object.keys(m || {})))];
  table.dataset.columns = JSON.stringify(columns);
  table.tHead.replaceChildren(el('tr', {}, ...columns.map((c) => el('th', { scope: 'col', text: c }))));
  table.tBodies[0].replaceChildren(...shown.map((m) => el('tr', { class: 'measurement' },
    ...columns.map((c) => el('td', { text: format(m[c]) })))));
  countMeasurements(raw, shown.length);
}

// A job's measurements and the row of the newest (`X-Last-Measurement-Row`).
async function fetchMeasurements(id) {
  const response = await fetch('/api/v1/jobs/' + id + '/measurements',
    { headers: { Authorization: 'Bearer ' + view.token } });
  if (!response.ok) throw new ApiError('measurements of job ' + id + ': ' + response.status + ' ' + response.statusText);
  const last = response.headers.get('X-Last-Measurement-Row');
  return { list: await response.json(), last: last === null ? 0 : Number(last) };
}

async function downloadFile(file) {
  const response = await fetch(file.url, { headers: { Authorization: 'Bearer ' + view.token } });
  if (!response.ok) throw new ApiError(file.name + ': ' + response.status + ' ' + response.statusText);
  const link = el('a', { href: URL.createObjectURL(await response.blob()), download: file.name });
  link.click();
  setTimeout(() => URL.revokeObjectURL(link.href), 0);
}

// Every measurement of the job shown, as CSV (dotted columns for nested values).
function downloadMeasurements() {
  const rows = (view.detailMeasurements || []).map((m) => flatten(m, '', {}));
  const columns = [...new Set(rows.flatMap((m) => Object.keys(m)))];
  const cell = (v) => {
    const text = v === undefined || v === null ? '' : typeof v === 'object' ? JSON.stringify(v) : String(v);
    return /[",\n]/.test(text) ? '"' + text.replace(/"/g, '""') + '"' : text;
  };
  const csv = [columns.join(','), ...rows.map((r) => columns.map((c) => cell(r[c])).join(','))].join('\n') + '\n';
  const link = el('a', { href: URL.createObjectURL(new Blob([csv], { type: 'text/csv' })),
    download: 'job-' + view.detailJob + '-measurements.csv' });
  link.click();
  setTimeout(() => URL.revokeObjectURL(link.href), 0);
}

function format(value) {
  if (value === undefined || value === null) return '';
  if (typeof value === 'number') return Number.isInteger(value) ? String(value) : value.toFixed(4);
  return typeof value === 'object' ? JSON.stringify(value) : String(value);
}

async function loadHistory() {
  const jobs = await api('/api/v1/jobs?limit=50');
  for (const job of jobs) upsertJob(job);
  renderHistory();
  renderRunning();
}

// ---- profiles

async function loadProfiles() {
  const machine = $('profile-machine').value;
  if (!machine) return;
  const base = '/api/v1/machines/' + encodeURIComponent(machine) + '/profiles';
  const profiles = await api(base);
  const activeByName = new Map();
  for (const p of profiles) if (p.active) activeByName.set(p.name, p);
  const rows = profiles.map((p) => {
    const path = base + '/' + encodeURIComponent(p.name);
    const actions = el('td', {},
      el('button', { type: 'button', class: 'activate', disabled: p.active ? '' : null,
        'aria-label': 'Activate ' + p.name + ' version ' + p.version, text: 'Activate',
        onclick: () => {
          // The operator confirms what it changes: the machine's next jobs use it.
          const current = activeByName.get(p.name);
          const question = 'Activate ' + p.name + ' v' + p.version + ' on machine ' + machine + '?\n'
            + 'Its next jobs use it' + (current ? ' instead of v' + current.version : '') + '.';
          if (!window.confirm(question)) return;
          post(path + '/' + p.version + '/activate').then(loadProfiles).catch(reportError);
        } }));
    if (p.version > 1) {
      actions.append(' ', el('button', { type: 'button', class: 'show-diff', text: 'Changes',
        'aria-label': 'What changed from ' + p.name + ' version ' + (p.version - 1) + ' to ' + p.version,
        onclick: () => api(path + '/' + p.version + '/diff')
          .then((d) => d.summary)
          .catch((error) => 'v' + (p.version - 1) + ' -> v' + p.version + ': ' + error.message)
          .then((text) => {
            $('profile-diff').textContent = text;
            $('profile-diff').setAttribute('data-version', p.version);
          }) }));
    }
    if (p.active) {
      actions.append(' ', el('button', { type: 'button', class: 'rollback',
        'aria-label': 'Roll ' + p.name + ' back to the version active before', text: 'Roll back',
        onclick: () => post(path + '/rollback').then(loadProfiles).catch(reportError) }));
    }
    if (p.kind === 'error_map') {
      actions.append(' ', el('button', { type: 'button', class: 'show-heatmap', text: 'Heat map',
        onclick: () => showHeatmap(machine, p).catch(reportError) }));
    }
    return el('tr', { 'data-profile': p.name, 'data-version': p.version, 'data-kind': p.kind,
      'data-active': String(p.active) },
      el('td', { text: p.name }), el('td', { text: p.kind }), el('td', { text: String(p.version) }),
      el('td', { class: 'profile-active', text: p.active ? 'active' : '' }),
      el('td', { text: p.created_at }), el('td', { text: p.note || '' }), actions);
  });
  $('profile-rows').replaceChildren(...rows);
  // Show the heat map of the active error map (or the newest error map) by default.
  const maps = profiles.filter((p) => p.kind === 'error_map');
  const shown = maps.find((p) => p.active) || maps[maps.length - 1];
  if (shown) await showHeatmap(machine, shown);
}

async function showHeatmap(machine, profile) {
  const url = '/api/v1/machines/' + encodeURIComponent(machine) + '/profiles/' +
    encodeURIComponent(profile.name) + '/' + profile.version + '/heatmap.svg';
  const title = 'Error map ' + profile.name + ' v' + profile.version;
  const img = await svgImage(url, { alt: title, 'data-profile': profile.name, 'data-version': profile.version });
  $('heatmap-image').replaceChildren(img);
  $('heatmap-caption').textContent = title;
  $('heatmap').hidden = false;
  $('heatmap').setAttribute('data-profile', profile.name);
  $('heatmap').setAttribute('data-version', profile.version);
}

// ---- live events

function connectEvents() {
  if (!view.token) return;
  if (view.socket) {
    // A new token replaces the old connection (its close handler then does nothing).
    const old = view.socket;
    view.socket = null;
    old.close();
  }
  const scheme = location.protocol === 'https:' ? 'wss:' : 'ws:';
  // Browsers cannot set headers on a WebSocket: the token goes in the subprotocol list.
  const socket = new WebSocket(scheme + '//' + location.host + '/api/v1/events',
    ['gateway.v1', 'bearer.' + view.token]);
  view.socket = socket;
  socket.addEventListener('open', () => {
    view.reconnectDelayMs = 500;
    // A failure to reach the box is over once it answers again.
    if (view.networkError) {
      view.networkError = false;
      $('error').textContent = '';
    }
    $('connection').textContent = 'Live';
    $('connection').setAttribute('data-state', 'open');
  });
  socket.addEventListener('message', (event) => {
    try { handleEvent(JSON.parse(event.data)); } catch (error) { reportError(error); }
  });
  socket.addEventListener('close', () => {
    if (view.socket !== socket) return;
    view.socket = null;
    $('connection').textContent = 'Disconnected, reconnecting';
    $('connection').setAttribute('data-state', 'closed');
    if (!view.token) return;
    // Back off up to 10 s; reload the lists on reconnect (events were missed).
    setTimeout(() => { connectEvents(); loadHistory().catch(reportError); }, view.reconnectDelayMs);
    view.reconnectDelayMs = Math.min(view.reconnectDelayMs * 2, 10000);
  });
}

function handleEvent(message) {
  switch (message.type) {
    case 'hello':
      view.machines = new Map(message.machines.map((m) => [m.id, m]));
      for (const m of message.machines) if (m.job) upsertJob(m.job);
      renderMachines();
      for (const m of message.machines) if (m.state === 'busy') loadFrame(m.id);
      renderHistory();
      loadProfiles().catch(reportError);
      break;
    case 'machine':
      view.machines.set(message.machine.id, message.machine);
      if (message.machine.job) upsertJob(message.machine.job);
      renderMachines();
      break;
    case 'job': {
      const previous = view.jobs.get(message.job.id);
      upsertAndRender(message.job);
      if (FINAL_STATES.includes(message.job.state) && (!previous || previous.state !== message.job.state)) {
        loadProfiles().catch(reportError);
      }
      break;
    }
    case 'progress': {
      const job = view.jobs.get(message.job_id);
      if (job) job.progress = { done: message.done, total: message.total };
      renderProgress(message.job_id, message.done, message.total);
      view.liveProgress.set(message.job_id, (view.liveProgress.get(message.job_id) || 0) + 1);
      const row = document.querySelector('#history-rows tr[data-job-id="' + message.job_id + '"]');
      if (row) row.setAttribute('data-live-progress', view.liveProgress.get(message.job_id));
      break;
    }
    case 'measurement':
      // The event carries the measurement: the detail appends it (each is fetched once).
      if (view.detailJob === message.job_id && view.detailMeasurements) {
        view.detailMeasurements.push(message.measurement);
        appendMeasurement(view.detailMeasurements);
      } else if (view.detailJob === message.job_id && view.pendingMeasurements) {
        view.pendingMeasurements.push(message);
      }
      break;
    case 'frame':
      // Only that a new frame is there: fetched (the newest) when none is in flight.
      loadFrame(message.machine);
      break;
    default:
      break; // newer servers may send more types
  }
}

// ---- start

// The start form is built from the API's own schema of each job kind's params
// (`components.schemas["job.<kind>"]` of the OpenAPI document): the same types, defaults,
// ranges and help the API checks. The page checks nothing itself: the API's errors,
// which name the field, are shown beside it.

async function loadSchemas() {
  const doc = await api('/api/v1/openapi.json');
  view.schemas = {};
  for (const [name, schema] of Object.entries(doc.components.schemas || {})) {
    if (name.startsWith('job.')) view.schemas[name.slice(4)] = schema;
  }
  renderKinds();
}

function renderKinds() {
  const machine = view.machines.get($('job-machine').value);
  const kinds = Object.keys(view.schemas)
    .filter((k) => !machine || !machine.kinds || machine.kinds.includes(k));
  const select = $('job-kind');
  const chosen = select.value;
  if ([...select.options].map((o) => o.value).join() !== kinds.join()) {
    select.replaceChildren(...kinds.map((k) => el('option', { value: k, text: k })));
    if (kinds.includes(chosen)) select.value = chosen;
    renderForm();
  }
}

// One property of an OpenAPI 3.1 schema as the form needs it.
function fieldSpec(schema) {
  let inner = schema;
  let nullable = false;
  if (schema.oneOf) {
    const parts = schema.oneOf.filter((p) => p.type !== 'null');
    nullable = parts.length < schema.oneOf.length;
    inner = parts[0] || {};
  }
  let type = inner.type;
  if (Array.isArray(type)) {
    nullable = nullable || type.includes('null');
    type = type.find((t) => t !== 'null');
  }
  return {
    type, nullable, choices: inner.enum, min: inner.minimum ?? schema.minimum,
    max: inner.maximum ?? schema.maximum, def: schema.default ?? inner.default,
    help: schema.description || inner.description || '', format: inner.format,
    items: inner.items,
  };
}

// The unit a field's name carries (`gap_mm`, `drift_threshold_um`, `feed_mm_min`).
function unitOf(name) {
  const units = [['_mm_min', 'mm/min'], ['_mm', 'mm'], ['_um', 'µm'], ['_s', 's']];
  const found = units.find(([suffix]) => name.endsWith(suffix));
  return found ? found[1] : '';
}

function fieldInput(name, spec, required) {
  const id = 'field-' + name;
  const common = { id, name, 'data-field-input': name, 'aria-describedby': id + '-help ' + id + '-error' };
  if (spec.type === 'boolean') return el('input', { ...common, type: 'checkbox' });
  if (spec.choices) {
    const options = spec.choices.map((c) => el('option', { value: c, text: c }));
    if (!required) options.unshift(el('option', { value: '', text: spec.def === undefined ? '(default)' : '(default: ' + spec.def + ')' }));
    const select = el('select', common, ...options);
    select.value = required ? spec.choices[0] : '';
    return select;
  }
  if (spec.format === 'binary') {
    // A file's text (a layout): read when chosen; its extension sets the `format` field.
    const input = el('input', { ...common, type: 'file', accept: '.json,.dxf,.svg' });
    input.addEventListener('change', () => {
      const file = input.files[0];
      const format = document.getElementById('field-format'); // built with the form
      const ext = file ? file.name.split('.').pop().toLowerCase() : '';
      if (format && [...format.options].some((o) => o.value === ext)) format.value = ext;
      $(id + '-help').textContent = file ? file.name + ', ' + (file.size / 1024).toFixed(1) + ' kB' : spec.help;
    });
    return input;
  }
  if (spec.type === 'array' && spec.items && spec.items.type === 'string') {
    return el('textarea', { ...common, rows: 2, placeholder: 'one per line' });
  }
  if (spec.type === 'array') {
    return el('input', { ...common, type: 'text', inputmode: 'decimal', placeholder: 'x, y',
      value: Array.isArray(spec.def) ? spec.def.join(', ') : '' });
  }
  if (spec.type === 'integer' || spec.type === 'number') {
    return el('input', { ...common, type: 'number', step: spec.type === 'integer' ? 1 : 'any',
      min: spec.min, max: spec.max, value: spec.def, placeholder: spec.nullable ? 'default' : '' });
  }
  return el('input', { ...common, type: 'text', value: spec.def, placeholder: spec.nullable ? 'default' : '' });
}

function renderForm() {
  const kind = $('job-kind').value;
  const schema = view.schemas[kind];
  $('job-kind-help').textContent = schema ? schema.description || '' : '';
  const required = new Set((schema && schema.required) || []);
  const rows = Object.entries((schema && schema.properties) || {}).map(([name, prop]) => {
    const spec = fieldSpec(prop);
    const unit = unitOf(name);
    const range = [spec.min !== undefined ? 'from ' + spec.min : '', spec.max !== undefined ? 'to ' + spec.max : '']
      .filter(Boolean).join(' ');
    return el('div', { class: 'field', 'data-field': name, 'data-type': spec.type || 'string' },
      el('label', { for: 'field-' + name, text: name + (unit ? ' (' + unit + ')' : '') + (required.has(name) ? ' *' : '') }),
      fieldInput(name, spec, required.has(name)),
      el('small', { id: 'field-' + name + '-help', class: 'help', text: spec.help + (range ? ' [' + range + ']' : '') }),
      el('span', { id: 'field-' + name + '-error', class: 'field-error', 'data-field-error': name, role: 'alert' }));
  });
  $('job-fields').replaceChildren(...rows);
}

// The params the form describes: an empty field is left out (the API's default).
async function formParams() {
  const params = {};
  for (const row of $('job-fields').querySelectorAll('.field')) {
    const name = row.dataset.field;
    const input = row.querySelector('[data-field-input]');
    if (input.type === 'checkbox') {
      if (input.checked) params[name] = true;
    } else if (input.type === 'file') {
      if (input.files[0]) params[name] = await input.files[0].text();
    } else if (input.value.trim() !== '') {
      const text = input.value.trim();
      const type = row.dataset.type;
      if (type === 'integer' || type === 'number') params[name] = Number(text);
      else if (type === 'array' && input.tagName === 'TEXTAREA') params[name] = text.split('\n').map((l) => l.trim()).filter(Boolean);
      else if (type === 'array') params[name] = text.split(',').map((v) => Number(v.trim()));
      else params[name] = text;
    }
  }
  return params;
}

function clearFieldErrors() {
  for (const span of $('job-fields').querySelectorAll('.field-error')) span.textContent = '';
  for (const input of $('job-fields').querySelectorAll('[aria-invalid]')) input.removeAttribute('aria-invalid');
}

async function startJob(event) {
  event.preventDefault();
  $('error').textContent = '';
  clearFieldErrors();
  const machine = $('job-machine').value;
  const response = await fetch('/api/v1/machines/' + encodeURIComponent(machine) + '/jobs', {
    method: 'POST',
    headers: { Authorization: 'Bearer ' + view.token, 'Content-Type': 'application/json' },
    body: JSON.stringify({ kind: $('job-kind').value, params: await formParams() }),
  });
  const body = await response.json().catch(() => ({}));
  if (response.status === 401) {
    showLogin('The token was refused; enter a valid one.');
    return;
  }
  if (!response.ok) {
    // `params.grid_step_mm`, `assign[2]`: the field's row shows the API's message.
    const field = String(body.field || '').replace(/^params\.?/, '').replace(/\[.*$/, '').split('.')[0];
    const span = field && $('job-fields').querySelector('[data-field-error="' + CSS.escape(field) + '"]');
    if (span) {
      // Beside the field its name is not repeated.
      const message = String(body.message || body.error);
      span.textContent = message.startsWith(body.field + ': ') ? message.slice(body.field.length + 2) : message;
      span.previousElementSibling.previousElementSibling.setAttribute('aria-invalid', 'true');
    } else {
      $('error').textContent = (body.error ? body.error + ': ' : '') + (body.message || response.statusText);
    }
    return;
  }
  upsertAndRender(body);
}

async function enter(token) {
  view.token = token;
  $('login').hidden = true;
  $('app').hidden = false;
  const machines = await api('/api/v1/machines');
  view.machines = new Map(machines.map((m) => [m.id, m]));
  renderMachines();
  await loadSchemas();
  await loadHistory();
  await loadProfiles();
  connectEvents();
}

document.addEventListener('DOMContentLoaded', () => {
  $('login-form').addEventListener('submit', (event) => {
    event.preventDefault();
    const token = $('token-input').value.trim();
    if (!token) return;
    sessionStorage.setItem(TOKEN_KEY, token);
    enter(token).catch(reportError);
  });
  $('start-form').addEventListener('submit', (event) => startJob(event).catch(reportError));
  $('profile-machine').addEventListener('change', () => loadProfiles().catch(reportError));
  $('job-machine').addEventListener('change', renderKinds);
  $('job-kind').addEventListener('change', renderForm);
  $('measurements-csv').addEventListener('click', downloadMeasurements);
  // A link with #token= opened on a page already loaded changes only the fragment.
  window.addEventListener('hashchange', () => {
    const fresh = takeToken();
    if (fresh && fresh !== view.token) enter(fresh).catch(reportError);
  });
  const token = takeToken();
  if (token) enter(token).catch(reportError);
  else showLogin('');
});
