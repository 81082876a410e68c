"""The overshoot of the steps inside plateau sequences (issue 14, h20s).

The SPEC's single 2 % step meets its overshoot target; the plateau steps of the nominal robustness
box (``benchmarks/robustness.py --box nominal``: the nominal plant at max Δp, friction scatter and
ripple, random plateau sequences) did not: 5 of 203 steps >= 1 % of stroke overshot more than 50 %
(seeds 1000-1039; 4 of 222 on seeds 2000-2039).  Traced: every one of those runs had learned a
steady valve load of 2.8 N*m (half the static friction) on a valve that carries none -- the
integrator's breakaway toward a followed demand step below the move threshold was read as a relax
slip at the drive of the hold's latest *settled* period (~0), and its one-edge prior put the load
half the static level beyond it.  Every later move started from a drive uncocked to that load, up to
half the static friction toward (or away from) its breakaway.  Each closed-loop test here failed
on main 807b5de.
"""
import functools
import math

import numpy as np
import pytest

from fuel_valve_control.common.contract import STROKE_RAD
from fuel_valve_control.core.model import NominalModel
from fuel_valve_control.core.params import CONTROLLER_SPEC, DEFAULT_MODE
from fuel_valve_control.tools import metrics as M
from fuel_valve_control.tools import sim
from prefetch import ModuleRuns, jobs, selected_items

#: the nominal model's static valve friction at max Δp, N*m
_STATIC_NM = NominalModel.from_params(CONTROLLER_SPEC.defaults()).friction(6206.0).valve_static_nm


def _record(step_pct: float, overshoot_pct: float, start_pct: float = 50.0) -> dict:
    start = start_pct / 100.0 * STROKE_RAD
    return {"from_rad": start, "to_rad": start + step_pct / 100.0 * STROKE_RAD, "overshoot_pct": overshoot_pct}


def test_plateau_step_overshoot_counts_the_steps_of_at_least_one_percent_of_stroke():
    plats = [_record(0.99, 300.0), _record(1.0, 12.0), _record(-2.5, 60.0, 70.0), _record(-0.2, 90.0),
             _record(4.0, 0.0)]
    assert M.plateau_step_overshoots(plats, STROKE_RAD) == [12.0, 60.0, 0.0]
    assert M.plateau_step_overshoots(plats, STROKE_RAD, min_fraction=0.001) == [300.0, 12.0, 60.0, 90.0, 0.0]


def test_overshoot_tail_counts_beyond_ten_and_fifty_percent():
    tail = M.overshoot_tail([0.0, 5.0, 10.0, 10.5, 49.0, 51.0, float("nan"), None])
    assert tail["n"] == 6
    assert tail["over_10"] == 3 and tail["over_50"] == 1       # strictly beyond
    assert tail["max"] == 51.0 and tail["median"] == pytest.approx(10.25)
    empty = M.overshoot_tail([])
    assert empty["n"] == 0 and empty["max"] is None and empty["over_10"] == 0


@functools.lru_cache(maxsize=None)
def _nominal_run(seed: int) -> tuple[list[dict], float]:
    """:func:`_simulate_nominal_run`'s run, once per seed (from the module's look-ahead workers
    while the module fixture below is active, test/prefetch.py)."""
    return _AHEAD.result(seed)


@functools.cache
def _robustness_bench():
    """``benchmarks/robustness.py`` as a module, once per process (conftest's
    ``robustness_bench`` fixture is not at hand in a look-ahead worker)."""
    from conftest import load_benchmark
    return load_benchmark("robustness")


def _simulate_nominal_run(seed: int) -> tuple[list[dict], float]:
    """Plateau results of nominal-box run ``seed`` and the largest |held load| (N*m) the default
    mode's hold learned during it."""
    rb = _robustness_bench()
    case = rb.sample_case(seed, "nominal")
    sc = rb.case_scenario(case)
    p, c = sim.build(sc, rb.plant_overrides(case), rb.controller_knowledge(case), None, DEFAULT_MODE)
    held = [0.0]
    exchange = sim.exchange_period

    def watched(driver, plant, t, demand_pct):
        out = exchange(driver, plant, t, demand_pct)
        law = driver.controller.law
        held[0] = max(held[0], abs(getattr(law, "main", law).held_load))
        return out

    sim.exchange_period = watched
    try:
        res = sim.simulate(sc, p, c)
    finally:
        sim.exchange_period = exchange
    log = res.log
    tr = M.Trace(log[:, 0], log[:, 1], log[:, 2], np.hypot(log[:, 7], log[:, 8]), log[:, 9], res.stroke_rad)
    return M.plateau_results(tr), held[0]


