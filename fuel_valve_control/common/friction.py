"""The friction law shared by the plant and the controller's nominal model (SPEC §2).

One schedule, written once: valve friction grows linearly with the pressure differential,

    T(Δp) = (base + per_dp · clamp(Δp / Δp_max, 0, 1)) · scale          [N·m]

for both the static (breakaway) and the Coulomb level; motor-shaft friction does not depend
on Δp.  The plant integrates these levels; the controller designs deadbands and feed-forward
from its own nominal values of the same parameters.  Levels are magnitudes (N·m, motor side
at the motor shaft).
"""
from __future__ import annotations

from dataclasses import dataclass


def pressure_fraction(pressure_kpa: float, pressure_max_kpa: float) -> float:
    """Δp / Δp_max clamped to 0..1."""
    return min(max(pressure_kpa / pressure_max_kpa, 0.0), 1.0)


@dataclass(frozen=True)
class FrictionCoefficients:
    """Friction parameters of both shafts (N·m); valve levels at Δp = 0 plus the increment
    at full pressure (``*_per_dp``)."""

    motor_coulomb_nm: float
    motor_static_nm: float
    valve_coulomb_nm: float
    valve_coulomb_per_dp_nm: float
    valve_static_nm: float
    valve_static_per_dp_nm: float
    pressure_max_kpa: float

    def levels(self, pressure_kpa: float, scale: float = 1.0) -> "FrictionLevels":
        """Friction levels at ``pressure_kpa``, every level multiplied by ``scale``."""
        f = pressure_fraction(pressure_kpa, self.pressure_max_kpa)
        return FrictionLevels(
            motor_coulomb_nm=scale * self.motor_coulomb_nm,
            motor_static_nm=scale * self.motor_static_nm,
            valve_coulomb_nm=scale * (self.valve_coulomb_nm + self.valve_coulomb_per_dp_nm * f),
            valve_static_nm=scale * (self.valve_static_nm + self.valve_static_per_dp_nm * f),
        )


@dataclass(frozen=True)
class FrictionLevels:
    """Static and Coulomb friction of both shafts, N·m (motor side in motor units)."""

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
