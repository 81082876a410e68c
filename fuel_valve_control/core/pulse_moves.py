"""A plant-free model of the fine stage's torque doublet: how far the valve moves (issue 14, Deliver 1).

:class:`PulseMoves` answers, from the controller's own :class:`~fuel_valve_control.core.model.NominalModel`,
the question ``benchmarks/plateau_floor.py`` tabulates on the simulated plant (docs §75, §80): the valve's
move for one doublet of :class:`~fuel_valve_control.core.fine_positioning.FinePositioner` whose twist *apex*
lies ``overdrive`` above the valve's static level, that level lying ``excess`` above the Coulomb-equilibrium
twist.  It is built for a pulse policy that places the apex where the chance to land within tolerance is
best given the distribution of the level drawn at each stop.

Sign conventions and units
--------------------------
* ``direction`` d = +1 opens (the valve angle grows), -1 closes.  Every twist, excess, overdrive, aim and move
  argument or result is a magnitude *toward* ``d`` (rad at the valve; twist = gear-output angle - valve angle).
* ``excess`` x >= 0: the static level's twist ``(load + d T_s) / K`` lies ``d x`` beyond the Coulomb-equilibrium
  twist ``φe = (load + d T_c(Δp)) / K`` (``T_s = T_c + K x``): the per-stop draw of the level, in rad.
* ``overdrive``: the apex less the static level's twist.  The apex is the largest *coupling torque over K*
  (the twist plus its damping's share ``c (ω1 - ωL) / K``: what meets the valve's static level) the doublet
  reaches on a valve that stays stuck: the preload plus :meth:`PulseMoves.rise`.  <= 0: the kick does not
  break the valve loose (exact in the model).  The twist alone -- what the resolvers show -- peaks ~1.3e-5 rad
  lower (its rate is not quite 0 at the apex).
* ``aim``: the error the stage asks the doublet to close; its observe servo then pulls the gear output to
  the final twist ``φe + d aim / 2`` measured from the valve angle the doublet started at
  (:meth:`FinePositioner._start_pulse`: ``final = φe + aim / 2``).  **The move depends on it**, so
  :meth:`PulseMoves.move` takes it (``aim_rad``, default 0): up to an aim that grows with the excess the move
  does not depend on it at all (bare plant: equal to 1e-9 rad); beyond it the servo's rebound breaks the valve
  loose a second time, a whole further jump (a sharp step: 0.23 -> 2.04e-3 rad between aims 1.0 and 1.2e-3 at
  excess 1e-3, apex 2e-5 over) -- the model answers NaN there, as it does where the rebound breaks a valve the
  kick did not (levels within ~0.6e-3 rad of the Coulomb equilibrium, or large aims).  At small excesses
  (< ~0.6e-3 rad) the servo drags the valve on instead, a move growing smoothly with the aim (tabulated).

What is simulated (one vectorised time loop over every grid point at once)
--------------------------------------------------------------------------
The equations live in :mod:`~fuel_valve_control.core.drivetrain_step` (task h41k, docs §109: one source run on numpy
lanes here and on float lanes by :meth:`PulseMoves.trough_fast`).
Two masses at the gear output (motor ``J1 = Jm N²`` with its viscous term and its Coulomb / static
friction, stick-slip as the plant integrates it; the valve ``JL`` with its viscous term, the spring +
flow load ``model.load_torque`` at the moving valve angle, and stick-slip at ``T_c(Δp)`` sliding /
``T_c + K x`` static), the coupling ``K``, ``c``; the drive's q-axis current loop (decoupled PI of bandwidth
``current_bandwidth_hz`` cancelling the R-L pole, voltage limited to the SVPWM circle ``V_dc / √3`` with the
back-EMF, conditional integration: the retreat's 30 A reversal slews at up to ~60 A/ms at 28 V, so it takes
half a period).  Substeps of ``period / substeps`` (20 = the plant's 20 kHz; 10 gave 1.8e-4 rad median error
against 40).  The controller's torque per 1 kHz period (zero-order hold): the doublet as
:meth:`FinePositioner._doublet_torque` commands it on the hold torque ``K φp / N`` (+ d x the motor's Coulomb
friction, ``park_friction``: the park climbed to the preload, and the stuck motor's reaction holds what the
servo carried), one period of kick ``+ d kick``, ``fine.retreat_full_periods`` of ``hold - d cap``, one of
``hold - d cap / 2``, each capped at ``± cap``; then the stage's observe servo (:meth:`FinePositioner._servo`:
feed-forward ``K (θ1_ref - θL) / N``, PD ``kp, kd`` on the gear output sampled once a period with a
backward-difference speed, integral ``ki`` from 0) toward ``θ1_ref = θL0 + φe + d aim / 2`` for
``observe_periods`` periods; the move is the valve's displacement at the end.

Not modelled (the caller's business or small): resolver quantisation, noise and the 50 µs delay; the
servo's integral and feed-forward error carried from the park (the hold is as above, the integral starts at
0); the park's own motion (the model starts at rest); backlash; LuGre and the Stribeck drop (the nominal
valve has none); the static level's new draw when the valve stops (the model's valve re-sticks at the same
level: a second breakaway's size is the bare valve's -- hence NaN); the levels' position ripple over the move;
the told model's errors (friction scale, Δp, inertia: ``for_positioner`` takes the stage's planning model).
Keyed tables and preparing them (docs §80.9)
--------------------------------------------
By default the tables are keyed on a fixed grid -- direction x ``DP_GRID`` (Δp) x ``ANGLE_GRID`` (valve angle) x kick
current -- and :meth:`PulseMoves.move` / :meth:`PulseMoves.rise` interpolate between the grid's neighbours of the asked
Δp and angle (on grids normalised by each Δp's friction levels): the Δp and the angle are *approximated*, and the
set of tables is finite, so :meth:`PulseMoves.prepare` can build all of them ahead.  **A real-time caller (the ROS
controller node) must call ``prepare()`` at configure / activate, outside its control callback** (a table costs
~0.12 s of CPU; the default grid 114 tables, ~14 s); afterwards ``prepared`` is True and no call simulates anything
(``move`` on a 61 x 40 array ~0.2 ms).  Offline the tables are built lazily on first use (a nominal-box run, max Δp:
6 tables).  ``exact=True`` keeps h33m's per-key tables (Δp to 1e-3 kPa, angle to 0.01 rad): the reference the keyed
grid's error is measured against (``benchmarks/pulse_moves_check.py --grid``).

The disk cache and the background build (task h36b)
----------------------------------------------------
C1's kicks to 16 A read 342 tables (~41 s of CPU): too long for a node's configure.  Each keyed table can be saved to
and read from a cache directory (:meth:`PulseMoves.save_table`, :meth:`PulseMoves.read_cached`: one ``.npz`` per key,
~130 kB, under a directory named by :meth:`PulseMoves.signature_hash` -- the model, every setting, :data:`TABLE_VERSION`
and the source of :data:`SOURCE_FILES`; written atomically; a partial, corrupt or foreign file is built again, never
raised), and :class:`TableBuild` makes a set of keys ready off the caller's thread: it reads what the cache has and
builds the rest in a separate low-priority process (``nice 19``) that writes the cache.  Read back, a table equals the
one built in the process bit for bit.  The ROS controller node uses it (its fine stage runs main's staircase until the
tables are in, :meth:`FinePositioner.defer_tables`); offline nothing touches the disk (lazy builds, as before).

Validation (docs §80): bare nominal plant, 300 random points, 99.3 % within max(10 %, 1e-4 rad), p95 1.6e-4,
max 3.9e-4 rad, rise to 1e-8 rad; the stage's own 2310 doublets on the nominal box (40 runs): rise -2..-3 %,
no break misclassified beyond the rise's error, moves within +0.02 (median) / 0.07 (p90 |err|) e-3 rad.
"""
from __future__ import annotations

import hashlib
import math
import os
import tempfile
import threading
import time
from collections import OrderedDict
from pathlib import Path

import numpy as np

from .drivetrain_step import ARRAYS, FLOATS, Doublet
from .model import NominalModel
from .params import CONTROLLER_SPEC

#: the drive's current-loop bandwidth when the caller gives none (``drive.current_loop_bandwidth_hz``'s default)
DEFAULT_BANDWIDTH = CONTROLLER_SPEC.defaults()["drive.current_loop_bandwidth_hz"]

