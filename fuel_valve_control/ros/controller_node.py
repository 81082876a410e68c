"""``ros2 run fuel_valve controller``: the valve driver (position controller + fault logic).

A thin layer over :class:`~fuel_valve_control.core.driver.ValveDriver`, the same object the
offline simulator runs.  Each ``resolver`` sample triggers one control period (the sample
is the loop's clock, so the command leaves as soon as the measurement arrives); a watchdog
timer keeps the fault logic running when samples stop, so silence trips the drive too.

Topics (SPEC §4): subscribes ``demand`` (percent), ``demand_ma`` (4-20 mA), ``resolver``,
``pressure_differential`` (measured Δp, kPa: schedules the friction terms) and, optionally,
the plant's ``drive`` telemetry (measured current for the over-current check); publishes ``current_command`` (A), ``drive_enable``, ``position`` (percent),
``estimate`` and ``/diagnostics``.  Services ``~/trip`` and ``~/reset`` (std_srvs/Trigger); the
valve tests' ``~/signature_test``, ``~/partial_stroke_test`` and latched ``valve_test``
(:mod:`.valve_test_services`).

With ``lockstep:=true`` (and ``use_sim_time:=true``) each period waits for a fresh demand as
well as the resolver sample, so runs are deterministic: the demand source is part of the
lockstep loop (the ``demand`` node with ``lockstep:=true`` publishes once per ``/clock``).
A resolver sample whose stamp has been answered already (the plant re-publishes a tick whose
command it has not received) is dropped, and the command is never re-sent: the plant steps
once per command, and an unstamped copy could not be told from the next period's.  So the
first command waits until ``current_command`` has matched the plant's subscription (a
command published before that would be lost, and the run would stall).
"""
from __future__ import annotations

import collections
import functools
import math
import threading
import time

from rclpy.node import Node

from ..common import contract
from . import interface as ri
from .node_runner import run_node
from .valve_test_services import create_valve_test_interface
from ..common.paramspec import ConfigError

from ..core.params import CONTROLLER_NODE_SPEC, CONTROLLER_SPEC, load_controller_params
from ..core.driver import Health, ValveDriver

LEVEL_NAMES = {0: "OK", 1: "WARN", 2: "ERROR"}


def locked(method):
    """Run a callback under the node's lock (the driver is not thread-safe; callbacks and the
    executor's timers must never interleave inside it).  A callback never raises into the
    executor: an exception latches the driver's internal-error fault and the drive is switched
    off at once (:meth:`ControllerNode.fail_safe`); the node keeps running and reports it."""
    @functools.wraps(method)
    def wrapper(self, *args):
        with self._lock:
            try:
                return method(self, *args)
            except Exception as exc:       # noqa: BLE001 - a defect must fail safe, not end the loop
                self.fail_safe(method.__name__, exc)
                if len(args) == 2 and hasattr(args[1], "success"):     # a service: answer it
                    args[1].success, args[1].message = False, f"internal error: {exc}"
                    return args[1]
                return None
    return wrapper


