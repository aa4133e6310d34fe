#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# What the support inertia (Material::support_inertia, docs/solver.md "Support inertia") does
# to beam3 under the default 64 substeps x 1 iteration at 60 Hz, E 10 kPa - 10 MPa:
#  - at rest (pliant-sim static, damping 5/s) against the Newton equilibrium of the same mesh,
#    -> docs/data/support_inertia_static_beam3.jsonl
#  - let go from rest under gravity (pliant-sim run, default damping 0.5/s): when the tip first
#    turns back (tip_first_turn_s), against 1024 substeps without it,
#    -> docs/data/support_inertia_swing_beam3.jsonl
#   bash scripts/support-inertia.sh [BUILD_DIR]      (about 5 minutes on 2 cores)
set -euo pipefail
cd "$(dirname "$0")/.."
B=${1:-build}
SIM="$B/solver/pliant-sim"
D=docs/data
mkdir -p "$D"
say() { echo "[support-inertia] $*" >&2; }
frames=$(mktemp -d)
trap 'rm -rf "$frames"' EXIT
: > "$D/support_inertia_static_beam3.jsonl"
: > "$D/support_inertia_swing_beam3.jsonl"
for E in 1e4 1e5 1e6 1e7; do
  say "Newton reference beam3 E=$E"
  "$SIM" reference --mesh beam3 --young "$E" --steps 10 | tail -n 1 >> "$D/support_inertia_static_beam3.jsonl" || true
  for K in 0 0.1 0.3 1; do
    say "beam3 E=$E support inertia $K"
    "$SIM" static --mesh beam3 --young "$E" --support-inertia "$K" --substeps 64 --iterations 1 --dt 1/60 \
      --damping 5 --speed-tol 1e-3 --max-steps 600 | tail -n 1 >> "$D/support_inertia_static_beam3.jsonl" || true
    "$SIM" run --mesh beam3 --young "$E" --support-inertia "$K" --substeps 64 --iterations 1 --dt 1/60 \
      --steps 60 --every 1000 --out "$frames" | tail -n 1 >> "$D/support_inertia_swing_beam3.jsonl"
  done
  say "beam3 E=$E, 1024 substeps"
  "$SIM" run --mesh beam3 --young "$E" --substeps 1024 --iterations 1 --dt 1/60 \
    --steps 60 --every 1000 --out "$frames" | tail -n 1 >> "$D/support_inertia_swing_beam3.jsonl"
done
say "wrote $D/support_inertia_static_beam3.jsonl and $D/support_inertia_swing_beam3.jsonl"
