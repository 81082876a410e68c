"""The hold's learned friction and load (core/integral_policy.py, issue 14 Deliver 2/3): a wrong
Δp reading is only the prior of what the hold schedules on."""
import pytest

from fuel_valve_control.common.contract import PRESSURE_MAX_KPA
from fuel_valve_control.core.integral_policy import IntegralPolicy, JumpLearner, SlipEdges

LIMIT_NM = 24.9
POLICY = IntegralPolicy(0.55, 2.9e-4, relax_time_s=0.3, load_limit_nm=LIMIT_NM)
#: a valve at Δp 0 (static 0.5 N*m) under a 2.2 N*m load toward closed the model does not know
#: (e.g. the flow torque of a Δp reading at max), told the static level of max Δp (5.5 N*m)
LOAD, STATIC, TOLD_STATIC = -2.2, 0.5, 5.5


def test_one_slip_puts_the_load_a_fraction_of_the_scheduled_static_level_inside_it():
    opening_edge = LOAD + STATIC
    load = POLICY.learn_load(opening_edge, +1.0, TOLD_STATIC)
    assert load == pytest.approx(opening_edge - 0.5 * TOLD_STATIC)
    assert load < LOAD - STATIC          # the wrong schedule puts it beyond the band's other edge


def test_both_edges_give_the_load_whatever_the_schedule_says():
    edges = SlipEdges()
    assert edges.static_nm is None and edges.opposite(+1.0) is None
    edges.met(LOAD - STATIC, -1.0)                          # a closing slip at the lower edge
    assert edges.opposite(+1.0) == pytest.approx(LOAD - STATIC) and edges.opposite(-1.0) is None
    load = POLICY.learn_load(LOAD + STATIC, +1.0, TOLD_STATIC, 0.0, edges.opposite(+1.0))
    assert load == pytest.approx(LOAD)
    edges.met(LOAD + STATIC, +1.0)
    assert edges.static_nm == pytest.approx(STATIC)
    edges.reset()
    assert edges.static_nm is None


def test_an_opposite_edge_beyond_this_one_is_not_used():
    # the band moved since the other slip (its edge lies above this opening one): back to the prior
    load = POLICY.learn_load(LOAD + STATIC, +1.0, TOLD_STATIC, 0.0, LOAD + 2.0)
    assert load == pytest.approx(LOAD + STATIC - 0.5 * TOLD_STATIC)


def test_a_held_load_is_known_only_from_two_consistent_edges():
    """h19b: the breakaway start's retreat trusts a one-way breakaway reading net of the held load
    only when that load is known: both edges met and the opening one above the closing one.  None
    met (assumed 0), one edge (the scheduled level's prior) or contradictory edges (one of them
    was no edge of the band, campaign seeds 1022, 1029) each leave it off by up to the static level."""
    edges = SlipEdges()
    assert not edges.known
    edges.met(LOAD - STATIC, -1.0)
    assert not edges.known
    edges.met(LOAD - 2.0 * STATIC, +1.0)            # an "opening edge" below the closing one
    assert not edges.known
    edges.met(LOAD + STATIC, +1.0)
    assert edges.known
    edges.reset()
    assert not edges.known


def test_the_learned_load_stays_within_the_continuous_torque_with_both_edges():
    load = POLICY.learn_load(30.0, +1.0, TOLD_STATIC, 5.0, 28.0)
    assert load == pytest.approx(LIMIT_NM - 5.0)


@pytest.mark.parametrize("met, expected", [(None, TOLD_STATIC), (STATIC, STATIC), (0.01, 0.25), (9.0, TOLD_STATIC)])
def test_the_hold_schedules_on_the_friction_met_within_the_schedule_and_a_floor(met, expected):
    assert POLICY.hold_static_nm(TOLD_STATIC, met, 0.25) == pytest.approx(expected)


# ------------------------------------------------------------------ slips read as drift (h17w)
THRESHOLD = 2.9e-4          # rad, the integral policy's min_rad (3 valve resolver counts): a jump
CREEP = 3 * THRESHOLD       # rad, the default mode's creep threshold
RATE = 1.9e-5               # rad per 1 ms period: the 19 mrad/s creep of the grid's F x0.5 Δp 0 told-max cell


