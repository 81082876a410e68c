"""The move model's doublet, one control period at a time, written once for numpy lanes and for plain floats
(task h41k, docs §109).

:meth:`PulseMoves._simulate <fuel_valve_control.core.pulse_moves.PulseMoves._simulate>` runs the fine stage's torque
doublet on thousands of lanes at once (the move tables: numpy arrays); :meth:`PulseMoves.trough_fast` runs the same
doublet on a valve that stays stuck, one lane at a time in Python floats (1-11 lanes in the control loop, where
numpy's per-operation overhead would be most of the cost, docs §105.4).  Both run the functions below: :func:`start`
(the lanes at rest on the hold), :func:`period` (the command of one control period -- the kick, the retreat, its
half period, the observe servo with its integral and its delayed samples -- held over the period) and
:func:`substeps` (the drivetrain: the drive's q current -- decoupled PI, the SVPWM voltage circle less the back-EMF,
conditional integration, the exact R-L step -- and the gear output's and the valve's semi-implicit Euler with exact
stick-slip, :func:`stick_slip`).

**The backends.** The functions are written with Python's operators (``&`` / ``|`` on conditions), ``abs``, and a
few elementwise names -- ``where(cond, a, b)``, ``clip(x, lo, hi)``, ``sqrt``, ``maximum``, ``minimum``,
``full(value, like)`` -- that this module binds to numpy: :data:`ARRAYS` runs them as written.  :data:`FLOATS` runs
the same source compiled once more at import (:func:`_for_floats`) with those names bound to ``math.sqrt``, ``max``,
``min``, every ``where(c, a, b)`` made the inline ``(a if c else b)``, ``clip`` the same two comparisons inline, and
``&`` / ``|`` ``and`` / ``or``: a float lane computes one side only, as hand-written float code would (without the
source -- a byte-code-only install -- or with a source file that no longer compiles to the loaded functions, the
same code objects run with eager ``where`` / ``clip`` functions: the same values, ~1.2 x slower).  Both compute every
value with the same IEEE operations in the same order, so a float lane and the same numpy lane agree to the bit
(``test_retreat_trough.py``); every constant is computed once, in floats, by :class:`Doublet` for both.

A valve whose static level is infinite (every lane of ``PulseMoves.trough`` and of the rise) never moves: its
stick-slip keeps its speed at exactly 0 and its angle at the start, so the kernel skips its update there
(``valve_free`` False) -- the same bits, and a float lane carries the gear output alone."""
from __future__ import annotations

import ast
import copy
import inspect
import math
import types
from typing import Callable, NamedTuple

import numpy as np

# ---------------------------------------------------------------- the elementwise names, bound to numpy (ARRAYS)
where = np.where
sqrt = np.sqrt
maximum = np.maximum
minimum = np.minimum


def clip(x, lo, hi):
    """``x`` within [``lo``, ``hi``] (``np.clip``'s values)."""
    return np.minimum(np.maximum(x, lo), hi)


def full(value, like):
    """``value`` on every lane of ``like``."""
    return np.full(np.shape(like), float(value))


# ---------------------------------------------------------------- the kernel (one source for both backends)
def stick_slip(w, t_ext, dt_inertia, t_coulomb, t_static):
    """One step of a shaft with static / Coulomb friction (no Stribeck), as the plant's kernel: stuck while the torque
    on it is within the static level (breaking away at the Coulomb level), stopped where its speed would reverse within
    the step.  ``dt_inertia``: the step over the shaft's inertia."""
    stuck = w == 0.0
    # the Coulomb torque opposes a moving shaft's own direction, a stuck one's torque
    w_new = w + dt_inertia * (t_ext - where(where(stuck, t_ext, w) > 0.0, t_coulomb, -t_coulomb))
    return where((stuck & (abs(t_ext) <= t_static)) | (w_new * w < 0.0), 0.0, w_new)


