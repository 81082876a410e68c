"""The deep-retreat apex build's other-valve hunter and its unmoved judgement (task h35v, docs §89).

``fine.retreat_return_guard``: on a low-friction valve (other valves' ``slippery``, friction x0.4) the deep retreat's
trough (two periods at -cap: the twist 9.3e-3 rad below the preload) reaches the other way's breakaway level, and a
valve the kick moved slides back -- traced on campaign seed 1001: +1.25e-3 rad, then back to its start, judged
"unmoved" 4 periods after the kick (half a tolerance from the start), not counted, and repeated 11 times: hunting.
With the guard, the period the valve is a tolerance back from the furthest it went, the plateau is left as after a move
away from the target (counted; the main law takes it, or the stage holds where a hand-back could be the hunting
metric's second reversal) and the stage's later doublets on that plant retreat one whole period.

``fine.unmoved_settled``: an unmoved doublet is judged (and the next park planned from rest) only once the gear
output's speed is below ``fine.park_approach_speed_rad_s``, or at the observe window's end.

Stage-alone tests (no plant, < 1 s each) plus the traced campaign run (slippery valve, seed 1001, ~6 s CPU)."""
import sys
from pathlib import Path

import pytest

from fuel_valve_control.core.params import CONTROLLER_SPEC
# the stage-alone cases are main's staircase with the deep retreat (DEEP), as measured (task h35v); C1 is the default
# since stop 25 (docs §91)
from test_fine_positioning import C1_FINE, _main_stage as _stage, _torques_until_observe

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT / "benchmarks") not in sys.path:
    sys.path.insert(0, str(ROOT / "benchmarks"))

DEEP = {"fine.retreat_full_periods": 2, "fine.retreat_cap": True}


def _observe_there_and_back(fine, m, direction, err):
    """After the doublet's pulse: the valve goes two tolerances toward the try for 3 periods, then back to its start
    and rests there; the gear output stays put.  Returns the phase once the stage has judged (or 60 periods)."""
    tol = fine.cfg.tolerance_rad
    th1 = 0.5 + fine._final
    for k in range(60):
        thl = 0.5 + (direction * 2.0 * tol if k < 3 else 0.0)
        fine.update(0.5 + err, th1, thl, True, 0.3, m.pressure_max_kpa)
        if fine.phase != "observe":
            return fine.phase
    return fine.phase


@pytest.mark.parametrize("direction", [1, -1])
def test_a_doublet_whose_valve_came_back_leaves_the_plateau_and_cuts_the_deep_retreat(direction):
    ps = CONTROLLER_SPEC.defaults()
    assert ps["fine.retreat_return_guard"] is False
    err = direction * 0.5 * ps["fine.doublet_max_error_rad"]
    # off (main): judged unmoved 4 periods after the pulse (back within half a tolerance), not counted: the next park
    fine, m = _stage(**DEEP)
    _torques_until_observe(fine, err, m.pressure_max_kpa)
    assert _observe_there_and_back(fine, m, direction, err) == "park"
    assert fine.pulses_this_plateau == 0 and not fine._deep_unfit
    # on: the period it is a tolerance back from its furthest point, the plateau is left as after a move away from
    # the target (counted; handed back: neither fine.hold_reversed nor the apex policy here), the deep retreat cut
    fine, m = _stage(**DEEP, **{"fine.retreat_return_guard": True})
    _torques_until_observe(fine, err, m.pressure_max_kpa)
    assert _observe_there_and_back(fine, m, direction, err) == "idle"
    assert fine.pulses_this_plateau == 1 and fine._deep_unfit and fine._unfit
    # fine.retreat_return_hold: held where it is instead (no more pulses on the plateau)
    fine, m = _stage(**DEEP, **{"fine.retreat_return_guard": True, "fine.retreat_return_hold": True})
    _torques_until_observe(fine, err, m.pressure_max_kpa)
    assert _observe_there_and_back(fine, m, direction, err) == "hold"
    assert fine.pulses_this_plateau == 1 and fine._deep_unfit and fine._unfit
    # fine.retreat_return_rest: the observe's reference frozen, judged at rest -- back at its start: counted and held
    fine, m = _stage(**DEEP, **{"fine.retreat_return_guard": True, "fine.retreat_return_rest": True})
    _torques_until_observe(fine, err, m.pressure_max_kpa)
    assert _observe_there_and_back(fine, m, direction, err) == "hold"
    assert fine.pulses_this_plateau == 1 and fine._deep_unfit and fine._k >= fine.cfg.observe_periods
    # a stage that has seen it retreats one whole period at -cap, then the observe servo
    cap = ps["fine.peak_current_a"] * m.torque_constant_nm_per_a
    fine2, m = _stage(**DEEP, **{"fine.retreat_return_guard": True})
    fine2._deep_unfit = True
    out = _torques_until_observe(fine2, err, m.pressure_max_kpa)
    assert out[-2] == pytest.approx(-direction * cap)
    assert out[-3] != pytest.approx(-direction * cap)
    assert out[-1] != pytest.approx(-direction * cap) and fine2._k == 1


@pytest.mark.parametrize("direction", [1, -1])
def test_an_unmoved_doublet_is_judged_once_its_swing_has_settled(direction):
    """The gear output still swinging (0.5 rad/s, 5 x the park's approach speed) after the kick: judged unmoved at
    ``no_move_periods`` off; on, only once it has stopped (or at the observe window's end)."""
    ps = CONTROLLER_SPEC.defaults()
    assert ps["fine.unmoved_settled"] is False
    err = direction * 0.5 * ps["fine.doublet_max_error_rad"]
    for on in (False, True):
        fine, m = _stage(**DEEP, **{"fine.unmoved_settled": on})
        _torques_until_observe(fine, err, m.pressure_max_kpa)
        th1, per = 0.5 + fine._final, fine.period
        v = 5.0 * fine.cfg.park_approach_speed
        judged = None
        for k in range(1, fine.cfg.observe_periods + 5):
            th1 += direction * v * per if k <= 8 else 0.0
            fine.update(0.5 + err, th1, 0.5, True, 0.3, m.pressure_max_kpa)
            if fine.phase != "observe":
                judged = k
                break
        assert fine.phase == "park"
        if on:
            assert judged == 9              # the first period the backward difference reads it stopped
        else:
            assert judged < 8               # mid-swing (the observe's first period was the pulse's last)


def test_the_slippery_valve_hunter_is_cured():
    """Other valves' slippery valve (friction x0.4), campaign seed 1001, with the deep-retreat apex build (b): its last
    plateau hunted (3 reversals, 10 doublets went there and back); with fine.retreat_return_guard no plateau hunts."""
    import other_valves as OV
    b = {"fine.apex_policy": True, "fine.apex_kick_max_a": 16.0, "fine.apex_retreat_periods": 2,
         "fine.retreat_cap": True, "fine.observe_hold_moved": True, "fine.retreat_return_guard": True,
         "fine.apex_excess_nominal": False,                      # build (b), as traced (C1 = b + this)
         **C1_FINE}                                              # C1's law, floor, engage and hand-over (C3's since stop 28)
    orig = OV.overrides
    try:
        OV.overrides = lambda v: (orig(v)[0], {**orig(v)[1], **b})
        res = OV.run_campaign(("slippery", "observer_fp", 1001))
    finally:
        OV.overrides = orig
    assert "error" not in res
    assert not res["hunts"]
    assert res["plateaus"][11]["final_error_rad"] < 5e-4          # 0.11e-3 (without the guard: 0.82e-3, hunting)
