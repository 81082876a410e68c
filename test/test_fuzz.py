"""Fault-injection and fuzz campaign, ROS-free part (issue 13, item 10): the same core objects
the nodes run (``ValveDriver`` behind the controller node, ``Plant`` behind the plant node,
the demand profile behind the demand node), closed loop as in the offline simulator.

Generated, so new inputs and parameters are covered without editing this file:

* every input of the controller (the topics it subscribes to, :data:`CONTROLLER_INPUTS`,
  checked against the node's real subscriptions in ``test_fuzz_nodes.py``) gets NaN, ±inf,
  huge, negative, out-of-range values and wrong stamps, once and as a 50-period burst;
* every parameter of every node's schema (the one schema per node: ``CONTROLLER_NODE_SPEC``,
  ``PLANT_NODE_SPEC``, ``DEMAND_NODE_SPEC``) gets its boundary values (min, max, just outside),
  NaN/inf, a wrong type; run-time ones through the node's own run-time path
  (``prepare_params``/``request_params``, ``Plant.check_params``, ``profile_from_params``), the
  rest at start-up;
* trip and reset at odd times (before any input, twice, reset before trip, during a fault).

What must hold: nothing raises out of an input handler or the loop; every bad input is
rejected (the parameters unchanged) or ends in a latched fault with the drive off (enable
false, 0 A); and outside a latched fault the valve never goes beyond the largest demand of
the last 0.3 s + 2 % of stroke (:func:`check_safe`; a mode that does worse at its defaults,
the pi_dither baseline, observer_fc and kalman_fc after a switch, is held to its own figure
+ 0.5 %).  Plant parameters describe the valve, not a command: rejected or the plant runs.
Known shortfalls are strict xfails: :data:`KNOWN_OVERSHOOT`.  In-range plant values with which the
fixed-step physics diverged (:data:`PLANT_DIVERGED`) are now refused by its stability check.
The DDS side (every subscription and parameter of the real node objects, the services):
``test_fuzz_nodes.py``.
"""
from __future__ import annotations

import collections
import math

import pytest

from fuel_valve_control.common import contract as c
from fuel_valve_control.common.paramspec import Param
from fuel_valve_control.core.driver import INTERNAL, TRIPPED, ValveDriver
from fuel_valve_control.core.params import CONTROLLER_NODE_SPEC, CONTROLLER_SPEC, MODES, load_controller_params
from fuel_valve_control.core.params import check_consistency as controller_consistency
from fuel_valve_control.core.position_controller import PositionController
from fuel_valve_control.tools.profiles import DEMAND_NODE_SPEC, ProfileError, profile_from_params
from fuel_valve_plant.physics.params import PLANT_NODE_SPEC, PLANT_SPEC, check_consistency, load_plant_params
from fuel_valve_plant.physics.plant import Plant
from prefetch import ModuleRuns, jobs, selected_items
from snapshots import Snapshots

N = 48.019
HOLD_PCT = 30.0
#: outside a latched fault the valve stays below the largest recent demand + this, % of stroke
MARGIN_PCT = 2.0
RECENT_S = 0.3

BAD_NUMBERS = [math.nan, math.inf, -math.inf, 1e308, -1e308, 1e9, -1e9, -1.0, -1e-9, 0.0, 5e-324]


# ------------------------------------------------------------------ the closed loop
class Loop:
    """Driver + plant as the offline simulator runs them, with the safety invariant checked
    every period."""

    def __init__(self, controller_ps=None, plant_ps=None):
        self.plant = Plant(plant_ps if plant_ps is not None else load_plant_params(
            overrides={"pressure_sensor.noise_kpa": 0.0}))
        self.drv = ValveDriver(controller_ps if controller_ps is not None else load_controller_params())
        self.t = 0.0
        #: the demands of the last RECENT_S, % (what check_safe compares the valve with)
        self.recent = collections.deque(maxlen=int(RECENT_S / self.drv.period))
        self.margin = MARGIN_PCT
        self.worst_excess = -math.inf          # largest valve - recent demand outside a fault, %

    def period(self, demand_pct: float = HOLD_PCT, inject=None, resolver: bool = True) -> None:
        drv, plant, t = self.drv, self.plant, self.t
        if inject is not None:
            inject(self)
        drv.demand_percent(t, demand_pct)
        self.recent.append(demand_pct)
        dp = plant.pressure_sample()
        if dp is not None:
            drv.pressure_differential(t, dp)
        s = plant.resolver()
        if resolver and s is not None:
            drv.resolver(s.stamp_s, s.motor_rad, s.valve_rad, now=t)
        out = drv.step(t)
        plant.set_command(out.current_a, out.enable)
        plant.advance(drv.period)
        self.t = t + drv.period
        check_safe(self, out)

    def run(self, seconds: float, demand_pct: float = HOLD_PCT, inject=None) -> None:
        for _ in range(int(round(seconds / self.drv.period))):
            self.period(demand_pct, inject)


