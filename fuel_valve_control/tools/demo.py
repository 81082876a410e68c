"""``fuel_valve_demo``: run the node suite (plant, controller, demand, optional recorder) as
separate processes talking over DDS, watch it live and summarise it.

    fuel_valve_demo [--scenario NAME|FILE] [--lockstep] [--controller MODE] [--bag DIR]
                    [--duration S] [--namespace NS] [--set section.key=value ...]

The stand-in for ``ros2 launch`` on machines with only the PyPI ROS wheels (the launch file
``launch/fuel_valve.launch.py`` does the same job on a full ROS install).  Without
``--scenario`` the demand node plays the start-up-to-core-idle profile at maximum Δp.

A scenario (``config/scenarios``) is translated into node parameters: Δp and plant
overrides to the plant, controller overrides (and the Δp the supervisor tells it) to the
controller, the demand profile to the demand node; ``initial_percent`` starts the plant held
there by the drive (``start_held``) and the controller from the holding current, as the
offline simulator does.  Scenario events (trip, reset, set_plant, set_controller) are sent
through the controller's services and the nodes' parameter services when the suite's clock
passes them: on time in real time, within a few periods in lockstep (service calls are
asynchronous to the loop).

While it runs, one status line per second (simulated time in lockstep) shows demand,
position, error, current, valve-friction estimate, driver state and faults; at the end a
summary, and with ``--bag`` the bag's report (``fuel_valve_report``) and its plot.
Exit code: 0 run completed, 1 a node failed, 2 bad arguments.
"""
from __future__ import annotations

import argparse
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from ..common.paramspec import ConfigError, parse_overrides
from fuel_valve_plant.physics.plant import Plant
from ..common.config_dir import default_config_dir
from fuel_valve_plant.physics.params import PLANT_SPEC

from ..core.params import MODES
from .scenarios import Scenario, load_scenario

NODES = ("plant", "controller", "demand")
#: what a real-time demo records: everything the report uses, without the two 1 kHz loop
#: topics (resolver, current_command) whose recording costs CPU the loop needs on 2 cores
REPORT_TOPICS = ["demand", "demand_ma", "joint_states", "drive", "drive_enable", "position", "estimate",
                 "/diagnostics"]
#: wall-clock limit for the suite to come up (DDS discovery, imports), s
STARTUP_TIMEOUT_S = 30.0


# ---------------------------------------------------------------------------------- parameters
@dataclass
class SuitePlan:
    """What to start: per-node parameters and the run's length."""
    duration_s: float
    params: dict = field(default_factory=dict)       # node -> {param: value}
    events: list = field(default_factory=list)
    description: str = ""


def plan_for(scenario: Scenario | None, lockstep: bool, mode: str | None = None, duration_s: float | None = None,
             plant_overrides: dict | None = None, controller_overrides: dict | None = None) -> SuitePlan:
    """Node parameters for a scenario (None: the start-up profile), layered like the offline
    simulator's: config defaults < scenario < overrides."""
    plant, controller = {}, {}
    if scenario is None:
        demand = {"profile": "startup"}
        duration = 20.0
        description = "start-up to core idle at maximum differential pressure"
        events = []
    else:
        plant.update(scenario.plant)
        controller.update(scenario.controller)
        if scenario.pressure_kpa is not None:
            plant["pressure_differential_kpa"] = scenario.pressure_kpa
            controller.setdefault("pressure_differential_kpa", scenario.pressure_kpa)
        demand = demand_params(scenario.demand_spec)
        duration = scenario.duration_s
        description = scenario.description
        events = list(scenario.events)
    plant.update(plant_overrides or {})
    controller.update(controller_overrides or {})
    if mode is not None:
        controller["mode"] = mode
    if scenario is not None and scenario.initial_percent > 0.0:
        # as fuel_valve_sim does: the plant starts held there, the loop from the holding current
        # (the controller turns it into torque with its nominal torque constant, like the simulator)
        ps = _plant_params(plant)
        angle = scenario.initial_percent / 100.0 * ps["valve.stroke_rad"]
        plant["initial_position_rad"] = angle
        plant["start_held"] = True
        controller["initial_current_a"] = Plant(ps).hold_at(angle)
    duration = float(duration_s if duration_s is not None else duration)
    plant["lockstep"] = lockstep
    controller["lockstep"] = lockstep
    demand["lockstep"] = lockstep
    if lockstep:
        plant["stop_after_s"] = duration
    return SuitePlan(duration, {"plant": plant, "controller": controller, "demand": demand}, events, description)


