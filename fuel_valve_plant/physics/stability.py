"""Numerical stability of the fixed-step physics kernel for a parameter set (issue 13).

The kernel (:mod:`.kernel`) integrates the dq currents exactly over a step but everything
that couples them to the shafts (back-EMF, torque, cross-coupling) and the two-mass drivetrain
explicitly (semi-implicit Euler).  An explicit scheme is stable only while the fastest
eigenvalue λ of what it integrates stays inside its region, |λ|·dt of order 1: a stiff or
strongly damped coupling (damping c over the reduced inertia of the two shafts), a strong
electromechanical coupling (the pole ω² ≈ 1.5 p² ψ² / (L J), growing with the pole pairs p and
the flux linkage ψ) or a fast current loop can leave it, and the physics diverges to NaN in a
few steps (in-range ``motor.pole_pairs`` 32, ``motor.flux_linkage_wb`` 1.0 and
``coupling.damping_nms`` 100 did).  Which combination does is not a per-parameter range, so
the check is the scheme itself: the one-step map of the kernel, linearised by finite
differences around a slowly moving state with friction, backlash, stops and voltage limit out
of the way (they only dissipate or clip), must have a spectral radius of at most 1.
"""
from __future__ import annotations

import numpy as np

from fuel_valve_control.common.paramspec import ConfigError, ParamSet

from . import kernel as K

#: the states of the linear part of the step map: dq currents, shafts, current-PI integrators
_STATES = (K.S_ID, K.S_IQ, K.S_THM, K.S_WM, K.S_THL, K.S_WL, K.S_XD, K.S_XQ)
#: spectral radius above 1 still accepted: the finite-difference error on a marginally stable
#: (undamped, |λ| = 1) mode of the symplectic scheme, and the lossless ideal motor (R = 0: no
#: loss at all, so the saturated EMF loop is marginal, 1 + 2.6e-4 with the data-sheet motor; the
#: energy-balance test's plant).  Values that diverge are at 1 + 1.3e-3 and beyond (10 % past
#: the bound g = 2 (1 - a) of :func:`step_map_spectral_radius`; pole pairs 16: 1 + 2.8e-3).
RADIUS_TOLERANCE = 5e-4


def step_map_spectral_radius(ps: ParamSet, saturated: bool = False) -> float:
    """Spectral radius of the kernel's one-step map for parameter set ``ps`` (drive enabled,
    zero current reference), linearised around mid-stroke with both shafts turning slowly
    forward (so no shaft stops within the step): > 1 means the physics diverges.

    ``saturated``: the current regulator at its voltage limit (the voltage no longer follows
    the current: regulator gains and back-EMF decoupling out of the map).  Then the back-EMF
    closes an explicit loop current -> torque -> speed -> EMF -> current whose gain per step is
    g = 1.5 p² ψ² b dt / Jm (b = the current's response to a volt over the step), and the step
    map is stable only while g < 2 (1 - a) (a = exp(-R dt / Lq)): with the data-sheet motor
    g ≈ 1e-3 against 5.4e-2; ``motor.pole_pairs`` 32 or ``motor.flux_linkage_wb`` 1.0 are far beyond."""
    from .plant import pack_parameters          # plant imports this module's caller (params)
    S, O, P, ring = K.new_arrays(1)
    pack_parameters(ps, P)
    for idx in (K.P_TCM, K.P_TSM, K.P_TCL, K.P_TSL, K.P_SCATTER, K.P_RIPPLE, K.P_LUGRE, K.P_BACKLASH_HALF):
        P[idx] = 0.0                            # friction and backlash: dissipative / piecewise
    if saturated:
        for idx in (K.P_KPD, K.P_KID, K.P_KPQ, K.P_KIQ, K.P_DECOUPLE):
            P[idx] = 0.0
    n, stroke = P[K.P_N], P[K.P_STROKE]
    # an equilibrium in uniform motion: the spring's preload cancelled at mid-stroke (its rate
    # stays), no flow torque or load (slow, not stiff), so no shaft reverses within the step
    P[K.P_SPRING0] = -P[K.P_SPRINGK] * 0.5 * stroke
    P[K.P_FLOWMAX] = P[K.P_LOAD] = 0.0
    wl = 1e-3 * stroke                          # slow: back-EMF far below the bus voltage
    S[K.S_THL], S[K.S_WL] = 0.5 * stroke, wl
    S[K.S_THM], S[K.S_WM] = 0.5 * stroke * n, n * wl
    if saturated:       # the held voltage balances the back-EMF: no braking current, uniform motion
        S[K.S_XQ] = P[K.P_POLES] * n * wl * P[K.P_PSI]
    scatter = np.zeros(1)
    states = list(_STATES)

    def step(x: np.ndarray) -> np.ndarray:
        s = S.copy()
        s[states] = x
        K.advance(s, O.copy(), P, ring.copy(), 1, 0.0, 1.0, scatter)
        return s[states]

    x0 = S[states]
    f0 = step(x0)
    jac = np.empty((len(states), len(states)))
    for j in range(len(states)):
        h = 1e-7 * max(abs(x0[j]), 1e-3)
        x = x0.copy()
        x[j] += h
        jac[:, j] = (step(x) - f0) / h
    if not np.all(np.isfinite(jac)):
        return float("inf")
    return float(np.max(np.abs(np.linalg.eigvals(jac))))


def check_step_stability(ps: ParamSet) -> None:
    """Raise :class:`ConfigError` if the fixed-step physics would diverge with ``ps``."""
    radius = max(step_map_spectral_radius(ps), step_map_spectral_radius(ps, saturated=True))
    if not radius <= 1.0 + RADIUS_TOLERANCE:
        raise ConfigError(
            f"plant: these parameters make the {ps['physics_rate_hz']:g} Hz fixed-step physics unstable (one-step "
            f"spectral radius {radius:.3g} > 1): a fast mode -- coupling damping/stiffness over the shaft inertias, "
            "or the electromechanical pole (pole pairs, flux linkage, inductance, rotor inertia) -- is beyond "
            "the explicit scheme; raise physics_rate_hz or use physical values")
