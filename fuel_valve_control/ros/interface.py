"""ROS side of the interface contract (SPEC §4): QoS per topic, message builders/readers and
ROS-parameter declaration from a :class:`~fuel_valve_control.common.paramspec.ParamSpec`.

Names and types of the topics are in :mod:`fuel_valve_control.common.contract` (no rclpy);
this module is imported only by nodes and tools, never by the cores.

QoS (documented in README): every topic is RELIABLE so any subscriber (a recorder with a
deep reliable queue, ``ros2 topic echo``) can connect.  Loop topics (``resolver``,
``current_command``, ``demand``, ``demand_ma``) keep only the newest sample (depth 1): a
control loop wants the latest value, never a backlog.  ``drive_enable`` is TRANSIENT_LOCAL so
a plant that starts late still learns whether the drive may run.  Telemetry keeps 10 (the 1 kHz
loop measured worse with 100 in one comparison; recorders keep deep reader queues).
"""
from __future__ import annotations

import math
import time
from typing import Iterable, Sequence

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from ..common import contract as c

# --- QoS ---------------------------------------------------------------------------------------
LOOP_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)
LATCHED_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
TELEMETRY_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.VOLATILE)


def quiet_publisher(node, msg_type, topic: str, qos: QoSProfile | None = None):
    """A publisher without rclpy's default QoS-event handlers: each handler is one more entity
    in every executor wait, and in a 1 kHz loop that overhead is most of the cost."""
    from rclpy.event_handler import PublisherEventCallbacks
    return node.create_publisher(msg_type, topic, qos or qos_for(topic),
                                 event_callbacks=PublisherEventCallbacks(use_default_callbacks=False))


def quiet_subscription(node, msg_type, topic: str, callback, qos: QoSProfile | None = None):
    """A subscription without the default QoS-event handlers (see :func:`quiet_publisher`)."""
    from rclpy.event_handler import SubscriptionEventCallbacks
    return node.create_subscription(msg_type, topic, callback, qos or qos_for(topic),
                                    event_callbacks=SubscriptionEventCallbacks(use_default_callbacks=False))


def qos_for(topic: str) -> QoSProfile:
    """The QoS profile of one of the suite's topics (by its relative name)."""
    if topic in c.LOOP_TOPICS:
        return LOOP_QOS
    if topic in c.LATCHED_TOPICS:
        return LATCHED_QOS
    return TELEMETRY_QOS


# --- messages ----------------------------------------------------------------------------------
def joint_state(stamp, positions: Sequence[float], velocities: Sequence[float] = (),
                efforts: Sequence[float] = ()):
    """A ``sensor_msgs/JointState`` for (motor_shaft, valve_shaft)."""
    from sensor_msgs.msg import JointState
    msg = JointState()
    msg.header.stamp = stamp
    msg.name = list(c.JOINT_NAMES)
    msg.position = [float(x) for x in positions]
    msg.velocity = [float(x) for x in velocities]
    msg.effort = [float(x) for x in efforts]
    return msg


def joint_values(msg, field: str = "position") -> dict[str, float]:
    """``{joint name: value}`` of a JointState field; malformed messages give ``{}``."""
    values = getattr(msg, field, None)
    if values is None or len(values) != len(msg.name):
        return {}
    return {name: float(v) for name, v in zip(msg.name, values)}


def labelled_array(labels: Iterable[str], values: Sequence[float]):
    """``std_msgs/Float64MultiArray`` whose layout has one dimension per entry, labelled with
    the entry's name (size 1, stride 1), so readers can find values by name."""
    from std_msgs.msg import Float64MultiArray, MultiArrayDimension
    msg = Float64MultiArray()
    msg.layout.dim = [MultiArrayDimension(label=label, size=1, stride=1) for label in labels]
    msg.layout.data_offset = 0
    msg.data = [float(v) for v in values]
    return msg


