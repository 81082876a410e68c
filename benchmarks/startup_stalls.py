#!/usr/bin/env python3
"""Real-time start-ups of plant + controller + demand: does the controller latch a resolver-timeout fault, how late
did the plant's ticks get, how long until the drive is enabled (docs/control_results.md section 107).

Each run starts the three nodes (the slow sine demand of ``ros_loop.py``) through the launcher, waits ``--seconds``
after the plant's "plant up", stops them and reads their logs: the controller's first "no resolver sample for N ms"
fault, the plant's tick lateness max (its loop statistics), its drive-watchdog trips, and launch -> plant up /
controller active / drive enabled (s; launch = the moment the plant's parameter file was written).
``--variant "LABEL [ENV=VALUE ...] [controller.KEY=VALUE ...]"`` (repeatable): the runs alternate between the
variants (interleaved, so a change of machine load hits all); upper-case names are environment variables of the
node processes, e.g. main's behaviour before section 107::

    python benchmarks/startup_stalls.py --runs 20 --seconds 6 --domain 61 \\
        --variant "main OPENBLAS_THREAD_TIMEOUT=28 controller.faults.arm_steady_s=0" --variant "default"

``--fifo off``: no SCHED_FIFO (``ros2 run``'s scheduling); default: the launcher's (plant and controller FIFO 10).
Per run one JSON line, then per variant a summary line.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from fuel_valve_control.common.paramspec import parse_overrides  # noqa: E402
from fuel_valve_control.core.params import CONTROLLER_SPEC  # noqa: E402
from fuel_valve_control.tools.launcher import Launcher, Scheduling  # noqa: E402
from fuel_valve_control.tools.run_plan import REAL_TIME, plan_run  # noqa: E402
from fuel_valve_control.tools.scenarios import parse_scenario  # noqa: E402

DEMAND = {"type": "sine", "offset": 40.0, "amplitude": 5.0, "frequency_hz": 0.5}


def parse_variant(text: str) -> tuple[str, dict, dict]:
    """``"LABEL [ENV=VALUE ...] [controller.KEY=VALUE ...]"`` -> (label, environment, controller parameters)."""
    label, *items = text.split()
    env = {k: v for k, v in (i.split("=", 1) for i in items if i.split("=", 1)[0].isupper())}
    sets = [i for i in items if not i.split("=", 1)[0].isupper()]
    controller = parse_overrides(sets, ("controller",)).get("controller", {}) if sets else {}
    # "=0" for a float parameter: a float (the node refuses an integer for a double parameter)
    defaults = CONTROLLER_SPEC.defaults()
    return label, env, {k: float(v) if isinstance(v, int) and isinstance(defaults[k], float) else v
                        for k, v in controller.items()}


def log_time(log: str, text: str) -> float | None:
    """Wall time (s) of the first rclpy log line containing ``text``."""
    m = re.search(r"\[(\d+\.\d+)\] \[[^\]]*\]: " + re.escape(text), log)
    return float(m.group(1)) if m else None


def one_run(variant, seconds: float, domain: int, fifo: bool, run_dir: Path) -> dict:
    label, env, controller = variant
    scenario = parse_scenario({"name": "startup_stalls", "duration_s": 3600.0, "demand": DEMAND})
    plan = plan_run(scenario, REAL_TIME, controller_overrides=controller)
    launcher = Launcher(plan, "/startup_stalls", run_dir=run_dir,
                        env=dict(env, ROS_DOMAIN_ID=str(domain), PYTHONWARNINGS="ignore"),
                        scheduling=Scheduling() if fifo else Scheduling.off())
    launcher.start()
    try:
        launcher.wait_for_log("plant", "plant up", 120.0)
        time.sleep(seconds)
    finally:
        launcher.stop()
    t0 = (run_dir / "plant.params.yaml").stat().st_mtime
    plant, ctl = launcher.log("plant"), launcher.log("controller")
    fault = re.search(r"no resolver sample for \d+ ms", ctl)
    stats = launcher.loop_statistics() or {}
    since = {name: None if t is None else round(t - t0, 3) for name, t in (
        ("plant_up", log_time(plant, "plant up")), ("controller_active", log_time(ctl, "controller active")),
        ("drive_enabled", log_time(ctl, "drive enabled")))}
    return {"variant": label, "fault": fault.group(0) if fault else None,
            "tick_late_max_ms": round(float(stats["tick_late_max_ms"]), 1) if "tick_late_max_ms" in stats else None,
            "plant_watchdog_trips": len(re.findall(r"drive watchdog: no current command", plant)),
            "since_launch_s": since, "load_average": round(os.getloadavg()[0], 2)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=10, help="start-ups in all (alternating the variants)")
    parser.add_argument("--seconds", type=float, default=6.0, help="run time after 'plant up', s")
    parser.add_argument("--domain", type=int, default=61, help="ROS_DOMAIN_ID of the nodes")
    parser.add_argument("--fifo", choices=("default", "off"), default="default", help="the launcher's SCHED_FIFO or none")
    parser.add_argument("--variant", action="append", default=[], metavar='"LABEL [ENV=VALUE ...] [controller.KEY=VALUE ...]"')
    parser.add_argument("--keep", type=Path, default=None, help="keep the run directories (logs) here")
    args = parser.parse_args()
    variants = [parse_variant(v) for v in args.variant] or [("default", {}, {})]
    base = args.keep or Path(tempfile.mkdtemp(prefix="startup_stalls_"))
    runs = []
    for i in range(args.runs):
        r = one_run(variants[i % len(variants)], args.seconds, args.domain, args.fifo == "default", base / f"run{i}")
        runs.append(r)
        print(json.dumps(r), flush=True)
    for label, _, _ in variants:
        rs = [r for r in runs if r["variant"] == label]
        enabled = sorted(r["since_launch_s"]["drive_enabled"] for r in rs if r["since_launch_s"]["drive_enabled"])
        print(f"{label}: faulted {sum(1 for r in rs if r['fault'])} of {len(rs)}; tick lateness max (ms) "
              f"{sorted(r['tick_late_max_ms'] for r in rs if r['tick_late_max_ms'] is not None)}; launch -> drive "
              f"enabled (s) {enabled} ({len(rs) - len(enabled)} not within the run); plant watchdog trips "
              f"{sum(r['plant_watchdog_trips'] for r in rs)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
