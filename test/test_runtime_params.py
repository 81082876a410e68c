"""Run-time parameters without ROS: every controller parameter marked run-time reaches what
uses it (the law is rebuilt from it, the current limiter is reconfigured, or the driver reads it
from the swapped set every period), changes are atomic and bumpless, and the config files are
the ones the schemas generate.  The same through the ROS parameter services: ``test_parameters.py``.
"""
from __future__ import annotations

import functools
from typing import Any, Iterator, Mapping

import numpy as np
import pytest

from fuel_valve_control import __main__ as config_tool
from fuel_valve_control.common.paramspec import ConfigError, Param, read_ros_param_file
from fuel_valve_control.common.config_dir import default_config_dir
from fuel_valve_control.core import driver as D
from fuel_valve_control.core.driver import ValveDriver
from fuel_valve_control.core.params import CONTROLLER_SPEC, MODES, TIGHTEN_ONLY, load_controller_params
from fuel_valve_control.core.position_controller import PositionController
from fuel_valve_control.tools.sim import exchange_period
from fuel_valve_plant.physics.params import load_plant_params
from fuel_valve_plant.physics.plant import Plant
from snapshots import Snapshots

#: run-time parameters that can change from their defaults (demand_timeout_action's default,
#: trip, is its tightest choice: it only changes at start-up)
RUNTIME = [p.name for p in CONTROLLER_SPEC if p.runtime and not (
    isinstance(TIGHTEN_ONLY.get(p.name), tuple) and TIGHTEN_ONLY[p.name][-1] == p.default)]
LAW_KEYS = {mode: PositionController(CONTROLLER_SPEC.defaults().replace({"mode": mode})).law_params
            for mode in MODES}
LIMIT_KEYS = {"limits.peak_current_a", "limits.peak_time_s", "limits.continuous_current_a"}


def changed_value(p: Param) -> Any:
    """A valid value different from the default; for a rating/supervision limit a tighter one
    (they only tighten at run time, ``test_safety.py``)."""
    rule = TIGHTEN_ONLY.get(p.name)
    if p.choices is not None:
        if isinstance(rule, tuple):
            return rule[rule.index(p.default) + 1]          # IndexError: none tighter (see RUNTIME)
        return next(c for c in p.choices if c != p.default)
    if p.kind is bool:
        return not p.default
    if p.kind is list:
        return p.coerce(p.default[:1], "test")              # a shorter list
    low, high = p.low or 0.0, p.high or 1.0
    candidates = (p.default * 0.8, p.default * 1.2, low + 0.5 * (high - low), low + 0.75 * (high - low))
    if rule is not None:
        candidates = (p.default * (1.0 + 0.2 * rule),)
    for candidate in candidates:
        value = p.kind(candidate)
        if value != p.default:
            try:
                return p.coerce(value, "test")
            except ConfigError:
                continue
    raise AssertionError(f"no other valid value for {p.name}")


class Reads(Mapping[str, Any]):
    """A parameter set view that records what was read."""

    def __init__(self, values):
        self.values, self.read = values, set()

    def __getitem__(self, name):
        self.read.add(name)
        return self.values[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self.values)

    def __len__(self):
        return len(self.values)


def closed_loop(drv: ValveDriver, plant: Plant, t0: float, periods: int, demand_pct: float) -> list[float]:
    """Run the offline simulator's loop for ``periods``; the current commands, A."""
    currents = []
    for k in range(periods):
        t = t0 + k * drv.period
        out, _ = exchange_period(drv, plant, t, demand_pct)
        currents.append(out.current_a)
        plant.set_command(out.current_a, out.enable)
        plant.advance(drv.period)
    return currents


def _fresh_held_loop(mode: str):
    """A driver in ``mode`` holding the valve at 30 % for 0.6 s (closed loop, real plant), run now."""
    plant = Plant(load_plant_params(overrides={"pressure_sensor.noise_kpa": 0.0}))
    drv = ValveDriver(load_controller_params(overrides={"mode": mode}))
    closed_loop(drv, plant, 0.0, 600, 30.0)
    return drv, plant


