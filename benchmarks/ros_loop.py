#!/usr/bin/env python3
"""Real-time 1 kHz loop over DDS (plant and controller as separate processes) and lockstep speed.

Starts ``plant``, ``controller`` and ``demand`` (a slow sine, so the loop works) as real
processes through their installed executables (the run-plan and launcher of
``fuel_valve_demo``), lets them run, then stops them and reads the plant's loop statistics
from ``/diagnostics``.  The fine stage never engages on the sine: ``--demand plateaus`` plays
the nominal box's campaign case ``--plateau-seed`` instead (benchmarks/robustness.py: its plant,
its controller knowledge and its random 0.1-5 % plateaus, as many as the run needs, through the
demand node as corner points), so the apex policy chooses its tries as in the campaign (task
h39n, docs §103).  ``--build "LABEL KEY=VALUE ..."`` (repeatable): controller builds, each run
once per repeat, interleaved.  Per run also the controller's own figures from its
``/diagnostics`` over the window: periods whose sample -> command time passed 0.5 / 1 / 2 ms,
the work left for after a command (``fine.apex_choice_after_command``: count, over 0.5 / 1 /
2 ms, max), the apex policy's tries chosen, its late-loop events (each stands the fine stage
aside for ``fine.late_loop_holdoff_s``) and its last status line (a latched fault shows there):

* round trip plant -> controller -> plant: time from publishing a resolver sample to
  receiving the current command computed from it (median / p99 / max, over the run),
* missed control periods: plant ticks that found no new command since the previous sample
  (counted over the measured window, after a warm-up),
* CPU: user + system seconds of each process per second of run time.

Variants (each run ``--repeat`` times, interleaved, so a change of machine load hits both):

* ``plain``: plant + controller + demand;
* ``record`` (``--record``, or both with ``--both``): the ``recorder`` too (started first,
  stopped last, every suite topic, MCAP, as the launcher and main job run it; the nodes
  publish once it has matched, ``recorded_topics``).  Per topic: the messages the nodes
  published (each node prints its counts at exit, and how many of them went out before the
  recorder had matched) against the messages in the bag's metadata.  ``lost`` = published -
  in bag - published before the match (never below 0); ``startup`` = what the bag misses of
  the messages published before the match; the recorder's own queue drops are listed too;
* ``main`` (``--main``, or all three with ``--all``): the main job itself (``fuel_valve_demo``'s
  run: start-up profile, the recorder on the report's topics, the demo's monitor in this
  process), its own length; the loop figures are the plant's last report before the stop,
  as the demo prints them, plus the worst driver status;
* ``lockstep`` (``--lockstep S``): a lockstep run of S simulated seconds; speed = simulated s
  per wall s, from the plant's "starting" to its "stop_after_s reached" log lines, and CPU per
  process per control period.

``--profile`` runs every node's spin loop under cProfile (``FUEL_VALVE_PROFILE``, see
:mod:`fuel_valve_control.ros.node_runner`) and prints, per process, the share of its
executor-thread time inside ``spin_once`` itself (DDS, the executor, waiting) and the
Python functions that cost most per control period.

OS levers (A/B: run the script alternately with and without, the runs interleave):
``--nice`` / ``--affinity`` / ``--fifo`` (the launcher's :class:`Scheduling`; default: plant
and controller SCHED_FIFO where permitted, recorder and monitor niceness 5; ``--nice off
--fifo off``: none), ``--timer-slack NS`` (the plant tick thread's
timer slack), ``--gc-freeze 0|1`` (the node runner's ``gc.freeze()`` after a node is built).  Each run's JSON holds the levers in force (``levers``) and the plant's tick
lateness (wake-up minus scheduled tick: median / p99 / max over the run), to tell a late
tick from a late answer.

Per run one line; then a summary per variant (median, min, max over the runs).  The last line
printed is one JSON object: ``{"runs": [...], "summary": {variant: {...}}}``.

    python benchmarks/ros_loop.py [--seconds 60] [--record | --both | --main | --all] [--repeat 3] [--domain 107]
                                  [--nice recorder=5,monitor=5|off] [--affinity plant=0,controller=1]
                                  [--fifo plant,controller] [--timer-slack 1000]
    python benchmarks/ros_loop.py --lockstep 10 [--repeat 3] [--profile]
    python benchmarks/ros_loop.py --demand plateaus --seconds 30 --repeat 3 --build "inline fine.apex_choice_after_command=false" --build after
"""
from __future__ import annotations

