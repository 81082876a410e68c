"""Fine positioning (mode ``observer_fp``, issue 14): the learned friction twists (bounded,
reset, visible, saved and loaded) and what the stage does in closed loop."""
import dataclasses
import math
import json

import numpy as np
import pytest

from fuel_valve_control.core.driver import ValveDriver
from fuel_valve_control.core.fine_positioning import FineLearner
from fuel_valve_control.core.params import CONTROLLER_SPEC
from prefetch import Ahead, jobs


def test_learned_twists_are_bounded_and_reset():
    lr = FineLearner(bands=4, limit_rad=0.01)
    lr.set("equilibrium", 1, 3, 0.5)
    lr.set("breakaway", -1, 0, -0.5)
    assert lr.equilibrium[1][3] == 0.01 and lr.breakaway[-1][0] == -0.01
    assert [lr.band(f) for f in (0.0, 0.24, 0.25, 0.99, 1.0, 1.7, -0.2)] == [0, 0, 1, 3, 3, 3, 0]
    lr.set("min_move", 1, 0, -1e-3)                   # a move size is never negative
    lr.set("min_move", -1, 2, 0.5)
    assert lr.min_move[1][0] == 0.0 and lr.min_move[-1][2] == 0.01
    lr.set("scatter", -1, 1, -2e-3)                   # nor is a scatter
    lr.set("scatter", 1, 1, 0.5)
    assert lr.scatter[-1][1] == 0.0 and lr.scatter[1][1] == 0.01
    lr.reset()
    assert lr.equilibrium == {1: [0.0] * 4, -1: [0.0] * 4} and lr.pulses == 0
    assert lr.min_move == lr.scatter == {1: [0.0] * 4, -1: [0.0] * 4}


def test_learned_twists_survive_a_restart(tmp_path):
    a = FineLearner(4, 0.1)
    a.set("equilibrium", 1, 2, 1.5e-3)
    a.set("breakaway", -1, 1, -2e-3)
    a.set("min_move", 1, 3, 1.2e-3)
    a.set("scatter", -1, 2, 4e-4)
    a.pulses = 17
    path = tmp_path / "valve_friction.json"
    a.save(path)
    b = FineLearner(4, 0.1)
    b.load(path)
    assert b.to_dict() == a.to_dict()
    # a file that does not fit is refused and changes nothing
    doc = json.loads(path.read_text())
    doc["equilibrium"]["open"][0] = float("nan")
    with pytest.raises(ValueError, match="finite"):
        b.from_dict(doc)
    with pytest.raises(ValueError, match="bands"):
        FineLearner(3, 0.1).from_dict(a.to_dict())
    assert b.to_dict() == a.to_dict()


def test_a_version_1_file_loads_with_the_move_sizes_unlearned():
    a = FineLearner(4, 0.1)
    a.set("breakaway", 1, 1, 3e-3)
    a.set("min_move", 1, 1, 1e-3)
    doc = a.to_dict()
    doc["version"] = 1
    del doc["min_move"]
    b = FineLearner(4, 0.1)
    b.from_dict(doc)
    assert b.breakaway == a.breakaway and b.min_move == b.scatter == {1: [0.0] * 4, -1: [0.0] * 4}
    doc["version"] = FineLearner.VERSION + 1
    with pytest.raises(ValueError, match="version"):
        b.from_dict(doc)


def test_a_version_3_file_loads_with_the_breakaway_scatter_unlearned():
    """Version 3 held a ``margin`` table (the staircase start, adapted x1.5 / x0.9); version 4
    learns the breakaway scatter it stood in for: an old file loads, its margins dropped."""
    a = FineLearner(4, 0.1)
    a.set("breakaway", -1, 3, -2e-3)
    a.set("misfit", 1, 0, 0.4)
    doc = a.to_dict()
    doc["version"] = 3
    doc["margin"] = doc.pop("scatter")
    doc["margin"]["open"][1] = 7e-4
    b = FineLearner(4, 0.1)
    b.set("scatter", 1, 1, 3e-4)
    b.from_dict(doc)
    assert b.breakaway == a.breakaway and b.misfit == a.misfit
    assert b.scatter == {1: [0.0] * 4, -1: [0.0] * 4}
    assert FineLearner.VERSION == 5 and "scatter" in a.to_dict() and "margin" not in a.to_dict()


def test_breakaway_samples_learn_its_mean_and_scatter():
    """The breakaway level is drawn anew at every stop: samples (the main law's breakaways from
    rest, the doublets') give its mean and rms scatter per direction and Δp band, bounded."""
    rng = np.random.default_rng(3)
    lr = FineLearner(4, 0.01)
    for x in rng.normal(4e-4, 5e-4, 400):
        lr.observe_breakaway(-1, 2, float(x), 0.05, prior=1e-3)
    assert lr.breakaway[-1][2] == pytest.approx(4e-4, abs=2e-4)
    assert lr.scatter[-1][2] == pytest.approx(5e-4, rel=0.3)
    assert lr.breakaway[1] == lr.scatter[1] == [0.0] * 4 and lr.scatter[-1][1] == 0.0
    lr.observe_breakaway(1, 0, 0.0, 0.2, prior=1e-3)     # a sample on the mean: the prior shrinks
    assert lr.scatter[1][0] == pytest.approx(math.sqrt(0.8) * 1e-3)
    for _ in range(50):                                  # implausible samples stay bounded
        lr.observe_breakaway(1, 0, 1.0, 0.5, prior=1e-3)
    assert lr.breakaway[1][0] <= 0.01 and lr.scatter[1][0] <= 0.01


def test_the_staircase_starts_the_learned_scatters_below_the_learned_breakaway():
    """After a stop the doublet's first preload lies ``fine.doublet_sigmas`` learned scatters
    (plus the kick's rise) below the learned breakaway twist; before any sample the prior is
    ``fine.doublet_margin`` of the static band.  A wider scatter starts it lower."""
    ps = CONTROLLER_SPEC.defaults()
    pres = []
    for scatter in (0.0, 2e-4, 6e-4):
        fine, m = _main_stage()
        p = m.pressure_max_kpa
        band = fine.learn.band(m.pressure_fraction(p))
        _break_loose(fine, 0.5, p)
        fine.learn.reset()
        fine.learn.set("scatter", 1, band, scatter)
        assert _engages(fine, 0.5e-3, p)
        _, b0 = fine._nominal(0.5, p, 1)
        e0, _ = fine._nominal(0.5, p, 1)
        below = b0 - fine._pre - ps["fine.kick_rise_rad"]
        sigma = scatter or ps["fine.doublet_margin"] * (b0 - e0) / ps["fine.doublet_sigmas"]
        assert below == pytest.approx(ps["fine.doublet_sigmas"] * sigma, rel=1e-6)
        pres.append(fine._pre)
    assert pres[2] < pres[1]


def test_the_preload_ends_slowly():
    """The servo overshoots the end of a fast preload (2.7e-4 rad median at 0.5 rad/s, 4-7
    staircase steps): the last ``fine.park_approach_rad`` is approached at
    ``fine.park_approach_speed_rad_s``, the rest at ``fine.park_speed_rad_s``."""
    ps = CONTROLLER_SPEC.defaults()
    fine, m = _stage()
    fine._phi_start, fine._pre = 0.01, 0.0135
    fine._plan_park()
    per = fine.period
    xs = [fine._park_ref(k) for k in range(fine._park_n + 1)]
    assert xs[0][0] == pytest.approx(0.01) and xs[-1][0] == pytest.approx(0.0135)
    assert all(b[0] >= a[0] for a, b in zip(xs, xs[1:]))
    near = [(x, v) for x, v, _ in xs if x > 0.0135 - ps["fine.park_approach_rad"] + 1e-9]
    assert max(v for _, v in near) <= 2.0 * ps["fine.park_approach_speed_rad_s"]   # sin²: peak = pi/2 x mean
    assert max(v for _, v, _ in xs) > 2.0 * ps["fine.park_approach_speed_rad_s"]
    assert fine._park_n * per >= ps["fine.park_approach_rad"] / ps["fine.park_approach_speed_rad_s"]


