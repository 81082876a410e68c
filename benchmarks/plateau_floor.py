#!/usr/bin/env python3
"""What an idealised fine-positioning policy can reach on the nominal plateaus (issue 14, target row 1; task h32c).

Issue 14's first target: nominal random plateaus (``benchmarks/robustness.py --box nominal``) end within
p95 <= 5e-4 and max <= 8e-4 rad.  This benchmark measures, on the real plant core (:class:`Plant`,
nominal parameters, max Δp, stick-slip with the nominal box's static-level scatter and position
ripple exactly as the campaign draws them), what a *pulse-based* fine-positioning policy could
reach at best.  Three parts:

1. **Engage sample** (:func:`engage_sample`): main's default controller on the nominal box; per
   plateau, the true signed error at the moment the fine stage first engages (or, where it never
   engages, when the valve last came to rest), the plant time left on the plateau (the budget), the
   valve angle and the run's friction draw (scatter rms, ripple amplitude / period / phase) and main's
   own final error.
2. **Pulse table** (:func:`pulse_table`): the valve's move for one shaped torque pulse from rest, on
   the bare nominal plant (no scatter / ripple, the static level set to ``T_c + K x`` for an *excess
   twist* ``x``, a stiff servo on the true motor angle): the twist is parked quasi-statically, then
   one period (1 ms, the loop period) of kick current, ``n_r`` periods of retreat current, then the
   servo to a motor angle ``g`` beyond the start's Coulomb equilibrium.  The pulse family searched
   (the grid, :data:`FAMILY`): kick current ``A`` above the hold, retreat current ``R`` (toward the
   start), ``n_r`` retreat periods, the final servo lead ``g``; the twist *apex* (what the kick
   reaches on a valve that stays stuck, calibrated per pulse) and its *overdrive* ``apex - level``.
   Every current command is capped at 30 A.  Gives the move's distribution against the scatter
   (mean, sd, P(no move), P(|move - wanted| <= 5e-4) for wanted sizes 0.4...3e-3 rad).
3. **Plateau bounds** (:func:`run_stop`): each engage sample replayed on a real :class:`Plant` (its
   run's ripple and scatter law; the plant's own seeded draw per stop), with try after try while the
   plateau's budget lasts (each try costs its park + pulse + settle periods; a reversal of direction
   costs the park across the static band):

   * **oracle**: knows every stop's drawn static level (reads the plant) and tries candidates on copies
     of the plant; per try the family member / overdrive that leaves the smallest |error|, only while
     that improves it; where no single pulse does (the level drawn here is too high for this error),
     the best two-pulse plan (a first move past the target or away from it -- a new stop, a new
     draw -- then the best second);
   * **distribution-aware** (``bayes``): knows the scatter's law of the run (its rms, and the ripple
     map, so the mean level at each position) but not the draw: a posterior over the level (the
     clipped normal, truncated from below by every apex that did not move the valve, reset by every
     move, which draws anew) and per try the member and apex (grid: the law's points) that maximise
     P(land within the stop tolerance) + P(no move) x (the best landing chance of the next try on the
     truncated law), never a try that more likely worsens |e| (``--miss-value``: value misses by a
     fresh try's chance instead -- measured worse);
   * ``bayes_box``: the same knowing only the nominal box's law (rms and ripple unknown: a mixture).

   Reports median / p95 / max and the fractions > 5e-4 / > 8e-4 of the final plateau error for each,
   beside main's own final errors on the same plateaus.

Idealisations (all in the policy's favour, so the numbers are floors for this family): true states
(no resolver quantisation or noise), exact knowledge of the plant's model, loads and hold twist, no
Δp or inertia error.  Not idealised: the 1 kHz command period, the 30 A cap, the drive's current
loop, the plant's dynamics and its friction draws.

Ablations (task h33a, docs §82; the default output is unchanged without them): ``--family`` restricts the policies
to main's doublet (kick, the whole current backwards on the hold, then half of it: a member's fifth element) or a
few shapes near it, with main's final twist phi_e + e/2 (:data:`FAMILIES`); ``--realism`` gives the distribution-
aware policies the resolvers' readings, an apex placed in measured coordinates with a seeded park error
(``--apex-rms``) and the truncation at the measured apex (``--floor``).

Learning policies (task h34r, docs §87; off unless named in ``--policies``): ``bayes_learn`` / ``bayes_rms`` /
``bayes_level`` / ``bayes_local`` are ``bayes_box`` with the level's law the posterior predictive of a
:class:`LevelLearner` (the box's law as its prior) carried across each run's plateaus in order and told every stop's
censored outcome -- the run's law (rms x ripple amplitude x wavenumber x phase), the rms only, one position-free level
(what ``FineLearner`` holds) or a kernel map of it; ``--learn-scope plateau|none`` are the controls (forgotten at every
plateau; never told).  They add a learning-curve table (p95 by the plateau's place in its run).

    python benchmarks/plateau_floor.py [--jobs 2] [--runs 40] [--seed 1000] [--engage PATH.json]
                                       [--stop-tol 4e-4] [--policies oracle,bayes,bayes_box] [--miss-value]
                                       [--family full|main|kicks|kicks2|strong|deep|deep4]
                                       [--realism [--apex-rms 6e-5] [--floor peak|park|plan]]
                                       [--policies ...,bayes_learn,bayes_rms,bayes_level,bayes_local
                                        [--learn-scope run|plateau|none]]
                                       [--json PATH] [--markdown PATH]

Last stdout line: one JSON object.
"""
from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import sys
import time
from multiprocessing import Pool
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
if str(ROOT / "benchmarks") not in sys.path:
    sys.path.insert(0, str(ROOT / "benchmarks"))

from fuel_valve_control.core.params import CONTROLLER_SPEC  # noqa: E402
from fuel_valve_plant.physics import kernel as KN  # noqa: E402
from fuel_valve_plant.physics.params import PLANT_SPEC  # noqa: E402
from fuel_valve_plant.physics.plant import Plant  # noqa: E402

PS = PLANT_SPEC.defaults()
CS = CONTROLLER_SPEC.defaults()
PERIOD = 1.0 / CS["loop_rate_hz"]                      # s, the controller's command period
N = PS["gearbox.ratio"]
K = PS["coupling.stiffness_nm_per_rad"]                # N*m/rad
KT = 1.5 * PS["motor.pole_pairs"] * PS["motor.flux_linkage_wb"]   # N*m/A at the motor
J1 = PS["motor.inertia_kgm2"] * N * N                  # kg*m^2, the motor at the gear output
TS = PS["friction.valve.static_nm"] + PS["friction.valve.static_per_dp_nm"]     # N*m at max Δp
TC = PS["friction.valve.coulomb_nm"] + PS["friction.valve.coulomb_per_dp_nm"]   # N*m at max Δp
CAP_A = 30.0                                           # A, every current command's magnitude limit
TOL_TARGET, TOL_MAX = 5e-4, 8e-4                       # rad, issue 14's p95 / max targets
SERVO_HZ = 60.0                                        # Hz, the park servo's bandwidth (as benchmarks/fine_doublet.py)
PARK_PERIODS = 8                                       # periods of the quasi-static twist ramp of a try (+ 3 still)
PARK_RATE_RAD = 1e-3                                   # rad of twist per extra park period (a reversal: ~23 more)
SETTLE_PERIODS = 6                                     # periods the valve must rest after a pulse before the next
E_READY_RAD = 3e-3                                     # rad: the policies take over at the first rest within this

#: the pulse family searched: kick A above the hold, retreat R (A below the hold, toward the start; the
#: command is capped at 30 A, so 36 is the cap whatever the hold), retreat
#: periods n_r, final servo lead g (rad beyond the start's Coulomb equilibrium, toward the move)
FAMILY = {"kick_a": (2.0, 4.0, 8.0, 16.0), "retreat_a": (36.0, 24.0, 12.0, 0.0), "retreat_periods": (1, 2),
          "lead_rad": (0.0, 5e-4, 1e-3, 2e-3)}
#: excess twists (static level - Coulomb level)/K tabulated, rad; overdrives (apex - level), rad
EXCESS_GRID = tuple(float(x) for x in np.linspace(0.0, 5.2e-3, 27))
OVERDRIVE_GRID = (1e-5, 5e-5, 1e-4, 2e-4, 4e-4, 8e-4, 1.6e-3, 3.2e-3, 6.4e-3)
#: True: the table clamps overdrives / excesses beyond its grid to the edge (a model error the policies can exploit);
#: False: the move there is unknown (NaN)
CLAMP_TABLE = False
WANTED = (4e-4, 6e-4, 8e-4, 1e-3, 1.5e-3, 2e-3, 3e-3)

