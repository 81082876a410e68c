#!/usr/bin/env python3
"""Soak: the whole suite (plant, controller, demand, recorder as processes) for N minutes.

The valve follows a slow sine (40 ± 20 % at 0.1 Hz) the whole time, in real time (default)
or in lockstep (``--lockstep``), optionally with ``--cpu-hog K`` busy-loop processes beside it
(the CI box is loaded).  Measured:

* RSS (``/proc/<pid>/status`` VmRSS) of every process every ``--sample-s`` seconds: the
  first sample after a 30 s warm-up and the last, the largest, and the growth from the first minute's mean to the last
  minute's mean;
* faults: the controller's drive disablements (``drive DISABLED`` in its log, with the fault
  names), the plant's drive-watchdog trips (its last ``/diagnostics`` in the bag);
* valve against demand, from the bag: the excess of the true valve position (the plant's
  ``joint_states``) over the largest demand of the trailing ``EXCESS_WINDOW_S`` (a valve still
  on its way down after a falling demand is lag, not overshoot), counted only while the drive
  is enabled (``drive_enable`` true): a latched fault with the drive off is excluded;
* bag counts against published counts: each node prints its published counts per topic at
  exit, the bag's metadata.yaml has what was recorded (``lost`` = published − in bag).

The last line printed is one JSON object.

With ``--reset-faults`` an operator (:class:`Operator`) resets latched faults, so a fault at
start-up (a loaded machine latches the 20 ms resolver timeout while the processes warm up)
does not leave the rest of the soak with the drive off.

    python benchmarks/soak.py --minutes 10 [--lockstep] [--cpu-hog 1] [--reset-faults] [--domain 120]
"""
from __future__ import annotations

import argparse
import json
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from fuel_valve_control.common.contract import DRIVE_STATE_ENABLED, STROKE_RAD, VALVE_JOINT  # noqa: E402
from fuel_valve_control.tools.launcher import Launcher, add_scheduling_arguments, scheduling_from_args  # noqa: E402
from fuel_valve_control.tools.run_plan import LOCKSTEP, REAL_TIME, plan_run  # noqa: E402
from fuel_valve_control.tools.scenarios import parse_scenario  # noqa: E402

DEMAND = {"type": "sine", "offset": 40.0, "amplitude": 20.0, "frequency_hz": 0.1}
#: the valve is compared with the largest demand of this trailing window, s (the stroke time
#: is about 0.12 s; a falling demand is followed with some lag)
EXCESS_WINDOW_S = 0.5
NODES = ("plant", "controller", "demand", "recorder")
HOG = "while True: pass"
#: RSS "start" is the first sample after this long (or a quarter of the run), s
WARM_UP_S = 30.0


