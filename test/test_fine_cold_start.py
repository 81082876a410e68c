"""The fine stage's cold start (issue 14, task h21c): a run's first steps too small for the main
law's hold to move the valve were left 1.1-2.4e-3 rad off (nominal box: 10 + 4 plateaus > 8e-4 rad
on seeds 1000-1039 / 2000-2039), the stage waiting for a breakaway to judge the valve by.  With
``fine.cold_start`` it judges the valve at rest (its twist inside the nominal static band) and by
its own first doublets, and hands the plateau back when the first breakaway they find does not fit
the nominal breakaway twist.  On by default since stop 34 with the climb (``fine.cold_climb``, docs §116-§117); the
tests here of the cold start *without* the climb set ``fine.cold_climb`` false (``COLD_ONLY``)."""
from __future__ import annotations

import numpy as np
import pytest

from first_step import first_step
from fuel_valve_control.common.contract import PRESSURE_MAX_KPA

COLD_ONLY = {"fine.cold_start": True, "fine.cold_climb": False}


@pytest.mark.parametrize("direction", [1, -1])
def test_a_cold_stage_ends_a_first_step_too_small_for_the_main_law(direction):
    step = direction * 1.5e-3
    # without it (the default before stop 34): the main law's hold never moves the valve for a step inside its
    # deadband, and the stage waits for a breakaway that never comes
    plateaus, _ = first_step(step, **{"fine.cold_start": False})
    assert plateaus[-1]["final_error_rad"] > 1.0e-3
    plateaus, log = first_step(step, **{"fine.cold_start": True})
    assert plateaus[-1]["final_error_rad"] <= 5e-4, plateaus[-1]
    assert not plateaus[-1]["hunts"]
    # ... by its own doublets: the valve never went a whole stick-slip jump (4.6e-3 rad) past the
    # target, as a quasi-static breakaway (the main law's) from rest would have taken it
    t, target, valve = log[:, 0], log[:, 1], log[:, 2]
    after = t >= 0.3
    assert np.max(direction * (valve[after] - target[after])) < 1.5e-3


@pytest.mark.parametrize("direction", [1, -1])
def test_a_cold_stage_on_a_low_friction_valve_jumps_across_the_target_without_hunting(direction):
    """Why ``fine.cold_start`` was off by default until the climb (stop 34): on a valve with friction x0.6 the cold staircase's
    first preload breaks it loose, a whole jump across the target (before any breakaway the level
    is known only to lie above the twist at rest; what the drive knows at rest does not tell a x0.6
    valve from a nominal one).  The stage then hands the plateau back (any breakaway in a cold
    preload: full box seed 1032 hunted when a second preload broke it back), and it does not hunt."""
    plateaus, log = first_step(direction * 1.5e-3, friction_scale=0.6, **COLD_ONLY)
    t, target, valve = log[:, 0], log[:, 1], log[:, 2]
    after = t >= 0.3
    assert np.max(direction * (valve[after] - target[after])) > 2e-3     # the cold preload's jump
    assert not plateaus[-1]["hunts"]


def _gated_stage(gate: bool):
    from fuel_valve_control.core.params import CONTROLLER_SPEC
    from fuel_valve_control.core.position_controller import PositionController
    pc = PositionController(CONTROLLER_SPEC.defaults().replace(
        {"mode": "observer_fp", **COLD_ONLY, "fine.cold_band_gate": gate}))
    return pc.law.fine, pc.model


@pytest.mark.parametrize("gate", [False, True])
def test_the_band_gate_lets_a_cold_stage_engage_only_on_a_static_band_the_hold_measured_near_the_told_one(gate):
    """``fine.cold_band_gate`` (h30c, docs §67): before any breakaway the stage engages cold only if the
    main law's hold has met both slip edges of a static band within ``fine.breakaway_fit`` x T_s of the
    told static friction.  A band of 0.6 or 2.77 x (the low- and high-friction valves the cold start
    jumped on / hunted on, §29.3) or none at all (every cold first plateau traced on the nominal box,
    quick 1000 and quick 3000: the hold had met no slip edge yet) keeps the stage waiting, as on main."""
    fine, m = _gated_stage(gate)
    p = PRESSURE_MAX_KPA
    ts = m.friction(p).valve_static_nm
    fine._steady = 10 ** 6                      # the demand held long enough; no breakaway seen yet
    fine._plateau_valve = 0.3                   # the valve still where this plateau's demand found it
    err = 1.5e-3                                # inside half the nominal jump
    verdicts = {}
    for band in (None, 0.6 * ts, ts, 1.1 * ts, 2.77 * ts):
        fine.hold_static_nm = band
        verdicts[band] = fine._cold_ready(err, 0.3, p)
    if not gate:
        assert all(verdicts.values())           # ungated: the cold start ignores the band
    else:
        assert verdicts == {None: False, 0.6 * ts: False, ts: True, 1.1 * ts: True, 2.77 * ts: False}


def test_the_band_gated_cold_stage_does_not_jump_a_low_friction_valve_across_its_target():
    """Friction x0.6, the same first step the ungated cold start jumps > 2e-3 rad across
    (:func:`test_a_cold_stage_on_a_low_friction_valve_jumps_across_the_target_without_hunting`): with the
    band gate the hold has measured no band before the step, so the stage waits as on main (the step is
    left to the main law: 1.5e-3 rad off, never past the target)."""
    plateaus, log = first_step(1.5e-3, friction_scale=0.6, **COLD_ONLY, **{"fine.cold_band_gate": True})
    t, target, valve = log[:, 0], log[:, 1], log[:, 2]
    after = t >= 0.3
    assert np.max(valve[after] - target[after]) < 5e-4
    assert not plateaus[-1]["hunts"]
