"""Start and stop the node processes of one run: the one place that knows how.

:class:`Launcher` starts the plant, controller, demand and recorder nodes of a
:class:`~.run_plan.RunPlan` as processes (the stand-in for ``ros2 launch`` on machines with
only the PyPI ROS wheels; ``launch/fuel_valve.launch.py``, which imports only launch API,
writes the same lockstep wiring and ``test/test_launch_file.py`` checks it against
:func:`lockstep_parameters` and :func:`clock_participants` here):

* command: the installed executable (:func:`executable`), ``--ros-args``, the namespace, the
  node's ``config/*.yaml`` and a parameter file with the plan's node parameters on top;
* lockstep wiring: the plant owns the clock (``use_sim_time`` false) and waits for
  ``lockstep_participants`` distinct clock subscribers -- controller, demand, recorder
  and the run's observers (the demo's monitor, a test's gate node) --, every other node runs
  on simulated time.  Each valve has a clock of its own: ``/clock`` is remapped to
  ``/<namespace>/clock`` (:func:`clock_topic`, :func:`clock_remap`) for every node of the run,
  so two valves side by side in lockstep neither tick on each other's clock nor count each
  other's participants;
* environment: the caller's plus ``env`` (e.g. ``ROS_DOMAIN_ID``), unbuffered output;
* recording wiring: with a bag, the plant, controller and demand hold their first publish until
  the recorder has matched (:func:`recording_parameters`), so the bag holds everything they send;
* OS scheduling (:class:`Scheduling`): in real time the loop's two processes, plant and
  controller, run SCHED_FIFO where the OS permits it (root, CAP_SYS_NICE or an RLIMIT_RTPRIO),
  the demand node and the recorder SCHED_FIFO below them, so on a busy machine the 1 kHz loop
  is served first and the nodes it depends on next; optionally niceness and CPU affinity per
  process.  What the OS
  refuses (SCHED_FIFO for an unprivileged user, a CPU that does not exist) is printed and the
  node runs at normal priority: never a failed start;
* logs: ``<run_dir>/<node>.log`` (stdout and stderr);
* stop: SIGINT (publishers first, the recorder last, so the bag holds all they sent), then SIGTERM,
  then SIGKILL for what hangs; the exit codes are returned.

No rclpy and no simulator imports here (only subprocesses and parameter files).
"""
from __future__ import annotations

import json
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
from typing import TYPE_CHECKING, Mapping

import yaml

from ..common import contract
from ..common.config_dir import default_config_dir
from ..common.paramspec import ALL_TOPICS

if TYPE_CHECKING:                       # no simulator import for a process starter
    from .run_plan import RunPlan

#: node -> module, for running from a source tree without console scripts
MODULES = {"plant": "fuel_valve_plant.ros.plant_node", "controller": "fuel_valve_control.ros.controller_node",
           "demand": "fuel_valve_control.ros.demand_node", "recorder": "fuel_valve_control.tools.recorder"}
#: nodes that subscribe to /clock in lockstep (besides observers); the plant publishes it
CLOCK_NODES = ("controller", "demand")
#: nodes whose publishing waits for the run's recorder to match (:func:`recording_parameters`)
PUBLISHING_NODES = ("plant", "controller", "demand")
#: stop order: the publishers first (demand, then the loop), the recorder last, so it drains and
#: records everything they published before it closes the bag
STOP_ORDER = ("demand", "controller", "plant", "recorder")
#: exit codes of a node stopped on request (rclpy's SIGINT handling: 0, or killed by SIGINT)
CLEAN_EXIT_CODES = (0, -signal.SIGINT)
#: a lockstep participant that does nothing but subscribe to /clock (a test's start gate)
GATE_SCRIPT = """
import sys
import rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter
rclpy.init(args=sys.argv)
node = Node("lockstep_gate", parameter_overrides=[Parameter("use_sim_time", value=True)])
try:
    rclpy.spin(node)
except BaseException:
    pass
"""


