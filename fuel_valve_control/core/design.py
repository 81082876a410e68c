"""Gain design from the nominal model: PI(D) loop shaping, pole placement, LQR, Kalman.

Every function takes physical/design parameters and returns gains; nothing here is a pasted
number.  Conventions: the discrete plant is the ZOH model of :mod:`.model` at the loop period;
the integral state is ``ζ[k+1] = ζ[k] + T (r - θL)``; the control law is
``u = u_ff - K (x̂ - x_ref) + K_I ζ`` (motor torque, N*m); observers are *current*
estimators (the estimate at k uses y[k]).
"""
from __future__ import annotations

import cmath
import functools
import math
import warnings
from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_discrete_are
from scipy.signal import place_poles

from ..common.drive import steady_voltage, voltage_limit
from ..common.paramspec import ConfigError

from .model import NominalModel


# ------------------------------------------------------------------------------ baseline PI(D)
@dataclass(frozen=True)
class PIDGains:
    """Series PI(D): ``C(s) = kp (1 + wi/s) (1 + s/wz) / (1 + s/wp)`` on the valve-angle error,
    output motor torque (N*m).  ``crossover``, ``phase_margin_deg`` are what the design achieved
    on the nominal linear plant including the sample-and-hold delay."""

    kp: float
    wi: float
    wz: float
    wp: float
    crossover_rad_s: float
    phase_margin_deg: float


def valve_response(model: NominalModel, w: float) -> complex:
    """θL / u (rad per N*m of motor torque) of the linear nominal model at ``s = jw``."""
    a, bu, _, _ = model.continuous()
    s = 1j * w
    x = np.linalg.solve(s * np.eye(4) - a, bu[:, 0])
    return complex(x[2])


def design_pid(model: NominalModel, period_s: float, crossover_hz: float, phase_margin_deg: float,
               integral_ratio: float, filter_ratio: float) -> PIDGains:
    """Loop-shape the vendor-style PI(D) for a crossover and phase margin on the linear plant.

    The sample-and-hold and computation are modelled as a delay of 1.5 periods.  The lead
    zero is solved for the phase margin; ``kp`` then puts the crossover where asked.
    """
    wc = 2.0 * math.pi * crossover_hz
    wi = integral_ratio * wc
    wp = filter_ratio * wc
    plant = valve_response(model, wc) * cmath.exp(-1j * wc * 1.5 * period_s)
    pi_part = 1.0 + wi / (1j * wc)
    needed_lead = math.radians(phase_margin_deg - 180.0) - cmath.phase(plant) - cmath.phase(pi_part)
    needed_lead = (needed_lead + math.pi) % (2 * math.pi) - math.pi
    # lead of (1 + s/wz)/(1 + s/wp) at wc:  atan(wc/wz) - atan(wc/wp) = needed_lead
    target = needed_lead + math.atan(wc / wp)
    if not 0.0 < target < math.pi / 2:
        raise ConfigError(f"controller: a PI(D) with pi.derivative_filter_ratio={filter_ratio:g} cannot reach "
                          f"{phase_margin_deg:g} deg phase margin at {crossover_hz:g} Hz")
    wz = wc / math.tan(target)
    lead = (1.0 + 1j * wc / wz) / (1.0 + 1j * wc / wp)
    kp = 1.0 / abs(plant * pi_part * lead)
    loop = kp * plant * pi_part * lead
    return PIDGains(kp, wi, wz, wp, wc, 180.0 + math.degrees(cmath.phase(loop)))


# ------------------------------------------------------------------------------ state feedback
@dataclass(frozen=True)
class StateFeedback:
    """``u = -K x + K_I ζ`` on the augmented discrete model, plus the closed-loop poles (z)."""

    k: np.ndarray          # shape (4,)
    ki: float
    poles: np.ndarray


def augmented(ad: np.ndarray, bu: np.ndarray, period_s: float):
    """Augment with the integral of ``r - θL``: ``ζ[k+1] = ζ[k] - T θL[k]`` (+ T r)."""
    n = ad.shape[0]
    aa = np.zeros((n + 1, n + 1))
    aa[:n, :n] = ad
    aa[n, 2] = -period_s
    aa[n, n] = 1.0
    ba = np.vstack([bu, [[0.0]]])
    return aa, ba


