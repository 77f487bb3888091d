// The Enbarr surface station page: plain JavaScript, no build step, no network but the
// vessel's own server (the vessel is often offline). Protocol: enbarr_plugins/station/protocol.py.
'use strict';

const AXES = ['surge', 'sway', 'heave', 'yaw'];
// Keys as the terminal teleop (enbarr_plugins/operator/keyboard.py): [axis, direction].
const KEYS = { w: ['surge', 1], s: ['surge', -1], a: ['sway', 1], d: ['sway', -1],
  r: ['heave', 1], f: ['heave', -1], q: ['yaw', 1], e: ['yaw', -1] };
// The browser's standard gamepad mapping of a DualShock 4 (W3C Gamepad, "standard" layout).
const PAD_BUTTONS = { 0: 'cross', 1: 'circle', 2: 'square', 3: 'triangle', 4: 'l1', 5: 'r1',
  6: 'l2', 7: 'r2', 8: 'share', 9: 'options', 10: 'l3', 11: 'r3', 12: 'dpad_up',
  13: 'dpad_down', 14: 'dpad_left', 15: 'dpad_right', 16: 'ps' };
const MODE_PRESS_TICKS = 2;   // a mode button is held this many input ticks: one rising edge

const $ = (id) => document.getElementById(id);
const token = new URLSearchParams(location.search).get('token');
const state = {
  ws: null, hello: null, seq: 0, sendTimer: null, held: {}, holdButtons: {}, pressed: {},
  lights: false, lastTelemetry: 0, telemetry: null, trail: [], truthTrail: [], path: null,
  gain: 0.5, camera: null, image: null, boxes: new Map(), padOptions: false,
};

function fmt(x, digits) { return (x === undefined || x === null) ? '-' : Number(x).toFixed(digits); }
function setText(id, text) { const el = $(id); if (el.textContent !== text) el.textContent = text; }

// -- connection --------------------------------------------------------------------------
function connect() {
  const proto = location.protocol === 'https:' ? 'wss:' : 'ws:';
  const ws = new WebSocket(`${proto}//${location.host}/ws` + (token ? `?token=${encodeURIComponent(token)}` : ''));
  state.ws = ws;
  ws.onopen = () => { setBadge('conn', 'connected', ''); };
  ws.onmessage = (ev) => onMessage(JSON.parse(ev.data));
  ws.onclose = (ev) => {
    stopSending();
    releaseAll();
    setBadge('conn', `disconnected${ev.reason ? ': ' + ev.reason : ''}`, 'bad');
    setTimeout(connect, 1000);
  };
}

function setBadge(id, text, cls) {
  const el = $(id);
  el.textContent = text;
  el.className = 'badge' + (cls ? ' ' + cls : '');
}

function onMessage(msg) {
  if (msg.type === 'hello') {
    state.hello = msg;
    buildControls(msg);
    startSending(msg.input_rate);
  } else if (msg.type === 'telemetry') {
    state.telemetry = msg;
    state.lastTelemetry = performance.now();
    showTelemetry(msg);
  } else if (msg.type === 'error') {
    setText('error', msg.reason);
  }
}

// -- input -------------------------------------------------------------------------------
function startSending(rate) {
  stopSending();
  state.sendTimer = setInterval(sendInput, 1000 / rate);
}

function stopSending() {
  if (state.sendTimer !== null) clearInterval(state.sendTimer);
  state.sendTimer = null;
}

function releaseAll() {
  state.held = {};
  state.holdButtons = {};
  state.pressed = {};
  document.querySelectorAll('.hold.active').forEach((b) => b.classList.remove('active'));
}

function gamepad() {
  const pads = navigator.getGamepads ? navigator.getGamepads() : [];
  for (const p of pads) if (p && p.connected) return p;
  return null;
}