def demand_params(spec: dict) -> dict:
    """Demand-node parameters for a profile description (profiles.py keys)."""
    out = {}
    for key, value in spec.items():
        if key == "type":
            out["profile"] = value
        elif key == "points":
            out["points"] = [float(x) for pair in value for x in pair]
        elif key == "path":
            out["csv_path"] = str(value)
        else:
            out[key] = float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else value
    return out


def _plant_params(overrides: dict):
    ps = PLANT_SPEC.defaults()
    known = {k: v for k, v in overrides.items() if k in PLANT_SPEC}
    return ps.replace(PLANT_SPEC.validate(known))


def write_params_file(path: Path, params: dict) -> None:
    """A ROS 2 parameter file for any node (``/**``), dotted names nested."""
    tree: dict = {}
    for name, value in params.items():
        node = tree
        parts = name.split(".")
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = _plain(value)
    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": tree}}, sort_keys=False))


def _plain(value):
    """YAML-safe Python scalars/lists (numpy floats become float)."""
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if hasattr(value, "item") and not isinstance(value, (str, bytes)):
        return value.item()
    return value


def executable(name: str) -> list[str]:
    """Command that starts node ``name``: the installed executable next to this Python (the
    venv's console scripts), on PATH, or in a colcon install's lib/fuel_valve; else the module."""
    here = Path(sys.executable).parent / name
    if here.is_file():
        return [str(here)]
    found = shutil.which(name)
    if found:
        return [found]
    modules = {"plant": "fuel_valve_plant.ros.plant_node", "controller": "fuel_valve_control.ros.controller_node",
               "demand": "fuel_valve_control.ros.demand_node", "recorder": "fuel_valve_control.tools.recorder"}
    return [sys.executable, "-m", modules[name]]


# ---------------------------------------------------------------------------------- processes
class Suite:
    """The node processes of one run.  Use as a context manager: every process is stopped
    (SIGINT, then SIGKILL after a grace period) on exit, whatever happened."""

    def __init__(self, plan: SuitePlan, namespace: str = "/fuel_valve", run_dir: Path | None = None,
                 bag: Path | None = None, bag_storage: str = "mcap", env: dict | None = None,
                 monitor: bool = True):
        self.plan = plan
        self.namespace = "/" + namespace.strip("/")
        self.run_dir = Path(run_dir) if run_dir else Path(tempfile.mkdtemp(prefix="fuel_valve_run_"))
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.bag = Path(bag) if bag else None
        self.bag_storage = bag_storage
        self.env = dict(os.environ, **(env or {}))
        self.env.setdefault("PYTHONUNBUFFERED", "1")
        self.procs: dict[str, subprocess.Popen] = {}
        self.logs: dict[str, Path] = {}
        self.lockstep = bool(plan.params["plant"].get("lockstep"))
        self.monitor = monitor

    def clock_participants(self) -> int:
        """Distinct nodes that subscribe to /clock in lockstep (the plant waits for them)."""
        return 2 + (1 if self.bag else 0) + (1 if self.monitor else 0)

    def start(self, names=NODES) -> None:
        cfg = default_config_dir()
        files = {"plant": cfg / "plant.yaml", "controller": cfg / "controller.yaml", "demand": cfg / "demand.yaml"}
        for name in names:
            params = dict(self.plan.params.get(name, {}))
            if self.lockstep:
                params["use_sim_time"] = True
                if name == "plant":
                    params["use_sim_time"] = False          # the plant owns /clock
                    params["lockstep_participants"] = self.clock_participants()
            self._spawn(name, params, files.get(name))

    def start_recorder(self, topics: list[str] | None = None) -> None:
        params = {"output": str(self.bag), "storage": self.bag_storage, "use_sim_time": self.lockstep}
        if topics:
            params["topics"] = topics
        self._spawn("recorder", params, None)

    def _spawn(self, name: str, params: dict, base_file: Path | None) -> None:
        pfile = self.run_dir / f"{name}.params.yaml"
        write_params_file(pfile, params)
        cmd = executable(name) + ["--ros-args", "-r", f"__ns:={self.namespace}"]
        if base_file is not None:
            cmd += ["--params-file", str(base_file)]
        cmd += ["--params-file", str(pfile)]
        log = self.run_dir / f"{name}.log"
        self.logs[name] = log
        with open(log, "w") as fh:
            self.procs[name] = subprocess.Popen(cmd, stdout=fh, stderr=subprocess.STDOUT, env=self.env,
                                                stdin=subprocess.DEVNULL)

    def failed(self) -> list[str]:
        """Nodes that exited on their own."""
        return [n for n, p in self.procs.items() if p.poll() is not None]

    def stop(self, order=("recorder", "demand", "controller", "plant"), grace_s: float = 10.0) -> dict:
        """SIGINT each node (recorder first, so it finalises the bag with everything), wait,
        kill what hangs.  Returns ``{node: exit code}``."""
        codes = {}
        for name in list(order) + [n for n in self.procs if n not in order]:
            proc = self.procs.get(name)
            if proc is None:
                continue
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
                try:
                    proc.wait(timeout=grace_s)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()
            codes[name] = proc.returncode
        return codes

    def log_tail(self, name: str, lines: int = 15) -> str:
        try:
            return "\n".join(self.logs[name].read_text().splitlines()[-lines:])
        except (KeyError, OSError):
            return ""

    def loop_statistics(self) -> dict | None:
        """The plant's loop statistics line (printed when it exits)."""
        text = self.logs.get("plant").read_text() if "plant" in self.logs else ""
        m = re.search(r"loop statistics: (\{.*\})", text)
        if not m:
            return None
        try:
            return yaml.safe_load(m.group(1).replace("'", '"'))
        except yaml.YAMLError:
            return None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop()
        return False