def continuous_poles(model: NominalModel, bandwidth_hz: float, damping: float, integrator_ratio: float,
                     resonance_damping: float, resonance_ratio: float) -> np.ndarray:
    """Desired continuous closed-loop poles (rad/s): dominant pair, integrator, coupling mode."""
    wn = 2.0 * math.pi * bandwidth_hz
    wr = model.resonance_rad_s * resonance_ratio
    poles = []
    for w, z in ((wn, damping), (wr, resonance_damping)):
        if z < 1.0:
            wd = w * math.sqrt(1.0 - z * z)
            poles += [complex(-z * w, wd), complex(-z * w, -wd)]
        else:  # overdamped: two real poles
            root = w * math.sqrt(z * z - 1.0)
            poles += [-z * w + root, -z * w - root]
    poles.append(-integrator_ratio * wn)
    return np.array(poles)


def to_discrete(poles_s: np.ndarray, period_s: float) -> np.ndarray:
    return np.exp(np.asarray(poles_s) * period_s)


def place_state_feedback(model: NominalModel, period_s: float, poles_s: np.ndarray) -> StateFeedback:
    """Pole placement on the augmented ZOH model (scipy ``place_poles``)."""
    ad, bu, _, _ = model.discrete(period_s)
    aa, ba = augmented(ad, bu, period_s)
    gain = _place(aa, ba, to_discrete(poles_s, period_s))
    return StateFeedback(gain[0, :4].copy(), float(-gain[0, 4]), np.linalg.eigvals(aa - ba @ gain))


def hold_stiff_state_feedback(model: NominalModel, period_s: float, bandwidth_hz: float, damping: float,
                              integrator_ratio: float, resonance_damping: float,
                              resonance_ratio: float) -> tuple[StateFeedback, np.ndarray]:
    """Pole placement (:func:`continuous_poles`, :func:`place_state_feedback`) whose coupling-mode
    damping is at most ``resonance_damping`` and lowered, where needed, until the gain on the
    gear-output angle θ1 is not negative: ``(feedback, continuous poles)``.

    Why: the valve spends most of its time stuck by static friction, and then the loop acts on
    the motor alone through the coupling.  With the valve locked, a motor torque ``u`` twists
    the coupling ``N u / K`` at rest, while the state feedback answers ``-k1`` per rad of θ1, so
    the drive's static stiffness against its own integrator (and the hold's relax, which moves
    the integrator) is ``K (1 + k1 N / K)``: a negative ``k1`` takes it away.  Damping a stiff
    coupling's mode at its own frequency asks the placement for exactly that (non-collocated:
    ``k1`` negative, ``k3`` on the valve angle large): K 1500 N*m/rad at ζr 0.2 gave
    ``1 + k1 N/K = -0.008`` -- the relax of a stuck valve swung the drive from one edge of the
    static band to the other (6 -> 15 N*m in 0.15 s) and the hold hunted 1.2e-2 rad (section 35).
    The nominal valve (K 480) has ``k1 > 0`` at the configured damping and is designed as before.
    The coupling's own damping is left to it below that (a bisection over the damping; the
    lowest tried is 1 % of ``resonance_damping``)."""
    def placed(zr: float):
        poles = continuous_poles(model, bandwidth_hz, damping, integrator_ratio, zr, resonance_ratio)
        return place_state_feedback(model, period_s, poles), poles

    fb, poles = placed(resonance_damping)
    if fb.k[0] >= 0.0:
        return fb, poles
    lo, hi = 0.01 * resonance_damping, resonance_damping
    best = placed(lo)
    if best[0].k[0] < 0.0:
        return best
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        trial = placed(mid)
        if trial[0].k[0] >= 0.0:
            lo, best = mid, trial
        else:
            hi = mid
    return best


def lqr_state_feedback(model: NominalModel, period_s: float, q, r: float) -> StateFeedback:
    """Discrete LQR on the augmented model (``solve_discrete_are``); ``q`` the 5 x 5 state
    weight on [θ1, ω1, θL, ωL, ζ] (a 1-D array: its diagonal), ``r`` the motor-torque weight."""
    ad, bu, _, _ = model.discrete(period_s)
    aa, ba = augmented(ad, bu, period_s)
    q = np.asarray(q, dtype=float)
    q = np.diag(q) if q.ndim == 1 else q
    p = solve_discrete_are(aa, ba, q, np.array([[r]]))
    gain = np.linalg.solve(ba.T @ p @ ba + r, ba.T @ p @ aa)[0]
    return StateFeedback(gain[:4].copy(), float(-gain[4]), np.linalg.eigvals(aa - ba @ gain[None, :]))


