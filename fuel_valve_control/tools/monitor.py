"""The demo's watcher: an in-process rclpy node that follows a running suite and acts as its
supervisor for scenario events.

It subscribes to the suite's demand, position feedback, friction estimate and
``/diagnostics`` (and, in lockstep, ``/clock`` once those have matched their publishers, so
it is one of the lockstep participants and the run starts only when it can watch),
keeps what the status line and the summary need (including the plant's latest loop
statistics), and sends scenario events through the controller's ``trip`` / ``reset``
services and the nodes' parameter services.

In real time it runs in the demo's process next to the 1 kHz loop on a 2-core machine, so it
is cheap by construction: it samples instead of following every message.  The demand (200 Hz), position
and estimate (100 Hz each) and ``/clock`` (every lockstep period) are read with history depth
1, and :meth:`Monitor.spin_for` sleeps between takes (the demo's loop takes every 20 ms):
each take finds at most the newest sample per topic, which is all a status line once a second
needs.  Following every message cost this process a wake-up per message, ~400 a second:
8 % of a core against 1-3 % sampled (benchmarks/ros_loop.py --main, ``monitor_cpu_fraction``).
The demand is read BEST_EFFORT: that matches a reliable publisher (the demand node) and a
supervisor publishing best-effort alike (the controller hears both since h24u; a reliable
subscription would show no demand from such a supervisor).  ``/diagnostics`` keeps its depth (every status counts for the worst level).  Service and
parameter calls are asynchronous: in lockstep an event lands within a few control periods of
its time, not exactly on it (the offline simulator applies events exactly).
"""
from __future__ import annotations

import math
import time

from ..common.timebase import stamp_seconds
from .scenarios import TRIGGER_ACTIONS

