"""The signals a control law exchanges with its caller: a resolver sample in, an estimate out.

Conventions: angles rad (valve side unless named motor), velocities rad/s, torques N*m at the
motor shaft unless a name says valve; ``θ1 = θm / N``.
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Measurement:
    """One resolver sample: motor shaft angle (multi-turn, rad) and valve angle (rad)."""

    motor_rad: float
    valve_rad: float


@dataclass(frozen=True)
class Estimate:
    """What the law believes: angles/velocities of both shafts (motor side in motor units) and
    estimated friction torques (N*m, motor at the motor shaft, valve at the valve shaft)."""

    motor_angle: float
    motor_velocity: float
    valve_angle: float
    valve_velocity: float
    motor_friction_nm: float = 0.0
    valve_friction_nm: float = 0.0