def _creep(watch, periods, net0=-1.4, dnet=0.002, rate=RATE, still=20):
    """``still`` settled periods at 0, then the valve creeps at ``rate`` per period while the
    relax keeps raising the drive by ``dnet`` per period; returns the first slip and its period."""
    net = net0
    for k in range(still + periods):
        valve = max(k - still, 0) * rate
        slip = watch.left(valve)
        if slip is not None:
            return slip, k
        watch.settled(net, valve)
        net += dnet
    return None, None


def test_a_creep_slower_than_the_stuck_speed_is_a_slip_with_the_drive_where_it_began():
    from fuel_valve_control.core.integral_policy import SlipWatch
    slip, k = _creep(SlipWatch(THRESHOLD, CREEP), 500)
    assert slip is not None
    net, moved = slip
    assert moved > CREEP and k <= 20 + CREEP / RATE + 1              # seen within ~46 ms of creeping
    # the drive torque of the slip is the one while the valve was still near its place (half the
    # creep threshold: ~23 periods of creep), not the one the relax had reached since
    assert net == pytest.approx(-1.4 + 0.002 * (20 + 0.5 * CREEP / RATE), abs=0.002 * 2)
    # read period to period only (the other modes) the same creep is never a slip
    assert _creep(SlipWatch(THRESHOLD), 2000)[0] is None
    # a jump is read period to period as before, with the drive of the period before
    watch = SlipWatch(THRESHOLD, CREEP)
    watch.settled(1.0, 0.0)
    watch.settled(1.1, 0.0)
    assert watch.left(4e-4) == (1.1, pytest.approx(4e-4))


def test_a_valve_at_rest_with_resolver_noise_does_not_slip():
    import numpy as np
    from fuel_valve_control.common.contract import RESOLVER_COUNT_RAD
    from fuel_valve_control.core.integral_policy import SlipWatch
    rng = np.random.default_rng(0)
    # 1.2 counts rms (the campaign's noisiest valve resolver), averaged over the speed window
    noise = rng.normal(0.0, 1.2 * RESOLVER_COUNT_RAD, 20_000 + 4)
    filtered = np.convolve(noise, np.ones(5) / 5, mode="valid")
    watch = SlipWatch(THRESHOLD, CREEP)
    for v in filtered:
        assert watch.left(float(v)) is None
        watch.settled(0.0, float(v))


@pytest.mark.parametrize("inertia", [0.8, 1.0, 1.2])
def test_a_valve_creeping_under_a_wrong_dp_reading_is_held_without_hunting(inertia):
    """Adaptation grid (``benchmarks/adaptation_grid.py --dp-error``), friction x 0.5 at Δp 0 told
    max: the fake flow torque (~2.2 N*m) is ~9x the valve's static friction, and the relax drove
    it beyond its band the way the drive pushes: it crept 19 mrad/s, below the stuck speed, to
    the 8 mrad deadband's edge, the integrator pulled it back and the relax sent it off again
    (tail peak-to-peak 7.4-8.4 mrad against an allowance of 0.4 mrad, ~1 Hz).  Read as drift from
    where it settled (:class:`SlipWatch`) the creep is a slip: the band's edges, so the load, are
    learned and the relax stops short of them."""
    from conftest import load_benchmark
    grid = load_benchmark("adaptation_grid")
    cell = {**grid.NOMINAL, "friction": 0.5, "inertia": inertia, "dp_kpa": 0.0, "stiffness": 1.0}
    r = grid.run_cell("observer_ff", cell, told_dp_kpa=PRESSURE_MAX_KPA)
    assert not r["fault"]
    assert r["tail_pp_rad"] <= r["hunting_allowance_rad"], r


def test_a_slip_contradicting_a_known_band_is_not_an_edge_of_it():
    """h19b, campaign seed 1082: edges at 1.1 (closing) and 3.73 N*m (opening) gave 2.41 N*m; the
    integrator's pull back after an overshoot then read as a closing slip at 4.48 N*m, beyond the
    opening edge.  Learned with the one-edge prior it put the load at 7.23 N*m (the next move
    started from a drive cocked 5 N*m open and ran 22 mrad past).  Such a slip contradicts a known
    band: not learned, the band unknown from then on (the next slip a first edge again)."""
    edges = SlipEdges()
    assert not edges.contradicts(4.48, -1.0)              # nothing known: every slip teaches
    edges.met(1.1, -1.0)
    assert not edges.contradicts(4.48, +1.0)              # one edge: not known either
    edges.met(3.73, +1.0)
    assert edges.known
    assert edges.contradicts(4.48, -1.0)                  # a closing "edge" above the opening one
    assert edges.contradicts(0.9, +1.0)                   # an opening "edge" below the closing one
    assert not edges.contradicts(0.9, -1.0)               # the band's own edges move: learned as before
    assert not edges.contradicts(3.9, +1.0)


