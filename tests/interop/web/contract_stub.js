#!/usr/bin/env node
// A stand-in for `gateway serve` that answers the API v1 of the service contract with
// made-up data (one machine "demo"; a job runs 5 steps and makes a new version of the
// error map "xy"). It lets the page and drive_page.js be developed and checked without
// the service: node contract_stub.js PORT TOKEN (PORT 0: any free port, printed as "listening PORT"), then open http://127.0.0.1:PORT/#token=TOKEN.
// tests/tests/web_page_stub.rs drives the page against it; tests/tests/service_web.rs
// runs the real service.
'use strict';
const http = require('http');
const fs = require('fs');
const path = require('path');
const crypto = require('crypto');
const zlib = require('zlib');

const [port, token] = [Number(process.argv[2] || 8099), process.argv[3] || 'stub-token'];
const web = path.join(__dirname, '..', '..', '..', 'gateway', 'webpage', 'web');
const now = () => new Date().toISOString();
const machine = { id: 'demo', description: 'stub machine', stage: 'sim', camera: 'sim', state: 'idle',
  state_detail: null, job: null, queued: 0, queue: [] };
const jobs = new Map();
const measurements = new Map();
const profiles = [];
const activations = []; // stack of versions
const sockets = new Set();
let nextId = 1;

function send(socket, object) {
  const data = Buffer.from(JSON.stringify(object));
  let header;
  if (data.length < 126) header = Buffer.from([0x81, data.length]);
  else if (data.length < 65536) { header = Buffer.from([0x81, 126, 0, 0]); header.writeUInt16BE(data.length, 2); }
  else { header = Buffer.alloc(10); header[0] = 0x81; header[1] = 127; header.writeBigUInt64BE(BigInt(data.length), 2); }
  socket.write(Buffer.concat([header, data]));
}
const broadcast = (object) => sockets.forEach((s) => send(s, object));

// The camera's last frame: a made-up 64 x 48 8-bit grey PNG with a 4 x 3 grid of dark
// dots, and its overlay (as the service's frame.json).
let frame = null;
function crc32(bytes) {
  let c = ~0;
  for (const b of bytes) {
    c ^= b;
    for (let k = 0; k < 8; k++) c = (c >>> 1) ^ (0xedb88320 & -(c & 1));
  }
  return ~c >>> 0;
}
function chunk(type, data) {
  const head = Buffer.alloc(8);
  head.writeUInt32BE(data.length, 0);
  head.write(type, 4, 'ascii');
  const crc = Buffer.alloc(4);
  crc.writeUInt32BE(crc32(Buffer.concat([head.subarray(4), data])), 0);
  return Buffer.concat([head, data, crc]);
}
function makeFrame(jobId, step) {
  const [w, h] = [64, 48];
  const dots = [];
  for (let j = 0; j < 3; j++) for (let i = 0; i < 4; i++) dots.push([8 + 16 * i + step % 3, 8 + 16 * j]);
  const raw = Buffer.alloc((w + 1) * h, 200);
  for (let y = 0; y < h; y++) {
    raw[y * (w + 1)] = 0; // filter: none
    for (let x = 0; x < w; x++) {
      if (dots.some(([dx, dy]) => (x - dx) ** 2 + (y - dy) ** 2 <= 9)) raw[y * (w + 1) + 1 + x] = 30;
    }
  }
  const ihdr = Buffer.alloc(13);
  ihdr.writeUInt32BE(w, 0); ihdr.writeUInt32BE(h, 4); ihdr[8] = 8; ihdr[9] = 0;
  const png = Buffer.concat([Buffer.from([0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a]), chunk('IHDR', ihdr),
    chunk('IDAT', zlib.deflateSync(raw)), chunk('IEND', Buffer.alloc(0))]);
  const overlay = { width: w, height: h, source_width: w * 4, source_height: h * 4, factor: 4, dots,
    centre_px: [31.5, 23.5], centre_mm: [step * 10 + 0.001, 5], target_mm: [step * 10, 5], target_index: 0,
    deviation_um: [1, 0], sequence: step };
  return { png, json: { machine: 'demo', job_id: jobId, at: now(), overlay } };
}

