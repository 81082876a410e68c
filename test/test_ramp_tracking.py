"""Slow demand ramps are followed (issue 14, task h19r; the v2 modes).

A valve with stiction follows a slow ramp by stick-slip: it sticks, the hold lets the error grow to
its deadband (about half a stick-slip jump), its stuck ramp winds the drive to breakaway within
``integral.stuck_ramp_time_s``, and the valve jumps ``2 (Ts - Tc)/K`` ahead.  So the error stays
within one nominal jump plus the ramp's travel during the stuck ramp (:func:`bound`): 4.6e-3 +
0.7e-3 rad on the `startup` ramps (7e-3 rad/s at max Δp).

Before the fix the `startup` ramp 23 -> 25 % was not followed: the hold's jump learner read the
cold start's catch-up (the first move ends with the valve stuck 3.8e-2 rad behind, then driven
onto the target) as a stick-slip jump 7.9x the nominal one; the deadband grew to 2e-2 rad and the
valve sat in it for the whole ramp (`observer_ff`: 1.9e-2 rad behind).  `observer_fp` jumped
1.9e-2 rad ahead at the ramp's start: the fine stage hands the plateau back with the twist
preloaded toward breakaway and the reference feed-forward added the static level on top (also
1.2-1.6e-2 rad on the second leg of a reversing ramp).
"""
from __future__ import annotations

import functools

import pytest

from fuel_valve_plant.physics.friction import friction_levels
from fuel_valve_control.tools.run_plan import OFFLINE, plan_run
from fuel_valve_control.tools.scenarios import load_scenario, parse_scenario
from fuel_valve_control.tools.sim import simulate_plan
from prefetch import ModuleRuns, jobs, selected_items

pytestmark = [pytest.mark.slow]

P_MAX = 6206.0
V2_MODES = ("observer_ff", "observer_fp")
#: `startup` up to the end of its second ramp (13 s) and a little of the plateau after it
STARTUP_UNTIL_S = 13.5


def bound(plan, ramp: dict) -> float:
    """Largest |demand - valve| (rad) a followed ramp may show: one nominal stick-slip jump at
    the run's Δp plus the ramp's travel while the hold's stuck ramp winds the drive through
    the static band (see the module docstring)."""
    ps = plan.plant_params
    jump = friction_levels(ps).stick_slip_jump_rad(ps["coupling.stiffness_nm_per_rad"])
    return jump + abs(ramp["rate_rad_s"]) * plan.controller_params["integral.stuck_ramp_time_s"]


def _ramps(plan) -> list[dict]:
    result = simulate_plan(plan)
    ramps = [s for s in result.segments if s["kind"] == "ramp"]
    assert ramps, "the demand has no ramp"
    return ramps


@functools.cache
def _startup(mode: str, seed: int):
    return _AHEAD.result("startup", mode, seed)


def _points(points, dp_kpa: float, mode: str, seed: int = 0):
    return _AHEAD.result("points", tuple(map(tuple, points)), dp_kpa, mode, seed)


def _simulate(kind: str, *args):
    """``(plan, ramps)`` of a run (here or in a look-ahead worker, test/prefetch.py):
    ``("startup", mode, seed)`` -- `startup` up to STARTUP_UNTIL_S; ``("points", points, dp_kpa,
    mode, seed)`` -- a linear demand through ``points`` ([t s, percent], ...) at ``dp_kpa``."""
    if kind == "startup":
        mode, seed = args
        sc = load_scenario("startup")
        sc.duration_s = STARTUP_UNTIL_S
    else:
        points, dp_kpa, mode, seed = args
        points = [list(p) for p in points]
        sc = parse_scenario({"name": "ramp", "duration_s": points[-1][0], "pressure_differential_kpa": dp_kpa,
                             "initial_percent": points[0][1], "demand": {"type": "points", "points": points}})
    plan = plan_run(sc, OFFLINE, mode=mode, seed=seed)
    return plan, _ramps(plan)


