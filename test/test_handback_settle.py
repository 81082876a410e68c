"""``fine.handback_settle`` (stop 28, docs §108; C3's, on by default since stop 28): the fine stage's own hand-back, decided mid-park /
-pulse / -observe with the gear output still turning faster than ``fine.handover_settle_speed_rad_s``, holds the gear
output where it is until it turns slower with the valve at rest, then leaves the plateau to the main law -- which
restarts with its observer's speeds at 0: handed the observe's pull-back from a retreat's trough (nominal box seed 4013
#9, C3: the twist rising 2.8e-3 rad a period) it ran on through the breakaway, 1.06e-2 rad past a 9.4e-3 step.

Stage only (no plant), no move tables built: the stage engaged toward an opening target (PARK), then the valve slides
3 tolerances away from it (the stage's reason to hand back) with the gear output turning, then still."""
import pytest

from test_handover_settle import _engaged

C3_SETTLE = {"fine.handover_settle_speed_rad_s": 0.1}


def _slide_away(fine, p, moving_periods, speed_rad_s):
    """Periods from the slide until the stage leaves the plateau to the main law (returns None), the gear output turning
    at ``speed_rad_s`` for ``moving_periods`` periods, then still; and the torques it returned before."""
    th1 = fine._last_th1
    thl = fine._last_valve - 3.0 * fine.cfg.tolerance_rad          # away from the (opening) target
    target = fine._target
    torques = []
    for k in range(1, 200):
        if k <= moving_periods:
            th1 += speed_rad_s * fine.period
        torque = fine.update(target, th1, thl, False, 0.3, p)
        if torque is None:
            assert fine.phase == "idle" and fine._handback_wait is None
            return k, torques
        assert fine.phase == "hold"
        torques.append(torque)
    return None, torques


def test_off_hands_back_at_once():
    fine, p = _engaged(**C3_SETTLE, **{"fine.handback_settle": False})
    assert fine.cfg.handback_settle is False
    assert _slide_away(fine, p, 8, 2.0)[0] == 1


@pytest.mark.parametrize("speed", [2.0, -2.0])
def test_on_holds_the_swing_then_hands_back(speed):
    fine, p = _engaged(**C3_SETTLE, **{"fine.handback_settle": True})
    k, torques = _slide_away(fine, p, 8, speed)
    assert k is not None and 8 < k <= 8 + 2          # held while it turns, handed back once it is still
    assert len(torques) == k - 1 and all(t is not None for t in torques)
    assert fine._unfit                               # and no more pulses on this plateau


def test_on_bounded_when_the_gear_output_never_settles():
    fine, p = _engaged(**C3_SETTLE, **{"fine.handback_settle": True})
    k, _ = _slide_away(fine, p, 10_000, 1.0)
    assert k == 2 * fine.cfg.observe_periods + 2


def test_on_still_gear_output_hands_back_at_once():
    fine, p = _engaged(**C3_SETTLE, **{"fine.handback_settle": True})
    assert _slide_away(fine, p, 0, 0.0)[0] == 1


def test_needs_the_settle_speed():
    fine, p = _engaged(**{"fine.handover_settle_speed_rad_s": 0.0, "fine.handback_settle": True})
    assert _slide_away(fine, p, 8, 2.0)[0] == 1


def test_a_new_demand_during_the_wait_still_waits_for_the_swing():
    fine, p = _engaged(**C3_SETTLE, **{"fine.handback_settle": True})
    th1, thl = fine._last_th1, fine._last_valve - 3.0 * fine.cfg.tolerance_rad
    th1 += 2.0 * fine.period
    assert fine.update(fine._target, th1, thl, False, 0.3, p) is not None and fine.phase == "hold"
    th1 += 2.0 * fine.period
    assert fine.update(thl + 2.0e-2, th1, thl, False, 0.3, p) is not None    # the new demand: held on
    assert fine._handover is not None


def test_on_by_default():
    from fuel_valve_control.core.params import CONTROLLER_SPEC
    assert CONTROLLER_SPEC.defaults()["fine.handback_settle"] is True
