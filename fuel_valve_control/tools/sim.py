"""Offline closed-loop simulator (no ROS): plant + valve driver + demand profile -> metrics.

    fuel_valve_sim --scenario NAME|FILE [--controller MODE] [--set section.key=value ...]
                   [--seed N] [--json PATH] [--plot PATH]

Prints one JSON object: ``{"scenario", "controller", "metrics", "sim_time_s", "wall_time_s",
"real_time_factor"}`` plus ``"segments"`` (per step/hold/sweep/trip details).  Unknown
scenario, mode or parameter: a message on stderr and exit code 2.

The loop is the same as on ROS: at every control period the resolver is sampled (and the
pressure differential, at the transducer's rate), the driver (the controller node's core)
computes the current command, and the plant integrates one period with it.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass

import numpy as np

from ..common.paramspec import ConfigError, ParamSet, parse_overrides
from fuel_valve_plant.physics.plant import Plant
from fuel_valve_plant.physics.params import load_plant_params

from . import metrics as M
from ..core.params import MODES, load_controller_params
from ..core.driver import ValveDriver
from .scenarios import Scenario, load_scenario

#: columns of :attr:`SimResult.log`
LOG_COLUMNS = ("t", "demand_rad", "position_rad", "measured_rad", "motor_rad", "velocity_rad_s", "current_cmd_a",
               "i_d_a", "i_q_a", "enable", "friction_motor_nm", "friction_valve_nm",
               "friction_est_motor_nm", "friction_est_valve_nm", "estimate_rad", "estimate_velocity_rad_s",
               "motor_velocity_rad_s", "estimate_motor_velocity_rad_s", "reference_rad")


@dataclass
class SimResult:
    scenario: str
    controller: str
    log: np.ndarray                 # rows per control period, columns LOG_COLUMNS
    metrics: dict
    segments: list
    sim_time_s: float
    wall_time_s: float
    stroke_rad: float

    def column(self, name: str) -> np.ndarray:
        return self.log[:, LOG_COLUMNS.index(name)]

    def summary(self) -> dict:
        return {"scenario": self.scenario, "controller": self.controller, "metrics": self.metrics,
                "sim_time_s": self.sim_time_s, "wall_time_s": round(self.wall_time_s, 4),
                "real_time_factor": round(self.sim_time_s / max(self.wall_time_s, 1e-9), 2),
                "segments": self.segments}


def build(scenario: Scenario, plant_overrides=None, controller_overrides=None, seed=None,
          mode: str | None = None) -> tuple[ParamSet, ParamSet]:
    """Plant and controller parameter sets for a scenario (defaults < scenario < overrides)."""
    p_over = dict(scenario.plant)
    c_over = dict(scenario.controller)
    if scenario.pressure_kpa is not None:      # set on the plant only: the controller measures it
        p_over["pressure_differential_kpa"] = scenario.pressure_kpa
    p_over.update(plant_overrides or {})
    c_over.update(controller_overrides or {})
    if seed is not None:
        p_over["seed"] = seed
    if mode is not None:
        c_over["mode"] = mode
    return load_plant_params(overrides=p_over), load_controller_params(overrides=c_over)


def simulate(scenario: Scenario, plant_ps: ParamSet, controller_ps: ParamSet) -> SimResult:
    plant = Plant(plant_ps)
    driver = ValveDriver(controller_ps)
    period = driver.period
    stroke = plant_ps["valve.stroke_rad"]
    kt = driver.controller.model.torque_constant_nm_per_a
    if scenario.initial_percent > 0.0:
        hold_a = plant.hold_at(scenario.initial_percent / 100.0 * stroke)
        driver.start_from_torque(hold_a * kt)
    n = int(round(scenario.duration_s / period))
    log = np.empty((n, len(LOG_COLUMNS)))
    events = list(scenario.events)
    demand = scenario.demand
    start = time.perf_counter()
    for k in range(n):
        t = k * period
        while events and events[0].at_s <= t + 1e-12:
            _apply_event(events.pop(0), plant, driver)
        pct = demand.value(t)
        driver.demand_percent(t, pct)
        dp = plant.pressure_sample()              # the Δp transducer, at its own rate
        if dp is not None:
            driver.pressure_differential(t, dp)
        sample = plant.resolver()
        if sample is not None:
            driver.resolver(sample.stamp_s, sample.motor_rad, sample.valve_rad)
        out = driver.step(t)
        est = driver.controller.estimate()
        truth = plant.truth()
        i_d, i_q = plant.currents
        fm, fl = plant.friction_torques()
        log[k] = (t, pct / 100.0 * stroke, truth.valve_angle,
                  math.nan if sample is None else sample.valve_rad, truth.motor_angle, truth.valve_velocity,
                  out.current_a, i_d, i_q, 1.0 if out.enable else 0.0, fm, fl,
                  est.motor_friction_nm, est.valve_friction_nm, est.valve_angle, est.valve_velocity,
                  truth.motor_velocity, est.motor_velocity, driver.controller.reference_position())
        plant.set_command(out.current_a, out.enable)
        plant.advance(period)
    wall = time.perf_counter() - start
    trace = M.Trace(log[:, 0], log[:, 1], log[:, 2], np.hypot(log[:, 7], log[:, 8]), log[:, 9], stroke)
    metrics, segments = M.compute(trace)
    return SimResult(scenario.name, controller_ps["mode"], log, metrics, segments, n * period, wall, stroke)


def _apply_event(ev, plant: Plant, driver: ValveDriver) -> None:
    if ev.action == "trip":
        driver.trip("scenario trip")
    elif ev.action == "reset":
        driver.reset()
    elif ev.action == "set_plant":
        plant.set_params(ev.params)
    elif ev.action == "set_controller":
        driver.set_params(ev.params)


def run(scenario_name: str, mode: str | None = None, plant_overrides=None, controller_overrides=None,
        seed=None) -> SimResult:
    """Load a scenario and simulate it (convenience for tests and benchmarks)."""
    sc = load_scenario(scenario_name)
    p, c = build(sc, plant_overrides, controller_overrides, seed, mode)
    return simulate(sc, p, c)


def _jsonable(obj):
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    return obj


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="fuel_valve_sim", description="Offline closed-loop simulation of the "
                                     "fuel-valve actuator and controller (no ROS).")
    parser.add_argument("--scenario", required=True, help="built-in scenario name or a scenario YAML file")
    parser.add_argument("--controller", metavar="MODE", help=f"control mode: {', '.join(MODES)}")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                        help="override a plant or controller parameter, e.g. plant.friction_scale=2")
    parser.add_argument("--seed", type=int, help="resolver noise seed")
    parser.add_argument("--json", metavar="PATH", help="also write the JSON result here")
    parser.add_argument("--plot", metavar="PATH", help="write a PNG of the run here")
    args = parser.parse_args(argv)
    try:
        if args.controller is not None and args.controller not in MODES:
            raise ConfigError(f"unknown controller mode {args.controller!r}; allowed: {', '.join(MODES)}")
        over = parse_overrides(args.overrides, ("plant", "controller"))
        sc = load_scenario(args.scenario)
        p, c = build(sc, over["plant"], over["controller"], args.seed, args.controller)
    except ConfigError as exc:
        print(f"fuel_valve_sim: error: {exc}", file=sys.stderr)
        return 2
    result = simulate(sc, p, c)
    doc = _jsonable(result.summary())
    text = json.dumps(doc)
    print(text)
    if args.json:
        with open(args.json, "w") as f:
            f.write(json.dumps(doc, indent=2) + "\n")
    if args.plot:
        from .plotting import plot_result
        plot_result(result, args.plot)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
