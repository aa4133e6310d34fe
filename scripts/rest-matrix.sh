#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# The real-time robustness case brought to rest: the thesis hippo and armadillo hanging from their first 10%
# of x under gravity, 60 Hz ticks of the default 64 substeps x 1 iteration, E 10 kPa - 10 MPa,
# nu 0.4, damping 5/s so that they settle in seconds. One JSON line per run (pliant-sim
# static's last line, with the command in front) goes to docs/data/rest_matrix[_TAG].jsonl.
#   bash scripts/rest-matrix.sh [BUILD_DIR] [TAG -- extra pliant-sim flags]
# e.g. `bash scripts/rest-matrix.sh build plain -- --inertia-floor 0` for plain lumped masses.
# About 20 minutes on 2 cores (the two models run side by side); progress goes to stderr.
set -euo pipefail
cd "$(dirname "$0")/.."
B=${1:-build}
TAG=${2:-}
shift $(( $# > 2 ? 3 : $# ))
EXTRA=("$@")
SIM="$B/solver/pliant-sim"
OUT=docs/data/rest_matrix${TAG:+_$TAG}.jsonl
mkdir -p docs/data

run_model() {  # mesh clamp-x max-ticks -> one line per E on stdout
  local mesh=$1 fx=$2 ticks=$3
  for E in 1e4 1e5 1e6 1e7; do
    local cmd=(static --mesh "$mesh" --young "$E" --fix-x-max "$fx" --substeps 64 --iterations 1
               --dt 1/60 --damping 5 --speed-tol 1e-3 --max-steps "$ticks" "${EXTRA[@]}")
    echo "[rest-matrix] $mesh E $E ${EXTRA[*]}" >&2
    local line
    line=$("$SIM" "${cmd[@]}" 2>/dev/null | tail -n 1) || true  # exit 4: not at rest (reported in the JSON)
    # The line as JSON (python3's json: the command quoted whatever its characters; a last
    # line that is not JSON, e.g. after a crash, becomes result null with the text beside it).
    python3 -c 'import json, sys
cmd, line = sys.argv[1], sys.argv[2]
try:
    out = {"command": cmd, "result": json.loads(line) if line.strip() else None}
except ValueError:
    out = {"command": cmd, "result": None, "unparsed": line}
print(json.dumps(out, allow_nan=False))' "pliant-sim ${cmd[*]}" "$line"
  done
}

tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
run_model hippo -0.07159 600 > "$tmp/hippo" &
run_model armadillo -0.04936 400 > "$tmp/armadillo" &
wait
cat "$tmp/hippo" "$tmp/armadillo" > "$OUT"
echo "[rest-matrix] wrote $OUT" >&2
