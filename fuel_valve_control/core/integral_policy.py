"""When the state-feedback law may integrate: the friction-sized deadband (SPEC §6) and the
learner that sizes it from the breakaway jumps the valve really makes."""
from __future__ import annotations

import math
from dataclasses import dataclass

from .model import NominalModel


@dataclass(frozen=True)
class IntegralPolicy:
    """Integral action near the target (the anti-hunting measure of SPEC §6).

    With stiction above Coulomb friction every breakaway jumps ~2 (Ts - Tc)/K; an integrator
    that keeps pushing inside that distance can only hunt.  The integrator is therefore frozen
    while the error is inside ``max(min_rad, jump_fraction * jump(Δp))`` and during planned moves.
    Outside it, a valve that is stuck gets its torque ramped (at least) at ``Ts(Δp) /
    stuck_ramp_time_s`` until it breaks away: quasi-static, so the jump stays the physical
    minimum, but much quicker than the integrator alone (whose rate shrinks with the error).
    Inside it, once the valve is at rest, the drive relaxes toward the middle of the static
    band (valve torque = known load + the learned steady load) with time constant
    ``relax_time_s``.

    A steady load the model does not know (issue 14: up to the actuator's continuous torque)
    makes the middle of the band move: relaxing toward the known load alone lets a load larger
    than the static friction slip the valve, the integrator pulls it back, and the two make a
    limit cycle.  :meth:`learn_load` reads the load from such a slip: the valve gives way when
    ``|net − L| = Ts``, i.e. ``L = net_slip − s Ts`` with ``s`` the slip direction; taking
    ``load_static_fraction`` (0.5: the lowest friction of the robustness box) of the nominal
    ``Ts`` keeps the estimate between the slip point and the true load, i.e. inside the band,
    for any friction from ×0.5 up.  Bounded by ``load_limit_nm``; the relax and the uncocking
    at a move start keep this load on the drive: it is held by integral action.
    """

    jump_fraction: float
    min_rad: float
    stuck_speed: float = 0.03          # rad/s: at or below, the valve counts as stuck
    stuck_ramp_time_s: float = math.inf  # time to ramp through Ts while stuck outside the deadband
    relax_time_s: float = 0.0          # time constant of relaxing a settled drive (0 = off)
    load_limit_nm: float = 0.0         # bound of the learned steady load (valve side, N*m)
    load_static_fraction: float = 0.5  # a slip while relaxing puts the load this fraction of Ts beyond it
    #: h23h: give the stuck ramp's static-Coulomb surplus back at breakaway in observer_ff /
    #: observer_fp too, on valves whose swing cannot arrest itself against it
    #: (StateFeedbackLaw.SWING_ARREST_RATIO; never the nominal valve)
    relieve_unarrested_swing: bool = False
    #: s32 (docs section 115): the same give-back at every breakaway of the hold, whatever JL / J1
    relieve_every_breakaway: bool = False
    #: ... except where the drive met at the breakaway lies within this fraction of the told static level
    relieve_fit: float = 0.15
    #: h25h: size that give-back on the drive the valve broke away at (the static friction met)
    #: times the schedule's 1 - Tc/Ts, instead of the scheduled Ts - Tc
    relieve_met_surplus: bool = True
    #: h24k: read the coupling's stiffness at every hold and size the hold's jump and the planned
    #: moves' coupling-snap feed-forward on it (StateFeedbackLaw._read_stiffness; v2 modes)
    read_stiffness: bool = False
    #: h25k: K_model / K read at the holds is acted on only beyond 1 + this + the reading's
    #: scatter bound (HoldStiffness.tolerance).  0.25 (h24k, the snap feed-forward's own
    #: tolerance) acted on campaign seed 1195's K x 0.77 (true 1.29, readings 1.21-1.42 for a
    #: bound of 0.07-0.14: the estimate crossed the gate at 1.40 and hunted); a coupling within
    #: x 0.67 of the model's is left to the model-based loop, which holds the full box there
    stiffness_tolerance: float = 0.5
    #: h26k: where only the soft coupling's jump floor holds the valve (its error beyond the
    #: deadband the jumps learned and met would give, inside the floor's), the hold's stuck ramp
    #: still pushes toward the target, but only up to the friction whose jump on the coupling read
    #: would leave the error at the deadband's edge (StateFeedbackLaw._probe_cap_nm): a valve with
    #: less friction than the schedule lets go and lands within that jump, one with more stays
    probe_soft_floor: bool = False      # (the schema's default: true since h26k)
    #: h30h: where the deadband in force (jumps learned, the crossing breaker's chain) holds a valve
    #: further from its target than the deadband of the quasi-static jump at the static friction the
    #: hold has met (:attr:`SlipEdges.static_nm`) would, the hold's stuck ramp still pushes toward
    #: the target once per target, bounded like ``probe_soft_floor``'s probe on that jump
    #: (StateFeedbackLaw._shown_probe_cap_nm): a valve with more friction than told that a move
    #: left stuck inside a widened deadband is broken loose instead of held short for the plateau
    probe_shown_friction: bool = False
    #: h31c: the limit-cycle breaker's chain (:meth:`JumpLearner._chain_start`) joins a piece to
    #: the breakaway before only if the coupling was not wound up again in the piece's direction
    #: between them (:attr:`JumpLearner.unchain_rewound`): a jump's unspent twist only unwinds
    unchain_rewound: bool = False
    #: h32b: the limit-cycle breaker's widening from a *chained* breakaway (pieces joined by
    #: :meth:`JumpLearner._chain_start`) is bounded by the jump the friction met at the chain's
    #: breakaways allows: ``cross_met_margin`` x the quasi-static jump at the drive the hold had
    #: on the valve when it let go (its ratio to the nominal jump: drive / scheduled Ts, times
    #: K_model / K read), never below the jump the last piece made alone
    #: (:attr:`JumpLearner.cross_met_margin`; 0 = off)
    cross_ratio_from_met: bool = False
    #: the bound's margin over the quasi-static jump: breakaways on the box's couplings run
    #: 1.1-1.45x quasi-static (the gear output follows the relaxing coupling; h26k's trace, docs
    #: section 42), so 1.5 is the measured upper end, not a fit to one case
    cross_met_margin: float = 1.5
    #: h32b: the limit-cycle breaker's widening holds for the target it was met at: a planned move
    #: (a new demand) returns both directions to the jumps' own ratios
    #: (:attr:`JumpLearner.cross_until_move`)
    cross_until_move: bool = False
    #: h32f: > 0: the widening is returned at a planned move (as ``cross_until_move``) only while
    #: the hold has counted fewer than this many crossings; from then on it is kept across moves
    #: (:attr:`JumpLearner.cross_keep_after`; 0 = off).  Measured and refuted (docs section 78): the
    #: runs ``cross_until_move`` hurts (full box 1190, 1163, 1010) crossed *once* on main; their
    #: later crossings were the reset's doing, so a count cannot tell them from the runs it helps
    cross_keep_after: int = 0
    #: h32f: with the widening returned at a planned move (``cross_until_move`` or
    #: ``cross_keep_after``), a direction the valve has not jumped in yet keeps it: its "own"
    #: ratio is only the mean of the other way's jumps (:attr:`JumpLearner.cross_keep_unmet`;
    #: full box 1190 / 1163 and quick 3025 back to main, 1010 not: docs section 78.5)
    cross_keep_unmet: bool = False

    @property
    def settle_time_s(self) -> float:
        """A valve relaxed this long (a tenth of the relax time constant: 10 % of the drive's
        excess given back) counts as settled; slips before that are the move's own stick-slip."""
        return 0.1 * self.relax_time_s

    def deadband(self, model: NominalModel, pressure_kpa: float, jump_ratio: float = 1.0) -> float:
        """``max(min_rad, jump_fraction * jump)``, the jump being the nominal one times the
        measured/nominal ratio learned by :class:`JumpLearner`."""
        jump = model.friction(pressure_kpa).stick_slip_jump_rad(model.coupling_stiffness_nm_per_rad)
        return max(self.min_rad, self.jump_fraction * jump * jump_ratio)


    def learn_load(self, net_at_slip: float, direction: float, static_nm: float, known_nm: float = 0.0,
                   opposite_edge_nm: float | None = None) -> float:
        """Steady unknown valve load (N*m, positive = the drive must push toward open) from a
        slip of a relaxing, settled valve in ``direction`` (sign of its speed).

        ``opposite_edge_nm``: the drive torque beyond the known load (N*m, valve side) at the
        latest such slip the other way, if any (:class:`SlipEdges`).  The two slips are the two
        edges of the static band, ``L + Ts`` and ``L − Ts``: their mean is the load whatever the
        friction, so the scheduled ``static_nm`` is then not used at all.  With one edge only, the
        load is put ``load_static_fraction`` of the scheduled static level inside it -- a prior
        that a wrong Δp reading makes wrong: told max on a valve at Δp 0 (Ts 0.5 instead of
        5.5 N*m) it put the load 2.3 N*m beyond the band, the relax then slipped the valve the
        other way, and the two readings alternated (adaptation grid, Δp 0 told 6206 kPa: the
        learned load flipped −3.2 / +0.5 / −3.0 / +0.7 N*m and the hold hunted 5-8 mrad).  An
        opposite edge that lies beyond this one (``(net − opposite) * direction <= 0``: the band
        has moved since, or one of the two was no edge of it) is not used, and the load so learned
        is not *known* (:attr:`SlipEdges.known`).  With ``ff.read_breakaway_wrong_dp`` a move
        whose breakaway reading only a misread Δp explains re-learns a one-edge load with
        ``static_nm`` the level scheduled at that Δp (h27d: the grid's valve at Δp 0 told max,
        one opening edge at −0.42 N*m: −3.17 N*m on the told 5.5 N*m, −0.67 on Δp 0's 0.5, the
        valve's −1.18; on −3.17 the hold slid the valve 5.8 mrad back after the move).
        Measured and not kept (h19b): aiming the relax at
        the centre of the two contradictory readings instead.  It held campaign seed 1029 (a
        closing edge at 3.27 N*m, then the integrator's pull read as an opening one at 1.71 N*m,
        true band 2.1…4.3 N*m: the prior from the newer, false, edge put the load at 1.33 N*m),
        but on the clock seed 1022 (LuGre x 0.64, 10.2 N*m) then hunted: there the *older* edge
        was the false one (closing at 15.1 N*m, the genuine opening edge at 13.0 N*m), the centre
        lay above the band and the prior from the newer edge (11.3 N*m) inside it.  Which of two
        contradictory readings is false is not known here; 1029 is held by the breakaway start's
        load-free retreat instead (:meth:`~.compensation.ReferenceFeedforward._retreat_scale`).

        Bounded so that the whole load the relax holds, ``known_nm`` (the known load at the
        valve, N*m, + toward closed) plus the learned one, stays within ``load_limit_nm`` (the
        continuous torque): a relax aimed beyond it asks for more than the continuous current
        for ever, the I2t limit clamps the drive there and the jam fault latches although the
        valve is held (campaign seed 1019: learned 18.2 N*m on a 9.3 N*m load, 15 A clamped
        for 2 s, ``overcurrent_i2t``)."""
        if opposite_edge_nm is not None and (net_at_slip - opposite_edge_nm) * direction > 0.0:
            load = 0.5 * (net_at_slip + opposite_edge_nm)
        else:
            load = net_at_slip - math.copysign(self.load_static_fraction * static_nm, direction)
        return min(max(load, -self.load_limit_nm - known_nm), self.load_limit_nm - known_nm)

    def hold_static_nm(self, scheduled_nm: float, met_nm: float | None, floor_nm: float) -> float:
        """Static valve friction (N*m) the hold's drive test and stuck ramp are scheduled on: the
        friction the Δp schedule predicts (``scheduled_nm``), lowered to the friction the hold
        has met (``met_nm``, :attr:`SlipEdges.static_nm`; None: not met yet) but not below
        ``floor_nm`` (the lowest the valve can have) -- the told Δp is only the prior.

        Told max on a valve at Δp 0 (Ts 0.5 instead of 5.5 N*m), the drive test judged every
        breakaway of the hold (at ~0.5 N*m) as "not the drive's" and learned no jump, and the
        stuck ramp (5.5 N*m per ``stuck_ramp_time_s``) broke the valve loose 11x faster than
        quasi-static: it slid 4.5 mrad across the 1.3 mrad deadband each way, a hunt the learner
        never saw (adaptation grid, Δp 0 told 6206 kPa).  Never raised above the schedule: a
        reading above it would only make the ramp more violent."""
        if met_nm is None:
            return scheduled_nm
        return min(max(met_nm, floor_nm), scheduled_nm)

    @staticmethod
    def accepts(pending: float, applied_nm: float, saturated: bool) -> bool:
        """Whether an integrator change ``pending`` (same sign as the torque it adds) may be
        taken with the drive at ``applied_nm`` (N*m, the clamped torque): always while the
        current is not limited, and while it is, only a change that takes the request back
        toward the limit (conditional integration).  Freezing it outright also froze the relax
        of a settled valve held at the continuous-current clamp: the request stayed above the
        continuous current and the I2t jam fault latched on a valve that was held."""
        return not saturated or pending * applied_nm < 0.0


