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
import { spawn } from 'node:child_process';
import { createConnection } from 'node:net';
import { randomBytes } from 'node:crypto';
import { mkdtempSync, readFileSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { parseArgs } from 'node:util';

const { values: args } = parseArgs({
  options: {
    server: { type: 'string' }, web: { type: 'string' }, cli: { type: 'string' }, 'web-root': { type: 'string' },
    mesh: { type: 'string', default: 'armadillo' },
    'create-flags': { type: 'string', default: '--rate 60 --fix-box -1,-1,-1,1,-0.040,1 --substeps 1 --iterations 2' },
    seconds: { type: 'string', default: '20' }, 'stall-seconds': { type: 'string', default: '60' },
  },
});
for (const k of ['server', 'web', 'cli', 'web-root']) {
  if (!args[k]) { console.error(`load: --${k} is required`); process.exit(2); }
}
const children = [];
const dir = mkdtempSync(join(tmpdir(), 'pliant-load-'));
process.on('exit', () => {
  for (const c of children) if (c.exitCode === null) c.kill('SIGTERM');
  rmSync(dir, { recursive: true, force: true });
});
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

function start(argv) {
  return new Promise((resolve, reject) => {
    const c = spawn(argv[0], argv.slice(1), { stdio: ['ignore', 'pipe', 'pipe'] });
    children.push(c);
    let log = '';
    const on = (d) => {
      log += d;
      const m = log.match(/listening on .*\(port (\d+)\)/);
      if (m) resolve({ port: Number(m[1]), pid: c.pid });
    };
    c.stdout.on('data', on);
    c.stderr.on('data', on);
    c.on('exit', (code) => reject(new Error(`${argv[0]} exited (${code}): ${log}`)));
    setTimeout(() => reject(new Error(`${argv[0]} did not start: ${log}`)), 30000);
  });
}

// A minimal RFC 6455 client: text out (masked), frames in; answers pings unless stalled.
class RawSocket {
  constructor(port, path) {
    this.frames = [];          // lateness_ms of each frame received
    this.latencies = [];       // ms from the end of its tick to its arrival here
    this.bytes = 0;
    this.buf = Buffer.alloc(0);
    this.open = new Promise((resolve, reject) => {
      this.sock = createConnection(port, '127.0.0.1', () => {
        this.sock.write(`GET ${path} HTTP/1.1\r\nHost: 127.0.0.1:${port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n` +
          `Sec-WebSocket-Key: ${randomBytes(16).toString('base64')}\r\nSec-WebSocket-Version: 13\r\n\r\n`);
      });
      let handshake = true;
      this.sock.on('data', (d) => {
        this.buf = Buffer.concat([this.buf, d]);
        if (handshake) {
          const end = this.buf.indexOf('\r\n\r\n');
          if (end < 0) return;
          if (!this.buf.subarray(0, 12).toString().includes('101')) return reject(new Error(this.buf.toString()));
          this.buf = this.buf.subarray(end + 4);
          handshake = false;
          resolve();
        }
        this.parse();
      });
      this.sock.on('error', reject);
    });
  }
  send(obj, opcode = 1) {
    const payload = Buffer.from(typeof obj === 'string' ? obj : JSON.stringify(obj));
    const mask = randomBytes(4);
    const head = payload.length < 126 ? Buffer.from([0x80 | opcode, 0x80 | payload.length])
      : Buffer.from([0x80 | opcode, 0x80 | 126, payload.length >> 8, payload.length & 255]);
    const body = Buffer.from(payload.map((b, i) => b ^ mask[i % 4]));
    this.sock.write(Buffer.concat([head, mask, body]));
  }
  parse() {
    for (;;) {
      if (this.buf.length < 2) return;
      const op = this.buf[0] & 0x0f;
      let len = this.buf[1] & 0x7f, off = 2;
      if (len === 126) { if (this.buf.length < 4) return; len = this.buf.readUInt16BE(2); off = 4; }
      else if (len === 127) { if (this.buf.length < 10) return; len = Number(this.buf.readBigUInt64BE(2)); off = 10; }
      if (this.buf.length < off + len) return;
      const p = this.buf.subarray(off, off + len);
      this.buf = this.buf.subarray(off + len);
      this.bytes += len;
      if (op === 9) this.send(p.toString('latin1'), 10);           // ping -> pong
      else if (op === 2 && p[0] === 2) {
        this.frames.push(p.readDoubleLE(80));
        const nowNs = (performance.timeOrigin + performance.now()) * 1e6;
        this.latencies.push((nowNs - Number(p.readBigInt64LE(88))) / 1e6);
      }
    }
  }
  stall() { this.sock.pause(); }
  close() { this.sock.destroy(); }
}

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
    s.send({ type: 'subscribe', scene: 'load', max_rate_hz: 0 });
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
  mesh: args.mesh, create_flags: args['create-flags'], seconds,
  one_client: one, ten_clients: ten,
  stalled: { seconds: stallSeconds, web_rss_kb_every_5s: rss, rss_growth_kb: rss[rss.length - 1] - rss[1],
    reader_frames_per_s: Number(readerFps.toFixed(1)) },
}));
process.exit(0);
