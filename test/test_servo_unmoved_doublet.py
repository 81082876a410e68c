"""``fine.servo_unmoved_doublet`` (task h42s, docs §112): after N servo-blended pulses toward one way that did not
move the valve at a stop, the next pulse there is a doublet (the apex policy's try) while |e| is within one nominal
stick-slip jump.  The stage alone (no plant)."""
import pytest

from test_fine_positioning import _stage


def _stuck(changes, err, pulses):
    """A stage engaged on ``err`` (rad, beyond fine.doublet_max_error_rad) after ``pulses`` unmoved servo-blended
    pulses; returns the stage and the kinds of the pulses it started (True: a doublet)."""
    fine, model = _stage(**changes)
    p = model.pressure_max_kpa
    thl = 0.5
    phi = fine._twists(thl, p, 1)[0]
    kinds = []
    floors = []
    fine._start_try = lambda *a, **k: (kinds.append("try"), floors.append(fine._apex_floor))  # the policy's choice
    fine.floors = floors                                     # (no move model built here) and its floor then
    fine._engage(thl + err, thl + phi, thl, 0.0, p)
    kinds.append(fine._doublet)
    for _ in range(pulses):
        fine.phase, fine._pulsed = "observe", True
        fine._after_move(thl + phi, thl, p, pulsed=True)         # unmoved
        kinds.append(fine._doublet)
    return fine, kinds, p


def test_off_by_default_the_servo_blended_pulses_go_on():
    fine, kinds, _ = _stuck({}, 1.06e-3, 6)
    assert fine.cfg.servo_unmoved_doublet == 0
    assert kinds == [False] * 7


def test_after_n_unmoved_servo_blended_pulses_the_next_is_the_policys_doublet():
    """Nominal 2026 #5 (docs §112.1): |e| 1.06e-3 rad, a resolver count beyond the doublet's 1e-3; with the option
    3, the fourth pulse is a doublet and goes to the policy's choice."""
    fine, kinds, _ = _stuck({"fine.servo_unmoved_doublet": 3}, 1.06e-3, 4)
    assert kinds[:5] == [False, False, False, "try", True]
    assert fine._servo_unmoved[1] >= 3
    # the policy's floor at the hand-over: the furthest twist the unmoved servo-blended pulses reached (not none)
    assert fine.floors[0] == (1, pytest.approx(fine._safe)) and fine._safe is not None


def test_beyond_one_stick_slip_jump_the_servo_blended_pulse_stays():
    fine, model = _stage()
    jump = fine.m.friction(model.pressure_max_kpa).stick_slip_jump_rad(fine.m.coupling_stiffness_nm_per_rad)
    fine, kinds, _ = _stuck({"fine.servo_unmoved_doublet": 3}, 1.2 * jump, 5)
    assert kinds == [False] * 6
