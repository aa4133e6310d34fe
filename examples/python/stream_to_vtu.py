#!/usr/bin/env python3
# SPDX-License-Identifier: Apache-2.0
"""Streams a scene's frames from a Pliant server and writes one .vtu file per frame plus a .pvd
collection with each frame's simulation time; open the .pvd in ParaView.

    PYTHONPATH=build/python python3 examples/python/stream_to_vtu.py \\
        --address 127.0.0.1:50051 --scene demo --frames 600 --out frames/

With --create the scene is created first (beam1 clamped at x = 0, realtime at --rate Hz) and
deleted at the end. A reader thread takes frames off the stream as they come and hands them to
the writer, so a slow disk does not make the subscriber skip frames. The last line printed is a
JSON summary (frames, first and last tick, skipped frames, gaps between ticks); the exit status
is 1 when --require-every-frame is given and a frame was skipped.
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import queue
import sys
import threading
import time

import numpy as np

import pliant
from pliant.vtu import write_pvd, write_vtu

log = logging.getLogger("stream_to_vtu")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--address", default=os.environ.get("PLIANT_ADDRESS", "localhost:50051"))
    ap.add_argument("--token", default=os.environ.get("PLIANT_TOKEN"))
    ap.add_argument("--scene", default="vtu-demo", help="scene id (default vtu-demo)")
    ap.add_argument("--frames", type=int, default=600, help="frames to write (default 600)")
    ap.add_argument("--out", default="frames", help="output folder (default frames/)")
    ap.add_argument("--ascii", action="store_true", help="ASCII arrays instead of base64 binary")
    ap.add_argument("--create", action="store_true", help="create the scene first, delete it at the end")
    ap.add_argument("--mesh", default="beam1", help="with --create: builtin mesh or model (default beam1)")
    ap.add_argument("--rate", type=float, default=60.0, help="with --create: tick rate, Hz (default 60)")
    ap.add_argument("--young", type=float, default=None, help="with --create: Young's modulus, Pa")
    ap.add_argument("--require-every-frame", action="store_true",
                    help="exit 1 if a frame was skipped or ticks are not consecutive")
    ap.add_argument("--log-level", default="warning")
    args = ap.parse_args()
    logging.basicConfig(level=args.log_level.upper(), format="%(levelname)s %(name)s: %(message)s")
    if args.frames < 1:
        ap.error(f"--frames must be >= 1, got {args.frames}")

    os.makedirs(args.out, exist_ok=True)
    client = pliant.Client(args.address, args.token)
    try:
        client.wait_ready(10.0)
        if args.create:
            client.create_scene(args.scene, args.mesh, rate_hz=args.rate, fix_x_below=0.001,
                                young_modulus=args.young, start_paused=True)
        topo = client.topology(args.scene)
        rest = topo.rest_positions
        frames: "queue.Queue" = queue.Queue()
        stream = client.frames(args.scene, fields=["positions", "solver_stats"])
        errors = []

        def read() -> None:
            try:
                for i, m in enumerate(stream.messages()):
                    frames.put(m)  # converted by the writer: this thread only keeps up
                    if i + 1 == args.frames:
                        break
            except Exception as e:  # handed to the main thread, raised there
                errors.append(e)
            finally:
                frames.put(None)
                stream.cancel()

        reader = threading.Thread(target=read, name="frames", daemon=True)
        reader.start()
        if args.create:
            client.resume_scene(args.scene)  # start ticking once the stream is open

        entries, ticks, skipped, backlog, last = [], [], 0, 0, None
        t0 = time.monotonic()
        while True:
            m = frames.get()
            if m is None:
                break
            f = pliant.Frame.from_message(m)
            backlog = max(backlog, frames.qsize())
            last = f
            if f.positions.shape[0] != topo.vertex_count:
                raise RuntimeError(f"frame {f.tick} has {f.positions.shape[0]} positions, "
                                   f"topology {topo.vertex_count}")
            name = f"{args.scene}_{f.tick:06d}.vtu"
            write_vtu(os.path.join(args.out, name), f.positions, topo.tets,
                      {"displacement": (f.positions - rest).astype(np.float32)},
                      binary=not args.ascii)
            entries.append((f.sim_time, name))
            ticks.append(f.tick)
            skipped += f.skipped_frames
        reader.join()
        write_pvd(os.path.join(args.out, f"{args.scene}.pvd"), entries)
        if errors:
            raise errors[0]
        gaps = int(sum(1 for a, b in zip(ticks, ticks[1:]) if b != a + 1))
        summary = {"frames": len(ticks), "first_tick": ticks[0] if ticks else None,
                   "last_tick": ticks[-1] if ticks else None, "skipped_frames": skipped,
                   "tick_gaps": gaps, "vertices": topo.vertex_count, "tets": int(topo.tets.shape[0]),
                   "wall_s": round(time.monotonic() - t0, 3), "writer_backlog_max": backlog,
                   # The scene's own counters at the last frame: deadlines it missed (late) or
                   # skipped (a whole tick behind), i.e. whether the machine kept real time.
                   "scene_late_ticks": last.late_ticks if last else None,
                   "scene_skipped_ticks": last.skipped_ticks if last else None,
                   "pvd": os.path.join(args.out, f"{args.scene}.pvd")}
        print(json.dumps(summary))
        if args.require_every_frame and (skipped or gaps or len(ticks) != args.frames):
            log.error("frames were skipped: %s", summary)
            return 1
        return 0
    except pliant.PliantError as e:
        print(f"stream_to_vtu: {e}", file=sys.stderr)
        return 1
    finally:
        if args.create:
            try:
                client.delete_scene(args.scene)
            except pliant.PliantError as e:
                log.warning("could not delete scene %s: %s", args.scene, e)
        client.close()


if __name__ == "__main__":
    sys.exit(main())
