"""``fine.apex_floor_repeat`` (task h37m, docs §95, off by default): once the apex policy plans an apex no further
(within half a tolerance) than one it already tried at this stop without moving the valve, the law is truncated at
the *planned* apex, not the measured one, for the rest of the stop -- the reading (once a period, below the kick's
peak) has shown itself short of the plan (traced: ``startup`` seed 0, C1 + the mixture law: 80 tries at a handful
of apexes over 2.2 s, none moved).

Stage only: the floor's bookkeeping (no move tables, no closed loop)."""
import pytest

from test_apex_policy import _policy_stage


def _unmoved(fine, d, plan, short=1e-4):
    """One unmoved try toward ``d`` planned at ``plan`` whose reading lay ``short`` rad below it, booked as
    ``FinePositioner._after_move`` books it."""
    fine._apex_last = (d, plan)
    fine._note_unmoved_plan(d)
    reading = plan - d * short
    if fine._apex_floor is None or fine._apex_floor[0] != d or d * (reading - fine._apex_floor[1]) > 0:
        fine._apex_floor = (d, reading)


@pytest.mark.parametrize("direction", [1, -1])
def test_the_floor_is_the_plan_once_the_policy_repeats_an_apex(direction):
    d, a = direction, 0.0105
    tol = None
    for opt in (False, True):
        # the floor at the reading until the repeat (fine.apex_floor_plan, C2's, takes the plan from the first try)
        fine, _ = _policy_stage(**{"fine.apex_floor_repeat": opt, "fine.apex_floor_plan": False})
        tol = fine.cfg.tolerance_rad
        _unmoved(fine, d, a)
        assert fine._floor(d) == (d, pytest.approx(a - d * 1e-4))        # the first try: the reading
        _unmoved(fine, d, a + d * 0.4 * tol)                              # the same apex again (within half a tol)
        assert fine._floor(d)[1] == pytest.approx(a + d * 0.4 * tol if opt else a + d * 0.4 * tol - d * 1e-4)
        _unmoved(fine, d, a + d * 3e-4)                                   # then a climb: the plan stays the floor
        assert fine._floor(d)[1] == pytest.approx(a + d * 3e-4 if opt else a + d * 2e-4)
        # a new stop (a move drops the floor): the reading again until the next repeat
        fine._apex_floor = None
        _unmoved(fine, d, a)
        assert fine._floor(d)[1] == pytest.approx(a - d * 1e-4)
    # climbing by more than half a tolerance per try is no repeat: the reading stays the floor
    fine, _ = _policy_stage(**{"fine.apex_floor_repeat": True})
    for k in range(4):
        _unmoved(fine, d, a + d * k * 0.6 * tol)
    assert fine._floor(d)[1] == pytest.approx(a + d * 3 * 0.6 * tol - d * 1e-4)


def test_off_by_default():
    from fuel_valve_control.core.params import CONTROLLER_SPEC
    assert CONTROLLER_SPEC.defaults()["fine.apex_floor_repeat"] is False
