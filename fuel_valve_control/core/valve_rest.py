"""Whether a valve read through a noisy resolver is at rest, and where a slide began (task s35).

The fine-positioning stage engages on a valve that has sat still for its engage time, and reads
the main law's breakaway twist at the last period the valve sat still.  Its own test is
sample-to-sample: a step of less than half the tolerance (1.5 counts at the default 3).  On the
nominal resolver (0.25 count rms before quantisation) that is sound; at 0.5-1 count rms a step of
2 counts comes every few periods, the rest count seldom reaches the engage time, and the rest's
twist is left stale while the main law's ramp moves on -- the stage read the valve as a misfit
of its model and stayed out (nominal box seed 1000: 14 / 43 / 137 / 200 plateaus > 8e-4 rad of
480 at 0.25 / 0.5 / 0.8 / 1 count rms).

:class:`ValveRest` reads the resolver's noise from the readings themselves and, where the
readings are noisy, tests rest on the means of two windows, finds a slide's onset by looking
back, and gives the stage a short mean of the readings to judge its tries by.  All angles in
rad, noise in resolver counts (:data:`RESOLVER_COUNT_RAD`).  Nothing here depends on the
simulated plant.
"""
from __future__ import annotations

import math

from ..common.contract import RESOLVER_COUNT_RAD

#: second differences are clipped at D2_CLIP counts (a move's acceleration is no noise) and averaged
#: over ~NOISE_TIME_S of held periods; white noise of rms sigma gives a mean |second difference| of
#: D2_GAIN x sigma
D2_CLIP, NOISE_TIME_S = 4.0, 0.5
D2_GAIN = math.sqrt(6.0) * math.sqrt(2.0 / math.pi)
#: the estimate is trusted after TRUST_S of held still periods (a mean over 200 samples at 1 kHz: the
#: campaign's first move comes 0.3 s in; over 100, one or two failing steps read 1-2 %)
TRUST_S = 0.2
#: a slide's onset is the newest reading within ONSET_SIGMAS of the noise from the rest's mean
ONSET_SIGMAS = 2.0
#: where noisy, the stage reads the valve as the mean of its last SMOOTH_PERIODS readings: the noise
#: halved for 1.5 periods of lag (nominal box at 1 count rms, seed 1000: 8 periods 16 plateaus > 8e-4
#: of 480, 4 periods 13, the raw reading 29)
SMOOTH_PERIODS = 4


