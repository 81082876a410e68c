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
