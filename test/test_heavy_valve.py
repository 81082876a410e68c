"""A heavy valve (valve inertia JL x3, everything else nominal; docs/control_results.md sections
35 and 38, ``benchmarks/other_valves.py``), the controller told its model.

Stuck short of its target the hold ramps the drive to the static friction Ts; once the valve
lets go it needs only the Coulomb level Tc.  With the drive left at Ts, the gear output (J1)
and the valve (JL) on the coupling accelerate together at (Ts - Tc) / (J1 + JL) while the
coupling swings; the valve's speed, ``∝ c s + sin s`` (c = JL / J1, s = ω t), comes back to
zero -- the slide arrests itself, ~2 (Ts - Tc) / K -- only if c < 0.2172 (the tangent of
``c s + sin s`` through the origin, tan s0 = s0).  Nominal c = 0.11; JL x3 c = 0.33, and in
``observer_fp`` / ``observer_ff`` (whose compensator did not give the surplus back) the
`startup` 0.5 % steps slid 1.07e-2 rad for 3.6e-3 and ended 3.8-4.6e-3 rad off (main).

``integral.relieve_unarrested_swing`` (off by default: the heavy valve's observer_fp campaign
p95 got worse, section 38) gives the surplus back on such valves only.
"""
from __future__ import annotations

import functools
import math

import numpy as np
import pytest
from scipy.optimize import brentq

from conftest import load_benchmark
from prefetch import ModuleRuns, jobs, selected_items
from fuel_valve_control.core.laws.state_feedback import StateFeedbackLaw
from fuel_valve_control.core.model import NominalModel
from fuel_valve_control.core.params import CONTROLLER_SPEC
from fuel_valve_control.tools import metrics as M
from fuel_valve_control.tools import sim

OV = load_benchmark("other_valves")


def _model(valve: str) -> NominalModel:
    _, ctrl = OV.overrides(OV.VALVES[valve])
    return NominalModel.from_params(CONTROLLER_SPEC.load(None, ctrl))


@functools.lru_cache(maxsize=None)
def _startup(valve: str, mode: str, relieve: bool = False):
    return _AHEAD.result(valve, mode, relieve)


def _simulate(valve: str, mode: str, relieve: bool = False):
    """The start-up run itself (here or in a look-ahead worker, test/prefetch.py)."""
    plant, ctrl = OV.overrides(OV.VALVES[valve])
    if relieve:
        ctrl = {**ctrl, "integral.relieve_unarrested_swing": True}
    return sim.run("startup", mode=mode, plant_overrides=plant, controller_overrides=ctrl, seed=0)


#: the module's look-ahead runs (test/prefetch.py); none outside the module fixture below
_AHEAD = ModuleRuns(_simulate)
#: the start-up runs each test asks for
_PLANNED = {"test_heavy_valve_startup_plateaus_settle_with_the_relief": [("heavy_valve", "observer_fp", True)],
            "test_heavy_valve_startup_plateaus_settle_by_default": [("heavy_valve", "observer_fp", False)],
            "test_nominal_startup_keeps_working_with_the_relief": [("nominal", "observer_fp", True),
                                                                    ("nominal", "observer_fp", False)]}


@pytest.fixture(scope="module", autouse=True)
def _look_ahead(request):
    """The module's start-up runs on both cores; each test still takes and asserts its own run."""
    keys = [key for item in selected_items(request) for key in _PLANNED.get(item.originalname, [])]
    with _AHEAD.planned(keys, jobs(request.config)):
        yield


def _worst_plateau(res) -> float:
    log = res.log
    tr = M.Trace(log[:, 0], log[:, 1], log[:, 2], np.hypot(log[:, 7], log[:, 8]), log[:, 9], res.stroke_rad)
    return max(abs(pl["final_error_rad"]) for pl in M.plateau_results(tr))


