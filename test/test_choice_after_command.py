"""The apex policy's choice after the period's command (``fine.apex_choice_after_command``, task h39n, docs §103),
and the real-time benchmark's plateau demand through the demand node (``benchmarks/ros_loop.py --demand plateaus``).

No timing is asserted: the tests check the same commands to the last bit, where the choice runs, and that the
demand node plays the campaign's plateaus."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

from fuel_valve_control.common.paramspec import ConfigError
from fuel_valve_control.core.driver import ValveDriver
from fuel_valve_control.tools import sim
from fuel_valve_control.tools.profiles import profile_from_params
from fuel_valve_control.tools.run_plan import REAL_TIME, plan_run
from fuel_valve_control.tools.scenarios import parse_scenario
from fuel_valve_plant.physics.plant import Plant

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT / "benchmarks") not in sys.path:
    sys.path.insert(0, str(ROOT / "benchmarks"))

#: nominal box seed 1000's first 2.5 s: four plateaus, the apex policy chooses 6 tries (C1)
SEED, SECONDS = 1000, 2.5


def _closed_loop(sets: dict, call_after: bool) -> tuple[list, object, int]:
    """(commands, fine stage, after_period() calls that ran work) of the nominal case ``SEED`` for ``SECONDS``,
    the driver built with ``sets``; ``call_after``: the ROS node's order (``after_period`` once the command is
    out), else the offline simulator's (nobody calls it)."""
    import robustness as rb
    plan, plant, driver = rb.held_case(rb.sample_case(SEED, "nominal"), None, sets)
    period, commands, ran = driver.period, [], 0
    for k in range(int(round(SECONDS / period))):
        t = k * period
        out, _ = sim.exchange_period(driver, plant, t, plan.demand.value(t))
        commands.append((out.current_a, out.enable))
        plant.set_command(out.current_a, out.enable)
        if call_after:
            ran += driver.after_period()
        plant.advance(period)
    return commands, driver.controller.law.fine, ran


def test_the_choice_after_the_command_gives_the_same_commands_to_the_last_bit():
    """Inline (the option off, main's order), after the command in the node's order, and after the command left to
    the next period (offline): the same commands, bit for bit; the tries are chosen after their command, and in the
    node's order every one by ``after_period``.  (Fails if the starting period's command read anything the choice
    sets, or if the pending start ran on the next period's inputs.)"""
    inline, f_inline, ran_inline = _closed_loop({"fine.apex_choice_after_command": False,
                                                 "fine.retreat_plan_after_command": False}, True)
    node, f_node, ran_node = _closed_loop({}, True)
    offline, f_offline, _ = _closed_loop({}, False)
    assert f_inline.apex_choices == f_node.apex_choices == f_offline.apex_choices >= 5
    assert f_inline.apex_choices_after_command == 0 and ran_inline == 0
    assert f_node.apex_choices_after_command == f_node.apex_choices
    # (the kicks' retreat plans run after their own periods' commands too: fine.retreat_plan_after_command)
    assert ran_node == f_node.apex_choices + f_node.retreat_plans_after_command
    assert f_offline.apex_choices_after_command == f_offline.apex_choices
    assert node == inline
    assert offline == inline


def test_the_retreat_plan_after_the_kick_gives_the_same_commands_to_the_last_bit():
    """``fine.retreat_plan_after_command`` (docs §111): the doublet's retreat (the move model's trough bound, planned in
    the kick period) is planned after the kick's command -- by ``after_period`` in the node's order, by the next
    period offline -- and every command is the inline plan's, bit for bit, with the plan itself unchanged.  (Fails if
    the kick read the plan, or if the deferred plan ran on the next period's state: the stage's twist and speed are
    taken from that period's samples.)"""
    base = {"fine.apex_choice_after_command": False}
    inline, f_inline, ran_inline = _closed_loop({**base, "fine.retreat_plan_after_command": False}, True)
    node, f_node, ran_node = _closed_loop(base, True)
    offline, f_offline, _ = _closed_loop(base, False)
    assert f_inline.retreat_plans_after_command == 0 and ran_inline == 0
    # every doublet's retreat after its kick's command: in the node's order each by after_period
    assert f_node.retreat_plans_after_command == ran_node >= 5
    assert f_offline.retreat_plans_after_command == f_node.retreat_plans_after_command
    assert f_node._retreat == f_inline._retreat == f_offline._retreat
    assert node == inline
    assert offline == inline


