// SPDX-License-Identifier: Apache-2.0
// Decoders of pliant-web's binary messages (docs/web.md, "Binary messages"). Little-endian;
// arrays are 4-byte aligned, so positions are viewed in place over the message's buffer.

export const WIRE_VERSION = 1;
export const KIND_TOPOLOGY = 1;
export const KIND_FRAME = 2;
export const TOPOLOGY_HEADER_BYTES = 24;
export const FRAME_HEADER_BYTES = 128;
export const ENCODING_FLOAT32 = 0;
export const ENCODING_UINT16 = 1;
export const SCENE_STATES = ['unspecified', 'running', 'paused', 'lockstep'];
export const BODY_KINDS = ['other', 'fluid', 'cloth', 'rope'];
export const BODY_RECORD_BYTES = 20;
export const FLAG_ROLLED_BACK = 1;
export const FLAG_BODIES = 2;
export const FLAG_BODY_STATS = 4;
export const FLAG_BODY_CONTACTS = 8;
export const BODY_STATS_BYTES = 32;
export const BODY_CONTACTS_BYTES = 8;
export const BODY_SELF_COLLISION_SUSPENDED = 1;

function check(view, kind) {
  if (view.byteLength < 8) throw new Error(`message of ${view.byteLength} bytes is too short`);
  const k = view.getUint8(0), v = view.getUint8(1);
  if (k !== kind) throw new Error(`message kind ${k}, expected ${kind}`);
  if (v !== WIRE_VERSION) throw new Error(`wire version ${v} not supported (page speaks ${WIRE_VERSION})`);
}

// The kind of a binary message (KIND_TOPOLOGY or KIND_FRAME).
export function messageKind(buffer) {
  return new DataView(buffer).getUint8(0);
}

// { subscription, surfaceVertices, bodyVertices, triangles: Uint32Array (surface-local),
//   surfaceToBody: Uint32Array, fixed: Uint32Array (surface-local), rest: Float32Array,
//   bodies: [{ name, kind ('fluid'|'cloth'|'rope'|'other'), particles, size (m, 0 unknown),
//              triangles: Uint32Array, pinned: Uint32Array, rest: Float32Array }] }
export function decodeTopology(buffer) {
  const view = new DataView(buffer);
  check(view, KIND_TOPOLOGY);
  const n = view.getUint32(8, true), tris = view.getUint32(12, true), fixed = view.getUint32(16, true);
  const bodyCount = view.getUint16(2, true);
  const need = (off, bytes) => {
    if (off + bytes > buffer.byteLength)
      throw new Error(`topology of ${buffer.byteLength} bytes is too short (needs ${off + bytes})`);
  };
  let off = TOPOLOGY_HEADER_BYTES;
  need(off, 4 * (3 * tris + n + fixed + 3 * n));
  const triangles = new Uint32Array(buffer, off, 3 * tris); off += 12 * tris;
  const surfaceToBody = new Uint32Array(buffer, off, n); off += 4 * n;
  const fixedArr = new Uint32Array(buffer, off, fixed); off += 4 * fixed;
  const rest = new Float32Array(buffer, off, 3 * n); off += 12 * n;
  const bodies = [];
  for (let i = 0; i < bodyCount; ++i) {
    need(off, BODY_RECORD_BYTES);
    const kind = view.getUint8(off), len = view.getUint8(off + 1);
    const p = view.getUint32(off + 4, true), bt = view.getUint32(off + 8, true), k = view.getUint32(off + 12, true);
    const size = view.getFloat32(off + 16, true);
    off += BODY_RECORD_BYTES;
    need(off, len);
    const name = new TextDecoder().decode(new Uint8Array(buffer, off, len));
    off += Math.ceil(len / 4) * 4;
    need(off, 4 * (3 * bt + k + 3 * p));
    const btris = new Uint32Array(buffer, off, 3 * bt); off += 12 * bt;
    const pinned = new Uint32Array(buffer, off, k); off += 4 * k;
    const brest = new Float32Array(buffer, off, 3 * p); off += 12 * p;
    bodies.push({ name, kind: BODY_KINDS[kind] ?? 'other', particles: p, size, triangles: btris, pinned, rest: brest });
  }
  if (buffer.byteLength !== off)
    throw new Error(`topology of ${buffer.byteLength} bytes, its header says ${off}`);
  return {
    subscription: view.getUint32(4, true),
    surfaceVertices: n,
    bodyVertices: view.getUint32(20, true),
    triangles, surfaceToBody, fixed: fixedArr, rest, bodies,
  };
}

