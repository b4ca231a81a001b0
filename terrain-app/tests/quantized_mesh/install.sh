#!/usr/bin/env bash
# Installs the quantized-mesh checker's npm packages (@loaders.gl/terrain and core, versions
# pinned by package-lock.json) into the git-ignored node_modules beside this script.
set -euo pipefail
cd "$(dirname "$0")"
npm ci --no-audit --no-fund --loglevel=error
