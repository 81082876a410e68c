"""The doublet staircase's start learned from censored outcomes (task h29q, docs §62).

``fine.start_quantile`` (off by default, 0): each staircase's first stair is a censored sample of the
breakaway level drawn at its stop -- the valve let go in the first stair's preload or kick (the level
lay below the first apex) or it did not (above).  A Robbins-Monro quantile tracker
(:meth:`FineLearner.observe_start`) moves the start, in learned scatters below the learned breakaway,
``fine.start_step_sigmas`` x (1 - q) deeper after a let-go and x q shallower after a miss, so that a
fraction q of first stairs let go.  No plant: the learner alone, and the stage on a valve that never
moves (a few hundred stage periods)."""
import math

import numpy as np
import pytest

from fuel_valve_control.core.fine_positioning import START_SIGMAS_MAX, START_SIGMAS_MIN, FineLearner
from fuel_valve_control.core.params import CONTROLLER_SPEC
# the staircase's learner: C1 (the default since stop 25, docs §91) off -- its apex policy climbs no staircase
from test_fine_positioning import _break_loose, _main_stage as _stage, _rest_twist
from test_fine_staircase import _stuck_staircase


@pytest.mark.parametrize("q", [0.1, 0.3])
def test_the_start_settles_where_that_fraction_of_first_stairs_let_go(q):
    """Levels drawn N(0, 1.4 σ) about the learned mean (the nominal box's spread about it, σ the learned
    scatter): from the prior 2 σ the tracker settles where a fraction q of first apexes lie above the level
    -- at the level's q-quantile, -1.4 Φ⁻¹(1-q) σ -- whatever the prior and without knowing the spread."""
    rng = np.random.default_rng(7)
    lr = FineLearner(4, 0.01)
    spread, outcomes, depths = 1.4, [], []
    for level in rng.normal(0.0, spread, 6000):
        z = lr.start[1][3] or 2.0
        let_go = level <= -z                       # the first apex lies z scatters below the mean
        lr.observe_start(1, 3, bool(let_go), q, 0.5, prior=2.0)
        outcomes.append(let_go)
        depths.append(z)
    assert np.mean(outcomes[2000:]) == pytest.approx(q, abs=0.03)
    want = {0.1: 1.2816, 0.3: 0.5244}[q] * spread
    assert np.mean(depths[2000:]) == pytest.approx(want, abs=0.15)
    assert lr.start[-1] == [0.0] * 4 and lr.start[1][:3] == [0.0] * 3   # per direction and Δp band


def test_the_learned_start_is_bounded_and_never_reads_as_unlearned():
    lr = FineLearner(2, 0.01)
    for _ in range(200):                               # misses only: as shallow as allowed, still learned
        lr.observe_start(1, 0, False, 0.5, 1.0, prior=2.0)
    assert lr.start[1][0] == START_SIGMAS_MIN > 0.0
    for _ in range(200):                               # let-gos only: no deeper than the bound
        lr.observe_start(-1, 1, True, 0.1, 1.0, prior=2.0)
    assert lr.start[-1][1] == START_SIGMAS_MAX
    lr.reset()
    assert lr.start == {1: [0.0, 0.0], -1: [0.0, 0.0]}


def test_the_learned_start_survives_a_restart_and_a_version_4_file_loads_without_it(tmp_path):
    a = FineLearner(4, 0.1)
    a.set("breakaway", 1, 1, 3e-3)
    a.observe_start(-1, 2, True, 0.2, 0.5, prior=2.0)
    assert a.start[-1][2] == pytest.approx(2.4)
    path = tmp_path / "valve_friction.json"
    a.save(path)
    b = FineLearner(4, 0.1)
    b.load(path)
    assert b.to_dict() == a.to_dict() and b.to_dict()["version"] == 5
    old = a.to_dict()
    old["version"] = 4
    del old["start"]
    c = FineLearner(4, 0.1)
    c.from_dict(old)
    assert c.breakaway[1][1] == 3e-3 and c.start == {1: [0.0] * 4, -1: [0.0] * 4}


