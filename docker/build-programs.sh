#!/bin/sh
# Build stage of docker/Dockerfile: a Release build (ninja, ccache) of the programs the image ships,
# staged under $OUT as they will lie in the image (/usr/local/bin, /usr/share/pliant/{meshes,web}).
#   build-programs.sh [OUT=/out]
# Env: PLIANT_REQUIRED  programs the image cannot do without (default "pliant-server pliant pliant-haptic pliant-web");
#      JOBS             parallel jobs (default: nproc).
# Only the targets pliant-server, pliant, pliant-haptic and pliant-web are built (no tests, benchmarks, tools);
# those the tree does not have yet are skipped, the required ones must exist.
set -eu
OUT=${1:-/out}
BUILD=/tmp/pliant-build     # not in the image layer: only $OUT is kept
REQUIRED=${PLIANT_REQUIRED-pliant-server pliant pliant-haptic pliant-web}

cmake -S . -B "$BUILD" -G Ninja -DCMAKE_BUILD_TYPE=Release \
  -DCMAKE_CXX_COMPILER_LAUNCHER=ccache \
  -DPLIANT_BUILD_TESTS=OFF -DPLIANT_BUILD_BENCH=OFF \
  -DPLIANT_MESH_DIR=/usr/share/pliant/meshes >/dev/null
targets=""
for t in pliant-server pliant pliant-haptic pliant-web; do
  if ninja -C "$BUILD" -t query "$t" >/dev/null 2>&1; then targets="$targets $t"; fi
done
echo "image: building${targets:- nothing}"
[ -z "$targets" ] || cmake --build "$BUILD" -j "${JOBS:-$(nproc)}" --target $targets

mkdir -p "$OUT/usr/local/bin" "$OUT/usr/share/pliant/meshes"
for exe in pliant-server pliant pliant-haptic pliant-web; do
  f=$(find "$BUILD" -type f -name "$exe" -perm -u+x | head -n 1)
  if [ -n "$f" ]; then
    install -m 0755 -s "$f" "$OUT/usr/local/bin/$exe"
    echo "image: $exe ($(du -k "$OUT/usr/local/bin/$exe" | cut -f1) KiB stripped)"
  else
    echo "image: $exe not in this tree, left out"
  fi
done
for exe in $REQUIRED; do
  [ -x "$OUT/usr/local/bin/$exe" ] || { echo "image: required program $exe was not built" >&2; exit 1; }
done
if [ -x "$OUT/usr/local/bin/pliant-web" ]; then
  mkdir -p "$OUT/usr/share/pliant/web"
  cp -a web/. "$OUT/usr/share/pliant/web/"
  echo "image: web/ (the viewer's page)"
fi
if [ -d meshes ]; then
  cp -a meshes/. "$OUT/usr/share/pliant/meshes/"
  echo "image: meshes/ ($(du -sk meshes | cut -f1) KiB)"
fi
ccache --show-stats 2>/dev/null | grep -E 'Hits|Misses' || true
rm -rf "$BUILD"