def check_safe(loop: Loop, out) -> None:
    """The campaign's invariant for one period's output."""
    if out.faults:
        assert not out.enable and out.current_a == 0.0, (out.faults, out.enable, out.current_a)
        return
    assert math.isfinite(out.current_a)
    valve = 100.0 * loop.plant.truth().valve_angle / c.STROKE_RAD
    recent = max(loop.recent)
    loop.worst_excess = max(loop.worst_excess, valve - recent)
    assert valve <= recent + loop.margin, f"valve {valve:.2f} % beyond demand {recent:.2f} % + {loop.margin:.2f} %"


_BASE: dict = {}


def base_params(mode: str | None = None):
    """(controller, plant) parameter sets of the campaign (loaded once: YAML is slow)."""
    key = mode or "default"
    if key not in _BASE:
        _BASE[key] = (load_controller_params(overrides={"mode": mode} if mode else None),
                      load_plant_params(overrides={"pressure_sensor.noise_kpa": 0.0}))
    return _BASE[key]


def _hold(mode: str | None) -> Loop:
    loop = Loop(*base_params(mode))
    loop.run(0.3)
    assert not loop.drv.last.faults and loop.drv.last.enable
    return loop


_HELD = Snapshots(_hold)


def held_loop(mode: str | None = None) -> Loop:
    """A loop holding the valve at 30 % (built once per mode, then deep-copied: snapshots.py)."""
    return _HELD[mode]


# ------------------------------------------------------------------ inputs of the controller
def _resolver(loop: Loop, motor=None, valve=None, stamp=None, now=None):
    s = loop.plant.truth()
    loop.drv.resolver(loop.t if stamp is None else stamp, N * s.valve_angle if motor is None else motor,
                      s.valve_angle if valve is None else valve, now=loop.t if now is None else now)


#: topic the controller subscribes to -> (name, injector(loop, value)) pairs: each injector
#: hands a bad value to the driver exactly as the node's callback does
CONTROLLER_INPUTS = {
    c.DEMAND: [("value", lambda loop, v: loop.drv.demand_percent(loop.t, v))],
    c.DEMAND_MA: [("value", lambda loop, v: loop.drv.demand_ma(loop.t, v))],
    c.PRESSURE_DIFFERENTIAL: [("value", lambda loop, v: loop.drv.pressure_differential(loop.t, v))],
    c.RESOLVER: [("valve", lambda loop, v: _resolver(loop, valve=v)),
                 ("motor", lambda loop, v: _resolver(loop, motor=v)),
                 ("both", lambda loop, v: _resolver(loop, motor=v, valve=v)),
                 ("stamp", lambda loop, v: _resolver(loop, stamp=v)),
                 ("stamp_offset", lambda loop, v: _resolver(loop, stamp=loop.t + v))],
    c.DRIVE: [("current", lambda loop, v: loop.drv.measured_current(loop.t, v))],
    c.DRIVE_STATUS: [("state", lambda loop, v: loop.drv.drive_status(loop.t, v))],
}
#: values per input beyond BAD_NUMBERS: out of range for that input (percent, mA, kPa, rad, s)
EXTRA = {c.DEMAND: [105.1, 150.0, -5.1, -50.0, 100.0, 0.0], c.DEMAND_MA: [3.6, 3.7, 20.9, 21.0, 25.0, 4.0, 20.0],
         c.PRESSURE_DIFFERENTIAL: [c.PRESSURE_MAX_KPA * 2, -500.0],
         c.RESOLVER: [c.STROKE_RAD + 0.5, -0.5, 3600.0, -3600.0, 0.06], c.DRIVE: [100.0, -100.0],
         c.DRIVE_STATUS: [c.DRIVE_STATE_DISABLED, c.DRIVE_STATE_ENABLED, c.DRIVE_STATE_WATCHDOG,
                          c.DRIVE_STATE_FAULT, 4, 255]}