@pytest.mark.parametrize("direction", [1, -1])
def test_a_first_stair_that_did_not_move_the_valve_starts_the_next_staircase_shallower(direction):
    """With ``fine.start_quantile`` q the first stair's miss lifts the learned start q x
    ``fine.start_step_sigmas`` scatters and the next staircase starts that much higher; off, nothing is
    learned and every staircase starts ``fine.doublet_sigmas`` scatters below the learned level."""
    ps = CONTROLLER_SPEC.defaults()
    q, step, z0 = 0.2, ps["fine.start_step_sigmas"], ps["fine.doublet_sigmas"]
    for on in (False, True):
        fine, m = _stage(**({"fine.start_quantile": q} if on else {}))
        p = m.pressure_max_kpa
        band = fine.learn.band(m.pressure_fraction(p))
        _, depths = _stuck_staircase(fine, direction * 0.6e-3, p, stairs=2)
        learned = fine.learn.start[direction][band]
        assert learned == (pytest.approx(z0 - q * step) if on else 0.0)
        # a new stop: the next staircase's first depth below the learned level
        fine._stair = None
        fine._start_pulse(fine._thl0 + fine._pre, fine._thl0, p)
        ratio = fine._stair / depths[0]
        assert ratio == pytest.approx((z0 - q * step) / z0 if on else 1.0, rel=1e-6)
    assert math.isclose(ratio * z0, learned)


def test_the_main_laws_breakaways_count_fine_main_sample_weight_of_a_doublets():
    """``fine.main_sample_weight`` w (1 by default): a main-law breakaway from rest moves the learned breakaway
    w x ``fine.scatter_gain`` of its deviation (its samples are unbiased but ±7e-4 rad p10/p90 off the true
    level on the nominal box, a moved doublet's 1.6e-4 wide; task h29q)."""
    from test_fine_positioning import _break_loose
    ps = CONTROLLER_SPEC.defaults()
    moved = {}
    for w in (1.0, 0.5):
        fine, m = _stage(**{"fine.main_sample_weight": w})
        p = m.pressure_max_kpa
        band = fine.learn.band(m.pressure_fraction(p))
        _break_loose(fine, 0.5, p, offset=0.1)
        moved[w] = fine.learn.breakaway[1][band]
        x = 0.1 * m.friction(p).valve_static_nm / m.coupling_stiffness_nm_per_rad
        assert moved[w] == pytest.approx(w * ps["fine.scatter_gain"] * x, rel=1e-6)
    assert moved[0.5] == pytest.approx(0.5 * moved[1.0])


# ---------------------------------------------------------------------------------------------------------
# fine.unbiased_samples (task h30u, docs §69): every input a sample of the level, not a ratchet

@pytest.mark.parametrize("spread", [0.5, 1.5])
def test_censored_samples_alone_learn_the_levels_mean_and_scatter(spread):
    """Levels drawn N(0.4, spread) (units of the prior scatter 1), each seen only as a bound -- a pulse's apex
    drawn about the learned level: above it (the pulse moved the valve) the level lay below the apex, else above
    it.  :meth:`FineLearner.observe_interval` (the conditional mean and second moment of the learned normal)
    settles on the true mean and spread from bounds alone; the ratchet-and-pull it replaces did not."""
    rng = np.random.default_rng(11)
    lr = FineLearner(1, 100.0)
    mus, sig = [], []
    for level in rng.normal(0.4, spread, 4000):
        apex = lr.breakaway[1][0] + rng.normal(0.0, 1.0)
        lo, hi = (-math.inf, apex) if level <= apex else (apex, math.inf)
        lr.observe_interval(1, 0, lo, hi, 0.05, prior=1.0)
        mus.append(lr.breakaway[1][0])
        sig.append(lr.scatter[1][0])
    assert np.mean(mus[1000:]) == pytest.approx(0.4, abs=0.1 * spread + 0.05)
    assert np.mean(sig[1000:]) == pytest.approx(spread, rel=0.2)


