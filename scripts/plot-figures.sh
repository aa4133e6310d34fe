#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# Draws the convergence figures of docs/solver.md (docs/img/*.png) from the data that
# scripts/thesis-figures.sh wrote to docs/data/ (gnuplot; no solver run):
#   bash scripts/plot-figures.sh
# Every curve has its own colour, dash pattern and marker; axes are logarithmic where the data
# spans decades, so curves that nearly coincide stay distinguishable.
set -euo pipefail
cd "$(dirname "$0")/.."
D=docs/data
if ! command -v gnuplot >/dev/null; then
  echo "[figures] gnuplot not found: no plots" >&2
  exit 0
fi
gnuplot <<GP
set datafile separator ","
set terminal pngcairo size 1000,600 font ",11"
set termoption noenhanced
set logscale xy
set key outside right spacing 1.3 width 2
set grid xtics ytics mxtics mytics lw 0.5 lc rgb "#dddddd"
set format y "%g"
set ytics (0.5, 0.6, 0.7, 0.8, 0.9, 1, 1.2, 1.5, 2, 3, 4, 5, 6, 8)
methods = "xpbd sor lambda-sor chebyshev anderson anderson-sor extrapolation"
# Seven distinct colours (colour-blind safe where possible), dash types and point types.
colours = "#000000 #0072b2 #d55e00 #009e73 #cc79a7 #e69f00 #56b4e9"
# Markers at log-spaced iterations, staggered per curve so coinciding curves show each marker.
rnd(x) = floor(x + 0.5)
mark(n, i) = (n >= 1 && n == floor(2**(rnd(log(n)/log(2) - i/7.0) + i/7.0)))
set title "beam3, E = 1 MPa, nu = 0.4, h = 1/60: one step from a 10 mm bend (coloured Gauss-Seidel)"
set xlabel "iteration (log)"; set ylabel "relative residual ||r|| / ||r0|| (log)"
set xrange [1:700]
set yrange [0.5:8]
set output "docs/img/converge_beam3_residual.png"
plot for [i=1:7] "$D/converge_beam3_".word(methods,i).".csv" using (\$1 > 0 ? \$1 : 1/0):3 with lines lw 2 dt i lc rgb word(colours,i) notitle, \
     for [i=1:7] "$D/converge_beam3_".word(methods,i).".csv" using (mark(\$1, i) ? \$1 : 1/0):3 \
     with points pt i ps 1.3 lc rgb word(colours,i) notitle, \
     for [i=1:7] NaN with linespoints lw 2 dt i pt i ps 1.3 lc rgb word(colours,i) title word(methods,i)
set ylabel "true error ||x - x*|| / ||x0 - x*||, x*: Newton's solution of the step (log)"
set yrange [0.6:1.05]
set output "docs/img/converge_beam3_error.png"
plot for [i=1:7] "$D/converge_beam3_".word(methods,i).".csv" using (\$1 > 0 ? \$1 : 1/0):4 with lines lw 2 dt i lc rgb word(colours,i) notitle, \
     for [i=1:7] "$D/converge_beam3_".word(methods,i).".csv" using (mark(\$1, i) ? \$1 : 1/0):4 \
     with points pt i ps 1.3 lc rgb word(colours,i) notitle, \
     for [i=1:7] NaN with linespoints lw 2 dt i pt i ps 1.3 lc rgb word(colours,i) title word(methods,i)
set xlabel "solver time, ms, one thread (log)"; set ylabel "relative residual ||r|| / ||r0|| (log)"
set xrange [*:*]
set yrange [0.5:8]
set output "docs/img/converge_beam3_time.png"
plot for [i=1:7] "$D/converge_beam3_".word(methods,i).".csv" using (\$5 > 0 ? \$5 : 1/0):3 with lines lw 2 dt i lc rgb word(colours,i) notitle, \
     for [i=1:7] "$D/converge_beam3_".word(methods,i).".csv" using (mark(\$1, i) ? \$5 : 1/0):3 \
     with points pt i ps 1.3 lc rgb word(colours,i) notitle, \
     for [i=1:7] NaN with linespoints lw 2 dt i pt i ps 1.3 lc rgb word(colours,i) title word(methods,i)
# The thesis's sequential sweep beside the coloured one: residual and true error.
set key outside right font ",9"
set title "beam3, 1 MPa, h = 1/60: sweep order x tet numbering"
set xrange [1:700]
set yrange [0.45:1.4]
set xlabel "iteration (log)"; set ylabel "||r||/||r0|| (solid: xpbd, dashed: anderson-sor 2) / true error (dotted)"
set output "docs/img/sweep_order_beam3.png"
cfgs = "sequential_x-slabs sequential_mesh gauss-seidel_x-slabs gauss-seidel_mesh"
plot for [i=1:4] "$D/converge_beam3_".word(cfgs,i)."_xpbd.csv" using (\$1 > 0 ? \$1 : 1/0):3 with linespoints lw 2 pt i ps 1 pointinterval -50 lc rgb word(colours,i+1) title word(cfgs,i)." xpbd ||r||", \
     for [i=1:4] "$D/converge_beam3_".word(cfgs,i)."_anderson-sor.csv" using (\$1 > 0 ? \$1 : 1/0):3 with linespoints lw 2 dt 2 pt i+4 ps 1 pointinterval -50 lc rgb word(colours,i+1) title word(cfgs,i)." anderson-sor ||r||", \
     for [i=1:4] "$D/converge_beam3_".word(cfgs,i)."_anderson-sor.csv" using (\$1 > 0 ? \$1 : 1/0):4 with lines lw 3 dt 3 lc rgb word(colours,i+1) title word(cfgs,i)." anderson-sor error"
GP
echo "[figures] plots in docs/img/" >&2