INPUT_CASES = [pytest.param(topic, name, value, burst, id=f"{topic}-{name}-{value!r}-{'burst' if burst else 'once'}")
               for topic, injectors in CONTROLLER_INPUTS.items() for name, _ in injectors
               for value in BAD_NUMBERS + EXTRA.get(topic, []) for burst in (False, True)]


@pytest.mark.parametrize("topic, name, value, burst", INPUT_CASES)
def test_bad_controller_input_is_rejected_or_latches_safely(topic, name, value, burst):
    loop = held_loop()
    inject = dict(CONTROLLER_INPUTS[topic])[name]
    # the bad value once, or instead of nothing for 50 periods (a burst), then 0.2 s more
    loop.period(inject=lambda lp: inject(lp, value))
    for _ in range(49 if burst else 0):
        loop.period(inject=lambda lp: inject(lp, value))
    loop.run(0.1)
    assert INTERNAL not in loop.drv.last.faults, loop.drv.last.faults      # handled, not a defect
    # a reset is refused or re-arms cleanly; the loop stays safe either way
    loop.drv.reset()
    loop.run(0.05)


# ------------------------------------------------------------------ parameters
def boundary_values(p: Param) -> list:
    """min, max, just outside, NaN/inf, a wrong type: from the parameter's own schema entry."""
    if p.choices is not None:
        return list(p.choices) + ["not_a_choice", 3.5, True]
    if p.kind is bool:
        return [True, False, "yes", 2, math.nan]
    if p.kind is list:
        return [[], ["x"], [math.nan, 1.0], 5, "abc"]
    if p.kind is str:
        return ["", "x" * 300, 5, math.nan]
    values: list = []
    step = 1 if p.kind is int else None
    for edge, outward in ((p.low, -1), (p.high, 1)):
        if edge is None:
            values.append(p.kind(-2 ** 62 if outward < 0 else 2 ** 62) if p.kind is int else outward * 1e308)
            continue
        if not (outward < 0 and p.low_open):
            values.append(p.kind(edge))
        values.append(edge + outward * step if step else math.nextafter(edge, outward * math.inf))
    if p.kind is float:
        values += [math.nan, math.inf, -math.inf, "abc"]
    else:
        values += [1.5, "abc", math.nan]
    return values


LAW_KEYS = {mode: PositionController(CONTROLLER_SPEC.defaults().replace({"mode": mode})).law_params
            for mode in MODES}
#: start-up values at the edge of their range with which the loop overshoots a 3 % step (or
#: the hold after start-up) by more than 2 % of stroke (measured 2.0-5.5 %): a design far from
#: the defaults or a nominal model far from the valve.  Known shortfalls, not crashes: the loop
#: stays stable and supervised (no fault needed); narrowing these ranges is for the control issue.
#: (design.damping 0.2 and design.resonance_damping 1.0 left the list with the design that keeps
#: the gear-output angle gain non-negative, design.hold_stiff_state_feedback: both had made it
#: negative on the nominal valve; docs/control_results.md section 35; fine.servo_hz 200 left it with
#: the fine stage's phase-margin gate: a 200 Hz servo has none on a 1 kHz loop, so the stage stays
#: out and the main law holds, section 37)
KNOWN_OVERSHOOT = [("design.bandwidth_hz", 0.5),
                   ("design.resonance_frequency_ratio", 3.0), ("observer.bandwidth_ratio", 1.0),
                   ("integral.stuck_ramp_time_s", 0.001), ("model.gear_ratio", 1000.0),
                   ("model.stroke_rad", 3.2),
                   # 20 ms resolver delay (20 periods) compensated by prediction, gains not detuned
                   # for it: 2.24 % over a 3 % step since the faster designed trajectory (issue 14)
                   ("resolver_delay_s", 0.02)]