class ValveRest:
    """The valve's rest on a possibly noisy resolver.

    ``window``: periods per window (the stage's engage periods); ``step_rad``: the sample-to-sample
    rest test's largest step (half the stage's tolerance), rad; ``noisy_rate``: the fraction of the
    still valve's steps failing that test above which the readings count as noisy (0: never);
    ``period_s``: the loop period, s.
    Feed every period with :meth:`update`; then :attr:`noisy`, :meth:`at_rest`,
    :meth:`rest_valve` and :meth:`onset_twist` answer for the readings so far.
    """

    def __init__(self, window: int, step_rad: float, noisy_rate: float, period_s: float):
        self.window = max(int(window), 1)
        self.step_rad = step_rad
        self.noisy_rate = noisy_rate
        self.period_s = period_s
        self.reset()
        self.forget()

    def reset(self) -> None:
        """Forget the readings' windows (a re-arm: the valve may have moved meanwhile); the noise read
        stays -- it is the resolver's, which a re-arm does not change (restarted, the estimate's
        first 100 periods read 2 % of failing steps from one or two on the nominal resolver)."""
        self._valve: list[float] = []     # the last 2 x window valve readings, rad (oldest first)
        self._twist: list[float] = []     # ... and the twists (gear output - valve) read with them, rad
        self._still = False               # :meth:`at_rest` of the readings so far (computed once per update)

    def forget(self) -> None:
        """Forget the noise read as well (a learning reset)."""
        self._n = 0                       # held periods taken into the noise estimate
        self._d2 = 0.0                    # their mean clipped |second difference|, counts
        self._steps = 0.0                 # the fraction of their steps that fail the sample-to-sample test

    def update(self, valve: float, twist: float, held: bool) -> None:
        """Take one period's valve reading and twist (rad); ``held``: the main law holds an arrived
        reference and the stage is idle.  Only held periods whose windows' means show the valve still
        (:meth:`at_rest`) feed the noise estimate: a constant speed does not show in a second
        difference, but the valve settling or creeping under a hold did show in the steps (the
        `startup` scenario's first 0.14 s read 26 % of them failing the sample-to-sample test on
        the nominal 0.25-count resolver)."""
        v = self._valve
        v.append(valve)
        self._twist.append(twist)
        n = self.window
        if len(v) > 2 * n:
            del v[0], self._twist[0]
        self._still = len(v) == 2 * n and abs(sum(v[n:]) - sum(v[:n])) < self.step_rad * n
        if held and self._still and len(v) >= 3:
            d2 = min(abs(v[-1] - 2.0 * v[-2] + v[-3]) / RESOLVER_COUNT_RAD, D2_CLIP)
            self._n += 1
            gain = max(self.period_s / NOISE_TIME_S, 1.0 / self._n)
            self._d2 += gain * (d2 - self._d2)
            self._steps += gain * (float(abs(v[-1] - v[-2]) >= self.step_rad) - self._steps)

    @property
    def noise_counts(self) -> float:
        """The resolver's noise as read, rms counts (0 before any held period).  Read on the
        robustness campaign: the nominal 0.25-count resolver reads 0.28-0.42 once settled
        (quantisation adds), 0.6-1 count reads 0.57-1.02; above ~1 count the clip reads it low (1.5
        counts: ~1.25)."""
        return self._d2 / D2_GAIN if self._n else 0.0

    @property
    def step_rate(self) -> float:
        """The fraction of the still valve's steps that fail the sample-to-sample rest test (0 before
        any held period).  Read on the nominal box (20 runs each, after ``TRUST_S``): at 0.25 count
        rms 0.14 % median, 0.78 % at most; at 0.4 count 1.8 % median; at 0.5 count 4.7 % median,
        1.7 % at least; at 0.6 count 3.8 % at least.  A reading dithering across a count boundary
        reads ~0.5 count of noise from its second differences but steps one count at most, which
        the test passes: the rate, not the noise, says whether the test still works."""
        return self._steps if self._n else 0.0

    @property
    def noisy(self) -> bool:
        """Whether the readings are too noisy for the sample-to-sample test: after ``TRUST_S`` of
        held periods, more than ``noisy_rate`` of the still valve's steps fail it."""
        return self.noisy_rate > 0.0 and self._n * self.period_s >= TRUST_S and self._steps > self.noisy_rate

    def at_rest(self) -> bool:
        """Rest by the means: the mean of the last ``window`` readings lies within ``step_rad`` of
        the mean of the ``window`` before them (not yet 2 x window readings: no).  The means'
        difference has 0.45 x the noise's rms at 10 periods a window; as a speed the test is
        ``window`` times stricter than the sample-to-sample test.  Computed in :meth:`update`."""
        return self._still

    def smoothed(self) -> float:
        """The valve angle as the mean of the last ``SMOOTH_PERIODS`` readings (rad; fewer before
        that many)."""
        v = self._valve[-SMOOTH_PERIODS:]
        return sum(v) / len(v)

    def rest_valve(self) -> float:
        """The valve angle of the rest the means vouch for (rad): the older window's mean (the newer
        one may hold the first periods of a slide the means do not show yet)."""
        n = min(self.window, len(self._valve))
        return sum(self._valve[:n]) / n

    def onset_twist(self, d: int, valve: float) -> float:
        """The twist (rad) a valve seen sliding toward ``d`` (+1 opening, -1 closing) from its rest
        at ``valve`` (rad, :meth:`rest_valve`) broke loose at: the twist of the newest reading no
        further toward ``d`` than ``ONSET_SIGMAS`` of the noise -- the slide's onset, to a period
        or two (at 625 rad/s^2 the valve moves 2 counts in 0.8 ms).  Why not the last rest
        period's twist: the means read rest for a few periods into a slide while the main law's
        move drives the gear output on past the level -- up to 3e-3 rad beyond it on the nominal
        box at 1 count rms, read as a misfit of the model (nor the window's furthest twist: the
        same overshoot)."""
        tol = ONSET_SIGMAS * self.noise_counts * RESOLVER_COUNT_RAD
        v = self._valve
        for k in range(len(v) - 1, -1, -1):
            if d * (v[k] - valve) <= tol:
                return self._twist[k]
        return self._twist[0]
