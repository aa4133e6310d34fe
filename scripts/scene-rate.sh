#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# Ticks per second a server keeps on one realtime 60 Hz scene: starts BUILD/server/pliant-server
# on a free local port (with a Prometheus endpoint), creates the scene with BUILD/client/pliant,
# lets it run WARMUP seconds, then measures SECONDS: ticks per second, the solver's mean wall time
# per tick and the late ticks over that window (from /metrics), plus the progress line of
# `pliant scenes get` at its end; then stops the server. Several build dirs are measured in turn,
# ROUNDS times (interleaved, so that a shared machine's load hits them alike).
#   bash scripts/scene-rate.sh [--seconds S] [--warmup S] [--rounds N] [--iterations I]
#                              [--scene armadillo|hippo|armadillo-hanging] [--server-threads T] [--linear L]
#                              BUILD_DIR...
# Scenes (E 1 MPa, gravity, 1 substep):
#   armadillo  the service's armadillo standing on its feet (y <= -0.040 fixed), the default
#              method (XPBD), I iterations (default 1)
#   hippo      the thesis hippo hanging from its first 10% of x (x <= -0.07159 fixed), I Newton
#              iterations per tick, 2 solver threads (server --threads 2 unless --server-threads)
#   armadillo-hanging  the thesis armadillo with the thesis's clamp (x <= -0.04936 fixed), as hippo
# --linear L: newton's linear solver (auto | direct | cg | cg-jacobi | cg-factor | cg-twolevel; default auto).
set -euo pipefail
seconds=20 warmup=5 rounds=1 iterations=1 scene=armadillo server_threads="" linear=""
while [ $# -gt 0 ]; do
  case "$1" in
    --seconds) seconds=$2; shift 2 ;;
    --warmup) warmup=$2; shift 2 ;;
    --rounds) rounds=$2; shift 2 ;;
    --iterations) iterations=$2; shift 2 ;;
    --scene) scene=$2; shift 2 ;;
    --server-threads) server_threads=$2; shift 2 ;;
    --linear) linear=$2; shift 2 ;;
    -*) echo "scene-rate.sh: unknown flag $1" >&2; exit 2 ;;
    *) break ;;
  esac
done
[ $# -gt 0 ] || { echo "usage: scene-rate.sh [--seconds S] [--warmup S] [--rounds N] [--iterations I] [--scene armadillo|hippo|armadillo-hanging] [--server-threads T] [--linear L] BUILD_DIR..." >&2; exit 2; }
case "$scene" in
  armadillo) create=(--mesh armadillo --rate 60 --fix-box -1,-1,-1,1,-0.040,1 --substeps 1 --iterations "$iterations")
             server_threads=${server_threads:-1} ;;
  hippo) create=(--mesh hippo --young 1e6 --rate 60 --fix-box -1,-1,-1,-0.07159,1,1 --method newton --substeps 1
                 --iterations "$iterations" --threads 2)
         server_threads=${server_threads:-2} ;;
  armadillo-hanging) create=(--mesh armadillo --young 1e6 --rate 60 --fix-box -1,-1,-1,-0.04936,1,1 --method newton
                             --substeps 1 --iterations "$iterations" --threads 2)
                     server_threads=${server_threads:-2} ;;
  *) echo "scene-rate.sh: --scene is armadillo, hippo or armadillo-hanging, not '$scene'" >&2; exit 2 ;;
esac
[ -z "$linear" ] || create+=(--newton-linear-solver "$linear")
meshes="$(cd "$(dirname "$0")/.." && pwd)/meshes"

free_port() { python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])'; }

# ticks_total, step_seconds_mean and late_ticks_total of the scene from a /metrics page.
metrics() {
  curl -s "http://127.0.0.1:$1/metrics" | awk '
    /^pliant_scene_ticks_total\{/ {t=$2} /^pliant_scene_step_seconds_mean\{/ {m=$2}
    /^pliant_scene_late_ticks_total\{/ {l=$2} END {print t+0, m+0, l+0}'
}

measure() {
  local build=$1 port mport data pid
  port=$(free_port)
  mport=$(free_port)
  data=$(mktemp -d)
  "$build/server/pliant-server" --listen "127.0.0.1:$port" --metrics-listen "127.0.0.1:$mport" --data-dir "$data" \
    --no-restore --threads "$server_threads" --model-path "$meshes" --log-level warn >"$data/server.log" 2>&1 &
  pid=$!
  local cli=("$build/client/pliant" --address "127.0.0.1:$port")
  for _ in $(seq 100); do "${cli[@]}" health >/dev/null 2>&1 && break; sleep 0.1; done
  "${cli[@]}" scenes create "$scene" "${create[@]}" >/dev/null
  sleep "$warmup"
  local a b
  a=$(metrics "$mport")
  sleep "$seconds"
  b=$(metrics "$mport")
  local line
  line=$("${cli[@]}" scenes get "$scene" | tr '\n' ' ' | sed 's/  */ /g; s/.*progress/progress/')
  kill "$pid"
  wait "$pid" 2>/dev/null || true
  rm -rf "$data"
  local window
  window=$(echo "$a $b $seconds" | awk '{dt = $4 - $1; printf "%.2f ticks/s, %.2f ms mean solver step, %d late ticks over the last %d s",
    dt / $7, (dt > 0 ? 1000 * ($5 * $4 - $2 * $1) / dt : 0), $6 - $3, $7}')
  echo "$(date -u +%H:%M:%S) load $(cut -d' ' -f1 /proc/loadavg) $build $scene: $window; $line"
}

for _ in $(seq "$rounds"); do
  for build in "$@"; do measure "$build"; done
done
