#!/usr/bin/env node
// CNCjs (npm `cncjs`, run headless) as the G-code sender: its server opens the serial
// port with its own GRBL controller code, and this script drives it through its
// socket.io API as its web page and pendants do: open the port, home, load a program,
// start it, and wait until CNCjs says every line was answered.
//
// Usage: node cncjs_sender.js CNCJS_DIR SERIAL_PORT GCODE_FILE
//   CNCJS_DIR holds node_modules/cncjs (npm install cncjs@1.11.5 there).
// Prints one JSON object: {"ok", "total", "received", "errors", "alarms", "final_status",
// "lines_read"}; exit status 1 on a timeout or a failure to connect.
'use strict';
const path = require('path');
const fs = require('fs');
const os = require('os');
const net = require('net');
const { spawn } = require('child_process');

const [cncjsDir, serialPort, gcodeFile] = process.argv.slice(2);
const mod = (m) => require(path.join(cncjsDir, 'node_modules', m));
const jwt = mod('jsonwebtoken');
const io = mod('socket.io-client');

const TIMEOUT_MS = 120000;
const out = { ok: false, total: 0, received: 0, errors: [], alarms: [], final_status: null, lines_read: 0 };
let server = null;

function finish(ok, why) {
  out.ok = ok;
  if (why) out.why = why;
  process.stdout.write(JSON.stringify(out) + '\n');
  if (server) server.kill('SIGKILL');
  process.exit(ok ? 0 : 1);
}
setTimeout(() => finish(false, 'timed out'), TIMEOUT_MS);

function freePort() {
  return new Promise((resolve) => {
    const s = net.createServer();
    s.listen(0, '127.0.0.1', () => {
      const { port } = s.address();
      s.close(() => resolve(port));
    });
  });
}

async function main() {
  const dir = fs.mkdtempSync(path.join(os.tmpdir(), 'cncjs-'));
  const config = path.join(dir, 'cncrc.json');
  const secret = 'interop-' + process.pid;
  fs.writeFileSync(config, JSON.stringify({ secret, state: { checkForUpdates: false } }));
  const port = await freePort();
  server = spawn(process.execPath, [
    path.join(cncjsDir, 'node_modules', 'cncjs', 'bin', 'cncjs'),
    '-p', String(port), '-H', '127.0.0.1', '-c', config, '--controller', 'Grbl',
  ], { stdio: ['ignore', 'ignore', 'pipe'], env: { ...process.env, HOME: dir } });
  server.stderr.on('data', () => {});
  const token = jwt.sign({ id: '', name: 'interop' }, secret, { expiresIn: '1h' });
  const gcode = fs.readFileSync(gcodeFile, 'utf8');

  let socket = null;
  // The server takes a few seconds to listen: retry until it answers.
  const connect = () => {
    socket = io.connect('ws://127.0.0.1:' + port, { query: 'token=' + token, reconnection: true, reconnectionDelay: 200 });
    socket.on('connect', onConnect);
  };
  let opened = false;
  let homed = false;
  let started = false;
  const onConnect = () => {
    if (opened) return;
    opened = true;
    socket.emit('open', serialPort, { controllerType: 'Grbl', baudrate: 115200 }, (err) => {
      if (err) finish(false, 'open: ' + err);
    });
  };
  connect();
  socket.on('serialport:read', (line) => {
    out.lines_read += 1;
    if (/^error:/.test(line)) out.errors.push(line);
    if (/^ALARM:/.test(line)) out.alarms.push(line);
  });
  socket.on('controller:state', (type, state) => {
    const status = state && state.status;
    if (!status) return;
    out.final_status = { activeState: status.activeState, mpos: status.mpos, wpos: status.wpos };
    if (!homed && (status.activeState === 'Alarm' || status.activeState === 'Idle')) {
      homed = true;
      socket.emit('command', serialPort, 'homing');
      return;
    }
    if (homed && !started && status.activeState === 'Idle') {
      started = true;
      socket.emit('command', serialPort, 'gcode:load', path.basename(gcodeFile), gcode, (err, data) => {
        if (err) finish(false, 'gcode:load: ' + err);
        out.total = data.total;
        socket.emit('command', serialPort, 'gcode:start');
      });
    }
  });
  socket.on('sender:status', (s) => {
    if (!started) return;
    out.total = s.total;
    out.received = s.received;
    if (s.total > 0 && s.received >= s.total && s.finishTime > 0) {
      // One more status report for the final position.
      setTimeout(() => finish(out.errors.length === 0 && out.alarms.length === 0), 500);
    }
  });
}

main().catch((e) => finish(false, String(e && e.stack || e)));
