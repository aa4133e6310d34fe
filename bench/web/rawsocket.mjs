// SPDX-License-Identifier: Apache-2.0
// A minimal WebSocket client for the benchmarks (node's net, no packages): subscribes like a
// browser would and records, for every frame it reads, the tick's lateness and the latency from
// the end of the tick to the frame's arrival.
import { createConnection } from 'node:net';
import { randomBytes } from 'node:crypto';

// A minimal RFC 6455 client: text out (masked), frames in; answers pings unless stalled.
export class RawSocket {
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
      if (this.onMessage && (op === 1 || op === 2)) this.onMessage(op, p);  // text or binary, as received
      else if (op === 2 && p[0] === 2) {
        this.frames.push(p.readDoubleLE(80));
        const nowNs = (performance.timeOrigin + performance.now()) * 1e6;
        this.latencies.push((nowNs - Number(p.readBigInt64LE(88))) / 1e6);
        if (this.onFrame) this.onFrame();
      }
    }
  }
  stall() { this.sock.pause(); }
  close() { this.sock.destroy(); }
}
