// SPDX-License-Identifier: Apache-2.0
// The page's decoder (web/wire.js) against the golden bytes the C++ encoder is tested against
// (golden/*.hex): the same frame and topology, field by field.
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { fileURLToPath } from 'node:url';
import { decodeFrame, decodeFrameHeader, decodeTopology, frameBytes, messageKind, KIND_FRAME, KIND_TOPOLOGY,
  FLAG_BODIES, FLAG_BODY_STATS, FLAG_BODY_CONTACTS }
  from '../../web/wire.js';

function golden(name) {
  const hex = readFileSync(fileURLToPath(new URL(`golden/${name}`, import.meta.url)), 'utf8').split(/\s+/).filter(Boolean);
  const bytes = new Uint8Array(hex.map((h) => parseInt(h, 16)));
  return bytes.buffer;
}

const positions = [0.0, -0.01, 0.005, 0.1, 0.0, 0.01, 0.05, 0.02, 0.0];

function checkHeader(h, encoding) {
  assert.equal(h.encoding, encoding);
  assert.equal(h.state, 'running');
  assert.equal(h.subscription, 9);
  assert.equal(h.vertexCount, 3);
  assert.equal(h.residualCount, 2);
  assert.equal(h.tick, 42);
  assert.equal(h.simTime, 0.7);
  assert.equal(h.lateTicks, 7);
  assert.equal(h.skippedTicks, 5);
  assert.equal(h.skippedFrames, 3);
  assert.equal(h.iterations, 8);
  assert.equal(h.ticksPerSecond, 60);
  assert.equal(h.residual, 0.125);
  assert.equal(h.stepMs, 1.5);
  assert.equal(h.latenessMs, 0.25);
  assert.equal(h.publishedUnixNs, 1700000000123456789n);
  assert.equal(h.rollbacks, 2);
  assert.equal(h.rolledBack, true);
  assert.deepEqual(h.bboxMin, [0, Math.fround(-0.01), 0]);
  assert.deepEqual(h.bboxMax, [Math.fround(0.1), Math.fround(0.02), Math.fround(0.01)]);
}

test('float32 frame: header, residuals and positions viewed in place', () => {
  const buf = golden('frame_float32.hex');
  assert.equal(messageKind(buf), KIND_FRAME);
  assert.equal(buf.byteLength, frameBytes(3, 2, 0));
  const { header, residuals, positions: p } = decodeFrame(buf);
  checkHeader(header, 0);
  assert.deepEqual(Array.from(residuals), [0.5, 0.125]);
  assert.equal(p.buffer, buf, 'positions are a view over the message, not a copy');
  assert.deepEqual(Array.from(p), positions.map(Math.fround));
});

test('16-bit frame: dequantised within half a step of the bounding box', () => {
  const buf = golden('frame_uint16.hex');
  assert.equal(buf.byteLength, frameBytes(3, 2, 1));
  const { header, positions: p } = decodeFrame(buf);
  checkHeader(header, 1);
  for (let i = 0; i < 9; ++i) {
    const k = i % 3;
    const step = (header.bboxMax[k] - header.bboxMin[k]) / 65535;
    assert.ok(Math.abs(p[i] - positions[i]) <= 0.5 * step + 1e-7, `value ${i}: ${p[i]} vs ${positions[i]}`);
  }
});

test('topology: surface-local triangles, the body map, fixed vertices, rest positions', () => {
  const buf = golden('topology.hex');
  assert.equal(messageKind(buf), KIND_TOPOLOGY);
  const t = decodeTopology(buf);
  assert.equal(t.subscription, 9);
  assert.equal(t.surfaceVertices, 4);
  assert.equal(t.bodyVertices, 5);
  assert.deepEqual(Array.from(t.triangles), [0, 1, 2, 0, 2, 3, 0, 3, 1, 1, 3, 2]);
  assert.deepEqual(Array.from(t.surfaceToBody), [0, 1, 3, 4]);
  assert.deepEqual(Array.from(t.fixed), [1]);
  assert.deepEqual(Array.from(t.rest.slice(6, 9)), [3, 3.25, 3.5]);
});

test('truncated or foreign messages are refused with the reason', () => {
  const buf = golden('frame_float32.hex');
  assert.throws(() => decodeFrameHeader(buf.slice(0, buf.byteLength - 4)), /bytes, its header says/);
  assert.throws(() => decodeTopology(buf), /message kind 2, expected 1/);
});

// The same scene with a rope (3 particles, first pinned), a cloth (4, 2 triangles, 2 pinned)
// and a fluid (2): test_wire.cpp's sample_topology_with_bodies / sample_frame_with_bodies.
const bodyPositions = [
  [0.1, 0, 0, 0.18, -0.05, 0, 0.2, -0.12, 0],
  [0, 0.1, 0, 0.1, 0.1, 0, 0, 0.08, 0.1, 0.1, 0.07, 0.1],
  [0.5, -0.02, 0, 0.52, -0.02, 0.01],
];

