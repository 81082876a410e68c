"""A bag survives a recorder crash (issue 13, defect 9).

* lockstep run (plant, controller, demand, recorder through the launcher), the recorder
  SIGKILLed in the middle, MCAP and sqlite3: ``recorder --reindex`` rebuilds metadata.yaml (and
  the MCAP footer), rosbags' AnyReader opens the bag, every message deserialises and the
  counts per topic in the metadata are the messages present;
* real time, sqlite3: what is committed at the SIGKILL covers the run up to at most 1 s before
  it (the recorder commits every ``FLUSH_INTERVAL_S``; rosbags alone commits only at close);
* reindex refuses a directory without a bag file and a bag closed cleanly.

Progress is waited for by condition (messages on the disk), never by fixed sleeps.  The
module runs in a DDS domain of its own (conftest.py).
"""
from __future__ import annotations

import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

pytest.importorskip("rclpy")
pytest.importorskip("rosbags")

from rosbags.highlevel import AnyReader  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

from fuel_valve_control.tools import bag_recovery  # noqa: E402
from fuel_valve_control.tools.launcher import Launcher  # noqa: E402
from fuel_valve_control.tools.recorder import FLUSH_INTERVAL_S  # noqa: E402
from fuel_valve_control.tools.run_plan import LOCKSTEP, REAL_TIME, plan_run  # noqa: E402
from fuel_valve_control.tools.scenarios import load_scenario  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.slow]

NS = "/fv_crash"
TS = get_typestore(Stores.ROS2_JAZZY)


def on_disk(bag: Path, storage: str) -> int:
    """Messages of the bag that have reached the disk so far (committed rows / complete MCAP
    records), read while the recorder runs."""
    files = list(bag.glob("*.db3" if storage == "sqlite3" else "*.mcap"))
    if not files:
        return 0
    if storage == "mcap":
        try:
            return sum(t.count for t in bag_recovery.scan_mcap(files[0])[0].values())
        except bag_recovery.RecoveryError:      # created, its header not written yet (a starved writer)
            return 0
    try:
        conn = sqlite3.connect(f"file:{files[0]}?mode=ro", uri=True, timeout=5.0)
        try:
            return conn.execute("SELECT COUNT(*) FROM messages").fetchone()[0]
        finally:
            conn.close()
    except sqlite3.Error:
        return 0


def wait_until(condition, timeout_s: float, what: str, launcher: Launcher) -> None:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if condition():
            return
        dead = launcher.failed()
        if dead:
            raise AssertionError(f"{dead} exited while waiting for {what}:\n"
                                 + "\n".join(launcher.log_tail(n) for n in dead))
        time.sleep(0.1)
    raise AssertionError(f"no {what} within {timeout_s} s")


def kill_recorder_and_stop(la: Launcher) -> None:
    """SIGKILL the recorder, then SIGINT to every other node at once; the caller checks the
    bag meanwhile and calls the launcher's stop at the end (it waits for each node, escalating
    as it does).  At exit every publishing node waits up to ``RecorderGate.DRAIN_S`` (5 s) for
    the recorder to acknowledge what it sent, and a SIGKILLed recorder never does (its DDS
    participant stays matched until its lease ends): stopped one after another, as the
    launcher's order has it, that was 5 s per node, 15 s per lockstep test before the bag was
    even looked at; now the waits overlap each other and the reindexing (nothing writes the
    bag once the recorder is dead)."""
    la.procs["recorder"].send_signal(signal.SIGKILL)
    la.procs["recorder"].wait(timeout=30)
    for proc in la.procs.values():
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)


def reindex_cli(bag: Path, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fuel_valve_control.tools.recorder", "--reindex", str(bag), *extra],
                          capture_output=True, text=True, timeout=120)


