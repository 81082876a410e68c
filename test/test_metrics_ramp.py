"""Ramp segments of tools/metrics.py (issue 14, task h19r): a followed ramp's tracking error and
lag, judged on synthetic traces whose answer is known."""
import numpy as np
import pytest

from fuel_valve_control.tools import metrics as M

DT = 1e-3
RATE = 7e-3          # rad/s: the `startup` profile's 23 -> 25 % in 3 s


def _profile(points):
    """Demand at 1 kHz, linear between ``(t s, rad)`` points (a repeated time is a step)."""
    t = np.arange(0.0, points[-1][0], DT)
    ts = [p[0] for p in points]
    return t, np.interp(t, ts, [p[1] for p in points])


def _trace(t, demand, position):
    return M.Trace(t, demand, position, np.zeros_like(t), np.ones_like(t))


def test_a_ramp_between_plateaus_is_found_and_a_lagging_valve_is_measured():
    t, d = _profile([(0.0, 0.2), (1.0, 0.2), (4.0, 0.2 + 3.0 * RATE), (6.0, 0.2 + 3.0 * RATE)])
    lag = 0.05                                          # s: the valve follows 0.05 s late
    pos = np.interp(t - lag, t, d)
    metrics, details = M.compute(_trace(t, d, pos))
    ramps = [s for s in details if s["kind"] == "ramp"]
    assert len(ramps) == 1
    assert ramps[0]["t_start_s"] == pytest.approx(1.0, abs=2 * DT)
    assert ramps[0]["t_end_s"] == pytest.approx(4.0, abs=2 * DT)
    assert ramps[0]["rate_rad_s"] == pytest.approx(RATE, rel=1e-3)
    assert metrics["ramp_max_error_rad"] == pytest.approx(RATE * lag, rel=1e-2)
    assert metrics["ramp_lag_s"] == pytest.approx(lag, rel=2e-2)


def test_a_valve_stuck_through_a_ramp_shows_the_whole_ramp_as_its_error():
    t, d = _profile([(0.0, 0.2), (1.0, 0.2), (4.0, 0.2 + 3.0 * RATE), (6.0, 0.2 + 3.0 * RATE)])
    pos = np.full_like(t, 0.2)
    metrics, _ = M.compute(_trace(t, d, pos))
    assert metrics["ramp_max_error_rad"] == pytest.approx(3.0 * RATE, rel=1e-2)
    assert metrics["ramp_lag_s"] == pytest.approx(1.6, rel=2e-2)     # mean error 1.6 s of ramp, from 0.2 s on


def test_the_first_settle_time_of_a_ramp_is_not_judged():
    t, d = _profile([(0.0, 0.2), (1.0, 0.2), (4.0, 0.2 + 3.0 * RATE), (6.0, 0.2 + 3.0 * RATE)])
    pos = d.copy()
    early = (t > 1.0) & (t < 1.0 + 0.9 * M.RAMP_SETTLE_S)
    pos[early] = 0.2                                      # picks the ramp up late
    metrics, _ = M.compute(_trace(t, d, pos))
    assert metrics["ramp_max_error_rad"] == pytest.approx(0.0, abs=1e-12)
    pos[(t > 2.0) & (t < 2.1)] -= 3e-3                    # later it counts
    metrics, _ = M.compute(_trace(t, d, pos))
    assert metrics["ramp_max_error_rad"] == pytest.approx(3e-3, rel=1e-6)


def test_a_reversing_ramp_is_two_ramps_and_the_worst_is_reported():
    t, d = _profile([(0.0, 0.5), (0.5, 0.5), (1.5, 0.4), (2.5, 0.5), (3.5, 0.5)])
    pos = d.copy()
    pos[(t > 2.0) & (t < 2.2)] += 4e-3                    # ahead on the way back
    metrics, details = M.compute(_trace(t, d, pos))
    ramps = [s for s in details if s["kind"] == "ramp"]
    assert [round(r["rate_rad_s"], 3) for r in ramps] == [-0.1, 0.1]
    assert ramps[0]["ramp_max_error_rad"] == pytest.approx(0.0, abs=1e-12)
    assert metrics["ramp_max_error_rad"] == pytest.approx(4e-3, rel=1e-6)


def test_steps_sweeps_and_short_or_tiny_ramps_are_no_ramps():
    t, d = _profile([(0.0, 0.2), (1.0, 0.2), (1.0, 0.25), (2.0, 0.25),        # a step
                     (2.2, 0.26), (3.0, 0.26),                                # 0.2 s: too short
                     (4.0, 0.26 + 0.5 * M.MIN_STEP_RAD), (5.0, 0.26 + 0.5 * M.MIN_STEP_RAD)])  # too small
    metrics, details = M.compute(_trace(t, d, d))
    assert not [s for s in details if s["kind"] == "ramp"] and "ramp_max_error_rad" not in metrics
    t = np.arange(0.0, 4.0, DT)
    d = 0.5 + np.where((t > 1.0) & (t < 3.0), 0.02 * np.sin(2 * np.pi * 5.0 * (t - 1.0)), 0.0)
    _, details = M.compute(_trace(t, d, d))
    assert [s["kind"] for s in details if s["kind"] in ("ramp", "sweep")] == ["sweep"]


def test_a_ramp_to_the_end_of_the_trace_is_measured():
    t, d = _profile([(0.0, 0.2), (1.0, 0.2), (3.0, 0.2 + 2.0 * RATE)])
    pos = d - 1e-3
    metrics, _ = M.compute(_trace(t, d, pos))
    assert metrics["ramp_max_error_rad"] == pytest.approx(1e-3, rel=1e-6)


@pytest.mark.parametrize("period_s", [0.005, 0.01, 0.02])
def test_a_ramp_recorded_as_held_demand_messages_is_a_ramp_not_a_sweep(period_s):
    # in a bag the demand is the last message received, sampled at each position sample: a ramp
    # published every few ms reads as a staircase.  Its flat treads are no extrema: judged as
    # extrema, every ramp of the main job's report was listed as a "sweep" without its error
    t, d = _profile([(0.0, 0.2), (1.0, 0.2), (4.0, 0.2 + 3.0 * RATE), (6.0, 0.2 + 3.0 * RATE)])
    held = np.interp(np.floor(t / period_s) * period_s, t, d)
    lag = 0.05
    pos = np.interp(t - lag, t, d)
    metrics, details = M.compute(_trace(t, held, pos))
    kinds = [s["kind"] for s in details]
    assert "sweep" not in kinds and kinds.count("ramp") == 1, kinds
    # the held demand is at most one message behind the true one: the error is the valve's lag
    assert metrics["ramp_max_error_rad"] == pytest.approx(RATE * lag, rel=0.05)


def test_a_sampled_sine_is_still_a_sweep():
    t = np.arange(0.0, 6.0, DT)
    d = np.where((t > 1.0) & (t < 5.0), 0.2 + 0.02 * np.sin(2 * np.pi * 2.0 * (t - 1.0)), 0.2)
    held = np.interp(np.floor(t / 0.005) * 0.005, t, d)
    _, details = M.compute(_trace(t, held, held))
    assert [s["kind"] for s in details].count("sweep") == 1
