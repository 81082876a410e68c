"""Seating: demands at a stop drive the valve onto the stop and hold it there (SPEC §3)."""
from __future__ import annotations

import math
from dataclasses import dataclass

from .model import NominalModel
from .trajectory import TrajectoryShaper


@dataclass(frozen=True)
class Seating:
    """Demands within ``margin`` of a stop mean "on the stop": the reference is aimed
    ``overtravel`` beyond it so the valve arrives at speed, and once it rests there the loop
    holds it with the known load plus ``torque`` (valve side) instead of fighting the stop
    with an integrator that could only wind up.

    ``damping_nms`` (N*m*s/rad at the gear output) and ``settle_periods``: for that many loop
    periods after the valve has *arrived* on a stop (seated after an unseated period) the
    seated torque also damps the motor's swing against the blocked valve,
    ``-damping_nms * ω1 / N`` (motor N*m; ω1 the gear output's estimated speed, rad/s, + toward
    open: the stop holds the valve still, so it is the coupling's twist rate).  Why: the approach aims ``overtravel`` beyond the
    stop, so the drive arrives with the coupling wound well past the seated twist (nominal
    6.4e-2 rad, 31 N*m, where the seat holds with 3.2e-2; 80:1 gear 8.3e-2 with 3.2e-2).  A
    constant seated torque leaves that excess to swing the motor, undamped, through the
    seated twist to about as far below it: below ``(load - T_s) / K`` the valve leaves the stop
    (nominal once, 1.3e-2 rad; on an 80:1 gear, whose reflected motor inertia ``Jm N^2`` is 2.8x
    the nominal, every re-seat, 2.5e-2 rad bounces every ~55 ms: docs/control_results.md §39).
    0 / 0: the constant seated torque alone (before §39)."""

    margin: float
    overtravel: float
    torque_nm: float
    stroke: float
    damping_nms: float = 0.0
    settle_periods: int = 0

    @staticmethod
    def swing_design(model: NominalModel, damping_ratio: float, period_s: float) -> tuple[float, int]:
        """(damping N*m*s/rad at the gear output, periods to apply it) that give the motor's
        swing against a blocked valve -- reflected inertia ``j1 = Jm N^2`` on the coupling
        stiffness ``K``, ``ω_b = sqrt(K / j1)`` -- the damping ratio ``damping_ratio``:
        ``c = 2 ζ sqrt(K j1)``, applied for twice the swing's 2 % settling time ``4 / (ζ ω_b)``
        (twice: a model off in ``K`` or ``Jm`` settles later).  ``damping_ratio`` 0: (0, 0)."""
        if damping_ratio <= 0.0:
            return 0.0, 0
        k, j1 = model.coupling_stiffness_nm_per_rad, model.j1
        c = 2.0 * damping_ratio * math.sqrt(k * j1)
        settle = 2.0 * 4.0 / (damping_ratio * math.sqrt(k / j1))
        return c, max(int(math.ceil(settle / period_s)), 1)

    def target(self, demand: float) -> tuple[float, int]:
        if demand >= self.stroke - self.margin:
            return self.stroke + self.overtravel, 1
        if demand <= self.margin:
            return -self.overtravel, -1
        return demand, 0

    def seated(self, shaper: TrajectoryShaper, target: float, valve: float) -> bool:
        stop = self.stroke if target > self.stroke else 0.0
        arrived = shaper.arrived(target) or shaper.at(stop)
        return arrived and abs(valve - stop) <= self.margin

    def torque(self, model: NominalModel, stop: float, side: int, pressure_kpa: float,
               swing_rad_s: float = 0.0) -> float:
        """Seated motor torque (N*m): the known load at ``stop`` plus ``torque_nm`` toward
        ``side`` (valve side, never below 0: the drive does not pull a closed valve open), less
        ``damping_nms * swing_rad_s`` (the gear output's speed ω1, rad/s; pass 0 outside the settle
        window), all over the gear ratio."""
        load = model.load_torque(stop, pressure_kpa)
        return (max(load + side * self.torque_nm, 0.0) - self.damping_nms * swing_rad_s) / model.gear_ratio
