"""``fine.apex_policy`` (task h33p, docs §81; on by default since stop 25 with C1, docs §91): the doublet's apex placed from the learned level's
law, truncated from below by this stop's unmoved apexes, instead of a staircase.

The stage alone (no plant) for the law and the choice; one nominal-box run in closed loop."""
import math
import sys
from pathlib import Path

import numpy as np
import pytest

from fuel_valve_control.core.params import CONTROLLER_SPEC
from test_fine_positioning import C3_FINE, MAIN_DOUBLET, _stage

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT / "benchmarks") not in sys.path:
    sys.path.insert(0, str(ROOT / "benchmarks"))


def _policy_stage(**changes):
    """The stage with §81's policy alone (main's 4 A kick, main's retreat: C1's other options off, as these
    stage-alone tests were written; C1 is the default since stop 25, docs §91) under ``changes``."""
    fine, model = _stage(**{**MAIN_DOUBLET, "fine.apex_policy": True, **changes})
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


#: C1 (docs §88), the default since stop 25 (task h36f, docs §91): the apex policy with kicks to 16 A, the deep
#: retreat (two periods at -cap), the observe servo's integral held after a move, the move model's excess coordinate
C1 = {"fine.apex_policy": True, "fine.apex_kick_max_a": 16.0, "fine.apex_retreat_periods": 2, "fine.retreat_cap": True,
      "fine.observe_hold_moved": True, "fine.apex_excess_nominal": True}


def test_c1_is_the_default_and_off_is_main():
    """C1's six options are the defaults (task h36f, docs §91), and C3's seven on top of them (stop 28, docs §108);
    with the policy off the stage makes no move model."""
    ps = CONTROLLER_SPEC.defaults()
    assert {k: ps[k] for k in C1} == C1
    assert {k: ps[k] for k in C3_FINE} == C3_FINE
    fine, _ = _stage()
    assert fine.cfg.apex_policy is True and fine._moves is not None
    fine, _ = _stage(**{"fine.apex_policy": False})
    assert fine.cfg.apex_policy is False and fine._moves is None


def test_a_nominal_plateau_main_leaves_off_ends_within_tolerance():
    """Nominal box seed 1015 plateau 3 (0.3-0.8 s plateaus, max Δp, scatter + ripple): main's staircase ends
    8.98e-4 rad off; with the policy and kicks up to 16 A the plateau ends within the issue's max, 8e-4 rad
    (measured 6.63e-4 on the keyed move model main ships, h33r §80.9; 1.08e-4 on h33m's exact per-angle tables,
    which the branch measured §81 with)."""
    import robustness as rb
    case = rb.sample_case(1015, "nominal")
    # §81's build as measured: the policy with kicks to 16 A on main's retreat (C1's other options off)
    res = rb.run_case((case, "observer_fp", {**MAIN_DOUBLET, "fine.apex_policy": True, "fine.apex_kick_max_a": 16.0}))
    assert res["plateaus"][3]["final_error_rad"] < 8e-4
    assert not res["hunts"] and not res["fault"]


# --------------------------------------------------------------------------------------------- task h34m, docs §85
@pytest.mark.parametrize("direction", [1, -1])
def test_the_model_excess_is_taken_from_the_model_coulomb_equilibrium_not_the_learned_swing_centre(direction):
    """``fine.apex_excess_nominal`` (task h34m, docs §85): the move model is built in the stage model's coordinates
    -- excess = the level above (load + T_c)/K -- so the policy's expected move for a given level law must not
    change when the learned swing centre (``learn.equilibrium``, the stage's own moves' φ_final - move / 2, 0.14-0.21e-3
    rad toward the try on the nominal box) moves.  Without the option (main's reading) a learned offset of 0.2e-3 rad
    shrinks the expected move (the 1.3-1.4 x the closed loop measured); with it the move is unchanged."""
    d, sigma = direction, 3e-4
    means = {}
    for opt in (False, True):
        for off in (0.0, 2e-4):
            fine, model = _policy_stage(**{"fine.apex_excess_nominal": opt})
            p = model.pressure_max_kpa
            band = fine.learn.band(1.0)
            fine.learn.equilibrium[d][band] = d * off
            phi_e, phi_b = _twists(fine, d, p)
            assert fine._choose_apex(d * 1.2e-3, d, phi_e, phi_b, sigma, p, 0.0, 0.5) is not None
            means[opt, off] = (fine._apex_plan[0] - phi_b, fine._apex_try[1])
    # main: the learned offset changes the plan (the model reads a smaller excess: smaller moves, another apex)
    assert means[False, 0.0] != pytest.approx(means[False, 2e-4], rel=1e-6, abs=1e-9)
    assert means[True, 0.0] == pytest.approx(means[True, 2e-4], rel=1e-9, abs=1e-12)


