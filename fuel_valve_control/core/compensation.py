"""Friction compensation strategies for the state-feedback laws (SPEC §3, §6).

Each strategy returns, once per period, the torque to add to the motor command (N*m at the
motor) and its belief of the friction on both shafts (fed to the observer as known loads).
Friction estimates are signed torques *opposing* motion as seen by the shaft: a positive
estimate is friction acting toward closed (the shaft moves toward open).

* :class:`FriedlandPark` (modes ``observer_fc``, ``kalman_fc``): the dissertation's two
  parallel Friedland–Park observers on the estimated velocities, ``F̂1 + F̂2/N`` added.
* :class:`StictionGain` (mode ``fc_gain``): appendix A's fixed stiction-breaking term, a
  torque of ``gain x Ts(Δp)`` in the direction of the error outside the deadband.
* :class:`ReferenceFeedforward` (mode ``observer_ff``): friction feed-forward in the direction
  the *reference* moves (known in advance, noise free), sized from the Δp-scheduled friction
  model, static level while the valve is at rest, and adapted on line by the Friedland–Park
  update while the valve slides (so friction that differs from the model is learned).
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

from ..common.contract import RESOLVER_COUNT_RAD
from .friction_observer import FrictionObserver
from .model import NominalModel
from .trajectory import Move, TrajectoryShaper

#: a clocked move's breakaway is read as the shaper reads a waiting move's: a slide
TRAJECTORY_BREAKAWAY_WINDOW = TrajectoryShaper.BREAKAWAY_WINDOW
TRAJECTORY_BREAKAWAY_SLIDE = TrajectoryShaper.BREAKAWAY_SLIDE


@dataclass
class Context:
    """What a compensator may use this period (valve-side units unless named motor)."""

    pressure_kpa: float
    th1: float                  # estimated gear-output angle, rad
    w1: float                   # estimated gear-output velocity, rad/s
    thl: float                  # estimated valve angle, rad
    wl: float                   # estimated valve velocity, rad/s
    valve_speed_meas: float     # valve velocity from the valve resolver (short average), rad/s
    applied_torque: float       # motor torque applied last period, N*m (motor)
    ref_velocity: float         # reference velocity, rad/s
    ref_acceleration: float     # reference acceleration, rad/s²
    ref_moving: bool            # a planned move is under way
    error: float                # demand - valve angle estimate, rad
    outside_deadband: bool      # |error| beyond the friction-sized deadband (hold phase)
    armed: float = 0.0          # direction of a planned move waiting for breakaway (Reference.armed)
    broke_away: bool = False    # the valve broke away this period and started that move
    held_load: float = 0.0      # steady valve load beyond the known one the law holds, N*m (+ toward open)
    #: the held load is known: learned from both edges of the static band, consistently
    #: (:attr:`~.integral_policy.SlipEdges.known`); False: nothing learned yet, or from one edge's
    #: prior or from edges that contradict each other (it may be off by the static friction)
    held_load_known: bool = False
    #: the valve resolver's angle averaged over the speed window, rad (None: not given)
    valve_filtered: float | None = None
    #: this period's valve resolver sample, rad (None: not given)
    valve_meas: float | None = None
    #: the coupling's twist from the two resolvers, motor angle / N - valve angle, rad
    #: (+ winds toward open; None: not given)
    twist_meas: float | None = None
    #: the planned move under way (:class:`~.trajectory.Move`; None: none, or not given) and the
    #: time into it its acceleration is sampled at this period (the shaper's clock plus its
    #: feed-forward lead), s: the coupling-snap feed-forward's plan (``ff.snap_fit_cap``, h27k)
    move: Move | None = None
    move_time: float = 0.0
    #: the static valve friction the hold has met, half the width of the static band its relax slips
    #: showed from both edges, consistently (N*m, friction alone: a steady load cancels; None: the
    #: band is not known; :attr:`~.integral_policy.SlipEdges.static_nm`)
    hold_static_nm: float | None = None


@dataclass
class _MoveRead:
    """A clocked planned move's breakaway reading (:meth:`ReferenceFeedforward._read_move_breakaway`)."""
    way: float                        # the move's direction, ±1
    start: float                      # the valve angle at the move's start, rad
    #: the valve samples of the latest periods, rad (the slide test's window)
    recent: deque = field(default_factory=lambda: deque(maxlen=TRAJECTORY_BREAKAWAY_WINDOW + 1))
    done: bool = False                # read (or nothing to read: the valve was not at rest)
    stuck_nm: float | None = None     # the static friction met in the latest stuck period, N*m
    leaving_nm: float | None = None   # ... in the first period seen leaving, N*m (None while stuck)
    #: (valve sample rad, coupling torque net of the loads N*m) of the periods after the slide
    slide: list = field(default_factory=list)
    #: the valve's friction while sliding, coupling torque less J_L x its acceleration, N*m
    sliding_nm: list = field(default_factory=list)
    #: (``ff.slide_lowers_wrong_dp_cap``) the least cap (x the schedule) the sliding reading may set
    #: when the move's cap was a cut only a misread Δp explains; None: the sliding reading only raises
    slide_floor: float | None = None
    #: periods of the move read so far with the valve still within half a breakaway of its start
    stuck_periods: int = 0
    #: the largest valve friction level (N*m, valve side, the move's way) fed while the reading was not
    #: made yet (``ff.wrong_dp_cut_retreat``: what wound the coupling before the cut)
    fed_nm: float = 0.0


def _sat(x: float) -> float:
    return -1.0 if x < -1.0 else (1.0 if x > 1.0 else x)


class Compensator:
    """No compensation (mode ``observer``)."""

    #: whether the state observer takes this compensator's friction belief as a known input
    feeds_observer = True
    #: whether the law gives the breakaway surplus Ts - Tc back when a valve held short of its
    #: target breaks away (:meth:`StateFeedbackLaw._relieve_breakaway`)
    relieves_breakaway = False

    def reset(self, model: NominalModel, pressure_kpa: float) -> None:
        pass

    def update(self, ctx: Context) -> tuple[float, float, float]:
        """(torque to add at the motor, motor friction estimate, valve friction estimate)."""
        return 0.0, 0.0, 0.0

    def scale(self, pressure_kpa: float) -> tuple[float, float] | None:
        """Learned / nominal Coulomb level of (motor, valve) at ``pressure_kpa`` kPa; None for
        a strategy that learns nothing."""
        return None

    def reference_moves(self, ctx: Context) -> bool:
        """Whether the reference counts as moving (else the law holds)."""
        return ctx.ref_moving

    def jump_ratio(self) -> float | None:
        """The stick-slip jump this compensator expects, over the model's (friction and
        coupling it has met), or None when it has met nothing."""
        return None

    #: motor torque (N*m) of this period's coupling-snap feed-forward, part of :meth:`update`'s
    #: output (0: none; :meth:`ReferenceFeedforward._coupling_snap`)
    snap_nm = 0.0

    def coupling_misfit(self, softness: float) -> None:
        """The law read the coupling at its holds as K_model / K = ``softness`` (1: the
        model's, or within the reading's scatter of it; :class:`HoldStiffness`)."""

    def wait_over(self) -> bool:
        """Whether a move waiting for breakaway should start on its clock now."""
        return False

    def rescheduled(self, model: NominalModel, old_kpa: float, new_kpa: float, position_rad: float) -> None:
        """The friction schedule moved from ``old_kpa`` to ``new_kpa`` (kPa; the Δp cross-check)
        with the valve near ``position_rad``: re-seed from the new schedule (what this strategy
        learned was learned against the old one)."""
        self.reset(model, new_kpa)


def _non_friction_accels(model: NominalModel, ctx: Context) -> tuple[float, float]:
    """Accelerations from every torque but friction: (motor shaft, rad/s² motor units; valve)."""
    n = model.gear_ratio
    twist = model.coupling_stiffness_nm_per_rad * (ctx.th1 - ctx.thl) \
        + model.coupling_damping_nms * (ctx.w1 - ctx.wl)
    wm = (ctx.applied_torque - twist / n - model.motor_viscous_nms * n * ctx.w1) / model.motor_inertia_kgm2
    wv = (twist - model.valve_viscous_nms * ctx.wl - model.load_torque(ctx.thl, ctx.pressure_kpa)) \
        / model.valve_inertia_kgm2
    return wm, wv


def _seed_levels(motor: FrictionObserver, valve: FrictionObserver, model: NominalModel, pressure_kpa: float) -> None:
    """Start both shafts' observers at the nominal Coulomb levels (as accelerations, rad/s²)."""
    fl = model.friction(pressure_kpa)
    motor.reset(fl.motor_coulomb_nm / model.motor_inertia_kgm2)
    valve.reset(fl.valve_coulomb_nm / model.valve_inertia_kgm2)


