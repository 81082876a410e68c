"""The doublet's deep retreat (task h34s, docs §84): ``fine.retreat_cap`` (the retreat is the -cap command itself for
its whole periods, no half period: ``benchmarks/plateau_floor.py``'s deep shape, §82) and
``fine.observe_hold_integral`` / ``fine.observe_hold_moved`` (the gear-output servo's integral held while it pulls the
retreat's swing back: after every doublet / after one that moved the valve).

The torque sequence runs the stage alone on a stuck valve (no plant); the closed-loop case runs the first 1.85 s of
nominal box seed 1008 with the true valve angle watched: with two whole retreat periods, main's observe servo
(integrating its whole pull-back at the cap) overshoots the final twist and its rebound breaks the valve loose a second
time inside the same doublet's observe (traced: t = 1.77 s, a 0.65e-3 rad move followed by 3.8e-3 rad more); with the
integral held it does not."""
import sys
from dataclasses import replace
from pathlib import Path

import pytest

from fuel_valve_control.core.params import CONTROLLER_SPEC
from test_fine_positioning import MAIN_DOUBLET, _main_stage as _stage, _torques_until_observe

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT / "benchmarks") not in sys.path:
    sys.path.insert(0, str(ROOT / "benchmarks"))


@pytest.mark.parametrize("direction", [1, -1])
def test_the_cap_retreat_is_the_cap_for_its_whole_periods_and_has_no_half_period(direction):
    """Kick on the hold for one period, then two periods of -cap (direction-signed: not hold - cap), then the observe
    servo -- no period of half the cap."""
    ps = CONTROLLER_SPEC.defaults()
    assert ps["fine.retreat_cap"] is True and ps["fine.observe_hold_integral"] is False   # C1's default (docs §91)
    fine, m = _stage(**{"fine.retreat_full_periods": 2, "fine.retreat_cap": True})
    kt = m.torque_constant_nm_per_a
    cap = ps["fine.peak_current_a"] * kt
    out = _torques_until_observe(fine, direction * 0.5 * ps["fine.doublet_max_error_rad"], m.pressure_max_kpa)
    # _torques_until_observe stops at the first period in observe: with no half period that is the servo's
    hold = out[-5]
    assert out[-4] == pytest.approx(hold + direction * ps["fine.kick_current_a"] * kt)
    assert out[-3] == pytest.approx(-direction * cap) == pytest.approx(out[-2])
    if hold * direction > 0.0:
        assert abs(hold - direction * cap) < cap        # main's hold - cap would not have been the cap
    assert out[-1] != pytest.approx(hold - direction * 0.5 * cap)
    assert out[-1] == pytest.approx(fine._servo_torque) and fine._k == 1
    # the stage's own hold - cap, off
    fine, m = _stage(**{"fine.retreat_full_periods": 2})
    out = _torques_until_observe(fine, direction * 0.5 * ps["fine.doublet_max_error_rad"], m.pressure_max_kpa)
    assert out[-2] == pytest.approx(max(min(out[-5] - direction * cap, cap), -cap))
    assert out[-1] == pytest.approx(max(min(out[-5] - direction * 0.5 * cap, cap), -cap))


@pytest.mark.parametrize("direction", [1, -1])
def test_the_cap_retreat_may_keep_mains_half_period(direction):
    """``fine.retreat_cap_half``: the two periods at -cap, then main's period of the hold less half the cap."""
    ps = CONTROLLER_SPEC.defaults()
    assert ps["fine.retreat_cap_half"] is False
    fine, m = _stage(**{"fine.retreat_full_periods": 2, "fine.retreat_cap": True, "fine.retreat_cap_half": True})
    cap = ps["fine.peak_current_a"] * m.torque_constant_nm_per_a
    out = _torques_until_observe(fine, direction * 0.5 * ps["fine.doublet_max_error_rad"], m.pressure_max_kpa)
    hold = out[-5]
    assert out[-3] == pytest.approx(-direction * cap) == pytest.approx(out[-2])
    assert out[-1] == pytest.approx(max(min(hold - direction * 0.5 * cap, cap), -cap))
    assert fine.phase == "observe" and fine._k == 0