# ---------------------------------------------------------------------------------- monitor
class Monitor:
    """An in-process rclpy node that watches the run: suite time, demand, position, current,
    friction estimate and driver health, for the status line, the summary and events."""

    def __init__(self, namespace: str, lockstep: bool, record_truth: bool = False):
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64
        from ..common import contract
        from ..ros import interface as ri

        self.rclpy = rclpy
        self.context = rclpy.context.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("suite_monitor", namespace=namespace, context=self.context)
        self.lockstep = lockstep
        self.sim_time = None
        self.demand = None
        self.position = None
        self.friction_estimate = None
        self.health: dict = {}
        self.level = None
        self.message = ""
        self.worst_level = 0
        self.armed = False
        self.fault_messages: list[str] = []
        self.errors: list[float] = []              # |demand - position| %, per position sample
        n = self.node
        ri.quiet_subscription(n, Float64, contract.DEMAND, self._on_demand, ri.TELEMETRY_QOS)
        ri.quiet_subscription(n, Float64, contract.POSITION, self._on_position)
        ri.quiet_subscription(n, JointState, contract.ESTIMATE, self._on_estimate)
        ri.quiet_subscription(n, DiagnosticArray, contract.DIAGNOSTICS, self._on_diagnostics)
        if lockstep:
            ri.quiet_subscription(n, Clock, contract.CLOCK, self._on_clock, ri.TELEMETRY_QOS)
        #: (stamp s, true valve angle rad, true valve velocity rad/s) per plant sample
        self.truth: list[tuple[float, float, float]] = []
        if record_truth:
            from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
            deep = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE)
            ri.quiet_subscription(n, JointState, contract.JOINT_STATES, self._on_truth, deep)
        self.executor = rclpy.executors.SingleThreadedExecutor(context=self.context)
        self.executor.add_node(n)

    def _on_clock(self, msg):
        self.sim_time = msg.clock.sec + 1e-9 * msg.clock.nanosec

    def _on_truth(self, msg):
        st = msg.header.stamp
        t = st.sec + 1e-9 * st.nanosec
        if not self.truth or t > self.truth[-1][0]:          # lockstep may re-send a sample
            self.truth.append((t, msg.position[1], msg.velocity[1]))

    def _on_demand(self, msg):
        self.demand = msg.data

    def _on_position(self, msg):
        self.position = msg.data
        if self.demand is not None and math.isfinite(msg.data):
            self.errors.append(abs(self.demand - msg.data))

    def _on_estimate(self, msg):
        if len(msg.effort) >= 2:
            self.friction_estimate = msg.effort[1]

    def _on_diagnostics(self, msg):
        for st in msg.status:
            if "valve driver" not in st.name or not st.name.startswith(self.node.get_namespace() + "/"):
                continue
            self.level = st.level[0] if isinstance(st.level, bytes) else int(st.level)
            self.message = st.message
            self.health = {kv.key: kv.value for kv in st.values}
            # the worst status counts from the first OK on: "waiting for a valid demand" before
            # the demand node starts is the start-up, not a degradation (faults always count)
            self.armed = self.armed or self.level == 0
            if (self.armed or self.level == 2) and self.level > self.worst_level:
                self.worst_level = self.level
            if self.level == 2 and st.message not in self.fault_messages:
                self.fault_messages.append(st.message)

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=max(0.0, min(0.05, end - time.monotonic())))

    def controller_ready(self) -> bool:
        return self.level is not None

    def call_trigger(self, service: str):
        from std_srvs.srv import Trigger
        client = self.node.create_client(Trigger, service)
        if not client.wait_for_service(timeout_sec=2.0):
            return None
        return client.call_async(Trigger.Request())

    def set_parameters(self, node_name: str, params: dict):
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter
        client = self.node.create_client(SetParameters, f"{node_name}/set_parameters")
        if not client.wait_for_service(timeout_sec=2.0):
            return None
        req = SetParameters.Request(parameters=[Parameter(k, value=v).to_parameter_msg() for k, v in params.items()])
        return client.call_async(req)

    def status_line(self, t: float) -> str:
        def num(x, fmt):
            return format(x, fmt) if isinstance(x, (int, float)) and math.isfinite(x) else "  n/a"
        err = self.demand - self.position if self.demand is not None and self.position is not None else None
        current = _float(self.health.get("current_a"))
        faults = self.health.get("faults", "none")
        return (f"t {t:6.2f} s | demand {num(self.demand, '6.2f')} % | position {num(self.position, '6.2f')} % | "
                f"error {num(err, '+6.3f')} % | current {num(current, '6.2f')} A | friction est "
                f"{num(self.friction_estimate, '5.2f')} N*m | {self.health.get('state', 'starting')} | "
                f"faults {faults}")

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.rclpy.shutdown(context=self.context)