def array_values(msg) -> dict[str, float]:
    """Decode :func:`labelled_array` (works on rclpy and rosbags message objects)."""
    labels = [d.label for d in msg.layout.dim]
    data = list(msg.data)
    if len(labels) != len(data):
        return {}
    return dict(zip(labels, (float(x) for x in data)))


def finite(x) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x)


# --- parameters -------------------------------------------------------------------------------
def declare_spec(node, spec, values=None, names: Iterable[str] | None = None) -> None:
    """Declare ``spec``'s parameters on ``node`` with descriptors (description, unit, range,
    read-only unless run-time changeable), defaulting to ``values`` (a ParamSet)."""
    from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
    wanted = set(names) if names is not None else None
    for p in spec:
        if wanted is not None and p.name not in wanted:
            continue
        desc = ParameterDescriptor(description=f"{p.description} [{p.unit}]" if p.unit else p.description,
                                   read_only=not p.runtime)
        desc.additional_constraints = p.range_text()
        if p.kind is float and (p.low is not None or p.high is not None):
            desc.floating_point_range = [FloatingPointRange(
                from_value=float(p.low if p.low is not None else -1e300),
                to_value=float(p.high if p.high is not None else 1e300), step=0.0)]
        elif p.kind is int and (p.low is not None or p.high is not None):
            desc.integer_range = [IntegerRange(from_value=int(p.low if p.low is not None else -2**62),
                                               to_value=int(p.high if p.high is not None else 2**62), step=0)]
        default = p.default if values is None else values[p.name]
        node.declare_parameter(p.name, default, desc)


def handle_parameter_changes(node, spec, check, apply) -> None:
    """Run-time parameter changes of ``spec``'s parameters, in two steps as rclpy intends:
    ``check(changes)`` validates in the on-set callback (raise ``ValueError`` to reject, with
    the message as the reason; no side effects there), and ``apply(changes)`` takes effect in
    the post-set callback, once every change of the request has been accepted.  ``changes`` is
    ``{name: value}`` of the request's parameters that belong to ``spec``."""
    from rcl_interfaces.msg import SetParametersResult

    def changes_of(params) -> dict:
        return {p.name: list(p.value) if spec.params[p.name].kind is list else p.value
                for p in params if p.name in spec}

    def on_set(params) -> SetParametersResult:
        changes = changes_of(params)
        try:
            if changes:
                check(changes)
        except ValueError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def post_set(params) -> None:
        changes = changes_of(params)
        if changes:
            apply(changes)
            node.get_logger().info(f"parameters changed: {changes}")

    node.add_on_set_parameters_callback(on_set)
    node.add_post_set_parameters_callback(post_set)


def read_spec(node, spec, names: Iterable[str] | None = None) -> dict:
    """Current values of the declared parameters of ``spec`` as ``{name: value}``."""
    out = {}
    for p in spec:
        if names is not None and p.name not in names:
            continue
        value = node.get_parameter(p.name).value
        out[p.name] = list(value) if p.kind is list else value
    return out


