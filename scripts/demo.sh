#!/usr/bin/env bash
# Set up (if needed) and run the main job: plant, controller and demand (start-up-to-core-idle
# profile at maximum differential pressure, 20 s, real time at 1 kHz) as separate ROS 2
# processes, recorded into a rosbag2 bag under runs/, with a live status line, a summary and
# the bag's report (metrics + plot) at the end.  Extra arguments go to fuel_valve_demo
# (e.g. --lockstep, --scenario hold, --controller pi).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
mkdir -p runs
exec .venv/bin/fuel_valve_demo --bag "runs/run_$(date +%Y%m%d_%H%M%S)" --run-dir "runs/logs_$(date +%Y%m%d_%H%M%S)" "$@"
