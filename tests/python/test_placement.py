# SPDX-License-Identifier: Apache-2.0
"""Scene placement in Python against the golden vectors the C++ test reads too
(tests/client/placement_golden.tsv) and the published FNV-1a vectors."""
from __future__ import annotations

import os
import unittest
from collections import Counter

from pliant import placement

GOLDEN = os.path.join(os.environ.get("PLIANT_SOURCE_DIR", ""), "tests", "client", "placement_golden.tsv")


class PlacementTest(unittest.TestCase):
    def test_fnv1a64_published_vectors(self) -> None:
        self.assertEqual(placement.fnv1a64(b""), 0xCBF29CE484222325)
        self.assertEqual(placement.fnv1a64(b"a"), 0xAF63DC4C8601EC8C)
        self.assertEqual(placement.fnv1a64(b"foobar"), 0x85944171F73967E8)

    def test_golden_vectors_shared_with_cpp(self) -> None:
        rows = 0
        with open(GOLDEN, encoding="utf-8") as f:
            for line in f:
                line = line.rstrip("\n")
                if not line or line.startswith("#"):
                    continue
                sid, n, k, score = line.split("\t")
                self.assertEqual(placement.owner_index(sid, int(n)), int(k), f"{sid!r} over {n}")
                self.assertEqual(placement.score(sid, int(k)), int(score, 16), sid)
                rows += 1
        self.assertGreaterEqual(rows, 100)

    def test_even_spread_and_few_moves(self) -> None:
        ids = [f"scene-{i}" for i in range(6000)]
        three = [placement.owner_index(s, 3) for s in ids]
        four = [placement.owner_index(s, 4) for s in ids]
        for k, c in Counter(three).items():
            self.assertAlmostEqual(c, 2000, delta=200, msg=f"server {k}")
        moved = [(a, b) for a, b in zip(three, four) if a != b]
        self.assertTrue(all(b == 3 for _, b in moved), "scenes only move to the added server")
        self.assertAlmostEqual(len(moved), 1500, delta=200)

    def test_bad_input(self) -> None:
        with self.assertRaises(ValueError):
            placement.owner_index("", 3)
        with self.assertRaises(ValueError):
            placement.owner_index("a", 0)
        self.assertEqual(placement.parse_servers("a:1, b:2,c:3"), ["a:1", "b:2", "c:3"])
        self.assertEqual(placement.statefulset_servers("pliant", 2, namespace="sim"),
                         ["pliant-0.pliant.sim.svc:50051", "pliant-1.pliant.sim.svc:50051"])
        for bad in ("", "a:1,,b:2", "a:1,a:1"):
            with self.assertRaises(ValueError) as e:
                placement.parse_servers(bad)
            self.assertIn(repr(bad), str(e.exception))


if __name__ == "__main__":
    unittest.main()
