# SPDX-License-Identifier: Apache-2.0
"""Three real servers: scenes placed by id with the rendezvous rule by the Python client, by
the C++ client library (placement_probe) and by the pliant CLI (--servers), each found and
streamed by the others."""
from __future__ import annotations

import json
import os
import subprocess
import time
import unittest

import grpc

import pliant
import servers

PROBE = os.environ.get("PLIANT_PLACEMENT_PROBE", "")
CLI = os.environ.get("PLIANT_CLI_BIN", "")


class ShardedTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls) -> None:
        cls.servers = servers.start(3)
        cls.addresses = [s.address for s in cls.servers]
        cls.client = pliant.ShardedClient(cls.addresses)
        for c in cls.client.clients:
            c.wait_ready(servers.PATIENCE_S)

    @classmethod
    def tearDownClass(cls) -> None:
        cls.client.close()
        for s in cls.servers:
            s.stop()

    def probe(self, *args: str) -> list:
        self.assertTrue(PROBE and os.path.exists(PROBE), f"PLIANT_PLACEMENT_PROBE={PROBE!r}")
        run = subprocess.run([PROBE, "--servers", ",".join(self.addresses), *args],
                             capture_output=True, text=True, timeout=120)
        self.assertEqual(run.returncode, 0, run.stderr + run.stdout)
        return [line.split() for line in run.stdout.splitlines()]

    def test_python_places_cpp_finds_and_streams(self) -> None:
        ids = [f"py-{i}" for i in range(9)]
        for sid in ids:
            self.client.create_scene(sid, "beam1", mode="lockstep", fix_x_below=0.001)
        owners = {sid: pliant.owner_index(sid, 3) for sid in ids}
        self.assertEqual(len(set(owners.values())), 3, f"9 ids should reach all 3 servers: {owners}")
        for sid in ids:
            for k, c in enumerate(self.client.clients):
                if k == owners[sid]:
                    self.assertEqual(c.get_scene(sid).scene_id, sid)
                else:
                    with self.assertRaises(pliant.PliantError) as e:
                        c.get_scene(sid)
                    self.assertEqual(e.exception.code, grpc.StatusCode.NOT_FOUND)
        listed = sorted((k, s.scene_id) for k, s in self.client.list_scenes() if s.scene_id.startswith("py-"))
        self.assertEqual(listed, sorted((owners[s], s) for s in ids))
        # The C++ client library computes the same owners and streams from them.
        for sid, k, tick in self.probe(*ids):
            self.assertEqual(int(k), owners[sid], sid)
            self.assertGreaterEqual(int(tick), 0)

    def test_cpp_places_python_finds_and_streams(self) -> None:
        ids = [f"cpp-{i}" for i in range(9)]
        placed = {sid: int(k) for sid, k, _ in self.probe("--create", *ids)}
        self.assertEqual(sorted(placed), sorted(ids))
        for sid in ids:
            self.assertEqual(self.client.owner_index(sid), placed[sid], sid)
            scene = self.client.get_scene(sid)
            with self.client.frames(sid, fields=["positions"]) as stream:
                step = self.client.step(sid, 2)
                for f in stream:
                    if f.tick == step.tick:
                        break
            self.assertEqual(f.positions.shape, (scene.vertex_count, 3))
            self.client.delete_scene(sid)
            for c in self.client.clients:
                with self.assertRaises(pliant.PliantError):
                    c.get_scene(sid)


    def cli(self, *args: str, ok: bool = True) -> subprocess.CompletedProcess:
        self.assertTrue(CLI and os.path.exists(CLI), f"PLIANT_CLI_BIN={CLI!r}")
        run = subprocess.run([CLI, "--servers", ",".join(self.addresses), *args],
                             capture_output=True, text=True, timeout=120, env={**os.environ, "PLIANT_ADDRESS": ""})
        if ok:
            self.assertEqual(run.returncode, 0, run.stderr + run.stdout)
        return run

    def test_cli_places_python_finds_cli_gets_watches_and_lists(self) -> None:
        ids = [f"cli-{i}" for i in range(9)]
        for sid in ids:
            self.cli("scenes", "create", sid, "--mesh", "beam1", "--mode", "lockstep", "--fix-x-below", "0.001")
        owners = {sid: pliant.owner_index(sid, 3) for sid in ids}
        self.assertEqual(len(set(owners.values())), 3, f"9 ids should reach all 3 servers: {owners}")
        for sid in ids:
            # On its owner only (the Python client's direct per-server clients).
            for k, c in enumerate(self.client.clients):
                if k == owners[sid]:
                    self.assertEqual(c.get_scene(sid).scene_id, sid)
                else:
                    with self.assertRaises(pliant.PliantError):
                        c.get_scene(sid)
            got = json.loads(self.cli("--json", "scenes", "get", sid).stdout)
            self.assertEqual(got["scene_id"], sid)
        # watch streams from the owner: step the scene meanwhile, the summary counts its frames.
        sid = ids[0]
        watch = subprocess.Popen([CLI, "--servers", ",".join(self.addresses), "watch", sid, "--duration", "3",
                                  "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            for _ in range(20):
                self.client.step(sid, 1)
                time.sleep(0.05)
            out, err = watch.communicate(timeout=60)
        finally:
            if watch.poll() is None:
                watch.kill()
        self.assertEqual(watch.returncode, 0, err)
        self.assertGreater(json.loads(out.strip().splitlines()[-1])["frames"], 0, out)
        listed = json.loads(self.cli("--json", "scenes", "list").stdout)
        self.assertEqual(sorted(s["scene_id"] for s in listed["scenes"] if s["scene_id"].startswith("cli-")), sorted(ids))
        # Usage errors: one line naming what is wrong, exit 2.
        for argv, needle in ((["scenes", "create", "--mesh", "beam1"], "needs a scene ID"),
                             (["health"], "--address"),
                             (["--address", "127.0.0.1:1", "scenes", "get", sid], "not both")):
            r = self.cli(*argv, ok=False)
            self.assertEqual(r.returncode, 2, r.stderr)
            self.assertIn(needle, r.stderr)
            self.assertEqual(len(r.stderr.strip().splitlines()), 1, r.stderr)
        r = subprocess.run([CLI, "--servers", "a:1,,b:2", "scenes", "list"], capture_output=True, text=True, timeout=60)
        self.assertEqual(r.returncode, 2, r.stderr)
        self.assertIn("--servers", r.stderr)
        for sid in ids:
            self.cli("scenes", "delete", sid)

if __name__ == "__main__":
    unittest.main()
