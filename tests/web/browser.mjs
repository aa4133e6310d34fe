// SPDX-License-Identifier: Apache-2.0
// The page in a real browser: starts pliant-server and pliant-web on free loopback ports,
// creates a realtime beam scene and drives Debian's headless Chromium (software WebGL) with
// playwright-core. Checks that frames arrive and are drawn, the canvas changes, the plots have
// points, that dragging the beam's tip grabs it, moves it and releases it, and that the canvas
// is not redrawn while the scene is paused; then, on a scene with a rope, a cloth and a fluid,
// that the page draws the particle bodies (the renderer's point and triangle counts, and the
// canvas pixels where the rope's end is differ with the bodies hidden), and that pressing on the
// rope's end grabs that particle by body name. Saves a screenshot of the page (docs/img/web.png
// comes from here; --bodies-screenshot: docs/img/web-bodies.png).
//
//   node tests/web/browser.mjs --server BIN --web BIN --cli BIN --web-root DIR [--screenshot PNG]
//        [--bodies-screenshot PNG]
//   node tests/web/browser.mjs ... --bench [--seconds S] [--encoding float32|uint16]
//        [--mesh NAME] [--create-flags="--rate 60 ..."] [--pages N] [--browser-nice N]
//        [--gpu-compositing] [--cpu-profile FILE]
//
// --bench streams a scene (default: the thesis armadillo, realtime 60 Hz) instead and prints one
// JSON line: frames received and drawn per second, latency from the end of a tick to the frame
// handled in the page (p50/p99), an observer socket's latency and every tick's lateness, the
// page's main-thread ms per stage, bytes per frame; with --pages N, the same again with N pages
// on the scene (`with_pages`). --gpu-compositing: the compositor on SwiftShader's GL too (the
// old setup); --browser-nice N: the browser's processes at nice N; --cpu-profile FILE: a V8
// profile of the page during the measurement. The browser is Chromium at $PLIANT_CHROMIUM or /usr/bin/chromium;
// a missing browser or playwright-core is an error (scripts/web-test-deps.sh installs both).
import { spawn, spawnSync } from 'node:child_process';
import { existsSync, mkdtempSync, readdirSync, readFileSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { parseArgs } from 'node:util';

// ---- processes --------------------------------------------------------------------------------
const children = [];
const dir = mkdtempSync(join(tmpdir(), 'pliant-browser-'));
function cleanup() {
  for (const c of children) if (c.exitCode === null) c.kill('SIGTERM');
  try { rmSync(dir, { recursive: true, force: true }); } catch { /* best effort */ }
}
process.on('exit', cleanup);

const { values: args } = parseArgs({
  options: {
    server: { type: 'string' }, web: { type: 'string' }, cli: { type: 'string' }, 'web-root': { type: 'string' },
    screenshot: { type: 'string' }, 'bodies-screenshot': { type: 'string' }, bench: { type: 'boolean', default: false },
    seconds: { type: 'string', default: '20' }, encoding: { type: 'string', default: 'float32' },
    mesh: { type: 'string', default: 'armadillo' },
    pages: { type: 'string', default: '1' }, 'gpu-compositing': { type: 'boolean', default: false },
    'cpu-profile': { type: 'string' }, 'browser-nice': { type: 'string' },
    'create-flags': { type: 'string', default: '--rate 60 --fix-box -1,-1,-1,1,-0.040,1' },
  },
});
for (const k of ['server', 'web', 'cli', 'web-root']) if (!args[k]) fail(`--${k} is required`);
if (!['float32', 'uint16'].includes(args.encoding)) fail(`--encoding must be float32 or uint16, got '${args.encoding}'`);

const chromiumPath = process.env.PLIANT_CHROMIUM || '/usr/bin/chromium';
if (!existsSync(chromiumPath)) fail(`no browser at ${chromiumPath}: install Debian's chromium (bash scripts/web-test-deps.sh)`);
let chromium;
try {
  ({ chromium } = await import('playwright-core'));
} catch (e) {
  fail(`playwright-core is not installed (bash scripts/web-test-deps.sh): ${e.message}`);
}

function fail(msg) {
  console.error(`browser: FAILED: ${msg}`);
  cleanup();
  process.exit(1);
}

// Starts a program and resolves with its port once it logs "listening on ... (port N)".
function startProgram(name, argv) {
  return new Promise((resolve, reject) => {
    const child = spawn(argv[0], argv.slice(1), { stdio: ['ignore', 'pipe', 'pipe'] });
    children.push(child);
    let log = '';
    const timer = setTimeout(() => reject(new Error(`${name} did not start in 30 s:\n${log}`)), 30000);
    const onData = (d) => {
      log += d.toString();
      const m = log.match(/listening on .*\(port (\d+)\)/);
      if (m) { clearTimeout(timer); resolve({ port: Number(m[1]), child, log: () => log }); }
    };
    child.stdout.on('data', onData);
    child.stderr.on('data', onData);
    child.on('exit', (code) => { clearTimeout(timer); reject(new Error(`${name} exited (${code}):\n${log}`)); });
  });
}

const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

async function waitFor(page, what, fn, arg, timeoutMs = 30000) {
  try {
    await page.waitForFunction(fn, arg, { timeout: timeoutMs, polling: 50 });
  } catch {
    const s = await page.evaluate(() => ({ frames: window.pliant?.framesReceived, banner: window.pliant?.banner,
      errors: window.pliant?.errors })).catch(() => ({}));
    throw new Error(`timed out waiting for ${what} (${JSON.stringify(s)})`);
  }
}

process.on('unhandledRejection', (e) => fail(e.message));
const server = await startProgram('pliant-server',
  [args.server, '--listen', '127.0.0.1:0', '--data-dir', join(dir, 'data'), '--log-level', 'info']);
const address = `127.0.0.1:${server.port}`;
const token = 'browser-test';
const web = await startProgram('pliant-web',
  [args.web, '--listen', '127.0.0.1:0', '--address', address, '--web-token', token, '--web-root', args['web-root']]);

// The page cannot create scenes (pliant-web has no such message): the pliant CLI does.
const cli = args.cli;
function pliant(...argv) {
  return new Promise((resolve, reject) => {
    const c = spawn(cli, ['--address', address, ...argv], { stdio: ['ignore', 'pipe', 'pipe'] });
    let out = '';
    c.stdout.on('data', (d) => { out += d; });
    c.stderr.on('data', (d) => { out += d; });
    c.on('exit', (code) => (code === 0 ? resolve(out) : reject(new Error(`pliant ${argv.join(' ')}: ${out}`))));
  });
}

const sceneId = args.bench ? 'bench' : 'beam';
if (args.bench) {
  // By default the thesis armadillo standing on its feet (every vertex below y = -4 cm fixed).
  await pliant('scenes', 'create', sceneId, '--mesh', args.mesh, ...args['create-flags'].split(' ').filter(Boolean));
} else {
  // Support inertia holds the 1 MPa beam near its converged shape at a small budget.
  await pliant('scenes', 'create', sceneId, '--mesh', 'beam1', '--fix-x-below', '0.001', '--rate', '60',
    '--substeps', '4', '--iterations', '4', '--support-inertia', '1');
}

// ---- browser ----------------------------------------------------------------------------------
// Chromium as it runs on a machine without a GPU: WebGL on SwiftShader (software), the page
// composited in software. --gpu-compositing instead forces the compositor onto SwiftShader's GL
// too, which costs several times more per frame for the same page (docs/web.md, Measurements).
const browser = await chromium.launch({
  executablePath: chromiumPath,
  headless: true,
  args: args['gpu-compositing']
    ? ['--use-gl=angle', '--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--ignore-gpu-blocklist']
    : ['--enable-unsafe-swiftshader'],
});
const page = await browser.newPage({ viewport: { width: 1280, height: 720 } });
const consoleErrors = [];
page.on('console', (m) => { if (m.type() === 'error') consoleErrors.push(m.text()); });
page.on('pageerror', (e) => consoleErrors.push(String(e)));
const url = `http://127.0.0.1:${web.port}/?token=${token}&scene=${sceneId}&encoding=${args.encoding}`;

// --browser-nice N: the browser's processes (and the renderers they start later) at nice N, as
// if the browsers ran on other machines: what is left is the cost of the gateway and the sockets.
function reniceBrowser() {
  if (args['browser-nice'] === undefined) return;
  const parent = new Map();
  for (const d of readdirSync('/proc')) {
    if (!/^\d+$/.test(d)) continue;
    try {
      const stat = readFileSync(`/proc/${d}/stat`, 'utf8');
      parent.set(Number(d), Number(stat.slice(stat.lastIndexOf(')') + 2).split(' ')[1]));
    } catch { /* gone */ }
  }
  const ours = new Set(children.map((c) => c.pid));
  const isBrowser = (pid) => {
    for (let p = pid; p > 1; p = parent.get(p)) {
      if (ours.has(p)) return false;
      if (p === process.pid) return pid !== process.pid;
    }
    return false;
  };
  const pids = [...parent.keys()].filter(isBrowser);
  spawnSync('renice', ['-n', args['browser-nice'], '-p', ...pids.map(String)], { stdio: 'ignore' });
}
reniceBrowser();

let exitCode = 0;
try {
  await page.goto(url);
  if (args.bench) await bench();
  else await check();
} catch (e) {
  console.error(`browser: FAILED: ${e.message}`);
  if (consoleErrors.length) console.error(`browser: page errors: ${consoleErrors.join('\n')}`);
  console.error(`browser: pliant-web log:\n${web.log()}`);
  exitCode = 1;
}
await browser.close();
cleanup();
process.exit(exitCode);

async function check() {
  const results = [];
  const ok = (name, cond, detail) => {
    results.push({ name, ok: !!cond });
    console.log(`browser: ${cond ? 'ok  ' : 'FAIL'} ${name}${detail ? ` (${detail})` : ''}`);
  };

  await waitFor(page, 'the first frame', () => window.pliant.framesReceived >= 1);
  const canvas = page.locator('#gl');
  const first = await canvas.screenshot();
  await waitFor(page, '60 frames', () => window.pliant.framesReceived >= 60);
  const s = await page.evaluate(() => ({ received: window.pliant.framesReceived, drawn: window.pliant.framesDrawn,
    plots: window.pliant.plotPoints(), bytes: window.pliant.lastFrameBytes, latency: window.pliant.latenciesMs.slice(-1)[0] }));
  ok('at least 60 frames arrive', s.received >= 60, `${s.received} received, ${s.drawn} drawn, ${s.bytes} bytes each`);
  ok('frames are drawn', s.drawn >= 5, `${s.drawn} drawn (the rate is measured by --bench)`);
  const later = await canvas.screenshot();
  ok('the canvas pixels change', !first.equals(later));
  await sleep(300);  // the plots redraw every 100 ms
  const plots = await page.evaluate(() => window.pliant.plotPoints());
  ok('the plots have points', plots.residual > 0 && plots.error > 10 && plots.tps > 10 && plots.late > 10 && plots.step > 10,
    JSON.stringify(plots));

  // The tip: a point on the top face near the free end, on screen. The beam still swings a
  // little: a press that misses it (the page then orbits) is tried again where the tip now is.
  const findTheTip = () => page.evaluate(() => {
    const p = window.pliant;
    const t = p.topology, n = t.surfaceVertices;
    let maxX = -Infinity, maxY = -Infinity, minX = Infinity;
    for (let i = 0; i < n; ++i) {
      const v = p.vertex(i);
      maxX = Math.max(maxX, v[0]); minX = Math.min(minX, v[0]); maxY = Math.max(maxY, v[1]);
    }
    const len = maxX - minX;
    const near = [];
    for (let i = 0; i < n; ++i) {
      const v = p.vertex(i);
      if (v[0] > maxX - 0.08 * len) near.push(v);
    }
    const top = Math.max(...near.map((v) => v[1]));
    const onTop = near.filter((v) => v[1] > top - 1e-3);
    const c = [0, 1, 2].map((k) => onTop.reduce((a, v) => a + v[k], 0) / onTop.length);
    let tipIndex = 0;
    for (let i = 0; i < n; ++i) if (p.vertex(i)[0] > p.vertex(tipIndex)[0]) tipIndex = i;
    return { screen: p.project(c), tipIndex, tipY: p.vertex(tipIndex)[1] };
  });
  let tip = null;
  for (let attempt = 0; ; ++attempt) {
    tip = await findTheTip();
    await page.mouse.move(tip.screen.x, tip.screen.y);
    await page.mouse.down();
    try {
      await waitFor(page, 'the grab', () => window.pliant.grab && window.pliant.grab.id !== null, undefined,
        attempt < 4 ? 1500 : 5000);
      break;
    } catch (e) {
      if (attempt >= 4) throw e;
      await page.mouse.up();
      await sleep(200);
    }
  }
  ok('pressing on the tip grabs it', true, `grab ${await page.evaluate(() => window.pliant.grab.id)}`);
  await page.mouse.move(tip.screen.x, tip.screen.y - 90, { steps: 15 });
  await sleep(800);
  const during = await page.evaluate((i) => ({ y: window.pliant.vertex(i)[1], force: window.pliant.grab?.force,
    tick: window.pliant.header.tick, drawing: window.pliant.grabDrawing() }), tip.tipIndex);
  ok('dragging moves the tip in the next frames', during.y > tip.tipY + 0.003,
    `tip y ${(tip.tipY * 1000).toFixed(2)} -> ${(during.y * 1000).toFixed(2)} mm`);
  ok('the grab force is shown', during.force && Math.hypot(...during.force) > 0 && during.drawing.line && during.drawing.arrow,
    during.force ? `${Math.hypot(...during.force).toFixed(3)} N` : 'none');
  if (args.screenshot) {
    await page.screenshot({ path: args.screenshot });
    console.log(`browser: screenshot ${args.screenshot}`);
  }
  await page.mouse.up();
  await waitFor(page, 'the release', () => window.pliant.grab === null && window.pliant.grabsReleased >= 1, undefined, 5000);
  ok('releasing removes the grab', true);

  // A paused scene sends no frames: the page stops drawing the canvas (nothing on it changed).
  await page.click('#pause');
  const snap = () => page.evaluate(() => ({ frames: window.pliant.framesReceived, renders: window.pliant.renders,
    animation: window.pliant.animationFrames }));
  // Until no frame came for 500 ms (the last frames were in flight); the baseline is the snapshot
  // at the end of that quiet half second, when the last frame has been drawn (a frame counted
  // just before a snapshot is drawn in the next animation frame, after it).
  let idle0 = await snap();
  for (let i = 0; i < 40; ++i) {
    await sleep(500);
    const s1 = await snap();
    const quiet = s1.frames === idle0.frames;
    idle0 = s1;
    if (quiet) break;
  }
  await sleep(1000);
  const idle1 = await snap();
  ok('a paused scene is not redrawn', Number.isInteger(idle1.renders) && idle1.frames === idle0.frames &&
    idle1.animation > idle0.animation &&
    idle1.renders === idle0.renders,
    `${idle1.frames - idle0.frames} frames, ${idle1.renders - idle0.renders} renders in ${idle1.animation - idle0.animation} animation frames`);
  await page.click('#resume');
  const resumedAt = idle1.frames;
  await waitFor(page, 'frames after resume', (n) => window.pliant.framesReceived > n, resumedAt, 10000);

  await checkBodies(ok);

  ok('no page errors', consoleErrors.length === 0, consoleErrors.join('; '));

  const failed = results.filter((r) => !r.ok).length;
  console.log(`${results.length - failed} passed, ${failed} failed`);
  if (failed) throw new Error(`${failed} browser check(s) failed`);
}

// A scene with a rope hanging off the beam's tip, a cloth hanging from two corners above it and
// a box of fluid beside it, picked in the page's scene list.
async function checkBodies(ok) {
  const spec = {
    mesh: { builtin: 'beam1' },
    fixed: { boxes: [{ min: { x: -1, y: -1, z: -1 }, max: { x: 0.001, y: 1, z: 1 } }] },
    solver: { method: 'METHOD_XPBD', substeps: 4, iterations: 2 },
    tick: { dt: 1 / 60, mode: 'TICK_MODE_REALTIME' },
    bodies: [
      { name: 'rope', rope: { points: [{ x: 0.13, y: 0.0075, z: 0.0075 }, { x: 0.33, y: 0.0075, z: 0.0075 }],
        segments: 20, damping: 0.5, pins: { indices: [0] } } },
      { name: 'sheet', cloth: { grid: { resolution_x: 12, resolution_y: 12, size_x: 0.15, size_y: 0.15,
        origin: { x: 0, y: 0.06, z: -0.075 }, u: { x: 1 }, v: { z: 1 } },
      pins: { indices: [0, 11] } } },
      { name: 'water', fluid: { spacing: 0.02,
        blocks: [{ min: { x: -0.2, y: -0.2, z: -0.06 }, max: { x: -0.1, y: -0.08, z: 0.06 } }],
        container: { box: { center: { x: -0.15, y: -0.15, z: 0 }, half_extent: { x: 0.08, y: 0.08, z: 0.08 } } },
        // A tap just above the water: one particle per layer, 25 a second, 40 in all.
        emitters: [{ center: { x: -0.15, y: -0.085, z: 0 }, speed: 0.5, radius: 0.01, max_particles: 40 }] } },
    ],
  };
  const specFile = join(dir, 'bodies.json');
  writeFileSync(specFile, JSON.stringify(spec));
  await pliant('scenes', 'create', 'bodies', '--spec', specFile);
  await waitFor(page, 'the scene in the picker', () => [...document.querySelectorAll('#scene option')].some((o) => o.value === 'bodies'));
  await page.selectOption('#scene', 'bodies');
  await waitFor(page, 'the bodies topology', () => window.pliant.topology && window.pliant.topology.bodies.length === 3);
  // The block's 5 x 6 x 6 particles at creation, then the tap's 40 as frames bring them.
  const atCreation = await page.evaluate(() => window.pliant.topology.bodies[2].particles);
  await waitFor(page, 'the tap to pour its 40 particles', () => window.pliant.bodies()[2].particles === 220);
  ok('the fluid grows in the page as the tap pours', atCreation === 180, `${atCreation} particles at creation, then 220`);
  const f0 = await page.evaluate(() => window.pliant.framesReceived);
  await waitFor(page, 'frames of the bodies scene', (n) => window.pliant.framesReceived >= n + 20 && window.pliant.renderInfo, f0);
  const seen = await page.evaluate(() => ({ bodies: window.pliant.bodies(), info: window.pliant.renderInfo,
    surfaceTriangles: window.pliant.topology.triangles.length / 3,
    cloth: window.pliant.topology.bodies[1].triangles.length / 3, bytes: window.pliant.lastFrameBytes }));
  const particles = Object.fromEntries(seen.bodies.map((b) => [b.name, b.particles]));
  ok('the page lists the rope, the cloth and the fluid',
    seen.bodies.map((b) => `${b.name}:${b.kind}`).join(',') === 'rope:rope,sheet:cloth,water:fluid',
    seen.bodies.map((b) => `${b.name} ${b.kind} ${b.particles}`).join(', '));
  // Points: the rope's beads, the fluid's particles and the pinned markers; triangles: the
  // beam's front faces at most plus both sides of the cloth (one draw call, double-sided).
  const minPoints = particles.rope + particles.water;
  // Each body's step in the side bar: a row with its particles, its error (a fluid's density
  // error, the others' stretch, mean / max as percentages), contacts and time, and a plot of
  // its error over time.
  const table = await page.evaluate(() => ({ rows: window.pliant.bodyTable(), plots: window.pliant.plotPoints().bodies,
    stats: window.pliant.bodyStats }));
  // A cloth whose tick left self-collision out (over-stretched) says so beside its error; the
  // rope and the fluid have none to leave out (the table and the stats may be a frame apart, so
  // the sheet's row is not compared with the stats). The rope stays whole (its RMS stretch under
  // 100%: a few percent hanging; it read 517% to 3965% when its links fought the sheet).
  const percent = /^\d+\.\d+% \/ \d+\.\d+%( \(self-collision off: over-stretched\))?$/;
  const saysSuspended = (r) => r[0] === 'sheet' || !r[2].includes('self-collision');
  ok('the bodies table and plots show each body\'s step',
    table.rows.map((r) => r[0]).join(',') === 'rope,sheet,water' && table.rows.every((r) => r.length === 5 && percent.test(r[2]) && Number(r[4]) >= 0) &&
    table.rows.every(saysSuspended) && parseFloat(table.rows[0][2]) < 100 &&
    table.rows[2][1] === '220' && table.stats.length === 3 && table.stats[2].iterations > 0 &&
    table.plots.length === 3 && table.plots.every((n) => n > 10),
    `${JSON.stringify(table.rows)}; plot points ${JSON.stringify(table.plots)}`);
  ok('the renderer draws every particle and the cloth', seen.info.points >= minPoints && seen.info.lines >= 1 &&
    seen.info.triangles >= seen.cloth, `${JSON.stringify(seen.info)}; at least ${minPoints} points, ${seen.cloth} cloth triangles; ${seen.bytes} bytes per frame`);

  // Paused, the rope's end stays where it is: the canvas there differs with the bodies hidden.
  // Pressing on it grabs that particle of the body named "rope", unless something else lies in
  // front of it under the cursor at that moment (the swinging rope seen end-on, or the cloth):
  // then the grab must be that nearer thing, and the scene runs on a little and is paused again.
  const pauseAndFindTheRopesEnd = async () => {
    await page.click('#pause');
    let last = -1;
    for (let i = 0; i < 40; ++i) {
      await sleep(500);
      const n = await page.evaluate(() => window.pliant.framesReceived);
      if (n === last) break;
      last = n;
    }
    await sleep(300);
    return page.evaluate(() => {
      const p = window.pliant;
      const n = p.bodies()[0].particles;
      const xyz = p.vertex(n - 1, 'rope');
      return { xyz, screen: p.project(xyz), index: n - 1 };
    });
  };
  let end = await pauseAndFindTheRopesEnd();
  const clip = { x: Math.round(end.screen.x) - 6, y: Math.round(end.screen.y) - 6, width: 12, height: 12 };
  const withBodies = await page.screenshot({ clip });
  if (args['bodies-screenshot']) {
    await page.screenshot({ path: args['bodies-screenshot'] });
    console.log(`browser: screenshot ${args['bodies-screenshot']}`);
  }
  await page.evaluate(() => window.pliant.showBodies(false));
  await sleep(300);
  const without = await page.screenshot({ clip });
  await page.evaluate(() => window.pliant.showBodies(true));
  ok('the rope is drawn where its end is', !withBodies.equals(without),
    `end at (${end.xyz.map((v) => (1000 * v).toFixed(1)).join(', ')}) mm, screen (${end.screen.x.toFixed(0)}, ${end.screen.y.toFixed(0)})`);

  let g = null;
  const occluders = [];
  for (let attempt = 0; attempt < 6; ++attempt) {
    if (attempt > 0) {
      await page.click('#resume');
      await sleep(700);
      end = await pauseAndFindTheRopesEnd();
    }
    await sleep(300);
    await page.mouse.move(end.screen.x, end.screen.y);
    await page.mouse.down();
    await waitFor(page, 'the rope grab', () => window.pliant.grab && window.pliant.grab.id !== null, undefined, 5000);
    g = await page.evaluate(() => ({ body: window.pliant.grab.body, vertex: window.pliant.grab.vertex }));
    await page.mouse.up();
    await waitFor(page, 'the rope release', () => window.pliant.grab === null, undefined, 5000);
    if (g.body === 'rope' && Math.abs(g.vertex - end.index) <= 2) break;
    // Something else was grabbed: it must be under the cursor and in front of the rope's end.
    const other = await page.evaluate(({ body, vertex }) => window.pliant.project(window.pliant.vertex(vertex, body)), g);
    const inFront = Math.hypot(other.x - end.screen.x, other.y - end.screen.y) < 20 && other.depth < end.screen.depth;
    occluders.push(`${g.body} ${g.vertex}${inFront ? '' : ' (not in front)'}`);
    if (!inFront) break;
  }
  ok('pressing on the rope grabs its particle by body name', g.body === 'rope' && Math.abs(g.vertex - end.index) <= 2,
    `body ${g.body}, particle ${g.vertex}${occluders.length ? `; before, in front of it: ${occluders.join(', ')}` : ''}`);
  await page.click('#resume');
}

async function bench() {
  const seconds = Number(args.seconds);
  const pagesWanted = Number(args.pages);
  if (!Number.isInteger(pagesWanted) || pagesWanted < 1) throw new Error(`--pages must be an integer >= 1, got '${args.pages}'`);
  // An observer reading every frame (no acknowledgements), for the lateness of every tick.
  const { RawSocket } = await import('../../bench/web/rawsocket.mjs');
  const observer = new RawSocket(web.port, `/ws?token=${token}`);
  await observer.open;
  observer.send({ type: 'subscribe', scene: sceneId, max_rate_hz: 0 });

  await waitFor(page, 'the first frame', () => window.pliant.framesReceived >= 1, undefined, 60000);
  const phases = [await measure([page], seconds, observer)];
  if (pagesWanted > 1) {
    // More browsers on the same scene: each in its own context (its own renderer process, as
    // separate browsers would have), all visible.
    const more = await Promise.all(Array.from({ length: pagesWanted - 1 }, async () => {
      const ctx = await browser.newContext({ viewport: { width: 1280, height: 720 } });
      const p = await ctx.newPage();
      p.on('pageerror', (e) => consoleErrors.push(String(e)));
      await p.goto(url, { timeout: 180000 });
      await waitFor(p, 'the first frame', () => window.pliant.framesReceived >= 1, undefined, 180000);
      return p;
    }));
    reniceBrowser();
    phases.push(await measure([page, ...more], seconds, observer));
  }
  observer.close();
  const out = { mesh: args.mesh, create_flags: args['create-flags'], encoding: args.encoding,
    compositing: args['gpu-compositing'] ? 'gpu' : 'software', web_root: args['web-root'],
    browser_nice: args['browser-nice'] === undefined ? 0 : Number(args['browser-nice']), ...phases[0] };
  if (phases.length > 1) out.with_pages = phases[1];
  console.log(JSON.stringify(out));
  if (consoleErrors.length) throw new Error(`page errors: ${consoleErrors.join('; ')}`);
}

// Streams for `seconds` (after 2 s of warm-up) and returns what the pages and the observer saw.
async function measure(pages, seconds, observer) {
  await sleep(2000);  // warm up
  const snap = (p) => p.evaluate(() => {
    const s = window.pliant;
    return { r: s.framesReceived, d: s.framesDrawn, a: s.animationFrames, rd: s.renders, sk: s.skippedFrames,
      t: s.header.tick, st: s.header.skippedTicks, perf: { ...s.perf }, now: performance.now(), visible: document.visibilityState };
  });
  const before = await Promise.all(pages.map(snap));
  await Promise.all(pages.map((p) => p.evaluate(() => { window.pliant.latenciesMs.length = 0; if (window.pliant.latenessMs) window.pliant.latenessMs.length = 0; })));
  observer.frames.length = 0;
  observer.latencies.length = 0;
  let cdp = null;
  if (args['cpu-profile'] && pages.length === 1) {
    cdp = await page.context().newCDPSession(page);
    await cdp.send('Profiler.enable');
    await cdp.send('Profiler.setSamplingInterval', { interval: 200 });
    await cdp.send('Profiler.start');
  }
  const load0 = loadAverage();
  await sleep(seconds * 1000);
  if (cdp) {
    const { profile } = await cdp.send('Profiler.stop');
    writeFileSync(args['cpu-profile'], JSON.stringify(profile));
    console.error(`browser: CPU profile ${args['cpu-profile']}; self time by function:`);
    for (const line of summarizeProfile(profile, 25)) console.error(`browser:   ${line}`);
  }
  const after = await Promise.all(pages.map((p) => p.evaluate(() => {
    const s = window.pliant;
    return { r: s.framesReceived, d: s.framesDrawn, a: s.animationFrames, rd: s.renders, sk: s.skippedFrames,
      t: s.header.tick, st: s.header.skippedTicks, perf: { ...s.perf }, now: performance.now(), lat: s.latenciesMs.slice(),
      bytes: s.lastFrameBytes, n: s.topology.surfaceVertices, late: s.header.lateTicks };
  })));
  const perPage = after.map((a, i) => {
    const b = before[i];
    const wall = (a.now - b.now) / 1000;
    const frames = a.d - b.d, msgs = a.r - b.r;
    const per = (k, n) => Number(n ? ((a.perf[k] - b.perf[k]) / n).toFixed(3) : NaN);
    return { wall, ticks: (a.t - b.t) / wall, skippedTicks: (a.st - b.st) / wall, received: msgs / wall, drawn: frames / wall, animation: (a.a - b.a) / wall,
      renders: (a.rd - b.rd) / wall, skipped: a.sk - b.sk, visible: b.visible,
      decode_ms: per('decodeMs', msgs), normals_ms: per('normalsMs', frames), render_ms: per('renderMs', a.rd - b.rd),
      plots_ms: per('plotsMs', a.perf.plotDraws - b.perf.plotDraws) };
  });
  const lat = after.flatMap((a) => a.lat).sort((x, y) => x - y);
  const q = (xs, p) => (xs.length ? xs[Math.min(xs.length - 1, Math.floor(p * xs.length))] : NaN);
  const late = observer.frames.slice().sort((x, y) => x - y);
  const r1 = (x) => Number(x.toFixed(1)), r2 = (x) => Number(x.toFixed(2));
  const med = (xs) => q(xs.slice().sort((x, y) => x - y), 0.5);
  const p0 = perPage[0];
  const res = {
    pages: pages.length, surface_vertices: after[0].n, seconds: r1(p0.wall), load_average: r2(load0),
    ticks_per_s: r1(p0.ticks), ticks_skipped_per_s: r1(p0.skippedTicks),
    // with several pages: the median page, and the lowest
    frames_received_per_s: r1(med(perPage.map((p) => p.received))),
    frames_drawn_per_s: r1(med(perPage.map((p) => p.drawn))),
    frames_drawn_per_s_lowest: r1(Math.min(...perPage.map((p) => p.drawn))),
    animation_frames_per_s: r1(med(perPage.map((p) => p.animation))),
    renders_per_s: r1(med(perPage.map((p) => p.renders))),
    frames_skipped: perPage.reduce((s, p) => s + p.skipped, 0),
    latency_p50_ms: r2(q(lat, 0.5)), latency_p99_ms: r2(q(lat, 0.99)), latency_samples: lat.length,
    // the same path without a browser: end of tick -> frame read by the observer socket
    socket_latency_p50_ms: r2(q(observer.latencies.slice().sort((x, y) => x - y), 0.5)),
    tick_lateness_p50_ms: r2(q(late, 0.5)), tick_lateness_p99_ms: r2(q(late, 0.99)), tick_lateness_samples: late.length,
    // main-thread ms: per frame message, per drawn frame (normals), per render call, per plot redraw
    page_ms: { decode: p0.decode_ms, normals: p0.normals_ms, render_call: p0.render_ms, plots: p0.plots_ms },
    hidden_pages: perPage.filter((p) => p.visible !== 'visible').length,
    bytes_per_frame: after[0].bytes, late_ticks: after[0].late,
  };
  return res;
}

// The 1-minute load average of this machine at the start of a measurement.
function loadAverage() {
  try { return Number(readFileSync('/proc/loadavg', 'utf8').split(' ')[0]); } catch { return NaN; }
}

// Self time per function (name, file:line) of a V8 CPU profile, largest first, as text lines.
function summarizeProfile(profile, top) {
  const dt = new Map();  // node id -> ms sampled
  for (let i = 0; i < profile.samples.length; ++i) {
    const id = profile.samples[i];
    dt.set(id, (dt.get(id) || 0) + (profile.timeDeltas[i] || 0) / 1000);
  }
  const byFn = new Map();
  let total = 0;
  for (const n of profile.nodes) {
    const ms = dt.get(n.id) || 0;
    total += ms;
    const f = n.callFrame;
    const key = `${f.functionName || '(anonymous)'} ${f.url.split('/').pop()}:${f.lineNumber + 1}`;
    byFn.set(key, (byFn.get(key) || 0) + ms);
  }
  return [...byFn.entries()].sort((a, b) => b[1] - a[1]).slice(0, top)
    .map(([k, ms]) => `${ms.toFixed(0).padStart(7)} ms ${((100 * ms) / total).toFixed(1).padStart(5)}%  ${k}`);
}