def _float(text):
    try:
        return float(text)
    except (TypeError, ValueError):
        return None


# ---------------------------------------------------------------------------------- running
def run(plan: SuitePlan, namespace: str = "/fuel_valve", bag: Path | None = None, run_dir: Path | None = None,
        out=sys.stdout, status_period_s: float = 1.0, bag_storage: str = "mcap", env: dict | None = None,
        record_truth: bool = False) -> dict:
    """Start the suite, run ``plan`` to its end, stop it.  Returns a summary dict."""
    lockstep = bool(plan.params["plant"].get("lockstep"))
    if env and "ROS_DOMAIN_ID" in env:
        os.environ["ROS_DOMAIN_ID"] = str(env["ROS_DOMAIN_ID"])
    monitor = Monitor(namespace, lockstep, record_truth)
    summary: dict = {"lockstep": lockstep, "duration_s": plan.duration_s, "namespace": monitor.node.get_namespace()}
    wall0 = time.monotonic()
    try:
        with Suite(plan, namespace, run_dir, bag, bag_storage, env) as suite:
            summary["run_dir"] = str(suite.run_dir)
            if bag:
                suite.start_recorder(None if lockstep else REPORT_TOPICS)
            if lockstep:                    # profile time = simulated time: all at once
                suite.start(NODES)
            else:                           # profile time starts with the demand node: start it
                suite.start(("plant", "controller"))       # once the loop runs
                if not _wait(monitor, suite, monitor.controller_ready):
                    return _failed(summary, suite, "the controller did not come up", out)
                suite.start(("demand",))
            t_start = None
            next_status = 0.0
            events = list(plan.events)
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
                while events and events[0].at_s <= t:
                    pending.append(_send_event(monitor, namespace, events.pop(0), out))
                if t >= next_status:
                    print(monitor.status_line(t), file=out, flush=True)
                    next_status += status_period_s
                if t >= plan.duration_s - 1e-9:
                    break
                if lockstep and time.monotonic() - wall0 > STARTUP_TIMEOUT_S + 50.0 * plan.duration_s:
                    return _failed(summary, suite, "lockstep run stalled", out)
            monitor.spin_for(0.2)                   # let the last diagnostics arrive
            summary["wall_time_s"] = round(time.monotonic() - wall0, 2)
            codes = suite.stop()
            summary["exit_codes"] = codes
            summary["loop"] = suite.loop_statistics()
    finally:
        final = monitor.status_line(plan.duration_s)
        summary.update(final_status=final, worst_level=monitor.worst_level, faults=monitor.fault_messages,
                       final_error_pct=(monitor.demand - monitor.position)
                       if monitor.demand is not None and monitor.position is not None else None,
                       health=monitor.health, truth=monitor.truth)
        monitor.close()
    summary["ok"] = all(c in (0, -signal.SIGINT) for c in summary.get("exit_codes", {}).values())
    return summary


