"""A command the drive holds while the loop is stalled (issue 14, §49; the stall test's load flake).

Offline closed loop (default mode, nominal plant, Δp noise off) on a 45.8 -> 47.5 % step with the
loop flagged late every period (the fine stage aside, as on a loaded host).  At a given period
of the move the controller stalls: the drive keeps the last command for ``held`` periods, then
is off; it reports its watchdog trip, the driver re-arms (from the measurement and the holding
torque) and re-enables it, runs ONE period -- the re-armed law's first command, the §40.3 trace's
"29.4 A at the stuck valve" -- and stalls again, the drive holding that first command as well.

What it shows (§49): with the drive's designed 5 ms watchdog the re-armed law's lurch
(20-34 A held) keeps the valve within demand + 2 %; the node failure's 52-57 % needs the command
to *act* 9-13 ms, i.e. the drive's own watchdog late (a starved plant process, §40.5), and then
even the main law's ordinary hold command (16.4 A) overshoots -- a cap at the holding plus the
scaled breakaway torque (17.1 A, §40.5's lead) would not have stopped it.
"""
from __future__ import annotations

import pytest

from fuel_valve_control.common import contract
from fuel_valve_control.common.contract import STROKE_RAD
from fuel_valve_control.core import driver as D
from fuel_valve_control.core.params import load_controller_params
from fuel_valve_control.tools import sim
from fuel_valve_plant.physics.params import load_plant_params
from fuel_valve_plant.physics.plant import Plant

from test_fine_positioning import MAIN_DOUBLET
from test_param_swap import loop

START, DEMAND = 45.8, 47.5          # % of stroke: the trace's stuck valve and its demand
GAP = 13                            # periods the loop is silent per stall (the trace's 13 ms)
#: the fine stage these cases were traced with (§49, §54): main's doublet staircase.  With C1 the default (stop 26) the
#: hold before the step ends elsewhere and neither starved case overshoots any more (13 ms held: within demand + 2 %;
#: stale samples: 47.6 %) -- the cases, not the mechanism, went away, so they keep the build that shows it
TRACED = MAIN_DOUBLET


def _double_stall(offset: int, held: int | None = None) -> tuple[float, float]:
    """Peak valve (% of stroke) and the re-armed law's first command (A).  ``held``: periods
    the drive applies the last command at each stall (None: its designed command watchdog)."""
    plant = Plant(load_plant_params(overrides={"pressure_sensor.noise_kpa": 0.0}))
    drv = D.ValveDriver(load_controller_params(overrides={**TRACED, "faults.drive_command_timeout_s": 0.0}))
    drv.drive_status(0.0, contract.DRIVE_STATE_ENABLED)
    loop(drv, plant, 0.0, 1500, lambda t: START)
    t, period, peak = 1.5, drv.period, 0.0
    if held is None:
        held = int(round(contract.DRIVE_COMMAND_TIMEOUT_S / period))

    def step(drive_on: bool = True) -> D.DriverOutput:
        nonlocal t, peak
        drv.loop_timing(t - 0.03, t)               # a late loop: the fine stage stands aside
        out, _ = sim.exchange_period(drv, plant, t, DEMAND)
        plant.set_command(out.current_a if drive_on else 0.0, out.enable and drive_on)
        plant.advance(period)
        t += period
        peak = max(peak, plant.truth().valve_angle)
        return out

    def stall() -> None:                           # nobody steps the driver; the drive holds
        nonlocal t, peak
        last = drv.last
        for k in range(GAP):
            on = k < held
            plant.set_command(last.current_a if on else 0.0, last.enable and on)
            plant.advance(period)
            t += period
            peak = max(peak, plant.truth().valve_angle)
        drv.drive_status(t, contract.DRIVE_STATE_WATCHDOG)

    for _ in range(offset):
        step()
    stall()
    for _ in range(50):                            # re-armed once the valve is slow enough
        if step(drive_on=False).reenable:
            break
    drv.drive_status(t, contract.DRIVE_STATE_ENABLED)
    first = step().current_a                       # the re-armed law's first command ...
    stall()                                        # ... held by the next stall
    drive_on = False
    for _ in range(400):
        out = step(drive_on)
        if out.reenable and not drive_on:
            drive_on = True
            drv.drive_status(t, contract.DRIVE_STATE_ENABLED)
    assert drv.stall_rearms == 2 and not drv.last.faults, drv.last.faults
    return 100.0 * peak / STROKE_RAD, first



def test_the_re_armed_laws_lurch_held_for_the_drives_watchdog_keeps_the_valve_within_demand_plus_2():
    # offset 10: the valve still stuck at the move's start (45.8 %), the re-armed law asks
    # ~31 A (the trace's 29.4 A); held for the drive's 5 ms it does not throw the valve past
    peak, first = _double_stall(10)
    assert abs(first) > 25.0, first                # the lurch is there (the case is the trace's)
    assert peak <= DEMAND + 2.0, peak


