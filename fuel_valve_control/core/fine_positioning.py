"""Fine positioning of a stuck valve by preloaded twist and a shaped torque pulse (issue 14).

Physics (SPEC §6 feasibility study).  A valve with static friction above its Coulomb level
cannot be crept to a target: every breakaway under a quasi-static torque jumps
``2 (Ts - Tc)/K`` (4.6e-3 rad at max Δp), and reacting after breakaway is too late (the jump
is over in ~6 ms).  What works is acting *before* the valve moves:

1. hold the gear output ``θ1 = θm/N`` stiffly on the motor resolver (48x finer than the valve
   resolver), with the coupling torque fed forward, so the twist ``φ = θ1 - θL`` is set, not
   suffered;
2. *park* the twist where a released valve would swing to the target: a valve released from
   rest slides about the twist where coupling torque balances load + Coulomb friction
   (``φe``) and stops again symmetrically, so a move ``d`` needs ``φ_park = φe + d/2`` -- below
   the breakaway twist ``φb``, so parking does not move it;
3. break it loose with a short doublet pulse of the gear output (+a, -a, -a, +a over four loop
   periods, peak ``A`` above the park) that overdrives ``φb`` briefly and returns to the park
   before the valve has swung far, so the swing is the one the park planned;
4. learn from each pulse: the measured move gives ``φe = φ_park - d/2`` (pulse contribution
   included), a pulse that did not move the valve raises ``φb``, one that did lowers it
   toward the peak that worked.  Both per direction and per Δp band, bounded.

Small errors (<= ``fine.doublet_max_error_rad``, 1e-3 rad) get a **torque doublet** instead
of the servo-blended pulse: preload to a staircase level below the learned breakaway, then one
period of kick (``fine.kick_current_a`` on the hold torque), then the whole current backwards
(one period, then half), then the servo to the final twist.  Measured on the bare plant (true
states, exact breakaway, max Δp, task h14f): breaking loose at ~0 overdrive moves the valve
0.86-1.0e-3 rad at <= 30 A (the servo-blended pulse: 1.3-1.9e-3), and each 0.057e-3 rad of
twist overdrive adds ~0.25e-3 rad (~4 rad/rad) -- so the staircase climbs in small steps
(``fine.doublet_probe_step`` = 0.03 of the static band, 0.07e-3 rad), on past the learned
breakaway if need be, from ``fine.doublet_sigmas`` (2) learned scatters below it, and a doublet
that has not moved the valve 4 periods after its apex did not break it.  The breakaway's mean
and rms scatter from stop to stop are learned per direction and Δp band from every breakaway
seen: the main law's from rest (one per move, when it fits the model) and each doublet's (task
h17f; measured scatter 0.3-0.9e-3 rad of twist on the nominal box: 2-8 % static scatter plus
ripple).  A preload that breaks the valve loose slides it the whole 4.6e-3 rad: the preload's
last ``fine.park_approach_rad`` is approached slowly, as the servo overshot the end of a fast
one by 2.7e-4 rad (median), and two such breakaways on one plateau hand it back.  A doublet that retreats to a *sized* final twist
instead (-i, +i over two periods) moved 1.6e-3 + 0.9 d: sized, but never small.

Stopping rule: the smallest move the stage can make -- a doublet's, at ~0 overdrive -- is
learned per direction and Δp band (the mean of the doublets' moves, weight 0.3 each; task
h17f: the servo-blended pulse's larger moves taken in held 15 of the 29 nominal-box plateaus
> 8e-4 rad as "below the smallest move"); an error below ``fine.min_move_fraction`` (0.5) of it
is not pulsed -- the move would leave the valve further off (m improves e only if m < 2|e|).
A servo-blended pulse (errors beyond the doublet's) aims ``fine.approach_short_rad`` short of
the target, so that the doublet finishes from the same side.

Never a hunt by the metric (task h19x).  The campaign calls a plateau hunting when its valve
reverses direction twice (moves > 1 count) from 0.3 s after the step with more than 2 counts half
peak-to-peak (:mod:`fuel_valve_control.common.hunting`); the stage's moves are larger than the
errors they are for (a doublet crosses the target 4 times in 5, a servo-blended pulse for 1-2e-3
rad 3 times in 4), and on main 26f43b9 4 of 40 nominal-box runs hunted by them.  The stage counts
the valve's reversals on the plateau as the metric does (its :class:`ReversalCounter`, on the
measured angle averaged over ``REVERSAL_MEAN_PERIODS``, from ``fine.reversal_lead_s`` before the
metric's window) and never makes the reversal that would be the second; the move that would be
the last one allowed (the way back after a crossing) must not cross again: up to twice
``fine.no_cross_short`` x the stick-slip jump it is a doublet, beyond that a servo-blended pulse
aiming that far short (:meth:`FinePositioner._cross_guard`).  A valve at rest past the breakaway
twist the stage would plan is left to the main law's hold (:meth:`FinePositioner._rests_beyond_breakaway`).

What limits it (nominal box, ``benchmarks/robustness.py --box nominal --runs 20``, 240
plateaus): final error median 3.3e-4, p95 9.6e-4, max 3.6e-3 rad (before this task 3.8e-4 /
1.29e-3 / 2.0e-3).  The floor is half the smallest move (~0.45e-3 rad at 30 A and one-period
current steps against the 57 A/ms slew) plus the move spread from the staircase step times
~4 rad/rad; the tail is breakaways while preloading: the static level is drawn anew at every
stop (2-8 % rms = 0.2-0.9e-3 rad of twist), so a preload close enough for a small overdrive is
sometimes above the new level, and the valve jumps the whole 4.6e-3 rad; the pulses that bring
it back from the other side use up ``fine.max_crossings``.  (Retreating at once when the
valve breaks during the preload measured worse: 45 vs 29 plateaus > 8e-4.)

Knowing when the model does not fit (task h16f, per-run traces of the quick campaign).  On the
full campaign the stage was far worse than observer_ff (median 1.7e-2 vs 2.2e-3 rad, 6 of 30
runs hunting): on a valve with an unknown load or a soft coupling the preload, planned from the
nominal twists, *unloaded* the coupling and the valve slid 7e-3 rad away at every pulse; on a
noisy demand every conditioned shift of a count restarted the stage with a fresh pulse budget;
at 0.9 ms resolver delay and 18 V the 60 Hz stiff hold limit-cycled at +-30 A; with friction
x0.6 every preload broke the valve loose for a whole jump across the target.  The stage now
engages only on evidence that the model describes the valve, and otherwise leaves the plateau
to the main law's integral hold (observer_ff behaviour):

* the twist holding the valve at rest lies inside the nominal static band widened by
  ``fine.fit_margin``;
* the twist at which the main law last broke the valve loose (from a rest of the engage time,
  once it has moved two tolerances) lies within ``fine.breakaway_fit`` x T_s/K of the nominal
  breakaway twist -- measured within 0.15 on the nominal plant with scatter, 0.5-2.7 off on the
  valves the stage hunted on (friction x0.6 or x2-3, soft coupling, load, Δp wrong); the stage
  waits for such a breakaway on the plateau (or ``FRESH_WAIT`` engage times without one);
* its learned misfit record for the direction and Δp band (``fine.misfit_*``) is good.

Once engaged it hands the plateau back (the main law restarts from :meth:`hold_torque`) when
the valve slides away from the target while preloading, a move leaves it beyond
``fine.max_move_rad``, the learned twists leave the plausible range, or the stiff hold
limit-cycles (feedback torques above 0.3 x the cap that keep reversing; 0 on every nominal
run, 4.6 on the one that did).  A demand shift within the tolerance is the same plateau.
Quick campaign (30 runs, seeds 1000 and 3000): hunting runs 6 -> 0 (observer_ff 0) and
1 (observer_ff 1); the stage engages on 10 of 360 full-box plateaus and 234 of 240 nominal ones.

Earlier measurements (task h14b) of the servo-blended pulse, which larger errors still get:
a pulse that breaks the valve loose moves it 1.3-2.5e-3 rad when less is wanted, because the
gear output (J1 = Jm N² = 9x the valve's inertia) cannot retreat within the valve's 6 ms half
swing at <= 30 A with the current slewing ~57 A/ms at 28 V.  The pulse torque is capped at
``fine.peak_current_a`` (30 A; uncapped 36 A) -- a slower pulse, whose reached twist is measured
and learned from -- and a plateau on which pulses carried the valve across the target
``fine.max_crossings`` times is left alone: its moves are larger than the error, pulsing on
would be hunting.

Compared with the issue's prototype (measured with per-pulse traces, issue 14 task h14b):

* the pulse as the servo realises it reaches only 60-75 % of its planned peak: the PULSE phase
  starts its sin² blend at ``t = one period`` (the first rise period is skipped) and samples
  the acceleration feed-forward at the period boundaries, where a two-period sin² rise has
  none.  Fixed (first period at t = 0, feed-forward at the period's midpoint) the twist reaches
  >= 93 % of plan -- but then, with the preload raised to just below the learned breakaway
  (not capped at the final twist) and a staircase of 0.05 x the static band, pulses that break
  the valve loose at an overdrive of ~0 still move it 1.7-1.9e-3 rad, and the nominal box got
  worse (median 6.5e-4 .. 2e-3, p95 2.2-5e-3 over six variants, incl. a one-period full-current
  retreat) -- so those changes are not in;
* the floor is the retreat acceleration of the gear output at the instant of breakaway: a
  two-mass model (K 480 N*m/rad, valve 1.76e-3 kg*m², excess Ts - Tc 1.1 N*m) released at the
  apex of a parabola of retreat acceleration A gives a smallest move of 1.5 / 0.96 / 0.73 /
  0.59e-3 rad for A = 1000 / 2000 / 3000 / 4000 rad/s² (3000 rad/s² at the gear output is the
  whole 30 A), +0.4e-3 rad per 0.1e-3 rad of overdrive.  The prototype's 0.6e-3 rad therefore
  needs the full current *already* reversed at the apex and more than 30 A;
* the breakaway level is drawn anew at every stop (scatter up to 8 % rms = 0.9e-3 rad of
  twist at max Δp), so only a staircase of small steps (pulses that do not move the valve cost
  nothing) bounds the overdrive.

All learned quantities are twists in rad *relative to* the nominal model's prediction
``(load(θ) ± T(Δp)) / K_nom``, so they stay meaningful across positions; they are the
:class:`FineLearner`, which can be saved to and loaded from a JSON file.

Angles rad (valve side), torques N*m at the motor unless named, positive = opening.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, fields, replace
from pathlib import Path

import numpy as np
from scipy.special import erf as _erf

from ..common.contract import RESOLVER_COUNT_RAD
from ..common.hunting import HUNT_REVERSALS, ReversalCounter
from .model import NominalModel
from .valve_rest import ValveRest

IDLE, PARK, PULSE, OBSERVE, HOLD = "idle", "park", "pulse", "observe", "hold"
#: fraction of each doublet's move taken into the learned smallest move (the first is taken whole)
MOVE_GAIN = 0.3
#: servo limit-cycle watch: feedback torques beyond this fraction of the stage's cap that reverse
#: sign count one, the count leaks by this factor per period
OSC_TORQUE_FRACTION, OSC_LEAK = 0.3, 0.95
#: ... and at this count the servo limit-cycles: the stage hands the plateau back.  Measured
#: (quick campaign, per-run maximum while observing after a pulse or holding): 0 on all 12
#: nominal-box runs and on 9 of 11 full-box runs, 1.0 on two, 4.6 on the run whose 60 Hz hold
#: limit-cycled at +-30 A (resolver delay 0.89 ms, 18.4 V supply)
OSC_LIMIT = 2.0
#: breakaways below the planned preload on one plateau that hand it back: the preload lies
#: ``fine.doublet_sigmas`` learned scatters below the learned breakaway (2 of 531 doublets broke
#: loose below it on 10 nominal-box runs), so twice on one plateau says the learned twists do not
#: describe this valve (quick campaign run 1010, friction x0.58: a whole jump at every preload,
#: and the main law, handed the plateau after three of them, hunted on the next)
EARLY_BREAKS = 2
#: without a breakaway seen on the plateau the stage waits this many engage times (a step the
#: main law does not move the valve for)
FRESH_WAIT = 10
#: the stage counts the valve's reversals on the mean of this many resolver samples: on the raw
#: samples (0.25 count rms noise, quantised) it counted up to 236 reversals on nominal-box plateaus
#: where the metric (true angle) counts 0, and held 46 of 82 plateaus > 8e-4 rad for them
REVERSAL_MEAN_PERIODS = 8
#: fine.learned_scale_*: the main-law breakaways per direction whose friction ratios are kept (their median
#: is the direction's reading; two are read as their mean when they agree within fine.breakaway_fit -- one
#: alone is not: a nominal-box valve showed an opening "breakaway" at -0.40 among seven at +-0.84..1.10, and
#: read from it the stage planned from friction x0.76; task h26f), and the change of the read scale (or load
#: offset, in T_s units) that re-plans the stage's model
SCALE_SAMPLES, SCALE_REPLAN = 3, 0.1
#: ... and on the scale read the stage stays out of a move whose planned breakaway twist takes more than this
#: fraction of the continuous current to hold: its pulses on top of such a hold heat the I2t budget (h18g, docs
#: §19: a loaded valve near its rating latched the fault; friction x2 at 90 % open, ~14 of 15 A, task h26f: the
#: hold's twist sagged between the pulses and they never reached the breakaway)
SCALE_HOLD_FRACTION = 0.8
#: fine.start_quantile (task h29q): the learned staircase start, in learned scatters below the learned breakaway,
#: stays within [START_SIGMAS_MIN, START_SIGMAS_MAX] (the floor keeps 0 meaning "not learned yet"; the ceiling is
#: fine.doublet_sigmas' own range)
START_SIGMAS_MIN, START_SIGMAS_MAX = 1e-3, 10.0


#: fine.apex_policy (task h33p): the level's law is a clipped normal on this many points over +-APEX_LAW_SIGMAS
#: learned scatters (plateau_floor's level_prior: 41 points over +-3 sigma)
APEX_LAW_POINTS, APEX_LAW_SIGMAS = 41, 3.0
#: ... and reads the move model at Δp rounded to this fraction of the rated Δp
APEX_DP_STEP = 0.01
#: the FineConfig options measured together with ``fine.apex_policy`` as one build (C1, docs §88, default since stop
#: 25): while the policy's move tables are not ready (:meth:`FinePositioner.defer_tables`) the stage runs main's
#: staircase with these off -- the build measured before them (stop 24's default), not an unmeasured mix
APEX_BUILD_OFF = ("apex_policy", "retreat_cap", "observe_hold_moved")
#: fine.apex_kick_continuous (task h34m): the preload lies this fraction of the smallest kick's rise below the last
#: unmoved apex (the move model's rise reads the closed loop's +2-3 % high, docs §80.3)
APEX_PRE_MARGIN = 0.05
#: fine.apex_policy: the most kicks its set holds (stop 26).  Every kick is a set of move tables (342 with C1's
#: three: 43 MB, ~41 s of CPU to build) and a column of every try's scoring, so the set is bounded whatever the
#: schema's bounds allow (fine.apex_kick_ratio 1.05 from 4 to 30 A would be 42 kicks: ~4800 tables, ~600 MB,
#: ~10 min of background CPU per signature on the node); past it the set spans the same range in this many
#: geometric steps.  C1's default set (4 / 8 / 16 A) is three.
APEX_MAX_KICKS = 6
#: fine.retreat_trough_bound (task h36g): one retreat period's scale is read between this many points from the full
#: retreat (1) to the hold (0) of the move model's trough (a resolution: interpolated linearly between them)
TROUGH_SCALES = 11


def scaled_retreat(depth, room: float, scales: np.ndarray) -> float:
    """(``fine.retreat_trough_bound``, docs §90, §111) The retreat period's scale: the first of ``scales`` (falling
    from 1, the whole period, to 0, the hold) whose trough depth ``depth(j)`` (rad of twist below the start, a
    callable: one move-model lane each) is within ``room`` (rad), interpolated linearly with the point before it; 1 if
    the whole period fits, 0 if the hold alone does not.  Found by bisection: the ends and log2(len - 1) midpoints
    (5 lane runs for 11 points where the 11-lane batch cost 2-4 ms in the kick period at Δp 0.15 x rated) -- the
    batch's answer, as the depth falls with the scale and a lane's trough does not depend on the lanes run beside it
    (89 batches at Δp 0.15-0.2 x rated, closed loop: every lane equal to the bit, every batch monotonic).  Were the
    depth ever not monotonic, the scale still lies between a point that fits and one that does not."""
    last = len(scales) - 1
    one = {0: depth(0)}
    if one[0] <= room:
        return 1.0
    one[last] = depth(last)
    if one[last] > room:
        return 0.0
    lo, hi = 0, last
    while hi - lo > 1:
        mid = (lo + hi) // 2
        one[mid] = depth(mid)
        lo, hi = (mid, hi) if one[mid] > room else (lo, mid)
    # linear between the last point that crossed and this one (the trough falls with the scale)
    f = (one[lo] - room) / max(one[lo] - one[hi], 1e-12)
    return float(scales[lo] + f * (scales[hi] - scales[lo]))


#: fine.apex_level_law (task h36l, docs §92): a non-normal level law is weighed on this many points (the mixture spans
#: +-3 of its largest scatter, several of the learned one: the normal's 41 points over +-3 learned scatters would
#: space them ~0.5 learned scatters apart), and a scale mixture over this many scatters (log-spaced midpoints)
APEX_MIX_POINTS, APEX_MIX_SCALES = 81, 7


def level_law_scales(kind: str, sigma: float, sigma_hi: float, nu: float) -> tuple[np.ndarray, np.ndarray]:
    """(``fine.apex_level_law``, task h36l, docs §92) The level's law as a scale mixture of normals about the learned
    level: (rms scatters, rad; their weights, summing to 1).

    * ``"normal"``: the learned scatter ``sigma`` alone (C1's law, the default of stop 26).
    * ``"mixture"``: scatters log-uniform between ``sigma`` and ``sigma_hi`` (rad; the widest scatter the stage is
      designed for): the box draws each valve's scatter rms from a range and per stop the level is normal with that
      rms, so with a scatter known only within a range the level's law is the normals' mixture over it -- heavier
      tailed than one normal.  ``sigma_hi <= sigma`` collapses it to ``"normal"``.
    * ``"student"``: a Student-t of ``nu`` degrees of freedom with scale ``sigma`` (the learned rms taken from
      ~``nu`` + 1 stops): its precision Gamma(nu/2, nu/2), on APEX_MIX_SCALES equal-probability quantiles.
    """
    key = (kind, sigma, sigma_hi, nu)
    hit = _LAW_SCALES.get(key)
    if hit is None:                 # (task h40m) 4 of 5 tries ask what the previous asked (the same scatter and Δp)
        hit = _LAW_SCALES[key] = _level_law_scales(kind, sigma, sigma_hi, nu)
        for a in hit:
            a.flags.writeable = False
        while len(_LAW_SCALES) > 8:
            _LAW_SCALES.pop(next(iter(_LAW_SCALES)))
    return hit


_LAW_SCALES: dict = {}


def _level_law_scales(kind: str, sigma: float, sigma_hi: float, nu: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`level_law_scales`, computed."""
    if kind == "mixture" and sigma_hi > sigma * (1.0 + 1e-6):
        u = (np.arange(APEX_MIX_SCALES) + 0.5) / APEX_MIX_SCALES
        return sigma * (sigma_hi / sigma) ** u, np.full(APEX_MIX_SCALES, 1.0 / APEX_MIX_SCALES)
    if kind == "student" and np.isfinite(nu) and nu > 0.0:
        # equal-probability quantiles of the precision lambda ~ Gamma(nu/2, rate nu/2) (the Wilson-Hilferty
        # approximation of the chi-square quantile, as built and tested -- scipy.special.chdtri would give it exactly);
        # the scatter sigma / sqrt(lambda)
        from statistics import NormalDist     # noqa: PLC0415
        u = (np.arange(APEX_MIX_SCALES) + 0.5) / APEX_MIX_SCALES
        zq = np.array([NormalDist().inv_cdf(float(x)) for x in u])
        c = 2.0 / (9.0 * nu)
        chi = nu * np.maximum(1.0 - c + zq * math.sqrt(c), 1e-3) ** 3
        return sigma / np.sqrt(chi / nu), np.full(APEX_MIX_SCALES, 1.0 / APEX_MIX_SCALES)
    return np.array([sigma]), np.array([1.0])


def mixture_level_law(center: float, d: int, scales: np.ndarray, weights: np.ndarray,
                      floor: float | None = None, points: int = APEX_MIX_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """(``fine.apex_level_law``, task h36l, docs §92) The level (absolute twist, rad) toward ``d`` as the mixture
    sum_j weights_j N(``center``, scales_j^2) on ``points`` equally spaced levels over +-APEX_LAW_SIGMAS of the
    largest scatter, truncated from below by ``floor`` (absolute twist, rad, or None): the points then span from just
    above the floor to the larger of the law's top and the floor + the largest scatter (a floor beyond the top: the
    mixture's own far tail above it, no point mass).  Returns (levels ordered toward ``d``, weights summing to 1)."""
    smax = float(np.max(scales))
    lo, hi = -APEX_LAW_SIGMAS * smax, APEX_LAW_SIGMAS * smax
    if floor is not None:
        f = d * (floor - center)
        if f >= lo:
            hi = max(hi, f + smax)
            t = np.linspace(f, hi, points + 1)[1:]
        else:
            t = np.linspace(lo, hi, points)
    else:
        t = np.linspace(lo, hi, points)
    # each component's density in log form (the far tail of the widest one must not underflow to an all-zero law)
    logp = -0.5 * (t[None, :] / scales[:, None]) ** 2 - np.log(scales)[:, None] + np.log(weights)[:, None]
    top = logp.max()
    w = np.exp(logp - top).sum(axis=0)
    return center + d * t, w / w.sum()


def _pulse_moves(fine: "FinePositioner") -> object:
    """The doublet's move model for ``fine.apex_policy``: :class:`~fuel_valve_control.core.pulse_moves.PulseMoves`
    (task h33m, docs §80) of the stage ``fine`` -- its planning model, doublet, servo gains and current cap --
    with its doublets' retreat (``fine.apex_retreat_periods``, else ``fine.retreat_full_periods``) and the drive's
    bus voltage."""
    from .pulse_moves import PulseMoves    # noqa: PLC0415 (imports this module's constants)
    cfg = fine.cfg
    kw = {"retreat_full_periods": cfg.apex_retreat_periods or cfg.retreat_full_periods}
    if cfg.retreat_cap or cfg.observe_hold_integral or cfg.observe_hold_moved:
        # (task h34s) the doublet's shape and observe as the stage runs them (off: the model's signature unchanged)
        kw.update(retreat_cap=cfg.retreat_cap and not cfg.retreat_cap_half, retreat_cap_full=cfg.retreat_cap,
                  observe_hold_integral=cfg.observe_hold_integral,
                  observe_hold_moved=cfg.observe_hold_moved)
    if cfg.supply_voltage_v is not None:
        kw["supply_voltage_v"] = cfg.supply_voltage_v
    return PulseMoves.for_positioner(fine, **kw)


_BREAK_LIMITS: dict = {}
#: (``fine.apex_policy``) the normal level law's points (scatters) and unnormalised weights, formed once
_APEX_Z = np.linspace(-APEX_LAW_SIGMAS, APEX_LAW_SIGMAS, APEX_LAW_POINTS)
_APEX_W = np.exp(-0.5 * _APEX_Z * _APEX_Z)
_APEX_Z.flags.writeable = _APEX_W.flags.writeable = False
#: (``fine.apex_policy``) the candidate apexes above the law's top, in learned scatters (formed once, task h40m)
_APEX_ABOVE = np.linspace(0.1, 1.5, 8)
_APEX_ABOVE.flags.writeable = False


def _break_limit(sigmas: float) -> float:
    """(``fine.apex_policy``) The largest chance of breaking the valve loose in its preload a try may take: main's
    staircase start's, Φ(-``fine.doublet_sigmas``) (+1e-9); kept per value (a scalar erf per try otherwise)."""
    v = _BREAK_LIMITS.get(sigmas)
    if v is None:
        v = _BREAK_LIMITS[sigmas] = float(_norm_cdf(-sigmas)) + 1e-9
    return v


def _wsum(x: np.ndarray, w: np.ndarray, fixed: bool) -> np.ndarray:
    """``x @ w`` (the sum over the last axis weighted by ``w``).  ``fixed`` (task h38x, docs §99): without BLAS, in an
    order numpy's code fixes (the products elementwise, then numpy's pairwise sum over each row): the same bits
    whatever BLAS's threads or kernel, with or without numpy's AVX-512 loops (checked, docs §99; one numpy build).  Else through BLAS as ever (its kernel, chosen for the CPU at load, and for
    large enough products its thread count set the last bits: the normal law's, kept so its choices stay main's)."""
    if not fixed:
        return x @ w
    return np.add.reduce(x * w, axis=-1)


def _beyond_best(hit: np.ndarray, w: np.ndarray, beyond: np.ndarray, fixed: bool) -> np.ndarray:
    """V1 of the apex policy's choice: per candidate a, the best over the rows r of ``hit`` [r, k] (a try's landing
    chance at level k) averaged over the law ``w`` [k] truncated to the levels ``beyond`` [a, k] the candidate
    (0 where no weight lies beyond it).  Not ``fixed``: main's ``(hit @ trunc.T).max(axis=0)`` with the truncated
    law normalised first (a BLAS matrix product: at the mixture law's 89 x 81 x 89 OpenBLAS runs it on all its
    threads, 8 ms of the calling thread's CPU, and its bits depend on the thread count and the CPU's kernel).
    ``fixed`` (task h38x, docs §99): the same quantity without BLAS, in a fixed order -- the levels are ordered toward
    the try, so the levels beyond a candidate are a suffix of them: the suffix sums of hit x w (a cumulative sum from
    the last level down, numpy's sequential accumulate) read at each candidate's first level beyond, the best row's
    divided by the suffix sum of w: O(rows x levels), not O(rows x candidates x levels).  Levels not ordered (no law
    builds them so): the sums over the truncated law elementwise, numpy's pairwise sum.  ``beyond`` may be 1-D
    (``fixed`` only, :func:`_beyond_levels`): each candidate's first level beyond it, the levels known ordered."""
    if not fixed:
        trunc = np.where(beyond, w[None, :], 0.0)
        tot = trunc.sum(axis=1, keepdims=True)
        trunc = np.divide(trunc, tot, out=np.zeros_like(trunc), where=tot > 0.0)
        return (hit @ trunc.T).max(axis=0)
    nk = len(w)
    if beyond.ndim == 1:
        start = beyond                           # (task h40m) given as each candidate's first level beyond it
    else:
        start = nk - np.count_nonzero(beyond, axis=1)             # [a] the first level beyond the candidate
    if beyond.ndim == 1 or np.array_equal(np.arange(nk)[None, :] >= start[:, None], beyond):   # a suffix
        hw = np.zeros((hit.shape[0], nk + 1))
        np.cumsum((hit * w)[:, ::-1], axis=1, out=hw[:, nk - 1::-1])
        tw = np.zeros(nk + 1)
        tw[:nk] = np.cumsum(w[::-1])[::-1]
        num, tot = hw.max(axis=0)[start], tw[start]     # (the best row per suffix, then read: the same maxima)
    else:
        trunc = np.where(beyond, w[None, :], 0.0)
        num = np.add.reduce(hit[:, None, :] * trunc[None, :, :], axis=-1).max(axis=0)
        tot = np.add.reduce(trunc, axis=-1)
    return np.divide(num, tot, out=np.zeros_like(num), where=tot > 0.0)


def _beyond_levels(d: int, lv: np.ndarray, cand: np.ndarray, fixed: bool) -> np.ndarray:
    """The levels ``lv`` the law keeps after no move at each candidate apex ``cand`` toward ``d`` (those beyond it):
    [a, k] True where d (lv_k - cand_a) > 0.  With ``fixed`` and the levels ordered toward ``d`` (every law builds
    them so) the same as each candidate's first level beyond it, 1-D (task h40m, docs §106; for
    :func:`_beyond_best`): d (lv_k - a) > 0 exactly when d lv_k > d a (IEEE subtraction keeps the sign), so the
    levels beyond are those after d lv's right insertion point of d a."""
    if fixed:
        dl = d * lv
        if np.all(dl[1:] >= dl[:-1]):            # (False with a NaN: the matrix)
            return np.searchsorted(dl, d * cand, side="right")
    return d * (lv[None, :] - cand[:, None]) > 0.0


_PREFIX_MASKS: dict = {}


def _prefix_mask(n: int) -> np.ndarray:
    """[n + 1, n]: row m True on the first m columns (kept per n)."""
    mask = _PREFIX_MASKS.get(n)
    if mask is None:
        mask = _PREFIX_MASKS[n] = np.arange(n)[None, :] < np.arange(n + 1)[:, None]
        mask.flags.writeable = False
    return mask


def _norm_cdf(x):
    """The standard normal's CDF, elementwise (scipy's ufunc ``erf``: ``math.erf`` through ``np.vectorize`` was
    half of the apex policy's ~1.6-4 ms per try, measured in a nominal run)."""
    return 0.5 * (1.0 + _erf(np.asarray(x) / math.sqrt(2.0)))


#: (task h40m, docs §106) |x| beyond which the normal CDF is exactly 0.0 or 1.0 in this arithmetic (0.5 (1 +
#: erf(x / sqrt 2)): erf rounds to +-1 past ~5.9 / sqrt 2 ... checked densely from 8.5 to 60, and at +-inf, in the test)
CDF_SATURATED = 9.0
#: erf saturates there on this scipy build (else the tails are computed like the rest)
_CDF_TAILS_EXACT = bool(0.5 * (1.0 + _erf(CDF_SATURATED / math.sqrt(2.0))) == 1.0
                        and 0.5 * (1.0 + _erf(-CDF_SATURATED / math.sqrt(2.0))) == 0.0)


def _norm_cdf_tails(x: np.ndarray) -> np.ndarray:
    """:func:`_norm_cdf` (the same bits), with ``erf`` evaluated only where |x| <= CDF_SATURATED: beyond, the CDF is
    exactly 1.0 (x > 0) or 0.0 (task h40m, docs §106: the mixture law's choice evaluates ~15 000 CDFs per try, ~3 of 4
    in the tails).  NaN stays NaN (through ``erf``)."""
    x = np.asarray(x, dtype=float)
    if not _CDF_TAILS_EXACT or x.size < 1024:
        return _norm_cdf(x)
    mid = np.flatnonzero(~(np.abs(x) > CDF_SATURATED))
    out = (x > 0.0).astype(float)
    out.reshape(-1).put(mid, 0.5 * (1.0 + _erf(x.reshape(-1).take(mid) / math.sqrt(2.0))))
    return out


#: (fine.kick_lost_fraction) the least second difference of the motor angle (motor-resolver counts) a kick must be planned
#: to make for the check to read it: at the nominal valve a 4 A kick makes ~100, a 26 A one ~670
KICK_SEEN_MIN_COUNTS = 20.0
#: (fine.pulse_fallback) the band-middle torque is recomputed once the valve has moved this far (rad) from where it
#: was computed: the spring and flow torques change by milli-N*m over a few counts
MIDDLE_REUSE_RAD = 1e-3


@dataclass(frozen=True)
class LearnedModel(NominalModel):
    """The told model with the valve friction scaled by ``friction_scale`` (Coulomb and static,
    their Δp slopes too) and a steady load ``load_offset_nm`` (N*m, valve side, + toward closed)
    added to the known one: the twists ``(load ± s T(Δp)) / K`` a valve whose main-law breakaways
    were read shows (:meth:`FinePositioner._observe_scale`).  The coupling stiffness, inertias and
    gear are the told model's (a soft coupling reads as a larger friction twist: the same band)."""

    friction_scale: float = 1.0
    load_offset_nm: float = 0.0

    @classmethod
    def of(cls, model: NominalModel, scale: float, load_offset_nm: float) -> "LearnedModel":
        base = {f.name: getattr(model, f.name) for f in fields(NominalModel)}
        for name in ("valve_coulomb_nm", "valve_coulomb_per_dp_nm", "valve_static_nm", "valve_static_per_dp_nm"):
            base[name] *= scale
        return cls(**base, friction_scale=scale, load_offset_nm=load_offset_nm)

    def load_torque(self, valve_angle: float, pressure_kpa: float) -> float:
        return super().load_torque(valve_angle, pressure_kpa) + self.load_offset_nm


class FineLearner:
    """Learned twist offsets and move sizes per direction (+1 opening, -1 closing) and Δp band, rad.

    ``equilibrium[d][b]``: offset of the effective swing centre ``φe`` from its nominal value;
    ``breakaway[d][b]``: offset of the breakaway twist ``φb`` from its nominal value (both
    bounded to ``±limit_rad``); ``min_move[d][b]``: the size of the smallest move a pulse makes,
    from pulses that moved the valve further than asked (0 = not yet seen; bounded to
    ``0..limit_rad``); ``scatter[d][b]``: the rms scatter of the breakaway twist about
    ``breakaway`` from stop to stop (0 = not yet learned; bounded to ``0..limit_rad``): the
    doublet's staircase starts ``fine.doublet_sigmas`` of it below the learned breakaway;
    ``start[d][b]``: with ``fine.start_quantile`` the staircase's start, in learned scatters below the
    learned breakaway (0 = not yet learned: ``fine.doublet_sigmas``), tracked from the first stairs'
    outcomes (:meth:`observe_start`); ``misfit[d][b]``: the
    stage's recent record on this valve, 0..1 (an exponentially weighted fraction of its
    engagements that failed: handed back, or left the valve further off than it found it;
    above ``fine.misfit_limit`` the stage stays out, decaying per plateau it stays out of).
    :meth:`reset` returns to the nominal model (all 0).
    """

    VERSION = 5
    TABLES = ("equilibrium", "breakaway", "min_move", "scatter", "misfit", "start")
    #: tables of sizes (never negative), and the version each came with (version 2-3 files held a
    #: ``margin`` table, the staircase start adapted by x1.5 / x0.9 steps: version 4 learns the
    #: breakaway scatter it stood in for, and an older file loads with the scatter not yet learned; version 5
    #: added the staircase start ``start``, in scatters, and a version 1-4 file loads with it not yet learned)
    SIZES = ("min_move", "scatter", "misfit", "start")
    SINCE = {"min_move": 2, "scatter": 4, "misfit": 3, "start": 5}

    def __init__(self, bands: int, limit_rad: float):
        self.bands = max(int(bands), 1)
        self.limit = limit_rad
        self.reset()

    def reset(self) -> None:
        self.equilibrium = {1: [0.0] * self.bands, -1: [0.0] * self.bands}
        self.breakaway = {1: [0.0] * self.bands, -1: [0.0] * self.bands}
        self.min_move = {1: [0.0] * self.bands, -1: [0.0] * self.bands}
        self.scatter = {1: [0.0] * self.bands, -1: [0.0] * self.bands}
        self.misfit = {1: [0.0] * self.bands, -1: [0.0] * self.bands}
        self.start = {1: [0.0] * self.bands, -1: [0.0] * self.bands}
        self.pulses = 0

    def band(self, pressure_fraction: float) -> int:
        return min(int(max(pressure_fraction, 0.0) * self.bands), self.bands - 1)

    def _clip(self, table: str, x: float) -> float:
        if table == "start":
            return min(max(x, START_SIGMAS_MIN), START_SIGMAS_MAX) if x > 0.0 else 0.0
        return min(max(x, 0.0 if table in self.SIZES else -self.limit), 1.0 if table == "misfit" else self.limit)

    def set(self, table: str, direction: int, band: int, value: float) -> None:
        getattr(self, table)[direction][band] = self._clip(table, value)

    def observe_breakaway(self, direction: int, band: int, offset: float, gain: float, prior: float) -> None:
        """Take one sample ``offset`` (rad) of the breakaway twist's offset from its nominal value
        into the learned breakaway (its mean) and scatter (rms about it), each with weight
        ``gain`` (an exponentially weighted mean and variance; ``prior``: the scatter before
        the first sample).  The level is drawn anew at every stop (friction scatter, position
        ripple): the doublet's staircase starts ``fine.doublet_sigmas`` scatters below the mean,
        so a preload seldom breaks the valve loose for a whole jump and the staircase is no
        longer than the scatter makes it.  Both stay bounded (:meth:`set`)."""
        d, b = direction, band
        mu = self.breakaway[d][b]
        sigma = self.scatter[d][b] or prior
        dev = offset - mu
        self.set("breakaway", d, b, mu + gain * dev)
        self.set("scatter", d, b, math.sqrt((1.0 - gain) * sigma * sigma + gain * dev * dev))

    def observe_interval(self, direction: int, band: int, low: float, high: float, gain: float,
                         prior: float) -> None:
        """Take one *censored* sample of the breakaway twist's offset from its nominal value (rad): the level
        drawn at one stop lay between ``low`` and ``high`` (either may be infinite: a pulse that moved the valve
        bounds it from above, the furthest unmoved apex at that stop from below).  The learned level and scatter
        are taken as a normal distribution, and the sample they take (each with weight ``gain``) is the level's
        conditional mean and second moment about the learned mean, given the interval -- the stochastic-EM
        step of the censored mean and variance, so that an input which only bounds the level neither ratchets
        it (an unmoved pulse, task h30u) nor pulls it to the bound (a moved one).  Both stay bounded."""
        d, b = direction, band
        mu = self.breakaway[d][b]
        sigma = max(self.scatter[d][b] or prior, 1e-9)
        a = (low - mu) / sigma if math.isfinite(low) else -math.inf
        z = (high - mu) / sigma if math.isfinite(high) else math.inf
        if not a < z:
            return

        def pdf(x: float) -> float:
            return 0.0 if math.isinf(x) else math.exp(-0.5 * x * x) / math.sqrt(2.0 * math.pi)

        def cdf(x: float) -> float:
            return 0.5 * math.erfc(-x / math.sqrt(2.0))

        mass = cdf(z) - cdf(a)
        if mass < 1e-12:
            # the interval lies far in a tail of what was learned: its near edge is the best sample
            self.observe_breakaway(d, b, low if math.isfinite(low) and a > 0.0 else high, gain, prior)
            return
        m1 = (pdf(a) - pdf(z)) / mass                                   # E[(L - mu) / sigma | interval]
        m2 = 1.0 + ((a * pdf(a) if math.isfinite(a) else 0.0) - (z * pdf(z) if math.isfinite(z) else 0.0)) / mass
        self.set("breakaway", d, b, mu + gain * sigma * m1)
        self.set("scatter", d, b, math.sqrt(max((1.0 - gain) * sigma * sigma + gain * sigma * sigma * max(m2, 0.0),
                                                0.0)))

    def observe_start(self, direction: int, band: int, let_go: bool, quantile: float, step: float,
                      prior: float) -> None:
        """Take one staircase's first-stair outcome into its learned start (``start``, in learned scatters of
        the breakaway twist below the learned breakaway; ``prior`` before the first outcome): a censored
        sample of the level drawn at that stop -- ``let_go`` (the valve broke loose in the first stair's
        preload or kick): the level lay below the first apex; not: above it.  A stochastic-approximation
        quantile tracker (Robbins-Monro): the start goes ``step`` x (1 - ``quantile``) scatters deeper after a
        let-go and ``step`` x ``quantile`` shallower after a miss, so that at equilibrium a fraction
        ``quantile`` of first stairs let the valve go.  It needs no model of the kick's real rise, the
        doublet's dynamic let-go or the scatter's shape: the first stair's outcome is measured at the apex
        the plan really reaches.  Bounded (:meth:`set`)."""
        z = self.start[direction][band] or prior
        z += step * ((1.0 - quantile) if let_go else -quantile)
        self.set("start", direction, band, max(z, START_SIGMAS_MIN))

    # ---- persistence ---------------------------------------------------------------------
    def to_dict(self) -> dict:
        return {"version": self.VERSION, "bands": self.bands, "limit_rad": self.limit,
                **{t: {"open": getattr(self, t)[1], "close": getattr(self, t)[-1]} for t in self.TABLES},
                "pulses": self.pulses}

    def from_dict(self, doc: dict) -> None:
        """Load learned values (validated: shape, finiteness; values are clipped to the bound).
        An older file loads with the tables it lacks not yet learned (version 1: no move sizes,
        versions 1-2: no misfit record, versions 1-3: no breakaway scatter, versions 1-4: no staircase start)."""
        if doc.get("version") not in (1, 2, 3, 4, self.VERSION) or int(doc.get("bands", -1)) != self.bands:
            raise ValueError(f"learned friction file: needs version {self.VERSION} with {self.bands} bands")
        new = {}
        for table in self.TABLES:
            if doc.get("version") < self.SINCE.get(table, 1):
                rows = {"open": [0.0] * self.bands, "close": [0.0] * self.bands}
            else:
                rows = doc[table]
            for key, d in (("open", 1), ("close", -1)):
                vals = [float(v) for v in rows[key]]
                if len(vals) != self.bands or not all(math.isfinite(v) for v in vals):
                    raise ValueError(f"learned friction file: {table}.{key} needs {self.bands} finite values")
                new[(table, d)] = [self._clip(table, v) for v in vals]
        for (table, d), vals in new.items():
            getattr(self, table)[d] = vals
        self.pulses = int(doc.get("pulses", 0))

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=1) + "\n")

    def load(self, path: str | Path) -> None:
        self.from_dict(json.loads(Path(path).read_text()))


