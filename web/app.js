// SPDX-License-Identifier: Apache-2.0
// The Pliant viewer: connects to pliant-web's socket, draws the scene's surface as frames
// arrive, plots the solver's behaviour and lets the mouse pull the body (Grab / MoveGrab /
// Release). URL parameters: scene=ID, token=WEB_TOKEN, encoding=float32|uint16, rate=HZ.
import * as THREE from '/three/build/three.module.js';
import { OrbitControls } from '/three/examples/jsm/controls/OrbitControls.js';
import { decodeTopology, decodeFrame, messageKind, KIND_TOPOLOGY, KIND_FRAME } from './wire.js';
import { StripChart, ResidualPlot } from './plots.js';

const params = new URLSearchParams(location.search);
const $ = (id) => document.getElementById(id);

// What the page knows; also read by the browser test (window.pliant).
const state = {
  connected: false,
  scenes: [],
  scene: params.get('scene') || '',
  subscription: 0,
  subscribing: false,
  ended: false,
  topology: null,
  framesReceived: 0,
  framesDrawn: 0,
  bytesReceived: 0,
  lastFrameBytes: 0,
  skippedFrames: 0,
  header: null,
  latenciesMs: [],          // end of tick (server publish) -> frame handled here, last 2000
  grab: null,               // { vertex (surface-local), id, target, force }
  grabsMade: 0,
  grabsReleased: 0,
  errors: [],
  banner: '',
};
window.pliant = state;

// ---- three.js scene ---------------------------------------------------------------------------
const canvas = $('gl');
// No antialiasing and device pixels capped at 2: software WebGL (headless, remote desktops)
// keeps up with 60 frames/s.
const renderer = new THREE.WebGLRenderer({ canvas, antialias: false });
renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
const scene3 = new THREE.Scene();
scene3.background = new THREE.Color(0x1a2027);
const camera = new THREE.PerspectiveCamera(40, 1, 1e-4, 100);
scene3.add(camera);
scene3.add(new THREE.HemisphereLight(0xdde8ff, 0x30281e, 0.6));
const keyLight = new THREE.DirectionalLight(0xffffff, 0.8);
keyLight.position.set(0.4, 1, 0.6);
camera.add(keyLight);
const controls = new OrbitControls(camera, canvas);
controls.enableDamping = false;
const grid = new THREE.GridHelper(1, 20, 0x3a4450, 0x262d35);
scene3.add(grid);

let mesh = null;           // the surface
let positionAttr = null;   // its position attribute (array swapped per frame, no copy)
let dequantized = null;    // scratch for 16-bit frames
let frameDirty = false;
let sceneSize = 0.1;
const grabLine = new THREE.Line(new THREE.BufferGeometry().setFromPoints([new THREE.Vector3(), new THREE.Vector3()]),
  new THREE.LineBasicMaterial({ color: 0xffee58 }));
grabLine.visible = false;
grabLine.frustumCulled = false;
scene3.add(grabLine);
const forceArrow = new THREE.ArrowHelper(new THREE.Vector3(0, 1, 0), new THREE.Vector3(), 0.01, 0xff5252);
forceArrow.visible = false;
scene3.add(forceArrow);
// The grab's line and force are drawn over the body, never hidden inside it.
for (const o of [grabLine, forceArrow.line, forceArrow.cone]) {
  o.material.depthTest = false;
  o.renderOrder = 10;
}

function resize() {
  const w = canvas.clientWidth, h = canvas.clientHeight;
  if (canvas.width !== Math.floor(w * renderer.getPixelRatio()) || canvas.height !== Math.floor(h * renderer.getPixelRatio())) {
    renderer.setSize(w, h, false);
    camera.aspect = w / Math.max(h, 1);
    camera.updateProjectionMatrix();
  }
}