@pytest.mark.parametrize("direction", [1, -1])
def test_the_floor_climbs_from_the_planned_apex(direction):
    """``fine.apex_floor_plan``: after an unmoved try the law is truncated at the higher of the measured apex (the
    once-a-period reading, below the kick's peak) and the apex the try planned; off, at the reading."""
    d, sigma = direction, 3e-4
    for opt in (False, True):
        fine, model = _policy_stage(**{"fine.apex_floor_plan": opt})
        p = model.pressure_max_kpa
        phi_e, phi_b = _twists(fine, d, p)
        apex = fine._choose_apex(d * 0.9e-3, d, phi_e, phi_b, sigma, p, 0.0, 0.5)
        fine._apex_floor = (d, apex - d * 1e-4)                   # the reading 1e-4 below the plan
        lv, w = fine._apex_law(d, phi_b, sigma)
        low = lv[w > 0].min() if d > 0 else lv[w > 0].max()
        floor = apex if opt else apex - d * 1e-4
        assert d * (low - floor) > 0.0
        assert d * (low - floor) < 0.2 * sigma                     # the next law point above it
    fine._apex_floor = None
    assert fine._floor(d) is None


@pytest.mark.parametrize("direction", [1, -1])
def test_the_continuous_kick_is_sized_to_reach_the_apex_from_the_floor(direction):
    """``fine.apex_kick_continuous``: after an unmoved try the preload stays at the floor (less 5 % of the smallest
    kick's rise) and each candidate apex gets the kick whose rise reaches it: the model's rise *at that kick*
    (a table built for it) lies within 3e-5 rad (the linear interpolation across the kick set, ~2 % of a 16 A kick's
    rise) of the apex's height above the preload; kicks within fine.kick_current_a .. fine.apex_kick_max_a, the hold
    plus the kick within the current cap; a candidate beyond the largest kick's rise is never sized."""
    from fuel_valve_control.core.fine_positioning import APEX_PRE_MARGIN
    d, sigma = direction, 3e-4
    fine, model = _policy_stage(**{"fine.apex_kick_continuous": True, "fine.apex_kick_max_a": 16.0})
    p = model.pressure_max_kpa
    phi_e, phi_b = _twists(fine, d, p)
    fine._moves = __import__("fuel_valve_control.core.fine_positioning", fromlist=["_pulse_moves"])._pulse_moves(fine)
    pm = fine._moves
    floor = phi_b - d * 1.0 * sigma
    kicks = fine._apex_kicks()
    r0 = pm.rise(d, p, kick_current_a=kicks[0], valve_angle_rad=0.5)
    rmax = pm.rise(d, p, kick_current_a=kicks[-1], valve_angle_rad=0.5)
    pre = floor - d * APEX_PRE_MARGIN * r0
    cand = pre + d * np.array([0.5 * r0, 1.2 * r0, 0.5 * (r0 + rmax), 0.9 * rmax, 1.1 * rmax])
    lv, _ = fine._apex_law(d, phi_b, sigma)
    od = d * (cand[:, None] - lv[None, :])
    ex = np.maximum(d * (lv - phi_e), 0.0)[None, :] + 0 * od
    tabs = [(k, pm.rise(d, p, kick_current_a=k, valve_angle_rad=0.5),
             np.asarray(pm.move(d, p, ex, od, kick_current_a=k, aim_rad=1e-3, valve_angle_rad=0.5))) for k in kicks]
    kick, rise, mv = fine._continuous_kick(d, floor, cand, tabs)
    assert np.isnan(kick[0]) and np.isnan(kick[-1])               # below the smallest kick's rise / beyond the largest
    for j in (1, 2, 3):
        assert kicks[0] <= kick[j] <= kicks[-1]
        assert rise[j] == pytest.approx(d * (cand[j] - pre))
        exact = pm.rise(d, p, kick_current_a=float(kick[j]), valve_angle_rad=0.5)
        assert abs(exact - rise[j]) < 3e-5
        hold = (model.coupling_stiffness_nm_per_rad * pre / model.gear_ratio + d * model.motor_coulomb_nm) \
            / model.torque_constant_nm_per_a
        assert abs(hold + d * kick[j]) <= fine.cfg.peak_current_a + 1e-9
    # chosen through the policy: the preload is the floor's, the kick the continuous one when it wins
    fine._apex_floor = (d, floor)
    apex = fine._choose_apex(d * 1.5e-3, d, phi_e, phi_b, sigma, p, 0.0, 0.5)
    assert apex is not None and d * (apex - floor) > 0.0
    if fine._apex_kick not in kicks:
        assert (apex - d * fine._apex_rise) == pytest.approx(pre, abs=1e-12)