import argparse
import json
import math
import os
import random
import re
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from fuel_valve_control.common.paramspec import ConfigError, parse_overrides  # noqa: E402
from fuel_valve_control.core.params import CONTROLLER_SPEC  # noqa: E402
from fuel_valve_control.ros.node_runner import GC_FREEZE_ENV, PROFILE_ENV, TIMER_SLACK_ENV  # noqa: E402
from fuel_valve_control.tools.launcher import Launcher, add_scheduling_arguments, scheduling_from_args  # noqa: E402
from fuel_valve_control.tools.run_plan import LOCKSTEP, REAL_TIME, plan_run  # noqa: E402
from fuel_valve_control.tools.scenarios import load_scenario, parse_scenario  # noqa: E402

#: the demand: a slow sine around 40 %, so the valve keeps moving
DEMAND = {"type": "sine", "offset": 40.0, "amplitude": 5.0, "frequency_hz": 0.5}
NS = "/fuel_valve_bench"
#: ``--demand plateaus``: the shortest plateau of the nominal box's sequence (s), so a run of
#: ``--seconds`` plus its warm-up never runs out of plateaus
PLATEAU_MIN_HOLD_S = 0.3
#: ... and what the warm-up and the stop may take on top of ``--seconds`` (s)
PLATEAU_MARGIN_S = 90.0


def parse_build(text: str) -> tuple[str, dict]:
    """``--build "LABEL [section.]key=value ..."``: a label and the controller parameters of that build
    (``controller.`` may be left out; values as ``--set``'s)."""
    label, *items = text.split()
    items = [i if i.startswith("controller.") else "controller." + i for i in items]
    sets = parse_overrides(items, ("controller",))["controller"]
    # the schema's values, checked and typed (a "0" for a float parameter is 0.0: written as an integer into the
    # node's parameter file, rclpy refused it as the wrong type and the controller never started)
    checked = CONTROLLER_SPEC.load(None, sets)
    return label, {k: checked[k] for k in sets}


def demand_plan(args, build: dict, timing: str = REAL_TIME):
    """The real-time run's plan: the slow sine (``--demand sine``, the default) on the configured plant, or
    (``--demand plateaus``) the nominal box's campaign case ``--plateau-seed`` (benchmarks/robustness.py: its
    plant -- friction scatter, ripple, seed -- its controller knowledge and its plateau sequence, as many
    plateaus as the run needs, the plant started held at the first) -- so the fine stage engages and makes its
    tries as in the campaign.  ``build``: the run's controller parameters on top."""
    if args.demand == "sine":
        scenario = parse_scenario({"name": "ros_loop_benchmark", "duration_s": 3600.0, "demand": DEMAND})
        return plan_run(scenario, timing, mode=args.mode, controller_overrides=dict(build),
                        demand_overrides={"publish_rate_hz": args.demand_rate})
    import robustness as R      # noqa: PLC0415 (benchmarks/; the campaign's cases)
    case = R.sample_case(args.plateau_seed, "nominal")
    if args.plateau_dp is not None:
        # the case's plant at this Δp, read right by the transducer (docs §111: the retreat bound's plan is
        # dearest where the static band is narrow, ~0.15 x rated)
        case["dp_true_kpa"] = case["dp_told_kpa"] = args.plateau_dp * R.PRESSURE_MAX_KPA
    count = int(math.ceil((args.seconds + PLATEAU_MARGIN_S) / PLATEAU_MIN_HOLD_S))
    scenario = R.case_scenario(case, count=count)
    return plan_run(scenario, timing, mode=args.mode, plant_overrides=R.plant_overrides(case),
                    controller_overrides={**R.controller_knowledge(case), **build},
                    demand_overrides={"publish_rate_hz": args.demand_rate})


