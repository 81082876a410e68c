"""The drive's fallback current for a period without a command (``contract.CURRENT_FALLBACK``, ``fine.pulse_fallback``)
and the real-time loop's late answers emulated offline (``tools/loop_stalls.py``; docs §113).

The fine stage's doublet is a one-period kick and then the retreat that stops the valve it broke loose.  In real
time a late answer made the drive hold the kick a second period (a longer kick: a throw of a whole jump or more,
§111.5b).  The controller now tells the drive, per doublet period, the next period's planned torque; the drive
applies it over a period without a new command instead of holding the last one.
"""
from __future__ import annotations

import math
import time

import numpy as np
import pytest

from fuel_valve_control.common import contract
from fuel_valve_control.core import driver as D
from fuel_valve_control.core.fine_positioning import PULSE
from fuel_valve_control.tools import sim
from fuel_valve_control.tools.loop_stalls import LoopStalls, StalledDrive
from fuel_valve_control.tools.run_plan import OFFLINE, plan_run
from fuel_valve_control.tools.scenarios import load_scenario
from fuel_valve_plant.physics.plant import Plant


@pytest.mark.parametrize("fallback, missed, applied", [((), 1, 5.0), ((), 3, 5.0), ((-3.0,), 1, -3.0),
                                                       ((-3.0,), 4, -3.0), ((-30.0, 6.0), 1, -30.0),
                                                       ((-30.0, 6.0), 2, 6.0), ((-30.0, 6.0), 9, 6.0)])
def test_a_period_without_a_command_applies_the_fallback_schedule_else_holds_the_last_command(fallback, missed,
                                                                                            applied):
    assert contract.current_without_command(5.0, fallback, missed) == applied


@pytest.mark.parametrize("fallback, valid", [((), True), ((1.0, -2.0), True), ((math.nan,), False),
                                             ((1.0, math.inf), False)])
def test_a_schedule_with_a_non_finite_current_is_refused(fallback, valid):
    assert contract.fallback_valid(fallback) == valid


def test_the_stall_schedule_is_seeded_and_a_sleeping_controller_loses_its_commands():
    model = LoopStalls(transit_rate=0.01, controller_rate=0.002, seed=3)
    lost, asleep = model.schedule(20000)
    lost2, asleep2 = LoopStalls(transit_rate=0.01, controller_rate=0.002, seed=3).schedule(20000)
    assert np.array_equal(lost, lost2) and np.array_equal(asleep, asleep2)
    assert not np.array_equal(lost, LoopStalls(transit_rate=0.01, controller_rate=0.002, seed=4).schedule(20000)[0])
    assert np.all(lost[asleep])                       # asleep: nothing answered
    assert 0 < asleep.sum() < lost.sum()
    # log-uniform lengths 1..5 (mean ~2.0 periods) at 1 % starts: ~2 % of the periods lost to transit
    assert 0.01 < (lost & ~asleep).mean() < 0.03


class _Out:
    def __init__(self, amps, fallback=(), enable=True, reenable=False):
        self.current_a, self.fallback_currents_a, self.enable, self.reenable = amps, fallback, enable, reenable


def test_the_emulated_drive_holds_or_falls_back_and_its_watchdog_needs_a_re_enable():
    drive = StalledDrive(LoopStalls(command_timeout_periods=3))
    assert drive.command(_Out(5.0)) == (5.0, True)
    assert drive.no_command() == (5.0, True)                 # no fallback: held
    drive.command(_Out(7.0, fallback=(-30.0, 2.0)))
    assert drive.no_command() == (-30.0, True)               # the schedule: its first current, then the last
    assert drive.no_command() == (2.0, True)
    assert drive.no_command() == (2.0, True)
    assert drive.fallback_periods == 3
    assert drive.no_command() == (0.0, False)                # beyond 3 periods without a command: the watchdog
    assert drive.trips == 1 and drive.state == contract.DRIVE_STATE_WATCHDOG
    assert drive.command(_Out(6.0)) == (0.0, False)          # resumed commands do not re-enable it
    assert drive.command(_Out(6.0, reenable=True)) == (6.0, True)
    assert drive.state == contract.DRIVE_STATE_ENABLED
    drive.command(_Out(7.0, fallback=(math.nan,)))           # refused: held
    assert drive.no_command() == (7.0, True)
    # a re-enable sent in a period whose command was late is not lost (drive_enable is latched and reliable): it
    # arrives with the next command
    for _ in range(4):
        drive.no_command()
    assert drive.state == contract.DRIVE_STATE_WATCHDOG and drive.trips == 2
    assert drive.missed(_Out(6.0, reenable=True)) == (0.0, False)
    assert drive.command(_Out(6.5)) == (6.5, True) and not drive.reenable_pending
    # an enable edge re-enables too (the controller node publishes drive_enable on a change), as on the plant node
    for _ in range(4):
        drive.no_command()
    assert drive.command(_Out(0.0, enable=False)) == (0.0, False)
    assert drive.command(_Out(6.0)) == (6.0, True) and drive.state == contract.DRIVE_STATE_ENABLED
    # a drive without the feature holds whatever the controller says
    old = StalledDrive(LoopStalls(fallback=False))
    old.command(_Out(7.0, fallback=(-2.0,)))
    assert old.no_command() == (7.0, True) and old.fallback_periods == 0


