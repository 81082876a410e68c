"""The coupling stiffness read at every hold (``integral.read_stiffness``, h24k, docs section 41).

The plant's coupling may be softer than the controller's model (issue 14 Deliver 2: the same
gains over stiffness x 0.1 / 0.3 ... 1, the controller not told).  At rest the coupling carries
the drive, so the twist of the two resolvers against the applied torque reads K; beyond that
reading's scatter the hold's jump floor and the planned moves' coupling-snap feed-forward are
sized on it.  Unit tests of the reader, then the adaptation grid's cells the reading cures
(each one ``step_small`` run, ~0.5 s)."""
from __future__ import annotations

import pytest

from fuel_valve_control.common.contract import RESOLVER_COUNT_RAD
from fuel_valve_control.core.compensation import HoldStiffness
from fuel_valve_control.core.model import NominalModel
from fuel_valve_control.core.params import CONTROLLER_SPEC

P_MAX = 6206.0
TWO_COUNTS = 2.0 * RESOLVER_COUNT_RAD


def _model() -> NominalModel:
    return NominalModel.from_params(CONTROLLER_SPEC.defaults())


def _reader(m: NominalModel) -> HoldStiffness:
    return HoldStiffness(m.coupling_stiffness_nm_per_rad, m.gear_ratio, m.motor_static_nm, RESOLVER_COUNT_RAD,
                         rest_periods=20)


def _rest(h: HoldStiffness, m: NominalModel, valve_nm: float, k_true: float, periods: int = 20,
          gear_friction_nm: float = 0.0):
    """``periods`` at rest with ``valve_nm`` (N*m, valve side) through a coupling of ``k_true``;
    the drive also carries ``gear_friction_nm`` (motor side) of the gear's static friction."""
    twist = valve_nm / k_true
    out = None
    for _ in range(periods):
        r = h.update(True, twist, valve_nm / m.gear_ratio + gear_friction_nm)
        out = r if r is not None else out
    return out


def test_a_hold_reads_the_coupling_and_acts_only_beyond_its_scatter():
    m = _model()
    k = m.coupling_stiffness_nm_per_rad
    h = _reader(m)
    # the model's coupling, the gear's static friction against the reading: read ~1, not acted on
    r = _rest(h, m, 9.0, k, gear_friction_nm=m.motor_static_nm)
    assert r == pytest.approx(k / (k * (1.0 + m.gear_ratio * m.motor_static_nm / 9.0)), rel=1e-9)
    assert h.misfit == 1.0
    # a rest ended before rest_periods gives nothing; a new rest reads again
    h.update(False, None, 0.0)
    assert _rest(h, m, 9.0, k, periods=19) is None
    h.update(False, None, 0.0)
    # K x 0.3 (the box's soft couplings): read within the gear friction's share, acted on
    h.reset()
    r = _rest(h, m, 9.0, 0.3 * k, gear_friction_nm=-m.motor_static_nm)
    assert r == pytest.approx(1.0 / 0.3, rel=0.06)
    assert h.misfit == h.softness == r
    # a drive too small to read against the gear's friction (bound > max_bound): no reading
    h.reset()
    assert _rest(h, m, 0.5, 0.3 * k) is None and h.misfit == 1.0


def test_a_coupling_near_the_models_is_not_acted_on_whatever_its_reading_scatter():
    """h25k: campaign seed 1195 (K x 0.77 = softness 1.29) read 1.21-1.42 at bounds 0.07-0.14;
    at h24k's tolerance 0.25 the estimate crossed the gate at 1.40 and the jump floor made the
    first plateau hunt.  The default tolerance (0.5) leaves such a coupling to the model-based
    loop; the grid's K x 0.5 (softness 2) is still acted on."""
    m = _model()
    k = m.coupling_stiffness_nm_per_rad
    # 1195's drive (~13 N*m at the valve) with the gear's static friction making it read 9 % soft
    h = _reader(m)
    r = _rest(h, m, 13.0, k / 1.29, gear_friction_nm=-0.5 * m.motor_static_nm)
    assert r is not None and h.last[1] < 0.16 and r > 1.29
    assert h.misfit == 1.0
    old = HoldStiffness(k, m.gear_ratio, m.motor_static_nm, RESOLVER_COUNT_RAD, rest_periods=20, tolerance=0.25)
    _rest(old, m, 13.0, k / 1.29 / 1.09)          # the 1.40 the campaign's estimate reached
    assert old.misfit == old.softness > 1.25     # h24k's gate: acted on
    h.reset()
    _rest(h, m, 13.0, 0.5 * k)
    assert h.misfit == h.softness == pytest.approx(2.0, rel=1e-9)
    assert CONTROLLER_SPEC.defaults()["integral.stiffness_tolerance"] == h.tolerance