def cpu_seconds(pid: int) -> float:
    """user + system CPU seconds of a live process (from /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def profile_report(profile_dir: Path, periods: int, top: int = 8) -> dict:
    """Per process (``<node>.prof``): executor-thread seconds, the share inside ``spin_once``
    itself (its own time: DDS, the C++ executor, waiting) and the costliest Python functions
    (own time per control period, µs)."""
    import pstats
    out = {}
    for path in sorted(profile_dir.glob("*.prof")):
        stats = pstats.Stats(str(path)).stats           # {(file, line, fn): (cc, nc, tt, ct, callers)}
        total = sum(v[2] for v in stats.values())
        spin = sum(v[2] for k, v in stats.items() if k[2].endswith("spin_once") or "spin_once" in k[2])
        rows = sorted(((v[2], k) for k in stats for v in (stats[k],) if "spin_once" not in k[2]), reverse=True)
        out[path.stem] = {
            "seconds": round(total, 3), "spin_once_share": round(spin / total, 3) if total else None,
            "top_us_per_period": [(f"{Path(k[0]).name}:{k[1]}({k[2]})", round(1e6 * tt / max(periods, 1), 2))
                                  for tt, k in rows[:top]]}
    return out


def _env(args, domain: int, profile_dir: Path | None) -> dict:
    env = dict(ROS_DOMAIN_ID=str(domain), PYTHONWARNINGS="ignore")
    if profile_dir is not None:
        env[PROFILE_ENV] = str(profile_dir)
    if args.timer_slack is not None:
        env[TIMER_SLACK_ENV] = str(args.timer_slack)
    if args.gc_freeze is not None:
        env[GC_FREEZE_ENV] = args.gc_freeze
    return env


def levers(args, launcher: Launcher, stats: dict) -> dict:
    """The OS levers of a run: the launcher's scheduling, what the OS refused of it, and the
    timer slack the plant's tick thread reported."""
    return {"scheduling": launcher.scheduling.describe(), "refused": list(launcher.scheduling_refused),
            "timer_slack_ns": stats.get("timer_slack_ns"), "timer_slack_asked": args.timer_slack,
            "gc_freeze_asked": args.gc_freeze}


def tick_lateness(stats: dict) -> dict:
    """The plant's tick lateness figures (ms, over the whole run) from its loop statistics."""
    return {k: round(float(stats[k]), 3) for k in ("tick_late_median_ms", "tick_late_p99_ms", "tick_late_max_ms")
            if k in stats}


def missed_timeline(bag: Path) -> list[tuple[int, int]]:
    """(ticks, missed) between consecutive loop reports of the plant (once a second) in a
    recorded bag's ``/diagnostics``: where in the run the misses fall (start-up, steady, end)."""
    from rosbags.highlevel import AnyReader
    out, prev = [], None
    with AnyReader([bag]) as reader:
        conns = [c for c in reader.connections if c.topic == "/diagnostics"]
        for conn, _, data in reader.messages(connections=conns):
            for st in reader.deserialize(data, conn.msgtype).status:
                if st.name == f"{NS}/plant: loop":
                    v = {kv.key: kv.value for kv in st.values}
                    now = (int(v["ticks"]), int(v["missed"]))
                    if prev is not None:
                        out.append((now[0] - prev[0], now[1] - prev[1]))
                    prev = now
    return out


