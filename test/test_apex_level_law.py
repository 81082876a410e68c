"""``fine.apex_level_law`` (task h36l, docs §92, default "normal"): the apex policy's law of the static level as a
scale mixture of normals -- scatters log-uniform from the learned one to the widest the stage is designed for
("mixture"), or a Student-t of the learned scatter's sample count ("student") -- instead of one clipped normal.

Stage only (no plant, no closed loop): the law's shape and the choice it changes."""
import math

import numpy as np
import pytest

from fuel_valve_control.core import fine_positioning as FP
from fuel_valve_control.core.params import CONTROLLER_SPEC
from test_fine_positioning import _stage


def _moments(lv, w, center, d):
    t = d * (lv - center)
    m = (w * t).sum()
    var = (w * (t - m) ** 2).sum()
    return m, math.sqrt(var), (w * (t - m) ** 4).sum() / var ** 2


@pytest.mark.parametrize("kind", ["mixture", "student"])
def test_the_law_has_heavier_tails_than_the_normal(kind):
    """At the learned scatter 0.32e-3 rad (nominal box seed 1000's, whose first tries' levels lay a sd of 1.47
    learned scatters about the learned level, 5.3 % beyond 3: docs §92) and the design's widest 1.15e-3 rad: both
    laws are centred on the learned level, wider than the learned scatter, with a kurtosis above the normal's 3,
    and more of their weight beyond 3 scatters than the normal's 0.27 %."""
    sigma, hi = 0.32e-3, 1.146e-3
    scales, weights = FP.level_law_scales(kind, sigma, hi, 8.0)
    assert len(scales) == FP.APEX_MIX_SCALES and weights.sum() == pytest.approx(1.0)
    for d in (1, -1):
        lv, w = FP.mixture_level_law(0.01, d, scales, weights)
        assert w.sum() == pytest.approx(1.0) and np.all(np.diff(d * lv) > 0.0)
        mean, sd, kurt = _moments(lv, w, 0.01, d)
        assert mean == pytest.approx(0.0, abs=1e-9)
        assert sd > 1.05 * sigma
        assert kurt > 3.3
        assert w[np.abs(lv - 0.01) > 3.0 * sigma].sum() > 0.005
    # the normal on the same points: kurtosis 3 (within the clip at +-3 sigma and the quadrature)
    lv, w = FP.mixture_level_law(0.0, 1, np.array([sigma]), np.array([1.0]))
    assert _moments(lv, w, 0.0, 1)[2] == pytest.approx(3.0, abs=0.25)


def test_the_mixture_collapses_to_the_normal_when_its_range_does():
    """The mixture's range is [learned scatter, fine.breakaway_fit / 3 x T_s/K]: where that bound is no wider than
    the learned scatter it is one normal, and the stage's law is today's clipped normal to the bit."""
    scales, weights = FP.level_law_scales("mixture", 5e-4, 4e-4, 8.0)
    assert scales.tolist() == [5e-4] and weights.tolist() == [1.0]
    scales, weights = FP.level_law_scales("normal", 5e-4, 2e-3, 8.0)
    assert scales.tolist() == [5e-4]
    normal, model = _stage(**{"fine.apex_policy": True, "fine.apex_level_law": "normal"})
    p = model.pressure_max_kpa
    # breakaway_fit 0.01: the design's widest scatter 0.04e-3 rad, below any learned one
    mix, _ = _stage(**{"fine.apex_policy": True, "fine.apex_level_law": "mixture", "fine.breakaway_fit": 0.01})
    for d in (1, -1):
        phi_b = normal._twists(0.5, p, d)[1]
        for floor in (None, phi_b - d * 1e-4, phi_b + d * 1.2e-3):
            normal._apex_floor = mix._apex_floor = None if floor is None else (d, floor)
            a, b = normal._apex_law(d, phi_b, 3e-4, p), mix._apex_law(d, phi_b, 3e-4, p)
            assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])