#: the module's look-ahead runs (test/prefetch.py); none outside the module fixture below
_AHEAD = ModuleRuns(_simulate)
#: the demands of the ramp tests below ([t s, percent], ...)
LOW_DP_RAMP = ((0, 23), (1, 23), (4, 25), (5, 25))
REVERSING_RAMP = ((0, 30), (1, 30), (4, 28), (5, 28), (8, 30), (9, 30))


def _planned(item) -> list[tuple]:
    """The runs (``_simulate``'s arguments) a selected test asks for; a run
    left out here is simulated when the test asks, as before."""
    name, params = item.originalname, getattr(getattr(item, "callspec", None), "params", {})
    if name.startswith("test_the_") and "_startup_ramp_" in name:
        return [("startup", params["mode"], params["seed"])]
    if name == "test_both_legs_of_a_reversing_ramp_are_followed_within_a_jump":
        return [("points", REVERSING_RAMP, P_MAX, params["mode"], 1)]
    if name == "test_a_ramp_at_low_and_half_dp_is_followed_within_a_jump":
        return [("points", LOW_DP_RAMP, params["dp_kpa"], "observer_fp", 0)]
    return []


@pytest.fixture(scope="module", autouse=True)
def _look_ahead(request):
    """The module's runs on both cores (test/prefetch.py); each test still takes and asserts its
    own run."""
    keys = [key for item in selected_items(request) for key in _planned(item)]
    keys.sort(key=lambda k: -(STARTUP_UNTIL_S if k[0] == "startup" else k[1][-1][0]))    # simulated s
    with _AHEAD.planned(keys, jobs(request.config)):
        yield


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("mode", V2_MODES)
def test_the_first_startup_ramp_is_followed_within_a_jump(mode, seed):
    plan, ramps = _startup(mode, seed)
    first = ramps[0]
    assert first["t_start_s"] == pytest.approx(3.0, abs=0.01)
    assert first["ramp_max_error_rad"] <= bound(plan, first), first


@pytest.mark.parametrize("seed", [0, 1])
@pytest.mark.parametrize("mode", V2_MODES)
def test_the_second_startup_ramp_is_followed_within_a_jump(mode, seed, request):
    if mode == "observer_ff":
        request.applymarker(pytest.mark.xfail(strict=True, reason=(
            "observer_ff: the first breakaway on this ramp (10.39 s seed 0, 10.77 s seed 1) slides "
            "twice (5e-3 then 6e-3 rad): the stuck ramp wound the drive to the static level, it "
            "stays there after the valve lets go, the gear output (9x the valve's inertia) runs "
            "on and breaks the valve loose again; 7.8e-3 / 7.4e-3 rad ahead against a bound of "
            "5.3e-3 (the v2 hold gives no breakaway surplus back; observer_fp follows this "
            "ramp within 3.8e-3)")))
    plan, ramps = _startup(mode, seed)
    second = ramps[1]
    assert second["t_start_s"] == pytest.approx(10.0, abs=0.01)
    assert second["ramp_max_error_rad"] <= bound(plan, second), second


@pytest.mark.parametrize("dp_kpa", [0.0, 0.5 * P_MAX])
def test_a_ramp_at_low_and_half_dp_is_followed_within_a_jump(dp_kpa):
    plan, ramps = _points(LOW_DP_RAMP, dp_kpa, "observer_fp")
    assert ramps[0]["ramp_max_error_rad"] <= bound(plan, ramps[0]), ramps[0]


@pytest.mark.parametrize("mode", V2_MODES)
def test_both_legs_of_a_reversing_ramp_are_followed_within_a_jump(mode):
    plan, ramps = _points(REVERSING_RAMP, P_MAX, mode, seed=1)
    assert len(ramps) == 2 and ramps[0]["rate_rad_s"] < 0.0 < ramps[1]["rate_rad_s"]
    for ramp in ramps:
        assert ramp["ramp_max_error_rad"] <= bound(plan, ramp), ramp
