// SPDX-License-Identifier: Apache-2.0
// The benches' child processes: each started program is killed when the bench exits, and
// start() resolves once it logs "listening on ... (port N)".
import { spawn } from 'node:child_process';

const children = [];
process.on('exit', () => {
  for (const c of children) if (c.exitCode === null) c.kill('SIGTERM');
});

// Starts argv; resolves { port, pid } when it listens, rejects when it exits first or is
// silent for 30 s.
export function start(argv) {
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