def test_an_interval_sample_moves_the_level_into_the_interval():
    """Gain 1: the level becomes the conditional mean inside the interval, the scatter the rms distance of the
    interval's level from the level before (as a point sample's deviation would be)."""
    lr = FineLearner(1, 1.0)
    lr.observe_interval(1, 0, 0.1, 0.2, 1.0, prior=0.1)
    assert 0.1 < lr.breakaway[1][0] < 0.2 and 0.1 < lr.scatter[1][0] < 0.2
    lr.observe_interval(1, 0, 0.3, 0.2, 0.5, prior=0.1)       # an empty interval: nothing learned
    assert 0.1 < lr.breakaway[1][0] < 0.2
    lr.reset()
    lr.observe_interval(1, 0, 50.0, math.inf, 0.5, prior=0.1)  # far in the tail: its edge, clipped
    assert lr.breakaway[1][0] == 1.0


@pytest.mark.parametrize("direction", [1, -1])
def test_an_unmoved_servo_blended_pulse_leaves_the_level_and_its_move_takes_a_censored_sample(direction):
    """``fine.unbiased_samples``: a servo-blended pulse that did not move the valve (its twist stayed at its
    preload) leaves the learned breakaway where it was -- off, the ratchet raises it ``fine.probe_step`` x the
    band (nominal box: 822 such raises of +2.3e-4 rad median, h29q) -- while the next pulse's planned peak still
    climbs the step.  When that pulse moves the valve, the level takes the censored sample: above the unmoved
    apex, below the moving apex plus the let-go offset."""
    from test_fine_positioning import _unmoved_short_pulse
    for on in (False, True):
        fine, pre, peak, before, b, step = _unmoved_short_pulse(direction, **{"fine.unbiased_samples": on})
        raised = direction * (fine.learn.breakaway[direction][b] - before)
        if not on:
            assert raised == pytest.approx(step, rel=1e-6)          # the ratchet
            continue
        assert raised == pytest.approx(0.0, abs=1e-12)
        assert direction * (fine._peak_planned - peak) == pytest.approx(step, rel=1e-6)   # the peak climbs
        p = fine.m.pressure_max_kpa
        err, thl = direction * 2.0 * fine.cfg.doublet_max_error_rad, 0.5
        e0, b0 = fine._nominal(thl, p, direction)
        lo = direction * (pre - b0)                                 # the unmoved apex: its preload
        sigma = fine._scatter(direction, b, abs(b0 - e0))
        for _ in range(600):                                        # the next pulse moves the valve
            phase = fine.phase
            if phase == "observe":
                thl = 0.5 + err
            fine.update(0.5 + err, 0.5 + (fine._pre if phase == "park" else fine._final), thl, True, 0.3, p)
            if fine.phase == "hold":
                break
        assert fine.phase == "hold" and fine._pushes[(direction, b)] == 0.0
        hi = direction * (fine._peak_seen - b0) + fine._let_go_offset()
        assert hi > lo
        want = FineLearner(fine.learn.bands, fine.learn.limit)
        want.breakaway[direction][b] = before
        # the table holds signed offsets: a closing move's bounds (toward the move) mirrored
        want.observe_interval(direction, b, *((lo, hi) if direction > 0 else (-hi, -lo)), fine.cfg.scatter_gain,
                              sigma)
        assert fine.learn.breakaway[direction][b] == pytest.approx(want.breakaway[direction][b], rel=1e-9)
        assert fine.learn.breakaway[direction][b] != before