# main = the policy off explicitly (C1, with the policy, is the default since stop 25: docs §91)
@pytest.mark.parametrize("sets, holds", [({"fine.apex_policy": False}, False),
                                         ({"fine.apex_policy": False, "fine.hold_reversed": True}, True),
                                         ({"fine.apex_policy": True}, True)])
def test_a_plateau_the_valve_reversed_on_is_held_not_handed_back(sets, holds):
    """(``fine.hold_reversed``, in force also with ``fine.apex_policy``; task h34h, docs §86) Where the stage would hand
    the plateau back (two preload breakaways, a move away from the target, an unfit twist) after the valve has
    reversed once on the plateau's late window, the main law's move back could be the hunting metric's second
    reversal: the stage holds the gear output where it is and makes no more pulses.  A free move (no reversal yet,
    the last move toward the target) is still handed back; main (both off) always hands back."""
    from fuel_valve_control.common.hunting import ReversalCounter
    fine, model = _stage(**sets)
    p = model.pressure_max_kpa
    fine._reversals = ReversalCounter(0.5)
    fine._reversals.count, fine._reversals.direction = 1, -1        # reversed once, now moving down (closing)
    held = fine._hold_not_hand_back(0.52, -3e-3, p)                  # the valve 3e-3 above its target
    assert held is holds
    if holds:
        assert fine.phase == "hold" and fine._hold_ref == 0.52 and fine._spent()
    fine, _ = _stage(**sets)
    fine._reversals = ReversalCounter(0.5)
    fine._reversals.direction = -1                                  # no reversal yet, moving toward the target
    assert fine._hold_not_hand_back(0.52, -3e-3, p) is False


def test_an_error_beyond_the_stages_reach_is_handed_back_not_held():
    """An error beyond ``fine.max_move_rad`` (0.02 rad) is the main law's: the stage hands it back even after a
    reversal (a real-time run whose late period stretched a kick threw the valve 2.1 % of stroke past the demand, and
    the stage held it there for the rest of the plateau; docs §104).  The same error within a larger
    ``fine.max_move_rad`` is held as before."""
    from fuel_valve_control.common.hunting import ReversalCounter
    for max_move, holds in ((None, False), (0.05, True)):
        fine, model = _stage(**({} if max_move is None else {"fine.max_move_rad": max_move}))
        fine._reversals = ReversalCounter(0.5)
        fine._reversals.count, fine._reversals.direction = 1, -1    # reversed once, now moving down (closing)
        assert fine._hold_not_hand_back(0.52, -0.0213, model.pressure_max_kpa) is holds
        assert (fine.phase == "hold") is holds