@dataclass(frozen=True)
class FineConfig:
    tolerance_rad: float          # done when |target - valve| is within this
    engage_periods: int           # valve at rest (within a count) this long before fine positioning
    observe_periods: int          # periods to wait after a pulse for the valve to stop
    park_periods: int             # at least this many periods to move the twist to the preload
    park_speed: float             # ... and at most this twist rate, rad/s
    overdrive_fraction: float     # pulse peak above the learned breakaway, fraction of (φb - φe)
    preload_margin: float         # preload below the learned breakaway, fraction of (φb - φe)
    rise_periods: int             # pulse: periods from the preload to the peak
    fall_periods: int             # pulse: periods from the peak to the final twist
    learn_gain: float             # fraction of each measured correction taken into the learned values
    max_pulses: int               # pulses per plateau before giving up (hold where it is)
    servo_hz: float               # bandwidth of the stiff gear-output hold
    max_move_rad: float           # larger errors are left to the main law
    peak_current_a: float = math.inf  # the stage never asks for more current than this, A
    max_crossings: int = 1000     # pulses that took the valve across the target, per plateau,
                                  # before the stage holds (its moves are then larger than the error)
    probe_step: float = 0.1       # a pulse that did not move the valve raises the breakaway this
                                  # fraction of the static band beyond the twist it reached
    min_move_fraction: float = 0.0  # no pulse for an error below this fraction of the learned
                                    # smallest move (0: pulse whatever the move sizes)
    doublet_max_error_rad: float = 0.0  # errors up to this get the torque doublet (0: never)
    kick_current_a: float = 0.0   # doublet: current added for one period on the preload, A
    kick_rise_rad: float = 0.0    # doublet: preload this far below the learned breakaway twist
    doublet_probe_step: float = 0.0  # doublet: as probe_step, for a doublet that did not move it
    doublet_margin: float = 0.0   # doublet: first apex this fraction of the static band below the
                                  # learned breakaway after each stop, until the scatter is learned
    park_approach_rad: float = 0.0  # the last this much of the preload ...
    park_approach_speed: float = math.inf  # ... at most at this twist rate, rad/s
    approach_short: float = 0.0   # a servo-blended pulse aims this fraction of the static band short
    min_move_prior: float = 0.0   # smallest move before one is learned, fraction of the stick-slip jump
    doublet_sigmas: float = 2.0   # doublet: ... then this many learned scatters below it
    scatter_gain: float = 0.2     # weight of each breakaway sample in the learned breakaway and scatter
    no_move_periods: int = 4      # doublet: periods after which an unmoved valve was not broken loose
    misfit_weight: float = 0.0    # weight of each engagement's outcome in the learned misfit record
    misfit_limit: float = 1.0     # above this record the stage stays out of a direction / Δp band
    misfit_decay: float = 1.0     # ... and the record decays by this factor per plateau it stays out of
    breakaway_fit: float = math.inf  # the main law's last breakaway twist must lie within this fraction
                                     # of T_s(Δp)/K of the nominal breakaway twist, else the stage stays out
    fit_margin: float = math.inf  # the twist holding the valve at rest must lie inside the nominal static
                                  # band widened by this fraction of T_s(Δp)/K, else the stage stays out
    reversal_window_periods: int | None = None  # the valve's reversals on a plateau are counted from this
                                  # many periods after its start, as the hunting metric counts them (None:
                                  # never: the stage moves regardless)
    no_cross_short: float = 0.0   # a move that must not cross the target aims this fraction of the stick-slip
                                  # jump short of it, and is made only for an error of at least twice that
    move_per_overdrive: float = 0.0  # doublet: valve move per twist overdrive at breakaway, rad/rad: sizes the
                                     # staircase's stairs to the error (0: every stair doublet_probe_step)
    move_per_level: float = 0.0   # doublet: the valve's move per rad of twist its breakaway level lies above the learned
                                  # mean: a staircase stops where the move it would make exceeds twice the error
                                  # (:meth:`_level_outgrows_error`; 0: never)
    retreat_full_periods: int = 1  # doublet: periods of the whole current backwards after the kick (then one of half)
    cold_start: bool = False      # engage before any breakaway was seen, judging the valve by the stage's own
                                  # first doublets (:meth:`FinePositioner._cold_ready`)
    cold_climb: bool = False      # while cold, climb from the twist proven to hold with the largest kick (s33)
    cold_friction_min: float = 0.0  # fine.cold_climb: the least friction (x the told) assumed before any breakaway
    cold_still: bool = True       # a cold engagement only on a valve still since its plateau's demand arrived (s34)
    rest_noise_rate: float = 0.0  # where more than this fraction of a still valve's sample-to-sample steps fail the rest
                                  # test (a noisy valve resolver), rest compares the means of two windows of
                                  # engage_periods readings instead (:class:`~.valve_rest.ValveRest`; 0: never; s35)
    servo_margin_rad: float = 0.0  # the servo's least phase margin with the resolver delay, rad (0: not checked; s34)
    resolver_delay_s: float = 0.0  # the measured resolver delay (s) the servo's margin counts (servo_margin_rad)
    timeable_delay: bool = False  # the stage stays out where its servo has no phase margin with that delay (s35)
    cold_band_gate: bool = False  # a cold engagement also needs the main law's hold to have measured the static
                                  # band (both slip edges) within breakaway_fit of the nominal T_s (h30c)
    learn_kick_rise: bool = False  # doublet: plan each preload against the kick's rise learned from the stage's
                                   # own apexes (:meth:`FinePositioner._kick_rise`) instead of ``kick_rise_rad``
    first_kick_fraction: float = 1.0  # doublet: a staircase's first stair kicks with this fraction of kick_current_a
    preload_cap: bool = False     # a servo-blended pulse's preload at most the furthest twist an unmoved pulse reached
                                  # at this stop
    probe_reached: bool = False   # an unmoved pulse raises the learned breakaway only to probe_step x the band
                                  # beyond the twist it reached (not beyond the learned level it fell short of)
    doublet_jump_fraction: float = 0.0  # doublet also for errors up to this fraction of the nominal stick-slip
                                        # jump 2 (T_s - T_c(Δp)) / K (0: only up to doublet_max_error_rad)
    learned_scale_min: float = 1.0  # the stage plans from the friction scale and load its valve's main-law breakaways
    learned_scale_max: float = 1.0  # show when that scale lies in [min, max] and the told model does not fit them
                                    # (:meth:`FinePositioner._observe_scale`; 1, 1: the told model only)
    continuous_current_a: float = math.inf  # the drive's continuous rating, A (SCALE_HOLD_FRACTION)
    learned_load_max: float = math.inf  # ... and the steady load read beyond the told one is at most this x T_s
    retreat_unmoved_fraction: float = 0.5  # doublet: the half retreat period's current (x cap, backwards) if unmoved
    retreat_stop_unmoved: bool = False  # doublet: an unmoved valve's observe holds near the preload (task h28r)
    learned_one_sample: bool = False  # the scale read from one breakaway each way when it is plausible
                                      # (:meth:`FinePositioner._reading`; task h28f, docs §59)
    learned_agree: bool = False  # a direction's kept friction ratios are read only while they agree within
                                 # breakaway_fit (:meth:`FinePositioner._reading`; task h29f, docs §64)
    stair_far_sigmas: float = 0.0  # doublet: stairs of up to kick_rise_rad while the apex lies more than this many
                                   # learned scatters below the learned breakaway (0: every stair the floor)
    preload_sigmas: float = 0.0   # a servo-blended pulse's preload at least this many learned breakaway scatters below
                                  # the learned breakaway (0: fine.preload_margin x the band only; task h29a)
    drop_rest_at_engage: bool = False  # the rest the main law's next breakaway is read from is dropped when the stage
                                       # engages: the stage's own moves are no breakaway from that rest (task h29a)
    repark_from_state: bool = False  # doublet: a staircase's next park planned from the twist and twist rate the
                                     # unmoved stair's retreat left (:meth:`_plan_repark`; task h29r, docs §61)
    start_quantile: float = 0.0   # doublet: the staircase starts where this fraction of first stairs let the valve go,
                                  # learned from their outcomes (FineLearner.observe_start; 0: doublet_sigmas scatters)
    start_step_sigmas: float = 0.5  # ... the tracker's step, learned scatters
    main_sample_weight: float = 1.0  # the main law's breakaway samples count this much of a doublet's in the learned
                                     # breakaway and scatter (task h29q: unbiased, but +-7e-4 rad p10/p90 off the true level)
    restair_sigmas: float = 0.0   # after EARLY_BREAKS preload breakaways on a plateau the stage goes on with a doublet
                                  # staircase whose first apex lies this many learned scatters below the preload twist the
                                  # last one broke at (the same direction), instead of handing the plateau back; a further
                                  # preload breakaway hands it back (0: hand back at once; task h30b, docs §66)
    unbiased_samples: bool = False  # every stage input a sample of the level: a moved doublet's at its apex plus the
                                    # let-go offset, a servo-blended pulse's a censored one (no ratchet; task h30u)
    engage_inside_deadband: bool = False  # no FRESH_WAIT for a main-law breakaway where the error at rest lies inside
                                          # the main law's integrator deadband (:meth:`FinePositioner._main_stays`;
                                          # task h32d, docs §76)
    stair_growth_after: int = 0   # doublet: after this many unmoved stairs of one staircase each further stair grows
                                  # (:meth:`FinePositioner._grown_stair`; task h32e, docs §77; 0: never)
    stair_growth_slope: float = 4.0  # ... bounded as fine.move_per_overdrive bounds it (this slope where that is 0)
    apex_policy: bool = False     # doublet: each apex placed where the learned level's law (truncated by this stop's
                                  # unmoved apexes) gives the best chance to land within apex_land_rad
                                  # (:meth:`FinePositioner._choose_apex`; task h33p, docs §81), not a staircase
    apex_land_rad: float = 4e-4   # ... the landing tolerance the policy aims into, rad
    apex_move_sd_rad: float = 2e-4  # ... the rms error of the move model about its prediction, rad
    apex_min_chance: float = 0.0  # ... no try whose chance of ending within apex_land_rad is not above this
    apex_kick_max_a: float = 0.0  # ... the kick chosen per try among kick_current_a x 1, 2, 4 ... up to this, A
                                  # (0 or below kick_current_a: kick_current_a only)
    apex_kick_ratio: float = 2.0  # ... successive kicks of that set this many times the last
    apex_retreat_periods: int = 0  # ... its doublets retreat this many periods at the whole current (0: fine.retreat_full_periods)
    retreat_cap: bool = False     # doublet: the retreat is -peak_current_a itself (direction-signed) for its whole
                                  # periods, no half period (plateau_floor's deep shape; task h34s, docs §84)
    retreat_cap_half: bool = False  # ... but with main's half period kept after the whole ones (docs §84)
    observe_hold_integral: bool = False  # doublet: the servo's integral held (not integrated) in the observe phase
                                         # after a doublet (task h34s, docs §84)
    observe_hold_moved: bool = False  # ... only once that doublet has moved the valve half a tolerance (docs §84)
    apex_excess_nominal: bool = False  # ... the model's excess against the stage model's Coulomb equilibrium, not the
                                       # learned swing centre (task h34m, docs §85)
    apex_floor_plan: bool = False  # ... an unmoved try truncates the law at max(measured apex, planned apex)
    apex_choice_after_command: bool = False  # ... the choice of a try started by an observe's verdict runs after the
                                             # period's command (run_pending; task h39n, docs §103): same bits
    retreat_plan_after_command: bool = False  # fine.retreat_trough_bound: the doublet's retreat is planned after its
                                              # kick period's command (run_pending; docs §111): same bits
    apex_kick_continuous: bool = False  # ... after an unmoved try: preload at that apex, the kick sized to the apex
    apex_worse_given_move: bool = False  # ... no try more likely to worsen |e| than not, given that it moves
    apex_keep_rad: float = 0.0    # ... (task h41n, docs §110) that rule only from a rest within this |e| (0: off)
    servo_unmoved_doublet: int = 0  # after this many servo-blended pulses that did not move the valve at a stop, the
                                    # next pulses are doublets while |e| <= one nominal stick-slip jump (0: off; task
                                    # h42s, docs §112)
    servo_unmoved_doublet_jumps: float = 1.0  # ... while |e| <= this many nominal stick-slip jumps at the stop's Δp
    apex_level_law: str = "normal"  # ... the level's law: "normal" (the learned scatter), "mixture" (normals over scatters
                                    # log-uniform from the learned one to breakaway_fit / 3 x T_s/K), "student" (a t with
                                    # the learned scatter and (2 - scatter_gain) / scatter_gain - 1 degrees of freedom)
    apex_floor_repeat: bool = False  # ... the planned apex is the floor once the policy re-planned an apex it had tried
                                     # unmoved at this stop (the reading shown short; task h37m, docs §95)
    engage_gear_rest: float = 0.0  # no engagement while the gear output still winds the twist away from the target
                                   # by more than this fraction of the tolerance a period (0: off; a stick mid-swing;
                                   # task h37m, docs §95)
    handover_unwind: bool = False  # a new demand from HOLD with the twist on the new move's side of the band's middle:
                                   # the gear output moved to the middle before the hand-over (task h38s, docs §98)
    handover_unwind_max_jumps: float = 0.0  # ... only for a new demand within this many nominal stick-slip jumps of
                                            # the valve (0: any; task h39h, docs §101)
    handover_unwind_near: float = 0.0  # ... only with the twist within this many (T_s - T_c)/K of the new move's learned
                                       # breakaway (0: anywhere on that side; task h39h, docs §101)
    hold_relax: float = 0.0  # in HOLD: the twist moved this fraction of the way to the static band's middle (between the
                             # two learned breakaways), slowly, so that the next demand's move starts from a symmetric
                             # twist (0: off, today's; task h39h, docs §101)
    hold_relax_periods: int = 60  # ... the move's length, periods (a sin² blend)
    handover_settle_speed: float = 0.0  # a new demand mid-park / -pulse / -observe: the stage holds the gear output
                                        # where it is until it turns slower than this (rad/s) with the valve at rest
                                        # (or 2 x observe_periods), then hands over (0: at once, today's; task h38s,
                                        # docs §98)
    handback_settle: bool = False  # the stage's own hand-back mid-park / -pulse / -observe waits likewise: the gear
                                   # output held where it is until it turns slower than handover_settle_speed with the
                                   # valve at rest (or 2 x observe_periods), then the main law takes over (stop 28,
                                   # docs §108)
    apex_mix_points: int = APEX_MIX_POINTS   # fine.apex_level_law not normal: the levels it is weighed on (task h40m)
    apex_stop_rad: float = 0.0    # fine.apex_policy: done once the valve rests within this of the target (when above
                                  # tolerance_rad; 0: tolerance_rad only; task h39t, docs §102)
    supply_voltage_v: float | None = None  # the drive's bus, V (the move model's current loop; None: no limit)
    unbiased_preload_pull: bool = False  # ... but a servo-blended pulse's preload that broke the valve loose pulls the
                                         # level below it with learn_gain, as main does, unless an unmoved pulse at
                                         # that stop held an apex beyond it (task h32a, docs §73)
    retreat_return_guard: bool = False  # a doublet whose valve went a tolerance toward the try and came back is a
                                        # move (counted, the plateau held) and the deep retreat is cut to one whole
                                        # period for the rest of the run (task h35v, docs §89)
    retreat_return_rest: bool = False  # ... or: the observe's reference frozen where the return is seen, the doublet
                                       # judged at rest (back at its start: counted, held; task h35v, docs §89)
    retreat_return_hold: bool = False  # ... and the stage then holds the gear output where it is instead of handing
                                       # the plateau back (task h35v, docs §89)
    servo_mode_ref_rad_s: float = 0.0  # the reference valve's stuck-valve drivetrain mode sqrt(K/J1), rad/s: the servo's
                                       # stiffness is capped so that with the coupling's it is at most the reference
                                       # valve's closed loop (fine.servo_coupling_cap; 0: off; task h40s, docs §105)
    unmoved_settled: bool = False  # a doublet is judged unmoved only once the gear output's speed is below
                                   # fine.park_approach_speed_rad_s (or at fine.observe_time_s; task h35v, docs §89)
    retreat_trough_bound: bool = False  # doublet: a retreat whose trough, predicted by the move model on a stuck valve,
                                        # would pass the other way's learned breakaway less fine.doublet_sigmas learned
                                        # scatters is made shallower: fewer whole periods, then one period's current
                                        # scaled toward the hold (:meth:`FinePositioner._retreat_plan`; task h36g, §90)
    retreat_trough_misfit: bool = False  # ... the margin also fine.breakaway_fit x T_s/K (the level misfit the stage
                                         # engages with)
    park_settle: bool = False     # doublet: the kick waits (up to the park's length again) for the gear output to settle
                                  # on the preload: speed within sqrt(K/J1) x tolerance (task h37t, docs §96)
    apex_unraised_plan: bool = False  # (fine.apex_policy) after an unmoved try whose reading raised the floor by less
                                      # than a count, the floor is that try's planned apex (task h37t, docs §96)
    apex_probe_hold: bool = False  # (fine.apex_policy, where fine.retreat_trough_bound cut the retreat) a try with
                                   # P(no move) >= 1 - Phi(-doublet_sigmas) retreats one period at the hold (h37t, §96)
    trough_delay_s: float = 0.0   # (fine.retreat_trough_delay) the trough model's servo reads this late: the resolver delay
    hold_reversed: bool = False   # the stage holds instead of handing back a plateau on which the main law's move
                                  # could be the hunting metric's second reversal (task h34h, docs §86; in force also
                                  # with apex_policy)
    kick_lost_fraction: float = 0.0  # doublet: a kick whose gear-output acceleration, read from the motor resolver
                                     # in the next sample, is below this fraction of the commanded one did not reach
                                     # the drive: kicked again instead of retreating (0: never checked; docs §114)


