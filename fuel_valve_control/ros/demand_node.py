"""``ros2 run fuel_valve demand``: emulates the turbine supervisory stack's valve demand.

Publishes a profile (see :mod:`~fuel_valve_control.tools.profiles`) on ``demand`` (percent) or,
with ``output:=ma``, on ``demand_ma`` as a 4-20 mA signal (4 mA = closed, 20 mA = open).
Profile time starts when the node starts (at ROS time 0 in lockstep runs).

Parameters: :data:`~fuel_valve_control.tools.profiles.DEMAND_NODE_SPEC` (``profile`` and its
numbers, ``output``, ``publish_rate_hz`` and ``lockstep``: publish exactly once per ``/clock``
tick, so a lockstep run sees one demand per control period).  Profile parameters and
``output`` may change at run time: the new profile starts from the current time.
"""
from __future__ import annotations

import time

from rclpy.node import Node

from ..common import contract
from ..common.timebase import stamp_seconds
from . import interface as ri
from .node_runner import run_node

from ..common.paramspec import ConfigError
from ..tools.profiles import DEMAND_NODE_SPEC, ProfileError, profile_from_params

#: lockstep: longest wall time a tick waits for the demand's other subscribers to match once the
#: loop's controller has; after it the demand goes out anyway (a graph entry that never matches,
#: e.g. a vanished node, must not stall)
MATCH_WAIT_S = contract.LOCKSTEP_MATCH_WAIT_S


class DemandNode(Node):
    def __init__(self, **kwargs):
        super().__init__("demand", **kwargs)
        ri.declare_spec(self, DEMAND_NODE_SPEC)
        ri.unknown_overrides(self)           # typos in a parameter file: logged
        try:
            self.ps = DEMAND_NODE_SPEC.defaults().replace(ri.read_spec(self, DEMAND_NODE_SPEC))
            self.profile = profile_from_params(self.ps)
        except (ConfigError, ProfileError) as exc:
            raise SystemExit(f"demand: {exc}") from None
        self.output = self.ps["output"]
        self.lockstep = self.ps["lockstep"]
        from std_msgs.msg import Float64
        self._msg_type = Float64
        recorded = ri.recorded_topics(self.ps["recorded_topics"])
        deep = bool(recorded)                 # a recorder in the run: deep writer histories
        self.pub_pct = ri.quiet_publisher(self, Float64, contract.DEMAND, recorded=deep)
        self.pub_ma = ri.quiet_publisher(self, Float64, contract.DEMAND_MA, recorded=deep)
        self.t0 = None
        ri.handle_parameter_changes(self, DEMAND_NODE_SPEC, self.check_parameters, self.apply_parameters)
        self._pending_tick = None
        self._answered_tick = None
        self._controller_matched = False
        #: messages published per topic (printed at exit) and the recorder hold (recorded_topics)
        self.recorder_gate = ri.RecorderGate(self, recorded)
        if self.lockstep:
            from rosgraph_msgs.msg import Clock
            ri.quiet_subscription(self, Clock, contract.CLOCK, self.on_clock, ri.TELEMETRY_QOS)
            from rclpy.clock import Clock as WallClock, ClockType
            # a wall-clock timer: simulated time stands still while the tick waits
            self.create_timer(0.01, self._answer_tick, clock=WallClock(clock_type=ClockType.STEADY_TIME))
        else:
            self.create_timer(1.0 / self.ps["publish_rate_hz"], self.publish)
        self.get_logger().info(f"demand up: profile {self.ps['profile']}, output {self.output}")

    def check_parameters(self, changes: dict):
        """Validation (on-set): the new values and the profile they describe, or ``ValueError``."""
        ps = self.ps.replace(changes)
        return ps, profile_from_params(ps)

    def apply_parameters(self, changes: dict) -> None:
        """Post-set: the new profile starts now."""
        self.ps, self.profile = self.check_parameters(changes)
        self.output = self.ps["output"]
        self.t0 = None

    def now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def on_clock(self, msg) -> None:
        # the tick as the offline simulator has it: k * period (common/timebase.py)
        t = stamp_seconds(msg.clock.sec, msg.clock.nanosec, self.ps["tick_period_s"])
        latest = self._pending_tick if self._pending_tick is not None else self._answered_tick
        if latest is not None and t <= latest:
            # a re-published tick (see plant_node): answered once.  Simulated time only moves
            # forward, so any tick not after the newest one seen is a copy, however late it
            # comes (comparing with the last one only would answer a stale copy again, and
            # the controller would take that extra demand for the next period's)
            return
        self._pending_tick = t
        self._tick_since = time.monotonic()
        self._answer_tick()

    def _answer_tick(self) -> None:
        """Lockstep: publish the demand for the latest tick once the loop's controller (the
        node publishing ``current_command``) subscribes and every subscriber discovery has seen
        is matched: the controller waits for this very message, and one published before its
        subscription matched would be lost (the run would stall).  Other subscribers (a
        monitor, a recorder) may be seen first, so "all seen are matched" alone is not enough."""
        if self._pending_tick is None or not self.recorder_gate.is_open:
            return
        topic, pub = (contract.DEMAND, self.pub_pct) if self.output == "percent" else (contract.DEMAND_MA, self.pub_ma)
        if not self._controller_matched:
            controllers = {(i.node_namespace, i.node_name)
                           for i in self.get_publishers_info_by_topic(contract.CURRENT_COMMAND)}
            subscribers = self.get_subscriptions_info_by_topic(topic)
            seen = len(subscribers)
            if not any((i.node_namespace, i.node_name) in controllers for i in subscribers):
                if time.monotonic() - self._tick_since > 5.0:
                    self.get_logger().info("lockstep: waiting for the controller to subscribe to the demand",
                                           throttle_duration_sec=5.0)
                return                      # the retry timer asks again shortly
            if pub.get_subscription_count() < seen and time.monotonic() - self._tick_since < MATCH_WAIT_S:
                return
            self._controller_matched = True         # matched for good: later ticks go out at once
        t, self._pending_tick = self._pending_tick, None
        self._answered_tick = t
        self.publish(t)

    def publish(self, now: float | None = None) -> None:
        if not self.recorder_gate.is_open:      # real time: the profile starts once it is
            return
        now = self.now_s() if now is None else now
        if self.t0 is None:
            self.t0 = now if not self.lockstep else 0.0
        pct = self.profile.value(now - self.t0)
        if self.output == "percent":
            self.pub_pct.publish(self._msg_type(data=float(pct)))
            self.recorder_gate.count(contract.DEMAND)
        else:
            self.pub_ma.publish(self._msg_type(data=contract.percent_to_ma(min(max(pct, 0.0), 100.0))))
            self.recorder_gate.count(contract.DEMAND_MA)


def main(args=None) -> int:
    return run_node(DemandNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
