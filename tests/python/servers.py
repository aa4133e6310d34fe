# SPDX-License-Identifier: Apache-2.0
"""Real pliant-server processes for the Python client's tests: each on 127.0.0.1 port 0, the
port read from its 'listening on ... (port N)' log line."""
from __future__ import annotations

import os
import re
import signal
import subprocess
import tempfile
import time
from typing import List, Optional

SERVER_BIN = os.environ.get("PLIANT_SERVER_BIN", "")
PATIENCE_S = 30.0
_PORT_RE = re.compile(r"listening on .*\(port (\d+)\)")


def wait_until(condition, timeout: float, what: str):
    """Polls ``condition`` until it returns a truthy value; AssertionError naming ``what`` after ``timeout``."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.02)


class Server:
    def __init__(self, *extra: str) -> None:
        if not SERVER_BIN or not os.path.exists(SERVER_BIN):
            raise AssertionError(f"PLIANT_SERVER_BIN is not a pliant-server binary: {SERVER_BIN!r}")
        self.dir = tempfile.TemporaryDirectory(prefix="pliant-py-")
        self.log_path = os.path.join(self.dir.name, "server.log")
        self._log = open(self.log_path, "wb")
        self.proc = subprocess.Popen(
            [SERVER_BIN, "--listen", "127.0.0.1:0", "--log-level", "info",
             *extra], stdout=self._log, stderr=subprocess.STDOUT)
        self.port = int(wait_until(self._port, PATIENCE_S, "the server's 'listening on ... (port N)' log line"))
        self.address = f"127.0.0.1:{self.port}"

    def _port(self) -> Optional[str]:
        if self.proc.poll() is not None:
            raise AssertionError(f"pliant-server exited with {self.proc.returncode}:\n{self.log()}")
        m = _PORT_RE.search(self.log())
        return m.group(1) if m else None

    def log(self) -> str:
        with open(self.log_path, "r", errors="replace") as f:
            return f.read()

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=PATIENCE_S)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._log.close()
        self.dir.cleanup()
        return self.proc.returncode

    def __enter__(self) -> "Server":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


def start(count: int, *extra: str) -> List[Server]:
    servers: List[Server] = []
    try:
        for _ in range(count):
            servers.append(Server(*extra))
    except BaseException:
        for s in servers:
            s.stop()
        raise
    return servers
