"""Friction levels of both shafts as functions of the operating point (SPEC §2).

These are the *magnitudes* the plant integrates and the nominal values a controller may use
for design (deadbands, feed-forward).  Valve friction grows linearly with the pressure
differential; ``friction_scale`` multiplies every level.
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class FrictionLevels:
    """Static and Coulomb friction of both shafts, N*m (motor side in motor units)."""

    motor_coulomb_nm: float
    motor_static_nm: float
    valve_coulomb_nm: float
    valve_static_nm: float

    def stick_slip_jump_rad(self, coupling_stiffness: float) -> float:
        """Peak-to-peak valve jump of one breakaway against the coupling, ``2 (Ts - Tc) / K``.

        The valve sticks until the coupling torque reaches Ts; friction then drops to Tc and the
        light valve swings about the new equilibrium with amplitude (Ts - Tc)/K, stopping again
        after half a period, 2 (Ts - Tc) / K further on (the coupling is very lightly damped).
        """
        return 2.0 * (self.valve_static_nm - self.valve_coulomb_nm) / coupling_stiffness


def friction_levels(ps, pressure_kpa: float | None = None, scale: float | None = None) -> FrictionLevels:
    """Friction levels for parameter set ``ps`` at ``pressure_kpa`` (default: ps's own)."""
    dp = ps["pressure_differential_kpa"] if pressure_kpa is None else pressure_kpa
    k = ps["friction_scale"] if scale is None else scale
    frac = min(max(dp / ps["friction.pressure_max_kpa"], 0.0), 1.0)
    return FrictionLevels(
        motor_coulomb_nm=k * ps["friction.motor.coulomb_nm"],
        motor_static_nm=k * ps["friction.motor.static_nm"],
        valve_coulomb_nm=k * (ps["friction.valve.coulomb_nm"] + ps["friction.valve.coulomb_per_dp_nm"] * frac),
        valve_static_nm=k * (ps["friction.valve.static_nm"] + ps["friction.valve.static_per_dp_nm"] * frac),
    )


def flow_torque_peak_nm(ps, pressure_kpa: float | None = None) -> float:
    """Peak flow torque (toward closed) at the given pressure: scales linearly with Δp."""
    dp = ps["pressure_differential_kpa"] if pressure_kpa is None else pressure_kpa
    return ps["flow.torque_max_nm"] * min(max(dp / ps["friction.pressure_max_kpa"], 0.0), 1.0)
