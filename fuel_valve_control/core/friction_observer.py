"""Friedland–Park adaptive Coulomb-friction observer for one shaft (Friedland & Park 1992).

For a shaft with velocity v, non-friction acceleration w (all torques except friction divided
by the inertia) and friction ``F = a sgn(v)`` (a in rad/s², friction per unit inertia)::

    â = z - α |v|^β
    ż = α β |v|^(β-1) (w - â sgn v) sgn v          estimated friction F̂ = â sgn v

The estimation error e = a - â then obeys ė = -α β |v|^(β-1) e: it decays while |v| stays away
from zero.  Practicalities (SPEC §6) for use with *estimated* velocities in a 1 kHz loop:

* the adaptation gain ``α β |v|^(β-1)`` is capped (``gain_cap``, 1/s) so the explicit update
  stays stable (``T * gain_cap < 1``) at motor-shaft speeds, where it would explode for β >= 2;
* below ``freeze_velocity`` the estimate is frozen: at rest the friction is a reaction, not
  Coulomb friction, and the velocity sign is noise;
* the compensation uses a smooth sign ``sat(v / boundary)`` (boundary layer; default the
  freeze velocity), never the raw sign of a noisy velocity estimate, so it fades to zero at
  rest instead of chattering.
"""
from __future__ import annotations

import math


class FrictionObserver:
    def __init__(self, alpha: float, beta: float, gain_cap: float, freeze_velocity: float, period_s: float,
                 initial_level: float = 0.0, max_level: float = math.inf, boundary_velocity: float | None = None):
        if period_s * gain_cap >= 1.0:
            raise ValueError(f"gain_cap {gain_cap:g} 1/s too large for a {period_s:g} s update (needs T*cap < 1)")
        self.alpha = alpha
        self.beta = beta
        self.gain_cap = gain_cap
        self.freeze_velocity = freeze_velocity
        self.boundary_velocity = freeze_velocity if boundary_velocity is None else boundary_velocity
        self.period = period_s
        self.max_level = max_level
        self.level = initial_level          # â, rad/s² (friction / inertia)
        self._z = None

    def reset(self, level: float) -> None:
        self.level = min(max(level, 0.0), self.max_level)
        self._z = None

    def gain(self, speed: float) -> float:
        """Capped adaptation gain α β |v|^(β-1), 1/s."""
        if speed <= 0.0:
            return 0.0 if self.beta >= 1.0 else self.gain_cap
        return min(self.alpha * self.beta * speed ** (self.beta - 1.0), self.gain_cap)

    def update(self, velocity: float, accel_non_friction: float) -> float:
        """One period with velocity estimate ``v`` and non-friction acceleration ``w``; returns â."""
        speed = abs(velocity)
        if speed < self.freeze_velocity:
            self._z = None                  # frozen: re-seed z from â when motion resumes
            return self.level
        sgn = 1.0 if velocity > 0.0 else -1.0
        shape = self.alpha * speed ** self.beta
        if self._z is None:
            self._z = self.level + shape
        level = self._z - shape
        z = self._z + self.period * self.gain(speed) * (accel_non_friction - level * sgn) * sgn
        self.level = min(max(z - shape, 0.0), self.max_level)   # friction is never negative
        self._z = self.level + shape
        return self.level

    def compensation(self, velocity: float) -> float:
        """Estimated friction per unit inertia with a smooth sign (fades to 0 at rest)."""
        if self.boundary_velocity <= 0.0:
            return self.level * (1.0 if velocity > 0 else -1.0 if velocity < 0 else 0.0)
        return self.level * min(max(velocity / self.boundary_velocity, -1.0), 1.0)
