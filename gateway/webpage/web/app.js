// The service's web page: plain JavaScript, no build step, no outside scripts.
// It codes against the HTTP API v1 and the /api/v1/events WebSocket (see the service
// contract in docs/service.md). Every element a test looks at has a stable id or data-*
// attribute: #machines li[data-machine][data-state], #running-jobs li[data-job-id][data-machine],
// #machines ol.machine-queue[data-machine] li.queued-job[data-job-id][data-position] (button.queue-up,
// .queue-down, .queue-cancel),
// #history-rows tr[data-job-id][data-state][data-live-progress] (progress events seen), #job-charts img[data-chart],
// #job-result table[data-result] (iso230-figures, verify-before-after, compensate-before-after, figures),
// #profile-rows tr[data-profile][data-version][data-active][data-in-use], #heatmap-image img,
// #machines li[data-machine] figure.live-frame[data-machine][data-job-id][data-dots] (img.frame-image,
// svg.frame-overlay circle.frame-dot, .frame-centre), body[data-live] (false while the
// event connection is down: nothing shown is current), #form-errors (every field's
// refusal at once), .field-error[data-field-error] beside each field, #job-next (what
// happened to a stopped job and what can be done: button.resume-job).
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
  live: false, // the event connection is open: what is shown is current
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
  // An action that changes the box waits for the page to be live (setLive).
  if (node.classList.contains('live-action')) {
    node.setAttribute('data-off', String(node.disabled));
    if (!view.live) node.disabled = true;
  }
  return node;
}

// ---- words, units and numbers as an operator reads them

// The unit a name carries (`gap_mm`, `drift_threshold_um`, `feed_mm_min`, `machine_time_s`).
const UNIT_SUFFIXES = [['_mm_min', 'mm/min'], ['_mm2', 'mm²'], ['_mm', 'mm'], ['_pct', '%'], ['_percent', '%'], ['_um', 'µm'], ['_ms', 'ms'], ['_s', 's'],
  ['_deg', '°'], ['_arcsec', '″'], ['_px', 'px']];
function unitOf(name) {
  const found = UNIT_SUFFIXES.find(([suffix]) => name.endsWith(suffix));
  return found ? found[1] : '';
}

// What the page calls the API's names (params, results, measurements); any other name is
// made readable: `line_step_mm` -> "Line step".
const LABELS = {
  targets: 'Targets', method: 'Method', name: 'Name', grid_step_mm: 'Grid step', line_step_mm: 'Line step',
  passes: 'Passes', tool_offset_mm: 'Tool offset X, Y', points: 'Check points', seed: 'Random seed',
  spot_check: 'Spot check only', drift_threshold_um: 'Drift threshold', layout: 'Layout file', format: 'File format',
  tools: 'Tools', window_mm: 'Cutting window', gap_mm: 'Gap between groups', width_mm: 'Material width',
  material_width_mm: 'Output material width', clearance_mm: 'Clearance', assign: 'Fixed groups',
  widen: 'Widen gaps to clear overlaps', chord_tolerance_mm: 'Arc tolerance', out_format: 'Output format',
  picture: 'Picture', max_shift_um: 'Largest zero shift', axis: 'Axis', positions: 'Positions', runs: 'Runs',
  cycle: 'Test cycle', overrun_mm: 'Overrun', from_mm: 'From', to_mm: 'To', at_mm: 'Other axis at',
  certificate_uncertainty_um: 'Board uncertainty (k = 2)', with_map: 'With the active error map',
  machine_time_s: 'Machine time', kept_as: 'Saved as', residual_rms_um: 'Residual rms', rms_um: 'rms', max_um: 'max',
  mean_um: 'mean', dx_um: 'dx', dy_um: 'dy', dx_mm: 'dx', dy_mm: 'dy', x_mm: 'X', y_mm: 'Y',
};
const STATE_WORDS = { queued: 'queued', running: 'running', succeeded: 'done', failed: 'failed',
  cancelled: 'cancelled', interrupted: 'interrupted', idle: 'idle', busy: 'busy', opening: 'connecting',
  link_lost: 'link lost', stopped: 'stopped' };

function labelOf(name) {
  if (LABELS[name]) return LABELS[name];
  const unit = UNIT_SUFFIXES.find(([suffix]) => name.endsWith(suffix));
  const bare = (unit ? name.slice(0, -unit[0].length) : name).replace(/_/g, ' ').trim();
  return bare.charAt(0).toUpperCase() + bare.slice(1);
}
// A job kind as the registry names it for operators (its schema's title).
const kindLabel = (kind) => (view.schemas[kind] && view.schemas[kind].title) || labelOf(kind);
const stateWord = (state) => STATE_WORDS[state] || String(state || '').replace(/_/g, ' ');

// Help written for the shop floor comes with each kind's schema (`x-help` of the kind and
// of its fields, from the registry); a field without it shows its documentation, cleaned
// of the developers' references and of what only the command line does.
function cleanHelp(text) {
  return String(text || '')
    // Sentences and remarks about the command line's flags are not the page's.
    .replace(/\s*\([^()]*(command line|--[a-z])[^()]*\)/gi, '')
    .replace(/(^|\s)(?:[^.;]|[.;](?=\S))*(command line|--[a-z])(?:[^.;]|[.;](?=\S))*([.;](?=\s|$)|$)/gi, '$1')
    .replace(/\[`([^`\]]+)`\]/g, '$1').replace(/`/g, '')
    .replace(/\s*\((source [A-Z]|the CLI[^)]*|the paper[^)]*)\)/g, '')
    .replace(/\bS\d+'s\s*/g, 'the ').replace(/\bum\b/g, 'µm').trim();
}

// `10000` -> `10 000` (a no-break space between groups of three from five digits on).
function groupDigits(text) {
  const [whole, fraction] = String(text).split('.');
  const sign = whole.startsWith('-') ? '-' : '';
  const digits = whole.replace('-', '');
  const grouped = digits.length > 4 ? digits.replace(/\B(?=(\d{3})+(?!\d))/g, '\u00a0') : digits;
  return sign + grouped + (fraction !== undefined ? '.' + fraction : '');
}