#: default niceness: the demo's own process (its monitor, :func:`nice_own_threads`), whose lag
#: only delays a status line.  Not the demand node (its silence trips the drive:
#: ``demand_timeout_s`` 0.5 s) nor the recorder (a starved one loses messages): niced on a
#: loaded machine both were starved that long (a nice-5 process gets a third of a nice-0
#: one's share); where SCHED_FIFO is permitted they run it below the loop (:data:`DEFAULT_FIFO`)
DEFAULT_NICE = {"monitor": 5}
#: processes that run SCHED_FIFO in real time by default, where permitted, and their priority
#: (1-99): the loop's two at 10, the demand node and the recorder below them at 5 (they yield
#: to the loop, and outrank only normal processes).  Measured (benchmarks/ros_loop.py --fifo;
#: README): on a loaded machine (load average 17-38 on 2 cores) the only lever that kept the
#: plant's ticks on time (tick lateness p99 0.05-0.1 ms against 6-8 ms at normal priority,
#: missed periods 0.08-0.4 % against 19-37 %); at normal priority, or niced, the demand node was
#: starved into a demand-stale trip (0.5 s) and the recorder lost messages.  Every priority
#: is below the kernel's own real-time threads (50), and the kernel's real-time throttling
#: (95 % of each second by default) still leaves the machine to the rest should one spin.
DEFAULT_FIFO = {"plant": 10, "controller": 10, "demand": 5, "recorder": 5}
#: SCHED_FIFO priority of a name given without one (``--fifo plant``)
DEFAULT_FIFO_PRIORITY = 10


@dataclass(frozen=True)
class Scheduling:
    """OS scheduling of a run's processes (Linux; each lever is optional and unprivileged
    where it can be):

    * ``nice``: process name -> niceness added to the launcher's own (0..19; a positive value
      lowers the priority).  Names: plant, controller, demand, recorder, gate, and ``monitor``
      for an in-process observer that applies it to itself (:func:`nice_own_threads`);
    * ``affinity``: process name -> CPUs it may run on (``os.sched_setaffinity``);
    * ``fifo``: process name -> SCHED_FIFO priority (1-99) in real time (never in lockstep,
      where the processes run flat out, one after the other); needs root, CAP_SYS_NICE or an
      RLIMIT_RTPRIO: refused, it is reported and the process runs at normal priority.

    Applied to a process right after it is started, before its interpreter starts threads
    (threads inherit niceness, affinity and policy)."""

    nice: Mapping[str, int] = field(default_factory=lambda: dict(DEFAULT_NICE))
    affinity: Mapping[str, tuple[int, ...]] = field(default_factory=dict)
    fifo: Mapping[str, int] = field(default_factory=lambda: dict(DEFAULT_FIFO))

    @classmethod
    def off(cls) -> "Scheduling":
        """Every process at the launcher's own priority and policy, on every CPU."""
        return cls(nice={}, fifo={})

    def describe(self) -> dict:
        """What is set, JSON-ready (the benchmarks print it)."""
        return {"nice": dict(self.nice), "affinity": {k: list(v) for k, v in self.affinity.items()},
                "fifo": dict(self.fifo)}

    def apply(self, name: str, pid: int, real_time: bool = True) -> list[str]:
        """Apply this scheduling to process ``pid`` (node ``name``; ``real_time`` False: a
        lockstep run, no SCHED_FIFO); returns what the OS refused (one sentence each; empty:
        all applied)."""
        refused = []
        n = int(self.nice.get(name, 0))
        if n:
            try:
                os.setpriority(os.PRIO_PROCESS, pid, os.getpriority(os.PRIO_PROCESS, pid) + n)
            except (OSError, AttributeError) as exc:
                refused.append(f"niceness +{n} for {name} refused ({exc})")
        cpus = self.affinity.get(name)
        if cpus:
            try:
                os.sched_setaffinity(pid, set(cpus))
            except (OSError, AttributeError, ValueError) as exc:
                refused.append(f"CPU affinity {sorted(cpus)} for {name} refused ({exc})")
        if real_time and name in self.fifo:
            try:
                os.sched_setscheduler(pid, os.SCHED_FIFO, os.sched_param(self.fifo[name]))
            except (OSError, AttributeError) as exc:
                refused.append(f"SCHED_FIFO {self.fifo[name]} for {name} refused ({exc}): normal priority")
        return refused