def test_learned_state_is_on_the_diagnostics():
    drv = ValveDriver(CONTROLLER_SPEC.defaults().replace({"mode": "observer_fp"}))
    values = drv.health().values
    assert values["fine_phase"] == "idle"
    assert json.loads(values["learned_breakaway_rad"]) == {"open": [0.0] * 4, "close": [0.0] * 4}
    assert json.loads(values["learned_min_move_rad"]) == {"open": [0.0] * 4, "close": [0.0] * 4}
    assert json.loads(values["learned_scatter_rad"]) == {"open": [0.0] * 4, "close": [0.0] * 4}
    # other modes learn nothing of this kind
    assert "fine_phase" not in ValveDriver(CONTROLLER_SPEC.defaults().replace({"mode": "observer_ff"})).health().values


def _rest_twist(fine, thl: float, pressure_kpa: float) -> float:
    """The twist (rad) holding a nominal valve at rest at ``thl``: the nominal load's."""
    return fine.m.load_torque(thl, pressure_kpa) / fine.m.coupling_stiffness_nm_per_rad


def _break_loose(fine, thl: float, pressure_kpa: float, offset: float = 0.0) -> None:
    """Let the stage watch the main law break a valve at rest at ``thl`` loose toward open, at
    the nominal breakaway twist plus ``offset`` x T_s/K (the evidence it engages on)."""
    m = fine.m
    k = m.coupling_stiffness_nm_per_rad
    static = m.friction(pressure_kpa).valve_static_nm / k
    phi = m.load_torque(thl, pressure_kpa) / k + static * (1.0 + offset)
    far = thl + 2.0 * fine.cfg.max_move_rad              # a demand the stage leaves to the main law
    for _ in range(fine.cfg.engage_periods + 2):
        fine.update(far, thl + phi, thl, False, 0.3, pressure_kpa)
    moved = thl + 3.0 * fine.cfg.tolerance_rad
    fine.update(far, moved + phi, moved, False, 0.3, pressure_kpa)


#: periods within which a settled stage that has seen a breakaway engages (it waits up to
#: FRESH_WAIT engage times for one on the plateau itself)
def _patience(fine) -> int:
    from fuel_valve_control.core.fine_positioning import FRESH_WAIT
    return (FRESH_WAIT + 3) * fine.cfg.engage_periods


def _engages(fine, error_rad: float, pressure_kpa: float, twist_rad: float | None = None) -> bool:
    """Whether the stage takes over a settled valve ``error_rad`` short of a steady target,
    held at rest by ``twist_rad`` (default: the nominal load's twist)."""
    thl = 0.5
    th1 = thl + (_rest_twist(fine, thl, pressure_kpa) if twist_rad is None else twist_rad)
    if fine._breakaway_seen is None:
        _break_loose(fine, thl, pressure_kpa)
    for _ in range(_patience(fine)):
        if fine.update(thl + error_rad, th1, thl, True, 0.3, pressure_kpa) is not None:
            return True
    return False


@pytest.mark.parametrize("direction", [1, -1])
def test_stage_stays_out_when_the_learned_twists_do_not_fit_the_model(direction):
    """Learned offsets beyond half the nominal static twist mean the valve is not the one the
    model describes (friction far off, unknown load, wrong Δp): the stage leaves the plateau to
    the main law's integral hold instead of pulsing with a model that does not fit."""
    from fuel_valve_control.core.position_controller import PositionController
    pc = PositionController(CONTROLLER_SPEC.defaults().replace({"mode": "observer_fp"}))
    fine, m = pc.law.fine, pc.model
    p = m.pressure_max_kpa
    bound = 0.5 * m.friction(p).valve_static_nm / m.coupling_stiffness_nm_per_rad
    band = pc.learner.band(m.pressure_fraction(p))
    err = direction * 1e-3
    assert _engages(fine, err, p)                       # nominal model: it pulses
    for table, sign in (("breakaway", 1.0), ("equilibrium", -1.0)):
        pc.learner.reset()
        # (2 x: the main law's breakaway the stage waits for, at the nominal twist, is itself a
        # sample that draws the learned breakaway 20 % of the way back)
        pc.learner.set(table, direction, band, sign * 2.0 * bound)
        fine.reset()
        assert not _engages(fine, err, p)
        pc.learner.set(table, direction, band, sign * 0.8 * bound)
        fine.reset()
        assert _engages(fine, err, p)


@pytest.mark.parametrize("direction", [1, -1])
def test_stage_does_not_pulse_an_error_its_smallest_move_would_enlarge(direction):
    """A pulse moves the valve at least the learned smallest move m; for an error e below
    ``fine.min_move_fraction`` x m (0.5: the move improves e only if m < 2|e|) the stage holds."""
    from fuel_valve_control.core.position_controller import PositionController
    pc = PositionController(CONTROLLER_SPEC.defaults().replace({"mode": "observer_fp"}))
    fine, m = pc.law.fine, pc.model
    p = m.pressure_max_kpa
    band = pc.learner.band(m.pressure_fraction(p))
    frac = fine.cfg.min_move_fraction
    assert frac > 0.0
    err = direction * 1e-3
    pc.learner.set("min_move", direction, band, 1.1 * abs(err) / frac)
    fine.reset()
    assert not _engages(fine, err, p)
    pc.learner.set("min_move", -direction, band, 10 * abs(err))   # the other direction's says nothing here
    pc.learner.set("min_move", direction, band, 0.9 * abs(err) / frac)
    fine.reset()
    assert _engages(fine, err, p)


@pytest.mark.parametrize("direction", [1, -1])
def test_before_any_move_is_learned_the_smallest_move_is_a_prior_from_the_jump(direction):
    """With no doublet move learned yet, the stopping rule uses ``fine.min_move_prior`` x the
    nominal stick-slip jump 2 (T_s - T_c(Δp)) / K (0.86e-3 of 4.6e-3 rad at max Δp): an error just
    outside the tolerance is not pulsed (a nominal-box doublet for 3.4e-4 rad broke the valve loose
    for a whole jump), one above half the prior move is.  (The policy's stop radius, fine.apex_stop_rad, off: 1.1 x
    half the prior lies inside its default 4.8e-4 rad.)"""
    fine, m = _stage(**{"fine.apex_stop_rad": 0.0})
    p = m.pressure_max_kpa
    fl = m.friction(p)
    prior = fine.cfg.min_move_prior * 2.0 * (fl.valve_static_nm - fl.valve_coulomb_nm) / m.coupling_stiffness_nm_per_rad
    half = fine.cfg.min_move_fraction * prior
    assert fine.cfg.tolerance_rad < 0.9 * half
    assert not _engages(fine, direction * 0.95 * half, p)
    fine.reset()
    assert _engages(fine, direction * 1.1 * half, p)


@pytest.mark.parametrize("side", [1, -1])
def test_stage_stays_out_of_a_valve_whose_twist_at_rest_the_model_cannot_explain(side):
    """A stuck valve's twist lies inside its static band (load +- T_s(Δp)) / K.  Held beyond the
    nominal band (an unknown load, a softer coupling, a wrong Δp: quick campaign runs whose
    preload unloaded the coupling and let the valve slide 7e-3 rad away, three times a plateau)
    the stage leaves the plateau to the main law; inside it (scatter and ripple) it engages --
    for a move back into the band: a move further out from a twist past the breakaway the stage
    would plan is left to the hold as well (test_a_valve_at_rest_past_the_planned_breakaway_is_left_to_the_hold)."""
    fine, m = _stage()
    p = m.pressure_max_kpa
    static = m.friction(p).valve_static_nm / m.coupling_stiffness_nm_per_rad
    centre = _rest_twist(fine, 0.5, p)
    widened = static * (1.0 + fine.cfg.fit_margin)
    for err in (1e-3, -1e-3):
        fine.reset()
        assert _engages(fine, err, p, centre + side * 0.95 * widened) is (err * side < 0)
        fine.reset()
        assert not _engages(fine, err, p, centre + side * 1.05 * widened)
        assert not _engages(fine, err, p, centre)        # ... nor later on the same demand