def _wait(monitor: Monitor, suite: Suite, ready, timeout_s: float = STARTUP_TIMEOUT_S) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        monitor.spin_for(0.05)
        if ready():
            return True
        if suite.failed():
            return False
    return False


def _failed(summary: dict, suite: Suite, why: str, out) -> dict:
    summary.update(ok=False, error=why)
    print(f"fuel_valve_demo: {why}", file=out, flush=True)
    for name in suite.procs:
        tail = suite.log_tail(name)
        if tail:
            print(f"--- {name} log (last lines) ---\n{tail}", file=out, flush=True)
    return summary


def _send_event(monitor: Monitor, namespace: str, ev, out):
    ns = "/" + namespace.strip("/")
    print(f"event at {ev.at_s:g} s: {ev.action} {ev.params or ''}", file=out, flush=True)
    if ev.action in ("trip", "reset"):
        return monitor.call_trigger(f"{ns}/controller/{ev.action}")
    node = "plant" if ev.action == "set_plant" else "controller"
    return monitor.set_parameters(f"{ns}/{node}", ev.params)


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
        print(f"loop: the plant ticked {loop['ticks']} times at 1 kHz; in {100 * loop['missed_fraction']:.2f} % of "
              f"the ticks the controller's answer to the previous sample had not arrived yet (missed periods: the "
              f"plant held the old current); sample -> command round trip median {loop['rtt_median_ms']:.3f} ms, "
              f"99 % within {loop['rtt_p99_ms']:.3f} ms (a period is 1 ms)", file=out)
    if loop and summary["lockstep"]:
        print(f"loop: {loop.get('commands')} control periods in lockstep", file=out)
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
    args = parser.parse_args(argv)
    try:
        if args.controller is not None and args.controller not in MODES:
            raise ConfigError(f"unknown controller mode {args.controller!r}; allowed: {', '.join(MODES)}")
        over = parse_overrides(args.set, ("plant", "controller"))
        scenario = load_scenario(args.scenario) if args.scenario else None
        plan = plan_for(scenario, args.lockstep, args.controller, args.duration, over.get("plant"),
                        over.get("controller"))
        if args.bag and Path(args.bag).exists():
            raise ConfigError(f"bag {args.bag} exists already; choose another --bag")
    except ConfigError as exc:
        print(f"fuel_valve_demo: {exc}", file=sys.stderr)
        return 2
    print(f"fuel_valve_demo: {plan.description or args.scenario} | "
          f"{'lockstep' if args.lockstep else 'real time 1 kHz'} | {plan.duration_s:g} s"
          + (f" | recording {args.bag}" if args.bag else ""), flush=True)
    summary = run(plan, args.namespace, Path(args.bag) if args.bag else None,
                  Path(args.run_dir) if args.run_dir else None, bag_storage=args.storage)
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
        return report.main([args.bag, "--plot", plot])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
