"""The cold start's climb (``fine.cold_climb``, task s33, docs §116): before any breakaway the stage does not
know the valve's level, and the cold start's first preload, placed below the *told* level, broke a valve of less
friction loose while parked -- a whole stick-slip jump across a run's first small step (friction x0.6, 1.5e-3 rad:
3.9-4.3e-3 rad off; §114.9).  With the climb, each cold try parks at a twist the valve is proven to hold and kicks
from there, so a low level is crossed in a kick whose retreat cuts the move short; its trough and the observe
servo's final twist are sized for the level the valve is proven to have (``fine.cold_friction_min``: none assumed by
default), not the told one."""
from __future__ import annotations

import numpy as np
import pytest

from first_step import first_step
from fuel_valve_control.core import fine_positioning as fp
from fuel_valve_control.core.params import CONTROLLER_SPEC

COLD = {"fine.cold_start": True, "fine.cold_climb": False}      # the cold start without the climb
CLIMB = {"fine.cold_start": True, "fine.cold_climb": True}


def _across(log, direction: int) -> float:
    """The furthest the valve went past the target after the step (rad, > 0: across it)."""
    t, target, valve = log[:, 0], log[:, 1], log[:, 2]
    after = t >= 0.3
    return float(np.max(direction * (valve[after] - target[after])))


def test_the_climb_is_on_by_default_and_does_nothing_without_the_cold_start():
    defaults = CONTROLLER_SPEC.defaults()
    assert defaults["fine.cold_start"] is True and defaults["fine.cold_climb"] is True    # since stop 34 (§117)
    _, base = first_step(1.5e-3, 0.6, **{"fine.cold_start": False, "fine.cold_climb": False})
    _, climb_only = first_step(1.5e-3, 0.6, **{"fine.cold_start": False})
    assert np.array_equal(base, climb_only)
    _, default = first_step(1.5e-3, 0.6)
    _, climb = first_step(1.5e-3, 0.6, **CLIMB)
    assert np.array_equal(default, climb) and not np.array_equal(default, base)


@pytest.mark.parametrize("direction", [1, -1])
@pytest.mark.parametrize("friction_scale", [0.3, 0.5, 0.6])
def test_a_low_friction_valves_first_small_step_is_not_thrown_across(friction_scale, direction):
    step = direction * 1.5e-3
    plateaus, log = first_step(step, friction_scale, **COLD)
    assert _across(log, direction) > 2e-3                     # without the climb: a whole jump across
    # with it: nearer than it started (x0.5: 1.0-1.1e-3 rad across, the kick's overdrive on the level; x0.3 / 0.6:
    # 0.4-0.9e-3 off), never thrown further
    plateaus, log = first_step(step, friction_scale, **CLIMB)
    assert plateaus[-1]["final_error_rad"] < 0.8 * abs(step), plateaus[-1]
    assert _across(log, direction) < 0.8 * abs(step)
    assert not plateaus[-1]["hunts"]


@pytest.mark.parametrize("direction", [1, -1])
def test_the_told_valves_first_small_step_still_lands(direction):
    plateaus, log = first_step(direction * 1.5e-3, 1.0, **CLIMB)
    assert plateaus[-1]["final_error_rad"] <= 5e-4, plateaus[-1]
    assert _across(log, direction) < 5e-4


def test_a_first_step_between_half_the_jump_and_the_main_laws_deadband_is_taken():
    """2.4e-3 rad: beyond the cold start's half jump (2.29e-3 rad at max Δp) but inside the main law's deadband
    (2.52e-3): without the climb neither moves it."""
    plateaus, _ = first_step(2.4e-3, 1.0, **COLD)
    assert plateaus[-1]["final_error_rad"] > 2.3e-3
    plateaus, _ = first_step(2.4e-3, 1.0, **CLIMB)
    assert plateaus[-1]["final_error_rad"] <= 5e-4, plateaus[-1]


class _Tries:
    """Records every cold try's park target and the valve's move when it ends (wraps the stage's methods)."""

    def __init__(self, monkeypatch):
        self.parks, self.ends = [], []
        start, after = fp.FinePositioner._start_try, fp.FinePositioner._after_move
        rec = self

        def start_try(stage, choice, th1, thl, final):
            cold = stage._cold
            start(stage, choice, th1, thl, final)
            if cold and stage.phase == fp.PARK:
                rec.parks.append((choice[1], stage._pre, stage._phi0, stage._floor(choice[1])))

        def after_move(stage, th1, thl, pressure_kpa, pulsed, after_command=False):
            if stage._cold:
                rec.ends.append((pulsed, thl - stage._thl0))
            return after(stage, th1, thl, pressure_kpa, pulsed, after_command)

        monkeypatch.setattr(fp.FinePositioner, "_start_try", start_try)
        monkeypatch.setattr(fp.FinePositioner, "_after_move", after_move)