#: the nominal-box runs whose plateau steps overshot > 50 % on main 807b5de (largest: 111.5, 70.9,
#: 62.8, 62.0, 189.3, 103.8 %)
_TAIL_SEEDS = (1038, 1036, 1019, 1009, 2008, 2007)
#: the module's look-ahead runs (test/prefetch.py); none outside the module fixture below
_AHEAD = ModuleRuns(_simulate_nominal_run)


@pytest.fixture(scope="module", autouse=True)
def _look_ahead(request):
    """The module's nominal-box runs on both cores (test/prefetch.py); each test still takes and
    asserts its own run."""
    keys = [(item.callspec.params["seed"],) for item in selected_items(request)
            if item.originalname in ("test_a_load_free_valve_learns_no_load_from_the_integrators_breakaway",
                                     "test_nominal_box_plateau_steps_do_not_overshoot_by_half_the_step")]
    with _AHEAD.planned(keys, jobs(request.config)):
        yield


@pytest.mark.slow
@pytest.mark.parametrize("seed", _TAIL_SEEDS)
def test_a_load_free_valve_learns_no_load_from_the_integrators_breakaway(seed):
    """The nominal box has no load beyond the known one.  A relax slip is a valve let go by the
    relaxing drive; the breakaway the integrator and stuck ramp force toward a followed step is
    not one (on main the hold learned 2.76-2.86 N*m in each of these runs)."""
    _, held = _nominal_run(seed)
    assert held < 0.25 * _STATIC_NM


@pytest.mark.slow
@pytest.mark.parametrize("seed", _TAIL_SEEDS)
def test_nominal_box_plateau_steps_do_not_overshoot_by_half_the_step(seed):
    plats, _ = _nominal_run(seed)
    overshoots = M.plateau_step_overshoots(plats, STROKE_RAD)
    assert overshoots and max(overshoots) <= 50.0
    assert not any(pl["hunts"] for pl in plats)
    assert all(math.isfinite(pl["final_error_rad"]) for pl in plats)


def _main_law():
    from fuel_valve_control.core.position_controller import PositionController
    law = PositionController(CONTROLLER_SPEC.defaults()).law
    return getattr(law, "main", law)


def _pull(law, way: float, edge_nm: float, periods: int = 20, start: float = 0.5) -> None:
    """The integrator pulls a stuck valve ``way`` (+1 opening) with the drive reaching ``edge_nm``
    (N*m beyond the known load), then it breaks loose and slides 1 mrad."""
    for i in range(periods):
        law._read_pull(True, True, start, 0.6, way * 3e-3, edge_nm * (i + 1) / periods, _STATIC_NM, 12.0)
    for k in range(1, 6):
        law._read_pull(True, False, start + way * 2e-4 * k, 0.6, way * 3e-3, edge_nm, _STATIC_NM, 12.0)


def test_the_integrators_breakaway_is_an_edge_at_the_drive_it_broke_away_at():
    law = _main_law()
    _pull(law, -1.0, -6.3)
    assert law.slip_edges.edges == {-1: pytest.approx(-6.3)}
    assert law.held_load == 0.0          # one edge: stored, no load from the half-static prior
    _pull(law, 1.0, 5.7)
    assert law.slip_edges.edges[1] == pytest.approx(5.7)
    assert law.held_load == pytest.approx(-0.3)      # both edges: their mean
    assert law.slip_edges.known


def test_a_pull_that_ends_inside_the_deadband_or_never_breaks_teaches_nothing():
    law = _main_law()
    for i in range(30):                  # stuck all along
        law._read_pull(True, True, 0.5, 0.6, 3e-3, -0.2 * i, _STATIC_NM, 12.0)
    law._read_pull(False, True, 0.5, 0.6, 1e-4, -6.0, _STATIC_NM, 12.0)     # back inside: the pull lapses
    law._read_pull(True, False, 0.499, 0.6, 3e-3, -6.0, _STATIC_NM, 12.0)
    assert law.slip_edges.edges == {} and law.held_load == 0.0


def test_a_pull_under_a_moving_demand_is_no_edge():
    """A followed ramp: the valve stick-slips with the reference; no slip there is a band edge."""
    law = _main_law()
    for i in range(20):
        law._read_pull(True, True, 0.5, 0.6 + 1e-5 * i, 3e-3, 0.3 * i, _STATIC_NM, 12.0)
    law._read_pull(True, False, 0.5012, 0.6 + 2e-4, 3e-3, 6.0, _STATIC_NM, 12.0)
    assert law.slip_edges.edges == {}