#: a step of the tabulated move between neighbouring aims larger than this many aim spacings is the observe
#: servo's second breakaway (a whole further jump, docs §80): :meth:`PulseMoves.move` takes the nearer aim's move
#: there instead of a blend of the two regimes (the dragged regime grows ~1 rad of move per rad of aim)
AIM_STEP_JUMPS = 3.0
#: the second breakaway's aim is refined between the two tabulated aims to 1 / 2**this of their spacing (one run)
THRESHOLD_BISECTIONS = 3
#: the Δp points (fractions of ``model.pressure_max_kpa``) the keyed tables are built at; a move between them is
#: interpolated linearly in Δp on the grids normalised by that Δp's friction levels (docs §80.9: error measured)
#: (dense below 0.4: there the doublet carries a lightly held valve several jumps and the regime boundary moves
#: fast with Δp; 0.1 apart above it)
DP_GRID = (0.0, 0.025, 0.05, 0.075, 0.1, 0.125, 0.15, 0.175, 0.2, 0.25, 0.3, 0.35, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)
#: the valve angles (fractions of the stroke) the keyed tables are built at (the load's slope and the hold current
#: change along the stroke); interpolated linearly in the angle
ANGLE_GRID = (0.0, 0.5, 1.0)
#: keyed mode: the blend's second-break / servo-break aims: "min" the neighbours' smallest (conservative), "mean"
#: their bilinear blend where every neighbour has one (docs §80.9)
BLEND_THRESHOLDS = "min"
#: keyed mode: blended tables (one per asked (direction, Δp, kick, angle)) kept
BLEND_CACHE_SIZE = 16
#: keyed mode: the process keeps the tables of this many model / settings signatures, shared by every PulseMoves of
#: one signature (``share``), least recently made evicted.  **The bound on the tables held in memory** (task h37b): a
#: signature's whole keyed set is ~0.13 MB per table -- C1 (kicks to 16 A): 342 tables, 44 MB read from the cache (43
#: MB on disk), 46 MB once each was read (its flat copy; measured, docs §93); the 4 A kick alone: 114 tables, ~15 MB --
#: so at most 4 x 46 MB = ~185 MB here, plus the stores of PulseMoves still alive outside it (an evicted signature's
#: tables live as long as a law holding its model does: the ROS node holds at most two laws, the one in force and the
#: one waiting for its swap)
SHARED_SIGNATURES = 4
_SHARED: OrderedDict = OrderedDict()
#: the keyed tables' disk cache (:meth:`PulseMoves.save_table` / :meth:`PulseMoves.read_cached`, task h36b): the version
#: of what a table holds and how it is built.  The cache signature also hashes the source of :data:`SOURCE_FILES` (any
#: edit there rebuilds the cache by itself); **bump this by hand** when the tables change for a reason those files
#: do not show: a table-building helper moved to another module, a numpy whose arithmetic changed the tables, a new
#: field
TABLE_VERSION = 1
#: the modules (relative to this one) whose source the cache signature hashes: the table physics (this module's
#: ``_table`` / ``_simulate``, the doublet's kernel ``drivetrain_step``, the model's friction and load)
SOURCE_FILES = ("pulse_moves.py", "drivetrain_step.py", "model.py", "../common/friction.py")
#: environment variable naming the cache directory ("" / "off": no disk cache); default
#: ``$ROS_HOME/fuel_valve/move_tables`` (``ROS_HOME`` default ``~/.ros``)
CACHE_ENV = "FUEL_VALVE_MOVE_TABLES"
#: environment variable (stop 26) naming a directory through which the tables built *lazily* (offline: the simulator,
#: the benchmarks, the tests; a lockstep node) are shared between processes: a table another process wrote there is
#: read instead of built (~2 ms instead of ~0.12 s of CPU; read back it is the built table bit for bit), one built
#: here is written there.  Unset (the default): a lazy build touches no disk, as before.  The test suite sets it to a
#: directory of its own (``test/conftest.py``), so its look-ahead workers, node processes and modules build each
#: table once per session.
LAZY_CACHE_ENV = "FUEL_VALVE_MOVE_TABLES_LAZY"
#: a table's fields as saved (``_flat``, derived on first read, is not)
_TABLE_FIELDS = ("excess", "overdrive", "aim", "moves", "rise", "second_break_aim", "last_ok", "servo_break_aim",
                 "build_s")
#: tables kept per PulseMoves in the ``exact`` mode (the keyed grid keeps all of its finite set; each (direction, Δp,
#: kick, valve angle) key one table of ~20k floats)
CACHE_SIZE = 32


