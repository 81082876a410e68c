#!/usr/bin/env python3
"""Real-time 1 kHz loop over DDS: plant and controller as separate processes.

Starts ``plant``, ``controller`` and ``demand`` (a slow sine, so the loop works) as real
processes through their installed executables (the run-plan and launcher of
``fuel_valve_demo``; node logs in a temporary run directory), lets them run, then stops them and reads
the plant's loop statistics from ``/diagnostics``:

* round trip plant -> controller -> plant: time from publishing a resolver sample to
  receiving the current command computed from it (median / p99 / max),
* missed control periods: plant ticks that found no new command since the previous sample,
* CPU: user + system seconds of each process per second of run time.

The last line printed is a JSON object with ``rtt_p99_ms`` and ``missed_fraction``.

    python benchmarks/ros_loop.py [--seconds 60] [--mode observer_ff]
"""
from __future__ import annotations

import argparse
import json
import os
import random
import sys
import time
from pathlib import Path

from fuel_valve_control.common.paramspec import ConfigError
from fuel_valve_control.tools.launcher import Launcher
from fuel_valve_control.tools.run_plan import REAL_TIME, plan_run
from fuel_valve_control.tools.scenarios import parse_scenario

#: the demand: a slow sine around 40 %, so the valve keeps moving
DEMAND = {"type": "sine", "offset": 40.0, "amplitude": 5.0, "frequency_hz": 0.5}


def cpu_seconds(pid: int) -> float:
    """user + system CPU seconds of a live process (from /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--demand-rate", type=float, default=200.0, help="demand publish rate, Hz")
    parser.add_argument("--mode", default=None, help="controller mode (default: controller.yaml)")
    args = parser.parse_args()
    # the DDS domain: ROS_DOMAIN_ID when set, else a random one (not the default 0 of other runs)
    env = dict(ROS_DOMAIN_ID=os.environ.get("ROS_DOMAIN_ID") or str(random.randint(100, 200)),
               PYTHONWARNINGS="ignore")
    try:
        scenario = parse_scenario({"name": "ros_loop_benchmark", "duration_s": 3600.0, "demand": DEMAND})
        plan = plan_run(scenario, REAL_TIME, mode=args.mode, demand_overrides={"publish_rate_hz": args.demand_rate})
    except ConfigError as exc:
        print(f"ros_loop: {exc}", file=sys.stderr)
        return 2
    launcher = Launcher(plan, "/fuel_valve_bench", env=env)
    launcher.start()
    procs = launcher.procs
    stats = {}
    try:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        os.environ["ROS_DOMAIN_ID"] = env["ROS_DOMAIN_ID"]
        rclpy.init()
        node = rclpy.create_node("ros_loop_benchmark")

        compute = []                     # controller: mean / max ms per period, per report

        def on_diag(msg):
            for st in msg.status:
                if not st.name.startswith("/fuel_valve_bench/"):
                    continue
                values = {kv.key: kv.value for kv in st.values}
                if st.name.endswith("plant: loop"):
                    stats.update(values)
                elif st.name.endswith("valve driver") and values.get("compute_mean_ms", "n/a") != "n/a":
                    compute.append((float(values["compute_mean_ms"]), float(values["compute_max_ms"]),
                                    int(values["samples_since_last_report"])))
        node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 10)
        # warm-up: wait until the loop runs, then measure over a fresh window
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline and float(stats.get("rtt_samples", 0) or 0) < 100:
            rclpy.spin_once(node, timeout_sec=0.1)
        if not stats:
            raise SystemExit("the loop never started: " + "; ".join(launcher.log_tail(n) for n in launcher.failed()))
        start_stats = dict(stats)
        cpu0 = {n: cpu_seconds(p.pid) for n, p in procs.items()}
        t0 = time.monotonic()
        while time.monotonic() - t0 < args.seconds:
            rclpy.spin_once(node, timeout_sec=0.1)
        wall = time.monotonic() - t0
        cpu = {n: (cpu_seconds(p.pid) - cpu0[n]) / wall for n, p in procs.items()}
        # one more diagnostics message so the statistics cover the whole window
        seen = stats.get("ticks")
        t1 = time.monotonic()
        while stats.get("ticks") == seen and time.monotonic() - t1 < 3.0:
            rclpy.spin_once(node, timeout_sec=0.1)
        node.destroy_node()
        rclpy.shutdown()
    finally:
        launcher.stop()
    ticks = int(stats["ticks"]) - int(start_stats["ticks"])
    missed = int(stats["missed"]) - int(start_stats["missed"])
    result = {
        "seconds": round(wall, 1),
        "ticks": ticks,
        "rate_hz": round(ticks / wall, 1),
        "missed_fraction": round(missed / ticks, 5) if ticks else None,
        # the plant's percentiles cover the whole run including the warm-up
        "rtt_median_ms": round(float(stats["rtt_median_ms"]), 3),
        "rtt_p99_ms": round(float(stats["rtt_p99_ms"]), 3),
        "rtt_max_ms": round(float(stats["rtt_max_ms"]), 3),
        "cpu_fraction": {k: round(v, 3) for k, v in cpu.items()},
        "controller_compute_mean_ms": round(sum(c[0] * c[2] for c in compute) / max(sum(c[2] for c in compute), 1), 4),
        "controller_compute_max_ms": round(max((c[1] for c in compute), default=0.0), 3),
    }
    print(f"1 kHz loop over DDS for {result['seconds']} s: {ticks} ticks ({result['rate_hz']} Hz), missed "
          f"{100 * (result['missed_fraction'] or 0):.3f} %, round trip median {result['rtt_median_ms']} ms, "
          f"p99 {result['rtt_p99_ms']} ms, max {result['rtt_max_ms']} ms; CPU {result['cpu_fraction']}; controller "
          f"compute per period mean {result['controller_compute_mean_ms']} ms, max {result['controller_compute_max_ms']} ms")
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