@pytest.mark.parametrize("settle", [False, True])
@pytest.mark.parametrize("direction", [1, -1])
def test_a_valve_sliding_away_while_preloading_is_handed_back_for_the_plateau(direction, settle):
    """While the twist moves to its preload the valve may only move toward the target; one that
    slides away shows the planned twists do not hold it: the stage returns control to the main
    law at once (``None``) and stays out until the demand changes.  With ``fine.handback_settle`` (C3's, the
    default since stop 28, docs §108) the gear output, which moved with the slide, is first held where it is until it
    is still with the valve at rest (3 periods here), then the main law takes over."""
    fine, m = _stage(**{"fine.handback_settle": settle})
    p = m.pressure_max_kpa
    thl = 0.5
    phi = _rest_twist(fine, thl, p)
    target = thl + direction * 1e-3
    _break_loose(fine, thl, p)
    for _ in range(_patience(fine)):
        if fine.update(target, thl + phi, thl, True, 0.3, p) is not None:
            break
    assert fine.phase == "park"
    thl -= direction * 3.0 * fine.cfg.tolerance_rad          # it slides the wrong way
    for _ in range(3 if settle else 0):
        assert fine.update(target, thl + phi, thl, True, 0.3, p) is not None
        assert fine.phase == "hold"
    assert fine.update(target, thl + phi, thl, True, 0.3, p) is None
    assert fine.phase == "idle"
    for _ in range(_patience(fine)):                          # settled again: not on this demand
        assert fine.update(target, thl + phi, thl, True, 0.3, p) is None
    _break_loose(fine, thl, p)          # the main law moves it on: a breakaway that fits the model
    thl += 3.0 * fine.cfg.tolerance_rad
    target = thl + direction * 1e-3                           # a new demand: the stage may try again
    assert any(fine.update(target, thl + phi, thl, True, 0.3, p) is not None
               for _ in range(_patience(fine)))


#: the tests that play the gear output by hand (it does not accelerate under a kick) run without the lost-kick check,
#: which reads that acceleration (fine.kick_lost_fraction; test_kick_lost.py checks it on the plant)
HAND_PLAYED = {"fine.kick_lost_fraction": 0.0}


def _stage(**changes):
    from fuel_valve_control.core.position_controller import PositionController
    pc = PositionController(CONTROLLER_SPEC.defaults().replace({"mode": "observer_fp", **HAND_PLAYED, **changes}))
    return pc.law.fine, pc.model


#: C1 (+ the stop radius): the default of stops 26-27 -- the apex policy with the normal law of the level, the stage
#: engaging on the valve's rest alone, the floor at the measured apex, the hand-overs and hand-backs at once, the
#: two-period retreat whatever its trough, the servo's gains as designed on any coupling.  C3 -- these seven changed
#: (the mixture law, docs §92; the engage gate and the planned floor, §95; the hand-over settle, §98; the retreat's
#: trough bound, §90, and the servo's coupling cap, §105; the hand-back settle, §108) -- is the default since stop 28
#: (docs §108); the tests written for C1's stage set this explicitly.
C1_FINE = {"fine.apex_level_law": "normal", "fine.engage_gear_rest": 0.0, "fine.apex_floor_plan": False,
           "fine.handover_settle_speed_rad_s": 0.0, "fine.retreat_trough_bound": False,
           "fine.servo_coupling_cap": False, "fine.handback_settle": False,
           "fine.apex_keep_rad": 0.0}     # (and the keep radius, on since stop 29: docs §110, §111)
#: ... and C3's values of the seven (the defaults since stop 28)
C3_FINE = {"fine.apex_level_law": "mixture", "fine.engage_gear_rest": 0.1, "fine.apex_floor_plan": True,
           "fine.handover_settle_speed_rad_s": 0.1, "fine.retreat_trough_bound": True,
           "fine.servo_coupling_cap": True, "fine.handback_settle": True}

#: main's doublet before stop 25: the staircase (no apex policy), the hold - cap retreat with its period of half the
#: cap, the observe servo's integral wound as ever -- C1's six options (docs §88) off, and C2's four (:data:`C1_FINE`).
#: C1 was the default from stop 25 (task h36f, docs §91), C2 since stop 27; the tests of the staircase and of main's
#: doublet shape set this explicitly.
MAIN_DOUBLET = {"fine.apex_policy": False, "fine.apex_kick_max_a": 0.0, "fine.apex_retreat_periods": 0,
                "fine.retreat_cap": False, "fine.observe_hold_moved": False, "fine.apex_excess_nominal": False,
                **C1_FINE}


def _main_stage(**changes):
    """:func:`_stage` with main's doublet (:data:`MAIN_DOUBLET`) under ``changes``."""
    return _stage(**{**MAIN_DOUBLET, **changes})


def _torques_until_observe(fine, error_rad, pressure_kpa, hold_nm=0.3, periods=400):
    """Torques the stage commands for a stuck valve ``error_rad`` short of a steady target,
    until its first pulse is over (phase ``observe``); while it preloads, the gear output is
    where the preload wants it (a stiff servo)."""
    thl = 0.5
    th1 = thl + _rest_twist(fine, thl, pressure_kpa)
    _break_loose(fine, thl, pressure_kpa)
    out = []
    for _ in range(periods):
        if fine.phase == "park":
            th1 = thl + fine._pre
        tq = fine.update(thl + error_rad, th1, thl, True, hold_nm, pressure_kpa)
        if tq is not None:
            out.append(tq)
        if fine.phase == "observe":
            return out
    raise AssertionError("the stage never pulsed")


@pytest.mark.parametrize("direction", [1, -1])
def test_small_errors_get_a_torque_doublet_against_the_current_slew(direction):
    """Up to ``fine.doublet_max_error_rad`` the pulse is a torque doublet on the hold torque
    the preload ended with: one period of kick toward the target, then the whole current
    backwards (SPEC §6: the retreat must be at full current when the valve breaks), half the
    next period; larger errors get the servo-blended pulse, which never reverses that hard."""
    ps = CONTROLLER_SPEC.defaults()
    fine, m = _main_stage()
    kt = m.torque_constant_nm_per_a
    cap = ps["fine.peak_current_a"] * kt
    small = 0.5 * ps["fine.doublet_max_error_rad"]
    out = _torques_until_observe(fine, direction * small, m.pressure_max_kpa)
    hold = out[-4]                                    # the last period of the preload
    assert abs(hold) < cap - ps["fine.kick_current_a"] * kt
    assert out[-3] == pytest.approx(hold + direction * ps["fine.kick_current_a"] * kt)
    assert out[-2] == pytest.approx(max(min(hold - direction * cap, cap), -cap))
    assert out[-1] == pytest.approx(max(min(hold - direction * 0.5 * cap, cap), -cap))
    fine, m = _main_stage()
    large = 2.0 * ps["fine.doublet_max_error_rad"]
    out = _torques_until_observe(fine, direction * large, m.pressure_max_kpa)
    assert all(abs(t) <= cap + 1e-12 for t in out)
    assert out[-2] != pytest.approx(max(min(out[-4] - direction * cap, cap), -cap))


def test_the_main_law_restarts_from_the_holding_torque_not_a_pulse():
    """After a demand change the main law restarts from the torque that holds the present
    twist (engage torque + K * twist change / N), never from a pulse's torque."""
    fine, m = _stage()
    assert fine.hold_torque(0.51, 0.5) is None                     # never engaged
    out = _torques_until_observe(fine, 0.5e-3, m.pressure_max_kpa, hold_nm=0.3)
    assert abs(out[-2] - 0.3) > 0.5                                  # mid-doublet: a large torque
    phi0 = _rest_twist(fine, 0.5, m.pressure_max_kpa)
    assert fine.hold_torque(0.5 + phi0, 0.5) == pytest.approx(0.3)   # the engage twist: the engage torque
    dphi = 1e-3
    assert fine.hold_torque(0.5 + phi0 + dphi, 0.5) == pytest.approx(
        0.3 + m.coupling_stiffness_nm_per_rad * dphi / m.gear_ratio)


