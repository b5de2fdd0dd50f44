#!/usr/bin/env bash
# Create .venv at the repo root, install everything (service, training, dev tools, client SDK)
# and run the whole test suite, one pytest-xdist worker per core (PYTEST_WORKERS=N for N, 0 for
# one process), a test file per worker at a time, the longest files first (tests/conftest.py).
# Extra arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
export PIP_NO_CACHE_DIR=1  # torch brings ~5 GB of CUDA libraries: no second copy in pip's cache
[ -x .venv/bin/python ] || python3 -m venv .venv
# setuptools' note on every editable install (folders named like the package), not actionable
QUIET_EDITABLE='ignore:Editable installation'
.venv/bin/python -m pip install -q --upgrade pip
PYTHONWARNINGS=$QUIET_EDITABLE .venv/bin/python -m pip install -q -e ".[train,dev]" -e clients/python
exec .venv/bin/python -m pytest -n "${PYTEST_WORKERS:-auto}" --dist loadfile "$@"
