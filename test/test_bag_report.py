"""fuel_valve_report / bag_io on bags written here with rosbags from an offline simulation (no
ROS processes): the report must reproduce fuel_valve_sim's metrics from the bag, for MCAP
and sqlite3, for a recorder-style bag (sim-time receive stamps) and a ``ros2 bag record``
style one (wall-clock receive stamps, /clock mapping, decimated demand); bad input gives
exit code 2 with a readable message."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

pytest.importorskip("rosbags")

from rosbags.rosbag2 import StoragePlugin, Writer  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

from fuel_valve_control.tools import report, sim  # noqa: E402
from fuel_valve_control.tools.bag_io import BagError, read_bag  # noqa: E402

TS = get_typestore(Stores.ROS2_JAZZY)
NS = "/fv"
WALL0 = 1_790_000_000_000_000_000        # a wall-clock epoch for ros2-bag-record-style stamps


@pytest.fixture(scope="module")
def step_small():
    return sim.run("step_small")


def _time(ns: int):
    Time = TS.types["builtin_interfaces/msg/Time"]
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def write_bag(path, result, storage="mcap", wall_clock=False, demand_every=1, topics=None):
    """A bag of the suite's topics from a SimResult (what the ROS nodes would publish)."""
    T = TS.types
    Float64, Bool = T["std_msgs/msg/Float64"], T["std_msgs/msg/Bool"]
    JointState, Header = T["sensor_msgs/msg/JointState"], T["std_msgs/msg/Header"]
    MAD, Dim, Layout = (T["std_msgs/msg/Float64MultiArray"], T["std_msgs/msg/MultiArrayDimension"],
                        T["std_msgs/msg/MultiArrayLayout"])
    Clock = T["rosgraph_msgs/msg/Clock"]
    c = result.column
    stroke = result.stroke_rad
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    all_topics = {"/clock": "rosgraph_msgs/msg/Clock", f"{NS}/demand": "std_msgs/msg/Float64",
                  f"{NS}/joint_states": "sensor_msgs/msg/JointState", f"{NS}/drive": "std_msgs/msg/Float64MultiArray",
                  f"{NS}/drive_enable": "std_msgs/msg/Bool", f"{NS}/current_command": "std_msgs/msg/Float64",
                  f"{NS}/estimate": "sensor_msgs/msg/JointState"}
    wanted = all_topics if topics is None else {k: v for k, v in all_topics.items() if k.rsplit("/", 1)[-1] in topics}
    with Writer(path, version=9, storage_plugin=plugin) as w:
        conns = {name: w.add_connection(name, typ, typestore=TS) for name, typ in wanted.items()}

        def put(topic, t_ns, msg, typ):
            if topic in conns:
                log = t_ns + (WALL0 + 250_000 if wall_clock else 0)
                w.write(conns[topic], log, TS.serialize_cdr(msg, typ))
        last_enable = None
        for k in range(len(result.log)):
            t_ns = int(round(c("t")[k] * 1e9))
            stamp = _time(t_ns)
            put("/clock", t_ns, Clock(clock=stamp), "rosgraph_msgs/msg/Clock")
            js = JointState(header=Header(stamp=stamp, frame_id=""), name=["motor_shaft", "valve_shaft"],
                            position=np.array([c("motor_rad")[k], c("position_rad")[k]]),
                            velocity=np.array([c("motor_velocity_rad_s")[k], c("velocity_rad_s")[k]]),
                            effort=np.array([0.0, 0.0]))
            put(f"{NS}/joint_states", t_ns, js, "sensor_msgs/msg/JointState")
            labels = ["i_d", "i_q", "friction_motor_nm", "friction_valve_nm"]
            values = [c("i_d_a")[k], c("i_q_a")[k], c("friction_motor_nm")[k], c("friction_valve_nm")[k]]
            put(f"{NS}/drive", t_ns, MAD(layout=Layout(dim=[Dim(label=lb, size=1, stride=1) for lb in labels],
                                                       data_offset=0), data=np.array(values)),
                "std_msgs/msg/Float64MultiArray")
            if k % demand_every == 0:
                put(f"{NS}/demand", t_ns, Float64(data=float(c("demand_rad")[k] / stroke * 100.0)),
                    "std_msgs/msg/Float64")
            enable = bool(c("enable")[k])
            if enable != last_enable:
                put(f"{NS}/drive_enable", t_ns, Bool(data=enable), "std_msgs/msg/Bool")
                last_enable = enable
            put(f"{NS}/current_command", t_ns, Float64(data=float(c("current_cmd_a")[k])), "std_msgs/msg/Float64")
            if k % 10 == 0:
                est = JointState(header=Header(stamp=stamp, frame_id=""), name=["motor_shaft", "valve_shaft"],
                                 position=np.array([0.0, c("estimate_rad")[k]]), velocity=np.array([0.0, 0.0]),
                                 effort=np.array([c("friction_est_motor_nm")[k], c("friction_est_valve_nm")[k]]))
                put(f"{NS}/estimate", t_ns, est, "sensor_msgs/msg/JointState")
    return path