# (spring preload 200, flow torque 50, valve Coulomb 100 / per Δp 100 N*m: refused at start since
# the planned moves are designed from the drive's current, which cannot move such a load)


@pytest.mark.slow
@pytest.mark.parametrize("name", list(CONTROLLER_NODE_SPEC.params))
def test_controller_parameter_boundary_values_are_rejected_or_safe(name):
    p = CONTROLLER_NODE_SPEC.params[name]
    for index, value in enumerate(boundary_values(p)):
        if (name, value) not in KNOWN_OVERSHOOT:
            _AHEAD.result("controller", name, index)        # _controller_case(p, name, value)


@pytest.mark.xfail(strict=True, reason="start-up value at the edge of its range: the valve overshoots the "
                   "demand by 2.0-5.5 % of stroke (stable, supervised); see KNOWN_OVERSHOOT")
@pytest.mark.parametrize("name, value", KNOWN_OVERSHOOT)
def test_controller_parameter_edge_values_known_to_overshoot(name, value):
    _controller_case(CONTROLLER_NODE_SPEC.params[name], name, value)


def _node_setting_case(node_spec, p, name, value):
    """A start-up-only node setting: refused by the node's schema, or accepted only if finite."""
    try:
        node_spec.defaults().replace({name: value})
    except ValueError:
        return
    assert p.kind is not float or math.isfinite(value), (name, value)


def _controller_case(p, name, value):
    if name not in CONTROLLER_SPEC.params:      # node settings (rates, lockstep...): start-up only
        _node_setting_case(CONTROLLER_NODE_SPEC, p, name, value)
        return
    mode = next((m for m in MODES if name in LAW_KEYS[m]), None)
    target = value if name == "mode" and value in MODES else mode
    margin = max(MARGIN_PCT, reference_excess(mode, target) + REFERENCE_SLACK_PCT)
    if p.runtime:
        loop = held_loop(mode)
        loop.margin = margin
        ps, law = loop.drv.ps, loop.drv.controller.law
        try:
            change = loop.drv.prepare_params({name: value})
        except ValueError:                       # rejected (ConfigError is a ValueError): nothing changed
            assert loop.drv.ps is ps and loop.drv.controller.law is law and not loop.drv.params_pending
            return
        loop.drv.request_params(change)
    else:
        try:
            ps = base_params(mode)[0].replace({name: value})
            controller_consistency(ps)
        except ValueError:
            return
        try:
            loop = Loop(ps, base_params(mode)[1])
        except ValueError:                       # the design code refused it at start-up: a clear error
            return
        loop.margin = margin
        loop.run(0.25)
    step_sequence(loop)
    assert INTERNAL not in loop.drv.last.faults, (name, value, loop.drv.last.faults)


def step_sequence(loop: Loop) -> None:
    """After an accepted change: the swap, then a small step (+3 %) and a hold."""
    loop.run(0.05, HOLD_PCT)
    loop.run(0.15, HOLD_PCT + 3.0)


#: a parameter at a boundary may cost this much more excess than its mode at the defaults, %
REFERENCE_SLACK_PCT = 0.5
_REFERENCE: dict = {}


def reference_excess(mode: str | None, target: str | None) -> float:
    """Largest valve excess over the recent demand (%) of ``mode``'s held loop switched to
    ``target`` at the defaults through :func:`step_sequence`: what the mode itself does (the
    pi_dither baseline dithers ±4 %; observer_fc and kalman_fc overshoot a 3 % step by about
    2.5 % after a switch, their own known shortfalls), so a boundary value is judged against
    its own mode, and the default mode against the 2 % bound."""
    key = (mode, target)
    if key not in _REFERENCE:
        loop = held_loop(mode)
        loop.margin = math.inf
        if target is not None and target != loop.drv.ps["mode"]:
            loop.drv.request_params(loop.drv.prepare_params({"mode": target}))
        step_sequence(loop)
        _REFERENCE[key] = loop.worst_excess
    return _REFERENCE[key]


