"""A late real-time loop and the fine stage's timed pulses (offline, no ROS).

The fine stage (``observer_fp``) moves a stuck valve with torque pulses a few periods long.  A
real-time loop that is late holds the last command for as long as it is late, so a kick meant
for ~4 ms can act for ~7 ms: beside two CPU hogs a held valve was kicked 6.5e-2 rad
(test_safety_nodes' stall test, 54 % for a 47.5 % hold).  The driver marks the loop late from
the intervals between resolver samples (stamps and arrivals, so a clock offset between drive and
controller does not count) and from drive watchdog trips; the stage then stands aside for
``fine.late_loop_holdoff_s`` and the main law holds.
"""
from __future__ import annotations

import numpy as np
import pytest

from fuel_valve_control.common.contract import STROKE_RAD
from fuel_valve_control.core.driver import ValveDriver
from fuel_valve_control.core.params import load_controller_params
from fuel_valve_control.tools.sim import exchange_period
from fuel_valve_plant.physics.params import load_plant_params
from fuel_valve_plant.physics.plant import Plant


def _aside(drv: ValveDriver) -> str:
    return drv.health().values["fine_stage_aside"]


def test_late_intervals_mark_the_loop_late_a_clock_offset_does_not():
    drv = ValveDriver(load_controller_params())
    period, late = drv.period, drv.ps["fine.late_loop_s"]
    offset = 0.3                           # the controller's clock 0.3 s ahead of the drive's
    t = 1.0
    for _ in range(200):                   # on time, with jitter inside the bound
        t += period
        drv.loop_timing(t, t + offset + 0.4 * late * np.sin(t * 1e3))
    assert drv.late_loop_events == 0
    t += period + 1.2 * late               # samples missed: the stamps jump
    drv.loop_timing(t, t + offset)
    assert drv.late_loop_events == 1
    t += period                            # on time again, but this one arrived late
    drv.loop_timing(t, t + offset + 1.2 * late)
    assert drv.late_loop_events == 2
    t += period                            # the queue drains: arrivals bunch up (not late)
    drv.loop_timing(t, t + offset + 1.2 * late + 1e-4)
    assert drv.late_loop_events == 2


def _hold_sequence(holdoff_s: float, late_periods: int, seed: int = 0, every_s: float = 0.25):
    """Offline closed loop (default mode, max Δp) over 12 random plateau steps of 0.1-2 % of
    stroke, 0.6 s each; from 1 s on, every ``every_s`` the loop is ``late_periods`` periods
    late: the drive keeps the last command meanwhile (shorter than its 5 ms watchdog), then the
    driver gets the next sample with the stamp gap.  Returns (largest |valve - demand| later
    than 0.3 s into a plateau, rad; the driver)."""
    rng = np.random.default_rng(seed)
    plant = Plant(load_plant_params(overrides={"pressure_sensor.noise_kpa": 0.0, "seed": seed}))
    drv = ValveDriver(load_controller_params(overrides={"fine.late_loop_holdoff_s": holdoff_s}))
    period, t, next_late, worst = drv.period, 0.0, 1.0, 0.0
    levels = [30.0]
    for _ in range(12):
        levels.append(levels[-1] + rng.choice([-1.0, 1.0]) * rng.uniform(0.1, 2.0))
    for level in levels:
        target, start = level / 100.0 * STROKE_RAD, t
        while t - start < 0.6:
            if late_periods and t >= next_late:
                next_late += every_s
                last = drv.last
                for _ in range(late_periods):
                    plant.set_command(last.current_a, last.enable)
                    plant.advance(period)
                    t += period
                    if t - start > 0.3:
                        worst = max(worst, abs(plant.truth().valve_angle - target))
            out, _ = exchange_period(drv, plant, t, level)
            drv.loop_timing(t, t)                    # as the node does in real time
            plant.set_command(out.current_a, out.enable)
            plant.advance(period)
            t += period
            if t - start > 0.3:
                worst = max(worst, abs(plant.truth().valve_angle - target))
    return worst, drv


def test_on_a_loop_that_keeps_time_the_guard_changes_nothing():
    with_guard, drv = _hold_sequence(2.0, 0)
    without, _ = _hold_sequence(0.0, 0)
    assert drv.late_loop_events == 0 and with_guard == without


@pytest.mark.parametrize("seed", [0, 2])
def test_a_late_loop_does_not_stretch_the_fine_stages_pulses(seed):
    # 4-period late loops every 0.25 s: without the guard the stretched kicks moved held valves
    # 3.5-5.7e-2 rad (seeds 0-2); with it the main law holds, within about half a jump
    # (2.3-3.1e-3 rad at max Δp)
    guarded, drv = _hold_sequence(2.0, 4, seed)
    unguarded, _ = _hold_sequence(0.0, 4, seed)
    assert drv.late_loop_events >= 40
    jump = drv.controller.model.friction(drv.pressure_kpa).stick_slip_jump_rad(
        drv.controller.model.coupling_stiffness_nm_per_rad)
    assert guarded <= jump, (guarded, jump)
    assert unguarded > 4 * jump, (unguarded, jump)      # the mechanism the guard is for


def test_a_drive_watchdog_trip_sets_the_stage_aside_for_the_holdoff():
    from fuel_valve_control.common import contract
    plant = Plant(load_plant_params(overrides={"pressure_sensor.noise_kpa": 0.0}))
    drv = ValveDriver(load_controller_params())
    drv.drive_status(0.0, contract.DRIVE_STATE_ENABLED)
    period, t = drv.period, 0.0
    for _ in range(300):
        out, _ = exchange_period(drv, plant, t, 40.0)
        plant.set_command(out.current_a, out.enable)
        plant.advance(period)
        t += period
    assert _aside(drv) == ""
    drv.drive_status(t, contract.DRIVE_STATE_WATCHDOG)
    out, _ = exchange_period(drv, plant, t, 40.0)
    drv.drive_status(t, contract.DRIVE_STATE_ENABLED)
    assert drv.stall_rearms == 1 and "watchdog" in _aside(drv)
    holdoff = drv.ps["fine.late_loop_holdoff_s"]
    while t < 0.3 + holdoff + 5 * period:
        out, _ = exchange_period(drv, plant, t, 40.0)
        plant.set_command(out.current_a, out.enable)
        plant.advance(period)
        t += period
        if t < 0.3 + 0.9 * holdoff:
            assert drv.controller.law._aside, t
    assert _aside(drv) == "" and not drv.controller.law._aside