@pytest.mark.parametrize("friction_scale", [0.6, 1.0])
def test_no_cold_try_breaks_the_valve_loose_in_its_park(monkeypatch, friction_scale):
    """Every cold try parks no further than a twist proven to hold -- the rest twist (here the load's: the band's
    middle) or the last unmoved apex -- and the valve never lets go in a cold park (``pulsed`` False: the park's
    move)."""
    tries = _Tries(monkeypatch)
    first_step(1.5e-3, friction_scale, **CLIMB)
    assert len(tries.parks) >= 2                              # a climb, not one lucky try
    assert tries.ends and all(pulsed for pulsed, _ in tries.ends)
    for d, pre, rest, floor in tries.parks:
        proven = rest if floor is None else max(d * rest, d * floor[1]) * d
        assert d * (pre - proven) <= 0.0


def test_a_least_friction_assumed_above_the_valves_breaks_it_loose_in_the_first_park(monkeypatch):
    """The first park goes to ``fine.cold_friction_min`` x the told level less the prior margin where that lies
    beyond the rest twist: assumed 0.7, a x0.6 valve breaks loose in it (why the default assumes nothing)."""
    tries = _Tries(monkeypatch)
    first_step(1.5e-3, 0.6, **CLIMB, **{"fine.cold_friction_min": 0.7})
    assert any(not pulsed and abs(move) > 1e-3 for pulsed, move in tries.ends)


@pytest.fixture(scope="module")
def grid():
    from conftest import load_benchmark
    return load_benchmark("adaptation_grid")


def test_no_cold_climb_on_the_error_the_valve_started_with(grid):
    """``adaptation_grid.py --dp-error``, F x 0.5, Δp 0 told the rated Δp (friction x0.045 of the told): the valve
    starts 5.2e-4 rad off its first demand.  Engaged cold on that start, the climb's first kick carried the valve
    along and the main law's 2 % step from where it was left overshot 46 %; the climb waits for the demand to change,
    and the cell is the default's to the bit."""
    cell = {**grid.NOMINAL, "friction": 0.5, "inertia": 1.0, "dp_kpa": 0.0, "stiffness": 1.0}
    told = grid.P_MAX
    off = grid.run_cell("observer_fp", cell, told_dp_kpa=told)
    on = grid.run_cell("observer_fp", cell, told_dp_kpa=told, controller_sets=CLIMB)
    for key in ("overshoot_pct", "final_error_rad", "tail_pp_rad", "peak_current_a"):
        assert on[key] == off[key], key
    assert on["overshoot_pct"] < 5.0


def test_no_cold_engagement_on_a_valve_the_hold_moved_this_plateau(robustness_bench):
    """``fine.cold_still`` (task s34, docs §117), full box seed 3025 (LuGre friction x2.9, an untold 9.3 N*m load, Δp
    read 9 % low): the run's first step (-3.1e-3 rad) lies beyond the main law's deadband, its hold creeps the valve
    0.8e-3 rad toward the target with no slip the stage reads as a breakaway, and the valve rests at the edge of its
    band.  Climbing from that rest, the first kick let it go a whole jump of this friction: 1.5e-2 rad across.  With
    the gate the cold start leaves a valve that moved on this plateau to the main law: the plateau ends as the
    default's."""
    case = robustness_bench.sample_case(3025, "full")

    def first(sets):
        return robustness_bench.run_case((case, None, sets))["plateaus"][0]

    base = first({})
    assert 1.5e-3 < base["final_error_rad"] < 3e-3                 # the main law's: inside its deadband
    thrown = first({**CLIMB, "fine.cold_still": False})
    assert thrown["final_error_rad"] > 1e-2 and thrown["overshoot_pct"] > 100.0
    gated = first(CLIMB)
    assert gated["final_error_rad"] == base["final_error_rad"] and gated["overshoot_pct"] == base["overshoot_pct"]


def test_no_cold_engagement_while_the_policy_waits_for_its_move_tables():
    """A ROS node's stage runs main's staircase, the policy off, until its move tables are built (task h36b,
    ``FinePositioner.defer_tables``).  The climb is the policy's: a cold engagement then would be the staircase's cold
    start, which throws a valve of less friction than told a whole jump across its first step (docs §114.9) -- none
    is made until the policy is back."""
    from dataclasses import replace

    from fuel_valve_control.common.contract import PRESSURE_MAX_KPA
    from fuel_valve_control.core.position_controller import PositionController
    pc = PositionController(CONTROLLER_SPEC.defaults().replace({"mode": "observer_fp"}))
    fine = pc.law.fine
    fine._steady = 10 ** 6                      # the demand held long enough, changed since the start
    fine._demand_moved = True
    fine._plateau_valve = 0.3                   # the valve still where this plateau's demand found it
    assert fine._cold_ready(1.5e-3, 0.3, PRESSURE_MAX_KPA)
    fine.cfg = replace(fine.cfg, **dict.fromkeys(fp.APEX_BUILD_OFF, False))    # what defer_tables' gate sets
    assert not fine._cold_ready(1.5e-3, 0.3, PRESSURE_MAX_KPA)
