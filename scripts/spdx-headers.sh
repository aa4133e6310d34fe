#!/usr/bin/env bash
# Puts `SPDX-License-Identifier: Apache-2.0` at the top of Pliant's own source files (C++,
# .proto, shell, Python, JavaScript, CMake), after a #! line if there is one, in the file's
# comment syntax. Idempotent: a file that already has an SPDX line is left alone.
#   scripts/spdx-headers.sh           add the line where it is missing (tracked files only)
#   scripts/spdx-headers.sh --check   list files without it; exit 1 if there are any
# Not touched: meshes/ (each model keeps its own licence, meshes/SOURCES.md), generated and
# third-party files (proto/grpc/: gRPC's health API; fuzz/corpus/, test data, lock files).
set -euo pipefail
cd "$(dirname "$0")/.."
check=0
[ "${1:-}" = --check ] && check=1
tag="SPDX-License-Identifier: Apache-2.0"
missing=0
while IFS= read -r f; do
  case "$f" in
    meshes/*|proto/grpc/*|fuzz/corpus/*|*/node_modules/*|*/golden/*|*/data/*) continue ;;
  esac
  case "$f" in
    *.sh|*.py|*.cmake|*.cmake.in|*CMakeLists.txt) line="# $tag" ;;
    *.cpp|*.hpp|*.hpp.in|*.proto|*.js|*.mjs) line="// $tag" ;;
    *) continue ;;
  esac
  head -n 3 "$f" | grep -q "SPDX-License-Identifier" && continue
  missing=$((missing + 1))
  if [ $check = 1 ]; then echo "$f"; continue; fi
  if head -n 1 "$f" | grep -q '^#!'; then
    { head -n 1 "$f"; echo "$line"; tail -n +2 "$f"; } >"$f.spdx"
  else
    { echo "$line"; cat "$f"; } >"$f.spdx"
  fi
  chmod --reference="$f" "$f.spdx"
  mv "$f.spdx" "$f"
done < <(git ls-files)
if [ $check = 1 ]; then
  [ $missing = 0 ] && echo "spdx-headers: every source file has its SPDX line" || echo "spdx-headers: $missing files without it"
  [ $missing = 0 ]
else
  echo "spdx-headers: added to $missing files"
fi