function buildMesh(topo) {
  if (mesh) {
    scene3.remove(mesh);
    mesh.geometry.dispose();
  }
  const g = new THREE.BufferGeometry();
  positionAttr = new THREE.BufferAttribute(Float32Array.from(topo.rest), 3);
  positionAttr.setUsage ? positionAttr.setUsage(THREE.DynamicDrawUsage) : (positionAttr.dynamic = true);
  g.setAttribute('position', positionAttr);
  g.setIndex(new THREE.BufferAttribute(topo.triangles, 1));
  // Fixed vertices in slate blue, free ones in a tissue-like orange.
  const colors = new Float32Array(3 * topo.surfaceVertices);
  for (let i = 0; i < topo.surfaceVertices; ++i) colors.set([0.93, 0.55, 0.36], 3 * i);
  for (const f of topo.fixed) colors.set([0.35, 0.45, 0.75], 3 * f);
  g.setAttribute('color', new THREE.BufferAttribute(colors, 3));
  g.computeVertexNormals();
  g.computeBoundingSphere();
  mesh = new THREE.Mesh(g, new THREE.MeshLambertMaterial({ vertexColors: THREE.VertexColors, side: THREE.DoubleSide }));
  mesh.frustumCulled = false;
  scene3.add(mesh);
  dequantized = new Float32Array(3 * topo.surfaceVertices);

  // Frame the body: camera in front, above and to the side of its bounding sphere.
  const c = g.boundingSphere.center, r = Math.max(g.boundingSphere.radius, 1e-3);
  sceneSize = 2 * r;
  const box = new THREE.Box3().setFromBufferAttribute(positionAttr);
  grid.scale.setScalar(4 * r);
  grid.position.set(c.x, Math.min(box.min.y, c.y - 1.2 * r), c.z);  // below where the body sags
  const dist = (1.25 * r) / Math.tan((camera.fov * Math.PI) / 360);
  camera.position.copy(c).add(new THREE.Vector3(0.25, 0.45, 1).normalize().multiplyScalar(dist));
  camera.near = dist / 100;
  camera.far = dist * 100;
  camera.updateProjectionMatrix();
  controls.target.copy(c);
  controls.update();
}

function applyFrame(buffer) {
  const { header, residuals, positions } = decodeFrame(buffer, dequantized);
  if (header.subscription !== state.subscription || !mesh) return;  // from an older subscription
  if (positions.length === positionAttr.array.length) {
    positionAttr.array = positions;  // a view over the message (float32) or the scratch array
    positionAttr.needsUpdate = true;
    frameDirty = true;
  }
  state.framesReceived += 1;
  state.lastFrameBytes = buffer.byteLength;
  state.skippedFrames += header.skippedFrames;
  state.header = header;
  residualPlot.set(residuals);
  charts.error.push(header.residual);
  charts.tps.push(header.ticksPerSecond);
  charts.late.push(header.latenessMs);
  charts.step.push(header.stepMs);
  const nowNs = (performance.timeOrigin + performance.now()) * 1e6;
  const latency = (nowNs - Number(header.publishedUnixNs)) / 1e6;
  if (header.publishedUnixNs > 0n && latency >= 0) {
    state.latenciesMs.push(latency);
    if (state.latenciesMs.length > 2000) state.latenciesMs.shift();
  }
}

// ---- plots and text ---------------------------------------------------------------------------
const residualPlot = new ResidualPlot($('p-residual'));
const charts = {
  error: new StripChart($('p-error'), { name: 'error indicator |r| final', log: true, color: '#ef9a9a' }),
  tps: new StripChart($('p-tps'), { name: 'ticks/s', color: '#81c784' }),
  late: new StripChart($('p-late'), { name: 'lateness', unit: 'ms', color: '#ffd54f' }),
  step: new StripChart($('p-step'), { name: 'step time', unit: 'ms', color: '#4fc3f7' }),
};
state.plotPoints = () => ({
  residual: residualPlot.points,
  error: charts.error.points, tps: charts.tps.points, late: charts.late.points, step: charts.step.points,
});

function showText() {
  const h = state.header;
  if (h) {
    $('s-tick').textContent = h.tick;
    $('s-time').textContent = `${h.simTime.toFixed(3)} s`;
    $('s-state').textContent = h.state + (h.rolledBack ? ' (rolled back)' : '');
    $('s-tps').textContent = h.ticksPerSecond.toFixed(1);
    $('s-late').textContent = `${h.lateTicks} / ${h.skippedTicks}`;
    $('s-skipped').textContent = state.skippedFrames;
    $('s-iter').textContent = h.iterations;
    $('s-bytes').textContent = `${(state.lastFrameBytes / 1024).toFixed(1)} KiB, ${h.encoding ? 'uint16' : 'float32'}`;
    const l = state.latenciesMs;
    if (l.length) $('s-latency').textContent = `${l[l.length - 1].toFixed(2)} ms`;
  }
  const g = state.grab;
  $('s-grab').textContent = g ? (g.force ? `${vlen(g.force).toFixed(3)} N` : 'grabbing') : '-';
}
const vlen = (v) => Math.hypot(v[0], v[1], v[2]);

function setBanner(text) {
  state.banner = text;
  $('banner').hidden = !text;
  $('banner').textContent = text;
}

// ---- socket -----------------------------------------------------------------------------------
let ws = null;
function send(msg) {
  if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify(msg));
}

