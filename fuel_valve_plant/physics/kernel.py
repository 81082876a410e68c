"""Fixed-step physics kernel of the actuator: PMS motor + dq current loop + two-mass drivetrain.

One call advances ``n`` physics steps of length ``dt`` with a constant current reference.
The code is plain Python on float64 arrays so it runs as is, and is compiled with numba when
numba is importable (set ``FUEL_VALVE_NO_JIT=1`` to force the interpreted version; the tests
check both give the same trajectory).  Indices into the arrays are module constants.

Per step:

1. Electrical: the digital dq PI current regulators (running at the physics rate, like a
   PWM-synchronous drive) compute the voltage, limited to the SVPWM circle ``Vdc/sqrt(3)``
   with conditional-integration anti-windup.  The R-L dynamics are integrated exactly for
   the step (exponential), with the rotational EMF and cross-coupling held over the step.
   With the drive disabled the bridge only freewheels: currents decay against the bus and
   stay at zero while the back-EMF is below it.
2. Mechanics: semi-implicit (symplectic) Euler on both shafts.  Stick-slip is exact: a shaft
   at rest stays at rest (velocity exactly 0, angle unchanged, friction = reaction) while the
   applied torque is within the static level; a moving shaft whose velocity would cross zero
   in a step is stopped at zero and re-checked next step.  No smoothing, hence no creep while
   stuck and no chattering at zero speed.  LuGre is the alternative smooth model.
3. Valve stops at 0 and the stroke are inelastic: the valve stops dead and the stop supplies
   whatever reaction keeps it there.

Friction that does not repeat exactly (valve shaft, both models): both valve levels are
multiplied by a position ripple ``1 + a sin(2π θL/λ + φ)``, and the static level by a factor
drawn anew every time the valve comes to rest (stick-slip) or, having slid faster than the
Stribeck speed, stops or reverses (LuGre), from the
caller's array of standard-normal draws ``scatter``: ``1 + σ n`` with ``n`` clipped to ±3,
never below the Coulomb level.  ``S[S_SCAT_IDX]`` counts the draws used (the caller refills
the array); ``S[S_SCAT]`` is the factor in force.  With ``a = σ = 0`` both factors are exactly 1
and the trajectory is bit-for-bit the one without this feature.
"""
from __future__ import annotations

import math
import os

import numpy as np

# ---- state vector S -----------------------------------------------------------------------
S_ID, S_IQ, S_THM, S_WM, S_THL, S_WL, S_XD, S_XQ, S_ZM, S_ZL, S_RING, S_SCAT, S_SCAT_IDX, S_SCAT_ARMED = range(14)
N_STATE = 14

# ---- outputs O (values of the last step; E_IN accumulates) -----------------------------
O_VD, O_VQ, O_TE, O_TFM, O_TFL, O_TSPRING, O_TFLOW, O_TCOUPLING, O_EIN = range(9)
N_OUT = 9

# ---- parameters P ---------------------------------------------------------------------------
(P_DT, P_POLES, P_R, P_LD, P_LQ, P_PSI, P_KPD, P_KID, P_KPQ, P_KIQ, P_VLIM, P_DECOUPLE,
 P_AD, P_BD, P_AQ, P_BQ, P_JM, P_BM, P_N, P_BACKLASH_HALF, P_K, P_C, P_JL, P_BL, P_STROKE,
 P_LUGRE, P_TCM, P_TSM, P_VSM, P_TCL, P_TSL, P_VSL, P_SIG0M, P_SIG1M, P_SIG0L, P_SIG1L,
 P_SPRING0, P_SPRINGK, P_FLOWMAX, P_LOAD, P_SCATTER, P_RIPPLE, P_RIPPLE_K, P_RIPPLE_PHASE) = range(44)
N_PARAM = 44

#: clip of the standard-normal draws of the static-level scatter (in standard deviations)
SCATTER_CLIP = 3.0


