"""The existing analog driver as a control law (modes ``pi``, ``pi_dither``)."""
from __future__ import annotations

import math

from ..design import PIDGains
from ..model import NominalModel
from ..signals import Estimate, Measurement
from .base import ControlLaw


class PIDLaw(ControlLaw):
    """The existing analog driver: series PI(D) on the valve resolver, linear tuning.

    ``C(s) = kp (1 + wi/s) (1 + s/wz)/(1 + s/wp)``: the lead part is discretised with Tustin,
    the integral is conditional (frozen while the current is limited).  ``dither`` adds the
    field workaround: a sine of ``dither_amplitude`` rad at ``dither_hz`` on the demand.
    """

    def __init__(self, gains: PIDGains, model: NominalModel, period_s: float,
                 dither_amplitude: float = 0.0, dither_hz: float = 25.0):
        self.name = "pi_dither" if dither_amplitude > 0 else "pi"
        self.g = gains
        self.model = model
        self.period = period_s
        self.dither_amplitude = dither_amplitude
        self.dither_hz = dither_hz
        # Tustin of (1 + s/wz)/(1 + s/wp): y[k] = b0 e[k] + b1 e[k-1] - a1 y[k-1]
        k = 2.0 / period_s
        den = 1.0 + k / gains.wp
        self._b0 = (1.0 + k / gains.wz) / den
        self._b1 = (1.0 - k / gains.wz) / den
        self._a1 = (1.0 - k / gains.wp) / den
        self._e1 = 0.0
        self._y1 = 0.0
        self._integral = 0.0
        self._pending = 0.0
        self._last_valve = None
        self._valve_velocity = 0.0
        self._motor_last = None
        self._motor_velocity = 0.0
        self._meas = Measurement(0.0, 0.0)

    def reset(self, meas, torque_nm, pressure_kpa):
        self._e1 = self._y1 = 0.0
        self._integral = torque_nm / (self.g.kp * self.g.wi)
        self._last_valve = meas.valve_rad
        self._motor_last = meas.motor_rad
        self._valve_velocity = self._motor_velocity = 0.0
        self._meas = meas

    def update(self, t, demand_rad, meas, pressure_kpa):
        if self._last_valve is not None:
            self._valve_velocity = (meas.valve_rad - self._last_valve) / self.period
            self._motor_velocity = (meas.motor_rad - self._motor_last) / self.period
        self._last_valve, self._motor_last, self._meas = meas.valve_rad, meas.motor_rad, meas
        r = demand_rad
        if self.dither_amplitude > 0.0:
            r += self.dither_amplitude * math.sin(2.0 * math.pi * self.dither_hz * t)
        e = r - meas.valve_rad
        y = self._b0 * e + self._b1 * self._e1 - self._a1 * self._y1
        self._e1, self._y1 = e, y
        self._pending = self.period * y
        return self.g.kp * (y + self.g.wi * self._integral)

    def applied(self, torque_nm, saturated):
        if not saturated:
            self._integral += self._pending

    def estimate(self):
        return Estimate(self._meas.motor_rad, self._motor_velocity, self._meas.valve_rad, self._valve_velocity)