# ------------------------------------------------------------------ jump learner (h19r)
JUMP, BAND = 4.6e-3, 2.5e-3          # rad: the nominal jump at max Δp and the deadband around it
CATCH_UP = 100                       # periods (0.1 s at 1 kHz): a slide this long was driven


def _slide(learner, start, end, periods, target=0.0):
    """A valve at rest at ``start`` (rad) breaks away while the hold holds ``target`` and comes
    to rest at ``end`` after sliding ``periods`` periods."""
    for _ in range(3):
        learner.update(start, True, True, JUMP, target, BAND)
    for k in range(1, periods):
        learner.update(start + (end - start) * k / periods, False, True, JUMP, target, BAND)
    learner.update(end, True, True, JUMP, target, BAND)


def test_a_catch_up_driven_onto_the_target_does_not_teach_a_larger_jump():
    # the cold start of `startup`: the first move ends with the valve stuck 3.8e-2 rad short,
    # the hold drives it onto the target (1.7e-3 short) in 0.126 s: read as a jump, 7.9x nominal
    learner = JumpLearner(catch_up_periods=CATCH_UP)
    _slide(learner, -3.8e-2, -1.7e-3, 126)
    assert learner.ratio == 1.0 and learner.ratio_toward(+1.0) == 1.0 and learner.catch_ups == 1
    old = JumpLearner()                  # the other modes: learned as before
    _slide(old, -3.8e-2, -1.7e-3, 126)
    assert old.ratio_toward(+1.0) == pytest.approx((3.8e-2 - 1.7e-3) / JUMP)


@pytest.mark.parametrize("start, end, periods", [
    (-3e-3, +2.6e-3, 10),       # a nominal jump across the target beyond the band
    (-1.05e-1, -2.7e-2, 30),    # flexible_worst (K x 0.1): stops by itself far short of the target
    (-3.8e-2, -1.7e-3, 20),     # as far as the catch-up, but a coupling's half swing long
    (-8.7e-3, -0.4e-3, 120),    # onto the target, but from within twice the jump known
])
def test_a_breakaway_that_is_no_catch_up_is_learned_as_a_jump(start, end, periods):
    learner = JumpLearner(catch_up_periods=CATCH_UP)
    _slide(learner, start, end, periods)
    assert learner.ratio_toward(+1.0) == pytest.approx((end - start) / JUMP) and learner.catch_ups == 0


def test_a_slide_the_law_did_not_see_end_is_not_learned():
    # observer_fp: the fine stage takes the plateau over while the valve slides, and hands it
    # back seconds later; what moved the valve in between was not the main law's hold
    learner = JumpLearner(catch_up_periods=CATCH_UP)
    for _ in range(3):
        learner.update(-3.8e-2, True, True, JUMP, 0.0, BAND)
    learner.update(-3.0e-2, False, True, JUMP, 0.0, BAND)
    learner.drop_slide()
    learner.update(0.3e-3, True, True, JUMP, 0.0, BAND)
    learner.update(0.3e-3, True, True, JUMP, 0.0, BAND)
    assert learner.ratio == 1.0 and not learner.directed


# ------------------------------------------------------------------ h21h: a breakaway in pieces
CHAIN = 30                            # periods (the hold's settle time, 0.03 s at 1 kHz)


def _breakaway_in_two_pieces(learner: JumpLearner, gap: int, band: float = 1.8e-3) -> JumpLearner:
    """Feed ``learner`` seed 1112's breakaway (rad from the target): at rest 3.8e-3 short, sliding
    to 0.3e-3 beyond, resting there ``gap`` periods inside the ``band``, sliding on to 2.5e-3."""
    for _ in range(3):
        learner.update(-3.8e-3, True, True, JUMP, 0.0, band)
    for v in (-2.0e-3, -0.5e-3):
        learner.update(v, False, True, JUMP, 0.0, band)
    for _ in range(gap):
        learner.update(0.3e-3, True, True, JUMP, 0.0, band)
    for v in (1.0e-3, 2.0e-3):
        learner.update(v, False, True, JUMP, 0.0, band)
    learner.update(2.5e-3, True, True, JUMP, 0.0, band)
    return learner