#: time between two takes of the monitor's subscriptions, s (events due meanwhile are sent at
#: the next take: at most this late in real time)
POLL_S = 0.05


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
        from .launcher import clock_remap
        # the valve's own clock in lockstep, as its nodes have it (launcher.clock_remap)
        cli = ["--ros-args", *clock_remap(namespace, True)] if lockstep else None
        # no parameter services: nobody sets the monitor's parameters, and each service is one
        # more entity in every wait of its executor
        self.node = rclpy.create_node("suite_monitor", namespace=namespace, context=self.context, cli_args=cli,
                                      start_parameter_services=False)
        self.lockstep = lockstep
        self.sim_time = None
        self.demand = None
        self.position = None
        self.friction_estimate = None
        self.health: dict = {}
        self.level = None
        self.message = ""
        self.worst_level = 0
        self.armed = False                         # a first OK status was seen
        self.fault_messages: list[str] = []
        #: the plant's latest loop statistics (its "loop" status on /diagnostics: ticks, missed,
        #: round trip ...), values as published (text)
        self.loop: dict[str, str] = {}
        self.loop_reports = 0                      # how many of them arrived
        #: the newest loop report's header stamp (s; in real time the plant's system clock)
        self.loop_stamp: float | None = None
        self._taken = 0                            # callbacks run (spin_for drains until none)
        n = self.node
        from rclpy.qos import HistoryPolicy, QoSProfile
        # sampled topics: the newest sample only (module docstring); reliability and durability
        # as the publishers offer them
        latest = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ri.TELEMETRY_QOS.reliability,
                            durability=ri.TELEMETRY_QOS.durability)
        self._latest_qos = latest
        from rclpy.qos import ReliabilityPolicy
        # the demand: best effort, which every publisher matches (module docstring)
        any_publisher = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.BEST_EFFORT,
                                   durability=ri.TELEMETRY_QOS.durability)
        #: (subscription, publishers it must have matched) before a lockstep run may start
        self._watch = [(ri.quiet_subscription(n, Float64, contract.DEMAND, self._on_demand, any_publisher), 1),
                       (ri.quiet_subscription(n, Float64, contract.POSITION, self._on_position, latest), 1),
                       (ri.quiet_subscription(n, JointState, contract.ESTIMATE, self._on_estimate, latest), 1),
                       # plant and controller
                       (ri.quiet_subscription(n, DiagnosticArray, contract.DIAGNOSTICS, self._on_diagnostics), 2)]
        self._clock_type = Clock
        self._clock_sub = None
        #: (stamp s, true valve angle rad, true valve velocity rad/s) per plant sample
        self.truth: list[tuple[float, float, float]] = []
        if record_truth:
            from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
            deep = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE)
            self._watch.append((ri.quiet_subscription(n, JointState, contract.JOINT_STATES, self._on_truth, deep), 1))
        self.executor = rclpy.executors.SingleThreadedExecutor(context=self.context)
        self.executor.add_node(n)

    def _on_clock(self, msg):
        self._taken += 1
        self.sim_time = stamp_seconds(msg.clock.sec, msg.clock.nanosec)

    def _on_truth(self, msg):
        self._taken += 1
        st = msg.header.stamp
        t = stamp_seconds(st.sec, st.nanosec)
        if not self.truth or t > self.truth[-1][0]:          # lockstep may re-send a sample
            self.truth.append((t, msg.position[1], msg.velocity[1]))

    def _on_demand(self, msg):
        self._taken += 1
        self.demand = msg.data

    def _on_position(self, msg):
        self._taken += 1
        self.position = msg.data

    def _on_estimate(self, msg):
        self._taken += 1
        if len(msg.effort) >= 2:
            self.friction_estimate = msg.effort[1]

    def _on_diagnostics(self, msg):
        self._taken += 1
        for st in msg.status:
            if st.name == self._plant_loop_name:
                self.loop = {kv.key: kv.value for kv in st.values}
                self.loop_reports += 1
                self.loop_stamp = stamp_seconds(msg.header.stamp.sec, msg.header.stamp.nanosec)
                continue
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

    @property
    def _plant_loop_name(self) -> str:
        return f"{self.node.get_namespace().rstrip('/')}/plant: loop"

    def spin_for(self, seconds: float) -> None:
        """Real time: sleep ``seconds`` (:data:`POLL_S` at a time), taking what arrived after
        each sleep; at least one take (lockstep: every message as it comes).  A take runs every ready callback (service responses, the newest
        sample of each sampled topic, the queued diagnostics)."""
        end = time.monotonic() + seconds
        if self.lockstep:
            # lockstep follows every message, as it did: a sampling monitor lost the truth
            # samples of a lockstep run after its first 0.2 s (test_nodes), and nothing runs
            # against a real-time loop there
            while time.monotonic() < end:
                self._join_lockstep()
                self.executor.spin_once(timeout_sec=max(0.0, min(0.05, end - time.monotonic())))
            return
        while True:
            time.sleep(max(0.0, min(POLL_S, end - time.monotonic())))
            self._join_lockstep()
            self._take()
            if time.monotonic() >= end:
                return

    def _take(self, most: int = 100000) -> None:
        for _ in range(most):
            before = self._taken
            self.executor.spin_once(timeout_sec=0.0)
            if self._taken == before:             # nothing of ours was ready (or a service reply: the
                return                            # next take has the rest)

    def _join_lockstep(self) -> None:
        """Lockstep: subscribe to ``/clock`` -- which makes this node one of the participants
        the plant waits for -- only once the topics it watches have matched their publishers:
        a short run is over in a second or two, before a late match would show anything."""
        if not self.lockstep or self._clock_sub is not None:
            return
        if all(sub.get_publisher_count() >= n for sub, n in self._watch):
            from ..common import contract
            from ..ros import interface as ri
            self._clock_sub = ri.quiet_subscription(self.node, self._clock_type, contract.CLOCK, self._on_clock,
                                                    self._latest_qos)

    def loop_statistics(self) -> dict | None:
        """The plant's latest loop statistics (:attr:`loop`) as numbers; None before the first."""
        if not self.loop:
            return None
        out = {}
        for key, text in self.loop.items():
            try:
                out[key] = int(text) if text.lstrip("-").isdigit() else float(text)
            except ValueError:
                out[key] = text
        return out

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


def send_event(monitor: Monitor, namespace: str, ev, out):
    """Send a scenario event (a controller Trigger service, set_plant, set_controller) to the suite; returns the
    pending service future (None when the service is not there)."""
    ns = "/" + namespace.strip("/")
    print(f"event at {ev.at_s:g} s: {ev.action} {ev.params or ''}", file=out, flush=True)
    if ev.action in TRIGGER_ACTIONS:
        return monitor.call_trigger(f"{ns}/controller/{ev.action}")
    node = "plant" if ev.action == "set_plant" else "controller"
    return monitor.set_parameters(f"{ns}/{node}", ev.params)