def run_main(args, domain: int, tmp: Path) -> dict:
    """One run of the main job (``fuel_valve_demo``'s :func:`run`, recording the report's
    topics, status lines discarded): the loop figures it prints and its worst driver status."""
    import io
    from fuel_valve_control.tools import demo
    import resource
    plan = plan_run(None, REAL_TIME, mode=args.mode)
    t0 = time.monotonic()
    own0 = resource.getrusage(resource.RUSAGE_SELF)
    summary = demo.run(plan, NS, bag=tmp / "bag", run_dir=tmp / "run", out=io.StringIO(),
                       env=_env(args, domain, None), scheduling=scheduling_from_args(args))
    own1 = resource.getrusage(resource.RUSAGE_SELF)
    wall = time.monotonic() - t0
    loop = summary.get("loop") or {}
    ticks = int(loop.get("ticks", 0))
    rec = summary.get("recording") or {}
    return {"variant": "main", "seconds": round(wall, 1), "ticks": ticks,
            # this process: the demo's monitor (and the launcher), CPU s per wall s of the run
            "monitor_cpu_fraction": round((own1.ru_utime + own1.ru_stime - own0.ru_utime - own0.ru_stime) / wall, 3),
            "missed_pct": round(100 * float(loop.get("missed_fraction", float("nan"))), 3) if loop else None,
            "rtt_median_ms": round(float(loop.get("rtt_median_ms", float("nan"))), 3),
            "rtt_p99_ms": round(float(loop.get("rtt_p99_ms", float("nan"))), 3),
            "rtt_max_ms": round(float(loop.get("rtt_max_ms", float("nan"))), 3),
            "tick_lateness": tick_lateness(loop),
            "worst_status": {0: "OK", 1: "WARN", 2: "ERROR"}.get(summary.get("worst_level"), "?"),
            "faults": summary.get("faults"), "ok": summary.get("ok"), "recorder_lost": rec.get("lost"),
            "missed_per_second": [m for _, m in missed_timeline(tmp / "bag")] if (tmp / "bag").exists() else None,
            "levers": {"scheduling": scheduling_from_args(args).describe(), "refused": summary.get("scheduling_refused"),
                       "timer_slack_ns": loop.get("timer_slack_ns"), "timer_slack_asked": args.timer_slack,
                       "gc_freeze_asked": args.gc_freeze},
            "load_average": os.getloadavg()[0]}


