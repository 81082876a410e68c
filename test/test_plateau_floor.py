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