def _shaft_stick_slip(w, t_ext, inertia, t_coulomb, t_static, v_stribeck, dt):
    """One step of a shaft with static/Coulomb(/Stribeck) friction.

    ``t_ext`` is every torque on the shaft except friction (viscous included).  Returns the new
    velocity and the friction torque that acted (signed, on the shaft).
    """
    if w == 0.0:
        if abs(t_ext) <= t_static:
            return 0.0, -t_ext                    # stuck: friction is the reaction
        direction = 1.0 if t_ext > 0.0 else -1.0  # breakaway
        level = t_static if v_stribeck > 0.0 else t_coulomb
        friction = -direction * level
        return dt * (t_ext + friction) / inertia, friction
    direction = 1.0 if w > 0.0 else -1.0
    level = t_coulomb
    if v_stribeck > 0.0:
        ratio = w / v_stribeck
        level = t_coulomb + (t_static - t_coulomb) * math.exp(-ratio * ratio)
    friction = -direction * level
    w_new = w + dt * (t_ext + friction) / inertia
    if w_new * w < 0.0:                           # would reverse within the step: stop here
        return 0.0, friction
    return w_new, friction


def _shaft_lugre(w, z, t_ext, inertia, t_coulomb, t_static, v_stribeck, sigma0, sigma1, dt):
    """One step of a shaft with LuGre friction; returns (w_new, z_new, friction on the shaft).

    The bristle state is integrated exactly for a velocity held over the step:
    ``dz/dt = v - sigma0 |v| z / g(v)`` relaxes exponentially to ``g(v) sgn(v) / sigma0``.
    """
    z_new = z
    if w != 0.0:
        ratio = w / v_stribeck
        g = t_coulomb + (t_static - t_coulomb) * math.exp(-ratio * ratio)
        if g > 0.0:
            rate = sigma0 * abs(w) / g
            z_ss = (g / sigma0) * (1.0 if w > 0.0 else -1.0)
            z_new = z_ss + (z - z_ss) * math.exp(-rate * dt)
        else:
            z_new = 0.0
    friction = -(sigma0 * z_new + sigma1 * (z_new - z) / dt)
    return w + dt * (t_ext + friction) / inertia, z_new, friction


def _draw_scatter(S, scatter, sigma):
    """Next static-level factor ``1 + σ n`` (n clipped to ±SCATTER_CLIP), consuming one draw."""
    idx = int(S[S_SCAT_IDX])
    draw = scatter[idx % scatter.shape[0]]
    S[S_SCAT_IDX] = idx + 1
    draw = min(max(draw, -SCATTER_CLIP), SCATTER_CLIP)
    return 1.0 + sigma * draw


