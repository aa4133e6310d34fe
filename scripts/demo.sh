#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# The README's main command: installs what is missing, builds pliant-server, pliant and
# pliant-web, starts the server in the background with a demo scene (a cantilever beam clamped
# at x = 0 sagging under gravity, realtime 60 Hz) and the viewer pliant-web, prints the URL to
# open in a browser, and shows the scene live with `pliant watch` in the foreground.
# Ctrl-C stops all; with --duration S it ends by itself.
#   bash scripts/demo.sh [--duration S] [--mesh beam1|beam2|beam3] [--rate HZ] [--port P]
#                        [--web-port P] [--method NAME] [--substeps N] [--iterations N] [--json]
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD_DIR=${BUILD_DIR:-build}
JOBS=${JOBS:-$(nproc)}
DURATION=""; MESH=beam1; RATE=60; PORT=${PLIANT_DEMO_PORT:-50051}; METHOD=auto; JSON=""
WEB_PORT=${PLIANT_DEMO_WEB_PORT:-8080}
# Method auto: the server measures its solvers on the beam and keeps the most accurate within
# half the tick (the choice shows in `pliant scenes get demo`). --substeps/--iterations pin a budget.
SUBSTEPS=""; ITERATIONS=
while [ $# -gt 0 ]; do
  case "$1" in
    --duration) DURATION=$2; shift 2 ;;
    --mesh) MESH=$2; shift 2 ;;
    --rate) RATE=$2; shift 2 ;;
    --port) PORT=$2; shift 2 ;;
    --web-port) WEB_PORT=$2; shift 2 ;;
    --method) METHOD=$2; shift 2 ;;
    --substeps) SUBSTEPS=$2; shift 2 ;;
    --iterations) ITERATIONS=$2; shift 2 ;;
    --json) JSON=--json; shift ;;
    -h|--help) sed -n "2,10p" "$0"; exit 0 ;;
    *) echo "demo: unknown argument '$1' (see --help)" >&2; exit 2 ;;
  esac
done

bash scripts/deps.sh
GEN=(); command -v ninja >/dev/null && GEN=(-G Ninja)
if [ ! -f "$BUILD_DIR/CMakeCache.txt" ]; then
  cmake -S . -B "$BUILD_DIR" "${GEN[@]}" -DCMAKE_BUILD_TYPE=Release >/dev/null
fi
cmake --build "$BUILD_DIR" -j "$JOBS" --target pliant-server pliant pliant-web

SERVER_BIN="$BUILD_DIR/server/pliant-server"
CLI=("$BUILD_DIR/client/pliant" --address "127.0.0.1:$PORT")
LOG="$BUILD_DIR/demo-server.log"
"$SERVER_BIN" --listen "127.0.0.1:$PORT" --log-level info >"$LOG" 2>&1 &
SERVER_PID=$!
WEB_PID=""
stop_server() {
  if [ -n "$WEB_PID" ] && kill -0 "$WEB_PID" 2>/dev/null; then
    kill -TERM "$WEB_PID" 2>/dev/null || true
    wait "$WEB_PID" 2>/dev/null || true
  fi
  if kill -0 "$SERVER_PID" 2>/dev/null; then
    kill -TERM "$SERVER_PID" 2>/dev/null || true
    wait "$SERVER_PID" 2>/dev/null || true
  fi
}
trap stop_server EXIT

for _ in $(seq 100); do
  "${CLI[@]}" health --timeout 1 >/dev/null 2>&1 && break
  if ! kill -0 "$SERVER_PID" 2>/dev/null; then
    echo "demo: pliant-server did not start; its log ($LOG):" >&2
    cat "$LOG" >&2
    exit 1
  fi
  sleep 0.1
done

BUDGET=()
[ -n "$SUBSTEPS" ] && BUDGET+=(--substeps "$SUBSTEPS")
[ -n "$ITERATIONS" ] && BUDGET+=(--iterations "$ITERATIONS")
"${CLI[@]}" scenes create demo --mesh "$MESH" --fix-x-below 0.001 --rate "$RATE" --method "$METHOD" "${BUDGET[@]}"
WEB_LOG="$BUILD_DIR/demo-web.log"
"$BUILD_DIR/client/pliant-web" --listen "127.0.0.1:$WEB_PORT" --address "127.0.0.1:$PORT" >"$WEB_LOG" 2>&1 &
WEB_PID=$!
for _ in $(seq 50); do
  grep -q "listening on" "$WEB_LOG" 2>/dev/null && break
  if ! kill -0 "$WEB_PID" 2>/dev/null; then
    echo "demo: pliant-web did not start; its log ($WEB_LOG):" >&2
    cat "$WEB_LOG" >&2
    exit 1
  fi
  sleep 0.1
done
echo "demo: pliant-server on 127.0.0.1:$PORT (log: $LOG); try in another shell:"
echo "        ${CLI[*]} scenes get demo"
echo "demo: the viewer (pliant-web, log: $WEB_LOG): open in a browser"
echo "        http://127.0.0.1:$WEB_PORT/?scene=demo"
echo "demo: watching scene 'demo' (Ctrl-C to stop)"
WATCH=(watch demo)
[ -n "$DURATION" ] && WATCH+=(--duration "$DURATION")
[ -n "$JSON" ] && WATCH+=(--json)
"${CLI[@]}" "${WATCH[@]}"
