#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# Regenerates the solver figures in docs/solver.md and docs/figures.md from the built tools:
#   bash scripts/thesis-figures.sh [BUILD_DIR]
# Writes docs/data/*.csv|*.jsonl and docs/img/*.png (gnuplot). Takes a few minutes on 2 cores,
# plus about 10 for the sequential-sweep runs (armadillo included; SKIP_SEQUENTIAL=1 skips them)
# and 5 for the accuracy table (SKIP_ACCURACY=1); progress goes to stderr.
set -euo pipefail
cd "$(dirname "$0")/.."
B=${1:-build}
SIM="$B/solver/pliant-sim"
D=docs/data
mkdir -p "$D" docs/img
say() { echo "[figures] $*" >&2; }

# 1. Convergence on beam3 (thesis figures 3.5-3.9): E = 1 MPa, nu 0.4, rho 1000, h = 1/60.
: > "$D/converge_beam3.jsonl"
for m in xpbd sor lambda-sor chebyshev anderson anderson-sor extrapolation; do
  say "converge beam3 $m"
  "$SIM" converge --mesh beam3 --method "$m" --iterations 600 --young 1e6 --match xpbd \
    --csv "$D/converge_beam3_$m.csv" | tail -n 1 >> "$D/converge_beam3.jsonl" || true  # lambda-sor may diverge (exit 3)
done

# 2. Omega sweep: Anderson+SOR against plain extrapolation at the same omega (what the
#    Anderson part adds), and the textbook type-II form.
: > "$D/omega_sweep_beam3.jsonl"
for w in 1 1.5 2 5 10; do
  for m in anderson-sor extrapolation; do
    say "omega $w $m"
    "$SIM" converge --mesh beam3 --method "$m" --omega "$w" --iterations 600 --young 1e6 --match xpbd | tail -n 1 >> "$D/omega_sweep_beam3.jsonl" || true
  done
  "$SIM" converge --mesh beam3 --method anderson-sor --anderson-form type2 --omega "$w" --iterations 600 --young 1e6 --match xpbd | tail -n 1 >> "$D/omega_sweep_beam3.jsonl" || true
done

# 3. Stiffness sweep of the gain (E 1e5, 1e7) for anderson (omega 1) and anderson-sor (2).
: > "$D/young_sweep_beam3.jsonl"
for E in 1e5 1e7; do
  for m in anderson anderson-sor; do
    say "E $E $m"
    "$SIM" converge --mesh beam3 --method "$m" --iterations 600 --young "$E" --match xpbd | tail -n 1 >> "$D/young_sweep_beam3.jsonl" || true
  done
done

# 3b. The thesis's own setting: the sequential sweep (one tet at a time in mesh order, one
#     thread) beside the coloured one, over three numberings of beam3's tets (the builtin's
#     x-fastest order, cube slabs along the beam, sorted by centroid x), plain XPBD and
#     Anderson+SOR at omega 2.
#     SKIP_SEQUENTIAL=1 keeps the previous data.
if [ "${SKIP_SEQUENTIAL:-0}" != 1 ]; then
: > "$D/sweep_order_beam3.jsonl"
for order in mesh x-slabs x-sorted; do
  for sw in sequential gauss-seidel; do
    for m in xpbd anderson-sor; do
      say "sweep order beam3: $sw, tets $order, $m"
      "$SIM" converge --mesh beam3 --method "$m" --iterations 600 --young 1e6 --match xpbd --sweep "$sw" \
        --tet-order "$order" --csv "$D/converge_beam3_${sw}_${order}_$m.csv" | tail -n 1 >> "$D/sweep_order_beam3.jsonl" || true
    done
  done
done
# The omega sweep and the other meshes in both sweeps (thesis figures 3.5-3.9 and its omega
# figure in its own setting; the thesis models' own numbering).
: > "$D/omega_sweep_sequential_beam3.jsonl"
for w in 1 1.5 2 5 10; do
  for order in mesh x-slabs x-sorted; do
    say "omega $w sequential ($order)"
    "$SIM" converge --mesh beam3 --method anderson-sor --omega "$w" --iterations 600 --young 1e6 --match xpbd \
      --sweep sequential --tet-order "$order" | tail -n 1 >> "$D/omega_sweep_sequential_beam3.jsonl" || true
  done