@pytest.mark.parametrize("option", ["fine.observe_hold_integral", "fine.observe_hold_moved"])
def test_the_held_integral_is_not_wound_by_the_pull_back(option):
    """In a doublet's observe the servo's integral stays where the park left it: with fine.observe_hold_integral
    always, with fine.observe_hold_moved once the valve has moved half a tolerance from the doublet's start (an
    unmoved stair's observe winds it as main's does); off, it winds."""
    ps = CONTROLLER_SPEC.defaults()
    assert ps[option] is (option == "fine.observe_hold_moved")       # C1's default (docs §91)
    err = 0.5 * ps["fine.doublet_max_error_rad"]
    for on in (True, False):
        for moved in (False, True):
            fine, m = _stage(**{"fine.retreat_full_periods": 2, "fine.retreat_cap": True, option: on})
            _torques_until_observe(fine, err, m.pressure_max_kpa)
            thl = 0.5 + (fine.cfg.tolerance_rad if moved else 0.0)
            before = fine._integral
            th1 = 0.5 + fine._final - 1e-2              # the retreat's trough: the gear output far behind
            for _ in range(3):
                fine.update(0.5 + err, th1, thl, True, 0.3, m.pressure_max_kpa)
            held = on and (moved or option == "fine.observe_hold_integral")
            assert (fine._integral == before) is held, (on, moved)


def _second_breaks(sets: dict, until_s: float) -> int:
    """Nominal box seed 1008 for ``until_s`` seconds: the doublets (kick to the end of their observe) in which the
    true valve started moving a second time after it had stopped."""
    import robustness as rb
    from fuel_valve_control.core.driver import ValveDriver
    from fuel_valve_control.tools import sim
    from fuel_valve_control.tools.run_plan import OFFLINE, plan_run
    from fuel_valve_plant.physics.plant import Plant
    case = rb.sample_case(1008, "nominal")
    sc = rb.case_scenario(case)
    p, c = sim.build(sc, rb.plant_overrides(case), rb.controller_knowledge(case), None, None)
    plan = replace(plan_run(sc, OFFLINE), plant_params=p, controller_params=c.replace({**MAIN_DOUBLET, **sets}))
    plant, driver = Plant(plan.plant_params), ValveDriver(plan.controller_params)
    plan.start_held(plant, driver)
    fine = driver.controller.law.fine
    period = driver.period
    prev = plant.truth().valve_angle
    inside, moving, starts, second = False, False, 0, 0
    for k in range(int(round(until_s / period))):
        t = k * period
        out, _ = sim.exchange_period(driver, plant, t, plan.demand.value(t))
        win = fine.phase in ("pulse", "observe") and fine._doublet
        plant.set_command(out.current_a, out.enable)
        plant.advance(period)
        now = plant.truth().valve_angle
        if win:
            if not inside:
                moving, starts = False, 0
            m = abs(now - prev) > 2e-7                   # rad per period: the valve slides (stuck: exactly 0)
            if m and not moving:
                starts += 1
                second += starts == 2
            moving = m
        inside, prev = win, now
    return second


def test_the_held_integral_leaves_the_deep_retreats_swing_alone_in_closed_loop():
    """Two periods of -cap: main's observe breaks the valve loose a second time, the held integral does not."""
    deep = {"fine.retreat_full_periods": 2, "fine.retreat_cap": True}
    assert _second_breaks(deep, 1.85) >= 1
    assert _second_breaks({**deep, "fine.observe_hold_integral": True}, 1.85) == 0
    assert _second_breaks({**deep, "fine.observe_hold_moved": True}, 1.85) == 0