def test_readings_persist_and_move_the_estimate_halfway():
    m = _model()
    k = m.coupling_stiffness_nm_per_rad
    h = _reader(m)
    _rest(h, m, 9.0, 0.25 * k)
    h.update(False, None, 0.0)
    _rest(h, m, 9.0, 0.5 * k)
    assert h.readings == 2
    assert h.softness == pytest.approx((4.0 * 2.0) ** 0.5, rel=1e-9)    # the logarithm halfway
    h.reset()
    assert (h.softness, h.misfit, h.readings) == (1.0, 1.0, 0)


# ===================================================== in the loop (step_small, the default mode)
def _cell(friction: float, dp: float, stiffness: float, inertia: float = 1.0, read: bool = True, **controller):
    """One adaptation-grid cell (benchmarks/adaptation_grid.py): the 2 % step on a plant of
    ``stiffness`` x the model's coupling, the controller not told; (metrics, tail peak-to-peak
    rad, hunting allowance rad, learned state)."""
    import sys
    from pathlib import Path
    root = Path(__file__).resolve().parents[1]
    sys.path.insert(0, str(root / "benchmarks"))
    from control_quality import NOMINAL, corner_overrides, hunting_allowance

    from fuel_valve_control.tools import sim
    from fuel_valve_control.tools.scenarios import load_scenario
    sc = load_scenario("step_small")
    plant, _ = corner_overrides({**NOMINAL, "friction": friction, "inertia": inertia, "dp_kpa": dp,
                                 "stiffness": stiffness})
    p, c = sim.build(sc, plant, {"integral.read_stiffness": read, **controller})
    seen = {}
    exchange = sim.exchange_period

    def watched(driver, plant_, t, demand_pct):
        seen["driver"] = driver
        return exchange(driver, plant_, t, demand_pct)

    sim.exchange_period = watched
    try:
        res = sim.simulate(sc, p, c)
    finally:
        sim.exchange_period = exchange
    t, pos = res.column("t"), res.column("position_rad")
    tail = pos[t >= t[-1] - 1.0]
    return res.metrics, float(tail.max() - tail.min()), hunting_allowance(p)[1], \
        seen["driver"].controller.law.learned_state()


def test_k03_at_dp0_the_linear_loop_no_longer_overshoots():
    """K x 0.3, Δp 0 (tiny friction): the overshoot was the move against the model's coupling
    (12.5 % on main; the coupling-snap feed-forward on K_model / K read at the first hold)."""
    m, pp, allowance, learned = _cell(1.0, 0.0, 0.3)
    assert 1.0 / 0.3 * 0.9 <= learned["coupling_softness"] <= 1.0 / 0.3 * 1.1
    assert m["overshoot_pct"] <= 10.0            # main (read_stiffness off): 12.5 %
    assert pp <= allowance
    assert m["peak_current_a"] <= 30.0


def test_k03_low_friction_max_dp_no_longer_hunts():
    """F x 0.5, max Δp, J +20 %, K x 0.3: main's tail was 1.26x the jump + 2 counts."""
    m, pp, allowance, _ = _cell(0.5, P_MAX, 0.3, inertia=1.2)
    assert pp <= allowance
    assert m["peak_current_a"] <= 30.0


def test_k01_dp0_step_within_10_pct_under_the_current_cap():
    """K x 0.1, Δp 0: 25.1 % on main; the snap feed-forward sized on the read softness (~10)
    asked 31-35 A until cut at ``fine.peak_current_a``."""
    m, pp, allowance, _ = _cell(1.0, 0.0, 0.1)
    assert m["overshoot_pct"] <= 10.0
    assert m["peak_current_a"] <= 30.0
    assert pp <= allowance


@pytest.mark.xfail(strict=True, reason="F x 3, max Δp, K x 0.3: the stick-slip jump 2 (Ts - Tc)/K is 4.6e-2 "
                   "rad, 2.2x the 2 % step (overshoot floor 119 %); the move overshoots 130 % and the tail "
                   "is 1.06x the jump + 2 counts with or without the reading (the physical floor)")
def test_k03_high_friction_max_dp_stays_at_the_jump_floor():
    m, pp, allowance, _ = _cell(3.0, P_MAX, 0.3)
    assert pp <= allowance


