"""``fine.engage_gear_rest`` (task h37m, docs §95; 0.1, on by default since stop 28, docs §108): the fine stage does not engage while the gear
output still winds the twist away from the target -- the valve at rest there sits in a stick mid-swing of the main
law's last move and slides on (traced: nominal box seed 4022 #11, C1 + the mixture law: an engagement 9 periods
after the valve stuck, the twist still falling 1e-4 rad a period onto the other way's edge, was handed back when
the valve slid on, and the main law's move back left the plateau 5.5e-3 rad off).

Stage only (no plant): the gate on the engage time, both directions."""
import pytest

from test_fine_positioning import _break_loose, _rest_twist, _stage


def _engage_period(fine, err, p, rate_tol, unwind_periods):
    """Periods from a new steady demand ``err`` (rad) off a valve at rest until the stage engages, the gear output
    moving ``rate_tol`` tolerances a period *toward* the target (< 0: away) for the first ``unwind_periods``
    periods, then still (the main law's deadband 4e-3 rad: no fresh wait, fine.engage_inside_deadband)."""
    thl = 0.5
    _break_loose(fine, thl, p)
    th1 = thl + _rest_twist(fine, thl, p)
    d = 1 if err > 0 else -1
    for k in range(1, 200):
        if k <= unwind_periods:
            th1 += d * rate_tol * fine.cfg.tolerance_rad
        fine.main_deadband_rad = 4e-3
        fine.update(thl + err, th1, thl, True, 0.3, p)
        if fine.phase != "idle":
            return k
    return None


@pytest.mark.parametrize("direction", [1, -1])
def test_no_engagement_while_the_gear_unwinds_away_from_the_target(direction):
    err = direction * 2.0e-3
    base = {"fine.engage_inside_deadband": True}
    off, m = _stage(**{**base, "fine.engage_gear_rest": 0.0})
    p = m.pressure_max_kpa
    n = off.cfg.engage_periods
    unwind = 3 * n                                       # still unwinding well past the engage time
    # off: the valve's rest alone -- it engages mid-unwind, at the engage time
    k_off = _engage_period(off, err, p, -0.75, unwind)
    assert k_off is not None and k_off <= n + 2
    # on: not before the unwinding stops, then at once (the valve has been at rest all along)
    on, _ = _stage(**{**base, "fine.engage_gear_rest": 0.5})
    k_on = _engage_period(on, err, p, -0.75, unwind)
    assert k_on is not None and unwind < k_on <= unwind + 2
    # a gear output winding *toward* the target (the main law climbing to the breakaway), or unwinding by less
    # than the gate (0.5 tolerance a period): no gate
    for rate in (0.75, -0.4):
        fine, _ = _stage(**{**base, "fine.engage_gear_rest": 0.5})
        assert _engage_period(fine, err, p, rate, unwind) == k_off


def test_on_by_default():
    """C3, the default since stop 28 (docs §108): the gate at 0.1 of a tolerance a period."""
    from fuel_valve_control.core.params import CONTROLLER_SPEC
    assert CONTROLLER_SPEC.defaults()["fine.engage_gear_rest"] == 0.1
    fine, _ = _stage()
    assert fine.cfg.engage_gear_rest == 0.1