def bryson_weights(model: NominalModel, position_rad: float, velocity_rad_s: float, twist_rad: float,
                   integral_rad_s: float, current_a: float) -> tuple[np.ndarray, float]:
    """Bryson's rule on the physical quantities: each weighted by 1/(acceptable value)².

    The cost is ``(θL/pos)² + ((θ1-θL)/twist)² + (ω1/vel)² + (ωL/vel)² + (ζ/integral)²`` plus
    ``(u/(current kt))²``: the twist of the coupling is weighted as a twist (cross terms of
    θ1 and θL), so the weight damps the coupling mode instead of asking the gear angle to
    stand still (a weight on θ1 alone left the 89 Hz mode at ζ 0.09).

    Returns the 5 x 5 state weight on [θ1, ω1, θL, ωL, ζ] and the motor-torque weight.
    """
    cz = np.array([[0.0, 0.0, 1.0, 0.0, 0.0],       # valve angle
                   [1.0, 0.0, -1.0, 0.0, 0.0],      # coupling twist
                   [0.0, 1.0, 0.0, 0.0, 0.0],       # gear-output velocity
                   [0.0, 0.0, 0.0, 1.0, 0.0],       # valve velocity
                   [0.0, 0.0, 0.0, 0.0, 1.0]])      # integrated error
    w = np.diag([1.0 / position_rad ** 2, 1.0 / twist_rad ** 2, 1.0 / velocity_rad_s ** 2,
                 1.0 / velocity_rad_s ** 2, 1.0 / integral_rad_s ** 2])
    torque = current_a * model.torque_constant_nm_per_a
    return cz.T @ w @ cz, 1.0 / torque ** 2


# ------------------------------------------------------------------------------ observers
def observer_poles(model: NominalModel, bandwidth_hz: float, ratio: float, period_s: float) -> np.ndarray:
    """Continuous poles (rad/s) of the disturbance observer (six states): a well-damped pair
    ``ratio`` times the controller's dominant frequency, a pair at least as fast as the
    coupling mode, and two real disturbance poles at the dominant observer frequency; all
    kept below 0.45 x Nyquist so the discrete observer stays well conditioned."""
    w_max = 0.45 * math.pi / period_s
    w_slow = min(ratio * 2.0 * math.pi * bandwidth_hz, w_max)
    w_fast = min(max(model.resonance_rad_s, 1.5 * w_slow), w_max)
    poles = []
    for w, z in ((w_slow, 0.8), (w_fast, 0.7)):
        wd = w * math.sqrt(1.0 - z * z)
        poles += [complex(-z * w, wd), complex(-z * w, -wd)]
    poles += [-0.7 * w_slow, -0.9 * w_slow]
    return np.array(poles)


def current_estimator_gain(ad: np.ndarray, cm: np.ndarray, poles_z: np.ndarray) -> np.ndarray:
    """Gain L of ``x̂ = x̄ + L (y - C x̄)``, ``x̄ = A x̂⁻ + B u``: error dynamics ``A - L C A``."""
    return _place(ad.T, (cm @ ad).T, poles_z).T


