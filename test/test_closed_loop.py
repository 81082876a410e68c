"""Closed-loop targets of SPEC §6 in the offline simulator (plant + valve driver, no ROS).

* the default mode on the nominal plant at max Δp: stroke, overshoot, settling, hold
  (limit cycle, steady-state error), bandwidth, trip close time, peak current everywhere;
* the robustness box (friction x 0.5…3, Δp 0…max, coupling stiffness x 0.1…1, inertia
  ±20 %) at the same gains, every single-parameter extreme and every corner: stable, no
  hunting beyond the stick-slip jump ``2 (Ts - Tc)/K`` of *that* plant plus two counts, and
  small-step overshoot ≤ 10 %; the documented shortfalls (``docs/control_results.md`` §2)
  are ``xfail(strict=True)`` with the measured reason, so a fix shows as XPASS;
* the ``pi`` baseline shows the field problem the new controller removes.

Every number comes from a simulation run here; nothing is a stored result.  Runs are cached
per module so each scenario is simulated once.
"""
import functools
import itertools
import math

import pytest

from fuel_valve_control.tools import sim
from fuel_valve_control.core.params import DEFAULT_MODE
from fuel_valve_control.tools.metrics import RESOLVER_COUNT_RAD
from fuel_valve_control.tools.scenarios import builtin_names, load_scenario
from fuel_valve_plant.physics.friction import friction_levels
from fuel_valve_plant.physics.params import PLANT_SPEC
from prefetch import ModuleRuns, jobs, selected_items

TWO_COUNTS = 2.0 * RESOLVER_COUNT_RAD            # 1.92e-4 rad
SSE_TARGET = 1e-3                                 # SPEC §6 hold steady-state error, rad
P_MAX = 6206.0
_D = PLANT_SPEC.defaults()


def _run(scenario: str, mode: str = DEFAULT_MODE, plant: tuple = (), controller: tuple = (), seed=None):
    """Simulate a built-in scenario; overrides as sorted item tuples (hashable, cached)."""
    # every argument passed positionally: lru_cache keys ``_run("hold")`` and
    # ``_run("hold", seed=None)`` apart, and the same 30 s hold was simulated twice
    return _simulated(scenario, mode, plant, controller, seed)


@functools.lru_cache(maxsize=None)
def _simulated(scenario: str, mode: str, plant: tuple, controller: tuple, seed):
    return _AHEAD.result(scenario, mode, plant, controller, seed)


def _simulate(scenario: str, mode: str, plant: tuple, controller: tuple, seed):
    """The run itself (here or in a look-ahead worker, test/prefetch.py)."""
    sc = load_scenario(scenario)
    p, c = sim.build(sc, dict(plant), dict(controller), seed, mode)
    return sim.simulate(sc, p, c), p


#: the module's look-ahead runs (test/prefetch.py); none outside the module fixture below
_AHEAD = ModuleRuns(_simulate)


def _metrics(scenario, **kw):
    return _run(scenario, **kw)[0].metrics


_LOW_SUPPLY = dict(plant=(("supply_voltage_v", 18.0),), controller=(("drive.supply_voltage_v", 18.0),))


def _planned(item) -> list[tuple]:
    """The runs (``_simulated``'s arguments) a selected test of this module asks ``_run`` for;
    a run left out here is simulated when the test asks, as before."""
    name, params = item.originalname, getattr(getattr(item, "callspec", None), "params", {})
    nominal = ((), (), None)
    runs = {"test_full_stroke_time": [("full_stroke", {})],
            "test_large_step_overshoot": [("large_step", {})],
            "test_sine_sweep_bandwidth": [("sine_sweep", {})],
            "test_trip_closes_within_datasheet_time": [("trip", {})],
            "test_pi_dither_does_not_cure_hunting": [("hold", dict(mode="pi_dither"))],
            "test_pi_baseline_shows_the_field_limit_cycle": [("hold", dict(mode="pi")), ("step_small", dict(mode="pi")),
                                                             ("hold", {})]}.get(name)
    if runs is None and "seed" in params:
        runs = [({"test_hold_no_hunting_and_small_error": "hold"}.get(name, "step_small"), dict(seed=params["seed"]))]
    elif runs is None and "scenario" in params:
        runs = [(params["scenario"], {})]
        if name == "test_moves_at_the_low_supply_slow_down_instead_of_saturating":
            runs.append((params["scenario"], _LOW_SUPPLY))
    elif runs is None and "c" in params:
        plant, ctrl = corner(**params["c"])
        if name in ("test_adaptation_grid_small_step_overshoot_without_hunting", "test_breakaway_start_on_a_soft_coupling"):
            ctrl = BREAKAWAY_START
        runs = [("hold" if "hold" in name else "step_small", dict(plant=plant, controller=ctrl))]
    keys = []
    for scenario, kw in runs or []:
        plant, controller, seed = kw.get("plant", nominal[0]), kw.get("controller", nominal[1]), kw.get("seed")
        keys.append((scenario, kw.get("mode", DEFAULT_MODE), plant, controller, seed))
    return keys


