// SPDX-License-Identifier: Apache-2.0
// The bytes pliant-web sends for scene spec files: starts pliant-server and pliant-web on free
// loopback ports, creates each scene (pliant scenes create --spec FILE, lockstep), subscribes in
// both encodings and prints one JSON line per scene: surface vertices and triangles, each
// particle body (kind, particles, triangles, pinned), the topology's bytes and a frame's bytes
// as float32 and as 16-bit (docs/web.md, "Particle bodies").
//
//   node bench/web/frame_bytes.mjs --server BIN --web BIN --cli BIN --web-root DIR SPEC.json...
import { spawn } from 'node:child_process';
import { mkdtempSync, readFileSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { basename, join } from 'node:path';
import { parseArgs } from 'node:util';
import { start } from './processes.mjs';
import { RawSocket } from './rawsocket.mjs';

const { values: args, positionals: specs } = parseArgs({
  allowPositionals: true,
  options: { server: { type: 'string' }, web: { type: 'string' }, cli: { type: 'string' }, 'web-root': { type: 'string' } },
});
for (const k of ['server', 'web', 'cli', 'web-root']) {
  if (!args[k]) { console.error(`frame_bytes: --${k} is required`); process.exit(2); }
}
if (!specs.length) { console.error('frame_bytes: give at least one scene spec file'); process.exit(2); }
const dir = mkdtempSync(join(tmpdir(), 'pliant-bytes-'));
process.on('exit', () => {
  rmSync(dir, { recursive: true, force: true });
});

function run(argv) {
  return new Promise((resolve, reject) => {
    const c = spawn(argv[0], argv.slice(1), { stdio: ['ignore', 'pipe', 'pipe'] });
    let out = '';
    c.stdout.on('data', (d) => { out += d; });
    c.stderr.on('data', (d) => { out += d; });
    c.on('exit', (code) => (code === 0 ? resolve(out) : reject(new Error(`${argv.join(' ')}: ${out}`))));
  });
}

const { port: serverPort } = await start([args.server, '--listen', '127.0.0.1:0', '--data-dir', join(dir, 'data')]);
const address = `127.0.0.1:${serverPort}`;
const { port: webPort } = await start([args.web, '--listen', '127.0.0.1:0', '--address', address, '--web-root', args['web-root']]);

// The subscribed reply, the topology's size and the first frame's size for one encoding.
async function sample(scene, encoding) {
  const ws = new RawSocket(webPort, '/ws');
  await ws.open;
  const got = { subscribed: null, topology: 0, frame: 0 };
  const done = new Promise((resolve) => {
    ws.onMessage = (op, p) => {
      if (op === 1) {
        const m = JSON.parse(p.toString());
        if (m.type === 'subscribed') got.subscribed = m;
        if (m.type === 'error') throw new Error(JSON.stringify(m));
      } else if (p[0] === 1) got.topology = p.length;
      else if (p[0] === 2 && !got.frame) { got.frame = p.length; resolve(); }
    };
  });
  ws.send({ type: 'subscribe', scene, max_rate_hz: 0, encoding });
  await new Promise((r) => setTimeout(r, 300));
  await run([args.cli, '--address', address, 'step', scene, '1']);
  await done;
  ws.close();
  return got;
}

for (const file of specs) {
  const spec = JSON.parse(readFileSync(file, 'utf8'));
  spec.tick = { ...(spec.tick || {}), mode: 'TICK_MODE_LOCKSTEP' };
  const lockstep = join(dir, basename(file));
  writeFileSync(lockstep, JSON.stringify(spec));
  const scene = basename(file, '.json').replace(/[^A-Za-z0-9_.-]/g, '_');
  await run([args.cli, '--address', address, 'scenes', 'create', scene, '--spec', lockstep]);
  const f32 = await sample(scene, 'float32');
  const u16 = await sample(scene, 'uint16');
  const s = f32.subscribed;
  console.log(JSON.stringify({ spec: file, surface_vertices: s.surface_vertices, surface_triangles: s.surface_triangles,
    bodies: s.bodies, topology_bytes: f32.topology, frame_bytes_float32: f32.frame, frame_bytes_uint16: u16.frame }));
}
process.exit(0);
