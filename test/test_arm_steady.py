"""``faults.arm_steady_s``: in real time the drive's first arm waits for a steady resolver stream
(docs/control_results.md section 107; offline, no ROS, no plant).

A node process's start-up stall (the plant silent ~0.1 s while the controller was already armed)
latched "no resolver sample for 1xx ms" in about half the real-time start-ups.  The driver now arms
only once the stream has run on time for ``faults.arm_steady_s``; before that a silence restarts
the wait (the drive is off, the spring holds the valve) instead of latching.  After the arm a
silence latches as before.  Offline and in lockstep (no ``loop_timing``) it arms on the first
sample, so the campaigns are unchanged.
"""
from __future__ import annotations

import pytest

from fuel_valve_control.core.driver import RESOLVER_SETTLING, RESOLVER_STALE, ValveDriver
from fuel_valve_control.core.params import load_controller_params

VALVE_RAD = 0.3


@pytest.fixture(scope="module")
def params():
    return load_controller_params()


def _driver(params, **overrides) -> ValveDriver:
    return ValveDriver(params.replace(overrides) if overrides else params)


def _period(drv: ValveDriver, t: float, real_time: bool = True):
    """One period as the node runs it: the sample (stamped and received at ``t``), its timing
    (real time only), then the step."""
    drv.demand_percent(t, 40.0)
    drv.resolver(t, VALVE_RAD * drv.n, VALVE_RAD, now=t if real_time else None)
    if real_time:
        drv.loop_timing(t, t)
    return drv.step(t)


def _first_enabled(drv: ValveDriver, t0: float, seconds: float, real_time: bool = True) -> float | None:
    """Run periods from ``t0`` for ``seconds``; the time of the first with the drive enabled."""
    k = 0
    while k * drv.period < seconds:
        t = t0 + k * drv.period
        out = _period(drv, t, real_time)
        assert not out.faults, out.faults
        if out.enable:
            return t
        assert out.state == "waiting" and RESOLVER_SETTLING in out.warnings
        k += 1
    return None


def test_real_time_first_arm_waits_for_a_steady_stream(params):
    drv = _driver(params)
    wait = drv.ps["faults.arm_steady_s"]
    assert wait > 0.0
    assert not _period(drv, 1.0).enable
    health = drv.health()
    assert health.level == 1 and "resolver stream has run on time" in health.message
    armed = _first_enabled(drv, 1.0 + drv.period, 2 * wait)
    assert armed is not None and wait - drv.period <= armed - 1.0 <= wait + 2 * drv.period
    assert "resolver stream" not in drv.health().message


def test_a_silence_before_the_arm_restarts_the_wait_without_a_fault(params):
    drv = _driver(params)
    wait, period = drv.ps["faults.arm_steady_s"], drv.period
    assert _first_enabled(drv, 1.0, 0.5 * wait) is None            # half the wait on time
    out = drv.step(1.0 + 0.5 * wait + 0.1)                          # the stream silent 0.1 s (watchdog)
    assert not out.faults and not out.enable and RESOLVER_SETTLING in out.warnings
    resumed = 1.0 + 0.5 * wait + 0.1 + period
    armed = _first_enabled(drv, resumed, 2 * wait)
    assert armed is not None and armed - resumed >= wait - period   # a whole wait after the silence


def test_after_the_arm_a_silence_latches_as_before(params):
    drv = _driver(params)
    armed = _first_enabled(drv, 1.0, 1.0)
    assert armed is not None
    out = drv.step(armed + 0.1)
    assert RESOLVER_STALE in out.faults and not out.enable


def test_offline_and_zero_arm_on_the_first_sample(params):
    # offline (no loop_timing): the first period with a sample and a demand arms, as before
    assert _period(_driver(params), 1.0, real_time=False).enable
    # faults.arm_steady_s 0: in real time too
    assert _period(_driver(params, **{"faults.arm_steady_s": 0.0}), 1.0).enable


def test_activation_proves_the_stream_again(params):
    drv = _driver(params)
    armed = _first_enabled(drv, 1.0, 1.0)
    drv.set_inhibited(True)
    assert not _period(drv, armed + 0.1).enable
    drv.set_inhibited(False)
    again = _first_enabled(drv, armed + 0.1 + drv.period, 1.0)
    assert again is not None and again - (armed + 0.1) >= drv.ps["faults.arm_steady_s"] - drv.period
