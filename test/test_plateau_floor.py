"""``benchmarks/plateau_floor.py`` (task h32c, docs §75): the pulse primitive its bounds are built on.

The floor the benchmark reports rests on one physical fact of the plant: a valve stuck at a static
level breaks loose only when the twist reaches it, and then slides by an amount set by how far that
level lies above the Coulomb level (the stored excess twist) -- the retreat at the 30 A cap cuts the
free swing (twice the excess) but cannot cut it to zero.  These tests pin that on the bare plant,
and the helpers the policies use (the level's law, the table's interpolation)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import load_benchmark


@pytest.fixture(scope="module")
def pf():
    return load_benchmark("plateau_floor")


MEMBER = (2.0, 36.0, 2, 0.0)          # a small kick, the whole retreat for two periods, no lead


def _move(pf, excess: float, overdrive: float, d: int = 1) -> float:
    rise = pf.calibrate_rise(d, MEMBER)
    pl = pf.bare_plant(0.5, excess)
    apex = (pf.load_torque(0.5) + d * (pf.TC + pf.K * excess)) / pf.K + d * overdrive
    move, periods = pf.try_pulse(pl, d, apex, rise, MEMBER, pf.TC)
    assert periods > 0
    return d * move


def test_a_pulse_below_the_level_does_not_move_the_valve(pf):
    assert _move(pf, 2.3e-3, -1e-4) == 0.0


def test_the_smallest_move_grows_with_the_drawn_level_and_stays_below_the_free_swing(pf):
    small, nominal, high = (_move(pf, x, 1e-5) for x in (1.6e-3, 2.3e-3, 3.0e-3))
    # the retreat cuts the free swing (2 x excess: the valve oscillating about the Coulomb twist)
    assert 0.0 < nominal < 2.0 * 2.3e-3 * 0.5
    # ... but a stop that drew a higher level slides further: the move follows the draw, and at the
    # nominal excess (T_s - T_c)/K = 2.3e-3 no pulse of this family moves it by less than ~0.6e-3
    assert small < nominal < high
    assert nominal > 5e-4


def test_level_prior_is_the_clipped_scatter_above_coulomb(pf):
    x, w = pf.level_prior(0.05, 1.0)
    assert math.isclose(w.sum(), 1.0)
    assert (x >= 0.0).all()
    assert math.isclose(float((x * w).sum()), (pf.TS - pf.TC) / pf.K, rel_tol=1e-3)
    # a ripple scales both levels, so the excess too
    x2, _ = pf.level_prior(0.05, 1.04)
    assert np.allclose(x2, 1.04 * x)


def test_table_move_is_zero_below_the_level_and_unknown_beyond_the_grid(pf):
    shape = (1, len(pf.EXCESS_GRID), len(pf.OVERDRIVE_GRID))
    grid = np.add.outer(np.asarray(pf.EXCESS_GRID), np.asarray(pf.OVERDRIVE_GRID))[None]
    t = pf.Table([MEMBER], {(1, 0): 0.0, (-1, 0): 0.0}, {1: grid.copy(), -1: np.zeros(shape)})
    assert t.move(1, 0, 2e-3, -1e-5) == 0.0
    assert math.isclose(float(t.move(1, 0, 2e-3, 1e-4)), 2e-3 + 1e-4, rel_tol=1e-9)
    assert math.isnan(float(t.move(1, 0, 2e-3, 2 * pf.OVERDRIVE_GRID[-1])))


# --- task h33a (docs §82): main's doublet as a member kind (kick, whole retreat, then half of it for one period)
MAIN_DOUBLET = (4.0, 30.0, 1, 0.0, 0.5)


def _member_move(pf, member: tuple, excess: float, overdrive: float, d: int = 1) -> float:
    rise = pf.calibrate_rise(d, member)
    pl = pf.bare_plant(0.5, excess)
    apex = (pf.load_torque(0.5) + d * (pf.TC + pf.K * excess)) / pf.K + d * overdrive
    move, _ = pf.try_pulse(pl, d, apex, rise, member, pf.TC)
    return d * move


@pytest.mark.parametrize("d", [1, -1])
def test_main_doublet_member_moves_only_past_the_level(pf, d):
    # the apex (park + the calibrated rise of kick, whole and half retreat) 1e-4 below the nominal level: the valve
    # stays; 1e-5 past it: it breaks loose and slides toward the pulse, less than the free swing (2 x excess)
    assert _member_move(pf, MAIN_DOUBLET, 2.3e-3, -1e-4, d) == 0.0
    moved = _member_move(pf, MAIN_DOUBLET, 2.3e-3, 1e-5, d)
    assert 0.0 < moved < 2.0 * 2.3e-3


def test_main_family_is_mains_doublet_and_the_lead_rule_interpolates(pf):
    ms = pf.members("main")
    assert {m[:3] + m[4:] for m in ms} == {(pf.CS["fine.kick_current_a"], pf.CS["fine.peak_current_a"],
                                           pf.CS["fine.retreat_full_periods"], 0.5)}
    assert sorted(m[3] for m in ms) == list(pf.LEAD_GRID)
    # the lead rule interpolates the moves and the rise between the tabulated leads
    n = len(ms)
    moves = np.arange(n, dtype=float)[:, None] * np.ones((n, 2))
    t = pf.Table(ms, {(1, i): float(i) for i in range(n)}, {}, lead_rule=True)
    g0, g1 = pf.LEAD_GRID[1], pf.LEAD_GRID[2]
    out, mem, rise = t.at_lead(1, moves, 0.5 * (g0 + g1))
    i0, i1 = [i for i, m in enumerate(ms) if m[3] in (g0, g1)]
    assert len(mem) == 1 and math.isclose(mem[0][3], 0.5 * (g0 + g1))
    assert np.allclose(out[0], 0.5 * (i0 + i1)) and math.isclose(rise[0], 0.5 * (i0 + i1))
    # beyond the grid: its end
    _, mem, _ = t.at_lead(1, moves, 1.0)
    assert mem[0][3] == pf.LEAD_GRID[-1]


def test_realism_reads_the_twist_through_the_resolvers_within_a_few_counts(pf):
    # --realism's readings: the twist as the motor resolver / N minus the valve resolver shows it (quantised to the
    # valve's count, noisy, once a period): within a couple of counts of the truth at rest; the peak read during a
    # pulse that does not move the valve lies above the park's end but not above the apex planned (the kick's
    # apex falls between two samples -- what the policy must not climb from, docs §82.3)
    d, x = 1, 2.3e-3
    pl = pf.bare_plant(0.5, x)
    level = (pf.load_torque(0.5) + d * (pf.TC + pf.K * x)) / pf.K
    dr = pf.Driver(pl)
    dr.sense = d
    dr.park(level - 1e-3, pf.PARK_PERIODS)
    assert abs(dr.last - dr.twist()) < 2 * pf.LSB_RAD
    rise = pf.calibrate_rise(d, MAIN_DOUBLET)
    seen: dict = {}
    move, _ = pf.try_pulse(pl, d, level - 3e-4, rise, MAIN_DOUBLET, pf.TC, seen=seen)
    assert move == 0.0
    assert seen["park"] < seen["peak"] < level - 3e-4 + 2 * pf.LSB_RAD


# ---------------------------------------------------------------- h34r: learning the run's law from censored tries
def _synthetic_stops(pf, rng, n, sigma, ripple=None, thetas=None, step=1.5e-4):
    """``n`` stops as the policies see them: the plant's level x = (T_s r (1 + σ n) - T_c)/K drawn at each stop, a
    staircase of apexes from 2e-3 below the nominal level's excess in ``step`` rad stairs: the highest that did not
    move it (lo) and the one that did (hi) -- every third stop ends unmoved (hi None), as a plateau's last stop can."""
    out = []
    for i in range(n):
        th = float(thetas[i]) if thetas is not None else 0.5
        r = 1.0 if ripple is None else ripple(th)
        f = 1.0 + sigma * float(np.clip(rng.standard_normal(), -3.0, 3.0))
        x = (pf.TS * r * f - pf.TC) / pf.K
        a0 = (pf.TS - pf.TC) / pf.K - 2e-3
        j = int(np.floor((x - a0) / step))
        lo, hi = a0 + j * step, a0 + (j + 1) * step
        out.append((th, lo, None if i % 3 == 2 else hi))
    return out


