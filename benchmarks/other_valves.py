#!/usr/bin/env python3
"""Other valves (issue 14, docs/control_results.md section 35): does the controller generalise
to actuators it was not tuned on, when it is told their correct model?

Every campaign before perturbs the *nominal* valve (48:1 gear, K 480 N*m/rad, JL 1.76e-3
kg*m^2, friction 5.5 / 4.4 N*m static / Coulomb at max Δp, stroke 1.047 rad, 1 kHz loop).
Here each entry of :data:`VALVES` is one physically plausible *other* actuator: the same
parameters set on the plant (``plant.X``) and in the controller's model (``controller.model.X``),
so the controller's designed gains and physically derived thresholds must carry over.  Any
constant fitted to the nominal valve shows up as hunting, a fault, overshoot or an exception.

Per valve and mode (default ``observer_fp`` and ``observer_ff``) it runs the scenarios
:data:`SCENARIOS` (seed 0) and a short plateau campaign (``robustness.py``'s nominal box:
12 random plateaus at max Δp with friction scatter and ripple, seeds ``--seed``..), in a
process pool, prints one table and, as its last line, one JSON object.

    python benchmarks/other_valves.py [--jobs N] [--runs N] [--seed S] [--valves a,b] [--modes m1,m2]
                                      [--scenarios s1,s2] [--json PATH]

Per (valve, mode) row: worst overshoot of the steps (step_small, large_step, %), the hold's
final error and limit cycle, hunting (any plateau of any scenario / campaign run), faults
(drive disabled by a latched fault outside the ``trip`` scenario), peak current, campaign
plateau final error median / p95 / max, and exceptions.

Units: rad, N*m, A, s, kPa; percent of stroke for demands.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
import traceback
from multiprocessing import Pool
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for p in (ROOT, ROOT / "benchmarks"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

import robustness as R  # noqa: E402
from fuel_valve_control.core.params import CONTROLLER_SPEC  # noqa: E402
from fuel_valve_control.common.paramspec import ConfigError  # noqa: E402
from fuel_valve_control.tools import metrics as M  # noqa: E402
from fuel_valve_control.tools import sim  # noqa: E402
from fuel_valve_control.tools.scenarios import load_scenario  # noqa: E402
from fuel_valve_plant.physics.params import PLANT_SPEC  # noqa: E402

_P = PLANT_SPEC.defaults()
_C = CONTROLLER_SPEC.defaults()

SCENARIOS = ("step_small", "hold", "large_step", "startup", "sine_sweep", "full_stroke", "trip")
MODES = ("observer_fp", "observer_ff")

#: physical parameter -> (plant key, controller model key); the model key None: plant only
_KEYS = {
    "gear_ratio": ("gearbox.ratio", "model.gear_ratio"),
    "stiffness": ("coupling.stiffness_nm_per_rad", "model.coupling_stiffness_nm_per_rad"),
    "coupling_damping": ("coupling.damping_nms", "model.coupling_damping_nms"),
    "valve_inertia": ("valve.inertia_kgm2", "model.valve_inertia_kgm2"),
    "valve_viscous": ("valve.viscous_nms", "model.valve_viscous_nms"),
    "motor_inertia": ("motor.inertia_kgm2", "model.motor_inertia_kgm2"),
    "motor_resistance": ("motor.resistance_ohm", "model.motor_resistance_ohm"),
    "motor_lq": ("motor.lq_h", "model.motor_lq_h"),
    "stroke": ("valve.stroke_rad", "model.stroke_rad"),
    "spring_preload": ("spring.preload_nm", "model.spring_preload_nm"),
    "spring_rate": ("spring.rate_nm_per_rad", "model.spring_rate_nm_per_rad"),
    "flow_torque": ("flow.torque_max_nm", "model.flow_torque_max_nm"),
    "valve_coulomb": ("friction.valve.coulomb_nm", "model.valve_coulomb_nm"),
    "valve_coulomb_per_dp": ("friction.valve.coulomb_per_dp_nm", "model.valve_coulomb_per_dp_nm"),
    "valve_static": ("friction.valve.static_nm", "model.valve_static_nm"),
    "valve_static_per_dp": ("friction.valve.static_per_dp_nm", "model.valve_static_per_dp_nm"),
    "motor_coulomb": ("friction.motor.coulomb_nm", "model.motor_coulomb_nm"),
    "motor_static": ("friction.motor.static_nm", "model.motor_static_nm"),
}


def _friction(scale: float) -> dict:
    """Valve friction levels ``scale`` x nominal (static and Coulomb, both Δp terms), N*m."""
    return {k: scale * _P[_KEYS[k][0]] for k in ("valve_coulomb", "valve_coulomb_per_dp", "valve_static",
                                                  "valve_static_per_dp")}


#: The other valves: physical parameters (names of :data:`_KEYS`, plus ``flux_linkage`` Wb for the
#: motor's torque constant 1.5 p psi_f and ``loop_rate_hz``); what is not given is nominal.
#: Each is sized so its continuous torque (15 A x kt x N) still breaks the valve loose at
#: full stroke and max Δp (spring + flow + static friction), as the nominal one does (24.8 vs
#: 19.7 N*m), unless its description says otherwise.
VALVES = {
    "nominal": {},
    # a faster, lower-ratio gearbox driven by a stronger motor (same output torque)
    "gear30_strong_motor": {"gear_ratio": 30.0, "flux_linkage": 0.0184, "motor_inertia": 1.1e-5,
                            "motor_resistance": 0.22, "motor_lq": 3.6e-4},
    # a high-ratio gearbox: more torque, slower, more reflected motor inertia
    "gear80": {"gear_ratio": 80.0},
    # a stiff torsion coupling (resonance 3x higher in K)
    "stiff_coupling": {"stiffness": 1500.0},
    # a soft coupling the controller knows about (mode at ~K/(JL) lower)
    "soft_coupling": {"stiffness": 200.0},
    # a heavier valve shaft (x3 inertia), same friction
    "heavy_valve": {"valve_inertia": 3 * 1.76e-3, "valve_viscous": 0.1},
    # a stickier valve (friction x2) with the gearbox that can still break it loose
    "sticky_gear80": {**_friction(2.0), "gear_ratio": 80.0},
    # a low-friction valve (x0.4): small stick-slip jump, small breakaway torque
    "slippery": {**_friction(0.4)},
    # a 90 deg (ball) valve: longer stroke
    "long_stroke": {"stroke": 1.5708},
    # a smaller motor (kt x0.7, Jm x0.6) behind a higher ratio
    "small_motor_gear70": {"gear_ratio": 70.0, "flux_linkage": 0.0080, "motor_inertia": 4.2e-6,
                           "motor_resistance": 0.12, "motor_lq": 2.0e-4},
    # the nominal valve on a 2 kHz loop and on a 500 Hz loop
    "loop2k": {"loop_rate_hz": 2000.0},
    "loop500": {"loop_rate_hz": 500.0},
}


def overrides(valve: dict) -> tuple[dict, dict]:
    """(plant overrides, controller overrides) of a valve: each physical parameter on the plant and
    in the controller's model, so the controller is told the correct model."""
    plant, ctrl = {}, {}
    for name, value in valve.items():
        if name == "flux_linkage":
            plant["motor.flux_linkage_wb"] = value
            ctrl["model.torque_constant_nm_per_a"] = 1.5 * _P["motor.pole_pairs"] * value
        elif name == "loop_rate_hz":
            ctrl["loop_rate_hz"] = value     # offline, the plant advances one controller period per step
        else:
            pk, ck = _KEYS[name]
            plant[pk] = value
            if ck:
                ctrl[ck] = value
    return plant, ctrl