def start(dbl, preload, ts, aim, speed0, hold0, ref_twist, scale):
    """The lanes at rest at ``dbl.th0`` with the twist at ``preload`` (absolute, rad; a lane each), the valve's static
    level ``ts`` (N*m; inf: stuck), the observe servo's target ``th0 + φe + d aim / 2`` (``aim``: per lane; or
    ``ref_twist``: absolute twist, rad), the retreat's ``scale`` (None: the model's own), the gear output's speed
    ``speed0`` (rad/s, toward +; None: 0) and the hold torque ``hold0`` (N*m at the motor; None: the quasi-static hold
    ``K φp / N``, plus the motor's Coulomb friction toward d with ``park_friction``)."""
    d = dbl.d
    s = Lanes()
    s.ones = full(1.0, preload)
    s.thl = full(dbl.th0, preload)
    s.wl = full(0.0, preload)
    s.th1 = s.thl + preload
    s.w1 = full(0.0 if speed0 is None else speed0, preload)
    hold = dbl.k * preload / dbl.n_gear                                 # N*m at the motor
    if dbl.park_friction:
        # the park climbed to the preload toward d: the servo's hold carries the motor's Coulomb friction
        # too, which the stuck motor's reaction takes over (released by the kick: +5 % rise, docs §80)
        hold = hold + d * dbl.motor_coulomb
    if hold0 is not None:
        hold = full(hold0, preload)
    s.hold = hold
    s.iq = hold / dbl.kt
    s.xq = dbl.r_ohm * s.iq                                             # the current PI's integral at rest
    s.ts = ts
    # the observe servo's gear-output target
    s.ref1 = (dbl.th0 + dbl.phi_e) + d * aim / 2.0
    if ref_twist is not None:
        s.ref1 = full(dbl.th0 + float(ref_twist), aim)
    s.scale = scale
    s.integral = full(0.0, preload)
    s.th1_prev = s.th1
    s.apex = d * preload
    s.trough = d * preload
    s.th1_s, s.thl_s = s.th1, s.thl                        # the samples the next period's servo reads
    s.th1_s_prev = s.th1_s
    return s


def period(dbl, s, period):
    """Advance the lanes ``s`` through control period ``period`` (0: the kick): the command, held over the period
    (zero-order hold), then the drivetrain's substeps."""
    d, per, th0, k, n_gear, cap = dbl.d, dbl.per, dbl.th0, dbl.k, dbl.n_gear, dbl.cap
    hold = s.hold
    if period == 0:
        torque = hold + d * dbl.kick * dbl.kt
    elif period <= dbl.retreat_full:
        torque = -d * cap if dbl.cap_full else hold - d * cap
        if s.scale is not None:
            torque = hold + s.scale * (torque - hold)
    elif period == dbl.retreat_full + 1 and not dbl.retreat_cap:
        frac = 0.5
        if dbl.unmoved:
            # the last retreat period's fraction of the cap where the valve has not moved half a count
            frac = where(abs(s.thl - th0) < 0.5 * dbl.tolerance, dbl.unmoved_fraction, 0.5)
        torque = hold - d * frac * cap
    else:
        # the observe servo (FinePositioner._servo, a_ref = v_ref = 0), sampled at the period's start
        if dbl.lag:
            # (servo_delay_s) read ``lag`` substeps before the period's start
            r1, rl, w1s = s.th1_s, s.thl_s, (s.th1_s - s.th1_s_prev) / per
        else:
            r1, rl, w1s = s.th1, s.thl, (s.th1 - s.th1_prev) / per   # the stage's backward difference
        ref1 = s.ref1
        e = ref1 - r1
        if dbl.hold_moved and not dbl.hold_integral:
            s.integral = s.integral + where(abs(rl - th0) >= 0.5 * dbl.tolerance, 0.0, e * per)
        elif not dbl.hold_integral:
            s.integral = s.integral + e * per
        ff = k * (ref1 - rl) / n_gear + dbl.servo_offset
        torque = ff + (dbl.kp * e - dbl.kd * w1s + dbl.ki * s.integral) / n_gear
    s.th1_prev = s.th1
    iq_ref = clip(torque, -cap, cap) / dbl.kt * s.ones
    if dbl.lag:
        s.th1_s_prev = s.th1_s
        if dbl.lag == dbl.substeps:
            s.th1_s, s.thl_s = s.th1, s.thl
    substeps(dbl, s, iq_ref, dbl.track_trough and period >= 1)