#: ``--family`` (task h33a, docs §82): which pulses the policy may choose.  ``full``: :data:`FAMILY` (default).
#: The others are main's doublet (:meth:`FinePositioner._doublet_torque`): one period of kick on the hold, then
#: ``fine.retreat_full_periods`` periods of the whole current ``fine.peak_current_a`` backwards on the hold (hold -
#: 30 A: main's "whole current", not the cap -30 A the full family's R = 36 gives), then one period of half of it, then
#: the servo to main's final twist phi_e + e/2 (the lead is half the error the try starts from, :data:`LEAD_GRID`'s
#: end at most): ``main`` with main's kick ``fine.kick_current_a`` (4 A); ``kicks`` with a kick of 4, 8 or 16 A;
#: ``strong``: a 16 A kick, two periods at the cap (R = 36), no half period, the same final twist; ``deep``: that
#: retreat with a kick of 4, 8 or 16 A; ``kicks2``: ``kicks`` with two whole periods before the half one (main with
#: ``fine.retreat_full_periods`` 2); ``deep4``: the ``deep`` retreat with main's kick only
FAMILIES = ("full", "main", "kicks", "kicks2", "strong", "deep", "deep4")
MAIN_KICK_A = CS["fine.kick_current_a"]                # A
MAIN_RETREAT_A = CS["fine.peak_current_a"]             # A below the hold
MAIN_FULL_PERIODS = CS["fine.retreat_full_periods"]
MAIN_HALF = 0.5                                        # the last retreat period's fraction of the whole current
#: leads (rad) tabulated for the families that set the lead by main's rule (e/2): interpolated between them
LEAD_GRID = (0.0, 2.5e-4, 5e-4, 7.5e-4, 1e-3, 1.5e-3, 2e-3, 3e-3, 5e-3)
#: ``--realism``: the valve resolver's count (rad), and main's "moved" test (fine_positioning's OBSERVE: the valve
#: at least half of ``fine.tolerance_counts`` counts from the pulse's start)
LSB_RAD = 2.0 * math.pi / (1 << int(PS["resolver.bits"]))
MOVED_RAD = 0.5 * CS["fine.tolerance_counts"] * LSB_RAD
#: ``--apex-rms`` default: the servo's park ends off the plan by ~0.3-0.9e-4 rad (median, §55 / §61.3: main
#: 0.87e-4, the planned re-park 0.33e-4); a zero-mean normal of the middle, 0.6e-4 rad rms
APEX_RMS_RAD = 6e-5


def load_torque(theta: float, ps=PS) -> float:
    """Spring + flow + steady load on the valve at ``theta`` (N*m, toward closed), max Δp."""
    stroke = ps["valve.stroke_rad"]
    return (ps["spring.preload_nm"] + ps["spring.rate_nm_per_rad"] * theta
            + ps["flow.torque_max_nm"] * math.sin(math.pi * min(max(theta / stroke, 0.0), 1.0)) + ps["load_torque_nm"])


# ------------------------------------------------------------------------------------------ one try on a plant
class Driver:
    """Idealised actuator commands on a :class:`Plant` (true states, 1 kHz periods, |iq| <= 30 A)."""

    def __init__(self, plant: Plant):
        self.pl = plant
        w = 2.0 * math.pi * SERVO_HZ
        self.kp, self.kd = J1 * w * w, 2.0 * 0.8 * w * J1
        self.periods = 0
        #: ``--realism``: the direction whose measured twist peak is tracked (None: not sensed)
        self.sense: int | None = None
        self.peak: float | None = None     # rad, the measured twist furthest toward ``sense`` (once a period)
        self.last: float | None = None     # rad, the last measured twist

    def twist(self) -> float:
        t = self.pl.truth()
        return t.motor_angle / N - t.valve_angle

    def run(self, iq: float) -> None:
        self.pl.set_command(min(max(iq, -CAP_A), CAP_A), True)
        self.pl.advance(PERIOD)
        self.periods += 1
        if self.sense is not None:
            # the twist as the controller reads it once a period: the motor resolver / N minus the valve resolver
            # (both quantised, with their noise and delay)
            r = self.pl.resolver()
            if r is not None:
                phi = r.motor_rad / N - r.valve_rad
                self.last = phi
                if self.peak is None or self.sense * phi > self.sense * self.peak:
                    self.peak = phi

    def servo_current(self, th1_ref: float, ff_nm: float) -> float:
        """Current holding the gear output at ``th1_ref`` (rad) with ``ff_nm`` of coupling torque fed forward."""
        t = self.pl.truth()
        return (ff_nm + self.kp * (th1_ref - t.motor_angle / N) - self.kd * t.motor_velocity / N) / (N * KT)

    def park(self, twist_to: float, periods: int) -> None:
        """Ramp the twist (cosine) from the present one to ``twist_to`` (rad) quasi-statically: ``periods``
        plus one period per mrad of twist to carry (a reversal across the static band costs ~23 more)."""
        thl = self.pl.valve_angle
        phi0 = self.twist()
        periods += int(math.ceil(abs(twist_to - phi0) / PARK_RATE_RAD))
        for k in range(periods + 3):
            u = min(k / max(periods, 1), 1.0)
            phi = phi0 + (twist_to - phi0) * 0.5 * (1.0 - math.cos(math.pi * u))
            self.run(self.servo_current(thl + phi, K * phi))

    def pulse(self, d: int, kick_a: float, retreat_a: float, retreat_periods: int, final_th1: float,
              final_ff: float, half: float = 0.0) -> None:
        """The kick, the retreat (``retreat_periods`` of ``retreat_a``, then with ``half`` > 0 one period of
        ``half`` x ``retreat_a``: main's doublet), then the servo at ``final_th1`` until the valve has rested
        ``SETTLE_PERIODS`` (at most 4 x that)."""
        t = self.pl.truth()
        hold = K * (t.motor_angle / N - t.valve_angle) / (N * KT)
        self.run(hold + d * kick_a)
        for _ in range(retreat_periods):
            self.run(hold - d * retreat_a)
        if half > 0.0:
            self.run(hold - d * half * retreat_a)
        rest = 0
        for _ in range(4 * SETTLE_PERIODS):
            self.run(self.servo_current(final_th1, final_ff))
            rest = rest + 1 if self.pl.valve_velocity == 0.0 else 0
            if rest >= SETTLE_PERIODS:
                break


def bare_plant(theta: float, excess_rad: float) -> Plant:
    """Nominal plant at rest at ``theta``, max Δp, no scatter / ripple, static level T_c + K x."""
    ts = TC + K * excess_rad
    c0 = PS["friction.valve.coulomb_nm"]
    pl = Plant(PS.replace({"friction.valve.static_nm": c0, "friction.valve.static_per_dp_nm": ts - c0}))
    pl.hold_at(theta)
    return pl


def try_pulse(pl: Plant, d: int, apex: float, rise: float, member: tuple, coulomb_nm: float,
              park_periods: int = PARK_PERIODS, table: bool = True, seen: dict | None = None) -> tuple[float, int]:
    """One try on ``pl`` (at rest): park at ``apex - rise`` (absolute twist, rad), pulse ``member``
    = (kick_a, retreat_a, retreat_periods, lead_rad[, half]) (``half``: one more retreat period at that
    fraction of ``retreat_a``, main's doublet).  Returns (valve move rad, periods spent); with ``table`` the
    move is NaN when the park itself broke the valve loose (no pulse of this member).  With ``seen`` (a dict)
    the twist is also read through the resolvers once a period: ``seen['peak']`` = the measured twist
    furthest toward ``d`` during the try (rad, absolute)."""
    kick, retreat, nr, lead = member[:4]
    half = member[4] if len(member) > 4 else 0.0
    dr = Driver(pl)
    if seen is not None:
        dr.sense = d
    thl0 = pl.valve_angle
    load = load_torque(thl0, pl.params)
    dr.park(apex - d * rise, park_periods)
    moved_early = pl.valve_angle - thl0
    if seen is not None:
        seen["park"] = dr.last                          # the measured twist at the park's end (at rest, quasi-static)
    final_th1 = thl0 + (load + d * coulomb_nm) / K + d * lead
    dr.pulse(d, kick, retreat, nr, final_th1, load + d * coulomb_nm, half)
    move = pl.valve_angle - thl0
    if seen is not None:
        seen["peak"] = dr.peak
    return (math.nan if table and abs(moved_early) > 1e-9 else move), dr.periods


def calibrate_rise(d: int, member: tuple, theta: float = 0.5) -> float:
    """Twist (rad, toward ``d``) a pulse of ``member`` adds above a quasi-static park at the nominal static
    level on a valve held stuck: the kick, the retreat and then the servo toward the start's Coulomb twist +
    the lead, as :meth:`Driver.pulse` runs them (a member that does not retreat keeps rising into the servo)."""
    pl = bare_plant(theta, 0.15)                      # a level nothing reaches (72 N*m)
    load = load_torque(theta)
    dr = Driver(pl)
    park = (load + d * TS) / K
    dr.park(park, PARK_PERIODS)
    kick, retreat, nr, lead = member[:4]
    half = member[4] if len(member) > 4 else 0.0
    nh = 1 if half > 0.0 else 0
    t = pl.truth()
    thl0 = t.valve_angle
    hold = K * (t.motor_angle / N - t.valve_angle) / (N * KT)
    final_th1, final_ff = thl0 + (load + d * TC) / K + d * lead, load + d * TC
    apex = d * dr.twist()
    steps = pl.steps_for(PERIOD)
    for k in range(1 + nr + nh + SETTLE_PERIODS):
        iq = (hold + d * kick if k == 0 else hold - d * retreat if k <= nr else hold - d * half * retreat if k <= nr + nh
              else dr.servo_current(final_th1, final_ff))
        pl.set_command(min(max(iq, -CAP_A), CAP_A), True)
        for _ in range(steps):
            pl.step(1)
            apex = max(apex, d * dr.twist())
    return apex - d * park