def _startup_periods(overrides: dict, seconds: float = 20.0):
    """The start-up profile's first ``seconds`` offline, the loop closed as the node closes it (the driver's
    ``after_period`` after each command): per period the output and whether the fine stage was in a doublet's
    pulse."""
    plan = plan_run(load_scenario("startup"), OFFLINE, seed=0, controller_overrides=overrides)
    plant, drv = Plant(plan.plant_params), D.ValveDriver(plan.controller_params)
    plan.start_held(plant, drv)
    rows = []
    for k in range(int(round(seconds / drv.period))):
        t = k * drv.period
        out, _ = sim.exchange_period(drv, plant, t, plan.demand.value(t))
        fine = getattr(drv.controller.law, "fine", None)
        # 1: the doublet's kick, 2..: its retreat (0: not in a doublet's pulse)
        doublet = fine._k if fine is not None and fine.phase == PULSE and fine._doublet else 0
        drv.after_period()
        rows.append((out, drv.fallback_currents(), doublet))
        plant.set_command(out.current_a, out.enable)
        plant.advance(drv.period)
    return rows


def test_in_a_doublet_the_fallback_is_the_next_periods_command_then_the_band_middle():
    rows = _startup_periods({})
    kicks = 0
    for (out, fallback, doublet), (nxt, _, _) in zip(rows, rows[1:]):
        if doublet == 1:
            # after the kick's command (and after the retreat planned meanwhile) the drive's first fallback is the
            # retreat the next period commands, then the current holding the valve against the known load
            kicks += 1
            assert len(fallback) == 2 and fallback[0] == pytest.approx(nxt.current_a, abs=1e-9), (fallback, nxt)
            assert abs(nxt.current_a - out.current_a) > 10.0         # (a kick, then a retreat)
            assert abs(fallback[1]) < 15.0
        elif doublet > 1:
            # a retreat period: the next retreat period and the band middle, or after the last the band middle alone
            # (the observe servo's first command is a feedback torque up to the cap: not what a late answer should
            # leave applied, and a retreat held over several periods breaks the valve loose backwards)
            assert (len(fallback) == 2 and fallback[0] == pytest.approx(nxt.current_a, abs=1e-9)) or (
                len(fallback) == 1 and abs(fallback[0]) < 15.0), (fallback, nxt)
        elif out.fallback_currents_a:
            # the stage's other periods (park, observe, hold): the band middle alone
            assert len(fallback) == 1 and abs(fallback[0]) < 15.0
    assert kicks >= 2, kicks              # (the profile's plateaus take 2 doublets; the rest are servo-blended pulses)
    # the main law's periods (its moves, a plateau's wait before the stage engages): hold
    assert sum(not o.fallback_currents_a for o, _, _ in rows) > 0.1 * len(rows)
    # off: never set
    assert not any(o.fallback_currents_a for o, _, _ in _startup_periods({"fine.pulse_fallback": False}, 4.0))


def _steps(overrides: dict, stall_seed: int) -> list[float]:
    plan = plan_run(load_scenario("startup"), OFFLINE, seed=0, controller_overrides=overrides)
    result = sim.simulate_plan(plan, stalls=LoopStalls(seed=stall_seed))
    return [s.get("overshoot_pct", 0.0) for s in result.segments if s["kind"] == "step"]


def test_with_late_answers_emulated_the_fallback_keeps_a_doublet_from_throwing_the_valve():
    # stall seed 6 (§113): the drive holding the last command through the late answers, the stage kept aside 2 s
    # after any late loop (stop 29's build), overshoots 73 % twice; with the fallback and the short hold-off after an
    # isolated late loop no step beyond 15 %
    old = _steps({"fine.pulse_fallback": False, "fine.late_loop_holdoff_first_s": 2.0}, 6)
    new = _steps({}, 6)
    assert max(old) > 50.0, old
    assert max(new) < 15.0, new


@pytest.mark.ros
def test_the_plant_node_applies_the_fallback_in_a_tick_without_a_command():
    pytest.importorskip("rclpy")
    import rclpy
    from rclpy.parameter import Parameter
    from std_msgs.msg import Bool, Float64, Float64MultiArray
    from fuel_valve_plant.ros import plant_node as pn

    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    node = pn.PlantNode(context=ctx, namespace="/fallback_test",
                        parameter_overrides=[Parameter("command_timeout_s", value=0.1)])
    try:
        def ticks(n: int = 20) -> None:
            start = node.stats.ticks
            end = time.monotonic() + 10.0
            while node.stats.ticks < start + n and time.monotonic() < end:
                time.sleep(0.002)
            assert node.stats.ticks >= start + n

        node.on_enable(Bool(data=True))
        node.on_command(Float64(data=5.0))
        ticks()
        assert node._iq == 5.0 and node.fallback_periods == 0          # no fallback set: held
        node.on_fallback(Float64MultiArray(data=[-3.0]))
        node.on_command(Float64(data=5.0))
        ticks()
        assert node._iq == -3.0 and node.fallback_periods > 0
        node.on_fallback(Float64MultiArray(data=[-30.0, 2.0]))         # the first period's, then the last one
        node.on_command(Float64(data=5.0))
        ticks()
        assert node._iq == 2.0
        node.on_fallback(Float64MultiArray(data=[1.0, math.inf]))      # refused: hold again
        assert node._fallback == ()
        node.on_command(Float64(data=4.0))
        ticks()
        assert node._iq == 4.0
    finally:
        node.stop()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
