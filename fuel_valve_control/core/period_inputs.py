"""One loop period's exchange with the driver, written once for the offline simulator and the
lockstep controller node.

A period hands the driver, all at the period's time ``t`` (s): the demand(s), the Δp
reading(s) that came with the period, then the resolver sample (stamped ``t``), then runs
:meth:`~.driver.ValveDriver.step`.  The offline simulator collects a period's inputs from the
plant and runs it at ``k * period``; the lockstep node collects them from its subscriptions as
they arrive (in any order: the demand node answers the plant's ``/clock`` tick, the plant
publishes the tick's Δp before its resolver sample) and runs the period when the resolver
sample and a fresh demand are both in, at the sample's stamp read by
:func:`~..common.timebase.stamp_seconds` -- the same floats in the same order, so the two runs
are identical.  (Timed on arrival, a lockstep demand was taken at the time of the period
answered *before* it, one period early: the demand filter's noise estimate differed in the
last bit from the simulator's, and from t = 6.018 s of the start-up profile the commands
differed, the valve by 6.3e-6 rad at 8.013 s and 3.1e-3 rad later.)

The real-time node hands its inputs to the driver when they arrive, at the node clock.
"""
from __future__ import annotations

from .driver import DriverOutput, ValveDriver


class PeriodInputs:
    """The inputs collected for the next period (demand in percent or mA, Δp in kPa), handed
    to the driver by :meth:`run` at that period's time."""

    def __init__(self):
        self._demands: list[tuple[str, float]] = []
        self._pressures: list[float] = []

    def demand_percent(self, value: float) -> None:
        self._demands.append(("percent", value))

    def demand_ma(self, value: float) -> None:
        self._demands.append(("ma", value))

    def pressure_differential(self, kpa: float) -> None:
        self._pressures.append(kpa)

    def clear(self) -> None:
        self._demands.clear()
        self._pressures.clear()

    def run(self, driver: ValveDriver, t: float, motor_rad: float | None = None, valve_rad: float | None = None,
            now: float | None = None) -> DriverOutput:
        """Hand the collected inputs to ``driver`` at ``t`` (demands first, then Δp, each in
        arrival order: the driver sees one order whatever order they arrived in), then the
        resolver sample stamped ``t`` (none when ``valve_rad`` is None: a dropout), received
        at ``now`` (:meth:`~.driver.ValveDriver.resolver`), and step the driver at ``t``."""
        for kind, value in self._demands:
            if kind == "percent":
                driver.demand_percent(t, value)
            else:
                driver.demand_ma(t, value)
        for kpa in self._pressures:
            driver.pressure_differential(t, kpa)
        self.clear()
        if valve_rad is not None:
            driver.resolver(t, motor_rad, valve_rad, now=now)
        return driver.step(t)