class SlipEdges:
    """The edges of the static-friction band a settled, relaxing drive has met: per slip
    direction (+1 opening, -1 closing), the drive torque beyond the known load (N*m, valve
    side) at the latest slip that way.  Both edges give the steady unknown load (their mean)
    and the static friction really met (half their difference) without the Δp schedule
    (:meth:`IntegralPolicy.learn_load`).  Forgotten with the controller (reset) and when the
    friction schedule changes (the known load the torques are net of changes with Δp)."""

    def __init__(self) -> None:
        self.edges: dict[int, float] = {}

    def reset(self) -> None:
        self.edges.clear()

    def shift(self, delta_nm: float) -> None:
        """The known load the edges are net of fell by ``delta_nm`` (N*m, valve side; a Δp
        reschedule changed its flow torque): the same edges of the same band, net of the new
        known load, lie ``delta_nm`` higher.  Their difference (the static friction met) and
        whether they are consistent do not change."""
        self.edges = {w: e + delta_nm for w, e in self.edges.items()}

    def opposite(self, direction: float) -> float | None:
        """The edge met the other way from ``direction``, if any."""
        return self.edges.get(-1 if direction > 0.0 else 1)

    def met(self, net_nm: float, direction: float) -> None:
        """A slip in ``direction`` at drive torque ``net_nm`` beyond the known load."""
        self.edges[1 if direction > 0.0 else -1] = net_nm

    def contradicts(self, net_nm: float, direction: float) -> bool:
        """Whether a slip in ``direction`` at drive ``net_nm`` (N*m beyond the known load) lies
        beyond the opposite edge of a band that is :attr:`known` -- an opening slip below the
        closing edge, or the reverse.  No band ``L ± Ts`` has such edges: the reading was no edge
        of it (the integrator pulling a valve back to its target, read as a relax slip), so it is
        not learned; the band is *unknown* from then on (:meth:`reset`: the next slip is learned
        as a first edge, so a band that really moved is not locked out) and the load learned so
        far is kept.  Campaign seed 1082 (Stribeck x 0.81, 2.2 N*m, breakaway start): edges 1.1
        and 3.73 N*m gave 2.41 N*m; the pull back after an overshoot then read as a closing edge
        at 4.48 N*m and its prior put the load at 7.23 N*m; the next move started from a drive
        cocked 5 N*m open, ran 22 mrad past its target and the final hold hunted."""
        opposite = self.opposite(direction)
        return self.known and opposite is not None and (net_nm - opposite) * direction <= 0.0

    @property
    def known(self) -> bool:
        """Whether the steady load is known from these edges: both met and consistent (the
        opening edge above the closing one).  None met, the load is not known (only assumed 0);
        one edge gives it only through the scheduled static level's prior, and of contradictory
        ones one was no edge of the band (:meth:`IntegralPolicy.learn_load`): each may be off by
        about the static friction."""
        return len(self.edges) == 2 and self.edges[1] > self.edges[-1]

    @property
    def static_nm(self) -> float | None:
        """Static friction met (half the band's width, N*m; None before both edges)."""
        if len(self.edges) < 2:
            return None
        return max(0.5 * (self.edges[1] - self.edges[-1]), 0.0)