class FinePositioner:
    """The fine-positioning stage: a state machine run once per loop period while the main law
    holds.  :meth:`update` returns a motor torque (N*m) while it is in charge, else ``None``."""

    #: (task h36b) ``fine.apex_policy``'s tables built elsewhere (:meth:`defer_tables`): None (not deferred: offline,
    #: tables built lazily), "closed" (the stage runs with ``apex_policy`` off: main's staircase), "released" (the
    #: tables are in: the policy's configuration comes back at the next plateau the stage starts idle)
    _tables_gate: str | None = None
    _full_cfg: FineConfig | None = None

    def __init__(self, model: NominalModel, period_s: float, cfg: FineConfig, learner: FineLearner):
        self._pending = None               # (fine.apex_choice_after_command) a try's start left for after the command
        self._retreat_pending = None       # (fine.retreat_plan_after_command) the kick period's (Δp, kick, periods)
                                           # whose retreat is planned after its command (:meth:`_settle_retreat`)
        #: (fine.pulse_fallback) the torques (N*m) for the drive to apply in the first, second, ... period in a row whose
        #: command is late (:meth:`update`; ``()``: hold this period's)
        self.fallback_nm: tuple[float, ...] = ()
        #: (fine.kick_lost_fraction) the second difference (rad) of the gear output the kick's torque alone would make,
        #: the kicks in a row found lost, and how many kicks were lost since the start (/diagnostics ``fine_kicks_lost``)
        self._kick_expected = 0.0
        self._kick_retries = 0
        self.kicks_lost = 0
        #: (fine.pulse_fallback) the band-middle torque's cache: model, Δp (kPa), valve angle (rad), torque (N*m)
        self._middle: tuple | None = None
        self.m, self.period, self.cfg, self.learn = model, period_s, cfg, learner
        self.m0 = model                    # the told model (self.m: the one the stage plans from)
        # (fine.rest_noise_rate, task s35) the valve resolver's noise and the rest by means on a noisy one
        self.valve_rest = ValveRest(cfg.engage_periods, 0.5 * cfg.tolerance_rad, cfg.rest_noise_rate, period_s)
        self.forget_scale()
        self._last_engage = None
        j1 = model.j1
        w = 2.0 * math.pi * cfg.servo_hz
        self.kp, self.kd, self.ki = self._servo_gains(model, w)
        if cfg.servo_margin_rad > 0.0 and cfg.resolver_delay_s > 0.0 and \
                self.servo_margin_rad(j1, self.kp, self.kd, period_s + cfg.resolver_delay_s) < cfg.servo_margin_rad:
            w = self._delay_limited_bandwidth(model, w, period_s + cfg.resolver_delay_s)
            self.kp, self.kd, self.ki = self._servo_gains(model, w)
        self.servo_w = w                   # rad/s: the servo's design bandwidth
        # (fine.timeable_delay, task s35) the margin counting the told resolver delay: a servo with none left
        # limit-cycles (full box 3109, 1 ms: +-30 A in the observe, the landed valve thrown 1.9e-2 rad and the main
        # law's restart hunting); without it the loop period's lag alone, as before
        self.timeable = self.servo_margin_rad(
            j1, self.kp, self.kd, period_s + (cfg.resolver_delay_s if cfg.timeable_delay else 0.0)) > 0.0
        self._moves = None                 # fine.apex_policy: the doublet's move model (built when first needed)
        self.apex_choices = 0              # fine.apex_policy: the tries chosen (:meth:`_choose_apex` calls), a count
        self.apex_choices_after_command = 0  # ... of them run after their period's command (:meth:`run_pending`)
        self.retreat_plans_after_command = 0  # doublet retreats planned after their kick's command (run_pending)
        self._pushes = {}                  # fine.probe_reached: {(direction, Δp band): rad of twist (>= 0, toward the
                                           # move) a servo-blended pulse's planned peak lies beyond the learned level's}
        # fine.repark_from_state / fine.retreat_unmoved_fraction: kept across resets (the last gear-output
        # speeds rad/s, None before the first period; the planned re-park; the servo's integral at the last preload)
        self._w1_now: float | None = None
        self._w1_prev: float | None = None
        self._repark: tuple[float, float, float, float] | None = None
        self._integral_held: float | None = None
        self._unmoved_now = False          # the valve within half a tolerance of the pulse's start (this period)
        self._excursion = 0.0              # (fine.retreat_return_guard) the furthest the valve went toward the try
                                           # since this doublet's kick, rad (>= 0)
        self._returned = False             # (fine.retreat_return_rest) this doublet's return has been seen
        self._deep_unfit = False           # (fine.retreat_return_guard) a doublet's valve came back on this plant:
                                           # its retreat's trough passes the other way's breakaway (kept for the run)
        self._retreat = None               # (fine.retreat_trough_bound) the doublet in progress' retreat: (whole
                                           # periods, scale) (:meth:`_retreat_plan`)
        self.main_deadband_rad = None  # the main law's integrator deadband in force (rad; set by the law each period;
                                       # None: its hold may move the valve inside it -- a probe), fine.engage_inside_deadband
        self.reset()

    def _servo_gains(self, model: NominalModel, w: float) -> tuple[float, float, float]:
        """The gear-output servo's ``(kp, kd, ki)`` (N*m/rad, N*m*s/rad, N*m/(rad*s) at the gear output) for the
        bandwidth ``w`` (rad/s): PD on the gear output's inertia J1 at damping 0.8 (``fine.servo_coupling_cap`` caps
        kp on a stiffer coupling), the integral slow (w/8) to remove the feed-forward's error."""
        j1 = model.j1
        kp = j1 * w * w
        kd = 2.0 * 0.8 * w * j1
        if self.cfg.servo_mode_ref_rad_s > 0.0:
            kp = self.coupling_capped_kp(kp, j1, model.coupling_stiffness_nm_per_rad, w, self.cfg.servo_mode_ref_rad_s)
        return kp, kd, kp * w / 8.0

    def _delay_limited_bandwidth(self, model: NominalModel, w: float, lag_s: float) -> float:
        """(``fine.servo_margin_deg``, task s34, docs §118) The servo bandwidth (rad/s, at most ``w``) whose phase
        margin with the loop's lag ``lag_s`` (s: the period and the measured resolver delay) is ``servo_margin_rad``.
        The gear output is read resolver_delay_s late, a lag the period's alone does not hold: at 0.6-0.9 ms the 60 Hz
        servo's margin falls from 31 to 11-0 deg and the observe / hold servos rattled at +-30 A, ~125 Hz (full box
        1032: the landed valve broken loose backwards).  Bisection on w (the margin falls as w grows)."""
        lo, hi = 0.0, w
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            kp, kd, _ = self._servo_gains(model, mid)
            if self.servo_margin_rad(model.j1, kp, kd, lag_s) >= self.cfg.servo_margin_rad:
                lo = mid
            else:
                hi = mid
        return max(lo, 1e-3)

    @staticmethod
    def coupling_capped_kp(kp: float, j1: float, stiffness: float, w: float, ref_mode: float) -> float:
        """(``fine.servo_coupling_cap``, task h40s, docs §105) The servo's proportional gain (N*m/rad at the gear
        output) on a coupling stiffer than the reference valve's.  With the valve stuck the coupling is a spring the
        servo's own adds to: the gear output's closed loop is ``J1 s² + kd s + (kp + K)`` (the feed-forward cancels
        the coupling torque of the *reference* twist only), its natural frequency ``sqrt(w² + K/J1)`` for the design's
        ``kp = J1 w²``.  On the reference (default) valve that is the designed loop; on a stiffer coupling it is
        faster and -- with the same ``kd`` and one loop period of delay -- less damped: K 1500 N*m/rad (other valves'
        ``stiff_coupling``) ζ 0.73 → 0.62, phase margin 31.9 → 29.4 deg (delay-free poles; the resolver's delay takes
        more).  The pull back from a doublet's retreat trough then overshot the final twist by 1.2e-3 rad, past this
        valve's opening breakaway (its static band 2 T_s/K is a third of the reference's; C3 + ``fine.retreat_trough_bound``,
        `step_small`: 14.4 %; the bound is what keeps the two-period trough from passing the closing breakaway).  Capped, the total
        stiffness ``kp + K`` is at most ``J1 (w² + ref_mode²)`` -- the reference valve's closed loop, poles and all --
        and never below the stiffness of a servo of half the bandwidth (``J1 w² / 4``).  Couplings no stiffer
        relative to their J1 than the reference's (``K/J1 <= ref_mode²``) keep ``kp``: nothing changes there."""
        excess = stiffness - j1 * ref_mode * ref_mode      # the coupling's stiffness beyond the reference's mode
        if excess <= 1e-9 * stiffness:
            return kp                                       # (the reference valve itself: its kp, to the bit)
        return max(kp - excess, 0.25 * kp)

    @staticmethod
    def servo_margin_rad(j1: float, kp: float, kd: float, period_s: float) -> float:
        """Phase margin (rad) of the stage's gear-output servo on this loop: the PD ``kp + kd s`` on
        the gear output's inertia ``j1`` crosses over at ``ωc`` (``j1² ωc⁴ = kd² ωc² + kp²``) with
        ``atan(kd ωc / kp)`` (70 deg at fine.servo_hz's damping 0.8), less the lag of one loop period
        ``ωc T`` (the zero-order hold's half period and the backward-difference speed's half
        period).  Nominal 1 kHz loop, 60 Hz: ωc 103 Hz, margin 33 deg; 2 kHz: 52 deg; 500 Hz: -4 deg
        -- there the servo rang +-3e-3 rad of twist about the preload reference and broke the valve
        loose while preloading (task h23s, docs §37).  Where the margin is not positive the stage
        stays out and the main law's hold keeps the plateau (the slow integral, ω/8, ignored)."""
        wc = math.sqrt((kd * kd + math.sqrt(kd ** 4 + 4.0 * j1 * j1 * kp * kp)) / (2.0 * j1 * j1))
        return math.atan2(kd * wc, kp) - wc * period_s

    @staticmethod
    def swing_scale(model: NominalModel, reference: NominalModel) -> float:
        """The factor (>= 1) the servo-blended pulse's rise and fall times (``fine.rise_time_s``,
        ``fine.fall_time_s``, set on the ``reference`` valve: the default model) take on ``model``'s valve:
        ``max(√(K_ref / K), 1)``.  The pulse drives the twist across a fraction of the static band
        ``(T_s - T_c)/K``; on a softer coupling the same friction torques span a band ``K_ref/K`` times
        wider, and the gear output's acceleration ``Δφ / t²`` -- the current the ``fine.peak_current_a``
        cap limits -- grows with it at a given time.  Lengthened by the square root of the ratio, the
        acceleration is the reference valve's (and the times keep their share of the valve's half swing
        ``π √(JL/K)``, which grows the same way); on a stiffer coupling they stay (the pulse is within the
        cap already).  Soft coupling (K 200, times x1.55): with the reference's seconds the capped pulses
        reached 0.0781 rad of twist against a learned breakaway planned up to 0.083, each raised it
        (``fine.probe_step``) and the next preload, planned from it, broke the valve loose a whole jump,
        27.6 % past a 2 % step; lengthened, the first pulse moved it on target.  Measured and left out
        (task h24s, docs §42): the times also shortened on a stiff coupling, or scaled with the half swing
        on a heavy valve (worse campaigns there), or lengthened with the friction's band too (friction x2:
        campaign better, startup and hold mixed).  Nominal valve: 1 exactly."""
        return max(math.sqrt(reference.coupling_stiffness_nm_per_rad / model.coupling_stiffness_nm_per_rad), 1.0)

    def reset(self, measurements: bool = True, keep_breakaway: bool = False) -> None:
        """Back to idle; ``measurements=False`` (a new demand) keeps what the resolvers have
        shown: how long the valve has sat still and the twist of the last breakaway seen;
        ``keep_breakaway`` keeps that breakaway alone (a re-arm of the loop: the same valve)."""
        self.run_pending()                # a try's start left for after the command: its verdicts first, as inline
        self.phase = IDLE
        self._kick_retries = 0             # (fine.kick_lost_fraction)
        self._target = None
        self._handover = None             # (fine.handover_settle_speed_rad_s) a hand-over waiting for the gear output
        self._handback_wait = None        # (fine.handback_settle) periods a hand-back has held the gear output so far
        self._unwind = None               # (fine.handover_unwind) the hold's unwinding before a hand-over
        self._relax = None                # (fine.hold_relax) the hold's relaxation toward the band's middle
        if measurements:
            self._rest = 0
            self._last_valve = None
            self.valve_rest.reset()       # (fine.rest_noise_rate) the readings' noise and their rest by means
            self._last_th1 = None
            self._rest_point = None       # (twist, valve, Δp) of the last period the valve sat still
            if not keep_breakaway:
                self._breakaway_seen = None   # (direction, twist rad, valve rad, Δp kPa) of the last breakaway seen
            self._first_demand = None     # (fine.cold_climb) the first demand since, and whether one has differed
            self._demand_moved = False
        self._last_target = None
        self._fresh = False
        self._plateau_valve = None    # (fine.cold_still) the valve angle when this plateau's demand arrived, rad
        self._plateau = None          # the demand this plateau started with (shifts within the tolerance
                                      # -- a conditioned noisy demand -- are the same plateau)
        self._steady = 0
        self._new_plateau()
        self._stair = None
        self._floor_unraised = None   # (fine.apex_unraised_plan) the floor an unmoved try's reading did not raise
        self._apex_floor = None       # fine.apex_policy: (direction, twist rad) the highest apex an unmoved doublet
                                      # reached at this stop (None: none yet)
        self._apex_plan = None        # fine.apex_policy: (apex, P(land), P(no move), score, kick) of the last choice
        self._apex_kick = None        # fine.apex_policy: the kick current (A) of the doublet in progress (None: main's)
        self._apex_try = None         # ... (direction, the model's mean move if it moves, rad) of that doublet
        self._park_hold = False       # (fine.apex_keep_rad) the park in progress ends in the policy's hold, no kick
        self._apex_rise = 0.0         # ... and its rise above the preload, rad
        self._apex_last = None        # ... (direction, planned apex rad) of the last try the policy chose
        self._apex_tried = None       # (fine.apex_floor_repeat) the furthest apex an unmoved try planned at this stop
        self._apex_repeat = False     # ... and whether the policy has planned an apex it had already tried there
        self._safe = None             # fine.preload_cap: the furthest twist toward the move an unmoved pulse reached
                                      # at this stop, rad (None: none yet)
        self._stairs_unmoved = 0      # fine.stair_growth_after: unmoved stairs of the staircase in progress
        self._servo_unmoved = (0, 0)  # (fine.servo_unmoved_doublet) (direction, count) of unmoved servo-blended
                                      # pulses at this stop
        self._stair_step = 0.0        # the last stair's climb, rad of twist (the level lies within it below the apex)
        self._rise_seen = [0.0, 0.0]  # mean twist a doublet's kick raised above its planned preload, rad (0: none
                                      # yet), [later stairs, a staircase's first stair]
        self._first_stair = False     # this doublet is its staircase's first stair
        self._kick_apex = 0.0         # the largest twist since this pulse left its preload, rad
        self.hold_static_nm = None    # the static friction the main law's hold band measured (N*m, valve side;
                                      # set by the law each period; None: not both edges), fine.cold_band_gate
        self._cold = False            # engaged before any breakaway was seen: doublets only, until the first
        self._judged = None           # (direction, band) of an engagement whose outcome is not yet judged
        self._osc, self._osc_sign = 0.0, 0   # the servo's limit-cycle watch (leaky count of reversals)
        self._servo_torque = 0.0
        self._anchor = None           # (rad, way ±1): the furthest pulse start toward the target

    def _new_plateau(self) -> None:
        self.pulses_this_plateau = 0
        self.crossings_this_plateau = 0
        self._early_breaks = 0        # breakaways below the planned preload on this plateau
        self._restair = None          # fine.restair_sigmas: (direction, twist rad) of the last preload breakaway
                                      # once EARLY_BREAKS of them were seen on this plateau (None: not yet)
        self._unfit = False           # the valve showed on this plateau that the model does not fit it
        self._climbed_out = False     # a doublet staircase climbed beyond any plausible breakaway
        self._plateau_k = 0           # periods since the plateau started
        self._reversals = None        # ReversalCounter of the valve on the plateau's late window
        self._recent = []             # the last REVERSAL_MEAN_PERIODS valve samples, rad

    # ------------------------------------------------------------------ nominal twists
    def _nominal(self, thl: float, pressure_kpa: float, direction: int) -> tuple[float, float]:
        """Nominal (swing-centre, breakaway) twists for a move in ``direction``, rad."""
        m = self.m
        fl = m.friction(pressure_kpa)
        k = m.coupling_stiffness_nm_per_rad
        load = m.load_torque(thl, pressure_kpa)
        return (load + direction * fl.valve_coulomb_nm) / k, (load + direction * fl.valve_static_nm) / k

    def _plausible(self, thl: float, pressure_kpa: float, direction: int) -> bool:
        """Whether the learned offsets for a move in ``direction`` fit the nominal model: within
        half the nominal static twist ``T_s(Δp)/K`` (3 sigma of an 8 % breakaway scatter at max
        Δp is 2.5 times less).  Beyond it the valve is not the one the model describes (friction
        far from nominal, an unknown load, a wrong Δp reading, a soft coupling) and the stage
        leaves the plateau to the main law's integral hold."""
        m = self.m
        bound = self._plausible_offset_rad(pressure_kpa)
        band = self.learn.band(m.pressure_fraction(pressure_kpa))
        return (abs(self.learn.equilibrium[direction][band]) <= bound
                and abs(self.learn.breakaway[direction][band]) <= bound)

    def _plausible_offset_rad(self, pressure_kpa: float) -> float:
        """Largest plausible learned twist offset from the nominal model at ``pressure_kpa``:
        half the nominal static twist ``T_s(Δp)/K``, rad (:meth:`_plausible`)."""
        m = self.m
        return 0.5 * m.friction(pressure_kpa).valve_static_nm / m.coupling_stiffness_nm_per_rad

    def _twists(self, thl, pressure_kpa, direction):
        e0, b0 = self._nominal(thl, pressure_kpa, direction)
        band = self.learn.band(self.m.pressure_fraction(pressure_kpa))
        return e0 + self.learn.equilibrium[direction][band], b0 + self.learn.breakaway[direction][band], band

    # ------------------------------------------------------------------ per period
    def update(self, target: float, th1: float, thl: float, holding: bool, torque_now: float,
               pressure_kpa: float) -> float | None:
        """``target`` valve angle, measured ``th1`` (motor resolver / N) and ``thl`` (valve
        resolver), ``holding``: the main law's reference has arrived at ``target``;
        ``torque_now``: the torque applied last period (N*m, motor).  Returns the torque (N*m, motor) or None (the
        main law's period).  Sets :attr:`fallback_nm`, the torque for the drive to apply next period if that
        period's command is late (``fine.pulse_fallback``): a doublet's next planned step, else the middle of the
        static band -- every torque of the stage is a timed preload, pulse or stiff servo torque (up to the whole
        30 A while the observe servo pulls a retreat's swing back), which held for a few late periods throws the
        valve (docs §113)."""
        torque = self._update(target, th1, thl, holding, torque_now, pressure_kpa)
        if torque is not None:
            # a doublet period's next step, then (and in every other period of the stage) the band middle
            middle = self._band_middle_torque(pressure_kpa)
            self.fallback_nm = self.fallback_nm + (() if middle is None else (middle,))
        return torque

    def _update(self, target: float, th1: float, thl: float, holding: bool, torque_now: float,
                pressure_kpa: float) -> float | None:
        if self._pending is not None or self._retreat_pending is not None:
            self.run_pending()            # not run after the last command (offline: nobody calls it): now, the same
        self.fallback_nm = ()             # (fine.pulse_fallback) set by a doublet period for the next: _doublet_torque
        if self._tables_gate == "released" and self.phase == IDLE and (
                self._plateau is None or abs(target - self._plateau) > self.cfg.tolerance_rad):
            # (task h36b) the deferred move tables are in: the policy from this plateau on (never mid-engagement)
            self.cfg, self._tables_gate = self._full_cfg, None
        cfg = self.cfg
        w1 = 0.0 if self._last_th1 is None else (th1 - self._last_th1) / self.period
        at_rest = self._last_valve is not None and abs(thl - self._last_valve) < 0.5 * cfg.tolerance_rad
        noisy = False
        if cfg.rest_noise_rate > 0.0:
            # (fine.rest_noise_rate, task s35) a noisy valve resolver: rest by the means of two windows
            self.valve_rest.update(thl, th1 - thl, holding and self.phase == IDLE)
            noisy = self.valve_rest.noisy
            if noisy:
                at_rest = self.valve_rest.at_rest()
                # ... and every judgment of the stage reads the valve through a short mean: a try's move against half
                # the tolerance, the observe's verdict and excursion, the hand-back's creep were single readings
                # (nominal box at 1 count rms, seeds 1000 / 2000 / 4000: plateaus > 8e-4 29 / 55 / 24 -> 13 / 16 / 18)
                thl = self.valve_rest.smoothed()
        self._last_th1, self._last_valve = th1, thl
        self._rest = self._rest + 1 if at_rest else 0
        if self.phase == IDLE:
            # the main law's moves: the twist of the last period the valve sat still (for the
            # engage time: a stick mid-swing is no breakaway from rest), once it has moved a couple
            # of tolerances from there (not a resolver-noise count), is the twist it broke loose
            # at (with the direction, position and Δp)
            if self._rest >= cfg.engage_periods:
                # (fine.rest_noise_rate) on a noisy resolver the means read rest for a few periods into a slide:
                # the rest is the older window's mean, its twist read at the slide's onset once the slide is seen
                self._rest_point = (None, self.valve_rest.rest_valve(), pressure_kpa) if noisy \
                    else (th1 - thl, thl, pressure_kpa)
            elif self._rest_point is not None and abs(thl - self._rest_point[1]) > 2.0 * cfg.tolerance_rad:
                phi, v, p = self._rest_point
                if phi is None:
                    phi = self.valve_rest.onset_twist(1 if thl > v else -1, v)
                self._breakaway_seen = (1 if thl > v else -1, phi, v, p)
                self._fresh = True
                self._rest_point = None
                self._observe_scale(self._breakaway_seen[0], phi, v, p)
                if self._breakaway_fits():
                    # the main law's breakaways from rest sample the same level the doublet
                    # climbs to (quasi-static: no overdrive), one per move, for free
                    d = self._breakaway_seen[0]
                    e0, b0 = self._nominal(v, p, d)
                    self._learn_breakaway(d, self.learn.band(self.m.pressure_fraction(p)), phi - b0, abs(b0 - e0),
                                          cfg.main_sample_weight)
        if self._first_demand is None:
            self._first_demand = target
        elif abs(target - self._first_demand) > cfg.tolerance_rad:
            self._demand_moved = True
        # a demand that keeps changing (ramps, sweeps, noise) is followed by the main law
        same = self._last_target is not None and abs(target - self._last_target) <= 1e-12
        self._steady = self._steady + 1 if same else 0
        self._last_target = target
        new_plateau = self._plateau is None or abs(target - self._plateau) > cfg.tolerance_rad
        if self.phase != IDLE and (self._target is None or new_plateau):
            if self._handover_settling(th1, w1):
                return self._servo(self._handover[0], 0.0, th1, w1, thl)
            torque = self._handover_unwinding(target, th1, w1, thl, pressure_kpa)
            if torque is not None:
                return torque
            self.reset(measurements=False)             # a new demand: the main law moves
            return None
        if new_plateau:
            self._plateau = target
            self._plateau_valve = thl     # (fine.cold_still) where the valve was when this demand arrived
            self._new_plateau()
            self._fresh = False           # no breakaway seen on this plateau yet
        self._count_reversals(thl)
        if self.phase != IDLE:
            # a demand shifted within the tolerance (a noisy analog demand, conditioned) is the same
            # plateau: it was reset at every shift and re-engaged with a fresh budget of pulses, so
            # 2 of 30 quick-campaign runs hunted at 1-7e-3 rad through a stream of new engagements
            self._target = target
        if self.phase == IDLE:
            err = target - thl
            if not self.timeable or not holding or self._rest < cfg.engage_periods \
                    or self._steady < cfg.engage_periods or abs(err) <= self._done_rad() \
                    or abs(err) > cfg.max_move_rad or self._spent() or self._below_min_move(err, pressure_kpa) \
                    or not self._plausible(thl, pressure_kpa, 1 if err > 0 else -1) \
                    or self._near_rating(thl, pressure_kpa, 1 if err > 0 else -1) \
                    or self._gear_unwinding(err, w1):
                return None
            cold = self._cold_ready(err, thl, pressure_kpa)
            early = not cold and not math.isinf(cfg.breakaway_fit) and (self._breakaway_seen is None or (
                not self._fresh and self._steady < FRESH_WAIT * cfg.engage_periods))
            if early and (self._breakaway_seen is None or not self._main_stays(err)):
                # wait for the main law to break it loose on this plateau (its breakaway twist is
                # the evidence the model fits), or to have held it a while without (a step too
                # small for it: the last breakaway seen is the evidence)
                return None
            fits = self._twist_fits(th1 - thl, thl, pressure_kpa) and (cold or self._breakaway_fits()) \
                and not self._rests_beyond_breakaway(th1 - thl, thl, pressure_kpa, 1 if err > 0 else -1)
            if early and (not fits or self._misfit_high(err, pressure_kpa)):
                # (fine.engage_inside_deadband) before the wait's end a twist that does not fit yet is no verdict: the
                # main law's hold relaxes the twist it left at its last stop by 1-2.7e-3 rad over the wait (toward the
                # band's middle), and judged at once, 1 of the nominal box's plateaus was marked unfit for good
                # (seed 1004 #4, 2.07e-3 rad off); the plateau is judged at the wait's end, as without the option
                return None
            if not fits or self._record_bad(err, pressure_kpa):
                self._unfit = True
                return None
            if self._cross_guard(err, pressure_kpa) is None:
                return None               # a move now could make the plateau hunt: the main law holds
            self._cold = cold
            self._engage(target, th1, thl, torque_now, pressure_kpa)
        torque = self._run(th1, w1, thl, pressure_kpa)
        if torque is None and self._handback_wait == 0:
            # (fine.handback_settle) a hand-back decided in this period that waits for the swing: held from now
            torque = self._servo(self._hold_ref, 0.0, th1, w1, thl)
        return torque

    def _done_rad(self) -> float:
        """The plateau's done-test radius, rad: ``fine.tolerance_rad``, or with ``fine.apex_policy`` and
        ``fine.apex_stop_rad`` above it, that (task h39t, docs §102).  The policy scores a try by its chance to land
        within ``fine.apex_land_rad`` and counts no value for the rest it already has: traced on C2 + F (nominal box,
        seeds 1000 / 2000 / 4000, 1440 plateaus), from rests at 2.9-4e-4 rad its tries moved the valve 85 times, 75 %
        of those left |e| larger and 59 % > 5e-4 (the smallest move a stop allows is ~0.7-1.4e-3 rad, §75.2); 81 of
        the 188 plateaus that ended > 5e-4 had rested within 5e-4 on the way."""
        cfg = self.cfg
        if cfg.apex_policy and cfg.apex_stop_rad > cfg.tolerance_rad:
            return cfg.apex_stop_rad
        return cfg.tolerance_rad

    def _handover_settling(self, th1: float, w1: float) -> bool:
        """(``fine.handover_settle_speed_rad_s``, task h38s, docs §98) Whether a new demand that arrived while the
        stage was mid-park, -pulse or -observe still waits for the gear output to settle before the main law takes
        over.  The main law restarts (:meth:`.laws.state_feedback.StateFeedbackLaw.reset`) from the torque that
        holds the present twist with its observer's gear-output and valve speeds at 0: handed over mid-doublet it is
        told a still twist while the gear output still runs at the kick's / retreat's speed (nominal seed 4034
        plateau #11: 2-3 rad/s toward the breakaway the step then goes to; the valve broke loose within 2 periods and
        slid 5.2e-3 rad past a 1.16e-2 step, 44.7 %).  Meanwhile the stage holds the gear output where it was when
        the demand changed (its servo brakes the swing) and hands over once it turns slower than the speed with the
        valve at rest for 3 periods, or after 2 x ``fine.observe_time_s``.  Off (0): at once, as before."""
        speed = self.cfg.handover_settle_speed
        if not speed > 0.0 or (self.phase not in (PARK, PULSE, OBSERVE) and self._handback_wait is None):
            return False
        if self._handover is None:
            self._handover = [th1, 0]     # (the gear output's angle held, periods waited)
        self._handover[1] += 1
        return not self._swing_settled(w1, self._handover[1])

    def _swing_settled(self, w1: float, waited: int) -> bool:
        """Whether a hand-over (:meth:`_handover_settling`) or a hand-back (``fine.handback_settle``) held for
        ``waited`` periods may let the main law take over: the gear output turns no faster than
        ``fine.handover_settle_speed_rad_s`` with the valve at rest for 3 periods, or 2 x ``fine.observe_time_s`` are up."""
        return (abs(w1) <= self.cfg.handover_settle_speed and self._rest >= 3) or waited > 2 * self.cfg.observe_periods

    def _handover_unwinding(self, target: float, th1: float, w1: float, thl: float,
                            pressure_kpa: float) -> float | None:
        """(``fine.handover_unwind``, task h38s, docs §98) A new demand arriving while the stage holds the valve (HOLD)
        with the twist on the new move's side of the static band's middle (between the learned breakaways): the stage
        first moves the gear output to the band's middle (a sin² blend over ``fine.observe_time_s``) and hands over once
        there, so that the main law's move does not start next to that way's breakaway (`startup` seed 0, C2: held
        2.8e-3 short of the opening breakaway, the +5.2e-3 step broke loose at once and the 5.7e-3 stick-slip jump
        ran 14.6 % past).  The torque, or None: hand over now (off, not HOLD, the twist on the other side, the blend
        done, or the valve moved)."""
        cfg = self.cfg
        if not cfg.handover_unwind or self.phase != HOLD:
            return None
        if self._unwind is None:
            jumps = cfg.handover_unwind_max_jumps
            if jumps > 0.0 and abs(target - thl) > jumps * self.m.friction(pressure_kpa).stick_slip_jump_rad(
                    self.m.coupling_stiffness_nm_per_rad):
                # (task h39h, docs §101) a step larger than the jump: started next to that way's breakaway the valve
                # lets go at once and slides toward the target, no further than it is; unwound to the middle first,
                # the main law's move stopped short more often (nominal 2028 #7, 2031 #6: 4.2-4.5e-3 short, its hold
                # then crept a whole jump past: 57.6 / 44.9 %)
                return None
            d = 1 if target > thl else -1
            mid = 0.5 * (self._twists(thl, pressure_kpa, 1)[1] + self._twists(thl, pressure_kpa, -1)[1])
            if d * ((th1 - thl) - mid) <= 0.0:
                return None
            near = cfg.handover_unwind_near
            if near > 0.0:
                fl = self.m.friction(pressure_kpa)
                gap = d * (self._twists(thl, pressure_kpa, d)[1] - (th1 - thl))   # twist left to that breakaway
                if gap > near * (fl.valve_static_nm - fl.valve_coulomb_nm) / self.m.coupling_stiffness_nm_per_rad:
                    # (task h39h) far enough from it that the main law's move creeps rather than lets go at once
                    # (nominal 2013 #2: 4.6e-3 rad of twist left; unwound, the plateau ended 1.3e-3 off, the next 5e-3)
                    return None
            self._unwind = [th1, thl + mid, 0, thl, target]   # (gear output from, to, periods, the valve and the
                                                                # demand at the start)
        th1_0, th1_1, k, thl0, target0 = self._unwind
        k += 1
        self._unwind[2] = k
        n = max(cfg.observe_periods, 1)
        if abs(thl - thl0) > 2.0 * cfg.tolerance_rad or k > n + 3:
            return None
        if cfg.handover_unwind_max_jumps > 0.0 and abs(target - target0) > 1e-12:
            # (task h39h) the demand moves on (a ramp's start, a sweep): followed by the main law, at once -- unwound,
            # a ramp from a hold started 18 periods late (startup seed 1: its ramp's path and later plateaus changed)
            return None
        x, v, a = self._blend(th1_0, th1_1, k * self.period, n * self.period)
        return self._servo(x, a, th1, w1, thl, v)

    def _gear_unwinding(self, err: float, w1: float) -> bool:
        """(``fine.engage_gear_rest``, task h37m, docs §95) Whether the gear output is still winding the twist away from
        the target (``err`` = target - valve, rad; ``w1`` the gear output's speed, rad/s, the valve at rest: the twist's
        rate) by more than ``fine.engage_gear_rest`` x ``fine.tolerance_rad`` a period: the main law's last move is
        still unwinding, the valve sits in a stick mid-swing with the twist running toward the other way's breakaway,
        and it slides on.  Traced (nominal
        box seed 4022 #11, C1 + ``fine.apex_level_law`` mixture): the main law's 3.9e-3 closing step broke the valve
        loose and it restuck 3.6e-3 past the target; the stage engaged 9 periods later (the valve still) with the twist
        still falling 1e-4 rad a period onto the closing edge, its first pulse's park saw the valve slide on (a "move
        away from the target": handed back) and the main law's move back overshot 1.2e-2 -- the plateau ended 5.5e-3
        off; nominal seed 2035 #7 with the gate at 0.5: the same chain, engaged with the twist still falling 0.49
        tolerance a period).  0 (default): no such gate (the valve's rest alone)."""
        if not self.cfg.engage_gear_rest > 0.0:
            return False
        d = 1 if err > 0 else -1
        return d * w1 * self.period < -self.cfg.engage_gear_rest * self.cfg.tolerance_rad

    def prepare(self, build: bool = True) -> tuple[int, float]:
        """Build ahead what the stage would otherwise build inside :meth:`update` (task h34t): with
        ``fine.apex_policy``, the doublet's move model (:func:`_pulse_moves`) and every keyed table its
        :meth:`_choose_apex` can read -- every Δp and angle point of the grid, both directions, every kick of
        :meth:`_apex_kicks` (the default 114 tables, ~14 s of CPU; kicks to 16 A three times that).  A lazy build
        inside a 1 kHz period costs ~0.12 s of CPU per table: a real-time caller calls this outside its control
        callback (the ROS controller node builds them in a background process instead: :meth:`defer_tables`).  The move model is made from the model the stage plans
        from now and kept (:class:`PositionController` calls ``prepare(build=False)`` as it builds the law: the told
        model, offline and in the node alike).  ``build`` False: make the model and count, build no table.
        Returns (tables that were still to build, CPU seconds spent building them);
        (0, 0.0) without ``fine.apex_policy`` (nothing is made: no cost for the default)."""
        if not self._configured.apex_policy:
            return 0, 0.0
        if self._moves is None:
            self._moves = _pulse_moves(self)
        kicks = self._apex_kicks()
        pending = len(self._moves.pending(kicks=kicks))
        if not build or not pending:
            return pending, 0.0
        return pending, self._moves.prepare(kicks=kicks)

    @property
    def _configured(self) -> FineConfig:
        """The stage's configuration as built -- not the staircase it runs while its move tables are deferred."""
        return self._full_cfg if self._tables_gate else self.cfg

    def defer_tables(self, gate: bool = True) -> list:
        """(task h36b) For a real-time caller that builds the tables elsewhere (a background process,
        :class:`~fuel_valve_control.core.pulse_moves.TableBuild`): the keys :meth:`prepare` would build ([]: none,
        or ``fine.apex_policy`` off -- nothing changes).  With keys pending the stage runs with ``fine.apex_policy``
        and its build's other options off (:data:`APEX_BUILD_OFF`) -- main's staircase, exactly -- until
        :meth:`release_tables`; the move model (:attr:`moves`) is made
        here.  No table is ever built inside :meth:`update` meanwhile.  ``gate`` False: the keys and the model only,
        the stage unchanged (it builds what it asks for lazily, as offline: a lockstep caller, whose simulated time
        waits for it, so its run is the offline simulator's whatever the cache holds)."""
        if not self._configured.apex_policy:
            return []
        self.prepare(build=False)
        keys = self._moves.pending(kicks=self._apex_kicks())
        if not gate:
            return keys
        if keys and self._tables_gate is None:
            self._full_cfg, self.cfg = self.cfg, replace(self.cfg, **dict.fromkeys(APEX_BUILD_OFF, False))
            self._tables_gate = "closed"
        elif keys:
            self._tables_gate = "closed"
        return keys

    def release_tables(self) -> bool:
        """(task h36b) The deferred tables are in the move model (:meth:`PulseMoves.adopt`): the policy takes over
        at the next plateau the stage starts idle (:meth:`update`).  False (still closed) while any table it can
        read is missing."""
        if self._tables_gate is None:
            return True
        if self._moves.pending(kicks=self._apex_kicks()):
            return False
        self._tables_gate = "released"
        return True

    @property
    def tables_deferred(self) -> bool:
        """(task h36b) The stage runs main's staircase while its ``fine.apex_policy`` tables are being made."""
        return self._tables_gate is not None

    @property
    def moves(self):
        """``fine.apex_policy``'s move model (:class:`~fuel_valve_control.core.pulse_moves.PulseMoves`) or None."""
        return self._moves

    def forget_scale(self) -> None:
        """Back to the told model: no friction scale read (``fine.learned_scale_*``) and no breakaway seen."""
        self.run_pending()                  # a try's start left for after the command is planned on the model it had
        self._breakaway_seen = None
        self.m = self.m0
        self.applied_scale = None           # (friction scale, load offset in T_s units) the stage plans from, or None
        self._time_scale = 1.0              # the servo-blended pulse's rise and fall times x this
        self._ratios = {1: [], -1: []}      # per direction: the last SCALE_SAMPLES friction ratios
        self.valve_rest.forget()            # (fine.rest_noise_rate) the resolver's noise read

    def _observe_scale(self, d: int, phi: float, thl: float, pressure_kpa: float) -> None:
        """Read the valve's friction scale from a main-law breakaway from rest toward ``d`` at twist
        ``phi`` (rad), valve ``thl`` (rad), Δp ``pressure_kpa`` (``fine.learned_scale_min/max``; off
        at 1, 1).  Its ratio ``r = (phi K - load(θ, Δp)) / T_s(Δp)`` (told model) is ``d s + l``: a valve
        with friction x s (or a coupling 1/s as stiff, or a Δp reading 1/s off in T_s) and an unknown
        steady load ``l T_s``.  Read each way (:meth:`_reading`: a median of the last ``SCALE_SAMPLES``)
        ``s = (r+ - r-) / 2``, ``l = (r+ + r-) / 2``.  Where the told model already fits
        them (``|s - 1| + |l|`` within ``fine.breakaway_fit``: every breakaway within its fit), ``s``
        lies outside [min, max] or ``|l|`` beyond ``fine.learned_load_max``, the stage plans from the told model (today's behaviour); else from
        :class:`LearnedModel` ``(s, l T_s)`` -- every check, preload, step and prior of the stage is then
        the told one on that model, and its learned twists (offsets from the model's) start over.  A
        change of ``s`` or ``l`` by more than ``SCALE_REPLAN`` x s re-plans (only while idle)."""
        cfg = self.cfg
        if cfg.learned_scale_min >= 1.0 >= cfg.learned_scale_max:
            return
        m0 = self.m0
        ts = m0.friction(pressure_kpa).valve_static_nm
        if ts <= 0.0:
            return
        r = (phi * m0.coupling_stiffness_nm_per_rad - m0.load_torque(thl, pressure_kpa)) / ts
        self._ratios[d] = (self._ratios[d] + [r])[-SCALE_SAMPLES:]
        rp, rm = self._reading(1), self._reading(-1)
        if rp is None or rm is None:
            return
        s, l = 0.5 * (rp - rm), 0.5 * (rp + rm)
        want = None if (abs(s - 1.0) + abs(l) <= cfg.breakaway_fit or abs(l) > cfg.learned_load_max
                        or not cfg.learned_scale_min <= s <= cfg.learned_scale_max) else (s, l)
        have = self.applied_scale
        if want is None and have is None:
            return
        if want is not None and have is not None and abs(want[0] - have[0]) <= SCALE_REPLAN * have[0] \
                and abs(want[1] - have[1]) <= SCALE_REPLAN * have[0]:
            return
        self.applied_scale = want
        self.m = self.m0 if want is None else LearnedModel.of(self.m0, s, l * ts)
        # the pulse drives the twist across a band s times the told one: its times x sqrt(s) keep the gear
        # output's acceleration (the current the cap limits) the told valve's, as fine.swing_scaled_pulse
        # does for a softer coupling (friction x2 with the told times: the capped pulses' apexes fell
        # 3-10e-3 rad of twist short of the planned peak, below the breakaway, task h26f)
        self._time_scale = 1.0 if want is None else max(math.sqrt(s), 1.0)
        for table in ("equilibrium", "breakaway", "scatter"):
            for dd in (1, -1):
                for b in range(self.learn.bands):
                    self.learn.set(table, dd, b, 0.0)

    def _reading(self, d: int) -> float | None:
        """The friction ratio of the main law's breakaways toward ``d`` (:meth:`_observe_scale`): the median
        of the last ``SCALE_SAMPLES``, the mean of two that agree within ``fine.breakaway_fit``, else None."""
        x = sorted(self._ratios[d])
        if len(x) >= 3:
            # fine.learned_agree: friction scatter spreads a valve's breakaways from rest by < 0.15 T_s (the
            # nominal plant, fine.breakaway_fit's measurement); kept ratios spread wider are not one valve's
            # edge but stops the main law ended off it (full box 1112, friction x0.59 with a 2.2 N*m load and
            # backlash 0.6e-3: closing ratios 0.68, 0.15, 0.30, then 0.45 ... 1.26 against openings 1.46-1.59;
            # their median read s 0.59, l 0.89 and the stage's move of -10.5e-3 left the run's plateaus 22.6 ->
            # 31.3e-3 rad in sum, task h29f) -- as two ratios that disagree, they read nothing
            if self.cfg.learned_agree and x[-1] - x[0] > self.cfg.breakaway_fit:
                return None
            return x[len(x) // 2]
        if len(x) == 2 and x[1] - x[0] <= self.cfg.breakaway_fit:
            return 0.5 * (x[0] + x[1])
        if len(x) == 1 and self.cfg.learned_one_sample and self._plausible_ratio(d, x[0]):
            return x[0]
        return None

    def _plausible_ratio(self, d: int, r: float) -> bool:
        """``fine.learned_one_sample``: whether a lone friction ratio ``r`` toward ``d`` may stand for its
        direction.  A breakaway toward ``d`` needs the twist beyond the other way's: ``d (r - r_other) > 0``
        for every ratio seen the other way (an opening ratio below a closing one is not a breakaway -- the
        nominal-box run 1036's opening -0.40 among closings at -1.0, task h26f); and it must lie within
        ``fine.breakaway_fit`` of the told edge ``d + l`` shifted by no more load than ``fine.learned_load_max``
        allows, i.e. ``|d r - 1| <= learned_scale_max - 1 + fit`` below and above -- the scatter friction
        explains, not a stop the main law ended on a load transient."""
        other = self._ratios[-d]
        if not other:
            return False
        if any(d * (r - q) <= 0.0 for q in other):
            return False
        cfg = self.cfg
        # a friction scale (or a softer coupling) moves both edges the same sense: |r| - 1 off the told edge
        # by more than fine.breakaway_fit one way AND every ratio the other way off the same sense.  A lone
        # misfit one way against a fitting other way is a stop the main law ended early, not a scale
        # (nominal-box run 1027: closing -0.48 against openings 0.90, 1.08, then -0.97, -0.94...; read as
        # friction x0.74 the box p95 went 1.32 -> 1.46e-3, task h28f)
        m = d * r - 1.0
        if abs(m) <= cfg.breakaway_fit or any(abs(-d * q - 1.0) <= cfg.breakaway_fit or (-d * q - 1.0) * m <= 0.0
                                               for q in other):
            return False
        lo = cfg.learned_scale_min - cfg.learned_load_max - cfg.breakaway_fit
        hi = cfg.learned_scale_max + cfg.learned_load_max + cfg.breakaway_fit
        return lo <= d * r <= hi

    def _near_rating(self, thl: float, pressure_kpa: float, direction: int) -> bool:
        """On a scale read (``fine.learned_scale_*``): whether the planned breakaway twist toward
        ``direction`` takes more than ``SCALE_HOLD_FRACTION`` x the continuous current to hold (the
        coupling torque at the told stiffness, at the motor).  On the told model: never (today's rule)."""
        if self.applied_scale is None or math.isinf(self.cfg.continuous_current_a):
            return False
        m = self.m
        phi_b = self._twists(thl, pressure_kpa, direction)[1]
        amps = abs(m.coupling_stiffness_nm_per_rad * phi_b) / (m.gear_ratio * m.torque_constant_nm_per_a)
        return amps > SCALE_HOLD_FRACTION * self.cfg.continuous_current_a

    def _cold_ready(self, err: float, thl: float, pressure_kpa: float) -> bool:
        """Whether to engage *cold*: no breakaway seen yet this run (the run's first steps, too
        small for the main law's hold to move the valve: 10 + 4 of the nominal box's plateaus >
        8e-4 rad on seeds 1000-1039 / 2000-2039 waited for one, 1.1-2.4e-3 off; task h21c), the
        valve held still ``FRESH_WAIT`` engage times on this demand, the error within half the
        nominal stick-slip jump (a quasi-static breakaway from rest slides the valve the whole jump,
        so the main law's hold leaves such an error alone -- its integrator's deadband is 0.55 of
        the jump; a larger one it ramps through within ~0.1 s, and a cold engagement that cut into
        that ramp left first plateaus 1-4e-3 off that the main law had finished), and
        ``fine.cold_start`` on.  ``thl`` (rad): the valve angle now, against where this plateau's demand found it
        (``fine.cold_still``).  With ``fine.cold_climb``: only once the demand has changed since the start and while
        the apex policy is on (the climb is the policy's).
        The valve is then judged by what the drive knows at rest -- its twist inside the nominal
        static band (:meth:`_twist_fits`, checked as for any engagement) -- and by the stage's own
        first breakaway, which must fit as the main law's would (:meth:`_breakaway_fits`).  Only
        doublets are made while cold (their moves at ~0 overdrive are the smallest the stage
        makes, and their staircase starts below the nominal breakaway)."""
        cfg = self.cfg
        if not cfg.cold_start:
            return False
        limit = 0.5 * self.m.friction(pressure_kpa).stick_slip_jump_rad(self.m.coupling_stiffness_nm_per_rad)
        if cfg.cold_climb and self.main_deadband_rad is not None:
            # (fine.cold_climb, task s33) any error the main law's hold leaves alone: its deadband (0.55 of the
            # jump) lies above half the jump, and first plateaus of 2.3-2.5e-3 rad stayed unmoved between the two (the
            # wait at rest has shown the hold leaves it: no count of noise margin, as :meth:`_main_stays` keeps)
            limit = max(limit, self.main_deadband_rad)
        if cfg.cold_climb and not cfg.apex_policy:
            # (fine.cold_climb, task s34) the climb is the policy's (its kicks' rises come from the move tables): where
            # the policy is off -- a ROS node's stage on main's staircase until its move tables are built (task h36b) --
            # a cold engagement would be the staircase's cold start, which throws a valve of less friction than told a
            # whole jump across its first small step (docs §114.9); none then
            return False
        if cfg.cold_climb and not self._demand_moved:
            # (fine.cold_climb, task s33) not on the error the valve started with: a demand the hold has not been
            # asked to reach is no step the main law left, and on the wrong-Δp grid (told the rated Δp at 0 Δp,
            # friction x0.05-0.09 of the told) the climb's first kick on the start's 5.2e-4 rad error carried the
            # valve along, and the main law's 2 % step from where it left it overshot 46 %
            return False
        if cfg.cold_still and (self._plateau_valve is None or abs(thl - self._plateau_valve) > cfg.tolerance_rad):
            # (fine.cold_still, task s34, docs §117) the valve moved on this plateau: the main law's hold carried it
            # toward the target (a creep below any slip the stage reads as a breakaway: LuGre friction) and it rests at
            # the edge of its band, not inside it -- the rest twist is no proof of a margin, and the climb's first kick
            # from it threw full box 3025 (LuGre x2.9, an untold 9.3 N*m load) 1.5e-2 rad across a 3.1e-3 rad step
            return False
        return (self._breakaway_seen is None and not math.isinf(cfg.breakaway_fit)
                and self._steady >= FRESH_WAIT * cfg.engage_periods
                and abs(err) <= limit
                and (not cfg.cold_band_gate or self._cold_band_fits(pressure_kpa)))

    def _main_stays(self, err: float) -> bool:
        """``fine.engage_inside_deadband``: whether the main law's hold will not move the valve on this plateau, so
        the stage need not wait ``FRESH_WAIT`` engage times for its breakaway (the last breakaway seen is the
        evidence, as after the wait).  Its integrator and stuck ramp act only on an error beyond the deadband
        in force (:attr:`main_deadband_rad`, rad, the jump-sized band of the main law's last period); inside it,
        by at least ``fine.tolerance_counts`` (a count of resolver noise cannot carry the error across the edge
        within the engage time), the hold keeps the drive it has, and the valve sits where it stopped.  The law
        leaves the band unset (None) where its hold probes inside the band (a coupling read softer than told,
        ``integral.probe_*``): there the wait is kept.  Traced (task h32d, docs §76, nominal box, seeds 1000-1039 /
        2000-2039): of 129 / 122 plateaus whose error at rest lay inside the deadband when the wait began, the
        main law moved the valve (> 0.5e-3 rad) during the wait on 1 / 0; the wait, 90 periods each, was 15 / 12
        of the 32 / 30 plateaus that ended > 8e-4 rad with the doublet staircase still climbing."""
        band = self.main_deadband_rad
        return (self.cfg.engage_inside_deadband and band is not None
                and abs(err) < band - self.cfg.tolerance_rad)

    def _cold_band_fits(self, pressure_kpa: float) -> bool:
        """``fine.cold_band_gate``: whether the static band the main law's hold has measured (half
        the width between its relax slips' two edges, N*m valve side, :attr:`hold_static_nm`, set by
        the law every period; None until both edges are met) lies within ``fine.breakaway_fit`` x
        T_s(Δp) of the told static friction.  A valve whose hold met both edges of a band this wide
        before any breakaway is a valve of about the told friction: the cold staircase, planned from
        the told breakaway, neither breaks a low-friction valve loose in its first preload (friction
        x0.6-0.85, §29.3: a whole jump across the target) nor climbs toward a level far above it
        (quick 3000 seed 3010, x2.77: hunted).  No band measured: no cold engagement (main's
        behaviour).  Traced (h30c, docs §67): on the nominal box the hold has met no slip edge at all
        before a run's first breakaway, so this gate, as measured, leaves the cold start off there."""
        band = self.hold_static_nm
        ts = self.m.friction(pressure_kpa).valve_static_nm
        return band is not None and ts > 0.0 and abs(band / ts - 1.0) <= self.cfg.breakaway_fit

    def _breakaway_fits(self) -> bool:
        """Whether the twist at which the main law last broke the valve loose fits the nominal
        breakaway twist ``(load(θ) ± T_s(Δp)) / K`` within ``fine.breakaway_fit`` x T_s/K (no
        breakaway seen yet: no -- engaged before any, on a x2.8-friction valve, 9 pulses that
        did not move it were followed by a hunt).  With the check off (``inf``) it is not needed.  Measured at each engagement (quick campaign and nominal box,
        task h16f): within +-0.15 T_s/K on the nominal plant with 2-8 % scatter, 0.5-2.7 off on
        the perturbed valves the stage hunted on (friction x0.6 / x2-3, soft coupling, load)
        -- every twist the stage plans from the model is then off by more than its preload margin."""
        if math.isinf(self.cfg.breakaway_fit):
            return True
        if self._breakaway_seen is None:
            return False
        d, phi, thl, pressure_kpa = self._breakaway_seen
        m = self.m
        k = m.coupling_stiffness_nm_per_rad
        static = m.friction(pressure_kpa).valve_static_nm / k
        nominal = m.load_torque(thl, pressure_kpa) / k + d * static
        return abs(phi - nominal) <= self.cfg.breakaway_fit * static

    def _misfit_high(self, err: float, pressure_kpa: float) -> bool:
        """Whether the misfit record of the direction of ``err`` at this Δp band is above ``fine.misfit_limit``
        (:meth:`_record_bad` without its decay: a look, not a plateau stayed out of)."""
        d = 1 if err > 0 else -1
        return self.learn.misfit[d][self.learn.band(self.m.pressure_fraction(pressure_kpa))] > self.cfg.misfit_limit

    def _record_bad(self, err: float, pressure_kpa: float) -> bool:
        """Whether the stage's recent record on this valve (direction of ``err``, this Δp band)
        is too poor to engage; staying out of a plateau lets the record decay, so the stage
        tries again after a few plateaus (friction that changes back is found again)."""
        d = 1 if err > 0 else -1
        b = self.learn.band(self.m.pressure_fraction(pressure_kpa))
        rec = self.learn.misfit[d][b]
        if rec <= self.cfg.misfit_limit:
            return False
        self.learn.set("misfit", d, b, rec * self.cfg.misfit_decay)
        return True

    def _judge(self, failed: bool) -> None:
        """Enter the outcome of this engagement into the misfit record (once per engagement)."""
        if self._judged is None:
            return
        d, b = self._judged
        self._judged = None
        w = self.cfg.misfit_weight
        self.learn.set("misfit", d, b, (1.0 - w) * self.learn.misfit[d][b] + w * (1.0 if failed else 0.0))

    def _engage(self, target, th1, thl, torque_now, pressure_kpa):
        if self.cfg.drop_rest_at_engage:
            # (h29a) the rest point is recorded only while the stage is idle, so the one held now dates from before
            # this engagement; kept, the first idle period after it (a hand-back, a new demand mid-staircase) read
            # the valve's displacement by the stage's own pulses as a main-law breakaway from that rest, at the twist
            # of that rest -- the twist the main law had held the valve with *before* the stage moved it, often in the
            # other direction's half of the band (nominal box seed 1003 #1: a "closing breakaway" at +2.0 T_s/K from
            # the nominal one, unfit: the stage stayed out and the plateau ended 2.9e-3 rad off)
            self._rest_point = None
        self._err0 = abs(target - thl)
        self._judged = (1 if target > thl else -1, self.learn.band(self.m.pressure_fraction(pressure_kpa)))
        self._target = target
        self._ff0 = torque_now                 # holds the present twist against load + reaction
        self._phi0 = th1 - thl                 # ... which is this twist
        self._anchor = None                    # (rad, way ±1): the furthest start toward the target
        self._last_engage = (self._ff0, self._phi0)
        self._integral = 0.0
        self._start_pulse(th1, thl, pressure_kpa)

    def _start_pulse(self, th1, thl, pressure_kpa, after_command: bool = False):
        """The next pulse's plan from the valve at ``thl`` (and the gear output at ``th1``).  ``after_command``
        (an observe's verdict with ``fine.apex_choice_after_command``, :meth:`_after_move`): an apex policy's
        choice is left for :meth:`run_pending`."""
        cfg = self.cfg
        err = self._target - thl
        d = 1 if err > 0 else -1
        phi_e, phi_b, band = self._twists(thl, pressure_kpa, d)
        gap = max(d * (phi_b - phi_e), 1e-5)                    # the static band above φe
        # preload just below breakaway; the pulse rises past it and falls to where the
        # planned swing (about φe) ends on the target -- a servo-blended pulse (errors beyond
        # the doublet's) ``fine.approach_short`` x the static band short of it: its moves spread
        # +-1e-3 rad about the plan at max Δp (nominal box, task h17f: 5.6-8.8e-3 for 4.7-8.3e-3
        # asked), and one that crosses leaves the doublet to come back from the other side with
        # a new staircase; short, it ends on the same side, where the doublet finishes the move.
        # (Sized by the band, not in rad: 5e-4 rad short at Δp 0, a tenth of the band there,
        # left a doublet to a valve the pulse had put on target -- 28 % overshoot of a 2 % step.)
        short = self._cross_guard(err, pressure_kpa) or 0.0
        # a staircase in progress at this stop stays a staircase: the valve has not moved since its
        # last doublet, and an error a count either side of fine.doublet_max_error_rad flipped the
        # pulse kind at every stair -- each servo-blended pulse that did not move the valve raised
        # the learned breakaway, the next doublet's preload started ~1e-3 rad higher and broke the
        # valve loose a whole jump across (nominal box, seed 2013 #8: 6.2e-3 rad; task h20p)
        stuck = self._servo_stuck(err, d, pressure_kpa)
        doublet = (abs(err) <= max(cfg.doublet_max_error_rad, 2.0 * short, self._doublet_jump_range(pressure_kpa))
                   or self._stair is not None and abs(err) <= cfg.doublet_max_error_rad + cfg.tolerance_rad
            or self._cold or self._restair is not None or stuck) and cfg.kick_current_a > 0.0
        if stuck and doublet and cfg.apex_policy and self._safe is not None and (
                self._apex_floor is None or self._apex_floor[0] != d or d * (self._safe - self._apex_floor[1]) > 0.0):
            # (fine.servo_unmoved_doublet) the policy's floor starts at the furthest twist the unmoved servo-blended
            # pulses reached at this stop (the level lies beyond it), not afresh from the law's start: handed over
            # without it, the policy's first tries reached 1.5e-3 rad of twist less than the last pulse had
            # (nominal 4013 #4, docs §112)
            self._apex_floor = (d, self._safe)
        aim = err if doublet else d * max(abs(err) - max(cfg.approach_short * gap, short), 0.0)
        final = phi_e + aim / 2.0
        pre = phi_b - d * cfg.preload_margin * gap
        if cfg.preload_sigmas > 0.0 and self.learn.scatter[d][band] > 0.0:
            # (h29a) the level is drawn anew at every stop: a preload fine.preload_margin x the band (0.69e-3 rad at
            # max Δp) below the learned level is 1-2 learned scatters on the nominal box's valves, and 86 of 2697
            # servo-blended pulses broke the valve loose a whole jump in their preload (two on a plateau hand it
            # back: 13 of its 117 plateaus > 8e-4 rad, seeds 1000-1039 / 2000-2039) -- at least as many scatters
            # below it as the doublet's staircase starts
            pre = phi_b - d * max(cfg.preload_margin * gap, cfg.preload_sigmas * self.learn.scatter[d][band])
        peak = phi_b + d * (cfg.overdrive_fraction * gap + self._pushes.get((d, band), 0.0))
        if d * (final - peak) > 0.0:
            peak = final
        if d * (pre - final) > 0.0:
            pre = final
        if cfg.preload_cap and self._safe is not None and d * (pre - self._safe) > 0.0:
            # the learned level may have climbed past what the unmoved pulses proved (the probe ratchet): a
            # preload beyond the furthest twist they reached at this stop is not known to hold the valve
            pre = self._safe
        self._dir, self._band = d, band
        self._thl0 = thl
        if self._anchor is None or self._anchor[1] != d or d * (thl - self._anchor[0]) > 0.0:
            self._anchor = (thl, d)
        self._pre, self._peak_planned, self._final = pre, peak, final
        self._phi_start = th1 - thl
        self._k = 0
        self._doublet = doublet
        self._apex_try = None
        self._park_hold = False
        if self._doublet:
            # the kick rises kick_rise above the preload; the retreat after it is the whole
            # current, so the valve breaks loose while the gear output is already turning back
            # ... and starts a staircase ``_stair`` below the learned breakaway: the level is
            # drawn anew at every stop, and one that breaks while preloading jumps the whole way
            self._first_stair = self._stair is None
            if self._stair is None:
                self._stairs_unmoved = 0       # (fine.stair_growth_after) a new staircase
                self._stair = self._start_sigmas(d, band) * self._scatter(d, band, gap)
                self._stair_step = cfg.doublet_probe_step * self._nominal_gap(thl, pressure_kpa, d)
                if self._restair is not None and self._restair[0] == d:
                    # (h30b) two preloads broke the valve loose below the learned level at this plateau's stops:
                    # the level lies lower than learned here -- the first apex goes fine.restair_sigmas learned
                    # scatters below the twist the last one broke at, not below the learned level
                    self._stair = d * (phi_b - self._restair[1]) + cfg.restair_sigmas * self._scatter(d, band, gap)
            self._pre = phi_b - d * (self._kick_rise() + self._stair)
            if cfg.apex_policy:
                choice = (err, d, phi_e, phi_b, self._scatter(d, band, gap), pressure_kpa, short, thl)
                if after_command:
                    # (fine.apex_choice_after_command) the choice and what follows from it run after this period's
                    # command has gone out (:meth:`run_pending`): nothing this period's command reads depends on it
                    self._pending = (choice, th1, thl, final, None)
                    return
                self._start_try(choice, th1, thl, final)
                return
        else:
            self._apex_last = None             # (fine.apex_floor_plan) a servo-blended pulse: no planned apex to climb from
        self._plan_park()
        self.phase = PARK
        self._peak_seen = th1 - thl

    def _start_try(self, choice: tuple, th1: float, thl: float, final: float) -> None:
        """(``fine.apex_policy``; :meth:`_start_pulse`'s end) The policy's choice for the doublet being started --
        ``choice``: :meth:`_choose_apex`'s arguments, ``th1`` / ``thl`` / ``final`` the start's -- and what follows
        from it: the park toward the apex's preload, or the hold when no try is worth making."""
        cfg = self.cfg
        err, d = choice[0], choice[1]
        # (task h33p) the apex from the level's law, not the staircase's stair; the preload the model's
        # kick rise below it
        # (fine.cold_climb) before any breakaway, a climb from the twist proven to hold while below the told level
        climb = None
        if self._cold and cfg.cold_climb:
            _, _, _, phi_b, sigma, pressure_kpa, _, valve = choice
            climb = self._cold_climb(d, phi_b, sigma, pressure_kpa, valve)
        apex = climb if climb is not None else self._choose_apex(*choice)
        if apex is None:
            # no try more likely to land than the policy's floor, or more likely to worsen |e|: hold here
            self._judge(failed=abs(err) > self._err0 + cfg.tolerance_rad)
            # ... at the doublet's final twist (about φe, inside the static band), not at th1: after an
            # unmoved doublet th1 lies in its retreat's trough, ~5e-3 rad of twist back (§55.1), and held
            # there the valve broke loose backwards (traced, nominal box seed 1017 #5: 5.8e-3 rad)
            if cfg.apex_keep_rad > 0.0 and self._w1_now is not None and abs(self._w1_now) > cfg.park_approach_speed:
                # (fine.apex_keep_rad, task h41n, docs §110) decided on an unmoved try's early verdict, the gear output
                # still swinging back from the retreat's trough (~2-4 rad/s): the hold's servo, its reference stepped
                # to the final twist, carried that swing past the apex the try had just failed to reach (nominal box
                # seed 4028 #11: twist 0.020 -> 0.038 rad, the valve slid 5.6e-3 rad toward the try).  Reached by a
                # park from the present twist instead (the reference leaves the gear output where it is, as a next
                # try's park does), held once the park ends
                self._pre, self._phi_start, self._park_hold = final, th1 - thl, True
                self._plan_park()
                self.phase = PARK
                self._peak_seen = th1 - thl
                return
            self.phase = HOLD
            self._hold_ref = thl + final
            return
        self._pre = apex - d * self._apex_rise
        self._plan_park()
        self.phase = PARK
        self._peak_seen = th1 - thl

    def _cold_climb(self, d: int, phi_b: float, sigma: float, pressure_kpa: float, thl: float) -> float | None:
        """(``fine.cold_climb``, task s33, docs §116) A cold try's apex (absolute twist, rad) toward ``d`` from the
        valve angle ``thl`` while the climb is still below the told level's region, or None (then the policy chooses,
        its law truncated at the climb's floor).  ``phi_b`` / ``sigma``: the learned level (absolute twist, rad) and
        its scatter (rad) the policy would place its try on.  The try parks at the furthest twist the valve is proven
        to hold toward ``d`` -- the highest apex an unmoved try reached at this stop, the twist it rested at when the
        stage engaged, or (``fine.cold_friction_min`` > 0) ``fine.doublet_sigmas`` scatters below the level of that
        fraction of the told friction, whichever lies furthest -- less the smallest kick's rise, and kicks with the
        largest kick (:meth:`_apex_kicks`).  Sets the kick, its rise and the observe servo's final twist.

        Why: before any breakaway the valve's level is not known; the policy's first preload, placed below the
        *told* level, broke a valve of friction x0.5-0.8 loose while parked -- a whole stick-slip jump past a 1.5e-3
        rad step (2.2-4.3e-3 rad off, docs §114.9).  A level on the climb is crossed in a kick, at most one climb step
        of overdrive (1.26e-3 rad of twist with 16 A at the rated Δp), and the retreat after it cuts the move short.
        Once the next apex would enter the told level's region (``fine.doublet_sigmas`` learned -- here prior --
        scatters below it) the policy takes over."""
        cfg = self.cfg
        if self._moves is None:
            self._moves = _pulse_moves(self)
        # the furthest twist proven to hold: the rest at engagement, the climb's floor, the least level assumed (if
        # any: with none, the load's twist less the margin is no proof -- under a load the controller was not told,
        # full box 3010's first park went 9.5e-3 rad of twist from the rest toward it)
        proven = self._phi0
        fl = self._floor(d)
        if fl is not None and d * (fl[1] - proven) > 0.0:
            proven = fl[1]
        if cfg.cold_friction_min > 0.0:
            assumed = self._load_twist(thl, pressure_kpa) + d * (self._cold_least_rad(pressure_kpa)
                                                                 - cfg.doublet_sigmas * sigma)
            if d * (assumed - proven) > 0.0:
                proven = assumed
        kicks = self._apex_kicks()
        step = APEX_DP_STEP * self.m.pressure_max_kpa
        rises = self._moves.rises(d, round(pressure_kpa / step) * step, kicks, valve_angle_rad=thl)
        # the park to the preload rings past it (2.4e-4 rad of twist on a x0.6 valve, which broke loose 2.7e-3 rad
        # across in the park to its floor): the preload lies the smallest kick's rise short of the proven twist
        apex = proven + d * (rises[-1] - rises[0])
        if d * (apex - (phi_b - d * cfg.doublet_sigmas * sigma)) >= 0.0:
            return None
        self._apex_kick, self._apex_rise = kicks[-1], rises[-1]
        self._apex_last, self._apex_try, self._apex_plan = (d, apex), None, None
        # the observe servo's final twist on the level this try would meet: the told swing centre (load + T_c) / K is
        # the told valve's; a valve that lets go at the climb's apex has the levels of friction x (apex - e) K / T_s,
        # and held at the told centre it slid on (x0.6: 6.9e-3 rad for a 1.5e-3 rad step) -- its own centre is the
        # told T_c / T_s of the way to the apex
        fr = self.m.friction(pressure_kpa)
        e = self._load_twist(thl, pressure_kpa)
        ratio = fr.valve_coulomb_nm / fr.valve_static_nm if fr.valve_static_nm > 0.0 else 1.0
        self._final = e + ratio * (apex - e) + (self._target - thl) / 2.0
        return apex

    def _load_twist(self, thl: float, pressure_kpa: float) -> float:
        """The twist that holds the told load at ``thl`` (rad): the middle of the static band."""
        m = self.m
        return m.load_torque(thl, pressure_kpa) / m.coupling_stiffness_nm_per_rad

    def _cold_static_min(self, d: int, thl: float, pressure_kpa: float) -> float:
        """(``fine.cold_climb``) The least static twist T_s/K (rad) the valve is known to have before any breakaway:
        ``fine.cold_friction_min`` x the told, or more where the twist it rested at (its distance from the load's
        twist) or the climb's floor toward ``d`` shows it."""
        e = self._load_twist(thl, pressure_kpa)
        fl = self._floor(d)
        return max(self._cold_least_rad(pressure_kpa), abs(self._phi0 - e), 0.0 if fl is None else d * (fl[1] - e))

    def _cold_least_rad(self, pressure_kpa: float) -> float:
        """(``fine.cold_climb``) ``fine.cold_friction_min`` x the told static twist T_s(Δp)/K, rad."""
        m = self.m
        return self.cfg.cold_friction_min * m.friction(pressure_kpa).valve_static_nm / m.coupling_stiffness_nm_per_rad

    def run_pending(self) -> bool:
        """(``fine.apex_choice_after_command``, task h39n, docs §103) Finish the try whose start an observe's verdict
        left for after the period's command (:meth:`_start_pulse`): the apex policy's choice (~0.5-1 ms of CPU) and
        the park or hold it leads to.  The ROS node calls it once the period's command has gone out
        (``ValveDriver.after_period``); otherwise the next :meth:`update` (or :meth:`reset`) runs it first.  The
        period that started the try commands what the inline choice's period commanded (its observe servo reads
        nothing the choice sets) but for the limit-cycle watch's count, which a hold's verdict adds here.  A kick
        period's retreat plan left for after its command (``fine.retreat_plan_after_command``, :meth:`_settle_retreat`)
        is made here too.  Returns whether there was any such work."""
        retreat = self._retreat_pending is not None
        if retreat:
            self._settle_retreat()            # (fine.retreat_plan_after_command) the kick period's retreat plan
            self.retreat_plans_after_command += 1
            if self.fallback_nm:
                # (fine.pulse_fallback) the kick period's: the planned retreat, then the band middle
                self.fallback_nm = (self._retreat_torque(self._retreat),) + self.fallback_nm[1:]
        pending, self._pending = self._pending, None
        if pending is None:
            return retreat
        choice, th1, thl, final, fb = pending
        self.apex_choices_after_command += 1
        self._start_try(choice, th1, thl, final)
        if self.phase == HOLD and fb is not None:
            # the servo's limit-cycle watch in the starting period counted a hold as settled (:meth:`_servo`): what
            # the inline choice's HOLD phase counted there, after the same leak
            self._count_reversal(fb, self.cfg.peak_current_a * self.m.torque_constant_nm_per_a)
        return True

    def _apex_law(self, d: int, phi_b: float, sigma: float,
                  pressure_kpa: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(``fine.apex_policy``) The law of the level (the breakaway twist, rad, absolute) this stop drew, toward
        ``d``: the learned level ``phi_b`` and scatter ``sigma`` as a clipped normal on APEX_LAW_POINTS points over
        +-APEX_LAW_SIGMAS scatters (the box's law as plateau_floor's (b') knows it), truncated from below by the
        highest apex an unmoved doublet reached at this stop (``_apex_floor``: a measured twist, reset by a move).
        Where the floor lies beyond the law's points the level is in the normal's far tail: there the law is the
        tail's exponential (rate z / sigma, z the floor's distance in scatters) above the floor.  With
        ``fine.apex_level_law`` not "normal" the law is :func:`mixture_level_law` over :meth:`_level_scales` (at
        ``pressure_kpa``, None: the rated Δp).
        Returns (levels, weights summing to 1)."""
        fl = self._floor(d)
        if self.cfg.apex_level_law != "normal":
            scales, weights = self._level_scales(sigma, pressure_kpa)
            if len(scales) > 1:
                return mixture_level_law(phi_b, d, scales, weights, None if fl is None else fl[1],
                                         self.cfg.apex_mix_points)
        z, w = _APEX_Z, _APEX_W
        lv = phi_b + d * sigma * z
        if fl is not None:
            above = d * (lv - fl[1]) > 0.0
            if (w * above).sum() < 1e-3 * w.sum():
                zf = max(d * (fl[1] - phi_b) / sigma, 1.0)
                t = np.linspace(0.0, 3.0 * sigma / zf, APEX_LAW_POINTS)[1:]
                lv, w = fl[1] + d * t, np.exp(-t * zf / sigma)
            else:
                w = np.where(above, w, 0.0)
        return lv, w / w.sum()

    def _level_scales(self, sigma: float, pressure_kpa: float | None) -> tuple[np.ndarray, np.ndarray]:
        """(``fine.apex_level_law``, task h36l, docs §92) The scatters (rad) and weights of the level's law
        (:func:`level_law_scales`): for "mixture" from the learned ``sigma`` up to the widest scatter the stage is
        designed for -- a level within ``fine.breakaway_fit`` x T_s(Δp)/K of nominal (the engage gate's bound) at
        APEX_LAW_SIGMAS scatters: breakaway_fit / 3 x T_s/K (0.1 T_s/K = 1.15e-3 rad at the rated Δp, nominal
        valve); for "student" the degrees of freedom of the learned scatter, an exponentially weighted mean of
        squares with weight ``fine.scatter_gain`` g: (2 - g) / g samples' worth, less one."""
        cfg, m = self.cfg, self.m
        p = m.pressure_max_kpa if pressure_kpa is None else pressure_kpa
        hi = cfg.breakaway_fit / APEX_LAW_SIGMAS * m.friction(p).valve_static_nm / m.coupling_stiffness_nm_per_rad
        g = min(max(cfg.scatter_gain, 1e-6), 1.0)
        nu = max((2.0 - g) / g - 1.0, 1.0)
        return level_law_scales(cfg.apex_level_law, sigma, hi if np.isfinite(hi) else sigma, nu)

    def _floor(self, d: int) -> tuple[int, float] | None:
        """(``fine.apex_policy``) (direction, twist rad) below which this stop's level does not lie toward ``d``: the
        highest apex an unmoved doublet reached (``_apex_floor``, as the resolvers read it) -- with
        ``fine.apex_floor_plan`` the higher of that and the apex the last (unmoved) try planned: the twist is
        sampled once a period and its reading misses the kick's peak (0.4-1.6e-4 rad below it for 4-8 A kicks,
        docs §82.3; the true apex lay a median 2e-5 rad *past* the plan, §85), so a law truncated at the reading
        keeps levels the try has already ruled out and the next try repeats it.  None: no floor."""
        fl = self._apex_floor
        if fl is None or fl[0] != d:
            return None
        last = self._apex_last
        if (self.cfg.apex_unraised_plan and self._floor_unraised == fl and last is not None and last[0] == d
                and d * (last[1] - fl[1]) > 0.0):
            # (task h37t, docs §96) the last unmoved try's reading raised the floor by less than a resolver count:
            # the law truncated at the reading gives the same try again (full box 1027, K x0.81 untold: the kick's
            # apex read 0.45e-3 rad below its plan, 15 / 15 / 141 identical unmoved tries on plateaus #9-#11) --
            # the try's planned apex is the floor instead, so the next try climbs
            return (d, last[1])
        plan = self.cfg.apex_floor_plan or (self.cfg.apex_floor_repeat and self._apex_repeat)
        if plan and last is not None and last[0] == d and d * (last[1] - fl[1]) > 0.0:
            return (d, last[1])
        return fl

    def _note_unmoved_plan(self, d: int) -> None:
        """(``fine.apex_floor_repeat``, task h37m, docs §95) Book an unmoved policy try toward ``d`` (called before the
        floor takes its reading): the furthest apex planned by an unmoved try at this stop (:attr:`_apex_tried`; the
        stop's first unmoved try -- no floor yet -- starts it afresh) and whether this try's plan lay no further than
        that (within half of ``fine.tolerance_rad``): the law truncated at the measured apex led the policy back to an
        apex it had tried -- the reading is short of the plan (§85: 0.4-1.6e-4 rad for 4-8 A kicks) -- and from then
        on :meth:`_floor` is the plan for the rest of the stop.  Traced (``startup`` seed 0, C1 + the mixture law):
        after a crossing the policy made 81 tries at 15 apexes over 2.2 s, a median 1.65e-4 rad past their readings
        and 0.9-11e-4 short of the level, none moved; the plateau ended 4.6e-4 off, parked mid-doublet on the far side
        of the band, and the ramp after it lagged 10.6e-3 rad."""
        if self._apex_floor is None or self._apex_floor[0] != d:
            self._apex_tried, self._apex_repeat = None, False
        last = self._apex_last
        if not self.cfg.apex_floor_repeat or last is None or last[0] != d:
            return
        tried = self._apex_tried
        if tried is not None and d * (last[1] - tried) <= 0.5 * self.cfg.tolerance_rad:
            self._apex_repeat = True
        if tried is None or d * (last[1] - tried) > 0.0:
            self._apex_tried = last[1]

    def _apex_kicks(self) -> list[float]:
        """(``fine.apex_policy``) The kick currents (A) the policy chooses among: ``fine.kick_current_a`` times
        ``fine.apex_kick_ratio`` (2) while within ``fine.apex_kick_max_a``, at most :data:`APEX_MAX_KICKS` of them (a finer
        ratio: the same span in that many geometric steps) (docs §75.4: the kick's size sets how much the level's draw matters
        -- a larger kick rises further above its preload, breaks the valve loose earlier in its rise for a low
        level, and its move varies less with the level)."""
        k0, top, r = self.cfg.kick_current_a, self.cfg.apex_kick_max_a, max(self.cfg.apex_kick_ratio, 1.05)
        kicks = [k0]
        if not k0 > 0.0:
            return kicks               # (no kick to grow: 0 x r stays 0 -- the loop below would never end)
        while kicks[-1] * r <= top + 1e-9:
            kicks.append(kicks[-1] * r)
        if len(kicks) > APEX_MAX_KICKS:
            # a finer set than the tables and the try's CPU can carry: the same span in APEX_MAX_KICKS steps
            step = (kicks[-1] / k0) ** (1.0 / (APEX_MAX_KICKS - 1))
            kicks = [k0 * step ** i for i in range(APEX_MAX_KICKS)]
        return kicks

    def _choose_apex(self, err: float, d: int, phi_e: float, phi_b: float, sigma: float, pressure_kpa: float,
                     short: float, thl: float) -> float | None:
        """(``fine.apex_policy``, task h33p, docs §81) The doublet's apex (absolute twist, rad) for the error
        ``err`` (target - valve, rad) toward ``d`` from the valve angle ``thl``, or None (no try worth making: the
        stage holds); sets the kick (:attr:`_apex_kick`, A) and its rise above the preload (:attr:`_apex_rise`).
        Over the level's law (:meth:`_apex_law`, points L_k with weights w_k), each kick (:meth:`_apex_kicks`) and
        candidate apex a (the law's points and up to 1.5 scatters above its top) moves the valve where it
        exceeds the level (overdrive a - L_k > 0) by the move model's M(excess L_k - φe, overdrive, aim |e|)
        (:func:`_pulse_moves`), read with an rms error ``fine.apex_move_sd_rad``; a level below the preload (a
        - the kick's rise) breaks the valve loose while parked, a whole stick-slip jump.  Each scores
        P(|e - M| <= ``fine.apex_land_rad``) + P(no move) x V1(a), V1 the best such landing chance of one more
        try (main's kick) on the law truncated at a (benchmarks/plateau_floor.py's ``choose_bayes``, one step
        ahead; the plateau's time left is not known to the stage: every try counts it).  Not made: a try more
        likely to leave |e| larger than smaller, one more likely to break the valve loose in its preload than
        main's staircase start (Φ(-``fine.doublet_sigmas``)), one whose score is not above
        ``fine.apex_min_chance``.  ``short`` > 0 (:meth:`_cross_guard`: the move must not cross): a landing
        counts only on this side of the target, any crossing as a worse |e|."""
        cfg = self.cfg
        self.apex_choices += 1
        if self._moves is None:
            self._moves = _pulse_moves(self)
        lv, w = self._apex_law(d, phi_b, sigma, pressure_kpa)
        # the model's tables are keyed by Δp and angle: read at 1 % of the rated Δp (the measured Δp's noise would
        # build a new table at every try, 0.15 s of CPU each; the levels change < 1 % over it) and 0.01 rad
        step = APEX_DP_STEP * self.m.pressure_max_kpa
        pressure_kpa = round(pressure_kpa / step) * step
        top = lv[-1] if d * (lv[-1] - lv[0]) > 0 else lv[0]
        cand = np.concatenate([lv, top + d * sigma * _APEX_ABOVE])
        fl = self._floor(d)
        if fl is not None:
            cand = cand[d * (cand - fl[1]) > 0.0]
        if len(cand) == 0:
            return None
        if cfg.apex_excess_nominal:
            # (task h34m, docs §85) the move model's excess is the level above the Coulomb equilibrium of the model
            # it was built from (load + T_c)/K; the learned φe is the swing centre of the stage's own moves
            # (φ_final - move / 2), which lies 0.14-0.21e-3 rad further toward the try (nominal box), and read the
            # moves 1.3-1.4 x short
            phi_e = self._nominal(thl, pressure_kpa, d)[0]
        od = d * (cand[:, None] - lv[None, :])               # [a, k] overdrive, rad
        excess = np.maximum(d * (lv - phi_e), 0.0)         # [k] the level above φe
        moved = od > 0.0
        e, s, tol = abs(err), max(cfg.apex_move_sd_rad, 1e-9), cfg.apex_land_rad
        lo = 0.0 if short > 0.0 else -tol
        worse_edge = 0.0 if short > 0.0 else -e
        fixed = self._fixed_sums()
        p_none = _wsum((~moved).astype(float), w, fixed)
        beyond = _beyond_levels(d, lv, cand, fixed)         # the levels the law keeps after no move at a
        break_limit = _break_limit(cfg.doublet_sigmas)
        kicks = self._apex_kicks()
        if cfg.apex_kick_continuous and fl is not None and len(kicks) > 1:
            best = self._score_tables(d, pressure_kpa, thl, kicks, cand, fl, od,
                                      np.broadcast_to(excess[None, :], od.shape), moved, w, beyond, p_none,
                                      e, s, tol, lo, worse_edge, break_limit)
        else:
            best = self._score_points(d, pressure_kpa, thl, kicks, cand, od, excess, moved, w, beyond, p_none,
                                      e, s, tol, lo, worse_edge, break_limit)
        self._apex_plan = (best[1], best[4], best[5], best[0], best[2], best[6])
        if not best[0] > cfg.apex_min_chance:
            return None
        self._apex_kick, self._apex_rise = best[2], best[3]
        self._apex_last = (d, best[1])
        self._apex_try = (d, best[6])          # the model's mean move, if this try moves (traced in §81)
        return best[1]

    def _worse_given_move(self, e: float) -> bool:
        """Whether a try from the error ``e`` (|target - valve|, rad) is judged by its chance to worsen |e| *given
        that it moves* (``p_worse <= ½ (1 - P(no move))``) rather than unconditionally (``p_worse < ½``): always with
        ``fine.apex_worse_given_move`` (§85), and with ``fine.apex_keep_rad`` > 0 from a rest within that radius
        (task h41n, docs §110).  Why the radius: traced on C3 (nominal box, seeds 1000 / 2000 / 4000), of the 36
        plateaus > 8e-4 rad that are not a run's first, 16 ended after a try from a rest at 4.8-7.9e-4 rad (12 of
        them with P(land) <= 0.05 and P(no move) 0.85-0.96: the unconditional rule passes such a try on P(no move)
        alone) whose move, a stick-slip jump of 1.15-2.0e-3, crossed the target and left |e| larger.  From a rest
        that close the move can only be smaller than the jump by luck, and the rest is worth keeping; from further
        out (the rule everywhere, §85 / §110.3) holding instead gives up plateaus a later try would have landed.
        Measured (radius 8e-4, nominal pool of 1440): > 8e-4 63 -> 56, p95 0.756 -> 0.706e-3, > 5e-4 162 -> 167."""
        cfg = self.cfg
        return cfg.apex_worse_given_move or (cfg.apex_keep_rad > 0.0 and e <= cfg.apex_keep_rad)

    def _fixed_sums(self) -> bool:
        """(task h38x, docs §99) Whether the choice's weighted sums avoid BLAS (:func:`_wsum`, :func:`_beyond_best`):
        for every level law but "normal" (the mixture's 89 x 81 x 89 product ran on BLAS's threads, its bits the
        machine's; the normal law's products keep main's bits)."""
        return self.cfg.apex_level_law != "normal"

    def _score_tables(self, d, pressure_kpa, thl, kicks, cand, fl, od, excess, moved, w, beyond, p_none, e, s, tol,
                      lo, worse_edge, break_limit) -> tuple:
        """(:meth:`_choose_apex`) The best try over every candidate x kick (with ``fine.apex_kick_continuous``, the
        continuous kick's too) scored on whole [candidate, level] tables of moves: (score, apex, kick, rise,
        P(land), P(no move), mean move).  The arrays as :meth:`_choose_apex` builds them."""
        cfg = self.cfg
        fixed = self._fixed_sums()
        best, v1 = None, None
        tabs = [(kick, self._moves.rise(d, pressure_kpa, kick_current_a=kick, valve_angle_rad=thl),
                 np.asarray(self._moves.move(d, pressure_kpa, excess, od, kick_current_a=kick, aim_rad=e,
                                             valve_angle_rad=thl), dtype=float)) for kick in kicks]
        options = list(tabs)
        if cfg.apex_kick_continuous and fl is not None and len(tabs) > 1:
            options.append(self._continuous_kick(d, fl[1], cand, tabs))
        for kick, rise, mv in options:
            if kick is None:
                continue
            rise = np.asarray(rise, dtype=float)[:, None] if np.ndim(rise) else rise
            # a level below the preload breaks the valve loose while parked: a quasi-static release, the whole
            # stick-slip jump 2 x excess (main's staircase starts fine.doublet_sigmas scatters below the level for
            # this; traced, task h33p: nominal box seed 1021, a preload 0.39e-3 below the learned level broke it
            # loose for 3.4e-3 rad)
            mv = np.where(od > rise, 2.0 * excess, mv)
            left = e - np.where(np.isfinite(mv), mv, 2.0 * e + 1.0)   # |e| left toward the target (< 0: crossed)
            hit = np.where(moved, _norm_cdf((tol - left) / s) - _norm_cdf((lo - left) / s), 0.0)
            worse = np.where(moved, _norm_cdf((worse_edge - left) / s), 0.0)
            p_hit, p_worse, p_break = (_wsum(hit, w, fixed), _wsum(worse, w, fixed),
                                       _wsum((od > rise).astype(float), w, fixed))
            if v1 is None:
                v1 = _beyond_best(hit, w, beyond, fixed)     # one more try after no move at a: the law beyond a
            score = p_hit + p_none * v1
            ok = p_worse < 0.5
            if self._worse_given_move(e):
                # (task h34m, docs §85) more likely to worsen |e| than not *if it moves*: at a stop whose level lies
                # high (excess 2.5-4.5e-3 rad, smallest move 1.2e-3 and more) every move overshoots the error, and
                # the unconditional rule let the law's climb (P(no move) 0.8-0.9, P(land) 0) go on until the valve
                # let go for 1.3-2.2e-3 rad against errors of 0.35-0.75e-3 (nominal box seed 1020)
                ok = ok & (p_worse <= 0.5 * (1.0 - p_none))
            score = np.where(ok & (p_break <= break_limit), score, -np.inf)
            if np.ndim(kick):
                score = np.where(np.isfinite(kick), score, -np.inf)   # a continuous kick the set cannot size
            j = int(np.argmax(score))
            if best is None or score[j] > best[0]:
                pm = float(_wsum(moved[j].astype(float), w, fixed))
                m_mean = (float(_wsum(np.where(moved[j] & np.isfinite(mv[j]), mv[j], 0.0), w, fixed) / pm)
                          if pm > 0 else 0.0)
                kj, rj = (float(kick[j]), float(rise[j, 0])) if np.ndim(kick) else (kick, rise)
                best = (float(score[j]), float(cand[j]), kj, rj, float(p_hit[j]), float(p_none[j]), m_mean)
        return best

    def _score_points(self, d, pressure_kpa, thl, kicks, cand, od, excess, moved, w, beyond, p_none, e, s, tol, lo,
                      worse_edge, break_limit) -> tuple:
        """(:meth:`_choose_apex`, task h37a, docs §94) :meth:`_score_tables` for the kick set alone, bit for bit, on
        the elements that change a sum: a try's chances are sums over the levels weighted by the law (and v1's by
        the law truncated at the candidate), so a level of weight 0 (below the stop's floor) adds an exact 0 whatever
        its move; a level below the preload (overdrive > the kick's rise) moves the whole jump 2 x excess, a function
        of the level alone (its chances read once per level, not per candidate and kick); an apex below the level
        does not move (chances 0).  The move model is read (:meth:`PulseMoves.move_points`, all kicks in one pass)
        and the normal CDFs evaluated (one pass for all kicks) only where the apex lies between the level and the
        preload's reach at a level of weight.  ``excess``: per level (1-D).  Returns as :meth:`_score_tables`."""
        cfg = self.cfg
        fixed = self._fixed_sums()
        rises = self._moves.rises(d, pressure_kpa, kicks, valve_angle_rad=thl)
        nk, ak = od.shape[1], od.size
        brk = od[None, :, :] > np.array(rises)[:, None, None]     # [kick, a, k] a level below the preload
        # (task h40m, docs §106) the points read on the move model by flat index [kick, a, k] (ascending)
        idx = np.flatnonzero((moved & (w > 0.0)[None, :])[None, :, :] & ~brk)
        kk = idx // ak
        pair = idx - kk * ak
        ki = pair % nk
        mvp = self._moves.move_points(d, pressure_kpa, kicks, kk, excess, od.reshape(-1)[pair], aim_rad=e,
                                      valve_angle_rad=thl, level=ki)
        # |e| left: at the read points, and per level for a break in the preload (2 x excess, finite)
        left = np.concatenate([e - np.where(np.isfinite(mvp), mvp, 2.0 * e + 1.0), e - 2.0 * excess])
        # the three normal CDFs of every |e| left in one pass (the edges of a landing, a worsening)
        cdf = _norm_cdf_tails((np.array([tol, lo, worse_edge])[:, None] - left[None, :]) / s)
        n = len(mvp)
        if fixed:
            # (task h40m) hit, worse and break side by side: one fill, one product, one sum (each row's sum is the
            # same bits computed alone or with the others, docs §99)
            prefix = beyond.ndim == 1        # the levels ordered toward the try: each row's break mask is a prefix
            lvl = np.empty((2 if prefix else 3, nk))
            np.subtract(cdf[0, n:], cdf[1, n:], out=lvl[0])
            lvl[1] = cdf[2, n:]
            if not prefix:
                lvl[2] = 1.0
            slab = np.where(brk[None], lvl[:, None, None, :], 0.0)     # [hit / worse (/ break), kick, a, k]
            flat = slab.reshape(len(lvl), -1)
            flat[0, idx] = cdf[0, :n] - cdf[1, :n]
            flat[1, idx] = cdf[2, :n]
            sums = np.add.reduce(slab * w, axis=-1)
            p_hit, p_worse = sums[0], sums[1]
            if prefix:
                # (task h40m) od falls along each row (d lv ordered), so a level below the preload is one of the first
                # m of its row: the break's sum is the law's first-m sum, row m of a table of prefixes (the same
                # elements w / 0.0, the same row sums)
                m = np.count_nonzero(brk, axis=-1)
                p_break = np.add.reduce(np.where(_prefix_mask(nk), w, 0.0), axis=-1)[m]
            else:
                p_break = sums[2]
            hit = slab[0]
        else:
            # the normal law: main's BLAS products, each on its own array as ever
            hit_all, worse_all = cdf[0] - cdf[1], cdf[2]
            hit = np.where(brk, hit_all[n:], 0.0)
            hit.reshape(-1)[idx] = hit_all[:n]
            worse = np.where(brk, worse_all[n:], 0.0)
            worse.reshape(-1)[idx] = worse_all[:n]
            p_hit, p_worse, p_break = (_wsum(hit, w, fixed), _wsum(worse, w, fixed),
                                       _wsum(brk.astype(float), w, fixed))
        v1 = _beyond_best(hit[0], w, beyond, fixed)   # one more try after no move at a (main's kick): the law beyond a
        score = p_hit + p_none * v1
        ok = p_worse < 0.5
        if self._worse_given_move(e):
            ok = ok & (p_worse <= 0.5 * (1.0 - p_none))
        score = np.where(ok & (p_break <= break_limit), score, -np.inf)
        js = np.argmax(score, axis=1)
        bi = None
        for i, j in enumerate(js):               # the first kick whose best is above every earlier kick's
            if bi is None or score[i, j] > score[bi, js[bi]]:
                bi = i
        j = int(js[bi])
        pm = float(_wsum(moved[j].astype(float), w, fixed))
        # the try's mean move (its row as _score_tables reads it at the levels of weight: the whole jump below the
        # preload, the model's move between the level and the preload's reach; 0 elsewhere -- each x 0 in the sum)
        mrow = np.where(brk[bi, j], 2.0 * excess, 0.0)
        r0, r1 = np.searchsorted(idx, (bi * ak + j * nk, bi * ak + (j + 1) * nk))    # the read points of (bi, j)
        mrow[ki[r0:r1]] = mvp[r0:r1]
        m_mean = float(_wsum(np.where(moved[j] & np.isfinite(mrow), mrow, 0.0), w, fixed) / pm) if pm > 0 else 0.0
        return (float(score[bi, j]), float(cand[j]), kicks[bi], rises[bi], float(p_hit[bi, j]), float(p_none[j]),
                m_mean)

    def _continuous_kick(self, d: int, floor: float, cand: np.ndarray, tabs: list) -> tuple:
        """(``fine.apex_kick_continuous``, task h34m, docs §85) The continuous kick from the floor: the preload stays
        at the stop's last unmoved apex ``floor`` (absolute twist, rad: a twist that held the valve, so the park
        cannot break it loose), less APEX_PRE_MARGIN of the smallest kick's rise (the model's rise error against the
        closed loop, +2-3 %, docs §80.3), and each candidate apex ``cand`` is reached by the kick whose rise (the
        model's, :meth:`PulseMoves.rise`, inverted by interpolation over the kick set ``tabs`` = [(kick A, rise rad,
        moves [candidate, level])]) is the apex's height above that preload; its moves interpolated linearly in the
        kick between the set's two neighbouring kicks.  A candidate out of the set's range of rises, or whose kick
        would take the command past the current cap (the hold at the preload + the kick), gets NaN moves (never
        chosen).  Returns (kick per candidate A, rise per candidate rad, moves [candidate, level])."""
        cfg, m = self.cfg, self.m
        ks = np.array([t[0] for t in tabs], dtype=float)
        rs = np.array([t[1] for t in tabs], dtype=float)
        pre = floor - d * APEX_PRE_MARGIN * rs[0]
        need = d * (cand - pre)                              # the rise each candidate asks of the kick, rad
        kick = np.interp(need, rs, ks, left=np.nan, right=np.nan)
        # the hold at the preload (the coupling's torque at the gear output, and the motor's Coulomb friction the park
        # climbed against) plus the kick stays within the cap
        hold = (m.coupling_stiffness_nm_per_rad * pre / m.gear_ratio
                + d * m.motor_coulomb_nm) / m.torque_constant_nm_per_a
        kick = np.where(kick <= cfg.peak_current_a - d * hold, kick, np.nan)
        i = np.clip(np.searchsorted(ks, np.nan_to_num(kick, nan=ks[0]), side="right") - 1, 0, len(ks) - 2)
        t = np.clip((np.nan_to_num(kick, nan=ks[0]) - ks[i]) / (ks[i + 1] - ks[i]), 0.0, 1.0)[:, None]
        mvs = np.stack([tb[2] for tb in tabs])               # [kick, candidate, level]
        rows = np.arange(len(cand))
        mv = (1.0 - t) * mvs[i, rows] + t * mvs[i + 1, rows]
        mv = np.where(np.isfinite(kick)[:, None], mv, np.nan)
        return kick, np.where(np.isfinite(kick), need, 0.0), mv

    def _start_sigmas(self, d: int, b: int) -> float:
        """How many learned scatters below the learned breakaway a new staircase starts (its first preload
        lies this far, and the kick's rise, below it): ``fine.doublet_sigmas``, or with ``fine.start_quantile``
        the start learned from the first stairs' outcomes (:meth:`FineLearner.observe_start`) once one was."""
        if self.cfg.start_quantile > 0.0 and self.learn.start[d][b] > 0.0:
            return self.learn.start[d][b]
        return self.cfg.doublet_sigmas

    def _plan_park(self) -> None:
        """Plan the preload from ``_phi_start`` to ``_pre``: quasi-statically (a fast unwind
        would overshoot the servo into breakaway), at ``fine.park_speed_rad_s`` to within
        ``fine.park_approach_rad`` of it, then at ``fine.park_approach_speed_rad_s``.  The servo
        lags the reference by about its rate over its bandwidth, and with the loop delay it
        overshoots the end by a like amount: measured at 0.5 rad/s (nominal box, task h17f) the
        twist went 2.7e-4 rad (median; p90 4.7e-4) beyond the preload -- 4-7 of the doublet's
        staircase steps, so the staircase climbed by the overshoot, not by its steps, and the
        preload itself broke the valve loose for a whole jump; at 0.2 rad/s: -0.5e-4 / 0.5e-4."""
        cfg, per = self.cfg, self.period
        d = 1 if self._pre >= self._phi_start else -1
        dist = abs(self._pre - self._phi_start)
        near = min(cfg.park_approach_rad, dist)
        self._park_mid = self._pre - d * near
        self._park_n1 = max(int((dist - near) / (cfg.park_speed * per)) + 1, 1) if dist > near else 0
        self._park_n2 = max(int(near / (max(cfg.park_approach_speed, 1e-9) * per)) + 1, 1)
        extra = cfg.park_periods - self._park_n1 - self._park_n2
        if extra > 0:
            self._park_n2 += extra
        self._park_n = self._park_n1 + self._park_n2
        self._repark = None
        if cfg.repark_from_state and self._doublet and not self._first_stair:
            self._plan_repark(per)

    def _plan_repark(self, per: float) -> None:
        """(task h29r, ``fine.repark_from_state``, off by default) The fast part of a staircase's next park
        planned from the state the unmoved stair's retreat left, not from rest at the twist it was judged at.  The
        retreat's momentum swings the gear output ~5.7e-3 rad below the preload, and the observe servo (pulling
        toward the move's final twist) already throws it back up at ~2 rad/s when the stair is judged unmoved
        (nominal box, seed 1000: twist 5.4e-3 below the level, rising ~2 rad/s); the park planned from rest at that
        twist started its reference at 0.25 rad/s, the servo braked the rebound 3-4e-3 rad above its reference and
        the reference took 8-9 periods to catch the twist up (§55.1, §61).  Planned here instead: the twist
        reference leaves the measured twist ``x0`` (rad) at the estimated twist rate ``v0`` (rad/s, the backward
        difference extrapolated half a period: the sample's own instant), already in the judging period, and
        arrives at the approach point ``_park_mid`` at the approach rate ``v_app`` -- a cubic, monotonic toward the
        preload for ``T <= 3 Δ / (v0 + v_app)`` (``Δ`` the way to go); a slow rebound gets ``T = 1.5 Δ /
        fine.park_speed_rad_s`` -- then a cubic from there to the preload, arriving at rest over the approach's
        periods (it does not stop at the approach point: the gear output stopped there stuck in its friction and
        jumped 0.3e-3 rad past the preload when the approach pulled it loose).  Sign: rad and rad/s of twist,
        positive toward the preload when ``_dir`` is +1.  Measured (§61): the park 17 -> 15 periods, its
        breakaways 25 -> 10, nominal box plateaus > 8e-4 rad 67 -> 62 / 50 -> 41 (seeds 1000 / 2000), but the
        moved doublets' moves median 0.86 -> 1.05e-3 rad, p95 1.32 -> 1.49e-3 rad on seed 1000 and the worst
        step overshoot 16.6 -> 40.1 %: off by default."""
        d = self._dir
        x0 = self._phi_start
        gap = d * (self._park_mid - x0)
        if gap <= 0.0 or self._park_n1 <= 0:
            return
        w1 = self._w1_now if self._w1_now is not None else 0.0
        w1_prev = self._w1_prev if self._w1_prev is not None else 0.0
        v0 = max(d * (1.5 * w1 - 0.5 * w1_prev), 0.0)
        v_app = min(self.cfg.park_approach_speed, self.cfg.park_speed)
        t_want = 3.0 * gap / max(v0 + v_app, 2.0 * self.cfg.park_speed)
        n1 = max(int(t_want / per), 1)
        t = n1 * per
        self._repark = (x0, d * v0, d * v_app, t)
        # the servo's integral back to the whole static correction (integral and proportional part) that held
        # the preload before the kick: the feed-forward's error there.  The observe servo's pull on the trough
        # (~5e-3 rad for 3-4 periods) wound it ~0.6 A further toward the move; the park from rest unwound that
        # while the twist ran ahead of its reference, but a reference that follows the rebound leaves it wound
        # and the twist settled 0.3-0.8e-3 rad past the preload (seed 1000).  The integral alone restored, the
        # park's end error stayed in the proportional part and the integral drifted ~0.13 A toward the move
        # over a staircase (the park ends 0.9e-4 rad past the preload, median); with it, 0.3e-4 (§61)
        if self._integral_held is not None:
            self._integral = self._integral_held
        self._park_n1 = n1
        self._park_n2 = max(self._park_n2, self.cfg.park_periods - n1)
        self._park_n = self._park_n1 + self._park_n2

    def _park_settled(self, w1: float) -> bool:
        """(``fine.park_settle``, task h37t, docs §96) Whether the parked gear output has settled on the preload: its
        speed ``w1`` (rad/s, the stage's backward difference) is within the stuck-valve drivetrain mode's
        sqrt(K / J1) x the tolerance -- a ringing of at most ``fine.tolerance_counts`` in amplitude.  A kick on a
        park still ringing adds the swing to its apex and to its retreat's trough (full box 1069: +1 rad/s, the
        trough 3-4e-3 rad deeper than the move model's from that state)."""
        m = self.m
        omega = math.sqrt(m.coupling_stiffness_nm_per_rad / max(m.j1, 1e-12))
        return abs(w1) <= omega * self.cfg.tolerance_rad

    def _park_ref(self, k: int) -> tuple[float, float, float]:
        """The preload twist reference in period ``k`` of the park: (rad, rad/s, rad/s²)."""
        per = self.period
        if self._repark is not None:
            return self._repark_ref(k)
        if k <= self._park_n1:
            return self._blend(self._phi_start, self._park_mid, k * per, self._park_n1 * per)
        return self._blend(self._park_mid, self._pre, (k - self._park_n1) * per, self._park_n2 * per)

    @staticmethod
    def _hermite(x0: float, v0: float, x1: float, v1: float, t: float, tau: float) -> tuple[float, float]:
        """Cubic from (x0 rad, v0 rad/s) to (x1, v1) over ``t`` s at time ``tau`` (clipped to [0, t]): (x, a)."""
        s = min(max(tau / t, 0.0), 1.0)
        dx = x1 - x0
        c2 = 3.0 * dx - (2.0 * v0 + v1) * t
        c3 = -2.0 * dx + (v0 + v1) * t
        return x0 + v0 * t * s + c2 * s * s + c3 * s ** 3, (2.0 * c2 + 6.0 * c3 * s) / (t * t) if s < 1.0 else 0.0

    def _repark_ref(self, k: int) -> tuple[float, float, float]:
        """(fine.repark_from_state) The planned re-park's reference in period ``k`` (0: the period it was
        planned in): the cubic from the measured state to the approach point, arriving at the approach rate,
        then the cubic from there to the preload, arriving at rest.  The rate handed to the servo is the plan's
        backward difference over the last period, as the measured rate it is compared with is (in the plan's
        first period the measured rate itself: it starts on the measured state, no feedback)."""
        per = self.period
        x0, v0, v_app, t1 = self._repark
        t2 = self._park_n2 * per

        def at(kk):
            tau = kk * per
            if tau <= t1:
                return self._hermite(x0, v0, self._park_mid, v_app, t1, tau)
            return self._hermite(self._park_mid, v_app, self._pre, 0.0, t2, tau - t1)

        x, a = at(k)
        v = (x - at(k - 1)[0]) / per if k > 0 else self._w1_now
        return x, v, a

    def hold_torque(self, th1: float, thl: float) -> float | None:
        """Motor torque (N*m) that holds the present twist ``th1 - thl`` statically (the engage
        torque plus the nominal coupling-torque change), or ``None`` before the stage engaged.
        The main law restarts from this, not from the torque last applied: that may be a
        pulse's kick or retreat at up to the whole current."""
        if self._last_engage is None:
            return None
        ff0, phi0 = self._last_engage
        m = self.m
        return ff0 + m.coupling_stiffness_nm_per_rad * ((th1 - thl) - phi0) / m.gear_ratio

    def _track_peak(self, phi: float) -> None:
        if self._dir * phi > self._dir * self._peak_seen:
            self._peak_seen = phi
        if self.phase in (PULSE, OBSERVE) and self._dir * phi > self._dir * self._kick_apex:
            self._kick_apex = phi

    def _servo(self, th1_ref, a_ref, th1, w1, thl, v_ref=0.0, integrate=True):
        """Torque holding the gear output on ``th1_ref`` (feed-forward: the engage torque plus
        the nominal coupling-torque change, and J1 a_ref for the pulse).  ``integrate`` False: this
        period's error acts through the integral term but is not kept in it (``fine.observe_hold_*``)."""
        m = self.m
        n = m.gear_ratio
        # coupling torque of the *reference* twist (the valve is stuck until breakaway)
        ff = self._ff0 + m.coupling_stiffness_nm_per_rad * ((th1_ref - thl) - self._phi0) / n
        e = th1_ref - th1
        integral = self._integral + e * self.period
        if integrate:
            self._integral = integral
        torque = ff + (m.j1 * a_ref + self.kp * e + self.kd * (v_ref - w1) + self.ki * integral) / n
        # the pulse's acceleration is what draws the peak current: capped, the pulse is slower,
        # not wrong (the twist it reached is measured and learned from)
        cap = self.cfg.peak_current_a * m.torque_constant_nm_per_a
        self._servo_torque = min(max(torque, -cap), cap)
        # limit-cycle watch: large feedback torques that keep reversing (a leaky count)
        fb = self._servo_torque - ff
        self._osc *= OSC_LEAK
        settled = self.phase == HOLD or (self.phase == OBSERVE and 2 * self._k >= self.cfg.observe_periods)
        if self._pending is not None and self._pending[4] is None:
            # (fine.apex_choice_after_command) the starting period's servo: a hold's verdict counts it (run_pending);
            # the try's PARK, as the pending start's OBSERVE at k = 0, does not
            self._pending = self._pending[:4] + (fb,)
            settled = False
        if settled:
            self._count_reversal(fb, cap)
        return self._servo_torque

    def _count_reversal(self, fb: float, cap: float) -> None:
        """The servo's limit-cycle watch: a feedback torque ``fb`` (N*m) beyond :data:`OSC_TORQUE_FRACTION` of the
        torque cap ``cap`` counts one reversal when its sign flipped since the last such torque."""
        if abs(fb) > OSC_TORQUE_FRACTION * cap:
            sign = 1 if fb > 0 else -1
            if sign == -self._osc_sign:
                self._osc += 1.0
            self._osc_sign = sign

    @staticmethod
    def _blend(x0: float, x1: float, tau: float, length: float) -> tuple[float, float, float]:
        """sin² blend from x0 to x1 over ``length`` s at time ``tau``: (x, v, a)."""
        u = min(max(tau / length, 0.0), 1.0)
        w = math.pi / length
        dx = x1 - x0
        if u >= 1.0:
            return x1, 0.0, 0.0
        return (x0 + dx * 0.5 * (1.0 - math.cos(math.pi * u)), dx * 0.5 * w * math.sin(math.pi * u),
                dx * 0.5 * w * w * math.cos(math.pi * u))

    def _run(self, th1, w1, thl, pressure_kpa):
        cfg, per = self.cfg, self.period
        if self._osc >= OSC_LIMIT:
            # its stiff hold limit-cycles on this plant (a resolver delay, a slow current
            # slew at low supply): shaking the valve is worse than the main law's hold
            self._hand_back(settle=False)
            return None
        self._k += 1
        self._w1_prev, self._w1_now = (w1 if self._w1_now is None else self._w1_now), w1   # (fine.repark_from_state)
        base = self._thl0
        if self.phase == PARK:
            x, v, a = self._park_ref(self._k)
            if self._park_hold and self._k >= self._park_n + 2:
                # (fine.apex_keep_rad) a park to the policy's hold: held at its preload, no kick
                self._park_hold = False
                self.phase = HOLD
                self._hold_ref = base + x
                return self._servo(self._hold_ref, 0.0, th1, w1, thl)
            if self._k >= self._park_n + 2 and (not (cfg.park_settle and self._doublet) or self._park_settled(w1)
                                                 or self._k >= 2 * self._park_n + 2):
                self.phase, self._k = PULSE, 0
                self._kick_apex = th1 - thl       # the kick's apex is tracked from the preload reached
                self._excursion = 0.0
                self._returned = False
            if self._dir * (thl - self._thl0) < -2.0 * cfg.tolerance_rad or (
                    self._anchor is not None and self._dir * (thl - self._anchor[0]) < -2.0 * cfg.tolerance_rad):
                # (h21h) the second reading: from the furthest start toward the target since the
                # stage engaged this way (``_anchor``), not only from this pulse's start -- a valve
                # that creeps away a count or so per pulse is as unfit.  Campaign
                # seed 1195 (LuGre x 2.40 at max Δp, 4.4 N*m load, K x 0.77, 1.6 mrad backlash):
                # 12 pulses over 0.3 s, each starting where the last had let the valve creep, the
                # valve 0.76 mrad further from the target at the end -- 3 reversals of 4.4e-4 rad
                # it slides *away* from the target while the twist moves toward it: the twists
                # the model planned do not hold this valve -- the main law takes it back at once
                return self._hand_back()
            if abs(thl - self._thl0) > 2.0 * cfg.tolerance_rad:
                # broke away while preloading: hold the gear output where it is and judge the
                # move once the valve has stopped (judged mid-swing, the next pulse would start
                # from a valve still moving)
                self.phase, self._k, self._final, self._pulsed = OBSERVE, 0, x, False
                self._break_twist = th1 - thl     # (a cold engagement judges the valve by it)
                self._break_ref = x               # the preload reference when it slid (the twist it held up to)
            return self._servo(base + x, a, th1, w1, thl, v)
        if self.phase == PULSE and self._doublet:
            # torque doublet on the hold torque the park ended with: one period of kick, then
            # the whole current backwards (one period, then half), then the servo to the final
            # twist (SPEC §6: the retreat must already be at full current when the valve breaks;
            # through the 60 Hz servo it is not)
            if self._k == 2 and self._kick_lost():
                if self._kick_retries >= 1:
                    return self._hand_back()       # lost twice in a row: the loop cannot time a pulse now
                self._kick_retries += 1
                self._k = 1                        # the try again from the preload it still holds: this period kicks
            self._track_peak(th1 - thl)
            if self._k == 1:
                self._hold_torque = self._servo_torque
                # (fine.repark_from_state) the servo's whole static correction at the preload it held, its
                # proportional part moved into the integral: the re-park restores it (:meth:`_plan_repark`)
                self._integral_held = self._integral + self.kp * (self._thl0 + self._pre - th1) / self.ki
            self._unmoved_now = abs(thl - self._thl0) < 0.5 * cfg.tolerance_rad
            self._excursion = max(self._excursion, self._dir * (thl - self._thl0))
            torque = self._doublet_torque(pressure_kpa)
            if torque is not None:
                return torque
            self._k = 1                            # (fine.retreat_cap) the observe's first period is this one
        if self.phase == PULSE:
            # shaped pulse of the gear output: rise past breakaway, then fall to the final twist
            t = self._k * per
            t_rise, t_fall = cfg.rise_periods * per * self._time_scale, cfg.fall_periods * per * self._time_scale
            if t < t_rise:
                x, v, a = self._blend(self._pre, self._peak_planned, t, t_rise)
            else:
                x, v, a = self._blend(self._peak_planned, self._final, t - t_rise, t_fall)
            self._track_peak(th1 - thl)
            if t >= t_rise + t_fall:
                self.phase, self._k, self._pulsed = OBSERVE, 0, True
            return self._servo(base + x, a, th1, w1, thl, v)
        if self.phase == OBSERVE:
            self._track_peak(th1 - thl)
            self._excursion = max(self._excursion, self._dir * (thl - self._thl0))
            # a pulse that has not moved the valve a count or two a few periods after its apex
            # did not break it loose (a valve that breaks moves 1.5 counts within ~0.7 ms): a
            # doublet's apex is its kick, a servo-blended pulse's lies its fall time before this
            # phase.  (The servo-blended pulse waited the whole ``fine.observe_time_s`` instead:
            # 27 ms per pulse that did not move the valve, 873 of 1390 on the nominal box, 40 runs,
            # and 14 of its 73 plateaus > 8e-4 rad ended mid-staircase; task h20p.)
            unmoved = self._pulsed and self._k >= cfg.no_move_periods \
                and abs(thl - self._thl0) < 0.5 * cfg.tolerance_rad
            if cfg.retreat_return_guard and self._doublet and self._pulsed and self._excursion >= cfg.tolerance_rad \
                    and self._excursion - self._dir * (thl - self._thl0) >= cfg.tolerance_rad:
                # (task h35v) the valve went a tolerance toward the try and is now a tolerance back from there: the kick
                # broke it loose and the retreat's trough, deeper than this valve's static band, broke it loose the
                # other way (other valves, friction x0.4, campaign seed 1001: the trough's twist 9.3e-3 rad below the
                # preload, at the closing level; +1.25e-3 and back to the start, judged "unmoved" and repeated 10 times
                # -- hunting; seed 1003: +0.5e-3, -2.5e-3, then the observe's rebound +4.4e-3 across the target).
                # Every later doublet on this plant retreats one whole period; this plateau is left as after a move
                # away from the target (the main law takes it, or with fine.hold_reversed / the apex policy the stage
                # holds where a hand-back could be the second reversal)
                self._deep_unfit = True
                if cfg.retreat_return_rest:
                    # the observe's reference frozen at the gear output's present angle (no rebound toward the final
                    # twist), the doublet judged once the valve rests (:meth:`_after_move`)
                    if not self._returned:
                        self._returned = True
                        self._final = th1 - self._thl0
                    unmoved = False
                    if not (self._k >= cfg.observe_periods and self._rest >= 3):
                        return self._servo(self._thl0 + self._final, 0.0, th1, w1, thl)
                    self._after_move(th1, thl, pressure_kpa, pulsed=self._pulsed)
                    if self.phase == IDLE:
                        return None
                    if self.phase == HOLD:
                        return self._servo(self._hold_ref, 0.0, th1, w1, thl)
                    return self._servo(self._thl0 + self._final, 0.0, th1, w1, thl)
                self.pulses_this_plateau += 1
                if cfg.retreat_return_hold:
                    # hold the gear output where it is: the observe servo's pull toward the final twist is what threw
                    # seed 1003's valve back across the target; no more pulses on this plateau
                    self._hold_here(th1, failed=False)
                    return self._servo(self._hold_ref, 0.0, th1, w1, thl)
                if self._hold_not_hand_back(th1, self._target - thl, pressure_kpa):
                    return self._servo(self._hold_ref, 0.0, th1, w1, thl)
                self._hand_back()
                return None
            if unmoved and self._doublet and cfg.unmoved_settled and self._k < cfg.observe_periods \
                    and abs(w1) > cfg.park_approach_speed:
                # (task h35v) the retreat's swing still rebounds: judged now, the next park is planned from rest at
                # a twist the gear output is leaving at up to ~0.65 rad/s after a 16 A kick, and carries that swing
                # 0.36e-3 rad (median; max 1.3e-3) past its preload -- 12 of 120 such parks broke the valve loose a
                # whole jump (docs §86.2).  Judged once the gear output moves no faster than the park's own final
                # approach (fine.park_approach_speed_rad_s), or at the observe window's end
                unmoved = False
            if unmoved or (self._k >= cfg.observe_periods and self._rest >= 3):
                # (fine.apex_choice_after_command) the next try's choice after this period's command, where that
                # command reads nothing of it: not with fine.retreat_stop_unmoved (the preload it sets) or
                # fine.repark_from_state (the re-park takes over in this period)
                self._after_move(th1, thl, pressure_kpa, pulsed=self._pulsed,
                                 after_command=cfg.apex_choice_after_command and not cfg.retreat_stop_unmoved
                                 and not cfg.repark_from_state)
                if self.phase == IDLE or self._handback_wait == 0:
                    return None                   # (fine.handback_settle: :meth:`update` holds the swing from here)
                if self.phase == PARK and self._repark is not None:
                    # (fine.repark_from_state) the planned re-park takes over in this period already: the
                    # observe servo pulling on toward the final twist is what throws the rebound past the plan
                    x, v, a = self._park_ref(0)
                    return self._servo(self._thl0 + x, a, th1, w1, thl, v)
            ref = self._final
            if cfg.retreat_stop_unmoved and self._doublet and self._pulsed \
                    and abs(thl - self._thl0) < 0.5 * cfg.tolerance_rad:
                # (h28r) the valve has not let go (yet): hold the gear output just short of the preload
                # proven to hold, not at the move's final twist -- the retreat's trough (5.7e-3 rad below
                # the preload, §55.1) is what the next stair's slow park has to climb back
                ref = self._pre - self._dir * cfg.park_approach_rad
            if self._doublet and self._pulsed and (cfg.observe_hold_integral or cfg.observe_hold_moved and abs(
                    thl - self._thl0) >= 0.5 * cfg.tolerance_rad):
                # (task h34s) the pull-back from the retreat's trough runs at the cap for 3-4 periods with a position
                # error of up to ~1.6e-2 rad: integrated, it wound the slow integral to ~3.4e-3 rad of equivalent
                # error (main's doublet: 0.6e-3), the gear output overshot the final twist by 2-3e-3 rad and its
                # rebound reached the kick's apex again -- a second breakaway (nominal box, fine.retreat_full_periods
                # 2: 6 of 22 moves).  Held at the park's value, the swing is pulled back by the PD alone.
                # (fine.observe_hold_moved: only once the valve has moved -- held after an unmoved stair too, the next
                # park, tuned with the observe integrating, ended 0.57e-3 rad short of its preload: 12 vs 29 moves)
                return self._servo(base + ref, 0.0, th1, w1, thl, integrate=False)
            return self._servo(base + ref, 0.0, th1, w1, thl)
        # HOLD: keep the gear output where it is (twist inside the static band: the valve stays)
        if self._handback_wait is not None:
            # (fine.handback_settle) a hand-back waiting for the swing it was decided in to die out
            self._handback_wait += 1
            if self._swing_settled(w1, self._handback_wait):
                self._release()
                return None
            return self._servo(self._hold_ref, 0.0, th1, w1, thl)
        if cfg.hold_relax > 0.0:
            return self._hold_relaxing(th1, w1, thl, pressure_kpa)
        return self._servo(self._hold_ref, 0.0, th1, w1, thl)

    def _hold_relaxing(self, th1: float, w1: float, thl: float, pressure_kpa: float) -> float:
        """(``fine.hold_relax``, task h39h, docs §101) The hold's torque while the stage moves the held twist
        ``fine.hold_relax`` of the way to the static band's middle (the mean of the two learned breakaway twists at this
        angle and Δp, the load included) over ``fine.hold_relax_time_s`` (a sin² blend), then holds there.  Why: a hold
        is entered where the last try stopped -- after a doublet, on the side of the band it pushed, next to that way's
        breakaway (`startup` seed 0, C2: 2.8e-3 rad of twist short of the opening breakaway, the band ~2.2e-2 wide).
        The next demand's move that way then breaks the valve loose at once and its stick-slip jump (5.7e-3) ran past a
        5.2e-3 step (14.6 %); from the middle every later move winds half a band first, either way alike.  The
        middle lies inside both breakaways, and the move goes away from the near one, so the valve stays; should it
        move anyway (more than half a tolerance: a band learned wrong), the blend stops and the gear output is held
        where its reference was.  A new hold (a new ``_hold_ref``) plans a new relaxation."""
        cfg = self.cfg
        rel = self._relax
        if rel is None or rel[0] != self._hold_ref:
            mid = 0.5 * (self._twists(thl, pressure_kpa, 1)[1] + self._twists(thl, pressure_kpa, -1)[1])
            twist = self._hold_ref - thl
            rel = self._relax = [self._hold_ref, self._hold_ref + cfg.hold_relax * (mid - twist), 0, thl, None]
        th1_0, th1_1, k, thl0, stop = rel
        if stop is not None:
            return self._servo(stop, 0.0, th1, w1, thl)
        k += 1
        rel[2] = k
        n = max(cfg.hold_relax_periods, 1)
        x, v, a = self._blend(th1_0, th1_1, k * self.period, n * self.period)
        if abs(thl - thl0) > 0.5 * cfg.tolerance_rad or k >= n:
            rel[4] = x if k < n else th1_1         # the valve moved: held where the reference is; or the blend is done
            return self._servo(rel[4], 0.0, th1, w1, thl)
        return self._servo(x, a, th1, w1, thl, v)

    def _servo_stuck(self, err: float, d: int, pressure_kpa: float) -> bool:
        """(``fine.servo_unmoved_doublet``, task h42s, docs §112) Whether the next pulse toward ``d`` is a doublet
        because ``fine.servo_unmoved_doublet`` servo-blended pulses toward ``d`` have not moved the valve at this
        stop, and |err| is within ``fine.servo_unmoved_doublet_jumps`` nominal stick-slip jumps at ``pressure_kpa``
        (a doublet's move is about one jump; a larger error is the servo-blended pulse's).  Why: a servo-blended
        pulse's reach is its servo's; at a stop whose level was drawn high its apex stops short of its plan (nominal 2026 #5: the planned apex climbed 5e-3
        rad of twist past the first in 19 pulses, the reached one 2.8e-3 and then stayed), each unmoved pulse
        raises the learned level one probe step more, and the pulse that lets go throws the valve a whole jump."""
        n = self.cfg.servo_unmoved_doublet
        if n <= 0 or self._servo_unmoved[0] != d or self._servo_unmoved[1] < n:
            return False
        jump = self.m.friction(pressure_kpa).stick_slip_jump_rad(self.m.coupling_stiffness_nm_per_rad)
        return abs(err) <= self.cfg.servo_unmoved_doublet_jumps * jump

    def _doublet_jump_range(self, pressure_kpa: float) -> float:
        """Errors up to this (rad) may get a doublet besides ``fine.doublet_max_error_rad``:
        ``fine.doublet_jump_fraction`` x the nominal stick-slip jump at ``pressure_kpa`` (0: none).
        On a soft coupling (K 200, jump 1.1e-2 rad) the main law stops ~half a jump short, where the
        servo-blended pulse's preloads broke the valve loose a whole jump across (task h23s)."""
        f = self.cfg.doublet_jump_fraction
        return f * self.m.friction(pressure_kpa).stick_slip_jump_rad(self.m.coupling_stiffness_nm_per_rad) if f > 0.0 else 0.0

    def _kick_rise(self) -> float:
        """The twist (rad, >= 0) the doublet's kick raises above its preload, as the preload is planned
        below the apex: ``fine.kick_rise_rad``, or with ``fine.learn_kick_rise`` the mean rise the stage's
        own unmoved doublets reached above their planned preload once one was seen.  (Nominal box, task
        h22f: every unmoved doublet's kick of 4 A rose 0.28-0.30e-3 rad above its preload, where 0.15e-3 is
        planned -- each apex lay ~0.13e-3 above the stair the plan put it on.  Learned, the whole staircase
        lies that much lower; measured no better (121 / 124 vs 144 / 116 plateaus > 5e-4 rad on seeds 1000 /
        2000, p95 1.85e-3 vs 1.32e-3 rad on seed 1000; the first stairs that let the valve go while the kick
        still raised the twist 9 vs 6 on the 80 runs): off by default.)"""
        cfg = self.cfg
        first = self._first_stair and cfg.first_kick_fraction != 1.0   # its own kick: its own rise
        seen = self._rise_seen[1 if first else 0]
        if cfg.learn_kick_rise and seen > 0.0:
            return seen
        return cfg.kick_rise_rad * (cfg.first_kick_fraction if first else 1.0)

    def _retreat_plan(self, pressure_kpa: float | None, kick: float, periods: int) -> tuple[int, float]:
        """(``fine.retreat_trough_bound``, task h36g, docs §90) The doublet's retreat, decided in its kick period:
        (whole periods, scale) -- each period's command moved ``scale`` of the way from the hold torque to the
        retreat's (1: the planned retreat).  The deep retreat's trough (two periods at the 30 A cap, docs §84) lies
        7-17e-3 rad of twist below the preload: at max Δp the nominal valve's static band (2 T_s / K, ~23e-3 rad) holds
        it, but at low Δp, on low friction or a stiff coupling (full box 1069, Δp 0.98 MPa: band ~5.4e-3 nominal; other
        valves' slippery, stiff_coupling) it passes the other way's breakaway and the valve breaks loose backwards
        (docs §88.4b, §89).  The trough is predicted by the move model on a valve that stays stuck
        (:meth:`PulseMoves.trough`) from the doublet's actual start -- the twist, the gear output's speed and the hold
        torque of this period (a park still ringing adds its swing to the retreat's) -- and must stay above the other
        way's learned breakaway twist by ``fine.doublet_sigmas`` of its learned scatter (the staircase's own margin
        against a park break).  The deepest of: the planned periods, fewer whole periods, one period scaled toward
        the hold (linear between TROUGH_SCALES points); none: one period at the hold (scale 0)."""
        cfg, d = self.cfg, self._dir
        if not cfg.retreat_trough_bound or pressure_kpa is None or self._last_th1 is None:
            return periods, 1.0
        step = APEX_DP_STEP * self.m.pressure_max_kpa
        p = round(pressure_kpa / step) * step
        thl = self._last_valve
        pre = self._last_th1 - thl                   # the twist the kick starts from (rad)
        phi_eo, phi_bo, band = self._twists(thl, p, -d)
        margin = cfg.doublet_sigmas * self._scatter(-d, band, max(abs(phi_bo - phi_eo), 1e-5))
        if cfg.retreat_trough_misfit and not math.isinf(cfg.breakaway_fit):
            # the stage engages on a valve whose breakaway lies up to fine.breakaway_fit x T_s/K off the model's: the
            # other way's level, not learned at this stop, may lie that much nearer (full box 1069, K x0.91 untold:
            # the true closing level 1.5e-3 rad above the learned one)
            m = self.m
            margin += cfg.breakaway_fit * m.friction(p).valve_static_nm / m.coupling_stiffness_nm_per_rad
        room = d * (pre - phi_bo) - margin           # rad of twist the trough may lie below the start
        if self._cold and cfg.cold_climb:
            # (fine.cold_climb, task s33) before any breakaway the other way's level is the told one only if the
            # valve is the told one: a valve of friction x0.6 broke loose backwards in the trough of the climb's
            # first try from its rest twist (its static band 0.6 x as wide), and the observe servo's pull back then
            # threw it 1.1e-2 rad forwards.  The least level the valve is known to have (:meth:`_cold_static_min`),
            # mirrored about the load's twist, bounds the trough instead
            room = d * (pre - self._load_twist(thl, p)) + self._cold_static_min(d, thl, p) - margin
        if self._moves is None:
            self._moves = _pulse_moves(self)
        mv = self._moves
        # the kick's actual start (the park may still ring: 1069's ran +1 rad/s into the kick) and the stage's own
        # observe servo (its feed-forward's engage offset and integral, its final twist)
        kn = self.m.coupling_stiffness_nm_per_rad / self.m.gear_ratio
        state = dict(kick_current_a=kick, valve_angle_rad=thl, speed0=self._w1_now, hold0=self._hold_torque,
                     servo_offset=self._ff0 - kn * self._phi0 + self.ki * self._integral / self.m.gear_ratio,
                     ref_twist=self._final, servo_delay_s=min(max(cfg.trough_delay_s, 0.0), self.period))
        # (task h40s, docs §105) the move model's trough in floats (PulseMoves.trough_fast: the same equations and bits
        # as PulseMoves.trough, ~13x less CPU on one lane), one lane at a time: the whole periods first, then one period
        # scaled toward the hold (scaled_retreat's bisection, docs §111)
        for n in range(periods, 1, -1):
            if d * (pre - float(mv.trough_fast(d, p, pre, retreat_periods=n, **state)[0])) <= room:
                return n, 1.0
        scales = np.linspace(1.0, 0.0, TROUGH_SCALES)

        def depth(j: int) -> float:
            """The trough's depth below the start (rad of twist, toward -d) of one period at ``scales[j]``."""
            return d * (pre - float(mv.trough_fast(d, p, pre, retreat_periods=1, retreat_scale=float(scales[j]),
                                                   **state)[0]))

        return 1, scaled_retreat(depth, room, scales)

    def _settle_retreat(self) -> tuple[int, float]:
        """The doublet in progress' retreat (whole periods, scale; :meth:`_retreat_plan`), planned now if its kick
        period left it for after the command (``fine.retreat_plan_after_command``): from the state that period
        ended with -- nothing between that command and the next period's start changes what the plan reads, so
        offline (the next :meth:`update` runs it first) and in the node (``ValveDriver.after_period``) the plan and
        every command are those of the inline plan, to the bit."""
        pending, self._retreat_pending = self._retreat_pending, None
        if pending is not None:
            pressure_kpa, kick, periods = pending
            cfg = self.cfg
            self._retreat = self._retreat_plan(pressure_kpa, kick, periods)
            if (cfg.apex_probe_hold and cfg.apex_policy and self._retreat != (periods, 1.0)
                    and self._apex_try is not None and self._apex_plan is not None
                    and self._apex_plan[2] >= 1.0 - float(_norm_cdf(-cfg.doublet_sigmas))):
                # (task h37t, docs §96) where fine.retreat_trough_bound has cut the planned retreat, a try the policy
                # expects not to move the valve (P(no move) within main's park-break chance of 1) has no move for the
                # retreat to stop: one period at the hold, then the observe servo -- the model's one-period troughs
                # read 3.3-4.2e-3 rad shallow on run 1069 (#7: P(no move) 1.000); for every try (the bound not
                # consulted) nominal seed 1000 went worse (p95 0.989 -> 1.244e-3: the rise tables assume the deep
                # retreat, the apex overshoots its plan)
                self._retreat = (1, 0.0)
        return self._retreat

    def _doublet_torque(self, pressure_kpa: float | None = None) -> float:
        """The doublet's torque in its period ``_k`` (1: kick; then ``fine.retreat_full_periods`` of the
        whole current backwards and one of half of it), N*m.  The valve lets go at the end of the first
        retreat period (nominal box, task h22m: 2.9-3.4 ms after the doublet's start, the twist's apex at
        3.4 ms), so the half period is what pulls while it slides; on the bare plant a second whole
        period cuts the smallest move 0.74 -> 0.68e-3 rad (1.29 -> 1.15e-3 at a static level x1.07), but in
        closed loop (``fine.retreat_full_periods`` 2) the servo pulling the deeper swing back broke valves
        loose for whole jumps (moves p90 1.5 -> 4.9e-3 rad): nominal box 139 vs 67 plateaus > 8e-4 rad."""
        cfg, d = self.cfg, self._dir
        kt = self.m.torque_constant_nm_per_a
        cap = cfg.peak_current_a * kt
        if self._k == 1:
            # (a first stair's kick may be smaller: ``fine.first_kick_fraction``)
            kick = cfg.kick_current_a * (cfg.first_kick_fraction if self._first_stair else 1.0)
            if cfg.apex_policy and self._apex_kick is not None:
                kick = self._apex_kick             # (task h33p) the kick the policy chose for this try
            torque = self._hold_torque + d * kick * kt
            # (fine.kick_lost_fraction) the gear output's second difference this kick alone makes by the next sample:
            # its torque over the motor inertia (reflected), for one period (the cap as the drive applies it)
            self._kick_expected = 0.5 * self.period ** 2 * d * (min(max(torque, -cap), cap) - self._hold_torque) \
                * self.m.gear_ratio / self.m.j1       # (> 0: in the kick's direction)
            # (fine.retreat_return_guard: one whole period once a doublet's valve came back on this plant)
            periods = 1 if self._deep_unfit else max(
                cfg.apex_retreat_periods if cfg.apex_policy and cfg.apex_retreat_periods > 0
                else cfg.retreat_full_periods, 1)
            # (fine.retreat_trough_bound) fewer / scaled periods where the trough would break the valve loose
            # backwards: the plan (0.3-1.2 ms of CPU, docs §108.5) sets nothing this period's command reads, so with
            # fine.retreat_plan_after_command it runs after the kick has gone out (:meth:`run_pending`)
            self._retreat, self._retreat_pending = None, (pressure_kpa, kick, periods)
            if not (cfg.retreat_plan_after_command and cfg.retreat_trough_bound):
                self._settle_retreat()
            # (fine.pulse_fallback) the next period's retreat, planned or (its plan left for after the command:
            # run_pending sets the planned one) whole; then the band middle (:meth:`update`)
            self.fallback_nm = (self._retreat_torque(self._retreat or (periods, 1.0)),)
        elif self._k <= 1 + self._settle_retreat()[0]:
            torque = self._retreat_torque(self._retreat)
            if self._k < 1 + self._retreat[0]:
                self.fallback_nm = (torque,)          # another whole retreat period follows
            elif not (cfg.retreat_cap and not cfg.retreat_cap_half):
                self.fallback_nm = (self._retreat_half_torque(),)
            # (after the last: the band middle alone, :meth:`update`)
        elif cfg.retreat_cap and not cfg.retreat_cap_half:
            # ... and no half period: the observe servo takes this period (None: :meth:`_run` runs it)
            self.phase, self._k, self._pulsed = OBSERVE, 0, True
            return None
        else:
            torque = self._retreat_half_torque()
            self.phase, self._k, self._pulsed = OBSERVE, 0, True
        return min(max(torque, -cap), cap)

    def _kick_lost(self) -> bool:
        """(``fine.kick_lost_fraction``) Whether the kick commanded last period did not reach the drive: the gear
        output's second difference over the park's last, the kick's and this sample (rad, motor resolver / N: the
        change of the per-period speeds ``_w1_prev`` -> ``_w1_now`` times the period), in the kick's direction, is
        below the fraction of the one the kick's torque alone makes (:meth:`_doublet_torque`).
        Why: in real time a command can miss the drive's tick (docs §113: a transit stall the controller does not
        see); the drive then holds the band middle, and the retreat that follows on time, with no kick before it,
        swings the twist below the closing breakaway -- stall seed 89 of the start-up profile: the valve thrown 4.7e-3
        rad back, then 5.7e-3 across the target by the observe servo's pull (54 % overshoot).  A kick of 4-30 A makes
        0.2-1.4e-3 rad here; the motor resolver reads it to ~2e-6 rad.  A kick seen counts the retries down."""
        frac = self.cfg.kick_lost_fraction
        # (a kick the cap left almost nothing of -- a hold already near the cap -- is no reading: below
        # KICK_SEEN_MIN_COUNTS motor-resolver counts the ratio would be resolver noise)
        if frac <= 0.0 or self._w1_prev is None \
                or self._kick_expected < KICK_SEEN_MIN_COUNTS * RESOLVER_COUNT_RAD / self.m.gear_ratio:
            return False
        seen = self._dir * (self._w1_now - self._w1_prev) * self.period / self._kick_expected
        if seen >= frac:
            self._kick_retries = 0
            return False
        self.kicks_lost += 1
        return True

    def _retreat_torque(self, retreat: tuple[int, float]) -> float:
        """A whole retreat period's torque (N*m) under the plan ``retreat`` (periods, scale; :meth:`_retreat_plan`)."""
        cfg, d = self.cfg, self._dir
        cap = cfg.peak_current_a * self.m.torque_constant_nm_per_a
        # (task h34s, ``fine.retreat_cap``) the cap itself backwards, not the hold less the cap (an opening
        # pulse at 0.5 rad, max Δp, holds ~+10.6 A: hold - cap is -19.4 A; plateau_floor's deep shape, §82)
        torque = -d * cap if cfg.retreat_cap else self._hold_torque - d * cap
        if retreat[1] != 1.0:
            torque = self._hold_torque + retreat[1] * (torque - self._hold_torque)
        return min(max(torque, -cap), cap)

    def _retreat_half_torque(self) -> float:
        """The retreat's closing half period (N*m; h28r, ``fine.retreat_unmoved_fraction``: a valve not yet moved by
        now may get less of it)."""
        cfg = self.cfg
        cap = cfg.peak_current_a * self.m.torque_constant_nm_per_a
        frac = cfg.retreat_unmoved_fraction if self._unmoved_now else 0.5
        return min(max(self._hold_torque - self._dir * frac * cap, -cap), cap)

    def _band_middle_torque(self, pressure_kpa: float | None) -> float | None:
        """(``fine.pulse_fallback``) The motor torque holding the valve at its last measured angle against the known
        load (spring, Δp; no friction): the middle of the static band, where a held valve stays and a sliding one is
        braked by its whole Coulomb friction -- what the drive applies after a doublet's last retreat period when
        the next command is late.  None without a Δp."""
        if pressure_kpa is None or self._last_valve is None:
            return None
        c = self._middle
        # (the model by identity: a dataclass == compares every field, every period the stage commands)
        if c is None or c[0] is not self.m or c[1] != pressure_kpa or abs(c[2] - self._last_valve) > MIDDLE_REUSE_RAD:
            c = self._middle = (self.m, pressure_kpa, self._last_valve,
                                self.m.equilibrium(self._last_valve, pressure_kpa)[1])
        return c[3]

    def _spent(self) -> bool:
        """The plateau's pulses are used up (a doublet that did not move the valve does not count),
        or the valve has crossed the target so often that the moves the stage can make are
        evidently larger than the error left (pulsing on would be hunting), or the valve has shown
        on this plateau that the model does not fit it (a hand-back, or a doublet staircase that
        climbed beyond any plausible breakaway)."""
        return (self.pulses_this_plateau >= self.cfg.max_pulses or self.crossings_this_plateau >= self.cfg.max_crossings
                or self._unfit or self._climbed_out)

    def _twist_fits(self, phi: float, thl: float, pressure_kpa: float) -> bool:
        """Whether a valve held at rest by the twist ``phi`` (rad) fits the nominal model: a stuck
        valve's twist lies inside its static band ``(load(θ) ± T_s(Δp)) / K``; beyond the nominal
        band (widened by ``fine.fit_margin`` x T_s/K for the breakaway scatter and ripple) the
        valve carries a load the model does not know, its coupling is softer, its friction
        higher or its Δp reading wrong -- every twist the stage would plan from the model is then
        off by more than the band it aims into, and the main law's integral hold does better."""
        m = self.m
        k = m.coupling_stiffness_nm_per_rad
        static = m.friction(pressure_kpa).valve_static_nm / k
        centre = m.load_torque(thl, pressure_kpa) / k
        return abs(phi - centre) <= static * (1.0 + self.cfg.fit_margin)

    def _rests_beyond_breakaway(self, phi: float, thl: float, pressure_kpa: float, direction: int) -> bool:
        """Whether a valve held at rest by the twist ``phi`` (rad) already lies beyond the breakaway
        twist the stage would plan for a move in ``direction`` (nominal plus learned), by more than
        ``fine.doublet_sigmas`` learned scatters of it: its breakaway is then higher than planned,
        the preload would unwind the twist holding it and the pulses never reach it.  Campaign seed
        1071 (LuGre friction x2.2, Δp reading missing, K x0.73; h18g, task h19x): engaged at rest
        ~2e-3 rad of twist past the planned breakaway, 9-13 pulses that never moved the valve, then
        handed back to a main law that hunted on the final hold.  Such a plateau is left to the
        main law's hold.  (Branch h18g, which plans from learned twists, has the same test on
        them.)"""
        phi_e, phi_b, band = self._twists(thl, pressure_kpa, direction)
        sigma = self._scatter(direction, band, max(direction * (phi_b - phi_e), 1e-5))
        return direction * (phi - phi_b) > self.cfg.doublet_sigmas * sigma

    def _nominal_gap(self, thl: float, pressure_kpa: float, direction: int) -> float:
        """The nominal static band (T_s - T_c(Δp)) / K above the swing centre, rad."""
        e0, b0 = self._nominal(thl, pressure_kpa, direction)
        return abs(b0 - e0)

    def _fitting_stair(self, err: float, pressure_kpa: float, gap0: float) -> float:
        """The next stair's climb (rad of twist) after a doublet that did not move the valve, for the
        error ``err`` (rad, target - valve).  The level lies somewhere within the stair above the last
        apex, so the doublet that breaks the valve loose does so at an overdrive of up to a stair and
        moves it up to the smallest move ``m`` (learned, else the prior) plus
        ``fine.move_per_overdrive`` x the stair (benchmarks/fine_doublet.py: ~4 rad/rad).  The stair is
        the largest whose worst move still leaves at most half the error (a move up to 1.5 |err|;
        up to |err| where the move must not cross the target, :meth:`_cross_guard`), at least
        ``fine.doublet_probe_step`` x the band (the floor: where the smallest move itself, ~0.6-1e-3
        rad, leaves no room) and at most ``fine.kick_rise_rad`` -- the preload stays below the apex the
        last stair reached and did not break the valve loose (a preload above it would at times break
        it for a whole stick-slip jump).  Without the slope (``fine.move_per_overdrive`` 0, the
        default) every stair is the floor.  Errors near ``fine.doublet_max_error_rad`` -- where the
        staircases that outlast their plateau end, 0.85-1e-3 rad off -- then climb in stairs up to
        ~2x the floor.  Measured (task h21n, nominal box): plateaus > 8e-4 rad 66 / 50 / 187 ->
        57 / 41 / 157 on seeds 1000 / 2000 / 5000 (40 / 40 / 120 runs), but p95 on seeds 1000
        1.46 -> 1.85e-3 rad (the larger stairs' larger moves); the worst move allowed up to 2 |err|
        (the stopping rule's test) measured worse (67 / 56 / 172)."""
        cfg = self.cfg
        floor = cfg.doublet_probe_step * gap0
        if cfg.move_per_overdrive <= 0.0:
            return floor
        d = 1 if err > 0 else -1
        m = self._smallest_move(d, pressure_kpa)
        room = (1.0 if self._cross_guard(err, pressure_kpa) else 1.5) * abs(err) - m
        return min(max(room / cfg.move_per_overdrive, floor), max(cfg.kick_rise_rad, floor))

    def _grown_stair(self, err: float, pressure_kpa: float, gap0: float) -> float:
        """(``fine.stair_growth_after`` = N > 0; task h32e, docs §77) The next stair's climb (rad of twist) after the
        n-th unmoved doublet of this staircase: the stair :meth:`_fitting_stair` gives, until n > N; then
        ``floor`` x n / N, where ``floor`` is ``fine.doublet_probe_step`` x the band -- it grows with the stairs
        already climbed.  Why the count: the staircase starts ``fine.doublet_sigmas`` learned scatters below the
        learned level, and the stairs a staircase needs (nominal box, h32d §76.1: median 6, p90 19, max 39) put the
        level this stop drew ~1.3 scatters below the learned one at the median; a staircase N ~ 12 stairs up is in
        that distribution's tail, where the level lies above the learned one by an amount its scatter does not
        describe (the learned Gaussian's mean excess above the apex, ``σ (λ(z) - z)``, shrinks there: it cannot
        size the step).  The growth is bounded as ``fine.move_per_overdrive`` (§28.3) bounds a stair: the level lies
        anywhere within the stair above the last apex, so the doublet that lets go does so at an overdrive of up
        to the stair and moves the valve up to the smallest move plus the slope (``fine.move_per_overdrive``,
        else ``fine.stair_growth_slope``) x the stair -- at most 1.5 |err| (|err| where the move must not
        cross); and never above ``fine.kick_rise_rad``: the next preload stays below the apex this stair reached
        and did not break the valve loose.  Never below the fixed stair."""
        cfg = self.cfg
        base = self._fitting_stair(err, pressure_kpa, gap0)
        n, big_n = self._stairs_unmoved, cfg.stair_growth_after
        if n <= big_n:
            return base
        floor = cfg.doublet_probe_step * gap0
        d = 1 if err > 0 else -1
        slope = cfg.move_per_overdrive if cfg.move_per_overdrive > 0.0 else cfg.stair_growth_slope
        room = (1.0 if self._cross_guard(err, pressure_kpa) else 1.5) * abs(err) - self._smallest_move(d, pressure_kpa)
        cap = min(room / max(slope, 1e-9), cfg.kick_rise_rad)
        return max(base, min(floor * n / big_n, cap))

    def _smallest_move(self, d: int, pressure_kpa: float) -> float:
        """The smallest move (rad, > 0 unless the jump is 0) a doublet makes toward ``d`` (+1 open,
        -1 close) at this Δp: the one learned in its direction and Δp band, else
        ``fine.min_move_prior`` x the nominal stick-slip jump ``2 (T_s - T_c(Δp)) / K``."""
        m = self.learn.min_move[d][self.learn.band(self.m.pressure_fraction(pressure_kpa))]
        if m <= 0.0:
            m = self.cfg.min_move_prior * self.m.friction(pressure_kpa).stick_slip_jump_rad(
                self.m.coupling_stiffness_nm_per_rad)
        return m

    def _below_min_move(self, err: float, pressure_kpa: float) -> bool:
        """Whether the error is so small against the smallest move pulses have made that a
        pulse would most likely leave the valve further from the target (a move ``m`` improves
        an error ``e`` only if ``m < 2|e|``).  Before any doublet has moved the valve in this
        direction and Δp band, ``fine.min_move_prior`` x the nominal stick-slip jump
        ``2 (T_s - T_c(Δp)) / K`` (task h17f: without a prior a doublet for an error of 3.4e-4 rad,
        just outside the tolerance, broke a nominal-box valve loose for a whole jump, seed 2001)."""
        m = self._smallest_move(1 if err > 0 else -1, pressure_kpa)
        return m > 0.0 and abs(err) < self.cfg.min_move_fraction * m

    def _level_outgrows_error(self, err: float, pressure_kpa: float, learned_b: float) -> bool:
        """Whether a doublet staircase that has climbed this far should stop: the level lies above
        the apex the last stair reached without breaking the valve loose (``_peak_seen``, rad of
        twist), and a valve that breaks loose at a higher level swings further -- the doublet does not
        size its move, the level the plant drew at the last stop does.  Measured (task h22m, nominal
        box, seeds 1000-1039, the plant's true level read per doublet): the 112 doublets that moved
        the valve broke it loose at a true overdrive of -1e-5..5e-5 rad (p10-p90: no share of the
        spread), and their moves, 0.58-1.4e-3 rad, follow the true static excess (level less the
        Coulomb twist, 1.6-2.7e-3 rad) at 0.64 rad/rad (r^2 0.70; residual rms 0.19e-3 rad).  The
        move expected at a level at least the apex is the learned smallest move (the doublets' mean)
        plus ``fine.move_per_level`` x how far that apex lies above the learned breakaway
        ``learned_b`` (rad of twist; never less than the learned move); when it exceeds
        1 / ``fine.min_move_fraction`` x the error (twice it: the move would not improve it) the
        staircase stops and the stage holds.  Off (``fine.move_per_level`` 0, the default): never."""
        cfg = self.cfg
        if cfg.move_per_level <= 0.0:
            return False
        d = 1 if err > 0 else -1
        m = self._smallest_move(d, pressure_kpa)
        expected = m + cfg.move_per_level * max(d * (self._peak_seen - learned_b), 0.0)
        return abs(err) < cfg.min_move_fraction * expected

    def _after_move(self, th1, thl, pressure_kpa, pulsed: bool, after_command: bool = False):
        cfg, d, b = self.cfg, self._dir, self._band
        move = thl - self._thl0
        if cfg.retreat_return_rest and self._returned and pulsed and self._doublet:
            self._returned = False
            if abs(move) <= 0.5 * cfg.tolerance_rad:
                # (task h35v) there and back to its start: counted, the plateau held (the same try would repeat it)
                self.pulses_this_plateau += 1
                self.learn.pulses += 1
                self._judge(failed=False)
                self.phase = HOLD
                self._hold_ref = th1
                return
        if not (pulsed and self._doublet and abs(move) <= 0.5 * cfg.tolerance_rad):
            # a doublet that did not move the valve is a stair of its staircase, not a move: the
            # staircase is bounded by its climb instead (below).  Counted, they used up
            # ``fine.max_pulses`` before the staircase had reached the learned breakaway on
            # valves whose learned scatter is ~1e-3 rad (2 scatters at 0.07e-3 per stair: ~29
            # stairs), even on the 4 s final hold (nominal box, 40 runs, seeds 2000-2039: 5 such
            # plateaus ended 0.9-1e-3 rad off, 25 doublets that never moved the valve; task h20p)
            self.pulses_this_plateau += 1
        self.learn.pulses += 1
        e0, b0 = self._nominal(self._thl0, pressure_kpa, d)
        gap0 = abs(b0 - e0)
        curb = self.learn.breakaway[d][b]
        if cfg.start_quantile > 0.0 and self._doublet and self._first_stair and not self._cold \
                and (pulsed or abs(move) > 0.5 * cfg.tolerance_rad):
            # (task h29q) the first stair's outcome is a censored sample of the level this stop drew: below
            # its apex (broke loose in the kick or the preload) or above it.  The learned mean is not biased
            # (nominal box, the plant's true level at each first stair: median 1.7e-5 rad above the learned
            # one), but the start, fine.doublet_sigmas scatters below it, is where the staircase's time goes
            self.learn.observe_start(d, b, abs(move) > 0.5 * cfg.tolerance_rad, cfg.start_quantile,
                                     cfg.start_step_sigmas, cfg.doublet_sigmas)
        below = self._safe                     # (fine.unbiased_samples) the stop's furthest unmoved apex, if any
        if pulsed and not self._doublet and abs(move) <= 0.5 * cfg.tolerance_rad:
            # (fine.servo_unmoved_doublet) one more unmoved servo-blended pulse toward d at this stop
            n0 = self._servo_unmoved[1] if self._servo_unmoved[0] == d else 0
            self._servo_unmoved = (d, n0 + 1)
        if abs(move) > 0.5 * cfg.tolerance_rad:
            self._stair = None                 # a new stop: a new breakaway level
            self._servo_unmoved = (0, 0)
            floor, self._apex_floor = self._apex_floor, None
            if cfg.unbiased_samples:
                self._pushes[(d, b)] = 0.0     # (h30u) a new stop: the climb was this stop's (its bound is learned)
            elif not self._doublet:
                self._pushes[(d, b)] = (1.0 - MOVE_GAIN) * self._pushes.get((d, b), 0.0)
            self._safe = None
            self._early_breaks += 0 if pulsed else 1
            if self._cold:
                # the first breakaway of a cold engagement is the evidence the main law's would have
                # been: the twist it broke loose at (a doublet's apex; in the preload, the twist where
                # the slide was seen -- not the planned preload: a x0.54-friction valve broke loose
                # 1e-2 rad of twist below it, and judged by it as fitting, a second preload broke it
                # back, the metric's second reversal: full box seed 1032)
                phi = self._peak_seen if pulsed else self._break_twist
                self._cold = False
                self._breakaway_seen = (d, phi, self._thl0, pressure_kpa)
                self._fresh = True
                if not pulsed or not self._breakaway_fits():     # judged as the main law's, just recorded
                    # (a breakaway in the preload of a cold staircase, which starts 2 prior scatters
                    # below the nominal breakaway, says the level lies lower than the model puts it
                    # -- seed 1032 broke loose 0.29 T_s/K below, inside the fit -- and another preload
                    # would break it loose again, back across the target: the main law takes it)
                    self._hand_back()
                    return
        if d * move > 0.5 * cfg.tolerance_rad:
            if pulsed:
                # it swung about φe from the twist it was left at: φe = φ_final - move / 2
                phi_e = (th1 - self._thl0) - move / 2.0
                cur = self.learn.equilibrium[d][b]
                self.learn.set("equilibrium", d, b, cur + cfg.learn_gain * ((phi_e - e0) - cur))
            if self._doublet and not (self._restair is not None and not pulsed):
                # (h30b: a restaircase's preload that breaks loose is no sample: it was planned below where the level
                # had already broken, and taken in it doubled the learned scatter for the later stops -- 2018: 0.32 ->
                # 0.94e-3 rad)
                # a sample of the level drawn at the last stop: within one stair step below the
                # apex that broke it loose (the apex before did not), or below the preload it
                # broke loose at (the staircase started too close: the scatter grows)
                half_step = 0.5 * (self._stair_step or cfg.doublet_probe_step * gap0)
                if cfg.apex_policy and not self._cold:
                    # (task h33p) the policy's apexes overdrive the level by up to its law's width: the level lay
                    # between this stop's highest unmoved apex (if any) and the twist the valve let go at (the apex
                    # seen plus the let-go offset; in the preload: the preload) -- a censored sample, not the apex
                    # less half a stair
                    lo = d * (floor[1] - b0) if floor is not None and floor[0] == d else -math.inf
                    hi = d * ((self._peak_seen + d * self._let_go_offset() if pulsed else self._pre) - b0)
                    self._learn_interval(d, b, lo, hi, gap0)
                elif cfg.unbiased_samples and pulsed:
                    # (task h30u) the kick let it go: the level lies at the apex plus the let-go offset
                    # (:meth:`_let_go_offset`), not half a stair below it -- there every moved doublet's
                    # sample lay 1.3e-4 rad below the plant's true level (nominal box, h29q)
                    self._learn_breakaway(d, b, self._peak_seen + d * self._let_go_offset() - b0, gap0)
                elif cfg.unbiased_samples:
                    # it broke loose in the preload: the level lay below it (a censored sample)
                    self._learn_interval(d, b, -math.inf, d * (self._pre - b0), gap0)
                else:
                    self._learn_breakaway(d, b, (self._peak_seen if pulsed else self._pre) - d * half_step - b0,
                                          gap0)
            elif cfg.unbiased_samples:
                # (task h30u) a servo-blended pulse's move bounds the level: below the twist it let go at
                # (the apex plus the let-go offset, or the preload it broke loose in), above the furthest
                # apex an unmoved pulse reached at this stop -- a censored sample, not a pull to the apex
                hi = self._peak_seen + d * self._let_go_offset() if pulsed else self._pre
                lo = d * (below - b0) if below is not None else -math.inf
                if cfg.unbiased_preload_pull and not pulsed and (below is None or d * (self._pre - below) > 0.0):
                    # (task h32a) it broke loose in the preload, planned below the learned level: the level is not
                    # just scattered, it lies lower than learned.  The censored step (fine.scatter_gain toward the
                    # normal's tail mean) left it above that preload -- full box seed 1137 (friction x0.71):
                    # 0 -> -1.09e-4 rad after a break at -4.59e-4, and the next staircase's preload, planned
                    # from it, broke the valve loose for 7.7e-3 rad; startup seed 1: -0.03 -> -1.8e-4 after a
                    # break at -7.8e-4, the pulses then planned from it overshot 4.6e-4 and a doublet back
                    # 5.8e-4.  Main's pull: below the preload by 0.05 band, with fine.learn_gain.  Not when an
                    # unmoved pulse at this stop reached beyond the preload: then the move is that pulse's late
                    # let-go (the interval is empty, nothing is learned) -- full box seed 1039 (friction x1.64 on
                    # K x0.72): an apex 4.46e-3 held, the valve went in the next preload at -1.92e-3, and pulled
                    # to -1.40e-3 the level planned a pulse that moved 7.7e-3, a doublet 2.3e-2 and a hunt
                    new_b = d * min(d * (b0 + curb), d * self._pre) - d * 0.05 * gap0
                    self.learn.set("breakaway", d, b, curb + cfg.learn_gain * ((new_b - b0) - curb))
                else:
                    self._learn_interval(d, b, lo, d * (hi - b0), gap0)
            else:
                # breakaway at most the largest twist seen: probe a little lower next time
                seen = self._peak_seen if pulsed else self._pre
                new_b = d * min(d * (b0 + curb), d * seen) - d * 0.05 * gap0
                self.learn.set("breakaway", d, b, curb + cfg.learn_gain * ((new_b - b0) - curb))
            cur = self.learn.min_move[d][b]
            if pulsed and self._doublet and not cfg.apex_policy:
                # (fine.apex_policy: its moves come at the overdrive it chose, no sample of the smallest move)
                # a doublet breaks the valve loose from its staircase at ~0 overdrive: each move
                # it makes is a sample of the smallest move the stage can make -- their mean,
                # not the smallest seen: the stopping rule weighs the move the next doublet will
                # most likely make against the error.  (The servo-blended pulse's moves, 1.3-2.9e-3
                # rad sized by the error, are not such samples: taken in, they held 15 of the 29
                # nominal-box plateaus > 8e-4 rad, 0.8-1.4e-3 off, as "below the smallest move".)
                m = abs(move)
                self.learn.set("min_move", d, b, m if cur <= 0.0 else cur + MOVE_GAIN * (m - cur))
        elif pulsed:
            # the pulse did not move it: breakaway lies beyond the peak reached
            if self._doublet and self._stair is not None and cfg.apex_policy:
                # (task h33p) the level lies beyond the apex the kick really reached (measured): the policy's law
                # is truncated there until the valve moves
                self._note_unmoved_plan(d)
                prev = self._apex_floor
                if self._apex_floor is None or self._apex_floor[0] != d or d * (self._kick_apex - self._apex_floor[1]) > 0:
                    self._apex_floor = (d, self._kick_apex)
                # (fine.apex_unraised_plan) a reading that raised this way's floor by less than a resolver count
                self._floor_unraised = self._apex_floor if (
                    prev is not None and prev[0] == d and d * (self._kick_apex - prev[1]) <= RESOLVER_COUNT_RAD) else None
                self._stairs_unmoved += 1
                if d * (self._apex_floor[1] - b0) > self._plausible_offset_rad(pressure_kpa):
                    # beyond any plausible learned level (:meth:`_plausible`): it is not this valve
                    self._climbed_out = True
            elif self._doublet and self._stair is not None:
                # the kick's rise above the planned preload, seen where the valve stayed (a valve that
                # let go cuts the rise short): a sample of the twist the next kick will add
                rise = d * (self._kick_apex - self._pre)
                i = 1 if self._first_stair and cfg.first_kick_fraction != 1.0 else 0
                if rise > 0.0:
                    cur = self._rise_seen[i]
                    self._rise_seen[i] = rise if cur <= 0.0 else cur + MOVE_GAIN * (rise - cur)
                # climb the staircase, on past the learned breakaway if need be (the level found
                # is learned from the doublet that breaks it loose), in small steps: each 1e-4 rad
                # of overdrive adds ~4e-4 rad to the move.  (Steps of 0.3 x the way left to the
                # learned breakaway, far below it where the level seldom lies, took 30 % fewer
                # doublets but made larger moves: nominal box 40 runs, 2-3 runs hunting vs 0.)
                self._stair_step = self._fitting_stair(self._target - thl, pressure_kpa, gap0)
                far = cfg.stair_far_sigmas * self._scatter(d, b, gap0)
                if cfg.stair_far_sigmas > 0.0 and self._stair > far:
                    # (task h27s) the staircase starts fine.doublet_sigmas learned scatters below the learned
                    # level in stairs of 0.03 band at 24 periods each, and 33 of the nominal box's 67 plateaus
                    # > 8e-4 rad ended with it still climbing.  Until the apex is within fine.stair_far_sigmas
                    # scatters of the level, a stair climbs up to fine.kick_rise_rad (the largest that keeps
                    # the next preload below the apex this stair reached), never past that bound.  Measured
                    # (1: unmoved stairs before a move median 10.5 -> 5) no better: the larger overdrive at the
                    # stair that lets go makes the move larger (p90 2.6 -> 3.2e-3 rad), 67 -> 71 plateaus
                    # > 8e-4, p95 1.32 -> 1.49e-3 rad (docs §55): off by default
                    self._stair_step = max(self._stair_step, min(max(cfg.kick_rise_rad, self._stair_step),
                                                                 self._stair - far))
                self._stairs_unmoved += 1
                if cfg.stair_growth_after > 0:
                    # (task h32e) past fine.stair_growth_after unmoved stairs a staircase is in its tail
                    self._stair_step = max(self._stair_step, self._grown_stair(self._target - thl, pressure_kpa, gap0))
                self._stair -= self._stair_step
                if d * curb - (self._kick_rise() + self._stair) > self._plausible_offset_rad(pressure_kpa):
                    # the next stair's preload would lie beyond the nominal breakaway b0 by more
                    # than any plausible learned offset (:meth:`_plausible`): it is not this valve
                    self._climbed_out = True
            else:
                step = cfg.doublet_probe_step if self._doublet else cfg.probe_step
                if self._safe is None or d * self._peak_seen > d * self._safe:
                    self._safe = self._peak_seen
                if cfg.unbiased_samples:
                    # (task h30u) an unmoved pulse only bounds this stop's level from below (the apex): that
                    # bound enters the learned level once, with the move that ends the stop (above).  Raised
                    # here by fine.probe_step x the band at each unmoved pulse (the §46 ratchet: +2.3e-4 rad
                    # median over 822 pulses, the level lying 1.8e-4 above before them), the level drifted up
                    # from every stop; the next pulse still climbs, by the push its peak is planned with
                    # as far as the ratchet would have raised the level (max(level, apex) + step x band)
                    self._pushes[(d, b)] = max(self._pushes.get((d, b), 0.0),
                                               d * (self._peak_seen - (b0 + curb))) + step * gap0
                    new_b = b0 + curb
                elif cfg.probe_reached:
                    # an unmoved pulse proves only that the level at this stop lies beyond the apex the
                    # twist really reached: a pulse that fell short of the learned level (the servo
                    # reaches 60-75 % of a planned overdrive) proves nothing above it -- raised anyway,
                    # 10 such pulses climbed 0.0782 -> 0.0831 rad on the soft coupling, and the preload
                    # planned from it broke the valve loose a whole jump (task h24s/h25p).  The learned
                    # level takes only what the reached apex proves; the next pulse's planned peak (not
                    # its preload) still climbs by the old step, so a servo that falls short of its plan
                    # reaches further each time (:attr:`_pushes`: per direction and Δp band, kept across
                    # stops -- the servo's shortfall is the loop's, not the stop's -- and decayed x0.7 at each
                    # servo-blended move; reset per stop, it measured worse, task h25p)
                    ratchet = d * max(d * (b0 + curb), d * self._peak_seen) + d * step * gap0
                    new_b = d * max(d * (b0 + curb), d * self._peak_seen + step * gap0)
                    self._pushes[(d, b)] = self._pushes.get((d, b), 0.0) + d * (ratchet - new_b)
                else:
                    new_b = d * max(d * (b0 + curb), d * self._peak_seen) + d * step * gap0
                self.learn.set("breakaway", d, b, new_b - b0)
        err = self._target - thl
        if d * err < 0.0:
            self.crossings_this_plateau += 1
            if self.applied_scale is not None:
                # on a scale read (fine.learned_scale_*) a move across the target ends the engagement: the
                # move back unwinds the twist across the whole static band, s times the told one, and its
                # preloads broke the valve loose back across (full box seeds 1013 and 1199, friction x1.4 on
                # K x0.78-0.86 with a load: 3.5e-3 over, 5.7e-3 back, 1.2e-2 over again -- hunting; task h26f).
                # It holds there if the move left the valve closer than it found it, else the main law takes
                # the plateau back
                if abs(err) <= self._err0:
                    self._judge(failed=False)
                    self.phase = HOLD
                    self._hold_ref = th1
                else:
                    self._hand_back()
                return
        if cfg.restair_sigmas > 0.0 and self._early_breaks >= EARLY_BREAKS and not pulsed and self._restair is None:
            # (h30b) instead of handing the plateau back at the second preload breakaway (the main law's deadband is
            # ~half a jump: nominal box seed 2018 #1 was left 6.1e-3 rad off), a doublet staircase from below the
            # preload reference it broke loose at -- not the twist seen once the valve had slid two tolerances, which
            # has unwound with the slide (2018 #1: 1.2e-3 rad beyond the reference); one more preload breakaway
            # hands it back
            self._restair = (d, self._break_ref)
            self._early_breaks -= 1
        if d * move < -2.0 * cfg.tolerance_rad or abs(err) > cfg.max_move_rad or self._early_breaks >= EARLY_BREAKS \
                or not self._plausible(thl, pressure_kpa, 1 if err > 0 else -1) \
                or not self._twist_fits(th1 - thl, thl, pressure_kpa):
            # it moved away from the target, or further than the stage handles, or what it
            # learned does not fit the model: the model does not describe this valve
            if self._hold_not_hand_back(th1, err, pressure_kpa):
                return
            self._hand_back()
            return
        policy = cfg.apex_policy and self._doublet and abs(err) <= cfg.doublet_max_error_rad
        if abs(err) <= self._done_rad() or self._spent() or (not policy and (self._below_min_move(err, pressure_kpa) \
                or (pulsed and self._doublet and self._stair is not None
                    and self._level_outgrows_error(err, pressure_kpa, b0 + curb)))) \
                or self._cross_guard(err, pressure_kpa) is None:
            # close enough, or its moves are larger than the error left, or a move could make the
            # plateau hunt: hold where it is
            self._judge(failed=abs(err) > self._err0 + cfg.tolerance_rad)
            self.phase = HOLD
            self._hold_ref = th1
            return
        self._start_pulse(th1, thl, pressure_kpa, after_command)

    def _count_reversals(self, thl: float) -> None:
        """Count the valve's direction reversals on this plateau as the hunting metric counts them
        (:class:`~fuel_valve_control.common.hunting.ReversalCounter`, from ``reversal_window_periods``
        after the plateau's start) -- on the measured angle averaged over ``REVERSAL_MEAN_PERIODS``
        (the metric counts on the true one)."""
        k = self.cfg.reversal_window_periods
        if k is None:
            return
        self._plateau_k += 1
        recent = self._recent
        recent.append(thl)
        if len(recent) > REVERSAL_MEAN_PERIODS:
            del recent[0]
        mean = sum(recent) / len(recent)
        if self._reversals is not None:
            self._reversals.update(mean)
        elif self._plateau_k >= k:
            self._reversals = ReversalCounter(mean)

    def _cross_guard(self, err: float, pressure_kpa: float) -> float | None:
        """Whether a move toward the target (``err`` = target - valve, rad) can be made without
        the plateau hunting by the metric (:mod:`~fuel_valve_control.common.hunting`: two
        reversals on its late window), and how far short it must aim: ``None`` = no move;
        0 = free (it may cross the target: the move back is still allowed); > 0 = the move, or
        the one after it, would make the last reversal the metric allows, so it must not cross
        the target again: it aims ``fine.no_cross_short`` x the stick-slip jump short (its moves
        spread with the jump: a preload that breaks the valve loose moves it a whole jump, a
        servo-blended pulse's overshoot its aim by up to ~0.35 of it) and is made only for an
        error of at least twice that (the servo-blended pulse's smallest moves are ~0.3-0.4 of
        the jump; the doublet's, ~0.19-0.35 of it, cross 4 times in 5: task h19x, nominal box).
        The stage never makes the reversal that would be the metric's second (nominal box, main
        26f43b9: 4 of 40 runs hunted by the stage's crossing moves, each a pulse sized larger
        than the error it was for)."""
        c = self._reversals
        if c is None:
            return 0.0
        d = 1 if err > 0 else -1
        after = c.count + (1 if c.direction == -d else 0)
        if after >= HUNT_REVERSALS:
            return None
        if after < HUNT_REVERSALS - 1:
            return 0.0
        return self.cfg.no_cross_short * self.m.friction(pressure_kpa).stick_slip_jump_rad(
            self.m.coupling_stiffness_nm_per_rad)

    def _scatter(self, d: int, b: int, gap: float) -> float:
        """The learned rms scatter (rad) of the breakaway twist from stop to stop, or before any
        sample ``fine.doublet_margin`` x the static band ``gap`` / ``fine.doublet_sigmas``."""
        cfg = self.cfg
        return self.learn.scatter[d][b] or cfg.doublet_margin * gap / max(cfg.doublet_sigmas, 1e-9)

    def _learn_breakaway(self, d: int, b: int, x: float, gap: float, weight: float = 1.0) -> None:
        """One sample ``x`` (rad) of the breakaway twist's offset from its nominal value
        (:meth:`FineLearner.observe_breakaway`, the prior scatter :meth:`_scatter`'s), taken with
        ``weight`` x ``fine.scatter_gain`` (the main law's samples: ``fine.main_sample_weight``)."""
        self.learn.observe_breakaway(d, b, x, self.cfg.scatter_gain * weight, self._scatter(d, b, gap))

    def _learn_interval(self, d: int, b: int, low: float, high: float, gap: float) -> None:
        """One censored sample (:meth:`FineLearner.observe_interval`): the breakaway twist's offset from its
        nominal value lay in [``low``, ``high``] at one stop, rad **toward the move** (``d`` x the signed offset the
        table holds: a closing move's bounds are mirrored); weight ``fine.scatter_gain``."""
        lo, hi = (low, high) if d > 0 else (-high, -low)
        self.learn.observe_interval(d, b, lo, hi, self.cfg.scatter_gain, self._scatter(d, b, gap))

    def _let_go_offset(self) -> float:
        """How far (rad of twist, >= 0) the twist a pulse let the valve go at lies above the apex the stage saw:
        the valve breaks loose between two samples while the kick raises the twist, so the last sample lies on
        average half the rise the kick adds below it -- half of :meth:`_kick_rise` (task h30u; traced on the
        nominal box, h29q: a moved doublet's apex lay a median 0.94e-4 rad below the plant's quasi-static level,
        p10 / p90 -1.5e-4 / +0.1e-4; the kick's measured rise is 0.28-0.30e-3 rad)."""
        return 0.5 * self._kick_rise()

    def _hold_not_hand_back(self, th1: float, err: float, pressure_kpa: float) -> bool:
        """(``fine.hold_reversed``, in force also with ``fine.apex_policy``; task h34h, docs §86) Instead of handing the
        plateau back to the main law, hold the gear output where it is (``th1``, rad; the valve is at rest:
        :meth:`_after_move` judges a move once it has stopped) and make no more pulses on this plateau, when the main
        law's move toward the target (``err`` = target - valve, rad) could be the hunting metric's second reversal (:meth:`_cross_guard`:
        not a free move).  Returns whether it holds.

        Why: the stage hands back after two preload breakaways on a plateau, a move away from the target, or a learned
        state / twist that does not fit -- each time with the valve just stopped after a slide, its twist at the edge
        of the static band it slid toward.  The main law restarts from the torque that holds that twist and, with the
        error beyond its deadband, unwinds it: the valve at the edge lets go at once and slides on a whole stick-slip
        jump or more.  Traced (nominal box seed 2035 plateau 10, ``fine.apex_policy`` with kicks to 16 A): a doublet's
        park broke the valve loose 5.6e-3 rad across the target, the servo-blended pulse back broke loose in its own
        park (1.6e-3 rad back: the first reversal), the stage handed back 3.3e-3 rad over; the main law's hold slid
        the valve 1.9e-2 rad the other way and its ramp brought it back 1.1e-2 rad -- the metric's second reversal
        (hunting, 1.0e-2 rad; the plateau ended 4.8e-3 off).  The stage's own moves never make that reversal
        (:meth:`_cross_guard`); a hand-back must not give it to the main law either.  Held, the plateau ends where
        the valve stopped (a known shortfall the next demand's move takes up), without hunting.

        Not beyond ``fine.max_move_rad``: an error that large is the main law's by definition (a step it plans and
        makes, not a hold's slide of a jump), and held it would stay for the rest of the plateau -- a real-time run
        whose late period stretched a kick threw the valve 2.1 % of stroke past the demand and the stage held it
        there (``test_nodes.py::test_demand_step_moves_the_valve_in_real_time``, stop 27, docs §104)."""
        cfg = self.cfg
        if not (cfg.hold_reversed or cfg.apex_policy) or self._cold or abs(err) > cfg.max_move_rad:
            return False
        if self._cross_guard(err, pressure_kpa) == 0.0:
            return False                       # a main-law move across the target is still no hunt
        self._hold_here(th1, failed=True)
        return True

    def _hold_here(self, th1: float, failed: bool) -> None:
        """Hold the gear output at ``th1`` (rad) for the rest of the plateau, with no more pulses on it (as after a
        hand-back, but the stage keeps the valve): the plateau judged ``failed`` (:meth:`_judge`), the staircase and
        the policy's floor dropped."""
        self._judge(failed=failed)
        self._unfit = True
        self._stair = None
        self._servo_unmoved = (0, 0)
        self._apex_floor = None
        self.phase = HOLD
        self._hold_ref = th1

    def _hand_back(self, settle: bool = True) -> None:
        """Leave the plateau to the main law (which restarts from :meth:`hold_torque`): the
        valve has shown that the model's twists do not fit it; no more pulses until the demand
        changes.

        ``fine.handback_settle`` (with ``fine.handover_settle_speed_rad_s`` > 0; stop 28, docs §108): decided
        mid-park, -pulse or -observe with the gear output still turning faster than that speed, the hand-back first
        holds the gear output where it is (phase HOLD, :meth:`_run`) and releases the plateau to the main law once it
        turns slower with the valve at rest for 3 periods, or after 2 x ``fine.observe_time_s`` -- as a new demand's
        hand-over does (:meth:`_handover_settling`).  Why: the main law restarts with its observer's speeds at 0 and
        the swing's momentum unaccounted.  Traced (nominal box seed 4013 plateau 9, C3): 26 servo-blended pulses
        did not move a valve whose static level was drawn high; the 27th's verdict handed back in the observe's pull
        back from the retreat's trough, the twist rising 2.8e-3 rad a period; it ran on through the breakaway and
        the valve slid 1.06e-2 rad past a 9.4e-3 step (112 %).  ``settle=False``: at once (the limit-cycle watch:
        holding on is what shakes the valve)."""
        self._judge(failed=True)
        self._unfit = True
        cfg = self.cfg
        if settle and cfg.handback_settle and cfg.handover_settle_speed > 0.0 and self.phase in (PARK, PULSE, OBSERVE) \
                and self._last_th1 is not None and self._w1_now is not None \
                and abs(self._w1_now) > cfg.handover_settle_speed:
            self._osc, self._osc_sign = 0.0, 0
            self.phase = HOLD
            self._hold_ref = self._last_th1
            self._handback_wait = 0
            return
        self._release()

    def _release(self) -> None:
        """The plateau to the main law now (the end of :meth:`_hand_back`, at once or once the swing has settled)."""
        self._handback_wait = None
        self._osc, self._osc_sign = 0.0, 0
        self.phase = IDLE
        self._target = None
        self._stair = None
        self._servo_unmoved = (0, 0)
        self._apex_floor = None

    def health(self) -> dict:
        self.run_pending()                  # (fine.apex_choice_after_command) what the stage learned, verdicts included
        return {"fine_phase": self.phase, "fine_pulses_total": self.learn.pulses, "fine_kicks_lost": self.kicks_lost,
                "learned_equilibrium_rad": {"open": list(self.learn.equilibrium[1]),
                                            "close": list(self.learn.equilibrium[-1])},
                "learned_breakaway_rad": {"open": list(self.learn.breakaway[1]),
                                          "close": list(self.learn.breakaway[-1])},
                "learned_min_move_rad": {"open": list(self.learn.min_move[1]),
                                         "close": list(self.learn.min_move[-1])},
                "learned_scatter_rad": {"open": list(self.learn.scatter[1]), "close": list(self.learn.scatter[-1])},
                "learned_misfit": {"open": list(self.learn.misfit[1]), "close": list(self.learn.misfit[-1])},
                "valve_noise_counts": self.valve_rest.noise_counts,
                "valve_rest_step_rate": self.valve_rest.step_rate}