function currentInput() {
  const axes = { surge: 0, sway: 0, heave: 0, yaw: 0 };
  for (const [axis, dir] of Object.values(state.held)) axes[axis] += dir * state.gain;
  const buttons = new Set();
  const pad = gamepad();
  if (pad) {
    setBadge('gamepad', pad.id.slice(0, 30), '');
    const a = pad.axes;
    const b = pad.buttons;
    // Browser: stick up/left reads -1; REP-103: surge ahead, sway port, yaw ccw are +.
    if (state.hello && state.hello.command === 'twist') {
      // The ROV pilot's pad (docs/rov_gamepad.png, control/rov_gamepad.py): right stick
      // surge and sway, left stick heave and yaw; options toggles the lights.
      axes.surge += -(a[3] || 0);
      axes.sway += -(a[2] || 0);
      axes.heave += -(a[1] || 0);
      axes.yaw += -(a[0] || 0);
      const options = b.length > 9 && b[9].pressed;
      if (options && !state.padOptions) toggleLights();
      state.padOptions = options;
    } else {
      axes.surge += -(a[1] || 0);
      axes.sway += -(a[0] || 0);
      axes.yaw += -(a[2] || 0);
      if (b.length > 7) axes.heave += (b[7].value || 0) - (b[6].value || 0);
    }
    b.forEach((btn, i) => { if (btn.pressed && PAD_BUTTONS[i]) buttons.add(PAD_BUTTONS[i]); });
  } else {
    setBadge('gamepad', 'no gamepad', 'warn');
  }
  for (const [name, ticks] of Object.entries(state.pressed)) {
    buttons.add(name);
    if (ticks <= 1) delete state.pressed[name]; else state.pressed[name] = ticks - 1;
  }
  for (const k of AXES) axes[k] = Math.max(-1, Math.min(1, axes[k]));
  return { axes, buttons: [...buttons] };
}

function sendInput() {
  const ws = state.ws;
  if (!ws || ws.readyState !== WebSocket.OPEN) return;
  const inp = currentInput();
  state.seq += 1;
  ws.send(JSON.stringify({ type: 'input', seq: state.seq, t: performance.now(),
    axes: inp.axes, buttons: inp.buttons, lights: state.lights }));
  for (const k of AXES) setText('in-' + k, inp.axes[k].toFixed(2));
  showStaleness();
}

// Our own input is stale when the vessel has not acknowledged an input of ours for longer
// than its timeout (it then stops commanding), or when telemetry stopped arriving.
function showStaleness() {
  const t = state.telemetry;
  const now = performance.now();
  const limit = state.hello ? state.hello.input_timeout * 1000 : 500;
  let stale = true;
  if (t && t.drive && t.drive.holder && t.drive.ack_t !== null) {
    stale = (now - t.drive.ack_t) > limit || (now - state.lastTelemetry) > limit;
  }
  $('input-stale').hidden = !stale;
  if (t && t.drive) {
    if (t.drive.holder) {
      setBadge('drive-state', 'driving', '');
      if ($('error').textContent.startsWith('another page drives')) setText('error', '');
    }
    else if (t.drive.taken) setBadge('drive-state', 'watching: another page drives', 'warn');
    else setBadge('drive-state', 'not driving', 'warn');
  }
}

function pressMode(button) { state.pressed[button] = MODE_PRESS_TICKS; }

function buildControls(hello) {
  const modes = $('modes');
  modes.textContent = '';
  hello.modes.forEach(([mode, button], i) => {
    const b = document.createElement('button');
    b.type = 'button';
    b.id = 'mode-' + mode;
    b.textContent = `${mode} (${button}, ${i + 1})`;
    b.addEventListener('click', () => pressMode(button));
    modes.appendChild(b);
  });
  const rov = hello.command === 'twist';
  document.querySelectorAll('.rov').forEach((el) => { el.hidden = !rov; });
  $('lights-row').hidden = !rov;
}

