#!/usr/bin/env python3
"""Smallest move of the fine-positioning torque doublet on the bare plant (issue 14, task h14f).

The nominal plant at max Δp, held at rest at 0.5 rad, no friction scatter, true states: the
gear output is preloaded quasi-statically (a stiff PD servo on the true motor angle, the
coupling torque fed forward) to a fraction of the valve's static twist ``(load + f Ts)/K``, then
the doublet of ``fine_positioning`` -- one period of ``fine.kick_current_a`` on the hold current,
then ``fine.peak_current_a`` backwards for one period and half of it for the next -- then the
servo to the Coulomb equilibrium twist.  Prints the valve's move for each preload fraction
(0 = not broken loose): the smallest move at breakaway and how it grows with overdrive.
Last line: one JSON object.

    python benchmarks/fine_doublet.py [--kick A] [--fractions 0.95:1.0:0.0025]
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from fuel_valve_control.core.params import CONTROLLER_SPEC  # noqa: E402
from fuel_valve_plant.physics.params import PLANT_SPEC  # noqa: E402
from fuel_valve_plant.physics.plant import Plant  # noqa: E402

PS = PLANT_SPEC.defaults()
CS = CONTROLLER_SPEC.defaults()
PERIOD = 1.0 / CS["loop_rate_hz"]
N, K = PS["gearbox.ratio"], PS["coupling.stiffness_nm_per_rad"]
KT = 1.5 * PS["motor.pole_pairs"] * PS["motor.flux_linkage_wb"]
J1 = PS["motor.inertia_kgm2"] * N * N
TS = PS["friction.valve.static_nm"] + PS["friction.valve.static_per_dp_nm"]
TC = PS["friction.valve.coulomb_nm"] + PS["friction.valve.coulomb_per_dp_nm"]


def doublet_move(fraction: float, kick_a: float, cap_a: float, servo_hz: float = 60.0) -> tuple[float, float]:
    """(valve move rad, peak |iq| A) of one doublet from a preload of ``fraction`` x Ts."""
    pl = Plant(PS)
    pl.hold_at(0.5)
    tr = pl.truth()
    thl0 = tr.valve_angle
    phi0 = tr.motor_angle / N - thl0
    load = K * phi0
    w = 2.0 * math.pi * servo_hz
    kp, kd = J1 * w * w, 2.0 * 0.8 * w * J1
    peak = 0.0

    def servo(twist: float) -> float:
        t = pl.truth()
        return (K * twist + kp * (thl0 + twist - t.motor_angle / N) - kd * t.motor_velocity / N) / (N * KT)

    def run(iq: float) -> None:
        nonlocal peak
        pl.set_command(min(max(iq, -cap_a), cap_a), True)
        for _ in range(pl.steps_for(PERIOD)):
            pl.step(1)
            peak = max(peak, abs(pl.currents[1]))

    pre = (load + fraction * TS) / K
    n_park = 20
    for k in range(n_park + 10):
        u = min(k / n_park, 1.0)
        run(servo(phi0 + (pre - phi0) * 0.5 * (1.0 - math.cos(math.pi * u))))
    if abs(pl.valve_angle - thl0) > 1e-6:
        return float("nan"), peak                       # broke loose while preloading
    t = pl.truth()
    hold = K * (t.motor_angle / N - t.valve_angle) / (N * KT)
    for iq in (hold + kick_a, hold - cap_a, hold - 0.5 * cap_a):
        run(iq)
    for _ in range(60):
        run(servo((load + TC) / K))
    return pl.valve_angle - thl0, peak


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--kick", type=float, default=CS["fine.kick_current_a"], help="kick current, A")
    ap.add_argument("--cap", type=float, default=CS["fine.peak_current_a"], help="current cap, A")
    ap.add_argument("--fractions", default="0.95:1.0:0.0025", help="start:stop:step of the preload, x Ts")
    a = ap.parse_args(argv)
    lo, hi, st = (float(x) for x in a.fractions.split(":"))
    rows = []
    for f in np.arange(lo, hi + 0.5 * st, st):
        move, peak = doublet_move(float(f), a.kick, a.cap)
        rows.append({"preload_fraction": round(float(f), 6), "overdrive_twist_rad": None,
                     "move_rad": move, "peak_current_a": peak})
        print(f"preload {f:.4f} Ts  move {move * 1e3:7.3f} mrad  peak {peak:5.1f} A")
    moved = [r for r in rows if math.isfinite(r["move_rad"]) and r["move_rad"] > 1e-6]
    first = moved[0] if moved else None
    for r in rows:
        if first is not None:
            r["overdrive_twist_rad"] = (r["preload_fraction"] - first["preload_fraction"]) * TS / K
    slope = None
    if len(moved) >= 2:
        x = np.array([r["overdrive_twist_rad"] for r in moved])
        y = np.array([r["move_rad"] for r in moved])
        slope = float(np.polyfit(x, y, 1)[0])
        print(f"smallest move {first['move_rad'] * 1e3:.3f} mrad at preload {first['preload_fraction']:.4f} Ts; "
              f"move per twist overdrive {slope:.2f} rad/rad; peak {max(r['peak_current_a'] for r in moved):.1f} A")
    print(json.dumps({"kick_a": a.kick, "cap_a": a.cap, "smallest_move_rad": first and first["move_rad"],
                      "move_per_overdrive": slope, "rows": rows}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
