"""``ros2 run fuel_valve demand``: emulates the turbine supervisory stack's valve demand.

Publishes a profile (see :mod:`~fuel_valve_control.tools.profiles`) on ``demand`` (percent) or,
with ``output:=ma``, on ``demand_ma`` as a 4-20 mA signal (4 mA = closed, 20 mA = open).
Profile time starts when the node starts (at ROS time 0 in lockstep runs).

Parameters: ``profile`` (constant | step | ramp | sine | chirp | points | startup | csv) and
its numbers (``percent``, ``initial``, ``final``, ``at_s``, ``start_s``, ``duration_s``,
``offset``, ``amplitude``, ``frequency_hz``, ``f0_hz``, ``f1_hz``, ``points`` as a flat
[t0, p0, t1, p1, ...] list, ``interpolation``, ``csv_path``), ``output``,
``publish_rate_hz`` and ``lockstep`` (publish exactly once per ``/clock`` tick, so a lockstep
run sees one demand per control period).  Profile parameters may change at run time: the
new profile starts from the current time.
"""
from __future__ import annotations

import collections
import time

from rclpy.node import Node
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor, SetParametersResult

from ..common import contract
from . import interface as ri
from .node_runner import run_node

from ..tools.profiles import ProfileError, make_profile

#: lockstep: longest wall time a tick waits for the demand's subscribers to match; after it the
#: demand goes out anyway (a graph entry that never matches, e.g. a vanished node, must not stall)
MATCH_WAIT_S = 2.0

PROFILE_KEYS = {
    # name: (default, description)
    "percent": (20.0, "constant: demand, %"),
    "initial": (20.0, "step/ramp: start value, %"),
    "final": (22.0, "step/ramp: end value, %"),
    "at_s": (1.0, "step: time of the step, s"),
    "start_s": (1.0, "ramp/chirp: start time, s"),
    "duration_s": (10.0, "ramp/chirp: duration, s"),
    "offset": (50.0, "sine/chirp: centre, %"),
    "amplitude": (2.0, "sine/chirp: amplitude, %"),
    "frequency_hz": (1.0, "sine: frequency, Hz"),
    "f0_hz": (0.5, "chirp: start frequency, Hz"),
    "f1_hz": (20.0, "chirp: end frequency, Hz"),
}


class DemandNode(Node):
    def __init__(self, **kwargs):
        super().__init__("demand", **kwargs)
        self.declare_parameter("profile", "startup", ParameterDescriptor(
            description="constant | step | ramp | sine | chirp | points | startup | csv"))
        for key, (default, text) in PROFILE_KEYS.items():
            self.declare_parameter(key, default, ParameterDescriptor(description=text))
        self.declare_parameter("points", [0.0, 20.0], ParameterDescriptor(
            description="points: flat list t0, p0, t1, p1, ... (s, %)"))
        self.declare_parameter("interpolation", "linear", ParameterDescriptor(
            description="points/csv: linear | previous"))
        self.declare_parameter("csv_path", "", ParameterDescriptor(description="csv: file with t,percent rows"))
        self.declare_parameter("output", "percent", ParameterDescriptor(
            description="percent (topic demand) | ma (topic demand_ma, 4-20 mA)"))
        self.declare_parameter("publish_rate_hz", 200.0, ParameterDescriptor(
            description="publish rate in real time [Hz]",
            floating_point_range=[FloatingPointRange(from_value=1.0, to_value=10000.0, step=0.0)], read_only=True))
        self.declare_parameter("lockstep", False, ParameterDescriptor(
            description="publish once per /clock tick (deterministic lockstep runs)", read_only=True))
        try:
            self.profile = self._build({})
        except ProfileError as exc:
            raise SystemExit(f"demand: {exc}") from None
        self.output = self._output(self.get_parameter("output").value)
        from std_msgs.msg import Float64
        self._msg_type = Float64
        self.pub_pct = ri.quiet_publisher(self, Float64, contract.DEMAND)
        self.pub_ma = ri.quiet_publisher(self, Float64, contract.DEMAND_MA)
        self.t0 = None
        self.add_on_set_parameters_callback(self.on_set_parameters)
        self._pending_tick = None
        #: messages published per topic (reported at exit: benchmarks compare bag counts)
        self.published = collections.Counter()
        if self.get_parameter("lockstep").value:
            from rosgraph_msgs.msg import Clock
            ri.quiet_subscription(self, Clock, contract.CLOCK, self.on_clock, ri.TELEMETRY_QOS)
            from rclpy.clock import Clock as WallClock, ClockType
            # a wall-clock timer: simulated time stands still while the tick waits
            self.create_timer(0.01, self._answer_tick, clock=WallClock(clock_type=ClockType.STEADY_TIME))
        else:
            self.create_timer(1.0 / self.get_parameter("publish_rate_hz").value, self.publish)
        self.get_logger().info(f"demand up: profile {self.get_parameter('profile').value}, output {self.output}")

    def _output(self, value: str) -> str:
        if value not in ("percent", "ma"):
            raise SystemExit(f"demand: output must be 'percent' or 'ma', not {value!r}")
        return value

    def _build(self, overrides: dict):
        def get(name):
            return overrides[name] if name in overrides else self.get_parameter(name).value
        spec = {"type": get("profile"), "interpolation": get("interpolation")}
        spec.update({k: get(k) for k in PROFILE_KEYS})
        flat = list(get("points"))
        if len(flat) % 2:
            raise ProfileError("points must hold t, percent pairs")
        spec["points"] = list(zip(flat[0::2], flat[1::2]))
        spec["path"] = get("csv_path")
        return make_profile(spec)

    def now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def on_clock(self, msg) -> None:
        self._pending_tick = msg.clock.sec + 1e-9 * msg.clock.nanosec
        self._tick_since = time.monotonic()
        self._answer_tick()

    def _answer_tick(self) -> None:
        """Lockstep: publish the demand for the latest tick, but only once every subscriber
        discovery has seen is matched: the controller waits for this very message, and one
        published before its subscription matched would be lost (the run would stall)."""
        if self._pending_tick is None:
            return
        topic, pub = (contract.DEMAND, self.pub_pct) if self.output == "percent" else (contract.DEMAND_MA, self.pub_ma)
        seen = self.count_subscribers(topic)
        waited = time.monotonic() - self._tick_since
        if (seen == 0 or pub.get_subscription_count() < seen) and waited < MATCH_WAIT_S:
            return                          # the retry timer asks again shortly
        t, self._pending_tick = self._pending_tick, None
        self.publish(t)

    def publish(self, now: float | None = None) -> None:
        now = self.now_s() if now is None else now
        if self.t0 is None:
            self.t0 = now if not self.get_parameter("lockstep").value else 0.0
        pct = self.profile.value(now - self.t0)
        if self.output == "percent":
            self.pub_pct.publish(self._msg_type(data=float(pct)))
            self.published[contract.DEMAND] += 1
        else:
            self.pub_ma.publish(self._msg_type(data=contract.percent_to_ma(min(max(pct, 0.0), 100.0))))
            self.published[contract.DEMAND_MA] += 1

    def on_set_parameters(self, params) -> SetParametersResult:
        changes = {p.name: p.value for p in params}
        try:
            if "output" in changes:
                if changes["output"] not in ("percent", "ma"):
                    raise ProfileError("output must be 'percent' or 'ma'")
            profile = self._build(changes)
        except (ProfileError, TypeError, ValueError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        self.profile = profile
        self.output = changes.get("output", self.output)
        self.t0 = None                                  # the new profile starts now
        return SetParametersResult(successful=True)


def main(args=None) -> int:
    return run_node(DemandNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