class FriedlandPark(Compensator):
    """Two parallel Friedland–Park observers (motor and valve shaft) on estimated velocities,
    ``F̂1 + F̂2/N`` fed forward (the dissertation's structure), made to work (issue 14):

    * the estimates are *not* fed back into the state observer as known inputs: signed by the
      estimated velocity they would close a fast loop through the observer that flips sign
      every period at rest; the observer's disturbance states absorb friction instead;
    * the sign is a boundary layer ``sat(v̂ / v_b)``, ``v_b`` = one valve resolver count per
      loop period (N times that on the motor shaft): below it the velocity is not resolved;
    * adaptation runs only while the valve resolver itself shows sliding (``stuck_speed``) the
      way the estimate goes, so a stuck valve never teaches the observers its stiction reaction.

    * the valve term acts only while the reference moves (a planned move, or a followed
      demand faster than the boundary velocity): holding, the valve-velocity estimate of a
      stuck valve follows the motor through the coupling model and a ±Tc term signed by it
      kept a ~20 Hz motor oscillation going that shook the valve loose (observer_fc 9.6e-3 rad
      in ``load_step``, 1.0e-2 in ``startup``) and, on a K x 0.1 coupling, a 300 rad/s one at
      31-37 A (kalman_fc).  Holding, the integral action carries the friction.

    * a valve held stuck short of its target gets the breakaway surplus ``Ts - Tc`` back
      out of the drive the moment it breaks away (``relieves_breakaway``): a 2 % step stops
      short as the reference decelerates, and the stuck ramp's breakaway then overshot by the
      surplus (observer_fc 22-34 %, seeds 0-7; now 0-2.4 %; kalman_fc's startup limit cycle of
      2.4e-3 rad was the same surplus both ways).

    Known floor (measured, issue 14): a breakaway from rest travels at least the stick-slip
    jump ``2 (Ts - Tc)/K`` (4.6e-3 rad at max Δp), so a move ends anywhere inside ±half a jump
    (the integral deadband): on 3 of 8 seeds the 2 % step ends 2.0-2.5e-3 rad off, beyond the
    0.1° band.  Sub-jump moves need a pulse before breakaway (``observer_fp``).
    """

    feeds_observer = False
    relieves_breakaway = True

    def __init__(self, motor: FrictionObserver, valve: FrictionObserver, fraction: float = 1.0,
                 stuck_speed: float = 0.0):
        self.motor, self.valve, self.fraction = motor, valve, fraction
        self.stuck_speed = stuck_speed
        self.model: NominalModel | None = None

    def reset(self, model, pressure_kpa):
        self.model = model
        _seed_levels(self.motor, self.valve, model, pressure_kpa)

    def update(self, ctx):
        m = self.model
        vm = m.gear_ratio * ctx.w1
        sliding = abs(ctx.valve_speed_meas) > self.stuck_speed and ctx.valve_speed_meas * ctx.wl > 0.0
        if sliding:
            wm, wv = _non_friction_accels(m, ctx)
            self.motor.update(vm, wm)
            self.valve.update(ctx.wl, wv)
        fm = m.motor_inertia_kgm2 * self.motor.compensation(vm)
        # the valve term only while the reference moves (faster than one valve count per
        # period when a demand is followed): then the estimated valve velocity is motion, not
        # the stuck valve's estimate following the motor through the coupling model (holding
        # with it on hunted: observer_fc load_step 9.6e-3 rad, startup 1.0e-2 rad).  Gating it
        # on measured sliding instead came too late: the drive, already at breakaway, got +Tc
        # on top (2 % step overshoot 150 %)
        fv = m.valve_inertia_kgm2 * self.valve.compensation(ctx.wl) if self.reference_moves(ctx) else 0.0
        return self.fraction * (fm + fv / m.gear_ratio), self.fraction * fm, self.fraction * fv

    def reference_moves(self, ctx: Context) -> bool:
        """A planned move, or a followed demand faster than one valve count per period."""
        return ctx.ref_moving or abs(ctx.ref_velocity) > self.valve.boundary_velocity


class StictionGain(Compensator):
    """Appendix A: a fixed stiction-breaking torque ``gain x Ts(Δp)`` toward the target,
    ramped over ``error_scale`` and applied only outside the deadband while holding."""

    def __init__(self, gain: float, error_scale: float):
        self.gain, self.error_scale = gain, error_scale
        self.model: NominalModel | None = None

    def reset(self, model, pressure_kpa):
        self.model = model

    def update(self, ctx):
        if not ctx.outside_deadband or ctx.ref_moving:
            return 0.0, 0.0, 0.0
        ts = self.model.friction(ctx.pressure_kpa).valve_static_nm
        return self.gain * ts / self.model.gear_ratio * _sat(ctx.error / self.error_scale), 0.0, 0.0


def _merged_softness(reading: float, estimate: float, readings: int,
                     bounds: tuple[float, float]) -> tuple[float, float]:
    """A coupling reading (K_model / K) clipped to ``bounds``, and the persistent estimate it
    makes: the first plausible reading sets it, each later one moves its logarithm halfway (the
    coupling does not change from move to move or hold to hold; one reading's scatter is halved).
    Returns ``(clipped reading, new estimate)``."""
    reading = min(max(reading, bounds[0]), bounds[1])
    return reading, (reading if readings == 0 else math.sqrt(estimate * reading))


class CouplingStiffness:
    """The coupling's stiffness read in breakaway wind-ups, as ``softness`` = K_model / K.

    While a move waits for breakaway the valve is stuck and the drive winds the coupling up:
    every period gives a pair (twist θ1 - θL, rad; drive torque N u, N*m valve side, the
    move's way).  The least-squares slope of torque over twist is the stiffness met: a slope,
    so the constant part of the drive that is not twist (the turning motor's Coulomb friction,
    a cocked hold's offset) does not enter.  Pairs count only once the twist has grown
    ``start_rad`` past its value at arming (before that the motor's own static friction takes
    the torque and the twist does not move).  A wind-up is *plausible* when it spans at least
    ``min_span_rad`` of twist over ``min_points`` pairs, the slope is positive and the pairs lie
    on a line (r² >= ``min_r2``); only plausible wind-ups update the estimate (a valve held
    cocked near breakaway lets go within a few periods: its 1-2 count wind-up read K x 2-20
    and gave the retreat a tenth of what it needed, campaign seed 1017).  The coupling does
    not change from move to move, so the estimate persists and each plausible reading moves
    its logarithm halfway (one noisy reading cannot throw it); bounded to ``bounds``,
    forgotten on :meth:`reset` (then 1: the model's coupling).
    """

    def __init__(self, start_rad: float, min_span_rad: float, min_points: int = 8, min_r2: float = 0.25,
                 bounds: tuple[float, float] = (0.5, 20.0)):
        self.start_rad, self.min_span_rad = start_rad, min_span_rad
        self.min_points, self.min_r2, self.bounds = min_points, min_r2, bounds
        #: K_model / K, the persistent estimate (1 before the first plausible wind-up)
        self.softness = 1.0
        #: plausible wind-ups read since the last reset
        self.readings = 0
        #: the latest wind-up's reading (K_model / K), None when it was not plausible
        self.last: float | None = None
        self._twist0: float | None = None
        self._sums = [0.0] * 6          # n, Σx, Σy, Σxx, Σxy, Σyy (x twist rad, y torque N*m)

    def reset(self) -> None:
        self.softness, self.readings, self.last = 1.0, 0, None
        self._twist0 = None

    def begin(self, twist_rad: float) -> None:
        """A wind-up starts (twist signed the move's way)."""
        self._twist0 = twist_rad
        self._sums = [0.0] * 6

    def add(self, twist_rad: float, drive_nm: float) -> None:
        """One wind-up period: twist (rad) and drive torque (N*m, valve side), both signed the
        move's way."""
        if self._twist0 is None or twist_rad - self._twist0 < self.start_rad:
            return
        x, y = twist_rad, drive_nm
        for i, v in enumerate((1.0, x, y, x * x, x * y, y * y)):
            self._sums[i] += v

    def finish(self, k_model: float) -> float | None:
        """The wind-up ended in breakaway: update the estimate from it if it is plausible;
        returns the reading (K_model / K) or None."""
        n, sx, sy, sxx, sxy, syy = self._sums
        self._twist0, self.last = None, None
        if n < self.min_points:
            return None
        vxx, vxy, vyy = sxx - sx * sx / n, sxy - sx * sy / n, syy - sy * sy / n
        if vxx < (self.min_span_rad ** 2) * n / 12.0 or vxy <= 0.0 or vyy <= 0.0 \
                or vxy * vxy < self.min_r2 * vxx * vyy:
            return None          # too little twist (a uniform spread of min_span has variance span²/12), or no line
        reading, self.softness = _merged_softness(k_model * vxx / vxy, self.softness, self.readings, self.bounds)
        self.readings += 1
        self.last = reading
        return reading


