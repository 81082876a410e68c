"""Cross-check of the measured pressure differential against the valve friction actually met.

Valve friction grows about elevenfold from Δp 0 to Δp max (:mod:`..common.friction`), so the
friction the valve really shows says roughly what Δp it is under.  A Δp reading that is wrong
(a biased or failed transducer, a wrong fallback) schedules friction terms the valve does not
have; a schedule well above the real friction pushes the valve past breakaway on its own and
hunts.  :class:`FrictionCheck` reads the static friction at every breakaway it can trust and
asks whether the Δp reading can explain it at all:

* **breakaway** (:meth:`FrictionCheck.update`): the valve resolver at rest (within
  ``band_counts`` of where it came to rest, the mean of the samples at rest) for
  ``rest_periods``, then leaving that place, is a *candidate*.  It is read only if the wind-up before it was quasi-static and went the way the
  valve then moved (the gear output turned that way over the window: the motor's Coulomb
  friction then opposed the wind-up and its sign is known; a valve slipping back as the drive
  is taken away is not a wind-up), and it counts only once **confirmed** within
  ``confirm_periods``: ``confirm_samples`` samples in a row beyond the band (resolver noise
  does that a few times a million) and the valve, their mean, has outrun the gear output by
  ``drop_counts`` since the rest — the coupling
  *unwinds* at a stick-slip breakaway (the valve jumps, the drive cannot follow in a few
  periods), whereas under LuGre pre-sliding (bristle creep, a few counts at a rising drive) or
  a dithering hold the valve only follows the drive and the twist keeps its size.  An
  unconfirmed candidate is creep: the rest place moves with it, the wind-up goes on counting.
  (Before: every 3-count creep step of a LuGre valve x2.2 under a 7.6 N*m load read as a
  breakaway at 0.7, 1.8, 3.3 ... N*m, the median fell to 0.23x and a true max Δp was
  rescheduled to 0, and the valve hunted; campaign seed 1004.)
* **friction met at a breakaway**: the valve torque that broke it loose, read from the motor
  side, where the coupling stiffness (x0.1…1 in the scenarios) does not enter: the coupling
  carries ``N u − J1 α1 − B1 ω1`` (α1, ω1 from differences of the motor resolver, whose
  count is 1/N of a valve count) less the motor's Coulomb friction, which opposes the wind-up;
  the friction met is ``s (that − load(θL, Δp))`` (``s`` the direction of the motion, ``load``
  the known spring and flow torque toward closed), its peak over the last ``window`` samples
  before the motion was seen.  Only a quasi-static wind-up counts: the readings over the window
  must span no more than ``quasi_static`` of the level met.
* **met static level**: per direction, the median of the latest ``keep`` breakaways; the mean
  of the two directions (an error in the known load, e.g. the flow torque of a wrong Δp or an
  unknown steady load, cancels: it adds to one direction and subtracts from the other), once
  each direction has ``min_per_direction`` breakaways.  The verdict uses the range the
  readings span (:attr:`FrictionCheck.met_range_nm`): only what every reading allows counts.
* **verdict** (:meth:`FrictionCheck.schedule`): friction scale and Δp are confounded (a valve
  with x3 friction at Δp 0.3 max shows what a nominal valve shows at max), so the check acts
  only where the friction met is *impossible* for the Δp told at any friction scale the valve
  may have (``scale_range``, x0.5…3 of the nominal schedule), widened by ``margin`` for the
  scatter of the readings: met / scheduled outside ``lo / margin .. hi * margin``.  Then the
  friction terms are scheduled for the Δp whose nominal friction equals the friction met
  (:meth:`friction_pressure_kpa`), frozen there (the law is re-seeded once, not every period)
  and that Δp is itself checked against later readings the same way.  The reading is used
  again once it agrees within the tighter ``lo / sqrt(margin) .. hi * sqrt(margin)``
  (hysteresis).  A 0 <-> max error is always outside: the nominal schedule's static levels
  are 0.5 and 5.5 N*m, so x0.5…3 of them (0.25…1.5 and 2.75…16.5 N*m) do not overlap, with a
  factor 1.83 to spare, which ``margin`` 1.3 splits.

Angles rad, torques N*m (valve side unless named motor), pressures kPa.
"""
from __future__ import annotations

import math
from collections import deque

import numpy as np

from .model import NominalModel
from .signals import Measurement