def test_the_design_bound_is_breakaway_fit_at_three_scatters():
    """The mixture's widest scatter is fine.breakaway_fit x T_s(Δp)/K / 3 (the engage gate's bound at the law's
    clip), at the Δp it is read at; the Student-t's degrees of freedom are the learned scatter's sample count."""
    fine, model = _stage(**{"fine.apex_policy": True, "fine.apex_level_law": "mixture"})
    p = model.pressure_max_kpa
    scales, _ = fine._level_scales(3e-4, p)
    ts_k = model.friction(p).valve_static_nm / model.coupling_stiffness_nm_per_rad
    top = fine.cfg.breakaway_fit / 3.0 * ts_k
    assert scales.min() > 3e-4 and scales.max() < top
    assert math.log(scales.max() / scales.min()) == pytest.approx(
        math.log(top / 3e-4) * (FP.APEX_MIX_SCALES - 1) / FP.APEX_MIX_SCALES, rel=1e-9)
    fine, _ = _stage(**{"fine.apex_policy": True, "fine.apex_level_law": "student"})
    scales, _ = fine._level_scales(3e-4, p)
    # scatter_gain 0.2: (2 - 0.2) / 0.2 - 1 = 8 degrees of freedom; the t's rms sqrt(8 / 6) x its scale
    lv, w = FP.mixture_level_law(0.0, 1, scales, np.full(len(scales), 1.0 / len(scales)))
    assert _moments(lv, w, 0.0, 1)[1] == pytest.approx(3e-4 * math.sqrt(8.0 / 6.0), rel=0.12)


@pytest.mark.parametrize("direction", [1, -1])
def test_a_floor_far_above_the_learned_level_leaves_the_mixture_mass_far_above_it(direction):
    """After unmoved apexes up to 2.7 learned scatters above the learned level (seed 1000's stop whose level lay 5.1
    scatters up: the normal's law then held all its weight within 0.3 scatters of the floor and the policy repeated
    one apex ten times, "certain" to move), the mixture keeps most of its weight more than half a scatter above the
    floor, the normal almost none."""
    d, sigma = direction, 3.2e-4
    normal, model = _stage(**{"fine.apex_policy": True, "fine.apex_level_law": "normal"})
    mix, _ = _stage(**{"fine.apex_policy": True, "fine.apex_level_law": "mixture"})
    p = model.pressure_max_kpa
    phi_b = normal._twists(0.5, p, d)[1]
    floor = phi_b + d * 2.7 * sigma
    normal._apex_floor = mix._apex_floor = (d, floor)
    far = {}
    for name, fine in (("normal", normal), ("mixture", mix)):
        lv, w = fine._apex_law(d, phi_b, sigma, p)
        assert w[d * (lv - floor) <= 0.0].sum() == 0.0 and w.sum() == pytest.approx(1.0)
        far[name] = w[d * (lv - floor) > 0.5 * sigma].sum()
    assert far["normal"] < 0.1 and far["mixture"] > 0.5


@pytest.mark.parametrize("direction", [-1])    # one direction: its move tables cost ~5 s of CPU; the law is tested both ways
def test_the_choice_after_a_high_floor_climbs_where_the_mixture_says_the_level_may_lie(direction):
    """The stage's choice (kicks to 16 A, the excess from the model's equilibrium) after unmoved tries up to 2.7
    learned scatters above a learned level 1.5e-3 rad below nominal (an error of 0.6e-3 rad): the normal holds all
    its weight within 0.3 scatters of the floor, so it plans a hair's climb (< 0.2 scatters) certain not to move and
    values it at the next try's near-certain landing (score > 0.9; on seed 1000 tries the normal called certain to
    move moved 1 time in 16, docs §92); the mixture climbs at least 0.5 scatters past the floor with a kick that
    may move the valve (0.2 < P(no move) < 0.9) and scores it below 0.7."""
    d, sigma, err = direction, 3.2e-4, direction * 0.6e-3
    plans = {}
    for name in ("normal", "mixture"):
        fine, model = _stage(**{"fine.apex_policy": True, "fine.apex_kick_max_a": 16.0, "fine.apex_excess_nominal": True,
                                "fine.apex_level_law": name})
        p = model.pressure_max_kpa
        phi_e, phi_b = fine._twists(0.5, p, d)[:2]
        phi_b -= d * 1.5e-3
        floor = phi_b + d * 2.7 * sigma
        fine._apex_floor = (d, floor)
        apex = fine._choose_apex(err, d, phi_e, phi_b, sigma, p, 0.0, 0.5)
        assert apex is not None
        plans[name] = (d * (apex - floor) / sigma, fine._apex_plan)
    above, plan = plans["normal"]
    assert 0.0 < above < 0.2 and plan[2] > 0.99 and plan[3] > 0.9
    above, plan = plans["mixture"]
    assert above > 0.5 and 0.2 < plan[2] < 0.9 and plan[3] < 0.7


