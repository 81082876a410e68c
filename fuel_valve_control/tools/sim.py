"""Offline closed-loop simulator (no ROS): plant + valve driver + demand profile -> metrics.

    fuel_valve_sim --scenario NAME|FILE [--controller MODE] [--set section.key=value ...]
                   [--seed N] [--json PATH] [--plot PATH] [--trace PATH.csv] [--baseline PATH.json]

Prints one JSON object: ``{"scenario", "controller", "metrics", "sim_time_s", "wall_time_s",
"real_time_factor"}`` plus ``"segments"`` (per step/hold/sweep/trip details), and for a
scenario with valve-test events (``config/valve_tests/*.yaml``) ``"valve_tests"`` (name ->
result, :mod:`fuel_valve_control.core.valve_tests`) and ``"valve_test_refusals"``.  Unknown
scenario, mode or parameter: a message on stderr and exit code 2.

``--trace`` writes the run's time series as CSV (columns: :mod:`.trace`).  The run's set-up
(parameters, initial state, events) is the run-plan's (:mod:`.run_plan`), shared with
``fuel_valve_demo``.  The loop is the same as on ROS: at every control period the resolver is
sampled (and the pressure differential, at the transducer's rate), the driver (the controller
node's core) computes the current command, and the plant integrates one period with it.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass, field, replace

import numpy as np

from fuel_valve_plant.physics.plant import Plant

from ..common.paramspec import ConfigError, ParamSet, parse_overrides
from ..core.driver import ValveDriver
from ..core.period_inputs import PeriodInputs
from ..core.params import MODES
from ..core.valve_tests import ValveTests, load_baselines
from . import metrics as M
from .loop_stalls import LoopStalls, StalledDrive
from .run_plan import OFFLINE, RunPlan, apply_event, plan_run
from .scenarios import Scenario, load_scenario

#: scenario events that start a valve test
VALVE_TEST_ACTIONS = ("signature_test", "partial_stroke_test")

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
    fault: np.ndarray = field(default_factory=lambda: np.zeros(0))   # 1: a latched driver fault
    #: valve-test results by test name (core/valve_tests.py), when the scenario ran tests
    valve_tests: dict = field(default_factory=dict)
    #: messages of refused valve-test requests
    valve_test_refusals: list = field(default_factory=list)
    warnings: dict = field(default_factory=dict)    # the driver's warnings at the end (code -> message)
    #: with emulated loop stalls (:mod:`.loop_stalls`): periods whose command was lost, the controller asleep, the
    #: drive's watchdog trips and the periods it applied the controller's fallback current
    stall_counts: dict = field(default_factory=dict)

    def column(self, name: str) -> np.ndarray:
        return self.log[:, LOG_COLUMNS.index(name)]

    def series(self) -> dict[str, np.ndarray]:
        """The run as named series (the vocabulary of :mod:`.plotting` and :mod:`.trace`).
        True friction is given as the torque resisting motion (minus the torque friction
        applies to the shaft), the sign convention of the controller's estimate."""
        c = self.column
        return {"t": c("t"), "demand": c("demand_rad"), "position": c("position_rad"),
                "measured": c("measured_rad"), "motor": c("motor_rad"), "velocity": c("velocity_rad_s"),
                "current_cmd": c("current_cmd_a"), "current": np.hypot(c("i_d_a"), c("i_q_a")),
                "i_q": c("i_q_a"), "i_d": c("i_d_a"),
                "friction_valve": -c("friction_valve_nm"), "friction_valve_est": c("friction_est_valve_nm"),
                "friction_motor": -c("friction_motor_nm"), "friction_motor_est": c("friction_est_motor_nm"),
                "enable": c("enable"), "fault": self.fault}

    def summary(self) -> dict:
        out = {"scenario": self.scenario, "controller": self.controller, "metrics": self.metrics,
               "sim_time_s": self.sim_time_s, "wall_time_s": round(self.wall_time_s, 4),
               "real_time_factor": round(self.sim_time_s / max(self.wall_time_s, 1e-9), 2),
               "segments": self.segments}
        if self.valve_tests or self.valve_test_refusals:
            out["valve_tests"] = self.valve_tests
            out["valve_test_refusals"] = self.valve_test_refusals
        return out


