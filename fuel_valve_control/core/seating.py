"""Seating: demands at a stop drive the valve onto the stop and hold it there (SPEC §3)."""
from __future__ import annotations

from dataclasses import dataclass

from .model import NominalModel
from .trajectory import TrajectoryShaper


@dataclass(frozen=True)
class Seating:
    """Demands within ``margin`` of a stop mean "on the stop": the reference is aimed
    ``overtravel`` beyond it so the valve arrives at speed, and once it rests there the loop
    holds it with the known load plus ``torque`` (valve side) instead of fighting the stop
    with an integrator that could only wind up."""

    margin: float
    overtravel: float
    torque_nm: float
    stroke: float

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

    def torque(self, model: NominalModel, stop: float, side: int, pressure_kpa: float) -> float:
        load = model.load_torque(stop, pressure_kpa)
        return max(load + side * self.torque_nm, 0.0) / model.gear_ratio