@pytest.mark.parametrize("gap, crossing", [(11, True), (2 * CHAIN, False)])
def test_a_breakaway_that_rests_on_the_way_is_one_crossing_to_the_breaker(gap, crossing):
    # campaign seed 1112: 3.8 mrad short, the valve jumps to 0.3 mrad beyond the target, rests
    # 11 ms inside the band and goes on to 2.5 mrad beyond it (outside the band): one 6.3 mrad
    # breakaway across the target.  Read as two pieces neither of which crossed, the breaker never
    # fired and the pieces pulled the learned jump down.  Pieces a settle time apart stay two.
    learner = _breakaway_in_two_pieces(JumpLearner(cross_hold=True, chain_periods=CHAIN), gap)
    assert learner.crossings == (1 if crossing else 0)
    whole = (2.5e-3 + 3.8e-3) / JUMP
    if crossing:
        assert learner.ratio_toward(+1.0) == pytest.approx(whole) and learner.ratio_toward(-1.0) == pytest.approx(whole)
    else:
        assert learner.ratio_toward(+1.0) < 0.9 * whole      # learned in pieces, as before
    # without the chain (main b059704): no crossing seen
    assert _breakaway_in_two_pieces(JumpLearner(cross_hold=True), gap).crossings == 0


# ------------------------------------------------------------------ h20w: a Δp reschedule
def test_a_dp_reschedule_keeps_the_held_load_and_the_band():
    """Campaign seed 1096 (Stribeck x 0.52, 9.4 N*m, Δp missing, told max, true 1.5 MPa): the
    cross-check rescheduled mid-move and the held 9.1 N*m went to 0; the hold hunted.  The valve's
    load did not change, only the part of it the schedule knows (the flow torque): the held load
    and the edges move by that change, the static friction met stays."""
    from fuel_valve_control.core.driver import ValveDriver
    from fuel_valve_control.core.params import load_controller_params
    from fuel_valve_control.core.signals import Measurement
    drv = ValveDriver(load_controller_params())
    law = getattr(drv.controller.law, "main", drv.controller.law)
    pos = 0.4 * law.model.stroke_rad
    meas = Measurement(pos * law.model.gear_ratio, pos)
    law.reset(meas, 0.0, PRESSURE_MAX_KPA)
    law.update(0.0, pos, meas, PRESSURE_MAX_KPA)
    law.held_load = 9.1
    law.slip_edges.met(7.0, -1.0)
    law.slip_edges.met(11.2, +1.0)
    static, known = law.slip_edges.static_nm, law.slip_edges.known
    total = law.model.load_torque(pos, PRESSURE_MAX_KPA) + law.held_load
    law.friction_rescheduled(438.0)
    assert law.model.load_torque(pos, 438.0) + law.held_load == pytest.approx(total)
    assert law.held_load > 9.1                           # less flow torque known: more held
    assert law.slip_edges.static_nm == pytest.approx(static) and law.slip_edges.known == known
    assert law.slip_edges.edges[1] - law.held_load == pytest.approx(11.2 - 9.1)


# ------------------------------------------------------------------ the soft coupling's floor probed (h26k)
def _soft_step(friction: float, probe: bool):
    """The adaptation grid's 2 % step (benchmarks/adaptation_grid.py) at max Δp on a coupling of
    K x 0.1, the controller not told: (metrics, step rad, tail peak-to-peak rad over the last
    second, hunting allowance rad)."""
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from control_quality import NOMINAL, corner_overrides, hunting_allowance

    from fuel_valve_control.tools import sim
    from fuel_valve_control.tools.scenarios import load_scenario
    sc = load_scenario("step_small")
    plant, _ = corner_overrides({**NOMINAL, "friction": friction, "stiffness": 0.1})
    p, c = sim.build(sc, plant, {"integral.probe_soft_floor": probe})
    res = sim.simulate(sc, p, c)
    step = [g for g in res.segments if g["kind"] == "step"][-1]
    t, pos = res.column("t"), res.column("position_rad")
    tail = pos[t >= t[-1] - 1.0]
    return res.metrics, step["to_rad"] - step["from_rad"], float(tail.max() - tail.min()), hunting_allowance(p)[1]