def substeps(dbl, s, iq_ref, track_trough):
    """The drivetrain over one control period at the q-current command ``iq_ref`` (A, held)."""
    (d, k, c, dt, n_sub, wc, vlim2, kpc, kic_dt, a_rl, b_rl, c_emf, c_vd, ktn, b1, bl, dt_j1, dt_jl, tcm, tsm, tc,
     th0, load0, load_slope, valve_free, track_apex, apex_torque, sample_at) = dbl.consts
    ts = s.ts
    th1, w1, thl, wl, iq, xq = s.th1, s.w1, s.thl, s.wl, s.iq, s.xq
    trough, apex = s.trough, s.apex
    for sub in range(n_sub):
        # ---- the drive's q current (decoupled PI, voltage circle with the back-EMF, exact R-L step)
        if wc is None:
            iq_new = iq_mid = iq_ref
        else:
            emf_q = c_emf * w1                                          # ωe ψ, ωe = p N ω1
            err = iq_ref - iq
            vq = kpc * err + xq + emf_q
            if vlim2 is not None:
                vd = c_vd * (w1 * iq)                                   # |d-axis EMF| ωe Lq iq (id = 0)
                vq_max = sqrt(maximum(vlim2 - vd * vd, 0.0))
                sat = abs(vq) > vq_max
                vq = clip(vq, -vq_max, vq_max)
                xq = xq + where(sat, 0.0, kic_dt) * err                 # conditional integration
            else:
                xq = xq + kic_dt * err
            iq_new = a_rl * iq + b_rl * (vq - emf_q)
            iq_mid = 0.5 * (iq + iq_new)
        iq = iq_new
        # ---- mechanics (the plant's semi-implicit Euler with exact stick-slip), gear-output coordinates
        tk = k * (th1 - thl) + c * (w1 - wl)
        w1 = stick_slip(w1, ktn * iq_mid - tk - b1 * w1, dt_j1, tcm, tsm)
        if valve_free:
            wl = stick_slip(wl, tk - bl * wl - (load0 + load_slope * (thl - th0)), dt_jl, tc, ts)
        th1 = th1 + dt * w1
        if valve_free:
            thl = thl + dt * wl
        if track_apex:
            # the coupling's torque over K (twist + its damping's share c (ω1 - ωL) / K): what the valve's
            # static level is met by -- the twist alone peaks ~4e-5 rad lower, while it still rises
            apex = maximum(apex, d * (k * (th1 - thl) + c * (w1 - wl)) / k if apex_torque else d * (th1 - thl))
        if track_trough:
            trough = minimum(trough, d * (k * (th1 - thl) + c * (w1 - wl)) / k)
        if sub == sample_at:
            s.th1_s, s.thl_s = th1, thl
    s.th1, s.w1, s.thl, s.wl, s.iq, s.xq = th1, w1, thl, wl, iq, xq
    s.trough, s.apex = trough, apex


_KERNEL = (stick_slip, start, period, substeps)


# ---------------------------------------------------------------- the backends
class Backend(NamedTuple):
    """The kernel's entry points bound to one kind of lane (:data:`ARRAYS`, :data:`FLOATS`)."""
    name: str
    start: Callable
    period: Callable
    stick_slip: Callable
    inline: bool          #: FLOATS: compiled from the source with ``where`` / ``clip`` inline (False: eager calls)


class _Inline(ast.NodeTransformer):
    """The float lane's rewrite of the kernel's source: ``where(c, a, b)`` -> ``(a if c else b)``, ``clip(x, lo, hi)``
    -> ``(lo if x < lo else (hi if x > hi else x))`` (the kernel's arguments are pure expressions: evaluating one twice
    gives the same value), and ``c1 & c2`` / ``c1 | c2`` (the kernel uses them on conditions only) -> ``and`` /
    ``or``."""

    def visit_Call(self, node):
        self.generic_visit(node)
        name = node.func.id if isinstance(node.func, ast.Name) and not node.keywords else None
        if name == "where" and len(node.args) == 3:
            c, a, b = node.args
            return ast.copy_location(ast.IfExp(test=c, body=a, orelse=b), node)
        if name == "clip" and len(node.args) == 3:
            x, lo, hi = node.args
            cp = copy.deepcopy
            inner = ast.IfExp(test=ast.Compare(left=cp(x), ops=[ast.Gt()], comparators=[cp(hi)]), body=hi, orelse=x)
            return ast.copy_location(ast.IfExp(test=ast.Compare(left=cp(x), ops=[ast.Lt()], comparators=[cp(lo)]),
                                               body=lo, orelse=inner), node)
        return node

    def visit_BinOp(self, node):
        self.generic_visit(node)
        if isinstance(node.op, (ast.BitAnd, ast.BitOr)):
            op = ast.And() if isinstance(node.op, ast.BitAnd) else ast.Or()
            return ast.copy_location(ast.BoolOp(op=op, values=[node.left, node.right]), node)
        return node