def _close(a, b, rel=1e-9, abs_=1e-12):
    if a is None or b is None:
        return a is b
    return math.isclose(a, b, rel_tol=rel, abs_tol=abs_)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_report_reproduces_sim_metrics(tmp_path, step_small, storage):
    bag = write_bag(tmp_path / f"step_{storage}", step_small, storage)
    doc = report.analyse_bag(bag)
    assert doc["scenario"] == bag.name and doc["controller"] == "unknown"
    assert doc["bag"]["storage"] == storage
    assert set(doc["metrics"]) == set(step_small.metrics)
    for key, value in step_small.metrics.items():
        assert _close(doc["metrics"][key], value), (key, doc["metrics"][key], value)
    assert [s["kind"] for s in doc["segments"]] == [s["kind"] for s in step_small.segments]


def test_ros2_bag_record_style_bag(tmp_path, step_small):
    """Receive stamps in wall-clock time (ros2 bag record without --use-sim-time on a
    lockstep run) and a demand at 1/5 of the loop rate: mapped through /clock and held."""
    bag = write_bag(tmp_path / "wall", step_small, "mcap", wall_clock=True, demand_every=5)
    doc = report.analyse_bag(bag)
    m, ref = doc["metrics"], step_small.metrics
    assert doc["segments"][0]["kind"] == "step" and abs(doc["segments"][0]["t_start_s"] - 0.5) < 1e-9
    for key in ("rise_time_s", "settling_time_s", "overshoot_pct", "peak_current_a"):
        assert _close(m[key], ref[key], rel=1e-6), key
    assert _close(m["iae_rad_s"], ref["iae_rad_s"], rel=0.02)


def test_cli_outputs_and_json_shape(tmp_path, step_small, capsys):
    bag = write_bag(tmp_path / "cli", step_small, "mcap")
    js, png = tmp_path / "r.json", tmp_path / "r.png"
    assert report.main([str(bag), "--json", str(js), "--plot", str(png)]) == 0
    out = capsys.readouterr().out
    assert "rise_time_s" in out and "segments:" in out
    doc = json.loads(out.strip().splitlines()[-1])
    assert {"scenario", "controller", "metrics", "segments"} <= set(doc)
    assert json.loads(js.read_text()) == doc
    assert png.stat().st_size > 20_000
    # the .mcap file inside the bag directory is accepted as well
    assert report.analyse_bag(next(bag.glob("*.mcap")))["metrics"] == doc["metrics"]


