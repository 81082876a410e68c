"""How hunting is counted (SPEC §5, issue 14), written once: the campaign's metric
(:func:`fuel_valve_control.tools.metrics.plateau_results`) and the fine-positioning stage, which
must never make a plateau hunt by it (:mod:`fuel_valve_control.core.fine_positioning`), both count
direction reversals with :class:`ReversalCounter`.

A plateau *hunts* when, from ``HUNT_SETTLE_S`` after its step to its end, the valve angle reverses
direction at least twice (each move counted only once it exceeds the hysteresis, one resolver
count) and its half peak-to-peak there exceeds ``HUNT_COUNTS`` resolver counts.

Angles rad; times s.
"""
from __future__ import annotations

from .contract import RESOLVER_COUNT_RAD

#: a plateau hunts when, after this long, its angle still reverses twice (moves of more than one
#: count) and its half peak-to-peak exceeds HUNT_COUNTS resolver counts
HUNT_SETTLE_S = 0.3
HUNT_COUNTS = 2.0
#: reversals on a plateau's late window that make it hunt
HUNT_REVERSALS = 2


class ReversalCounter:
    """Direction reversals of an angle fed one sample at a time, counting only moves larger than
    ``hysteresis`` (rad): a move's direction is taken once the angle has left the range seen so far
    by more than it, and each later turn by more than it from the extreme of the present move is
    one reversal.  ``direction``: +1 / -1 of the present move, 0 before the first."""

    __slots__ = ("hysteresis", "count", "direction", "_lo", "_hi", "_ext")

    def __init__(self, start: float, hysteresis: float = RESOLVER_COUNT_RAD):
        self.hysteresis = hysteresis
        self.count = 0
        self.direction = 0
        self._lo = self._hi = self._ext = float(start)

    def update(self, x: float) -> int:
        """Take the next sample ``x`` (rad); returns the reversals counted so far."""
        h = self.hysteresis
        if self.direction == 0:
            self._lo, self._hi = min(self._lo, x), max(self._hi, x)
            if x > self._lo + h:
                self.direction, self._ext = 1, x
            elif x < self._hi - h:
                self.direction, self._ext = -1, x
        elif self.direction * (x - self._ext) > 0.0:
            self._ext = x                              # the present move goes on
        elif self.direction * (self._ext - x) > h:
            self.count, self.direction, self._ext = self.count + 1, -self.direction, x
        return self.count
