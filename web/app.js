// SPDX-License-Identifier: Apache-2.0
// The Pliant viewer: connects to pliant-web's socket, draws the scene's surface and its
// particle bodies (fluid points, cloth surfaces, ropes) as frames arrive, plots the solver's
// behaviour and lets the mouse pull the body or a particle (Grab / MoveGrab / Release).
// URL parameters: scene=ID, token=WEB_TOKEN, encoding=float32|uint16, rate=HZ.
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
  bodyStats: [],            // each particle body's step in the last frame's tick (wire.js decodeFrame)
  latenciesMs: [],          // end of tick (server publish) -> frame handled here, the last 2000 or more
  latenessMs: [],           // the server's lateness of each frame's tick (header), as latenciesMs
  animationFrames: 0,       // requestAnimationFrame callbacks
  renders: 0,               // animation frames that drew the canvas (a new frame, camera, grab or size)
  // Main-thread time spent per stage, ms (summed; the bench divides by the counts above):
  // decode + apply of each frame message, normals of each drawn frame, renderer.render calls.
  perf: { decodeMs: 0, normalsMs: 0, renderMs: 0, plotsMs: 0, plotDraws: 0 },
  grab: null,               // { vertex (surface-local, or the body's particle), body (name or absent), id, target, force }
  renderInfo: null,         // what the last render drew: { calls, triangles, points, lines } (three.js)
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
// The canvas is drawn only when something on it changed: a new frame, the camera, the grab's
// drawing or the canvas size. Animation frames without a change cost nothing.
let needsRender = true;
const invalidate = () => { needsRender = true; };
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
controls.addEventListener('change', invalidate);
const grid = new THREE.GridHelper(1, 20, 0x3a4450, 0x262d35);
scene3.add(grid);

let mesh = null;           // the surface
let positionAttr = null;   // its position attribute (array swapped per frame, no copy)
let normalAttr = null;     // its normals, recomputed in place for each drawn frame
let triangles = null;      // the surface's triangles (Uint32Array, 3 per triangle)
let dequantized = null;    // scratch for 16-bit frames
let frameDirty = false;    // a frame arrived since the last draw
let plotsDirty = true;     // a frame arrived since the plots were drawn
let sceneSize = 0.1;
// The particle bodies, in the topology's order: { name, kind, particles, size, attr (positions,
// swapped per frame like the surface's), normals (cloth), colors (fluid), prev (fluid, the
// positions last drawn), objects (added to the scene), pick (what the mouse can grab), dirty }.
let bodies = [];
let bodyScratch = [];       // 16-bit frames: one dequantised array per body
let drawnSimTime = null;    // sim time of the last drawn frame (the fluid's speed colours)
let frameSimTime = 0;
const grabLine = new THREE.Line(new THREE.BufferGeometry().setFromPoints([new THREE.Vector3(), new THREE.Vector3()]),
  new THREE.LineBasicMaterial({ color: 0xffee58 }));
const grabLineAttr = grabLine.geometry.getAttribute('position');
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

// The canvas's CSS size, from a ResizeObserver: reading clientWidth in every animation frame
// would force a layout whenever the statistics table changed.
let cssSize = null;
new ResizeObserver((entries) => {
  const r = entries[entries.length - 1].contentRect;
  cssSize = { w: r.width, h: r.height };
  invalidate();
}).observe(canvas);

function resize() {
  if (!cssSize) return;
  const { w, h } = cssSize;
  cssSize = null;
  renderer.setSize(w, h, false);
  camera.aspect = w / Math.max(h, 1);
  camera.updateProjectionMatrix();
}