_CAMPAIGNS: dict = {}
_BENCH: dict = {}       # the robustness benchmark module the look-ahead workers run with


def _campaign(rb, mode: str, runs: int = 4, also: tuple = ()) -> list[dict]:
    """The first ``runs`` cases of the nominal campaign (seeds 2000...) in ``mode``, each
    simulated once in this module; ``also``: modes a test needs too, simulated alongside (the
    runs on both cores, test/prefetch.py: the same runs, pickled back)."""
    wanted = [m for m in dict.fromkeys((mode, *also)) if (rb, m, runs) not in _CAMPAIGNS]
    if wanted:
        _BENCH["rb"] = rb
        keys = [(2000 + i, m) for m in wanted for i in range(runs)]
        with Ahead(_campaign_case, keys, jobs()) as ahead:
            for m in wanted:
                _CAMPAIGNS[(rb, m, runs)] = [ahead.result(2000 + i, m) for i in range(runs)]
    return _CAMPAIGNS[(rb, mode, runs)]


def _campaign_case(seed: int, mode: str) -> dict:
    rb = _BENCH["rb"]
    return rb.run_case((rb.sample_case(seed, "nominal"), mode, {}))


@pytest.mark.slow
def test_fine_positioning_ends_plateaus_closer_than_the_deadband_does(robustness_bench):
    """Seeded sample of the nominal campaign (friction scatter + ripple, 0.1-5 % plateaus)."""
    fp = [pl["final_error_rad"] for r in _campaign(robustness_bench, "observer_fp", also=("observer_ff",))
          for pl in r["plateaus"]]
    ff = [pl["final_error_rad"] for r in _campaign(robustness_bench, "observer_ff") for pl in r["plateaus"]]
    assert np.median(fp) < 0.5 * np.median(ff)
    assert np.percentile(fp, 95) < np.percentile(ff, 95)
    assert not any(r["hunts"] or r["fault"] for r in _campaign(robustness_bench, "observer_fp"))


@pytest.mark.slow
def test_fine_positioning_pulses_stay_within_their_current_cap(robustness_bench):
    """The pulses are what draws the peak; capped at ``fine.peak_current_a`` (30 A, the issue's
    target) they only get slower, and the campaign sample stays within it (36 A uncapped)."""
    cap = CONTROLLER_SPEC.defaults()["fine.peak_current_a"]
    runs = _campaign(robustness_bench, "observer_fp")
    assert max(r["peak_current_a"] for r in runs) <= cap + 0.5     # + the current loop's ripple


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="issue 14 plateau target not reached by observer_fp: nominal campaign "
                   "(benchmarks/robustness.py --box nominal --runs 80 --mode observer_fp) final error median "
                   "3.15e-4, p95 1.49e-3, max 4.40e-3 rad (target p95 5e-4, max 8e-4) -- the smallest move a "
                   "torque doublet makes at <= 30 A is 0.86-1.0e-3 rad (+~4 rad per rad of overdrive), and a "
                   "preload near the breakaway drawn anew at every stop sometimes breaks it loose: a whole "
                   "4.6e-3 rad jump")
def test_fine_positioning_meets_the_issue_targets(robustness_bench):
    fp = [pl["final_error_rad"] for r in _campaign(robustness_bench, "observer_fp") for pl in r["plateaus"]]
    assert np.percentile(fp, 95) <= 5e-4 and max(fp) <= 8e-4


@pytest.mark.parametrize("offset", [-0.6, 0.6])
def test_stage_stays_out_when_the_main_laws_breakaway_twist_does_not_fit_the_model(offset):
    """The twist at which the main law broke the valve loose is the evidence the model fits:
    within ``fine.breakaway_fit`` x T_s/K of the nominal breakaway twist the stage engages;
    0.5-2.7 T_s/K off (measured on the quick-campaign valves it hunted on) it leaves the
    plateau to the main law."""
    fine, m = _stage()
    p = m.pressure_max_kpa
    assert 0.1 < fine.cfg.breakaway_fit < abs(offset)
    _break_loose(fine, 0.5, p, offset=0.1 * math.copysign(1.0, offset))
    assert _engages(fine, 1e-3, p)
    fine.reset()
    _break_loose(fine, 0.5, p, offset=offset)
    assert not _engages(fine, 1e-3, p)


def test_a_poor_record_keeps_the_stage_out_and_decays_per_plateau(tmp_path):
    """Engagements that failed (handed back, or left the valve further off) enter the learned
    misfit record per direction and Δp band; above ``fine.misfit_limit`` the stage stays out of
    that direction and band, the record decaying by ``fine.misfit_decay`` per plateau it stays
    out of, so it tries again later.  The record is saved with the learned twists."""
    from fuel_valve_control.core.position_controller import PositionController
    pc = PositionController(CONTROLLER_SPEC.defaults().replace({"mode": "observer_fp"}))
    fine, m = pc.law.fine, pc.model
    p = m.pressure_max_kpa
    band = pc.learner.band(m.pressure_fraction(p))
    cfg = fine.cfg
    pc.learner.set("misfit", 1, band, 0.9)
    assert pc.learner.misfit[1][band] == 0.9
    fine.reset()
    assert not _engages(fine, 1e-3, p)
    assert pc.learner.misfit[1][band] == pytest.approx(0.9 * cfg.misfit_decay)   # once per plateau
    assert _engages(fine, -1e-3, p)                  # the other direction's record is clean
    path = tmp_path / "learned.json"
    pc.learner.save(path)
    other = FineLearner(pc.learner.bands, pc.learner.limit)
    other.load(path)
    assert other.misfit[1][band] == pytest.approx(0.9 * cfg.misfit_decay)
    pc.learner.set("misfit", 1, band, 3.0)           # a record is a fraction
    assert pc.learner.misfit[1][band] == 1.0
    pc.learner.reset()
    assert pc.learner.misfit == {1: [0.0] * 4, -1: [0.0] * 4}


def test_a_hand_back_keeps_the_load_the_main_laws_hold_learned():
    """When the stage hands a plateau back, the main law restarts bumplessly but keeps the steady
    load its hold learned (and the slip edges that taught it).  A full reset forgot them at every
    hand-back and the restarted hold relaxed toward the known load alone (h18g: campaign seed
    3007, 10 N*m load, slid 8e-3 rad off target)."""
    from fuel_valve_control.core.position_controller import PositionController
    from fuel_valve_control.core.signals import Measurement
    pc = PositionController(CONTROLLER_SPEC.defaults().replace({"mode": "observer_fp"}))
    law, m = pc.law, pc.model
    p = m.pressure_max_kpa
    th = 0.3
    meas = Measurement(th * m.gear_ratio, th)
    law.reset(meas, 0.0, p)
    law.main.update(0.0, th, meas, p)
    law.main.held_load = 4.0
    law.main.slip_edges.edges.update({1: 6.0, -1: 2.0})
    law._fine_active = True             # the stage had the plateau; its update now hands it back
    law.update(0.001, th, meas, p)
    assert law.main.held_load == pytest.approx(4.0)
    assert law.main.slip_edges.edges == {1: 6.0, -1: 2.0}


def _valve_history(fine, pressure_kpa, target, stops, rest=20, first=None):
    """Feed the stage a plateau on ``target`` on which the main law (the stage told it is not
    holding) leaves the valve at rest at each of ``stops`` (valve angles, rad) in turn, the first
    until the hunting metric's window has begun (or ``first`` periods); each stop's twist is the nominal breakaway twist
    toward the next one (the evidence the stage engages on).  Returns the last stop's twist."""
    first = fine.cfg.reversal_window_periods + 5 if first is None else first
    phi = 0.0
    for i, v in enumerate(stops):
        d = 1 if i + 1 < len(stops) and stops[i + 1] > v else -1
        if i + 1 == len(stops):
            d = 1 if target > v else -1
        phi = fine._nominal(v, pressure_kpa, d)[1]
        for _ in range(first if i == 0 else rest):
            assert fine.update(target, v + phi, v, False, 0.3, pressure_kpa) is None
    return phi