def run_real_time(args, record: bool, domain: int, tmp: Path, build: tuple[str, dict] = ("", {})) -> dict:
    """One real-time run (with or without the recorder) of ``build`` (label, controller parameters); the
    result dict."""
    plan = demand_plan(args, build[1])
    profile_dir = tmp / "profile" if args.profile else None
    launcher = Launcher(plan, NS, run_dir=tmp, bag=tmp / "bag" if record else None,
                        env=_env(args, domain, profile_dir), scheduling=scheduling_from_args(args))
    if record:       # first, so it is subscribed before the loop's first messages
        launcher.start_recorder()
        launcher.wait_for_log("recorder", "recording")
    launcher.start()
    procs = launcher.procs
    stats = {}
    try:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        context = rclpy.Context()
        rclpy.init(context=context, domain_id=domain)
        node = rclpy.create_node("ros_loop_benchmark", context=context)
        executor = rclpy.executors.SingleThreadedExecutor(context=context)
        executor.add_node(node)
        compute = []                     # controller: mean / max ms per period, per report
        over = {}                        # controller: periods over each compute threshold, summed over reports
        driver = {}                      # controller: its last counts (apex choices, late loops) and at the window's start
        after_max = []                   # controller: the work after a command, the worst per report (ms)
        status = {}                      # controller: its last status message and move-table status

        def on_diag(msg):
            for st in msg.status:
                if not st.name.startswith(f"{NS}/"):
                    continue
                values = {kv.key: kv.value for kv in st.values}
                if st.name.endswith("plant: loop"):
                    stats.update(values)
                elif st.name.endswith("valve driver") and values.get("compute_mean_ms", "n/a") != "n/a":
                    compute.append((float(values["compute_mean_ms"]), float(values["compute_max_ms"]),
                                    int(values["samples_since_last_report"])))
                    for key in ("apex_choices", "apex_choices_after_command", "late_loop_events"):
                        if values.get(key, "n/a") != "n/a":
                            driver[key] = int(values[key])
                    status.update(move_tables=values.get("move_tables"), message=st.message)
                    if measuring:
                        driver.setdefault("at_start", {k: v for k, v in driver.items() if k != "at_start"})
                        for key, value in values.items():
                            if key.startswith(("compute_over_", "after_command_over_")) or key == "after_command_count":
                                over[key] = over.get(key, 0) + int(value)
                        if values.get("after_command_max_ms", "n/a") != "n/a":
                            after_max.append(float(values["after_command_max_ms"]))
        measuring = False
        node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 10)
        # warm-up: wait until the loop runs, then measure over a fresh window
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline and float(stats.get("rtt_samples", 0) or 0) < 100:
            executor.spin_once(timeout_sec=0.1)
        if not stats:
            raise SystemExit("the loop never started: " + "; ".join(launcher.log_tail(n) for n in launcher.failed()))
        start_stats = dict(stats)
        compute.clear()                  # the window's reports only
        measuring = True
        cpu0 = {n: cpu_seconds(p.pid) for n, p in procs.items()}
        t0 = time.monotonic()
        while time.monotonic() - t0 < args.seconds:
            executor.spin_once(timeout_sec=0.1)
        wall = time.monotonic() - t0
        cpu = {n: (cpu_seconds(p.pid) - cpu0[n]) / wall for n, p in procs.items()}
        # one more diagnostics message so the statistics cover the whole window
        seen = stats.get("ticks")
        t1 = time.monotonic()
        while stats.get("ticks") == seen and time.monotonic() - t1 < 3.0:
            executor.spin_once(timeout_sec=0.1)
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=context)
    finally:
        launcher.stop()            # the publishers first, the recorder last (it drains, then closes the bag)
    ticks = int(stats["ticks"]) - int(start_stats["ticks"])
    missed = int(stats["missed"]) - int(start_stats["missed"])
    result = {
        "variant": "record" if record else "plain",
        "build": build[0], "controller_sets": build[1], "demand": args.demand,
        "seconds": round(wall, 1),
        "ticks": ticks,
        # over the plant's own time between the two statistics messages (the window's ends)
        "rate_hz": round(ticks / max(float(stats["plant_time_s"]) - float(start_stats["plant_time_s"]), 1e-9), 1),
        "missed_pct": round(100 * missed / ticks, 3) if ticks else None,
        # the plant's percentiles cover the whole run including the warm-up
        "rtt_median_ms": round(float(stats["rtt_median_ms"]), 3),
        "rtt_p99_ms": round(float(stats["rtt_p99_ms"]), 3),
        "rtt_max_ms": round(float(stats["rtt_max_ms"]), 3),
        "cpu_fraction": {k: round(v, 3) for k, v in cpu.items()},
        "controller_compute_mean_ms": round(sum(c[0] * c[2] for c in compute) / max(sum(c[2] for c in compute), 1), 4),
        "controller_compute_max_ms": round(max((c[1] for c in compute), default=0.0), 3),
        # periods whose compute time (sample in -> command out) passed 0.5 / 1 / 2 ms, in the window
        "controller_compute_over": dict(sorted(over.items())),
        "controller_periods": sum(c[2] for c in compute),
        "controller_after_command_max_ms": round(max(after_max, default=0.0), 3),
        "controller_status": dict(status),
        # the window's apex choices (all / run after their command) and late-loop events (each stands the fine stage
        # aside for fine.late_loop_holdoff_s)
        **{f"controller_{k}": driver[k] - driver.get("at_start", {}).get(k, 0)
           for k in ("apex_choices", "apex_choices_after_command", "late_loop_events") if k in driver},
        "exit_codes": {n: p.returncode for n, p in procs.items()},
        "tick_lateness": tick_lateness(stats),
        "levers": levers(args, launcher, stats),
        "load_average": os.getloadavg()[0],
    }
    if record:
        rec = launcher.recording_losses()
        result.update(recorder_lost=rec["lost"], recorder_startup_lost=rec["startup_lost"],
                      recorder_queue_dropped=rec["queue_dropped"], recorder_topics=rec["topics"],
                      bag_messages=rec["bag_messages"])
    if profile_dir is not None:
        result["profile"] = profile_report(profile_dir, int(stats.get("commands", ticks)))
    return result


