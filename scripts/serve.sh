#!/usr/bin/env bash
# Create .venv at the repo root, install the service (no torch) and serve the shipped default
# model on http://127.0.0.1:8000 (docs at /docs). Extra arguments go to `planar-pose-serve`.
set -euo pipefail
cd "$(dirname "$0")/.."
[ -x .venv/bin/python ] || python3 -m venv .venv
# setuptools' note on every editable install (folders named like the package), not actionable
QUIET_EDITABLE='ignore:Editable installation'
.venv/bin/python -m pip install -q --upgrade pip
PYTHONWARNINGS=$QUIET_EDITABLE .venv/bin/python -m pip install -q -e .
exec .venv/bin/planar-pose-serve "$@"
