"""The doublet's move tables built ahead (task h34t, ``fine.apex_policy``, docs §80.9 / §81).

With ``fine.apex_policy`` the fine stage reads keyed Δp x angle tables of the doublet's move
(:class:`~fuel_valve_control.core.pulse_moves.PulseMoves`); built lazily, each costs ~0.12 s of CPU inside the
period that first needs it.  :meth:`PositionController.prepare` (the fine stage's :meth:`FinePositioner.prepare`)
builds every table the policy can ask for; the ROS controller node calls it at configure, and refuses a run-time
change whose law would need a table not built then.  Here: after ``prepare()`` no update builds or simulates
anything; with the option off nothing is made; the node builds at configure and refuses (a reason given) what it
cannot serve from its tables (``fine.apex_policy`` itself is read-only on the node: not a run-time parameter).

The tables are built on a 2 x 2 (Δp x angle) grid here (the grid's corners: every Δp and angle still lies inside
it) instead of the default 19 x 3 -- the wiring is what is tested, not the grid (~1 s of CPU instead of ~14 s).
"""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

from fuel_valve_control.core.pulse_moves import PulseMoves
from fuel_valve_control.tools.sim import exchange_period

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import robustness as R  # noqa: E402

#: the small grid (fractions of the max Δp and of the stroke): its corners
SMALL_GRID = {"dp_grid": (0.0, 1.0), "angle_grid": (0.0, 1.0)}
#: the nominal-box run driven (its first apex-policy doublet comes within the first plateaus)
SEED = 1000
#: periods run after the build: past the first doublets the policy plans (nominal box seed 1000: the first
#: choice at period 357)
PERIODS = 800


@pytest.fixture
def small_grid(monkeypatch):
    """Every move model the fine stage makes uses :data:`SMALL_GRID`."""
    make = PulseMoves.for_positioner.__func__

    def small(cls, fine, ps=None, **kw):
        return make(cls, fine, ps, **{**SMALL_GRID, **kw})

    monkeypatch.setattr(PulseMoves, "for_positioner", classmethod(small))


def _run(plan, plant, driver, periods):
    per = driver.period
    for k in range(periods):
        t = k * per
        out, _ = exchange_period(driver, plant, t, plan.demand.value(t))
        plant.set_command(out.current_a, out.enable)
        plant.advance(per)


def test_prepare_builds_every_table_the_apex_policy_reads(small_grid, monkeypatch):
    plan, plant, driver = R.held_case(R.sample_case(SEED, "nominal"), controller_sets={"fine.apex_policy": True})
    ctl = driver.controller
    fine = ctl.law.fine
    moves = fine._moves                                # made with the law, on the told model: no table built
    assert moves is not None and moves.builds == 0 and moves.m is fine.m0
    pending, _ = ctl.prepare()
    assert fine._moves is moves and moves.pending(kicks=fine._apex_kicks()) == []
    # directions x Δp x angle points x kicks (some may be shared; C1's default kicks 4 / 8 / 16 A since stop 25, docs §91)
    assert pending <= 2 * 2 * 2 * len(fine._apex_kicks())
    assert ctl.prepare(build=False) == (0, 0.0)        # nothing left
    builds, runs = moves.builds, moves.runs
    choices = []
    choose = fine._choose_apex

    def counted(*a, **kw):
        choices.append(a)
        return choose(*a, **kw)

    monkeypatch.setattr(fine, "_choose_apex", counted)
    _run(plan, plant, driver, PERIODS)
    assert choices, "no doublet was planned in the periods run: the check saw no table read"
    assert fine._moves is moves
    assert (moves.builds, moves.runs) == (builds, runs), "a table was built inside an update after prepare()"


def test_prepare_makes_nothing_with_the_apex_policy_off():
    # off explicitly: C1 (the apex policy with kicks to 16 A) is the default since stop 25 (task h36f, docs §91)
    plan, plant, driver = R.held_case(R.sample_case(SEED, "nominal"), controller_sets={"fine.apex_policy": False})
    ctl = driver.controller
    assert ctl.prepare() == (0, 0.0)
    assert ctl.law.fine._moves is None
    _run(plan, plant, driver, 300)
    assert ctl.law.fine._moves is None


@pytest.mark.ros
def test_node_builds_the_tables_at_configure_and_refuses_changes_it_cannot_serve(small_grid):
    rclpy = pytest.importorskip("rclpy")
    from rclpy.parameter import Parameter
    from fuel_valve_control.ros.controller_node import ControllerNode

    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    try:
        node = ControllerNode(context=ctx, namespace="/tables_on", parameter_overrides=[
            Parameter("autostart", value=False), Parameter("fine.apex_policy", value=True),
            Parameter("fine.apex_kick_max_a", value=0.0)])     # main's 4 A kick only (C1's 16 A is the default)
        assert node.driver is None
        node.trigger_configure()
        fine = node.driver.controller.law.fine
        assert fine._moves is not None and fine._moves.pending(kicks=fine._apex_kicks()) == []
        law = node.driver.controller.law
        # kicks to 16 A: tables for 8 and 16 A the loop would build -> refused, the law stays
        res = node.set_parameters([Parameter("fine.apex_kick_max_a", value=16.0)])[0]
        assert not res.successful and "move tables" in res.reason and "configure" in res.reason, res.reason
        res = node.set_parameters([Parameter("fine.apex_policy", value=False)])[0]
        assert not res.successful and "read-only" in res.reason, res.reason        # not a run-time parameter
        assert node.driver.ps["fine.apex_kick_max_a"] == 0.0 and node.driver.ps["fine.apex_policy"] is True
        # a change its tables serve: accepted
        res = node.set_parameters([Parameter("fine.apex_land_rad", value=3e-4)])[0]
        assert res.successful, res.reason
        assert node.driver.params_pending or node.driver.controller.law is not law
        node.destroy_node()

        node = ControllerNode(context=ctx, namespace="/tables_off", parameter_overrides=[
            Parameter("autostart", value=False), Parameter("fine.apex_policy", value=False)])   # on by default (C1)
        node.trigger_configure()
        assert node.driver.controller.law.fine._moves is None       # off: nothing made at configure
        assert not node.set_parameters([Parameter("fine.apex_policy", value=True)])[0].successful
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)
