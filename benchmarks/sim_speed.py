#!/usr/bin/env python3
"""How much CPU does the offline closed loop take?  Per control period and per driver built.

Runs ``fuel_valve_sim``'s loop (:func:`fuel_valve_control.tools.sim.simulate`: driver step,
plant integration and the run's log, one period of simulated time per row) for a scenario
and mode, ``--repeat`` times after one warm-up run (numba kernel compiled or loaded,
caches filled), and builds ``--builds`` drivers from the same parameters.  Figures are
process CPU seconds (``time.process_time``; on a machine shared with other work wall time
says more about the neighbours), the best of the repeats:

* ``period_cpu_us``: CPU per simulated control period (1 ms), µs;
* ``driver_build_cpu_ms``: CPU per :class:`~fuel_valve_control.core.driver.ValveDriver` built
  from the scenario's parameter set (the gains' design), ms;
* ``build_cpu_ms``: CPU per ``sim.build`` (the run plan: parameter files and scenario read), ms.

    python benchmarks/sim_speed.py [--scenario startup] [--mode observer_fp] [--repeat 3] [--builds 20]

To compare two versions, run it in both checkouts back to back (same machine state), e.g.
``PYTHONPATH=/path/to/old/checkout python benchmarks/sim_speed.py`` from that checkout.
The last line printed is one JSON object.
"""
from __future__ import annotations

import argparse
import json
import time


def measure(scenario: str, mode: str | None, repeat: int, builds: int) -> dict:
    from fuel_valve_control.core.driver import ValveDriver
    from fuel_valve_control.tools.scenarios import load_scenario
    from fuel_valve_control.tools.sim import build, simulate

    sc = load_scenario(scenario)
    simulate(sc, *build(sc, seed=0, mode=mode))           # warm-up: kernel, caches
    best_run, periods = float("inf"), 0
    for _ in range(repeat):
        plant_ps, controller_ps = build(sc, seed=0, mode=mode)
        start = time.process_time()
        result = simulate(sc, plant_ps, controller_ps)
        best_run = min(best_run, time.process_time() - start)
        periods = len(result.log)
    start = time.process_time()
    for _ in range(builds):
        plant_ps, controller_ps = build(sc, seed=0, mode=mode)
    build_s = (time.process_time() - start) / builds
    start = time.process_time()
    for _ in range(builds):
        ValveDriver(controller_ps)
    driver_s = (time.process_time() - start) / builds
    return {"scenario": scenario, "mode": controller_ps["mode"], "periods": periods,
            "run_cpu_s": round(best_run, 4), "period_cpu_us": round(best_run / periods * 1e6, 2),
            "driver_build_cpu_ms": round(driver_s * 1e3, 3), "build_cpu_ms": round(build_s * 1e3, 3)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="startup")
    parser.add_argument("--mode", default=None, help="control mode (default: the configured default)")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--builds", type=int, default=20)
    args = parser.parse_args()
    r = measure(args.scenario, args.mode, max(args.repeat, 1), max(args.builds, 1))
    print(f"{r['scenario']} / {r['mode']}: {r['periods']} periods in {r['run_cpu_s']:.3f} s CPU "
          f"({r['period_cpu_us']:.1f} us per period); driver build {r['driver_build_cpu_ms']:.2f} ms, "
          f"sim.build {r['build_cpu_ms']:.2f} ms CPU")
    print(json.dumps(r))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