function profileView(p) {
  const active = activations.length > 0 && activations[activations.length - 1] === p.version;
  // One profile name here: its active version is the one in use.
  return { machine: 'demo', name: 'xy', kind: 'error_map', version: p.version, active, in_use: active,
    created_at: p.created_at, source_job: p.source_job, note: null };
}

function runJob(job) {
  job.state = 'running'; job.started_at = now(); job.progress = { done: 0, total: 5 };
  machine.state = 'busy'; machine.job = job;
  broadcast({ type: 'job', job }); broadcast({ type: 'machine', machine });
  let step = 0;
  const timer = setInterval(() => {
    step += 1;
    const m = { point: step, x_mm: step * 10, dev_um: Math.sin(step) * 3 };
    measurements.get(job.id).push(m);
    job.progress = { done: step, total: 5 };
    broadcast({ type: 'progress', job_id: job.id, machine: 'demo', done: step, total: 5 });
    broadcast({ type: 'measurement', job_id: job.id, machine: 'demo', measurement: m });
    frame = makeFrame(job.id, step);
    broadcast({ type: 'frame', job_id: job.id, machine: 'demo', at: frame.json.at, sequence: step });
    if (step === 5) {
      clearInterval(timer);
      job.state = 'succeeded'; job.finished_at = now(); job.result = { max_um: 3 };
      profiles.push({ version: profiles.length + 1, created_at: now(), source_job: job.id });
      machine.state = 'idle'; machine.job = null;
      broadcast({ type: 'job', job }); broadcast({ type: 'machine', machine });
    }
  }, 150);
}

function reply(res, status, body, type) {
  res.writeHead(status, { 'Content-Type': type || 'application/json' });
  res.end(type ? body : JSON.stringify(body));
}

const openapi = { openapi: '3.1.0', components: { schemas: {
  'job.map': { type: 'object', description: 'An error-map scan.', additionalProperties: false, properties: {
    name: { type: 'string', default: 'map', description: "The map's name." },
    grid_step_mm: { type: 'number', default: 10, minimum: 0.25, maximum: 10000, description: "The grid's step, mm." },
    line_step_mm: { type: 'number', default: 1, minimum: 0.05, maximum: 10000, description: 'The dense lines\' step, mm.' },
    passes: { type: 'integer', default: 2, minimum: 1, maximum: 10, description: 'Times each point is measured.' },
    tool_offset_mm: { type: 'array', items: { type: 'number' }, default: [0, 0], description: 'Tool minus camera, mm.' },
  } },
} } };

const svg = (label) => `<svg xmlns="http://www.w3.org/2000/svg" width="200" height="100"><rect width="200" height="100" fill="#fc8"/><text x="10" y="50">${label}</text></svg>`;

