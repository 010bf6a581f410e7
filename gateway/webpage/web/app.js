// The service's web page: plain JavaScript, no build step, no outside scripts.
// It codes against the HTTP API v1 and the /api/v1/events WebSocket (see the service
// contract in the README). Every element a test looks at has a stable id or data-*
// attribute: #machines li[data-machine][data-state], #running-job[data-job-id],
// #history-rows tr[data-job-id][data-state][data-live-progress] (progress events seen), #job-charts img[data-chart],
// #profile-rows tr[data-profile][data-version][data-active], #heatmap-image img.
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
  $('error').textContent = String(error.message || error);
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
        + (machine.rotary ? ', A/C table ' + machine.rotary : '') })));
  }
  for (const select of [$('job-machine'), $('profile-machine')]) {
    const chosen = select.value;
    select.replaceChildren(...[...view.machines.keys()].map((id) => el('option', { value: id, text: id })));
    if (view.machines.has(chosen)) select.value = chosen;
  }
  renderRunning();
}

function runningJob() {
  for (const machine of view.machines.values()) {
    if (machine.job && machine.job.state === 'running') return machine.job;
  }
  for (const job of view.jobs.values()) if (job.state === 'running') return job;
  return null;
}

function renderRunning() {
  const job = runningJob();
  $('running-none').hidden = !!job;
  $('running-job').hidden = !job;
  if (!job) {
    $('running-job').removeAttribute('data-job-id');
    return;
  }
  $('running-job').setAttribute('data-job-id', job.id);
  $('running-label').textContent = 'Job ' + job.id + ' (' + job.kind + ') on ' + job.machine;
  $('running-state').textContent = job.state;
  $('running-state').setAttribute('data-state', job.state);
  renderProgress(job.id, job.progress ? job.progress.done : 0, job.progress ? job.progress.total : 0);
}

function renderProgress(jobId, done, total) {
  if ($('running-job').getAttribute('data-job-id') !== String(jobId)) return;
  const bar = $('running-progress');
  bar.max = Math.max(total, 1);
  bar.value = done;
  bar.setAttribute('data-done', done);
  bar.setAttribute('data-total', total);
  $('running-progress-text').textContent = done + ' / ' + total;
}

// ---- history and one job

function upsertJob(job) {
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
  if (view.detailJob === job.id) showJob(job.id).catch(reportError);
}

async function showJob(id) {
  view.detailJob = id;
  const [job, charts, measurements] = await Promise.all([
    api('/api/v1/jobs/' + id),
    api('/api/v1/jobs/' + id + '/charts'),
    api('/api/v1/jobs/' + id + '/measurements'),
  ]);
  if (view.detailJob !== id) return;
  releaseImages();
  const section = $('job-detail');
  section.hidden = false;
  section.setAttribute('data-job-id', id);
  section.setAttribute('data-state', job.state);
  $('job-detail-title').textContent = 'Job ' + id + ' (' + job.kind + ', ' + job.state + ')';
  $('job-summary').textContent = JSON.stringify(
    { params: job.params, profile: job.profile, error: job.error, result: job.result }, null, 2);
  const images = await Promise.all(charts.map((chart) =>
    svgImage(chart.url, { 'data-chart': chart.name, alt: chart.title, title: chart.title })
      .then((img) => el('figure', {}, img, el('figcaption', { text: chart.title })))));
  $('job-charts').replaceChildren(...images);
  renderMeasurements(measurements);
  // Heat maps change when a job made a new profile.
  loadProfiles().catch(reportError);
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

function renderMeasurements(raw) {
  const measurements = raw.map((m) => flatten(m, '', {}));
  const table = $('job-measurements');
  const columns = [...new Set(measurements.flatMap((m) => Object.keys(m || {})))];
  table.tHead.replaceChildren(el('tr', {}, ...columns.map((c) => el('th', { scope: 'col', text: c }))));
  table.tBodies[0].replaceChildren(...measurements.map((m) => el('tr', { class: 'measurement' },
    ...columns.map((c) => el('td', { text: format(m[c]) })))));
  $('job-measurement-count').textContent = measurements.length + ' measurements';
  $('job-measurement-count').setAttribute('data-count', measurements.length);
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
        onclick: () => post(path + '/' + p.version + '/activate').then(loadProfiles).catch(reportError) }));
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
      if (view.detailJob === message.job_id) {
        api('/api/v1/jobs/' + message.job_id + '/measurements').then(renderMeasurements).catch(reportError);
      }
      break;
    default:
      break; // newer servers may send more types
  }
}

// ---- start

async function startJob(event) {
  event.preventDefault();
  $('error').textContent = '';
  let params;
  try {
    params = JSON.parse($('job-params').value || '{}');
  } catch (error) {
    $('error').textContent = 'Parameters are not valid JSON: ' + error.message;
    return;
  }
  const machine = $('job-machine').value;
  const job = await post('/api/v1/machines/' + encodeURIComponent(machine) + '/jobs',
    { kind: $('job-kind').value, params });
  upsertAndRender(job);
}

async function enter(token) {
  view.token = token;
  $('login').hidden = true;
  $('app').hidden = false;
  const machines = await api('/api/v1/machines');
  view.machines = new Map(machines.map((m) => [m.id, m]));
  renderMachines();
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
  $('cancel-job').addEventListener('click', () => {
    const id = $('running-job').getAttribute('data-job-id');
    if (id) post('/api/v1/jobs/' + id + '/cancel').then(upsertAndRender).catch(reportError);
  });
  $('profile-machine').addEventListener('change', () => loadProfiles().catch(reportError));
  // A link with #token= opened on a page already loaded changes only the fragment.
  window.addEventListener('hashchange', () => {
    const fresh = takeToken();
    if (fresh && fresh !== view.token) enter(fresh).catch(reportError);
  });
  const token = takeToken();
  if (token) enter(token).catch(reportError);
  else showLogin('');
});
