"""Demand conditioning for a real analog position demand (issue 14, deliverable 4).

A 4–20 mA demand carries noise (~0.1 % of stroke rms is realistic) and the odd single-sample
glitch (EMI, a relay).  Passed straight to the position loop every noise sample is a tiny
step: its derivative drives the velocity and friction feed-forward (a 0.1 % rms noise gives
valve excursions of ~7e-2 rad), and a glitch larger than the move threshold becomes a
planned move.  :class:`DemandFilter` stands between the signal and the loop:

1. **median of the last three samples** — a single-sample glitch never gets through, a
   genuine change arrives one sample late;
2. **noise level estimate** — robust running mean of the second difference of the raw
   samples (``|x_k − 2 x_(k−1) + x_(k−2)|``; ramps and sines up to tens of Hz hardly contribute,
   steps are clipped), converted to an rms: for white noise ``E|Δ²| = sqrt(6)·sqrt(2/π)·σ``;
3. **hold / track**: while the demand stays inside a band of ``band_sigmas`` noise rms (never
   less than ``min_band``) around the held value, the output is *held* — it moves only to the
   running mean of the samples since the hold began, and only in steps of at least
   ``quantum`` (one valve resolver count), so noise never reaches the loop as velocity; once
   ``confirm`` consecutive samples leave the band on the same side, the output *tracks* the
   median output directly (steps, ramps and sines pass with one sample of delay) until the
   demand has stayed within one band of an anchor for ``quiet_time``; then it holds again,
   starting from the mean of that quiet window.

Latency: a sine or ramp is delayed by one sample (the median: 1 ms at 1 kHz, 7.2° at 20 Hz);
a step by ``1 + confirm`` samples.  With a noisy demand, changes smaller than the band
(3 σ ≈ 0.3 % of stroke at 0.1 % rms) are not distinguishable from the noise and are followed
only through the running mean, i.e. to within ``σ / sqrt(n)`` of the true value.

Units: whatever the caller feeds (the driver feeds rad at the valve); times in s.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

#: E|second difference| / σ for white noise: sqrt(6) * sqrt(2/π)
_ABS_D2_PER_SIGMA = math.sqrt(6.0) * math.sqrt(2.0 / math.pi)
#: second differences beyond this many times the running mean are clipped (steps, not noise);
#: large enough that the estimate climbs to a new noise level within a few time constants
_CLIP = 8.0


@dataclass(frozen=True)
class DemandFilterConfig:
    band_sigmas: float        # hold band half-width in estimated noise rms
    min_band: float           # smallest band half-width (same unit as the demand)
    quantum: float            # smallest output change while holding
    confirm: int              # consecutive samples beyond the band that start tracking
    quiet_time_s: float       # demand within one band this long: hold again
    noise_time_s: float       # time constant of the noise estimate
    hold_window_s: float      # longest averaging window while holding


class DemandFilter:
    """Sample-by-sample conditioning of a noisy demand (see module doc)."""

    def __init__(self, cfg: DemandFilterConfig):
        self.cfg = cfg
        self.reset()

    def reset(self, value: float | None = None) -> None:
        """Forget the history; with ``value`` start holding it."""
        self._raw: list[float] = [] if value is None else [value] * 3
        self._abs_d2 = 0.0               # running mean of |Δ²| (noise estimate)
        self._t: float | None = None
        self.output: float | None = value
        self.tracking = False
        self._beyond = 0                 # consecutive samples beyond the band (signed count)
        self._sum = 0.0 if value is None else value
        self._n = 0 if value is None else 1
        self._anchor = value
        self._quiet_since: float | None = None
        self._quiet_sum = 0.0
        self._quiet_n = 0

    @property
    def noise_rms(self) -> float:
        """Estimated rms noise of the demand (its unit)."""
        return self._abs_d2 / _ABS_D2_PER_SIGMA

    @property
    def band(self) -> float:
        return max(self.cfg.min_band, self.cfg.band_sigmas * self.noise_rms)

    def update(self, t: float, value: float) -> float:
        """Take one demand sample at ``t`` (s); returns the conditioned demand."""
        cfg = self.cfg
        value = float(value)
        if self.output is None:
            self.reset(value)
            self._t = t
            return value
        dt = max(t - self._t, 0.0) if self._t is not None else 0.0
        self._t = t
        raw = self._raw
        raw.append(value)
        del raw[:-3]
        m = sorted(raw)[1] if len(raw) == 3 else value
        if len(raw) == 3 and dt > 0.0:
            d2 = abs(raw[2] - 2.0 * raw[1] + raw[0])
            # steps (and glitches that got through) are clipped so they do not inflate the estimate
            d2 = min(d2, _CLIP * max(self._abs_d2, cfg.min_band))
            self._abs_d2 += min(dt / cfg.noise_time_s, 1.0) * (d2 - self._abs_d2)
        band = self.band
        if self.tracking:
            self.output = m
            if self._anchor is None or abs(m - self._anchor) > band:
                self._anchor, self._quiet_since, self._quiet_sum, self._quiet_n = m, t, 0.0, 0
            self._quiet_sum += m
            self._quiet_n += 1
            if t - self._quiet_since >= cfg.quiet_time_s:
                self.tracking = False
                self._sum, self._n = self._quiet_sum, self._quiet_n
                self.output = self._sum / self._n
                self._beyond = 0
            return self.output
        side = int(m > self.output + band) - int(m < self.output - band)
        if side == 0:
            self._beyond = 0
            self._sum += m
            self._n += 1
            cap = max(int(cfg.hold_window_s / dt), 1) if dt > 0.0 else None
            if cap is not None and self._n > cap:       # a finite memory: follow slow drifts
                self._sum *= cap / self._n
                self._n = cap
            mean = self._sum / self._n
            if abs(mean - self.output) >= cfg.quantum:
                self.output = mean
            return self.output
        self._beyond = self._beyond + side if self._beyond * side > 0 else side
        if abs(self._beyond) >= cfg.confirm:
            self.tracking = True
            self.output = m
            self._anchor, self._quiet_since, self._quiet_sum, self._quiet_n = m, t, m, 1
        return self.output

    def state(self) -> dict:
        """Diagnostics: estimated noise rms, band, tracking or holding."""
        return {"demand_noise_rms_rad": self.noise_rms, "demand_band_rad": self.band,
                "demand_filter": "tracking" if self.tracking else "holding"}