#: in-range plant values with which the fixed-step physics diverged (NaN after a few periods;
#: the resolver then raised converting NaN): refused now (physics/stability.py)
PLANT_DIVERGED = [("motor.pole_pairs", 32), ("motor.flux_linkage_wb", 1.0), ("coupling.damping_nms", 100.0)]


@pytest.mark.slow
@pytest.mark.parametrize("name", list(PLANT_NODE_SPEC.params))
def test_plant_parameter_boundary_values_are_rejected_or_run(name):
    """A plant parameter describes the simulated valve, not a command, so the valve-vs-demand
    bound does not apply (a plant far from the controller's model may overshoot: that is the
    robustness campaign's subject, benchmarks/robustness.py); what must hold: rejected, or the
    plant runs (finite, no exception) and the controller stays supervised (faults: drive off)."""
    for index, _ in enumerate(boundary_values(PLANT_NODE_SPEC.params[name])):
        _AHEAD.result("plant", name, index)                 # _plant_case(p, name, value)


@pytest.mark.parametrize("name, value", PLANT_DIVERGED)
def test_plant_values_that_diverged_are_refused_by_the_stability_check(name, value):
    _plant_case(PLANT_NODE_SPEC.params[name], name, value)      # refused, or runs finite
    with pytest.raises(ValueError, match="unstable"):
        check_consistency(base_params()[1].replace({name: value}))
    if PLANT_SPEC.params[name].runtime:                          # at run time: refused, unchanged
        plant = Plant(base_params()[1])
        before = plant.params
        with pytest.raises(ValueError, match="unstable"):
            plant.set_params({name: value})
        assert plant.params is before


def test_the_stability_check_follows_the_electromechanical_pole():
    """With the current regulator saturated the back-EMF closes an explicit loop of gain
    g = 1.5 p² ψ² b dt / Jm per step (b = (1 - a) / R, a = exp(-R dt / Lq)), stable while
    g < 2 (1 - a) (physics/stability.py): the check refuses exactly the pole-pair counts and
    flux linkages beyond that bound (a margin of 10 % around it left out)."""
    base = base_params()[1]
    for name, values in (("motor.pole_pairs", range(1, 33)), ("motor.flux_linkage_wb", (0.01, 0.03, 0.05, 0.07,
                                                                                         0.1, 0.3, 1.0))):
        for value in values:
            ps = base.replace({name: value})
            dt, r, lq = 1.0 / ps["physics_rate_hz"], ps["motor.resistance_ohm"], ps["motor.lq_h"]
            a = math.exp(-r * dt / lq)
            g = 1.5 * (ps["motor.pole_pairs"] * ps["motor.flux_linkage_wb"]) ** 2 * (1 - a) / r * dt \
                / ps["motor.inertia_kgm2"]
            ratio = g / (2.0 * (1.0 - a))
            if abs(ratio - 1.0) < 0.1:
                continue
            try:
                check_consistency(ps)
                refused = False
            except ValueError:
                refused = True
            assert refused == (ratio > 1.0), (name, value, ratio)


def _plant_case(p, name, value):
    base = base_params()[1]
    if name not in PLANT_SPEC.params:           # node settings: start-up only
        _node_setting_case(PLANT_NODE_SPEC, p, name, value)
        return
    if p.runtime:
        loop = held_loop()
        before = loop.plant.params
        try:
            loop.plant.set_params({name: value})
        except ValueError:
            assert loop.plant.params is before
            return
    else:
        try:
            ps = base.replace({name: value})
            check_consistency(ps)
        except ValueError:
            return
        loop = Loop(base_params()[0], ps)       # the plant as started with it
        loop.margin = math.inf
        loop.run(0.3)
    loop.margin = math.inf
    loop.run(0.15)
    assert math.isfinite(loop.plant.truth().valve_angle), (name, value)
    assert INTERNAL not in loop.drv.last.faults, (name, value, loop.drv.last.faults)


