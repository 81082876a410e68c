#!/usr/bin/env python3
"""Control quality: every control mode over every built-in scenario, plus the robustness box.

1. **Scenarios**: each mode of SPEC §3 runs each scenario of ``config/scenarios/`` on the
   nominal plant; one table row per mode x scenario with the SPEC §5 metrics.
2. **Robustness** (SPEC §6): ``observer_fc`` and the default mode run ``step_small`` and
   ``hold`` at the same gains (the controller's nominal model is never told) on plants
   perturbed to the edges of the box: friction scale 0.5 / 3, Δp 0 / max (the supervisor
   reports Δp, so the controller is told), coupling stiffness x 0.1 / 1, inertia (both shafts)
   -20 / +20 %.  Single-parameter extremes and all 16 corners.  For each: small-step
   overshoot and settling, the hold's limit cycle against the allowance
   ``2 (Ts - Tc)/K + 2 counts`` computed from that plant's own friction and stiffness.

Prints readable tables, then, as the last line, one JSON object with every result.

    python benchmarks/control_quality.py [--jobs N] [--quick] [--modes a,b] [--scenarios a,b]
                                         [--no-robustness] [--json PATH] [--markdown PATH]

``--quick`` shortens the long scenarios (hold 12 s, startup 10 s, sine sweep unchanged as its
bandwidth needs the full sweep) and runs only the single-parameter robustness extremes.
"""
from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import sys
import time
from multiprocessing import Pool
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from fuel_valve_control.tools import metrics, sim  # noqa: E402
from fuel_valve_control.core.params import DEFAULT_MODE, MODES  # noqa: E402
from fuel_valve_control.tools.metrics import RESOLVER_COUNT_RAD  # noqa: E402
from fuel_valve_control.tools.scenarios import builtin_names, load_scenario  # noqa: E402
from fuel_valve_plant.physics.friction import friction_levels  # noqa: E402
from fuel_valve_plant.physics.params import PLANT_SPEC  # noqa: E402

METRIC_KEYS = ("rise_time_s", "overshoot_pct", "settling_time_s", "steady_state_error_rad",
               "limit_cycle_amplitude_rad", "limit_cycle_frequency_hz", "peak_current_a", "rms_current_a",
               "stroke_time_s", "close_time_s", "bandwidth_hz", "iae_rad_s", "ramp_max_error_rad", "ramp_lag_s")
QUICK_DURATION_S = {"hold": 12.0, "startup": 10.0}
ROBUST_MODES = ("observer_fc", DEFAULT_MODE)
P_MAX = 6206.0
_D = PLANT_SPEC.defaults()
JM, JL, K0 = _D["motor.inertia_kgm2"], _D["valve.inertia_kgm2"], _D["coupling.stiffness_nm_per_rad"]

# the box of SPEC §6: (label, value at the low edge, value at the high edge)
AXES = {
    "friction": (0.5, 3.0),
    "dp_kpa": (0.0, P_MAX),
    "stiffness": (0.1, 1.0),
    "inertia": (0.8, 1.2),
}
NOMINAL = {"friction": 1.0, "dp_kpa": P_MAX, "stiffness": 1.0, "inertia": 1.0}


def corner_name(c: dict) -> str:
    parts = []
    if c["friction"] != 1.0:
        parts.append(f"F×{c['friction']:g}")
    if c["dp_kpa"] != P_MAX:
        parts.append(f"Δp={c['dp_kpa']:g}")
    if c["stiffness"] != 1.0:
        parts.append(f"K×{c['stiffness']:g}")
    if c["inertia"] != 1.0:
        parts.append(f"J{(c['inertia'] - 1) * 100:+.0f}%")
    return " ".join(parts) or "nominal"


def corners(full: bool = True) -> list[dict]:
    """Nominal, the eight single-parameter extremes (those equal to nominal dropped) and,
    with ``full``, the 16 corners of the box."""
    out = [dict(NOMINAL)]
    for axis, values in AXES.items():
        for v in values:
            if v != NOMINAL[axis]:
                out.append({**NOMINAL, axis: v})
    if full:
        for combo in itertools.product(*AXES.values()):
            c = dict(zip(AXES, combo))
            if c not in out:
                out.append(c)
    return out


def corner_overrides(c: dict) -> tuple[dict, dict]:
    """(plant overrides, controller overrides) for a corner: the controller keeps its nominal
    model and measures Δp (the plant's pressure_differential output)."""
    plant = {"friction_scale": c["friction"], "pressure_differential_kpa": c["dp_kpa"],
             "coupling.stiffness_nm_per_rad": K0 * c["stiffness"],
             "motor.inertia_kgm2": JM * c["inertia"], "valve.inertia_kgm2": JL * c["inertia"]}
    return plant, {}