def kalman_gain(ad: np.ndarray, g: np.ndarray, cm: np.ndarray, q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Steady-state Kalman gain of the current estimator (filtered form): ``M = P Cᵀ (C P Cᵀ + R)⁻¹``
    with ``P`` the a-priori covariance from the dual Riccati equation."""
    p = solve_discrete_are(ad.T, cm.T, g @ q @ g.T, r)
    return p @ cm.T @ np.linalg.inv(cm @ p @ cm.T + r)


# ------------------------------------------------------------------------------ planned moves
@dataclass(frozen=True)
class TrajectoryLimits:
    """Speed and peak acceleration of planned moves (valve side, rad/s and rad/s²) and what
    they were designed against: the worst known resisting torque (valve side, N*m), the
    current the peak acceleration takes against it (A) and the voltage budget (V)."""

    max_velocity_rad_s: float
    max_acceleration_rad_s2: float
    resisting_torque_nm: float
    planned_current_a: float
    voltage_budget_v: float


def worst_resisting_torque(model: NominalModel) -> float:
    """Largest torque (valve side, N*m) the model knows to oppose an opening move: return
    spring + flow torque at maximum Δp over the stroke plus the drivetrain's Coulomb friction
    there (valve + N x motor)."""
    pmax = model.pressure_max_kpa
    load = max(model.load_torque(x, pmax) for x in np.linspace(0.0, model.stroke_rad, 65))
    lv = model.friction(pmax)
    return load + lv.valve_coulomb_nm + model.gear_ratio * lv.motor_coulomb_nm


@functools.lru_cache(maxsize=32)     # deterministic in its (hashable) arguments: a driver build cost 3 ms of it
def design_trajectory(model: NominalModel, supply_voltage_v: float, peak_current_a: float,
                      current_fraction: float, voltage_fraction: float) -> TrajectoryLimits:
    """Limits of the planned moves (sin²-shaped acceleration phases, :mod:`.trajectory`) from
    the drive's ratings and the supply it runs from.

    The dq voltage the drive needs at valve speed ``v`` with q current ``i`` is the resistive
    drop plus the back-EMF ``ωe ψf`` and the cross-coupling ``ωe Lq i``
    (:func:`~fuel_valve_control.common.drive.steady_voltage`, ``ωe = p N v``); the inverter
    gives at most ``Vdc / sqrt 3``.  The current a move needs is that for inertia
    ``(JL + N² Jm) a`` + viscous + the worst resisting torque (:func:`worst_resisting_torque`).

    * Top speed: the fastest cruise that needs no more than ``voltage_fraction`` of the circle
      (the rest stays for the feedback's corrections): it follows the supply, so at 18 V a
      move plans slower instead of asking for a voltage the drive does not have (its current
      loop would saturate and the valve fall behind the plan).
    * Peak acceleration: the smaller of what ``current_fraction * peak_current_a`` gives
      against the worst resisting torque and what keeps the whole acceleration phase up to
      the top speed inside the full circle (resistive drop and cross-coupling grow with the
      current; at a low supply this binds).

    Raises :class:`ConfigError` when the budget cannot hold the worst load."""
    n, kt = model.gear_ratio, model.torque_constant_nm_per_a
    resist = worst_resisting_torque(model)
    current = current_fraction * peak_current_a
    inertia = model.total_inertia
    a_current = (kt * n * current - resist) / inertia
    circle = voltage_limit(supply_voltage_v)
    budget = voltage_fraction * circle
    viscous = model.valve_viscous_nms + model.b1
    s = np.linspace(0.0, 1.0, 101)                         # fraction of an acceleration phase
    shape_v = s - np.sin(2.0 * np.pi * s) / (2.0 * np.pi)   # v / v_top through a sin² phase
    shape_a = np.sin(np.pi * s) ** 2                        # a / a_peak

    def worst_voltage(v_top: float, a_peak: float) -> float:
        v = v_top * shape_v
        i = (inertia * a_peak * shape_a + viscous * v + resist) / (kt * n)
        return max(steady_voltage(n * vk, ik, model.motor_resistance_ohm, model.motor_lq_h,
                                  model.motor_pole_pairs, kt) for vk, ik in zip(v, i))

    if a_current <= 0.0 or worst_voltage(0.0, 0.0) >= budget:
        raise ConfigError(f"controller: {current:.3g} A (trajectory.current_fraction x limits.peak_current_a) "
                          f"at {supply_voltage_v:g} V cannot move the worst known load "
                          f"({resist:.3g} N*m at the valve)")

    def largest(ok, hi: float) -> float:
        """Bisection for the largest x in [0, hi] with ok(x) (ok holds at 0, fails beyond)."""
        lo = 0.0
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if ok(mid) else (lo, mid)
        return lo

    # back-EMF alone uses the whole budget at budget / (ψf p N)
    v_top = largest(lambda v: worst_voltage(v, 0.0) <= budget, budget / (kt / 1.5) / n)
    a_max = a_current if worst_voltage(v_top, a_current) <= circle else \
        largest(lambda a: worst_voltage(v_top, a) <= circle, a_current)
    return TrajectoryLimits(v_top, float(a_max), float(resist), current, budget)


def _place(a: np.ndarray, b: np.ndarray, poles: np.ndarray) -> np.ndarray:
    """``place_poles`` gain with the poles checked.  scipy warns when its robustness
    iteration (which only tunes the eigenvectors) stops early; the placement itself is
    verified here instead, so that warning is silenced."""
    poles = _distinct(poles)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        gain = place_poles(a, b, poles).gain_matrix
    got = np.sort_complex(np.linalg.eigvals(a - b @ gain))
    want = np.sort_complex(poles)
    if not np.allclose(got, want, atol=1e-6 * max(1.0, float(np.max(np.abs(want))))):
        raise ValueError(f"pole placement failed: wanted {want}, got {got}")
    return gain


def _distinct(poles: np.ndarray) -> np.ndarray:
    """place_poles rejects repeated poles beyond the input rank: nudge exact repeats apart."""
    out = list(np.asarray(poles, dtype=complex))
    for i in range(len(out)):
        for j in range(i):
            if abs(out[i] - out[j]) < 1e-9:
                out[i] = out[i] * (1.0 - 1e-4 * (i + 1))
    return np.array(out)
