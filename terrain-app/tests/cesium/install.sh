#!/usr/bin/env bash
# Installs the CesiumJS check's npm packages (cesium and playwright-core, versions pinned by
# package-lock.json) into the git-ignored node_modules beside this script. Chromium itself is
# Debian's (`apt-get install chromium`, /usr/bin/chromium): playwright-core never downloads one.
set -euo pipefail
cd "$(dirname "$0")"
npm ci --no-audit --no-fund --loglevel=error
