"""Observer-based state feedback with integral action and friction compensation (modes
``observer``, ``observer_fc``, ``kalman_fc``, ``fc_gain``, ``observer_ff``).

Conventions: angles rad (valve side unless named motor), velocities rad/s, torques N*m at the
motor shaft unless a name says valve; ``θ1 = θm / N``.
"""
from __future__ import annotations

import math
from collections import deque

import numpy as np

from ...common.contract import RESOLVER_COUNT_RAD
from ..compensation import Compensator, Context, HoldStiffness
from ..design import StateFeedback
from ..integral_policy import IntegralPolicy, JumpLearner, SlipEdges, SlipWatch
from ..model import NominalModel
from ..seating import Seating
from ..signals import Estimate
from ..trajectory import Reference, TrajectoryShaper
from .base import ControlLaw


class StateFeedbackLaw(ControlLaw):
    """Discrete observer-based state feedback with integral action (modes ``observer``,
    ``observer_fc``, ``kalman_fc``, ``fc_gain``, ``observer_ff``).

    Per period: the disturbance observer ``x̂ = x̄ + L (y - C x̄)`` (``x̄`` predicted from the
    applied torque, the known loads and the compensator's friction belief), then

        u = u_ff(ref) - K (x̂ - x_ref) + K_I ζ + compensation

    where ``x_ref``/``u_ff`` hold the shaped reference against the known loads (spring,
    nominal flow torque, inertia and viscous feed-forward) and ``ζ += T (r - θ̂L)`` only
    outside the friction-sized deadband, outside planned moves and while the current is not
    limited.  The compensation strategy is a :class:`~..compensation.Compensator`.

    Resolver delay (``delay_periods`` = the measured delay in loop periods): a sample taken
    ``D`` periods ago corrects the observer's estimate of the state *then* (the delayed-state
    observer ``x̂[k-D]``), which is predicted forward through the ``D`` inputs applied since
    (``x̂[k] = A^D x̂[k-D] + Σ A^i B u``) for the feedback, the reference error and the friction
    compensation.  Without it a 1 ms delay gave a 2 % step 27.7 % overshoot and no settling.
    """

    #: s: a slide onto the target that lasts this long is driven there, no stick-slip jump
    #: (:meth:`~..integral_policy.JumpLearner._driven_to`): a jump is a half swing of the
    #: coupling mode, ~6 ms nominal and ~18 ms at the box's softest coupling (K x 0.1; read as
    #: 10-30 ms through the speed window), while the hold's catch-ups after a cold start took
    #: 0.12-0.13 s (`startup`, campaign seed 1070)
    CATCH_UP_S = 0.1
    #: periods beyond the deadband after which a settled valve's slip record is no longer the
    #: relaxing drive's (:meth:`update`): twice the speed window a slip is read through (a relax
    #: slip that carries the valve beyond the deadband is read within ~3 periods of its start)
    INTEGRATOR_DRIVEN_PERIODS = 10
    #: JL / J1 above which a valve's stick-slip swing does not stop by itself while the drive
    #: stays at the breakaway torque (h23h).  Two masses (gear output J1, valve JL) on the
    #: coupling, the drive held at Ts, the sliding valve's friction Tc: the pair's centre
    #: accelerates at (Ts - Tc) / (J1 + JL) while the coupling swings; the valve's speed
    #: ``∝ c s + sin s`` (s = ω t, c = JL / J1) returns to zero only if c is below the tangent
    #: value -cos(s0), tan s0 = s0 (s0 = 4.4934): 0.2172.  Nominal valve 0.11 (arrests after
    #: 6.4 ms, 3.75e-3 rad ≈ the quasi-static 2 (Ts - Tc) / K); JL x3 0.33 (no arrest: the
    #: slide ran 1.07e-2 rad for a 3.6e-3 rad error until the position loop took it back)
    SWING_ARREST_RATIO = 0.2172
    #: valve resolver counts inside the deadband's edge where the hold's bounded probe
    #: (:meth:`_probe_cap_nm`) stops: the estimate's ~1 count rms noise flickers the error across
    #: the edge there, each flicker outside ramps the drive unbounded, and a probe holding the
    #: drive near its cap instead of relaxing it let the flickers carry the valve over
    #: (K x 0.3, Δp 0, adaptation grid: a 1.8e-3 rad crossing in the tail, 1.13x the allowance)
    PROBE_EDGE_COUNTS = 2.0

    def __init__(self, name: str, model: NominalModel, period_s: float, feedback: StateFeedback,
                 observer_gain: np.ndarray, shaper: TrajectoryShaper, integral: IntegralPolicy,
                 compensator: Compensator, seating: Seating, speed_window: int = 4, delay_periods: int = 0,
                 v2: bool = False, hold_on_friction_met: bool = False, snap_peak_nm: float = math.inf):
        self.name = name
        #: issue 14 (h14c) behaviour of the v2 modes (observer_ff, observer_fp): breakaway jumps
        #: read from the tracking error, a settled relax not reset by speed-estimate flicker;
        #: the dissertation's modes and fc_gain keep what they were measured with
        self.v2 = v2
        #: issue 14 (h16w), the default mode: the hold scheduled on the friction it meets, the Δp
        #: reading only the prior (the held load from both edges of the static band, the drive
        #: test and stuck ramp on the friction met, the limit-cycle breaker); observer_fp too since
        #: task h17f (with the hold as it was its main law hunted on quick-campaign run 3018, where
        #: the fine stage never engaged and observer_ff did not hunt)
        self.met_hold = v2 and hold_on_friction_met
        self.model = model
        #: give the stuck ramp's static-Coulomb surplus back at breakaway (:meth:`_relieve_breakaway`)
        #: also under a compensator that does not ask for it when this valve's swing cannot arrest
        #: itself against the surplus (:data:`SWING_ARREST_RATIO`; never on the nominal valve) and
        #: ``integral.relieve_unarrested_swing`` is on (off by default: docs section 38)
        #: ... or on every valve with ``integral.relieve_every_breakaway`` (off by default: docs section 115;
        #: the half swing arrests, but the gear output still driven at the breakaway torque winds the
        #: coupling up again, and a valve whose friction differs from the told one slides on)
        self.relieve_every = v2 and integral.relieve_every_breakaway
        self.relieve_swing = self.relieve_every or (v2 and integral.relieve_unarrested_swing
                                                    and model.valve_inertia_kgm2 / model.j1 > self.SWING_ARREST_RATIO)
        self.period = period_s
        self.fb = feedback
        self.ao, self.bu, self.bd, self.co = model.observer_model(period_s)
        self.obs_gain = observer_gain
        self.shaper = shaper
        self.integral = integral
        self.compensator = compensator
        self.seating = seating
        #: seating (§39): None until the first period after a reset (a valve the law starts on
        #: a stop has not arrived there), then whether the last period was seated
        self._was_seated: bool | None = None
        self._seat_damp_periods = 0    # periods left in which the seated torque damps the swing
        # default mode: the limit-cycle breaker (cross_hold) on.  With the hold scheduled on the
        # friction met (h16w) the full campaign hunted in 3 of 200 runs without it (1052, 1096, 1133:
        # 35-38 mrad jumps across the target on K x 0.3) and in 1 with it; it costs ~6 % of the
        # median plateau error (the band widens to the jump made).  rest_periods stays 1 (h14r)
        # default mode: a breakaway's pieces within the hold's settle time are one breakaway to the
        # limit-cycle breaker (JumpLearner._chain_start; h21h, campaign seed 1112)
        self.jumps = JumpLearner(cross_hold=self.met_hold,
                                 catch_up_periods=round(self.CATCH_UP_S / period_s) if v2 else 0,
                                 chain_periods=round(integral.settle_time_s / period_s) if self.met_hold else 0,
                                 unchain_rewound=integral.unchain_rewound,
                                 cross_met_margin=integral.cross_met_margin if integral.cross_ratio_from_met else 0.0,
                                 cross_until_move=integral.cross_until_move,
                                 cross_keep_after=integral.cross_keep_after,
                                 cross_keep_unmet=integral.cross_keep_unmet)
        #: h24k: the coupling's stiffness read at every hold (``integral.read_stiffness``, v2
        #: modes): K_model / K sizes the hold's jump and the planned moves' coupling-snap
        #: feed-forward once it lies beyond the reading's scatter (:class:`HoldStiffness`).  A rest
        #: of 20 ms is one reading: several half swings of the coupling mode (~6 ms nominal, ~18 ms
        #: at the box's K x 0.1), so a stop's swing has died in the mean.  Kept across moves and
        #: the fine stage's hand-backs, forgotten with the jump ratio (:meth:`forget`)
        self.stiffness = (HoldStiffness(model.coupling_stiffness_nm_per_rad, model.gear_ratio, model.motor_static_nm,
                                        RESOLVER_COUNT_RAD, rest_periods=max(round(0.02 / period_s), 1),
                                        tolerance=integral.stiffness_tolerance)
                          if v2 and integral.read_stiffness else None)
        #: motor torque (N*m) beyond which the coupling-snap feed-forward of a coupling read soft
        #: is cut (:meth:`update`): the fine stage's current cap (``fine.peak_current_a``, 30 A).
        #: On K x 0.1 the 20 ms minimum move's snap asked 31-35 A (adaptation grid)
        self.snap_peak_nm = snap_peak_nm
        #: static valve friction of the nominal model at Δp 0 (N*m): the least the schedule knows
        self._static_floor = model.friction(0.0).valve_static_nm
        self.xo = np.zeros(6)      # observer state [θ1, ω1, θL, ωL, d1, dL] at the sample's time
        self.x_now = self.xo       # ... predicted forward over the resolver delay (= xo without one)
        #: (motor torque net of friction N*m, known valve load N*m) of the last delay_periods + 1
        #: periods, oldest first: the oldest drives the observer, the rest the prediction
        self._inputs: deque = deque(maxlen=max(int(delay_periods), 0) + 1)
        self.zeta = 0.0
        self._valve_history: deque = deque(maxlen=max(speed_window, 1) + 1)
        self._u_net = 0.0          # motor torque of the last period net of estimated motor friction
        self._d = 0.0              # known valve load of the last period (toward closed)
        self._applied = 0.0
        self._pending = 0.0
        self._fm = 0.0
        self._fl = 0.0
        self.deadband = 0.0        # rad, the integrator's deadband this period
        #: steady valve load beyond the known one (N*m, + = drive pushes toward open) learned from
        #: slips of a relaxing drive (:meth:`IntegralPolicy.learn_load`); kept across moves
        self.held_load = 0.0
        #: the slips that taught it, per direction (default mode: both edges of the band give the load)
        self.slip_edges = SlipEdges()
        #: the settled place of a relaxing valve and the drive there: its slips (jumps, and in the
        #: default mode creeps beyond 3x the jump threshold) are edges of the static band
        #: (a re-take after a reference shift cured campaign seed 1052, but 1022 hunted and 1095
        #: latched a fault instead: measured and not kept, h17w)
        self.slip_watch = SlipWatch(integral.min_rad, 3.0 * integral.min_rad if self.met_hold else 0.0)
        self._relax_periods = 0                 # periods relaxed in a row
        self._outside_periods = 0               # periods in a row the error was beyond the deadband
        #: (drive N*m beyond the known load, valve rad, way ±1, target rad) of the latest stuck
        #: period while the integrator pulls the valve toward its target (:meth:`_read_pull`)
        self._pull: tuple[float, float, float, float] | None = None
        #: (valve angle rad, direction ±1 to the target, drive N*m beyond the loads) where a held
        #: valve stuck short of its target, until it breaks away (modes whose compensator relieves the breakaway)
        self._stuck_short: tuple[float, float, float] | None = None
        #: (valve angle rad, way ±1, drive N*m toward the target) of the latest stuck period of the
        #: hold's bounded probe (``integral.probe_soft_floor``), until the valve lets go
        self._probe_stuck: tuple[float, float, float] | None = None
        #: the target (rad) a probe on the friction met (``integral.probe_shown_friction``) has
        #: been made toward, and the one it is under way toward: one probe per target, ended by the
        #: valve letting go or by its error leaving the probe's range, so a misfit cannot repeat
        self._shown_probed: float | None = None
        self._shown_probing: float | None = None
        self._cocked = False
        self.reference: Reference | None = None
        self._pressure: float | None = None   # kPa, Δp of the latest update

    def loop_late(self) -> None:
        # a breakaway that starts or ends in a late loop's hold-off is not learned as this valve's jump: in real time a
        # stall held a fine-stage pulse for several periods and threw the valve 2.8e-2 rad; learned, the jump ratio
        # went 1.22 -> 13.1 and the deadband 3.1e-3 -> 4.6e-2 rad held it 3.3e-2 off for good (docs §111.5b)
        self.jumps.drop_slide()

    def forget(self) -> None:
        self.jumps.reset()
        if self.stiffness is not None:
            self.stiffness.reset()
            self.compensator.coupling_misfit(1.0)

    def friction_rescheduled(self, pressure_kpa: float) -> None:
        # bumpless: the reference state and torque carry the known load (spring, preload and
        # the flow torque of the Δp scheduled); the valve's real load did not change, so the
        # integrator takes over the change of the flow torque and the drive stays where it
        # is.  Without this a valve at Δp 0 held under a told max (its fake 1.2 N*m of flow
        # torque worked off by the integrator) was let go by the reschedule and slipped
        # 8.5 mrad (adaptation grid, F x1 Δp 0 told max)
        if self._pressure is not None and self.reference is not None:
            m = self.model
            pos = self.reference.position
            dtk = m.load_torque(pos, pressure_kpa) - m.load_torque(pos, self._pressure)
            du = dtk / m.gear_ratio + float(self.fb.k[0]) * dtk / m.coupling_stiffness_nm_per_rad
            self.zeta -= du / self.fb.ki
        # the Friedland-Park levels were seeded from the old schedule and adapt only while the
        # valve slides: seeded at Δp max on a valve at Δp 0 (observer_fc) they kept the ±Tc term
        # 9x too large and hunted for 1.5 s after the cross-check had caught the wrong Δp
        if self._pressure is not None and self.reference is not None:
            self.compensator.rescheduled(self.model, self._pressure, pressure_kpa, self.reference.position)
        else:
            self.compensator.reset(self.model, pressure_kpa)
        # the jump ratio was learned against the old schedule's nominal jump (told 0 on a valve
        # at Δp max: ratio ~11, which on the max schedule made a 16 mrad deadband): the jumps
        # measured are kept, as a ratio to the new nominal jump.  Forgotten instead, the
        # deadband fell to the nominal at the new Δp (0.29 mrad at Δp ~0) below the valve's
        # 0.5-1 mrad jumps, and the hold hunted +-0.5 mrad at 1.7 Hz (test_pressure_input,
        # observer_ff told max on a valve at Δp 0)
        if self._pressure is None:
            self.jumps.reset()
        else:
            k = self.model.coupling_stiffness_nm_per_rad
            old = self.model.friction(self._pressure).stick_slip_jump_rad(k)
            new = self.model.friction(pressure_kpa).stick_slip_jump_rad(k)
            self.jumps.rescale(old / new if new > 0.0 else 1.0)
        self._keep_held_load(pressure_kpa)

    def _keep_held_load(self, pressure_kpa: float) -> None:
        """A Δp reschedule to ``pressure_kpa`` (kPa; the old schedule is ``self._pressure``):
        the valve's real load did not change, only the part of it the schedule knows (the flow
        torque), so the held load -- the load beyond the known one (N*m, + the drive pushes toward
        open) -- and the slip edges that taught it (drive torques beyond the known load) move by the
        change of the known load at the reference, and the static friction they met (half the
        band's width) stays (default mode, h20w).  Forgotten instead (main 807b5de), the relax aimed
        at no load at all: campaign seed 1096 (Stribeck x 0.52, 9.4 N*m, Δp missing, told max, true
        1.5 MPa, breakaway start) -- the cross-check switched the schedule mid-move (438 -> 6206 kPa),
        the held 9.1 N*m went to 0 and the hold hunted 2.6 mrad (3 reversals) on that plateau.  The
        other modes keep the held load as it was and forget the edges (as before)."""
        if not self.met_hold:
            self.slip_edges.reset()
            return
        if self._pressure is None or self.reference is None:
            self.slip_edges.reset()
            self.held_load = 0.0
            return
        pos = self.reference.position
        shift = self.model.load_torque(pos, self._pressure) - self.model.load_torque(pos, pressure_kpa)
        self.held_load += shift
        self.slip_edges.shift(shift)

    def reset(self, meas, torque_nm, pressure_kpa, keep_held_load: bool = False):
        """Restart bumplessly from ``torque_nm`` (N*m, motor shaft).  ``keep_held_load``: keep
        what the hold has learned about this valve -- the steady load beyond the known one and
        the slip edges of the static band that taught it -- as the fine stage's hand-back does
        (:meth:`.fine.FinePositioningLaw._resume_main`); a fault reset or a new law forgets them."""
        m = self.model
        th1 = meas.motor_rad / m.gear_ratio
        # start the observer with the valve at rest *in equilibrium*: the valve torque the
        # nominal model does not explain (a coupling softer than the model reads as a larger
        # twist torque; friction holding a valve) starts in the valve disturbance state.
        # Starting it at 0 made the observer's first periods accelerate the valve by the
        # unexplained torque: on a coupling of K x 0.1 (flexible_worst) the estimates jumped
        # and the command hit the peak limit (36.3 A in every state-feedback mode; now 13-19 A).
        # The gear-output state d1 is not seeded: seeding it from the arming torque too broke
        # the signature test's 2 % step settling at max dp (re-arm from zero torque; not traced)
        twist = m.coupling_stiffness_nm_per_rad * (th1 - meas.valve_rad)     # N*m, + winds toward open
        dl = twist - m.load_torque(meas.valve_rad, pressure_kpa)             # valve, + toward closed
        self.xo = self.x_now = np.array([th1, 0.0, meas.valve_rad, 0.0, 0.0, dl])
        self.shaper.reset(meas.valve_rad)
        self._valve_history.clear()
        self.compensator.reset(m, pressure_kpa)
        self._fm = self._fl = 0.0
        x_ref, u_ff = m.equilibrium(meas.valve_rad, pressure_kpa)
        # bumpless: the integral state makes the first output equal the present torque
        self.zeta = (torque_nm - u_ff + float(self.fb.k @ (self.xo[:4] - x_ref))) / self.fb.ki
        self._applied = self._u_net = torque_nm
        if not keep_held_load:
            self.held_load = 0.0
            self.slip_edges.reset()
        #: the fine stage's hand-back (v2): its hold leaves the twist preloaded toward breakaway,
        #: uncocked when the reference starts to follow a ramp (:meth:`update`)
        self._cocked = keep_held_load and self.v2
        if self._cocked:
            self.jumps.drop_slide()
        self.slip_watch.reset()
        self._relax_periods = self._outside_periods = 0
        self._pull = None
        self._stuck_short = None
        self._probe_stuck = None
        self._shown_probed = None
        self._shown_probing = None
        self._d = m.load_torque(meas.valve_rad, pressure_kpa) - m.spring_rate_nm_per_rad * meas.valve_rad
        self._inputs.clear()
        self._inputs.extend([(torque_nm, self._d)] * (self._inputs.maxlen - 1))   # at rest before
        self._was_seated = None
        self._seat_damp_periods = 0

    def update(self, t, demand_rad, meas, pressure_kpa):
        m = self.model
        n = m.gear_ratio
        self._pressure = pressure_kpa
        # ---- disturbance observer (current estimator)
        self._inputs.append((self._u_net, self._d))       # what the period just ended applied
        u_old, d_old = self._inputs[0]
        # hoisted: the same arrays, sliced once; ``.dot`` is the BLAS call ``@`` makes (dgemv,
        # the same floats: checked on every scenario's log), without the ufunc overhead
        ao, bu, bd = self.ao.dot, self.bu[:, 0], self.bd[:, 0]
        x_bar = ao(self.xo) + bu * u_old + bd * d_old
        self.xo = x_bar + self.obs_gain.dot(np.array([meas.motor_rad / n, meas.valve_rad]) - self.co.dot(x_bar))
        x_now = self.xo
        for i in range(1, len(self._inputs)):              # predict over the resolver delay
            u_i, d_i = self._inputs[i]
            x_now = ao(x_now) + bu * u_i + bd * d_i
        self.x_now = x_now
        th1, w1, thl, wl = x_now[:4].tolist()      # Python floats: the same values, cheaper arithmetic
        hist = self._valve_history
        hist.append(meas.valve_rad)
        valve_speed = (hist[-1] - hist[0]) / (self.period * (len(hist) - 1)) if len(hist) > 1 else 0.0
        # ---- seating: demands at a stop drive the valve onto it and hold it there
        target, seat = self.seating.target(demand_rad)
        if seat and self.seating.seated(self.shaper, target, thl):
            stop = 0.0 if seat < 0 else m.stroke_rad
            self.shaper.reset(stop)
            self.reference = Reference(stop, 0.0, 0.0, False)
            self._pending, self._fm, self._fl = 0.0, 0.0, 0.0
            self._d = m.load_torque(stop, pressure_kpa) - m.spring_rate_nm_per_rad * stop
            if self._was_seated is False:
                # arrived from a move: the coupling is wound past the seated twist (§39)
                self._seat_damp_periods = self.seating.settle_periods
            self._was_seated = True
            swing = 0.0
            if self._seat_damp_periods > 0:
                # the gear output's speed alone: the stop holds the valve still, which the
                # observer does not know (its valve-speed estimate swung along at ~half of it)
                self._seat_damp_periods -= 1
                swing = w1
            return self.seating.torque(m, stop, seat, pressure_kpa, swing)
        self._was_seated = False
        self._seat_damp_periods = 0
        # ---- reference, deadband
        load_nm = m.load_torque(thl, pressure_kpa)   # the known valve load (spring, preload, flow), once per period
        was_moving = self.reference is not None and self.reference.moving
        self.shaper.hold_band = self.deadband     # (the previous period's)
        ref = self.shaper.update(target, meas.valve_rad)
        if (ref.moving and not was_moving) or (
                self._cocked and ref.velocity * (n * self._applied - load_nm - self.held_load) > 0.0):
            # a move starts: uncock the drive first (valve torque back to the known load) so the
            # move's feed-forward starts from neutral, not from a drive wound up to breakaway.
            # So does a followed demand after the fine stage's hand-back that moves the way the
            # stage left the twist preloaded (toward breakaway): the reference feed-forward adds
            # the static level the moment the reference moves (ReferenceFeedforward: so that a
            # relaxed valve breaks away), on a preloaded drive twice the breakaway; the valve was
            # carried 1.9e-2 rad past a 7e-3 rad/s ramp (`startup`, 23 -> 25 %; a reversing ramp
            # 1.6e-2).  Uncocked at the hand-back itself, the small steps the preload helps
            # overshot (`startup`'s 0.5 % step 29 -> 137 %); uncocked on any motion of the
            # followed reference (demand noise too), quick-campaign seed 3014 hunted
            net = n * self._applied - load_nm - self.held_load
            self.zeta -= net / n / self.fb.ki
            self._cocked = False
        self.reference = ref
        stuck = abs(valve_speed) <= self.integral.stuck_speed
        friction = m.friction(pressure_kpa)         # once per period: the jump, the drive test, the load learning and the stuck ramp read it
        nominal_jump = friction.stick_slip_jump_rad(m.coupling_stiffness_nm_per_rad)
        soft = self._read_stiffness(ref.moving, stuck, w1, meas)
        # the drive's torque on the valve beyond the load it holds, against half the lowest
        # static friction the valve can have (x 0.5 in the robustness box; at the box's edge a
        # genuine breakaway comes right at it, so half of it): less, and the valve was broken
        # loose by something else
        drive_nm = n * self._applied - load_nm - self.held_load
        # default mode: on the friction the hold has met, the schedule only the prior (a wrong Δp)
        static = (self.integral.hold_static_nm(friction.valve_static_nm, self.slip_edges.static_nm,
                                               self.integral.load_static_fraction * self._static_floor)
                  if self.met_hold else friction.valve_static_nm)
        driven = abs(drive_nm) >= 0.5 * self.integral.load_static_fraction * static
        # v2: the jump is read from the tracking error: while the reference follows a ramp the
        # valve's travel is mostly the ramp's (issue 14: read as a jump, it froze the integrator)
        frame = ref.position if self.v2 else 0.0
        # v2: the breakaway and slip readings use the valve angle averaged over the speed
        # window: single samples read ~1 count rms resolver noise as 3-4 count "jumps" and
        # "slips" that collapsed the deadband and flipped the learned load (IntegralPolicy, h14r)
        valve = sum(hist) / len(hist) if self.v2 else meas.valve_rad
        self.jumps.update(valve - frame, stuck, not ref.moving, max(nominal_jump, self.integral.min_rad),
                          target - frame, self.deadband, driven, valve if self.v2 else None,
                          meas.motor_rad / m.gear_ratio - meas.valve_rad if self.integral.unchain_rewound else None,
                          # h32b: the quasi-static jump the drive on the valve would make, over the nominal one
                          soft * drive_nm / friction.valve_static_nm
                          if self.integral.cross_ratio_from_met and friction.valve_static_nm > 0.0 else None)
        # v2: sized by the jump the valve makes toward the target (the jumps differ by direction)
        ratio = self.jumps.ratio_toward(target - thl) if self.v2 else self.jumps.ratio
        met = self.compensator.jump_ratio()     # the jump the friction met at breakaway implies
        # the jump is at least the friction's on the coupling read at the holds (2 (Ts - Tc) / K;
        # the learner's ratio is to the model's K): a floor, so a jump the learner has measured
        # stays what it is.  Default mode (h25k): at the static friction the hold has met
        # (``static``: the schedule lowered to the slip edges' band, never raised), not the
        # schedule -- on a low-friction valve told max Δp the scheduled floor parked the valve
        # further off (full box, option on: median 2.58e-3 -> 2.56e-3 rad, 1912 -> 1905 plateaus
        # > 8e-4; the grids cell for cell the same: a single 2 % step meets no slip edges)
        learned = ratio if met is None else max(ratio, met)     # the jumps this valve has shown
        if soft != 1.0:
            ratio = max(ratio, soft * static / friction.valve_static_nm if self.met_hold and friction.valve_static_nm > 0.0
                        else soft)
        if met is not None:
            ratio = max(ratio, met)
        self.deadband = self.integral.deadband(m, pressure_kpa, ratio)
        error = ref.position - thl
        outside = abs(target - thl) > self.deadband and not ref.moving
        # h26k: inside the floor but beyond what the jumps learned would hold: a bounded probe
        probe_cap = (self._probe_cap_nm(abs(target - thl), static, self.integral.deadband(m, pressure_kpa, learned))
                     if self.integral.probe_soft_floor and soft != 1.0 and not outside and not ref.moving else None)
        shown_probe = False
        if (probe_cap is None and self.integral.probe_shown_friction and self.met_hold and not outside
                and not ref.moving and (self._shown_probed is None
                                        or abs(target - self._shown_probed) > self.deadband)):
            # (a target within the deadband of the one probed toward is that demand: demand noise)
            # h30h: inside a deadband wider than the friction met implies: a bounded probe, once
            probe_cap = self._shown_probe_cap_nm(abs(target - thl), m, pressure_kpa, friction)
            shown_probe = probe_cap is not None
        if shown_probe:
            self._shown_probing = target
        elif self._shown_probing is not None:
            # the probe ended (the valve let go, the error left its range, a move began): not again
            # toward this target -- a LuGre valve that creeps in and out of the range was probed
            # again and again and hunted on the final hold (full box 1001, 1057, 1174, ...)
            self._shown_probed, self._shown_probing = self._shown_probing, None
        if probe_cap is not None:
            # the probe's breakaway is the drive's, not a relaxing drive's slip
            self.slip_watch.reset()
        # ---- friction compensation
        ctx = Context(pressure_kpa, th1, w1, thl, wl, valve_speed, self._applied, ref.velocity, ref.acceleration,
                      ref.moving, error, outside, ref.armed, ref.broke_away, self.held_load,
                      self.met_hold and self.slip_edges.known, valve if self.v2 else None,
                      meas.valve_rad, meas.motor_rad / n - meas.valve_rad,
                      # the planned move and the time its acceleration is sampled at (ff.snap_fit_cap)
                      self.shaper.move if ref.moving else None, self.shaper.sample_time,
                      # the static friction the hold's band showed (ff.band_starts_wrong_dp_move)
                      self.band_static_nm)
        comp, self._fm, self._fl = self.compensator.update(ctx)
        if self.met_hold and not ref.moving:
            self._reprior_held_load(load_nm if self.v2 else 0.0, friction.valve_static_nm)
        if ref.armed and self.compensator.wait_over():
            self.shaper.start_clock()           # the valve did not let go where expected (h17b)
        # ---- state feedback around the dynamically consistent reference state
        x_ref, u_ff = m.reference_state(ref.position, ref.velocity, ref.acceleration, pressure_kpa,
                                        0.0, self._fl)
        u = u_ff + (comp - self._fl / n) - float(self.fb.k.dot(x_now[:4] - x_ref)) + self.fb.ki * self.zeta
        self._pending = 0.0
        if self.met_hold and self._outside_periods > self.INTEGRATOR_DRIVEN_PERIODS:
            # default mode: the settled record is the drive of the latest relaxing period; once the
            # error has been beyond the deadband for longer than a slip takes to be read, the
            # integrator and the stuck ramp have driven the valve from there toward a new target
            # (a followed demand step below the move threshold), and the breakaway they cause is no
            # relax slip.  Read at the stale settled drive (~0 on a load-free valve), its one-edge
            # prior put half the static level (2.8 N*m) of load on a valve that carries none
            # (nominal box seeds 1009, 1019, 1026, 1036, 1038: every later move started from a drive
            # uncocked to that load, half the static friction toward or away from its breakaway,
            # and overshot 62-112 %; h20s).  The creep record too (its drive is as stale): the
            # valve rests again before the next one is taken
            self.slip_watch.reset()
        self._outside_periods = self._outside_periods + 1 if outside else 0
        if self.met_hold:
            self._read_pull((outside or probe_cap is not None) and not ref.moving, stuck, valve, target, target - thl,
                            n * self._applied - load_nm, friction.valve_static_nm, load_nm)
        slip = None if ref.moving else self.slip_watch.left(valve)
        if ref.moving:
            self.slip_watch.reset()
        elif slip is not None:
            # a valve that had settled (relaxing for settle_time) left its place by more than
            # the resolver's noise, the way the relaxing drive let it go (the relax takes support
            # away from the side the load pushes): a steady load beyond the known one
            net0, moved = slip
            if moved * (net0 - self.held_load) < 0.0 and self.met_hold and self.slip_edges.contradicts(net0, moved):
                self.slip_edges.reset()         # a known band contradicted: unknown now, the load kept (h19b)
            elif moved * (net0 - self.held_load) < 0.0:
                self.held_load = self.integral.learn_load(
                    net0, moved, friction.valve_static_nm,
                    load_nm if self.v2 else 0.0, self.slip_edges.opposite(moved) if self.met_hold else None)
                self.slip_edges.met(net0, moved)
        relaxing = False
        if not outside and probe_cap is None and not ref.moving and stuck and self.integral.relax_time_s > 0.0:
            # settled: relax the drive to the middle of the static-friction band.  The valve
            # torque is the applied motor torque times N less the known load (robust to the
            # coupling stiffness, which may be far from nominal); shrinking it cannot break the
            # valve loose, and the next move starts from a neutral drive, not a cocked one.
            # The middle of the band includes the steady load learned from earlier slips.
            net = n * self._applied - load_nm
            relaxing = True
            self._relax_periods += 1
            if self._relax_periods * self.period >= self.integral.settle_time_s:
                self.slip_watch.settled(net, valve)   # where and with what drive it had settled
            self._pending = -(net - self.held_load) / n * self.period / self.integral.relax_time_s / self.fb.ki
        if (outside or ref.moving or probe_cap is not None) if self.v2 else not relaxing:
            # a settled valve stays settled through a period the speed estimate calls moving:
            # with ~1 count rms resolver noise the 4-period speed flickers across the stuck
            # threshold, the count never reached settle_time, a load beyond the static friction
            # was never learned from its slips and the relax let it slip again and again
            # (campaign seed 1019: 9.3 N*m, 116-count hunting on the final hold; none now)
            self._relax_periods = 0
        if self.compensator.relieves_breakaway or self.relieve_swing:
            # (integral.relieve_every_breakaway) only at a plateau's hold: a valve stick-slipping
            # behind a followed ramp is tracking, and a planned move waiting for its breakaway has the
            # compensator's own retreat (docs section 115)
            self._relieve_breakaway(meas.valve_rad, stuck, outside, self.compensator.reference_moves(ctx)
                                    or (self.relieve_every and (ref.velocity != 0.0 or ref.armed)), error,
                                    friction, drive_nm)
        if outside:
            self._pending = self.period * error
            if stuck:
                # stuck short of the target: ramp the torque quasi-statically to breakaway
                # instead of waiting for the slow integrator (the jump is the same either way)
                rate = static / self.integral.stuck_ramp_time_s
                ramp = rate / n * self.period / self.fb.ki
                self._pending = math.copysign(max(abs(self._pending), ramp), error)
        elif probe_cap is not None:
            # the stuck ramp toward the target, the drive (valve side, beyond the known and the
            # learned load) held at the cap; nothing more once the valve slides: the twist stored
            # at breakaway carries it the quasi-static jump, the least it can make
            way = 1.0 if target > thl else -1.0
            headroom = max(probe_cap - way * drive_nm, 0.0) / n / self.fb.ki
            ramp = static / self.integral.stuck_ramp_time_s / n * self.period / self.fb.ki
            self._pending = way * min(ramp, headroom) if stuck else 0.0
            if stuck:
                self._probe_stuck = (meas.valve_rad, way, way * drive_nm)
            elif self._probe_stuck is not None and (meas.valve_rad - self._probe_stuck[0]) * self._probe_stuck[1] \
                    >= self.jumps.min_jump:
                # let go: give the static-Coulomb surplus of the drive it let go at back, so the
                # gear output does not follow the relaxing coupling and carry the valve further
                _, w0, d0 = self._probe_stuck
                if shown_probe:
                    self._shown_probed = target
                if friction.valve_static_nm > 0.0 and d0 > 0.0:
                    surplus = d0 * (1.0 - friction.valve_coulomb_nm / friction.valve_static_nm)
                    self.zeta -= w0 * surplus / n / self.fb.ki
                self._probe_stuck = None
        if probe_cap is None and self._probe_stuck is not None and stuck:
            self._probe_stuck = None
        known_load = load_nm - m.spring_rate_nm_per_rad * thl   # preload + flow
        self._d = known_load + (self._fl if self.compensator.feeds_observer else 0.0)
        snap = self.compensator.snap_nm
        if self.stiffness is not None and snap * u > 0.0 and abs(u) > self.snap_peak_nm:
            u -= math.copysign(min(abs(u) - self.snap_peak_nm, abs(snap)), u)
        return u

    @property
    def band_static_nm(self) -> float | None:
        """The static valve friction the hold's band showed (N*m, valve side: half the width between
        its relax slips' two edges, :attr:`SlipEdges.static_nm`), or None: not a hold on the friction
        met, or not both edges known.  Read by the move's feed-forward (``ff.band_starts_wrong_dp_move``)
        and by the fine stage's cold start (``fine.cold_band_gate``)."""
        return self.slip_edges.static_nm if self.met_hold and self.slip_edges.known else None

    def _probe_cap_nm(self, error_rad: float, static_nm: float, learned_rad: float) -> float | None:
        """The drive (N*m at the valve beyond the known and the learned load, toward the target)
        up to which the hold may push a valve ``error_rad`` (rad, > 0) from its target while the
        soft coupling's jump floor alone holds it (``integral.probe_soft_floor``; h26k), or None
        where it does not: the error is within ``learned_rad`` (the deadband of the jumps this
        valve has shown and the friction its moves met, without the floor: the hold stays), or
        beyond the deadband in force (the stuck ramp pushes as ever), or within
        :data:`PROBE_EDGE_COUNTS` of it (the hold relaxes as before), or once the hold has seen this
        valve jump at all (:attr:`JumpLearner.directed`: its jumps are then known, not guessed, and
        the cap's quasi-static promise no longer needed; probing on, K x 0.3 friction x 0.5 max Δp
        jumped 1.1-1.2e-2 rad, 1.5x quasi-static, and crossed the target three times, 5.9 / 5.2 /
        6.8e-3 rad, before the learner's deadband held it).

        The floor is the jump ``2 (Ts - Tc) / K_read`` at the static friction ``static_nm`` (the
        schedule, lowered to the friction the hold has met) -- a guess before the valve has
        slipped: the box's friction runs x 0.5 ... 3 of it.  A quasi-static breakaway at a drive
        ``D`` jumps ``2 D (1 - Tc/Ts) / K``, i.e. the floor's jump times ``D / static_nm``; so a
        valve that lets go at ``D <= static_nm * error / deadband`` lands within the jump whose
        deadband just holds this error, no farther beyond the target than
        ``(1 / jump_fraction - 1) x error`` if the jump were quasi-static, and one that does not
        stays where the floor held it.  K x 0.1, friction x 0.5, max Δp (adaptation grid): the floor
        (2.56e-2 rad at the scheduled 5.5 N*m) held the valve at the whole 2 % step (2.09e-2 rad)
        for ever; with the probe (cap 4.5 N*m) it lets go at 2.75 N*m and jumps 2.58e-2 rad, 1.13x
        the quasi-static 2.29e-2 (the gear output follows the relaxing coupling): 23 % overshoot
        against the 9.4 % floor, 4.8e-3 rad off at the end.  The jumps on soft couplings run
        1.1-1.45x quasi-static, so a probe near the deadband's edge may land beyond the target by
        more than the error it started from (K x 0.3, friction x 0.5, max Δp: 5.8e-3 -> 5.1e-3 rad,
        across)."""
        if (self.jumps.directed or error_rad <= learned_rad
                or error_rad >= self.deadband - self.PROBE_EDGE_COUNTS * RESOLVER_COUNT_RAD):
            return None
        return static_nm * error_rad / self.deadband

    def _shown_probe_cap_nm(self, error_rad: float, m, pressure_kpa: float, friction) -> float | None:
        """The drive (N*m at the valve beyond the known and the learned load, toward the target)
        up to which the hold may push a valve ``error_rad`` (rad, > 0) from its target that the
        deadband in force holds although the quasi-static jump at the static friction the hold has
        met would not (``integral.probe_shown_friction``; h30h), or None where that does not apply:
        no band met yet (:attr:`SlipEdges.static_nm`), the error within that friction's deadband
        (the hold stays, as the jump-sized deadband means it to), or within
        :data:`PROBE_EDGE_COUNTS` of the deadband in force (the hold relaxes as before).

        The deadband in force can be far wider than this valve's quasi-static jump: the crossing
        breaker (:class:`~..integral_policy.JumpLearner`) widens both ways to the length of a
        chained breakaway, whose second piece may be the gear output's own swing.  Friction x 1.5
        nominal plant, nominal-box seed 2001: a 10 mrad jump and a 6.7 mrad swing-driven second
        piece set both ways to 3.66 nominal jumps (9.23e-3 rad); the next 9.2 mrad opening step's
        move did not break the valve loose, the 8.4e-3 rad error lay inside the band, and the hold
        relaxed it for the whole plateau while the friction met (8.85 N*m: the x 1.5) gives a
        jump of 6.9 mrad, a deadband of 3.8e-3 rad.

        As :meth:`_probe_cap_nm`: a quasi-static breakaway at a drive ``D`` jumps the met
        friction's jump times ``D / static met``, so one that lets go at
        ``D <= static met * error / band`` lands within the jump whose deadband just holds this
        error."""
        shown = self.slip_edges.static_nm
        scheduled = friction.valve_static_nm
        if shown is None or shown <= 0.0 or scheduled <= 0.0:
            return None
        band = self.integral.deadband(m, pressure_kpa, shown / scheduled)
        edge = self.PROBE_EDGE_COUNTS * RESOLVER_COUNT_RAD
        if error_rad <= band + edge or error_rad >= self.deadband - edge:
            return None
        return shown * error_rad / band

    def _reprior_held_load(self, known_nm: float, scheduled_nm: float) -> None:
        """A move's reading said the Δp told is misread (``ff.read_breakaway_wrong_dp``): a held
        load learned from one relax slip edge took the told schedule's static level
        (``scheduled_nm``, N*m) as its prior; re-learn it on the friction the reading shows
        (:meth:`~..integral_policy.IntegralPolicy.learn_load`,
        :attr:`~..compensation.ReferenceFeedforward.wrong_dp_static_nm`; h27d, §56).  Only a held
        load that *is* that prior (the integrator's pull edge alone is only stored, h20s: campaign
        seed 1010 read a closing pull edge at -4.9 N*m and the re-prior put -2.6 N*m on a valve
        the hold had held at 0); ``known_nm``: the known load at the valve, N*m (the bounds)."""
        static = getattr(self.compensator, "wrong_dp_static_nm", None)
        if static is None:
            return
        self.compensator.wrong_dp_static_nm = None
        if len(self.slip_edges.edges) != 1:
            return
        way, edge = next(iter(self.slip_edges.edges.items()))
        if abs(self.held_load - self.integral.learn_load(edge, way, scheduled_nm, known_nm)) < 1e-9:
            self.held_load = self.integral.learn_load(edge, way, static, known_nm, None)

    def _read_pull(self, pulling: bool, stuck: bool, valve: float, target: float, error: float, net_nm: float,
                   static_nm: float, known_nm: float) -> None:
        """The breakaway the integrator and its stuck ramp force toward the target (``pulling``:
        the error beyond the deadband, no planned move) is an edge of the static band too, read
        at the drive it broke away at (``net_nm``, N*m beyond the known load, of the latest period
        the valve was ``stuck``): the ramp is quasi-static, so that drive is ``L + s Ts`` with
        ``s`` the way it broke.  One such edge alone gives the load only through the scheduled
        static level's prior (half of it: an estimate off by up to half the static friction,
        the error the move's start then carries, see :meth:`update`), so it is only *stored*;
        with the opposite edge it gives the load as their mean, whatever the friction
        (:meth:`~..integral_policy.IntegralPolicy.learn_load`).  A reading that contradicts a
        known band is not used (h20s).

        Only toward a demand that holds still (``target``, rad, the same from the last stuck period
        to the breakaway): under a followed ramp the valve stick-slips along with the reference and
        the drive at each slip carries the ramp's dynamics; read there, the signature test's ramps
        at 3.1 MPa made a band whose scheduling left its 0.5 % and 2 % steps unsettled."""
        if not pulling:
            self._pull = None
            return
        if stuck:
            self._pull = (net_nm, valve, 1.0 if error > 0.0 else -1.0, target)
            return
        if self._pull is None:
            return
        edge, start, way, aim = self._pull
        if target != aim:
            self._pull = None
            return
        if way * (valve - start) <= self.integral.min_rad:
            return
        self._pull = None
        if self.slip_edges.contradicts(edge, way):
            return
        opposite = self.slip_edges.opposite(way)
        if opposite is not None and (edge - opposite) * way > 0.0:
            self.held_load = self.integral.learn_load(edge, way, static_nm, known_nm, opposite)
        self.slip_edges.met(edge, way)

    def _relieve_breakaway(self, valve_rad, stuck, outside, moving, error, friction, drive_nm=0.0) -> None:
        """Give back the breakaway surplus once a valve held stuck short of its target breaks
        away (``moving``: the reference moves, planned or followed; then nothing is done: a
        followed sine reversing through a stuck valve is tracking, not a hold).

        Stuck outside the deadband, the stuck ramp winds the drive up to the static friction
        ``Ts``; sliding, the valve needs only the Coulomb level ``Tc``.  Left in the integral
        state, the surplus ``Ts - Tc`` (valve side) keeps pushing the sliding valve until the
        position feedback has taken it back: with the dissertation's soft position loops
        (140 / 200 N*m/rad at the valve, pole placement / LQR, against the coupling's 480)
        that is ~8e-3 rad past the breakaway point, and the 2 % step's second breakaway overshot 22-34 % (observer_fc,
        seeds 0-7).  Read from the valve resolver (three counts the error's way), once per
        breakaway.

        ``drive_nm`` (N*m at the valve beyond the known and the learned load, this period) is
        the breakaway reading: with ``integral.relieve_met_surplus`` (swing relief only) the
        surplus is sized on the drive of the last stuck period, i.e. the static friction the
        valve *met*, times the schedule's ``1 - Tc/Ts`` (the Coulomb level in the same
        proportion), not on the scheduled ``Ts - Tc``: the campaign perturbs the friction and
        Δp, and a scheduled give-back off the met one left (or over-took) the surplus a c > 0.2172
        swing cannot arrest against (h25h, docs section 47)."""
        if moving or (stuck and not outside):
            self._stuck_short = None            # tracking, or at rest where it may stay
        elif stuck:
            self._stuck_short = (valve_rad, 1.0 if error > 0.0 else -1.0, drive_nm)
        elif self._stuck_short is not None:
            start, sign, drive0 = self._stuck_short
            if (valve_rad - start) * sign >= self.jumps.min_jump:
                self._stuck_short = None
                static = friction.valve_static_nm
                met = max(sign * drive0, 0.0)           # the drive the valve broke away at, toward the target
                if self.relieve_every and static > 0.0 and abs(met / static - 1.0) <= self.integral.relieve_fit:
                    # (integral.relieve_every_breakaway) a valve of the told friction: its slide is the one the
                    # stage is planned on (given back there, holds stopped short, nominal hold 1.6e-4 -> 4.4e-4 rad)
                    return
                surplus = max(static - friction.valve_coulomb_nm, 0.0)
                if self.relieve_swing and self.integral.relieve_met_surplus and static > 0.0:
                    scaled = met * surplus / static
                    # (integral.relieve_every_breakaway) at most the scheduled surplus: the drive met
                    # includes any load the hold has not learned, and one hindering the move inflated
                    # the give-back (full box seed 5000, uncapped: overload faults 5 -> 10, all on plants
                    # that need more than the continuous torque to open; capped 8; docs section 115)
                    surplus = min(scaled, surplus) if self.relieve_every else scaled
                self.zeta -= sign * surplus / self.model.gear_ratio / self.fb.ki

    def applied(self, torque_nm, saturated):
        self._applied = torque_nm
        self._u_net = torque_nm - (self._fm if self.compensator.feeds_observer else 0.0)
        if self.integral.accepts(self._pending, torque_nm, saturated) if self.v2 else not saturated:
            self.zeta += self._pending

    def estimate(self):
        n = self.model.gear_ratio
        th1, w1, thl, wl = self.x_now[:4].tolist()
        return Estimate(th1 * n, w1 * n, thl, wl, self._fm, self._fl)

    def reference_position(self) -> float | None:
        return self.reference.position if self.reference is not None else None

    def deadband_rad(self) -> float | None:
        return self.deadband

    def learned_state(self) -> dict | None:
        out = {"held_load_nm": self.held_load, "jump_ratio": self.jumps.ratio}
        if self.stiffness is not None:
            out["coupling_softness"] = self.stiffness.softness     # K_model / K read at the holds
        return out

    def _read_stiffness(self, moving: bool, stuck: bool, w1: float, meas) -> float:
        """K_model / K to act on this period (1 without ``integral.read_stiffness``): one
        period of the hold reading (:class:`HoldStiffness`; at rest = no planned move, valve and
        gear output still), and on a change of it the compensator told (the coupling-snap
        feed-forward of planned moves)."""
        if self.stiffness is None:
            return 1.0
        old = self.stiffness.misfit
        at_rest = not moving and stuck and abs(w1) <= self.integral.stuck_speed
        twist = meas.motor_rad / self.model.gear_ratio - meas.valve_rad
        self.stiffness.update(at_rest, twist, self._applied)
        new = self.stiffness.misfit
        if new != old:
            self.compensator.coupling_misfit(new)
        return new

    def friction_trend(self) -> float | None:
        scale = self.compensator.scale(self._pressure) if self._pressure is not None else None
        return scale[1] if scale is not None else None

