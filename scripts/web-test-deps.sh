#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# Installs what the viewer's browser test needs (tests/web/browser.mjs): Debian's chromium and
# node, and the npm package playwright-core pinned in tests/web/package-lock.json (npm ci).
# Skips each step that is already done. scripts/deps.sh runs it (not with --no-dev).
set -euo pipefail
cd "$(dirname "$0")/.."
SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO=sudo
need=()
[ -x /usr/bin/chromium ] || need+=(chromium)
command -v node >/dev/null || need+=(nodejs)
command -v npm >/dev/null || need+=(npm)
if [ ${#need[@]} -gt 0 ]; then
  echo "web-test-deps: installing ${need[*]}"
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
fi
lock=tests/web/package-lock.json
stamp=tests/web/node_modules/.package-lock.json
if [ -f "$stamp" ] && [ -d tests/web/node_modules/playwright-core ] && [ "$stamp" -nt "$lock" ]; then
  echo "web-test-deps: playwright-core present"
else
  echo "web-test-deps: npm ci (playwright-core; no browser download: the test uses /usr/bin/chromium)"
  PLAYWRIGHT_SKIP_BROWSER_DOWNLOAD=1 npm ci --prefix tests/web --no-audit --no-fund --ignore-scripts >/dev/null
fi