// A number with the precision its unit deserves: µm to 0.01 (0.1 from 100), mm to 0.001,
// seconds to 0.1, whole numbers whole, anything else 4 significant digits.
function fmtNumber(v, unit) {
  if (typeof v !== 'number' || !Number.isFinite(v)) return v === null || v === undefined ? '' : String(v);
  const a = Math.abs(v);
  let text;
  if (unit === 'µm') text = v.toFixed(a >= 100 ? 1 : 2);
  else if (unit === 'mm' || unit === 'mm/min') text = Number.isInteger(v) ? String(v) : v.toFixed(3);
  else if (unit === 's' && a >= 60) return duration(v);
  else if (unit === 's' || unit === 'ms') text = v.toFixed(1);
  else if (Number.isInteger(v)) text = String(v);
  else text = a >= 1e4 ? v.toFixed(0) : String(Number(v.toPrecision(4)));
  if (/e/.test(text)) return text;
  return groupDigits(text);
}
function withUnit(v, unit) {
  const text = fmtNumber(v, unit);
  if (!text || !unit || typeof v !== 'number') return text;
  if (unit === 's' && Math.abs(v) >= 60) return text; // a duration carries its units
  return text + '\u00a0' + unit;
}

// `14:02, 3 min ago` (the browser's local time; the date too when not today), with the
// exact instant in its title.
function ago(ms) {
  const s = Math.round(ms / 1000);
  if (s < 45) return 'just now';
  if (s < 3600) return Math.max(1, Math.round(s / 60)) + ' min ago';
  if (s < 48 * 3600) return Math.round(s / 3600) + ' h ago';
  return Math.round(s / 86400) + ' days ago';
}
function fmtTime(iso, bare) {
  const t = Date.parse(iso);
  if (!Number.isFinite(t)) return '';
  const d = new Date(t);
  const now = new Date();
  const hm = d.toLocaleTimeString([], { hour: '2-digit', minute: '2-digit', hourCycle: 'h23' });
  const day = d.toDateString() === now.toDateString() ? ''
    : d.toLocaleDateString([], { day: 'numeric', month: 'short', year: d.getFullYear() === now.getFullYear() ? undefined : 'numeric' }) + ' ';
  return day + hm + (bare ? '' : ', ' + ago(now - d));
}
// `bare`: the time only (beside another time that says how long ago).
function timeEl(iso, bare) {
  if (!iso) return '';
  return el('time', { datetime: iso, 'data-ago': bare ? null : '', title: new Date(Date.parse(iso)).toLocaleString(),
    text: fmtTime(iso, bare) });
}
function refreshTimes() {
  for (const t of document.querySelectorAll('time[data-ago]')) t.textContent = fmtTime(t.getAttribute('datetime'));
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
      el('span', { class: 'state machine-state', 'data-state': machine.state, text: stateWord(machine.state) }),
      el('span', { class: 'machine-detail', text: detail }),
      el('span', { class: 'machine-queued', 'data-queued': machine.queued,
        text: machine.queued ? ', ' + machine.queued + ' queued' : '' }),
      el('div', { class: 'machine-description', text: machine.description || '' }),
      el('div', { class: 'machine-links', text: 'Stage ' + machine.stage + ', camera ' + machine.camera
        + (machine.rotary ? ', A/C table ' + machine.rotary : '') }),
      renderQueue(machine),
      frameFor(machine) ? frameFigure(machine.id) : ''));
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

// The frame shown for a machine: only one of the job it is running now (a frame of an
// earlier job, or of a job that has ended, is not shown as the machine's picture).
function frameFor(machine) {
  const frame = view.frames.get(machine.id);
  const running = machine.job && machine.job.state === 'running' ? machine.job.id : null;
  return frame && running !== null && frame.data.job_id === running ? frame : null;
}

// A machine's job ended or changed: its frame goes with it.
function dropStaleFrames() {
  for (const [id, frame] of view.frames) {
    const machine = view.machines.get(id);
    if (!machine || !frameFor(machine)) {
      URL.revokeObjectURL(frame.url);
      view.frames.delete(id);
      const figure = document.querySelector('#machines li[data-machine="' + CSS.escape(id) + '"] figure.live-frame');
      if (figure) figure.remove();
    }
  }
}

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
  img.alt = 'Camera picture of ' + machineId + ' during job ' + data.job_id;
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
  const caption = figure.querySelector('figcaption');
  const line = (text) => caption.append(el('span', { class: 'frame-line', text }));
  line('Job ' + data.job_id + ', picture at ' + fmtTime(data.at) + '.');
  if (o.centre_mm) {
    line('Camera centre on the board: X ' + fmtNumber(o.centre_mm[0], 'mm') + ', Y ' + fmtNumber(o.centre_mm[1], 'mm')
      + ' mm (board coordinates).');
  }
  if (o.deviation_um) {
    line('Off its target by X ' + fmtNumber(o.deviation_um[0], 'µm') + ', Y ' + fmtNumber(o.deviation_um[1], 'µm') + ' µm.');
  }
  caption.append(el('span', { class: 'frame-legend' },
    el('span', { class: 'legend-dot', 'aria-hidden': 'true' }), ' ' + o.dots.length + ' board dots found ',
    el('span', { class: 'legend-cross', 'aria-hidden': 'true', text: '+' }), ' measured point (picture centre)'));
  return figure;
}

function showFrame(machineId) {
  const item = document.querySelector('#machines li[data-machine="' + CSS.escape(machineId) + '"]');
  if (!item) return;
  const figure = frameFigure(machineId);
  const old = item.querySelector('figure.live-frame');
  if (old) old.replaceWith(figure);
  else item.append(figure);
}

