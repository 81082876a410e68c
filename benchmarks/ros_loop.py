#!/usr/bin/env python3
"""Real-time 1 kHz loop over DDS: plant and controller as separate processes.

Starts ``plant``, ``controller`` and ``demand`` (a slow sine, so the loop works) as real
processes through their installed executables (the run-plan and launcher of
``fuel_valve_demo``), lets them run, then stops them and reads the plant's loop statistics
from ``/diagnostics``:

* round trip plant -> controller -> plant: time from publishing a resolver sample to
  receiving the current command computed from it (median / p99 / max),
* missed control periods: plant ticks that found no new command since the previous sample,
* CPU: user + system seconds of each process per second of run time.

With ``--record`` the ``recorder`` runs too (started first, stopped last, every suite topic,
MCAP, as in the main job): per topic, the messages the nodes published (each node prints
its counts at exit) against the messages in the bag's metadata, and the recorder's own
queue drops.

The last line printed is a JSON object with ``rtt_p99_ms``, ``missed_fraction`` and, with
``--record``, ``recorder_lost``.

    python benchmarks/ros_loop.py [--seconds 60] [--record] [--domain 107] [--mode observer_ff]
"""
from __future__ import annotations

import argparse
import json
import os
import random
import re
import shutil
import sys
import tempfile
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


def published_counts(log_text: str) -> dict[str, int]:
    """``{topic: n}`` from a node's exit line ``[name] published: {...}`` (relative names)."""
    found = re.findall(r"\] published: (\{.*\})", log_text)
    return json.loads(found[-1]) if found else {}


def recorder_report(bag: Path, launcher: Launcher, ns: str) -> dict:
    """Per loop topic: published (the nodes' exit counts) vs in the bag (metadata.yaml)."""
    import yaml
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    in_bag = {t["topic_metadata"]["name"]: t["message_count"] for t in meta["topics_with_message_count"]}
    published: dict[str, int] = {}
    for name in ("plant", "controller", "demand"):
        for topic, n in published_counts(launcher.log(name)).items():
            published[f"{ns}/{topic}"] = published.get(f"{ns}/{topic}", 0) + n
    topics = {t: {"published": n, "in_bag": in_bag.get(t, 0)} for t, n in sorted(published.items())}
    dropped = re.findall(r"closed: \d+ messages, (\d+) dropped", launcher.log("recorder"))
    return {"topics": topics, "lost": sum(max(0, v["published"] - v["in_bag"]) for v in topics.values()),
            "queue_dropped": int(dropped[-1]) if dropped else None, "bag_messages": meta["message_count"]}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--demand-rate", type=float, default=200.0, help="demand publish rate, Hz")
    parser.add_argument("--mode", default=None, help="controller mode (default: controller.yaml)")
    parser.add_argument("--record", action="store_true", help="run the recorder too (every suite topic, MCAP)")
    parser.add_argument("--domain", type=int, default=None,
                        help="ROS_DOMAIN_ID for the run (default: $ROS_DOMAIN_ID, else a random one in 100-200)")
    args = parser.parse_args()
    domain = args.domain if args.domain is not None else int(os.environ.get("ROS_DOMAIN_ID") or random.randint(100, 200))
    env = dict(ROS_DOMAIN_ID=str(domain), PYTHONWARNINGS="ignore")
    ns_name = "/fuel_valve_bench"
    tmp = Path(tempfile.mkdtemp(prefix="ros_loop_"))
    try:
        scenario = parse_scenario({"name": "ros_loop_benchmark", "duration_s": 3600.0, "demand": DEMAND})
        plan = plan_run(scenario, REAL_TIME, mode=args.mode, demand_overrides={"publish_rate_hz": args.demand_rate})
    except ConfigError as exc:
        print(f"ros_loop: {exc}", file=sys.stderr)
        return 2
    launcher = Launcher(plan, ns_name, run_dir=tmp, bag=tmp / "bag" if args.record else None, env=env)
    if args.record:       # first, so it is subscribed before the loop's first messages
        launcher.start_recorder()
        launcher.wait_for_log("recorder", "recording")
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
                if not st.name.startswith(f"{ns_name}/"):
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
        launcher.stop()            # the publishers first, the recorder last (it drains, then closes the bag)
    ticks = int(stats["ticks"]) - int(start_stats["ticks"])
    missed = int(stats["missed"]) - int(start_stats["missed"])
    result = {
        "seconds": round(wall, 1),
        "record": args.record,
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
        "exit_codes": {n: p.returncode for n, p in procs.items()},
    }
    print(f"1 kHz loop over DDS for {result['seconds']} s{' with the recorder' if args.record else ''}: {ticks} "
          f"ticks ({result['rate_hz']} Hz), missed {100 * (result['missed_fraction'] or 0):.3f} %, round trip median "
          f"{result['rtt_median_ms']} ms, p99 {result['rtt_p99_ms']} ms, max {result['rtt_max_ms']} ms; CPU "
          f"{result['cpu_fraction']}; controller compute per period mean {result['controller_compute_mean_ms']} ms, "
          f"max {result['controller_compute_max_ms']} ms; exit codes {result['exit_codes']}")
    if args.record:
        rec = recorder_report(launcher.bag, launcher, ns_name)
        result.update(recorder_lost=rec["lost"], recorder_queue_dropped=rec["queue_dropped"],
                      recorder_topics=rec["topics"], bag_messages=rec["bag_messages"])
        for topic, v in rec["topics"].items():
            print(f"  {topic:<36} published {v['published']:>7}  in bag {v['in_bag']:>7}")
        print(f"recorder: {rec['bag_messages']} messages in the bag, lost {rec['lost']} (published - in bag, "
              f"summed over the topics above), queue drops {rec['queue_dropped']}")
    shutil.rmtree(tmp, ignore_errors=True)
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
