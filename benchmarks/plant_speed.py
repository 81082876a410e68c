#!/usr/bin/env python3
"""How fast does the plant integrate?  Steps it for 10 simulated seconds at 20 kHz physics.

The current command changes every 1 ms like a position controller's would: a slow
square-wave stroke demand (±15 A bursts), a 3 Hz sine and a small dither, so the valve
travels, sticks, slips and hits its stops during the run.  The last line printed is a JSON
object with ``real_time_factor`` (simulated seconds per wall second) and ``physics_rate_hz``.

    python benchmarks/plant_speed.py [--seconds 10] [--rate 20000] [--no-jit]

``--no-jit`` re-runs the measurement in a child process with the numba kernel disabled,
to show what the compiled kernel buys.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time


def measure(seconds: float, rate_hz: float, period_s: float = 1e-3) -> dict:
    from fuel_valve_plant.physics import kernel
    from fuel_valve_plant.physics.plant import Plant
    from fuel_valve_plant.physics.params import load_plant_params

    plant = Plant(load_plant_params(overrides={"physics_rate_hz": rate_hz}))
    plant.set_command(0.0, True)
    plant.advance(period_s)                         # compile / warm up outside the timing
    plant = Plant(load_plant_params(overrides={"physics_rate_hz": rate_hz}))
    periods = int(round(seconds / period_s))
    start = time.perf_counter()
    for k in range(periods):
        t = k * period_s
        burst = 15.0 if (t % 1.0) < 0.25 else (-4.0 if (t % 1.0) < 0.5 else 6.0)
        iq = burst + 3.0 * math.sin(2 * math.pi * 3.0 * t) + 0.5 * math.sin(2 * math.pi * 25.0 * t)
        plant.set_command(iq, True)
        plant.advance(period_s)
        plant.resolver()
    wall = time.perf_counter() - start
    return {
        "simulated_s": seconds,
        "wall_s": round(wall, 4),
        "real_time_factor": round(seconds / wall, 2),
        "physics_rate_hz": rate_hz,
        "physics_steps_per_s": round(seconds * rate_hz / wall),
        "compiled_kernel": bool(kernel.JIT),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--rate", type=float, default=20000.0, help="physics rate, Hz")
    parser.add_argument("--no-jit", action="store_true", help="also measure the interpreted kernel")
    args = parser.parse_args()
    result = measure(args.seconds, args.rate)
    if args.no_jit:
        env = dict(os.environ, FUEL_VALVE_NO_JIT="1")
        child = subprocess.run([sys.executable, __file__, "--seconds", str(min(args.seconds, 2.0)),
                                "--rate", str(args.rate)], env=env, capture_output=True, text=True, check=True)
        interpreted = json.loads(child.stdout.strip().splitlines()[-1])
        result["interpreted_real_time_factor"] = interpreted["real_time_factor"]
    print(f"plant: {result['simulated_s']:g} s simulated at {result['physics_rate_hz']:g} Hz physics in "
          f"{result['wall_s']:.3f} s wall -> {result['real_time_factor']:.1f}x real time "
          f"({'numba' if result['compiled_kernel'] else 'interpreted'} kernel)")
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