class ControllerNode(Node):
    def __init__(self, **kwargs):
        super().__init__("controller", **kwargs)
        ri.declare_spec(self, CONTROLLER_NODE_SPEC)
        try:
            node_ps = CONTROLLER_NODE_SPEC.defaults().replace(ri.read_spec(self, CONTROLLER_NODE_SPEC))
            ps = load_controller_params(None, CONTROLLER_SPEC.pick(node_ps))
        except ConfigError as exc:
            raise SystemExit(f"controller: invalid parameters: {exc}") from None
        self.driver = ValveDriver(ps)
        initial_a = node_ps["initial_current_a"]
        if initial_a:
            self.driver.start_from_torque(initial_a * self.driver.controller.model.torque_constant_nm_per_a)
        self.lockstep = node_ps["lockstep"]
        self.stroke = self.driver.stroke
        self._fresh_demand = False
        self._pending_sample = None
        self._last_sample_stamp = None
        self._bad_messages = 0
        self._last_enable = None
        self._level = 0

        from diagnostic_msgs.msg import DiagnosticArray
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Bool, Float64, Float64MultiArray
        from std_srvs.srv import Trigger
        from builtin_interfaces.msg import Time
        self._float, self._bool, self._time = Float64, Bool, Time
        self.pub_current = ri.quiet_publisher(self, Float64, contract.CURRENT_COMMAND)
        self.pub_enable = ri.quiet_publisher(self, Bool, contract.DRIVE_ENABLE)
        self.pub_position = ri.quiet_publisher(self, Float64, contract.POSITION)
        self.pub_estimate = ri.quiet_publisher(self, JointState, contract.ESTIMATE)
        self.pub_diag = ri.quiet_publisher(self, DiagnosticArray, contract.DIAGNOSTICS)
        # one lock serialises the driver between callbacks: the node runner spins one thread
        # today, and a multi-threaded executor must not change the driver's behaviour
        self._lock = threading.Lock()
        # every input on this node and the one executor (node_runner): no helper node.
        # Δp first: in lockstep it was published before the resolver sample of the same period
        ri.quiet_subscription(self, Float64, contract.PRESSURE_DIFFERENTIAL, self.on_pressure)
        ri.quiet_subscription(self, Float64, contract.DEMAND, self.on_demand)
        ri.quiet_subscription(self, Float64, contract.DEMAND_MA, self.on_demand_ma)
        ri.quiet_subscription(self, JointState, contract.RESOLVER, self.on_resolver)
        if node_ps["monitor_drive_telemetry"]:
            ri.quiet_subscription(self, Float64MultiArray, contract.DRIVE, self.on_drive)
        self._decimation = node_ps["telemetry_decimation"]
        self._periods = 0
        #: messages published per loop topic (reported at exit: benchmarks compare bag counts)
        self.published = collections.Counter()
        self._compute = ComputeTime()
        self.create_service(Trigger, "~/trip", self.on_trip)
        self.create_service(Trigger, "~/reset", self.on_reset)
        #: signature / partial-stroke tests: ~/signature_test, ~/partial_stroke_test, latched valve_test
        self.valve_tests = create_valve_test_interface(self, self.driver, self._lock)
        ri.handle_parameter_changes(self, CONTROLLER_SPEC, self.check_parameters, self.apply_parameters)
        period = self.driver.period
        # the watchdog runs the fault logic when no samples arrive (silence must trip)
        if self.lockstep:
            from rclpy.clock import Clock, ClockType
            self._command_matched = False
            # wall-clock: simulated time stands still while a period waits for the match
            self._match_timer = self.create_timer(0.01, self._run_when_matched,
                                                  clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._watchdog_period = max(5.0 * period, 0.01)
        self._watchdog_last = time.monotonic()
        self.create_timer(self._watchdog_period, self.watchdog)
        self.create_timer(1.0 / node_ps["diagnostics_rate_hz"], self.publish_diagnostics)
        self.get_logger().info(f"controller up: mode {ps['mode']}, loop {ps['loop_rate_hz']:g} Hz, demand from "
                               f"{ps['demand_source']}{', lockstep' if self.lockstep else ''}")

    # ------------------------------------------------------------------ time
    def now_s(self) -> float:
        """The loop's time, s.  In lockstep it is the stamp of the latest resolver sample (the
        plant's clock, exact and deterministic); otherwise the node clock."""
        if self.lockstep:
            return self._last_sample_stamp if self._last_sample_stamp is not None else 0.0
        return self.get_clock().now().nanoseconds * 1e-9

    # ------------------------------------------------------------------ inputs
    @locked
    def on_demand(self, msg) -> None:
        self.driver.demand_percent(self.now_s(), msg.data)
        self._demand_arrived()

    @locked
    def on_demand_ma(self, msg) -> None:
        self.driver.demand_ma(self.now_s(), msg.data)
        self._demand_arrived()

    def _demand_arrived(self) -> None:
        self._fresh_demand = True
        if self._pending_sample is not None and self._loop_matched():   # lockstep: the sample was waiting
            sample, self._pending_sample = self._pending_sample, None
            self.run_period(sample)

    def _loop_matched(self) -> bool:
        """Lockstep: the command publisher has matched the plant (checked until it has once)."""
        if not self._command_matched:
            self._command_matched = self.pub_current.get_subscription_count() >= 1
        return self._command_matched

    @locked
    def _run_when_matched(self) -> None:
        """Lockstep: run a period that was ready but held back for the command's match."""
        if self._command_matched and self._periods:
            self._match_timer.cancel()               # matched for good: the timer's job is done
        elif self._pending_sample is not None and self._fresh_demand and self._loop_matched():
            sample, self._pending_sample = self._pending_sample, None
            self.run_period(sample)

    @locked
    def on_pressure(self, msg) -> None:
        self.driver.pressure_differential(self.now_s(), msg.data)

    @locked
    def on_drive(self, msg) -> None:
        values = ri.array_values(msg)
        if "i_d" in values and "i_q" in values:
            self.driver.measured_current(self.now_s(), math.hypot(values["i_d"], values["i_q"]))

    @locked
    def on_resolver(self, msg) -> None:
        values = ri.joint_values(msg)
        motor, valve = values.get(contract.MOTOR_JOINT), values.get(contract.VALVE_JOINT)
        if motor is None or valve is None:
            self._bad_messages += 1
            self.get_logger().warn(f"resolver message without {contract.MOTOR_JOINT}/{contract.VALVE_JOINT} positions ignored",
                                   throttle_duration_sec=1.0)
            return
        stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        clock = self.get_clock().now().nanoseconds * 1e-9       # sim time in lockstep (/clock)
        if stamp - clock > self.driver.ps["faults.stamp_future_tolerance_s"]:
            # never the loop's time or the jump reference; the driver latches it as implausible
            self.driver.resolver(stamp, motor, valve, now=clock)
            self._bad_messages += 1
            return
        sample = (stamp, motor, valve, clock)
        if self.lockstep:
            if self._last_sample_stamp is not None and stamp <= self._last_sample_stamp:
                return                              # a re-sent sample of a period already run
            if not self._fresh_demand or not self._loop_matched():
                self._pending_sample = sample       # wait for this period's demand (or the match)
                return
        self.run_period(sample)

    # ------------------------------------------------------------------ loop
    def run_period(self, sample) -> None:
        t0 = time.perf_counter()
        stamp, motor, valve, clock = sample
        self._fresh_demand = False
        self._last_sample_stamp = stamp
        self.driver.resolver(stamp, motor, valve, now=clock)
        self.publish_step(stamp if self.lockstep else self.now_s())
        self._compute.add(time.perf_counter() - t0)

    @locked
    def watchdog(self) -> None:
        timeout = self.driver.ps["faults.resolver_timeout_s"]
        if self.lockstep:
            return                       # sim time stands still while nobody steps the plant
        now = time.monotonic()
        late = now - self._watchdog_last > 2.0 * self._watchdog_period
        self._watchdog_last = now
        if late:
            # this process itself was not scheduled: a sample that arrived meanwhile may still
            # wait in the executor's queue behind this timer; judge silence on the next run
            return
        last = self.driver.last_resolver_time
        if last is not None and self.now_s() - last > timeout:
            self.publish_step(self.now_s())

    def fail_safe(self, where: str, exc: BaseException) -> None:
        """An exception in the node's own code: latch the driver's internal-error fault and
        command the drive off (enable false, 0 A) now, not at the next period."""
        self.driver.internal_fault(where, exc)
        self.get_logger().error(f"internal error in {where}: {type(exc).__name__}: {exc}; drive disabled "
                                "(fault latched, ~/reset to re-arm)", throttle_duration_sec=1.0)
        try:
            self.pub_enable.publish(self._bool(data=False))
            self.pub_current.publish(self._float(data=0.0))
            self._last_enable = False
        except Exception:                   # noqa: BLE001 - context gone: the plant's watchdog acts
            pass

    def publish_step(self, t: float) -> None:
        """One driver period: the command first (the plant is waiting for it), then the rest."""
        out = self.driver.step(t)
        if out.enable != self._last_enable:       # latched topic: publish changes only, before
            self.pub_enable.publish(self._bool(data=bool(out.enable)))   # the command it applies to
        self.pub_current.publish(self._float(data=float(out.current_a)))
        self.published[contract.CURRENT_COMMAND] += 1
        self._periods += 1
        if self._periods % self._decimation == 0:
            if out.position_pct is not None:
                self.pub_position.publish(self._float(data=float(out.position_pct)))
                self.published[contract.POSITION] += 1
            est = self.driver.controller.estimate()
            sec = int(t)
            stamp = self._time(sec=sec, nanosec=int((t - sec) * 1e9)) if self.lockstep \
                else self.get_clock().now().to_msg()
            self.pub_estimate.publish(ri.joint_state(
                stamp, (est.motor_angle, est.valve_angle), (est.motor_velocity, est.valve_velocity),
                (est.motor_friction_nm, est.valve_friction_nm)))
            self.published[contract.ESTIMATE] += 1
        if out.enable != self._last_enable:
            if self._last_enable is not None:
                # one call site per severity: rclpy refuses a site that changes severity
                if out.enable:
                    self.get_logger().info(f"drive enabled: state {out.state}")
                else:
                    self.get_logger().error(f"drive DISABLED: state {out.state}"
                                            + (f", faults: {'; '.join(out.faults.values())}" if out.faults else ""))
            self._last_enable = out.enable

    # ------------------------------------------------------------------ services
    @locked
    def on_trip(self, request, response):
        self.driver.trip("trip requested through ~/trip")
        self.publish_step(self.now_s())
        response.success = True
        response.message = "tripped: drive disabled, the return spring closes the valve; call ~/reset to re-arm"
        self.get_logger().warn(response.message)
        return response

    @locked
    def on_reset(self, request, response):
        ok, message = self.driver.reset()
        response.success, response.message = ok, message
        if ok:
            self.get_logger().info(f"reset: {message}")
        else:
            self.get_logger().warn(f"reset refused: {message}")
        return response

    # ------------------------------------------------------------------ parameters
    def check_parameters(self, changes: dict) -> None:
        """Validation only (on-set): raises ``ValueError`` for a change the driver would refuse
        (a rejection, not a fault: not :func:`locked`'s fail-safe)."""
        with self._lock:
            self.driver.check_params(changes)

    @locked
    def apply_parameters(self, changes: dict) -> None:
        """After acceptance (post-set): the driver swaps in the new set (and law) atomically."""
        self.driver.set_params(changes)

    # ------------------------------------------------------------------ diagnostics
    @locked
    def publish_diagnostics(self) -> None:
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
        try:
            h = self.driver.health()
        except Exception as exc:            # noqa: BLE001 - still say something on /diagnostics
            self.fail_safe("health", exc)
            h = Health(2, f"FAULT: internal error while reporting health: {exc}", {"faults": "internal_error"})
        values = dict(h.values, malformed_messages=self._bad_messages, periods=self._periods,
                      **self._compute.take(), **self.valve_tests.summary())
        st = DiagnosticStatus(level=bytes([h.level]), name=f"{self.get_fully_qualified_name()}: valve driver",
                              message=h.message, hardware_id="fuel_valve_driver",
                              values=[KeyValue(key=k, value=_fmt(v)) for k, v in values.items()])
        msg = DiagnosticArray(status=[st])
        msg.header.stamp = self.get_clock().now().to_msg()
        self.pub_diag.publish(msg)
        if h.level != self._level:
            self.get_logger().info(f"status {LEVEL_NAMES[h.level]}: {h.message}")
            self._level = h.level


class ComputeTime:
    """Time spent per control period (sample in -> command out, plus telemetry), since the
    last report: shows whether the node keeps up with the loop rate."""

    def __init__(self):
        self.n, self.total, self.worst = 0, 0.0, 0.0

    def add(self, seconds: float) -> None:
        self.n += 1
        self.total += seconds
        self.worst = max(self.worst, seconds)

    def take(self) -> dict:
        out = {"compute_mean_ms": 1e3 * self.total / self.n if self.n else None,
               "compute_max_ms": 1e3 * self.worst if self.n else None, "samples_since_last_report": self.n}
        self.n, self.total, self.worst = 0, 0.0, 0.0
        return out


def _fmt(x) -> str:
    if x is None:
        return "n/a"
    if isinstance(x, float):
        return f"{x:.6g}"
    return str(x)


def main(args=None) -> int:
    return run_node(ControllerNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
