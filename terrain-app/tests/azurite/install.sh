#!/usr/bin/env bash
# Installs Azurite (the Azure Storage emulator, version pinned by package-lock.json) into the
# git-ignored node_modules beside this script, for the az:// store test of
# terrain-app/tests/remote_store.rs (which starts `azurite-blob` on 127.0.0.1).
set -euo pipefail
cd "$(dirname "$0")"
npm ci --no-audit --no-fund --loglevel=error