// The vessel's surface stop (surface_command/stop): it holds the goal at zero whatever any
// command source sends, until released; any page may set it.
function toggleSurfaceStop() {
  if (!state.ws || state.ws.readyState !== WebSocket.OPEN) return;
  const on = !(state.telemetry && state.telemetry.surface_stop);
  state.ws.send(JSON.stringify({ type: 'surface_stop', stop: on }));
}

// The manipulator: the driving page asks for manipulator_step steps one way or the other, the
// same io request the keyboard teleop sends.
function manipulator(direction) {
  if (!state.ws || state.ws.readyState !== WebSocket.OPEN) return;
  state.ws.send(JSON.stringify({ type: 'manipulator', direction }));
}

function record(action) {
  if (!state.ws || state.ws.readyState !== WebSocket.OPEN) return;
  state.ws.send(JSON.stringify({ type: 'record', action }));
}

function toggleLights() {
  state.lights = !state.lights;
  setText('lights', `lights (l): ${state.lights ? 'on' : 'off'}`);
}

document.addEventListener('keydown', (ev) => {
  if (ev.target.tagName === 'INPUT') return;
  const k = ev.key.toLowerCase();
  if (KEYS[k]) { state.held['key-' + k] = KEYS[k]; ev.preventDefault(); }
  else if (k === ' ') { releaseAll(); ev.preventDefault(); }
  else if (k === 'l' && state.hello && state.hello.command === 'twist') toggleLights();
  else if (k === 'x' && state.hello && state.hello.surface_stop) toggleSurfaceStop();
  else if (k === 'm' && state.hello && state.hello.command === 'twist') manipulator(1);
  else if (k === 'n' && state.hello && state.hello.command === 'twist') manipulator(-1);
  else if (['1', '2', '3'].includes(k) && state.hello && state.hello.modes[+k - 1]) {
    pressMode(state.hello.modes[+k - 1][1]);
  }
});
document.addEventListener('keyup', (ev) => { delete state.held['key-' + ev.key.toLowerCase()]; });
window.addEventListener('blur', releaseAll);   // a key released while elsewhere is never seen

document.querySelectorAll('.hold').forEach((b) => {
  const id = 'btn-' + b.dataset.axis + b.dataset.dir;
  const down = (ev) => {
    state.held[id] = [b.dataset.axis, Number(b.dataset.dir)];
    b.classList.add('active');
    ev.preventDefault();
  };
  const up = () => { delete state.held[id]; b.classList.remove('active'); };
  b.addEventListener('pointerdown', down);
  b.addEventListener('pointerup', up);
  b.addEventListener('pointerleave', up);
});
$('stop').addEventListener('click', releaseAll);
$('lights').addEventListener('click', toggleLights);
$('surface-stop').addEventListener('click', toggleSurfaceStop);
$('manipulator-plus').addEventListener('click', () => manipulator(1));
$('manipulator-minus').addEventListener('click', () => manipulator(-1));
$('rec-start').addEventListener('click', () => record('start'));
$('rec-stop').addEventListener('click', () => record('stop'));
$('camera-toggle').addEventListener('click', toggleCamera);
$('gain').addEventListener('input', (ev) => {
  state.gain = Number(ev.target.value);
  setText('gain-value', state.gain.toFixed(2));
});