_HELD = Snapshots(_fresh_held_loop)


def held_loop(mode: str):
    """A driver in ``mode`` holding the valve at 30 % for 0.6 s (closed loop, real plant): a
    copy of one run per mode (snapshots.py; a copy continues bit for bit as a fresh run would:
    :func:`test_a_copied_held_loop_continues_as_a_fresh_run`), so the hundreds of cases below
    pay 0.6 s of simulated loop once per mode, not once or twice each."""
    return _HELD[mode]


def test_a_copied_held_loop_continues_as_a_fresh_run():
    """The premise of :func:`held_loop`'s cache (and test_fuzz's): two copies, the first run
    before the second is taken (nothing it does may reach the cache), and a new run give the
    same commands after the same change and the same move (every mode)."""
    def change_and_move(drv, plant):
        drv.set_params({"limits.peak_current_a": CONTROLLER_SPEC.params["limits.peak_current_a"].default * 0.9})
        return closed_loop(drv, plant, 0.6, 100, 34.0)

    for mode in MODES:
        first = change_and_move(*held_loop(mode))
        assert change_and_move(*held_loop(mode)) == first == change_and_move(*_fresh_held_loop(mode)), mode


# ------------------------------------------------------------------ coverage
def test_every_runtime_parameter_has_a_consumer():
    """Each run-time key is read by a law, the limiter or the driver's own loop (recorded while
    the loop runs through demands, Δp and its gap, a tracking error and a reset): a new run-time key that
    nothing reads fails here."""
    drv = ValveDriver(CONTROLLER_SPEC.defaults())
    drv.ps = Reads(drv.ps)
    drv.valve_health.configure(drv.ps)       # the NE107/counter core reads its own (set_params does this)
    for k in range(600):
        t = k * 1e-3
        drv.demand_percent(t, 90.0 if k > 100 else 20.0)            # a far demand: tracking error
        if k < 300 or k >= 450:                                      # stale between (armed): the fallback,
            drv.pressure_differential(t, 3000.0)                     # then timely again (recovery)
        drv.resolver(t, 0.2 * 48.019, 0.2, now=t)                    # received on the loop clock
        drv.loop_timing(t, t + (0.01 if k >= 200 else 0.0))          # real time: one late arrival
        drv.step(t)
    drv.reset()
    drv.health()
    law_keys = set().union(*LAW_KEYS.values())
    filter_reads = Reads(CONTROLLER_SPEC.defaults())
    D.demand_filter_config(filter_reads)           # the demand conditioning, rebuilt by set_params
    # tests.*: read by core/valve_tests.py while a test runs (test_valve_tests.py checks them)
    orphans = (set(RUNTIME) - {"mode"} - law_keys - LIMIT_KEYS - drv.ps.read     # mode: picks the law
               - filter_reads.read - {k for k in RUNTIME if k.startswith("tests.")})
    assert not orphans, f"run-time parameters nothing reads: {sorted(orphans)}"


@pytest.mark.parametrize("name", RUNTIME)
def test_runtime_parameter_takes_effect(name):
    p = CONTROLLER_SPEC.params[name]
    value = changed_value(p)
    # a mode whose law reads it (else the default mode)
    mode = next((m for m in MODES if name in LAW_KEYS[m]), CONTROLLER_SPEC.params["mode"].default)
    drv, plant = held_loop(mode)
    law_before = drv.controller.law
    drv.set_params({name: value})
    assert drv.ps[name] == value and drv.controller.ps[name] == value
    new_mode = value if name == "mode" else mode
    if name == "mode" or name in LAW_KEYS[mode]:
        # the running law was rebuilt, and its build read the new value
        assert drv.controller.law is not law_before
        assert name == "mode" or name in drv.controller.law_params
        assert drv.controller.law_params == LAW_KEYS[new_mode]
    else:
        assert drv.controller.law is law_before          # unrelated changes keep the law's state
    if name in LIMIT_KEYS:
        assert drv.controller.current_limits == (drv.ps["limits.peak_current_a"], (
            drv.ps["limits.peak_current_a"] ** 2 - min(drv.ps["limits.continuous_current_a"],
                                                       drv.ps["limits.peak_current_a"]) ** 2)
            * drv.ps["limits.peak_time_s"])
    closed_loop(drv, plant, 0.6, 5, 30.0)                # and the loop keeps running with it


