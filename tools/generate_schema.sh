#!/usr/bin/env bash
# Regenerates plugin/schema/generatedSchema.usda and plugInfo.json from plugin/schema/schema.usda with usd-core's
# usdGenSchema (codeless: no C++). plugInfo.json's Root and ResourcePath (".") are edits usdGenSchema keeps.
set -euo pipefail
cd "$(dirname "$0")/.."
.venv/bin/python -m pxr.Usd.usdGenSchema plugin/schema/schema.usda plugin/schema "$@"