const positionBytes = (n, encoding) => (encoding === ENCODING_FLOAT32 ? 12 * n : Math.ceil((6 * n) / 4) * 4);

// Bytes of a frame; bodyParticles: the particle count of each body it carries (none: []);
// bodyStats: whether their statistics follow; bodyContacts: whether their contacts follow those.
export function frameBytes(vertices, residuals, encoding, bodyParticles = [], bodyStats = false, bodyContacts = false) {
  let n = FRAME_HEADER_BYTES + 4 * residuals + positionBytes(vertices, encoding);
  if (bodyParticles.length) n += 4 + bodyParticles.reduce((a, p) => a + 4 + positionBytes(p, encoding), 0);
  if (bodyParticles.length && bodyStats) n += 4 + BODY_STATS_BYTES * bodyParticles.length;
  if (bodyParticles.length && bodyStats && bodyContacts) n += 4 + BODY_CONTACTS_BYTES * bodyParticles.length;
  return n;
}

// The particle counts of a frame's bodies and where each one's positions start.
function frameBodies(view, h) {
  const out = [];
  if (!(h.flags & FLAG_BODIES)) return out;
  let off = FRAME_HEADER_BYTES + 4 * h.residualCount + positionBytes(h.vertexCount, h.encoding);
  if (off + 4 > view.byteLength) return null;
  const b = view.getUint32(off, true);
  off += 4;
  for (let i = 0; i < b; ++i) {
    if (off + 4 > view.byteLength) return null;
    const p = view.getUint32(off, true);
    out.push({ particles: p, offset: off + 4 });
    off += 4 + positionBytes(p, h.encoding);
  }
  return out;
}

// The fixed header of a frame (numbers; u64 counters as Numbers, exact below 2^53).
export function decodeFrameHeader(buffer) {
  const v = new DataView(buffer);
  check(v, KIND_FRAME);
  const u64 = (o) => Number(v.getBigUint64(o, true));
  const h = {
    encoding: v.getUint8(2),
    state: SCENE_STATES[v.getUint8(3)] ?? 'unspecified',
    subscription: v.getUint32(4, true),
    vertexCount: v.getUint32(8, true),
    residualCount: v.getUint32(12, true),
    tick: u64(16),
    simTime: v.getFloat64(24, true),
    lateTicks: u64(32),
    skippedTicks: u64(40),
    skippedFrames: v.getUint32(48, true),
    iterations: v.getUint32(52, true),
    ticksPerSecond: v.getFloat64(56, true),
    residual: v.getFloat64(64, true),
    stepMs: v.getFloat64(72, true),
    latenessMs: v.getFloat64(80, true),
    publishedUnixNs: v.getBigInt64(88, true),
    rollbacks: v.getUint32(96, true),
    flags: v.getUint32(100, true),
    rolledBack: (v.getUint32(100, true) & FLAG_ROLLED_BACK) !== 0,
    bboxMin: [v.getFloat32(104, true), v.getFloat32(108, true), v.getFloat32(112, true)],
    bboxMax: [v.getFloat32(116, true), v.getFloat32(120, true), v.getFloat32(124, true)],
  };
  if (h.encoding !== ENCODING_FLOAT32 && h.encoding !== ENCODING_UINT16)
    throw new Error(`frame encoding ${h.encoding} unknown`);
  const bodies = frameBodies(v, h);
  const expected = bodies ? frameBytes(h.vertexCount, h.residualCount, h.encoding, bodies.map((b) => b.particles),
    (h.flags & FLAG_BODY_STATS) !== 0, (h.flags & FLAG_BODY_CONTACTS) !== 0) : -1;
  if (buffer.byteLength !== expected)
    throw new Error(`frame of ${buffer.byteLength} bytes, its header says ${bodies ? expected : 'more'}`);
  h.bodyCount = bodies.length;
  return h;
}

