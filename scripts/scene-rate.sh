#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# Ticks per second a server keeps on the service's armadillo scene (feet fixed, E 1 MPa, gravity,
# 1 substep x 1 iteration at 60 Hz, realtime): starts BUILD/server/pliant-server on a free local
# port, creates the scene with BUILD/client/pliant, waits SECONDS, prints the progress line of
# `pliant scenes get arm` (ticks, ticks/s, late ticks, rollbacks) and stops the server. Several
# build dirs are measured in turn, ROUNDS times (interleaved, so that a shared machine's load
# hits them alike).
#   bash scripts/scene-rate.sh [--seconds S] [--rounds N] [--iterations I] BUILD_DIR...
set -euo pipefail
seconds=20 rounds=1 iterations=1
while [ $# -gt 0 ]; do
  case "$1" in
    --seconds) seconds=$2; shift 2 ;;
    --rounds) rounds=$2; shift 2 ;;
    --iterations) iterations=$2; shift 2 ;;
    -*) echo "scene-rate.sh: unknown flag $1" >&2; exit 2 ;;
    *) break ;;
  esac
done
[ $# -gt 0 ] || { echo "usage: scene-rate.sh [--seconds S] [--rounds N] [--iterations I] BUILD_DIR..." >&2; exit 2; }
meshes="$(cd "$(dirname "$0")/.." && pwd)/meshes"

free_port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])'; }

measure() {
  local build=$1 port data pid
  port=$(free_port)
  data=$(mktemp -d)
  "$build/server/pliant-server" --listen "127.0.0.1:$port" --data-dir "$data" --no-restore \
    --model-path "$meshes" --log-level warn >"$data/server.log" 2>&1 &
  pid=$!
  local cli=("$build/client/pliant" --address "127.0.0.1:$port")
  for _ in $(seq 100); do "${cli[@]}" health >/dev/null 2>&1 && break; sleep 0.1; done
  "${cli[@]}" scenes create arm --mesh armadillo --rate 60 --fix-box -1,-1,-1,1,-0.040,1 \
    --substeps 1 --iterations "$iterations" >/dev/null
  sleep "$seconds"
  local line
  line=$("${cli[@]}" scenes get arm | tr '\n' ' ' | sed 's/  */ /g; s/.*progress/progress/')
  kill "$pid"
  wait "$pid" 2>/dev/null || true
  rm -rf "$data"
  echo "$(date -u +%H:%M:%S) load $(cut -d' ' -f1 /proc/loadavg) $build: $line"
}

for _ in $(seq "$rounds"); do
  for build in "$@"; do measure "$build"; done
done