def _preload_break(direction, held_beyond=False, **changes):
    """A servo-blended pulse whose preload breaks the stuck valve loose (it slides 0.6 of the error while the
    preload holds the twist); returns the learned breakaway toward ``direction`` after it (rad, toward the
    move), that preload's twist offset from the nominal breakaway (toward the move), the nominal static band
    and the stage.  ``held_beyond``: an unmoved pulse at this stop had already reached half a band beyond the
    preload (the move is that pulse's late let-go)."""
    ps = CONTROLLER_SPEC.defaults()
    fine, m = _stage(**changes)
    p = m.pressure_max_kpa
    b = fine.learn.band(m.pressure_fraction(p))
    err = direction * 2.0 * ps["fine.doublet_max_error_rad"]               # a servo-blended pulse's error
    thl = 0.5
    th1 = thl + _rest_twist(fine, thl, p)
    _break_loose(fine, thl, p)
    before = fine.learn.breakaway[direction][b]
    for _ in range(400):
        if fine.phase == "park":
            break
        fine.update(0.5 + err, th1, thl, True, 0.3, p)
    assert fine.phase == "park" and not fine._doublet
    pre = fine._pre
    e0, b0 = fine._nominal(0.5, p, direction)
    if held_beyond:
        fine._safe = pre + direction * 0.5 * abs(b0 - e0)
    for _ in range(50):
        fine.update(0.5 + err, 0.5 + pre, 0.5 + 0.6 * err, True, 0.3, p)
        if fine.learn.breakaway[direction][b] != before or (held_beyond and fine._safe is None):   # the stop ended
            break
    assert (fine.learn.breakaway[direction][b] != before) != held_beyond  # it learned from the break (or not)
    return direction * fine.learn.breakaway[direction][b], direction * (pre - b0), abs(b0 - e0), fine


@pytest.mark.parametrize("direction", [1, -1])
def test_a_preload_that_broke_the_valve_loose_pulls_the_unbiased_level_below_it(direction):
    """``fine.unbiased_samples`` + ``fine.unbiased_preload_pull`` (task h32a, docs §73): a servo-blended pulse's
    preload, planned below the learned breakaway, breaks the valve loose.  The censored step alone
    (``fine.scatter_gain`` toward the normal's tail mean) leaves the learned level *above* the twist the valve
    has just broken at -- the next preload, planned from it, breaks it loose again for a whole jump (full box seed
    1137: 7.7e-3 rad).  With the pull the level goes ``fine.learn_gain`` of the way to 0.05 band below that
    preload, as main's learner takes it."""
    censored, broke_at, gap, _ = _preload_break(direction, **{"fine.unbiased_samples": True})
    pulled, broke_at2, _, fine = _preload_break(direction, **{"fine.unbiased_samples": True,
                                                            "fine.unbiased_preload_pull": True})
    assert broke_at2 == pytest.approx(broke_at, abs=1e-12)
    assert censored > broke_at                    # the censored step alone: above where it broke (the fault)
    assert pulled == pytest.approx(fine.cfg.learn_gain * (broke_at - 0.05 * gap), rel=1e-9)
    assert pulled < censored - 0.25 * gap


@pytest.mark.parametrize("direction", [1, -1])
def test_the_preload_pull_is_inert_without_unbiased_samples(direction):
    """``fine.unbiased_preload_pull`` acts only in ``fine.unbiased_samples``' path: off, main's learner."""
    main = _preload_break(direction)
    pull = _preload_break(direction, **{"fine.unbiased_preload_pull": True})
    assert main[:3] == pull[:3]


@pytest.mark.parametrize("direction", [1, -1])
def test_no_pull_when_an_unmoved_pulse_at_the_stop_reached_beyond_the_preload(direction):
    """An unmoved pulse at this stop already held an apex beyond the preload: the valve that goes in the next
    preload is that pulse's late let-go, not a level below the preload (full box seed 1039, friction x1.64 on
    K x0.72: an apex 4.46e-3 rad held, the valve went at a preload of -1.92e-3; pulled to -1.40e-3 the level
    planned a pulse that moved 7.7e-3, a doublet 2.3e-2 and a hunt).  The censored interval is empty and the
    pull stands aside: the level is unchanged."""
    level, _, _, _ = _preload_break(direction, held_beyond=True, **{"fine.unbiased_samples": True,
                                                                    "fine.unbiased_preload_pull": True})
    assert level == pytest.approx(0.0, abs=1e-12)