def rss_mb(pid: int) -> float | None:
    """Resident set size of a live process, MB (None once it has gone)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def trailing_extreme(stamps_ns: np.ndarray, values: np.ndarray, t_ns: np.ndarray, window_ns: int,
                     extreme=np.maximum) -> np.ndarray:
    """The largest (``extreme`` np.maximum) or smallest (np.minimum) of ``values`` (sorted by
    ``stamps_ns``) over the trailing window ``t - window_ns .. t`` of every ``t_ns`` (at least
    the latest value before ``t``; NaN before the first): a sparse table, O(n log n) (the soak
    has ~10^5-10^6 samples)."""
    hi = np.searchsorted(stamps_ns, t_ns, side="right")
    lo = np.searchsorted(stamps_ns, t_ns - window_ns, side="left")
    lo = np.minimum(lo, np.maximum(hi - 1, 0))          # at least the latest value before t
    valid = hi > 0
    levels = [values]
    while (1 << len(levels)) <= len(values):
        prev, step = levels[-1], 1 << (len(levels) - 1)
        levels.append(extreme(prev[:-step], prev[step:]))
    k = np.floor(np.log2(np.maximum(hi - lo, 1))).astype(int)
    out = np.full(len(t_ns), np.nan)
    for level in np.unique(k[valid]):
        sel = valid & (k == level)
        out[sel] = extreme(levels[level][lo[sel]], levels[level][hi[sel] - (1 << level)])
    return out


def valve_excess(bag_dir: Path, until_ns: int | None = None) -> dict:
    """Largest valve-over-demand excess (percent of stroke) while the controller enabled the
    drive (``drive_enable`` true), and while the drive was really on (its ``drive_status``
    enabled too: not off by its command watchdog, where the spring closes the valve, or
    friction at high Δp holds it where it stopped, so the valve lags a falling demand).

    Also the other side, reported only: the valve's largest shortfall under the *smallest*
    demand of the trailing window (a valve still on its way up after a rising demand is lag),
    over every sample (``shortfall_max_pct``) and while the drive was enabled, from the valve's
    first arrival within 2 % of the demand on (before it: the start-up move).

    ``until_ns`` (wall-clock ns, the bag's receive time): samples after it are not judged --
    the soak's end, when the launcher stops the nodes, demand node first (the controller then
    latches "no valid demand" and the spring closes the valve: teardown, not the soak).  A drive the
    controller keeps off -- its re-arm after a watchdog trip waiting for the valve, a latched
    fault -- lets the spring close the valve: invisible to the excess, which counts enabled
    samples only, and for a fuel valve a flow dip as real as an excess (the soak's trips once
    closed the valve every time, 59 % under a 60 % demand)."""
    from fuel_valve_control.tools.bag_io import read_bag
    bag = read_bag(bag_dir, ["joint_states", "demand", "drive_enable", "drive_status"])
    js, dem, en = bag.find("joint_states"), bag.find("demand"), bag.find("drive_enable")
    status = bag.find("drive_status")
    if js is None or dem is None or len(dem) == 0:
        return {"excess_max_pct": None, "samples": 0}
    keep = slice(None) if until_ns is None else slice(0, int(np.searchsorted(js.log_ns, until_ns, side="right")))
    t = js.log_ns[keep]
    valve = 100.0 * js[f"{VALVE_JOINT}.position"][keep] / STROKE_RAD
    dt, dv = dem.log_ns, dem["data"]
    order = np.argsort(dt, kind="stable")
    dt, dv = dt[order], dv[order]
    window = int(EXCESS_WINDOW_S * 1e9)
    dmax = trailing_extreme(dt, dv, t, window, np.maximum)
    dmin = trailing_extreme(dt, dv, t, window, np.minimum)
    valid = np.isfinite(dmax) & np.isfinite(valve)
    enabled = np.zeros(len(t), dtype=bool)
    if en is not None and len(en):
        idx = np.searchsorted(en.log_ns, t, side="right") - 1
        enabled = (idx >= 0) & (en["data"][np.maximum(idx, 0)] > 0.5)
    mask = valid & enabled
    excess = valve[mask] - dmax[mask]
    # the shortfall from the valve's first arrival at the demand on (before: the start-up move)
    arrived = np.flatnonzero(valid & (np.abs(valve - dmax) <= 2.0))
    after = np.arange(len(t)) >= (arrived[0] if arrived.size else len(t))
    short_all = (dmin - valve)[valid & after]
    short_en = (dmin - valve)[mask & after]
    out = {"excess_max_pct": round(float(excess.max()), 3) if excess.size else None,
           "samples": int(mask.sum()), "samples_drive_off": int((valid & ~enabled).sum()),
           "excess_over_2pct_samples": int((excess > 2.0).sum()),
           "shortfall_max_pct": round(float(short_all.max()), 3) if short_all.size else None,
           "shortfall_over_2pct_samples": int((short_all > 2.0).sum()),
           "shortfall_enabled_max_pct": round(float(short_en.max()), 3) if short_en.size else None}
    if status is not None and len(status):
        idx = np.searchsorted(status.log_ns, t, side="right") - 1
        on = (idx >= 0) & (status["data"][np.maximum(idx, 0)] == DRIVE_STATE_ENABLED)
        sel = mask & on
        ex_on = valve[sel] - dmax[sel]
        out.update(drive_on_excess_max_pct=round(float(ex_on.max()), 3) if ex_on.size else None,
                   drive_on_samples=int(sel.sum()), drive_on_excess_over_2pct_samples=int((ex_on > 2.0).sum()),
                   watchdog_off_samples=int((mask & ~on).sum()))
    return out


class Operator:
    """``--reset-faults``: watches the controller's ``/diagnostics`` and, when it reports a
    latched fault, calls ``~/reset`` (at most once a second), as an operator would after a
    start-up transient; the faults and resets are counted, so the soak goes on measuring a
    running loop instead of a closed valve."""

    def __init__(self, ns: str, domain: int):
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from std_srvs.srv import Trigger
        os.environ["ROS_DOMAIN_ID"] = str(domain)
        self._rclpy, self._trigger = rclpy, Trigger
        rclpy.init()
        self.node = rclpy.create_node("soak_operator")
        self.client = self.node.create_client(Trigger, f"{ns}/controller/reset")
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 10)
        self.ns, self.faulted, self.resets, self.refused = ns, False, 0, 0
        self.faults: list[str] = []
        self._last_try = 0.0
        self._future = None

    def _on_diag(self, msg) -> None:
        for st in msg.status:
            if st.name.startswith(f"{self.ns}/controller") and st.name.endswith("valve driver"):
                was, self.faulted = self.faulted, st.level == bytes([2])
                if self.faulted and not was:
                    self.faults.append(st.message[:200])

    def spin(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self._rclpy.spin_once(self.node, timeout_sec=0.05)
            if self._future is not None and self._future.done():
                res = self._future.result()
                self.resets += bool(res and res.success)
                self.refused += not (res and res.success)
                self._future = None
            if self.faulted and self._future is None and time.monotonic() - self._last_try > 1.0 \
                    and self.client.service_is_ready():
                self._last_try = time.monotonic()
                self._future = self.client.call_async(self._trigger.Request())

    def close(self) -> None:
        self.node.destroy_node()
        self._rclpy.shutdown()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--lockstep", action="store_true", help="lockstep (simulated time) instead of real time")
    parser.add_argument("--cpu-hog", type=int, default=0, metavar="K", help="busy-loop processes beside the suite")
    parser.add_argument("--sample-s", type=float, default=10.0, help="RSS sampling period, s")
    parser.add_argument("--storage", default="mcap", choices=("mcap", "sqlite3"))
    parser.add_argument("--mode", default=None, help="controller mode (default: controller.yaml)")
    parser.add_argument("--domain", type=int, default=None,
                        help="ROS_DOMAIN_ID (default: $ROS_DOMAIN_ID, else a random one in 100-200)")
    parser.add_argument("--reset-faults", action="store_true",
                        help="call the controller's ~/reset when it reports a latched fault (counted)")
    parser.add_argument("--keep", action="store_true", help="keep the run directory (logs, bag)")
    add_scheduling_arguments(parser)        # the main job's defaults: the soak runs the product as shipped
    args = parser.parse_args()
    scheduling = scheduling_from_args(args)
    domain = args.domain if args.domain is not None else int(os.environ.get("ROS_DOMAIN_ID") or random.randint(100, 200))
    env = dict(ROS_DOMAIN_ID=str(domain), PYTHONWARNINGS="ignore")
    ns = "/fuel_valve_soak"
    seconds = 60.0 * args.minutes
    tmp = Path(tempfile.mkdtemp(prefix="soak_"))
    scenario = parse_scenario({"name": "soak", "duration_s": seconds, "demand": DEMAND})
    plan = plan_run(scenario, LOCKSTEP if args.lockstep else REAL_TIME, mode=args.mode)
    launcher = Launcher(plan, ns, run_dir=tmp, bag=tmp / "bag", bag_storage=args.storage, env=env,
                        observers=1 if args.lockstep else 0, scheduling=scheduling)
    operator = None
    hogs = [subprocess.Popen([sys.executable, "-c", HOG]) for _ in range(args.cpu_hog)]
    rss: dict[str, list] = {n: [] for n in NODES}
    times: list[float] = []
    try:
        launcher.start_recorder()
        launcher.wait_for_log("recorder", "recording")
        if args.lockstep:
            launcher.start(("controller", "demand", "plant"))
            for name, text in (("controller", "controller up"), ("demand", "demand up"), ("plant", "plant up")):
                launcher.wait_for_log(name, text, 60.0)
            time.sleep(1.0)
            launcher.start_gate()
        else:
            launcher.start()
        operator = Operator(ns, domain) if args.reset_faults else None
        t0 = time.monotonic()
        next_sample = t0
        while True:
            if operator is not None:
                operator.spin(0.2)
            now = time.monotonic()
            if now >= next_sample:
                times.append(now - t0)
                for name in NODES:
                    rss[name].append(rss_mb(launcher.procs[name].pid))
                next_sample += args.sample_s
            if args.lockstep:
                if "stop_after_s reached" in launcher.log("plant"):
                    break
            elif now - t0 >= seconds:
                break
            if launcher.failed():
                print(f"soak: processes exited early: {launcher.failed()}", file=sys.stderr)
                break
            time.sleep(min(1.0, args.sample_s))
        wall = time.monotonic() - t0
        end_ns = time.time_ns()             # the measured window ends here: then the teardown
        if operator is not None:
            operator.close()
        died = [n for n in launcher.failed() if n != "plant" or not args.lockstep]
    finally:
        codes = launcher.stop(grace_s=20.0)
        for h in hogs:
            h.send_signal(signal.SIGKILL)
            h.wait()
    rec = launcher.recording_losses()          # the one reader of the nodes' published counts
    excess = valve_excess(launcher.bag, end_ns)
    # drive disablements within the measured window (log lines are stamped with wall-clock s)
    disabled = [faults for stamp, faults in re.findall(r"\[(\d+\.\d+)\] \[[^]]*\]: drive DISABLED: state \w+(?:, faults: (.*?)(?:: clear the cause.*)?)?$",
                                                       launcher.log("controller"), re.M) if float(stamp) * 1e9 <= end_ns]
    from fuel_valve_control.tools.bag_io import read_bag
    diag = read_bag(launcher.bag, ["/diagnostics"]).diagnostics
    plant_diag = next((v for k, v in diag.items() if k.endswith("plant: loop") or "plant" in k), {})
    controller_diag = next((v for k, v in diag.items() if "controller" in k and "stall_rearms" in v), {})

    warm_up_s = min(WARM_UP_S, 0.25 * wall)

    def summary(series):
        # from the first sample after the warm-up (imports, DDS discovery, first chunks)
        vals = [v for t, v in zip(times, series) if v is not None and t >= warm_up_s]
        if not vals:
            return None
        per_min = max(int(round(60.0 / args.sample_s)), 1)
        first, last = vals[:per_min], vals[-per_min:]
        return {"start_mb": round(vals[0], 1), "end_mb": round(vals[-1], 1), "max_mb": round(max(vals), 1),
                "growth_first_to_last_minute_mb": round(float(np.mean(last) - np.mean(first)), 2)}
    result = {
        "minutes": args.minutes, "timing": "lockstep" if args.lockstep else "real_time", "cpu_hogs": args.cpu_hog,
        "wall_s": round(wall, 1), "died": died, "exit_codes": codes,
        "rss": {n: summary(v) for n, v in rss.items()},
        "rss_samples": {"t_s": [round(t, 1) for t in times], **{n: [None if v is None else round(v, 1) for v in s]
                                                                 for n, s in rss.items()}},
        "drive_disablements": len(disabled), "fault_messages": sorted(set(f for f in disabled if f))[:10],
        "plant_watchdog_trips": plant_diag.get("watchdog_trips"),
        "controller_rearms_after_drive_off": controller_diag.get("stall_rearms"),
        "operator_resets": None if operator is None else operator.resets,
        "operator_faults_seen": None if operator is None else operator.faults[:10],
        "valve_excess_max_pct": excess["excess_max_pct"], "valve_excess": excess,
        "bag_lost": rec["lost"], "bag_startup_lost": rec["startup_lost"], "bag_queue_dropped": rec["queue_dropped"], "bag_messages": rec["bag_messages"],
        "bag_topics": rec["topics"],
        "scheduling": scheduling.describe(), "scheduling_refused": list(launcher.scheduling_refused),
    }
    print(f"soak {args.minutes:g} min {result['timing']}, {args.cpu_hog} CPU hog(s): died {died}, drive "
          f"disablements {len(disabled)}, plant watchdog trips {result['plant_watchdog_trips']}, controller "
          f"re-arms after the drive went off {result['controller_rearms_after_drive_off']}")
    for name, s in result["rss"].items():
        print(f"  RSS {name:<10} {s}")
    print(f"  valve over demand (drive enabled): max {excess['excess_max_pct']} % over {excess['samples']} samples; "
          f"drive really on (drive_status): max {excess.get('drive_on_excess_max_pct')} % over "
          f"{excess.get('drive_on_samples')} samples")
    print(f"  valve under demand (reported only): max {excess.get('shortfall_max_pct')} % over all samples "
          f"({excess.get('shortfall_over_2pct_samples')} > 2 %), {excess.get('shortfall_enabled_max_pct')} % "
          f"with the drive enabled")
    for topic, v in rec["topics"].items():
        print(f"  {topic:<40} published {v['published']:>8}  in bag {v['in_bag']:>8}")
    print(f"  bag: {rec['bag_messages']} messages, lost {rec['lost']} (before the recorder matched: "
          f"{rec['startup_lost']}), queue drops {rec['queue_dropped']}")
    if args.keep:
        print(f"  run directory kept: {tmp}")
    else:
        shutil.rmtree(tmp, ignore_errors=True)
    print(json.dumps(result))
    return 0 if not died else 1


if __name__ == "__main__":
    raise SystemExit(main())