# --- the loop's hot path -----------------------------------------------------------------------
class LoopIO:
    """The loop's hot subscriptions, taken by a dedicated thread with a private wait set.

    rclpy's executor costs a few hundred microseconds of Python per wake-up (it rebuilds
    its wait set from every entity and wraps each callback in a task), which at 1 kHz is
    most of a core and most of the round trip.  Here the loop subscriptions live on a lean
    helper node (``<name>_loop``: no parameter services, no rosout) that no executor spins;
    a thread waits on them alone and calls the callbacks directly, in subscription order.  The main
    node keeps services, parameters, timers and slow topics.  Callbacks run in this thread:
    the owner serialises access to shared state (a lock).  The wait set is rclpy's own
    (``_rclpy.WaitSet``), the same object its executors use.
    """

    #: GIL switch interval while a loop thread runs, s: a sample arriving while another thread
    #: runs Python waits at most this long (CPython's default is 5 ms, five control periods)
    SWITCH_INTERVAL_S = 0.0002

    def __init__(self, owner):
        import rclpy
        self.node = rclpy.create_node(f"{owner.get_name()}_loop", namespace=owner.get_namespace(),
                                      context=owner.context, start_parameter_services=False,
                                      enable_rosout=False)
        self.subs = []
        self._wake = self.node.create_guard_condition(lambda: None)
        self._running = False
        self._thread = None

    def subscribe(self, msg_type, topic: str, callback, qos: QoSProfile | None = None) -> None:
        """Add a subscription; when several have messages, they are taken in this order."""
        self.subs.append(quiet_subscription(self.node, msg_type, topic, callback, qos))

    def start(self, idle=None, idle_period_s: float = 0.01) -> None:
        """Start the thread; ``idle()``, if given, also runs on it every ``idle_period_s``
        (a watchdog that needs no timer, and so no executor wake-ups, on the main node)."""
        import sys
        import threading
        self._idle, self._idle_period = idle, idle_period_s
        sys.setswitchinterval(min(sys.getswitchinterval(), self.SWITCH_INTERVAL_S))
        self._running = True
        self._thread = threading.Thread(target=self._spin, name=self.node.get_name(), daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
        import contextlib
        context = self.node.context
        subs, wake = self.subs, self._wake
        try:
            with contextlib.ExitStack() as stack:
                for entity in (context, wake, *subs):
                    stack.enter_context(entity.handle)
                ws = _rclpy.WaitSet(len(subs), 1, 0, 0, 0, 0, context.handle)
                timeout_ns = int(1e9 * (self._idle_period if self._idle else 0.1))
                next_idle = time.monotonic() + self._idle_period
                while self._running and context.ok():
                    ws.clear_entities()
                    for sub in subs:
                        ws.add_subscription(sub.handle)
                    ws.add_guard_condition(wake.handle)
                    ws.wait(timeout_ns)
                    if self._idle is not None and time.monotonic() >= next_idle:
                        next_idle = time.monotonic() + self._idle_period
                        self._idle()
                    for sub in subs:                           # in order, everything queued
                        while self._running:
                            info = sub.handle.take_message(sub.msg_type, sub.raw)
                            if info is None:
                                break
                            sub.callback(info[0])
        except Exception:                       # noqa: BLE001 - context shut down under us
            if context.ok() and self._running:
                raise

    def stop(self) -> None:
        self._running = False
        try:
            self._wake.trigger()
        except Exception:                       # noqa: BLE001 - already destroyed with the context
            pass
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        self.node.destroy_node()


# --- process entry point -----------------------------------------------------------------------
def run_node(factory, args=None, on_exit=None) -> int:
    """Run a node until Ctrl-C / SIGTERM, then shut down cleanly.

    rclpy's own signal handlers (SIGINT and SIGTERM) shut the context down and the executor
    returns; ``factory()`` builds the node (a ``SystemExit`` from it is a configuration error:
    message printed, exit code 2); ``on_exit(node)`` runs before the node is destroyed (the
    context may already be shut down: print, do not publish).  The single-threaded executor is
    used: the experimental events executor of this rclpy ignores signals and spins a core.
    """
    import rclpy
    from rclpy.exceptions import InvalidParameterValueException, ParameterException
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

    rclpy.init(args=args)
    node = None
    code = 0
    try:
        node = factory()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except SystemExit as exc:
        print(exc, flush=True)
        code = 2
    except (ParameterException, InvalidParameterValueException) as exc:
        # a parameter file or -p value outside a declared range: a configuration error
        print(f"invalid parameter: {exc}", flush=True)
        code = 2
    except Exception:                       # noqa: BLE001 - a shutdown race inside spin()
        if rclpy.ok():
            raise
    finally:
        if node is not None:
            if on_exit is not None:
                on_exit(node)
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return code