def hunting_allowance(plant_ps) -> tuple[float, float]:
    """(stick-slip jump 2 (Ts - Tc)/K of this plant, allowance = jump + 2 counts), rad."""
    jump = friction_levels(plant_ps).stick_slip_jump_rad(plant_ps["coupling.stiffness_nm_per_rad"])
    return jump, jump + 2.0 * RESOLVER_COUNT_RAD


def _run(job: tuple) -> dict:
    kind, mode, scenario, duration, corner = job
    sc = load_scenario(scenario)
    if duration is not None:
        sc.duration_s = duration
    p_over, c_over = corner_overrides(corner) if corner is not None else ({}, {})
    p, c = sim.build(sc, p_over, c_over, None, mode)
    res = sim.simulate(sc, p, c)
    out = {"kind": kind, "mode": mode, "scenario": scenario, "duration_s": sc.duration_s,
           "wall_time_s": round(res.wall_time_s, 3),
           "metrics": {k: res.metrics[k] for k in METRIC_KEYS if k in res.metrics}}
    steps = [g for g in res.segments if g["kind"] == "step"]
    if steps:
        out["step_rad"] = steps[-1]["to_rad"] - steps[-1]["from_rad"]
    if corner is not None:
        jump, allowance = hunting_allowance(p)
        out.update(corner=corner, corner_name=corner_name(corner), jump_rad=jump, hunting_allowance_rad=allowance)
        # stability evidence: the valve ends near the demand, at rest or within the allowance
        pos, dem = res.column("position_rad"), res.column("demand_rad")
        out["final_error_rad"] = float(abs(dem[-1] - pos[-1]))
        out["final_speed_rad_s"] = float(abs(res.column("velocity_rad_s")[-200:]).max())
        out["enabled_at_end"] = bool(res.column("enable")[-1] > 0.5)
    return out


def _fmt(v, unit_scale=1.0, digits=3) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "—"
    x = v * unit_scale
    if x != 0 and (abs(x) < 1e-3 or abs(x) >= 1e4):
        return f"{x:.2e}"
    return f"{x:.{digits}g}"


SCEN_COLS = (("rise s", "rise_time_s"), ("OS %", "overshoot_pct"), ("settle s", "settling_time_s"),
             ("sse rad", "steady_state_error_rad"), ("LC amp rad", "limit_cycle_amplitude_rad"),
             ("LC Hz", "limit_cycle_frequency_hz"), ("peak A", "peak_current_a"), ("rms A", "rms_current_a"),
             ("stroke s", "stroke_time_s"), ("close s", "close_time_s"), ("BW Hz", "bandwidth_hz"),
             ("IAE rad·s", "iae_rad_s"), ("ramp err rad", "ramp_max_error_rad"), ("ramp lag s", "ramp_lag_s"))


def scenario_table(results: list[dict]) -> str:
    head = "| mode | scenario | " + " | ".join(h for h, _ in SCEN_COLS) + " |"
    rows = [head, "|" + "---|" * (len(SCEN_COLS) + 2)]
    for r in results:
        m = r["metrics"]
        cells = [_fmt(m[k]) if k in m else "" for _, k in SCEN_COLS]
        rows.append(f"| {r['mode']} | {r['scenario']} | " + " | ".join(cells) + " |")
    return "\n".join(rows)


SSE_TARGET = 1e-3        # SPEC §6 hold accuracy, rad


def overshoot_floor_pct(jump: float, step: float) -> float:
    """Overshoot a single quasi-static breakaway cannot avoid: the valve, stuck at the start,
    slides at least one jump 2 (Ts - Tc)/K once it lets go (the heavy motor side cannot pull
    it back within the ~6 ms the jump lasts)."""
    return max(0.0, (jump - step) / step * 100.0)