def _engages_after(fine, pressure_kpa, target, stops, first=None) -> bool:
    phi = _valve_history(fine, pressure_kpa, target, stops, first=first)
    v = stops[-1]
    return any(fine.update(target, v + phi, v, True, 0.3, pressure_kpa) is not None for _ in range(_patience(fine)))


@pytest.mark.parametrize("direction", [1, -1])
def test_the_stage_never_makes_the_metrics_second_reversal(direction):
    """A plateau hunts by the metric (common.hunting) when its valve reverses twice from 0.3 s
    after the step.  The stage counts the reversals as the metric does and never makes the one
    that would be the second: a valve that crossed the target and came back short of it is left
    where it is, one that reached the same place in one move is pulsed on (nominal box, main
    26f43b9: 4 of 40 runs hunted by the stage's crossing moves, each larger than its error)."""
    fine, m = _stage()
    p = m.pressure_max_kpa
    d, v0 = direction, 0.5
    target = v0 + d * 4e-3
    _break_loose(fine, v0, p)
    # one move toward the target, short of it: no reversal yet, the stage pulses on
    assert _engages_after(fine, p, target, [v0, v0 + d * 1.5e-3])
    fine, m = _stage()
    _break_loose(fine, v0, p)
    # across the target (a first direction), back short of it (reversal 1): a move toward the
    # target again would be reversal 2
    assert not _engages_after(fine, p, target, [v0, v0 + d * 6e-3, v0 + d * 1.5e-3])
    assert fine._reversals.count == 1 and fine._reversals.direction == -d
    # the same history before the metric's window (HUNT_SETTLE_S after the step) is not counted
    fine, m = _stage()
    _break_loose(fine, v0, p)
    win = fine.cfg.reversal_window_periods
    assert win * fine.period == pytest.approx(0.3 - CONTROLLER_SPEC.defaults()["fine.reversal_lead_s"])
    fine.cfg = dataclasses.replace(fine.cfg, reversal_window_periods=win + 5 + 2 * 20 + 10)
    assert _engages_after(fine, p, target, [v0, v0 + d * 6e-3, v0 + d * 1.5e-3], first=win + 5)


@pytest.mark.parametrize("direction", [1, -1])
def test_a_move_back_across_the_target_must_not_cross_it_again(direction):
    """After the first move in the metric's window crossed the target, the move back is the last
    reversal the metric allows: it must not cross again.  Up to twice ``fine.no_cross_short`` x
    the stick-slip jump it is a doublet (the smallest move, ~0.19 of the jump) even beyond
    ``fine.doublet_max_error_rad``; beyond that a servo-blended pulse aiming that far short."""
    ps = CONTROLLER_SPEC.defaults()
    for err, doublet in ((2.0e-3, True), (6.0e-3, False)):
        fine, m = _stage()
        p = m.pressure_max_kpa
        d, v0 = direction, 0.5
        short = ps["fine.no_cross_short"] * m.friction(p).stick_slip_jump_rad(m.coupling_stiffness_nm_per_rad)
        assert ps["fine.doublet_max_error_rad"] < 2.0e-3 < 2.0 * short < 6.0e-3
        v1 = v0 + d * 12e-3                      # crossed: the target lies back the way it came
        target = v1 - d * err
        _break_loose(fine, v0, p)
        assert _engages_after(fine, p, target, [v0, v1])
        assert fine._dir == -d and fine._doublet is doublet
        if not doublet:
            phi_e, _, _ = fine._twists(v1, p, -d)
            assert fine._final == pytest.approx(phi_e - d * (err - short) / 2.0)


#: nominal-box runs (``robustness.py --box nominal --seed S --runs 1``) that hunted on main 26f43b9
#: by the stage's own crossing moves: servo-blended pulses for errors of 1.1-1.9e-3 rad that moved
#: the valve 2.5-5e-3 across the target, then pulses back and forth (two reversals > 2 counts)
NOMINAL_CROSSING_HUNTERS = (1002, 1004, 1015, 1022)


@pytest.mark.slow
@pytest.mark.parametrize("seed", NOMINAL_CROSSING_HUNTERS)
def test_nominal_runs_the_stage_made_hunt_hold_without_hunting(robustness_bench, seed):
    r = robustness_bench.run_case((robustness_bench.sample_case(seed, "nominal"), "observer_fp", {}))
    assert not r["hunts"] and not r["fault"]
    assert max(pl["final_error_rad"] for pl in r["plateaus"]) < 4.6e-3     # within one stick-slip jump


@pytest.mark.parametrize("direction", [1, -1])
def test_a_valve_at_rest_past_the_planned_breakaway_is_left_to_the_hold(direction):
    """A valve held at rest by a twist beyond the breakaway twist the stage would plan for the
    move (by more than ``fine.doublet_sigmas`` learned scatters) breaks loose higher than planned:
    the preload would unwind the twist holding it and the pulses never reach it (campaign seed
    1071: 9-13 pulses that never moved the valve, a hand-back, then the main law hunted).  The
    plateau stays with the main law's hold; just short of that twist the stage engages."""
    fine, m = _stage()
    p = m.pressure_max_kpa
    thl = 0.5
    phi_e, phi_b, band = fine._twists(thl, p, direction)
    sigma = fine._scatter(direction, band, direction * (phi_b - phi_e))
    limit = phi_b + direction * fine.cfg.doublet_sigmas * sigma
    # (both inside the nominal band widened by fine.fit_margin: only the new rule tells them apart)
    static = m.friction(p).valve_static_nm / m.coupling_stiffness_nm_per_rad
    for phi in (limit + direction * 2e-4, limit - direction * 2e-4):
        assert abs(phi - _rest_twist(fine, thl, p)) < static * (1.0 + fine.cfg.fit_margin)
    assert not _engages(fine, direction * 2e-3, p, limit + direction * 2e-4)
    fine.reset()
    assert _engages(fine, direction * 2e-3, p, limit - direction * 2e-4)


@pytest.mark.parametrize("direction", [1, -1])
def test_a_servo_blended_pulse_that_did_not_move_the_valve_is_judged_as_soon_as_a_doublet(direction):
    """A valve that breaks loose moves 1.5 counts within ~0.7 ms: a servo-blended pulse (errors
    beyond ``fine.doublet_max_error_rad``) that has not moved it ``no_move_periods`` after its
    fall did not break it, and the next pulse starts then -- it waited the whole
    ``fine.observe_time_s`` (27 ms per such pulse; on the nominal box 14 of 73 plateaus > 8e-4 rad
    ended mid-staircase, task h20p).  A pulse that moved it is still watched until it stops."""
    ps = CONTROLLER_SPEC.defaults()
    for moved in (False, True):
        fine, m = _stage()
        p = m.pressure_max_kpa
        err = direction * 2.0 * ps["fine.doublet_max_error_rad"]
        _torques_until_observe(fine, err, p)
        assert not fine._doublet and fine.phase == "observe"
        thl = 0.5 + (direction * 1e-3 if moved else 0.0)
        th1 = thl + fine._final
        periods = 0
        while fine.phase == "observe" and periods < 100:
            fine.update(0.5 + err, th1, thl, True, 0.3, p)
            periods += 1
        assert fine.phase == "park"                        # judged: the next pulse
        if moved:
            assert periods >= fine.cfg.observe_periods
        else:
            assert periods <= fine.cfg.no_move_periods + 1 < fine.cfg.observe_periods