class PulseMoves:
    """The doublet's valve move from the controller's model, tabulated lazily per
    (direction, Δp, kick current, valve angle) and interpolated.

    ``period_s``: the loop period (s); ``kick_current_a``: ``fine.kick_current_a`` (A, the default kick);
    ``peak_current_a``: ``fine.peak_current_a`` (A, every command's cap); ``retreat_full_periods``:
    ``fine.retreat_full_periods``; ``servo_kp`` (N*m/rad), ``servo_kd`` (N*m*s/rad), ``servo_ki``
    (N*m/(rad*s)): the stage's gear-output servo gains (:class:`FinePositioner` ``kp, kd, ki``, at the gear
    output); ``supply_voltage_v``: the drive's bus (``drive.supply_voltage_v``; None: no voltage limit).
    Keyword extras: ``current_bandwidth_hz`` (the drive's current-loop bandwidth; None: the current
    follows its command at once), ``observe_periods`` (periods of the observe servo simulated after the
    retreat, ``fine.observe_time_s`` / period), ``substeps`` (integration steps per period),
    ``retreat_unmoved_fraction`` (``fine.retreat_unmoved_fraction``: the last retreat period's current, x cap,
    when the valve has not moved a half count by then; ``tolerance_rad`` that count's threshold x 2).
    Grids: ``excess_fraction`` (the excesses tabulated: 0 ... this x T_s(Δp)/K, the plausible learned-offset
    bound of :meth:`FinePositioner._plausible_offset_rad`), ``overdrive_points`` log-spaced from 1e-3 to 1 x
    the stick-slip jump ``2 (T_s - T_c) / K`` at Δp, ``aim_points`` aims over 0 ... ``aim_fraction`` x that jump.
    ``park_friction``: the hold torque carries the motor's Coulomb friction toward the move (module docstring).
    A table (41 x 20 x 17 points and the second-break refinement) costs ~0.12 s of CPU, once per key: build them before
    the loop needs them (:meth:`prepare`) where a period's budget matters.
    Keying (docs §80.9): ``dp_grid`` (fractions of the model's max Δp) and ``angle_grid`` (fractions of the stroke): the
    grid the tables are built at, interpolated between (module docstring); ``extra_kicks`` (A): kicks besides
    ``kick_current_a`` that :meth:`prepare` builds by default (``for_positioner``: the staircase's first-stair kick,
    ``fine.first_kick_fraction`` x the kick); ``exact``: per-key tables instead (Δp to 1e-3 kPa, angle to 0.01 rad,
    LRU ``CACHE_SIZE``; no :meth:`prepare`); ``coarse_aims``: simulate every other aim and the rest only where the
    second breakaway's step lies between (False: every aim, h33m's table); ``share``: keyed tables shared in the
    process by every PulseMoves of the same model and settings (``SHARED_SIGNATURES`` kept).  Counters: ``builds``
    (tables), ``runs`` (time-loop simulations) -- this instance's own work.
    """

    def __init__(self, model: NominalModel, period_s: float, *, kick_current_a: float, peak_current_a: float,
                 retreat_full_periods: int, servo_kp: float, servo_kd: float, servo_ki: float,
                 supply_voltage_v: float | None = None, current_bandwidth_hz: float | None = DEFAULT_BANDWIDTH,
                 observe_periods: int = 15, substeps: int = 20, retreat_unmoved_fraction: float = 0.5,
                 tolerance_rad: float = 0.0, excess_fraction: float = 0.5, excess_points: int = 41,
                 overdrive_points: int = 20, aim_fraction: float = 1.0, aim_points: int = 17,
                 park_friction: bool = True, dp_grid=DP_GRID, angle_grid=ANGLE_GRID, extra_kicks=(),
                 exact: bool = False, coarse_aims: bool = True, share: bool = True, retreat_cap: bool = False,
                 observe_hold_integral: bool = False, observe_hold_moved: bool = False,
                 retreat_cap_full: bool = False):
        # what a worker process needs to make the same model (:meth:`spec`): the constructor's arguments
        self._spec = (model, float(period_s), {k: v for k, v in locals().items()
                                               if k not in ("self", "model", "period_s", "share")})
        self.m = model
        self.period = float(period_s)
        self.kick = float(kick_current_a)
        self.cap = float(peak_current_a)
        self.retreat_full = max(int(retreat_full_periods), 1)
        # (task h34s) fine.retreat_cap: the retreat periods command -cap itself, no half period;
        # fine.observe_hold_integral: the observe servo's integral is not integrated (stays at 0 here)
        self.retreat_cap, self.hold_integral = bool(retreat_cap), bool(observe_hold_integral)
        self.hold_moved = bool(observe_hold_moved)     # ... only where the valve has moved half a tolerance
        # fine.retreat_cap with fine.retreat_cap_half: -cap for the whole periods, main's half period kept
        self.cap_full = bool(retreat_cap_full) or self.retreat_cap
        self.kp, self.kd, self.ki = float(servo_kp), float(servo_kd), float(servo_ki)
        self.vlim = None if supply_voltage_v is None else supply_voltage_v / math.sqrt(3.0)
        self.wc = None if current_bandwidth_hz is None else 2.0 * math.pi * current_bandwidth_hz
        self.observe_periods = int(observe_periods)
        self.substeps = int(substeps)
        self.unmoved_fraction = float(retreat_unmoved_fraction)
        self.tolerance = float(tolerance_rad)
        self.excess_fraction = float(excess_fraction)
        self.n_excess, self.n_overdrive = int(excess_points), int(overdrive_points)
        self.aim_fraction, self.n_aim = float(aim_fraction), int(aim_points)
        self.park_friction = bool(park_friction)
        # the keyed grid (fractions of the model's max Δp and of its stroke); ``exact``: one table per
        # (direction, Δp to 1e-3 kPa, kick, angle to 0.01 rad) as h33m built it (the reference the grid is measured on)
        self.exact = bool(exact)
        self.coarse_aims = bool(coarse_aims)
        self.dp_grid = np.unique(np.clip(np.asarray(dp_grid, dtype=float), 0.0, 1.0)) * model.pressure_max_kpa
        self.angle_grid = np.unique(np.clip(np.asarray(angle_grid, dtype=float), 0.0, 1.0)) * model.stroke_rad
        self.kicks = tuple(dict.fromkeys(round(float(k), 6) for k in (self.kick, *extra_kicks)))
        self._tables: OrderedDict = OrderedDict()
        self._rises: dict = {}
        # the keyed tables depend on nothing but these (and the key): the process-wide share and the disk cache's
        # signature (:meth:`signature_hash`)
        sig = (model, self.period, self.cap, self.retreat_full, self.kp, self.kd, self.ki, self.vlim, self.wc,
               self.observe_periods, self.substeps, self.unmoved_fraction, self.tolerance, self.excess_fraction,
               self.n_excess, self.n_overdrive, self.aim_fraction, self.n_aim, self.park_friction, self.coarse_aims,
               self.retreat_cap, self.hold_integral, self.hold_moved, self.cap_full)
        self._sig, self._sig_hash = sig, None
        self._share = bool(share) and not self.exact
        if self._share:
            # every PulseMoves of one signature in the process shares them (a campaign's runs with one told model
            # build them once; read-only once built)
            store = _SHARED.get(sig)
            if store is None:
                store = _SHARED[sig] = (self._tables, self._rises)
                while len(_SHARED) > SHARED_SIGNATURES:
                    _SHARED.popitem(last=False)
            _SHARED.move_to_end(sig)
            self._tables, self._rises = store
        self._blends: OrderedDict = OrderedDict()
        self._stacks: OrderedDict = OrderedDict()   # (:meth:`move_points`) a grid key's kick set's tables side by side
        self._rise_sets: OrderedDict = OrderedDict()    # (:meth:`rises`) the last few asked
        self.builds = 0                  # tables simulated so far (tests count the cache's work)
        self.runs = 0                    # time-loop runs (_simulate calls: tables, refinements and rises)

    @classmethod
    def for_positioner(cls, fine, ps=None, **kw) -> "PulseMoves":
        """The move model of a :class:`FinePositioner` ``fine``: its planning model, period, doublet settings
        (``fine.cfg``) and servo gains (``fine.kp, kd, ki``); ``ps`` (a controller parameter set, optional):
        ``drive.supply_voltage_v`` and ``drive.current_loop_bandwidth_hz`` (else their defaults).  ``kw``
        overrides any keyword of the constructor."""
        vals = CONTROLLER_SPEC.defaults() if ps is None else ps
        cfg = fine.cfg
        args = dict(kick_current_a=cfg.kick_current_a, peak_current_a=cfg.peak_current_a,
                    retreat_full_periods=cfg.retreat_full_periods, servo_kp=fine.kp, servo_kd=fine.kd,
                    servo_ki=fine.ki, supply_voltage_v=vals["drive.supply_voltage_v"],
                    current_bandwidth_hz=vals["drive.current_loop_bandwidth_hz"],
                    observe_periods=cfg.observe_periods, retreat_unmoved_fraction=cfg.retreat_unmoved_fraction,
                    tolerance_rad=cfg.tolerance_rad,
                    extra_kicks=(cfg.kick_current_a * cfg.first_kick_fraction,))
        args.update(kw)
        return cls(fine.m, fine.period, **args)

    # ------------------------------------------------------------------ public
    def rise(self, direction: int, pressure_kpa: float, kick_current_a: float | None = None,
             valve_angle_rad: float | None = None) -> float:
        """Twist (rad, >= 0, toward ``direction``) the doublet's kick -- and the retreat's first instants,
        while the current slews back -- raises above a quasi-static preload on a valve that stays stuck: the
        doublet's apex lies this far above its preload.  Keyed mode (default): interpolated between the grid's
        (Δp, angle) points (it depends on neither by more than 2e-6 rad: the valve is held); ``exact``: per
        (direction, Δp, kick, angle), cached."""
        d, p, kick, th = self._key_parts(direction, pressure_kpa, kick_current_a, valve_angle_rad)
        if self.exact:
            return self._rise_at(d, p, kick, th)
        return float(sum(w * self._rise_at(d, pk, kick, tk) for pk, tk, w in self._corners(p, th)))

    def move(self, direction: int, pressure_kpa: float, excess_rad, overdrive_rad,
             kick_current_a: float | None = None, aim_rad=0.0, valve_angle_rad: float | None = None) -> np.ndarray:
        """The valve's move (rad, >= 0 toward ``direction``; an ndarray of the broadcast shape of
        ``excess_rad``, ``overdrive_rad`` and ``aim_rad``) for a doublet whose apex lies ``overdrive_rad``
        above the static level, the level ``excess_rad`` above the Coulomb-equilibrium twist (both rad,
        toward ``direction``), asked to close the error ``aim_rad`` (rad toward ``direction``, >= 0: the
        observe servo's final twist is ``φe + aim / 2``; the move grows with it -- pass the error the
        doublet is for).  0 where ``overdrive_rad <= 0`` (no break); NaN where the observe servo's rebound breaks
        the valve loose a second time (or, below the level, at all: a move the model does not predict); NaN outside
        the table (excess beyond ``excess_fraction`` x T_s/K or below 0, overdrive beyond one stick-slip jump, aim
        beyond one jump or below 0: the caller counts it a miss).  ``valve_angle_rad``: where the doublet starts
        (the load's angle; None: mid-stroke).

        Keyed mode (default): ``pressure_kpa`` and ``valve_angle_rad`` are *approximated* -- the answer is
        interpolated (bilinear in Δp and angle) between the tables at the neighbouring points of ``dp_grid`` x
        ``angle_grid``, each asked at the same point of its grid normalised by its own friction levels (excess /
        (``excess_fraction`` T_s/K), overdrive and aim / the jump 2 (T_s - T_c)/K) and its move read in jumps; NaN
        where any neighbour with a weight answers NaN.  Error against the exact per-key table: docs §80.9
        (``benchmarks/pulse_moves_check.py --grid``).  Within a table: linear in excess and aim, in log overdrive.
        Builds the neighbours' tables if they are not built yet (~0.12 s each): call :meth:`prepare` first where
        a period's budget matters."""
        d, p, kick, th = self._key_parts(direction, pressure_kpa, kick_current_a, valve_angle_rad)
        x, od, aim = np.broadcast_arrays(np.asarray(excess_rad, dtype=float), np.asarray(overdrive_rad, dtype=float),
                                         np.asarray(aim_rad, dtype=float))
        if self.exact:
            return self._raw_move(self._table(d, p, kick, th), x, od, aim)
        return self._raw_move(self._blend(d, p, kick, th), x, od, aim)

    def move_points(self, direction: int, pressure_kpa: float, kicks, which, excess_rad, overdrive_rad,
                    aim_rad: float = 0.0, valve_angle_rad: float | None = None, level=None) -> np.ndarray:
        """:meth:`move` at points of several kicks in one pass (task h37a, docs §94): the move (rad) at each point i of
        the 1-D arrays ``excess_rad``, ``overdrive_rad`` for the kick ``kicks[which[i]]`` (A), one scalar
        ``aim_rad``; equal bit for bit to ``move(direction, pressure_kpa, excess_rad[i], overdrive_rad[i],
        kicks[which[i]], aim_rad, valve_angle_rad)``: the same arithmetic, element by element, on the kicks' tables
        side by side (:meth:`_blend_stack`; where the kicks' grids differ, or a point lies below its level, one
        :meth:`_raw_move` per kick).  ``level`` (task h40m, docs §106; an index array like ``which``): the excess is
        per level, point i's ``excess_rad[level[i]]`` (the excess's share of the arithmetic formed once per level).
        Builds what :meth:`move` would build."""
        x, od = np.asarray(excess_rad, dtype=float), np.asarray(overdrive_rad, dtype=float)
        which = np.asarray(which, dtype=np.intp)
        keys = [self._key_parts(direction, pressure_kpa, kick, valve_angle_rad) for kick in kicks]
        if not self.exact and not (od <= 0.0).any():
            stack = self._blend_stack(keys[0][0], keys[0][1], tuple(k[2] for k in keys), keys[0][3])
            if stack is not None:
                return self._raw_move_stacked(stack, which, x, od, float(aim_rad), level)
        if level is not None:
            x = x[np.asarray(level, dtype=np.intp)]
        v = np.empty(x.shape)
        for i, (d, p, kk, th) in enumerate(keys):
            sel = which == i
            tab = self._table(d, p, kk, th) if self.exact else self._blend(d, p, kk, th)
            v[sel] = self._raw_move(tab, x[sel], od[sel], float(aim_rad))
        return v

    def rises(self, direction: int, pressure_kpa: float, kicks, valve_angle_rad: float | None = None) -> list:
        """[:meth:`rise` of each kick of ``kicks``] (the same floats; the grid's corners found once)."""
        key = ("rises", direction, pressure_kpa, tuple(kicks), valve_angle_rad)
        hit = self._rise_sets.get(key)       # (an unmoved try's next asks at the same Δp and valve angle)
        if hit is not None:
            return list(hit)
        keys = [self._key_parts(direction, pressure_kpa, kick, valve_angle_rad) for kick in kicks]
        if self.exact:
            out = [self._rise_at(d, p, kick, th) for d, p, kick, th in keys]
        else:
            corners = self._corners(keys[0][1], keys[0][3])
            out = [float(sum(w * self._rise_at(d, pk, kick, tk) for pk, tk, w in corners)) for d, p, kick, th in keys]
        self._rise_sets[key] = tuple(out)
        while len(self._rise_sets) > BLEND_CACHE_SIZE:
            self._rise_sets.popitem(last=False)
        return out

    @staticmethod
    def _flat(tab) -> tuple:
        """Per-table constants of :meth:`_raw_move`, kept in the table: flat views of the moves and ``last_ok`` for
        the gathers, the second-break aims capped one aim step beyond the grid."""
        flat = tab.get("_flat")
        if flat is None:
            ag = tab["aim"]
            beyond = ag[-1] + (ag[1] - ag[0])
            flat = tab["_flat"] = (tab["moves"].ravel(), np.asarray(tab["last_ok"], dtype=float).ravel(),
                                   np.minimum(np.asarray(tab["second_break_aim"], dtype=float), beyond).ravel())
        return flat

    def _corner_stack(self, d, p, kicks, th):
        """The kicks' tables at one grid key side by side: (the first's table, their moves, ``last_ok`` and
        second-break aims raveled end to end), or None where their grids differ; the last BLEND_CACHE_SIZE kept."""
        key = (d, p, kicks, th)
        hit = self._stacks.get(key)
        if hit is not None:
            self._stacks.move_to_end(key)
        else:
            tabs = [self._table(d, p, kick, th) for kick in kicks]
            t0 = tabs[0]
            if all(all(np.array_equal(t[n], t0[n]) for n in ("excess", "overdrive", "aim"))
                   and t["moves"].shape == t0["moves"].shape for t in tabs[1:]):
                hit = (t0, np.concatenate([t["moves"].ravel() for t in tabs]),
                       np.concatenate([np.asarray(t["last_ok"], dtype=float).ravel() for t in tabs]),
                       np.concatenate([np.asarray(t["second_break_aim"], dtype=float).ravel() for t in tabs]))
            else:
                hit = (None,)
            self._stacks[key] = hit
            while len(self._stacks) > BLEND_CACHE_SIZE:     # (each ~0.35 MB: three kicks' moves)
                self._stacks.popitem(last=False)
        return None if hit[0] is None else hit

    def _blend_stack(self, d, p, kicks, th):
        """:meth:`_blend` of every kick of ``kicks`` at once, as :meth:`_raw_move_stacked` reads it: (grids (excess,
        overdrive, aim), table shape, [(weight x jump ratio, the corner's moves)] -- None: a single corner's own
        moves --, ``last_ok``, capped second-break aims), the kicks' tables end to end; the same arithmetic as
        :meth:`_blend` then :meth:`_flat` per kick (elementwise: the same bits), the moves' blend left to the cells
        read.  None where the kicks' grids differ (or ``BLEND_THRESHOLDS`` is not "min").  The last few kept."""
        key = ("blend", d, p, kicks, th)
        hit = self._blends.get(key)
        if hit is not None:
            self._blends.move_to_end(key)
            return hit
        corners = self._corners(p, th)
        if len(corners) == 1:
            st = self._corner_stack(d, corners[0][0], kicks, corners[0][1])
            if st is None:
                return None
            t0 = st[0]
            grids, mv, lok, sba = (t0["excess"], t0["overdrive"], t0["aim"]), [(None, st[1])], st[2], st[3]
        else:
            if BLEND_THRESHOLDS != "min":
                return None
            xs, js = self._scales(p)
            mv, lok, sba = [], np.inf, np.inf
            for pk, tk, w in corners:
                st = self._corner_stack(d, pk, kicks, tk)
                if st is None:
                    return None
                t0 = st[0]
                xk, jk = self._scales(pk)
                r = js / jk
                grids = (t0["excess"] * (xs / xk), t0["overdrive"] * r, t0["aim"] * r)
                mv.append((w * r, st[1]))
                sba = np.minimum(sba, st[3] * r)
                lok = np.minimum(lok, st[2])
        ag = grids[2]
        beyond = ag[-1] + (ag[1] - ag[0])
        hit = (grids, st[0]["moves"].shape, mv, lok, np.minimum(sba, beyond))
        self._blends[key] = hit
        while len(self._blends) > BLEND_CACHE_SIZE:
            self._blends.popitem(last=False)
        return hit

    @staticmethod
    def _raw_move_stacked(stack, which, x, od, aim: float, level=None) -> np.ndarray:
        """:meth:`_raw_move` on the kicks' tables side by side (``stack``: :meth:`_blend_stack`): point i (1-D
        points above their levels, ``od`` > 0) read on the table ``which[i]``, one scalar ``aim``; ``level`` (None:
        ``x`` per point) an index into ``x`` per point (``x`` per level).  The arithmetic is :meth:`_raw_move`'s (and
        :meth:`_blend`'s), operation for operation: each cell's move at the aim (a function of the cell alone for one
        aim) is formed once per cell instead of once per point and corner, from the cell's two aims' moves blended
        as :meth:`_blend` blends the whole table; the excess's grid index, weight and range test once per level
        (functions of the excess alone); the same bits."""
        (xg, og, ag), (nx, no, na), mvs, lok, thr = stack
        off = which * (nx * no)                      # each table's first cell in the stacked constants
        eps = 1e-12
        fx = np.minimum(np.maximum(x * (1.0 / (xg[1] - xg[0])), 0.0), nx - 1)
        i0 = np.minimum(fx.astype(np.intp), nx - 2)
        ax = fx - i0
        bad = (x < -eps) | ~np.isfinite(x) | (x > xg[-1] * (1 + 1e-6) + eps)
        if level is not None:
            level = np.asarray(level, dtype=np.intp)
            i0, ax, bad = i0[level], ax[level], bad[level]
        fo = np.minimum(np.log(np.maximum(od, og[0]) * (1.0 / og[0])) * (1.0 / math.log(og[1] / og[0])), no - 1)
        fa = np.minimum(np.maximum(aim * (1.0 / (ag[1] - ag[0])), 0.0), na - 1)
        j0 = np.minimum(fo.astype(np.intp), no - 2)
        ao = fo - j0
        # the four corner cells of every point, and each one's move at the aim as _raw_move forms it (a function of
        # the cell alone for one aim; on _blend's moves: the cell's two aims blended as _blend blends the table)
        row = i0 * no + j0 + off
        n = len(row)
        cells = np.concatenate([row, row + 1, row + no, row + (no + 1)])
        if 4 * n > len(lok):
            # (task h40m, docs §106) more corner reads than cells (the mixture law's thousands of points): every
            # cell's move at the aim formed once, then read at the corners -- each cell's the same arithmetic
            at_aim = PulseMoves._cells_at_aim(mvs, lok, fa, na)[cells].reshape(4, n)
        else:
            at_aim = PulseMoves._cells_at_aim(mvs, lok[cells], fa, na, cells).reshape(4, n)
        th_at = thr[cells].reshape(4, n)
        v = np.zeros(n)
        t = np.zeros(n)
        bx, bo = 1.0 - ax, 1.0 - ao
        for c, wx, wo in ((0, bx, bo), (1, bx, ao), (2, ax, bo), (3, ax, ao)):
            w2 = wx * wo
            v += at_aim[c] * w2
            t += th_at[c] * w2
        bad = bad | (od > og[-1] * (1 + 1e-6))
        if aim < -eps or aim > ag[-1] * (1 + 1e-6) + eps or not math.isfinite(aim):
            bad[:] = True
        v[(aim >= t) | bad] = np.nan
        return v

    @staticmethod
    def _cells_at_aim(mvs, lok, fa: float, na: int, cells=None) -> np.ndarray:
        """(:meth:`_raw_move_stacked`) The move at the aim index ``fa`` of the stacked cells ``cells`` (None: every
        cell; ``lok``: their ``last_ok`` aims): the cell's two neighbouring aims' moves, each the corners' blend
        (``mvs``, as :meth:`_blend` blends the table), blended linearly -- a function of the cell alone."""
        kk = np.minimum(fa, lok)
        k = np.minimum(kk.astype(np.intp), na - 2)
        w = kk - k
        base = (np.arange(len(lok)) if cells is None else cells) * na + k
        if mvs[0][0] is None:
            m0, m1 = mvs[0][1][base], mvs[0][1][base + 1]
        else:
            m0 = m1 = 0.0
            for c, m in mvs:
                m0 = m0 + c * m[base]
                m1 = m1 + c * m[base + 1]
        return m0 * (1.0 - w) + m1 * w

    def table(self, direction: int, pressure_kpa: float, kick_current_a: float | None = None,
              valve_angle_rad: float | None = None) -> dict:
        """The raw table behind :meth:`move`: ``excess``, ``overdrive``, ``aim`` (grids, rad) and ``moves``
        [excess, overdrive, aim] (rad toward ``direction``), ``rise`` (rad), ``build_s`` (s of CPU it took).
        Keyed mode: the table of the grid point nearest to (``pressure_kpa``, ``valve_angle_rad``)."""
        d, p, kick, th = self._key_parts(direction, pressure_kpa, kick_current_a, valve_angle_rad)
        if not self.exact:
            p = float(self.dp_grid[np.argmin(np.abs(self.dp_grid - p))])
            th = float(self.angle_grid[np.argmin(np.abs(self.angle_grid - th))])
        return self._table(d, p, kick, th)

    def trough(self, direction: int, pressure_kpa: float, preload_rad, kick_current_a: float | None = None,
               valve_angle_rad: float | None = None, aim_rad: float = 0.0, retreat_periods: int | None = None,
               retreat_scale=1.0, speed0: float | None = None, hold0: float | None = None, servo_offset: float = 0.0,
               ref_twist: float | None = None, servo_delay_s: float = 0.0) -> np.ndarray:
        """(task h36g, docs §90) The retreat's trough on a valve that stays stuck: the smallest coupling torque over K
        toward ``direction`` (absolute twist, rad, the static levels' coordinate) the doublet from a quasi-static
        preload ``preload_rad`` (absolute twist, rad; an array: one lane each) reaches after its kick -- through the
        retreat periods and the observe servo's pull back (toward ``φe + d aim / 2``) -- where the *other* direction's
        static level ``(load - d T_s) / K`` meets it: below that level the retreat itself breaks the valve loose
        backwards.  ``retreat_periods`` (None: the model's ``retreat_full_periods``; 0: the kick then the observe
        servo) and ``retreat_scale`` (broadcast with ``preload_rad``: each retreat period's command moved this fraction
        of the way from the hold torque to the model's own retreat command -- 1 the model's doublet, 0 the hold)
        reshape the doublet; ``speed0`` (rad/s, the gear output's speed at the kick, signed) and ``hold0`` (N*m at the
        motor: the torque the kick is added to) start it from the stage's actual state (None: at rest on the
        quasi-static hold); ``servo_offset`` (N*m at the motor: the stage's servo's static torque less the model's
        ``K φ / N`` at the same twist -- its feed-forward's engage offset and its integral) and ``ref_twist`` (absolute
        twist, rad: the stage's final twist; None: ``φe + d aim / 2``) make the observe servo the stage's;
        ``servo_delay_s`` (s, task h37t, docs §96; 0: none) the observe servo reads the gear output and the valve this much
        late (the resolver delay; at most one period).  Simulated until the servo has turned the swing (one run of a few lanes, ~5 ms of CPU);
        not tabulated."""
        d, p, kick, th = self._key_parts(direction, pressure_kpa, kick_current_a, valve_angle_rad)
        pre, scale = np.broadcast_arrays(np.atleast_1d(np.asarray(preload_rad, dtype=float)),
                                         np.atleast_1d(np.asarray(retreat_scale, dtype=float)))
        n = pre.shape[0]
        return self._simulate(d, p, kick, th, preload=pre.copy(), excess=np.full(n, np.inf),
                              aim=np.full(n, float(aim_rad)), track_trough=True, retreat_periods=retreat_periods,
                              retreat_scale=scale.copy(), speed0=speed0, hold0=hold0, servo_offset=servo_offset,
                              ref_twist=ref_twist, servo_delay_s=servo_delay_s)

    def trough_fast(self, direction: int, pressure_kpa: float, preload_rad, kick_current_a: float | None = None,
                    valve_angle_rad: float | None = None, aim_rad: float = 0.0, retreat_periods: int | None = None,
                    retreat_scale=1.0, speed0: float | None = None, hold0: float | None = None,
                    servo_offset: float = 0.0, ref_twist: float | None = None, servo_delay_s: float = 0.0) -> np.ndarray:
        """(task h40s, docs §105) :meth:`trough`'s answer, to the bit, in plain floats: the same kernel
        (:mod:`~fuel_valve_control.core.drivetrain_step`, task h41k, docs §109) run on one float lane per preload --
        the valve stays stuck in :meth:`trough` (its static level is infinite), so only the gear output (its angle,
        speed and stick-slip), the drive's q current and the observe servo are stepped; the lanes run in step and stop
        together, as :meth:`_simulate`'s do (once every lane's swing has turned).  ~0.15-0.2 ms of CPU per lane where
        :meth:`trough`'s numpy run costs ~4-17 ms on 1-11 lanes (its per-operation overhead).  Same arguments."""
        d, p, kick, th = self._key_parts(direction, pressure_kpa, kick_current_a, valve_angle_rad)
        pre, scale = np.broadcast_arrays(np.atleast_1d(np.asarray(preload_rad, dtype=float)),
                                         np.atleast_1d(np.asarray(retreat_scale, dtype=float)))
        dbl = Doublet(self, d, p, kick, th, valve_free=False, track_trough=True, retreat_periods=retreat_periods,
                      servo_offset=servo_offset, servo_delay_s=servo_delay_s)
        lanes = [dbl.start(FLOATS, float(a), math.inf, float(aim_rad), speed0=speed0, hold0=hold0, ref_twist=ref_twist,
                           scale=float(b)) for a, b in zip(pre, scale)]
        n_pulse, step = dbl.n_pulse, FLOATS.period
        for period in range(n_pulse + self.observe_periods):
            if period > n_pulse and all(dbl.turned(lane) for lane in lanes):
                break                                    # the servo has turned every lane's swing: the trough is past
            for lane in lanes:
                step(dbl, lane, period)
        return np.array([d * lane.trough for lane in lanes])

    def pending(self, pressures_kpa=None, directions=(1, -1), kicks=None) -> list:
        """The (direction, Δp, kick, angle) keys :meth:`prepare` with these arguments would still build (tables or
        rises not built yet); [] once prepared.  Keyed mode only (``exact``: every new key is a new table)."""
        return [key for key in self._needed(pressures_kpa, directions, kicks)
                if key not in self._tables or key not in self._rises]

    @property
    def prepared(self) -> bool:
        """True when every table the keyed grid can need (every Δp and angle point, both directions, every kick
        in ``kicks``) is built: no :meth:`move` or :meth:`rise` with those kicks builds anything any more."""
        return not self.exact and not self.pending()

    def prepare(self, pressures_kpa=None, directions=(1, -1), kicks=None, max_s: float | None = None) -> float:
        """Build ahead every table the stage can need, so that no later :meth:`move` / :meth:`rise` builds one;
        returns the CPU seconds spent (``time.process_time``).  ``pressures_kpa``: None, every Δp point of the grid
        (any Δp then interpolates between built tables); else the grid's neighbours of each.  ``directions``: +1
        / -1.  ``kicks`` (A): None, ``kicks`` (``kick_current_a`` and ``extra_kicks``).  Every angle point.
        Keyed mode only.  **The ROS controller node must call it at configure / activate, outside its 1 kHz
        control callback** (one table costs ~0.12 s of CPU: built lazily inside the callback it would stall the
        loop ~150 periods; it now builds them in a background process instead, :class:`TableBuild`, task h36b);
        offline a lazy build is harmless (docs §80.9).  ``max_s`` (s of CPU, optional): stop after
        the table that passes this budget (a caller spreading the work over idle time calls again until ``prepared``
        / :meth:`pending` says nothing is left)."""
        if self.exact:
            raise ValueError("prepare(): the exact mode has no finite set of keys (its Δp and angle are continuous)")
        t0 = time.process_time()
        for key in self._needed(pressures_kpa, directions, kicks):
            if key in self._tables and key in self._rises:
                continue
            self._table(*key)
            if max_s is not None and time.process_time() - t0 >= max_s:
                break
        return time.process_time() - t0

    # ------------------------------------------------------------------ disk cache (task h36b)
    def spec(self) -> tuple:
        """(model, period s, keyword arguments): what makes an equal PulseMoves in another process (picklable)."""
        return self._spec

    def signature_hash(self) -> str:
        """The disk cache's signature (hex): a hash of every setting a keyed table depends on (the process-wide
        share's signature, the model's parameters), :data:`TABLE_VERSION` and the source of :data:`SOURCE_FILES`.
        Two PulseMoves with equal hashes build equal tables for equal keys; any model, setting, version or code
        change gives another hash (and another cache directory: the old files are never read)."""
        if self._sig_hash is None:
            h = hashlib.sha256(f"fuel_valve move tables v{TABLE_VERSION}\n{_canon(self._sig)}\n".encode())
            h.update(_source_digest().encode())
            self._sig_hash = h.hexdigest()[:32]
        return self._sig_hash

    def cache_dir(self, root) -> Path:
        """This signature's directory under the cache ``root``: one ``.npz`` per (direction, Δp, kick, angle) key."""
        return Path(root) / self.signature_hash()

    def table_file(self, root, key) -> Path:
        """The file of one key's table under ``root`` (named by a hash of the key; the key is stored inside too)."""
        return self.cache_dir(root) / f"t_{hashlib.sha256(_canon(tuple(key)).encode()).hexdigest()[:24]}.npz"

    def save_table(self, root, key) -> Path:
        """Write the built table of ``key`` (direction, Δp kPa, kick A, angle rad) and its rise to the cache
        ``root`` atomically (a temporary file in the same directory, then ``os.replace``: a reader sees the whole
        file or none).  Returns the path."""
        key = tuple(key)
        tab = self._tables[key]
        path = self.table_file(root, key)
        path.parent.mkdir(parents=True, exist_ok=True)
        arrays = {name: np.asarray(tab[name]) for name in _TABLE_FIELDS}
        arrays["rise_at"] = np.asarray(self._rises[key])
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp_", suffix=".npz")
        try:
            with os.fdopen(fd, "wb") as f:
                np.savez(f, signature=np.asarray(self.signature_hash()), key=np.asarray(key, dtype=float), **arrays)
            os.chmod(tmp, 0o644)                # (mkstemp's 0600: another user's node may read the cache too)
            os.replace(tmp, path)
        except BaseException:
            try:
                os.unlink(tmp)
            except OSError:
                pass
            raise
        return path

    def read_cached(self, root, keys, stop=None) -> dict:
        """{key: (table, rise)} of the ``keys`` whose files in the cache ``root`` are whole and this signature's;
        a missing, partial, corrupt or foreign file (another signature or key, wrong shapes) is skipped (the key
        is to build), never raised.  Reads only: safe from any thread (:meth:`adopt` takes them in).  ``stop()``
        (optional) is asked before each file: True ends the read there (what was read so far is returned; a
        cancelled :class:`TableBuild` lets go of its ~43 MB at once instead of reading the whole set first)."""
        out = {}
        for key in keys:
            if stop is not None and stop():
                break
            key = tuple(key)
            path = self.table_file(root, key)
            if not path.is_file():
                continue
            try:
                with np.load(path, allow_pickle=False) as z:
                    if str(z["signature"]) != self.signature_hash() or z["key"].shape != (4,) \
                            or not np.array_equal(z["key"], np.asarray(key, dtype=float)):
                        continue
                    tab = {name: z[name] for name in _TABLE_FIELDS}
                    rise = float(z["rise_at"])
            except Exception:          # noqa: BLE001 - a bad file is a table to build again, never a crash
                continue
            nx, no, na = self.n_excess, self.n_overdrive, self.n_aim
            if tab["moves"].shape != (nx, no, na) or tab["second_break_aim"].shape != (nx, no) \
                    or tab["excess"].shape != (nx,) or tab["overdrive"].shape != (no,) or tab["aim"].shape != (na,):
                continue
            for name in ("rise", "build_s"):
                tab[name] = float(tab[name])
            out[key] = (tab, rise)
        return out

    def adopt(self, tables: dict) -> int:
        """Take in tables read by :meth:`read_cached` (keys not built yet only; a built table is never replaced);
        returns how many were new.  The keyed store is shared with every PulseMoves of this signature: the
        process-wide share's store of this signature too, when it is another one (this model's store was evicted
        from :data:`_SHARED` and a later model of the signature made a new one) -- the same table objects, no copy."""
        new = 0
        stores = [(self._tables, self._rises)]
        shared = _SHARED.get(self._sig) if self._share else None
        if shared is not None and shared[0] is not self._tables:
            stores.append(shared)
        for key, (tab, rise) in tables.items():
            for i, (tabs, rises) in enumerate(stores):
                if key not in tabs:
                    tabs[key] = tab
                    new += i == 0
                rises.setdefault(key, rise)
        return new

    @property
    def signature(self) -> tuple:
        """What the keyed tables depend on besides their key (the process-wide share's key): two PulseMoves of one
        signature read and build the same tables."""
        return self._sig

    def missing(self, keys) -> list:
        """The ``keys`` whose table or rise is not in this model's store (yet)."""
        return [tuple(k) for k in keys if tuple(k) not in self._tables or tuple(k) not in self._rises]

    def build_and_save(self, root, keys, stop=None) -> int:
        """Build each of ``keys`` not in the cache ``root`` yet and save it there, one file per table as it is
        done (a build cut short keeps what it finished); ``stop()`` (optional) is asked between tables.  Returns
        the tables built."""
        built = 0
        for key in keys:
            key = tuple(key)
            if stop is not None and stop():
                break
            if self.read_cached(root, [key]):
                continue                       # another process built it meanwhile
            self._table(*key)
            self.save_table(root, key)
            built += 1
        return built

    # ------------------------------------------------------------------ internals
    def _key_parts(self, direction, pressure_kpa, kick_current_a, valve_angle_rad):
        d = 1 if direction > 0 else -1
        kick = round(self.kick if kick_current_a is None else float(kick_current_a), 6)
        th = 0.5 * self.m.stroke_rad if valve_angle_rad is None else float(valve_angle_rad)
        if not self.exact:
            # keyed: continuous, clamped to the grid (the friction law and the flow torque saturate at max Δp)
            p = min(max(float(pressure_kpa), self.dp_grid[0]), self.dp_grid[-1])
            return d, p, kick, min(max(th, self.angle_grid[0]), self.angle_grid[-1])
        # the load changes little over 0.01 rad of angle (spring rate + flow slope: < 0.1 % of K per 0.01 rad)
        return d, round(float(pressure_kpa), 3), kick, round(th, 2)

    @staticmethod
    def _bracket(grid, v):
        """[(grid point, weight)] of the linear interpolation at ``v`` (one point where ``v`` is on the grid)."""
        if len(grid) == 1:
            return [(float(grid[0]), 1.0)]
        i = int(min(max(np.searchsorted(grid, v, side="right") - 1, 0), len(grid) - 2))
        w = (v - grid[i]) / (grid[i + 1] - grid[i])
        # on a grid point to rounding (0.9 x max Δp computed two ways): that point alone, no neighbour to build
        w = 0.0 if w < 1e-9 else 1.0 if w > 1.0 - 1e-9 else w
        return [(float(g), ww) for g, ww in ((grid[i], 1.0 - w), (grid[i + 1], w)) if ww > 0.0]

    def _corners(self, p, th):
        """[(Δp, angle, weight)]: the grid points the keyed mode interpolates between at (``p``, ``th``)."""
        return [(pk, tk, wp * wt) for pk, wp in self._bracket(self.dp_grid, p)
                for tk, wt in self._bracket(self.angle_grid, th)]

    def _blend(self, d, p, kick, th) -> dict:
        """Keyed mode: the table at (``p``, ``th``) blended from its grid neighbours (bilinear weights) on their common
        normalised grids (excess / (``excess_fraction`` T_s/K), overdrive and aim / the jump): the moves read in jumps
        and rescaled to ``p``'s jump; the second-break aims, ``last_ok`` and the servo-break aims the smallest of the
        neighbours' (conservative: NaN where any neighbour breaks a second time).  Cached (LRU) per query key: the
        stage asks at one Δp and angle for a whole plateau."""
        key = (d, p, kick, th)
        hit = self._blends.get(key)
        if hit is not None:
            self._blends.move_to_end(key)
            return hit
        corners = self._corners(p, th)
        if len(corners) == 1:
            tab = self._table(d, corners[0][0], kick, corners[0][1])
        else:
            xs, js = self._scales(p)
            tab = {"moves": 0.0, "rise": 0.0, "second_break_aim": np.inf, "last_ok": np.inf, "servo_break_aim": np.inf}
            mean = {"second_break_aim": 0.0, "servo_break_aim": 0.0}
            for pk, tk, w in corners:
                t = self._table(d, pk, kick, tk)
                xk, jk = self._scales(pk)
                r = js / jk
                tab["excess"], tab["overdrive"], tab["aim"] = t["excess"] * (xs / xk), t["overdrive"] * r, t["aim"] * r
                tab["moves"] = tab["moves"] + (w * r) * t["moves"]
                tab["rise"] += w * t["rise"]
                for name in ("second_break_aim", "servo_break_aim"):
                    tab[name] = np.minimum(tab[name], t[name] * r)
                    mean[name] = mean[name] + w * (t[name] * r)
                tab["last_ok"] = np.minimum(tab["last_ok"], t["last_ok"])
            if BLEND_THRESHOLDS == "mean":
                for name in ("second_break_aim", "servo_break_aim"):
                    tab[name] = np.where(np.isfinite(mean[name]), mean[name], tab[name])
        self._blends[key] = tab
        while len(self._blends) > BLEND_CACHE_SIZE:
            self._blends.popitem(last=False)
        return tab

    def _scales(self, p):
        """(excess range, stick-slip jump) at Δp ``p`` (rad): the table's grids' scales (``_table``)."""
        fl = self.m.friction(p)
        k = self.m.coupling_stiffness_nm_per_rad
        return self.excess_fraction * fl.valve_static_nm / k, max(fl.stick_slip_jump_rad(k), 1e-6)

    def _needed(self, pressures_kpa, directions, kicks):
        """The keys :meth:`prepare` builds (module docstring of :meth:`prepare`)."""
        if pressures_kpa is None:
            ps = [float(v) for v in self.dp_grid]
        else:
            ps = sorted({pk for v in np.atleast_1d(pressures_kpa)
                         for pk, _ in self._bracket(self.dp_grid, self._key_parts(1, v, None, None)[1])})
        ks = self.kicks if kicks is None else tuple(round(float(k), 6) for k in kicks)
        # highest Δp first, both directions and every angle before the next Δp: a budgeted prepare (``max_s``) has the
        # operating point (max Δp, the fine stage's tight plateaus) ready first
        return [(1 if d > 0 else -1, pk, kk, float(tk)) for pk in sorted(ps, reverse=True) for kk in ks
                for d in directions for tk in self.angle_grid]

    def _rise_at(self, d, p, kick, th) -> float:
        """The rise at one key (simulated once, cached)."""
        key = (d, p, kick, th)
        if key not in self._rises:
            phi_s = self._levels(d, p, th)[2]
            # a valve held stuck (static level far beyond reach); the preload at the nominal level
            apex = self._simulate(d, p, kick, th, preload=np.array([phi_s]), excess=np.array([np.inf]),
                                  aim=np.array([0.0]), track_apex=True)
            self._rises[key] = float(max(d * (apex[0] - phi_s), 0.0))
        return self._rises[key]

    @staticmethod
    def _raw_move(tab, x, od, aim) -> np.ndarray:
        """:meth:`move` on one table (arrays of one shape, rad toward the table's direction).  The grids are
        uniform (excess, aim) and geometric (overdrive): the fractional indices are computed, not searched; the
        corners are gathered by flat index (the policy's 61 x 40 call: ~0.1 ms)."""
        xg, og, ag, moves = tab["excess"], tab["overdrive"], tab["aim"], tab["moves"]
        nx, no, na = moves.shape
        beyond = ag[-1] + (ag[1] - ag[0])
        mv, lok, thr = PulseMoves._flat(tab)
        # (np.minimum / np.maximum: np.clip costs twice as much here)
        fx = np.minimum(np.maximum(x * (1.0 / (xg[1] - xg[0])), 0.0), nx - 1)
        fo = np.minimum(np.log(np.maximum(od, og[0]) * (1.0 / og[0])) * (1.0 / math.log(og[1] / og[0])), no - 1)
        fa = np.minimum(np.maximum(aim * (1.0 / (ag[1] - ag[0])), 0.0), na - 1)
        i0 = np.minimum(fx.astype(np.intp), nx - 2)
        j0 = np.minimum(fo.astype(np.intp), no - 2)
        ax, ao = fx - i0, fo - j0
        v = np.zeros(x.shape)
        t = np.zeros(x.shape)
        for di, wx in ((0, 1.0 - ax), (1, ax)):
            for dj, wo in ((0, 1.0 - ao), (1, ao)):
                cell = (i0 + di) * no + (j0 + dj)
                w2 = wx * wo
                # along the aim, linear over this corner's aims short of its second breakaway (flat beyond them)
                kk = np.minimum(fa, lok[cell])
                k = np.minimum(kk.astype(np.intp), na - 2)
                w = kk - k
                base = cell * na + k
                v += (mv[base] * (1.0 - w) + mv[base + 1] * w) * w2
                t += thr[cell] * w2
        # the observe servo pulls the valve loose a second time (a whole further jump at a level drawn anew on the
        # real valve): no prediction
        eps = 1e-12
        bad = (x < -eps) | (aim < -eps) | (aim > ag[-1] * (1 + 1e-6) + eps) | ~np.isfinite(x) | ~np.isfinite(aim)
        v[(aim >= t) | bad | (x > xg[-1] * (1 + 1e-6) + eps) | (od > og[-1] * (1 + 1e-6))] = np.nan
        # an apex below the level: no move -- unless the aim puts the observe servo's rebound into the level
        # (then the servo breaks the valve loose, unpredicted: NaN)
        below = od <= 0.0
        if below.any():
            ub = np.interp(x, xg, np.minimum(tab["servo_break_aim"], beyond))
            v[below] = np.where((aim >= ub) | bad, np.nan, 0.0)[below]
        return v

    def _load(self, th, p):
        """``model.load_torque`` (N*m toward closed) over an array of valve angles ``th`` (rad) at Δp ``p``."""
        m = self.m
        frac = np.clip(th / m.stroke_rad, 0.0, 1.0)
        return (m.spring_preload_nm + m.spring_rate_nm_per_rad * th
                + m.flow_torque_max_nm * min(max(p / m.pressure_max_kpa, 0.0), 1.0) * np.sin(np.pi * frac))

    def _levels(self, d, p, th):
        """(T_c, T_s) at Δp (N*m) and the nominal static level's twist (rad, absolute) at angle ``th``."""
        fl = self.m.friction(p)
        load = self.m.load_torque(th, p)
        return fl.valve_coulomb_nm, fl.valve_static_nm, (load + d * fl.valve_static_nm) / self.m.coupling_stiffness_nm_per_rad

    def _table(self, d, p, kick, th) -> dict:
        key = (d, p, kick, th)
        if key in self._tables:
            self._tables.move_to_end(key)
            return self._tables[key]
        lazy = None if self.exact else lazy_cache_dir()
        if lazy is not None:
            got = self.read_cached(lazy, [key])
            if got:
                self.adopt(got)
                return self._tables[key]
        tab = self._build_table(d, p, kick, th)
        if lazy is not None:
            try:
                self.save_table(lazy, key)
            except OSError:                  # an unwritable directory: the table is built, only not shared
                pass
        return tab

    def _build_table(self, d, p, kick, th) -> dict:
        key = (d, p, kick, th)
        t0 = time.process_time()
        m = self.m
        k = m.coupling_stiffness_nm_per_rad
        fl = m.friction(p)
        jump = max(fl.stick_slip_jump_rad(k), 1e-6)
        xg = np.linspace(0.0, self.excess_fraction * fl.valve_static_nm / k, self.n_excess)
        og = jump * np.geomspace(1e-3, 1.0, self.n_overdrive)
        ag = np.linspace(0.0, self.aim_fraction * jump, self.n_aim)
        rise = self._rise_at(d, p, kick, th)
        load0 = m.load_torque(th, p)
        # ... and per excess x aim one doublet whose apex stays just short of the level (og[0] below it): where
        # the observe servo's rebound from the retreat's trough overshoots into the level, even an apex below
        # it moves the valve
        X2, A2 = np.meshgrid(xg, ag, indexing="ij")
        pre2 = (load0 + d * (fl.valve_coulomb_nm + k * X2)) / k + d * (-og[0] - rise)
        # the (excess, overdrive) cells at the aims ``ka``: their preloads (the static level's twist + overdrive - rise)
        cell_pre = lambda ii, jj: (load0 + d * (fl.valve_coulomb_nm + k * xg[ii])) / k + d * (og[jj] - rise)
        nx, no, na = len(xg), len(og), len(ag)
        coarse = self.coarse_aims and na >= 5 and na % 2 == 1
        ka = np.arange(0, na, 2) if coarse else np.arange(na)
        I, J, KA = np.meshgrid(np.arange(nx), np.arange(no), ka, indexing="ij")
        # the doublet once per cell (and per excess for the short-of-the-level rows), the observe servo per aim
        ic, jc = np.meshgrid(np.arange(nx), np.arange(no), indexing="ij")
        row_pre = (load0 + d * (fl.valve_coulomb_nm + k * xg)) / k + d * (-og[0] - rise)
        end = self._simulate(d, p, kick, th, preload=np.concatenate([cell_pre(ic, jc).ravel(), row_pre]),
                             excess=np.concatenate([np.repeat(xg, no), xg]),
                             aim=np.concatenate([ag[KA].ravel(), A2.ravel()]),
                             base=np.concatenate([(I * no + J).ravel(), nx * no + np.repeat(np.arange(nx), na)]))
        moved = np.maximum(d * (end - th), 0.0)
        moves = np.empty((nx, no, na))
        moves[:, :, ka] = moved[:I.size].reshape(I.shape)
        if coarse:
            # every other aim simulated; between two of them the move is linear in the aim (the dragged regime's
            # smooth growth; no dependence at all elsewhere) -- except across the second breakaway's step, where the
            # cell's odd aims are simulated too (one more run), so the step detector below sees the full grid
            ev = moves[:, :, ka]
            moves[:, :, 1::2] = 0.5 * (ev[:, :, :-1] + ev[:, :, 1:])
            need = (np.abs(np.diff(ev, axis=2)) > AIM_STEP_JUMPS * (ag[1] - ag[0])).any(axis=2)
            if need.any():
                ci, cj = np.nonzero(need)
                ko = np.arange(1, na, 2)
                ii, jj = np.repeat(ci, len(ko)), np.repeat(cj, len(ko))
                kk = np.tile(ko, len(ci))
                mo = np.maximum(d * (self._simulate(d, p, kick, th, preload=cell_pre(ci, cj), excess=xg[ci],
                                                    aim=ag[kk], base=np.repeat(np.arange(len(ci)), len(ko)))
                                     - th), 0.0)
                moves[ii, jj, kk] = mo
        short = moved[I.size:].reshape(X2.shape) > 1e-6           # the unbroken doublet moved the valve
        first2 = np.argmax(short, axis=1)
        # the aim from which the servo breaks an unbroken valve loose (between the last still and first moved aim)
        unbroken_thr = np.where(short.any(axis=1), np.where(first2 > 0, 0.5 * (ag[np.maximum(first2 - 1, 0)]
                                                                           + ag[first2]), 0.0), np.inf)
        # the aim at which the observe servo's overshoot breaks the valve loose a second time: the first step
        # between neighbouring aims of more than AIM_STEP_JUMPS aim spacings (midway between them; inf: none)
        step = np.abs(np.diff(moves, axis=2)) > AIM_STEP_JUMPS * (ag[1] - ag[0])
        has = step.any(axis=2)
        first = np.argmax(step, axis=2)
        thr = np.full(has.shape, np.inf)
        if has.any():
            # refine the threshold between the two aims: 2**THRESHOLD_BISECTIONS - 1 aims evenly between them, all
            # cells in one run (as fine as that many bisections, in one pass)
            ci, cj = np.nonzero(has)
            kf = first[ci, cj]
            lo_a, hi_a = ag[kf], ag[kf + 1]
            lo_m, hi_m = moves[ci, cj, kf], moves[ci, cj, kf + 1]
            parts = 2 ** THRESHOLD_BISECTIONS
            frac = np.arange(1, parts) / parts
            mids = lo_a[:, None] + (hi_a - lo_a)[:, None] * frac[None, :]
            pre = (load0 + d * (fl.valve_coulomb_nm + k * xg[ci])) / k + d * (og[cj] - rise)
            mm = np.maximum(d * (self._simulate(d, p, kick, th, preload=pre, excess=xg[ci], aim=mids.ravel(),
                                                base=np.repeat(np.arange(len(ci)), parts - 1)) - th), 0.0)
            mm = mm.reshape(mids.shape)
            dragged = np.abs(mm - lo_m[:, None]) > np.abs(mm - hi_m[:, None])
            # the first dragged of the sub-aims (parts: none -- the upper tabulated aim), the threshold half a step below
            j = np.where(dragged.any(axis=1), np.argmax(dragged, axis=1) + 1, parts)
            thr[ci, cj] = lo_a + (hi_a - lo_a) * (j - 0.5) / parts
        last_ok = np.where(has, first, len(ag) - 1).astype(float)
        tab = {"excess": xg, "overdrive": og, "aim": ag, "moves": moves, "rise": rise,
               "second_break_aim": thr, "last_ok": last_ok,
               "servo_break_aim": unbroken_thr, "build_s": time.process_time() - t0}
        self.builds += 1
        self._tables[key] = tab
        while self.exact and len(self._tables) > CACHE_SIZE:
            self._tables.popitem(last=False)
        return tab

    def _simulate(self, d, p, kick, th0, *, preload, excess, aim, track_apex=False, apex_torque=True, base=None,
                  track_trough=False, retreat_periods=None, retreat_scale=None, speed0=None, hold0=None,
                  servo_offset=0.0, ref_twist=None, servo_delay_s=0.0):
        """Run the doublet on every lane at once from rest at valve angle ``th0`` with the twist at ``preload``
        (absolute, rad), the valve's static level ``T_c + K excess``; returns the valve angle at the end
        (or, with ``track_apex``, the largest twist toward ``d`` reached, absolute rad).  ``base`` (int array,
        optional): ``preload`` and ``excess`` are per *base* lane and ``aim`` per final lane, lane i starting from
        base lane ``base[i]``: the doublet itself (kick and retreat) does not depend on the aim, so it is run once
        per base lane and the state copied out to the final lanes for the observe servo (the same answers).
        (:meth:`trough`, task h36g) ``track_trough``: return the smallest coupling torque over K toward ``d`` reached
        after the kick instead (absolute twist, rad); ``retreat_periods`` (None: the model's own) and ``retreat_scale``
        (per lane, in [0, 1]: the retreat periods' command moved this fraction of the way from the hold to the model's
        own retreat command; None: the model's own) reshape the doublet for it; ``speed0`` (rad/s at the gear output,
        toward +) and ``hold0`` (N*m at the motor) the gear output's speed and the hold torque the kick starts on (None:
        at rest on the quasi-static hold); ``servo_offset`` (N*m at the motor) added to the observe servo's torque and
        ``ref_twist`` (absolute twist, rad; None: ``φe + d aim / 2``) its reference: the stage's own servo; the run
        stops once every lane's twist rises again after the retreat.  ``servo_delay_s`` (s, 0 .. one period; task
        h37t): the observe servo reads the gear output and valve angles this much before the period's start (the
        resolver delay) -- 0 (default): at the start, as before."""
        self.runs += 1
        k = self.m.coupling_stiffness_nm_per_rad
        tc = self.m.friction(p).valve_coulomb_nm
        finite = np.isfinite(excess)
        ts = np.where(finite, tc + k * np.where(finite, excess, 0.0), np.inf)
        # one implementation of the doublet for these lanes and trough_fast's floats (drivetrain_step, docs §109); a
        # valve whose every lane's static level is infinite never moves (its update skipped, the same bits)
        dbl = Doublet(self, d, p, kick, th0, valve_free=bool(finite.any()), track_apex=track_apex,
                      apex_torque=apex_torque, track_trough=track_trough, retreat_periods=retreat_periods,
                      servo_offset=servo_offset, servo_delay_s=servo_delay_s)
        s = dbl.start(ARRAYS, preload, ts, aim, speed0=speed0, hold0=hold0, ref_twist=ref_twist, scale=retreat_scale)
        n_pulse = dbl.n_pulse
        for period in range(n_pulse + self.observe_periods):
            if track_trough and period > n_pulse and np.all(dbl.turned(s)):
                break                                    # the servo has turned every lane's swing: the trough is past
            if base is not None and period == n_pulse:
                # the doublet done on the base lanes: one lane per aim from here
                s.thl, s.wl, s.th1, s.w1, s.iq, s.xq, s.th1_prev, s.ts = (
                    v[base] for v in (s.thl, s.wl, s.th1, s.w1, s.iq, s.xq, s.th1_prev, s.ts))
                s.integral, s.ones = np.zeros(len(base)), np.ones(len(base))
            dbl.period(ARRAYS, s, period)
        if track_trough:
            return d * s.trough
        return d * s.apex if track_apex else s.thl


