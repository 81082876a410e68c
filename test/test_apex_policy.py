"""``fine.apex_policy`` (task h33p, docs §81, off by default): the doublet's apex placed from the learned level's
law, truncated from below by this stop's unmoved apexes, instead of a staircase.

The stage alone (no plant) for the law and the choice; one nominal-box run in closed loop."""
import sys
from pathlib import Path

import numpy as np
import pytest

from fuel_valve_control.core.params import CONTROLLER_SPEC
from test_fine_positioning import _stage

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT / "benchmarks") not in sys.path:
    sys.path.insert(0, str(ROOT / "benchmarks"))


def _policy_stage(**changes):
    fine, model = _stage(**{"fine.apex_policy": True, **changes})
    return fine, model


def _twists(fine, d, pressure_kpa, thl=0.5):
    phi_e, phi_b, band = fine._twists(thl, pressure_kpa, d)
    return phi_e, phi_b


@pytest.mark.parametrize("direction", [1, -1])
def test_the_law_is_truncated_by_an_unmoved_apex_and_reset_by_a_move(direction):
    """The level's law: a normal about the learned level; after an unmoved doublet's apex (``_apex_floor``) no
    weight at or below it; a floor beyond the law's +3 σ leaves the normal's far tail above the floor (not a
    point mass); a move (``_after_move`` with the valve moved) or a hand-back clears the floor."""
    fine, model = _policy_stage()
    d, sigma = direction, 3e-4
    p = model.pressure_max_kpa
    _, phi_b = _twists(fine, d, p)
    lv, w = fine._apex_law(d, phi_b, sigma)
    assert w.sum() == pytest.approx(1.0) and d * ((lv * w).sum() - phi_b) == pytest.approx(0.0, abs=1e-9)
    fine._apex_floor = (d, phi_b - d * 0.5 * sigma)
    lv2, w2 = fine._apex_law(d, phi_b, sigma)
    assert w2[d * (lv2 - fine._apex_floor[1]) <= 0.0].sum() == 0.0
    assert d * ((lv2 * w2).sum() - phi_b) > 0.3 * sigma          # the posterior mean rose above the learned level
    fine._apex_floor = (-d, phi_b - d * 0.5 * sigma)             # the other direction's floor does not apply
    assert np.allclose(fine._apex_law(d, phi_b, sigma)[1], w)
    fine._apex_floor = (d, phi_b + d * 4.0 * sigma)              # beyond the law: its far tail
    lv3, w3 = fine._apex_law(d, phi_b, sigma)
    assert np.all(d * (lv3 - fine._apex_floor[1]) > 0.0) and w3.max() < 0.5
    fine._hand_back()
    assert fine._apex_floor is None


@pytest.mark.parametrize("direction", [1, -1])
def test_the_choice_keeps_the_preload_safe_climbs_past_an_unmoved_apex_and_skips_a_hopeless_error(direction):
    """The choice on a synthetic law (main's kick only): the first preload (apex less the kick's rise) lies about
    fine.doublet_sigmas scatters below the level (no more likely to break the valve loose while parked than main's
    staircase start); after an unmoved apex the next apex lies above it and its preload not beyond it (the law
    holds no level below the apex that held); an error far below the smallest move the law allows gets no try
    (with fine.apex_min_chance 0.02: each would more likely worsen it or never move the valve)."""
    fine, model = _policy_stage()
    d, sigma = direction, 3e-4
    p = model.pressure_max_kpa
    phi_e, phi_b = _twists(fine, d, p)
    first = fine._choose_apex(d * 0.9e-3, d, phi_e, phi_b, sigma, p, 0.0, 0.5)
    assert first is not None
    assert d * (phi_b - (first - d * fine._apex_rise)) >= 1.9 * sigma
    fine._apex_floor = (d, first)
    nxt = fine._choose_apex(d * 0.9e-3, d, phi_e, phi_b, sigma, p, 0.0, 0.5)
    assert nxt is not None and d * (nxt - first) > 0.0
    assert d * ((nxt - d * fine._apex_rise) - first) <= 0.1 * sigma
    # an error of 1e-4 rad: no try lands it with 2 % chance (fine.apex_min_chance 0, the measured setting, still
    # lets apexes that do not move the valve climb: their value is the next try's, docs §81)
    fine, _ = _policy_stage(**{"fine.apex_min_chance": 0.02})
    assert fine._choose_apex(d * 1e-4, d, phi_e, phi_b, sigma, p, 0.0, 0.5) is None
    assert fine._choose_apex(d * 9e-4, d, phi_e, phi_b, sigma, p, 0.0, 0.5) is not None


def test_off_by_default():
    assert CONTROLLER_SPEC.defaults()["fine.apex_policy"] is False
    fine, _ = _stage()
    assert fine.cfg.apex_policy is False and fine._moves is None


def test_a_nominal_plateau_main_leaves_off_ends_within_tolerance():
    """Nominal box seed 1015 plateau 3 (0.3-0.8 s plateaus, max Δp, scatter + ripple): main's staircase ends
    8.98e-4 rad off; with the policy and kicks up to 16 A the plateau ends within the issue's max, 8e-4 rad
    (measured 6.63e-4 on the keyed move model main ships, h33r §80.9; 1.08e-4 on h33m's exact per-angle tables,
    which the branch measured §81 with)."""
    import robustness as rb
    case = rb.sample_case(1015, "nominal")
    res = rb.run_case((case, "observer_fp", {"fine.apex_policy": True, "fine.apex_kick_max_a": 16.0}))
    assert res["plateaus"][3]["final_error_rad"] < 8e-4
    assert not res["hunts"] and not res["fault"]
