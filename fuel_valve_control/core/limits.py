"""Actuator current limits: 37 A for at most 20 ms, 15 A continuous, tracked as an I²t budget.

The budget integrates ``(i² - I_cont²) dt`` (never below zero) and holds
``(I_peak² - I_cont²) * t_peak`` (22.9 A²s with the defaults): a cold actuator may draw the peak
current for ``t_peak``, after which the limit falls to the continuous rating until the
integral has drained.  While the budget is exhausted and the loop keeps asking for more than
the continuous current, ``overload_time`` grows: the fault logic uses it to detect a jam.
"""
from __future__ import annotations

import math


class CurrentLimiter:
    def __init__(self, peak_a: float, peak_time_s: float, continuous_a: float, period_s: float):
        self.configure(peak_a, peak_time_s, continuous_a)
        self.period = period_s
        self.budget_used = 0.0     # A²s
        self.overload_time = 0.0   # s
        self.saturated = False

    def configure(self, peak_a: float, peak_time_s: float, continuous_a: float) -> None:
        self.peak = peak_a
        self.continuous = min(continuous_a, peak_a)
        self.budget = (peak_a ** 2 - self.continuous ** 2) * peak_time_s

    @property
    def limit(self) -> float:
        """Largest current magnitude allowed this period, A."""
        if self.budget_used >= self.budget:
            return self.continuous
        # spend what is left of the budget within this period at most
        room = (self.budget - self.budget_used) / self.period + self.continuous ** 2
        return min(self.peak, math.sqrt(room))

    def apply(self, request_a: float) -> float:
        """Clamp a current request to the present limit and account for it."""
        lim = self.limit
        out = min(max(request_a, -lim), lim)
        self.saturated = out != request_a
        self.budget_used = max(self.budget_used + (out * out - self.continuous ** 2) * self.period, 0.0)
        if self.budget_used >= self.budget and abs(request_a) > self.continuous:
            self.overload_time += self.period
        else:
            self.overload_time = 0.0
        return out

    def reset(self) -> None:
        self.budget_used = 0.0
        self.overload_time = 0.0
        self.saturated = False
