#!/usr/bin/env bash
# Set up (if needed) and run the whole test suite.  Extra arguments go to pytest.
# `bash scripts/test.sh -n 2`: two pytest-xdist workers, one running the DDS modules one after
# another (as this serial run does) while the other runs the offline modules beside it
# (test/conftest.py: work units).  Not the default yet: see README "Tests".
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/python -m pytest -q "$@" test