@pytest.fixture(scope="module", autouse=True)
def _look_ahead(request):
    """The module's runs on both cores (test/prefetch.py), the 30 s holds first; each test
    still takes and asserts its own run."""
    keys = [key for item in selected_items(request) for key in _planned(item)]
    keys.sort(key=lambda k: -load_scenario(k[0]).duration_s)      # stable: the longest first
    with _AHEAD.planned(keys, jobs(request.config)):
        yield


# ============================================================================ nominal targets
def test_full_stroke_time():
    """Issue 14: full stroke to 98 % at 28 V within 0.100 s (the planned move's top speed is
    designed from the back-EMF the 28 V supply leaves room for), no overshoot, <= 30 A."""
    m = _metrics("full_stroke")
    # the metric is quantised to the 1 ms loop period: 0.100 s (+ rounding) meets "<= 0.100 s"
    assert m["stroke_time_s"] is not None and m["stroke_time_s"] <= 0.100 + 1e-9
    assert m["overshoot_pct"] <= 1.0
    assert m["peak_current_a"] <= 30.0


@pytest.mark.parametrize("scenario", ["full_stroke", "large_step"])
def test_moves_at_the_low_supply_slow_down_instead_of_saturating(scenario):
    """At 18 V (the data sheet's low end) the controller, told the supply, plans slower moves
    the drive's voltage can follow: no overshoot, no current beyond the target, and slower
    than at 28 V (the plan follows the supply)."""
    low = _metrics(scenario, plant=(("supply_voltage_v", 18.0),), controller=(("drive.supply_voltage_v", 18.0),))
    nominal = _metrics(scenario)
    assert low["overshoot_pct"] <= 1.0
    assert low["peak_current_a"] <= 30.0
    assert low["settling_time_s"] is not None and low["settling_time_s"] > nominal["settling_time_s"]


def test_large_step_overshoot():
    m = _metrics("large_step")
    assert m["overshoot_pct"] <= 1.0
    assert m["settling_time_s"] is not None


@pytest.mark.parametrize("seed", [None, 1, 2])
def test_small_step_overshoot_and_settling(seed):
    m = _metrics("step_small", seed=seed)
    assert m["overshoot_pct"] <= 2.0
    assert m["settling_time_s"] is not None and m["settling_time_s"] <= 0.2
    assert m["rise_time_s"] <= 0.2


# The hold is 30 s (settled half 15-30 s) on purpose; do not shorten it to save time (h24t measured):
# an integrator winding up through the static friction starts hunting late, and when is erratic:
# pi first slips at 11.7 s, pi with integral_corner_ratio 0.12 / 0.5 / 0.15 / 0.2 / 0.3 at
# 9.7 / 14.3 / 14.8 / 17.6 / 23.4 s.  On a 10 s hold this test passes pi (amplitude 0, error
# 3.3e-4 rad); on a 20 s hold it passes the 0.3 variant.  Every default-mode hold here (3 seeds,
# 22 box corners) already gives the 30 s run's metrics when cut at 6 s: on main a cut would show nothing.
@pytest.mark.parametrize("seed", [None, 1, 2])
def test_hold_no_hunting_and_small_error(seed):
    m = _metrics("hold", seed=seed)
    assert m["limit_cycle_amplitude_rad"] <= TWO_COUNTS
    assert m["steady_state_error_rad"] <= SSE_TARGET


def test_sine_sweep_bandwidth():
    assert _metrics("sine_sweep")["bandwidth_hz"] >= 8.0


def test_trip_closes_within_datasheet_time():
    res, _ = _run("trip")
    assert res.metrics["close_time_s"] is not None and res.metrics["close_time_s"] <= 0.120
    # the drive really is off after the trip: zero current command
    t, i_cmd = res.column("t"), res.column("current_cmd_a")
    assert all(abs(i) < 1e-9 for i in i_cmd[t > 0.31])


