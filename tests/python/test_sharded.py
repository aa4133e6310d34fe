# SPDX-License-Identifier: Apache-2.0
"""Three real servers: scenes placed by id with the rendezvous rule by the Python client and by
the C++ client library (placement_probe), each found and streamed by the other."""
from __future__ import annotations

import os
import subprocess
import unittest

import grpc

import pliant
import servers

PROBE = os.environ.get("PLIANT_PLACEMENT_PROBE", "")


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


if __name__ == "__main__":
    unittest.main()