// Area-weighted vertex normals of the surface, in place (what three.js's
// computeVertexNormals gives, without its per-triangle vector objects).
function computeNormals(pos, tris, out) {
  out.fill(0);
  for (let t = 0; t < tris.length; t += 3) {
    const a = 3 * tris[t], b = 3 * tris[t + 1], c = 3 * tris[t + 2];
    const bx = pos[b], by = pos[b + 1], bz = pos[b + 2];
    const ux = pos[c] - bx, uy = pos[c + 1] - by, uz = pos[c + 2] - bz;
    const vx = pos[a] - bx, vy = pos[a + 1] - by, vz = pos[a + 2] - bz;
    const nx = uy * vz - uz * vy, ny = uz * vx - ux * vz, nz = ux * vy - uy * vx;
    out[a] += nx; out[a + 1] += ny; out[a + 2] += nz;
    out[b] += nx; out[b + 1] += ny; out[b + 2] += nz;
    out[c] += nx; out[c + 1] += ny; out[c + 2] += nz;
  }
  for (let i = 0; i < out.length; i += 3) {
    const l = Math.sqrt(out[i] * out[i] + out[i + 1] * out[i + 1] + out[i + 2] * out[i + 2]);
    if (l > 0) { out[i] /= l; out[i + 1] /= l; out[i + 2] /= l; }
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
  normalAttr = new THREE.BufferAttribute(new Float32Array(3 * topo.surfaceVertices), 3);
  normalAttr.setUsage ? normalAttr.setUsage(THREE.DynamicDrawUsage) : (normalAttr.dynamic = true);
  g.setAttribute('normal', normalAttr);
  triangles = topo.triangles;
  computeNormals(positionAttr.array, triangles, normalAttr.array);
  g.computeBoundingSphere();
  // The surface is closed and its triangles face outward: back faces are culled, which halves
  // what software WebGL rasterises and lights.
  mesh = new THREE.Mesh(g, new THREE.MeshLambertMaterial({ vertexColors: THREE.VertexColors, side: THREE.FrontSide }));
  mesh.frustumCulled = false;
  scene3.add(mesh);
  dequantized = new Float32Array(3 * topo.surfaceVertices);

  buildBodies(topo);

  // Frame the scene: camera in front, above and to the side of the bounding sphere of the body
  // and the particle bodies.
  const box = new THREE.Box3().setFromBufferAttribute(positionAttr);
  for (const b of bodies) box.union(new THREE.Box3().setFromBufferAttribute(b.attr));
  const sphere = box.getBoundingSphere(new THREE.Sphere());
  const c = sphere.center, r = Math.max(sphere.radius, 1e-3);
  sceneSize = 2 * r;
  grid.scale.setScalar(4 * r);
  grid.position.set(c.x, Math.min(box.min.y, c.y - 1.2 * r), c.z);  // below where the body sags
  const dist = (1.25 * r) / Math.tan((camera.fov * Math.PI) / 360);
  camera.position.copy(c).add(new THREE.Vector3(0.25, 0.45, 1).normalize().multiplyScalar(dist));
  camera.near = dist / 100;
  camera.far = dist * 100;
  camera.updateProjectionMatrix();
  controls.target.copy(c);
  controls.update();
  invalidate();
}

// A round point sprite (fluid particles, rope beads, pinned markers), drawn once.
const dotTexture = (() => {
  const c = document.createElement('canvas');
  c.width = c.height = 64;
  const g = c.getContext('2d');
  g.fillStyle = '#fff';
  g.beginPath();
  g.arc(32, 32, 30, 0, 2 * Math.PI);
  g.fill();
  return new THREE.CanvasTexture(c);
})();

// Points over a body's positions: `size` m when known (perspective), else `pixels` on screen.
function pointsMaterial(size, pixels, options) {
  return new THREE.PointsMaterial({
    size: size > 0 ? size : pixels, sizeAttenuation: size > 0, map: dotTexture, alphaTest: 0.5, ...options,
  });
}

function dynamicAttr(array) {
  const a = new THREE.BufferAttribute(array, 3);
  a.setUsage ? a.setUsage(THREE.DynamicDrawUsage) : (a.dynamic = true);
  return a;
}

// The particle bodies of a topology: fluids as round points (the particle spacing wide, coloured
// by speed), cloth as a lit double-sided surface, ropes as a line with a bead per particle;
// pinned particles as slate-blue dots, like the surface's fixed vertices.
function buildBodies(topo) {
  for (const b of bodies) {
    for (const o of b.objects) {
      scene3.remove(o);
      o.geometry.dispose();  // the body's, and the pinned markers' own
      o.material.dispose();
    }
  }
  bodies = [];
  bodyScratch = [];
  drawnSimTime = null;
  for (const t of topo.bodies || []) {
    const g = new THREE.BufferGeometry();
    const attr = dynamicAttr(Float32Array.from(t.rest));
    g.setAttribute('position', attr);
    const b = { name: t.name, kind: t.kind, particles: t.particles, size: t.size, attr, geometry: g,
      normals: null, colors: null, prev: null, triangles: null, objects: [], pick: null, dirty: false };
    if (t.kind === 'cloth' && t.triangles.length) {
      g.setIndex(new THREE.BufferAttribute(t.triangles, 1));
      b.triangles = t.triangles;
      b.normals = dynamicAttr(new Float32Array(3 * t.particles));
      g.setAttribute('normal', b.normals);
      computeNormals(attr.array, b.triangles, b.normals.array);
      b.pick = new THREE.Mesh(g, new THREE.MeshLambertMaterial({ color: 0x7fb3d5, side: THREE.DoubleSide }));
    } else if (t.kind === 'rope') {
      b.objects.push(new THREE.Line(g, new THREE.LineBasicMaterial({ color: 0xd7c49e })));
      // Beads a little wider than the rope, so it reads as a rope at any zoom.
      b.pick = new THREE.Points(g, pointsMaterial(2 * t.size, 6, { color: 0xd7c49e }));
    } else {
      // Fluid (and any other particle body): a point per particle, coloured by speed.
      b.colors = new THREE.BufferAttribute(new Float32Array(3 * t.particles), 3);
      b.colors.setUsage ? b.colors.setUsage(THREE.DynamicDrawUsage) : (b.colors.dynamic = true);
      g.setAttribute('color', b.colors);
      b.prev = Float32Array.from(t.rest);
      speedColors(b, 0);
      b.pick = new THREE.Points(g, pointsMaterial(t.size, 5, { vertexColors: THREE.VertexColors }));
    }
    b.objects.push(b.pick);
    if (t.pinned.length) {
      // The same positions, indexed by the pinned particles only.
      const pg = new THREE.BufferGeometry();
      pg.setAttribute('position', attr);
      pg.setIndex(new THREE.BufferAttribute(t.pinned, 1));
      const marker = new THREE.Points(pg, pointsMaterial(0, 9, { color: 0x5973bf, depthTest: false }));
      marker.renderOrder = 5;
      b.objects.push(marker);
    }
    for (const o of b.objects) {
      o.frustumCulled = false;
      o.userData.body = b;
      scene3.add(o);
    }
    bodies.push(b);
    bodyScratch.push(new Float32Array(3 * t.particles));
  }
  state.bodyStats = [];
  buildBodyPanel();
}

// A fluid's new particle count: a new geometry of that size (the old one's GPU buffers are
// freed), the particles it had keep their previous positions for the speed colours, new ones
// start still.
function resizeFluid(b, positions) {
  const old = b.geometry;
  const g = new THREE.BufferGeometry();
  b.attr = dynamicAttr(Float32Array.from(positions));
  g.setAttribute('position', b.attr);
  b.colors = new THREE.BufferAttribute(new Float32Array(positions.length), 3);
  b.colors.setUsage ? b.colors.setUsage(THREE.DynamicDrawUsage) : (b.colors.dynamic = true);
  g.setAttribute('color', b.colors);
  // The speed colours of the next drawn frame compare with these: the particles it had where
  // they were, new ones where they are (still).
  const prev = Float32Array.from(positions);
  prev.set(b.prev.subarray(0, Math.min(b.prev.length, prev.length)));
  b.prev = prev;
  const col = b.colors.array;
  for (let i = 0; i < col.length; i += 3) col.set(STILL_WATER, i);
  for (const o of b.objects) if (o.geometry === old) o.geometry = g;
  b.geometry = g;
  b.particles = positions.length / 3;
  old.dispose();
}

// Fluid colours from each particle's speed since the last drawn frame (dt s): still water
// blue, 1 m/s and faster white.
const STILL_WATER = [0.16, 0.5, 0.9];
function speedColors(b, dt) {
  const x = b.attr.array, prev = b.prev, col = b.colors.array;
  for (let i = 0; i < x.length; i += 3) {
    const v = dt > 0 ? Math.hypot(x[i] - prev[i], x[i + 1] - prev[i + 1], x[i + 2] - prev[i + 2]) / dt : 0;
    const u = Math.min(v, 1);
    col[i] = 0.16 + 0.84 * u;
    col[i + 1] = 0.5 + 0.5 * u;
    col[i + 2] = 0.9 + 0.1 * u;
  }
  prev.set(x);
  b.colors.needsUpdate = true;
}

// A frame message: positions into the geometry (the GPU upload and the normals wait for the
// next drawn animation frame, so frames arriving faster than the screen cost only this), the
// header into the table and plots.
function applyFrame(buffer) {
  const t0 = performance.now();
  const { header, residuals, positions, bodies: bodyPositions, bodyStats } = decodeFrame(buffer, dequantized, bodyScratch);
  if (header.subscription !== state.subscription || !mesh) return;  // from an older subscription
  if (positions.length === positionAttr.array.length) {
    positionAttr.array = positions;  // a view over the message (float32) or the scratch array
    frameDirty = true;
  }
  for (let i = 0; i < bodies.length && i < bodyPositions.length; ++i) {
    if (bodyPositions[i].length !== bodies[i].attr.array.length) {
      // A fluid's emitters add particles (a rollback or a restore may take some back); cloth
      // and ropes keep their count.
      if (bodies[i].kind !== 'fluid') continue;
      resizeFluid(bodies[i], bodyPositions[i]);
      bodyScratch[i] = new Float32Array(bodyPositions[i].length);
    }
    bodies[i].attr.array = bodyPositions[i];
    bodies[i].dirty = true;
    frameDirty = true;
  }
  frameSimTime = header.simTime;
  state.framesReceived += 1;
  state.lastFrameBytes = buffer.byteLength;
  state.skippedFrames += header.skippedFrames;
  state.header = header;
  residualPlot.set(residuals);
  state.bodyStats = bodyStats;
  for (let i = 0; i < bodies.length && i < bodyStats.length; ++i) bodies[i].chart.push(100 * bodyStats[i].error);
  charts.error.push(header.residual);
  charts.tps.push(header.ticksPerSecond);
  charts.late.push(header.latenessMs);
  charts.step.push(header.stepMs);
  plotsDirty = true;
  const now = performance.now();
  const latency = ((performance.timeOrigin + now) * 1e6 - Number(header.publishedUnixNs)) / 1e6;
  if (header.publishedUnixNs > 0n && latency >= 0) {
    keepLast(state.latenciesMs, latency);
    keepLast(state.latenessMs, header.latenessMs);
  }
  state.perf.decodeMs += now - t0;
}

// Appends to a list that keeps at least its last 2000 values (trimmed in batches, not per push).
function keepLast(list, v) {
  list.push(v);
  if (list.length > 4000) list.splice(0, list.length - 2000);
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
  bodies: bodies.map((b) => b.chart.points),
});
// The bodies' table as shown: one row of cell texts per body.
state.bodyTable = () => [...$('body-stats').querySelectorAll('tbody tr')].map((tr) =>
  [...tr.children].map((td) => td.textContent));