@pytest.mark.parametrize("scenario", builtin_names())
def test_peak_current_within_rating(scenario):
    res, _ = _run(scenario)
    assert math.isfinite(res.metrics["peak_current_a"])
    assert res.metrics["peak_current_a"] <= 37.0
    assert all(math.isfinite(v) for v in res.column("position_rad"))


@pytest.mark.parametrize("scenario", ["startup", "load_step"])
def test_startup_and_load_step_hold_without_hunting(scenario):
    m = _metrics(scenario)
    assert m["limit_cycle_amplitude_rad"] <= TWO_COUNTS
    # the valve stops inside the integrator deadband (0.55 x the 4.6e-3 rad jump at max Δp),
    # so after the start-up ramps the error is bounded by that, not by the 1e-3 hold target
    # (measured 2.6e-3 rad; see docs/control_results.md)
    _, ps = _run(scenario)
    jump = friction_levels(ps).stick_slip_jump_rad(ps["coupling.stiffness_nm_per_rad"])
    assert m["steady_state_error_rad"] <= 0.6 * jump


# ============================================================================ robustness box
def corner(friction=1.0, dp=P_MAX, stiffness=1.0, inertia=1.0):
    """(plant overrides, controller overrides) as hashable tuples.  The controller keeps its
    nominal model (same gains) and measures Δp on the plant's pressure_differential output."""
    plant = {"friction_scale": friction, "pressure_differential_kpa": dp,
             "coupling.stiffness_nm_per_rad": _D["coupling.stiffness_nm_per_rad"] * stiffness,
             "motor.inertia_kgm2": _D["motor.inertia_kgm2"] * inertia,
             "valve.inertia_kgm2": _D["valve.inertia_kgm2"] * inertia}
    return tuple(sorted(plant.items())), ()


def _id(c):
    return "-".join(f"{k}{v:g}" for k, v in c.items()) or "nominal"


NOMINAL = dict(friction=1.0, dp=P_MAX, stiffness=1.0, inertia=1.0)
AXES = dict(friction=(0.5, 3.0), dp=(0.0, P_MAX), stiffness=(0.1, 1.0), inertia=(0.8, 1.2))


def _box() -> list[dict]:
    """The robustness box of SPEC §6 as ``benchmarks/control_quality.py`` runs it: the six
    single-parameter extremes and the 16 corners (the nominal plant has its own tests above).
    Each as the overrides that differ from nominal (also the test id)."""
    full = [{**NOMINAL, axis: v} for axis, values in AXES.items() for v in values if v != NOMINAL[axis]]
    full += [c for c in (dict(zip(AXES, combo)) for combo in itertools.product(*AXES.values()))
             if c not in full]
    return [{k: v for k, v in c.items() if v != NOMINAL[k]} for c in full]


BOX = _box()


def _key(c: dict) -> frozenset:
    return frozenset(c.items())


def _cases(shortfalls: dict) -> list:
    """Every corner of the box; a documented shortfall (docs/control_results.md §2) is an
    ``xfail(strict=True)`` with its measured reason, so it is seen to fail and a fix shows."""
    unknown = set(shortfalls) - {_key(c) for c in BOX}
    assert not unknown, f"shortfalls outside the box: {unknown}"
    return [pytest.param(c, id=_id(c), marks=[pytest.mark.xfail(strict=True, reason=shortfalls[_key(c)])]
                         if _key(c) in shortfalls else []) for c in BOX]


def _corner(**c) -> frozenset:
    return _key(c)


# hold: where the default mode ends farther from the demand than that plant's own jump + 2 counts
HOLD_SHORTFALLS = {
    _corner(friction=0.5, dp=0.0, inertia=1.2):
        "stops 2.9e-3 rad from the demand (observer_fp, the default since h18s; observer_ff 1.5e-3; target 1e-3; "
        "the fine stage stays out at Δp 0, fine.min_jump_rad) since the planned moves' limits are designed "
        "from the drive's voltage and current (issue 14, h14c): where the faster arrival sticks inside "
        "the integrator deadband is a coin flip of the stick-slip (the F x0.5 J x0.8 corner at max Δp, "
        "3.1e-3 rad before, now passes); no hunting",
    _corner(friction=3.0, dp=0.0, inertia=1.2):
        "stops 1.9e-3 rad from the demand (band: jump + 2 counts = 1.4e-3; observer_fp as observer_ff: the fine "
        "stage stays out at Δp 0), no hunting, since the default mode's "
        "limit-cycle breaker is on (h16w, JumpLearner(cross_hold)): a breakaway across the target widens both "
        "directions' deadband to its own jump and the valve may stop anywhere inside it (5.4e-4 rad without it)",
}