function readPositions(buffer, off, values, header, scratch) {
  if (header.encoding === ENCODING_FLOAT32) return new Float32Array(buffer, off, values);
  const q = new Uint16Array(buffer, off, values);
  const positions = scratch && scratch.length === values ? scratch : new Float32Array(values);
  const lo = header.bboxMin, hi = header.bboxMax;
  const s = [(hi[0] - lo[0]) / 65535, (hi[1] - lo[1]) / 65535, (hi[2] - lo[2]) / 65535];
  for (let i = 0; i < values; i += 3) {
    positions[i] = lo[0] + q[i] * s[0];
    positions[i + 1] = lo[1] + q[i + 1] * s[1];
    positions[i + 2] = lo[2] + q[i + 2] * s[2];
  }
  return positions;
}

// Each body's step statistics, in the topology's order ([] when the frame has none).
function readBodyStats(view, h, bodies) {
  if (!(h.flags & FLAG_BODY_STATS) || !bodies.length) return [];
  const last = bodies[bodies.length - 1];
  let off = last.offset + positionBytes(last.particles, h.encoding);
  const b = view.getUint32(off, true);
  off += 4;
  const out = [];
  for (let i = 0; i < b; ++i, off += BODY_STATS_BYTES) {
    out.push({
      error: view.getFloat32(off, true),
      maxError: view.getFloat32(off + 4, true),
      stepMs: view.getFloat32(off + 8, true),
      substeps: view.getUint32(off + 12, true),
      iterations: view.getUint32(off + 16, true),
      contacts: view.getUint32(off + 20, true),
      toolContacts: view.getUint32(off + 24, true),
      bodyContacts: view.getUint32(off + 28, true),
      softBodyContacts: 0,
      selfCollisionSuspended: false,
    });
  }
  if (h.flags & FLAG_BODY_CONTACTS) {
    if (view.getUint32(off, true) !== b) throw new Error('frame body contacts and statistics disagree on the bodies');
    off += 4;
    for (let i = 0; i < b; ++i, off += BODY_CONTACTS_BYTES) {
      out[i].softBodyContacts = view.getUint32(off, true);
      out[i].selfCollisionSuspended = (view.getUint32(off + 4, true) & BODY_SELF_COLLISION_SUSPENDED) !== 0;
    }
  }
  return out;
}

// A frame: its header, residuals (Float32Array view), the surface positions, each particle
// body's positions (`bodies`, in the topology's order; [] without bodies) and their step
// statistics (`bodyStats`: { error, maxError, stepMs, substeps, iterations, contacts,
// toolContacts, bodyContacts, softBodyContacts, selfCollisionSuspended } each; [] without). Float32 positions
// are views over the buffer (no copy); 16-bit ones are dequantised into `scratch` (a
// Float32Array of 3 x vertices) and `bodyScratch[i]` (one per body), reused between frames,
// when given, else into new arrays.
export function decodeFrame(buffer, scratch = null, bodyScratch = []) {
  const header = decodeFrameHeader(buffer);
  const residuals = new Float32Array(buffer, FRAME_HEADER_BYTES, header.residualCount);
  const off = FRAME_HEADER_BYTES + 4 * header.residualCount;
  const positions = readPositions(buffer, off, 3 * header.vertexCount, header, scratch);
  const view = new DataView(buffer);
  const layout = frameBodies(view, header);
  const bodies = layout.map((b, i) => readPositions(buffer, b.offset, 3 * b.particles, header, bodyScratch[i]));
  return { header, residuals, positions, bodies, bodyStats: readBodyStats(view, header, layout) };
}