const server = http.createServer((req, res) => {
  const url = new URL(req.url, 'http://stub');
  const files = { '/': ['index.html', 'text/html'], '/app.js': ['app.js', 'text/javascript'], '/style.css': ['style.css', 'text/css'] };
  if (files[url.pathname]) {
    return reply(res, 200, fs.readFileSync(path.join(web, files[url.pathname][0])), files[url.pathname][1]);
  }
  if (req.headers.authorization !== 'Bearer ' + token) return reply(res, 401, { error: 'unauthorized', message: 'bad token' });
  let body = '';
  req.on('data', (c) => { body += c; });
  req.on('end', () => {
    const p = url.pathname;
    let m;
    if (p === '/api/v1/machines') return reply(res, 200, [machine]);
    // The contract's job params as the service's OpenAPI document gives them (a subset:
    // the map kind's, with the same bounds; the page builds its form from it).
    if (p === '/api/v1/openapi.json') return reply(res, 200, openapi);
    if (p === '/api/v1/machines/demo/frame' || p === '/api/v1/machines/demo/frame.json') {
      if (!frame) return reply(res, 404, { error: 'no_frame', message: 'machine "demo" has shown no camera frame' });
      return p.endsWith('.json') ? reply(res, 200, frame.json) : reply(res, 200, frame.png, 'image/png');
    }
    if (p === '/api/v1/jobs') return reply(res, 200, [...jobs.values()].reverse());
    if (req.method === 'POST' && p === '/api/v1/machines/demo/jobs') {
      const request = JSON.parse(body);
      const grid = (request.params || {}).grid_step_mm;
      if (grid !== undefined && !(grid >= 0.25 && grid <= 10000)) {
        return reply(res, 400, { error: 'invalid_params', field: 'params.grid_step_mm',
          message: `params.grid_step_mm: must be a number from 0.25 to 10000, got ${grid}` });
      }
      const job = { id: nextId++, machine: 'demo', kind: request.kind, params: request.params, state: 'queued',
        created_at: now(), started_at: null, finished_at: null, progress: null, profile: null, error: null, result: null };
      jobs.set(job.id, job); measurements.set(job.id, []);
      broadcast({ type: 'job', job });
      setTimeout(() => runJob(job), 200);
      return reply(res, 202, job);
    }
    if ((m = p.match(/^\/api\/v1\/jobs\/(\d+)$/))) return reply(res, 200, jobs.get(Number(m[1])));
    if ((m = p.match(/^\/api\/v1\/jobs\/(\d+)\/measurements$/))) return reply(res, 200, measurements.get(Number(m[1])));
    if ((m = p.match(/^\/api\/v1\/jobs\/(\d+)\/charts$/))) {
      return reply(res, 200, [{ name: 'deviation', title: 'Deviation', url: `/api/v1/jobs/${m[1]}/charts/deviation.svg` }]);
    }
    if ((m = p.match(/^\/api\/v1\/jobs\/(\d+)\/files$/))) {
      return reply(res, 200, [{ name: 'deviation.svg', title: 'Deviation', media_type: 'image/svg+xml', size: 180,
        url: `/api/v1/jobs/${m[1]}/files/deviation.svg` }]);
    }
    if ((m = p.match(/^\/api\/v1\/machines\/demo\/profiles\/xy\/(\d+)\/diff$/))) {
      const v = Number(m[1]);
      return reply(res, 200, { profile: 'xy', machine: 'demo', from: v - 1, to: v, kind: 'error_map',
        summary: `v${v - 1} -> v${v}: the errors moved by at most 0.50 µm (stub)` });
    }
    if (p.endsWith('.svg')) return reply(res, 200, svg(p), 'image/svg+xml');
    if (p === '/api/v1/machines/demo/profiles') return reply(res, 200, profiles.map(profileView));
    if ((m = p.match(/^\/api\/v1\/machines\/demo\/profiles\/xy\/(\d+)\/activate$/))) {
      const v = Number(m[1]);
      if (activations[activations.length - 1] !== v) activations.push(v);
      return reply(res, 200, profileView(profiles[v - 1]));
    }
    if (p === '/api/v1/machines/demo/profiles/xy/rollback') {
      if (activations.length < 2) return reply(res, 409, { error: 'nothing_to_roll_back', message: 'no earlier activation' });
      activations.pop();
      return reply(res, 200, profileView(profiles[activations[activations.length - 1] - 1]));
    }
    return reply(res, 404, { error: 'not_found', message: p });
  });
});

server.on('upgrade', (req, socket) => {
  const offered = (req.headers['sec-websocket-protocol'] || '').split(',').map((s) => s.trim());
  if (!offered.includes('bearer.' + token)) { socket.end('HTTP/1.1 401 Unauthorized\r\n\r\n'); return; }
  const accept = crypto.createHash('sha1').update(req.headers['sec-websocket-key'] + '258EAFA5-E914-47DA-95CA-C5AB0DC85B11').digest('base64');
  socket.write(`HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Accept: ${accept}\r\nSec-WebSocket-Protocol: gateway.v1\r\n\r\n`);
  sockets.add(socket);
  socket.on('close', () => sockets.delete(socket));
  socket.on('error', () => sockets.delete(socket));
  send(socket, { type: 'hello', machines: [machine] });
});

server.listen(port, '127.0.0.1', () => process.stdout.write(`listening ${server.address().port}\n`));
