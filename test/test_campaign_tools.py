"""Tools of the robustness campaign (issue 14): plateau-sequence demand, analog demand noise,
per-plateau metrics (final error, hunting) and the campaign's seeded sampling."""
import math

import numpy as np
import pytest

from fuel_valve_control.common.paramspec import ConfigError
from fuel_valve_control.tools import metrics as M
from fuel_valve_control.tools.profiles import ProfileError, make_profile
from fuel_valve_control.tools.scenarios import parse_scenario

COUNT = M.RESOLVER_COUNT_RAD
PLATEAUS = {"type": "plateaus", "seed": 4, "count": 40, "initial": 50, "start_s": 0.3, "min_step_pct": 0.1,
            "max_step_pct": 5.0, "hold_s": [0.3, 0.8], "final_hold_s": 2.0, "low": 45, "high": 55}


def _corners(profile, dt=1e-3):
    t = np.arange(0.0, profile.duration_s, dt)
    v = np.array([profile.value(x) for x in t])
    change = np.flatnonzero(np.diff(v) != 0.0) + 1
    return t, v, change


def test_plateau_profile_steps_are_in_range_and_seeded():
    p = make_profile(PLATEAUS)
    t, v, change = _corners(p)
    steps = np.abs(v[change] - v[change - 1])
    assert len(change) == PLATEAUS["count"]
    assert steps.min() >= 0.1 - 1e-9 and steps.max() <= 5.0 + 1e-9
    assert v.min() >= 45 and v.max() <= 55                        # reflected at the bounds
    holds = np.diff(t[change])
    assert holds.min() >= 0.3 - 2e-3 and holds.max() <= 0.8 + 2e-3
    assert t[-1] - t[change[-1]] == pytest.approx(2.0, abs=2e-3)
    assert v[0] == 50.0 and t[change[0]] == pytest.approx(0.3, abs=1e-3)
    # log-uniform sizes: both small and large steps occur
    assert (steps < 0.5).any() and (steps > 1.0).any()
    assert np.array_equal(v, _corners(make_profile(PLATEAUS))[1])
    assert not np.array_equal(v, _corners(make_profile({**PLATEAUS, "seed": 5}))[1])


def test_plateau_profile_errors_are_clear():
    with pytest.raises(ProfileError, match="hold_s"):
        make_profile({k: v for k, v in PLATEAUS.items() if k != "hold_s"})
    with pytest.raises(ProfileError, match="min_step_pct"):
        make_profile({**PLATEAUS, "min_step_pct": 6.0})


def test_demand_noise_and_glitches_leave_the_nominal_demand_alone():
    spec = {"type": "constant", "percent": 30.0, "noise_rms_pct": 0.1, "noise_seed": 3,
            "glitches": [[0.5, 0.6]]}
    p = make_profile(spec)
    t = np.arange(0.0, 5.0, 1e-3)
    v = np.array([p.value(x) for x in t])
    assert all(p.nominal(x) == 30.0 for x in t)
    noise = np.delete(v - 30.0, 500)
    assert noise.std() == pytest.approx(0.1, rel=0.05)
    assert v[500] - 30.0 == pytest.approx(0.6, abs=0.5)            # the glitch rides on the noise
    # sampled and held: within one sample the value does not change; reproducible in any order
    assert p.value(1.2341) == p.value(1.2349)
    q = make_profile(spec)
    assert [q.value(x) for x in t[::-1]][::-1] == list(v)
    # without noise keys a profile is unchanged (value == nominal)
    plain = make_profile({"type": "constant", "percent": 30.0})
    assert plain.value(1.0) == plain.nominal(1.0) == 30.0


def test_scenario_yaml_accepts_plateaus_with_noise():
    sc = parse_scenario({"name": "x", "duration_s": 5.0, "demand": {**PLATEAUS, "noise_rms_pct": 0.05}})
    assert sc.demand.value(1.0) != sc.demand.nominal(1.0)
    with pytest.raises(ConfigError, match="demand"):
        parse_scenario({"name": "x", "duration_s": 5.0, "demand": {**PLATEAUS, "count": 0}})


def test_reversals_count_only_moves_beyond_the_hysteresis():
    assert M.reversals(np.array([0, 0, 3, 0, 3, 3]) * COUNT) == 2
    assert M.reversals(np.array([0, 0.5, 0, 0.5, 0]) * COUNT) == 0          # within one count
    assert M.reversals(np.array([0, 5, 10, 15]) * COUNT) == 0               # one way only
    t = np.linspace(0.0, 2.0, 2001)
    assert M.reversals(10 * COUNT * np.sin(2 * math.pi * 2.0 * t)) == 8       # 8 extrema, each turned


def _plateau_trace(late_motion):
    t = np.arange(0.0, 2.0, 1e-3)
    demand = np.where(t < 0.5, 0.3, 0.31)
    pos = np.where(t < 0.6, 0.3, 0.31 + 4e-4)
    pos = pos + np.where(t >= 1.0, late_motion(t), 0.0)
    return M.Trace(t, demand, pos, np.zeros_like(t), np.ones_like(t))


def test_plateau_results_final_error_and_hunting():
    (quiet,) = M.plateau_results(_plateau_trace(lambda t: 0.0 * t))
    assert quiet["final_error_rad"] == pytest.approx(4e-4)
    assert quiet["overshoot_rad"] == pytest.approx(4e-4)
    assert not quiet["hunts"] and quiet["hunting_reversals"] == 0
    (hunting,) = M.plateau_results(_plateau_trace(lambda t: 5 * COUNT * np.sin(2 * math.pi * 1.5 * t)))
    assert hunting["hunts"] and hunting["hunting_amplitude_rad"] == pytest.approx(5 * COUNT, rel=0.02)
    (small,) = M.plateau_results(_plateau_trace(lambda t: 1.5 * COUNT * np.sin(2 * math.pi * 1.5 * t)))
    assert not small["hunts"]                                                # within 2 counts
    (one_move,) = M.plateau_results(_plateau_trace(lambda t: np.where(t > 1.5, -4e-4, 0.0)))
    assert not one_move["hunts"] and one_move["final_error_rad"] < 1e-12     # a late correction


def test_campaign_cases_are_seeded_and_cover_the_box(robustness_bench):
    rb = robustness_bench
    cases = [rb.sample_case(1000 + i) for i in range(200)]
    assert cases[0] == rb.sample_case(1000)
    assert {c["friction_model"] for c in cases} == {"stick_slip", "stribeck", "lugre"}
    assert {c["dp_kind"] for c in cases} == {"exact", "measured", "wrong", "missing"}
    f = [c["friction_scale"] for c in cases]
    assert 0.5 <= min(f) < 0.6 and 2.6 < max(f) <= 3.0
    k = [c["stiffness_scale"] for c in cases]
    assert 0.3 <= min(k) < 0.35 and max(k) <= 1.0
    assert all(0.8 <= c["valve_inertia_scale"] <= 1.2 for c in cases)
    assert all(18.0 <= c["supply_v"] <= 32.0 for c in cases)
    # every case builds valid plant/controller parameter sets (the plant's own checks pass)
    from fuel_valve_control.tools import sim
    for c in cases[:20]:
        sc = rb.case_scenario(c)
        sim.build(sc, rb.plant_overrides(c), rb.controller_knowledge(c))
        # the steady load stays within the continuous torque at the most open plateau
        assert c["load_nm"] + 8.0 + 4.0 * 1.0472 * 0.95 + 2.0 <= rb.CONTINUOUS_TORQUE_NM + 1e-9
