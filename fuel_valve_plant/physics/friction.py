"""Friction levels of the simulated plant as functions of its operating point (SPEC §2).

The schedule itself (levels vs Δp) is :class:`fuel_valve_control.common.friction.FrictionCoefficients`,
shared with the controller's nominal model; this module reads the plant's parameter set into it.
"""
from __future__ import annotations

from fuel_valve_control.common.friction import FrictionCoefficients, FrictionLevels, pressure_fraction

__all__ = ["FrictionLevels", "coefficients", "friction_levels", "flow_torque_peak_nm"]


def coefficients(ps) -> FrictionCoefficients:
    """The plant's friction coefficients (``friction.*``) as the shared schedule."""
    return FrictionCoefficients(
        ps["friction.motor.coulomb_nm"], ps["friction.motor.static_nm"],
        ps["friction.valve.coulomb_nm"], ps["friction.valve.coulomb_per_dp_nm"],
        ps["friction.valve.static_nm"], ps["friction.valve.static_per_dp_nm"],
        ps["friction.pressure_max_kpa"])


def friction_levels(ps, pressure_kpa: float | None = None, scale: float | None = None) -> FrictionLevels:
    """Friction levels for parameter set ``ps`` at ``pressure_kpa`` (default: ps's own)."""
    dp = ps["pressure_differential_kpa"] if pressure_kpa is None else pressure_kpa
    k = ps["friction_scale"] if scale is None else scale
    return coefficients(ps).levels(dp, k)


def flow_torque_peak_nm(ps, pressure_kpa: float | None = None) -> float:
    """Peak flow torque (toward closed) at the given pressure: scales linearly with Δp."""
    dp = ps["pressure_differential_kpa"] if pressure_kpa is None else pressure_kpa
    return ps["flow.torque_max_nm"] * pressure_fraction(dp, ps["friction.pressure_max_kpa"])