function showText() {
  const h = state.header;
  if (h) {
    setText('s-tick', h.tick);
    setText('s-time', `${h.simTime.toFixed(3)} s`);
    setText('s-state', h.state + (h.rolledBack ? ' (rolled back)' : ''));
    setText('s-tps', h.ticksPerSecond.toFixed(1));
    setText('s-late', `${h.lateTicks} / ${h.skippedTicks}`);
    setText('s-skipped', state.skippedFrames);
    setText('s-iter', h.iterations);
    setText('s-bytes', `${(state.lastFrameBytes / 1024).toFixed(1)} KiB, ${h.encoding ? 'uint16' : 'float32'}`);
    const l = state.latenciesMs;
    if (l.length) setText('s-latency', `${l[l.length - 1].toFixed(2)} ms`);
  }
  for (let i = 0; i < bodies.length; ++i) {
    const b = bodies[i], s = state.bodyStats[i];
    const pct = (v) => `${(100 * v).toFixed(v < 0.001 ? 3 : 2)}%`;
    setCell(b.cells.particles, b.particles);
    if (!s) continue;
    setCell(b.cells.error, `${pct(s.error)} / ${pct(s.maxError)}${s.selfCollisionSuspended ? ' (self-collision off: over-stretched)' : ''}`);
    setCell(b.cells.contacts, s.contacts + s.toolContacts + s.bodyContacts + s.softBodyContacts);
    setCell(b.cells.ms, s.stepMs.toFixed(2));
  }
  const g = state.grab;
  setText('s-grab', g ? (g.force ? `${vlen(g.force).toFixed(3)} N` : 'grabbing') : '-');
}
const vlen = (v) => Math.hypot(v[0], v[1], v[2]);
const shownText = new Map();
function setText(id, text) {
  const t = String(text);
  if (shownText.get(id) === t) return;
  shownText.set(id, t);
  $(id).textContent = t;
}

