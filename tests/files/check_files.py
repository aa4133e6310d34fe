#!/usr/bin/python3
# SPDX-License-Identifier: Apache-2.0
"""Files the programs write and read, checked with independent readers.

  sim      pliant-sim run writes a recording; VTK's own XML reader (python3-vtk9) reads the .pvd's
           frames back: point count, array names, displacement = points - rest, det_F recomputed
           from the points, fixed vertices not moving, times.
  record   pliant record streams a realtime scene of a real pliant-server into a recording; the
           same checks, and velocity = the finite difference of consecutive frames.
  record-bodies  the same with a scene's rope, cloth and fluid, each its own series (body-NAME.pvd):
           its points, pins, cells (lines, triangles, vertices), velocity.
  examples every examples/scenes/*.json is accepted by a real pliant-server through
           `pliant scenes create --spec`, GetScene shows what the file set; a spec with a
           misspelt field is refused naming the field.

Each mode exits non-zero with a message on the first failed check.
"""
import argparse
import glob
import json
import os
import re
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET

import numpy as np
import vtk
from vtk.util.numpy_support import vtk_to_numpy


def fail(msg):
    print("FAIL: " + msg, file=sys.stderr)
    sys.exit(1)


def check(cond, msg):
    if not cond:
        fail(msg)


def read_recording(pvd):
    """[(time, file, dict of arrays)] in collection order, read with vtkXMLUnstructuredGridReader."""
    root = ET.parse(pvd).getroot()
    check(root.get("type") == "Collection", f"{pvd}: type is {root.get('type')}, not Collection")
    frames = []
    for ds in root.iter("DataSet"):
        path = os.path.join(os.path.dirname(pvd), ds.get("file"))
        r = vtk.vtkXMLUnstructuredGridReader()
        r.SetFileName(path)
        r.Update()
        grid = r.GetOutput()
        check(grid is not None and grid.GetNumberOfPoints() > 0, f"{path}: VTK read no points")
        pd, cd, fd = grid.GetPointData(), grid.GetCellData(), grid.GetFieldData()
        arrays = {
            "points": vtk_to_numpy(grid.GetPoints().GetData()).astype(float),
            "point_names": sorted(pd.GetArrayName(i) for i in range(pd.GetNumberOfArrays())),
            "cell_names": sorted(cd.GetArrayName(i) for i in range(cd.GetNumberOfArrays())),
            "field_names": sorted(fd.GetArrayName(i) for i in range(fd.GetNumberOfArrays())),
            "connectivity": vtk_to_numpy(grid.GetCells().GetConnectivityArray()),
            "types": {grid.GetCellType(i) for i in range(grid.GetNumberOfCells())},
            "cell_count": grid.GetNumberOfCells(),
        }
        if arrays["types"] == {10}:
            arrays["cells"] = arrays["connectivity"].reshape(-1, 4)
        for name in arrays["point_names"]:
            arrays[name] = vtk_to_numpy(pd.GetArray(name))
        for name in arrays["cell_names"]:
            arrays[name] = vtk_to_numpy(cd.GetArray(name))
        for name in arrays["field_names"]:
            arrays[name] = vtk_to_numpy(fd.GetArray(name))
        frames.append((float(ds.get("timestep")), ds.get("file"), arrays))
    check(frames, f"{pvd}: no DataSet")
    return frames


def det_f(rest, cur, cells):
    def vol(p):
        a, b, c, d = (p[cells[:, k]] for k in range(4))
        return np.einsum("ij,ij->i", b - a, np.cross(c - a, d - a))
    return vol(cur) / vol(rest)