# ------------------------------------------------------------------------------------------ main's engage sample
def _engage_run(seed: int) -> list[dict]:
    """Main's default controller on the nominal-box run ``seed``: per plateau the true signed error
    (demand - angle, rad) and plant time when the fine stage first engages (else when the valve last
    came to rest on the plateau), the budget left (s), the valve angle and main's final error."""
    import robustness as R
    from fuel_valve_control.core.fine_positioning import IDLE
    from fuel_valve_control.tools import sim

    case = R.sample_case(seed, "nominal")
    plan, plant, driver = R.held_case(case)
    period = driver.period
    n = int(round(plan.duration_s / period))
    stroke = plan.plant_params["valve.stroke_rad"]
    law = driver.controller.law
    fine = getattr(law, "fine", None)
    dem, pos, vel, eng = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n, dtype=bool)
    for k in range(n):
        t = k * period
        out, _ = sim.exchange_period(driver, plant, t, plan.demand.value(t))
        tr = plant.truth()
        dem[k], pos[k], vel[k] = plan.demand.nominal(t) / 100.0 * stroke, tr.valve_angle, tr.valve_velocity
        eng[k] = fine is not None and fine.phase != IDLE
        plant.set_command(out.current_a, out.enable)
        plant.advance(period)
    # plateaus: runs of constant demand after a step (the first, held from the start, is no step)
    edges = [0] + [k for k in range(1, n) if dem[k] != dem[k - 1]] + [n]
    rows = []
    for i0, i1 in zip(edges[1:-1], edges[2:]):
        seg = slice(i0, i1)
        # the stage's first engagement on this plateau (a rising edge: it may still be busy with the last
        # plateau for a period or two after the demand steps)
        idx = np.flatnonzero(eng[i0 + 1:i1] & ~eng[i0:i1 - 1]) + 1
        err = dem[i0:i1] - pos[i0:i1]
        still = vel[i0:i1] == 0.0
        rest3 = still & np.concatenate([[False, False], still[:-2] & still[1:-1]])
        if len(idx):
            # from the stage's engagement on: the first period the valve has rested 3 periods within
            # E_READY_RAD of the demand (the stage's own first pulse takes a far error there)
            engaged = True
            near = np.flatnonzero(rest3[idx[0]:] & (np.abs(err[idx[0]:]) <= E_READY_RAD))
            k0 = i0 + int(idx[0]) + (int(near[0]) if len(near) else 0)
        else:
            # never engaged: where the valve last came to rest
            moving = np.flatnonzero(~still)
            k0, engaged = i0 + (int(moving[-1]) + 1 if len(moving) else 0), False
            k0 = min(k0, i1 - 1)
        rows.append({"seed": seed, "engaged": engaged, "error_rad": float(dem[k0] - pos[k0]),
                     "engage_s": round(float(idx[0]) * period, 4) if len(idx) else None,
                     "t_ready_s": round((k0 - i0) * period, 4), "budget_s": round((i1 - k0) * period, 4),
                     "length_s": round((i1 - i0) * period, 4), "theta_rad": float(pos[k0]),
                     "final_error_rad": float(abs(dem[i1 - 1] - pos[i1 - 1])),
                     "static_scatter": case["static_scatter"], "ripple": case["ripple"],
                     "ripple_period_rad": case["ripple_period_rad"], "ripple_phase_rad": case["ripple_phase_rad"]})
    return rows


def engage_sample(seeds, jobs: int) -> list[dict]:
    """:func:`_engage_run` over ``seeds`` (a pool of ``jobs``); the rows of every plateau."""
    if jobs > 1:
        with Pool(jobs) as pool:
            parts = pool.map(_engage_run, list(seeds), chunksize=1)
    else:
        parts = [_engage_run(s) for s in seeds]
    return [r for part in parts for r in part]


# ------------------------------------------------------------------------------------------ the pulse table
def members(family: str = "full") -> list[tuple]:
    """Every member (kick_a, retreat_a, retreat_periods, lead_rad) of :data:`FAMILY` (``family`` 'full'), or of
    one of the other :data:`FAMILIES` (kick_a, retreat_a, retreat_periods, lead_rad, half) over :data:`LEAD_GRID`."""
    if family == "full":
        return list(itertools.product(FAMILY["kick_a"], FAMILY["retreat_a"], FAMILY["retreat_periods"], FAMILY["lead_rad"]))
    shapes = {"main": [(MAIN_KICK_A, MAIN_RETREAT_A, MAIN_FULL_PERIODS, MAIN_HALF)],
              "kicks": [(k, MAIN_RETREAT_A, MAIN_FULL_PERIODS, MAIN_HALF) for k in (4.0, 8.0, 16.0)],
              "kicks2": [(k, MAIN_RETREAT_A, 2, MAIN_HALF) for k in (4.0, 8.0, 16.0)],
              "strong": [(16.0, 36.0, 2, 0.0)],
              "deep": [(k, 36.0, 2, 0.0) for k in (4.0, 8.0, 16.0)],
              "deep4": [(MAIN_KICK_A, 36.0, 2, 0.0)]}[family]
    return [(k, r, n, g, h) for (k, r, n, h) in shapes for g in LEAD_GRID]


def _table_row(job: tuple) -> tuple:
    d, member = job
    rise = calibrate_rise(d, member)
    theta = 0.5
    load = load_torque(theta)
    moves = np.full((len(EXCESS_GRID), len(OVERDRIVE_GRID)), np.nan)
    for i, x in enumerate(EXCESS_GRID):
        level = (load + d * (TC + K * x)) / K
        for j, od in enumerate(OVERDRIVE_GRID):
            mv, _ = try_pulse(bare_plant(theta, x), d, level + d * od, rise, member, TC)
            moves[i, j] = d * mv                      # toward the pulse's direction
    return d, member, rise, moves


class Table:
    """Valve move (rad, toward the pulse) for direction x member x excess x overdrive, and the kick's rise.
    (A plain class, not a dataclass: the tests load this script as a module without registering it.)"""

    def __init__(self, members: list, rise: dict, moves: dict, lead_rule: bool = False):
        self.members = members        # (kick_a, retreat_a, retreat_periods, lead_rad[, half])
        self.rise = rise              # (d, member index) -> rad
        self.moves = moves            # d -> array [member, excess, overdrive], rad
        #: the lead is not chosen but main's rule, half the error (the members tabulate it over :data:`LEAD_GRID`)
        self.lead_rule = lead_rule

    def at_lead(self, d: int, moves: np.ndarray, lead: float) -> tuple[np.ndarray, list, list]:
        """``moves`` [member, ...] (of :meth:`move_all`) and the rises interpolated in the lead to ``lead`` (rad)
        per pulse shape (the members alike but for the lead): (moves [shape, ...], members, rises)."""
        groups: dict = {}
        for i, m in enumerate(self.members):
            groups.setdefault(m[:3] + m[4:], []).append((m[3], i))
        out, mem, rise = [], [], []
        for key, pts in groups.items():
            pts.sort()
            gs = np.array([g for g, _ in pts])
            lead = min(max(lead, gs[0]), gs[-1])
            j = min(int(np.searchsorted(gs, lead, side="right")) - 1, len(gs) - 2) if len(gs) > 1 else 0
            i0, i1 = pts[j][1], pts[min(j + 1, len(pts) - 1)][1]
            t = 0.0 if i0 == i1 else (lead - gs[j]) / (gs[j + 1] - gs[j])
            out.append((1.0 - t) * moves[i0] + t * moves[i1])
            mem.append(key[:3] + (float(lead),) + key[3:])
            rise.append((1.0 - t) * self.rise[(d, i0)] + t * self.rise[(d, i1)])
        return np.asarray(out), mem, rise

    def move(self, d: int, m: int, excess, overdrive):
        """Interpolated move(s) of member ``m``; 0 where the overdrive is <= 0 (the apex stays below the level)."""
        return self.move_all(d, excess, overdrive, self.moves[d][m][None])[0]

    def move_all(self, d: int, excess, overdrive, tab=None):
        """:meth:`move` of every member at once: an array [member, *shape of the arguments]."""
        x = np.asarray(excess, dtype=float)
        od = np.asarray(overdrive, dtype=float)
        tab = self.moves[d] if tab is None else tab
        xg, og = np.asarray(EXCESS_GRID), np.log(np.asarray(OVERDRIVE_GRID))
        fx = np.clip(np.interp(x, xg, np.arange(len(xg))), 0, len(xg) - 1)
        fo = np.clip(np.interp(np.log(np.maximum(od, OVERDRIVE_GRID[0])), og, np.arange(len(og))), 0, len(og) - 1)
        i0, j0 = np.minimum(fx.astype(int), len(xg) - 2), np.minimum(fo.astype(int), len(og) - 2)
        ax, ao = fx - i0, fo - j0
        v = (tab[:, i0, j0] * (1 - ax) * (1 - ao) + tab[:, i0 + 1, j0] * ax * (1 - ao)
             + tab[:, i0, j0 + 1] * (1 - ax) * ao + tab[:, i0 + 1, j0 + 1] * ax * ao)
        # beyond the tabulated overdrives / excesses the move is unknown (NaN: the policies count it a miss)
        if not CLAMP_TABLE:
            v = np.where((od > OVERDRIVE_GRID[-1] * 1.0001) | (x > EXCESS_GRID[-1] * 1.0001), np.nan, v)
        return np.where(od > 0.0, v, 0.0)


def pulse_table(jobs: int, family: str = "full") -> Table:
    """Tabulate every member's move on the bare plant (both directions) in a pool of ``jobs``."""
    ms = members(family)
    work = [(d, m) for d in (1, -1) for m in ms]
    if jobs > 1:
        with Pool(jobs) as pool:
            rows = pool.map(_table_row, work, chunksize=4)
    else:
        rows = [_table_row(w) for w in work]
    moves = {1: np.zeros((len(ms), len(EXCESS_GRID), len(OVERDRIVE_GRID))),
             -1: np.zeros((len(ms), len(EXCESS_GRID), len(OVERDRIVE_GRID)))}
    rise = {}
    for d, member, r, mv in rows:
        i = ms.index(member)
        moves[d][i] = mv
        rise[(d, i)] = r
    return Table(ms, rise, moves, lead_rule=family != "full")


# ------------------------------------------------------------------------------------------ the plateau bounds
POLICIES = ("oracle", "bayes", "bayes_box")
N_LEVELS = 61                                          # grid of the scatter's standard-normal draw, -3..3
ORACLE_CANDIDATES = 8                                  # members the oracle tries on copies of the plant per try


