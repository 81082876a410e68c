"""``fuel_valve_demo``: run the node suite (plant, controller, demand, optional recorder) as
separate processes talking over DDS, watch it live and summarise it.

    fuel_valve_demo [--scenario NAME|FILE] [--lockstep] [--controller MODE] [--bag DIR]
                    [--duration S] [--namespace NS] [--set section.key=value ...]
                    [--nice NAME=N,...|off] [--affinity NAME=CPU,...] [--fifo NAME,...]

The stand-in for ``ros2 launch`` on machines with only the PyPI ROS wheels (the launch file
``launch/fuel_valve.launch.py`` does the same job on a full ROS install).  Without
``--scenario`` the demand node plays the start-up-to-core-idle profile at maximum Δp.

A scenario (``config/scenarios``) becomes a run-plan (:mod:`.run_plan`, the same one
``fuel_valve_sim`` runs offline): node parameters, the initial state (``initial_percent``:
the plant starts held there, the controller from the holding current), the demand profile and
the timed events.  :mod:`.launcher` starts the nodes; :mod:`.monitor` watches them and sends
the scenario events (trip, reset, set_plant, set_controller) through the controller's services
and the nodes' parameter services when the suite's clock passes them: on time in real time,
within a few periods in lockstep (service calls are asynchronous to the loop; exact event
times would need the plant to pause the lockstep loop for them -- use ``fuel_valve_sim`` when
an event's exact period matters).

While it runs, one status line per second (simulated time in lockstep) shows demand,
position, error, current, valve-friction estimate, driver state and faults; at the end a
summary, and with ``--bag`` the bag's report (``fuel_valve_report``) and its plot.
OS scheduling (``--nice``, ``--affinity``, ``--fifo``; :class:`.launcher.Scheduling`): by
default the plant and the controller run SCHED_FIFO in real time where the OS permits it
(root or CAP_SYS_NICE; otherwise a line says so and they run at normal priority), the demand
node and the recorder SCHED_FIFO below them, and this process with its monitor at a lower
priority (niceness 5), so on a busy 2-core machine the 1 kHz loop is served first.

Exit code: 0 run completed, 1 a node failed, 2 bad arguments.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from ..common.paramspec import ConfigError, parse_overrides
from ..core.params import MODES
from .launcher import (CLEAN_EXIT_CODES, Launcher, Scheduling, add_scheduling_arguments, nice_own_threads,
                       scheduling_from_args)
from .monitor import Monitor, send_event
from .run_plan import LOCKSTEP, REAL_TIME, RunPlan, plan_run
from .scenarios import load_scenario

#: what a real-time demo records: everything the report uses, without the two 1 kHz loop
#: topics (resolver, current_command) whose recording costs CPU the loop needs on 2 cores
REPORT_TOPICS = ["demand", "demand_ma", "joint_states", "drive", "drive_enable", "position", "estimate",
                 "/diagnostics"]
#: wall-clock limit for the suite to come up (DDS discovery, imports, the plant kernel's JIT
#: compilation), s: only a dead-node detector, so generous -- at load average 20 on the 2-core
#: machine the plant and controller were still importing after 30 s
STARTUP_TIMEOUT_S = 120.0
#: real time, at the profile's end: how long to wait for the plant's next loop report (it
#: reports once a second), s -- a stalled one is not waited for longer
LOOP_REPORT_WAIT_S = 5.0


# ---------------------------------------------------------------------------------- running
def run(plan: RunPlan, namespace: str = "/fuel_valve", bag: Path | None = None, run_dir: Path | None = None,
        out=sys.stdout, status_period_s: float = 1.0, bag_storage: str = "mcap", env: dict | None = None,
        record_truth: bool = False, scheduling: Scheduling | None = None) -> dict:
    """Start the suite, run ``plan`` (real time or lockstep) to its end, stop it.  Returns a
    summary dict (``ok``, final status, faults, loop statistics, node exit codes, ``truth``:
    (stamp s, true valve angle rad, velocity rad/s) per plant sample when ``record_truth``).

    ``scheduling``: OS priorities of the processes (:class:`.launcher.Scheduling`; None: its
    default); its ``monitor`` niceness applies to this process once every node is started (in
    real time: a lockstep monitor starved on a loaded machine lost its truth samples).
    The loop statistics (``loop``) are, in real time, the plant's first report after the
    profile's end (stamped after it), taken before the stop (the run's periods from the loop's
    closing to the profile's end, plus up to a second; what the plant counts while the suite
    shuts down -- ticks with the controller already gone -- is no part of the run).  Where no
    such report arrives within :data:`LOOP_REPORT_WAIT_S` (a starved plant or monitor), the
    plant's exit line instead (``loop_source`` "exit" rather than "report")."""
    scheduling = Scheduling() if scheduling is None else scheduling
    lockstep = plan.lockstep
    if env and "ROS_DOMAIN_ID" in env:
        os.environ["ROS_DOMAIN_ID"] = str(env["ROS_DOMAIN_ID"])
    monitor = Monitor(namespace, lockstep, record_truth)
    summary: dict = {"lockstep": lockstep, "duration_s": plan.duration_s, "namespace": monitor.node.get_namespace()}
    wall0 = time.monotonic()
    try:
        with Launcher(plan, namespace, run_dir, bag, bag_storage, env, observers=1, scheduling=scheduling) as suite:
            summary["run_dir"] = str(suite.run_dir)
            summary["scheduling_refused"] = suite.scheduling_refused     # filled as the nodes start
            summary["real_time_priority"] = [] if lockstep else [n for n in scheduling.fifo
                                                                 if n in ("plant", "controller")]
            if bag:
                suite.start_recorder(None if lockstep else REPORT_TOPICS)
            if lockstep:                    # profile time = simulated time: all at once
                suite.start()
            else:                           # profile time starts with the demand node: start it
                suite.start(("plant", "controller"))       # once the loop runs
                if not _wait(monitor, suite, monitor.controller_ready):
                    return _failed(summary, suite, "the controller did not come up", out)
                suite.start(("demand",))
            # real time only: in lockstep the monitor is a participant and takes every truth sample
            for why in nice_own_threads(0 if lockstep else scheduling.nice.get("monitor", 0)):
                suite.scheduling_refused.append(why)
                print(f"fuel_valve_demo: {why}", file=sys.stderr, flush=True)
            t_start = None
            next_status = 0.0
            events = plan.event_queue()
            pending = []
            while True:
                monitor.spin_for(0.02)
                if suite.failed():
                    return _failed(summary, suite, f"node(s) exited: {', '.join(suite.failed())}", out)
                if lockstep:
                    t = monitor.sim_time or 0.0
                    if monitor.sim_time is None and time.monotonic() - wall0 > STARTUP_TIMEOUT_S:
                        return _failed(summary, suite, "lockstep did not start (participants missing)", out)
                else:
                    if t_start is None and monitor.demand is not None:
                        t_start = time.monotonic()
                    t = time.monotonic() - t_start if t_start is not None else 0.0
                    if t_start is None and time.monotonic() - wall0 > STARTUP_TIMEOUT_S:
                        return _failed(summary, suite, "no demand arrived", out)
                for ev in events.due(t):
                    pending.append(send_event(monitor, namespace, ev, out))
                if t >= next_status:
                    print(monitor.status_line(t), file=out, flush=True)
                    next_status += status_period_s
                if t >= plan.duration_s - 1e-9:
                    break
                if lockstep and time.monotonic() - wall0 > STARTUP_TIMEOUT_S + 50.0 * plan.duration_s:
                    return _failed(summary, suite, "lockstep run stalled", out)
            monitor.spin_for(0.2)                   # let the last diagnostics arrive
            summary["wall_time_s"] = round(time.monotonic() - wall0, 2)
            covered = False
            if not lockstep:                        # a report stamped after the profile's end covers it
                # (the stamp, not the count of reports: a report queued while this process was
                # starved arrives late and covers only part of the run -- a CI run read one
                # 1.3 s into a 3 s profile)
                profile_end = time.time()
                covered = _wait(monitor, suite, lambda: (monitor.loop_stamp or 0.0) >= profile_end,
                                LOOP_REPORT_WAIT_S)
            summary["loop"] = monitor.loop_statistics() if covered else None    # before the stop (docstring)
            summary["loop_source"] = "report" if covered else "exit"
            codes = suite.stop()
            summary["exit_codes"] = codes
            if summary["loop"] is None:     # lockstep, or no covering report: the plant's exit line
                summary["loop"] = suite.loop_statistics()
            if bag is not None and codes.get("recorder") in CLEAN_EXIT_CODES:
                try:
                    summary["recording"] = suite.recording_losses()
                except (OSError, KeyError, TypeError, ValueError):    # no readable metadata.yaml
                    summary["recording"] = None
    finally:
        final = monitor.status_line(plan.duration_s)
        summary.update(final_status=final, worst_level=monitor.worst_level, faults=monitor.fault_messages,
                       final_error_pct=(monitor.demand - monitor.position)
                       if monitor.demand is not None and monitor.position is not None else None,
                       health=monitor.health, truth=monitor.truth)
        monitor.close()
    summary["ok"] = all(c in CLEAN_EXIT_CODES for c in summary.get("exit_codes", {}).values())
    return summary