# ---------------------------------------------------------------------- the disk cache and the background build
def lazy_cache_dir() -> Path | None:
    """The directory lazy builds share their tables through: ``$FUEL_VALVE_MOVE_TABLES_LAZY`` (:data:`LAZY_CACHE_ENV`;
    unset, "", "off", "none": None -- no disk)."""
    env = os.environ.get(LAZY_CACHE_ENV)
    if env is None or env.strip().lower() in ("", "off", "none"):
        return None
    return Path(os.path.expanduser(os.path.expandvars(env))).absolute()


def default_cache_dir() -> Path | None:
    """The move tables' cache root: ``$FUEL_VALVE_MOVE_TABLES`` if set ("", "off", "none": no disk cache, None), else
    ``$ROS_HOME/fuel_valve/move_tables`` (``ROS_HOME`` default ``~/.ros``); ``~`` and ``$VARS`` expanded."""
    env = os.environ.get(CACHE_ENV)
    if env is not None:
        if env.strip().lower() in ("", "off", "none"):
            return None
        return Path(os.path.expanduser(os.path.expandvars(env))).absolute()
    return Path(os.path.expanduser(os.environ.get("ROS_HOME") or "~/.ros")).absolute() / "fuel_valve" / "move_tables"


def _canon(obj) -> str:
    """A stable text of a signature: numbers as ``float.hex`` (so 4 and 4.0 agree, as they do in the process-wide
    share), dataclasses by field, tuples element-wise."""
    if obj is None or isinstance(obj, (bool, str)):
        return repr(obj)
    if isinstance(obj, (int, float, np.integer, np.floating)):
        return float(obj).hex()
    if isinstance(obj, (tuple, list)):
        return "(" + ",".join(_canon(v) for v in obj) + ")"
    fields = getattr(obj, "__dataclass_fields__", None)
    if fields is not None:
        return type(obj).__name__ + "{" + ",".join(f"{n}={_canon(getattr(obj, n))}" for n in fields) + "}"
    raise TypeError(f"no stable signature text for {type(obj).__name__}")


