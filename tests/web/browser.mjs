// SPDX-License-Identifier: Apache-2.0
// The page in a real browser: starts pliant-server and pliant-web on free loopback ports,
// creates a realtime beam scene and drives Debian's headless Chromium (software WebGL) with
// playwright-core. Checks that frames arrive and are drawn, the canvas changes, the plots have
// points, and that dragging the beam's tip grabs it, moves it and releases it. Saves a
// screenshot of the page (docs/img/web.png comes from here).
//
//   node tests/web/browser.mjs --server BIN --web BIN --cli BIN --web-root DIR [--screenshot PNG]
//   node tests/web/browser.mjs ... --bench [--seconds S] [--encoding float32|uint16]
//        [--mesh NAME] [--create-flags="--rate 60 ..."]
//
// --bench streams a scene (default: the thesis armadillo, realtime 60 Hz) instead and prints one
// JSON line:
// frames drawn per second, latency from the end of a tick to the frame handled in the page
// (p50/p99), bytes per frame. The browser is Chromium at $PLIANT_CHROMIUM or /usr/bin/chromium;
// a missing browser or playwright-core is an error (scripts/web-test-deps.sh installs both).
import { spawn } from 'node:child_process';
import { existsSync, mkdtempSync, rmSync } from 'node:fs';
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
    screenshot: { type: 'string' }, bench: { type: 'boolean', default: false },
    seconds: { type: 'string', default: '20' }, encoding: { type: 'string', default: 'float32' },
    mesh: { type: 'string', default: 'armadillo' },
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
const browser = await chromium.launch({
  executablePath: chromiumPath,
  headless: true,
  args: ['--use-gl=angle', '--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--ignore-gpu-blocklist'],
});
const page = await browser.newPage({ viewport: { width: 1280, height: 720 } });
const consoleErrors = [];
page.on('console', (m) => { if (m.type() === 'error') consoleErrors.push(m.text()); });
page.on('pageerror', (e) => consoleErrors.push(String(e)));
const url = `http://127.0.0.1:${web.port}/?token=${token}&scene=${sceneId}&encoding=${args.encoding}`;

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

  // The tip: a point on the top face near the free end, on screen.
  const tip = await page.evaluate(() => {
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
  await page.mouse.move(tip.screen.x, tip.screen.y);
  await page.mouse.down();
  await waitFor(page, 'the grab', () => window.pliant.grab && window.pliant.grab.id !== null, undefined, 5000);
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
  ok('no page errors', consoleErrors.length === 0, consoleErrors.join('; '));

  const failed = results.filter((r) => !r.ok).length;
  console.log(`${results.length - failed} passed, ${failed} failed`);
  if (failed) throw new Error(`${failed} browser check(s) failed`);
}

async function bench() {
  const seconds = Number(args.seconds);
  await waitFor(page, 'the first frame', () => window.pliant.framesReceived >= 1, undefined, 60000);
  await sleep(2000);  // warm up
  const before = await page.evaluate(() => ({ r: window.pliant.framesReceived, d: window.pliant.framesDrawn,
    s: window.pliant.skippedFrames, t: window.pliant.header.tick }));
  await page.evaluate(() => { window.pliant.latenciesMs.length = 0; });
  const t0 = Date.now();
  await sleep(seconds * 1000);
  const after = await page.evaluate(() => ({ r: window.pliant.framesReceived, d: window.pliant.framesDrawn,
    s: window.pliant.skippedFrames, t: window.pliant.header.tick, lat: window.pliant.latenciesMs.slice(),
    bytes: window.pliant.lastFrameBytes, n: window.pliant.topology.surfaceVertices, tps: window.pliant.header.ticksPerSecond,
    late: window.pliant.header.lateTicks }));
  const wall = (Date.now() - t0) / 1000;
  const lat = after.lat.sort((a, b) => a - b);
  const q = (p) => (lat.length ? lat[Math.min(lat.length - 1, Math.floor(p * lat.length))] : NaN);
  console.log(JSON.stringify({
    mesh: args.mesh, create_flags: args['create-flags'], surface_vertices: after.n, encoding: args.encoding, seconds: Number(wall.toFixed(1)),
    ticks_per_s: Number(((after.t - before.t) / wall).toFixed(1)),
    frames_received_per_s: Number(((after.r - before.r) / wall).toFixed(1)),
    frames_drawn_per_s: Number(((after.d - before.d) / wall).toFixed(1)),
    frames_skipped: after.s - before.s,
    latency_p50_ms: Number(q(0.5).toFixed(2)), latency_p99_ms: Number(q(0.99).toFixed(2)),
    latency_samples: lat.length, bytes_per_frame: after.bytes, late_ticks: after.late,
  }));
}