_FF_LOW = ("the friction feed-forward is scheduled on the nominal friction and a 2 % step is too short "
           "to adapt it: the valve gets about twice the breakaway torque it needs")
_FLOOR = ("physics: the stick-slip jump 2(Ts-Tc)/K exceeds the 0.021 rad step, so a quasi-static "
          "breakaway overshoots by at least the jump whatever the controller")
# small step: where overshoot > 10 % (docs/control_results.md §2, benchmarks/control_quality.py)
STEP_SHORTFALLS = {
    # (observer_fp, the default since h18s, as observer_ff within 1 %: the overshoot is the main law's move)
    # (friction=0.5 with inertia x0.8 / 1 / 1.2 at max Δp) overshot 31-37 % (the feed-forward
    # scheduled on the nominal friction) until the move's breakaway reading became the default
    # (ff.read_breakaway, h21g/h22g/h24g, docs/control_results.md §31, §34, §43): 0.4-1.6 %
    # (friction=3.0 with inertia x0.8 / 1 / 1.2) overshot 43-45 % (the friction feed-forward a
    # third of the real breakaway torque, the stuck ramp wound the coupling to the real Ts and the
    # valve let go with the stored twist, jump 0.0137 rad > remaining error) until the jump
    # learner read whole, noise-filtered slides per direction (h14r): now within 10 %
    # (inertia=0.8) overshot 20.9 % with observer_ff as the default (the acceleration feed-forward and
    # the observer built on the nominal inertias over-drive a 20 % lighter drivetrain at the start,
    # and its deadband holds the valve there); observer_fp, the default since h18s: 0 %, settled in
    # 0.047 s, 3.2e-5 rad (the fine stage finishes the move the main law stopped)
    # K x 0.1 corners that pass since the hold's stiffness reading became the default (integral.read_stiffness,
    # stop 19, docs/control_results.md §41, §45: the hold's jump sized on the coupling read at rest):
    # (stiffness=0.1) overshot 123 % against a physical floor of 119 % (jump 0.046 rad > the 0.021 rad step);
    # (friction=3.0, stiffness=0.1, inertia=0.8 / 1.2) 451 / 467 % against a floor of 557 % (jump 0.137 rad);
    # (friction=0.5, stiffness=0.1, inertia=0.8 / 1.2) 22.2 / 32.2 % against a floor of 9.4 % (jump 0.023 rad):
    # where the jump read exceeds the step the valve now stays, its error the step itself (within the jump +
    # 2 counts this test allows; at F x 0.5 that is 2.09e-2 rad left where the moving valve had ended 4.7-6.7e-3
    # off: the cost, stated in §45; since the floor is probed, h26k §52, those two follow the step again, below);
    # (friction=0.5, dp=0.0, stiffness=0.1, inertia=1.2) 10.6 %.
    _corner(friction=0.5, dp=0.0, stiffness=0.1, inertia=0.8):
        "steady-state error 2.49e-3 rad against the jump + 2 counts 2.28e-3 since the hold's stiffness reading "
        "became the default (stop 19, integral.read_stiffness; before: 4.7 % overshoot, within).  Traced (docs "
        "section 52): the coupling-snap feed-forward of the coupling read 10x soft asks ~10x the 30 A cap of the "
        "20 ms move; clipped there, the command rings +-30 A at 4-6 ms, the valve is dragged 8 mrad back before it "
        "is thrown forward and stops 2.49e-3 short, inside the 5.2e-3 rad deadband the start-up swing taught "
        "(jumps 22-28x nominal in the first 70 ms, before the first stiffness reading); the compensator not told "
        "the reading (no snap): 4.7 %, 9.8e-4 rad.  With ff.snap_fit_cap (off; section 57: the term from the plan, "
        "a period earlier and its first positive snap fed; the cap fit's factor is 0.998 here): 0 %, 1.33e-3 rad, "
        "within; kept off for the full box's plateaus > 8e-4 (1881 -> 1904)",
    **{_corner(friction=0.5, stiffness=0.1, inertia=j): (
        f"overshoot {pct} % against a physical floor of 9.4 % (the valve's jump 2.3e-2 rad > the 2.1e-2 rad step), "
        f"end error {err} rad: the valve follows the step since the hold's floor is probed "
        "(integral.probe_soft_floor, docs section 52; stop 19: it never moved, 2.09e-2 rad off; stop 18, without the "
        "stiffness reading: 22.2 / 32.2 %, 4.7 / 6.7e-3 rad); the jump on this soft coupling is 1.13x quasi-static")
       for j, pct, err in ((0.8, 17.8, "3.7e-3"), (1.2, 26.7, "5.6e-3"))},
    _corner(friction=3.0, dp=0.0, stiffness=0.1, inertia=1.2):
        "overshoot 13.4 % since the hold's stiffness reading became the default (stop 19, integral.read_stiffness; "
        "before 8.5-8.8 %).  Traced (docs section 52): the coupling-snap feed-forward of a coupling read 10x soft, "
        "~10x the 30 A cap on the 20 ms move and clipped there: the compensator not told the reading, 0 % and "
        "9.9e-5 rad; but the K x 0.1 Δp-0 friction x 1 cell needs it (25.1 -> 8.0 %).  With ff.snap_fit_cap (off, "
        "section 57): 18.0 %, worse",
    # (friction=3.0, dp=0.0, stiffness=0.1, inertia=1.2) overshot 20-28 % until the observers
    # started in equilibrium with the measured twist (h14a): the soft coupling's initial twist
    # had read as a 10x torque; now 8.8 / 8.8 / 8.5 % over seeds 0-2
}