def test_the_choice_stays_inline_where_the_starting_period_reads_it():
    """With ``fine.retreat_stop_unmoved`` the starting period's observe servo holds short of the new preload (set from
    the choice): there the choice stays inline, and the commands are the option-off ones.  (Left after the command, the
    commands differed from period 357 on: checked by removing the guard.)"""
    sets = {"fine.retreat_stop_unmoved": True}
    inline, f_inline, _ = _closed_loop({**sets, "fine.apex_choice_after_command": False}, True)
    on, f_on, ran = _closed_loop(sets, True)
    assert f_on.apex_choices == f_inline.apex_choices >= 5
    assert f_on.apex_choices_after_command == 0 and ran == f_on.retreat_plans_after_command  # (only retreat plans)
    assert on == inline


def test_a_pending_start_runs_before_a_reset_and_before_the_next_update():
    """A try left pending is finished before anything else touches the stage: a reset (a new demand, a fault) and
    the next period's update run it first, so its verdicts (the learner's) are never lost or judged on later state;
    ``run_pending`` with nothing pending does nothing."""
    import robustness as rb
    plan, plant, driver = rb.held_case(rb.sample_case(SEED, "nominal"), None, {})
    fine = driver.controller.law.fine
    period = driver.period
    for k in range(int(round(SECONDS / period))):
        t = k * period
        out, _ = sim.exchange_period(driver, plant, t, plan.demand.value(t))
        plant.set_command(out.current_a, out.enable)
        plant.advance(period)
        if fine._pending is not None:
            break
    else:
        pytest.fail("no try was left for after its command")
    assert fine.phase == "observe"                 # the start's phase is the choice's: not set yet
    choices = fine.apex_choices
    fine.reset(measurements=False)
    assert fine._pending is None and fine.apex_choices == choices + 1 and fine.phase == "idle"
    assert fine.run_pending() is False


def test_a_plateau_demand_reaches_the_demand_node_as_the_same_profile():
    """``benchmarks/ros_loop.py --demand plateaus``: a scenario's ``plateaus`` demand goes to the demand node as its
    corner points (``previous``), the profile the node builds from its parameters equals the plan's at every corner
    and between; a plateau demand with noise the node cannot play is a clear error."""
    import robustness as rb
    case = rb.sample_case(SEED, "nominal")
    plan = plan_run(rb.case_scenario(case, count=40), REAL_TIME)
    params = plan.node_parameters()["demand"]
    assert params["profile"] == "points" and params["interpolation"] == "previous"
    node_profile = profile_from_params(params)
    corners = plan.demand.points
    assert len(corners) == 2 * 40 + 2
    times = sorted({t for t, _ in corners} | {t + 1e-4 for t, _ in corners} | {t - 1e-4 for t, _ in corners if t})
    assert [node_profile.value(t) for t in times] == [plan.demand.value(t) for t in times]
    # the campaign's first 12 steps are the same with more plateaus drawn
    twelve = rb.case_scenario(case).demand.points
    assert [p for _, p in corners[:2 * 12]] == [p for _, p in twelve[:2 * 12]]
    noisy = parse_scenario({"name": "n", "duration_s": 5.0, "demand": {
        "type": "plateaus", "seed": 1, "count": 3, "initial": 30.0, "start_s": 0.3, "min_step_pct": 0.1,
        "max_step_pct": 5.0, "hold_s": [0.3, 0.8], "final_hold_s": 1.0, "noise_rms_pct": 0.05}})
    with pytest.raises(ConfigError, match="noise"):
        plan_run(noisy, REAL_TIME).node_parameters()


def test_the_controller_node_counts_the_periods_over_its_budget():
    """The controller node's compute figures on /diagnostics: per report the periods over 0.5 / 1 / 2 ms, and the
    work left for after a command under its own keys."""
    pytest.importorskip("rclpy")
    from fuel_valve_control.ros.controller_node import ComputeTime
    c = ComputeTime()
    for s in (1e-4, 6e-4, 1.5e-3, 2.5e-3):
        c.add(s)
    out = c.take()
    assert (out["compute_over_0p5_ms"], out["compute_over_1_ms"], out["compute_over_2_ms"]) == (3, 2, 1)
    assert out["samples_since_last_report"] == 4 and out["compute_max_ms"] == pytest.approx(2.5)
    assert c.take()["compute_over_0p5_ms"] == 0                   # counted since the last report
    a = ComputeTime("after_command")
    a.add(8e-4)
    out = a.take()
    assert out["after_command_count"] == 1 and out["after_command_over_0p5_ms"] == 1
    assert "samples_since_last_report" not in out
