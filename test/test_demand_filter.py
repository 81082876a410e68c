"""Demand conditioning (issue 14, deliverable 4): noise and single-sample glitches of an
analog demand do not become valve moves; genuine steps and the ±2 % sine still pass."""
import math

import numpy as np
import pytest

from fuel_valve_control.common.contract import STROKE_RAD
from fuel_valve_control.core.demand_filter import DemandFilter
from fuel_valve_control.core.driver import ValveDriver, demand_filter_config
from fuel_valve_control.core.params import CONTROLLER_SPEC
from fuel_valve_control.tools import sim
from fuel_valve_control.tools.scenarios import parse_scenario

PCT = STROKE_RAD / 100.0           # rad per percent of stroke
T = 1e-3


def _filter():
    return DemandFilter(demand_filter_config(CONTROLLER_SPEC.defaults()))


def _run(f, values):
    return np.array([f.update(k * T, v) for k, v in enumerate(values)])


def test_single_sample_glitches_never_reach_the_output():
    x = np.full(2000, 30.0 * PCT)
    for k, g in ((500, 0.6), (900, -0.6), (1400, 5.0)):
        x[k] += g * PCT
    y = _run(_filter(), x)
    assert np.ptp(y) == 0.0


def test_noise_is_estimated_and_held_out():
    rng = np.random.default_rng(1)
    sigma = 0.1 * PCT
    y = _run(f := _filter(), 30.0 * PCT + sigma * rng.standard_normal(3000))
    assert f.noise_rms == pytest.approx(sigma, rel=0.25)
    settled = y[1000:]
    # held: a few quantum-sized updates of the running mean, never a noise sample
    assert np.ptp(settled) < 0.5 * sigma
    assert abs(settled[-1] - 30.0 * PCT) < 0.3 * sigma


def test_a_clean_step_passes_exactly_and_promptly():
    x = np.where(np.arange(1000) >= 300, 20.1 * PCT, 20.0 * PCT)     # the smallest campaign step, 0.1 %
    y = _run(_filter(), x)
    arrived = int(np.flatnonzero(np.abs(y - x[-1]) < 1e-12)[0])
    assert arrived - 300 <= 1 + CONTROLLER_SPEC.defaults()["demand.confirm_samples"]
    assert np.all(np.abs(y[arrived:] - x[-1]) < 1e-12)


def test_a_noisy_step_ends_near_the_new_level():
    rng = np.random.default_rng(2)
    sigma = 0.1 * PCT
    x = np.where(np.arange(3000) >= 1500, 31.0 * PCT, 30.0 * PCT) + sigma * rng.standard_normal(3000)
    y = _run(_filter(), x)
    assert np.all(np.abs(y[1510:] - 31.0 * PCT) < 3.0 * sigma)
    assert abs(y[-1] - 31.0 * PCT) < 0.3 * sigma


def test_a_sine_passes_one_sample_late():
    t = np.arange(2000) * T
    x = (50.0 + 2.0 * np.sin(2 * math.pi * 20.0 * t)) * PCT
    y = _run(_filter(), x)
    err = y[100:] - np.roll(x, 1)[100:]
    assert np.max(np.abs(err)) < 0.02 * 2.0 * PCT        # the median of a smooth signal is its middle sample


def test_pi_baselines_take_the_raw_demand():
    for mode, conditioned in (("pi", False), ("pi_dither", False), ("observer_ff", True)):
        d = ValveDriver(CONTROLLER_SPEC.defaults().replace({"mode": mode}))
        for k in range(5):
            d.demand_percent(k * T, 30.0 + (0.6 if k == 4 else 0.0))
        assert (d.demand_rad() == pytest.approx(30.0 * PCT)) == conditioned


def _closed_loop(demand, duration=3.0, initial=30.0, mode=None):
    doc = {"name": "dc", "duration_s": duration, "initial_percent": initial, "pressure_differential_kpa": 6206,
           "demand": demand}
    sc = parse_scenario(doc)
    p, c = sim.build(sc, None, None, None, mode)
    return sim.simulate(sc, p, c)


@pytest.mark.parametrize("seed", [1, 2])
def test_demand_noise_does_not_move_the_valve(seed):
    """Issue 14 target: 0.1 % rms demand noise moves the valve by <= 3e-3 rad (was 6.8e-2)."""
    res = _closed_loop({"type": "constant", "percent": 30, "noise_rms_pct": 0.1, "noise_seed": seed})
    t, pos = res.column("t"), res.column("position_rad")
    assert np.ptp(pos[t >= 0.5]) <= 3e-3


def test_demand_glitches_do_not_move_the_valve():
    res = _closed_loop({"type": "constant", "percent": 30, "glitches": [[1.0, 0.6], [2.0, -0.6]]})
    t, pos = res.column("t"), res.column("position_rad")
    assert np.ptp(pos[t >= 0.5]) <= 3e-3


def test_sine_at_20hz_within_45_degrees_and_3db():
    """Issue 14 target: ±2 % sine, −3 dB >= 20 Hz and phase at 20 Hz within −45° (was −90°)."""
    f = 20.0
    res = _closed_loop({"type": "sine", "offset": 50, "amplitude": 2, "frequency_hz": f}, 1.5, 50.0)
    t = res.column("t")
    m = t >= 0.7
    basis = np.column_stack([np.sin(2 * np.pi * f * t[m]), np.cos(2 * np.pi * f * t[m]), np.ones(m.sum())])
    cp = np.linalg.lstsq(basis, res.column("position_rad")[m], rcond=None)[0]
    cd = np.linalg.lstsq(basis, res.column("demand_rad")[m], rcond=None)[0]
    h = complex(cp[0], cp[1]) / complex(cd[0], cd[1])
    assert abs(h) >= 1.0 / math.sqrt(2.0)
    assert math.degrees(math.atan2(h.imag, h.real)) >= -45.0
