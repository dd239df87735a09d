#!/usr/bin/env bash
# Runs every test: the C++ tests (ctest) then the Python and image tests (pytest), with Vulkan validation on.
set -euo pipefail
cd "$(dirname "$0")/.."
tools/bootstrap.sh
export TESSERA_VALIDATION=1
ctest --test-dir build/py --output-on-failure --timeout 300
.venv/bin/python -m pytest -q testenv