done
: > "$D/sweep_meshes.jsonl"
for mesh in beam1 beam2 hippo armadillo; do
  for sw in sequential gauss-seidel; do
    say "sweeps on $mesh: $sw"
    "$SIM" converge --mesh "$mesh" --method anderson-sor --iterations 600 --young 1e6 --match xpbd --sweep "$sw" \
      | tail -n 1 >> "$D/sweep_meshes.jsonl" || true
  done
done
fi

# 3c. The figure of merit: true error of one step against wall-clock ms for real-time budgets
#     (XPBD substeps x iterations, Anderson+SOR, the other solver families; a family not in the
#     build is reported as refused) on beam3 at 1 MPa, with the dynamic measures.
if [ "${SKIP_ACCURACY:-0}" != 1 ]; then
say "accuracy beam3 1 MPa"
"$SIM" accuracy --mesh beam3 --young 1e6 --dt 1/60 --start bend --budget-ms 1000 --dynamic --substep-floor \
  --methods xpbd:64x1,xpbd:16x4,xpbd:4x16,xpbd:Nx1,xpbd:1xN,anderson-sor:1xN:omega=2,chebyshev:1xN,xpbd:1xN:sweep=sequential,anderson-sor:1xN:omega=2:sweep=sequential,newton:1xN,vbd:1xN \
  --csv-dir "$D/accuracy_beam3" --png docs/img/accuracy_beam3.png | tail -n 1 > "$D/accuracy_beam3.json" || true
fi

# 4. Static equilibrium of beam3 against the Newton reference (same mesh, same model).
#    The slow part (minutes); SKIP_STATIC=1 keeps the previous data.
if [ "${SKIP_STATIC:-0}" != 1 ]; then
: > "$D/static_beam3.jsonl"
for E in 1e7 1e5; do
  say "static beam3 E=$E (XPBD)"
  "$SIM" static --mesh beam3 --young "$E" --threads 2 | tail -n 1 >> "$D/static_beam3.jsonl" || true
  say "static beam3 E=$E (Newton reference)"
  "$SIM" reference --mesh beam3 --young "$E" --steps 10 | tail -n 1 >> "$D/static_beam3.jsonl" || true
done
fi

# 5. What a real-time budget gives: beam3 brought to rest under gravity at a 60 Hz tick with
#    S substeps x 1 iteration, against the Newton equilibrium of the same mesh. SKIP_REALTIME=1
#    keeps the previous data (about 10 minutes).
if [ "${SKIP_REALTIME:-0}" != 1 ]; then
: > "$D/realtime_accuracy_beam3.jsonl"
for E in 1e4 1e5 1e6 1e7; do
  for S in 64 256 1024; do
    say "real-time budget beam3 E=$E ${S}x1"
    "$SIM" static --mesh beam3 --young "$E" --substeps "$S" --iterations 1 --dt 1/60 --damping 5 \
      --speed-tol 1e-3 --max-steps 600 | tail -n 1 >> "$D/realtime_accuracy_beam3.jsonl" || true
  done
  say "Newton reference beam3 E=$E"
  "$SIM" reference --mesh beam3 --young "$E" --steps 10 | tail -n 1 >> "$D/realtime_accuracy_beam3.jsonl" || true
done
# The same 256 sweeps per tick split into substeps x iterations, plain and accelerated (1 MPa).
echo "# beam3, E = 1 MPa: pliant-sim static --mesh beam3 --young 1e6 --substeps S --iterations N --method M --dt 1/60 --damping 5 --speed-tol 1e-3 --max-steps 600 (columns: S N M, then the JSON line). Newton: see realtime_accuracy_beam3.jsonl." > "$D/budget_split_beam3.txt"
for cfg in "256 1 xpbd" "64 4 xpbd" "32 8 xpbd" "32 8 anderson" "32 8 chebyshev" "16 16 xpbd" "16 16 anderson" "16 16 chebyshev"; do
  set -- $cfg
  say "budget split beam3 1 MPa: $1 x $2 $3"
  echo "$1 $2 $3 $("$SIM" static --mesh beam3 --young 1e6 --substeps "$1" --iterations "$2" --method "$3" --dt 1/60 \
    --damping 5 --speed-tol 1e-3 --max-steps 600 | tail -n 1)" >> "$D/budget_split_beam3.txt" || true
done
fi

# 6. Plots (docs/img), from the data above.
bash scripts/plot-figures.sh