@pytest.mark.xfail(strict=True, reason="a command acting 13 ms (the drive's own watchdog late: a starved "
                                       "plant) throws the valve to 56 %; §49.  Not what the nodes do: the plant "
                                       "node's watchdog bounded every command to 5.9-7.4 ms in 10 runs beside two "
                                       "hogs (§54); a stale sample's command is the case there (test below)")
def test_a_command_held_13_ms_at_the_end_of_a_move_keeps_the_valve_within_demand_plus_2():
    # offset 30: the valve 0.4 % below demand, the main law's hold command 16.4 A (below
    # §40.5's proposed cap of 17.1 A) held for the whole 13 ms stall
    peak, _ = _double_stall(30, GAP)
    assert peak <= DEMAND + 2.0, peak


# ------------------------------------------------------------------ stale samples (§54)
def _starved(stale_periods: float, periods: int = 700) -> tuple[float, float, int]:
    """The 45.8 -> 47.5 % step on a starved real-time loop as the nodes showed it beside two
    CPU hogs (§54): the loop answers after 3 periods the sample 2 periods old (the DDS receive
    thread behind), then twice at once a fresh one; the drive applies each answer until the
    next (within its 5 ms watchdog: no trip).  Returns (peak, final valve, % of stroke; stale
    samples counted)."""
    plant = Plant(load_plant_params(overrides={"pressure_sensor.noise_kpa": 0.0}))
    drv = D.ValveDriver(load_controller_params(overrides={**TRACED, "faults.stale_sample_periods": stale_periods}))
    drv.drive_status(0.0, contract.DRIVE_STATE_ENABLED)
    loop(drv, plant, 0.0, 1500, lambda t: START)
    period = drv.period
    t, peak, samples, wait, i = 1.5, 0.0, [], 0, 0
    pattern = ((3, 2), (1, 0), (1, 0))          # (periods to the answer, age of its sample)
    for k in range(periods):
        s = plant.resolver()
        samples.append((t, s.motor_rad, s.valve_rad))
        wait += 1
        every, age = pattern[i % len(pattern)]
        if wait >= every:
            stamp, motor, valve = samples[-1 - age]
            drv.demand_percent(t, DEMAND)
            drv.resolver(stamp, motor, valve, now=t)
            drv.loop_timing(stamp, t)            # the node's real-time call: stamp vs arrival
            out = drv.step(t)
            plant.set_command(out.current_a, out.enable)
            wait, i = 0, i + 1
        plant.advance(period)
        t += period
        peak = max(peak, plant.truth().valve_angle)
    assert not drv.last.faults, drv.last.faults
    return 100.0 * peak / STROKE_RAD, 100.0 * plant.truth().valve_angle / STROKE_RAD, drv.stale_samples


#: ``faults.stale_sample_periods`` as measured in §54 (an option, off by default: no better on the nodes)
STALE_PERIODS = 1.5


@pytest.fixture(scope="module")
def starved():
    """The starved step with the stale-sample rule off (the default) and on."""
    assert load_controller_params()["faults.stale_sample_periods"] == 0.0      # off by default (§54)
    return {"off": _starved(0.0), "on": _starved(STALE_PERIODS)}


def test_a_starved_loop_answering_stale_samples_overshoots_without_the_stale_sample_rule(starved):
    # the case is the nodes' mechanism: commands for samples 2 ms old, held 3 ms, throw the
    # valve past demand + 2 % (52.4 %) -- guards that the next test measures something
    peak, _, stale = starved["off"]
    assert peak > DEMAND + 2.0 and stale == 0, (peak, stale)


def test_a_stale_samples_period_holds_the_valve_and_the_step_still_arrives(starved):
    # the stale samples' periods command the holding torque: no overshoot (47.3 %), and the
    # law, not re-armed by them, still brings the valve to its demand (within 0.5 % of stroke)
    peak, final, stale = starved["on"]
    assert stale > 100, stale
    assert peak <= DEMAND + 2.0, peak
    assert abs(final - DEMAND) < 0.5, final


def test_the_stale_sample_rule_reads_the_age_beyond_the_usual_latency_not_a_clock_offset():
    drv = D.ValveDriver(load_controller_params(overrides={"faults.stale_sample_periods": STALE_PERIODS}))
    period = drv.period
    offset = 0.05                                # the drive's clock 50 ms behind the loop's
    for k in range(100):                         # a constant latency: never stale
        drv.loop_timing(k * period, k * period + offset + 2e-4)
        assert not drv._stale_sample
    assert drv.sample_late_s < 1e-6
    drv.loop_timing(100 * period, 100 * period + offset + 2e-4 + 2.0 * period)     # 2 periods late
    assert drv._stale_sample and abs(drv.sample_late_s - 2.0 * period) < 1e-6
    drv.loop_timing(101 * period, 101 * period + offset + 2e-4 + 1.0 * period)     # 1: within 1.5
    assert not drv._stale_sample
