"""ROS side of the interface contract (SPEC §4): QoS per topic, message builders/readers and
ROS-parameter declaration from a :class:`~fuel_valve_control.common.paramspec.ParamSpec`.

Names and types of the topics are in :mod:`fuel_valve_control.common.contract` (no rclpy);
this module is imported only by nodes and tools, never by the cores.

QoS (documented in README): every topic is RELIABLE so any subscriber (a recorder with a
deep reliable queue, ``ros2 topic echo``) can connect.  Loop topics (``resolver``,
``current_command``, ``demand``, ``demand_ma``) keep only the newest sample (depth 1): a
control loop wants the latest value, never a backlog.  ``drive_enable`` is TRANSIENT_LOCAL so
a plant that starts late still learns whether the drive may run.  Telemetry keeps 10 (the 1 kHz
loop measured worse with 100 in one comparison; recorders keep deep reader queues).  The
controller's subscriptions to the inputs an outside client publishes (``demand``,
``demand_ma``, ``pressure_differential``) are BEST_EFFORT in real time (:data:`INPUT_QOS`), so
a client's writer of either reliability matches; a RELIABLE reader ignored a best-effort
supervisor without a word.
"""
from __future__ import annotations

import functools
import math
from typing import Iterable, Sequence

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from ..common import contract as c
from ..common.paramspec import ALL_TOPICS

# --- QoS ---------------------------------------------------------------------------------------
LOOP_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)
LATCHED_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
TELEMETRY_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.VOLATILE)
#: the controller's subscriptions to the inputs a client outside the suite publishes (``demand``,
#: ``demand_ma``, ``pressure_differential``) in real time: BEST_EFFORT, the most permissive
#: request, so a publisher of either reliability matches (DDS pairs a RELIABLE reader only with
#: RELIABLE writers: a supervisor publishing its demand best-effort, e.g. with the sensor-data
#: profile, was silently ignored and the controller tripped on a stale demand, h24u).  The
#: inputs are levels whose newest value wins, so a sample lost on the way costs nothing the
#: next one does not repair.  VOLATILE also accepts any writer (TRANSIENT_LOCAL ones too).  Not
#: in lockstep: there each period waits for its demand, and a lost sample would stall the loop.
INPUT_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.BEST_EFFORT,
                       durability=DurabilityPolicy.VOLATILE)
#: writer history of a volatile topic while a recorder is part of the run (``recorded_topics``):
#: samples a starved recorder has not acknowledged yet, which DDS re-sends once it runs again.
#: The 1 kHz topics times the worst stall of the recorder process seen on the loaded 2-core
#: machine (a few hundred ms): with depth 1 or 10 a reliable keep-last writer overwrites the
#: unacknowledged sample and the bag misses it.  The loop's readers still keep only the newest.
RECORDED_WRITER_DEPTH = 1000


def quiet_publisher(node, msg_type, topic: str, qos: QoSProfile | None = None, recorded: bool = False):
    """A publisher without rclpy's default QoS-event handlers: each handler is one more entity
    in every executor wait, and in a 1 kHz loop that overhead is most of the cost.
    ``recorded``: a recorder is part of the run (:func:`qos_for`)."""
    from rclpy.event_handler import PublisherEventCallbacks
    return node.create_publisher(msg_type, topic, qos or qos_for(topic, recorded),
                                 event_callbacks=PublisherEventCallbacks(use_default_callbacks=False))


def quiet_subscription(node, msg_type, topic: str, callback, qos: QoSProfile | None = None):
    """A subscription without the default QoS-event handlers (see :func:`quiet_publisher`)."""
    from rclpy.event_handler import SubscriptionEventCallbacks
    return node.create_subscription(msg_type, topic, callback, qos or qos_for(topic),
                                    event_callbacks=SubscriptionEventCallbacks(use_default_callbacks=False))


def qos_for(topic: str, recorded: bool = False) -> QoSProfile:
    """The QoS profile of one of the suite's topics (by its relative name; anything else, e.g.
    ``/clock``, is telemetry).  ``recorded`` (a publisher's, while a recorder is in the run):
    writers keep :data:`RECORDED_WRITER_DEPTH` samples for the recorder's re-sends."""
    if topic in c.LATCHED_TOPICS:
        base = LATCHED_QOS
    else:
        base = LOOP_QOS if topic in c.LOOP_TOPICS else TELEMETRY_QOS
    if recorded:
        # latched ones too: a state that changes twice within a recorder stall (drive_status:
        # watchdog, then enabled again a millisecond later) must reach the bag twice; a late
        # joiner then replays the recent changes, in order, ending on the state in force
        return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=RECORDED_WRITER_DEPTH,
                          reliability=base.reliability, durability=base.durability)
    return base


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
    from std_msgs.msg import Float64MultiArray
    msg = Float64MultiArray()
    msg.layout = _layout(tuple(labels))
    msg.data = [float(v) for v in values]
    return msg