// -- telemetry ---------------------------------------------------------------------------
function showTelemetry(t) {
  const pose = t.estimate || t.truth;
  if (pose) {
    setText('x', fmt(pose.x, 2)); setText('y', fmt(pose.y, 2)); setText('z', fmt(pose.z, 2));
    setText('heading', fmt(pose.yaw * 180 / Math.PI, 1));
    setText('u', fmt(pose.u, 2)); setText('v', fmt(pose.v, 2)); setText('w', fmt(pose.w, 2));
    setText('r', fmt(pose.r * 180 / Math.PI, 1));
  }
  if (t.estimate) pushTrail(state.trail, t.estimate);
  if (t.truth) pushTrail(state.truthTrail, t.truth);
  setText('mode', t.mode || t.pilot_mode || '-');
  setText('failsafe', t.failsafe || '-');
  setText('active-source', t.active_source || '-');
  setText('surface-stop', t.surface_stop ? 'RELEASE STOP (x)' : 'STOP VESSEL (x)');
  let refusal = '-';
  let recording = '-';
  for (const [name, st] of Object.entries(t.diagnostics || {})) {
    if (st.values && st.values.last_refusal) refusal = st.values.last_refusal;
    if (name.endsWith('recorder')) recording = st.message;
  }
  if (t.pilot_reason) refusal = t.pilot_reason;   // the ROV's pilot modes
  setText('refusal', refusal);
  setText('recording', recording);
  showRecorder(t.diagnostics || {});
  if (t.io) {
    setText('lights-state', t.io.lights === null ? '-' : (t.io.lights ? 'on' : 'off'));
    setText('manipulator-state', t.io.manipulator === null ? '-' : fmt(t.io.manipulator, 0));
  }
  showActuators(t);
  showDiagnostics(t.diagnostics || {});
  drawMap(t);
}

// The recorder's own status (its /diagnostics values): recording or not, the bag, its size.
function showRecorder(diags) {
  const name = Object.keys(diags).find((n) => n.endsWith('recorder'));
  if (!name) { setText('rec-state', 'no recorder'); return; }
  const v = diags[name].values || {};
  setText('rec-state', v.recording === 'true' ? 'recording' : diags[name].message);
  setText('rec-bag', v.bag || '-');
  setText('rec-size', size(v.bag_bytes));
  setText('rec-free', size(v.free_bytes));
  setText('rec-refusal', v.last_control_refusal || '-');
}

// Bytes in the largest unit that keeps a number >= 1: a bag of a few seconds is some kB.
function size(bytes) {
  if (bytes === undefined || bytes === 'unknown') return '-';
  let x = Number(bytes);
  for (const unit of ['B', 'kB', 'MB', 'GB']) {
    if (x < 1024 || unit === 'GB') return `${x.toFixed(unit === 'B' ? 0 : 1)} ${unit}`;
    x /= 1024;
  }
  return '-';
}

// -- camera ------------------------------------------------------------------------------
// Its own WebSocket (/camera): binary messages are frames (sec, nanosec as big-endian
// uint32, then the JPEG), text ones the detections of an image, by the image's stamp. Only
// the boxes of the image shown are drawn on it.
function toggleCamera() {
  if (state.camera) {
    state.camera.close();
    return;
  }
  const proto = location.protocol === 'https:' ? 'wss:' : 'ws:';
  const ws = new WebSocket(`${proto}//${location.host}/camera` + (token ? `?token=${encodeURIComponent(token)}` : ''));
  ws.binaryType = 'arraybuffer';
  state.camera = ws;
  setText('camera-toggle', 'stop watching');
  setText('camera-state', 'waiting for an image');
  ws.onmessage = (ev) => {
    if (typeof ev.data === 'string') {
      const msg = JSON.parse(ev.data);
      if (msg.type !== 'detections') return;
      const key = msg.stamp.join('.');
      state.boxes.set(key, msg.boxes);
      while (state.boxes.size > 32) state.boxes.delete(state.boxes.keys().next().value);
      if (state.image && state.image.key === key) drawCamera();
      return;
    }
    const view = new DataView(ev.data);
    const key = `${view.getUint32(0)}.${view.getUint32(4)}`;
    createImageBitmap(new Blob([ev.data.slice(8)], { type: 'image/jpeg' })).then((bitmap) => {
      if (state.image) state.image.bitmap.close();
      state.image = { key, bitmap };
      drawCamera();
    }).catch((err) => setText('camera-state', 'bad image: ' + err));
  };
  ws.onclose = () => {
    state.camera = null;
    setText('camera-toggle', 'watch');
    setText('camera-state', 'not watching');
    $('camera').hidden = true;
  };
}