def _wait(monitor: Monitor, suite: Launcher, ready, timeout_s: float = STARTUP_TIMEOUT_S) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        monitor.spin_for(0.05)
        if ready():
            return True
        if suite.failed():
            return False
    return False


def _failed(summary: dict, suite: Launcher, why: str, out) -> dict:
    summary.update(ok=False, error=why)
    print(f"fuel_valve_demo: {why}", file=out, flush=True)
    for name in suite.procs:
        tail = suite.log_tail(name)
        if tail:
            print(f"--- {name} log (last lines) ---\n{tail}", file=out, flush=True)
    return summary


def _priority_note(summary: dict) -> str:
    """How the loop's processes were scheduled, in words (launcher.Scheduling)."""
    fifo = summary.get("real_time_priority") or []
    refused = [n for n in fifo if any("SCHED_FIFO" in r and f" for {n} " in r
                                      for r in summary.get("scheduling_refused", []))]
    if not fifo:
        return "normal (real-time priority off: --fifo off)"
    if refused:
        return (f"normal for {', '.join(refused)}: real-time priority (SCHED_FIFO) needs root or CAP_SYS_NICE; "
                "without it other work on the machine delays the loop")
    return f"real time (SCHED_FIFO) for {', '.join(fifo)}: other work on the machine waits for the loop"


