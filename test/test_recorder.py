"""The ``recorder`` node on a live lockstep run (plant, controller, demand as processes, like
step_small: max dp, held at 20 %, step to 22 % at 0.5 s).

* the MCAP bag reads back with rosbags' AnyReader: expected topics and counts, metadata
  version 9, every message deserialises, per-topic receive times monotonic, type hashes
  and definitions those of Jazzy (MCAP publish time = DDS source time: a known shortfall, xfail);
* fuel_valve_report on it agrees with fuel_valve_sim --scenario step_small (tolerance below);
* sqlite3 storage, stopped by SIGINT in the middle of the run: a finalised, readable bag;
* refuses to overwrite an existing output unless told to, never deletes a non-bag directory.

The module runs in a DDS domain of its own (conftest.py).  Wall time: about 30 s on 2 cores.
"""
from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

pytest.importorskip("rclpy")
pytest.importorskip("rosbags")

from rosbags.highlevel import AnyReader  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.slow]

NS = "/fv_rec"
DURATION_S = 2.0
PERIODS = int(round(DURATION_S * 1000)) + 1      # samples 0 .. 2.000 s at 1 kHz
#: report vs offline simulator on the same scenario: times within one control period, the
#: rest relative (the bag has the sample at 2.000 s the simulator's log stops short of)
TIME_TOL_S = 1.5e-3
REL_TOL = 2e-3
TS = get_typestore(Stores.ROS2_JAZZY)


def step_small_plan(duration_s: float = DURATION_S):
    """The run-plan of step_small in lockstep, ``duration_s`` long (default 2 s)."""
    from fuel_valve_control.tools.run_plan import LOCKSTEP, plan_run
    from fuel_valve_control.tools.scenarios import load_scenario
    return plan_run(load_scenario("step_small"), LOCKSTEP, duration_s=duration_s)


class LockstepRun:
    """recorder + controller + demand, then the plant (lockstep) once the others are up, then a
    gate participant (see :meth:`Launcher.start_gate`): the plant only starts when every
    subscriber had time to match."""

    def __init__(self, tmp: Path, bag: Path, storage: str = "mcap", duration_s: float = DURATION_S):
        from fuel_valve_control.tools.launcher import Launcher
        self.bag = bag
        self.launcher = Launcher(step_small_plan(duration_s), NS, tmp, bag, storage, observers=1)

    def log(self, name) -> str:
        return self.launcher.log(name)

    def wait_for(self, name, text, timeout=40.0):
        self.launcher.wait_for_log(name, text, timeout)

    def start(self):
        la = self.launcher
        la.start_recorder()
        la.start(("controller", "demand", "plant"))
        for name, text in (("recorder", "recording"), ("controller", "controller up"), ("demand", "demand up"),
                           ("plant", "plant up")):
            self.wait_for(name, text)
        time.sleep(1.0)
        la.start_gate()

    def stop(self, names=None) -> dict:
        return self.launcher.stop(names, grace_s=15.0)


def read_all(bag: Path):
    """{topic: [(log_ns, msg)]}, connections (every message deserialised)."""
    out: dict[str, list] = {}
    with AnyReader([bag], default_typestore=TS) as reader:
        conns = {c.topic: c for c in reader.connections}
        for conn, t, raw in reader.messages():
            out.setdefault(conn.topic, []).append((t, reader.deserialize(raw, conn.msgtype)))
    return out, conns