# ------------------------------------------------------------------ the keys of the bug report
@pytest.mark.parametrize("mode, name, value", [
    ("observer_ff", "ff.stuck_speed_rad_s", 0.3),
    ("observer_ff", "ff.static_start", True),
    ("observer_ff", "ff.velocity_smoothing_rad_s", 0.1),
    ("pi_dither", "pi.dither_pct", 3.0),
    ("pi_dither", "pi.dither_hz", 60.0),
])
def test_feedforward_and_dither_changes_change_the_behaviour(mode, name, value):
    """ff.* and pi.dither_* were accepted but ignored: the command after the change (a move
    from 30 to 34 %) must differ from the unchanged run's."""
    b, pb = held_loop(mode)
    b.set_params({name: value})
    ia = _unchanged(mode, 400, 34.0)
    ib = closed_loop(b, pb, 0.6, 400, 34.0)
    assert max(abs(x - y) for x, y in zip(ia, ib)) > 0.05


#: replacements whose new law restarts estimators that matter at this hold (the friction
#: observers, the reference feed-forward's stuck/moving state, the dither phase): the command
#: continues in the period of the change, but the fresh estimators then move it faster than
#: the running law does (measured: up to 10.7 A per period for fp.*).  observer_ff -> observer_fc
#: / kalman_fc are bumpless since their observers start balanced on the measured twist and the
#: valve friction term acts only while the reference moves (issue 14)
RESTARTS_ESTIMATORS = {("fp.compensation_fraction", None),
                       ("pi.dither_pct", None)} | {(f"fp.{shaft}.{k}", None) for shaft in ("motor", "valve")
                                                    for k in ("alpha", "beta", "freeze_velocity_rad_s", "gain_cap")}
_XFAIL = pytest.mark.xfail(strict=True, reason="a rebuilt law restarts its estimators (friction observers, "
                           "feed-forward state) instead of taking over the running law's: bumpless only in the "
                           "period of the change, a transient follows (state transfer between laws: not done)")
# (a rebuilt fine-positioning stage, observer_fp, restarted its engage/preload/pulse sequence on a
# valve already parked, 1.2-1.8 A steps; since task h16f it engages only after it has seen the main
# law break the valve loose, so a rebuilt stage waits: bumpless, no mark)


def _marks(name, value):
    if (name, value) in RESTARTS_ESTIMATORS:
        return [_XFAIL]
    return []


BUMPLESS_CASES = [pytest.param(mode, name, value, marks=_marks(name, value))
                  for mode, name, value in
                  [("observer_ff", "mode", m) for m in MODES if m != "observer_ff"]
                  + [(next(m for m in MODES if k in LAW_KEYS[m]), k, None)
                     for k in sorted(set().union(*LAW_KEYS.values()) & set(RUNTIME))]]


@functools.cache
def _unchanged(mode: str, periods: int, demand_pct: float) -> tuple[float, ...]:
    """The held loop's commands over ``periods`` after 0.6 s, with no change, A."""
    a, pa = held_loop(mode)
    return tuple(closed_loop(a, pa, 0.6, periods, demand_pct))


@functools.cache
def _replace_law(mode, name, value):
    """(unchanged run's, changed run's) commands over the 50 periods after the change (once per
    case: both tests below read it)."""
    b, pb = held_loop(mode)
    law = b.controller.law
    b.set_params({name: changed_value(CONTROLLER_SPEC.params[name]) if value is None else value})
    assert b.controller.law is not law
    return _unchanged(mode, 50, 30.0), tuple(closed_loop(b, pb, 0.6, 50, 30.0))


