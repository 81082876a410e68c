"""Robustness of the default mode on seeded samples of the campaign (issue 14, h14r): the
mechanisms behind the full-box runs that hunted or latched a fault, each checked on the
campaign seed that showed it (``benchmarks/robustness.py --seed S --runs 1`` reproduces one)
and on the unit that carries the fix."""
import functools

import pytest

from fuel_valve_control.core.integral_policy import IntegralPolicy

LIMIT_NM = 24.85          # continuous torque at the valve (15 A x 0.0345 N*m/A x 48.0)


@functools.lru_cache(maxsize=None)
def _run(rb, seed: int, **case_changes) -> dict:
    case = {**rb.sample_case(seed), **case_changes}
    return rb.run_case((case, "observer_ff", {}))


def test_learned_load_keeps_the_whole_held_load_within_the_continuous_torque():
    pol = IntegralPolicy(0.55, 2.9e-4, relax_time_s=0.3, load_limit_nm=LIMIT_NM)
    # a slip read with the drive at 30 N*m beyond a known load of 12.5 N*m: unbounded by the
    # known load the relax would aim at 12.5 + 24.85 N*m, beyond the continuous current
    assert pol.learn_load(30.0, 1.0, 5.5, known_nm=12.5) == pytest.approx(LIMIT_NM - 12.5)
    assert pol.learn_load(-40.0, -1.0, 5.5, known_nm=-3.0) == pytest.approx(-LIMIT_NM + 3.0)
    # inside the bound: the slip point less half the static friction, as before
    assert pol.learn_load(8.0, 1.0, 5.5, known_nm=12.5) == pytest.approx(8.0 - 2.75)


def test_integration_while_current_limited_only_takes_the_request_back():
    assert IntegralPolicy.accepts(+1e-4, 20.0, saturated=False)
    assert IntegralPolicy.accepts(-1e-4, 20.0, saturated=False)
    assert not IntegralPolicy.accepts(+1e-4, 20.0, saturated=True)     # deeper into the limit
    assert IntegralPolicy.accepts(-1e-4, 20.0, saturated=True)         # back toward it
    assert IntegralPolicy.accepts(+1e-4, -20.0, saturated=True)
    assert not IntegralPolicy.accepts(-1e-4, -20.0, saturated=True)


def test_a_held_heavy_load_does_not_latch_the_i2t_jam_fault(robustness_bench):
    """Seed 1019: 9.3 N*m unknown load at max Δp (within the continuous torque with spring and
    flow), K x 0.66, 1 count resolver noise.  Before: the learned load overshot to 18.2 N*m,
    the relax aimed beyond the continuous current, the I2t limit clamped the drive at 15 A
    with the valve held, the integrator (and so the relax) was frozen by the clamp and the
    ``overcurrent_i2t`` jam fault latched at 8.2 s."""
    r = _run(robustness_bench, 1019)
    assert not r["fault"]
    assert r["peak_current_a"] < 30.0
