#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# Inexact Newton (method newton, newton_linear_solver cg) on the thesis hippo and armadillo at
# E = 1 MPa hanging from their first 10% of x, and beam3's first swing under Newton: the figures
# of docs/solver.md, "Inexact Newton". One JSON line per run (pliant-sim's last line, with the
# command in front) goes to docs/data/newton_cg.jsonl.
#   bash scripts/newton-cg-figures.sh [BUILD_DIR]
# Load-independent figures: the rest tip at a fixed number of Newton iterations per tick (CG to
# the forcing term) against Newton's static tip, and beam3's first turn at 1 / 2 / 3 Newton
# iterations per tick. Machine-dependent ones (THREADS=2 by default): the same at a realtime
# budget of half a 60 Hz tick, and the one-step error against ms of cg and direct.
# SKIP_ARMADILLO=1 leaves the armadillo out (its static reference alone takes minutes).
set -euo pipefail
cd "$(dirname "$0")/.."
B=${1:-build}
SIM="$B/solver/pliant-sim"
THREADS=${THREADS:-2}
OUT=docs/data/newton_cg.jsonl
mkdir -p docs/data
say() { echo "[newton-cg] $*" >&2; }
run() {  # pliant-sim args -> one JSON line on stdout
  say "$*"
  local line
  line=$("$SIM" "$@" 2>/dev/null | tail -n 1) || true  # exit 4: not at rest (in the JSON)
  echo "{\"command\":\"pliant-sim $*\",\"result\":${line:-null}}"
}
rest() {  # mesh clamp-x max-ticks extra... : at rest at 60 Hz, damping 0.5 (the server's default)
  local mesh=$1 fx=$2 ticks=$3
  shift 3
  run static --mesh "$mesh" --young 1e6 --fix-x-max "$fx" --method newton --substeps 1 --dt 1/60 \
    --damping 0.5 --speed-tol 1e-5 --max-steps "$ticks" --threads "$THREADS" "$@"
}
{
  run reference --mesh hippo --young 1e6 --fix-x-max -0.07159
  for it in 1 3 10; do rest hippo -0.07159 900 --newton-linear-solver cg --iterations "$it"; done
  rest hippo -0.07159 900 --newton-linear-solver cg-jacobi --iterations 1
  rest hippo -0.07159 900 --newton-linear-solver cg --iterations 100000 --time-budget-ms 8.333
  rest hippo -0.07159 900 --newton-linear-solver direct --iterations 100000 --time-budget-ms 8.333
  run accuracy --mesh hippo --young 1e6 --fix-x-max -0.07159 --dt 1/60 --start sag --budget-ms 2000 \
    --threads "$THREADS" --methods newton:1xN:linear=cg,newton:1xN:linear=direct,newton:1xN:linear=cg-jacobi
  if [ -z "${SKIP_ARMADILLO:-}" ]; then
    run reference --mesh armadillo --young 1e6 --fix-x-max -0.04936
    for it in 1 3; do rest armadillo -0.04936 400 --newton-linear-solver cg --iterations "$it" ; done
    rest armadillo -0.04936 400 --newton-linear-solver cg --iterations 100000 --time-budget-ms 8.333
  fi
  run accuracy --mesh beam3 --young 1e6 --dt 1/60 --start sag --budget-ms 100 --dynamic \
    --methods newton:1x1,newton:1x2,newton:1x3,newton:1x5,newton:1x1:linear=cg,newton:1x2:linear=cg
} > "$OUT"
say "wrote $OUT"