def parse_scheduling(nice: str | None = None, affinity: str | None = None, fifo: str | None = None) -> Scheduling:
    """A :class:`Scheduling` from command-line text: ``nice`` ``"demand=5,recorder=5"``
    (None: :data:`DEFAULT_NICE`, ``""`` or ``"off"``: none), ``affinity``
    ``"plant=0,controller=1"`` (CPUs separated by ``+``: ``"demand=0+1"``; None: none), ``fifo``
    ``"plant,controller=10,demand=5"`` (a name alone: :data:`DEFAULT_FIFO_PRIORITY`; None:
    :data:`DEFAULT_FIFO`, ``""`` or ``"off"``: none).  ValueError on malformed text."""
    def pairs(text, default=None):
        out = {}
        for item in filter(None, (t.strip() for t in text.split(","))):
            key, sep, value = item.partition("=")
            if not key.strip() or (not sep and default is None):
                raise ValueError(f"expected name=value, got {item!r}")
            out[key.strip()] = value.strip() if sep else default
        return out
    nice_map = dict(DEFAULT_NICE) if nice is None else {} if nice.strip() in ("", "off") else \
        {k: int(v) for k, v in pairs(nice).items()}
    if any(not 0 <= v <= 19 for v in nice_map.values()):
        raise ValueError(f"niceness must be 0..19 (unprivileged processes cannot raise priority): {nice_map}")
    aff = {k: tuple(int(c) for c in v.split("+")) for k, v in pairs(affinity or "").items()}
    fifo_map = dict(DEFAULT_FIFO) if fifo is None else {} if fifo.strip() in ("", "off") else \
        {k: int(v) for k, v in pairs(fifo, str(DEFAULT_FIFO_PRIORITY)).items()}
    if any(not 1 <= v <= 99 for v in fifo_map.values()):
        raise ValueError(f"SCHED_FIFO priorities are 1..99: {fifo_map}")
    return Scheduling(nice=nice_map, affinity=aff, fifo=fifo_map)


def add_scheduling_arguments(parser) -> None:
    """The ``--nice`` / ``--affinity`` / ``--fifo`` options of the tools that start a run
    (:func:`scheduling_from_args` reads them)."""
    parser.add_argument("--nice", default=None, metavar="NAME=N,...",
                        help="niceness of processes (plant, controller, demand, recorder, monitor), 'off' for "
                             f"none (default: {','.join(f'{k}={v}' for k, v in DEFAULT_NICE.items())})")
    parser.add_argument("--affinity", default=None, metavar="NAME=CPU[+CPU],...",
                        help="CPU affinity of processes, e.g. plant=0,controller=1 (default: none)")
    parser.add_argument("--fifo", default=None, metavar="NAME[=PRIO],...",
                        help="run these processes SCHED_FIFO in real time, 'off' for none (needs root or "
                             "CAP_SYS_NICE; refused: normal priority; default: "
                             f"{','.join(f'{k}={v}' for k, v in DEFAULT_FIFO.items())})")


def scheduling_from_args(args) -> Scheduling:
    """:class:`Scheduling` from :func:`add_scheduling_arguments`' options (ValueError: malformed)."""
    return parse_scheduling(args.nice, args.affinity, args.fifo)


