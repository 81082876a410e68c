"""The recorder loses nothing on a real-time run (issue 10): plant, controller and demand at
1 kHz / 200 Hz as processes, the recorder started first, through the launcher as the main job
and ``benchmarks/ros_loop.py --record`` run it.

Every publishing node counts what it sends per topic and prints it at exit (node_runner);
with a recorder in the run they hold their first publish until it has matched
(``recorded_topics``, ``interface.RecorderGate``), and the launcher stops the publishers
first and the recorder last (it drains, then closes the bag).  So the bag's metadata must
hold exactly what was published, topic by topic: no start-up loss, no loss in the run, no
queue drop.  The run is short and the test waits on conditions, not on the clock's speed.
"""
from __future__ import annotations

import time

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("rosbags")

pytestmark = [pytest.mark.ros, pytest.mark.slow]

NS = "/fv_loss"
#: wall time the loop runs once every node has seen the recorder, s
RUN_S = 3.0


def test_real_time_run_bag_holds_every_published_message(tmp_path):
    from fuel_valve_control.tools.launcher import CLEAN_EXIT_CODES, PUBLISHING_NODES, Launcher
    from fuel_valve_control.tools.run_plan import REAL_TIME, plan_run
    from fuel_valve_control.tools.scenarios import parse_scenario

    scenario = parse_scenario({"name": "recorder_loss", "duration_s": 3600.0,
                               "demand": {"type": "sine", "offset": 40.0, "amplitude": 5.0, "frequency_hz": 0.5}})
    launcher = Launcher(plan_run(scenario, REAL_TIME), NS, tmp_path / "run", tmp_path / "bag")
    with launcher:
        launcher.start_recorder()                   # every suite topic
        launcher.start()
        for name in PUBLISHING_NODES:               # each node's hold ends when the recorder matched
            launcher.wait_for_log(name, "recorder matched", timeout_s=60.0)
        time.sleep(RUN_S)
        assert not launcher.failed(), {n: launcher.log_tail(n) for n in launcher.failed()}
        codes = launcher.stop()
    assert all(code in CLEAN_EXIT_CODES for code in codes.values()), codes

    report = launcher.recording_losses()
    topics = report["topics"]
    # the loop ran and every publishing node reported its counts
    assert topics[f"{NS}/resolver"]["published"] > 100, topics
    assert topics[f"{NS}/current_command"]["published"] > 100, topics
    assert topics[f"{NS}/demand"]["published"] > 20, topics
    assert topics[f"{NS}/drive_enable"]["published"] >= 1, topics
    assert topics["/diagnostics"]["published"] >= 1, topics
    # exactly what was published is in the bag, per topic; nothing went out before the match
    assert {t: v["in_bag"] for t, v in topics.items()} == {t: v["published"] for t, v in topics.items()}, topics
    assert {t: v["before_match"] for t, v in topics.items() if v["before_match"]} == {}, topics
    assert report["queue_dropped"] == 0, launcher.log_tail("recorder")
    assert report["lost"] == report["startup_lost"] == 0
