#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# Builds the test programs with AddressSanitizer + UndefinedBehaviorSanitizer in their own
# build directory (SAN_BUILD_DIR, default build-asan) and runs them with ctest.
#   scripts/sanitize.sh                 every test
#   scripts/sanitize.sh -R Service      ctest arguments (a subset)
# SAN_TARGETS (default: the test programs) and JOBS. Any sanitizer report fails its test.
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD=${SAN_BUILD_DIR:-build-asan}
JOBS=${JOBS:-$(nproc)}
SAN="-fsanitize=address,undefined -fno-sanitize-recover=undefined -fno-omit-frame-pointer"
GEN=(); command -v ninja >/dev/null && GEN=(-G Ninja)
if [ ! -f "$BUILD/CMakeCache.txt" ]; then
  cmake -S . -B "$BUILD" "${GEN[@]}" -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DCMAKE_CXX_FLAGS="$SAN" -DCMAKE_EXE_LINKER_FLAGS="$SAN" -DPLIANT_BUILD_BENCH=OFF >/dev/null
fi
if [ -n "${SAN_TARGETS:-}" ]; then
  read -r -a targets <<<"$SAN_TARGETS"
  cmake --build "$BUILD" -j "$JOBS" --target "${targets[@]}"
else
  cmake --build "$BUILD" -j "$JOBS"
fi
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=1}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}
cd "$BUILD"
ctest --output-on-failure -j "$JOBS" --timeout 900 "$@"
