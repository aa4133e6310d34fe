#!/usr/bin/env python3
# SPDX-License-Identifier: Apache-2.0
"""Convergence of the solver methods on one tick: the residual |r| after every iteration of the
tick's last substep, per method, as CSV and a plot.

    PYTHONPATH=build/python python3 examples/python/convergence_plot.py \\
        --address 127.0.0.1:50051 --out convergence/

For each method it creates a lockstep scene (beam1 clamped at x = 0, one substep of
--iterations iterations), steps --ticks ticks, and keeps the residual history of the last one.
Writes OUT/convergence.csv (method, iteration, residual, relative), OUT/convergence.gp (a gnuplot
script) and, when matplotlib or gnuplot is installed, OUT/convergence.png.
"""
from __future__ import annotations

import argparse
import csv
import os
import shutil
import subprocess
import sys

import pliant

METHODS = ["xpbd", "chebyshev", "anderson", "anderson-sor"]
# Methods the --omega factor applies to (the others ignore it).
OMEGA_METHODS = ("sor", "lambda-sor", "anderson-sor", "extrapolation")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--address", default=os.environ.get("PLIANT_ADDRESS", "localhost:50051"))
    ap.add_argument("--token", default=os.environ.get("PLIANT_TOKEN"))
    ap.add_argument("--mesh", default="beam1")
    ap.add_argument("--methods", default=",".join(METHODS), help=f"comma-separated (default {','.join(METHODS)})")
    ap.add_argument("--iterations", type=int, default=200, help="iterations of the one substep (default 200)")
    ap.add_argument("--ticks", type=int, default=10, help="ticks before the measured one (default 10)")
    ap.add_argument("--young", type=float, default=1e6)
    ap.add_argument("--omega", type=float, default=1.5,
                    help="over-relaxation of sor, lambda-sor, anderson-sor, extrapolation (default 1.5)")
    ap.add_argument("--out", default="convergence")
    ap.add_argument("--no-plot", action="store_true", help="CSV and gnuplot script only")
    args = ap.parse_args()
    methods = [m for m in args.methods.split(",") if m]
    if not methods:
        ap.error("--methods must name at least one method")
    os.makedirs(args.out, exist_ok=True)

    rows = []
    with pliant.Client(args.address, args.token) as c:
        c.wait_ready(10.0)
        for m in methods:
            sid = f"convergence-{m}"
            c.create_scene(sid, args.mesh, mode="lockstep", method=m, substeps=1,
                           iterations=args.iterations, tolerance=0.0, young_modulus=args.young,
                           omega=args.omega if m in OMEGA_METHODS else None,
                           fix_x_below=0.001)
            try:
                if args.ticks > 1:
                    c.step(sid, args.ticks - 1)
                with c.frames(sid, fields=["residuals", "solver_stats"]) as stream:
                    c.step(sid, 1)
                    frame = next(iter(stream))
            finally:
                c.delete_scene(sid)
            r = frame.residuals
            if r.size == 0:
                print(f"convergence_plot: method {m} reported no residuals", file=sys.stderr)
                return 1
            r0 = frame.message.solver.residual_initial or float(r[0])
            for i, v in enumerate(r, start=1):
                rows.append((m, i, float(v), float(v) / r0 if r0 > 0 else 0.0))
            print(f"{m:14s} {r.size:4d} iterations: |r| {r0:.3e} -> {float(r[-1]):.3e}")

    csv_path = os.path.join(args.out, "convergence.csv")
    with open(csv_path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["method", "iteration", "residual", "relative"])
        w.writerows(rows)
    png = os.path.join(args.out, "convergence.png")
    gp = os.path.join(args.out, "convergence.gp")
    with open(gp, "w") as f:
        f.write("set datafile separator ','\nset terminal pngcairo size 900,600\n")
        f.write(f"set output '{os.path.basename(png)}'\nset logscale y\n")
        f.write("set xlabel 'iteration'\nset ylabel '|r| / |r0|'\nset key top right\n")
        f.write(f"set title 'Residual over one tick ({args.mesh}, E = {args.young:g} Pa)'\n")
        plots = [f"'convergence.csv' using 2:(strcol(1) eq '{m}' ? $4 : 1/0) with lines title '{m}'"
                 for m in methods]
        f.write("plot " + ", \\\n     ".join(plots) + "\n")
    print(f"wrote {csv_path} and {gp}")
    if args.no_plot:
        return 0
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        plt = None
    if plt is not None:
        fig, ax = plt.subplots(figsize=(9, 6))
        for m in methods:
            xs = [r[1] for r in rows if r[0] == m]
            ys = [r[3] for r in rows if r[0] == m]
            ax.semilogy(xs, ys, label=m)
        ax.set_xlabel("iteration")
        ax.set_ylabel("|r| / |r0|")
        ax.legend()
        fig.savefig(png, dpi=100)
        print(f"wrote {png} (matplotlib)")
    elif shutil.which("gnuplot"):
        subprocess.run(["gnuplot", os.path.basename(gp)], cwd=args.out, check=True)
        print(f"wrote {png} (gnuplot)")
    else:
        print("no matplotlib or gnuplot: plot skipped (CSV and script written)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