def check_frames(frames, n_points=None):
    """Checks every recording shares; returns the rest positions."""
    first = frames[0][2]
    rest = first["points"] - first["displacement"]
    for t, name, a in frames:
        check(a["point_names"] == ["displacement", "fixed", "velocity"], f"{name}: point arrays {a['point_names']}")
        check(a["cell_names"] == ["det_F"], f"{name}: cell arrays {a['cell_names']}")
        check({"residual", "TimeValue"} <= set(a["field_names"]), f"{name}: field arrays {a['field_names']}")
        check(a["types"] == {10}, f"{name}: cell types {a['types']} (want only VTK_TETRA 10)")
        n = a["points"].shape[0]
        if n_points is not None:
            check(n == n_points, f"{name}: {n} points, expected {n_points}")
        check(a["displacement"].shape == (n, 3) and a["velocity"].shape == (n, 3), f"{name}: vector shapes")
        check(a["fixed"].shape == (n,), f"{name}: fixed shape {a['fixed'].shape}")
        check(np.allclose(a["points"] - a["displacement"], rest, rtol=0, atol=1e-6),
              f"{name}: points - displacement is not the rest shape")
        expected = det_f(rest, a["points"], a["cells"])
        check(np.allclose(a["det_F"], expected, rtol=1e-4, atol=1e-6),
              f"{name}: det_F differs from the volume ratio by up to {np.max(np.abs(a['det_F'] - expected)):.3g}")
        check(abs(float(a["TimeValue"][0]) - t) <= 1e-12 * max(1, abs(t)), f"{name}: TimeValue {a['TimeValue'][0]} != {t}")
        check(np.isfinite(a["residual"][0]) and a["residual"][0] >= 0, f"{name}: residual {a['residual'][0]}")
        fixed = a["fixed"] == 1
        check(fixed.any(), f"{name}: no fixed vertex")
        check(np.all(np.abs(a["displacement"][fixed]) < 1e-6), f"{name}: a fixed vertex moved")
    times = [f[0] for f in frames]
    check(all(b > a for a, b in zip(times, times[1:])), f"frame times not increasing: {times}")
    return rest


def mode_sim(args):
    with tempfile.TemporaryDirectory() as d:
        out = os.path.join(d, "rec")
        r = subprocess.run([args.sim, "run", "--mesh", "beam1", "--steps", "6", "--every", "2", "--out", out],
                           capture_output=True, text=True, timeout=120)
        check(r.returncode == 0, f"pliant-sim run failed: {r.stderr}")
        frames = read_recording(os.path.join(out, "frames.pvd"))
        check([f[1] for f in frames] == [f"frame_{k:06d}.vtu" for k in (0, 2, 4, 6)],
              f"frame files {[f[1] for f in frames]}")
        check(np.allclose([f[0] for f in frames], [k / 60 for k in (0, 2, 4, 6)], rtol=1e-12),
              f"times {[f[0] for f in frames]}")
        n = frames[0][2]["points"].shape[0]
        check(n == 216, f"beam1 has 216 vertices (24 x 3 x 3), the frame {n}")
        check_frames(frames, n)
        first, last = frames[0][2], frames[-1][2]
        check(np.all(first["displacement"] == 0) and np.all(first["velocity"] == 0), "frame 0 is not the rest state")
        free = last["fixed"] == 0
        check(np.min(last["displacement"][free][:, 1]) < -1e-6, "the free end did not sag under gravity")
        check(np.max(np.abs(last["velocity"][free])) > 1e-4, "no velocity on the free vertices after 6 steps")
        check(all(f[2]["residual"][0] > 0 for f in frames[1:]), "a stepped frame has residual 0")
        print(f"ok: {len(frames)} frames of {n} points read back by VTK {vtk.vtkVersion.GetVTKVersion()}")
        if args.mesh_tool:
            check_compressed_read(args.mesh_tool, os.path.join(out, frames[-1][1]), d)