def test_the_apex_policy_hunter_is_held_not_handed_back():
    """Nominal box seed 2035 plateau 10 (a 1.56e-2 rad step, max Δp, static scatter 7.2 %) with ``fine.apex_policy``
    (kicks to 16 A), replayed up to the next plateau's step: a doublet's park broke the valve loose 5.6e-3 rad across
    the target (the learned level 1.4e-3 above the drawn one after 18 unmoved servo-blended pulses raised it), the
    pulse back broke loose in its own park (1.6e-3 back, the first reversal), and handed back 3.3e-3 over, the main
    law's hold slid the valve 1.9e-2 the other way and its ramp brought it back -- the metric's second reversal (it
    hunted, 1.0e-2 rad, ending 4.8e-3 off; main 1.3e-4).  Held instead: no hunting, the plateau ends where the stage's
    last move left the valve (measured 3.34e-3), not further."""
    import robustness as rb
    from fuel_valve_control.tools import metrics as M
    from fuel_valve_control.tools import sim
    case = rb.sample_case(2035, "nominal")
    sc = rb.case_scenario(case)
    sc.duration_s = 6.62                                             # plateau 10 ends at 6.591 s
    # the traced build: §81's policy with kicks to 16 A on main's retreat (C1's other options off; C1 is the default)
    p, c = sim.build(sc, rb.plant_overrides(case), {**rb.controller_knowledge(case), **MAIN_DOUBLET,
                                                    "fine.apex_policy": True, "fine.apex_kick_max_a": 16.0},
                     None, "observer_fp")
    res = sim.simulate(sc, p, c)
    log = res.log
    plats = M.plateau_results(M.Trace(log[:, 0], log[:, 1], log[:, 2], np.hypot(log[:, 7], log[:, 8]), log[:, 9],
                                      res.stroke_rad))
    pl = plats[10]
    assert abs(pl["to_rad"] - pl["from_rad"]) == pytest.approx(1.558e-2, abs=1e-4)   # the traced plateau
    assert not pl["hunts"] and pl["hunting_reversals"] <= 1
    assert pl["final_error_rad"] < 3.5e-3
    assert not any(q["hunts"] for q in plats[:11])


def test_the_kick_set_is_finite_without_a_kick():
    """``fine.kick_current_a`` 0 (a boundary value the schema accepts): the policy's kick set is that one kick -- its
    growth by ``fine.apex_kick_ratio`` (0 x r stays 0) once never ended and ate the memory (test_fuzz's boundary case,
    OOM-killed when C1 made the policy the default, stop 25)."""
    fine, _ = _stage(**{"fine.kick_current_a": 0.0})
    assert fine._apex_kicks() == [0.0]
    fine, _ = _stage()
    kicks = fine._apex_kicks()
    assert kicks[0] == fine.cfg.kick_current_a and kicks[-1] <= fine.cfg.apex_kick_max_a + 1e-9 and len(kicks) == 3


def test_the_kick_set_is_bounded_at_the_finest_ratio():
    """(stop 26) ``fine.apex_kick_ratio`` at its schema minimum with the widest kick range would be ~40 kicks, each a set
    of move tables and a column of every try: the set holds at most APEX_MAX_KICKS, over the same span, geometric;
    the default ratio's set is untouched."""
    from fuel_valve_control.core.fine_positioning import APEX_MAX_KICKS
    fine, _ = _stage(**{"fine.apex_kick_ratio": 1.05, "fine.apex_kick_max_a": 30.0})
    kicks = fine._apex_kicks()
    assert len(kicks) == APEX_MAX_KICKS and kicks[0] == fine.cfg.kick_current_a
    unbounded = fine.cfg.kick_current_a * 1.05 ** int(math.log(30.0 / fine.cfg.kick_current_a) / math.log(1.05) + 1e-9)
    assert kicks[-1] == pytest.approx(unbounded, rel=1e-9) and kicks[-1] <= 30.0 + 1e-9
    assert np.allclose(np.diff(np.log(kicks)), math.log(kicks[1] / kicks[0]))
    fine, _ = _stage(**{"fine.apex_kick_ratio": 1.5})          # 4, 6, 9, 13.5 A: within the bound, as the ratio says
    assert fine._apex_kicks() == pytest.approx([4.0, 6.0, 9.0, 13.5])


def _same_choice(fine, args):
    """(outcome of main's choice, outcome of the stage's) on copies of ``fine`` (the move model shared): the return
    value and everything the choice sets on the stage (benchmarks/apex_choice.py's reference, main's code)."""
    from apex_choice import _copy, _outcome, reference_choose_apex
    a, b = _copy(fine), _copy(fine)
    return _outcome(a, reference_choose_apex(a, *args)), _outcome(b, b._choose_apex(*args))