def stop_plant(row: dict) -> Plant:
    """The real plant of an engage sample: nominal, max Δp, its run's scatter and ripple, its own seed, at
    rest at the sample's angle (the drive holding it with the load's twist)."""
    ps = PS.replace({"friction.valve.static_scatter": row["static_scatter"], "friction.valve.ripple": row["ripple"],
                     "friction.valve.ripple_period_rad": row["ripple_period_rad"],
                     "friction.valve.ripple_phase_rad": row["ripple_phase_rad"],
                     "seed": (row["seed"] * 131 + int(round(row["theta_rad"] * 1e6))) % (2**31 - 1)})
    pl = Plant(ps)
    pl.hold_at(row["theta_rad"])
    return pl


def ripple_at(row: dict, theta: float) -> float:
    """The ripple factor on both valve levels at ``theta`` (the scatter's law, known to both policies)."""
    return 1.0 + row["ripple"] * math.sin(2.0 * math.pi / row["ripple_period_rad"] * theta + row["ripple_phase_rad"])


def level_prior(sigma: float, r: float) -> tuple[np.ndarray, np.ndarray]:
    """(excess twists rad, weights) of the static level's law at ripple ``r``: ``1 + σ n``, n ~ N(0,1)
    clipped to ±3 (the clipped tails' mass on the ends), never below the Coulomb level."""
    n = np.linspace(-KN.SCATTER_CLIP, KN.SCATTER_CLIP, N_LEVELS)
    w = np.exp(-0.5 * n * n)
    w /= w.sum()
    x = r * np.maximum(TS * (1.0 + sigma * n) - TC, 0.0) / K
    return x, w


#: the nominal box's law of the scatter and ripple as ``robustness.py`` draws it per run (rms U(0.02, 0.08), ripple
#: amplitude U(0, 0.05) at a uniform phase), in a few quadrature points: what the ``bayes_box`` policy knows
BOX_SIGMAS = (0.03, 0.05, 0.07)
#: the ripple factor 1 + a sin(phase) at the 1/8, 3/8, 5/8, 7/8 quantiles of a ~ U(0, 0.05) x sin(U(0, 2 pi))
BOX_RIPPLES = (1.0 - 0.0248, 1.0 - 0.0049, 1.0 + 0.0049, 1.0 + 0.0248)
BOX_LEVELS = 15