def _log_time(log: str, text: str) -> float | None:
    """Wall time (s, the rclpy log line's stamp) of the first log line containing ``text``."""
    m = re.search(r"\[(\d+\.\d+)\] \[[^\]]*\]: " + re.escape(text), log)
    return float(m.group(1)) if m else None


def run_lockstep(args, domain: int, tmp: Path) -> dict:
    """One lockstep run of ``args.lockstep`` simulated seconds: speed and CPU per period."""
    scenario = load_scenario(args.lockstep_scenario) if args.lockstep_scenario else None
    plan = plan_run(scenario, LOCKSTEP, mode=args.mode, duration_s=args.lockstep)
    profile_dir = tmp / "profile" if args.profile else None
    launcher = Launcher(plan, NS, run_dir=tmp, env=_env(args, domain, profile_dir),
                        scheduling=scheduling_from_args(args))
    launcher.start()
    cpu = {}
    try:
        launcher.wait_for_log("plant", "participants connected", timeout_s=120.0)
        cpu0 = {n: cpu_seconds(p.pid) for n, p in launcher.procs.items()}
        launcher.wait_for_log("plant", "stop_after_s reached", timeout_s=120.0 + 50.0 * args.lockstep)
        cpu = {n: cpu_seconds(p.pid) - cpu0[n] for n, p in launcher.procs.items()}
    finally:
        codes = launcher.stop()
    log = launcher.log("plant")
    start, end = _log_time(log, "lockstep: participants connected"), _log_time(log, "lockstep: stop_after_s")
    stats = launcher.loop_statistics() or {}
    periods = int(stats.get("commands", 0)) or round(args.lockstep * 1000)
    wall = end - start
    result = {"variant": "lockstep", "simulated_s": args.lockstep, "wall_s": round(wall, 2),
              "speed": round(args.lockstep / wall, 3), "periods": periods,
              "period_wall_us": round(1e6 * wall / periods, 1),
              "cpu_us_per_period": {n: round(1e6 * c / periods, 1) for n, c in cpu.items()},
              "republished_ticks": len(re.findall(r"tick re-published", log)),
              "exit_codes": codes, "levers": levers(args, launcher, stats), "load_average": os.getloadavg()[0]}
    if profile_dir is not None:
        result["profile"] = profile_report(profile_dir, periods)
    return result


def describe(r: dict) -> str:
    """One line per run, in words."""
    if r["variant"] == "lockstep":
        return (f"lockstep {r['simulated_s']:g} s simulated in {r['wall_s']} s wall: speed {r['speed']}x real time, "
                f"{r['period_wall_us']} us wall per period; CPU us per period {r['cpu_us_per_period']}; "
                f"ticks re-published {r['republished_ticks']}; load {r['load_average']:.1f}") + _profile_lines(r)
    if r["variant"] == "main":
        return (f"main   {r['seconds']} s wall: {r['ticks']} ticks, missed {r['missed_pct']} %, round trip median "
                f"{r['rtt_median_ms']} ms, p99 {r['rtt_p99_ms']} ms, max {r['rtt_max_ms']} ms; tick lateness "
                f"{r['tick_lateness']}; monitor CPU {r['monitor_cpu_fraction']}; missed per second "
                f"{r['missed_per_second']}; worst driver status {r['worst_status']}"
                + (f" ({' | '.join(r['faults'])})" if r.get("faults") else "")
                + f"; recorder lost {r['recorder_lost']}; levers {r['levers']}; load {r['load_average']:.1f}")
    line = (f"{r['variant']:<6}{' ' + r['build'] if r.get('build') else ''} {r['seconds']} s: {r['ticks']} ticks ({r['rate_hz']} Hz), missed {r['missed_pct']:.3f} %, "
            f"round trip median {r['rtt_median_ms']} ms, p99 {r['rtt_p99_ms']} ms, max {r['rtt_max_ms']} ms; CPU "
            f"{r['cpu_fraction']}; controller compute mean {r['controller_compute_mean_ms']} ms, max "
            f"{r['controller_compute_max_ms']} ms, periods over {r.get('controller_compute_over')} of "
            f"{r.get('controller_periods')}; apex choices {r.get('controller_apex_choices')} (after the command "
            f"{r.get('controller_apex_choices_after_command')}, max {r.get('controller_after_command_max_ms')} ms); "
            f"late loops {r.get('controller_late_loop_events')}; tick lateness "
            f"{r['tick_lateness']}; levers {r['levers']}; load {r['load_average']:.1f}")
    if "recorder_lost" in r:
        line += (f"\n       recorder: {r['bag_messages']} messages in the bag, lost {r['recorder_lost']}, start-up "
                 f"lost {r['recorder_startup_lost']}, queue drops {r['recorder_queue_dropped']}")
        for topic, v in r["recorder_topics"].items():
            line += (f"\n         {topic:<40} published {v['published']:>7} (before match {v['before_match']:>3})  "
                     f"in bag {v['in_bag']:>7}  lost {v['lost']}")
    return line + _profile_lines(r)