@functools.lru_cache(maxsize=16)
def _layout(labels: tuple[str, ...]):
    """The ``MultiArrayLayout`` of :func:`labelled_array`, built once per label set: the plant
    publishes one array per period, and building its 13 dimension messages each time cost more
    than the publish's Python side (cProfile of a lockstep run, benchmarks/ros_loop.py
    --profile).  Shared read-only: nothing changes a published message's layout."""
    from std_msgs.msg import MultiArrayDimension, MultiArrayLayout
    return MultiArrayLayout(dim=[MultiArrayDimension(label=label, size=1, stride=1) for label in labels],
                            data_offset=0)


class LabelledArrayCdr:
    """The serialized (CDR) :func:`labelled_array` of a fixed label set, for
    ``Publisher.publish(bytes)`` (rclpy's public raw publish): the same bytes as publishing the
    message, without converting its constant layout (one string per label) on every publish.

    The plant publishes its 13-value ``drive`` telemetry every period; converting that message
    cost it more than any other publish (benchmarks/ros_loop.py --profile).  The bytes are the
    serialized message of a probe, up to its data, followed by the values packed as
    little-endian doubles; the constructor checks, for two probes, that they have the length
    of ``serialize_message``'s and deserialise to the same message (alignment padding is not
    compared: the serializer leaves it uninitialised), so the layout is verified, not assumed.
    """

    def __init__(self, labels: Sequence[str]):
        import struct
        from rclpy.serialization import deserialize_message, serialize_message
        from std_msgs.msg import Float64MultiArray
        self.labels = tuple(labels)
        self._pack = struct.Struct(f"<{len(self.labels)}d").pack
        probes = [tuple(0.5 + k for k in range(len(self.labels))), tuple(-1e-3 * k for k in range(len(self.labels)))]
        tail = len(self._pack(*probes[0]))
        ref = serialize_message(labelled_array(self.labels, probes[0]))
        self._prefix = ref[:len(ref) - tail]
        for probe in probes:
            msg = labelled_array(self.labels, probe)
            data = self(probe)
            if len(serialize_message(msg)) != len(data) or deserialize_message(data, Float64MultiArray) != msg:
                raise ValueError("labelled_array: this middleware's CDR differs from the packed layout")

    def __call__(self, values: Sequence[float]) -> bytes:
        """CDR bytes of ``labelled_array(labels, values)``."""
        return self._prefix + self._pack(*values)


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
            # an exclusive lower bound (low_open: value > low) as the smallest double above it,
            # so the descriptor (``ros2 param describe``) and rclpy's own check say what the node
            # enforces; with ``low`` itself rclpy would call the edge valid and show it as allowed
            low = p.low if not (p.low is not None and p.low_open) else math.nextafter(p.low, math.inf)
            desc.floating_point_range = [FloatingPointRange(
                from_value=float(low if low is not None else -1e300),
                to_value=float(p.high if p.high is not None else 1e300), step=0.0)]
        elif p.kind is int and (p.low is not None or p.high is not None):
            desc.integer_range = [IntegerRange(from_value=int(p.low if p.low is not None else -2**62),
                                               to_value=int(p.high if p.high is not None else 2**62), step=0)]
        default = p.default if values is None else values[p.name]
        node.declare_parameter(p.name, default, desc)


def unknown_overrides(node) -> list[str]:
    """Call after every declaration: the names a parameter file or ``-p`` set for this node
    that it does not have, each logged as a warning with the closest declared name.  rclpy
    drops such overrides without a word, so a typo in a technician's YAML
    (``faults.resolver_timeout: 0.5``) left the default in force while the file said
    otherwise (h24u).  Not an error: one ``/**`` file may serve several nodes."""
    import difflib
    declared = sorted(node._parameters)
    # rclpy keeps the overrides that matched this node (its name, a wildcard) in one dict;
    # no public accessor in Jazzy
    unknown = sorted(n for n in getattr(node, "_parameter_overrides", {}) if n not in node._parameters)
    for name in unknown:
        close = difflib.get_close_matches(name, declared, n=1, cutoff=0.6)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        node.get_logger().warn(f"parameter {name!r} set by a parameter file or -p is not a parameter of this node: "
                               f"ignored{hint}")
    return unknown


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
        except Exception as exc:        # noqa: BLE001 - a value the design code cannot use: refuse it
            return SetParametersResult(successful=False, reason=f"rejected: {type(exc).__name__}: {exc}")
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


# --- recording ----------------------------------------------------------------------------------
#: name of the recorder node (tools/recorder.py) a :class:`RecorderGate` waits for
RECORDER_NODE = "recorder"
#: publishers every rclpy node has, never part of a run's recording
_INFRASTRUCTURE_TOPICS = ("/rosout", "/parameter_events")


def recorded_topics(text: str) -> tuple[str, ...]:
    """The node parameter ``recorded_topics`` (common.paramspec.RECORDED_TOPICS, comma-separated)
    as names: ``()`` = no recorder in the run, else the names (or :data:`ALL_TOPICS`)."""
    return tuple(e.strip() for e in text.split(",") if e.strip())