def ratings(valve: dict) -> dict:
    """Continuous torque at the valve (15 A x kt x N) and the torque needed to break the valve loose
    toward open at full stroke and max Δp (spring + flow peak + static friction), N*m: a physical
    check of the valve's sizing, not a controller figure."""
    v = {**{k: _P[pk] for k, (pk, _) in _KEYS.items()}, **valve}
    kt = 1.5 * _P["motor.pole_pairs"] * v.get("flux_linkage", _P["motor.flux_linkage_wb"])
    cont = _C["limits.continuous_current_a"] * kt * v["gear_ratio"]
    need = (v["spring_preload"] + v["spring_rate"] * v["stroke"] + v["flow_torque"]
            + v["valve_static"] + v["valve_static_per_dp"])
    return {"continuous_torque_nm": cont, "breakaway_open_nm": need, "margin": cont / need}


def _plateau_summary(tr) -> list[dict]:
    return [{k: pl.get(k) for k in ("from_rad", "to_rad", "final_error_rad", "overshoot_pct", "overshoot_rad",
                                    "hunting_amplitude_rad", "hunting_reversals", "hunts")}
            for pl in M.plateau_results(tr)]


def _trace(res):
    log = res.log
    return M.Trace(log[:, 0], log[:, 1], log[:, 2], np.hypot(log[:, 7], log[:, 8]), log[:, 9], res.stroke_rad)


