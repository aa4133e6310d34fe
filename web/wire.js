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
//   surfaceToBody: Uint32Array, fixed: Uint32Array (surface-local), rest: Float32Array }
export function decodeTopology(buffer) {
  const view = new DataView(buffer);
  check(view, KIND_TOPOLOGY);
  const n = view.getUint32(8, true), tris = view.getUint32(12, true), fixed = view.getUint32(16, true);
  const expected = TOPOLOGY_HEADER_BYTES + 4 * (3 * tris + n + fixed + 3 * n);
  if (buffer.byteLength !== expected)
    throw new Error(`topology of ${buffer.byteLength} bytes, its header says ${expected}`);
  let off = TOPOLOGY_HEADER_BYTES;
  const triangles = new Uint32Array(buffer, off, 3 * tris); off += 12 * tris;
  const surfaceToBody = new Uint32Array(buffer, off, n); off += 4 * n;
  const fixedArr = new Uint32Array(buffer, off, fixed); off += 4 * fixed;
  const rest = new Float32Array(buffer, off, 3 * n);
  return {
    subscription: view.getUint32(4, true),
    surfaceVertices: n,
    bodyVertices: view.getUint32(20, true),
    triangles, surfaceToBody, fixed: fixedArr, rest,
  };
}

export function frameBytes(vertices, residuals, encoding) {
  const pos = encoding === ENCODING_FLOAT32 ? 12 * vertices : Math.ceil((6 * vertices) / 4) * 4;
  return FRAME_HEADER_BYTES + 4 * residuals + pos;
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
    rolledBack: (v.getUint32(100, true) & 1) !== 0,
    bboxMin: [v.getFloat32(104, true), v.getFloat32(108, true), v.getFloat32(112, true)],
    bboxMax: [v.getFloat32(116, true), v.getFloat32(120, true), v.getFloat32(124, true)],
  };
  if (h.encoding !== ENCODING_FLOAT32 && h.encoding !== ENCODING_UINT16)
    throw new Error(`frame encoding ${h.encoding} unknown`);
  const expected = frameBytes(h.vertexCount, h.residualCount, h.encoding);
  if (buffer.byteLength !== expected) throw new Error(`frame of ${buffer.byteLength} bytes, its header says ${expected}`);
  return h;
}

// A frame: its header, residuals (Float32Array view) and positions. Float32 positions are a
// view over the buffer (no copy); 16-bit ones are dequantised into `scratch` (a Float32Array
// of 3 x vertices, reused between frames) when given, else into a new array.
export function decodeFrame(buffer, scratch = null) {
  const header = decodeFrameHeader(buffer);
  const residuals = new Float32Array(buffer, FRAME_HEADER_BYTES, header.residualCount);
  const off = FRAME_HEADER_BYTES + 4 * header.residualCount;
  const values = 3 * header.vertexCount;
  let positions;
  if (header.encoding === ENCODING_FLOAT32) {
    positions = new Float32Array(buffer, off, values);
  } else {
    const q = new Uint16Array(buffer, off, values);
    positions = scratch && scratch.length === values ? scratch : new Float32Array(values);
    const lo = header.bboxMin, hi = header.bboxMax;
    const s = [(hi[0] - lo[0]) / 65535, (hi[1] - lo[1]) / 65535, (hi[2] - lo[2]) / 65535];
    for (let i = 0; i < values; i += 3) {
      positions[i] = lo[0] + q[i] * s[0];
      positions[i + 1] = lo[1] + q[i + 1] * s[1];
      positions[i + 2] = lo[2] + q[i + 2] * s[2];
    }
  }
  return { header, residuals, positions };
}
