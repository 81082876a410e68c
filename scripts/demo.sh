#!/usr/bin/env bash
# Set up (if needed) and run the main job.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
.venv/bin/fuel_valve_datasheet
.venv/bin/python benchmarks/plant_speed.py