class SlipWatch:
    """Whether a settled, relaxing valve has left its place: a slip, read by
    :meth:`IntegralPolicy.learn_load` as an edge of the static band.

    A *jump*: the valve's (noise-filtered) angle moved more than ``threshold`` (rad) from where
    it was at the latest settled period; the drive torque of the slip is the one of that period.

    A *creep* (``creep_threshold`` > 0, the default mode): the angle drifted more than
    ``creep_threshold`` from the place where it settled, however slowly; the drive torque is the
    one of the latest period it was still within half that of the place (where it began to give
    way).  Read period to period only, a valve that creeps under a drive beyond its static band
    slower than the stuck-speed threshold (0.03 rad/s, set by the resolver noise) went unseen --
    adaptation grid, friction x 0.5 at Δp 0 told max: the relax pushed the valve toward open
    1.1 N*m beyond its band, it crept 19 mrad/s for 0.45 s to the 8 mrad deadband's edge, the
    integrator pulled it back and the relax sent it off again (~1 Hz, 7-8 mrad, never learned).
    The creep threshold (3x the jump's in the default mode) leaves every slip faster than a
    creep to the jump reading the other modes use, unchanged; a creep is then confirmed after
    ~0.9 mrad (45 ms at 19 mrad/s, well inside an 8 mrad deadband).  Measured on the full
    campaign (seeds 1000-1199, with the re-take below): the same single hunting run with the
    creep threshold at 1x (no separate jump reading) and at 3x; without the re-take the creep
    reading leaves the campaign as it was (the same hunting run and faults, one plateau fewer
    beyond 5e-4 rad).

    Measured and not kept (h17w): re-taking the place after a followed reference shift only
    where the valve has rested again for a settle time.  Campaign seed 1052 read the 6.3 mrad
    jump after a followed 2.9 mrad step as a slip (edge 4.7 N*m) and, 1.3 s later, the
    integrator's pull-back of the valve stuck just outside the deadband as another with the
    drive of before: learned 8.2 N*m on a 4.1 N*m load, hunted.  With the re-take 1052 held, but
    on the full campaign 1022 hunted instead and 1095, a plant beyond the continuous rating,
    latched the I2t fault (docs/control_results.md section 15).  Forgotten (:meth:`reset`) when
    a planned move starts."""

    def __init__(self, threshold: float, creep_threshold: float = 0.0):
        self.threshold = threshold
        self.creep_threshold = creep_threshold
        self.reset()

    def reset(self) -> None:
        self.recent: tuple[float, float] | None = None   # (drive N*m, valve rad) of the latest settled period
        self.place: float | None = None       # rad, the valve angle where it settled (creep)
        self.edge_nm: float | None = None     # N*m, drive torque beyond the known load while there

    def settled(self, net_nm: float, valve: float) -> None:
        """A settled, relaxing period: drive torque ``net_nm`` beyond the known load (valve side,
        N*m) and the valve's filtered angle ``valve`` (rad)."""
        self.recent = (net_nm, valve)
        if self.creep_threshold > 0.0:
            if self.place is None:
                self.place = valve
            if abs(valve - self.place) <= 0.5 * self.creep_threshold:
                self.edge_nm = net_nm

    def left(self, valve: float) -> tuple[float, float] | None:
        """``(drive torque of the slip N*m, distance moved rad)`` once the valve has jumped from
        its latest settled angle or crept from its place (both then forgotten), else None."""
        slip = None
        if self.recent is not None and abs(valve - self.recent[1]) > self.threshold:
            slip = (self.recent[0], valve - self.recent[1])
        elif self.place is not None and self.edge_nm is not None and abs(valve - self.place) > self.creep_threshold:
            slip = (self.edge_nm, valve - self.place)
        if slip is not None:
            self.reset()
        return slip