function setCell(td, text) {
  const t = String(text);
  if (td.textContent !== t) td.textContent = t;
}

// The bodies' table (what each body's step did in the last frame's tick) and a plot of each
// one's constraint error: a fluid's density error, a cloth's or rope's stretch.
function buildBodyPanel() {
  const tbody = $('body-stats').querySelector('tbody');
  tbody.replaceChildren();
  $('body-plots').replaceChildren();
  $('body-stats').hidden = bodies.length === 0;
  for (const b of bodies) {
    const tr = document.createElement('tr');
    const cell = (text) => {
      const td = document.createElement('td');
      td.textContent = text;
      tr.appendChild(td);
      return td;
    };
    cell(b.name).title = b.kind;
    b.cells = { particles: cell(b.particles), error: cell('-'), contacts: cell('-'), ms: cell('-') };
    tbody.appendChild(tr);
    const canvas = document.createElement('canvas');
    canvas.className = 'plot';
    canvas.width = 300;
    canvas.height = 60;
    $('body-plots').appendChild(canvas);
    b.chart = new StripChart(canvas, { name: `${b.name}: ${b.kind === 'fluid' ? 'density error' : 'stretch'} mean`,
      unit: '%', color: '#ce93d8' });
  }
}

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

// A surface vertex's position, or a particle's of the body named `body`.
function vertexPosition(i, body = null) {
  const b = body ? bodies.find((x) => x.name === body) : null;
  const a = b ? b.attr.array : positionAttr.array;
  return new THREE.Vector3(a[3 * i], a[3 * i + 1], a[3 * i + 2]);
}