@pytest.mark.parametrize("sigma_true", (0.025, 0.075))
def test_rms_learner_moves_toward_the_runs_scatter(pf, sigma_true):
    """The rms-only learner's posterior mean of σ leaves the box's prior (0.05) toward the run's rms after
    30 stops of censored readings (the ripple a box draw per stop, as the policy models it)."""
    rng = np.random.default_rng(3)
    lr = pf.LevelLearner("rms", 0.5)
    prior = lr.summary(0.5, {"static_scatter": sigma_true, "ripple": 0.0, "ripple_period_rad": 0.02,
                             "ripple_phase_rad": 0.0})["sigma_mean"]
    for th, lo, hi in _synthetic_stops(pf, rng, 30, sigma_true):
        lr.observe(th, lo, hi)
    post = float((lr.w * lr.sigma).sum())
    assert abs(prior - 0.05) < 1e-9
    assert abs(post - sigma_true) < 0.5 * abs(prior - sigma_true)


def test_ripple_learner_finds_the_phase_and_predicts_the_map(pf):
    """The run's-law learner (σ x a x k x ψ): readings at 40 stops spread over 0.1 rad of a run with a strong ripple
    (a 0.046, λ 20 mrad) and a small scatter put most of the weight within π/4 of the true phase within 2.5 /rad of
    the true wavenumber (over a 0.1 rad span the wavenumber is resolved to ~1/0.1 rad), and its predictive ripple factor at fresh positions in the span follows the true map."""
    theta0, k_true, psi_true, a_true = 0.40, 50.0, 2.0, 0.046
    ripple = lambda th: 1.0 + a_true * math.sin(2.0 * math.pi * k_true * (th - theta0) + psi_true)   # noqa: E731
    rng = np.random.default_rng(5)
    thetas = theta0 + rng.uniform(0.0, 0.1, 40)
    lr = pf.LevelLearner("learn", theta0)
    w0 = lr.w
    near = (np.abs(lr.k - k_true) < 2.5) & (np.abs(np.angle(np.exp(1j * (lr.psi - psi_true)))) <= math.pi / 4 + 1e-9)
    for th, lo, hi in _synthetic_stops(pf, rng, 40, 0.025, ripple, thetas, step=1e-4):
        lr.observe(th, lo, hi)
    w = lr.w
    assert w[near].sum() > 0.9 > 50 * w0[near].sum()   # the prior: 0.011
    for th in theta0 + np.array([0.013, 0.037, 0.071, 0.094]):
        r = lr.ripple(th)
        mean = float((w * r).sum())
        assert abs(mean - ripple(th)) < 0.25 * a_true
    # the predictive law it hands the policy: where the level lies (the apex coordinate x_p) at a trough of the map is
    # lower than at a crest, by most of the map's 2 a T_s / K (1.05e-3 rad)
    crest = theta0 + (0.25 - psi_true / (2 * math.pi)) % 1.0 / k_true
    trough = crest + 0.5 / k_true
    mx = [float((xp * ww).sum()) for _, xp, ww in (lr.samples(crest), lr.samples(trough))]
    assert mx[0] - mx[1] > pf.TS * a_true / pf.K