// At most one fetch in flight per machine: a frame event during it asks for one more
// after it (the newest then), the ones between are dropped. A frame of another job than
// the one the machine runs is not shown.
async function loadFrame(machineId) {
  if (view.frameFetch.has(machineId)) {
    view.frameFetch.set(machineId, 'again');
    return;
  }
  view.frameFetch.set(machineId, 'busy');
  try {
    const base = '/api/v1/machines/' + encodeURIComponent(machineId) + '/frame';
    const data = await api(base + '.json');
    const machine = view.machines.get(machineId);
    const running = machine && machine.job && machine.job.state === 'running' ? machine.job.id : null;
    if (data.job_id !== running) return;
    const response = await fetch(base, { headers: { Authorization: 'Bearer ' + view.token } });
    if (!response.ok) throw new ApiError(response.status + ' ' + response.statusText);
    const url = URL.createObjectURL(await response.blob());
    const previous = view.frames.get(machineId);
    view.frames.set(machineId, { url, data });
    if (frameFor(view.machines.get(machineId))) showFrame(machineId);
    else dropStaleFrames();
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

// Cancel asks first, naming the job and what stopping it means.
function confirmCancel(job) {
  const what = kindLabel(job.kind) + ' job ' + job.id + ' on machine ' + job.machine;
  const question = job.state === 'running'
    ? 'Cancel ' + what + '?\nThe machine stops; what it measured so far is kept.'
    : 'Cancel ' + what + '?\nIt has not started; it leaves the queue.';
  if (!window.confirm(question)) return;
  post('/api/v1/jobs/' + job.id + '/cancel').then(upsertAndRender).catch(reportError);
}

// A machine's queue in run order (the first runs next), each job with Up, Down and
// Cancel; the machine's event after a move or a cancel redraws it.
function renderQueue(machine) {
  const queue = machine.queue || [];
  const list = el('ol', { class: 'machine-queue', 'data-machine': machine.id, 'aria-label': 'Queue of ' + machine.id });
  queue.forEach((job, index) => {
    const move = (position) => post('/api/v1/jobs/' + job.id + '/move', { position }).catch(reportError);
    list.append(el('li', { class: 'queued-job', 'data-job-id': job.id, 'data-position': index },
      el('span', { class: 'queued-label', text: 'Job ' + job.id + ', ' + kindLabel(job.kind) + ' ' }),
      el('button', { type: 'button', class: 'queue-up live-action', text: 'Up', disabled: index === 0 ? '' : null,
        'aria-label': 'Up: run job ' + job.id + ' earlier', onclick: () => move(index - 1) }), ' ',
      el('button', { type: 'button', class: 'queue-down live-action', text: 'Down', disabled: index === queue.length - 1 ? '' : null,
        'aria-label': 'Down: run job ' + job.id + ' later', onclick: () => move(index + 1) }), ' ',
      el('button', { type: 'button', class: 'queue-cancel live-action', text: 'Cancel', 'aria-label': 'Cancel job ' + job.id,
        onclick: () => confirmCancel({ ...job, machine: machine.id, state: 'queued' }) })));
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
    const bar = el('progress', { class: 'running-progress', max: 1, value: 0, 'aria-label': 'Progress of job ' + job.id });
    const item = el('li', { class: 'running-job', 'data-job-id': job.id, 'data-machine': job.machine },
      el('span', { class: 'running-label', text: job.machine + ': job ' + job.id + ', ' + kindLabel(job.kind) + ' ' }),
      el('span', { class: 'state', 'data-state': job.state, text: stateWord(job.state) }), ' ',
      bar, ' ', el('span', { class: 'running-progress-text', 'aria-live': 'polite' }), ' ',
      el('button', { type: 'button', class: 'cancel-running live-action', text: 'Cancel', 'aria-label': 'Cancel job ' + job.id,
        onclick: () => confirmCancel(job) }));
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
  let text = done + ' of ' + total;
  // No estimate while the page is not live: the job may have ended meanwhile.
  if (!view.live) text += ' (last known; not live)';
  else if (done > 0 && total > done && Number.isFinite(started)) {
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

function upsertJob(full) {
  const known = view.jobs.get(full.id);
  if (known && rank(known.state) > rank(full.state)) return;
  // The list keeps no params or result (a layout job's are megabytes): the job's detail
  // fetches them.
  const { params, result, ...job } = full;
  view.jobs.set(job.id, job);
  const machine = view.machines.get(job.machine);
  if (machine && machine.job && machine.job.id === job.id) machine.job = job;
}

function renderHistory() {
  const rows = [...view.jobs.values()].sort((a, b) => b.id - a.id).map((job) => {
    const actions = el('td', { class: 'actions' },
      el('button', { type: 'button', class: 'show-job', 'data-job-id': job.id, text: 'Show',
        'aria-label': 'Show job ' + job.id, onclick: () => showJob(job.id).catch(reportError) }));
    if (job.state === 'queued' || job.state === 'running') {
      actions.append(' ', el('button', { type: 'button', class: 'cancel-job live-action', text: 'Cancel',
        'aria-label': 'Cancel job ' + job.id, onclick: () => confirmCancel(job) }));
    }
    return el('tr', { 'data-job-id': job.id, 'data-state': job.state,
      'data-live-progress': view.liveProgress.get(job.id) || 0 },
      el('td', { class: 'num', text: String(job.id) }),
      el('td', { text: job.machine }),
      el('td', { text: kindLabel(job.kind) }),
      el('td', {}, el('span', { class: 'state job-state', 'data-state': job.state, text: stateWord(job.state) })),
      el('td', {}, timeEl(job.created_at)),
      el('td', {}, timeEl(job.finished_at)),
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
  $('job-detail-title').textContent = 'Job ' + id + ': ' + kindLabel(job.kind) + ' on ' + job.machine + ', ' + stateWord(job.state);
  // What a person reads first: the summary (the CLI's text) or the error; the whole
  // record is under the developer view.
  $('job-summary').textContent = job.error ? 'Error: ' + job.error
    : (job.summary || (job.state === 'running' ? 'Running, not finished yet.' : job.state === 'queued' ? 'Waiting in the queue.' : ''));
  renderJobTimes(job);
  renderNext(job, measurements ? measurements.list.length : (view.detailMeasurements || []).length);
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

function renderJobTimes(job) {
  const times = [['Queued', job.created_at], ['started', job.started_at], ['ended', job.finished_at]].filter(([, t]) => t);
  const parts = times.flatMap(([label, t], i) => [(i ? ', ' : '') + label + ' ', timeEl(t, i < times.length - 1)]);
  $('job-times').replaceChildren(...parts);
}

// What happened to a job that did not finish, as the service recorded it, and what the
// operator can do: a stopped map scan is resumed by the same scan started again.
function renderNext(job, measured) {
  const box = $('job-next');
  box.replaceChildren();
  box.removeAttribute('data-next');
  const kept = measured === 1 ? ' Its measurement is kept.' : measured ? ' Its ' + measured + ' measurements are kept.' : '';
  let text = '';
  if (job.state === 'interrupted') {
    text = 'The service stopped while this job was running (a restart or a power loss); the job did not finish.' + kept;
  } else if (job.state === 'cancelled') {
    text = 'Cancelled before the end' + (job.error ? ': ' + job.error : '') + '.' + kept;
  } else if (job.state === 'failed' && measured) {
    text = 'Failed before the end.' + kept;
  }
  if (!text) {
    box.hidden = true;
    return;
  }
  box.hidden = false;
  box.setAttribute('data-next', job.state);
  box.append(el('span', { text }));
  if (job.kind === 'map' && job.params && measured) {
    box.append(' ', el('span', { text: 'Starting the same scan again measures only what is missing.' }), ' ',
      el('button', { type: 'button', class: 'resume-job live-action', text: 'Resume the scan',
        onclick: () => {
          if (!window.confirm('Resume the error map scan of job ' + job.id + ' on machine ' + job.machine + '?')) return;
          post('/api/v1/machines/' + encodeURIComponent(job.machine) + '/jobs', { kind: job.kind, params: job.params })
            .then(upsertAndRender).catch(reportError);
        } }));
  }
}

// ---- a finished job's numbers as tables (its charts are the job's SVG files)

const num = (v, digits) => (typeof v === 'number' && Number.isFinite(v) ? v.toFixed(digits ?? 3) : '');

function table(attributes, head, rows) {
  return el('div', { class: 'table-scroll' }, el('table', attributes,
    el('thead', {}, el('tr', {}, ...head.map((h) => el('th', { scope: 'col', text: h })))),
    el('tbody', {}, ...rows.map(([rowAttributes, cells]) =>
      el('tr', rowAttributes, ...cells.map((c, i) => el(i === 0 ? 'th' : 'td', i === 0 ? { scope: 'row', text: c } : { text: c })))))));
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

// Any other kind: its values, one level deep, each labelled with its unit and shown with
// its unit's precision (`errors.dx_mm` -> "Errors: dx, mm"); arrays of a few numbers in a
// line, longer ones counted.
function figuresTable(r) {
  const rows = [];
  const show = (v, unit) => {
    if (typeof v === 'number') return fmtNumber(v, unit);
    if (typeof v === 'boolean') return v ? 'yes' : 'no';
    if (Array.isArray(v) && v.every((x) => typeof x === 'number')) {
      return v.length <= 6 ? v.map((x) => fmtNumber(x, unit)).join('; ') : v.length + ' values';
    }
    return String(v);
  };
  const add = (key, parent, v) => {
    const name = key.split('.').pop();
    const unit = unitOf(name);
    const shown = typeof v === 'number' || typeof v === 'boolean' || (typeof v === 'string' && v.length <= 80)
      || (Array.isArray(v) && v.every((x) => typeof x === 'number'));
    if (!shown) return;
    const label = (parent ? labelOf(parent) + ': ' : '') + labelOf(name) + (unit && unit !== 's' ? ', ' + unit : '');
    rows.push([{ 'data-figure': key }, [label, show(v, unit)]]);
  };
  for (const [key, v] of Object.entries(r || {})) {
    if (v && typeof v === 'object' && !Array.isArray(v)) {
      for (const [inner, w] of Object.entries(v)) add(key + '.' + inner, key, w);
    } else {
      add(key, '', v);
    }
    if (rows.length >= 60) break;
  }
  return table({ class: 'result-table', 'data-result': 'figures' }, ['Figure', 'Value'], rows);
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
    box.querySelector('table').setAttribute('aria-label', 'Results of job ' + job.id);
  } catch (error) {
    // A result of an unexpected shape still shows its numbers.
    box.replaceChildren(figuresTable(job.result));
    box.querySelector('table').setAttribute('aria-label', 'Results of job ' + job.id);
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
  body.append(el('tr', { class: 'measurement' }, ...columns.map((c) => el('td', { text: format(row[c], c) }))));
  while (body.rows.length > SHOWN_MEASUREMENTS) body.deleteRow(0);
  countMeasurements(raw, body.rows.length);
}

function renderMeasurements(raw) {
  const shown = raw.slice(-SHOWN_MEASUREMENTS).map((m) => flatten(m, '', {}));
  const table = $('job-measurements');
  const columns = [...new Set(shown.flatMap((m) => Object.keys(m || {})))];
  table.dataset.columns = JSON.stringify(columns);
  table.tHead.replaceChildren(el('tr', {}, ...columns.map((c) => el('th', { scope: 'col', title: c, text: columnLabel(c, columns) }))));
  table.tBodies[0].replaceChildren(...shown.map((m) => el('tr', { class: 'measurement' },
    ...columns.map((c) => el('td', { text: format(m[c], c) })))));
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

// A dotted column (`measurement.observation.residual_rms_um`) by its last name, with
// its parent's when two columns end alike, and its unit: "Residual rms, µm".
function columnLabel(column, columns) {
  const parts = column.split('.');
  const last = parts[parts.length - 1];
  const twin = columns.some((c) => c !== column && c.split('.').pop() === last);
  const unit = unitOf(last);
  return (twin && parts.length > 1 ? labelOf(parts[parts.length - 2]) + ' ' : '') + labelOf(last) + (unit ? ', ' + unit : '');
}

function format(value, column) {
  if (value === undefined || value === null) return '';
  const unit = unitOf(String(column || '').split('.').pop());
  if (typeof value === 'number') return fmtNumber(value, unit);
  if (Array.isArray(value) && value.every((x) => typeof x === 'number')) return value.map((x) => fmtNumber(x, unit)).join('; ');
  if (typeof value === 'boolean') return value ? 'yes' : 'no';
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
  // Of several profiles of a kind with an active version, jobs use the one activated last
  // (`in_use`); the others stay active for their name and can be put back in use.
  const inUseByKind = new Map();
  for (const p of profiles) if (p.in_use) inUseByKind.set(p.kind, p);
  const rows = profiles.map((p) => {
    const path = base + '/' + encodeURIComponent(p.name);
    const actions = el('td', { class: 'actions' },
      el('button', { type: 'button', class: 'activate live-action', disabled: p.in_use ? '' : null,
        'aria-label': 'Activate ' + p.name + ' version ' + p.version, text: 'Activate',
        onclick: () => {
          // The operator confirms what it changes: the machine's next jobs use it.
          const current = inUseByKind.get(p.kind);
          const question = 'Activate ' + p.name + ' v' + p.version + ' on machine ' + machine + '?\n'
            + 'Its next jobs use it' + (current ? ' instead of ' + current.name + ' v' + current.version : '') + '.';
          if (!window.confirm(question)) return;
          post(path + '/' + p.version + '/activate').then(loadProfiles).catch(reportError);
        } }));
    if (p.version > 1) {
      actions.append(' ', el('button', { type: 'button', class: 'show-diff', text: 'Changes',
        'aria-label': 'Changes from ' + p.name + ' version ' + (p.version - 1) + ' to ' + p.version,
        onclick: () => api(path + '/' + p.version + '/diff')
          .then((d) => d.summary)
          .catch((error) => 'v' + (p.version - 1) + ' -> v' + p.version + ': ' + error.message)
          .then((text) => {
            $('profile-diff').textContent = text;
            $('profile-diff').setAttribute('data-version', p.version);
          }) }));
    }
    if (p.active) {
      actions.append(' ', el('button', { type: 'button', class: 'rollback live-action',
        'aria-label': 'Roll back ' + p.name + ' to the version active before', text: 'Roll back',
        onclick: () => {
          // As Activate: the operator confirms what the machine's next jobs will use.
          const question = 'Roll back ' + p.name + ' on machine ' + machine + '?\n'
            + p.name + ' goes back to the version that was active before v' + p.version
            + '; the machine\u2019s next jobs use the ' + labelOf(p.kind).toLowerCase()
            + ' activated last.';
          if (!window.confirm(question)) return;
          post(path + '/rollback').then(loadProfiles).catch(reportError);
        } }));
    }
    if (p.kind === 'error_map') {
      actions.append(' ', el('button', { type: 'button', class: 'show-heatmap', text: 'Heat map',
        'aria-label': 'Heat map of ' + p.name + ' version ' + p.version,
        onclick: () => showHeatmap(machine, p).catch(reportError) }));
    }
    return el('tr', { 'data-profile': p.name, 'data-version': p.version, 'data-kind': p.kind,
      'data-active': String(p.active), 'data-in-use': String(p.in_use) },
      el('td', { text: p.name }), el('td', { text: labelOf(p.kind) }), el('td', { class: 'num', text: String(p.version) }),
      el('td', { class: 'profile-active', text: p.in_use ? 'in use' : p.active ? 'active, not in use' : '',
        title: p.active && !p.in_use ? 'Jobs use ' + inUseByKind.get(p.kind)?.name + ' (activated later); Activate puts this one back in use.' : null }),
      el('td', {}, timeEl(p.created_at)), el('td', { text: p.note || '' }), actions);
  });
  $('profile-rows').replaceChildren(...rows);
  // Show the heat map of the error map in use (or the newest error map) by default.
  const maps = profiles.filter((p) => p.kind === 'error_map');
  const shown = maps.find((p) => p.in_use) || maps[maps.length - 1];
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
    // Live again only with the service's own word on everything: its `hello` (machines)
    // and the lists fetched after it.
  });
  socket.addEventListener('message', (event) => {
    try { handleEvent(JSON.parse(event.data)); } catch (error) { reportError(error); }
  });
  socket.addEventListener('close', () => {
    if (view.socket !== socket) return;
    view.socket = null;
    $('connection').textContent = 'Not live: the box cannot be reached; what is shown may be out of date. Reconnecting';
    $('connection').setAttribute('data-state', 'closed');
    setLive(false);
    if (!view.token) return;
    // Back off up to 10 s; the lists are reloaded on reconnect (events were missed).
    setTimeout(connectEvents, view.reconnectDelayMs);
    view.reconnectDelayMs = Math.min(view.reconnectDelayMs * 2, 10000);
  });
}

// Live: the event connection is open and the lists were fetched after it opened. Not
// live: everything is marked out of date, estimates hidden and actions disabled.
function setLive(live) {
  view.live = live;
  document.body.setAttribute('data-live', String(live));
  $('stale').hidden = live;
  for (const button of document.querySelectorAll('.live-action')) {
    button.disabled = !live || button.getAttribute('data-off') === 'true';
  }
  renderRunning();
}

function handleEvent(message) {
  switch (message.type) {
    case 'hello':
      view.machines = new Map(message.machines.map((m) => [m.id, m]));
      for (const m of message.machines) if (m.job) upsertJob(m.job);
      dropStaleFrames();
      renderMachines();
      for (const m of message.machines) if (m.state === 'busy') loadFrame(m.id);
      // After a reconnect (a restart, maybe) what happened meanwhile is the service's:
      // the history and the job shown are fetched again before the page is live.
      // (The job shown is fetched whole: its measurements' events were missed too.)
      Promise.all([loadHistory(), view.detailJob !== null ? showJob(view.detailJob) : null])
        .then(() => setLive(true)).catch(reportError);
      loadProfiles().catch(reportError);
      break;
    case 'machine':
      view.machines.set(message.machine.id, message.machine);
      if (message.machine.job) upsertJob(message.machine.job);
      dropStaleFrames();
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
      // Progress belongs to a running job; a late one of a job that ended is dropped.
      if (job && job.state !== 'running' && job.state !== 'queued') break;
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
// (`components.schemas["job.<kind>"]` of the OpenAPI document): the same types, defaults
// and ranges the API checks. The page reads every field as an operator types it and
// checks them all against the schema before anything is queued, each refusal beside its
// field; the API checks again, and its refusal (a file its reader cannot read, say) is
// shown beside the field it names.

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
    select.replaceChildren(...kinds.map((k) => el('option', { value: k, text: kindLabel(k) })));
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
    help: schema.description || inner.description || '', shopHelp: schema['x-help'], format: inner.format,
    items: inner.items, pattern: inner.pattern ?? schema.pattern,
    minItems: inner.minItems ?? schema.minItems, maxItems: inner.maxItems ?? schema.maxItems,
  };
}

// "between 0.25 and 10 000 mm", "at least 1", "from 5".
function rangeWords(spec, unit) {
  const u = unit ? '\u00a0' + unit : '';
  const n = (v) => fmtNumber(v, '');
  if (spec.min !== undefined && spec.max !== undefined) return 'between ' + n(spec.min) + ' and ' + n(spec.max) + u;
  if (spec.min !== undefined) return 'at least ' + n(spec.min) + u;
  if (spec.max !== undefined) return 'at most ' + n(spec.max) + u;
  return '';
}

// A number as people type it: `12.5`, `12,5`, `-3`, `1e-3`, `10 000`, `12,5 mm` (the
// field's own unit may follow). Refused, with the reason, when it cannot be read exactly:
// two decimal marks, a comma followed by exactly three digits (`1,250`: 1.25 or 1250?),
// another unit, anything else. Returns { value } or { error }.
function readNumber(raw, unit, integer) {
  let text = raw.trim().replace(/[\u00a0\u202f\u2009]/g, ' ').replace(/\u2212/g, '-');
  if (unit) {
    const units = unit === 'µm' ? ['µm', 'μm', 'um'] : [unit];
    const found = units.find((u) => text.toLowerCase().endsWith(u.toLowerCase()));
    if (found) text = text.slice(0, -found.length).trim();
  }
  const trailing = text.match(/[a-zµμ°″"']+\s*$/i);
  if (trailing && /\d/.test(text) && !/^e$/i.test(trailing[0])) {
    return { error: 'is in ' + (unit || 'plain numbers') + '; "' + trailing[0].trim() + '" cannot be used here. Type the value in ' + (unit || 'numbers') + ' only' };
  }
  // Spaces between groups of three digits: 10 000.
  if (/^[+-]?\d{1,3}( \d{3})+([.,]\d+)?$/.test(text)) text = text.replace(/ /g, '');
  const commas = (text.match(/,/g) || []).length;
  const points = (text.match(/\./g) || []).length;
  if (commas + points > 1) return { error: 'has more than one decimal mark; type it like 12.5 or 12,5' };
  if (commas === 1 && /^[+-]?\d+,\d{3}$/.test(text)) {
    const [a, b] = text.split(',');
    return { error: 'could be ' + a + '.' + b + ' or ' + a + b + '; type it without the comma, or with a point' };
  }
  const normal = text.replace(',', '.');
  if (!/^[+-]?(\d+\.?\d*|\.\d+)(e[+-]?\d+)?$/i.test(normal)) {
    return { error: raw.trim() === '' ? 'is empty' : 'is not a number' + (/[a-z]/i.test(normal) ? '' : ' the page can read') + '; type digits, e.g. 12.5 or 12,5' };
  }
  const value = Number(normal);
  if (!Number.isFinite(value)) return { error: 'is too large' };
  if (integer) {
    if (!Number.isInteger(value)) return { error: 'must be a whole number; you entered ' + raw.trim() };
    if (!Number.isSafeInteger(value)) return { error: 'is too large to be read exactly' };
  }
  return { value };
}

// A list of numbers (`X, Y`): separated by `;` or spaces (a comma is a decimal mark).
function readNumbers(raw, unit) {
  const tokens = raw.trim().split(/\s*;\s*|\s+/).map((t) => t.replace(/,$/, '')).filter(Boolean);
  const values = [];
  for (const token of tokens) {
    const read = readNumber(token, unit, false);
    if (read.error) return { error: '"' + token + '" ' + read.error };
    values.push(read.value);
  }
  return { value: values };
}

function fieldInput(name, spec, required, kind) {
  const id = 'field-' + name;
  const common = { id, name, 'data-field-input': name, 'aria-describedby': id + '-help ' + id + '-error' };
  if (spec.type === 'boolean') return el('input', { ...common, type: 'checkbox', checked: spec.def === true ? '' : null });
  if (spec.choices) {
    const options = spec.choices.map((c) => el('option', { value: c, text: c }));
    if (!required) options.unshift(el('option', { value: '', text: spec.def === undefined || spec.def === null ? '(default)' : '(default: ' + spec.def + ')' }));
    const select = el('select', common, ...options);
    select.value = required ? spec.choices[0] : '';
    return select;
  }
  if (spec.format === 'binary' || spec.format === 'byte') {
    // A file's text (a layout, a program, a measurements file), or a picture sent as
    // base64 (`byte`: a frame to localize): checked when chosen; a layout's extension
    // sets the `format` field.
    const accept = leafOf(name) === 'layout' ? '.json,.dxf,.svg' : spec.format === 'byte' ? '.png,image/png' : undefined;
    const input = el('input', { ...common, type: 'file', accept });
    input.addEventListener('change', () => checkUpload(input, name, spec, kind));
    return input;
  }
  if (spec.type === 'array' && spec.items && spec.items.type === 'string') {
    return el('textarea', { ...common, rows: 2, placeholder: 'one per line' });
  }
  if (spec.type === 'array') {
    return el('input', { ...common, type: 'text', inputmode: 'decimal', autocomplete: 'off', placeholder: 'X; Y',
      value: Array.isArray(spec.def) ? spec.def.join('; ') : '' });
  }
  if (spec.type === 'integer' || spec.type === 'number') {
    // Text, not type=number: a browser's number field turns `12,5` into nothing or 125.
    return el('input', { ...common, type: 'text', inputmode: spec.type === 'integer' ? 'numeric' : 'decimal',
      autocomplete: 'off', value: spec.def === null || spec.def === undefined ? null : String(spec.def),
      placeholder: spec.nullable || !required ? 'default' : '' });
  }
  return el('input', { ...common, type: 'text', autocomplete: 'off', value: spec.def,
    placeholder: spec.nullable ? 'default' : '' });
}

// A chosen layout file, checked before anything is sent: its kind from its name and first
// bytes (a picture or a binary file is refused at once); the service's reader has the
// last word when the job is queued.
const LAYOUT_FORMATS = ['json', 'dxf', 'svg'];
async function checkUpload(input, name, spec, kind) {
  const file = input.files[0];
  const help = document.getElementById('field-' + name + '-help'); // built with the form
  setFieldError(name, '');
  if (!file) {
    help.textContent = fieldHelp(kind, name, spec);
    return;
  }
  const ext = file.name.includes('.') ? file.name.split('.').pop().toLowerCase() : '';
  const layout = leafOf(name) === 'layout';
  const format = document.getElementById('field-' + name.slice(0, -leafOf(name).length) + 'format'); // built with the form
  if (layout && format && LAYOUT_FORMATS.includes(ext)) format.value = ext;
  help.textContent = file.name + ', ' + fmtNumber(file.size / 1024, '') + ' kB';
  const problem = spec.format === 'byte' ? await pictureProblem(file) : await uploadProblem(file, ext, layout);
  if (problem) setFieldError(name, problem);
}

// A frame to localize: a PNG picture (the service decodes it and says more).
async function pictureProblem(file) {
  const head = new Uint8Array(await file.slice(0, 8).arrayBuffer());
  const png = [0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a].every((b, i) => head[i] === b);
  return png ? '' : file.name + ' is not a PNG picture: choose the camera\u2019s frame saved as PNG.';
}

// A file's bytes as base64 (what a `byte` field carries).
async function base64Of(file) {
  const bytes = new Uint8Array(await file.arrayBuffer());
  let text = '';
  for (let i = 0; i < bytes.length; i += 0x8000) text += String.fromCharCode(...bytes.subarray(i, i + 0x8000));
  return btoa(text);
}

async function uploadProblem(file, ext, layout) {
  const head = new Uint8Array(await file.slice(0, 16).arrayBuffer());
  const starts = (...bytes) => bytes.every((b, i) => head[i] === b);
  const picture = starts(0x89, 0x50, 0x4e, 0x47) ? 'a PNG picture' : starts(0xff, 0xd8, 0xff) ? 'a JPEG picture'
    : starts(0x25, 0x50, 0x44, 0x46) ? 'a PDF document' : starts(0x50, 0x4b, 0x03, 0x04) ? 'a ZIP archive' : '';
  if (picture && !layout) return file.name + ' is ' + picture + ', not a text file: choose the file the job reads.';
  if (picture) return file.name + ' is ' + picture + ', not a layout: choose the layout\u2019s JSON, DXF or SVG file.';
  if (layout && !LAYOUT_FORMATS.includes(ext)) return file.name + ': a layout is a .json, .dxf or .svg file.';
  const text = await file.text();
  if (text.includes('\ufffd') || text.includes('\u0000')) return file.name + ' is not a text file' + (layout ? ', so not a layout.' : '.');
  if (!layout) return '';
  if (ext === 'json') {
    try { JSON.parse(text); } catch (error) { return file.name + ' is not valid JSON: ' + error.message; }
  }
  return '';
}

function fieldHelp(kind, name, spec) {
  const unit = unitOf(name);
  const range = spec.type === 'integer' || spec.type === 'number' ? rangeWords(spec, unit) : '';
  const text = spec.shopHelp || cleanHelp(spec.help);
  return text + (range ? ' (' + range + ')' : '');
}

// A schema's fields, those of a nested object (a cut's `partition`) named by their path
// (`partition.tools`): [name, schema, required].
function formFields(schema, prefix = '') {
  const required = new Set((schema && schema.required) || []);
  const properties = (schema && schema.properties) || {};
  return Object.entries(properties).flatMap(([name, prop]) => {
    // Real ports on the box a command runs on: the service refuses them, so no field.
    if (prop['x-command-line-only']) return [];
    // How messages name a chosen file (`program_name` for `program`): the file's own
    // name, sent with it (readForm), never typed.
    if (fileNameField(properties, name)) return [];
    // An object field, inline (`oneOf` of one object when it has its own description).
    const inner = prop.oneOf && prop.oneOf.length === 1 ? prop.oneOf[0] : prop;
    return inner.type === 'object' && inner.properties ? formFields(inner, prefix + name + '.')
      : [[prefix + name, prop, required.has(name)]];
  });
}

// Whether `name` is the field that names the file of another (`program_name`).
function fileNameField(properties, name) {
  if (!name.endsWith('_name') || !properties[name]) return false;
  const file = properties[name.slice(0, -'_name'.length)];
  const format = file && fieldSpec(file).format;
  return format === 'binary' || format === 'byte';
}

// `{'partition.tools': 2}` as `{partition: {tools: 2}}`.
function nested(flat) {
  const out = {};
  for (const [path, value] of Object.entries(flat)) {
    const keys = path.split('.');
    let at = out;
    for (const k of keys.slice(0, -1)) at = at[k] = at[k] || {};
    at[keys[keys.length - 1]] = value;
  }
  return out;
}

const leafOf = (name) => name.split('.').pop();

function renderForm() {
  const kind = $('job-kind').value;
  const schema = view.schemas[kind];
  $('job-kind-help').textContent = schema ? schema['x-help'] || cleanHelp(schema.description) : '';
  $('form-errors').replaceChildren();
  const rows = formFields(schema).map(([name, prop, required]) => {
    const spec = fieldSpec(prop);
    const unit = unitOf(name);
    return el('div', { class: 'field', 'data-field': name, 'data-type': spec.type || 'string' },
      el('label', { for: 'field-' + name, text: labelOf(leafOf(name)) + (unit ? ' (' + unit + ')' : '') + (required ? ' *' : '') }),
      fieldInput(name, spec, required, kind),
      el('small', { id: 'field-' + name + '-help', class: 'help', text: fieldHelp(kind, name, spec) }),
      el('span', { id: 'field-' + name + '-error', class: 'field-error', 'data-field-error': name }));
  });
  $('job-fields').replaceChildren(...rows);
}

function setFieldError(name, message) {
  const span = $('job-fields').querySelector('[data-field-error="' + CSS.escape(name) + '"]');
  if (!span) return false;
  span.textContent = message;
  const input = span.parentElement.querySelector('[data-field-input]');
  if (message) input.setAttribute('aria-invalid', 'true');
  else input.removeAttribute('aria-invalid');
  return true;
}

// Every field read and checked against the kind's schema: { params, errors } where
// errors maps a field to its refusal in words ("Grid step must be between 0.25 and
// 10 000 mm; you entered 0.01"). An empty optional field is left out (the default).
async function readForm() {
  const kind = $('job-kind').value;
  const schema = view.schemas[kind] || {};
  const params = {};
  const errors = {};
  const fields = new Map(formFields(schema).map(([name, prop, isRequired]) => [name, [prop, isRequired]]));
  const required = new Set([...fields].filter(([, [, r]]) => r).map(([name]) => name));
  for (const row of $('job-fields').querySelectorAll('.field')) {
    const name = row.dataset.field;
    const spec = fieldSpec((fields.get(name) || [{}])[0]);
    const input = row.querySelector('[data-field-input]');
    const label = labelOf(leafOf(name));
    const unit = unitOf(name);
    const text = input.type === 'file' ? '' : String(input.value || '').trim();
    if (input.type === 'checkbox') {
      // Sent when it says something the default does not: a box that is on by default
      // (a dnc job's `send`) and cleared is sent as false, not left to the default.
      if (input.checked || spec.def === true) params[name] = input.checked;
      continue;
    }
    if (input.type === 'file') {
      const file = input.files[0];
      if (!file) {
        if (required.has(name)) errors[name] = label + ' is needed: choose the file.';
        continue;
      }
      const picture = spec.format === 'byte';
      const problem = picture ? await pictureProblem(file)
        : await uploadProblem(file, file.name.split('.').pop().toLowerCase(), leafOf(name) === 'layout');
      if (problem) errors[name] = problem;
      else params[name] = picture ? await base64Of(file) : await file.text();
      // Messages name it as the operator knows it.
      const properties = name.includes('.') ? {} : schema.properties || {};
      if (fileNameField(properties, name + '_name')) params[name + '_name'] = file.name;
      continue;
    }
    if (text === '') {
      if (required.has(name)) errors[name] = label + ' is needed.';
      continue;
    }
    if (spec.choices) {
      params[name] = text;
    } else if (spec.type === 'integer' || spec.type === 'number') {
      const read = readNumber(text, unit, spec.type === 'integer');
      if (read.error) {
        errors[name] = label + ' ' + read.error + '.';
        continue;
      }
      const v = read.value;
      if ((spec.min !== undefined && v < spec.min) || (spec.max !== undefined && v > spec.max)) {
        errors[name] = label + ' must be ' + rangeWords(spec, unit) + '; you entered ' + text + '.';
        continue;
      }
      params[name] = v;
    } else if (spec.type === 'array' && input.tagName === 'TEXTAREA') {
      params[name] = text.split('\n').map((l) => l.trim()).filter(Boolean);
    } else if (spec.type === 'array') {
      const read = readNumbers(text, unit);
      const want = spec.minItems !== undefined && spec.minItems === spec.maxItems ? spec.minItems : 2;
      if (read.error) errors[name] = label + ': ' + read.error + '.';
      else if (read.value.length !== want) {
        errors[name] = label + ' needs ' + want + ' numbers separated by ";" or a space, like 1.5; -2 (you entered ' + text + ').';
      } else params[name] = read.value;
    } else {
      if (spec.pattern && !new RegExp(spec.pattern).test(text)) {
        errors[name] = spec.pattern === '^[A-Za-z0-9_-]{1,64}$'
          ? label + ' may hold letters, digits, - and _ only, at most 64 of them; you entered "' + text + '".'
          : label + ' does not have the expected form; you entered "' + text + '".';
        continue;
      }
      params[name] = text;
    }
  }
  // A bound that depends on another field (the layout's clearance is at most its gap).
  if (params.clearance_mm !== undefined && params.gap_mm !== undefined && params.clearance_mm > params.gap_mm) {
    errors.clearance_mm = 'Clearance must be at most the gap, ' + fmtNumber(params.gap_mm, 'mm') + ' mm; you entered '
      + fmtNumber(params.clearance_mm, 'mm') + '.';
  }
  return { params: nested(params), errors };
}

function clearFieldErrors() {
  for (const span of $('job-fields').querySelectorAll('.field-error')) span.textContent = '';
  for (const input of $('job-fields').querySelectorAll('[aria-invalid]')) input.removeAttribute('aria-invalid');
  $('form-errors').replaceChildren();
}

// Every refusal beside its field, and their list above the Start button (each links to
// its field); the first invalid field gets the focus.
function showFormErrors(errors) {
  const names = Object.keys(errors);
  for (const name of names) setFieldError(name, errors[name]);
  $('form-errors').replaceChildren(
    el('p', { text: names.length === 1 ? 'One field needs attention; nothing was started:'
      : names.length + ' fields need attention; nothing was started:' }),
    el('ul', {}, ...names.map((name) => el('li', {}, el('a', { href: '#field-' + name, text: errors[name] })))));
  const first = document.getElementById('field-' + names[0]);
  if (first) first.focus();
}

// An API refusal in the form's words: `params.grid_step_mm: must be ...` -> "Grid step
// must be ...".
function apiFieldMessage(field, message) {
  const path = field.replace(/^params\.?/, '').replace(/\[.*$/, '');
  // The form's field of that path (a nested one: `partition.tools`), else its top.
  const name = document.querySelector('[data-field="' + CSS.escape(path) + '"]') ? path : path.split('.')[0];
  const text = message.startsWith(field + ': ') ? message.slice(field.length + 2) : message;
  return { name, text: labelOf(leafOf(name)) + ': ' + text };
}

async function startJob(event) {
  event.preventDefault();
  $('error').textContent = '';
  clearFieldErrors();
  const { params, errors } = await readForm();
  if (Object.keys(errors).length) {
    showFormErrors(errors);
    return;
  }
  const machine = $('job-machine').value;
  const response = await fetch('/api/v1/machines/' + encodeURIComponent(machine) + '/jobs', {
    method: 'POST',
    headers: { Authorization: 'Bearer ' + view.token, 'Content-Type': 'application/json' },
    body: JSON.stringify({ kind: $('job-kind').value, params }),
  });
  const body = await response.json().catch(() => ({}));
  if (response.status === 401) {
    showLogin('The token was refused; enter a valid one.');
    return;
  }
  if (!response.ok) {
    // `params.grid_step_mm`, `assign[2]`: the field's row shows the API's message.
    const { name, text } = apiFieldMessage(String(body.field || ''), String(body.message || body.error));
    if (name && setFieldError(name, text)) showFormErrors({ [name]: text });
    else $('error').textContent = (body.message || response.statusText);
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
  // The raw records are for developers: shown only with this toggle, kept per browser.
  const developer = localStorage.getItem('gateway.developer') === 'true';
  $('developer').checked = developer;
  document.body.classList.toggle('developer', developer);
  $('developer').addEventListener('change', () => {
    localStorage.setItem('gateway.developer', String($('developer').checked));
    document.body.classList.toggle('developer', $('developer').checked);
  });
  setInterval(refreshTimes, 30000);
  // A link with #token= opened on a page already loaded changes only the fragment.
  window.addEventListener('hashchange', () => {
    const fresh = takeToken();
    if (fresh && fresh !== view.token) enter(fresh).catch(reportError);
  });
  const token = takeToken();
  if (token) enter(token).catch(reportError);
  else showLogin('');
});
