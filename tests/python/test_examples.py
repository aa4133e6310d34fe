# SPDX-License-Identifier: Apache-2.0
"""The examples in examples/python against a real pliant-server.

stream_to_vtu: 600 frames of a 60 Hz realtime scene, none skipped, written as .vtu files and a
.pvd that VTK's own reader (python3-vtk9) reads back, and that pliant.vtu.read_vtu checks strictly.
convergence_plot: CSV and gnuplot script with a residual history per method.
"""
from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import tempfile
import unittest

import numpy as np

from pliant import vtu
import servers

EXAMPLES = os.path.join(os.environ.get("PLIANT_SOURCE_DIR", ""), "examples", "python")

try:
    from vtkmodules.vtkCommonCore import vtkCommand
    from vtkmodules.vtkIOXML import vtkXMLUnstructuredGridReader
    from vtkmodules.util.numpy_support import vtk_to_numpy
except ImportError:  # python3-vtk9 missing: the strict reader alone checks the files
    vtkXMLUnstructuredGridReader = None


def vtk_read(path: str):
    """(points, tets, displacement) through VTK's reader; AssertionError on any reader error."""
    errors = []
    r = vtkXMLUnstructuredGridReader()
    r.AddObserver(vtkCommand.ErrorEvent, lambda obj, ev: errors.append(ev))
    r.GetExecutive().AddObserver(vtkCommand.ErrorEvent, lambda obj, ev: errors.append(ev))
    r.SetFileName(path)
    r.Update()
    if errors or r.GetErrorCode() != 0:
        raise AssertionError(f"VTK could not read {path}: {errors} (error code {r.GetErrorCode()})")
    g = r.GetOutput()
    cells = vtk_to_numpy(g.GetCells().GetConnectivityArray()).reshape(-1, 4)
    types = {g.GetCellType(i) for i in range(g.GetNumberOfCells())}
    if types and types != {vtu.VTK_TETRA}:
        raise AssertionError(f"{path}: cell types {types}, expected tetrahedra")
    disp = g.GetPointData().GetArray("displacement")
    return (vtk_to_numpy(g.GetPoints().GetData()), cells,
            vtk_to_numpy(disp) if disp is not None else None)


