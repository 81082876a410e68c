#!/usr/bin/env python3
"""Real-time 1 kHz loop over DDS: plant and controller as separate processes.

Starts ``plant``, ``controller`` and ``demand`` (a slow sine, so the loop works) as real
processes through their installed executables, lets them run, then stops them and reads
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
import resource
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def executable(name: str) -> str:
    here = Path(sys.executable).parent / name
    return str(here) if here.exists() else (shutil.which(name) or name)


def cpu_seconds(pid: int) -> float:
    """user + system CPU seconds of a live process (from /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--demand-rate", type=float, default=200.0, help="demand publish rate, Hz")
    parser.add_argument("--mode", default=None, help="controller mode (default: controller.yaml)")
    parser.add_argument("--domain", type=int, default=None,
                        help="ROS_DOMAIN_ID for the run (default: $ROS_DOMAIN_ID, else a random one in 100-200)")
    args = parser.parse_args()
    domain = args.domain if args.domain is not None else int(os.environ.get("ROS_DOMAIN_ID") or random.randint(100, 200))
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), PYTHONWARNINGS="ignore")
    ns = ["-r", "__ns:=/fuel_valve_bench"]
    cfg = ROOT / "config"
    ctrl = [executable("controller"), "--ros-args", "--params-file", str(cfg / "controller.yaml"), *ns]
    if args.mode:
        ctrl += ["-p", f"mode:={args.mode}"]
    cmds = {
        "plant": [executable("plant"), "--ros-args", "--params-file", str(cfg / "plant.yaml"), *ns],
        "controller": ctrl,
        "demand": [executable("demand"), "--ros-args", "--params-file", str(cfg / "demand.yaml"), *ns,
                   "-p", "profile:=sine", "-p", f"publish_rate_hz:={args.demand_rate}", "-p", "offset:=40.0", "-p", "amplitude:=5.0", "-p", "frequency_hz:=0.5"],
    }
    procs = {name: subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
             for name, cmd in cmds.items()}
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
            raise SystemExit("the loop never started: " + "; ".join(p.stdout.read(2000) for p in procs.values()
                                                                    if p.poll() is not None))
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
        for p in procs.values():
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
        for p in procs.values():
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
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
