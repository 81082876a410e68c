#!/usr/bin/env bash
# Set up (if needed) and run the whole test suite.  Extra arguments go to pytest.
# Two pytest-xdist workers: one runs the DDS modules one after another (as a serial run would)
# while the other runs the offline modules beside it (test/conftest.py: work units); `-n 0`
# after it runs everything in this one process.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/python -m pytest -q -n 2 "$@" test