def nice_own_threads(increment: int) -> list[str]:
    """Lower the priority of every thread of this process by ``increment`` (an in-process
    observer such as the demo's monitor, after it has started the run's processes: a process
    started later from a niced thread would inherit the niceness and could not get rid of it).
    Linux applies niceness per thread, so each thread of ``/proc/self/task`` is set; elsewhere
    the process.  Returns what was refused (empty: applied)."""
    if increment <= 0:
        return []
    try:
        tids = [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        tids = [0]
    refused = []
    for tid in tids:
        try:
            os.setpriority(os.PRIO_PROCESS, tid, os.getpriority(os.PRIO_PROCESS, tid) + increment)
        except OSError as exc:
            if tid == os.getpid() or tid == 0:
                refused.append(f"niceness +{increment} refused ({exc})")
    return refused


def clock_participants(record: bool, observers: int = 0) -> int:
    """Distinct nodes subscribed to /clock in a lockstep run (what the plant waits for):
    controller and demand, the recorder when recording, plus ``observers``."""
    return len(CLOCK_NODES) + (1 if record else 0) + observers


def recording_parameters(node: str, record: bool, topics: list[str] | None = None) -> dict:
    """Recording wiring of ``node``: with a recorder in the run (recording ``topics``, None: its
    default, every topic), the publishing nodes hold their first publish until it has matched
    those of their topics (``recorded_topics``, see
    :class:`fuel_valve_control.ros.interface.RecorderGate`), so the bag loses nothing to discovery."""
    if not record or node not in PUBLISHING_NODES:
        return {}
    return {"recorded_topics": ",".join(topics) if topics else ALL_TOPICS}


def clock_topic(namespace: str) -> str:
    """The simulated clock of the valve in ``namespace`` (lockstep): ``/<namespace>/clock``
    (``/clock`` in the root namespace)."""
    ns = namespace.strip("/")
    return f"/{ns}/clock" if ns else contract.CLOCK


def clock_remap(namespace: str, lockstep: bool) -> list[str]:
    """ROS arguments that give a node of the valve in ``namespace`` that valve's clock: the
    remapping of ``/clock`` (which rclpy's time source and the suite's nodes use) to
    :func:`clock_topic`; none in real time (no simulated clock)."""
    return ["-r", f"{contract.CLOCK}:={clock_topic(namespace)}"] if lockstep else []


def lockstep_parameters(node: str, lockstep: bool, participants: int) -> dict:
    """Clock wiring of ``node`` (plant | controller | demand | recorder) for a run: empty in
    real time (ROS default: wall clock); in lockstep the plant publishes /clock and waits for
    ``participants``, everything else runs on it."""
    if not lockstep:
        return {}
    if node == "plant":
        return {"use_sim_time": False, "lockstep_participants": participants}
    return {"use_sim_time": True}


def executable(name: str) -> list[str]:
    """Command that starts node ``name``: the installed executable next to this Python (the
    venv's console scripts), on PATH, or in a colcon install's lib/fuel_valve; else the module."""
    here = Path(sys.executable).parent / name
    if here.is_file():
        return [str(here)]
    found = shutil.which(name)
    if found:
        return [found]
    return [sys.executable, "-m", MODULES[name]]


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


class Launcher:
    """The node processes of one run.  Use as a context manager: every process is stopped on
    exit, whatever happened.

    ``observers``: how many /clock subscribers besides the nodes the caller brings (the
    demo's monitor node, a test's :meth:`start_gate`); they count as lockstep participants.
    ``bag``: the recorder's output (:meth:`start_recorder`); it counts as a participant too.
    ``scheduling``: OS priorities of the processes (:class:`Scheduling`; None:
    :meth:`Scheduling.off`, the launcher's own).  The tools that run the loop for a user or a
    measurement -- ``fuel_valve_demo`` (the main job), ``benchmarks/ros_loop.py`` -- pass
    :class:`Scheduling`'s default (SCHED_FIFO loop where permitted); the node tests keep the
    launcher's priority (with a SCHED_FIFO controller, test_lifecycle_nodes' enable-rule test
    saw non-zero commands through its whole "deactivated" hold -- not investigated yet).
    """

    def __init__(self, plan: "RunPlan", namespace: str = "/fuel_valve", run_dir: Path | None = None,
                 bag: Path | None = None, bag_storage: str = "mcap", env: dict | None = None, observers: int = 0,
                 scheduling: Scheduling | None = None):
        self.plan = plan
        self.namespace = "/" + namespace.strip("/")
        self.run_dir = Path(run_dir) if run_dir else Path(tempfile.mkdtemp(prefix="fuel_valve_run_"))
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.bag = Path(bag) if bag else None
        self.bag_storage = bag_storage
        self.env = dict(os.environ, **{k: str(v) for k, v in (env or {}).items()})
        self.env.setdefault("PYTHONUNBUFFERED", "1")
        self.observers = observers
        self.scheduling = Scheduling.off() if scheduling is None else scheduling
        #: what the OS refused of :attr:`scheduling` (also printed to stderr)
        self.scheduling_refused: list[str] = []
        self.procs: dict[str, subprocess.Popen] = {}
        #: what the recorder records (:meth:`start_recorder`; None: every topic)
        self.record_topics: list[str] | None = None
        self.logs: dict[str, Path] = {}
        self._node_params = plan.node_parameters()

    @property
    def lockstep(self) -> bool:
        return self.plan.lockstep

    def clock_participants(self) -> int:
        return clock_participants(self.bag is not None, self.observers)

    def node_parameters(self, name: str) -> dict:
        """What ``name``'s parameter file holds: the plan's node parameters and the clock wiring."""
        params = dict(self._node_params.get(name, {}))
        params.update(lockstep_parameters(name, self.lockstep, self.clock_participants()))
        params.update(recording_parameters(name, self.bag is not None, self.record_topics))
        return params

    def start(self, names=None) -> None:
        """Start node processes ``names`` (default: the plan's plant, controller and demand)."""
        cfg = default_config_dir()
        for name in names or tuple(self._node_params):
            self._spawn(name, self.node_parameters(name), cfg / f"{name}.yaml")

    def start_recorder(self, topics: list[str] | None = None) -> None:
        """The recorder writing :attr:`bag` (``topics`` None: every topic of the suite)."""
        if self.bag is None:
            raise ValueError("start_recorder needs the launcher's bag")
        params = {"output": str(self.bag), "storage": self.bag_storage}
        params.update(lockstep_parameters("recorder", self.lockstep, self.clock_participants()))
        if topics:
            params["topics"] = topics
            self.record_topics = list(topics)
        self._spawn("recorder", params, None)

    def start_gate(self) -> None:
        """A do-nothing /clock subscriber (one of the ``observers``): started last, after the
        nodes had time to match, it lets a lockstep plant begin (its participant count is
        judged from the ROS graph, which can run ahead of publisher/subscriber matching)."""
        self._popen("gate", [sys.executable, "-c", GATE_SCRIPT, "--ros-args", "-r", f"__ns:={self.namespace}"]
                    + clock_remap(self.namespace, self.lockstep))

    def _spawn(self, name: str, params: dict, base_file: Path | None) -> None:
        pfile = self.run_dir / f"{name}.params.yaml"
        write_params_file(pfile, params)
        cmd = executable(name) + ["--ros-args", "-r", f"__ns:={self.namespace}"] + clock_remap(self.namespace,
                                                                                                self.lockstep)
        if base_file is not None:
            cmd += ["--params-file", str(base_file)]
        cmd += ["--params-file", str(pfile)]
        self._popen(name, cmd)

    def _popen(self, name: str, cmd: list[str]) -> None:
        log = self.run_dir / f"{name}.log"
        self.logs[name] = log
        with open(log, "w") as fh:
            self.procs[name] = subprocess.Popen(cmd, stdout=fh, stderr=subprocess.STDOUT, env=self.env,
                                                stdin=subprocess.DEVNULL)
        # Popen returns once the child has exec'd: its interpreter is still starting, no thread yet
        for why in self.scheduling.apply(name, self.procs[name].pid, real_time=not self.lockstep):
            self.scheduling_refused.append(why)
            print(f"launcher: {why}", file=sys.stderr, flush=True)

    def failed(self) -> list[str]:
        """Nodes that exited on their own."""
        return [n for n, p in self.procs.items() if p.poll() is not None]

    def log(self, name: str) -> str:
        try:
            return self.logs[name].read_text()
        except (KeyError, OSError):
            return ""

    def log_tail(self, name: str, lines: int = 15) -> str:
        return "\n".join(self.log(name).splitlines()[-lines:])

    def wait_for_log(self, name: str, text: str, timeout_s: float = 40.0) -> None:
        """Wait until ``text`` appears in ``name``'s log; AssertionError (with the log) when
        the node exits or the time runs out."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if text in self.log(name):
                return
            if self.procs[name].poll() is not None:
                raise AssertionError(f"{name} exited ({self.procs[name].returncode}):\n{self.log(name)}")
            time.sleep(0.05)
        raise AssertionError(f"{name}: no {text!r} within {timeout_s} s:\n{self.log(name)}")

    def stop(self, names=None, grace_s: float = 10.0) -> dict:
        """Stop ``names`` (default: all in :data:`STOP_ORDER`): SIGINT, after ``grace_s``
        SIGTERM, after 2 s more SIGKILL.  Returns ``{node: exit code}``."""
        if names is None:
            names = list(STOP_ORDER) + [n for n in self.procs if n not in STOP_ORDER]
        codes = {}
        for name in names:
            proc = self.procs.get(name)
            if proc is None:
                continue
            if proc.poll() is None:
                for sig, wait_s in ((signal.SIGINT, grace_s), (signal.SIGTERM, 2.0), (signal.SIGKILL, None)):
                    proc.send_signal(sig)
                    try:
                        proc.wait(timeout=wait_s)
                        break
                    except subprocess.TimeoutExpired:
                        continue
            codes[name] = proc.returncode
        return codes

    def loop_statistics(self) -> dict | None:
        """The plant's loop statistics line (printed when it exits)."""
        m = re.search(r"loop statistics: (\{.*\})", self.log("plant"))
        if not m:
            return None
        try:
            return yaml.safe_load(m.group(1).replace("'", '"'))
        except yaml.YAMLError:
            return None

    def published_counts(self) -> dict[str, dict[str, int]]:
        """``{topic: {"published": n, "before_match": m}}`` summed over the publishing nodes'
        exit lines (node_runner: every message each sent, and how many before the run's
        recorder had matched), topics fully qualified in this run's namespace."""
        out: dict[str, dict[str, int]] = {}
        for name in PUBLISHING_NODES:
            log = self.log(name)
            for key, label in (("published", "published"), ("before_match", "published before the recorder matched")):
                found = re.findall(rf"\] {label}: (\{{.*\}})", log)
                for topic, n in (json.loads(found[-1]) if found else {}).items():
                    full = topic if topic.startswith("/") else f"{self.namespace}/{topic}"
                    entry = out.setdefault(full, {"published": 0, "before_match": 0})
                    entry[key] += n
        return out

    def recording_losses(self) -> dict:
        """Per topic, what the nodes published against what the bag's metadata.yaml holds (call
        after :meth:`stop`): ``lost`` = published - in bag - published before the recorder
        matched (never below 0: a real loss), ``startup_lost`` = what the bag misses of the
        messages published before the match.  Also the totals and the recorder's own queue
        drops (its closing summary)."""
        meta = yaml.safe_load((self.bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
        in_bag = {t["topic_metadata"]["name"]: t["message_count"] for t in meta["topics_with_message_count"]}
        topics = {}
        for topic, c in sorted(self.published_counts().items()):
            if topic not in in_bag:
                continue                    # not recorded (a topic list without it)
            missing = max(0, c["published"] - in_bag[topic])
            topics[topic] = dict(c, in_bag=in_bag[topic], startup_lost=min(c["before_match"], missing),
                                 lost=max(0, missing - c["before_match"]))
        dropped = re.findall(r"closed: \d+ messages, (\d+) dropped", self.log("recorder"))
        return {"topics": topics, "lost": sum(v["lost"] for v in topics.values()),
                "startup_lost": sum(v["startup_lost"] for v in topics.values()),
                "queue_dropped": int(dropped[-1]) if dropped else None, "bag_messages": meta["message_count"]}

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop()
        return False
