"""Voltage relations of the PMS motor drive, shared by the plant (which integrates them) and
the controller's trajectory design (which plans within them).

Amplitude-invariant Park transform (dissertation eq. 2-29): the torque constant is
``Kt = 1.5 p ψf`` (N*m per q-axis ampere with id = 0) and an SVPWM inverter's voltage limit is a
circle of radius ``Vdc / sqrt(3)`` in the dq plane.  Steady state with id = 0 at electrical
speed ``ωe = p ωm``: ``vq = R iq + ωe ψf`` (back-EMF), ``vd = -ωe Lq iq`` (cross-coupling).
"""
from __future__ import annotations

import math

SQRT3 = math.sqrt(3.0)


def voltage_limit(supply_voltage_v: float) -> float:
    """Largest dq voltage amplitude an SVPWM inverter produces from the DC bus, V."""
    return supply_voltage_v / SQRT3


def steady_voltage(motor_speed_rad_s: float, current_q_a: float, resistance_ohm: float, lq_h: float,
                   pole_pairs: float, torque_constant_nm_per_a: float) -> float:
    """dq voltage amplitude (V) the drive needs to hold ``current_q_a`` (A, id = 0) at
    ``motor_speed_rad_s`` (mechanical, rad/s; positive with the current = motoring): the
    resistive drop plus the back-EMF ``ωe ψf`` (ψf from ``Kt / (1.5 p)``) on the q axis, the
    cross-coupling ``ωe Lq iq`` on the d axis."""
    we = pole_pairs * motor_speed_rad_s
    psi = torque_constant_nm_per_a / (1.5 * pole_pairs)
    return math.hypot(resistance_ohm * current_q_a + we * psi, we * lq_h * current_q_a)