def test_swing_arrest_limit_is_the_tangent_value():
    """``c s + sin s`` has a zero at s > 0 iff c < -cos s0 with tan s0 = s0; the nominal valve is
    below it (its swing arrests itself, nothing changes for it), the heavy valve above."""
    s0 = brentq(lambda s: math.tan(s) - s, math.pi + 0.1, 1.5 * math.pi - 1e-6)
    assert StateFeedbackLaw.SWING_ARREST_RATIO == pytest.approx(-math.cos(s0), abs=1e-4)
    nominal = NominalModel.from_params(CONTROLLER_SPEC.defaults())
    assert nominal.valve_inertia_kgm2 / nominal.j1 < StateFeedbackLaw.SWING_ARREST_RATIO
    heavy = _model("heavy_valve")
    assert heavy.valve_inertia_kgm2 / heavy.j1 > StateFeedbackLaw.SWING_ARREST_RATIO


def test_heavy_valve_startup_plateaus_settle_with_the_relief():
    """Default mode with ``integral.relieve_unarrested_swing``, JL x3 told: every `startup`
    plateau ends within 8e-4 rad (main / option off: the 0.5 % steps' slides ended 4.6e-3 and
    3.8e-3 rad off), no fault, within the 30 A of the pulses."""
    res = _startup("heavy_valve", "observer_fp", True)
    assert _worst_plateau(res) < 8e-4
    assert not np.any(res.fault > 0)
    assert res.metrics["peak_current_a"] < 30.0


def test_heavy_valve_startup_plateaus_settle_by_default():
    """Default mode, relief off (JL x3 told): every `startup` plateau ends within 8e-4 rad since C1 is the default
    (stop 25, task h36f, docs §91: the apex policy's doublets finish the 0.5 % steps' slides).  Before C1 a strict
    xfail: main's staircase left them 4.6e-3 and 3.8e-3 rad off (the relief is off as its campaign p95 got worse,
    section 38)."""
    assert _worst_plateau(_startup("heavy_valve", "observer_fp")) < 8e-4


def test_nominal_startup_keeps_working_with_the_relief():
    """The nominal valve's swing arrests itself: with the option on its law is unchanged,
    `startup` worst plateau 2.9e-4 rad as on main."""
    res = _startup("nominal", "observer_fp", True)
    assert _worst_plateau(res) == pytest.approx(_worst_plateau(_startup("nominal", "observer_fp")), abs=0.0)
    assert _worst_plateau(res) < 5e-4


def _heavy_law(**extra):
    from fuel_valve_control.core.position_controller import PositionController
    _, ctrl = OV.overrides(OV.VALVES["heavy_valve"])
    pc = PositionController(CONTROLLER_SPEC.load(None, {**ctrl, "mode": "observer_fp",
                                                        "integral.relieve_unarrested_swing": True, **extra}))
    law = pc.law.main                     # observer_fp: the fine stage around the state-feedback law
    assert law.relieve_swing
    return law


@pytest.mark.parametrize("met", [True, False])
def test_swing_relief_gives_back_the_surplus_the_valve_met(met):
    """h25h (section 47): the give-back at breakaway is sized on the drive the valve broke away at
    (the static friction met) times the schedule's 1 - Tc/Ts, not the scheduled Ts - Tc: a valve
    that broke away at 6.3 N*m (the campaign's static scatter; Ts 5.5 scheduled, Tc 4.4) has
    1.26 N*m of surplus to take back, not 1.1.  ``integral.relieve_met_surplus`` false: the
    scheduled surplus (section 38)."""
    law = _heavy_law(**{"integral.relieve_met_surplus": met})
    fr = law.model.friction(law.model.pressure_max_kpa)
    ts, tc = fr.valve_static_nm, fr.valve_coulomb_nm
    drive = 1.15 * ts                     # toward the target (+), beyond the loads
    law.zeta = 0.0
    law._relieve_breakaway(0.5, True, True, False, 1e-2, fr, drive)          # stuck short, outside
    law._relieve_breakaway(0.5 + 0.5 * law.jumps.min_jump, False, True, False, 1e-2, fr, drive)
    assert law.zeta == 0.0                # not slid a jump yet
    law._relieve_breakaway(0.5 + 1.01 * law.jumps.min_jump, False, True, False, 1e-2, fr, drive)
    given = -law.zeta * law.fb.ki * law.model.gear_ratio                    # N*m at the valve
    assert given == pytest.approx(drive * (ts - tc) / ts if met else ts - tc, rel=1e-9)
