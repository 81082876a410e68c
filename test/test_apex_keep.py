"""``fine.apex_keep_rad`` (task h41n, docs §110): from a rest within the radius the apex policy judges a try by its
chance to worsen |e| *given that it moves* (as ``fine.apex_worse_given_move``), and a policy hold decided while the
gear output still swings is reached by a park from the present twist, not by a servo reference stepped to the
final twist.  The stage alone (no plant)."""
import pytest

from test_fine_positioning import _stage
from fuel_valve_control.core.fine_positioning import HOLD, PARK

#: the rule off: C3's policy (the default of stop 28)
OFF = {"fine.apex_keep_rad": 0.0}


def test_keep_radius_is_on_by_default_and_bounds_the_rule():
    """8e-4 rad by default since stop 29 (docs §111); 0 turns the rule off (C3's policy everywhere)."""
    keep, _ = _stage()
    assert keep.cfg.apex_keep_rad == 8e-4
    assert keep._worse_given_move(8e-4) and not keep._worse_given_move(8.1e-4)
    fine, _ = _stage(**OFF)
    assert fine.cfg.apex_keep_rad == 0.0 and not fine._worse_given_move(1e-4)


def _choose(fine, d, e, phi_e, phi_b, sigma, p, floor):
    fine._apex_floor, fine._apex_last = (d, phi_b + d * floor * sigma), None
    apex = fine._choose_apex(d * e, d, phi_e, phi_b, sigma, p, 0.0, 0.5)
    return apex, fine._apex_plan


def test_a_near_rest_gets_no_try_that_would_only_throw_it_across():
    """A closing stop whose level lies two scatters above the learned one (the floor there): from |e| 6e-4 rad C3's
    rule takes a try whose move, if any, is a stick-slip jump (mean 1.3e-3 > 2 |e|: every move leaves |e| larger) on
    P(no move) ~0.93 alone; within the keep radius the policy takes no try that can move the valve there (none, or
    an apex that moves it with chance 0).  Beyond the radius (|e| 1.2e-3) the choice is C3's to the bit."""
    d, sigma = -1, 3e-4
    fine, model = _stage(**OFF)
    keep, _ = _stage(**{"fine.apex_keep_rad": 8e-4})
    p = model.pressure_max_kpa
    phi_e, phi_b, _ = fine._twists(0.5, p, d)
    apex, plan = _choose(fine, d, 6e-4, phi_e, phi_b, sigma, p, 2.0)
    assert apex is not None and plan[1] < 0.01 and plan[2] < 0.99 and plan[5] > 2 * 6e-4
    keep._moves = fine._moves
    apex_k, plan_k = _choose(keep, d, 6e-4, phi_e, phi_b, sigma, p, 2.0)
    assert apex_k is None or plan_k[2] == pytest.approx(1.0)
    far = _choose(fine, d, 1.2e-3, phi_e, phi_b, sigma, p, 2.0)
    assert repr(_choose(keep, d, 1.2e-3, phi_e, phi_b, sigma, p, 2.0)) == repr(far)


def _engaged(changes, w1):
    """A stage engaged on a 6e-4 rad error whose next choice is a hold, with the gear output turning at ``w1``."""
    fine, model = _stage(**changes)
    p = model.pressure_max_kpa
    thl, target = 0.5, 0.5 + 6e-4
    phi = fine._twists(thl, p, 1)[0]
    fine._choose_apex = lambda *a, **k: None          # no try worth making (no move model built)
    fine._engage(target, thl + phi, thl, 0.0, p)
    fine._w1_now = w1
    twist = phi - 4e-3                                 # in the retreat's trough
    choice = (6e-4, 1, phi, phi + 8e-3, 3e-4, p, 0.0, thl)
    final = phi + 3e-4
    fine._start_try(choice, thl + twist, thl, final)
    return fine, p, thl, twist, final


def test_a_hold_decided_mid_swing_is_reached_by_a_park_from_the_present_twist():
    fine, p, thl, twist, final = _engaged({"fine.apex_keep_rad": 8e-4}, w1=3.0)
    assert fine.phase == PARK and fine._park_hold
    assert fine._park_ref(0)[0] == pytest.approx(twist)          # the reference leaves the gear output where it is
    n = fine._park_n + 2
    for _ in range(n):
        fine._run(thl + twist, 0.0, thl, p)
    assert fine.phase == HOLD and fine._hold_ref == pytest.approx(thl + final)
    assert not fine._park_hold


@pytest.mark.parametrize("changes, w1", [({"fine.apex_keep_rad": 8e-4}, 0.05), (OFF, 3.0)])
def test_a_hold_at_rest_or_without_the_option_is_held_at_once(changes, w1):
    fine, p, thl, twist, final = _engaged(changes, w1)
    assert fine.phase == HOLD and fine._hold_ref == pytest.approx(thl + final) and not fine._park_hold