class HoldStiffness:
    """The coupling's stiffness read at every hold, as ``softness`` = K_model / K (h24k).

    At rest (gear output and valve still, no planned move) the motor side is in static
    balance: the coupling carries the drive, ``K (θm/N - θL) = N (u - f_m)`` with ``u`` the
    applied motor torque and ``|f_m| <= Ts_m`` the gear's static friction (N*m, motor side),
    whatever holds the valve (its friction, the spring, the flow torque or a stop).  The twist
    comes from the two resolvers, so ``K_model * twist / (N u)`` is K_model / K up to the relative
    scatter ``bound = N Ts_m * FRICTION_MARGIN / |N u| + (COUNT_MARGIN counts + BACKLASH_RAD / 2) / |twist|``
    (the gear's static friction, up to the box's x 3, the valve resolver's counts and the gear's
    play).  A rest of ``rest_periods`` periods gives one reading (the means of twist and drive
    over it); a reading is plausible only when ``bound <= max_bound`` (a drive too small to
    read against the gear's friction, a twist of a few counts: no reading).  At the nominal
    valve's 20 % hold (spring and flow torque ~9-10 N*m) the bound is 0.05 on the model's
    coupling and 0.17 on one of K x 0.3 (the same torque, 3.3x the twist).  The coupling does
    not change from hold to hold, so the estimate persists: the first plausible reading sets it
    and each later one moves its logarithm halfway (as :class:`CouplingStiffness`); bounded to
    ``bounds``; forgotten on :meth:`reset` (then 1).

    :attr:`misfit` is the softness *used*: 1 while the estimate lies within ``tolerance`` plus
    the latest reading's scatter bound of the model's coupling (so a plant on the model's
    coupling is left exactly as it was: its readings lie within their bound of 1), else the
    estimate.  ``tolerance`` (``integral.stiffness_tolerance``): h24k used the snap
    feed-forward's, 0.25 (a 10 % misreading of K moved a 2 % step's overshoot 0 -> 6 %,
    :meth:`ReferenceFeedforward._coupling_snap`); h25k 0.5: the hold's readings scatter beyond
    their bound from rest to rest (campaign seed 1195, K x 0.77 = softness 1.29: readings
    1.21-1.42, bounds 0.07-0.14), and at 0.25 a softness of 1.29 sat on the gate -- its
    estimate crossed at 1.40, the jump floor acted and the first plateau hunted (575 %
    overshoot; main 98 %).  At 0.5 only a coupling softer than ~x 0.6 is acted on (the grid's
    x 0.5 / 0.3 / 0.1 all are); between, the model-based loop holds as on main.
    """

    FRICTION_MARGIN = 3.0     # the box's highest friction scale (the gear's static friction too)
    COUNT_MARGIN = 2.0        # resolver counts: quantisation and ~1 count rms noise
    #: rad: the gear backlash the robustness box allows (0…2 mrad, benchmarks/robustness.py); at
    #: rest the drive has closed the play its way, so the twist reads up to half of it too far
    #: (always softer): campaign seed 1195 (K x 0.77, backlash 1.6 mrad, friction x 2.4) read
    #: 1.33-1.42 for 1.29 with the play left out of the bound, acted on it and hunted
    BACKLASH_RAD = 2e-3

    def __init__(self, k_model: float, gear_ratio: float, motor_static_nm: float, count_rad: float,
                 rest_periods: int = 20, max_bound: float = 0.5, tolerance: float = 0.5,
                 bounds: tuple[float, float] = (0.5, 20.0)):
        self.k_model, self.n, self.motor_static_nm, self.count_rad = k_model, gear_ratio, motor_static_nm, count_rad
        self.rest_periods, self.max_bound, self.tolerance, self.bounds = rest_periods, max_bound, tolerance, bounds
        #: K_model / K, the persistent estimate (1 before the first plausible reading)
        self.softness = 1.0
        #: plausible readings since the last reset
        self.readings = 0
        #: the latest plausible reading (K_model / K) and its relative scatter bound, None before one
        self.last: tuple[float, float] | None = None
        self._sums = [0, 0.0, 0.0]      # periods at rest, Σ twist rad, Σ drive N*m (valve side)

    def reset(self) -> None:
        self.softness, self.readings, self.last = 1.0, 0, None
        self._sums = [0, 0.0, 0.0]

    @property
    def misfit(self) -> float:
        """K_model / K to act on: the estimate once it lies beyond ``tolerance`` + the latest
        reading's scatter bound of 1, else 1."""
        if self.last is None:
            return 1.0
        return self.softness if abs(self.softness - 1.0) > self.tolerance + self.last[1] else 1.0

    def update(self, at_rest: bool, twist_rad: float | None, drive_nm: float) -> float | None:
        """One period: ``at_rest`` (gear output and valve still, no planned move), the
        resolvers' twist (rad, + winds toward open) and the applied drive (N*m at the motor).
        Returns the reading taken this period (K_model / K) or None."""
        if not at_rest or twist_rad is None:
            self._sums = [0, 0.0, 0.0]
            return None
        self._sums[0] += 1
        self._sums[1] += twist_rad
        self._sums[2] += self.n * drive_nm
        if self._sums[0] != self.rest_periods:
            return None                 # one reading per rest, once it has lasted rest_periods
        twist, drive = self._sums[1] / self.rest_periods, self._sums[2] / self.rest_periods
        if twist * drive <= 0.0:
            return None
        bound = (self.n * self.motor_static_nm * self.FRICTION_MARGIN / abs(drive)
                 + (self.COUNT_MARGIN * self.count_rad + 0.5 * self.BACKLASH_RAD) / abs(twist))
        if bound > self.max_bound:
            return None
        reading, self.softness = _merged_softness(self.k_model * twist / drive, self.softness, self.readings,
                                                  self.bounds)
        self.readings += 1
        self.last = (reading, bound)
        return reading