function drawCamera() {
  const canvas = $('camera');
  const { key, bitmap } = state.image;
  if (canvas.width !== bitmap.width) canvas.width = bitmap.width;
  if (canvas.height !== bitmap.height) canvas.height = bitmap.height;
  canvas.hidden = false;
  const ctx = canvas.getContext('2d');
  ctx.drawImage(bitmap, 0, 0);
  const boxes = state.boxes.get(key) || [];
  ctx.strokeStyle = '#00e676';
  ctx.fillStyle = '#00e676';
  ctx.lineWidth = 2;
  ctx.font = '12px sans-serif';
  for (const [cls, score, x0, y0, x1, y1] of boxes) {
    ctx.strokeRect(x0, y0, x1 - x0, y1 - y0);
    ctx.fillText(`${cls} ${score.toFixed(2)}`, x0 + 2, Math.max(12, y0 - 3));
  }
  canvas.dataset.stamp = key;        // what is shown, for a reader of the page (the tests)
  canvas.dataset.boxes = String(boxes.length);
  setText('camera-state', `${bitmap.width}x${bitmap.height}, ${boxes.length} boxes`);
}

function pushTrail(trail, p) {
  const last = trail[trail.length - 1];
  if (!last || Math.hypot(last[0] - p.x, last[1] - p.y) > 0.01) trail.push([p.x, p.y]);
  if (trail.length > 2000) trail.shift();
}

function showActuators(t) {
  const rows = [];
  if (t.azimuths) {
    rows.push('<tr><th>azimuth</th><th>angle [deg]</th><th>thrust [N]</th></tr>');
    for (const a of t.azimuths) {
      rows.push(`<tr><td>${esc(a.name)}</td><td>${fmt(a.angle * 180 / Math.PI, 1)}</td>` +
        `<td>${fmt(a.thrust, 2)}</td></tr>`);
    }
  }
  if (t.thrusters) {
    rows.push('<tr><th>thruster</th><th colspan="2">command (-1..1)</th></tr>');
    for (const a of t.thrusters) {
      rows.push(`<tr><td>${esc(a.name)}</td><td colspan="2">${fmt(a.effort, 2)}</td></tr>`);
    }
  }
  if (t.goal) {
    rows.push(`<tr><td>velocity goal</td><td colspan="2">${t.goal.map((x) => fmt(x, 2)).join(', ')}</td></tr>`);
  }
  const html = rows.join('');
  if ($('actuators').innerHTML !== html) $('actuators').innerHTML = html;
}

function showDiagnostics(diags) {
  const rows = ['<tr><th>node</th><th>state</th></tr>'];
  for (const name of Object.keys(diags).sort()) {
    const d = diags[name];
    rows.push(`<tr><td>${esc(name)}</td><td class="level-${d.level}">${esc(d.message)}</td></tr>`);
  }
  const html = rows.join('');
  if ($('diagnostics').innerHTML !== html) $('diagnostics').innerHTML = html;
}

function esc(s) {
  return String(s).replace(/[&<>"']/g, (c) => ({ '&': '&amp;', '<': '&lt;', '>': '&gt;',
    '"': '&quot;', "'": '&#39;' }[c]));
}

