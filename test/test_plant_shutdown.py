"""The plant's real-time tick thread at the end of a process (``node_runner.run_node``'s
``on_exit`` -> ``PlantNode.stop()`` -> ``tear_down``): ``stop()`` joins the thread for at most
1 s; on a starved machine the thread can still be mid-tick when the node is destroyed and the
context shut down.  What it does then must end the thread quietly -- no thread traceback in the
log (``test_node_runner`` asserts none) and no drive fault latched for the process's own end.
"""
from __future__ import annotations

import threading
import time

import pytest

pytest.importorskip("rclpy")

pytestmark = [pytest.mark.ros]


def test_a_tick_thread_still_running_after_stop_and_tear_down_ends_quietly(monkeypatch):
    import rclpy
    from fuel_valve_plant.ros import plant_node as pn

    escaped: list[BaseException] = []
    monkeypatch.setattr(threading, "excepthook", lambda args: escaped.append(args.exc_value))
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    node = pn.PlantNode(context=ctx, namespace="/plant_shutdown_test")
    starved, release = threading.Event(), threading.Event()
    add_late = node.stats.add_late

    def late(seconds):
        # the tick thread woke from its sleep after stop() had been asked: hold it here (a thread
        # the scheduler does not run) until the node and its context are gone
        if not node._running:
            starved.set()
            release.wait(10.0)
        add_late(seconds)

    node.stats.add_late = late
    try:
        end = time.monotonic() + 10.0
        while node.plant.time < 0.02 and time.monotonic() < end:    # ticking
            time.sleep(0.01)
        assert node.plant.time >= 0.02
        thread = node._thread
        monkeypatch.setattr(thread, "join", lambda timeout=None: None)   # the join that timed out
        node.stop()
        assert starved.wait(5.0)
        # the controller ended with the same signal: its last sample is unanswered, so this
        # tick trips the drive watchdog, which reports the drive state (a publish)
        node.stats.commands = 1
        node._awaiting_since = node.plant.time - 1.0
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    finally:
        release.set()
    threading.Thread.join(thread, 5.0)          # the real join (the instance's is patched)
    assert not thread.is_alive()
    assert escaped == []
    assert node._fault is None