def robustness_table(results: list[dict]) -> str:
    by = {}
    for r in results:
        by.setdefault((r["mode"], r["corner_name"]), {})[r["scenario"]] = r
    head = ("| mode | corner | jump 2(Ts−Tc)/K rad | step OS % | OS floor % | step settle s | hold LC amp rad | "
            "hold p-p / allowance | hold LC Hz | hold sse rad | peak A | verdict |")
    rows = [head, "|" + "---|" * 12]
    for (mode, name), d in by.items():
        st, ho = d.get("step_small"), d.get("hold")
        if st is None or ho is None:
            continue
        os_ = st["metrics"].get("overshoot_pct")
        step = abs(st["step_rad"])
        peak = max(st["metrics"]["peak_current_a"], ho["metrics"]["peak_current_a"])
        amp = ho["metrics"].get("limit_cycle_amplitude_rad", 0.0)
        allowance = ho["hunting_allowance_rad"]
        ratio = 2.0 * amp / allowance
        # bounded: drive still on (no fault latched) and the current within the rating
        bounded = ho["enabled_at_end"] and st["enabled_at_end"] and peak <= 37.0
        on_target = ho["final_error_rad"] <= max(SSE_TARGET, allowance)
        verdict = ["bounded" if bounded else "FAULT/UNBOUNDED", "no hunting" if ratio <= 1.0 else "HUNTS",
                   "OS ok" if os_ is not None and os_ <= 10.0 else "OS > 10 %"]
        if not on_target:
            verdict.append(f"stuck {ho['final_error_rad']:.2g} rad off")
        rows.append(f"| {mode} | {name} | {_fmt(ho['jump_rad'])} | {_fmt(os_)} | "
                    f"{_fmt(overshoot_floor_pct(ho['jump_rad'], step))} | "
                    f"{_fmt(st['metrics'].get('settling_time_s'))} | {_fmt(amp)} | {ratio:.2f} | "
                    f"{_fmt(ho['metrics'].get('limit_cycle_frequency_hz'))} | "
                    f"{_fmt(ho['metrics'].get('steady_state_error_rad'))} | "
                    f"{_fmt(peak)} | {', '.join(verdict)} |")
    return "\n".join(rows)


def run_jobs(fn, jobs: list, workers: int) -> list:
    """``[fn(j) for j in jobs]``, over a process pool of ``workers`` when more than one."""
    if workers > 1:
        with Pool(workers) as pool:
            return pool.map(fn, jobs, chunksize=1)
    return [fn(j) for j in jobs]


def emit_json(doc: dict, path: str | None) -> None:
    """Print ``doc`` as the benchmark's last line (and write it to ``path`` when given)."""
    doc = metrics.jsonable(doc)
    if path:
        Path(path).write_text(json.dumps(doc, indent=1) + "\n")
    print(json.dumps(doc))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="worker processes (default: CPUs)")
    ap.add_argument("--quick", action="store_true", help="shorter long scenarios, single-parameter corners only")
    ap.add_argument("--modes", default=",".join(MODES), help="comma-separated modes (default: all)")
    ap.add_argument("--scenarios", default=None, help="comma-separated scenarios (default: all built-in)")
    ap.add_argument("--no-robustness", action="store_true", help="skip the robustness box")
    ap.add_argument("--json", metavar="PATH", help="also write the JSON here")
    ap.add_argument("--markdown", metavar="PATH", help="also write the tables as markdown here")
    args = ap.parse_args(argv)
    modes = [m for m in args.modes.split(",") if m]
    bad = [m for m in modes if m not in MODES]
    scenarios = args.scenarios.split(",") if args.scenarios else builtin_names()
    bad += [s for s in scenarios if s not in builtin_names()]
    if bad:
        print(f"control_quality: unknown mode/scenario {', '.join(bad)}", file=sys.stderr)
        return 2
    jobs = [("scenario", m, s, QUICK_DURATION_S.get(s) if args.quick else None, None)
            for m in modes for s in scenarios]
    if not args.no_robustness:
        hold = QUICK_DURATION_S["hold"] if args.quick else None
        jobs += [("robustness", m, s, d, c) for m in ROBUST_MODES for c in corners(full=not args.quick)
                 for s, d in (("step_small", None), ("hold", hold))]
    start = time.perf_counter()
    results = run_jobs(_run, jobs, args.jobs)
    wall = time.perf_counter() - start
    scen = [r for r in results if r["kind"] == "scenario"]
    rob = [r for r in results if r["kind"] == "robustness"]
    command = "python benchmarks/control_quality.py " + " ".join(argv if argv is not None else sys.argv[1:])
    text = [f"## Scenarios (nominal plant)\n\n{scenario_table(scen)}"]
    if rob:
        text.append("## Robustness box (same gains; step_small and hold)\n\n" + robustness_table(rob))
    text.append(f"_{len(results)} runs in {wall:.1f} s wall with {args.jobs} job(s): `{command.strip()}`_")
    md = "\n\n".join(text)
    print(md)
    if args.markdown:
        Path(args.markdown).write_text(md + "\n")
    emit_json({"command": command.strip(), "wall_time_s": round(wall, 2), "jobs": args.jobs, "quick": args.quick,
               "scenarios": scen, "robustness": rob}, args.json)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