canvas.addEventListener('pointerdown', (ev) => {
  if (ev.button !== 0 || !mesh || !state.connected || state.ended) return;
  const targets = [mesh];
  mesh.geometry.computeBoundingSphere();
  for (const b of bodies) {
    b.geometry.computeBoundingSphere();
    targets.push(b.pick);
  }
  const ray = rayAt(ev);
  // Points are hit within a bead's radius (or 1% of the scene where the size is unknown).
  const fluid = bodies.find((b) => b.kind !== 'cloth' && b.size > 0);
  ray.params.Points.threshold = fluid ? fluid.size : 0.01 * sceneSize;
  const hit = ray.intersectObjects(targets)[0];
  if (!hit) return;  // orbit
  controls.enabled = false;
  const body = hit.object.userData.body ? hit.object.userData.body.name : null;
  let local;
  if (hit.face) {
    const face = [hit.face.a, hit.face.b, hit.face.c];
    const d = (v) => vertexPosition(v, body).distanceTo(hit.point);
    local = face.reduce((best, v) => (d(v) < d(best) ? v : best));
  } else {
    local = hit.index;  // a particle (Points)
  }
  const p = vertexPosition(local, body);
  dragPlane.setFromNormalAndCoplanarPoint(camera.getWorldDirection(new THREE.Vector3()), p);
  state.grab = { vertex: local, body, id: null, pending: true, target: [p.x, p.y, p.z], sent: null, inFlight: false, force: null };
  const msg = { type: 'grab', vertex: body ? local : state.topology.surfaceToBody[local], target: state.grab.target };
  if (body) msg.body = body;
  send(msg);
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
  const p = vertexPosition(g.vertex, g.body);
  grabLineAttr.setXYZ(0, p.x, p.y, p.z);
  grabLineAttr.setXYZ(1, g.target[0], g.target[1], g.target[2]);
  grabLineAttr.needsUpdate = true;
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

// Helpers for the browser test: a vertex's (or a body particle's) position and its place on
// screen (client pixels).
state.vertex = (i, body = null) => vertexPosition(i, body).toArray();
state.bodies = () => bodies.map((b) => ({ name: b.name, kind: b.kind, particles: b.particles, size: b.size }));
// Shows or hides the particle bodies (the browser test compares the canvas with and without).
state.showBodies = (on) => {
  for (const b of bodies) for (const o of b.objects) o.visible = on;
  invalidate();
};
state.project = (xyz) => {
  const v = new THREE.Vector3(...xyz).project(camera);
  const r = canvas.getBoundingClientRect();
  // depth: the normalised device depth, smaller is nearer the camera.
  return { x: r.left + ((v.x + 1) / 2) * r.width, y: r.top + ((1 - v.y) / 2) * r.height, depth: v.z };
};

// What the grab draws: its line and force arrow, when visible (read by the browser test).
state.grabDrawing = () => ({ line: grabLine.visible, arrow: forceArrow.visible,
  from: grabLine.visible ? Array.from(grabLine.geometry.getAttribute('position').array) : null });

// ---- loop ---------------------------------------------------------------------------------------
function animate() {
  requestAnimationFrame(animate);
  state.animationFrames += 1;
  resize();
  if (frameDirty && mesh) {
    const t0 = performance.now();
    positionAttr.needsUpdate = true;
    computeNormals(positionAttr.array, triangles, normalAttr.array);
    normalAttr.needsUpdate = true;
    const dt = drawnSimTime === null ? 0 : frameSimTime - drawnSimTime;
    for (const b of bodies) {
      if (!b.dirty) continue;
      b.dirty = false;
      b.attr.needsUpdate = true;
      if (b.normals) {
        computeNormals(b.attr.array, b.triangles, b.normals.array);
        b.normals.needsUpdate = true;
      }
      if (b.colors) speedColors(b, dt);
    }
    drawnSimTime = frameSimTime;
    state.perf.normalsMs += performance.now() - t0;
    state.framesDrawn += 1;
    frameDirty = false;
    needsRender = true;
  }
  if (state.grab || grabLine.visible) {
    drawGrab();
    needsRender = true;
  }
  if (!needsRender) return;
  needsRender = false;
  const t0 = performance.now();
  renderer.render(scene3, camera);
  state.perf.renderMs += performance.now() - t0;
  const info = renderer.info.render;
  state.renderInfo = { calls: info.calls, triangles: info.triangles, points: info.points, lines: info.lines };
  state.renders += 1;
}

// Plots and table 5 times a second; the plots only when a frame came, the table's cells only
// where their text changed (each change costs a layout and a paint of the side bar).
function drawPlots() {
  showText();
  if (!plotsDirty) return;
  plotsDirty = false;
  const t0 = performance.now();
  residualPlot.draw();
  for (const c of Object.values(charts)) c.draw();
  for (const b of bodies) b.chart.draw();
  state.perf.plotsMs += performance.now() - t0;
  state.perf.plotDraws += 1;
}
setInterval(drawPlots, 200);
setInterval(() => send({ type: 'list' }), 2000);  // scene list, and resubscribe after an end

$('scene').addEventListener('change', (ev) => subscribe(ev.target.value));
for (const action of ['pause', 'resume', 'reset']) {
  $(action).addEventListener('click', () => state.scene && send({ type: action, scene: state.scene }));
}

connect();
animate();
