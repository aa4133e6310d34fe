#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# Pliant's position-based fluid beside SPlisHSPlasH's PBF on the same dam breaks, one program
# after the other on this machine (docs/fluids.md, "Beside SPlisHSPlasH"):
#   SPLISHSPLASH_SRC=/path/to/SPlisHSPlasH bash scripts/pbf-reference.sh [BUILD_DIR] [THREADS]
# SPLISHSPLASH_SRC is a checkout of github.com/InteractiveComputerGraphics/SPlisHSPlasH (measured
# at c5a063d). The script builds its SPHSimulator once (Release, its defaults: single precision,
# AVX, OpenMP) in BUILD_DIR/splishsplash, writes the scenes there, and runs both programs for 4 s
# of the 10,000- and 20,000-particle dam breaks of `pliant-sim fluid --scene dam-break`: the same
# block (17 x 34 x 17 or 22 x 44 x 22 particles 2 cm apart) in the corner of the same closed box,
# support 4 cm, gravity 9.81, XSPH 0.01, 1/60 s cut into 4 substeps of 4 iterations (SPlisHSPlasH:
# fixed steps of 1/240 s, CFL off, exactly 4 PBF iterations). SPlisHSPlasH's walls are volume maps
# (Bender et al. 2019) and, for the 10,000 particles, also boundary particles (Akinci et al. 2012);
# Pliant's are the analytic box. One line per run on stdout; a run of SPlisHSPlasH takes 0.5-1.5
# minutes on 2 cores.
set -euo pipefail
cd "$(dirname "$0")/.."
B=${1:-build}
THREADS=${2:-2}
SRC=${SPLISHSPLASH_SRC:?set SPLISHSPLASH_SRC to a checkout of SPlisHSPlasH}
SIM="$B/solver/pliant-sim"
W="$B/splishsplash"
say() { echo "[pbf-reference] $*" >&2; }
[[ -x "$SIM" ]] || { echo "no $SIM: build Pliant first (bash scripts/build.sh)" >&2; exit 1; }
mkdir -p "$W/scenes" "$W/out"
W=$(cd "$W" && pwd)
SRC=$(cd "$SRC" && pwd)

if [[ ! -x "$SRC/bin/SPHSimulator" ]]; then
  say "building SPlisHSPlasH's SPHSimulator in $W/build (about 15 minutes on 2 cores)"
  cmake -S "$SRC" -B "$W/build" -DCMAKE_BUILD_TYPE=Release -DUSE_PYTHON_BINDINGS=OFF >&2
  # Its external projects first: the simulator's rules do not wait for their libraries.
  cmake --build "$W/build" --target Ext_NeighborhoodSearch Ext_Discregrid Ext_GenericParameters Ext_PBD >&2
  cmake --build "$W/build" --target SPHSimulator >&2
fi

# scene NX BOUNDARY: the dam break of pliant-sim (block NX x 2NX x NX at spacing d from the
# origin, box 4NX d x 4NX d x NX d). SPlisHSPlasH fills a block's box inset by one radius, so
# its box reaches half a spacing past the outer particles on each side.
scene() {
  local nx=$1 bh=$2
  python3 - "$nx" "$bh" "$SRC/data/models/UnitBox.obj" <<'EOF'
import json, sys
nx, bh, box = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
d = 0.02
w, depth = 4 * nx * d, nx * d
print(json.dumps({
    "Configuration": {
        "particleRadius": d / 2, "numberOfStepsPerRenderUpdate": 1, "simulationMethod": 2,
        "gravitation": [0, -9.81, 0], "timeStepSize": 1 / 240, "cflMethod": 0, "stopAt": 4.0,
        "boundaryHandlingMethod": bh, "enableVTKExport": False, "enablePartioExport": False,
        "PBF": {"minIterations": 4, "maxIterations": 4, "maxError": 0.0, "velocityUpdateMethod": 0}},
    "Materials": [{"id": "Fluid", "density0": 1000, "viscosityMethod": 0, "vorticityMethod": 0,
                   "XSPH": {"xsph": 0.01, "xsphBoundary": 0.0}}],
    "RigidBodies": [{"geometryFile": box, "translation": [w / 2, w / 2, depth / 2],
                     "rotationAxis": [1, 0, 0], "rotationAngle": 0, "scale": [w, w, depth],
                     "isDynamic": False, "isWall": True, "mapInvert": True, "mapThickness": 0.0,
                     "mapResolution": [40, 40, 12]}],
    "FluidBlocks": [{"denseMode": 0, "start": [-d / 2, -d / 2, -d / 2],
                     "end": [nx * d + d / 2, 2 * nx * d + d / 2, nx * d + d / 2],
                     "translation": [0, 0, 0], "scale": [1, 1, 1]}]}, indent=1))
EOF
}

echo "# $(date -u +%F) $(nproc) cores, $THREADS threads, load $(cut -d' ' -f1-3 /proc/loadavg)"
for run in "10000 17 2" "10000 17 0" "20000 22 2"; do
  read -r n nx bh <<< "$run"
  name="dam${nx}_b${bh}"
  scene "$nx" "$bh" > "$W/scenes/$name.json"
  say "SPlisHSPlasH PBF, $n particles, boundary method $bh"
  OMP_NUM_THREADS=$THREADS "$SRC/bin/SPHSimulator" --no-gui --output-dir "$W/out" "$W/scenes/$name.json" \
    > "$W/out/$name.log" 2>&1
  particles=$(sed -n 's/^Number of fluid particles: //p' "$W/out/$name.log" | tail -n 1)
  step_ms=$(sed -n 's/^Average time: SimStep: \([0-9.e+-]*\) ms/\1/p' "$W/out/$name.log")
  search_ms=$(sed -n 's/^Average time: neighborhood_search: \([0-9.e+-]*\) ms/\1/p' "$W/out/$name.log")
  python3 -c "
import json, sys
n, step, search, bh = int(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4])
print(json.dumps({'program': 'SPlisHSPlasH PBF', 'boundary': ['Akinci 2012 particles', '', 'Bender 2019 volume maps'][bh],
                  'particles': n, 'ms_per_substep_mean': step, 'neighbour_search_ms_per_substep': search,
                  'ms_per_60hz_step': 4 * step, 'ns_per_particle_iteration': step * 1e6 / (n * 4)}))
" "$particles" "$step_ms" "$search_ms" "$bh"
  if [[ $bh == 2 ]]; then
    say "Pliant, $n particles"
    "$SIM" fluid --scene dam-break --particles "$n" --substeps 4 --iterations 4 --threads "$THREADS" --seconds 4 --quiet | tail -n 1
  fi
done