def test_a_low_friction_valve_on_a_soft_coupling_follows_the_step_with_the_probe():
    """K x 0.1, friction x 0.5, max Δp: the hold's jump floor read at the scheduled friction
    (2.56e-2 rad) exceeds the 2 % step (2.09e-2), so without the probe the valve never moves (its
    error the whole step; docs section 52); the probe's cap (4.5 N*m) is above this valve's
    breakaway (2.75 N*m): it lets go, lands 23 % beyond (floor 9.4 %) and stays, no hunting."""
    off, step, _, _ = _soft_step(0.5, probe=False)
    assert off["steady_state_error_rad"] == pytest.approx(step, rel=0.01)         # the cost measured
    on, step, tail, allowance = _soft_step(0.5, probe=True)
    assert on["steady_state_error_rad"] < 0.3 * step
    assert on["overshoot_pct"] < 30.0
    assert tail <= allowance
    assert on["peak_current_a"] <= 30.0


def test_the_probe_does_not_break_loose_a_valve_whose_jump_would_not_fit():
    """K x 0.1, friction x 1, max Δp: the valve's jump (4.6e-2 rad) is 2.2x the step, so letting it
    go could only land it farther beyond (119 % overshoot, main before the stiffness reading);
    the probe's cap (4.5 N*m) stays below its breakaway (5.5 N*m) and the valve stays."""
    on, step, tail, _ = _soft_step(1.0, probe=True)
    assert on["overshoot_pct"] == 0.0
    assert on["steady_state_error_rad"] == pytest.approx(step, rel=0.01)
    assert tail < 1e-3


# ------------------------------------------------------------------ a deadband wider than the friction met (h30h)
def _heavy_valve_run(probe: bool, unchain: bool = False) -> dict:
    """Nominal-box campaign seed 2001 (benchmarks/robustness.py) on a plant with 1.5x the told
    friction, the controller not told: the robustness run's record."""
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    import robustness as rb

    from fuel_valve_control.core.params import DEFAULT_MODE
    case = {**rb.sample_case(2001, "nominal"), "friction_scale": 1.5}
    return rb.run_case((case, DEFAULT_MODE, {"integral.probe_shown_friction": probe,
                                             "integral.unchain_rewound": unchain}))


def test_a_heavier_valve_held_inside_a_widened_deadband_is_probed_loose():
    """Friction x 1.5, seed 2001, plateau 7 (a 9.2 mrad opening step): a chained breakaway (10 mrad,
    then a 6.7 mrad piece the gear output's swing drove) set the crossing breaker's jump to 3.66
    nominal both ways, a 9.23e-3 rad deadband; the step's move did not break the valve loose and
    the hold relaxed its 8.4e-3 rad error for the whole plateau (docs section 68).  The friction
    met (8.85 N*m, the x 1.5) gives a 3.8e-3 rad deadband: probed up to the drive whose
    quasi-static jump that would hold, the valve lets go and ends within 2e-3 rad (1.1e-3; with
    the option off, the default, 8.39e-3: one run only, to keep the suite cheap)."""
    on = _heavy_valve_run(True)
    assert on["plateaus"][7]["final_error_rad"] < 2e-3
    assert not on["hunts"] and not on["fault"] and on["peak_current_a"] <= 30.0


def test_a_piece_the_drive_wound_up_again_is_no_rest_of_the_breakaway_before():
    """The same heavier valve (friction x 1.5, seed 2001) with ``integral.unchain_rewound``: on
    plateau 6 the 6.7 mrad piece started after the gear output wound the coupling up again by
    4.8 mrad (> half the 4.6 mrad nominal jump) from the lowest twist since the 10.1 mrad jump
    before it; not joined to it, no 16.8 mrad crossing widens both ways to 3.66 nominal, and
    plateau 7's 9.2 mrad step is no longer inside the deadband: 1.7e-3 rad (off, the default:
    8.39e-3; docs section 71).  One run, ~2.5 s CPU."""
    on = _heavy_valve_run(False, unchain=True)
    assert on["plateaus"][7]["final_error_rad"] < 3e-3
    assert not on["hunts"] and not on["fault"] and on["peak_current_a"] <= 30.0