def test_mixture_by_default():
    """C3, the default since stop 28 (docs §108): the mixture law."""
    assert CONTROLLER_SPEC.defaults()["fine.apex_level_law"] == "mixture"
    fine, _ = _stage()
    assert fine.cfg.apex_level_law == "mixture"


def test_the_fixed_order_sums_equal_the_law_and_read_each_row_alone():
    """(task h38x, docs §99) The non-normal laws' weighted sums without BLAS: V1 (:func:`FP._beyond_best`, suffix sums
    over the levels ordered toward the try) equals the law truncated beyond each candidate averaged explicitly (to
    1e-15; 0 where no weight lies beyond), on the suffix path and on the unordered levels' fallback; and each
    row's sums are the same bits whether computed with the other rows or alone (no blocking across rows, as BLAS's
    kernels and threads do)."""
    rng = np.random.default_rng(99)
    for n in range(12):
        d = 1 if n % 2 else -1
        floor = None if n % 3 == 0 else 0.01 + d * float(rng.uniform(-1e-3, 2e-3))
        lv, w = FP.mixture_level_law(0.01, d, np.array([2e-4, 5e-4, 1.1e-3]), np.array([0.5, 0.3, 0.2]), floor)
        cand = np.concatenate([lv, lv[-1] + d * np.linspace(1e-5, 1e-3, 8)])[rng.uniform(size=len(lv) + 8) < 0.8]
        hit = np.where(rng.uniform(size=(len(cand), len(lv))) < 0.4, rng.uniform(size=(len(cand), len(lv))), 0.0)
        beyond = d * (lv[None, :] - cand[:, None]) > 0.0
        want = np.zeros(len(cand))
        for a in range(len(cand)):
            tot = w[beyond[a]].sum()
            if tot > 0.0:
                want[a] = max(float((hit[r][beyond[a]] * w[beyond[a]]).sum()) / tot for r in range(len(cand)))
        got = FP._beyond_best(hit, w, beyond, True)
        assert np.allclose(got, want, rtol=0.0, atol=1e-15) and np.array_equal(got == 0.0, want == 0.0)
        perm = rng.permutation(len(lv))                      # levels not ordered: the elementwise fallback
        assert np.allclose(FP._beyond_best(hit[:, perm], w[perm], beyond[:, perm], True), want, rtol=0.0, atol=1e-15)
        x = rng.uniform(size=(3, len(cand), len(lv)))
        whole = FP._wsum(x, w, True)
        assert all(np.array_equal(whole[k, a], FP._wsum(x[k, a], w, True))
                   for k in range(3) for a in range(0, len(cand), 7))
        assert np.allclose(whole, x @ w, rtol=1e-13, atol=0.0)


def test_the_mixture_choice_is_the_same_whatever_blas_threads_or_kernel():
    """(task h38x, docs §99) The mixture law's choices (C2's law) on a few random stage states, each in a subprocess
    with OPENBLAS_NUM_THREADS 1 and 2 (and, on an x86-64 with AVX2, OpenBLAS's Haswell kernels as such a machine
    picks them): the same outcome to the last bit (return value, plan, kick, rise, mean move).  On main the Haswell
    kernels changed the mean move's last bits in 2 of these 6 draws (the choice's gemv), and the 89 x 81 x 89 product
    of random inputs differs between 1 and 2 threads (benchmarks/apex_threads.py)."""
    import platform
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    import apex_threads
    variants = ["1", "2"]
    try:
        avx2 = platform.machine() == "x86_64" and "avx2" in Path("/proc/cpuinfo").read_text()
    except OSError:
        avx2 = False
    if avx2:
        variants.append("Haswell")
    res = apex_threads.compare(["mixture"], 6, variants, parallel=len(variants))
    assert res["differ"] == {"mixture": []}, res["differ"]
    assert res["chose"]["mixture"] >= 3                  # the draws chose tries (not only "hold")