@pytest.mark.slow
@pytest.mark.parametrize("c", _cases(HOLD_SHORTFALLS))
def test_robust_hold_is_stable_without_hunting_beyond_the_jump(c):
    plant, ctrl = corner(**c)
    res, ps = _run("hold", plant=plant, controller=ctrl)
    m = res.metrics
    jump = friction_levels(ps).stick_slip_jump_rad(ps["coupling.stiffness_nm_per_rad"])
    allowance = jump + TWO_COUNTS
    # hunting: peak-to-peak of the settled half within one physical jump plus two counts
    assert 2.0 * m["limit_cycle_amplitude_rad"] <= allowance, f"p-p {2 * m['limit_cycle_amplitude_rad']:.3g} > {allowance:.3g}"
    # stable: drive still on (no fault), current bounded, and the valve ended near the demand:
    # within the nominal accuracy target or, where friction is wider, within one jump
    assert res.column("enable")[-1] > 0.5
    band = max(SSE_TARGET, allowance)
    assert m["steady_state_error_rad"] <= band
    assert abs(res.column("demand_rad")[-1] - res.column("position_rad")[-1]) <= band
    assert m["peak_current_a"] <= 37.0


@pytest.mark.slow
@pytest.mark.parametrize("c", _cases(STEP_SHORTFALLS))
def test_robust_small_step_overshoot(c):
    plant, ctrl = corner(**c)
    res, ps = _run("step_small", plant=plant, controller=ctrl)
    m = res.metrics
    assert m["overshoot_pct"] <= 10.0
    jump = friction_levels(ps).stick_slip_jump_rad(ps["coupling.stiffness_nm_per_rad"])
    assert m["steady_state_error_rad"] <= max(SSE_TARGET, jump + TWO_COUNTS)
    assert m["peak_current_a"] <= 37.0


# ===================================================== adaptation grid (issue 14, Deliver 2)
#: the 2 % step over friction x inertia x Δp at K nominal (benchmarks/adaptation_grid.py) with
#: the default mode's move started on breakaway (trajectory.breakaway_wait_s; off by default, see
#: docs/control_results.md §9): issue 14's target is <= 10 % overshoot, <= 5 % the aim; with
#: the move on the clock (the default) 7 of these 18 cells miss 10 % (F x0.5 at max Δp 31-37 %,
#: F x3 at max Δp 43-45 %, J -20 % 23.5 %) and 4 hunt
ADAPTATION_GRID = [dict(friction=f, dp=dp, inertia=j)
                   for f in (0.5, 1.0, 3.0) for j in (0.8, 1.0, 1.2) for dp in (0.0, P_MAX)]
BREAKAWAY_START = (("trajectory.breakaway_wait_s", 0.25),)
HUNT_WINDOW_S = 1.0    # the last second of step_small (the step is at 0.5 s)