_SOURCE_DIGEST = None


def _source_digest() -> str:
    """A hash of :data:`SOURCE_FILES`' bytes ("unread" for a file that cannot be read: then only
    :data:`TABLE_VERSION` guards the cache against a code change)."""
    global _SOURCE_DIGEST
    if _SOURCE_DIGEST is None:
        h = hashlib.sha256()
        here = Path(__file__).resolve().parent
        for name in SOURCE_FILES:
            try:
                h.update((here / name).read_bytes())
            except OSError:
                h.update(b"unread")
        _SOURCE_DIGEST = h.hexdigest()
    return _SOURCE_DIGEST


def _worker(spec, keys, root, nice: int, parent: int) -> None:
    """The background build's process body: builds ``keys`` of the PulseMoves ``spec`` into the cache ``root`` at
    niceness ``nice``, one file per table; stops between tables once the process ``parent`` is gone (no orphan
    building on).  One builder per signature at a time (a lock file: two valves of one model build it once)."""
    if nice:
        try:
            os.nice(nice)
        except OSError:
            pass
    model, period, kw = spec
    moves = PulseMoves(model, period, share=False, **kw)
    try:
        import fcntl
        moves.cache_dir(root).mkdir(parents=True, exist_ok=True)
        lock = open(moves.cache_dir(root) / ".lock", "a")
        fcntl.flock(lock, fcntl.LOCK_EX)
    except (ImportError, OSError):
        lock = None
    try:
        moves.build_and_save(root, keys, stop=lambda: os.getppid() != parent)
    finally:
        if lock is not None:
            lock.close()


