#!/bin/sh
# SPDX-License-Identifier: Apache-2.0
# Build stage of docker/Dockerfile: a Release build (ninja, ccache) of the programs the image ships,
# installed with `cmake --install` (component runtime, stripped) under $OUT as they will lie in the
# image: /usr/local/bin, /usr/local/share/pliant/{meshes,web}, /usr/local/share/doc/pliant.
#   build-programs.sh [OUT=/out]
# Env: PLIANT_REQUIRED  programs the image cannot do without (default "pliant-server pliant pliant-haptic pliant-web");
#      PLIANT_ARCH      -march of the image's programs (default x86-64-v2: runs on any x86-64 CPU
#                       since 2009; docs/deploy.md gives the speed it costs); ignored off x86-64;
#      JOBS             parallel jobs (default: nproc).
# Only the programs are built (no tests, benchmarks); those the tree does not have yet are
# skipped, the required ones must exist.
set -eu
OUT=${1:-/out}
BUILD=/tmp/pliant-build     # not in the image layer: only $OUT is kept
REQUIRED=${PLIANT_REQUIRED-pliant-server pliant pliant-haptic pliant-web}
ARCH=${PLIANT_ARCH-x86-64-v2}
case "$(uname -m)" in
  x86_64|amd64) ;;
  *) [ -z "$ARCH" ] || echo "image: PLIANT_ARCH=$ARCH ignored on $(uname -m)"; ARCH="" ;;
esac
echo "image: -march=${ARCH:-<compiler default>}"

cmake -S . -B "$BUILD" -G Ninja -DCMAKE_BUILD_TYPE=Release \
  -DCMAKE_CXX_COMPILER_LAUNCHER=ccache -DCMAKE_INSTALL_PREFIX=/usr/local \
  -DPLIANT_ARCH="$ARCH" -DPLIANT_NATIVE=OFF \
  -DPLIANT_BUILD_TESTS=OFF -DPLIANT_BUILD_BENCH=OFF >/dev/null
targets=""
for t in pliant-server pliant pliant-haptic pliant-web pliant-mesh pliant-sim; do
  if ninja -C "$BUILD" -t query "$t" >/dev/null 2>&1; then targets="$targets $t"; fi
done
echo "image: building${targets:- nothing}"
[ -z "$targets" ] || cmake --build "$BUILD" -j "${JOBS:-$(nproc)}" --target $targets

# The runtime component: programs, the model set, the viewer's page, LICENSE and NOTICE (not the
# libraries, headers and CMake package: those are the development component).
DESTDIR="$OUT" cmake --install "$BUILD" --component runtime --strip >/dev/null
for exe in pliant-server pliant pliant-haptic pliant-web pliant-mesh pliant-sim; do
  f="$OUT/usr/local/bin/$exe"
  if [ -x "$f" ]; then echo "image: $exe ($(du -k "$f" | cut -f1) KiB stripped)"
  else echo "image: $exe not in this tree, left out"; fi
done
for exe in $REQUIRED; do
  [ -x "$OUT/usr/local/bin/$exe" ] || { echo "image: required program $exe was not built" >&2; exit 1; }
done
for d in meshes web; do
  [ ! -d "$OUT/usr/local/share/pliant/$d" ] || echo "image: share/pliant/$d ($(du -sk "$OUT/usr/local/share/pliant/$d" | cut -f1) KiB)"
done
ccache --show-stats 2>/dev/null | grep -E 'Hits|Misses' || true
rm -rf "$BUILD"