def _where_eager(cond, a, b):
    return a if cond else b


def _clip_eager(x, lo, hi):
    return lo if x < lo else (hi if x > hi else x)


def _full_float(value, like):
    return float(value)


def _for_floats(inline: bool = True) -> tuple:
    """The kernel's functions for one lane of Python floats, and whether they are inline: the module's source of each
    compiled once more in a namespace binding the elementwise names to the float operations, every ``where`` / ``clip``
    call made an inline conditional (:class:`_Inline`); without the source, with a source file that does not compile to
    the loaded functions' code (edited since the import), or with ``inline`` False: the same code objects with eager
    ``where`` / ``clip`` functions (the same values, slower)."""
    ns = dict(globals())
    ns.update(where=_where_eager, sqrt=math.sqrt, maximum=max, minimum=min, clip=_clip_eager, full=_full_float)
    names = {fn.__name__ for fn in _KERNEL}
    try:
        if not inline:
            raise OSError("eager")
        filename = inspect.getsourcefile(stick_slip)
        if filename is None:
            raise OSError("no source file")
        with open(filename, encoding="utf-8") as f:
            tree = ast.parse(f.read(), filename)
        # the kernel's definitions (with the module's __future__ imports: the same compile flags)
        body = [node for node in tree.body if (isinstance(node, ast.ImportFrom) and node.module == "__future__")
                or (isinstance(node, ast.FunctionDef) and node.name in names)]
        # the source read must be the source the loaded functions were compiled from (not a file edited since)
        plain = compile(ast.Module(body=body, type_ignores=[]), filename, "exec")
        codes = {c.co_name: c for c in plain.co_consts if isinstance(c, types.CodeType)}
        if any(codes.get(fn.__name__) != fn.__code__ for fn in _KERNEL):
            raise OSError("the source file is not the loaded module's")
    except (OSError, TypeError, SyntaxError, UnicodeDecodeError, ValueError):
        for fn in _KERNEL:
            ns[fn.__name__] = types.FunctionType(fn.__code__, ns, fn.__name__, fn.__defaults__)
        return ns, False
    module = _Inline().visit(ast.Module(body=body, type_ignores=[]))
    exec(compile(ast.fix_missing_locations(module), filename, "exec"), ns)
    return ns, True


def _backend(name: str, ns: dict, inline: bool = False) -> Backend:
    return Backend(name, ns["start"], ns["period"], ns["stick_slip"], inline)



# ---------------------------------------------------------------- the state and the constants
class Lanes:
    """The doublet's state on its lanes (numpy arrays, or floats for one lane): gear output ``th1``, ``w1``; valve
    ``thl``, ``wl`` (rad, rad/s at the gear output); the drive's ``iq`` (A) and its PI's integral ``xq`` (V); the
    observe servo's ``integral`` (rad*s), its last sample ``th1_prev`` and the delayed samples ``th1_s``, ``thl_s``,
    ``th1_s_prev``; the valve's static level ``ts`` (N*m, inf: stuck), the ``hold`` torque (N*m at the motor), the
    servo's reference ``ref1`` (rad), the retreat's ``scale`` (None: the model's own); ``trough``, ``apex``: the
    tracked extremes toward ``d``; ``ones``: 1 on every lane."""
    __slots__ = ("th1", "w1", "thl", "wl", "iq", "xq", "integral", "th1_prev", "th1_s", "thl_s", "th1_s_prev", "ts",
                 "hold", "ref1", "scale", "trough", "apex", "ones")


