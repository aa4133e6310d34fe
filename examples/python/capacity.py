#!/usr/bin/env python3
# SPDX-License-Identifier: Apache-2.0
"""How many realtime scenes one server holds: adds scenes in steps and measures, per step, the
fraction of ticks that ended late and the deadlines skipped, until lateness appears.

    PYTHONPATH=build/python python3 examples/python/capacity.py --address 127.0.0.1:50051 \\
        --counts 1,2,4,6,8,12,16 --rate 60 --seconds 5

Each scene is the demo's cantilever (beam1 clamped at x = 0, realtime at --rate Hz) with the
server's default solver budget, or --method auto (the demo's: the server picks the most
accurate method within half the tick). Start the server with --max-scenes at least the largest
count. Prints one JSON line per step; stops after the first step whose late fraction exceeds
--late-limit. Scenes it created are deleted at the end.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

import pliant


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--address", default=os.environ.get("PLIANT_ADDRESS", "localhost:50051"))
    ap.add_argument("--token", default=os.environ.get("PLIANT_TOKEN"))
    ap.add_argument("--counts", default="1,2,4,6,8,12,16", help="scene counts to try, ascending")
    ap.add_argument("--rate", type=float, default=60.0, help="tick rate of every scene, Hz")
    ap.add_argument("--mesh", default="beam1")
    ap.add_argument("--method", default=None, help="solver method (default: the server's)")
    ap.add_argument("--seconds", type=float, default=5.0, help="measurement window per step")
    ap.add_argument("--late-limit", type=float, default=0.01,
                    help="stop after a step with more than this fraction of late ticks (default 0.01)")
    args = ap.parse_args()
    counts = [int(x) for x in args.counts.split(",") if x]
    if not counts or counts != sorted(counts) or counts[0] < 1:
        ap.error(f"--counts must be ascending positive integers, got {args.counts!r}")

    created = []
    with pliant.Client(args.address, args.token) as c:
        c.wait_ready(10.0)
        try:
            for n in counts:
                while len(created) < n:
                    sid = f"capacity-{len(created)}"
                    c.create_scene(sid, args.mesh, rate_hz=args.rate, fix_x_below=0.001,
                                   method=args.method)
                    created.append(sid)
                time.sleep(1.0)  # let the new scenes settle (method choice, first ticks)
                before = {s.scene_id: s for s in c.list_scenes() if s.scene_id in created}
                time.sleep(args.seconds)
                after = {s.scene_id: s for s in c.list_scenes() if s.scene_id in created}
                ticks = sum(after[s].tick - before[s].tick for s in created)
                late = sum(after[s].late_ticks - before[s].late_ticks for s in created)
                skipped = sum(after[s].skipped_ticks - before[s].skipped_ticks for s in created)
                expected = n * args.rate * args.seconds
                row = {"scenes": n, "rate_hz": args.rate, "ticks": ticks,
                       "tick_ratio": round(ticks / expected, 4),
                       "late_fraction": round(late / max(ticks, 1), 4), "skipped_deadlines": skipped,
                       "method": pliant.pb.Method.Name(after[created[0]].spec.solver.method),
                       "substeps": after[created[0]].spec.solver.substeps}
                print(json.dumps(row), flush=True)
                if late / max(ticks, 1) > args.late_limit:
                    break
        finally:
            for sid in created:
                try:
                    c.delete_scene(sid)
                except pliant.PliantError as e:
                    print(f"capacity: could not delete {sid}: {e}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
