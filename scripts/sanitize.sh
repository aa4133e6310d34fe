#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# Builds the tests with a sanitizer (clang-14) in their own build directory and runs them with
# ctest. SANITIZER picks which:
#   address (default)  AddressSanitizer + UndefinedBehaviorSanitizer, in build-asan
#   thread             ThreadSanitizer, in build-tsan
#   scripts/sanitize.sh                                   every test under ASan + UBSan
#   scripts/sanitize.sh -L 'unit|physics'                 ctest arguments (a subset)
#   SANITIZER=thread SAN_TARGETS=pliant_service_tests scripts/sanitize.sh -L service
#                                                         the service tests under TSan
#   SAN_LABELS='unit|service' scripts/sanitize.sh         builds only those labels' test
#                                                         executables and runs `ctest -L` them
# SAN_BUILD_DIR (default by sanitizer), SAN_TARGETS (default: everything but the benchmarks),
# SAN_TIMEOUT_SCALE (every test's timeout is multiplied by it; default 4 for address, 6 for
# thread), JOBS. CMAKE_CXX_COMPILER_LAUNCHER (e.g. ccache) is honoured by the configure step.
# Any sanitizer report fails its test. Under TSan the system's gRPC, protobuf and absl are not
# instrumented: races inside them go unseen, and scripts/tsan.supp names the reports that
# their uninstrumented synchronisation causes in our code's view.
set -euo pipefail
cd "$(dirname "$0")/.."
SANITIZER=${SANITIZER:-address}
case "$SANITIZER" in
  address)
    BUILD=${SAN_BUILD_DIR:-build-asan}
    SAN="-fsanitize=address,undefined -fno-sanitize-recover=undefined -fno-omit-frame-pointer"
    # -O1 and line tables only (stack traces keep file:line): the build is CI's largest piece.
    BUILD_TYPE=None
    EXTRA="-O1 -gline-tables-only"
    SCALE=${SAN_TIMEOUT_SCALE:-4}
    # The libFuzzer harnesses too, so that scripts/fuzz.sh can run them from this directory
    # (FUZZ_BUILD_DIR=build-asan) without a second sanitized build; fuzz/CMakeLists.txt
    # instruments the code they exercise for coverage.
    EXTRA_CMAKE=(-DPLIANT_BUILD_FUZZERS=ON)
    ;;
  thread)
    BUILD=${SAN_BUILD_DIR:-build-tsan}
    SAN="-fsanitize=thread -fno-omit-frame-pointer"
    # -O1 and line tables only: TSan needs no more, and it halves the build.
    BUILD_TYPE=None
    EXTRA="-O1 -g1"
    SCALE=${SAN_TIMEOUT_SCALE:-6}
    EXTRA_CMAKE=()
    ;;
  *)
    echo "sanitize.sh: SANITIZER must be address or thread, got '$SANITIZER'" >&2
    exit 2
    ;;
esac
JOBS=${JOBS:-$(nproc)}
if ! command -v clang++-14 >/dev/null || [ ! -d /usr/lib/llvm-14/lib/clang/14.0.6/lib/linux ]; then
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO=sudo
  $SUDO apt-get install -y -qq --no-install-recommends clang-14 libclang-rt-14-dev >/dev/null
fi
GEN=(); command -v ninja >/dev/null && GEN=(-G Ninja)
if [ ! -f "$BUILD/CMakeCache.txt" ]; then
  cmake -S . -B "$BUILD" "${GEN[@]}" -DCMAKE_BUILD_TYPE="$BUILD_TYPE" -DCMAKE_CXX_COMPILER=clang++-14 \
    -DCMAKE_CXX_FLAGS="$SAN $EXTRA" -DCMAKE_EXE_LINKER_FLAGS="$SAN" -DCMAKE_SHARED_LINKER_FLAGS="$SAN" \
    -DPLIANT_BUILD_BENCH=OFF "${EXTRA_CMAKE[@]}" >/dev/null
fi
# SAN_LABELS (a ctest -L pattern of labels joined by |): the other labels' test executables
# are not compiled (PLIANT_TEST_BUILD_LABELS), and ctest runs these labels only. Unset: all
# (the cache entry dropped, so that its default, every label, comes back).
LABELS_OPTION=(-UPLIANT_TEST_BUILD_LABELS)
LABEL_ARGS=()
if [ -n "${SAN_LABELS:-}" ]; then
  if ! [[ "$SAN_LABELS" =~ ^[a-z]+(\|[a-z]+)*$ ]]; then
    echo "sanitize.sh: SAN_LABELS must be labels joined by |, got '$SAN_LABELS'" >&2
    exit 2
  fi
  LABELS_OPTION=(-DPLIANT_TEST_BUILD_LABELS="${SAN_LABELS//|/;}")
  LABEL_ARGS=(-L "^(${SAN_LABELS})\$")
fi
cmake "$BUILD" -DPLIANT_TEST_TIMEOUT_SCALE="$SCALE" "${LABELS_OPTION[@]}" >/dev/null
if [ -n "${SAN_TARGETS:-}" ]; then
  read -r -a targets <<<"$SAN_TARGETS"
  cmake --build "$BUILD" -j "$JOBS" --target "${targets[@]}"
else
  cmake --build "$BUILD" -j "$JOBS"
fi
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=1}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}
export TSAN_OPTIONS=${TSAN_OPTIONS:-halt_on_error=1:second_deadlock_stack=1:suppressions=$PWD/scripts/tsan.supp}
cd "$BUILD"
ctest --output-on-failure -j "$JOBS" "${LABEL_ARGS[@]}" "$@"
