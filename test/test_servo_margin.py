"""The stage's gear-output servo and the measured resolver delay (``fine.servo_margin_deg``, task s34, docs §118).

The 60 Hz servo's phase margin counts one loop period of lag (33 deg at 1 kHz); the gear output it holds is read
``resolver_delay_s`` late as well (31 deg at the nominal box's 50 us, 11 deg at 0.6 ms, none at 0.9 ms).  On the full
box's delayed plants the observe and hold servos rattled between -20 and +30 A at ~125 Hz (run 1032: a try that had
landed the valve 2.1e-4 rad off, then broke it loose backwards, 3.67e-3 rad).  With the option the servo's bandwidth is
lowered until the margin with the delay is the one asked for.  Off by default: the full box gets worse (docs §118)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from fuel_valve_control.core.params import CONTROLLER_SPEC
from fuel_valve_control.core.position_controller import PositionController


def _stage(delay_s: float, margin_deg: float):
    pc = PositionController(CONTROLLER_SPEC.defaults().replace(
        {"mode": "observer_fp", "resolver_delay_s": delay_s, "fine.servo_margin_deg": margin_deg}))
    return pc.law.fine, pc.model


def _margin_deg(fine, model, delay_s: float) -> float:
    return math.degrees(fine.servo_margin_rad(model.j1, fine.kp, fine.kd, fine.period + delay_s))


def test_the_option_is_off_by_default():
    assert CONTROLLER_SPEC.defaults()["fine.servo_margin_deg"] == 0.0


@pytest.mark.parametrize("delay_s", [3e-4, 6e-4, 9e-4])
def test_the_servo_is_slowed_to_the_margin_asked_for(delay_s):
    off, model = _stage(delay_s, 0.0)
    on, _ = _stage(delay_s, 30.0)
    assert _margin_deg(off, model, delay_s) < 25.0                    # the 60 Hz servo with the delay
    assert _margin_deg(on, model, delay_s) == pytest.approx(30.0, abs=0.05)
    assert on.servo_w < off.servo_w and on.kp < off.kp and on.kd < off.kd


def test_a_servo_with_margin_enough_is_the_designed_one():
    """The nominal box's 50 us delay leaves the 60 Hz servo 31 deg: asked for 30 it is unchanged, gain for gain."""
    off, _ = _stage(5e-5, 0.0)
    on, _ = _stage(5e-5, 30.0)
    assert (on.kp, on.kd, on.ki, on.servo_w) == (off.kp, off.kd, off.ki, off.servo_w)


def test_full_box_1032s_landed_valve_is_not_rattled_loose(robustness_bench):
    """Full box 1032 (Stribeck x0.54, backlash 1.3e-3 rad, 0.6 ms resolver delay): the run's first plateau, a 1.1e-3
    rad step the cold climb's first try lands 2.1e-4 rad off.  With the delay not counted the observe / hold servos
    then rattle at +-30 A and the valve ends 3.67e-3 rad off; with a 30 deg margin it stays.  (Since stop 35 the
    default reads this valve's resolver as noisy, ``fine.rest_noise_rate``, and its first plateau takes another path
    that ends 2.1e-4 rad off without the rattle: both runs here pin stop 34's sample-to-sample rest.)"""
    from fuel_valve_control.tools import sim
    case = robustness_bench.sample_case(1032, "full")

    def first(sets):
        res = sim.simulate_plan(robustness_bench.case_plan(case, None, sets))
        t = res.log[:, 0]
        cmd = res.log[:, sim.LOG_COLUMNS.index("current_cmd_a")]
        err = np.abs(res.log[:, 1] - res.log[:, 2])
        window = (t > 0.6) & (t < 0.7)
        return float(err[np.searchsorted(t, 0.72)]), int(np.sum(np.abs(cmd[window]) >= 25.0))

    stop34 = {"fine.rest_noise_rate": 0.0}
    err_off, big_off = first(stop34)
    err_on, big_on = first({**stop34, "fine.servo_margin_deg": 30.0})
    assert err_off > 3e-3 and big_off >= 5
    assert err_on < 5e-4 and big_on <= 2