def test_bag_io_columns(tmp_path, step_small):
    bag = read_bag(write_bag(tmp_path / "cols", step_small, "sqlite3"))
    js = bag.find("joint_states")
    assert len(js) == len(step_small.log) and np.all(np.diff(js.stamp_ns) > 0)
    np.testing.assert_allclose(js["valve_shaft.position"], step_small.column("position_rad"))
    assert {"i_d", "i_q", "friction_valve_nm"} <= set(bag.find("/fv/drive").columns)
    assert bag.find("estimate")["valve_shaft.effort"].shape == (len(step_small.log[::10]),)


# ------------------------------------------------------------------------------------- errors
def _run_main(capsys, *argv):
    code = report.main([str(a) for a in argv])
    return code, capsys.readouterr().err


def test_not_a_bag(tmp_path, capsys):
    f = tmp_path / "notes.txt"
    f.write_text("hello")
    code, err = _run_main(capsys, f)
    assert code == 2 and "not a rosbag2 bag" in err
    code, err = _run_main(capsys, tmp_path / "missing")
    assert code == 2 and "does not exist" in err
    d = tmp_path / "half"
    d.mkdir()
    (d / "half.mcap").write_bytes(b"\x89MCAP0\r\n")
    code, err = _run_main(capsys, d)
    assert code == 2 and "no metadata.yaml" in err and "unfinished" in err
    (d / "metadata.yaml").write_text("garbage: [")
    code, err = _run_main(capsys, d)
    assert code == 2 and "cannot read bag" in err


def test_empty_bag(tmp_path, capsys):
    with Writer(tmp_path / "empty", version=9, storage_plugin=StoragePlugin.MCAP) as w:
        w.add_connection(f"{NS}/demand", "std_msgs/msg/Float64", typestore=TS)
    code, err = _run_main(capsys, tmp_path / "empty")
    assert code == 2 and "empty" in err


def test_missing_topics(tmp_path, step_small, capsys):
    bag = write_bag(tmp_path / "partial", step_small, "mcap", topics={"clock", "demand"})
    code, err = _run_main(capsys, bag)
    assert code == 2 and "valve angle" in err and "current" in err and "/fv/demand" in err
    with pytest.raises(BagError):
        read_bag(tmp_path / "nothing_here")


def test_profile_s_judges_the_run_not_the_suites_shutdown(tmp_path, step_small, capsys):
    """fuel_valve_demo stops the demand node first, then the controller: the plant's drive
    watchdog lets the spring close the valve with no drive_enable false on record, and the last
    hold read the closing as a 0.18 rad error and a 0.14 rad limit cycle (a real-time demo bag,
    stop 15).  ``--profile-s``: the samples after the profile are the shutdown, left out."""
    import copy
    run = copy.deepcopy(step_small)
    t = run.column("t")
    tail = t > 1.5                                      # the "shutdown": the valve closes, enable on
    pos = run.log[:, sim.LOG_COLUMNS.index("position_rad")]
    pos[tail] *= np.exp(-(t[tail] - 1.5) / 0.05)
    run.log[tail, sim.LOG_COLUMNS.index("demand_rad")] = run.column("demand_rad")[~tail][-1]
    bag = write_bag(tmp_path / "shutdown", run, "mcap", demand_every=5)
    whole = report.analyse_bag(bag)
    assert whole["metrics"]["steady_state_error_rad"] > 0.1          # what the report said before
    assert report.main([str(bag), "--profile-s", "1.5"]) == 0
    doc = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert doc["sim_time_s"] == pytest.approx(1.5, abs=2e-3)
    assert doc["metrics"]["steady_state_error_rad"] < 1e-3
    assert "profile" in doc["bag"]["sources"]
    # equal to the same run cut at 1.5 s before it is recorded
    cut = copy.deepcopy(step_small)
    cut.log = cut.log[t <= 1.5 + 1e-9]
    ref = report.analyse_bag(write_bag(tmp_path / "cut", cut, "mcap", demand_every=5))
    assert doc["metrics"] == ref["metrics"]
    # nonsense is refused with a clear error
    assert report.main([str(bag), "--profile-s", "-1"]) == 2
    assert "must be positive" in capsys.readouterr().err
