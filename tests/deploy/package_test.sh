#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# The CMake package, as a user gets it: `cmake --install` of this build tree into a scratch
# prefix, the prefix moved elsewhere (an install must not depend on where it was made), the
# consumer example (examples/consumer: find_package(Pliant), Pliant::client) configured and
# built against it, the installed pliant-server started on a free port, and the consumer run
# against it (create a scene, list, stream a frame). Also checks that the installed programs
# find the installed model set and page (share/pliant/{meshes,web}) relative to themselves.
#   package_test.sh BUILD_DIR SOURCE_DIR [CXX_COMPILER] [COMPILER_LAUNCHER] [CXX_FLAGS]
# CXX_FLAGS: the build's CMAKE_CXX_FLAGS, also used to compile and link the consumer (a
# sanitizer build's static libraries need the sanitizer runtime in the program that links them).
# Exit status 0 passed; anything else failed, with the step and the log that says why.
set -euo pipefail
BUILD=$(cd "$1" && pwd)
SRC=$(cd "$2" && pwd)
CXX=${3:-}
LAUNCHER=${4:-}
CXX_FLAGS=${5:-}
SCRATCH=$(mktemp -d "${TMPDIR:-/tmp}/pliant-package.XXXXXX")
SERVER_PID=""
cleanup() {
  if [ -n "$SERVER_PID" ]; then kill "$SERVER_PID" 2>/dev/null || true; wait "$SERVER_PID" 2>/dev/null || true; fi
  rm -rf "$SCRATCH"
}
trap cleanup EXIT
fail() { echo "package_test: FAIL: $*" >&2; exit 1; }
step() { echo "package_test: $*"; }

# 1. Install, then move the prefix.
step "cmake --install $BUILD --prefix $SCRATCH/staged"
cmake --install "$BUILD" --prefix "$SCRATCH/staged" >"$SCRATCH/install.log" 2>&1 \
  || { cat "$SCRATCH/install.log" >&2; fail "cmake --install failed (are all programs built? cmake --build $BUILD)"; }
mv "$SCRATCH/staged" "$SCRATCH/prefix"
PREFIX=$SCRATCH/prefix
for f in bin/pliant-server bin/pliant bin/pliant-mesh bin/pliant-sim lib/cmake/Pliant/PliantConfig.cmake \
         lib/cmake/Pliant/PliantConfigVersion.cmake include/pliant/client/client.hpp \
         include/pliant/v1/pliant.pb.h include/pliant/version.hpp share/pliant/meshes/SOURCES.md \
         share/pliant/proto/pliant/v1/pliant.proto share/doc/pliant/LICENSE; do
  [ -e "$PREFIX/$f" ] || fail "the install has no $f"
done
# lib may be lib64 or lib/<multiarch> elsewhere; GNUInstallDirs on Debian gives lib.
if grep -rq -- "$SRC\|$BUILD" "$PREFIX/lib/cmake/Pliant/"; then
  grep -rn -- "$SRC\|$BUILD" "$PREFIX/lib/cmake/Pliant/" >&2
  fail "the installed CMake package refers to the source or build tree"
fi

# 2. The installed tools find the installed model set (not the source tree's).
models=$("$PREFIX/bin/pliant-mesh" models 2>&1) || { echo "$models" >&2; fail "pliant-mesh models"; }
echo "$models" | grep -q "$PREFIX/share/pliant/meshes/liver/liver_sofa.msh" \
  || { echo "$models" >&2; fail "installed pliant-mesh does not find liver in $PREFIX/share/pliant/meshes"; }

# 3. The consumer, configured and built against the moved prefix.
GEN=(); command -v ninja >/dev/null && GEN=(-G Ninja)
CONF=(-DCMAKE_PREFIX_PATH="$PREFIX" -DCMAKE_BUILD_TYPE=Release)
[ -n "$CXX" ] && CONF+=(-DCMAKE_CXX_COMPILER="$CXX")
[ -n "$LAUNCHER" ] && CONF+=(-DCMAKE_CXX_COMPILER_LAUNCHER="$LAUNCHER")
[ -n "$CXX_FLAGS" ] && CONF+=(-DCMAKE_CXX_FLAGS="$CXX_FLAGS" -DCMAKE_EXE_LINKER_FLAGS="$CXX_FLAGS")
step "configure examples/consumer against $PREFIX"
cmake -S "$SRC/examples/consumer" -B "$SCRATCH/consumer" "${GEN[@]}" "${CONF[@]}" >"$SCRATCH/configure.log" 2>&1 \
  || { cat "$SCRATCH/configure.log" >&2; fail "configuring the consumer (find_package(Pliant)) failed"; }
step "build the consumer"
cmake --build "$SCRATCH/consumer" -j 2 >"$SCRATCH/build.log" 2>&1 \
  || { cat "$SCRATCH/build.log" >&2; fail "building the consumer against Pliant::client failed"; }

# 4. The installed server on a free port (port 0: the server logs the one it got).
step "start $PREFIX/bin/pliant-server"
env -u PLIANT_MODEL_PATH -u PLIANT_TOKEN "$PREFIX/bin/pliant-server" --listen 127.0.0.1:0 \
  --data-dir "$SCRATCH/data" >"$SCRATCH/server.log" 2>&1 &
SERVER_PID=$!
port=""
for _ in $(seq 1 300); do
  port=$(sed -n 's/.*listening on .*(port \([0-9]*\)).*/\1/p' "$SCRATCH/server.log" | head -n 1)
  [ -n "$port" ] && break
  kill -0 "$SERVER_PID" 2>/dev/null || { cat "$SCRATCH/server.log" >&2; fail "pliant-server exited"; }
  sleep 0.1
done
[ -n "$port" ] || { cat "$SCRATCH/server.log" >&2; fail "pliant-server did not log 'listening on ... (port N)' in 30 s"; }
grep -q "model path: $PREFIX/share/pliant/meshes" "$SCRATCH/server.log" \
  || { cat "$SCRATCH/server.log" >&2; fail "installed pliant-server's model path is not $PREFIX/share/pliant/meshes"; }

# 5. The consumer against it, and a scene from the installed model set through the installed CLI.
step "run the consumer against 127.0.0.1:$port"
out=$(env -u PLIANT_TOKEN "$SCRATCH/consumer/pliant-consumer" --address "127.0.0.1:$port" 2>&1) \
  || { echo "$out" >&2; cat "$SCRATCH/server.log" >&2; fail "pliant-consumer failed"; }
echo "$out"
echo "$out" | grep -q "^created consumer: 216 vertices" || fail "consumer: unexpected scene (want beam1, 216 vertices)"
echo "$out" | grep -q "^scenes:.* consumer" || fail "consumer: the scene is not in the list"
echo "$out" | grep -q "^frame: tick [1-9][0-9]*, .* 216 vertex positions" || fail "consumer: no frame of 216 positions"
pliant() { env -u PLIANT_TOKEN "$PREFIX/bin/pliant" --address "127.0.0.1:$port" "$@"; }
cli=$(pliant scenes create installed-liver --mesh liver --mode lockstep 2>&1 && pliant scenes get installed-liver 2>&1) \
  || { echo "$cli" >&2; fail "installed pliant CLI: a scene from the installed model set (liver) failed"; }
echo "$cli" | grep -q "liver: 181 vertices" || { echo "$cli" >&2; fail "the liver scene does not have 181 vertices"; }
step "passed"