@pytest.mark.parametrize("direction", [1, -1])
def test_doublets_that_do_not_move_the_valve_climb_until_the_plausible_bound_not_the_pulse_budget(direction):
    """A doublet that did not move the valve is a stair of its staircase, not a move: it does not
    use up ``fine.max_pulses`` (on valves whose learned scatter is ~1e-3 rad the budget ran out
    before the staircase reached the learned breakaway, even on the 4 s final hold: nominal box,
    seeds 2000-2039, 5 plateaus 0.9-1e-3 rad off; task h20p).  The staircase stops instead where
    its preload would lie beyond the nominal breakaway twist by more than a plausible learned
    offset (half the nominal static twist, :meth:`FinePositioner._plausible`)."""
    fine, m = _main_stage()
    p = m.pressure_max_kpa
    err = direction * 0.6e-3
    _torques_until_observe(fine, err, p)
    assert fine._doublet
    thl = 0.5
    stairs, pres = 0, []
    for _ in range(40000):
        phase = fine.phase
        th1 = thl + (fine._pre if phase == "park" else fine._final)
        fine.update(thl + err, th1, thl, True, 0.3, p)      # the valve never moves
        if phase != "observe" and fine.phase == "observe":
            stairs += 1
        if phase == "park" and fine.phase == "pulse":
            pres.append(fine._pre)
        if fine.phase in ("hold", "idle"):
            break
    assert fine.phase == "hold" and fine._climbed_out and fine._spent()
    assert stairs > fine.cfg.max_pulses
    _, b0 = fine._nominal(thl, p, direction)
    static = m.friction(p).valve_static_nm / m.coupling_stiffness_nm_per_rad
    assert all(direction * (pre - b0) <= 0.5 * static for pre in pres)
    assert direction * (pres[-1] - b0) > 0.5 * static - 2.0 * fine.cfg.doublet_probe_step * static


@pytest.mark.parametrize("direction", [1, -1])
def test_a_staircase_in_progress_stays_a_staircase_when_the_error_reads_a_count_more(direction):
    """An error a count either side of ``fine.doublet_max_error_rad`` flipped the pulse kind at
    every stair of one stop; each servo-blended pulse that did not move the valve raised the learned
    breakaway, and the next doublet's preload broke the valve loose a whole jump across (nominal
    box, seed 2013 #8: 6.2e-3 rad, task h20p).  After a doublet that did not move the valve the
    next pulse at that stop is a doublet again while the error is within a tolerance of the limit;
    a fresh stop beyond the limit still gets the servo-blended pulse."""
    from fuel_valve_control.common.contract import RESOLVER_COUNT_RAD as count
    lim = CONTROLLER_SPEC.defaults()["fine.doublet_max_error_rad"]
    fine, m = _main_stage()
    p = m.pressure_max_kpa
    err = direction * (lim - 0.2 * count)
    _torques_until_observe(fine, err, p)
    assert fine._doublet and fine.phase == "observe"
    thl = 0.5 - direction * count                       # reads a count further off: not moved
    for _ in range(3 * fine.cfg.observe_periods):
        fine.update(0.5 + err, thl + fine._final, thl, True, 0.3, p)
        if fine.phase == "park":
            break
    assert fine.phase == "park" and abs(0.5 + err - thl) > lim
    assert fine._doublet
    fine, m = _main_stage()
    _torques_until_observe(fine, direction * (lim + 0.8 * count), p)
    assert not fine._doublet


def _stuck_staircase(fine, err, p, stairs=12):
    """The stage's doublet staircase on a valve that never moves, ``err`` short of a steady target:
    (periods spent, climb of each stair in rad of twist, the error each stair was sized for)."""
    _torques_until_observe(fine, err, p)
    assert fine._doublet
    thl, periods, climbs, stair = 0.5, 0, [], fine._stair
    while len(climbs) < stairs:
        phase = fine.phase
        th1 = thl + (fine._pre if phase == "park" else fine._final)
        fine.update(thl + err, th1, thl, True, 0.3, p)
        periods += 1
        if fine._stair != stair:
            climbs.append(stair - fine._stair)
            stair = fine._stair
        assert fine.phase not in ("hold", "idle")
    return periods, climbs


@pytest.mark.parametrize("direction", [1, -1])
def test_stairs_sized_to_the_error_climb_faster_and_their_worst_move_still_improves_it(direction):
    """``fine.move_per_overdrive`` (off by default: measured no better on the nominal box, task h21n):
    after a doublet that did not move the valve, the next stair climbs as far as the worst move it
    allows (the smallest move plus the slope x the stair) still leaves at most half the error -- a
    move up to 1.5 x it -- between the fixed stair (``fine.doublet_probe_step`` x the band) and ``fine.kick_rise_rad``
    (the preload stays below the apex that did not break the valve).  For an error near
    ``fine.doublet_max_error_rad`` it reaches a given twist in fewer periods than fixed stairs; for
    an error of about the smallest move the stairs stay the fixed ones."""
    slope = 4.0
    lim = CONTROLLER_SPEC.defaults()["fine.doublet_max_error_rad"]
    fixed, m = _main_stage()
    p = m.pressure_max_kpa
    sized, _ = _main_stage(**{"fine.move_per_overdrive": slope})
    err = direction * 0.95 * lim
    n_fixed, c_fixed = _stuck_staircase(fixed, err, p)
    n_sized, c_sized = _stuck_staircase(sized, err, p)
    floor = c_fixed[0]
    assert all(c == pytest.approx(floor) for c in c_fixed)
    cfg = sized.cfg
    m0 = cfg.min_move_prior * m.friction(p).stick_slip_jump_rad(m.coupling_stiffness_nm_per_rad)
    assert all(floor < c <= max(cfg.kick_rise_rad, floor) + 1e-12 for c in c_sized)
    assert all(m0 + slope * c <= 1.5 * abs(err) + 1e-12 for c in c_sized)
    # twist climbed per period of staircase: the same stairs, each taking about as long
    assert sum(c_sized) / n_sized > 1.5 * sum(c_fixed) / n_fixed
    small, _ = _main_stage(**{"fine.move_per_overdrive": slope})
    _, c_small = _stuck_staircase(small, direction * 0.95 * (m0 + slope * floor) / 1.5, p, stairs=4)
    assert all(c == pytest.approx(floor) for c in c_small)


def _staircase_with_apex(fine, err, p, rise, periods=3000):
    """The stage's doublet staircase on a valve that never moves, ``err`` short of a steady target,
    each doublet's apex ``rise`` (rad of twist) beyond its preload (the bare kick adds ~2.7e-4 rad,
    task h22m): (final phase, the apexes reached, rad of twist relative to the valve)."""
    thl = 0.5
    th1 = thl + _rest_twist(fine, thl, p)
    _break_loose(fine, thl, p)
    d = 1 if err > 0 else -1
    apexes, engaged = [], False
    for _ in range(periods):
        phase = fine.phase
        engaged = engaged or phase != "idle"
        if phase == "park":
            th1 = thl + fine._pre
        elif phase in ("pulse", "observe"):
            th1 = thl + fine._pre + d * rise
        fine.update(thl + err, th1, thl, True, 0.3, p)
        if phase == "observe" and fine.phase != "observe":
            apexes.append(fine._peak_seen)
        if engaged and fine.phase in ("hold", "idle") or fine._climbed_out:
            break
    return fine.phase, apexes


@pytest.mark.parametrize("direction", [1, -1])
def test_a_staircase_stops_where_the_level_makes_the_move_larger_than_twice_the_error(direction):
    """``fine.move_per_level`` (off by default: measured no better on the nominal box, task h22m):
    the doublet's move follows the level the plant drew at the stop (0.64 rad per rad of static
    excess, the true overdrive ~0), so a staircase whose unmoved apex has climbed so far above the
    learned breakaway that the move expected there -- the smallest move plus the slope x the apex's
    excess over the learned breakaway -- is more than twice the error stops and holds, at the first
    such stair; without the slope the staircase climbs on."""
    slope, rise = 0.64, 2.7e-4
    fine, m = _main_stage(**{"fine.move_per_level": slope})
    p = m.pressure_max_kpa
    m0 = fine.cfg.min_move_prior * m.friction(p).stick_slip_jump_rad(m.coupling_stiffness_nm_per_rad)
    err = direction * 0.6 * m0
    phase, apexes = _staircase_with_apex(fine, err, p, rise)
    assert phase == "hold" and len(apexes) > 3
    b = fine._nominal(0.5, p, direction)[1] + fine.learn.breakaway[direction][fine.learn.band(m.pressure_fraction(p))]
    expected = [m0 + slope * max(direction * (a - b), 0.0) for a in apexes]
    assert expected[-1] > 2.0 * abs(err) >= expected[-2]
    plain, _ = _main_stage()
    phase, more = _staircase_with_apex(plain, err, p, rise)
    assert phase != "hold" and len(more) > len(apexes) + 3


