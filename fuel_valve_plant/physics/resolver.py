"""Resolver-to-digital conversion: quantisation, noise and injected faults.

Both resolvers deliver ``2**bits`` counts per mechanical turn of their own shaft; the motor
resolver is read multi-turn (the converter counts turns), so on the valve angle it is
``gearbox.ratio`` times finer than the valve resolver.  Noise is added before quantisation
(it is converter noise), so a quiet input gives exact multiples of the count.

Faults act on the valve resolver, the position feedback a driver's fault logic watches:

* ``resolver_stuck``: the reading freezes at its value when the fault was injected;
* ``resolver_dropout``: no sample at all (the converter stops answering);
* ``resolver_noise_burst``: gaussian noise of ``fault_noise_burst_rad`` is added.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ResolverSample:
    """Measured angles (rad) taken at ``stamp_s`` (plant time of the sample, delay included)."""

    stamp_s: float
    motor_rad: float
    valve_rad: float


class Resolver:
    """A quantising, noisy resolver channel."""

    def __init__(self, bits: int, noise_counts: float, rng: np.random.Generator):
        self.lsb_rad = 2.0 * math.pi / (1 << bits)
        self.noise_counts = noise_counts
        self._rng = rng

    def quantise(self, angle_rad: float, extra_noise_rad: float = 0.0) -> float:
        """Angle seen through the converter: ``round((θ + noise) / lsb) * lsb``."""
        noise = self.noise_counts * self.lsb_rad
        if noise > 0.0 or extra_noise_rad > 0.0:
            angle_rad += float(self._rng.normal(0.0, math.hypot(noise, extra_noise_rad)))
        return math.floor(angle_rad / self.lsb_rad + 0.5) * self.lsb_rad


class ValveResolverFaults:
    """Applies the injected fault mode to valve-resolver readings."""

    def __init__(self):
        self.mode = "none"
        self._frozen: float | None = None

    def set_mode(self, mode: str) -> None:
        if mode != self.mode:
            self._frozen = None
        self.mode = mode

    def apply(self, reading: float) -> float | None:
        if self.mode == "resolver_dropout":
            return None
        if self.mode == "resolver_stuck":
            if self._frozen is None:
                self._frozen = reading
            return self._frozen
        return reading