@pytest.mark.parametrize("mode, name, value", [c.values for c in BUMPLESS_CASES])
def test_command_continues_in_the_period_of_a_law_replacement(mode, name, value):
    ia, ib = _replace_law(mode, name, value)
    assert abs(ia[0] - ib[0]) < 1e-9


@pytest.mark.parametrize("mode, name, value", BUMPLESS_CASES)
def test_law_replacement_is_bumpless(mode, name, value):
    """After a change that replaces the law the command moves no more per period, over the
    next 50 periods, than the unchanged run's does (plus 0.3 A)."""
    ia, ib = _replace_law(mode, name, value)
    steps_a = np.abs(np.diff(ia)).max()
    assert np.abs(np.diff(ib)).max() < steps_a + 0.3, (np.abs(np.diff(ib)).max(), steps_a)


def test_set_params_is_atomic():
    drv, _ = held_loop("observer_ff")
    ps, law = drv.ps, drv.controller.law
    with pytest.raises(ValueError):      # a good value with a bad one: nothing changes
        drv.set_params({"ff.stuck_speed_rad_s": 0.2, "limits.continuous_current_a": 39.0})
    with pytest.raises(ValueError, match="cannot change at run time"):
        drv.set_params({"ff.stuck_speed_rad_s": 0.2, "loop_rate_hz": 500.0})
    assert drv.ps is ps and drv.controller.law is law and drv.controller.ps is ps
    drv.check_params({"ff.stuck_speed_rad_s": 0.2})          # validation alone changes nothing
    assert drv.ps is ps and drv.controller.law is law


# ------------------------------------------------------------------ config files
@pytest.mark.parametrize("node", ["plant", "controller", "demand"])
def test_config_files_are_generated_from_the_schemas(node):
    path = default_config_dir() / f"{node}.yaml"
    assert path.read_text() == config_tool.config_text(node), \
        f"{path} differs from its schema: run python -m fuel_valve_control write-config"
    spec = config_tool.node_schemas()[node][0]
    assert set(read_ros_param_file(path)) == set(spec.params)


def test_a_law_replaced_while_the_fine_stage_holds_continues_from_its_hold_command():
    """A run-time change that replaces the law while the fine stage holds a finished plateau: the successor continues
    from the stage's hold command, not from the static hold of the twist -- they differ by the hold servo's integral.
    C3's options (docs §104) reach the held loop's 0.6 s in the stage's hold with that difference 0.41 A: the replaced
    law's second period stepped by it (the bumpless bound below is the unchanged run's largest step + 0.3 A)."""
    c3 = {"mode": "observer_fp", "fine.apex_level_law": "mixture", "fine.engage_gear_rest": 0.1,
          "fine.apex_floor_plan": True, "fine.handover_settle_speed_rad_s": 0.1, "fine.apex_stop_rad": 4.8e-4}
    runs = []
    for change in (False, True):
        plant = Plant(load_plant_params(overrides={"pressure_sensor.noise_kpa": 0.0}))
        drv = ValveDriver(load_controller_params(overrides=c3))
        closed_loop(drv, plant, 0.0, 600, 30.0)
        law = drv.controller.law
        assert law.fine.phase == "hold"
        fine = law.fine
        th1 = plant.truth().motor_angle / drv.controller.model.gear_ratio
        static = fine.hold_torque(th1, plant.truth().valve_angle) / drv.controller.model.torque_constant_nm_per_a
        assert abs(drv.controller.last_current - static) > 0.3      # the case: the hold's command is not the static hold
        if change:
            drv.set_params({"fine.tolerance_counts": 3.5})
        runs.append(np.array(closed_loop(drv, plant, 0.6, 50, 30.0)))
        if change:
            assert drv.controller.law is not law
    unchanged, replaced = runs
    assert np.abs(np.diff(replaced)).max() < np.abs(np.diff(unchanged)).max() + 0.3