test('topology with bodies: the surface as before, then each body record', () => {
  const buf = golden('topology_bodies.hex');
  const t = decodeTopology(buf);
  assert.equal(t.surfaceVertices, 4);
  assert.deepEqual(Array.from(t.triangles), [0, 1, 2, 0, 2, 3, 0, 3, 1, 1, 3, 2]);
  assert.deepEqual(Array.from(t.fixed), [1]);
  assert.deepEqual(t.bodies.map((b) => [b.name, b.kind, b.particles]),
    [['rope', 'rope', 3], ['sheet', 'cloth', 4], ['water', 'fluid', 2]]);
  assert.deepEqual(t.bodies.map((b) => b.size), [0.005, 0.002, 0.02].map(Math.fround));
  assert.deepEqual(Array.from(t.bodies[0].pinned), [0]);
  assert.deepEqual(Array.from(t.bodies[0].triangles), []);
  assert.deepEqual(Array.from(t.bodies[1].triangles), [0, 1, 2, 1, 3, 2]);
  assert.deepEqual(Array.from(t.bodies[1].pinned), [0, 1]);
  assert.deepEqual(Array.from(t.bodies[2].pinned), []);
  assert.deepEqual(Array.from(t.bodies[0].rest), [0.1, 0, 0, 0.2, 0, 0, 0.3, 0, 0].map(Math.fround));
  assert.deepEqual(Array.from(t.bodies[2].rest), [0.5, 0, 0, 0.52, 0, 0].map(Math.fround));
  assert.equal(t.bodies[2].rest.buffer, buf, 'rest positions are a view over the message');
  // The surface-only golden topology still decodes, with no bodies.
  assert.deepEqual(decodeTopology(golden('topology.hex')).bodies, []);
});

test('frame with bodies, float32: the bodies viewed in place after the surface', () => {
  const buf = golden('frame_bodies_float32.hex');
  assert.equal(buf.byteLength, frameBytes(3, 2, 0, [3, 4, 2]));
  const { header, positions: p, bodies } = decodeFrame(buf);
  assert.equal(header.flags, FLAG_BODIES | 1);
  assert.equal(header.bodyCount, 3);
  assert.equal(header.rolledBack, true);
  assert.deepEqual(header.bboxMin, [0, Math.fround(-0.12), 0]);
  assert.deepEqual(header.bboxMax, [Math.fround(0.52), Math.fround(0.1), Math.fround(0.1)]);
  assert.deepEqual(Array.from(p), positions.map(Math.fround));
  assert.equal(bodies.length, 3);
  for (let b = 0; b < 3; ++b) {
    assert.equal(bodies[b].buffer, buf, `body ${b} is a view over the message`);
    assert.equal(bodies[b].byteOffset % 4, 0);
    assert.deepEqual(Array.from(bodies[b]), bodyPositions[b].map(Math.fround));
  }
  // A surface-only frame has no bodies.
  assert.deepEqual(decodeFrame(golden('frame_float32.hex')).bodies, []);
});

test('frame with bodies, 16-bit: within half a step of the box of everything', () => {
  const buf = golden('frame_bodies_uint16.hex');
  assert.equal(buf.byteLength, frameBytes(3, 2, 1, [3, 4, 2]));
  const scratch = [new Float32Array(9), new Float32Array(12), new Float32Array(6)];
  const { header, positions: p, bodies } = decodeFrame(buf, null, scratch);
  assert.equal(bodies[1], scratch[1], 'dequantised into the scratch arrays');
  const within = (got, want, what) => {
    for (let i = 0; i < want.length; ++i) {
      const k = i % 3;
      const step = (header.bboxMax[k] - header.bboxMin[k]) / 65535;
      assert.ok(Math.abs(got[i] - want[i]) <= 0.5 * step + 1e-7, `${what} value ${i}: ${got[i]} vs ${want[i]}`);
    }
  };
  within(p, positions, 'surface');
  for (let b = 0; b < 3; ++b) within(bodies[b], bodyPositions[b], `body ${b}`);
});

test('a frame with bodies cut short is refused', () => {
  const buf = golden('frame_bodies_float32.hex');
  assert.throws(() => decodeFrameHeader(buf.slice(0, buf.byteLength - 4)), /bytes, its header says/);
  const topo = golden('topology_bodies.hex');
  assert.throws(() => decodeTopology(topo.slice(0, topo.byteLength - 4)), /too short/);
});

test('frame with body statistics: after the bodies, one record per body', () => {
  const buf = golden('frame_body_stats_float32.hex');
  assert.equal(buf.byteLength, frameBytes(3, 2, 0, [3, 4, 2], true, true));
  assert.equal(buf.byteLength, frameBytes(3, 2, 0, [3, 4, 2]) + 4 + 3 * 32 + 4 + 3 * 8);
  const { header, bodies, bodyStats } = decodeFrame(buf);
  assert.equal(header.flags, FLAG_BODIES | FLAG_BODY_STATS | FLAG_BODY_CONTACTS | 1);
  for (let b = 0; b < 3; ++b) assert.deepEqual(Array.from(bodies[b]), bodyPositions[b].map(Math.fround));
  assert.deepEqual(bodyStats, [
    { error: Math.fround(0.0125), maxError: 0.05, stepMs: 0.25, substeps: 16, iterations: 1, contacts: 2,
      toolContacts: 0, bodyContacts: 1, softBodyContacts: 5, selfCollisionSuspended: false },
    { error: Math.fround(0.003), maxError: 0.0078125, stepMs: 0.5, substeps: 16, iterations: 1, contacts: 0,
      toolContacts: 1, bodyContacts: 0, softBodyContacts: 0, selfCollisionSuspended: true },
    { error: 0.015625, maxError: 0.125, stepMs: 1.75, substeps: 2, iterations: 4, contacts: 7, toolContacts: 0,
      bodyContacts: 3, softBodyContacts: 11, selfCollisionSuspended: false },
  ].map((s) => ({ ...s, maxError: Math.fround(s.maxError) })));
  assert.deepEqual(decodeFrame(golden('frame_bodies_float32.hex')).bodyStats, []);
  assert.throws(() => decodeFrameHeader(buf.slice(0, buf.byteLength - 4)), /bytes, its header says/);
});
