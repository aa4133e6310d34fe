# SPDX-License-Identifier: Apache-2.0
"""The Python client against a real pliant-server: scenes, frames as numpy, errors with their
gRPC status, grabs and the haptic stream."""
from __future__ import annotations

import threading
import unittest

import grpc
import numpy as np

import pliant
import servers


class ClientTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls) -> None:
        cls.server = servers.Server()
        cls.client = pliant.Client(cls.server.address)
        cls.client.wait_ready(servers.PATIENCE_S)

    @classmethod
    def tearDownClass(cls) -> None:
        cls.client.close()
        cls.server.stop()

    def test_create_list_get_delete(self) -> None:
        c = self.client
        s = c.create_scene("crud", "beam1", young_modulus=2e6, poisson_ratio=0.35, density=1100,
                           rate_hz=30, mode="lockstep", fix_x_below=0.001)
        self.assertEqual(s.scene_id, "crud")
        self.assertAlmostEqual(s.spec.material.young_modulus, 2e6)
        self.assertAlmostEqual(s.spec.material.poisson_ratio, 0.35)
        self.assertAlmostEqual(s.spec.material.density, 1100)
        self.assertAlmostEqual(s.spec.tick.dt, 1 / 30)
        self.assertEqual(s.state, pliant.pb.SCENE_STATE_LOCKSTEP)
        self.assertIn("crud", [x.scene_id for x in c.list_scenes()])
        self.assertEqual(c.get_scene("crud").vertex_count, s.vertex_count)
        topo = c.topology("crud")
        self.assertEqual(topo.rest_positions.shape, (s.vertex_count, 3))
        self.assertEqual(topo.tets.shape, (s.tet_count, 4))
        self.assertGreater(len(topo.fixed_vertices), 0)
        self.assertTrue(np.all(topo.rest_positions[topo.fixed_vertices, 0] <= 0.001 + 1e-6))
        c.delete_scene("crud")
        with self.assertRaises(pliant.PliantError) as e:
            c.get_scene("crud")
        self.assertEqual(e.exception.code, grpc.StatusCode.NOT_FOUND)
        self.assertIn("crud", e.exception.details)

    def test_errors_carry_status_and_message(self) -> None:
        with self.assertRaises(pliant.PliantError) as e:
            self.client.create_scene("bad", "beam1", poisson_ratio=0.5)
        self.assertEqual(e.exception.code, grpc.StatusCode.INVALID_ARGUMENT)
        self.assertEqual(e.exception.code_name, "INVALID_ARGUMENT")
        self.assertIn("poisson_ratio", e.exception.details)
        self.assertIn("0.5", str(e.exception))
        self.client.create_scene("dup", "beam1", mode="lockstep")
        try:
            with self.assertRaises(pliant.PliantError) as e:
                self.client.create_scene("dup", "beam1", mode="lockstep")
            self.assertEqual(e.exception.code, grpc.StatusCode.ALREADY_EXISTS)
        finally:
            self.client.delete_scene("dup")
        with self.assertRaises(ValueError):
            self.client.create_scene("x", "beam1", mode="sometimes")

    def test_step_and_frames_as_numpy(self) -> None:
        c = self.client
        s = c.create_scene("steps", "beam1", mode="lockstep", fix_x_below=0.001)
        try:
            with c.frames("steps") as stream:
                r = c.step("steps", 5)
                self.assertEqual(r.tick, 5)
                got = []
                for f in stream:
                    got.append(f)
                    if f.tick == 5:
                        break
            # Lockstep ticks run back to back, so a busy stream may skip some; each frame says
            # how many it skipped since the previous one.
            ticks = [f.tick for f in got]
            self.assertEqual(ticks[-1], 5)
            for a, b in zip(got, got[1:]):
                self.assertEqual(b.tick - a.tick - 1, b.skipped_frames, ticks)
            last = got[-1]
            self.assertEqual(last.positions.shape, (s.vertex_count, 3))
            self.assertEqual(last.positions.dtype, np.float32)
            self.assertAlmostEqual(last.sim_time, 5 / 60, places=9)
            self.assertGreater(last.iterations, 0)
            self.assertGreater(last.residuals.size, 0)
            # Gravity pulls the free end down.
            rest = c.topology("steps").rest_positions
            self.assertLess(float(last.positions[:, 1].min()), float(rest[:, 1].min()))
            with self.assertRaises(pliant.PliantError) as e:
                c.step("nope", 1)
            self.assertEqual(e.exception.code, grpc.StatusCode.NOT_FOUND)
        finally:
            c.delete_scene("steps")

    def test_paused_reader_gets_the_newest_frame(self) -> None:
        # A reader that stops reading while the scene runs 900 ticks gets, when it reads again,
        # a frame within a few ticks of the scene's (at most one older frame, already in its
        # transport, comes first), not a backlog from when it stopped: the frame connection's
        # receive window stays small (frame_window_bytes), as the C++ client's.
        c = self.client
        c.create_scene("paused-reader", "beam1", mode="lockstep", fix_x_below=0.001,
                       substeps=1, iterations=1)
        try:
            c.step("paused-reader", 1)
            for fields in (None, ["solver_stats"]):
                with self.subTest(fields=fields), c.frames("paused-reader", fields=fields) as stream:
                    f = next(stream)
                    now = c.step("paused-reader", 900).tick
                    reads, first = 0, None
                    while f.tick + 3 < now and reads < 50:
                        f = next(stream)
                        reads += 1
                        first = first if first is not None else f.tick
                    self.assertLessEqual(reads, 2, f"scene at tick {now}, first read after the pause at tick "
                                                   f"{first}, {reads} reads to tick {f.tick}")
                    self.assertGreaterEqual(f.tick + 3, now)
                    self.assertGreater(f.skipped_frames, 0)
        finally:
            c.delete_scene("paused-reader")

    def test_grab_move_release(self) -> None:
        c = self.client
        c.create_scene("grab", "beam1", mode="lockstep", fix_x_below=0.001)
        try:
            topo = c.topology("grab")
            tip = int(np.argmax(topo.rest_positions[:, 0]))
            g = c.grab("grab", tip)
            c.step("grab", 1)
            target = topo.rest_positions[tip].astype(float) + [0.0, 0.05, 0.0]
            force = c.move_grab("grab", g, target)
            self.assertEqual(force.shape, (3,))
            c.step("grab", 30)
            with c.frames("grab", fields=["positions"]) as stream:
                c.step("grab", 1)
                f = next(iter(stream))
            self.assertLess(float(np.linalg.norm(f.positions[tip] - target)), 0.01)
            c.release("grab", g)
            with self.assertRaises(pliant.PliantError) as e:
                c.release("grab", g)
            self.assertEqual(e.exception.code, grpc.StatusCode.NOT_FOUND)
        finally:
            c.delete_scene("grab")

    def test_haptic_stream(self) -> None:
        c = self.client
        # Realtime: the server answers after every tick, whenever the tool joined the scene. The
        # solver is pinned: method auto would pick by this machine's speed, and how the body
        # bounces off the tool depends on the method.
        c.create_scene("tool", "beam1", rate_hz=60, fix_x_below=0.001, gravity=[0, 0, 0],
                       method="xpbd", substeps=64, iterations=1)
        try:
            topo = c.topology("tool")
            top = float(topo.rest_positions[:, 1].max())
            mid_x = float(topo.rest_positions[:, 0].mean())
            mid_z = float(topo.rest_positions[:, 2].mean())
            with c.haptic("tool", "sphere", radius=0.01) as h:
                watchdog = threading.Timer(servers.PATIENCE_S, h.cancel)
                watchdog.start()
                try:
                    seq = h.send([mid_x, top + 0.005, mid_z])
                    used = []
                    for f in h:
                        if f.pose_seq == seq:
                            used.append(f)
                        if len(used) == 10:
                            break
                finally:
                    watchdog.cancel()
            self.assertEqual(len(used), 10, "feedback that used the pose")
            self.assertTrue(all(f.force.shape == (3,) for f in used))
            # The body bounces off the tool, so not every tick touches; most do.
            touching = [f for f in used if f.contact_count > 0]
            self.assertGreaterEqual(len(touching), 3, [(f.tick, f.contact_count) for f in used])
            self.assertTrue(all(f.force[1] > 0.0 for f in touching),
                            f"the body pushes the tool up: {[f.force.tolist() for f in touching]}")
        finally:
            c.delete_scene("tool")


class TokenTest(unittest.TestCase):
    def test_token_is_sent(self) -> None:
        with servers.Server("--token", "s3cret-token") as srv:
            with pliant.Client(srv.address) as anonymous:
                with self.assertRaises(pliant.PliantError) as e:
                    anonymous.list_scenes()
                self.assertEqual(e.exception.code, grpc.StatusCode.UNAUTHENTICATED)
            with pliant.Client(srv.address, token="s3cret-token") as c:
                self.assertEqual(c.list_scenes(), [])


if __name__ == "__main__":
    unittest.main()
