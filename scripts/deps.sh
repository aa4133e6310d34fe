#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# Installs the Debian 12 packages Pliant needs to build, test and run (root, or sudo).
# Skips apt entirely when everything is already there.
#   deps.sh            everything: build, tests, benchmarks, tools
#   deps.sh --no-dev   only what a Release build of the programs needs (the container's build stage)
set -euo pipefail
PKGS=(build-essential cmake ninja-build pkg-config
      libeigen3-dev libspdlog-dev libfmt-dev
      libgrpc++-dev libprotobuf-dev protobuf-compiler protobuf-compiler-grpc
      libassimp-dev libgtest-dev libgmock-dev libbenchmark-dev
      tetgen gnuplot-nox python3-yaml
      python3-grpcio python3-protobuf python3-numpy python3-vtk9 xvfb xauth
      libcivetweb-dev nlohmann-json3-dev libcli11-dev libjs-three chromium zlib1g-dev
      calculix-ccx)
# Needed only by tests, benchmarks and tools, not to build the programs; left out by --no-dev.
# The Python client (python/, docs/python.md) runs on python3-grpcio/-protobuf/-numpy; its stubs
# need only protobuf-compiler-grpc. python3-vtk9: VTK's own reader checks the recordings and the
# Python examples' files; xvfb, xauth: the offscreen render of a recording for the docs
# (scripts/render-recording.sh). calculix-ccx: the independent FEM code the static shapes are
# checked against (tests/solver/test_calculix.cpp).
DEV_ONLY=(libgtest-dev libgmock-dev libbenchmark-dev tetgen gnuplot-nox python3-yaml chromium
          python3-grpcio python3-protobuf python3-numpy python3-vtk9 xvfb xauth calculix-ccx)
if [ "${1:-}" = --no-dev ]; then
  keep=()
  for p in "${PKGS[@]}"; do [[ " ${DEV_ONLY[*]} " == *" $p "* ]] || keep+=("$p"); done
  PKGS=("${keep[@]}")
fi
missing=()
for p in "${PKGS[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  echo "deps: all ${#PKGS[@]} packages present"
else
  echo "deps: installing ${missing[*]}"
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO=sudo
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
  echo "deps: done"
fi
# The viewer's browser test: node and the npm package playwright-core (pinned).
[ "${1:-}" = --no-dev ] || bash "$(dirname "$0")/web-test-deps.sh"
