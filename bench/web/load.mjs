// SPDX-License-Identifier: Apache-2.0
// Load on pliant-web without browsers: raw WebSocket clients (node's net, no packages) on one
// realtime scene. Prints one JSON line:
//   lateness_p99_ms with 1 reading client, then with 10 (the server's tick lateness, from the
//   frames' headers: does fan-out cost the tick anything?), the latency from the end of a tick
//   to the frame's arrival at the clients (p50/p99), and pliant-web's RSS every 5 s while one
//   client subscribes and never reads (does a stalled browser grow memory?).
//
//   node bench/web/load.mjs --server BIN --web BIN --cli BIN --web-root DIR
//        [--mesh armadillo] [--create-flags="..."] [--seconds 20] [--stall-seconds 60]
//        [--ack]   (the clients acknowledge each frame on arrival, as the page does)
import { spawn } from 'node:child_process';
import { mkdtempSync, readFileSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { parseArgs } from 'node:util';
import { start } from './processes.mjs';
import { RawSocket } from './rawsocket.mjs';

const { values: args } = parseArgs({
  options: {
    server: { type: 'string' }, web: { type: 'string' }, cli: { type: 'string' }, 'web-root': { type: 'string' },
    mesh: { type: 'string', default: 'armadillo' },
    'create-flags': { type: 'string', default: '--rate 60 --fix-box -1,-1,-1,1,-0.040,1 --substeps 1 --iterations 2' },
    seconds: { type: 'string', default: '20' }, 'stall-seconds': { type: 'string', default: '60' },
    ack: { type: 'boolean', default: false },
  },
});
for (const k of ['server', 'web', 'cli', 'web-root']) {
  if (!args[k]) { console.error(`load: --${k} is required`); process.exit(2); }
}
const dir = mkdtempSync(join(tmpdir(), 'pliant-load-'));
process.on('exit', () => {
  rmSync(dir, { recursive: true, force: true });
});
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));


function quantile(xs, q) {
  const s = [...xs].sort((a, b) => a - b);
  return s.length ? s[Math.min(s.length - 1, Math.floor(q * s.length))] : NaN;
}
const p99 = (xs) => quantile(xs, 0.99);
const rssKb = (pid) => Number(readFileSync(`/proc/${pid}/status`, 'utf8').match(/VmRSS:\s+(\d+)/)[1]);

const server = await start([args.server, '--listen', '127.0.0.1:0', '--data-dir', join(dir, 'data'), '--log-level', 'info']);
const address = `127.0.0.1:${server.port}`;
const web = await start([args.web, '--listen', '127.0.0.1:0', '--address', address, '--web-root', args['web-root']]);
await new Promise((resolve, reject) => {
  const c = spawn(args.cli, ['--address', address, 'scenes', 'create', 'load', '--mesh', args.mesh,
    ...args['create-flags'].split(' ').filter(Boolean)], { stdio: 'inherit' });
  c.on('exit', (code) => (code === 0 ? resolve() : reject(new Error(`scenes create: exit ${code}`))));
});
const seconds = Number(args.seconds);
const path = '/ws';

async function phase(n) {
  const socks = [];
  for (let i = 0; i < n; ++i) {
    const s = new RawSocket(web.port, path);
    await s.open;
    s.send({ type: 'subscribe', scene: 'load', max_rate_hz: 0, ack: args.ack });
    if (args.ack) s.onFrame = () => s.send({ type: 'ack' });  // as the page does, on arrival
    socks.push(s);
  }
  await sleep(2000);  // warm up
  for (const s of socks) { s.frames.length = 0; s.latencies.length = 0; }
  await sleep(seconds * 1000);
  const lat = socks.flatMap((s) => s.latencies);
  const r = { clients: n, frames_per_client_per_s: Number((socks[0].frames.length / seconds).toFixed(1)),
    lateness_p99_ms: Number(p99(socks[0].frames).toFixed(2)),
    latency_p50_ms: Number(quantile(lat, 0.5).toFixed(2)), latency_p99_ms: Number(p99(lat).toFixed(2)) };
  for (const s of socks) s.close();
  await sleep(500);
  return r;
}

const one = await phase(1);
const ten = await phase(10);

// A stalled client next to a reading one; pliant-web's RSS every 5 s.
const reader = new RawSocket(web.port, path);
await reader.open;
reader.send({ type: 'subscribe', scene: 'load', max_rate_hz: 0 });
const stalled = new RawSocket(web.port, path);
await stalled.open;
stalled.send({ type: 'subscribe', scene: 'load', max_rate_hz: 0 });
await sleep(1000);
stalled.stall();
const rss = [];
const stallSeconds = Number(args['stall-seconds']);
for (let t = 0; t <= stallSeconds; t += 5) {
  rss.push(rssKb(web.pid));
  if (t < stallSeconds) await sleep(5000);
}
const readerFps = reader.frames.length / (stallSeconds + 1);
console.log(JSON.stringify({
  mesh: args.mesh, create_flags: args['create-flags'], seconds, ack: args.ack,
  one_client: one, ten_clients: ten,
  stalled: { seconds: stallSeconds, web_rss_kb_every_5s: rss, rss_growth_kb: rss[rss.length - 1] - rss[1],
    reader_frames_per_s: Number(readerFps.toFixed(1)) },
}));
process.exit(0);