function connect() {
  const proto = location.protocol === 'https:' ? 'wss:' : 'ws:';
  const token = params.get('token');
  ws = new WebSocket(`${proto}//${location.host}/ws${token ? `?token=${encodeURIComponent(token)}` : ''}`);
  ws.binaryType = 'arraybuffer';
  ws.onopen = () => {
    state.connected = true;
    $('status').textContent = 'connected';
    setBanner('');
    send({ type: 'list' });
  };
  ws.onclose = () => {
    const was = state.connected;
    state.connected = false;
    state.grab = null;
    $('status').textContent = 'disconnected';
    setBanner(was ? 'Lost the connection to pliant-web; reconnecting…'
      : 'Cannot reach pliant-web (or the web token is wrong); retrying…');
    setTimeout(connect, 2000);
  };
  ws.onmessage = (ev) => {
    if (typeof ev.data === 'string') return onControl(JSON.parse(ev.data));
    state.bytesReceived += ev.data.byteLength;
    const kind = messageKind(ev.data);
    if (kind === KIND_TOPOLOGY) {
      const topo = decodeTopology(ev.data);
      if (topo.subscription !== state.subscription) return;
      state.topology = topo;
      buildMesh(topo);
    } else if (kind === KIND_FRAME) {
      applyFrame(ev.data);
      send({ type: 'ack' });
    }
  };
}

function subscribe(id) {
  state.scene = id;
  state.topology = null;
  state.grab = null;
  for (const c of Object.values(charts)) c.clear();
  if (!id) return send({ type: 'unsubscribe' });
  state.subscribing = true;
  // ack: the gateway sends a frame only when the page has handled the one before last, so a
  // page that falls behind gets the latest frame, not a queue.
  send({ type: 'subscribe', scene: id, max_rate_hz: Number(params.get('rate') || 60),
    encoding: params.get('encoding') || 'float32', ack: true });
}

function onControl(m) {
  switch (m.type) {
    case 'hello':
      $('status').textContent = `connected (server ${m.server})`;
      break;
    case 'scenes': {
      state.scenes = m.scenes;
      const sel = $('scene');
      const ids = m.scenes.map((s) => s.id);
      sel.innerHTML = '<option value="">(none)</option>' + ids.map((id) => `<option>${escapeHtml(id)}</option>`).join('');
      if (!state.scene && ids.length) state.scene = ids[0];
      if (ids.includes(state.scene)) {
        sel.value = state.scene;
        if ((!state.subscription || state.ended) && !state.subscribing) { state.ended = false; subscribe(state.scene); }
        if (state.banner.startsWith('Scene')) setBanner('');
      } else if (state.scene) {
        setBanner(`Scene '${state.scene}' does not exist on the server (any more); pick another one.`);
      } else {
        setBanner('The server has no scenes: create one (pliant scenes create demo --mesh beam1 --fix-x-below 0.001).');
      }
      break;
    }
    case 'subscribed':
      state.subscription = m.subscription;
      state.subscribing = false;
      setBanner('');
      break;
    case 'ended':
      if (m.subscription !== state.subscription) break;
      state.ended = true;
      state.grab = null;
      setBanner(m.code === 'NOT_FOUND' ? `Scene '${m.scene}' was deleted (${m.message}).`
        : m.code === 'UNAVAILABLE' ? `pliant-server went away (${m.message}); retrying…`
          : `The stream of '${m.scene}' ended: ${m.code} ${m.message}`);
      break;
    case 'grabbed':
      if (state.grab && state.grab.pending) {
        state.grab.id = m.grab_id;
        state.grab.pending = false;
        state.grabsMade += 1;
        if (state.grab.releaseWhenGrabbed) releaseGrab();
        else flushMove();
      } else {
        send({ type: 'release', grab_id: m.grab_id });  // the mouse was already up
      }
      break;
    case 'moved':
      if (state.grab && state.grab.id === m.grab_id) {
        state.grab.force = m.force;
        state.grab.inFlight = false;
        flushMove();
      }
      break;
    case 'released':
      state.grabsReleased += 1;
      break;
    case 'error':
      state.errors.push(m);
      if (m.request === 'list' || m.request === 'subscribe') {
        setBanner(m.code === 'UNAVAILABLE' ? `pliant-server is unreachable: ${m.message}` : `${m.request}: ${m.code} ${m.message}`);
        if (m.request === 'subscribe') { state.ended = true; state.subscribing = false; }
      } else if (m.request === 'grab' || m.request === 'move') {
        state.grab = null;
      }
      break;
    default:
      break;
  }
}