def law_samples(row: dict, theta: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(table excess x_t, apex coordinate x_p, weight) of the static level's law as the distribution-aware
    policy knows it at ``theta``.  ``row['law'] == 'run'``: the run's scatter rms and its ripple (so the
    ripple factor here, which scales both levels: x_p = x_t, relative to the true Coulomb twist);
    ``'box'``: only the box's law (rms and ripple unknown, :data:`BOX_SIGMAS` x :data:`BOX_RIPPLES`), the
    apex measured from the nominal Coulomb twist: x_p = (T_s r f - T_c)/K, x_t = r (T_s f - T_c)/K."""
    if row.get("law", "run") == "run":
        x, w = level_prior(row["static_scatter"], ripple_at(row, theta))
        return x, x, w
    if row.get("law") == "learn":
        return row["_learner"].samples(theta)        # the posterior predictive of the run's tries so far (h34r)
    n = np.linspace(-KN.SCATTER_CLIP, KN.SCATTER_CLIP, BOX_LEVELS)
    wn = np.exp(-0.5 * n * n)
    xt, xp, w = [], [], []
    for sig in BOX_SIGMAS:
        f = 1.0 + sig * n
        for r in BOX_RIPPLES:
            ts = np.maximum(TS * f * r, TC * r)
            xt.append((ts - TC * r) / K)
            xp.append((ts - TC) / K)
            w.append(wn)
    w = np.concatenate(w)
    return np.concatenate(xt), np.concatenate(xp), w / w.sum()


# ------------------------------------------------------------------------------------------ learning the run's law (h34r)
#: ``--policies bayes_learn / bayes_rms / bayes_level`` (task h34r, docs §87): the ``bayes_box`` policy whose level law is
#: the posterior predictive of a learner carried across the run's plateaus in order, updated from its own tries
LEARN_POLICIES = ("bayes_learn", "bayes_rms", "bayes_level", "bayes_local")
#: the learner's kinds: ``learn`` the run's law (scatter rms x ripple amplitude x ripple wavenumber x phase), ``rms`` the
#: scatter rms only (the ripple at each stop a fresh draw of the box's law, as ``bayes_box`` has it), ``level`` one
#: position-free level (a mean factor and a spread: what ``FineLearner`` holds -- the ripple is scatter to it)
LEARN_KIND = {"bayes_learn": "learn", "bayes_rms": "rms", "bayes_level": "level", "bayes_local": "local"}
#: the box's ranges (``robustness.py --box nominal``): rms U(0.02, 0.08), ripple U(0, 0.05), period U(5, 50) mrad
BOX_SIGMA_RANGE, BOX_RIPPLE_MAX, BOX_PERIOD_RANGE = (0.02, 0.08), 0.05, (0.005, 0.05)
#: ``local``'s kernel width (rad): the angle over which the box's shortest ripple (5 mrad) turns one radian of phase
LOCAL_WIDTH_RAD = BOX_PERIOD_RANGE[0] / (2.0 * math.pi)
LEARN_SIGMAS = tuple(BOX_SIGMA_RANGE[0] + (i + 0.5) * (BOX_SIGMA_RANGE[1] - BOX_SIGMA_RANGE[0]) / 7 for i in range(7))
LEARN_AMPS = tuple((i + 0.5) * BOX_RIPPLE_MAX / 6 for i in range(6))
LEARN_PHASES = 16
#: the wavenumber grid's step (1/rad): a hypothesis' phase is then within pi/4 of the nearest grid point's out to
#: LEARN_SPAN_RAD from the run's first plateau (a run of 12 nominal plateaus spans 0.02-0.2 rad)
LEARN_SPAN_RAD = 0.25
LEARN_DK = 1.0 / (4.0 * LEARN_SPAN_RAD)
#: the position-free level's hypotheses: mean factor (the box's ripple at one position, 0.95..1.05) x spread
LEVEL_MEANS = tuple(float(v) for v in np.linspace(0.95, 1.05, 11))
LEVEL_SPREADS = tuple(float(v) for v in np.linspace(0.02, 0.09, 8))
#: the predictive's ripple-factor bins (the learned law as a mixture of (rms, ripple factor) components)
LEARN_R_BINS = np.linspace(1.0 - BOX_RIPPLE_MAX, 1.0 + BOX_RIPPLE_MAX, 22)
#: a tie's odds against any one reading being wrong (the model's error: a move judged wrongly, a rise off the table)
LEARN_OUTLIER = 1e-3
#: rad: the softness of the censoring in true states (the bare-plant rise calibration vs this stop's)
LEARN_SOFT_RAD = 2e-5


def _phi(z):
    from scipy.special import ndtr
    return ndtr(z)


class LevelLearner:
    """Posterior over the run's static-level law from the policy's censored tries (task h34r, docs §87).

    The plant draws the static level anew at every stop, ``T_s r(θ) (1 + σ n)``, n ~ N(0, 1) clipped to ±3, with the
    run's ripple ``r(θ) = 1 + a sin(2π θ/λ + φ)`` (:mod:`fuel_valve_plant.physics.kernel`).  In the policy's apex
    coordinate (twist above the nominal Coulomb twist toward the try, rad) the level is x = (T_s r (1 + σ n) - T_c)/K.
    A stop tells, once it ends, the interval the level lay in: above the highest apex that did not move the valve
    (``lo``), below the apex that did (``hi``; None: the plateau ended first) -- each apex known to ``soft`` rad rms.
    Each stop is one draw of n: the likelihood of a hypothesis is P(lo < x < hi | σ, r(θ)), a normal CDF difference.

    Kinds (hypotheses h, weights a discrete posterior, the prior the box's law):

    * ``learn``: σ (7) x a (6) x wavenumber k = 1/λ (``LEARN_DK`` steps over 20..200 /rad, prior ∝ 1/k² as λ is
      uniform) x phase ψ at the run's first plateau θ0 (16): r = 1 + a sin(2π k (θ - θ0) + ψ) -- ~1.2e5 hypotheses,
      one update ~5 ms;
    * ``rms``: σ (7) only; the ripple at each stop a fresh draw of the box's law (:data:`BOX_RIPPLES`) in both the
      likelihood and the predictive;
    * ``level``: one position-free law, a mean factor μ (11, prior the box's ripple at one position) x spread s (8):
      x = (T_s μ (1 + s n) - T_c)/K everywhere -- one level per direction and Δp band as ``FineLearner`` holds it,
      the ripple read as scatter;
    * ``local``: a non-parametric map, the ``level`` law fitted per position by a kernel: at θ each stop's
      log-likelihood counts with the weight exp(-(θ - θ_i)² / 2 w²), w = :data:`LOCAL_WIDTH_RAD` (a kernel-weighted
      local likelihood; state: the stops' angles and their 88 log-likelihoods).

    :meth:`samples` gives the posterior predictive at θ as :func:`law_samples` does the box's law: (x_t, x_p, w)."""

    def __init__(self, kind: str, theta0: float, soft: float = LEARN_SOFT_RAD):
        self.kind, self.theta0, self.soft = kind, float(theta0), float(soft)
        self.n_obs = 0
        if kind == "learn":
            ks = np.arange(1.0 / BOX_PERIOD_RANGE[1], 1.0 / BOX_PERIOD_RANGE[0] + 1e-9, LEARN_DK)
            s, a, k, p = np.meshgrid(np.asarray(LEARN_SIGMAS), np.asarray(LEARN_AMPS), ks,
                                     2.0 * math.pi * np.arange(LEARN_PHASES) / LEARN_PHASES, indexing="ij")
            self.sigma, self.amp, self.k, self.psi = s.ravel(), a.ravel(), k.ravel(), p.ravel()
            self.logw = -2.0 * np.log(self.k)
        elif kind == "rms":
            self.sigma = np.asarray(LEARN_SIGMAS, dtype=float)
            self.logw = np.zeros(len(self.sigma))
        elif kind in ("level", "local"):
            self.obs: list = []                        # local: (θ, log-likelihood per hypothesis) of every stop
            m, s = np.meshgrid(np.asarray(LEVEL_MEANS), np.asarray(LEVEL_SPREADS), indexing="ij")
            self.mu, self.sigma = m.ravel(), s.ravel()
            # the box's ripple factor at one position: a ~ U(0, 0.05) x sin(uniform phase), by sampling
            rng = np.random.default_rng(0)
            rr = 1.0 + rng.uniform(0, BOX_RIPPLE_MAX, 20000) * np.sin(rng.uniform(0, 2 * math.pi, 20000))
            edges = np.concatenate([[-np.inf], 0.5 * (np.asarray(LEVEL_MEANS)[1:] + np.asarray(LEVEL_MEANS)[:-1]), [np.inf]])
            pm = np.histogram(rr, edges)[0] / len(rr)
            self.logw = np.log(np.maximum(np.repeat(pm, len(LEVEL_SPREADS)), 1e-12))
        else:
            raise ValueError(kind)
        self.logw = self.logw - self.logw.max()

    @property
    def w(self) -> np.ndarray:
        w = np.exp(self.logw - self.logw.max())
        return w / w.sum()

    def weights(self, theta: float) -> np.ndarray:
        """The posterior weights that hold at ``theta`` (all kinds but ``local``: :attr:`w`, the same everywhere)."""
        if self.kind != "local":
            return self.w
        lw = self.logw.copy()
        for th, ll in self.obs:
            lw = lw + math.exp(-0.5 * ((theta - th) / LOCAL_WIDTH_RAD) ** 2) * ll
        w = np.exp(lw - lw.max())
        return w / w.sum()

    def ripple(self, theta: float) -> np.ndarray:
        """The ripple factor at ``theta`` of every hypothesis (``rms``: not one -- see :meth:`_components`)."""
        if self.kind == "learn":
            return 1.0 + self.amp * np.sin(2.0 * math.pi * self.k * (theta - self.theta0) + self.psi)
        if self.kind in ("level", "local"):
            return self.mu
        raise ValueError("rms: the ripple is a fresh box draw at each stop")

    def _interval_p(self, r, sigma, lo, hi) -> np.ndarray:
        """P(lo < x < hi) of the level x = (T_s r (1 + σ n) - T_c)/K, each bound known to ``soft`` rad rms."""
        out = np.ones(np.broadcast(r, sigma).shape)
        sn = K * self.soft / (TS * r * sigma)
        c = 1.0 / np.sqrt(1.0 + sn * sn)
        if hi is not None:
            out = _phi(((K * hi + TC) / (TS * r) - 1.0) / sigma * c)
        if lo is not None:
            out = out - _phi(((K * lo + TC) / (TS * r) - 1.0) / sigma * c)
        return np.maximum(out, 0.0)

    def observe(self, theta: float, lo: float | None, hi: float | None) -> None:
        """One stop's outcome at ``theta`` (rad): the level above ``lo`` and below ``hi`` (apex coordinates, rad)."""
        if lo is None and hi is None:
            return
        if self.kind == "rms":
            rs = np.asarray(BOX_RIPPLES)
            p = self._interval_p(rs[None, :], self.sigma[:, None], lo, hi).mean(axis=1)
        else:
            p = self._interval_p(self.ripple(theta), self.sigma, lo, hi)
        self.n_obs += 1
        if self.kind == "local":
            self.obs.append((float(theta), np.log(p + LEARN_OUTLIER)))
            return
        self.logw = self.logw + np.log(p + LEARN_OUTLIER)
        self.logw -= self.logw.max()

    def _components(self, theta: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(σ, ripple factor, weight) of the predictive's mixture at ``theta``."""
        w = self.weights(theta)
        if self.kind == "rms":
            rs = np.asarray(BOX_RIPPLES)
            return (np.repeat(self.sigma, len(rs)), np.tile(rs, len(self.sigma)),
                    np.repeat(w, len(rs)) / len(rs))
        r = self.ripple(theta)
        if self.kind in ("level", "local"):
            return self.sigma, r, w
        # bin the hypotheses' ripple factor here per σ: a mixture of (σ, r) components, r the bin's weighted mean
        nb = len(LEARN_R_BINS) - 1
        b = np.clip(np.searchsorted(LEARN_R_BINS, r) - 1, 0, nb - 1)
        si = np.searchsorted(np.asarray(LEARN_SIGMAS), self.sigma - 1e-12)
        idx = si * nb + b
        ws = np.bincount(idx, weights=w, minlength=len(LEARN_SIGMAS) * nb)
        wr = np.bincount(idx, weights=w * r, minlength=len(LEARN_SIGMAS) * nb)
        keep = ws > 1e-5 * ws.max()
        cs = np.repeat(np.asarray(LEARN_SIGMAS), nb)[keep]
        return cs, wr[keep] / ws[keep], ws[keep] / ws[keep].sum()

    def samples(self, theta: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(table excess x_t, apex coordinate x_p, weight) of the posterior predictive level law at ``theta``."""
        sig, r, wc = self._components(theta)
        n = np.linspace(-KN.SCATTER_CLIP, KN.SCATTER_CLIP, BOX_LEVELS)
        wn = np.exp(-0.5 * n * n)
        wn /= wn.sum()
        f = 1.0 + sig[:, None] * n[None, :]
        ts = np.maximum(TS * f * r[:, None], TC * r[:, None])
        xt = (ts - TC * r[:, None]) / K
        xp = (ts - TC) / K
        w = wc[:, None] * wn[None, :]
        return xt.ravel(), xp.ravel(), w.ravel() / w.sum()

    def summary(self, theta: float, row: dict) -> dict:
        """What the learner knows at ``theta`` against the run's truth ``row``: posterior means of σ (and a), the
        predictive ripple factor's mean / sd here and the true one."""
        w = self.weights(theta)
        out = {"n_obs": self.n_obs, "sigma_mean": float((w * self.sigma).sum()), "sigma_true": row["static_scatter"]}
        true_r = ripple_at(row, theta)
        out["r_true"] = true_r
        if self.kind != "rms":
            r = self.ripple(theta)
            mr = float((w * r).sum())
            out.update({"r_mean": mr, "r_sd": float(math.sqrt(max((w * (r - mr) ** 2).sum(), 0.0)))})
        if self.kind == "learn":
            out["amp_mean"] = float((w * self.amp).sum())
            out["amp_true"] = row["ripple"]
        return out


def _est_periods(pl: Plant, d: int, apex: float, rise: float, member: tuple) -> int:
    t = pl.truth()
    phi = t.motor_angle / N - t.valve_angle
    half = 1 if len(member) > 4 and member[4] > 0.0 else 0
    return PARK_PERIODS + 3 + int(math.ceil(abs(apex - d * rise - phi) / PARK_RATE_RAD)) + 1 + member[2] + half + SETTLE_PERIODS


def _apex(pl: Plant, row: dict, d: int, x: float, known_r: bool = False) -> tuple[float, float]:
    """(absolute apex twist rad, Coulomb level N*m) at ``x`` above the Coulomb twist toward ``d`` (the ripple's
    Coulomb level where it is known: ``known_r`` or the run's law, else the nominal one)."""
    th = pl.valve_angle
    tc = TC * ripple_at(row, th) if known_r or row.get("law", "run") == "run" else TC
    return (load_torque(th) + d * tc) / K + d * x, tc


def _oracle_single(pl: Plant, row: dict, table: Table, e: float, budget: int, d: int | None = None,
                   aim: float | None = None, count: int = ORACLE_CANDIDATES):
    """The ``count`` members / overdrives whose tabulated move at the true level now lands closest to
    ``aim`` (default: the error ``e``) toward ``d`` (default: toward the target), each tried on a copy of
    ``pl``: a list of (|e_new|, plant copy, periods), best first."""
    import copy
    d = (1 if e > 0 else -1) if d is None else d
    aim = abs(e) if aim is None else aim
    tc, ts = pl.valve_friction_levels()
    x = (ts - tc) / K
    pred = np.array([[table.move(d, m, x, od) for od in OVERDRIVE_GRID] for m in range(len(table.members))])
    miss = np.abs(aim - pred)
    miss[~np.isfinite(miss)] = np.inf
    out = []
    for flat in np.argsort(miss, axis=None)[:count]:
        m, j = np.unravel_index(flat, miss.shape)
        if not math.isfinite(miss[m, j]):
            break
        member, rise = table.members[m], table.rise[(d, m)]
        apex, tcr = _apex(pl, row, d, x + OVERDRIVE_GRID[j], known_r=True)
        if _est_periods(pl, d, apex, rise, member) > budget:
            continue
        trial = copy.deepcopy(pl)
        _, per = try_pulse(trial, d, apex, rise, member, tcr, table=False)
        out.append((abs(e - (trial.valve_angle - pl.valve_angle)), trial, per))
    return sorted(out, key=lambda c: c[0])


def choose_oracle(pl: Plant, row: dict, table: Table, e: float, budget: int):
    """Part 2(a): the member and overdrive that, at the true level now (the oracle reads the plant, and
    tries candidates on copies of it), leave the smallest |error|.  Where no single pulse improves |e|
    (the level drawn here is too high for this error: every move overshoots by more than |e|), two-pulse
    plans: a first move past the target or away from it (a new stop: a new draw, which the oracle also
    knows) and the best second.  Returns (|e_new|, plant, periods) of the first pulse of the best plan, or
    None when nothing improves |e| within the budget."""
    best = _oracle_single(pl, row, table, e, budget)
    if best and best[0][0] < abs(e) - 1e-5:
        return best[0]
    plans = []
    d = 1 if e > 0 else -1
    for way, aims in ((d, (abs(e) + 3e-4, abs(e) + 6e-4, abs(e) + 1e-3, abs(e) + 1.5e-3)),
                      (-d, (3e-4, 6e-4, 1e-3, 1.5e-3))):
        for aim in aims:
            for first in _oracle_single(pl, row, table, e, budget, d=way, aim=aim, count=2):
                e1 = e - (first[1].valve_angle - pl.valve_angle)
                if abs(e1) < 1e-7:
                    continue
                second = _oracle_single(first[1], row, table, e1, budget - first[2], count=4)
                if second and second[0][0] < abs(e) - 1e-5:
                    plans.append((second[0][0], first))
    if not plans:
        return None
    return min(plans, key=lambda p: p[0])[1]


def _fresh_moves(row: dict, table: Table, d: int, theta: float):
    """(x_t [k], x_p [k], weights [k], apexes xa [a], moves [m, a, k]) of a fresh stop's law toward ``d``
    (:func:`law_samples`; the apex candidates: the law's points, or for the box law 30 of its quantiles)."""
    xt, xp, w = law_samples(row, theta)
    if row.get("law", "run") == "run":
        base = xp
    else:
        order = np.argsort(xp)
        cum = np.cumsum(w[order])
        base = xp[order][np.minimum(np.searchsorted(cum, np.linspace(0.005, 0.995, 30)), len(xp) - 1)]
    xa = np.unique(np.concatenate([base + 1e-5, [xp.max() + 2e-4, xp.max() + 5e-4]]))
    od = xa[None, :] - xp[:, None]                     # [k, a]
    moves = np.swapaxes(table.move_all(d, np.broadcast_to(xt[:, None], od.shape), od), 1, 2)
    return xt, xp, w, xa, moves


def continuation(row: dict, table: Table, theta: float, stop_tol: float, errors: np.ndarray) -> np.ndarray:
    """The best chance one fresh try (a new stop: the law's full prior) lands within ``stop_tol`` from each
    signed error in ``errors`` (rad): the value the distribution-aware policy gives a move that misses."""
    out = np.zeros(len(errors))
    for d in (1, -1):
        _, _, w, xa, moves = _fresh_moves(row, table, d, theta)
        mv = np.nan_to_num(moves, nan=1.0)
        for i, e in enumerate(errors):
            if (1 if e > 0 else -1) != d:
                continue
            if abs(e) <= stop_tol:
                out[i] = 1.0
                continue
            out[i] = float(((np.abs(abs(e) - mv) <= stop_tol) & (moves > 1e-7)).astype(float).dot(w).max())
    return out


def choose_bayes(pl: Plant, row: dict, table: Table, e: float, floor_x: float | None, budget: int,
                 stop_tol: float, cont: tuple | None = None):
    """Part 2(b): the member and apex maximising the chance to end within ``stop_tol``: P(land within it)
    + P(no move) x (the best landing chance of the next try on the posterior that no move leaves) + the
    misses' chance from where they leave the valve (``cont``: (errors, values) of :func:`continuation`,
    a fresh draw there), the level's law truncated at ``floor_x`` (the highest apex that did not move it).
    The later terms count only when the budget leaves time for another try (a reversal's park included)."""
    d = 1 if e > 0 else -1
    _, x, w0, xa, moves = _fresh_moves(row, table, d, pl.valve_angle)   # x: the apex coordinate x_p
    mems, rises = table.members, [table.rise[(d, m)] for m in range(len(table.members))]
    if table.lead_rule:
        # main's final twist phi_e + e/2: the lead is the error's half, not a choice
        moves, mems, rises = table.at_lead(d, moves, abs(e) / 2.0)
    w = w0
    if floor_x is not None:
        w = np.where(x >= floor_x, w, 0.0)
        if w.sum() <= 0.0:
            w = np.where(x == x.max(), 1.0, 0.0)
        w = w / w.sum()
    nm = len(mems)
    moved = (xa[None, :] > x[:, None]).T[None, :, :]  # [1, a, k]
    fin = np.isfinite(moves)
    mv = np.nan_to_num(moves, nan=1.0)
    e_new = abs(e) - mv                                # toward the target positive, [m, a, k]
    hit = moved & fin & (np.abs(e_new) <= stop_tol)
    p_hit = (hit * w).sum(axis=2)                      # [m, a]
    p_none = ((~moved[0]) * w).sum(axis=1)             # [a]
    mean_after = (np.where(moved, np.where(fin, np.abs(e_new), 1.0), abs(e)) * w).sum(axis=2)
    p_better = ((~moved | (fin & (np.abs(e_new) < abs(e)))) * w).sum(axis=2)
    # one step ahead: after no move at apex a the level lies above xa[a]
    trunc = np.where(x[None, :] >= xa[:, None], w[None, :], 0.0)
    tot = trunc.sum(axis=1, keepdims=True)
    trunc = np.divide(trunc, tot, out=np.zeros_like(trunc), where=tot > 0)
    v1 = (hit.reshape(nm * len(xa), -1).astype(float) @ trunc.T).max(axis=0)   # [a]
    p_miss_value = np.zeros_like(p_hit)
    if cont is not None:
        errs, vals = cont
        vmiss = np.interp(d * e_new, errs, vals)       # signed error left, toward the original direction
        p_miss_value = (np.where(moved & fin & ~hit, vmiss, 0.0) * w).sum(axis=2)
    best = None
    for m in range(nm):
        member, rise = mems[m], rises[m]
        rank = p_hit[m] + p_none * v1 + p_miss_value[m]
        if floor_x is not None:
            rank = np.where(xa > floor_x, rank, -np.inf)   # apexes at or below the floor: the same no move again
        for a in np.argsort(-rank)[:3]:
            if not math.isfinite(rank[a]):
                break
            apex, _ = _apex(pl, row, d, xa[a])
            per = _est_periods(pl, d, apex, rise, member)
            if per > budget:
                continue
            left = budget - per
            more = left >= PARK_PERIODS + 3 + 2 + 1 + SETTLE_PERIODS + 3
            again = left >= PARK_PERIODS + 3 + 2 + 1 + SETTLE_PERIODS + 3 + int(2 * TS / K / PARK_RATE_RAD)
            score = p_hit[m, a] + (p_none[a] * v1[a] if more else 0.0) + (p_miss_value[m, a] if again else 0.0)
            if score <= 0.0 or (not more and mean_after[m, a] >= abs(e)):
                continue
            if cont is None and p_better[m, a] <= 0.5:
                continue                               # without a value for misses: no try that more likely worsens |e|
            if best is None or score > best[0]:
                best = (score, m, xa[a], member, rise)
    return best


def run_stop(job: tuple) -> dict:
    """Replay one engage sample under ``policy`` ('oracle', 'bayes' or 'none'); the final |error| and tries.
    ``job`` = (row, policy, table, stop_tol, miss_value[, realism]); ``realism`` (None: true states) is the
    distribution-aware policies' measurement model, a dict with ``apex_rms`` (rad): the policy reads the valve
    through its resolver (quantised, the plant's noise) once the valve rests, judges a try moved only when that
    reading changed by :data:`MOVED_RAD`, its apex lands off the plan by a seeded zero-mean normal of that rms, and
    an unmoved try truncates the level's law at the apex it *measured* (the motor resolver / N minus the valve
    resolver, once a period: the highest since the last move), not at the apex it planned."""
    row, policy, table, stop_tol, miss_value = job[:5]
    realism = job[5] if len(job) > 5 else None
    #: (h34r) a :class:`LevelLearner` carried across the run's plateaus: its predictive is the level's law, and every
    #: stop's outcome (the interval its tries left the level in) updates it once the stop ends -- within a stop the
    #: law is truncated by its unmoved apexes as for the other policies, which is the same Bayes update, made once
    learner = job[6] if len(job) > 6 else None
    law = "learn" if policy in LEARN_POLICIES else "box" if policy == "bayes_box" else "run"
    row = {**row, "law": law, **({"_learner": learner} if learner is not None else {})}
    pl = stop_plant(row)
    target = pl.valve_angle + row["error_rad"]
    budget = int(round(row["budget_s"] / PERIOD))
    floor_x, tries, moves, spent, log = None, 0, 0, 0, []
    real = realism is not None and policy.startswith("bayes")
    rng = np.random.default_rng([row["seed"], int(round(abs(row["theta_rad"]) * 1e6)), 82]) if real else None

    def read() -> float:
        if not real:
            return pl.valve_angle
        r = pl.resolver()
        return pl.valve_angle if r is None else r.valve_rad

    cont = None
    if policy.startswith("bayes") and miss_value:
        errs = np.linspace(-4e-3, 4e-3, 81)
        cont = (errs, continuation(row, table, pl.valve_angle, stop_tol, errs))
    stop_theta = None                                  # (h34r) where the stop the learner will be told of is
    while policy != "none":
        th_m = read()
        e = target - th_m
        if abs(e) <= stop_tol:
            break
        if stop_theta is None:
            stop_theta = th_m                          # the stop's first reading (no extra resolver read: its noise)
        d = 1 if e > 0 else -1
        if policy == "oracle":
            got = choose_oracle(pl, row, table, e, budget - spent)
            if got is None:
                break
            _, pl_new, per = got
            moved = abs(pl_new.valve_angle - pl.valve_angle) > 1e-7
            log.append({"e": e, "move": pl_new.valve_angle - pl.valve_angle})
            pl = pl_new
        else:
            got = choose_bayes(pl, row, table, e, floor_x, budget - spent, stop_tol, cont)
            if got is None:
                break
            _, m, xa, member, rise = got
            apex, tcr = _apex(pl, row, d, xa)
            before = pl.valve_angle
            if real:
                seen: dict = {}
                # the apex is placed in the policy's coordinates, the twist as the resolvers show it: the truth
                # differs by the reading's offset at this stop (the valve count's quantisation, both noises) and
                # the servo's park error
                r = pl.resolver()
                offset = 0.0 if r is None else (r.motor_rad / N - r.valve_rad) - (pl.truth().motor_angle / N - before)
                err = float(rng.normal(0.0, realism["apex_rms"]))
                _, per = try_pulse(pl, d, apex - offset + err, rise, member, tcr, table=False, seen=seen)
                seen_move = read() - th_m
                moved_seen = abs(seen_move) >= MOVED_RAD
                if moved_seen:
                    if learner is not None:
                        learner.observe(stop_theta, floor_x, float(xa))
                    stop_theta = None
                    floor_x = None
                elif seen.get("peak") is not None:
                    # the apex the resolvers showed, in the law's coordinate (above the Coulomb twist toward d); with
                    # floor 'park': the twist they showed at the park's end plus the member's calibrated rise
                    # (plan: the higher of the measured peak and the apex planned -- the sampled peak misses the kick's
                    # apex between two samples, and the same apex was tried again and again)
                    how = realism.get("floor", "peak")
                    top = seen["peak"] if how in ("peak", "plan") else seen["park"] + d * rise
                    x_seen = d * (top - (load_torque(th_m) + d * tcr) / K)
                    if how == "plan":
                        x_seen = max(x_seen, xa)
                    floor_x = x_seen if floor_x is None else max(floor_x, x_seen)
                log.append({"e": e, "member": member, "apex_excess": xa, "apex_error": err - offset,
                            "floor": floor_x, "move": pl.valve_angle - before, "move_seen": seen_move})
            else:
                _, per = try_pulse(pl, d, apex, rise, member, tcr, table=False)
                if learner is not None and abs(pl.valve_angle - before) > 1e-7:
                    learner.observe(stop_theta, floor_x, float(xa))
                if abs(pl.valve_angle - before) > 1e-7:
                    stop_theta = None
                floor_x = None if abs(pl.valve_angle - before) > 1e-7 else xa
                log.append({"e": e, "member": member, "apex_excess": xa, "move": pl.valve_angle - before})
            moved = abs(pl.valve_angle - before) > 1e-7
        tries += 1
        moves += moved
        spent += per
        if spent >= budget:
            break
    if learner is not None and floor_x is not None and stop_theta is not None:
        learner.observe(stop_theta, floor_x, None)    # the plateau ends on a stop whose level lies above its tries
    return {"seed": row["seed"], "policy": policy, "start_error_rad": row["error_rad"],
            "final_error_rad": float(abs(target - pl.valve_angle)), "tries": tries, "moves": int(moves),
            "spent_s": spent * PERIOD, "budget_s": row["budget_s"], "main_final_error_rad": row["final_error_rad"], "log": log}


class _Frozen:
    """A learner's prior that no outcome updates (``--learn-scope none``: the learning policies' control)."""

    def __init__(self, learner: "LevelLearner"):
        self.learner = learner

    def samples(self, theta: float):
        return self.learner.samples(theta)

    def observe(self, theta, lo, hi) -> None:
        pass


def run_run(job: tuple) -> list[dict]:
    """(h34r) One run's plateaus in order under a learning policy (:data:`LEARN_POLICIES`): a :class:`LevelLearner`
    of the box's law as the prior, carried from plateau to plateau.  ``job`` = (rows of one run in order, policy,
    table, stop_tol, miss_value, realism); each stop's result gains ``index`` (the plateau's place in the run, 0..)
    and ``learned`` (:meth:`LevelLearner.summary` at the plateau's engage angle before it starts)."""
    rows, policy, table, stop_tol, miss_value, realism = job[:6]
    scope = job[6] if len(job) > 6 else "run"
    soft = LEARN_SOFT_RAD
    if realism is not None:
        # an apex planned in measured coordinates: the park's error, the valve count's quantisation
        soft = math.sqrt(LEARN_SOFT_RAD ** 2 + realism["apex_rms"] ** 2 + LSB_RAD ** 2 / 12.0)
    learner = LevelLearner(LEARN_KIND[policy], rows[0]["theta_rad"], soft)
    out = []
    for i, row in enumerate(rows):
        if scope == "plateau" and i > 0:
            # the control that forgets at every plateau: within-plateau learning only
            learner = LevelLearner(LEARN_KIND[policy], rows[0]["theta_rad"], soft)
        known = learner.summary(row["theta_rad"], row)
        told = _Frozen(learner) if scope == "none" else learner      # none: the prior, never told
        res = run_stop((row, policy, table, stop_tol, miss_value, realism, told))
        res.update({"index": i, "learned": known})
        out.append(res)
    return out


# ------------------------------------------------------------------------------------------ reports
def move_distribution(table: Table, sigma: float, d: int = 1) -> list[dict]:
    """Part 1: per wanted size, the member and preload (apex as a fraction of the mean static excess) that
    maximise P(|move - wanted| <= 5e-4) over the scatter's law (rms ``sigma``, no ripple): that chance,
    P(no move), and the mean / sd of the moves that happen."""
    x, w = level_prior(sigma, 1.0)
    mean_x = float((x * w).sum())
    fractions = np.linspace(0.5, 2.0, 31)              # apex excess / mean excess
    out = []
    for wanted in WANTED:
        best = None
        for m in range(len(table.members)):
            for fr in fractions:
                od = fr * mean_x - x
                mv = table.move(d, m, x, od)
                ok = np.isfinite(mv)                   # NaN: the park alone breaks these draws loose -- a move of
                moved = od > 0.0                       # a size this table does not know, counted a miss
                p_hit = float((w * (moved & ok & (np.abs(np.nan_to_num(mv, nan=1.0) - wanted) <= TOL_TARGET))).sum())
                if best is None or p_hit > best["p_within_5e-4"]:
                    pm = float((w * moved).sum())
                    wk = w * (moved & ok)               # mean / sd of the moves of known size
                    pk = float(wk.sum())
                    mvk = np.nan_to_num(mv)
                    mu = float((wk * mvk).sum() / pk) if pk > 0 else math.nan
                    sd = float(math.sqrt(max((wk * (mvk - mu) ** 2).sum() / pk, 0.0))) if pk > 0 else math.nan
                    best = {"wanted_rad": wanted, "p_within_5e-4": p_hit, "p_no_move": 1.0 - pm, "mean_rad": mu,
                            "sd_rad": sd, "member": table.members[m], "apex_fraction": round(float(fr), 3)}
        out.append(best)
    return out


def smallest_moves(table: Table, d: int) -> list[dict]:
    """The smallest move of any member just past the level (overdrive 1e-5 rad), per excess twist."""
    out = []
    for i, x in enumerate(EXCESS_GRID):
        mv = table.moves[d][:, i, 0]
        mv = mv[np.isfinite(mv) & (mv > 1e-7)]
        out.append({"excess_rad": x, "smallest_move_rad": float(mv.min()) if len(mv) else None})
    return out


def stats(v) -> dict:
    v = np.asarray(v, dtype=float)
    return {"n": int(len(v)), "median": float(np.median(v)), "p95": float(np.percentile(v, 95)), "max": float(v.max()),
            "over_5e-4": float(np.mean(v > TOL_TARGET)), "over_8e-4": float(np.mean(v > TOL_MAX))}


_TABLE: Table | None = None


def _init(table: Table) -> None:
    global _TABLE
    _TABLE = table


def _run_stop_global(job: tuple):
    row, policy, stop_tol, miss_value = job[:4]
    if policy in LEARN_POLICIES:                       # row: the run's rows in order
        return run_run((row, policy, _TABLE, stop_tol, miss_value) + tuple(job[4:]))
    return run_stop((row, policy, _TABLE, stop_tol, miss_value) + tuple(job[4:]))


def _plateau_index(rows: list[dict]) -> list[int]:
    """Each engage row's place in its run (0..): the rows are in the run's order, runs one after another."""
    out, last, i = [], None, 0
    for r in rows:
        i = i + 1 if r["seed"] == last else 0
        last = r["seed"]
        out.append(i)
    return out


def learning_curve(stops: list[dict], policy: str, index: list[int] | None = None) -> list[dict]:
    """(h34r) p95 / > 5e-4 count of ``policy``'s final errors by the plateau's place in its run (1-based)."""
    sel = [s for s in stops if s["policy"] == policy]
    idx = [s["index"] for s in sel] if index is None else index
    out = []
    for i in sorted(set(idx)):
        v = np.array([s["final_error_rad"] for s, j in zip(sel, idx) if j == i])
        out.append({"plateau": i + 1, "n": int(len(v)), "p95": float(np.percentile(v, 95)),
                    "over_5e-4": int((v > TOL_TARGET).sum()), "median": float(np.median(v))})
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="worker processes (default: CPUs)")
    ap.add_argument("--runs", type=int, default=40, help="nominal-box runs of main's engage sample (default 40)")
    ap.add_argument("--seed", type=int, default=1000, help="seed of the first run (default 1000)")
    ap.add_argument("--engage", metavar="PATH", help="read the engage sample here (written there if missing)")
    ap.add_argument("--stop-tol", type=float, default=4e-4, help="rad: the policies stop within this (default 4e-4)")
    ap.add_argument("--miss-value", action="store_true", help="(b) values a move that misses by a fresh try's "
                    "chance from where it leaves the valve (measured worse: the table's bare-plant moves are optimistic "
                    "for the large moves it then gambles on); default: only landings and no-moves count")
    ap.add_argument("--policies", default=",".join(POLICIES), help=f"comma list of {', '.join(POLICIES + LEARN_POLICIES)} (default: "
                    f"{', '.join(POLICIES)}; the learning ones (h34r) carry a learner across each run's plateaus)")
    ap.add_argument("--family", choices=FAMILIES, default="full", help="the pulses the policies choose from (default "
                    "full: the 128-member grid; main: main's doublet only, 4 A kick, whole / half retreat, final twist "
                    "phi_e + e/2; kicks: the same with a 4, 8 or 16 A kick; strong: 16 A kick, two periods at the cap; "
                    "deep: that retreat with a 4, 8 or 16 A kick; kicks2: kicks with two whole retreat periods; deep4: deep with "
                    "main's kick only)")
    ap.add_argument("--realism", action="store_true", help="the distribution-aware policies read the valve and the "
                    "twist through the resolvers, their apex lands off the plan (--apex-rms), and an unmoved try "
                    "truncates the level's law at the measured apex (default: true states)")
    ap.add_argument("--apex-rms", type=float, default=APEX_RMS_RAD, help=f"rad: with --realism, the apex's "
                    f"realisation error, a seeded zero-mean normal of this rms (default {APEX_RMS_RAD:g})")
    ap.add_argument("--learn-scope", choices=("run", "plateau", "none"), default="run", help="the learning policies' "
                    "learner: carried across the run's plateaus (run, default), forgotten at every plateau (plateau: "
                    "within-plateau learning only), or its prior never updated (none: the control)")
    ap.add_argument("--json", metavar="PATH", help="also write the JSON with every stop here")
    ap.add_argument("--markdown", metavar="PATH", help="also write the tables here")
    ap.add_argument("--floor", choices=("peak", "park", "plan"), default="peak", help="with --realism, the apex an unmoved "
                    "try truncates the level's law at: peak = the highest twist the resolvers showed (once a period: "
                    "the kick's apex falls between samples), park = the twist they showed at the park's end + the "
                    "member's calibrated rise, plan = the higher of peak and the apex the policy planned (default peak)")
    a = ap.parse_args(argv)
    if a.miss_value and a.family != "full":
        ap.error("--miss-value needs --family full (its continuation chooses the lead)")
    extra = a.family != "full" or a.realism           # the default invocation's output stays as it was
    realism = {"apex_rms": a.apex_rms, "floor": a.floor} if a.realism else None
    t0 = time.perf_counter()
    if a.engage and Path(a.engage).exists():
        rows = json.loads(Path(a.engage).read_text())
    else:
        rows = engage_sample(range(a.seed, a.seed + a.runs), a.jobs)
        if a.engage:
            Path(a.engage).write_text(json.dumps(rows) + "\n")
    t1 = time.perf_counter()
    table = pulse_table(a.jobs, a.family)
    t2 = time.perf_counter()
    pols = [p for p in POLICIES + LEARN_POLICIES if p in a.policies.split(",")]
    learn = any(p in LEARN_POLICIES for p in pols)
    runs: dict = {}
    for r in rows:
        runs.setdefault(r["seed"], []).append(r)
    # the learning policies take a run's plateaus in order as one job (the learner is carried across them)
    jobs = [((r, pol, a.stop_tol, a.miss_value) + ((realism,) if realism else ())) for pol in pols if pol not in LEARN_POLICIES
            for r in rows]
    jobs += [(rr, pol, a.stop_tol, a.miss_value, realism, a.learn_scope) for pol in pols if pol in LEARN_POLICIES
             for rr in runs.values()]
    if a.jobs > 1:
        with Pool(a.jobs, initializer=_init, initargs=(table,)) as pool:
            got = pool.map(_run_stop_global, jobs, chunksize=1 if learn else 8)
    else:
        _init(table)
        got = [_run_stop_global(j) for j in jobs]
    stops = [s for g in got for s in (g if isinstance(g, list) else [g])]
    if learn:
        index = _plateau_index(rows)
        for pol in pols:
            if pol not in LEARN_POLICIES:
                for s, i in zip([s for s in stops if s["policy"] == pol], index):
                    s["index"] = i
    t3 = time.perf_counter()
    main_final = [r["final_error_rad"] for r in rows]
    start = [abs(r["error_rad"]) for r in rows]
    bounds = {"main": stats(main_final), "start": stats(start)}
    for pol in pols:
        bounds[pol] = stats([s["final_error_rad"] for s in stops if s["policy"] == pol])
        bounds[pol]["tries_mean"] = float(np.mean([s["tries"] for s in stops if s["policy"] == pol]))
        if extra:
            bounds[pol]["moves_mean"] = float(np.mean([s["moves"] for s in stops if s["policy"] == pol]))
    dist = {f"{sig:g}": move_distribution(table, sig) for sig in (0.02, 0.05, 0.08)}
    small = {d: smallest_moves(table, d) for d in (1, -1)}
    lines = [f"### plateau floor: {len(rows)} nominal plateaus (seeds {a.seed}..{a.seed + a.runs - 1}), "
             f"stop tolerance {a.stop_tol:g} rad" + (f", family {a.family}" + (f", realism (apex rms {a.apex_rms:g} rad, floor {a.floor})"
                                                                          if a.realism else "") if extra else ""), "",
             "| final plateau error | median | p95 | max | > 5e-4 | > 8e-4 | tries / plateau |", "|---|---|---|---|---|---|---|"]
    for key, name in (("start", "start (main's at the policies' take-over)"), ("main", "main (a3beb09)"),
                      ("oracle", "(a) oracle (knows each stop's level)"),
                      ("bayes", "(b) distribution-aware, knows the run's law (scatter rms, ripple map)"),
                      ("bayes_box", "(b') distribution-aware, knows only the box's law"),
                      ("bayes_learn", "(c) learns the run's law (rms, ripple) from its tries"),
                      ("bayes_rms", "(c-rms) learns the scatter rms only"),
                      ("bayes_level", "(c-level) learns one position-free level"),
                      ("bayes_local", "(c-local) learns a kernel (position-binned) level map")):
        if key not in bounds:
            continue
        b = bounds[key]
        lines.append(f"| {name} | {b['median']:.3g} | {b['p95']:.3g} | {b['max']:.3g} | {100 * b['over_5e-4']:.1f} % | "
                     f"{100 * b['over_8e-4']:.1f} % | {b.get('tries_mean', float('nan')):.2f} |"
                     + (f" moves / plateau {b['moves_mean']:.2f}" if "moves_mean" in b else ""))
    curves = {}
    if learn:
        curves = {pol: learning_curve(stops, pol) for pol in pols}
        lines += ["", "learning curve: p95 of the final error (rad) by the plateau's place in its run "
                  "(> 5e-4 count in brackets):", "",
                  "| policy | " + " | ".join(str(c["plateau"]) for c in curves[pols[0]]) + " |",
                  "|---|" + "---|" * len(curves[pols[0]])]
        for pol in pols:
            lines.append(f"| {pol} | " + " | ".join(f"{c['p95'] * 1e4:.2f}e-4 ({c['over_5e-4']})" for c in curves[pol]) + " |")
    lines += ["", "smallest move of any member just past the level (overdrive 1e-5 rad), rad:", "",
              "| excess twist (T_s - T_c)/K | " + " | ".join(f"{r['excess_rad'] * 1e3:.2f}e-3" for r in small[1][::3]) + " |",
              "|---|" + "---|" * len(small[1][::3])]
    for d, name in ((1, "opening"), (-1, "closing")):
        lines.append(f"| {name} | " + " | ".join("—" if r["smallest_move_rad"] is None else f"{r['smallest_move_rad']:.2e}"
                                               for r in small[d][::3]) + " |")
    for sig, rowsd in dist.items():
        lines += ["", f"one pulse over the scatter's law (rms {sig}, opening, best member and preload per wanted size):", "",
                  "| wanted rad | P(within ±5e-4) | P(no move) | mean move | sd | member (A, R, n_r, g) | apex / mean excess |",
                  "|---|---|---|---|---|---|---|"]
        for r in rowsd:
            lines.append(f"| {r['wanted_rad']:.1e} | {r['p_within_5e-4']:.2f} | {r['p_no_move']:.2f} | {r['mean_rad']:.2e} | "
                         f"{r['sd_rad']:.2e} | {r['member']} | {r['apex_fraction']} |")
    lines += ["", f"_engage sample {t1 - t0:.0f} s, table {t2 - t1:.0f} s, policies {t3 - t2:.0f} s with {a.jobs} job(s)_"]
    md = "\n".join(lines)
    print(md)
    if a.markdown:
        Path(a.markdown).write_text(md + "\n")
    doc = {"runs": a.runs, "seed": a.seed, "stop_tol_rad": a.stop_tol, "miss_value": a.miss_value, "plateaus": len(rows), "bounds": bounds,
           "move_distribution": dist, "smallest_moves": {str(d): v for d, v in small.items()},
           "family": FAMILY, "wall_time_s": round(t3 - t0, 1)}
    if extra:
        doc.update({"pulse_family": a.family, "members": table.members, "realism": realism})
    if learn:
        doc["learning_curve"] = curves
    if a.json:
        Path(a.json).write_text(json.dumps({**doc, "stops": stops, "engage": rows}, indent=1, default=str) + "\n")
    print(json.dumps(doc, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