class JumpLearner:
    """Measures the breakaway jumps the valve actually makes while holding.

    The nominal jump ``2 (Ts - Tc)/K`` assumes nominal friction and coupling; a worn valve or
    a soft coupling (x 0.1 stiffness) jumps much further, and a deadband sized for the
    nominal jump would then hunt.  Each breakaway outside a planned move (stuck -> sliding ->
    stuck) gives a measured jump; the ratio measured/nominal is tracked with gain ``gain``.
    Moves shorter than ``min_jump`` (three resolver counts) are reading noise and are ignored.

    The jump is the change of the *tracking error* (valve − reference) across the slide, not
    the valve's travel: while the reference follows a ramp, the travel includes the ramp's,
    and a 10 %/s ramp 50 -> 40 -> 50 % was read as a jump 11x the nominal one (a 28 mrad
    deadband: the integrator froze and the valve stopped 1.7 % short).  Across a stick-slip
    jump the error changes by the jump whether the reference holds or moves slowly; across
    a slide that follows a ramp it changes by the lag only.  (The caller chooses the frame:
    the default law's v2 hands the tracking error, the other state-feedback modes the valve
    angle, as before.)

    A slide *driven onto the target* is no jump (``catch_up_periods``, v2; :meth:`_driven_to`): a
    valve stuck more than twice the jump it is known to make short of the target, that slides for
    at least ``catch_up_periods`` and comes to rest inside the deadband, went as far as the target
    was, not as far as its friction threw it.  A stick-slip jump is a half swing of the coupling
    mode (read as ~10 ms nominal, ~30 ms at K x 0.1 through the speed window); `startup`'s cold
    start ends its first move with the valve stuck 3.8e-2 rad behind the reference, the hold
    then drove it onto the target in 0.13 s, and read as a jump (7.9x nominal) that made a 2e-2
    rad deadband in which the valve sat through the whole 23 -> 25 % ramp (1.9e-2 rad behind).
    Measured and not kept (h19r): any slide onto the target from beyond the band or from twice
    the known jump, whatever its length -- the 40-90 ms slides of LuGre / Stribeck valves with
    backlash (full-campaign seeds 1043, 1073, 1157) were then not learned and those runs hunted.
    A valve that really jumps far stops short of the target by more than the deadband
    (flexible_worst, K x 0.1: 7.7e-2 rad from 0.105 short) and is learned as before.

    The upper limit must cover the robustness box of SPEC §6: friction x 3 on a coupling
    x 0.1 jumps 30x the nominal jump at any Δp (a cap of 20 left that corner hunting at
    Δp = 0); 50 gives margin.

    A disturbance (a load kick, a stalled loop) can look like a big jump, and it inflated the
    deadband (issue 13.4: two 60 ms ±25 N*m kicks, ratio x16, the valve resting 7 % off its
    demand).  So a measurement must be plausible as the drive's own breakaway: the drive broke
    the valve loose only if its torque on the valve (beyond the load it holds) had reached the
    lowest static friction the valve can have (the caller judges it: ``driven``).  A valve
    that breaks away with less and ends up further from the target by more than the deadband
    was displaced by something else: that move is not learned, and neither is any breakaway
    until the valve has rested within the deadband again (the return from the displacement is a
    recovery, not stick-slip) or a new move starts.  :meth:`reset` (a fault reset) returns to the nominal
    ratio, so nothing learned before a fault outlives it.

    Resolver noise and small followed steps are no breakaways (campaign, h14r: 7 of the 9
    hunting runs among seeds 1000-1099 had ~1 count rms valve noise).  With single samples, a
    "stuck -> sliding -> stuck" flicker of the speed estimate read 4 counts of noise as a
    0.38 mrad jump, and a followed 1.9 mrad demand step moved the tracking-error frame by
    1.9 mrad while the valve stood still; each such reading pulled the ratio halfway toward
    0.1, the deadband fell below the real jump (16 mrad on a K x 0.41 coupling) and the
    integrator hunted across it (seed 1084: ratio 4.2 -> 2.3 -> 1.2, 3 reversals of 15-21 mrad on
    the final hold).  So the caller may hand ``travel``, the valve's own angle averaged over the
    speed window (rad): a breakaway is learned only if the valve itself travelled at least
    ``min_jump`` by that reading (the average of n samples has 1/sqrt(n) of the noise).
    """

    def __init__(self, gain: float = 0.5, limits: tuple[float, float] = (0.5, 50.0), min_jump: float = 3e-4,
                 rest_periods: int = 1, cross_hold: bool = False, catch_up_periods: int = 0,
                 chain_periods: int = 0, unchain_rewound: bool = False, cross_met_margin: float = 0.0,
                 cross_until_move: bool = False, cross_keep_after: int = 0, cross_keep_unmet: bool = False):
        self.gain = gain
        #: h32f: at the move that returns the widening, a direction with no jump measured in it
        #: (:attr:`met`) keeps its widened ratio (full box 1190: the unmet −1 way 6.27 -> 3.64, the
        #: integrator then pushed the valve into an 8.17-nominal crossing)
        self.cross_keep_unmet = cross_keep_unmet
        #: h32f: > 0: a planned move returns the widening to the jumps' own ratios (as
        #: ``cross_until_move``, which this implies) only while fewer than this many crossings
        #: (:attr:`crossings`, since :meth:`reset`) have been counted; after that the widening is
        #: the valve's and holds across moves.  0 = off (``cross_until_move`` alone decides)
        self.cross_keep_after = int(cross_keep_after)
        #: h32b: a crossing widens both ways (``cross_hold``) only until the next planned move: the
        #: hold at a new target sizes its deadband by the jumps' own ratios (:attr:`own`).  Friction
        #: x 1.5, seed 2001: plateau 6's chained crossing (3.66 nominal) held plateau 7's 9.2 mrad
        #: step inside its 9.23e-3 rad band; a limit cycle about the target crossed is the same hold
        self.cross_until_move = cross_until_move
        #: h32b: > 0: the ratio a chained crossing sets both ways is at most this times the
        #: largest quasi-static jump ratio the drive implied at the chain's breakaways (the
        #: ``drive_ratio`` handed to :meth:`update` the last period at rest before each piece),
        #: and never below the last piece's own jump (0 = off: the whole chain, as before)
        self.cross_met_margin = cross_met_margin
        #: h31c: a piece is no rest of the breakaway before if the coupling's twist (gear output
        #: minus valve, valve side, rad) rose the piece's way by half the nominal jump or more
        #: between that breakaway's end and the piece's start (:meth:`_chain_start`; needs
        #: ``twist`` in :meth:`update`)
        self.unchain_rewound = unchain_rewound
        #: a breakaway the same way that starts within this many periods of the end of the one
        #: before (0 = off) is read by the limit-cycle breaker (``cross_hold``) as the rest of it
        #: (:meth:`_chain_start`)
        self.chain_periods = int(chain_periods)
        #: a breakaway across the target that lands beyond the deadband sets both directions'
        #: ratios to at least its own (:meth:`ratio_toward`; v2).  Averaged with the small slips
        #: of a creeping valve, the 5-6 mrad crossings of seed 1096 kept a 1.3-1.8 mrad band
        self.cross_hold = cross_hold
        #: periods in a row at rest that end a slide.  A slow (Stribeck) slide reads "stuck" for
        #: a period now and then; ended there it was learned in pieces: seed 1096 (friction
        #: x 0.52, Δp told max instead of 1.5 MPa) swung 5-6 mrad each way at ~6 Hz while the
        #: learner read 2.3-3.8 mrad pieces, so the deadband stayed at 1.3-1.8 mrad
        self.rest_periods = max(int(rest_periods), 1)
        self.min_jump = min_jump          # rad: smaller "jumps" are resolver noise, not breakaways
        #: a slide driven onto the target that lasted at least this many periods is no jump
        #: (:meth:`_driven_to`; v2; 0 = off)
        self.catch_up_periods = int(catch_up_periods)
        self.limits = limits
        self.reset()

    def reset(self) -> None:
        """Forget the learned ratio (nominal jumps) and any breakaway in progress."""
        self.ratio = 1.0
        self._stuck_at: float | None = None
        self._rest = 0                        # periods at rest in a row
        self._start: float | None = None
        self._slide = 0                       # periods since the breakaway in progress
        self._stuck_travel: float | None = None   # the filtered valve angle at _stuck_at / _start
        self._start_travel: float | None = None
        self.disturbed = False            # displaced by something else: learning paused
        self._driven = True               # the breakaway in progress was the drive's
        self.rejected = 0                 # breakaways not learned as implausible (diagnostics)
        #: the ratio learned from the jumps in each direction alone (+1 opening, -1 closing; a
        #: direction not met yet is absent): :meth:`ratio_toward`
        self.directed: dict[int, float] = {}
        #: the same, learned from the jumps alone, never widened by the breaker (``cross_until_move``)
        self.own: dict[int, float] = {}
        self._widened = False             # the breaker widened ``directed`` since the last move
        self.met: set[int] = set()        # directions a jump was measured in (``cross_keep_unmet``)
        self.crossings = 0                # breakaways across the target beyond the band (diagnostics)
        #: (start rad, way ±1, the period it ended (:attr:`_period`), ended inside the deadband) of
        #: the latest breakaway, pieces chained (:meth:`_chain_start`)
        self._chain: tuple[float, int, int, bool] | None = None
        #: the lowest and highest twist (rad) from that breakaway's start up to the next start
        self._chain_twist: tuple[float, float] | None = None
        self._slide_twist: tuple[float, float] | None = None   # the same over the slide in progress
        self._stuck_twist: float | None = None   # the twist at _stuck_at (rad), then at _start
        self._start_twist: float | None = None
        self._period = 0                  # periods updated (the clock of the chain's end)
        #: the drive's quasi-static jump ratio (signed, + opening) at _stuck_at, then at _start
        #: (``cross_met_margin``), and the largest toward its way over the chain's pieces
        self._stuck_drive: float | None = None
        self._start_drive: float | None = None
        self._chain_drive: float | None = None
        self.met_bounded = 0              # chained crossings the met friction's jump bounded (diagnostics)
        self.catch_ups = 0                # slides driven onto the target, not learned (diagnostics)

    def drop_slide(self) -> None:
        """Forget a breakaway in progress: the law was not in charge until now (the fine stage's
        hand-back), and what moved the valve in between was not this law's hold.  Ended later
        across the stage's pulses, the cold start's catch-up (0.62 s) was read at the hand-back
        (3.04 s) as one 3.8e-2 rad jump (`startup`, observer_fp)."""
        self._start = None
        self._stuck_at = None

    def rescale(self, factor: float) -> None:
        """The nominal jump changed by 1/``factor`` (the friction terms were rescheduled for
        another Δp): keep the jumps measured, i.e. multiply every learned ratio by ``factor``
        (within the limits), and drop a breakaway in progress."""
        lo, hi = self.limits
        self.ratio = min(max(self.ratio * factor, lo), hi)
        self.directed = {w: min(max(r * factor, lo), hi) for w, r in self.directed.items()}
        self.own = {w: min(max(r * factor, lo), hi) for w, r in self.own.items()}
        self._start = None

    def ratio_toward(self, direction: float) -> float:
        """The measured/nominal jump ratio of breakaways in ``direction`` (sign: + opening),
        once one has been met in it; the ratio of both directions until then.

        The jumps need not be alike both ways (campaign seed 1189, Stribeck friction x 0.55,
        6.5 N*m unknown load, 1.5 mrad backlash: opening jumps 8.6-12.2 mrad, closing 2.8-5.0):
        a deadband sized from their mean (2.3-3.8 mrad) lets the integrator push a valve
        3-5 mrad short into an opening jump that lands as far beyond, and back: a hunt of
        4.4 mrad.  The deadband toward the side the integrator would push is sized by that
        side's own jump."""
        return self.directed.get(1 if direction > 0.0 else -1, self.ratio)

    def _chain_start(self, way: int, inside: bool, nominal_jump: float = 0.0,
                     twist: float | None = None, target: float | None = None) -> float:
        """Where the breakaway that just ended (from ``self._start``, ``way`` ±1) began, its
        pieces joined: a slide that starts the same way within ``chain_periods`` of the end of the
        one before is the rest of that breakaway, and the chain's start is the first piece's.

        A jump can stop for a few periods on the way (the backlash taken up, the coupling's
        twist not yet spent) and go on by itself: campaign seed 1112 (stick-slip x 0.59, K x 0.86,
        0.64 mrad backlash) jumped 6.3 mrad from 3.8 mrad short to 2.5 mrad beyond the target,
        resting 11 ms at 0.3 mrad beyond it on the way.  Read as two jumps (4.1 mrad ending inside
        the 1.8 mrad deadband, then 2.1 mrad starting inside it), neither crossed the target and
        beyond the band, so the limit-cycle breaker never saw the crossing, the pieces pulled the
        ratio down (0.87 -> 0.67) and the final hold hunted 3.5 mrad.  The window is the hold's
        settle time (:attr:`IntegralPolicy.settle_time_s`): slips before it are the move's own.

        Only a piece that came to rest *inside* the deadband (``inside``, of the piece before) is
        continued: one that ended beyond it across the target has been judged by the breaker at
        its own size already.  Chaining those too widened the band to the whole chain on nominal
        valves (nominal box, 40 runs: 66 -> 71 plateaus > 8e-4 rad; h21h).

        ``unchain_rewound`` (h31c): a piece that started after the coupling was wound up again its
        way (``twist`` at its start minus the lowest twist, its way, since the piece before started) by
        at least half the ``nominal_jump`` (rad; floored at ``min_jump``) *from beyond the target*
        (``target``: the piece before had crossed it already) was the gear output's overtravel
        driving the valve away from the target, not the breakaway's unspent twist going on (which
        only unwinds): it is not chained.  A piece that starts short of the target while the hold
        winds on is chained as before: unchained there too (the twist rose 0.65-0.69 mrad, over
        half of a 1.13 mrad nominal jump at low Δp), full-box seed 1191 lost the chain's crossing
        and hunted on its final hold.  Friction x 1.5,
        nominal-box seed 2001 plateau 6: a 10.1 mrad jump rested inside the band, the gear output
        kept winding (twist 36.8 -> 41.1 mrad, the valve at rest), 12 ms later the valve slid
        6.7 mrad more; joined, the 16.8 mrad "jump" across the target set both ways to 3.66
        nominal, a 9.23e-3 rad deadband that held plateau 7 8.39e-3 short (docs section 68/71)."""
        start = self._start
        chain = self._chain
        span = self._chain_twist
        rewound = (self.unchain_rewound and twist is not None and self._start_twist is not None
                   and span is not None and target is not None and way * (target - self._start) < 0.0
                   and way * (self._start_twist - (span[0] if way > 0 else span[1]))
                   >= max(0.5 * nominal_jump, self.min_jump))
        drive = None if self._start_drive is None else max(way * self._start_drive, 0.0)
        if (self.chain_periods > 0 and chain is not None and chain[1] == way and chain[3]
                and self._period - chain[2] <= self.chain_periods + self._slide and not rewound):
            start = chain[0]
            if drive is not None and self._chain_drive is not None:
                drive = max(drive, self._chain_drive)
        self._chain_drive = drive
        self._chain = (start, way, self._period, inside)
        self._chain_twist = self._slide_twist
        return start

    def _driven_to(self, target: float | None, valve: float, band: float, known: float) -> bool:
        """Whether the slide that just ended (from ``self._start`` to ``valve``) was driven onto
        the target rather than thrown by a breakaway: it started more than twice the jump this
        valve is known to make that way (``known``, rad) and outside the deadband ``band`` short
        of ``target``, and came to rest inside the deadband (on either side of the target)."""
        return (target is not None and self._slide >= self.catch_up_periods
                and abs(target - self._start) > max(band, 2.0 * known) and abs(target - valve) <= band)

    def update(self, valve: float, stuck: bool, holding: bool, nominal_jump: float,
               target: float | None = None, band: float = 0.0, driven: bool = True,
               travel: float | None = None, twist: float | None = None,
               drive_ratio: float | None = None) -> None:
        """One period: ``valve`` the angle the jump is read from (rad: the valve angle, or the
        tracking error valve − reference, see the class docstring), at rest or not, holding (no
        planned move), the nominal jump (rad); ``driven``: the drive's torque could have broken
        the valve loose (read when it does), ``target`` (in the same frame as ``valve``) and
        ``band`` (rad): the target and the deadband in force, for the end of a displacement;
        ``travel`` (rad, optional): the valve's own noise-filtered angle, which must have moved
        by ``min_jump`` for a breakaway to count (None: no such check); ``twist`` (rad, optional,
        + the valve's positive way): the coupling's twist, gear output minus valve, valve side, for
        ``unchain_rewound`` (None: chained as before); ``drive_ratio`` (optional, signed, + opening):
        the quasi-static jump the drive on the valve this period would make over the nominal one
        (drive beyond the loads / scheduled static friction x K_model / K read), for
        ``cross_met_margin`` (None: the chain's widening unbounded)."""
        until_move = self.cross_until_move or self.cross_keep_after > 0
        if (not holding and until_move and self._widened
                and (self.cross_keep_after <= 0 or self.crossings < self.cross_keep_after)):
            # a new demand: the crossing met at the last target widens no more (h32f: unless
            # the valve has crossed cross_keep_after times: then its jumps are that long)
            self.directed = {w: r if (self.cross_keep_unmet and w not in self.met) else self.own.get(w, r)
                             for w, r in self.directed.items()}
            self._widened = False
        if not holding:
            self._start = None
            self._chain = None
            self.disturbed = False
        elif not stuck and self._stuck_at is not None and self._start is None:
            self._start = self._stuck_at                      # broke away while holding
            self._slide = 0
            self._start_travel = self._stuck_travel
            self._start_twist = self._stuck_twist
            self._start_drive = self._stuck_drive
            self._slide_twist = None if self._stuck_twist is None else (self._stuck_twist, self._stuck_twist)
            self._driven = driven
        elif stuck and self._start is not None and self._rest + 1 >= self.rest_periods:
            moved = valve - self._start
            if (not self._driven and target is not None
                    and abs(target - valve) > abs(target - self._start) + band):
                self.disturbed = True                         # displaced off the target, not by the drive
            real = travel is None or self._start_travel is None or abs(travel - self._start_travel) >= self.min_jump
            if abs(moved) >= self.min_jump and real:
                way = 1 if moved > 0.0 else -1
                own = self.directed.get(way)
                if self.disturbed:
                    self.rejected += 1
                elif self.catch_up_periods > 0 and self._driven_to(
                        target, valve, band, (self.ratio if own is None else own) * nominal_jump):
                    self.catch_ups += 1        # its length was where the target was, not the friction's
                else:
                    self.ratio += self.gain * (abs(moved) / nominal_jump - self.ratio)
                    seen = abs(moved) / nominal_jump
                    own = seen if own is None else own + self.gain * (seen - own)
                    self.directed[way] = min(max(own, self.limits[0]), self.limits[1])
                    mine = self.own.get(way)
                    mine = seen if mine is None else mine + self.gain * (seen - mine)
                    self.own[way] = min(max(mine, self.limits[0]), self.limits[1])
                    self.met.add(way)
                    origin = self._chain_start(way, target is None or abs(target - valve) <= band,
                                               nominal_jump, twist, target)
                    if origin != self._start:
                        chained = abs(valve - origin) / nominal_jump
                        if self.cross_met_margin > 0.0 and self._chain_drive is not None:
                            # h32b: the chain can be longer than any breakaway at the friction met:
                            # a piece the gear output's overtravel drove (friction x 1.5, seed
                            # 2001: 10.1 + 6.7 mrad, 3.66 nominal, where the drive at let-go
                            # allows ~1.5 x the margin) -- widen no further than that allows
                            bound = max(seen, self.cross_met_margin * self._chain_drive)
                            if chained > bound:
                                chained = bound
                                self.met_bounded += 1
                        seen = max(seen, chained)
                    if (self.cross_hold and target is not None and (target - origin) * (target - valve) < 0.0
                            and abs(target - valve) > band):
                        # the breakaway carried the valve across the target and beyond the
                        # deadband: the integrator would push it back by a jump of that size
                        # and hunt.  Both directions expect at least this jump (limit-cycle
                        # breaker: the band widens to the jump that was really made)
                        for w in (1, -1):
                            self.directed[w] = min(max(self.directed.get(w, self.ratio), seen), self.limits[1])
                            self.own.setdefault(w, self.ratio)
                        self._widened = True
                        self.crossings += 1
            self.ratio = min(max(self.ratio, self.limits[0]), self.limits[1])
            self._start = None
        if stuck and self.disturbed and self._start is None and target is not None and abs(target - valve) <= band:
            self.disturbed = False                            # at rest within the deadband again
        self._stuck_at = valve if stuck else None
        self._rest = self._rest + 1 if stuck else 0
        self._slide += 1
        self._period += 1
        self._stuck_travel = travel if stuck else None
        self._stuck_twist = twist if stuck else None
        self._stuck_drive = drive_ratio if stuck else None
        if twist is not None:
            # the coupling's twist from a breakaway's start to the next one's: a jump unwinds it,
            # its unspent twist going on only unwinds it further; wound up again from its lowest
            # (the jump's way) the gear output drove it
            if self._start is not None:
                lo, hi = self._slide_twist or (twist, twist)
                self._slide_twist = (min(lo, twist), max(hi, twist))
            elif self._chain_twist is not None:
                self._chain_twist = (min(self._chain_twist[0], twist), max(self._chain_twist[1], twist))

