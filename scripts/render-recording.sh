#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# Regenerates docs/img/recording_armadillo.png: `pliant-sim run` records the armadillo clamped at
# its low-x end sagging under gravity (binary .vtu frames + frames.pvd), and VTK renders the last
# frame offscreen (scripts/render_recording.py; xvfb-run supplies an X server when there is no
# display). Needs a build (scripts/build.sh) and python3-vtk9, xvfb (scripts/deps.sh).
#   scripts/render-recording.sh [BUILD_DIR] [extra pliant-sim run flags...]
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD=${1:-build}; shift || true
OUT=$(mktemp -d)
trap 'rm -rf "$OUT"' EXIT
STEPS=${STEPS:-30}
"$BUILD/solver/pliant-sim" run --mesh armadillo --young 1e6 --support-inertia 1 --steps "$STEPS" --every "$STEPS" --out "$OUT/rec" "$@" | tail -1
RUN=(/usr/bin/python3 scripts/render_recording.py "$OUT/rec/frames.pvd" docs/img/recording_armadillo.png
     --title "armadillo, E = 1 MPa, support inertia 1, t = $(awk "BEGIN{printf \"%.2f\", $STEPS/60}") s: |displacement| (pliant-sim run -> frames.pvd)")
if [ -n "${DISPLAY:-}" ]; then "${RUN[@]}"; else xvfb-run -a -s "-screen 0 1400x1000x24" "${RUN[@]}"; fi