# the reasons below hold for observer_fp, the default since h18s (measured: 1.6 % / 2.7 % with the tail
# slips; the fine stage stays out at Δp 0, fine.min_jump_rad; the K x 0.3 F x 3 max-Δp cells 90.6-91.2 %)
GRID_SHORTFALLS = {
    _corner(friction=3.0, dp=0.0, inertia=1.2):
        "overshoot 1.6 %, but one late slip in the last second: 1.2x the jump + 2 counts "
        "(jump 1.25e-3 rad at Δp 0); the integrator's stuck ramp finishing a move that stopped "
        "short",
    _corner(friction=1.0, dp=0.0, inertia=1.0):
        "overshoot 2.6 %, but the move ends 5e-4 rad short and the hold's stuck ramp corrects it by "
        "slips of 5.6e-4 rad past and back: tail 1.6x the jump + 2 counts (jump 4.6e-4 rad at Δp 0); "
        "the hold's small Δp-0 deadband, not the move (h16g: the end point moved with the wind-up's "
        "stiffness reading)",
}
#: the same grid on a coupling K x 0.3 (issue 14 Deliver 2: the same default must hold on
#: stiffness x 0.3...1): overshoot only (the friction x 3 cells at Δp 0 slip in the tail, within
#: their own jump's scale)
SOFT_GRID = [dict(c, stiffness=0.3) for c in ADAPTATION_GRID]
SOFT_GRID_SHORTFALLS = {
    _corner(friction=3.0, dp=P_MAX, inertia=j, stiffness=0.3):
        "91 % overshoot: at friction x 3, max Δp on K x 0.3 the stick-slip jump 2 (Ts - Tc)/K is "
        "4.6e-2 rad, 2.2x the 2 % step; the retreat over one valve period does not take that back "
        "(119 % for a quasi-static breakaway; 130 % on the clock)"
    for j in (0.8, 1.0, 1.2)
}


def _grid_cases(grid=ADAPTATION_GRID, shortfalls=GRID_SHORTFALLS) -> list:
    return [pytest.param(c, id=_id({k: v for k, v in c.items() if v != NOMINAL[k]}),
                         marks=[pytest.mark.xfail(strict=True, reason=shortfalls[_key(c)])]
                         if _key(c) in shortfalls else []) for c in grid]


@pytest.mark.slow
@pytest.mark.parametrize("c", _grid_cases())
def test_adaptation_grid_small_step_overshoot_without_hunting(c):
    plant, _ = corner(**c)
    res, ps = _run("step_small", plant=plant, controller=BREAKAWAY_START)
    m = res.metrics
    assert m["overshoot_pct"] <= 10.0        # issue 14's target (measured: <= 5.4 %)
    assert m["settling_time_s"] is not None and m["settling_time_s"] <= 0.2
    assert m["peak_current_a"] <= 30.0
    # no hunting: over the last second the valve moves less than one stick-slip jump of that
    # plant plus two counts (at rest it does not move at all)
    jump = friction_levels(ps).stick_slip_jump_rad(ps["coupling.stiffness_nm_per_rad"])
    t, pos = res.column("t"), res.column("position_rad")
    tail = pos[t >= t[-1] - HUNT_WINDOW_S]
    assert tail.max() - tail.min() <= jump + TWO_COUNTS


@pytest.mark.slow
@pytest.mark.parametrize("c", _grid_cases(SOFT_GRID, SOFT_GRID_SHORTFALLS))
def test_breakaway_start_on_a_soft_coupling(c):
    """K x 0.3: the wind-up reads the coupling (K_model / K ~ 3.3), the retreat and the
    coupling-snap feed-forward are sized by it (before h16g: 17-30 % in 15 of these cells)."""
    plant, _ = corner(**c)
    m = _metrics("step_small", plant=plant, controller=BREAKAWAY_START)
    assert m["overshoot_pct"] <= 10.0
    assert m["peak_current_a"] <= 30.0


# ============================================================================ pi baseline
def test_pi_baseline_shows_the_field_limit_cycle():
    hold = _metrics("hold", mode="pi")
    # limit cycle of order 0.01 rad at a low frequency (SPEC §3: ~1 Hz in the field, 1.25 Hz in
    # the dissertation; this plant and tuning give ~0.2 Hz)
    assert 3e-3 <= hold["limit_cycle_amplitude_rad"] <= 3e-2
    assert 0.05 <= hold["limit_cycle_frequency_hz"] <= 2.0
    assert hold["overshoot_pct"] > 5.0
    step = _metrics("step_small", mode="pi")
    assert step["overshoot_pct"] > 10.0
    # the default controller removes it: at least 10x smaller (it is in fact below two counts)
    assert _metrics("hold")["limit_cycle_amplitude_rad"] <= 0.1 * hold["limit_cycle_amplitude_rad"]


def test_pi_dither_does_not_cure_hunting():
    m = _metrics("hold", mode="pi_dither")
    assert m["limit_cycle_amplitude_rad"] > TWO_COUNTS