def advance(S, O, P, ring, n, iq_ref, enabled, scatter):
    """Advance the plant ``n`` physics steps with q-current reference ``iq_ref`` (A).

    ``enabled`` (1.0/0.0) is the drive enable.  ``ring`` (R x 2) receives the true motor and
    valve angles of every step, for the resolver delay line; ``S[S_RING]`` is its write index.
    ``scatter`` holds standard-normal draws for the valve static-level scatter (used only when
    ``P[P_SCATTER] > 0``; index ``S[S_SCAT_IDX]``, taken modulo its length).
    """
    dt = P[P_DT]
    poles = P[P_POLES]
    ld = P[P_LD]
    lq = P[P_LQ]
    psi = P[P_PSI]
    vlim = P[P_VLIM]
    n_gear = P[P_N]
    stroke = P[P_STROKE]
    ring_len = ring.shape[0]
    i_d = S[S_ID]
    i_q = S[S_IQ]
    thm = S[S_THM]
    wm = S[S_WM]
    thl = S[S_THL]
    wl = S[S_WL]
    xd = S[S_XD]
    xq = S[S_XQ]
    zm = S[S_ZM]
    zl = S[S_ZL]
    ridx = int(S[S_RING])
    e_in = O[O_EIN]
    sigma = P[P_SCATTER]
    ripple = P[P_RIPPLE]
    scat = S[S_SCAT] if sigma > 0.0 else 1.0
    vd = 0.0
    vq = 0.0
    te = 0.0
    tfm = 0.0
    tfl = 0.0
    t_spring = 0.0
    t_flow = 0.0
    t_k = 0.0
    for _ in range(n):
        # ---------------- electrical ------------------------------------------------
        we = poles * wm
        emf_d = -we * lq * i_q               # L di/dt = v - R i - emf
        emf_q = we * (ld * i_d + psi)
        if enabled > 0.5:
            err_d = -i_d                      # id reference is zero (no field weakening)
            err_q = iq_ref - i_q
            vd = P[P_KPD] * err_d + xd
            vq = P[P_KPQ] * err_q + xq
            if P[P_DECOUPLE] > 0.5:
                vd += emf_d
                vq += emf_q
            if vd * vd + vq * vq > vlim * vlim:
                # d-axis priority keeps id at zero; the q axis gets what is left of the circle
                vd = min(max(vd, -vlim), vlim)
                vq_max = math.sqrt(vlim * vlim - vd * vd)
                vq = min(max(vq, -vq_max), vq_max)
            else:                             # integrate only while unsaturated (anti-windup)
                xd += P[P_KID] * err_d * dt
                xq += P[P_KIQ] * err_q * dt
        else:
            xd = 0.0
            xq = 0.0
            imag = math.sqrt(i_d * i_d + i_q * i_q)
            vd = emf_d
            vq = emf_q
            if imag > 0.0:                    # freewheel: the bridge opposes the current
                vd -= vlim * i_d / imag
                vq -= vlim * i_q / imag
            vmag = math.sqrt(vd * vd + vq * vq)
            if vmag > vlim:
                vd *= vlim / vmag
                vq *= vlim / vmag
        id_new = P[P_AD] * i_d + P[P_BD] * (vd - emf_d)
        iq_new = P[P_AQ] * i_q + P[P_BQ] * (vq - emf_q)
        if enabled <= 0.5 and (id_new * i_d + iq_new * i_q < 0.0 or (
                emf_d * emf_d + emf_q * emf_q <= vlim * vlim
                and id_new * id_new + iq_new * iq_new <= (vlim * P[P_BQ]) ** 2)):
            # diodes block: the current cannot reverse, and once it is smaller than one
            # step's decay at full bus voltage it is extinguished (unless the back-EMF
            # exceeds the bus and drives a braking current through the diodes)
            id_new = 0.0
            iq_new = 0.0
            vd = emf_d
            vq = emf_q
        id_mid = 0.5 * (i_d + id_new)
        iq_mid = 0.5 * (i_q + iq_new)
        i_d = id_new
        i_q = iq_new
        te = 1.5 * poles * (psi + (ld - lq) * id_mid) * iq_mid
        e_in += 1.5 * (vd * id_mid + vq * iq_mid) * dt

        # ---------------- mechanics -------------------------------------------------
        twist = thm / n_gear - thl
        half = P[P_BACKLASH_HALF]
        engaged = True
        if half > 0.0:
            if twist > half:
                twist -= half
            elif twist < -half:
                twist += half
            else:
                twist = 0.0
                engaged = False
        t_k = 0.0
        if engaged:
            t_k = P[P_K] * twist + P[P_C] * (wm / n_gear - wl)
        t_spring = P[P_SPRING0] + P[P_SPRINGK] * thl
        t_flow = P[P_FLOWMAX] * math.sin(math.pi * min(max(thl / stroke, 0.0), 1.0)) + P[P_LOAD]
        text_m = te - t_k / n_gear - P[P_BM] * wm
        text_l = t_k - P[P_BL] * wl - t_spring - t_flow
        tcl = P[P_TCL]
        tsl = P[P_TSL]
        if ripple > 0.0:
            r = 1.0 + ripple * math.sin(P[P_RIPPLE_K] * thl + P[P_RIPPLE_PHASE])
            tcl *= r
            tsl *= r
        if sigma > 0.0:
            tsl = max(tsl * scat, tcl)
        if P[P_LUGRE] > 0.5:
            wm_new, zm, tfm = _shaft_lugre(wm, zm, text_m, P[P_JM], P[P_TCM], P[P_TSM], P[P_VSM],
                                           P[P_SIG0M], P[P_SIG1M], dt)
            wl_new, zl, tfl = _shaft_lugre(wl, zl, text_l, P[P_JL], tcl, tsl, P[P_VSL],
                                           P[P_SIG0L], P[P_SIG1L], dt)
            if sigma > 0.0:
                # a new contact once the valve has really slid (beyond the Stribeck speed) and
                # then stops or reverses; the micro-motion of presliding draws nothing
                if abs(wl_new) > P[P_VSL]:
                    S[S_SCAT_ARMED] = 1.0
                elif S[S_SCAT_ARMED] > 0.5 and wl_new * wl <= 0.0:
                    scat = _draw_scatter(S, scatter, sigma)
                    S[S_SCAT_ARMED] = 0.0
        else:
            wm_new, tfm = _shaft_stick_slip(wm, text_m, P[P_JM], P[P_TCM], P[P_TSM], P[P_VSM], dt)
            wl_new, tfl = _shaft_stick_slip(wl, text_l, P[P_JL], tcl, tsl, P[P_VSL], dt)
            if sigma > 0.0 and wl != 0.0 and wl_new == 0.0:
                scat = _draw_scatter(S, scatter, sigma)       # came to rest: next breakaway differs
        # stops: the valve cannot be driven further into a stop it rests on
        if (thl <= 0.0 and wl_new < 0.0) or (thl >= stroke and wl_new > 0.0):
            wl_new = 0.0
        wm = wm_new
        wl = wl_new
        thm += dt * wm
        thl += dt * wl
        if thl < 0.0:                         # inelastic impact on the closed stop
            thl = 0.0
            wl = 0.0
        elif thl > stroke:                    # ... and on the open stop
            thl = stroke
            wl = 0.0
        ridx += 1
        if ridx >= ring_len:
            ridx = 0
        ring[ridx, 0] = thm
        ring[ridx, 1] = thl

    S[S_ID] = i_d
    S[S_IQ] = i_q
    S[S_THM] = thm
    S[S_WM] = wm
    S[S_THL] = thl
    S[S_WL] = wl
    S[S_XD] = xd
    S[S_XQ] = xq
    S[S_ZM] = zm
    S[S_ZL] = zl
    S[S_RING] = ridx
    if sigma > 0.0:
        S[S_SCAT] = scat
    O[O_VD] = vd
    O[O_VQ] = vq
    O[O_TE] = te
    O[O_TFM] = tfm
    O[O_TFL] = tfl
    O[O_TSPRING] = t_spring
    O[O_TFLOW] = t_flow
    O[O_TCOUPLING] = t_k
    O[O_EIN] = e_in


def _compile():
    """Compile the kernel with numba if available (and not disabled); else keep Python."""
    if os.environ.get("FUEL_VALVE_NO_JIT", "") == "1":
        return False
    try:
        import numba
    except ImportError:
        return False
    global _shaft_stick_slip, _shaft_lugre, _draw_scatter, advance
    jit = numba.njit(cache=True, nogil=True)
    _shaft_stick_slip = jit(_shaft_stick_slip)
    _shaft_lugre = jit(_shaft_lugre)
    _draw_scatter = jit(_draw_scatter)
    advance = jit(advance)
    return True


#: True when :func:`advance` is the numba-compiled version
JIT = _compile()


def new_arrays(ring_len: int):
    """Fresh (S, O, P, ring) arrays."""
    return (np.zeros(N_STATE), np.zeros(N_OUT), np.zeros(N_PARAM), np.zeros((max(ring_len, 1), 2)))