def test_the_chain_still_joins_a_piece_the_drive_did_not_wind():
    """JumpLearner alone, chain and ``unchain_rewound`` on, nominal jump 4 mrad, band 2.2 mrad: a
    4 mrad jump crosses the target and comes to rest 1 mrad beyond it (inside the band), then a
    4 mrad piece the same way lands 5 mrad beyond.  With the coupling's twist only unwound by the
    valve's travel (the first jump's unspent twist going on, seed 1112's case) the pieces are one
    8 mrad crossing: both ways 2.0 nominal.  With the gear output winding the twist up again by
    3 mrad (> half the nominal jump) while the valve rests beyond the target, the piece is the
    drive's overtravel, not joined: no crossing, the ratio stays the jumps' own (1.0)."""
    from fuel_valve_control.core.integral_policy import JumpLearner

    def learner(rewind: float) -> JumpLearner:
        j = JumpLearner(cross_hold=True, chain_periods=50, unchain_rewound=True)
        path = ([(-3e-3, True)] * 5 + [(-1e-3, False), (1e-3, False)] + [(1e-3, True)] * 10
                + [(3e-3, False), (5e-3, False)] + [(5e-3, True)] * 3)
        twist, before = 0.040, path[0][0]
        for i, (valve, stuck) in enumerate(path):
            twist -= valve - before                       # the valve's travel unwinds the coupling
            before = valve
            if 7 <= i < 17:
                twist += rewind / 10.0                    # the gear output winds it up again (or not)
            j.update(valve, stuck, True, 4e-3, 0.0, 2.2e-3, True, None, twist)
        return j

    unspent, rewound = learner(0.0), learner(3e-3)
    assert unspent.crossings == 1 and unspent.ratio_toward(-1) == pytest.approx(2.0)
    assert rewound.crossings == 0 and rewound.ratio_toward(-1) == pytest.approx(1.0)


# ------------------------------------------------------------------ the chained crossing bounded by the friction met (h32b)
def _chained_crossing(margin: float, drive_ratio: float | None) -> JumpLearner:
    """JumpLearner alone, chain on, nominal jump 4 mrad, band 2.2 mrad: a 4 mrad jump crosses the
    target and rests 1 mrad beyond it (inside the band), then a 4 mrad piece the same way lands
    5 mrad beyond: one 8 mrad crossing (2.0 nominal).  The drive on the valve while it was at rest
    before each piece is handed as its quasi-static jump ratio (``drive_ratio``, signed, + opening:
    both pieces open)."""
    j = JumpLearner(cross_hold=True, chain_periods=50, cross_met_margin=margin)
    path = ([(-3e-3, True)] * 5 + [(-1e-3, False), (1e-3, False)] + [(1e-3, True)] * 10
            + [(3e-3, False), (5e-3, False)] + [(5e-3, True)] * 3)
    for valve, stuck in path:
        j.update(valve, stuck, True, 4e-3, 0.0, 2.2e-3, True, None, None,
                 drive_ratio)
    return j


def test_a_chained_crossing_widens_no_further_than_the_drive_at_let_go_allows():
    """``integral.cross_ratio_from_met`` (h32b): the chain's 8 mrad (2.0 nominal) is what the breaker
    sets both ways without a bound, or without a drive reading; with the drive at let-go a
    quasi-static 1.1 nominal jump and the margin 1.5, at most 1.65 nominal -- but never less than
    the last piece made alone (1.0: a drive of 0.5 nominal bounds it there)."""
    assert _chained_crossing(0.0, 1.1).ratio_toward(1) == pytest.approx(2.0)      # off: main's chain
    assert _chained_crossing(1.5, None).ratio_toward(1) == pytest.approx(2.0)     # no drive read: unbounded
    bounded = _chained_crossing(1.5, 1.1)
    assert bounded.crossings == 1 and bounded.met_bounded == 1
    assert bounded.ratio_toward(1) == pytest.approx(1.65) and bounded.ratio_toward(-1) == pytest.approx(1.65)
    assert _chained_crossing(1.5, 0.5).ratio_toward(1) == pytest.approx(1.0)
    assert _chained_crossing(1.5, 2.0).met_bounded == 0                          # 3.0 allowed: the chain's 2.0