class FrictionCheck:
    """Static friction met at confirmed breakaways, and the Δp schedule it allows (see the
    module docstring).  ``scale_range``: (lowest, highest) friction the valve may have as a
    multiple of the nominal schedule; ``margin`` (> 1): the readings' scatter allowed beyond it."""

    def __init__(self, model: NominalModel, period_s: float, count_rad: float,
                 scale_range: tuple[float, float] = (0.5, 3.0), margin: float = 1.3,
                 rest_periods: int = 10, band_counts: float = 3.0, window: int = 5, confirm_periods: int = 8,
                 drop_counts: float = 1.0, confirm_samples: int = 3, min_per_direction: int = 1, keep: int = 5,
                 stop_margin_rad: float = 0.01, quasi_static: float = 0.5):
        lo, hi = scale_range
        if not 0.0 < lo <= hi:
            raise ValueError(f"scale_range must be 0 < low <= high (got {lo:g}, {hi:g})")
        if margin <= 1.0:
            raise ValueError(f"margin must exceed 1 (got {margin:g})")
        self.model = model
        self.period = period_s
        self.band_rad = band_counts * count_rad
        self.drop_rad = drop_counts * count_rad
        self.scale_range = (lo, hi)
        self.margin = margin
        self.rest_periods = rest_periods
        self.confirm_periods = confirm_periods
        self.confirm_samples = confirm_samples
        self.min_per_direction = min_per_direction
        self.keep = keep
        self.stop_margin = stop_margin_rad
        self.quasi_static = quasi_static
        # the latest samples: valve-side drive torque net of the known load (N*m, + opening),
        # gear output angle and valve angle (rad)
        self._torques: deque = deque(maxlen=window)
        self._gear: deque = deque(maxlen=max(window, 3))
        self._valve: deque = deque(maxlen=max(window, confirm_samples))
        self.reset()

    def reset(self) -> None:
        """Forget every breakaway met (after a fault reset or a re-arm)."""
        self._torques.clear()
        self._gear.clear()
        self._valve.clear()
        self._anchor: float | None = None
        self._rest = 0
        self._rest_sum = 0.0
        #: a candidate breakaway waiting for its confirmation: (direction, friction met N*m,
        #: twist before it rad, periods waited)
        self._candidate: list | None = None
        #: latest static levels met per direction (+1 opening, -1 closing), N*m at the valve
        self.static_met: dict[int, deque] = {1: deque(maxlen=self.keep), -1: deque(maxlen=self.keep)}
        self.breakaways = 0
        self.rejected = 0               # candidates not confirmed (creep, noise)
        self.override_kpa: float | None = None   # Δp scheduled from the friction met (None: the reading)

    # ------------------------------------------------------------------ breakaways
    def update(self, meas: Measurement, applied_torque_nm: float, pressure_kpa: float) -> None:
        """One period: the resolver sample, the motor torque applied since the previous sample
        (N*m at the motor) and the Δp the schedule uses now (kPa)."""
        m = self.model
        n = m.gear_ratio
        theta = meas.valve_rad
        gear = self._gear
        gear.append(meas.motor_rad / n)
        self._valve.append(theta)
        if len(gear) >= 3:
            t = self.period
            w1 = (gear[-1] - gear[-2]) / t
            a1 = (gear[-1] - 2.0 * gear[-2] + gear[-3]) / (t * t)
            coupling = n * applied_torque_nm - m.j1 * a1 - m.b1 * w1
            self._torques.append(coupling - m.load_torque(theta, pressure_kpa))
        if self._candidate is not None:
            self._confirm(theta, gear[-1])
            return
        if self._anchor is None:
            self._rest_at(theta)
            return
        moved = theta - self._anchor
        if abs(moved) <= self.band_rad:
            # the rest place: the mean of the samples at rest (a single sample carries the
            # resolver's ~1 count rms noise, and a band around a noise peak is left by noise)
            self._rest += 1
            self._rest_sum += theta
            self._anchor = self._rest_sum / (self._rest + 1)
            return
        inside = self.stop_margin < self._anchor < m.stroke_rad - self.stop_margin
        if self._rest >= self.rest_periods and inside and len(self._torques) >= 3:
            s = 1 if moved > 0.0 else -1
            window = [s * v for v in list(self._torques)[:-1]]
            gears = list(gear)[-len(window) - 1:-1]
            valves = list(self._valve)[-len(window) - 1:-1]
            # the wind-up peak before the motion was seen; the motor's own friction opposed it
            met = max(window) - n * m.motor_coulomb_nm
            # only a quasi-static wind-up says what the friction is: a drive swinging through the
            # window (a hunting loop, a violent move start) reads its own dynamics, not friction;
            # and only one going the motion's way (the gear output turned that way): a valve the
            # drive lets go slips back with the motor turning the other way (its Coulomb
            # friction then helps instead of opposing)
            quasi_static = max(window) - min(window) <= self.quasi_static * max(abs(met), m.valve_static_nm)
            wound = s * (gears[-1] - gears[0]) > 0.0
            if quasi_static and wound:
                # the twist at the last stuck sample: the gear output then (its resolver is
                # N times finer) less the stuck valve's mean over the window (its noise)
                twist = gears[-1] - float(np.mean(valves))
                self._candidate = [s, met, twist, 0]
                return
        self._rest_at(theta)

    def _rest_at(self, theta: float) -> None:
        self._anchor, self._rest, self._rest_sum = theta, 0, theta

    def _confirm(self, theta: float, gear: float) -> None:
        """A candidate: confirmed once the valve has outrun the gear output by ``drop_counts``
        (the coupling unwinds); creep and resolver noise do not."""
        s, met, twist0, waited = self._candidate
        waited += 1
        self._candidate[3] = waited
        # the valve over the last confirm_samples samples: two noise samples 4-5 counts off
        # with the drive winding up fast read as a 2.2-count unwinding (campaign seed 1073,
        # ~1 count rms: a -7.5 N*m closing "breakaway" on a valve whose closing level is -2.5)
        valves = list(self._valve)[-self.confirm_samples:]
        twist = gear - float(np.mean(valves))
        beyond = waited + 1 >= self.confirm_samples and all(s * (v - self._anchor) > self.band_rad for v in valves)
        if beyond and s * (twist0 - twist) >= self.drop_rad:
            self.static_met[s].append(met)     # may read below 0 by a load error: the mean cancels it
            self.breakaways += 1
            self._candidate = None
            self._rest_at(theta)
        elif waited >= self.confirm_periods or s * (theta - self._anchor) < 0.0:
            # creep (the valve followed the drive) or a noise sample: no breakaway.  The valve
            # is still held by its friction: the rest place moves with it, the rest goes on
            self.rejected += 1
            self._candidate = None
            self._anchor = float(np.mean(self._valve))       # the recent samples: not a noise peak
            self._rest_sum = self._anchor * (self._rest + 1)

    # ------------------------------------------------------------------ what was met
    @property
    def met_static_nm(self) -> float | None:
        """Static valve friction met (N*m): the mean over both directions of the median of
        each; None before ``min_per_direction`` breakaways each way."""
        # both directions: a steady load the model does not know (up to the continuous torque)
        # adds to one and subtracts from the other; one direction alone read it as friction
        # (a closing-only reading under a 9 N*m load said 0 friction and latched a fault)
        if any(len(v) < self.min_per_direction for v in self.static_met.values()):
            return None
        medians = [float(np.median(v)) for v in self.static_met.values()]
        return max(sum(medians) / len(medians), 0.0)

    @property
    def met_range_nm(self) -> tuple[float, float] | None:
        """(lowest, highest) static valve friction the breakaways met could say (N*m): the mean
        over both directions of the smallest, and of the largest, of each direction's latest
        readings; None before ``min_per_direction`` breakaways each way."""
        # the verdict acts only on what *every* reading allows: an outlier (a breakaway read
        # low or high for a reason not traced) can then only hold the verdict back, never make
        # it.  With the median instead, three low opening readings of five (3.7-4.1 among
        # 8.4-9.0 N*m; campaign seed 3023, Stribeck x1.9, K x0.39, 6.4 N*m load, backlash)
        # moved the level met 2.9 -> 0.74 N*m, a right-enough reading was rescheduled to
        # 296 kPa for 0.8 s and the final hold hunted
        if any(len(v) < self.min_per_direction for v in self.static_met.values()):
            return None
        lows = [min(v) for v in self.static_met.values()]
        highs = [max(v) for v in self.static_met.values()]
        return max(sum(lows) / len(lows), 0.0), max(sum(highs) / len(highs), 0.0)

    def ratio(self, pressure_kpa: float) -> float | None:
        """Met / scheduled static friction at ``pressure_kpa``; None while not yet known."""
        met = self.met_static_nm
        if met is None:
            return None
        return met / max(self.model.friction(pressure_kpa).valve_static_nm, 1e-9)

    def plausible(self, pressure_kpa: float, margin: float | None = None) -> bool:
        """Whether some friction scale within ``scale_range`` (widened by ``margin``, default
        :attr:`margin`) explains some friction the breakaways met could say
        (:attr:`met_range_nm`) at ``pressure_kpa`` (True while nothing has been met yet)."""
        met = self.met_range_nm
        if met is None:
            return True
        margin = self.margin if margin is None else margin
        lo, hi = self.scale_range
        scheduled = self.model.friction(pressure_kpa).valve_static_nm
        return met[1] >= lo / margin * scheduled and met[0] <= hi * margin * scheduled

    def friction_pressure_kpa(self) -> float | None:
        """Δp (kPa, 0..max) whose nominal static valve friction equals the friction met."""
        met = self.met_static_nm
        if met is None:
            return None
        m = self.model
        if m.valve_static_per_dp_nm <= 0.0:
            return None
        frac = (met - m.valve_static_nm) / m.valve_static_per_dp_nm
        return min(max(frac, 0.0), 1.0) * m.pressure_max_kpa

    def schedule(self, reading_kpa: float) -> float:
        """The Δp (kPa) to schedule the friction terms for, given the Δp reading: the reading
        while the friction met allows it, else the Δp the friction met says, frozen while the
        friction met goes on allowing that (:attr:`override_kpa`; see the module docstring)."""
        if self.override_kpa is None:
            if not self.plausible(reading_kpa):
                self.override_kpa = self.friction_pressure_kpa()
        elif self.plausible(reading_kpa, math.sqrt(self.margin)):
            self.override_kpa = None                  # the reading agrees again (hysteresis)
        elif not self.plausible(self.override_kpa):
            self.override_kpa = self.friction_pressure_kpa()   # the friction met has moved on
        return reading_kpa if self.override_kpa is None else self.override_kpa