def run_scenario(job: tuple) -> dict:
    """One scenario on one valve (seed 0): metrics, hunting plateaus, fault, peak current."""
    vname, mode, scen, *sets = job
    plant, ctrl = overrides(VALVES[vname])
    ctrl = {**ctrl, **(sets[0] if sets else {})}
    out = {"valve": vname, "mode": mode, "kind": "scenario", "name": scen}
    try:
        res = sim.run(scen, mode=mode, plant_overrides=plant, controller_overrides=ctrl, seed=0)
    except Exception as exc:  # noqa: BLE001 -- an exception on another valve is a finding
        out["error"] = f"{type(exc).__name__}: {exc}"
        out["traceback"] = traceback.format_exc(limit=4)
        return out
    tr = _trace(res)
    plats = _plateau_summary(tr)
    out.update(metrics=res.metrics, fault=bool(np.any(res.fault > 0)), disabled=bool(np.min(tr.enable) < 0.5),
               peak_current_a=float(np.max(np.abs(tr.current))), hunts=any(pl["hunts"] for pl in plats),
               plateaus=plats, warnings=sorted(res.warnings))
    return out


def run_campaign(job: tuple) -> dict:
    """One nominal-box plateau run (robustness.py's case) on one valve."""
    vname, mode, seed, *sets = job
    plant, ctrl = overrides(VALVES[vname])
    ctrl = {**ctrl, **(sets[0] if sets else {})}
    case = R.sample_case(seed, "nominal")
    out = {"valve": vname, "mode": mode, "kind": "campaign", "name": f"seed{seed}"}
    try:
        sc = R.case_scenario(case)
        pover = {**R.plant_overrides(case), **plant}
        p, c = sim.build(sc, pover, {**R.controller_knowledge(case), **ctrl}, None, mode)
        res = sim.simulate(sc, p, c)
    except Exception as exc:  # noqa: BLE001
        out["error"] = f"{type(exc).__name__}: {exc}"
        out["traceback"] = traceback.format_exc(limit=4)
        return out
    tr = _trace(res)
    plats = _plateau_summary(tr)
    out.update(fault=bool(np.any(res.fault > 0)), disabled=bool(np.min(tr.enable) < 0.5),
               peak_current_a=float(np.max(np.abs(tr.current))), hunts=any(pl["hunts"] for pl in plats),
               plateaus=plats, stroke_rad=res.stroke_rad, warnings=sorted(res.warnings))
    return out


def _pct(v, q):
    return float(np.percentile(v, q)) if len(v) else None


def summarise(results: list[dict]) -> dict:
    """Per ``valve/mode``: the figures of the table (see the module docstring)."""
    rows = {}
    for r in results:
        row = rows.setdefault(f"{r['valve']}/{r['mode']}", {
            "valve": r["valve"], "mode": r["mode"], "errors": [], "hunting": [], "faults": [], "peak_current_a": 0.0,
            "step_overshoot_pct": {}, "hold_error_rad": None, "hold_limit_cycle_rad": None, "startup_worst_rad": None,
            "campaign_errors": [], "campaign_step_overshoots": []})
        tag = f"{r['kind']}:{r['name']}"
        if "error" in r:
            row["errors"].append(f"{tag}: {r['error'][:120]}")
            continue
        if r["hunts"]:
            row["hunting"].append(tag)
        if r["fault"] and r["name"] != "trip":
            row["faults"].append(tag)
        row["peak_current_a"] = max(row["peak_current_a"], r["peak_current_a"])
        if r["kind"] == "scenario":
            m = r["metrics"]
            if r["name"] in ("step_small", "large_step"):
                row["step_overshoot_pct"][r["name"]] = m.get("overshoot_pct")
            if r["name"] == "hold":
                row["hold_error_rad"] = m.get("steady_state_error_rad")
                row["hold_limit_cycle_rad"] = m.get("limit_cycle_amplitude_rad")
            if r["name"] == "startup":
                row["startup_worst_rad"] = max((pl["final_error_rad"] for pl in r["plateaus"]), default=None)
        else:
            row["campaign_errors"] += [pl["final_error_rad"] for pl in r["plateaus"]]
            row["campaign_step_overshoots"] += M.plateau_step_overshoots(r["plateaus"], r["stroke_rad"])
    for row in rows.values():
        e = row.pop("campaign_errors")
        so = row.pop("campaign_step_overshoots")
        row["campaign"] = {"plateaus": len(e), "median_rad": _pct(e, 50), "p95_rad": _pct(e, 95),
                           "max_rad": max(e) if e else None, "over_8e-4": sum(x > 8e-4 for x in e),
                           "step_overshoot_p95_pct": _pct(so, 95), "steps_over_10pct": sum(x > 10 for x in so)}
        row["ratings"] = ratings(VALVES[row["valve"]])
    return rows