def mcap_messages(path: Path):
    """(channel topic, sequence, log_time, publish_time) of every message: a minimal MCAP
    reader for uncompressed chunks (what the recorder writes)."""
    import struct
    data = path.read_bytes()
    assert data[:8] == b"\x89MCAP0\r\n"
    channels, out = {}, []

    def records(buf, pos, end):
        while pos + 9 <= end:
            op, length = buf[pos], struct.unpack_from("<Q", buf, pos + 1)[0]
            yield op, buf[pos + 9:pos + 9 + length]
            pos += 9 + length

    def handle(op, body):
        if op == 0x04:
            cid, _sid, tlen = struct.unpack_from("<HHI", body, 0)
            channels[cid] = body[8:8 + tlen].decode()
        elif op == 0x05:
            cid, seq, log, pub = struct.unpack_from("<HIQQ", body, 0)
            out.append((channels[cid], seq, log, pub))
    for op, body in records(data, 8, len(data) - 8):
        if op == 0x06:                                      # chunk
            _s, _e, _usize, _crc = struct.unpack_from("<QQQI", body, 0)
            clen = struct.unpack_from("<I", body, 28)[0]
            comp = body[32:32 + clen].decode()
            assert comp == "", comp
            size = struct.unpack_from("<Q", body, 32 + clen)[0]
            inner = body[40 + clen:40 + clen + size]
            for op2, b2 in records(inner, 0, len(inner)):
                handle(op2, b2)
        elif op == 0x04 and not out:
            handle(op, body)
    return out