def test_position_free_level_learner_reads_the_ripple_as_scatter(pf):
    """The position-free learner (what ``FineLearner`` holds) on a run whose ripple alternates between two
    positions: its mean factor stays near the average and its spread grows beyond the scatter's rms -- it cannot
    tell the two positions apart, where the run's-law learner's predictive differs between them."""
    rng = np.random.default_rng(7)
    theta0 = 0.3
    ripple = lambda th: 1.0 + 0.045 * math.sin(2.0 * math.pi * 40.0 * (th - theta0) + 1.0)   # noqa: E731
    thetas = np.where(np.arange(40) % 2 == 0, theta0 + 0.005, theta0 + 0.0175)   # 2.45 and 0.55 rad of phase
    lv = pf.LevelLearner("level", theta0)
    for th, lo, hi in _synthetic_stops(pf, rng, 40, 0.025, ripple, thetas, step=1e-4):
        lv.observe(th, lo, hi)
    w = lv.w
    assert abs(float((w * lv.mu).sum()) - 1.0) < 0.02
    assert float((w * lv.sigma).sum()) > 0.04
    a, b = (float((xp * ww).sum()) for _, xp, ww in (lv.samples(thetas[0]), lv.samples(thetas[1])))
    assert a == b
    # the kernel map (``local``) told the same stops keeps the two positions apart: the crest's level above the
    # trough's by most of 2 x 0.045 x 0.77 T_s / K (0.8e-3 rad); far from every stop it is the prior again
    lc = pf.LevelLearner("local", theta0)
    for th, lo, hi in _synthetic_stops(pf, np.random.default_rng(7), 40, 0.025, ripple, thetas, step=1e-4):
        lc.observe(th, lo, hi)
    a, b, far = (float((xp * ww).sum()) for _, xp, ww in (lc.samples(t) for t in (*thetas[:2], theta0 + 0.1)))
    prior = float((lambda s: (s[1] * s[2]).sum())(pf.LevelLearner("local", theta0).samples(theta0)))
    assert a - b > 0.5 * 2 * 0.045 * 0.77 * pf.TS / pf.K
    assert abs(far - prior) < 1e-9
