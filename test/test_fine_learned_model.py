"""The fine stage on the friction its valve shows (``fine.learned_scale_min/max``, task h26f, docs §50):
the friction scale and steady load read from the main law's breakaways from rest, and the stage
planning from them -- or staying with the told model where that fits, the scale lies outside the
range, or the planned breakaway is held near the continuous rating."""
import numpy as np
import pytest

from fuel_valve_control.core.fine_positioning import SCALE_HOLD_FRACTION
from fuel_valve_control.core.params import CONTROLLER_SPEC
from fuel_valve_control.core.position_controller import PositionController

#: the option as §50 measured it (the median read); OFF: the told model only (main before task h29f)
ON = {"fine.learned_scale_min": 0.5, "fine.learned_scale_max": 2.0, "fine.learned_one_sample": False}
OFF = {"fine.learned_scale_min": 1.0, "fine.learned_scale_max": 1.0, "fine.learned_one_sample": False}


def _stage(**changes):
    pc = PositionController(CONTROLLER_SPEC.defaults().replace({"mode": "observer_fp", **changes}))
    return pc.law.fine


def _twist(m0, thl, p, direction, scale, load):
    """The breakaway twist (rad) toward ``direction`` of a valve with friction x ``scale`` and a steady
    load ``load`` x T_s(Δp) beyond the told one, on the told coupling."""
    ts = m0.friction(p).valve_static_nm
    return (m0.load_torque(thl, p) + direction * scale * ts + load * ts) / m0.coupling_stiffness_nm_per_rad


def _break(fine, thl, p, direction, scale, load=0.0):
    """Let the stage watch the main law break such a valve loose from rest at ``thl`` toward ``direction``."""
    phi = _twist(fine.m0, thl, p, direction, scale, load)
    far = thl + direction * 2.0 * fine.cfg.max_move_rad          # a demand the stage leaves to the main law
    for _ in range(fine.cfg.engage_periods + 2):
        fine.update(far, thl + phi, thl, False, 0.3, p)
    moved = thl + direction * 3.0 * fine.cfg.tolerance_rad
    fine.update(far, moved + phi, moved, False, 0.3, p)


def _engages(fine, thl, p, err, scale, load=0.0) -> bool:
    """Whether the stage takes over the valve at rest at ``thl`` (twist: the centre of its static band)
    ``err`` short of a steady target, having last seen it break loose toward the error."""
    from fuel_valve_control.core.fine_positioning import FRESH_WAIT
    d = 1 if err > 0 else -1
    _break(fine, thl, p, d, scale, load)
    m0 = fine.m0
    th1 = thl + (m0.load_torque(thl, p) + load * m0.friction(p).valve_static_nm) / m0.coupling_stiffness_nm_per_rad
    return any(fine.update(thl + err, th1, thl, True, 0.3, p) is not None
               for _ in range((FRESH_WAIT + 3) * fine.cfg.engage_periods))


def _read(fine, thl, p, scale, load=0.0):
    for d in (1, -1, 1, -1):
        _break(fine, thl, p, d, scale, load)


@pytest.mark.parametrize("scale, load", [(1.9, 0.0), (0.6, 0.0), (1.7, 0.2), (1.0, 0.5)])
def test_the_stage_reads_the_friction_scale_and_load_its_valve_breaks_loose_at(scale, load):
    """Friction x0.6-2 (or a coupling that much softer), an unknown steady load: the ratios (φ K - load) / T_s
    of the main law's breakaways are ``±s + l``; read both ways, the stage plans from friction x s and the
    load, and engages on a valve whose breakaways the told model puts 0.4-1 T_s/K off (today it stays out)."""
    p = 6000.0
    off, on = _stage(**OFF), _stage(**ON)
    thl = 0.1
    for fine in (off, on):
        _read(fine, thl, p, scale, load)
    assert off.applied_scale is None and off.m is off.m0
    s, l = on.applied_scale
    assert s == pytest.approx(scale, abs=1e-6) and l == pytest.approx(load, abs=1e-6)
    assert on.m.friction(p).valve_static_nm == pytest.approx(scale * on.m0.friction(p).valve_static_nm)
    for err in (1.5e-3, -1.5e-3):
        assert not _engages(off, thl, p, err, scale, load)
        assert _engages(on, thl, p, err, scale, load)
        on.reset(), off.reset()


