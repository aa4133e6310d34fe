// SPDX-License-Identifier: Apache-2.0
// Small 2D-canvas plots: a strip chart of a value over time (last N points) and a bar/line of
// the residual per iteration of the last tick. Log scales for residuals.

export class StripChart {
  // name: shown in the corner; unit: after the latest value; log: log10 axis.
  constructor(canvas, { name, unit = '', log = false, capacity = 300, color = '#4fc3f7' }) {
    this.canvas = canvas;
    this.ctx = canvas.getContext('2d');
    this.name = name;
    this.unit = unit;
    this.log = log;
    this.capacity = capacity;
    this.color = color;
    this.values = [];
  }

  push(value) {
    if (!Number.isFinite(value)) return;
    this.values.push(value);
    if (this.values.length > this.capacity) this.values.shift();
  }

  clear() { this.values = []; }

  get points() { return this.values.length; }

  draw() {
    const { ctx, canvas } = this;
    const w = canvas.width, h = canvas.height;
    ctx.fillStyle = '#101418';
    ctx.fillRect(0, 0, w, h);
    const ys = this.values.map((v) => (this.log ? Math.log10(Math.max(v, 1e-30)) : v));
    ctx.fillStyle = '#9aa5b1';
    ctx.font = '11px sans-serif';
    const last = this.values[this.values.length - 1];
    ctx.fillText(`${this.name}: ${last === undefined ? '-' : fmt(last)} ${this.unit}`, 4, 12);
    if (ys.length < 2) return;
    let lo = Math.min(...ys), hi = Math.max(...ys);
    if (!this.log) lo = Math.min(lo, 0);
    if (hi - lo < 1e-12) { hi += 0.5; lo -= 0.5; }
    ctx.fillText(this.log ? (10 ** hi).toExponential(2) : fmt(hi), w - 56, 12);
    ctx.fillText(this.log ? (10 ** lo).toExponential(2) : fmt(lo), w - 56, h - 3);
    ctx.strokeStyle = this.color;
    ctx.lineWidth = 1.5;
    ctx.beginPath();
    const top = 16, bottom = h - 4;
    ys.forEach((y, i) => {
      const px = (i / (this.capacity - 1)) * (w - 2) + 1;
      const py = bottom - ((y - lo) / (hi - lo)) * (bottom - top);
      if (i === 0) ctx.moveTo(px, py); else ctx.lineTo(px, py);
    });
    ctx.stroke();
  }
}

// The residual after each iteration of the last tick's last substep, log10 scale.
export class ResidualPlot {
  constructor(canvas) {
    this.canvas = canvas;
    this.ctx = canvas.getContext('2d');
    this.values = new Float32Array(0);
  }

  set(residuals) { this.values = Float32Array.from(residuals); }

  get points() { return this.values.length; }

  draw() {
    const { ctx, canvas } = this;
    const w = canvas.width, h = canvas.height;
    ctx.fillStyle = '#101418';
    ctx.fillRect(0, 0, w, h);
    ctx.fillStyle = '#9aa5b1';
    ctx.font = '11px sans-serif';
    const n = this.values.length;
    ctx.fillText(`residual per iteration, last tick (${n})`, 4, 12);
    if (n === 0) return;
    const ys = Array.from(this.values, (v) => Math.log10(Math.max(v, 1e-30)));
    let lo = Math.min(...ys), hi = Math.max(...ys);
    if (hi - lo < 1e-9) { hi += 0.5; lo -= 0.5; }
    ctx.fillText((10 ** hi).toExponential(2), w - 56, 12);
    ctx.fillText((10 ** lo).toExponential(2), w - 56, h - 3);
    const top = 16, bottom = h - 4;
    ctx.strokeStyle = '#ffb74d';
    ctx.fillStyle = '#ffb74d';
    ctx.beginPath();
    ys.forEach((y, i) => {
      const px = n === 1 ? w / 2 : 6 + (i / (n - 1)) * (w - 64);
      const py = bottom - ((y - lo) / (hi - lo)) * (bottom - top);
      if (i === 0) ctx.moveTo(px, py); else ctx.lineTo(px, py);
      ctx.fillRect(px - 2, py - 2, 4, 4);
    });
    ctx.stroke();
  }
}

function fmt(v) {
  const a = Math.abs(v);
  if (a !== 0 && (a < 1e-3 || a >= 1e5)) return v.toExponential(2);
  return v.toFixed(a < 10 ? 3 : 1);
}
