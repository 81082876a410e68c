"""Reference shaping: large demand changes become smooth, limited moves.

A jump in the demand larger than ``step_threshold`` would saturate the current, wind up the
loop and ring the coupling; instead the reference travels along a planned move from rest to
rest: a trapezoidal velocity profile whose acceleration phases are sin² shaped, so the
acceleration (and the friction and inertia feed-forward built on it) rises and falls
smoothly — jerk-limited, nothing that rings the 87 Hz coupling mode.  A move lasts at least
``min_move_time``: a small step is a quick, smooth push fast enough for the valve to slide
continuously (at max Δp it only slides smoothly above ~1 rad/s; slower it stick-slips).

While a move runs, further demand changes are remembered and planned when it ends.  Small or
continuous demand changes (ramps, sines, dither) pass straight through, so the shaper costs
no bandwidth; their velocity (for feed-forward) is the demand's derivative through a
first-order filter of ``velocity_filter`` seconds; with ``follow_acceleration`` the
acceleration too (the same filter on the velocity's difference; the velocity then comes from
the median of the last three per-sample slopes, so a one-sample step is not a velocity
impulse), and with ``follow_lead`` the
followed reference is extrapolated that far ahead (``p + lead v``, ``v + lead a``: it makes up
for the demand conditioning's one-sample median delay).  The acceleration of a move is sampled
``lead`` seconds ahead: the torque it feeds forward acts through the zero-order hold and the
current loop, i.e. late.  Units: rad, rad/s, rad/s², s.

**Start on breakaway** (``breakaway_wait`` > 0, issue 14): a planned move from a valve at rest
waits at its start (``Reference.armed`` = the move's direction, +1 opening) while the friction
feed-forward ramps the drive toward breakaway, and its clock starts on the period the valve
resolver shows the valve has left its start by more than ``breakaway_rad`` the move's way
(``Reference.broke_away``), or after ``breakaway_wait`` seconds at most.  Only moves up to
``breakaway_max_move`` wait: a longer one has the time to catch a late breakaway up on its way
(waiting cost the full stroke 84 ms, 0.100 -> 0.184 s).  On a clock the move
ran away from a valve whose friction differs from the model: stuck 6e-3 rad behind the reference
(friction x3, or a 20 % lighter drivetrain) it stalled short and a second full stick-slip jump
finished it (43-45 %, 23 % overshoot); with half the friction it broke loose early under the
full feed-forward (36 %).

A waiting move is planned from the valve's measured angle, not from the old reference (a valve
rests anywhere inside the hold's deadband); when that leaves nothing beyond the step threshold or
the hold's deadband (``hold_band``, set by the law), the demand is the hold's and no move is
planned.  Breakaway is a *slide*: ``breakaway_rad`` from the start and 2/3 of it within the last
:attr:`TrajectoryShaper.BREAKAWAY_WINDOW` periods (a presliding creep is not one).  The law ends
a wait early with :meth:`TrajectoryShaper.start_clock` when the friction compensation sees the
drive well past the breakaway this valve has shown
(:meth:`~.compensation.ReferenceFeedforward.wait_over`).
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass


@dataclass
class Reference:
    position: float
    velocity: float
    acceleration: float
    moving: bool          # True while a planned move is under way
    #: direction (+1 opening, -1 closing) of a planned move waiting at its start for the valve
    #: to break away; 0 otherwise
    armed: float = 0.0
    #: the valve broke away this period and started the waiting move's clock
    broke_away: bool = False


@dataclass(frozen=True)
class Move:
    """A rest-to-rest move of ``distance`` (signed) with sin²-shaped acceleration phases."""

    start: float
    distance: float
    accel_time: float     # duration of each acceleration phase, s
    cruise_time: float
    peak_velocity: float  # magnitude

    @classmethod
    def plan(cls, start: float, target: float, v_max: float, a_max: float, min_time: float) -> "Move":
        d = abs(target - start)
        # sin² acceleration with peak a: an acceleration phase of t_a gains v = a t_a / 2
        v = min(v_max, math.sqrt(d * a_max / 2.0))
        t_a = 2.0 * v / a_max
        t_c = d / v - t_a if v > 0 else 0.0
        if 2.0 * t_a + t_c < min_time:          # too quick for a small move: stretch it
            if d / v_max >= min_time / 2.0:      # cruising at v_max, longer ramps
                v = v_max
                t_a = max(min_time - d / v, 0.0)
                t_c = d / v - t_a
            else:                                # no cruise: two ramps of min_time / 2
                t_a, t_c = min_time / 2.0, 0.0
                v = d / t_a
        return cls(start, target - start, t_a, max(t_c, 0.0), v)

    @property
    def duration(self) -> float:
        return 2.0 * self.accel_time + self.cruise_time

    def sample(self, tau: float) -> tuple[float, float, float]:
        """(position, velocity, acceleration) at ``tau`` seconds into the move."""
        sgn = 1.0 if self.distance >= 0 else -1.0
        ta, tc, v = self.accel_time, self.cruise_time, self.peak_velocity
        if tau >= self.duration or ta <= 0.0:
            return self.start + self.distance, 0.0, 0.0
        a_pk = 2.0 * v / ta
        w = 2.0 * math.pi / ta

        def ramp(t):   # distance, velocity, acceleration of one sin² ramp from rest
            return (a_pk * (t * t / 4.0 + (math.cos(w * t) - 1.0) / (2.0 * w * w)),
                    a_pk * (t / 2.0 - math.sin(w * t) / (2.0 * w)),
                    a_pk * math.sin(math.pi * t / ta) ** 2)

        d_ramp = v * ta / 2.0
        if tau < ta:
            p, vel, acc = ramp(tau)
        elif tau < ta + tc:
            p, vel, acc = d_ramp + v * (tau - ta), v, 0.0
        else:
            rem = self.duration - tau             # the deceleration mirrors the acceleration
            p_r, v_r, a_r = ramp(rem)
            p, vel, acc = abs(self.distance) - p_r, v_r, -a_r
        return self.start + sgn * p, sgn * vel, sgn * acc


class TrajectoryShaper:
    #: a waiting move's valve counts as broken away only once it has also moved BREAKAWAY_SLIDE x
    #: ``breakaway_rad`` the move's way within BREAKAWAY_WINDOW periods (a slide, not a creep:
    #: 0.19 mrad in 5 ms is 0.04 rad/s).  A whole ``breakaway_rad`` in the window detected a real
    #: breakaway a period late (the 2 % step at friction x 0.5 overshot 6.9 %, not 1.1 %); half of
    #: it let resolver noise on a creep through again (seed 1018)
    BREAKAWAY_WINDOW = 5
    BREAKAWAY_SLIDE = 2.0 / 3.0

    def __init__(self, period_s: float, max_velocity: float, max_acceleration: float, step_threshold: float,
                 velocity_filter: float = 0.0, min_move_time: float = 0.0, lead: float = 0.0,
                 follow_acceleration: bool = False, follow_lead: float = 0.0, breakaway_wait: float = 0.0,
                 breakaway_rad: float = 0.0, breakaway_max_move: float = math.inf):
        self.period = period_s
        self.breakaway_wait = breakaway_wait
        self.breakaway_rad = breakaway_rad
        self.breakaway_max_move = breakaway_max_move
        self._wait = 0.0           # s a planned move has waited at its start for breakaway
        self._anchor: float | None = None   # valve angle when the waiting move was planned, rad
        #: rad, the hold's deadband (set by the law each period): a move that would wait for
        #: breakaway from a valve this close to its demand is left to the hold
        self.hold_band = 0.0
        #: valve angles of the latest periods of a wait (rad), oldest first
        self._recent: deque = deque(maxlen=self.BREAKAWAY_WINDOW + 1)
        self.lead = lead
        self.follow_acceleration = follow_acceleration
        self.follow_lead = follow_lead
        self.v_max = max_velocity
        self.a_max = max_acceleration
        self.threshold = step_threshold
        self.min_move_time = min_move_time
        self._alpha = period_s / (period_s + velocity_filter)
        self._p: float | None = None
        self._v = 0.0
        self._a = 0.0
        self._slopes: list[float] = []
        self._move: Move | None = None
        self._tau = 0.0

    def reset(self, position: float) -> None:
        """Start at rest at ``position`` (e.g. the measured valve angle)."""
        self._p = position
        self._v = 0.0
        self._a = 0.0
        self._slopes: list[float] = []
        self._move = None
        self._anchor = None

    def start_clock(self) -> None:
        """End the wait of a move armed for breakaway: its clock starts on the next period
        (the friction compensation judged that the valve will not let go where it expected)."""
        if self._move is not None and self._tau == 0.0:
            self._wait = max(self._wait, self.breakaway_wait)

    def _waits(self, distance: float) -> bool:
        """Whether a planned move of ``distance`` (rad) waits at its start for breakaway."""
        return self.breakaway_wait > 0.0 and abs(distance) <= self.breakaway_max_move

    @property
    def moving(self) -> bool:
        return self._move is not None

    @property
    def move(self) -> Move | None:
        """The planned move under way (None: none)."""
        return self._move

    @property
    def sample_time(self) -> float:
        """The time into the move (s) its reference is sampled at this period: the clock plus the
        feed-forward lead."""
        return self._tau + self.lead

    def arrived(self, target: float) -> bool:
        """At rest on ``target`` (a planned move has ended there)."""
        return self._move is None and self._p == target

    def at(self, position: float) -> bool:
        return self._move is None and self._p == position

    def update(self, demand: float, valve_rad: float | None = None) -> Reference:
        """Advance one period toward ``demand``; returns the reference for this period.
        ``valve_rad``: the measured valve angle (rad), which starts a move waiting for
        breakaway (without it a move starts on the clock)."""
        if self._p is None:
            self.reset(demand)
        if self._move is None and abs(demand - self._p) > self.threshold:
            start = self._p
            if self._waits(demand - self._p) and valve_rad is not None:
                # a move that waits for breakaway starts where the valve *is*: a valve held
                # anywhere inside the hold's deadband of the old target (up to half a jump off)
                # would otherwise start its move that far from the planned start, and the hold's
                # uncock absorbs the offset, so the move ended the offset past its target
                # (campaign seed 1004: 6 mrad short of the old plateau, the 24 mrad closing move
                # ran 15 mrad past), or even armed the wrong way (seed 1006: stuck 46 mrad short
                # of an opening plateau, the next small closing step waited for a closing breakaway)
                start = valve_rad
                if abs(demand - start) <= max(self.threshold, self.hold_band):
                    # no move is left to plan from where the valve is (or the valve already sits
                    # within the hold's deadband of the demand, where a breakaway would carry
                    # it a whole jump): the demand is the hold's, as for a step below the threshold
                    self._p, self._v, self._a, self._slopes = demand, 0.0, 0.0, []
                    return Reference(demand, 0.0, 0.0, False)
            self._move = Move.plan(start, demand, self.v_max, self.a_max, self.min_move_time)
            self._tau = 0.0
            self._wait = 0.0
            self._anchor = valve_rad          # where the valve was when the move was planned
            self._recent.clear()
            self._recent.append(valve_rad)
        broke = False
        if self._move is not None and self._tau == 0.0 and self._waits(self._move.distance) \
                and self._anchor is not None and valve_rad is not None:
            sgn = 1.0 if self._move.distance >= 0 else -1.0
            # breakaway: beyond breakaway_rad from the start *and* BREAKAWAY_SLIDE of it within
            # the last BREAKAWAY_WINDOW periods (the valve slides).  A creep of a valve pressed toward
            # breakaway (LuGre presliding) crosses the first alone: read as breakaway it started
            # the move's clock and the retreat on a valve still stuck, which stayed 26 mrad short
            # of a 0.4 s plateau (campaign seed 1018)
            self._recent.append(valve_rad)
            broke = sgn * (valve_rad - self._anchor) > self.breakaway_rad \
                and sgn * (valve_rad - self._recent[0]) > self.BREAKAWAY_SLIDE * self.breakaway_rad
            if not broke and self._wait < self.breakaway_wait:
                self._wait += self.period
                return Reference(self._move.start, 0.0, 0.0, True, armed=sgn)
        if self._move is None:
            raw = (demand - self._p) / self.period
            if self.follow_acceleration:
                # median of the last three per-sample slopes: a sine or ramp keeps its slope, a
                # one-sample step (a small plateau change below the move threshold) gives none,
                # so it is not kicked by a velocity and acceleration impulse
                self._slopes = (self._slopes + [raw])[-3:]
                raw = sorted(self._slopes)[len(self._slopes) // 2] if len(self._slopes) == 3 else 0.0
            v_old = self._v
            self._v += self._alpha * (min(max(raw, -self.v_max), self.v_max) - self._v)
            # acceleration of a followed demand: the derivative of the filtered velocity through
            # the same filter (inertia feed-forward; the motor inertia reflected through N^2
            # dominates the torque a sine needs)
            if self.follow_acceleration:
                acc = min(max((self._v - v_old) / self.period, -self.a_max), self.a_max)
                self._a += self._alpha * (acc - self._a)
            self._p = demand
            lead = self.follow_lead
            return Reference(demand + lead * self._v, self._v + lead * self._a, self._a, False)
        self._tau += self.period
        p, v, _ = self._move.sample(self._tau)
        a = self._move.sample(self._tau + self.lead)[2]   # inertia feed-forward leads the hold delay
        if self._tau >= self._move.duration:
            self._move = None                       # arrived exactly; a changed demand is planned next
        self._p, self._v, self._a = p, v, 0.0
        self._slopes = []
        return Reference(p, v, a, self._move is not None, broke_away=broke)