def check_compressed_read(mesh_tool, vtu, workdir):
    """VTK writes the frame zlib-compressed (inline base64 and raw appended, both header types);
    pliant-mesh must read the same points and tets."""
    r = vtk.vtkXMLUnstructuredGridReader()
    r.SetFileName(vtu)
    r.Update()
    grid = r.GetOutput()
    for mode in ("binary", "appended"):
        for header in (32, 64):
            path = os.path.join(workdir, f"zlib_{mode}_{header}.vtu")
            w = vtk.vtkXMLUnstructuredGridWriter()
            w.SetFileName(path)
            w.SetInputData(grid)
            w.SetCompressorTypeToZLib()
            w.SetBlockSize(1024)  # several blocks per array
            w.SetHeaderTypeToUInt64() if header == 64 else w.SetHeaderTypeToUInt32()
            w.SetDataModeToBinary() if mode == "binary" else w.SetDataModeToAppended()
            if mode == "appended":
                w.EncodeAppendedDataOff()
            check(w.Write() == 1, f"VTK could not write {path}")
            text = open(path, "rb").read(400)
            check(b'compressor="vtkZLibDataCompressor"' in text, f"{path}: VTK did not compress")
            converted = os.path.join(workdir, f"zlib_{mode}_{header}_back.vtu")
            res = subprocess.run([mesh_tool, "convert", path, converted], capture_output=True, text=True, timeout=60)
            check(res.returncode == 0, f"pliant-mesh could not read VTK's zlib {mode} UInt{header} file: {res.stderr}")
            back = vtk.vtkXMLUnstructuredGridReader()
            back.SetFileName(converted)
            back.Update()
            g = back.GetOutput()
            check(g.GetNumberOfPoints() == grid.GetNumberOfPoints() and g.GetNumberOfCells() == grid.GetNumberOfCells(),
                  f"zlib {mode} UInt{header}: {g.GetNumberOfPoints()} points / {g.GetNumberOfCells()} tets back, "
                  f"wrote {grid.GetNumberOfPoints()} / {grid.GetNumberOfCells()}")
            a = vtk_to_numpy(grid.GetPoints().GetData()).astype(float)
            b = vtk_to_numpy(g.GetPoints().GetData()).astype(float)
            check(np.array_equal(a, b), f"zlib {mode} UInt{header}: points differ after the round trip")
            ca = vtk_to_numpy(grid.GetCells().GetConnectivityArray())
            cb = vtk_to_numpy(g.GetCells().GetConnectivityArray())
            check(np.array_equal(ca, cb), f"zlib {mode} UInt{header}: tets differ after the round trip")
    print("ok: VTK's zlib-compressed files (inline and appended, UInt32 and UInt64 headers) read by pliant-mesh")


class Server:
    def __init__(self, binary, workdir):
        self.log = os.path.join(workdir, "server.log")
        self.proc = subprocess.Popen([binary, "--listen", "127.0.0.1:0", "--log-level", "info"],
                                     stdout=open(self.log, "w"), stderr=subprocess.STDOUT)
        deadline = time.time() + 60
        while time.time() < deadline:
            m = re.search(r"listening on .*\(port (\d+)\)", open(self.log).read())
            if m:
                self.address = f"127.0.0.1:{m.group(1)}"
                return
            check(self.proc.poll() is None, f"pliant-server exited: {open(self.log).read()}")
            time.sleep(0.05)
        fail("pliant-server did not log its port")

    def stop(self):
        self.proc.terminate()
        self.proc.wait(timeout=60)


def cli(args, server, *argv, ok=True):
    r = subprocess.run([args.cli, "--address", server.address, *argv], capture_output=True, text=True, timeout=120)
    if ok:
        check(r.returncode == 0, f"pliant {' '.join(argv)} exited {r.returncode}: {r.stderr}")
    return r


def mode_record(args):
    with tempfile.TemporaryDirectory() as d:
        server = Server(args.server, d)
        try:
            cli(args, server, "scenes", "create", "rec", "--mesh", "beam1", "--fix-x-below", "0.001",
                "--rate", "60", "--method", "xpbd", "--substeps", "8", "--iterations", "2")
            out = os.path.join(d, "rec")
            r = cli(args, server, "--json", "record", "rec", "--out", out, "--frames", "12")
            summary = json.loads(r.stdout.strip().splitlines()[-1])
            check(summary["frames"] == 12, f"summary {summary}")
            frames = read_recording(os.path.join(out, "frames.pvd"))
            check(len(frames) == 12, f"{len(frames)} frames in the .pvd")
            check(frames[0][1] == f"frame_{summary['first_tick']:06d}.vtu", f"first file {frames[0][1]}, {summary}")
            rest = check_frames(frames, 216)
            # Fixed flags: the vertices with rest x <= 0.001 (the clamp).
            check(np.array_equal(frames[0][2]["fixed"] == 1, rest[:, 0] <= 0.001 + 1e-7), "fixed flags differ from the clamp")
            check(np.all(frames[0][2]["velocity"] == 0), "the first frame's velocity is not zero")
            for (t0, _, a), (t1, name, b) in zip(frames, frames[1:]):
                fd = (b["points"] - a["points"]) / (t1 - t0)
                check(np.allclose(b["velocity"], fd, rtol=1e-6, atol=1e-6),
                      f"{name}: velocity is not the finite difference of the frames")
            # Bad input: one line on stderr, non-zero exit.
            for argv, needle in ((["record", "rec"], "--out"), (["record", "rec", "--out", out, "--frames", "0"], "--frames"),
                                 (["record", "rec", "--out", out, "--duration", "x"], "--duration"),
                                 (["record", "nosuch", "--out", out, "--frames", "1"], "nosuch")):
                r = cli(args, server, *argv, ok=False)
                check(r.returncode != 0 and needle in r.stderr, f"pliant {argv}: rc {r.returncode}, stderr {r.stderr!r}")
        finally:
            server.stop()
        print(f"ok: {len(frames)} streamed frames read back by VTK")