@pytest.mark.parametrize("scale, load", [(2.8, 0.0), (0.4, 0.0), (1.1, 0.1), (1.5, 1.5)])
def test_the_stage_keeps_the_told_model_outside_the_range_or_where_it_fits(scale, load):
    """Friction x2.8 or x0.4 lies outside [0.5, 2]; x1.1 with a small load fits the told model (every
    breakaway within ``fine.breakaway_fit`` x T_s/K); a load of 1.5 T_s beyond the told one exceeds
    ``fine.learned_load_max``: the stage plans from the told model, as today."""
    fine = _stage(**ON)
    _read(fine, 0.1, 6000.0, scale, load)
    assert fine.applied_scale is None and fine.m is fine.m0


def test_a_scale_read_is_forgotten_with_the_learning_and_replaced_when_the_valve_changes():
    pc = PositionController(CONTROLLER_SPEC.defaults().replace({"mode": "observer_fp", **ON}))
    fine, p = pc.law.fine, 6000.0
    _read(fine, 0.1, p, 1.9)
    assert fine.applied_scale[0] == pytest.approx(1.9)
    for _ in range(8):                                   # the valve changes: friction x0.6
        _read(fine, 0.1, p, 0.6)
    assert fine.applied_scale[0] == pytest.approx(0.6, rel=0.15)     # (re-planned on a change > SCALE_REPLAN)
    pc.reset_learning()
    assert fine.applied_scale is None and fine.m is fine.m0


def test_on_a_scale_read_the_stage_stays_out_of_a_breakaway_held_near_the_continuous_rating():
    """Friction x1.9 with the valve nearly open: the planned breakaway takes more than SCALE_HOLD_FRACTION of
    the continuous current to hold, and pulses on top of that hold heat the I2t budget -- the main law keeps
    the plateau; nearly closed, the stage engages."""
    fine = _stage(**ON)
    m0, p = fine.m0, 6000.0
    amps = lambda thl: (m0.coupling_stiffness_nm_per_rad * _twist(m0, thl, p, 1, 1.9, 0.0)
                        / (m0.gear_ratio * m0.torque_constant_nm_per_a))
    cont = CONTROLLER_SPEC.defaults()["limits.continuous_current_a"]
    high, low = 0.9, 0.1
    assert amps(high) > SCALE_HOLD_FRACTION * cont > amps(low)
    _read(fine, low, p, 1.9)
    assert not _engages(fine, high, p, 1.5e-3, 1.9)
    fine.reset()
    assert _engages(fine, low, p, 1.5e-3, 1.9)


@pytest.mark.slow
def test_a_low_friction_valves_plateaus_are_finished_by_the_stage(robustness_bench):
    """Nominal-box run 2000 on a valve with friction x0.6 (nothing else off-nominal): the told model does not
    fit its breakaways, so today the stage stays out and the main law's hold ends the plateaus ~1.7e-3 rad off
    (median); planning from the scale it reads, the stage ends them closer, without hunting or a fault."""
    case = {**robustness_bench.sample_case(2000, "nominal"), "friction_scale": 0.6}
    runs = {name: robustness_bench.run_case((case, "observer_fp", sets)) for name, sets in
            (("off", OFF), ("on", ON))}
    err = {name: np.median([pl["final_error_rad"] for pl in r["plateaus"]]) for name, r in runs.items()}
    assert err["on"] < 0.5 * err["off"]
    assert not runs["on"]["hunts"] and not runs["on"]["fault"]


ONE = {**ON, "fine.learned_one_sample": True}