@pytest.fixture(scope="module")
def lockstep_bag(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("rec_mcap")
    run = LockstepRun(tmp, tmp / "step_small_bag", "mcap")
    t0 = time.monotonic()
    try:
        run.start()
        run.wait_for("plant", "stop_after_s reached", timeout=60)
    finally:
        codes = run.stop()
    run.wall_s = time.monotonic() - t0
    run.codes = codes
    return run


def test_recorded_bag_reads_back(lockstep_bag):
    run = lockstep_bag
    assert run.codes["recorder"] == 0, run.log("recorder")
    meta = yaml.safe_load((run.bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["version"] == 9 and meta["storage_identifier"] == "mcap"
    counts = {t["topic_metadata"]["name"]: t["message_count"] for t in meta["topics_with_message_count"]}
    msgs, conns = read_all(run.bag)
    # metadata counts are the messages in the file
    assert {k: len(v) for k, v in msgs.items()} == {k: v for k, v in counts.items() if v}
    assert meta["message_count"] == sum(counts.values())
    # /clock is the valve's own clock in lockstep (launcher.clock_remap)
    expected = {"/diagnostics"} | {f"{NS}/{t}" for t in (
        "clock", "demand", "demand_ma", "position", "current_command", "drive_enable", "resolver", "joint_states",
        "drive", "drive_status", "estimate", "pressure_differential", "valve_test",   # valve_test: no test run, 0 messages
        "current_fallback")}
    assert set(counts) == expected
    # every message the nodes published is in the bag, topic by topic (a tick the plant re-published
    # after a wall-clock stall -- /clock and resolver -- was sent twice and is in it twice) ...
    published = run.launcher.recording_losses()["topics"]
    assert {t: v["in_bag"] for t, v in published.items()} == {t: v["published"] for t, v in published.items()}
    # the demand node publishes percent; no valve test ran, so nothing was published on valve_test
    assert set(published) == expected - {f"{NS}/demand_ma", f"{NS}/valve_test"}
    # ... and every period is in it once per topic
    for topic in ("joint_states", "drive", "current_command", "demand"):
        assert counts[f"{NS}/{topic}"] == PERIODS, (topic, counts[f"{NS}/{topic}"])
    resolver = {m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for _, m in msgs[f"{NS}/resolver"]}
    assert len(resolver) == PERIODS
    assert counts[f"{NS}/position"] == PERIODS // 10 and counts[f"{NS}/demand_ma"] == 0
    assert counts[f"{NS}/drive_enable"] >= 1
    # the Δp transducer samples at 100 Hz of plant time: every 10th period, from the first
    assert counts[f"{NS}/pressure_differential"] == -(-PERIODS // 10)
    for topic, items in msgs.items():
        log = np.array([t for t, _ in items])
        assert np.all(np.diff(log) >= 0), topic
    # sim-time receive stamps: the clock's receive time is the time it carries (or later)
    clock_all = np.array([m.clock.sec * 10**9 + m.clock.nanosec for _, m in msgs[f"{NS}/clock"]])
    assert np.all(np.array([t for t, _ in msgs[f"{NS}/clock"]]) >= clock_all)
    clock = np.unique(clock_all)                        # re-published ticks once
    assert len(clock) == PERIODS and np.all(np.diff(clock) == 1_000_000) and clock[0] == 0
    js = msgs[f"{NS}/joint_states"]
    stamps = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for _, m in js])
    np.testing.assert_array_equal(stamps, clock)
    # definitions and hashes are Jazzy's
    for topic, conn in conns.items():
        assert conn.digest == TS.hash_rihs01(conn.msgtype), topic
        assert conn.msgdef.data == TS.generate_msgdef(conn.msgtype, ros_version=2)[0]
    assert {t["topic_metadata"]["type_description_hash"] for t in meta["topics_with_message_count"]} == \
        {TS.hash_rihs01(c.msgtype) for c in conns.values()}


@pytest.mark.xfail(strict=True, reason="rosbags' public Writer.write(connection, timestamp, data) has no publish "
                   "time or sequence argument (it writes publish_time = log_time, sequence = 0), and rclpy's "
                   "events executor cannot pass the message info (source timestamp) to a callback (issue 10)")
def test_mcap_publish_time_and_sequence(lockstep_bag):
    (mcap,) = lockstep_bag.bag.glob("*.mcap")
    recs = mcap_messages(mcap)
    by_topic: dict[str, list] = {}
    for topic, seq, log, pub in recs:
        by_topic.setdefault(topic, []).append((seq, log, pub))
    js = by_topic[f"{NS}/joint_states"]
    # sequence numbers 1, 2, ... (compared as arrays: a failing == of two 2000-item lists makes pytest build a
    # full difflib diff when the CI variable is set -- 445 s of the suite's time for this strict xfail)
    seq = np.array([s for s, _, _ in js])
    assert np.array_equal(seq, np.arange(1, len(js) + 1)), f"sequence numbers {seq[:5]} ..., not 1, 2, ..."
    pub = np.array([p for _, _, p in js])
    assert np.all(pub > 1_000_000_000 * 10**9)          # DDS source time: system clock, not sim time
    assert np.all(np.diff(pub) >= 0)
    log = np.array([lg for _, lg, _ in js])
    assert log.max() < 10 * 10**9                        # receive time: sim time


def test_report_agrees_with_offline_sim(lockstep_bag, capsys):
    from fuel_valve_control.tools import report, sim
    code = report.main([str(lockstep_bag.bag)])
    out = capsys.readouterr().out
    print(out)
    assert code == 0
    doc = report.analyse_bag(lockstep_bag.bag)
    ref = sim.run("step_small")
    assert doc["controller"] == ref.controller
    assert [s["kind"] for s in doc["segments"]] == [s["kind"] for s in ref.segments] == ["step"]
    m = doc["metrics"]
    assert set(m) == set(ref.metrics)
    for key, value in ref.metrics.items():
        if key.endswith("_s") and key != "iae_rad_s":
            assert abs(m[key] - value) <= TIME_TOL_S, (key, m[key], value)
        else:
            assert m[key] == pytest.approx(value, rel=REL_TOL, abs=1e-9), (key, m[key], value)


#: simulated time the interrupted run has reached before its SIGINT, s
MID_RUN_S = 0.3


def _wait_for_sim_time(t_s: float, timeout: float = 60.0) -> None:
    """Block until the plant's ground truth (``joint_states``, lockstep stamps = simulated
    time) has reached ``t_s``: a listener only, not a lockstep participant."""
    from ros_probe import Probe
    from fuel_valve_control.common import contract
    probe = Probe(NS)
    try:
        def reached():
            msg = probe.get(contract.JOINT_STATES)
            return msg is not None and msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec >= t_s
        probe.wait_for(reached, timeout, f"simulated time {t_s} s")
    finally:
        probe.close()


def test_sigint_mid_run_leaves_a_readable_sqlite3_bag(tmp_path):
    from fuel_valve_control.tools import report
    # a run far longer than the wait below, so it is mid-run however fast lockstep goes
    run = LockstepRun(tmp_path, tmp_path / "interrupted", "sqlite3", duration_s=60.0)
    try:
        run.start()
        run.wait_for("plant", "participants connected", timeout=60)
        # mid-run: wait for progress, not for a wall time (a loaded CI machine once took the
        # 1 s re-send of a lost first tick: one joint_states sample after a fixed 1 s sleep)
        _wait_for_sim_time(MID_RUN_S)
        assert "stop_after_s reached" not in run.log("plant")
        codes = run.stop(("recorder",))
        assert codes["recorder"] == 0, run.log("recorder")
    finally:
        run.stop()
    meta = yaml.safe_load((run.bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["storage_identifier"] == "sqlite3"
    msgs, _ = read_all(run.bag)
    counts = {t["topic_metadata"]["name"]: t["message_count"] for t in meta["topics_with_message_count"]}
    assert {k: len(v) for k, v in msgs.items()} == {k: v for k, v in counts.items() if v}
    n = counts[f"{NS}/joint_states"]
    assert MID_RUN_S * 1000 <= n < 60 * 1000
    assert "closed:" in run.log("recorder")
    doc = report.analyse_bag(run.bag)
    assert doc["bag"]["storage"] == "sqlite3" and doc["metrics"]["peak_current_a"] > 0


def _recorder(tmp_path, *params):
    from fuel_valve_control.tools.launcher import executable
    cmd = executable("recorder") + ["--ros-args", "-r", f"__ns:={NS}"]
    for p in params:
        cmd += ["-p", p]
    env = dict(os.environ)
    return subprocess.Popen(cmd, env=env, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def test_existing_output_is_not_overwritten(tmp_path):
    existing = tmp_path / "bag1"
    existing.mkdir()
    (existing / "metadata.yaml").write_text("x")
    other = tmp_path / "photos"
    other.mkdir()
    (other / "a.jpg").write_text("keep")
    # the three refusals are independent (different outputs): their recorders start side by
    # side, so the suite waits for one process start-up instead of three
    refused = {"existing bag": _recorder(tmp_path, f"output:={existing}"),
               # a directory that is not a bag is never deleted, even with overwrite
               "not a bag": _recorder(tmp_path, f"output:={other}", "overwrite:=true"),
               # bad storage: configuration error
               "bad storage": _recorder(tmp_path, "output:=x", "storage:=rosbag1")}
    outs = {case: p.communicate(timeout=60)[0] for case, p in refused.items()}
    out, code = outs["existing bag"], refused["existing bag"].returncode
    assert code == 2 and "exists already" in out and "overwrite:=true" in out, out
    assert (existing / "metadata.yaml").read_text() == "x"
    out, code = outs["not a bag"], refused["not a bag"].returncode
    assert code == 2 and "not a bag" in out and (other / "a.jpg").exists(), out
    out, code = outs["bad storage"], refused["bad storage"].returncode
    assert code == 2 and "storage" in out, out
    # overwrite:=true replaces an existing bag; SIGTERM with no traffic gives an empty, valid bag
    p = _recorder(tmp_path, f"output:={existing}", "overwrite:=true", "topics:=['demand']")
    end = time.monotonic() + 20
    while not any(existing.glob("*.mcap")):              # the old bag is gone, the new one open
        assert time.monotonic() < end and p.poll() is None
        time.sleep(0.05)
    time.sleep(0.3)
    p.send_signal(signal.SIGTERM)
    out, _ = p.communicate(timeout=20)
    assert p.returncode == 0, out
    meta = yaml.safe_load((existing / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["message_count"] == 0
    assert [t["topic_metadata"]["name"] for t in meta["topics_with_message_count"]] == [f"{NS}/demand"]