def check_body_series(frames, kind, particles, pinned):
    """A particle body's series: its points, pins, cells of its kind, velocity as the finite difference."""
    want_types = {"rope": {3}, "cloth": {5}, "fluid": {1}}[kind]
    first = frames[0][2]
    rest = first["points"] - first["displacement"]
    for t, name, a in frames:
        check(a["point_names"] == ["displacement", "fixed", "velocity"], f"{name}: point arrays {a['point_names']}")
        check(a["cell_names"] == [], f"{name}: cell arrays {a['cell_names']} (a body has no det_F)")
        check(a["types"] == want_types, f"{name}: cell types {a['types']}, want {want_types} for a {kind}")
        check(a["points"].shape == (particles, 3), f"{name}: {a['points'].shape[0]} points, expected {particles}")
        check(np.allclose(a["points"] - a["displacement"], rest, rtol=0, atol=1e-6), f"{name}: rest shape differs")
        check(sorted(np.nonzero(a["fixed"] == 1)[0].tolist()) == pinned, f"{name}: fixed {np.nonzero(a['fixed'])[0]}")
        check(np.all(np.abs(a["displacement"][a["fixed"] == 1]) < 1e-6), f"{name}: a pinned particle moved")
        check(abs(float(a["TimeValue"][0]) - t) <= 1e-12 * max(1, abs(t)), f"{name}: TimeValue {a['TimeValue'][0]}")
    if kind == "rope":
        check(first["cell_count"] == particles - 1, f"rope: {first['cell_count']} segments for {particles} particles")
    if kind == "fluid":
        check(first["cell_count"] == particles, f"fluid: {first['cell_count']} vertex cells for {particles} particles")
    for (t0, _, a), (t1, name, b) in zip(frames, frames[1:]):
        fd = (b["points"] - a["points"]) / (t1 - t0)
        check(np.allclose(b["velocity"], fd, rtol=1e-6, atol=1e-6), f"{name}: velocity is not the finite difference")
    # Under gravity the free particles fell.
    check(np.mean(frames[-1][2]["displacement"][:, 1]) < 0, f"{kind}: the body did not fall")


def mode_record_bodies(args):
    """pliant record writes one series per particle body beside the tet body's."""
    with tempfile.TemporaryDirectory() as d:
        server = Server(args.server, d)
        try:
            cli(args, server, "scenes", "create", "bod", "--mesh", "beam1", "--fix-x-below", "0.001", "--rate", "60",
                "--method", "xpbd", "--substeps", "4", "--iterations", "2",
                "--rope", "line:from=0,0.3,0:to=0.3,0.3,0:segments=10:pin=0",
                "--cloth", "sheet:origin=0.5,0.3,0:size=0.2,0.2:resolution=5,5:pin=0,4",
                "--fluid", "drop:min=-0.55,0,-0.05:max=-0.45,0.1,0.05:spacing=0.05:container=-0.5,0.1,0,0.2,0.2,0.2")
            out = os.path.join(d, "bod")
            r = cli(args, server, "--json", "record", "bod", "--out", out, "--frames", "6")
            summary = json.loads(r.stdout.strip().splitlines()[-1])
            check([b["name"] for b in summary["bodies"]] == ["line", "sheet", "drop"], f"bodies in {summary}")
            check(all(b["frames"] == 6 for b in summary["bodies"]), f"body frames in {summary}")
            check_frames(read_recording(os.path.join(out, "frames.pvd")), 216)
            series = {b["name"]: read_recording(b["pvd"]) for b in summary["bodies"]}
            check(os.path.basename(summary["bodies"][0]["pvd"]) == "body-line.pvd", f"pvd name {summary['bodies'][0]}")
            check(series["line"][0][1] == f"body-line_{summary['first_tick']:06d}.vtu", f"file {series['line'][0][1]}")
            check_body_series(series["line"], "rope", 11, [0])
            check_body_series(series["sheet"], "cloth", 25, [0, 4])
            fluid_particles = series["drop"][0][2]["points"].shape[0]
            check(fluid_particles > 0, "the fluid has no particles")
            check_body_series(series["drop"], "fluid", fluid_particles, [])
        finally:
            server.stop()
        print(f"ok: a rope, a cloth and a fluid recorded as their own series, read back by VTK")


