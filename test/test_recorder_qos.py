"""The recorder's adaptive QoS (as ``ros2 bag record``): a supervisor that publishes the demand
best-effort -- which the controller hears since h24u -- must land in the bag too.

* a best-effort ``demand`` publisher that appears after the recorder started, and a volatile
  ``drive_enable`` publisher (the suite's is transient-local): both are matched within a few
  ``QOS_RECHECK_S`` and every sample published after that is recorded, raw, once;
* :func:`adapted_qos` only ever weakens the profile (never back to reliable).

On main the recorder subscribed RELIABLE only and recorded nothing of either.  In one process;
wall about 3 s.
"""
from __future__ import annotations

import time

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("rosbags")

pytestmark = [pytest.mark.ros]

NS = "/fv_qos"


def test_best_effort_and_volatile_publishers_are_recorded(tmp_path):
    import rclpy
    from rclpy.parameter import Parameter
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.serialization import serialize_message
    from rosbags.highlevel import AnyReader
    from std_msgs.msg import Bool, Float64
    import yaml

    from fuel_valve_control.common import contract
    from fuel_valve_control.ros import interface as ri
    from fuel_valve_control.ros import node_runner
    from fuel_valve_control.tools.recorder import Recorder

    bag = tmp_path / "bag"
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        recorder = Recorder(context=context, namespace=NS, parameter_overrides=[
            Parameter("output", value=str(bag)),
            Parameter("topics", value=[contract.DEMAND, contract.DRIVE_ENABLE])])
        executor = node_runner.make_executor(context=context)
        executor.add_node(recorder)
        executor.spin_once(timeout_sec=0.1)
        # the supervisor comes up after the recorder
        supervisor = rclpy.create_node("supervisor", namespace=NS, context=context)
        best_effort = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                                 reliability=ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE)
        volatile = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                              reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
        pub_demand = ri.quiet_publisher(supervisor, Float64, contract.DEMAND, best_effort)
        pub_enable = ri.quiet_publisher(supervisor, Bool, contract.DRIVE_ENABLE, volatile)
        end = time.monotonic() + 8.0
        while pub_demand.get_subscription_count() < 1 or pub_enable.get_subscription_count() < 1:
            assert time.monotonic() < end, (
                f"recorder never matched the supervisor: demand {pub_demand.get_subscription_count()}, "
                f"drive_enable {pub_enable.get_subscription_count()}")
            executor.spin_once(timeout_sec=0.05)
        time.sleep(0.2)                                   # both ends of the match known
        sent = [Float64(data=0.01 * i) for i in range(100)]
        pub_enable.publish(Bool(data=True))
        for msg in sent:
            pub_demand.publish(msg)
            executor.spin_once(timeout_sec=0.0)
            time.sleep(0.001)                             # best effort: a pace the reader keeps
        end = time.monotonic() + 5.0
        while recorder.received < len(sent) + 1 and time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
        counts = recorder.finish()
        executor.shutdown()
        supervisor.destroy_node()
        recorder.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)

    assert counts == {f"{NS}/demand": len(sent), f"{NS}/drive_enable": 1}
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    qos = {t["topic_metadata"]["name"]: t["topic_metadata"]["offered_qos_profiles"]
           for t in meta["topics_with_message_count"]}
    assert [q["reliability"] for q in qos[f"{NS}/demand"]] == ["best_effort"]
    assert [q["durability"] for q in qos[f"{NS}/drive_enable"]] == ["volatile"]
    with AnyReader([bag]) as reader:
        raw = [data for conn, _, data in reader.messages() if conn.topic == f"{NS}/demand"]
    assert raw == [serialize_message(m) for m in sent]


def test_adapted_qos_only_weakens():
    pytest.importorskip("rclpy")
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
