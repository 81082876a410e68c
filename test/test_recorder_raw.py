"""The recorder's hot path and bag metadata, in one process (no lockstep run needed).

* raw pass-through: the bag holds exactly the CDR bytes the publisher sent, one message per
  publish, counts in metadata.yaml = messages written = messages published, none dropped;
* offered QoS: metadata.yaml lists, per topic, the QoS its publisher offered (RELIABLE /
  TRANSIENT_LOCAL for the latched ``drive_enable``, VOLATILE for the rest), and
  ``ros_distro: jazzy``;
* the writer thread's queue is bounded and a message that does not fit is counted as dropped;
* adaptive QoS (as ``ros2 bag record``): best-effort and volatile publishers are recorded too, and
  the subscription's profile is only ever weakened.
"""
from __future__ import annotations

import threading
import time

import pytest
import yaml

pytest.importorskip("rclpy")
pytest.importorskip("rosbags")

pytestmark = [pytest.mark.ros]

NS = "/fv_raw"
NS_QOS = "/fv_qos"


def _record(tmp_path, ns: str, sent, demand_qos=None, enable_qos=None, pace_s: float = 0.0):
    """Record ``sent`` (std_msgs/Float64 on ``demand``) and one ``Bool(True)`` on ``drive_enable``
    through a :class:`Recorder` in this process; the publishers are a node of the same context
    that comes up after the recorder (QoS None: the suite's own profile for the topic), matched
    before anything is sent; ``pace_s`` between demand samples.  Returns ``(recorder, counts,
    metadata, raw demand bytes in the bag)``."""
    import rclpy
    from rclpy.parameter import Parameter
    from std_msgs.msg import Bool, Float64  # noqa: F401 (the sent messages' type)
    from rosbags.highlevel import AnyReader

    from fuel_valve_control.common import contract
    from fuel_valve_control.ros import interface as ri
    from fuel_valve_control.ros import node_runner
    from fuel_valve_control.tools.recorder import Recorder

    bag = tmp_path / "bag"
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        recorder = Recorder(context=context, namespace=ns, parameter_overrides=[
            Parameter("output", value=str(bag)),
            Parameter("topics", value=[contract.DEMAND, contract.DRIVE_ENABLE])])
        assert all(sub.raw for sub in recorder.subscriptions)
        executor = node_runner.make_executor(context=context)
        executor.add_node(recorder)
        executor.spin_once(timeout_sec=0.1)
        source = rclpy.create_node("source", namespace=ns, context=context)
        pub_demand = ri.quiet_publisher(source, Float64, contract.DEMAND, demand_qos)
        pub_enable = ri.quiet_publisher(source, Bool, contract.DRIVE_ENABLE, enable_qos)
        end = time.monotonic() + 10.0
        while pub_demand.get_subscription_count() < 1 or pub_enable.get_subscription_count() < 1:
            assert time.monotonic() < end, (
                f"recorder never matched the source: demand {pub_demand.get_subscription_count()}, "
                f"drive_enable {pub_enable.get_subscription_count()}")
            executor.spin_once(timeout_sec=0.05)
        time.sleep(0.2)                                   # both ends of the match known
        pub_enable.publish(Bool(data=True))
        for msg in sent:
            pub_demand.publish(msg)
            executor.spin_once(timeout_sec=0.0)
            if pace_s:
                time.sleep(pace_s)
        end = time.monotonic() + 5.0
        while recorder.received < len(sent) + 1 and time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
        counts = recorder.finish()
        executor.shutdown()
        source.destroy_node()
        recorder.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    with AnyReader([bag]) as reader:
        raw = [data for conn, _, data in reader.messages() if conn.topic == f"{ns}/demand"]
    return recorder, counts, meta, raw


def _offered_qos(meta) -> dict:
    """Topic name -> the QoS profiles its publishers offered, as metadata.yaml lists them."""
    return {t["topic_metadata"]["name"]: t["topic_metadata"]["offered_qos_profiles"]
            for t in meta["topics_with_message_count"]}


def test_raw_bytes_counts_qos_and_distro(tmp_path):
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Float64

    sent = [Float64(data=0.1 * i + 1e-9) for i in range(300)]
    recorder, counts, meta, raw = _record(tmp_path, NS, sent)
    assert counts == {f"{NS}/demand": len(sent), f"{NS}/drive_enable": 1}
    assert recorder.dropped == {}
    assert meta["ros_distro"] == "jazzy"
    assert {t["topic_metadata"]["name"]: t["message_count"] for t in meta["topics_with_message_count"]} == counts
    qos = _offered_qos(meta)
    assert [(q["reliability"], q["durability"]) for q in qos[f"{NS}/drive_enable"]] == [("reliable", "transient_local")]
    assert [(q["reliability"], q["durability"]) for q in qos[f"{NS}/demand"]] == [("reliable", "volatile")]
    assert raw == [serialize_message(m) for m in sent]