class StreamToVtuTest(unittest.TestCase):
    def test_600_frames_of_a_60_hz_scene_none_skipped(self) -> None:
        with servers.Server() as srv, tempfile.TemporaryDirectory(prefix="pliant-vtu-") as out:
            run = subprocess.run(
                [sys.executable, os.path.join(EXAMPLES, "stream_to_vtu.py"), "--address", srv.address,
                 "--create", "--scene", "vtu", "--rate", "60", "--frames", "600", "--out", out],
                capture_output=True, text=True, timeout=120)
            self.assertEqual(run.returncode, 0, run.stderr + run.stdout)
            summary = json.loads(run.stdout.strip().splitlines()[-1])
            self.assertEqual(summary["frames"], 600, summary)

            # Every file is there and reads back; the collection gives the simulation times.
            entries = vtu.read_pvd(summary["pvd"])
            self.assertEqual(len(entries), 600)
            times = np.array([t for t, _ in entries])
            ticks = np.array([int(f.rsplit("_", 1)[1].split(".")[0]) for _, f in entries])
            np.testing.assert_allclose(times, ticks / 60.0, rtol=1e-9)
            rest = None
            for i, (_, name) in enumerate(entries):
                points, tets, data = vtu.read_vtu(os.path.join(out, name))
                self.assertEqual(points.shape, (summary["vertices"], 3))
                self.assertEqual(tets.shape, (summary["tets"], 4))
                if rest is None:
                    rest = points - data["displacement"]
                np.testing.assert_allclose(points - data["displacement"], rest, atol=1e-6)
                if vtkXMLUnstructuredGridReader is not None and (i % 60 == 0 or i == 599):
                    vp, vt, vd = vtk_read(os.path.join(out, name))
                    np.testing.assert_array_equal(vp, points)
                    np.testing.assert_array_equal(vt, tets)
                    np.testing.assert_array_equal(vd, data["displacement"])
            # The beam sags: the last frame's lowest point is below the rest shape's.
            self.assertLess(points[:, 1].min(), rest[:, 1].min())

            # No frame skipped, ticks consecutive. A frame can only be lost when the server's
            # stream falls a whole tick behind; when that happened while the scene itself missed
            # its deadlines (the machine did not keep real time), say so instead of failing.
            lost = summary["skipped_frames"] + summary["tick_gaps"]
            if lost and summary["scene_late_ticks"]:
                self.skipTest(f"machine too loaded to keep 60 Hz: the scene ran "
                              f"{summary['scene_late_ticks']} late ticks and skipped "
                              f"{summary['scene_skipped_ticks']} deadlines; {summary['skipped_frames']} "
                              f"frames skipped: {summary}")
            self.assertEqual(summary["skipped_frames"], 0, summary)
            self.assertEqual(summary["tick_gaps"], 0, summary)
            self.assertEqual(summary["last_tick"] - summary["first_tick"], 599, summary)

    def test_ascii_and_binary_files_read_alike(self) -> None:
        pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], dtype=np.float32)
        tets = np.array([[0, 1, 2, 3], [1, 2, 3, 4]], dtype=np.int32)
        disp = (pts * 0.5).astype(np.float32)
        with tempfile.TemporaryDirectory() as d:
            for binary in (True, False):
                p = os.path.join(d, f"t{int(binary)}.vtu")
                vtu.write_vtu(p, pts, tets, {"displacement": disp}, binary=binary)
                rp, rt, rd = vtu.read_vtu(p)
                np.testing.assert_array_equal(rp, pts)
                np.testing.assert_array_equal(rt, tets)
                np.testing.assert_array_equal(rd["displacement"], disp)
                if vtkXMLUnstructuredGridReader is not None:
                    vp, vt, vd = vtk_read(p)
                    np.testing.assert_array_equal(vp, pts)
                    np.testing.assert_array_equal(vt, tets)
                    np.testing.assert_array_equal(vd, disp)
            # A file cut short is refused, naming the problem.
            bad = os.path.join(d, "bad.vtu")
            with open(os.path.join(d, "t1.vtu")) as f:
                text = f.read()
            with open(bad, "w") as f:
                f.write(text.replace('NumberOfCells="2"', 'NumberOfCells="3"'))
            with self.assertRaises(vtu.VtuFormatError) as e:
                vtu.read_vtu(bad)
            self.assertIn("offsets", str(e.exception))
        with self.assertRaises(ValueError):
            vtu.write_vtu(os.path.join(tempfile.gettempdir(), "never.vtu"), pts, tets + 10)


class ConvergencePlotTest(unittest.TestCase):
    def test_csv_per_method(self) -> None:
        with servers.Server() as srv, tempfile.TemporaryDirectory(prefix="pliant-conv-") as out:
            run = subprocess.run(
                [sys.executable, os.path.join(EXAMPLES, "convergence_plot.py"), "--address", srv.address,
                 "--methods", "xpbd,anderson", "--iterations", "40", "--ticks", "3", "--out", out],
                capture_output=True, text=True, timeout=120)
            self.assertEqual(run.returncode, 0, run.stderr + run.stdout)
            with open(os.path.join(out, "convergence.csv")) as f:
                rows = list(csv.DictReader(f))
            for m in ("xpbd", "anderson"):
                its = [int(r["iteration"]) for r in rows if r["method"] == m]
                self.assertEqual(its, list(range(1, 41)), m)
                res = [float(r["residual"]) for r in rows if r["method"] == m]
                self.assertTrue(all(np.isfinite(res)) and min(res) > 0, m)
            self.assertTrue(os.path.exists(os.path.join(out, "convergence.gp")))
            self.assertTrue(os.path.exists(os.path.join(out, "convergence.png")), run.stdout)


if __name__ == "__main__":
    unittest.main()
