"""PMS motor relations (dissertation eqs 2-21…2-30) used by the plant and by controller design.

Amplitude-invariant Park transform (eq. 2-29): dq quantities equal phase amplitudes, so the
electrical power is ``1.5 (vd id + vq iq)``, the torque ``1.5 p (ψf + (Ld - Lq) id) iq`` and the
SVPWM voltage limit is a circle of radius ``Vdc / sqrt(3)`` in the dq plane.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from fuel_valve_control.common.drive import voltage_limit  # noqa: F401  (one relation, shared with the controller)


@dataclass(frozen=True)
class MotorConstants:
    pole_pairs: int
    resistance_ohm: float
    ld_h: float
    lq_h: float
    flux_linkage_wb: float

    @classmethod
    def from_params(cls, ps) -> "MotorConstants":
        return cls(ps["motor.pole_pairs"], ps["motor.resistance_ohm"], ps["motor.ld_h"], ps["motor.lq_h"],
                   ps["motor.flux_linkage_wb"])

    @property
    def torque_constant(self) -> float:
        """N*m per ampere of q current with id = 0: ``1.5 p ψf``."""
        return 1.5 * self.pole_pairs * self.flux_linkage_wb

    def torque(self, i_d: float, i_q: float) -> float:
        """Electromagnetic torque, N*m (eq. 2-28)."""
        return 1.5 * self.pole_pairs * (self.flux_linkage_wb + (self.ld_h - self.lq_h) * i_d) * i_q


def current_pi_gains(inductance_h: float, resistance_ohm: float, bandwidth_hz: float) -> tuple[float, float]:
    """(Kp [V/A], Ki [V/(A*s)]) of a dq current PI that cancels the R-L pole.

    With decoupling the axis is ``L di/dt = v - R i``; ``Kp = L ωc`` and ``Ki = R ωc`` give the
    first-order closed loop ``ωc / (s + ωc)``.
    """
    wc = 2.0 * math.pi * bandwidth_hz
    return inductance_h * wc, resistance_ohm * wc


def dq_to_abc(i_d: float, i_q: float, theta_e: float) -> tuple[float, float, float]:
    """Inverse Park transform (eq. 2-30), amplitude invariant."""
    out = []
    for shift in (0.0, -2.0 * math.pi / 3.0, 2.0 * math.pi / 3.0):
        angle = theta_e + shift
        out.append(i_d * math.cos(angle) - i_q * math.sin(angle))
    return out[0], out[1], out[2]


def abc_to_dq(i_a: float, i_b: float, i_c: float, theta_e: float) -> tuple[float, float]:
    """Park transform (eq. 2-29), amplitude invariant."""
    shifts = (0.0, -2.0 * math.pi / 3.0, 2.0 * math.pi / 3.0)
    phases = (i_a, i_b, i_c)
    i_d = 2.0 / 3.0 * sum(x * math.cos(theta_e + s) for x, s in zip(phases, shifts))
    i_q = -2.0 / 3.0 * sum(x * math.sin(theta_e + s) for x, s in zip(phases, shifts))
    return i_d, i_q