def test_campaign_1195_soft_play_coupling_near_the_model_does_not_hunt_with_the_reading():
    """Full-box seed 1195 (LuGre x 2.4, K x 0.77, 1.6 mrad backlash, beyond rating, no fault) with
    ``integral.read_stiffness``: at h24k's tolerance 0.25 the first plateau overshot 575 % and
    hunted (main 98 %, no hunt).  One campaign run (~2 s)."""
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    import robustness as rb

    from fuel_valve_control.core.params import DEFAULT_MODE
    r = rb.run_case((rb.sample_case(1195), DEFAULT_MODE, {"integral.read_stiffness": True}))
    assert not r["hunts"] and not r["fault"]
    assert r["plateaus"][0]["overshoot_pct"] < 150.0


# ------------------------------------------------ the snap term from the plan, fitted to the cap (h27k, section 57)
def _snap_comp(cap_nm: float):
    from fuel_valve_control.core.compensation import ReferenceFeedforward
    from fuel_valve_control.core.friction_observer import FrictionObserver
    T = 1e-3
    fps = (FrictionObserver(0.1, 1.0, 100.0, 0.0, T), FrictionObserver(0.1, 1.0, 100.0, 0.0, T))
    c = ReferenceFeedforward(*fps, 0.01, 0.03, False, 1.0, T, snap_fit_cap=True, snap_cap_nm=cap_nm)
    m = _model()
    c.reset(m, 0.0)
    c.coupling.softness = 10.0                      # K x 0.1, read in a wind-up
    return c, m


def _fed(c, move, lead: float):
    """The snap terms (motor N*m) fed over ``move``'s clocked periods, and the contexts."""
    from fuel_valve_control.core.compensation import Context
    out = []
    for k in range(1, int(round(move.duration / c.period))):
        t = k * c.period
        a = move.sample(t + lead)[2]
        ctx = Context(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, a, True, 0.0, False, move=move, move_time=t + lead)
        out.append(c._coupling_snap(ctx))
    return out


def test_the_planned_snap_term_starts_with_the_moves_own_positive_snap():
    """h26k (section 52): the sampled term's history started empty, so an opening move's first,
    positive snap was never fed and the first term fed was negative.  From the plan the first term
    is the start's (positive), and the term keeps the plan's shape.  Fails on main (no such option)."""
    from fuel_valve_control.core.trajectory import Move
    c, m = _snap_comp(cap_nm=1e9)
    move = Move.plan(0.2, 0.2 + 0.02 * m.stroke_rad, 10.0, 1e4, 0.02)        # a 2 % step: two 10 ms ramps
    fed = _fed(c, move, lead=0.0)
    assert fed[0] > 0.0 and c.snap_factor == 1.0
    mid = int(round(move.accel_time / 2.0 / c.period)) - 1                   # the first ramp's middle
    assert fed[mid] < 0.0 and fed[-1] < 0.0                                  # ... and the move's end
    assert max(fed) == pytest.approx(-min(fed), rel=0.05)


def test_the_planned_snap_term_is_scaled_whole_to_fit_the_cap():
    """A cap below the plan's peak snap term (plus the move's static friction feed-forward): one factor
    for the move, every period's term that factor of the unscaled one, the peak within the cap."""
    from fuel_valve_control.core.trajectory import Move
    move = Move.plan(0.2, 0.2 + 0.02 * _model().stroke_rad, 10.0, 1e4, 0.02)
    free, _ = _snap_comp(cap_nm=1e9)
    unscaled = _fed(free, move, lead=0.0)
    c, m = _snap_comp(cap_nm=0.3)
    fed = _fed(c, move, lead=0.0)
    fl = m.friction(0.0)
    friction = fl.motor_static_nm + fl.valve_static_nm / m.gear_ratio
    assert 0.0 < c.snap_factor < 1.0
    assert all(f == pytest.approx(c.snap_factor * u, rel=1e-9, abs=1e-12) for f, u in zip(fed, unscaled))
    assert max(abs(f) for f in fed) + friction <= 0.3 * 1.001


def test_k01_low_friction_dp0_light_drivetrain_ends_within_its_jump_with_the_planned_snap():
    """K x 0.1, F x 0.5, Δp 0, J -20 % (the box corner that was a strict xfail in test_closed_loop.py):
    the clipped sampled snap dragged the valve 8 mrad back and it stopped 2.49e-3 rad off (section 52); the
    planned term: 1.3e-3 rad, inside the jump + 2 counts (2.28e-3), within the current cap."""
    m, pp, allowance, _ = _cell(0.5, 0.0, 0.1, inertia=0.8, **{"ff.snap_fit_cap": True})
    assert m["steady_state_error_rad"] <= allowance
    assert m["overshoot_pct"] <= 10.0
    assert pp <= allowance
    assert m["peak_current_a"] <= 30.0
