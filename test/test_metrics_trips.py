"""Trips in tools/metrics.py, on synthetic traces whose answer is known: a drive disabled for good
ends the step it happened in (the spring closes the valve, ``close_time_s``); a drive disabled for a
few ms and enabled again (a command watchdog's trip in real time, re-enabled by the loop) leaves the
step whole, so its end error is the valve's (docs/control_results.md §114: a start-up step cut at such a
blip read 3.8e-2 rad where the valve ended 3.4e-4 off)."""
import numpy as np
import pytest

from fuel_valve_control.tools import metrics as M

DT = 1e-3
STROKE = 1.0472


def _step_trace(enable_off: tuple[float, float] | None, close_after_s: float | None = None):
    """A 0 -> 0.24 rad step at 0.5 s, the valve there 0.1 s later and 3e-4 short; the drive off over
    ``enable_off`` (s, s); with ``close_after_s`` the valve closes (spring) from the disable on, this
    long to 2 % open."""
    t = np.arange(0.0, 3.0, DT)
    demand = np.where(t >= 0.5, 0.24, 0.0)
    pos = np.clip((t - 0.5) / 0.1, 0.0, 1.0) * (0.24 - 3e-4)
    enable = np.ones_like(t)
    if enable_off is not None:
        off = (t >= enable_off[0]) & (t < enable_off[1])
        enable[off] = 0.0
        if close_after_s is not None:
            k = t >= enable_off[0]
            pos[k] = np.maximum(pos[k][0] * (1.0 - (t[k] - enable_off[0]) / close_after_s), 0.0)
    return M.Trace(t, demand, pos, np.zeros_like(t), enable, STROKE)


def test_a_watchdog_blip_mid_move_leaves_the_step_whole():
    metrics, details = M.compute(_step_trace((0.55, 0.555)))
    steps = [s for s in details if s["kind"] == "step"]
    trips = [s for s in details if s["kind"] == "trip"]
    assert len(steps) == 1 and steps[0]["t_end_s"] == pytest.approx(3.0 - DT)
    assert steps[0]["steady_state_error_rad"] == pytest.approx(3e-4, rel=1e-6)
    # the blip is listed, from its disable to the re-enable; the valve did not close in it
    assert len(trips) == 1 and trips[0]["t_start_s"] == pytest.approx(0.55)
    assert trips[0]["t_end_s"] == pytest.approx(0.554) and trips[0]["close_time_s"] is None
    assert metrics["close_time_s"] is None


def test_a_drive_disabled_for_good_ends_the_step_and_the_spring_close_is_timed():
    metrics, details = M.compute(_step_trace((0.55, 3.0), close_after_s=0.05))
    steps = [s for s in details if s["kind"] == "step"]
    assert steps[0]["t_end_s"] == pytest.approx(0.549)                   # cut where the drive went off
    assert metrics["close_time_s"] == pytest.approx(0.05 * (1 - 0.02 * STROKE / (0.05 / 0.1 * 0.2397)), abs=2e-3)


def test_the_close_time_is_the_first_trip_that_closed_the_valve():
    tr = _step_trace((2.0, 3.0), close_after_s=0.05)
    tr.enable[int(0.7 / DT):int(0.705 / DT)] = 0.0                       # a blip before the trip
    metrics, details = M.compute(tr)
    assert [s["close_time_s"] is None for s in details if s["kind"] == "trip"] == [True, False]
    assert metrics["close_time_s"] == pytest.approx(0.05 * (1 - 0.02 * STROKE / 0.2397), abs=2e-3)
