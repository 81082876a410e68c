"""Data-sheet experiments on the plant (open loop): torque ratings, stroke and closing times.

These are the measurements the actuator data sheet quotes (dissertation table 2-3): 24.86 N*m
continuous at 15 A, 62.38 N*m peak at 37 A, 125 ms to open and 120 ms to close (spring) at
28 V.  The tests assert them and ``python -m fuel_valve_plant.tools.datasheet`` prints them.
"""
from __future__ import annotations

import argparse
import json

from fuel_valve_control.common.paramspec import ParamSet
from ..physics.plant import Plant
from ..physics.params import load_plant_params

RATED_CONTINUOUS = (15.0, 24.86)   # A, N*m at the valve
RATED_PEAK = (37.0, 62.38)
OPEN_TIME_LIMIT_S = 0.125
CLOSE_TIME_LIMIT_S = 0.120


def stall_torque(ps: ParamSet, current_a: float, ramp_s: float = 0.2, settle_s: float = 0.3) -> tuple[float, float]:
    """(electromagnetic torque x N, coupling torque) in N*m with the valve on its open stop.

    The valve starts on the open stop and the motor current ramps to ``current_a`` (a step
    would ring the lightly damped coupling); after ``settle_s`` the coupling torque equals the
    output torque less the motor's friction reaction.
    """
    stroke = ps["valve.stroke_rad"]
    plant = Plant(ps.replace({"initial_position_rad": stroke}))
    steps = max(int(ramp_s / 1e-3), 1)
    for k in range(steps):
        plant.set_command(current_a * (k + 1) / steps, True)
        plant.advance(1e-3)
    plant.advance(settle_s)
    # the lightly damped coupling still rings: average over whole samples of 0.2 s
    te = tk = 0.0
    for _ in range(200):
        plant.advance(1e-3)
        truth = plant.truth()
        te += truth.electromagnetic_torque / 200
        tk += truth.coupling_torque / 200
    return te * ps["gearbox.ratio"], tk


def stroke_time(ps: ParamSet, current_a: float = 37.0, fraction: float = 0.98, limit_s: float = 0.5) -> float:
    """Time from rest on the closed stop to ``fraction`` of the stroke with ``current_a`` commanded."""
    plant = Plant(ps.replace({"initial_position_rad": 0.0}))
    plant.set_command(current_a, True)
    target = fraction * ps["valve.stroke_rad"]
    while plant.time < limit_s:
        plant.step(1)
        if plant.valve_angle >= target:
            return plant.time
    return float("inf")


def spring_close_time(ps: ParamSet, fraction: float = 0.02, limit_s: float = 0.5) -> float:
    """Time for the return spring to close the valve from full open to ``fraction`` open, drive off."""
    plant = Plant(ps.replace({"initial_position_rad": ps["valve.stroke_rad"]}))
    plant.set_command(0.0, False)
    target = fraction * ps["valve.stroke_rad"]
    while plant.time < limit_s:
        plant.step(1)
        if plant.valve_angle <= target:
            return plant.time
    return float("inf")


def report(ps: ParamSet) -> dict:
    """All data-sheet figures for parameter set ``ps``."""
    pmax = ps.spec.params["pressure_differential_kpa"].high
    out = {
        "torque_at_15a_nm": stall_torque(ps, RATED_CONTINUOUS[0])[0],
        "torque_at_37a_nm": stall_torque(ps, RATED_PEAK[0])[0],
        "stroke_time_s": stroke_time(ps),
    }
    for label, dp in (("0", 0.0), ("mid", 0.5 * pmax), ("max", pmax)):
        out[f"spring_close_time_s_dp_{label}"] = spring_close_time(ps.replace({"pressure_differential_kpa": dp}))
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="Print the plant's data-sheet figures (open loop).")
    parser.add_argument("--params", default="default", help="plant parameter file (ROS 2 format)")
    args = parser.parse_args(argv)
    ps = load_plant_params(args.params)
    figures = report(ps)
    limits = {
        "torque_at_15a_nm": f"rated {RATED_CONTINUOUS[1]} continuous",
        "torque_at_37a_nm": f"rated {RATED_PEAK[1]} peak",
        "stroke_time_s": f"<= {OPEN_TIME_LIMIT_S}",
    }
    for key, value in figures.items():
        print(f"{key:32s} {value:9.4f}   {limits.get(key, f'<= {CLOSE_TIME_LIMIT_S}')}")
    print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