@pytest.mark.parametrize("direction", [1, -1])
def test_a_longer_whole_current_retreat_is_an_option(direction):
    """``fine.retreat_full_periods`` (1 by default: 2 measured far worse on the nominal box, task
    h22m): after the kick the doublet pulls the whole current backwards for that many periods, then
    half of it for one."""
    ps = CONTROLLER_SPEC.defaults()
    fine, m = _main_stage(**{"fine.retreat_full_periods": 2})
    kt = m.torque_constant_nm_per_a
    cap = ps["fine.peak_current_a"] * kt
    out = _torques_until_observe(fine, direction * 0.5 * ps["fine.doublet_max_error_rad"], m.pressure_max_kpa)
    hold = out[-5]
    assert out[-4] == pytest.approx(hold + direction * ps["fine.kick_current_a"] * kt)
    assert out[-3] == pytest.approx(max(min(hold - direction * cap, cap), -cap)) == pytest.approx(out[-2])
    assert out[-1] == pytest.approx(max(min(hold - direction * 0.5 * cap, cap), -cap))


@pytest.mark.parametrize("direction", [1, -1])
def test_a_learned_kick_rise_puts_each_apex_on_its_planned_stair(direction):
    """``fine.learn_kick_rise`` (off by default: measured, task h22f): the preload is planned below the
    stair's apex by the twist the stage's own unmoved doublets rose above their preload (nominal box:
    0.28-0.30e-3 rad) instead of ``fine.kick_rise_rad`` (0.15e-3), so from the second stair on each apex
    lies on the planned stair -- the learned breakaway less the stair -- instead of the rise's excess
    above it; without the option every apex lies that excess above its stair."""
    rise = 2.8e-4
    p, err = None, None

    def staircase(fine, m):
        nonlocal p, err
        p = m.pressure_max_kpa
        err = direction * 0.9 * fine.cfg.doublet_max_error_rad
        thl = 0.5
        th1 = thl + _rest_twist(fine, thl, p)
        _break_loose(fine, thl, p)
        rows, stair, engaged = [], None, False
        for _ in range(3000):
            phase = fine.phase
            engaged = engaged or phase != "idle"
            if phase == "park":
                th1 = thl + fine._pre
            elif phase in ("pulse", "observe"):
                th1 = thl + fine._pre + direction * rise
            if phase == "pulse" and stair is None:
                stair = fine._stair
            fine.update(thl + err, th1, thl, True, 0.3, p)
            if phase == "observe" and fine.phase != "observe":
                rows.append((fine._peak_seen, stair))
                stair = None
            if len(rows) >= 5 or engaged and fine.phase in ("hold", "idle") or fine._climbed_out:
                break
        assert len(rows) >= 5
        phi_b = fine._twists(thl, p, direction)[1]
        return [direction * (phi_b - apex) - s for apex, s in rows]   # apex below its planned stair, rad

    learned = staircase(*_main_stage(**{"fine.learn_kick_rise": True}))
    plain_fine, m = _main_stage()
    plain = staircase(plain_fine, m)
    excess = rise - plain_fine.cfg.kick_rise_rad
    assert all(x == pytest.approx(-excess, abs=1e-9) for x in plain)
    assert learned[0] == pytest.approx(-excess, abs=1e-9)          # the first kick: nothing seen yet
    assert all(x == pytest.approx(0.0, abs=1e-9) for x in learned[1:]), (learned, plain)


@pytest.mark.parametrize("direction", [1, -1])
def test_a_first_stair_may_kick_smaller_and_the_next_stairs_kick_whole(direction):
    """``fine.first_kick_fraction`` (1 by default: measured, task h22f): a staircase's first stair kicks
    with that fraction of ``fine.kick_current_a`` (a level drawn just above the first preload let the valve
    go while the whole kick still raised the twist: moves 0.3-2.0e-3 rad, nominal box), its preload that
    fraction of ``fine.kick_rise_rad`` below its apex; the stairs after it kick with the whole current."""
    ps = CONTROLLER_SPEC.defaults()
    frac = 0.5
    fine, m = _main_stage(**{"fine.first_kick_fraction": frac})
    kt = m.torque_constant_nm_per_a
    p = m.pressure_max_kpa
    out = _torques_until_observe(fine, direction * 0.5 * ps["fine.doublet_max_error_rad"], p)
    assert fine._first_stair
    assert out[-3] - out[-4] == pytest.approx(direction * frac * ps["fine.kick_current_a"] * kt)
    phi_b = fine._twists(0.5, p, direction)[1]
    assert direction * (phi_b - fine._pre) == pytest.approx(frac * ps["fine.kick_rise_rad"] + fine._stair)
    # the valve stays: the next stair kicks with the whole current
    thl, err = 0.5, direction * 0.5 * ps["fine.doublet_max_error_rad"]
    kicks, prev = [], None
    for _ in range(400):
        phase = fine.phase
        th1 = thl + (fine._pre if phase == "park" else fine._final)
        tq = fine.update(thl + err, th1, thl, True, 0.3, p)
        if phase == "pulse" and fine._k == 1:
            kicks.append(tq - prev)
        prev = tq
        if len(kicks) >= 1:
            break
    assert not fine._first_stair
    assert kicks[0] == pytest.approx(direction * ps["fine.kick_current_a"] * kt)


def _unmoved_short_pulse(direction, error_rad=None, **changes):
    """A servo-blended pulse whose twist stayed at its preload (0.3 x the static band below the learned
    breakaway) and did not move the valve; returns the stage at its next pulse's preload, the pulse's
    (preload, planned peak), the learned breakaway before it, the Δp band and ``fine.probe_step`` x the
    nominal static band (rad)."""
    ps = CONTROLLER_SPEC.defaults()
    fine, m = _stage(**changes)
    p = m.pressure_max_kpa
    b = fine.learn.band(m.pressure_fraction(p))
    err = direction * (error_rad or 2.0 * ps["fine.doublet_max_error_rad"])
    _torques_until_observe(fine, err, p)
    assert not fine._doublet and fine.phase == "observe"
    before = fine.learn.breakaway[direction][b]
    pre, peak = fine._pre, fine._peak_planned
    assert direction * (fine._peak_seen - pre) <= 1e-12           # the twist stayed at its preload
    thl, th1 = 0.5, 0.5 + pre
    for _ in range(100):
        fine.update(0.5 + err, th1, thl, True, 0.3, p)
        if fine.phase == "park":
            break
    assert fine.phase == "park" and not fine._doublet
    e0, b0 = fine._nominal(0.5, p, direction)
    return fine, pre, peak, before, b, ps["fine.probe_step"] * abs(b0 - e0)


@pytest.mark.parametrize("direction", [1, -1])
def test_a_pulse_that_fell_short_of_the_learned_breakaway_does_not_raise_it(direction):
    """An unmoved pulse proves only that the breakaway level at this stop lies beyond the twist it
    reached.  ``fine.probe_reached``: a servo-blended pulse whose twist stayed at its preload, 0.3 x
    the static band below the learned breakaway, leaves the learned level where it was (the ratchet
    raised it 0.1 band beyond it: on the nominal box 93 % of the unmoved pulses had fallen short of
    it, task h25p), and the next pulse keeps its preload while its planned peak climbs the step."""
    for reached in (False, True):
        fine, pre, peak, before, b, step = _unmoved_short_pulse(direction, **{"fine.probe_reached": reached})
        raised = direction * (fine.learn.breakaway[direction][b] - before)
        if reached:
            assert raised == pytest.approx(0.0, abs=1e-12)
            assert fine._pre == pytest.approx(pre, abs=1e-12)              # the preload did not climb ...
            assert direction * (fine._peak_planned - peak) == pytest.approx(step, rel=1e-6)  # ... the peak did
        else:
            assert raised == pytest.approx(step, rel=1e-6)      # the ratchet