@pytest.mark.parametrize("name", list(DEMAND_NODE_SPEC.params))
def test_demand_parameter_boundary_values_are_rejected_or_give_a_finite_profile(name):
    """The demand node builds its profile from its parameters (``profile_from_params``); a
    value it accepts gives a profile whose demand is finite at any time (a non-finite demand
    would in any case latch the controller's demand-signal fault)."""
    profiles = [{}] + [{"profile": t} for t in DEMAND_NODE_SPEC.params["profile"].choices if t != "csv"]
    for value, extra in [(v, e) for v in boundary_values(DEMAND_NODE_SPEC.params[name]) for e in profiles]:
        try:
            ps = DEMAND_NODE_SPEC.defaults().replace({**extra, name: value})
            profile = profile_from_params(ps)
        except (ValueError, ProfileError):
            continue
        for t in (0.0, 0.5, 1.0, 10.0, 1e6, 1e9):
            assert math.isfinite(profile.value(t)), (extra, name, value, t)


# ------------------------------------------------------------------ services at odd times
def test_trip_and_reset_at_odd_times():
    loop = Loop(*base_params())
    assert loop.drv.reset()[0] in (True, False)              # before any input: no crash
    loop.drv.trip("before any input")
    loop.run(0.05)
    assert loop.drv.last.faults and not loop.drv.last.enable
    ok, msg = loop.drv.reset()
    assert ok, msg
    loop.run(0.3)
    assert loop.drv.last.enable
    for _ in range(3):                                        # trip twice, reset twice
        loop.drv.trip("again")
    loop.period()
    assert TRIPPED in loop.drv.last.faults and not loop.drv.last.enable
    assert loop.drv.reset()[0]
    ok, msg = loop.drv.reset()                                # nothing to clear
    assert ok and "nothing" in msg
    loop.run(0.2)
    # reset during a move, trip mid-move, reset immediately
    loop.run(0.05, 60.0)
    loop.drv.trip("mid-move")
    loop.period(60.0)
    assert not loop.drv.last.enable
    loop.drv.reset()
    loop.run(0.5, 60.0)
    # reset while the resolver is silent: refused, the fault stays latched
    for _ in range(40):
        loop.period(60.0, resolver=False)
    assert loop.drv.last.faults
    ok, msg = loop.drv.reset()
    assert not ok and "resolver" in msg
    loop.period(60.0, resolver=False)
    assert loop.drv.last.faults and not loop.drv.last.enable


# ------------------------------------------------------------------ look-ahead (test/prefetch.py)
def _boundary_case(node: str, name: str, index: int) -> None:
    """``_controller_case`` / ``_plant_case`` of the ``index``-th boundary value of parameter
    ``name`` of the controller's / plant's node schema, here or in a look-ahead worker: a case
    that fails raises there, and :meth:`prefetch.Ahead.result` raises it in the test that asks
    for it (the worker's traceback attached)."""
    spec, case = (CONTROLLER_NODE_SPEC, _controller_case) if node == "controller" else (PLANT_NODE_SPEC, _plant_case)
    p = spec.params[name]
    case(p, name, boundary_values(p)[index])


#: the module's look-ahead cases; none outside the module fixture below
_AHEAD = ModuleRuns(_boundary_case)


def _planned(item) -> list[tuple]:
    """The boundary cases a selected parameter test asks for, in its order."""
    name = getattr(getattr(item, "callspec", None), "params", {}).get("name")
    if item.originalname == "test_controller_parameter_boundary_values_are_rejected_or_safe":
        return [("controller", name, i) for i, v in enumerate(boundary_values(CONTROLLER_NODE_SPEC.params[name]))
                if (name, v) not in KNOWN_OVERSHOOT]
    if item.originalname == "test_plant_parameter_boundary_values_are_rejected_or_run":
        return [("plant", name, i) for i, _ in enumerate(boundary_values(PLANT_NODE_SPEC.params[name]))]
    return []


@pytest.fixture(scope="module", autouse=True)
def _look_ahead(request):
    """The parameter-boundary cases (most of this module's CPU) on both cores while the input
    cases run here; each parameter test still takes its cases in order and fails with the
    first that fails."""
    keys = [key for item in selected_items(request) for key in _planned(item)]
    with _AHEAD.planned(keys, jobs(request.config)):
        yield