function drawMap(t) {
  const canvas = $('map');
  const ctx = canvas.getContext('2d');
  const w = canvas.width, h = canvas.height;
  const pose = t.estimate || t.truth || { x: 0, y: 0, yaw: 0 };
  const scale = 60;   // px per m
  const cx = pose.x, cy = pose.y;
  const px = (x) => w / 2 + (x - cx) * scale;
  const py = (y) => h / 2 - (y - cy) * scale;
  ctx.clearRect(0, 0, w, h);
  ctx.strokeStyle = '#eef';
  ctx.lineWidth = 1;
  for (let gx = Math.floor(cx - w / scale); gx <= cx + w / scale; gx += 1) {
    ctx.beginPath(); ctx.moveTo(px(gx), 0); ctx.lineTo(px(gx), h); ctx.stroke();
  }
  for (let gy = Math.floor(cy - h / scale); gy <= cy + h / scale; gy += 1) {
    ctx.beginPath(); ctx.moveTo(0, py(gy)); ctx.lineTo(w, py(gy)); ctx.stroke();
  }
  if (state.path && state.path.length >= 4) {
    ctx.strokeStyle = '#888'; ctx.setLineDash([6, 4]); ctx.beginPath();
    for (let i = 0; i + 1 < state.path.length; i += 2) {
      const f = i === 0 ? 'moveTo' : 'lineTo';
      ctx[f](px(state.path[i]), py(state.path[i + 1]));
    }
    ctx.stroke(); ctx.setLineDash([]);
  }
  drawTrail(ctx, state.truthTrail, '#bbb', px, py);
  drawTrail(ctx, state.trail, '#1565c0', px, py);
  for (const [x, y, x2, y2, r] of t.obstacles || []) {
    ctx.strokeStyle = '#c62828'; ctx.lineCap = 'round'; ctx.lineWidth = Math.max(2, 2 * r * scale);
    ctx.beginPath(); ctx.moveTo(px(x), py(y)); ctx.lineTo(px(x2) + 0.01, py(y2)); ctx.stroke();
  }
  ctx.lineWidth = 1;
  if (t.reference && t.mode !== 'manual') {   // in manual the last reference is stale
    ctx.fillStyle = '#2e7d32';
    ctx.beginPath(); ctx.arc(px(t.reference.x), py(t.reference.y), 5, 0, 2 * Math.PI); ctx.fill();
  }
  if (t.estimate || t.truth) {
    ctx.save();
    ctx.translate(px(pose.x), py(pose.y));
    ctx.rotate(-pose.yaw);
    ctx.fillStyle = '#13315c';
    ctx.beginPath(); ctx.moveTo(14, 0); ctx.lineTo(-9, 8); ctx.lineTo(-9, -8); ctx.closePath();
    ctx.fill();
    ctx.restore();
  }
}

function drawTrail(ctx, trail, colour, px, py) {
  if (trail.length < 2) return;
  ctx.strokeStyle = colour; ctx.lineWidth = 2; ctx.beginPath();
  trail.forEach(([x, y], i) => (i ? ctx.lineTo(px(x), py(y)) : ctx.moveTo(px(x), py(y))));
  ctx.stroke(); ctx.lineWidth = 1;
}

setInterval(() => {   // shows the loss even when no telemetry comes at all
  if (performance.now() - state.lastTelemetry > 1000) setBadge('conn', 'telemetry stale', 'bad');
  else if (state.ws && state.ws.readyState === WebSocket.OPEN) setBadge('conn', 'connected', '');
  showStaleness();
}, 250);

// -- tuning ------------------------------------------------------------------------------
// Only the latest load builds the table (a tab switch may start one while another runs);
// #params says 'loading' until then, 'ready' after.
let paramsGeneration = 0;

async function loadParams() {
  const generation = ++paramsGeneration;
  const box = $('params');
  box.dataset.state = 'loading';
  const res = await fetch('/api/params' + (token ? `?token=${encodeURIComponent(token)}` : ''));
  const data = await res.json();
  if (generation !== paramsGeneration) return;
  box.textContent = '';
  for (const node of data.nodes) {
    const div = document.createElement('div');
    div.className = 'node';
    div.dataset.node = node.node;
    div.innerHTML = `<h3>${esc(node.node)}${node.error ? ' - ' + esc(node.error) : ''}</h3>`;
    const table = document.createElement('table');
    for (const p of node.params) {
      if (p.name === 'path.waypoints' && Array.isArray(p.value)) state.path = p.value;
      table.appendChild(paramRow(node.node, p));
    }
    div.appendChild(table);
    box.appendChild(div);
  }
  applyFilter();
  box.dataset.state = 'ready';
}

