"""Issue 14, deliverable 3: no limit cycle under a steady external load up to the actuator's
continuous torque -- a load the valve cannot hold by friction is held by integral action (the
learned steady load), not relaxed away."""
import numpy as np
import pytest

from fuel_valve_control.common.contract import PRESSURE_MAX_KPA, RESOLVER_COUNT_RAD, STROKE_RAD
from fuel_valve_control.core.params import CONTROLLER_SPEC
from fuel_valve_control.tools import sim
from fuel_valve_control.tools.scenarios import parse_scenario
from fuel_valve_plant.physics.params import PLANT_SPEC
from prefetch import ModuleRuns, jobs, selected_items

_P, _C = PLANT_SPEC.defaults(), CONTROLLER_SPEC.defaults()
CONTINUOUS_TORQUE_NM = _C["limits.continuous_current_a"] * _C["model.torque_constant_nm_per_a"] * _C["model.gear_ratio"]


def _simulate(pct: float, fraction: float):
    """5 s at max Δp: a 2 % step up to ``pct`` % under a steady load of ``fraction`` x
    :func:`_room` (here or in a look-ahead worker, test/prefetch.py)."""
    load = fraction * _room(pct)
    doc = {"name": "steady_load", "duration_s": 5.0, "initial_percent": pct - 2.0,
           "pressure_differential_kpa": PRESSURE_MAX_KPA,
           "demand": {"type": "step", "initial": pct - 2.0, "final": pct, "at_s": 0.3}}
    sc = parse_scenario(doc)
    p, c = sim.build(sc, {"load_torque_nm": load}, None, 0)
    return sim.simulate(sc, p, c)


#: the module's look-ahead runs (test/prefetch.py); none outside the module fixture below
_AHEAD = ModuleRuns(_simulate)


@pytest.fixture(scope="module", autouse=True)
def _look_ahead(request):
    """The module's runs on both cores; each test still takes and asserts its own run."""
    keys = [(item.callspec.params["pct"], item.callspec.params["fraction"]) for item in selected_items(request)
            if item.originalname == "test_steady_load_is_held_without_a_limit_cycle"]
    with _AHEAD.planned(keys, jobs(request.config)):
        yield


def _room(pct: float) -> float:
    """Steady load (valve side, toward closed) that with spring and flow torque needs the whole
    continuous torque at ``pct`` % open."""
    spring = _P["spring.preload_nm"] + _P["spring.rate_nm_per_rad"] * STROKE_RAD * pct / 100.0
    return CONTINUOUS_TORQUE_NM - spring - _P["flow.torque_max_nm"]


@pytest.mark.parametrize("pct,fraction", [
    (30.0, 0.95), (60.0, 0.95),
    pytest.param(60.0, 0.5, marks=pytest.mark.xfail(strict=True, reason=(
        "ends 6.3e-3 rad short (limit 3e-3), no hunting.  Traced (h16w): the valve is left stuck 20 mrad "
        "short at the move's end under the 6.2 N*m unknown load and slides 19 mrad to the target once the "
        "drive has wound up; JumpLearner reads that catch-up as a 4.2x opening jump (opening deadband "
        "10.6 mrad), so after the relax lets the load slip the valve 6.3 mrad back (load then learned) the "
        "integrator does not pull it back.  Not learning such catch-ups (a slide from beyond 2 bands that "
        "comes to rest inside the band without crossing) cures it, but on the full campaign 1070, 1097, "
        "1157 and 1188 then hunted: their catch-up readings are what sized their deadbands.  Tried (h17w): sizing "
        "the way back after a relax slip away from the target by that slip's own jump (a quasi-static "
        "breakaway: 1.05x here) pulls it back to 0.5 mrad and the test passes, but on the full campaign 1083 "
        "and 1096 then hunted (a slip's own jump read smaller than the valve's real one: 2.94x -> 0.86x); "
        "not kept"))),
    (40.0, -0.2)])
def test_steady_load_is_held_without_a_limit_cycle(pct, fraction):
    res = _AHEAD.result(pct, fraction)
    t, pos = res.column("t"), res.column("position_rad")
    settled = t >= 2.5
    assert res.column("enable").min() == 1.0                      # no fault, the drive held it
    assert 0.5 * np.ptp(pos[settled]) <= 2 * RESOLVER_COUNT_RAD   # no hunting beyond two counts
    assert abs(pos[-1] - pct / 100.0 * STROKE_RAD) <= 3e-3        # within the deadband, not slipped away
