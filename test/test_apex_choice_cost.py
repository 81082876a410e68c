"""The apex policy's choice made cheaper with the same bits (task h40m, docs §106): the pieces the fast path uses
instead of main's arithmetic each equal it exactly -- the normal CDF's saturated tails, the levels beyond a candidate
as an insertion point, the law's memoised scatters.  (The whole choice against main's: test_apex_policy.py's
``test_the_choice_equals_main_choice_bit_for_bit``; the per-level move read: its ``test_the_move_points_...``.)
No speed is asserted."""
import math

import numpy as np
import pytest

from fuel_valve_control.core import fine_positioning as FP


def test_the_cdf_tails_are_the_cdf_to_the_bit():
    """Beyond ``CDF_SATURATED`` the normal CDF of this arithmetic is exactly 0.0 / 1.0 (a dense grid out to 60 and
    +-inf), so skipping ``erf`` there changes no bit: ``_norm_cdf_tails`` equals ``_norm_cdf`` element for element
    (NaN where NaN, the sign of zero too) on arrays of tails and middles, at the threshold and just inside it.  Fails
    with a threshold where erf has not yet saturated (checked: 5.0)."""
    assert FP._CDF_TAILS_EXACT
    grid = np.linspace(FP.CDF_SATURATED, 60.0, 200001)
    assert np.all(FP._norm_cdf(grid) == 1.0) and np.all(FP._norm_cdf(-grid) == 0.0)
    assert not np.signbit(FP._norm_cdf(-grid)).any()
    assert FP._norm_cdf(np.array([np.inf]))[0] == 1.0 and FP._norm_cdf(np.array([-np.inf]))[0] == 0.0
    rng = np.random.default_rng(40)
    t = FP.CDF_SATURATED
    for n in range(6):
        x = rng.normal(0.0, 12.0, (3, 1500))
        edge = np.array([t, -t, np.nextafter(t, 0.0), -np.nextafter(t, 0.0), np.nextafter(t, 99.0), 0.0, -0.0,
                         np.inf, -np.inf, np.nan, 1e300, -1e300])
        x.reshape(-1)[rng.choice(x.size, len(edge), replace=False)] = edge
        got, want = FP._norm_cdf_tails(x), FP._norm_cdf(x)
        assert got.shape == want.shape
        assert np.array_equal(got, want, equal_nan=True)
        assert np.array_equal(np.signbit(got), np.signbit(want))
    small = rng.normal(0.0, 12.0, 50)                     # below the size the masks pay: the plain CDF
    assert np.array_equal(FP._norm_cdf_tails(small), FP._norm_cdf(small))


@pytest.mark.parametrize("direction", [1, -1])
def test_the_levels_beyond_a_candidate_as_its_insertion_point(direction):
    """``_beyond_levels`` (fixed sums, levels ordered toward the try): each candidate's first level beyond it, the
    matrix main builds (d (lv - a) > 0) read as a suffix -- also where a candidate equals a level (the law's own
    points are candidates) -- and V1 from it the same bits as from the matrix; levels not ordered, or the normal
    law's BLAS path: the matrix itself."""
    d = direction
    rng = np.random.default_rng(41 + d)
    for n in range(10):
        floor = None if n % 3 == 0 else 0.01 + d * float(rng.uniform(-1e-3, 2e-3))
        lv, w = FP.mixture_level_law(0.01, d, np.array([2e-4, 5e-4, 1.1e-3]), np.array([0.5, 0.3, 0.2]), floor)
        top = lv[-1]
        cand = np.concatenate([lv, top + d * 4e-4 * np.linspace(0.1, 1.5, 8)])
        cand = cand[rng.uniform(size=len(cand)) < 0.85]
        cand = np.concatenate([cand, [lv[0] - d * 1e-4, np.nan]])           # below every level; not a number
        matrix = d * (lv[None, :] - cand[:, None]) > 0.0
        start = FP._beyond_levels(d, lv, cand, True)
        assert start.ndim == 1
        assert np.array_equal(np.arange(len(lv))[None, :] >= start[:, None], matrix)
        assert np.array_equal(FP._beyond_levels(d, lv, cand, False), matrix)
        hit = np.where(rng.uniform(size=(len(cand), len(lv))) < 0.5, rng.uniform(size=(len(cand), len(lv))), 0.0)
        assert np.array_equal(FP._beyond_best(hit, w, start, True), FP._beyond_best(hit, w, matrix, True))
        perm = rng.permutation(len(lv))
        assert np.array_equal(FP._beyond_levels(d, lv[perm], cand, True), matrix[:, perm])


def test_the_law_scales_are_memoised_unchanged_and_read_only():
    """``level_law_scales`` keeps its last few answers (most tries ask what the previous one asked): the same values
    as computed afresh for every law, arrays that cannot be changed in place, and a bounded memo."""
    for kind, sigma, hi in (("mixture", 3.2e-4, 1.146e-3), ("student", 3.2e-4, 1.146e-3), ("normal", 3.2e-4, 2e-3),
                            ("mixture", 5e-4, 4e-4)):
        for _ in range(2):
            got = FP.level_law_scales(kind, sigma, hi, 8.0)
            want = FP._level_law_scales(kind, sigma, hi, 8.0)
            assert all(np.array_equal(g, v) for g, v in zip(got, want))
            with pytest.raises(ValueError):
                got[0][0] = 1.0
    for k in range(20):
        FP.level_law_scales("mixture", 1e-4 * (1 + k), 1.146e-3, 8.0)
    assert len(FP._LAW_SCALES) <= 8
    assert math.isclose(float(FP.level_law_scales("mixture", 1e-4, 1.146e-3, 8.0)[1].sum()), 1.0)


@pytest.mark.parametrize("direction", [1, -1])
def test_the_break_sums_from_the_law_prefixes_equal_the_masked_sums(direction):
    """A level below a kick's preload (overdrive > its rise) is, on levels ordered toward the try, one of the first m
    of its candidate's row (the overdrive falls along the row): the law's sum over the break mask equals row m of
    the table of the law's prefix sums to the bit (the same elements w / 0.0 summed in the same order), as the
    choice's mixture path reads it; the prefix table's row m is True on the first m columns."""
    d = direction
    rng = np.random.default_rng(43 + d)
    mask = FP._prefix_mask(5)
    assert mask.shape == (6, 5) and np.array_equal(mask.sum(axis=1), np.arange(6)) and mask[3, :3].all()
    for n in range(8):
        floor = None if n % 2 else 0.01 + d * float(rng.uniform(-1e-3, 2e-3))
        lv, w = FP.mixture_level_law(0.01, d, np.array([2e-4, 5e-4, 1.1e-3]), np.array([0.5, 0.3, 0.2]), floor)
        cand = np.concatenate([lv, lv[-1] + d * 4e-4 * np.linspace(0.1, 1.5, 8)])
        od = d * (cand[:, None] - lv[None, :])
        rises = np.sort(rng.uniform(1e-4, 3e-3, 3))
        brk = od[None, :, :] > rises[:, None, None]
        m = np.count_nonzero(brk, axis=-1)
        assert np.array_equal(np.arange(len(lv))[None, None, :] < m[:, :, None], brk)      # a prefix per row
        want = np.add.reduce(brk.astype(float) * w, axis=-1)
        got = np.add.reduce(np.where(FP._prefix_mask(len(lv)), w, 0.0), axis=-1)[m]
        assert np.array_equal(got, want)