def build(scenario: Scenario, plant_overrides=None, controller_overrides=None, seed=None,
          mode: str | None = None) -> tuple[ParamSet, ParamSet]:
    """Plant and controller parameter sets of a scenario's offline run (the run-plan's:
    defaults < scenario < overrides < seed / mode)."""
    plan = plan_run(scenario, OFFLINE, mode=mode, seed=seed, plant_overrides=plant_overrides,
                    controller_overrides=controller_overrides)
    return plan.plant_params, plan.controller_params


def simulate(scenario: Scenario, plant_ps: ParamSet, controller_ps: ParamSet) -> SimResult:
    """Simulate ``scenario`` with parameter sets built elsewhere (e.g. :func:`build`)."""
    plan = replace(plan_run(scenario, OFFLINE), plant_params=plant_ps, controller_params=controller_ps)
    return simulate_plan(plan)


def exchange_period(driver, plant, t: float, demand_pct: float):
    """One control period's exchange at time ``t`` (s), as the lockstep nodes exchange it
    (:class:`~fuel_valve_control.core.period_inputs.PeriodInputs`): the demand (percent), the
    Δp transducer (at its own rate), the resolver sample (when the plant gives one; stamped
    ``t`` like the plant node's), then the driver's step.  Returns ``(DriverOutput, resolver
    sample or None)``; applying the command and advancing the plant is the caller's (it may
    log the state in between).  The one loop body of the offline simulator and of the tests
    that close the loop around a driver."""
    inputs = PeriodInputs()
    inputs.demand_percent(demand_pct)
    dp = plant.pressure_sample()
    if dp is not None:
        inputs.pressure_differential(dp)
    sample = plant.resolver()
    if sample is None:
        return inputs.run(driver, t), sample
    return inputs.run(driver, t, sample.motor_rad, sample.valve_rad), sample


def simulate_plan(plan: RunPlan, baselines: list[dict] = (), stalls: LoopStalls | None = None) -> SimResult:
    """Run an offline plan: every control period events due, demand, resolver sample, driver
    step, plant step (the order of the ROS loop).  A plan with valve-test events runs them on
    a :class:`~fuel_valve_control.core.valve_tests.ValveTests`, judged against ``baselines``
    (stored results; none: the first run of each test is its baseline).  ``stalls``: the
    real-time loop's late answers emulated (:mod:`.loop_stalls`): in a stalled period the
    driver does not run and the drive applies its no-command current; the log's command
    column holds the current the drive applied."""
    plant = Plant(plan.plant_params)
    driver = ValveDriver(plan.controller_params)
    tests = None
    if baselines or any(ev.action in VALVE_TEST_ACTIONS for ev in plan.events):
        tests = ValveTests(driver)
        for doc in baselines:
            tests.set_baseline(doc)
    period = driver.period
    stroke = plan.plant_params["valve.stroke_rad"]
    plan.start_held(plant, driver)
    n = int(round(plan.duration_s / period))
    rows = []                      # one tuple per period, made an array once after the run (cheaper than a row write)
    append = rows.append
    fault = np.zeros(n)
    events = plan.event_queue()
    demand = plan.demand
    start = time.perf_counter()
    lost = asleep = drive = None
    if stalls is not None:
        (lost, asleep), drive = stalls.schedule(n), StalledDrive(stalls)
        reported = None                # the drive state the driver was last told
    for k in range(n):
        t = k * period
        for ev in events.due(t):
            apply_event(ev, plant, driver)
        if drive is not None and asleep[k]:
            # the controller is not scheduled this period: the drive applies its no-command current
            amps, on = drive.no_command()
            out, sample = replace(driver.last, current_a=amps, enable=on), None
        else:
            if drive is not None:
                if drive.state != reported:
                    reported = drive.state
                    driver.drive_status(t, reported)
                driver.loop_timing(t, t)
            out, sample = exchange_period(driver, plant, t, demand.value(t))
            if drive is not None:
                # the command reaches the drive, or (a transit stall) not in time; then the work left for after
                # the command, as the node does it (the same bits: the next step would do it first), and the
                # fallback it may have changed
                if lost[k]:
                    amps, on = drive.missed(out)
                else:
                    amps, on = drive.command(out)
                    if driver.after_period():
                        drive.fallback(driver.fallback_currents())
                out = replace(out, current_a=amps, enable=on)
        est = driver.controller.estimate()
        truth = plant.truth()
        i_d, i_q = plant.currents
        fm, fl = plant.friction_torques()
        append((t, demand.nominal(t) / 100.0 * stroke, truth.valve_angle,
                  math.nan if sample is None else sample.valve_rad, truth.motor_angle, truth.valve_velocity,
                  out.current_a, i_d, i_q, 1.0 if out.enable else 0.0, fm, fl,
                  est.motor_friction_nm, est.valve_friction_nm, est.valve_angle, est.valve_velocity,
                  truth.motor_velocity, est.motor_velocity, driver.controller.reference_position()))
        if out.faults:
            fault[k] = 1.0
        plant.set_command(out.current_a, out.enable)
        plant.advance(period)
    wall = time.perf_counter() - start
    log = np.array(rows, dtype=float).reshape(n, len(LOG_COLUMNS))   # the same floats the row writes stored
    trace = M.Trace(log[:, 0], log[:, 1], log[:, 2], np.hypot(log[:, 7], log[:, 8]), log[:, 9], stroke)
    metrics, segments = M.compute(trace)
    counts = {} if drive is None else {"periods_lost": int(lost.sum()), "periods_asleep": int(asleep.sum()),
                                       "watchdog_trips": drive.trips, "fallback_periods": drive.fallback_periods}
    return SimResult(plan.name, plan.mode, log, metrics, segments, n * period, wall, stroke, fault,
                     dict(tests.results) if tests else {}, list(tests.refusals) if tests else [],
                     warnings=dict(driver.warnings), stall_counts=counts)


