"""The demo's monitor (tools/monitor.py) and its summary: it samples (the newest value of each
topic, not every message), keeps the plant's own loop report of its namespace, and the demo
summary explains the loop figures and the loop's priority in words."""
from __future__ import annotations

import io
import time

import pytest

pytest.importorskip("rclpy")

pytestmark = [pytest.mark.ros]

NS = "/mon_test"


def _loop_status(name: str, ticks: int, missed: int):
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    st = DiagnosticStatus(name=name, hardware_id="fuel_valve_plant")
    st.values = [KeyValue(key=k, value=v) for k, v in {
        "ticks": str(ticks), "missed": str(missed), "missed_fraction": f"{missed / ticks:.6g}",
        "rtt_p99_ms": "0.5", "timer_slack_ns": "None"}.items()]
    return DiagnosticArray(status=[st])


def test_monitor_samples_the_newest_values_and_keeps_the_plant_loop_report():
    import rclpy
    from std_msgs.msg import Float64
    from fuel_valve_control.common import contract
    from fuel_valve_control.ros import interface as ri
    from fuel_valve_control.tools.monitor import Monitor

    mon = Monitor(NS, lockstep=False)
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node("monitor_feeder", namespace=NS, context=ctx)
    try:
        pub_demand = node.create_publisher(Float64, contract.DEMAND, ri.TELEMETRY_QOS)
        pub_diag = node.create_publisher(type(_loop_status("x", 1, 0)), contract.DIAGNOSTICS, 10)
        end = time.monotonic() + 30.0
        while pub_demand.get_subscription_count() < 1 or pub_diag.get_subscription_count() < 1:
            assert time.monotonic() < end, "the monitor never matched"
            time.sleep(0.05)
        assert mon.loop_statistics() is None
        for k in range(50):                    # a burst while the monitor sleeps: it sees the newest
            pub_demand.publish(Float64(data=float(k)))
        pub_diag.publish(_loop_status("/elsewhere/plant: loop", 10, 9))      # another valve's: ignored
        report = _loop_status(f"{NS}/plant: loop", 2000, 3)
        report.header.stamp.sec, report.header.stamp.nanosec = 1234, 500_000_000
        pub_diag.publish(report)
        end = time.monotonic() + 30.0
        while mon.demand != 49.0 or not mon.loop:
            assert time.monotonic() < end, (mon.demand, mon.loop)
            mon.spin_for(0.05)
        # sampled: the burst of 50 cost one callback (two if a take fell inside it), not 50 --
        # plus the two diagnostics
        assert mon._taken <= 4, mon._taken
        assert mon.loop_reports == 1                      # this valve's report only
        # its stamp: what the demo compares with the profile's end (a report queued while the
        # monitor was starved covers only part of the run)
        assert mon.loop_stamp == pytest.approx(1234.5)
        assert mon.loop_statistics() == {"ticks": 2000, "missed": 3, "missed_fraction": 0.0015, "rtt_p99_ms": 0.5,
                                         "timer_slack_ns": "None"}
    finally:
        node.destroy_node()
        rclpy.shutdown(context=ctx)
        mon.close()


def test_demo_summary_explains_the_loop_and_its_priority():
    from fuel_valve_control.tools import demo
    base = {"lockstep": False, "duration_s": 20.0, "wall_time_s": 25.0, "final_status": "t 20 s", "worst_level": 0,
            "loop": {"ticks": 20000, "missed": 40, "missed_fraction": 0.002, "rtt_median_ms": 0.3,
                     "rtt_p99_ms": 0.7}, "run_dir": "/tmp/x", "real_time_priority": ["plant", "controller"]}
    for refused, expect in (([], "real time (SCHED_FIFO) for plant, controller"),
                            (["SCHED_FIFO 10 for plant refused ([Errno 1] Operation not permitted): normal priority"],
                             "normal for plant: real-time priority (SCHED_FIFO) needs root or CAP_SYS_NICE")):
        out = io.StringIO()
        demo.print_summary(dict(base, scheduling_refused=refused), out)
        text = out.getvalue()
        assert "worst driver status: OK" in text
        assert "ticked 20000 times at 1 kHz; in 0.20 % of the ticks" in text
        assert f"loop priority: {expect}" in text


def test_monitor_shows_a_best_effort_supervisors_demand():
    """A supervisor publishing the demand best-effort (which the controller hears since h24u):
    the monitor must show it (a reliable subscription matched no such publisher)."""
    import rclpy
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Float64
    from fuel_valve_control.common import contract
    from fuel_valve_control.tools.monitor import Monitor

    mon = Monitor(NS + "_be", lockstep=False)
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node("supervisor", namespace=NS + "_be", context=ctx)
    try:
        pub = node.create_publisher(Float64, contract.DEMAND, QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))
        end = time.monotonic() + 5.0
        while pub.get_subscription_count() < 1:
            assert time.monotonic() < end, "the monitor never matched a best-effort demand publisher"
            time.sleep(0.05)
        end = time.monotonic() + 5.0
        while mon.demand != 0.37:
            assert time.monotonic() < end, mon.demand
            pub.publish(Float64(data=0.37))
            mon.spin_for(0.05)
    finally:
        node.destroy_node()
        rclpy.shutdown(context=ctx)
        mon.close()