@pytest.mark.parametrize("scale, load", [(0.6, 0.0), (1.7, 0.2)])
def test_with_fine_learned_one_sample_one_breakaway_each_way_is_read(scale, load):
    """``fine.learned_one_sample`` (task h28f): the first breakaway each way is read when plausible --
    without it two each way are needed (the median read, docs §50)."""
    p, thl = 6000.0, 0.1
    two, one = _stage(**ON), _stage(**ONE)
    for fine in (two, one):
        _break(fine, thl, p, 1, scale, load)
        _break(fine, thl, p, -1, scale, load)
    assert two.applied_scale is None
    s, l = one.applied_scale
    assert s == pytest.approx(scale, abs=1e-6) and l == pytest.approx(load, abs=1e-6)


def test_with_fine_learned_one_sample_an_opening_ratio_below_the_closing_one_is_not_read():
    """Run 1036's outlier (docs §50): an opening "breakaway" at -0.40 against a closing one at -1.0 reads
    friction x0.3, outside the range; one below the closing one (-1.2) is no breakaway toward opening at
    all: the stage keeps the told model until more breakaways agree."""
    p, thl = 6000.0, 0.1
    fine = _stage(**ONE)
    _break(fine, thl, p, -1, 1.0)                        # closing at -1.0 T_s
    _break(fine, thl, p, 1, -1.0, 0.6)                   # "opening" at -1.0 + 0.6 = -0.4
    assert fine.applied_scale is None and fine.m is fine.m0
    fine = _stage(**ONE)
    _break(fine, thl, p, -1, 1.0)
    _break(fine, thl, p, 1, -1.0, -0.2)                  # "opening" at -1.2, below the closing -1.0
    assert not fine._plausible_ratio(1, fine._ratios[1][0])
    assert fine.applied_scale is None and fine.m is fine.m0


def test_by_default_the_stage_plans_only_from_a_friction_scale_above_the_told_one():
    """Task h29f (docs §64): the default reads the scale both ways (one breakaway each, as ``fine.learned_one_sample``)
    but plans from it only for s in [1, 2]: on the full box the seven runs whose read lay below 1 (1010: LuGre
    x0.58, read 0.57 -- the scale was right; 1112, 1183, 1137, 1162 ...) summed +25.7e-3 rad of plateau error,
    the four above 1 -36e-3.  Friction x0.6 keeps the told model, x1.7 with a load 0.2 T_s is read."""
    p, thl = 6000.0, 0.1
    low, high = _stage(), _stage()
    for fine, scale, load in ((low, 0.6, 0.0), (high, 1.7, 0.2)):
        _break(fine, thl, p, 1, scale, load)
        _break(fine, thl, p, -1, scale, load)
    assert low.applied_scale is None and low.m is low.m0
    s, l = high.applied_scale
    assert s == pytest.approx(1.7, abs=1e-6) and l == pytest.approx(0.2, abs=1e-6)


@pytest.mark.parametrize("agree", [False, True])
def test_with_fine_learned_agree_ratios_spread_wider_than_friction_scatter_read_nothing(agree):
    """``fine.learned_agree`` (task h29f): full box 1112's closing ratios 0.68, 0.15, 0.30 (openings 1.46-1.59)
    were read as their median; spread 0.53 T_s, wider than ``fine.breakaway_fit``, they are not one edge."""
    fine = _stage(**{**ON, "fine.learned_agree": agree})
    p, thl = 6000.0, 0.1
    for r_open, r_close in ((1.46, 0.68), (1.57, 0.15), (1.48, 0.30)):     # ratios (φ K - load) / T_s
        _break(fine, thl, p, 1, 0.0, r_open)
        _break(fine, thl, p, -1, 0.0, r_close)
    if agree:
        assert fine.applied_scale is None and fine.m is fine.m0
    else:                                                               # the median: s 0.59, l 0.89
        assert fine.applied_scale == pytest.approx((0.59, 0.89), abs=1e-6)