def mode_examples(args):
    specs = sorted(glob.glob(os.path.join(args.examples, "*.json")))
    check(specs, f"no example specs in {args.examples}")
    with tempfile.TemporaryDirectory() as d:
        server = Server(args.server, d)
        try:
            for i, path in enumerate(specs):
                sid = f"example-{i}"
                with open(path) as f:
                    spec = json.load(f)
                r = cli(args, server, "--json", "scenes", "create", sid, "--spec", path)
                scene = json.loads(r.stdout)
                got = scene["spec"]
                check(len(got.get("colliders", [])) == len(spec.get("colliders", [])),
                      f"{path}: GetScene shows {len(got.get('colliders', []))} colliders, the file has "
                      f"{len(spec.get('colliders', []))}")
                bodies = scene.get("bodies", [])
                check([b["name"] for b in bodies] == [b["name"] for b in spec.get("bodies", [])],
                      f"{path}: the scene has bodies {bodies}, the file {spec.get('bodies', [])}")
                # A fluid with emitters may start empty; it then has room to grow.
                check(all(b.get("particle_count", 0) > 0 or b.get("max_particle_count", 0) > 0 for b in bodies),
                      f"{path}: a body without particles: {bodies}")
                for key in ("young_modulus", "poisson_ratio", "density"):
                    if key in spec.get("material", {}):
                        check(abs(got["material"][key] - spec["material"][key]) <= 1e-12 * abs(spec["material"][key]),
                              f"{path}: material.{key} {got['material'][key]}")
                if "mode" in spec.get("tick", {}):
                    check(got["tick"]["mode"] == spec["tick"]["mode"], f"{path}: tick.mode {got['tick']['mode']}")
                cli(args, server, "scenes", "delete", sid)
                print(f"ok: {os.path.basename(path)}")
            # --collider on the command line, beside a spec file's own colliders.
            r = cli(args, server, "--json", "scenes", "create", "flags", "--spec",
                    os.path.join(args.examples, "drop_on_floor.json"), "--mode", "lockstep",
                    "--collider", "box:center=0,-1,0:half=1,0.5,1:friction=0.3",
                    "--collider", "sphere:center=0.2,0,0:radius=0.05")
            got = json.loads(r.stdout)["spec"]
            cols = got.get("colliders", [])
            check(len(cols) == 3, f"file + 2 flags: {len(cols)} colliders")
            check(cols[1]["box"]["half_extent"] == {"x": 1, "y": 0.5, "z": 1} and cols[1]["static_friction"] == 0.3
                  and cols[1]["dynamic_friction"] == 0.3, f"--collider box: {cols[1]}")
            check(cols[2]["sphere"]["radius"] == 0.05 and cols[2]["static_friction"] == 0.5, f"--collider sphere: {cols[2]}")
            check(got["tick"]["mode"] == "TICK_MODE_LOCKSTEP", f"--mode over the file: {got['tick']['mode']}")
            # --rope / --cloth / --fluid: compact particle bodies.
            r = cli(args, server, "--json", "scenes", "create", "bodies", "--mode", "lockstep",
                    "--rope", "r:from=0.2,0,0:to=0.4,0,0:segments=10:pin=0",
                    "--cloth", "c:origin=0.5,0,0:size=0.2,0.2:resolution=5,6",
                    "--fluid", "w:min=1,0,0:max=1.1,0.1,0.1:spacing=0.025")
            got = json.loads(r.stdout)
            check([(b["name"], b["kind"], b["particle_count"]) for b in got.get("bodies", [])] ==
                  [("r", "rope", 11), ("c", "cloth", 30), ("w", "fluid", 64)], f"body flags: {got.get('bodies')}")
            check(got["bodies"][0].get("pinned_count") == 1, f"--rope pin: {got['bodies'][0]}")
            r = cli(args, server, "scenes", "get", "bodies")
            check("r: rope, 11 particles" in r.stdout, f"scenes get shows the bodies: {r.stdout!r}")
            # A fluid that starts empty and fills from a tap.
            r = cli(args, server, "--json", "scenes", "create", "tapped", "--mode", "lockstep",
                    "--fluid", "t:tap=2,0.5,0:tap-radius=0.05:tap-speed=2:tap-max=500:spacing=0.025:"
                    "container=2,0.25,0,0.25,0.25,0.25")
            got = json.loads(r.stdout)
            emitters = got["spec"]["bodies"][0]["fluid"].get("emitters", [])
            check(len(emitters) == 1 and emitters[0]["speed"] == 2 and emitters[0]["max_particles"] == 500 and
                  got["bodies"][0].get("particle_count", 0) == 0 and got["bodies"][0]["max_particle_count"] == 500,
                  f"--fluid tap: {got['spec']['bodies']} {got['bodies']}")
            cli(args, server, "step", "tapped", "30")
            r = cli(args, server, "scenes", "get", "tapped")
            check("(up to 500)" in r.stdout and "t: fluid, 0 particles" not in r.stdout, f"the tap poured: {r.stdout!r}")
            r = cli(args, server, "scenes", "create", "--fluid", "w:spacing=0.02", ok=False)
            check(r.returncode == 2 and "tap=" in r.stderr, f"--fluid without a block or a tap: {r.stderr!r}")
            r = cli(args, server, "scenes", "create", "--rope", "r:from=0,0,0", ok=False)
            check(r.returncode == 2 and "to=" in r.stderr, f"--rope without to: rc {r.returncode}, {r.stderr!r}")
            r = cli(args, server, "scenes", "create", "--rope", "r:from=0,0,0:to=1,0,0:segments=0", ok=False)
            check(r.returncode == 2 and "segments" in r.stderr, f"--rope segments=0: rc {r.returncode}, {r.stderr!r}")
            for bad_flag, needle in (("plane:point=0,0,0", "normal="), ("cone:center=0,0,0", "cone"),
                                     ("sphere:center=0,0:radius=1", "center needs 3")):
                r = cli(args, server, "scenes", "create", "--collider", bad_flag, ok=False)
                check(r.returncode == 2 and needle in r.stderr and len(r.stderr.strip().splitlines()) == 1,
                      f"--collider {bad_flag}: rc {r.returncode}, stderr {r.stderr!r}")
            r = cli(args, server, "scenes", "create", "--collider", "plane:point=0,0,0:normal=0,0,0", ok=False)
            check(r.returncode == 1 and "spec.colliders[0].plane.normal" in r.stderr, f"zero normal: {r.stderr!r}")
            bad = os.path.join(d, "bad.json")
            with open(bad, "w") as f:
                json.dump({"mesh": {"builtin": "beam1"}, "solver": {"iteratons": 4}}, f)
            r = cli(args, server, "scenes", "create", "--spec", bad, ok=False)
            check(r.returncode == 2 and "iteratons" in r.stderr and len(r.stderr.strip().splitlines()) == 1,
                  f"misspelt field: rc {r.returncode}, stderr {r.stderr!r}")
            with open(bad, "w") as f:
                json.dump({"mesh": {"builtin": "beam1"}, "colliders": [{"sphere": {"radius": -2}}]}, f)
            r = cli(args, server, "scenes", "create", "--spec", bad, ok=False)
            check(r.returncode == 1 and "spec.colliders[0].sphere.radius" in r.stderr and "-2" in r.stderr,
                  f"bad radius: rc {r.returncode}, stderr {r.stderr!r}")
        finally:
            server.stop()


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("mode", choices=["sim", "record", "record-bodies", "examples"])
    p.add_argument("--sim")
    p.add_argument("--mesh-tool", help="pliant-mesh: also read VTK's zlib-compressed .vtu (sim mode)")
    p.add_argument("--server")
    p.add_argument("--cli")
    p.add_argument("--examples")
    args = p.parse_args()
    {"sim": mode_sim, "record": mode_record, "record-bodies": mode_record_bodies,
     "examples": mode_examples}[args.mode](args)


if __name__ == "__main__":
    main()
