"""The hold's learned friction and load (core/integral_policy.py, issue 14 Deliver 2/3): a wrong
Δp reading is only the prior of what the hold schedules on."""
import pytest

from fuel_valve_control.core.integral_policy import IntegralPolicy, SlipEdges

LIMIT_NM = 24.9
POLICY = IntegralPolicy(0.55, 2.9e-4, relax_time_s=0.3, load_limit_nm=LIMIT_NM)
#: a valve at Δp 0 (static 0.5 N*m) under a 2.2 N*m load toward closed the model does not know
#: (e.g. the flow torque of a Δp reading at max), told the static level of max Δp (5.5 N*m)
LOAD, STATIC, TOLD_STATIC = -2.2, 0.5, 5.5


def test_one_slip_puts_the_load_a_fraction_of_the_scheduled_static_level_inside_it():
    opening_edge = LOAD + STATIC
    load = POLICY.learn_load(opening_edge, +1.0, TOLD_STATIC)
    assert load == pytest.approx(opening_edge - 0.5 * TOLD_STATIC)
    assert load < LOAD - STATIC          # the wrong schedule puts it beyond the band's other edge


def test_both_edges_give_the_load_whatever_the_schedule_says():
    edges = SlipEdges()
    assert edges.static_nm is None and edges.opposite(+1.0) is None
    edges.met(LOAD - STATIC, -1.0)                          # a closing slip at the lower edge
    assert edges.opposite(+1.0) == pytest.approx(LOAD - STATIC) and edges.opposite(-1.0) is None
    load = POLICY.learn_load(LOAD + STATIC, +1.0, TOLD_STATIC, 0.0, edges.opposite(+1.0))
    assert load == pytest.approx(LOAD)
    edges.met(LOAD + STATIC, +1.0)
    assert edges.static_nm == pytest.approx(STATIC)
    edges.reset()
    assert edges.static_nm is None


def test_an_opposite_edge_beyond_this_one_is_not_used():
    # the band moved since the other slip (its edge lies above this opening one): back to the prior
    load = POLICY.learn_load(LOAD + STATIC, +1.0, TOLD_STATIC, 0.0, LOAD + 2.0)
    assert load == pytest.approx(LOAD + STATIC - 0.5 * TOLD_STATIC)


def test_the_learned_load_stays_within_the_continuous_torque_with_both_edges():
    load = POLICY.learn_load(30.0, +1.0, TOLD_STATIC, 5.0, 28.0)
    assert load == pytest.approx(LIMIT_NM - 5.0)


@pytest.mark.parametrize("met, expected", [(None, TOLD_STATIC), (STATIC, STATIC), (0.01, 0.25), (9.0, TOLD_STATIC)])
def test_the_hold_schedules_on_the_friction_met_within_the_schedule_and_a_floor(met, expected):
    assert POLICY.hold_static_nm(TOLD_STATIC, met, 0.25) == pytest.approx(expected)