def print_summary(summary: dict, out=sys.stdout) -> None:
    print("\n=== summary ===", file=out)
    print(f"mode: {'lockstep (simulated time)' if summary['lockstep'] else 'real time'}, "
          f"{summary['duration_s']:g} s in {summary.get('wall_time_s', float('nan')):g} s wall", file=out)
    print(f"final: {summary.get('final_status', '')}", file=out)
    level = {0: "OK", 1: "WARN", 2: "ERROR"}.get(summary.get("worst_level"), "?")
    print(f"worst driver status: {level}" + (f"; faults: {' | '.join(summary['faults'])}" if summary.get("faults")
                                             else ""), file=out)
    loop = summary.get("loop")
    if loop and "rtt_median_ms" in loop and not summary["lockstep"]:
        print(f"loop: during the run the plant ticked {loop['ticks']} times at 1 kHz; in "
              f"{100 * loop['missed_fraction']:.2f} % of "
              f"the ticks the controller's answer to the previous sample had not arrived yet (missed periods: the "
              f"plant held the old current); sample -> command round trip median {loop['rtt_median_ms']:.3f} ms, "
              f"99 % within {loop['rtt_p99_ms']:.3f} ms (a period is 1 ms); machine load average "
              f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores (other work delays the nodes)", file=out)
        print(f"loop priority: {_priority_note(summary)}", file=out)
    if loop and summary["lockstep"]:
        print(f"loop: {loop.get('commands')} control periods in lockstep", file=out)
    rec = summary.get("recording")
    if rec:
        missing = {t.rsplit('/', 1)[-1]: v["published"] - v["in_bag"] for t, v in rec["topics"].items()
                   if v["published"] != v["in_bag"]}
        published = sum(v["published"] for v in rec["topics"].values())
        print(f"recording: {rec['bag_messages']} messages in the bag; of the {published} the nodes published on "
              f"the recorded topics " + (f"{sum(missing.values())} are missing ({missing})" if missing else
                                         "none is missing"), file=out)
    print(f"node logs: {summary.get('run_dir')}", file=out, flush=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="fuel_valve_demo", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenario", help="scenario name or YAML file (default: start-up profile, 20 s)")
    parser.add_argument("--lockstep", action="store_true", help="deterministic simulated-time run (as fast as "
                        "the loop allows)")
    parser.add_argument("--controller", metavar="MODE", help=f"control mode: {', '.join(MODES)}")
    parser.add_argument("--duration", type=float, help="run length, s (default: the scenario's)")
    parser.add_argument("--namespace", default="/fuel_valve")
    parser.add_argument("--bag", help="record the run into this bag directory and report it at the end")
    parser.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap")
    parser.add_argument("--plot", help="report plot PNG (default: BAG.png)")
    parser.add_argument("--run-dir", help="where node logs and parameter files go (default: a temp dir)")
    parser.add_argument("--set", action="append", default=[], metavar="section.key=value",
                        help="plant.* / controller.* parameter override (repeatable)")
    add_scheduling_arguments(parser)
    args = parser.parse_args(argv)
    try:
        scheduling = scheduling_from_args(args)
    except ValueError as exc:
        print(f"fuel_valve_demo: {exc}", file=sys.stderr)
        return 2
    try:
        over = parse_overrides(args.set, ("plant", "controller"))
        scenario = load_scenario(args.scenario) if args.scenario else None
        plan = plan_run(scenario, LOCKSTEP if args.lockstep else REAL_TIME, mode=args.controller,
                        duration_s=args.duration, plant_overrides=over.get("plant"),
                        controller_overrides=over.get("controller"))
        if args.bag and Path(args.bag).exists():
            raise ConfigError(f"bag {args.bag} exists already; choose another --bag")
    except ConfigError as exc:
        print(f"fuel_valve_demo: {exc}", file=sys.stderr)
        return 2
    print(f"fuel_valve_demo: {plan.description or args.scenario} | "
          f"{'lockstep' if args.lockstep else 'real time 1 kHz'} | {plan.duration_s:g} s"
          + (f" | recording {args.bag}" if args.bag else ""), flush=True)
    summary = run(plan, args.namespace, Path(args.bag) if args.bag else None,
                  Path(args.run_dir) if args.run_dir else None, bag_storage=args.storage, scheduling=scheduling)
    print_summary(summary)
    if not summary.get("ok"):
        return 1
    if args.bag:
        plot = args.plot or str(Path(args.bag)) + ".png"
        try:
            from . import report
        except ImportError as exc:            # the report tool needs the rosbags reader
            print(f"no report: {exc}")
            return 0
        print(f"\n=== report of {args.bag} ===", flush=True)
        # judged on the profile the run played, not on the suite's shutdown after it
        return report.main([args.bag, "--plot", plot, "--profile-s", f"{plan.duration_s:g}"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
