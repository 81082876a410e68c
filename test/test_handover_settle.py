"""``fine.handover_settle_speed_rad_s`` (task h38s, docs §98; 0.1 rad/s, on by default since stop 28, docs §108): a
new demand that arrives while the fine stage is mid-park / -pulse / -observe waits for the gear output to settle before the main law takes over -- the main
law restarts with its observer's speeds at 0, and handed a doublet's swing (nominal seed 4034 #11, C2: the gear output
at 2-3 rad/s toward the breakaway the new step goes to) it broke the valve loose at once and slid 5.2e-3 rad past a
1.16e-2 step (44.7 %).

Stage only (no plant), no move tables built: the stage engaged (PARK), then a new demand with the gear output still
moving, then still."""
import pytest

from test_engage_gear_rest import _engage_period
from test_fine_positioning import _stage


def _engaged(**changes):
    fine, m = _stage(**{"fine.engage_inside_deadband": True, **changes})
    p = m.pressure_max_kpa
    assert _engage_period(fine, 2.0e-3, p, 0.0, 0) is not None
    assert fine.phase in ("park", "pulse", "observe")
    return fine, p


def _new_demand(fine, p, moving_periods, speed_rad_s):
    """Periods from a new demand (2e-2 rad further open) until the stage hands over (returns None), the gear output
    turning at ``speed_rad_s`` for ``moving_periods`` periods, then still (the valve at rest throughout)."""
    thl = fine._last_valve
    th1 = fine._last_th1
    for k in range(1, 200):
        if k <= moving_periods:
            th1 += speed_rad_s * fine.period
        torque = fine.update(thl + 2.0e-2, th1, thl, False, 0.3, p)
        if torque is None:
            assert fine.phase == "idle"
            return k
    return None


def test_off_hands_over_at_once():
    fine, p = _engaged(**{"fine.handover_settle_speed_rad_s": 0.0})
    assert fine.cfg.handover_settle_speed == 0.0
    assert _new_demand(fine, p, 10, 2.0) == 1


@pytest.mark.parametrize("speed", [2.0, -2.0])
def test_on_waits_for_the_gear_output_to_settle(speed):
    fine, p = _engaged(**{"fine.handover_settle_speed_rad_s": 0.1})
    k = _new_demand(fine, p, 8, speed)
    assert k is not None and 8 < k <= 8 + 2          # held while it turns, handed over once it is still
    assert fine._handover is None


def test_on_bounded_when_the_gear_output_never_settles():
    fine, p = _engaged(**{"fine.handover_settle_speed_rad_s": 0.1})
    k = _new_demand(fine, p, 10_000, 1.0)
    assert k == 2 * fine.cfg.observe_periods + 1


def test_on_still_gear_output_hands_over_at_once():
    fine, p = _engaged(**{"fine.handover_settle_speed_rad_s": 0.1})
    assert _new_demand(fine, p, 0, 0.0) == 1


def test_on_by_default():
    """C3 (C2 + the hand-over settle + ...), the default since stop 28 (docs §108)."""
    from fuel_valve_control.core.params import CONTROLLER_SPEC
    assert CONTROLLER_SPEC.defaults()["fine.handover_settle_speed_rad_s"] == 0.1


def _held(side, **changes):
    """The stage holding a valve at rest (HOLD) with the twist ``side`` (±1) x 0.4 of the band's half width from the
    band's middle (between the learned breakaways)."""
    fine, p = _engaged(**changes)
    thl = fine._last_valve
    mid = 0.5 * (fine._twists(thl, p, 1)[1] + fine._twists(thl, p, -1)[1])
    half = 0.5 * (fine._twists(thl, p, 1)[1] - fine._twists(thl, p, -1)[1])
    th1 = thl + mid + side * 0.4 * half
    fine.phase, fine._hold_ref = "hold", th1
    return fine, p, thl, th1, mid


@pytest.mark.parametrize("direction", [1, -1])
def test_unwind_moves_a_hold_on_the_new_moves_side_to_the_middle_first(direction):
    fine, p, thl, th1, mid = _held(direction, **{"fine.handover_unwind": True})
    n = fine.cfg.observe_periods
    for k in range(1, n + 10):
        torque = fine.update(thl + direction * 2.0e-2, th1, thl, False, 0.3, p)
        if torque is None:
            break
        assert fine._unwind is not None and abs(fine._unwind[1] - (thl + mid)) < 1e-12
    assert k == n + 4 and fine.phase == "idle"        # the blend's periods, then handed over


@pytest.mark.parametrize("changes", [{"fine.handover_unwind": True}, {}])
def test_unwind_not_from_the_other_side_nor_off(changes):
    for direction in (1, -1):
        side = -direction if changes else direction
        fine, p, thl, th1, _ = _held(side, **changes)
        assert fine.update(thl + direction * 2.0e-2, th1, thl, False, 0.3, p) is None
        assert fine.phase == "idle"


def test_unwind_off_by_default():
    from fuel_valve_control.core.params import CONTROLLER_SPEC
    assert CONTROLLER_SPEC.defaults()["fine.handover_unwind"] is False