class ReferenceFeedforward(Compensator):
    """Friction feed-forward in the reference's direction, Δp-scheduled and adapted.

    ``direction = sat(v_ref / v_smooth)``; the magnitude is the static level while the valve
    is at rest (so it breaks away when the reference starts) and the Coulomb level while it
    slides.  Both levels scale with the ratio ``adapted Coulomb / nominal Coulomb``; the
    adaptation is the Friedland–Park update run on the *measured* valve speed while the valve
    slides in the reference direction, so its sign never comes from noise.

    **Breakaway** (a planned move waiting at its start, ``ctx.armed``; issue 14): the valve
    feed-forward ramps from ``ramp_start`` x the learned static level upward by one learned
    static level per ``ramp_time`` seconds until the valve lets go (the move's clock then
    starts, :class:`~.trajectory.TrajectoryShaper`).  The drive torque at that moment is the
    static friction met: ``s (N u - load(θL)) - N Tc_motor`` (valve side, ``s`` the direction;
    read from the applied motor torque, so the coupling stiffness does not enter), and
    met / scheduled static level becomes the friction scale of both levels (the valve
    Friedland–Park level is re-seeded with it), so the sliding phase gets the Coulomb level of
    *this* valve, not the model's, from its first period, and the next move's ramp starts near
    its breakaway.  The scale is bounded to ``scale_bounds`` (wide: a wrong Δp reading moves the
    friction met by up to x11 against the schedule, friction wear x0.5…3 on top) and forgotten
    on :meth:`reset`.  It is the mean of the latest reading each way (a steady load the model
    does not know cancels) and is read only from a valve that let go while the ramp rose; the
    ramp starts where a hold pressing the move's way left the drive.

    **h17b**: the breakaway reading is net of the steady load the hold has learned
    (``ctx.held_load``); a wait ends on the clock (:meth:`wait_over`) once the drive passes
    ``WAIT_OVERRUN`` x the breakaway this valve has shown plus ``WAIT_MARGIN`` x the scheduled
    level; the retreat acts only while the valve is measured sliding and lapses with its move.

    **h19b**: readings are kept gross of the held load and netted of the one in force when used
    (:meth:`_reading`; the wait-over test compares the drive net of it too); the retreat is sized
    on load-free friction (:meth:`_retreat_scale`: the two ways' mean, a one-way reading only net
    of a held load known from both band edges, else no lower than ``RAMP_MIN_SCALE``).

    **Coupling** (h16g): every wind-up also reads the coupling stiffness
    (:class:`CouplingStiffness`, ``coupling_softness`` = K_model / K); it sizes the take-back
    of the stored static-Coulomb twist, the hold's deadband (:meth:`jump_ratio`) and, on a
    coupling measurably softer than the model, the snap feed-forward of planned moves
    (:meth:`_coupling_snap`).
    """

    #: the breakaway ramp stops at this multiple of the nominal breakaway level at max Δp
    RAMP_CAP = 4.0
    #: bounds of K_model / K_met read in a wind-up (the SPEC box reaches K x 0.1)
    SOFT_BOUNDS = (0.5, 20.0)
    #: a wind-up reads the stiffness once the twist has grown this many valve resolver counts,
    #: and only if it spans at least WINDUP_MIN_COUNTS (plausibility, :class:`CouplingStiffness`)
    WINDUP_START_COUNTS = 2.0
    WINDUP_MIN_COUNTS = 6.0
    #: the friction scale is read at a breakaway only if the ramp had risen this fraction of
    #: the breakaway level (5 periods at the default 50 ms ramp)
    MIN_RISE = 0.1
    #: the breakaway ramp's slope is at least this multiple of the scheduled level per ramp time
    #: (the lowest friction scale the SPEC box holds)
    RAMP_MIN_SCALE = 0.5
    #: the coupling-snap feed-forward acts on K_model / K - 1 beyond this (:meth:`_coupling_snap`)
    SNAP_TOLERANCE = 0.25
    #: a waiting move starts on its clock once the drive, the move's way beyond the known load,
    #: exceeds WAIT_OVERRUN x the breakaway this valve has shown plus WAIT_MARGIN x the scheduled
    #: level (:meth:`wait_over`)
    WAIT_OVERRUN = 1.5
    WAIT_MARGIN = 0.25
    #: a breakaway reading is kept only if the valve (its resolver angle averaged over the speed
    #: window) has gone CONFIRM_COUNTS resolver counts the move's way from where it was at arming
    #: within CONFIRM_PERIODS periods of the breakaway (:meth:`_confirm`)
    CONFIRM_COUNTS = 4.0
    CONFIRM_PERIODS = 6
    #: periods of sliding friction (coupling torque less the valve's inertia torque) averaged
    #: before a move's cap may be raised to it (:meth:`_read_move_breakaway`): one estimate
    #: scatters ~0.5 N*m (the second difference of a resolver with ~1 count of noise), and a
    #: 20 ms move that lets go 6 ms in slides ~10 periods before it decelerates
    SLIDE_PERIODS = 6
    #: a clocked move's breakaway reading caps its feed-forward only if its midpoint is at least
    #: this multiple of the scheduled static level, the least friction the valve can have (the SPEC
    #: box's lowest friction scale, as RAMP_MIN_SCALE): below it the valve let go with less torque
    #: on the coupling than any friction of the box holds, i.e. a load that neither the model nor the
    #: hold knows helped the move, and the reading says nothing of the friction
    #: (:meth:`_read_move_breakaway`; h24g, campaign seeds 1004, 1043, 3021: midpoints -2.6 ... 0.38 x
    #: on valves of 1.15-2.2 x with 5-10 N*m of unlearned load helping their closing moves; the
    #: adaptation grid's valves of 0.5 x read 0.54-0.61 x)
    FLOOR_SCALE = RAMP_MIN_SCALE
    #: periods over which the wind-up reads the gear output's acceleration (a one-period
    #: difference of the velocity estimate scattered the small wind-ups at Δp 0: r² 0.25)
    ACCEL_WINDOW = 4

    def __init__(self, motor: FrictionObserver, valve: FrictionObserver, velocity_smoothing: float,
                 stuck_speed: float, static_start: bool = True, fraction: float = 1.0, period_s: float = 1e-3,
                 ramp_time: float = 0.05, ramp_start: float = 0.4, scale_bounds: tuple[float, float] = (0.1, 30.0),
                 retreat_periods: int = 0, count_rad: float = RESOLVER_COUNT_RAD, read_breakaway: bool = False,
                 breakaway_rad: float = 3.0 * RESOLVER_COUNT_RAD, read_wrong_dp: bool = False,
                 snap_fit_cap: bool = False, snap_cap_nm: float = math.inf,
                 slide_lowers_wrong_dp_cap: bool = False, band_start: bool = False, unconfirmed_start: bool = False,
                 wrong_dp_cut_retreat: bool = False):
        #: ``ff.wrong_dp_cut_retreat`` (h33g): a move cut because only a misread Δp explains its reading
        #: (``read_wrong_dp``) takes back the coupling torque it carries at the cut beyond the cut's
        #: Coulomb level, over one period of the valve on the coupling (:meth:`_read_move_breakaway`)
        self.wrong_dp_cut_retreat = wrong_dp_cut_retreat
        #: the retreat (N*m, valve side) the latest such cut took back (diagnostics and tests; None: none)
        self.cut_retreat_nm: float | None = None
        #: ``ff.unconfirmed_dp_start`` (h29d): while the Δp told is unconfirmed and a misread Δp would
        #: help a clocked move, its stuck valve's level starts at the least friction any Δp explains and
        #: rises to the schedule over a quarter of the valve's period on the coupling (:meth:`_start_cap`)
        self.unconfirmed_start = unconfirmed_start
        #: ``ff.band_starts_wrong_dp_move`` (h29d): while a clocked planned move's valve still sticks,
        #: its valve level is at most the static friction the hold's band showed (``ctx.hold_static_nm``)
        #: where that is below the least the valve can have at the Δp told (:meth:`_start_cap`)
        self.band_start = band_start
        #: the cap (x the schedule) the latest move started under (:meth:`_start_cap`; None: none;
        #: diagnostics and tests)
        self.start_cap: float | None = None
        #: ``ff.slide_lowers_wrong_dp_cap`` (h28d): a move cut because a misread Δp explains its
        #: reading (``read_wrong_dp``) takes the friction it meets while sliding as its cap, lower
        #: or higher, down to the least friction the valve can have at any Δp (:meth:`_read_sliding`)
        self.slide_lowers_wrong_dp_cap = slide_lowers_wrong_dp_cap
        self.motor, self.valve = motor, valve
        #: ``ff.snap_fit_cap`` (h27k): a planned move's coupling-snap term is taken from its plan
        #: (no history lag, its first, positive snap fed) and scaled by one factor for the whole
        #: move so its planned peak plus the move's friction feed-forward fits ``snap_cap_nm``
        #: (motor N*m, the law's current cap), instead of being clipped sample by sample
        #: (:meth:`_coupling_snap`)
        self.snap_fit_cap = snap_fit_cap
        self.snap_cap_nm = snap_cap_nm
        self._snap_move: Move | None = None   # the move the factor below was decided for
        #: the factor (0...1) on the snap term of the move under way (diagnostics and tests)
        self.snap_factor = 1.0
        #: clocked planned moves: read the static friction the valve lets go at from the coupling's
        #: twist and cap the move's valve level at it (:meth:`_read_move_breakaway`, h21g)
        self.read_breakaway = read_breakaway
        self.breakaway_rad = breakaway_rad
        #: a move's reading below the least friction the valve can have at the Δp told is a Δp
        #: reading above the real one too, not only a load, while the moves' readings both ways
        #: have not confirmed the told Δp (:meth:`_least_friction_nm`, h26d)
        self.read_wrong_dp = read_wrong_dp
        #: the latest clocked move's reading per direction (+1 opening, -1 closing): the midpoint
        #: of its bounds gross of the held load over the scheduled static level then (None before
        #: one).  Kept across :meth:`reset` (the fine stage's hand-back resets the compensator every
        #: plateau), forgotten on :meth:`rescheduled`
        self._way_reading: dict[float, float | None] = {1.0: None, -1.0: None}
        #: the clocked move under way's breakaway reading; None outside planned moves
        self._move_read: _MoveRead | None = None
        #: the cap (x the schedule) on the valve's level for the rest of the move under way, None
        #: when nothing was read in it
        self._move_cap: float | None = None
        #: (lower, upper bound of the static friction met) / scheduled static level of the latest
        #: clocked move's breakaway reading (diagnostics and tests; None before one)
        self.move_reading: tuple[float, float] | None = None
        #: (``ff.read_breakaway_wrong_dp``) the static friction (N*m) a move's reading shows at the
        #: misread Δp that explains it where the told Δp does not (a cut the h24g floor alone would not
        #: make; :meth:`_explaining_static_nm`), for the hold's one-edge held-load prior
        #: (:meth:`.laws.state_feedback.StateFeedbackLaw._reprior_held_load`); None: none since the law took it
        self.wrong_dp_static_nm: float | None = None
        #: the coupling stiffness met in the wind-ups (K_model / K; persistent, plausibility-checked)
        self.coupling = CouplingStiffness(self.WINDUP_START_COUNTS * count_rad, self.WINDUP_MIN_COUNTS * count_rad,
                                          bounds=self.SOFT_BOUNDS)
        #: K_model / K the law has read at its holds beyond the reading's scatter (1: none;
        #: :class:`HoldStiffness`, :meth:`coupling_misfit`); the snap feed-forward's softness
        #: until a wind-up has read one.  The law's, so a reset (the fine stage's hand-back)
        #: keeps it
        self._hold_softness = 1.0
        self.period = period_s
        self._w1: list[float] = []       # rad/s, gear-output velocity estimates of the last wind-up periods
        self._acc: list[float] = []      # the reference accelerations of the last periods of a move, rad/s²
        self.ramp_per_period = period_s / ramp_time if ramp_time > 0 else 1.0
        self.ramp_start = ramp_start
        self.scale_bounds = scale_bounds
        self._armed_periods = 0
        self._armed_dir = 0.0
        self._ramp0 = 0.0                # N*m (valve side), the ramp's level at arming
        self._wait_over = False          # the armed drive passed the breakaway this valve has shown
        #: latest breakaway reading per direction (+1 opening, -1 closing): the drive beyond the
        #: *known* load, signed the move's way, over the scheduled level -- gross of any held
        #: load, so a steady load cancels exactly in the two ways' mean however the held-load
        #: estimate changed between them, and one way's reading is netted of the held load in
        #: force when it is used (:meth:`_reading`)
        self._met = {1.0: None, -1.0: None}
        self.retreat_periods = retreat_periods
        self._retreat_periods = 0
        self._retreat_nm = 0.0
        self._breakaway_move = False     # the levels of the move under way come from its breakaway
        #: static friction met / scheduled at the latest breakaway (None before the first)
        self.breakaway_ratio: float | None = None
        self.static_start = static_start
        self.v_smooth = velocity_smoothing
        self.stuck_speed = stuck_speed
        self.fraction = fraction
        self.model: NominalModel | None = None
        self.count_rad = count_rad
        #: the valve's filtered angle when the latest wait armed (rad)
        self._arm_valve: float | None = None
        #: a breakaway reading not yet confirmed by the valve's slide (:meth:`_confirm`):
        #: [direction, that way's reading before it, breakaway_ratio before it, periods since]
        self._unconfirmed: list | None = None

    def reset(self, model, pressure_kpa):
        self.model = model
        _seed_levels(self.motor, self.valve, model, pressure_kpa)
        self._arm_valve = None
        self._unconfirmed = None
        self._move_read = None
        self._move_cap = None
        self.move_reading = None
        self._armed_periods = 0
        self._armed_dir = 0.0
        self._wait_over = False
        self._retreat_periods = 0
        self._breakaway_move = False
        self.breakaway_ratio = None
        self._met = {1.0: None, -1.0: None}
        self.coupling.reset()

    def coupling_misfit(self, softness: float) -> None:
        self._hold_softness = softness

    @property
    def coupling_softness(self) -> float:
        """K_model / K of the coupling as read in the wind-ups so far (1: the model's)."""
        return self.coupling.softness

    def _breakaway(self, ctx: Context) -> tuple[float, float, float]:
        """A move waiting for breakaway: the static-level ramp; learn when the valve lets go."""
        m = self.model
        n = m.gear_ratio
        fl = m.friction(ctx.pressure_kpa)
        sm, sv = self.scale(ctx.pressure_kpa)
        if ctx.armed:
            if ctx.armed != self._armed_dir:
                self._armed_periods, self._armed_dir = 0, ctx.armed
                self._arm_valve = ctx.valve_filtered
                # where the wind-up starts: with the valve stuck, the gear output's travel
                # against the torque added says how stiff the coupling really is
                self.coupling.begin(ctx.armed * (ctx.th1 - ctx.thl))
                self._w1 = []
                # the ramp starts where the hold left the drive when it already presses the
                # move's way (the law uncocks the drive to the known + held load as the move
                # arms): starting at ramp_start on top of a hold cocked to near breakaway
                # stepped the drive ~4 N*m past it and the valve ran 3x the move (campaign
                # seed 1017: 181 % overshoot and hunting)
                pressed = ctx.armed * (n * ctx.applied_torque - m.load_torque(ctx.thl, ctx.pressure_kpa)
                                       - ctx.held_load)
                self._ramp0 = max(pressed, sv * self.ramp_start * (fl.valve_static_nm + n * fl.motor_coulomb_nm))
            self._armed_periods += 1
            # net of the held load like the readings it is compared with and the ramp's start: a
            # load the hold holds against the move's way (campaign seed 1029, 3.2 N*m toward
            # closed) otherwise counted as drive past breakaway on the first period, every opening
            # wait ended at once and only the load-helped closing breakaways were ever read
            self._wait_over = self._overrun(ctx.armed * (n * ctx.applied_torque - m.load_torque(ctx.thl, ctx.pressure_kpa)
                                                         - ctx.held_load),
                                            fl.valve_static_nm + n * fl.motor_coulomb_nm, ctx.held_load)
            # the drive less what accelerates the gear output (J1 dω1/dt; the ramp is quick
            # against the drivetrain: left in, 15-period wind-ups read the model's coupling as
            # K x 0.5) is what the coupling carries
            self._w1 = (self._w1 + [ctx.w1])[-self.ACCEL_WINDOW - 1:]
            accel = (self._w1[-1] - self._w1[0]) / (self.period * (len(self._w1) - 1)) if len(self._w1) > 1 else 0.0
            self.coupling.add(ctx.armed * (ctx.th1 - ctx.thl), ctx.armed * (n * ctx.applied_torque - m.j1 * accel))
            # capped at RAMP_CAP x the breakaway level at max Δp, not at a multiple of this Δp's:
            # at Δp 0 the motor's Coulomb friction through the gear is as large as the valve's
            # static (friction x3: the ramp stalled at the cap), and the Δp reading may be wrong
            top = self.RAMP_CAP * (m.valve_static_nm + m.valve_static_per_dp_nm + n * m.motor_coulomb_nm)
            # the ramp is on the drivetrain's breakaway level (valve static + the motor's Coulomb
            # through the gear: the motor already turns while the coupling winds up) and carried
            # as a valve torque: the coupling has to transmit all of it at breakaway
            static = fl.valve_static_nm + n * fl.motor_coulomb_nm
            # the ramp rises at no less than RAMP_MIN_SCALE x the scheduled level per ramp time:
            # a scale learned too low (a load the model does not know helping one direction's
            # breakaway read 0.1 x, campaign seed 1006) must not leave the ramp short of the valve
            rise = max(sv, self.RAMP_MIN_SCALE) * self._armed_periods * self.ramp_per_period * static
            level = min(self._ramp0 + rise, top)
            fv = self.fraction * level * ctx.armed
            return fv / n, 0.0, fv
        s = self._armed_dir
        # the valve let go: the drive torque of the period before is the friction met by the
        # whole drivetrain (valve static, and the turning motor's Coulomb through the gear, at
        # Δp 0 as large as the valve's); one scale for both shafts' levels.  Net of the steady
        # load the hold has learned (``held_load``): with one direction read so far, a load the
        # model does not know read as friction (toward the load: negative, the scale at its
        # 0.1 bound and the move's feed-forward a tenth of the friction; campaign seeds 1029,
        # 3019, 4-6 N*m); the two directions' mean cancels what is left of it
        gross = s * (n * ctx.applied_torque - m.load_torque(ctx.thl, ctx.pressure_kpa))
        static = fl.valve_static_nm + n * fl.motor_coulomb_nm
        if static > 0.0:
            # learned only from a valve that let go while the ramp rose (MIN_RISE of the level
            # above its start): one that lets go within a few periods of arming was at
            # breakaway already (a cocked hold, LuGre presliding), and the torque then is not
            # the friction's (campaign seeds 1017, 1010: 0.2-0.35 x read on plants of 0.6-0.9 x)
            if self._armed_periods * self.ramp_per_period >= self.MIN_RISE or self.breakaway_ratio is None:
                # a steady load the model does not know adds to the drive at one direction's
                # breakaway and subtracts at the other's: the mean of the latest reading each
                # way is the friction's alone (campaign seed 1006, 4.5 N*m toward closed: every
                # closing breakaway read 0.1 x, the next ramps stalled and a 4.4e-2 rad move
                # ended 4.8e-2 rad off)
                self._unconfirmed = [s, self._met[s], self.breakaway_ratio, 0]
                self._met[s] = gross / static
                other = self._met[-s]
                raw = self._reading(s, ctx.held_load, static) if other is None else 0.5 * (self._met[s] + other)
                ratio = min(max(raw, self.scale_bounds[0]), self.scale_bounds[1])
                self.breakaway_ratio = ratio
                self.valve.reset(ratio * fl.valve_coulomb_nm / m.valve_inertia_kgm2)
                self.motor.reset(ratio * fl.motor_coulomb_nm / m.motor_inertia_kgm2)
            else:
                ratio = sv
            # the coupling twist stored at breakaway exceeds what sliding needs by the valve's
            # static - Coulomb gap: take it back over one period of the valve on the coupling
            # (the free stick-slip jump takes half of it; over half a period the nominal 2 %
            # step overshot 6.6 %), or the valve runs that far ahead of the move.  The motor's
            # own gap is not stored in the coupling (retreating it too: friction x3 at Δp 0
            # stalled short and overshot 13.6 % on the second breakaway)
            # coupling stiffness met in the wind-ups (:class:`CouplingStiffness`): a coupling
            # softer than the model stores the gap as a larger twist, which takes
            # K_model / K_met times the torque cut and sqrt(K_model / K_met) times as long to
            # take back (on K x 0.3 the nominal retreat left 48 % overshoot)
            self.coupling.finish(m.coupling_stiffness_nm_per_rad)
            soft = self.coupling.softness
            self._retreat_nm = soft * self._retreat_scale(s, ratio, ctx) * max(fl.valve_static_nm - fl.valve_coulomb_nm, 0.0)
            self._retreat_periods = int(round(self.retreat_periods * math.sqrt(soft)))
            self._breakaway_move = True
        self._armed_periods, self._armed_dir, self._wait_over = 0, 0.0, False
        return None

    def _read_move_breakaway(self, ctx: Context) -> None:
        """A clocked planned move from a valve at rest: read the static friction the valve lets go
        at, and cap the valve's friction level for the rest of *this* move at it (h21g).

        While the valve is stuck the coupling carries everything the drive puts on it: the
        coupling torque ``K (θm/N - θL)``, read from the two resolvers (``ctx.twist_meas``) at the
        model's stiffness (over the softness a wind-up has read), less the known load at the valve
        and the steady load the hold holds (``ctx.held_load``), signed the move's way, is the
        friction holding the valve.  Its value in the latest period the valve was still within
        half of ``breakaway_rad`` of its start is the static friction met (a lower bound by at most
        the last period's rise), its value in the first period beyond that an upper bound;
        breakaway is a slide as the shaper reads it (``breakaway_rad`` from the start, 2/3 of it
        within the last BREAKAWAY_WINDOW periods).  If even the upper bound is below the scheduled
        *Coulomb* level -- the valve let go below what the move feeds it to keep sliding, so the
        feed-forward is certainly too large -- then from the next period to the end of the move
        the valve's level (static and Coulomb alike) is at most ``r`` = met (the lower bound) /
        scheduled static level (``scale_bounds[0]`` the least) times the schedule: the valve gets
        the Coulomb level of the friction it has.  Otherwise nothing changes: the gate lies the
        static-Coulomb gap (20 % of the level) below the schedule, beyond the breakaway-to-breakaway
        scatter of the static level (a few %) that a reading of it cannot tell from a lower friction
        (without the gate, a nominal valve read 0.89-1.01 x, lost up to 11 % of its Coulomb
        feed-forward, stopped short and the hold's jump overshot: nominal box seed 2032, 64.9 %).
        One that holds more than the schedule is left to the Friedland-Park update (a cap).
        Nor is a reading whose midpoint is below FLOOR_SCALE x the scheduled static level, the
        least friction the valve can have (h24g): a load neither the model nor the hold knows
        helped that valve let go, and capped at max(reading, 0.1) its move was fed a tenth of the
        schedule on valves of 1.2-2.2 x (campaign seeds 1004, 1043: hunting without the fault main
        has; 3021: a plateau 15 mrad off instead of 6.6), see docs/control_results.md §43.
        A cap may then be raised, never lowered, to the friction the valve meets while it slides
        (:meth:`_read_sliding`): a presliding valve passes half a breakaway before its friction
        peaks and is read low (campaign seed 1137, h22g).
        The cap lapses with the move: the next move starts from the learned level, not from one
        reading (kept across moves as the level itself, a breakaway that an unknown load helped
        left the next move the other way a tenth of its feed-forward; full box 5 runs hunting
        against 3, see docs/control_results.md §31).

        Why: the planned move feeds the scheduled Coulomb level forward from its first period and
        the update adapts only while the valve slides, too late for a ~20 ms move.  On a valve with
        half the scheduled friction (the adaptation grid's friction x 0.5 at max Δp) the valve let
        go at 2.5 of the 5.5 N*m scheduled, 6 ms into the move, and then got 4.4 N*m where it needed
        2.2: the 2 % step overshot 31-37 % (now 0.4-1.6 %).  The reading errs on the safe side
        wherever the model does not know the plant: a coupling softer than the model's (or
        backlash) shows a larger twist for the same torque, i.e. more friction (no cut); an unknown
        load helping the move lowers the static reading by the load and the Coulomb level x r then
        still exceeds what sliding needs (Tc - load) by the load x (1 - Tc/Ts)."""
        if not ctx.ref_moving:
            self._move_read = None
            self._move_cap = None
            return
        if ctx.armed or self._breakaway_move or ctx.valve_meas is None or ctx.twist_meas is None:
            return
        r = self._move_read
        if r is None:
            s = (ctx.ref_velocity > 0.0) - (ctx.ref_velocity < 0.0) or \
                (ctx.ref_acceleration > 0.0) - (ctx.ref_acceleration < 0.0)
            # only a move that starts from a valve at rest has a breakaway to read
            done = s == 0 or abs(ctx.valve_speed_meas) > self.stuck_speed
            self._move_read = r = _MoveRead(float(s), ctx.valve_meas, done=done)
        if r.done:
            if self._move_cap is not None and len(r.sliding_nm) < self.SLIDE_PERIODS:
                self._read_sliding(ctx, r)
            return
        s = r.way
        r.recent.append(ctx.valve_meas)
        travel = s * (ctx.valve_meas - r.start)
        m = self.model
        met = self._coupling_nm(ctx, s)
        if travel <= 0.5 * self.breakaway_rad:
            r.stuck_nm, r.leaving_nm = met, None    # still stuck: the lower bound
            r.stuck_periods += 1
            return
        if r.leaving_nm is None:
            r.leaving_nm = met              # the first period seen leaving: the upper bound
        if r.stuck_nm is None or travel <= self.breakaway_rad \
                or s * (ctx.valve_meas - r.recent[0]) <= TRAJECTORY_BREAKAWAY_SLIDE * self.breakaway_rad:
            return
        r.done = True
        fl = m.friction(ctx.pressure_kpa)
        if fl.valve_static_nm <= 0.0:
            return
        self.move_reading = (r.stuck_nm / fl.valve_static_nm, r.leaving_nm / fl.valve_static_nm)
        lower, upper = r.stuck_nm, max(r.stuck_nm, r.leaving_nm)
        self._way_reading[s] = (0.5 * (lower + upper) + s * ctx.held_load) / fl.valve_static_nm
        floor = self._least_friction_nm(ctx, s) if self.read_wrong_dp else self.FLOOR_SCALE * fl.valve_static_nm
        # a held load learned from one edge only may be off by up to the static level (its prior,
        # :attr:`Context.held_load_known`): the friction met lies between the reading net of it and
        # gross of it, and only what both say is certain (h24g: the adaptation grid's valve at Δp 0
        # told max read 0.50 x net of a one-edge -3.2 N*m, -0.08 x gross, on a valve of 0.09 x)
        spans = [(lower, upper)]
        if not ctx.held_load_known:
            spans.append((lower + s * ctx.held_load, upper + s * ctx.held_load))
        # a cut only where the valve let go below the Coulomb level fed (even the upper bound:
        # else no cut is certain) and the friction met (the bounds' midpoint, its best estimate)
        # is one the valve can have (else what was read is a load helping the move, not friction:
        # h24g, campaign seeds 1004, 1043, 3021)
        if all(floor <= 0.5 * (lo + up) and up < fl.valve_coulomb_nm for lo, up in spans):
            self._move_cap = max(max(lo for lo, _ in spans) / fl.valve_static_nm, self.scale_bounds[0])
            if self.read_wrong_dp and not all(self.FLOOR_SCALE * fl.valve_static_nm <= 0.5 * (lo + up)
                                              for lo, up in spans):
                self.wrong_dp_static_nm = self._explaining_static_nm(ctx, s, min(0.5 * (lo + up) for lo, up in spans))
                if self.slide_lowers_wrong_dp_cap:
                    # the least friction the valve can have at any Δp over the schedule told
                    # (0.5 Ts(0) / Ts(told), 0.045 x at max Δp), never above the usual bound
                    least = min(self.FLOOR_SCALE * m.friction(0.0).valve_static_nm / fl.valve_static_nm,
                                self.scale_bounds[0])
                    r.slide_floor = least
                    self._move_cap = max(max(lo for lo, _ in spans) / fl.valve_static_nm, least)
                # only where the reading is below half the least friction the valve can have at the Δp
                # told (the band start's margin, :meth:`_start_cap`): there the told level wound in many
                # times what the valve needed.  A reading just under that least (campaign seed 1010, LuGre
                # x 0.58 at 5695 kPa told 6206: 0.46-0.53 x) is a valve near the told schedule whose own
                # friction takes the wind-up: retreated there, the move it acted on overshot less (21 -> 9 %)
                # but the run's later plateaus lost 6.4 mrad between them (docs/control_results.md §83)
                if self.wrong_dp_cut_retreat and min(0.5 * (lo + up) for lo, up in spans) \
                        < 0.5 * self.FLOOR_SCALE * fl.valve_static_nm:
                    # the coupling now carries what the drive wound into it while the valve stuck under
                    # the told Δp's level (``met``, N*m beyond the known load); sliding needs the cut's
                    # Coulomb level: take the excess back over one period of the valve on the coupling,
                    # as the waiting move's retreat takes back the scheduled static - Coulomb gap
                    # (:meth:`_breakaway`; here the gap is measured, not scheduled)
                    # (gross of a one-edge held load too, as the cut's spans: only what both say is
                    # certain -- the grid's friction x1 valve at Δp 0 told max carried 3.0 N*m net of a
                    # one-edge -3.17 N*m, -0.17 gross, and let go on time: nothing stored to take back)
                    carried = min([met] + ([met + s * ctx.held_load] if not ctx.held_load_known else []))
                    # and only what the level fed while the valve stuck could have wound in: a move
                    # started under the hold's band (ff.band_starts_wrong_dp_move) was fed less than its
                    # cut, and the coupling it carries is the move's own catch-up, the law's business
                    # (the grid's friction x0.5 valve: a retreat of 0.9 N*m stopped it 3.4 mrad short)
                    self._retreat_nm = max(min(carried, r.fed_nm) - self._move_cap * fl.valve_coulomb_nm, 0.0)
                    self._retreat_periods = int(round(self.retreat_periods * math.sqrt(self.coupling.softness)))
                    self.cut_retreat_nm = self._retreat_nm

    def _start_cap(self, ctx: Context, static_nm: float) -> float | None:
        """``ff.band_starts_wrong_dp_move`` (h29d): the cap (x the scheduled static level
        ``static_nm``, N*m) on the valve's friction level while a clocked planned move's valve still
        sticks (its breakaway not read yet), or None: the static friction the hold's band showed
        from both edges (``ctx.hold_static_nm``) over the schedule, where that is below half of
        FLOOR_SCALE, the least friction the valve can have at the Δp told -- a valve whose band is that
        narrow is not at the Δp told (a misread Δp), and the band is this valve's friction, measured.
        With ``ff.unconfirmed_dp_start`` (off), otherwise, while the Δp told is unconfirmed and a
        misread Δp would help the move: a rise from the least friction at any Δp to the schedule.  Never
        below the least friction the valve can have at any Δp (FLOOR_SCALE x Ts(0) / Ts(told), the
        bound of h28d's cut).  From the move's breakaway reading on, that reading's cap rules.

        Why (h29d, docs/control_results.md §65): the adaptation grid's friction x 0.5 valve at Δp 0
        told max (static 0.25 N*m; band read 0.39 N*m) was fed the schedule's Coulomb level, 4.4 N*m,
        for the 4 periods its coupling took to reach breakaway; the drivetrain wound up by that drive
        carried the valve 3.5 mrad past a 20.9 mrad step (17.6 %) whatever the cap set after it."""
        r = self._move_read
        if r is None or r.done or static_nm <= 0.0:
            return None
        least = self.FLOOR_SCALE * self.model.friction(0.0).valve_static_nm / static_nm
        # below half the least friction the valve can have at the Δp told, as the hold's drive test
        # judges a breakaway (:class:`~.laws.state_feedback.StateFeedbackLaw`): the relax slips read the
        # band's edges low (presliding, ripple: campaign seeds 1052, 1137, 1183 read 0.33-0.50 x on
        # valves of 0.50-0.77 x at the Δp told, and their moves started under a cap at those lost
        # up to 12 mrad over their plateaus)
        if self.band_start and ctx.hold_static_nm is not None \
                and ctx.hold_static_nm / static_nm < 0.5 * self.FLOOR_SCALE:
            self.start_cap = max(ctx.hold_static_nm / static_nm, least)
            return self.start_cap
        if self.unconfirmed_start and self.read_wrong_dp and r.way \
                and self._least_friction_nm(ctx, r.way) < self.FLOOR_SCALE * static_nm:
            m = self.model
            # a quarter of the valve's period on the coupling (the model's, over the softness the
            # wind-ups read): the time the coupling takes to carry a step of the drive to the valve.
            # The level computed in the move's k-th period is applied through the next one, so it is
            # the rise's at the end of that period, (k + 1) / quarter (k / quarter, measured: the told
            # grid's J -20 % cell overshot 4.1 % against main's 3.8 %; docs/control_results.md §65)
            quarter = 0.5 * math.pi * math.sqrt(m.valve_inertia_kgm2 * self.coupling.softness
                                                / m.coupling_stiffness_nm_per_rad) / self.period
            rise = min((r.stuck_periods + 1) / max(quarter, 1.0), 1.0)
            self.start_cap = least + (1.0 - least) * rise
            return self.start_cap
        return None

    def _least_friction_nm(self, ctx: Context, way: float) -> float:
        """The least a move ``way``'s reading (the coupling torque beyond the known load at the Δp
        told, N*m) can be where the valve's friction, not a load, holds it (``ff.read_breakaway_wrong_dp``,
        h26d): FLOOR_SCALE x the scheduled static level at the Δp told -- and, until the moves'
        readings both ways confirm that Δp, the least over every Δp the transducer may have misread
        (0 ... max) whose flow torque helps the move, where the real flow torque differs from the
        known one by ``load(θ, p) - load(θ, told)`` and the friction is FLOOR_SCALE x that Δp's.
        A reading above it caps the move as any other (:meth:`_read_move_breakaway`).

        Why: a Δp read above the real one schedules friction the valve does not have (x 11 from
        Δp 0 to max) *and* a flow torque toward closed it does not carry, which helps every
        opening move; the reading of the first move after it is then below FLOOR_SCALE at the Δp
        told, the h24g floor took it for a load and the move was fed the schedule's Coulomb level:
        the adaptation grid's valves at Δp 0 told max overshot the 2 % step 38-95 % (read -0.08 ...
        0.1 x gross of the held load; docs/control_results.md §53).  The loads that floor is for
        read far below what any Δp explains (campaign seeds 1004, 1043: -2.7 ... -0.4 x, 5-10 N*m),
        and a steady load cancels in the mean of the two ways' readings, so once both ways were
        read and their mean is a friction the Δp told explains, the Δp is taken as confirmed and
        only its own floor stands (a load helping opening moves reads low opening and high
        closing)."""
        m = self.model
        told = ctx.pressure_kpa
        floor = self.FLOOR_SCALE * m.friction(told).valve_static_nm
        ways = [r for r in self._way_reading.values() if r is not None]
        if len(ways) == 2 and 0.5 * sum(ways) >= self.FLOOR_SCALE:
            return floor
        known = m.load_torque(ctx.valve_meas, told)
        # only a misread flow torque that helps the move (way x (load(p) - known) < 0): one that
        # hinders it reads 0.5 Ts(p) + |that| or more, the range a load helping the move reads on a
        # valve at the Δp told (campaign seeds 1013, 3021: closing moves at 0.38 x midpoints under
        # 5 N*m helping closing, cut there, their plateaus ended up to 4 mrad further off), and the
        # schedule's Coulomb level fed overshoots it by less than half as much
        helps = [self.FLOOR_SCALE * m.friction(p).valve_static_nm + way * (m.load_torque(ctx.valve_meas, p) - known)
                 for p in (0.0, m.pressure_max_kpa)
                 if way * (m.load_torque(ctx.valve_meas, p) - known) < 0.0]
        return min([floor] + helps)

    def _explaining_static_nm(self, ctx: Context, way: float, reading_nm: float) -> float:
        """The static friction (N*m) a move ``way``'s breakaway reading ``reading_nm`` (N*m beyond
        the known load at the Δp told, gross of the held load) shows where a misread Δp explains
        it: the reading less the flow torque ``d`` that Δp (0 or max) would add the move's way
        beyond the known one (``d`` < 0: it helps; the larger estimate if both explain it), never
        above the schedule at the Δp told (the one-edge prior it replaces)."""
        m = self.model
        told = ctx.pressure_kpa
        known = m.load_torque(ctx.valve_meas, told)
        cands = []
        for p in (0.0, m.pressure_max_kpa):
            d = way * (m.load_torque(ctx.valve_meas, p) - known)
            if d < 0.0 and self.FLOOR_SCALE * m.friction(p).valve_static_nm + d <= reading_nm:
                cands.append(reading_nm - d)
        return min(max(cands), m.friction(told).valve_static_nm) if cands else m.friction(told).valve_static_nm

    def _coupling_nm(self, ctx: Context, way: float) -> float:
        """The coupling torque ``K (θm/N - θL)`` from the two resolvers (the model's K over the
        softness a wind-up has read) less the known load at the valve and the held load, signed
        ``way`` (N*m, valve side): the friction the valve meets plus its inertia torque."""
        m = self.model
        k = m.coupling_stiffness_nm_per_rad / self.coupling.softness
        return way * (k * ctx.twist_meas - m.load_torque(ctx.valve_meas, ctx.pressure_kpa) - ctx.held_load)

    def _read_sliding(self, ctx: Context, r: _MoveRead) -> None:
        """A move whose breakaway reading capped its feed-forward: read the friction the valve
        meets while it slides, the coupling torque less ``J_L`` x the valve's acceleration (the
        central second difference of its resolver samples), and once SLIDE_PERIODS estimates are
        in, raise the cap to their mean over the scheduled Coulomb level if that is more (never a
        cut: the static reading decided that).

        Why (h22g, campaign seed 1137, LuGre x 0.71): the static reading takes the valve as stuck
        until its resolver leaves half a breakaway, but a LuGre valve passes 1.5 counts in
        presliding while its friction still rises, and the move's drive rises 15-20 % of the
        static level a period: the 45 mrad closing move read 0.36 x (the coupling then carried
        0.98 x as the valve slid), its feed-forward capped there left it 7.7 mrad short and the
        hold hunted (8 reversals, 33 mrad).  The sliding friction read this way is 0.3-0.6 x
        there and 0.40-0.49 x of the static schedule on the adaptation grid's friction x 0.5 valve
        (Coulomb 0.4 x): it is the level the cap feeds, measured where the valve slides."""
        r.slide.append((ctx.valve_meas, self._coupling_nm(ctx, r.way)))
        if len(r.slide) < 3:
            return
        (v0, _), (v1, met1), (v2, _) = r.slide[-3:]
        m = self.model
        accel = r.way * (v2 - 2.0 * v1 + v0) / (self.period * self.period)
        r.sliding_nm.append(met1 - m.valve_inertia_kgm2 * accel)
        if len(r.sliding_nm) < self.SLIDE_PERIODS:
            return
        fl = m.friction(ctx.pressure_kpa)
        if fl.valve_coulomb_nm > 0.0:
            slid = sum(r.sliding_nm) / len(r.sliding_nm) / fl.valve_coulomb_nm
            # a cut a misread Δp explains (h28d): the static reading's lower bound lags a low friction
            # by the drive's rise per period (~0.5 N*m, 2-3 x a 0.25 N*m valve's friction), the sliding
            # reading measures what the move needs beyond the known load (Tc plus the misread flow torque)
            self._move_cap = max(slid, r.slide_floor) if r.slide_floor is not None else max(self._move_cap, slid)

    def _confirm(self, ctx: Context) -> None:
        """Keep the latest breakaway reading only if the valve really let go: its filtered
        resolver angle goes CONFIRM_COUNTS counts the move's way from where it was when the wait
        armed within CONFIRM_PERIODS periods of the breakaway; else that direction's reading and
        the friction scale return to what they were (the move under way keeps the levels it
        started with).  The shaper's breakaway test compares single resolver samples (3 counts
        from the sample at arming): on a valve with ~1 count rms resolver noise a pair of noisy
        samples passes it while the valve still sticks, and the drive then is no friction met.
        Campaign seed 1073 (Stribeck x 0.95, 5.8 N*m toward closed, 1 count noise, breakaway
        start): three of its four opening readings were such samples, 11-12 periods into a ramp
        started from a hold cocked open (1.18-1.51 x against the first, real, 2.84 x); the
        two ways' mean with a real closing one (-0.77 x, the load helping) came out 0.37 x
        for a valve of 0.95 x, the next opening wait was ended by :meth:`wait_over` far below
        this valve's breakaway, the clocked move stopped 12 mrad short and the hold's jump
        hunted 6.8 mrad (3 reversals).  A real breakaway slides on: the move's clock and the
        stored twist carry the valve counts beyond the detection within a few periods."""
        u = self._unconfirmed
        if u is None:
            return
        s = u[0]
        if ctx.valve_filtered is None or self._arm_valve is None \
                or s * (ctx.valve_filtered - self._arm_valve) >= self.CONFIRM_COUNTS * self.count_rad:
            self._unconfirmed = None
            return
        u[3] += 1
        if u[3] > self.CONFIRM_PERIODS:
            self._met[s], self.breakaway_ratio = u[1], u[2]
            self._unconfirmed = None

    def _retreat_scale(self, direction: float, ratio: float, ctx: Context) -> float:
        """Friction scale (met / scheduled) the retreat of a move broken away in ``direction``
        is sized on.  The gap it takes back, the valve's static - Coulomb friction, is friction
        alone whatever load the valve carries, so it is read where no load enters: the two
        directions' mean (``ratio`` once both were read: a steady load cancels), or one
        direction's reading net of a held load that is known (both edges of the static band met,
        consistently: ``ctx.held_load_known``).  Otherwise the reading carries the error of the
        load estimate (up to the static level itself) and is used only down to RAMP_MIN_SCALE,
        the lowest friction the valve can have: a reading below it is a load helping the move.
        Campaign seeds 1010 (LuGre x 0.58, 1.6 N*m opening load never learned: read 0.33) and
        1029 (Stribeck x 1.5, 3.2 N*m closing load, held 1.33 N*m from one edge: read at the 0.1
        bound): the retreat took back a third and a tenth of the gap, the moves ended 3 mrad past
        their targets and the corrections hunted.  Too large a retreat leaves the valve short
        of the target, where the move's feedback and the hold take it on without a reversal."""
        if self._met[-direction] is not None or ctx.held_load_known:
            return ratio
        return max(ratio, self.RAMP_MIN_SCALE)

    def _reading(self, direction: float, held_nm: float, static_nm: float) -> float | None:
        """The latest breakaway reading ``direction``'s way net of the held load ``held_nm``
        now in force (friction met / scheduled ``static_nm``), None before one.  Netted of the
        held load of its own time instead, a reading went stale as soon as the hold learned the
        load better (campaign seed 1029: the closing reading, 0.52 net of 1.33 N*m, was -0.5 net
        of the 2.45 N*m learned later)."""
        gross = self._met[direction]
        if gross is None or static_nm <= 0.0:
            return None
        return gross - direction * held_nm / static_nm

    def _overrun(self, pressed_nm: float, static_nm: float, held_nm: float = 0.0) -> bool:
        """Whether the drive, ``pressed_nm`` (valve side, the armed move's way beyond the known
        load and the held load ``held_nm``), has passed WAIT_OVERRUN x the breakaway this valve has shown (the latest reading
        this way or the two ways' mean, whichever is larger; ``static_nm`` the scheduled level)
        plus WAIT_MARGIN x the scheduled level.  Before any reading the wait runs its full time
        (a valve three times the model's needs the whole ramp).  A valve that has not let go by
        then is held by something the readings do not know (campaign seed 1006: a 4.5 N*m load
        the model does not know, 1.7 mrad of backlash on a K x 0.31 coupling: the ramp never
        reached breakaway and the 0.25 s wait ate the whole 0.31 s plateau of a 44 mrad move,
        which then ended 46 mrad short); the clocked move's position feedback then takes it."""
        seen = [r for r in (self._reading(self._armed_dir, held_nm, static_nm), self.breakaway_ratio) if r is not None]
        if not seen:
            return False
        return pressed_nm > (self.WAIT_OVERRUN * max(seen) + self.WAIT_MARGIN) * static_nm

    def wait_over(self) -> bool:
        return self._wait_over

    def rescheduled(self, model, old_kpa, new_kpa, position_rad):
        """Keep what the breakaways taught that does not depend on the Δp schedule (h20w): the
        coupling stiffness met in the wind-ups, and the breakaway readings as the drive torques
        they were (N*m beyond the known load, re-expressed against the new known load at
        ``position_rad`` and over the new scheduled level); the friction scale follows them.  The
        true Δp did not change, only the schedule: forgotten (main 807b5de), a valve whose
        reading was rescheduled mid-run restarted from the model's friction and coupling
        (campaign seed 1002, Stribeck x 2.64 at max Δp told 2.1 MPa, breakaway start: the plateau
        after the cross-check's reschedule ended 23.7 mrad off, 15.7 on the clock)."""
        n = model.gear_ratio
        old_fl, new_fl = model.friction(old_kpa), model.friction(new_kpa)
        old_static = old_fl.valve_static_nm + n * old_fl.motor_coulomb_nm
        new_static = new_fl.valve_static_nm + n * new_fl.motor_coulomb_nm
        dl = model.load_torque(position_rad, old_kpa) - model.load_torque(position_rad, new_kpa)
        met = {s: None if r is None else (r * old_static + s * dl) / new_static for s, r in self._met.items()}
        ratio = self.breakaway_ratio
        softness, readings = self.coupling.softness, self.coupling.readings
        self.reset(model, new_kpa)
        self._way_reading = {1.0: None, -1.0: None}     # read against the old schedule (h26d)
        self.wrong_dp_static_nm = None
        self.coupling.softness, self.coupling.readings = softness, readings
        if ratio is None or new_static <= 0.0:
            return
        self._met = met
        both = [r for r in met.values() if r is not None]
        raw = 0.5 * sum(both) if len(both) == 2 else ratio * old_static / new_static
        ratio = min(max(raw, self.scale_bounds[0]), self.scale_bounds[1])
        self.breakaway_ratio = ratio
        self.valve.reset(ratio * new_fl.valve_coulomb_nm / model.valve_inertia_kgm2)
        self.motor.reset(ratio * new_fl.motor_coulomb_nm / model.motor_inertia_kgm2)

    def jump_ratio(self) -> float | None:
        """Friction met at breakaway x K_model / K met in the wind-ups: the jump
        ``2 (Ts - Tc) / K`` of this valve over the model's.  A move started on breakaway does
        not jump, so the hold's jump learner (:class:`~.integral_policy.JumpLearner`) never sees
        how far this valve jumps and the deadband stayed the model's: a move ending 2 mrad
        past a target, just outside a 1.9 mrad deadband, was driven back by a 6.7 mrad jump and
        hunted for the whole 4 s hold (campaign seed 1026, friction x 2, K x 0.85)."""
        if self.breakaway_ratio is None:
            return None
        return self.breakaway_ratio * self.coupling.softness

    def scale(self, pressure_kpa: float) -> tuple[float, float]:
        """Adapted / nominal Coulomb level of (motor, valve)."""
        m = self.model
        fl = m.friction(pressure_kpa)
        sm = m.motor_inertia_kgm2 * self.motor.level / fl.motor_coulomb_nm if fl.motor_coulomb_nm > 0 else 1.0
        sv = m.valve_inertia_kgm2 * self.valve.level / fl.valve_coulomb_nm if fl.valve_coulomb_nm > 0 else 1.0
        return sm, sv

    def update(self, ctx):
        if ctx.armed or (ctx.broke_away and self._armed_dir):
            out = self._breakaway(ctx)
            if out is not None:
                return out
        elif self._armed_dir:
            # the wait timed out (or was ended, :meth:`wait_over`): nothing learned
            self._armed_periods, self._armed_dir, self._wait_over = 0, 0.0, False
        self._confirm(ctx)
        if self.read_breakaway:
            self._read_move_breakaway(ctx)
        m = self.model
        n = m.gear_ratio
        direction = _sat(ctx.ref_velocity / self.v_smooth) if self.v_smooth > 0 else (
            (ctx.ref_velocity > 0) - (ctx.ref_velocity < 0))
        # adapt the levels only while the valve really slides the way the reference goes, and
        # not in a move whose breakaway set them: the Friedland-Park update reads friction
        # through the nominal coupling model, the breakaway reading does not (on a coupling of
        # K x 0.1 the update drove the valve level from the 1.0 N*m met to 7 N*m within one
        # 2 % step: 60 % overshoot)
        if not ctx.ref_moving:
            self._breakaway_move = False
            self._retreat_periods = 0          # a retreat the valve never slid into lapses with its move
        sliding = abs(ctx.valve_speed_meas) > self.stuck_speed and ctx.valve_speed_meas * ctx.ref_velocity > 0
        if sliding and not self._breakaway_move:
            wm, wv = _non_friction_accels(m, ctx)
            self.motor.update(n * ctx.valve_speed_meas, wm)
            self.valve.update(ctx.valve_speed_meas, wv)
        snap_nm = self.snap_nm = self._coupling_snap(ctx)
        at_rest = abs(ctx.valve_speed_meas) <= self.stuck_speed
        # breakaway help: static level while the reference pulls a valve at rest, i.e. when a
        # move starts (accelerating) or, holding, when the error is beyond the deadband
        breakaway = self.static_start and at_rest and ctx.ref_acceleration * direction > 0
        if direction == 0.0:
            return snap_nm, 0.0, 0.0
        fl = m.friction(ctx.pressure_kpa)
        sm, sv = self.scale(ctx.pressure_kpa)
        tm = sm * (fl.motor_static_nm if breakaway else fl.motor_coulomb_nm)
        if self._move_cap is not None:      # this move's breakaway showed less (h21g)
            sv = min(sv, self._move_cap)
        elif self.band_start or self.unconfirmed_start:
            start = self._start_cap(ctx, fl.valve_static_nm)
            if start is not None:
                sv = min(sv, start)
        tv = sv * (fl.valve_static_nm if breakaway else fl.valve_coulomb_nm)
        r = self._move_read
        if r is not None and not r.done:
            r.fed_nm = max(r.fed_nm, tv)
        if self._retreat_periods > 0 and not at_rest:
            # only from a valve that slides: a "breakaway" that was a creep (LuGre presliding
            # read through resolver noise) left the valve stuck with the drive cut by the
            # retreat, 26 mrad short of a 0.4 s plateau (campaign seed 1018)
            self._retreat_periods -= 1
            tv -= self._retreat_nm
        fm, fv = self.fraction * tm * direction, self.fraction * tv * direction
        return fm + fv / n + snap_nm, fm, fv
    def _coupling_snap(self, ctx: Context) -> float:
        """Motor torque (N*m) a coupling softer than the model needs beyond the model's
        feed-forward to make the valve follow a planned move.

        Through a coupling K the valve follows θL(t) when the gear output leads it by
        ``(JL a + load) / K`` (a = θL''), so the drive needs ``J1 JL s / K`` (s the move's snap,
        d⁴θL/dt⁴) beyond the rigid-body ``(J1 + JL) a``.  The model's feed-forward
        (:meth:`~.model.NominalModel.reference_state`) leaves that term out, which the 20 ms
        minimum move absorbs on the model's coupling; on one K_model / K = ``softness`` times
        softer the valve-coupling period reaches the move's length.  The difference
        ``J1 JL (1/K - 1/K_model) s`` is fed forward here, ``s`` the second difference of the
        planned move's acceleration; nothing on the model's coupling (softness 1), nothing
        outside planned moves."""
        if not ctx.ref_moving or ctx.armed:
            self._acc = []
            return 0.0
        self._acc = (self._acc + [ctx.ref_acceleration])[-3:]
        # only the part of K_model / K - 1 beyond the wind-up reading's scatter on the model's
        # coupling (0.91-1.19 over the grid): the term is large (a 10 % misreading moved the
        # 2 % step's overshoot 0 -> 6 %)
        if self.coupling.readings == 0 and self._hold_softness != 1.0:
            # read at the holds, already beyond that reading's scatter (HoldStiffness.misfit)
            excess = self._hold_softness - 1.0
        else:
            excess = self.coupling.softness - 1.0
            excess = math.copysign(max(abs(excess) - self.SNAP_TOLERANCE, 0.0), excess)
        m = self.model
        if self.snap_fit_cap and ctx.move is not None:
            gain = m.j1 * m.valve_inertia_kgm2 * excess / m.coupling_stiffness_nm_per_rad / m.gear_ratio
            return self._planned_snap(ctx, gain) if excess != 0.0 else 0.0
        if len(self._acc) < 3 or excess == 0.0:
            return 0.0
        snap = (self._acc[2] - 2.0 * self._acc[1] + self._acc[0]) / (self.period * self.period)
        # this order of operations is the one every run before ff.snap_fit_cap was measured with
        # (the campaigns are chaotic: a last-bit difference here moved 49 of 200 full-box runs)
        return m.j1 * m.valve_inertia_kgm2 * excess / m.coupling_stiffness_nm_per_rad * snap / m.gear_ratio

    @staticmethod
    def _plan_acc(move: Move, t: float) -> float:
        """The planned acceleration (rad/s²) ``t`` s into ``move``: 0 at rest before and after it."""
        return move.sample(t)[2] if 0.0 < t < move.duration else 0.0

    def _planned_snap(self, ctx: Context, gain: float) -> float:
        """``ff.snap_fit_cap``: the snap term (motor N*m) from the plan, ``gain`` (motor N*m per
        rad/s⁴ at the valve) times the plan's central second difference of its acceleration at the
        sampled time, times one factor for the move.

        The factor is decided on the move's first clocked period from its planned peak snap (a sin²
        ramp ``a_pk sin²(π t / t_a)`` has a second difference of at most
        ``a_pk (1 - cos(2π h / t_a)) / h²``, at its start, middle and end): the peak term plus the
        move's static friction feed-forward (motor N*m) must fit ``snap_cap_nm``.  On K x 0.1 a
        20 ms move's term asks ~10 x the cap: clipped period by period it rang -19 ... +30 A and
        dragged the valve backward (h26k, §52); scaled, the term keeps its shape."""
        mv, h = ctx.move, self.period
        if mv is not self._snap_move:
            self._snap_move = mv
            ta = mv.accel_time
            peak = 0.0
            if ta > 0.0:
                a_pk = 2.0 * mv.peak_velocity / ta
                peak = abs(gain) * a_pk * (1.0 - math.cos(2.0 * math.pi * h / ta)) / (h * h)
            m = self.model
            fl = m.friction(ctx.pressure_kpa)
            sm, sv = self.scale(ctx.pressure_kpa)
            friction = self.fraction * (sm * fl.motor_static_nm + sv * fl.valve_static_nm / m.gear_ratio)
            room = max(self.snap_cap_nm - friction, 0.0)
            self.snap_factor = min(1.0, room / peak) if peak > 0.0 else 1.0
        t = ctx.move_time
        snap = (self._plan_acc(mv, t + h) - 2.0 * self._plan_acc(mv, t) + self._plan_acc(mv, t - h)) / (h * h)
        return self.snap_factor * gain * snap