def run(scenario_name: str, mode: str | None = None, plant_overrides=None, controller_overrides=None,
        seed=None) -> SimResult:
    """Load a scenario and simulate it (convenience for tests and benchmarks)."""
    return simulate_plan(plan_run(load_scenario(scenario_name), OFFLINE, mode=mode, seed=seed,
                                  plant_overrides=plant_overrides, controller_overrides=controller_overrides))




def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="fuel_valve_sim", description="Offline closed-loop simulation of the "
                                     "fuel-valve actuator and controller (no ROS).")
    parser.add_argument("--scenario", required=True, help="built-in scenario name or a scenario YAML file")
    parser.add_argument("--controller", metavar="MODE", help=f"control mode: {', '.join(MODES)}")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE",
                        help="override a plant or controller parameter, e.g. plant.friction_scale=2")
    parser.add_argument("--seed", type=int, help="resolver noise seed")
    parser.add_argument("--baseline", metavar="PATH.json", help="valve tests (scenario events signature_test, "
                        "partial_stroke_test): judge them against the completed results in this JSON file "
                        "(an earlier --json output); default: the first run of each test is its baseline")
    parser.add_argument("--json", metavar="PATH", help="also write the JSON result here")
    parser.add_argument("--plot", metavar="PATH", help="write a PNG of the run here")
    parser.add_argument("--trace", metavar="PATH.csv", help="write the run's time series here (CSV, header row "
                        "with units)")
    args = parser.parse_args(argv)
    try:
        over = parse_overrides(args.overrides, ("plant", "controller"))
        plan = plan_run(load_scenario(args.scenario), OFFLINE, mode=args.controller, seed=args.seed,
                        plant_overrides=over["plant"], controller_overrides=over["controller"])
        baselines = load_baselines(args.baseline) if args.baseline else []
    except (ConfigError, OSError, ValueError) as exc:
        print(f"fuel_valve_sim: error: {exc}", file=sys.stderr)
        return 2
    result = simulate_plan(plan, baselines)
    doc = M.jsonable(result.summary())
    text = json.dumps(doc)
    print(text)
    if args.json:
        with open(args.json, "w") as f:
            f.write(json.dumps(doc, indent=2) + "\n")
    if args.plot:
        from .plotting import plot_result
        plot_result(result, args.plot)
        if result.valve_tests:               # the friction/hysteresis diagrams beside it
            from .report import plot_valve_tests
            plot_valve_tests(list(result.valve_tests.values()), args.plot, baselines)
    if args.trace:
        from .trace import write_trace
        write_trace(args.trace, result.series())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