def _worker_main() -> None:
    """Entry of the worker process (:class:`TableBuild`): its arguments pickled on stdin."""
    import pickle
    import signal
    import sys
    signal.signal(signal.SIGINT, signal.SIG_IGN)     # the parent ends it (its own session: a launch's Ctrl-C stays out)
    _worker(*pickle.load(sys.stdin.buffer))


#: s a cancelled worker has to end after SIGTERM before it is killed (:meth:`TableBuild._stop_process`; never waited
#: for on the controller node's loop thread: a cancel under its lock only signals, the reading thread reaps)
STOP_GRACE_S = 2.0
#: the worker process's program (``python -c``; tests replace it)
WORKER_CODE = "from fuel_valve_control.core.pulse_moves import _worker_main; _worker_main()"


class TableBuild:
    """The keyed tables ``keys`` of ``moves`` made ready off the control thread (task h36b): a thread reads the
    cache ``root`` (None: no disk cache -- a temporary directory carries the worker's tables and is removed), and
    starts, for the keys it lacks, a separate low-priority process (spawn context, :func:`_worker`) that builds them
    into it; then reads them.  :attr:`state`: "reading", "building", "ready", "failed", "cancelled"; :attr:`tables`
    ({key: (table, rise)}, for :meth:`PulseMoves.adopt`) once ready; :meth:`status` a line for diagnostics.  The
    caller adopts the tables on its own thread.  :meth:`cancel` ends the worker (terminate, then kill) and the
    thread.  ``start=False``: call :meth:`start` later (tests)."""

    def __init__(self, moves: PulseMoves, keys, root=None, nice: int = 19, start: bool = True):
        self.moves, self.keys = moves, [tuple(k) for k in keys]
        self.root = None if root is None else Path(root)
        self.nice = nice
        self.state, self.reason = "reading", ""
        self.tables: dict | None = None
        self.from_cache = 0               # tables found in the cache
        self.built = 0                    # tables the worker built (found on disk after it)
        self.build_wall_s = None          # the worker's wall time, s
        self.process = None
        self._cancel = threading.Event()
        self._thread = threading.Thread(target=self._run, name="move-tables", daemon=True)
        if start:
            self.start()

    def start(self) -> None:
        self._thread.start()

    @property
    def total(self) -> int:
        return len(self.keys)

    def done(self) -> bool:
        return self.state in ("ready", "failed", "cancelled")

    def progress(self) -> int:
        """Tables ready so far (in the cache or built; a file count while the worker runs)."""
        if self.state == "building" and self._dir is not None:
            return self.from_cache + sum(self.moves.table_file(self._dir, k).is_file() for k in self._missing)
        return self.from_cache + self.built

    def status(self) -> str:
        where = f" ({self.root})" if self.root is not None else " (no disk cache)"
        if self.state == "ready":
            how = f"{self.from_cache} loaded from cache" + (f", {self.built} built in {self.build_wall_s:.0f} s"
                                                             if self.built else "")
            return f"ready: {self.total} of {self.total} ({how}){where}"
        if self.state == "building":
            pid = self.process.pid if self.process is not None else "?"
            return f"building: {self.progress()} of {self.total} ready (worker pid {pid}, nice {self.nice}){where}"
        if self.state == "reading":
            return f"reading the cache{where}"
        return f"{self.state}: {self.reason}"

    @property
    def cancelled(self) -> bool:
        """:meth:`cancel` was called (the thread and the worker may still be ending: :meth:`alive`)."""
        return self._cancel.is_set()

    def alive(self) -> bool:
        """Its reading thread or its worker process still runs (a cancelled one ends at its next file / at once)."""
        proc = self.process
        return self._thread.is_alive() or (proc is not None and proc.poll() is None)

    def serves(self, moves: "PulseMoves", keys, root=None) -> bool:
        """This build, not cancelled nor failed, makes every one of ``keys`` for ``moves``' signature from the same
        cache ``root``: a model of that signature needs no build (and no read) of its own -- it waits for this one."""
        return (not self.cancelled and self.state not in ("failed", "cancelled")
                and moves.signature == self.moves.signature
                and (None if root is None else Path(root)) == self.root
                and set(map(tuple, keys)) <= set(self.keys))

    def cancel(self, timeout: float = 5.0) -> None:
        """End the worker and the thread; the cache keeps every table finished so far.

        ``timeout`` 0 (the controller node's calls under its loop's lock, task h37d): **never blocks** -- the worker
        is sent SIGTERM and the reading thread, which owns the process, reaps it off the caller's thread (it waits,
        kills a worker that ignores SIGTERM after :data:`STOP_GRACE_S` and waits again: no zombie, no orphan;
        :meth:`alive` stays True until then).  ``timeout`` > 0 (destroy): the worker ended here (terminate, wait,
        kill, wait) and the thread waited for up to ``timeout`` s (it ends the worker itself if it starts one after
        this)."""
        self._cancel.set()
        if timeout <= 0.0:
            self._signal_process()
            if not self._thread.is_alive():
                self._stop_process()             # (not started, or ended: nothing owns the process; done at once)
            return
        self._stop_process()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout)
        self._stop_process()

    def _signal_process(self) -> None:
        """SIGTERM to a running worker; returns at once (no wait)."""
        proc = self.process
        if proc is not None and proc.poll() is None:
            try:
                proc.terminate()
            except OSError:
                pass                             # ended meanwhile

    def _stop_process(self) -> None:
        """The worker ended and reaped: SIGTERM, up to :data:`STOP_GRACE_S` s for it, then SIGKILL and a wait."""
        import subprocess
        proc = self.process
        if proc is not None and proc.poll() is None:
            self._signal_process()
            try:
                proc.wait(STOP_GRACE_S)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()                      # SIGKILL cannot be ignored: the wait ends

    def _stderr_tail(self) -> str:
        try:
            self._err.seek(0)
            lines = self._err.read().decode(errors="replace").strip().splitlines()
            return f" ({lines[-1]})" if lines else ""
        except (OSError, AttributeError):
            return ""

    _dir = None
    _missing = ()

    def _run(self) -> None:
        tmp = None
        try:
            found = {} if self.root is None else self.moves.read_cached(self.root, self.keys, stop=self._cancel.is_set)
            self.from_cache = len(found)
            missing = [k for k in self.keys if k not in found]
            if missing and not self._cancel.is_set():
                self._dir = self.root
                if self._dir is not None:
                    try:
                        self.moves.cache_dir(self._dir).mkdir(parents=True, exist_ok=True)
                    except OSError:
                        self._dir = None             # an unwritable cache: the worker's tables go through a tmp dir
                if self._dir is None:
                    self._dir = tmp = Path(tempfile.mkdtemp(prefix="fuel_valve_tables_"))
                self._missing = missing
                # a fresh interpreter (fork + exec at once: never a fork of a process with rclpy / DDS threads that
                # runs on; multiprocessing's spawn would do the same but re-runs the parent's __main__ script), in
                # its own session (a launch's Ctrl-C reaches the parent, which ends it), at low priority (nice)
                import pickle
                import subprocess
                import sys
                env = dict(os.environ)
                pkg_root = str(Path(__file__).resolve().parents[2])
                env["PYTHONPATH"] = os.pathsep.join(p for p in (pkg_root, env.get("PYTHONPATH")) if p)
                self._err = tempfile.TemporaryFile()
                t0 = time.monotonic()
                self.process = subprocess.Popen(
                    [sys.executable, "-c", WORKER_CODE],
                    stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=self._err, env=env, close_fds=True,
                    start_new_session=True)
                self.state = "building"
                try:
                    self.process.stdin.write(pickle.dumps((self.moves.spec(), missing, str(self._dir), self.nice,
                                                           os.getpid())))
                    self.process.stdin.close()
                except OSError:
                    pass                                  # it died at once: its exit code says why
                while self.process.poll() is None:
                    if self._cancel.wait(0.2):
                        self._stop_process()
                        break
                self.build_wall_s = time.monotonic() - t0
                if self._cancel.is_set():
                    self.state, self.reason = "cancelled", "cancelled"
                    return
                got = self.moves.read_cached(self._dir, missing, stop=self._cancel.is_set)
                self.built = len(got)
                found.update(got)
                if self.process.returncode != 0 or len(got) < len(missing):
                    self.state = "failed"
                    self.reason = (f"the build worker exited with code {self.process.returncode}, "
                                   f"{len(missing) - len(got)} of {self.total} tables missing{self._stderr_tail()}")
                    return
            if self._cancel.is_set():
                self.state, self.reason = "cancelled", "cancelled"
                return
            self.tables = found
            self.state = "ready"
        except Exception as exc:               # noqa: BLE001 - a failed build is a state, reported by the caller
            self.state, self.reason = "failed", f"{type(exc).__name__}: {exc}"
        finally:
            # the thread owns the worker: it never leaves one running (a cancel under the node's lock only signals
            # it, an exception here must not orphan it) -- ended and reaped before the thread ends
            try:
                self._stop_process()
            except Exception:                  # noqa: BLE001 - (already reaped by another thread's wait)
                pass
            if getattr(self, "_err", None) is not None:
                self._err.close()
            if tmp is not None:
                import shutil
                shutil.rmtree(tmp, ignore_errors=True)