def _f(x, fmt=".2e"):
    return "—" if x is None else format(x, fmt)


def table(rows: dict) -> str:
    out = ["| valve | mode | margin | step_small / large_step OS % | hold err rad | startup worst rad | campaign "
           "med / p95 / max rad (> 8e-4) | camp. steps > 10 % | peak A | hunting | faults | errors |",
           "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in rows.values():
        c = row["campaign"]
        os_ = row["step_overshoot_pct"]
        out.append(f"| {row['valve']} | {row['mode']} | {row['ratings']['margin']:.2f} | "
                   f"{_f(os_.get('step_small'), '.1f')} / {_f(os_.get('large_step'), '.1f')} | "
                   f"{_f(row['hold_error_rad'])} | {_f(row['startup_worst_rad'])} | "
                   f"{_f(c['median_rad'])} / {_f(c['p95_rad'])} / {_f(c['max_rad'])} ({c['over_8e-4']}) | "
                   f"{c['steps_over_10pct']} | {row['peak_current_a']:.1f} | {', '.join(row['hunting']) or '-'} | "
                   f"{', '.join(row['faults']) or '-'} | {'; '.join(row['errors']) or '-'} |")
    return "\n".join(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--runs", type=int, default=6, help="campaign runs per valve and mode (nominal box)")
    ap.add_argument("--seed", type=int, default=1000, help="campaign seed of the first run")
    ap.add_argument("--valves", default=",".join(VALVES), help="comma-separated names of VALVES")
    ap.add_argument("--modes", default=",".join(MODES))
    ap.add_argument("--scenarios", default=",".join(SCENARIOS))
    ap.add_argument("--json", metavar="PATH", help="also write every run here")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="controller.KEY=VALUE",
                    help="controller parameter override on every valve (repeatable; after the valve's own model)")
    args = ap.parse_args(argv)
    try:
        sets = R.controller_sets(args.overrides)
    except ConfigError as exc:
        print(f"other_valves: {exc}", file=sys.stderr)
        return 2
    valves = [v for v in args.valves.split(",") if v]
    unknown = [v for v in valves if v not in VALVES]
    if unknown:
        print(f"other_valves: unknown valve(s) {unknown}; known: {', '.join(VALVES)}", file=sys.stderr)
        return 2
    modes = [m for m in args.modes.split(",") if m]
    scens = [s for s in args.scenarios.split(",") if s]
    for s in scens:
        load_scenario(s)
    jobs = [(run_scenario, (v, m, s, sets)) for v in valves for m in modes for s in scens]
    jobs += [(run_campaign, (v, m, args.seed + i, sets)) for v in valves for m in modes for i in range(args.runs)]
    start = time.perf_counter()
    if args.jobs > 1:
        with Pool(args.jobs) as pool:
            results = pool.map(_call, jobs, chunksize=1)
    else:
        results = [_call(j) for j in jobs]
    wall = time.perf_counter() - start
    rows = summarise(results)
    print(table(rows))
    print(f"\n_{len(jobs)} runs, {wall:.0f} s wall with {args.jobs} job(s)_")
    if args.json:
        Path(args.json).write_text(json.dumps(M.jsonable({"rows": rows, "results": results}), indent=1) + "\n")
    print(json.dumps(M.jsonable({"rows": rows, "wall_time_s": round(wall, 1)})))
    return 0


def _call(job):
    fn, arg = job
    return fn(arg)


if __name__ == "__main__":
    raise SystemExit(main())