@pytest.mark.parametrize("direction", [1, -1])
def test_the_choice_equals_main_choice_bit_for_bit(direction):
    """(task h37a, docs §94) The choice scored on the elements that change a sum (levels of weight, apexes between
    the level and the preload's reach, all kicks in one pass) chooses what main's full tables choose, to the last
    bit of every number it sets (apex, kick, rise, plan, mean move): random errors (either sign of the crossing
    guard), scatters, floors (none, inside the law, beyond it: the far tail), valve angles (between the angle grid's
    points and on one), the three level laws, fine.apex_worse_given_move, and the continuous kick's path."""
    from apex_choice import draw_try
    rng = np.random.default_rng(37 + direction)
    d = direction
    base = {"fine.apex_kick_max_a": 16.0, "fine.apex_excess_nominal": True}
    stages = [_policy_stage(**base), _policy_stage(**base, **{"fine.apex_level_law": "mixture"}),
              _policy_stage(**base, **{"fine.apex_level_law": "student", "fine.apex_worse_given_move": True}),
              _policy_stage(**base, **{"fine.apex_kick_continuous": True})]
    moves = None
    checked = 0
    for n in range(24):
        fine, model = stages[n % len(stages)]
        if moves is not None:
            fine._moves = moves                    # one move model (its tables built once)
        p = model.pressure_max_kpa
        thl = 0.5 * model.stroke_rad if n % 5 == 0 else float(rng.uniform(0.4, 0.6))
        phi_e, phi_b = _twists(fine, d, p, thl)
        ref, new = _same_choice(fine, draw_try(fine, rng, n, d, p, thl, phi_e, phi_b))
        assert repr(new) == repr(ref), (n, ref, new)
        moves = fine._moves
        checked += ref[0] is not None
    assert checked >= 12                           # most draws chose a try (not only "hold")


def test_the_move_points_equal_the_move_model_at_every_point():
    """(task h37a) :meth:`PulseMoves.move_points` -- several kicks' moves in one pass -- equals :meth:`PulseMoves.move`
    point by point, NaN where it is NaN: apexes above and below the level (the servo-break rule), beyond the tables,
    at a Δp between the grid's points (a four-table blend) and on a grid point of the angle (one table)."""
    fine, model = _policy_stage(**{"fine.apex_kick_max_a": 16.0})
    from fuel_valve_control.core.fine_positioning import _pulse_moves
    pm = _pulse_moves(fine)
    kicks = fine._apex_kicks()
    rng = np.random.default_rng(5)
    d = 1
    for p, thl in ((model.pressure_max_kpa, 0.45), (0.95 * model.pressure_max_kpa, 0.5 * model.stroke_rad),
                   (0.95 * model.pressure_max_kpa, 0.47)):
        n = 150
        which = rng.integers(0, len(kicks), n)
        x = rng.uniform(-1e-4, 2e-3, n)
        od = rng.uniform(-5e-4, 4e-3, n)
        aim = float(rng.uniform(0.0, 2e-3))
        got = pm.move_points(d, p, kicks, which, x, od, aim_rad=aim, valve_angle_rad=thl)
        up = od > 0.0
        got_up = pm.move_points(d, p, kicks, which[up], x[up], od[up], aim_rad=aim, valve_angle_rad=thl)
        want = np.array([pm.move(d, p, x[i], od[i], kick_current_a=kicks[which[i]], aim_rad=aim,
                                 valve_angle_rad=thl) for i in range(n)], dtype=float)
        assert np.array_equal(got, want, equal_nan=True)
        assert np.array_equal(got_up, want[up], equal_nan=True)
        # (task h40m) the excess given per level: point i's is x_levels[level[i]] -- the same bits
        x_levels = np.concatenate([x, [-1e-4, np.nan, 5e-2]])
        rl = np.random.default_rng(len(x_levels) + int(1e4 * aim))      # (its own draws: rng's stay as they were)
        level = np.where(rl.uniform(size=n) < 0.9, np.arange(n), n + rl.integers(0, 3, n))
        got_lv = pm.move_points(d, p, kicks, which[up], x_levels, od[up], aim_rad=aim, valve_angle_rad=thl,
                                level=level[up])
        assert np.array_equal(got_lv, pm.move_points(d, p, kicks, which[up], x_levels[level[up]], od[up],
                                                     aim_rad=aim, valve_angle_rad=thl), equal_nan=True)
        # (points below their level too: the per-kick fallback takes the excess per point)
        assert np.array_equal(pm.move_points(d, p, kicks, which, x_levels, od, aim_rad=aim, valve_angle_rad=thl,
                                             level=level),
                              pm.move_points(d, p, kicks, which, x_levels[level], od, aim_rad=aim,
                                             valve_angle_rad=thl), equal_nan=True)
        assert np.isfinite(want[up]).sum() > 30 and (want == 0.0).sum() > 2 and np.isnan(want).sum() > 2