@pytest.mark.parametrize("direction", [1, -1])
def test_a_capped_preload_goes_no_further_than_an_unmoved_pulse_reached(direction):
    """``fine.preload_cap``: the ratchet still raises the learned breakaway (and the next planned peak)
    the step beyond the level, but the next preload stays at the furthest twist an unmoved pulse reached
    at this stop -- uncapped it climbs the step with the learned level."""
    for cap in (False, True):
        # an error large enough that the preload is planned from the learned level (0.3 band below it),
        # not clipped to the swing's end
        fine, pre, peak, before, b, step = _unmoved_short_pulse(direction, 8e-3, **{"fine.preload_cap": cap})
        assert direction * (fine.learn.breakaway[direction][b] - before) == pytest.approx(step, rel=1e-6)
        if cap:
            assert fine._pre == pytest.approx(pre, abs=1e-12)
        else:
            assert direction * (fine._pre - pre) > 0.5 * step           # 0.7 step: the band widens too


@pytest.mark.parametrize("direction", [1, -1])
def test_the_peak_push_outlives_the_stop_and_shrinks_at_each_servo_blended_move(direction):
    """``fine.probe_reached``: the step an unmoved pulse did not prove goes to the planned peak (the servo's
    shortfall is the loop's, not the stop's): a servo-blended pulse that then moves the valve onto the target
    keeps 1 - 0.3 of it, and the first pulse at the next stop peaks that far beyond the learned level's
    overdrive.  (Reset at every stop, the nominal box measured worse -- 62 vs 59 plateaus > 8e-4 rad and a
    8.7e-3 rad max; corrected at each move as the ratchet's level would be, 66 and 8.4e-3: task h25p, h26p.)"""
    from fuel_valve_control.core.fine_positioning import MOVE_GAIN
    for reached in (False, True):
        fine, pre, peak, before, b, step = _unmoved_short_pulse(direction, **{"fine.probe_reached": reached})
        p = fine.m.pressure_max_kpa
        assert fine._pushes.get((direction, b), 0.0) == pytest.approx(step if reached else 0.0, rel=1e-6)
        err, thl = direction * 2.0 * fine.cfg.doublet_max_error_rad, 0.5
        for _ in range(600):                    # the next pulse moves the valve onto the target
            phase = fine.phase
            if phase == "observe":
                thl = 0.5 + err                 # (the gear output stays at the pulse's final twist)
            fine.update(0.5 + err, 0.5 + (fine._pre if phase == "park" else fine._final), thl, True, 0.3, p)
            if fine.phase == "hold":
                break
        assert fine.phase == "hold"
        push = (1.0 - MOVE_GAIN) * step if reached else 0.0
        assert fine._pushes.get((direction, b), 0.0) == pytest.approx(push, rel=1e-6, abs=1e-12)
        _torques_until_observe(fine, err, p)    # the next stop's first pulse
        assert not fine._doublet
        phi_e, phi_b, _ = fine._twists(0.5, p, direction)
        over = fine.cfg.overdrive_fraction * direction * (phi_b - phi_e)
        assert direction * (fine._peak_planned - phi_b) - over == pytest.approx(push, rel=1e-6, abs=1e-12)


@pytest.mark.parametrize("direction", [1, -1])
@pytest.mark.parametrize("drop", [True, False])
def test_the_stages_own_move_is_no_main_law_breakaway_from_the_rest_before_it(direction, drop):
    """The stage reads the main law's breakaway from the twist of the last rest it saw while idle.  A rest seen
    before the stage engaged is stale once the stage's own pulses have moved the valve: with
    ``fine.drop_rest_at_engage`` (the default) it is dropped at the engagement, and a new demand that arrives
    after the stage moved the valve (a staircase out of plateau, a hand-back) leaves the main law's last
    breakaway -- which fits -- the evidence, so the stage engages on the next plateau.  Without it (main ae79cb2)
    the stage's move is read as a main-law breakaway at the stale twist (here the load's, a whole T_s/K from the
    breakaway twist toward the move), which does not fit, and the stage stays out of that plateau (nominal box
    seed 1003 #1: a "closing breakaway" read at +2.0 T_s/K, the plateau left 2.9e-3 rad off; task h29a, docs §63)."""
    assert CONTROLLER_SPEC.defaults()["fine.drop_rest_at_engage"] is True
    # the hand-over at once (C1's): the new demand below arrives mid-observe, which fine.handover_settle_speed_rad_s
    # (C2) would first wait out with the gear output held
    fine, m = _stage(**{"fine.drop_rest_at_engage": drop, "fine.handover_settle_speed_rad_s": 0.0})
    p = m.pressure_max_kpa
    thl = 0.5
    _break_loose(fine, thl, p)                      # the main law's breakaway (toward open): it fits
    assert fine._breakaway_fits()
    target = thl + direction * 1e-3
    for _ in range(_patience(fine)):                # at rest on the load's twist: the stage engages
        if fine.update(target, thl + _rest_twist(fine, thl, p), thl, True, 0.3, p) is not None:
            break
    assert fine.phase == "park"
    moved = thl + direction * 0.8e-3                # the stage's own move (more than 2 tolerances)
    assert abs(moved - thl) > 2.0 * fine.cfg.tolerance_rad
    th1 = moved + _rest_twist(fine, moved, p)
    fine.update(target, th1, moved, True, 0.3, p)
    new = moved + direction * 1e-3                  # a new demand while the stage observes its move
    engaged = any(fine.update(new, th1, moved, True, 0.3, p) is not None for _ in range(_patience(fine)))
    assert engaged is drop
    d, phi = fine._breakaway_seen[:2]
    assert (d, phi) == ((1, pytest.approx(fine._nominal(thl, p, 1)[1], abs=1e-9)) if drop
                        else (direction, pytest.approx(_rest_twist(fine, thl, p), abs=1e-9)))


@pytest.mark.parametrize("direction", [1, -1])
@pytest.mark.parametrize("sigmas", [0.0, 1.0])
def test_after_two_preload_breakaways_a_staircase_starts_below_the_twist_it_broke_at(direction, sigmas):
    """Two servo-blended preloads that break the valve loose (toward the target, short of it) on one
    plateau: by default (``fine.restair_sigmas`` 0) the stage hands the plateau back to the main law;
    with ``fine.restair_sigmas`` > 0 it goes on with a doublet staircase whose first apex lies that many
    learned scatters below the preload reference the second one broke at (nominal box seed 2018 #1 was
    handed back 6.1e-3 rad off; task h30b, docs §66)."""
    fine, m = _main_stage(**{"fine.restair_sigmas": sigmas})
    p = m.pressure_max_kpa
    thl = 0.5
    phi = _rest_twist(fine, thl, p)
    target = thl + direction * 6e-3                       # a servo-blended pulse's error
    _break_loose(fine, thl, p)
    parks, breaks = 0, 0
    for _ in range(4000):
        was = fine.phase
        fine.update(target, thl + phi, thl, True, 0.3, p)
        if fine.phase == "park" and was != "park":
            parks, k = parks + 1, 0
        if fine.phase == "park":
            k += 1
            if k == 5 and breaks < 2:                     # it slides 1e-3 toward the target in the preload
                thl += direction * 1e-3
                breaks += 1
                continue
        if breaks == 2 and (fine.phase == "idle" or (fine.phase == "park" and parks == 3)):
            break
    assert breaks == 2
    if sigmas == 0.0:
        assert fine.phase == "idle" and fine._unfit        # handed back
        return
    assert fine.phase == "park" and fine._doublet          # a staircase instead
    d, ref = fine._restair
    assert d == direction
    phi_e, phi_b, band = fine._twists(thl, p, direction)
    apex = fine._pre + direction * fine._kick_rise()
    scatter = fine._scatter(direction, band, max(direction * (phi_b - phi_e), 1e-5))
    assert scatter > 0.0
    assert direction * (ref - apex) == pytest.approx(sigmas * scatter, rel=1e-9, abs=1e-12)
    assert direction * (fine._pre - fine._break_ref) < 0.0  # the preload lies below where it broke