const escapeHtml = (s) => s.replace(/[&<>"']/g, (c) => `&#${c.charCodeAt(0)};`);

// ---- pick and drag ------------------------------------------------------------------------------
const raycaster = new THREE.Raycaster();
const dragPlane = new THREE.Plane();

function rayAt(ev) {
  const r = canvas.getBoundingClientRect();
  const ndc = new THREE.Vector2(((ev.clientX - r.left) / r.width) * 2 - 1, -((ev.clientY - r.top) / r.height) * 2 + 1);
  raycaster.setFromCamera(ndc, camera);
  return raycaster;
}

function vertexPosition(i) {
  const a = positionAttr.array;
  return new THREE.Vector3(a[3 * i], a[3 * i + 1], a[3 * i + 2]);
}

canvas.addEventListener('pointerdown', (ev) => {
  if (ev.button !== 0 || !mesh || !state.connected || state.ended) return;
  mesh.geometry.computeBoundingSphere();
  const hit = rayAt(ev).intersectObject(mesh)[0];
  if (!hit) return;  // orbit
  controls.enabled = false;
  const face = [hit.face.a, hit.face.b, hit.face.c];
  const local = face.reduce((best, v) => (vertexPosition(v).distanceTo(hit.point) < vertexPosition(best).distanceTo(hit.point) ? v : best));
  const p = vertexPosition(local);
  dragPlane.setFromNormalAndCoplanarPoint(camera.getWorldDirection(new THREE.Vector3()), p);
  state.grab = { vertex: local, id: null, pending: true, target: [p.x, p.y, p.z], sent: null, inFlight: false, force: null };
  send({ type: 'grab', vertex: state.topology.surfaceToBody[local], target: state.grab.target });
  canvas.setPointerCapture(ev.pointerId);
});

canvas.addEventListener('pointermove', (ev) => {
  const g = state.grab;
  if (!g) return;
  const t = rayAt(ev).ray.intersectPlane(dragPlane, new THREE.Vector3());
  if (!t) return;
  g.target = [t.x, t.y, t.z];
  flushMove();
});

function endDrag(ev) {
  controls.enabled = true;
  if (ev && canvas.hasPointerCapture(ev.pointerId)) canvas.releasePointerCapture(ev.pointerId);
  if (!state.grab) return;
  if (state.grab.pending) state.grab.releaseWhenGrabbed = true;
  else releaseGrab();
}
canvas.addEventListener('pointerup', endDrag);
canvas.addEventListener('pointercancel', endDrag);

// One move in flight at a time: the newest target goes when the previous one is answered.
function flushMove() {
  const g = state.grab;
  if (!g || g.pending || g.inFlight || g.sent === g.target) return;
  g.sent = g.target;
  g.inFlight = true;
  send({ type: 'move', grab_id: g.id, target: g.target });
}

function releaseGrab() {
  const g = state.grab;
  state.grab = null;
  if (g && g.id !== null) send({ type: 'release', grab_id: g.id });
}

function drawGrab() {
  const g = state.grab;
  grabLine.visible = forceArrow.visible = false;
  if (!g || !mesh) return;
  const p = vertexPosition(g.vertex);
  const t = new THREE.Vector3(...g.target);
  grabLine.geometry.setFromPoints([p, t]);
  grabLine.visible = true;
  if (g.force) {
    const f = new THREE.Vector3(...g.force);
    const n = f.length();
    if (n > 1e-9) {
      // Length saturates: 0.1 N draws a fifth of the body's size, large forces two fifths.
      const len = sceneSize * 0.4 * (n / (n + 0.1));
      forceArrow.position.copy(p);
      forceArrow.setDirection(f.normalize());
      forceArrow.setLength(len, 0.25 * len, 0.12 * len);
      forceArrow.visible = true;
    }
  }
}

// Helpers for the browser test: a vertex's position and its place on screen (client pixels).
state.vertex = (i) => vertexPosition(i).toArray();
state.project = (xyz) => {
  const v = new THREE.Vector3(...xyz).project(camera);
  const r = canvas.getBoundingClientRect();
  return { x: r.left + ((v.x + 1) / 2) * r.width, y: r.top + ((1 - v.y) / 2) * r.height };
};

// What the grab draws: its line and force arrow, when visible (read by the browser test).
state.grabDrawing = () => ({ line: grabLine.visible, arrow: forceArrow.visible,
  from: grabLine.visible ? Array.from(grabLine.geometry.getAttribute('position').array) : null });

// ---- loop ---------------------------------------------------------------------------------------
function animate() {
  requestAnimationFrame(animate);
  resize();
  if (frameDirty && mesh) {
    mesh.geometry.computeVertexNormals();
    state.framesDrawn += 1;
    frameDirty = false;
  }
  drawGrab();
  renderer.render(scene3, camera);
}

function drawPlots() {
  residualPlot.draw();
  for (const c of Object.values(charts)) c.draw();
  showText();
}
setInterval(drawPlots, 100);
setInterval(() => send({ type: 'list' }), 2000);  // scene list, and resubscribe after an end

$('scene').addEventListener('change', (ev) => subscribe(ev.target.value));
for (const action of ['pause', 'resume', 'reset']) {
  $(action).addEventListener('click', () => state.scene && send({ type: action, scene: state.scene }));
}

connect();
animate();