function paramRow(node, p) {
  const tr = document.createElement('tr');
  tr.className = 'param';
  tr.dataset.node = node;
  tr.dataset.name = p.name;
  const range = (p.low !== null || p.high !== null) ? `[${p.low ?? ''}, ${p.high ?? ''}]` : '';
  tr.innerHTML = `<td>${esc(p.name)}</td><td class="editor"></td><td>${esc(p.unit)}</td>` +
    `<td>${esc(range)}</td><td class="desc">${esc(p.description)}</td>` +
    '<td class="param-status"></td>';
  const cell = tr.querySelector('.editor');
  const values = Array.isArray(p.value) ? p.value : [p.value];
  values.forEach((v, i) => {
    const input = document.createElement('input');
    input.dataset.index = i;
    input.disabled = p.read_only;
    if (p.type.startsWith('bool')) {
      input.type = 'checkbox';
      input.checked = !!v;
      input.addEventListener('change', () => submit(node, p, i, input.checked, tr));
    } else {
      input.type = (p.type.startsWith('double') || p.type.startsWith('int')) ? 'number' : 'text';
      if (input.type === 'number') input.step = 'any';
      input.value = v;
      input.addEventListener('change', () => {
        const raw = input.value;
        if (input.type === 'number' && (raw.trim() === '' || !Number.isFinite(Number(raw)))) {
          // An emptied field is no value (Number('') would send 0): nothing is sent.
          const status = tr.querySelector('.param-status');
          status.textContent = 'enter a number';
          status.className = 'param-status';
          return;
        }
        submit(node, p, i, input.type === 'number' ? Number(raw) : raw, tr);
      });
    }
    cell.appendChild(input);
  });
  return tr;
}

async function submit(node, p, index, value, tr) {
  const whole = Array.isArray(p.value) ? p.value.map((v, i) => (i === index ? value : v)) : value;
  const status = tr.querySelector('.param-status');
  status.textContent = 'setting...';
  status.className = 'param-status';
  const res = await fetch('/api/param' + (token ? `?token=${encodeURIComponent(token)}` : ''), {
    method: 'POST', headers: { 'Content-Type': 'application/json' },
    body: JSON.stringify({ node, name: p.name, value: whole }) });
  const answer = await res.json();
  if (answer.ok) {
    p.value = whole;
    status.textContent = 'applied';
    status.className = 'param-status ok';
  } else {
    status.textContent = 'refused: ' + answer.reason;
    status.className = 'param-status refused';
    const inputs = tr.querySelectorAll('.editor input');   // back to what the node kept
    const kept = Array.isArray(p.value) ? p.value : [p.value];
    inputs.forEach((input, i) => {
      if (input.type === 'checkbox') input.checked = !!kept[i]; else input.value = kept[i];
    });
  }
}

function applyFilter() {
  const f = $('filter').value.toLowerCase();
  document.querySelectorAll('tr.param').forEach((tr) => {
    tr.hidden = !!f && !(tr.dataset.node + ' ' + tr.dataset.name).toLowerCase().includes(f);
  });
  document.querySelectorAll('div.node').forEach((div) => {
    div.hidden = !!f && !div.querySelector('tr.param:not([hidden])');
  });
}

function showTab(name) {
  $('view-drive').hidden = name !== 'drive';
  $('view-tune').hidden = name !== 'tune';
  $('tab-drive').classList.toggle('active', name === 'drive');
  $('tab-tune').classList.toggle('active', name === 'tune');
  if (name === 'tune') loadParams();
}
$('tab-drive').addEventListener('click', () => showTab('drive'));
$('tab-tune').addEventListener('click', () => showTab('tune'));
$('reload').addEventListener('click', loadParams);
$('filter').addEventListener('input', applyFilter);

connect();
loadParams().catch((err) => setText('error', 'parameters: ' + err));