def read_back(bag: Path) -> tuple[dict, dict]:
    """(metadata counts per topic, messages read per topic; every one deserialised)."""
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    counts = {t["topic_metadata"]["name"]: t["message_count"] for t in meta["topics_with_message_count"]}
    read: dict[str, int] = {}
    with AnyReader([bag], default_typestore=TS) as reader:
        for conn, _t, raw in reader.messages():
            reader.deserialize(raw, conn.msgtype)
            read[conn.topic] = read.get(conn.topic, 0) + 1
        assert {c.topic: c.msgcount for c in reader.connections if c.msgcount} == read
    assert meta["message_count"] == sum(read.values())
    return counts, read


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_sigkilled_recorder_in_lockstep_the_bag_is_reindexed_and_reads_back(tmp_path, storage):
    plan = plan_run(load_scenario("step_small"), LOCKSTEP, duration_s=120.0)      # long: killed mid-run
    bag = tmp_path / "bag"
    la = Launcher(plan, NS, tmp_path, bag, storage, observers=1)
    try:
        la.start_recorder()
        la.start(("controller", "demand", "plant"))
        for name, text in (("recorder", "recording"), ("controller", "controller up"), ("demand", "demand up"),
                           ("plant", "plant up")):
            la.wait_for_log(name, text)
        la.start_gate()
        # mid-run: messages on the disk, and more after a later look (the run goes on)
        wait_until(lambda: on_disk(bag, storage) > 2000, 120.0, "messages on the disk", la)
        seen = on_disk(bag, storage)
        wait_until(lambda: on_disk(bag, storage) > seen, 60.0, "more messages on the disk", la)
        kill_recorder_and_stop(la)
        assert "stop_after_s reached" not in la.log("plant")        # it was mid-run
        # the bag is checked while the nodes finish their exit (see kill_recorder_and_stop)
        assert not (bag / "metadata.yaml").exists()                    # what a SIGKILL leaves
        with pytest.raises(Exception):
            with AnyReader([bag], default_typestore=TS):
                pass
        present = on_disk(bag, storage)
        out = reindex_cli(bag)
        assert out.returncode == 0, out.stderr
        counts, read = read_back(bag)
        assert {t: n for t, n in counts.items() if n} == read
        assert sum(read.values()) >= present > 2000
        assert any(t.endswith("/joint_states") for t in read) and any(t.endswith("/current_command") for t in read)
        # a second reindex refuses: the bag has its metadata now
        again = reindex_cli(bag)
        assert again.returncode == 2 and "exists" in again.stderr
    finally:
        la.stop()


def test_sqlite3_commits_at_least_every_second_in_real_time(tmp_path):
    """Real time (receive stamps are wall time): at the SIGKILL the committed messages reach
    to within 1 s of it."""
    plan = plan_run(load_scenario("step_small"), REAL_TIME, duration_s=120.0)
    bag = tmp_path / "bag"
    la = Launcher(plan, NS, tmp_path, bag, "sqlite3")
    assert FLUSH_INTERVAL_S <= 0.5          # half the bound: room for a scheduling stall
    try:
        la.start_recorder()
        la.wait_for_log("recorder", "recording")
        la.start(("plant",))                # publishes joint_states, resolver, ... at 1 kHz on its own
        wait_until(lambda: on_disk(bag, "sqlite3") > 1000, 120.0, "committed messages", la)
        first_seen = time.monotonic()
        # a few seconds of recording: committed counts keep growing while it runs
        wait_until(lambda: time.monotonic() - first_seen > 3.0 and on_disk(bag, "sqlite3") > 3000, 120.0,
                   "three seconds of committed messages", la)
        kill_ns = time.time_ns()
        kill_recorder_and_stop(la)
        assert reindex_cli(bag).returncode == 0
        meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
        newest_ns = meta["starting_time"]["nanoseconds_since_epoch"] + meta["duration"]["nanoseconds"]
        assert kill_ns - newest_ns <= 1_000_000_000, f"newest committed message {(kill_ns - newest_ns) / 1e9:.2f} s old"
        read_back(bag)
    finally:
        la.stop()


def test_reindex_refuses_what_it_cannot_recover(tmp_path):
    (tmp_path / "empty").mkdir()
    out = reindex_cli(tmp_path / "empty")
    assert out.returncode == 2 and "expected one .mcap or .db3" in out.stderr
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "junk.mcap").write_bytes(b"not an mcap file")
    out = reindex_cli(tmp_path / "junk")
    assert out.returncode == 2 and "not an MCAP file" in out.stderr