def test_a_crossing_widens_the_band_only_until_the_next_move():
    """``integral.cross_until_move`` (h32b): the chained 8 mrad crossing (2.0 nominal both ways) holds
    the deadband at the target crossed; a planned move (``holding`` false: a new demand) returns
    both ways to the jumps' own ratios (the two 4 mrad pieces: 1.0).  Off, the widening stays."""
    def after_move(keep: bool) -> JumpLearner:
        j = _chained_crossing(0.0, None)
        j.cross_until_move = keep
        assert j.crossings == 1 and j.ratio_toward(-1) == pytest.approx(2.0)
        j.update(5e-3, False, False, 4e-3)        # a planned move starts
        return j
    assert after_move(False).ratio_toward(-1) == pytest.approx(2.0)
    moved = after_move(True)
    assert moved.ratio_toward(1) == pytest.approx(1.0) and moved.ratio_toward(-1) == pytest.approx(1.0)


# ------------------------------------------------------------------ the widening kept after repeated crossings (h32f)
def _crossed_then_moved(times: int, keep_after: int, until_move: bool = False) -> JumpLearner:
    """The chained 8 mrad crossing (2.0 nominal both ways, the jumps' own 1.0), ``times`` = 2 adds a
    second crossing of the same target the other way (rest 5 mrad beyond, one 8 mrad jump to 3 mrad
    short), then a planned move starts (``holding`` false)."""
    j = _chained_crossing(0.0, None)
    j.cross_keep_after, j.cross_until_move = keep_after, until_move
    if times == 2:
        for valve, stuck in [(5e-3, True)] * 40 + [(3e-3, False), (-1e-3, False)] + [(-3e-3, True)] * 3:
            j.update(valve, stuck, True, 4e-3, 0.0, 2.2e-3)
    assert j.crossings == times
    j.update(-3e-3, False, False, 4e-3)
    return j


def test_a_crossing_widening_is_kept_across_moves_only_once_the_valve_crossed_repeatedly():
    """``integral.cross_keep_after`` (h32f): with 2, one crossing's widening ends at the next planned
    move (as ``cross_until_move``: both ways back to the jumps' own 1.0), but after a second crossing
    the valve's jumps are taken to be that long and the 2.0 holds across the move.  Off (0, main),
    one crossing's widening stays; ``cross_until_move`` alone returns it after two crossings too."""
    once = _crossed_then_moved(1, 2)
    assert once.ratio_toward(1) == pytest.approx(1.0) and once.ratio_toward(-1) == pytest.approx(1.0)
    twice = _crossed_then_moved(2, 2)
    assert twice.ratio_toward(1) == pytest.approx(2.0) and twice.ratio_toward(-1) == pytest.approx(2.0)
    assert _crossed_then_moved(1, 0).ratio_toward(-1) == pytest.approx(2.0)            # off: main keeps
    assert _crossed_then_moved(2, 0, until_move=True).ratio_toward(1) == pytest.approx(1.0)
    assert _crossed_then_moved(1, 3).ratio_toward(-1) == pytest.approx(1.0)


def test_a_move_keeps_the_widening_toward_a_way_no_jump_was_measured_in():
    """``integral.cross_keep_unmet`` (h32f): the chained crossing's two pieces both open, so the
    closing way's "own" ratio is only their mean.  A planned move under ``cross_until_move`` returns
    the opening way to its measured 1.0, and with the option keeps the unmet closing way at the
    crossing's 2.0 (full box 1190: the unmet way 6.27 -> 3.64 brought a second, 8.17 crossing)."""
    def moved(keep_unmet: bool) -> JumpLearner:
        j = _chained_crossing(0.0, None)
        j.cross_until_move, j.cross_keep_unmet = True, keep_unmet
        assert j.met == {1}
        j.update(5e-3, False, False, 4e-3)
        return j
    kept = moved(True)
    assert kept.ratio_toward(1) == pytest.approx(1.0) and kept.ratio_toward(-1) == pytest.approx(2.0)
    assert moved(False).ratio_toward(-1) == pytest.approx(1.0)