class RecorderGate:
    """Counts what a node publishes per topic and, with a recorder in the run (``recorded``:
    the node's ``recorded_topics``, :func:`recorded_topics`), holds the node's publishing until
    the recorder has matched every topic of this node that it records.

    Why: a volatile sample published before the recorder's subscription has matched the
    publisher never reaches the bag, so a recorded run would lose its first messages to
    discovery.  The gate :attr:`is_open` once (checked every ``CHECK_S`` on a steady timer,
    graph queries never on the hot path):

    * for every publisher of this node on a recorded topic, discovery shows the recorder node
      of this namespace subscribed to it and the publisher has matched every subscription
      discovery shows on that topic (``get_subscription_count()``);
    * that has held for :data:`SETTLE_S` (the reader side matches a little after the writer);
    * or, never stalling a run, after :data:`TIMEOUT_S` of wall time without it (logged).

    Without a recorder it is open from the start.  :meth:`count` records every publish in
    :attr:`published` and, while the gate is still closed, in :attr:`before_recorder`
    (messages the recorder may legitimately miss: start-up, not loss); the node runner prints
    both at exit and ``benchmarks/ros_loop.py --record`` compares them with the bag.
    Relative topic names are counted as such, absolute ones (``/diagnostics``) as they are.
    """

    CHECK_S = 0.05
    SETTLE_S = 0.2
    TIMEOUT_S = 20.0
    #: longest wait at exit for the recorder to acknowledge what was published, s: more than one
    #: writer heartbeat period (Fast DDS default 3 s), which is when a reader asks for a repair;
    #: below the launcher's 10 s SIGINT grace
    DRAIN_S = 5.0

    def __init__(self, node, recorded: tuple[str, ...]):
        import collections
        import threading
        import time
        self._node = node
        self._time = time.monotonic
        self._recorded = recorded
        self.published = collections.Counter()
        self.before_recorder = collections.Counter()
        self.opened = threading.Event()       # the plant's loop thread waits on it
        self._since = self._time()
        self._ready_since = None
        self._timer = None
        if not recorded:
            self.opened.set()
            return
        from rclpy.clock import Clock, ClockType
        # steady time: in lockstep simulated time stands still until the loop starts
        self._timer = node.create_timer(self.CHECK_S, self._check, clock=Clock(clock_type=ClockType.STEADY_TIME))

    @property
    def is_open(self) -> bool:
        return self.opened.is_set()

    def count(self, topic: str, latched: bool = False) -> None:
        """One message published on ``topic`` (``latched``: a transient-local topic, which a
        recorder that matches later still receives: never a start-up miss)."""
        self.published[topic] += 1
        if not latched and not self.opened.is_set():
            self.before_recorder[topic] += 1

    def recorded_publishers(self) -> list:
        """This node's publishers on topics the recorder records."""
        node = self._node
        if ALL_TOPICS in self._recorded:
            return [p for p in node.publishers if p.topic_name not in _INFRASTRUCTURE_TOPICS]
        # entries as the recorder takes them: "name" or "name:pkg/msg/Type"
        names = {node.resolve_topic_name(t.partition(":")[0].strip()) for t in self._recorded}
        return [p for p in node.publishers if p.topic_name in names]

    def drain(self) -> bool:
        """At exit, before the node is destroyed: wait (at most :data:`DRAIN_S` in all) until every
        recorded publisher's samples are acknowledged by its reliable readers -- the recorder,
        which the launcher stops last.  A sample whose first delivery was lost (a starved
        recorder) is re-sent from the writer's history only while the writer exists; a node
        that exits first takes it with it.  True when all were acknowledged (or no recorder)."""
        if not self._recorded:
            return True
        from rclpy.duration import Duration
        end = self._time() + self.DRAIN_S
        ok = True
        for pub in self.recorded_publishers():
            left = max(0.0, end - self._time())
            ok = pub.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9))) and ok
        if not ok:
            self._node.get_logger().warn(f"recorder: not every message acknowledged within {self.DRAIN_S:g} s at exit")
        return ok

    def _matched(self) -> bool:
        node = self._node
        me = (RECORDER_NODE, node.get_namespace())
        for pub in self.recorded_publishers():
            subs = node.get_subscriptions_info_by_topic(pub.topic_name)
            if me not in {(i.node_name, i.node_namespace) for i in subs} or pub.get_subscription_count() < len(subs):
                return False
        return True

    def _check(self) -> None:
        if self.opened.is_set():
            return
        now = self._time()
        if not self._matched():
            self._ready_since = None
            if now - self._since > self.TIMEOUT_S:
                self._open(f"recorder still unmatched after {self.TIMEOUT_S:g} s: publishing anyway")
            return
        if self._ready_since is None:
            self._ready_since = now
        elif now - self._ready_since >= self.SETTLE_S:
            self._open(f"recorder matched after {now - self._since:.2f} s: publishing")

    def _open(self, why: str) -> None:
        self._timer.cancel()
        self.opened.set()
        self._node.get_logger().info(why)
