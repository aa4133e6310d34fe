#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# Builds the libFuzzer harnesses (fuzz/) with clang-14, ASan and UBSan in their own build
# directory and runs each for a bounded time on a copy of its seed corpus (fuzz/corpus/).
#   scripts/fuzz.sh [SECONDS]   seconds per harness (default 30)
#   scripts/fuzz.sh --seeds     rewrites fuzz/corpus/ from fuzz/make_seeds.cpp
# FUZZ_BUILD_DIR (default build-fuzz, where everything is instrumented for coverage; CI uses the
# ASan test build, build-asan from scripts/sanitize.sh, where the harnesses' code is), JOBS.
# Exit status: non-zero if a harness found a crash, a sanitizer report or a leak (the input is
# left in $FUZZ_BUILD_DIR/findings/<harness>/).
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD=${FUZZ_BUILD_DIR:-build-fuzz}
JOBS=${JOBS:-$(nproc)}
if ! command -v clang++-14 >/dev/null || [ ! -d /usr/lib/llvm-14/lib/clang/14.0.6/lib/linux ]; then
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO=sudo
  $SUDO apt-get install -y -qq --no-install-recommends clang-14 libclang-rt-14-dev >/dev/null
fi
SAN="-fsanitize=address,undefined -fno-sanitize-recover=undefined -fno-omit-frame-pointer"
GEN=(); command -v ninja >/dev/null && GEN=(-G Ninja)
if [ ! -f "$BUILD/CMakeCache.txt" ]; then
  cmake -S . -B "$BUILD" "${GEN[@]}" -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DCMAKE_CXX_COMPILER=clang++-14 \
    -DCMAKE_CXX_FLAGS="$SAN -fsanitize=fuzzer-no-link" \
    -DCMAKE_EXE_LINKER_FLAGS="$SAN" \
    -DPLIANT_BUILD_FUZZERS=ON -DPLIANT_BUILD_TESTS=OFF -DPLIANT_BUILD_BENCH=OFF -DPLIANT_BUILD_CLIENTS=OFF \
    >/dev/null
fi
HARNESSES=(fuzz_mesh_loaders fuzz_snapshot fuzz_requests)
if [ "${1:-}" = --seeds ]; then
  cmake --build "$BUILD" -j "$JOBS" --target fuzz_make_seeds
  rm -rf fuzz/corpus
  "$BUILD/fuzz/fuzz_make_seeds" fuzz/corpus
  echo "fuzz: seeds written to fuzz/corpus/"
  exit 0
fi
SECONDS_EACH=${1:-30}
cmake --build "$BUILD" -j "$JOBS" --target "${HARNESSES[@]}"
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1}
status=0
for h in "${HARNESSES[@]}"; do
  corpus="fuzz/corpus/${h#fuzz_}"
  work="$BUILD/corpus/${h#fuzz_}"
  findings="$BUILD/findings/${h#fuzz_}"
  mkdir -p "$work" "$findings"
  cp -n "$corpus"/* "$work"/ 2>/dev/null || true
  echo "fuzz: $h for ${SECONDS_EACH} s"
  if ! "$BUILD/fuzz/$h" "$work" -max_total_time="$SECONDS_EACH" -timeout=20 -rss_limit_mb=4096 \
        -max_len=65536 -artifact_prefix="$findings/" -print_final_stats=1 >"$BUILD/$h.log" 2>&1; then
    echo "fuzz: $h FAILED (see $BUILD/$h.log and $findings/)"
    tail -40 "$BUILD/$h.log"
    status=1
  else
    grep -E "^stat::number_of_executed_units|^#[0-9]+ *DONE" "$BUILD/$h.log" | tail -2
  fi
done
exit $status
