"""``fuel_valve_sim --trace`` and ``fuel_valve_report --trace``: the run's time series as CSV.

A user must be able to recompute any metric from the CSV alone: read it back with csv/numpy,
rebuild :class:`metrics.Trace` from its columns and compare with the tool's own JSON.  The bag
comes from the offline simulation through test_bag_report's writer (no ROS processes).
"""
from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest

from fuel_valve_control.tools import metrics as M
from fuel_valve_control.tools import sim
from fuel_valve_control.tools.trace import HEADER, read_trace, write_trace

STROKE = 1.0472


def _metrics_from_csv(path) -> dict:
    cols = read_trace(path)
    trace = M.Trace(cols["t_s"], cols["demand_rad"], cols["valve_rad"], cols["current_a"], cols["enable"], STROKE)
    return M.compute(trace)[0]


def _assert_same_metrics(recomputed: dict, reported: dict) -> None:
    assert set(recomputed) == set(reported)
    for key, value in reported.items():
        mine = recomputed[key]
        if value is None:                       # JSON null: not reached / not finite
            assert mine is None or not math.isfinite(mine), key
        else:
            assert mine == pytest.approx(value, rel=1e-12, abs=1e-15), key


def test_sim_trace_recomputes_the_sim_metrics(tmp_path, capsys):
    csv_path, js = tmp_path / "run.csv", tmp_path / "run.json"
    assert sim.main(["--scenario", "trip", "--trace", str(csv_path), "--json", str(js), "--seed", "3"]) == 0
    capsys.readouterr()
    with open(csv_path, newline="") as fh:
        rows = list(csv.reader(fh))
    assert tuple(rows[0]) == HEADER and rows[0][:2] == ["t_s", "demand_rad"]
    doc = json.loads(js.read_text())
    assert len(rows) - 1 == round(doc["sim_time_s"] * 1000)            # one row per 1 kHz period
    _assert_same_metrics(_metrics_from_csv(csv_path), doc["metrics"])
    cols = read_trace(csv_path)
    # the trip at 0.3 s: enable falls and the driver's fault is latched from then on
    t_trip = cols["t_s"][np.argmax(cols["enable"] < 0.5)]
    assert t_trip == pytest.approx(0.3, abs=1.5e-3)
    np.testing.assert_array_equal(cols["fault"], (cols["t_s"] >= t_trip).astype(float))
    assert cols["valve_rad"][-1] < 0.02 * STROKE                      # and the spring closed the valve
    # every column the simulator has is filled in
    assert all(np.any(np.isfinite(cols[name])) for name in HEADER)


def test_bag_trace_recomputes_the_report_metrics_and_matches_the_sim_trace(tmp_path, capsys):
    pytest.importorskip("rosbags")
    from test_bag_report import write_bag
    from fuel_valve_control.tools import report

    result = sim.run("step_small")
    bag = write_bag(tmp_path / "bag", result, "mcap")
    csv_path, js = tmp_path / "bag.csv", tmp_path / "bag.json"
    assert report.main([str(bag), "--trace", str(csv_path), "--json", str(js)]) == 0
    capsys.readouterr()
    doc = json.loads(js.read_text())
    _assert_same_metrics(_metrics_from_csv(csv_path), doc["metrics"])
    # same columns, same values as the simulator's own trace where the bag has them
    sim_csv = write_trace(tmp_path / "sim.csv", result.series())
    a, b = read_trace(csv_path), read_trace(sim_csv)
    assert list(a) == list(b) == list(HEADER)
    for name in ("t_s", "demand_rad", "valve_rad", "motor_rad", "valve_velocity_rad_s", "current_cmd_a",
                 "current_a", "i_q_a", "friction_valve_nm", "friction_motor_nm", "enable"):
        np.testing.assert_allclose(a[name], b[name], rtol=1e-9, atol=1e-9, err_msg=name)
    # the estimate is published every 10th period and held in between
    np.testing.assert_allclose(a["friction_valve_est_nm"][::10], b["friction_valve_est_nm"][::10], atol=1e-12)
    # what the bag does not carry is empty, not invented: no resolver topic, no fault history
    assert np.all(np.isnan(a["valve_measured_rad"])) and np.all(np.isnan(a["fault"]))


def test_write_trace_rejects_misaligned_columns(tmp_path):
    with pytest.raises(ValueError, match="demand_rad"):
        write_trace(tmp_path / "x.csv", {"t": np.arange(3.0), "demand": np.zeros(2)})