class Doublet:
    """The doublet of a :class:`~fuel_valve_control.core.pulse_moves.PulseMoves` ``mv`` toward ``d`` at Δp ``p`` (kPa)
    with the kick ``kick`` (A) from valve angle ``th0`` (rad): its constants, computed once in floats for either backend
    (the keywords as :meth:`PulseMoves._simulate`'s; ``valve_free`` False: every lane's valve is stuck).
    :meth:`start` makes the lanes' state, :meth:`period` advances it one control period, :meth:`turned` tells where the
    servo has turned the swing."""

    def __init__(self, mv, d, p, kick, th0, *, valve_free=True, track_apex=False, apex_torque=True,
                 track_trough=False, retreat_periods=None, servo_offset=0.0, servo_delay_s=0.0):
        m = mv.m
        self.d, self.kick, self.th0 = d, kick, float(th0)
        self.track_trough = bool(track_trough)
        # the PulseMoves' doublet and servo settings
        self.park_friction, self.cap_full, self.retreat_cap = mv.park_friction, mv.cap_full, mv.retreat_cap
        self.hold_moved, self.hold_integral = mv.hold_moved, mv.hold_integral
        self.kp, self.kd, self.ki = mv.kp, mv.kd, mv.ki
        self.tolerance, self.unmoved_fraction = mv.tolerance, mv.unmoved_fraction
        # the last retreat period's current depends on the valve's move (else half the cap)
        self.unmoved = mv.unmoved_fraction != 0.5 and mv.tolerance > 0.0
        self.n_gear, self.k, c = m.gear_ratio, m.coupling_stiffness_nm_per_rad, m.coupling_damping_nms
        self.kt = kt = m.torque_constant_nm_per_a
        fl = m.friction(p)
        tc = fl.valve_coulomb_nm
        self.motor_coulomb = fl.motor_coulomb_nm
        # motor friction at the gear output (the plant's motor-shaft levels x N)
        tcm, tsm = fl.motor_coulomb_nm * self.n_gear, fl.motor_static_nm * self.n_gear
        self.r_ohm = r_ohm = m.motor_resistance_ohm
        lq = m.motor_lq_h
        pole = m.motor_pole_pairs
        psi = kt / (1.5 * pole)
        self.per = mv.period
        self.substeps = mv.substeps
        dt = self.per / self.substeps
        self.cap = mv.cap * kt
        # the load, linear about th0 over the doublet's few mrad (its curvature: < 1e-6 rad of twist over 5e-3 rad)
        load0 = m.load_torque(self.th0, p)
        frac0 = self.th0 / m.stroke_rad
        load_slope = m.spring_rate_nm_per_rad + (
            m.flow_torque_max_nm * m.pressure_fraction(p) * math.pi / m.stroke_rad * math.cos(math.pi * frac0)
            if 0.0 < frac0 < 1.0 else 0.0)
        self.phi_e = (load0 + d * tc) / self.k
        vlim2 = None if mv.vlim is None else mv.vlim ** 2
        kpc = kic_dt = a_rl = b_rl = None
        if mv.wc is not None:
            kpc, kic = lq * mv.wc, r_ohm * mv.wc
            kic_dt = kic * dt
            a_rl = math.exp(-r_ohm * dt / lq) if r_ohm > 0.0 else 1.0
            b_rl = (1.0 - a_rl) / r_ohm if r_ohm > 0.0 else dt / lq
        c_emf, c_vd = psi * pole * self.n_gear, lq * pole * self.n_gear
        self.retreat_full = mv.retreat_full if retreat_periods is None else max(int(retreat_periods), 0)
        self.n_pulse = 2 + self.retreat_full - (1 if mv.retreat_cap else 0)
        self.servo_offset = servo_offset
        # (servo_delay_s) the substep after which the servo's samples are taken: the period's end less the delay
        self.lag = min(max(int(round(float(servo_delay_s) / dt)), 0), self.substeps)
        sample_at = self.substeps - 1 - self.lag if 0 < self.lag < self.substeps else -1
        # what :func:`substeps` reads, in one tuple
        self.consts = (d, self.k, c, dt, self.substeps, mv.wc, vlim2, kpc, kic_dt, a_rl, b_rl, c_emf, c_vd,
                       kt * self.n_gear, m.b1, m.valve_viscous_nms, dt / m.j1, dt / m.valve_inertia_kgm2, tcm, tsm, tc,
                       self.th0, load0, load_slope, bool(valve_free), bool(track_apex), bool(apex_torque), sample_at)

    def start(self, backend: Backend, preload, ts, aim, *, speed0=None, hold0=None, ref_twist=None,
              scale=None) -> Lanes:
        """The lanes' state at the kick (:func:`start`)."""
        return backend.start(self, preload, ts, aim, speed0, hold0, ref_twist, scale)

    def period(self, backend: Backend, s: Lanes, period: int) -> None:
        """Advance ``s`` one control period (:func:`period`)."""
        backend.period(self, s, period)

    def turned(self, s: Lanes):
        """Per lane: the gear output runs toward d relative to the valve (the servo has turned the retreat's swing)."""
        return self.d * (s.w1 - s.wl) > 0.0


#: numpy arrays, every lane at once
ARRAYS = _backend("arrays", globals())
#: one lane in Python floats (the same source; ``where`` inline)
FLOATS = _backend("floats", *_for_floats())
