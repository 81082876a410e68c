#!/usr/bin/env python3
"""Robustness campaign (issue 14, SPEC §6): seeded Monte Carlo runs of random plateau
sequences on randomly perturbed plants, one controller configuration at the same gains.

Every run draws, from its own seed (``--seed`` + run index):

* friction: scale 0.5…3 (log-uniform), model stick-slip / Stribeck / LuGre, per-breakaway
  scatter of the static level (rms 2…8 %) and a position ripple (0…5 %, period 5…50 mrad);
* Δp: the true one (half the runs at the maximum, the rest 0…max) and what the controller is
  told: the plant's Δp transducer reads it exact, with an offset (measured with noise, or
  wrong: a ``pressure_sensor.bias_kpa`` that makes it read the told value), or sends nothing
  (missing → the controller's fallback, set to the told value) (:func:`plant_overrides`,
  :func:`controller_knowledge`);
* coupling stiffness ×0.3…1, motor and valve inertia ±20 % each, a steady load up to the
  actuator's continuous torque (with spring and flow torque) or a small opening load;
* resolver noise 0…1 count rms (both), delay 0…1 ms, gear backlash 0…2 mrad, supply 18…32 V;
* demand: 12 plateaus of 0.3…0.8 s after steps of 0.1…5 % of stroke (log-uniform, random
  sign) and a final 4 s hold; half the runs with 0…0.1 % rms demand noise, a third with
  single-sample (1 ms) glitches of ±0.6 %.

Per plateau: final error (|demand − true angle| at its end), overshoot, hunting amplitude
(half peak-to-peak after 0.3 s) and whether it hunts (≥ 2 reversals and > 2 counts); per
run: peak current and whether a fault latched (drive disabled).  Prints median/p95/max per
metric, the counts of runs that hunt / exceed 37 A / latch a fault, the worst runs with their
conditions, and as the last line one JSON object.

    python benchmarks/robustness.py [--runs N] [--quick] [--jobs N] [--seed S] [--box full|nominal] [--mode MODE]
                                    [--set controller.key=value ...] [--json PATH] [--markdown PATH]

``--box nominal`` keeps the nominal plant at max Δp and a clean demand; only the friction
scatter/ripple and the plateau sequence are drawn (issue 14's first target row).
``--quick`` = 30 runs.  Runs in a process pool over ``--jobs`` workers (default: all CPUs).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from dataclasses import replace
from multiprocessing import Pool
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from fuel_valve_control.common.contract import PRESSURE_MAX_KPA, STROKE_RAD  # noqa: E402
from fuel_valve_control.common.paramspec import ConfigError, parse_overrides  # noqa: E402
from fuel_valve_control.core.driver import ValveDriver  # noqa: E402
from fuel_valve_control.core.model import NominalModel  # noqa: E402
from fuel_valve_control.core.params import CONTROLLER_SPEC, DEFAULT_MODE, MODES  # noqa: E402
from fuel_valve_control.tools import metrics as M  # noqa: E402
from fuel_valve_control.tools import sim  # noqa: E402
from fuel_valve_control.tools.run_plan import OFFLINE, plan_run  # noqa: E402
from fuel_valve_control.tools.scenarios import parse_scenario  # noqa: E402
from fuel_valve_plant.physics.params import PLANT_SPEC  # noqa: E402
from fuel_valve_plant.physics.plant import Plant  # noqa: E402

DEFAULT_RUNS, QUICK_RUNS = 200, 30
CURRENT_LIMIT_A = 37.0
_P = PLANT_SPEC.defaults()
_C = CONTROLLER_SPEC.defaults()
#: the actuator's continuous output torque at the valve, N*m (15 A x kt x N)
CONTINUOUS_TORQUE_NM = _C["limits.continuous_current_a"] * _C["model.torque_constant_nm_per_a"] * _C["model.gear_ratio"]
PLATEAU_LOW_PCT, PLATEAU_HIGH_PCT = 5.0, 95.0
#: the nominal plant's physics as the controller's model holds it (spring, flow, friction schedule)
_MODEL = NominalModel.from_params(_C)


#: ``--box nominal``: the nominal plant at max Δp (told exactly), nominal resolvers and supply,
#: a clean demand -- only the friction scatter/ripple and the plateau sequence are random (the
#: first target row of issue 14)
NOMINAL_BOX = {"friction_model": "stick_slip", "friction_scale": 1.0, "dp_true_kpa": PRESSURE_MAX_KPA,
               "dp_kind": "exact", "dp_told_kpa": PRESSURE_MAX_KPA, "stiffness_scale": 1.0,
               "motor_inertia_scale": 1.0, "valve_inertia_scale": 1.0, "load_nm": 0.0,
               "valve_noise_counts": _P["resolver.valve_noise_counts"],
               "motor_noise_counts": _P["resolver.motor_noise_counts"], "resolver_delay_s": _P["resolver.delay_s"],
               "backlash_rad": 0.0, "supply_v": _P["supply_voltage_v"], "demand_noise_pct": 0.0, "glitches": []}
BOXES = ("full", "nominal")


def sample_case(seed: int, box: str = "full") -> dict:
    """The conditions of one run, drawn from ``seed`` (plain numbers, JSON-able)."""
    case = _sample_full(seed)
    if box == "nominal":
        case.update(NOMINAL_BOX)
    return case


def _sample_full(seed: int) -> dict:
    rng = np.random.default_rng(seed)
    u = rng.uniform
    model = ("stick_slip", "stribeck", "lugre")[int(rng.integers(3))]
    dp_true = PRESSURE_MAX_KPA if rng.random() < 0.5 else u(0.0, PRESSURE_MAX_KPA)
    r = rng.random()
    dp_kind = "exact" if r < 0.4 else "measured" if r < 0.7 else "wrong" if r < 0.9 else "missing"
    dp_told = {"exact": dp_true, "measured": dp_true + rng.normal(0.0, 0.05 * PRESSURE_MAX_KPA),
               "wrong": u(0.0, PRESSURE_MAX_KPA), "missing": PRESSURE_MAX_KPA}[dp_kind]
    initial = u(15.0, 85.0)
    # a steady load: the spring and flow torque plus this must stay within the continuous
    # torque at the most open plateau the sequence can reach
    spring_max = _P["spring.preload_nm"] + _P["spring.rate_nm_per_rad"] * _P["valve.stroke_rad"] * PLATEAU_HIGH_PCT / 100
    load_room = CONTINUOUS_TORQUE_NM - spring_max - _P["flow.torque_max_nm"]
    glitches = []
    if rng.random() < 1.0 / 3.0:
        glitches = [[round(u(0.5, 9.0), 3), float(rng.choice([-0.6, 0.6]))] for _ in range(int(rng.integers(1, 4)))]
    return {
        "seed": int(seed),
        "friction_model": model,
        "friction_scale": float(math.exp(u(math.log(0.5), math.log(3.0)))),
        "static_scatter": u(0.02, 0.08),
        "ripple": u(0.0, 0.05),
        "ripple_period_rad": u(0.005, 0.05),
        "ripple_phase_rad": u(0.0, 2 * math.pi),
        "stribeck_valve_rad_s": u(0.005, 0.05),
        "stribeck_motor_rad_s": u(0.5, 5.0),
        "dp_true_kpa": float(dp_true),
        "dp_kind": dp_kind,
        "dp_told_kpa": float(min(max(dp_told, 0.0), PRESSURE_MAX_KPA)),
        "stiffness_scale": u(0.3, 1.0),
        "motor_inertia_scale": u(0.8, 1.2),
        "valve_inertia_scale": u(0.8, 1.2),
        "load_nm": float(u(-0.3, 1.0) * load_room),
        "valve_noise_counts": u(0.0, 1.0),
        "motor_noise_counts": u(0.0, 1.0),
        "resolver_delay_s": u(0.0, 1e-3),
        "backlash_rad": u(0.0, 2e-3),
        "supply_v": u(18.0, 32.0),
        "demand_noise_pct": u(0.0, 0.1) if rng.random() < 0.5 else 0.0,
        "glitches": glitches,
        "initial_pct": initial,
        "plateau_seed": int(rng.integers(2**31 - 1)),
    }


def plant_overrides(case: dict) -> dict:
    """The perturbed plant of a case (SPEC §2 parameter names)."""
    over = {
        "pressure_differential_kpa": case["dp_true_kpa"],
        "friction_scale": case["friction_scale"],
        "friction.model": "lugre" if case["friction_model"] == "lugre" else "stick_slip",
        "friction.valve.static_scatter": case["static_scatter"],
        "friction.valve.ripple": case["ripple"],
        "friction.valve.ripple_period_rad": case["ripple_period_rad"],
        "friction.valve.ripple_phase_rad": case["ripple_phase_rad"],
        "coupling.stiffness_nm_per_rad": _P["coupling.stiffness_nm_per_rad"] * case["stiffness_scale"],
        "motor.inertia_kgm2": _P["motor.inertia_kgm2"] * case["motor_inertia_scale"],
        "valve.inertia_kgm2": _P["valve.inertia_kgm2"] * case["valve_inertia_scale"],
        "load_torque_nm": case["load_nm"],
        "resolver.valve_noise_counts": case["valve_noise_counts"],
        "resolver.motor_noise_counts": case["motor_noise_counts"],
        "resolver.delay_s": case["resolver_delay_s"],
        "gearbox.backlash_rad": case["backlash_rad"],
        "supply_voltage_v": case["supply_v"],
        "seed": case["seed"] % (2**31 - 1),
    }
    # what the Δp transducer tells the controller: the told value, or nothing (missing)
    if case["dp_kind"] == "missing":
        over["pressure_sensor.silent"] = True
    else:
        over["pressure_sensor.bias_kpa"] = case["dp_told_kpa"] - case["dp_true_kpa"]
    if case["friction_model"] == "stribeck":
        over["friction.valve.stribeck_velocity_rad_s"] = case["stribeck_valve_rad_s"]
        over["friction.motor.stribeck_velocity_rad_s"] = case["stribeck_motor_rad_s"]
    return over


def controller_knowledge(case: dict) -> dict:
    """What the controller is told about the operating point besides its Δp input (which the
    plant's biased or silent transducer carries, :func:`plant_overrides`): the fallback a
    missing Δp reading falls back to, the measured resolver delay and the supply voltage the
    drive measures on its DC bus (planned moves are designed for it)."""
    told = {"pressure.fallback_kpa": case["dp_told_kpa"]} if case["dp_kind"] == "missing" else {}
    if "resolver_delay_s" in CONTROLLER_SPEC.params:
        told["resolver_delay_s"] = case["resolver_delay_s"]
    if "drive.supply_voltage_v" in CONTROLLER_SPEC.params:
        told["drive.supply_voltage_v"] = case["supply_v"]
    return told


def case_scenario(case: dict, count: int = 12):
    """The plateau-sequence scenario of a case (the plant starts held at the first plateau): ``count`` plateaus
    (the campaign's 12; ``benchmarks/ros_loop.py --demand plateaus`` draws as many as its real-time run needs: the
    same first 12 steps, the 12th plateau held 0.3-0.8 s instead of ``final_hold_s``)."""
    demand = {"type": "plateaus", "seed": case["plateau_seed"], "count": int(count), "initial": case["initial_pct"],
              "start_s": 0.3, "min_step_pct": 0.1, "max_step_pct": 5.0, "hold_s": [0.3, 0.8],
              "final_hold_s": 4.0, "low": PLATEAU_LOW_PCT, "high": PLATEAU_HIGH_PCT,
              "noise_rms_pct": case["demand_noise_pct"], "noise_seed": case["seed"], "glitches": case["glitches"]}
    doc = {"name": f"robustness_{case['seed']}", "duration_s": 1.0, "initial_percent": case["initial_pct"],
           "pressure_differential_kpa": case["dp_true_kpa"], "demand": demand}
    sc = parse_scenario(doc)
    sc.duration_s = sc.demand.duration_s + 0.001
    return sc


def breakaway_torque_nm(case: dict, valve_rad: float) -> float:
    """Valve torque (N*m) the drive must apply to break the valve loose toward open at
    ``valve_rad``: the return spring and flow torque at the true Δp, the case's steady load and
    its static friction (nominal level x ``friction_scale``; scatter and ripple left out, so
    this is a lower bound)."""
    static = _MODEL.friction(case["dp_true_kpa"]).valve_static_nm * case["friction_scale"]
    return _MODEL.load_torque(valve_rad, case["dp_true_kpa"]) + case["load_nm"] + static


def beyond_rating(case: dict, plateaus: list[dict]) -> bool:
    """Whether an opening move of the run needs more than the actuator's continuous torque to
    break the valve loose (:func:`breakaway_torque_nm`): the load draw keeps spring + flow + load
    within it, but not the friction on top.  On such a plant only the I2t peak budget can open
    the valve, and a stall there is the overload the ``overcurrent_i2t`` fault is for."""
    return any(pl["to_rad"] > pl["from_rad"] and breakaway_torque_nm(case, pl["to_rad"]) > CONTINUOUS_TORQUE_NM
               for pl in plateaus)


def case_plan(case: dict, mode: str | None = None, controller_sets: dict | None = None):
    """The offline run plan (:class:`~fuel_valve_control.tools.run_plan.RunPlan`) of a campaign ``case`` as
    :func:`run_case` simulates it: its scenario (:func:`case_scenario`), the plant drawn (:func:`plant_overrides`),
    the controller told what the case lets it know (:func:`controller_knowledge`) plus ``controller_sets``
    (``{"section.key": value}``), in ``mode`` (None: the default)."""
    sc = case_scenario(case)
    p, c = sim.build(sc, plant_overrides(case), {**controller_knowledge(case), **(controller_sets or {})}, None, mode)
    return replace(plan_run(sc, OFFLINE), plant_params=p, controller_params=c)


def held_case(case: dict, mode: str | None = None, controller_sets: dict | None = None):
    """``(plan, plant, driver)`` of a campaign ``case`` (:func:`case_plan`): the plant and the driver built and
    started held at the first plateau exactly as :func:`run_case`'s ``sim.simulate_plan`` starts them, for a
    caller that closes the loop itself (``sim.exchange_period`` per period) and reads the plant's truth or the
    stage's state between periods (benchmarks/pulse_moves_check.py, benchmarks/plateau_floor.py, tests)."""
    plan = case_plan(case, mode, controller_sets)
    plant, driver = Plant(plan.plant_params), ValveDriver(plan.controller_params)
    plan.start_held(plant, driver)
    return plan, plant, driver


def run_case(job: tuple) -> dict:
    case, mode, controller_sets = job
    res = sim.simulate_plan(case_plan(case, mode, controller_sets))
    log = res.log
    tr = M.Trace(log[:, 0], log[:, 1], log[:, 2], np.hypot(log[:, 7], log[:, 8]), log[:, 9], res.stroke_rad)
    plats = M.plateau_results(tr)
    return {
        "case": case,
        "wall_time_s": round(res.wall_time_s, 3),
        "sim_time_s": res.sim_time_s,
        "peak_current_a": float(np.max(np.abs(tr.current))),
        "fault": bool(np.min(tr.enable) < 0.5),
        "beyond_rating": beyond_rating(case, plats),
        "hunts": any(pl["hunts"] for pl in plats),
        "plateaus": [{k: pl.get(k) for k in ("from_rad", "to_rad", "final_error_rad", "overshoot_pct",
                                             "overshoot_rad", "hunting_amplitude_rad", "hunting_reversals",
                                             "hunts", "duration_s")} for pl in plats],
    }


def _stats(values) -> dict:
    v = np.asarray([x for x in values if x is not None and math.isfinite(x)], dtype=float)
    if len(v) == 0:
        return {"n": 0, "median": None, "p95": None, "max": None}
    return {"n": int(len(v)), "median": float(np.median(v)), "p95": float(np.percentile(v, 95)),
            "max": float(v.max())}


def summarise(results: list[dict]) -> dict:
    plats = [pl for r in results for pl in r["plateaus"]]
    step_os = M.plateau_step_overshoots(plats, STROKE_RAD)
    return {
        "runs": len(results),
        "plateaus": len(plats),
        "final_error_rad": _stats(pl["final_error_rad"] for pl in plats),
        "overshoot_rad": _stats(pl["overshoot_rad"] for pl in plats),
        "overshoot_pct": _stats(pl["overshoot_pct"] for pl in plats),
        "overshoot_pct_steps_ge_1pct": _stats(step_os),
        # the plateau-step overshoot's tail (steps >= 1 % of stroke): n, median, p95, max, over_10, over_50
        "step_overshoot": M.overshoot_tail(step_os),
        "worst_step_overshoots": worst_steps(results),
        "hunting_amplitude_rad": _stats(max((pl["hunting_amplitude_rad"] for pl in r["plateaus"]), default=0.0)
                                        for r in results),
        "peak_current_a": _stats(r["peak_current_a"] for r in results),
        "runs_hunting": sum(r["hunts"] for r in results),
        "runs_over_37a": sum(r["peak_current_a"] > CURRENT_LIMIT_A for r in results),
        "runs_faulted": sum(r["fault"] for r in results),
        # faults on plants whose opening breakaway needs more than the continuous torque
        "runs_faulted_beyond_rating": sum(r["fault"] and r.get("beyond_rating", False) for r in results),
        "runs_beyond_rating": sum(r.get("beyond_rating", False) for r in results),
        "plateaus_over_5e-4": sum(pl["final_error_rad"] > 5e-4 for pl in plats),
        "plateaus_over_8e-4": sum(pl["final_error_rad"] > 8e-4 for pl in plats),
    }


def worst_steps(results: list[dict], count: int = 8) -> list[dict]:
    """The ``count`` largest plateau-step overshoots (steps >= 1 % of stroke,
    :func:`~fuel_valve_control.tools.metrics.plateau_step_overshoots`): seed, plateau index in
    its run, from / to (% of stroke) and overshoot (% of the step), largest first."""
    rows = []
    for r in results:
        for i, pl in enumerate(r["plateaus"]):
            for os_pct in M.plateau_step_overshoots([pl], STROKE_RAD):
                rows.append({"seed": r["case"]["seed"], "plateau": i, "from_pct": 100.0 * pl["from_rad"] / STROKE_RAD,
                             "to_pct": 100.0 * pl["to_rad"] / STROKE_RAD, "overshoot_pct": os_pct})
    return sorted(rows, key=lambda row: row["overshoot_pct"], reverse=True)[:count]


def _fmt(x) -> str:
    if x is None:
        return "—"
    if x != 0 and (abs(x) < 1e-2 or abs(x) >= 1e4):
        return f"{x:.2e}"
    return f"{x:.3g}"


def report(summary: dict, results: list[dict], label: str) -> str:
    rows = [f"### {label}: {summary['runs']} runs, {summary['plateaus']} plateaus", "",
            "| metric | median | p95 | max |", "|---|---|---|---|"]
    for key, name in (("final_error_rad", "plateau final error, rad"), ("overshoot_rad", "overshoot, rad"),
                      ("overshoot_pct", "overshoot, % of step"),
                      ("overshoot_pct_steps_ge_1pct", "overshoot, % of step (steps ≥ 1 %)"),
                      ("hunting_amplitude_rad", "hunting amplitude per run, rad"),
                      ("peak_current_a", "peak current per run, A")):
        s = summary[key]
        rows.append(f"| {name} | {_fmt(s['median'])} | {_fmt(s['p95'])} | {_fmt(s['max'])} |")
    rows += ["", f"runs that hunt (≥ 2 reversals, > 2 counts, after 0.3 s on a plateau): "
                 f"**{summary['runs_hunting']}**; over 37 A: **{summary['runs_over_37a']}**; "
                 f"fault latched: **{summary['runs_faulted']}** ({summary['runs_faulted_beyond_rating']} of them on "
                 f"the {summary['runs_beyond_rating']} plants whose opening breakaway needs more than the continuous "
                 f"torque); plateaus ending beyond 5e-4 / 8e-4 rad: "
                 f"{summary['plateaus_over_5e-4']} / {summary['plateaus_over_8e-4']}"]
    so = summary["step_overshoot"]
    rows += ["", f"plateau steps ≥ 1 % of stroke: {so['n']}; overshoot > 10 % of the step: **{so['over_10']}**, "
                 f"> 50 %: **{so['over_50']}**; largest:", "",
             "| seed | plateau | from → to % | overshoot % |", "|---|---|---|---|"]
    rows += [f"| {w['seed']} | {w['plateau']} | {w['from_pct']:.2f} → {w['to_pct']:.2f} | {w['overshoot_pct']:.1f} |"
             for w in summary["worst_step_overshoots"]]
    worst = sorted(results, key=lambda r: max((pl["final_error_rad"] for pl in r["plateaus"]), default=0.0),
                   reverse=True)[:5]
    rows += ["", "worst runs (largest plateau final error):", "",
             "| seed | model | F× | Δp true/told kPa (kind) | K× | load N·m | delay ms | noise % | "
             "worst final err rad | hunts | peak A |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in worst:
        c = r["case"]
        err = max((pl["final_error_rad"] for pl in r["plateaus"]), default=0.0)
        rows.append(f"| {c['seed']} | {c['friction_model']} | {c['friction_scale']:.2f} | "
                    f"{c['dp_true_kpa']:.0f}/{c['dp_told_kpa']:.0f} ({c['dp_kind']}) | {c['stiffness_scale']:.2f} | "
                    f"{c['load_nm']:.1f} | {c['resolver_delay_s'] * 1e3:.2f} | {c['demand_noise_pct']:.3f} | "
                    f"{_fmt(err)} | {r['hunts']} | {r['peak_current_a']:.1f} |")
    return "\n".join(rows)


def controller_sets(overrides: list[str]) -> dict:
    """``--set controller.KEY=VALUE`` arguments as the controller's parameter changes, checked against its schema
    (:class:`ConfigError` on an unknown key or a bad value) -- this campaign's and other_valves.py's."""
    sets = parse_overrides(overrides, ("controller",))["controller"]
    CONTROLLER_SPEC.load(None, sets)
    return sets


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=None, help=f"number of runs (default {DEFAULT_RUNS})")
    ap.add_argument("--quick", action="store_true", help=f"{QUICK_RUNS} runs")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="worker processes (default: CPUs)")
    ap.add_argument("--seed", type=int, default=1000, help="seed of the first run (run i uses seed + i)")
    ap.add_argument("--box", choices=BOXES, default="full", help="full: every perturbation (default); nominal: "
                    "nominal plant at max Δp, only friction scatter/ripple and the plateaus random")
    ap.add_argument("--mode", default=DEFAULT_MODE, help=f"control mode (default {DEFAULT_MODE})")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="controller.KEY=VALUE",
                    help="controller parameter for every run")
    ap.add_argument("--valve-noise-counts", type=float, default=None, metavar="COUNTS",
                    help="the valve resolver's rms noise (counts) of every run instead of the box's draw (the "
                         "nominal box: 0.25; docs section 119)")
    ap.add_argument("--json", metavar="PATH", help="also write the JSON (with every run) here")
    ap.add_argument("--markdown", metavar="PATH", help="also write the tables here")
    args = ap.parse_args(argv)
    if args.mode not in MODES:
        print(f"robustness: unknown mode {args.mode!r}; allowed: {', '.join(MODES)}", file=sys.stderr)
        return 2
    try:
        sets = controller_sets(args.overrides)
    except ConfigError as exc:
        print(f"robustness: {exc}", file=sys.stderr)
        return 2
    n = args.runs if args.runs is not None else (QUICK_RUNS if args.quick else DEFAULT_RUNS)
    if args.valve_noise_counts is not None and not 0.0 <= args.valve_noise_counts <= 100.0:
        print("robustness: --valve-noise-counts must lie in 0..100", file=sys.stderr)
        return 2
    noise = {} if args.valve_noise_counts is None else {"valve_noise_counts": args.valve_noise_counts}
    jobs = [({**sample_case(args.seed + i, args.box), **noise}, args.mode, sets) for i in range(n)]
    start = time.perf_counter()
    if args.jobs > 1:
        with Pool(args.jobs) as pool:
            results = pool.map(run_case, jobs, chunksize=1)
    else:
        results = [run_case(j) for j in jobs]
    wall = time.perf_counter() - start
    summary = summarise(results)
    command = "python benchmarks/robustness.py " + " ".join(argv if argv is not None else sys.argv[1:])
    label = f"`{args.mode}`, {args.box} box" + (f" ({', '.join(f'{k}={v}' for k, v in sets.items())})" if sets else "") \
        + (f", valve resolver noise {args.valve_noise_counts} counts rms" if noise else "")
    md = report(summary, results, label) + f"\n\n_{n} runs, {wall:.1f} s wall with {args.jobs} job(s): " \
                                            f"`{command.strip()}`_"
    print(md)
    if args.markdown:
        Path(args.markdown).write_text(md + "\n")
    doc = {"command": command.strip(), "mode": args.mode, "box": args.box, "controller_sets": sets, "seed": args.seed,
           "valve_noise_counts": args.valve_noise_counts,
           "wall_time_s": round(wall, 2), "jobs": args.jobs, "summary": summary}
    if args.json:
        Path(args.json).write_text(json.dumps(M.jsonable({**doc, "results": results}), indent=1) + "\n")
    print(json.dumps(M.jsonable(doc)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