def test_best_effort_and_volatile_publishers_are_recorded(tmp_path):
    """The recorder's adaptive QoS (as ``ros2 bag record``, h25r): a supervisor that publishes the
    demand best-effort -- which the controller hears since h24u -- and a volatile ``drive_enable``
    (the suite's is transient-local), both coming up after the recorder, are matched within a
    few ``QOS_RECHECK_S`` and every sample published after that is recorded, raw, once.  Before,
    the recorder subscribed RELIABLE / TRANSIENT_LOCAL only and recorded nothing of either."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Float64

    best_effort = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                             reliability=ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE)
    volatile = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                          reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
    sent = [Float64(data=0.01 * i) for i in range(100)]
    _, counts, meta, raw = _record(tmp_path, NS_QOS, sent, best_effort, volatile,
                                   pace_s=0.001)          # best effort: a pace the reader keeps
    assert counts == {f"{NS_QOS}/demand": len(sent), f"{NS_QOS}/drive_enable": 1}
    qos = _offered_qos(meta)
    assert [q["reliability"] for q in qos[f"{NS_QOS}/demand"]] == ["best_effort"]
    assert [q["durability"] for q in qos[f"{NS_QOS}/drive_enable"]] == ["volatile"]
    assert raw == [serialize_message(m) for m in sent]


def test_adapted_qos_only_weakens():
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    from fuel_valve_control.tools.recorder import adapted_qos

    start = QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL)
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    best_effort = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE)
    assert adapted_qos(start, []) is start
    assert adapted_qos(start, [latched]) is start
    weak = adapted_qos(start, [latched, best_effort])
    assert (weak.reliability, weak.durability, weak.depth) == (ReliabilityPolicy.BEST_EFFORT,
                                                               DurabilityPolicy.VOLATILE, 5000)
    assert adapted_qos(weak, [latched]) is weak          # never back: no replayed latched samples


class _SlowWriter:
    """A rosbags-Writer stand-in whose first write blocks until released."""

    def __init__(self):
        self.entered, self.release = threading.Event(), threading.Event()
        self.written = []
        self.closed = False

    def write(self, connection, stamp, data):
        self.entered.set()
        self.release.wait(10.0)
        self.written.append(data)

    def close(self):
        self.closed = True


def test_writer_queue_is_bounded_and_counts_drops(monkeypatch):
    from fuel_valve_control.tools.recorder import BagWriterThread, _Topic
    monkeypatch.setattr(BagWriterThread, "MAX_QUEUE", 5)
    writer = _SlowWriter()
    topic = _Topic("/t", "std_msgs/msg/Float64")
    bag = BagWriterThread(lambda: writer, lambda w, t: "conn", [topic])
    bag.put(topic, 1, b"first")
    assert writer.entered.wait(5.0)                  # the thread holds "first", queue empty
    for i in range(7):
        bag.put(topic, 2 + i, b"%d" % i)
    assert bag.dropped == {"/t": 2}                  # 5 queued, 2 did not fit
    writer.release.set()
    bag.close()
    assert writer.closed and writer.written == [b"first", b"0", b"1", b"2", b"3", b"4"]
    assert topic.count == 6


def test_prebuilt_drive_telemetry_bytes_are_the_message():
    # the plant publishes its drive telemetry as CDR bytes (interface.LabelledArrayCdr): they must
    # deserialise to exactly the labelled_array message, for any values (NaN, inf, signed zero)
    import math
    import struct
    from rclpy.serialization import deserialize_message, serialize_message
    from std_msgs.msg import Float64MultiArray
    from fuel_valve_control.common import contract
    from fuel_valve_control.ros import interface as ri
    cdr = ri.LabelledArrayCdr(contract.TELEMETRY_LABELS)
    values = [math.pi * k - 3.3e-7 for k in range(len(contract.TELEMETRY_LABELS))]
    values[1], values[2], values[3] = math.inf, -0.0, 1e-300
    data = cdr(values)
    msg = deserialize_message(data, Float64MultiArray)
    assert msg == ri.labelled_array(contract.TELEMETRY_LABELS, values)
    assert len(data) == len(serialize_message(msg))
    assert list(ri.array_values(msg)) == list(contract.TELEMETRY_LABELS)
    values[0] = math.nan
    assert math.isnan(ri.array_values(deserialize_message(cdr(values), Float64MultiArray))["i_d"])
    with pytest.raises(struct.error):            # a wrong number of values is refused
        cdr(values[:-1])


def test_final_write_stops_at_the_deadline_and_counts_the_rest_as_dropped():
    """A stop under ``ros2 launch`` must close the bag before launch escalates to SIGTERM and
    SIGKILL: the backlog is written until the deadline, the rest is dropped and counted."""
    import time
    from fuel_valve_control.tools.recorder import BagWriterThread, _Topic
    writer = _SlowWriter()
    topic = _Topic("/t", "std_msgs/msg/Float64")
    bag = BagWriterThread(lambda: writer, lambda w, t: "conn", [topic])
    bag.put(topic, 0, b"first")
    assert writer.entered.wait(5.0)                  # the thread holds "first"
    for i in range(500):
        bag.put(topic, 1 + i, b"%d" % i)
    closer = threading.Thread(target=bag.close, kwargs={"deadline": time.monotonic()})   # already due
    closer.start()
    while not bag._stop.is_set():
        time.sleep(0.001)
    writer.release.set()
    closer.join(10.0)
    assert writer.closed
    assert 1 < len(writer.written) < 501             # some of the backlog written, not all
    assert topic.count == len(writer.written)
    assert bag.dropped == {"/t": 501 - len(writer.written)}   # the rest counted, none lost silently