def _profile_lines(r: dict) -> str:
    """The ``--profile`` figures of a run, one line per process."""
    return "".join(
        f"\n       profile {proc}: {p['seconds']} s on the executor thread, {100 * (p['spin_once_share'] or 0):.0f} % "
        f"inside spin_once (DDS, executor, waiting); top own time, us per period: "
        + ", ".join(f"{name} {us}" for name, us in p["top_us_per_period"]) for proc, p in r.get("profile", {}).items())


def summarise(runs: list[dict]) -> dict:
    """Per variant: median, min and max over the runs of the headline figures."""
    keys = {"plain": ("missed_pct", "rtt_median_ms", "rtt_p99_ms", "rtt_max_ms"),
            "record": ("missed_pct", "rtt_median_ms", "rtt_p99_ms", "rtt_max_ms", "recorder_lost",
                       "recorder_startup_lost"),
            "main": ("missed_pct", "rtt_median_ms", "rtt_p99_ms", "rtt_max_ms", "recorder_lost"),
            "lockstep": ("speed", "wall_s", "period_wall_us")}
    out = {}
    builds = sorted({r.get("build") or "" for r in runs}, key=[r.get("build") or "" for r in runs].index)
    for variant in keys:
        for build in builds:
            rs = [r for r in runs if r["variant"] == variant and (r.get("build") or "") == build]
            if not rs:
                continue
            name = variant if len(builds) == 1 or not build else f"{variant}/{build}"
            out[name] = {"runs": len(rs)}
            for k in keys[variant] + (("controller_compute_mean_ms", "controller_compute_max_ms")
                                      if variant in ("plain", "record") else ()):
                vals = [r[k] for r in rs if r.get(k) is not None]
                if vals:
                    out[name][k] = {"median": statistics.median(vals), "min": min(vals), "max": max(vals),
                                    "each": vals}
            cpu = {}
            for r in rs:
                for proc, v in r.get("cpu_fraction", r.get("cpu_us_per_period", {})).items():
                    cpu.setdefault(proc, []).append(v)
            out[name]["cpu_median"] = {p: statistics.median(v) for p, v in cpu.items()}
            over = {}
            for r in rs:
                for key, v in r.get("controller_compute_over", {}).items():
                    over[key] = over.get(key, 0) + v
            if over:
                out[name]["controller_compute_over_total"] = dict(sorted(over.items()))
                out[name]["controller_periods_total"] = sum(r.get("controller_periods", 0) for r in rs)
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="real time: measured window per run, s")
    parser.add_argument("--demand-rate", type=float, default=200.0, help="demand publish rate, Hz")
    parser.add_argument("--mode", default=None, help="controller mode (default: controller.yaml)")
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--record", action="store_true", help="the 'record' variant only (recorder running too)")
    group.add_argument("--both", action="store_true", help="'plain' and 'record' runs, interleaved")
    group.add_argument("--main", action="store_true", help="the 'main' variant only (the main job)")
    group.add_argument("--all", action="store_true", help="'plain', 'record' and 'main' runs, interleaved")
    group.add_argument("--lockstep", type=float, metavar="S", default=None,
                       help="lockstep speed: runs of S simulated seconds instead of real time")
    parser.add_argument("--lockstep-scenario", default=None, help="scenario of the lockstep runs (default: the "
                        "start-up profile)")
    parser.add_argument("--repeat", type=int, default=1, help="runs of each variant (interleaved)")
    parser.add_argument("--demand", choices=("sine", "plateaus"), default="sine",
                        help="plain / record runs: the slow sine (default; the fine stage never engages on it) or "
                             "the nominal box's random plateaus (benchmarks/robustness.py, case --plateau-seed)")
    parser.add_argument("--plateau-seed", type=int, default=1000, help="--demand plateaus: the campaign case")
    parser.add_argument("--plateau-dp", type=float, default=None, metavar="FRACTION",
                        help="--demand plateaus: the case's Δp (true and read) as this fraction of the rated "
                             "(default: the case's own, the rated)")
    parser.add_argument("--build", action="append", default=[], metavar='"LABEL [controller.]KEY=VALUE ..."',
                        help="plain / record runs: a controller build (its parameters on top of the config); "
                             "several: every variant runs once per build, interleaved (default: one build, the "
                             "config's)")
    parser.add_argument("--profile", action="store_true", help="cProfile every node's executor thread")
    parser.add_argument("--domain", type=int, default=None,
                        help="ROS_DOMAIN_ID for the runs (default: $ROS_DOMAIN_ID, else a random one in 100-200)")
    parser.add_argument("--timer-slack", type=int, default=None, metavar="NS",
                        help="timer slack of the plant's tick thread, ns (default: the plant's own)")
    parser.add_argument("--gc-freeze", choices=("0", "1"), default=None,
                        help="gc.freeze() in every node once built: 1 on, 0 off (default: the node runner's)")
    add_scheduling_arguments(parser)
    args = parser.parse_args()
    if args.repeat < 1:
        parser.error("--repeat must be >= 1")
    try:
        scheduling_from_args(args)
    except ValueError as exc:
        parser.error(str(exc))
    try:
        builds = [parse_build(b) for b in args.build] or [("default", {})]
        for _, sets in builds:
            demand_plan(args, sets)             # a bad parameter is an error before any run
    except (ConfigError, ValueError) as exc:
        parser.error(str(exc))
    if len({label for label, _ in builds}) != len(builds):
        parser.error("--build labels must differ")
    domain = args.domain if args.domain is not None else int(os.environ.get("ROS_DOMAIN_ID") or random.randint(100, 200))
    variants = ["lockstep"] if args.lockstep else ["record"] if args.record else ["main"] if args.main else \
        ["plain", "record"] if args.both else ["plain", "record", "main"] if args.all else ["plain"]
    runs = []
    for k in range(args.repeat):
        for variant, build in [(v, b) for v in variants for b in (builds if v in ("plain", "record") else builds[:1])]:
            tmp = Path(tempfile.mkdtemp(prefix="ros_loop_"))
            try:
                if variant == "lockstep":
                    r = run_lockstep(args, domain, tmp)
                elif variant == "main":
                    r = run_main(args, domain, tmp)
                else:
                    r = run_real_time(args, variant == "record", domain, tmp, build)
            except ConfigError as exc:
                print(f"ros_loop: {exc}", file=sys.stderr)
                return 2
            finally:
                shutil.rmtree(tmp, ignore_errors=True)
            r["run"] = k + 1
            runs.append(r)
            print(f"run {k + 1}/{args.repeat} " + describe(r), flush=True)
    summary = summarise(runs)
    for variant, s in summary.items():
        figures = "; ".join(f"{k} {v['median']:g} (min {v['min']:g}, max {v['max']:g})"
                            for k, v in s.items() if isinstance(v, dict) and "median" in v)
        print(f"summary {variant} ({s['runs']} runs, median): {figures}; CPU {s['cpu_median']}")
    print(json.dumps({"runs": runs, "summary": summary}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
