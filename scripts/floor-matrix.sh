#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# The robustness matrix's thesis-model cases (the Matrix test's set-up: 64 x 1, clamp at the first
# 10% of x, gravity, one thread) run with each build dir's pliant-sim, one line per case:
#   pliant-sim run --mesh M --young E --fix-x-max X --steps K --every 100000 --threads 1
# (hippo X -0.07159 K 20; armadillo X -0.04936 K 6). ms_per_step is wall time.
#   bash scripts/floor-matrix.sh BUILD_DIR...   (docs/data/floor_matrix.txt)
set -euo pipefail
[ $# -gt 0 ] || { echo "usage: floor-matrix.sh BUILD_DIR..." >&2; exit 2; }
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
for young in 1e4 1e5 1e6 1e7; do
  for case in "hippo -0.07159 20" "armadillo -0.04936 6"; do
    read -r mesh clamp steps <<<"$case"
    for build in "$@"; do
      json=$("$build/solver/pliant-sim" run --mesh "$mesh" --young "$young" --fix-x-max "$clamp" --steps "$steps" \
        --every 100000 --threads 1 --out "$out/frames" --quiet | tail -1)
      python3 -c '
import json, sys
d = json.loads(sys.argv[1])
keys = ("inverted_tets", "max_inverted_tets", "steps_with_inverted")
print(sys.argv[2], sys.argv[3], sys.argv[4] + ":", " ".join(f"{k} {d[k]}" for k in keys),
      "max_speed %.4g ms_per_step %.0f tip %s" % (d["max_speed"], d["ms_per_step"], d["tip_displacement"]))' "$json" "$build" "$mesh" "$young"
    done
  done
done
